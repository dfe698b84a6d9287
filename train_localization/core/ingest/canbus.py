"""A wheel pulse generator's and a Doppler radar's CAN frames as body speeds (cantools decodes them).

The frames are described by a DBC file (``config/devices/odometry.dbc`` is the example; any DBC
whose two messages carry the signals below will do, named by the ``wheel_message`` and
``radar_message`` parameters):

  wheel (``WHEEL_PULSES``)  ``PulseCount`` the device's running pulse count (wrapping at the
                            signal's width), ``Direction`` (0 standstill, 1 forward, 2 backward),
                            ``Status`` (0 ok), ``AliveCounter`` (+1 per frame, wrapping)
  radar (``RADAR_SPEED``)   ``Speed`` [m/s] over ground, + forwards, ``Quality`` [%],
                            ``AliveCounter``

and become BodyTwist records (core/ingest/records.py), the standard input's reading of a
nav_msgs/Odometry or geometry_msgs/TwistWithCovarianceStamped:

  * wheel: the pulses between two frames over their bus time stamps, x pi D / pulses per
    revolution (``WheelGeometry``: the wheel sensor's nominal diameter, as core/sensors/wheel.py
    counts), signed by the direction; variance that of the count's quantisation at both ends,
    (pi D / ppr)^2 / 6 / dt^2. The first frame, and the first after a pause longer than
    ``max_gap`` (counted ``gaps``), only sets the reference count;
  * radar: the speed as sent; variance the quantisation of its DBC scale, scale^2 / 12.

The reader's error models (the wheel's slip and diameter, the radar's scale) are the standard
input's (core/ingest/speed.py); this module only refuses what the bus cannot have meant. Refused
with a one-line reason (InputRejected), nothing held changes:

  ``unknown_id``    a frame id that is neither message (or an extended id the DBC lacks)
  ``length``        a data length other than the message's
  ``out_of_range``  a signal beyond its DBC range (a status, direction or quality code the
                    DBC does not define), pulses that would mean more than ``max_speed``
  ``stale``         a frame stamped at or before the last one of its message, more than
                    ``max_age`` behind the newest frame on the bus, or whose alive counter did
                    not move (a frozen sender repeating its frame)
  ``device_fault``  a wheel status other than ok
  ``quality``       a radar quality below ``min_quality``
  ``implausible``   pulses counted while the device says standstill

A jump of the alive counter by more than one is counted ``lost`` (frames missing from the
sequence, lost on the bus or refused here); the speed still holds (the count is cumulative).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cantools

from ..signals import InputRejected
from .records import BodyTwist

WHEEL_SIGNALS = ("PulseCount", "Direction", "Status", "AliveCounter")
RADAR_SIGNALS = ("Speed", "Quality", "AliveCounter")
DIRECTION_SIGN = {0: 0, 1: 1, 2: -1}


@dataclass(frozen=True)
class CanFrame:
    """One frame as the bus delivered it: its receive stamp [s], id and data bytes."""

    stamp: float
    frame_id: int
    data: bytes
    is_extended_id: bool = False


@dataclass(frozen=True)
class WheelGeometry:
    """The pulse generator's disc and wheel: pulses per revolution, nominal diameter [m]."""

    pulses_per_revolution: int
    diameter: float

    def __post_init__(self):
        if self.pulses_per_revolution < 1 or not self.diameter > 0.0:
            raise ValueError(f"wheel needs pulses_per_revolution >= 1 and a diameter > 0 m, not "
                             f"{self.pulses_per_revolution}, {self.diameter}")

    @property
    def distance_per_pulse(self) -> float:
        return math.pi * self.diameter / self.pulses_per_revolution


@dataclass(frozen=True)
class DeviceSpeed:
    """A body speed from one of the bus's devices (``device``: "wheel" or "radar")."""

    device: str
    twist: BodyTwist


@dataclass(frozen=True)
class CanLimits:
    """What the decoder takes: the least radar quality [%], the oldest frame behind the newest
    on the bus [s], the longest pause between two wheel frames [s], the highest speed [m/s]."""

    min_quality: float = 50.0
    max_age: float = 0.5
    max_gap: float = 1.0
    max_speed: float = 100.0


class CanOdometryDecoder:
    """CanFrames of the wheel and radar messages -> DeviceSpeed records (module docstring).
    ValueError in one line for a DBC or message that cannot be used."""

    def __init__(self, dbc_path: str, wheel: WheelGeometry, limits: CanLimits = CanLimits(),
                 wheel_message: str = "WHEEL_PULSES", radar_message: str = "RADAR_SPEED"):
        try:
            db = cantools.database.load_file(str(dbc_path))
        except (OSError, ValueError, cantools.database.UnsupportedDatabaseFormatError) as exc:
            raise ValueError(f"DBC file {dbc_path}: {str(exc).splitlines()[0]}") from None
        self.messages = {}   # frame id -> (device, cantools message)
        for device, name, needed in (("wheel", wheel_message, WHEEL_SIGNALS), ("radar", radar_message,
                                                                                RADAR_SIGNALS)):
            if not name:
                continue
            try:
                msg = db.get_message_by_name(name)
            except KeyError:
                raise ValueError(f"DBC file {dbc_path} has no message {name!r}") from None
            missing = [s for s in needed if s not in msg.signal_tree]
            if missing:
                raise ValueError(f"DBC message {name} lacks the signals {', '.join(missing)}")
            self.messages[(msg.frame_id, msg.is_extended_frame)] = (device, msg)
        if not self.messages:
            raise ValueError("no CAN message to read: give wheel_message or radar_message")
        self.wheel = wheel
        self.limits = limits
        self._newest = -math.inf
        self._last: dict[str, tuple[float, dict]] = {}   # device -> (stamp, signals) of its last frame taken
        self._reference: tuple[float, int] | None = None  # the wheel's (stamp, count) speeds start from
        self.stats = {"frames": 0, "lost": 0, "gaps": 0}

    def frame_ids(self) -> list[tuple[int, bool]]:
        """(id, extended) of the messages read (a bus filter)."""
        return list(self.messages)

    def decode(self, f: CanFrame) -> DeviceSpeed | None:
        """The speed of one frame (None: a wheel frame that sets the reference); InputRejected."""
        try:
            device, msg = self.messages[(f.frame_id, f.is_extended_id)]
        except KeyError:
            raise InputRejected("unknown_id", f"CAN id 0x{f.frame_id:X} is none of the DBC messages read") from None
        if len(f.data) != msg.length:
            raise InputRejected("length", f"{msg.name}: {len(f.data)} data bytes, not {msg.length}")
        values = msg.decode(bytes(f.data), decode_choices=False, scaling=True)
        for sig in msg.signals:
            v = values[sig.name]
            if (sig.minimum is not None and v < sig.minimum) or (sig.maximum is not None and v > sig.maximum):
                raise InputRejected("out_of_range", f"{msg.name}.{sig.name} = {v:g} outside "
                                                    f"{sig.minimum:g} .. {sig.maximum:g}")
        self._check_fresh(device, msg, f.stamp, values)
        if device == "wheel":
            out = self._wheel(msg, f.stamp, values)
        else:
            out = self._radar(msg, f.stamp, values)
        self._take(device, msg, f.stamp, values)
        return out

    def _check_fresh(self, device: str, msg, stamp: float, values: dict) -> None:
        if stamp < self._newest - self.limits.max_age:
            raise InputRejected("stale", f"{msg.name} stamped {self._newest - stamp:.3f} s behind the newest frame "
                                         f"(max_age {self.limits.max_age:g} s)")
        last = self._last.get(device)
        if last is None:
            return
        if not stamp > last[0]:
            raise InputRejected("stale", f"{msg.name} stamped {stamp - last[0]:+.6f} s after the last one")
        if values["AliveCounter"] == last[1]["AliveCounter"]:
            raise InputRejected("stale", f"{msg.name} alive counter stuck at {values['AliveCounter']:g} "
                                         "(a frozen sender)")

    def _take(self, device: str, msg, stamp: float, values: dict) -> None:
        last = self._last.get(device)
        if last is not None:
            modulus = 1 << msg.get_signal_by_name("AliveCounter").length
            self.stats["lost"] += (int(values["AliveCounter"]) - int(last[1]["AliveCounter"]) - 1) % modulus
        self._last[device] = (stamp, values)
        self._newest = max(self._newest, stamp)
        self.stats["frames"] += 1

    def _wheel(self, msg, stamp: float, values: dict) -> DeviceSpeed | None:
        if values["Status"] != 0:
            raise InputRejected("device_fault", f"{msg.name} status {values['Status']:g} (not ok)")
        count = int(values["PulseCount"])
        ref, here = self._reference, (stamp, count)
        if ref is None or stamp - ref[0] > self.limits.max_gap:
            self.stats["gaps"] += ref is not None
            self._reference = here
            return None
        dt = stamp - ref[0]
        pulses = (count - ref[1]) % (1 << msg.get_signal_by_name("PulseCount").length)
        sign = DIRECTION_SIGN[int(values["Direction"])]
        if pulses and not sign:
            raise InputRejected("implausible", f"{msg.name}: {pulses} pulses at standstill")
        speed = sign * pulses * self.wheel.distance_per_pulse / dt
        if abs(speed) > self.limits.max_speed:
            raise InputRejected("out_of_range", f"{msg.name}: {pulses} pulses in {dt:.3f} s, {abs(speed):.1f} m/s "
                                                f"(max_speed {self.limits.max_speed:g})")
        self._reference = here
        variance = self.wheel.distance_per_pulse ** 2 / 6.0 / dt ** 2
        return DeviceSpeed("wheel", BodyTwist(stamp, speed, variance))

    def _radar(self, msg, stamp: float, values: dict) -> DeviceSpeed:
        if values["Quality"] < self.limits.min_quality:
            raise InputRejected("quality", f"{msg.name} quality {values['Quality']:g} % below "
                                           f"{self.limits.min_quality:g} %")
        scale = msg.get_signal_by_name("Speed").scale
        return DeviceSpeed("radar", BodyTwist(stamp, float(values["Speed"]), scale ** 2 / 12.0))

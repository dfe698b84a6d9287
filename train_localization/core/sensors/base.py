"""The two halves of every sensor: a device simulator and a decoder.

``Simulator`` turns ground truth into raw blocks the way the device does (physics
from the seed papers), ``Decoder`` turns raw blocks into measurements. The decoder
never sees the truth: it gets the same blocks whether they come from the simulator,
a device driver or a bag. Both are plain objects driven block by block, with no
ROS: the sensor node (nodes/sensor.py), the offline replay and the tests drive
them the same way.

Error model: every sensor module declares ``error_model(params, track, vehicle)``
returning an ``ErrorModel``: what the fusion must know of the sensor's errors,
computed from the same resolved parameters that the simulator and the decoder use
(docs/fusion.md). Nothing else copies a sensor's noise figures.

Parameters: every sensor module declares ``PARAMS``, a dict name -> Param(default,
description, limits). The description carries the unit and where the default comes from
(seed file or datasheet); every number has ``limits``, the range the device or the physics
admits (not a tuning range). Nodes declare them as ROS parameters; scenarios override
them per sensor; a number beyond its limits is refused by both (``resolve_params``).
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType
from typing import Any, Callable, Mapping, NamedTuple

import numpy as np

from ..measurements import Measurement
from ..truth import TruthBuffer
from ..vehicle import Vehicle
from ..signals import InputRejected, RawBlock
from ..track import Track
from .faults import FAULT_MODES


@dataclass(frozen=True)
class Param:
    default: Any
    description: str
    limits: tuple | None = None     # inclusive (lo, hi) of a number: node and resolve_params refuse beyond

    @property
    def numeric(self) -> bool:
        """An int or float parameter (not a bool): one that has limits."""
        return isinstance(self.default, (int, float)) and not isinstance(self.default, bool)

    @property
    def meaning(self) -> str:
        """Its description and, for a number with limits, its range (as the node says)."""
        return self.description + (f" [{self.limits[0]:g} .. {self.limits[1]:g}]" if self.limits else "")

    def refusal(self, name: str, value) -> str | None:
        """Why ``value`` is refused by the limits (one line, as the node says), or None."""
        return out_of_limits(name, value, self.limits, self.default)


def out_of_limits(name: str, value, limits: tuple | None, default=None) -> str | None:
    """Why a number ``value`` of parameter ``name`` is refused by its inclusive ``limits`` (lo,
    hi), in one line, or None (no limits, not a number, inside). NaN is taken only where the
    ``default`` is NaN (the parameter's 'not set')."""
    if limits is None or isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    lo, hi = limits
    if lo <= value <= hi or (math.isnan(value) and isinstance(default, float) and math.isnan(default)):
        return None
    return f"parameter {name!r} must be in {lo:g} .. {hi:g}, not {value!r}"


def check_declared(params: dict[str, "Param"], owner: str) -> None:
    """Every number of ``params`` has limits (lo <= hi, integers for an integer) that hold
    its default; ValueError naming ``owner`` and the parameter otherwise."""
    for name, p in params.items():
        if not p.numeric:
            continue
        if p.limits is None or len(p.limits) != 2 or not p.limits[0] <= p.limits[1]:
            raise ValueError(f"{owner}: numeric parameter {name!r} needs limits (lo, hi), not {p.limits!r}")
        if isinstance(p.default, int) and not all(isinstance(v, int) and not isinstance(v, bool) for v in p.limits):
            raise ValueError(f"{owner}: integer parameter {name!r} needs integer limits, not {p.limits!r}")
        why = p.refusal(name, p.default)
        if why:
            raise ValueError(f"{owner}: default of {why}")


COMMON_PARAMS = {
    "unit_id": Param("", "device instance name; empty = the sensor name"),
    "sample_rate": Param(0.0, "raw sample rate [Hz]; 0 = the sensor's default", (0.0, 1.0e8)),
    "block_duration": Param(0.05, "length of one raw block [s] (raw signals travel in blocks: docs/nodes.md)", (1.0e-3, 10.0)),
    "max_block_duration": Param(1.0, "longest raw block decoded [s], at least block_duration; a longer one is "
                                     "refused (too_large): it bounds the decoding time and memory per block",
                                (1.0e-3, 60.0)),
}
check_declared(COMMON_PARAMS, "COMMON_PARAMS")


def samples_per_block(params: dict, rate: float) -> int:
    """Samples in one raw block at ``rate`` [Hz]: ``block_duration`` of them, at least one."""
    return max(1, int(round(params.get("block_duration", COMMON_PARAMS["block_duration"].default) * rate)))


def resolve_params(declared: dict[str, Param], overrides: dict | None) -> dict[str, Any]:
    """Defaults of ``declared`` (plus the common ones) updated by ``overrides``.

    Unknown names raise ValueError so that a typo in a scenario or YAML file is not
    silently ignored; values are cast to the type of the default; a number beyond its
    ``limits`` raises ValueError in one line (the node's message: a scenario file is
    refused like a ROS parameter).
    """
    known = {**COMMON_PARAMS, **declared}
    params = {name: p.default for name, p in known.items()}
    for name, value in (overrides or {}).items():
        if name not in params:
            raise ValueError(f"unknown parameter {name!r}; known: {', '.join(sorted(params))}")
        default = params[name]
        if isinstance(default, bool):
            params[name] = bool(value)
        elif isinstance(default, float):
            params[name] = float(value)
        elif isinstance(default, int):
            params[name] = int(value)
        elif isinstance(default, list):
            params[name] = list(value)
        else:
            params[name] = value
        why = known[name].refusal(name, params[name])
        if why:
            raise ValueError(why)
    return params


def sensor_params(spec: "SensorSpec", overrides: dict | None, vehicle: Vehicle) -> dict[str, Any]:
    """A sensor's resolved parameters for one vehicle (the decoder's nominal wheel diameter
    and axle layout are the vehicle's unless set)."""
    params = dict(overrides or {})
    if "wheel_diameter" in spec.params and "wheel_diameter" not in params:
        params["wheel_diameter"] = vehicle.wheel_diameter
    if "axle_offsets" in spec.params and "axle_offsets" not in params:
        params["axle_offsets"] = list(vehicle.axles)
    return resolve_params(spec.params, params)


MEASURES = ("speed", "distance", "position", "occupancy", "yaw_rate", "acceleration")

# [m] least 1-sigma of a fix of a sensor that reads equipment from the track file: the millimetre
# of the file's chainages (a guard for sensors whose error parameters may all be 0)
MIN_FIX_SIGMA = 1e-3


class ReferenceWindow(NamedTuple):
    """Chainages [m] between which an honest fix naming one reference can lie (the
    reference's extent, widened by the antenna offsets and the reach of the sensor)."""

    lo: float
    hi: float


@dataclass(frozen=True)
class ReferenceTable:
    """The references a position sensor's fixes can name on one track, built by the sensor
    from the track's equipment (its ``error_model``): reference id -> ReferenceWindow.

    A fix naming an id that is not in the table is ``unknown_reference``; one whose
    position lies outside its reference's window by more than ``sigmas`` of its own
    1-sigma is ``reference_mismatch``. A composite id (``separator`` not empty: the
    stations an mm-wave fix used) names several references: each must be known and the
    fix must lie in every one's window.
    """

    windows: Mapping[str, ReferenceWindow]
    separator: str = ""
    sigmas: float = 5.0

    def __post_init__(self):
        object.__setattr__(self, "windows", MappingProxyType(dict(self.windows)))

    def passed(self, since: float, lo: float, hi: float) -> list[str]:
        """The references the train has passed since it was at ``since`` [m] (its last fix of
        this sensor) now that it is within [lo, hi] [m]: those whose whole window lies between
        the two, in the direction it went (nearest first)."""
        if lo > since:
            ahead = [(w.lo, ref) for ref, w in self.windows.items() if w.lo > since and w.hi < lo]
            return [ref for _, ref in sorted(ahead)]
        if hi < since:
            behind = [(-w.hi, ref) for ref, w in self.windows.items() if w.hi < since and w.lo > hi]
            return [ref for _, ref in sorted(behind)]
        return []

    def refusal(self, reference_id: str, position: float, stddev: float) -> InputRejected | None:
        """Why a fix naming ``reference_id`` at ``position`` [m] with 1-sigma ``stddev`` [m]
        cannot be an honest fix of this sensor on this track, or None."""
        parts = reference_id.split(self.separator) if self.separator else [reference_id]
        margin = self.sigmas * stddev
        for part in parts:
            window = self.windows.get(part)
            if window is None:
                return InputRejected("unknown_reference", f"reference {_short(part)!r} is not in the track's "
                                                          f"equipment ({len(self.windows)} known)")
            if not window.lo - margin <= position <= window.hi + margin:
                return InputRejected("reference_mismatch", f"fix at {position:.3f} m names {part!r}, whose fixes "
                                                           f"lie in {window.lo:.3f} .. {window.hi:.3f} m")
        return None


def _short(text: str, limit: int = 64) -> str:
    """``text`` cut to ``limit`` characters for a one-line message."""
    return text if len(text) <= limit else text[:limit] + "..."


# the range of each number of an ErrorModel (checked when one is made; the fusion node's nested
# parameters <sensor>.<field> carry it in their descriptors): scale errors as fractions, a wheel's
# creep coefficient [s^2/m], the gate's probability (1: no gate; NaN: the fusion's global one)
ERROR_MODEL_LIMITS = {
    "scale_sigma": (0.0, 1.0), "scale_tau": (0.0, math.inf), "scale_offset_sigma": (0.0, 1.0),
    "bias_sigma": (0.0, math.inf), "bias_tau": (0.0, math.inf), "fix_bias_sigma": (0.0, math.inf), "fix_bias_length": (0.0, math.inf),
    "fix_bias_tau": (0.0, math.inf), "fix_excess_length": (0.0, math.inf), "fix_excess_tau": (0.0, math.inf),
    "fix_white_sigma": (0.0, math.inf), "reported_scale": (0.0, 1.0),
    "reported_bias": (0.0, math.inf), "reported_fix_bias": (0.0, math.inf), "creep_coefficient": (0.0, 1.0),
    "scale_fault_sigma": (0.0, 1.0), "fault_duration_max": (0.0, math.inf), "slip_ratio_max": (0.0, 1.0),
    "timeout": (0.0, math.inf), "latency": (0.0, math.inf),
    "gate_probability": (0.5, 1.0), "stddev_factor": (1.0e-3, 1.0e3), "min_stddev": (0.0, math.inf),
}


# the fields whose NaN means "as the fusion or another field has it"
NAN_MEANS_DEFAULT = ("gate_probability", "fix_excess_length", "fix_excess_tau", "latency")


@dataclass(frozen=True)
class ErrorModel:
    """The errors of one sensor as the fusion models them (docs/fusion.md).

    A decoder reports each measurement's 1-sigma including its slowly varying
    errors as if they were white; the ``reported_*`` parts are the ones the fusion
    carries as states instead and removes from the measurement noise. Units: scale
    errors as fractions, speeds in m/s, positions in m, times in s.
    """

    sensor: str                          # sensor class (topic key)
    measures: str                        # one of MEASURES
    scale_sigma: float = 0.0             # 1-sigma scale error (stationary if scale_tau is finite); 0 = no state
    scale_tau: float = math.inf          # correlation time of the scale error [s]; inf = constant
    scale_offset_sigma: float = 0.0      # constant scale error on top of a Gauss-Markov one; 0 = no state
    bias_sigma: float = 0.0              # speed bias along the motion [m/s] (an acceleration's [m/s^2]); 0 = no state
    bias_tau: float = math.inf           # correlation time of the bias [s]; inf = constant
    fix_bias_sigma: float = 0.0          # persistent position-fix error [m]; 0 = no state
    fix_bias_length: float = math.inf    # its correlation length along the track [m]
    fix_bias_tau: float = math.inf       # its correlation time [s]
    fix_bias_per_reference: bool = False  # a new reference_id draws a new, independent fix bias
    fix_white_sigma: float = math.inf    # largest white 1-sigma of one fix [m]; what a fix reports beyond
                                         # it (the decoder's protection against an undetected fault)
                                         # persists as long as its cause: not averaged over that time
    fix_excess_length: float = math.nan  # that cause's correlation length [m] and time [s] (a transient
    fix_excess_tau: float = math.nan     # fault: an NLOS episode); NaN = the fix bias's
    reported_scale: float = 0.0          # scale 1-sigma included in the reported stddev
    reported_bias: float = 0.0           # bias 1-sigma [m/s] included in the reported stddev
    reported_fix_bias: float = 0.0       # fix-bias 1-sigma [m] included in the reported stddev
    creep_coefficient: float = 0.0       # wheel creep c [s^2/m]: wheel speed = v (1 + c a sign v)
    creep_in_traction: bool = True       # creep under traction too (a motored axle), else only braking
    faults: tuple[str, ...] = ()         # fault modes (faults.py) the fusion must check for
    common_causes: tuple[str, ...] = ()  # causes of failure it shares with other sensors of the train (a wheel's
                                         # and a radar's "track_surface": wet rail, snow): those fail together
    scale_fault_sigma: float = 0.0       # 1-sigma size of a persistent scale fault (``scale_fault``, ``wear``) [1]:
                                         # what its scale may be off by once the fusion suspects one
    fault_duration_max: float = math.inf  # longest episode of its transient fault modes (slip, slide)
                                         # [s]; a disagreement that lasts longer is not one of them
    slip_ratio_max: float = 0.0          # largest |slip ratio| of those episodes [1] (anti-slip and
                                         # wheel-slide protection's limit): what an undetected one can
                                         # put into a dead reckoning that uses the sensor
    timeout: float = math.inf            # longest silence while in use [s]; inf = sparse/event sensor
    latency: float = math.nan            # longest delay from a measurement's stamp to its delivery [s]: its
                                         # block's length plus the decoder's delay (SensorSpec.errors); a
                                         # holding fusion waits this long to apply inputs in stamp order
                                         # (core/fusion/runner.py); NaN = not declared (never waited for)
    gate_probability: float = math.nan   # chi-square gate of its measurements; NaN = the fusion's global one
    stddev_factor: float = 1.0           # factor on the white part of the reported stddev
    min_stddev: float = 0.0              # smallest 1-sigma an honest measurement of the sensor reports,
                                         # from its resolved parameters: [m] of a fix, [m/s] of a speed and
                                         # of an increment's mean speed (its distance_stddev / duration too);
                                         # a message that claims less is refused (below_model)
    sensor_offset: float = 0.0           # [m] of the sensor's own point behind the train front, where a
                                         # network's hypotheses place what it measures: a 2-D fix's antenna,
                                         # a gyro turning with the body (core/network/hypotheses.py)
    references: ReferenceTable | None = field(default=None, compare=False)
                                         # the track's references its fixes can name; None = not checked

    def __post_init__(self):
        if self.measures not in MEASURES:
            raise ValueError(f"{self.sensor}: measures must be one of {MEASURES}, not {self.measures!r}")
        unknown = set(self.faults) - set(FAULT_MODES)
        if unknown:
            raise ValueError(f"{self.sensor}: unknown fault modes {sorted(unknown)}; known: {FAULT_MODES}")
        for name, (lo, hi) in ERROR_MODEL_LIMITS.items():
            value = getattr(self, name)
            if name in NAN_MEANS_DEFAULT and math.isnan(value):
                continue
            if not lo <= value <= hi:
                raise ValueError(f"{self.sensor}: error model {name} = {value} must be in [{lo:g}, {hi:g}]")

    @property
    def relative(self) -> bool:
        """Measures speed or distance (dead reckoning), not position."""
        return self.measures in ("speed", "distance")

    def refusal(self, m) -> InputRejected | None:
        """Why measurement ``m`` of this sensor claims more than the model allows, or None: a
        1-sigma below ``min_stddev`` (``below_model``), a reference that is not in the track's
        equipment or lies elsewhere (``unknown_reference``, ``reference_mismatch``)."""
        floor = self.min_stddev * (1.0 - 1e-9)
        if self.measures == "position":
            if m.position_stddev < floor:
                return InputRejected("below_model", f"{self.sensor} fix claims 1-sigma {m.position_stddev:.3g} m, "
                                                    f"below its model's {self.min_stddev:.3g} m")
            if self.references is not None:
                return self.references.refusal(m.reference_id, m.position, m.position_stddev)
            return None
        if self.measures == "yaw_rate":
            if m.yaw_rate_stddev < floor:
                return InputRejected("below_model", f"{self.sensor} yaw rate claims 1-sigma {m.yaw_rate_stddev:.3g} "
                                                    f"rad/s, below its model's {self.min_stddev:.3g} rad/s")
            return None
        if self.measures == "acceleration":
            if m.acceleration_stddev < floor:
                return InputRejected("below_model", f"{self.sensor} acceleration claims 1-sigma "
                                                    f"{m.acceleration_stddev:.3g} m/s^2, below its model's "
                                                    f"{self.min_stddev:.3g} m/s^2")
            return None
        claimed = m.speed_stddev
        if self.measures == "distance":
            claimed = min(claimed, m.distance_stddev / m.duration)
        if claimed < floor:
            return InputRejected("below_model", f"{self.sensor} {self.measures} claims 1-sigma {claimed:.3g} m/s, "
                                                f"below its model's {self.min_stddev:.3g} m/s")
        return None

    def overridden(self, values: dict | None) -> "ErrorModel":
        """This model with some fields replaced (a user who knows better); unknown names raise."""
        if not values:
            return self
        names = {f.name for f in fields(self)} - {"sensor", "measures", "references"}
        bad = set(values) - names
        if bad:
            raise ValueError(f"unknown error-model field(s) {sorted(bad)} for {self.sensor}; known: "
                             f"{', '.join(sorted(names))}")
        kinds = {f.name: type(getattr(self, f.name)) for f in fields(self)}
        cast = {k: (tuple(v) if k == "faults" else bool(v) if kinds[k] is bool else float(v))
                for k, v in values.items()}
        return replace(self, **cast)


def first_order_filter(b: list, a: list, x: np.ndarray, zi) -> tuple[np.ndarray, np.ndarray]:
    """scipy.signal.lfilter(b, a, x, zi=zi): (output, final state) of a first-order IIR filter.
    scipy.signal is imported on first use: at module level it was 1.3 s of every node's 1.8 s
    start-up (`doppler_radar --help`), in the sensor nodes that never filter as in those that do."""
    from scipy.signal import lfilter
    return lfilter(b, a, x, zi=zi)


def gauss_markov(rng: np.random.Generator, sigma: float, tau: float, dt: float, n: int, last: float) -> np.ndarray:
    """n further samples, dt [s] apart, of a first-order Gauss-Markov process of 1-sigma ``sigma``
    and correlation time ``tau`` [s] whose previous sample was ``last`` (exact discretisation)."""
    phi = math.exp(-dt / tau)
    w = rng.normal(0.0, sigma * math.sqrt(1.0 - phi * phi), n)
    return first_order_filter([1.0], [1.0, -phi], w, [phi * last])[0]


def continuous_timeout(params: dict) -> float:
    """Timeout of a sensor that reports every block: 20 blocks, at least 1 s."""
    return max(1.0, 20.0 * float(params.get("block_duration", 0.05)))


OFF_RAILS = -1.0e7   # [m] chainage of an axle that is not on a wayside device's rails (beyond any equipment)


class Simulator(ABC):
    """Simulates one device: raw blocks of consecutive, gap-free intervals.

    Subclasses set ``sensor``, ``channels``, ``units``, ``default_sample_rate`` and
    implement ``samples``. ``rng`` is the device's own random stream.

    Wayside devices (``sees_all_trains``) also run on a line: ``fleet`` lists the vehicles
    of its trains, the truth is a scenario.LineTruth and ``samples`` gets (n, trains)
    arrays; ``orientations`` and ``axle_chainages`` place every train's axles.
    """

    sensor: str = ""
    channels: tuple[str, ...] = ()
    units: tuple[str, ...] = ()
    default_sample_rate: float = 100.0
    # resolution of the device's A/D conversion by channel unit, e.g. {"V": 5 / 4096};
    # samples of those channels are rounded to it (a real ADC; it also keeps bags small)
    adc_lsb: dict[str, float] = {}
    sees_all_trains: bool = False   # wayside equipment: on a line it sees every train

    def __init__(self, params: dict, track: Track, vehicle: Vehicle, rng: np.random.Generator,
                 fleet: list[Vehicle] | None = None):
        self.params = params
        self.track = track
        self.vehicle = vehicle
        self.rng = rng
        if fleet and not self.sees_all_trains:
            raise ValueError(f"{self.sensor} is on-board equipment: it sees only its own train")
        self.fleet = list(fleet) if fleet else [vehicle]   # the vehicles seen, in the truth's column order
        # on a network (core/network/wayside.py): per train, where its route runs along this
        # device's section (a Placement: route-line chainage -> section chainage), or None
        self.placements: list | None = None
        self._orients: list[int | None] | None = None
        self.unit_id = params.get("unit_id") or self.sensor
        self.sample_rate = float(params.get("sample_rate") or self.default_sample_rate)
        self.samples_per_block = samples_per_block(params, self.sample_rate)
        self.seq = 0
        self._next_t0: float | None = None

    def start(self, t0: float) -> None:
        """Set the time of the first sample [s] (default: the first truth stamp)."""
        self._next_t0 = t0

    def simulate(self, truth: TruthBuffer) -> list[RawBlock]:
        """All blocks that the truth received so far covers completely."""
        if truth.latest is None:
            return []
        if self._next_t0 is None:
            self._next_t0 = truth.earliest
        blocks = []
        block_len = self.samples_per_block / self.sample_rate
        while self._next_t0 + block_len <= truth.latest + 1e-9:
            n0 = self._sample_index(self._next_t0)
            times = (n0 + np.arange(self.samples_per_block)) / self.sample_rate
            s, v, a = truth.sample(times)
            data = self.samples(times, s, v, a)
            if self.adc_lsb:
                data = self._quantise(np.array(data, dtype=float))
            blocks.append(RawBlock.from_samples(self.sensor, self.unit_id, self.seq, float(times[0]),
                                                self.sample_rate, self.channels, self.units, data))
            self.seq += 1
            self._next_t0 = (n0 + self.samples_per_block) / self.sample_rate
        return blocks

    def orientations(self, speed: np.ndarray) -> list[int | None]:
        """Each seen train's orientation: the parameter ``orientation``, or if 0 the sign of the
        train's first motion (a train starts front first; None until it moves). ``speed``: (n,)
        for one train or (n, trains) [m/s]."""
        if self._orients is None:
            self._orients = [int(np.sign(self.params.get("orientation", 0))) or None] * len(self.fleet)
        spd = speed if speed.ndim == 2 else speed[:, None]
        for j, o in enumerate(self._orients):
            if o is None:
                moving = np.flatnonzero(np.abs(spd[:, j]) > 0.01)
                if len(moving):
                    self._orients[j] = int(np.sign(spd[moving[0], j]))
        return self._orients

    def axle_chainages(self, position: np.ndarray) -> list[np.ndarray]:
        """Chainages [m] of every seen train's axles, one (n, axles) array per train: axle k at
        front - o x offset_k, o the train's orientation (``orientations``; +1 before it is
        known). ``position``: (n,) for one train or (n, trains). On a network each train's
        axles are placed on the device's section by ``placements``."""
        orients = self._orients or [int(np.sign(self.params.get("orientation", 0))) or None] * len(self.fleet)
        pos = position if position.ndim == 2 else position[:, None]
        axles = [pos[:, j:j + 1] - (orients[j] or 1) * np.asarray(vehicle.axles, float)[None, :]
                 for j, vehicle in enumerate(self.fleet)]
        if self.placements is None:
            return axles
        return [place(x) if place is not None else np.full_like(x, OFF_RAILS)
                for x, place in zip(axles, self.placements)]

    def _quantise(self, data: np.ndarray) -> np.ndarray:
        lsb = np.array([self.adc_lsb.get(u, 0.0) for u in self.units])
        q = lsb > 0
        data[:, q] = np.round(data[:, q] / lsb[q]) * lsb[q]
        return data

    def _sample_index(self, t: float) -> int:
        return int(round(t * self.sample_rate))

    @abstractmethod
    def samples(self, times: np.ndarray, position: np.ndarray, speed: np.ndarray,
                acceleration: np.ndarray) -> np.ndarray:
        """Raw samples, shape (len(times), len(channels)), for the true motion given."""


class Decoder(ABC):
    """Decodes raw blocks of one device into measurements; keeps state between blocks.

    ``decode`` raises signals.InputRejected for a block it cannot use (unknown code,
    implausible signal); the caller counts it and goes on with the next block.
    """

    sensor: str = ""
    channels: tuple[str, ...] = ()
    # attributes that only memoise (bounded, results do not depend on them): the only state a
    # rejected block may change
    caches: tuple[str, ...] = ("_offsets",)

    def __init__(self, params: dict, track: Track):
        self.params = params
        self.track = track
        self.unit_id = params.get("unit_id") or self.sensor
        self.stats: dict[str, float] = {}
        self._offsets: dict = {}   # sample times - t0 per (n, sample rate)

    def sample_offsets(self, n: int, rate: float) -> np.ndarray:
        """Sample times of an n-sample block at ``rate`` [Hz] relative to its first sample [s]
        (as RawBlock.times), memoised per block shape (a few; read-only arrays)."""
        offsets = self._offsets.get((n, rate))
        if offsets is None:
            if len(self._offsets) > 8:
                self._offsets.clear()
            offsets = self._offsets[n, rate] = np.arange(n) / rate
            offsets.flags.writeable = False
        return offsets

    @abstractmethod
    def decode(self, block: RawBlock) -> list[Measurement]:
        """Measurements contained in one block (possibly none)."""


@dataclass(frozen=True)
class SensorSpec:
    """Everything a node or the offline replay needs to run one kind of sensor."""

    node: str                      # executable / node name, e.g. "doppler_radar"
    sensor: str                    # topic key: sensors/<sensor>/...
    simulator: type[Simulator]
    decoder: type[Decoder]
    params: dict[str, Param]
    description: str
    seeds: tuple[str, ...] = field(default=())
    # measurement kinds published: "position", "speed", "distance", "sections"
    outputs: tuple[str, ...] = ("position", "speed", "distance")
    # (resolved params, track, vehicle) -> ErrorModel
    error_model: Callable[[dict, Track, Vehicle], ErrorModel] | None = None
    # [s] longest a decoder holds a sample beyond the end of its block before the measurement it
    # makes is out (a read that needs the next block); with ``block_duration`` the sensor's latency
    decoder_delay: float = 0.0

    def __post_init__(self):
        check_declared(self.params, self.node)

    def errors(self, params: dict, track: Track, vehicle: Vehicle) -> ErrorModel:
        """The sensor's error model for its resolved ``params``; unless the model declares its
        latency, it is the length of one raw block plus ``decoder_delay`` [s]."""
        if self.error_model is None:
            raise ValueError(f"sensor {self.node} declares no error model")
        model = self.error_model(params, track, vehicle)
        if math.isnan(model.latency):   # a sample waits at most its block, then the decoder
            rate = float(params.get("sample_rate") or self.simulator.default_sample_rate)
            model = replace(model, latency=samples_per_block(params, rate) / rate + self.decoder_delay)
        return model

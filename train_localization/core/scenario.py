"""Scenario description and the ground-truth motion it produces.

A scenario (YAML in config/) names a track, a vehicle, a speed profile, the sensors
with their parameter overrides, and a random seed. The same scenario and seed give
bit-identical truth and sensor output (random streams are derived from the seed and
the device name, never from the order in which devices are created).

Speed profile: a list of legs run in order. Each leg drives the speed towards
``speed`` [m/s] (signed; a reversal passes through 0) with at most ``accel``
[m/s^2] when speeding up and ``decel`` [m/s^2] when slowing down, the acceleration
changing at most by ``jerk`` [m/s^3]; once there it holds the speed for ``hold``
[s]. ``speed: 0`` with ``hold`` is a stop with a dwell time.

Closed loop: instead of ``profile`` a scenario may give ``control`` (a speed controller and
its set-points, core/control.py) and ``dynamics`` (the vehicle's drive and resistance,
core/dynamics.py); its motion then comes from ``core.control.closed_loop`` (offline) or from
the simulator node integrating the controller's traction command, not from ``trajectory``.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from . import paths
from .track import Track


class ScenarioError(ValueError):
    """A scenario that cannot be run, with the reason."""


@dataclass(frozen=True)
class TruthState:
    """True kinematic state of the train front at ``stamp`` [s]."""

    stamp: float
    position: float      # chainage [m]
    speed: float         # [m/s]
    acceleration: float  # [m/s^2]


@dataclass(frozen=True)
class Leg:
    speed: float
    accel: float = 0.8
    decel: float = 1.0
    jerk: float = 0.5
    hold: float = 0.0


@dataclass
class Vehicle:
    """Vehicle type, length [m] and axle offsets behind the front [m] (none for maglev)."""

    kind: str = "conventional"
    length: float = 200.0
    axles: tuple[float, ...] = ()
    wheel_diameter: float = 0.92  # nominal [m]


@dataclass
class Scenario:
    name: str
    track: Track
    vehicle: Vehicle
    legs: list[Leg]
    duration: float
    seed: int = 0
    start_position: float = 0.0
    start_speed: float = 0.0
    truth_rate: float = 100.0            # ground_truth/state rate [Hz]
    sensors: dict[str, dict] = field(default_factory=dict)  # sensor node name -> parameters
    fusion: dict = field(default_factory=dict)  # FusionConfig overrides (core/fusion.py)
    source: Path | None = None
    description: dict = field(default_factory=dict, repr=False)  # the YAML, track inlined
    control: dict = field(default_factory=dict)    # closed-loop speed control (core/control.py); {} = profile
    dynamics: dict = field(default_factory=dict)   # drive and resistance parameters (core/dynamics.py)

    def to_yaml(self) -> str:
        """Self-contained YAML of the scenario (track inlined): recorded into bags."""
        return yaml.safe_dump(self.description, sort_keys=False)

    def rng(self, *names: str) -> np.random.Generator:
        """Independent random stream for one device, stable across runs and orderings."""
        digest = hashlib.sha256("/".join(names).encode()).digest()
        return np.random.default_rng([int(self.seed), int.from_bytes(digest[:8], "little")])

    def trajectory(self, dt: float = 1e-3) -> "Trajectory":
        if self.control:
            raise ScenarioError(f"scenario {self.name} runs under closed-loop control: its motion comes from "
                                "core.control.closed_loop or the simulator node, not from a profile")
        traj = Trajectory.from_legs(self.legs, self.start_position, self.start_speed, self.duration, dt)
        if self.track.closed:
            traj.period = self.track.length
        return traj

    @classmethod
    def from_yaml(cls, path: str | Path) -> "Scenario":
        path = paths.resolve(path)
        try:
            with open(path, encoding="utf-8") as fh:
                data = yaml.safe_load(fh)
        except OSError as exc:
            raise ScenarioError(f"cannot read scenario {path}: {exc.strerror}") from None
        return cls.from_dict(data, source=path)

    @classmethod
    def from_dict(cls, data: dict, source: Path | None = None) -> "Scenario":
        try:
            track_ref = data["track"]
            if isinstance(track_ref, dict):
                track_data = track_ref
            else:
                track_path = Path(track_ref)
                if not track_path.is_absolute() and source is not None and (source.parent / track_path.name).exists():
                    track_path = source.parent / track_path.name
                with open(paths.resolve(track_path), encoding="utf-8") as fh:
                    track_data = yaml.safe_load(fh)
            track = Track.from_dict(track_data)
            veh = data.get("vehicle", {}) or {}
            vehicle = Vehicle(kind=str(veh.get("type", "conventional")), length=float(veh.get("length", 200.0)),
                              axles=tuple(float(a) for a in veh.get("axles", ()) or ()),
                              wheel_diameter=float(veh.get("wheel_diameter", 0.92)))
            control = dict(data.get("control", {}) or {})
            legs = [Leg(**{k: float(v) for k, v in leg.items()})
                    for leg in (data.get("profile", []) if control else data["profile"]) or []]
            init = data.get("initial", {}) or {}
            scenario = cls(
                name=str(data.get("name", source.stem if source else "scenario")),
                track=track, vehicle=vehicle, legs=legs, duration=float(data["duration"]),
                seed=int(data.get("seed", 0)), start_position=float(init.get("position", 0.0)),
                start_speed=float(init.get("speed", 0.0)), truth_rate=float(data.get("truth_rate", 100.0)),
                sensors={name: dict(params or {}) for name, params in (data.get("sensors", {}) or {}).items()},
                fusion=dict(data.get("fusion", {}) or {}),
                source=source, description={**data, "track": track_data},
                control=control, dynamics=dict(data.get("dynamics", {}) or {}),
            )
        except KeyError as exc:
            raise ScenarioError(f"scenario lacks the key {exc}") from None
        except TypeError as exc:
            raise ScenarioError(f"scenario has a malformed entry: {exc}") from None
        if scenario.duration <= 0:
            raise ScenarioError("scenario duration must be > 0 s")
        if scenario.control:
            from .control import control_config
            from .dynamics import DYNAMICS_PARAMS
            from .sensors.base import resolve_params
            try:
                control_config(scenario.control)
                resolve_params(DYNAMICS_PARAMS, scenario.dynamics)
            except ValueError as exc:
                raise ScenarioError(f"scenario {scenario.name}: {exc}") from None
        if not 0 <= scenario.start_position <= track.length:
            raise ScenarioError(f"initial position {scenario.start_position} m is off the track")
        return scenario


class Trajectory:
    """Ground-truth motion sampled every ``dt`` [s]: arrays t, position, speed, acceleration.

    ``position`` is the distance run from the track's origin; on a closed track (``period`` its
    length [m]) ``state_at`` gives the chainage wrapped round it."""

    period: float | None = None

    def __init__(self, t, position, speed, acceleration):
        self.t, self.position, self.speed, self.acceleration = t, position, speed, acceleration

    @classmethod
    def from_legs(cls, legs, s0, v0, duration, dt):
        n = int(round(duration / dt)) + 1
        t = np.arange(n) * dt
        s = np.empty(n)
        v = np.empty(n)
        a = np.empty(n)
        s[0], v[0], a[0] = s0, v0, 0.0
        leg_idx, hold_left, reached = 0, None, False
        for k in range(1, n):
            acc = a[k - 1]
            if leg_idx < len(legs):
                leg = legs[leg_idx]
                err = leg.speed - v[k - 1]
                if not reached:
                    speeding_up = (err > 0) == (v[k - 1] >= 0) and abs(v[k - 1]) > 1e-9 or abs(v[k - 1]) <= 1e-9
                    limit = leg.accel if speeding_up else leg.decel
                    # accelerate with limited jerk; start easing off early enough
                    # that the acceleration is back to ~0 when the target is reached
                    a_target = math.copysign(limit, err)
                    ease = acc * acc / (2.0 * leg.jerk)
                    if abs(err) <= ease + abs(acc) * dt:
                        a_target = 0.0
                    acc += float(np.clip(a_target - acc, -leg.jerk * dt, leg.jerk * dt))
                    if abs(err) < 1e-3 or (abs(err) < abs(acc) * dt * 2 and a_target == 0.0):
                        reached, hold_left, acc = True, leg.hold, 0.0
                if reached:
                    acc = float(np.clip((leg.speed - v[k - 1]) / dt, -leg.jerk * dt, leg.jerk * dt))
                    hold_left -= dt
                    if hold_left <= 0:
                        leg_idx, reached = leg_idx + 1, False
            else:
                acc = float(np.clip(-acc, -0.5 * dt, 0.5 * dt)) + acc
            a[k] = acc
            v[k] = v[k - 1] + acc * dt
            s[k] = s[k - 1] + 0.5 * (v[k - 1] + v[k]) * dt
        return cls(t, s, v, a)

    def state_at(self, stamp: float) -> TruthState:
        position = float(np.interp(stamp, self.t, self.position))
        if self.period:
            position %= self.period
        return TruthState(float(stamp), position,
                          float(np.interp(stamp, self.t, self.speed)),
                          float(np.interp(stamp, self.t, self.acceleration)))


class TruthBuffer:
    """Recent ground-truth states; samples the motion at arbitrary times in between.

    Sensor simulators run on ``ground_truth/state`` messages (DESIGN.md section 5);
    between two states the acceleration of the earlier one is held, which is exact
    for the piecewise-constant acceleration of the simulator at its state rate.
    """

    def __init__(self, horizon: float = 10.0):
        self.horizon = horizon
        self._t: list[float] = []
        self._s: list[float] = []
        self._v: list[float] = []
        self._a: list[float] = []

    def add(self, state: TruthState) -> None:
        """Append a state; states must come in increasing time (others are ignored)."""
        if self._t and state.stamp <= self._t[-1]:
            return
        self._t.append(state.stamp)
        self._s.append(state.position)
        self._v.append(state.speed)
        self._a.append(state.acceleration)
        if self._t[-1] - self._t[0] > 2 * self.horizon:
            cut = int(np.searchsorted(self._t, self._t[-1] - self.horizon))
            del self._t[:cut], self._s[:cut], self._v[:cut], self._a[:cut]

    @property
    def latest(self) -> float | None:
        """Stamp of the newest state [s], None before the first."""
        return self._t[-1] if self._t else None

    @property
    def earliest(self) -> float | None:
        return self._t[0] if self._t else None

    def sample(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position, speed, acceleration) arrays at ``times`` [s]."""
        t = np.asarray(self._t)
        idx = np.clip(np.searchsorted(t, times, side="right") - 1, 0, len(t) - 1)
        dt = np.asarray(times) - t[idx]
        s0, v0, a0 = np.asarray(self._s)[idx], np.asarray(self._v)[idx], np.asarray(self._a)[idx]
        return s0 + v0 * dt + 0.5 * a0 * dt * dt, v0 + a0 * dt, a0

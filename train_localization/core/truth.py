"""Ground-truth motion: a speed profile's legs, the trajectory they give, and the truth states.

The data the simulators, the dynamics and the converters share with the scenario
(core/scenario.py), which holds a train's profile and makes its ``Trajectory``: kept apart
from the scenario so that the subsystems whose settings the scenario validates can use it
without importing the scenario.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .vehicle import Vehicle


@dataclass(frozen=True)
class TruthState:
    """True kinematic state of the train front at ``stamp`` [s]."""

    stamp: float
    position: float      # chainage [m]
    speed: float         # [m/s]
    acceleration: float  # [m/s^2]


@dataclass(frozen=True)
class Leg:
    """One leg of a speed profile: target ``speed`` [m/s] (signed), ``accel`` / ``decel``
    [m/s^2] when speeding up / slowing down, ``jerk`` [m/s^3], ``hold`` at the target [s]."""

    speed: float
    accel: float = 0.8
    decel: float = 1.0
    jerk: float = 0.5
    hold: float = 0.0



def _clamp(x: float, limit: float) -> float:
    """x within +-limit, on plain floats (np.clip per step was 97 % of a campaign draw: 150
    draws 3.05 s -> 0.60 s)."""
    return min(max(float(x), -limit), limit)

class Trajectory:
    """Ground-truth motion sampled every ``dt`` [s]: arrays t, position, speed, acceleration.

    ``position`` is the distance run from the track's origin; on a closed track (``period`` its
    length [m]) ``state_at`` gives the chainage wrapped round it."""

    period: float | None = None

    def __init__(self, t, position, speed, acceleration):
        self.t, self.position, self.speed, self.acceleration = t, position, speed, acceleration

    @classmethod
    def from_legs(cls, legs, s0, v0, duration, dt):
        """The legs driven from chainage ``s0`` [m] at speed ``v0`` [m/s] for ``duration`` [s],
        sampled every ``dt`` [s]. The loop runs on plain floats and fills the arrays at the end
        (numpy scalars per step cost 4x: every scenario and campaign draw builds one)."""
        n = int(round(duration / dt)) + 1
        s_k, v_k, acc = float(s0), float(v0), 0.0
        s, v, a = [s_k], [v_k], [acc]
        leg_idx, hold_left, reached = 0, None, False
        for _ in range(1, n):
            if leg_idx < len(legs):
                leg = legs[leg_idx]
                err = leg.speed - v_k
                if not reached:
                    speeding_up = (err > 0) == (v_k >= 0) and abs(v_k) > 1e-9 or abs(v_k) <= 1e-9
                    limit = leg.accel if speeding_up else leg.decel
                    # accelerate with limited jerk; start easing off early enough
                    # that the acceleration is back to ~0 when the target is reached
                    a_target = math.copysign(limit, err)
                    ease = acc * acc / (2.0 * leg.jerk)
                    if abs(err) <= ease + abs(acc) * dt:
                        a_target = 0.0
                    acc += _clamp(a_target - acc, leg.jerk * dt)
                    if abs(err) < 1e-3 or (abs(err) < abs(acc) * dt * 2 and a_target == 0.0):
                        reached, hold_left, acc = True, leg.hold, 0.0
                if reached:
                    acc = _clamp((leg.speed - v_k) / dt, leg.jerk * dt)
                    hold_left -= dt
                    if hold_left <= 0:
                        leg_idx, reached = leg_idx + 1, False
            else:
                acc = _clamp(-acc, 0.5 * dt) + acc
            v_next = v_k + acc * dt
            s_k = s_k + 0.5 * (v_k + v_next) * dt
            v_k = v_next
            s.append(s_k)
            v.append(v_k)
            a.append(acc)
        return cls(np.arange(n) * dt, np.array(s), np.array(v), np.array(a))

    def state_at(self, stamp: float) -> TruthState:
        position = float(np.interp(stamp, self.t, self.position))
        if self.period:
            position %= self.period
        return TruthState(float(stamp), position,
                          float(np.interp(stamp, self.t, self.speed)),
                          float(np.interp(stamp, self.t, self.acceleration)))


class TruthBuffer:
    """Recent ground-truth states; samples the motion at arbitrary times in between.

    Sensor simulators run on ``ground_truth/state`` messages (docs/nodes.md, simulator);
    between two states the acceleration of the earlier one is held, which is exact
    for the piecewise-constant acceleration of the simulator at its state rate.
    """

    def __init__(self, horizon: float = 10.0):
        self.horizon = horizon
        self._t: list[float] = []
        self._s: list[float] = []
        self._v: list[float] = []
        self._a: list[float] = []
        self._arrays: tuple | None = None   # the lists as arrays, until the next add

    def add(self, state: TruthState) -> None:
        """Append a state; states must come in increasing time (others are ignored)."""
        if self._t and state.stamp <= self._t[-1]:
            return
        self._t.append(state.stamp)
        self._s.append(state.position)
        self._v.append(state.speed)
        self._a.append(state.acceleration)
        self._arrays = None
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
        if self._arrays is None:   # a simulator samples many blocks between two states
            self._arrays = tuple(np.asarray(x) for x in (self._t, self._s, self._v, self._a))
        t, s, v, a = self._arrays
        idx = np.clip(np.searchsorted(t, times, side="right") - 1, 0, len(t) - 1)
        dt = np.asarray(times) - t[idx]
        s0, v0, a0 = s[idx], v[idx], a[idx]
        return s0 + v0 * dt + 0.5 * a0 * dt * dt, v0 + a0 * dt, a0


class LineTruth:
    """The ground truth of every train of a line, as a wayside device sees it.

    One TruthBuffer per train (in the scenario's order); ``sample`` gives arrays of shape
    (times, trains). The blocks of a wayside simulator are complete once every train's
    truth covers them (``latest`` is the oldest train's newest stamp).
    """

    def __init__(self, vehicles: dict[str, Vehicle], horizon: float = 10.0):
        self.vehicles = dict(vehicles)
        self.buffers = {name: TruthBuffer(horizon) for name in self.vehicles}

    def add(self, train: str, state: TruthState) -> None:
        self.buffers[train].add(state)

    @property
    def latest(self) -> float | None:
        stamps = [b.latest for b in self.buffers.values()]
        return None if None in stamps else min(stamps)

    @property
    def earliest(self) -> float | None:
        stamps = [b.earliest for b in self.buffers.values()]
        return None if None in stamps else max(stamps)

    def sample(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position, speed, acceleration) arrays of shape (len(times), trains)."""
        cols = [b.sample(times) for b in self.buffers.values()]
        return tuple(np.stack([c[i] for c in cols], axis=1) for i in range(3))

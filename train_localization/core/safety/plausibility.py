"""Kinematic plausibility of a stream of states (docs/reliability.md): a state whose interval or
speed the last admitted one rules out over the elapsed time is refused (``motion``), whatever
its stamp says. This is what stops one spoofed state -- a train 5 km away, a standstill claimed
during a brake -- from replacing the real one in a consumer.

From the last admitted state that claims a position (``Motion`` at t0: the interval [lo, hi] of
the front [m], the speed interval [v_lo, v_hi] [m/s]) the front can reach by t0 + dt at most

    [lo + dt v_lo - a dt^2 / 2,  hi + dt v_hi + a dt^2 / 2]   (and never faster than v_max)

with ``a`` = ``max_acceleration`` [m/s^2] the largest acceleration or deceleration of any
train (emergency brake with a wheel slide, an overshoot of traction), and its speed lies in
[v_lo - a dt, v_hi + a dt]. A new claimed state whose interval (widened by ``margin`` [m]) or
speed interval (widened by ``speed_margin`` [m/s]) is disjoint from these is refused. A state
that claims no position (initialising, lost) carries nothing to compare and passes; it does not
become the reference either. The reachable set grows with the time since the last admitted
state, so a real stream that the gate refused (a fusion reset elsewhere) is taken again once
the physical limits allow it; until then the consumer's stream is stale and it reacts fail-safe.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtri

from ..measurements import MAX_SPEED
from ..sensors.base import Param
from ..signals import InputRejected

PARAMS = {
    "max_acceleration": Param(5.0, "largest acceleration or deceleration of any train the kinematic "
                                   "plausibility allows between two states [m/s^2]", (0.1, 50.0)),
    "plausibility_margin": Param(1.0, "the interval of a state may lie this far outside what the last "
                                      "admitted one allows before it is refused (motion) [m]", (0.0, 1.0e4)),
    "speed_margin": Param(1.0, "likewise for the speed interval [m/s]", (0.0, 100.0)),
}


def speed_bound(confidence: float, speed_stddev: float) -> float:
    """The speed's bound [m/s] at a state's ``confidence``: its two-sided normal quantile times
    ``speed_stddev`` [m/s] (the confidence taken in 0.5 .. 1 - 1e-15; ETCS's v_ura)."""
    conf = min(max(confidence, 0.5), 1.0 - 1e-15)
    return float(ndtri(0.5 * (1.0 + conf))) * speed_stddev


def reach_bounds(lo, hi, v_lo, v_hi, dt, a: float, v_max: float = MAX_SPEED):
    """(lo, hi) [m] the front can reach ``dt`` [s] after it was in [``lo``, ``hi``] [m] with a
    speed in [``v_lo``, ``v_hi``] [m/s]: the speed interval over dt, plus a dt^2 / 2 either way
    (``a`` [m/s^2]), never faster than ``v_max`` [m/s] (the module doc). Floats or numpy arrays."""
    grow = 0.5 * a * dt * dt
    return (np.maximum(lo + dt * v_lo - grow, lo - v_max * dt), np.minimum(hi + dt * v_hi + grow, hi + v_max * dt))


@dataclass(frozen=True)
class Motion:
    """What a state says of the front at ``t`` [s]: ``claimed`` a position in [lo, hi] [m] with a
    speed in [v_lo, v_hi] [m/s] (along increasing chainage)."""
    t: float
    claimed: bool
    lo: float
    hi: float
    v_lo: float
    v_hi: float

    @classmethod
    def of(cls, t: float, claimed: bool, lo: float, hi: float, speed: float, speed_bound: float) -> "Motion":
        """From an interval [lo, hi] [m] and a speed [m/s] +- its bound ``speed_bound`` [m/s]."""
        return cls(t, claimed, min(lo, hi), max(lo, hi), speed - abs(speed_bound), speed + abs(speed_bound))


@dataclass(frozen=True)
class Reach:
    """Where the front can be at ``t`` [s] from the last admitted state: [lo, hi] [m] and speeds
    [v_lo, v_hi] [m/s]."""
    t: float
    lo: float
    hi: float
    v_lo: float
    v_hi: float


class MotionGate:
    """``check(motion)`` raises InputRejected("motion") for a claimed state the last admitted one
    rules out; ``accept(motion)`` makes an admitted claimed state the reference."""

    def __init__(self, max_acceleration: float = PARAMS["max_acceleration"].default,
                 margin: float = PARAMS["plausibility_margin"].default,
                 speed_margin: float = PARAMS["speed_margin"].default, max_speed: float = MAX_SPEED):
        if not (max_acceleration > 0.0 and margin >= 0.0 and speed_margin >= 0.0 and max_speed > 0.0):
            raise ValueError(f"motion gate: max_acceleration {max_acceleration}, margins {margin}, "
                             f"{speed_margin} and max_speed {max_speed} must be positive")
        self.a, self.margin, self.speed_margin, self.v_max = max_acceleration, margin, speed_margin, max_speed
        self.last: Motion | None = None

    @classmethod
    def from_params(cls, params) -> "MotionGate":
        return cls(float(params["max_acceleration"]), float(params["plausibility_margin"]),
                   float(params["speed_margin"]))

    def reach(self, t: float) -> Reach | None:
        """The reachable set at ``t`` [s] from the reference; None without one."""
        m = self.last
        if m is None:
            return None
        dt = max(0.0, t - m.t)
        lo, hi = reach_bounds(m.lo, m.hi, m.v_lo, m.v_hi, dt, self.a, self.v_max)
        return Reach(t, float(lo), float(hi), m.v_lo - self.a * dt, m.v_hi + self.a * dt)

    def check(self, motion: Motion) -> None:
        r = self.reach(motion.t) if motion.claimed else None
        if r is None:
            return
        if motion.hi < r.lo - self.margin or motion.lo > r.hi + self.margin:
            raise InputRejected("motion", f"interval [{motion.lo:.2f}, {motion.hi:.2f}] m at {motion.t:.3f} s "
                                          f"is out of reach of the last admitted state ([{r.lo:.2f}, {r.hi:.2f}] m "
                                          f"after {motion.t - self.last.t:.3f} s)")
        if motion.v_hi < r.v_lo - self.speed_margin or motion.v_lo > r.v_hi + self.speed_margin:
            raise InputRejected("motion", f"speed [{motion.v_lo:.2f}, {motion.v_hi:.2f}] m/s at {motion.t:.3f} s "
                                          f"is out of reach of the last admitted state ([{r.v_lo:.2f}, "
                                          f"{r.v_hi:.2f}] m/s after {motion.t - self.last.t:.3f} s)")

    def accept(self, motion: Motion) -> None:
        if motion.claimed and all(map(math.isfinite, (motion.lo, motion.hi, motion.v_lo, motion.v_hi))):
            self.last = motion

    def reset(self) -> None:
        self.last = None

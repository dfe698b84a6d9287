"""The front's interval carried forward since the LRBG (docs/etcs.md, "Safe front ends").

Two claims of the fusion each bound the true front: a state's interval [position_min,
position_max] at its time, and its speed interval v_est +- v_ura at every time. So the
interval of any state since the LRBG, moved on by the lowest and the highest distance the
speed intervals allow since (their ends integrated over time), still holds the front now. The
carried interval is the intersection of all of these: at each state

    lo = max(position_min, lo_before + integral of (v_est - v_ura) dt)
    hi = min(position_max, hi_before + integral of (v_est + v_ura) dt)

(chainage [m], the speed along increasing chainage, trapezoids between states). It is never
wider than the state's own interval, and narrower where the fused interval widens faster than
the speed interval allows (a hypothesis the fusion covers after it located the train well). It
starts again at each new LRBG, so a miss of either claim lasts at most to the next group. A
state without a position, speed or speed bound starts it again; where the two claims
contradict each other (disjoint) it is the state's own interval again.
"""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class CarriedStep:
    """What the carried interval takes of one fused state: time [s], interval [m], speed and
    its bound [m/s] (chainage direction)."""
    t: float
    position_min: float
    position_max: float
    speed: float
    v_ura: float


class CarriedInterval:
    """``restart`` at an LRBG, ``advance`` with each fused state (in time order); ``lo``, ``hi``
    [m] the carried interval (+-inf before the first state)."""

    def __init__(self):
        self.lo, self.hi = -math.inf, math.inf
        self._last: CarriedStep | None = None

    def restart(self) -> None:
        """Forget the states before (a new LRBG): the next state's interval starts it."""
        self.lo, self.hi = -math.inf, math.inf

    def advance(self, step: CarriedStep) -> tuple[float, float]:
        """The carried interval [m] at ``step``: the one before moved on by the speed interval
        since, intersected with the step's own interval."""
        last = self._last
        usable = math.isfinite(step.speed) and math.isfinite(step.v_ura) and \
            not (math.isnan(step.position_min) or math.isnan(step.position_max))
        self._last = step if usable else None
        if not usable:
            self.restart()
            return self.lo, self.hi
        if last is not None and step.t > last.t:
            dt = step.t - last.t
            self.lo += 0.5 * ((last.speed - last.v_ura) + (step.speed - step.v_ura)) * dt
            self.hi += 0.5 * ((last.speed + last.v_ura) + (step.speed + step.v_ura)) * dt
        lo, hi = max(self.lo, step.position_min), min(self.hi, step.position_max)
        # disjoint: one of the two claims failed; which, it cannot tell: the state's own interval
        self.lo, self.hi = (lo, hi) if lo <= hi else (step.position_min, step.position_max)
        return self.lo, self.hi

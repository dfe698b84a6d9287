"""Odometer monitoring (Baseline 4, SUBSET-026 section 3.6.8, as docs/etcs.md reads it): the
distance the odometer measured between two linked balise groups against their linking
distance.

The odometer here is the fused speed integrated over time (what the location function counts
with between balise groups). Each pair of consecutive LRBGs joined by a link gives an error
e = measured - linked distance [m]: > 0 over-reading, < 0 under-reading. Over the pairs of the
last ``monitoring_distance`` the over-readings and the under-readings are summed apart; the
odometer is impaired when either sum exceeds ``impairment_fixed`` + ``impairment_fraction`` x
the distance those pairs cover. It is restored when the pairs of a whole monitoring distance,
all measured after the impairment, are each within the odometry accuracy (``accuracy_fixed`` +
``accuracy_fraction`` x their distance: SUBSET-041 section 5.3.1.1, 5 m + 5 %).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from ..sensors.base import Param, check_declared

PARAMS = {
    "monitoring_distance": Param(2000.0, "distance over which the odometer errors are accumulated [m]",
                                 (100.0, 100000.0)),
    "impairment_fixed": Param(10.0, "accumulated over- or under-reading beyond which the odometer is impaired: "
                                    "fixed part [m]", (0.0, 1000.0)),
    "impairment_fraction": Param(0.05, "... and part proportional to the distance accumulated over [1]",
                                 (0.0, 1.0)),
    "accuracy_fixed": Param(5.0, "odometry accuracy of one pair of groups, fixed part [m] (SUBSET-041 5.3.1.1: "
                                 "5 m)", (0.0, 1000.0)),
    "accuracy_fraction": Param(0.05, "odometry accuracy, part proportional to the distance [1] (SUBSET-041: 5 %)",
                               (0.0, 1.0)),
}
check_declared(PARAMS, "odometer PARAMS")


@dataclass(frozen=True)
class PairError:
    """One pair of linked LRBGs: linked distance [m], odometer error [m] (> 0 over-reading), time [s]."""
    t: float
    distance: float
    error: float


class OdometerMonitor:
    """Feed each linked pair with ``add``; ``impaired`` says the monitoring's verdict."""

    def __init__(self, params: dict):
        self.params = params
        self.impaired = False
        self._window: deque[PairError] = deque()
        self._good_since_impairment = 0.0     # [m] of consecutive in-accuracy pairs since the impairment
        self.pairs = 0

    def allowance(self, distance: float) -> float:
        """Odometry accuracy over ``distance`` [m]: accuracy_fixed + accuracy_fraction x distance."""
        return self.params["accuracy_fixed"] + self.params["accuracy_fraction"] * abs(distance)

    def add(self, pair: PairError) -> bool | None:
        """Take one pair; returns True when it impairs the odometer, False when it restores it,
        None when the verdict does not change."""
        p = self.params
        self.pairs += 1
        self._window.append(pair)
        while sum(q.distance for q in self._window) - self._window[0].distance >= p["monitoring_distance"]:
            self._window.popleft()
        covered = sum(q.distance for q in self._window)
        over = sum(max(q.error, 0.0) for q in self._window)
        under = sum(max(-q.error, 0.0) for q in self._window)
        limit = p["impairment_fixed"] + p["impairment_fraction"] * covered
        if not self.impaired:
            if max(over, under) > limit:
                self.impaired, self._good_since_impairment = True, 0.0
                return True
            return None
        if abs(pair.error) <= self.allowance(pair.distance):
            self._good_since_impairment += pair.distance
        else:
            self._good_since_impairment = 0.0
        if self._good_since_impairment >= p["monitoring_distance"]:
            self.impaired = False
            self._window.clear()
            return False
        return None

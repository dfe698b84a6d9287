"""The late-data history: measurements of the last ``history`` seconds with the filter state
after each, so that a late measurement is inserted at its stamp and the ones after it
re-applied (lazily, when an estimate is next asked for). Snapshots are immutable tuples
(x, P, bookkeeping) that share their arrays: no copying. Ties are ordered by a key built
from the measurement itself, never by arrival, so the result equals in-order processing.
"""
from __future__ import annotations

import bisect
import math

from ..measurements import MAX_DURATION, Acceleration, DistanceIncrement, PositionFix, SpeedMeasurement, YawRate
from ..signals import InputRejected

# [s] two increments of one unit may share at their ends: their stamps are whole nanoseconds,
# and a stamp of the wall clock (1.8e9 s) resolves 0.24 us in a double
OVERLAP_TOLERANCE = 1.0e-5


def order_key(m) -> tuple:
    """Deterministic total order of measurements: by stamp, then by content."""
    if isinstance(m, PositionFix):
        body = (0, m.position, m.position_stddev)
    elif isinstance(m, SpeedMeasurement):
        body = (1, m.speed, m.speed_stddev)
    elif isinstance(m, YawRate):
        body = (3, m.yaw_rate, m.yaw_rate_stddev)
    elif isinstance(m, Acceleration):
        body = (4, m.acceleration, m.acceleration_stddev)
    else:
        body = (2, m.distance, m.duration)
    return (m.stamp, m.sensor, m.unit_id) + body


class History:
    """Kept measurements (sorted by ``order_key``), the snapshots after the applied ones, and
    the snapshot before the first (``base``)."""

    def __init__(self, span: float, base):
        self.span = span
        self.keys: list[tuple] = []
        self.stamps: list[float] = []
        self.meas: list = []
        self.snaps: list[tuple] = []
        self.n_applied = 0
        self.base = base
        self.base_key: tuple = (-math.inf,)
        # key of a measurement a fault check excluded after the fact -> (key of the one whose
        # check decided it, the disagreement it saw [m/s]) (a rewind before the decision undoes
        # it: it is taken again, or not)
        self.excluded: dict[tuple, tuple] = {}
        self.rollbacks = 0                  # insertions before a measurement stamped later
        # (sensor, unit) -> (ends, starts) [s] of the distance increments taken, by end; kept
        # while a later one may still reach back to them (span + MAX_DURATION)
        self.spans: dict[tuple[str, str], tuple[list[float], list[float]]] = {}

    def insert(self, m) -> None:
        """Insert at its stamp; raises InputRejected ``too_late`` / ``duplicate`` / ``overlap``."""
        key = order_key(m)
        newest = self.stamps[-1] if self.stamps else None
        if newest is not None and m.stamp < newest - self.span:
            raise InputRejected("too_late", f"{m.sensor} measurement {newest - m.stamp:.3f} s late "
                                f"(history {self.span} s)")
        if key <= self.base_key:
            raise InputRejected("too_late", f"{m.sensor} measurement at {m.stamp:.6f} s is before the "
                                "kept history (or the last reset)")
        i = bisect.bisect_left(self.keys, key)
        if i < len(self.keys) and self.keys[i] == key:
            raise InputRejected("duplicate", f"{m.sensor} measurement at {m.stamp:.6f} s seen before")
        if isinstance(m, DistanceIncrement):
            self._take_span(m)
        if i < len(self.keys):
            self.rollbacks += 1
        self.keys.insert(i, key)
        self.stamps.insert(i, m.stamp)
        self.meas.insert(i, m)
        self.rewind(i)

    def _take_span(self, m: DistanceIncrement) -> None:
        """Record the span [stamp - duration, stamp] of a distance increment; raises InputRejected
        ``overlap`` for one whose span overlaps an increment taken from the same unit (an echo or
        a repetition of it: its distance would be counted twice)."""
        ends, starts = self.spans.setdefault((m.sensor, m.unit_id), ([], []))
        start, end = m.stamp - m.duration, m.stamp
        j = bisect.bisect_right(ends, end)
        for k in (j - 1, j):   # the taken spans do not overlap: only the neighbours can
            if 0 <= k < len(ends) and min(end, ends[k]) - max(start, starts[k]) > OVERLAP_TOLERANCE:
                raise InputRejected("overlap", f"{m.sensor} increment {start:.6f} .. {end:.6f} s of unit "
                                               f"{m.unit_id[:64]!r} overlaps the one taken over {starts[k]:.6f} .. "
                                               f"{ends[k]:.6f} s")
        ends.insert(j, end)
        starts.insert(j, start)
        horizon = (self.stamps[-1] if self.stamps else end) - self.span - MAX_DURATION
        if len(ends) > 64 and ends[63] < horizon:   # forgotten in batches, as the measurements
            cut = bisect.bisect_left(ends, horizon)
            del ends[:cut], starts[:cut]

    def rewind(self, i: int) -> int:
        """Forget the states from index i on (they are re-applied), and the exclusions decided
        from there on, with the states they changed. Returns the index re-applied from."""
        if i >= self.n_applied:
            return self.n_applied
        if self.excluded:
            decided = self.keys[i]
            undone = [k for k, (by, _) in self.excluded.items() if by >= decided]
            for k in undone:
                del self.excluded[k]
                i = min(i, bisect.bisect_left(self.keys, k))
        del self.snaps[i:]
        self.n_applied = i
        return i

    def drop_states(self, i: int) -> None:
        """Forget the states from index i on, keeping every exclusion (a fault check re-applying
        the history after its own decision: the decisions before it stand)."""
        if i < self.n_applied:
            del self.snaps[i:]
            self.n_applied = i

    def exclude(self, first: int, last: int, sensor: str, shown: float) -> None:
        """Exclude ``sensor``'s measurements at indices first..last, decided at ``last`` by a
        disagreement of ``shown`` [m/s]."""
        by = self.keys[last], shown
        for k in range(first, last + 1):
            if self.meas[k].sensor == sensor:
                self.excluded[self.keys[k]] = by

    def snapshot_before(self, i: int):
        return self.snaps[i - 1] if i else self.base

    def pending(self) -> int:
        return len(self.meas) - self.n_applied

    def prune(self, batch: int = 64) -> None:
        """Forget the measurements older than ``span``, once ``batch`` of them have aged out."""
        stamps = self.stamps
        if len(stamps) <= batch or stamps[batch - 1] >= stamps[-1] - self.span:
            return
        cut = bisect.bisect_left(stamps, stamps[-1] - self.span)
        cut = min(cut, self.n_applied)
        if cut > 0:
            self.base, self.base_key = self.snaps[cut - 1], self.keys[cut - 1]
            del self.keys[:cut], self.stamps[:cut], self.meas[:cut], self.snaps[:cut]
            self.n_applied -= cut
            if self.excluded:
                self.excluded = {k: by for k, by in self.excluded.items() if k > self.base_key}

    def state_at(self, t: float):
        """Snapshot after every applied measurement stamped <= t (the base before the first)."""
        j = bisect.bisect_right(self.stamps, t) - 1
        return self.snaps[j] if j >= 0 else self.base

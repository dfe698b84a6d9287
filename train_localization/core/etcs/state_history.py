"""The fused states an ETCS location tracker keeps, with the odometer reading at each, found by
time in O(log n).

A balise fix is placed against the states around its stamp, and a read that waits for the
fusion's first claimed position is tried again at every state: scanning the whole history on
each try cost more than the rest of a campaign run's ETCS scoring (a 100 s run: 90 of 175 s).
"""
from __future__ import annotations

from bisect import bisect_left, bisect_right
from typing import Iterator

# stamps within this of a searched window's ends are tested by the caller's own predicate [s]
_EDGE = 1e-6
# a list's forgotten head is cut off once it is this long and half the list
_COMPACT = 1024


class StateHistory:
    """(state, odometer reading [m]) pairs in stamp order (``state.t`` [s]); each state must
    have a ``claimed`` property. ``forget_before(t)`` drops the older ones."""

    def __init__(self):
        self._states: list = []
        self._readings: list[float] = []
        self._times: list[float] = []
        self._head = 0
        self._claimed: list = []            # the claimed states only, in stamp order
        self._claimed_times: list[float] = []
        self._claimed_head = 0

    def __len__(self) -> int:
        return len(self._times) - self._head

    def append(self, state, reading: float) -> None:
        self._states.append(state)
        self._readings.append(reading)
        self._times.append(state.t)
        if state.claimed:
            self._claimed.append(state)
            self._claimed_times.append(state.t)

    def forget_before(self, t: float) -> None:
        """Drop the states stamped before ``t`` [s]."""
        self._head = bisect_left(self._times, t, self._head)
        self._claimed_head = bisect_left(self._claimed_times, t, self._claimed_head)
        if self._head > _COMPACT and 2 * self._head > len(self._times):
            del self._states[:self._head], self._readings[:self._head], self._times[:self._head]
            self._head = 0
        if self._claimed_head > _COMPACT and 2 * self._claimed_head > len(self._claimed_times):
            del self._claimed[:self._claimed_head], self._claimed_times[:self._claimed_head]
            self._claimed_head = 0

    def last(self) -> tuple:
        """The newest (state, reading)."""
        return self._states[-1], self._readings[-1]

    def first_time(self) -> float:
        return self._times[self._head]

    def around(self, t: float) -> tuple[tuple, tuple] | None:
        """The (state, reading) pairs before and after ``t`` [s] (the same pair if one is
        stamped at ``t`` or ``t`` is past the newest); None if the history is empty."""
        n = len(self._times)
        if n == self._head:
            return None
        k = min(bisect_left(self._times, t, self._head), n - 1)
        after = k
        before = max(k - 1, self._head) if self._times[k] > t else k
        return ((self._states[before], self._readings[before]), (self._states[after], self._readings[after]))

    def within(self, t: float, half_width: float) -> Iterator:
        """The states whose stamps lie within ``half_width`` [s] of ``t`` (|s.t - t| <= half_width)."""
        i = bisect_left(self._times, t - half_width - _EDGE, self._head)
        j = bisect_right(self._times, t + half_width + _EDGE, self._head)
        return (s for s in self._states[i:j] if abs(s.t - t) <= half_width)

    def first_claimed_from(self, t: float):
        """The first claimed state stamped at or after ``t`` [s], None if there is none."""
        k = bisect_left(self._claimed_times, t, self._claimed_head)
        return self._claimed[k] if k < len(self._claimed_times) else None

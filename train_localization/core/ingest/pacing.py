"""The pace of a recording replayed into a live graph (an NMEA file, a CAN log).

A record stamped ``t`` in the recording's time is due ``(t - t0) / rate`` seconds of the host's
clock after the first record (``t0``) was taken; ``rate`` 0 replays as fast as the reader goes.
A recording's time that runs back (a UTC day that wraps at midnight, a log of several sessions)
restarts the pace at that record.
"""
from __future__ import annotations


class ReplayPace:
    """When the records of a recording are due on the host's clock (module docstring)."""

    def __init__(self, rate: float):
        if not rate >= 0.0:
            raise ValueError(f"replay rate must be >= 0, not {rate!r}")
        self.rate = rate
        self._anchor: tuple[float, float] | None = None   # (recording time, host time) of the pace's start
        self._last: float | None = None

    def due(self, t: float, now: float) -> float:
        """The host time [s] at which the record stamped ``t`` [s] is due (``now``: the host clock)."""
        if self._anchor is None or (self._last is not None and t < self._last):
            self._anchor = (t, now)
        self._last = t
        if self.rate == 0.0:
            return self._anchor[1]
        return self._anchor[1] + (t - self._anchor[0]) / self.rate

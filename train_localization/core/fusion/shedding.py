"""Load shedding at the fusion's inputs: the state is the product, and it must keep coming at its
rate whatever one input does.

Each input (a topic) has a token bucket: ``max_input_rate`` messages per second on average,
bursts of ``burst`` seconds' worth. A message beyond it is shed before any parsing or filter
work and counted. The fastest device of the product (mm-wave ranging) delivers 200 fixes per
second, so the default of 1000/s sheds nothing a sensor sends, only a flood (a looping
publisher, an attack). Every shed message is lost information the filter never saw; the
counts say how many, per input.
"""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class Bucket:
    """One input's tokens [messages] at wall time ``t`` [s]."""

    tokens: float
    t: float


@dataclass
class InputShedder:
    """Token buckets per input. ``admit(source, now)`` is True for a message to take, False for
    one to shed (counted in ``shed``); ``now``: a monotonic clock [s] (the host's: shedding is
    about the host's work, not the simulated time)."""

    max_rate: float                 # [messages/s] per input
    burst: float = 0.25             # [s] of messages at max_rate that may come at once
    shed: dict[str, int] = field(default_factory=dict)
    _buckets: dict[str, Bucket] = field(default_factory=dict)

    def __post_init__(self):
        if not self.max_rate > 0.0 or not self.burst > 0.0:
            raise ValueError(f"max_rate ({self.max_rate}) and burst ({self.burst}) must be > 0")

    def admit(self, source: str, now: float) -> bool:
        capacity = self.max_rate * self.burst
        bucket = self._buckets.get(source)
        if bucket is None:
            bucket = self._buckets[source] = Bucket(capacity, now)
        bucket.tokens = min(capacity, bucket.tokens + (now - bucket.t) * self.max_rate) if now > bucket.t \
            else bucket.tokens
        bucket.t = max(bucket.t, now)
        if bucket.tokens >= 1.0:
            bucket.tokens -= 1.0
            return True
        self.shed[source] = self.shed.get(source, 0) + 1
        return False

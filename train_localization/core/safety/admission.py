"""Admission of one input stream of a consumer node (docs/reliability.md): the checks that stand
between what arrives on a topic and the safety function behind it, with no rclpy.

EN 50159 (safety-related communication in an open transmission system) names the threats a
consumer has to answer; this is how each is answered here:

=================  ===============================================  ======================
threat             defence                                          reason refused
=================  ===============================================  ======================
repetition         a stamp equal to the last admitted one           ``duplicate``
resequencing       a stamp before the last admitted one             ``stamp_back``
delay              a silence or refusals past ``timeout``: stale    (``stale``, not a refusal)
insertion          a stamp ahead of the consumer's clock            ``future``
                   a motion the last admitted state rules out       ``motion`` (plausibility.py)
corruption         a value that is NaN or infinite                  ``nan``
                   a value beyond the physical limits               ``implausible``
                   an id longer than MAX_ID_LENGTH                  ``too_long``
                   a list longer than the stream's ``max_items``    ``too_large``
masquerade         a source the consumer is not configured for      (the node's: ``other_track``,
                                                                    ``unknown_*``)
deletion           the stream's time-out: stale                     (``stale``)
=================  ===============================================  ======================

Only an admitted message moves the stream on (its stamp becomes the last, its arrival the last
admission), so a refused one can never become the reference that real ones are refused against.
A stream is **stale** when nothing was admitted for ``timeout`` [s] of the consumer's clock:
whatever its last message said, the consumer then reacts as if it had none (its safe reaction).
"""
from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass

from ..sensors.base import Param
from ..signals import MAX_ID_LENGTH, InputRejected

# the limits every consumer declares as parameters (``<name>``; the nodes' docs list them)
PARAMS = {
    "future_tolerance": Param(0.5, "an input stamped further ahead of the node clock than this is refused "
                                   "(future) [s]", (1.0e-3, 3600.0)),
    "input_timeout": Param(1.0, "an input stream with nothing admitted for this long is stale: the node "
                                "reacts as if it had none, whatever its last message said [s]", (0.01, 600.0)),
}
MAX_ITEMS = 256          # default longest list (ids, hypotheses, paths, switch positions) one message may carry


@dataclass(frozen=True)
class StreamLimits:
    """What one stream admits: stamps at most ``future`` [s] ahead of the consumer's clock, a
    silence of ``timeout`` [s] makes it stale, lists of at most ``max_items``; ``ordered``: stamps
    must increase (False for a stream whose messages may come in any order, e.g. events of
    several sources)."""
    future: float = PARAMS["future_tolerance"].default
    timeout: float = PARAMS["input_timeout"].default
    max_items: int = MAX_ITEMS
    ordered: bool = True

    def __post_init__(self):
        if not (self.future > 0.0 and self.timeout > 0.0 and self.max_items >= 1):
            raise ValueError(f"stream limits must be positive: future {self.future}, timeout {self.timeout}, "
                             f"max_items {self.max_items}")


class StreamAdmission:
    """One input stream: ``admit`` (or ``check`` then ``accept``) a message, ``stale(now)`` once
    nothing was admitted for the time-out. ``refused`` counts refusals by reason, ``admitted``
    the messages taken. Times: ``now`` is the consumer's clock [s] (0 or None: it has none yet, so
    nothing is compared with it); ``stamp`` the message's [s]."""

    def __init__(self, name: str, limits: StreamLimits | None = None):
        self.name = name
        self.limits = limits or StreamLimits()
        self.refused: Counter[str] = Counter()
        self.admitted = 0
        self.last_stamp: float | None = None      # of the last admitted message [s]
        self.admitted_at: float | None = None     # the consumer's clock at the last admission [s]
        self.started_at: float | None = None      # the consumer's clock when it began to wait [s]

    # ------------------------------------------------------------------ checks
    def check(self, stamp: float, now: float | None, values: Mapping[str, float] | None = None,
              ids: Mapping[str, str] | None = None, sizes: Mapping[str, int] | None = None,
              limits: Mapping[str, tuple[float, float]] | None = None) -> None:
        """Raises InputRejected (one line, with the reason of the module table) for a message
        stamped ``stamp`` [s] with numbers ``values``, ids ``ids`` and lists of ``sizes`` items;
        ``limits``: the physical range of some of ``values`` (inclusive)."""
        if not math.isfinite(stamp):
            raise InputRejected("nan", f"{self.name}: stamp {stamp!r}")
        for key, value in (values or {}).items():
            if not math.isfinite(value):
                raise InputRejected("nan", f"{self.name}: {key} is {value!r}")
        for key, (lo, hi) in (limits or {}).items():
            value = values[key]
            if not lo <= value <= hi:
                raise InputRejected("implausible", f"{self.name}: {key} {value:g} outside {lo:g} .. {hi:g}")
        for key, text in (ids or {}).items():
            if len(text) > MAX_ID_LENGTH:
                raise InputRejected("too_long", f"{self.name}: {key} of {len(text)} characters (at most "
                                                f"{MAX_ID_LENGTH}): {text[:16]!r}...")
        for key, n in (sizes or {}).items():
            if n > self.limits.max_items:
                raise InputRejected("too_large", f"{self.name}: {key} of {n} items (at most "
                                                 f"{self.limits.max_items})")
        if now and stamp - now > self.limits.future:
            raise InputRejected("future", f"{self.name}: stamped {stamp - now:.3f} s ahead of the node clock "
                                          f"(future_tolerance {self.limits.future:g} s)")
        if self.limits.ordered and self.last_stamp is not None:
            if stamp == self.last_stamp:
                raise InputRejected("duplicate", f"{self.name}: stamp {stamp:.6f} s again")
            if stamp < self.last_stamp:
                raise InputRejected("stamp_back", f"{self.name}: stamp {stamp:.6f} s before the last admitted "
                                                  f"{self.last_stamp:.6f} s")

    def accept(self, stamp: float, now: float | None) -> None:
        """The message stamped ``stamp`` [s] passed every check of the consumer: the stream moves on."""
        self.admitted += 1
        if self.last_stamp is None or stamp > self.last_stamp:
            self.last_stamp = stamp
        self.admitted_at = now if now else stamp    # no clock yet: the stamp stands for it

    def refuse(self, exc: InputRejected) -> InputRejected:
        """Count a refusal (the stream's own or the consumer's further checks); returns it."""
        self.refused[exc.reason] += 1
        return exc

    def admit(self, stamp: float, now: float | None, **checks) -> InputRejected | None:
        """``check`` and, when it passes, ``accept``: None, else the refusal (counted)."""
        try:
            self.check(stamp, now, **checks)
        except InputRejected as exc:
            return self.refuse(exc)
        self.accept(stamp, now)
        return None

    # ------------------------------------------------------------------ time-out
    def waiting_since(self, now: float) -> None:
        """The consumer began to expect this stream at ``now`` [s] (its start, or when the
        stream became required): stale after the time-out if nothing comes."""
        if self.started_at is None:
            self.started_at = now

    def silence(self, now: float) -> float:
        """Time [s] since the last admission (or since ``waiting_since``); inf if neither."""
        ref = self.admitted_at if self.admitted_at is not None else self.started_at
        return math.inf if ref is None else max(0.0, now - ref)

    def stale(self, now: float) -> bool:
        """Nothing admitted for longer than the time-out (refused and silent alike)."""
        return self.silence(now) > self.limits.timeout

    def reset(self) -> None:
        """Forget the stream's order and time (the consumer was reset: a node restarted, a new
        authority); the counts stay."""
        self.last_stamp = self.admitted_at = self.started_at = None


def limits_from(params: Mapping[str, float], max_items: int = MAX_ITEMS, ordered: bool = True) -> StreamLimits:
    """StreamLimits from a node's ``future_tolerance`` and ``input_timeout`` parameters."""
    return StreamLimits(float(params["future_tolerance"]), float(params["input_timeout"]), max_items, ordered)

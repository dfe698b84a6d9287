"""The fusion node's logic: the filter plus its fixed-rate output grid.

The live node (nodes/fusion.py) and the offline runs (core/offline/) both drive a
``FusionRunner``, so they make the same estimates from the same measurement sequence.
"""
from __future__ import annotations

import heapq
import math

from .. import convert
from ..signals import InputRejected
from .admission import Admission
from .filter import Estimate, TrainFilter
from .config import FusionConfig
from .history import order_key

STANDSTILL_SPEED_STDDEV = 0.01   # [m/s] of a train known to stand at its start position


class FusionRunner:
    """TrainFilter plus the fixed-rate output grid (k / rate seconds).

    ``add`` feeds a measurement through the admission checks (admission.py; refusals are
    counted by reason in ``rejected``, the last one kept in ``last_error``),
    ``advance(t)`` returns the estimates of every grid time <= t not yet produced,
    each with the sensor classes used since the previous one. The runner's clock, against
    which a measurement from the future is refused, is the latest ``t`` advanced to or the
    ``now`` given to ``add`` (the live node's clock).
    A configured ``initial_position`` puts the train there, at rest, at the time of the first
    measurement or output, whichever comes first.

    A clock that jumps back (one /clock message far ahead and then the real one again, a bag
    played in a loop) moves the grid back with it: the outputs go on at the clock's time, and
    where the clock is now before the filter's measurements (the loop's start) the filter
    starts afresh, as robot_localization's ``reset_on_time_jump`` does; counted in
    ``counters()["clock"]``. A jump forward is only time passing: the states predicted to it.

    ``hold``: inputs wait in a reorder buffer up to ``latency`` [s], the largest latency the
    configured sensors declare (core/sensors/base.py ErrorModel ``latency``), and enter the filter
    in stamp order, so that an input late by no more than that rewinds nothing. The estimate of
    grid time T is made once the clock has reached T + ``latency`` (or by ``drain``), from
    exactly the inputs stamped <= T: the published states lag by ``latency`` and are those of
    the same inputs arriving at their stamps. An input stamped before what was already released
    goes into the filter at once (its history rewinds) and is counted in
    ``counters()["rollbacks"]["late_beyond_latency"]``; a refusal of the history (duplicate,
    too_late, overlap, not_used) is counted when the input is released, after ``add`` returned True.
    """

    def __init__(self, config: FusionConfig, rate: float = 200.0, train_filter=None, hold: bool = False):
        # ``train_filter``: another filter with TrainFilter's interface (on a network, the track
        # hypotheses of core/network/hypotheses.py); by default a TrainFilter of ``config``
        self.filter = train_filter if train_filter is not None else TrainFilter(config)
        self.hold = hold
        self.latency = max((m.latency for m in self.filter.cfg.models.values() if math.isfinite(m.latency)),
                           default=0.0)   # [s]
        self._held: list[tuple] = []          # (order_key, arrival number, measurement), a heap
        self._arrivals = 0
        self._released = -math.inf            # [s] every held input stamped <= this has entered the filter
        self._first_advance: float | None = None   # [s] the first advance's time (a pending start's latest)
        self.beyond_latency = 0               # inputs stamped before what had been released
        self.admission = Admission(self.filter.cfg)
        self.clock: float | None = None   # [s]
        self.period = 1.0 / rate
        self._next_k: int | None = None
        self._used: set[str] = set()
        self.rejected: dict[str, int] = {}
        self.last_error: InputRejected | None = None   # why the last rejected measurement was
        self._start_pending = math.isfinite(config.initial_position)
        self._last_clock: float | None = None   # the caller's clock when last seen [s]
        self.clock_jumps = {"back": 0, "filter_reset": 0}

    def _start(self, t: float) -> None:
        """The known start position (``initial_position``), at rest, at ``t`` [s]."""
        self._start_pending = False
        cfg = self.filter.cfg
        self.filter.reset(position=cfg.initial_position, position_stddev=cfg.initial_position_stddev, speed=0.0,
                          speed_stddev=STANDSTILL_SPEED_STDDEV, stamp=t)

    def add(self, m, now: float | None = None) -> bool:
        """Take measurement ``m`` (True) or refuse and count it (False). ``now`` [s]: the
        caller's clock, if it has one (the live node)."""
        if now is not None:
            self._follow_clock(now)
        try:
            self.admission.check(m, self.clock)
        except InputRejected as exc:
            return self._refused(exc)
        if self.hold:
            if m.stamp > self._released:
                heapq.heappush(self._held, (order_key(m), self._arrivals, m))
                self._arrivals += 1
                return True
            self.beyond_latency += 1
        return self._take(m)

    def _refused(self, exc: InputRejected) -> bool:
        """Count a refused measurement (False)."""
        self.rejected[exc.reason] = self.rejected.get(exc.reason, 0) + 1
        self.last_error = exc
        return False

    def _take(self, m) -> bool:
        """An input enters the filter (a pending start at its stamp, or at the first advance's time
        if that is earlier: holding); False if the history refuses it (counted)."""
        if self._start_pending:
            self._start(m.stamp if self._first_advance is None else min(m.stamp, self._first_advance))
        try:
            self.filter.add(m)
        except InputRejected as exc:
            return self._refused(exc)
        self._used.add(m.sensor)
        return True

    def _release(self, t: float) -> None:
        """Every held input stamped <= t [s] enters the filter, in the filter's order."""
        held = self._held
        while held and held[0][2].stamp <= t:
            self._take(heapq.heappop(held)[2])
        self._released = max(self._released, t)

    def set_rate(self, rate: float) -> None:
        """Change the output rate [Hz]: the grid continues from the next grid time not produced."""
        if self._next_k is not None:
            t_next = self._next_k * self.period
            self._next_k = math.ceil(t_next * rate - 1e-9)
        self.period = 1.0 / rate

    def due(self, t: float) -> bool:
        """Whether ``advance(t)`` would produce an estimate (a grid time <= t not produced yet;
        holding, <= t - ``latency``)."""
        if self._next_k is None:
            return True
        if self.hold:
            t = min(t, max(t, self.clock if self.clock is not None else t) - self.latency)
        return math.floor(t / self.period + 1e-9) >= self._next_k

    def _clock_at(self, t: float) -> None:
        """The runner's clock moves on to ``t`` [s] (never back; a non-finite t is no time)."""
        if math.isfinite(t):
            self.clock = t if self.clock is None else max(self.clock, t)

    def counters(self) -> dict[str, dict]:
        """The filter's counters, with every refused measurement by reason (admission's and the
        history's), and the clock's jumps back."""
        out = {**self.filter.counters(), "rejected": dict(self.rejected), "clock": dict(self.clock_jumps)}
        if self.hold:
            out["rollbacks"] = {**out.get("rollbacks", {}), "late_beyond_latency": self.beyond_latency}
        return out

    def _clock_jumped_back(self, t: float) -> None:
        """The clock is at ``t`` [s], before the last output: the grid and the clock follow it; a
        filter whose measurements all lie after t - ``history`` (a loop) starts afresh."""
        self.clock_jumps["back"] += 1
        self._next_k = None
        self.clock = t
        stamps = self.filter.hist.stamps
        if stamps and t < stamps[-1] - self.filter.cfg.history:
            self.clock_jumps["filter_reset"] += 1
            self.filter.reset()
            self._start_pending = math.isfinite(self.filter.cfg.initial_position)
            self._held.clear()   # inputs of the time before the jump
            self._released, self._first_advance = -math.inf, None

    def _follow_clock(self, t: float) -> None:
        """The caller's clock is at ``t`` [s]: a jump back by more than one output period is
        followed (``_clock_jumped_back``), else the runner's clock moves on."""
        if self._last_clock is not None and t < self._last_clock - self.period:
            self._clock_jumped_back(t)
        if math.isfinite(t):
            self._last_clock = t
        self._clock_at(t)

    def advance(self, t: float, max_catch_up: int = 1000) -> list[tuple[Estimate, list[str]]]:
        """The estimates of every grid time <= t [s] not produced yet (at most ``max_catch_up``
        behind t), each with the sensor classes used since the previous one."""
        self._follow_clock(t)
        if self.hold:
            return self._held_outputs(t, self.clock - self.latency, max_catch_up)
        if self._start_pending:
            self._start(t)
        k_now = math.floor(t / self.period + 1e-9)
        if self._next_k is None or k_now - self._next_k > max_catch_up:
            self._next_k = k_now
        out = []
        while self._next_k <= k_now:
            out.append(self._output(convert.canonical(self._next_k * self.period)))
            self._next_k += 1
        return out

    def drain(self, t: float) -> list[tuple[Estimate, list[str]]]:
        """``advance(t)`` at the end of the input: every held input stamped <= t [s] enters the
        filter and the estimates of every grid time <= t are made, without waiting for ``latency``."""
        if not self.hold:
            return self.advance(t)
        self._follow_clock(t)
        return self._held_outputs(t, t, 1000)

    def _output(self, t: float) -> tuple[Estimate, list[str]]:
        """The estimate of grid time t [s] and the sensor classes used since the previous one."""
        out = self.filter.estimate(t), sorted(self._used)
        self._used.clear()
        return out

    def _held_outputs(self, t: float, horizon: float, max_catch_up: int) -> list[tuple[Estimate, list[str]]]:
        """``advance(t)`` holding: the grid times from the first advance's on, each made once every
        input stamped up to it has entered the filter, up to ``horizon`` [s] (every input stamped
        <= horizon is in by the sensors' declared latencies)."""
        if self._first_advance is None:
            self._first_advance = t
        k_now = math.floor(t / self.period + 1e-9)
        if self._next_k is None:
            self._next_k = k_now   # the grid starts at the first advance, as without holding
        k_out = min(k_now, math.floor(horizon / self.period + 1e-9))
        if k_out - self._next_k > max_catch_up:
            self._next_k = k_out
        out = []
        while self._next_k <= k_out:
            grid = convert.canonical(self._next_k * self.period)
            self._release(grid + 1e-9)
            if self._start_pending:
                self._start(self._first_advance)
            out.append(self._output(grid))
            self._next_k += 1
        self._release(min(horizon, convert.canonical(self._next_k * self.period)))
        return out


def estimate_to_msg(mc, est: Estimate, track_id: str, sensors, track=None):
    """The TrainState message of an estimate. On a closed ``track`` (core/track.py Track) the
    position is published as the truth is, wrapped into [0, circumference) by ``Track.wrap``,
    and the interval moves with it: position_min <= position <= position_max still holds, so
    near the seam an end may lie below 0 or beyond the circumference (msg_defs TrainState.msg).
    The filter itself runs on the unwrapped distance. An estimate on a network (a
    core/network NetworkEstimate) names its own track and that track's probability, and gives
    its interval as path distances too (``path_min`` / ``path_max``)."""
    track_id = getattr(est, "track_id", None) or track_id
    position, lo, hi = est.position, est.position_min, est.position_max
    if track is not None and track.closed and math.isfinite(position):
        laps = position - float(track.wrap(position))
        position, lo, hi = position - laps, lo - laps, hi - laps
    direction = getattr(est, "path_direction", 0)
    path = (est.path_position, est.path_min, est.path_max, direction) if direction else None
    return convert.train_state_to_msg(mc, est.stamp, track_id, position, est.speed, est.acceleration,
                                      est.position_stddev, est.speed_stddev, lo, hi, est.confidence, est.mode,
                                      sensors, getattr(est, "track_probability", 1.0), path=path)

"""Which train a wayside position fix belongs to, on a line with several trains.

A wayside decoder (axle-counter head passage, track-circuit boundary, INPO section) sees
every train of its track and publishes fixes that do not say which train caused them.
``Associator`` offers each fix to every train whose fused state at the fix's stamp
explains it:

  * same track;
  * direction: a fix with a direction (+1/-1) is not explained by a train whose fused
    speed is known to run the other way (|v| > ``gate`` x its 1-sigma and > ``min_speed``);
  * position: the fix lies in the train's fused interval [position_min, position_max] at
    the stamp (the union of the two published states around it; beyond the last one,
    moved on by the fused speed and widened by ``gate`` x its 1-sigma x the time),
    widened by ``gate`` x the fix's own 1-sigma.

A train that claims no position yet (INITIALISING) is ruled out only by its direction;
before its first fused state it explains every fix of its track, and so it does after its
last one while its state stream is stale (``stale``: nothing admitted for the node's
``input_timeout``): it may be anywhere now, so a fix it might have caused is ambiguous rather
than given to another train. Exactly one train explaining the fix:
the fix goes to that train's fusion. None (``unexplained``) or several (``ambiguous``):
the fix is used by no train, and counted. Section occupancy stays at line level.

On a network (``network``, docs/network.md) a fix names the section of its equipment, in
that section's chainage, and a train's fused state is a set of track hypotheses (core/network
NetworkEstimate ``hypotheses``): the train explains the fix if one of its hypotheses does, the
same tests on that hypothesis's path (the fix's place restated on the hypothesis's axis, the
path continued by one section where the fix lies just beyond its interval's sections). A
train on a track none of its hypotheses runs along does not explain it, whatever the
chainages.

What the node admits of each train (``TrainInputs``, docs/reliability.md): its fused states
through core/safety/fused_state.py (stamps, values, sizes and the kinematic plausibility: a state
out of reach of the train's last admitted one is refused ``motion``), and on a network its
track hypotheses: stamps as a stream of their own, at most MAX_HYPOTHESES hypotheses, a path
of at most the network's section count and MAX_PATH_SECTIONS, MAX_PATH_ENTRIES sections in one
message (``too_large``), sections and network of this network (``unknown_id``). What it keeps:
states for ``history`` and at most MAX_STATES; hypotheses on them at most TRACK_BUDGET (the
oldest states' hypotheses are dropped first: such a state claims no track, as one before the
first kept), and at most MAX_PENDING messages whose state has not come.
"""
from __future__ import annotations

import bisect
import dataclasses
import math
from collections import Counter, deque
from dataclasses import dataclass, field

from .convert import stamp_to_sec
from .fusion import MODE_INITIALISING
from .measurements import PositionFix
from .network.config import MAX_HYPOTHESES
from .network.hypotheses import TrackHypothesisState
from .network.path import TrackPath
from .safety import admission
from .safety.admission import StreamAdmission
from .signals import InputRejected
from .safety.fused_state import FusedStateStream, stream_params

USED, AMBIGUOUS, UNEXPLAINED = "used", "ambiguous", "unexplained"
# A hypothesis's path lists the sections its interval spans: 1 to 3 on a claimed state, every
# section of the path grown so far on one whose interval is unbounded. 64 sections are 1.9 km of
# the shortest ones a network has (a crossover's 30 m), beyond any interval the fusion claims; a
# path that lists more than the network's sections runs a loop twice. The fusion's default of 16
# hypotheses with such paths is MAX_PATH_ENTRIES.
MAX_PATH_SECTIONS = 64
MAX_PATH_ENTRIES = 1024      # sections all hypotheses of one TrackHypotheses message list together
TRACK_BUDGET = 16384         # hypotheses kept per train (1,024 messages of 16; 4.6 MB, docs/nodes.md)
MAX_PENDING = 16             # hypotheses messages kept per train whose state has not come yet
MAX_STATES = 4096            # fused states kept per train (twice the 10 s history at 200 Hz)
MAX_PATH_CACHE = 4096        # paths the associator keeps built


@dataclass(frozen=True)
class FusedState:
    """What the association reads of a published fused state (a core.fusion Estimate has the
    same fields): stamp [s], position, interval [m], speed and its 1-sigma [m/s], mode."""

    stamp: float
    position: float
    position_min: float
    position_max: float
    speed: float
    speed_stddev: float
    mode: int
    hypotheses: tuple | None = ()   # on a network: its core/network TrackHypothesisState, most probable
    #                                 first; None: dropped, older than what the node keeps
    track_id: str = ""
    confidence: float = 0.999

    @classmethod
    def from_msg(cls, msg) -> "FusedState":
        """A TrainState message's numbers (no hypotheses)."""
        return cls(stamp_to_sec(msg.header.stamp), float(msg.position), float(msg.position_min),
                   float(msg.position_max), float(msg.speed), float(msg.speed_stddev), int(msg.mode), (),
                   msg.track_id, float(msg.confidence))


@dataclass(frozen=True)
class Decision:
    """One wayside fix and the trains that explained it (``train``: the one it went to, or None)."""

    fix: PositionFix
    candidates: tuple[str, ...]
    train: str | None

    @property
    def outcome(self) -> str:
        return USED if self.train else AMBIGUOUS if self.candidates else UNEXPLAINED


@dataclass
class Associator:
    """Associates wayside fixes with trains from their published fused states.

    ``estimates``: train name -> the list of that train's fused states (core.fusion
    Estimate or FusedState), in stamp order, appended as they are made (the associator reads them, it
    does not copy them); ``track_ids``: train name -> the track it runs on (on a network: its
    route line, not used); ``network``: the core/network Network the trains run on, or None.
    """

    estimates: dict[str, list]
    track_ids: dict[str, str]
    gate: float = 3.29          # [sigma]: 99.9 % two-sided, as the fused interval's confidence
    min_speed: float = 0.5      # [m/s] below which a fused speed gives no direction
    network: object = None
    counts: Counter = field(default_factory=Counter)       # outcome -> fixes
    by_sensor: Counter = field(default_factory=Counter)    # (sensor, outcome) -> fixes
    delivered: Counter = field(default_factory=Counter)    # train -> fixes used
    decisions: list = field(default_factory=list)          # Decision of every fix offered

    def __post_init__(self):
        self._paths: dict[tuple[str, ...], TrackPath | None] = {}   # a hypothesis's sections -> its path

    @classmethod
    def for_trains(cls, estimates: dict[str, list], track_ids: dict[str, str], overrides: dict | None = None,
                   network=None):
        """An associator with a scenario's ``association:`` overrides (gate, min_speed)."""
        values = dict(overrides or {})
        unknown = set(values) - {"gate", "min_speed"}
        if unknown:
            raise ValueError(f"unknown association setting(s) {sorted(unknown)}; known: gate, min_speed")
        return cls(estimates, track_ids, **{k: float(v) for k, v in values.items()}, network=network)

    def explains(self, train: str, fix: PositionFix, stale: bool = False) -> bool:
        """Whether the train's fused state at the fix's stamp explains the fix (module doc);
        ``stale``: the train's state stream is."""
        if self.network is not None:
            return self._explains_on_network(train, fix, stale)
        if self.track_ids[train] != fix.track_id:
            return False
        state = self.state(train, fix.stamp, stale)
        if state is None:
            return True
        lo, hi, v, sd_v = state
        if fix.direction and abs(v) > max(self.gate * sd_v, self.min_speed) and (v > 0) != (fix.direction > 0):
            return False
        margin = self.gate * fix.position_stddev
        return lo - margin <= fix.position <= hi + margin

    def state(self, train: str, t: float, stale: bool = False) -> tuple[float, float, float, float] | None:
        """(position_min, position_max, speed, speed 1-sigma) of the train at t [s, m, m/s]; the
        interval is (-inf, inf) where it claims no position, and after its last state when
        ``stale``; None before its first state."""
        est = self.estimates[train]
        k = bisect.bisect_right(est, t, key=lambda e: e.stamp)
        if k == 0:
            return None
        if stale and k == len(est) and t > est[-1].stamp:
            return -math.inf, math.inf, 0.0, math.inf
        near = est[k - 1:k + 1]
        before = near[0]
        v, sd_v = before.speed, max(e.speed_stddev for e in near)
        if not all(math.isfinite(x) for x in (v, sd_v)):
            v, sd_v = 0.0, math.inf
        if any(e.mode == MODE_INITIALISING or not math.isfinite(e.position) for e in near):
            return -math.inf, math.inf, v, sd_v
        if len(near) == 2:
            return min(e.position_min for e in near), max(e.position_max for e in near), v, sd_v
        dt = t - before.stamp
        reach = self.gate * before.speed_stddev * dt
        return (before.position_min + before.speed * dt - reach, before.position_max + before.speed * dt + reach,
                v, sd_v)

    def _explains_on_network(self, train: str, fix: PositionFix, stale: bool = False) -> bool:
        """``explains`` on a network: one of the train's hypotheses, in the fused states around
        the fix's stamp (beyond the last one: moved on by its speed, or anywhere if ``stale``),
        explains the fix."""
        if fix.track_id not in self.network.sections:
            return False
        est = self.estimates[train]
        k = bisect.bisect_right(est, fix.stamp, key=lambda e: e.stamp)
        if k == 0 or (stale and k == len(est) and fix.stamp > est[-1].stamp):
            return True
        near = est[k - 1:k + 1]
        if any(e.mode == MODE_INITIALISING or not math.isfinite(e.position) or not e.hypotheses for e in near):
            return True     # no track claimed (yet): nothing rules the train out
        sd_v = max(e.speed_stddev for e in near)
        dt = fix.stamp - near[0].stamp if len(near) == 1 else 0.0
        margin = self.gate * fix.position_stddev + self.gate * sd_v * dt
        for e in near:
            for h in e.hypotheses:
                placed = self._on_axis(h, fix)
                if placed is None:
                    continue
                position, turn = placed
                v = h.speed * turn
                if fix.direction and abs(v) > max(self.gate * sd_v, self.min_speed) and (v > 0) != (fix.direction > 0):
                    continue
                if h.position_min + h.speed * dt - margin <= position <= h.position_max + h.speed * dt + margin:
                    return True
        return False

    def _on_axis(self, h, fix: PositionFix) -> tuple[float, int] | None:
        """(the fix's place on hypothesis h's axis [m], +1/-1: the fix's section chainage runs
        along/against it), None where h's path does not reach the fix's section."""
        key = tuple(h.path)
        if key not in self._paths:
            if len(self._paths) >= MAX_PATH_CACHE:
                self._paths.clear()
            self._paths[key] = TrackPath.through(self.network, key) if key else None
        path = self._paths[key]
        path = path.reaching(fix.track_id) if path is not None else None
        axis = path.step_on(h.track_id) if path is not None else None
        if axis is None:
            return None     # no path through those sections, or one without the hypothesis's own
        there = path.step_on(fix.track_id)
        return axis.chainage(there.distance(fix.position)), axis.direction * there.direction

    def associate(self, fix: PositionFix, stale: frozenset | set = frozenset()) -> str | None:
        """The train the fix goes to, or None (unexplained or ambiguous); counted either way.
        ``stale``: the trains whose state stream is stale (module doc)."""
        candidates = tuple(name for name in self.estimates if self.explains(name, fix, name in stale))
        train = candidates[0] if len(candidates) == 1 else None
        decision = Decision(fix, candidates, train)
        self.decisions.append(decision)
        self.counts[decision.outcome] += 1
        self.by_sensor[fix.sensor, decision.outcome] += 1
        if train:
            self.delivered[train] += 1
        return train

    def summary(self) -> dict:
        """Counts by outcome, by sensor and outcome, and fixes used per train."""
        return {"offered": sum(self.counts.values()), **{k: self.counts.get(k, 0) for k in (USED, AMBIGUOUS, UNEXPLAINED)},
                "by_sensor": {f"{s}/{o}": n for (s, o), n in sorted(self.by_sensor.items())},
                "delivered": dict(sorted(self.delivered.items()))}


class TrainInputs:
    """What the association node admits and keeps of one train (module doc): ``state(s, now,
    sizes)`` a FusedState, ``tracks(stamp, network_id, hypotheses, now)`` a TrackHypotheses
    message's (anything with a TrackHypothesis's fields); each returns None (admitted) or the
    refusal, counted in ``refused()``. ``states``: the admitted states, in stamp order, with
    their hypotheses joined by stamp (the list an Associator reads; changed in place).
    ``params``: core/safety/fused_state.py PARAMS; ``history`` [s]: states kept."""

    def __init__(self, name: str, params: dict | None = None, history: float = 10.0, network=None,
                 circumference: float | None = None):
        p = stream_params(params)
        self.history, self.network = history, network
        self.states: list[FusedState] = []
        self.state_stream = FusedStateStream(f"/{name}/localization/state", p, network, circumference)
        self.track_stream = StreamAdmission(f"/{name}/localization/tracks", admission.limits_from(p, MAX_HYPOTHESES))
        self.max_path = min(len(network.sections), MAX_PATH_SECTIONS) if network is not None else MAX_PATH_SECTIONS
        self._ids = {sid: sid for sid in network.sections} if network is not None else {}  # the network's own strings
        self.pending: dict[float, tuple] = {}        # stamp -> hypotheses whose state has not come
        self._carrying: deque[tuple[float, int]] = deque()   # (stamp, hypotheses) of kept states with some
        self.kept = 0                                # hypotheses on the kept states

    def refused(self) -> dict[str, Counter]:
        return {"state": self.state_stream.stream.refused, "tracks": self.track_stream.refused}

    def stale(self, now: float | None) -> bool:
        return self.state_stream.stale(now)

    def state(self, s: FusedState, now: float | None, sizes: dict[str, int] | None = None) -> InputRejected | None:
        refusal = self.state_stream.admit(s, now, sizes)
        if refusal is not None:
            return refusal
        hyps = self.pending.pop(s.stamp, ())
        self.states.append(dataclasses.replace(s, hypotheses=hyps))
        for stamp in [t for t in self.pending if t < s.stamp]:   # their state can no longer come
            del self.pending[stamp]
        if hyps:
            self._carry(s.stamp, len(hyps))
        self._prune()
        return None

    def tracks(self, stamp: float, network_id: str, hypotheses, now: float | None) -> InputRejected | None:
        clock = now if now and now > 0.0 else None
        try:
            self.track_stream.check(stamp, clock, ids={"network_id": network_id}, sizes={"hypotheses": len(hypotheses)})
            lengths = [len(h.path) for h in hypotheses]
            if max(lengths, default=0) > self.max_path or sum(lengths) > MAX_PATH_ENTRIES:
                raise InputRejected("too_large", f"paths of up to {max(lengths)} sections, {sum(lengths)} in all (at "
                                                 f"most {self.max_path} and {MAX_PATH_ENTRIES})")
            if self.network is None or network_id != self.network.network_id:
                raise InputRejected("unknown_id", f"network {network_id[:64]!r}, this is "
                                                  f"{getattr(self.network, 'network_id', None)!r}")
            unknown = next((sid for h in hypotheses for sid in (h.track_id, *h.path) if sid not in self._ids), None)
            if unknown is not None:
                raise InputRejected("unknown_id", f"section {unknown[:64]!r} is not in network {network_id}")
        except InputRejected as exc:
            return self.track_stream.refuse(exc)
        self.track_stream.accept(stamp, clock)
        ids = self._ids
        self._join(stamp, tuple(TrackHypothesisState(ids[h.track_id], float(h.position), float(h.speed),
                                                     float(h.position_min), float(h.position_max),
                                                     float(h.probability), tuple(ids[sid] for sid in h.path), 0)
                                for h in hypotheses))
        return None

    def _join(self, stamp: float, hyps: tuple) -> None:
        """The hypotheses to the state of their stamp, or pending until it comes."""
        states = self.states
        k = bisect.bisect_left(states, stamp, key=lambda e: e.stamp)
        if k < len(states) and states[k].stamp == stamp:
            if states[k].hypotheses is not None:     # None: already older than what is kept
                states[k] = dataclasses.replace(states[k], hypotheses=hyps)
                self._carry(stamp, len(hyps))
        elif k == len(states):                       # its state may still come
            self.pending[stamp] = hyps
            while len(self.pending) > MAX_PENDING:
                del self.pending[min(self.pending)]

    def _carry(self, stamp: float, n: int) -> None:
        """A kept state at ``stamp`` now carries ``n`` hypotheses: beyond TRACK_BUDGET the
        oldest states' are dropped."""
        bisect.insort(self._carrying, (stamp, n))
        self.kept += n
        while self.kept > TRACK_BUDGET:
            self._drop(*self._carrying.popleft())

    def _drop(self, stamp: float, n: int) -> None:
        self.kept -= n
        k = bisect.bisect_left(self.states, stamp, key=lambda e: e.stamp)
        if k < len(self.states) and self.states[k].stamp == stamp:
            self.states[k] = dataclasses.replace(self.states[k], hypotheses=None)

    def _prune(self) -> None:
        states = self.states
        cut = max(0, len(states) - MAX_STATES)
        if states[-1].stamp - states[0].stamp > 2 * self.history:
            cut = max(cut, bisect.bisect_left(states, states[-1].stamp - self.history, key=lambda e: e.stamp))
        if cut:
            del states[:cut]
            while self._carrying and self._carrying[0][0] < states[0].stamp:
                self.kept -= self._carrying.popleft()[1]

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
before its first fused state it explains every fix of its track. Exactly one train explaining the fix:
the fix goes to that train's fusion. None (``unexplained``) or several (``ambiguous``):
the fix is used by no train, and counted. Section occupancy stays at line level.

On a network (``network``, docs/network.md) a fix names the section of its equipment, in
that section's chainage, and a train's fused state is a set of track hypotheses (core/network
NetworkEstimate ``hypotheses``): the train explains the fix if one of its hypotheses does, the
same tests on that hypothesis's path (the fix's place restated on the hypothesis's axis, the
path continued by one section where the fix lies just beyond its interval's sections). A
train on a track none of its hypotheses runs along does not explain it, whatever the
chainages.
"""
from __future__ import annotations

import bisect
import math
from collections import Counter
from dataclasses import dataclass, field

from .fusion import MODE_INITIALISING
from .measurements import PositionFix
from .network.path import TrackPath

USED, AMBIGUOUS, UNEXPLAINED = "used", "ambiguous", "unexplained"


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
    hypotheses: tuple = ()   # on a network: its core/network TrackHypothesisState, most probable first


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

    def explains(self, train: str, fix: PositionFix) -> bool:
        """Whether the train's fused state at the fix's stamp explains the fix (module doc)."""
        if self.network is not None:
            return self._explains_on_network(train, fix)
        if self.track_ids[train] != fix.track_id:
            return False
        state = self.state(train, fix.stamp)
        if state is None:
            return True
        lo, hi, v, sd_v = state
        if fix.direction and abs(v) > max(self.gate * sd_v, self.min_speed) and (v > 0) != (fix.direction > 0):
            return False
        margin = self.gate * fix.position_stddev
        return lo - margin <= fix.position <= hi + margin

    def state(self, train: str, t: float) -> tuple[float, float, float, float] | None:
        """(position_min, position_max, speed, speed 1-sigma) of the train at t [s, m, m/s]; the
        interval is (-inf, inf) where it claims no position; None before its first state."""
        est = self.estimates[train]
        k = bisect.bisect_right(est, t, key=lambda e: e.stamp)
        if k == 0:
            return None
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

    def _explains_on_network(self, train: str, fix: PositionFix) -> bool:
        """``explains`` on a network: one of the train's hypotheses, in the fused states around
        the fix's stamp (beyond the last one: moved on by its speed), explains the fix."""
        if fix.track_id not in self.network.sections:
            return False
        est = self.estimates[train]
        k = bisect.bisect_right(est, fix.stamp, key=lambda e: e.stamp)
        if k == 0:
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
            self._paths[key] = TrackPath.through(self.network, key) if key else None
        path = self._paths[key]
        path = path.reaching(fix.track_id) if path is not None else None
        axis = path.step_on(h.track_id) if path is not None else None
        if axis is None:
            return None     # no path through those sections, or one without the hypothesis's own
        there = path.step_on(fix.track_id)
        return axis.chainage(there.distance(fix.position)), axis.direction * there.direction

    def associate(self, fix: PositionFix) -> str | None:
        """The train the fix goes to, or None (unexplained or ambiguous); counted either way."""
        candidates = tuple(name for name in self.estimates if self.explains(name, fix))
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

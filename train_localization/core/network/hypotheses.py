"""Track-selective fusion: one hypothesis per feasible path through the switches passed
(docs/network.md).

Fault hypothesis covered. The along-track filter (core/fusion, TrainFilter) covers the
train's place on the path it runs on; which path that is, is the new unknown. The train
may have taken either way at every facing switch its interval has reached, whatever the
interlocking reports (its report may be wrong: a detection fault). So every such way is
a hypothesis, each with a TrainFilter of its own in the path distance of its path, and
the published interval covers every hypothesis that is still plausible: while more than
one track is, the state is DEGRADED, never NOMINAL on a track that is not proven.

This is a multiple-hypothesis filter whose branches are pruned by evidence (the DLR
track-selective filter of Heirich, 2016, keeps the topological hypothesis in particles;
with a handful of switches in reach, exact enumeration is cheaper and has no sampling
loss). Evidence, and what it is allowed to do:

  ranking (probability)  the interlocking's reported way (prior 1 - wrong_switch_probability),
                         the lateral offset of every 2-D fix from each path (a Gaussian of
                         the fix's lateral 1-sigma with an outlier share), a gyro's turn rate
                         against each path's curvature times the speed (a turnout's curve
                         against the straight way, in a tunnel too), a reference fix that a
                         path does not contain (misread_probability);
  inconsistency          a fix that no hypothesis's path explains (a balise on a section none
                         contains, a 2-D fix off every path) holds the state DEGRADED for
                         exclusion_window: the set may have lost the train's track.
  exclusion              only evidence that holds under the sensors' fault modes: references
                         on another path from exclusion_references distinct references (one
                         may be misread), or map_exclusion_fixes consecutive 2-D fixes
                         further than map_lateral_gate sigma from the path while on another
                         one (a non-line-of-sight outlier is one fix). The interlocking never
                         excludes a way, and the last hypothesis is never excluded.

A hypothesis's path grows past a node when its interval's end comes within
``branch_margin`` (+ 1 s of travel) of it: from then on the interval covers every way.
"""
from __future__ import annotations

import copy
import math
from collections import Counter
from dataclasses import dataclass, field, replace

from ..fusion.config import FusionConfig
from ..fusion.filter import Estimate, TrainFilter
from ..fusion.mode import Mode
from ..measurements import MAX_YAW_RATE, PositionFix, YawRate
from ..signals import InputRejected
from .config import NetworkConfig
from .model import Network
from .path import TrackPath

LOG_FLOOR = -700.0   # log-weights are kept relative to the best, no lower than this


@dataclass(frozen=True, slots=True)
class TrackHypothesisState:
    """One hypothesis at one time, on the section its estimate lies on."""

    track_id: str
    position: float        # front chainage on track_id [m]
    speed: float           # [m/s] along track_id's chainage
    position_min: float    # interval on track_id's chainage axis, continued along the path [m]
    position_max: float
    probability: float
    path: tuple[str, ...]  # sections the interval spans, in the direction of travel
    mode: int
    ways: tuple[tuple[str, str], ...] = ()   # (switch, way) of the facing switches on its path
    pieces: tuple[tuple[float, float], ...] = ()   # the interval on each section of path, its chainages [m]


@dataclass(slots=True)
class NetworkEstimate(Estimate):
    """A TrainState on a network: position, speed and interval on ``track_id`` (the most
    probable hypothesis's section), the interval covering every plausible hypothesis."""

    track_id: str = ""
    track_probability: float = 1.0
    hypotheses: tuple = ()        # TrackHypothesisState, most probable first
    path_position: float = math.nan   # the same, as path distances (shared origin) [m]
    path_speed: float = math.nan      # [m/s] along the path (the direction of travel)
    path_min: float = math.nan
    path_max: float = math.nan
    path_direction: int = 0           # +1: the most probable path runs along track_id's chainage, -1 against


@dataclass(frozen=True)
class OperatorStart:
    """Where an operator's set_position puts the train on a network: the front on ``section`` at
    ``chainage`` [m], running along the section's chainage (``direction`` +1) or against it
    (-1); ``origin`` the path distance where its path enters the section [m] (the route's, so
    that ``position``, the path distance [m], is a route distance)."""

    section: str
    chainage: float
    direction: int
    origin: float
    position: float

    def describe(self) -> str:
        """One line: the section, the chainage and the direction."""
        return (f"section {self.section}, chainage {self.chainage:.3f} m, running "
                f"{'along' if self.direction > 0 else 'against'} its chainage (route distance {self.position:.3f} m)")


@dataclass(eq=False)
class Hypothesis:
    """A path and the along-track filter of the train on it."""

    path: TrackPath
    filter: TrainFilter
    log_weight: float = 0.0
    misses: list = field(default_factory=list)      # (stamp, reference id) of fixes it does not contain
    off_path: Counter = field(default_factory=Counter)   # receiver -> consecutive 2-D fixes off it
    last: Estimate | None = None                    # its latest estimate

    @property
    def where(self) -> float | None:
        """Path distance [m] of its latest estimate, None before it claims one."""
        return self.last.position if self.last is not None and math.isfinite(self.last.position) else None


class HypothesisSet:
    """Stands in for TrainFilter inside a FusionRunner (core/fusion/runner.py): the same
    ``cfg``, ``add``, ``estimate``, ``reset``, ``counters`` and ``hist``, over the set of
    track hypotheses. ``cfg`` is what admission checks (fixes on a section, in its chainage);
    each hypothesis's filter runs on ``inner`` (the same tuning, no references: its fixes are
    path distances)."""

    def __init__(self, cfg: FusionConfig, net: NetworkConfig, network: Network):
        if net.start_section not in network.sections:
            raise ValueError(f"start_section {net.start_section!r} is not a section of network "
                             f"{network.network_id} ({', '.join(network.sections)})")
        self.cfg = cfg
        self.net = net
        self.network = network
        self.inner = copy.copy(cfg)
        self.inner.models = {name: replace(m, references=None) for name, m in cfg.models.items()}
        self.inner.track, self.inner.track_id = None, ""
        self.models = cfg.models
        self.timeouts = {s: m.timeout for s, m in cfg.models.items() if math.isfinite(m.timeout)}
        self.switches: dict[str, str] = {}        # switch -> reported way (B1/B2), "" unknown
        self.contradicted: dict[str, tuple[str, str]] = {}   # switch -> (reported, found)
        self.events: Counter = Counter()
        self.overflow = False
        self.unexplained_at = -math.inf   # [s] of the last fix that no hypothesis's path explains
        self.hyps: list[Hypothesis] = []
        self.reset()

    # ---- the TrainFilter interface ------------------------------------------------
    @property
    def hist(self):
        return self.hyps[0].filter.hist

    def reset(self, position: float | None = None, position_stddev: float = 1.0, speed: float = 0.0,
              speed_stddev: float = 1.0, stamp: float | None = None, start: OperatorStart | None = None) -> None:
        """One hypothesis again, on the start section (position: path distance [m], which is
        the start section's chainage along the direction of travel), or on ``start``'s section
        (an operator's, ``operator_start``: position is then its path distance)."""
        if start is None:
            path = TrackPath.start(self.network, self.net.start_section, self.net.start_direction)
        else:
            path = TrackPath.start(self.network, start.section, start.direction, start.origin)
        f = TrainFilter(self.inner)
        f.reset(position, position_stddev, speed, speed_stddev, stamp)
        self.hyps = [Hypothesis(path, f)]
        self.overflow = False
        self.unexplained_at = -math.inf

    def operator_start(self, position: float, section: str = "", route: TrackPath | None = None) -> OperatorStart:
        """Where an operator's ``position`` [m] puts the train: with ``section``, a chainage on it,
        which the train's ``route`` must run along once, or else the track hypotheses (all in
        one direction); without, a distance along the route (by default the path from
        start_section). Raises InputRejected in one line: a section of no such path
        (``off_route``), one the route passes twice or the hypotheses run both ways
        (``ambiguous``), a chainage off the section or a distance off the route (``off_track``)."""
        route = route if route is not None else TrackPath.start(self.network, self.net.start_section,
                                                                self.net.start_direction)
        if not section:
            if not route.begin <= position <= route.end:
                raise InputRejected("off_track", f"route distance {position:.3f} m is off the route "
                                                 f"({route.begin:.3f} .. {route.end:.3f} m along "
                                                 f"{', '.join(st.section for st in route.steps)})")
            step = route.step_at(position)
            return OperatorStart(step.section, step.chainage(position), step.direction, step.start, position)
        if section not in self.network.sections:
            raise InputRejected("wrong_track", f"section {section[:64]!r} is no section of network "
                                               f"{self.network.network_id}")
        length = self.network.section(section).length
        if not 0.0 <= position <= length:
            raise InputRejected("off_track", f"chainage {position:.3f} m is off section {section} "
                                             f"(0 .. {length:.3f} m)")
        steps = [st for st in route.steps if st.section == section]
        if len(steps) > 1:
            raise InputRejected("ambiguous", f"the route passes section {section} {len(steps)} times: give the "
                                             "route distance (an empty section_id) instead")
        if not steps:
            steps = [st for h in self.hyps for st in h.path.steps if st.section == section]
            if not steps:
                known = dict.fromkeys(st.section for h in self.hyps for st in h.path.steps)
                raise InputRejected("off_route", f"section {section} is neither on the train's route "
                                                 f"({', '.join(st.section for st in route.steps)}) nor on a track "
                                                 f"hypothesis ({', '.join(known)})")
            if len({st.direction for st in steps}) > 1:
                raise InputRejected("ambiguous", f"the track hypotheses run along section {section} both ways")
        step = steps[0]
        return OperatorStart(section, position, step.direction, step.start, step.distance(position))

    def set_switches(self, positions: dict[str, str]) -> None:
        """The interlocking's report: switch -> "B1"/"B2" ("" or absent: unknown)."""
        self.switches.update(positions)

    def add(self, m) -> None:
        if isinstance(m, YawRate):
            self._yaw_rate(m)
            return
        if isinstance(m, PositionFix):
            if m.track_id not in self.network.sections:
                raise InputRejected("wrong_track", f"fix on {m.track_id[:64]!r}, which is no section of network "
                                                   f"{self.network.network_id}")
            if m.is_map_fix:
                self._map_fix(m)
            else:
                self._reference_fix(m)
            return
        first, *others = self.hyps
        first.filter.add(m)          # raises for a duplicate or a late one: the same for every filter
        for h in others:
            h.filter.add(m)

    def estimate(self, t: float) -> NetworkEstimate:
        self._grow(t)
        probs = self._probabilities()
        order = sorted(range(len(self.hyps)), key=lambda i: -probs[i])
        states = [self._state(self.hyps[i], probs[i]) for i in order]
        top = self.hyps[order[0]]
        est = top.last
        known = [h.last for h in self.hyps if math.isfinite(h.last.position)]
        if not math.isfinite(est.position) or not known:
            d = top.path.steps[-1].direction   # speed and acceleration along that section's chainage
            return NetworkEstimate(**{**_fields(est), "speed": est.speed * d, "acceleration": est.acceleration * d},
                                   track_id=top.path.steps[-1].section, track_probability=probs[order[0]],
                                   hypotheses=tuple(states), path_direction=d)
        lo = min(e.position_min for e in known)
        hi = max(e.position_max for e in known)
        modes = [e.mode for e in known]
        mode = Mode.LOST if Mode.LOST in modes or self.overflow else max(modes)
        if len({s.path for s in states}) > 1 or t - self.unexplained_at <= self.net.exclusion_window:
            # several tracks plausible, or a fix lately that no path explains (a track not followed)
            mode = max(mode, Mode.DEGRADED)
        step = top.path.step_at(est.position)
        a, b = step.chainage(lo), step.chainage(hi)
        return NetworkEstimate(
            t, step.chainage(est.position), est.speed * step.direction, est.acceleration * step.direction,
            max(e.position_stddev for e in known), max(e.speed_stddev for e in known), min(a, b), max(a, b),
            min(e.confidence for e in known), Mode(mode), est.scales, est.biases, track_id=step.section,
            track_probability=probs[order[0]], hypotheses=tuple(states), path_position=est.position,
            path_speed=est.speed, path_min=lo, path_max=hi, path_direction=step.direction)

    def counters(self) -> dict[str, dict]:
        out = self.hyps[0].filter.counters()
        out["network"] = {**dict(self.events), "hypotheses": len(self.hyps)}
        out["switches_contradicted"] = {k: f"reported {r}, found {f}" for k, (r, f) in self.contradicted.items()}
        return out

    # ---- evidence -------------------------------------------------------------------
    def _reference_fix(self, m: PositionFix) -> None:
        """A fix that names equipment on section m.track_id: a path without that section cannot
        explain it."""
        explained = []
        for h in self.hyps:
            s = h.path.distance(m.track_id, m.position, h.where)
            if s is not None:
                explained.append((h, s))
        if not explained:
            self.events["unexplained_reference"] += 1
            self.unexplained_at = max(self.unexplained_at, m.stamp)
            raise InputRejected("off_network_path", f"{m.sensor} fix of {m.reference_id[:64]!r} on section "
                                                    f"{m.track_id}, which no track hypothesis contains")
        if len(explained) < len(self.hyps):
            hit = {id(h) for h, _ in explained}
            needed = self.net.exclusion_references if "misread" in self.models[m.sensor].faults else 1
            for h in [h for h in self.hyps if id(h) not in hit]:
                h.log_weight += math.log(self.net.misread_probability)
                h.misses = [(t, r) for t, r in h.misses if m.stamp - t <= self.net.exclusion_window]
                h.misses.append((m.stamp, m.reference_id))
                if len({r for _, r in h.misses}) >= needed:
                    self._exclude(h, "reference")
        for h, s in explained:
            if h in self.hyps:
                step = h.path.step_at(s)
                h.filter.add(replace(m, track_id="", position=s, direction=m.direction * step.direction))

    def _map_fix(self, m: PositionFix) -> None:
        """A 2-D fix (its antenna's point): projected onto every path; its lateral offset ranks
        the paths, and excludes one only after map_exclusion_fixes consecutive fixes off it."""
        sec = self.network.section(m.track_id)
        x0, y0, heading = sec.pose(m.position)
        px, py = x0 - math.sin(heading) * m.lateral, y0 + math.cos(heading) * m.lateral
        offset = self.models[m.sensor].sensor_offset
        sigma = m.lateral_stddev
        gate = self.net.map_lateral_gate * sigma
        placed = []
        for h in self.hyps:
            if h.where is not None:
                s_ant, lat = h.path.project(px, py, h.where - offset, self.net.map_reach)
            else:
                s_ant, lat = h.path.project(px, py, 0.5 * (h.path.begin + h.path.end), math.inf)
            placed.append((h, s_ant + offset, lat))
        on = [abs(lat) <= gate for _, _, lat in placed]
        if not any(on):
            self.events["map_fix_off_every_path"] += 1
            self.unexplained_at = max(self.unexplained_at, m.stamp)
            raise InputRejected("off_network_path", f"{m.sensor} fix {min(abs(p[2]) for p in placed):.1f} m from "
                                                    f"every track hypothesis's path (gate {gate:.1f} m)")
        for (h, front, lat), near in zip(placed, on):
            h.log_weight += robust_log_likelihood(lat, sigma, self.net.map_outlier_probability, 2.0 * gate)
            if near:
                h.off_path[m.unit_id] = 0
                h.filter.add(replace(m, track_id="", position=front, lateral=0.0, lateral_stddev=0.0))
            else:
                h.off_path[m.unit_id] += 1
                if h.off_path[m.unit_id] >= self.net.map_exclusion_fixes:
                    self._exclude(h, "map")

    def _yaw_rate(self, m: YawRate) -> None:
        """A turn rate: each hypothesis predicts v x kappa of its path where it puts the gyro
        (kappa over the reach of its position's uncertainty); the residual ranks the paths. It
        excludes none: a gyro's bias could mimic a gentle curve."""
        model = self.models[m.sensor]
        eps = self.net.map_outlier_probability
        for h in self.hyps:
            e = h.filter.estimate(m.stamp)   # where the hypothesis had the train then (it may be late)
            if not (math.isfinite(e.position) and math.isfinite(e.speed)):
                continue
            s = e.position - model.sensor_offset
            reach = 2.0 * e.position_stddev + abs(e.speed) * 0.1 + 1.0
            k_lo, k_hi = h.path.curvature_range(s - reach, s + reach)
            lo, hi = sorted((e.speed * k_lo, e.speed * k_hi))
            residual = lo - m.yaw_rate if m.yaw_rate < lo else (m.yaw_rate - hi if m.yaw_rate > hi else 0.0)
            kappa = max(abs(k_lo), abs(k_hi))
            sigma = math.sqrt(m.yaw_rate_stddev ** 2 + (kappa * e.speed_stddev) ** 2
                              + (model.reported_scale * max(abs(lo), abs(hi))) ** 2)
            h.log_weight += robust_log_likelihood(residual, sigma, eps, 2.0 * MAX_YAW_RATE)

    def _exclude(self, h: Hypothesis, reason: str) -> None:
        if len(self.hyps) <= 1 or h not in self.hyps:
            return
        self.hyps.remove(h)
        self.events[f"excluded_{reason}"] += 1
        self._check_switches()

    def _check_switches(self) -> None:
        """A switch whose way every remaining hypothesis agrees on, against the interlocking."""
        ways = [h.path.ways() for h in self.hyps]
        for node, way in ways[0].items():
            reported = self.switches.get(node, "")
            if reported and way != reported and all(w.get(node) == way for w in ways[1:]) \
                    and node not in self.contradicted:
                self.contradicted[node] = (reported, way)
                self.events["switch_contradicted"] += 1

    # ---- growth ---------------------------------------------------------------------
    def _grow(self, t: float) -> None:
        """Every hypothesis's estimate at t; paths continued (and branched at facing switches)
        where their interval's ends come near a node."""
        work = list(self.hyps)
        grown: list[Hypothesis] = []
        while work:
            h = work.pop()
            est = h.last = h.filter.estimate(t)
            if not (math.isfinite(est.position_min) and math.isfinite(est.position_max)):
                grown.append(h)
                continue
            reach = self.net.branch_margin + abs(est.speed)
            ends = [(est.position_max + reach > h.path.end, h.path.ahead, TrackPath.extended),
                    (est.position_min - reach < h.path.begin, h.path.behind, TrackPath.prepended)]
            children = None
            for near_end, options, grow in ends:
                if not near_end:
                    continue
                conts = options()
                if len(conts) == 1:
                    h.path = grow(h.path, conts[0])
                    children = [h]
                    break
                if len(conts) > 1:
                    children = [self._branch(h, grow(h.path, c), self._prior(c)) for c in conts]
                    self.events["branches"] += 1
                    break
            if children is None:
                grown.append(h)
            else:
                work.extend(children)
        if len(grown) > self.net.max_hypotheses:
            grown.sort(key=lambda h: -h.log_weight)
            del grown[self.net.max_hypotheses:]
            self.overflow = True
            self.events["overflow"] += 1
        self.hyps = grown

    def _prior(self, c) -> float:
        if c.way is None:
            return 1.0
        reported = self.switches.get(c.node, "")
        if not reported:
            return 0.5
        p = self.net.wrong_switch_probability
        return 1.0 - p if c.way == reported else p

    def _branch(self, h: Hypothesis, path: TrackPath, prior: float) -> Hypothesis:
        memo = {id(self.inner): self.inner, id(self.inner.models): self.inner.models}
        return Hypothesis(path, copy.deepcopy(h.filter, memo), h.log_weight + math.log(prior), list(h.misses),
                          Counter(h.off_path), h.last)

    def _probabilities(self) -> list[float]:
        best = max(h.log_weight for h in self.hyps)
        for h in self.hyps:
            h.log_weight = max(h.log_weight - best, LOG_FLOOR)
        w = [math.exp(h.log_weight) for h in self.hyps]
        total = sum(w)
        return [x / total for x in w]

    def _state(self, h: Hypothesis, probability: float) -> TrackHypothesisState:
        e = h.last
        if not math.isfinite(e.position):
            step = h.path.steps[-1]
            return TrackHypothesisState(step.section, math.nan, math.nan, -math.inf, math.inf, probability,
                                        (step.section,), int(e.mode), tuple(h.path.ways().items()),
                                        ((-math.inf, math.inf),))
        step = h.path.step_at(e.position)
        a, b = step.chainage(e.position_min), step.chainage(e.position_max)
        spans = h.path.spans(e.position_min, e.position_max)
        return TrackHypothesisState(step.section, step.chainage(e.position), e.speed * step.direction, min(a, b),
                                    max(a, b), probability, tuple(sp.section for sp in spans), int(e.mode),
                                    tuple(h.path.ways().items()), tuple((sp.lo, sp.hi) for sp in spans))


def robust_log_likelihood(residual: float, sigma: float, outliers: float, span: float) -> float:
    """log of a residual's density: a Gaussian of 1-sigma ``sigma`` with a share ``outliers``
    spread uniformly over ``span`` (no single reading can drive a hypothesis's weight to 0)."""
    z = residual / sigma
    return math.log((1.0 - outliers) * math.exp(-0.5 * z * z) / (math.sqrt(2.0 * math.pi) * sigma)
                    + outliers / span)


def _fields(est: Estimate) -> dict:
    return {name: getattr(est, name) for name in Estimate.__slots__}

"""The ETCS location function of a train on a network (docs/network.md, "ETCS on a network";
SUBSET-026 section 3.6): the single-line LocationTracker (core/etcs/location.py) run in the path
distance of the path the train follows.

The followed path (core/network/followed.py) runs from the fusion's start through the section
the fused state puts the front on, and on ahead along the switches' reported ways; its ETCS data
(``path_data``) are the groups on its sections at their path distances, oriented along the path,
and the links a train on that path expects (NetworkEtcsData ``links_after`` whose path the
followed one takes). When the path grows or turns onto another way the data are rebuilt and the
expectation derived again (``LocationTracker.rebase``): a group expected on the way not taken is
not reported missed. Path distances of every path grown from the start share its origin, so the
LRBG and the history of fused states stay valid across a change of way.

Inputs. Fused states with their path fields (TrainState ``path_*``): the location function takes
the interval covering every plausible hypothesis, as path distances, for its safe front ends,
and the state's mode (DEGRADED while the hypotheses span several tracks). A balise fix names its
section and chainage; it is placed on the followed path once due (a fused state at or after its
stamp). A fix on a section the path lacks waits ``path_wait`` after its stamp for the path to
reach it (the fusion turning its most probable hypothesis onto that way), holding back the
missed-group verdict meanwhile; then it is refused (``off_network_path``) and counted.

The report names the network (``track_id``), the LRBG's section (``lrbg_track_id``), the front
ends as path distances and the followed path (``path``: sections, directions and origins), from
which a consumer restates a place (section, chainage) in the report's frame.
"""
from __future__ import annotations

import math
from dataclasses import replace

from ..measurements import PositionFix
from ..network.followed import ahead, follow
from ..network.path import TrackPath
from ..sensors.base import Param, check_declared, resolve_params
from .location import FusedState, LocationTracker
from .network_data import DEFAULT_REACH, NetworkEtcsData
from .records import LocationEvent, LocationReport, PathSection
from .track_data import LINK_TOLERANCE, BaliseGroup, EtcsData, Link

PARAMS = {
    "path_wait": Param(2.0, "on a network: a balise fix on a section the followed path lacks waits this long after "
                            "its stamp for the path to reach it, then is refused (off_network_path) [s]", (0.0, 60.0)),
    "path_reach": Param(DEFAULT_REACH, "on a network: the followed path runs this far ahead of the front along the "
                                       "reported switch ways (an end of authority must lie on it) [m]",
                        (100.0, 100000.0)),
}
check_declared(PARAMS, "etcs network location PARAMS")


def path_view(state: FusedState) -> FusedState:
    """A fused state on a network as the location function takes it: its path distance, the
    interval covering every plausible hypothesis as path distances, its speed along the path."""
    return FusedState(state.t, state.path_position, state.path_min, state.path_max,
                      state.speed * (state.path_direction or 1), state.speed_stddev, state.confidence, state.mode)


def start_path(scenario) -> TrackPath:
    """Where the fusion of a network train starts its paths (core/network/config.py
    ``network_fusion_config``: the route's first section and direction unless its ``fusion:``
    section sets ``start_section`` / ``start_direction``), path distance 0 entering it."""
    first = scenario.route.steps[0]
    fusion = scenario.fusion or {}
    return TrackPath.start(scenario.network, str(fusion.get("start_section", first.section)),
                           int(fusion.get("start_direction", first.direction)))


def path_data(data: NetworkEtcsData, path: TrackPath, keep: dict[str, BaliseGroup] | None = None) -> EtcsData:
    """The ETCS data of ``path`` as a single line in its path distance: the groups on its
    sections (a section passed twice: its first passage) at their path distances, their
    orientation relative to the path's direction; for each group and direction along the path, the link whose path the
    followed one takes (its target on the path, at the linked distance). ``keep``: groups kept
    as they are where the path lacks them (the LRBG after a change of way)."""
    groups: dict[str, BaliseGroup] = {}
    index: dict[str, int] = {}
    for i, step in enumerate(path.steps):
        for nid, located in data.groups.items():
            if located.section != step.section or nid in groups:
                continue
            g = located.group
            placed = sorted(zip((step.distance(x) for x in g.positions), g.balises))
            groups[nid] = BaliseGroup(nid, step.distance(g.reference), g.orientation * step.direction, g.q_locacc,
                                      tuple(b for _, b in placed), tuple(x for x, _ in placed))
            index[nid] = i
    for nid, group in (keep or {}).items():
        groups.setdefault(nid, group)
    links: dict[tuple[str, int], Link] = {}
    for nid, i in index.items():
        for d in (1, -1):
            sections = [st.section for st in (path.steps[i:] if d > 0 else path.steps[i::-1])]
            link = next((k for k in data.links_after(nid, d * path.steps[i].direction)
                         if tuple(sections[:len(k.path)]) == k.path), None)
            if link is None or link.to_bg not in index:
                continue
            if abs(d * (groups[link.to_bg].reference - groups[nid].reference) - link.distance) > LINK_TOLERANCE:
                continue   # the target's first passage is not the linked one
            links[(nid, d)] = Link(nid, link.to_bg, link.distance, d, link.reaction)
    group_of = {b: nid for nid, g in groups.items() for b in g.balises}
    return EtcsData(data.network_id, groups, group_of, links, data.q_nvlocacc)


class NetworkLocationTracker:
    """``on_fix`` takes balise fixes (section chainages), ``set_switches`` the interlocking's
    report, ``on_state`` the fused states with their path fields (in time order) and returns the
    report and the events; ``stats`` counts as LocationTracker's, plus ``off_network_path`` and
    ``path_changes`` (the followed path regrown)."""

    def __init__(self, data: NetworkEtcsData, network, start: TrackPath, params: dict | None = None,
                 switches: dict[str, str] | None = None):
        params = dict(params or {})
        own = resolve_params(PARAMS, {k: params.pop(k) for k in list(params) if k in PARAMS})
        self.wait, self.reach = float(own["path_wait"]), float(own["path_reach"])
        self.data, self.network = data, network
        self.switches = dict(switches or {})
        self.path = ahead(start, start.begin, self.switches, self.reach)
        self.tracker = LocationTracker(path_data(data, self.path), params)
        self._pending: list[PositionFix] = []
        self._switches_changed = False
        self.counts = {"off_network_path": 0, "path_changes": 0}

    @property
    def stats(self) -> dict[str, int]:
        return {**self.tracker.stats, **self.counts}

    def set_switches(self, positions: dict[str, str]) -> None:
        """The interlocking's report: switch -> "B1"/"B2" ("" unknown); the path ahead follows it."""
        self.switches.update(positions)
        self._switches_changed = True

    def on_fix(self, fix: PositionFix) -> None:
        """A balise fix on a section of the network; placed on the followed path once due."""
        self._pending.append(fix)

    def on_state(self, state: FusedState) -> tuple[LocationReport, list[LocationEvent]]:
        """The report of one fused state (on the followed path) and the events due by then."""
        if state.path_direction and math.isfinite(state.path_position):
            self._follow(state)
        on_path = path_view(state)
        self._place_fixes(state.t, on_path.position)
        report, events = self.tracker.on_state(on_path)
        return self._report(report), events

    # ----------------------------------------------------------------------- the path
    def _follow(self, state: FusedState) -> None:
        s = state.path_position
        path = follow(self.path, self.network, state.track_id, state.position, s, state.path_direction)
        if path is not self.path or self._switches_changed or path.end < s + self.reach:
            path = ahead(path, s, self.switches, self.reach)
            self._switches_changed = False
        if path.steps == self.path.steps:
            return
        self.path = path
        self.counts["path_changes"] += 1
        lrbg = self.tracker.lrbg
        keep = {lrbg.nid_bg: self.tracker.data.groups[lrbg.nid_bg]} if lrbg is not None else None
        self.tracker.rebase(path_data(self.data, path, keep))

    def _place_fixes(self, t: float, near: float) -> None:
        """Due fixes on the followed path go to the location function; those on a section it
        lacks wait ``path_wait`` (holding back a missed-group verdict), then are refused."""
        waiting = []
        for fix in self._pending:
            if fix.stamp > t:
                waiting.append(fix)
                continue
            steps = [st for st in self.path.steps if st.section == fix.track_id]
            if steps:
                step = min(steps, key=lambda st: abs(st.distance(fix.position) - near) if math.isfinite(near) else 0.0)
                self.tracker.on_fix(replace(fix, track_id=self.data.network_id, position=step.distance(fix.position),
                                            direction=fix.direction * step.direction))
            elif t - fix.stamp <= self.wait:
                waiting.append(fix)
            else:
                self.counts["off_network_path"] += 1
        self._pending = waiting
        self.tracker.hold_missed = any(f.stamp <= t for f in waiting)

    # ----------------------------------------------------------------------- the report
    def _report(self, report: LocationReport) -> LocationReport:
        """The report in the network's terms: the LRBG's section and the followed path from the
        LRBG's section (or the section of the nearer safe front end, if before it) on."""
        lrbg = self.data.groups.get(report.nid_lrbg)
        marks = [x for x in (report.min_safe_front_end, report.max_safe_front_end) if math.isfinite(x)]
        if lrbg is not None:
            marks.append(self.tracker.data.groups[report.nid_lrbg].reference)
        start = min(marks, default=-math.inf)
        first = next((i for i, st in enumerate(self.path.steps) if st.stop > start), len(self.path.steps) - 1)
        path = tuple(PathSection(st.section, st.direction, st.distance(0.0)) for st in self.path.steps[first:])
        return replace(report, lrbg_track_id=lrbg.section if lrbg is not None else "", path=path)

"""A path through a network: the sections a train runs along, in order (docs/network.md).

A path has one coordinate, the *path distance* s [m], which runs in the train's direction
of travel along every section it contains (against a section's chainage where the path
runs along it backwards). A scenario's route is a path (the simulator drives the train
along it); each hypothesis of the track-selective fusion is one (core/network/hypotheses.py).
Paths grown from one start share its origin, so a path distance is the distance run
whichever way the train took at the switches.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..track import Track
from .model import SWITCH_WAYS, Continuation, Network, NetworkError


@dataclass(frozen=True)
class PathStep:
    """One section of a path: it is entered at path distance ``start`` [m] and run along its
    chainage in ``direction`` (+1 increasing); ``node``/``way``: the node crossed to enter it
    and, after a facing switch, the way taken (B1/B2); None for the first step."""

    section: str
    direction: int
    start: float
    length: float
    node: str | None = None
    way: str | None = None

    @property
    def stop(self) -> float:
        return self.start + self.length

    def chainage(self, s: float) -> float:
        """Section chainage of path distance s (continued beyond the section's ends)."""
        return s - self.start if self.direction > 0 else self.length - (s - self.start)

    def distance(self, chainage: float) -> float:
        """Path distance of a section chainage (continued beyond the section's ends)."""
        return self.start + (chainage if self.direction > 0 else self.length - chainage)


@dataclass(frozen=True)
class SectionSpan:
    """A stretch of one section: chainages ``lo`` <= ``hi`` [m] on ``section``."""

    section: str
    lo: float
    hi: float


@dataclass(frozen=True)
class TrackPath:
    """Consecutive steps through ``network``; immutable (extending makes a new path)."""

    network: Network
    steps: tuple[PathStep, ...]

    @classmethod
    def start(cls, network: Network, section: str, direction: int, origin: float = 0.0) -> "TrackPath":
        """A path of one section, run in ``direction``; path distance ``origin`` where it enters."""
        if direction not in (1, -1):
            raise NetworkError(f"direction {direction} must be +1 or -1")
        sec = network.section(section)
        return cls(network, (PathStep(section, direction, origin, sec.length),))

    @property
    def begin(self) -> float:
        return self.steps[0].start

    @property
    def end(self) -> float:
        return self.steps[-1].stop

    def ahead(self) -> list[Continuation]:
        last = self.steps[-1]
        return self.network.continuations(last.section, last.direction)

    def behind(self) -> list[Continuation]:
        """Where the path can be continued backwards from its first section (the continuation's
        direction is that of the path's travel, i.e. the reverse of a train backing into it)."""
        first = self.steps[0]
        return [Continuation(c.section, -c.direction, c.node, c.way)
                for c in self.network.continuations(first.section, -first.direction)]

    def extended(self, c: Continuation) -> "TrackPath":
        length = self.network.section(c.section).length
        return TrackPath(self.network, self.steps + (PathStep(c.section, c.direction, self.end, length, c.node, c.way),))

    def prepended(self, c: Continuation) -> "TrackPath":
        """The path continued backwards by ``c`` (from ``behind``): the node/way stay on the step
        entered through them (the former first step)."""
        length = self.network.section(c.section).length
        first = self.steps[0]
        relinked = PathStep(first.section, first.direction, first.start, first.length, c.node,
                            _forward_way(self.network, c, first.section))
        return TrackPath(self.network, (PathStep(c.section, c.direction, self.begin - length, length),
                                        relinked) + self.steps[1:])

    def step_at(self, s: float) -> PathStep:
        """The step containing path distance s (the first or last beyond the path's ends)."""
        for step in self.steps:
            if s < step.stop:
                return step
        return self.steps[-1]

    def locate(self, s: float) -> tuple[str, float]:
        """(section, chainage) of path distance s."""
        step = self.step_at(s)
        return step.section, step.chainage(s)

    def step_on(self, section: str) -> PathStep | None:
        """The (first) step of the path along ``section``; None if the path does not contain it."""
        return next((st for st in self.steps if st.section == section), None)

    def distance(self, section: str, chainage: float, near: float | None = None) -> float | None:
        """Path distance of a place on ``section`` (the occurrence nearest ``near``), None if
        the path does not contain the section."""
        best = None
        for step in self.steps:
            if step.section == section:
                s = step.distance(chainage)
                if best is None or (near is not None and abs(s - near) < abs(best - near)):
                    best = s
        return best

    def sections(self, lo: float, hi: float) -> list[str]:
        """Sections the path distances lo .. hi span, in the path's order."""
        return [span.section for span in self.spans(lo, hi)]

    def spans(self, lo: float, hi: float) -> list["SectionSpan"]:
        """The path distances lo .. hi restated on each section they span, in the path's order
        (beyond the path's ends they run on along its first or last section's axis)."""
        steps = [st for st in self.steps if st.stop > lo and st.start < hi] or [self.step_at(lo)]
        out = []
        for st in steps:
            a = lo if st is self.steps[0] else max(lo, st.start)
            b = hi if st is self.steps[-1] else min(hi, st.stop)
            ca, cb = st.chainage(a), st.chainage(b)
            out.append(SectionSpan(st.section, min(ca, cb), max(ca, cb)))
        return out

    @classmethod
    def through(cls, network: Network, sections: tuple[str, ...] | list[str]) -> "TrackPath | None":
        """The path along ``sections`` (each joined to the one before at a node, as a published
        hypothesis's ``path`` lists them), path distance 0 where it enters the first; None if
        they do not join so or one is no section of the network. A single section is run along
        its chainage."""
        if not sections or any(sid not in network.sections for sid in sections):
            return None
        for direction in (1, -1):
            path: TrackPath | None = cls.start(network, sections[0], direction)
            for nxt in sections[1:]:
                c = next((c for c in path.ahead() if c.section == nxt), None)
                if c is None:
                    path = None
                    break
                path = path.extended(c)
            if path is not None:
                return path
        return None

    def reaching(self, section: str) -> "TrackPath | None":
        """The path itself if it contains ``section``, else continued by one section at either
        end to reach it; None if it does not join the path's ends."""
        if self.step_on(section) is not None:
            return self
        for c in self.ahead():
            if c.section == section:
                return self.extended(c)
        for c in self.behind():
            if c.section == section:
                return self.prepended(c)
        return None

    def ways(self) -> dict[str, str]:
        """node -> way (B1/B2) of every facing switch the path takes."""
        return {st.node: st.way for st in self.steps if st.way is not None}

    def curvature_range(self, lo: float, hi: float, step: float = 0.5) -> tuple[float, float]:
        """(least, greatest) curvature [1/m] of the path between path distances lo and hi, in
        its direction of travel (+ turning left; a section run backwards turns the other way)."""
        values = []
        for s in np.linspace(lo, hi, max(2, int(math.ceil((hi - lo) / step)) + 1)):
            st = self.step_at(float(s))
            values.append(st.direction * self.network.section(st.section).curvature(st.chainage(float(s))))
        return min(values), max(values)

    def xy(self, s: float) -> tuple[float, float]:
        section, chainage = self.locate(s)
        x, y, _ = self.network.section(section).pose(chainage)
        return x, y

    def project(self, x: float, y: float, near: float, reach: float) -> tuple[float, float]:
        """(path distance, lateral offset [m], + to the left of the direction of travel) of the
        point of the path nearest the map point (x, y) among the steps within ``reach`` of path
        distance ``near``."""
        best = (math.inf, near, 0.0)
        for step in self.steps:
            if step.stop < near - reach or step.start > near + reach:
                continue
            sec = self.network.section(step.section)
            chain, lateral = sec.project(x, y)
            c, lat = float(chain[0]), float(lateral[0])
            s = step.distance(c)
            px, py, _ = sec.pose(c)
            d = math.hypot(x - px, y - py)
            if d < best[0]:
                best = (d, s, lat * step.direction)
        return best[1], best[2]


def _forward_way(network: Network, c: Continuation, into_section: str) -> str | None:
    """The way a path running from ``c.section`` across ``c.node`` into ``into_section`` takes:
    B1/B2 when it enters a point switch at its A port (a facing move), else None."""
    node = network.nodes[c.node]
    if node.kind != "point_switch" or node.ports["A"].section != c.section:
        return None
    for way in SWITCH_WAYS:
        if node.ports[way].section == into_section:
            return way
    return None


def route_path(network: Network, sections: list[str], first_direction: int = 1) -> TrackPath:
    """The path through the listed sections, in order (each must follow the one before through
    a node); NetworkError names the first that does not."""
    if not sections:
        raise NetworkError("a route lists at least one section")
    path = TrackPath.start(network, str(sections[0]), first_direction)
    for sid in sections[1:]:
        options = [c for c in path.ahead() if c.section == str(sid)]
        if not options:
            last = path.steps[-1]
            reachable = ", ".join(c.section for c in path.ahead()) or "none: an end of the network"
            raise NetworkError(f"route: section {sid} does not follow {last.section} (run "
                               f"{'forwards' if last.direction > 0 else 'backwards'}); next sections: {reachable}")
        path = path.extended(options[0])
    return path


# equipment kinds a route line carries (a sensor that needs another kind is not yet
# supported on a network: core/scenario.py refuses it in one line)
ROUTE_KINDS = ("eurobalise", "transponder_tag", "structure")
# equipment that wayside devices see (core/network/wayside.py), no on-board sensor: not on route lines
WAYSIDE_ONLY_KINDS = ("axle_counter_head", "track_circuit")


def route_track(path: TrackPath, track_id: str) -> Track:
    """The path as a single line (core/track.py Track): chainage = path distance from the
    path's begin, the sections' alignments end to end, and the equipment of ROUTE_KINDS on
    them at their path distance, each item keeping its ``section`` and ``section_position``
    (its chainage there) and getting ``section_direction`` (+1 if the route runs along the
    section's chainage). The simulator and the on-board sensors of a train run on it; the
    wayside equipment (WAYSIDE_ONLY_KINDS) is not on it."""
    network = path.network
    first = path.steps[0]
    sec0 = network.section(first.section)
    x, y, h = sec0.pose(0.0 if first.direction > 0 else sec0.length)
    origin = (x, y, h if first.direction > 0 else h + math.pi)
    segments: list[tuple[float, float]] = []
    equipment: dict[str, list[dict]] = {}
    offset = -path.begin
    for step in path.steps:
        sec = network.section(step.section)
        segs = list(sec.segments) or [(sec.length, 0.0)]
        covered = sum(s[0] for s in segs)
        if covered < sec.length:
            segs.append((sec.length - covered, 0.0))
        segments += segs if step.direction > 0 else [(ln, -k) for ln, k in reversed(segs)]
        for kind, items in sec.equipment.items():
            if kind in WAYSIDE_ONLY_KINDS:
                continue
            if kind not in ROUTE_KINDS:
                raise NetworkError(f"section {sec.track_id}: equipment kind {kind!r} is not supported on a network "
                                   f"yet (supported: {', '.join(ROUTE_KINDS + WAYSIDE_ONLY_KINDS)})")
            for item in items:
                moved = {k: v for k, v in item.items() if k not in ("start", "end", "length")}
                moved.update(section=step.section, section_position=float(item["position"]),
                             section_direction=step.direction)
                if "end" in item or "length" in item:
                    a = float(item.get("start", item["position"]))
                    b = float(item["end"]) if "end" in item else a + float(item["length"])
                    sa, sb = sorted((step.distance(a), step.distance(b)))
                    moved.update(position=sa + offset, end=sb + offset)
                else:
                    moved["position"] = step.distance(float(item["position"])) + offset
                equipment.setdefault(kind, []).append(moved)
    for items in equipment.values():
        items.sort(key=lambda it: it["position"])
    length = path.end - path.begin
    track = Track(track_id=track_id, length=length, equipment=equipment, origin=origin, segments=segments,
                  resolution=min(s.resolution for s in network.sections.values()))
    track.network = network     # the decoders of 2-D fixes project onto the whole network
    track.path = path
    return track

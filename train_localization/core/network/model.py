"""A track network: sections joined at switches and crossings (docs/network.md).

The vocabulary is OSRD's railjson: a *section* (TrackSection) has a length, its own
chainage from 0 at its ``begin`` to ``length`` at its ``end``, a 2-D alignment and the
equipment placed on it; a *node* (TrackNode) joins section ends at its ports:

  point_switch  ports A, B1, B2: a train from A takes B1 or B2, the way the switch is set;
                from B1 or B2 it runs to A (a trailing move)
  crossing      ports A1, B1, A2, B2: A1-B1 and A2-B2 run straight across each other
  link          ports A, B: two sections joined end to end (a change of section id)

An end joined to no node is an end of the network (a buffer stop or the boundary of the
area described). A single line is a network of one section.

YAML (``track:`` of a scenario, or a file it names)::

    network_id: throat
    sections:
      - id: T1
        length: 600.0
        origin: {x: 0.0, y: 0.0, heading: 0.0}   # only where it cannot be derived
        alignment: [{length: 600.0, curvature: 0.0}]
        equipment: {eurobalise: [{id: B1, position: 200.0}]}
      - {id: T2, length: 400.0}                  # starts where W1 puts it
    nodes:
      - {id: W1, type: point_switch, A: T1.end, B1: T2.begin, B2: T3.begin, clearance: 40.0}
    geodetic: {latitude: 48.14, longitude: 11.56}   # optional: the map frame on WGS-84 (core/geodesy.py)

A section without ``origin`` starts at the node its ``begin`` is joined to, in the
direction the node's through route gives (a switch's B ports leave it the way its A port
enters it); the geometry of every node is checked: the joined ends lie within
JOINT_TOLERANCE of each other, and a through route keeps its heading within
HEADING_TOLERANCE.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from ..geodesy import GeodesyError, GeodeticAnchor
from ..track import Track, TrackError

NODE_PORTS = {
    "point_switch": ("A", "B1", "B2"),
    "crossing": ("A1", "B1", "A2", "B2"),
    "link": ("A", "B"),
}
# port -> ports a train entering the node there can leave by
THROUGH = {
    "point_switch": {"A": ("B1", "B2"), "B1": ("A",), "B2": ("A",)},
    "crossing": {"A1": ("B1",), "B1": ("A1",), "A2": ("B2",), "B2": ("A2",)},
    "link": {"A": ("B",), "B": ("A",)},
}
SWITCH_WAYS = ("B1", "B2")      # the positions of a point switch
ENDS = ("begin", "end")
JOINT_TOLERANCE = 0.5           # [m] between section ends joined at one node
HEADING_TOLERANCE = 0.05        # [rad] of a through route across a node
DEFAULT_CLEARANCE = 40.0        # [m] from a switch's point to its clearance point (fouling point)


class NetworkError(TrackError):
    """A network description that cannot be used, with the reason."""


@dataclass(frozen=True)
class SectionEnd:
    """One end of a section: ``begin`` (chainage 0) or ``end`` (chainage = length)."""

    section: str
    end: str

    def __str__(self) -> str:
        return f"{self.section}.{self.end}"


@dataclass(frozen=True)
class Node:
    """A switch, crossing or link: its ports and the section end joined at each."""

    node_id: str
    kind: str
    ports: dict[str, SectionEnd]
    clearance: float = DEFAULT_CLEARANCE   # [m] point to clearance point (point_switch)


@dataclass(frozen=True)
class Continuation:
    """Where a train goes on from the end of a section: the next section, the direction it
    runs along that section's chainage (+1 from its begin, -1 from its end), the node
    crossed and, at a switch taken from its A port (a facing move), the way (B1 or B2)."""

    section: str
    direction: int
    node: str
    way: str | None = None


@dataclass
class Network:
    """Sections (each a core/track.py Track with its own chainage, alignment and equipment)
    joined at nodes."""

    network_id: str
    sections: dict[str, Track]
    nodes: dict[str, Node] = field(default_factory=dict)
    geodetic: GeodeticAnchor | None = None   # WGS-84 place of the map frame (core/geodesy.py); None: none
    etcs: dict = field(default_factory=dict)   # ETCS data: national values, linking (core/etcs/network_data.py)

    def __post_init__(self):
        self._joints: dict[SectionEnd, tuple[str, str]] = {}
        for node in self.nodes.values():
            for port, end in node.ports.items():
                if end.section not in self.sections:
                    raise NetworkError(f"node {node.node_id} port {port} names section {end.section!r}, "
                                       f"which the network does not have")
                if end in self._joints:
                    other, other_port = self._joints[end]
                    raise NetworkError(f"section end {end} is joined twice: at {other} port {other_port} and "
                                       f"at {node.node_id} port {port}")
                self._joints[end] = (node.node_id, port)
        self._check_geometry()

    # ---- topology -------------------------------------------------------------
    def section(self, section_id: str) -> Track:
        try:
            return self.sections[section_id]
        except KeyError:
            raise NetworkError(f"network {self.network_id} has no section {section_id!r}") from None

    def joint(self, end: SectionEnd) -> tuple[Node, str] | None:
        """(node, port) a section end is joined at; None at an end of the network."""
        hit = self._joints.get(end)
        return (self.nodes[hit[0]], hit[1]) if hit else None

    def continuations(self, section_id: str, direction: int) -> list[Continuation]:
        """Where a train running along ``section_id`` in ``direction`` (+1: increasing chainage)
        can go on past the end it runs towards (empty at an end of the network)."""
        joint = self.joint(SectionEnd(section_id, "end" if direction > 0 else "begin"))
        if joint is None:
            return []
        node, port = joint
        out = []
        for exit_port in THROUGH[node.kind][port]:
            nxt = node.ports.get(exit_port)
            if nxt is None:
                continue
            way = exit_port if node.kind == "point_switch" and port == "A" else None
            out.append(Continuation(nxt.section, 1 if nxt.end == "begin" else -1, node.node_id, way))
        return out

    def switches(self) -> list[Node]:
        return [n for n in self.nodes.values() if n.kind == "point_switch"]

    def item_location(self, kind: str, item_id: str) -> tuple[str, dict] | None:
        """(section id, item) of a piece of equipment by id, None if no section has it."""
        index = getattr(self, "_item_index", None)
        if index is None:
            index = self._item_index = {(k, it["id"]): (sid, it) for sid, sec in self.sections.items()
                                        for k, items in sec.equipment.items() for it in items}
        return index.get((kind, item_id))

    # ---- geometry -------------------------------------------------------------
    def project(self, x: float, y: float) -> tuple[str, float, float]:
        """(section, chainage [m], signed lateral offset [m], + left of increasing chainage) of
        the point of the network nearest the map point (x, y) (Track.project on each section)."""
        best = (math.inf, "", 0.0, 0.0)
        for sid, sec in self.sections.items():
            chain, lateral = sec.project(x, y)
            c, lat = float(chain[0]), float(lateral[0])
            px, py, _ = sec.pose(c)
            d = math.hypot(x - px, y - py)
            if d < best[0]:
                best = (d, sid, c, lat)
        return best[1], best[2], best[3]

    def end_pose(self, end: SectionEnd) -> tuple[float, float, float]:
        """(x, y, outward heading [rad]) of a section end: the heading points from the node into
        the section."""
        sec = self.sections[end.section]
        if end.end == "begin":
            return sec.pose(0.0)
        x, y, h = sec.pose(sec.length)
        return x, y, h + math.pi

    def _check_geometry(self) -> None:
        for node in self.nodes.values():
            ends = list(node.ports.items())
            x0, y0, _ = self.end_pose(ends[0][1])
            for port, end in ends[1:]:
                x, y, _ = self.end_pose(end)
                gap = math.hypot(x - x0, y - y0)
                if gap > JOINT_TOLERANCE:
                    raise NetworkError(f"node {node.node_id}: section end {end} (port {port}) lies {gap:.2f} m from "
                                       f"{ends[0][1]} (port {ends[0][0]}); joined ends must meet within "
                                       f"{JOINT_TOLERANCE} m")
            for port, exits in THROUGH[node.kind].items():
                if port not in node.ports:
                    continue
                for exit_port in exits:
                    if exit_port not in node.ports or (node.kind == "point_switch" and port != "A"):
                        continue
                    h_in = self.end_pose(node.ports[port])[2]
                    h_out = self.end_pose(node.ports[exit_port])[2]
                    bend = abs(_angle(h_out - h_in - math.pi))
                    if bend > HEADING_TOLERANCE:
                        raise NetworkError(f"node {node.node_id}: the route {port}-{exit_port} bends by "
                                           f"{math.degrees(bend):.1f} deg; a through route keeps its heading "
                                           f"(within {math.degrees(HEADING_TOLERANCE):.1f} deg)")

    # ---- loading --------------------------------------------------------------
    @classmethod
    def from_dict(cls, data: dict) -> "Network":
        try:
            network_id = str(data["network_id"])
            entries = data["sections"]
        except KeyError as exc:
            raise NetworkError(f"network description lacks the key {exc}") from None
        if not isinstance(entries, list) or not entries:
            raise NetworkError("network: 'sections' must be a non-empty list of sections")
        raw: dict[str, dict] = {}
        for k, entry in enumerate(entries):
            if not isinstance(entry, dict) or "id" not in entry:
                raise NetworkError(f"network: section {k} is not a mapping with an 'id'")
            sid = str(entry["id"])
            if sid in raw:
                raise NetworkError(f"network: section id {sid!r} is used twice")
            if "/" in sid or not sid:
                raise NetworkError(f"network: section id {sid!r} must be non-empty, without '/'")
            raw[sid] = entry
        nodes = {}
        for k, entry in enumerate(data.get("nodes", []) or []):
            node = _node(k, entry, raw)
            if node.node_id in nodes or node.node_id in raw:
                raise NetworkError(f"network: node id {node.node_id!r} is used twice")
            nodes[node.node_id] = node
        sections = _place_sections(raw, nodes)
        try:
            geodetic = GeodeticAnchor.from_dict(data.get("geodetic"))
        except GeodesyError as exc:
            raise NetworkError(f"network {network_id}: {exc}") from None
        return cls(network_id=network_id, sections=sections, nodes=nodes, geodetic=geodetic,
                   etcs=data.get("etcs") or {})

    @classmethod
    def from_yaml(cls, path: str | Path) -> "Network":
        with open(path, encoding="utf-8") as fh:
            return cls.from_dict(yaml.safe_load(fh))

    @classmethod
    def single(cls, track: Track) -> "Network":
        """A single line as a network of one section."""
        return cls(network_id=track.track_id, sections={track.track_id: track})


def is_network(data) -> bool:
    """Whether a track description (a mapping) describes a network (it has ``sections``)."""
    return isinstance(data, dict) and "sections" in data


def _angle(a: float) -> float:
    """a wrapped into (-pi, pi]."""
    return math.atan2(math.sin(a), math.cos(a))


def _node(k: int, entry, sections: dict) -> Node:
    if not isinstance(entry, dict) or "id" not in entry or "type" not in entry:
        raise NetworkError(f"network: node {k} is not a mapping with 'id' and 'type'")
    node_id, kind = str(entry["id"]), str(entry["type"])
    if kind not in NODE_PORTS:
        raise NetworkError(f"node {node_id}: type {kind!r} is not one of {', '.join(NODE_PORTS)}")
    unknown = set(entry) - {"id", "type", "clearance", *NODE_PORTS[kind]}
    if unknown:
        raise NetworkError(f"node {node_id}: unknown keys {sorted(unknown)}; a {kind} has ports "
                           f"{', '.join(NODE_PORTS[kind])}")
    ports = {}
    for port in NODE_PORTS[kind]:
        if port not in entry:
            raise NetworkError(f"node {node_id}: port {port} is not joined (give it as <section>.begin or "
                               f"<section>.end)")
        ref = str(entry[port])
        sid, _, end = ref.rpartition(".")
        if end not in ENDS or not sid:
            raise NetworkError(f"node {node_id} port {port}: {ref!r} is not <section>.begin or <section>.end")
        if sid not in sections:
            raise NetworkError(f"node {node_id} port {port} names section {sid!r}, which the network does not have")
        ports[port] = SectionEnd(sid, end)
    if len(set(ports.values())) != len(ports):
        raise NetworkError(f"node {node_id}: a section end is joined at two of its ports")
    clearance = float(entry.get("clearance", DEFAULT_CLEARANCE))
    if not 0.0 < clearance < 1000.0:
        raise NetworkError(f"node {node_id}: clearance {clearance} m must lie in 0 .. 1000 m")
    return Node(node_id, kind, ports, clearance)


def _section_track(sid: str, entry: dict, origin: tuple[float, float, float]) -> Track:
    try:
        return Track.from_dict({**{k: v for k, v in entry.items() if k != "id"}, "track_id": sid,
                                "origin": {"x": origin[0], "y": origin[1], "heading": origin[2]}})
    except TrackError as exc:
        raise NetworkError(f"section {sid}: {exc}") from None


def _place_sections(raw: dict[str, dict], nodes: dict[str, Node]) -> dict[str, Track]:
    """Every section as a Track, those without an ``origin`` started at the node their begin is
    joined to, in the order the geometry becomes known."""
    placed: dict[str, Track] = {}
    for sid, entry in raw.items():
        if "origin" in entry:
            o = entry["origin"] or {}
            placed[sid] = _section_track(sid, entry, (float(o.get("x", 0.0)), float(o.get("y", 0.0)),
                                                      float(o.get("heading", 0.0))))
    by_begin = {end.section: (node, port) for node in nodes.values() for port, end in node.ports.items()
                if end.end == "begin"}
    pending = [sid for sid in raw if sid not in placed]
    while pending:
        progress = False
        for sid in list(pending):
            joint = by_begin.get(sid)
            pose = _port_pose(joint, placed) if joint else None
            if pose is None:
                continue
            placed[sid] = _section_track(sid, raw[sid], pose)
            pending.remove(sid)
            progress = True
        if not progress:
            if len(raw) == 1:   # a single section: at the map origin
                sid = pending.pop()
                placed[sid] = _section_track(sid, raw[sid], (0.0, 0.0, 0.0))
                continue
            raise NetworkError(f"section {pending[0]} has no origin, and its begin is joined to no node with a "
                               f"placed section on its through route: give it an origin")
    return {sid: placed[sid] for sid in raw}


def _port_pose(joint: tuple[Node, str], placed: dict[str, Track]) -> tuple[float, float, float] | None:
    """Pose (x, y, outward heading) at ``joint``'s port derived from a placed section on a
    through route of the node (the port's outward heading is that section's inward one)."""
    node, port = joint
    partners = THROUGH[node.kind][port]
    if node.kind == "point_switch" and port != "A":
        partners = ("A",) + tuple(p for p in SWITCH_WAYS if p != port)   # B1 and B2 leave the same way
    for other in partners:
        end = node.ports.get(other)
        if end is None or end.section not in placed:
            continue
        sec = placed[end.section]
        if end.end == "begin":
            x, y, h = sec.pose(0.0)
            outward = h
        else:
            x, y, h = sec.pose(sec.length)
            outward = h + math.pi
        same_side = node.kind == "point_switch" and other in SWITCH_WAYS and port in SWITCH_WAYS
        return x, y, _angle(outward if same_side else outward + math.pi)
    return None

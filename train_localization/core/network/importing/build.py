"""Tracks, junctions and equipment read from a source file -> the project's network (docs/network.md).

The readers (osm.py, railml.py) give what their format says in the map frame of one geodetic
anchor (core/geodesy.py): ``Line`` records (a track between two junctions or ends, as points),
``Junction`` records (what a point where lines meet is called and tagged) and ``Item`` records
(equipment on a line's point, at a chainage of a line, or at a map point near the tracks). This
module makes the network of them:

  * a point where lines end is a node by how many ends meet there: 2 a ``link``, 3 a
    ``point_switch`` (the two legs that leave in the closest directions are B1 and B2, the
    straighter of them B1, the third is A), 4 a ``crossing`` (a junction the source calls one;
    each leg paired with the one most opposite); 1 an end of the network;
  * each line's alignment is fitted through its points (alignment.py), its ends along the
    through route of the node they meet: the bisector of the two legs' directions, the same
    for every leg of a switch, so that the network's geometry checks hold;
  * equipment goes onto the sections at the chainage of its point; an item beside the tracks
    (a signal mast) onto the nearest section, if within ``max_offset``.

What cannot be used is left out with a one-line note (``Imported.notes``); what makes no network
raises TrackImportError in one line.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from ...geodesy import GeodeticAnchor
from ..model import Network, NetworkError
from ..path import ROUTE_KINDS, WAYSIDE_ONLY_KINDS
from .alignment import Fitted, chord_heading, fit, scaled, wrap

EQUIPMENT_KINDS = ROUTE_KINDS + WAYSIDE_ONLY_KINDS
LENGTH_TOLERANCE = 0.01   # a stated length may differ from the geometry's by this fraction


class TrackImportError(ValueError):
    """A source that makes no network, with the reason in one line."""


@dataclass
class Line:
    """A track between two junctions or ends: its id, its points in the map frame [m] (x east,
    y north), the key of each point (None: a plain shape point), and the length the source
    states [m] (None: the geometry's)."""

    line_id: str
    points: list[tuple[float, float]]
    keys: list[str | None]
    length: float | None = None


@dataclass(frozen=True)
class Junction:
    """What the source calls the point ``key``: the node's id, and its kind where the source
    says (``switch``, ``crossing``; None: by the number of ends that meet), for notes its
    ``source`` (e.g. 'OSM node 10')."""

    key: str
    node_id: str
    kind: str | None
    source: str


@dataclass(frozen=True)
class Item:
    """Equipment (``kind``: an equipment kind of docs/network.md, or what the source calls it,
    which is then noted and left out) at a line's point ``key``, at ``chainage`` [m] of
    ``line``, or at the map point ``xy``; ``extra`` keys go into its YAML entry."""

    kind: str
    item_id: str
    source: str
    key: str | None = None
    line: str | None = None
    chainage: float | None = None
    xy: tuple[float, float] | None = None
    extra: dict = field(default_factory=dict)


@dataclass
class Imported:
    """The network (its YAML mapping and the model it loads into) and the notes of what was
    left out."""

    data: dict
    network: Network
    notes: list[str]


@dataclass
class _Leg:
    line: str
    end: str          # "begin" or "end"
    outward: float    # heading leaving the junction along the line [rad]


def _legs(lines: list[Line]) -> dict[str, list[_Leg]]:
    legs: dict[str, list[_Leg]] = {}
    for line in lines:
        p = line.points
        for end, key, out in (("begin", line.keys[0], chord_heading(p[0], p[1])),
                              ("end", line.keys[-1], chord_heading(p[-1], p[-2]))):
            if key is not None:
                legs.setdefault(key, []).append(_Leg(line.line_id, end, out))
    return legs


def _through(a: _Leg, b: _Leg) -> float:
    """Heading of travel from leg ``a`` across the junction into leg ``b``."""
    into = a.outward + math.pi
    return into + 0.5 * wrap(b.outward - into)


def _node(key: str, legs: list[_Leg], junction: Junction | None, notes: list[str],
          headings: dict[tuple[str, str], float]) -> dict | None:
    """The node's YAML entry (None: an end of the network); sets the legs' outward headings."""
    node_id = junction.node_id if junction else f"J{key}"
    where = junction.source if junction else f"the point {key}"
    kind = junction.kind if junction else None
    ports: dict[str, _Leg] = {}
    if len(legs) == 1:
        if kind:
            notes.append(f"{kind} {node_id} ({where}) ends a single track: imported as an end of the network")
        return None
    if len(legs) == 2:
        if kind:
            notes.append(f"{kind} {node_id} ({where}) joins two track ends only: imported as a link")
        ports = {"A": legs[0], "B": legs[1]}
        through = {("A", "B"): _through(legs[0], legs[1])}
        node_type = "link"
    elif len(legs) == 3:
        if kind not in ("switch", None):
            raise TrackImportError(f"{kind} {node_id} ({where}) joins three track ends: only a switch can")
        if kind is None:
            notes.append(f"{where} joins three tracks without being tagged a switch: imported as switch {node_id}")
        pairs = [(i, j) for i in range(3) for j in range(i + 1, 3)]
        i, j = min(pairs, key=lambda ij: abs(wrap(legs[ij[0]].outward - legs[ij[1]].outward)))
        a = legs[3 - i - j]
        b1, b2 = sorted((legs[i], legs[j]), key=lambda b: abs(wrap(b.outward - a.outward - math.pi)))
        ports = {"A": a, "B1": b1, "B2": b2}
        t = _through(a, b1)
        through = {("A", "B1"): t, ("A", "B2"): t}
        node_type = "point_switch"
    elif len(legs) == 4 and kind == "crossing":
        first = legs[0]
        partner = max(legs[1:], key=lambda b: abs(wrap(b.outward - first.outward)))
        rest = [leg for leg in legs[1:] if leg is not partner]
        ports = {"A1": first, "B1": partner, "A2": rest[0], "B2": rest[1]}
        through = {("A1", "B1"): _through(first, partner), ("A2", "B2"): _through(rest[0], rest[1])}
        node_type = "crossing"
    else:
        raise TrackImportError(f"{where} joins {len(legs)} track ends and is no crossing: no node of the network "
                               "(docs/network.md) joins them")
    for (p_in, p_out), heading in through.items():
        headings[(ports[p_in].line, ports[p_in].end)] = heading + math.pi
        headings[(ports[p_out].line, ports[p_out].end)] = heading
    return {"id": node_id, "type": node_type, **{p: f"{leg.line}.{leg.end}" for p, leg in ports.items()}}


def _round(v: float) -> float:
    return round(float(v), 6) + 0.0   # no -0.0 in the YAML


def _fit_line(line: Line, headings: dict, notes: list[str]) -> Fitted:
    begin = headings.get((line.line_id, "begin"))
    end = headings.get((line.line_id, "end"))
    fitted = fit(line.points, begin, None if end is None else end + math.pi)
    if line.length is not None:
        if abs(line.length - fitted.length) > LENGTH_TOLERANCE * line.length:
            notes.append(f"track {line.line_id}: stated length {line.length:.3f} m, its geometry "
                         f"{fitted.length:.3f} m: the stated one is used")
        fitted = scaled(fitted, line.length)
    return fitted


def _section(line: Line, fitted: Fitted) -> dict:
    segments = [{"length": _round(length), "curvature": _round(k)} for length, k in fitted.segments]
    return {"id": line.line_id, "length": _round(sum(s["length"] for s in segments)),
            "origin": {"x": _round(line.points[0][0]), "y": _round(line.points[0][1]),
                       "heading": _round(fitted.heading)},
            "alignment": segments}


def _place(item: Item, at_key: dict, fitted: dict[str, Fitted], network: Network | None,
           max_offset: float) -> tuple[str, float] | str:
    """(section, chainage) of an item, or why it has none."""
    if item.key is not None:
        if item.key not in at_key:
            return "its point lies on no imported track"
        line, k = at_key[item.key]
        return line, fitted[line].chainages[k]
    if item.line is not None:
        if item.line not in fitted:
            return f"its track {item.line} is not imported"
        if not 0.0 <= item.chainage <= fitted[item.line].length + 1e-6:
            return f"at {item.chainage:.3f} m, beyond its track {item.line} (0 .. {fitted[item.line].length:.3f} m)"
        return item.line, min(item.chainage, fitted[item.line].length)
    section, chainage, lateral = network.project(*item.xy)
    if abs(lateral) > max_offset:
        return f"{abs(lateral):.1f} m from the nearest track (more than {max_offset:g} m)"
    return section, chainage


def build(network_id: str, anchor: GeodeticAnchor, lines: list[Line], junctions: dict[str, Junction],
          items: list[Item], notes: list[str] | None = None, max_offset: float = 10.0) -> Imported:
    """The network of what a reader read (module docstring); TrackImportError in one line."""
    notes = list(notes or [])
    if not lines:
        raise TrackImportError("no track to import")
    headings: dict[tuple[str, str], float] = {}
    nodes = []
    for key, legs in _legs(lines).items():
        node = _node(key, legs, junctions.get(key), notes, headings)
        if node is not None:
            nodes.append(node)
    for key, junction in junctions.items():
        if junction.kind and not any(key in line.keys for line in lines):
            notes.append(f"{junction.kind} {junction.node_id} ({junction.source}) lies on no imported track: left out")
    fitted = {line.line_id: _fit_line(line, headings, notes) for line in lines}
    sections = {line.line_id: _section(line, fitted[line.line_id]) for line in lines}
    data = {"network_id": network_id, "geodetic": anchor.to_dict(), "sections": list(sections.values()),
            "nodes": nodes}
    network = _load(data)
    at_key = {}
    for line in lines:
        for k, key in enumerate(line.keys):
            if key is not None:
                at_key.setdefault(key, (line.line_id, k))
    taken: dict[tuple[str, str], str] = {}
    for item in items:
        placed = _place(item, at_key, fitted, network, max_offset)
        if isinstance(placed, str):
            notes.append(f"{item.kind} {item.item_id} ({item.source}): {placed}; left out")
            continue
        section, chainage = placed
        if item.kind not in EQUIPMENT_KINDS:
            notes.append(f"{item.kind} {item.item_id} ({item.source}) at {section} {chainage:.1f} m: no equipment "
                         f"kind of a network holds it ({', '.join(EQUIPMENT_KINDS)}); left out")
            continue
        if (item.kind, item.item_id) in taken:
            notes.append(f"{item.kind} {item.item_id} ({item.source}): the id is {taken[(item.kind, item.item_id)]}'s "
                         "already; left out")
            continue
        taken[(item.kind, item.item_id)] = item.source
        entry = {"id": item.item_id, "position": _round(chainage), **item.extra}
        sections[section].setdefault("equipment", {}).setdefault(item.kind, []).append(entry)
    for sec in sections.values():
        for entries in sec.get("equipment", {}).values():
            entries.sort(key=lambda e: e["position"])
    return Imported(data, _load(data), notes)


def _load(data: dict) -> Network:
    try:
        return Network.from_dict(data)
    except NetworkError as exc:
        raise TrackImportError(f"the imported network does not hold together: {exc}") from None

"""OpenStreetMap railway data (an .osm / .osm.pbf extract, read with osmium) -> a network.

Read, by OpenRailwayMap's tagging:

  ``railway=rail`` ways            the tracks; a way is cut where it meets another way or a
                                   switch, and ways that meet end to end elsewhere are joined
                                   into one section (id ``w<first way id>``, ``_<n>`` for its
                                   further pieces)
  ``railway=switch`` nodes         the switches (id: ``ref``, else ``n<node id>``); three tracks
                                   meeting untagged are a switch too (noted)
  ``railway=railway_crossing``     a crossing (a diamond) of two tracks
  ``railway=balise``               Eurobalises (id ``ref``), where mapped
  ``railway=train_detection`` with ``railway:train_detection=axle_counter``: axle-counter heads
  ``railway=signal``               signals: no equipment kind of a network holds them (noted with
                                   their place)
  ``railway:position``             the line kilometre of a balise or detection point, kept as
                                   ``line_km`` [km]

The geodetic anchor is the middle of the file's bounds (else of its rail nodes), rounded to
1e-5 deg, unless given; every node is projected around it (core/geodesy.py, pyproj) and the
chainage is the length of the fitted alignment (alignment.py). Equipment on a way's node lies
at that node's chainage, equipment beside the track is projected onto the nearest section.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import osmium

from ...geodesy import GeodeticAnchor
from .build import Imported, Item, Junction, Line, TrackImportError, build

ITEM_TAGS = {"balise": "eurobalise", "signal": "signal"}


@dataclass
class _Read:
    ways: list[tuple[int, list[int]]] = field(default_factory=list)   # rail ways: id, node ids
    where: dict[int, tuple[float, float]] = field(default_factory=dict)   # node id -> (lat, lon)
    tagged: dict[int, dict] = field(default_factory=dict)              # railway nodes -> their tags
    skipped: int = 0                                                   # ways without usable nodes


class _Handler(osmium.SimpleHandler):
    def __init__(self, read: _Read):
        super().__init__()
        self.read = read

    def node(self, n):
        if "railway" in n.tags:
            self.read.tagged[n.id] = dict(n.tags)
            if n.location.valid():
                self.read.where[n.id] = (n.location.lat, n.location.lon)

    def way(self, w):
        if w.tags.get("railway") != "rail":
            return
        refs = []
        for nd in w.nodes:
            if not nd.location.valid():
                self.read.skipped += 1
                return
            self.read.where[nd.ref] = (nd.location.lat, nd.location.lon)
            refs.append(nd.ref)
        if len(refs) >= 2:
            self.read.ways.append((w.id, refs))


def _anchor(path: Path, read: _Read, nodes: set[int]) -> GeodeticAnchor:
    box = osmium.io.Reader(str(path)).header().box()
    if box.valid():
        lat = 0.5 * (box.bottom_left.lat + box.top_right.lat)
        lon = 0.5 * (box.bottom_left.lon + box.top_right.lon)
    else:
        lat = sum(read.where[n][0] for n in nodes) / len(nodes)
        lon = sum(read.where[n][1] for n in nodes) / len(nodes)
    return GeodeticAnchor(round(lat, 5), round(lon, 5))


def _pieces(read: _Read) -> list[tuple[str, list[int]]]:
    """The ways cut at every node another way shares or a switch or crossing is: (id, nodes)."""
    uses: dict[int, int] = {}
    for _, refs in read.ways:
        for k, ref in enumerate(refs):
            uses[ref] = uses.get(ref, 0) + (1 if k in (0, len(refs) - 1) else 2)
    cut = {ref for ref, n in uses.items() if n != 2}
    cut |= {ref for ref, tags in read.tagged.items() if tags.get("railway") in ("switch", "railway_crossing")}
    out = []
    for way_id, refs in read.ways:
        start, n = 0, 0
        for k in range(1, len(refs)):
            if refs[k] in cut or k == len(refs) - 1:
                out.append((f"w{way_id}" + (f"_{n}" if n else ""), refs[start:k + 1]))
                start, n = k, n + 1
    return out


def _chains(pieces: list[tuple[str, list[int]]], junction: set[int]) -> list[tuple[str, list[int]]]:
    """Pieces that meet end to end at a point that is no junction joined into one."""
    at: dict[int, list[int]] = {}
    for k, (_, refs) in enumerate(pieces):
        for ref in (refs[0], refs[-1]):
            at.setdefault(ref, []).append(k)
    done, out = set(), []
    for k, (pid, refs) in enumerate(pieces):
        if k in done or (refs[0] not in junction and refs[-1] not in junction):
            continue   # a middle piece: reached from a chain's start
        if refs[0] not in junction:
            refs = refs[::-1]
        done.add(k)
        chain = list(refs)
        while chain[-1] not in junction:
            nxt = [j for j in at[chain[-1]] if j not in done]
            if not nxt:
                break
            j = nxt[0]
            done.add(j)
            more = pieces[j][1]
            chain += (more if more[0] == chain[-1] else more[::-1])[1:]
        out.append((pid, chain))
    rings = [pid for k, (pid, _) in enumerate(pieces) if k not in done]
    if rings:
        raise TrackImportError(f"way piece {rings[0]} is part of a closed ring of track without a junction: a "
                               "network needs an end or a switch on it")
    return out


def read_osm(path: str | Path, anchor: GeodeticAnchor | None = None, network_id: str | None = None) -> Imported:
    """The network of an OSM file (module docstring); TrackImportError in one line."""
    path = Path(path)
    read = _Read()
    try:
        _Handler(read).apply_file(str(path), locations=True)
    except (RuntimeError, OSError) as exc:
        raise TrackImportError(f"{path}: not an OSM file osmium reads ({str(exc).splitlines()[0]})") from None
    if not read.ways:
        raise TrackImportError(f"{path}: no railway=rail way with its nodes")
    notes = [f"{read.skipped} railway=rail ways without all their nodes: left out"] if read.skipped else []
    rail_nodes = {ref for _, refs in read.ways for ref in refs}
    anchor = anchor or _anchor(path, read, rail_nodes)
    proj = anchor.projection()
    xy = {ref: proj.to_map(*read.where[ref]) for ref in rail_nodes}
    pieces = _pieces(read)
    ends: dict[int, int] = {}
    for _, refs in pieces:
        for ref in (refs[0], refs[-1]):
            ends[ref] = ends.get(ref, 0) + 1
    switchy = {ref for ref, tags in read.tagged.items() if tags.get("railway") in ("switch", "railway_crossing")}
    junction_refs = {ref for ref, n in ends.items() if n != 2} | (switchy & rail_nodes)
    lines = [Line(pid, [xy[r] for r in refs], [str(r) for r in refs]) for pid, refs in _chains(pieces, junction_refs)]
    junctions = {}
    for ref in junction_refs | switchy:
        tags = read.tagged.get(ref, {})
        kind = {"switch": "switch", "railway_crossing": "crossing"}.get(tags.get("railway"))
        name = tags.get("ref") or f"n{ref}"
        junctions[str(ref)] = Junction(str(ref), name, kind, f"OSM node {ref}")
    items = []
    for ref, tags in read.tagged.items():
        kind = ITEM_TAGS.get(tags.get("railway"))
        if tags.get("railway") == "train_detection" and tags.get("railway:train_detection") == "axle_counter":
            kind = "axle_counter_head"
        if kind is None or ref not in read.where:
            continue
        extra = {}
        if "railway:position" in tags:
            try:
                extra["line_km"] = float(tags["railway:position"].replace(",", "."))
            except ValueError:
                notes.append(f"OSM node {ref}: railway:position {tags['railway:position']!r} is no kilometre; "
                             "left out")
        on_way = ref in rail_nodes
        items.append(Item(kind, tags.get("ref") or f"n{ref}", f"OSM node {ref}", key=str(ref) if on_way else None,
                          xy=None if on_way else proj.to_map(*read.where[ref]), extra=extra))
    return build(network_id or path.name.split(".")[0], anchor, lines, junctions, items, notes)

"""A railML 3 infrastructure (read with lxml) -> a network.

Read (any railML 3.x namespace; elements by their local names):

  ``topology/netElements/netElement``   the micro-level tracks (those with a ``length`` or a
        geometry; aggregates of others are skipped): ``length`` [m] the section's length,
        ``associatedPositioningSystem/intrinsicCoordinate`` (``intrinsicCoord`` 0 .. 1) with
        its ``geometricCoordinate`` (``x``, ``y`` in the CRS of its ``positioningSystemRef``:
        ``common/positioning/geometricPositioningSystems/geometricPositioningSystem``
        ``crsDefinition``, EPSG:4326 when not given; x easting / longitude first) the shape
  ``topology/netRelations/netRelation``  ``positionOnA`` / ``positionOnB`` (0 begin, 1 end)
        of ``elementA`` / ``elementB``: the ends that meet; ends that meet form a node
        (build.py: 2 a link, 3 a switch, 4 a crossing)
  ``functionalInfrastructure``: ``switchesIS/switchIS`` and ``crossings/crossing`` name the
        node at their ``spotLocation``; ``balises/balise`` (its group by
        ``belongsToBaliseGroup``, kept as ``group``) and ``baliseGroups/baliseGroup`` without
        balises of their own are Eurobalises; ``trainDetectionElements/trainDetectionElement``
        of ``type`` axleCounter are axle-counter heads; ``signalsIS/signalIS`` are noted (no
        equipment kind of a network holds them); an item's chainage is its spotLocation's
        ``pos`` [m], else ``intrinsicCoord`` x length; its id the ``name`` child's, else its id

The geodetic anchor is the middle of the coordinates' extent, rounded to 1e-5 deg, unless given.
"""
from __future__ import annotations

from pathlib import Path

from lxml import etree
from pyproj import CRS, Transformer
from pyproj.exceptions import CRSError

from ...geodesy import GeodeticAnchor
from .build import Imported, Item, Junction, Line, TrackImportError, build

WGS84 = "EPSG:4326"
DETECTION_KINDS = {"axleCounter": "axle_counter_head"}


def _all(root, name: str) -> list:
    return root.xpath(f".//*[local-name()='{name}']")


def _child(el, name: str):
    found = el.xpath(f"./*[local-name()='{name}']")
    return found[0] if found else None


def _name(el) -> str:
    n = _child(el, "name")
    return n.get("name") if n is not None and n.get("name") else el.get("id")


def _float(el, attr: str, what: str) -> float:
    try:
        return float(el.get(attr))
    except (TypeError, ValueError):
        raise TrackImportError(f"{what}: attribute {attr}={el.get(attr)!r} is no number") from None


def _shape(ne, systems: dict[str, Transformer]) -> list[tuple[float, float, float]]:
    """(intrinsic coordinate, latitude, longitude) of a netElement's geometry, in order."""
    out = []
    for ic in ne.xpath("./*[local-name()='associatedPositioningSystem']/*[local-name()='intrinsicCoordinate']"):
        gc = _child(ic, "geometricCoordinate")
        if gc is None:
            continue
        ref = gc.get("positioningSystemRef")
        to_wgs84 = systems.get(ref) or systems[WGS84]
        lon, lat = to_wgs84.transform(_float(gc, "x", f"netElement {ne.get('id')}"),
                                      _float(gc, "y", f"netElement {ne.get('id')}"))
        out.append((_float(ic, "intrinsicCoord", f"netElement {ne.get('id')}"), lat, lon))
    return sorted(out)


def _systems(root) -> dict[str, Transformer]:
    out = {WGS84: Transformer.from_crs(WGS84, WGS84, always_xy=True)}
    for gps in _all(root, "geometricPositioningSystem"):
        crs = gps.get("crsDefinition") or WGS84
        try:
            out[gps.get("id")] = Transformer.from_crs(CRS.from_user_input(crs), WGS84, always_xy=True)
        except CRSError:
            raise TrackImportError(f"geometricPositioningSystem {gps.get('id')}: CRS {crs!r} unknown to pyproj") from None
    return out


def _ends(root, elements: set[str]) -> dict[str, str]:
    """Each netElement end that meets another ('<id>@0' / '<id>@1') -> the key of the point they share."""
    parent: dict[str, str] = {}

    def find(k: str) -> str:
        while parent.setdefault(k, k) != k:
            k = parent[k]
        return k
    for nr in _all(root, "netRelation"):
        a, b = _child(nr, "elementA"), _child(nr, "elementB")
        if a is None or b is None or a.get("ref") not in elements or b.get("ref") not in elements:
            continue
        ka = f"{a.get('ref')}@{int(_float(nr, 'positionOnA', 'netRelation ' + nr.get('id', '')))}"
        kb = f"{b.get('ref')}@{int(_float(nr, 'positionOnB', 'netRelation ' + nr.get('id', '')))}"
        parent[find(ka)] = find(kb)
    return {k: find(k) for k in parent}


def _spot(el) -> tuple[str, float | None, float | None] | None:
    s = _child(el, "spotLocation")
    if s is None or not s.get("netElementRef"):
        return None
    pos = float(s.get("pos")) if s.get("pos") is not None else None
    coord = float(s.get("intrinsicCoord")) if s.get("intrinsicCoord") is not None else None
    return s.get("netElementRef"), pos, coord


def read_railml(path: str | Path, anchor: GeodeticAnchor | None = None, network_id: str | None = None) -> Imported:
    """The network of a railML 3 file (module docstring); TrackImportError in one line."""
    path = Path(path)
    try:
        root = etree.parse(str(path)).getroot()
    except (OSError, etree.XMLSyntaxError) as exc:
        raise TrackImportError(f"{path}: not XML lxml reads ({str(exc).splitlines()[0]})") from None
    if etree.QName(root).localname.lower() != "railml" or not str(root.get("version", "3")).startswith("3"):
        raise TrackImportError(f"{path}: no railML 3 document (root {etree.QName(root).localname!r}, version "
                               f"{root.get('version')!r})")
    systems = _systems(root)
    notes: list[str] = []
    shapes, lengths = {}, {}
    for ne in _all(root, "netElement"):
        if _child(ne, "elementCollectionUnordered") is not None or _child(ne, "elementCollectionOrdered") is not None:
            continue   # a meso or macro element: an aggregate of micro ones
        ne_id = ne.get("id")
        shape = _shape(ne, systems)
        if len(shape) < 2:
            raise TrackImportError(f"netElement {ne_id}: {len(shape)} geometric coordinates; placing it needs its "
                                   "two ends' at least")
        if shape[0][0] != 0.0 or shape[-1][0] != 1.0:
            raise TrackImportError(f"netElement {ne_id}: its geometry runs from intrinsicCoord {shape[0][0]:g} to "
                                   f"{shape[-1][0]:g}, not 0 to 1")
        shapes[ne_id] = shape
        lengths[ne_id] = _float(ne, "length", f"netElement {ne_id}") if ne.get("length") is not None else None
    if not shapes:
        raise TrackImportError(f"{path}: no netElement with a geometry")
    if anchor is None:
        lats = [p[1] for s in shapes.values() for p in s]
        lons = [p[2] for s in shapes.values() for p in s]
        anchor = GeodeticAnchor(round(0.5 * (min(lats) + max(lats)), 5), round(0.5 * (min(lons) + max(lons)), 5))
    proj = anchor.projection()
    ends = _ends(root, set(shapes))
    lines = []
    for ne_id, shape in shapes.items():
        keys = [ends.get(f"{ne_id}@0", f"{ne_id}@0")] + [None] * (len(shape) - 2) + \
               [ends.get(f"{ne_id}@1", f"{ne_id}@1")]
        lines.append(Line(ne_id, [proj.to_map(lat, lon) for _, lat, lon in shape], keys, lengths[ne_id]))
    junctions = {}
    for kind, tag in (("switch", "switchIS"), ("crossing", "crossing")):
        for el in _all(root, tag):
            spot = _spot(el)
            if spot is None or spot[0] not in shapes:
                notes.append(f"{tag} {el.get('id')}: no spotLocation on an imported netElement; left out")
                continue
            coord = spot[2] if spot[2] is not None else (0.0 if not spot[1] else 1.0)
            key = f"{spot[0]}@{int(round(coord))}"
            key = ends.get(key, key)
            junctions[key] = Junction(key, _name(el), kind, f"railML {tag} {el.get('id')}")
    for k, key in enumerate(sorted(set(ends.values()) - set(junctions))):
        junctions[key] = Junction(key, f"J{k + 1}", None, f"railML netRelations at {key}")
    items = []
    grouped = set()
    for el in _all(root, "balise"):
        group = _child(el, "belongsToBaliseGroup")
        extra = {"group": group.get("ref")} if group is not None else {}
        grouped |= set(extra.values())
        items.append(_item(el, "eurobalise", "balise", lengths, extra, notes))
    items += [_item(el, "eurobalise", "baliseGroup", lengths, {}, notes)
              for el in _all(root, "baliseGroup") if el.get("id") not in grouped]
    for el in _all(root, "trainDetectionElement"):
        kind = DETECTION_KINDS.get(el.get("type"), f"trainDetectionElement of type {el.get('type')}")
        items.append(_item(el, kind, "trainDetectionElement", lengths, {}, notes))
    items += [_item(el, "signal", "signalIS", lengths, {}, notes) for el in _all(root, "signalIS")]
    return build(network_id or path.name.split(".")[0], anchor, lines, junctions,
                 [i for i in items if i is not None], notes)


def _item(el, kind: str, tag: str, lengths: dict, extra: dict, notes: list[str]) -> Item | None:
    source = f"railML {tag} {el.get('id')}"
    spot = _spot(el)
    if spot is None:
        notes.append(f"{source}: no spotLocation; left out")
        return None
    ne_id, pos, coord = spot
    if pos is None and (coord is None or lengths.get(ne_id) is None):
        notes.append(f"{source}: neither pos nor intrinsicCoord on a netElement of known length; left out")
        return None
    chainage = pos if pos is not None else coord * lengths[ne_id]
    return Item(kind, _name(el), source, line=ne_id, chainage=chainage, extra=extra)

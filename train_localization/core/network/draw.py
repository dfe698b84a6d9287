"""Random track networks for the campaign family ``network`` (core/campaign.py).

``draw_network`` lays out a station throat in a local frame in which every track runs
along +x, then turns it to a random heading and states it in the YAML form of model.py:

  tracks     a main track A (y = 0) from the left end of the network, in 60 % of the
             networks a parallel track B 4.0-5.0 m to one side from the left end too
             (a double-track line); further tracks come from turnouts
  elements   2-5 switches, placed one after the other along x at drawn gaps:
               crossover  an S-curve of two arcs (radius 150-500 m) from a track to the
                          adjacent one (lateral offset 2R(1 - cos theta)): a facing switch
                          on the track it leaves, a trailing one on the track it joins
               turnout    a facing switch on an outermost track and an S-curve to a new
                          track 4.0-5.0 m further out (a platform or third track)
               rejoin     an outermost track created by a turnout runs back into its
                          neighbour by an S-curve (a passing loop; a trailing switch)
               junction   a facing switch on an outermost track and a branch that curves
                          away (radius 300-1000 m, 8.6-28.6 deg) to an end of the network;
                          no track is added on that side after it
  sections   the tracks cut at the switches (the curve into or out of a turnout's track is
             part of that track's first or last section), the crossovers and the junction
             branches; a quarter of them with their chainage the other way round (their
             route runs along them backwards); B1 and B2 of a switch are either way
  equipment  balise groups of two balises 3 m apart (ids unique over the network) on the
             straight part of 70 % of the track sections and junction branches, a drawn
             spacing apart; 0-3 structures (tunnel, bridge, building) over every track
             section they span (DGPS outages and multipath); none on the crossovers
  clearance  of each switch, the distance from its point at which the track centres are
             CLEARANCE_OFFSET apart, from the curve's geometry, within CLEARANCE_LIMITS

Every route runs from the start track's first section (where the train stands) in +x to
an end of the network: each is at least ``ahead`` metres long from the start. The random
draws come from the campaign's ``Draw`` (``d``: ``u``, ``chance``, ``int``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from .model import Network, NetworkError
from .path import TrackPath

TRACK_SPACING = (4.0, 5.0)        # [m] between the centres of parallel tracks
CURVE_RADIUS = (150.0, 500.0)     # [m] of the arcs of crossovers and turnouts
JUNCTION_RADIUS = (300.0, 1000.0)  # [m] of a junction's branch
JUNCTION_TURN = (0.15, 0.5)       # [rad] the branch turns away through
CLEARANCE_OFFSET = 3.5            # [m] track centres this far apart at a switch's clearance point
CLEARANCE_LIMITS = (20.0, 80.0)   # [m] of the clearance
SWITCHES = (2, 5)
P_DOUBLE_TRACK = 0.6
P_REVERSED = 0.25                 # a section's chainage against the direction of the routes
P_NO_BALISES = 0.3                # a track section without balises
BALISE_SPACING = (100.0, 600.0)   # [m] between balise groups (one draw per network)
STRUCTURES = {"building": (40.0, 150.0), "bridge": (10.0, 30.0), "tunnel": (100.0, 400.0)}
WEIGHTS = {"crossover": 3.0, "turnout": 2.0, "junction": 1.0, "rejoin": 1.0}


def _r(x: float) -> float:
    """A float with 10 significant digits (readable YAML; the joints stay far within tolerance)."""
    return float(f"{float(x):.10g}")


def s_curve(offset: float, radius: float) -> tuple[float, float, float]:
    """(turn angle theta [rad], extent along the tracks [m], length [m]) of an S-curve of two
    arcs of ``radius`` that moves a track sideways by ``offset`` = 2R(1 - cos theta)."""
    theta = math.acos(1.0 - abs(offset) / (2.0 * radius))
    return theta, 2.0 * radius * math.sin(theta), 2.0 * radius * theta


def s_curve_clearance(offset: float, radius: float) -> float:
    """Distance along an S-curve from its switch point to where it is CLEARANCE_OFFSET from the
    track it left (on its second arc: offset - R(1 - cos phi) = CLEARANCE_OFFSET), in the limits."""
    theta, _, length = s_curve(offset, radius)
    rest = abs(offset) - CLEARANCE_OFFSET
    if rest <= 0.0:
        return _clamp(length)
    return _clamp(length - radius * math.acos(1.0 - rest / radius))


def arc_clearance(radius: float, turn: float) -> float:
    """The same for a branch that turns through ``turn`` on an arc of ``radius`` and then runs
    straight."""
    if radius * (1.0 - math.cos(turn)) >= CLEARANCE_OFFSET:
        return _clamp(radius * math.acos(1.0 - CLEARANCE_OFFSET / radius))
    lateral = radius * (1.0 - math.cos(turn))
    return _clamp(radius * turn + (CLEARANCE_OFFSET - lateral) / math.sin(turn))


def _clamp(x: float) -> float:
    return _r(min(max(x, CLEARANCE_LIMITS[0]), CLEARANCE_LIMITS[1]))


def _end_pose(pose: tuple[float, float, float], alignment: list[tuple[float, float]]) -> tuple[float, float, float]:
    """Pose at the end of an alignment of (length, curvature) segments from ``pose`` (exact arcs)."""
    x, y, h = pose
    for length, k in alignment:
        if k == 0.0:
            x, y = x + length * math.cos(h), y + length * math.sin(h)
        else:
            h1 = h + k * length
            x, y, h = x + (math.sin(h1) - math.sin(h)) / k, y + (math.cos(h) - math.cos(h1)) / k, h1
    return x, y, h


@dataclass
class _Track:
    name: str
    y: float
    x0: float                      # start of its straight part
    x1: float = math.nan           # end of its straight part
    head: tuple | None = None      # (alignment, start pose) of the S-curve into its first section
    tail: list | None = None       # alignment of the S-curve out of its last section
    cuts: list = field(default_factory=list)   # x of the switches on its straight part


@dataclass
class _Section:
    sid: str
    length: float
    alignment: list                # (length, curvature)
    pose: tuple                    # (x, y, heading) at its begin in the local frame
    straight: tuple | None         # (chainage from, chainage to, x at from) of its straight part
    equipment: dict = field(default_factory=dict)
    reversed: bool = False


@dataclass
class DrawnNetwork:
    """A drawn network (``network``: the YAML form of model.py), the routes a train standing on
    ``start_section`` at ``start_chainage`` (its own chainage) can take in ``start_direction``
    (lists of section ids, each run to an end of the network), what was drawn (``shape``) and
    the Network of the description (``model``)."""

    network: dict
    routes: list[list[str]]
    start_section: str
    start_direction: int
    start_chainage: float
    shape: dict
    model: Network


class _Layout:
    """The local-frame layout while it is drawn (module docstring)."""

    def __init__(self, d):
        self.d = d
        self.tracks: dict[str, _Track] = {}
        self.nodes: dict[str, dict] = {}        # node -> track, x, role, branch, clearance
        self.connections: dict[str, dict] = {}  # section id -> alignment, pose, length, straight
        self.active: list[str] = []
        self.closed: set[int] = set()           # sides a junction left on
        self.elements: list[str] = []
        self.radii: list[float] = []

    def add_track(self, y: float, x0: float, head=None) -> str:
        name = "ABCDEFGH"[len(self.tracks)]
        self.tracks[name] = _Track(name, y, x0, head=head)
        self.active.append(name)
        return name

    def node(self, track: str, x: float, role: str, branch: tuple, clearance: float) -> str:
        nid = f"W{len(self.nodes) + 1}"
        self.nodes[nid] = {"track": track, "x": x, "role": role, "branch": branch, "clearance": clearance}
        self.tracks[track].cuts.append(x)
        return nid

    def options(self, first: str | None) -> list[tuple]:
        """(kind, ...) of every element that fits the tracks at the cursor; ``first``: only those
        that leave that track (a facing switch on the start track)."""
        by_y = sorted(self.active, key=lambda n: self.tracks[n].y)
        outer = {-1: by_y[0], 1: by_y[-1]}
        out = []
        for a, b in zip(by_y, by_y[1:]):
            out += [("crossover", a, b), ("crossover", b, a)]
        for side in (-1, 1):
            if side in self.closed:
                continue
            if len(self.active) < 4:
                out.append(("turnout", outer[side], side))
            out.append(("junction", outer[side], side))
            t = self.tracks[outer[side]]
            if t.head is not None and len(by_y) >= 2 and not first:
                inner = by_y[1] if side < 0 else by_y[-2]
                out.append(("rejoin", outer[side], inner))
        if first is not None:
            out = [o for o in out if o[1] == first and o[0] != "rejoin"]
        return out

    def place(self, option: tuple, x: float) -> float:
        """Place an element (one of ``options``) at x; returns the x where its curves end."""
        d, kind = self.d, option[0]
        if kind == "crossover":
            src, dst = self.tracks[option[1]], self.tracks[option[2]]
            offset, radius = dst.y - src.y, d.u(*CURVE_RADIUS)
            theta, extent, _ = s_curve(offset, radius)
            sid = f"X{sum(k.startswith('X') for k in self.connections) + 1}"
            k = math.copysign(1.0 / radius, offset)
            self.connections[sid] = {"alignment": [(radius * theta, k), (radius * theta, -k)],
                                     "pose": (x, src.y, 0.0), "straight": None}
            clearance = s_curve_clearance(offset, radius)
            self.node(src.name, x, "diverge", (sid, "begin"), clearance)
            self.node(dst.name, x + extent, "merge", (sid, "end"), clearance)
            self.radii.append(radius)
            return x + extent
        if kind == "turnout":
            src, side = self.tracks[option[1]], option[2]
            offset, radius = side * d.u(*TRACK_SPACING), d.u(*CURVE_RADIUS)
            theta, extent, _ = s_curve(offset, radius)
            k = math.copysign(1.0 / radius, offset)
            name = self.add_track(src.y + offset, x + extent,
                                  head=([(radius * theta, k), (radius * theta, -k)], (x, src.y, 0.0)))
            self.node(src.name, x, "diverge", ("first", name), s_curve_clearance(offset, radius))
            self.radii.append(radius)
            return x + extent
        if kind == "junction":
            src, side = self.tracks[option[1]], option[2]
            radius, turn = d.u(*JUNCTION_RADIUS), d.u(*JUNCTION_TURN)
            sid = f"J{sum(k.startswith('J') for k in self.connections) + 1}"
            self.connections[sid] = {"alignment": [(radius * turn, side / radius)], "pose": (x, src.y, 0.0),
                                     "straight": radius * turn, "junction": True}
            self.node(src.name, x, "diverge", (sid, "begin"), arc_clearance(radius, turn))
            self.closed.add(side)
            return x + radius * math.sin(turn)
        # rejoin: the outermost track back into its neighbour
        t, into = self.tracks[option[1]], self.tracks[option[2]]
        offset, radius = into.y - t.y, d.u(*CURVE_RADIUS)
        theta, extent, _ = s_curve(offset, radius)
        k = math.copysign(1.0 / radius, offset)
        t.x1, t.tail = x, [(radius * theta, k), (radius * theta, -k)]
        self.node(into.name, x + extent, "merge", ("last", t.name), s_curve_clearance(offset, radius))
        self.active.remove(t.name)
        self.radii.append(radius)
        return x + extent

    def sections(self) -> tuple[dict[str, _Section], dict[str, dict]]:
        """The sections (track pieces and connections) and the nodes' ports."""
        out: dict[str, _Section] = {}
        pieces: dict[str, list[str]] = {}
        for t in self.tracks.values():
            bounds = [t.x0] + sorted(t.cuts) + [t.x1]
            pieces[t.name] = []
            for i, (a, b) in enumerate(zip(bounds, bounds[1:])):
                sid = f"T{t.name}{i + 1}"
                head = t.head if i == 0 and t.head else None
                tail = t.tail if i == len(bounds) - 2 and t.tail else None
                alignment = (list(head[0]) if head else []) + [(b - a, 0.0)] + (list(tail) if tail else [])
                pose = head[1] if head else (a, t.y, 0.0)
                off = sum(seg[0] for seg in head[0]) if head else 0.0
                out[sid] = _Section(sid, sum(seg[0] for seg in alignment), alignment, pose, (off, off + b - a, a))
                pieces[t.name].append(sid)
        for sid, c in self.connections.items():
            straight = None
            if c.get("junction"):
                start = c["straight"]
                straight = (start, start + c["alignment"][-1][0], None)
            out[sid] = _Section(sid, sum(seg[0] for seg in c["alignment"]), list(c["alignment"]), c["pose"], straight)
        ports = {}
        for nid, n in self.nodes.items():
            t = self.tracks[n["track"]]
            j = sorted(t.cuts).index(n["x"]) + 1      # piece j starts at the node, piece j - 1 ends there
            left, right = pieces[t.name][j - 1], pieces[t.name][j]
            ref, end = n["branch"]
            if ref == "first":
                ref, end = pieces[end][0], "begin"
            elif ref == "last":
                ref, end = pieces[end][-1], "end"
            if n["role"] == "diverge":
                a, ways = (left, "end"), [(right, "begin"), (ref, end)]
            else:
                a, ways = (right, "begin"), [(left, "end"), (ref, end)]
            if self.d.chance(0.5):
                ways.reverse()
            ports[nid] = {"A": a, "B1": ways[0], "B2": ways[1], "clearance": n["clearance"]}
        return out, ports


def _balises(d, sections: dict[str, _Section], spacing: float) -> int:
    """Balise groups (two balises 3 m apart) on the straight parts; returns the number of groups."""
    n = 0
    for sec in sections.values():
        if sec.straight is None or d.chance(P_NO_BALISES):
            continue
        a, b = sec.straight[0] + 5.0, sec.straight[1] - 8.0
        s = a + d.u(0.0, spacing)
        items = []
        while s <= b:
            items += [{"id": f"G{n:03d}a", "position": _r(s), "group": f"G{n:03d}"},
                      {"id": f"G{n:03d}b", "position": _r(s + 3.0), "group": f"G{n:03d}"}]
            n += 1
            s += spacing * d.u(0.75, 1.25)
        if items:
            sec.equipment["eurobalise"] = items
    return n


def _structures(d, sections: dict[str, _Section], lo: float, hi: float) -> list[str]:
    """0-3 structures over the x range lo..hi (none overlapping), on every track section they span."""
    drawn = []
    for _ in range(d.int(0, 3)):
        kind = tuple(STRUCTURES)[d.int(0, len(STRUCTURES) - 1)]
        x0 = d.u(lo, hi)
        drawn.append((x0, x0 + d.u(*STRUCTURES[kind]), kind))
    drawn.sort()
    kept = []
    for st in drawn:
        if not kept or st[0] > kept[-1][1] + 1.0:
            kept.append(st)
    for n, (x0, x1, kind) in enumerate(kept):
        for sec in sections.values():
            if sec.straight is None or sec.straight[2] is None:
                continue
            c0, c1, xa = sec.straight
            a, b = max(x0, xa), min(x1, xa + c1 - c0)
            if b - a >= 1.0:
                sec.equipment.setdefault("structure", []).append(
                    {"id": f"ST{n}{sec.sid}", "type": kind, "start": _r(c0 + a - xa),
                     "end": _r(min(c0 + b - xa, sec.length))})
    return [k for _, _, k in kept]


def _reverse(sec: _Section) -> None:
    """The section described from its other end: alignment reversed, equipment mirrored."""
    sec.pose = _end_pose(sec.pose, sec.alignment)
    sec.pose = (sec.pose[0], sec.pose[1], sec.pose[2] + math.pi)
    sec.alignment = [(ln, -k) for ln, k in reversed(sec.alignment)]
    for kind, items in sec.equipment.items():
        for it in items:
            if "end" in it:
                it["start"], it["end"] = _r(max(sec.length - it["end"], 0.0)), _r(min(sec.length - it["start"],
                                                                                     sec.length))
            else:
                it["position"] = _r(sec.length - it["position"])
        items.sort(key=lambda it: it.get("start", it.get("position")))
    sec.reversed = True


def draw_network(d, network_id: str, start: float, ahead: float, reach: float) -> DrawnNetwork:
    """A random station throat (module docstring) whose start track's first section holds the
    train's start ``start`` [m] from the left end of the network, with every route at least
    ``ahead`` [m] long from there; ``reach`` [m]: how far the run takes the train (the first
    switch and the gaps between the elements are drawn within it)."""
    lay = _Layout(d)
    lay.add_track(0.0, 0.0)
    if d.chance(P_DOUBLE_TRACK):
        lay.add_track((1 if d.chance(0.5) else -1) * d.u(*TRACK_SPACING), 0.0)
    start_track = "A" if len(lay.active) == 1 or d.chance(0.6) else "B"
    gap_hi = max(40.0, min(400.0, 0.2 * reach))
    x = start + d.u(0.05, 0.3) * reach + 10.0
    budget, first = d.int(*SWITCHES), True
    while budget > 0:
        options = [o for o in lay.options(start_track if first else None)
                   if o[0] != "crossover" or budget >= 2]
        if not options:
            break
        weights = [WEIGHTS[o[0]] for o in options]
        pick = d.u(0.0, sum(weights))
        k = 0
        while k < len(options) - 1 and pick > sum(weights[:k + 1]):
            k += 1
        before = len(lay.nodes)
        end = lay.place(options[k], x)
        budget -= len(lay.nodes) - before
        lay.elements.append(options[k][0])
        first = False
        x = end + max(n["clearance"] for n in list(lay.nodes.values())[before:]) + d.u(20.0, gap_hi)
    x_end = max(x + d.u(50.0, 300.0), start + ahead + 10.0)
    for name in lay.active:
        lay.tracks[name].x1 = x_end
    for c in lay.connections.values():   # junction branches reach as far as every route must
        if c.get("junction"):
            c["alignment"].append((max(100.0, start + ahead - c["pose"][0]) + d.u(0.0, 200.0), 0.0))
    sections, ports = lay.sections()
    groups = _balises(d, sections, d.u(*BALISE_SPACING))
    structures = _structures(d, sections, max(start - 100.0, 0.0), start + reach)
    for sec in sections.values():
        if d.chance(P_REVERSED):
            _reverse(sec)
    heading = d.u(-math.pi, math.pi)
    network = _describe(network_id, sections, ports, heading)
    first_section = sections[f"T{start_track}1"]
    direction = -1 if first_section.reversed else 1
    chainage = _r(first_section.length - start if first_section.reversed else start)
    net = _validated(network, sections, heading)
    routes = _routes(net, first_section.sid, direction)
    shape = {"tracks": len(lay.tracks), "double_track": "B" in lay.tracks and lay.tracks["B"].head is None,
             "elements": lay.elements, "switches": len(lay.nodes), "sections": len(sections),
             "reversed_sections": sum(s.reversed for s in sections.values()), "balise_groups": groups,
             "structures": structures, "radii": [_r(r) for r in lay.radii], "routes": len(routes),
             "start_track": start_track}
    return DrawnNetwork(network, routes, first_section.sid, direction, chainage, shape, net)


def _turned(pose: tuple, heading: float) -> dict:
    c, s = math.cos(heading), math.sin(heading)
    x, y, h = pose
    return {"x": _r(c * x - s * y), "y": _r(s * x + c * y), "heading": _r(math.atan2(math.sin(h + heading),
                                                                                      math.cos(h + heading)))}


def _describe(network_id: str, sections: dict[str, _Section], ports: dict[str, dict], heading: float) -> dict:
    """The YAML form: an origin only on the sections whose begin is joined to no node."""
    def flip(ref):
        sid, end = ref
        return sid, ({"begin": "end", "end": "begin"}[end] if sections[sid].reversed else end)
    nodes = []
    joined = set()
    for nid, p in ports.items():
        refs = {port: flip(p[port]) for port in ("A", "B1", "B2")}
        joined |= set(refs.values())
        nodes.append({"id": nid, "type": "point_switch", **{k: f"{s}.{e}" for k, (s, e) in refs.items()},
                      "clearance": p["clearance"]})
    out = []
    for sid, sec in sections.items():
        entry = {"id": sid, "length": _r(sec.length)}
        if (sid, "begin") not in joined:
            entry["origin"] = _turned(sec.pose, heading)
        entry["alignment"] = [{"length": _r(ln), "curvature": _r(k)} for ln, k in sec.alignment]
        if sec.equipment:
            entry["equipment"] = sec.equipment
        out.append(entry)
    return {"network_id": network_id, "sections": out, "nodes": nodes}


def _validated(network: dict, sections: dict[str, _Section], heading: float) -> Network:
    """The Network of the description (model.py checks every joint); where the sections cannot be
    placed from their nodes alone, every section gets its origin."""
    try:
        return Network.from_dict(network)
    except NetworkError as exc:
        if "has no origin" not in str(exc):
            raise
    for entry in network["sections"]:
        entry.setdefault("origin", _turned(sections[entry["id"]].pose, heading))
    return Network.from_dict(network)


def _routes(net: Network, section: str, direction: int) -> list[list[str]]:
    """Every route from ``section`` run in ``direction`` to an end of the network."""
    out, todo = [], [TrackPath.start(net, section, direction)]
    while todo:
        path = todo.pop()
        ahead = path.ahead()
        if not ahead:
            out.append([st.section for st in path.steps])
        todo.extend(path.extended(c) for c in ahead)
    return sorted(out)


def pick_route(d, routes: list[list[str]]) -> list[str]:
    """A route as a train's way through the network: at each facing switch either way with equal
    probability (not each route: a branch with more routes beyond it is no likelier)."""
    todo, depth = list(routes), 1
    while len(todo) > 1:
        nexts = sorted({r[depth] for r in todo if len(r) > depth})
        if len(nexts) > 1:
            chosen = nexts[d.int(0, len(nexts) - 1)]
            todo = [r for r in todo if len(r) > depth and r[depth] == chosen]
        depth += 1
    return list(todo[0])

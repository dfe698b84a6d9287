"""Wayside train detection on a network: one device's equipment on several sections
(docs/network.md, "Wayside equipment").

An axle-counter head or a track circuit works on the rails of its own section, in that
section's chainage (core/sensors/axle_counter.py, track_circuit.py; seed 004 sections 2.1,
2.2). A wayside device of a network is the equipment of its kind on every section that
carries some. Simulated, each section's part is the sensor's own simulator on that section,
side by side in one raw block (the sections' channels in the network's order), every train's
axles placed on the section by its route (``Placement``; elsewhere they are off its rails).
Decoded, an axle counter is one counter over the network (``NetworkAxleCounter``): its heads'
passages and fixes are the single-line decoder's, and the areas it counts run across the
nodes, so a switch's area is bounded by the heads on its legs, as an interlocking's switch
section is; a track circuit is one device too (``NetworkTrackCircuits``), its circuits handing over across
the nodes where they reach their sections' ends (an insulated joint there). A fix names
the section of its head or circuit boundary, in that section's chainage. Which train it
belongs to is the association's question (core/association.py): the device does not know.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..vehicle import Vehicle
from ..signals import MAX_CHANNELS
from ..sensors import track_circuit
from ..sensors.axle_counter import AxleCounterDecoder, Areas, device_heads
from ..sensors.base import OFF_RAILS, Decoder, ReferenceWindow, SensorSpec, Simulator
from ..sensors.track_circuit import TrackCircuitDecoder, circuit_table
from .model import Network, NetworkError, SectionEnd
from .path import TrackPath

_TOUCH = 1e-6    # [m] a circuit this near a section's end reaches it

# sensor class -> (equipment kind it monitors, the parameter that restricts a device to some of
# it, raw channels per piece of equipment: a head's two systems, a circuit's receiver level)
WAYSIDE_KINDS = {"axle_counter": ("axle_counter_head", "heads", 2), "track_circuit": ("track_circuit", "circuits", 1)}


@dataclass(frozen=True)
class Placement:
    """Where one train's route runs along one section: route-line chainage [m] (path distance
    less the route's begin, what the train's ground truth gives) -> the section's chainage."""

    origin: float       # path distance of route-line chainage 0 [m]
    start: float        # path distance where the route enters the section [m]
    stop: float         # ... and leaves it [m]
    direction: int      # +1: the route runs along the section's chainage
    length: float       # the section's length [m]

    @classmethod
    def of(cls, route: TrackPath, section: str) -> "Placement | None":
        """The placement of ``route`` on ``section``; None if the route does not run along it."""
        step = route.step_on(section)
        return cls(route.begin, step.start, step.stop, step.direction, step.length) if step is not None else None

    def __call__(self, chainage: np.ndarray) -> np.ndarray:
        """Section chainages of route-line chainages [m]; OFF_RAILS where not on the section."""
        s = chainage + self.origin
        on = (s >= self.start) & (s <= self.stop)
        along = s - self.start if self.direction > 0 else self.length - (s - self.start)
        return np.where(on, along, OFF_RAILS)


def _kind(spec: SensorSpec) -> tuple[str, str, int]:
    try:
        return WAYSIDE_KINDS[spec.sensor]
    except KeyError:
        raise NetworkError(f"{spec.node} does not work on a network as wayside equipment (those that do: "
                           f"{', '.join(WAYSIDE_KINDS)})") from None


def section_params(spec: SensorSpec, params: dict, network: Network) -> dict[str, dict]:
    """Section id -> the device's parameters on that section, for every section (in the
    network's order) that carries equipment of the device's kind; the restriction parameter
    (``heads``, ``circuits``) and the injected faults (``ID@...``) narrowed to the section's
    own ids. One-line NetworkError for an id used on two sections, a restriction or fault
    naming an id on none, or more equipment than one raw block has channels for."""
    kind, restrict, per_item = _kind(spec)
    ids = {sid: [str(it["id"]) for it in sec.items(kind)] for sid, sec in network.sections.items() if sec.items(kind)}
    owner: dict[str, str] = {}
    for sid, names in ids.items():
        for name in names:
            if name in owner:
                raise NetworkError(f"{kind} id {name!r} is on sections {owner[name]} and {sid}: ids of one "
                                   f"device must be unique in the network")
            owner[name] = sid
    if not ids:
        raise NetworkError(f"no section of network {network.network_id} carries {kind}: {spec.node} needs some")
    wanted = [h.strip() for h in str(params.get(restrict, "")).split(",") if h.strip()]
    faults = [f.strip() for f in str(params.get("faults", "")).split(";") if f.strip()]
    named = wanted + [f.split("@", 1)[0].strip() for f in faults]
    missing = sorted({n for n in named if n not in owner})
    if missing:
        raise NetworkError(f"{spec.node}: {', '.join(missing)} on no section of network {network.network_id}")
    used = len(wanted) if wanted else len(owner)
    if used * per_item > MAX_CHANNELS:
        raise NetworkError(f"{spec.node}: {used} {kind} give {used * per_item} raw channels, more than one block "
                           f"carries ({MAX_CHANNELS}): restrict the device to at most {MAX_CHANNELS // per_item} with "
                           f"'{restrict}'")
    out = {}
    for sid, names in ids.items():
        mine = [w for w in wanted if owner[w] == sid]
        if wanted and not mine:
            continue
        out[sid] = {**params, restrict: ",".join(mine),
                    "faults": ";".join(f for f in faults if owner[f.split("@", 1)[0].strip()] == sid)}
    return out


class SectionSimulators(Simulator):
    """A wayside device of a network, simulated: the sensor's simulator on each section that
    carries its equipment, every train's axles placed on the section by its route."""

    sees_all_trains = True

    def __init__(self, spec: SensorSpec, params: dict, network: Network, vehicle: Vehicle,
                 rng: np.random.Generator, fleet: list[Vehicle], routes: list[TrackPath]):
        per_section = section_params(spec, params, network)
        first = network.section(next(iter(per_section)))
        self.sensor = spec.sensor
        self.default_sample_rate = spec.simulator.default_sample_rate
        self.adc_lsb = spec.simulator.adc_lsb
        super().__init__(params, first, vehicle, rng, fleet)
        self.parts: list[Simulator] = []
        for (sid, p), child in zip(per_section.items(), rng.spawn(len(per_section))):
            sim = spec.simulator(p, network.section(sid), vehicle, child, fleet)
            sim.placements = [Placement.of(route, sid) for route in routes]
            self.parts.append(sim)
        self.channels = tuple(c for part in self.parts for c in part.channels)
        self.units = tuple(u for part in self.parts for u in part.units)

    def samples(self, times, position, speed, acceleration):
        return np.concatenate([part.samples(times, position, speed, acceleration) for part in self.parts], axis=1)


class NetworkAxleCounter(AxleCounterDecoder):
    """A network's axle counter, decoded as one device: the heads of every section (the raw
    block's channels in the order SectionSimulators gives them) and the areas they bound over
    the network (``network_areas``): an area runs across the nodes, so a switch's area is
    bounded by the heads on its legs, as an interlocking's switch section is. Each head's
    passages, first-axle identification and fixes are the single-line decoder's, on its own
    section's chainage; a fix names the head's section."""

    def __init__(self, params: dict, network: Network, per_section: dict[str, dict]):
        self.network, self.per_section = network, per_section
        super().__init__(params, network.section(next(iter(per_section))))

    def layout(self, track, params):
        return network_areas(self.network, self.per_section)


def network_areas(network: Network, per_section: dict[str, dict]) -> tuple[list[dict], Areas, list[str]]:
    """(heads, Areas, each head's section) of an axle counter over a network: each section's
    heads (``device_heads`` of its parameters, ``per_section``) cut it into pieces; the pieces
    that meet at a node are one area, and an area that reaches an end of the network (a buffer
    stop, the boundary of what is described) is not monitored. A monitored area is named by its
    bounding heads' ids in the order of the heads (on a single section: ``<id>-<id>``, as on a
    line)."""
    heads, tracks, first, count = [], [], {}, {}
    for sid, params in per_section.items():
        first[sid] = len(heads)
        items = device_heads(network.section(sid), params)
        count[sid] = len(items)
        heads += items
        tracks += [sid] * len(items)
    pieces = [(sid, j) for sid in network.sections for j in range(count.get(sid, 0) + 1)]
    parent = {piece: piece for piece in pieces}

    def root(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    def piece(end) -> tuple[str, int]:
        return (end.section, 0 if end.end == "begin" else count.get(end.section, 0))

    for node in network.nodes.values():
        ends = [piece(e) for e in node.ports.values()]
        for other in ends[1:]:
            parent[root(other)] = root(ends[0])
    roots = list(dict.fromkeys(root(x) for x in pieces))   # in the order of their first piece
    area = {r: k for k, r in enumerate(roots)}
    open_ends = {root(piece(SectionEnd(sid, end))) for sid in network.sections for end in ("begin", "end")
                 if network.joint(SectionEnd(sid, end)) is None}
    left = [area[root((tracks[h], h - first[tracks[h]]))] for h in range(len(heads))]
    right = [area[root((tracks[h], h - first[tracks[h]] + 1))] for h in range(len(heads))]
    bounding: dict[int, list[int]] = {}
    for h, (a, b) in enumerate(zip(left, right)):
        bounding.setdefault(a, []).append(h)
        bounding.setdefault(b, []).append(h)
    sections = []
    for r in roots:
        a = area[r]
        if r in open_ends or a not in bounding:
            continue
        hs = sorted(set(bounding[a]))
        name = "-".join(str(heads[h]["id"]) for h in hs)
        one = len(hs) == 2 and tracks[hs[0]] == tracks[hs[1]] and right[hs[0]] == a == left[hs[1]]
        start, end = ((float(heads[hs[0]]["position"]), float(heads[hs[1]]["position"])) if one
                      else (math.nan, math.nan))
        sections.append((a, name, start, end))
    sections.sort(key=lambda x: min(bounding[x[0]]))
    return heads, Areas(tuple(left), tuple(right), tuple(sections), len(roots)), tracks


def check_device(spec: SensorSpec, params: dict, network: Network) -> dict[str, dict]:
    """The device's ``section_params``; one-line NetworkError for a wayside device that cannot
    run on ``network`` (``section_params``), or one that would take a passage's direction along
    a section for its train's orientation: sections run either way, so on a network every
    train passes front first (``front_first``)."""
    per_section = section_params(spec, params, network)
    if not params.get("front_first", False):
        raise NetworkError(f"{spec.node} on a network needs front_first: true (its sections run either way: the "
                           f"direction of a passage along one says nothing of a train's orientation)")
    return per_section


def network_decoder(spec: SensorSpec, params: dict, network: Network) -> Decoder:
    """The decoder of a wayside device on a network: an axle counter counts over the network's
    areas (NetworkAxleCounter); track circuits hand over across the nodes (NetworkTrackCircuits)."""
    per_section = check_device(spec, params, network)
    if spec.sensor == "axle_counter":
        return NetworkAxleCounter(params, network, per_section)
    return NetworkTrackCircuits(params, network, per_section)


class NetworkTrackCircuits(TrackCircuitDecoder):
    """A network's track circuits, decoded as one device: every section's circuits (the raw
    block's channels in the order SectionSimulators gives them), neighbours on a section as on
    a line and, across a node, the circuits of the joined sections that touch it there
    (``network_circuits``). A hand-over is the single-line decoder's; across a node its fix
    names the entered circuit's section."""

    def __init__(self, params: dict, network: Network, per_section: dict[str, dict]):
        self.network, self.per_section = network, per_section
        super().__init__(params, network.section(next(iter(per_section))))

    def circuit_layout(self, track, params):
        return network_circuits(self.network, self.per_section)


def network_circuits(network: Network, per_section: dict[str, dict]) -> list[dict]:
    """The track circuits of a device over a network (core/sensors/track_circuit.py
    ``circuit_table`` of each section, in ``per_section``'s order, indices made the network's),
    each circuit that reaches an end of its section joined to the circuits that reach the
    section ends continuing it past the node (``across_start`` / ``across_end``). The joint
    there is an insulated one: an axle shunts the circuit of the section it is on (the
    simulator places it so, ``Placement``), so the fix of a hand-over across it lies at the
    joint itself (``fix_position``'s ``insulated``)."""
    table: list[dict] = []
    for sid, params in per_section.items():
        base = len(table)
        for c in circuit_table(network.section(sid), params):
            table.append(dict(c, below=c["below"] + base if c["below"] >= 0 else -1,
                              above=c["above"] + base if c["above"] >= 0 else -1, across_start=[], across_end=[]))
    at_end = {}      # (section, "begin"/"end") -> index of the circuit reaching it
    for k, c in enumerate(table):
        length = network.section(c["section"]).length
        if c["start"] <= _TOUCH:
            at_end[(c["section"], "begin")] = k
        if c["end"] >= length - _TOUCH:
            at_end[(c["section"], "end")] = k
    for (sid, end), k in at_end.items():
        key = "across_start" if end == "begin" else "across_end"
        for cont in network.continuations(sid, -1 if end == "begin" else 1):
            other = at_end.get((cont.section, "begin" if cont.direction > 0 else "end"))
            if other is not None:
                table[k][key].append(other)
    return table


def network_references(spec: SensorSpec, params: dict, network: Network) -> dict[str, ReferenceWindow]:
    """Reference windows of the fixes a wayside device gives only on a network (each in the
    chainage of the section its fix names): a track circuit's hand-overs across nodes; none for
    an axle counter (its heads' fixes are each section's own)."""
    if spec.sensor != "track_circuit":
        return {}
    return track_circuit.boundary_windows(params, network_circuits(network, section_params(spec, params, network)))

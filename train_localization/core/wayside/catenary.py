"""Catenary of a changeover section: two feeding sections, two air sections and a neutral
section between them, switched to either feeding section by ABB-1 / ABB-2 (seed 004
section 4.1, Fig. 5).

Layout along increasing chainage: substation A feeds the catenary west of air section 1,
substation B east of air section 2; the neutral section (about 1 km, seed 004 section 4.1;
at least 800 m, section 4.2) lies between them; in each air section the contact wires of
the two neighbouring sections run side by side, so a pantograph there touches both. The
neutral is fed from A through ABB-1 or from B through ABB-2 (power semiconductors); with
neither it is dead.

Electrically there are three conductors, A, B and N, and two sources, A and B, which are
different phases. Closed ABB switches and pantographs join conductors: a pantograph in an
air section joins the two it touches, and the raised pantographs of a train with a roof
bus join everything they touch. A and B joined is a short circuit between the phases
(seed 004 section 4.1: the feeders or the pantograph burn); a train whose pantographs touch
only conductors joined to no source is dead (no traction power).

``events`` evaluates ABB switching logs and pantograph positions on a time grid: short
circuits (with their cause), dead intervals per train, and switchings while a pantograph
is in an air section.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..sensors.base import Param, check_declared, resolve_params

MIN_NEUTRAL = 800.0        # [m] seed 004 section 4.2: the neutral section at least 800 m
A, B, N = 0, 1, 2          # conductors: feeding section A, feeding section B, neutral section
ABB1, ABB2 = "ABB-1", "ABB-2"

PARAMS = {
    "neutral_length": Param(1000.0, "length of the neutral section between the air sections [m] (seed 004 "
                                    "section 4.1: about 1 km; section 4.2: at least 800 m)", (MIN_NEUTRAL, 10000.0)),
    "air_length": Param(50.0, "length of an air section, where the contact wires of both neighbouring sections "
                              "overlap [m] (assumption: one span of about 50 m)", (1.0, 500.0)),
    "approach": Param(250.0, "distance from the outer counting point to the air section [m] (seed 004 section "
                             "4.2: a block of at least 800 m including the air section: 250 + 50 + half of "
                             "1000 m)", (0.0, 5000.0)),
    "track_circuit_length": Param(400.0, "length of each track circuit, from the middle counting point outwards "
                                         "[m] (seed 004 section 4.2: AF track circuits of about 400 m, inside the "
                                         "neutral section; at most the block: the 'blocks' variant lays them over "
                                         "the whole block, 800 m)", (50.0, 5000.0)),
    "lead": Param(1000.0, "track before the first and after the last counting point [m] (where the "
                          "trains start and end)", (100.0, 10000.0)),
    "supply_frequency": Param(60.0, "frequency of the traction supply [Hz] (Korean 25 kV AC: 60 Hz; "
                                    "assumption, not in seed 004)", (16.0, 60.0)),
}
check_declared(PARAMS, "catenary")


@dataclass(frozen=True)
class Layout:
    """Chainages [m] of a changeover section: counting points AC0 < AC1 < AC2 (AC1 in the
    middle of the neutral section), the air sections air1 = (a1, b1), air2 = (a2, b2), the
    track circuits tc1 = (AC1 - L, AC1) and tc2 = (AC1, AC1 + L) (L = ``track_circuit_length``).

    Seed 004 section 4.2: axle-counter blocks AC0..AC1 and AC1..AC2 of at least 800 m with
    the air section in them, AF track circuits of about 400 m, a neutral section of at least
    800 m: the 400 m circuits lie in the neutral section next to AC1, and only the axle
    counter sees a train in the outer part of a block (occupancy.py: no contradiction there)."""

    ac: tuple[float, float, float]
    air1: tuple[float, float]
    air2: tuple[float, float]
    length: float                       # track length [m]
    params: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self):
        x0, x1, x2 = self.ac
        neutral = self.air2[0] - self.air1[1]
        if neutral < MIN_NEUTRAL - 1e-6:
            raise ValueError(f"a neutral section of {neutral:g} m: seed 004 section 4.2 asks for at least "
                             f"{MIN_NEUTRAL:g} m")
        tc = self.params.get("track_circuit_length", PARAMS["track_circuit_length"].default)
        if tc > min(x1 - x0, x2 - x1) + 1e-6:
            raise ValueError(f"track circuits of {tc:g} m do not fit the blocks {x1 - x0:g} / {x2 - x1:g} m")

    @property
    def tc1(self) -> tuple[float, float]:
        """Track circuit TC1 on the A side, ending at AC1 [m]."""
        x1 = self.ac[1]
        return x1 - self.params.get("track_circuit_length", PARAMS["track_circuit_length"].default), x1

    @property
    def tc2(self) -> tuple[float, float]:
        """Track circuit TC2 on the B side, starting at AC1 [m]."""
        x1 = self.ac[1]
        return x1, x1 + self.params.get("track_circuit_length", PARAMS["track_circuit_length"].default)

    @classmethod
    def from_params(cls, overrides: dict | None = None) -> "Layout":
        p = resolve_params(PARAMS, overrides)
        x0 = p["lead"]
        a1 = x0 + p["approach"]
        b1 = a1 + p["air_length"]
        a2 = b1 + p["neutral_length"]
        b2 = a2 + p["air_length"]
        x2 = b2 + p["approach"]
        return cls((x0, 0.5 * (b1 + a2), x2), (a1, b1), (a2, b2), x2 + p["lead"], p)

    @classmethod
    def around(cls, ac: tuple[float, float, float], length: float, overrides: dict | None = None) -> "Layout":
        """The layout around three counting points of a line's track [m]: the air sections
        ``approach`` inside the outer ones, the neutral section between them (its length
        follows from the points; ``neutral_length`` and ``lead`` are not used). ValueError if
        the middle point is not inside the neutral section or that is shorter than MIN_NEUTRAL."""
        p = resolve_params(PARAMS, overrides)
        x0, x1, x2 = (float(x) for x in ac)
        a1, b2 = x0 + p["approach"], x2 - p["approach"]
        b1, a2 = a1 + p["air_length"], b2 - p["air_length"]
        if not (0.0 <= x0 and b1 < x1 < a2 and x2 <= length):
            raise ValueError(f"counting points {x0:g}, {x1:g}, {x2:g} m leave no neutral section around the middle "
                             f"one with approach {p['approach']:g} m and air sections of {p['air_length']:g} m "
                             f"on a track of {length:g} m")
        # the line's track lays the circuits (changeover.Site): this length only has to fit the blocks
        tc = min(p["track_circuit_length"], x1 - x0, x2 - x1)
        return cls((x0, x1, x2), (a1, b1), (a2, b2), float(length),
                   {**p, "neutral_length": a2 - b1, "track_circuit_length": tc})

    @property
    def neutral(self) -> tuple[float, float]:
        """Span of the neutral section's contact wire, air sections included [m]."""
        return self.air1[0], self.air2[1]

    def touches(self, x: np.ndarray) -> np.ndarray:
        """Which conductors a pantograph at chainages x touches: bool (..., 3) for A, B, N."""
        x = np.asarray(x, dtype=float)
        out = np.zeros(x.shape + (3,), dtype=bool)
        out[..., A] = x <= self.air1[1]
        out[..., B] = x >= self.air2[0]
        out[..., N] = (x >= self.air1[0]) & (x <= self.air2[1])
        return out

    def in_air_section(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        return ((x >= self.air1[0]) & (x <= self.air1[1])) | ((x >= self.air2[0]) & (x <= self.air2[1]))

    def track_dict(self, tc_params: dict | None = None) -> dict:
        """The detection of seed 004 Fig. 6 as track equipment: two UM71C track circuits
        TC1, TC2 either side of AC1 (``tc1``, ``tc2``) and three axle-counter heads (sections
        S1 = AC0..AC1, S2 = AC1..AC2)."""
        x0, x1, x2 = self.ac
        (s1, e1), (s2, e2) = self.tc1, self.tc2
        return {"track_id": "changeover", "length": self.length, "equipment": {
            "track_circuit": [{"id": "TC1", "start": s1, "end": e1, "system": "UM71C", "line": "T1"},
                              {"id": "TC2", "start": s2, "end": e2, "system": "UM71C", "line": "T1"}],
            "axle_counter_head": [{"id": "AC0", "position": x0, "section": "S1"},
                                  {"id": "AC1", "position": x1, "section": "S2"},
                                  {"id": "AC2", "position": x2}]}}


@dataclass(frozen=True)
class Switching:
    """An ABB state change taking effect at ``stamp`` [s]."""

    stamp: float
    switch: str          # ABB1 or ABB2
    on: bool


def effective(stamp: float, switch: str, on: bool, latency: float, supply_frequency: float) -> Switching:
    """The state change of an ABB command decided at ``stamp`` [s]: closing after the gate
    signal's ``latency``, opening half a supply cycle later (the semiconductor blocks at the
    next current zero)."""
    return Switching(stamp + latency + (0.0 if on else 0.5 / supply_frequency), switch, on)


def pantograph_chainages(front: np.ndarray, orientation: int, offsets) -> np.ndarray:
    """(n, P) chainages [m] of the raised pantographs at ``offsets`` behind the front of a
    train whose front is at ``front`` (n,) and faces ``orientation`` (+1: increasing chainage)."""
    return np.asarray(front, dtype=float)[:, None] - orientation * np.asarray(offsets, dtype=float)[None, :]


def switch_states(log: list[Switching], times: np.ndarray, initial=(True, False)) -> np.ndarray:
    """(n, 2) bool: ABB-1, ABB-2 closed at each time, from the switching log."""
    out = np.empty((len(times), 2), dtype=bool)
    out[:] = initial
    for sw in sorted(log, key=lambda s: s.stamp):
        k = 0 if sw.switch == ABB1 else 1
        out[times >= sw.stamp, k] = sw.on
    return out


def _components(abb: np.ndarray, touch: np.ndarray, roof: list[np.ndarray]) -> np.ndarray:
    """Which conductors are joined, per time: (n, 3, 3) bool adjacency closed transitively.

    abb (n, 2); touch (n, P, 3) per pantograph; roof: per train with a roof bus, the indices
    of its pantographs (all it touches are joined)."""
    n = abb.shape[0]
    adj = np.zeros((n, 3, 3), dtype=bool)
    adj[:, [A, B, N], [A, B, N]] = True
    adj[:, A, N] |= abb[:, 0]
    adj[:, B, N] |= abb[:, 1]
    groups = [touch[:, p] for p in range(touch.shape[1])]
    groups += [touch[:, idx].any(axis=1) for idx in roof if len(idx) > 1]
    for g in groups:
        adj |= g[:, :, None] & g[:, None, :]
    adj |= adj.transpose(0, 2, 1)
    for _ in range(2):   # three nodes: two squarings close the relation
        adj = (adj.astype(np.uint8) @ adj.astype(np.uint8)) > 0
    return adj


@dataclass
class CatenaryReport:
    """Events of one run (stamps [s])."""

    short_circuits: list[dict]          # {start, end, cause}
    air_switchings: list[dict]          # {stamp, switch, on, pantographs: [(train, chainage)]}
    dead: dict[str, float]              # train -> time dead with the controller's switching [s]
    unfed: dict[str, float]             # train -> time dead if the neutral were never fed [s]
    dead_intervals: dict[str, list[tuple[float, float]]]


def _intervals(mask: np.ndarray, times: np.ndarray) -> list[tuple[float, float]]:
    if not mask.any():
        return []
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return [(float(times[s]), float(times[e])) for s, e in zip(starts, ends)]


def events(layout: Layout, log: list[Switching], times: np.ndarray, pantographs: dict[str, np.ndarray],
           roof_bus: dict[str, bool], initial=(True, False)) -> CatenaryReport:
    """Short circuits, dead time and air-section switchings of a run.

    times: grid [s] (fine enough for the air sections: a few metres at the highest speed);
    pantographs: train -> chainages of its raised pantographs (n, P) [m], NaN off the line;
    roof_bus: train -> its raised pantographs are joined on the roof."""
    abb = switch_states(log, times, initial)
    names = list(pantographs)
    cols, roof, owner = [], [], []
    for name in names:
        x = np.asarray(pantographs[name], dtype=float).reshape(len(times), -1)
        idx = list(range(len(cols), len(cols) + x.shape[1]))
        cols.extend(x.T)
        owner.extend([name] * x.shape[1])
        if roof_bus.get(name):
            roof.append(np.array(idx))
    xs = np.array(cols).T if cols else np.zeros((len(times), 0))
    touch = layout.touches(np.where(np.isfinite(xs), xs, -math.inf))
    touch &= np.isfinite(xs)[..., None]
    adj = _components(abb, touch, roof)
    short = adj[:, A, B]
    shorts = []
    for t0, t1 in _intervals(short, times):
        i = int(np.searchsorted(times, t0))
        bridging = [owner[p] for p in range(xs.shape[1]) if touch[i, p].sum() >= 2]
        bridging += [f"{owner[idx[0]]} (roof bus)" for idx in roof if touch[i, idx].any(axis=0).sum() >= 2
                     and owner[idx[0]] not in bridging]
        cause = "ABB-1 and ABB-2 closed" if abb[i].all() else f"pantograph bridge: {', '.join(sorted(set(bridging)))}"
        shorts.append({"start": t0, "end": t1, "cause": cause})
    live = adj[:, :, A] | adj[:, :, B]                           # (n, 3): conductor joined to a source
    unfed_adj = _components(np.zeros_like(abb), touch, roof)
    unfed_live = unfed_adj[:, :, A] | unfed_adj[:, :, B]
    dt = np.diff(times, append=times[-1])
    dead, unfed, dead_iv = {}, {}, {}
    for name in names:
        idx = [p for p in range(xs.shape[1]) if owner[p] == name]
        t = touch[:, idx]                                       # (n, P, 3)
        on_line = t.any(axis=2).any(axis=1)
        powered = (t & live[:, None, :]).any(axis=2).any(axis=1)
        powered_unfed = (t & unfed_live[:, None, :]).any(axis=2).any(axis=1)
        d = on_line & ~powered
        dead[name] = float(dt[d].sum())
        unfed[name] = float(dt[on_line & ~powered_unfed].sum())
        dead_iv[name] = _intervals(d, times)
    air = []
    for sw in log:
        here = []
        for name in names:
            x = np.asarray(pantographs[name], dtype=float).reshape(len(times), -1)
            i = int(np.clip(np.searchsorted(times, sw.stamp), 0, len(times) - 1))
            for xp in x[i]:
                if math.isfinite(xp) and layout.in_air_section(xp):
                    here.append((name, float(xp)))
        if here:
            air.append({"stamp": sw.stamp, "switch": sw.switch, "on": sw.on, "pantographs": here})
    return CatenaryReport(shorts, air, dead, unfed, dead_iv)

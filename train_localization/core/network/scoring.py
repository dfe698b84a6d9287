"""Scores of a train's published states on a network against its true route (docs/network.md).

Heirich's measures (J. Sensors 2016): *track selectivity* on parallel track, the share of
the states on parallel track that name the train's true track, and *switch ways resolved*:
a facing switch counts as resolved when every state from the moment the true front is
``clearance`` past the switch point until it is ``vicinity`` further names the true way.
And the integrity on a network: a state is *on the true route* when its section is one
of the route's, at the place the truth is; it is *NOMINAL on a wrong track* when it is
not and claims NOMINAL (the product's rule: never); and the interval (which covers every
plausible path) is scored as path distances, which the true route shares with every
hypothesis (core/network/path.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..convert import stamp_to_sec
from ..fusion.mode import Mode
from ..scoring import FIELDS, StateSeries
from .path import TrackPath

PARALLEL_DISTANCE = 6.0   # [m] another track within this of the true front: parallel track
VICINITY = 20.0           # [m] beyond a switch's clearance point in which its way must hold
NEAR_ROUTE = 50.0         # [m] a state's place on the route may lie this far from the truth


@dataclass(frozen=True)
class HypothesisView:
    track_id: str
    position: float
    position_min: float
    position_max: float
    probability: float


@dataclass(frozen=True)
class PublishedState:
    """One published state of a train on a network (TrainState + its TrackHypotheses)."""

    t: float
    track_id: str
    position: float
    position_min: float
    position_max: float
    mode: int
    track_probability: float
    hypotheses: tuple[HypothesisView, ...] = ()

    @classmethod
    def of_estimate(cls, e) -> "PublishedState":
        """Of a core/network NetworkEstimate."""
        return cls(e.stamp, e.track_id, e.position, e.position_min, e.position_max, int(e.mode), e.track_probability,
                   tuple(HypothesisView(h.track_id, h.position, h.position_min, h.position_max, h.probability)
                         for h in e.hypotheses))


def path_series(estimates) -> StateSeries:
    """The along-track StateSeries of NetworkEstimates in path distances (the route's, for the
    states on it; every plausible path's interval, which the published one covers): what the
    single-line scores (core/scoring.py) take."""
    rows = [(e.stamp, e.path_position, e.path_speed, e.position_stddev, e.speed_stddev, e.path_min, e.path_max,
             e.mode) for e in estimates]
    arr = np.array(rows, dtype=float).reshape(-1, len(FIELDS))
    return StateSeries(*(arr[:, i] for i in range(len(FIELDS))))


def published_from_msgs(states, tracks) -> list[PublishedState]:
    """PublishedStates of TrainState messages and the TrackHypotheses of the same stamps."""
    by_stamp = {stamp_to_sec(m.header.stamp): m for m in tracks}
    out = []
    for m in states:
        t = stamp_to_sec(m.header.stamp)
        hyps = by_stamp.get(t)
        views = tuple(HypothesisView(h.track_id, h.position, h.position_min, h.position_max, h.probability)
                      for h in (hyps.hypotheses if hyps is not None else ()))
        out.append(PublishedState(t, m.track_id, m.position, m.position_min, m.position_max, int(m.mode),
                                  float(getattr(m, "track_probability", 1.0)), views))
    return out


def _covers(route: TrackPath, track_id: str, lo: float, hi: float, s_true: float) -> bool:
    """Whether an interval [lo, hi] on ``track_id``'s axis holds the route distance s_true."""
    a, b = route.distance(track_id, lo, s_true), route.distance(track_id, hi, s_true)
    return min(a, b) <= s_true <= max(a, b)


def _on_route(route: TrackPath, track_id: str, position: float, s_true: float) -> bool:
    d = route.distance(track_id, position, s_true)
    return d is not None and abs(d - s_true) <= NEAR_ROUTE


def parallel_mask(route: TrackPath, s: np.ndarray, distance: float = PARALLEL_DISTANCE) -> np.ndarray:
    """Whether the true front at route distances ``s`` is on parallel track: another section
    (not on the route within 200 m) passes within ``distance``, and the front is neither
    past a facing switch's point short of its clearance point nor within VICINITY before it."""
    network = route.network
    grid = np.arange(math.floor(s.min()) if s.size else 0.0, (math.ceil(s.max()) if s.size else 0.0) + 1.0, 1.0)
    flags = np.zeros(grid.size, dtype=bool)
    # from VICINITY before a facing switch's point (an estimate a few metres ahead of the truth
    # is already past it, on one of its ways) to its clearance point
    switch_zones = [(st.start - VICINITY, st.start + network.nodes[st.node].clearance) for st in route.steps if st.way]
    for i, g in enumerate(grid):
        if any(a <= g < b for a, b in switch_zones):
            continue
        x, y = route.xy(float(g))
        near = set(route.sections(g - 200.0, g + 200.0))
        for sid, sec in network.sections.items():
            if sid in near:
                continue
            c, lat = sec.project(x, y)
            px, py, _ = sec.pose(float(c[0]))
            if math.hypot(x - px, y - py) <= distance:
                flags[i] = True
                break
    if not grid.size:
        return np.zeros(s.size, dtype=bool)
    return flags[np.clip(np.round(s - grid[0]).astype(int), 0, grid.size - 1)]


def network_scores(route: TrackPath, truth_t, truth_s, states: list[PublishedState],
                   vicinity: float = VICINITY) -> dict:
    """Track selectivity, switch ways and the network integrity of a train's ``states`` on
    its true ``route`` (truth: times [s] and route distances [m], path distance - route.begin).
    Only states within the truth's time span are scored: a live run's recorded truth may end
    before its fusion's last states, and no truth is known there."""
    truth_t = np.asarray(truth_t, dtype=float)
    truth_s = np.asarray(truth_s, dtype=float) + route.begin
    span = (truth_t[0], truth_t[-1]) if truth_t.size else (math.inf, -math.inf)
    claimed = [st for st in states if st.mode != Mode.INITIALISING and math.isfinite(st.position)
               and span[0] <= st.t <= span[1]]
    if not claimed:
        return {"states": len(states), "claimed": 0}
    t = np.array([st.t for st in claimed])
    s_true = np.interp(t, truth_t, truth_s)
    correct = np.array([_on_route(route, st.track_id, st.position, s) for st, s in zip(claimed, s_true)])
    nominal = np.array([st.mode == Mode.NOMINAL for st in claimed])
    degraded = np.array([st.mode == Mode.DEGRADED for st in claimed])
    inside = np.zeros(len(claimed), dtype=bool)
    hyp_inside = np.zeros(len(claimed), dtype=bool)
    listed = np.array([bool(st.hypotheses) for st in claimed])   # a recorded state may lack its list
    error = np.full(len(claimed), np.nan)
    for i, (st, s) in enumerate(zip(claimed, s_true)):
        if correct[i]:
            error[i] = route.distance(st.track_id, st.position, s) - s
            inside[i] = _covers(route, st.track_id, st.position_min, st.position_max, s)
        hyp_inside[i] = any(_on_route(route, h.track_id, h.position, s)
                            and _covers(route, h.track_id, h.position_min, h.position_max, s) for h in st.hypotheses)
    parallel = parallel_mask(route, s_true)
    ways = []
    for step in route.steps:
        if not step.way:
            continue
        start = step.start + route.network.nodes[step.node].clearance
        sel = (s_true >= start) & (s_true <= start + vicinity)
        if sel.any():
            ways.append({"switch": step.node, "way": step.way, "resolved": bool(correct[sel].all()),
                         "wrong_states": int((~correct[sel]).sum())})
    n_par = int(parallel.sum())
    err = np.abs(error[correct])
    return {
        "states": len(states), "claimed": len(claimed),
        "position_error_m": {"rms": float(np.sqrt(np.mean(err ** 2))) if err.size else math.nan,
                             "max": float(err.max()) if err.size else math.nan},
        "on_true_track": float(correct.mean()),
        "wrong_track_states": int((~correct).sum()),
        "nominal_wrong_track": int((nominal & ~correct).sum()),
        "degraded_share": float(degraded.mean()),
        "inside": float(inside[correct].mean()) if correct.any() else math.nan,
        "true_hypothesis_inside": float(hyp_inside[listed].mean()) if listed.any() else math.nan,
        "true_hypothesis_outside": int((~hyp_inside & listed).sum()),
        "parallel_states": n_par,
        "parallel_correct": int(correct[parallel].sum()),
        "selectivity": float(correct[parallel].mean()) if n_par else math.nan,
        "switch_ways": len(ways), "switch_ways_resolved": sum(w["resolved"] for w in ways),
        "ways": ways,
    }

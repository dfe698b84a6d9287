"""The ETCS location function run over a fused run and scored on its truth (docs/etcs.md,
docs/campaign.md): safe front ends against the true front, the doubts against SUBSET-041's
allowance and the fixed rule of the open-source on-board units, v_ura against the true speed
and SUBSET-041's speed band, and the linking events.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..scoring import ENVELOPE_FIXED, ENVELOPE_RATE, speed_envelope
from .location import FusedState, LocationTracker, is_balise_fix
from .records import EventKind, LocationEvent, LocationReport
from .track_data import EtcsData


def subset041_position(d_lrbg: np.ndarray) -> np.ndarray:
    """SUBSET-041 5.3.1.1 odometry accuracy over a distance from the LRBG [m]: 5 m + 5 %."""
    return ENVELOPE_FIXED + ENVELOPE_RATE * np.abs(d_lrbg)


def fixed_rule(q_locacc: np.ndarray, d_lrbg: np.ndarray) -> np.ndarray:
    """The doubt of the open-source on-board units [m]: Q_LOCACC + 1 % of the distance from the LRBG."""
    return q_locacc + 0.01 * np.abs(d_lrbg)


@dataclass
class LocationRun:
    """Reports and events of one run of the location function, and its tracker (counters)."""
    reports: list[LocationReport] = field(default_factory=list)
    events: list[LocationEvent] = field(default_factory=list)
    tracker: LocationTracker | None = None   # or a NetworkLocationTracker (its ``stats`` alike)


def run_location(data: EtcsData, params: dict | None, estimates, arrivals) -> LocationRun:
    """Feed a run's fused estimates (core.fusion Estimate, in time order) and its delivered
    (arrival time, measurement) pairs to a LocationTracker: a balise fix is given once the
    fusion has made a state at or after its arrival, as the node gets them."""
    return run_tracker(LocationTracker(data, params), estimates, arrivals)


def run_tracker(tracker, estimates, arrivals) -> LocationRun:
    """``run_location`` with a tracker of one's own (a LocationTracker, or on a network a
    core/etcs/network_location.py NetworkLocationTracker)."""
    fixes = [(t, m) for t, m in arrivals if is_balise_fix(m)]
    run = LocationRun(tracker=tracker)
    j = 0
    for est in estimates:
        while j < len(fixes) and fixes[j][0] <= est.stamp + 1e-12:
            tracker.on_fix(fixes[j][1])
            j += 1
        report, events = tracker.on_state(FusedState.from_estimate(est))
        run.reports.append(report)
        run.events.extend(events)
    return run


def _quantiles(x: np.ndarray) -> dict:
    if not x.size:
        return {"median": float("nan"), "p95": float("nan"), "max": float("nan")}
    return {"median": float(np.median(x)), "p95": float(np.percentile(x, 95)), "max": float(np.max(x))}


def location_scores(run: LocationRun, truth_t: np.ndarray, truth_front: np.ndarray, truth_speed: np.ndarray,
                    orientation: int, read_groups: dict[str, list[float]] | None = None) -> dict:
    """Scores of a LocationRun on the truth (chainage of the front [m], speed [m/s] at truth_t [s]).

    ``read_groups``: group -> stamps [s] at which the reader produced a fix of it (all, before
    delivery); a missed linked group the reader did read is counted as ``missed_but_read``
    (the location function's fault, not the balise's)."""
    reps = [r for r in run.reports if r.has_position]
    out: dict = {"reports": len(run.reports), "claimed": len(reps)}
    if reps:
        t = np.array([r.t for r in reps])
        front = np.interp(t, truth_t, truth_front)
        speed = np.interp(t, truth_t, truth_speed)
        lo = np.array([min(r.min_safe_front_end, r.max_safe_front_end) for r in reps])
        hi = np.array([max(r.min_safe_front_end, r.max_safe_front_end) for r in reps])
        inside = (front >= lo) & (front <= hi)
        v_est = np.array([r.v_est for r in reps]) * orientation
        v_ura = np.array([r.v_ura for r in reps])
        speed_in = np.abs(speed - v_est) <= v_ura
        out.update({"inside": int(inside.sum()), "outside": int((~inside).sum()),
                    "inside_share": float(inside.mean()), "speed_inside_share": float(speed_in.mean()),
                    "speed_within_subset041_share": float(np.mean(v_ura <= speed_envelope(speed)))})
        with_lrbg = np.array([bool(r.nid_lrbg) for r in reps])
        if with_lrbg.any():
            d = np.array([r.d_lrbg for r in reps])[with_lrbg]
            q = np.array([r.q_locacc for r in reps])[with_lrbg]
            doubt = 0.5 * (np.array([r.l_doubtover for r in reps]) + np.array([r.l_doubtunder for r in reps]))[with_lrbg]
            out["doubt_m"] = _quantiles(doubt)
            out["ratio_subset041"] = _quantiles(doubt / subset041_position(d))
            out["ratio_fixed_rule"] = _quantiles(doubt / fixed_rule(q, d))
            out["below_fixed_rule_share"] = float(np.mean(doubt < fixed_rule(q, d)))
            out["d_lrbg_m"] = _quantiles(np.abs(d))
            out["with_lrbg"] = int(with_lrbg.sum())
    kinds = {k.name.lower(): 0 for k in EventKind}
    for e in run.events:
        kinds[e.kind.name.lower()] += 1
    out["events"] = kinds
    if read_groups is not None:
        out["missed_but_read"] = sum(
            1 for e in run.events if e.kind == EventKind.MISSED_LINKED_GROUP
            and any(abs(s - e.t) < 60.0 for s in read_groups.get(e.nid_bg, ())))
    out["tracker"] = dict(run.tracker.stats) if run.tracker is not None else {}
    return out

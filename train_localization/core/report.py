"""Scores and plots of a run against ground truth: the regression report.

Input: truth states, fused estimates (or TrainState messages) and the decoded
measurements of one run (live bag or offline replay). Output: a JSON-able dict and
PNG plots.

Checks, per published state with a claimed position:
  * ETCS odometry envelope (SUBSET-041 5.3.1): |position error| <= 5 m + 5 % of the
    distance travelled since the last absolute reference (balise group; in a run
    without balises, the last PositionFix of any on-board reference reader);
  * speed band (SUBSET-041 5.3.1.2): +-2 km/h below 30 km/h, rising linearly to
    +-12 km/h at 500 km/h;
  * integrity: truth inside [position_min, position_max].
Speed errors count from SPEED_SETTLING s after the first measurement (before it the
filter knows nothing of the motion).
Per-sensor residuals: measurement minus the fused estimate at its stamp (position
fixes against position, speed and distance increments against speed), raw and
normalised by the measurement's stddev.

A line (several trains, core/offline/line.py LineResult): ``line_report`` gives the report
of each train (its on-board measurements and the wayside fixes delivered to it) and the
line-level figures of the association (``association_check``) and, with a changeover
section, its catenary events (``changeover_check``: the replayed controller's commands;
``recorded_changeover``: the commands a live controller published, from its bag).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .measurements import DistanceIncrement, PositionFix, SpeedMeasurement
from .scoring import ENVELOPE_FIXED, ENVELOPE_RATE, speed_envelope, true_position

KMH = 1 / 3.6
REFERENCE_READERS = ("eurobalise", "lrl", "axle_counter")  # point references, in order of preference
SPEED_SETTLING = 1.0  # [s] after the first measurement before speed errors count


def _stats(err) -> dict:
    err = np.asarray(err, dtype=float)
    if err.size == 0:
        return {"n": 0, "rms": None, "p95": None, "max": None}
    a = np.abs(err)
    return {"n": int(err.size), "rms": float(np.sqrt(np.mean(err * err))), "p95": float(np.percentile(a, 95)),
            "max": float(a.max())}


def _columns(estimates):
    """Arrays from Estimate objects or TrainState messages. An estimate on a network (core/network
    NetworkEstimate) is taken in path distances, the coordinate its truth has along its route."""
    from .convert import stamp_to_sec
    rows = []
    for e in estimates:
        t = e.stamp if hasattr(e, "stamp") else stamp_to_sec(e.header.stamp)
        if hasattr(e, "path_position"):
            rows.append((t, e.path_position, e.path_speed, e.position_stddev, e.speed_stddev, e.path_min, e.path_max,
                         e.mode))
            continue
        rows.append((t, e.position, e.speed, e.position_stddev, e.speed_stddev, e.position_min, e.position_max,
                     e.mode))
    arr = np.array(rows, dtype=float).reshape(-1, 8)
    return {k: arr[:, i] for i, k in enumerate(("t", "position", "speed", "position_stddev", "speed_stddev",
                                                  "position_min", "position_max", "mode"))}


def evaluate(truth, estimates, measurements, circumference: float | None = None) -> tuple[dict, dict]:
    """(report dict, arrays for plotting); on a closed track of ``circumference`` [m] the
    position is compared modulo it (scoring.true_position)."""
    tt = np.array([s.stamp for s in truth])
    ts = np.array([s.position for s in truth])
    if circumference:   # the distance run (odometer below) across the loop's end, not a jump
        ts = np.unwrap(ts, period=circumference)
    tv = np.array([s.speed for s in truth])
    f = _columns(estimates)
    keep = (f["t"] >= tt[0]) & (f["t"] <= tt[-1])
    f = {k: v[keep] for k, v in f.items()}
    s_true = true_position(f["t"], tt, ts, f["position"], circumference)
    v_true = np.interp(f["t"], tt, tv)
    claimed = (f["mode"] != 0) & np.isfinite(f["position"])
    pos_err = f["position"] - s_true
    # speed is scored from 1 s after the first measurement: before it the filter
    # has no information at all (it starts at 0 m/s whatever the train does)
    first = min((m.stamp for m in measurements), default=f["t"][0] if f["t"].size else 0.0)
    scored = f["t"] >= first + SPEED_SETTLING
    spd_err = (f["speed"] - v_true)[scored]

    # distance travelled since the last point reference (true odometer difference)
    odo = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(ts)))])
    fixes = [m for m in measurements if isinstance(m, PositionFix)]
    reader = next((r for r in REFERENCE_READERS if any(m.sensor == r for m in fixes)), None)
    ref_times = np.array(sorted(m.stamp for m in fixes if reader is None or m.sensor == reader))
    odo_now = np.interp(f["t"], tt, odo)
    envelope = np.full(f["t"].shape, np.inf)
    if ref_times.size:
        idx = np.searchsorted(ref_times, f["t"], side="right") - 1
        has_ref = idx >= 0
        odo_ref = np.interp(ref_times[np.maximum(idx, 0)], tt, odo)
        envelope = np.where(has_ref, ENVELOPE_FIXED + ENVELOPE_RATE * (odo_now - odo_ref), np.inf)
    band = speed_envelope(v_true[scored])
    inside = (s_true >= f["position_min"]) & (s_true <= f["position_max"])
    pe = pos_err[claimed]
    env_c = envelope[claimed]
    finite_env = np.isfinite(env_c)
    report = {
        "duration_s": float(tt[-1] - tt[0]),
        "states": int(f["t"].size),
        "states_with_position": int(claimed.sum()),
        "position_error_m": _stats(pe),
        "speed_error_mps": _stats(spd_err),
        "speed_error_kmh_p95": float(np.percentile(np.abs(spd_err), 95) / KMH) if spd_err.size else None,
        "etcs_envelope": {
            "reference_reader": reader,
            "states_checked": int(finite_env.sum()),
            "inside_fraction": float(np.mean(np.abs(pe[finite_env]) <= env_c[finite_env])) if finite_env.any() else None,
            "p95_error_over_envelope": float(np.percentile(np.abs(pe[finite_env]) / env_c[finite_env], 95))
            if finite_env.any() else None,
            "speed_inside_fraction": float(np.mean(np.abs(spd_err) <= band)) if band.size else None,
            "speed_max_error_over_band": float(np.max(np.abs(spd_err) / band)) if band.size else None,
        },
        "integrity": {
            "confidence": None,
            "inside_fraction": float(inside[claimed].mean()) if claimed.any() else None,
            "outside_count": int((~inside[claimed]).sum()),
            "mean_interval_width_m": float(np.mean(f["position_max"][claimed] - f["position_min"][claimed]))
            if claimed.any() else None,
        },
        "modes": {str(int(m)): int(n) for m, n in zip(*np.unique(f["mode"], return_counts=True))},
        "residuals": {},
    }
    if hasattr(estimates[0], "confidence") if len(estimates) else False:
        report["integrity"]["confidence"] = float(estimates[-1].confidence)
    # per-sensor residuals against the fused estimate at the measurement stamp
    res_plot = {}
    groups: dict[str, list] = {}
    for m in measurements:
        if isinstance(m, PositionFix):
            key, z, sd, ref = f"{m.sensor}/position", m.position, m.position_stddev, "position"
        elif isinstance(m, SpeedMeasurement):
            key, z, sd, ref = f"{m.sensor}/speed", m.speed, m.speed_stddev, "speed"
        elif isinstance(m, DistanceIncrement):
            key, z, sd, ref = f"{m.sensor}/distance", m.distance / m.duration, m.speed_stddev, "speed"
        else:
            continue
        groups.setdefault(key, []).append((m.stamp, z, sd, ref))
    ok = claimed
    for key, rows in sorted(groups.items()):
        arr = np.array([(t, z, sd) for t, z, sd, _ in rows])
        ref = rows[0][3]
        series = f["position"] if ref == "position" else f["speed"]
        sel = ok if ref == "position" else np.ones_like(ok)
        if sel.sum() < 2:
            continue
        est = np.interp(arr[:, 0], f["t"][sel], series[sel])
        valid = (arr[:, 0] >= f["t"][sel][0]) & (arr[:, 0] <= f["t"][sel][-1])
        r = arr[valid, 1] - est[valid]
        nr = r / arr[valid, 2]
        report["residuals"][key] = {"n": int(r.size), "mean": float(r.mean()) if r.size else None,
                                    "std": float(r.std()) if r.size else None,
                                    "normalised_rms": float(np.sqrt(np.mean(nr * nr))) if r.size else None}
        res_plot[key] = (arr[valid, 0], r)
    arrays = {"t": f["t"], "pos_err": pos_err, "claimed": claimed, "lo": f["position_min"] - s_true,
              "hi": f["position_max"] - s_true, "spd_t": f["t"][scored], "spd_err": spd_err, "band": band,
              "envelope": envelope,
              "mode": f["mode"], "residuals": res_plot}
    return report, arrays


def plot(arrays: dict, out_dir: Path, title: str = "") -> list[Path]:
    """PNG plots: position error with interval and envelope, speed error with band,
    per-sensor residuals, mode timeline. Returns the files written."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out_dir.mkdir(parents=True, exist_ok=True)
    t, c = arrays["t"], arrays["claimed"]
    files = []

    def save(fig, name: str) -> None:
        files.append(out_dir / name)
        fig.tight_layout()
        fig.savefig(files[-1], dpi=110)
        plt.close(fig)

    fig, ax = plt.subplots(figsize=(10, 4.5))
    ax.fill_between(t[c], arrays["lo"][c], arrays["hi"][c], color="tab:blue", alpha=0.2,
                    label="confidence interval - truth")
    ax.plot(t[c], arrays["pos_err"][c], color="tab:blue", lw=0.8, label="position error (fused - truth)")
    env = np.where(np.isfinite(arrays["envelope"]), arrays["envelope"], np.nan)
    if np.isfinite(env).any():
        ax.plot(t, env, "k--", lw=0.7, label="ETCS envelope")
        ax.plot(t, -env, "k--", lw=0.7)
        lim = np.nanmax(np.abs(np.concatenate([arrays["lo"][c], arrays["hi"][c]]))) if c.any() else 1
        ax.set_ylim(-1.2 * lim, 1.2 * lim)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("[m]")
    ax.set_title(f"{title}: position error and confidence interval")
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)
    save(fig, "position_error.png")

    fig, ax = plt.subplots(figsize=(10, 3.5))
    st = arrays["spd_t"]
    ax.plot(st, arrays["spd_err"] / KMH, lw=0.8, label="speed error (fused - truth)")
    ax.plot(st, arrays["band"] / KMH, "k--", lw=0.7, label="SUBSET-041 band")
    ax.plot(st, -arrays["band"] / KMH, "k--", lw=0.7)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("[km/h]")
    ax.set_title(f"{title}: speed error")
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)
    save(fig, "speed_error.png")

    res = arrays["residuals"]
    n = max(1, len(res))
    fig, axes = plt.subplots(n, 1, figsize=(10, 1.8 * n + 0.6), sharex=True, squeeze=False)
    for ax, (key, (rt, r)) in zip(axes[:, 0], sorted(res.items())):
        ax.plot(rt, r, ".", ms=2)
        ax.set_ylabel(key, fontsize=7)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(f"{title}: residuals (measurement - fused) [m or m/s]")
    save(fig, "residuals.png")

    fig, ax = plt.subplots(figsize=(10, 2.0))
    ax.step(t, arrays["mode"], where="post")
    ax.set_yticks([0, 1, 2, 3], ["INIT", "NOMINAL", "DEGRADED", "LOST"])
    ax.set_xlabel("time [s]")
    ax.set_title(f"{title}: mode")
    ax.grid(alpha=0.3)
    save(fig, "modes.png")
    return files


def jsonable(obj):
    """JSON-safe copy: numpy scalars as Python numbers, NaN and infinities as None."""
    if isinstance(obj, dict):
        return {k: jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, (np.floating, float)):
        return None if not math.isfinite(float(obj)) else float(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def association_check(result) -> dict:
    """Line-level figures of a LineResult: the wayside fixes offered, used, ambiguous and
    unexplained (core/association.py), and against the truth: a used fix counts as
    ``wrong_train`` when another train's true front was nearer to it (direction alike)
    than the front of the train it went to; ``error_over_sigma_max`` is the largest
    |fix - true front of its train| / fix 1-sigma of the used fixes. On a network a fix names
    a section: it is compared in each train's route distance, and a train whose route does not
    run along that section is not near it."""
    assoc = result.associator
    scenario = result.scenario
    routes = ({name: tr.route for name, tr in scenario.trains.items()}
              if scenario is not None and scenario.network is not None else None)
    fronts = {}
    for name, run in result.trains.items():
        arr = np.array([(s.stamp, s.position, s.speed) for s in run.truth]).reshape(-1, 3)
        fronts[name] = arr
    wrong, ratios = 0, []
    for d in assoc.decisions:
        if d.train is None:
            continue
        m = d.fix
        dist = {}
        for name, arr in fronts.items():
            if not arr.size:
                continue
            v = float(np.interp(m.stamp, arr[:, 0], arr[:, 2]))
            position, direction = m.position, m.direction
            if routes is not None:
                step = routes[name].step_on(m.track_id)
                if step is None:
                    continue
                position = step.distance(m.position) - routes[name].begin
                direction = m.direction * step.direction
            if direction and abs(v) > 0.1 and (v > 0) != (direction > 0):
                continue
            dist[name] = abs(float(np.interp(m.stamp, arr[:, 0], arr[:, 1])) - position)
        if dist and min(dist, key=dist.get) != d.train:
            wrong += 1
        if d.train in dist:
            ratios.append(dist[d.train] / m.position_stddev)
        else:
            wrong += 1
    return {**assoc.summary(), "wrong_train": wrong,
            "error_over_sigma_max": float(max(ratios)) if ratios else None}


def _truth_arrays(runs: dict) -> dict:
    return {name: np.array([(s.stamp, s.position) for s in run.truth], dtype=float).reshape(-1, 2)
            for name, run in runs.items()}


def changeover_check(result) -> dict:
    """Catenary events of a LineResult's changeover section with the commands of its offline
    controller (core/wayside/changeover.py line_events), and the controller's summary."""
    from .wayside.changeover import line_events
    loop = result.changeover
    return {**line_events(loop.site, result.scenario, _truth_arrays(result.trains), loop.switchings()),
            **loop.summary()}


def recorded_changeover(bag, scenario) -> dict:
    """Catenary events of a line bag with the ABB commands recorded in it (the live
    controller's, at their log times) and the recorded truth."""
    from .bagio import read_bag
    from .convert import stamp_to_sec, truth_from_msg
    from .scenario import WAYSIDE
    from .wayside.changeover import ABB_TOPICS, line_events
    from .wayside.neutral_section import START
    site = scenario.changeover_site()
    topics = {f"/{WAYSIDE}/{topic}": switch for switch, topic in ABB_TOPICS.items()}
    truth_topics = {f"/{name}/ground_truth/state": name for name in scenario.trains}
    state = dict(START)       # the controller's start states (re-published latched: no change)
    switchings, commands, truth = [], [], {name: [] for name in scenario.trains}
    for topic, _, t_ns, msg in read_bag(bag, [*topics, *truth_topics]):
        if topic in truth_topics:
            truth[truth_topics[topic]].append((stamp_to_sec(msg.header.stamp), truth_from_msg(msg).position))
            continue
        switch, closed, t = topics[topic], bool(msg.data), t_ns / 1e9
        if closed != state[switch]:
            switchings.append(site.switching(t, switch, closed))
            commands.append({"stamp": t, "switch": switch, "on": closed})
        state[switch] = closed
    arrays = {name: np.array(v, dtype=float).reshape(-1, 2) for name, v in truth.items()}
    return {**line_events(site, scenario, arrays, switchings), "commands": commands}


def recorded_stator(bag, scenario, namespace: str) -> dict:
    """Stator feeding events of a one-train bag (core/wayside/stator.py) with the feed that the
    live stator_section_controller recorded under ``namespace`` and the recorded truth; the
    controller's parameters at their defaults (the graph's); ``switch_ons``: (decision stamp,
    section) of every section it switched on, in order."""
    from .bagio import read_bag
    from .convert import stamp_to_sec, truth_from_msg
    from .wayside import stator
    ns = namespace.rstrip("/")
    feed_topic, truth_topic = f"{ns}/{stator.FEED_TOPIC}", f"{ns}/ground_truth/state"
    feeds, truth = [], []
    for topic, _, _, msg in read_bag(bag, [feed_topic, truth_topic]):
        stamp = stamp_to_sec(msg.header.stamp)
        if topic == truth_topic:
            truth.append((stamp, truth_from_msg(msg).position))
        else:
            feeds.append((stamp, [sid for sid, on in zip(msg.section_ids, msg.fed) if on]))
    params = stator.controller_params()
    layout = stator.Layout.from_track(scenario.track, params["inverters"])
    commands = stator.commands_from_feed(feeds, params["command_latency"] + params["switch_time"])
    arr = np.array(truth, dtype=float).reshape(-1, 2)
    vehicle = stator.Vehicle(scenario.vehicle.length, scenario.orientation())
    return {**stator.evaluate(layout, commands, arr[:, 0], arr[:, 1], vehicle).as_dict(), "feed_messages": len(feeds),
            "switch_ons": [(c.stamp, c.section) for c in commands if c.on]}


def recorded_etcs(bag, scenario, namespace: str) -> dict:
    """The ETCS location reports, events and ATP commands a one-train bag holds under
    ``namespace`` (the live etcs_location and atp_supervision nodes), scored on the recorded
    truth (core/etcs/scoring.py ``location_scores``: the true front within [min, max safe front
    end] of the reports that claim a position), the LRBGs and the events that happened, the
    ATP's statuses and brakes, and the true front's closest approach to the end of authority
    (``eoa_margin`` [m], > 0 short of it)."""
    from .bagio import read_bag
    from .convert import etcs_event_from_msg, etcs_report_from_msg, stamp_to_sec
    from .etcs.records import EventKind
    from .etcs.scoring import LocationRun, location_scores
    ns = namespace.rstrip("/")
    topics = {f"{ns}/localization/etcs": "report", f"{ns}/localization/etcs_events": "event",
              f"{ns}/atp/command": "command", f"{ns}/ground_truth/state": "truth"}
    rows: dict[str, list] = {kind: [] for kind in topics.values()}
    for topic, _, _, msg in read_bag(bag, list(topics)):
        rows[topics[topic]].append((stamp_to_sec(msg.header.stamp), msg))
    o = scenario.orientation()
    truth = np.array([(t, m.position, m.speed) for t, m in rows["truth"]], dtype=float).reshape(-1, 3)
    run = LocationRun([etcs_report_from_msg(m, o) for _, m in rows["report"]],
                      [etcs_event_from_msg(m) for _, m in rows["event"]])
    scores = location_scores(run, truth[:, 0], truth[:, 1], truth[:, 2], o) if truth.size else {}
    out: dict = {"reports": len(run.reports), "claimed": scores.get("claimed", 0),
                 "events": {k: n for k, n in scores.get("events", {}).items() if n},
                 "lrbgs": [e.nid_bg for e in run.events if e.kind == EventKind.LRBG],
                 "commands": len(rows["command"]), "max_status": max((int(m.status) for _, m in rows["command"]),
                                                                       default=0),
                 "brakes": {}, "trips": sum(1 for _, m in rows["command"] if m.status == 4)}
    if "inside" in scores:
        out.update(inside=scores["inside"], outside=scores["outside"])
        if "doubt_m" in scores:
            out["doubt_m"] = scores["doubt_m"]["median"]
    for _, m in rows["command"]:
        out["brakes"][int(m.brake)] = out["brakes"].get(int(m.brake), 0) + 1
    eoas = [m.end_of_authority for _, m in rows["command"] if np.isfinite(m.end_of_authority)]
    if eoas and truth.size:
        out["end_of_authority"] = float(eoas[-1])
        out["eoa_margin"] = float(np.min((eoas[-1] - truth[:, 1]) * o))
        braked = [t for t, m in rows["command"] if m.brake]
        out["first_brake_s"] = float(braked[0]) if braked else None
    return out


def line_report(result) -> dict:
    """{"trains": train name -> evaluate() report, "association": association_check(),
    "changeover": changeover_check() (a line with a changeover section)}."""
    trains = {name: evaluate(run.truth, run.estimates, run.measurements)[0] for name, run in result.trains.items()}
    scenario = getattr(result, "scenario", None)
    for name, run in result.trains.items():
        train = scenario.trains.get(name) if scenario is not None else None
        if train is not None and train.network is not None:   # which track: core/network/scoring.py
            from .network.scoring import PublishedState, network_scores
            trains[name]["network"] = network_scores(
                train.route, [s.stamp for s in run.truth], [s.position for s in run.truth],
                [PublishedState.of_estimate(e) for e in run.estimates])
    out = {"trains": trains, "association": association_check(result),
           "wayside": {"blocks": result.blocks, "rejected": dict(result.rejected),
                       "measurements": len(result.wayside)}}
    if result.changeover is not None:
        out["changeover"] = changeover_check(result)
    return out


def recorded_network(bag, scenario, namespace: str) -> dict:
    """The states a train on a network published (localization/state and localization/tracks
    under ``namespace``), scored on its recorded truth along its route
    (core/network/scoring.py ``network_scores``: track selectivity, switch ways, states
    NOMINAL on a wrong track, the truth inside the interval and inside its true hypothesis)."""
    from .bagio import read_bag
    from .convert import stamp_to_sec, truth_from_msg
    from .network.scoring import network_scores, published_from_msgs
    ns = namespace.rstrip("/")
    topics = {f"{ns}/localization/state": "state", f"{ns}/localization/tracks": "tracks",
              f"{ns}/ground_truth/state": "truth"}
    rows: dict[str, list] = {kind: [] for kind in topics.values()}
    for topic, _, _, msg in read_bag(bag, list(topics)):
        rows[topics[topic]].append(msg)
    truth = np.array([(stamp_to_sec(m.header.stamp), truth_from_msg(m).position) for m in rows["truth"]],
                     dtype=float).reshape(-1, 2)
    if not truth.size:
        return {"states": len(rows["state"])}
    return network_scores(scenario.route, truth[:, 0], truth[:, 1], published_from_msgs(rows["state"], rows["tracks"]))


"""Benchmark of the fusion (core/fusion/): cost on the measurements of a scenario, and
accuracy figures of whole scenarios against their ground truth.

  python -m train_localization.tools.bench_fusion [--scenario config/scenario_maglev_500.yaml]
      [--duration 30] [--delay 0.2] [--seed 1] [--check]
  python -m train_localization.tools.bench_fusion --figures config/scenario_conventional_300.yaml \
      config/scenario_maglev_500.yaml config/scenario_demo.yaml
  python -m train_localization.tools.bench_fusion --lengths 60 300 1200 [--scenario ...] [--accelerometer]
  python -m train_localization.tools.bench_fusion --trains 1 2 4 [--line config/scenario_line_highspeed.yaml]
      [--duration 120]

``--accelerometer`` adds a longitudinal accelerometer to the scenario's sensors. ``--lengths`` and
``--trains``: the cost as the run grows (tools/bench_fusion_scaling.py).

Cost: the scenario's sensors are simulated once (not timed); their measurements, each
with the time at which its block completed (its arrival), are then fed to a
FusionRunner (the fusion node's logic: filter + 200 Hz publish grid) on one core, in
three orders, each without and with holding (FusionRunner ``hold``: the inputs wait up
to the sensors' declared latency and enter the filter in stamp order; the A/B ratio of
the two is measured in the same process):

  in order        as the sensors publish them (the fixes, speeds and ranges are stamped
                  inside their 50 ms blocks, so even this order has late arrivals)
  within latency  each measurement arriving at a uniform time between its arrival and
                  its stamp plus its sensor's declared latency (core/offline within_latency)
  shuffled        each measurement delayed by a further uniform 0..``delay`` s (transport,
                  wayside links): beyond the declared latency

It prints the cost of one filter update and of one estimate, then per run the CPU time
(process time: the host's load does not enter) per measurement and per published state,
the filter updates per measurement (the re-applications of a rewind included), the
rewinds (inputs inserted before a later-stamped one), the inputs later than declared,
and the real-time headroom (simulated time / CPU time). ``--check`` makes it exit non-zero
when the shuffled estimates without holding differ from the in-order ones (compared at T
once all data stamped up to T + slip_window are in), when the held runs in order and within
latency do not give the same estimates bit for bit, or when the headroom of a run is below 5.

Figures (``--figures``, ``figures(scenario, result)``): simulate_scenario of each
scenario (of a line: a block per train, then the association of the wayside fixes:
used, ambiguous, unexplained, used by the wrong train), then per published state against the truth: position error (states that
claim a position), its ratio to the ETCS SUBSET-041 envelope 5 m + 5 % of the distance
travelled since the last balise read (the last eurobalise fix; before it, since the
start), speed error and its ratio to the speed envelope (2 km/h below 30 km/h rising
linearly to 12 km/h at 500 km/h; states whose speed 1-sigma is still above 10 m/s,
i.e. before the first speed measurement, are left out), the fraction of states whose
true position lies in [position_min, position_max] and the mean width of that
interval; on a track with INPO sections also the errors where INPO covers the track
(INPO antenna over a section).
"""
from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from ..core.fusion import TrainFilter, order_key
# scenario_measurements, delayed and run (fuse_arrivals) are used by test/test_fusion.py through this module
from ..core.fusion import FusionRunner, fusion_config
from ..core.offline import delayed, scenario_measurements, within_latency
from ..core.offline import fuse_arrivals as run
from ..core.scenario import Scenario
from ..core.scoring import ENVELOPE_FIXED, ENVELOPE_RATE, SPEED_KNOWN, distance_since, speed_envelope
from .compare_estimates import same_estimates


def compare_history(config, arrivals_a, arrivals_b, t_end: float, step: float = 0.05, lag: float | None = None) -> float:
    """Largest difference of estimate(T) between two arrival orders of the same measurements.

    Every ``step`` s of arrival time, each stream gets what has arrived, and both are
    asked for estimate(T) at the latest T for which everything stamped <= T + ``lag`` has
    arrived in both (default lag: the fusion's ``slip_window``: a slip detected after T takes
    the increments of its onset out after the fact, so the states just before T can still
    change). Returns the largest |difference| of position and speed [m, m/s].
    """
    lag = config.slip_window if lag is None else lag
    runners = [FusionRunner(config), FusionRunner(config)]
    streams = [list(arrivals_a), list(arrivals_b)]
    # pending[i][j]: smallest stamp among the measurements of stream i not delivered before j
    pending = []
    for stream in streams:
        stamps = np.array([m.stamp for _, m in stream] + [math.inf])
        pending.append(np.minimum.accumulate(stamps[::-1])[::-1])
    idx = [0, 0]
    worst, last_q = 0.0, -math.inf
    for k in range(int(t_end / step) + 2):
        now = k * step
        for i in range(2):
            while idx[i] < len(streams[i]) and streams[i][idx[i]][0] <= now:
                runners[i].add(streams[i][idx[i]][1])
                idx[i] += 1
        q = min(now, *(float(np.nextafter(pending[i][idx[i]], -math.inf)) for i in range(2))) - lag
        if q <= last_q or q <= 0.0:
            continue
        last_q = q
        ea, eb = (r.filter.estimate(q) for r in runners)
        if ea.mode != eb.mode:
            return math.inf
        if math.isfinite(ea.position) or math.isfinite(eb.position):
            worst = max(worst, abs(ea.position - eb.position))
        worst = max(worst, abs(ea.speed - eb.speed))
    return worst


def _stats(err) -> dict:
    a = np.abs(err)
    if not a.size:
        return {"rms": math.nan, "p95": math.nan, "max": math.nan, "n": 0}
    return {"rms": float(np.sqrt(np.mean(a * a))), "p95": float(np.percentile(a, 95)), "max": float(a.max()),
            "n": int(a.size)}


def figures(scenario: Scenario, result) -> dict:
    """Accuracy and integrity of a simulate_scenario result against its truth (see the module doc)."""
    from ..core.fusion import MODE_INITIALISING
    from ..core.measurements import PositionFix
    truth = np.array([(s.stamp, s.position, s.speed) for s in result.truth])
    est = result.estimates
    t = np.array([e.stamp for e in est])
    if scenario.network is not None:
        # on a network: the states in path distances, as the truth runs along the route line
        # (core/network/scoring.py path_series; the route line's chainage 0 is the route's begin)
        from ..core.network.scoring import path_series
        series = path_series(est)
        begin = scenario.route.begin
        pos, lo, hi, spd = series.position - begin, series.position_min - begin, series.position_max - begin, series.speed
    else:
        pos = np.array([e.position for e in est])
        lo = np.array([e.position_min for e in est])
        hi = np.array([e.position_max for e in est])
        spd = np.array([e.speed for e in est])
    mode = np.array([e.mode for e in est])
    sd_v = np.array([e.speed_stddev for e in est])
    keep = (t >= truth[0, 0]) & (t <= truth[-1, 0])
    t, pos, lo, hi, spd, mode, sd_v = t[keep], pos[keep], lo[keep], hi[keep], spd[keep], mode[keep], sd_v[keep]
    s_true = np.interp(t, truth[:, 0], truth[:, 1])
    v_true = np.interp(t, truth[:, 0], truth[:, 2])
    reads = np.array(sorted(m.stamp for m in result.measurements
                            if isinstance(m, PositionFix) and m.sensor == "eurobalise"))
    since = distance_since(t, truth[:, 0], truth[:, 1], reads)
    claimed = (mode != MODE_INITIALISING) & np.isfinite(pos)
    err = (pos - s_true)[claimed]
    envelope = ENVELOPE_FIXED + ENVELOPE_RATE * since[claimed]
    ratio = np.abs(err) / envelope
    known = sd_v < SPEED_KNOWN
    verr = (spd - v_true)[known]
    vratio = np.abs(verr) / speed_envelope(v_true[known])
    inside = (s_true >= lo)[claimed] & (s_true <= hi)[claimed]
    width = (hi - lo)[claimed]
    out = {
        "scenario": scenario.name, "states": int(t.size), "states_with_position": int(claimed.sum()),
        "position_error_m": _stats(err),
        "envelope_ratio": {"max": float(ratio.max()) if ratio.size else math.nan,
                           "p95": float(np.percentile(ratio, 95)) if ratio.size else math.nan},
        "speed_error_kmh": _stats(verr * 3.6),
        "speed_envelope_ratio_max": float(vratio.max()) if vratio.size else math.nan,
        "integrity": {"inside_fraction": float(inside.mean()) if inside.size else math.nan,
                      "outside": int((~inside).sum()), "mean_width_m": float(width.mean()) if width.size else math.nan},
        "modes": {int(k): int(v) for k, v in zip(*np.unique(mode, return_counts=True))},
    }
    sections = scenario.track.items("inpo_section")
    if sections:
        from ..core.sensors import inpo
        params = {**{k: p.default for k, p in inpo.PARAMS.items()}, **scenario.sensors.get("inpo_receiver", {})}
        antenna = s_true - float(params["antenna_offset"])
        covered = np.zeros(t.size, dtype=bool)
        for sec in sections:
            start = float(sec.get("start", sec["position"]))
            end = float(sec["end"]) if "end" in sec else start + float(sec.get("length", scenario.track.length))
            covered |= (antenna >= start) & (antenna <= end)
        c = covered[claimed]
        out["inpo_covered"] = {"fraction": float(c.mean()), "position_error_m": _stats(err[c]),
                               "mean_width_m": float(width[c].mean()) if c.any() else math.nan}
        out["not_inpo_covered"] = {"position_error_m": _stats(err[~c]),
                                   "mean_width_m": float(width[~c].mean()) if (~c).any() else math.nan}
    return out


def print_figures(fig: dict) -> None:
    pe, se, it = fig["position_error_m"], fig["speed_error_kmh"], fig["integrity"]
    print(f"{fig['scenario']}: {fig['states']} states, {fig['states_with_position']} with a position")
    print(f"  position error rms {pe['rms']:.4f} m, p95 {pe['p95']:.4f} m, max {pe['max']:.4f} m; "
          f"SUBSET-041 envelope ratio max {fig['envelope_ratio']['max']:.4f}, p95 {fig['envelope_ratio']['p95']:.4f}")
    print(f"  speed error rms {se['rms']:.3f} km/h, p95 {se['p95']:.3f} km/h, max {se['max']:.3f} km/h; "
          f"envelope ratio max {fig['speed_envelope_ratio_max']:.3f}")
    print(f"  integrity: truth inside [min, max] in {100 * it['inside_fraction']:.3f} % of the states "
          f"({it['outside']} outside), mean interval width {it['mean_width_m']:.4f} m; modes {fig['modes']}")
    if "inpo_covered" in fig:
        c, n = fig["inpo_covered"], fig["not_inpo_covered"]
        print(f"  where INPO covers ({100 * c['fraction']:.1f} % of the states): "
              f"rms {1000 * c['position_error_m']['rms']:.2f} mm, "
              f"max {1000 * c['position_error_m']['max']:.2f} mm, mean width {1000 * c['mean_width_m']:.2f} mm; "
              f"elsewhere rms {1000 * n['position_error_m']['rms']:.2f} mm, "
              f"max {1000 * n['position_error_m']['max']:.2f} mm, mean width {1000 * n['mean_width_m']:.2f} mm")


def print_association(result) -> None:
    """The line-level figures of a line run (core/report.py association_check)."""
    from ..core.report import association_check
    a = association_check(result)
    print(f"line: {a['offered']} wayside fixes offered: {a['used']} used, {a['ambiguous']} ambiguous, "
          f"{a['unexplained']} unexplained; {a['wrong_train']} used by a train that did not cause them; "
          f"largest |fix - true front| {a['error_over_sigma_max'] or 0.0:.2f} sigma")
    print(f"  by sensor {a['by_sensor']}; used per train {a['delivered']}")


def with_accelerometer(scenario: Scenario) -> Scenario:
    """One-train ``scenario`` with a longitudinal accelerometer (its defaults) beside its sensors."""
    data = dict(scenario.description)
    data["sensors"] = {**(data.get("sensors") or {}), "accelerometer": {}}
    data["name"] = f"{scenario.name}+accelerometer"
    return Scenario.from_dict(data, source=scenario.source)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="config/scenario_maglev_500.yaml")
    ap.add_argument("--duration", type=float, default=30.0, help="simulated seconds [s]")
    ap.add_argument("--delay", type=float, default=0.2, help="largest extra delay when shuffled [s]")
    ap.add_argument("--seed", type=int, default=1, help="seed of the shuffling and of the delays within latency")
    ap.add_argument("--check", action="store_true", help="exit 1 unless exact and every run >= 5x real time")
    ap.add_argument("--figures", nargs="+", metavar="SCENARIO", help="accuracy figures of these scenarios "
                    "(simulate_scenario) instead of the cost benchmark")
    ap.add_argument("--accelerometer", action="store_true", help="the scenario's sensors and an accelerometer")
    ap.add_argument("--lengths", nargs="+", type=float, metavar="S", help="CPU per simulated second against the "
                    "run's length [s] (e.g. 60 300 1200), in order, instead of the arrival orders")
    ap.add_argument("--trains", nargs="+", type=int, metavar="N", help="CPU of the line's fusion with the first N "
                    "trains of --line (e.g. 1 2 4) over --duration s, instead of the arrival orders")
    ap.add_argument("--line", default="config/scenario_line_highspeed.yaml", help="line scenario of --trains")
    ap.add_argument("--repeat", type=int, default=1, help="--lengths, --trains: the least CPU of this many runs")
    args = ap.parse_args(argv)
    if args.figures:
        from ..core.offline import simulate_scenario
        for path in args.figures:
            sc = Scenario.from_yaml(path)
            t0 = time.perf_counter()
            result = simulate_scenario(sc)
            runs = result.trains if sc.line else {sc.train_name: result}
            for name, train_run in runs.items():   # a block per train
                print_figures(figures(sc.train(name), train_run))
                print(f"  filter counters: {train_run.runner.counters()}")
            if sc.line:
                print_association(result)
            if sc.line and result.changeover is not None:
                from ..core.report import changeover_check
                from .demo import print_changeover
                print_changeover(changeover_check(result), "the offline controller's ABB commands")
            print(f"  (simulate_scenario {time.perf_counter() - t0:.1f} s)")
        return 0
    if args.trains:
        from . import bench_fusion_scaling as scaling
        line = Scenario.from_yaml(args.line)
        duration = min(args.duration, line.duration)
        print(f"{line.name}: the line's fusion (every train's and the wayside fixes' association), {duration:.0f} s")
        scaling.print_costs(scaling.train_count_costs(line, args.trains, duration, args.repeat), per=args.trains)
        return 0
    scenario = Scenario.from_yaml(args.scenario)
    if args.accelerometer:
        scenario = with_accelerometer(scenario)
    if args.lengths:
        from . import bench_fusion_scaling as scaling
        costs = scaling.run_length_costs(scenario, args.lengths, args.repeat)
        scaling.print_costs(costs)
        return 0
    duration = min(args.duration, scenario.duration)
    t0 = time.perf_counter()
    arrivals = scenario_measurements(scenario, duration)
    print(f"{scenario.name}: {len(arrivals)} measurements in {duration:.1f} s simulated "
          f"({len(arrivals) / duration:.0f}/s; simulation {time.perf_counter() - t0:.1f} s, not timed)")
    counts: dict[str, int] = {}
    for _, m in arrivals:
        counts[m.sensor] = counts.get(m.sensor, 0) + 1
    print("  per sensor: " + ", ".join(f"{k} {v / duration:.1f}/s" for k, v in sorted(counts.items())))
    config = fusion_config(scenario)
    clock = time.process_time
    # the two elementary costs: an update (predict, scalar EKF update, snapshot) in stamp
    # order, and an estimate (prediction to a grid time, interval, mode)
    f = TrainFilter(config)
    for m in sorted((m for _, m in arrivals), key=order_key):
        f.add(m)
    c0 = clock()
    f.state()
    t_update = (clock() - c0) / max(f.applied, 1)
    grid = np.arange(0.0, duration, 0.005) + 0.002
    last = max(m.stamp for _, m in arrivals)
    c0 = clock()
    for t in grid:
        f.estimate(last + t)
    t_estimate = (clock() - c0) / len(grid)
    print(f"filter update {1e6 * t_update:.1f} us (state of {f.n}), estimate {1e6 * t_estimate:.1f} us")
    latencies = {k: m.latency for k, m in config.models.items()}
    streams = {"in order": arrivals, "within latency": within_latency(arrivals, latencies, args.seed),
               f"shuffled 0..{args.delay * 1000:.0f} ms": delayed(arrivals, args.delay, args.seed)}
    print(f"declared latency {1000 * FusionRunner(config, hold=True).latency:.0f} ms (the largest of "
          + ", ".join(f"{k} {1000 * v:.0f}" for k, v in sorted(latencies.items())) + " ms)")
    print(f"{'arrival order':<22} {'hold':<5} {'CPU s':>7} {'x real time':>11} {'us/meas':>8} {'us/state':>8} "
          f"{'updates/meas':>12} {'rewinds':>8} {'beyond latency':>14}")
    ok = True
    held = {}
    for label, stream in streams.items():
        costs = []
        for hold in (False, True):
            runner, est, t_add, t_adv = run(config, stream, duration + args.delay + 0.01,
                                            runner=FusionRunner(config, hold=hold))
            total = t_add + t_adv
            costs.append(total)
            counted = runner.counters()["rollbacks"]
            ok &= duration / total >= 5.0
            if hold:
                held[label] = est
            print(f"{label:<22} {'yes' if hold else 'no':<5} {total:>7.3f} {duration / total:>11.1f} "
                  f"{1e6 * total / len(stream):>8.1f} {1e6 * total / len(est):>8.1f} "
                  f"{counted['updates'] / len(stream):>12.2f} {counted['late']:>8d} "
                  f"{counted.get('late_beyond_latency', 0):>14d}")
        print(f"{'':<22} CPU with / without holding {costs[1] / costs[0]:.2f}")
    same = same_estimates(held["in order"], held["within latency"])
    ok &= same
    print(f"held, within latency vs in order: {'the same estimates, bit for bit' if same else 'NOT the same'}")
    diff = compare_history(config, arrivals, streams[f"shuffled 0..{args.delay * 1000:.0f} ms"], duration + args.delay)
    exact = diff <= 1e-9
    ok &= exact
    print(f"shuffled vs in order, estimate(T) once all data stamped <= T + slip_window are in: max difference "
          f"{diff:.3g} ({'exact' if exact else 'NOT exact'})")
    return 0 if ok or not args.check else 1


if __name__ == "__main__":
    sys.exit(main())

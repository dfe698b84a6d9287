"""tl_replay: offline replay of a bag through the decoders and the fusion, and its report.

  tl_replay BAG [--scenario S] [--out NEW.mcap] [--report DIR] [--recorded] [--serial] [--quiet]

Without DDS and as fast as the CPU allows, the bag's raw topics go through the
same decoders (ingest mode) and the same fusion as the live nodes; the recomputed
measurements and fused states can be written to a new bag (--out). The scenario
(track, vehicle, sensor parameters) is read from the bag's /train/scenario topic
unless --scenario is given (field recordings).
--report DIR writes report.json (error statistics, ETCS envelope, integrity,
per-sensor residuals, modes) and PNG plots. --recorded scores the bag's own
recorded localization/state instead of recomputing it. The sensors (of every
train, for a line's bag) are decoded in forked worker processes, one per CPU
besides the one this process fuses on (at least one); --serial does it all in this process, streaming the bag
(the result is the same).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from ..core import convert
from ..core.bagio import read_bag
from ..core.offline import FUSED_TOPIC, TRUTH_TOPIC, replay_bag, replay_line, scenario_from_bag
from ..graph import NAMESPACE
from ..core.report import evaluate, jsonable, line_report, plot
from ..core.scenario import Scenario
from ..core.signals import InputRejected


def recorded_run(bag: Path):
    """(truth, fused TrainState msgs, measurements, rejected) as recorded in a bag; a recorded
    measurement that fails validation is left out and counted in ``rejected`` {reason: n},
    as the fusion node refused it live."""
    truth, fused, measurements, rejected = [], [], [], {}
    parsers = {s: p for s, (_, p) in convert.MEASUREMENT_TOPICS.items()}
    for topic, _, _, msg in read_bag(bag):
        if topic == TRUTH_TOPIC:
            truth.append(convert.truth_from_msg(msg))
        elif topic == FUSED_TOPIC:
            fused.append(msg)
        elif topic.startswith(f"{NAMESPACE}/sensors/") and topic.rsplit("/", 1)[1] in parsers:
            try:
                measurements.append(parsers[topic.rsplit("/", 1)[1]](msg))
            except InputRejected as e:
                rejected[e.reason] = rejected.get(e.reason, 0) + 1
    return truth, fused, measurements, rejected


def report_for(bag: Path, scenario: Scenario | None = None, out_bag: Path | None = None,
               recorded: bool = False, progress: bool = False, parallel: bool = False) -> tuple[dict, dict]:
    """(report, plot arrays) for a bag, recomputed offline unless ``recorded``."""
    t0 = time.perf_counter()
    if recorded:
        truth, estimates, measurements, rejected = recorded_run(bag)
        extra = {"source": "recorded", "rejected_messages": rejected}
    else:
        run = replay_bag(bag, scenario, out_bag, progress=progress, parallel=parallel)
        truth, estimates, measurements = run.truth, run.estimates, run.measurements
        extra = {"source": "offline replay", "rejected_messages": run.rejected,
                 "fusion_counters": run.runner.counters()}
    if not truth:
        raise SystemExit(f"{bag}: no ground truth in the bag, nothing to score against")
    circumference = (scenario or scenario_from_bag(bag)).track.circumference
    report, arrays = evaluate(truth, estimates, measurements, circumference)
    wall = time.perf_counter() - t0
    report.update(extra)
    report["bag"] = str(bag)
    report["wall_time_s"] = wall
    report["speed_factor"] = report["duration_s"] / wall if wall > 0 else None
    return jsonable(report), arrays


def line_main(bag: Path, scenario: Scenario, out: Path | None, report_dir: Path | None,
              parallel: bool = True) -> int:
    """A line's bag (several trains): a block per train, then the association of the wayside fixes;
    report.json holds core/report.py line_report, the plots go to one directory per train."""
    t0 = time.perf_counter()
    result = replay_line(bag, scenario, out, parallel=parallel)
    wall = time.perf_counter() - t0
    report = jsonable(line_report(result))
    print(f"{bag.name}: line of {len(result.trains)} trains, {scenario.duration:.1f} s replayed in {wall:.2f} s "
          f"({scenario.duration / wall:.0f}x real time)")
    for name, rep in report["trains"].items():
        pe, integ = rep["position_error_m"], rep["integrity"]
        line = f"  {name}: {rep['states_with_position']} of {rep['states']} states with a position"
        if pe["n"]:
            line += (f"; position error RMS {pe['rms']:.4f} m, max {pe['max']:.4f} m; "
                     f"{100 * integ['inside_fraction']:.3f} % inside, mean width {integ['mean_interval_width_m']:.3f} m")
        print(line)
        net = rep.get("network")
        if net and net.get("claimed"):   # a train on a network: its track (docs/network.md)
            print(f"    track: {100 * net['on_true_track']:.2f} % on the true track, {net['nominal_wrong_track']} NOMINAL "
                  f"on a wrong one; selectivity {100 * net['selectivity']:.2f} % of {net['parallel_states']} states on "
                  f"parallel track; switch ways resolved {net['switch_ways_resolved']}/{net['switch_ways']}")
    a = report["association"]
    print(f"  wayside fixes: {a['offered']} offered, {a['used']} used, {a['ambiguous']} ambiguous, "
          f"{a['unexplained']} unexplained, {a['wrong_train']} used by the wrong train")
    if "changeover" in report:
        from .demo import print_changeover
        print_changeover(report["changeover"], "the replayed controller's ABB commands")
    if report_dir:
        report_dir.mkdir(parents=True, exist_ok=True)
        (report_dir / "report.json").write_text(json.dumps(report, indent=2))
        for name, run in result.trains.items():
            if run.truth:
                plot(evaluate(run.truth, run.estimates, run.measurements)[1], report_dir / name, f"{bag.stem} {name}")
        print(f"  report: {report_dir / 'report.json'}, plots per train in {report_dir}/<train>/")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag", type=Path)
    ap.add_argument("--scenario", help="scenario YAML (default: the one recorded in the bag)")
    ap.add_argument("--out", type=Path, help="write the recomputed run to this MCAP file")
    ap.add_argument("--report", type=Path, help="directory for report.json and the PNG plots")
    ap.add_argument("--recorded", action="store_true", help="score the recorded fused state, do not recompute")
    ap.add_argument("--serial", action="store_true",
                    help="decode in this process instead of one worker process per sensor")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    if not args.bag.exists():
        print(f"tl_replay: {args.bag} does not exist", file=sys.stderr)
        return 2
    scenario = Scenario.from_yaml(args.scenario) if args.scenario else None
    if not args.recorded and (scenario or scenario_from_bag(args.bag)).line:
        return line_main(args.bag, scenario or scenario_from_bag(args.bag), args.out, args.report,
                         parallel=not args.serial)
    report, arrays = report_for(args.bag, scenario, args.out, args.recorded, progress=not args.quiet,
                                parallel=not args.serial)
    pe, integ, env = report["position_error_m"], report["integrity"], report["etcs_envelope"]
    print(f"{args.bag.name}: {report['duration_s']:.1f} s replayed in {report['wall_time_s']:.2f} s "
          f"({report['speed_factor']:.0f}x real time)")
    if pe["n"]:
        print(f"  position error [m]: RMS {pe['rms']:.4f}  p95 {pe['p95']:.4f}  max {pe['max']:.4f}")
        print(f"  integrity: {100 * integ['inside_fraction']:.3f} % inside, mean width "
              f"{integ['mean_interval_width_m']:.3f} m")
    se = report["speed_error_mps"]
    print(f"  speed error [m/s]: RMS {se['rms']:.4f}  p95 {se['p95']:.4f}  max {se['max']:.4f}")
    if env["inside_fraction"] is not None:
        print(f"  ETCS envelope: {100 * env['inside_fraction']:.2f} % inside, p95 error/envelope "
              f"{env['p95_error_over_envelope']:.3f}")
    if args.report:
        args.report.mkdir(parents=True, exist_ok=True)
        (args.report / "report.json").write_text(json.dumps(report, indent=2))
        files = plot(arrays, args.report, args.bag.stem)
        print(f"  report: {args.report / 'report.json'}, plots: {', '.join(f.name for f in files)}")
    if args.out:
        print(f"  recomputed bag: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""tl_replay: offline replay of a bag through the decoders and the fusion, and its report.

  tl_replay BAG [--scenario S] [--out NEW.mcap] [--report DIR] [--recorded] [--serial] [--quiet]
  tl_replay FOLDER [--scenario S] [--report DIR] [--workers N] [--scheduler tcp://HOST:PORT | local]

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

A FOLDER replays every bag in it (*.mcap, a fleet's recordings re-scored after a change), each
serially in one job: on ``--workers`` local processes (default: the CPU count; 1: in this
process), or with ``--scheduler`` on a dask.distributed scheduler (``local``: a LocalCluster on
127.0.0.1), as tl_campaign runs its runs (tools/workers.py). --report DIR then holds
DIR/<bag>/report.json per bag (no plots) and DIR/summary.json: one row per bag (per train of a
line's bag) and the CPU seconds per log second of the whole.
"""
from __future__ import annotations

import argparse
import json
import os
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
from .workers import run_jobs


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


# the report fields that time the replay, not score it: they differ between two replays of a bag
TIMING_KEYS = ("wall_time_s", "speed_factor", "cpu_s", "cpu_per_log_second")


def bag_report(bag: str, scenario_path: str | None = None) -> dict:
    """The report of one bag recomputed serially (one job of a fleet replay): ``report_for``'s, or
    a line's bag's core/report.py line_report, with the CPU seconds it took and their ratio to
    the log's duration. A bag that cannot be scored raises RuntimeError."""
    c0 = time.process_time()
    path = Path(bag)
    scenario = Scenario.from_yaml(scenario_path) if scenario_path else scenario_from_bag(path)
    if scenario.line:
        report = jsonable(line_report(replay_line(path, scenario, parallel=False)))
        report.update(bag=str(path), duration_s=scenario.duration)
    else:
        try:
            report, _ = report_for(path, scenario)
        except SystemExit as exc:   # report_for's one-line refusal (no ground truth)
            raise RuntimeError(str(exc)) from None
    report["cpu_s"] = cpu = time.process_time() - c0
    report["cpu_per_log_second"] = cpu / report["duration_s"] if report["duration_s"] else None
    return report


def fleet_reports(folder: Path, scenario_path: str | None = None, workers: int | None = None,
                  scheduler: str | None = None) -> dict[str, dict]:
    """Bag file name -> ``bag_report`` of every bag in ``folder`` (sorted by name; a bag that
    failed: {"bag", "error"}), on ``workers`` local processes (1 and no scheduler: in this
    process) or a dask scheduler (tools/workers.py run_jobs)."""
    bags = sorted(folder.glob("*.mcap"))
    reports: dict[str, dict] = {}

    def lost(job: tuple, exc: BaseException) -> None:
        reports[Path(job[0]).name] = {"bag": job[0], "error": f"{type(exc).__name__}: {exc}"}

    if scheduler is None and workers == 1:
        for bag in bags:
            try:
                reports[bag.name] = bag_report(str(bag), scenario_path)
            except Exception as exc:
                lost((str(bag),), exc)
    else:
        run_jobs(bag_report, [(str(bag), scenario_path) for bag in bags], workers, scheduler,
                 lambda job, report: reports.__setitem__(Path(job[0]).name, report), lost)
    return {bag.name: reports[bag.name] for bag in bags}


def fleet_summary(reports: dict[str, dict]) -> dict:
    """One row per bag (per train of a line's bag): its scores; the bags, the failed ones, and
    the CPU seconds per log second of the whole."""
    rows = []
    for name, report in reports.items():
        if "error" in report:
            rows.append({"run": name, "error": report["error"]})
            continue
        trains = report["trains"].items() if "trains" in report else [("", report)]
        for train, rep in trains:
            pe, integ = rep["position_error_m"], rep["integrity"]
            rows.append({"run": f"{name}/{train}" if train else name, "states": rep["states"],
                         "position_rms_m": pe["rms"], "position_max_m": pe["max"],
                         "inside_fraction": integ["inside_fraction"],
                         "mean_width_m": integ["mean_interval_width_m"]})
    done = [r for r in reports.values() if "error" not in r]
    cpu, log = sum(r["cpu_s"] for r in done), sum(r["duration_s"] for r in done)
    return {"bags": len(reports), "failed": len(reports) - len(done), "rows": rows, "cpu_s": cpu, "log_s": log,
            "cpu_per_log_second": cpu / log if log else None}


def fleet_main(folder: Path, scenario_path: str | None, report_dir: Path | None, workers: int | None,
               scheduler: str | None) -> int:
    """A folder of bags (module doc): the reports, the summary, printed and written; exit 1 if a
    bag failed."""
    where = f"dask {scheduler}" if scheduler else f"{workers or os.cpu_count()} local processes"
    print(f"{folder}: {len(list(folder.glob('*.mcap')))} bags on {where}")
    reports = fleet_reports(folder, scenario_path, workers, scheduler)
    summary = fleet_summary(reports)
    for row in summary["rows"]:
        if "error" in row:
            print(f"  {row['run']}: FAILED {row['error']}")
            continue
        rms, worst, inside = row["position_rms_m"], row["position_max_m"], row["inside_fraction"]
        print(f"  {row['run']}: {row['states']} states; position error "
              + ("-" if rms is None else f"RMS {rms:.4f} m, max {worst:.4f} m")
              + ("" if inside is None else f"; {100 * inside:.3f} % inside, mean width {row['mean_width_m']:.3f} m"))
    if summary["cpu_per_log_second"] is not None:
        print(f"  {summary['log_s']:.1f} s of logs in {summary['cpu_s']:.1f} CPU s "
              f"({summary['cpu_per_log_second']:.4f} CPU s per log second); {summary['failed']} failed")
    if report_dir:
        for name, report in reports.items():
            (report_dir / Path(name).stem).mkdir(parents=True, exist_ok=True)
            (report_dir / Path(name).stem / "report.json").write_text(json.dumps(report, indent=2))
        (report_dir / "summary.json").write_text(json.dumps(summary, indent=2))
        print(f"  reports: {report_dir}/<bag>/report.json, summary: {report_dir / 'summary.json'}")
    return 1 if summary["failed"] else 0


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
    ap.add_argument("--workers", type=int, default=None, help="a folder: local worker processes (default: the CPU "
                                                               "count; 1: in this process)")
    ap.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT|local",
                    help="a folder: replay on a dask.distributed scheduler; 'local' starts a LocalCluster on 127.0.0.1")
    args = ap.parse_args(argv)
    if not args.bag.exists():
        print(f"tl_replay: {args.bag} does not exist", file=sys.stderr)
        return 2
    if args.bag.is_dir():
        if args.out or args.recorded:
            print("tl_replay: --out and --recorded take one bag, not a folder", file=sys.stderr)
            return 2
        return fleet_main(args.bag, args.scenario, args.report, args.workers, args.scheduler)
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

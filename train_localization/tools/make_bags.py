"""Record the regression bags of bags/ from the live graph and store their thresholds.

  python -m train_localization.tools.make_bags [--only NAME ...] [--rate 2]

For each entry of BAGS the demo graph (simulator, sensor nodes, fusion, recorder as
separate processes over DDS) runs the scenario and the recorder writes
bags/<name>.mcap (without /tf and odometry, which the fused state determines).
Then every bag is replayed offline and its scores, with margins, go to
bags/thresholds.json, which test/test_bags.py enforces. Re-run after a deliberate
change of a sensor model or the fusion, and say why in the commit.

A bag of RECORDINGS is no live graph's: scripts/record_drivers_bag.py writes it (a train's
drivers' standard messages and the truth); ``--only NAME --thresholds-only`` stores its bounds.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

import yaml

from ..core.offline import replay_line, scenario_from_bag
from ..core.paths import SOURCE_ROOT
from ..core.report import line_report
from ..graph import LEAN_EXCLUDE, lean_exclude
from .demo import run_graph, run_line_graph
from .replay import report_for

BAG_DIR = SOURCE_ROOT / "bags"
# name -> (scenario file, simulated duration [s], speed-up of the live run)
BAGS = {
    "maglev_500": ("config/scenario_maglev_500.yaml", 40.0, 1.0),
    "urban_stops": ("config/scenario_urban_stops.yaml", 100.0, 2.0),
    "conventional_slip": ("config/scenario_conventional_slip.yaml", 90.0, 1.0),
    "faults": ("config/scenario_faults.yaml", 60.0, 1.0),
    "stop_and_go": ("config/scenario_stop_and_go.yaml", 140.0, 2.0),
    "lzb": ("config/scenario_lzb.yaml", 80.0, 1.0),
    "track_circuit": ("config/scenario_track_circuit.yaml", 90.0, 1.0),
    "utm": ("config/scenario_utm.yaml", 90.0, 1.0),
    "mlx": ("config/scenario_mlx.yaml", 40.0, 1.0),
    "hsst": ("config/scenario_hsst.yaml", 90.0, 1.0),
    "mbahn": ("config/scenario_mbahn.yaml", 20.0, 1.0),
    "line_pair": ("config/scenario_line_pair.yaml", 40.0, 1.0),
    "rig": ("config/scenario_rig.yaml", 46.0, 1.0),
    "etcs_stop": ("config/scenario_etcs_stop.yaml", 115.0, 1.0),
    "throat": ("config/scenario_throat.yaml", 75.0, 1.0),   # both trains past their last switch
    # the three trains at rest short of their ends of authority; at 0.4 x real time: 22 nodes of three trains
    # kept up with a 2-core machine's clock at 1.0 only some of the time (sensor inputs late: DEGRADED)
    "network_line": ("config/scenario_network_line.yaml", 68.0, 0.4),
}
# the fusion's publish rate [Hz] of a bag where the default 200 Hz would take it over 5 MB: the
# supervised stops' location reports follow every state, the networks' track hypotheses too
FUSION_RATE = {"etcs_stop": 50.0, "throat": 50.0, "throat_wayside": 50.0, "network_line": 25.0}
# A line's raw blocks (every train's wheel pulses, the wayside's axle counters) fill 5 MB in about
# 30 s, before any train of the line scenarios has left its start. Their bags therefore take the
# line in its running phase: each train starts at its line speed (train name -> initial state and
# profile replacing the scenario's), placed so that it passes balises, axle-counter heads and
# track-circuit boundaries within the bag.
LINE_BAGS = {
    "line_highspeed": ("config/scenario_line_highspeed.yaml", 28.0, 1.0, {
        "train_a": ({"position": 2400.0, "speed": 83.33}, [{"speed": 83.33, "hold": 30.0}]),
        "train_b": ({"position": 1850.0, "speed": 22.22}, [{"speed": 22.22, "hold": 30.0}]),
        "train_c": ({"position": 1520.0, "speed": 22.22}, [{"speed": 22.22, "hold": 30.0}]),   # 330 m behind b
        "train_d": ({"position": 14500.0, "speed": -33.33}, [{"speed": -33.33, "hold": 30.0}])}),
    "line_conventional": ("config/scenario_line_conventional.yaml", 38.0, 1.0, {
        "ic": ({"position": 700.0, "speed": 44.44}, [{"speed": 44.44, "hold": 40.0}]),
        "reg": ({"position": 1900.0, "speed": 27.78}, [{"speed": 27.78, "hold": 40.0}]),
        "down": ({"position": 6830.0, "speed": -22.22}, [{"speed": -22.22, "hold": 40.0}])}),
    # the pair at 300 km/h through the changeover section at block headway, 46 s: train_a crosses it
    # (entering at 8.4 s, once the controller has left its start-up safe state), train_b enters S1
    # as train_a's rear leaves S2 and is switched over in the middle (at 42 s; the bag ends before
    # it reaches air section 2). The down trains are left out (None): a line's raw blocks fill 5 MB
    # in about 50 s with two trains, and one train needs 77 s through the changeover at 80 km/h
    "line_changeover": ("config/scenario_line_changeover.yaml", 46.0, 1.0, {
        "train_a": ({"position": 3300.0, "speed": 83.33}, [{"speed": 83.33, "hold": 60.0}]),
        "train_b": ({"position": 1500.0, "speed": 83.33}, [{"speed": 83.33, "hold": 60.0}]),
        "train_c": None, "train_d": None}),
    # the throat with its axle counter over the network, 36 s (the scenario's 105 s fill 12 MB). Each
    # train starts at rest where its fusion is told it stands (a start of mission on a known track:
    # a train started at speed would be somewhere else by the fusion's first state), nearer the
    # switches than in the scenario and quicker: south to 22 m/s through W2 and its wrongly
    # reported W3 until head AC9 on T7 finds the way (at 34 s); north to 16 m/s through W1 into the
    # crossover, following south into the counting areas it occupies (so the heads give north no
    # front fix, as a real counter's would not)
    "throat_wayside": ("config/scenario_throat_wayside.yaml", 36.0, 1.0, {
        "north": ({"position": 760.0, "speed": 0.0}, [{"speed": 16.0, "accel": 1.0, "jerk": 1.0, "hold": 60.0}]),
        "south": ({"position": 650.0, "speed": 0.0}, [{"speed": 22.0, "accel": 1.2, "jerk": 1.0, "hold": 60.0}])}),
}

# topics a bag leaves out besides LEAN_EXCLUDE: the network line's 22 nodes' /diagnostics would
# be a tenth of its file, and no score reads them
EXCLUDE = {"network_line": ["/diagnostics"]}

# bags written by a script of their own (name -> the script), not from the live graph
RECORDINGS = {"osm_drivers": "scripts/record_drivers_bag.py"}


def thresholds(report: dict) -> dict:
    """Bounds a later replay must respect: {metric: {"max": v} or {"min": v}}.

    Errors may grow by a margin over the recorded value; integrity and envelope
    fractions may not fall below the recorded value (integrity: below 99.9 %). A train that
    claimed no position in the bag (a line's train that passed a single reference) has speed
    bounds only."""
    pe, se, integ = report["position_error_m"], report["speed_error_mps"], report["integrity"]
    bounds = {
        "speed_error_mps.rms": {"max": se["rms"] * 1.25 + 0.002},
        "speed_error_mps.max": {"max": se["max"] * 1.5 + 0.01},
    }
    if pe["n"]:
        bounds.update({
            "position_error_m.rms": {"max": pe["rms"] * 1.25 + 0.002},
            "position_error_m.p95": {"max": pe["p95"] * 1.25 + 0.005},
            "position_error_m.max": {"max": pe["max"] * 1.5 + 0.01},
            "integrity.inside_fraction": {"min": min(integ["inside_fraction"], 0.999)},
        })
    if report["etcs_envelope"]["inside_fraction"] is not None:
        bounds["etcs_envelope.inside_fraction"] = {"min": report["etcs_envelope"]["inside_fraction"]}
    net = report.get("network")
    if net and net.get("claimed"):   # a train on a network: its track, never NOMINAL on a wrong one
        bounds["network.nominal_wrong_track"] = {"max": 0}
        bounds["network.true_hypothesis_inside"] = {"min": min(net["true_hypothesis_inside"], 0.999)}
        bounds["network.switch_ways_resolved"] = {"min": net["switch_ways_resolved"]}
        if net["parallel_states"]:
            bounds["network.selectivity"] = {"min": min(net["selectivity"], 0.999)}
    return bounds


def metric(report: dict, dotted: str) -> float:
    group, key = dotted.split(".", 1)
    return report[group][key]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="*", default=list(BAGS) + list(LINE_BAGS))
    ap.add_argument("--thresholds-only", action="store_true", help="do not record, only recompute thresholds")
    args = ap.parse_args(argv)
    BAG_DIR.mkdir(exist_ok=True)
    recorded = [name for name in args.only if name in RECORDINGS]
    if recorded and not args.thresholds_only:
        raise SystemExit(f"{', '.join(recorded)}: {RECORDINGS[recorded[0]]} records it; then --thresholds-only")
    for name in args.only:
        if args.thresholds_only:
            continue
        scenario_file, duration, rate, running = LINE_BAGS[name] if name in LINE_BAGS else (*BAGS[name], {})
        bag = BAG_DIR / f"{name}.mcap"
        with tempfile.TemporaryDirectory() as tmp:
            data = yaml.safe_load((SOURCE_ROOT / scenario_file).read_text())
            data["duration"] = duration
            data["name"] = name
            if "trains" in data:
                data["trains"] = [t for t in data["trains"] if running.get(t["name"], ()) is not None]
            for train in data.get("trains", ()):
                if train["name"] in running:
                    train["initial"], train["profile"], *sensors = running[train["name"]]
                    if sensors:
                        train["sensors"] = sensors[0]
            scen = Path(tmp) / f"{name}.yaml"
            scen.write_text(yaml.safe_dump(data, sort_keys=False))
            out = Path(tmp) / f"{name}.mcap"
            if "trains" in data:   # a line: every train's graph, the wayside, the simulator
                trains = [t["name"] for t in data["trains"]]
                codes = run_line_graph(str(scen), out, rate, Path(tmp) / "logs",
                                       exclude=lean_exclude(trains) + EXCLUDE.get(name, []),
                                       fusion_rate=FUSION_RATE.get(name))
            else:
                codes = run_graph(str(scen), out, rate, Path(tmp) / "logs", exclude=LEAN_EXCLUDE + EXCLUDE.get(name, []),
                                  fusion_rate=FUSION_RATE.get(name))
            if any(codes.values()):
                for log in (Path(tmp) / "logs").glob("*.log"):
                    print(log.name, log.read_text()[-2000:], file=sys.stderr)
                raise SystemExit(f"{name}: nodes failed: {codes}")
            shutil.move(str(out), bag)
        print(f"{bag}: {bag.stat().st_size / 1e6:.2f} MB")
    table_path = BAG_DIR / "thresholds.json"
    table = json.loads(table_path.read_text()) if table_path.exists() else {}
    for name in args.only:
        bag = BAG_DIR / f"{name}.mcap"
        scenario = scenario_from_bag(bag)
        if scenario.line:
            # per train, and no wayside fix may reach the wrong train
            report = line_report(replay_line(bag, scenario))
            table[name] = {"trains": {}, "association": {"wrong_train": {"max": 0}}}
            if "changeover" in report:   # the replayed controller: no short circuit, no air-section switching
                table[name]["changeover"] = {"short_circuits": {"max": 0}, "air_section_switchings": {"max": 0}}
            for train, rep in report["trains"].items():
                bounds = thresholds(rep)
                table[name]["trains"][train] = {"measured": {k: metric(rep, k) for k in bounds}, "bounds": bounds}
                print(name, train, json.dumps(table[name]["trains"][train]["measured"]))
            continue
        report, _ = report_for(bag)
        bounds = thresholds(report)
        table[name] = {"measured": {k: metric(report, k) for k in bounds}, "bounds": bounds}
        print(name, json.dumps(table[name]["measured"]))
    table_path.write_text(json.dumps(table, indent=2, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""tl_demo: run the whole graph on one scenario as separate processes, record a bag,
print a summary (messages per topic, fused-vs-truth errors, bag path).

  tl_demo [--scenario config/scenario_demo.yaml] [--rate 4] [--out out/demo]

Processes: recorder, one sensor node per sensor of the scenario (sim mode), fusion,
simulator; all in namespace /train with use_sim_time. A line scenario (several trains)
runs graph.line_graph instead (per train its sensor nodes in ingest mode and its fusion
in /<train>, the wayside sensor nodes and the association in /wayside, the simulator
publishing every device's raw blocks) and prints the summary of each train; with a changeover
section also its catenary events, evaluated from the ABB commands the live controller published
(recorded in the bag) against the recorded truth. DDS stays on loopback and
the run gets its own ROS_DOMAIN_ID, one in 10..99 that no other run of this project on the
host holds (tools/domains.py), unless the caller sets ROS_DOMAIN_ID and TL_DOMAIN_FROM_ENV=1.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

from ..core import paths
from ..core.bagio import read_bag, topic_counts
from ..core.report import jsonable, recorded_changeover, recorded_etcs, recorded_network, recorded_stator
from ..core.scenario import Scenario
from ..core.scoring import StateSeries, score
from ..core.offline import FUSED_TOPIC, TRUTH_TOPIC, scenario_from_bag
from ..core.wayside.stator import KIND as STATOR_KIND
from ..graph import NAMESPACE, demo_graph, graph_options, line_graph, ros_args
from . import domains


def spec_sensor(node: str) -> str:
    """Topic key of a sensor node name (doppler_radar -> doppler)."""
    from ..core.sensors import spec
    return spec(node).sensor


def executable(name: str) -> str:
    prefixes = [sys.prefix] + os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)
    for prefix in prefixes:
        candidate = Path(prefix) / "lib" / "train_localization" / name
        if candidate.exists():
            return str(candidate)
    raise FileNotFoundError(f"executable {name} not found under <prefix>/lib/train_localization "
                            "(run scripts/setup_env.sh or colcon build)")


def run_graph(scenario_path: str, bag: Path, rate: float, log_dir: Path, timeout: float | None = None,
              exclude: list[str] | None = None, fusion_rate: float | None = None) -> dict:
    """Start the demo graph, wait for the simulator to finish, stop everything; exit codes by node
    (``fusion_rate``: the fusion's publish_rate [Hz], default the node's)."""
    scenario = Scenario.from_yaml(scenario_path)
    if bag.exists():
        bag.unlink()
    graph = demo_graph(str(paths.resolve(scenario_path)), list(scenario.sensors), str(bag), rate, exclude,
                       fusion_rate=fusion_rate, **graph_options(scenario))
    return run_nodes(graph, "simulator", log_dir, timeout or (scenario.duration / max(rate, 1e-3) + 60.0))


def run_line_graph(scenario_path: str, bag: Path, rate: float, log_dir: Path, timeout: float | None = None,
                   exclude: list[str] | None = None, fusion_rate: float | None = None) -> dict:
    """Start the graph of a line scenario (graph.line_graph), wait for the simulator, stop
    everything; exit codes by node (namespace/name). ``exclude``: topics the recorder leaves out;
    ``fusion_rate``: the fusions' publish_rate [Hz], default the node's."""
    scenario = Scenario.from_yaml(scenario_path)
    if bag.exists():
        bag.unlink()
    graph = line_graph(str(paths.resolve(scenario_path)), str(bag), rate, exclude=exclude, fusion_rate=fusion_rate)
    return run_nodes(graph, "/simulator", log_dir, timeout or (scenario.duration / max(rate, 1e-3) + 60.0))


def _command(exe: str) -> list[str]:
    """The command of a node executable; a node of this package whose executable is not
    installed (an environment built before it existed) runs from its module."""
    try:
        return [executable(exe)]
    except FileNotFoundError:
        module = f"train_localization.nodes.{exe}"
        if exe.isidentifier() and (Path(__file__).parents[1] / "nodes" / f"{exe}.py").exists():
            return [sys.executable, "-c", f"from {module} import main; main()"]
        raise


def stop(proc: subprocess.Popen, timeout: float = 15.0) -> int:
    """Stop a node process as a user does (SIGINT), killed if it has not exited within
    ``timeout`` [s]; its exit code."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


def run_nodes(graph: list, driver: str, log_dir: Path, timeout: float) -> dict:
    """Start a graph's nodes (graph.py entries) as processes, wait at most ``timeout`` s for
    the ``driver`` (simulator or replayer) to finish, stop the others with SIGINT (the
    recorder last); exit codes by node. DDS on loopback and a domain of its own unless
    TL_DOMAIN_FROM_ENV=1. Entries (executable, name, parameters) run in /train and are keyed
    by name; (namespace, executable, name, parameters) run in their namespace and are keyed
    by namespace/name.

    Ctrl-C (or SIGTERM) stops every node started the same way before KeyboardInterrupt goes
    on (each runs in a session of its own: the terminal's SIGINT reaches only this process); a
    second one kills those left. The domain's lease is released once the last node has exited,
    and each node holds its lock too: the kernel keeps it while one of them lives, however this
    process ends (tools/domains.py)."""
    held = domains.lease(10, 99) if os.environ.get("TL_DOMAIN_FROM_ENV") != "1" else None
    env = domains.node_env(held.domain if held is not None else None)
    log_dir.mkdir(parents=True, exist_ok=True)
    procs: dict[str, tuple[subprocess.Popen, object]] = {}
    with _sigterm_interrupts():
        try:
            for entry in graph:
                namespace, exe, name, params = entry if len(entry) == 4 else (None, *entry)
                key = name if namespace is None else f"{namespace.rstrip('/')}/{name}"
                if exe == "recorder":
                    Path(params["output"]).parent.mkdir(parents=True, exist_ok=True)
                log = open(log_dir / f"{key.strip('/').replace('/', '_')}.log", "w")
                procs[key] = (subprocess.Popen(_command(exe) + ros_args(name, params, namespace or NAMESPACE),
                                               env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                                               pass_fds=(held.handle.fileno(),) if held is not None else ()), log)
            try:
                procs[driver][0].wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                print(f"[demo] {driver} did not finish within {timeout:.0f} s", file=sys.stderr)
            time.sleep(1.0)
        finally:
            try:
                codes = stop_nodes(procs, driver)
            finally:
                if held is not None:
                    held.release()
    return codes


def stop_nodes(procs: dict, driver: str) -> dict:
    """Stop the started nodes (key -> (process, log)) with SIGINT one after the other, the
    ``driver`` and the recorder last; a Ctrl-C meanwhile kills those left. Returns (exit codes
    by node) or raises only once every one has exited; their logs closed."""
    recorder = next((n for n in procs if n.rsplit("/", 1)[-1] == "recorder"), None)
    order = [n for n in procs if n not in (driver, recorder)] + [n for n in (recorder, driver) if n in procs]
    codes = {}
    try:
        for name in order:
            codes[name] = stop(procs[name][0])
    except KeyboardInterrupt:
        for name in order:
            proc = procs[name][0]
            if proc.poll() is None:
                proc.kill()
            codes[name] = proc.wait()
        raise
    finally:
        for _, log in procs.values():
            log.close()
    return codes


@contextmanager
def _sigterm_interrupts():
    """SIGTERM raises KeyboardInterrupt meanwhile, as Ctrl-C does (in the main thread only, where
    Python delivers signals)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def _interrupt(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _circumference(bag: Path) -> float | None:
    """The circumference [m] of the closed track a bag's scenario runs on (None: open track, or
    no scenario recorded)."""
    try:
        return scenario_from_bag(bag).track.circumference
    except ValueError:
        return None


def summarise(bag: Path, namespace: str = NAMESPACE, along_one_track: bool = True) -> dict:
    """Messages per topic, and the fused state of the train in ``namespace`` scored against its
    truth (``along_one_track``: both on one chainage; a train on a network is scored by
    core/report.py recorded_network instead)."""
    truth_topic, fused_topic = (TRUTH_TOPIC, FUSED_TOPIC) if namespace == NAMESPACE else \
        (f"{namespace}/ground_truth/state", f"{namespace}/localization/state")
    truth, fused = [], []
    for topic, _, _, msg in read_bag(bag, [truth_topic, fused_topic]):
        (truth if topic == truth_topic else fused).append(msg)
    counts = topic_counts(bag)
    result = {"bag": str(bag), "messages": counts}
    if truth:
        t = StateSeries.from_msgs(truth)
        result["duration_s"] = float(t.t[-1] - t.t[0])
        if fused and along_one_track:
            result["score"] = score(t, StateSeries.from_msgs(fused), _circumference(bag))
            result["score"]["integrity"]["confidence"] = float(fused[-1].confidence)
    return result


def print_summary(s: dict) -> None:
    print(f"\nduration (sim time): {s.get('duration_s', 0):.1f} s")
    print("messages per topic:")
    for topic, n in sorted(s["messages"].items()):
        print(f"  {n:8d}  {topic}")
    sc = s.get("score")
    if sc:
        pe, ve, integ = sc["position_error_m"], sc["speed_error_mps"], sc["integrity"]
        print("fused state vs ground truth:")
        if pe["n"]:
            print(f"  position error [m]   RMS {pe['rms']:.3f}  p95 {pe['p95']:.3f}  max {pe['max']:.3f}  "
                  f"({pe['n']} states)")
        print(f"  speed error [m/s]    RMS {ve['rms']:.3f}  p95 {ve['p95']:.3f}  max {ve['max']:.3f}")
        if integ["inside_fraction"] is not None:
            print(f"  truth inside the {100 * integ['confidence']:.1f} % interval: {100 * integ['inside_fraction']:.2f} % "
                  f"(mean width {integ['mean_interval_width_m']:.2f} m)")
        print(f"  modes (0 init, 1 nominal, 2 degraded, 3 lost): {sc['modes']}")
    print(f"bag: {s['bag']}")


def print_network(n: dict) -> None:
    """A train's states on a network scored on its route (core/report.py recorded_network)."""
    if not n.get("claimed"):
        print("  no state with a position")
        return
    pe = n["position_error_m"]
    print(f"  on the true track: {100 * n['on_true_track']:.2f} % of {n['claimed']} states; NOMINAL on a wrong "
          f"track: {n['nominal_wrong_track']}; DEGRADED {100 * n['degraded_share']:.1f} %")
    print(f"  truth inside the interval: {100 * n['inside']:.2f} %; inside its true hypothesis: "
          f"{100 * n['true_hypothesis_inside']:.2f} %; position error RMS {pe['rms']:.3f} m, max {pe['max']:.3f} m")
    sel = "n/a" if n["parallel_states"] == 0 else f"{100 * n['selectivity']:.2f} %"
    print(f"  track selectivity on parallel track: {sel} ({n['parallel_states']} states); switch ways resolved "
          f"within the clearance: {n['switch_ways_resolved']}/{n['switch_ways']}")


def print_changeover(co: dict, source: str) -> None:
    """The catenary events of a line's changeover section (core/report.py)."""
    print(f"\n[changeover] with {source}: {len(co['commands'])} ABB commands, "
          f"{co['short_circuits']} short circuits, {co['air_section_switchings']} switchings with a pantograph "
          "in an air section")
    for name, dead in co["dead_time_s"].items():
        print(f"  {name}: dead {dead:.2f} s (an unfed neutral section: {co['unfed_time_s'][name]:.2f} s; "
              f"leading pantograph over the neutral section: {co['crossing_time_s'][name]:.2f} s)")


def print_stator(st: dict) -> None:
    """The long-stator feeding events of a one-train run (core/report.py recorded_stator)."""
    print(f"\n[stator] with the live controller's recorded feed ({st['feed_messages']} messages, "
          f"{st['switchings']} switchings, {st['section_passages']} sections passed): switched off under the vehicle "
          f"{st['switched_off_under_vehicle']}, switched on late {st['switched_on_late']}, an inverter feeding two sections {st['double_feed']}, thrust lost "
          f"{st['thrust_loss_s']:.3f} s (from {st['startup_s']:.2f} s, when the first commands took effect)")


def print_etcs(e: dict) -> None:
    """The ETCS location and supervision of a one-train run (core/report.py recorded_etcs)."""
    print(f"\n[etcs] {e['reports']} location reports ({e['claimed']} with a position), true front within the safe "
          f"front ends: {e.get('inside', 0)} ({e.get('outside', 0)} outside); LRBGs {' '.join(e['lrbgs']) or '-'}; "
          f"events {e['events'] or '-'}")
    if e["commands"]:
        print(f"[atp] {e['commands']} commands, highest status {e['max_status']}, trips {e['trips']}, brakes "
              f"{e['brakes']}" + (f"; the true front came {e['eoa_margin']:.2f} m short of the end of authority "
                                   f"{e['end_of_authority']:.1f} m" if "eoa_margin" in e else ""))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="config/scenario_demo.yaml")
    ap.add_argument("--rate", type=float, default=2.0, help="simulation speed-up over real time")
    ap.add_argument("--out", default="out/demo", help="output directory (bag, logs, summary.json)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    bag = out / (Path(args.scenario).stem + ".mcap")
    print(f"[demo] scenario {args.scenario} at {args.rate}x real time; logs in {out / 'logs'}")
    scenario = Scenario.from_yaml(args.scenario)
    try:
        return _run(args, scenario, out, bag)
    except KeyboardInterrupt:
        print(f"[demo] interrupted: every node it started has stopped (logs in {out / 'logs'})", file=sys.stderr)
        return 130


def _run(args, scenario: Scenario, out: Path, bag: Path) -> int:
    """Run the graph of ``scenario``, print and write its summary; the exit code."""
    if scenario.line:
        codes = run_line_graph(args.scenario, bag, args.rate, out / "logs")
        summary = {name: summarise(bag, f"/{name}", scenario.trains[name].network is None) for name in scenario.trains}
        for name, train_summary in summary.items():
            print(f"\n[demo] train {name}")
            print_summary({**train_summary, "messages": {t: n for t, n in train_summary["messages"].items()
                                                         if t.startswith(f"/{name}/")}})
            if scenario.trains[name].network is not None:
                train_summary["network"] = jsonable(recorded_network(bag, scenario.trains[name], f"/{name}"))
                print_network(train_summary["network"])
        summary = {"trains": summary, "exit_codes": codes}
        if scenario.changeover:
            summary["changeover"] = jsonable(recorded_changeover(bag, scenario))
            print_changeover(summary["changeover"], "the live controller's recorded ABB commands")
    else:
        codes = run_graph(args.scenario, bag, args.rate, out / "logs")
        summary = summarise(bag, NAMESPACE, scenario.network is None)
        summary["exit_codes"] = codes
        print_summary(summary)
        if scenario.network is not None:   # one train on a network: scored on its route
            summary["network"] = jsonable(recorded_network(bag, scenario, NAMESPACE))
            print_network(summary["network"])
        if scenario.track.items(STATOR_KIND):
            summary["stator"] = jsonable(recorded_stator(bag, scenario, NAMESPACE))
            print_stator(summary["stator"])
        if scenario.track.etcs or scenario.atp:
            summary["etcs"] = jsonable(recorded_etcs(bag, scenario, NAMESPACE))
            print_etcs(summary["etcs"])
    bad = {n: c for n, c in codes.items() if c not in (0,)}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    if bad:
        print(f"[demo] nodes that did not exit cleanly: {bad} (see {out / 'logs'})", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

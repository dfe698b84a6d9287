"""A clean stop under load: every node of a running graph exits 0 within launch's grace
period when it is interrupted (launch sends SIGINT to every process at once, then SIGTERM
after ``sigterm_timeout``, 5 s by default), with CPU hogs beside the graph."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

from conftest import ROOT

# launch's default sigterm_timeout [s]: a node still running then is a failed process
LAUNCH_GRACE = 5.0


def test_every_node_of_a_loaded_line_graph_exits_0_within_the_grace_period_of_sigint(tmp_path):
    """The 23 nodes of the changeover line (four trains, the wayside nodes, simulator and
    recorder) running with twice as many busy processes as cores beside them, interrupted all
    at once mid-run: each exits 0 within LAUNCH_GRACE, and the recorder's bag is closed."""
    from train_localization.core.bagio import topic_counts
    from train_localization.graph import NAMESPACE, line_graph, ros_args
    from train_localization.tools.demo import _command
    scenario = str(ROOT / "config" / "scenario_line_changeover.yaml")
    bag = tmp_path / "line.mcap"
    graph = line_graph(scenario, str(bag), 1.0)
    hogs, procs, logs = [], {}, {}
    try:
        for namespace, exe, name, params in graph:
            key = f"{namespace.rstrip('/')}/{name}"
            logs[key] = tmp_path / f"{key.strip('/').replace('/', '_')}.log"
            with open(logs[key], "w") as log:
                procs[key] = subprocess.Popen(_command(exe) + ros_args(name, params, namespace or NAMESPACE),
                                              stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        deadline = time.monotonic() + 90.0     # until the simulator has started the scenario (it waits for
        while time.monotonic() < deadline:     # every subscriber) and run a few seconds of it
            if "starting scenario" in logs["/simulator"].read_text():
                break
            assert procs["/simulator"].poll() is None, logs["/simulator"].read_text()[-2000:]
            time.sleep(0.2)
        else:
            raise AssertionError("the simulator did not start the scenario within 90 s")
        # the load from here on: the graph runs and is interrupted beside the hogs (its start-up
        # is not what is tested, and 23 starts beside them kept both cores full for a minute)
        hogs += [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2 * (os.cpu_count() or 2))]
        time.sleep(8.0)
        assert all(p.poll() is None for p in procs.values()), {k: p.returncode for k, p in procs.items()}
        t0 = time.monotonic()
        for proc in procs.values():
            proc.send_signal(signal.SIGINT)
        took = {}
        while len(took) < len(procs) and time.monotonic() - t0 < 3 * LAUNCH_GRACE:
            for key, proc in procs.items():
                if key not in took and proc.poll() is not None:
                    took[key] = time.monotonic() - t0
            time.sleep(0.02)
    finally:
        for proc in [*hogs, *procs.values()]:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    late = {k: round(took.get(k, float("inf")), 2) for k in procs if took.get(k, float("inf")) > LAUNCH_GRACE}
    failed = {k: p.returncode for k, p in procs.items() if p.returncode != 0}
    assert not late and not failed, (late, failed, {k: logs[k].read_text()[-800:] for k in {**late, **failed}})
    assert len(procs) == 23
    assert topic_counts(bag)["/train_a/ground_truth/state"] > 0     # the recorder closed a readable bag


def test_the_exit_guard_ends_a_process_stuck_holding_the_interpreter_lock_with_its_code(tmp_path):
    """nodes/exit_guard.py: a process blocked in C code that holds the interpreter lock (as the
    ROS libraries' teardown was seen to, where no Python thread can run) still ends on time,
    with the exit code it was armed with."""
    script = tmp_path / "stuck.py"
    script.write_text("import ctypes, sys\nfrom train_localization.nodes import exit_guard\n"
                      "assert exit_guard.arm(0.5, int(sys.argv[1]))\n"
                      "ctypes.PyDLL(None).sleep(30)\nprint('not reached')\n")
    for code in (0, 3):
        # the process sleeps 30 s in C: an exit before the 20 s time-out (which raises) is the guard's
        done = subprocess.run([sys.executable, str(script), str(code)], capture_output=True, text=True, timeout=20,
                              cwd=ROOT)
        assert done.returncode == code, done.stderr[-2000:]
        assert "not reached" not in done.stdout

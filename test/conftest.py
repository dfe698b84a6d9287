"""Test set-up: DDS on loopback with a domain of this run's own; helpers for nodes."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from train_localization.tools import domains  # noqa: E402

# Test domains are 102..221, apart from the 10..99 that tl_demo leases for its own runs. Every
# test process (each pytest-xdist worker of scripts/test.sh) leases one of its own for its
# lifetime, so no two processes of this project on the host share one (tools/domains.py).
_DOMAIN = domains.lease(102, 221)
os.environ["ROS_DOMAIN_ID"] = str(_DOMAIN.domain)
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
os.environ["PYTHONUNBUFFERED"] = "1"

import pytest  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

# The files that take longest, longest first (pytest --durations=0, per file). scripts/test.sh hands whole files to its workers in collection order
# (--dist loadfile --no-loadscope-reorder): the long ones go first so that no worker is left
# with one of them while the other has finished (xdist's default order, by number of tests,
# put the one-test colcon build and the DDS fuzz last).
LONGEST_FIRST = ("test_nodes.py", "test_campaign.py", "test_fusion_integrity.py", "test_sensor_replay_identity.py",
                 "test_package.py", "test_network.py", "test_sensor_utm.py", "test_fusion_scenarios.py",
                 "test_network_wayside.py", "test_fuzz.py", "test_fusion_impact.py", "test_fusion_admission.py",
                 "test_bags.py", "test_sensor_axle_counter.py", "test_stop.py", "test_sensor_mmwave.py",
                 "test_sensor_mlx.py", "test_multitrain.py", "test_etcs_location.py", "test_fuzz_dds.py")


def pytest_collection_modifyitems(items):
    """Put the files of LONGEST_FIRST first, in its order; the others keep theirs."""
    rank = {name: k for k, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


@pytest.fixture(scope="session")
def ros_context():
    """rclpy initialised once for the test process."""
    import rclpy
    rclpy.init()
    yield rclpy
    rclpy.shutdown()


class NodeProcess:
    """A node executable run as a subprocess, with its output captured to a file."""

    def __init__(self, exe: str, args: list[str], log: Path):
        from train_localization.tools.demo import executable
        self.log_path = log
        self._log = open(log, "w")
        self.proc = subprocess.Popen([executable(exe)] + args, stdout=self._log, stderr=subprocess.STDOUT,
                                     start_new_session=True)

    def interrupt(self, timeout: float = 15.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                self._log.close()
                raise AssertionError(f"{self.log_path.name}: no exit within {timeout} s of SIGINT")
        self._log.close()
        return self.proc.returncode

    def output(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text()


@pytest.fixture
def start_node(tmp_path):
    procs = []

    def start(exe: str, *args: str) -> NodeProcess:
        p = NodeProcess(exe, list(args), tmp_path / f"{exe}-{len(procs)}.log")
        procs.append(p)
        return p
    yield start
    for p in procs:
        if p.proc.poll() is None:
            p.proc.kill()
            p.proc.wait()


def etcs_location_status(diags: list) -> dict:
    """The newest key/values of the etcs_location node's own status (not its inputs') among the
    received DiagnosticArray messages ``diags``; {} before the first."""
    found = [{kv.key: kv.value for kv in st.values} for arr in diags for st in arr.status
             if "ETCS location" in st.name and ": input " not in st.name]
    return found[-1] if found else {}


def spin_until(node, predicate, timeout: float = 20.0) -> bool:
    """Spin a test node until predicate() is true or the timeout passes."""
    from rclpy.executors import SingleThreadedExecutor
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            if predicate():
                return True
            ex.spin_once(timeout_sec=0.05)
        return predicate()
    finally:
        ex.remove_node(node)


def ask(node, client, request, attempts: int = 3, wait: float = 5.0):
    """Send an idempotent service request and return its reply, sending it again when none came.

    DDS matches a service's request path before its reply path: a request sent as soon as
    ``service_is_ready()`` can be answered into the void (seen in fresh-clone CI runs). Only for
    requests that may be applied twice; None when no reply came after every attempt."""
    for _ in range(attempts):
        future = client.call_async(request)
        if spin_until(node, future.done, wait):
            return future.result()
    return None


def lifecycle_replies(node, change_client, timeout: float = 30.0) -> bool:
    """Wait until a lifecycle change_state service answers, probing it with a transition label
    no node has (refused, no state change), so the first real transition's reply is not lost."""
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if spin_until(node, change_client.service_is_ready, deadline - time.monotonic()) and \
                ask(node, change_client, ChangeState.Request(transition=Transition(label="no_such_transition")),
                    attempts=1, wait=2.0) is not None:
            return True
    return False


def claimed_states(result, traj):
    """(estimates that claim a position (stddev < 10 m), fraction of them whose interval holds
    the truth, their position errors [m]) of a simulate_scenario result against its trajectory."""
    import numpy as np
    est = [e for e in result.estimates if e.position_stddev < 10.0]
    truth = np.interp(np.array([e.stamp for e in est]), traj.t, traj.position)
    inside = np.mean([(e.position_min <= x <= e.position_max) for e, x in zip(est, truth)])
    return est, inside, np.array([e.position for e in est]) - truth


def outside_scorer():
    """scripts/score_bag.py, the scorer that reads a bag with the mcap library alone, as a module."""
    import importlib.util
    spec = importlib.util.spec_from_file_location("score_bag", ROOT / "scripts" / "score_bag.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module

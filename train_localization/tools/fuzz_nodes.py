"""The processes of a fuzz run (tools/fuzz.py, tools/fuzz_attacks.py): the nodes under test,
each a subprocess on the run's own ROS domain with loopback discovery (``Child``,
``child_env``), and the fuzzer's own ROS node that publishes to them and reads their
diagnostics (``Probe``)."""
from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import time
from collections import Counter
from pathlib import Path
from typing import Any

from ..core.convert import NS, sec_to_ns
from . import domains
from .domains import DomainLease


def node_namespace(namespace: str, node: str) -> str:
    """Namespace of one node under test: ``<namespace>/<node>``, so that what a sensor node
    decodes does not reach the fusion under test."""
    return f"{namespace.rstrip('/')}/{node}"


def set_time(time_msg, t: float) -> None:
    """A builtin_interfaces/Time (a header's stamp, a Clock's clock) set to ``t`` [s]."""
    time_msg.sec, time_msg.nanosec = divmod(sec_to_ns(t), NS)


def rss_mb(pid: int) -> float | None:
    """Resident memory of a process (VmRSS of /proc/<pid>/status) [MB]; None if gone."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def pick_domain() -> DomainLease:
    """A free ROS_DOMAIN_ID in 1..101 held for the run (tools/domains.py), not the caller's own
    (its graph never sees the fuzz)."""
    own = os.environ.get("ROS_DOMAIN_ID", "").strip()
    return domains.lease(1, 101, avoid=[int(own)] if own.isdigit() else [])


def child_env(domain: int) -> dict:
    """Environment of the started nodes: loopback discovery, this run's domain, no static peers."""
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["ROS_DOMAIN_ID"] = str(domain)
    env.pop("ROS_STATIC_PEERS", None)
    env.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    env["PYTHONUNBUFFERED"] = "1"
    return env


@contextlib.contextmanager
def _loopback_discovery():
    """While this process's own DDS participant is made: loopback discovery and no static
    peers (read from the environment by rcl); the caller's environment is restored after."""
    saved = {k: os.environ.get(k) for k in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS")}
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_STATIC_PEERS", None)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


class Child:
    """A node executable run as a subprocess of its own session, output to a log file."""

    def __init__(self, exe: str, args: list[str], env: dict, log: Path):
        from .demo import executable   # the demo's imports (the offline runs) only when a node starts
        self.log_path = log
        self._log = open(log, "w")
        self._interrupted = False
        self.proc = subprocess.Popen([executable(exe)] + args, env=env, stdout=self._log,
                                     stderr=subprocess.STDOUT, start_new_session=True)

    def interrupt(self) -> None:
        """SIGINT, once."""
        if not self._interrupted and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            self._interrupted = True

    def stop(self, timeout: float) -> int:
        """SIGINT (unless sent), wait up to ``timeout`` [s], then SIGKILL; the exit code
        (negative: the signal that ended it)."""
        self.interrupt()
        try:
            self.proc.wait(timeout=max(timeout, 0.1))
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._log.close()
        return self.proc.returncode


class Probe:
    """The fuzzer's own ROS node (a context of its own on this run's domain): publishers to
    the nodes' inputs and the latest /diagnostics status of each node."""

    def __init__(self, domain: int, namespace: str, nodes: list[str]):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from diagnostic_msgs.msg import DiagnosticArray
        self.namespace = namespace
        self._by_id = {f"{node_namespace(namespace, n)}/{n}": n for n in nodes}   # hardware_id -> node
        self.context = Context()
        with _loopback_discovery():
            self.context.init(domain_id=domain)
            self.node = rclpy.create_node("fuzz_probe", namespace=namespace, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.pubs: dict[str, Any] = {}
        self.status: dict[str, dict[str, str]] = {}   # node name -> key/values of its own status
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 50)

    def _on_diag(self, arr) -> None:
        for st in arr.status:
            name = self._by_id.get(st.hardware_id)
            if name is not None and ": input " not in st.name:
                self.status[name] = {kv.key: kv.value for kv in st.values}

    def publisher(self, node: str, topic: str, cls):
        """The publisher to ``topic`` of ``node`` (relative to the node's namespace)."""
        from ..nodes.common import STREAM_QOS
        topic = f"{node_namespace(self.namespace, node)}/{topic}"
        if topic not in self.pubs:
            self.pubs[topic] = self.node.create_publisher(cls, topic, STREAM_QOS)
        return self.pubs[topic]

    def spin(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while True:
            self.executor.spin_once(timeout_sec=max(0.0, min(0.05, deadline - time.monotonic())))
            if time.monotonic() >= deadline:
                return

    def spin_until(self, predicate, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            self.executor.spin_once(timeout_sec=0.05)
        return predicate()

    def counters(self, node: str) -> tuple[int, Counter]:
        """(accepted, rejected by reason) of a node's latest diagnostics, over its inputs."""
        values = self.status.get(node, {})
        accepted = sum(int(v) for k, v in values.items() if k.startswith("accepted/"))
        rejected = Counter()
        for k, v in values.items():
            if k.startswith("rejected/"):
                rejected[k.rsplit("/", 1)[1]] += int(v)
        return accepted, rejected

    def total(self, node: str) -> int:
        accepted, rejected = self.counters(node)
        return accepted + sum(rejected.values())

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()

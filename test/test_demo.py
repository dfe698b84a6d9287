"""End to end over DDS: the demo graph on a short scenario, recorded and scored."""
from __future__ import annotations

import json

import pytest
import yaml

from conftest import ROOT
from train_localization.core.scenario import Scenario
from train_localization.tools import demo


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    data = yaml.safe_load((ROOT / "config" / "scenario_demo.yaml").read_text())
    data["duration"] = 40.0
    data["track"] = str(ROOT / "config" / "track_conventional.yaml")
    scenario = out / "scenario_short.yaml"
    scenario.write_text(yaml.safe_dump(data))
    assert demo.main(["--scenario", str(scenario), "--rate", "2", "--out", str(out)]) == 0
    return out, Scenario.from_yaml(scenario)


def test_demo_bag_holds_every_truth_state_and_the_fused_state(demo_run):
    out, scenario = demo_run
    bag = out / "scenario_short.mcap"
    counts = demo.topic_counts(bag)
    assert counts["/train/ground_truth/state"] == int(scenario.duration * scenario.truth_rate) + 1
    # the fused state through the run (its rate on a loaded host is a benchmark's figure, not this test's)
    assert counts["/train/localization/state"] > 0.5 * scenario.duration * 200.0
    for sensor in scenario.sensors:
        key = demo.spec_sensor(sensor)
        assert counts[f"/train/sensors/{key}/raw"] > 0


def test_demo_bag_decodes_with_the_mcap_library_alone(demo_run):
    from mcap_ros2.reader import read_ros2_messages
    out, _ = demo_run
    seen = {}
    for m in read_ros2_messages(str(out / "scenario_short.mcap"),
                                topics=["/train/ground_truth/state", "/train/localization/state"]):
        seen.setdefault(m.channel.topic, m.ros_msg)
    assert seen["/train/ground_truth/state"].track_id == "conventional_line"
    assert seen["/train/localization/state"].header.frame_id == "map"


def test_demo_summary_is_recomputed_from_the_bag(demo_run):
    out, _ = demo_run
    summary = json.loads((out / "summary.json").read_text())
    again = demo.summarise(out / "scenario_short.mcap")
    assert again["score"] == summary["score"]
    assert again["messages"] == summary["messages"]
    assert set(summary["exit_codes"].values()) == {0}


def test_every_diagnostics_report_is_stamped_in_the_simulated_time(demo_run):
    """The graph runs on /clock: no node's /diagnostics stamp is wall time (the simulator,
    which makes the time, stamps its reports in it too)."""
    from mcap_ros2.reader import read_ros2_messages
    out, scenario = demo_run
    stamps = {}
    for m in read_ros2_messages(str(out / "scenario_short.mcap"), topics=["/diagnostics"]):
        for status in m.ros_msg.status:
            t = m.ros_msg.header.stamp.sec + m.ros_msg.header.stamp.nanosec * 1e-9
            stamps.setdefault(status.name.split(":")[0], []).append(t)
    assert "simulator" in stamps and "fusion" in stamps
    assert all(0.0 <= t <= scenario.duration + 5.0 for ts in stamps.values() for t in ts), \
        {k: max(v) for k, v in stamps.items()}


def test_a_leased_domain_is_not_leased_again_until_released():
    """Two runs on one host never share a ROS_DOMAIN_ID (two demo graphs on one domain record
    each other's messages): a domain held by one lease is skipped by the next, whatever the
    random order, and free again once released. 232 is outside every range the project uses."""
    import subprocess
    import sys
    from train_localization.tools import domains
    first = domains.lease(232, 232)
    assert first.domain == 232
    with pytest.raises(RuntimeError, match="no free ROS_DOMAIN_ID in 232..232"):
        domains.lease(232, 232)
    other = subprocess.run([sys.executable, "-c", "from train_localization.tools import domains; "
                            "print(domains.lease(231, 232).domain)"], cwd=ROOT, capture_output=True, text=True)
    assert other.stdout.strip() == "231", other.stderr
    first.release()
    again = domains.lease(232, 232)
    assert again.domain == 232
    again.release()
    with pytest.raises(ValueError, match="within 0..232"):
        domains.lease(200, 240)


def test_a_discovery_range_set_but_empty_is_taken_as_unset():
    """tl_demo and the launch files keep the caller's ROS_AUTOMATIC_DISCOVERY_RANGE, LOCALHOST if
    unset; set but empty had been kept empty, which rmw takes for its default (the subnet: the
    nodes multicast off the machine)."""
    from train_localization.tools import domains
    assert domains.discovery_range({}) == "LOCALHOST"
    assert domains.discovery_range({"ROS_AUTOMATIC_DISCOVERY_RANGE": ""}) == "LOCALHOST"
    assert domains.discovery_range({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}) == "SUBNET"
    launch = (ROOT / "train_localization" / "launch_common.py").read_text()
    assert 'SetEnvironmentVariable("ROS_AUTOMATIC_DISCOVERY_RANGE", discovery_range(os.environ))' in launch


def _children(pid: int) -> set[int]:
    """The processes whose parent is ``pid`` (from /proc)."""
    import os
    out = set()
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat", encoding="utf-8") as fh:
                    stat = fh.read()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.add(int(entry))
    return out


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat", encoding="utf-8") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _held(domain: int) -> bool:
    """Whether some run holds ``domain``'s lease (its lock cannot be taken; released at once
    when it can)."""
    import fcntl
    from train_localization.tools import domains
    with open(domains.LOCK_DIR / f"{domain}.lock", "a") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return True
        fcntl.flock(fh, fcntl.LOCK_UN)
        return False


def test_ctrl_c_stops_every_node_and_the_lease_outlives_them(tmp_path):
    """Issue 48: Ctrl-C of tl_demo left every node it had started running (each in a session of
    its own, the terminal's SIGINT reaches none) and freed their domain. SIGINT to tl_demo
    while its graph runs: it stops every node, holds the domain while any of them lives,
    exits 130, and no node survives it."""
    import os
    import signal
    import subprocess
    import sys
    import time
    data = yaml.safe_load((ROOT / "config" / "scenario_demo.yaml").read_text())
    data["duration"] = 120.0
    data["track"] = str(ROOT / "config" / "track_conventional.yaml")
    scenario = tmp_path / "scenario_long.yaml"
    scenario.write_text(yaml.safe_dump(data))
    from train_localization.graph import demo_graph, graph_options
    sc = Scenario.from_yaml(scenario)
    expected = len(demo_graph(str(scenario), list(sc.sensors), str(tmp_path / "b.mcap"), 1.0, None,
                              **graph_options(sc)))
    env = {k: v for k, v in os.environ.items() if k not in ("ROS_DOMAIN_ID", "TL_DOMAIN_FROM_ENV")}
    proc = subprocess.Popen([sys.executable, "-m", "train_localization.tools.demo", "--scenario", str(scenario),
                             "--rate", "1", "--out", str(tmp_path / "out")], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 60.0
        while len(_children(proc.pid)) < expected and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
        nodes = _children(proc.pid)
        assert len(nodes) == expected, (nodes, proc.poll())
        with open(f"/proc/{min(nodes)}/environ", "rb") as fh:
            domain = int(dict(kv.split(b"=", 1) for kv in fh.read().split(b"\0") if b"=" in kv)[b"ROS_DOMAIN_ID"])
        time.sleep(3.0)   # the graph at work
        assert _held(domain) and all(_alive(p) for p in nodes)
        proc.send_signal(signal.SIGINT)
        while proc.poll() is None:
            if any(_alive(p) for p in nodes):
                assert _held(domain), "the domain was freed while a node still ran"
            time.sleep(0.05)
        output = proc.stdout.read()
        assert proc.returncode == 130, output
        assert "interrupted: every node it started has stopped" in output, output
        assert not [p for p in nodes if _alive(p)], output
        assert not _held(domain), output
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()

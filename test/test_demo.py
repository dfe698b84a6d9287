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
    assert counts["/train/localization/state"] > 0.9 * scenario.duration * 200.0
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

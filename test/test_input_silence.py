"""An ingest sensor node whose device is silent says so: its own /diagnostics are WARN when no
raw block arrived for ``input_timeout``, none since activation included (over DDS)."""
from __future__ import annotations

import time

from conftest import ROOT, spin_until

NS = ["-r", "__ns:=/train"]


def _own_reports(node, name: str) -> list:
    """(level, message) of every /diagnostics status of node ``name``'s own, as they come."""
    from diagnostic_msgs.msg import DiagnosticArray
    reports = []
    node.create_subscription(DiagnosticArray, "/diagnostics", lambda arr: reports.extend(
        (s.level[0], s.message) for s in arr.status if s.name.startswith(f"{name}:")), 10)
    return reports


def test_an_ingest_node_is_warn_without_raw_blocks_and_ok_while_they_come(ros_context, start_node):
    """A Doppler node in ingest mode (input_timeout 0.5 s): WARN "no raw block received" before
    the first block (it reported OK "running"), OK while blocks come at 20 Hz, WARN "no raw
    block for" once they stop."""
    from train_localization_msgs.msg import RawBlock
    from train_localization.core.convert import raw_block_to_msg
    from train_localization.core.pipeline import run_offline
    from train_localization.core.scenario import Scenario
    from train_localization.nodes.common import STREAM_QOS, rclpy_classes

    proc = start_node("doppler_radar", "--ros-args", *NS, "-p", "mode:=ingest", "-p", "input_timeout:=0.5")
    node = ros_context.create_node("probe_input_silence", namespace="/train")
    pub = node.create_publisher(RawBlock, "sensors/doppler/raw", STREAM_QOS)
    reports = _own_reports(node, "doppler_radar")
    sc = Scenario.from_yaml(ROOT / "config" / "scenario_demo.yaml")
    sc.duration = 30.0
    blocks = [b for b in run_offline("doppler_radar", sc)[0] if b.t0 > 20.0]
    mc = rclpy_classes()
    try:
        assert spin_until(node, lambda: any("no raw block received" in m for _, m in reports), 60.0), \
            (reports, proc.output())
        assert all(level == 1 for level, m in reports if "no raw block" in m), reports
        assert spin_until(node, lambda: pub.get_subscription_count() > 0, 10.0)
        reports.clear()
        deadline = time.monotonic() + 3.0
        k = 0
        while time.monotonic() < deadline and k < len(blocks):
            pub.publish(raw_block_to_msg(blocks[k], mc))
            k += 1
            spin_until(node, lambda: False, 0.05)
        # while blocks came: OK (a report may come before the first block reached the node)
        assert (0, "running") in reports, (reports, proc.output()[-2000:])
        reports.clear()
        assert spin_until(node, lambda: any(level == 1 and "no raw block for" in m for level, m in reports), 5.0), \
            reports
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_the_atp_supervision_without_any_report_says_none_was_received(ros_context, start_node):
    """No location report ever: once report_timeout (0.5 s) has passed, the supervision's status
    is WARN "no location report received" (no 'last at <start time>'); refused reports only:
    "no location report admitted (N refused)"."""
    import math
    from train_localization_msgs.msg import EtcsLocation
    from train_localization.nodes.common import STREAM_QOS

    proc = start_node("atp_supervision", "--ros-args", *NS, "-p", "report_timeout:=0.5")
    node = ros_context.create_node("probe_atp_no_report", namespace="/train")
    pub = node.create_publisher(EtcsLocation, "localization/etcs", STREAM_QOS)
    reports = _own_reports(node, "atp_supervision")
    try:
        assert spin_until(node, lambda: any("no location report received" in m for _, m in reports), 60.0), \
            (reports, proc.output())
        level, message = next((lv, m) for lv, m in reports if "no location report received" in m)
        assert level == 1 and "since the start (report_timeout 0.5 s)" in message and "last at" not in message
        assert spin_until(node, lambda: pub.get_subscription_count() > 0, 10.0)
        bad = EtcsLocation(track_id="test", mode=1, min_safe_front_end=math.nan, max_safe_front_end=100.0)
        bad.header.stamp = node.get_clock().now().to_msg()
        pub.publish(bad)
        assert spin_until(node, lambda: any("no location report admitted (1 refused)" in m for _, m in reports),
                          10.0), (reports[-3:], proc.output())
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()

"""The fusion's outputs under a flood of input it refuses (over DDS): the states and
/diagnostics keep coming, whatever the input does (nodes/fusion.py ``_outputs_when_late``; the
rate they keep is the benchmark ``tl_bench flood --invalid``)."""
from __future__ import annotations

import math
import time

import numpy as np

from conftest import spin_until

FLOOD_SECONDS = 3.0   # [s]
STATE_RATE = 200.0    # [Hz] the fusion's default publish_rate


def test_states_and_diagnostics_keep_their_rate_under_a_flood_of_invalid_speeds(ros_context, start_node):
    """NaN speeds as fast as the probe publishes (thousands a second) for 3 s: states and reports
    keep coming (the node is not starved: no gap of a second between two states), what was
    refused is counted as ``nan`` and the excess shed. The rate it keeps is a benchmark figure
    (``python -m train_localization.tools.bench flood --invalid``), not asserted here."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from train_localization_msgs.msg import SpeedMeasurement, TrainState
    from train_localization.nodes.common import STREAM_QOS
    from train_localization.tools.bench_flood import publish_flood, speed_message

    proc = start_node("fusion", "--ros-args", "-r", "__ns:=/flood", "-p", "sensors:=[doppler, eurobalise]",
                      "-p", f"publish_rate:={STATE_RATE}")
    node = ros_context.create_node("probe_invalid_flood", namespace="/flood")
    pub = node.create_publisher(SpeedMeasurement, "sensors/doppler/speed", STREAM_QOS)
    states: list[float] = []
    reports: list[tuple[float, dict]] = []   # (wall clock [s], the fusion's own key/values)

    def on_diag(arr):
        for st in arr.status:
            if st.hardware_id == "/flood/fusion" and ": input " not in st.name:
                reports.append((time.time(), {kv.key: kv.value for kv in st.values}))
    node.create_subscription(TrainState, "localization/state", lambda m: states.append(time.time()), STREAM_QOS)
    # the period of the states the node published during the flood, from their own stamps
    stamped: list[float] = []
    node.create_subscription(TrainState, "localization/state",
                             lambda m: stamped.append(m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec), STREAM_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 50)
    try:
        assert spin_until(node, lambda: pub.get_subscription_count() > 0 and len(states) > 10, 60.0), proc.output()
        ex = SingleThreadedExecutor()
        ex.add_node(node)
        sent, t0, t1 = publish_flood(pub, lambda t: speed_message(SpeedMeasurement, t, math.nan), math.inf,
                                     FLOOD_SECONDS, lambda: ex.spin_once(timeout_sec=0.0))
        deadline = time.time() + 2.0
        while time.time() < deadline:
            ex.spin_once(timeout_sec=0.05)
        ex.remove_node(node)
        during = sum(t0 + 0.5 <= s <= t1 for s in states) / (t1 - t0 - 0.5)
        diagnostics = sum(t0 + 0.5 <= t <= t1 for t, _ in reports)
        detail = (f"{sent / (t1 - t0):.0f} NaN speeds/s for {t1 - t0:.1f} s: {during:.0f} states/s, {diagnostics} "
                  f"reports in {t1 - t0 - 0.5:.1f} s")
        assert proc.proc.poll() is None, proc.output()
        flood = [t for t in stamped if t0 + 0.5 <= t <= t1]   # the node's clock is the wall clock
        assert len(flood) > 2 and max(np.diff([t0 + 0.5] + flood + [t1])) < 1.0, detail
        assert diagnostics >= 2, detail
        values = reports[-1][1]
        assert int(values.get("rejected/sensors/doppler/speed/nan", 0)) > 0, values
        assert sent <= 1000.0 * (t1 - t0) or int(values.get("shed/sensors/doppler/speed", 0)) > 0, values
        assert proc.interrupt() == 0, proc.output()
    finally:
        node.destroy_node()

"""A sensor node in simulator mode on the wall clock (no use_sim_time) refuses a truth state
stamped ahead of the truth's own time, as one on /clock refuses one ahead of its clock
(nodes/sensor.py ``_truth_clock``). Issue 48: such a node took a truth stamped + 1e6 s
and simulated every block up to it (memory 138 -> 295 MB in 40 s, no diagnostics)."""
from __future__ import annotations

import time

import pytest

from conftest import spin_until


@pytest.mark.parametrize("base", ["simulated", "wall"])
def test_a_truth_stamped_ahead_is_refused_on_the_wall_clock_and_the_real_ones_taken(base, ros_context,
                                                                                      start_node):
    """60 truth states 10 ms apart, stamped from 100 s (a simulator's time) or in the wall
    clock, and after the 21st two stamped 1000 s and 1e6 s ahead: both refused as ``future``,
    every real one taken, no burst of blocks (0.6 s of truth: at most twelve 50 ms blocks)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from train_localization_msgs.msg import RawBlock, TrainState
    from train_localization.nodes.common import STREAM_QOS
    from train_localization.tools.fuzz import set_time

    ns = f"/truth_{base}"
    proc = start_node("doppler_radar", "--ros-args", "-r", f"__ns:={ns}", "-p", "mode:=sim")
    node = ros_context.create_node(f"probe_truth_{base}", namespace=ns)
    pub = node.create_publisher(TrainState, "ground_truth/state", STREAM_QOS)
    raws, values = [], {}

    def on_diag(arr):
        for st in arr.status:
            if st.hardware_id == f"{ns}/doppler_radar":
                values.update({kv.key: kv.value for kv in st.values})
    node.create_subscription(RawBlock, "sensors/doppler/raw", raws.append, STREAM_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 50)
    try:
        assert spin_until(node, lambda: pub.get_subscription_count() > 0, 30.0), proc.output()

        def state(t: float, position: float) -> TrainState:
            m = TrainState(track_id="conventional_line", position=position, speed=20.0, mode=1)
            set_time(m.header.stamp, t)
            return m
        t0 = 100.0 if base == "simulated" else time.time()
        for k in range(60):
            t = t0 + 0.01 * k
            pub.publish(state(t, 100.0 + 0.2 * k))
            if k == 20:
                for ahead in (1000.0, 1e6):
                    pub.publish(state(t + ahead, 100.0))
            spin_until(node, lambda: False, 0.01)
        assert spin_until(node, lambda: values.get("accepted/ground_truth/state") == "60"
                          and values.get("rejected/ground_truth/state/future") == "2", 20.0), (values, proc.output())
        assert "ahead of the truth's own time" in values["last_error"] or base == "wall", values["last_error"]
        assert len(raws) <= 12, f"{len(raws)} raw blocks for 0.6 s of truth (a burst)"
        assert proc.proc.poll() is None and proc.interrupt() == 0, proc.output()
    finally:
        node.destroy_node()

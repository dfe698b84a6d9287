"""Node behaviour over DDS: start-up with use_sim_time, clean SIGINT, bad input."""
from __future__ import annotations

import math
import signal
import subprocess
import time

import numpy as np
import pytest

from conftest import ROOT, ask, lifecycle_replies, spin_until
from train_localization.core.sensors import NODE_NAMES

NS = ["-r", "__ns:=/train"]
SIM_TIME = ["-p", "use_sim_time:=true"]

NODE_ARGS = {
    "simulator": ["-p", "scenario:=config/scenario_demo.yaml", "-p", "start_delay:=0.0", "-p", "rate:=1.0"],
    "fusion": [],
    "recorder": [],
    **{name: [] for name in NODE_NAMES},
    # a device of the track's own equipment: the default track has no track circuits
    "track_circuit_receiver": ["-p", "track:=config/track_highspeed.yaml"],
    "checkin_loop": ["-p", "track:=config/track_hsst.yaml"],
    "wayside_occupancy": [], "neutral_section_controller": [], "crosscheck": [],
    "stator_section_controller": [],   # its default track (config/track_maglev.yaml) has stator sections
    "etcs_location": [],               # its default track (config/track_etcs.yaml) has ETCS data
    "atp_supervision": [],
    "rig_loop_receiver": ["-p", "track:=config/track_rig.yaml"],
    "speed_controller": ["-p", "scenario:=config/scenario_rig.yaml"],
}


# nodes started at once (each import costs about a second of CPU; the rest of a start and
# a stop is DDS discovery and shutdown, which a batch overlaps)
START_BATCH = 6
# what drives the others (the simulator's /clock, the controller's speed commands): started alone
DRIVING = ("simulator", "speed_controller")


@pytest.fixture(scope="module")
def started_and_stopped(ros_context, tmp_path_factory):
    """{exe: (up and running, exit code on SIGINT, output)} of every node of NODE_ARGS started
    with sim time, each in a namespace of its own, in batches: all of a batch are interrupted
    once each is up (or has died)."""
    from conftest import NodeProcess
    tmp = tmp_path_factory.mktemp("start_stop")
    names = sorted(NODE_ARGS)
    others = [exe for exe in names if exe not in DRIVING]
    batches = [[exe] for exe in DRIVING] + [others[k:k + START_BATCH] for k in range(0, len(others), START_BATCH)]
    outcome = {}
    node = ros_context.create_node("probe_start_stop")
    try:
        for batch in batches:
            procs = {}
            try:
                for exe in batch:
                    extra = ["-p", f"output:={tmp / 'r.mcap'}"] if exe == "recorder" else []
                    ns = NS if len(batch) == 1 else ["-r", f"__ns:=/train_{exe}"]
                    procs[exe] = NodeProcess(exe, ["--ros-args", *ns, *SIM_TIME, *NODE_ARGS[exe], *extra],
                                             tmp / f"{exe}.log")
                deadline = time.monotonic() + 30.0 * len(batch)
                up = {exe: spin_until(node, lambda: exe in node.get_node_names() or p.proc.poll() is not None,
                                      max(deadline - time.monotonic(), 1.0)) and p.proc.poll() is None
                      for exe, p in procs.items()}
                for p in procs.values():
                    if p.proc.poll() is None:
                        p.proc.send_signal(signal.SIGINT)
                for exe, p in procs.items():
                    try:
                        p.proc.wait(timeout=15.0)
                        outcome[exe] = (up[exe], p.interrupt(), p.output())   # exited: no second SIGINT
                    except subprocess.TimeoutExpired:
                        outcome[exe] = (up[exe], None, p.output() + "\n(no exit within 15 s of SIGINT)")
            finally:
                for p in procs.values():
                    if p.proc.poll() is None:
                        p.proc.kill()
                        p.proc.wait()
                    p.interrupt()    # exited by now: closes its log
    finally:
        node.destroy_node()
    return outcome


@pytest.mark.parametrize("exe", sorted(NODE_ARGS))
def test_node_starts_with_sim_time_and_stops_on_sigint(exe, started_and_stopped):
    up, code, output = started_and_stopped[exe]
    assert up, output
    assert code == 0, output
    assert "Traceback" not in output, output


def _diag_values(msgs, name_part):
    """Key/values of the latest status of a node (its own, not its per-input statuses)."""
    values = {}
    for arr in msgs:
        for st in arr.status:
            if name_part in st.name and ": input " not in st.name:
                values = {kv.key: kv.value for kv in st.values}
    return values


def test_sensor_node_rejects_bad_raw_blocks_and_keeps_running(ros_context, start_node):
    from diagnostic_msgs.msg import DiagnosticArray
    from train_localization_msgs.msg import RawBlock, SpeedMeasurement
    from train_localization.nodes.common import STREAM_QOS

    proc = start_node("doppler_radar", "--ros-args", *NS, "-p", "mode:=ingest")
    node = ros_context.create_node("probe_bad_raw", namespace="/train")
    pub = node.create_publisher(RawBlock, "sensors/doppler/raw", STREAM_QOS)
    speeds, diags = [], []
    node.create_subscription(SpeedMeasurement, "sensors/doppler/speed", speeds.append, STREAM_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    try:
        assert spin_until(node, lambda: pub.get_subscription_count() > 0 and node.count_publishers(
            "sensors/doppler/speed") > 0, 30.0), proc.output()

        def block(seq, t0, data, channels=("doppler_shift", "snr")):
            m = RawBlock(sensor="doppler", unit_id="doppler", seq=seq, sample_rate=200.0,
                         channels=list(channels), units=["Hz", "dB"][:len(channels)])
            m.header.stamp.sec, m.header.stamp.nanosec = int(t0), int(round((t0 % 1) * 1e9))
            m.data = np.asarray(data, dtype=np.float32)
            return m
        # both ends matched; let discovery settle on the node's side too before the sequence, whose
        # first block must not be lost (it failed once in a fresh clone under load)
        spin_until(node, lambda: False, 0.5)
        good = np.column_stack([np.full(10, 1000.0), np.full(10, 25.0)]).reshape(-1)
        nan = good.copy()
        nan[3] = math.nan
        sequence = [
            block(0, 1.00, good),          # ok
            block(1, 1.05, nan),           # NaN sample
            block(2, 1.05, good[:-1]),     # 19 values for 2 channels
            block(3, 1.05, good),          # ok
            block(3, 1.10, good),          # duplicate seq
            block(4, 1.02, good),          # starts before the previous block ended
            block(5, 1.10, good),          # ok
        ]
        for m in sequence:
            pub.publish(m)
        assert spin_until(node, lambda: len(speeds) >= 3 and _diag_values(diags, "doppler").get(
            "rejected/raw/stamp_back") == "1", 20.0), proc.output()
        values = _diag_values(diags, "doppler")
        assert [values.get(f"rejected/raw/{r}") for r in ("nan", "shape", "duplicate", "stamp_back")] == ["1"] * 4
        assert values["accepted/raw"] == "3"
        assert len(speeds) == 3
        v_expected = 1000.0 * 299_792_458.0 / (2 * 24.125e9 * math.cos(math.radians(45.0)))
        assert speeds[0].speed == pytest.approx(v_expected, rel=1e-6)
        assert proc.proc.poll() is None
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_fusion_node_rejects_nan_and_too_late_measurements(ros_context, start_node):
    from diagnostic_msgs.msg import DiagnosticArray
    from train_localization_msgs.msg import PositionFix, TrainState
    from train_localization.nodes.common import LATCHED_QOS, STREAM_QOS

    proc = start_node("fusion", "--ros-args", *NS, "-p", "history:=1.0")
    node = ros_context.create_node("probe_fusion", namespace="/train")
    pub = node.create_publisher(PositionFix, "sensors/eurobalise/position", STREAM_QOS)
    states, diags = [], []
    node.create_subscription(TrainState, "localization/state", states.append, LATCHED_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    try:
        assert spin_until(node, lambda: pub.get_subscription_count() > 0, 30.0), proc.output()

        def fix(t, pos, sd=1.0):   # EB000 at 500 m, the antenna 2 m behind the front
            m = PositionFix(sensor="eurobalise", unit_id="btm", track_id="conventional_line",
                            reference_id="EB000", position=pos, position_stddev=sd)
            m.header.stamp.sec, m.header.stamp.nanosec = int(t), int(round((t % 1) * 1e9))
            return m
        for m in [fix(10.0, 502.0), fix(10.5, math.nan), fix(11.0, 502.0, sd=0.0), fix(12.0, 502.5),
                  fix(10.2, 502.0), fix(12.0, 502.5)]:
            pub.publish(m)
        assert spin_until(node, lambda: _diag_values(diags, "fusion").get(
            "rejected/sensors/eurobalise/position/duplicate") == "1", 20.0), proc.output()
        values = _diag_values(diags, "fusion")
        assert values["rejected/sensors/eurobalise/position/nan"] == "1"
        assert values["rejected/sensors/eurobalise/position/stddev"] == "1"
        assert values["rejected/sensors/eurobalise/position/too_late"] == "1"
        assert values["accepted/sensors/eurobalise/position"] == "2"
        assert proc.proc.poll() is None
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_ids_of_a_megabyte_are_refused_and_never_echoed_whole(ros_context, start_node):
    """Over DDS: a fix whose sensor, track, unit or reference id is 1 MB long. A refused 1 MB
    sensor or track id had become the fusion's last_error, republished on /diagnostics every
    second; a 1 MB unit or reference id had been accepted. Every id is at most 64 characters
    (core/signals.py require_short), refused as ``too_long``, and last_error is bounded."""
    from diagnostic_msgs.msg import DiagnosticArray
    from train_localization_msgs.msg import PositionFix
    from train_localization.nodes.common import MAX_ERROR_LENGTH, STREAM_QOS

    proc = start_node("fusion", "--ros-args", *NS)
    node = ros_context.create_node("probe_long_ids", namespace="/train")
    pub = node.create_publisher(PositionFix, "sensors/eurobalise/position", STREAM_QOS)
    diags = []
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    huge = "X" * 1_000_000
    try:
        assert spin_until(node, lambda: pub.get_subscription_count() > 0, 30.0), proc.output()
        for t, field in enumerate(("sensor", "track_id", "unit_id", "reference_id")):
            ids = {"sensor": "eurobalise", "unit_id": "btm", "track_id": "conventional_line", "reference_id": "EB000"}
            m = PositionFix(**{**ids, field: huge}, position=502.0, position_stddev=1.0)
            m.header.stamp.sec = 10 + t
            pub.publish(m)
        key = "rejected/sensors/eurobalise/position/too_long"
        assert spin_until(node, lambda: _diag_values(diags, "fusion").get(key) == "4", 20.0), \
            (_diag_values(diags, "fusion"), proc.output()[-2000:])
        values = _diag_values(diags, "fusion")
        assert "accepted/sensors/eurobalise/position" not in values
        assert all(len(v) <= MAX_ERROR_LENGTH for v in values.values())
        assert max(len(line) for line in proc.output().splitlines()) < 2 * MAX_ERROR_LENGTH
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_sensor_node_in_sim_mode_rejects_bad_truth_states(ros_context, start_node):
    from diagnostic_msgs.msg import DiagnosticArray
    from train_localization_msgs.msg import RawBlock, TrainState
    from train_localization.nodes.common import STREAM_QOS

    proc = start_node("doppler_radar", "--ros-args", *NS, "-p", "mode:=sim")
    node = ros_context.create_node("probe_bad_truth", namespace="/train")
    pub = node.create_publisher(TrainState, "ground_truth/state", STREAM_QOS)
    raws, diags = [], []
    node.create_subscription(RawBlock, "sensors/doppler/raw", raws.append, STREAM_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    try:
        assert spin_until(node, lambda: pub.get_subscription_count() > 0, 30.0), proc.output()

        def state(t, position=100.0, speed=20.0):
            m = TrainState(track_id="conventional_line", position=position, speed=speed)
            m.header.stamp.sec, m.header.stamp.nanosec = int(t), int(round((t % 1) * 1e9))
            return m
        good = [state(k * 0.01, 100.0 + 0.2 * k) for k in range(30)]
        for m in good[:10] + [state(0.105, math.nan), good[5], good[9]] + good[10:]:
            pub.publish(m)
        assert spin_until(node, lambda: _diag_values(diags, "doppler").get(
            "rejected/ground_truth/state/stamp_back") == "1" and len(raws) >= 5, 20.0), proc.output()
        values = _diag_values(diags, "doppler")
        assert values["rejected/ground_truth/state/nan"] == "1"
        assert values["rejected/ground_truth/state/duplicate"] == "1"
        assert values["accepted/ground_truth/state"] == "30"
        assert len(raws) == 5  # 0.29 s of truth: five complete 50 ms blocks
        assert proc.proc.poll() is None and proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_fusion_diagnostics_level_follows_the_mode(ros_context, start_node):
    """WARN while no position is claimed, ERROR when LOST (one wayside fix and no speed
    source: the interval soon exceeds lost_stddev), OK when NOMINAL (after an operator
    reset), WARN when DEGRADED (a continuous sensor silent), with the mode named."""
    from diagnostic_msgs.msg import DiagnosticArray
    from train_localization_msgs.msg import PositionFix
    from train_localization_msgs.srv import SetPosition
    from train_localization.nodes.common import STREAM_QOS

    proc = start_node("fusion", "--ros-args", *NS, "-p", "sensors:=[axle_counter]", "-p", "lost_stddev:=5.0")
    node = ros_context.create_node("probe_fusion_diag", namespace="/train")
    pub = node.create_publisher(PositionFix, "sensors/axle_counter/position", STREAM_QOS)
    client = node.create_client(SetPosition, "localization/set_position")
    diags = []
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)

    def status():
        for arr in reversed(diags):
            for s in arr.status:
                if "fusion" in s.name:
                    return s.level[0] if isinstance(s.level, bytes) else s.level, s.message
        return None, ""

    def set_position(client):
        """Operator reset to 500 m, standing (SetPosition), answered successfully."""
        reply = ask(node, client, SetPosition.Request(position=500.0, position_stddev=0.1, speed=0.0,
                                                      speed_stddev=0.001))
        assert reply is not None and reply.success, proc.output()
    try:
        assert spin_until(node, lambda: pub.get_subscription_count() > 0 and client.service_is_ready(), 30.0), \
            proc.output()
        assert spin_until(node, lambda: status()[0] == 1 and "INITIALISING" in status()[1], 20.0), proc.output()
        m = PositionFix(sensor="axle_counter", unit_id="ac", track_id="conventional_line", reference_id="AC01",
                        position=3002.5, position_stddev=0.05)   # AC01 at 3000 m, the first axle 2.5 m back
        m.header.stamp = node.get_clock().now().to_msg()
        pub.publish(m)
        assert spin_until(node, lambda: status()[0] == 2 and "LOST" in status()[1], 30.0), proc.output()
        set_position(client)
        assert spin_until(node, lambda: status()[0] == 0 and "NOMINAL" in status()[1], 30.0), proc.output()
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()
    # a continuous sensor (the Doppler) silent beyond its timeout: DEGRADED, WARN
    proc = start_node("fusion", "--ros-args", *NS, "-p", "sensors:=[doppler,axle_counter]")
    node = ros_context.create_node("probe_fusion_degraded", namespace="/train")
    client = node.create_client(SetPosition, "localization/set_position")
    diags.clear()
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    try:
        assert spin_until(node, client.service_is_ready, 30.0), proc.output()
        set_position(client)
        assert spin_until(node, lambda: status()[0] == 1 and "DEGRADED" in status()[1], 30.0), proc.output()
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_parameters_take_integers_for_doubles_and_reject_bad_values_in_one_line(ros_context, start_node):
    """``-p publish_rate:=50`` (an integer for a double) starts the fusion; a value that is
    no number, or a scenario file that does not exist, stops it with exit code 2 and one
    line naming the problem, no traceback."""
    from train_localization_msgs.msg import TrainState
    from train_localization.nodes.common import LATCHED_QOS

    good = start_node("fusion", "--ros-args", *NS, "-p", "publish_rate:=50",
                      "-p", "sensors:=[axle_counter,wheel_sensor]")
    node = ros_context.create_node("probe_params", namespace="/train")
    states = []
    node.create_subscription(TrainState, "localization/state", states.append, LATCHED_QOS)
    try:
        assert spin_until(node, lambda: len(states) >= 5, 30.0), good.output()
        # a node name stands for its class; only the outputs that kind of sensor has
        assert node.count_subscribers("/train/sensors/wheel/distance") == 1
        assert node.count_subscribers("/train/sensors/wheel/position") == 0
        assert node.count_subscribers("/train/sensors/axle_counter/position") == 1
        assert node.count_subscribers("/train/sensors/axle_counter/speed") == 0
        assert good.proc.poll() is None and good.interrupt() == 0
    finally:
        node.destroy_node()
    for args, expected in ((["-p", "publish_rate:=fast"], "parameter 'publish_rate' must be a number"),
                           (["-p", "scenario:=no/such/scenario.yaml"], "no/such/scenario.yaml"),
                           (["-p", "sensors:=[odometer]"], "parameter 'sensors': unknown odometer")):
        bad = start_node("fusion", "--ros-args", *NS, *args)
        assert bad.proc.wait(timeout=30) == 2, bad.output()
        out = bad.output()
        assert "[fatal]" in out and expected in out and "Traceback" not in out, out


def test_a_late_joiner_gets_the_current_state_first(ros_context, start_node):
    """localization/state keeps only the latest state for late joiners: subscribed 4 s after
    the start at 1 Hz, the state handed over is a recent one, the next one newer, and the
    publisher is transient-local with a history of one (receive times cannot tell a
    history of one from a deeper one: the next publish may follow the handed-over state by
    any fraction of the period)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy
    from train_localization_msgs.msg import TrainState
    from train_localization.nodes.common import LATCHED_QOS, STATE_QOS

    proc = start_node("fusion", "--ros-args", *NS, "-p", "publish_rate:=1", "-p", "sensors:=[axle_counter]")
    node = ros_context.create_node("probe_late", namespace="/train")
    try:
        early = []
        sub = node.create_subscription(TrainState, "localization/state", early.append, LATCHED_QOS)
        assert spin_until(node, lambda: len(early) >= 1, 30.0), proc.output()
        node.destroy_subscription(sub)
        spin_until(node, lambda: False, 4.0)
        late = []
        node.create_subscription(TrainState, "localization/state",
                                 lambda m: late.append((m, node.get_clock().now().nanoseconds * 1e-9)), LATCHED_QOS)
        assert spin_until(node, lambda: len(late) >= 2, 20.0), proc.output()
        (first, received), (second, _) = late[:2]
        age = received - (first.header.stamp.sec + first.header.stamp.nanosec * 1e-9)
        assert age < 3.0, age                                   # not a state from the start
        assert second.header.stamp.sec + second.header.stamp.nanosec * 1e-9 > \
            first.header.stamp.sec + first.header.stamp.nanosec * 1e-9
        # (the graph reports the durability; DDS discovery does not carry the history depth)
        infos = node.get_publishers_info_by_topic("/train/localization/state")
        assert [i.qos_profile.durability for i in infos] == [DurabilityPolicy.TRANSIENT_LOCAL]
        assert (STATE_QOS.history, STATE_QOS.depth) == (HistoryPolicy.KEEP_LAST, 1)   # the fusion's
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_the_simulator_waits_for_the_publisher_it_is_told_to(ros_context, start_node):
    """With ``wait_for_publisher`` the simulator publishes no truth until that topic has a
    publisher (the demo graph: the fusion's localization/state), then starts."""
    from std_msgs.msg import String
    from train_localization_msgs.msg import TrainState
    from train_localization.nodes.common import STREAM_QOS

    proc = start_node("simulator", "--ros-args", *NS, "-p", "scenario:=config/scenario_demo.yaml",
                      "-p", "start_delay:=0.0", "-p", "rate:=4.0", "-p", "wait_for_publisher:=ready")
    node = ros_context.create_node("probe_ready", namespace="/train")
    try:
        truth = []
        node.create_subscription(TrainState, "ground_truth/state", truth.append, STREAM_QOS)
        assert spin_until(node, lambda: node.count_publishers("ground_truth/state") >= 1, 30.0), proc.output()
        spin_until(node, lambda: False, 3.0)
        assert truth == []
        node.create_publisher(String, "ready", 1)
        assert spin_until(node, lambda: len(truth) >= 10, 30.0), proc.output()
        assert truth[0].header.stamp.sec == 0 and truth[0].header.stamp.nanosec == 0   # from the start
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_with_an_odom_frame_the_fusion_publishes_map_to_odom_only(ros_context, start_node):
    """REP-105: with odom_frame set and another source publishing odom -> base_link, /tf
    from the fusion holds map -> odom (map -> base_link composed with the inverse of
    odom -> base_link), never a second parent of base_link; the odometry covariance lies
    along the track heading."""
    from geometry_msgs.msg import TransformStamped
    from nav_msgs.msg import Odometry
    from tf2_msgs.msg import TFMessage
    from train_localization_msgs.srv import SetPosition
    from train_localization.nodes.common import STREAM_QOS
    from train_localization.nodes.fusion import compose_inverse
    from train_localization.core.track import Track
    from train_localization.core import paths

    proc = start_node("fusion", "--ros-args", *NS, "-p", "sensors:=[axle_counter]", "-p", "odom_frame:=odom",
                      "-p", "publish_rate:=20")
    node = ros_context.create_node("probe_tf", namespace="/train")
    tf_pub = node.create_publisher(TFMessage, "/tf", 100)
    client = node.create_client(SetPosition, "localization/set_position")
    from_fusion, odoms = [], []
    node.create_subscription(TFMessage, "/tf", lambda m: from_fusion.extend(
        t for t in m.transforms if t.header.frame_id == "map"), 100)
    node.create_subscription(Odometry, "localization/odometry", odoms.append, STREAM_QOS)
    try:
        assert spin_until(node, client.service_is_ready, 30.0), proc.output()
        reply = ask(node, client, SetPosition.Request(position=1200.0, position_stddev=0.5, speed=0.0,
                                                      speed_stddev=0.001))
        assert reply is not None and reply.success, proc.output()
        ob = TransformStamped()
        ob.header.frame_id, ob.child_frame_id = "odom", "base_link"
        ob.transform.translation.x, ob.transform.translation.y = 40.0, -3.0
        ob.transform.rotation.z, ob.transform.rotation.w = math.sin(0.1), math.cos(0.1)   # yaw 0.2
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline and not (from_fusion and odoms):
            ob.header.stamp = node.get_clock().now().to_msg()
            tf_pub.publish(TFMessage(transforms=[ob]))
            spin_until(node, lambda: False, 0.2)
        assert from_fusion and odoms, proc.output()
        assert {t.child_frame_id for t in from_fusion} == {"odom"}
        x, y, yaw = Track.from_yaml(paths.resolve("config/track_conventional.yaml")).pose(1200.0)
        mo = compose_inverse((x, y, yaw), (40.0, -3.0, 0.2))
        t = from_fusion[-1].transform
        assert (t.translation.x, t.translation.y) == pytest.approx(mo[:2], abs=1e-3)
        assert 2 * math.atan2(t.rotation.z, t.rotation.w) == pytest.approx(mo[2], abs=1e-6)
        cov = np.array(odoms[-1].pose.covariance).reshape(6, 6)[:2, :2]
        heading = np.array([math.cos(yaw), math.sin(yaw)])
        assert heading @ cov @ heading == pytest.approx(np.trace(cov), rel=1e-9) and np.trace(cov) > 0.2
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_run_time_parameter_changes_take_effect_or_are_refused_with_a_reason(ros_context, start_node):
    """``ros2 param set``: publish_rate 2 -> 20 Hz takes effect; 2000 Hz is refused with its
    range; a start-up parameter (gate_probability) is read-only and refused."""
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    from train_localization_msgs.msg import TrainState
    from train_localization.nodes.common import LATCHED_QOS

    proc = start_node("fusion", "--ros-args", *NS, "-p", "publish_rate:=2", "-p", "sensors:=[axle_counter]")
    node = ros_context.create_node("probe_set", namespace="/train")
    client = node.create_client(SetParameters, "fusion/set_parameters")
    stamps = []   # the states' own stamps: the node's timer period shows in them, whatever the host's load
    node.create_subscription(TrainState, "localization/state",
                             lambda m: stamps.append(m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec), LATCHED_QOS)

    def set_param(name, value):
        v = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
        reply = ask(node, client, SetParameters.Request(parameters=[Parameter(name=name, value=v)]))
        assert reply is not None, proc.output()
        return reply.results[0]

    def period_of_next(n):
        """The median interval [s] of the stamps of the next n states."""
        n0 = len(stamps)
        assert spin_until(node, lambda: len(stamps) >= n0 + n, 60.0), proc.output()
        return float(np.median(np.diff(stamps[n0:n0 + n])))
    try:
        assert spin_until(node, lambda: client.service_is_ready() and len(stamps) >= 2, 30.0), proc.output()
        assert period_of_next(4) == pytest.approx(0.5, rel=0.2)
        assert set_param("publish_rate", 20.0).successful
        period_of_next(2)   # the one in flight when the rate changed
        assert period_of_next(9) == pytest.approx(0.05, rel=0.2)
        refused = set_param("publish_rate", 2000.0)   # beyond the range in its descriptor: rclpy refuses
        assert not refused.successful and "publish_rate out of range Min: 0.0, Max: 1000.0" in refused.reason
        refused = set_param("publish_rate", 0.0)      # in the range, but no rate: the node refuses
        assert not refused.successful and "(0, 1000]" in refused.reason
        refused = set_param("gate_probability", 2.0)
        assert not refused.successful and "read-only" in refused.reason.lower()
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_fusion_parameters_out_of_range_stop_the_node_in_one_line(start_node):
    """A tuning value beyond its limits (in the parameter's descriptor: rclpy refuses it, or for
    an integer given to a double, the node) names the parameter."""
    for arg, expected in (("gate_probability:=2.0", "gate_probability out of range"),
                          ("slip_window:=-1.0", "slip_window out of range"),
                          ("slip_window:=100", "parameter 'slip_window' must be in 0.05 .. 30, not 100.0"),
                          ("consistency_fixes:=1", "consistency_fixes out of range"),
                          ("publish_rate:=0", "publish_rate' must be in (0, 1000]")):
        proc = start_node("fusion", "--ros-args", *NS, "-p", arg, "-p", "sensors:=[axle_counter]")
        assert proc.proc.wait(timeout=30) == 2, proc.output()
        assert expected in proc.output() and "Traceback" not in proc.output(), proc.output()


def test_fusion_takes_nested_per_sensor_parameters_from_a_params_file(ros_context, start_node, tmp_path):
    """The usual YAML params-file form: ``doppler: {scale_sigma: ...}`` nested under the node
    overrides that field of the Doppler's own error model (logged), integers are taken for
    doubles and read back as doubles (also one set at run time), a nested field has its range
    in its descriptor, one beyond it stops the node in one line, and the example file in
    config/params starts the node."""
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import DescribeParameters, GetParameters, SetParameters
    from conftest import ROOT

    params = tmp_path / "fusion.yaml"
    params.write_text("/train/fusion:\n  ros__parameters:\n    sensors: [doppler, eurobalise]\n"
                      "    publish_rate: 20\n    doppler:\n      scale_sigma: 0.02\n      timeout: 3\n")
    proc = start_node("fusion", "--ros-args", *NS, "--params-file", str(params))
    node = ros_context.create_node("probe_params_file", namespace="/train")
    client = node.create_client(GetParameters, "fusion/get_parameters")
    try:
        assert spin_until(node, client.service_is_ready, 30.0), proc.output()
        reply = ask(node, client, GetParameters.Request(names=["doppler.scale_sigma", "doppler.timeout",
                                                               "publish_rate", "eurobalise.faults"]))
        assert reply is not None, proc.output()
        values = reply.values   # the integers given (3, 20) are stored as the doubles they mean
        assert [v.type for v in values[:3]] == [ParameterType.PARAMETER_DOUBLE] * 3
        assert [v.double_value for v in values[:3]] == [0.02, 3.0, 20.0]
        assert values[3].string_value == "misread,offset"
        assert "error model of doppler overridden: scale_sigma=0.02, timeout=3.0" in proc.output()
        assert "eurobalise overridden" not in proc.output()
        describe = node.create_client(DescribeParameters, "fusion/describe_parameters")
        assert spin_until(node, describe.service_is_ready, 10.0)
        described = ask(node, describe, DescribeParameters.Request(names=["doppler.scale_sigma",
                                                                         "doppler.timeout"])).descriptors
        assert [(d.floating_point_range[0].from_value, d.floating_point_range[0].to_value) for d in described] \
            == [(0.0, 1.0), (0.0, float("inf"))]
        assert all(d.read_only for d in described)
        setter = node.create_client(SetParameters, "fusion/set_parameters")
        assert spin_until(node, setter.service_is_ready, 10.0)
        integer = ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=40)
        assert ask(node, setter, SetParameters.Request(parameters=[Parameter(name="publish_rate",
                                                                             value=integer)])).results[0].successful
        rate = ask(node, client, GetParameters.Request(names=["publish_rate"])).values[0]
        assert (rate.type, rate.double_value) == (ParameterType.PARAMETER_DOUBLE, 40.0)
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()
    params.write_text("/**:\n  ros__parameters:\n    sensors: [doppler]\n    doppler:\n      scale_sigma: 2.0\n")
    beyond = start_node("fusion", "--ros-args", *NS, "--params-file", str(params))
    assert beyond.proc.wait(timeout=30) == 2, beyond.output()
    assert "doppler.scale_sigma out of range" in beyond.output() and "Traceback" not in beyond.output()
    # the example, run as its header says (no namespace given: its keys must apply anyway)
    example = start_node("fusion", "--ros-args", "--params-file", str(ROOT / "config" / "params" / "fusion.yaml"))
    spin_until(ros_context.create_node("probe_example"), lambda: "overridden" in example.output(), 20.0)
    assert example.proc.poll() is None, example.output()
    assert "error model of doppler overridden: scale_sigma=0.004" in example.output()
    assert example.interrupt() == 0


@pytest.mark.parametrize("exe", ["wheel_sensor", "eurobalise_reader"])
def test_a_sensor_node_starts_from_its_example_params_file(exe, start_node, tmp_path, ros_context):
    """config/params/<node>.yaml (every parameter at its default, NaN included) is read by
    ROS's own params-file parser, in the demo's namespace (its keys apply in any; run as its
    header says: test_params_files); the node then runs until interrupted. A value changed in a
    copy is applied (the files had been keyed /train/<node>: run as documented, they applied
    nothing)."""
    from conftest import ROOT
    text = (ROOT / "config" / "params" / f"{exe}.yaml").read_text()
    header = text.splitlines()[1]
    assert header == f"# ros2 run train_localization {exe} --ros-args --params-file config/params/{exe}.yaml"
    probe = ros_context.create_node(f"probe_params_{exe}")
    for ns in (NS,):
        proc = start_node(exe, "--ros-args", *ns, "--params-file", str(ROOT / "config" / "params" / f"{exe}.yaml"),
                          "-p", "mode:=ingest")
        # up once it is in the graph (a loaded host takes seconds to import; a fixed sleep
        # interrupted some mid-import), then running on
        deadline = time.monotonic() + 60.0
        while exe not in [n for n, _ in probe.get_node_names_and_namespaces()] and time.monotonic() < deadline \
                and proc.proc.poll() is None:
            time.sleep(0.2)
        time.sleep(1.0)
        assert proc.proc.poll() is None, proc.output()
        assert proc.interrupt() == 0, proc.output()
    probe.destroy_node()
    bad = tmp_path / f"{exe}.yaml"
    bad.write_text(text.replace("    mode: \"sim\"", "    mode: \"neither\""))
    proc = start_node(exe, "--ros-args", "--params-file", str(bad))
    assert proc.proc.wait(timeout=30) == 2 and "mode" in proc.output(), proc.output()


def test_fusion_reports_each_input_with_its_frequency_and_silence(ros_context, start_node):
    """One diagnostic status per subscribed sensor: the Doppler at 20 Hz is OK with its
    frequency; silent beyond its timeout it is WARN; the axle counter (an event sensor, no
    timeout) stays OK."""
    from diagnostic_msgs.msg import DiagnosticArray
    from train_localization_msgs.msg import SpeedMeasurement
    from train_localization.nodes.common import STREAM_QOS

    proc = start_node("fusion", "--ros-args", *NS, "-p", "sensors:=[doppler,axle_counter]")
    node = ros_context.create_node("probe_inputs", namespace="/train")
    pub = node.create_publisher(SpeedMeasurement, "sensors/doppler/speed", STREAM_QOS)
    diags = []
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)

    def latest(name):
        for arr in reversed(diags):
            for s in arr.status:
                if s.name.endswith(name):
                    return s.level[0] if isinstance(s.level, bytes) else s.level, {v.key: v.value for v in s.values}
        return None, {}
    try:
        assert spin_until(node, lambda: pub.get_subscription_count() > 0, 30.0), proc.output()
        diags.clear()
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            m = SpeedMeasurement(sensor="doppler", unit_id="radar", speed=10.0, speed_stddev=0.1)
            m.header.stamp = node.get_clock().now().to_msg()
            pub.publish(m)
            spin_until(node, lambda: False, 0.05)
        level, values = latest("input doppler")
        assert level == 0 and 12.0 < float(values["frequency_hz"]) < 25.0, values
        assert latest("input axle_counter")[0] == 0
        assert spin_until(node, lambda: latest("input doppler")[0] == 1, 10.0), proc.output()
        assert latest("input axle_counter")[0] == 0
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_an_event_input_that_misses_a_reference_the_train_passed_is_a_warning(ros_context, start_node):
    """Over DDS, simulated time: a train at 100 m/s located by balises EB000 and EB001 (1 km
    apart); the reader then says nothing while the fused interval passes EB002. The fusion's
    status of that input had stayed OK (no timeout for an event sensor); it is WARN naming the
    balise, and OK again once a fix of EB003 comes."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rosgraph_msgs.msg import Clock
    from train_localization_msgs.msg import PositionFix, SpeedMeasurement
    from train_localization.nodes.common import CLOCK_QOS, STREAM_QOS

    proc = start_node("fusion", "--ros-args", *NS, "-p", "use_sim_time:=true", "-p", "sensors:=[doppler,eurobalise]")
    node = ros_context.create_node("probe_expected", namespace="/train")
    clock_pub = node.create_publisher(Clock, "/clock", CLOCK_QOS)
    speed_pub = node.create_publisher(SpeedMeasurement, "sensors/doppler/speed", STREAM_QOS)
    fix_pub = node.create_publisher(PositionFix, "sensors/eurobalise/position", STREAM_QOS)
    diags = []
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)

    def stamp(m, t):
        m.header.stamp.sec, m.header.stamp.nanosec = int(t), int(round((t % 1) * 1e9))
        return m

    def balise():
        for arr in reversed(diags):
            for st in arr.status:
                if st.name.endswith("input eurobalise"):
                    return (st.level[0] if isinstance(st.level, bytes) else st.level), st.message
        return None, ""

    def overall(since=0):
        """(level, message) of the fusion's own status in every report from diags[since]."""
        return [(st.level[0], st.message) for arr in diags[since:] for st in arr.status if st.name == "fusion: fusion"]

    def drive(t0, t1, fixes):
        for k in range(int(round(t0 * 20)), int(round(t1 * 20))):
            t = k / 20.0
            clock = Clock()
            clock.clock.sec, clock.clock.nanosec = int(t), int(round((t % 1) * 1e9))
            clock_pub.publish(clock)
            speed_pub.publish(stamp(SpeedMeasurement(sensor="doppler", unit_id="radar", speed=100.0,
                                                     speed_stddev=0.1), t))
            if k % 200 == 0 and k // 200 in fixes:
                n = k // 200
                fix_pub.publish(stamp(PositionFix(sensor="eurobalise", unit_id="btm", track_id="conventional_line",
                                                  reference_id=f"EB{n:03d}", position=502.0 + 1000.0 * n,
                                                  position_stddev=0.4), t))
                # let the fix reach the node before the clock runs on: on a loaded host it was
                # taken 3.5 s of simulated time late, beyond the fusion's history
                spin_until(node, lambda: False, 0.2)
            if k % 5 == 0:
                spin_until(node, lambda: False, 0.03)
    try:
        assert spin_until(node, lambda: fix_pub.get_subscription_count() > 0 and speed_pub.get_subscription_count() > 0,
                          30.0), proc.output()
        drive(0.0, 15.0, fixes={0, 1})
        # located, every input OK: the fusion's own status OK (NOMINAL)
        assert any(level == 0 and msg.startswith("NOMINAL") for level, msg in overall()), overall()
        spin_until(node, lambda: False, 1.5)
        assert balise()[0] == 0, balise()
        mark = len(diags)
        drive(15.0, 26.0, fixes=set())                    # past EB002 (2,502 m at 20 s)
        assert spin_until(node, lambda: balise()[0] == 1, 5.0), (balise(), proc.output()[-1500:])
        assert "EB002" in balise()[1]
        # the fusion's own status says it too (it stayed OK NOMINAL)
        assert any(level == 1 and msg.startswith("NOMINAL") and "input eurobalise: no fix since" in msg
                   for level, msg in overall(mark)), overall(mark)
        drive(26.0, 31.0, fixes={3})                      # EB003 read at 30 s
        assert spin_until(node, lambda: balise()[0] == 0, 5.0), balise()
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_managed_fusion_follows_its_lifecycle_transitions(ros_context, start_node):
    """managed:=true: unconfigured at start (nothing published); configure -> inactive;
    activate -> states published; deactivate -> none; activate again -> published; cleanup
    after deactivate -> unconfigured; a bad configuration fails the configure transition
    with its reason logged, and the node stays up."""
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState, GetState
    from train_localization_msgs.msg import TrainState
    from train_localization.nodes.common import LATCHED_QOS

    proc = start_node("fusion", "--ros-args", *NS, "-p", "managed:=true", "-p", "publish_rate:=20",
                      "-p", "sensors:=[axle_counter]")
    node = ros_context.create_node("probe_lifecycle", namespace="/train")
    change = node.create_client(ChangeState, "fusion/change_state")
    get = node.create_client(GetState, "fusion/get_state")
    states = []
    node.create_subscription(TrainState, "localization/state", states.append, LATCHED_QOS)

    def transition(tid):
        future = change.call_async(ChangeState.Request(transition=Transition(id=tid)))
        assert spin_until(node, future.done, 10.0), proc.output()
        return future.result().success

    def label():
        reply = ask(node, get, GetState.Request())
        assert reply is not None, proc.output()
        return reply.current_state.label
    try:
        assert lifecycle_replies(node, change), proc.output()
        assert label() == "unconfigured"
        spin_until(node, lambda: False, 1.0)
        assert not states
        assert transition(Transition.TRANSITION_CONFIGURE) and label() == "inactive"
        spin_until(node, lambda: False, 1.0)
        assert not states
        assert transition(Transition.TRANSITION_ACTIVATE) and label() == "active"
        assert spin_until(node, lambda: len(states) >= 5, 10.0), proc.output()
        assert transition(Transition.TRANSITION_DEACTIVATE) and label() == "inactive"
        spin_until(node, lambda: False, 0.5)
        n = len(states)
        spin_until(node, lambda: False, 1.0)
        assert len(states) == n
        assert transition(Transition.TRANSITION_ACTIVATE)
        assert spin_until(node, lambda: len(states) >= n + 5, 10.0), proc.output()
        assert transition(Transition.TRANSITION_DEACTIVATE) and transition(Transition.TRANSITION_CLEANUP)
        assert label() == "unconfigured" and proc.proc.poll() is None
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()
    bad = start_node("fusion", "--ros-args", *NS, "-p", "managed:=true", "-p", "scenario:=no/such.yaml")
    node = ros_context.create_node("probe_lifecycle_bad", namespace="/train")
    change = node.create_client(ChangeState, "fusion/change_state")
    try:
        assert lifecycle_replies(node, change), bad.output()
        future = change.call_async(ChangeState.Request(transition=Transition(id=Transition.TRANSITION_CONFIGURE)))
        assert spin_until(node, future.done, 10.0) and not future.result().success
        assert "configure failed" in bad.output() and "no/such.yaml" in bad.output()
        assert bad.proc.poll() is None and bad.interrupt() == 0
    finally:
        node.destroy_node()


def test_managed_sensor_node_decodes_only_while_active(ros_context, start_node):
    """A managed Doppler node in ingest mode: inactive after configure (a raw block is not
    decoded), active after activate (decoded); deactivate stops it again."""
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    from train_localization_msgs.msg import RawBlock, SpeedMeasurement
    from train_localization.core.convert import raw_block_to_msg
    from train_localization.core.pipeline import run_offline
    from train_localization.core.scenario import Scenario
    from train_localization.nodes.common import STREAM_QOS, rclpy_classes
    from conftest import ROOT

    proc = start_node("doppler_radar", "--ros-args", *NS, "-p", "managed:=true", "-p", "mode:=ingest")
    node = ros_context.create_node("probe_sensor_lifecycle", namespace="/train")
    change = node.create_client(ChangeState, "doppler_radar/change_state")
    pub = node.create_publisher(RawBlock, "sensors/doppler/raw", STREAM_QOS)
    speeds = []
    node.create_subscription(SpeedMeasurement, "sensors/doppler/speed", speeds.append, STREAM_QOS)
    sc = Scenario.from_yaml(ROOT / "config" / "scenario_demo.yaml")
    sc.duration = 30.0
    blocks = [b for b in run_offline("doppler_radar", sc)[0] if b.t0 > 20.0]   # the train moves
    mc = rclpy_classes()

    def transition(tid):
        future = change.call_async(ChangeState.Request(transition=Transition(id=tid)))
        assert spin_until(node, future.done, 10.0), proc.output()
        return future.result().success

    def feed(k):
        pub.publish(raw_block_to_msg(blocks[k], mc))
        spin_until(node, lambda: False, 0.5)
    try:
        assert lifecycle_replies(node, change), proc.output()
        assert transition(Transition.TRANSITION_CONFIGURE)
        assert spin_until(node, lambda: pub.get_subscription_count() == 0, 2.0)   # not subscribed yet
        assert transition(Transition.TRANSITION_ACTIVATE)
        assert spin_until(node, lambda: pub.get_subscription_count() == 1, 10.0), proc.output()
        for k in range(3):
            feed(k)
        assert spin_until(node, lambda: len(speeds) >= 2, 10.0), proc.output()
        assert transition(Transition.TRANSITION_DEACTIVATE)
        assert spin_until(node, lambda: pub.get_subscription_count() == 0, 10.0), proc.output()
        n = len(speeds)
        feed(3)
        assert len(speeds) == n
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_fusion_rejects_fixes_off_its_track_and_stamps_from_the_future(ros_context, start_node):
    """A fix of another track, one 1e6 m off this one, a measurement stamped an hour ahead
    and one naming another sensor than its topic's are rejected with their reasons; the next valid fix is still accepted (an hour-
    ahead stamp no longer makes every later one too late)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from train_localization_msgs.msg import PositionFix
    from train_localization.nodes.common import STREAM_QOS

    proc = start_node("fusion", "--ros-args", *NS, "-p", "sensors:=[axle_counter]")
    node = ros_context.create_node("probe_offtrack", namespace="/train")
    pub = node.create_publisher(PositionFix, "sensors/axle_counter/position", STREAM_QOS)
    diags = []
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)

    def fix(ahead, pos, track="conventional_line", ref="AC01", sensor="axle_counter"):
        m = PositionFix(sensor=sensor, unit_id="ac", track_id=track, reference_id=ref, position=pos,
                        position_stddev=0.05)
        t = node.get_clock().now().nanoseconds * 1e-9 + ahead
        m.header.stamp.sec, m.header.stamp.nanosec = int(t), int(round((t % 1) * 1e9))
        return m
    try:
        assert spin_until(node, lambda: pub.get_subscription_count() > 0, 30.0), proc.output()
        for m in (fix(0.0, 500.0, track="maglev_line"), fix(0.0, 1.0e6), fix(3600.0, 500.0),
                  fix(0.0, 500.0, sensor="eurobalise"), fix(0.0, 3002.5)):   # AC01: 3000 m + 2.5 m
            pub.publish(m)
        topic = "sensors/axle_counter/position"
        assert spin_until(node, lambda: _diag_values(diags, "fusion").get(f"accepted/{topic}") == "1", 20.0), \
            proc.output()
        values = _diag_values(diags, "fusion")
        assert [values.get(f"rejected/{topic}/{r}") for r in ("wrong_track", "off_track", "future",
                                                              "wrong_sensor")] == ["1"] * 4
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_fixes_claiming_more_than_their_model_never_move_a_nominal_state(ros_context, start_node):
    """A balise fix claiming 1e-6 m 2 m off, and one naming a balise the track does not have
    (issue: NOMINAL 2 m wrong with a 2 mm stddev) are refused (below_model,
    unknown_reference); the NOMINAL state does not move."""
    from diagnostic_msgs.msg import DiagnosticArray
    from train_localization_msgs.msg import PositionFix, TrainState
    from train_localization.nodes.common import STREAM_QOS

    proc = start_node("fusion", "--ros-args", *NS, "-p", "sensors:=[eurobalise]", "-p", "publish_rate:=20",
                      "-p", "initial_position:=1502.0")
    node = ros_context.create_node("probe_lying_fixes", namespace="/train")
    pub = node.create_publisher(PositionFix, "sensors/eurobalise/position", STREAM_QOS)
    states, diags = [], []
    node.create_subscription(TrainState, "localization/state", states.append, STREAM_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)

    def fix(ref, pos, sd):
        m = PositionFix(sensor="eurobalise", unit_id="btm", track_id="conventional_line", reference_id=ref,
                        position=pos, position_stddev=sd)
        t = node.get_clock().now().nanoseconds * 1e-9
        m.header.stamp.sec, m.header.stamp.nanosec = int(t), int(round((t % 1) * 1e9))
        return m
    try:
        assert spin_until(node, lambda: pub.get_subscription_count() > 0 and states, 30.0), proc.output()
        assert states[-1].mode == TrainState.MODE_NOMINAL
        n_before = len(states)
        for m in (fix("EB001", 1504.0, 1e-6), fix("EB903", 1504.0, 0.5), fix("EB904", 1504.0, 0.5)):
            pub.publish(m)
        topic = "sensors/eurobalise/position"
        assert spin_until(node, lambda: _diag_values(diags, "fusion").get(
            f"rejected/{topic}/unknown_reference") == "2", 20.0), proc.output()
        assert spin_until(node, lambda: len(states) > n_before + 20, 10.0)
        values = _diag_values(diags, "fusion")
        assert values[f"rejected/{topic}/below_model"] == "1" and f"accepted/{topic}" not in values
        assert {s.mode for s in states} == {TrainState.MODE_NOMINAL}
        assert max(abs(s.position - 1502.0) for s in states) < 0.01
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_a_set_position_the_filter_cannot_take_is_refused_and_the_fusion_lives(ros_context, start_node):
    """SetPosition with a stddev of 1e200 killed the fusion; a NaN speed was taken. Refused with
    the reason; a valid request afterwards is answered and the state is NOMINAL there."""
    from train_localization_msgs.msg import TrainState
    from train_localization_msgs.srv import SetPosition
    from train_localization.nodes.common import STREAM_QOS

    proc = start_node("fusion", "--ros-args", *NS, "-p", "sensors:=[eurobalise]", "-p", "publish_rate:=20")
    node = ros_context.create_node("probe_set_position", namespace="/train")
    client = node.create_client(SetPosition, "localization/set_position")
    states = []
    node.create_subscription(TrainState, "localization/state", states.append, STREAM_QOS)
    try:
        assert spin_until(node, client.service_is_ready, 30.0), proc.output()
        for position, sd, speed, sd_v in ((500.0, 1e200, 0.0, 0.1), (500.0, 0.1, math.nan, 0.1),
                                          (1e12, 0.1, 0.0, 0.1), (500.0, 0.1, 1e300, 0.1)):
            reply = ask(node, client, SetPosition.Request(position=position, position_stddev=sd, speed=speed,
                                                          speed_stddev=sd_v))
            assert reply is not None and not reply.success and reply.message.startswith("refused"), proc.output()
        reply = ask(node, client, SetPosition.Request(position=500.0, position_stddev=0.1, speed=0.0,
                                                      speed_stddev=0.001))
        assert reply is not None and reply.success, proc.output()
        assert spin_until(node, lambda: states and states[-1].mode == TrainState.MODE_NOMINAL
                          and abs(states[-1].position - 500.0) < 0.01, 20.0), proc.output()
        assert proc.proc.poll() is None and proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_a_stopped_clock_makes_the_fusion_report_stale(ros_context, start_node):
    """Under use_sim_time, states follow /clock; when /clock stops (the simulator or the
    replayer died), the fusion's diagnostics go STALE within seconds of wall time instead of
    repeating the last mode."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rosgraph_msgs.msg import Clock
    from train_localization_msgs.msg import TrainState
    from train_localization.nodes.common import CLOCK_QOS, LATCHED_QOS

    proc = start_node("fusion", "--ros-args", *NS, "-p", "use_sim_time:=true", "-p", "sensors:=[axle_counter]")
    node = ros_context.create_node("probe_clock", namespace="/train")
    clock_pub = node.create_publisher(Clock, "/clock", CLOCK_QOS)
    states, diags = [], []
    node.create_subscription(TrainState, "localization/state", states.append, LATCHED_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)

    def level():
        for arr in reversed(diags):
            for s in arr.status:
                if s.name.endswith(": fusion"):
                    return s.level[0] if isinstance(s.level, bytes) else s.level
        return None
    try:
        assert spin_until(node, lambda: clock_pub.get_subscription_count() > 0, 30.0), proc.output()
        t = 100.0
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            t += 0.05
            msg = Clock()
            msg.clock.sec, msg.clock.nanosec = int(t), int(round((t % 1) * 1e9))
            clock_pub.publish(msg)
            spin_until(node, lambda: False, 0.05)
        assert states and level() != 3, proc.output()
        assert spin_until(node, lambda: level() == 3, 10.0), proc.output()
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_one_clock_message_far_ahead_does_not_stop_the_fusions_states(ros_context, start_node):
    """Over DDS: one /clock message 1e6 s ahead of the others. The fusion had published one state
    there and then nothing for good (its output grid stayed at 1e6 s); its grid now follows the
    clock back (core/fusion/runner.py), and the states go on at the clock's time."""
    from rosgraph_msgs.msg import Clock
    from train_localization_msgs.msg import TrainState
    from train_localization.nodes.common import CLOCK_QOS, LATCHED_QOS

    proc = start_node("fusion", "--ros-args", *NS, "-p", "use_sim_time:=true", "-p", "sensors:=[axle_counter]",
                      "-p", "publish_rate:=20.0")
    node = ros_context.create_node("probe_clock_jump", namespace="/train")
    clock_pub = node.create_publisher(Clock, "/clock", CLOCK_QOS)
    stamps = []
    node.create_subscription(TrainState, "localization/state",
                             lambda m: stamps.append(m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec), LATCHED_QOS)

    def tick(t):
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = int(t), int(round((t % 1) * 1e9))
        clock_pub.publish(msg)
        spin_until(node, lambda: False, 0.05)
    try:
        assert spin_until(node, lambda: clock_pub.get_subscription_count() > 0, 30.0), proc.output()
        t = 100.0
        for _ in range(40):
            t += 0.05
            tick(t)
        tick(t + 1e6)
        spin_until(node, lambda: False, 0.3)
        for _ in range(40):
            t += 0.05
            tick(t)
        spin_until(node, lambda: False, 0.5)
        after = [s for s in stamps if 102.5 < s < 1e5]
        assert len(after) >= 20, (stamps[-5:], proc.output())
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_holding_late_inputs_fuses_them_in_stamp_order_and_counts_those_later_than_declared(ros_context,
                                                                                          start_node):
    """hold_late_inputs: a fix 30 ms older than the one before it (the declared latency is 50 ms)
    waits in the runner's buffer and enters in stamp order: no rewind; one that arrives a second
    late rewinds the history once and is counted as late beyond the latency."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rosgraph_msgs.msg import Clock
    from train_localization_msgs.msg import PositionFix
    from train_localization.nodes.common import CLOCK_QOS, STREAM_QOS

    proc = start_node("fusion", "--ros-args", *NS, "-p", "use_sim_time:=true", "-p", "sensors:=[eurobalise]",
                      "-p", "hold_late_inputs:=true")
    node = ros_context.create_node("probe_hold", namespace="/train")
    clock_pub = node.create_publisher(Clock, "/clock", CLOCK_QOS)
    pub = node.create_publisher(PositionFix, "sensors/eurobalise/position", STREAM_QOS)
    diags = []
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)

    def stamp(msg, t):
        msg.sec, msg.nanosec = int(t), int(round((t % 1) * 1e9))

    def tick(t):
        msg = Clock()
        stamp(msg.clock, t)
        clock_pub.publish(msg)
        spin_until(node, lambda: False, 0.1)

    def fix(t, pos):   # EB000 at 500 m
        m = PositionFix(sensor="eurobalise", unit_id="btm", track_id="conventional_line", reference_id="EB000",
                        position=pos, position_stddev=1.0)
        stamp(m.header.stamp, t)
        pub.publish(m)
        spin_until(node, lambda: False, 0.1)
    try:
        assert spin_until(node, lambda: clock_pub.get_subscription_count() > 0 and pub.get_subscription_count() > 0,
                          30.0), proc.output()
        for _ in range(10):   # until the node's clock has surely taken /clock
            tick(12.0)
        fix(11.99, 502.0)
        fix(11.96, 502.0)   # 30 ms older than the one before, within the 50 ms latency: held and sorted
        for t in (12.2, 12.4, 12.6, 12.8, 13.0):
            tick(t)
        fix(11.975, 502.0)  # between the two taken, released long ago: beyond the latency, a rewind
        for k in range(30):
            tick(13.1 + 0.1 * k)
            values = _diag_values(diags, "fusion")
            if values.get("filter/rollbacks/late_beyond_latency") == "1":
                break
        values = _diag_values(diags, "fusion")
        assert values.get("filter/rollbacks/late_beyond_latency") == "1", (values, proc.output())
        assert values["filter/rollbacks/late"] == "1", values
        assert values["accepted/sensors/eurobalise/position"] == "3"
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()


def test_numeric_parameters_carry_their_range_and_a_value_beyond_it_stops_the_node(ros_context, start_node):
    """A sensor node's limited parameters have the range in their descriptor (what ``ros2
    param describe`` shows); a value beyond it, given as a double or as an integer, stops the
    node with exit code 2 and one line naming the parameter, no traceback."""
    from rcl_interfaces.srv import DescribeParameters
    good = start_node("doppler_radar", "--ros-args", *NS, "-p", "mode:=ingest", "-r", "__node:=radar_limits")
    node = ros_context.create_node("probe_limits", namespace="/train")
    try:
        client = node.create_client(DescribeParameters, "/train/radar_limits/describe_parameters")
        assert spin_until(node, client.service_is_ready, 30.0), good.output()
        reply = ask(node, client, DescribeParameters.Request(names=["max_block_duration", "future_tolerance", "carrier_frequency",
                                                            "faults"]))
        assert reply is not None, good.output()
        limited, tolerance, carrier, free = reply.descriptors
        assert (limited.floating_point_range[0].from_value, limited.floating_point_range[0].to_value) == (1e-3, 60.0)
        assert (tolerance.floating_point_range[0].from_value, tolerance.floating_point_range[0].to_value) == (1e-3, 3600.0)
        assert (carrier.floating_point_range[0].from_value, carrier.floating_point_range[0].to_value) == (1e9, 1e11)
        assert carrier.description.endswith("[1e+09 .. 1e+11]")
        assert not free.floating_point_range and not free.integer_range and limited.read_only
        assert good.interrupt() == 0
    finally:
        node.destroy_node()
    for value in ("100.0", "100"):
        bad = start_node("doppler_radar", "--ros-args", *NS, "-p", "mode:=ingest", "-p", f"max_block_duration:={value}")
        assert bad.proc.wait(timeout=30) == 2, bad.output()
        out = bad.output()
        assert "[fatal]" in out and "max_block_duration" in out and "Traceback" not in out, out


def test_every_node_executable_prints_its_usage_on_help_and_starts_nothing(tmp_path):
    """``<exe> --help`` prints the node's usage (its topics and parameters) and exits 0 without
    starting: the fusion and the wheel sensor had ignored it and started, the recorder had started
    writing recording.mcap in the current directory. A missing required parameter is one line."""
    from concurrent.futures import ThreadPoolExecutor
    from train_localization.tools.demo import executable
    from test_package import EXECUTABLES
    names = [*EXECUTABLES, "wayside_occupancy", "neutral_section_controller", "crosscheck", "association",
             "stator_section_controller", "etcs_location", "atp_supervision"]

    def run(exe):
        return exe, subprocess.run([executable(exe), "--help"], cwd=tmp_path, capture_output=True, text=True,
                                   timeout=60)
    with ThreadPoolExecutor(4) as pool:
        for exe, done in pool.map(run, names):
            assert done.returncode == 0, (exe, done.stdout[-500:], done.stderr[-500:])
            assert "arameter" in done.stdout and len(done.stdout.splitlines()) > 5, (exe, done.stdout)
    assert list(tmp_path.iterdir()) == []                    # no bag, no log written
    missing = subprocess.run([executable("replayer")], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2
    assert missing.stdout.strip().splitlines()[-1] == \
        "[fatal] ConfigurationError: parameter 'bag' is required (an MCAP file to play)"
    assert "Traceback" not in missing.stdout + missing.stderr


def test_a_flood_on_one_input_is_shed_and_the_states_keep_coming(tmp_path):
    """Over DDS (tl_bench flood): 5,000 valid Doppler speeds a second for 2 s into the live
    fusion. Before, 4,400/s had stopped its states for the flood's length (5,300/s: 58 Hz, 10 s
    behind). The excess beyond max_input_rate (1000/s) is shed before any work and counted, and
    the node publishes its states from the input's callbacks when its timer falls behind. The
    rates themselves are the benchmark's (README, Reliability); here only that states came
    during the flood and what was shed was counted."""
    from train_localization.tools import bench_flood
    (row,) = bench_flood.run([5000.0], 2.0, tmp_path)
    assert row.sent_rate > 2500.0, row                   # the flood was one
    assert row.shed >= 0.5 * (row.sent_rate - 1000.0) * 2.0, row
    assert row.output_rate > 50.0, row


def test_the_onboard_graph_decodes_and_fuses_blocks_stamped_on_the_hosts_clock(ros_context, start_node):
    """graph.onboard_graph (launch/onboard.launch.py) with use_sim_time false, over DDS: raw
    blocks published in real time and stamped with the host's clock, as a device driver on a
    train does (about 1.8e9 s); the operator sets the position at departure. The fused states
    are stamped on the host's clock, use the wheel and the radar, and hold the truth inside
    their interval."""
    import dataclasses
    from train_localization_msgs.msg import TrainState
    from train_localization_msgs.srv import SetPosition
    from train_localization.core.convert import raw_block_to_msg
    from train_localization.core.pipeline import SensorPipeline
    from train_localization.core.scenario import Scenario
    from train_localization.core.sensors import spec
    from train_localization.graph import onboard_graph, ros_args
    from train_localization.nodes.common import STREAM_QOS, rclpy_classes
    from conftest import ROOT

    scenario_path = str(ROOT / "config" / "scenario_demo.yaml")
    sensors = ["wheel_sensor", "doppler_radar", "eurobalise_reader"]
    # the demo train 20 m before balise group EB000 at 25 m/s, 12 s
    sc = dataclasses.replace(Scenario.from_yaml(scenario_path), start_position=480.0, start_speed=25.0, duration=12.0)
    traj = sc.trajectory()
    blocks = []
    for node in sensors:
        pipe = SensorPipeline(spec(node), sc.sensors.get(node, {}), sc.track, sc.vehicle, sc.rng(node, spec(node).sensor))
        for k in range(int(sc.duration * sc.truth_rate) + 1):
            blocks += [(node, b) for b in pipe.on_truth(traj.state_at(k / sc.truth_rate))]
    blocks.sort(key=lambda nb: nb[1].t0 + nb[1].duration)
    graph = onboard_graph(scenario_path, sensors, "", record=False, use_sim_time=False)
    assert all(params["use_sim_time"] is False for _, _, params in graph)
    procs = [start_node(exe, *ros_args(name, params)) for exe, name, params in graph]
    node = ros_context.create_node("probe_onboard", namespace="/train")
    mc = rclpy_classes()
    pubs = {n: node.create_publisher(mc.RawBlock, f"sensors/{spec(n).sensor}/raw", STREAM_QOS) for n in sensors}
    states = []
    node.create_subscription(TrainState, "localization/state", lambda m: states.append((m, time.time())), STREAM_QOS)
    operator = node.create_client(SetPosition, "localization/set_position")
    try:
        assert spin_until(node, lambda: all(p.get_subscription_count() > 0 for p in pubs.values()) and states, 60.0), \
            [p.output()[-800:] for p in procs]
        assert spin_until(node, operator.service_is_ready, 10.0)
        wall0, set_at = time.time() + 0.5, None
        for name, block in blocks:                      # each block when its last sample is taken
            end = wall0 + block.t0 + block.duration
            spin_until(node, lambda: time.time() >= end, max(0.0, end - time.time()) + 0.01)
            pubs[name].publish(raw_block_to_msg(dataclasses.replace(block, t0=wall0 + block.t0), mc))
            if set_at is None and end > wall0 + 1.0:   # the operator, at departure
                set_at = time.time() - wall0
                truth = traj.state_at(set_at)
                reply = ask(node, operator, SetPosition.Request(position=truth.position, position_stddev=0.5,
                                                                speed=truth.speed, speed_stddev=0.1))
                assert reply is not None and reply.success, reply
        spin_until(node, lambda: False, 1.5)
        assert all(p.proc.poll() is None for p in procs), [p.output()[-800:] for p in procs]
        after = [(m, rx) for m, rx in states if rx > wall0 + set_at + 0.5]
        assert len(after) > 100
        for m, rx in after:                             # stamped on the host's clock, not behind it
            assert abs(m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec - rx) < 1.0
        claimed = [m for m, _ in after if m.mode in (TrainState.MODE_NOMINAL, TrainState.MODE_DEGRADED)]
        for m in claimed:                               # while the blocks came (the truth ends there)
            t = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec - wall0
            if t <= sc.duration:
                truth = traj.state_at(t).position
                assert m.position_min <= truth <= m.position_max, (t, truth, m.position_min, m.position_max)
        assert len(claimed) > 0.9 * len(after) and {"wheel", "doppler"} <= {s for m, _ in after for s in m.sensors}
        assert all(p.interrupt() == 0 for p in procs)
    finally:
        node.destroy_node()


def test_the_stator_controller_refuses_a_track_without_stator_sections_in_one_line(tmp_path):
    from train_localization.tools.demo import executable
    done = subprocess.run([executable("stator_section_controller"), "--ros-args", "-p",
                           f"track:={ROOT / 'config' / 'track_conventional.yaml'}"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stdout + done.stderr
    assert done.stdout.strip().splitlines()[-1] == ("[fatal] ConfigurationError: track conventional_line has no "
                                                    "stator_section items: nothing to feed")
    assert "Traceback" not in done.stdout + done.stderr

"""Standard ROS messages of a train's drivers into the fusion (core/ingest, nodes/standard_inputs.py):
map matching of GNSS fixes, IMU frames, speed odometers, the refusals, and the on-board graph over
DDS fed by NavSatFix, Imu and Odometry publishers only."""
from __future__ import annotations

import dataclasses
import math
import time
from types import SimpleNamespace as NS

import numpy as np
import pytest

from conftest import ROOT, spin_until
from train_localization.core.geodesy import GeodeticAnchor
from train_localization.core.ingest import records
from train_localization.core.ingest.imu import ImuIngest, ImuMount
from train_localization.core.ingest.inputs import PARAMS, StandardInputs
from train_localization.core.ingest.navsat import NavSatIngest
from train_localization.core.ingest.speed import SpeedIngest
from train_localization.core.ingest.records import BodyTwist, GnssFix, ImuSample
from train_localization.core.scenario import Scenario
from train_localization.core.sensors import spec
from train_localization.core.sensors.base import sensor_params
from train_localization.core.sensors.dgps import fix_sigma
from train_localization.core.signals import InputRejected
from train_localization.core.track import Track, TrackError

SCENARIO = str(ROOT / "config" / "scenario_drivers.yaml")


@pytest.fixture(scope="module")
def sc():
    return Scenario.from_yaml(SCENARIO)


def _gnss(track, chainage, lateral=0.0, stamp=1.0, status=records.STATUS_GBAS_FIX, var=0.04):
    """The GnssFix of the map point ``lateral`` [m] left of ``chainage`` [m]."""
    x, y, h = track.pose(chainage)
    lat, lon = track.geodetic.projection().to_geodetic(x - lateral * math.sin(h), y + lateral * math.cos(h))
    return GnssFix(stamp, status, lat, lon, var, 0.0, var, records.COVARIANCE_TYPE_DIAGONAL_KNOWN)


def test_a_gnss_fix_is_map_matched_to_the_chainage_of_the_train_front(sc):
    p = sensor_params(spec("dgps_receiver"), {}, sc.vehicle)
    ing = NavSatIngest(p, sc.track)
    for s in (500.0, 1500.0, 3500.0):   # straight, in the curve, after it
        fix = ing.fix(_gnss(sc.track, s, lateral=0.3))
        assert fix.position == pytest.approx(s + p["antenna_offset"], abs=0.02)
        assert fix.position_stddev == pytest.approx(max(0.2, fix_sigma(p, 0.0, False)))
    # a receiver's 1-sigma below the model's multipath is floored; none given: the model's at nominal HDOP
    assert ing.fix(_gnss(sc.track, 800.0, var=1e-6)).position_stddev == pytest.approx(p["multipath_sigma"])
    unknown = dataclasses.replace(_gnss(sc.track, 800.0), covariance_type=records.COVARIANCE_TYPE_UNKNOWN)
    assert ing.fix(unknown).position_stddev == pytest.approx(fix_sigma(p, p["hdop_nominal"], False))
    # withheld and counted: a fix 5 m off the track, an autonomous one, no fix, under the bridge
    assert ing.fix(_gnss(sc.track, 800.0, lateral=5.0)) is None
    assert ing.fix(_gnss(sc.track, 800.0, status=records.STATUS_FIX)) is None
    assert ing.fix(dataclasses.replace(_gnss(sc.track, 800.0), status=records.STATUS_NO_FIX)) is None
    assert ing.fix(_gnss(sc.track, 2507.0)) is None
    assert {k: ing.stats[k] for k in ("fixes", "off_track", "autonomous", "no_fix", "under_structure")} == \
        {"fixes": 5, "off_track": 1, "autonomous": 1, "no_fix": 1, "under_structure": 1}


def test_a_track_without_a_geodetic_anchor_refuses_gnss_in_one_line(sc):
    track = Track.from_yaml(ROOT / "config" / "track_conventional.yaml")
    with pytest.raises(ValueError, match="has no geodetic block") as exc:
        NavSatIngest(sensor_params(spec("dgps_receiver"), {}, sc.vehicle), track)
    assert "\n" not in str(exc.value)
    with pytest.raises(TrackError, match="latitude"):
        Track.from_dict({"track_id": "t", "length": 10.0, "geodetic": {"latitude": 95.0, "longitude": 0.0}})
    assert GeodeticAnchor(48.2, 11.6).projection().to_map(48.2, 11.6) == pytest.approx((0.0, 0.0), abs=1e-6)


def _header(stamp):
    return NS(stamp=NS(sec=int(stamp), nanosec=int(round((stamp % 1) * 1e9))))


def test_bad_standard_messages_are_refused_with_their_reason():
    def navsat(lat, lon, cov=(0.1, 0, 0, 0, 0.1, 0, 0, 0, 0.1), status=2, kind=2):
        return NS(header=_header(5.0), status=NS(status=status), latitude=lat, longitude=lon, altitude=0.0,
                  position_covariance=cov, position_covariance_type=kind)
    cases = [(navsat(math.nan, 11.0), "nan"), (navsat(0.84, 200.0), "implausible"),
             (navsat(48.0, 11.0, status=7), "implausible"), (navsat(48.0, 11.0, kind=9), "implausible"),
             (navsat(48.0, 11.0, cov=(-1.0, 0, 0, 0, 0.1, 0, 0, 0, 0.1)), "covariance")]
    for msg, reason in cases:
        with pytest.raises(InputRejected) as exc:
            records.gnss_fix_from_msg(msg)
        assert exc.value.reason == reason
    assert records.gnss_fix_from_msg(navsat(math.nan, math.nan, status=-1)).status == records.STATUS_NO_FIX
    vec = NS(x=0.0, y=0.0, z=0.1)
    absent = NS(header=_header(1.0), angular_velocity=vec, angular_velocity_covariance=[-1.0] + [0.0] * 8,
                linear_acceleration=vec, linear_acceleration_covariance=[-1.0] + [0.0] * 8)
    with pytest.raises(InputRejected, match="absent") as exc:
        records.imu_sample_from_msg(absent)
    twist = NS(twist=NS(linear=NS(x=math.inf)), covariance=[0.0] * 36)
    with pytest.raises(InputRejected) as exc:
        records.twist_from_odometry(NS(header=_header(1.0), twist=twist))
    assert exc.value.reason == "nan"


def test_imu_samples_in_an_upside_down_frame_give_the_bodys_yaw_rate_per_block(sc):
    gyro = sensor_params(spec("gyro"), {}, sc.vehicle)
    ing = ImuIngest(sc.track, ImuMount(roll=math.pi), 0.1, 25.0, gyro, None)
    out = []
    for k in range(101):   # 1 s at 100 Hz, the body turning left at 0.02 rad/s: the IMU's z points down
        out += ing.add(ImuSample(10.0 + 0.01 * k, (0.0, 0.0, -0.02), (0.0,) * 9, (0.0, 0.0, -9.8), (0.0,) * 9))
    assert len(out) == 10 and all(m.sensor == "gyro" for m in out)
    assert all(m.yaw_rate == pytest.approx(0.02, abs=1e-6) for m in out)
    assert min(m.yaw_rate_stddev for m in out) >= spec("gyro").error_model(gyro, sc.track, sc.vehicle).min_stddev
    with pytest.raises(InputRejected) as exc:
        ing.add(ImuSample(10.5, (0.0, 0.0, 0.0), (0.0,) * 9, (0.0, 0.0, 0.0), (0.0,) * 9))
    assert exc.value.reason == "out_of_order"


def test_speed_messages_become_wheel_increments_or_radar_speeds_with_their_models_floors(sc):
    wheel_p = sensor_params(spec("wheel_sensor"), {}, sc.vehicle)
    wheel = spec("wheel_sensor").error_model(wheel_p, sc.track, sc.vehicle)
    ing = SpeedIngest(wheel, "wheel", direction=-1, max_gap=1.0)
    out = []
    for k in range(51):   # base_link x against the chainage: 10 m/s forward is -10 m/s along it
        out += ing.add(BodyTwist(1.0 + 0.02 * k, 10.0, 0.0))
    assert len(out) == 50 and sum(m.distance for m in out) == pytest.approx(-10.0)
    assert all(m.distance_stddev >= wheel.reported_scale * 0.2 * (1 - 1e-9) for m in out)
    assert ing.add(BodyTwist(5.0, 10.0, 0.0)) == [] and ing.stats["gaps"] == 1
    doppler_p = sensor_params(spec("doppler_radar"), {}, sc.vehicle)
    radar = spec("doppler_radar").error_model(doppler_p, sc.track, sc.vehicle)
    m, = SpeedIngest(radar, "doppler").add(BodyTwist(1.0, 20.0, 1e-6))
    assert m.speed == 20.0 and m.speed_stddev == pytest.approx(math.hypot(20.0 * radar.reported_scale,
                                                                           radar.reported_bias), rel=1e-3)
    with pytest.raises(ValueError, match="measures"):
        SpeedIngest(spec("gyro").error_model(sensor_params(spec("gyro"), {}, sc.vehicle), sc.track, sc.vehicle), "g")


def test_an_input_configuration_names_the_sensor_classes_the_fusion_takes(sc):
    values = {name: p.default for name, p in PARAMS.items()}
    with pytest.raises(ValueError, match="no input configured"):
        StandardInputs.build(values, sc.track, sc.sensors, sc.vehicle)
    values.update({"navsat.topic": "/gnss/fix", "imu.topic": "/imu", "twist.topic": "/radar"})
    assert StandardInputs.build(values, sc.track, sc.sensors, sc.vehicle).sensor_classes() == ["dgps", "gyro",
                                                                                                "doppler"]
    with pytest.raises(ValueError, match="twist.sensor"):
        StandardInputs.build({**values, "twist.sensor": "gyro"}, sc.track, sc.sensors, sc.vehicle)


def test_the_onboard_graph_fuses_navsatfix_imu_and_odometry_publishers(ros_context, start_node, sc):
    """The fusion and standard_inputs (its example params file) over DDS, fed in real time on the
    host's clock by a GNSS receiver (NavSatFix, 10 Hz), an IMU (Imu, 100 Hz) and a wheel odometer
    (Odometry, 50 Hz) made from the truth: no project message on the input side. The fused states
    hold the truth in their interval, from the GNSS fixes and the wheel; bad messages are refused
    and counted per reason."""
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import Imu, NavSatFix
    from train_localization_msgs.msg import TrainState
    from train_localization.graph import ros_args
    from train_localization.nodes.common import STREAM_QOS

    rng = np.random.default_rng(54)
    scn = dataclasses.replace(sc, start_position=900.0, start_speed=25.0, duration=10.0)
    traj = scn.trajectory()
    proj = sc.track.geodetic.projection()
    offset = sensor_params(spec("dgps_receiver"), {}, sc.vehicle)["antenna_offset"]
    fusion = start_node("fusion", *ros_args("fusion", {"scenario": SCENARIO, "sensors": ["dgps", "gyro", "wheel"]}))
    inputs = start_node("standard_inputs", "--ros-args", "-r", "__ns:=/train", "--params-file",
                        str(ROOT / "config" / "params" / "standard_inputs.yaml"), "-p", f"scenario:={SCENARIO}")
    node = ros_context.create_node("probe_drivers", namespace="/train")
    gnss = node.create_publisher(NavSatFix, "/gnss/fix", 100)
    imu = node.create_publisher(Imu, "/imu/data", 100)
    odom = node.create_publisher(Odometry, "/wheel/odometry", 100)
    states, diags = [], []
    node.create_subscription(TrainState, "localization/state", lambda m: states.append(m), STREAM_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: diags.append(m), 100)

    def stamp(msg, t):
        msg.header.stamp.sec, msg.header.stamp.nanosec = int(t), int(round((t % 1) * 1e9)) % 1_000_000_000
        return msg
    events = []   # (time from the start [s], publisher, message maker)
    for k in range(int(scn.duration * 10)):
        t = 0.1 * k
        def fix(t=t):
            st = traj.state_at(t)
            x, y, _ = sc.track.pose(st.position - offset)
            lat, lon = proj.to_geodetic(x + rng.normal(0, 0.3), y + rng.normal(0, 0.3))
            m = NavSatFix(latitude=lat, longitude=lon, position_covariance=[0.09, 0, 0, 0, 0.09, 0, 0, 0, 0.25],
                          position_covariance_type=NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN)
            m.status.status = 2
            return m
        events.append((t, gnss, fix))
    for k in range(int(scn.duration * 100)):
        t = 0.01 * k
        def sample(t=t):
            st = traj.state_at(t)
            m = Imu()
            m.angular_velocity.z = st.speed * float(sc.track.curvature(st.position - 5.0)) + rng.normal(0, 2e-3)
            m.linear_acceleration.z = 9.81
            return m
        events.append((t, imu, sample))
    for k in range(int(scn.duration * 50)):
        t = 0.02 * k
        def twist(t=t):
            m = Odometry()
            m.twist.twist.linear.x = traj.state_at(t).speed * 1.001 + rng.normal(0, 0.02)
            m.twist.covariance[0] = 4e-4
            return m
        events.append((t, odom, twist))
    events.sort(key=lambda e: e[0])
    def nan_fix():
        m = NavSatFix(latitude=math.nan, position_covariance_type=2)
        m.status.status = 2
        return m
    bad = [(gnss, nan_fix),                                                                     # nan
           (odom, lambda: Odometry()), (odom, lambda: Odometry())]                               # future (x2)
    try:
        assert spin_until(node, lambda: gnss.get_subscription_count() and imu.get_subscription_count()
                          and odom.get_subscription_count() and states, 60.0), inputs.output()[-800:]
        wall0 = time.time() + 0.3
        for t, pub, make in events:
            end = wall0 + t
            spin_until(node, lambda: time.time() >= end, max(0.0, end - time.time()) + 0.005)
            pub.publish(stamp(make(), end))
        for pub, make in bad:
            pub.publish(stamp(make(), time.time() + (0.0 if pub is gnss else 30.0)))
        spin_until(node, lambda: False, 2.5)
        assert fusion.proc.poll() is None and inputs.proc.poll() is None, inputs.output()[-800:]
        claimed = [m for m in states if m.mode in (TrainState.MODE_NOMINAL, TrainState.MODE_DEGRADED)
                   and m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec < wall0 + scn.duration]
        assert len(claimed) > 500, len(claimed)
        inside = [m.position_min <= traj.state_at(m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec - wall0
                                                  ).position <= m.position_max for m in claimed]
        assert all(inside), inside.count(False)
        assert {"dgps", "wheel"} <= {s for m in claimed for s in m.sensors}
        ours = [s for d in diags for s in d.status if s.name.startswith("standard_inputs")]
        last = {kv.key: kv.value for kv in ours[-1].values}
        assert {k: v for k, v in last.items() if k.startswith("rejected/")} == \
            {"rejected//gnss/fix/nan": "1", "rejected//wheel/odometry/future": "2"}, last
        assert int(last["navsat/fixes"]) >= 90
        assert fusion.interrupt() == 0 and inputs.interrupt() == 0
    finally:
        node.destroy_node()

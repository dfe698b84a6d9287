"""The longitudinal accelerometer (core/sensors/accelerometer.py) against the truth: the track's
gradient profile (core/gradient.py), the gravity of the gradient taken out at the position it is
told, each error term's effect and its share of the reported 1-sigma, bad input refused and
counted."""
from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import ROOT, spin_until
from train_localization.core.gradient import along_track_gravity
from train_localization.core.measurements import GRAVITY, Acceleration
from train_localization.core.pipeline import SensorPipeline
from train_localization.core.sensors import spec
from train_localization.core.sensors.base import sensor_params
from train_localization.core.sensors.accelerometer import (MIN_STDDEV, PARAMS, TrackPosition, lsb, min_stddev,
                                                           parse_faults, turn_on_sigma, white_sigma)
from train_localization.core.signals import InputRejected, RawBlock
from train_localization.core.track import Track, TrackError
from train_localization.core.truth import TruthState
from train_localization.core.vehicle import Vehicle
from train_localization.tools.accelerometer_figures import errors, figures, graded_track, motion, run

# every drawn or slow error off: what is left is the white noise and the quantisation
IDEAL = {"bias_sigma": 0.0, "bias_instability": 0.0, "scale_sigma": 0.0, "temp_coefficient": 0.0,
         "misalignment_sigma": 0.0, "noise_density": 0.0, "gradient_tolerance": 0.0}
OFFSET = PARAMS["mount_offset"].default


# ------------------------------------------------------------------------------ gradient profile
def test_the_gradient_profile_holds_between_change_points_and_turns_over_vertical_curves():
    track = graded_track()
    s = [0.0, 949.0, 1000.0, 1050.0, 2000.0, 2925.0, 3000.0, 3075.0, 4999.0, 6000.0, -5.0]
    assert track.grade(s) == pytest.approx([0.0, 0.0, 0.01, 0.02, 0.02, 0.02, 0.005, -0.01, -0.01, -0.01, 0.0])
    assert Track("flat", 100.0).grade(50.0) == 0.0 and Track("flat", 100.0).grade([1.0, 2.0]).tolist() == [0.0, 0.0]
    step = Track.from_dict({"track_id": "s", "length": 100.0, "gradient": {"profile": [
        {"position": 0.0, "gradient": 5.0}, {"position": 50.0, "gradient": -5.0}]}})
    assert step.grade([49.99, 50.01]) == pytest.approx([0.005, -0.005])   # no vertical curve: a step


@pytest.mark.parametrize("block, why", [
    ({"profile": []}, "non-empty 'profile'"),
    ({"profile": [{"position": 0.0}]}, "needs 'position'"),
    ({"profile": [{"position": 0.0, "gradient": 0.0}, {"position": 0.0, "gradient": 1.0}]}, "must increase"),
    ({"profile": [{"position": 6000.0, "gradient": 1.0}]}, "off the track"),
    ({"profile": [{"position": 0.0, "gradient": 300.0}]}, "beyond"),
    ({"vertical_curve_radius": 1.0e5, "profile": [{"position": 0.0, "gradient": 0.0},
                                                   {"position": 100.0, "gradient": 30.0}]}, "overlaps"),
    ({"vertical_curve_radius": -1.0, "profile": [{"position": 0.0, "gradient": 0.0}]}, ">= 0"),
    ({"profile": [{"position": 0.0, "gradient": "steep"}]}, "gradient 'steep' is not a number"),
    ([{"position": 0.0, "gradient": 1.0}], "must be a mapping"),
])
def test_a_bad_gradient_block_is_refused_in_one_line(block, why):
    with pytest.raises(TrackError, match=why) as exc:
        Track.from_dict({"track_id": "bad", "length": 5000.0, "gradient": block})
    assert "\n" not in str(exc.value) and "track 'bad'" in str(exc.value)


# ------------------------------------------------------------------------------ against the truth
def test_ideal_device_gives_the_truth_with_the_gradient_and_the_body_pitch_taken_out():
    out, truth, pipe = run(IDEAL, graded_track(), 60.0, lambda t: motion(t, 800.0, 0.8, 40.0))
    err, sigma = errors(out, truth)
    assert len(out) == 60 * 20 and not pipe.rejected
    # the 1-sigma is the quantisation's alone (16 bits over +-2 g, 5 samples a block), under the floor
    assert white_sigma(IDEAL | {"full_range": 2 * GRAVITY, "adc_bits": 16}, 5, 100.0) < MIN_STDDEV
    assert sigma == pytest.approx(MIN_STDDEV)
    assert np.abs(err).max() < lsb({"full_range": 2 * GRAVITY, "adc_bits": 16})
    on_ramp = (truth[0] - OFFSET > 1060.0) & (truth[0] - OFFSET < 2900.0)   # where gravity was taken out
    assert on_ramp.sum() > 500 and np.abs(err[on_ramp]).max() < 1e-3
    assert along_track_gravity(graded_track().grade(truth[0][on_ramp] - OFFSET), GRAVITY) == pytest.approx(0.19609, abs=1e-5)


def test_a_train_at_rest_on_a_rising_track_reads_g_sin_and_decodes_zero():
    track = graded_track()
    out, truth, pipe = run(IDEAL, track, 5.0, lambda t: TruthState(t, 2000.0, 0.0, 0.0))
    assert pipe.decoder.stats["gravity"] == pytest.approx(0.19609, abs=1e-5)
    raw = np.array([m.acceleration for m in out]) + pipe.decoder.stats["gravity"]   # what the device read
    assert raw == pytest.approx(0.19609, abs=1e-3)
    assert np.abs([m.acceleration for m in out]).max() < 1e-3


def test_without_a_position_the_gradient_span_bounds_the_gravity():
    out, truth, pipe = run(IDEAL, graded_track(), 5.0, lambda t: TruthState(t, 2000.0, 0.0, 0.0),
                            placed=lambda st: None)
    half_span = 0.5 * GRAVITY * (0.02 / math.sqrt(1.0004) + 0.01 / math.sqrt(1.0001))
    middle = GRAVITY * 0.5 * (0.02 / math.sqrt(1.0004) - 0.01 / math.sqrt(1.0001))
    assert pipe.decoder.stats["gravity"] == pytest.approx(middle, abs=1e-6)
    err, sigma = errors(out, truth)
    assert sigma == pytest.approx(half_span, rel=1e-3) and np.all(np.abs(err) <= sigma)
    # a level track loses nothing without a position
    level, truth, _ = run(IDEAL, Track("flat", 5000.0), 2.0, lambda t: TruthState(t, 200.0, 0.0, 0.0),
                           placed=lambda st: None)
    assert max(m.acceleration_stddev for m in level) < 1e-3


def test_a_stale_position_is_not_used():
    def placed(st):
        return (st.position, 0.0) if st.stamp <= 1.0 else None   # the position input stops at 1 s
    out, truth, _ = run(IDEAL | {"position_timeout": 2.0}, graded_track(), 6.0,
                         lambda t: TruthState(t, 2000.0, 0.0, 0.0), placed=placed)
    stamps = np.array([m.stamp for m in out])
    sigma = np.array([m.acceleration_stddev for m in out])
    assert sigma[stamps < 3.0].max() < 1e-3 and sigma[stamps > 3.0].min() > 0.1


def test_a_position_off_by_its_sigma_near_a_change_of_gradient_stays_within_the_reported_sigma():
    """The decoder told a position 20 m behind the truth with 1-sigma 20 m, on the vertical curve at
    3 km (gradient 20 -> -10 per mille over 150 m): the gravity's spread is in its 1-sigma."""
    out, truth, _ = run(IDEAL, graded_track(), 60.0, lambda t: motion(t, 2850.0, 0.8, 20.0),
                         placed=lambda st: (st.position - 20.0, 20.0))
    err, sigma = errors(out, truth)
    near = np.abs(truth[0] - OFFSET - 3000.0) < 100.0
    assert near.sum() > 100
    assert sigma[near].max() > 0.02 and np.all(np.abs(err) <= 3.0 * sigma)
    far = truth[0] - OFFSET > 3200.0   # beyond the curve (and 4.5 sigma) the position error costs nothing
    assert far.sum() > 50 and sigma[far].max() < 1e-3


GAIN = 1.0 + GRAVITY * PARAMS["pitch_compliance"].default   # the body's pitch, taken out by the decoder


@pytest.mark.parametrize("term, value", [("bias_sigma", 0.02), ("scale_sigma", 0.002), ("misalignment_sigma", 0.005),
                                         ("temp_coefficient", 5.0e-4), ("bias_instability", 2.0e-3)])
def test_each_error_term_makes_its_error_within_the_reported_sigma(term, value):
    """One error term at a time, at its default, on a curve (R 800 m) after 1 km straight: the
    error is what the term's draw makes (the simulator's) and lies within 4 reported 1-sigma."""
    track = Track.from_dict({"track_id": "c", "length": 5000.0,
                             "alignment": [{"length": 1000.0}, {"length": 4000.0, "curvature": 1 / 800}]})
    params = IDEAL | {term: value, "warmup_rise": 20.0, "warmup_tau": 30.0, "bias_tau": 5.0}
    out, truth, pipe = run(params, track, 80.0, lambda t: motion(t, 700.0, 0.6, 30.0), seed=16)
    err, sigma = errors(out, truth)
    sim = pipe.simulator
    quantum = 3.0e-4   # a few quantisation steps of the 5-sample mean (lsb 6e-4 / sqrt(12 x 5)) and the truth's
    if term == "bias_sigma":
        assert abs(sim._bias) > 0.3 * value and err == pytest.approx(sim._bias / GAIN, abs=quantum)
    elif term == "scale_sigma":
        assert abs(sim._scale) > 0.3 * value and err == pytest.approx(sim._scale * truth[2], abs=quantum)
    elif term == "misalignment_sigma":
        lateral = truth[1] ** 2 * track.curvature(truth[0] - OFFSET)    # 1.1 m/s^2 at 30 m/s on the curve
        assert lateral.max() == pytest.approx(900.0 / 800.0)
        assert abs(sim._misalignment) > 0.3 * value
        inside = np.abs(truth[0] - OFFSET - 1000.0) > 1.0   # a block that enters the curve averages both sides
        assert err[inside] == pytest.approx(sim._misalignment * lateral[inside] / GAIN, abs=quantum)
    elif term == "temp_coefficient":
        stamps = np.array([m.stamp for m in out])
        warm = 20.0 + 20.0 * (1.0 - np.exp(-stamps / 30.0)) - 25.0    # T - T_cal: -5 K to +13.6 K
        assert abs(sim._temp_k) > 0.3 * value and err == pytest.approx(sim._temp_k * warm / GAIN, abs=quantum)
    else:
        assert np.std(err) > 0.3 * value
    assert np.all(np.abs(err) <= 4.0 * sigma)
    assert np.all(sigma >= min_stddev(params) * (1 - 1e-9))


def test_default_device_on_the_graded_curved_track_within_its_sigma():
    """Every error at its default, 6 runs (the figures tool's, docs/nodes.md): every error within
    4 reported 1-sigma, their spread about the 1-sigma (it holds the drawn terms as bounds), the
    turn-on bias most of the error."""
    f = figures(6)
    assert f["blocks"] == 6 * 800 and f["max_ratio"] < 4.0 and 0.5 < f["ratio_std"] < 1.2
    assert 0.01 < f["rms_error"] < 0.04 and f["run_mean_rms"] > 0.8 * f["rms_error"]


def test_an_injected_bias_step_shows_in_its_window_only():
    out, truth, _ = run(IDEAL | {"faults": "10-20:0.05;30-40:-0.1:5"}, graded_track(), 45.0,
                         lambda t: TruthState(t, 500.0, 0.0, 0.0))
    err, _ = errors(out, truth)
    stamps = np.array([m.stamp for m in out])
    half_lsb = 0.5 * lsb({"full_range": 2 * GRAVITY, "adc_bits": 16})   # a constant force, no noise: rounded
    assert err[(stamps > 10.1) & (stamps < 19.9)] == pytest.approx(0.05 / GAIN, abs=half_lsb)
    assert err[(stamps > 35.1) & (stamps < 39.9)] == pytest.approx(-0.1 / GAIN, abs=half_lsb)
    ramp = (stamps > 30.1) & (stamps < 34.9)      # grown over 5 s
    assert err[ramp] == pytest.approx(-0.1 / GAIN * (stamps[ramp] - 30.0) / 5.0, abs=half_lsb)
    assert np.abs(err[(stamps < 9.9) | ((stamps > 20.1) & (stamps < 29.9)) | (stamps > 40.1)]).max() < 1e-3
    with pytest.raises(ValueError, match="malformed accelerometer fault"):
        parse_faults("10-20")


# ------------------------------------------------------------------------------ error model, bad input
def test_error_model_figures():
    accelerometer = spec("accelerometer")
    model = accelerometer.errors(sensor_params(accelerometer, {}, Vehicle()), graded_track(), Vehicle())
    assert model.measures == "acceleration" and not model.relative
    # the fusion's bias state: turn-on and instability, 5e-4 m/s^2/K over 5 K, 0.5 per mille of g
    reported = math.hypot(math.hypot(0.02, 0.002), GRAVITY * 0.5e-3)
    assert model.bias_sigma == pytest.approx(math.hypot(reported, 5.0e-4 * 5.0)) and model.bias_tau == 20.0
    assert model.reported_bias == pytest.approx(reported)
    assert model.scale_sigma == 0.0 == model.reported_scale   # 0.2 % of a: in the reported 1-sigma
    assert set(model.faults) == {"dropout", "bias_step"} and model.timeout == 1.0
    assert model.min_stddev == pytest.approx(math.hypot(turn_on_sigma({"bias_sigma": 0.02, "bias_instability": 0.002}),
                                                        GRAVITY * 0.5e-3))
    ok = Acceleration(1.0, "accelerometer", "accelerometer", 0.3, model.min_stddev)
    assert model.refusal(ok) is None
    assert model.refusal(Acceleration(1.0, "accelerometer", "accelerometer", 0.3, 0.5 * model.min_stddev)).reason \
        == "below_model"


def _block(seq: int, force, temperature=25.0, channels=("specific_force", "temperature")) -> RawBlock:
    data = np.column_stack([np.full(5, force, np.float32), np.full(5, temperature, np.float32)])
    return RawBlock("accelerometer", "accelerometer", seq, 0.05 * seq, 100.0, channels, ("m/s^2", "degC"), data)


def test_bad_input_is_refused_in_one_line_and_counted():
    pipe = SensorPipeline(spec("accelerometer"), {}, Track("flat", 1000.0), Vehicle(), simulate=False)
    assert pipe.on_block(_block(0, 0.1))[0].acceleration == pytest.approx(0.1 / (1 + GRAVITY * 1e-3))
    bad = {"saturated": _block(1, 2 * GRAVITY), "implausible": _block(1, 0.0, temperature=150.0),
           "channels": _block(1, 0.0, channels=("force", "temperature"))}
    for reason, block in bad.items():
        with pytest.raises(InputRejected) as exc:
            pipe.on_block(block)
        assert exc.value.reason == reason and "\n" not in str(exc.value)
    with pytest.raises(InputRejected) as exc:
        pipe.on_position(TrackPosition(0.1, math.nan, 1.0, 0.0))
    assert exc.value.reason == "nan"
    assert dict(pipe.rejected) == {"saturated": 1, "implausible": 1, "channels": 1, "nan": 1}
    assert pipe.on_block(_block(1, -0.2))[0].acceleration < 0.0   # it goes on after them
    for m in (Acceleration(0.0, "a", "a", math.nan, 0.1), Acceleration(0.0, "a", "a", 30.0, 0.1),
              Acceleration(0.0, "a", "a", 0.1, 0.0), Acceleration(math.inf, "a", "a", 0.1, 0.1)):
        with pytest.raises(InputRejected):
            m.validate()


def test_the_fusion_takes_an_acceleration_into_its_acceleration_and_the_bias_state():
    """A fusion configured with an accelerometer takes its Acceleration (nothing refused): the
    filter's acceleration moves towards the reading, the accelerometer's bias state (layout
    ``accel_bias``) takes a share of the difference, and the acceleration's variance shrinks."""
    from train_localization.core.fusion import FusionRunner, fusion_config
    from train_localization.core.scenario import Scenario
    sc = Scenario.from_yaml(ROOT / "config" / "scenario_demo.yaml")
    sc.sensors["accelerometer"] = {}
    runner = FusionRunner(fusion_config(sc))
    f = runner.filter
    c = f.layout.accel_bias["accelerometer"]
    P_aa = float(f.ekf.P[2, 2])
    runner.add(Acceleration(0.1, "accelerometer", "accelerometer", 0.5, 0.03))
    runner.advance(0.2)
    assert runner.rejected == {} and f.counters()["accepted"] == {"accelerometer": 1}
    a, bias = float(f.ekf.x[2, 0]), float(f.ekf.x[c, 0])
    assert 0.3 < a < 0.5 and 0.0 < bias < 0.05
    assert float(f.ekf.P[2, 2]) < 0.1 * P_aa


def test_the_node_takes_its_position_from_a_train_state_and_publishes_the_acceleration(ros_context, start_node,
                                                                                       tmp_path):
    """Over DDS: an ingest accelerometer node on a graded track (a train at rest at 2 km, 20 per
    mille), its raw blocks simulated here and its position on localization/state (the fusion's
    TrainState; states of another track refused): it publishes AccelWithCovarianceStamped with
    the gravity (0.196 m/s^2) taken out: about 0, within 4 sigma, its 1-sigma that of a placed
    position (not the track's span)."""
    import yaml
    from geometry_msgs.msg import AccelWithCovarianceStamped
    from train_localization_msgs.msg import RawBlock as RawBlockMsg, TrainState
    from train_localization.core.convert import raw_block_to_msg, train_state_to_msg
    from train_localization.nodes.common import STREAM_QOS, rclpy_classes

    track_file = tmp_path / "graded.yaml"
    track_file.write_text(yaml.safe_dump({"track_id": "t", "length": 5000.0, "gradient": {"profile": [
        {"position": 0.0, "gradient": 0.0}, {"position": 1000.0, "gradient": 20.0}]}}))
    proc = start_node("accelerometer", "--ros-args", "-r", "__ns:=/train", "-p", "mode:=ingest",
                      "-p", f"track:={track_file}")
    node = ros_context.create_node("probe_accelerometer", namespace="/train")
    raw_pub = node.create_publisher(RawBlockMsg, "sensors/accelerometer/raw", STREAM_QOS)
    state_pub = node.create_publisher(TrainState, "localization/state", STREAM_QOS)
    got = []
    node.create_subscription(AccelWithCovarianceStamped, "sensors/accelerometer/acceleration", got.append, STREAM_QOS)
    pipe = SensorPipeline(spec("accelerometer"), {}, Track.from_yaml(track_file), Vehicle(), np.random.default_rng(3))
    blocks = [b for k in range(301) for b in pipe.on_truth(TruthState(k / 100.0, 2000.0, 0.0, 0.0))]
    mc = rclpy_classes()
    try:
        assert spin_until(node, lambda: raw_pub.get_subscription_count() > 0 and state_pub.get_subscription_count() > 0,
                          30.0), proc.output()
        for k, block in enumerate(blocks):
            state_pub.publish(train_state_to_msg(mc, block.t0, "t", 2000.0, 0.0, 0.0, position_stddev=5.0))
            if k % 2:   # a newer state of another track, on the level part: refused, or the output shows it
                state_pub.publish(train_state_to_msg(mc, block.t0 + 0.001, "other", 500.0, 0.0, 0.0))
            spin_until(node, lambda: False, 0.01)
            raw_pub.publish(raw_block_to_msg(block, mc))
        assert spin_until(node, lambda: len(got) >= len(blocks) - 5, 20.0), (len(got), proc.output()[-2000:])
        placed = [m for m in got if m.accel.covariance[0] < 0.05 ** 2]   # the first may precede any position
        assert len(placed) > len(blocks) - 10 and {m.header.frame_id for m in placed} == {"accelerometer"}
        assert all(abs(m.accel.accel.linear.x) <= 4.0 * math.sqrt(m.accel.covariance[0]) for m in placed)
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()

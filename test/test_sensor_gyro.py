"""The yaw-rate gyro (core/sensors/gyro.py): its turn rate against the truth through a
turnout, its one-line refusals, and the along-track fusion's refusal of turn rates."""
from __future__ import annotations

import math

import numpy as np
import pytest

from train_localization.core.fusion import FusionRunner, fusion_config
from train_localization.core.measurements import YawRate
from train_localization.core.pipeline import SensorPipeline
from train_localization.core.scenario import Scenario
from train_localization.core.sensors import spec
from train_localization.core.sensors.gyro import PARAMS, reported_sigma
from train_localization.core.signals import InputRejected, RawBlock
from train_localization.core.track import Track


def test_the_curvature_of_an_alignment_is_its_segments():
    track = Track("t", 1000.0, segments=[(100.0, 0.0), (50.0, 0.01), (50.0, -0.004)])
    assert track.curvature(np.array([50.0, 120.0, 175.0, 600.0, -1.0])).tolist() == [0.0, 0.01, -0.004, 0.0, 0.0]
    assert track.curvature(150.0) == -0.004   # a segment starts where the previous ends


def _south_through_w3():
    sc = Scenario.from_yaml("config/scenario_throat.yaml").train("south")
    pipe = SensorPipeline(spec("gyro"), {}, sc.track, sc.vehicle, sc.rng("gyro"))
    traj = sc.trajectory()
    out = []
    for k in range(int(75.0 * 100) + 1):
        for block in pipe.on_truth(traj.state_at(k / 100.0)):
            out += pipe.on_block(block)
    return sc, traj, out


def test_the_turn_rate_through_the_turnout_is_speed_times_curvature():
    sc, traj, rates = _south_through_w3()
    offset = PARAMS["mount_offset"].default
    t = np.array([m.stamp for m in rates])
    measured = np.array([m.yaw_rate for m in rates])
    sigma = rates[0].yaw_rate_stddev
    assert sigma == pytest.approx(reported_sigma({"noise_density": 2.0e-4, "bias_sigma": 5.0e-4}, 5, 100.0))
    s = np.interp(t, traj.t, traj.position)
    v = np.interp(t, traj.t, traj.speed)
    true = v * sc.track.curvature(s - offset)
    # blocks that straddle a change of curvature average both sides: leave them out
    steady = sc.track.curvature(s - offset - 1.0) == sc.track.curvature(s - offset + 1.0)
    err = (measured - true)[steady]
    assert np.abs(err).max() < 4.0 * sigma + 0.005 * np.abs(true[steady]).max()
    turning = steady & (np.abs(true) > 0.05)
    assert turning.sum() > 40 and np.all(np.sign(measured[turning]) == np.sign(true[turning]))
    assert true.max() == pytest.approx(18.0 / 190.0, rel=0.01)   # 18 m/s on R 190 m, to the left first


def test_bad_blocks_are_refused_in_one_line():
    sc = Scenario.from_yaml("config/scenario_throat.yaml").train("south")
    pipe = SensorPipeline(spec("gyro"), {}, sc.track, sc.vehicle, simulate=False)
    good = RawBlock("gyro", "gyro", 0, 0.0, 100.0, ("rate",), ("rad/s",), np.zeros((5, 1), np.float32))
    assert pipe.on_block(good)[0].yaw_rate == 0.0
    spin = RawBlock("gyro", "gyro", 1, 0.05, 100.0, ("rate",), ("rad/s",), np.full((5, 1), 3.0, np.float32))
    with pytest.raises(InputRejected, match="beyond any vehicle's turn") as err:
        pipe.on_block(spin)
    assert err.value.reason == "implausible" and pipe.rejected["implausible"] == 1
    other = RawBlock("gyro", "gyro", 1, 0.05, 100.0, ("pitch",), ("rad/s",), np.zeros((5, 1), np.float32))
    with pytest.raises(InputRejected):
        pipe.on_block(other)
    assert pipe.accepted == 1


def test_the_along_track_fusion_refuses_a_turn_rate_and_counts_it():
    sc = Scenario.from_yaml("config/scenario_demo.yaml")
    runner = FusionRunner(fusion_config(sc, sensors={**fusion_config(sc).sensors,
                                                     "gyro": spec("gyro").errors(
                                                         {p: v.default for p, v in PARAMS.items()}, sc.track,
                                                         sc.vehicle)}))
    assert not runner.add(YawRate(0.1, "gyro", "gyro", 0.01, 0.001))
    assert runner.rejected == {"not_used": 1} and "turn rate" in str(runner.last_error)
    with pytest.raises(InputRejected, match="stddev"):
        YawRate(0.1, "gyro", "gyro", 0.01, 0.0).validate()
    with pytest.raises(InputRejected) as err:
        YawRate(0.1, "gyro", "gyro", math.nan, 0.001).validate()
    assert err.value.reason == "nan"

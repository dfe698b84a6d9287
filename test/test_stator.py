"""Sectional feeding of the long stator (core/wayside/stator.py, seed 000 section 2): the
layout, the controller driven by a fused state and its interval, and the events on the
true motion."""
import math

import numpy as np
import pytest

from train_localization.core import campaign
from train_localization.core.scoring import StateSeries
from train_localization.core.track import Track
from train_localization.core.wayside import stator

RATE = 200.0          # fused states per second
SPEED = 100.0         # [m/s], 360 km/h
LENGTH = 80.0         # vehicle length [m]


def _track(sections: list[dict], length: float = 6000.0) -> Track:
    return Track.from_dict({"track_id": "stator_test", "length": length, "equipment": {stator.KIND: sections}})


def _truth(duration: float = 40.0, start: float = 300.0):
    t = np.arange(0.0, duration + 1e-9, 0.01)
    return t, start + SPEED * t


def _fused(bias: float = 0.0, half_width: float = 1.0, mode: int = 1, speed_stddev: float = 0.05,
           lost: tuple[float, float] | None = None) -> StateSeries:
    """States of a fusion whose position is off by ``bias`` [m] with an interval of
    +-``half_width`` [m] around it; LOST (no claim) within ``lost`` (t0, t1) [s]."""
    t_truth, x_truth = _truth()
    t = np.arange(0.0, t_truth[-1] + 1e-9, 1.0 / RATE)
    x = np.interp(t, t_truth, x_truth) + bias
    modes = np.full(t.size, float(mode))
    if lost:
        modes[(t >= lost[0]) & (t < lost[1])] = 3.0
    n = t.size
    return StateSeries(t, x, np.full(n, SPEED), np.full(n, half_width / 3.29), np.full(n, speed_stddev),
                       x - half_width, x + half_width, modes)


def _run(section_length: float, series: StateSeries, overrides=None):
    layout = stator.Layout.from_track(_track(stator.lay_sections(0.0, 6000.0, section_length)))
    vehicle = stator.Vehicle(LENGTH, 1)
    ctrl = stator.run_controller(layout, vehicle, series, overrides)
    t, x = _truth()
    return ctrl, stator.evaluate(layout, ctrl.commands, t, x, vehicle)


def _long_enough() -> float:
    return stator.min_section_length(stator.controller_params(), LENGTH, SPEED, 2.0, 1.0 / RATE)


def test_sections_alternate_between_two_inverters_and_a_bad_layout_is_refused_in_one_line():
    layout = stator.Layout.from_track(_track(stator.lay_sections(0.0, 1000.0, 300.0)))
    assert [(s.section_id, s.start, s.end, s.inverter) for s in layout.sections] == [
        ("ST000", 0.0, 300.0, "INV1"), ("ST001", 300.0, 600.0, "INV2"), ("ST002", 600.0, 1000.0, "INV1")]
    assert list(layout.overlapping(250.0, 310.0)) == [0, 1]
    assert list(layout.overlapping(1000.0, 1200.0)) == []
    with pytest.raises(stator.StatorError, match="'A' .* overlaps 'B'"):
        stator.Layout.from_track(_track([{"id": "A", "position": 0.0, "end": 300.0},
                                         {"id": "B", "position": 290.0, "end": 600.0}]))
    with pytest.raises(stator.StatorError, match="neither 'end' nor 'length'"):
        stator.Layout.from_track(_track([{"id": "A", "position": 0.0}]))
    with pytest.raises(stator.StatorError, match="not after its start"):
        stator.Layout.from_track(_track([{"id": "A", "position": 10.0, "end": 10.0}]))
    with pytest.raises(ValueError, match="switch_time"):
        stator.controller_params({"switch_time": -1.0})


def test_an_honest_interval_feeds_every_section_ahead_of_the_vehicle_and_switches_none_under_it():
    ctrl, rep = _run(_long_enough() * 1.05, _fused(bias=0.8, half_width=1.0))
    passed = rep.section_passages
    assert passed == int((300.0 + SPEED * 40.0) // (_long_enough() * 1.05)) - int(300.0 // (_long_enough() * 1.05))
    assert rep.switched_under_vehicle == [] and rep.double_feed == []
    assert rep.thrust_loss_s == 0.0
    assert ctrl.counters["inverter_busy"] == 0
    # each passed section switched on once and off once, plus the two fed at the start
    assert ctrl.counters["switch_on"] == passed + 2 and ctrl.counters["switch_off"] == passed
    assert len(ctrl.fed) == 2


def test_an_interval_that_misses_the_truth_switches_a_section_off_under_the_vehicle_and_one_that_covers_it_does_not():
    # the fusion is 25 m ahead of the truth, more than the vehicle runs while a switch opens
    # (100 m/s x 0.15 s) plus the margin: the rear is believed past a section it is still over
    _, wrong = _run(_long_enough() * 1.3, _fused(bias=25.0, half_width=1.0))
    off_under = [e for e in wrong.switched_under_vehicle if e[2] == "off"]
    assert off_under and wrong.thrust_loss_s > 0.0
    assert wrong.as_dict()["switched_off_under_vehicle"] == len(off_under)
    _, covered = _run(_long_enough() * 1.3, _fused(bias=25.0, half_width=26.0))
    assert covered.switched_under_vehicle == [] and covered.thrust_loss_s == 0.0


def test_sections_shorter_than_the_least_length_make_the_controller_wait_for_an_inverter_and_cost_thrust():
    ctrl, rep = _run(0.7 * _long_enough(), _fused(half_width=1.0))
    assert ctrl.counters["inverter_busy"] > 0
    assert rep.thrust_loss_s > 0.0 and rep.double_feed == []
    assert {e[2] for e in rep.switched_under_vehicle} == {"on"}     # late, never cut under load


def test_a_lost_train_holds_its_sections_and_none_is_switched_under_it():
    ctrl, rep = _run(_long_enough() * 1.3, _fused(half_width=1.0, lost=(10.0, 10.5)))
    assert ctrl.counters["held"] > 0
    assert all(e[2] == "on" for e in rep.switched_under_vehicle)   # held: nothing cut under the vehicle
    assert rep.double_feed == []


def test_long_stator_campaign_runs_feed_every_section_in_time():
    for family, seed in (("highspeed_maglev", 3), ("mlx", 6)):
        r = campaign.run_one(family, seed, max_duration=15.0)
        assert "error" not in r, r.get("traceback")
        st = r["stator"]
        assert st["section_passages"] > 0 and st["switchings"] > 0
        assert st["switched_under_vehicle"] == 0 and st["double_feed"] == 0
        assert st["thrust_loss_s"] == 0.0
        assert r["conditions"]["stator_section_length"] >= 50.0
    summary = campaign.summarise([r])
    assert summary["checks"]["stator_none_switched_off_under_vehicle"] is True
    assert not math.isnan(summary["all"]["stator"]["thrust_loss_per_passage_s"]["max"])


def test_the_node_takes_a_claimed_state_and_refuses_one_it_cannot_use():
    from train_localization.nodes.stator import view_from_msg
    from train_localization_msgs.msg import TrainState
    msg = TrainState(position=1000.0, position_min=999.0, position_max=1001.5, speed=100.0, speed_stddev=0.1, mode=1)
    msg.header.stamp.sec, msg.header.stamp.nanosec = 12, 500_000_000
    assert view_from_msg(msg) == stator.TrainView(12.5, True, 999.0, 1001.5, 100.0, 0.1)
    msg.mode = 0                       # initialising: not claimed, held by the controller
    assert view_from_msg(msg).claimed is False
    msg.mode, msg.position_min, msg.position_max = 2, 1002.0, 1001.0
    with pytest.raises(ValueError, match="interval"):
        view_from_msg(msg)
    msg.position_min, msg.speed_stddev = 999.0, float("nan")
    with pytest.raises(ValueError, match="speed"):
        view_from_msg(msg)

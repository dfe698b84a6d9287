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
    ctrl, rep = _run(_long_enough() * 1.3, _fused(half_width=1.0, lost=(10.0, 11.0)))
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
    ctrl = _controller()
    msg.mode, msg.position_min, msg.position_max = 2, 1002.0, 1001.0
    assert ctrl.admit("train", view_from_msg(msg), None).reason == "implausible"       # upside down
    msg.position_min, msg.speed_stddev = 999.0, float("nan")
    assert ctrl.admit("train", view_from_msg(msg), None).reason == "nan"
    msg.mode = 3                       # lost: its interval and speed mean nothing, only its stamp counts
    assert ctrl.admit("train", view_from_msg(msg), None) is None
    assert ctrl.refused() == {"implausible": 1, "nan": 1}


# ---- admission (core/safety): spoofed states, the union of the admitted states ----------

SECTION = 300.0
TRACK = 6000.0


def _controller(overrides=None, length: float = LENGTH, inverters: int = 2) -> stator.StatorController:
    layout = stator.Layout.from_track(_track(stator.lay_sections(0.0, TRACK, SECTION)), inverters)
    return stator.StatorController(layout, {"train": stator.Vehicle(length, 1)}, overrides, extent=(0.0, TRACK))


def _view(t: float, front: float, speed: float = SPEED, half: float = 1.0, claimed: bool = True,
          speed_stddev: float = 0.05) -> stator.TrainView:
    return stator.TrainView(t, claimed, front - half, front + half, speed, speed_stddev)


def _drive(ctrl: stator.StatorController, events, t_end: float) -> list[tuple[float, list[str]]]:
    """``events`` (arrival [s], view) admitted in arrival order before each decision (every
    period, arrival at or before it, at the decision's time as the node's clock); the fed
    sections after each decision."""
    events = sorted(events, key=lambda e: e[0])
    fed, j = [], 0
    for now in np.arange(0.0, t_end + 1e-9, ctrl.params["period"]).tolist():
        while j < len(events) and events[j][0] <= now + 1e-9:
            ctrl.admit("train", events[j][1], now)
            j += 1
        ctrl.update(now)
        fed.append((now, ctrl.fed_sections()))
    return fed


def _under(front: float, length: float = LENGTH, section: float = SECTION, track: float = TRACK) -> set[str]:
    """Sections ST000.. of ``section`` [m] laid from 0 to ``track`` [m] (_controller's layout by
    default) under a vehicle of ``length`` [m] whose front is at ``front`` [m]."""
    return {f"ST{k:03d}" for k in range(int(track // section))
            if k * section < front and (k + 1) * section > front - length}


def test_spoofed_states_are_refused_by_reason_and_the_section_under_the_vehicle_stays_fed():
    """The finding of issue 48 offline: a real stream at 100 Hz (100 m/s from 500 m) and, for
    2 s, states 5 km ahead of it at 1 kHz, one with the interval [-1e9, 1e9] m, one NaN, one
    stamped 10 s ahead of the clock, one claiming standstill, one real state sent again and one
    sent late. Each spoof is refused with its reason (exact counts), every real state taken;
    the section under the vehicle is fed at every decision from the start-up on, nothing near
    the spoofs ever is."""
    ctrl = _controller()
    x0, duration = 500.0, 6.0
    truth = lambda t: x0 + SPEED * t                                            # noqa: E731
    real = [(t, _view(t, truth(t))) for t in np.round(np.arange(0.0, duration, 0.01), 6).tolist()]
    spoofs = [(t, _view(t, truth(t) + 5000.0)) for t in np.round(np.arange(2.0005, 4.0, 0.001), 6).tolist()]
    odd = [(3.0002, stator.TrainView(3.0002, True, -1e9, 1e9, SPEED, 0.05)),    # the whole line: implausible
           (3.0003, _view(3.0003, float("nan"))),                               # nan
           (3.0004, _view(13.0, truth(13.0))),                                  # 10 s ahead of the clock: future
           (3.0006, _view(3.0006, truth(3.0006), speed=0.0, speed_stddev=0.01)),  # standstill: motion
           (3.0107, _view(3.0, truth(3.0))),                                    # a real state again, late: stamp_back
           (3.0108, _view(3.01, truth(3.01)))]                                  # and once more at its stamp: duplicate
    fed = _drive(ctrl, real + spoofs + odd, duration)
    assert ctrl.refused() == {"motion": len(spoofs) + 1, "implausible": 1, "nan": 1, "future": 1, "stamp_back": 1,
                              "duplicate": 1}
    assert ctrl.trains["train"].stream.admitted == len(real)
    delay = ctrl.delay
    for now, ids in fed:
        if now >= 2.0 * delay:        # the first commands (at t = 0) have taken effect
            assert _under(truth(now)) <= set(ids), (now, ids)
    last = int((x0 + SPEED * duration) // SECTION) + 1        # nothing fed beyond the section ahead of the end
    assert max(int(sid[2:]) for _, ids in fed for sid in ids) <= last
    t = np.arange(0.0, duration, 0.001)
    rep = stator.evaluate(ctrl.layout, ctrl.commands, t, truth(t), stator.Vehicle(LENGTH, 1))
    assert rep.switched_under_vehicle == [] and rep.thrust_loss_s == 0.0 and rep.double_feed == []
    assert ctrl.counters["stale"] == 0 and ctrl.counters["held"] == 0


def test_the_latest_state_alone_would_have_cut_the_section_under_the_vehicle():
    """The same spoofs to a controller that takes every state unchecked (what the node did): the
    section under the vehicle goes unfed -- what the admission is for."""
    ctrl = _controller()
    truth = lambda t: 500.0 + SPEED * t                                         # noqa: E731
    ctrl.admit = lambda name, view, now: ctrl.trains[name].window.append(view) or None   # no admission
    ctrl.params["max_state_age"] = 0.001                                        # and the latest state only
    events = [(t, _view(t, truth(t))) for t in np.round(np.arange(0.0, 4.0, 0.01), 6).tolist()]
    events += [(t, _view(t, truth(t) + 5000.0)) for t in np.round(np.arange(2.0005, 4.0, 0.001), 6).tolist()]
    fed = _drive(ctrl, events, 4.0)
    assert any(not _under(truth(now)) <= set(ids) for now, ids in fed if now > 2.0)


def test_the_union_of_the_admitted_states_holds_a_section_while_any_of_them_may_place_the_vehicle_on_it():
    """State A (front 990..1010 m, at rest) and then states B (front 1005..1010 m, the same
    vehicle better placed): A's span reaches back into the section 900..950 m, B's does not.
    That section stays fed while A is within max_state_age (0.5 s) and is switched off after;
    a stream that then stays silent (stale after input_timeout) holds its sections."""
    layout = stator.Layout.from_track(_track(stator.lay_sections(0.0, 2000.0, 50.0)), 3)
    ctrl = stator.StatorController(layout, {"train": stator.Vehicle(50.0, 1)}, extent=(0.0, 2000.0))
    a = stator.TrainView(0.0, True, 990.0, 1010.0, 0.0, 0.01)
    b = [(t, stator.TrainView(t, True, 1005.0, 1010.0, 0.0, 0.01)) for t in np.round(np.arange(0.1, 1.0, 0.05), 6)]
    fed = dict((round(now, 3), ids) for now, ids in _drive(ctrl, [(0.0, a)] + b, 3.0))
    assert ctrl.refused() == {}
    assert fed[0.0] == fed[0.5] == ["ST018", "ST019", "ST020"]        # 900..950 by A, 950..1050 by both
    assert fed[0.52] == ["ST019", "ST020"]                            # A is older than 0.5 s
    assert ctrl.counters["stale"] > 0 and fed[3.0] == ["ST019", "ST020"]   # silent since 0.95 s: held
    assert ctrl.trains["train"].stream.stale(3.0) and ctrl.stale == {"train"}


def test_a_stale_stream_holds_its_sections_fed_under_spoofs_that_are_all_refused():
    """Real states stop at 2 s; spoofs 5 km ahead go on: all refused (motion), the stream is
    stale after input_timeout and its train holds what it needed: nothing switched off under
    it and nothing switched on for the spoofs."""
    ctrl = _controller()
    truth = lambda t: 500.0 + 20.0 * t                                          # noqa: E731
    real = [(t, _view(t, truth(t), speed=20.0)) for t in np.round(np.arange(0.0, 2.0, 0.01), 6).tolist()]
    spoofs = [(t, _view(t, truth(t) + 5000.0, speed=20.0)) for t in np.round(np.arange(2.0005, 5.0, 0.001), 6).tolist()]
    fed = _drive(ctrl, real + spoofs, 5.0)
    assert ctrl.refused() == {"motion": len(spoofs)}
    before = dict(fed)[1.99]
    assert _under(truth(1.99)) <= set(before)
    assert all(ids == before for now, ids in fed if now >= 1.99)
    assert ctrl.counters["stale"] > 0 and ctrl.stale == {"train"}


def test_admission_parameters_are_declared_with_ranges():
    for name in ("track_margin", "max_interval_width", "future_tolerance", "input_timeout", "max_acceleration",
                 "plausibility_margin", "speed_margin"):
        p = stator.PARAMS[name]
        assert p.description and p.limits and p.limits[0] <= p.default <= p.limits[1], name
    with pytest.raises(ValueError, match="max_interval_width"):
        stator.controller_params({"max_interval_width": 0.0})


def test_spoofed_states_at_1khz_never_leave_the_section_under_the_real_vehicle_unfed_over_dds(tmp_path):
    """Issue 48 over DDS: a running stator_section_controller (config/track_maglev.yaml, 250 m
    sections, an 80 m vehicle) fed the states of a vehicle running at 80 m/s (100 Hz, stamped
    on the wall clock as a fusion's) and, for 2 s of it, states 5 km ahead at about 1 kHz from
    another publisher, with one of interval [-1e9, 1e9] m among them. In every StatorFeed
    message from the start-up on, the sections under the real vehicle (from the message's
    stamp until its commands take effect) are fed; every spoof is counted as refused in
    /diagnostics and every real state as accepted; the node keeps running and exits 0."""
    import os
    import time
    from train_localization.core.convert import stamp_to_sec
    from train_localization.nodes.common import LATCHED_QOS, STREAM_QOS
    from train_localization.tools.fuzz import set_time
    from train_localization.tools.fuzz_attacks import AttackResult, Bench
    from train_localization_msgs.msg import StatorFeed, TrainState

    speed, length, section, x0 = 80.0, 80.0, 250.0, 400.0
    bench = Bench("stator", "/spoof", int(os.environ["ROS_DOMAIN_ID"]), tmp_path)
    result = AttackResult("stator_spoof")
    try:
        child = bench.start("stator_section_controller", "stator_section_controller", {"train_length": length})
        path = f"{bench.namespace}/stator_section_controller"
        real_pub = bench.node.create_publisher(TrainState, "localization/state", STREAM_QOS)
        spoof_pub = bench.node.create_publisher(TrainState, "localization/state", STREAM_QOS)
        feeds = []
        bench.node.create_subscription(StatorFeed, "stator/feed", feeds.append, LATCHED_QOS)
        assert bench.spin_until(lambda: real_pub.get_subscription_count() > 0
                                and spoof_pub.get_subscription_count() > 0 and path in bench.diag, 60.0), \
            child.log_path.read_text()

        def state(t: float, front: float, lo: float | None = None, hi: float | None = None) -> TrainState:
            m = TrainState(track_id="maglev", position=front, position_min=front - 1.0 if lo is None else lo,
                           position_max=front + 1.0 if hi is None else hi, speed=speed, speed_stddev=0.05, mode=1)
            set_time(m.header.stamp, t)
            return m
        t0 = time.time()
        truth = lambda t: x0 + speed * (t - t0)                                   # noqa: E731
        attack = (t0 + 1.5, t0 + 3.5)
        sent = {"real": 0, "spoof": 0}
        next_real, next_spoof, wide_sent = t0, attack[0], False
        while (now := time.time()) < t0 + 5.5:
            if now >= next_real:
                real_pub.publish(state(now, truth(now)))
                sent["real"] += 1
                next_real += 0.01
            while attack[0] <= now < attack[1] and next_spoof <= now:
                t = time.time()
                if not wide_sent and now >= attack[0] + 1.0:
                    spoof_pub.publish(state(t, truth(t), -1e9, 1e9))
                    wide_sent = True
                else:
                    spoof_pub.publish(state(t, truth(t) + 5000.0))
                sent["spoof"] += 1
                next_spoof += 0.001
            bench.executor.spin_once(timeout_sec=0.0005)
        assert wide_sent and sent["spoof"] >= 1900, sent

        def counted() -> bool:
            v = bench.values(path)
            refused = sum(int(n) for k, n in v.items() if k.startswith("rejected/localization/state/"))
            return int(v.get("accepted/localization/state", 0)) == sent["real"] and refused == sent["spoof"]
        assert bench.spin_until(counted, 15.0), (sent, bench.values(path), child.log_path.read_text()[-2000:])
        values = bench.values(path)
        assert values["rejected/localization/state/implausible"] == "1", values
        assert int(values["rejected/localization/state/motion"]) >= 0.9 * sent["spoof"], values
        assert child.proc.poll() is None
        last_front = truth(next_real - 0.01)
        # the real states stopped: stale after input_timeout (1 s), the train holds its sections
        assert bench.spin_until(lambda: bench.values(path).get("stale_trains") == "train", 5.0), bench.values(path)
        assert _under(last_front, length, section, 14000.0) <= set(bench.values(path)["fed"].split(",")), \
            bench.values(path)

        delay = 0.05 + 0.1                                      # command_latency + switch_time (defaults)
        checked = 0
        for msg in feeds:
            t = stamp_to_sec(msg.header.stamp)
            if t < t0 + 0.5:                                   # start-up: the first commands take effect
                continue
            fed = {sid for sid, on in zip(msg.section_ids, msg.fed) if on}
            under = _under(truth(t + delay), length + speed * delay, section, 14000.0)   # until it takes effect
            assert under <= fed, (t - t0, sorted(under), sorted(fed))
            checked += 1
        during = [m for m in feeds if attack[0] <= stamp_to_sec(m.header.stamp) <= attack[1]]
        assert checked >= 5 and during, [stamp_to_sec(m.header.stamp) - t0 for m in feeds]
    finally:
        bench.stop(result)
    assert all(code == 0 for code in result.exit_codes.values()), result.exit_codes

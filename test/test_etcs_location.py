"""The ETCS location function (core/etcs; docs/etcs.md): the track's balise groups, Q_LOCACC
and linking, the location report's LRBG, doubts and safe front ends from the fused interval,
the expectation windows and their events, the odometer monitoring, and the campaign's ETCS
family scored on its truth."""
import math
from dataclasses import replace

import numpy as np
import pytest

from train_localization.core import campaign
from train_localization.core.etcs.carried import CarriedInterval, CarriedStep
from train_localization.core.etcs.location import PREVIOUS_LRBGS, FusedState, LocationTracker
from train_localization.core.etcs.records import EventKind, QDirLrbg, Reaction
from train_localization.core.etcs.track_data import EtcsData
from train_localization.core.measurements import PositionFix
from train_localization.core.safety.plausibility import speed_bound
from train_localization.core.sensors import eurobalise
from train_localization.core.track import Track, TrackError

ANTENNA = 2.0          # reader's antenna behind the front [m]
SPEED = 50.0           # [m/s]
HALF = 1.0             # half width of the fused interval [m]
CONF = 0.999999
STEP = 0.01         # between fused states [s]


def _track(linking="auto", q=1.0, national=None, groups=12, spacing=1000.0, extra_etcs=None, **balise) -> Track:
    return Track.from_dict(_track_dict(linking, q, national, groups, spacing, extra_etcs, **balise))


def _track_dict(linking="auto", q=1.0, national=None, groups=12, spacing=1000.0, extra_etcs=None, **balise) -> dict:
    etcs = {"linking": linking, "link_reaction": "service_brake", **(extra_etcs or {})}
    if national is not None:
        etcs["q_nvlocacc"] = national
    if linking is None:
        etcs.pop("linking")
    entry = {"every": spacing, "start": 500.0, "end": 500.0 + spacing * (groups - 1), "id": "BG{n:03d}a",
             "group": "BG{n:03d}", **balise}
    second = {**entry, "start": 503.0, "end": 503.0 + spacing * (groups - 1), "id": "BG{n:03d}b"}
    if q is not None:
        entry["q_locacc"] = second["q_locacc"] = q
    return {"track_id": "etcs_test", "length": 500.0 + spacing * groups, "equipment": {"eurobalise": [entry, second]},
            "etcs": etcs}


class Run:
    """A train at SPEED from chainage 0 whose fused interval is +-half(t) (HALF) about the truth
    (+ bias), states every STEP, and a balise fix for each balise it passes (unless silenced)."""

    def __init__(self, track: Track, speed: float = SPEED, bias=lambda t: 0.0, odometer_scale: float = 1.0,
                 silent=(), moved=None, directions: bool = True, orientation: int = 1, half=lambda t: HALF):
        self.track, self.speed, self.bias, self.half = track, speed, bias, half
        self.tracker = LocationTracker(EtcsData.from_track(track), {"orientation": orientation})
        self.scale = odometer_scale
        self.fixes = []
        for it in track.items("eurobalise"):
            if it["id"] in silent:
                continue
            front = it["position"] + ANTENNA + (moved or {}).get(it["id"], 0.0)
            t = front / speed
            direction = (1 if it["id"].endswith("b") else 0) if directions else 0
            self.fixes.append(PositionFix(t, "eurobalise", "r", track.track_id, it["id"], it["position"] + ANTENNA,
                                          0.33, direction))
        self.reports, self.events = [], []

    def run(self, duration: float):
        fixes = sorted(self.fixes, key=lambda f: f.stamp)
        j = 0
        for t in np.arange(0.0, duration, STEP):
            while j < len(fixes) and fixes[j].stamp <= t:
                self.tracker.on_fix(fixes[j])
                j += 1
            x, h = self.speed * t + self.bias(t), self.half(t)
            report, events = self.tracker.on_state(FusedState(float(t), x, x - h, x + h, self.speed * self.scale,
                                                              0.05, CONF, 1))
            self.reports.append(report)
            self.events += events
        return self

    def kinds(self, kind):
        return [e for e in self.events if e.kind == kind]


# ------------------------------------------------------------------------- track data
def test_groups_take_their_balises_q_locacc_and_reference_and_auto_linking_their_chainages():
    data = EtcsData.from_track(_track(q=2.0))
    g = data.groups["BG003"]
    assert g.balises == ("BG003a", "BG003b") and g.positions == (3500.0, 3503.0)
    assert g.reference == 3500.0 and g.orientation == 1 and g.q_locacc == 2.0
    assert data.group_of_balise["BG003b"] == "BG003"
    up, down = data.link_after("BG003", 1), data.link_after("BG003", -1)
    assert (up.to_bg, up.distance, up.reaction) == ("BG004", 1000.0, Reaction.SERVICE_BRAKE)
    assert (down.to_bg, down.distance) == ("BG002", 1000.0)
    assert data.link_after("BG011", 1) is None and data.link_after("BG000", -1) is None


def test_a_group_without_q_locacc_takes_the_national_value_and_without_one_the_track_is_refused():
    assert EtcsData.from_track(_track(q=None, national=12.0)).groups["BG000"].q_locacc == 12.0
    with pytest.raises(TrackError, match=r"^balise group BG000 has no q_locacc and track etcs_test no national "
                                         r"value \(etcs.q_nvlocacc\)$"):
        _track(q=None)


def test_a_linking_distance_that_does_not_match_the_chainages_is_refused_in_one_line():
    links = [{"from": "BG000", "to": "BG001", "distance": 1000.4}]
    assert EtcsData.from_track(_track(linking=links)).link_after("BG000", 1).distance == 1000.4
    with pytest.raises(TrackError) as err:
        _track(linking=[{"from": "BG000", "to": "BG001", "distance": 1001.0}])
    assert str(err.value) == ("track etcs_test: link BG000 -> BG001 distance 1001 m does not match the chainages "
                              "(1000 m apart, tolerance 0.5 m)")
    for bad, words in (([{"from": "BG000", "to": "BG099", "distance": 1.0}], "unknown balise group BG099"),
                       ([{"from": "BG000", "to": "BG001", "distance": 1000.0, "reaction": "stop"}], "reaction 'stop'"),
                       ("nearest", "must be 'auto' or a list")):
        with pytest.raises(TrackError, match=words):
            _track(linking=bad)
    with pytest.raises(TrackError, match="outside 0..63 m"):
        _track(q=80.0)
    with pytest.raises(TrackError, match="unknown keys in 'etcs': linkage"):
        _track(extra_etcs={"linkage": 1})


def test_the_readers_location_error_is_bounded_by_each_balises_q_locacc():
    """The reader's error model and simulator take a balise's Q_LOCACC as the bound of its
    location error (1-sigma Q_LOCACC / 3); a track without it keeps location_sigma."""
    params = {k: v.default for k, v in eurobalise.PARAMS.items()}
    track = _track(q=3.0)
    item = track.items("eurobalise")[0]
    assert eurobalise.balise_location_sigma(params, track, item) == pytest.approx(1.0)
    plain = Track.from_dict({"track_id": "p", "length": 100.0, "equipment": {"eurobalise": [{"id": "1", "position": 50.0}]}})
    assert eurobalise.balise_location_sigma(params, plain, plain.items("eurobalise")[0]) == params["location_sigma"]
    model = eurobalise.error_model(params, track, None)
    assert model.min_stddev == pytest.approx(1.0)
    sim = eurobalise.EurobaliseSimulator.__new__(eurobalise.EurobaliseSimulator)
    sim.rng = np.random.default_rng(4)
    err = sim._installation_errors(np.full(100_000, 1.0))
    assert np.max(np.abs(err)) <= 3.0 and np.std(err) == pytest.approx(math.sqrt(0.97334), rel=0.02)


# ------------------------------------------------------------------------- location report
def test_the_report_follows_the_lrbg_with_the_fused_interval_as_its_safe_front_ends():
    run = Run(_track()).run(235.0)
    lrbgs = run.kinds(EventKind.LRBG)
    assert [e.nid_bg for e in lrbgs] == [f"BG{n:03d}" for n in range(12)]
    assert "unlinked" in lrbgs[0].detail and all("linked group" in e.detail for e in lrbgs[1:])
    last = run.reports[-1]
    assert last.nid_lrbg == "BG011" and last.q_dirlrbg == QDirLrbg.NOMINAL and last.q_locacc == 1.0
    x = SPEED * last.t
    assert last.d_lrbg == pytest.approx(x - 11500.0)
    assert last.l_doubtover == pytest.approx(HALF) and last.l_doubtunder == pytest.approx(HALF)
    assert (last.min_safe_front_end, last.max_safe_front_end) == pytest.approx((x - HALF, x + HALF))
    assert last.v_est == SPEED and last.v_ura == pytest.approx(4.8916 * 0.05, rel=1e-4)
    assert last.previous_lrbgs == tuple(f"BG{n:03d}" for n in range(10, 10 - PREVIOUS_LRBGS, -1))
    assert len(last.previous_lrbgs) >= 7 and not last.odometer_impaired
    assert not run.kinds(EventKind.MISSED_LINKED_GROUP) and run.tracker.stats["same_group"] == 12


def test_a_train_facing_decreasing_chainage_reports_its_safe_front_ends_ahead_of_it():
    run = Run(_track(), orientation=-1).run(20.0)
    last = run.reports[-1]
    assert last.max_safe_front_end < last.estimated_front_end < last.min_safe_front_end
    assert last.v_est == -SPEED and last.q_dirlrbg == QDirLrbg.REVERSE


def test_a_missed_linked_group_is_reported_with_its_reaction_and_linking_chains_on():
    run = Run(_track(), silent={"BG004a", "BG004b"}).run(130.0)
    missed = run.kinds(EventKind.MISSED_LINKED_GROUP)
    assert [(e.nid_bg, e.reaction) for e in missed] == [("BG004", Reaction.SERVICE_BRAKE)]
    # closed when the min safe front end passed the window's end: 3503 m + 2 m + Q_LOCACC 1 m
    assert missed[0].t == pytest.approx((4506.0 + HALF) / SPEED, abs=0.011)
    assert [e.nid_bg for e in run.kinds(EventKind.LRBG)][4] == "BG005"   # read in the chained window


def test_the_expected_group_read_outside_its_window_is_rejected_then_missed():
    """A group read 20 m from its linked place (relaid without new data) while the interval is
    +-1 m: rejected, then missed; the next group is taken in its window."""
    run = Run(_track(), moved={"BG004a": 20.0, "BG004b": 20.0}).run(235.0)
    assert [e.nid_bg for e in run.kinds(EventKind.OUTSIDE_WINDOW)] == ["BG004", "BG004"]
    assert [e.nid_bg for e in run.kinds(EventKind.MISSED_LINKED_GROUP)] == ["BG004"]
    assert "BG004" not in [e.nid_bg for e in run.kinds(EventKind.LRBG)]
    assert run.reports[-1].nid_lrbg == "BG011"


def test_a_group_the_linking_does_not_announce_and_an_unknown_balise_are_ignored_with_an_event():
    track = _track()
    run = Run(track)
    run.fixes.append(PositionFix(50.0, "eurobalise", "r", track.track_id, "BG009a", 9502.0, 0.33, 0))
    run.fixes.append(PositionFix(51.0, "eurobalise", "r", track.track_id, "XX1", 9502.0, 0.33, 0))
    run.run(60.0)
    assert [e.nid_bg for e in run.kinds(EventKind.NOT_LINKED)] == ["BG009"]
    assert [e.nid_bg for e in run.kinds(EventKind.UNKNOWN_GROUP)] == ["XX1"]
    assert "BG009" not in [e.nid_bg for e in run.kinds(EventKind.LRBG)]


def test_a_linked_group_passed_against_its_link_trips_the_train():
    track = _track()
    run = Run(track)
    run.fixes = [replace(f, direction=-1) if f.reference_id == "BG003b" else f
                 for f in run.fixes if f.reference_id != "BG003a"]
    run.run(80.0)
    wrong = run.kinds(EventKind.WRONG_DIRECTION)
    assert [(e.nid_bg, e.reaction) for e in wrong] == [("BG003", Reaction.TRAIN_TRIP)]


V_URA = speed_bound(CONF, 0.05)   # the Run's v_ura [m/s] (4.89 x its speed_stddev 0.05)


def test_a_fused_interval_widening_after_the_lrbg_is_held_to_the_interval_the_speed_interval_carries():
    """The fused interval +-1 m until 15 s, then +-30 m (a hypothesis the fusion covers): the
    safe front ends are the +-1 m of 14.99 s grown by v_ura each way since, the truth inside; the
    next LRBG (BG001, 30.04 s) starts the carried interval again from the state's +-30 m."""
    run = Run(_track(), half=lambda t: HALF if t < 15.0 else 30.0).run(40.0)
    for t in (15.0, 20.0, 25.0, 29.0):
        r = run.reports[round(t / STEP)]
        x = SPEED * r.t
        grown = HALF + V_URA * (r.t - 14.99)
        assert r.nid_lrbg == "BG000"
        assert r.l_doubtover == pytest.approx(grown, abs=1e-6) and r.l_doubtunder == pytest.approx(grown, abs=1e-6)
        assert r.min_safe_front_end < x < r.max_safe_front_end
    lrbg = next(e for e in run.kinds(EventKind.LRBG) if e.nid_bg == "BG001")
    after = [r for r in run.reports if r.t > lrbg.t + 0.1]
    assert after[0].nid_lrbg == "BG001"
    assert all(r.l_doubtover == pytest.approx(30.0) and r.l_doubtunder == pytest.approx(30.0) for r in after)


def test_an_estimate_outside_the_carried_interval_stays_within_its_safe_front_ends():
    """The estimate 5 m ahead of the truth from 20 s, its interval +-30 m about it: the carried
    interval (the truth +-(1 m + v_ura since 14.99 s)) does not reach it, the max safe front
    end is the estimate (L_DOUBTUNDER 0), the min safe front end the carried one."""
    run = Run(_track(), half=lambda t: HALF if t < 15.0 else 30.0,
              bias=lambda t: 5.0 if t >= 20.0 else 0.0).run(25.0)
    r = run.reports[-1]
    x = SPEED * r.t
    grown = HALF + V_URA * (r.t - 14.99)
    assert r.estimated_front_end == pytest.approx(x + 5.0)
    assert r.l_doubtunder == 0.0 and r.l_doubtover == pytest.approx(5.0 + grown, abs=1e-6)
    assert r.min_safe_front_end == pytest.approx(x - grown, abs=1e-6) and r.max_safe_front_end == r.estimated_front_end


def test_the_carried_interval_falls_back_to_the_states_own_where_the_claims_contradict_or_a_speed_is_missing():
    carried = CarriedInterval()
    assert carried.advance(CarriedStep(0.0, 99.0, 101.0, 10.0, 0.5)) == (99.0, 101.0)
    # 1 s at 10 +- 0.5 m/s: [108.5, 111.5], the state's [100, 120]
    assert carried.advance(CarriedStep(1.0, 100.0, 120.0, 10.0, 0.5)) == pytest.approx((108.5, 111.5))
    # the state's interval beyond what the speed allows: disjoint, the state's own
    assert carried.advance(CarriedStep(2.0, 150.0, 160.0, 10.0, 0.5)) == (150.0, 160.0)
    assert carried.advance(CarriedStep(3.0, 140.0, 180.0, math.nan, 0.5)) == (-math.inf, math.inf)
    # after a state without a speed: started again from the next state's interval
    assert carried.advance(CarriedStep(4.0, 170.0, 190.0, 10.0, 0.5)) == (170.0, 190.0)
    carried.restart()
    assert carried.advance(CarriedStep(5.0, 175.0, 205.0, 10.0, 0.5)) == (175.0, 205.0)


def test_an_over_reading_odometer_is_impaired_and_the_doubts_fall_back_to_subset041():
    """The fused speed 10 % high while the balises show the true progress: every linked pair
    over-reads 100 m per km; the odometer is impaired, the report DEGRADED with doubts of at
    least Q_LOCACC + 5 m + 5 % of d_lrbg."""
    run = Run(_track(), odometer_scale=1.1).run(130.0)
    impaired = run.kinds(EventKind.ODOMETER_IMPAIRED)
    assert len(impaired) == 1 and impaired[0].t == pytest.approx(1502.0 / SPEED, abs=0.01)
    last = run.reports[-1]
    assert last.odometer_impaired and last.mode == 2
    assert last.l_doubtover == pytest.approx(1.0 + 5.0 + 0.05 * last.d_lrbg)
    assert not run.kinds(EventKind.ODOMETER_RESTORED)


def test_an_odometer_back_within_accuracy_for_a_monitoring_distance_is_restored():
    run = Run(_track(), odometer_scale=1.0)
    run.scale = 1.1
    tracker = run.tracker
    run.run(35.0)       # over-reading over BG000..BG003
    assert tracker.monitor.impaired
    run.scale = 1.0
    run.reports, run.events = [], []
    fixes = [f for f in run.fixes if f.stamp > 35.0]
    run.fixes = fixes
    for t in np.arange(35.0, 80.0, STEP):
        while run.fixes and run.fixes[0].stamp <= t:
            tracker.on_fix(run.fixes.pop(0))
        x = SPEED * t
        report, events = tracker.on_state(FusedState(float(t), x, x - HALF, x + HALF, SPEED, 0.05, CONF, 1))
        run.events += events
    restored = run.kinds(EventKind.ODOMETER_RESTORED)
    assert len(restored) == 1 and not tracker.monitor.impaired
    # two pairs within 5 m + 5 % after the impairment (BG001-BG002, BG002-BG003) make the 2000 m
    # monitoring distance
    assert restored[0].nid_bg == "" and restored[0].t == pytest.approx(3502.0 / SPEED, abs=0.01)


# ------------------------------------------------------------------------- campaign
def test_an_etcs_campaign_run_misses_its_silent_group_with_the_drawn_reaction_and_stays_inside():
    seed = campaign.run_seed(0, 11)
    r = campaign.run_one("etcs", seed, max_duration=150.0)
    assert "error" not in r, r.get("traceback")
    e, cond = r["etcs"], r["conditions"]
    assert cond["silent_group"] == "BG019" and cond["link_reaction"] == "service_brake"
    assert e["outside"] == 0 and e["claimed"] > 20000 and e["speed_inside_share"] == 1.0
    assert e["events"]["missed_linked_group"] >= 1 and e["missed_but_read"] == 0
    assert e["events"]["outside_window"] == 0 and e["events"]["wrong_direction"] == 0
    assert e["ratio_subset041"]["median"] < 0.3 and e["ratio_fixed_rule"]["median"] < 1.0


# ------------------------------------------------------------------------- node
def test_the_node_reports_the_lrbg_and_publishes_its_events_and_refuses_what_it_cannot_use(ros_context, start_node):
    """etcs_location on config/track_etcs.yaml: fused states at 50 m/s past BG000 and its two
    balise fixes give reports with LRBG BG000 and an LRBG event; a NaN state and a fix of
    another track are refused and counted."""
    from diagnostic_msgs.msg import DiagnosticArray
    from train_localization_msgs.msg import EtcsEvent, EtcsLocation, PositionFix as FixMsg, TrainState
    from train_localization.nodes.common import LATCHED_QOS, STREAM_QOS
    from conftest import etcs_location_status, spin_until

    proc = start_node("etcs_location", "--ros-args", "-r", "__ns:=/train")
    node = ros_context.create_node("probe_etcs_location", namespace="/train")
    state_pub = node.create_publisher(TrainState, "localization/state", STREAM_QOS)
    fix_pub = node.create_publisher(FixMsg, "sensors/eurobalise/position", STREAM_QOS)
    reports, events, diags = [], [], []
    node.create_subscription(EtcsLocation, "localization/etcs", reports.append, STREAM_QOS)
    node.create_subscription(EtcsEvent, "localization/etcs_events", events.append, LATCHED_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)

    def state(t, x, speed=SPEED):
        m = TrainState(track_id="etcs_line", position=x, position_min=x - HALF, position_max=x + HALF, speed=speed,
                       speed_stddev=0.05, confidence=0.999, mode=1)
        m.header.stamp.sec, m.header.stamp.nanosec = int(t), int(round((t % 1) * 1e9))
        return m

    def fix(t, balise, position, track="etcs_line", direction=0):
        m = FixMsg(sensor="eurobalise", unit_id="eurobalise", track_id=track, reference_id=balise, position=position,
                   position_stddev=0.33, direction=direction)
        m.header.stamp.sec, m.header.stamp.nanosec = int(t), int(round((t % 1) * 1e9))
        return m

    def own():
        return etcs_location_status(diags)
    try:
        assert spin_until(node, lambda: state_pub.get_subscription_count() > 0 and fix_pub.get_subscription_count() > 0
                          and node.count_publishers("/train/localization/etcs") > 0, 30.0), proc.output()
        spin_until(node, lambda: False, 0.5)
        fix_pub.publish(fix(10.04, "BG000a", 502.0))
        fix_pub.publish(fix(10.10, "BG000b", 505.0, direction=1))
        fix_pub.publish(fix(10.2, "BG000a", 502.0, track="elsewhere"))
        spin_until(node, lambda: False, 0.3)
        for k in range(60):
            t = 9.9 + 0.01 * k
            state_pub.publish(state(t, SPEED * t))
        state_pub.publish(state(10.6, math.nan))
        assert spin_until(node, lambda: len(reports) >= 60 and events, 20.0), proc.output()
        last = reports[-1]
        assert last.nid_lrbg == "BG000" and last.q_dirlrbg == EtcsLocation.Q_DIRLRBG_NOMINAL
        assert last.d_lrbg == pytest.approx(SPEED * 10.49 - 500.0) and last.q_locacc == 1.0
        assert last.l_doubtover == pytest.approx(HALF) and last.max_safe_front_end == pytest.approx(SPEED * 10.49 + HALF)
        assert reports[0].nid_lrbg == "" and math.isnan(reports[0].d_lrbg)
        assert [(e.kind, e.nid_bg) for e in events] == [(EtcsEvent.KIND_LRBG, "BG000")]
        assert spin_until(node, lambda: own().get("rejected/localization/state/nan") == "1"
                          and own().get("rejected/sensors/eurobalise/position/other_track") == "1", 20.0), own()
        assert own()["nid_lrbg"] == "BG000" and own()["lrbg"] == "1" and own()["same_group"] == "1"
        assert proc.interrupt() == 0 and "Traceback" not in proc.output()
    finally:
        node.destroy_node()


# ------------------------------------------------------------------------- closed loop
def test_the_supervised_train_stops_short_of_its_authority_without_a_trip():
    """config/scenario_etcs_stop.yaml in closed loop (core/etcs/supervised_run.py): the driver
    never brakes for the EOA at 2200 m; the supervision's service brake (then the emergency
    brake, when a 15 % slide widens v_ura) stops the train short of it, no trip, the truth
    always within the safe front ends."""
    from train_localization.core.etcs.supervised_run import supervised_stop
    from train_localization.core.scenario import Scenario
    from conftest import ROOT
    res = supervised_stop(Scenario.from_yaml(ROOT / "config" / "scenario_etcs_stop.yaml"))
    assert res.stopped and res.trips == 0 and res.max_status == 3
    assert 0.0 < res.margin <= res.first_stop_margin < 300.0
    assert res.min_truth_to_safe_front >= 0.0 and res.max_safe_front_overshoot <= 0.0
    assert res.events.get("lrbg", 0) >= 2 and not res.events.get("missed_linked_group")


def test_randomised_stops_draw_a_braking_the_supervision_does_not_overrate():
    from train_localization.core.etcs.supervised_run import MASS, draw_stop
    for seed in range(30):
        d = draw_stop(seed)
        sc_track = Track.from_dict(d["track"])
        atp, dyn = d["atp"], d["dynamics"]
        assert atp["service_deceleration"] <= dyn["lim_force"] / MASS                 # what the train really has
        assert atp["brake_build_up_time"] > dyn["force_lag"]
        assert 2000.0 <= atp["end_of_authority"] - d["initial"]["position"] <= 6000.0
        assert atp["end_of_authority"] + 2000.0 < sc_track.length
        silent = d["sensors"]["eurobalise_reader"].get("silent_balises", "")
        assert all(b in EtcsData.from_track(sc_track).group_of_balise for b in silent.split(",") if b)


def _every_kind_run(track: Track, step: float = 0.05):
    """Fixes and fused states on ``track`` (``_track()``) whose events are every EventKind: a read
    naming BG010 before the first group (REFERENCE_REJECTED), BG000 (LRBG), a fused speed 10 %
    high until 40 s (ODOMETER_IMPAIRED, then RESTORED), an unknown balise, BG003 passed against
    its link (WRONG_DIRECTION, then MISSED_LINKED_GROUP), BG007 read 20 m late (OUTSIDE_WINDOW),
    BG009 read while BG008 is expected (NOT_LINKED)."""
    fixes = []
    for it in track.items("eurobalise"):
        bid = it["id"]
        if bid == "BG003a":
            continue
        late = 20.0 if bid.startswith("BG007") else 0.0
        direction = -1 if bid == "BG003b" else 1 if bid.endswith("b") else 0
        fixes.append(PositionFix((it["position"] + ANTENNA + late) / SPEED, "eurobalise", "r", track.track_id, bid,
                                 it["position"] + ANTENNA, 0.33, direction))
    fixes += [PositionFix(5.0, "eurobalise", "r", track.track_id, "BG010a", 250.0, 0.33, 0),
              PositionFix(51.0, "eurobalise", "r", track.track_id, "XX1", 2550.0, 0.33, 0),
              PositionFix(150.5, "eurobalise", "r", track.track_id, "BG009a", 9502.0, 0.33, 0)]
    states = [FusedState(float(t), SPEED * t, SPEED * t - HALF, SPEED * t + HALF, SPEED * (1.1 if t < 40.0 else 1.0),
                         0.05, CONF, 1) for t in np.arange(0.0, 235.0, step)]
    return fixes, states


def test_every_event_kind_is_published_by_the_live_node_and_none_stops_it(ros_context, start_node, tmp_path):
    """The run of ``_every_kind_run`` offline gives every EventKind; driven over DDS through a
    live etcs_location (fixes first, pending until the states pass their stamps) it publishes
    the same events in the same order, and the node keeps running (an event logged at another
    severity than the one before killed it: rclpy fixes a call site's severity)."""
    import yaml
    from train_localization_msgs.msg import EtcsEvent, EtcsLocation, PositionFix as FixMsg, TrainState
    from train_localization.nodes.common import LATCHED_QOS, STREAM_QOS
    from conftest import spin_until

    track = _track()
    fixes, states = _every_kind_run(track)
    tracker = LocationTracker(EtcsData.from_track(track), {"orientation": 1})
    for f in fixes:
        tracker.on_fix(f)
    expected = [(int(e.kind), e.nid_bg) for s in states for e in tracker.on_state(s)[1]]
    assert {k for k, _ in expected} == {int(k) for k in EventKind}, expected

    path = tmp_path / "track.yaml"
    path.write_text(yaml.safe_dump(_track_dict()))
    proc = start_node("etcs_location", "--ros-args", "-r", "__ns:=/kinds", "-p", f"track:={path}",
                      "-p", "max_input_rate:=1000000.0", "-p", "max_fix_rate:=1000000.0")
    node = ros_context.create_node("probe_etcs_kinds", namespace="/kinds")
    state_pub = node.create_publisher(TrainState, "localization/state", STREAM_QOS)
    fix_pub = node.create_publisher(FixMsg, "sensors/eurobalise/position", STREAM_QOS)
    reports, events = [], []
    node.create_subscription(EtcsLocation, "localization/etcs", reports.append, STREAM_QOS)
    node.create_subscription(EtcsEvent, "localization/etcs_events", events.append, LATCHED_QOS)

    def stamp(m, t):
        m.header.stamp.sec, m.header.stamp.nanosec = int(t), int(round((t % 1) * 1e9))
        return m
    try:
        assert spin_until(node, lambda: state_pub.get_subscription_count() > 0 and fix_pub.get_subscription_count() > 0
                          and node.count_publishers("/kinds/localization/etcs_events") > 0, 30.0), proc.output()
        spin_until(node, lambda: False, 0.5)
        for f in fixes:
            fix_pub.publish(stamp(FixMsg(sensor=f.sensor, unit_id=f.unit_id, track_id=f.track_id,
                                         reference_id=f.reference_id, position=f.position,
                                         position_stddev=f.position_stddev, direction=f.direction), f.stamp))
        spin_until(node, lambda: False, 0.5)
        for k, s in enumerate(states):
            state_pub.publish(stamp(TrainState(track_id=track.track_id, position=s.position,
                                               position_min=s.position_min, position_max=s.position_max,
                                               speed=s.speed, speed_stddev=s.speed_stddev, confidence=s.confidence,
                                               mode=s.mode), s.t))
            if k % 200 == 199:
                spin_until(node, lambda: len(reports) > k - 200, 10.0)
        last = round(states[-1].t * 1e9)
        assert spin_until(node, lambda: reports and reports[-1].header.stamp.sec * 10 ** 9
                          + reports[-1].header.stamp.nanosec == last and len(events) >= len(expected), 30.0), \
            (len(reports), len(events), proc.output())
        assert [(e.kind, e.nid_bg) for e in events] == expected
        assert proc.proc.poll() is None
        assert proc.interrupt() == 0 and "Traceback" not in proc.output()
    finally:
        node.destroy_node()


def test_a_supervised_stop_under_every_attack_refuses_each_and_neither_overruns_nor_releases_while_moving():
    """One randomised stop (seed 0: 2.2 km to the EOA at 87 km/h) with one attack of each kind handed to the
    chain where the nodes would receive it (core/etcs/attacks.py): the standstill stamped 50 s
    ahead refused as future, the standstill report in the brake refused as motion, the far group
    refused as misplaced (REFERENCE_REJECTED), the flood of unknown ids shed beyond
    max_fix_rate, the spoofed states to the stator controller refused with nothing switched off
    under the vehicle; the train stops short of its EOA without a trip or a release while moving."""
    from train_localization.core.etcs import supervised_run as sr
    from train_localization.core.etcs.attacks import Attack
    from train_localization.core.scenario import Scenario
    data = sr.draw_stop(0)
    attacks = (Attack("state_ahead", 20.0, ahead=50.0), Attack("standstill_report", 0.0),
               Attack("far_group", 0.5, group="BG003"), Attack("unknown_flood", 30.0, rate=2000.0, duration=2.0),
               Attack("stator_spoof", 25.0, offset=5000.0, rate=1000.0, duration=2.0))
    res = sr.supervised_stop(Scenario.from_dict({k: v for k, v in data.items() if k != "draw"}), attacks=attacks)
    assert res.margin > 0.0 and res.trips == 0 and res.releases_while_moving == 0
    assert res.min_truth_to_safe_front >= 0.0 and res.max_safe_front_overshoot <= 0.0
    assert res.attacked == {"state_ahead": 1, "standstill_report": 1, "far_group": 1, "unknown_flood": 4000}
    assert res.refused["localization/state/future"] == 1 and res.refused["localization/etcs/motion"] == 1
    assert res.events["reference_rejected"] == 1 and "BG003" not in [e.nid_bg for e in res.supervisor.events
                                                                        if e.kind == EventKind.LRBG]
    assert 0 < res.refused["shed/sensors/eurobalise/position"] < 4000
    clean, attacked = res.stator["clean"], res.stator["attacked"]
    assert attacked["switched_off_under_vehicle"] == clean["switched_off_under_vehicle"] == 0
    assert attacked["thrust_loss_s"] == clean["thrust_loss_s"] and sum(attacked["refused"].values()) == 2000

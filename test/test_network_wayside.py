"""Wayside equipment on a network (core/network/wayside.py) and the association of its fixes
with the trains' track hypotheses (core/association.py); docs/network.md."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from train_localization.core.association import AMBIGUOUS, UNEXPLAINED, USED, Associator, FusedState
from train_localization.core.measurements import PositionFix, SectionOccupancy
from train_localization.core.network import Network, NetworkError, route_path
from train_localization.core.network.hypotheses import TrackHypothesisState
from train_localization.core.network.config import network_fusion_config
from train_localization.core.network.wayside import (NetworkTrackCircuits, Placement, SectionSimulators, network_areas,
                                                     network_decoder, section_params)
from train_localization.core.offline import replay_line, simulate_line
from train_localization.core.paths import resolve
from train_localization.core.report import line_report
from train_localization.core.scenario import LineTruth, Scenario, TruthState, Vehicle
from train_localization.core.sensors import spec
from train_localization.core.sensors.base import OFF_RAILS, sensor_params
from train_localization.core.signals import InputRejected

SCENARIO = "config/scenario_throat_wayside.yaml"
AXLES = (2.5, 5.0, 27.5, 30.0, 90.0, 92.5, 115.0, 117.5)


@pytest.fixture(scope="module")
def throat():
    return Network.from_yaml(resolve("config/track_throat.yaml"))


# ---- equipment on sections -------------------------------------------------------------------

def test_a_route_places_a_trains_axles_on_a_section_only_where_it_runs_along_it(throat):
    forward = route_path(throat, ["T1", "T3", "T5"])
    on_t3 = Placement.of(forward, "T3")
    x = np.array([999.0, 1010.0, 1058.0, 1070.0])   # route-line chainage: T1 ends at 1000 m
    assert np.allclose(on_t3(x), [OFF_RAILS, 10.0, 58.0, OFF_RAILS], atol=0.6)
    assert Placement.of(forward, "T6") is None
    backward = route_path(throat, ["T5", "T3", "T1"], first_direction=-1)
    on_t1 = Placement.of(backward, "T1")
    start = backward.steps[2].start - backward.begin
    assert on_t1(np.array([start + 10.0]))[0] == pytest.approx(990.0)   # against T1's chainage


def test_a_devices_parameters_are_narrowed_to_each_sections_own_equipment(throat):
    ac = spec("axle_counter")
    per = section_params(ac, {"heads": "AC1,AC5,AC6", "faults": "AC5@10:missed;AC1@3:extra"}, throat)
    assert list(per) == ["T1", "T5"]
    assert per["T5"]["heads"] == "AC5,AC6" and per["T5"]["faults"] == "AC5@10:missed"
    assert per["T1"]["faults"] == "AC1@3:extra"
    data = yaml.safe_load(open(resolve("config/track_throat.yaml"), encoding="utf-8"))
    data["sections"][1]["equipment"]["axle_counter_head"].append({"id": "AC1", "position": 900.0})
    with pytest.raises(NetworkError, match="'AC1' is on sections T1 and T2") as err:
        section_params(ac, {}, Network.from_dict(data))
    assert "\n" not in str(err.value)
    data["sections"][1]["equipment"]["axle_counter_head"] = [{"id": f"M{k}", "position": 200.0 + 30.0 * k}
                                                             for k in range(24)]
    many = Network.from_dict(data)                # 10 - 2 + 24 = 32 heads: 64 channels, one block's most
    assert len(section_params(ac, {}, many)) == 6
    data["sections"][1]["equipment"]["axle_counter_head"].append({"id": "M24", "position": 1000.0})
    with pytest.raises(NetworkError, match="33 axle_counter_head give 66 raw channels.*at most 32 with 'heads'"):
        section_params(ac, {}, Network.from_dict(data))
    assert len(section_params(ac, {"heads": "M1,M2"}, Network.from_dict(data))) == 1


def _device(throat, routes):
    ac = spec("axle_counter")
    params = sensor_params(ac, {"front_first": True}, Vehicle(axles=AXLES))
    fleet = [Vehicle(axles=AXLES) for _ in routes]
    sim = SectionSimulators(ac, params, throat, fleet[0], np.random.default_rng(3), fleet, routes)
    return sim, network_decoder(ac, params, throat), params


def test_the_heads_of_every_section_see_a_train_only_on_its_route(throat):
    north = route_path(throat, ["T1", "T3", "T5", "T6"])
    sim, dec, _ = _device(throat, [north])
    assert dec.expected == sim.channels and len(sim.channels) == 2 * 10
    truth = LineTruth({"north": Vehicle(axles=AXLES)})
    fixes, reports = [], []
    for k in range(0, 9001):          # 12 m/s from route-line chainage 850 m for 90 s
        t = k / 100.0
        truth.add("north", TruthState(t, 850.0 + 12.0 * t, 12.0, 0.0))
        for block in sim.simulate(truth):
            for m in dec.decode(block):
                (fixes if isinstance(m, PositionFix) else reports).append(m)
    passed = [(f.track_id, f.reference_id) for f in fixes]
    # T1's head, T5's two and T6's first: never track A's (T2) or track C's (T7); each into an
    # empty area (AC5 into T5's, AC6 into the area of switch W3)
    assert passed == [("T1", "AC1"), ("T5", "AC5"), ("T5", "AC6"), ("T6", "AC7")]
    for f in fixes:
        step = north.step_on(f.track_id)
        t_front = (step.distance(f.position) - north.begin - 850.0) / 12.0
        assert abs(t_front - f.stamp) * 12.0 < 5 * f.position_stddev + 0.05, f
    # one report lists every area of the device: those of switches W1 + W2 (the crossover) and
    # W3 bounded by the heads on their legs
    last = {s.section_id: s.state for s in reports[-1].sections}
    assert set(last) == {"AC1-AC2-AC4-AC5", "AC2-AC3", "AC5-AC6", "AC6-AC7-AC9", "AC7-AC8", "AC9-AC10"}
    assert [k for k, v in last.items() if v != 0] == ["AC7-AC8"]       # where the train is at the end
    assert {(type(r).__name__, r.source) for r in reports} == {("SectionOccupancy", "axle_counter")}


def test_a_block_one_sections_columns_refuse_changes_no_sections_decoder(throat):
    north = route_path(throat, ["T1", "T2"])
    sim, dec, _ = _device(throat, [north])
    truth = LineTruth({"north": Vehicle(axles=AXLES)})
    truth.add("north", TruthState(0.0, 0.0, 0.0, 0.0))
    truth.add("north", TruthState(0.2, 0.0, 0.0, 0.0))
    block = sim.simulate(truth)[0]
    bad = block.data.copy()
    bad[:, -1] = 5.0                        # T7's last head: implausible damping
    from dataclasses import replace
    with pytest.raises(InputRejected) as err:
        dec.decode(replace(block, data=bad))
    assert err.value.reason == "implausible" and dec._last_report is None and not dec.count.any()
    with pytest.raises(InputRejected) as err:
        dec.decode(replace(block, channels=block.channels[:-1] + ("AC99.b",)))
    assert err.value.reason == "unknown_id"
    assert len(dec.decode(block)) == 1                         # the first report, of every area
    # track circuits over the network: one decoder, every circuit's checks first
    data = yaml.safe_load(open(resolve("config/track_throat.yaml"), encoding="utf-8"))
    for sec in data["sections"]:
        if sec["id"] in ("T2", "T6"):
            sec["equipment"]["track_circuit"] = [{"id": f"{sec['id']}a", "start": 10.0, "end": 200.0,
                                                  "system": "TI21"}]
    net = Network.from_dict(data)
    tc = spec("track_circuit_receiver")
    params = sensor_params(tc, {"front_first": True}, Vehicle(axles=AXLES))
    sim = SectionSimulators(tc, params, net, Vehicle(axles=AXLES), np.random.default_rng(1), [Vehicle(axles=AXLES)],
                            [north])
    dec = network_decoder(tc, params, net)
    assert isinstance(dec, NetworkTrackCircuits)
    block = sim.simulate(truth)[0]
    bad = block.data.copy()
    bad[:, -1] = 50.0                       # T6's receiver: beyond its range
    with pytest.raises(InputRejected) as err:
        dec.decode(replace(block, data=bad))
    assert err.value.reason == "implausible" and dec._last_report is None
    assert len(dec.decode(block)) == 1


# ---- association with track hypotheses ---------------------------------------------------------

def _state(stamp, hyps, speed_stddev=0.1):
    return FusedState(stamp, hyps[0].position, min(h.position_min for h in hyps),
                      max(h.position_max for h in hyps), hyps[0].speed, speed_stddev, 2, tuple(hyps))


def _hyp(track, position, half, speed, path):
    return TrackHypothesisState(track, position, speed, position - half, position + half, 0.5, tuple(path), 2)


def test_a_fix_goes_to_the_train_one_of_whose_hypotheses_explains_it_on_its_section(throat):
    # "a" may be on the crossover or on track A past W1; "b" runs on track B ahead of W2
    a = [_state(t, [_hyp("T3", 20.0 + 10 * t, 5.0, 10.0, ["T3"]), _hyp("T2", 20.0 + 10 * t, 5.0, 10.0, ["T2"])])
         for t in (1.0, 1.1)]
    b = [_state(t, [_hyp("T4", 700.0 + 10 * t, 3.0, 10.0, ["T4"])]) for t in (1.0, 1.1)]
    assoc = Associator({"a": a, "b": b}, {"a": "throat:a", "b": "throat:b"}, network=throat)
    fix = lambda track, pos, direction=1: PositionFix(1.05, "axle_counter", "ac", track, "X", pos, 0.05, direction)
    assert assoc.associate(fix("T2", 30.0)) == "a"          # a's second hypothesis
    assert assoc.associate(fix("T3", 31.0)) == "a"          # its first
    assert assoc.associate(fix("T4", 710.0)) == "b"
    assert assoc.associate(fix("T6", 30.0)) is None         # a section no hypothesis reaches
    assert assoc.associate(fix("T2", 30.0, -1)) is None     # the other direction
    # the crossover's far end is 58.5 m; a's interval on T3 ends at 35.5 m: T5 lies beyond it
    assert assoc.associate(fix("T5", 10.0)) is None
    # b's interval reaches T4's end (T5 follows through W2): a fix on T5 just past it is b's
    b_near = [_state(t, [_hyp("T4", 795.0 + 10 * t, 8.0, 10.0, ["T4"])]) for t in (1.0, 1.1)]
    assoc2 = Associator({"a": a, "b": b_near}, {}, network=throat)
    assert assoc2.associate(PositionFix(1.05, "axle_counter", "ac", "T5", "X", 2.0, 0.05, 1)) == "b"
    # a hypothesis of each train covering the same place: ambiguous, used by neither
    both = [_state(t, [_hyp("T2", 20.0 + 10 * t, 5.0, 10.0, ["T2"])]) for t in (1.0, 1.1)]
    assoc3 = Associator({"a": a, "c": both}, {}, network=throat)
    assert assoc3.associate(fix("T2", 30.0)) is None
    assert assoc3.counts == {AMBIGUOUS: 1}
    assert assoc.counts == {USED: 3, UNEXPLAINED: 3}
    # a hypothesis naming sections the network does not have, or a path without its own
    # section (a malformed message): it explains nothing, and nothing raises
    odd = [_state(t, [_hyp("T2", 30.0, 5.0, 10.0, ["T9"]), _hyp("T2", 30.0, 5.0, 10.0, ["T6"])]) for t in (1.0, 1.1)]
    assert Associator({"odd": odd}, {}, network=throat).associate(fix("T2", 30.0)) is None
    from train_localization.core.network import TrackPath
    assert TrackPath.through(throat, ("T1", "T9")) is None and TrackPath.through(throat, ("T1", "T6")) is None


# ---- the scenario, offline and replayed --------------------------------------------------------

@pytest.fixture(scope="module")
def wayside_run(tmp_path_factory):
    bag = tmp_path_factory.mktemp("wayside") / "throat_wayside.mcap"
    sc = Scenario.from_yaml(SCENARIO)
    return sc, simulate_line(sc, bag=bag, fusion_rate=50.0), bag


def test_every_head_fix_reaches_the_train_that_passed_it(wayside_run):
    sc, res, _ = wayside_run
    report = line_report(res)
    a = report["association"]
    assert a["offered"] == a["used"] == 8 and a["wrong_train"] == 0
    assert a["delivered"] == {"north": 4, "south": 4}     # AC5 and AC6 of T5 for both trains
    assert a["error_over_sigma_max"] < 3.0
    for name, train in report["trains"].items():
        net = train["network"]
        assert net["nominal_wrong_track"] == 0 and net["inside"] == 1.0, name
        assert net["true_hypothesis_outside"] == 0, name
    assert report["trains"]["north"]["network"]["switch_ways_resolved"] == 2
    counters = res.trains["south"].runner.counters()
    assert counters["switches_contradicted"] == {"W3": "reported B1, found B2"}


def test_a_head_beyond_a_switch_finds_the_way_sooner_than_the_balises(wayside_run):
    sc, res, _ = wayside_run
    with open(resolve(SCENARIO), encoding="utf-8") as fh:
        data = yaml.safe_load(fh)
    data.pop("wayside")
    data["track"] = resolve(data["track"])
    # the south train alone: without wayside fixes the trains do not meet (the same states as
    # with the north train beside it, each train drawing from streams of its own)
    data["trains"] = [train for train in data["trains"] if train["name"] == "south"]
    alone = simulate_line(Scenario.from_dict(data), fusion_rate=50.0)
    wrong = lambda run: sum(1 for e in run.estimates if e.track_id == "T6")
    with_heads, without = wrong(res.trains["south"]), wrong(alone.trains["south"])
    # the reported (wrong) way leads until evidence excludes it: the head AC9 45 m past W3
    # excludes it about 100 m before the balise group BG7 at 140 m does
    assert 0 < with_heads and with_heads + 250 < without
    assert all(e.mode == 2 for e in res.trains["south"].estimates if e.track_id == "T6")


def test_the_recorded_bag_replays_to_the_same_associations(wayside_run):
    sc, res, bag = wayside_run
    again = replay_line(bag, fusion_rate=50.0)
    decisions = lambda r: [(d.fix.reference_id, d.fix.stamp, d.train) for d in r.associator.decisions]
    assert decisions(again) == decisions(res)
    for name in res.trains:
        assert [e.position for e in again.trains[name].estimates] == [e.position for e in res.trains[name].estimates]


def _circuits_over_w3():
    """The throat with TI21 circuits up to W3 on track B (T5a, T5b) and from it on T6 and T7."""
    data = yaml.safe_load(open(resolve("config/track_throat.yaml"), encoding="utf-8"))
    t5 = next(sec for sec in data["sections"] if sec["id"] == "T5")["length"]
    circuits = {"T5": [("T5a", 20.0, 141.0), ("T5b", 141.0, t5)], "T6": [("T6a", 0.0, 200.0), ("T6b", 200.0, 400.0)],
                "T7": [("T7a", 0.0, 200.0)]}
    for sec in data["sections"]:
        if sec["id"] in circuits:
            sec["equipment"]["track_circuit"] = [{"id": cid, "start": a, "end": b, "system": "TI21"}
                                                 for cid, a, b in circuits[sec["id"]]]
    return data


def _circuit_fixes(net, sections, start, speed, seconds, direction=1):
    """Fixes and circuits seen occupied of one train at ``speed`` along ``sections`` from route-line
    chainage ``start``; and its route."""
    tc = spec("track_circuit_receiver")
    params = sensor_params(tc, {"front_first": True}, Vehicle(axles=AXLES))
    route = route_path(net, sections, direction)
    sim = SectionSimulators(tc, params, net, Vehicle(axles=AXLES), np.random.default_rng(1), [Vehicle(axles=AXLES)],
                            [route])
    dec = network_decoder(tc, params, net)
    truth = LineTruth({"train": Vehicle(axles=AXLES)})
    fixes, occupied = [], set()
    for k in range(0, int(seconds * 50) + 1):
        t = k / 50.0
        truth.add("train", TruthState(t, start + speed * t, speed, 0.0))
        for block in sim.simulate(truth):
            for m in dec.decode(block):
                if isinstance(m, SectionOccupancy):
                    occupied |= {s.section_id for s in m.sections if s.state != 0}
                else:
                    fixes.append(m)
    return fixes, occupied, route


def test_track_circuits_hand_over_across_a_switch_and_fix_the_way_taken():
    """A hand-over into a circuit of another section, across the node (an insulated joint), gives
    a fix on the entered circuit's section at the joint: at W3 T5b hands over to T6a for the
    train that goes straight and to T7a for the one that turns out; the fusion's references know
    both joints, each way, on the entered section."""
    net = Network.from_dict(_circuits_over_w3())
    north_fixes, north_seen, north = _circuit_fixes(net, ["T1", "T3", "T5", "T6"], 1050.0, 12.0, 55.0)
    assert [(f.track_id, f.reference_id, f.direction) for f in north_fixes] == [
        ("T5", "T5a/T5b", 1), ("T6", "T5b/T6a", 1), ("T6", "T6a/T6b", 1)]
    for f in north_fixes:
        step = north.step_on(f.track_id)
        t_front = (step.distance(f.position) - north.begin - 1050.0) / 12.0
        assert abs(t_front - f.stamp) * 12.0 < 3.3 * f.position_stddev
    assert north_fixes[1].position == pytest.approx(AXLES[0])          # at the joint, the first axle past it
    assert "T7a" not in north_seen
    south_fixes, south_seen, _ = _circuit_fixes(net, ["T4", "T5", "T7"], 750.0, 12.0, 45.0)
    assert [(f.track_id, f.reference_id) for f in south_fixes] == [("T5", "T5a/T5b"), ("T7", "T5b/T7a")]
    assert {"T6a", "T6b"}.isdisjoint(south_seen)
    back_fixes, _, _ = _circuit_fixes(net, ["T6", "T5", "T4"], 590.0, 12.0, 55.0, -1)   # from T6's 410 m, backwards
    assert [(f.track_id, f.reference_id, f.direction) for f in back_fixes] == [
        ("T6", "T6a/T6b", -1), ("T5", "T6a/T5b", -1), ("T5", "T5a/T5b", -1)]
    assert back_fixes[1].position == pytest.approx(net.section("T5").length - AXLES[0])
    data = yaml.safe_load(open(resolve(SCENARIO), encoding="utf-8"))
    data["track"] = _circuits_over_w3()
    data["wayside"]["sensors"] = {"track_circuit_receiver": {"front_first": True}}
    cfg, _ = network_fusion_config(Scenario.from_dict(data).trains["north"])
    windows = cfg.models["track_circuit"].references.windows
    assert windows["T5b/T6a"].lo == windows["T5b/T6a"].hi == pytest.approx(AXLES[0])
    assert windows["T6a/T5b"].lo == pytest.approx(net.section("T5").length - AXLES[0])
    assert {"T5b/T7a", "T7a/T5b", "T5a/T5b", "T6a/T6b"} <= set(windows)


# ---- randomised runs (core/network/line_campaign.py) ----------------------------------------

def test_drawn_runs_place_heads_past_every_clearance_point_and_trains_behind_each_other():
    from train_localization.core.network.line_campaign import HEAD_BEYOND, generate
    for seed in range(6):
        data = generate(seed)
        assert data == generate(seed)                     # from its seed alone
        net = Network.from_dict(data["track"])
        heads = {h["id"]: (sid, h["position"]) for sid, sec in net.sections.items()
                 for h in sec.items("axle_counter_head")}
        assert len(heads) == data["campaign"]["conditions"]["heads"] >= 3
        for node in net.switches():
            for port in ("B1", "B2"):
                end = node.ports[port]
                length = net.section(end.section).length
                want = node.clearance + HEAD_BEYOND
                if want + 1.0 < length:
                    at = want if end.end == "begin" else length - want
                    assert any(s == end.section and abs(x - at) < 1e-3 for s, x in heads.values()), (seed, node)
        sc = Scenario.from_dict(data)
        fronts = [tr.start_position for tr in sc.trains.values()]
        lengths = [tr.vehicle.length for tr in sc.trains.values()]
        for k in range(1, len(fronts)):                   # each behind the one ahead, not overlapping
            assert fronts[k] < fronts[k - 1] - lengths[k - 1]


# ---- the association node on a network (live) ---------------------------------------------------

def test_the_association_node_routes_a_head_fix_by_the_trains_track_hypotheses(ros_context, tmp_path):
    """The node pairs each train's TrainState with its TrackHypotheses of the same stamp (in
    either order) and sends a fix to the train one of whose hypotheses explains it on the fix's
    section; a TrackHypotheses message naming a section the network lacks is refused and counted."""
    import os
    import subprocess
    import sys
    from conftest import spin_until
    from diagnostic_msgs.msg import DiagnosticArray
    from train_localization.core import convert
    from train_localization.core.fusion import MODE_NOMINAL
    from train_localization.nodes.common import STREAM_QOS, rclpy_classes
    log = open(tmp_path / "association.log", "w")
    assoc = subprocess.Popen([sys.executable, "-c", "from train_localization.nodes.association import main; main()",
                              "--ros-args", "-r", "__ns:=/wayside", "-p", f"scenario:={resolve(SCENARIO)}"],
                             stdout=log, stderr=subprocess.STDOUT, start_new_session=True, env=dict(os.environ))
    mc = rclpy_classes()
    node = ros_context.create_node("network_association_probe")
    routed: dict[str, list] = {"north": [], "south": []}
    status: dict[str, str] = {}
    try:
        states = {n: node.create_publisher(mc.TrainState, f"/{n}/localization/state", STREAM_QOS) for n in routed}
        tracks = {n: node.create_publisher(mc.TrackHypotheses, f"/{n}/localization/tracks", STREAM_QOS)
                  for n in routed}
        fixes = node.create_publisher(mc.PositionFix, "/wayside/sensors/axle_counter/position", STREAM_QOS)
        for name in routed:
            node.create_subscription(mc.PositionFix, f"/{name}/sensors/axle_counter/position",
                                     lambda msg, name=name: routed[name].append(msg.reference_id), STREAM_QOS)
        node.create_subscription(DiagnosticArray, "/diagnostics", lambda msg: status.update(
            {kv.key: kv.value for st in msg.status if "association" in st.name for kv in st.values}), 10)
        ready = [*(lambda p=p: p.get_subscription_count() >= 1 for p in [*states.values(), *tracks.values(), fixes]),
                 *(lambda n=n: node.count_publishers(f"/{n}/sensors/axle_counter/position") >= 1 for n in routed)]
        assert spin_until(node, lambda: all(f() for f in ready), timeout=60.0), \
            (tmp_path / "association.log").read_text()
        # north: on the crossover T3 or on track A past W1; south: on track B (T5) near W3
        where = {"north": [_hyp("T3", 20.0, 4.0, 12.0, ["T3"]), _hyp("T2", 20.0, 4.0, 12.0, ["T2"])],
                 "south": [_hyp("T5", 300.0, 4.0, 15.0, ["T5"])]}
        for k in range(5):
            t = 10.0 + 0.1 * k
            for name, hyps in where.items():
                moved = [TrackHypothesisState(h.track_id, h.position + h.speed * (t - 10.0), h.speed,
                                              h.position_min + h.speed * (t - 10.0),
                                              h.position_max + h.speed * (t - 10.0), h.probability, h.path, 2)
                         for h in hyps]
                est = type("E", (), {"stamp": t, "hypotheses": moved})
                state = convert.train_state_to_msg(mc, t, moved[0].track_id, moved[0].position, moved[0].speed, 0.0,
                                                   1.0, 0.1, moved[0].position_min, moved[0].position_max, 0.999,
                                                   MODE_NOMINAL, [])
                if k % 2:   # either order
                    tracks[name].publish(convert.track_hypotheses_to_msg(mc, est, "throat"))
                    states[name].publish(state)
                else:
                    states[name].publish(state)
                    tracks[name].publish(convert.track_hypotheses_to_msg(mc, est, "throat"))
        bad = type("E", (), {"stamp": 10.45, "hypotheses": [_hyp("T99", 1.0, 1.0, 1.0, ["T99"])]})
        tracks["south"].publish(convert.track_hypotheses_to_msg(mc, bad, "throat"))
        spin_until(node, lambda: False, timeout=0.5)
        sent = [PositionFix(10.2, "axle_counter", "axle_counter", "T2", "AC2", 22.4, 0.05, 1),    # north's T2
                PositionFix(10.2, "axle_counter", "axle_counter", "T5", "AC6", 303.0, 0.05, 1),   # south
                PositionFix(10.2, "axle_counter", "axle_counter", "T6", "AC7", 22.0, 0.05, 1)]    # nobody's
        for f in sent:
            fixes.publish(convert.measurement_to_msg(f, mc))
        done = spin_until(node, lambda: routed["north"] and routed["south"]
                          and status.get("associated/unexplained") == "1"
                          and "unknown_id" in str(status), timeout=30.0)
        assert done, (routed, status, (tmp_path / "association.log").read_text()[-2000:])
        assert routed == {"north": ["AC2"], "south": ["AC6"]}
    finally:
        node.destroy_node()
        assoc.terminate()
        assoc.wait(timeout=10)
        log.close()


def test_a_track_circuit_hand_over_across_a_switch_resolves_the_way_at_its_point():
    """South alone through W3 (reported B1, lies B2) with track circuits as its only wayside
    equipment: the hand-over T5b/T7a across W3 is admitted by its fusion (a reference of the
    network's joints), delivered to south, and names the way at the switch point, so the way is
    resolved within the clearance where the axle-counter head 45 m beyond could not."""
    data = yaml.safe_load(open(resolve(SCENARIO), encoding="utf-8"))
    data["track"] = _circuits_over_w3()
    data["wayside"] = {"sensors": {"track_circuit_receiver": {"front_first": True}}}
    data["trains"] = [train for train in data["trains"] if train["name"] == "south"]
    data["trains"][0]["initial"] = {"position": 650.0, "speed": 0.0}
    data["trains"][0]["profile"] = [{"speed": 22.0, "accel": 1.2, "jerk": 1.0, "hold": 60.0}]
    data["duration"] = 38.0
    res = simulate_line(Scenario.from_dict(data), fusion_rate=50.0)
    report = line_report(res)
    decisions = [(d.fix.reference_id, d.train) for d in res.associator.decisions]
    assert decisions == [("T5a/T5b", "south"), ("T5b/T7a", "south")]
    south = res.trains["south"].runner.counters()
    assert not {"reference_mismatch", "unknown_reference", "wrong_track"} & set(south["rejected"]), south["rejected"]
    assert south["switches_contradicted"] == {"W3": "reported B1, found B2"}
    net = report["trains"]["south"]["network"]
    assert net["nominal_wrong_track"] == 0 and net["inside"] == 1.0 and net["true_hypothesis_outside"] == 0
    assert net["switch_ways_resolved"] == net["switch_ways"] == 1

"""ETCS on a network (docs/network.md, "ETCS on a network"): the data (core/etcs/network_data.py,
balise groups located on sections, linking that follows the routes), the followed path
(core/network/followed.py), the location function on it (core/etcs/network_location.py), the
supervision to an end of authority on a section, and the offline run through the throat."""
from __future__ import annotations

import math

import pytest
import yaml

from train_localization.core.etcs.network_data import NetworkEtcsData
from train_localization.core.campaign import run_scenario
from train_localization.core.etcs.location import FusedState
from train_localization.core.etcs.network_location import NetworkLocationTracker, path_data
from train_localization.core.etcs.records import EventKind
from train_localization.core.etcs.supervision import Brake, Status, Supervision
from train_localization.core.measurements import PositionFix
from train_localization.core.network import Network, route_path
from train_localization.core.network.followed import ahead, follow
from train_localization.core.network.path import TrackPath
from train_localization.core.paths import resolve
from train_localization.core.track import TrackError


def _throat(etcs: dict | None = None, change=None) -> Network:
    data = yaml.safe_load(open(resolve("config/track_throat.yaml"), encoding="utf-8"))
    data["etcs"] = {"q_nvlocacc": 12.0, "linking": "auto"} if etcs is None else etcs
    if change:
        change(data)
    return Network.from_dict(data)


def test_groups_are_located_on_their_sections_and_link_to_the_next_group_on_every_path():
    net = _throat()
    data = NetworkEtcsData.from_network(net)
    assert (data.groups["BG5a"].section, data.groups["BG5a"].group.reference) == ("T5", 120.0)
    assert data.group_of_balise["BG7b"] == "BG7b" and data.q_nvlocacc == 12.0
    assert [(k.to_bg, k.distance, k.path) for k in data.links_after("BG1a", 1)] == [("BG1b", 3.0, ("T1",))]
    t3 = net.section("T3").length
    # after BG1b towards W1: the next group on each way, at its distance along that way
    ahead = data.links_after("BG1b", 1)
    assert [(k.to_bg, k.path, k.ways) for k in ahead] == [
        ("BG2a", ("T1", "T2"), (("W1", "B1"),)), ("BG5a", ("T1", "T3", "T5"), (("W1", "B2"),))]
    assert [k.distance for k in ahead] == [pytest.approx(397.0 + 120.0), pytest.approx(397.0 + t3 + 120.0)]
    # backwards from BG5a through W2, a facing switch for a train running against T5's chainage
    back = data.links_after("BG5a", -1)
    assert [(k.to_bg, k.path, k.ways) for k in back] == [
        ("BG1b", ("T5", "T3", "T1"), (("W2", "B2"),)), ("BG4b", ("T5", "T4"), (("W2", "B1"),))]
    assert [k.distance for k in back] == [pytest.approx(120.0 + t3 + 397.0), pytest.approx(120.0 + 497.0)]
    # the link a train expects is the one on its route (or its most probable hypothesis's path)
    assert data.link_on("BG1b", 1, ["T1", "T3", "T5", "T6"]).to_bg == "BG5a"
    assert data.link_on("BG1b", 1, ["T1", "T2"]).to_bg == "BG2a"
    assert data.links_after("BG3b", 1) == ()            # T2 ends the network: nothing beyond
    assert NetworkEtcsData.from_network(net, reach=550.0).links_after("BG1b", 1)[0].to_bg == "BG2a"
    assert len(NetworkEtcsData.from_network(net, reach=550.0).links_after("BG1b", 1)) == 1


def _dup(data):
    data["sections"][1]["equipment"]["eurobalise"].append({"id": "BGx", "position": 300.0, "group": "BG1a"})


@pytest.mark.parametrize("etcs, change, message", [
    ({"linking": "auto"}, None, "no q_locacc and track T1 no national value"),
    ({"q_nvlocacc": 12.0, "linking": [{"from": "BG1a", "to": "BG1b", "distance": 3.0}]}, None,
     "must be 'auto' on a network"),
    ({"q_nvlocacc": 12.0, "linkage": "auto"}, None, "unknown keys in 'etcs': linkage"),
    ({"q_nvlocacc": 12.0}, _dup, "BG1a is on sections T1 and T2"),
])
def test_inconsistent_network_etcs_data_is_refused_in_one_line(etcs, change, message):
    with pytest.raises(TrackError, match=message) as err:
        NetworkEtcsData.from_network(_throat(etcs, change))
    assert "\n" not in str(err.value)


# ---- the followed path and its ETCS data ------------------------------------------------------

def _grouped(data):
    """The throat's balises in groups of two (BG1a + BG1b = group BG1, ...)."""
    for section in data["sections"]:
        for balise in section.get("equipment", {}).get("eurobalise", []):
            balise["group"] = balise["id"][:-1]


def test_the_followed_path_keeps_the_common_part_and_turns_onto_the_way_the_state_names():
    net = _throat()
    t3 = net.section("T3").length
    start = TrackPath.start(net, "T1", 1)
    on_t2 = follow(start, net, "T2", 10.0, 1010.0, 1)
    assert [st.section for st in on_t2.steps] == ["T1", "T2"] and follow(on_t2, net, "T2", 11.0, 1011.0, 1) is on_t2
    # the most probable hypothesis turns onto the crossover: cut back to T1 and regrown, same path distances
    on_t5 = follow(on_t2, net, "T5", 20.0, 1000.0 + t3 + 20.0, 1)
    assert [st.section for st in on_t5.steps] == ["T1", "T3", "T5"] and on_t5.steps[0] == on_t2.steps[0]
    # a place no continuation holds: a path of its section alone, its origin placed to hold it
    alone = follow(on_t5, net, "T6", 100.0, 5.0, 1)
    assert [(st.section, st.start) for st in alone.steps] == [("T6", -95.0)]
    # ahead: along the reported ways (W2 is trailing), up to a switch whose way is unknown, or reach
    sections = lambda switches, reach=5000.0: [st.section for st in ahead(start, 450.0, switches, reach).steps]
    assert sections({"W1": "B2", "W3": "B1"}) == ["T1", "T3", "T5", "T6"]
    assert sections({"W1": "B2", "W3": "B2"}) == ["T1", "T3", "T5", "T7"]
    assert sections({"W1": "B2"}) == sections({"W1": "B2", "W3": ""}) == ["T1", "T3", "T5"]
    assert sections({"W1": "B2", "W3": "B1"}, reach=600.0) == ["T1", "T3"]   # T3 ends 608.5 m past the front
    # cut after the front's section, then regrown: a changed report turns the path ahead
    assert [st.section for st in ahead(ahead(start, 450.0, {"W1": "B1"}, 5000.0), 450.0, {"W1": "B2"},
                                       600.0).steps] == ["T1", "T3"]


def test_the_etcs_data_of_a_path_place_its_groups_at_path_distances_and_link_along_it():
    net = _throat(change=_grouped)
    data = NetworkEtcsData.from_network(net)
    t3 = net.section("T3").length
    straight = path_data(data, route_path(net, ["T1", "T2"]))
    assert sorted(straight.groups) == ["BG1", "BG2", "BG3"] and straight.track_id == "throat"
    assert straight.groups["BG2"].reference == 1120.0 and straight.groups["BG2"].balises == ("BG2a", "BG2b")
    assert (straight.link_after("BG1", 1).to_bg, straight.link_after("BG1", 1).distance) == ("BG2", 520.0)
    assert straight.link_after("BG2", -1).to_bg == "BG1" and straight.link_after("BG3", 1) is None
    crossing = path_data(data, route_path(net, ["T1", "T3", "T5"]))
    assert crossing.link_after("BG1", 1).to_bg == "BG5"
    assert crossing.groups["BG5"].reference == pytest.approx(1000.0 + t3 + 120.0)
    # run against the chainage (T7 backwards into T5 and T4): the groups face against the path
    back = path_data(data, route_path(net, ["T7", "T5", "T4"], -1))
    assert back.groups["BG7"].orientation == -1 and back.groups["BG7"].balises == ("BG7b", "BG7a")
    assert back.groups["BG7"].reference == pytest.approx(net.section("T7").length - 140.0)
    assert back.link_after("BG7", 1).to_bg == "BG5" and back.link_after("BG5", 1).to_bg == "BG4"
    # a link whose path leaves the followed one (BG1 on to BG5 over the crossover) is none of the path's
    assert path_data(data, route_path(net, ["T1"])).link_after("BG1", 1) is None


# ---- the location function on the followed path ------------------------------------------------

SPEED, HALF = 15.0, 2.0   # [m/s] of the train, [m] half the fused interval


def _drive(route: list[str], start: float, switches: dict, turn_at: float | None, until: float):
    """A train along ``route`` of the grouped throat from chainage ``start`` on its first section at
    SPEED, its fused state at 10 Hz: on the interlocking's reported way until the front is ``turn_at``
    metres past W3 (None: never), on the true route after; every balise of the route read as the
    front passes it (the second of a group gives the direction). (tracker, reports, events)."""
    net = _throat(change=_grouped)
    truth = route_path(net, route)
    reported = route_path(net, ["T5", "T6"])
    w3 = truth.steps[0].stop
    tracker = NetworkLocationTracker(NetworkEtcsData.from_network(net), net, TrackPath.start(net, route[0], 1),
                                     {"orientation": 1}, switches)
    fixes = sorted((truth.distance(sid, b["position"]), b["id"], sid, b["position"])
                   for sid in route for b in net.section(sid).equipment.get("eurobalise", ()))
    reports, events = [], []
    for k in range(int(until * 10.0) + 1):
        t = k / 10.0
        s = start + SPEED * t
        while fixes and fixes[0][0] <= s:
            s_b, bid, sid, chainage = fixes.pop(0)
            tracker.on_fix(PositionFix((s_b - start) / SPEED, "eurobalise", "r", sid, bid, chainage, 0.3,
                                       1 if bid.endswith("b") else 0))
        on = truth if turn_at is not None and s >= w3 + turn_at or s < w3 else reported
        step = on.step_at(s)
        c = step.chainage(s)
        mode = 2 if abs(s - w3) < 60.0 else 1     # both ways plausible around the switch
        report, new = tracker.on_state(FusedState(t, c, c - HALF, c + HALF, SPEED, 0.05, 0.999, mode, step.section,
                                                  s, s - HALF, s + HALF, step.direction))
        reports.append(report)
        events += new
    return tracker, reports, events


def _kinds(events, kind):
    return [e.nid_bg for e in events if e.kind == kind]


def test_a_group_expected_on_the_reported_way_is_not_missed_when_the_train_takes_the_other():
    # W3 reported B1 (track B on, BG6 expected), the train turns to T7; the fusion names T7 24 m past the point
    tracker, reports, events = _drive(["T5", "T7"], 50.0, {"W3": "B1"}, 24.0, 35.0)
    assert _kinds(events, EventKind.LRBG) == ["BG5", "BG7"]
    assert [e.detail for e in events if e.kind == EventKind.LRBG][1] == "linked group BG7 is the LRBG"
    assert _kinds(events, EventKind.MISSED_LINKED_GROUP) == [] and tracker.stats["off_network_path"] == 0
    before = next(r for r in reports if r.t == 10.0)          # front 200 m along T5, BG5 the LRBG
    assert before.lrbg_track_id == "T5" and [p.section for p in before.path] == ["T5", "T6"]
    assert before.d_lrbg == pytest.approx(200.0 - 120.0) and before.track_id == "throat"
    last = reports[-1]                                         # front 575 m on: 233.3 m along T7
    assert last.lrbg_track_id == "T7" and last.nid_lrbg == "BG7" and last.previous_lrbgs == ("BG5",)
    assert last.d_lrbg == pytest.approx(50.0 + 35.0 * SPEED - 341.69262482327 - 140.0)
    assert (last.min_safe_front_end, last.max_safe_front_end) == (50.0 + 525.0 - HALF, 50.0 + 525.0 + HALF)
    assert [p.section for p in last.path] == ["T7"] and last.path_distance("T7", 140.0) == pytest.approx(
        341.69262482327 + 140.0)
    assert {r.mode for r in reports if abs(r.estimated_front_end - 341.69) < 60.0} == {2}   # DEGRADED, as the state


def test_a_read_on_a_way_the_path_lacks_waits_for_the_fusion_and_holds_back_the_missed_verdict():
    # the fusion learns the way only from BG7 (no DGPS), 1.5 s after its second balise: BG6's window
    # has closed by then, but BG7a waits for the path and the verdict waits with it
    tracker, _, events = _drive(["T5", "T7"], 50.0, {"W3": "B1"}, 143.0 + 1.5 * SPEED, 35.0)
    assert _kinds(events, EventKind.LRBG) == ["BG5", "BG7"] and _kinds(events, EventKind.MISSED_LINKED_GROUP) == []
    # a fusion that never names T7: both reads refused after path_wait, BG6 then reported missed
    tracker, reports, events = _drive(["T5", "T7"], 50.0, {"W3": "B1"}, None, 35.0)
    assert tracker.stats["off_network_path"] == 2 and _kinds(events, EventKind.LRBG) == ["BG5"]
    assert _kinds(events, EventKind.MISSED_LINKED_GROUP) == ["BG6"]
    assert _kinds(events, EventKind.UNKNOWN_GROUP) == [] and reports[-1].nid_lrbg == "BG5"


def test_an_end_of_authority_on_a_section_is_supervised_on_the_followed_path_and_braked_for_off_it():
    w3 = 341.69262482327                        # path distance of W3 (the end of T5)
    params = {"end_of_authority": 300.0, "end_of_authority_section": "T7", "start_braked": False}
    _, set_right, _ = _drive(["T5", "T7"], 50.0, {"W3": "B2"}, 0.0, 10.0)
    d = Supervision(params).update(set_right[-1])                   # the front 200 m along T5
    assert d.brake == Brake.NONE and d.distance_to_eoa == pytest.approx(w3 + 300.0 - (200.0 + HALF))
    # W3 reported B1: the followed path runs on to T6, which the authority is not on
    sup = Supervision(params)
    _, wrong, _ = _drive(["T5", "T7"], 50.0, {"W3": "B1"}, 24.0, 30.0)
    d = sup.update(wrong[100])
    assert (d.status, d.brake) == (Status.INTERVENTION, Brake.SERVICE) and math.isnan(d.distance_to_eoa)
    assert d.reason == "end of authority 300.00 m on section T7 is not on the followed path (T5, T6): service brake"
    assert sup.stats["intervention_eoa_off_path"] == 1
    # once the fusion names T7 the authority is placed again: 139.7 m ahead at 15 m/s, the emergency brake
    d = sup.update(wrong[-1])                                        # the front 500 m on
    assert d.distance_to_eoa == pytest.approx(w3 + 300.0 - (500.0 + HALF)) and d.brake == Brake.EMERGENCY
    assert d.reason.startswith("EBI: 139.7 m to the end of authority")
    # the min safe front end beyond it: a trip
    sup = Supervision({**params, "end_of_authority": 100.0})
    d = sup.update(wrong[-1])
    assert d.status == Status.TRIP and sup.stats["trip_eoa"] == 1


# ---- offline through the throat ----------------------------------------------------------------

VEHICLE = {"type": "conventional", "length": 120.0, "wheel_diameter": 0.92,
           "axles": [2.5, 5.0, 27.5, 30.0, 90.0, 92.5, 115.0, 117.5]}


def _throat_scenario(reported: dict) -> dict:
    data = yaml.safe_load(open(resolve("config/track_throat.yaml"), encoding="utf-8"))
    data["etcs"] = {"q_nvlocacc": 12.0, "linking": "auto"}
    _grouped(data)
    return {"name": "throat_etcs", "seed": 11, "duration": 36.0, "truth_rate": 100.0, "track": data,
            "vehicle": VEHICLE, "initial": {"position": 20.0, "speed": 15.0},
            "route": {"sections": ["T5", "T7"], "reported": reported},
            "profile": [{"speed": 15.0, "accel": 0.5, "hold": 100.0}],
            "sensors": {"wheel_sensor": {}, "doppler_radar": {}, "eurobalise_reader": {}, "dgps_receiver": {}}}


def test_offline_through_the_throat_the_true_front_lies_within_the_safe_front_ends_over_a_wrongly_reported_switch():
    # track B to track C over W3, which the interlocking reports as B1 (the way to T6 and BG6):
    # wheel, Doppler, Eurobalise reader and DGPS, fused at the campaign's rate, then the location
    # function on the followed path (core/campaign.py run_scenario)
    scenario = _throat_scenario({"W3": "B1"})
    out = run_scenario(scenario)
    etcs, network = out["etcs"], out["network"]
    assert etcs["claimed"] >= 7000 and etcs["inside_share"] >= 0.999
    assert etcs["lrbgs"] == ["BG5", "BG7"] and etcs["missed_groups"] == []
    assert etcs["events"]["not_linked"] == etcs["events"]["outside_window"] == etcs["events"]["unknown_group"] == 0
    assert etcs["tracker"]["off_network_path"] == 0 and etcs["tracker"]["path_changes"] >= 1
    assert network["nominal_wrong_track"] == 0 and network["switch_ways_resolved"] == 1


def test_the_node_follows_the_path_on_a_network_and_refuses_what_is_not_of_it(ros_context, start_node, tmp_path):
    """etcs_location on a network scenario: states with their path fields past BG5 on T5 and its two
    reads give reports on the network with the LRBG's section and the followed path along the
    reported way; a switch report naming no switch of the network and a read on no section of it
    are refused and counted."""
    from diagnostic_msgs.msg import DiagnosticArray
    from train_localization_msgs.msg import EtcsLocation, PositionFix as FixMsg, SwitchPositions, TrainState
    from train_localization.nodes.common import LATCHED_QOS, STREAM_QOS
    from conftest import etcs_location_status, spin_until

    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(_throat_scenario({"W3": "B1"})))
    proc = start_node("etcs_location", "--ros-args", "-r", "__ns:=/train", "-p", f"scenario:={path}")
    node = ros_context.create_node("probe_etcs_network", namespace="/train")
    state_pub = node.create_publisher(TrainState, "localization/state", STREAM_QOS)
    fix_pub = node.create_publisher(FixMsg, "sensors/eurobalise/position", STREAM_QOS)
    switch_pub = node.create_publisher(SwitchPositions, "interlocking/switches", LATCHED_QOS)
    reports, diags = [], []
    node.create_subscription(EtcsLocation, "localization/etcs", reports.append, STREAM_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)

    def stamped(m, t):
        m.header.stamp.sec, m.header.stamp.nanosec = int(t), int(round((t % 1) * 1e9))
        return m

    def own():
        return etcs_location_status(diags)
    try:
        assert spin_until(node, lambda: state_pub.get_subscription_count() > 0 and fix_pub.get_subscription_count() > 0
                          and node.count_publishers("/train/localization/etcs") > 0, 30.0), proc.output()
        switch_pub.publish(SwitchPositions(switch_ids=["W9"], positions=["B1"]))
        spin_until(node, lambda: False, 0.5)
        fix_pub.publish(stamped(FixMsg(sensor="eurobalise", unit_id="eurobalise", track_id="T5", reference_id="BG5a",
                                       position=120.0, position_stddev=0.33), 10.0))
        fix_pub.publish(stamped(FixMsg(sensor="eurobalise", unit_id="eurobalise", track_id="T5", reference_id="BG5b",
                                       position=123.0, position_stddev=0.33, direction=1), 10.2))
        fix_pub.publish(stamped(FixMsg(sensor="eurobalise", unit_id="eurobalise", track_id="elsewhere",
                                       reference_id="BG5a", position=120.0, position_stddev=0.33), 10.3))
        spin_until(node, lambda: False, 0.3)
        for k in range(60):
            t = 9.9 + 0.01 * k
            x = 120.0 + SPEED * (t - 10.0)
            state_pub.publish(stamped(TrainState(track_id="T5", position=x, position_min=x - HALF,
                                                 position_max=x + HALF, speed=SPEED, speed_stddev=0.05,
                                                 confidence=0.999, mode=1, path_position=x, path_min=x - HALF,
                                                 path_max=x + HALF, path_direction=1), t))
        assert spin_until(node, lambda: len(reports) >= 60, 20.0), proc.output()
        last = reports[-1]
        assert (last.track_id, last.nid_lrbg, last.lrbg_track_id) == ("throat", "BG5", "T5")
        assert last.d_lrbg == pytest.approx(SPEED * 0.49) and last.max_safe_front_end == pytest.approx(
            120.0 + SPEED * 0.49 + HALF)
        assert list(last.path) == ["T5", "T6"] and list(last.path_direction) == [1, 1]
        assert list(last.path_origin) == pytest.approx([0.0, 341.69262482327])
        assert spin_until(node, lambda: own().get("rejected/interlocking/switches/unknown_id") == "1"
                          and own().get("rejected/sensors/eurobalise/position/other_track") == "1", 20.0), own()
        assert proc.interrupt() == 0 and "Traceback" not in proc.output()
    finally:
        node.destroy_node()

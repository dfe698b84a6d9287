"""Track networks (core/network, docs/network.md): the model and its one-line errors, routes
and route lines, fixes restated on sections, the DGPS on a network, and the track-selective
fusion on the station throat (config/scenario_throat.yaml) and under injected faults."""
from __future__ import annotations

import copy
import math
from dataclasses import replace

import numpy as np
import pytest
import yaml

from train_localization.core import convert
from train_localization.core.bagio import typestore_classes
from train_localization.core.measurements import PositionFix
from train_localization.core.network import Network, NetworkError, route_path, route_track
from train_localization.core.network.labels import SectionLabels
from train_localization.core.network.scoring import PublishedState, network_scores
from train_localization.core.offline import fusion_runner, scenario_measurements, simulate_line, simulate_scenario
from train_localization.core.paths import resolve
from train_localization.core.scenario import Scenario, ScenarioError
from train_localization.core.signals import InputRejected
from train_localization.core.sensors import spec
from train_localization.core.sensors.dgps import DgpsDecoder, fix_sigma
from train_localization.core.sensors.base import sensor_params
from train_localization.core.scenario import Vehicle

THROAT = resolve("config/track_throat.yaml")


def throat_data() -> dict:
    with open(THROAT, encoding="utf-8") as fh:
        return yaml.safe_load(fh)


@pytest.fixture(scope="module")
def throat() -> Network:
    return Network.from_yaml(THROAT)


# ---- the model ------------------------------------------------------------------------

def test_the_throat_loads_with_sections_placed_from_their_nodes(throat):
    assert set(throat.sections) == {f"T{i}" for i in range(1, 8)}
    # the crossover T3 starts at W1 (the end of T1) and ends 4.5 m to the left, where W2 joins T4
    x, y, _ = throat.section("T3").pose(throat.section("T3").length)
    assert x == pytest.approx(1058.31, abs=0.02) and y == pytest.approx(4.5, abs=0.01)
    # T7 leaves track B at W3 and runs 4.5 m further left (track C)
    assert throat.section("T7").pose(500.0)[1] == pytest.approx(9.0, abs=0.01)
    ways = {(c.section, c.way) for c in throat.continuations("T1", 1)}
    assert ways == {("T2", "B1"), ("T3", "B2")}
    assert [(c.section, c.way) for c in throat.continuations("T3", 1)] == [("T5", None)]   # trailing at W2
    assert throat.continuations("T2", 1) == []                                           # an end of the network


@pytest.mark.parametrize("change, message", [
    (lambda d: d["nodes"].append({"id": "W9", "type": "point_switch", "A": "T2.end", "B1": "T1.end",
                                  "B2": "T6.end"}), "section end T1.end is joined twice"),
    (lambda d: d["nodes"][0].update(B2="T9.begin"), "names section 'T9'"),
    (lambda d: d["nodes"][0].update(B2="T3.middle"), "is not <section>.begin or <section>.end"),
    (lambda d: d["nodes"][0].pop("B2"), "port B2 is not joined"),
    (lambda d: d["nodes"][0].update(type="slip"), "type 'slip' is not one of"),
    (lambda d: d["sections"][3]["origin"].update(y=6.0), "lies 1.50 m from"),
    (lambda d: d["sections"][1].update(origin={"x": 1000.0, "y": 0.0, "heading": 0.2}), "route A-B1 bends by 11.5"),
    (lambda d: d["sections"][1]["equipment"]["eurobalise"].append({"id": "BGX", "position": 1500.0}),
     "section T2: eurobalise 'BGX' at 1500.0 m is off the track"),
    (lambda d: d["sections"].append({"id": "T1", "length": 10.0}), "section id 'T1' is used twice"),
    (lambda d: d["sections"].append({"id": "T8", "length": 10.0}), "section T8 has no origin"),
])
def test_an_inconsistent_network_is_refused_in_one_line(change, message):
    data = throat_data()
    change(data)
    with pytest.raises(NetworkError) as err:
        Network.from_dict(data)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_a_single_line_is_a_network_of_one_section():
    net = Network.from_dict({"network_id": "line", "sections": [{"id": "L", "length": 3000.0}]})
    assert list(net.sections) == ["L"] and net.continuations("L", 1) == [] and not net.nodes
    path = route_path(net, ["L"])
    assert path.locate(1234.5) == ("L", 1234.5) and path.distance("L", 10.0) == 10.0


# ---- routes and route lines ---------------------------------------------------------------

def test_a_route_line_joins_the_sections_and_carries_their_equipment(throat):
    path = route_path(throat, ["T1", "T3", "T5", "T7"])
    assert path.ways() == {"W1": "B2", "W3": "B2"}
    line = route_track(path, "throat:test")
    assert line.length == pytest.approx(1000.0 + throat.section("T3").length + throat.section("T5").length
                                        + throat.section("T7").length)
    for s in (300.0, 1020.0, 1200.0, 1500.0, 2300.0):   # the route line's map follows the sections'
        sec, c = path.locate(s)
        assert np.allclose(line.pose(s)[:2], throat.section(sec).pose(c)[:2], atol=0.02)
    balises = {b["id"]: b for b in line.items("eurobalise")}
    assert set(balises) == {"BG1a", "BG1b", "BG5a", "BG5b", "BG7a", "BG7b"}
    assert balises["BG7a"]["section"] == "T7" and balises["BG7a"]["section_position"] == 140.0
    assert balises["BG7a"]["position"] == pytest.approx(path.steps[3].start + 140.0)


def test_a_route_against_a_sections_chainage_counts_it_backwards(throat):
    path = route_path(throat, ["T5", "T3", "T1"], first_direction=-1)
    assert [st.direction for st in path.steps] == [-1, -1, -1]
    assert path.ways() == {"W2": "B2"}        # T5 -> T3 enters W2 at its A port: a facing move
    line = route_track(path, "throat:back")
    b = {it["id"]: it for it in line.items("eurobalise")}
    assert b["BG5a"]["position"] == pytest.approx(throat.section("T5").length - 120.0)
    assert b["BG1a"]["position"] > b["BG1b"]["position"]   # passed in the order 603, 600
    fix = PositionFix(1.0, "eurobalise", "eurobalise", line.track_id, "BG1a", b["BG1a"]["position"] + 2.0, 0.1, 1)
    moved = SectionLabels(line)(fix)
    assert (moved.track_id, moved.position, moved.direction) == ("T1", pytest.approx(598.0), -1)


def test_the_truth_of_a_network_train_names_its_section_and_chainage_like_the_state(throat):
    """ground_truth/state of a train on a network is in the fused state's frame (the section the
    front is on, its chainage and the speed along it) and carries the route distance, which the
    sensor simulators and the project's scores read back (convert.truth_from_msg)."""
    from train_localization.core.truth import TruthState
    mc = typestore_classes()
    back = route_track(route_path(throat, ["T5", "T3", "T1"], first_direction=-1), "throat:back")
    t5 = throat.section("T5").length
    for distance, section, chainage in ((10.0, "T5", t5 - 10.0), (t5 + 5.0, "T3", throat.section("T3").length - 5.0),
                                        (t5 + throat.section("T3").length + 100.0, "T1", 900.0)):
        state = TruthState(2.0, distance, 12.0, -0.5)
        msg = convert.truth_to_msg(mc, state, back)
        assert (msg.track_id, msg.route_id, msg.route_direction) == (section, "throat:back", -1)
        assert msg.position == pytest.approx(chainage) == msg.position_min == msg.position_max
        assert (msg.speed, msg.acceleration, msg.route_distance) == (-12.0, 0.5, distance)
        assert convert.truth_from_msg(msg) == state
    single = Scenario.from_yaml("config/scenario_demo.yaml").track
    msg = convert.truth_to_msg(mc, TruthState(1.0, 250.0, 3.0, 0.0), single)
    assert (msg.track_id, msg.position, msg.route_id, msg.route_direction) == (single.track_id, 250.0, "", 0)
    assert math.isnan(msg.route_distance) and convert.truth_from_msg(msg).position == 250.0


def test_a_hypothesis_restates_its_interval_on_every_section_it_spans(throat):
    """TrackHypothesis path_min / path_max: the interval on each section of its path, in that
    section's chainage, so that a place (section, chainage) is found in it without the topology."""
    path = route_path(throat, ["T5", "T3", "T1"], first_direction=-1)
    t5, t3 = throat.section("T5").length, throat.section("T3").length
    spans = path.spans(t5 - 4.0, t5 + t3 + 6.0)     # from 4 m before T5's begin to 6 m into T1
    assert [(sp.section, sp.lo, sp.hi) for sp in spans] == [
        ("T5", pytest.approx(0.0), pytest.approx(4.0)), ("T3", pytest.approx(0.0, abs=1e-9), pytest.approx(t3)),
        ("T1", pytest.approx(994.0), pytest.approx(1000.0))]
    assert path.sections(t5 - 4.0, t5 + t3 + 6.0) == ["T5", "T3", "T1"]
    beyond = path.spans(-3.0, 2.0)                  # the path's first section, continued before it
    assert [(sp.section, sp.lo, sp.hi) for sp in beyond] == [("T5", pytest.approx(t5 - 2.0), pytest.approx(t5 + 3.0))]


def test_a_route_through_sections_that_do_not_follow_is_refused(throat):
    with pytest.raises(NetworkError, match="section T6 does not follow T1"):
        route_path(throat, ["T1", "T6"])


@pytest.mark.parametrize("change, message", [
    (lambda d: d["trains"][0]["route"].update(sections=["T1", "T5"]), "section T5 does not follow T1"),
    (lambda d: d["trains"][1]["route"].update(reported={"W7": "B1"}), "'W7', which is no point switch"),
    (lambda d: d["trains"][1]["route"].update(reported={"W3": "left"}), "must be B1, B2 or ''"),
    (lambda d: d["trains"][0].pop("route"), "on a network a train needs 'route"),
    (lambda d: d["trains"][0]["sensors"].update(axle_counter={}), "axle_counter: wayside equipment, it sees every"),
    (lambda d: d["trains"][0]["sensors"].update(inpo_receiver={}), "['inpo_receiver'] do not work on a network yet"),
    (lambda d: d["trains"][0]["initial"].update(position=1200.0), "is off its first section T1"),
    (lambda d: d.update(wayside={"sensors": {"axle_counter": {"front_first": True}}, "changeover": {"sections": []}}),
     "a changeover section on a network is not supported yet"),
    (lambda d: d.update(wayside={"sensors": {"track_circuit_receiver": {"front_first": True}}}),
     "no section of network throat carries track_circuit"),
    (lambda d: d.update(wayside={"sensors": {"axle_counter": {"heads": "AC1,AC99"}}}), "AC99 on no section"),
    (lambda d: d.update(wayside={"sensors": {"axle_counter": {"faults": "AC42@3:missed"}}}), "AC42 on no section"),
    (lambda d: d.update(wayside={"sensors": {"axle_counter": {}}}), "axle_counter on a network needs front_first"),
])
def test_a_network_scenario_that_cannot_run_is_refused_in_one_line(change, message):
    with open(resolve("config/scenario_throat.yaml"), encoding="utf-8") as fh:
        data = yaml.safe_load(fh)
    data["track"] = throat_data()
    change(data)
    with pytest.raises(ScenarioError) as err:
        Scenario.from_dict(data)
    assert message in str(err.value) and "\n" not in str(err.value)


# ---- sensors on a network -----------------------------------------------------------------

def test_the_dgps_projects_onto_the_whole_network_and_keeps_the_lateral_offset(throat):
    path = route_path(throat, ["T1", "T2"])
    line = route_track(path, "throat:dgps")
    params = sensor_params(spec("dgps_receiver"), {}, Vehicle())
    dec = DgpsDecoder(params, line)
    # a fix 3.9 m left of track A at x = 700 m is nearer track B (T4, 0.6 m right of it)
    at_hdop_1 = lambda near: fix_sigma(params, 1.0, near)   # noqa: E731
    fix = dec.locate(1.0, 700.0, 3.9, at_hdop_1)
    assert fix.track_id == "T4" and fix.lateral == pytest.approx(-0.6, abs=1e-6)
    assert fix.is_map_fix and fix.lateral_stddev == fix.position_stddev
    assert fix.position == pytest.approx(700.0 - 258.30737517673, abs=1e-3)   # the antenna's chainage on T4
    assert dec.locate(2.0, 700.0, -30.0, at_hdop_1) is None and dec.stats["off_track"] == 1


def test_switch_positions_messages_are_checked():
    mc = typestore_classes()
    msg = convert.switch_positions_to_msg(mc, 1.0, {"W1": "B2", "W3": ""})
    assert convert.switch_positions_from_msg(msg) == {"W1": "B2", "W3": ""}
    with pytest.raises(InputRejected, match="not B1, B2"):
        convert.switch_positions_from_msg(mc.SwitchPositions(header=mc.header(0.0), switch_ids=["W1"],
                                                             positions=["reverse"]))
    with pytest.raises(InputRejected, match="2 switch ids and 1 positions"):
        convert.switch_positions_from_msg(mc.SwitchPositions(header=mc.header(0.0), switch_ids=["W1", "W2"],
                                                             positions=["B1"]))


# ---- the track-selective fusion -------------------------------------------------------------

@pytest.fixture(scope="module")
def throat_run():
    sc = Scenario.from_yaml("config/scenario_throat.yaml")
    return sc, simulate_line(sc, fusion_rate=50.0)


def _scores(train, result):
    return network_scores(train.route, [s.stamp for s in result.truth], [s.position for s in result.truth],
                          [PublishedState.of_estimate(e) for e in result.estimates])


def test_both_trains_through_the_throat_keep_their_track_and_interval(throat_run):
    sc, res = throat_run
    for name, result in res.trains.items():
        scores = _scores(sc.trains[name], result)
        assert scores["nominal_wrong_track"] == 0, name
        assert scores["inside"] == 1.0 and scores["true_hypothesis_inside"] == 1.0, name
        assert scores["switch_ways_resolved"] == scores["switch_ways"] == 1, name
        assert scores["selectivity"] == 1.0 and scores["parallel_states"] > 3000, name
        assert scores["position_error_m"]["max"] < 1.5, name


def test_a_wrongly_reported_switch_is_found_from_the_evidence(throat_run):
    sc, res = throat_run
    south = res.trains["south"]
    counters = south.runner.counters()
    assert counters["switches_contradicted"] == {"W3": "reported B1, found B2"}
    # the hypothesis of the reported way led until the DGPS saw the train leave track B: those
    # states were DEGRADED, and never NOMINAL
    wrong = [e for e in south.estimates if e.track_id == "T6"]
    assert wrong and all(e.mode == 2 for e in wrong)
    truth = {round(s.stamp, 6): s.position for s in south.truth}
    first_right = min(e.stamp for e in south.estimates if e.track_id == "T7")
    w3 = sc.trains["south"].route.steps[2].start
    assert truth[round(first_right, 6)] - w3 < 40.0   # resolved within W3's clearance length


def test_while_several_tracks_are_plausible_the_state_is_degraded_and_covers_them(throat_run):
    _, res = throat_run
    several = [e for e in res.trains["north"].estimates if len({h.path for h in e.hypotheses}) > 1]
    assert several and all(e.mode == 2 for e in several)
    for e in several:
        for h in e.hypotheses:   # every plausible hypothesis's interval lies within the published one
            assert e.path_min <= e.path_position <= e.path_max
            assert len(h.pieces) == len(h.path) and all(lo <= hi for lo, hi in h.pieces)
    msg = convert.track_hypotheses_to_msg(typestore_classes(), several[-1], "throat")
    for h, m in zip(several[-1].hypotheses, msg.hypotheses):   # the interval on each section of its path
        assert list(m.path) == list(h.path) and list(zip(m.path_min, m.path_max)) == list(h.pieces)


def _north_arrivals():
    sc = Scenario.from_yaml("config/scenario_throat.yaml").train("north")
    return sc, scenario_measurements(sc, t_end=70.0)


def _misread(t: float, balise: str, section: str, position: float) -> tuple[float, PositionFix]:
    return t, PositionFix(t, "eurobalise", "eurobalise", section, balise, position, 1.0, 1)


@pytest.fixture(scope="module")
def north_arrivals():
    return _north_arrivals()


def _fuse(sc, arrivals, t_end: float = 70.0):
    """Arrivals into the train's fusion, the states at 50 Hz as they come (as simulate does)."""
    runner = fusion_runner(sc, 50.0)
    estimates, j = [], 0
    for k in range(int(t_end * 50) + 1):
        t = k / 50.0
        while j < len(arrivals) and arrivals[j][0] <= t + 1e-12:
            runner.add(arrivals[j][1])
            j += 1
        estimates.extend(e for e, _ in runner.advance(t))
    return runner, estimates


def test_one_misread_balise_on_the_other_way_does_not_exclude_the_true_track(north_arrivals):
    sc, arrivals = north_arrivals
    # at 41 s both ways of W1 are hypotheses; a reader misreads BG5a (track B, beyond the crossover)
    arrivals = sorted(arrivals + [_misread(41.0, "BG5a", "T5", 122.0)], key=lambda a: a[0])
    runner, estimates = _fuse(sc, arrivals)
    last = estimates[-1]
    assert last.track_id == "T2" and last.mode != 3
    assert runner.counters()["network"].get("excluded_reference", 0) == 0


def test_two_misreads_exclude_the_true_track_but_the_state_is_then_not_nominal(north_arrivals):
    sc, arrivals = north_arrivals
    arrivals = sorted(arrivals + [_misread(41.0, "BG5a", "T5", 122.0), _misread(41.1, "BG5b", "T5", 125.0)],
                      key=lambda a: a[0])
    runner, estimates = _fuse(sc, arrivals)
    assert runner.counters()["network"]["excluded_reference"] == 1
    after = [e for e in estimates if e.stamp > 41.2 and e.track_id != "T2"]
    # beyond the fault hypothesis (two misreads in 30 s): the DGPS fixes are then off every path
    # and hold the state DEGRADED; it never claims the wrong track NOMINAL
    assert after and all(e.mode != 1 for e in after if e.stamp > 44.0)
    assert runner.counters()["network"]["map_fix_off_every_path"] > 0


def test_a_single_line_as_a_network_of_one_section_gives_the_same_states():
    line = Scenario.from_yaml("config/scenario_throat.yaml").train("north")
    # the same train on track A alone: one section, no switch
    data = {"name": "one_section", "duration": 30.0, "seed": 3,
            "track": {"network_id": "a", "sections": [{"id": "A", "length": 2400.0,
                                                        "equipment": {"eurobalise": [
                                                            {"id": "B1", "position": 600.0},
                                                            {"id": "B2", "position": 603.0}]}}]},
            "route": {"sections": ["A"]}, "initial": {"position": 450.0},
            "vehicle": {"length": 120.0, "axles": list(line.vehicle.axles)},
            "profile": [{"speed": 20.0, "accel": 0.8, "hold": 55.0}],
            "sensors": {"wheel_sensor": {}, "doppler_radar": {}, "eurobalise_reader": {}, "dgps_receiver": {}},
            "fusion": {"initial_position": 450.0, "initial_position_stddev": 1.0}}
    on_network = simulate_scenario(Scenario.from_dict(copy.deepcopy(data)), fusion_rate=50.0)
    single = {**data, "track": {"track_id": "A", "length": 2400.0,
                                "equipment": data["track"]["sections"][0]["equipment"]}}
    del single["route"]
    on_line = simulate_scenario(Scenario.from_dict(single), fusion_rate=50.0)
    assert len(on_network.estimates) == len(on_line.estimates)
    for a, b in zip(on_network.estimates, on_line.estimates):
        assert a.track_id == "A" and a.mode == b.mode
        assert a.position == pytest.approx(b.position, abs=1e-6)
        assert (a.position_min, a.position_max) == (pytest.approx(b.position_min, abs=1e-6),
                                                    pytest.approx(b.position_max, abs=1e-6))


def test_a_fix_on_a_section_no_hypothesis_contains_is_refused_and_counted(north_arrivals):
    sc, arrivals = north_arrivals
    runner = fusion_runner(sc, 50.0)
    runner.advance(0.0)
    fix = PositionFix(0.5, "eurobalise", "eurobalise", "T6", "BG6a", 122.0, 1.0, 1)
    assert not runner.add(fix) and runner.rejected["off_network_path"] == 1
    assert not runner.add(replace(fix, track_id="T99")) and runner.rejected["wrong_track"] == 1
    assert math.isfinite(runner.advance(1.0)[-1][0].position)


def test_a_train_running_against_the_sections_chainage_takes_their_balises():
    """A route run backwards along every section (T6 -> T5 -> T4: track B against its chainage,
    trailing through W3 and facing W2): the balise fixes restated on their sections lie on the
    other side of the balise (front = balise - antenna offset), within their reference windows."""
    data = {"name": "backwards", "duration": 105.0, "seed": 4, "track": throat_data(),
            "route": {"sections": ["T6", "T5", "T4"], "direction": -1}, "initial": {"position": 900.0},
            "vehicle": {"length": 120.0}, "profile": [{"speed": 20.0, "accel": 0.8, "hold": 100.0}],
            "sensors": {"wheel_sensor": {}, "doppler_radar": {}, "eurobalise_reader": {}, "dgps_receiver": {}}}
    sc = Scenario.from_dict(data)
    assert sc.route.ways() == {"W2": "B1"} and [st.direction for st in sc.route.steps] == [-1, -1, -1]
    run = simulate_scenario(sc, fusion_rate=50.0)
    balises = [m for m in run.measurements if m.sensor == "eurobalise"]
    assert {m.track_id for m in balises} == {"T6", "T5", "T4"}
    net = sc.network
    for m in balises:   # the front 2 m (the antenna offset) beyond the balise the way the train runs
        assert m.position == pytest.approx(net.item_location("eurobalise", m.reference_id)[1]["position"] - 2.0,
                                           abs=0.5)
    assert run.runner.rejected.get("reference_mismatch", 0) == 0, run.runner.rejected
    assert run.runner.counters()["accepted"]["eurobalise"] == len(balises)
    scores = _scores(sc, run)
    assert scores["nominal_wrong_track"] == 0 and scores["inside"] == 1.0
    assert scores["switch_ways_resolved"] == scores["switch_ways"] == 1


def _tunnel_over_w3(with_gyro: bool) -> dict:
    """The south train of the throat under a tunnel over W3 (no DGPS from 200 m before it to
    200 m after it) with W3 reported wrongly, and no balise on T7 before the tunnel's end."""
    with open(resolve("config/scenario_throat.yaml"), encoding="utf-8") as fh:
        data = yaml.safe_load(fh)
    data["track"] = throat_data()
    sections = {s["id"]: s for s in data["track"]["sections"]}
    for sid, span in (("T5", (141.0, 341.69)), ("T6", (0.0, 200.0)), ("T7", (0.0, 200.0))):
        sections[sid].setdefault("equipment", {})["structure"] = [{"id": f"TN_{sid}", "type": "tunnel",
                                                                    "start": span[0], "end": span[1]}]
    sections["T7"]["equipment"]["eurobalise"] = [{"id": "BG7a", "position": 400.0}, {"id": "BG7b", "position": 403.0}]
    south = next(t for t in data["trains"] if t["name"] == "south")
    if with_gyro:
        south["sensors"]["gyro"] = {}
    south["route"]["reported"] = {"W3": "B1"}
    return {**data, "trains": [south], "duration": 75.0}


@pytest.mark.parametrize("with_gyro", [False, True])
def test_a_gyro_names_the_way_where_neither_balise_nor_dgps_sees_it(with_gyro):
    """In a tunnel over W3 (reported B1, lying B2) no balise and no DGPS fix tells the ways
    apart: without a gyro both stay plausible (DEGRADED) and the wrong report ranks first past
    the clearance point; with one the turnout's curve (18 m/s on R 190 m: 0.095 rad/s) names
    the true way before it. Neither is ever NOMINAL on the wrong track."""
    sc = Scenario.from_dict(_tunnel_over_w3(with_gyro))
    res = simulate_line(sc, fusion_rate=50.0)
    south = res.trains["south"]
    scores = _scores(sc.trains["south"], south)
    assert scores["nominal_wrong_track"] == 0 and scores["true_hypothesis_inside"] == 1.0
    assert scores["switch_ways_resolved"] == (1 if with_gyro else 0), scores["ways"]
    if with_gyro:
        assert south.runner.counters()["accepted"].get("gyro", 0) == 0   # not an along-track measurement

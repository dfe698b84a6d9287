"""A changeover section on a line (core/wayside/changeover.py): laid from the line's track,
its detection and controller in the loop with every train of an offline line run, the
catenary events evaluated from the controller's commands and from a bag's recorded ones,
and the wayside nodes in the line's graph."""
from __future__ import annotations

import functools
import tempfile
from pathlib import Path

import numpy as np
import pytest
import yaml

from train_localization.core import paths
from train_localization.core.offline import simulate_line
from train_localization.core.report import changeover_check, line_report, recorded_changeover
from train_localization.core.scenario import Scenario, ScenarioError
from train_localization.core.wayside import catenary
from train_localization.core.wayside.changeover import ChangeoverError, Site
from train_localization.graph import line_graph

LINE = "config/scenario_line_changeover.yaml"
T_PAIR = 66.0        # [s] both 300 km/h trains (train_a, train_b) have crossed the changeover block


def line_dict() -> dict:
    return yaml.safe_load(paths.resolve(LINE).read_text())


@functools.lru_cache(maxsize=None)
def pair_run(faults: str = ""):
    """The line's first T_PAIR seconds (the up pair at 300 km/h through the changeover), with
    its bag; ``faults``: the wayside track circuits' faults."""
    data = line_dict()
    if faults:
        data["wayside"]["sensors"]["track_circuit_receiver"]["faults"] = faults
    scenario = Scenario.from_dict(data, source=paths.resolve(LINE))
    bag = Path(tempfile.mkdtemp(prefix="tl_changeover_")) / "line.mcap"
    return scenario, simulate_line(scenario, bag=bag, t_end=T_PAIR), bag


def test_the_changeover_is_laid_around_three_consecutive_heads_of_the_track():
    sc = Scenario.from_yaml(LINE)
    site = sc.changeover_site()
    lay = site.layout
    assert lay.ac == (4000.0, 4800.0, 5600.0)
    # air sections 250 m inside the outer counting points, 50 m long; the neutral between them
    assert lay.air1 == (4250.0, 4300.0) and lay.air2 == (5300.0, 5350.0)
    assert lay.params["neutral_length"] == pytest.approx(1000.0)      # seed 004 section 4.1: about 1 km
    # Fig. 6: a track circuit and an axle-counter section in each half; seed 004 section 4.2: the
    # blocks 800 m with the air section in them, the circuits 400 m, inside the neutral section
    assert site.section_strings() == ["S1:CO1:S1", "S2:CO2:S2"]
    assert lay.ac[1] - lay.ac[0] == lay.ac[2] - lay.ac[1] == 800.0
    circuits = {c["id"]: (c["start"], c["end"]) for c in sc.track.items("track_circuit")}
    assert circuits["CO1"] == (4400.0, 4800.0) and circuits["CO2"] == (4800.0, 5200.0)
    assert lay.air1[1] < circuits["CO1"][0] and circuits["CO2"][1] < lay.air2[0]
    assert site.switching(10.0, catenary.ABB1, False).stamp == pytest.approx(10.0 + 0.01 + 1 / 120)
    assert site.switching(10.0, catenary.ABB2, True).stamp == pytest.approx(10.01)


@pytest.mark.parametrize("change, message", [
    ({"counting_points": ["AC01", "AC03", "AC02"]}, "not consecutive heads"),
    ({"counting_points": ["AC01", "AC02"]}, "three axle-counter heads"),
    ({"counting_points": ["AC01", "AC02", "AC09"]}, "AC09 not on track"),
    ({"catenary": {"approach": 800.0}}, "leave no neutral section"),
    ({"catenary": {"approach": 360.0}}, "neutral section of 780 m: seed 004 section 4.2 asks for at least 800 m"),
    ({"command_latency": 5.0}, "command_latency"),
    ({"counting_points": ["AC01", "AC02", "AC03"], "switches": 2}, "unknown key"),
])
def test_a_changeover_that_cannot_be_laid_is_refused_in_one_line(change, message):
    data = line_dict()
    data["wayside"]["changeover"] = {**data["wayside"]["changeover"], **change}
    with pytest.raises(ScenarioError, match=message) as err:
        Scenario.from_dict(data, source=paths.resolve(LINE))
    assert "\n" not in str(err.value)


def test_a_half_without_its_own_track_circuit_is_refused():
    track = Scenario.from_yaml(LINE).track
    data = {"track_id": "t", "length": track.length,
            "equipment": {"axle_counter_head": track.items("axle_counter_head"),
                          "track_circuit": [{"id": "X", "start": 3000.0, "end": 4800.0}]}}
    from train_localization.core.track import Track
    with pytest.raises(ChangeoverError, match=r"no track circuit .* in 4000..4800 m \(AC01..AC02\) reaches the middle"):
        Site.from_config({"counting_points": ["AC01", "AC02", "AC03"]}, Track.from_dict(data))


def test_the_pair_at_300_kmh_is_switched_over_without_a_short_circuit_and_stays_inside():
    scenario, result, _ = pair_run()
    report = line_report(result)
    co = report["changeover"]
    assert co["short_circuits"] == 0 and co["air_section_switchings"] == 0
    # per train: A -> B (section 4.1): ABB-1 opens, ABB-2 closes, ABB-2 opens, ABB-1 closes
    passes = [(c["switch"], c["on"]) for c in co["commands"] if c["stamp"] > 10.0]
    one = [(catenary.ABB1, False), (catenary.ABB2, True), (catenary.ABB2, False), (catenary.ABB1, True)]
    assert passes == one + one
    for name in ("train_a", "train_b"):
        # the neutral is dead for a moment only, against 12 s of an unfed neutral at 300 km/h
        assert co["crossing_time_s"][name] == pytest.approx(12.0, abs=0.1)
        assert 0.0 < co["dead_time_s"][name] < 1.5
        assert co["unfed_time_s"][name] > 10.0
        integ = report["trains"][name]["integrity"]
        assert integ["inside_fraction"] == 1.0 and integ["mean_interval_width_m"] < 15.0
    # before any report the controller keeps the neutral dead (no detection: safe state), then recovers
    assert co["safe_state"][0]["stamp"] == 0.0 and "SILENT" in co["safe_state"][0]["reason"]
    assert co["final"]["mode"] == "IDLE" and co["final"]["feed"] == "A"


def test_the_bag_holds_the_commands_and_gives_the_same_events():
    scenario, result, bag = pair_run()
    replayed = changeover_check(result)
    recorded = recorded_changeover(bag, scenario)
    assert [(c["switch"], c["on"]) for c in recorded["commands"]] == \
        [(c["switch"], c["on"]) for c in replayed["commands"]]
    assert np.allclose([c["stamp"] for c in recorded["commands"]], [c["stamp"] for c in replayed["commands"]],
                       atol=0.011)
    assert recorded["short_circuits"] == replayed["short_circuits"] == 0
    for name, dead in replayed["dead_time_s"].items():
        assert recorded["dead_time_s"][name] == pytest.approx(dead, abs=0.02)


def test_a_circuit_stuck_occupied_on_the_line_makes_the_changeover_safe():
    _, result, _ = pair_run("CO2@20.0:tx_failed")
    co = changeover_check(result)
    reasons = [s["reason"] for s in co["safe_state"] if s["stamp"] > 10.0]
    assert reasons and "S2" in reasons[0]
    assert co["final"]["safe"] and co["final"]["feed"] == "OFF"
    # the neutral stays dead: no short circuit, the trains coast through it
    assert co["short_circuits"] == 0
    assert co["dead_time_s"]["train_b"] == pytest.approx(co["unfed_time_s"]["train_b"], abs=0.05)


def test_line_graph_runs_the_changeover_nodes_in_the_wayside_namespace(tmp_path):
    graph = line_graph(str(paths.resolve(LINE)), str(tmp_path / "b.mcap"))
    nodes = {(ns, name): params for ns, _, name, params in graph}
    for name in ("wayside_occupancy", "neutral_section_controller"):
        assert nodes[("/wayside", name)]["sections"] == ["S1:CO1:S1", "S2:CO2:S2"]
        assert nodes[("/wayside", name)]["use_sim_time"] is True
    # a line without a changeover section has neither
    other = line_graph(str(paths.resolve("config/scenario_line_pair.yaml")), str(tmp_path / "c.mcap"))
    assert not any(name == "neutral_section_controller" for _, _, name, _ in other)


def test_a_changeover_needs_trains_with_pantographs():
    data = line_dict()
    for train in data["trains"]:
        train["vehicle"].pop("pantographs")
    with pytest.raises(ScenarioError, match="pantographs"):
        Scenario.from_dict(data, source=paths.resolve(LINE))
    data = line_dict()
    data["trains"][0]["vehicle"]["pantographs"] = [250.0]
    with pytest.raises(ScenarioError, match="not on the vehicle"):
        Scenario.from_dict(data, source=paths.resolve(LINE))

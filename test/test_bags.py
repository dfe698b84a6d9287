"""Regression: every bag in bags/ replays offline within its stored bounds, and the
offline replay agrees with the live graph that recorded it; the recording of a train's
drivers' standard messages (osm_drivers) replays through the standard inputs."""
from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest
from mcap.reader import make_reader

from conftest import ROOT, outside_scorer
from train_localization.core import convert
from train_localization.core.bagio import read_bag, topic_counts
from train_localization.core.fusion import Mode
from train_localization.core.ingest.nmea import NmeaFix, decode_log
from train_localization.core.offline import SCENARIO_TOPIC, TRUTH_TOPIC, replay_bag, replay_line, scenario_from_bag
from train_localization.core.report import (evaluate, line_report, recorded_changeover, recorded_etcs, recorded_network,
                                          recorded_stator)
from train_localization.core.scoring import StateSeries
from train_localization.core.wayside import stator
from train_localization.tools.make_bags import metric
from train_localization.tools.replay import recorded_run

BAGS = ROOT / "bags"
TABLE = json.loads((BAGS / "thresholds.json").read_text()) if (BAGS / "thresholds.json").exists() else {}


def test_every_bag_has_bounds_and_is_small():
    bags = sorted(p.stem for p in BAGS.glob("*.mcap"))
    assert len(bags) >= 5
    assert bags == sorted(TABLE), "bags/thresholds.json must list exactly the bags in bags/"
    for name in bags:
        assert (BAGS / f"{name}.mcap").stat().st_size < 5e6, f"{name}.mcap is over 5 MB"
        assert f"`{name}.mcap`" in (BAGS / "README.md").read_text(), f"{name} is not described in bags/README.md"


def _live(bag) -> bool:
    """Whether a bag holds a live graph's fused states (a recording of drivers' messages has none)."""
    return any(topic.endswith("/localization/state") for topic in topic_counts(bag))


@pytest.fixture(scope="module", params=sorted(TABLE))
def replayed(request, tmp_path_factory):
    """(bag name, {train: offline replay}, {train: its report}, line report or None, the file
    holding the fused states: the bag, or for a bag without live states the offline replay's
    output); a one-train bag has the one train ``train``."""
    name = request.param
    bag = BAGS / f"{name}.mcap"
    scenario = scenario_from_bag(bag)
    if scenario.line:
        result = replay_line(bag, scenario)
        report = line_report(result)
        return name, result.trains, report["trains"], report, bag
    fused = bag if _live(bag) else tmp_path_factory.mktemp(name) / "replayed.mcap"
    run = replay_bag(bag, scenario, None if fused == bag else fused)
    report = evaluate(run.truth, run.estimates, run.measurements, scenario.track.circumference)[0]
    return name, {"train": run}, {"train": report}, None, fused


def _failures(label: str, bounds: dict, report: dict) -> list[str]:
    failures = []
    for key, bound in bounds.items():
        value = metric(report, key)
        if "max" in bound and not value <= bound["max"]:
            failures.append(f"{label}: {key} = {value:.6g} is worse than the bound {bound['max']:.6g}")
        if "min" in bound and not value >= bound["min"]:
            failures.append(f"{label}: {key} = {value:.6g} is worse than the bound {bound['min']:.6g}")
    return failures


def test_offline_replay_scores_stay_within_stored_bounds(replayed):
    name, _, reports, line, _ = replayed
    if line is None:
        failures = _failures(f"{name}.mcap", TABLE[name]["bounds"], reports["train"])
    else:   # every train within its bounds, no wayside fix given to the wrong train
        failures = [f for train, entry in TABLE[name]["trains"].items()
                    for f in _failures(f"{name}.mcap {train}", entry["bounds"], reports[train])]
        wrong = line["association"]["wrong_train"]
        if wrong > TABLE[name]["association"]["wrong_train"]["max"]:
            failures.append(f"{name}.mcap: {wrong} wayside fixes given to the wrong train")
    assert not failures, "\n".join(failures)


def _live_states(bag, train: str) -> list:
    """The fused states the live graph recorded for ``train`` (``train``: a one-train bag)."""
    if train == "train":
        return recorded_run(bag)[1]
    return [msg for topic, _, _, msg in read_bag(bag) if topic == f"/{train}/localization/state"]


def test_offline_replay_matches_the_live_graph_within_the_filter_tolerance(replayed):
    name, runs, _, _, fused = replayed
    if fused != BAGS / f"{name}.mcap":
        pytest.skip(f"{name}: a recording of the drivers' messages, no live fused state")
    ring = scenario_from_bag(BAGS / f"{name}.mcap").track.circumference
    for train, run in runs.items():
        _matches_live(f"{name} {train}", run.estimates, _live_states(BAGS / f"{name}.mcap", train), ring)


def _matches_live(name: str, offline: list, live: list, ring: float | None = None) -> None:
    """``ring``: the circumference of a closed track, on which the published positions are wrapped
    and the filter's are the distance run (compared modulo it)."""
    off_t = np.array([e.stamp for e in offline])
    off_s = np.array([e.position for e in offline])
    live_t = np.array([convert.stamp_to_sec(m.header.stamp) for m in live])
    live_s = np.array([m.position for m in live])
    live_sd = np.array([m.position_stddev for m in live])
    both = np.isfinite(live_s) & (live_t >= off_t[0]) & (live_t <= off_t[-1])
    idx = np.searchsorted(off_t, live_t[both])
    idx = np.clip(idx, 0, len(off_t) - 1)
    same_time = np.abs(off_t[idx] - live_t[both]) < 1e-6
    diff = off_s[idx][same_time] - live_s[both][same_time]
    diff = np.abs((diff + 0.5 * ring) % ring - 0.5 * ring if ring else diff)
    sd = live_sd[both][same_time]
    ok = np.isfinite(diff)
    if not both.any():   # the live train claimed no position (a line's train that passed one reference)
        assert all(e.mode == Mode.INITIALISING for e in offline), f"{name}: offline claims a position, live did not"
        return
    assert ok.sum() > 0.5 * both.sum(), f"{name}: too few common states"
    within = diff[ok] <= 3.0 * sd[ok]
    assert within.mean() >= 0.99, (f"{name}: offline and live fused position differ by more than 3 sigma in "
                                   f"{100 * (1 - within.mean()):.2f} % of the states")


def test_a_changeover_bag_switches_live_and_replayed_without_a_short_circuit(replayed):
    """A line bag with a changeover section: the replayed controller (offline, from the recorded
    wayside raw blocks) makes the live controller's commands, and neither shorts the phases or
    switches under a pantograph in an air section."""
    name, _, _, line, _ = replayed
    if line is None or "changeover" not in line:
        pytest.skip(f"{name}: no changeover section")
    bounds = TABLE[name]["changeover"]
    offline = line["changeover"]
    live = recorded_changeover(BAGS / f"{name}.mcap", scenario_from_bag(BAGS / f"{name}.mcap"))
    for label, co in (("replayed", offline), ("live", live)):
        for key, bound in bounds.items():
            assert co[key] <= bound["max"], f"{name} {label}: {key} = {co[key]}"
    assert [(c["switch"], c["on"]) for c in live["commands"]] == [(c["switch"], c["on"]) for c in offline["commands"]]
    # the same decisions within the live controller's timer period and message delays
    assert np.allclose([c["stamp"] for c in live["commands"]], [c["stamp"] for c in offline["commands"]], atol=0.3)


def test_a_long_stator_bag_feeds_live_and_replayed_without_a_switching_under_the_vehicle(replayed):
    """A bag whose track has stator sections (core/wayside/stator.py): the live
    stator_section_controller's recorded feed and the controller replayed on the offline
    fused states switch no section under the vehicle, lose no thrust, never feed two sections
    from one inverter, and switch the same sections at about the same times."""
    name, runs, _, line, _ = replayed
    bag = BAGS / f"{name}.mcap"
    scenario = scenario_from_bag(bag)
    if line is not None or not scenario.track.items(stator.KIND):
        pytest.skip(f"{name}: no long-stator sections")
    live = recorded_stator(bag, scenario, "/train")
    run = runs["train"]
    layout = stator.Layout.from_track(scenario.track)
    vehicle = stator.Vehicle(scenario.vehicle.length, scenario.orientation())
    ctrl = stator.run_controller(layout, vehicle, StateSeries.from_estimates(run.estimates))
    truth = np.array([s.stamp for s in run.truth]), np.array([s.position for s in run.truth])
    offline = stator.evaluate(layout, ctrl.commands, *truth, vehicle).as_dict()
    for label, st in (("live", live), ("replayed", offline)):
        assert st["section_passages"] >= 20, f"{name} {label}: {st}"
        assert st["switched_under_vehicle"] == 0 and st["double_feed"] == 0, f"{name} {label}: {st}"
        assert st["thrust_loss_s"] == 0.0, f"{name} {label}: {st}"
    live_ons = live["switch_ons"]
    replayed_ons = [(c.stamp, c.section) for c in ctrl.commands if c.on]
    assert [s for _, s in live_ons] == [s for _, s in replayed_ons]
    assert np.allclose([t for t, _ in live_ons], [t for t, _ in replayed_ons], atol=0.3)


def test_an_etcs_bag_stops_short_of_its_authority_live_and_locates_the_same_replayed(replayed):
    """A bag with the ETCS location function and the ATP supervision (docs/etcs.md): the live
    nodes' recorded reports keep the true front within their safe front ends, the supervision
    braked, never tripped, and the train came to rest short of its end of authority; the
    location function run on the offline replay's states and balise fixes keeps the truth
    inside too and takes the same LRBGs."""
    from train_localization.core.etcs import scoring as etcs_scoring
    from train_localization.core.etcs.track_data import EtcsData
    name, runs, _, line, _ = replayed
    bag = BAGS / f"{name}.mcap"
    scenario = scenario_from_bag(bag)
    if line is not None or not scenario.atp:
        pytest.skip(f"{name}: no ATP supervision")
    live = recorded_etcs(bag, scenario, "/train")
    assert live["claimed"] > 3000 and live["outside"] == 0, live
    assert live["trips"] == 0 and live["max_status"] == 3 and live["brakes"].get(1, 0) > 0, live
    assert 0.0 < live["eoa_margin"] < 500.0, live
    run = runs["train"]
    o = scenario.orientation()
    replay = etcs_scoring.run_location(EtcsData.from_track(scenario.track), {"orientation": o}, run.estimates,
                                       [(m.stamp, m) for m in run.measurements])
    truth = np.array([s.stamp for s in run.truth]), np.array([s.position for s in run.truth]), \
        np.array([s.speed for s in run.truth])
    scores = etcs_scoring.location_scores(replay, *truth, o)
    assert scores["outside"] == 0 and scores["speed_inside_share"] == 1.0, scores
    assert [e.nid_bg for e in replay.events if e.kind.name == "LRBG"] == live["lrbgs"] != []


def test_a_network_bag_names_each_trains_track_live_and_replayed(replayed):
    """A bag of trains on a network (docs/network.md): the states the live fusions recorded
    never claim a wrong track NOMINAL, keep the truth inside the interval and inside the true
    track's hypothesis, and resolve every switch way within its clearance; the replayed
    fusions reach the same tracks (the same switch ways, the same contradicted report)."""
    name, runs, reports, line, _ = replayed
    bag = BAGS / f"{name}.mcap"
    scenario = scenario_from_bag(bag)
    networked = [n for n, tr in scenario.trains.items() if tr.network is not None]
    if not networked or line is None:
        pytest.skip(f"{name}: no line of trains on a network")
    for train in networked:
        live = recorded_network(bag, scenario.trains[train], f"/{train}")
        assert live["claimed"] > 1500 and live["nominal_wrong_track"] == 0, (train, live)
        assert live["inside"] == 1.0 and live["true_hypothesis_inside"] >= 0.999, (train, live)
        # every way resolved within its clearance where the bag's evidence can (throat_wayside's south:
        # only the head 45 m past W3 tells its way, beyond the clearance: bags/thresholds.json)
        resolved = TABLE[name]["trains"][train]["bounds"]["network.switch_ways_resolved"]["min"]
        assert live["switch_ways"] >= 1 and live["switch_ways_resolved"] >= resolved, (train, live)
        replayed_ways = [(w["switch"], w["resolved"]) for w in reports[train]["network"]["ways"]]
        assert replayed_ways == [(w["switch"], w["resolved"]) for w in live["ways"]], train
    contradicted = {tr: runs[tr].runner.counters()["switches_contradicted"] for tr in networked}
    reported_wrong = {tr: {k: v for k, v in scenario.trains[tr].interlocking.items()
                           if v and scenario.trains[tr].route.ways().get(k, v) != v} for tr in networked}
    assert {tr: sorted(c) for tr, c in contradicted.items()} == {tr: sorted(w) for tr, w in reported_wrong.items()}


def test_a_recording_of_drivers_standard_messages_replays_through_the_standard_inputs(replayed):
    """bags/osm_drivers.mcap (scripts/record_drivers_bag.py): a train's drivers' standard messages
    only (NavSatFix from the NMEA log test/fixtures/osm_drivers.nmea, Imu, Odometry) and its truth,
    through the passing loop of the track imported from OSM. The NMEA path refuses the log's
    corrupt sentences by reason and the bag's fixes are the log's; the replay reads the messages
    as the standard_inputs node does, refuses the bad ones by reason, and its fused states hold
    the truth in every state, name the truth's track through the loop's switches and err by less
    than half a metre."""
    name, runs, reports, _, fused = replayed
    bag = BAGS / f"{name}.mcap"
    scenario = scenario_from_bag(bag)
    if not scenario.standard_inputs:
        pytest.skip(f"{name}: no standard inputs")
    with open(bag, "rb") as fh:
        summary = make_reader(fh).get_summary()
    types = {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
    assert types == {"/gnss/fix": "sensor_msgs/msg/NavSatFix", "/imu/data": "sensor_msgs/msg/Imu",
                     "/wheel/odometry": "nav_msgs/msg/Odometry", SCENARIO_TOPIC: "std_msgs/msg/String",
                     TRUTH_TOPIC: "train_localization_msgs/msg/TrainState"}
    records, refused = decode_log((ROOT / "test" / "fixtures" / "osm_drivers.nmea").read_bytes().splitlines())
    assert refused == {"checksum": 3, "truncated": 2}   # a GGA, a GST and an RMC with a bad checksum, a GGA and a GST cut
    fixes = [r for r in records if isinstance(r, NmeaFix)]
    recorded = [msg for _, _, _, msg in read_bag(bag, ["/gnss/fix"])]
    assert len(fixes) == len(recorded) == 298   # 300 epochs, two GGAs refused
    assert [(f.latitude, f.longitude, f.status) for f in fixes] == \
        [(m.latitude, m.longitude, m.status.status) for m in recorded]
    assert [m.position_covariance_type for m in recorded].count(0) == 2   # the epochs whose GST was refused
    run = runs["train"]
    assert run.rejected == {"nan": 1, "out_of_order": 1}   # the Imu with a NaN rate, the Odometry stamped back
    assert Counter(m.sensor for m in run.measurements) == {"dgps": 298, "gyro": 599, "wheel": 1199}
    report = reports["train"]
    assert report["integrity"]["inside_fraction"] == 1.0 and report["integrity"]["outside_count"] == 0, report
    assert report["position_error_m"]["n"] > 11000, report["position_error_m"]
    assert report["position_error_m"]["rms"] < 0.25 and report["position_error_m"]["max"] < 0.5, report
    net = recorded_network(fused, scenario.trains["train"], "/train")
    assert net["nominal_wrong_track"] == 0 and net["on_true_track"] == 1.0 and net["inside"] == 1.0, net
    assert [(w["switch"], w["way"], w["resolved"]) for w in net["ways"]] == [("W1", "B2", True)], net


def test_the_outside_scorer_uses_no_project_code():
    import ast
    tree = ast.parse((ROOT / "scripts" / "score_bag.py").read_text())
    imported = {alias.name.split(".")[0] for node in ast.walk(tree) if isinstance(node, ast.Import)
                for alias in node.names}
    imported |= {node.module.split(".")[0] for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    assert imported <= {"__future__", "argparse", "bisect", "json", "math", "sys", "collections", "yaml", "mcap",
                        "mcap_ros2"}, imported


def test_every_bag_scores_inside_per_train_from_the_mcap_file_alone(replayed):
    """An outside scorer (scripts/score_bag.py: mcap's ROS 2 decoder, no project code) finds the
    truth inside the published interval in >= 99.9 % of every train's states, none outside while
    NOMINAL and none NOMINAL on a wrong track: the truth is in the fused state's frame (on a
    network its section and chainage), a closed track's positions are wrapped in both streams. A
    recording of drivers' messages is scored in its offline replay's output. A train with ETCS
    location reports has the truth within its safe front ends in >= 99.9 % of them and, supervised
    to an end of authority, never passes it."""
    name, _, _, _, fused = replayed
    scores = outside_scorer().score_bag(str(fused))
    assert scores, f"{name}: no train with a truth and a fused state"
    claimed = {ns: s for ns, s in scores.items() if s["states"]}
    assert claimed, name
    for ns, s in claimed.items():
        assert s["inside"] >= 0.999 and s["nominal_outside"] == 0 and s["nominal_wrong_track"] == 0, (name, ns, s)
        etcs = s.get("etcs")
        if etcs:
            assert etcs["reports"] > 0 and etcs["etcs_inside"] >= 0.999 and etcs.get("overruns", 0) == 0, (name, ns, etcs)

"""Several trains on one line: the scenario format, wayside sensors seeing every train, the
association of wayside fixes with the trains, per-train integrity, and replay of a line bag."""
from __future__ import annotations

import functools
import math
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest

from train_localization.core.association import Associator
from train_localization.core.bagio import BagReader, BagWriter
from train_localization.core.fusion import MODE_INITIALISING, MODE_NOMINAL, Estimate
from train_localization.core.measurements import PositionFix, SectionOccupancy
from train_localization.core.offline import LineResult, replay_bag, simulate_scenario, wayside_pipelines
from train_localization.core.report import association_check, line_report
from train_localization.core.scenario import Scenario, ScenarioError

LINE = "config/scenario_line_pair.yaml"


def line_dict(**changes) -> dict:
    """config/scenario_line_pair.yaml: two trains following each other at 25 m/s, 250 m apart
    (front of the follower to the tail of the leader), 10 s; the follower has no balise reader:
    its position comes from the wayside fixes associated with it (heads and balises every 200 m)."""
    import yaml
    from train_localization.core import paths
    data = yaml.safe_load(paths.resolve(LINE).read_text())
    data.update(changes)
    return data


SHORT, LONGER = (train["vehicle"] for train in line_dict()["trains"])


@functools.lru_cache(maxsize=None)
def line_run() -> tuple[Scenario, LineResult, Path]:
    """The two-train line simulated once, with its bag."""
    sc = Scenario.from_yaml(LINE)
    bag = Path(tempfile.mkdtemp(prefix="tl_multitrain_")) / "line.mcap"
    return sc, simulate_scenario(sc, bag=bag), bag


# ---- scenario format ---------------------------------------------------------------------

def test_line_scenario_has_trains_with_their_own_vehicles_sensors_and_random_streams():
    sc = Scenario.from_dict(line_dict())
    assert sc.line and sc.train_names == ["lead", "follow"]
    lead, follow = sc.train("lead"), sc.train("follow")
    assert lead.vehicle.length == 60.0 and follow.vehicle.length == 80.0
    assert list(lead.sensors) == ["doppler_radar", "eurobalise_reader"] and list(follow.sensors) == ["wheel_sensor", "doppler_radar"]
    assert set(sc.wayside) == {"axle_counter"} and lead.wayside == sc.wayside
    # the same device on two trains draws two independent streams
    assert lead.rng("doppler_radar").normal() != follow.rng("doppler_radar").normal()
    assert lead.trajectory().position[0] == 560.0
    with pytest.raises(ScenarioError, match="several trains"):
        sc.trajectory()
    with pytest.raises(ScenarioError, match="no train 'x'"):
        sc.train("x")


def test_one_train_scenario_is_the_train_named_train():
    sc = Scenario.from_yaml("config/scenario_conventional_300.yaml")
    assert not sc.line and sc.train_names == ["train"] and sc.train("train") is sc and sc.wayside == {}


@pytest.mark.parametrize("change, message", [
    (lambda d: d["trains"][1].update(name="lead"), "used twice"),
    (lambda d: d["trains"][1].update(name="wayside"), "name 'wayside' must be"),
    (lambda d: d["trains"][1].update(name="2nd"), "name '2nd' must be"),
    (lambda d: d["trains"][1]["initial"].update(position=530.0), "overlap at the start"),
    (lambda d: d["trains"][1]["initial"].update(position=4500.0), "off the track"),
    (lambda d: d["wayside"]["sensors"].update(wheel_sensor={}), "wheel_sensor is on-board equipment"),
    (lambda d: d["trains"][0]["sensors"].update(axle_counter={}), "axle_counter is wayside equipment"),
    (lambda d: d["wayside"]["sensors"].update(flux_meter={}), "unknown sensor 'flux_meter'"),
    (lambda d: d.update(trains=[]), "non-empty list"),
    (lambda d: d["trains"][0].pop("profile"), "lacks the key 'profile'"),
])
def test_line_scenario_errors_are_one_line(change, message):
    data = line_dict()
    change(data)
    with pytest.raises(ScenarioError, match=message) as err:
        Scenario.from_dict(data)
    assert "\n" not in str(err.value)


def test_trains_facing_each_other_do_not_overlap_at_the_start():
    data = line_dict()
    # the second train runs the other way: its tail (80 m above its front at 490 m) reaches into
    # the leader (500..560 m)
    data["trains"][1].update(initial={"position": 490.0}, profile=[{"speed": -10.0}])
    with pytest.raises(ScenarioError, match="overlap"):
        Scenario.from_dict(data)
    data["trains"][1]["initial"]["position"] = 3000.0
    assert Scenario.from_dict(data).train("follow").orientation() == -1


# ---- wayside sensors see every train -----------------------------------------------------

def test_axle_counter_counts_every_axle_of_both_trains():
    sc, result, _ = line_run()
    heads = np.array([h["position"] for h in sc.track.items("axle_counter_head")])

    def axles_at(t):
        """True axle chainages of every train at t."""
        out = []
        for name, run in result.trains.items():
            tt = [s.stamp for s in run.truth]
            front = np.interp(t, tt, [s.position for s in run.truth])
            out.append(front - np.asarray(sc.train(name).vehicle.axles))
        return np.concatenate(out)

    # the last report with no axle within 1 m of a head (one being counted)
    occ = next(m for m in reversed(result.wayside) if isinstance(m, SectionOccupancy)
               and np.min(np.abs(axles_at(m.stamp)[:, None] - heads[None, :])) > 1.0)
    assert occ.stamp > 35.0
    # every axle of both trains that has passed a head is counted into the section beyond it
    # (the region beyond the last head is not a section)
    axles = axles_at(occ.stamp)
    expected = [int(np.count_nonzero(axles > heads[k])) for k in range(heads.size - 1)]
    assert [s.axles_in for s in occ.sections] == expected
    assert expected[0] == len(SHORT["axles"]) + len(LONGER["axles"]) and expected[2] > len(SHORT["axles"])
    first = occ.sections[0]
    assert first.axles_out == first.axles_in and first.state == 0   # CLEAR after both trains


# ---- association -------------------------------------------------------------------------

def _est(t, lo, hi, v=25.0, sd_v=0.1, mode=MODE_NOMINAL):
    mid = 0.5 * (lo + hi)
    return Estimate(t, mid, v, 0.0, (hi - lo) / 6.6, sd_v, lo, hi, 0.999, mode, {})


def _fix(position, t=10.0, sd=0.5, direction=1, track="test_line"):
    return PositionFix(t, "axle_counter", "axle_counter", track, "AC01", position, sd, direction)


def test_association_delivers_to_the_train_that_explains_and_counts_the_rest():
    # two trains close together: "a" around 1000 m, "b" 30 m behind it, "c" running the other way
    est = {"a": [_est(9.99, 995.0, 1005.0), _est(10.0, 995.25, 1005.25)],
           "b": [_est(9.99, 960.0, 985.0), _est(10.0, 960.25, 985.25)],
           "c": [_est(9.99, 1000.0, 1010.0, v=-25.0), _est(10.0, 999.75, 1009.75, v=-25.0)]}
    assoc = Associator(est, {"a": "test_line", "b": "test_line", "c": "test_line"})
    assert assoc.associate(_fix(1001.0)) == "a"          # only a (c runs the other way)
    assert assoc.associate(_fix(970.0)) == "b"
    assert assoc.associate(_fix(1005.0, direction=-1)) == "c"
    # on purpose: a fix between a and b whose 1-sigma reaches both intervals
    assert assoc.associate(_fix(990.0, sd=2.0)) is None
    assert assoc.decisions[-1].candidates == ("a", "b")
    assert assoc.associate(_fix(1100.0)) is None          # nobody there
    assert assoc.associate(_fix(1001.0, track="other")) is None
    assert dict(assoc.counts) == {"used": 3, "ambiguous": 1, "unexplained": 2}
    assert dict(assoc.delivered) == {"a": 1, "b": 1, "c": 1}
    # a fix stamped after the last state: the interval is carried on by the fused speed
    assert assoc.associate(_fix(1018.0, t=10.5)) == "a"


def test_a_train_without_a_position_is_ruled_out_only_by_its_direction():
    est = {"a": [_est(10.0, 995.0, 1005.0)],
           "b": [_est(10.0, math.nan, math.nan, mode=MODE_INITIALISING)],
           "c": [_est(10.0, math.nan, math.nan, v=-20.0, mode=MODE_INITIALISING)]}
    assoc = Associator(est, {"a": "test_line", "b": "test_line", "c": "test_line"})
    assert assoc.associate(_fix(1000.0)) is None and assoc.decisions[-1].candidates == ("a", "b")
    assert assoc.associate(_fix(3000.0)) == "b"
    assert assoc.associate(_fix(3000.0, direction=-1)) == "c"
    with pytest.raises(ValueError, match="unknown association setting"):
        Associator.for_trains(est, {}, {"gates": 3})


def test_two_close_trains_get_their_own_wayside_fixes():
    sc, result, _ = line_run()
    check = association_check(result)
    # both trains get head passages; none goes to the wrong train, each lies within 3.3 sigma of
    # its train's true front
    assert check["delivered"].get("lead", 0) >= 2 and check["delivered"].get("follow", 0) >= 3
    assert check["wrong_train"] == 0
    assert check["error_over_sigma_max"] < 3.3
    # until the follower has a position (it has no balise reader), the leader's passages are
    # ambiguous: the follower cannot be ruled out
    assert check["ambiguous"] >= 1
    assert check["used"] + check["ambiguous"] + check["unexplained"] == check["offered"]
    first_follow = min(d.fix.stamp for d in result.associator.decisions if d.train == "follow")
    assert all(d.fix.stamp <= first_follow + 1.0 for d in result.associator.decisions if d.outcome == "ambiguous")


def test_each_train_keeps_its_integrity():
    sc, result, _ = line_run()
    report = line_report(result)
    for name, rep in report["trains"].items():
        it = rep["integrity"]
        assert rep["states_with_position"] > 0.4 * rep["states"], name
        assert it["inside_fraction"] >= 0.999, (name, it)
        # the leader's radar is its only speed source: its interval covers a radar scale fault
        # over the distance since the last fix (3.29 x 5 % of up to 200 m each side); the
        # follower's three wayside axle-counter fixes (1-sigma 1 m) may share an offset up to
        # the gate's radius, 3.89 m (core/fusion/impact.py): 8.4 m without that hypothesis
        bound = 3.29 * 0.05 * 200.0 if name == "lead" else 16.0
        assert it["mean_interval_width_m"] < bound, (name, it)
    # the follower's position comes from the associated wayside fixes only
    follow = result.trains["follow"]
    assert {m.sensor for m in follow.measurements if isinstance(m, PositionFix)} == {"axle_counter"}


@pytest.mark.parametrize("parallel, cpus, statistics", [(False, None, True), (True, None, True), (True, 4, True),
                                                        (True, 4, False)],
                         ids=["serial", "parallel", "parallel-3-workers", "parallel-no-statistics"])
def test_line_bag_replays_to_the_same_estimates(parallel, cpus, statistics, monkeypatch):
    """The same estimates serial and in worker processes; with several workers their windows
    merge back into the bag's order (one worker per CPU besides the fusion's), also where
    the bag's summary has no message counts to share the topics out by."""
    if cpus:
        monkeypatch.setattr(os, "cpu_count", lambda: cpus)
    if not statistics:
        def no_statistics(path):
            raise AttributeError("'NoneType' object has no attribute 'channel_message_counts'")
        monkeypatch.setattr("train_localization.core.bagio.topic_counts", no_statistics)
    sc, result, bag = line_run()
    replayed = replay_bag(bag, parallel=parallel)
    assert isinstance(replayed, LineResult) and set(replayed.trains) == {"lead", "follow"}
    for name, run in result.trains.items():
        again = replayed.trains[name]
        assert again.measurements == run.measurements and again.blocks == run.blocks
        assert len(again.estimates) == len(run.estimates)
        a = np.array([(e.position, e.position_min, e.position_max) for e in run.estimates])
        b = np.array([(e.position, e.position_min, e.position_max) for e in again.estimates])
        assert np.array_equal(np.isnan(a), np.isnan(b)) and np.allclose(a[~np.isnan(a)], b[~np.isnan(b)])
    assert replayed.associator.summary() == result.associator.summary()


@pytest.mark.parametrize("parallel", [False, True], ids=["serial", "parallel"])
def test_a_malformed_truth_message_of_a_line_is_counted_with_its_train(parallel, tmp_path):
    """One of the follower's truth messages cut short: refused as malformed and counted in
    that train's ``rejected``; the rest of the replay is as before."""
    sc, result, bag = line_run()
    broken = tmp_path / "broken.mcap"
    cut = None
    with BagReader(bag) as reader, BagWriter(broken) as writer:
        for topic, typename, t_ns, data in reader.cdr():
            if cut is None and topic == "/follow/ground_truth/state" and t_ns > 1_000_000_000:
                cut, data = t_ns, bytes(data)[:10]
            writer.write_cdr(topic, typename, bytes(data), t_ns)
    replayed = replay_bag(broken, parallel=parallel)
    assert cut is not None
    assert replayed.trains["follow"].rejected == {"malformed": 1}
    assert not replayed.trains["lead"].rejected
    assert len(replayed.trains["follow"].truth) == len(result.trains["follow"].truth) - 1
    assert len(replayed.trains["follow"].estimates) == len(result.trains["follow"].estimates)


def test_wayside_pipelines_take_every_train_and_refuse_an_unknown_one():
    sc = Scenario.from_dict(line_dict())
    (topic, pipe), = wayside_pipelines(sc).items()
    assert topic == "/wayside/sensors/axle_counter/raw"
    state = sc.train("lead").trajectory().state_at(0.0)
    assert pipe.on_truth(state, "lead") == []     # blocks wait for the other train
    from train_localization.core.signals import InputRejected
    with pytest.raises(InputRejected, match="train 'ghost'"):
        pipe.on_truth(state, "ghost")


# ---- nodes -------------------------------------------------------------------------------

def test_for_namespace_gives_each_node_its_part_and_line_graph_lists_them(tmp_path):
    sc = Scenario.from_dict(line_dict())
    assert sc.for_namespace("/follow") is sc.train("follow")
    wayside = sc.for_namespace("/wayside")
    assert set(wayside.sensors) == {"axle_counter"} and wayside.vehicle.axles == ()   # two layouts: none
    with pytest.raises(ScenarioError, match="names no train"):
        sc.for_namespace("/train")
    one = Scenario.from_yaml("config/scenario_demo.yaml")
    assert one.for_namespace("/anything") is one
    path = tmp_path / "line.yaml"
    import yaml
    path.write_text(yaml.safe_dump(line_dict()))
    from train_localization.graph import line_graph
    graph = line_graph(str(path), str(tmp_path / "bag"))
    where = {(ns, name) for ns, _, name, _ in graph}
    assert {("/lead", "doppler_radar"), ("/lead", "eurobalise_reader"), ("/lead", "fusion"),
            ("/follow", "wheel_sensor"), ("/follow", "doppler_radar"), ("/follow", "fusion"),
            ("/wayside", "axle_counter"), ("/wayside", "association"), ("/", "simulator"),
            ("/", "recorder")} == where
    fusion = next(p for ns, _, name, p in graph if (ns, name) == ("/follow", "fusion"))
    assert sorted(fusion["sensors"]) == ["axle_counter", "doppler", "wheel"]   # its own and the wayside


def test_line_nodes_simulator_wayside_counter_and_association(ros_context, start_node, tmp_path):
    """The simulator of a line publishes each train's truth in its namespace and the wayside raw
    blocks; a wayside axle-counter node in /wayside decodes them in ingest mode; the association
    node in /wayside sends each wayside fix to the namespace of the one train whose published fused
    state explains it, and none for an ambiguous one."""
    import os
    import subprocess
    import sys
    import yaml
    from conftest import spin_until
    from diagnostic_msgs.msg import DiagnosticArray
    from train_localization.core import convert
    from train_localization.nodes.common import STREAM_QOS, rclpy_classes
    path = tmp_path / "line.yaml"
    path.write_text(yaml.safe_dump(line_dict(duration=8.0)))   # no head passage before 9 s
    log = open(tmp_path / "association.log", "w")
    assoc = subprocess.Popen([sys.executable, "-c", "from train_localization.nodes.association import main; main()",
                              "--ros-args", "-r", "__ns:=/wayside", "-p", f"scenario:={path}"],
                             stdout=log, stderr=subprocess.STDOUT, start_new_session=True, env=dict(os.environ))
    counter = start_node("axle_counter", "--ros-args", "-r", "__ns:=/wayside", "-p", "mode:=ingest",
                         "-p", f"scenario:={path}")
    mc = rclpy_classes()
    node = ros_context.create_node("line_probe")
    got: dict[str, int] = {}
    routed: dict[str, list] = {"lead": [], "follow": []}
    try:
        topics = {"/lead/ground_truth/state": mc.TrainState, "/follow/ground_truth/state": mc.TrainState,
                  "/follow/sensors/wheel/raw": mc.RawBlock, "/wayside/sensors/axle_counter/raw": mc.RawBlock,
                  "/wayside/wayside/sections": mc.SectionOccupancy}
        for topic, cls in topics.items():
            node.create_subscription(cls, topic, lambda msg, topic=topic: got.__setitem__(topic, got.get(topic, 0) + 1),
                                     STREAM_QOS)
        states = {name: node.create_publisher(mc.TrainState, f"/{name}/localization/state", STREAM_QOS)
                  for name in routed}
        fixes = node.create_publisher(mc.PositionFix, "/wayside/sensors/axle_counter/position", STREAM_QOS)
        association_status: dict[str, str] = {}   # the association's last diagnostics, for a failure message
        node.create_subscription(DiagnosticArray, "/diagnostics", lambda msg: association_status.update(
            {kv.key: kv.value for st in msg.status if "association" in st.name for kv in st.values}), 10)
        for name in routed:
            node.create_subscription(mc.PositionFix, f"/{name}/sensors/axle_counter/position",
                                     lambda msg, name=name: routed[name].append(msg.position), STREAM_QOS)
        # the counter listens to the raw blocks and publishes the sections, the association listens
        # to the fixes and the fused states and publishes each train's routed fixes, before the
        # simulator starts (a routed fix sent before the association's publisher has matched the
        # probe is lost: the topics are volatile)
        ready = [lambda: node.count_subscribers("/wayside/sensors/axle_counter/raw") >= 2,
                 lambda: node.count_publishers("/wayside/wayside/sections") >= 1,
                 *(lambda p=p: p.get_subscription_count() >= 1 for p in [*states.values(), fixes]),
                 *(lambda name=name: node.count_publishers(f"/{name}/sensors/axle_counter/position") >= 1
                   for name in routed)]
        assert spin_until(node, lambda: all(f() for f in ready), timeout=60.0), \
            (counter.output(), (tmp_path / "association.log").read_text())
        # five subscribers: the probe's four topics and the axle counter's raw blocks; paced at
        # 2x real time: a flood at full speed can outrun the DDS buffers of a loaded machine and
        # lose raw blocks, which is not what this test is about
        sim = start_node("simulator", "--ros-args", "-p", f"scenario:={path}", "-p", "rate:=2.0",
                         "-p", "start_delay:=0.5", "-p", "wait_for_subscribers:=5")
        # the line runs first (ground truth and raw blocks to the end, sections decoded), which also
        # gives discovery between the probe and the association seconds to settle on a loaded machine
        ran = spin_until(node, lambda: min(got.get("/lead/ground_truth/state", 0),
                                           got.get("/follow/ground_truth/state", 0)) >= 801
                         and got.get("/wayside/wayside/sections", 0) >= 5, timeout=60.0)
        assert ran, "\n".join([f"received {got}", sim.output()[-2000:], counter.output()[-2000:]])
        assert got["/wayside/sensors/axle_counter/raw"] >= 150 and got["/follow/sensors/wheel/raw"] >= 150
        # lead around 1000 m, follow around 960 m (intervals 10 m wide), both at 25 m/s
        for k in range(11):
            t = 9.0 + 0.1 * k
            for name, front in (("lead", 1000.0), ("follow", 960.0)):
                s = front + 25.0 * (t - 10.0)
                states[name].publish(convert.train_state_to_msg(mc, t, "test_line", s, 25.0, 0.0, 1.5, 0.1,
                                                                s - 5.0, s + 5.0, 0.999, MODE_NOMINAL, []))
        spin_until(node, lambda: False, timeout=0.3)
        for position, sd in ((1001.0, 0.5), (962.0, 0.5), (980.0, 5.0), (1003.0, 0.5)):
            fixes.publish(convert.measurement_to_msg(_fix(position, t=10.0, sd=sd), mc))
        done = spin_until(node, lambda: len(routed["lead"]) >= 2 and len(routed["follow"]) >= 1, timeout=30.0)
        assert done, "\n".join([f"routed {routed}; association diagnostics {association_status}",
                                 (tmp_path / "association.log").read_text()[-2000:]])
        spin_until(node, lambda: False, timeout=0.3)
        assert routed == {"lead": [1001.0, 1003.0], "follow": [962.0]}   # 980 m: ambiguous, not sent
    finally:
        node.destroy_node()
        assoc.terminate()
        assoc.wait(timeout=10)
        log.close()


def test_a_track_circuit_is_shunted_by_any_train():
    """Wayside track circuits on a line: the receivers of the circuits holding either train drop,
    the others stay at their clear level (the axles of both trains shunt the same rails)."""
    from train_localization.core.pipeline import SensorPipeline
    from train_localization.core.scenario import TruthState
    from train_localization.core.sensors import spec
    from train_localization.core.sensors.track_circuit import PARAMS
    sc = Scenario.from_yaml("config/scenario_line_highspeed.yaml")
    a, d = sc.train("train_a").vehicle, sc.train("train_d").vehicle
    pipe = SensorPipeline(spec("track_circuit_receiver"), {}, sc.track, a, sc.rng("tc"), fleet={"a": a, "d": d})
    fronts = {"a": 2800.0, "d": 7000.0}          # in TC01 (2000-3500) and TC04 (6500-8000)
    blocks = []
    for k in range(21):
        for name, front in fronts.items():
            blocks += pipe.on_truth(TruthState(k * 0.01, front, 0.0, 0.0), name)
    level = np.concatenate([b.data for b in blocks]).mean(axis=0)
    low = [c.split(".")[0] for c, v in zip(blocks[0].channels, level) if v < PARAMS["threshold_drop"].default]
    assert low == ["TC01", "TC04"]
    assert level.max() > PARAMS["threshold_pick"].default

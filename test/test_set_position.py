"""An operator's position (localization/set_position) on a network: a chainage on a named
section, or a route distance said back as the section and chainage it is; ambiguous or
unplaceable input refused in one line (core/network/hypotheses.py ``operator_start``;
nodes/fusion.py ``on_set_position``). Issue 48: a route distance restarted the train on the
route's first section, silently (T1 DEGRADED, then LOST, while the train was on T2)."""
from __future__ import annotations

from functools import lru_cache

import pytest

from conftest import ROOT, ask, spin_until
from train_localization.core.network.path import PathStep, TrackPath
from train_localization.core.offline import fusion_runner, scenario_measurements
from train_localization.core.scenario import Scenario
from train_localization.core.signals import InputRejected

RATE = 50.0   # [Hz] of the runner's states


@lru_cache(maxsize=None)
def north():
    """The north train of the throat (route T1, T2: straight through W1), its arrivals to 80 s."""
    sc = Scenario.from_yaml(str(ROOT / "config" / "scenario_throat.yaml")).train("north")
    return sc, tuple(scenario_measurements(sc, t_end=80.0))


@lru_cache(maxsize=None)
def trajectory():
    return north()[0].trajectory()


def fused_until(t_end: float, runner=None, t_start: float = 0.0):
    """The north train's fusion fed its arrivals in (t_start, t_end] [s]; (runner, estimates)."""
    sc, arrivals = north()
    runner = runner or fusion_runner(sc, RATE)
    estimates = []
    for arrival, m in arrivals:
        if t_start < arrival <= t_end:
            estimates += [e for e, _ in runner.advance(arrival)]
            runner.add(m)
    estimates += [e for e, _ in runner.advance(t_end)]
    return runner, estimates


def truth_at(t: float) -> float:
    """The north train's route distance [m] at t [s] (its truth is the route-line chainage)."""
    return trajectory().state_at(t).position + north()[0].route.begin


def test_a_chainage_on_a_section_of_the_route_restarts_the_train_there():
    """At 60 s the train is on T2: a restart on T2 at its true chainage puts every later state on
    T2 with the truth inside the interval (not on T1, the route's first section)."""
    sc, _ = north()
    runner, _ = fused_until(60.0)
    s = truth_at(60.0)
    section, chainage = sc.route.locate(s)
    assert section == "T2"
    start = runner.filter.operator_start(chainage, "T2", sc.route)
    assert (start.section, start.direction, start.position) == ("T2", 1, pytest.approx(s))
    speed = trajectory().state_at(60.0).speed
    runner.filter.reset(start.position, 1.0, speed, 0.1, 60.0, start)
    _, after = fused_until(80.0, runner, 60.0)
    assert len(after) >= 0.99 * 20.0 * RATE
    for e in after:
        truth = sc.route.locate(truth_at(e.stamp))
        assert e.track_id == truth[0] == "T2", e
        assert e.position_min <= truth[1] <= e.position_max, e
    assert after[-1].mode == 1


def test_a_route_distance_is_said_back_as_the_section_and_chainage_it_is():
    sc, _ = north()
    runner, _ = fused_until(5.0)
    start = runner.filter.operator_start(1200.0, "", sc.route)
    assert (start.section, start.chainage, start.position, start.origin) == ("T2", 200.0, 1200.0, 1000.0)
    assert start.describe() == "section T2, chainage 200.000 m, running along its chainage (route distance " \
                               "1200.000 m)"
    start = runner.filter.operator_start(450.0, "", sc.route)
    assert (start.section, start.chainage) == ("T1", 450.0)


def test_a_section_off_the_route_but_on_a_track_hypothesis_is_taken():
    """Approaching W1 the fusion grows a hypothesis through the crossover T3: the operator may
    name it though the route does not (a train sent the other way)."""
    sc, arrivals = north()
    runner = fusion_runner(sc, RATE)
    for arrival, m in arrivals:
        runner.advance(arrival)
        runner.add(m)
        if any(st.section == "T3" for h in runner.filter.hyps for st in h.path.steps):
            break
    else:
        pytest.fail("no hypothesis through T3")
    start = runner.filter.operator_start(20.0, "T3", sc.route)
    assert (start.section, start.direction, start.chainage) == ("T3", 1, 20.0)
    assert start.position == pytest.approx(1020.0)


@pytest.mark.parametrize("position, section, reason, message", [
    (100.0, "T6", "off_route", "section T6 is neither on the train's route (T1, T2) nor on a track hypothesis (T1)"),
    (100.0, "T99", "wrong_track", "section 'T99' is no section of network throat"),
    (1500.0, "T2", "off_track", "chainage 1500.000 m is off section T2 (0 .. 1400.000 m)"),
    (-1.0, "T1", "off_track", "chainage -1.000 m is off section T1 (0 .. 1000.000 m)"),
    (2500.0, "", "off_track", "route distance 2500.000 m is off the route (0.000 .. 2400.000 m along T1, T2)"),
])
def test_a_position_that_cannot_be_placed_is_refused_in_one_line(position, section, reason, message):
    sc, _ = north()
    runner, _ = fused_until(5.0)
    with pytest.raises(InputRejected) as err:
        runner.filter.operator_start(position, section, sc.route)
    assert err.value.reason == reason and message in str(err.value) and "\n" not in str(err.value)


def test_a_section_the_route_passes_twice_is_ambiguous():
    """A route that comes back along T2 (a reversal at the platform's end): a chainage on T2 is
    two places of the route; refused, the route distance says which."""
    sc, _ = north()
    runner, _ = fused_until(5.0)
    back = TrackPath(sc.route.network, sc.route.steps + (PathStep("T2", -1, sc.route.end, 1400.0),))
    with pytest.raises(InputRejected, match="the route passes section T2 2 times: give the route distance") as err:
        runner.filter.operator_start(200.0, "T2", back)
    assert err.value.reason == "ambiguous"
    start = runner.filter.operator_start(3000.0, "", back)
    assert (start.section, start.direction, start.chainage) == ("T2", -1, pytest.approx(800.0))


def test_set_position_over_dds_on_a_network_and_on_a_single_line(ros_context, start_node):
    """The live fusion of the throat's north train: a chainage on T2 restarts it there (its
    states name T2), a route distance is said back as T2's chainage, T6 is refused; a single
    line's fusion refuses a section_id other than its track's."""
    from train_localization_msgs.msg import TrainState
    from train_localization_msgs.srv import SetPosition
    from train_localization.nodes.common import STREAM_QOS
    scenario = str(ROOT / "config" / "scenario_throat.yaml")
    net = start_node("fusion", "--ros-args", "-r", "__ns:=/north", "-p", f"scenario:={scenario}",
                     "-p", "publish_rate:=20.0")
    line = start_node("fusion", "--ros-args", "-r", "__ns:=/single", "-p", "sensors:=[eurobalise]",
                      "-p", "publish_rate:=20.0")
    node = ros_context.create_node("probe_set_position")
    states = []
    node.create_subscription(TrainState, "/north/localization/state", states.append, STREAM_QOS)
    clients = {ns: node.create_client(SetPosition, f"/{ns}/localization/set_position") for ns in ("north", "single")}
    try:
        assert spin_until(node, lambda: all(c.service_is_ready() for c in clients.values()), 60.0), \
            net.output() + line.output()

        def request(ns, position, section_id, speed=0.0):
            reply = ask(node, clients[ns], SetPosition.Request(position=position, section_id=section_id,
                                                               position_stddev=1.0, speed=speed, speed_stddev=0.1))
            assert reply is not None
            return reply
        reply = request("north", 1200.0, "")
        assert reply.success and reply.message == "position set to section T2, chainage 200.000 m, running along " \
                                                  "its chainage (route distance 1200.000 m)", reply.message
        reply = request("north", 100.0, "T6")
        assert not reply.success and reply.message.startswith("refused: off_route: section T6 is neither on the "
                                                              "train's route (T1, T2)"), reply.message
        reply = request("north", 300.0, "T2", speed=-5.0)
        assert reply.success and "section T2, chainage 300.000 m" in reply.message, reply.message
        n = len(states)
        assert spin_until(node, lambda: len(states) > n + 5, 20.0), net.output()
        last = states[-1]
        assert last.track_id == "T2" and last.position_min <= 300.0 <= last.position_max + 5.0, last
        assert last.speed < 0.0   # along T2's chainage, as given
        reply = request("single", 500.0, "T2")
        assert not reply.success and reply.message == "refused: wrong_track: section_id 'T2' is not this fusion's " \
                                                      "track 'conventional_line'", reply.message
        reply = request("single", 500.0, "conventional_line")
        assert reply.success and reply.message == "position set to 500.000 m", reply.message
        assert net.interrupt() == 0 and line.interrupt() == 0
    finally:
        node.destroy_node()

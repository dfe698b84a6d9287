"""Simulator node: publishes /clock and ground_truth/state from a scenario.

Parameters:
  scenario (string, required)  scenario YAML (config/scenario_*.yaml or a path)
  rate (double, 1.0)           speed-up over real time; 0 = as fast as possible
  start_delay (double, 1.0)    wall-clock seconds to wait before t = 0 (lets
                               subscribers connect)
  exit_at_end (bool, true)     shut the node down after the last state
  wait_for_subscribers (int, 0)  before starting, wait (at most 60 s) until
                               ground_truth/state has this many subscribers
  wait_for_publisher (string, "")  and until this topic has a publisher (the
                               demo graph: the fusion's localization/state, so that
                               the fused states start with the scenario); "" = none
Topics: /clock (rosgraph_msgs/Clock), ground_truth/state (TrainState, stddevs 0,
interval = position), scenario (std_msgs/String, transient-local: the scenario
YAML with the track inlined, so that a recorded bag describes itself), /diagnostics.
A train on a network (docs/network.md): its truth is in the fused state's frame (track_id the
section the front is on, position its chainage there) with its route (route_id
``<network>:<train>``), the distance along it and its direction there; and interlocking/switches (SwitchPositions, transient-local) gives
the switch positions the interlocking reports for its route.

A line (several trains, core/scenario.py): every train's truth on
``/<train>/ground_truth/state``, the scenario on ``/scenario``, and the simulated raw
blocks of every train's on-board sensors on ``/<train>/sensors/<sensor>/raw`` and of
the wayside sensors (which see every train) on ``/wayside/sensors/<sensor>/raw``
(core/offline/line.py LineSimulation): the sensor nodes of a line run in ingest mode, each
in its train's namespace or in /wayside. ``wait_for_subscribers`` then counts the
subscribers of all its truth and raw topics together.

A scenario with ``control`` (closed loop, core/control.py) has no profile: the simulator
subscribes control/traction (std_msgs/Float64, thrust [N], from the speed_controller node)
and control/brake (std_msgs/Float64, friction brake demand 0..1) and integrates the vehicle's
dynamics (core/dynamics.py) with the latest commands at every truth step; a non-finite
command is refused and counted (the last good one stays).
"""
from __future__ import annotations

import math
import threading
import time

from rosgraph_msgs.msg import Clock
from rclpy.node import Node

from ..core.convert import raw_block_to_msg, sec_to_ns, switch_positions_to_msg, truth_to_msg
from ..core.sensors.base import Param
from .common import (CLOCK_QOS, LATCHED_QOS, STREAM_QOS, ConfigurationError, Diagnostics, declare_param,
                     rclpy_classes, required_scenario, spin)


# the node's parameters (tools/docs.py writes them into config/params/simulator.yaml)
PARAMS = {
    "scenario": Param("", "scenario YAML file"),
    "rate": Param(1.0, "speed-up over real time; 0 = as fast as possible"),
    "start_delay": Param(1.0, "wall seconds before t = 0 [s]"),
    "exit_at_end": Param(True, "shut down after the last state"),
    "wait_for_subscribers": Param(0, "subscribers of ground_truth/state to wait for"),
    "wait_for_publisher": Param("", "a topic that must have a publisher before the start (e.g. "
                                    "localization/state); empty: none"),
}


class SimulatorNode(Node):
    def __init__(self):
        super().__init__("simulator")
        self.scenario = required_scenario(self, PARAMS, "a scenario YAML file")
        self.rate = float(declare_param(self, PARAMS, "rate"))
        self.start_delay = float(declare_param(self, PARAMS, "start_delay"))
        self.exit_at_end = bool(declare_param(self, PARAMS, "exit_at_end"))
        self.wait_for = int(declare_param(self, PARAMS, "wait_for_subscribers"))
        self.wait_for_publisher = str(declare_param(self, PARAMS, "wait_for_publisher"))
        if not self.rate >= 0.0:
            raise ConfigurationError(f"parameter 'rate' must be >= 0 (0: as fast as possible), not {self.rate}")
        self.dynamics = None
        if self.scenario.control and self.scenario.line:
            raise ConfigurationError("a closed-loop scenario (control) runs one train, not a line")
        if self.scenario.control:
            from std_msgs.msg import Float64

            from ..core.dynamics import Dynamics
            self.dynamics = Dynamics(self.scenario.dynamics, self.scenario.track, self.scenario.start_position,
                                     self.scenario.start_speed)
            self.create_subscription(Float64, "control/traction", self.on_traction, STREAM_QOS)
            self.create_subscription(Float64, "control/brake", self.on_brake, STREAM_QOS)
        self.mc = rclpy_classes()
        self.clock_pub = self.create_publisher(Clock, "/clock", CLOCK_QOS)
        from std_msgs.msg import String
        self.line = None
        if self.scenario.line:
            from ..core.offline import LINE_SCENARIO_TOPIC, LineSimulation
            self.line = LineSimulation(self.scenario)
            self.truth_pubs = {name: self.create_publisher(self.mc.TrainState, f"{ns}/ground_truth/state",
                                                           STREAM_QOS)
                               for name, ns in self.line.namespaces.items()}
            topics = [f"{self.line.namespaces[name]}/sensors/{pipe.spec.sensor}/raw"
                      for name, pipes in self.line.pipes.items() for pipe in pipes] + list(self.line.wayside)
            self.raw_pubs = {topic: self.create_publisher(self.mc.RawBlock, topic, STREAM_QOS) for topic in topics}
            self.truth_pub = next(iter(self.truth_pubs.values()))
            self.scenario_pub = self.create_publisher(String, LINE_SCENARIO_TOPIC, LATCHED_QOS)
        else:
            if self.dynamics is None:
                self.trajectory = self.scenario.trajectory()
            self.truth_pub = self.create_publisher(self.mc.TrainState, "ground_truth/state", STREAM_QOS)
            self.scenario_pub = self.create_publisher(String, "scenario", LATCHED_QOS)
        self.scenario_pub.publish(String(data=self.scenario.to_yaml()))
        # trains on a network: the switch positions the interlocking reports for each (latched)
        self.interlocking_pubs = []
        for name, train in self.scenario.trains.items():
            if train.network is not None:
                ns = self.line.namespaces[name] if self.line is not None else ""
                pub = self.create_publisher(self.mc.SwitchPositions, f"{ns}/interlocking/switches".lstrip("/"),
                                            LATCHED_QOS)
                pub.publish(switch_positions_to_msg(self.mc, 0.0, train.interlocking))
                self.interlocking_pubs.append(pub)
        self.diag = Diagnostics(self, "simulator")
        # the simulator makes the time (/clock) and runs on the wall clock: its reports are
        # stamped in the simulated time like every other node's
        self.sim_time = 0.0
        self.diag.clock = lambda: self.sim_time
        self.diag.values["scenario"] = self.scenario.name
        self.finished = False
        self.published = 0
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._stop = threading.Event()
        self._thread.start()

    def _run(self):
        sc = self.scenario
        n = int(round(sc.duration * sc.truth_rate)) + 1
        deadline = time.monotonic() + 60.0
        while (self._subscribers() < self.wait_for or self.wait_for_publisher
               and not self.count_publishers(self.wait_for_publisher)) and time.monotonic() < deadline:
            self._stop.wait(0.05)
        subs = [i.node_name for i in self.get_subscriptions_info_by_topic(self.truth_pub.topic_name)]
        self.get_logger().info(f"starting scenario '{sc.name}' with {self.truth_pub.get_subscription_count()} "
                               f"truth subscribers {subs} after {time.monotonic() - deadline + 60.0:.1f} s")
        self._stop.wait(self.start_delay)
        wall0 = time.monotonic()
        for k in range(n):
            if self._stop.is_set():
                return
            t = k / sc.truth_rate
            if self.rate > 0:
                lag = wall0 + t / self.rate - time.monotonic()
                if lag > 0:
                    self._stop.wait(lag)
            clock = Clock()
            clock.clock.sec, clock.clock.nanosec = divmod(sec_to_ns(t), 1_000_000_000)
            self.clock_pub.publish(clock)
            if self.line is not None:
                self._publish_line(k)
            else:
                if self.dynamics is not None:
                    if k:
                        self.dynamics.step(1.0 / sc.truth_rate)
                    st = self.dynamics.state(t)
                else:
                    st = self.trajectory.state_at(t)
                self.truth_pub.publish(truth_to_msg(self.mc, st, sc.track))
            self.published += 1
            self.sim_time = t
            self.diag.values["sim_time"] = f"{t:.2f}"
        self.diag.set_status(0, "scenario finished")
        self.get_logger().info(f"scenario '{sc.name}' finished: {self.published} states")
        if self.exit_at_end:
            self._stop.wait(0.5)
            self.finished = True

    def _subscribers(self) -> int:
        """Subscribers of the truth (of a line: of every truth and raw topic, summed)."""
        if self.line is None:
            return self.truth_pub.get_subscription_count()
        pubs = [*self.truth_pubs.values(), *self.raw_pubs.values()]
        return sum(pub.get_subscription_count() for pub in pubs)

    def _publish_line(self, k: int) -> None:
        """Truth step k of a line: every train's truth, then the raw blocks completed."""
        t, truths, blocks = self.line.step(k)
        for name, st in truths.items():
            self.truth_pubs[name].publish(truth_to_msg(self.mc, st, self.scenario.trains[name].track))
        for ns, _, block in blocks:
            self.raw_pubs[f"{ns}/sensors/{block.sensor}/raw"].publish(raw_block_to_msg(block, self.mc))

    def on_traction(self, msg) -> None:
        """Thrust command [N] of the speed controller (closed-loop scenarios)."""
        if not math.isfinite(msg.data):
            self.diag.reject("control/traction", "nan", f"traction command {msg.data}")
            return
        self.diag.accept("control/traction")
        self.dynamics.set_command(msg.data)

    def on_brake(self, msg) -> None:
        """Friction brake demand 0..1 of the speed controller (closed-loop scenarios; NaN is refused)."""
        if not math.isfinite(msg.data):
            self.diag.reject("control/brake", "nan", f"brake demand {msg.data}")
            return
        self.diag.accept("control/brake")
        self.dynamics.set_brake(msg.data)

    def close(self):
        """Stop the publishing thread before the node goes away (no publish after destroy)."""
        self._stop.set()
        self._thread.join(timeout=5.0)


def main(args=None):
    return spin(SimulatorNode, args, usage=__doc__)

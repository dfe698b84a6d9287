"""``stator_section_controller``: sectional feeding of a long-stator guideway from the fused
train states (core/wayside/stator.py, seed 000 section 2), a thin shell.

Subscribes ``localization/state`` (TrainState: one train, this namespace) or, with
``trains``, ``/<name>/localization/state`` of each train of a line (reliable, deep queue:
every state); every ``period`` it decides which stator sections its inverters feed and
publishes ``stator/feed`` (StatorFeed, reliable + transient-local) on every change and every
second.

Parameters: ``scenario`` (YAML: the track with its ``stator_section`` items, the vehicle's
length and orientation; a line scenario gives each train's) or ``track`` (track YAML) with
``train_length`` [m] and ``orientation`` (+1/-1); ``trains`` (names of a line's trains; empty:
the train of this namespace); the PARAMS of core/wayside/stator.py (``inverters``,
``command_latency``, ``switch_time``, ``period``, ``margin``, ``speed_confidence``,
``max_state_age``, ``track_margin``, ``max_interval_width``, ``future_tolerance``,
``input_timeout``, ``max_acceleration``, ``plausibility_margin``, ``speed_margin``). The timer
runs on the node clock (use_sim_time on simulated time).

Every state is admitted first (core/wayside/stator.py TrainStates over core/safety's
StateStream): refused and counted by reason in /diagnostics (``rejected/<topic>/<reason>``:
nan, implausible, future, duplicate, stamp_back, motion) and otherwise ignored. The
controller feeds the union of the spans of every state admitted within ``max_state_age``.

/diagnostics: the fed sections and the controller's counters; WARN while a train is held (no
claimed state admitted within max_state_age: nothing is switched for it), its stream is
stale (nothing admitted for ``input_timeout``: held, its sections stay fed) or a section waits
for its inverter.
"""
from __future__ import annotations

import math
import sys

from rclpy.node import Node

from ..core import convert, paths
from ..core.scenario import Scenario
from ..core.track import Track
from ..core.wayside import stator
from ..core.sensors.base import Param
from .common import (LATCHED_QOS, STREAM_QOS, ConfigurationError, Diagnostics, declare_param, declare_params, now_sec,
                     rclpy_classes, spin)

PUBLISH_EVERY = 1.0    # [s] the feed is republished at least this often
# the node's parameters (tools/docs.py writes them into config/params/stator_section_controller.yaml)
PARAMS = {
    "scenario": Param("", "scenario YAML (track with stator sections, vehicle)"),
    "track": Param("config/track_maglev.yaml", "track YAML when no scenario is given"),
    "trains": Param([""], "names of a line's trains whose /<name>/localization/state are fed; [''] = the train "
                          "of this namespace"),
    "train_length": Param(200.0, "vehicle length behind the front [m] (without a scenario)", (1.0, 2000.0)),
    "orientation": Param(1, "+1: the front faces increasing chainage, -1: decreasing (without a scenario)", (-1, 1)),
    **stator.PARAMS,
}


def view_from_msg(msg) -> stator.TrainView:
    """The controller's view of a TrainState message, as it is: the controller's admission
    (StatorController.admit) decides whether it can be used."""
    return stator.TrainView(convert.stamp_to_sec(msg.header.stamp), msg.mode in (1, 2), float(msg.position_min),
                            float(msg.position_max), float(msg.speed), float(msg.speed_stddev))


class StatorControllerNode(Node):
    """The node: admits each train's states (StatorController.admit), decides every ``period``
    (StatorController.update) and publishes the feed."""

    def __init__(self, **kw):
        Node.__init__(self, "stator_section_controller", **kw)
        from train_localization_msgs.msg import StatorFeed
        self._feed_cls = StatorFeed
        self.diag = Diagnostics(self, "long-stator sectional feeding")
        track, vehicles, topics = self._configuration()
        params = declare_params(self, stator.PARAMS)
        try:
            layout = stator.Layout.from_track(track, int(params["inverters"]))
        except stator.StatorError as exc:
            raise ConfigurationError(str(exc)) from None
        if not len(layout):
            raise ConfigurationError(f"track {track.track_id} has no {stator.KIND} items: nothing to feed")
        self.ctrl = stator.StatorController(layout, vehicles, params, extent=(0.0, track.length))
        self.topics = topics
        self.mc = rclpy_classes()
        for name, topic in topics.items():
            self.create_subscription(self.mc.TrainState, topic, lambda msg, n=name: self.on_state(n, msg),
                                     STREAM_QOS)
        self.pub = self.create_publisher(StatorFeed, stator.FEED_TOPIC, LATCHED_QOS)
        self._last_fed: tuple | None = None
        self._last_pub = -math.inf
        self.create_timer(params["period"], self.evaluate)
        self.diag.set_status(1, "no train state yet: nothing fed")

    def _configuration(self) -> tuple[Track, dict, dict]:
        """(track, train name -> stator.Vehicle, train name -> state topic) from the parameters."""
        scenario_path = declare_param(self, PARAMS, "scenario")
        track_path = declare_param(self, PARAMS, "track")
        trains = [str(t) for t in declare_param(self, PARAMS, "trains") if str(t)]
        length = declare_param(self, PARAMS, "train_length")
        orientation = declare_param(self, PARAMS, "orientation")
        if orientation == 0:
            raise ConfigurationError("parameter 'orientation' must be +1 or -1")
        if not scenario_path:
            track = Track.from_yaml(paths.resolve(track_path))
            names = trains or ["train"]
            vehicles = {n: stator.Vehicle(float(length), int(orientation)) for n in names}
        else:
            line = Scenario.from_yaml(scenario_path)
            track = line.track
            if trains:
                vehicles = {n: stator.Vehicle(line.train(n).vehicle.length, line.train(n).orientation())
                            for n in trains}
            else:
                own = line.for_namespace(self.get_namespace())
                vehicles = {"train": stator.Vehicle(own.vehicle.length, own.orientation())}
        topics = ({n: f"/{n}/localization/state" for n in trains} if trains
                  else {next(iter(vehicles)): "localization/state"})
        return track, vehicles, topics

    def on_state(self, name: str, msg) -> None:
        refused = self.ctrl.admit(name, view_from_msg(msg), now_sec(self) or None)
        if refused is not None:
            self.diag.reject(self.topics[name], refused.reason, refused.message)
        else:
            self.diag.accept(self.topics[name])

    def now(self) -> float:
        """Node clock, or the newest admitted stamp while no clock runs."""
        t = now_sec(self)
        return t if t > 0.0 else (self.ctrl.latest_stamp() or 0.0)

    def evaluate(self) -> None:
        if self.ctrl.latest_stamp() is None:       # nothing admitted yet: nothing to feed
            return
        now = self.now()
        busy_before = self.ctrl.counters["inverter_busy"]
        held_before = self.ctrl.counters["held"]
        stale_before = self.ctrl.counters["stale"]
        for cmd in self.ctrl.update(now):
            self.get_logger().info(f"{cmd.section} {'on' if cmd.on else 'off'} (effective {cmd.effective:.3f} s)")
        fed = tuple(self.ctrl.fed_sections())
        if fed != self._last_fed or now - self._last_pub >= PUBLISH_EVERY:
            self.pub.publish(self._feed_msg(now))
            self._last_fed, self._last_pub = fed, now
        self.diag.values["fed"] = ",".join(fed)
        self.diag.values["stale_trains"] = ",".join(sorted(self.ctrl.stale))
        self.diag.values.update({k: str(v) for k, v in self.ctrl.counters.items()})
        notes = []
        if self.ctrl.counters["stale"] > stale_before:
            notes.append(f"stale: nothing admitted from {', '.join(sorted(self.ctrl.stale))} for input_timeout: "
                         "held, its sections stay fed")
        elif self.ctrl.counters["held"] > held_before:
            notes.append("a train is held (no claimed state admitted within max_state_age): nothing switched for it")
        if self.ctrl.counters["inverter_busy"] > busy_before:
            notes.append("a needed section waits for its inverter")
        self.diag.set_status(1 if notes else 0, "; ".join(notes) or f"feeding {', '.join(fed) or 'nothing'}")

    def _feed_msg(self, now: float):
        sections = self.ctrl.layout.sections
        fed = set(self.ctrl.fed_sections())
        return self._feed_cls(header=self.mc.header(now), section_ids=[s.section_id for s in sections],
                              inverters=[s.inverter for s in sections], fed=[s.section_id in fed for s in sections])


def main(args=None):
    sys.exit(spin(StatorControllerNode, args, usage=f"{__doc__}\n{StatorControllerNode.__doc__}"))

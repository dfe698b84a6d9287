"""Sensor node: one device of one sensor kind, simulated or ingested.

The same node serves every sensor kind of core/sensors (one executable per kind,
e.g. ``ros2 run train_localization doppler_radar``). It wraps a
core.pipeline.SensorPipeline:

  mode = sim     subscribes ground_truth/state, simulates the device, publishes the
                 raw blocks on sensors/<sensor>/raw AND decodes them;
  mode = ingest  subscribes sensors/<sensor>/raw (a device driver or a bag) and
                 decodes it.

Decoded output: sensors/<sensor>/position | speed | distance | yaw_rate | acceleration, and
wayside/sections for occupancy. A decoder that needs the train's position (the accelerometer's
gradient) subscribes to the TrainState topic of its parameter ``position_topic`` (the fusion's
localization/state, or ground_truth/state) in both modes. Common parameters: mode, scenario (YAML: track, vehicle, seed and
this sensor's parameter overrides), track (track YAML, used when no scenario is
given), plus every parameter of the sensor kind (docs/nodes.md and core/sensors/*.py list
them with units and sources), and ``managed`` (a lifecycle node: see SensorNode). Bad
raw blocks or truth states are rejected with a diagnostic and counted; the node keeps
running.

A truth state (sim) stamped further than ``future_tolerance`` ahead of the node's time is
refused (``future``): on /clock (use_sim_time) the node clock; on the wall clock, whose time
the simulated truth is not in, the truth's own time: the last truth state taken advanced by
the wall time since (or the wall clock, for truth stamped in it). Taken, a truth state far
ahead would make the device simulate every block up to it at once.
"""
from __future__ import annotations

import sys
import time

from rclpy.lifecycle import TransitionCallbackReturn

from ..core import convert
from ..core.pipeline import SensorPipeline
from ..core.scenario import Scenario, Vehicle
from ..core.sensors import NODE_NAMES, spec as sensor_spec
from ..core.sensors.accelerometer import TrackPosition
from ..core.sensors.base import COMMON_PARAMS
from ..core.signals import InputRejected
from ..core.track import Track
from ..core import paths
from ..core.sensors.base import Param
from .common import (LATCHED_QOS, STREAM_QOS, ConfigurationError, ManagedNode, declare, declare_param,
                     future_tolerance_param, now_sec, rclpy_classes, refuse_future, spin)

# the parameters of every sensor node beyond its kind's (core/sensors/<kind>.py) and the common ones
NODE_PARAMS = {
    "mode": Param("sim", "sim: simulate from ground_truth/state; ingest: decode sensors/<sensor>/raw"),
    "scenario": Param("", "scenario YAML (track, vehicle, seed, sensor overrides)"),
    "track": Param("config/track_conventional.yaml", "track YAML when no scenario is given"),
    "future_tolerance": future_tolerance_param("a raw block (its last sample) or a truth state"),
    "input_timeout": Param(1.0, "no raw block (ingest) or truth state (sim) received for this long while active, "
                                "none since activation included: the node's diagnostics are WARN [s] of the wall "
                                "clock", (0.01, 3600.0)),
}


class SensorNode(ManagedNode):
    """A managed (lifecycle) sensor node, like the fusion: with ``managed`` false (the plain
    executable) it configures and activates itself at start; with ``managed`` true a
    lifecycle manager drives it: configure (parameters, the sensor pipeline, the
    publishers), activate (subscribe to the truth or the raw blocks), deactivate
    (unsubscribe; the pipeline keeps its state), cleanup (drop the pipeline)."""

    def __init__(self, node_name: str):
        self.spec = sensor_spec(node_name)
        super().__init__(node_name, self.spec.sensor)
        self.pubs: dict = {}
        self._active_since: float | None = None   # monotonic clock [s] of the activation; None: inactive
        self._input_at: float | None = None       # monotonic clock [s] of the last input received
        self.diag.extra(self._input_silence)
        # managed: every parameter is there before configure (the scenario's defaults come at configure)
        self.predeclare({**NODE_PARAMS, **COMMON_PARAMS, **self.spec.params})
        self.start()

    def on_configure(self, state) -> TransitionCallbackReturn:
        result = super().on_configure(state)
        if result == TransitionCallbackReturn.SUCCESS:
            self.diag.set_status(1, f"inactive (configured, {self.mode})")
        return result

    def _configure(self) -> None:
        node_name = self.get_name()
        # every parameter is read at start-up: read-only (``ros2 param set`` refuses a change)
        mode = declare_param(self, NODE_PARAMS, "mode")
        scenario_path = declare_param(self, NODE_PARAMS, "scenario")
        track_path = declare_param(self, NODE_PARAMS, "track")
        if mode not in ("sim", "ingest"):
            raise ConfigurationError(f"parameter 'mode' must be 'sim' or 'ingest', not {mode!r}")
        self.mode = mode
        overrides: dict = {}
        if scenario_path:
            # on a line: the train of this node's namespace, or the wayside equipment in /wayside
            line = Scenario.from_yaml(scenario_path)
            scenario = line.for_namespace(self.get_namespace())
            if line.line and mode == "sim":
                raise ConfigurationError("on a line the simulator node simulates every device (the wayside ones "
                                         "see all trains): run the sensor nodes with mode:=ingest")
            track, vehicle = scenario.track, scenario.vehicle
            overrides = dict(scenario.sensors.get(self.spec.node, {}))
        else:
            scenario, track, vehicle = None, Track.from_yaml(paths.resolve(track_path)), Vehicle()
        # every sensor parameter is a ROS parameter; the scenario gives the defaults
        for name, p in {**COMMON_PARAMS, **self.spec.params}.items():
            default = overrides.get(name, p.default)
            if isinstance(p.default, float):
                default = float(default)
            if isinstance(p.default, list) and not default:
                continue  # empty lists have no ROS parameter type; keep the default
            overrides[name] = declare(self, name, default, p.description, read_only=True, limits=p.limits)
        self.future_tolerance = float(declare_param(self, NODE_PARAMS, "future_tolerance"))
        self.input_timeout = float(declare_param(self, NODE_PARAMS, "input_timeout"))
        self.sim_time = bool(self.get_parameter("use_sim_time").value)
        self._truth_taken: tuple[float, float] | None = None   # (stamp, monotonic clock) [s] of the last truth
        unit = overrides.get("unit_id") or self.spec.sensor
        rng = scenario.rng(self.spec.node, unit) if scenario else None
        if mode == "sim" and rng is None:
            import numpy as np
            rng = np.random.default_rng(0)
        # a wayside device of a network: its equipment on every section (core/network/wayside.py)
        network = scenario.network if scenario is not None and self.spec.simulator.sees_all_trains else None
        self.pipe = SensorPipeline(self.spec, overrides, track, vehicle, rng, simulate=(mode == "sim"), network=network)
        self.mc = rclpy_classes()
        self.diag.name = f"{node_name}: {self.spec.sensor} {unit} ({mode})"
        base = f"sensors/{self.spec.sensor}"
        # a decoder that takes the train's position (set_position) gets it from a TrainState topic
        self.position_topic = overrides.get("position_topic") if hasattr(self.pipe.decoder, "set_position") else None
        self.raw_pub = None
        if mode == "sim":
            self.raw_pub = self.create_lifecycle_publisher(self.mc.RawBlock, f"{base}/raw", STREAM_QOS)
        # publishers exist from the start, so subscribers match before the first output
        from ..core.convert import MEASUREMENT_TOPICS
        for kind in self.spec.outputs:
            if kind == "sections":
                self.pubs[convert.SECTIONS_TOPIC] = self.create_lifecycle_publisher(
                    self.mc.SectionOccupancy, convert.SECTIONS_TOPIC, LATCHED_QOS)
            else:
                cls = getattr(self.mc, MEASUREMENT_TOPICS[kind][0])
                self.pubs[f"{base}/{kind}"] = self.create_lifecycle_publisher(cls, f"{base}/{kind}", STREAM_QOS)

    def on_activate(self, state) -> TransitionCallbackReturn:
        self._truth_taken = None   # the truth went on while inactive: its time is learnt again
        if self.mode == "sim":
            self._subs.append(self.create_subscription(self.mc.TrainState, "ground_truth/state", self.on_truth,
                                                       STREAM_QOS))
        else:
            self._subs.append(self.create_subscription(self.mc.RawBlock, f"sensors/{self.spec.sensor}/raw",
                                                       self.on_raw, STREAM_QOS))
        if self.position_topic:
            self._subs.append(self.create_subscription(self.mc.TrainState, self.position_topic, self.on_position,
                                                       STREAM_QOS))
        self.diag.set_status(0, "running")
        self._active_since, self._input_at = time.monotonic(), None
        return super().on_activate(state)

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        self._active_since = None
        return super().on_deactivate(state)

    def _input_silence(self) -> list:
        """Before each report: a WARN line while active and no input (raw block, or truth state in
        sim) was received for ``input_timeout``, none since activation included; no extra status."""
        self.diag.warnings = []
        if self._active_since is None:
            return []
        now = time.monotonic()
        what = "raw block" if self.mode == "ingest" else "truth state"
        if self._input_at is None and now - self._active_since > self.input_timeout:
            self.diag.warnings = [f"no {what} received in {now - self._active_since:.1f} s since activation "
                                  f"(input_timeout {self.input_timeout:g} s)"]
        elif self._input_at is not None and now - self._input_at > self.input_timeout:
            self.diag.warnings = [f"no {what} for {now - self._input_at:.1f} s (input_timeout "
                                  f"{self.input_timeout:g} s)"]
        return []

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        for pub in list(self.pubs.values()) + ([self.raw_pub] if self.raw_pub is not None else []):
            self.destroy_lifecycle_publisher(pub)
        self.pubs, self.raw_pub, self.pipe = {}, None, None
        self.diag.set_status(1, "unconfigured")
        return TransitionCallbackReturn.SUCCESS

    def _publisher(self, topic: str, msg):
        if topic not in self.pubs:
            qos = LATCHED_QOS if topic == convert.SECTIONS_TOPIC else STREAM_QOS
            self.pubs[topic] = self.create_lifecycle_publisher(type(msg), topic, qos)
        return self.pubs[topic]

    def on_truth(self, msg):
        self._input_at = time.monotonic()
        try:
            truth = convert.truth_from_msg(msg)
            now, clock = self._truth_clock()
            refuse_future(truth.stamp, now, self.future_tolerance, "truth state", clock)
            blocks = self.pipe.on_truth(truth)
        except InputRejected as exc:
            self.diag.reject("ground_truth/state", exc.reason, str(exc))
            return
        self._truth_taken = (truth.stamp, time.monotonic())
        self.diag.accept("ground_truth/state")
        for block in blocks:
            self.raw_pub.publish(convert.raw_block_to_msg(block, self.mc))
            self._decode(block)

    def on_position(self, msg):
        """The train's position for the decoder (a TrainState: the fusion's or the truth); a state
        that claims no position (MODE_INITIALISING) is skipped, one on another track refused
        (``wrong_track``, counted)."""
        if msg.mode == self.mc.TrainState.MODE_INITIALISING:
            return
        try:
            if msg.track_id and msg.track_id != self.pipe.track.track_id:
                raise InputRejected("wrong_track", f"position on track {msg.track_id[:64]!r}, not the node's "
                                                   f"{self.pipe.track.track_id!r}")
            self.pipe.on_position(TrackPosition(convert.stamp_to_sec(msg.header.stamp), float(msg.position),
                                                float(msg.position_stddev), float(msg.speed)))
        except InputRejected as exc:
            self.diag.reject(self.position_topic, exc.reason, str(exc))
            return
        self.diag.accept(self.position_topic)

    def _truth_clock(self) -> tuple[float, str]:
        """(time [s], its name) a truth state's stamp is checked against: the node clock on
        /clock; on the wall clock the last truth state taken advanced by the wall time since,
        when that is earlier (the truth's own time, which a simulator's truth is stamped in)."""
        now = now_sec(self)
        if self.sim_time or self._truth_taken is None:
            return now, "the node clock"
        stamp, taken_at = self._truth_taken
        simulated = stamp + (time.monotonic() - taken_at)
        if simulated >= now:
            return now, "the node clock"
        return simulated, (f"the truth's own time (the last truth state taken, at {stamp:.3f} s, and the wall "
                           "time since: the node runs on the wall clock)")

    def on_raw(self, msg):
        self._input_at = time.monotonic()
        try:
            block = convert.raw_block_from_msg(msg)
            refuse_future(block.t_end, now_sec(self), self.future_tolerance, "raw block end")
        except InputRejected as exc:
            self.pipe.rejected[exc.reason] += 1
            self.diag.reject("raw", exc.reason, str(exc))
            return
        self._decode(block)

    def _decode(self, block):
        try:
            measurements = self.pipe.on_block(block)
        except InputRejected as exc:
            self.diag.reject("raw", exc.reason, str(exc))
            return
        self.diag.accept("raw")
        for m in measurements:
            out = convert.measurement_to_msg(m, self.mc)
            self._publisher(convert.measurement_topic(m), out).publish(out)
        self.diag.values.update({f"decoder/{k}": str(v) for k, v in self.pipe.decoder.stats.items()})


def usage(node_name: str | None) -> str:
    """The help of a sensor node: this module's description, then its kind's parameters with their
    defaults, units and ranges (core/sensors/<kind>.py)."""
    if node_name is None:
        return __doc__
    s = sensor_spec(node_name)
    lines = [f"{node_name}: {s.description}", "", __doc__, f"Parameters of {node_name} (default; meaning [range]):"]
    for name, p in {**COMMON_PARAMS, **s.params}.items():
        lines.append(f"  {name} ({p.default!r}) {p.meaning}")
    return "\n".join(lines)


def main(args=None, node_name: str | None = None):
    return spin(lambda: SensorNode(node_name), args, usage=usage(node_name))


def _entry(node_name):
    def entry(args=None):
        sys.exit(main(args, node_name))
    entry.__name__ = f"main_{node_name}"
    return entry


for _name in NODE_NAMES:
    globals()[f"main_{_name}"] = _entry(_name)

"""Fusion node: absolute along-track position and speed from every sensor.

Subscribes sensors/<sensor>/position | speed | distance | yaw_rate | acceleration (what that kind
of sensor publishes; a turn rate serves only the track selection on a network) for each sensor in
``sensors``; publishes at a fixed rate, independent of the inputs (the grid of
core/fusion/runner.py FusionRunner, the same code as the offline runs):
  localization/state     TrainState (reliable, transient-local, depth 1: a late joiner gets the
                         current state first)
  localization/odometry  nav_msgs/Odometry, pose in map from the track alignment
  /tf                    map -> base_frame, or map -> odom_frame when odom_frame is set (then
                         odom -> base_frame comes from another source on /tf, REP-105)
  /diagnostics           level from the mode (OK NOMINAL, WARN INITIALISING and DEGRADED, ERROR
                         LOST; WARN also once input was rejected, and while an input's own status
                         is WARN, named in the message), counts of accepted, gated and
                         rejected measurements, mode, NIS; one status per sensor input (frequency,
                         age of the last message, WARN when silent beyond its timeout)
Service: localization/set_position (train_localization_msgs/SetPosition): on a network with a
section_id the position is a chainage on that section, without one a distance along the route
(the reply names the section and chainage used); ambiguous or unplaceable input is refused in
one line (core/network/hypotheses.py operator_start).
On a network (a scenario whose track has sections, docs/network.md): one filter per track
hypothesis (core/network/hypotheses.py); localization/state names the most probable section,
and the node also publishes
  localization/tracks    TrackHypotheses (reliable, transient-local): every hypothesis
and subscribes
  interlocking/switches  SwitchPositions (latched): the interlocking's switch positions, a prior
with the NetworkConfig fields (core/network/config.py) as further read-only parameters.

Parameters:
  managed (bool, false)         true: a lifecycle manager drives configure/activate/deactivate/cleanup;
                                false: configure and activate at start (the plain executable)
  track (string)                track YAML (or take it from ``scenario``)
  scenario (string, "")         scenario YAML: the track, the sensors whose error models configure
                                the filter, and the ``fusion:`` tuning (set parameters override it)
  sensors (string[])            sensor classes to subscribe (sensor node names map to their class;
                                anything else stops the node with the list of known ones)
  sensor_params (string, "")    YAML file: sensor node name -> parameters; the error models of the
                                subscribed sensors are built from it (without a scenario)
  max_input_rate (double, 1000.0) [messages/s] per input topic, 1 .. 1e6: beyond it the excess is
                                shed before any work and counted (shed/<topic>; core/fusion/shedding.py)
  publish_rate (double, 200.0)  [Hz], (0, 1000] (MLX position system updates every 5 ms, seed 002);
                                the only parameter that may change at run time (the others are
                                read-only); an integer is taken for a double everywhere
  map_frame ("map"), base_frame ("base_link"), odom_frame ("": none)
  <sensor>.<field>              per configured sensor, its error-model fields (core/sensors/base.py
                                ErrorModel, e.g. doppler.scale_sigma; faults as "slip,slide"):
                                default the sensor's own model; a different value overrides it
  and every global tuning field of core/fusion/config.py FusionConfig under its own name,
  with the same default and description.
"""
from __future__ import annotations

import math
import time

from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Odometry
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.node import Node

from ..core import convert, paths
from ..core.fusion import FusionConfig, FusionRunner, Mode, estimate_to_msg, fusion_config, sensor_models
from ..core.fusion.shedding import InputShedder
from ..core.scenario import Scenario
from ..core.signals import InputRejected
from ..core.track import Track
from ..core.sensors import NODE_NAMES, sensor_classes, spec
from ..core.sensors.base import ERROR_MODEL_LIMITS
from ..core.network.config import NetworkConfig, network_fusion_config
from ..core.network.hypotheses import HypothesisSet
from ..core.network.model import is_network
from ..core.sensors.base import Param
from .common import (LATCHED_QOS, STATE_QOS, STREAM_QOS, SWITCH_TOPIC, ConfigurationError, ManagedNode, declare,
                     declare_param, now_sec, rclpy_classes, spin, switch_positions)

# every sensor class, in the registry's order (core/sensors/__init__.py)
ALL_SENSORS = list(dict.fromkeys(sensor_classes().values()))
# the node's own parameters but publish_rate (declared at start, writable)
NODE_PARAMS = {
    "scenario": Param("", "scenario YAML (gives the track and the fusion tuning)"),
    "track": Param("config/track_conventional.yaml", "track YAML"),
    "sensors": Param(ALL_SENSORS, "sensor classes to subscribe (a sensor node's name is taken for its class)"),
    "sensor_params": Param("", "YAML file: sensor node name -> its parameters (the sensors' own parameter files); "
                               "their error models configure the filter (default: the scenario's sensors, else "
                               "default parameters)"),
    "map_frame": Param("map", "fixed frame (REP-105 map)"),
    "base_frame": Param("base_link", "vehicle frame"),
    "odom_frame": Param("", "REP-105 odom frame of a source that publishes odom -> base_frame on /tf: then this "
                            "node publishes map -> odom (as robot_localization does); empty: map -> base_frame"),
    "max_input_rate": Param(1000.0, "messages per second per input topic beyond which the excess is shed before "
                                    "any work (counted: shed/<topic>); the fastest device sends 200/s", (1.0, 1.0e6)),
    "hold_late_inputs": Param(False, "hold every input for the largest latency its sensor declares (the error "
                                     "models' latency) and fuse in stamp order: an input no later than that "
                                     "rewinds nothing; the states are published that latency late "
                                     "(core/fusion/runner.py)"),
}


def _ros_value(value):
    """A FusionConfig tuning value as a ROS parameter value."""
    return value


def _from_ros(default, value):
    if isinstance(default, float):
        return float(value)
    if isinstance(default, int) and not isinstance(default, bool):
        return int(value)
    return value


def error_model_parameters(model) -> dict:
    """The fields of a sensor's error model (core/sensors/base.py ErrorModel) as ROS parameter
    values: numbers, booleans, and the fault modes as one comma-separated string."""
    from dataclasses import fields
    out = {}
    for f in fields(model):
        if f.name in ("sensor", "measures", "references"):
            continue
        value = getattr(model, f.name)
        out[f.name] = ",".join(value) if f.name == "faults" else value
    return out


def overrides_from_parameters(model, values: dict) -> dict:
    """The fields whose parameter value differs from the sensor's own model (``values``:
    field -> parameter value): what the user overrides."""
    own = error_model_parameters(model)
    out = {}
    for name, value in values.items():
        if name == "faults":
            if value != own[name]:
                out[name] = tuple(v.strip() for v in value.split(",") if v.strip())
        elif value != own[name] and not (isinstance(value, float) and math.isnan(value) and math.isnan(own[name])):
            out[name] = value
    return out


def declare_fusion_config(node: Node, base: FusionConfig, track) -> FusionConfig:
    """Declare every global tuning field (default: ``base``) and, per configured sensor, its
    error-model fields as nested parameters ``<sensor>.<field>`` (default: the sensor's own
    model with ``base``'s overrides, e.g. a scenario's), and build the config. A value that
    differs from the sensor's own model is an override (logged)."""
    values = declare_fields(node, [f for f in FusionConfig.tuning_fields() if f.name != "track_id"], base)
    overrides: dict = {}
    try:
        for sensor, own in base.sensors.items():
            start = own.overridden((base.overrides or {}).get(sensor))
            given = {name: declare_param(node, error_model_params(sensor, start), f"{sensor}.{name}")
                     for name in error_model_parameters(start)}
            changed = overrides_from_parameters(own, given)
            if changed:
                overrides[sensor] = changed
                node.get_logger().info(f"error model of {sensor} overridden: "
                                       + ", ".join(f"{k}={v}" for k, v in sorted(changed.items())))
        return FusionConfig(track_id=track.track_id if track is not None else "", track=track, sensors=base.sensors,
                            overrides=overrides, **values)
    except ValueError as exc:
        raise ConfigurationError(f"fusion parameters: {exc}") from None


def error_model_params(sensor: str, model) -> dict:
    """The nested parameters ``<sensor>.<field>`` of a sensor class's error model (core Params,
    default the model's values)."""
    return {f"{sensor}.{name}": Param(value, f"{sensor} error model: {name} (core/sensors/base.py ErrorModel; "
                                             "default: the sensor's own model)", ERROR_MODEL_LIMITS.get(name))
            for name, value in error_model_parameters(model).items()}


def field_params(fields_, base) -> dict:
    """A config's ``fields_`` (described and bounded by ``doc_field``) as core Params, default
    their value in ``base``."""
    return {f.name: Param(_ros_value(getattr(base, f.name)), f.metadata.get("doc", ""), f.metadata.get("limits"))
            for f in fields_}


def declare_fields(node: Node, fields_, base) -> dict:
    """Declare each of a config's ``fields_`` (described and bounded by ``doc_field``) as a read-only
    parameter, default its value in ``base``; field name -> the value set."""
    params = field_params(fields_, base)
    return {f.name: _from_ros(getattr(base, f.name), declare_param(node, params, f.name)) for f in fields_}


def parameter_table() -> dict:
    """Every parameter the fusion may declare, at its default without a scenario: the node's,
    the tuning fields, the error-model fields of every sensor class, the network's (a managed
    node declares them all before configure; configure uses those its sensors and track need)."""
    from dataclasses import fields
    from ..core.fusion.config import default_models
    table = {**NODE_PARAMS, **field_params([f for f in FusionConfig.tuning_fields() if f.name != "track_id"],
                                           FusionConfig())}
    for sensor, model in default_models().items():
        table.update(error_model_params(sensor, model))
    return {**table, **field_params(fields(NetworkConfig), NetworkConfig())}


def declare_network_config(node: Node, base: NetworkConfig) -> NetworkConfig:
    """Declare every NetworkConfig field (the track-selective fusion, docs/network.md) as a
    read-only parameter (default: ``base``, from the scenario's route) and build the config."""
    from dataclasses import fields
    values = declare_fields(node, fields(NetworkConfig), base)
    try:
        return NetworkConfig(**values)
    except ValueError as exc:
        raise ConfigurationError(f"network parameters: {exc}") from None


def is_network_file(path) -> bool:
    """Whether a track YAML describes a network (core/network)."""
    import yaml
    try:
        with open(path, encoding="utf-8") as fh:
            return is_network(yaml.safe_load(fh))
    except (OSError, yaml.YAMLError):
        return False


# diagnostic level per mode (diagnostic_msgs/DiagnosticStatus: 0 OK, 1 WARN, 2 ERROR): no position
# yet and DEGRADED are warnings, LOST an error
_MODE_LEVEL = {Mode.INITIALISING: 1, Mode.NOMINAL: 0, Mode.DEGRADED: 1, Mode.LOST: 2}


def mode_status(est) -> tuple[int, str]:
    """(diagnostic level, message) of the fused state ``est``."""
    mode = Mode(est.mode)
    if mode == Mode.INITIALISING:
        return _MODE_LEVEL[mode], "INITIALISING: no position claimed yet"
    return _MODE_LEVEL[mode], f"{mode.name}: position {est.position:.2f} m, interval " \
                              f"[{est.position_min:.2f}, {est.position_max:.2f}] m"


def compose_inverse(a: tuple, b: tuple) -> tuple:
    """Planar transform a * b^-1 of (x, y, yaw) poses: map -> odom from map -> base and
    odom -> base."""
    xa, ya, ta = a
    xb, yb, tb = b
    t = ta - tb
    c, s = math.cos(t), math.sin(t)
    return xa - (c * xb - s * yb), ya - (s * xb + c * yb), math.atan2(math.sin(t), math.cos(t))


def sensor_classes(names: list[str]) -> list[str]:
    """Sensor classes (topic keys) from the ``sensors`` parameter: class names, or sensor
    node names (``wheel_sensor`` -> ``wheel``); ConfigurationError for anything else."""
    by_node = {n: spec(n).sensor for n in NODE_NAMES}
    known = set(by_node.values())
    out, unknown = [], []
    for name in (n.strip() for n in names):
        cls = by_node.get(name, name)
        if not name:
            continue
        if cls not in known:
            unknown.append(name)
        elif cls not in out:
            out.append(cls)
    if unknown:
        raise ConfigurationError(f"parameter 'sensors': unknown {', '.join(unknown)}; sensor classes are "
                                 f"{', '.join(sorted(known))} (or the node names {', '.join(NODE_NAMES)})")
    return out


MAX_PUBLISH_RATE = 1000.0   # [Hz]


def publish_rate_problem(value) -> str | None:
    """Why ``value`` is no valid publish_rate (a number in (0, MAX_PUBLISH_RATE] Hz), or None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f"'publish_rate' must be a number in (0, {MAX_PUBLISH_RATE:g}] Hz, not {value!r}"
    if not 0.0 < value <= MAX_PUBLISH_RATE:
        return f"'publish_rate' must be in (0, {MAX_PUBLISH_RATE:g}] Hz, not {value!r}"
    return None


class FusionNode(ManagedNode):
    """A managed (lifecycle) node. With ``managed`` false (the default, the plain executable)
    it configures and activates itself at start; with ``managed`` true a lifecycle manager
    drives it: configure (read the parameters, build the filter, create the publishers and
    the service), activate (subscribe, publish at ``publish_rate``), deactivate (unsubscribe,
    stop publishing; the filter keeps its state), cleanup (drop the filter)."""

    def __init__(self):
        super().__init__("fusion", "fusion")
        rate = declare(self, "publish_rate", 200.0, "state publish rate [Hz], > 0; may change at run time",
                       limits=(0.0, MAX_PUBLISH_RATE))
        problem = publish_rate_problem(rate)
        if problem:
            raise ConfigurationError(f"parameter {problem}")
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.runner = None
        self._timer = None
        self.predeclare(parameter_table())   # managed: every parameter before configure
        self.start()

    def _configure(self) -> None:
        scenario_path = declare_param(self, NODE_PARAMS, "scenario")
        track = declare_param(self, NODE_PARAMS, "track")
        # on a line: the train of this node's namespace (its sensors and the wayside ones)
        scenario = Scenario.from_yaml(scenario_path).for_namespace(self.get_namespace()) if scenario_path else None
        self.track = scenario.track if scenario else Track.from_yaml(paths.resolve(track))
        sensors = sensor_classes(declare_param(self, NODE_PARAMS, "sensors"))
        params_file = declare_param(self, NODE_PARAMS, "sensor_params")
        self.network = scenario.network if scenario else None
        self.route = scenario.route if scenario else None   # on a network: the train's route (a TrackPath)
        if self.network is None and not scenario and is_network_file(paths.resolve(track)):
            raise ConfigurationError(f"track {track} is a network: the fusion takes it from a scenario whose trains "
                                     "have routes through it (parameter scenario)")
        if self.network is not None:
            base, net_base = network_fusion_config(scenario)
        else:
            base = fusion_config(scenario)
        if params_file or not scenario:
            base = FusionConfig(**{**{f.name: getattr(base, f.name) for f in FusionConfig.tuning_fields()},
                                   "sensors": self._models(sensors, params_file), "overrides": base.overrides})
        cfg = declare_fusion_config(self, base, None if self.network is not None else self.track)
        self.map_frame = declare_param(self, NODE_PARAMS, "map_frame")
        self.base_frame = declare_param(self, NODE_PARAMS, "base_frame")
        self.odom_frame = declare_param(self, NODE_PARAMS, "odom_frame")
        self._odom_base = None   # latest odom -> base_frame from /tf: (x, y, yaw)
        max_input_rate = float(declare_param(self, NODE_PARAMS, "max_input_rate"))
        self.shedder = InputShedder(max_input_rate)
        self.mc = rclpy_classes()
        hypotheses = self.tracks_pub = None
        if self.network is not None:
            net = declare_network_config(self, net_base)
            hypotheses = HypothesisSet(cfg, net, self.network)
            self.tracks_pub = self.create_lifecycle_publisher(self.mc.TrackHypotheses, "localization/tracks",
                                                              STATE_QOS)
        hold = bool(declare_param(self, NODE_PARAMS, "hold_late_inputs"))
        self.runner = FusionRunner(cfg, float(self.get_parameter("publish_rate").value), hypotheses, hold=hold)
        self.filter = self.runner.filter
        self.sensors = sensors
        self._inputs: dict[str, list] = {}   # sensor -> [accepted since the last report, wall time, age]
        # event sensors (no timeout, references on the track) -> chainage [m] of their last accepted
        # fix, or where the train was first located: the references passed since are expected
        self._fixed_at: dict[str, float] = {}
        self._last_est = None
        self._inputs_since = self._last_state_wall = time.monotonic()
        self.diag.extra(self.input_statuses)
        self.state_pub = self.create_lifecycle_publisher(self.mc.TrainState, "localization/state", STATE_QOS)
        self.odom_pub = self.create_lifecycle_publisher(Odometry, "localization/odometry", STREAM_QOS)
        try:
            from tf2_msgs.msg import TFMessage
            self.tf_pub = self.create_lifecycle_publisher(TFMessage, "/tf", 100)
            self._tf_cls = TFMessage
        except ImportError:
            self.tf_pub = None
            self.get_logger().warn("tf2_msgs is not installed: /tf is not published")
        from train_localization_msgs.srv import SetPosition
        self._service = self.create_service(SetPosition, "localization/set_position", self.on_set_position)

    def on_activate(self, state) -> TransitionCallbackReturn:
        parsers = {"position": (self.mc.PositionFix, convert.position_fix_from_msg),
                   "speed": (self.mc.SpeedMeasurement, convert.speed_from_msg),
                   "distance": (self.mc.DistanceIncrement, convert.distance_from_msg),
                   "yaw_rate": (self.mc.YawRate, convert.yaw_rate_from_msg),
                   "acceleration": (self.mc.AccelWithCovarianceStamped, convert.acceleration_from_msg)}
        outputs = {spec(n).sensor: spec(n).outputs for n in NODE_NAMES}
        for sensor in self.sensors:
            for suffix in (o for o in outputs[sensor] if o in parsers):   # only what that sensor publishes
                cls, parse = parsers[suffix]
                topic = f"sensors/{sensor}/{suffix}"
                self._subs.append(self.create_subscription(
                    cls, topic, lambda msg, t=topic, p=parse: self.on_measurement(t, p, msg), STREAM_QOS))
        if self.odom_frame and self.tf_pub is not None:
            self._subs.append(self.create_subscription(self._tf_cls, "/tf", self.on_tf, 100))
        if self.network is not None:
            self._subs.append(self.create_subscription(self.mc.SwitchPositions, SWITCH_TOPIC,
                                                       self.on_switches, LATCHED_QOS))
        self._timer = self.create_timer(self.runner.period, self.on_timer)
        self._last_state_wall = time.monotonic()
        self.diag.set_status(1, "active, no state yet")
        return super().on_activate(state)

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        self.destroy_timer(self._timer)
        self._timer = None
        return super().on_deactivate(state)

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        for pub in (self.state_pub, self.odom_pub, self.tf_pub, self.tracks_pub):
            if pub is not None:
                self.destroy_lifecycle_publisher(pub)
        self.destroy_service(self._service)
        self.runner = None
        self.diag.extra(None)
        self.diag.warnings = []
        self.diag.set_status(1, "unconfigured")
        return TransitionCallbackReturn.SUCCESS

    def _on_set_parameters(self, params):
        """Run-time changes: publish_rate (> 0, <= 1000 Hz) takes effect at once; the other
        parameters are read-only (rclpy refuses them before this is called)."""
        from rcl_interfaces.msg import SetParametersResult
        for p in params:
            problem = publish_rate_problem(p.value) if p.name == "publish_rate" else None
            if problem:
                return SetParametersResult(successful=False, reason=problem)
        for p in params:
            if p.name == "publish_rate" and self.runner is not None:
                rate = float(p.value)
                self.runner.set_rate(rate)
                if self._timer is not None:
                    self.destroy_timer(self._timer)
                    self._timer = self.create_timer(1.0 / rate, self.on_timer)
                self.get_logger().info(f"publish_rate set to {rate:g} Hz")
        return SetParametersResult(successful=True)

    def _models(self, classes: list[str], params_file: str) -> dict:
        """Error models of the subscribed sensor classes, from their parameter file (if any)."""
        import yaml
        from ..core.scenario import Vehicle
        by_class = {spec(n).sensor: n for n in NODE_NAMES}
        unknown = [c for c in classes if c not in by_class]
        if unknown:
            raise ValueError(f"unknown sensor classes {unknown}; known: {', '.join(sorted(by_class))}")
        given = {}
        if params_file:
            with open(paths.resolve(params_file), encoding="utf-8") as fh:
                given = yaml.safe_load(fh) or {}
        return sensor_models({by_class[c]: given.get(by_class[c], {}) for c in classes}, self.track, Vehicle())

    def on_measurement(self, topic, parse, msg):
        wall = time.monotonic()
        if not self.shedder.admit(topic, wall):
            self._outputs_when_late(wall)   # a flood: shed before any work, counted (input_statuses reports it)
            return
        try:
            m = parse(msg)
            sensor = topic.split("/")[1]
            if m.sensor != sensor:   # what only the node can tell: the rest is core/fusion/admission.py
                raise InputRejected("wrong_sensor", f"measurement of sensor {m.sensor[:64]!r} on the topic "
                                                    f"of {sensor!r}")
        except InputRejected as exc:
            self.diag.reject(topic, exc.reason, str(exc))
            self._outputs_when_late(wall)
            return
        now = now_sec(self)
        if not self.runner.add(m, now):
            exc = self.runner.last_error
            self.diag.reject(topic, exc.reason, str(exc))
            self._outputs_when_late(wall, now)
            return
        self.diag.accept(topic)
        seen = self._inputs.setdefault(m.sensor, [0, None, None])
        seen[0] += 1
        seen[1], seen[2] = wall, now - m.stamp
        if hasattr(m, "reference_id"):
            self._fixed_at[m.sensor] = m.position
        self._outputs_when_late(wall, now)

    def _outputs_when_late(self, wall: float, now: float | None = None) -> None:
        """The outputs are the product, whatever the input does: when the executor serves a stream
        of input (taken, refused or shed alike) before the timers, the states due more than two
        periods ago and the 1 Hz diagnostics are published from here. ``wall``: the monotonic
        clock [s]; ``now``: the node clock [s] if read already (a taken message: checked at
        every one; a refused or shed one: only once no state came for two periods of wall time,
        the check that costs least)."""
        self.diag.publish_if_due(wall)
        if self._timer is None:
            return
        late = 2.0 * self.runner.period
        if now is None:
            if wall - self._last_state_wall < late:
                return
            now = now_sec(self)
        if self.runner.due(now - late):
            self.on_timer()

    def on_switches(self, msg) -> None:
        """The interlocking's switch positions (a network): priors of the track hypotheses."""
        positions = switch_positions(self.diag, msg, self.network)
        if positions is not None:
            self.filter.set_switches(positions)

    def input_statuses(self) -> list:
        """One status per subscribed sensor (diagnostic_updater's frequency and timestamp
        checks): accepted messages per second since the last report, age of the last one
        (node clock - its stamp); WARN when a continuous sensor is silent beyond its timeout,
        or its last message was older than the history or stamped in the future."""
        from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
        now = time.monotonic()
        self._report_counters()
        silent = now - self._last_state_wall
        if self._timer is not None and silent > max(2.0, 5.0 * self.runner.period):
            # active, but no state for seconds of wall time: the clock (/clock) stopped
            self.diag.set_status(3, f"STALE: no state published for {silent:.1f} s of wall time "
                                    "(is the clock running?)")
        elapsed = max(now - self._inputs_since, 1e-9)
        self._inputs_since = now
        out = []
        self.diag.warnings = []   # an input that is WARN makes the fusion's own status WARN too, naming it
        for sensor in self.sensors:
            count, last_wall, age = self._inputs.get(sensor, [0, None, None])
            self._inputs[sensor] = [0, last_wall, age]
            timeout = self.filter.timeouts.get(sensor)
            silent = now - last_wall if last_wall is not None else math.inf
            level, message = 0, "OK"
            passed = self._passed_unread(sensor) if timeout is None else []
            if timeout is not None and silent > timeout:
                level, message = 1, f"no accepted measurement for {silent:.1f} s (timeout {timeout:g} s)"
            elif passed:
                level, message = 1, (f"no fix since {self._fixed_at[sensor]:.1f} m, though the train has passed "
                                     f"{len(passed)} of its references ({', '.join(passed[:3])})")
            elif age is not None and not -0.05 <= age <= self.filter.cfg.history:
                level, message = 1, f"last measurement stamped {age:.3f} s before the node clock"
            if level:
                self.diag.warnings.append(f"input {sensor}: {message}")
            values = [KeyValue(key="frequency_hz", value=f"{count / elapsed:.2f}"),
                      KeyValue(key="last_age_s", value="none" if age is None else f"{age:.3f}"),
                      KeyValue(key="timeout_s", value="none" if timeout is None else f"{timeout:g}")]
            out.append(DiagnosticStatus(level=bytes([level]), name=f"{self.get_name()}: input {sensor}",
                                        message=message, hardware_id=self.get_fully_qualified_name(),
                                        values=values))
        return out

    def _passed_unread(self, sensor: str) -> list[str]:
        """The references of event sensor ``sensor`` (no timeout: a balise reader, an axle
        counter) that the train has passed, by its fused interval, since the sensor's last
        accepted fix (or since it was first located): each should have given one."""
        model, est = self.filter.models.get(sensor), self._last_est
        if self.network is not None:   # references in their sections' chainages: not along one line
            return []
        if model is None or model.references is None or est is None or not math.isfinite(est.position):
            return []
        since = self._fixed_at.setdefault(sensor, est.position)
        return model.references.passed(since, est.position_min, est.position_max)

    def on_set_position(self, request, response):
        t = now_sec(self)
        if request.reset:
            self._fixed_at.clear()   # the references passed are counted from the next position
            self.filter.reset(stamp=t)
            response.success, response.message = True, "filter reset: INITIALISING"
            self.get_logger().info(response.message)
            return response
        try:
            self.runner.admission.check_set_position(request.position, request.position_stddev, request.speed,
                                                     request.speed_stddev)
            if self.network is None:
                if request.section_id and request.section_id != self.track.track_id:
                    raise InputRejected("wrong_track", f"section_id {request.section_id[:64]!r} is not this "
                                                       f"fusion's track {self.track.track_id!r}")
                self.filter.reset(request.position, request.position_stddev, request.speed, request.speed_stddev, t)
                response.message = f"position set to {request.position:.3f} m"
            else:
                start = self.filter.operator_start(request.position, request.section_id, self.route)
                # with a section, the speed is along its chainage (as TrainState's); else along the route
                speed = request.speed * start.direction if request.section_id else request.speed
                self.filter.reset(start.position, request.position_stddev, speed, request.speed_stddev, t, start)
                response.message = f"position set to {start.describe()}"
        except InputRejected as exc:
            response.success, response.message = False, f"refused: {exc}"
            self.get_logger().warn(response.message)
            return response
        self._fixed_at.clear()   # an operator's position: the references passed are counted from it
        response.success = True
        self.get_logger().info(response.message)
        return response

    def on_timer(self):
        states = self.runner.advance(now_sec(self), max_catch_up=200)
        for est, used in states:
            self.publish_state(est, used)
        if states:
            est = states[-1][0]
            self.diag.set_status(*mode_status(est))
            self.diag.values.update({"mode": str(est.mode), "position_stddev": f"{est.position_stddev:.3f}"})

    def _report_counters(self) -> None:
        """The filter's counters and the shed inputs into the diagnostics (at their 1 Hz, not at
        every state: building them costs as much as a state)."""
        if self.runner is None:
            return
        for group, values in self.runner.counters().items():
            for k, v in values.items():
                self.diag.values[f"filter/{group}/{k}"] = f"{v:.3f}" if isinstance(v, float) else str(v)
        for topic, n in self.shedder.shed.items():
            self.diag.values[f"shed/{topic}"] = str(n)

    def publish_state(self, est, used):
        self._last_state_wall = time.monotonic()
        self._last_est = est
        on_network = self.network is not None
        msg = estimate_to_msg(self.mc, est, self.track.track_id, used, None if on_network else self.track)
        self.state_pub.publish(msg)
        if on_network:
            self.tracks_pub.publish(convert.track_hypotheses_to_msg(self.mc, est, self.network.network_id))
        if not math.isfinite(est.position):
            return
        track = self.network.section(est.track_id) if on_network else self.track
        x, y, yaw = track.pose(est.position)
        odom = Odometry()
        odom.header.stamp = msg.header.stamp
        odom.header.frame_id = self.map_frame
        odom.child_frame_id = self.base_frame
        odom.pose.pose.position.x, odom.pose.pose.position.y = x, y
        odom.pose.pose.orientation.z, odom.pose.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
        # along-track variance along the track heading; no cross-track freedom (on the track)
        var, c, s_ = est.position_stddev ** 2, math.cos(yaw), math.sin(yaw)
        cov = [0.0] * 36
        cov[0], cov[7] = var * c * c, var * s_ * s_
        cov[1] = cov[6] = var * c * s_
        odom.pose.covariance = cov
        odom.twist.twist.linear.x = est.speed
        tcov = [0.0] * 36
        tcov[0] = est.speed_stddev ** 2
        odom.twist.covariance = tcov
        self.odom_pub.publish(odom)
        if self.tf_pub is None:
            return
        child = self.base_frame
        if self.odom_frame:   # map -> odom = (map -> base) (odom -> base)^-1, in the plane
            if self._odom_base is None:
                return
            x, y, yaw = compose_inverse((x, y, yaw), self._odom_base)
            child = self.odom_frame
        tf = TransformStamped()
        tf.header = odom.header
        tf.child_frame_id = child
        tf.transform.translation.x, tf.transform.translation.y = x, y
        tf.transform.rotation.z, tf.transform.rotation.w = math.sin(yaw / 2), math.cos(yaw / 2)
        self.tf_pub.publish(self._tf_cls(transforms=[tf]))

    def on_tf(self, msg):
        for t in msg.transforms:
            if t.header.frame_id == self.odom_frame and t.child_frame_id == self.base_frame:
                q = t.transform.rotation
                yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
                self._odom_base = (t.transform.translation.x, t.transform.translation.y, yaw)


def main(args=None):
    return spin(FusionNode, args, usage=__doc__)

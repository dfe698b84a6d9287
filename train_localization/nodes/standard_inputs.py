"""standard_inputs node: a train's drivers' standard ROS messages into the fusion's inputs.

Subscribes, each only when its topic parameter is set (docs/integration.md, "From your drivers"):
  <navsat.topic>    sensor_msgs/NavSatFix: map-matched onto the track (or the network's sections)
                    -> sensors/dgps/position (PositionFix; on a network with its lateral offset)
  <imu.topic>       sensor_msgs/Imu (REP-145, frame by imu.mount_rpy) -> sensors/gyro/yaw_rate
                    (YawRate) and, with imu.acceleration, sensors/accelerometer/acceleration
                    (geometry_msgs/AccelWithCovarianceStamped)
  <odometry.topic>  nav_msgs/Odometry, <twist.topic> geometry_msgs/TwistWithCovarianceStamped:
                    the body's speed -> sensors/wheel/distance (DistanceIncrement) or
                    sensors/doppler/speed (SpeedMeasurement), by odometry.sensor / twist.sensor
each with a QoS that takes reliable and best-effort (sensor data) publishers alike. The math is
core/ingest (map matching by the DGPS decoder, the gyro's and accelerometer's decoders, the
sensors' error models as floors). Give the fusion the same ``scenario`` (or ``sensor_params``)
and the sensor classes this node publishes as its ``sensors``.

Refused and counted per reason in /diagnostics (``rejected/<topic>/<reason>``), never
published: NaN, out-of-range coordinates and covariances (core/ingest/records.py), a stamp
further ahead of the node clock than ``future_tolerance`` (``future``), out of order, and any
measurement beyond the physical limits (core/measurements.py). Withheld fixes (no fix,
autonomous, off the track, under a structure) are counted in ``navsat/<count>``.

Parameters: scenario (string, ""): scenario YAML (the track and the sensors' parameters);
track (string), sensor_params (string, ""): without a scenario, the track YAML and a YAML of
sensor node name -> parameters; future_tolerance; and the inputs' (core/ingest/inputs.py
PARAMS, docs/nodes.md).
"""
from __future__ import annotations

import yaml
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ..core import convert, paths
from ..core.ingest.inputs import PARAMS as INPUT_PARAMS, StandardInputs
from ..core.scenario import Scenario, Vehicle
from ..core.sensors.accelerometer import TrackPosition
from ..core.sensors.base import Param
from ..core.signals import InputRejected
from ..core.track import Track
from .common import (STREAM_QOS, ConfigurationError, ManagedNode, declare_param, future_tolerance_param, now_sec,
                     rclpy_classes, refuse_future, spin)
from .recorder import message_class

NODE_PARAMS = {
    "scenario": Param("", "scenario YAML: the track and the sensors' parameters (the fusion's)"),
    "track": Param("config/track_conventional.yaml", "track YAML when no scenario is given"),
    "sensor_params": Param("", "YAML file: sensor node name -> its parameters, when no scenario is given"),
    "future_tolerance": future_tolerance_param("a message"),
    **INPUT_PARAMS,
}
# best effort takes the drivers' sensor-data publishers and reliable ones alike
DRIVER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT,
                        durability=DurabilityPolicy.VOLATILE)
KIND_OF = {"dgps": "position", "gyro": "yaw_rate", "accelerometer": "acceleration", "wheel": "distance",
           "doppler": "speed"}


class StandardInputsNode(ManagedNode):
    """A managed (lifecycle) node like the sensor nodes: ``managed`` false configures and activates
    it at start."""

    def __init__(self):
        super().__init__("standard_inputs", "standard inputs")
        self.predeclare(NODE_PARAMS)
        self.start()

    def _configure(self) -> None:
        values = {name: declare_param(self, NODE_PARAMS, name) for name in NODE_PARAMS}
        if values["scenario"]:
            sc = Scenario.from_yaml(values["scenario"]).for_namespace(self.get_namespace())
            track, sensors, vehicle = sc.track, sc.sensors, sc.vehicle
        else:
            track, vehicle, sensors = Track.from_yaml(paths.resolve(values["track"])), Vehicle(), {}
            if values["sensor_params"]:
                with open(paths.resolve(values["sensor_params"]), encoding="utf-8") as fh:
                    sensors = yaml.safe_load(fh) or {}
        try:
            self.inputs = StandardInputs.build(values, track, sensors, vehicle)
        except ValueError as exc:
            raise ConfigurationError(str(exc)) from None
        self.future_tolerance = float(values["future_tolerance"])
        self.position_topic = values["imu.position_topic"] if values["imu.acceleration"] else ""
        self.mc = rclpy_classes()
        from ..core.convert import MEASUREMENT_TOPICS
        self.pubs = {}
        for sensor in self.inputs.sensor_classes():
            topic = f"sensors/{sensor}/{KIND_OF[sensor]}"
            cls = getattr(self.mc, MEASUREMENT_TOPICS[KIND_OF[sensor]][0])
            self.pubs[topic] = self.create_lifecycle_publisher(cls, topic, STREAM_QOS)
        self.diag.name = f"{self.get_name()}: standard inputs -> {', '.join(self.inputs.sensor_classes())}"

    def on_activate(self, state) -> TransitionCallbackReturn:
        for topic, reader in self.inputs.readers().items():
            self._subs.append(self.create_subscription(
                message_class(reader.typename), topic, lambda msg, t=topic, r=reader: self.on_message(t, r, msg),
                DRIVER_QOS))
        if self.position_topic:
            self._subs.append(self.create_subscription(self.mc.TrainState, self.position_topic, self.on_position,
                                                       STREAM_QOS))
        self.diag.set_status(0, "running")
        return super().on_activate(state)

    def _admit(self, record) -> None:
        refuse_future(record.stamp, now_sec(self), self.future_tolerance, "a message")

    def on_message(self, topic: str, reader, msg) -> None:
        try:
            out = reader.read(msg, self._admit)
        except InputRejected as exc:
            self.diag.reject(topic, exc.reason, str(exc))
            return
        self.diag.accept(topic)
        for m in out:
            self.pubs[convert.measurement_topic(m)].publish(convert.measurement_to_msg(m, self.mc))
        for ing in self.inputs.navsat.values():
            self.diag.values.update({f"navsat/{k}": str(v) for k, v in ing.stats.items()})

    def on_position(self, msg) -> None:
        """The fused state places the accelerometer's gradient (as the accelerometer node does)."""
        if msg.mode == self.mc.TrainState.MODE_INITIALISING:
            return
        try:
            where = TrackPosition(convert.stamp_to_sec(msg.header.stamp), float(msg.position),
                                  float(msg.position_stddev), float(msg.speed))
            for ing in self.inputs.imu.values():
                ing.set_position(where)
        except InputRejected as exc:
            self.diag.reject(self.position_topic, exc.reason, str(exc))


def main(args=None):
    return spin(StandardInputsNode, args, usage=__doc__)

"""Fusion node: absolute along-track position and speed from every sensor.

Subscribes sensors/<sensor>/position | speed | distance for each sensor in
``sensors``; publishes at a fixed rate, independent of the inputs (the grid of
core/offline.py FusionRunner, the same code as the offline runs):
  localization/state     TrainState (reliable, transient-local)
  localization/odometry  nav_msgs/Odometry, pose in map from the track alignment
  /tf                    map -> base_link
  /diagnostics           counts of accepted, gated and rejected measurements, mode, NIS
Service: localization/set_position (train_localization_msgs/SetPosition).

Parameters:
  track (string)                track YAML (or take it from ``scenario``)
  scenario (string, "")         scenario YAML; gives the track and the ``fusion:`` tuning
                                (explicitly set parameters override it)
  sensors (string[])            sensor classes to subscribe
  publish_rate (double, 200.0)  [Hz] (MLX position system updates every 5 ms, seed 002)
  map_frame ("map"), base_frame ("base_link")
  and every field of core/fusion.py FusionConfig under its own name, with the same
  default and description: numbers as doubles, sensor lists as string arrays, and the
  per-sensor tables (timeouts, scale_tau, scale_sigma, bias_sigma, reported_scale,
  reported_bias, stddev_factor, gate_probabilities, fix_bias_sigma, fix_bias_length,
  creep_coefficient) as string arrays of "sensor:value" entries.
"""
from __future__ import annotations

import math
from dataclasses import fields

from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node

from ..core import convert, paths
from ..core.fusion import FusionConfig
from ..core.offline import FusionRunner, estimate_to_msg, fusion_config
from ..core.scenario import Scenario
from ..core.signals import InputRejected
from ..core.track import Track
from .common import LATCHED_QOS, STREAM_QOS, Diagnostics, declare, now_sec, rclpy_classes, spin

ALL_SENSORS = ["doppler", "wheel", "eurobalise", "lrl", "inpo", "pattern_belt", "mmwave", "axle_counter"]


def _ros_value(value):
    """A FusionConfig value as a ROS parameter value (dicts and tuples as string arrays)."""
    if isinstance(value, dict):
        return [f"{k}:{v!r}" for k, v in value.items()] or [""]
    if isinstance(value, (tuple, list)):
        return [str(v) for v in value] or [""]
    return value


def _from_ros(default, value):
    if isinstance(default, dict):
        out = {}
        for item in value:
            if item:
                name, sep, number = item.partition(":")
                if not sep:
                    raise ValueError(f"expected 'sensor:value', got {item!r}")
                out[name.strip()] = float(number)
        return out
    if isinstance(default, tuple):
        return tuple(v for v in value if v)
    if isinstance(default, float):
        return float(value)
    return value


def declare_fusion_config(node: Node, base: FusionConfig, track_id: str) -> FusionConfig:
    """Declare every FusionConfig field as a parameter (default: ``base``) and build the config."""
    values = {}
    for f in fields(FusionConfig):
        if f.name == "track_id":
            continue
        default = getattr(base, f.name)
        values[f.name] = _from_ros(default, declare(node, f.name, _ros_value(default), f.metadata.get("doc", "")))
    return FusionConfig(track_id=track_id, **values)


class FusionNode(Node):
    def __init__(self):
        super().__init__("fusion")
        scenario_path = declare(self, "scenario", "", "scenario YAML (gives the track and the fusion tuning)")
        track = declare(self, "track", "config/track_conventional.yaml", "track YAML")
        scenario = Scenario.from_yaml(scenario_path) if scenario_path else None
        self.track = scenario.track if scenario else Track.from_yaml(paths.resolve(track))
        sensors = declare(self, "sensors", ALL_SENSORS, "sensor classes to subscribe")
        rate = float(declare(self, "publish_rate", 200.0, "state publish rate [Hz]"))
        cfg = declare_fusion_config(self, fusion_config(scenario), self.track.track_id)
        self.map_frame = declare(self, "map_frame", "map", "fixed frame")
        self.base_frame = declare(self, "base_frame", "base_link", "vehicle frame")
        self.runner = FusionRunner(cfg, rate)
        self.filter = self.runner.filter
        self.mc = rclpy_classes()
        self.diag = Diagnostics(self, "fusion")
        parsers = {"position": (self.mc.PositionFix, convert.position_fix_from_msg),
                   "speed": (self.mc.SpeedMeasurement, convert.speed_from_msg),
                   "distance": (self.mc.DistanceIncrement, convert.distance_from_msg)}
        for sensor in sensors:
            for suffix, (cls, parse) in parsers.items():
                topic = f"sensors/{sensor}/{suffix}"
                self.create_subscription(cls, topic, lambda msg, t=topic, p=parse: self.on_measurement(t, p, msg),
                                         STREAM_QOS)
        self.state_pub = self.create_publisher(self.mc.TrainState, "localization/state", LATCHED_QOS)
        self.odom_pub = self.create_publisher(Odometry, "localization/odometry", STREAM_QOS)
        try:
            from tf2_msgs.msg import TFMessage
            self.tf_pub = self.create_publisher(TFMessage, "/tf", 100)
            self._tf_cls = TFMessage
        except ImportError:
            self.tf_pub = None
            self.get_logger().warn("tf2_msgs is not installed: /tf is not published")
        from train_localization_msgs.srv import SetPosition
        self.create_service(SetPosition, "localization/set_position", self.on_set_position)
        self.create_timer(1.0 / rate, self.on_timer)

    def on_measurement(self, topic, parse, msg):
        try:
            m = parse(msg)
        except InputRejected as exc:
            self.diag.reject(topic, exc.reason, str(exc))
            return
        if not self.runner.add(m):
            exc = self.runner.last_error
            self.diag.reject(topic, exc.reason, str(exc))
            return
        self.diag.accept(topic)

    def on_set_position(self, request, response):
        t = now_sec(self)
        if request.reset:
            self.filter.reset(stamp=t)
            response.success, response.message = True, "filter reset: INITIALISING"
        elif not (math.isfinite(request.position) and request.position_stddev > 0 and request.speed_stddev > 0):
            response.success, response.message = False, "position must be finite and stddevs > 0"
        else:
            self.filter.reset(request.position, request.position_stddev, request.speed, request.speed_stddev, t)
            response.success, response.message = True, f"position set to {request.position:.3f} m"
        self.get_logger().info(response.message)
        return response

    def on_timer(self):
        states = self.runner.advance(now_sec(self), max_catch_up=200)
        for est, used in states:
            self.publish_state(est, used)
        if states:
            est = states[-1][0]
            self.diag.values.update({"mode": str(est.mode), "position_stddev": f"{est.position_stddev:.3f}"})
            for group, values in self.filter.counters().items():
                for k, v in values.items():
                    self.diag.values[f"filter/{group}/{k}"] = f"{v:.3f}" if isinstance(v, float) else str(v)

    def publish_state(self, est, used):
        msg = estimate_to_msg(self.mc, est, self.track.track_id, used)
        self.state_pub.publish(msg)
        if not math.isfinite(est.position):
            return
        x, y, yaw = self.track.pose(est.position)
        odom = Odometry()
        odom.header.stamp = msg.header.stamp
        odom.header.frame_id = self.map_frame
        odom.child_frame_id = self.base_frame
        odom.pose.pose.position.x, odom.pose.pose.position.y = x, y
        odom.pose.pose.orientation.z, odom.pose.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
        cov = [0.0] * 36
        cov[0] = cov[7] = est.position_stddev ** 2
        odom.pose.covariance = cov
        odom.twist.twist.linear.x = est.speed
        tcov = [0.0] * 36
        tcov[0] = est.speed_stddev ** 2
        odom.twist.covariance = tcov
        self.odom_pub.publish(odom)
        if self.tf_pub is not None:
            tf = TransformStamped()
            tf.header = odom.header
            tf.child_frame_id = self.base_frame
            tf.transform.translation.x, tf.transform.translation.y = x, y
            tf.transform.rotation = odom.pose.pose.orientation
            self.tf_pub.publish(self._tf_cls(transforms=[tf]))


def main(args=None):
    return spin(FusionNode, args)

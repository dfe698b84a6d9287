"""Fusion node: absolute along-track position and speed from every sensor.

Subscribes sensors/<sensor>/position | speed | distance for each sensor in
``sensors``; publishes at a fixed rate, independent of the inputs:
  localization/state     TrainState (reliable, transient-local)
  localization/odometry  nav_msgs/Odometry, pose in map from the track alignment
  /tf                    map -> base_link
  /diagnostics           counts of accepted, gated and rejected measurements, mode
Service: localization/set_position (train_localization_msgs/SetPosition).

Parameters (defaults in core/fusion.py FusionConfig):
  track (string)                track YAML (or take it from ``scenario``)
  scenario (string, "")         scenario YAML; gives the track
  sensors (string[])            sensor classes to subscribe
  publish_rate (double, 200.0)  [Hz] (MLX position system updates every 5 ms, seed 002)
  confidence (double, 0.999)    probability of [position_min, position_max]
  gate_probability (double, 0.9999), jerk_psd, history [s], slip_holdoff [s], lost_stddev [m]
  timeouts (string[], [])       "sensor:seconds" entries; a class past its timeout -> DEGRADED
  map_frame ("map"), base_frame ("base_link")
"""
from __future__ import annotations

import math

from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node

from ..core import convert, paths
from ..core.fusion import FusionConfig, TrainFilter
from ..core.scenario import Scenario
from ..core.signals import InputRejected
from ..core.track import Track
from .common import LATCHED_QOS, STREAM_QOS, Diagnostics, declare, now_sec, rclpy_classes, spin

ALL_SENSORS = ["doppler", "wheel", "eurobalise", "lrl", "inpo", "pattern_belt", "mmwave", "axle_counter"]


class FusionNode(Node):
    def __init__(self):
        super().__init__("fusion")
        scenario = declare(self, "scenario", "", "scenario YAML (gives the track)")
        track = declare(self, "track", "config/track_conventional.yaml", "track YAML")
        self.track = Scenario.from_yaml(scenario).track if scenario else Track.from_yaml(paths.resolve(track))
        sensors = declare(self, "sensors", ALL_SENSORS, "sensor classes to subscribe")
        rate = float(declare(self, "publish_rate", 200.0, "state publish rate [Hz]"))
        d = FusionConfig()
        timeouts = {}
        for item in declare(self, "timeouts", [""], "'sensor:seconds' -> DEGRADED past the timeout"):
            if item:
                name, _, sec = item.partition(":")
                timeouts[name] = float(sec)
        cfg = FusionConfig(
            track_id=self.track.track_id,
            confidence=float(declare(self, "confidence", d.confidence, "probability of the interval")),
            gate_probability=float(declare(self, "gate_probability", d.gate_probability, "chi-square gate")),
            jerk_psd=float(declare(self, "jerk_psd", d.jerk_psd, "white jerk PSD [m^2/s^5]")),
            history=float(declare(self, "history", d.history, "how late a measurement may be [s]")),
            slip_holdoff=float(declare(self, "slip_holdoff", d.slip_holdoff, "wheel exclusion after slip [s]")),
            lost_stddev=float(declare(self, "lost_stddev", d.lost_stddev, "1-sigma above which LOST [m]")),
            timeouts=timeouts)
        self.map_frame = declare(self, "map_frame", "map", "fixed frame")
        self.base_frame = declare(self, "base_frame", "base_link", "vehicle frame")
        self.filter = TrainFilter(cfg)
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
        self.period = 1.0 / rate
        self._next_k = None
        self._used: set[str] = set()
        self.create_timer(self.period, self.on_timer)

    def on_measurement(self, topic, parse, msg):
        try:
            m = parse(msg)
            self.filter.add(m)
        except InputRejected as exc:
            self.diag.reject(topic, exc.reason, str(exc))
            return
        self.diag.accept(topic)
        self._used.add(m.sensor)

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
        now = now_sec(self)
        k_now = math.floor(now / self.period + 1e-9)
        if self._next_k is None or k_now - self._next_k > 200:
            self._next_k = k_now
        while self._next_k <= k_now:
            self.publish_state(self._next_k * self.period)
            self._next_k += 1

    def publish_state(self, t):
        est = self.filter.estimate(t)
        msg = convert.train_state_to_msg(self.mc, t, self.track.track_id, est.position, est.speed, est.acceleration,
                                         est.position_stddev, est.speed_stddev, est.position_min, est.position_max,
                                         est.confidence, est.mode, sorted(self._used))
        self._used.clear()
        self.state_pub.publish(msg)
        self.diag.values.update({"mode": str(est.mode), "position_stddev": f"{est.position_stddev:.3f}"})
        for group, values in self.filter.counters().items():
            for k, v in values.items():
                self.diag.values[f"filter/{group}/{k}"] = f"{v:.3f}" if isinstance(v, float) else str(v)
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

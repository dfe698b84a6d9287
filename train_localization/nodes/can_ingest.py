"""can_ingest node: a wheel pulse generator's and a Doppler radar's CAN frames as standard odometry.

Reads a CAN bus through python-can (``interface`` and ``channel``: socketcan ``vcan0`` / ``can0``,
``virtual`` in one process, any python-can interface) or replays a recorded log (``log``:
candump ``.log``, ``.asc``, ``.blf``, ``.csv``, as can.LogReader reads them, at ``rate``), decodes
the frames with the DBC file ``dbc`` (cantools; core/ingest/canbus.py) and publishes:
  <wheel.topic>  nav_msgs/Odometry of the wheel pulse generator: twist.linear.x the speed from the
                 pulses between two frames, its variance the count's quantisation
  <radar.topic>  geometry_msgs/TwistWithCovarianceStamped of the radar: its speed, the variance
                 of its resolution
both in ``frame_id`` (base_link: + forwards), stamped at receipt on the node clock. The
standard_inputs node reads them as odometry.topic (wheel_sensor) and twist.topic
(doppler_radar) with those sensors' error models (docs/integration.md, "From your drivers").
Refused and counted per reason in /diagnostics (``rejected/can/<reason>``: unknown_id, length,
out_of_range, stale, device_fault, quality, implausible, error_frame: an error or remote frame), never published; ``can/<count>``
counts the frames taken, the frames ``lost`` from the alive counters and the wheel's ``gaps``.

Parameters: PARAMS below (docs/nodes.md).
"""
from __future__ import annotations

import time

import can
from geometry_msgs.msg import TwistWithCovarianceStamped
from nav_msgs.msg import Odometry

from ..core import paths
from ..core.ingest.canbus import CanFrame, CanLimits, CanOdometryDecoder, WheelGeometry
from ..core.ingest.pacing import ReplayPace
from ..core.sensors import wheel
from ..core.sensors.base import Param, check_declared
from ..core.signals import InputRejected
from .common import STREAM_QOS, ConfigurationError, PollingNode, declare_param, spin

PARAMS = {
    "dbc": Param("config/devices/odometry.dbc", "DBC file describing the wheel and radar frames"),
    "interface": Param("socketcan", "python-can interface of the bus (socketcan, virtual, pcan, kvaser, ...)"),
    "channel": Param("vcan0", "its channel (vcan0, can0, ...)"),
    "bus_filter": Param(False, "true: the bus passes only the two messages read (a bus shared with other "
                               "devices); false: every other frame is refused and counted unknown_id"),
    "log": Param("", "recorded CAN log replayed instead of a bus (candump .log, .asc, .blf, .csv); empty: the bus"),
    "rate": Param(1.0, "log replay speed: 1 at the pace of its frames' stamps, 0 as fast as read", (0.0, 1000.0)),
    "wait_for_subscribers": Param(0, "a log replay starts once each topic published has this many subscribers",
                                  (0, 100)),
    "wheel.message": Param("WHEEL_PULSES", "DBC message of the wheel pulse generator; empty: none"),
    "wheel.topic": Param("/wheel/odometry", "nav_msgs/Odometry topic of the wheel's speed"),
    "wheel.pulses_per_revolution": Param(wheel.PARAMS["pulses_per_revolution"].default,
                                         "pulses per wheel revolution of the pulse generator [1]", (1, 1000)),
    "wheel.diameter": Param(wheel.PARAMS["wheel_diameter"].default, "nominal wheel diameter [m] (the wheel "
                                                                     "sensor's wheel_diameter)", (0.1, 2.0)),
    "radar.message": Param("RADAR_SPEED", "DBC message of the Doppler radar; empty: none"),
    "radar.topic": Param("/radar/twist", "geometry_msgs/TwistWithCovarianceStamped topic of the radar's speed"),
    "radar.min_quality": Param(CanLimits.min_quality, "least radar quality of a speed taken [%]", (0.0, 100.0)),
    "max_age": Param(CanLimits.max_age, "a frame stamped further behind the newest on the bus is stale [s]",
                     (0.001, 60.0)),
    "max_gap": Param(CanLimits.max_gap, "two wheel frames further apart give no speed (the next starts anew) [s]",
                     (0.001, 60.0)),
    "max_speed": Param(wheel.PARAMS["max_speed"].default, "highest speed a frame may mean [m/s]", (1.0, 160.0)),
    "frame_id": Param("base_link", "frame of the speeds (x forwards)"),
    "poll_period": Param(0.005, "time between two reads of the bus [s]", (0.001, 1.0)),
}
check_declared(PARAMS, "can_ingest PARAMS")
STREAM = "can"   # the diagnostics' name of the input
MAX_FRAMES = 1000   # frames taken per poll at most (a flood cannot starve the executor)


class CanIngestNode(PollingNode):
    """A managed (lifecycle) node like the sensor nodes: the bus or log is opened on activate."""

    def __init__(self):
        super().__init__("can_ingest", "CAN ingest")
        self.predeclare(PARAMS)
        self._bus = self._log = None
        self.start()

    def _configure(self) -> None:
        v = self.values = {name: declare_param(self, PARAMS, name) for name in PARAMS}
        self.poll_period = float(v["poll_period"])
        try:
            self.decoder = CanOdometryDecoder(
                paths.resolve(v["dbc"]), WheelGeometry(int(v["wheel.pulses_per_revolution"]), v["wheel.diameter"]),
                CanLimits(v["radar.min_quality"], v["max_age"], v["max_gap"], v["max_speed"]),
                v["wheel.message"], v["radar.message"])
        except ValueError as exc:
            raise ConfigurationError(str(exc)) from None
        self.pubs = {"wheel": self.create_lifecycle_publisher(Odometry, v["wheel.topic"], STREAM_QOS),
                     "radar": self.create_lifecycle_publisher(TwistWithCovarianceStamped, v["radar.topic"],
                                                              STREAM_QOS)}

    def _open(self) -> None:
        v = self.values
        try:
            if v["log"]:
                self._log = iter(can.LogReader(paths.resolve(v["log"])))
                self.pace = ReplayPace(float(v["rate"]))
                self._held = None   # the next frame of the log, not yet due
            else:
                filters = ([{"can_id": i, "can_mask": 0x1FFFFFFF if ext else 0x7FF, "extended": ext}
                            for i, ext in self.decoder.frame_ids()] if v["bus_filter"] else None)
                self._bus = can.Bus(interface=v["interface"], channel=v["channel"], can_filters=filters)
        except (OSError, ValueError, ImportError, can.CanError) as exc:
            where = f"log {v['log']}" if v["log"] else f"{v['interface']} {v['channel']}"
            raise OSError(f"CAN {where}: {exc}") from None

    def _close(self) -> None:
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None
        self._log = None

    def _frames(self):
        """The frames that have arrived (a bus) or are due (a log)."""
        for _ in range(MAX_FRAMES):
            if self._bus is not None:
                msg = self._bus.recv(timeout=0.0)
            elif self._log is not None:
                msg = self._held or next(self._log, None)
                if msg is None:
                    self._log = None
                    self.diag.set_status(0, "end of log")
                elif self.pace.due(msg.timestamp, time.monotonic()) > time.monotonic():
                    self._held = msg
                    return
                self._held = None
            else:
                return
            if msg is None:
                return
            yield msg

    def on_timer(self) -> None:
        if self._log is not None and self.pace is not None and any(
                p.get_subscription_count() < self.values["wait_for_subscribers"] for p in self.pubs.values()):
            return
        for msg in self._frames():
            if msg.is_error_frame or msg.is_remote_frame:   # a bus event or a request: no device data
                self.diag.reject(STREAM, "error_frame", f"{'error' if msg.is_error_frame else 'remote'} frame")
                continue
            try:
                out = self.decoder.decode(CanFrame(msg.timestamp, msg.arbitration_id, bytes(msg.data),
                                                   msg.is_extended_id))
            except InputRejected as exc:
                self.diag.reject(STREAM, exc.reason, str(exc))
                continue
            self.diag.accept(STREAM)
            if out is not None:
                self._publish(out.device, out.twist)
        self.diag.values.update({f"can/{k}": str(n) for k, n in self.decoder.stats.items()})

    def _publish(self, device: str, twist) -> None:
        msg = Odometry(child_frame_id=self.values["frame_id"]) if device == "wheel" else TwistWithCovarianceStamped()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = "odom" if device == "wheel" else self.values["frame_id"]
        msg.twist.twist.linear.x = twist.speed
        msg.twist.covariance[0] = twist.speed_variance
        self.pubs[device].publish(msg)


def main(args=None):
    return spin(CanIngestNode, args, usage=__doc__)

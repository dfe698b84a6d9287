"""Speed controller node: a PID on the fused speed commands the traction (seed 003 section 4.3).

Parameters:
  scenario (string, required)  scenario YAML with a ``control`` section (set-points, gains:
                               core/control.py) and ``dynamics`` (the drive's thrust limit:
                               core/dynamics.py)
Topics:
  subscribes localization/state   TrainState of the fusion (reliable, deep queue: every state)
             atp/command          AtpCommand of atp_supervision (reliable): while its brake is
                                  service or emergency the thrust is 0, the friction brake's
                                  demand full and the integral cleared, whatever the state's
                                  quality; released, the PID resumes (nobody publishing: no brake)
  publishes  control/traction     std_msgs/Float64, thrust command along the track [N]
             control/brake        std_msgs/Float64, friction brake demand 0..1 (core/dynamics.py),
                                  on every ATP command and every state
             control/setpoint     std_msgs/Float64, the set-point speed in force [m/s]
             /diagnostics         states and ATP commands taken and refused, the last command,
                                  the ATP brake in force
A state whose speed is not finite or whose stamp goes back is refused and counted; the
controller then commands nothing until the next good state (core.control.SpeedController).
An ATP command with an unknown brake is refused and counted; the brake in force stands.
"""
from __future__ import annotations

import math

from rclpy.node import Node
from std_msgs.msg import Float64

from ..core.control import SpeedController, control_config
from ..core.convert import stamp_to_sec
from ..core.dynamics import Dynamics
from .common import STREAM_QOS, ConfigurationError, Diagnostics, rclpy_classes, required_scenario, spin


class SpeedControllerNode(Node):
    def __init__(self):
        super().__init__("speed_controller")
        sc = required_scenario(self, "scenario YAML with a 'control' section", "a scenario YAML with 'control'")
        if not sc.control:
            raise ConfigurationError(f"scenario {sc.name} has no 'control' section")
        params, setpoints = control_config(sc.control)
        limit = Dynamics(sc.dynamics, sc.track).force_limit
        self.controller = SpeedController(params, setpoints, limit)
        self.mc = rclpy_classes()
        self.traction_pub = self.create_publisher(Float64, "control/traction", STREAM_QOS)
        self.setpoint_pub = self.create_publisher(Float64, "control/setpoint", STREAM_QOS)
        self.brake_pub = self.create_publisher(Float64, "control/brake", STREAM_QOS)
        self.diag = Diagnostics(self, "speed_controller")
        self._t_last: float | None = None
        self.create_subscription(self.mc.TrainState, "localization/state", self.on_state, STREAM_QOS)
        from train_localization_msgs.msg import AtpCommand
        self.create_subscription(AtpCommand, "atp/command", self.on_atp_command, STREAM_QOS)
        self.diag.values["atp_brake"] = self.controller.brake.name

    def on_atp_command(self, msg) -> None:
        try:
            self.controller.set_brake(msg.brake)
        except ValueError:
            self.diag.reject("atp/command", "brake", f"brake {msg.brake} is not one of AtpCommand.BRAKE_*")
            return
        self.diag.accept("atp/command")
        self.brake_pub.publish(Float64(data=float(self.controller.brake_demand)))
        if self.diag.values.get("atp_brake") != self.controller.brake.name:
            self.get_logger().info(f"ATP brake {self.controller.brake.name.lower()}: {msg.reason}")
        self.diag.values["atp_brake"] = self.controller.brake.name

    def on_state(self, msg) -> None:
        t = stamp_to_sec(msg.header.stamp)
        if not math.isfinite(msg.speed) or not math.isfinite(t):
            self.diag.reject("localization/state", "nan", f"state at {t} s with speed {msg.speed}")
            return
        if self._t_last is not None and t <= self._t_last:
            self.diag.reject("localization/state", "stamp_back", f"state at {t:.6f} s after {self._t_last:.6f} s")
            return
        self._t_last = t
        self.diag.accept("localization/state")
        force = self.controller.update(t, msg.speed, msg.acceleration, msg.speed_stddev)
        self.traction_pub.publish(Float64(data=float(force)))
        self.brake_pub.publish(Float64(data=float(self.controller.brake_demand)))
        self.setpoint_pub.publish(Float64(data=float(self.controller.setpoint(t))))
        self.diag.values["command_N"] = f"{force:.2f}"


def main(args=None):
    return spin(SpeedControllerNode, args, usage=__doc__)

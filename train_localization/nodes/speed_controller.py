"""Speed controller node: a PID on the fused speed commands the traction (seed 003 section 4.3).

Parameters:
  scenario (string, required)  scenario YAML with a ``control`` section (set-points, gains:
                               core/control.py) and ``dynamics`` (the drive's thrust limit:
                               core/dynamics.py)
  require_atp (bool)           no traction without a fresh ATP command (default: true when the
                               scenario has an ``atp`` section): until the first one and once
                               they are older than ``atp_timeout`` the controller acts as under
                               an emergency brake
  atp_timeout (double, 1.0)    [s] ATP commands older than this are stale (0.01 .. 60)
  future_tolerance, input_timeout, max_acceleration, plausibility_margin, speed_margin: the
                               admission of the fused states (core/safety; docs/reliability.md)
Topics:
  subscribes localization/state   TrainState of the fusion (reliable, deep queue: every state)
             atp/command          AtpCommand of atp_supervision (reliable): while its brake is
                                  service or emergency the thrust is 0, the friction brake's
                                  demand full and the integral cleared, whatever the state's
                                  quality; released, the PID resumes
  publishes  control/traction     std_msgs/Float64, thrust command along the track [N]
             control/brake        std_msgs/Float64, friction brake demand 0..1 (core/dynamics.py),
                                  on every ATP command and every state
             control/setpoint     std_msgs/Float64, the set-point speed in force [m/s]
             /diagnostics         states and ATP commands taken and refused, the last command,
                                  the ATP brake in force; WARN while the states are stale
Admission: a state stamped ahead of the node clock, not after the last admitted one, with a
speed that is not finite, or out of kinematic reach of the last admitted one (motion) is
refused and counted; an ATP command with an unknown brake or stamped ahead likewise. Every 0.1 s
(node clock): no admitted state for ``input_timeout`` publishes a thrust of 0 (no traction on a
stale state: the last command is never left standing), and a stale ATP (``require_atp``) the
full brake demand.
"""
from __future__ import annotations

from rclpy.node import Node
from std_msgs.msg import Float64

from ..core.control import SpeedController, control_config
from ..core.convert import stamp_to_sec
from ..core.dynamics import Dynamics
from ..core.etcs.supervision import Brake
from ..core.safety import admission, plausibility
from ..core.safety.admission import StreamAdmission, StreamLimits
from ..core.safety.plausibility import Motion, MotionGate, speed_bound
from ..core.safety.state_stream import StateStream
from ..core.signals import InputRejected
from ..core.sensors.base import Param
from .common import (STREAM_QOS, ConfigurationError, Diagnostics, declare_param, declare_params, now_sec,
                     rclpy_classes, required_scenario, spin)

STATE, COMMAND = "localization/state", "atp/command"
WATCHDOG_PERIOD = 0.1     # [s] of the node clock
GUARD_PARAMS = {**admission.PARAMS, **plausibility.PARAMS}
# the node's parameters (tools/docs.py writes them into config/params/speed_controller.yaml)
PARAMS = {
    "scenario": Param("", "scenario YAML with a 'control' section"),
    "require_atp": Param(False, "no traction without a fresh ATP command (default: the scenario has an 'atp' "
                                "section)"),
    "atp_timeout": Param(1.0, "ATP commands older than this are stale: acted on as an emergency brake when "
                              "require_atp [s]", (0.01, 60.0)),
    **GUARD_PARAMS,
}
SCENARIO_DEFAULTS = ("require_atp",)   # their default is the scenario's


class SpeedControllerNode(Node):
    def __init__(self):
        super().__init__("speed_controller")
        sc = required_scenario(self, PARAMS, "a scenario YAML with 'control'")
        if not sc.control:
            raise ConfigurationError(f"scenario {sc.name} has no 'control' section")
        params, setpoints = control_config(sc.control)
        limit = Dynamics(sc.dynamics, sc.track).force_limit
        self.controller = SpeedController(params, setpoints, limit)
        self.require_atp = bool(declare_param(self, PARAMS, "require_atp", bool(sc.atp)))
        atp_timeout = float(declare_param(self, PARAMS, "atp_timeout"))
        guard = declare_params(self, GUARD_PARAMS)
        self.states = StateStream(STATE, admission.limits_from(guard), MotionGate.from_params(guard))
        self.commands = StreamAdmission(COMMAND, StreamLimits(guard["future_tolerance"], atp_timeout, ordered=False))
        self.mc = rclpy_classes()
        self.traction_pub = self.create_publisher(Float64, "control/traction", STREAM_QOS)
        self.setpoint_pub = self.create_publisher(Float64, "control/setpoint", STREAM_QOS)
        self.brake_pub = self.create_publisher(Float64, "control/brake", STREAM_QOS)
        self.diag = Diagnostics(self, "speed_controller")
        self.create_subscription(self.mc.TrainState, STATE, self.on_state, STREAM_QOS)
        from train_localization_msgs.msg import AtpCommand
        self.create_subscription(AtpCommand, COMMAND, self.on_atp_command, STREAM_QOS)
        self.create_timer(WATCHDOG_PERIOD, self.watchdog)
        if self.require_atp:
            self.controller.set_brake(Brake.EMERGENCY)
        self.diag.values["atp_brake"] = self.controller.brake.name

    def on_atp_command(self, msg) -> None:
        refusal = self.commands.admit(stamp_to_sec(msg.header.stamp), now_sec(self))
        try:
            if refusal is not None:
                raise refusal
            brake = Brake(int(msg.brake))
        except InputRejected as exc:
            self.diag.reject(COMMAND, exc.reason, exc.message)
            return
        except ValueError:
            self.diag.reject(COMMAND, "brake", f"brake {msg.brake} is not one of AtpCommand.BRAKE_*")
            return
        self.diag.accept(COMMAND)
        self._brake(brake, msg.reason)

    def _brake(self, brake: Brake, why: str) -> None:
        self.controller.set_brake(brake)
        self.brake_pub.publish(Float64(data=float(self.controller.brake_demand)))
        if self.diag.values.get("atp_brake") != self.controller.brake.name:
            self.get_logger().info(f"ATP brake {self.controller.brake.name.lower()}: {why}")
        self.diag.values["atp_brake"] = self.controller.brake.name

    def on_state(self, msg) -> None:
        t = stamp_to_sec(msg.header.stamp)
        claimed = msg.mode in (1, 2)
        motion = Motion.of(t, claimed, msg.position_min, msg.position_max, msg.speed,
                           speed_bound(msg.confidence, msg.speed_stddev) if claimed else 0.0)
        refusal = self.states.admit(motion, now_sec(self), values={"speed": msg.speed, "speed_stddev": msg.speed_stddev,
                                                                   "acceleration": msg.acceleration})
        if refusal is not None:
            self.diag.reject(STATE, refusal.reason, refusal.message)
            return
        self.diag.accept(STATE)
        force = self.controller.update(t, msg.speed, msg.acceleration, msg.speed_stddev)
        self.traction_pub.publish(Float64(data=float(force)))
        self.brake_pub.publish(Float64(data=float(self.controller.brake_demand)))
        self.setpoint_pub.publish(Float64(data=float(self.controller.setpoint(t))))
        self.diag.values["command_N"] = f"{force:.2f}"
        self.diag.set_status(0, "running")

    def watchdog(self) -> None:
        """No traction on stale states; the brake on a stale ATP (require_atp)."""
        now = now_sec(self)
        if self.require_atp and self.commands.stale(now) and self.controller.brake != Brake.EMERGENCY:
            self._brake(Brake.EMERGENCY, f"no ATP command for {self.commands.silence(now):.1f} s (fail safe)")
        if self.states.admitted and self.states.stale(now) and self.controller.command != 0.0:
            self.controller.integral, self.controller.command = 0.0, 0.0
            self.traction_pub.publish(Float64(data=0.0))
            self.diag.values["command_N"] = "0.00"
            self.diag.set_status(1, f"fused states stale ({self.states.silence(now):.1f} s): no traction")


def main(args=None):
    return spin(SpeedControllerNode, args, usage=__doc__)

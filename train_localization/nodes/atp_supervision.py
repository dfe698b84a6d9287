"""``atp_supervision``: the ATP supervision of one train to its end of authority from the ETCS
location reports (core/etcs/supervision.py, SUBSET-026 section 3.13 simplified), a thin shell.

Topics:
  subscribes localization/etcs         EtcsLocation of etcs_location (reliable, every report)
             localization/etcs_events  EtcsEvent (reliable): linking reactions (train trip,
                                       service brake; none is counted)
             atp/end_of_authority      std_msgs/Float64, a new end of authority (chainage [m]; on a
                                       network on end_of_authority_section; reliable, volatile:
                                       the parameter gives the first one)
  publishes  atp/command               AtpCommand (reliable) for every report that changes the
                                       status or the brake and otherwise every ``command_period``
                                       (0.1 s), every event with a reaction and every new
                                       authority: status, brake (held until standstill), distance
                                       to the EOA, permitted speed
             /diagnostics              OK (normal, indication, warning), WARN on intervention,
                                       ERROR on trip; the supervision's counters; WARN when no
                                       report was received (or none admitted) within
                                       ``report_timeout`` of the start

Parameters (core/etcs/supervision.py PARAMS, read at start): ``end_of_authority`` (chainage
[m]; NaN: none until one comes on the topic), ``end_of_authority_section`` (on a network: its
section, restated on the followed path of each report; the service brake while that path does
not reach it; docs/network.md, "ETCS on a network"), ``orientation`` (+1/-1: the direction the
train's front faces), ``emergency_deceleration`` and ``service_deceleration`` [m/s^2],
``brake_build_up_time`` [s], ``traction_acceleration`` [m/s^2], ``warning_time`` and
``indication_time`` [s], ``unknown_position_speed`` and ``standstill_speed`` [m/s],
``standstill_confirmation`` [s] (a brake is released only after this long at a standstill in
every admitted report); ``report_timeout`` [s] (no admitted location report this long: position
unknown, emergency brake whatever the last report said; checked every 0.1 s on the node clock);
``command_period`` [s] (the node's: how often an unchanged command is repeated); the admission's
``future_tolerance`` [s], ``max_acceleration`` [m/s^2], ``plausibility_margin`` [m],
``speed_margin`` [m/s] (core/etcs/admission.py).

Admission (docs/reliability.md): a report stamped ahead of the node clock (future), not after
the last admitted one (stamp_back, duplicate), that claims a position with a front end or speed
that is not finite (nan) or beyond any train, safe front ends upside down or a negative doubt or
v_ura (implausible), too many previous LRBGs (too_large), or whose safe front ends or speed the
last admitted report rules out (motion: a standstill claimed in the middle of a brake from
speed); an event stamped ahead or with an unknown kind or reaction; a non-finite end of
authority: each refused and counted (rejected/<topic>/<reason>), the last command stands, and a
report stream refused or silent past ``report_timeout`` brakes. The end of authority carries no
stamp or source: it must come from a trusted interface (docs/reliability.md).
"""
from __future__ import annotations

import math
import sys

from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64

from ..core.convert import etcs_event_from_msg, etcs_report_from_msg
from ..core.etcs import admission, supervision
from ..core.etcs.records import Reaction
from ..core.signals import InputRejected
from ..core.sensors.base import Param
from .common import (STREAM_QOS, ConfigurationError, Diagnostics, declare_param, declare_params, now_sec, rclpy_classes,
                     spin)

REPORTS, EVENTS, AUTHORITY, COMMAND = ("localization/etcs", "localization/etcs_events", "atp/end_of_authority",
                                       "atp/command")
# a new authority: reliable (none lost), volatile (matches any reliable publisher)
AUTHORITY_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
LEVEL = {supervision.Status.INTERVENTION: 1, supervision.Status.TRIP: 2}   # others: OK
# the report stream's time-out is report_timeout; nothing is shed (reports come at the state rate)
GUARD_PARAMS = {name: p for name, p in admission.PARAMS.items()
                if name not in ("input_timeout", "max_input_rate", "max_fix_rate")}
# the node's parameters (tools/docs.py writes them into config/params/atp_supervision.yaml)
PARAMS = {**supervision.PARAMS,
          "command_period": Param(0.1, "atp/command is published on every change of status or brake and otherwise "
                                       "at most this often [s]; 0 = for every report", (0.0, 10.0)),
          **GUARD_PARAMS}


class AtpSupervisionNode(Node):
    """Supervision to the end of authority; see the module doc."""

    def __init__(self, **kw):
        Node.__init__(self, "atp_supervision", **kw)
        from train_localization_msgs.msg import AtpCommand, EtcsEvent, EtcsLocation
        self._cmd_cls = AtpCommand
        self.diag = Diagnostics(self, "ATP supervision to the end of authority")
        params = declare_params(self, supervision.PARAMS)
        try:
            self.sup = supervision.Supervision(params)
        except ValueError as exc:
            raise ConfigurationError(str(exc)) from None
        self.command_period = declare_param(self, PARAMS, "command_period")
        self._published: tuple | None = None     # (stamp [s], status, brake) of the last command
        # the report stream's time-out is report_timeout; nothing is shed (reports come at the state rate)
        guard = declare_params(self, GUARD_PARAMS)
        self.inputs = admission.SupervisionAdmission(guard, self.sup.orientation, params["report_timeout"])
        self.mc = rclpy_classes()
        self.track_id = ""
        self.pub = self.create_publisher(AtpCommand, COMMAND, STREAM_QOS)
        self.create_subscription(EtcsLocation, REPORTS, self.on_report, STREAM_QOS)
        self.create_subscription(EtcsEvent, EVENTS, self.on_event, STREAM_QOS)
        self.create_subscription(Float64, AUTHORITY, self.on_authority, AUTHORITY_QOS)
        self.diag.set_status(0, "no location report yet")
        self.create_timer(0.1, self.check_stale)

    def on_report(self, msg) -> None:
        try:
            report = etcs_report_from_msg(msg, self.sup.orientation)
        except InputRejected as exc:
            self.diag.reject(REPORTS, exc.reason, exc.message)
            return
        refusal = self.inputs.report(report, now_sec(self))
        if refusal is not None:
            self.diag.reject(REPORTS, refusal.reason, refusal.message)
            return
        self.track_id = report.track_id
        self.diag.accept(REPORTS)
        d = self.sup.update(report)
        last = self._published
        if last is None or (d.status, d.brake) != last[1:] or not d.t - last[0] < self.command_period:
            self.publish(d)
        else:
            self._diagnose(d)

    def check_stale(self) -> None:
        """Every 0.1 s: the emergency brake when the location reports have stopped (fail safe);
        before the first admitted one, WARN once none came for report_timeout."""
        if not self.inputs.reports.admitted:
            self._check_first_report()
            return
        decision = self.sup.check_stale(self.inputs.reports.silence(now_sec(self)))
        if decision is not None:
            self.get_logger().error(decision.reason)
            self.publish(decision)

    def _check_first_report(self) -> None:
        """No report admitted yet: WARN, saying whether none was received or every one refused, once
        ``report_timeout`` has passed on the node clock since it first ran (nothing to say about a
        last report: there is none)."""
        now = now_sec(self)
        if now <= 0.0:   # no /clock yet
            return
        self.inputs.reports.waiting_since(now)
        waited, timeout = self.inputs.reports.silence(now), self.sup.params["report_timeout"]
        if not waited > timeout:
            return
        refused = sum(n for key, n in self.diag.rejected.items() if key.startswith(f"{REPORTS}/"))
        what = f"admitted ({refused} refused)" if refused else "received"
        self.diag.set_status(1, f"no location report {what} in {waited:.1f} s since the start "
                                f"(report_timeout {timeout:g} s)")

    def on_event(self, msg) -> None:
        try:
            event = etcs_event_from_msg(msg)
        except InputRejected as exc:
            self.diag.reject(EVENTS, exc.reason, exc.message)
            return
        refusal = self.inputs.event(event, now_sec(self))
        if refusal is not None:
            self.diag.reject(EVENTS, refusal.reason, refusal.message)
            return
        self.diag.accept(EVENTS)
        decision = self.sup.on_event(event)
        if event.reaction != Reaction.NONE:
            self.get_logger().warn(f"{event.reaction.name.lower()} on {event.kind.name.lower()} {event.nid_bg}")
            self.publish(decision)
        else:
            self._diagnose(decision)

    def on_authority(self, msg) -> None:
        try:
            decision = self.sup.set_authority(msg.data)
        except ValueError as exc:
            self.diag.reject(AUTHORITY, "nan" if not math.isfinite(msg.data) else "range", str(exc))
            return
        self.diag.accept(AUTHORITY)
        where = f" on section {self.sup.eoa_section}" if self.sup.eoa_section else ""
        self.get_logger().info(f"end of authority {msg.data:.2f} m{where}")
        if self.sup.last_report is not None:
            self.publish(decision)
        else:
            self._diagnose(decision)

    def publish(self, d: supervision.AtpDecision) -> None:
        self._published = (d.t, d.status, d.brake)
        self.pub.publish(self._cmd_cls(header=self.mc.header(d.t), track_id=self.track_id, status=int(d.status),
                                       brake=int(d.brake), end_of_authority=d.end_of_authority,
                                       distance_to_eoa=d.distance_to_eoa, permitted_speed=d.permitted_speed,
                                       reason=d.reason))
        self._diagnose(d)

    def _diagnose(self, d: supervision.AtpDecision) -> None:
        previous = self.diag.values.get("status")
        self.diag.values.update({"status": d.status.name, "brake": d.brake.name,
                                 "end_of_authority_m": f"{d.end_of_authority:.2f}",
                                 "distance_to_eoa_m": f"{d.distance_to_eoa:.2f}",
                                 "permitted_speed_mps": f"{d.permitted_speed:.2f}"})
        self.diag.values.update({k: str(v) for k, v in self.sup.stats.items()})
        self.diag.set_status(LEVEL.get(d.status, 0), f"{d.status.name.lower()}: {d.reason}")
        if previous != d.status.name and d.status >= supervision.Status.INTERVENTION:
            self.get_logger().warn(f"{d.status.name.lower()}, brake {d.brake.name.lower()}: {d.reason}")


def main(args=None):
    sys.exit(spin(AtpSupervisionNode, args, usage=f"{__doc__}\n{AtpSupervisionNode.__doc__}"))

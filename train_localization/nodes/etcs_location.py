"""``etcs_location``: the ETCS location report of one train from its fused state and its balise
reads (core/etcs/location.py; docs/etcs.md), a thin shell.

Subscribes ``localization/state`` (TrainState of the fusion) and ``sensors/eurobalise/position``
(PositionFix of the Eurobalise reader); publishes, for every state, ``localization/etcs``
(EtcsLocation) and, when they happen, ``localization/etcs_events`` (EtcsEvent, reliable:
LRBG changes, groups outside their window, missed linked groups with their Q_LINKREACTION,
wrong-direction passages, ignored groups, odometer impairment).

Parameters: ``scenario`` (YAML: the track with its ETCS data, core/etcs/track_data.py, and the
train's orientation) or ``track`` (track YAML) with ``orientation``; the PARAMS of
core/etcs/location.py (``fix_latency``, ``history``) and of the odometer monitoring
(core/etcs/odometer.py). A track whose ETCS data are inconsistent stops the node with one line.

On a network (a scenario whose train has a route; docs/network.md, "ETCS on a network") the
location function follows the train's path (core/etcs/network_location.py, ``path_wait``,
``path_reach``): it takes the state's path fields, balise fixes on any section of the network,
and ``interlocking/switches`` (SwitchPositions, latched: the path ahead follows the reported
ways; a malformed report or an unknown switch is refused and counted). The report's front ends
are path distances, its ``track_id`` the network's, ``lrbg_track_id`` the LRBG's section and
``path`` the followed path. A network track without a scenario is refused in one line (the
route gives the start).

Admission (core/etcs/admission.py, docs/reliability.md): a state or fix stamped more than
``future_tolerance`` ahead of the node clock (future), not after the last admitted one
(stamp_back, duplicate), with a value that is not finite (nan) or beyond any train
(implausible), an id too long (too_long), a fix of another track (other_track), a state whose
interval or speed the last admitted state rules out (motion: ``max_acceleration``,
``plausibility_margin``, ``speed_margin``) is refused, counted by reason and never reaches the
location function; beyond ``max_input_rate`` states or ``max_fix_rate`` fixes per second they
are shed (``shed/<topic>``), fixes before they are deserialised. No event kind and no input can stop the node.

/diagnostics: the LRBG, d_lrbg, the doubts and the counters; WARN while the odometer is
impaired and for ALARM_HOLD (30 s) after a missed linked group, a rejected group or a group
refused as misplaced (REFERENCE_REJECTED), ERROR for as long after a wrong-direction passage
and while the fused states are stale (nothing admitted for ``input_timeout``: no report is
made, the ATP's report time-out brakes).
"""
from __future__ import annotations

import math
import sys
import time

import yaml

from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message

from ..core import convert, paths
from ..core.etcs import admission, location, network_location
from ..core.etcs.admission import FIX_TOPIC, STATE_TOPIC
from ..core.etcs.network_data import NetworkEtcsData
from ..core.etcs.records import EventKind, LocationEvent, LocationReport
from ..core.etcs.track_data import EtcsData
from ..core.scenario import Scenario
from ..core.signals import InputRejected
from ..core.track import Track
from ..core.sensors.base import Param
from .common import (LATCHED_QOS, STREAM_QOS, SWITCH_TOPIC, ConfigurationError, Diagnostics, declare_param,
                     declare_params, now_sec, rclpy_classes, spin, switch_positions)

ALARM_HOLD = 30.0      # [s] of state time a linking or odometer alarm stays in the diagnostics
REPORT_TOPIC = "localization/etcs"
EVENT_TOPIC = "localization/etcs_events"
# balise fixes: reliable, but a short queue: under a flood DDS drops what the node has not taken
# rather than queueing thousands ahead of the fused states (a reader gives ~12 fixes/s at most)
FIX_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=32, reliability=ReliabilityPolicy.RELIABLE)
# events that are a linking or odometer alarm (WARN for ALARM_HOLD), and the one that is an ERROR
ALARMS = (EventKind.MISSED_LINKED_GROUP, EventKind.OUTSIDE_WINDOW, EventKind.ODOMETER_IMPAIRED,
          EventKind.REFERENCE_REJECTED, EventKind.NOT_LINKED, EventKind.UNKNOWN_GROUP)
# the tracker's parameters but its orientation (the node's, or the scenario's train's)
TRACKER_PARAMS = {name: p for name, p in location.PARAMS.items() if name != "orientation"}
# the node's parameters (tools/docs.py writes them into config/params/etcs_location.yaml)
PARAMS = {
    "scenario": Param("", "scenario YAML (track with ETCS data, the train)"),
    "track": Param("config/track_etcs.yaml", "track YAML when no scenario is given"),
    "orientation": Param(1, "+1: the front faces increasing chainage, -1: decreasing (without a scenario)", (-1, 1)),
    **TRACKER_PARAMS, **network_location.PARAMS, **admission.PARAMS,
}


def state_from_msg(msg) -> location.FusedState:
    """The location function's view of a TrainState message (checked by the admission), with its
    path fields on a network."""
    return location.FusedState(convert.stamp_to_sec(msg.header.stamp), float(msg.position), float(msg.position_min),
                               float(msg.position_max), float(msg.speed), float(msg.speed_stddev),
                               float(msg.confidence), int(msg.mode), msg.track_id,
                               float(getattr(msg, "path_position", math.nan)), float(getattr(msg, "path_min", math.nan)),
                               float(getattr(msg, "path_max", math.nan)), int(getattr(msg, "path_direction", 0)))


def report_to_msg(report: LocationReport, cls, header):
    return cls(header=header, track_id=report.track_id, nid_lrbg=report.nid_lrbg, d_lrbg=report.d_lrbg,
               q_dirlrbg=int(report.q_dirlrbg), q_locacc=report.q_locacc, l_doubtover=report.l_doubtover,
               l_doubtunder=report.l_doubtunder, estimated_front_end=report.estimated_front_end,
               min_safe_front_end=report.min_safe_front_end, max_safe_front_end=report.max_safe_front_end,
               v_est=report.v_est, v_ura=report.v_ura, odometer_impaired=report.odometer_impaired,
               previous_lrbgs=list(report.previous_lrbgs), mode=report.mode, lrbg_track_id=report.lrbg_track_id,
               path=[p.section for p in report.path], path_direction=[p.direction for p in report.path],
               path_origin=[p.origin for p in report.path])


def event_to_msg(event: LocationEvent, cls, header, track_id: str):
    return cls(header=header, track_id=track_id, kind=int(event.kind), nid_bg=event.nid_bg,
               reaction=int(event.reaction), detail=event.detail[:256])


class EtcsLocationNode(Node):
    def __init__(self, **kw):
        Node.__init__(self, "etcs_location", **kw)
        from train_localization_msgs.msg import EtcsEvent, EtcsLocation
        self._report_cls, self._event_cls = EtcsLocation, EtcsEvent
        self.diag = Diagnostics(self, "ETCS location")
        track, orientation, own = self._configuration()
        params = {**declare_params(self, TRACKER_PARAMS), "orientation": orientation}
        on_network = declare_params(self, network_location.PARAMS)
        guard = declare_params(self, admission.PARAMS)
        self.network = own.network if own is not None else None
        try:
            if self.network is None:
                self.tracker = location.LocationTracker(EtcsData.from_track(track), params)
                self.track_id, sections = track.track_id, None
            else:
                self.tracker = network_location.NetworkLocationTracker(
                    NetworkEtcsData.from_network(self.network), self.network, network_location.start_path(own),
                    {**params, **on_network}, own.interlocking)
                self.track_id, sections = self.network.network_id, self.network.sections
        except ValueError as exc:
            raise ConfigurationError(str(exc)) from None
        self.inputs = admission.LocationAdmission(guard, self.track_id, sections)
        self.mc = rclpy_classes()
        self.report_pub = self.create_publisher(EtcsLocation, REPORT_TOPIC, STREAM_QOS)
        self.event_pub = self.create_publisher(EtcsEvent, EVENT_TOPIC, LATCHED_QOS)
        self.create_subscription(self.mc.TrainState, STATE_TOPIC, self.on_state, STREAM_QOS)
        # raw: a fix beyond max_fix_rate is shed before it is deserialised (a flood costs little)
        self.create_subscription(self.mc.PositionFix, FIX_TOPIC, self.on_fix_bytes, FIX_QOS, raw=True)
        if self.network is not None:
            self.create_subscription(self.mc.SwitchPositions, SWITCH_TOPIC, self.on_switches, LATCHED_QOS)
        self._alarm = (0, "", -math.inf)   # (level, what, state time)
        self._report: LocationReport | None = None
        self.diag.set_status(1, "no train state yet")
        self.diag.extra(self._health)

    def _configuration(self) -> tuple[Track, int, Scenario | None]:
        """(track, orientation, the train's scenario or None without one)."""
        scenario_path = declare_param(self, PARAMS, "scenario")
        track_path = declare_param(self, PARAMS, "track")
        orientation = declare_param(self, PARAMS, "orientation")
        if not scenario_path:
            if orientation == 0:
                raise ConfigurationError("parameter 'orientation' must be +1 or -1")
            with open(paths.resolve(track_path), encoding="utf-8") as fh:
                data = yaml.safe_load(fh)
            if isinstance(data, dict) and "sections" in data:
                raise ConfigurationError(f"track {track_path} is a network: give a scenario (the train's route "
                                         f"gives where the location starts)")
            return Track.from_dict(data), int(orientation), None
        own = Scenario.from_yaml(scenario_path).for_namespace(self.get_namespace())
        return own.track, own.orientation(), own

    def on_switches(self, msg) -> None:
        """The interlocking's switch positions (a network): the followed path ahead follows them."""
        positions = switch_positions(self.diag, msg, self.network)
        if positions is not None:
            self.tracker.set_switches(positions)

    def on_fix_bytes(self, data: bytes) -> None:
        if self.inputs.shed(FIX_TOPIC, time.monotonic()):
            return
        self.on_fix(deserialize_message(data, self.mc.PositionFix))

    def on_fix(self, msg) -> None:
        try:
            fix = convert.position_fix_from_msg(msg)
        except (InputRejected, ValueError) as exc:
            reason = exc.reason if isinstance(exc, InputRejected) else "implausible"
            self.diag.reject(FIX_TOPIC, reason, str(exc))
            return
        refusal = self.inputs.fix(fix, now_sec(self))
        if refusal is not None:
            self.diag.reject(FIX_TOPIC, refusal.reason, refusal.message)
            return
        self.diag.accept(FIX_TOPIC)
        self.tracker.on_fix(fix)

    def on_state(self, msg) -> None:
        if self.inputs.shed(STATE_TOPIC, time.monotonic()):
            return
        state = state_from_msg(msg)
        # on a network the stream is checked in path distances (a section's chainage restarts at a node)
        seen = network_location.path_view(state) if self.network is not None else state
        refusal = self.inputs.state(seen, now_sec(self))
        if refusal is not None:
            self.diag.reject(STATE_TOPIC, refusal.reason, refusal.message)
            return
        self.diag.accept(STATE_TOPIC)
        report, events = self.tracker.on_state(state)
        self._report = report
        self.report_pub.publish(report_to_msg(report, self._report_cls, self.mc.header(state.t)))
        for event in events:
            self._on_event(event, state.t)
        if state.t - self._alarm[2] > ALARM_HOLD:
            self._alarm = (0, "", -math.inf)
        self._diagnose(report)

    def _on_event(self, event: LocationEvent, t: float) -> None:
        """Publish, log (one call per severity: rclpy fixes a call site's severity) and hold an alarm."""
        self.event_pub.publish(event_to_msg(event, self._event_cls, self.mc.header(event.t), self.track_id))
        if event.kind in (EventKind.LRBG, EventKind.ODOMETER_RESTORED):
            self.get_logger().info(event.detail)
        elif event.kind == EventKind.WRONG_DIRECTION:
            self.get_logger().error(event.detail)
        elif event.kind in (EventKind.UNKNOWN_GROUP, EventKind.NOT_LINKED, EventKind.REFERENCE_REJECTED):
            self.get_logger().warning(event.detail, throttle_duration_sec=1.0)   # may come in floods
        else:
            self.get_logger().warning(event.detail)
        level = 2 if event.kind == EventKind.WRONG_DIRECTION else 1 if event.kind in ALARMS else 0
        if level and (level >= self._alarm[0] or t - self._alarm[2] > ALARM_HOLD):
            self._alarm = (level, event.detail, t)

    def _health(self) -> list:
        """Every diagnostics period: the state stream's time-out (ERROR while stale) and the shed counts."""
        now = now_sec(self)
        self.inputs.states.waiting_since(now)
        self.diag.values.update({f"shed/{k}": str(v) for k, v in self.inputs.shed_counts.items()})
        if self.inputs.states.stale(now):
            silence = self.inputs.states.silence(now)
            self.diag.set_status(2, f"fused states stale: none admitted for {silence:.1f} s "
                                    f"(input_timeout {self.inputs.states.stream.limits.timeout:g} s): no report")
        elif self._report is not None:
            self._diagnose(self._report)
        return []

    def _diagnose(self, report: LocationReport) -> None:
        self.diag.values.update({"nid_lrbg": report.nid_lrbg or "none", "d_lrbg_m": f"{report.d_lrbg:.2f}",
                                 "l_doubtover_m": f"{report.l_doubtover:.3f}",
                                 "l_doubtunder_m": f"{report.l_doubtunder:.3f}",
                                 "odometer_impaired": str(report.odometer_impaired)})
        self.diag.values.update({k: str(v) for k, v in self.tracker.stats.items()})
        level, note, _ = self._alarm
        if report.odometer_impaired:
            level, note = max(level, 1), note or "odometer impaired: doubts at 5 m + 5 % at least"
        if not report.has_position:
            level, note = max(level, 1), note or "no position claimed by the fusion"
        self.diag.set_status(level, note or f"LRBG {report.nid_lrbg or 'none'}")


def main(args=None):
    sys.exit(spin(EtcsLocationNode, args, usage=__doc__))

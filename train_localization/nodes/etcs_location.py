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

/diagnostics: the LRBG, d_lrbg, the doubts and the counters; WARN while the odometer is
impaired and for ALARM_HOLD (30 s) after a missed linked group or a rejected group, ERROR for as
long after a wrong-direction passage; a state or fix that cannot be used (NaN, an interval upside down, another track) is
counted as rejected and ignored.
"""
from __future__ import annotations

import math
import sys

from rclpy.node import Node

from ..core import convert, paths
from ..core.etcs import location
from ..core.etcs.records import EventKind, LocationEvent, LocationReport
from ..core.etcs.track_data import EtcsData
from ..core.scenario import Scenario
from ..core.signals import InputRejected
from ..core.track import Track
from .common import LATCHED_QOS, STREAM_QOS, ConfigurationError, Diagnostics, declare, rclpy_classes, spin

FIX_TOPIC = "sensors/eurobalise/position"
ALARM_HOLD = 30.0      # [s] of state time a linking or odometer alarm stays in the diagnostics
REPORT_TOPIC = "localization/etcs"
EVENT_TOPIC = "localization/etcs_events"


def state_from_msg(msg) -> location.FusedState:
    """The location function's view of a TrainState message; ValueError if it cannot be used."""
    state = location.FusedState(convert.stamp_to_sec(msg.header.stamp), float(msg.position), float(msg.position_min),
                                float(msg.position_max), float(msg.speed), float(msg.speed_stddev),
                                float(msg.confidence), int(msg.mode))
    if not math.isfinite(state.t):
        raise ValueError(f"stamp {state.t} is not finite")
    if state.claimed:
        values = (state.position, state.position_min, state.position_max, state.speed, state.speed_stddev)
        if not all(map(math.isfinite, values)) or not state.position_min <= state.position <= state.position_max:
            raise ValueError(f"position {state.position} in [{state.position_min}, {state.position_max}], speed "
                             f"{state.speed} +- {state.speed_stddev} cannot be used")
    return state


def report_to_msg(report: LocationReport, cls, header):
    return cls(header=header, track_id=report.track_id, nid_lrbg=report.nid_lrbg, d_lrbg=report.d_lrbg,
               q_dirlrbg=int(report.q_dirlrbg), q_locacc=report.q_locacc, l_doubtover=report.l_doubtover,
               l_doubtunder=report.l_doubtunder, estimated_front_end=report.estimated_front_end,
               min_safe_front_end=report.min_safe_front_end, max_safe_front_end=report.max_safe_front_end,
               v_est=report.v_est, v_ura=report.v_ura, odometer_impaired=report.odometer_impaired,
               previous_lrbgs=list(report.previous_lrbgs), mode=report.mode)


def event_to_msg(event: LocationEvent, cls, header, track_id: str):
    return cls(header=header, track_id=track_id, kind=int(event.kind), nid_bg=event.nid_bg,
               reaction=int(event.reaction), detail=event.detail[:256])


class EtcsLocationNode(Node):
    def __init__(self, **kw):
        Node.__init__(self, "etcs_location", **kw)
        from train_localization_msgs.msg import EtcsEvent, EtcsLocation
        self._report_cls, self._event_cls = EtcsLocation, EtcsEvent
        self.diag = Diagnostics(self, "ETCS location")
        track, orientation = self._configuration()
        params = {name: declare(self, name, p.default, p.description, read_only=True, limits=p.limits)
                  for name, p in location.PARAMS.items() if name != "orientation"}
        try:
            data = EtcsData.from_track(track)
        except ValueError as exc:
            raise ConfigurationError(str(exc)) from None
        self.tracker = location.LocationTracker(data, {**params, "orientation": orientation})
        self.track_id = track.track_id
        self.mc = rclpy_classes()
        self.report_pub = self.create_publisher(EtcsLocation, REPORT_TOPIC, STREAM_QOS)
        self.event_pub = self.create_publisher(EtcsEvent, EVENT_TOPIC, LATCHED_QOS)
        self.create_subscription(self.mc.TrainState, "localization/state", self.on_state, STREAM_QOS)
        self.create_subscription(self.mc.PositionFix, FIX_TOPIC, self.on_fix, STREAM_QOS)
        self._t_last = -math.inf
        self._alarm = (0, "", -math.inf)   # (level, what, state time)
        self.diag.set_status(1, "no train state yet")

    def _configuration(self) -> tuple[Track, int]:
        scenario_path = declare(self, "scenario", "", "scenario YAML (track with ETCS data, the train)",
                                read_only=True)
        track_path = declare(self, "track", "config/track_etcs.yaml", "track YAML when no scenario is given",
                             read_only=True)
        orientation = declare(self, "orientation", 1, "+1: the front faces increasing chainage, -1: decreasing "
                              "(without a scenario)", read_only=True, limits=(-1, 1))
        if not scenario_path:
            if orientation == 0:
                raise ConfigurationError("parameter 'orientation' must be +1 or -1")
            return Track.from_yaml(paths.resolve(track_path)), int(orientation)
        own = Scenario.from_yaml(scenario_path).for_namespace(self.get_namespace())
        return own.track, own.orientation()

    def on_fix(self, msg) -> None:
        try:
            fix = convert.position_fix_from_msg(msg)
        except (InputRejected, ValueError) as exc:
            self.diag.reject(FIX_TOPIC, "implausible", str(exc))
            return
        if fix.track_id != self.track_id:
            self.diag.reject(FIX_TOPIC, "other_track", f"fix on track {fix.track_id!r}, this is {self.track_id!r}")
            return
        self.diag.accept(FIX_TOPIC)
        self.tracker.on_fix(fix)

    def on_state(self, msg) -> None:
        try:
            state = state_from_msg(msg)
        except ValueError as exc:
            self.diag.reject("localization/state", "implausible", str(exc))
            return
        if state.t <= self._t_last:
            self.diag.reject("localization/state", "stamp_back", f"state at {state.t:.6f} s after {self._t_last:.6f} s")
            return
        self._t_last = state.t
        self.diag.accept("localization/state")
        report, events = self.tracker.on_state(state)
        header = self.mc.header(state.t)
        self.report_pub.publish(report_to_msg(report, self._report_cls, header))
        for event in events:
            self.event_pub.publish(event_to_msg(event, self._event_cls, self.mc.header(event.t), self.track_id))
            log = self.get_logger().warning if event.kind not in (EventKind.LRBG,) else self.get_logger().info
            log(event.detail)
            level = 2 if event.kind == EventKind.WRONG_DIRECTION else 1 if event.kind in (
                EventKind.MISSED_LINKED_GROUP, EventKind.OUTSIDE_WINDOW, EventKind.ODOMETER_IMPAIRED) else 0
            if level and (level >= self._alarm[0] or state.t - self._alarm[2] > ALARM_HOLD):
                self._alarm = (level, event.detail, state.t)
        if state.t - self._alarm[2] > ALARM_HOLD:
            self._alarm = (0, "", -math.inf)
        self._diagnose(report)

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

"""Wayside nodes of the neutral-section changeover (seed 004 sections 4.1-4.2), thin shells
around core/wayside:

``wayside_occupancy``           subscribes ``wayside/sections`` (the track-circuit and
                                axle-counter reports), votes per section (occupancy.py) and
                                publishes ``wayside/combined`` (SectionOccupancy, source
                                "combined", reliable + transient-local) on every change and
                                every second; /diagnostics: per section the voted and both
                                systems' states, the disagreements (WARN), contradictions
                                and degraded sections (ERROR).
``neutral_section_controller``  subscribes ``wayside/sections``, votes the same way and runs
                                the changeover (neutral_section.py); publishes
                                ``changeover/abb1`` and ``changeover/abb2`` (std_msgs/Bool,
                                true = closed; reliable + transient-local) on every command;
                                /diagnostics: mode, feed, the safe state with its reason
                                (ERROR), a hold for a following train (WARN).
``crosscheck``                  subscribes ``localization/state`` (the train's fused
                                interval) and ``wayside/combined``; /diagnostics WARN with
                                the flags of crosscheck.py (a train where the line sees
                                nobody, an occupied section no train claims).

Parameters: ``sections`` (strings "SECTION:CIRCUIT:AXLE_SECTION", default seed 004 Fig. 6:
S1:TC1:S1, S2:TC2:S2), ``tc_source`` / ``ac_source`` (the systems' unit ids), the PARAMS of
occupancy.py, neutral_section.py (controller), crosscheck.py (cross-check; ``train_id``),
``rate`` (evaluation timer [Hz], 20). The timer uses the node clock: run with
``use_sim_time`` when the detection runs on simulated time. A report of another source is
counted and ignored (``accepted/sections/other_source``).

Every input is admitted in core first (docs/reliability.md, docs/nodes.md): each system's
reports by occupancy.admit_report (``future``, ``stamp_back``, ``nan``, ``implausible``,
``too_long``, ``too_large``), the cross-check's fused states by core/safety/fused_state.py (and
``motion``); each refusal is counted in /diagnostics (``rejected/<stream>/<reason>``). A stream
with nothing admitted for its time-out is stale: its sections are never CLEAR (a silent system;
the controller then holds the neutral section dead, both ABBs open), the cross-check warns.
"""
from __future__ import annotations

import math
import sys

from rclpy.node import Node

from ..core import convert
from ..core.association import FusedState
from ..core.signals import InputRejected
from ..core.wayside import crosscheck as cc
from ..core.wayside.changeover import ABB_TOPICS, COMBINED_TOPIC
from ..core.wayside import neutral_section as ns
from ..core.wayside import occupancy as oc
from ..core.sensors.base import Param
from .common import (LATCHED_QOS, STATE_QOS, ConfigurationError, Diagnostics, declare_param, declare_params, now_sec,
                     rclpy_classes, spin)

LEVEL = {"ok": 0, "warn": 1, "error": 2}

# the nodes' parameters (tools/docs.py writes them into config/params/<node>.yaml)
VOTING_PARAMS = {   # the combined occupancy's (wayside_occupancy, neutral_section_controller)
    "sections": Param(["S1:TC1:S1", "S2:TC2:S2"], "combined sections SECTION:CIRCUIT:AXLE_SECTION (seed 004 Fig. 6)"),
    "tc_source": Param("track_circuit", "unit id of the track-circuit system"),
    "ac_source": Param("axle_counter", "unit id of the axle-counter system"),
    **oc.PARAMS,
}
OCCUPANCY_PARAMS = {**VOTING_PARAMS, "rate": Param(20.0, "evaluation rate [Hz]", (0.1, 1000.0))}
CONTROLLER_PARAMS = {**VOTING_PARAMS, **ns.PARAMS, "rate": Param(20.0, "evaluation rate [Hz]", (0.1, 1000.0)),
                     "controller": Param("staged", "changeover sequence: 'staged' (both systems agree, the last "
                                                   "axle has left) or 'seed' (seed 004 section 4.1's moments per "
                                                   "running direction); the trade: docs/changeover.md")}
CROSSCHECK_PARAMS = {"train_id": Param("train", "name of the train in the flags"), **cc.PARAMS,
                     "rate": Param(4.0, "evaluation rate [Hz]", (0.1, 1000.0))}


def _section_map(node: Node) -> oc.SectionMap:
    entries = declare_param(node, VOTING_PARAMS, "sections")
    pairs = {}
    for e in entries:
        parts = str(e).split(":")
        if len(parts) != 3 or not all(parts):
            raise ConfigurationError(f"parameter 'sections': {e!r} is not SECTION:CIRCUIT:AXLE_SECTION")
        pairs[parts[0]] = (parts[1], parts[2])
    tc = declare_param(node, VOTING_PARAMS, "tc_source")
    ac = declare_param(node, VOTING_PARAMS, "ac_source")
    return oc.SectionMap(pairs, tc, ac)


class _Voting:
    """The combined occupancy fed from wayside/sections (shared by two nodes)."""

    def _setup_voting(self):
        self.mc = rclpy_classes()
        self.combined = oc.CombinedOccupancy(_section_map(self), declare_params(self, oc.PARAMS))
        self.create_subscription(self.mc.SectionOccupancy, convert.SECTIONS_TOPIC, self.on_sections, LATCHED_QOS)

    def on_sections(self, msg) -> None:
        try:
            occ = convert.occupancy_from_msg(msg)
        except InputRejected as exc:
            self.diag.reject("sections", exc.reason, str(exc))
            return
        if self.combined.update(occ, now_sec(self)):
            self.diag.accept("sections")
            self.latest = max(getattr(self, "latest", -math.inf), occ.stamp)
            self.evaluate()
        elif self.combined.refusal is not None:
            self.diag.reject("sections", self.combined.refusal.reason, str(self.combined.refusal))
        else:
            self.diag.accept("sections/other_source")

    def now(self) -> float:
        return _clock(self)


def _clock(node: Node) -> float:
    """Node clock, or the latest admitted stamp while no clock runs."""
    t = now_sec(node)
    return t if t > 0.0 else getattr(node, "latest", 0.0)


class WaysideOccupancyNode(_Voting, Node):
    def __init__(self, **kw):
        Node.__init__(self, "wayside_occupancy", **kw)
        self.diag = Diagnostics(self, "combined wayside detection")
        self._setup_voting()
        self.pub = self.create_publisher(self.mc.SectionOccupancy, COMBINED_TOPIC, LATCHED_QOS)
        self._last = None
        self._last_pub = -math.inf
        rate = declare_param(self, OCCUPANCY_PARAMS, "rate")
        self.create_timer(1.0 / rate, self.evaluate)
        self.diag.set_status(1, "no report yet")

    def evaluate(self) -> None:
        now = self.now()
        sections = self.combined.evaluate(now)
        states = tuple((s.section_id, s.state) for s in sections)
        if states != self._last or now - self._last_pub >= 1.0:
            self.pub.publish(convert.measurement_to_msg(oc.to_occupancy(now, sections), self.mc))
            self._last, self._last_pub = states, now
        level, notes = 0, []
        for s in sections:
            self.diag.values[f"{s.section_id}/state"] = oc.STATE_NAMES[s.state]
            self.diag.values[f"{s.section_id}/track_circuit"] = oc.STATE_NAMES[s.tc]
            self.diag.values[f"{s.section_id}/axle_counter"] = oc.STATE_NAMES[s.ac]
            if s.contradiction or s.degraded or s.state == oc.DISTURBED:
                level = 2
                notes.append(f"{s.section_id} {'contradictory' if s.contradiction else 'degraded'}")
            elif s.disagreement:
                level = max(level, 1)
                notes.append(f"{s.section_id} disagreement")
        self.diag.values["disagreements"] = str(len(self.combined.records))
        for k, rec in enumerate(self.combined.records[-3:]):
            self.diag.values[f"disagreement/{k}"] = rec.text()
        self.diag.set_status(level, "; ".join(notes) or "systems agree")


class ChangeoverControllerNode(_Voting, Node):
    def __init__(self, **kw):
        Node.__init__(self, "neutral_section_controller", **kw)
        self.diag = Diagnostics(self, "neutral-section changeover")
        self._setup_voting()
        from std_msgs.msg import Bool
        self._bool = Bool
        kind = declare_param(self, CONTROLLER_PARAMS, "controller")
        if kind not in ns.CONTROLLERS:
            raise ConfigurationError(f"parameter 'controller': {kind!r} is not one of {', '.join(ns.CONTROLLERS)}")
        self.ctrl = ns.CONTROLLERS[kind](declare_params(self, ns.PARAMS))
        self.pubs = {sw: self.create_publisher(Bool, topic, LATCHED_QOS) for sw, topic in ABB_TOPICS.items()}
        for sw, closed in self.ctrl.abb.items():
            self.pubs[sw].publish(Bool(data=closed))
        rate = declare_param(self, CONTROLLER_PARAMS, "rate")
        self.create_timer(1.0 / rate, self.evaluate)

    def evaluate(self) -> None:
        now = self.now()
        for cmd in self.ctrl.update(now, self.combined.evaluate(now)):
            self.pubs[cmd.switch].publish(self._bool(data=cmd.on))
            self.get_logger().info(f"{cmd.switch} {'closed' if cmd.on else 'opened'} ({self.ctrl.mode})")
        st = self.ctrl.status()
        self.diag.values.update({k: str(v) for k, v in st.items()})
        if self.ctrl.safe:
            self.diag.set_status(2, f"SAFE STATE (neutral section dead): {self.ctrl.reason}")
        elif self.ctrl.mode.startswith("HOLD"):
            self.diag.set_status(1, f"hold: {self.ctrl.reason}")
        else:
            self.diag.set_status(0, f"{st['mode']}, neutral fed from {st['feed']}")


class CrossCheckNode(Node):
    def __init__(self, **kw):
        Node.__init__(self, "crosscheck", **kw)
        self.diag = Diagnostics(self, "on-board / wayside cross-check")
        self.mc = rclpy_classes()
        train = declare_param(self, CROSSCHECK_PARAMS, "train_id")
        self.inputs = cc.CrossCheckInputs(train, declare_params(self, cc.PARAMS))
        self.inputs.waiting_since(now_sec(self))
        self.create_subscription(self.mc.TrainState, "localization/state", self.on_state, STATE_QOS)
        self.create_subscription(self.mc.SectionOccupancy, COMBINED_TOPIC, self.on_combined, LATCHED_QOS)
        rate = declare_param(self, CROSSCHECK_PARAMS, "rate")
        self.create_timer(1.0 / rate, self.evaluate)
        self.diag.set_status(1, "waiting for the fused state and the combined occupancy")

    def on_state(self, msg) -> None:
        self._count("localization/state", self.inputs.state(FusedState.from_msg(msg), now_sec(self),
                                                            {"sensors": len(msg.sensors)}), msg.header.stamp)

    def on_combined(self, msg) -> None:
        try:
            refusal = self.inputs.occupancy(convert.occupancy_from_msg(msg), now_sec(self))
        except InputRejected as exc:
            refusal = exc
        self._count("wayside/combined", refusal, msg.header.stamp)

    def _count(self, stream: str, refusal: InputRejected | None, stamp) -> None:
        if refusal is not None:
            self.diag.reject(stream, refusal.reason, str(refusal))
            return
        self.diag.accept(stream)
        self.latest = max(getattr(self, "latest", -math.inf), convert.stamp_to_sec(stamp))

    def evaluate(self) -> None:
        flags, stale = self.inputs.evaluate(_clock(self))
        self.diag.values["flags"] = str(len(self.inputs.check.records))
        self.diag.values["stale"] = "; ".join(stale)
        if flags or stale:
            self.diag.set_status(1, "; ".join(stale + [f.text() for f in flags]))
        else:
            self.diag.set_status(0, "fused position agrees with the wayside occupancy")


def main_occupancy(args=None):
    sys.exit(spin(WaysideOccupancyNode, args, usage=f"{__doc__}\n{WaysideOccupancyNode.__doc__}"))


def main_controller(args=None):
    sys.exit(spin(ChangeoverControllerNode, args, usage=f"{__doc__}\n{ChangeoverControllerNode.__doc__}"))


def main_crosscheck(args=None):
    sys.exit(spin(CrossCheckNode, args, usage=f"{__doc__}\n{CrossCheckNode.__doc__}"))

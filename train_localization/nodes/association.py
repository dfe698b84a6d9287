"""Association node: wayside position fixes to the train that explains them (core/association.py).

Runs in ``/wayside`` on a line scenario (several trains). Subscribes the position fixes
of the scenario's wayside sensors (``sensors/<sensor>/position``, relative: in /wayside)
and every train's fused state (``/<train>/localization/state``; on a network also its track
hypotheses, ``/<train>/localization/tracks``, paired with the state of the same stamp); a
fix that exactly one train's fused state explains is published on
``/<train>/sensors/<sensor>/position``, where that train's fusion takes it. Ambiguous and
unexplained fixes are used by no train and counted (``/diagnostics``:
associated/<outcome>, associated/<sensor>/<outcome>).

Parameters:
  scenario (string, required)   the line scenario YAML (trains, their tracks, wayside sensors)
  gate (double)                 [sigma] of the fused interval and the fix (default: the
                                scenario's ``association:``, else 3.29)
  min_speed (double)            [m/s] fused speed below which it gives no direction
  history (double, 10.0)        [s] of fused states kept per train
  future_tolerance (double, 2.0) [s]: a fused state stamped further ahead of the node clock is
                                refused (``future``): one far ahead would make every later one old
"""
from __future__ import annotations

import dataclasses

from rclpy.node import Node

from ..core import convert
from ..core.association import Associator, FusedState
from ..core.network.config import MAX_HYPOTHESES
from ..core.network.hypotheses import TrackHypothesisState
from ..core.scenario import ScenarioError
from ..core.sensors import spec as sensor_spec
from ..core.signals import InputRejected
from .common import (STREAM_QOS, Diagnostics, declare, declare_future_tolerance, now_sec, rclpy_classes,
                     refuse_future, required_scenario, spin)


class AssociationNode(Node):
    def __init__(self):
        super().__init__("association")
        line = required_scenario(self, "line scenario YAML", "a line scenario YAML file")
        if not line.line:
            raise ScenarioError(f"scenario {line.name} has one train: nothing to associate")
        defaults = Associator.for_trains({}, {}, line.association)
        gate = float(declare(self, "gate", defaults.gate, "gate of the fused interval and the fix [sigma]",
                             read_only=True, limits=(1.0, 10.0)))
        min_speed = float(declare(self, "min_speed", defaults.min_speed, "fused speed below which it gives no "
                                  "direction [m/s]", read_only=True, limits=(0.0, 10.0)))
        self.history = float(declare(self, "history", 10.0, "fused states kept per train [s]", read_only=True,
                                     limits=(0.1, 3600.0)))
        self.future_tolerance = declare_future_tolerance(self, "a train's fused state")
        self.mc = rclpy_classes()
        self.states = {name: [] for name in line.trains}
        self.assoc = Associator(self.states, {n: tr.track.track_id for n, tr in line.trains.items()}, gate, min_speed,
                                line.network)
        self.tracks: dict[str, dict[float, tuple]] = {name: {} for name in line.trains}   # stamp -> hypotheses
        self.diag = Diagnostics(self, "association of wayside fixes")
        self.diag.set_status(0, "running")
        self._subs = []
        for name in line.trains:
            self._subs.append(self.create_subscription(
                self.mc.TrainState, f"/{name}/localization/state",
                lambda msg, name=name: self.on_state(name, msg), STREAM_QOS))
            if line.network is not None:
                self._subs.append(self.create_subscription(
                    self.mc.TrackHypotheses, f"/{name}/localization/tracks",
                    lambda msg, name=name: self.on_tracks(name, msg), STREAM_QOS))
        self.pubs = {}
        for node in line.wayside:
            sp = sensor_spec(node)
            if "position" not in sp.outputs:
                continue
            self._subs.append(self.create_subscription(
                self.mc.PositionFix, f"sensors/{sp.sensor}/position", self.on_fix, STREAM_QOS))
            for name in line.trains:
                self.pubs[name, sp.sensor] = self.create_publisher(
                    self.mc.PositionFix, f"/{name}/sensors/{sp.sensor}/position", STREAM_QOS)

    def on_tracks(self, train: str, msg) -> None:
        """A train's track hypotheses: joined to its state of the same stamp (now or when it comes).
        Refused (counted): more than MAX_HYPOTHESES, or a section the network does not have."""
        stamp = convert.stamp_to_sec(msg.header.stamp)
        sections = self.assoc.network.sections
        if len(msg.hypotheses) > MAX_HYPOTHESES:
            self.diag.reject(f"/{train}/localization/tracks", "too_large",
                             f"{len(msg.hypotheses)} hypotheses (at most {MAX_HYPOTHESES})")
            return
        unknown = [sid for h in msg.hypotheses for sid in (h.track_id, *h.path) if sid not in sections]
        if unknown:
            self.diag.reject(f"/{train}/localization/tracks", "unknown_id",
                             f"section {unknown[0][:64]!r} is not in network {self.assoc.network.network_id}")
            return
        self.diag.accept(f"/{train}/localization/tracks")
        hypotheses = tuple(TrackHypothesisState(h.track_id, float(h.position), float(h.speed), float(h.position_min),
                                                float(h.position_max), float(h.probability), tuple(h.path), 0)
                           for h in msg.hypotheses)
        states = self.states[train]
        for k in range(len(states) - 1, max(-1, len(states) - 50), -1):
            if states[k].stamp == stamp:
                states[k] = dataclasses.replace(states[k], hypotheses=hypotheses)
                return
            if states[k].stamp < stamp:
                break
        pending = self.tracks[train]
        pending[stamp] = hypotheses
        while len(pending) > 50:   # hypotheses whose state never came
            del pending[min(pending)]

    def on_state(self, train: str, msg) -> None:
        states = self.states[train]
        stamp = convert.stamp_to_sec(msg.header.stamp)
        state = FusedState(stamp, float(msg.position), float(msg.position_min),
                           float(msg.position_max), float(msg.speed), float(msg.speed_stddev), int(msg.mode),
                           self.tracks[train].pop(stamp, ()))
        try:
            refuse_future(state.stamp, now_sec(self), self.future_tolerance, "fused state")
        except InputRejected as exc:
            self.diag.reject(f"/{train}/localization/state", exc.reason, str(exc))
            return
        if states and state.stamp <= states[-1].stamp:
            self.diag.reject(f"/{train}/localization/state", "stamp_back", "fused state not newer than the last")
            return
        states.append(state)
        self.diag.accept(f"/{train}/localization/state")
        if state.stamp - states[0].stamp > 2 * self.history:
            cut = next(i for i, s in enumerate(states) if s.stamp >= state.stamp - self.history)
            del states[:cut]

    def on_fix(self, msg) -> None:
        try:
            fix = convert.position_fix_from_msg(msg)
            fix.validate()
            if (fix.sensor not in {s for _, s in self.pubs}):
                raise InputRejected("unknown_sensor", f"fix of sensor {fix.sensor!r}, not wayside equipment here")
        except InputRejected as exc:
            self.diag.reject("fixes", exc.reason, str(exc))
            return
        self.diag.accept("fixes")
        train = self.assoc.associate(fix)
        outcome = self.assoc.decisions[-1].outcome
        self.diag.values[f"associated/{outcome}"] = str(self.assoc.counts[outcome])
        self.diag.values[f"associated/{fix.sensor}/{outcome}"] = str(self.assoc.by_sensor[fix.sensor, outcome])
        del self.assoc.decisions[:-100]   # a node runs for hours: keep the last ones only
        if train is not None:
            self.pubs[train, fix.sensor].publish(msg)


def main(args=None):
    return spin(AssociationNode, args, usage=__doc__)

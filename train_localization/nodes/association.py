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
  future_tolerance, input_timeout, max_acceleration, plausibility_margin, speed_margin: the
                                admission of each train's fused states and track hypotheses
                                (core/safety/fused_state.py, core/association.py TrainInputs;
                                docs/nodes.md): refused by reason, counted in /diagnostics
                                (rejected//<train>/localization/state/<reason>); a train whose
                                stream is stale explains every fix after its last state
"""
from __future__ import annotations

from rclpy.node import Node

from ..core import convert
from ..core.association import Associator, FusedState, TrainInputs
from ..core.scenario import ScenarioError
from ..core.sensors import spec as sensor_spec
from ..core.signals import InputRejected
from ..core.safety.fused_state import PARAMS as ADMISSION_PARAMS
from ..core.sensors.base import Param
from .common import (STREAM_QOS, Diagnostics, declare_param, declare_params, now_sec, rclpy_classes, required_scenario,
                     spin)

# the node's parameters (tools/docs.py writes them into config/params/association.yaml)
PARAMS = {
    "scenario": Param("", "line scenario YAML"),
    "gate": Param(Associator.gate, "gate of the fused interval and the fix [sigma]", (1.0, 10.0)),
    "min_speed": Param(Associator.min_speed, "fused speed below which it gives no direction [m/s]", (0.0, 10.0)),
    "history": Param(10.0, "fused states kept per train [s]", (0.1, 3600.0)),
    **ADMISSION_PARAMS,
}
SCENARIO_DEFAULTS = ("gate", "min_speed")   # their default is the scenario's association: section


class AssociationNode(Node):
    def __init__(self):
        super().__init__("association")
        line = required_scenario(self, PARAMS, "a line scenario YAML file")
        if not line.line:
            raise ScenarioError(f"scenario {line.name} has one train: nothing to associate")
        defaults = Associator.for_trains({}, {}, line.association)
        gate = float(declare_param(self, PARAMS, "gate", defaults.gate))
        min_speed = float(declare_param(self, PARAMS, "min_speed", defaults.min_speed))
        history = float(declare_param(self, PARAMS, "history"))
        params = declare_params(self, ADMISSION_PARAMS)
        self.mc = rclpy_classes()
        self.inputs = {name: TrainInputs(name, params, history, line.network, tr.track.circumference)
                       for name, tr in line.trains.items()}
        for inputs in self.inputs.values():
            inputs.state_stream.waiting_since(now_sec(self))
        self.assoc = Associator({n: i.states for n, i in self.inputs.items()},
                                {n: tr.track.track_id for n, tr in line.trains.items()}, gate, min_speed, line.network)
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
        """A train's track hypotheses: joined to its state of the same stamp (now or when it comes)."""
        self._count(f"/{train}/localization/tracks", self.inputs[train].tracks(
            convert.stamp_to_sec(msg.header.stamp), msg.network_id, msg.hypotheses, now_sec(self)))

    def on_state(self, train: str, msg) -> None:
        self._count(f"/{train}/localization/state", self.inputs[train].state(
            FusedState.from_msg(msg), now_sec(self), {"sensors": len(msg.sensors)}))

    def _count(self, stream: str, refusal: InputRejected | None) -> None:
        if refusal is None:
            self.diag.accept(stream)
        else:
            self.diag.reject(stream, refusal.reason, str(refusal))

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
        now = now_sec(self)
        stale = sorted(n for n, i in self.inputs.items() if i.stale(now))
        self.diag.values["stale_trains"] = ", ".join(stale)
        self.diag.set_status(1 if stale else 0, f"stale: {', '.join(stale)} (may be anywhere after their last state)"
                             if stale else "running")
        train = self.assoc.associate(fix, set(stale))
        outcome = self.assoc.decisions[-1].outcome
        self.diag.values[f"associated/{outcome}"] = str(self.assoc.counts[outcome])
        self.diag.values[f"associated/{fix.sensor}/{outcome}"] = str(self.assoc.by_sensor[fix.sensor, outcome])
        del self.assoc.decisions[:-100]   # a node runs for hours: keep the last ones only
        if train is not None:
            self.pubs[train, fix.sensor].publish(msg)


def main(args=None):
    return spin(AssociationNode, args, usage=__doc__)

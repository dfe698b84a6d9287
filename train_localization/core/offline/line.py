"""Several trains on one line (``Scenario.line``), offline: the simulated devices of the line
(``LineSimulation``), the fusion side of a line run (``LineFusion``: every train's fusion,
the wayside measurements, their association with the trains, a changeover section's
detection and controller) and the simulation of a line (``simulate_line``).

The bags carry train X's topics under ``/X/...``, the wayside's under ``/wayside/...`` and
the scenario on ``/scenario``. A line with a changeover section (``wayside: changeover:``)
also runs its combined detection and controller on the wayside reports
(core/wayside/changeover.py ChangeoverLoop, as the two wayside nodes do live) and writes
the ABB commands on ``/wayside/changeover/abb1`` and ``abb2`` (std_msgs/Bool).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .. import convert
from ..association import Associator
from ..bagio import BagWriter, typestore, typestore_classes
from ..measurements import PositionFix, SectionOccupancy
from ..pipeline import SensorPipeline, sensor_pipelines
from ..scenario import Scenario
from ..sensors import spec as sensor_spec
from ..signals import InputRejected
from ..wayside.changeover import ABB_TOPICS, ChangeoverLoop
from .bags import string_message, write_interlocking
from .feed import FusionFeed, RunResult, fusion_runner
from .topics import LINE_SCENARIO_TOPIC, WAYSIDE_NAMESPACE, raw_topic, train_namespace


@dataclass
class LineResult:
    """A line run: one RunResult per train, the wayside measurements (all, as decoded) and the
    association of the wayside fixes with the trains."""

    trains: dict = field(default_factory=dict)        # train name -> RunResult
    wayside: list = field(default_factory=list)       # wayside measurements
    associator: Associator | None = None
    blocks: int = 0                                    # wayside raw blocks
    rejected: dict = field(default_factory=dict)      # wayside rejections by reason
    changeover: ChangeoverLoop | None = None          # the changeover section's detection and controller
    scenario: Scenario | None = None


def wayside_pipelines(scenario: Scenario, simulate: bool = True) -> dict[str, SensorPipeline]:
    """Raw topic -> SensorPipeline of each wayside sensor of a line, simulating ones seeing every train."""
    fleet = {name: tr.vehicle for name, tr in scenario.trains.items()} if simulate else None
    routes = {name: tr.route for name, tr in scenario.trains.items()}
    wayside = scenario.for_namespace(WAYSIDE_NAMESPACE)
    pipes = {}
    for node, params in wayside.sensors.items():
        spec = sensor_spec(node)
        unit = (params or {}).get("unit_id") or spec.sensor
        pipes[raw_topic(spec.sensor, WAYSIDE_NAMESPACE)] = SensorPipeline(
            spec, params, wayside.track, wayside.vehicle, wayside.rng(node, unit), simulate=simulate, fleet=fleet,
            network=scenario.network, routes=routes)
    return pipes


class LineFusion:
    """The fusion side of a line run: every train's FusionFeed, the wayside measurements and
    their association. Wayside fixes are associated with the fused states published
    before the truth step at which they are decoded, as an association node would."""

    def __init__(self, scenario: Scenario, fusion_rate: float, writer: BagWriter | None, mc):
        self.writer, self.mc = writer, mc
        self.outs = {}
        for name, train in scenario.trains.items():
            runner = fusion_runner(train, fusion_rate)
            self.outs[name] = FusionFeed(runner, RunResult(runner=runner), writer, mc, train.track,
                                         train_namespace(train))
        associator = Associator.for_trains({n: o.result.estimates for n, o in self.outs.items()},
                                           {n: o.track_id for n, o in self.outs.items()}, scenario.association,
                                           scenario.network)
        site = scenario.changeover_site()
        self.result = LineResult(trains={n: o.result for n, o in self.outs.items()}, associator=associator,
                                 changeover=ChangeoverLoop(site) if site else None, scenario=scenario)
        if writer and site:
            ctrl = self.result.changeover.controller
            for switch, closed in ctrl.abb.items():   # the controller node's latched start states
                self._abb(switch, closed, 0.0)

    def _abb(self, switch: str, closed: bool, t: float) -> None:
        self.writer.write(f"{WAYSIDE_NAMESPACE}/{ABB_TOPICS[switch]}",
                          typestore().types["std_msgs/msg/Bool"](data=bool(closed)), convert.sec_to_ns(t))

    def _control(self, t: float) -> None:
        loop = self.result.changeover
        if loop is None:
            return
        for cmd in loop.evaluate(t):
            if self.writer:
                self._abb(cmd.switch, cmd.on, t)

    def truth(self, name: str, state, t_ns: int) -> None:
        self.outs[name].truth(state, t_ns)

    def wayside(self, measurements: list, t: float) -> None:
        """Wayside measurements decoded at t [s]: published under /wayside; each fix goes to the
        train the association names (published there too), or to none."""
        for m in measurements:
            self.result.wayside.append(m)
            if self.writer:
                self.writer.write(f"{WAYSIDE_NAMESPACE}/{convert.measurement_topic(m)}",
                                  convert.measurement_to_msg(m, self.mc), convert.sec_to_ns(t))
            if isinstance(m, PositionFix):
                train = self.result.associator.associate(m)
                if train is not None:
                    self.outs[train].take([m], t)
            elif isinstance(m, SectionOccupancy) and self.result.changeover is not None:
                self.result.changeover.report(m)
        self._control(t)

    def reject(self, exc: InputRejected) -> None:
        self.result.rejected[exc.reason] = self.result.rejected.get(exc.reason, 0) + 1

    def states(self, t: float) -> None:
        self._control(t)
        for out in self.outs.values():
            out.states(t)

    def flush(self) -> None:
        for out in self.outs.values():
            out.flush()


class LineSimulation:
    """The simulated devices of a line, stepped at the truth rate: every train's truth and
    on-board sensors, and the wayside sensors seeing all trains (what simulate_line fuses
    and what the simulator node of a line publishes).

    ``step(k)`` returns (t, {train: TruthState}, [(namespace, pipeline, raw block), ...]) of
    truth step k, blocks in the order they complete: each train's on-board ones after its
    truth, the wayside ones once every train's truth of the step is in.
    """

    def __init__(self, scenario: Scenario):
        self.scenario = scenario
        self.trains = scenario.trains
        self.trajectories = {name: tr.trajectory() for name, tr in self.trains.items()}
        self.pipes = {name: sensor_pipelines(tr) for name, tr in self.trains.items()}
        self.namespaces = {name: train_namespace(tr) for name, tr in self.trains.items()}
        self.wayside = wayside_pipelines(scenario)

    def steps(self, t_end: float | None = None) -> int:
        t_end = self.scenario.duration if t_end is None else t_end
        return int(round(t_end * self.scenario.truth_rate)) + 1

    def step(self, k: int):
        t = convert.canonical(k / self.scenario.truth_rate)
        truths, blocks = {}, []
        for name in self.trains:
            state = truths[name] = self.trajectories[name].state_at(t)
            ns = self.namespaces[name]
            blocks.extend((ns, pipe, block) for pipe in self.pipes[name] for block in pipe.on_truth(state))
            for pipe in self.wayside.values():
                blocks.extend((WAYSIDE_NAMESPACE, pipe, block) for block in pipe.on_truth(state, name))
        return t, truths, blocks


def simulate_line(scenario: Scenario, bag: str | Path | None = None, fusion_rate: float = 200.0,
                  record_raw: bool = True, t_end: float | None = None) -> LineResult:
    """``simulate_scenario`` of a line: at each truth step every train's truth, its on-board
    sensors and their measurements, then the wayside sensors (complete once all trains'
    truth is in) and the association of their fixes, then every train's fused states."""
    mc = typestore_classes() if bag else None
    writer = BagWriter(bag) if bag else None
    line = LineFusion(scenario, fusion_rate, writer, mc)
    sim = LineSimulation(scenario)
    outs = {out.namespace: out for out in line.outs.values()}
    if writer:
        writer.write(LINE_SCENARIO_TOPIC, string_message(scenario.to_yaml()), 0)
        for name, train in scenario.trains.items():
            write_interlocking(writer, mc, train, train_namespace(train))
    try:
        for k in range(sim.steps(t_end)):
            t, truths, blocks = sim.step(k)
            for name, state in truths.items():
                line.truth(name, state, convert.sec_to_ns(t))
            for ns, pipe, block in blocks:
                if writer and record_raw:
                    writer.write(raw_topic(block.sensor, ns), convert.raw_block_to_msg(block, mc), convert.sec_to_ns(t))
                out = outs.get(ns)
                if out is not None:
                    out.result.blocks += 1
                    out.decode(pipe, block, t)
                    continue
                line.result.blocks += 1
                try:
                    line.wayside(pipe.on_block(block), t)
                except InputRejected as exc:
                    line.reject(exc)
            line.states(t)
        line.flush()
    finally:
        if writer:
            writer.close()
    return line.result

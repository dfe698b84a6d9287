"""One train's fusion in an offline run: its FusionRunner, what the run collects
(``RunResult``) and the feed that hands the decoded measurements to the fusion and writes
both to the bag (``FusionFeed``)."""
from __future__ import annotations

from dataclasses import dataclass, field

from .. import convert
from ..bagio import BagWriter
from ..fusion import FusionRunner, estimate_to_msg, fusion_config, order_key
from ..measurements import SectionOccupancy
from ..network.config import network_fusion_config
from ..network.hypotheses import HypothesisSet
from ..pipeline import SensorPipeline
from ..scenario import Scenario
from ..signals import InputRejected
from ..track import Track
from ..truth import TruthState
from ...graph import NAMESPACE
from .topics import TRACKS_TOPIC


@dataclass
class RunResult:
    """A one-train offline run: truth states, estimates and measurements in order, raw blocks
    read, rejections by reason, and the runner."""

    truth: list = field(default_factory=list)       # TruthState
    estimates: list = field(default_factory=list)   # Estimate
    measurements: list = field(default_factory=list)
    blocks: int = 0
    rejected: dict = field(default_factory=dict)
    runner: FusionRunner | None = None


def fusion_runner(scenario: Scenario, rate: float = 200.0) -> FusionRunner:
    """The fusion of one train's scenario: a FusionRunner of its FusionConfig, or on a network
    (core/network) one over the track hypotheses, with the interlocking's switch positions
    (what the train's ``interlocking/switches`` topic carries)."""
    if scenario.network is None:
        return FusionRunner(fusion_config(scenario), rate)
    cfg, net = network_fusion_config(scenario)
    hypotheses = HypothesisSet(cfg, net, scenario.network)
    hypotheses.set_switches(scenario.interlocking)
    return FusionRunner(cfg, rate, hypotheses)


class FusionFeed:
    """Takes decoded measurements, feeds the fusion, collects and writes both.

    The measurements decoded since the last grid step are held and given to the
    fusion in the filter's own order (``order_key``) just before the next estimate
    is made: the filter's result does not depend on the order in which a set of
    measurements is added (core/fusion/history.py), so the estimates are the same, but
    measurements of one step that arrive out of stamp order (blocks of several
    sensors ending at the same time) no longer roll the filter back one by one.
    """

    def __init__(self, runner: FusionRunner, result: RunResult, writer: BagWriter | None, mc, track: Track,
                 namespace: str = NAMESPACE):
        self.runner, self.result, self.writer, self.mc = runner, result, writer, mc
        self.track, self.track_id = track, track.track_id   # the train's track (on a network: its route line)
        self.namespace = namespace
        self._pending: list = []

    def truth(self, state: TruthState, t_ns: int) -> None:
        """A ground-truth state: kept, and written in the fused state's frame (convert.truth_to_msg)."""
        self.result.truth.append(state)
        if self.writer:
            self.writer.write(f"{self.namespace}/ground_truth/state", convert.truth_to_msg(self.mc, state, self.track),
                              t_ns)

    def reject(self, exc: InputRejected) -> None:
        self.result.rejected[exc.reason] = self.result.rejected.get(exc.reason, 0) + 1

    def decode(self, pipe: SensorPipeline, block, t: float) -> None:
        try:
            measurements = pipe.on_block(block)
        except InputRejected as exc:
            self.reject(exc)
            return
        self.take(measurements, t)

    def take(self, measurements: list, t: float) -> None:
        """Measurements decoded at time t [s] (published then)."""
        for m in measurements:
            self.result.measurements.append(m)
            if self.writer:
                self.writer.write(f"{self.namespace}/{convert.measurement_topic(m)}",
                                  convert.measurement_to_msg(m, self.mc), convert.sec_to_ns(t))
            if not isinstance(m, SectionOccupancy):
                self._pending.append(m)

    def flush(self) -> None:
        """Give the held measurements to the fusion, in the filter's order."""
        if self._pending:
            pending, self._pending = self._pending, []
            pending.sort(key=order_key)
            for m in pending:
                self.runner.add(m)

    def states(self, t: float) -> None:
        if not self.runner.due(t):
            return
        self.flush()
        for est, used in self.runner.advance(t):
            self.result.estimates.append(est)
            if self.writer:
                self.writer.write(f"{self.namespace}/localization/state",
                                  estimate_to_msg(self.mc, est, self.track_id, used, self.runner.filter.cfg.track),
                                  convert.sec_to_ns(est.stamp))
                network = getattr(self.runner.filter, "network", None)
                if network is not None:
                    self.writer.write(f"{self.namespace}/{TRACKS_TOPIC}",
                                      convert.track_hypotheses_to_msg(self.mc, est, network.network_id), convert.sec_to_ns(est.stamp))

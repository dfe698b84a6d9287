"""A scenario simulated offline: its sensors, decoders and fusion in one process, optionally
into a bag with the live graph's topics (``simulate_scenario``); the measurement sequence
alone and the fusion of it, for benchmarks and campaigns (``scenario_measurements``,
``delayed``, ``fuse_arrivals``)."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .. import convert
from ..bagio import BagWriter, typestore_classes
from ..fusion import FusionConfig, FusionRunner
from ..measurements import SectionOccupancy
from ..pipeline import SensorPipeline, sensor_pipelines
from ..scenario import Scenario
from ..signals import InputRejected
from ...graph import NAMESPACE
from .bags import string_message, write_interlocking
from .feed import FusionFeed, RunResult, fusion_runner
from .line import simulate_line
from .topics import SCENARIO_TOPIC, raw_topic


def scenario_measurements(scenario: Scenario, t_end: float | None = None,
                          pipes: list[SensorPipeline] | None = None, trajectory=None) -> list[tuple[float, object]]:
    """(arrival time, measurement) of every fused measurement of a simulated scenario.

    The sensors run as in ``simulate_scenario`` (same pipelines, random streams and
    truth steps); a measurement arrives at the truth step that completed its block.
    ``pipes`` (from ``sensor_pipelines``) lets the caller read the devices'
    statistics afterwards, ``trajectory`` saves computing the scenario's motion again.
    Rejected blocks are counted in each pipeline's ``rejected``.
    """
    pipes = sensor_pipelines(scenario) if pipes is None else pipes
    traj = scenario.trajectory() if trajectory is None else trajectory
    t_end = scenario.duration if t_end is None else t_end
    out = []
    for k in range(int(round(t_end * scenario.truth_rate)) + 1):
        t = convert.canonical(k / scenario.truth_rate)
        state = traj.state_at(t)
        for pipe in pipes:
            for block in pipe.on_truth(state):
                try:
                    ms = pipe.on_block(block)
                except InputRejected:
                    continue
                out.extend((t, m) for m in ms if not isinstance(m, SectionOccupancy))
    return out


def delayed(arrivals, delay: float, seed: int = 1):
    """The same measurements, each arriving a further U(0, delay) s later, in arrival order."""
    rng = np.random.default_rng(seed)
    late = [(t + float(rng.uniform(0.0, delay)), i, m) for i, (t, m) in enumerate(arrivals)]
    late.sort(key=lambda item: (item[0], item[1]))
    return [(t, m) for t, _, m in late]


def within_latency(arrivals, latencies: dict[str, float], seed: int = 1):
    """The same measurements, each arriving at a uniform time between its arrival and its stamp
    plus its sensor's ``latencies`` [s] (one arriving later already keeps its time), in arrival order."""
    rng = np.random.default_rng(seed)
    late = []
    for i, (t, m) in enumerate(arrivals):
        last = m.stamp + latencies.get(m.sensor, 0.0)
        late.append((t + float(rng.uniform(0.0, last - t)) if last > t else t, i, m))
    late.sort(key=lambda item: (item[0], item[1]))
    return [(t, m) for t, _, m in late]


def fuse_arrivals(config: FusionConfig, arrivals, t_end: float, rate: float = 200.0, tick: float = 0.005,
                  runner: FusionRunner | None = None):
    """Feed (arrival time, measurement) pairs to a FusionRunner, advancing its output grid every ``tick`` s.

    Everything that has arrived by a tick is added before the estimates up to that tick
    are made, as the fusion node does in real time; the last tick ends the input
    (``FusionRunner.drain``: a holding runner makes its last states without waiting). ``runner``: the FusionRunner to feed (a
    train on a network: ``fusion_runner``'s, over its track hypotheses); by default a new one
    of ``config`` at ``rate``. Returns (runner, estimates, CPU seconds in add, CPU seconds in
    advance).
    """
    runner = FusionRunner(config, rate) if runner is None else runner
    estimates = []
    t_add = t_adv = 0.0
    j, n = 0, len(arrivals)
    clock = time.process_time
    last = int(round(t_end / tick))
    for k in range(last + 1):
        now = k * tick
        c0 = clock()
        while j < n and arrivals[j][0] <= now + 1e-12:
            runner.add(arrivals[j][1])
            j += 1
        c1 = clock()
        estimates.extend(e for e, _ in (runner.drain(now) if k == last else runner.advance(now)))
        c2 = clock()
        t_add += c1 - c0
        t_adv += c2 - c1
    return runner, estimates, t_add, t_adv


def simulate_scenario(scenario: Scenario, bag: str | Path | None = None, fusion_rate: float = 200.0,
                      record_raw: bool = True, t_end: float | None = None) -> RunResult:
    """Run the scenario's sensors and the fusion in one process; optionally write a bag.

    Order of events: at each truth step the truth is published, every sensor turns
    the blocks it completed into measurements (published at the block end), the
    fusion takes them, then the fused states up to the step time are produced.
    A line scenario runs ``simulate_line`` (a LineResult).
    """
    if scenario.line:
        return simulate_line(scenario, bag, fusion_rate, record_raw, t_end)
    mc = typestore_classes() if bag else None
    writer = BagWriter(bag) if bag else None
    pipes = sensor_pipelines(scenario)
    runner = fusion_runner(scenario, fusion_rate)
    traj = scenario.trajectory()
    result = RunResult(runner=runner)
    t_end = scenario.duration if t_end is None else t_end
    n = int(round(t_end * scenario.truth_rate)) + 1
    out = FusionFeed(runner, result, writer, mc, scenario.track)
    if writer:
        writer.write(SCENARIO_TOPIC, string_message(scenario.to_yaml()), 0)
        write_interlocking(writer, mc, scenario, NAMESPACE)
    try:
        for k in range(n):
            t = convert.canonical(k / scenario.truth_rate)
            state = traj.state_at(t)
            out.truth(state, convert.sec_to_ns(t))
            for pipe in pipes:
                for block in pipe.on_truth(state):
                    result.blocks += 1
                    if writer and record_raw:
                        writer.write(raw_topic(block.sensor),
                                     convert.raw_block_to_msg(block, mc), convert.sec_to_ns(t))
                    out.decode(pipe, block, t)
            out.states(t)
        out.flush()
    finally:
        if writer:
            writer.close()
    return result

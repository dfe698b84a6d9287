"""Offline replay (docs/replay.md): a bag's raw topics through the decoders (ingest mode) and
the fusion, in log-time order, as fast as the CPU allows, optionally into a new bag with the
recomputed outputs: one train's bag (``replay_bag``) or a line's (``replay_line``). A train
whose scenario names ``standard_inputs`` has its drivers' standard messages (NavSatFix, Imu,
Odometry, ...) read from those topics by the standard_inputs node's core (core/ingest/inputs.py)."""
from __future__ import annotations

import contextlib
import gc
from pathlib import Path
from typing import Callable

from .. import convert
from ..bagio import BagReader, BagWriter, topic_counts, typestore_classes
from ..ingest.inputs import InputReader, StandardInputs, input_values
from ..pipeline import SensorPipeline
from ..scenario import Scenario
from ..sensors import spec as sensor_spec
from ..signals import InputRejected
from .bags import scenario_from_bag
from .feed import FusionFeed, RunResult, fusion_runner
from .line import LineFusion, LineResult, wayside_pipelines
from .parallel import can_fork, decode_in_parallel
from .topics import TRUTH_TOPIC, raw_topic, train_namespace


class MessageDecoder:
    """One replayed message -> what the fusion loop needs.

    Returns a TruthState (ground truth topic), the measurements of a raw block (a
    raw topic, through that sensor's SensorPipeline) or of a standard message (a topic of
    ``readers``, core/ingest/inputs.py), or the InputRejected that refused the message
    (malformed CDR, invalid block or message, decoder rejection).
    """

    def __init__(self, pipes: dict[str, SensorPipeline], deserialize, truth_topics=(TRUTH_TOPIC,),
                 readers: dict[str, InputReader] | None = None):
        self.pipes, self.deserialize, self.truth_topics = pipes, deserialize, frozenset(truth_topics)
        self.readers = readers or {}

    def __call__(self, topic: str, typename: str, data: bytes):
        try:
            msg = self.deserialize(data, typename)
            if topic in self.truth_topics:
                return convert.truth_from_msg(msg)
            if topic in self.readers:
                return self.readers[topic].read(msg)
            return self.pipes[topic].on_block(convert.raw_block_from_msg(msg))
        except InputRejected as exc:
            return exc


def standard_inputs(scenario: Scenario) -> StandardInputs | None:
    """The ingests of the drivers' standard topics a train's scenario names, or None."""
    if not scenario.standard_inputs:
        return None
    return StandardInputs.build(input_values(scenario.standard_inputs), scenario.track, scenario.sensors,
                                scenario.vehicle)


def _at_log_times(items, states: Callable[[float], None]):
    """(topic, log time [ns], log time [s], item) of decoded (topic, log time [ns], item) triples in
    log-time order; ``states(t)`` makes the fused states up to a log time t once every message
    logged at t is in (as simulate_scenario does within a truth step), the last after the items."""
    t_prev = None
    for topic, t_ns, item in items:
        t = t_ns / 1e9
        if t_prev is not None and t > t_prev:
            states(t_prev)
        t_prev = t
        yield topic, t_ns, t, item
    if t_prev is not None:
        states(t_prev)


def _fuse(items, out: FusionFeed, bar) -> None:
    """Feed decoded (topic, log time [ns], item) triples, in log-time order, to the fusion."""
    result, writer = out.result, out.writer
    for topic, t_ns, t, item in _at_log_times(items, out.states):
        if bar:
            bar.update(1)
        if topic != TRUTH_TOPIC:
            result.blocks += 1
        if isinstance(item, InputRejected):
            out.reject(item)
        elif topic == TRUTH_TOPIC:
            out.truth(item, t_ns)
        else:
            out.take(item, t)
    out.flush()


@contextlib.contextmanager
def _older_objects_frozen():
    """Speed trick: the objects alive before a replay (the imported libraries' hundred thousand)
    are left out of the garbage collector's full passes during it (``gc.freeze``); a line replay
    runs about 10 % faster (tl_bench replay)."""
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


@_older_objects_frozen()
def replay_bag(bag: str | Path, scenario: Scenario | None = None, out_bag: str | Path | None = None,
               fusion_rate: float = 200.0, progress: bool = False, parallel: bool = False) -> RunResult:
    """Decode a bag's raw topics and fuse them, in log-time order, without DDS.

    ``scenario`` gives the track, vehicle and sensor set-up (default: the one the
    bag carries on /train/scenario). A line's bag goes to ``replay_line``. The ground truth of the bag (if any) is copied
    to the result and the new bag. Raw topics of sensors the scenario does not list
    are ignored; a message that does not deserialise, a bad block or a decoder
    rejection is counted in ``rejected`` by reason (``blocks`` counts the raw
    messages read). The scenario's ``standard_inputs`` topics are read as the
    standard_inputs node reads them, instead of the raw topics of the sensor classes
    they stand for.

    ``parallel`` reads and decodes the sensors in forked worker processes while this
    one fuses (``decode_in_parallel``); the result is identical to the serial replay.
    """
    if scenario is None:
        scenario = scenario_from_bag(bag)
    if scenario.line:
        return replay_line(bag, scenario, out_bag, fusion_rate, parallel=parallel)
    mc = typestore_classes() if out_bag else None
    writer = items = bar = None
    try:
        with BagReader(bag) as reader:
            standard = standard_inputs(scenario)
            readers = standard.readers() if standard else {}
            from_standard = standard.sensor_classes() if standard else []
            pipes = {}
            for node, params in scenario.sensors.items():
                spec = sensor_spec(node)
                if spec.sensor not in from_standard:
                    pipes[raw_topic(spec.sensor)] = SensorPipeline(
                        spec, params, scenario.track, scenario.vehicle, simulate=False)
            runner = fusion_runner(scenario, fusion_rate)
            result = RunResult(runner=runner)
            topics = list(pipes) + list(readers) + [TRUTH_TOPIC]
            if progress:
                from tqdm import tqdm
                bar = tqdm(total=sum(n for t, n in topic_counts(bag).items() if t in topics), unit="msg",
                           desc=Path(bag).name)
            decoder = MessageDecoder(pipes, reader.deserialize, readers=readers)
            parallel = parallel and can_fork()
            if parallel:
                items = decode_in_parallel(reader.source, decoder, topics, bar)
            else:
                items = ((topic, t_ns, decoder(topic, typename, data))
                         for topic, typename, t_ns, data in reader.cdr(topics))
            writer = BagWriter(out_bag) if out_bag else None
            _fuse(items, FusionFeed(runner, result, writer, mc, scenario.track), bar if not parallel else None)
    finally:
        if items is not None:
            items.close()   # parallel: ends the worker processes
        if bar:
            bar.close()
        if writer:
            writer.close()
    return result


@_older_objects_frozen()
def replay_line(bag: str | Path, scenario: Scenario | None = None, out_bag: str | Path | None = None,
                fusion_rate: float = 200.0, parallel: bool = False) -> LineResult:
    """``replay_bag`` of a line's bag: every train's raw topics through its decoders and fusion,
    the wayside raw topics through the wayside decoders and the association, in log-time
    order (the same sequence as ``simulate_line``, so the same estimates).

    ``parallel`` decodes the topics (every train's sensors and truth, the wayside sensors) in
    forked worker processes while this one fuses and associates, as ``replay_bag`` does; the
    result is identical to the serial replay.
    """
    if scenario is None:
        scenario = scenario_from_bag(bag)
    mc = typestore_classes() if out_bag else None
    writer = BagWriter(out_bag) if out_bag else None
    line = LineFusion(scenario, fusion_rate, writer, mc)
    items = None
    owner, pipes, truth_topics = {}, {}, set()   # topic -> train name (None: the wayside); topic -> pipeline
    for name, train in scenario.trains.items():
        ns = train_namespace(train)
        owner[f"{ns}/ground_truth/state"] = name
        truth_topics.add(f"{ns}/ground_truth/state")
        for node, params in train.sensors.items():
            spec = sensor_spec(node)
            topic = raw_topic(spec.sensor, ns)
            owner[topic] = name
            pipes[topic] = SensorPipeline(spec, params, train.track, train.vehicle, simulate=False)
    for topic, pipe in wayside_pipelines(scenario, simulate=False).items():
        owner[topic], pipes[topic] = None, pipe
    try:
        with BagReader(bag) as reader:
            decoder = MessageDecoder(pipes, reader.deserialize, truth_topics)
            if parallel and can_fork():
                items = decode_in_parallel(reader.source, decoder, list(owner), None)
            else:
                items = ((topic, t_ns, decoder(topic, typename, data))
                         for topic, typename, t_ns, data in reader.cdr(list(owner)))
            for topic, t_ns, t, item in _at_log_times(items, line.states):
                name = owner[topic]
                out = line.outs[name] if name is not None else None
                if topic in truth_topics:
                    if isinstance(item, InputRejected):   # counted with its train, as a bad raw block is
                        out.reject(item)
                    else:
                        line.truth(name, item, t_ns)
                    continue
                if out:
                    out.result.blocks += 1
                else:
                    line.result.blocks += 1
                if isinstance(item, InputRejected):
                    (out.reject if out else line.reject)(item)
                elif out:
                    out.take(item, t)
                else:
                    line.wayside(item, t)
            line.flush()
    finally:
        if items is not None:
            items.close()   # parallel: ends the worker processes
        if writer:
            writer.close()
    return line.result

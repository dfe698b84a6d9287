"""The graph without DDS: scenario -> sensors -> fusion, and bag -> decoders -> fusion.

``FusionRunner`` is the fusion node's logic (filter + fixed-rate output grid); the
node wraps it and so do the offline functions here, so live and offline runs make
the same estimates from the same measurement sequence.

``simulate_scenario`` runs every sensor of a scenario in simulation mode and the
fusion, and can write a bag with the same topics as the live graph.
``replay_bag`` feeds a bag's raw topics through the decoders (ingest mode) and the
fusion as fast as the CPU allows and can write a new bag with the recomputed
outputs (offline replay, docs/replay.md).

A line (several trains, ``Scenario.line``): ``simulate_line`` and ``replay_line`` run
every train's on-board sensors and fusion, the wayside sensors, which see all trains,
and the association of the wayside fixes with the trains (core/association.py); the
bags carry train X's topics under ``/X/...``, the wayside's under ``/wayside/...`` and
the scenario on ``/scenario``. A line with a changeover section (``wayside: changeover:``)
also runs its combined detection and controller on the wayside reports
(core/wayside/changeover.py ChangeoverLoop, as the two wayside nodes do live) and writes
the ABB commands on ``/wayside/changeover/abb1`` and ``abb2`` (std_msgs/Bool).
"""
from __future__ import annotations

import contextlib
import gc
import heapq
import multiprocessing
import os
import time
import traceback
from dataclasses import dataclass, field
from operator import itemgetter
from pathlib import Path

import numpy as np

from ..graph import NAMESPACE   # the graph's namespace: the bags carry its topics
from . import convert
from .association import Associator
from .bagio import BagWriter, typestore_classes
from .fusion import FusionConfig, FusionRunner, estimate_to_msg, fusion_config, order_key
from .measurements import PositionFix, SectionOccupancy
from .pipeline import SensorPipeline
from .scenario import WAYSIDE, Scenario
from .sensors import spec as sensor_spec
from .signals import InputRejected
from .wayside.changeover import ABB_TOPICS, ChangeoverLoop

SCENARIO_TOPIC = f"{NAMESPACE}/scenario"
TRUTH_TOPIC = f"{NAMESPACE}/ground_truth/state"
FUSED_TOPIC = f"{NAMESPACE}/localization/state"
TRACKS_TOPIC = "localization/tracks"           # a train on a network: its track hypotheses
INTERLOCKING_TOPIC = "interlocking/switches"   # ... and the switch positions reported for it


LINE_SCENARIO_TOPIC = "/scenario"        # the scenario of a line's bag (every train and the wayside)
WAYSIDE_NAMESPACE = f"/{WAYSIDE}"


def raw_topic(sensor: str, namespace: str = NAMESPACE) -> str:
    """Bag topic of a sensor class's raw blocks."""
    return f"{namespace}/sensors/{sensor}/raw"


def train_namespace(scenario: Scenario) -> str:
    """Namespace of a train's graph: /train for a one-train scenario, /<name> on a line."""
    return f"/{scenario.train_name}" if scenario.line else NAMESPACE



@dataclass
class RunResult:
    truth: list = field(default_factory=list)       # TruthState
    estimates: list = field(default_factory=list)   # Estimate
    measurements: list = field(default_factory=list)
    blocks: int = 0
    rejected: dict = field(default_factory=dict)
    runner: FusionRunner | None = None


def _ns(t: float) -> int:
    return convert.sec_to_ns(t)


def fusion_runner(scenario: Scenario, rate: float = 200.0) -> FusionRunner:
    """The fusion of one train's scenario: a FusionRunner of its FusionConfig, or on a network
    (core/network) one over the track hypotheses, with the interlocking's switch positions
    (what the train's ``interlocking/switches`` topic carries)."""
    if scenario.network is None:
        return FusionRunner(fusion_config(scenario), rate)
    from .network.config import network_fusion_config
    from .network.hypotheses import HypothesisSet
    cfg, net = network_fusion_config(scenario)
    hypotheses = HypothesisSet(cfg, net, scenario.network)
    hypotheses.set_switches(scenario.interlocking)
    return FusionRunner(cfg, rate, hypotheses)


def write_interlocking(writer: BagWriter, mc, scenario: Scenario, namespace: str) -> None:
    """The interlocking's switch positions of a train on a network, at t = 0 (latched live)."""
    if scenario.network is not None:
        writer.write(f"{namespace}/{INTERLOCKING_TOPIC}", convert.switch_positions_to_msg(mc, 0.0, scenario.interlocking), 0)


def sensor_pipelines(scenario: Scenario) -> list[SensorPipeline]:
    """A simulating SensorPipeline per sensor of the scenario, each on its own random stream."""
    pipes = []
    for node, params in scenario.sensors.items():
        spec = sensor_spec(node)
        unit = (params or {}).get("unit_id") or spec.sensor
        pipes.append(SensorPipeline(spec, params, scenario.track, scenario.vehicle, scenario.rng(node, unit)))
    return pipes


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


def fuse_arrivals(config: FusionConfig, arrivals, t_end: float, rate: float = 200.0, tick: float = 0.005,
                  runner: FusionRunner | None = None):
    """Feed (arrival time, measurement) pairs to a FusionRunner, advancing its output grid every ``tick`` s.

    Everything that has arrived by a tick is added before the estimates up to that tick
    are made, as the fusion node does in real time. ``runner``: the FusionRunner to feed (a
    train on a network: ``fusion_runner``'s, over its track hypotheses); by default a new one
    of ``config`` at ``rate``. Returns (runner, estimates, CPU seconds in add, CPU seconds in
    advance).
    """
    runner = FusionRunner(config, rate) if runner is None else runner
    estimates = []
    t_add = t_adv = 0.0
    j, n = 0, len(arrivals)
    clock = time.process_time
    for k in range(int(round(t_end / tick)) + 1):
        now = k * tick
        c0 = clock()
        while j < n and arrivals[j][0] <= now + 1e-12:
            runner.add(arrivals[j][1])
            j += 1
        c1 = clock()
        estimates.extend(e for e, _ in runner.advance(now))
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
    track_id = scenario.track.track_id
    t_end = scenario.duration if t_end is None else t_end
    n = int(round(t_end * scenario.truth_rate)) + 1
    out = FusionFeed(runner, result, writer, mc, track_id)
    if writer:
        writer.write(SCENARIO_TOPIC, typestore_classes_string(scenario.to_yaml()), 0)
        write_interlocking(writer, mc, scenario, NAMESPACE)
    try:
        for k in range(n):
            t = convert.canonical(k / scenario.truth_rate)
            state = traj.state_at(t)
            result.truth.append(state)
            if writer:
                writer.write(TRUTH_TOPIC, convert.train_state_to_msg(
                    mc, t, track_id, state.position, state.speed, state.acceleration), _ns(t))
            for pipe in pipes:
                for block in pipe.on_truth(state):
                    result.blocks += 1
                    if writer and record_raw:
                        writer.write(raw_topic(block.sensor),
                                     convert.raw_block_to_msg(block, mc), _ns(t))
                    out.decode(pipe, block, t)
            out.states(t)
        out.flush()
    finally:
        if writer:
            writer.close()
    return result


def typestore_classes_string(text: str):
    from .bagio import typestore
    return typestore().types["std_msgs/msg/String"](data=text)


def scenario_from_bag(bag: str | Path) -> Scenario:
    """The scenario a bag was made from (its /train/scenario topic)."""
    from .bagio import BagReader
    with BagReader(bag) as reader:
        return _recorded_scenario(reader)


def _recorded_scenario(reader) -> Scenario:
    import yaml
    for _, typename, _, data in reader.cdr([SCENARIO_TOPIC, LINE_SCENARIO_TOPIC]):
        return Scenario.from_dict(yaml.safe_load(reader.deserialize(data, typename).data))
    raise ValueError(f"{reader.path} has no {SCENARIO_TOPIC} or {LINE_SCENARIO_TOPIC} topic: give the scenario "
                     f"explicitly")


class FusionFeed:
    """Takes decoded measurements, feeds the fusion, collects and writes both.

    The measurements decoded since the last grid step are held and given to the
    fusion in the filter's own order (``order_key``) just before the next estimate
    is made: the filter's result does not depend on the order in which a set of
    measurements is added (core/fusion.py), so the estimates are the same, but
    measurements of one step that arrive out of stamp order (blocks of several
    sensors ending at the same time) no longer roll the filter back one by one.
    """

    def __init__(self, runner: FusionRunner, result: RunResult, writer: BagWriter | None, mc, track_id: str,
                 namespace: str = NAMESPACE):
        self.runner, self.result, self.writer, self.mc, self.track_id = runner, result, writer, mc, track_id
        self.namespace = namespace
        self._pending: list = []

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
                                  convert.measurement_to_msg(m, self.mc), _ns(t))
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
                                  _ns(est.stamp))
                network = getattr(self.runner.filter, "network", None)
                if network is not None:
                    self.writer.write(f"{self.namespace}/{TRACKS_TOPIC}",
                                      convert.track_hypotheses_to_msg(self.mc, est, network.network_id), _ns(est.stamp))


class _MessageDecoder:
    """One replayed message -> what the fusion loop needs.

    Returns a TruthState (ground truth topic), the measurements of a raw block (a
    raw topic, through that sensor's SensorPipeline), or the InputRejected that
    refused the message (malformed CDR, invalid block, decoder rejection).
    """

    def __init__(self, pipes: dict[str, SensorPipeline], deserialize, truth_topics=(TRUTH_TOPIC,)):
        self.pipes, self.deserialize, self.truth_topics = pipes, deserialize, frozenset(truth_topics)

    def __call__(self, topic: str, typename: str, data: bytes):
        try:
            msg = self.deserialize(data, typename)
            if topic in self.truth_topics:
                return convert.truth_from_msg(msg)
            return self.pipes[topic].on_block(convert.raw_block_from_msg(msg))
        except InputRejected as exc:
            return exc


# (bag file, decoder, topics read) of the parallel replay running now: set before its worker
# processes are forked, which so inherit it
_PARALLEL_JOB: tuple | None = None
_first = itemgetter(0)
PARALLEL_WINDOW = 1.0   # log time [s] that the workers decode before handing it over


def _decode_topic_windows(mine: list[str], conn) -> None:
    """Worker process: read the bag's messages of every replayed topic in order, decode those of
    ``mine``, and send each window of log time as [(index in the bag's order, topic, log time
    [ns], item), ...]; then None. Every worker reads the same messages, so all send the same
    windows and the indices merge them back into the bag's order."""
    source, decoder, topics = _PARALLEL_JOB
    os.nice(5)   # the fusion in the parent is the critical path: it goes first
    mine = frozenset(mine)
    window_ns = round(PARALLEL_WINDOW * 1e9)
    try:
        from .bagio import BagReader
        with BagReader(source) as reader:
            window, k = [], None
            for i, (topic, typename, t_ns, data) in enumerate(reader.cdr(topics)):
                if t_ns // window_ns != k:
                    if k is not None:
                        conn.send(window)
                        window = []
                    k = t_ns // window_ns
                if topic in mine:
                    window.append((i, topic, t_ns, decoder(topic, typename, data)))
        conn.send(window)
        conn.send(None)
    except BaseException:   # hand the failure to the parent, which raises it
        conn.send(RuntimeError(f"decoding {', '.join(sorted(mine))} failed in its worker process:\n"
                               f"{traceback.format_exc()}"))
    finally:
        conn.close()


def _decode_in_parallel(source: Path, decoder: _MessageDecoder, topics: list[str], bar,
                        workers: int | None = None):
    """Decoded (topic, log time [ns], item) of the messages of ``topics`` in the bag ``source``,
    in its order, read and decoded in forked worker processes while the caller fuses.

    The sensors are independent until the fusion, as the live nodes are, so each
    topic goes through its own pipeline, in order, in a worker; the topics are
    shared out over ``workers`` processes (default: one per CPU besides the one the
    fusion runs on here, which is the critical path; forking costs about 10 ms a
    process, more than a small topic's decoding), balanced by their message
    counts. Each worker streams the bag itself (nothing is held in memory beyond a
    window) and hands over one window of log time after the other, so the caller
    fuses window k while window k + 1 is decoded. The items come in the bag's
    order, as in the serial replay, so the result is the same.
    """
    global _PARALLEL_JOB
    from .bagio import topic_counts
    try:
        counts = topic_counts(source)
    except Exception:   # a summary without message statistics: the topics shared out by number
        counts = {}
    weight = {t: counts.get(t, 1) for t in topics}
    topics = [t for t in topics if weight[t]]
    if not topics:
        return
    workers = workers or max((os.cpu_count() or 1) - 1, 1)
    groups: list[list[str]] = [[] for _ in range(min(workers, len(topics)))]
    load = [0] * len(groups)
    for topic in sorted(topics, key=weight.get, reverse=True):   # largest first, to the least loaded
        i = load.index(min(load))
        groups[i].append(topic)
        load[i] += weight[topic]
    ctx = multiprocessing.get_context("fork")
    conns, procs = [], []
    _PARALLEL_JOB = (source, decoder, topics)
    try:
        for mine in groups:
            receive, send = ctx.Pipe(duplex=False)
            proc = ctx.Process(target=_decode_topic_windows, args=(mine, send), daemon=True,
                               name=f"replay {mine[0]}")
            proc.start()
            send.close()    # the worker holds it: a worker that dies ends the parent's recv
            conns.append(receive)
            procs.append(proc)
    finally:
        _PARALLEL_JOB = None
    try:
        while True:
            windows = []
            for conn in conns:
                got = conn.recv()
                if isinstance(got, BaseException):
                    raise got
                windows.append(got)
            if windows[0] is None:
                break
            for _, topic, t_ns, item in heapq.merge(*windows, key=_first):
                yield topic, t_ns, item
            if bar:
                bar.update(sum(map(len, windows)))
    finally:
        for proc in procs:
            if proc.is_alive():
                # SIGKILL: a worker may be blocked writing to a full pipe, and may have
                # inherited a SIGTERM handler that does not exit (rclpy.init installs one)
                proc.kill()
            proc.join()
        for conn in conns:
            conn.close()


def can_fork() -> bool:
    """Whether parallel replay is available here (it forks worker processes)."""
    return "fork" in multiprocessing.get_all_start_methods()


def _fuse(items, out: FusionFeed, bar) -> None:
    """Feed decoded (topic, log time [ns], item) triples, in log-time order, to the fusion."""
    result, writer = out.result, out.writer
    t_prev = None
    for topic, t_ns, item in items:
        t = t_ns / 1e9
        # the fused states up to a log time are made once every message logged at
        # that time is in (as simulate_scenario does within a truth step)
        if t_prev is not None and t > t_prev:
            out.states(t_prev)
        t_prev = t
        if bar:
            bar.update(1)
        if topic != TRUTH_TOPIC:
            result.blocks += 1
        if isinstance(item, InputRejected):
            out.reject(item)
        elif topic == TRUTH_TOPIC:
            result.truth.append(item)
            if writer:
                writer.write(topic, convert.train_state_to_msg(out.mc, item.stamp, out.track_id, item.position,
                                                               item.speed, item.acceleration), t_ns)
        else:
            out.take(item, t)
    if t_prev is not None:
        out.states(t_prev)
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
    messages read).

    ``parallel`` reads and decodes the sensors in forked worker processes while this
    one fuses (``_decode_in_parallel``); the result is identical to the serial replay.
    """
    from .bagio import BagReader, topic_counts
    if scenario is None:
        scenario = scenario_from_bag(bag)
    if scenario.line:
        return replay_line(bag, scenario, out_bag, fusion_rate, parallel=parallel)
    mc = typestore_classes() if out_bag else None
    writer = items = bar = None
    try:
        with BagReader(bag) as reader:
            pipes = {}
            for node, params in scenario.sensors.items():
                spec = sensor_spec(node)
                pipes[raw_topic(spec.sensor)] = SensorPipeline(
                    spec, params, scenario.track, scenario.vehicle, simulate=False)
            runner = fusion_runner(scenario, fusion_rate)
            result = RunResult(runner=runner)
            track_id = scenario.track.track_id
            topics = list(pipes) + [TRUTH_TOPIC]
            if progress:
                from tqdm import tqdm
                bar = tqdm(total=sum(n for t, n in topic_counts(bag).items() if t in topics), unit="msg",
                           desc=Path(bag).name)
            decoder = _MessageDecoder(pipes, reader.deserialize)
            parallel = parallel and can_fork()
            if parallel:
                items = _decode_in_parallel(reader.source, decoder, topics, bar)
            else:
                items = ((topic, t_ns, decoder(topic, typename, data))
                         for topic, typename, t_ns, data in reader.cdr(topics))
            writer = BagWriter(out_bag) if out_bag else None
            _fuse(items, FusionFeed(runner, result, writer, mc, track_id), bar if not parallel else None)
    finally:
        if items is not None:
            items.close()   # parallel: ends the worker processes
        if bar:
            bar.close()
        if writer:
            writer.close()
    return result


# ---- several trains on one line ------------------------------------------------------

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


class _Line:
    """The fusion side of a line run: every train's FusionFeed, the wayside measurements and
    their association. Wayside fixes are associated with the fused states published
    before the truth step at which they are decoded, as an association node would."""

    def __init__(self, scenario: Scenario, fusion_rate: float, writer: BagWriter | None, mc):
        self.writer, self.mc = writer, mc
        self.outs = {}
        for name, train in scenario.trains.items():
            runner = fusion_runner(train, fusion_rate)
            self.outs[name] = FusionFeed(runner, RunResult(runner=runner), writer, mc, train.track.track_id,
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
        from .bagio import typestore
        self.writer.write(f"{WAYSIDE_NAMESPACE}/{ABB_TOPICS[switch]}",
                          typestore().types["std_msgs/msg/Bool"](data=bool(closed)), _ns(t))

    def _control(self, t: float) -> None:
        loop = self.result.changeover
        if loop is None:
            return
        for cmd in loop.evaluate(t):
            if self.writer:
                self._abb(cmd.switch, cmd.on, t)

    def truth(self, name: str, state, t_ns: int) -> None:
        out = self.outs[name]
        out.result.truth.append(state)
        if self.writer:
            self.writer.write(f"{out.namespace}/ground_truth/state", convert.train_state_to_msg(
                self.mc, state.stamp, out.track_id, state.position, state.speed, state.acceleration), t_ns)

    def wayside(self, measurements: list, t: float) -> None:
        """Wayside measurements decoded at t [s]: published under /wayside; each fix goes to the
        train the association names (published there too), or to none."""
        for m in measurements:
            self.result.wayside.append(m)
            if self.writer:
                self.writer.write(f"{WAYSIDE_NAMESPACE}/{convert.measurement_topic(m)}",
                                  convert.measurement_to_msg(m, self.mc), _ns(t))
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
    line = _Line(scenario, fusion_rate, writer, mc)
    sim = LineSimulation(scenario)
    outs = {out.namespace: out for out in line.outs.values()}
    if writer:
        writer.write(LINE_SCENARIO_TOPIC, typestore_classes_string(scenario.to_yaml()), 0)
        for name, train in scenario.trains.items():
            write_interlocking(writer, mc, train, train_namespace(train))
    try:
        for k in range(sim.steps(t_end)):
            t, truths, blocks = sim.step(k)
            for name, state in truths.items():
                line.truth(name, state, _ns(t))
            for ns, pipe, block in blocks:
                if writer and record_raw:
                    writer.write(raw_topic(block.sensor, ns), convert.raw_block_to_msg(block, mc), _ns(t))
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
    from .bagio import BagReader
    if scenario is None:
        scenario = scenario_from_bag(bag)
    mc = typestore_classes() if out_bag else None
    writer = BagWriter(out_bag) if out_bag else None
    line = _Line(scenario, fusion_rate, writer, mc)
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
            decoder = _MessageDecoder(pipes, reader.deserialize, truth_topics)
            if parallel and can_fork():
                items = _decode_in_parallel(reader.source, decoder, list(owner), None)
            else:
                items = ((topic, t_ns, decoder(topic, typename, data))
                         for topic, typename, t_ns, data in reader.cdr(list(owner)))
            t_prev = None
            for topic, t_ns, item in items:
                t = t_ns / 1e9
                if t_prev is not None and t > t_prev:
                    line.states(t_prev)
                t_prev = t
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
            if t_prev is not None:
                line.states(t_prev)
            line.flush()
    finally:
        if items is not None:
            items.close()   # parallel: ends the worker processes
        if writer:
            writer.close()
    return line.result

"""Fuzz the live nodes over DDS: malformed input must be rejected, counted and survived.

  python -m train_localization.tools.fuzz [--nodes doppler_radar,fusion] [--messages 200] [--seed 0]

The offline tests feed bad input to the core; this command does the same to the running
nodes, through DDS, the message conversion and the diagnostics. It starts the nodes under
test as subprocesses (sensor nodes in ``mode:=ingest`` with the scenario of config/ that
has them, the fusion with the demo scenario's sensors), each in ``<namespace>/<node>`` (a
sensor node's output does not reach the fusion under test), with DDS on loopback and a
ROS_DOMAIN_ID of this run's own, both set for the children only. To each node's inputs it
publishes a deterministic (``--seed``) mix of valid and malformed messages: NaN/inf
samples, empty or ragged data, wrong channels or units, sample rates 0, < 0, NaN, 1e-300,
1e300 or another than the device's, another sensor's name or unit_id, duplicate and
backwards seq/stamps, seq 2^32-1, stamps far ahead or beyond 2^31 s (nanosec >= 1e9),
blocks at and beyond the size limit
(core/signals.py MAX_BLOCK_VALUES), a unit_id or channel name of 1 MB; for the fusion
NaN/inf/0/<0/1e-300/1e300 values and stddevs, speeds 1e4 m/s, positions 1e12 m and off the
track, another track_id, an unknown or another sensor's name, late, duplicate and future
stamps, increments of 1e-300 s, a sensor, unit_id, track_id or reference_id of 1 MB.

Valid raw blocks are those the core simulator makes (the blocks a sensor node in sim
mode publishes); valid fusion input is what their decoders make, stamped with the wall
clock when sent. What a sensor node must count is computed here by the core
``SensorPipeline`` fed the same messages in the same order; the fusion's reasons are
fixed by construction. A lost message, a crash or a wrong counter therefore shows.

Then the attacks that are not one bad message (``--attacks``, tools/fuzz_attacks.py): hostile
set_position requests, /clock jumps, states stamped far ahead to a sensor node in simulator
mode and to the line's association, a flood on one fusion input; each with nodes of its own.

After the mix, a tail of valid messages must all be accepted (a bad message must not blind
the input). Printed per node: sent (bad/good), accepted, the tail, alive, exit code on
SIGINT, resident memory before -> after [MB], rejected by reason (from /diagnostics); then
the malformed messages a node cannot tell from valid ones, and findings (WARN) on what the
core itself does: a malformed kind it accepts although it should not (SHOULD_REJECT), a
kind of fixed reason counted otherwise, more valid blocks refused in a row than the sequence
guard's resynchronisation allows. Exit code 0 when every node stayed alive,
exited cleanly, counted exactly what was expected and accepted the tail; 1 otherwise, with
one line per failing node.
"""
from __future__ import annotations

import argparse
import copy
import json
import math
import random
import sys
import time
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

from .fuzz_attacks import ATTACKS, run_attacks
from .fuzz_nodes import Child, Probe, child_env, node_namespace, pick_domain, rss_mb, set_time

ACCEPTED = "accepted"
FUSION = "fusion"
# scenarios that provide the valid raw blocks: the first one that lists a sensor node is used
SCENARIOS = ("config/scenario_demo.yaml", "config/scenario_maglev_500.yaml", "config/scenario_urban_stops.yaml",
             "config/scenario_lzb.yaml", "config/scenario_track_circuit.yaml", "config/scenario_utm.yaml",
             "config/scenario_mlx.yaml", "config/scenario_hsst.yaml", "config/scenario_mbahn.yaml",
             "config/scenario_rig_open.yaml")
FUSION_SCENARIO = "config/scenario_demo.yaml"
# the fusion's valid input: the demo train 20 m before balise group EB000 (500 m) at 25 m/s,
# so that the window holds position fixes besides speeds and distance increments
FUSION_WINDOW = {"start_position": 480.0, "start_speed": 25.0, "duration": 2.5}
MOVING_SPEED = 5.0        # valid raw blocks start once the train is this fast [m/s]
FUTURE_SEC = 2 ** 31 - 1  # largest header.stamp.sec (int32) [s]
SEQ_MAX = 2 ** 32 - 1     # largest RawBlock.seq (uint32)
IN_FLIGHT = 400           # messages sent to one node and not yet counted in its diagnostics
ONCE = frozenset({"too_large", "at_limit"})   # kinds of about 8 MB: at most one per node
LONG_TEXT = "x" * 1_000_000   # an id of 1 MB (ids are refused beyond 64 characters, core/signals.py)

# raw-block kinds -> the reason the sensor node must count whatever came before (None: it
# depends on the node's state, e.g. a duplicate seq after a block that was itself refused,
# or a valid block with seq 2^32-1, which is accepted: the next valid blocks are then refused
# until the sequence guard resynchronises, core/signals.py BlockSequenceGuard)
RAW_KINDS = {
    "nan_sample": "nan", "inf_sample": "nan", "empty_data": "shape", "ragged_data": "shape",
    "no_channels": "channels", "units_mismatch": "shape", "extra_channel": None, "renamed_channels": None,
    "rate_zero": "sample_rate", "rate_negative": "sample_rate", "rate_nan": "sample_rate",
    "rate_1e-300": "sample_rate", "rate_1e300": "sample_rate", "rate_doubled": "sample_rate",
    "wrong_sensor": "sensor", "duplicate": None, "seq_back": None, "stamp_back": None, "seq_max": None,
    "stamp_future": None, "stamp_overflow": "stamp", "too_large": "too_large", "at_limit": "too_large",
    "foreign_unit": None, "long_unit_id": "too_long", "long_channel": "too_long",
}

# fusion kinds -> (message kind the kind needs: position/speed/distance/any, reason to count)
FUSION_KINDS = {
    "nan_value": ("any", "nan"), "inf_value": ("any", "nan"), "nan_stddev": ("any", "nan"),
    "zero_stddev": ("any", "stddev"), "negative_stddev": ("any", "stddev"),
    "stddev_1e-300": ("any", "implausible"), "stddev_1e300": ("any", "implausible"),
    "speed_1e4": ("speed", "implausible"), "position_1e12": ("position", "implausible"),
    "off_track": ("position", "off_track"), "wrong_track": ("position", "wrong_track"),
    "unknown_sensor": ("any", "wrong_sensor"), "foreign_sensor": ("any", "wrong_sensor"),
    "duplicate": ("any", "duplicate"),
    "too_late": ("any", "too_late"), "future": ("any", "future"),
    "duration_1e-300": ("distance", "implausible"), "duration_zero": ("distance", "stddev"),
    "duration_nan": ("distance", "nan"), "distance_1e12": ("distance", "implausible"),
    "long_unit_id": ("any", "too_long"), "long_sensor": ("any", "too_long"),
    "long_track_id": ("position", "too_long"), "long_reference_id": ("position", "too_long"),
}

# kinds that input validation should refuse but the nodes accept: reported as findings (the
# counters are still compared with what the nodes do)
SHOULD_REJECT = {
    "foreign_unit": "the last valid block, sent again under another unit_id, is decoded again: the sequence "
                    "guard keys on the block's unit_id and nothing checks it against the device's",
}


@dataclass
class Item:
    """One message to send: ``build(now)`` makes it (``now``: wall time [s]); ``expect`` is
    ACCEPTED or the rejection reason the node must count."""

    kind: str
    topic: str
    build: Callable[[float], Any]
    expect: str


@dataclass
class Plan:
    """What one node gets: ``body`` (valid messages first and last, the mix between) and
    ``tail`` (valid messages only), and the message type of each topic."""

    node: str
    topics: dict[str, type]
    body: list[Item]
    tail: list[Item]


@dataclass
class Report:
    node: str
    sent: Counter = field(default_factory=Counter)        # kind -> messages sent
    expected: Counter = field(default_factory=Counter)    # reason or ACCEPTED -> count
    counted: Counter = field(default_factory=Counter)     # from /diagnostics
    kinds: dict = field(default_factory=dict)             # kind -> Counter of expected outcomes
    bad_accepted: Counter = field(default_factory=Counter)   # kind -> malformed ones expected accepted
    tail_sent: int = 0
    tail_accepted: int | None = None
    alive: bool = False
    exit_code: int | None = None
    rss_before: float | None = None
    rss_after: float | None = None
    failures: list[str] = field(default_factory=list)
    findings: list[str] = field(default_factory=list)     # what the core does other than RAW_KINDS says

    @property
    def good_refused(self) -> int:
        """Valid messages the node is expected to refuse (after an accepted malformed block,
        until the sequence guard resynchronises)."""
        return self.sent["good"] - self.kinds.get("good", Counter())[ACCEPTED]

    def add(self, item: Item) -> None:
        self.sent[item.kind] += 1
        self.expected[item.expect] += 1
        self.kinds.setdefault(item.kind, Counter())[item.expect] += 1
        if item.kind != "good" and item.expect == ACCEPTED:
            self.bad_accepted[item.kind] += 1

    def find(self) -> None:
        """Findings: malformed kinds handled other than RAW_KINDS / SHOULD_REJECT say."""
        for kind, outcomes in sorted(self.kinds.items()):
            n = sum(outcomes.values())
            if kind in SHOULD_REJECT and outcomes[ACCEPTED]:
                self.findings.append(f"{kind} accepted {outcomes[ACCEPTED]}/{n}")
            elif RAW_KINDS.get(kind) and self.node != FUSION and set(outcomes) != {RAW_KINDS[kind]}:
                self.findings.append(f"{kind} counted as {dict(outcomes)}, not {RAW_KINDS[kind]} {n}")

    def to_dict(self) -> dict:
        return {"node": self.node, "sent": dict(self.sent), "expected": dict(self.expected),
                "counted": dict(self.counted), "kinds": {k: dict(v) for k, v in self.kinds.items()},
                "bad_accepted": dict(self.bad_accepted), "good_refused": self.good_refused,
                "tail_sent": self.tail_sent, "tail_accepted": self.tail_accepted, "alive": self.alive,
                "exit_code": self.exit_code, "rss_before_mb": self.rss_before, "rss_after_mb": self.rss_after,
                "failures": self.failures, "findings": self.findings}


# ---- plans -----------------------------------------------------------------------

def _layout(n: int, rng: random.Random, kinds: list[str]) -> tuple[list[str | None], int]:
    """Kinds of the ``n`` messages of one node (None: a valid one) and the tail length.

    Three valid messages first; then the mix (about half malformed, every kind once before
    any repeats, ONCE kinds at most once); three valid ones (a guard that took a bad block
    resynchronises on three in a row); then the tail, about a tenth of ``n``, at least three."""
    from ..core.signals import RESYNC_BLOCKS
    head, settle = 3, RESYNC_BLOCKS
    tail = max(RESYNC_BLOCKS, n // 10)
    middle = n - head - settle - tail
    n_bad = middle // 2
    order: list[str] = []
    pool = list(kinds)
    while len(order) < n_bad:
        rng.shuffle(pool)
        order += [k for k in pool if k not in ONCE or k not in order]
        pool = [k for k in pool if k not in ONCE]
        if not pool:
            break
    order = order[:n_bad]
    slots: list[str | None] = [None] * middle
    for pos, kind in zip(sorted(rng.sample(range(middle), len(order))), order):
        slots[pos] = kind
    return [None] * head + slots + [None] * settle, tail


def scenario_path(node: str) -> str:
    """Absolute path of the scenario that gives a sensor node its valid blocks (and the
    node its track and parameters): the first of SCENARIOS that lists it; FUSION_SCENARIO
    for the fusion."""
    from ..core import paths
    from ..core.scenario import Scenario
    for path in (FUSION_SCENARIO,) if node == FUSION else SCENARIOS:
        if node == FUSION or node in Scenario.from_yaml(path).sensors:
            return str(paths.resolve(path).resolve())
    raise ValueError(f"no scenario of {', '.join(SCENARIOS)} has the sensor {node}")


def start_args(node: str, namespace: str) -> list[str]:
    """Command-line ROS arguments of a node under test: a sensor node in ingest mode with
    its scenario, the fusion with the scenario and its sensors (as graph.demo_graph)."""
    args = ["--ros-args", "-r", f"__ns:={node_namespace(namespace, node)}", "-p", f"scenario:={scenario_path(node)}"]
    if node == FUSION:
        from ..core.scenario import Scenario
        from ..core.sensors import spec
        classes = [spec(s).sensor for s in Scenario.from_yaml(FUSION_SCENARIO).sensors]
        return args + ["-p", f"sensors:=[{','.join(classes)}]"]
    return args + ["-p", "mode:=ingest"]


def _moving_since(scenario) -> float:
    """First time at which the train is at least MOVING_SPEED fast [s]."""
    import numpy as np
    traj = scenario.trajectory(dt=0.01)
    idx = np.flatnonzero(np.abs(traj.speed) >= MOVING_SPEED)
    return float(traj.t[idx[0]]) if idx.size else 0.0


def _valid_blocks(node: str, scenario, count: int) -> list:
    """``count`` consecutive raw blocks of ``node`` from the core simulator, the train moving."""
    from ..core.pipeline import simulate_and_decode
    t0 = _moving_since(scenario)
    block = float(scenario.sensors.get(node, {}).get("block_duration", 0.05))
    t_end = t0 + (count + 2) * block + 0.1
    while True:   # a device may send its blocks less often than every block_duration (the DGPS: its fixes)
        short = replace(scenario, duration=min(scenario.duration, t_end + 1.0))
        blocks = [b for b in simulate_and_decode(node, short, t_end=t_end).blocks if b.t0 >= t0 - 1e-9]
        if len(blocks) >= count or t_end >= scenario.duration:
            break
        t_end = min(scenario.duration, t0 + 2.0 * (t_end - t0))
    if len(blocks) < count:
        raise RuntimeError(f"{node}: the simulator made {len(blocks)} blocks, {count} needed")
    return blocks[:count]


def _raw_bad(kind: str, nxt, last_msg, rng: random.Random, mc):
    """The malformed RawBlock message of ``kind``, made from ``nxt`` (the next valid block, a
    core RawBlock) or ``last_msg`` (the last valid message sent)."""
    import numpy as np
    from ..core import convert
    from ..core.sensors import NODE_NAMES, spec
    from ..core.signals import MAX_BLOCK_VALUES

    msg = convert.raw_block_to_msg(nxt, mc)
    data = nxt.data.copy()
    nch = len(nxt.channels)
    if kind in ("nan_sample", "inf_sample"):
        data.reshape(-1)[rng.randrange(data.size)] = math.nan if kind == "nan_sample" else -math.inf
    elif kind == "empty_data":
        data = np.zeros((0, nch), np.float32)
    elif kind == "extra_channel":
        msg.channels, msg.units = list(nxt.channels) + ["fuzz"], list(nxt.units) + ["1"]
        data = np.column_stack([data, np.zeros(len(data), np.float32)])
    elif kind == "renamed_channels":
        msg.channels = [f"fuzz_{i}" for i in range(nch)]
    elif kind == "no_channels":
        msg.channels, msg.units = [], []
    elif kind == "units_mismatch":
        msg.units = list(nxt.units)[:-1]
    elif kind.startswith("rate_"):
        msg.sample_rate = {"rate_zero": 0.0, "rate_negative": -nxt.sample_rate, "rate_nan": math.nan,
                           "rate_1e-300": 1e-300, "rate_1e300": 1e300, "rate_doubled": 2.0 * nxt.sample_rate}[kind]
    elif kind == "wrong_sensor":
        msg.sensor = next(spec(n).sensor for n in NODE_NAMES if spec(n).sensor != nxt.sensor)
    elif kind == "duplicate":
        return copy.deepcopy(last_msg)
    elif kind == "foreign_unit":
        msg = copy.deepcopy(last_msg)
        msg.unit_id = "fuzz_unit"
        return msg
    elif kind == "seq_back":
        msg.seq = max(0, last_msg.seq - 1)
    elif kind == "stamp_back":
        msg.header.stamp.sec = max(0, last_msg.header.stamp.sec - 1)
        msg.header.stamp.nanosec = last_msg.header.stamp.nanosec
    elif kind == "seq_max":
        msg.seq = SEQ_MAX
    elif kind == "long_unit_id":
        msg.unit_id = LONG_TEXT
    elif kind == "long_channel":
        msg.channels = [LONG_TEXT] + list(msg.channels)[1:]
    elif kind == "stamp_future":
        msg.header.stamp.sec, msg.header.stamp.nanosec = FUTURE_SEC, 0
    elif kind == "stamp_overflow":   # nanosec beyond 1e9: the stamp passes 2^31 s
        msg.header.stamp.sec, msg.header.stamp.nanosec = FUTURE_SEC, 2 ** 32 - 1
    elif kind in ("too_large", "at_limit"):
        rows = MAX_BLOCK_VALUES // nch + (1 if kind == "too_large" else 0)
        data = np.tile(data, (-(-rows // len(data)), 1))[:rows]
    flat = data.reshape(-1)
    if kind == "ragged_data":
        flat = flat[:-1]
    msg.data = mc.array(flat, "float32")
    return msg


def sensor_plan(node: str, n: int, seed: int) -> Plan:
    """The messages for a sensor node in ingest mode and what it must count for each: the
    core SensorPipeline of the same scenario decodes the same messages in the same order
    (nodes/sensor.py: on_raw, _decode)."""
    from ..core import convert
    from ..core.pipeline import SensorPipeline
    from ..core.scenario import Scenario
    from ..core.sensors import spec
    from ..core.signals import InputRejected
    from ..nodes.common import rclpy_classes
    from ..nodes.common import FUTURE_TOLERANCE

    rng = random.Random(f"{seed}/{node}")
    slots, n_tail = _layout(n, rng, list(RAW_KINDS))
    scenario = Scenario.from_yaml(scenario_path(node))
    sp = spec(node)
    goods = iter(_valid_blocks(node, scenario, sum(s is None for s in slots) + n_tail + 1))
    pipe = SensorPipeline(sp, scenario.sensors.get(node, {}), scenario.track, scenario.vehicle, None,
                          simulate=False)
    mc = rclpy_classes()
    topic = f"sensors/{sp.sensor}/raw"

    def outcome(msg) -> str:
        try:
            block = convert.raw_block_from_msg(msg)
            if block.t_end - time.time() > FUTURE_TOLERANCE:   # the node's clock: wall time
                return "future"
            pipe.on_block(block)
        except InputRejected as exc:
            return exc.reason
        return ACCEPTED

    body, tail, last = [], [], None
    nxt = next(goods)
    for kind in slots + [None] * n_tail:
        if kind is None:
            msg = convert.raw_block_to_msg(nxt, mc)
            (body if len(body) < len(slots) else tail).append(Item("good", topic, lambda now, m=msg: m, outcome(msg)))
            last, nxt = msg, next(goods)
        elif kind in ONCE:   # about 8 MB: made again when sent, from the same draws
            def build(now, args=(kind, nxt, last, f"{seed}/{node}/{kind}")):
                return _raw_bad(*args[:3], random.Random(args[3]), mc)
            body.append(Item(kind, topic, build, outcome(build(0.0))))
        else:
            msg = _raw_bad(kind, nxt, last, rng, mc)
            body.append(Item(kind, topic, lambda now, m=msg: m, outcome(msg)))
    return Plan(node, {topic: mc.RawBlock}, body, tail)


class _Stamps:
    """Strictly increasing wall-clock stamps [s], whole nanoseconds."""

    def __init__(self):
        self.last = 0.0

    def next(self, now: float) -> float:
        self.last = max(round(now, 6), round(self.last + 1e-6, 6))
        return self.last


def _set_stamp(msg, t: float) -> None:
    set_time(msg.header.stamp, t)


def _stamp(msg) -> float:
    from ..core.convert import stamp_to_sec
    return stamp_to_sec(msg.header.stamp)


def _fusion_pool():
    """Decoded measurements (PositionFix, SpeedMeasurement, DistanceIncrement) of the
    fusion's sensors over FUSION_WINDOW, in stamp order."""
    from ..core.measurements import DistanceIncrement, PositionFix, SpeedMeasurement
    from ..core.pipeline import simulate_and_decode
    from ..core.scenario import Scenario
    scenario = replace(Scenario.from_yaml(FUSION_SCENARIO), **FUSION_WINDOW)
    pool = []
    for node in scenario.sensors:
        pool += [m for m in simulate_and_decode(node, scenario).measurements
                 if isinstance(m, (PositionFix, SpeedMeasurement, DistanceIncrement))]
    return scenario, sorted(pool, key=lambda m: m.stamp)


def _chain(msg, ended: dict) -> None:
    """A valid increment re-stamped with the wall clock: its span shortened so that it begins
    where its unit's previous one ended (``ended``: (sensor, unit) -> stamp [s], updated), its
    distance and 1-sigma with it (the same mean speed); overlapping spans of one unit are
    refused (``overlap``, core/fusion/history.py)."""
    t = _stamp(msg)
    previous = ended.get((msg.sensor, msg.unit_id))
    if previous is not None and t - previous < msg.duration:
        share = max(t - previous, 2.0e-6) / msg.duration
        msg.duration, msg.distance, msg.distance_stddev = (msg.duration * share, msg.distance * share,
                                                           msg.distance_stddev * share)
    ended[(msg.sensor, msg.unit_id)] = t


def fusion_plan(n: int, seed: int) -> Plan:
    """The messages for the fusion (the demo scenario's sensors): decoded measurements
    stamped with the wall clock when sent, and malformed ones of FUSION_KINDS."""
    from ..core import convert
    from ..core.measurements import DistanceIncrement, PositionFix, SpeedMeasurement
    from ..core.fusion import fusion_config
    from ..core.sensors import spec
    from ..nodes.common import rclpy_classes

    rng = random.Random(f"{seed}/{FUSION}")
    slots, n_tail = _layout(n, rng, list(FUSION_KINDS))
    scenario, pool = _fusion_pool()
    history = fusion_config(scenario).history
    by_type = {PositionFix: "position", SpeedMeasurement: "speed", DistanceIncrement: "distance"}
    missing = set(by_type.values()) - {by_type[type(m)] for m in pool}
    if missing:
        raise RuntimeError(f"the fusion window has no {', '.join(sorted(missing))} measurement")
    mc = rclpy_classes()
    classes = [spec(s).sensor for s in scenario.sensors]
    stamps = _Stamps()
    last: dict[str, Any] = {}    # message kind and "any" -> (kind, the last valid message built)
    stddev = {"position": "position_stddev", "speed": "speed_stddev", "distance": "distance_stddev"}
    foreign = {s: next(c for c in classes if c != s) for s in classes}

    ended: dict[tuple[str, str], float] = {}   # (sensor, unit) -> stamp [s] of its last valid increment

    def good(m):
        def build(now):
            msg = convert.measurement_to_msg(m, mc)
            _set_stamp(msg, stamps.next(now))
            if isinstance(m, DistanceIncrement):
                _chain(msg, ended)
            last[by_type[type(m)]] = last["any"] = (by_type[type(m)], msg)
            return msg
        return Item("good", convert.measurement_topic(m), build, ACCEPTED)

    def bad(kind, topic):
        need, expect = FUSION_KINDS[kind]

        def build(now):
            what, msg = last[need]
            msg = copy.deepcopy(msg)
            if kind not in ("duplicate", "too_late"):
                _set_stamp(msg, stamps.next(now))
            if kind in ("nan_value", "inf_value"):
                setattr(msg, what, math.nan if kind == "nan_value" else math.inf)
            elif kind.endswith("_stddev") or kind.startswith("stddev_"):
                setattr(msg, stddev[what], {"nan_stddev": math.nan, "zero_stddev": 0.0, "negative_stddev": -1.0,
                                            "stddev_1e-300": 1e-300, "stddev_1e300": 1e300}[kind])
            elif kind == "speed_1e4":
                msg.speed = 1.0e4
            elif kind == "position_1e12":
                msg.position = 1.0e12
            elif kind == "off_track":
                msg.position = 1.0e6
            elif kind == "wrong_track":
                msg.track_id = "fuzz_line"
            elif kind == "unknown_sensor":
                msg.sensor = "fuzz_sensor"
            elif kind == "foreign_sensor":
                msg.sensor = foreign[msg.sensor]
            elif kind == "too_late":
                _set_stamp(msg, _stamp(msg) - history - 1.0)
            elif kind == "future":
                _set_stamp(msg, now + 1.0e6)
            elif kind.startswith("duration_"):
                msg.duration = {"duration_1e-300": 1e-300, "duration_zero": 0.0, "duration_nan": math.nan}[kind]
            elif kind == "distance_1e12":
                msg.distance = 1.0e12
            elif kind.startswith("long_"):
                setattr(msg, kind[len("long_"):], LONG_TEXT)
            return msg
        return Item(kind, topic, build, expect)

    # the head: one valid message of each kind, so that every malformed kind has a template
    firsts = [next(m for m in pool if isinstance(m, t)) for t in by_type]
    rest = [m for m in pool if all(m is not f for f in firsts)]
    cycle = iter(firsts + [rest[k % len(rest)] for k in range(n)])
    body, tail, topic_of = [], [], {}
    for kind in slots + [None] * n_tail:
        if kind is None:
            it = good(next(cycle))
            topic_of[it.topic.rsplit("/", 1)[1]] = topic_of["any"] = it.topic
            (body if len(body) < len(slots) else tail).append(it)
        else:
            need = FUSION_KINDS[kind][0]
            body.append(bad(kind, topic_of[need]))
    topics = {f"sensors/{spec(s).sensor}/{o}": getattr(mc, convert.MEASUREMENT_TOPICS[o][0])
              for s in scenario.sensors for o in spec(s).outputs if o in convert.MEASUREMENT_TOPICS}
    return Plan(FUSION, topics, body, tail)


def blinded(items: list[Item]) -> int:
    """The most valid blocks refused in a row, counting across malformed blocks that the
    sequence guard never sees or lets pass; a streak ends at an accepted block or one the
    guard refuses (it starts the guard's count again)."""
    streak = worst = 0
    for it in items:
        if it.expect == ACCEPTED or (it.kind != "good" and it.expect in ("duplicate", "stamp_back")):
            streak = 0
        elif it.kind == "good":
            streak += 1
            worst = max(worst, streak)
    return worst


# ---- the run ---------------------------------------------------------------------

def _send(probe: Probe, plans: dict[str, Plan], items: dict[str, list[Item]], sent: dict[str, int],
          reports: dict[str, Report], children: dict[str, Child], timeout: float) -> None:
    """Publish every node's items, round robin, at most IN_FLIGHT ahead of its diagnostics."""
    queues = {name: list(its) for name, its in items.items()}
    pos = dict.fromkeys(queues, 0)
    deadline = time.monotonic() + timeout
    while any(pos[n] < len(q) for n, q in queues.items()) and time.monotonic() < deadline:
        progress = False
        for name, queue in queues.items():
            if pos[name] >= len(queue) or children[name].proc.poll() is not None:
                continue
            if sent[name] - probe.total(name) >= IN_FLIGHT:
                continue
            it = queue[pos[name]]
            msg = it.build(time.time())
            probe.publisher(name, it.topic, plans[name].topics[it.topic]).publish(msg)
            pos[name] += 1
            sent[name] += 1
            progress = True
        probe.executor.spin_once(timeout_sec=0.0 if progress else 0.05)
    for name, queue in queues.items():
        if pos[name] < len(queue):
            reports[name].failures.append(f"only {pos[name]} of {len(queue)} messages sent "
                                          "(node dead or not counting)")


def _settle(probe: Probe, sent: dict[str, int], children: dict[str, Child], timeout: float) -> None:
    """Spin until every live node's diagnostics count everything sent to it (or the timeout)."""
    probe.spin_until(lambda: all(probe.total(n) >= sent[n] or c.proc.poll() is not None
                                 for n, c in children.items()), timeout)


def run(nodes: list[str], messages: int, seed: int, namespace: str, domain: int, log_dir: Path,
        startup_timeout: float = 60.0, settle_timeout: float = 30.0) -> list[Report]:
    """Start ``nodes``, fuzz them, stop them; one Report per node (in the order given)."""
    log_dir.mkdir(parents=True, exist_ok=True)
    env = child_env(domain)
    children: dict[str, Child] = {}
    reports = {n: Report(n) for n in nodes}
    probe = None
    t_start = time.monotonic()
    try:
        for name in nodes:   # the nodes start while the plans are made (the simulator's CPU time)
            children[name] = Child(name, start_args(name, namespace), env, log_dir / f"{name}.log")
        plans = {n: fusion_plan(messages, seed) if n == FUSION else sensor_plan(n, messages, seed) for n in nodes}
        for name, plan in plans.items():
            rep = reports[name]
            for it in plan.body + plan.tail:
                rep.add(it)
            rep.tail_sent = len(plan.tail)
            rep.find()
            if name != FUSION:
                from ..core.signals import RESYNC_BLOCKS
                streak = blinded(plan.body + plan.tail)
                if streak >= RESYNC_BLOCKS:
                    rep.findings.append(f"{streak} valid blocks in a row refused after a malformed one (at most "
                                        f"{RESYNC_BLOCKS - 1}: the sequence guard resynchronises after "
                                        f"{RESYNC_BLOCKS} in a row)")
            if any(it.expect != ACCEPTED for it in plan.tail):
                rep.findings.append("the core itself refuses part of the valid tail")
        print(f"[fuzz] {len(nodes)} node(s) in {namespace}, ROS_DOMAIN_ID={domain}, seed {seed}, "
              f"{messages} messages each; logs in {log_dir}", flush=True)
        probe = Probe(domain, namespace, nodes)
        for name, plan in plans.items():
            for topic, cls in plan.topics.items():
                probe.publisher(name, topic, cls)

        def ready(name: str) -> bool:
            return name in probe.status and all(probe.publisher(name, t, c).get_subscription_count() > 0
                                                for t, c in plans[name].topics.items())
        probe.spin_until(lambda: all(ready(n) or children[n].proc.poll() is not None for n in nodes),
                         max(1.0, startup_timeout - (time.monotonic() - t_start)))
        for name in nodes:
            if not ready(name):
                reports[name].failures.append("not up within the start-up timeout" if children[name].proc.poll()
                                              is None else f"exited at start-up ({children[name].proc.returncode})")
        probe.spin(0.5)   # both ends matched: let discovery settle on the nodes' side as well
        live = [n for n in nodes if not reports[n].failures]
        for name in nodes:
            reports[name].rss_before = rss_mb(children[name].proc.pid)
        sent = dict.fromkeys(nodes, 0)
        _send(probe, plans, {n: plans[n].body for n in live}, sent, reports, children, settle_timeout * 2)
        _settle(probe, sent, {n: children[n] for n in live}, settle_timeout)
        before_tail = {n: probe.counters(n)[0] for n in live}
        _send(probe, plans, {n: plans[n].tail for n in live}, sent, reports, children, settle_timeout)
        _settle(probe, sent, {n: children[n] for n in live}, settle_timeout)
        for name in nodes:
            rep, child = reports[name], children[name]
            accepted, rejected = probe.counters(name)
            rep.counted = Counter({ACCEPTED: accepted, **rejected})
            if name in before_tail:
                rep.tail_accepted = accepted - before_tail[name]
            rep.alive = child.proc.poll() is None
            rep.rss_after = rss_mb(child.proc.pid)
    finally:
        deadline = time.monotonic() + 15.0
        for child in children.values():
            child.interrupt()
        for name, child in children.items():
            reports[name].exit_code = child.stop(deadline - time.monotonic())
        if probe is not None:
            probe.close()
    for rep in reports.values():
        _judge(rep, sum(rep.sent.values()))
    return [reports[n] for n in nodes]


def _judge(rep: Report, n_sent: int) -> None:
    """Failures of one node: not up, dead, unclean exit, messages not counted, counters
    other than expected, the tail not accepted."""
    not_up = any(f.startswith(("not up", "exited at start-up")) for f in rep.failures)
    if not rep.alive and not not_up:
        rep.failures.insert(0, f"died during the fuzz (exit code {rep.exit_code})")
    elif rep.alive and rep.exit_code != 0:
        rep.failures.append(f"exit code {rep.exit_code} on SIGINT")
    if rep.failures:
        return
    total = sum(rep.counted.values())
    if total != n_sent:
        rep.failures.append(f"counted {total} of {n_sent} messages sent")
    elif rep.counted != +rep.expected:
        keys = sorted(k for k in set(rep.counted) | set(rep.expected) if rep.counted[k] != rep.expected[k])
        rep.failures.append("counters differ: " + ", ".join(f"{k} {rep.counted[k]} (expected {rep.expected[k]})"
                                                           for k in keys))
    if rep.tail_accepted != rep.tail_sent:
        rep.failures.append(f"accepted {rep.tail_accepted} of the {rep.tail_sent} valid messages after the bad ones")


def _mb(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"


def print_table(reports: list[Report]) -> None:
    """One row per node (rejected reasons last: the longest column), then the malformed
    messages a node cannot tell from valid ones, and the findings."""
    head = ("node", "sent bad/good", "accepted", "tail", "alive", "exit", "RSS [MB]", "rejected by reason")
    rows = []
    for r in reports:
        bad = sum(v for k, v in r.sent.items() if k != "good")
        rejected = ", ".join(f"{k} {v}" for k, v in sorted(r.counted.items()) if k != ACCEPTED) or "-"
        rows.append((r.node, f"{bad}/{r.sent['good']}", str(r.counted.get(ACCEPTED, 0)),
                     f"{r.tail_accepted if r.tail_accepted is not None else '-'}/{r.tail_sent}",
                     "yes" if r.alive else "NO", "-" if r.exit_code is None else str(r.exit_code),
                     f"{_mb(r.rss_before)} -> {_mb(r.rss_after)}", rejected))
    widths = [max(len(row[i]) for row in rows + [head]) for i in range(len(head) - 1)]
    for row in [head] + rows:
        print("  ".join(c.ljust(w) for c, w in zip(row, widths)) + "  " + row[-1])
    for r in reports:
        accepted = {k: v for k, v in r.bad_accepted.items() if k not in SHOULD_REJECT}
        if accepted:
            print(f"{r.node}: malformed but well-formed to the node, accepted: "
                  + ", ".join(f"{k} {v}" for k, v in sorted(accepted.items()))
                  + (f"; {r.good_refused} valid blocks after them refused until the sequence guard "
                     "resynchronised" if r.good_refused else ""))
    for r in reports:
        if r.findings:
            print(f"WARN {r.node}: {'; '.join(r.findings)}")
    for kind, why in SHOULD_REJECT.items():
        if any(kind in f for r in reports for f in r.findings):
            print(f"WARN {kind}: {why}")


def _node_list(text: str) -> list[str]:
    from ..core.sensors import NODE_NAMES
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in NODE_NAMES and n != FUSION]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"unknown node(s) {', '.join(unknown) or '(none given)'}; "
                                         f"known: {', '.join(NODE_NAMES)}, {FUSION}")
    return list(dict.fromkeys(names))


def _attack_list(text: str) -> list[str]:
    names = [a.strip() for a in text.split(",") if a.strip()]
    if names == ["none"]:
        return []
    unknown = [a for a in names if a not in ATTACKS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"unknown attack(s) {', '.join(unknown) or '(none given)'}; "
                                         f"known: {', '.join(ATTACKS)}, or none")
    return list(dict.fromkeys(names))


def _messages(text: str) -> int:
    n = int(text)
    if n < 20:
        raise argparse.ArgumentTypeError("at least 20 messages per node")
    return n


def _domain(text: str) -> int:
    d = int(text)
    if not 0 <= d <= 232:
        raise argparse.ArgumentTypeError("a ROS_DOMAIN_ID is 0 .. 232")
    return d


def parse_args(argv=None) -> argparse.Namespace:
    from ..core.sensors import NODE_NAMES
    ap = argparse.ArgumentParser(prog="python -m train_localization.tools.fuzz", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--nodes", type=_node_list, default=list(NODE_NAMES) + [FUSION],
                    help="comma-separated nodes to fuzz (default: every sensor node in ingest mode and the "
                         "fusion)")
    ap.add_argument("--messages", type=_messages, default=200,
                    help="messages per node, malformed and valid (default 200, at least 20)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the mix: the same seed sends the same messages")
    ap.add_argument("--namespace", default="/fuzz", help="namespace of the started nodes (default /fuzz)")
    ap.add_argument("--domain-id", type=_domain, default=None, metavar="ID",
                    help="ROS_DOMAIN_ID of the run (default: a free one in 1..101 other than the caller's)")
    ap.add_argument("--log-dir", default="out/fuzz", help="directory of the nodes' logs (default out/fuzz)")
    ap.add_argument("--json", default=None, metavar="PATH", help="also write the per-node report as JSON")
    ap.add_argument("--startup-timeout", type=float, default=60.0,
                    help="wall time the nodes have to come up [s] (default 60)")
    ap.add_argument("--attacks", type=_attack_list, default=list(ATTACKS), metavar="LIST",
                    help="attacks run after the message mix, comma-separated, or 'none' (default: "
                         f"{','.join(ATTACKS)}; tools/fuzz_attacks.py)")
    ap.add_argument("--settle-timeout", type=float, default=30.0,
                    help="wall time to wait for a node's diagnostics to count what was sent [s] (default 30)")
    return ap.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    if not args.namespace.startswith("/"):
        args.namespace = "/" + args.namespace
    held = pick_domain() if args.domain_id is None else None
    domain = args.domain_id if held is None else held.domain
    t0 = time.monotonic()
    try:
        reports = run(args.nodes, args.messages, args.seed, args.namespace, domain, Path(args.log_dir),
                      args.startup_timeout, args.settle_timeout)
        attacks = run_attacks(args.attacks, args.namespace, domain, Path(args.log_dir))
    except KeyboardInterrupt:
        print("[fuzz] interrupted; the nodes are stopped", file=sys.stderr)
        return 130
    finally:
        if held is not None:
            held.release()
    print_table(reports)
    failing = [r for r in reports if r.failures]
    for r in failing:
        print(f"FAIL {r.node}: {'; '.join(r.failures)} (log: {Path(args.log_dir) / (r.node + '.log')})")
    for a in attacks:
        if not a.passed:
            print(f"FAIL attack {a.attack}: {a.detail} (logs: {args.log_dir})")
    failed_attacks = [a for a in attacks if not a.passed]
    print(f"[fuzz] {len(reports) - len(failing)} of {len(reports)} node(s) and {len(attacks) - len(failed_attacks)} "
          f"of {len(attacks)} attack(s) passed in {time.monotonic() - t0:.1f} s")
    if args.json:
        Path(args.json).write_text(json.dumps({"domain_id": domain, "seed": args.seed, "messages": args.messages,
                                               "nodes": [r.to_dict() for r in reports],
                                               "attacks": [a.to_dict() for a in attacks]}, indent=2))
    return 1 if failing or failed_attacks else 0


if __name__ == "__main__":
    sys.exit(main())

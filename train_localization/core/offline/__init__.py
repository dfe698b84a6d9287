"""The graph without DDS: scenario -> sensors -> fusion, and bag -> decoders -> fusion.

``FusionRunner`` is the fusion node's logic (filter + fixed-rate output grid); the node wraps
it and so does every offline run here, so live and offline runs make the same estimates from
the same measurement sequence. One concern a module:

  topics.py        the topics and namespaces of the bags (those of the live graph)
  bags.py          what a bag records besides the topics: the scenario, the interlocking
  feed.py          one train's fusion: its runner, RunResult, and FusionFeed (fuses, writes)
  simulate.py      simulate_scenario (optionally into a bag); the measurement sequence alone
  line.py          several trains on one line: LineSimulation, LineFusion, simulate_line
  replay.py        replay_bag, replay_line: a bag's raw topics through the decoders and fusion
  parallel.py      the parallel decoding of a replay, in forked worker processes
  control_loop.py  closed_loop: dynamics -> sensors -> fusion -> speed controller -> dynamics
"""
from ..pipeline import sensor_pipelines
from .bags import scenario_from_bag, string_message, write_interlocking
from .control_loop import ClosedLoopResult, closed_loop
from .feed import FusionFeed, RunResult, fusion_runner
from .line import LineFusion, LineResult, LineSimulation, simulate_line, wayside_pipelines
from .parallel import PARALLEL_WINDOW, can_fork, decode_in_parallel
from .replay import MessageDecoder, replay_bag, replay_line
from .simulate import delayed, fuse_arrivals, scenario_measurements, simulate_scenario, within_latency
from .topics import (FUSED_TOPIC, INTERLOCKING_TOPIC, LINE_SCENARIO_TOPIC, SCENARIO_TOPIC, TRACKS_TOPIC, TRUTH_TOPIC,
                     WAYSIDE_NAMESPACE, raw_topic, train_namespace)

__all__ = ["ClosedLoopResult", "FUSED_TOPIC", "FusionFeed", "INTERLOCKING_TOPIC", "LINE_SCENARIO_TOPIC", "LineFusion",
           "LineResult", "LineSimulation", "MessageDecoder", "PARALLEL_WINDOW", "RunResult", "SCENARIO_TOPIC",
           "TRACKS_TOPIC", "TRUTH_TOPIC", "WAYSIDE_NAMESPACE", "can_fork", "closed_loop", "decode_in_parallel", "delayed",
           "fuse_arrivals", "fusion_runner", "raw_topic", "replay_bag", "replay_line", "scenario_from_bag",
           "scenario_measurements", "sensor_pipelines", "simulate_line", "simulate_scenario", "string_message",
           "train_namespace", "wayside_pipelines", "within_latency", "write_interlocking"]

"""Recorder node: writes topics to one MCAP file (ros2msg schemas, CDR as received).

Subscriptions are raw (serialized bytes, no deserialisation, docs/nodes.md, recorder),
so the bytes in the bag are exactly those published. Topics are discovered
periodically; a topic is recorded from the moment it is discovered.

Parameters:
  output (string, "recording.mcap")   file to write (parent directories are created)
  topics (string[], [])               topics to record (absolute or relative to the
                                      node namespace); empty = every topic seen
  exclude (string[], ["/rosout", "/parameter_events"])
  discovery_period (double, 0.2)      [s]
  compression (string, "zstd")        zstd | lz4 | none
  chunk_size (int, 262144)            bytes of messages per chunk, 1024 .. 67108864; a full
                                      chunk is flushed to the file at once, so a SIGKILL or power
                                      loss loses only the open chunk (tl_bag recover)
Log time of each message = the node clock at reception (sim time with
use_sim_time:=true). On SIGINT/SIGTERM every message received so far is written and
the file is closed properly; ``counts`` in the final log line are per topic.
"""
from __future__ import annotations

import importlib

from rclpy.node import Node

from ..core.bagio import BagWriter
from ..core.sensors.base import Param
from .common import CLOCK_QOS, LATCHED_QOS, STREAM_QOS, declare_param, spin, steady_clock

# the node's parameters (tools/docs.py writes them into config/params/recorder.yaml)
PARAMS = {
    "output": Param("recording.mcap", "MCAP file to write"),
    "topics": Param([""], "topics to record; empty = all"),
    "exclude": Param(["/rosout", "/parameter_events"], "topics never recorded"),
    "discovery_period": Param(0.2, "topic discovery period [s]"),
    "compression": Param("zstd", "chunk compression: zstd, lz4 or none"),
    "chunk_size": Param(256 * 1024, "bytes of messages per chunk: a chunk reaches the file when full, a SIGKILL "
                                    "loses only the open one", (1024, 64 * 1024 * 1024)),
}


def message_class(typename: str):
    pkg, kind, name = typename.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


class RecorderNode(Node):
    def __init__(self):
        super().__init__("recorder")
        self.output = declare_param(self, PARAMS, "output", read_only=False)
        wanted = [t for t in declare_param(self, PARAMS, "topics", read_only=False) if t]
        self.wanted = {self.resolve_topic_name(t) for t in wanted}
        self.exclude = set(declare_param(self, PARAMS, "exclude", read_only=False))
        period = float(declare_param(self, PARAMS, "discovery_period", read_only=False))
        compression = declare_param(self, PARAMS, "compression", read_only=False)
        chunk_size = declare_param(self, PARAMS, "chunk_size", read_only=False)
        self.writer = BagWriter(self.output, chunk_size=chunk_size, compression=compression)
        self.subs = {}
        self._discover()
        # wall-clock timer: with use_sim_time there is no /clock before the simulator runs
        self.create_timer(period, self._discover, clock=steady_clock())
        self.get_logger().info(f"recording to {self.output}")

    def _discover(self):
        for topic, types in self.get_topic_names_and_types():
            if topic in self.subs or topic in self.exclude or (self.wanted and topic not in self.wanted):
                continue
            typename = types[0]
            try:
                cls = message_class(typename)
            except (ImportError, AttributeError, ValueError):
                self.get_logger().warn(f"cannot record {topic}: type {typename} is not importable")
                self.exclude.add(topic)
                continue
            qos = CLOCK_QOS if topic == "/clock" else STREAM_QOS
            infos = self.get_publishers_info_by_topic(topic)
            if any(i.qos_profile.durability == LATCHED_QOS.durability for i in infos):
                qos = LATCHED_QOS
            self.subs[topic] = self.create_subscription(
                cls, topic, lambda data, topic=topic, typename=typename: self._on_msg(topic, typename, data),
                qos, raw=True)

    @property
    def activity(self) -> int:
        """Messages written so far (the shutdown drain waits until it stops growing)."""
        return sum(self.writer.counts.values())

    def _on_msg(self, topic, typename, data: bytes):
        self.writer.write_cdr(topic, typename, data, self.get_clock().now().nanoseconds)

    def close(self):
        self.writer.close()
        counts = ", ".join(f"{t}={n}" for t, n in sorted(self.writer.counts.items()))
        print(f"[recorder] wrote {self.output}: {counts}", flush=True)


def main(args=None):
    return spin(RecorderNode, args, usage=__doc__)

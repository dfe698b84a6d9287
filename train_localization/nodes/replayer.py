"""Replayer node: plays an MCAP bag into the graph, like ``ros2 bag play``.

Messages are published as the serialized bytes stored in the bag (no decoding),
paced by their log time. /clock is published from the bag's time line (unless the
bag's own /clock is replayed), so nodes with use_sim_time follow the recording.

Parameters:
  bag (string, required)     MCAP file
  rate (double, 1.0)         playback speed factor; 0 = as fast as possible
  start_offset (double, 0.0) skip the first seconds of the bag [s]
  loop (bool, false)         start again at the end
  topics (string[], [])      topics to play; empty = all
  remap (string[], [])       "from:=to" topic remappings, e.g. "/train/sensors/doppler/raw:=/lab/raw"
  clock_rate (double, 100.0) /clock publications per second of bag time [Hz]
  exit_at_end (bool, true)   shut down after the last message (ignored with loop)
  wait_for_subscribers (int, 0)  before playing, wait (at most 60 s) until the
                             played topics have this many matched subscribers in all
  wait_for_clock_subscribers (int, 0)  ... and /clock this many (every node with
                             use_sim_time)
  wait_for_publishers (string[], [])  ... and a publisher on each of these topics: a node
                             that listens to no played topic (the fusion: its
                             localization/state) has /clock from its creation, but
                             listens to its inputs only once it is set up
  wait_for_subscribed (string[], [])  ... and a subscriber on each of these topics (the
                             fusion's inputs, which the sensor nodes publish from the
                             played raw blocks)
A truncated bag (its recorder killed) is played up to its last complete chunk, with a
warning.
"""
from __future__ import annotations

import threading
import time

from mcap.exceptions import McapError
from mcap.reader import make_reader
from rclpy.node import Node
from rosgraph_msgs.msg import Clock

from ..core.bagio import recovered_copy
from ..core.sensors.base import Param
from .common import CLOCK_QOS, LATCHED_QOS, STATE_QOS, STREAM_QOS, ConfigurationError, declare_param, spin
from .recorder import message_class

# the node's parameters (tools/docs.py writes them into config/params/replayer.yaml)
PARAMS = {
    "bag": Param("", "MCAP file to play"),
    "rate": Param(1.0, "playback speed factor; 0 = as fast as possible"),
    "start_offset": Param(0.0, "skip this much of the bag [s]"),
    "loop": Param(False, "start again at the end"),
    "topics": Param([""], "topics to play; empty = all"),
    "remap": Param([""], "'from:=to' topic remappings"),
    "clock_rate": Param(100.0, "/clock rate [Hz of bag time]"),
    "exit_at_end": Param(True, "shut down at the end"),
    "wait_for_subscribers": Param(0, "matched subscribers to wait for"),
    "wait_for_clock_subscribers": Param(0, "matched /clock subscribers to wait for (nodes with use_sim_time)"),
    "wait_for_publishers": Param([""], "topics that must have a publisher before playing"),
    "wait_for_subscribed": Param([""], "topics that must have a subscriber before playing"),
}


class ReplayerNode(Node):
    def __init__(self):
        super().__init__("replayer")
        self.bag = declare_param(self, PARAMS, "bag", read_only=False)
        if not self.bag:
            raise ConfigurationError("parameter 'bag' is required (an MCAP file to play)")
        self.rate = float(declare_param(self, PARAMS, "rate", read_only=False))
        self.start_offset = float(declare_param(self, PARAMS, "start_offset", read_only=False))
        self.loop = bool(declare_param(self, PARAMS, "loop", read_only=False))
        self.topics = {t for t in declare_param(self, PARAMS, "topics", read_only=False) if t}
        self.remap = {}
        for item in declare_param(self, PARAMS, "remap", read_only=False):
            if item:
                src, sep, dst = item.partition(":=")
                if not sep:
                    raise ConfigurationError(f"remap entry {item!r} is not 'from:=to'")
                self.remap[src] = dst
        self.clock_period = 1.0 / float(declare_param(self, PARAMS, "clock_rate", read_only=False))
        self.exit_at_end = bool(declare_param(self, PARAMS, "exit_at_end", read_only=False))
        self.wait_for = int(declare_param(self, PARAMS, "wait_for_subscribers", read_only=False))
        self.wait_for_clock = int(declare_param(self, PARAMS, "wait_for_clock_subscribers", read_only=False))
        self.wait_for_publishers = [str(t) for t in declare_param(self, PARAMS, "wait_for_publishers",
                                                                   read_only=False) if t]
        self.wait_for_subscribed = [str(t) for t in declare_param(self, PARAMS, "wait_for_subscribed",
                                                                   read_only=False) if t]
        self.pubs = {}
        self.published = 0
        self.finished = False
        self._stop = threading.Event()
        self._recovered = None
        summary = self._summary()
        self._channels = {cid: ch for cid, ch in summary.channels.items()
                          if not self.topics or ch.topic in self.topics}
        for cid, ch in self._channels.items():
            typename = summary.schemas[ch.schema_id].name
            topic = self.remap.get(ch.topic, ch.topic)
            qos = CLOCK_QOS if topic == "/clock" else STATE_QOS if topic.endswith("localization/state") else \
                LATCHED_QOS if topic.endswith("sections") else STREAM_QOS
            self.pubs[cid] = self.create_publisher(message_class(typename), topic, qos)
        self._own_clock = not any(ch.topic == "/clock" for ch in self._channels.values())
        self.clock_pub = self.create_publisher(Clock, "/clock", CLOCK_QOS) if self._own_clock else None
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _summary(self):
        """The bag's summary; a truncated bag (its recorder killed) is first rewritten to a
        temporary file up to its last complete chunk (core/bagio.py recover_bag), with a warning."""
        try:
            with open(self.bag, "rb") as fh:
                summary = make_reader(fh).get_summary()
            if summary is not None:
                return summary
        except McapError:
            pass
        self._recovered, warning = recovered_copy(self.bag)
        self.get_logger().warn(warning)
        self.bag = str(self._recovered)
        with open(self.bag, "rb") as fh:
            return make_reader(fh).get_summary()

    def _publish_clock(self, t_ns: int):
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(int(t_ns), 1_000_000_000)
        self.clock_pub.publish(msg)

    def _run(self):
        deadline = time.monotonic() + 60.0
        while ((sum(p.get_subscription_count() for p in self.pubs.values()) < self.wait_for
                or (self.clock_pub is not None and self.clock_pub.get_subscription_count() < self.wait_for_clock)
                or any(self.count_publishers(t) < 1 for t in self.wait_for_publishers)
                or any(self.count_subscribers(t) < 1 for t in self.wait_for_subscribed))
               and time.monotonic() < deadline and not self._stop.is_set()):
            self._stop.wait(0.05)
        self._stop.wait(0.5)  # let subscribers match
        while not self._stop.is_set():
            self._play_once()
            if not self.loop:
                break
        self.get_logger().info(f"replay finished: {self.published} messages")
        if self.exit_at_end and not self.loop:
            self._stop.wait(0.5)
            self.finished = True

    def _play_once(self):
        with open(self.bag, "rb") as fh:
            reader = make_reader(fh)
            t0_bag = None
            wall0 = time.monotonic()
            next_clock = None
            for _, channel, message in reader.iter_messages(log_time_order=True):
                if self._stop.is_set():
                    return
                if t0_bag is None:
                    t0_bag = message.log_time + int(self.start_offset * 1e9)
                if message.log_time < t0_bag or channel.id not in self.pubs:
                    continue
                rel = (message.log_time - t0_bag) * 1e-9
                if self.rate > 0:
                    lag = wall0 + rel / self.rate - time.monotonic()
                    if lag > 0:
                        self._stop.wait(lag)
                if self.clock_pub is not None:
                    if next_clock is None or message.log_time >= next_clock:
                        self._publish_clock(message.log_time)
                        next_clock = message.log_time + int(self.clock_period * 1e9)
                self.pubs[channel.id].publish(message.data)
                self.published += 1

    def close(self):
        """Stop the publishing thread before the node goes away (no publish after destroy)."""
        self._stop.set()
        self._thread.join(timeout=5.0)
        if self._recovered is not None:
            self._recovered.unlink(missing_ok=True)


def main(args=None):
    return spin(ReplayerNode, args, usage=__doc__)

"""MCAP bags without ROS: the typestore, a writer and a reader.

Bags are single ``.mcap`` files with ``ros2msg`` schemas (the full concatenated
message definition, as rosbag2 writes them) and CDR messages, so ``ros2 bag play``,
rosbags and the mcap library's ROS 2 decoder all read them without this package.

The message definitions of train_localization_msgs come from the installed package
(ament index) or, in a source checkout, from msg_defs/.
"""
from __future__ import annotations

import logging
import os
import tempfile
from collections import Counter
from functools import lru_cache
from pathlib import Path
from typing import Iterator

import numpy as np
from mcap.writer import CompressionType, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from .convert import MsgClasses
from .paths import SOURCE_ROOT
from .signals import InputRejected

MSG_PACKAGE = "train_localization_msgs"


def _msg_dir() -> Path:
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
        try:
            return Path(get_package_share_directory(MSG_PACKAGE)) / "msg"
        except PackageNotFoundError:
            pass
    except ImportError:
        pass
    return SOURCE_ROOT / "msg_defs" / "msg"


@lru_cache(maxsize=1)
def typestore():
    """rosbags typestore: ROS 2 Jazzy types + train_localization_msgs."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for path in sorted(_msg_dir().glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"{MSG_PACKAGE}/msg/{path.stem}"))
    store.register(types)
    return store


def typestore_classes() -> MsgClasses:
    """MsgClasses backed by the typestore (for writing bags offline)."""
    t = typestore().types

    def cls(name):
        return t[name]

    def array(values: np.ndarray, kind: str):
        return np.ascontiguousarray(values, dtype=np.float32 if kind == "float32" else np.float64)

    def make(name):
        c = cls(name)

        def build(**kw):
            return c(**kw)
        return build

    def accel_body(x: float, variance: float):
        vector = t["geometry_msgs/msg/Vector3"]
        covariance = np.zeros(36)
        covariance[0] = variance
        return t["geometry_msgs/msg/AccelWithCovariance"](
            accel=t["geometry_msgs/msg/Accel"](linear=vector(x=x, y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=0.0)),
            covariance=covariance)

    p = MSG_PACKAGE + "/msg/"
    return MsgClasses(Time=make("builtin_interfaces/msg/Time"), Header=make("std_msgs/msg/Header"),
                      TrainState=make(p + "TrainState"), RawBlock=make(p + "RawBlock"),
                      PositionFix=make(p + "PositionFix"), SpeedMeasurement=make(p + "SpeedMeasurement"),
                      DistanceIncrement=make(p + "DistanceIncrement"), SectionState=make(p + "SectionState"),
                      SectionOccupancy=make(p + "SectionOccupancy"), TrackHypothesis=make(p + "TrackHypothesis"),
                      TrackHypotheses=make(p + "TrackHypotheses"), SwitchPositions=make(p + "SwitchPositions"),
                      YawRate=make(p + "YawRate"), array=array,
                      AccelWithCovarianceStamped=make("geometry_msgs/msg/AccelWithCovarianceStamped"),
                      accel_body=accel_body)


def ros2_typename(name: str) -> str:
    """'pkg/msg/Type' (rosbags, ROS 2 graph) for 'pkg/msg/Type' or 'pkg/Type'."""
    parts = name.split("/")
    return name if len(parts) == 3 else f"{parts[0]}/msg/{parts[-1]}"


class BagWriter:
    """Writes CDR messages to one MCAP file; schemas and channels are added on first use.

    Chunks are zstd-compressed. ``close`` must be called (the recorder does it on every
    exit path) to write the summary; until then data is flushed chunk by chunk.
    """

    def __init__(self, path: str | Path, chunk_size: int = 256 * 1024, compression: str = "zstd"):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(self.path, "wb")
        self._written = 0       # file position after the last chunk, flushed to the OS
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[compression]
        self._writer = Writer(self._fh, chunk_size=chunk_size, compression=comp)
        self._writer.start(profile="ros2", library="train_localization")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.counts: Counter[str] = Counter()
        self._closed = False

    def _channel(self, topic: str, typename: str) -> int:
        if topic not in self._channels:
            typename = ros2_typename(typename)
            if typename not in self._schemas:
                msgdef, _ = typestore().generate_msgdef(typename, ros_version=2)
                self._schemas[typename] = self._writer.register_schema(
                    name=typename, encoding="ros2msg", data=msgdef.encode())
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=self._schemas[typename],
                metadata={"offered_qos_profiles": ""})
        return self._channels[topic]

    def write_cdr(self, topic: str, typename: str, data: bytes, log_time_ns: int,
                  publish_time_ns: int | None = None) -> None:
        channel = self._channel(topic, typename)
        self._writer.add_message(channel_id=channel, log_time=int(log_time_ns), data=bytes(data),
                                 publish_time=int(log_time_ns if publish_time_ns is None else publish_time_ns),
                                 sequence=self.counts[topic])
        self.counts[topic] += 1
        if self._fh.tell() != self._written:   # a chunk was completed: to the OS at once, so that a
            self._fh.flush()                   # SIGKILL loses only the open chunk
            self._written = self._fh.tell()

    def write(self, topic: str, msg, log_time_ns: int) -> None:
        """Serialise a typestore message object and write it."""
        typename = msg.__msgtype__
        self.write_cdr(topic, typename, bytes(typestore().serialize_cdr(msg, typename)), log_time_ns)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._writer.finish()
            self._fh.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class BagReader:
    """One bag, read in log-time order: messages as CDR bytes, and their deserialiser.

    Types are taken from the bag's own schemas, so bags from other versions decode. A
    truncated MCAP file (its writer killed) is read up to its last complete chunk, with a
    warning.
    ``deserialize`` keeps working after the reader is closed (it only needs the types),
    so the bytes can be decoded later or in another process (core/offline/parallel.py).
    """

    def __init__(self, path: str | Path):
        from rosbags.highlevel import AnyReader
        self.path = Path(path)
        self._reader = AnyReader([self.path], default_typestore=typestore())
        self._store = None
        self._recovered: Path | None = None   # temporary copy of a truncated bag

    def __enter__(self) -> "BagReader":
        try:
            self._reader.open()
        except Exception:   # rosbags: a file without summary (its writer was killed)
            if not _is_mcap(self.path):
                raise
            self._recovered, warning = recovered_copy(self.path)
            logging.getLogger(__name__).warning(warning)
            from rosbags.highlevel import AnyReader
            self._reader = AnyReader([self._recovered], default_typestore=typestore())
            self._reader.open()
        self._store = self._reader.typestore
        return self

    @property
    def source(self) -> Path:
        """The file read: the bag, or the valid copy of a truncated one (another process can
        open it with its own reader while this one is open)."""
        return self._recovered or self.path

    def __exit__(self, *exc) -> None:
        self._reader.close()
        if self._recovered is not None:
            self._recovered.unlink(missing_ok=True)

    def cdr(self, topics: list[str] | None = None) -> Iterator[tuple[str, str, int, bytes]]:
        """(topic, typename, log_time_ns, CDR bytes) of the messages of ``topics`` (all if None)."""
        conns = [c for c in self._reader.connections if topics is None or c.topic in topics]
        if not conns:
            return  # (an empty list would mean "all connections" to rosbags)
        for conn, t_ns, raw in self._reader.messages(connections=conns):
            yield conn.topic, conn.msgtype, t_ns, raw

    def deserialize(self, data: bytes, typename: str):
        """Message object of CDR bytes; raises InputRejected("malformed") for bytes that do not parse."""
        try:
            return self._store.deserialize_cdr(data, typename)
        except Exception as exc:   # rosbags raises SerdeError, struct.error, IndexError, ...
            raise InputRejected("malformed", f"{typename} message does not deserialise: {exc}") from None


def _is_mcap(path: Path) -> bool:
    with open(path, "rb") as fh:
        return fh.read(8) == b"\x89MCAP0\r\n"


def read_bag(path: str | Path, topics: list[str] | None = None) -> Iterator[tuple[str, str, int, object]]:
    """(topic, typename, log_time_ns, message) of every message, in log-time order.

    Raises InputRejected for a message that does not deserialise.
    """
    with BagReader(path) as reader:
        for topic, typename, t_ns, raw in reader.cdr(topics):
            yield topic, typename, t_ns, reader.deserialize(raw, typename)


def topic_counts(path: str | Path) -> dict[str, int]:
    """Messages per topic from the MCAP summary."""
    from mcap.reader import make_reader
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    channels = summary.channels
    counts: Counter[str] = Counter()
    for cid, n in summary.statistics.channel_message_counts.items():
        counts[channels[cid].topic] += n
    return dict(counts)


def recover_bag(src: str | Path, dst: str | Path) -> tuple[dict[str, int], str | None]:
    """Rewrite a truncated MCAP file (its writer was killed: no summary, a chunk cut off) into
    a valid one: every message up to the last complete record, schemas and channels as they
    were. Returns (messages per topic copied, why the input ended early or None if it was
    complete)."""
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    counts: Counter[str] = Counter()
    schemas: dict[int, int] = {}
    channels: dict[int, tuple[int, str]] = {}
    problem = None
    Path(dst).parent.mkdir(parents=True, exist_ok=True)
    with open(src, "rb") as fh, open(dst, "wb") as out:
        writer = Writer(out, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="train_localization recover")
        try:
            for rec in StreamReader(fh).records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = writer.register_schema(rec.name, rec.encoding, rec.data)
                elif isinstance(rec, Channel):
                    channels[rec.id] = (writer.register_channel(rec.topic, rec.message_encoding,
                                                                schemas.get(rec.schema_id, 0), rec.metadata),
                                        rec.topic)
                elif isinstance(rec, Message) and rec.channel_id in channels:
                    cid, topic = channels[rec.channel_id]
                    writer.add_message(cid, rec.log_time, rec.data, rec.publish_time, rec.sequence)
                    counts[topic] += 1
        except Exception as exc:  # noqa: BLE001 - the cut: a record runs past the end (McapError,
            # EOFError, struct.error) or a cut chunk does not decompress (zstd/lz4 errors)
            problem = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
        writer.finish()
    return dict(counts), problem


def recovered_copy(path: str | Path) -> tuple[Path, str]:
    """A truncated bag rewritten by ``recover_bag`` to a temporary file (the caller deletes
    it), and the warning to log about it."""
    fd, tmp = tempfile.mkstemp(suffix=".mcap")
    os.close(fd)
    counts, problem = recover_bag(path, tmp)
    return Path(tmp), (f"{path} is truncated ({problem or 'no summary'}): reading the "
                       f"{sum(counts.values())} messages of its complete chunks")

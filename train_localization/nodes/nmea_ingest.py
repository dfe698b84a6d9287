"""nmea_ingest node: a GNSS receiver's NMEA 0183 sentences as sensor_msgs/NavSatFix.

Reads one source (exactly one of ``file``, ``udp.port``, ``serial.device``) and publishes:
  <fix_topic>  sensor_msgs/NavSatFix of each GGA epoch, its covariance the epoch's GST 1-sigma
               (COVARIANCE_TYPE_DIAGONAL_KNOWN) or none (COVARIANCE_TYPE_UNKNOWN); the fix
               quality as NavSatStatus (core/ingest/nmea.py). standard_inputs' navsat.topic
               reads it (docs/integration.md, "From your drivers").
  <vel_topic>  geometry_msgs/TwistStamped of each RMC / VTG: velocity over ground, linear.x east,
               linear.y north [m/s] (as nmea_navsat_driver's ``vel``); empty: not published
Stamped at receipt on the node clock (as nmea_navsat_driver by default). A file is replayed at
``rate`` times the pace of its sentences' UTC times (0: as fast as read) and the node stays up
at its end (the status says so). Sentences are parsed by pynmea2; refused and
counted per reason in /diagnostics (``rejected/nmea/<reason>``: checksum, truncated, malformed,
talker, out_of_range), never published; ``nmea/<count>`` counts sentences, fixes, velocities,
ignored and void ones.

Parameters: PARAMS below (docs/nodes.md).
"""
from __future__ import annotations

import time

from geometry_msgs.msg import TwistStamped
from sensor_msgs.msg import NavSatFix, NavSatStatus

from ..core.ingest.nmea import TALKERS, NmeaDecoder, NmeaFix
from ..core.ingest.pacing import ReplayPace
from ..core.ingest.streams import BAUDS, FileLines, SerialLines, UdpLines
from ..core.sensors.base import Param, check_declared
from ..core.signals import InputRejected
from .common import STREAM_QOS, ConfigurationError, PollingNode, declare_param, spin

PARAMS = {
    "file": Param("", "NMEA file replayed, one sentence a line; exactly one of file, udp.port, serial.device"),
    "rate": Param(1.0, "file replay speed: 1 at the pace of the sentences' UTC times, 0 as fast as read",
                  (0.0, 1000.0)),
    "wait_for_subscribers": Param(0, "a file replay starts once each topic published has this many subscribers",
                                  (0, 100)),
    "udp.port": Param(0, "UDP port the sentences arrive at (10110 by custom); 0: none", (0, 65535)),
    "udp.address": Param("127.0.0.1", "address the UDP port is bound to (127.0.0.1: this host only)"),
    "serial.device": Param("", "serial device of the receiver (/dev/ttyUSB0); empty: none"),
    "serial.baud": Param(9600, f"its baud rate (one of {', '.join(map(str, BAUDS))})", (BAUDS[0], BAUDS[-1])),
    "talkers": Param(list(TALKERS), "talker IDs taken (GP GPS, GL GLONASS, GA Galileo, GB/BD BeiDou, GQ QZSS, "
                                    "GN several); a sentence of another is refused (talker)"),
    "fix_topic": Param("/gnss/fix", "sensor_msgs/NavSatFix topic"),
    "vel_topic": Param("", "geometry_msgs/TwistStamped topic of the velocity over ground; empty: not published"),
    "frame_id": Param("gnss", "header.frame_id of the messages (the antenna's frame)"),
    "poll_period": Param(0.01, "time between two reads of the source [s]", (0.001, 1.0)),
}
check_declared(PARAMS, "nmea_ingest PARAMS")
STREAM = "nmea"   # the diagnostics' name of the input


class NmeaIngestNode(PollingNode):
    """A managed (lifecycle) node like the sensor nodes: the source is opened on activate."""

    def __init__(self):
        super().__init__("nmea_ingest", "NMEA 0183 ingest")
        self.predeclare(PARAMS)
        self._source = None
        self.start()

    def _configure(self) -> None:
        self.values = {name: declare_param(self, PARAMS, name) for name in PARAMS}
        self.poll_period = float(self.values["poll_period"])
        given = [bool(self.values["file"]), bool(self.values["udp.port"]), bool(self.values["serial.device"])]
        if sum(given) != 1:
            raise ConfigurationError("give exactly one source: file, udp.port or serial.device")
        self.fix_pub = self.create_lifecycle_publisher(NavSatFix, self.values["fix_topic"], STREAM_QOS)
        self.vel_pub = (self.create_lifecycle_publisher(TwistStamped, self.values["vel_topic"], STREAM_QOS)
                        if self.values["vel_topic"] else None)

    def _open(self) -> None:
        v = self.values
        if v["file"]:
            self._source = FileLines(v["file"])
        elif v["udp.port"]:
            self._source = UdpLines(v["udp.address"], int(v["udp.port"]))
        else:
            self._source = SerialLines(v["serial.device"], int(v["serial.baud"]))
        self.decoder = NmeaDecoder(v["talkers"])
        self.pace = ReplayPace(float(v["rate"])) if v["file"] else None
        self._queue: list[tuple[float, object]] = []   # (host time due, record)

    def _close(self) -> None:
        if self._source is not None:
            self._source.close()
            self._source = None

    def on_timer(self) -> None:
        if self.pace is not None and any(p.get_subscription_count() < self.values["wait_for_subscribers"]
                                         for p in (self.fix_pub, self.vel_pub) if p is not None):
            return
        now = time.monotonic()
        # a file is read ahead only as far as its records are due; a live source is read whole
        while self._source is not None and not self._source.eof and (
                self.pace is None or not self._queue or self._queue[-1][0] <= now):
            lines = self._source.read(1 if self.pace is not None else 100)
            if not lines:
                break
            for line in lines:
                self._take(line, now)
        if self._source is not None and self._source.eof and self.pace is not None:
            self._queue += [(now, r) for r in self.decoder.flush()]
            self.pace = None
            self.diag.set_status(0, "end of file")
        while self._queue and self._queue[0][0] <= now:
            self._publish(self._queue.pop(0)[1])
        self.diag.values.update({f"nmea/{k}": str(n) for k, n in self.decoder.stats.items()})

    def _take(self, line: bytes, now: float) -> None:
        try:
            records = self.decoder.feed(line)
        except InputRejected as exc:
            self.diag.reject(STREAM, exc.reason, str(exc))
            return
        self.diag.accept(STREAM)
        for r in records:   # a VTG has no time: due with what came before it
            due = now if self.pace is None or r.utc_time is None else self.pace.due(r.utc_time, now)
            self._queue.append((max(due, self._queue[-1][0]) if self._queue else due, r))

    def _header(self, msg):
        """Stamped at receipt on the node clock (as nmea_navsat_driver by default)."""
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self.values["frame_id"]
        return msg

    def _publish(self, record) -> None:
        if isinstance(record, NmeaFix):
            msg = NavSatFix(latitude=record.latitude, longitude=record.longitude, altitude=record.altitude)
            msg.status.status, msg.status.service = record.status, NavSatStatus.SERVICE_GPS
            cov, msg.position_covariance_type = record.covariance
            msg.position_covariance = list(cov)
            self.fix_pub.publish(self._header(msg))
        elif self.vel_pub is not None:
            msg = TwistStamped()
            msg.twist.linear.x, msg.twist.linear.y = record.east_north
            self.vel_pub.publish(self._header(msg))


def main(args=None):
    return spin(NmeaIngestNode, args, usage=__doc__)

"""A GNSS receiver's NMEA 0183 sentences as NavSatFix-like records (pynmea2 parses them).

What a receiver's serial port, a UDP stream or a logged file carries, sentence by sentence:

  ``GGA``  the fix: UTC time, latitude, longitude, fix quality, satellites, HDOP, altitude
  ``GST``  the error statistics of the epoch: 1-sigma of the latitude, longitude and altitude
           errors [m], which become the fix's covariance (COVARIANCE_TYPE_DIAGONAL_KNOWN, as
           nmea_navsat_driver does); a fix without its GST has none (COVARIANCE_TYPE_UNKNOWN:
           the reader's receiver model rates it, core/ingest/navsat.py)
  ``RMC``, ``VTG``  the velocity over ground (speed [m/s], true course [deg])

A GGA is held until its epoch is complete: the GST of the same UTC time (before or after it),
or any sentence of a later epoch, or ``flush`` (end of a file). The fix quality becomes
NavSatStatus as nmea_navsat_driver maps it: 0, 6 (dead reckoning), 7 (manual), 8 (simulator) no
fix; 1, 3 (PPS) autonomous; 2, 9 (SBAS/WAAS) SBAS; 4, 5 (RTK fixed, float) GBAS.

Refused with a one-line reason (InputRejected), counted by the caller, nothing held changes:

  ``checksum``      the checksum does not match the sentence
  ``truncated``     no checksum (a sentence cut off in the stream), or fewer fields than its type has
  ``malformed``     not an NMEA sentence, not ASCII, or a field that is no number / time / date
  ``talker``        a talker other than ``talkers`` (GP GPS, GL GLONASS, GA Galileo, GB/BD BeiDou,
                    GQ QZSS, GN several)
  ``out_of_range``  a latitude beyond 90 deg, a longitude beyond 180 deg, minutes of 60 or more, an
                    unknown fix quality, an HDOP <= 0, a satellite count beyond 99, a negative
                    sigma or speed, a course beyond 360 deg

Other sentence types (GSV, GSA, ZDA, proprietary ones) are counted ``ignored``; an RMC or VTG
whose status or mode says invalid (V, N) is counted ``void``.
"""
from __future__ import annotations

import datetime as dt
import math
from dataclasses import dataclass, replace

import pynmea2

from ..signals import InputRejected
from .records import (COVARIANCE_TYPE_DIAGONAL_KNOWN, COVARIANCE_TYPE_UNKNOWN, STATUS_FIX, STATUS_GBAS_FIX,
                      STATUS_NO_FIX, STATUS_SBAS_FIX, GnssFix)

TALKERS = ("GP", "GL", "GA", "GB", "BD", "GQ", "GN")
FIELDS = {"GGA": 14, "GST": 8, "RMC": 11, "VTG": 8}   # least field count of each type read
QUALITY_STATUS = {0: STATUS_NO_FIX, 1: STATUS_FIX, 2: STATUS_SBAS_FIX, 3: STATUS_FIX, 4: STATUS_GBAS_FIX,
                  5: STATUS_GBAS_FIX, 6: STATUS_NO_FIX, 7: STATUS_NO_FIX, 8: STATUS_NO_FIX, 9: STATUS_SBAS_FIX}
KNOT = 1852.0 / 3600.0   # [m/s]
MAX_LINE = 82            # NMEA 0183: longest sentence, '$' to <CR><LF> [characters]


@dataclass(frozen=True)
class NmeaFix:
    """One epoch's fix: UTC time of day [s], WGS-84
    latitude and longitude [deg], altitude above mean sea level [m], NavSatStatus ``status``,
    the GGA ``quality``, satellites in use, HDOP, and the GST 1-sigma east, north, up [m] (None
    without a GST for the epoch)."""

    utc_time: float
    status: int
    quality: int
    latitude: float
    longitude: float
    altitude: float
    satellites: int
    hdop: float
    sigma_enu: tuple[float, float, float] | None = None

    @property
    def covariance(self) -> tuple[tuple[float, ...], int]:
        """The ENU position covariance (9 values, row-major) [m^2] and its COVARIANCE_TYPE."""
        if self.sigma_enu is None:
            return (0.0,) * 9, COVARIANCE_TYPE_UNKNOWN
        e, n, u = self.sigma_enu
        return (e * e, 0.0, 0.0, 0.0, n * n, 0.0, 0.0, 0.0, u * u), COVARIANCE_TYPE_DIAGONAL_KNOWN

    def gnss_fix(self, stamp: float) -> GnssFix:
        """The fix as the standard input reads a NavSatFix (core/ingest/records.py), at ``stamp``."""
        cov, kind = self.covariance
        return GnssFix(stamp, self.status, self.latitude, self.longitude, cov[0], cov[1], cov[4], kind)


@dataclass(frozen=True)
class NmeaVelocity:
    """Velocity over ground of an RMC or VTG: speed [m/s], true course [deg clockwise from north],
    at UTC time of day ``utc_time`` [s] (None: a VTG, which carries no time)."""

    utc_time: float | None
    speed: float
    course: float

    @property
    def east_north(self) -> tuple[float, float]:
        c = math.radians(self.course)
        return self.speed * math.sin(c), self.speed * math.cos(c)


def _seconds(t) -> float:
    if not isinstance(t, dt.time):
        raise InputRejected("malformed", f"time field {t!r} is no hhmmss.ss")
    return t.hour * 3600.0 + t.minute * 60.0 + t.second + t.microsecond * 1e-6


def _number(value, name: str, kind=float, empty=None):
    if value in ("", None):
        if empty is not None:
            return empty
        raise InputRejected("truncated", f"field {name} is empty")
    try:
        out = kind(value)
    except (TypeError, ValueError):
        raise InputRejected("malformed", f"field {name} {value!r} is no number") from None
    if isinstance(out, float) and not math.isfinite(out):
        raise InputRejected("malformed", f"field {name} is {value!r}")
    return out


def _angle(text: str, hemisphere: str, degree_digits: int, limit: float, name: str) -> float:
    """Degrees of an NMEA (d)ddmm.mmmm field and its hemisphere letter."""
    if not text or not hemisphere:
        raise InputRejected("truncated", f"{name} field is empty")
    degrees, minutes = _number(text[:degree_digits], name, int), _number(text[degree_digits:], name)
    if not 0.0 <= minutes < 60.0:
        raise InputRejected("out_of_range", f"{name} {text}: {minutes:g} minutes")
    if hemisphere not in ("NS" if degree_digits == 2 else "EW"):
        raise InputRejected("malformed", f"{name} hemisphere {hemisphere!r}")
    value = degrees + minutes / 60.0
    if value > limit:
        raise InputRejected("out_of_range", f"{name} {value:g} deg beyond {limit:g}")
    return -value if hemisphere in "SW" else value


def _nonnegative(value: float, name: str, limit: float = math.inf) -> float:
    if not 0.0 <= value <= limit:
        raise InputRejected("out_of_range", f"{name} {value:g} outside 0 .. {limit:g}")
    return value


class NmeaDecoder:
    """Sentences -> NmeaFix and NmeaVelocity records (module docstring). ``stats``: sentences
    taken, fixes and velocities emitted, sentences ``ignored`` and ``void``."""

    def __init__(self, talkers=TALKERS):
        self.talkers = tuple(talkers)
        self._pending: NmeaFix | None = None
        self._last_gst: tuple[float, tuple[float, float, float]] | None = None   # utc time, sigmas
        self.stats = {"sentences": 0, "fixes": 0, "velocities": 0, "ignored": 0, "void": 0}

    def feed(self, line: str | bytes) -> list:
        """The records completed by one sentence; InputRejected for a bad one."""
        msg = self._parse(line)
        kind = getattr(msg, "sentence_type", None)
        if kind not in FIELDS:
            self.stats["ignored"] += 1
            return []
        if len(msg.data) < FIELDS[kind]:
            raise InputRejected("truncated", f"{msg.talker}{kind} has {len(msg.data)} fields, not {FIELDS[kind]}")
        record = getattr(self, f"_{kind.lower()}")(msg)   # checked before anything held changes
        self.stats["sentences"] += 1
        return self._take(kind, record)

    def flush(self) -> list:
        """The fix still held (end of a file)."""
        out, self._pending = [self._pending] if self._pending else [], None
        self.stats["fixes"] += len(out)
        return out

    def _parse(self, line: str | bytes):
        if isinstance(line, bytes):
            try:
                line = line.decode("ascii")
            except UnicodeDecodeError:
                raise InputRejected("malformed", "sentence holds non-ASCII bytes") from None
        line = line.strip()
        if len(line) > MAX_LINE:
            raise InputRejected("malformed", f"sentence of {len(line)} characters (NMEA 0183: at most {MAX_LINE})")
        if not line.startswith(("$", "!")):
            raise InputRejected("malformed", f"{line[:20]!r} does not start with $")
        if len(line.rpartition("*")[2]) != 2 or "*" not in line:
            raise InputRejected("truncated", f"{line[:20]!r}... has no checksum")
        try:
            msg = pynmea2.parse(line, check=True)
        except pynmea2.ChecksumError as exc:
            raise InputRejected("checksum", f"{line[:20]!r}...: {exc.args[0]}") from None
        except pynmea2.ParseError as exc:
            raise InputRejected("malformed", f"{line[:20]!r}...: {exc.args[0]}") from None
        if not isinstance(msg, pynmea2.TalkerSentence):
            return None   # a proprietary or query sentence: nothing to read (ignored)
        if msg.talker not in self.talkers:
            raise InputRejected("talker", f"talker {msg.talker!r} is none of {', '.join(self.talkers)}")
        return msg

    def _gga(self, m) -> NmeaFix:
        t = _seconds(m.timestamp)
        quality = _number(m.data[5], "quality", int)
        if quality not in QUALITY_STATUS:
            raise InputRejected("out_of_range", f"GGA fix quality {quality} is none of 0 .. 9")
        satellites = _number(m.data[6], "satellites", int, empty=0)
        hdop = _number(m.data[7], "hdop", empty=math.nan)
        if not 0 <= satellites <= 99 or hdop <= 0.0:
            raise InputRejected("out_of_range", f"GGA with {satellites} satellites, HDOP {hdop:g}")
        status = QUALITY_STATUS[quality]
        if status == STATUS_NO_FIX:
            return NmeaFix(t, status, quality, math.nan, math.nan, math.nan, satellites, hdop)
        lat = _angle(m.data[1], m.data[2], 2, 90.0, "latitude")
        lon = _angle(m.data[3], m.data[4], 3, 180.0, "longitude")
        alt = _number(m.data[8], "altitude", empty=math.nan)
        return NmeaFix(t, status, quality, lat, lon, alt, satellites, hdop)

    def _gst(self, m) -> tuple[float, tuple[float, float, float]]:
        t = _seconds(m.timestamp)
        lat_s, lon_s, alt_s = (_nonnegative(_number(m.data[k], name), name, 1e4)
                               for k, name in ((5, "sigma_latitude"), (6, "sigma_longitude"), (7, "sigma_altitude")))
        return t, (lon_s, lat_s, alt_s)

    def _rmc(self, m) -> NmeaVelocity | None:
        t = _seconds(m.timestamp)
        if m.data[1] != "A":
            self.stats["void"] += 1
            return None
        speed = _nonnegative(_number(m.data[6], "speed", empty=0.0) * KNOT, "speed [m/s]", 300.0)
        course = _nonnegative(_number(m.data[7], "course", empty=0.0), "course", 360.0)
        return NmeaVelocity(t, speed, course)

    def _vtg(self, m) -> NmeaVelocity | None:
        if len(m.data) > 8 and m.data[8] == "N":   # NMEA 2.3 mode indicator: data not valid
            self.stats["void"] += 1
            return None
        speed = _nonnegative(_number(m.data[6], "speed", empty=0.0) / 3.6, "speed [m/s]", 300.0)
        course = _nonnegative(_number(m.data[0], "course", empty=0.0), "course", 360.0)
        return NmeaVelocity(None, speed, course)

    def _take(self, kind: str, record) -> list:
        out = []
        epoch = record[0] if kind == "GST" else getattr(record, "utc_time", None)
        if self._pending is not None and epoch is not None and epoch != self._pending.utc_time:
            out += self.flush()   # a later epoch: the held fix has no GST
        if kind == "GGA":
            if self._last_gst is not None and self._last_gst[0] == record.utc_time:
                out.append(replace(record, sigma_enu=self._last_gst[1]))
                self.stats["fixes"] += 1
            else:
                self._pending = record
        elif kind == "GST":
            self._last_gst = record
            if self._pending is not None:
                out.append(replace(self._pending, sigma_enu=record[1]))
                self.stats["fixes"] += 1
                self._pending = None
        elif record is not None:
            out.append(record)
            self.stats["velocities"] += 1
        return out


def decode_log(lines) -> tuple[list, dict[str, int]]:
    """The records of a logged stream's lines, read whole as nmea_ingest reads a file (the fix
    held at the end flushed), and the sentences refused, by reason."""
    decoder, records, refused = NmeaDecoder(), [], {}
    for line in lines:
        try:
            records += decoder.feed(line)
        except InputRejected as exc:
            refused[exc.reason] = refused.get(exc.reason, 0) + 1
    return records + decoder.flush(), refused


class LineBuffer:
    """The bytes of a stream (a serial port) -> its complete lines. Bytes that run past ``limit``
    without a line end (noise on the line, a wrong baud rate) come out as one line, which the
    decoder refuses."""

    def __init__(self, limit: int = 4 * MAX_LINE):
        self.limit = limit
        self._buf = b""

    def feed(self, data: bytes) -> list[bytes]:
        *lines, self._buf = (self._buf + data).split(b"\n")
        if len(self._buf) > self.limit:
            lines.append(self._buf)
            self._buf = b""
        return [line for line in (raw.strip() for raw in lines) if line]

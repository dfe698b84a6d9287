"""DGPS receiver (on-board, UTM-02 urban maglev), seed 002 section 2.1.2.

Seed 002 section 2.1.2 ("UTM(Urban Transit Maglev) 자기부상철도"): UTM-02 detects the train
position with DGPS, a Doppler sensor and transponders; the Doppler speed is integrated for
the distance, and D-GPS and the transponder tags serve to initialise the train position and
to correct its error. The seed gives no DGPS accuracy, rate or antenna: the numbers below
are assumptions of a code-differential GNSS receiver (RTCM corrections), marked as such.

Raw signal (the receiver's navigation solution as it delivers it, one sample per epoch at
its output rate, default 10 Hz): ``x``, ``y`` [m] the antenna position in the track's
``map`` frame (a driver subtracts the frame origin from the receiver's projected grid
coordinates: float32 samples keep millimetres only near the origin), ``quality`` [1] the
fix quality as in NMEA GGA (0 no fix, 1 autonomous GNSS, 2 differential), ``satellites``
[1] in use and ``hdop`` [1] (99.9 without a fix, the NMEA convention).

Modelled:
  * white noise of the solution, 1-sigma ``white_sigma`` per horizontal axis at the
    nominal HDOP, scaled by HDOP / ``hdop_nominal``;
  * a multipath and residual differential error per axis: Gauss-Markov in the distance run
    (``multipath_length``: the reflectors around the antenna change as it moves) and in
    time (``multipath_tau``: the satellite geometry changes), 1-sigma ``multipath_sigma``
    in the open and ``structure_multipath_factor`` times that within ``structure_reach`` of
    a structure (reflections from its walls and deck, part of the sky masked; there the
    HDOP is ``structure_hdop_factor`` times nominal and ``structure_satellites_lost``
    satellites are lost). A code multipath error is bounded by the correlator's error
    envelope: the process is clipped at ``multipath_bound`` times its local 1-sigma;
  * outages: with the antenna under a structure (track equipment ``structure``: a tunnel,
    a station roof, a bridge deck over the guideway) the receiver has no fix; once the sky
    is back it needs ``reacquisition_time`` to track the satellites again and apply the
    corrections;
  * injected faults 'T0-T1:nocorr' (the correction link lost: autonomous fixes, quality 1,
    with ``autonomous_sigma`` more error per axis).

Decoder (the same for simulated, recorded and ingested blocks): every differential epoch
with enough satellites (``min_satellites``) and HDOP at most ``max_hdop`` is projected onto
the track alignment (Track.project): antenna chainage and lateral offset. The fix is the
train front = antenna chainage + ``antenna_offset`` at the epoch, 1-sigma
hypot(``white_sigma`` x HDOP / ``hdop_nominal``, the multipath 1-sigma where the antenna
is: open or near a structure, from the track's structures; the decoder's zone near a
structure is wider than ``structure_reach`` by the largest along-track error of a fix there,
so that a fix near one is never taken for one in the open). The cross-track component is a
free consistency check: a fix further from the alignment than ``lateral_gate`` times its
1-sigma, beyond an end of the track or inside a structure (where no satellite is in view)
is withheld and counted; so is a fix that another part of the alignment passes within that
gate as well (a track that crosses or comes back near itself, a flyover or a hairpin: the
2-D fix cannot tell which part the train is on, and the nearest may be kilometres off).
Counted: ``no_fix`` epochs and ``outages`` (runs of them), ``autonomous``,
``weak_geometry``, ``off_track``, ``ambiguous``, ``under_structure``. A fix gives no
direction (0). Implausible blocks (a quality code other than 0/1/2, a satellite count
that is no count, an HDOP <= 0 or beyond 99.9) are rejected as "implausible".

Track equipment (kind ``structure``; shared with any sensor that sees the sky)::

    structure:
      - {id: ST1, type: station, start: 1950.0, end: 2050.0}    # roof over the platform
      - {id: BR1, type: bridge, position: 3200.0, length: 15.0}  # road deck over the guideway
      - {id: TN1, type: tunnel, start: 4300.0, end: 4800.0}

Not modelled: the receiver's latency (the epoch is the sample stamp), height, carrier-phase
(RTK) solutions, a satellite lost elsewhere than near structures.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from ..measurements import PositionFix
from ..signals import InputRejected, RawBlock
from ..track import Track, TrackError, extent
from .base import Decoder, ErrorModel, Param, SensorSpec, Simulator

SENSOR = "dgps"
STRUCTURE_KIND = "structure"
NO_FIX_HDOP = 99.9      # NMEA: the HDOP field of an epoch without a fix
QUALITIES = (0, 1, 2)   # NMEA GGA fix quality: no fix, autonomous, differential
RESOLUTION = 0.001      # output resolution of the solution [m]: the least 1-sigma of a fix

PARAMS = {
    "antenna_offset": Param(5.0, "GNSS antenna distance behind the train front [m] (assumption: on the roof "
                                 "above the leading bogie); within a train of up to 1 km", (0.0, 1000.0)),
    "white_sigma": Param(0.4, "1-sigma white error of a differential fix per horizontal axis at the nominal "
                              "HDOP [m] (assumption: code DGPS, about 1 m 2DRMS; seed 002 section 2.1.2 "
                              "gives no accuracy)", (0.0, 100.0)),
    "hdop_nominal": Param(1.0, "HDOP with the open sky of an elevated guideway [1] (assumption)", (0.5, 20.0)),
    "satellites_nominal": Param(9, "satellites in use with the open sky [1] (assumption)", (4, 64)),
    "multipath_sigma": Param(0.3, "1-sigma multipath and residual differential error per axis in the open "
                                  "[m] (assumption)", (0.0, 100.0)),
    "multipath_length": Param(50.0, "correlation length of that error along the track [m] (assumption: the "
                                    "reflectors around the antenna change)", (0.1, 1.0e6)),
    "multipath_tau": Param(60.0, "correlation time of that error [s] (assumption: satellite geometry)",
                           (0.1, 1.0e6)),
    "multipath_bound": Param(3.0, "bound of the multipath error per axis in units of its local 1-sigma [1] "
                                  "(the code multipath error envelope of the correlator; assumption)",
                             (0.5, 10.0)),
    "structure_reach": Param(30.0, "distance from a structure within which the antenna sees it mask part of "
                                   "the sky and reflect [m] (assumption)", (0.0, 1000.0)),
    "structure_multipath_factor": Param(3.0, "multipath 1-sigma within structure_reach of a structure, in "
                                             "units of multipath_sigma [1] (assumption)", (1.0, 20.0)),
    "structure_hdop_factor": Param(2.0, "HDOP within structure_reach of a structure, in units of the nominal "
                                        "[1] (assumption: half the sky masked)", (1.0, 20.0)),
    "structure_satellites_lost": Param(3, "satellites lost within structure_reach of a structure [1] "
                                          "(assumption)", (0, 60)),
    "reacquisition_time": Param(3.0, "time from the sky coming back to the next differential fix [s] "
                                     "(assumption: reacquisition of the satellites and corrections)",
                                (0.0, 600.0)),
    "autonomous_sigma": Param(2.0, "1-sigma extra error per axis of an autonomous fix (no corrections) [m] "
                                   "(assumption)", (0.0, 100.0)),
    "faults": Param("", "injected faults 'T0-T1:nocorr' (correction link lost: autonomous fixes) separated "
                        "by ';' (tests)"),
    "max_hdop": Param(4.0, "decoder: largest HDOP of a fix used [1]", (0.5, 99.0)),
    "min_satellites": Param(5, "decoder: fewest satellites of a fix used [1]", (4, 64)),
    "lateral_gate": Param(4.0, "decoder: largest distance of a fix from the alignment in units of its "
                               "1-sigma [1]; beyond it the fix is withheld (off_track)", (1.0, 100.0)),
}


def structures(track: Track | None) -> np.ndarray:
    """(start, end) [m] of the track's structures, shape (n, 2), sorted; TrackError for one
    that ends before it starts."""
    rows = []
    for item in (track.items(STRUCTURE_KIND) if track is not None else []):
        start, end = extent(STRUCTURE_KIND, item)
        if not end >= start:
            raise TrackError(f"structure '{item['id']}' ends at {end} m before its start {start} m")
        rows.append((start, end))
    return np.array(sorted(rows), dtype=float).reshape(-1, 2)


def sky_zone(spans: np.ndarray, chainage: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """(under a structure, within ``reach`` of one but not under) for antenna chainages [m]."""
    s = np.asarray(chainage, dtype=float)[:, None]
    if spans.size == 0:
        zero = np.zeros(s.shape[0], dtype=bool)
        return zero, zero.copy()
    under = ((s >= spans[:, 0]) & (s <= spans[:, 1])).any(axis=1)
    near = ((s >= spans[:, 0] - reach) & (s <= spans[:, 1] + reach)).any(axis=1) & ~under
    return under, near


def fix_sigma(params: dict, hdop: float, near: bool) -> float:
    """1-sigma [m] of a differential fix at ``hdop`` [1], ``near`` a structure or in the open:
    hypot(white_sigma x HDOP / hdop_nominal, the multipath 1-sigma there), at least the 1 mm
    output resolution of the solution (the simulator's ``adc_lsb``). The decoder's stddev;
    its lowest (HDOP -> 0, in the open) is the error model's floor."""
    mp = params["multipath_sigma"] * (params["structure_multipath_factor"] if near else 1.0)
    return max(math.hypot(params["white_sigma"] * hdop / params["hdop_nominal"], mp), RESOLUTION)


def parse_faults(text: str) -> list[tuple[float, float]]:
    """'T0-T1:nocorr' items -> [(t0, t1)]."""
    out = []
    for item in filter(None, (s.strip() for s in str(text or "").split(";"))):
        try:
            window, kind = item.rsplit(":", 1)
            if kind != "nocorr":
                raise ValueError(kind)
            t0, t1 = (float(v) for v in window.split("-", 1))
            out.append((t0, t1))
        except ValueError:
            raise ValueError(f"malformed dgps fault {item!r}; expected 'T0-T1:nocorr'") from None
    return out


class DgpsSimulator(Simulator):
    """The receiver's navigation solution for the antenna on the train."""

    sensor = SENSOR
    channels = ("x", "y", "quality", "satellites", "hdop")
    units = ("m", "m", "1", "1", "1")
    default_sample_rate = 10.0
    adc_lsb = {"m": RESOLUTION}   # the solution's output resolution

    def __init__(self, *args):
        super().__init__(*args)
        self._spans = structures(self.track)
        self._faults = parse_faults(self.params["faults"])
        self._g = self.rng.normal(0.0, 1.0, 2)      # unit Gauss-Markov multipath per axis
        self._prev: tuple[float, float] | None = None   # (time, antenna chainage) of the last epoch
        self._sky_since: float | None = -math.inf    # when the sky came back (None: under a structure)

    def multipath_sigma(self, near: np.ndarray) -> np.ndarray:
        p = self.params
        return p["multipath_sigma"] * np.where(near, p["structure_multipath_factor"], 1.0)

    def samples(self, times, position, speed, acceleration):
        p = self.params
        n = len(times)
        ant = position - p["antenna_offset"]
        under, near = sky_zone(self._spans, ant, p["structure_reach"])
        sig_mp = self.multipath_sigma(near)
        out = np.zeros((n, 5))
        px, py = self.track.xy(ant)
        for i in range(n):
            t, s = float(times[i]), float(ant[i])
            if self._prev is not None:
                dt, ds = t - self._prev[0], abs(s - self._prev[1])
                phi = math.exp(-ds / p["multipath_length"] - dt / p["multipath_tau"])
                self._g = phi * self._g + math.sqrt(max(1.0 - phi * phi, 0.0)) * self.rng.normal(0.0, 1.0, 2)
            self._prev = (t, s)
            bias = np.clip(self._g, -p["multipath_bound"], p["multipath_bound"]) * sig_mp[i]
            if under[i]:
                self._sky_since = None
                out[i] = (0.0, 0.0, 0, int(self.rng.integers(0, 4)), NO_FIX_HDOP)
                continue
            if self._sky_since is None:
                self._sky_since = t
            if t - self._sky_since < p["reacquisition_time"]:
                out[i] = (0.0, 0.0, 0, int(self.rng.integers(0, 4)), NO_FIX_HDOP)
                continue
            hdop = p["hdop_nominal"] * (p["structure_hdop_factor"] if near[i] else 1.0)
            sats = p["satellites_nominal"] - (p["structure_satellites_lost"] if near[i] else 0)
            if sats < 4:
                out[i] = (0.0, 0.0, 0, max(sats, 0), NO_FIX_HDOP)
                continue
            err = bias + self.rng.normal(0.0, p["white_sigma"] * hdop / p["hdop_nominal"], 2)
            quality = 2
            if any(t0 <= t < t1 for t0, t1 in self._faults):
                quality = 1
                err = err + self.rng.normal(0.0, p["autonomous_sigma"], 2)
            out[i] = (px[i] + err[0], py[i] + err[1], quality, sats, hdop)
        return out


class DgpsDecoder(Decoder):
    sensor = SENSOR
    channels = DgpsSimulator.channels

    def __init__(self, params, track):
        super().__init__(params, track)
        p = self.params
        self._spans = structures(track)
        track.segments_table()      # the alignment's segments for the projection, built once
        # a fix near a structure may lie this far along the track from the antenna (its multipath
        # bound and 4 sigma of its noise there): the decoder's zone is that much wider, so that it
        # never takes such a fix for one in the open
        self._reach = p["structure_reach"] + (p["multipath_bound"] * p["structure_multipath_factor"]
                                              * p["multipath_sigma"]
                                              + 4.0 * p["white_sigma"] * p["structure_hdop_factor"])
        # a train on a network (its route line carries the network): a fix is projected onto the
        # whole network, not onto the route, and keeps its lateral offset (docs/network.md)
        self._network = getattr(track, "network", None)
        if self._network is not None:
            self._section_spans = {sid: structures(sec) for sid, sec in self._network.sections.items()}
        self._had_fix = True
        self.stats = {key: 0 for key in ("epochs", "fixes", "no_fix", "outages", "autonomous", "weak_geometry",
                                         "off_track", "ambiguous", "under_structure")}

    def _check(self, block: RawBlock) -> np.ndarray:
        if block.channels != self.channels:
            raise InputRejected("channels", f"DGPS channels {block.channels}, expected {self.channels}")
        data = block.data.astype(float)
        q, sats, hdop = data[:, 2], data[:, 3], data[:, 4]
        if not np.all(np.isin(q, QUALITIES)):
            raise InputRejected("implausible", "fix quality other than 0 (none), 1 (autonomous), 2 (DGPS)")
        if np.any((sats < 0) | (sats > 64) | (sats != np.round(sats))):
            raise InputRejected("implausible", "satellite count that is no count of 0..64")
        if np.any(~(hdop > 0.0) | (hdop > NO_FIX_HDOP + 1e-3)):
            raise InputRejected("implausible", f"HDOP outside 0 .. {NO_FIX_HDOP}")
        return data

    def decode(self, block: RawBlock):
        p = self.params
        data = self._check(block)   # raises before any state changes
        t = block.t0 + self.sample_offsets(block.n_samples, block.sample_rate)
        out: list[PositionFix] = []
        for i in range(block.n_samples):
            x, y, q, sats, hdop = data[i]
            self.stats["epochs"] += 1
            if q == 0:
                self.stats["no_fix"] += 1
                if self._had_fix:
                    self.stats["outages"] += 1
                self._had_fix = False
                continue
            self._had_fix = True
            if q == 1:
                self.stats["autonomous"] += 1
                continue
            if hdop > p["max_hdop"] or sats < p["min_satellites"]:
                self.stats["weak_geometry"] += 1
                continue
            fix = self.locate(float(t[i]), float(x), float(y), lambda near, h=float(hdop): fix_sigma(p, h, near))
            if fix is not None:
                out.append(fix)
        return out

    def locate(self, t: float, x: float, y: float, sigma_at: Callable[[bool], float]) -> PositionFix | None:
        """The fix of one differential epoch at ``t`` [s]: the antenna at map point (x, y) [m]
        projected onto the track (or the network), 1-sigma ``sigma_at(near)`` [m] where the antenna
        is (``near`` a structure or in the open); None when it is withheld (counted in ``stats``,
        module docstring). The same map matching serves this decoder's blocks and a receiver's
        standard messages (core/ingest/navsat.py)."""
        p = self.params
        if self._network is not None:
            return self._network_fix(t, x, y, sigma_at)
        chain, lateral = self.track.project(x, y)
        s = float(chain[0])
        under, near = sky_zone(self._spans, np.array([s]), self._reach)
        sigma = sigma_at(bool(near[0]))
        gate = p["lateral_gate"] * sigma
        if s <= 0.0 or s >= self.track.length or not abs(float(lateral[0])) <= gate:
            self.stats["off_track"] += 1
            return None
        if self.track.distance_elsewhere(x, y, s, 2.0 * gate) <= gate:
            # another part of the alignment passes within the gate too (a flyover, a hairpin):
            # a 2-D fix cannot tell which, and the nearest may be the wrong one by kilometres
            self.stats["ambiguous"] += 1
            return None
        if under[0]:
            self.stats["under_structure"] += 1
            return None
        self.stats["fixes"] += 1
        return PositionFix(t, self.sensor, self.unit_id, self.track.track_id, self.unit_id,
                           s + p["antenna_offset"], sigma, 0)

    def _network_fix(self, t: float, x: float, y: float, sigma_at: Callable[[bool], float]) -> PositionFix | None:
        """The fix of an epoch on a network: the antenna's point on the nearest section, with its
        lateral offset from it (a map fix: the track-selective fusion projects it onto each
        hypothesis's path and adds the antenna offset along it). Withheld as on a line: further
        than ``lateral_gate`` sigma from every section, or under a structure."""
        p = self.params
        section, s, lateral = self._network.project(x, y)
        under, near = sky_zone(self._section_spans[section], np.array([s]), self._reach)
        sigma = sigma_at(bool(near[0]))
        if not abs(lateral) <= p["lateral_gate"] * sigma:
            self.stats["off_track"] += 1
            return None
        if under[0]:
            self.stats["under_structure"] += 1
            return None
        self.stats["fixes"] += 1
        return PositionFix(t, self.sensor, self.unit_id, section, self.unit_id, s, sigma, 0, (), lateral, sigma)


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """DGPS fixes for the fusion: the multipath and residual differential error is one fix
    bias, Gauss-Markov in the distance run (``multipath_length``) and in time
    (``multipath_tau``) with its open-sky 1-sigma (its along-track part: the error is the
    same on either axis); the decoder reports it in its stddev. Near a structure the decoder
    reports a larger multipath: the white part of a fix is at most the receiver noise at the
    HDOP next to a structure, and what it reports beyond it persists like the bias (the
    fusion does not average it over the 10 Hz epochs). Fault modes: a multipath (NLOS)
    fix that passed the decoder's checks, and the outages under structures (no timeout:
    a tunnel is a normal silence). Floor: the decoder's ``fix_sigma`` at HDOP -> 0 in the
    open (it accepts any HDOP > 0): the open-sky multipath 1-sigma, at least the 1 mm
    resolution. No references: a fix names the receiver (its unit id), no equipment."""
    mp = float(params["multipath_sigma"])
    return ErrorModel(SENSOR, "position", fix_bias_sigma=mp, fix_bias_length=float(params["multipath_length"]),
                      fix_bias_tau=float(params["multipath_tau"]), reported_fix_bias=mp,
                      fix_white_sigma=max(params["white_sigma"] * params["structure_hdop_factor"], 1e-3),
                      faults=("nlos", "outage"), min_stddev=fix_sigma(params, 0.0, False),
                      sensor_offset=float(params["antenna_offset"]))


SPEC = SensorSpec(
    node="dgps_receiver", sensor=SENSOR, simulator=DgpsSimulator, decoder=DgpsDecoder, params=PARAMS,
    description="on-board DGPS receiver (UTM-02): 2-D differential fix projected onto the track alignment",
    seeds=("002",), outputs=("position",), error_model=error_model,
)

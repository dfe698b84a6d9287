"""LZB cable loop receiver (German ICE continuous train control), seed 000.

Physics (seed 000 section 3.1 "독일 ICE", Fig. 11-12): Germany requires the cab-signalling
system LZB (Linienzugbeeinflussung) for trains above 160 km/h. A pair of conductors laid
in the track forms an inductive loop (in LZB practice one in the track centre, one at the
rail foot: not in the seed); the conductors cross every 100 m and a loop is up to 12.7 km
long (Fig. 12). Each loop is
connected to feeder cases, one feeder case serving 300 m on either side. The on-board
antenna detects the drop of the received level at every crossing, so the train counts
100 m steps, and it recognises the number uniquely assigned to each loop when it runs onto
it: loop number + crossing count = absolute position. Over the same loop the train sends
its data (train length, braking, top speed) and its position to the wayside, which
returns target speed and distance (Fig. 11).

Field model (Biot-Savart; the same law as seed 003 eq. 1-4): the antenna, ``antenna_height``
= r above the near conductor, sees the field of the conductor segment under it. A straight
segment from a to b gives at along-track position x

    B(x) = B_inf / 2 * (f(x - a) - f(x - b)),   f(u) = u / sqrt(u^2 + r^2),

so between crossings the level is the full level, and at a crossing, where the pair swaps
sides and the current under the antenna reverses, the received carrier is

    z(u) = -c f(u)        (u: distance past the crossing, c: complex carrier of the cell before)

its level |z| falls to 0 within +-r and its phase reverses by 180 deg (the seed's level
drop; the phase reversal is the same sign change, the seed does not describe it). The
far conductor and the lateral jumper of the crossing are folded into r and a small
quadrature field at the crossing (``crossing_leakage``): the level drops to a few per cent,
not to 0. Everything of a loop and its neighbours adds up (z = sum of the segments).

Loops and feeders (track equipment kind ``lzb_loop``)::

    lzb_loop:
      - {id: L01, number: 1, position: 0.0, end: 600.0}                 # position = loop start
      - {id: L02, number: 2, start: 600.0, length: 1200.0, spacing: 100.0,
         feeders: [900.0, 1500.0]}                                      # feeder case chainages [m]
      - {every: 12700.0, start: 1800.0, end: 14500.0, id: "M{n}", length: 12700.0}   # M0, M1

``position`` (or ``start``) is the loop start [m], ``end`` [m] or ``length`` [m] its end (at
most 12.7 km, seed 000 section 3.1), ``number`` the loop number in the telegrams (default:
1-based order along the track; unique, 1..65535), ``spacing`` [m] the crossing spacing
(default parameter ``spacing``, 100 m), ``feeders`` the feeder-case chainages (default:
every 2 x ``feeder_reach`` from start + ``feeder_reach``, the last one at most at the
end). Every point of a loop must lie within ``feeder_reach`` (300 m) of a feeder case; a
cable section is fed by its nearest feeder case. Crossings lie at start + k x spacing; the
last cell may be shorter. Loops must not overlap; where one ends and the next begins
(end == start) the pair also crosses at the joint (assumption: the crossing pattern
continues across a joint, the loops being fed coherently from one LZB centre), so the
joint is one more crossing, the first of the loop entered. Feeder cases are named
``<loop id>/F<k>`` (k from 0 along the loop) for the fault injection.

Simulation (raw signal, default 2 kHz: the null at a crossing is 1.15 r = 0.35 m wide,
8 samples at 300 km/h): channels ``level`` [V] (envelope of the received carrier),
``phase`` [rad] (carrier phase against the receiver's reference, wrapped to +-pi), and
``loop`` [1]: the loop number of a wayside telegram at the sample where it was received
completely, 0 elsewhere. Modelled: every crossing's real chainage differs from the grid by
``crossing_sigma`` (installation) plus the loop's common ``survey_sigma``; per-loop gain
``level_sigma``; cable attenuation away from the feeder case; the feeder cases' carrier
phase ``feeder_phase_sigma``; complex white receiver noise; the receiver's reference
offset from the carrier (the phase drifts by 360 x offset deg/s); telegrams of
``telegram_period`` s decoded when the level stays above ``telegram_level`` on one loop
(and failing their CRC with ``telegram_error_rate``). Faults: a crossing whose null the
receiver misses (``miss_probability`` per crossing, no carrier over ``blank_length`` m
around it: interference, a damaged crossing), zones without carrier
(``faults`` 'X0-X1:blank': a cable interruption) and feeder cases switched off
('FEEDER@T0-T1:off': its cable sections fall silent).

Decoder (the same for simulated, recorded and ingested blocks): samples below
``strong_fraction`` x ``amplitude`` form a null. When the level comes back the null is
judged by the phase step across it (against the carrier drift bound
``max_carrier_offset``) and by its lost samples (below ``detect_level``: no carrier):
  * observed throughout, phase reversed: one crossing passed, moving on in the same
    direction. Its time is the zero of a straight line fitted to the level projected on
    the phase before the null (it runs from +L to -L through the crossing); the slope
    gives the speed (|slope| = L v / r, times the line-fit factor of f). 1-sigma of the
    fix: the zero's regression error x speed, the crossing's installation tolerance and
    the loop's survey error. A null too poorly fitted is counted but not timed;
  * observed throughout, phase unchanged: the train turned back inside the null (or the
    level dipped); where the train cannot have stopped since the last timed crossing it
    is a dip and ignored, else the count is lost;
  * with lost samples (a dropout, a gap between blocks): crossings may have been missed.
    If the train cannot have stopped and cannot have covered a cell during the dropout
    (speed bounds from the last timed crossing, ``speed_tolerance``, ``max_acceleration``)
    the phase tells whether it passed one crossing or none: the count goes on, the
    crossing's fix is withheld (``stats["withheld_doubtful"]``); otherwise the count is
    lost (``stats["lost_dropout"]``).
Between two crossings the train may also have stopped and come back over the same
crossing, which looks like the next one: if the speeds at both crossings allow a stop in
between, the count is lost (``stats["lost_stop"]``), so the count only survives above
about 40 km/h (LZB serves trains above 160 km/h). The count is (re)gained at a joint: the
loop number of the telegrams changes from a loop to its neighbour within
``max_telegram_delay`` of a clean crossing, which was the joint; the order of the two
loops gives the direction. Fixes are published only while counting: the train front =
crossing chainage + ``antenna_offset`` at the crossing time, reference id = the loop the
antenna is on (its survey error is one fix bias per loop). A telegram whose loop
disagrees with the count loses it (``stats["lost_telegram"]``); crossings seen without a
count are withheld (``stats["withheld_uncounted"]``). Implausible blocks (level beyond
``adc_range`` or negative, phase beyond +-pi, a loop number that is no integer) are
rejected as "implausible", a loop number not in the track as "unknown_id".

Not modelled: the train-to-wayside direction of the loop (the train reporting its
position, train data; seed 000 Fig. 11) and the wayside LZB centre's target speed and
distance -- this stack localises on board; the FSK modulation of the telegrams (only
their timing and success); the subdivision of the 100 m cells by odometry (the fusion does
that with the wheel and radar); track-circuit/turnout interruptions of the cable other
than as 'blank' zones.
"""
from __future__ import annotations

import math

import numpy as np

from ..measurements import PositionFix
from ..signals import InputRejected, RawBlock
from ..track import Track, TrackError, extent
from .base import Decoder, ErrorModel, Param, ReferenceTable, ReferenceWindow, SensorSpec, Simulator

KIND = "lzb_loop"
SENSOR = "lzb"
MAX_LOOP_LENGTH = 12700.0     # [m] seed 000 section 3.1: a loop reaches up to 12.7 km
NUMBER_MAX = 65535            # loop numbers (exact in float32)
TWO_PI = 2.0 * math.pi

PARAMS = {
    "spacing": Param(100.0, "crossing spacing of the loops without 'spacing' [m] (seed 000 section 3.1, Fig. 12: "
                            "the conductors cross every 100 m)", (1.0, 1000.0)),
    "feeder_reach": Param(300.0, "loop length a feeder case serves on either side [m] (seed 000 section 3.1: "
                                 "300 m each side); default feeder cases every 2 x reach", (10.0, 6350.0)),
    "antenna_offset": Param(2.5, "receiving antenna distance behind the train front [m] (assumption: under the "
                                 "leading bogie); within a train of up to 1 km", (0.0, 1000.0)),
    "antenna_height": Param(0.3, "distance r of the antenna from the near loop conductor [m]: the null at a "
                                 "crossing is 1.15 r wide (assumption: antenna ~0.15 m above rail top, "
                                 "conductor on the sleeper)", (0.02, 2.0)),
    "amplitude": Param(1.0, "received level at full coupling with the nominal loop current [V]", (1.0e-3, 10.0)),
    "crossing_sigma": Param(0.1, "1-sigma installation error of a crossing's chainage [m] (assumption: cable "
                                 "clipped to sleepers 0.6 m apart, +-0.3 m taken as 3 sigma)", (0.0, 10.0)),
    "survey_sigma": Param(0.05, "1-sigma error of a loop's chainage reference, common to its crossings [m] "
                                "(survey; assumption)", (0.0, 10.0)),
    "noise": Param(0.01, "1-sigma white noise of each quadrature component of the received carrier [V] "
                         "(40 dB SNR at full level; assumption)", (0.0, 1.0)),
    "level_sigma": Param(0.1, "1-sigma gain of a loop (its current, antenna coupling) [1] (fraction; "
                              "assumption)", (0.0, 0.5)),
    "attenuation": Param(3.0, "attenuation of the loop cable away from its feeder case [dB/km] (assumption; "
                              "below 1 dB over the 300 m reach of seed 000 section 3.1)", (0.0, 100.0)),
    "feeder_phase_sigma": Param(5.0, "1-sigma carrier phase of a feeder case against its loop [deg] (feeder "
                                     "cases driven from one LZB centre; assumption)", (0.0, 90.0)),
    "crossing_leakage": Param(0.05, "quadrature field of a crossing's jumper, fraction of the full level [1]: "
                                    "the level drops to it, not to 0", (0.0, 0.5)),
    "carrier_offset_sigma": Param(0.02, "1-sigma offset of the receiver's phase reference from the carrier "
                                        "[Hz] (0.5 ppm of a 36 kHz carrier; assumption): the phase drifts by "
                                        "360 x offset deg/s", (0.0, 10.0)),
    "telegram_period": Param(0.07, "duration of one wayside telegram carrying the loop number [s] (LZB "
                                   "practice, about 83 bit at 1200 bit/s; assumption, not in seed 000)",
                             (0.005, 2.0)),
    "telegram_level": Param(0.2, "level [V] above which the telegram is received; a telegram counts if at "
                                 "least 90 % of it is above it on one loop", (0.0, 10.0)),
    "telegram_error_rate": Param(0.01, "probability that a telegram received at a good level fails its CRC [1] "
                                       "(assumption)", (0.0, 1.0)),
    "miss_probability": Param(0.0, "probability that the receiver gets no carrier around a crossing [1] "
                                   "(interference, a damaged crossing: drawn once per crossing)", (0.0, 1.0)),
    "blank_length": Param(5.0, "length of track around such a crossing without carrier [m]", (0.1, 100.0)),
    "faults": Param("", "injected faults separated by ';' (tests): 'X0-X1:blank' (no carrier with the antenna "
                        "between chainages X0 and X1 [m]), 'FEEDER@T0-T1:off' (feeder case FEEDER = "
                        "'<loop id>/F<k>' off from T0 to T1 [s])"),
    "adc_range": Param(2.0, "receiver level output range [V]; a level at or beyond it is implausible",
                       (0.1, 100.0)),
    "strong_fraction": Param(0.5, "decoder: a sample below this fraction of 'amplitude' is in a null or a "
                                  "dropout [1]", (0.05, 0.95)),
    "detect_level": Param(0.03, "decoder: level below which no carrier is received (a lost sample) [V]",
                          (0.0, 10.0)),
    "max_lost_fraction": Param(0.3, "decoder: a null with more lost samples than this fraction is a dropout, not "
                                    "an observed crossing [1]", (0.0, 1.0)),
    "phase_tolerance": Param(45.0, "decoder: largest deviation of the phase step across a null from 180 deg "
                                   "(crossing) or 0 deg (none) [deg], on top of the carrier drift bound (feeder "
                                   "phases, the crossing's quadrature field at the edges of the null)",
                             (1.0, 89.0)),
    "max_carrier_offset": Param(0.1, "decoder: bound of the receiver's carrier offset [Hz]: across a null of T s "
                                     "the phase may drift 360 x offset x T deg", (0.0, 10.0)),
    "max_acceleration": Param(2.0, "decoder: largest |acceleration| of the train [m/s^2] (assumption: above "
                                   "emergency braking, ~1.2-1.5 m/s^2): bounds where it can be after a "
                                   "crossing", (0.1, 10.0)),
    "speed_tolerance": Param(0.25, "decoder: relative error bound of the speed measured from a null's slope [1] "
                                   "(antenna height, fit)", (0.0, 0.9)),
    "min_fit_samples": Param(3, "decoder: fewest samples in a null that time its crossing [1]", (2, 100000)),
    "max_residual": Param(0.15, "decoder: largest RMS misfit of the line through a null, fraction of the full "
                                "level [1]; beyond it the crossing is counted but not timed", (0.0, 1.0)),
    "max_telegram_delay": Param(0.3, "decoder: longest time from a crossing to the first telegram of the next "
                                     "loop for that crossing to be the joint [s] (two telegrams and margin)",
                                (0.0, 10.0)),
}


# ----------------------------------------------------------------------------------
# Loops of a track
# ----------------------------------------------------------------------------------

def loop_table(track: Track | None, params: dict) -> list[dict]:
    """The lzb_loop entries of a track, sorted along it, as dicts: id, number, start, end,
    spacing, crossings (chainages: start, start + k spacing, end), feeders (chainages),
    feeder_ids, below / above (index of the loop joined at the start / end, or -1).
    TrackError for a loop that cannot be laid (too long, overlapping, not fed, ...)."""
    if track is None:
        return []
    reach = float(params["feeder_reach"])
    out: list[dict] = []
    numbers: set[int] = set()
    for i, item in enumerate(track.items(KIND)):
        lid = str(item["id"])
        start, end = extent(KIND, item)
        spacing = float(item.get("spacing", params["spacing"]))
        number = item.get("number", i + 1)
        if not (end > start and spacing > 0.0):
            raise TrackError(f"{KIND} '{lid}': need end > start and spacing > 0")
        if end - start > MAX_LOOP_LENGTH + 1e-6:
            raise TrackError(f"{KIND} '{lid}' is {end - start:g} m long; a loop reaches at most "
                             f"{MAX_LOOP_LENGTH:g} m (seed 000 section 3.1)")
        if start < -1e-9 or end > track.length + 1e-9:
            raise TrackError(f"{KIND} '{lid}' ({start:g}..{end:g} m) is off the track (0..{track.length:g} m)")
        if isinstance(number, bool) or not float(number).is_integer() or not 1 <= int(number) <= NUMBER_MAX \
                or int(number) in numbers:
            raise TrackError(f"{KIND} '{lid}': number {number!r} is not a new integer 1..{NUMBER_MAX}")
        number = int(number)
        if out and start < out[-1]["end"] - 1e-6:
            raise TrackError(f"{KIND} '{lid}' overlaps '{out[-1]['id']}'")
        if "feeders" in item:
            feeders = np.sort(np.asarray([float(f) for f in item["feeders"] or []], dtype=float))
        else:
            k = np.arange(int(math.ceil((end - start) / (2.0 * reach) - 1e-9)))
            feeders = np.minimum(start + reach * (2.0 * k + 1.0), end)
        if feeders.size == 0 or feeders[0] < start - 1e-6 or feeders[-1] > end + 1e-6:
            raise TrackError(f"{KIND} '{lid}': feeder cases must lie on the loop ({start:g}..{end:g} m)")
        reach_gaps = np.r_[feeders[0] - start, np.diff(feeders) / 2.0, end - feeders[-1]]
        if np.any(reach_gaps > reach + 1e-6):
            raise TrackError(f"{KIND} '{lid}': a part of the loop is more than {reach:g} m from every feeder case "
                             "(seed 000 section 3.1: one serves 300 m on either side)")
        n_in = int(math.ceil((end - start) / spacing - 1e-9))
        crossings = np.r_[start + spacing * np.arange(n_in), end]
        numbers.add(number)
        out.append({"id": lid, "number": number, "start": start, "end": end, "spacing": spacing,
                    "crossings": crossings, "feeders": feeders,
                    "feeder_ids": [f"{lid}/F{k}" for k in range(feeders.size)], "below": -1, "above": -1})
    for k in range(1, len(out)):
        if abs(out[k]["start"] - out[k - 1]["end"]) <= 1e-6:
            out[k]["below"], out[k - 1]["above"] = k - 1, k
    return out


def parse_faults(text: str, loops: list[dict]) -> tuple[list[tuple[float, float]], list[tuple[str, float, float]]]:
    """('X0-X1:blank' zones [(x0, x1)], 'FEEDER@T0-T1:off' outages [(feeder id, t0, t1)])."""
    blanks, outages = [], []
    known = {f for row in loops for f in row["feeder_ids"]}
    for entry in (e.strip() for e in (text or "").split(";")):
        if not entry:
            continue
        try:
            where, kind = entry.rsplit(":", 1)
            if kind == "blank":
                x0, x1 = (float(v) for v in where.split("-", 1))
                blanks.append((min(x0, x1), max(x0, x1)))
            elif kind == "off":
                feeder, span = where.split("@", 1)
                t0, t1 = (float(v) for v in span.split("-", 1))
                if feeder not in known:
                    raise ValueError(f"unknown feeder case {feeder!r}")
                outages.append((feeder, t0, t1))
            else:
                raise ValueError(f"unknown fault kind {kind!r}")
        except (ValueError, TypeError) as exc:
            raise ValueError(f"lzb fault {entry!r}: expected 'X0-X1:blank' or 'FEEDER@T0-T1:off' ({exc})") from None
    return blanks, outages


def _f(u, r: float):
    """Field shape of a segment end: u / sqrt(u^2 + r^2) (Biot-Savart, straight conductor)."""
    return u / np.sqrt(u * u + r * r)


def slope_factor(s: float) -> float:
    """Least-squares slope of f(u) r over the null |f| < s, relative to f'(0) r = 1: the
    level projected on the carrier runs through a null as -L f(u); its fitted slope is
    L v / r times this (0.915 for s = 0.5)."""
    s = min(max(s, 1e-3), 0.999)
    a = s / math.sqrt(1.0 - s * s)
    return (a * math.sqrt(a * a + 1.0) - math.asinh(a)) * 3.0 / (2.0 * a ** 3)


# ----------------------------------------------------------------------------------
# Simulator
# ----------------------------------------------------------------------------------

class LzbSimulator(Simulator):
    """The on-board LZB receiver over the loops of a track."""

    sensor = SENSOR
    channels = ("level", "phase", "loop")
    units = ("V", "rad", "1")
    default_sample_rate = 2000.0   # the 0.35 m null at a crossing: 8 samples at 300 km/h
    adc_lsb = {"V": 2.0 / 4096, "rad": TWO_PI / 4096}  # 12-bit level (2 V range) and phase; the loop number exact

    def __init__(self, *args):
        super().__init__(*args)
        p, rng = self.params, self.rng
        self.loops = loop_table(self.track, p)
        self.blanks, outages = parse_faults(p["faults"], self.loops)
        nl = len(self.loops)
        # per loop: survey offset, gain, chain phase (joined loops are fed coherently)
        survey = rng.normal(0.0, p["survey_sigma"], nl)
        gain = np.maximum(0.05, 1.0 + rng.normal(0.0, p["level_sigma"], nl))
        chain_phase = rng.uniform(0.0, TWO_PI, nl)
        for k, row in enumerate(self.loops):
            if row["below"] >= 0:
                chain_phase[k] = chain_phase[row["below"]]
        # breakpoints: crossings (joints once), loop edges, feeder section boundaries off the crossings
        nominal, is_cross, shift = [], [], []
        feeder_global, feeder_phase, feeder_pos, feeder_loop = {}, [], [], []
        for k, row in enumerate(self.loops):
            for j, fid in enumerate(row["feeder_ids"]):
                feeder_global[fid] = len(feeder_phase)
                feeder_phase.append(math.radians(p["feeder_phase_sigma"]) * rng.normal())
                feeder_pos.append(row["feeders"][j])
                feeder_loop.append(k)
            cr = row["crossings"]
            first = 1 if row["below"] >= 0 else 0
            for j in range(first, cr.size):
                edge = (j == 0 and row["below"] < 0) or (j == cr.size - 1 and row["above"] < 0)
                nominal.append(cr[j])
                is_cross.append(not edge)
                shift.append(0.5 * (survey[k] + survey[row["above"]]) if j == cr.size - 1 and row["above"] >= 0
                             else survey[k])
            f = row["feeders"]
            for b in 0.5 * (f[1:] + f[:-1]):
                if np.min(np.abs(cr - b)) > 1e-6:
                    nominal.append(b)
                    is_cross.append(False)
                    shift.append(survey[k])
        nominal = np.asarray(nominal, dtype=float)
        order = np.argsort(nominal, kind="stable")
        nominal = nominal[order]
        self._is_cross = np.asarray(is_cross, dtype=bool)[order]
        tol = rng.normal(0.0, p["crossing_sigma"], nominal.size)
        true = nominal + np.asarray(shift, dtype=float)[order] + np.where(self._is_cross, tol, 0.0)
        self._B = np.maximum.accumulate(true) if true.size else true
        self._leak_sign = np.where(rng.random(nominal.size) < 0.5, -1.0, 1.0)
        # segment s lies between breakpoints s-1 and s (0 and S: outside everything)
        n_seg = nominal.size + 1
        self._c = np.zeros(n_seg, dtype=complex)
        self._feeder_of_seg = np.full(n_seg, -1, dtype=np.int64)
        starts = np.array([row["start"] for row in self.loops])
        ends = np.array([row["end"] for row in self.loops])
        sign = 1.0
        fpos, fph = np.asarray(feeder_pos, dtype=float), np.asarray(feeder_phase, dtype=float)
        floop = np.asarray(feeder_loop, dtype=np.int64)
        for s in range(1, n_seg - 1):
            if self._is_cross[s - 1]:
                sign = -sign
            mid = 0.5 * (nominal[s - 1] + nominal[s])
            k = int(np.searchsorted(starts, mid, side="right")) - 1
            if k < 0 or mid >= ends[k]:
                continue
            mine = np.flatnonzero(floop == k)
            fi = int(mine[np.argmin(np.abs(fpos[mine] - mid))])
            att = 10.0 ** (-p["attenuation"] * abs(mid - fpos[fi]) / 20000.0)
            self._c[s] = sign * p["amplitude"] * gain[k] * att * np.exp(1j * (chain_phase[k] + fph[fi]))
            self._feeder_of_seg[s] = fi
        self._outages = [(feeder_global[f], t0, t1) for f, t0, t1 in outages]
        # crossings whose null the receiver misses: no carrier around them
        miss = rng.random(nominal.size) < p["miss_probability"]
        half = 0.5 * p["blank_length"]
        self.blanks += [(float(b) - half, float(b) + half) for b in self._B[miss & self._is_cross]]
        self._blank = np.array(sorted(self.blanks), dtype=float).reshape(-1, 2)
        self._loop_start, self._loop_end = starts, ends
        self._numbers = np.array([row["number"] for row in self.loops], dtype=float)
        self._freq_offset = rng.normal(0.0, p["carrier_offset_sigma"])
        self._tel_offset = rng.uniform(0.0, p["telegram_period"])
        self._tel: list | None = None   # telegram in progress: [index, samples, samples ok, loop, mixed]

    def _amp(self, seg: np.ndarray, times: np.ndarray) -> np.ndarray:
        """Carrier of segments ``seg`` at ``times`` (0 while their feeder case is off)."""
        c = self._c[seg]
        if self._outages:
            fo = self._feeder_of_seg[seg]
            off = np.zeros(seg.shape, dtype=bool)
            for f, t0, t1 in self._outages:
                off |= (fo == f) & (times >= t0) & (times < t1)
            c = np.where(off, 0.0, c)
        return c

    def field(self, x: np.ndarray, times: np.ndarray) -> np.ndarray:
        """Complex carrier [V] at antenna chainages x (noise-free): the segment under the
        antenna plus the end effects of the breakpoints around it."""
        p = self.params
        r = p["antenna_height"]
        n_bp = self._B.size
        if n_bp == 0:
            return np.zeros(x.shape, dtype=complex)
        k = np.searchsorted(self._B, x, side="right")
        z = self._amp(k, times)
        q = p["crossing_leakage"]
        for o in (-2, -1, 0, 1):
            j = k + o
            valid = (j >= 0) & (j < n_bp)
            jj = np.clip(j, 0, n_bp - 1)
            u = x - self._B[jj]
            fu = _f(u, r)
            c0, c1 = self._amp(jj, times), self._amp(jj + 1, times)
            term = (fu - np.where(u >= 0.0, 1.0, -1.0)) * (c1 - c0) * 0.5
            leak = np.where(self._is_cross[jj], 0.5j * q * self._leak_sign[jj] * (c0 - c1) / (1.0 + (u / r) ** 2),
                            0.0)
            z = z + np.where(valid, term + leak, 0.0)
        return z

    def samples(self, times, position, speed, acceleration):
        p = self.params
        n = len(times)
        x = position - p["antenna_offset"]
        z = self.field(x, times)
        if self._blank.size:
            k = np.searchsorted(self._blank[:, 0], x, side="right") - 1
            inside = (k >= 0) & (x <= self._blank[np.maximum(k, 0), 1])
            z = np.where(inside, 0.0, z)
        noise = self.rng.normal(0.0, p["noise"], (n, 2))
        z = z + noise[:, 0] + 1j * noise[:, 1]
        level = np.minimum(np.abs(z), 0.999 * p["adc_range"])
        phase = np.angle(z * np.exp(1j * TWO_PI * self._freq_offset * times))
        return np.column_stack([level, phase, self._telegrams(times, x, level)])

    def _telegrams(self, times, x, level) -> np.ndarray:
        """The loop channel: a telegram's loop number at the first sample after it ended."""
        p = self.params
        out = np.zeros(len(times))
        if not self.loops:
            return out
        li = np.searchsorted(self._loop_start, x, side="right") - 1
        li = np.where((li >= 0) & (x < self._loop_end[np.maximum(li, 0)]), li, -1)
        ok = level >= p["telegram_level"]
        kk = np.floor((times - self._tel_offset) / p["telegram_period"]).astype(np.int64)
        bounds = [0, *(np.flatnonzero(np.diff(kk)) + 1).tolist(), len(times)]
        for a, b in zip(bounds[:-1], bounds[1:]):
            w = self._tel
            if w is None or w[0] != kk[a]:
                if w is not None:
                    out[a] = self._complete(w)
                w = self._tel = [int(kk[a]), 0, 0, int(li[a]), False]
            w[1] += b - a
            w[2] += int(np.count_nonzero(ok[a:b]))
            if np.any(li[a:b] != w[3]):
                w[4] = True
        return out

    def _complete(self, w) -> float:
        """Loop number of a finished telegram, 0 if it was not received."""
        _, n, n_ok, loop, mixed = w
        if mixed or loop < 0 or n_ok < 0.9 * n:
            return 0.0
        if self.rng.random() < self.params["telegram_error_rate"]:
            return 0.0
        return float(self._numbers[loop])


# ----------------------------------------------------------------------------------
# Decoder
# ----------------------------------------------------------------------------------

def _wrap_deg(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


class LzbDecoder(Decoder):
    sensor = SENSOR
    channels = LzbSimulator.channels

    def __init__(self, params: dict, track: Track):
        super().__init__(params, track)
        self.loops = loop_table(track, params)
        self._by_number = {row["number"]: k for k, row in enumerate(self.loops)}
        self._known = set(self._by_number) | {0}
        self._min_cell = {k: float(np.min(np.diff(row["crossings"]))) for k, row in enumerate(self.loops)}
        # state carried between blocks (plain numbers: a rejected block changes none of it)
        self._t_last: float | None = None   # time of the last sample [s]
        self._phi: float | None = None      # phase of the last strong sample [rad]; None: no carrier yet
        self._L = float(params["amplitude"])  # full level, running [V]
        self._gap: dict | None = None       # the null/dropout in progress (sums of its samples)
        self._queue: list = []              # telegrams received while a null was open
        self._tel_loop = 0                  # loop number of the last telegram
        self._tel_t = -math.inf             # its time [s]
        self._event: tuple | None = None    # last crossing: (t, timed, speed, sigma_t, observed)
        self._counting = False              # the count is valid
        self._loop = -1                     # index of the loop the antenna is on (while counting)
        self._cell = 0                      # cell of that loop (between crossings cell and cell + 1)
        self._dir = 0                       # direction of travel while counting (+1, -1)
        self._speed: tuple | None = None    # (time, speed) of the last timed crossing
        for key in ("fixes", "crossings", "anchors", "dropouts", "dips", "withheld_doubtful", "withheld_uncounted",
                    "lost_stop", "lost_dropout", "lost_telegram", "lost_edge"):
            self.stats[key] = 0

    # --- checks ------------------------------------------------------------------
    def _check(self, block: RawBlock):
        p = self.params
        if block.channels != self.channels:
            raise InputRejected("channels", f"LZB channels {block.channels}, expected {self.channels}")
        rows = block.data.T.astype(float)
        level, phase, loop = rows[0], rows[1], rows[2]
        if float(level.min()) < -1e-6 or float(level.max()) >= p["adc_range"]:
            raise InputRejected("implausible", f"level {level.min():.3g}..{level.max():.3g} V outside "
                                               f"0..{p['adc_range']} V")
        if float(np.abs(phase).max()) > math.pi + 1e-3:
            raise InputRejected("implausible", "carrier phase beyond +-pi")
        tel = np.flatnonzero(loop)
        if tel.size:
            nums = loop[tel]
            if np.any(np.abs(nums - np.round(nums)) > 1e-3) or float(nums.min()) < 0 or float(nums.max()) > NUMBER_MAX:
                raise InputRejected("implausible", "loop channel holds a value that is no loop number")
            unknown = set(np.round(nums).astype(int).tolist()) - self._known
            if unknown:
                raise InputRejected("unknown_id", f"LZB loop number(s) {sorted(unknown)} not on track "
                                                  f"{self.track.track_id}")
        return level, phase, loop, tel

    # --- decoding -----------------------------------------------------------------
    def decode(self, block: RawBlock):
        p = self.params
        level, phase, loop, tel = self._check(block)   # raises before any state changes
        n = block.n_samples
        t = block.t0 + self.sample_offsets(n, block.sample_rate)
        dt = 1.0 / block.sample_rate
        out: list[PositionFix] = []
        if self._t_last is not None and t[0] - self._t_last > 1.5 * dt:
            # lost blocks: what happened in between was not observed
            if self._gap is None:
                self._gap = self._open(self._t_last, self._phi)
            self._gap["unobserved"] = True
        weak = level < p["strong_fraction"] * p["amplitude"]
        if self._gap is None and tel.size == 0 and not weak.any():   # the usual block: carrier, no event
            self._phi = float(phase[-1])
            self._update_level(level)
            self._t_last = float(t[-1])
            return out
        change = np.flatnonzero(weak[1:] != weak[:-1]) + 1
        bounds = [0, *change.tolist(), n]
        ti, tels = 0, tel.tolist()
        for a, b in zip(bounds[:-1], bounds[1:]):
            if weak[a]:
                if self._gap is None:
                    self._gap = self._open(float(t[a - 1]) if a > 0 else (self._t_last if self._t_last is not None
                                                                          else float(t[a])),
                                           float(phase[a - 1]) if a > 0 else self._phi)
                self._add(t[a:b], level[a:b], phase[a:b])
                while ti < len(tels) and tels[ti] < b:
                    self._queue = (self._queue + [(int(round(loop[tels[ti]])), float(t[tels[ti]]))])[-4:]
                    ti += 1
            else:
                if self._gap is not None:
                    out += self._close(float(t[a]), phase[a:min(b, a + 3)])
                    queued, self._queue = self._queue, []
                    for number, t_tel in queued:
                        out += self._telegram(number, t_tel)
                while ti < len(tels) and tels[ti] < b:
                    out += self._telegram(int(round(loop[tels[ti]])), float(t[tels[ti]]))
                    ti += 1
                self._phi = float(phase[b - 1])
                if b - a >= 20:
                    self._update_level(level[a:b])
        self._t_last = float(t[-1])
        self.stats["fixes"] += len(out)
        return out

    def _update_level(self, level: np.ndarray) -> None:
        """The full level L of the carrier between crossings: follows a rise at once and a fall
        slowly (2 % a block), so that the slope into a null does not pull it down."""
        if level.size >= 20:
            med = float(np.median(level))
            L = med if med > self._L else self._L + 0.02 * (med - self._L)
            self._L = min(max(L, self.params["strong_fraction"] * self.params["amplitude"]), self.params["adc_range"])

    def _open(self, t0: float, phi: float | None) -> dict:
        return {"t0": t0, "phi": phi, "n": 0, "lost": 0, "s1": 0.0, "sy": 0.0, "s11": 0.0, "s1y": 0.0, "syy": 0.0,
                "unobserved": phi is None, "L": self._L}

    def _add(self, t, level, phase) -> None:
        g = self._gap
        g["n"] += len(t)
        g["lost"] += int(np.count_nonzero(level < self.params["detect_level"]))
        if g["phi"] is None:
            return
        tau = t - g["t0"]
        y = level * np.cos(phase - g["phi"])
        g["s1"] += float(tau.sum())
        g["sy"] += float(y.sum())
        g["s11"] += float(np.dot(tau, tau))
        g["s1y"] += float(np.dot(tau, y))
        g["syy"] += float(np.dot(y, y))

    def _fit(self, g: dict):
        """(crossing time [s], its 1-sigma [s], speed [m/s]) of the line through a null, or
        None if it cannot be timed."""
        p = self.params
        n = g["n"]
        if n < p["min_fit_samples"] or g["lost"] > p["max_lost_fraction"] * n:
            return None
        m1, my = g["s1"] / n, g["sy"] / n
        sxx = g["s11"] - n * m1 * m1
        sxy = g["s1y"] - n * m1 * my
        syy = g["syy"] - n * my * my
        if not sxx > 0.0:
            return None
        beta = sxy / sxx
        if not beta < 0.0:
            return None                      # the projection must fall from +L to -L
        tau_c = m1 - my / beta
        dur = g["t1"] - g["t0"]
        if not -1e-9 <= tau_c <= dur + 1e-9:
            return None
        L = g["L"]
        res = max(syy - beta * sxy, 0.0) / max(n - 2, 1)
        if math.sqrt(res) > p["max_residual"] * L:
            return None
        r = p["antenna_height"]
        speed = -beta * r / (L * slope_factor(p["strong_fraction"] * p["amplitude"] / L))
        if not 0.0 < speed <= 200.0:
            return None
        sigma_y = max(math.sqrt(res), p["noise"])
        var_t = sigma_y * sigma_y / (beta * beta) * (1.0 / n + (tau_c - m1) ** 2 / sxx)
        return g["t0"] + tau_c, math.sqrt(var_t), speed

    def _close(self, t1: float, phase_after: np.ndarray) -> list[PositionFix]:
        """Judge the null that ended at t1 (the first strong sample after it)."""
        p = self.params
        g, self._gap = self._gap, None
        g["t1"] = t1
        if g["phi"] is None:
            self._lose("lost_dropout")   # the carrier appeared: nothing to compare with
            self._event = None
            return []
        after = float(np.angle(np.mean(np.exp(1j * phase_after))))
        step = _wrap_deg(math.degrees(after - g["phi"]))
        dur = t1 - g["t0"]
        tol = p["phase_tolerance"] + 360.0 * p["max_carrier_offset"] * dur
        if tol >= 90.0:
            parity = None
        elif abs(_wrap_deg(step - 180.0)) <= tol:
            parity = 1
        elif abs(step) <= tol:
            parity = 0
        else:
            parity = None
        observed = not g["unobserved"] and g["lost"] <= p["max_lost_fraction"] * g["n"]
        if observed and parity == 1:
            self.stats["crossings"] += 1
            fit = self._fit(g)
            if fit is None:
                event = (g["t0"] + 0.5 * dur, False, math.nan, math.nan, True)
            else:
                event = (fit[0], True, fit[2], fit[1], True)
            self._event = event
            return self._count(event)
        if observed and parity == 0:
            # turned back inside the null, or a dip of the level: only a dip if the train cannot stop
            # (a sample or two at the threshold: receiver noise at the edge of a null)
            if g["n"] < p["min_fit_samples"] or (self._counting and not self._could_stop(t1, 0.0)):
                self.stats["dips"] += 1
            else:
                self._lose("lost_stop")
            return []
        # a dropout (or a phase step that is neither): crossings may have passed unseen
        self.stats["dropouts"] += 1
        self._event = (g["t0"] + 0.5 * dur, False, math.nan, math.nan, False)
        if not self._counting:
            return []
        if parity is None or self._could_stop(t1, 0.0):
            self._lose("lost_dropout")
            return []
        ts, vs = self._speed
        v_hi = vs * (1.0 + p["speed_tolerance"]) + p["max_acceleration"] * (t1 - ts)
        if v_hi * dur >= self._min_cell[self._loop]:
            self._lose("lost_dropout")
            return []
        if parity == 1:
            return self._count(self._event)
        return []

    def _could_stop(self, t: float, v_now: float) -> bool:
        """Whether the train may have stood still (and turned back) since the last timed crossing,
        arriving at t with speed v_now (0: unknown)."""
        if self._speed is None:
            return True
        p = self.params
        ts, vs = self._speed
        keep = 1.0 - p["speed_tolerance"]
        return (vs * keep + v_now * keep) / p["max_acceleration"] <= t - ts

    def _lose(self, why: str) -> None:
        if self._counting:
            self.stats[why] += 1
        self._counting = False
        self._speed = None

    def _count(self, event) -> list[PositionFix]:
        """One crossing passed (``event``: t, timed, speed, sigma_t, observed) while counting."""
        t, timed, speed, sigma_t, _ = event
        if not self._counting:
            self.stats["withheld_uncounted"] += 1
            return []
        if self._could_stop(t, speed if timed else 0.0):
            self._lose("lost_stop")
            self.stats["withheld_uncounted"] += 1
            return []
        row = self.loops[self._loop]
        idx = self._cell + 1 if self._dir > 0 else self._cell
        chainage = float(row["crossings"][idx])
        cell = self._cell + self._dir
        joint = False
        if not 0 <= cell < row["crossings"].size - 1:
            nb = row["above"] if self._dir > 0 else row["below"]
            if nb < 0:
                self._lose("lost_edge")
                return []
            self._loop, row, joint = nb, self.loops[nb], True
            cell = 0 if self._dir > 0 else row["crossings"].size - 2
        self._cell = cell
        if not timed:
            self.stats["withheld_doubtful"] += 1
            return []
        self._speed = (t, speed)
        return [self._fix(t, chainage, speed, sigma_t, row, joint)]

    def _fix(self, t: float, chainage: float, speed: float, sigma_t: float, row: dict, joint: bool) -> PositionFix:
        p = self.params
        return PositionFix(float(t), self.sensor, self.unit_id, self.track.track_id, row["id"],
                           chainage + p["antenna_offset"], fix_sigma(p, speed * sigma_t, joint), self._dir)

    def _telegram(self, number: int, t: float) -> list[PositionFix]:
        """A telegram of loop ``number`` received at t: confirms the count, or anchors it at a joint.

        The joint lies after the start of the last telegram of the old loop (its window, one
        ``telegram_period``, was all on that loop) and at most ``max_telegram_delay`` before
        this one; in so short a time (< 0.5 s) the train passes at most one crossing: the last
        crossing seen is the joint if it falls in there."""
        p = self.params
        if number == self._tel_loop:
            self._tel_t = t
            return []
        old, old_t = self._tel_loop, self._tel_t
        self._tel_loop, self._tel_t = number, t
        k = self._by_number[number]
        if self._counting:
            if self._loop == k:
                return []                    # the count moved onto this loop at the joint
            self._lose("lost_telegram")
        ev = self._event
        if not old or ev is None or not ev[4] or not old_t - p["telegram_period"] < ev[0] <= t \
                or t - ev[0] > p["max_telegram_delay"]:
            return []
        o = self._by_number[old]
        row = self.loops[k]
        if row["below"] == o:
            direction, cell, chainage = 1, 0, row["start"]
        elif row["above"] == o:
            direction, cell, chainage = -1, row["crossings"].size - 2, row["end"]
        else:
            return []                        # not neighbours: no joint to anchor at
        self._counting, self._loop, self._cell, self._dir = True, k, cell, direction
        self.stats["anchors"] += 1
        t_ev, timed, speed, sigma_t, _ = ev
        if not timed:
            self._speed = None
            return []
        self._speed = (t_ev, speed)
        return [self._fix(t_ev, float(chainage), speed, sigma_t, row, True)]


MIN_FIX_SIGMA = 1e-4   # [m] least 1-sigma of a fix: 0.1 mm, far below any laid crossing (a guard for
                       # crossing_sigma = survey_sigma = 0)


def fix_sigma(params: dict, timing: float = 0.0, joint: bool = False) -> float:
    """1-sigma [m] of a crossing fix: the timing error ``timing`` [m] (speed x the null's
    regression error), the crossing's installation tolerance and the loop's survey error (a
    joint carries the mean of two loops' survey errors: half a survey variance more); at least
    MIN_FIX_SIGMA. With timing 0 off a joint the least a fix reports."""
    var = timing ** 2 + params["crossing_sigma"] ** 2 + params["survey_sigma"] ** 2
    if joint:
        var += 0.5 * params["survey_sigma"] ** 2
    return max(math.sqrt(var), MIN_FIX_SIGMA)


def loop_window(params: dict, row: dict) -> tuple[float, float]:
    """Chainages [m] between which a fix naming loop ``row`` lies: a crossing of the loop, its
    ends (joints) included, + ``antenna_offset`` (antenna behind the front, either direction)."""
    return row["start"] + params["antenna_offset"], row["end"] + params["antenna_offset"]


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """LZB fixes for the fusion: a loop's survey error is common to its crossings, so it is a
    fix-bias state redrawn per loop (reference_id); the crossings' installation error and the
    timing are white. The decoder includes both in its stddev. Fault modes: a miscount (a
    crossing missed or counted twice that the decoder could not see), a loop/feeder outage,
    and an offset shared by a run of fixes beyond what the survey state's prior allows (a loop
    laid or surveyed off by more than ``survey_sigma``, a wrong antenna offset): the campaign's
    lzb:296076971 of seed 0, 4 fixes 3.3 sigma off, had 79 NOMINAL states outside.
    Floor: the decoder's ``fix_sigma`` without timing, off a joint. References: every loop
    of the track (``loop_table``), window ``loop_window``."""
    survey = float(params["survey_sigma"])
    references = None
    if track is not None:
        references = ReferenceTable({row["id"]: ReferenceWindow(*loop_window(params, row))
                                     for row in loop_table(track, params)})
    return ErrorModel(SENSOR, "position", fix_bias_sigma=survey, fix_bias_per_reference=True,
                      reported_fix_bias=survey, faults=("miscount", "outage", "offset"), min_stddev=fix_sigma(params),
                      references=references)


SPEC = SensorSpec(
    node="lzb_receiver", sensor=SENSOR, simulator=LzbSimulator, decoder=LzbDecoder, params=PARAMS,
    description="on-board LZB cable-loop receiver (German ICE): counts the 100 m conductor crossings, "
                "loop number -> absolute position fix at each crossing",
    seeds=("000",), outputs=("position",), error_model=error_model,
)

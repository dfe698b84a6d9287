"""INPO crossed inductive loop position system (wayside), seeds 000, 002 and 003.

Physics (seed 000 section 2.1.1, MLU; 2.1.2, Transrapid INPO; seed 002 section
2.2.1): a transmitter antenna on the vehicle radiates a carrier; crossed loops laid
along the guideway receive it. A loop reverses its winding every half period, so
the envelope-detected voltage of a loop pair follows the antenna position x as

    E_u = E0 cos(2 pi x / p)                                  (seed 000 eq. 1)

Three pairs U, V, W offset by p/3 give a 3-phase signal whose space vector (Clarke
transform) turns like the rotating field of a motor: its angle is the position
within the period p. Counting the 0..360 deg repetitions from the section start
gives the absolute position. MLU lays 6 loops (each phase twice, the second set
shifted by p/2, i.e. a 6-phase system at p/6 spacing) so that the 2nd and 3rd
harmonics of a non-sinusoidal envelope cancel (seed 000 section 2.1.1, last
paragraph). Transrapid INPO resolves the position to +-8 deg (electrical) of the
motor period (seed 000 section 2.1.2), which seed 002 section 2.2.1 gives as +-8 deg
(12 mm).

Period: 8 deg = 12 mm means 360 deg = 540 mm, i.e. one electrical period of the
long-stator motor = 2 pole pitches. The Transrapid pole pitch is 258 mm, so the
default period is p = 0.516 m (8 deg = 11.5 mm ~ 12 mm). The two seeds part here: seed 000
gives the +-8 deg "over one pole length", which read as 360 deg per pole pitch would be
8/360 x 258 mm = 5.7 mm. The default follows seed 002, which states the millimetres, and
the degrees as electrical ones: a pole pitch spans 180 electrical degrees, so the 360 deg
of the loop's phase are the motor's period of two pole pitches (docs/references.md). (Seed 003's experimental
crossed loop has a 0.63 m period: its 1/3-period pulse train repeats every 21 cm,
section 4.1.)

Track equipment (kind ``inpo_section``): one wayside receiver per loop section::

    inpo_section:
      - {id: INPO01, position: 1000.0, end: 3000.0, period: 0.516}   # position = section start
      - {every: 2000.0, start: 4000.0, end: 8000.0, id: "INPO{n:02d}", length: 2000.0}  # 3 adjacent

``position`` is the chainage of the loop start [m] (``start`` is accepted as an alias),
``end`` [m] or ``length`` [m] its end, ``period`` [m] the loop period (default:
parameter ``period``) and optional ``receiver`` the receiver number reported in the raw
data (default: 1-based order along the track). Sections must not overlap; adjacent
sections (end == next start) hand over to one another. The phase origin (0 deg of
phase U) is the section start.

Sample rate (default 2 kHz, common parameter ``sample_rate``): at 500 km/h (139 m/s)
the phase turns at 139 / 0.516 = 269 Hz, so counting periods needs > 538 Hz (phase
advance per sample < 180 deg). 2 kHz gives 48.5 deg per sample, leaving a wide margin
for the +-8 deg error and noise in the unwrapping, and resolves the envelope's 3rd
harmonic (807 Hz < 1 kHz Nyquist). Data rate: 4 channels x 2 kHz = 8000 values/s
(6 pairs: 7 x 2 kHz = 14000 values/s).

Raw signal: the envelope voltages [V] of the loop
pairs (``u, v, w``; with ``n_pairs = 6``: ``u1, v1, w1, u2, v2, w2``) of the receiver
that currently carries the vehicle's signal, and ``receiver``: the number of that
receiver (the wayside evaluation unit switches to the receiver with the strongest
carrier and holds its last choice when none is above the squelch; 0 = none yet).
Outside a section the channels carry noise and detector offsets only.

Errors modelled (defaults calibrated so that the total per-sample phase error of the
3-pair system reaches, but stays within, the +-8 deg of the INPO specification):
  * 2nd and 3rd harmonics of the envelope (non-ideal loop/antenna geometry), their
    relative size decaying with the antenna height like exp(-2 pi (n-1) z / p) (field of
    a periodic current sheet), with a channel-to-channel spread;
  * channel gain mismatch, detector DC offsets, loop laying skew of each pair;
  * amplitude variation with the air gap: E0 ~ B_z of a rectangular loop cell from the
    Biot-Savart law (seed 003 eq. 2), the gap varying along the guideway;
  * white noise of the envelope detector; the detector's group delay;
  * the coupling ramps up/down over the antenna length at the section ends;
  * the surveyed chainage of a section start differs from the real loop start.

Decoder: Clarke transform of the 3 (or 6) signals -> phase -> position within the
period; unwrapping counts the periods. The count is initialised when the antenna
enters a section (amplitude crosses ``on_threshold`` after a low-amplitude sample, or
the receiver changes at a hand-over): once the phase has moved a quarter period the
direction is known and the entry sample is placed at the nearest phase-consistent
position to the section start (moving forwards) or end (moving backwards). Absolute
antenna position = section start + count x p + phase/(2 pi) x p; the fix is the train
front = antenna position + ``antenna_offset``. One PositionFix per ``fix_samples``
samples (0 = one per block), direction from the sign of the phase rate, 1-sigma from
the +-8 deg spec taken as 2.5 sigma per sample (its periodic part averaging out with the
distance run in the fix, the white part with the sample count) plus the section's fixed
survey and loop-laying errors. Lost or rejected blocks up to ``max_bridge`` seconds are
bridged by the phase rate; a longer gap, or a count that places the antenna off the
loops that still see it, loses the count until the next section entry. Blocks with a
saturated channel, an amplitude beyond any air gap, a zero-sequence voltage (broken
pair), a signal without a receiver or an impossible phase step are rejected as
"implausible"; an unknown receiver number as "unknown_id".
"""
from __future__ import annotations

import math

import numpy as np

from ..measurements import PositionFix
from ..signals import InputRejected, RawBlock
from ..track import Track, TrackError, extent
from .base import Decoder, ErrorModel, Param, ReferenceTable, ReferenceWindow, SensorSpec, Simulator

SECTION_KIND = "inpo_section"
TWO_PI = 2.0 * math.pi
SQRT3 = math.sqrt(3.0)

PARAMS = {
    "period": Param(0.516, "loop period p [m] for sections without 'period': 2 x 258 mm Transrapid pole "
                           "pitch, so that 8 deg = 11.5 mm ~ the 12 mm of seed 002 section 2.2.1", (0.05, 5.0)),
    "n_pairs": Param(3, "loop pairs evaluated [1]: 3 (U, V, W at p/3; Transrapid INPO) or 6 (MLU: each phase "
                        "twice, second set shifted p/2, cancels 2nd/3rd harmonics; seed 000 section 2.1.1)", (3, 6)),
    "antenna_offset": Param(1.5, "transmitter antenna distance behind the train front [m], i.e. at front "
                                 "chainage - offset (vehicle layout); within a train of up to 1 km", (0.0, 1000.0)),
    "antenna_length": Param(0.3, "length of the transmitter antenna along the track [m]; the coupling ramps "
                                 "up/down over it at a section end (antenna size a, seed 000 section 2.1.1)",
                            (0.01, 5.0)),
    "amplitude": Param(1.0, "envelope amplitude E0 of one pair at the nominal gap, full coupling [V] "
                            "(receiver output level, seed 000 eq. 1)", (1.0e-3, 10.0)),
    "noise": Param(0.01, "1-sigma white noise of each envelope channel [V] (40 dB SNR in the 1 kHz "
                         "envelope bandwidth; calibrated into the +-8 deg budget of seed 002 section 2.2.1)",
                   (0.0, 1.0)),
    "harmonic2": Param(0.07, "2nd harmonic of the envelope, fraction of the fundamental at the nominal gap [1] "
                              "(non-ideal loop/antenna geometry, seed 000 section 2.1.1); with 3 pairs it gives "
                              "up to asin(h2) = 4.0 deg of phase error", (0.0, 1.0)),
    "harmonic2_phase": Param(30.0, "phase of the 2nd harmonic [deg]", (-180.0, 180.0)),
    "harmonic3": Param(0.10, "3rd harmonic of the envelope, fraction of the fundamental [1] (cancels in the "
                             "Clarke transform except for the channel-to-channel spread)", (0.0, 1.0)),
    "harmonic3_phase": Param(-20.0, "phase of the 3rd harmonic [deg]", (-180.0, 180.0)),
    "harmonic_spread": Param(0.12, "1-sigma channel-to-channel spread of the harmonic amplitudes (fraction) "
                                  "and phases [rad] (loop manufacturing tolerance)", (0.0, 1.0)),
    "gain_tolerance": Param(0.01, "1-sigma gain mismatch between the pair channels [1] (fraction; receiver and "
                                   "loop tolerance)", (0.0, 1.0)),
    "offset_sigma": Param(0.005, "1-sigma DC offset of each envelope detector [V]", (0.0, 1.0)),
    "skew_sigma": Param(0.001, "1-sigma laying error of each loop pair along the track [m]", (0.0, 0.1)),
    "nominal_gap": Param(0.03, "antenna-to-loop distance z at the nominal levitation gap [m]", (1.0e-3, 0.5)),
    "gap_variation": Param(0.0015, "1-sigma variation of that distance along the guideway [m] (levitation "
                                   "gap control +-2..3 mm, girder deflection)", (0.0, 0.05)),
    "loop_half_width": Param(0.05, "half width b of the crossed loop across the track [m] (seed 003 eq. 2)",
                             (5.0e-3, 1.0)),
    "detector_delay": Param(5e-5, "group delay of the envelope detector [s] (first-order low pass, 3.2 kHz); "
                                  "the decoder back-dates the samples by it (7 mm at 139 m/s otherwise)",
                            (0.0, 0.01)),
    "survey_sigma": Param(0.002, "1-sigma error of the surveyed chainage of a section start [m]", (0.0, 1.0)),
    "squelch": Param(0.2, "carrier level (fraction of full coupling) [1] above which the evaluation unit "
                          "switches to a receiver", (0.0, 1.0)),
    "on_threshold": Param(0.5, "decoder: amplitude (fraction of 'amplitude') [1] at which the antenna is taken "
                               "to have entered a section", (0.0, 1.0)),
    "off_threshold": Param(0.3, "decoder: amplitude below which the antenna has left (hysteresis) [fraction of "
                                "'amplitude']", (0.0, 1.0)),
    "max_amplitude": Param(1.6, "decoder: amplitude above this fraction of 'amplitude' is implausible (more "
                                "than any air gap gives) [1]", (1.0, 10.0)),
    "zero_sequence_limit": Param(0.3, "decoder: |U+V+W|/3 above this fraction of 'amplitude' in a section "
                                      "is implausible (a broken or stuck pair) [1]", (0.0, 1.0)),
    "adc_range": Param(5.0, "receiver output range [V]; a sample at or beyond it is saturated (implausible)",
                       (0.1, 10.0)),
    "max_step": Param(0.3, "decoder: phase step per sample above this many periods is implausible [1] "
                           "(0.3 x 0.516 m x 2 kHz = 310 m/s); at most 1/2 (a larger step is ambiguous)",
                      (0.0, 0.5)),
    "accuracy_deg": Param(8.0, "INPO phase accuracy +-[deg] (seed 000 section 2.1.2, seed 002 section 2.2.1), "
                               "taken as 2.5 sigma of one sample for the fix stddev", (0.0, 180.0)),
    "fix_samples": Param(0, "samples per PositionFix [1]; 0 = one fix per block", (0, 1000000)),
    "min_fix_samples": Param(5, "fewest tracked samples that make a fix [1]", (1, 1000000)),
    "max_bridge": Param(0.2, "longest gap (lost/rejected blocks) bridged with the phase rate [s]", (0.0, 10.0)),
}


def section_table(track: Track, default_period: float) -> list[dict]:
    """The inpo_section entries of a track as dicts id, start, end, period, receiver."""
    out, receivers = [], set()
    for i, item in enumerate(track.items(SECTION_KIND)):
        start, end = extent(SECTION_KIND, item)
        period = float(item.get("period", default_period))
        receiver = int(item.get("receiver", i + 1))
        if not (end > start and period > 0.0):
            raise TrackError(f"{SECTION_KIND} '{item['id']}': need end > start and period > 0")
        if end > track.length + 1e-9:
            raise TrackError(f"{SECTION_KIND} '{item['id']}' ends at {end} m, off the track (0..{track.length} m)")
        if receiver <= 0 or receiver in receivers:
            raise TrackError(f"{SECTION_KIND} '{item['id']}': receiver {receiver} is not a new positive number")
        if out and start < out[-1]["end"] - 1e-9:
            raise TrackError(f"{SECTION_KIND} '{item['id']}' overlaps '{out[-1]['id']}'")
        receivers.add(receiver)
        out.append({"id": str(item["id"]), "start": start, "end": end, "period": period, "receiver": receiver})
    return out


def pair_channels(n_pairs: int) -> tuple[str, ...]:
    if n_pairs == 3:
        return ("u", "v", "w")
    if n_pairs == 6:
        return ("u1", "v1", "w1", "u2", "v2", "w2")
    raise ValueError(f"n_pairs must be 3 or 6, not {n_pairs}")


def loop_field_z(x, y, z, l: float, b: float):
    """B_z of a 2l x 2b rectangular loop carrying mu0 I / (4 pi) = 1 (seed 003 eq. 2)."""
    x, y, z = np.asarray(x, float), np.asarray(y, float), np.asarray(z, float)
    out = 0.0
    for yy, sign in ((y + b, 1.0), (y - b, -1.0)):
        r2 = yy * yy + z * z
        out = out + sign * yy / r2 * ((x + l) / np.sqrt((x + l) ** 2 + r2) - (x - l) / np.sqrt((x - l) ** 2 + r2))
    return out


def space_vector(data: np.ndarray, n_pairs: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(phase [rad], amplitude [V], zero sequence [V]) per sample from the pair voltages.

    ``data``: (n, n_pairs) envelope voltages. With 6 pairs the two sets are first
    combined differentially, U = (U1 - U2)/2 (cancels the even harmonics), then the
    Clarke transform alpha = 2/3 (U - (V + W)/2), beta = (V - W)/sqrt(3) gives the space
    vector, whose angle is 2 pi x / p (seed 000 section 2.1.1) and whose length is E0.
    The zero sequence (U + V + W)/3 is ~0 for a healthy system.
    """
    data = np.asarray(data, dtype=float)
    if n_pairs == 6:
        data = 0.5 * (data[:, :3] - data[:, 3:6])
    return _clarke(data[:, 0], data[:, 1], data[:, 2])


def _clarke(u, v, w):
    """(phase, amplitude, zero sequence) of the pair voltages u, v, w (see space_vector)."""
    alpha = (2.0 / 3.0) * (u - 0.5 * (v + w))
    beta = (v - w) / SQRT3
    return np.arctan2(beta, alpha), np.hypot(alpha, beta), (u + v + w) / 3.0


class InpoSimulator(Simulator):
    """The wayside receivers of all inpo_sections of a track, seen through the
    evaluation unit's receiver switch."""

    sensor = "inpo"
    default_sample_rate = 2000.0  # 48.5 deg of phase per sample at 139 m/s with p = 0.516 m
    adc_lsb = {"V": 5.0 / 4096}  # 12-bit ADC over the 5 V input range (adc_range)

    def __init__(self, *args):
        super().__init__(*args)
        p = self.params
        self.n_pairs = int(p["n_pairs"])
        self.pairs = pair_channels(self.n_pairs)
        self.channels = self.pairs + ("receiver",)
        self.units = ("V",) * self.n_pairs + ("1",)
        self.sections = section_table(self.track, p["period"])
        ns, nc = len(self.sections), self.n_pairs
        rng = self.rng
        # per-section truth: real loop start, channel tolerances (drawn in a fixed order)
        self.true_start = np.array([s["start"] for s in self.sections]) + rng.normal(0.0, p["survey_sigma"], ns)
        self.true_end = self.true_start + np.array([s["end"] - s["start"] for s in self.sections])
        self.period = np.array([s["period"] for s in self.sections])
        self.receiver = np.array([s["receiver"] for s in self.sections], dtype=float)
        self.gain = 1.0 + rng.normal(0.0, p["gain_tolerance"], (ns, nc))
        self.offset = rng.normal(0.0, p["offset_sigma"], (ns, nc))
        self.skew = rng.normal(0.0, p["skew_sigma"], (ns, nc))
        spread = p["harmonic_spread"]
        self.h2 = p["harmonic2"] * (1.0 + rng.normal(0.0, spread, (ns, nc)))
        self.h3 = p["harmonic3"] * (1.0 + rng.normal(0.0, spread, (ns, nc)))
        self.ph2 = math.radians(p["harmonic2_phase"]) + rng.normal(0.0, spread, (ns, nc))
        self.ph3 = math.radians(p["harmonic3_phase"]) + rng.normal(0.0, spread, (ns, nc))
        self.idle_offset = rng.normal(0.0, p["offset_sigma"], nc)
        # air gap along the guideway: a few girder/stator-pack wavelengths with random phases
        self._gap_wl = np.array([24.768, 6.192, 3.096, 1.032])
        amp = rng.uniform(0.5, 1.0, len(self._gap_wl))
        self._gap_amp = amp * p["gap_variation"] * math.sqrt(2.0) / math.sqrt(np.sum(amp * amp))
        self._gap_ph = rng.uniform(0.0, TWO_PI, len(self._gap_wl))
        # channel phase: pair c of set s sits at c * p/3 + s * p/2 (6 pairs: 60 deg spacing)
        idx = np.arange(nc)
        self._ch_phase = (idx % 3) * TWO_PI / 3.0 + (idx // 3) * math.pi
        self._last_rx = -1  # index into self.sections; -1 = none selected yet

    def gap(self, x):
        """Antenna-to-loop distance [m] at antenna chainage x."""
        x = np.asarray(x, float)[:, None]
        return self.params["nominal_gap"] + np.sum(
            self._gap_amp * np.sin(TWO_PI * x / self._gap_wl + self._gap_ph), axis=1)

    def _ramp(self, k, x):
        a = self.params["antenna_length"]
        return (np.clip((x - self.true_start[k]) / a + 0.5, 0.0, 1.0)
                * np.clip((self.true_end[k] - x) / a + 0.5, 0.0, 1.0))

    def samples(self, times, position, speed, acceleration):
        p = self.params
        n, nc = len(times), self.n_pairs
        tau = p["detector_delay"]
        # the detector output at t shows the antenna position at t - tau
        x = position - speed * tau + 0.5 * acceleration * tau * tau - p["antenna_offset"]
        noise = self.rng.normal(0.0, p["noise"], (n, nc))
        out = np.empty((n, nc + 1))
        if not self.sections:
            out[:, :nc] = self.idle_offset + noise
            out[:, nc] = 0.0
            return out
        z = self.gap(x)
        l_cell, b = 0.25 * self.period, p["loop_half_width"]
        # receiver switch: strongest carrier among the sections around x
        j = np.searchsorted(self.true_start, x, side="right") - 1
        cand = np.clip(np.stack([j - 1, j, j + 1], axis=1), 0, len(self.sections) - 1)
        level = self._ramp(cand, x[:, None])
        best = np.argmax(level, axis=1)
        k = cand[np.arange(n), best]
        on = level[np.arange(n), best] > p["squelch"]
        idx = np.where(on, np.arange(n), -1)
        np.maximum.accumulate(idx, out=idx)
        held = np.where(idx >= 0, k[np.maximum(idx, 0)], self._last_rx)
        self._last_rx = int(held[-1])
        sel = np.maximum(held, 0)
        ramp = np.where(held >= 0, self._ramp(sel, x), 0.0)
        # coupling vs air gap: B_z at a loop cell centre (seed 003 eq. 2) relative to the nominal gap
        lc = l_cell[sel]
        g = loop_field_z(0.0, 0.0, z, lc, b) / loop_field_z(0.0, 0.0, p["nominal_gap"], lc, b)
        dz = (z - p["nominal_gap"])[:, None]
        per = self.period[sel][:, None]
        theta = (TWO_PI * (x[:, None] - self.true_start[sel][:, None] - self.skew[sel]) / per
                 - self._ch_phase)
        h2 = self.h2[sel] * np.exp(-TWO_PI * dz / per)
        h3 = self.h3[sel] * np.exp(-2.0 * TWO_PI * dz / per)
        env = (np.cos(theta) + h2 * np.cos(2.0 * theta + self.ph2[sel])
               + h3 * np.cos(3.0 * theta + self.ph3[sel]))
        coupling = (p["amplitude"] * g * ramp)[:, None] * self.gain[sel]
        offs = np.where((held >= 0)[:, None], self.offset[sel], self.idle_offset)
        out[:, :nc] = coupling * env + offs + noise
        out[:, nc] = np.where(held >= 0, self.receiver[sel], 0.0)
        return out


def _wrap(a: float) -> float:
    """Angle a [rad] wrapped into [-pi, pi)."""
    return (a + math.pi) % TWO_PI - math.pi


def _unwrap(p: np.ndarray, dd: np.ndarray, ddmod: np.ndarray) -> np.ndarray:
    """np.unwrap(p) for a 1-D array (same arithmetic, without its generic-axis overhead),
    given its steps dd = p[1:] - p[:-1] and ddmod = mod(dd + pi, 2 pi) - pi (not modified)."""
    if len(p) < 2:
        return p.astype(float)
    if _any(ddmod == -math.pi):   # a step of exactly +-pi (rare)
        ddmod = np.where((ddmod == -math.pi) & (dd > 0), math.pi, ddmod)
    ph_correct = ddmod - dd
    np.copyto(ph_correct, 0.0, where=np.abs(dd) < math.pi)
    up = p.astype(float)
    up[1:] += ph_correct.cumsum()
    return up


# ndarray.any/all/sum/min/max go through Python wrappers (numpy 2); the decoder, called for
# every block with small arrays, calls the ufunc reductions directly
_sum, _any, _all = np.add.reduce, np.logical_or.reduce, np.logical_and.reduce
_max, _min, _fmax = np.maximum.reduce, np.minimum.reduce, np.fmax.reduce


class InpoDecoder(Decoder):
    sensor = "inpo"
    channels = ()  # depend on n_pairs; checked in decode()

    def __init__(self, params: dict, track: Track):
        super().__init__(params, track)
        self.n_pairs = int(params["n_pairs"])
        self.pairs = pair_channels(self.n_pairs)
        self.expected = self.pairs + ("receiver",)
        self.sections = {s["receiver"]: s for s in section_table(track, params["period"])}
        self._known_rx = set(self.sections) | {0}
        # state carried between blocks
        self._t_last: float | None = None   # time of the last processed sample [s]
        self._in = False                     # hysteresis state of the last sample
        self._rx = 0                         # receiver of the last sample
        self._mode = "lost"                  # lost | out | pending | track
        self._w_last = 0.0                   # unwrapped phase of the last in-section sample [periods]
        self._theta_last = 0.0
        self._w_entry = 0.0                  # pending: unwrapped phase at the entry sample
        self._offset = 0.0                   # track: u = w + offset, u = periods from the section start
        self._rate = 0.0                     # phase rate [periods/s]
        for key in ("fixes", "entries", "bridged", "count_lost"):
            self.stats[key] = 0

    # --- helpers -----------------------------------------------------------------
    def _check(self, block: RawBlock):
        """(theta, amp, receiver, all strong, phase steps, wrapped phase steps) of a block;
        raises InputRejected for a bad block. ``receiver`` is an int if one receiver carries
        the whole block (the common case, checked once), else an array. Tests "any sample
        above a limit" use the NaN-ignoring maximum (np.fmax), "all samples above" the
        NaN-propagating minimum: one reduction each, a NaN sample passes as before."""
        p = self.params
        if block.channels != self.expected:
            raise InputRejected("channels", f"INPO channels {block.channels}, expected {self.expected}")
        rows = block.data.T.astype(float, order="C")   # channel-major: pairs, then the receiver
        volts, rx_f = rows[: self.n_pairs], rows[self.n_pairs]
        r0 = float(rx_f[0])
        if math.isfinite(r0) and _all(rx_f == r0):
            rx = round(r0)   # = np.rint (half to even)
            if abs(r0 - rx) > 1e-3:
                raise InputRejected("implausible", "receiver number is not an integer")
            if rx not in self._known_rx:
                raise InputRejected("unknown_id", f"unknown INPO receiver(s) {[rx]}")
        else:
            rx = np.rint(rx_f).astype(int)
            if _any(np.abs(rx_f - rx) > 1e-3):
                raise InputRejected("implausible", "receiver number is not an integer")
            unknown = set(rx.tolist()) - self._known_rx
            if unknown:
                raise InputRejected("unknown_id", f"unknown INPO receiver(s) {sorted(unknown)}")
        if _fmax(np.abs(volts), axis=None) >= p["adc_range"]:
            raise InputRejected("implausible", f"envelope voltage at the {p['adc_range']} V limit (saturated)")
        if self.n_pairs == 6:
            volts = 0.5 * (volts[:3] - volts[3:6])
        theta, amp, zero = _clarke(volts[0], volts[1], volts[2])
        e0 = p["amplitude"]
        if _fmax(amp) > p["max_amplitude"] * e0:
            raise InputRejected("implausible", f"loop signal {amp.max():.2f} V beyond {p['max_amplitude']} x E0")
        on = p["on_threshold"] * e0
        all_strong = bool(_min(amp) > on)
        one_rx = isinstance(rx, int)
        strong = None if all_strong and one_rx else amp > on
        lim = p["zero_sequence_limit"] * e0
        if (_fmax(np.abs(zero)) > lim) if strong is None else _any(strong & (np.abs(zero) > lim)):
            raise InputRejected("implausible", "zero-sequence voltage: a loop pair is broken or stuck")
        if one_rx:
            no_rx = rx == 0 and (all_strong or bool(_any(strong)))
        else:
            no_rx = _any(strong & (rx == 0))
        if no_rx:
            raise InputRejected("implausible", "loop signal without a selected receiver")
        d = theta[1:] - theta[:-1]
        dmod = np.mod(d + math.pi, TWO_PI) - math.pi
        step = np.abs(dmod) / TWO_PI   # |wrapped phase step|
        if strong is None:
            both = None   # every step is between strong samples of one receiver
            bad = _fmax(step) > p["max_step"]
        else:
            both = strong[1:] & strong[:-1]
            if not one_rx:
                both &= rx[1:] == rx[:-1]
            bad = _any(both & (step > p["max_step"]))
        if bad:
            raise InputRejected("implausible", f"phase step {(step if both is None else step[both]).max():.2f} "
                                               f"periods per sample")
        return theta, amp, rx, all_strong, d, dmod

    def _hysteresis(self, amp, first_in: bool):
        e0 = self.params["amplitude"]
        ev = np.where(amp > self.params["on_threshold"] * e0, 1,
                      np.where(amp < self.params["off_threshold"] * e0, 0, -1))
        idx = np.where(ev >= 0, np.arange(len(amp)), -1)
        np.maximum.accumulate(idx, out=idx)
        return np.where(idx >= 0, ev[np.maximum(idx, 0)] == 1, first_in)

    def _runs(self, amp, rx, all_strong: bool, first_in: bool):
        """[(i0, i1, inside, receiver)] of the runs of samples with one hysteresis state
        (inside a section: above on_threshold since the last sample below off_threshold,
        and a receiver) and one receiver."""
        n = len(amp)
        if isinstance(rx, int):   # one receiver: usually one run
            if rx == 0:
                return [(0, n, False, 0)]
            if all_strong:
                return [(0, n, True, rx)]
            if _all(amp < self.params["off_threshold"] * self.params["amplitude"]):
                return [(0, n, False, rx)]
            rx = np.full(n, rx)
        inside = self._hysteresis(amp, first_in)
        inside &= rx > 0
        change = ((inside[1:] != inside[:-1]) | (rx[1:] != rx[:-1])).nonzero()[0] + 1
        bounds = [0, *change.tolist(), n]
        inside_l, rx_l = inside.tolist(), rx.tolist()
        return [(i0, i1, inside_l[i0], rx_l[i0]) for i0, i1 in zip(bounds[:-1], bounds[1:])]

    # --- decoding ---------------------------------------------------------------
    def decode(self, block: RawBlock):
        p = self.params
        theta, amp, rx, all_strong, d, dmod = self._check(block)  # raises before any state changes
        n = block.n_samples
        t = block.t0 + self.sample_offsets(n, block.sample_rate)   # = block.times()
        dt = 1.0 / block.sample_rate
        mode, w_last, theta_last = self._mode, self._w_last, self._theta_last
        w_entry, offset, rate, prev_in, prev_rx = self._w_entry, self._offset, self._rate, self._in, self._rx
        t_last = self._t_last
        contiguous = t_last is not None and t[0] - t_last <= 1.5 * dt
        bridge = False
        counts = dict.fromkeys(("entries", "bridged", "count_lost"), 0)
        if not contiguous:
            if mode == "track" and t_last is not None and t[0] - t_last <= p["max_bridge"]:
                bridge = True
                counts["bridged"] += 1
            else:
                if mode in ("track", "pending"):
                    counts["count_lost"] += 1
                mode, prev_in = "lost", False
        runs = self._runs(amp, rx, all_strong, prev_in)
        tracked = []   # (i0, i1, receiver, u [periods from the section start], u has NaN)
        for i0, i1, inside, r in runs:
            if not inside:
                mode = "out"  # an observed low-amplitude sample: ready for the next entry
                prev_in, prev_rx = False, r
                continue
            section = self.sections[r]
            per = section["period"]
            w = _unwrap(theta[i0:i1], d[i0:i1 - 1], dmod[i0:i1 - 1]) / TWO_PI
            first_of_block = i0 == 0
            continues = prev_in and prev_rx == r and mode in ("track", "pending")
            if first_of_block and not (contiguous or bridge):
                continues = False
            if continues:
                if first_of_block and bridge:
                    target = w_last + rate * (t[0] - t_last)
                else:
                    target = w_last + _wrap(float(theta[i0]) - theta_last) / TWO_PI
                w = w + round(target - float(w[0]))
            else:
                # entry: after an observed low-amplitude sample, or a hand-over between receivers
                handover = prev_in and prev_rx != r and (i0 > 0 or contiguous)
                entry = handover or (mode == "out" and not prev_in)
                if entry:
                    mode, w_entry = "pending", float(w[0])
                    counts["entries"] += 1
                else:
                    mode = "lost"
            if mode == "pending":
                moved = np.flatnonzero(np.abs(w - w_entry) >= 0.25)
                if moved.size:
                    d_dir = np.sign(w[moved[0]] - w_entry)
                    frac = w_entry - math.floor(w_entry)
                    if d_dir > 0:   # entered at the section start
                        u_entry = frac - round(frac)
                    else:       # entered at the section end
                        n_end = (section["end"] - section["start"]) / per
                        u_entry = frac + round(n_end - frac)
                    offset = u_entry - w_entry
                    mode = "track"
            if mode == "track":
                u_run = w + offset
                slack = p["antenna_length"] / per + 0.5   # [periods]; section_window (error model)
                n_end = (section["end"] - section["start"]) / per
                lo = _min(u_run)
                if lo < -slack or _max(u_run) > n_end + slack:
                    # the count says the antenna is off the loops while they still see it: the
                    # count is wrong (e.g. a slip during a bridged gap); wait for the next entry
                    mode = "lost"
                    counts["count_lost"] += 1
                else:
                    tracked.append((i0, i1, r, u_run, lo != lo))
            w_last, theta_last = float(w[-1]), float(theta[i1 - 1])
            if i1 - i0 >= 2:
                rate = (w_last - float(w[0])) / float(t[i1 - 1] - t[i0])
            prev_in, prev_rx = True, r
        # commit state
        self._mode, self._w_last, self._theta_last = mode, w_last, theta_last
        self._w_entry, self._offset, self._rate = w_entry, offset, rate
        self._in, self._rx, self._t_last = runs[-1][2], runs[-1][3], float(t[-1])
        for key, value in counts.items():
            if value:
                self.stats[key] += value
        return self._fixes(t, n, tracked) if tracked else []

    def _fixes(self, t, n, tracked):
        """PositionFixes of the tracked runs (i0, i1, receiver, u, has NaN) of a block with the
        sample times t [s]: one per fix_samples samples (0: per block) and section."""
        p = self.params
        t = t - p["detector_delay"]
        chunk = int(p["fix_samples"]) or n
        out = []
        for c0 in range(0, n, chunk):
            c1 = min(n, c0 + chunk)
            # per section: the tracked samples of the chunk as (times, u) pieces in time order
            pieces: dict = {}
            for i0, i1, r, u, has_nan in tracked:
                a, b = max(i0, c0), min(i1, c1)
                if a < b:
                    t_p, u_p = t[a:b], u[a - i0:b - i0]
                    if has_nan:   # a NaN sample is not tracked
                        keep = u_p == u_p
                        t_p, u_p = t_p[keep], u_p[keep]
                    pieces.setdefault(r, []).append((t_p, u_p))
            if sum(len(u_p) for ps in pieces.values() for _, u_p in ps) < p["min_fix_samples"]:
                continue
            for r in sorted(pieces):
                ps = pieces[r]
                k = sum(len(u_p) for _, u_p in ps)
                if k < p["min_fix_samples"] or not k:
                    continue
                if len(ps) == 1:
                    tt, u_r = ps[0]
                else:
                    tt, u_r = np.concatenate([t_p for t_p, _ in ps]), np.concatenate([u_p for _, u_p in ps])
                sec = self.sections[r]
                per = sec["period"]
                x = sec["start"] + u_r * per + p["antenna_offset"]
                tm = float(_sum(tt) / k)
                dtt = tt - tm
                xm = _sum(x) / k
                slope = float(np.dot(dtt, x - xm) / max(np.dot(dtt, dtt), 1e-12))
                direction = int(np.sign(slope)) if abs(slope) > 0.05 else 0
                span = abs(slope) * (tt[-1] - tt[0])
                sigma_s = per * p["accuracy_deg"] / 360.0 / 2.5
                periodic = min(1.0, per / (TWO_PI * span)) if span > 0 else 1.0
                sigma = fix_sigma(p, sigma_s ** 2 * (periodic ** 2 + 1.0 / k))
                out.append(PositionFix(tm, self.sensor, self.unit_id, self.track.track_id, sec["id"],
                                       float(xm), sigma, direction))
        self.stats["fixes"] += len(out)
        return out


MIN_FIX_SIGMA = 1e-4   # [m] least 1-sigma of a fix: 0.1 mm, the phase resolution of one sample (12-bit ADC:
                       # 1.2 mV of a 1 V envelope, 1.2 mrad of a 0.516 m period)


def fix_sigma(params: dict, phase_var: float = 0.0) -> float:
    """1-sigma [m] of a fix: the phase error variance ``phase_var`` [m^2] of the decoder (the
    +-8 deg spec, its periodic part averaged with the distance run, its white part with the
    samples) plus the section's fixed errors, survey of its start and the mean laying error
    of its pairs; at least MIN_FIX_SIGMA. With phase_var 0 the least a fix reports."""
    fixed = params["survey_sigma"] ** 2 + params["skew_sigma"] ** 2 / int(params["n_pairs"])
    return max(math.sqrt(phase_var + fixed), MIN_FIX_SIGMA)


def section_window(params: dict, section: dict) -> tuple[float, float]:
    """Chainages [m] between which a fix of ``section`` lies: the decoder tracks the antenna
    while its count stays within ``antenna_length`` + half a period of the loops (else the
    count is lost) and adds ``antenna_offset`` (antenna behind the front, both directions)."""
    slack = params["antenna_length"] + 0.5 * section["period"]
    return (section["start"] - slack + params["antenna_offset"], section["end"] + slack + params["antenna_offset"])


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """INPO fixes for the fusion: the section's fixed error (survey of the section start,
    mean loop-pair skew; seed 002 section 2.2.1) is common to every fix of a section,
    so it is a fix-bias state redrawn per section (reference_id); the decoder includes
    it in its stddev. Floor: the decoder's ``fix_sigma`` without the phase error (which
    averages out with the distance run and the samples of a fix). References: every
    section of the track (``section_table``), window ``section_window``."""
    fixed = math.hypot(params["survey_sigma"], params["skew_sigma"] / math.sqrt(params["n_pairs"]))
    references = None
    if track is not None:
        references = ReferenceTable({s["id"]: ReferenceWindow(*section_window(params, s))
                                     for s in section_table(track, params["period"])})
    return ErrorModel("inpo", "position", fix_bias_sigma=fixed, fix_bias_per_reference=True,
                      reported_fix_bias=fixed, faults=("outage", "offset"), min_stddev=fix_sigma(params),
                      references=references)


SPEC = SensorSpec(
    node="inpo_receiver", sensor="inpo", simulator=InpoSimulator, decoder=InpoDecoder, params=PARAMS,
    description="wayside INPO crossed inductive loops (Transrapid; MLU with 6 pairs): absolute position "
                "from the 3-phase loop signals and period counting",
    seeds=("000", "002", "003"),
    outputs=("position",), error_model=error_model,
)

"""HSST pattern belt: incremental position from an 8-shaped loop (on-board), seeds 000, 002, 003.

Principle (seed 000 section 2.2.1, seed 002 section 2.1.1, seed 003 sections 2 and
4.1): a loop laid along the guideway is widened and narrowed at equal intervals
(HSST: an 8-shaped, i.e. crossed, loop on an FRP belt) and fed with a high-frequency
carrier (seed 003: 190 kHz, loop 11.14 uH tuned with 0.062 uF). Receiving coils on
the vehicle, shaped like the loop pattern, pick up a high voltage over the wide parts
and almost none over the narrow parts. Three coils spaced p/3 give three signals
120 deg apart; after envelope detection and Schmitt triggers their switching points
divide one period p into 6 states, i.e. a resolution of p/6 (HSST: p = 0.6 m ->
10 cm, seed 000 2.2.1 and seed 002 2.1.1); the order in which the coils switch gives
the direction. Seed 003 adds the three Schmitt outputs into a p/3 pulse train (its 21 cm
adder period: a p = 0.63 m loop on a rotating disc up to 100 km/h; modelled by
``rig_loop.py``, which takes this module's field model).

Physics of the raw signal: the flux of the loop through each receiving coil is
computed from the Biot-Savart law for straight conductors (seed 003 eq. 1-3): every
wide part of the loop is a rectangle 2l x 2b; its B_z at the coil (height ``gap``)
is the sum of the finite-segment expression of seed 003 eq. 2 for the two long sides
plus the same expression for the two short sides (eq. 2 keeps only the long ones);
in the narrow parts the two wires run together and their fields cancel. In the
crossed (8-shaped) belt consecutive rectangles carry opposite currents. B_z is
integrated over the coil area (eq. 3, Gauss-Legendre 24 x 12 points) for every coil
position in one period and for a range of gaps, once per geometry (cached; < 0.5 s),
and interpolated bilinearly at run time (grid p/300 x 7 gaps; interpolation error
< 0.1 % of the peak). The coil EMF is the transformer EMF at the carrier,
|V| = omega N |psi| (the motional term of eq. 4, dpsi/dx dx/dt, is below 1e-3 of it
at these speeds: v/p << 190 kHz), so the envelope is proportional to |psi(x)|; the
amplifier gain is set so that the nominal peak is ``peak_voltage``.

Errors modelled: white noise of the receiver (in-phase and quadrature, so the
envelope is Rician; off the belt it is Rayleigh noise), the gap (antenna height)
varying around ``gap`` (AR(1): levitation/suspension), per-coil gain mismatch and
detector offset, coil mounting (spacing) error, the envelope detector's RC low-pass,
the installed belt period differing from the nominal (track entry key ``period``),
the coupling ending at the belt ends.

Decoder (vectorised): Schmitt triggers with hysteresis (``threshold_on`` /
``threshold_off`` [V]) -> 3 bits -> one of the 6 states (000 and 111 are invalid)
-> steps of +-1 state (p/6) with direction from the switching order; a change by
2 or 3 states (skipped state: speed beyond the sample rate) is illegal. When all
three envelopes are below ``loss_threshold`` the belt is absent (end of the belt,
belt fault): counting stops and restarts afresh on the belt. One DistanceIncrement
per block: signed distance = count x p/6, speed from the timing of switching points
of the same kind (whole periods, so coil tolerances cancel) or from the count. The
time of a switching point is interpolated between the two samples around the
threshold crossing (the envelope is analog), which makes the speed ~10x finer than
the 0.5 ms sample spacing would allow.

Track equipment (kind ``pattern_belt``), one entry per belt section::

    pattern_belt:
      - {id: PB01, position: 0.0, end: 1500.0}            # position = start chainage [m]
      - {id: PB02, position: 1600.0, length: 800.0, period: 0.6005}

``position`` = chainage of the belt start [m] (pattern phase 0 = start of a wide
part), ``end`` [m] or ``length`` [m] its end (default: the end of the track),
``period`` [m] the installed pattern period (default: the parameter ``period``; the
decoder always uses the parameter). No entry at all: the belt covers the whole
track, pattern origin at chainage 0. Generator entries ({every, ...}) make no sense
for a continuous belt and are not supported.

Speed limit: the decoder needs every state sampled at least once. With
``sample_rate`` 2 kHz and states at least 0.75 p/6 long this holds up to
0.75 p/6 x 2000 Hz = 150 m/s (540 km/h) for p = 0.6 m (HSST), and 52 m/s (189 km/h)
for a short p = 0.21 m belt; urban maglev runs at ~100 km/h.
Above the limit states are skipped and the decoder rejects the blocks ("implausible").
"""
from __future__ import annotations

import functools
import itertools
import math

import numpy as np

from ..signals import InputRejected, RawBlock
from ..track import Track, extent
from .base import Decoder, ErrorModel, Param, SensorSpec, Simulator, continuous_timeout, first_order_filter, gauss_markov
from .wheel import SPEED_STDDEV_FLOOR, CycleCounter, IncrementEstimator, increment_or_reject, restart_after_gap

KIND = "pattern_belt"
MIN_STATE_FRACTION = 0.75   # shortest state / (p/6) allowed for by the speed limit

PARAMS = {
    "period": Param(0.6, "nominal pattern period p [m]: HSST 0.6 m (1/6 period = 10 cm, seed 000 "
                         "2.2.1, seed 002 2.1.1); the seed 003 rig's loop 0.63 m (its adder period 0.21 m = p/3)",
                         (0.05, 5.0)),
    "wide_fraction": Param(0.5, "fraction of a period where the loop is wide [1] (widened and narrowed "
                                "at equal intervals, seed 003 section 2 / Fig. 2)", (0.01, 0.99)),
    "loop_width": Param(0.12, "width 2b of the wide parts of the loop [m] (assumed; belt of the "
                              "order of 0.1 m, seed 000 Fig. 15)", (0.01, 1.0)),
    "crossed": Param(True, "8-shaped (crossed) loop: consecutive wide parts carry opposite currents "
                           "(seed 002 2.1.1); False = plain widened/narrowed loop (seed 003)"),
    "coil_length": Param(0.0, "receiving coil length along the track [m]; 0 = wide_fraction x period "
                              "(coil shaped like the loop pattern, seed 002 2.1.1)", (0.0, 5.0)),
    "coil_width": Param(0.0, "receiving coil width [m]; 0 = loop_width", (0.0, 1.0)),
    "gap": Param(0.04, "nominal height of the coils above the loop [m] (assumed)", (1.0e-3, 0.5)),
    "gap_sigma": Param(0.002, "1-sigma variation of the gap [m] (levitation / suspension)", (0.0, 0.05)),
    "gap_tau": Param(1.0, "correlation time of the gap variation [s]", (1.0e-3, 1.0e6)),
    "antenna_offset": Param(1.0, "distance of coil 1 (the front one) behind the train front [m]; "
                                 "coils 2 and 3 follow at p/3 and 2p/3 (seed 003 section 2); within a train "
                                 "of up to 1 km", (0.0, 1000.0)),
    "spacing_error": Param(0.001, "1-sigma mounting error of each coil's position [m], per device", (0.0, 0.1)),
    "carrier_frequency": Param(190e3, "loop carrier [Hz] (seed 003 section 3.1: 190 kHz); inductive loop "
                                      "carriers 10 kHz-10 MHz", (1.0e4, 1.0e7)),
    "peak_voltage": Param(2.0, "envelope at the peak of the pattern at the nominal gap [V] "
                               "(amplifier gain set at commissioning); receiver outputs within 10 V",
                          (0.01, 10.0)),
    "gain_mismatch": Param(0.03, "1-sigma gain difference between the 3 receive chains [1], per device",
                           (0.0, 1.0)),
    "detector_offset": Param(0.01, "1-sigma DC offset of each envelope detector [V], per device", (0.0, 1.0)),
    "noise": Param(0.02, "1-sigma receiver noise per quadrature component at the detector [V] "
                         "(SNR 40 dB at the peak)", (0.0, 1.0)),
    "detector_bandwidth": Param(1000.0, "-3 dB bandwidth of the envelope detector's RC low-pass [Hz]; 1 MHz, "
                                        "beyond the carrier, is no low-pass (an ideal detector, tests)",
                                (1.0, 1.0e6)),
    "saturation": Param(5.0, "output swing of the detector [V]", (0.1, 10.0)),
    "threshold_on": Param(1.02, "Schmitt trigger: output goes high above this [V]; with threshold_off "
                                "centred on 0.97 V = 48.7 % of the peak, the level at which the default "
                                "geometry gives 50 % duty (even p/6 states)", (0.0, 10.0)),
    "threshold_off": Param(0.92, "Schmitt trigger: output goes low below this [V] (hysteresis "
                                 "0.1 V = 5 x noise)", (0.0, 10.0)),
    "loss_threshold": Param(0.4, "decoder: all three envelopes below this = no belt [V]", (0.0, 10.0)),
    "max_speed": Param(30.6, "highest speed the configuration must resolve [m/s] (110 km/h, HSST "
                             "urban maglev); the simulator refuses a sample rate that cannot; at most the "
                             "maglev speed record, 603 km/h", (0.0, 170.0)),
    "scale_sigma": Param(0.0006, "decoder: 1-sigma relative error of the installed period "
                                 "(FRP belt, thermal expansion ~1.5e-5/K over +-40 K) [1]", (0.0, 1.0)),
    "transition_jitter": Param(0.006, "decoder: 1-sigma scatter of a switching point [m] "
                                      "(noise / slope, gap and gain changes, hysteresis)", (0.0, 0.5)),
    "speed_window": Param(0.25, "decoder: longest time span of the switching points used for the "
                                "speed [s]", (1.0e-3, 10.0)),
}

DEFAULT_SAMPLE_RATE = 2000.0
"""3 envelopes at 2 kHz (6 k samples/s): every p/6 state lasts >= 1 sample up to
150 m/s for p = 0.6 m and 52 m/s for p = 0.21 m (see the module docstring)."""

# Schmitt outputs (coil1 + 2 coil2 + 4 coil3) -> position in the forward sequence
# 101 -> 100 -> 110 -> 010 -> 011 -> 001 (coil1 coil2 coil3); 000 and 111 invalid
_STATE_INDEX = np.array([-1, 1, 3, 2, 5, 0, 4, -1], dtype=np.int64)


def _output_tables() -> tuple[np.ndarray, np.ndarray]:
    """Tables indexed by y1 + 3 y2 + 9 y3 of the three Schmitt outputs y (0, 1, -1 = unknown),
    in -13..13 (a negative index counts from the end): the state index (-1 = unknown or
    invalid) and whether all are known but 000 or 111 (invalid), so that the decoder
    looks both up in one step."""
    state = np.full(27, -1, dtype=np.int64)
    invalid = np.zeros(27, dtype=bool)
    for y1, y2, y3 in itertools.product((0, 1), repeat=3):
        s = _STATE_INDEX[y1 + 2 * y2 + 4 * y3]
        state[y1 + 3 * y2 + 9 * y3] = s
        invalid[y1 + 3 * y2 + 9 * y3] = s < 0
    return state, invalid


_Y_WEIGHTS = np.array([1, 3, 9], dtype=np.int64)
_STATE_OF_Y, _INVALID_Y = _output_tables()


# --------------------------------------------------------------------------- field model
def _seg_x(x, y, z, x1, x2, y0):
    """B_z (per mu0 I / 4 pi) of a straight wire from (x1, y0, 0) to (x2, y0, 0), current +x.

    Seed 003 eq. 2 (one of its two terms): Y/(Y^2+z^2) [(x2-x)/R2 + (x-x1)/R1].
    """
    yy = y - y0
    r2 = yy * yy + z * z
    return yy / r2 * ((x2 - x) / np.sqrt((x2 - x) ** 2 + r2) + (x - x1) / np.sqrt((x - x1) ** 2 + r2))


def _seg_y(x, y, z, y1, y2, x0):
    """B_z (per mu0 I / 4 pi) of a straight wire from (x0, y1, 0) to (x0, y2, 0), current +y."""
    xx = x - x0
    r2 = xx * xx + z * z
    return -xx / r2 * ((y2 - y) / np.sqrt((y2 - y) ** 2 + r2) + (y - y1) / np.sqrt((y - y1) ** 2 + r2))


def rectangle_bz(x, y, z, xc, l, b):
    """B_z (per mu0 I / 4 pi) of a rectangular loop 2l x 2b centred at (xc, 0), counter-clockwise."""
    return (_seg_x(x, y, z, xc - l, xc + l, -b) - _seg_x(x, y, z, xc - l, xc + l, b)
            + _seg_y(x, y, z, -b, b, xc + l) - _seg_y(x, y, z, -b, b, xc - l))


@functools.lru_cache(maxsize=32)
def flux_table(period: float, wide_fraction: float, loop_width: float, coil_length: float,
               coil_width: float, crossed: bool, gaps: tuple[float, ...], nx: int = 300,
               neighbours: int = 3) -> np.ndarray:
    """Flux through one coil per unit loop current [Wb/A], shape (len(gaps), nx).

    Column j is the coil centre at j/nx of a period from the start of a wide part.
    Seed 003 eq. 3: psi = integral of B_z over the coil area.
    """
    mu0_4pi = 1e-7
    u = np.arange(nx) * period / nx
    gx, wx = np.polynomial.legendre.leggauss(24)
    gy, wy = np.polynomial.legendre.leggauss(12)
    xs = u[:, None, None] + 0.5 * coil_length * gx[None, :, None]
    ys = 0.5 * coil_width * gy[None, None, :]
    w = 0.25 * coil_length * coil_width * wx[None, :, None] * wy[None, None, :]
    l, b = 0.5 * wide_fraction * period, 0.5 * loop_width
    out = np.empty((len(gaps), nx))
    for i, z in enumerate(gaps):
        bz = 0.0
        for k in range(-neighbours, neighbours + 2):
            sign = (-1.0) ** k if crossed else 1.0
            bz = bz + sign * rectangle_bz(xs, ys, z, k * period + l, l, b)
        out[i] = mu0_4pi * (bz * w).sum(axis=(1, 2))
    return out


def table_lookup(table: np.ndarray, frac: np.ndarray, gap: np.ndarray, gaps: tuple) -> np.ndarray:
    """Bilinear interpolation of a (gap, place in the period) table (its last column the first
    again) at fractions ``frac`` [0, 1) of the period and gaps [m] (clipped to the evenly spaced
    ``gaps`` of its rows)."""
    nx = table.shape[1] - 1
    fx = frac * nx
    jx = np.minimum(fx.astype(np.int64), nx - 1)
    wx = fx - jx
    gz = (np.clip(gap, gaps[0], gaps[-1]) - gaps[0]) / (gaps[1] - gaps[0])
    jz = np.minimum(gz.astype(np.int64), len(gaps) - 2)
    wz = gz - jz
    return ((1 - wz) * ((1 - wx) * table[jz, jx] + wx * table[jz, jx + 1])
            + wz * ((1 - wx) * table[jz + 1, jx] + wx * table[jz + 1, jx + 1]))


def geometry(params: dict) -> dict:
    """Resolved loop/coil geometry of a parameter set."""
    p = params["period"]
    return {
        "period": p, "wide_fraction": params["wide_fraction"], "loop_width": params["loop_width"],
        "coil_length": params["coil_length"] or params["wide_fraction"] * p,
        "coil_width": params["coil_width"] or params["loop_width"], "crossed": bool(params["crossed"]),
    }


def _flux_row(params: dict, gap: float) -> np.ndarray:
    """|flux| of a coil over one period (the simulator's table row, unnormalised) at ``gap`` [m]."""
    g = geometry(params)
    return np.abs(flux_table(g["period"], g["wide_fraction"], g["loop_width"], g["coil_length"],
                             g["coil_width"], g["crossed"], (float(gap),))[0])


def envelope_profile(params: dict, gap: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(position in the period [m], normalised envelope |psi|/max) at a gap (default nominal).

    For commissioning: the Schmitt thresholds should straddle the level at which the
    envelope is high half of the period (even p/6 states).
    """
    tab = _flux_row(params, params["gap"] if gap is None else gap)
    return np.arange(tab.size) * geometry(params)["period"] / tab.size, tab / tab.max()


def half_duty_level(params: dict) -> float:
    """Envelope level [V] above which a coil is half of the period (nominal gap)."""
    _, env = envelope_profile(params)
    return float(np.median(env)) * params["peak_voltage"]


def transition_unevenness(params: dict) -> float:
    """1-sigma offset [m] of a switching point from the even p/6 grid: the coil's mounting
    error, its receive chain's gain mismatch and detector offset moving the threshold crossing
    along the envelope's slope (fixed per coil and switching direction), and the levitation
    gap's variation ``gap_sigma`` changing the envelope's level, which lengthens the high states
    and shortens the low ones (or the reverse) for as long as it lasts (``gap_tau``)."""
    nominal = _flux_row(params, params["gap"])
    period = geometry(params)["period"]
    x = np.arange(nominal.size) * period / nominal.size
    gain = params["peak_voltage"] / nominal.max()       # the amplifier's, set for the nominal gap
    level = nominal * gain
    mid = 0.5 * (params["threshold_on"] + params["threshold_off"])
    crossing = np.nonzero(np.diff(np.sign(level - mid)))[0]
    slope = float(np.min(np.abs(np.gradient(level, x)[crossing])))

    def high(row):   # fraction of the period a coil is high
        return float(np.mean(row * gain > mid))
    # the gap term: the high state's length changes with the gap (+- gap_sigma). A rising and a
    # falling switching point move apart by twice the shift of one, so an increment between the
    # two errs by 2 x shift; with the edges taken as independent (IncrementEstimator) each
    # carries sqrt(2) x shift so that such an increment gets that 1-sigma
    gap_shift = max(abs(high(_flux_row(params, max(params["gap"] + s * params["gap_sigma"], 1.0e-4)))
                        - high(nominal)) for s in (-1.0, 1.0)) * period / 2.0
    return math.sqrt(params["spacing_error"] ** 2 + (params["gain_mismatch"] * mid / slope) ** 2
                     + (params["detector_offset"] / slope) ** 2 + 2.0 * gap_shift ** 2)


def belt_sections(track: Track, default_period: float) -> np.ndarray:
    """(start, end, period) rows of the belt sections, sorted; whole track if none."""
    rows = []
    for item in track.items(KIND):
        start, end = extent(KIND, item, default_end=track.length)
        period = float(item.get("period", default_period))
        if end <= start or period <= 0:
            raise ValueError(f"pattern belt {item['id']}: needs end > position and period > 0")
        rows.append((start, min(end, track.length), period))
    if not rows:
        rows = [(0.0, track.length, default_period)]
    rows.sort()
    arr = np.array(rows, dtype=float)
    if np.any(arr[1:, 0] < arr[:-1, 1] - 1e-9):
        raise ValueError("pattern belt sections overlap")
    return arr


def resolvable_speed(sample_rate: float, period: float) -> float:
    """Highest speed [m/s] at which every p/6 state (>= 0.75 p/6 long) lasts one sample."""
    return sample_rate * MIN_STATE_FRACTION * period / 6.0


class PatternBeltSimulator(Simulator):
    sensor = "pattern_belt"
    channels = ("coil_1", "coil_2", "coil_3")
    units = ("V", "V", "V")
    adc_lsb = {"V": 5.0 / 4096}  # 12-bit ADC over 0..5 V (the detector saturates at 5 V)
    default_sample_rate = DEFAULT_SAMPLE_RATE

    def __init__(self, *args):
        super().__init__(*args)
        p = self.params
        period = p["period"]
        v_res = resolvable_speed(self.sample_rate, period)
        if v_res < p["max_speed"]:
            raise ValueError(f"pattern_belt: {self.sample_rate:.0f} Hz resolves p/6 states of a {period} m "
                             f"pattern only up to {v_res:.1f} m/s < max_speed {p['max_speed']} m/s")
        self.sections = belt_sections(self.track, period)
        g = geometry(p)
        z0 = p["gap"]
        self._gaps = tuple(float(z) for z in z0 * np.linspace(0.7, 1.3, 7))
        tab = np.abs(flux_table(g["period"], g["wide_fraction"], g["loop_width"], g["coil_length"],
                                g["coil_width"], g["crossed"], self._gaps))
        # the amplifier gain makes the nominal peak = peak_voltage; omega N I folded in
        self._table = tab * (p["peak_voltage"] / _flux_row(p, z0).max())
        self._table = np.concatenate([self._table, self._table[:, :1]], axis=1)  # wrap column
        self.gain = 1.0 + self.rng.normal(0.0, p["gain_mismatch"], 3)
        self.offset = self.rng.normal(0.0, p["detector_offset"], 3)
        self.coil_positions = (p["antenna_offset"] + np.arange(3) * period / 3.0
                               + self.rng.normal(0.0, p["spacing_error"], 3))  # behind the front [m]
        self._gap_dev = float(self.rng.normal(0.0, p["gap_sigma"]))
        self._lp_zi = np.zeros((3, 1))

    def _amplitude(self, x: np.ndarray, gap: np.ndarray) -> np.ndarray:
        """Noise-free envelope [V] of a coil centred at chainages x, at gaps [m]."""
        sec = self.sections
        i = np.searchsorted(sec[:, 0], x, side="right") - 1
        ic = np.clip(i, 0, len(sec) - 1)
        inside = (i >= 0) & (x < sec[ic, 1])
        frac = np.mod((x - sec[ic, 0]) / sec[ic, 2], 1.0)
        return np.where(inside, table_lookup(self._table, frac, gap, self._gaps), 0.0)

    def samples(self, times, position, speed, acceleration):
        p = self.params
        n = len(times)
        dt = 1.0 / self.sample_rate
        dev = gauss_markov(self.rng, p["gap_sigma"], p["gap_tau"], dt, n, self._gap_dev)
        self._gap_dev = float(dev[-1])
        gap = p["gap"] + dev
        noise = self.rng.normal(0.0, p["noise"], (2, n, 3))
        alpha = math.exp(-2.0 * math.pi * p["detector_bandwidth"] * dt)
        out = np.empty((n, 3))
        for k in range(3):
            amp = self._amplitude(position - self.coil_positions[k], gap) * self.gain[k]
            env = np.hypot(amp + noise[0, :, k], noise[1, :, k]) + self.offset[k]
            env, self._lp_zi[k] = first_order_filter([1.0 - alpha], [1.0, -alpha], env, self._lp_zi[k])
            out[:, k] = env
        return np.clip(out, 0.0, p["saturation"])


class PatternBeltDecoder(Decoder):
    sensor = "pattern_belt"
    channels = PatternBeltSimulator.channels

    def __init__(self, params, track):
        super().__init__(params, track)
        p = self.params
        if not p["threshold_on"] > p["threshold_off"] > 0.0:
            raise ValueError("pattern_belt: needs threshold_on > threshold_off > 0")
        self.step = p["period"] / 6.0
        self.counter = CycleCounter(6, history=max(1.0, 2 * p["speed_window"]))
        self.estimator = IncrementEstimator(self.sensor, self.unit_id, self.counter, self.step, self.step,
                                            p["scale_sigma"], p["speed_window"],
                                            position_jitter=p["transition_jitter"], timing_sigma=0.05,
                                            unevenness=transition_unevenness(p), settles=True)
        self._y = np.full(3, -1, dtype=np.int64)   # Schmitt outputs (-1 unknown)
        self._env_last: np.ndarray | None = None   # last envelope sample of the previous block
        self._rows = np.empty((0, 1), dtype=np.int64)  # 1..n as a column (Schmitt trigger)
        self._cols = np.arange(3)
        self._offsets_key: tuple | None = None
        self._offsets = np.empty(0)
        self._t_next: float | None = None
        self.stats = {"transitions": 0, "illegal_transitions": 0, "gaps": 0, "no_belt_samples": 0,
                      "invalid_states": 0}

    @property
    def count(self) -> int:
        """Cumulative signed count of p/6 steps since start."""
        return self.counter.count

    def _schmitt(self, env: np.ndarray) -> np.ndarray:
        """Schmitt trigger outputs (0/1, -1 unknown) per sample and coil; keeps the last ones."""
        p = self.params
        on = env > p["threshold_on"]
        off = env < p["threshold_off"]
        n = env.shape[0]
        if self._rows.shape[0] != n:
            self._rows = np.arange(1, n + 1)[:, None]
        # row (1-based) of the last sample at or before each one that was outside the
        # hysteresis band; row 0 = the outputs at the end of the previous block
        last = np.where(on | off, self._rows, 0)
        np.maximum.accumulate(last, axis=0, out=last)
        out = np.empty((n + 1, env.shape[1]), dtype=np.int64)
        out[0] = self._y
        out[1:] = on
        y = out[last, self._cols]
        self._y = y[-1].copy()
        return y

    def _crossing_times(self, times: np.ndarray, env: np.ndarray, y: np.ndarray, y_before: np.ndarray,
                        env_before: np.ndarray, dt: float, k: np.ndarray) -> np.ndarray:
        """At samples ``k``: time at which a Schmitt output that switched at the sample crossed
        its threshold, interpolated linearly between the sample and the one before [s]; the
        mean if several switched, half a sample before the sample if none did.
        ``env_before``, ``y_before``: the last envelopes and outputs of the previous block.

        Called for the samples where the state changes: usually a few, so plain Python;
        many (high speed) or a mean of three crossings (the order of the sum matters) are
        left to the vectorised version.
        """
        if len(k) > 20:
            return self._crossing_times_all(times, env, y, y_before, env_before, dt)[k]
        on, off = self.params["threshold_on"], self.params["threshold_off"]
        prev_env, prev_y = env[k - 1].tolist(), y[k - 1].tolist()
        if k[0] == 0:
            prev_env[0], prev_y[0] = env_before.tolist(), y_before.tolist()
        out = []
        for t, e, pe, yk, py in zip(times[k].tolist(), env[k].tolist(), prev_env, y[k].tolist(), prev_y):
            cross = []
            for c in range(len(e)):
                if yk[c] + py[c] == 1:  # switched: 0 -> 1 or 1 -> 0 (-1 = unknown)
                    denom = e[c] - pe[c]
                    frac = ((on if yk[c] == 1 else off) - pe[c]) / denom if denom != 0 else 0.5
                    cross.append(t - dt + min(max(frac, 0.0), 1.0) * dt)
            if not cross:
                out.append(t - 0.5 * dt)
            elif len(cross) == 1:
                out.append(cross[0])
            elif len(cross) == 2:
                out.append((cross[0] + cross[1]) / 2)
            else:
                return self._crossing_times_all(times, env, y, y_before, env_before, dt)[k]
        return np.array(out)

    def _crossing_times_all(self, times: np.ndarray, env: np.ndarray, y: np.ndarray, y_before: np.ndarray,
                            env_before: np.ndarray, dt: float) -> np.ndarray:
        """_crossing_times at every sample of the block, vectorised."""
        p = self.params
        prev_env = np.vstack([env_before[None, :], env[:-1]])
        prev_y = np.vstack([y_before[None, :], y[:-1]])
        switched = (y != prev_y) & (y >= 0) & (prev_y >= 0)
        thr = np.where(y == 1, p["threshold_on"], p["threshold_off"])
        denom = env - prev_env
        frac = np.clip(np.divide(thr - prev_env, denom, out=np.full(env.shape, 0.5), where=denom != 0), 0.0, 1.0)
        t_cross = times[:, None] - dt + frac * dt
        n_sw = switched.sum(axis=1)
        mean_cross = np.where(switched, t_cross, 0.0).sum(axis=1) / np.maximum(n_sw, 1)
        return np.where(n_sw > 0, mean_cross, times - 0.5 * dt)

    def decode(self, block: RawBlock):
        p = self.params
        env = block.data.astype(float)
        row_max = env.max(axis=1)
        env_min, env_max = env.min(), row_max.max()
        if env_min < -0.5 or env_max > p["saturation"] + 0.5:
            raise InputRejected("implausible", f"envelope {env_min:.2f}..{env_max:.2f} V outside the "
                                f"detector's 0..{p['saturation']} V")
        fs = block.sample_rate
        if restart_after_gap(self, block):
            self._y[:] = -1
            self._env_last = None
        y_before = self._y.copy()
        env_before = self._env_last[0] if self._env_last is not None else env[0]
        y = self._schmitt(env)
        n = env.shape[0]
        if self._offsets_key != (n, fs):
            self._offsets_key = (n, fs)
            self._offsets = np.arange(n) / fs   # sample times - t0 [s], as RawBlock.times
        times = block.t0 + self._offsets
        # crossing times are needed only where the state changes: feed asks for those
        crossing = functools.partial(self._crossing_times, times, env, y, y_before, env_before, 1.0 / fs)
        self._env_last = env[-1:].copy()
        lost = row_max < p["loss_threshold"]
        n_lost = int(np.count_nonzero(lost))
        code = y @ _Y_WEIGHTS
        state = _STATE_OF_Y[code]
        invalid_state = _INVALID_Y[code]
        if n_lost:
            state[lost] = -1
            invalid_state &= ~lost
        invalid = int(np.count_nonzero(invalid_state))
        self.stats["no_belt_samples"] += n_lost
        self.stats["invalid_states"] += invalid
        res = self.counter.feed(times, state, lost if n_lost else None, sample_period=1.0 / fs,
                                crossing_times=crossing)
        self.stats["transitions"] += res.transitions
        self.stats["illegal_transitions"] += res.illegal
        on_belt = n - n_lost
        if on_belt and invalid > 0.45 * on_belt:
            self.counter.reset()
            self.estimator.reset()
            raise InputRejected("implausible", f"{invalid} of {on_belt} samples with all or none of the coils "
                                "switched on: stuck channel or mis-set thresholds")
        return increment_or_reject(self.counter, self.estimator, res, fs, max(1, 0.1 * res.transitions),
                                   "state changes", "coil")


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """Belt errors for the fusion: the installed period's relative error ``scale_sigma``
    (constant along a belt section, reported inside the decoder's stddev); contactless,
    so no slip."""
    return ErrorModel("pattern_belt", "distance", scale_sigma=params["scale_sigma"],
                      reported_scale=params["scale_sigma"], timeout=continuous_timeout(params),
                      min_stddev=SPEED_STDDEV_FLOOR)   # wheel.IncrementEstimator.make's floor of both stddevs


SPEC = SensorSpec(
    node="pattern_belt", sensor="pattern_belt", simulator=PatternBeltSimulator, decoder=PatternBeltDecoder,
    params=PARAMS, description="HSST pattern belt (8-shaped HF loop, 3 coils at p/3): signed distance "
    "increments at p/6 resolution, from switching point to switching point, and speed",
    seeds=("000", "002", "003"),
    outputs=("distance",), error_model=error_model,
)

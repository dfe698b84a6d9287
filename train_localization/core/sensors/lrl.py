"""INKREFA Location Reference Lug (LRL) scanner (on-board), seeds 002 and 000.

Principle (seed 002 sections 2.2.1 and 3.1, seed 000 section 2.1.2): lugs of
conductive material carrying 4 bits each are fixed to the guideway; a U-shaped
sensor on the vehicle head has transmit/receive channels across its slot; the lug
passing through the slot attenuates the HF signal of a channel wherever it has
conductive material, so the receive level drops from ~1 to ~0. The sensor has two
kinds of channels, 10 in all (5 used per scan mode):

  * single scan: P1..P4 data channels + D0 sync channel; when D0 goes to 0 the four
    P channels are read at once (the 4 bits of the lug);
  * continuous scan: N1..N4 sync channels + D1 data channel; as N4, N3, N2, N1 in turn
    reach the threshold, D1 is read bit by bit;
  * the direction of travel follows from the order in which the channels see the lug;
  * a group of LRLs extends the code (4 bits per lug); 4 redundant sensors are mounted
    on the vehicle head.

Geometry (the seeds give no dimensions; the values below are assumptions sized so
that 1 kHz sampling resolves a lug at 500 km/h: 139 mm per sample). Offsets o are
along the track from the sensor reference point (+ = towards increasing chainage,
the vehicle front), lug coordinates from the lug reference point (its sync mark):

  continuous scan (bit pitch p = ``bit_pitch``, default 0.35 m):
    N1..N4 at o = -1.5p, -0.5p, +0.5p, +1.5p (N4 leads when moving forwards), D1 at 0;
    lug: sync tab [-(p+0.05)/2, (p+0.05)/2] read by N; data row of 4 cells of length p
    centred at c_j = (j - 1.5)p, cell j conductive iff bit j = 1. N4 over the tab puts
    D1 over cell 0, N3 -> cell 1, N2 -> cell 2, N1 -> cell 3 (seed 002 Fig. 7). Moving
    backwards N1 leads and D1 reads the cells in the order 3, 2, 1, 0: the decoder maps
    each read to its cell by the channel geometry, so the code comes out in lug order
    in both directions.
  single scan (channel pitch q = 0.2 m):
    P1..P4 at o = +1.5q, +0.5q, -0.5q, -1.5q, D0 at 0;
    lug: D0 row a sync tab [-0.25, 0.25] m; each P row a plate [-0.7, 0.7] m with a
    0.4 m hole centred at o_i where bit i is 0. When D0 is over its tab, P_i is over
    the centre of its hole position (seed 002 Fig. 6). The plate edges pass P1..P4 in
    order moving forwards and in reverse order moving backwards (direction).

Bit j of a lug is bit (3 - j) of its 4-bit value: bit 0 (most significant) is cell 0
(lowest chainage) in continuous scan and row P1 in single scan.

Raw signal (default 1 kHz; ``n_sensors`` x 5 channels, 20 k samples/s for 4 sensors):
channels ``s<k>_<name>`` (P1 P2 P3 P4 D0, or N1 N2 N3 N4 D1) per sensor k: receive
level [1] = gain_k (1 - attenuation x coverage) + white noise. Coverage is the
conductive fraction of the channel's footprint, a linear ramp of ``edge_width`` at
every edge. Per sensor gain error ``gain_sigma``. Misreads: with probability
``misread_probability`` per sensor and lug passage one bit of that sensor reads
inverted (dirt, ice, a foreign metal part, a weak channel).

Decoder: a lug passage is a run of samples in which any channel is in the "lug" state
(level below ``threshold``, with +-0.2 hysteresis). Per sensor, every threshold
crossing of a sync or plate channel (N1..N4; or D0 and the plate edges of P1..P4),
interpolated along its ramp, is a point (ref, t): the channel at offset o meets the
lug edge e when the sensor reference point is at ref = e - o. The order in which the
channels see the lug gives the direction; a line t(ref) through the points (a
quadratic when the train accelerates over the lug) gives the time t(0) at which the
sensor passed the sync mark, the speed 1/t'(0) and the read instants: t(0) for
P1..P4 (the D0 pulse centre), t(c_j) for D1 cell j (N4, N3, N2, N1 over the tab).
Vote over the valid sensors: the value of a strict majority of them, read by at least
two (on a head of ``n_sensors`` >= 2: one valid read is confirmed by nothing,
``stats["unconfirmed_lugs"]``); else the lug is unresolved (``stats["unresolved_lugs"]``)
and its group gives no fix -- two sensors that disagree, 2-2 or 2-1-1 on four sensors
cannot tell which one misread, and taking the larger group of a split would turn one more
misread into a fix at another group. Every disagreement is counted
(``stats["sensor_disagreements"]``). Lugs less than ``group_gap`` apart form a
group; travelling backwards the lug order is reversed to the track's order; the code
is looked up in the track's ``lrl_group`` list -> PositionFix of the train front =
chainage of the lug last read + ``sensor_offset``, stamped when the sensor passed it.
A code not in the track -> InputRejected("unknown_id").

Track equipment (kind ``lrl_group``)::

    lrl_group:
      - {id: LRL12, position: 1500.0, code: [3, 12, 7], spacing: 3.0}
      - {every: 500.0, start: 100.0, end: 9600.0, id: "LRL{n:03d}", lugs: 3}

``position``: chainage of the first lug's sync mark (lowest chainage) [m]; lug k at
position + k x spacing; ``code``: 4-bit values 0..15 in chainage order; ``spacing``
[m] (default: parameter ``lug_spacing``; at least 2 x lug_extent() + 0.5 m, 2.5 m with
the default geometry, so that the sensor never sees two lugs at once). Without ``code`` (e.g.
generated entries) the code is the number in the id (n of "LRL{n:03d}"), scrambled by
an odd multiplier mod 16^lugs, in ``lugs`` (default ``lugs_per_group``) hex digits.
"""
from __future__ import annotations

import hashlib
import math
import re

import numpy as np

from ..measurements import PositionFix
from ..signals import InputRejected, RawBlock
from ..track import nearby_runs
from .base import MIN_FIX_SIGMA, Decoder, ErrorModel, Param, ReferenceTable, ReferenceWindow, SensorSpec, Simulator

KIND = "lrl_group"
Q_PITCH = 0.2                # single-scan P-channel pitch [m]
D0_HALF = 0.25               # single-scan sync tab half-length [m]
PLATE_HALF = 0.7             # single-scan plate half-length [m]
HOLE_HALF = 0.2              # single-scan bit-0 hole half-length [m]
READ_HALF = 0.05             # data channels are read within +-5 cm of the read point [m]
CODE_SCRAMBLE = 0x9E3779B1   # odd multiplier: bijection of the id numbers mod 16^lugs

MODES = ("single", "continuous")
CHANNEL_NAMES = {"single": ("P1", "P2", "P3", "P4", "D0"), "continuous": ("N1", "N2", "N3", "N4", "D1")}

PARAMS = {
    "scan_mode": Param("single", "scan mode of the U-sensor: 'single' (P1..P4 + D0 sync) or 'continuous' "
                                 "(N1..N4 sync + D1 data), seed 002 section 3.1"),
    "n_sensors": Param(4, "redundant sensors on the vehicle head [1] (seed 002 section 2.2.1: 4), all at the "
                          "same along-track position", (1, 8)),
    "sensor_offset": Param(1.5, "distance of the sensor reference point behind the train front [m] "
                                "(on the vehicle head; assumption); within a train of up to 1 km", (0.0, 1000.0)),
    "lug_spacing": Param(3.0, "default spacing of the lugs of a group [m] (assumption; >= 2.5 m)", (0.1, 100.0)),
    "lugs_per_group": Param(3, "lugs of a group without an explicit code [1] (12 bits = 4096 codes)", (1, 16)),
    "bit_pitch": Param(0.35, "continuous scan: data cell length = N-channel pitch [m] (assumption: >= 2.5 "
                             "samples per cell at 500 km/h and 1 kHz)", (0.01, 2.0)),
    "edge_width": Param(0.02, "width of the level ramp at a lug edge (channel footprint) [m] (assumption)",
                        (1.0e-4, 0.5)),
    "attenuation": Param(0.95, "fraction of the HF signal a conductive lug blocks [1] (level ~1 -> ~0.05)",
                         (0.01, 1.0)),
    "level_noise": Param(0.05, "1-sigma white noise of a receive level [1] (assumption: 26 dB SNR)", (0.0, 1.0)),
    "gain_sigma": Param(0.05, "1-sigma gain error of one sensor [1] (assumption)", (0.0, 1.0)),
    "threshold": Param(0.5, "receive level below which a channel sees conductive material [1]", (0.0, 1.0)),
    "misread_probability": Param(1e-3, "probability that one sensor reads one bit of a lug wrong [1] "
                                       "(dirt, ice, foreign metal; assumption)", (0.0, 1.0)),
    "install_sigma": Param(0.005, "1-sigma error of a lug's real position vs the track file [m] "
                                  "(guideway manufacturing tolerance; assumption)", (0.0, 1.0)),
    "group_gap": Param(10.0, "a group is closed when the train has moved this far past its last lug [m]",
                       (0.1, 1000.0)),
}


# ----------------------------------------------------------------------------------
# Track equipment
# ----------------------------------------------------------------------------------

def group_code(item: dict, lugs_per_group: int = 3) -> tuple[int, ...]:
    """4-bit lug values of an ``lrl_group`` entry, in chainage order (see module doc)."""
    if "code" in item:
        code = item["code"]
        if isinstance(code, (int, np.integer)):
            code = [int(code)]
        code = tuple(int(c) for c in code)
        if not code or any(not 0 <= c <= 15 for c in code):
            raise ValueError(f"lrl_group {item['id']}: code {item['code']!r} must be 4-bit values 0..15")
        return code
    lugs = int(item.get("lugs", lugs_per_group))
    m = re.search(r"(\d+)$", str(item["id"]))
    number = int(m.group(1)) if m else int.from_bytes(hashlib.sha256(str(item["id"]).encode()).digest()[:8],
                                                     "little")
    value = (number * CODE_SCRAMBLE) % (16 ** lugs)
    return tuple((value >> (4 * (lugs - 1 - k))) & 15 for k in range(lugs))


def lug_extent(mode: str = "single", bit_pitch: float = 0.35) -> float:
    """Largest distance [m] between the sensor reference point and a lug's sync mark at
    which some channel still sees the lug."""
    if mode == "single":
        return 1.5 * Q_PITCH + PLATE_HALF
    return max(1.5 * bit_pitch + 0.5 * (bit_pitch + 0.05), 2.0 * bit_pitch)


def track_groups(track, params: dict) -> list[tuple[dict, tuple[int, ...], float]]:
    """(item, code, spacing) of every LRL group of the track; spacing checked."""
    out = []
    min_spacing = 2.0 * lug_extent(params.get("scan_mode", "single"), params.get("bit_pitch", 0.35)) + 0.5
    for item in track.items(KIND):
        code = group_code(item, params["lugs_per_group"])
        spacing = float(item.get("spacing", params["lug_spacing"]))
        if len(code) > 1 and spacing < min_spacing:
            raise ValueError(f"lrl_group {item['id']}: lug spacing {spacing} m < {min_spacing:.2f} m")
        out.append((item, code, spacing))
    return out


def nibble_bits(value: int) -> tuple[int, int, int, int]:
    """Bits 0..3 of a lug value (bit 0 = most significant)."""
    return tuple((value >> (3 - j)) & 1 for j in range(4))


def channel_offsets(mode: str, bit_pitch: float) -> np.ndarray:
    """Along-track offsets [m] of the 5 channels of one sensor, in CHANNEL_NAMES order."""
    if mode == "single":
        return np.array([1.5, 0.5, -0.5, -1.5, 0.0]) * np.array([Q_PITCH] * 4 + [1.0])
    return np.array([-1.5, -0.5, 0.5, 1.5, 0.0]) * np.array([bit_pitch] * 4 + [1.0])


def _ramp(x, e):
    return np.clip(x / e + 0.5, 0.0, 1.0)


def _cover(x, a, b, e):
    """Fraction of a channel footprint at x covered by conductive material on [a, b]."""
    return _ramp(x - a, e) - _ramp(x - b, e)


def _check_mode(mode: str) -> str:
    if mode not in MODES:
        raise ValueError(f"scan_mode {mode!r}: must be one of {MODES}")
    return mode


def _channels(mode: str, n_sensors: int) -> tuple[str, ...]:
    return tuple(f"s{k}_{name}" for k in range(n_sensors) for name in CHANNEL_NAMES[mode])


# ----------------------------------------------------------------------------------
# Simulator
# ----------------------------------------------------------------------------------

class LrlSimulator(Simulator):
    sensor = "lrl"
    channels = ()
    units = ()
    adc_lsb = {"1": 1 / 1024}  # 10-bit conversion of the normalised receive level
    default_sample_rate = 1000.0

    def __init__(self, *args):
        super().__init__(*args)
        p = self.params
        self.mode = _check_mode(p["scan_mode"])
        self.n_sensors = int(p["n_sensors"])
        if self.n_sensors < 1:
            raise ValueError("n_sensors must be >= 1")
        self.channels = _channels(self.mode, self.n_sensors)
        self.units = ("1",) * len(self.channels)
        self.offsets = channel_offsets(self.mode, p["bit_pitch"])
        pos, bits = [], []
        for item, code, spacing in track_groups(self.track, p):
            for k, value in enumerate(code):
                pos.append(item["position"] + k * spacing)
                bits.append(nibble_bits(value))
        pos = np.array(pos, dtype=float) + self.rng.normal(0.0, p["install_sigma"], len(pos))
        order = np.argsort(pos, kind="stable")
        self._pos = pos[order]
        self._bits = np.array(bits, dtype=float).reshape(-1, 4)[order]
        self._gain = np.maximum(0.5, 1.0 + p["gain_sigma"] * self.rng.normal(size=self.n_sensors))
        self._passage: tuple[int, np.ndarray] | None = None    # (lug index, flip mask per sensor)
        self._near = lug_extent(self.mode, p["bit_pitch"]) + 0.2

    def flips(self) -> np.ndarray:
        """Bit-flip mask (n_sensors, 4) of one lug passage: each sensor misreads one bit with
        ``misread_probability`` (a study forcing a misread pattern replaces this method)."""
        mask = np.zeros((self.n_sensors, 4))
        for s in range(self.n_sensors):
            if self.rng.random() < self.params["misread_probability"]:
                mask[s, self.rng.integers(4)] = 1.0
        return mask

    def coverage(self, u: np.ndarray, bits: np.ndarray) -> np.ndarray:
        """Coverage (n, n_sensors, 5) of the channels for sensor-to-lug offsets u (n,) [m]
        and effective bits (n, n_sensors, 4) of the lug in front of each sensor."""
        p = self.params
        e = p["edge_width"]
        n = len(u)
        cov = np.zeros((n, self.n_sensors, 5))
        if self.mode == "single":
            for i in range(4):
                x = (u + self.offsets[i])[:, None]
                o = self.offsets[i]
                plate = _cover(x, -PLATE_HALF, PLATE_HALF, e)
                hole = _cover(x, o - HOLE_HALF, o + HOLE_HALF, e)
                cov[:, :, i] = plate - hole * (1.0 - bits[:, :, i])
            cov[:, :, 4] = _cover(u, -D0_HALF, D0_HALF, e)[:, None]
        else:
            pitch = p["bit_pitch"]
            half_tab = 0.5 * (pitch + 0.05)
            for i in range(4):
                cov[:, :, i] = _cover(u + self.offsets[i], -half_tab, half_tab, e)[:, None]
            d1 = np.zeros((n, self.n_sensors))
            for j in range(4):
                c = (j - 1.5) * pitch
                d1 += bits[:, :, j] * _cover(u, c - 0.5 * pitch, c + 0.5 * pitch, e)[:, None]
            cov[:, :, 4] = np.clip(d1, 0.0, 1.0)
        return cov

    def samples(self, times, position, speed, acceleration):
        p = self.params
        n = len(times)
        cov = np.zeros((n, self.n_sensors, 5))
        if self._pos.size:
            ref = position - p["sensor_offset"]
            u, runs = nearby_runs(self._pos, ref, self._near)
            bits = np.zeros((n, self.n_sensors, 4))
            for r0, r1, kk in runs:
                if kk < 0:
                    self._passage = None
                    continue
                if self._passage is None or self._passage[0] != kk or r0 != 0:
                    self._passage = (kk, self.flips())
                eff = np.abs(self._bits[kk][None, :] - self._passage[1])        # XOR
                bits[r0:r1] = eff[None, :, :]
            cov = self.coverage(u, bits)
        level = self._gain[None, :, None] * (1.0 - p["attenuation"] * cov)
        level = level + self.rng.normal(0.0, p["level_noise"], level.shape)
        return level.reshape(n, -1)


# ----------------------------------------------------------------------------------
# Decoder
# ----------------------------------------------------------------------------------

def hysteresis(lev: np.ndarray, lo: float, hi: float, init: np.ndarray) -> np.ndarray:
    """Channel states (True = conductive material seen) of levels (n, C): a channel goes
    low below ``lo`` and high again above ``hi``; ``init`` (C,) is the state before."""
    n, c = lev.shape
    st = np.where(lev < lo, 1, np.where(lev > hi, 0, -1))
    idx = np.where(st >= 0, np.arange(n)[:, None], -1)
    idx = np.maximum.accumulate(idx, axis=0)
    return np.where(idx >= 0, st[np.maximum(idx, 0), np.arange(c)[None, :]] == 1, init[None, :])


def _median(values: list) -> float:
    """Median of a non-empty list of floats, as np.median (the mean of the two middle
    values for an even count)."""
    v = sorted(values)
    h = len(v) // 2
    return v[h] if len(v) % 2 else (v[h - 1] + v[h]) / 2


def vote(values: list) -> tuple:
    """(value read by most sensors, how many read it) of a non-empty list of lug values;
    a tie goes to the larger value (it is no majority anyway)."""
    count, best = max((values.count(x), x) for x in set(values))
    return best, count


def _ramp_crossing(t: np.ndarray, lev: np.ndarray, i0: int, i1: int, thr: float) -> float:
    """Time at which the level crosses thr on the ramp of samples i0..i1 (inclusive): a
    straight line fitted to the ramp samples (2 samples at speed: linear interpolation)."""
    if i1 - i0 == 1:                          # two samples: linear interpolation
        a, b = lev[i0], lev[i1]
        return float(t[i1] if a == b else t[i0] + (a - thr) / (a - b) * (t[i1] - t[i0]))
    tt, ll = t[i0:i1 + 1], lev[i0:i1 + 1]
    if len(tt) < 2:
        return float(tt[0])
    tm, lm = tt.mean(), ll.mean()
    dt_ = tt - tm
    den = float(np.dot(dt_, dt_))
    slope = float(np.dot(dt_, ll - lm)) / den if den > 0 else 0.0
    if slope == 0.0:
        return float(tm)
    return float(np.clip(tm + (thr - lm) / slope, tt[0], tt[-1]))


class LrlDecoder(Decoder):
    sensor = "lrl"
    channels = ()            # depend on scan_mode and n_sensors: checked per block

    MAX_PASSAGE = 120.0      # [s] a longer lug passage (train stopped over a lug) is dropped
    HYSTERESIS = 0.2         # channel state hysteresis +- around the threshold [1] (4 sigma of the noise)
    HISTORY = 400            # samples kept before a passage for the first falling ramp

    def __init__(self, params, track):
        super().__init__(params, track)
        p = self.params
        self.mode = _check_mode(p["scan_mode"])
        self.n_sensors = int(p["n_sensors"])
        self.expected = _channels(self.mode, self.n_sensors)
        self.offsets = channel_offsets(self.mode, p["bit_pitch"])
        # channels timed by _sensor: (index, half-length of the lug part it sees [m], whether
        # it may see several runs of which the first and last count)
        if self.mode == "single":
            self._chans = [(4, D0_HALF, False)] + [(i, PLATE_HALF, True) for i in range(4)]
        else:
            half_tab = 0.5 * (p["bit_pitch"] + 0.05)
            self._chans = [(i, half_tab, False) for i in range(4)]
        offs = [float(self.offsets[ch]) for ch, _, _ in self._chans]
        self._chan_order = np.argsort(offs).tolist()
        self._chan_half_off = [(half, off) for (_, half, _), off in zip(self._chans, offs)]
        self._groups: dict[tuple[int, ...], list[tuple[dict, float]]] = {}
        lengths = set()
        for item, code, spacing in track_groups(track, p):
            self._groups.setdefault(code, []).append((item, spacing))
            lengths.add(len(code))
        self._group_len = max(lengths) if len(lengths) == 1 else 0   # 0: groups end by gap only
        self._lo = p["threshold"] - self.HYSTERESIS
        self._hi = p["threshold"] + self.HYSTERESIS
        self._state = np.zeros(len(self.expected), dtype=bool)
        self._active = False
        self._seg: list[np.ndarray] = []
        self._seg_t: list[np.ndarray] = []
        self._seg_start = 0.0
        self._state_any = False
        # quiet samples before a passage, as (times, levels) chunks, oldest first: they
        # are joined only when a passage starts
        self._hist_chunks: list[tuple[np.ndarray, np.ndarray]] = []
        self._hist_n = 0
        self._offsets_key: tuple | None = None
        self._offsets = np.zeros(0)
        self._rows_cache = np.zeros((0, 1), dtype=np.intp)
        self._group: list[dict] = []
        self.stats = {"lugs": 0, "sensor_invalid": 0, "sensor_disagreements": 0, "unresolved_lugs": 0,
                      "unconfirmed_lugs": 0,
                      "groups": 0, "incomplete_groups": 0, "unknown_id": 0, "dropped_passages": 0}

    # -- block handling -------------------------------------------------------------
    def decode(self, block: RawBlock):
        p = self.params
        if block.channels != self.expected:
            raise InputRejected("channels", f"channels {block.channels} differ from the {self.mode}-scan "
                                            f"layout of {self.n_sensors} sensors")
        lev = block.data.astype(float)
        lev_min, lev_max = lev.min(), lev.max()
        if lev_min < -1.0 or lev_max > 3.0:
            raise InputRejected("implausible", f"receive levels {lev_min:.2f}..{lev_max:.2f} are outside "
                                               "0..1 plus noise")
        n = len(lev)
        if self._offsets_key != (n, block.sample_rate):
            self._offsets_key = (n, block.sample_rate)
            self._offsets = np.arange(n) / block.sample_rate
        t = block.t0 + self._offsets      # sample times [s], as block.times()
        out: list[PositionFix] = []
        errors: list[InputRejected] = []
        if not self._active and not self._state_any and lev_min >= self._lo:
            # quiet block (most of them): no channel sees a lug, all of it is history
            self._hist_chunks.append((t, lev))
            self._hist_n += n
            while self._hist_n - len(self._hist_chunks[0][0]) >= self.HISTORY:
                self._hist_n -= len(self._hist_chunks.pop(0)[0])
        else:
            self._passages(t, lev, out, errors)
        # a group whose next lug is overdue is closed
        if self._group and not self._active:
            g = self._group[-1]
            if (block.t_end - g["t"]) * abs(g["v"]) > p["group_gap"]:
                self._close_group(out, errors)
        if errors and not out:
            raise errors[0]
        return out

    def _history(self) -> tuple[np.ndarray, np.ndarray]:
        """Times [s] and levels of the last (at most HISTORY) quiet samples."""
        chunks = self._hist_chunks
        if not chunks:
            return np.zeros(0), np.zeros((0, len(self.expected)))
        if len(chunks) > 1:
            chunks[:] = [(np.concatenate([c[0] for c in chunks])[-self.HISTORY:],
                          np.concatenate([c[1] for c in chunks])[-self.HISTORY:])]
        return chunks[0]

    def _passages(self, t: np.ndarray, lev: np.ndarray, out: list, errors: list) -> None:
        """Lug passages of a block that is not quiet: channel states, passage segments
        (with up to HISTORY quiet samples before each), one _lug per completed passage."""
        state = hysteresis(lev, self._lo, self._hi, self._state)
        self._state = state[-1].copy()
        self._state_any = bool(self._state.any())
        act = state.any(axis=1)
        i, n = 0, len(t)
        hist_t, hist = self._history()
        q0 = 0     # quiet samples since the last passage
        while i < n:
            if not self._active:
                nz = np.flatnonzero(act[i:])
                if not nz.size:
                    break
                j = i + int(nz[0])
                pre_t = np.r_[hist_t, t[q0:j]][-self.HISTORY:]
                pre = np.vstack([hist, lev[q0:j]])[-self.HISTORY:]
                self._active, self._seg_t, self._seg, i = True, [pre_t], [pre], j
                self._seg_start = t[j]
            else:
                nz = np.flatnonzero(~act[i:])
                j = i + int(nz[0]) if nz.size else n
                end = min(j + 1, n)             # keep the first quiet sample (end of the last ramp)
                self._seg_t.append(t[i:end])
                self._seg.append(lev[i:end])
                if j >= n:
                    if t[-1] - self._seg_start > self.MAX_PASSAGE:
                        self.stats["dropped_passages"] += 1
                        self._active = False
                    break
                self._active, i = False, j + 1
                self._lug(np.concatenate(self._seg_t), np.vstack(self._seg), out, errors)
                hist_t, hist, q0 = t[:0], lev[:0], j
        if self._active:
            self._hist_chunks, self._hist_n = [], 0
        else:
            hist_t = np.r_[hist_t, t[q0:]][-self.HISTORY:]
            self._hist_chunks, self._hist_n = [(hist_t, np.vstack([hist, lev[q0:]])[-self.HISTORY:])], len(hist_t)

    # -- one lug passage --------------------------------------------------------------
    def _edges(self, lev: np.ndarray) -> tuple[list, list, list, list, list]:
        """Per channel of a lug passage (all sensors at once): number of runs in the lug
        state, start k0 of the first and end k1 (exclusive) of the last, the last sample
        before k0 above the high level (0 if none; start of the falling ramp) and the last
        sample before k1 below the low level (start of the rising ramp)."""
        m, c = lev.shape
        below, above = lev < self._lo, lev > self._hi
        # hysteresis (as hysteresis() from the free state): the state follows the last
        # sample outside the band, ``last`` (-1: none yet)
        last = np.where(below | above, self._rows(m), -1)
        np.maximum.accumulate(last, axis=0, out=last)
        cols = np.arange(c)
        low = below[np.maximum(last, 0), cols] & (last >= 0)
        n_runs = (low[1:] > low[:-1]).sum(axis=0) + low[0]
        k0 = low.argmax(axis=0)
        k1 = m - low[::-1].argmax(axis=0)
        # the state is free just before k0 and in the lug state just before k1, so the last
        # sample outside the band there is the one above (if any) / below the band
        f0 = np.maximum(last[np.maximum(k0 - 1, 0), cols], 0)
        r0 = last[np.maximum(k1 - 1, 0), cols]
        return n_runs.tolist(), k0.tolist(), k1.tolist(), f0.tolist(), r0.tolist()

    def _rows(self, m: int) -> np.ndarray:
        """Column of the sample indices 0..m-1 (cached: a passage's length repeats)."""
        if len(self._rows_cache) < m:
            self._rows_cache = np.arange(max(m, 2 * len(self._rows_cache)))[:, None]
        return self._rows_cache[:m]

    def sensor_read(self, t: np.ndarray, lev: np.ndarray, edges) -> tuple[int, float, float, int, float] | None:
        """(value, t_ref, v, n_crossings, fit residual [m]) of one sensor's lug passage, None
        if unusable (the vote over the head's sensors takes these; a study of a failing sensor
        replaces this method). ``edges``: _edges of the sensor's 5 channels.

        Every threshold crossing of a sync or plate channel is a point (ref, t): the
        channel at offset o crosses the lug edge e when the sensor reference point is at
        ref = e - o (which edge comes first depends on the direction). A line (a quadratic
        when the train accelerates over the lug) t(ref) through these points gives the time
        the sensor passed the sync mark, t(0), the speed 1/t'(0) and the read instants.
        """
        p = self.params
        thr = p["threshold"]
        n_runs, k0s, k1s, f0s, r0s = edges
        chans = [ch for ch, _, _ in self._chans]
        for ch, half, first_last in self._chans:
            if not n_runs[ch] or (not first_last and n_runs[ch] != 1):
                return None
            if k0s[ch] == 0 or k1s[ch] >= len(t):      # an edge was not seen
                return None
        # the ramps: falling f0..k0, rising r0..k1; at speed most are two samples, for
        # which the crossing is interpolated here from the samples fetched at once
        ramps = [(f0s[ch], k0s[ch]) for ch in chans] + [(r0s[ch], k1s[ch]) for ch in chans]
        idx = [i for ramp in ramps for i in ramp]
        lv = lev[idx, [ch for ch in chans for _ in (0, 1)] * 2].tolist()
        tv = t[idx].tolist()
        t_cross = []
        for k, (i0, i1) in enumerate(ramps):
            if i1 - i0 == 1:
                a, b = lv[2 * k], lv[2 * k + 1]
                t0, t1 = tv[2 * k], tv[2 * k + 1]
                t_cross.append(t1 if a == b else t0 + (a - thr) / (a - b) * (t1 - t0))
            else:
                t_cross.append(_ramp_crossing(t, lev[:, chans[k % len(chans)]], i0, i1, thr))
        t_fall, t_rise = t_cross[:len(chans)], t_cross[len(chans):]
        # centres of the channels' pulses, in the order of their offsets
        centres = [0.5 * (t_fall[k] + t_rise[k]) for k in self._chan_order]
        steps = [b - a for a, b in zip(centres[:-1], centres[1:])]
        if not (all(x > 0 for x in steps) or all(x < 0 for x in steps)):
            return None                       # channels not passed in order (reversal, glitch)
        forward = steps[0] < 0                # the channel ahead (larger offset) sees the lug first
        sgn = 1.0 if forward else -1.0
        refs = np.array([-sgn * h - o for h, o in self._chan_half_off] + [sgn * h - o for h, o in self._chan_half_off])
        ts = np.array(t_fall + t_rise)
        dt = t[1] - t[0] if len(t) > 1 else 0.0
        fit = np.polyfit(refs, ts, 1)
        rms = math.sqrt(((ts - np.polyval(fit, refs)) ** 2).sum() / len(ts))   # as np.sqrt(np.mean())
        fit_err = 0.0
        if rms * abs(1.0 / fit[0]) > abs(1.0 / fit[0]) * dt / math.sqrt(12.0) * 2.0 + 0.001:
            fit = np.polyfit(refs, ts, 2)     # accelerating / braking over the lug
            fit_err = float(np.sqrt(np.mean((ts - np.polyval(fit, refs)) ** 2))) / abs(fit[1])
        slope0 = fit[-2]
        if slope0 == 0.0 or slope0 * sgn <= 0.0:
            return None
        v = 1.0 / slope0
        if abs(v) > 200.0:
            return None
        t_ref = float(np.polyval(fit, 0.0))
        win = READ_HALF * abs(slope0)
        if self.mode == "single":
            # P1..P4 are all read at t_ref
            read = lev[self._read_rows(t, t_ref, win), :4].T.tolist()
            bits = [_median(levels) < thr for levels in read]
        else:
            read_t = np.polyval(fit, (np.arange(4) - 1.5) * p["bit_pitch"])
            bits = [_median(lev[self._read_rows(t, read_t[j], win), 4].tolist()) < thr for j in range(4)]
        value = 0
        for j, bit in enumerate(bits):
            value |= int(bit) << (3 - j)
        return value, t_ref, float(v), len(ts), fit_err

    @staticmethod
    def _read_rows(t: np.ndarray, t_read: float, win: float) -> np.ndarray:
        """Samples within ``win`` [s] of t_read, else the nearest one."""
        dist = np.abs(t - t_read)
        sel = dist <= win
        if not sel.any():
            sel = np.zeros(len(t), bool)
            sel[int(np.argmin(dist))] = True
        return sel

    def _lug(self, t, lev, out, errors) -> None:
        p = self.params
        self.stats["lugs"] += 1
        reads = []
        n_runs, k0, k1, f0, r0 = self._edges(lev)
        for s in range(self.n_sensors):
            c = slice(5 * s, 5 * s + 5)
            r = self.sensor_read(t, lev[:, c], (n_runs[c], k0[c], k1[c], f0[c], r0[c]))
            if r is None:
                self.stats["sensor_invalid"] += 1
            else:
                reads.append(r)
        if not reads:
            self.stats["unresolved_lugs"] += 1
            return
        values = [r[0] for r in reads]
        best, count = vote(values)
        if count < len(values):
            self.stats["sensor_disagreements"] += 1
        value = best if 2 * count > len(values) and (count >= 2 or self.n_sensors == 1) else None
        if value is None:
            self.stats["unresolved_lugs"] += 1
            if count == len(values):
                self.stats["unconfirmed_lugs"] += 1   # one valid read of a redundant head
        agree = [r for r in reads if r[0] == best]
        t_ref = float(np.mean([r[1] for r in agree]))
        v = float(np.mean([r[2] for r in agree]))
        dt = t[1] - t[0] if len(t) > 1 else 0.0
        n_pts = agree[0][3]
        # crossing times quantised by the sampling (sharp edges) and jittered by the noise;
        # the sensors sample at the same instants, so their quantisation errors are common
        sig_q = abs(v) * dt / math.sqrt(12.0 * n_pts)
        sig_n = p["level_noise"] * p["edge_width"] / p["attenuation"] / math.sqrt(n_pts * len(agree))
        sig_fit = float(np.mean([r[4] for r in agree]))      # acceleration over the lug
        lug = {"value": value, "t": t_ref, "v": v, "sigma": math.sqrt(sig_q ** 2 + sig_n ** 2 + sig_fit ** 2)}
        if self._group:
            g = self._group[-1]
            if (np.sign(v) != np.sign(g["v"]) or
                    (t_ref - g["t"]) * 0.5 * (abs(v) + abs(g["v"])) > p["group_gap"]):
                self._close_group(out, errors)
        self._group.append(lug)
        if self._group_len and len(self._group) >= self._group_len:
            self._close_group(out, errors)

    def _close_group(self, out, errors) -> None:
        p = self.params
        lugs, self._group = self._group, []
        self.stats["groups"] += 1
        if any(lug["value"] is None for lug in lugs):
            return                            # counted in unresolved_lugs
        direction = 1 if np.mean([lug["v"] for lug in lugs]) > 0 else -1
        code = tuple(lug["value"] for lug in lugs)
        if direction < 0:
            code = code[::-1]                 # travel order -> chainage order
        match = self._groups.get(code)
        if not match:
            if self._group_len and len(code) < self._group_len:
                self.stats["incomplete_groups"] += 1
                return
            self.stats["unknown_id"] += 1
            errors.append(InputRejected("unknown_id", f"LRL code {list(code)} is no group of track "
                                                      f"{self.track.track_id}"))
            return
        if len(match) > 1:
            self.stats["unknown_id"] += 1
            errors.append(InputRejected("unknown_id", f"LRL code {list(code)} is used by several groups: "
                                                      f"{[m[0]['id'] for m in match]}"))
            return
        item, spacing = match[0]
        last = lugs[-1]
        k_last = len(code) - 1 if direction > 0 else 0
        sigma = fix_sigma(p, last["sigma"])
        out.append(PositionFix(float(last["t"]), self.sensor, self.unit_id, self.track.track_id, str(item["id"]),
                               fix_position(p, item, k_last, spacing), float(sigma), direction))


def fix_sigma(params: dict, timing: float = 0.0) -> float:
    """1-sigma [m] of a group fix: the lug's ``install_sigma`` and the edge-timing 1-sigma ``timing``
    [m] of the last lug (the decoder's), at least MIN_FIX_SIGMA; with timing 0 the least a fix
    reports (the error model's floor)."""
    return max(math.hypot(params["install_sigma"], timing), MIN_FIX_SIGMA)


def fix_position(params: dict, item: dict, k: int, spacing: float) -> float:
    """Train-front chainage [m] of a fix at lug ``k`` (0 = lowest chainage) of group ``item``:
    the lug's sync mark + ``sensor_offset`` (the decoder assumes the sensor behind the front towards
    decreasing chainage, as the simulator)."""
    return float(item["position"] + k * spacing + params["sensor_offset"])


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """LRL fixes for the fusion: white (lug edge timing in the decoder's stddev); fault
    mode: a misread code. Floor: ``fix_sigma`` without timing, max(install_sigma, 1 mm).
    References: every group of the track (``track_groups``, as the decoder), window from its
    first to its last lug + sensor_offset (``fix_position``: the last lug read, the first or the
    last by the direction of travel)."""
    references = None
    if track is not None:
        windows: dict[str, ReferenceWindow] = {}
        for item, code, spacing in track_groups(track, params):
            lo, hi = fix_position(params, item, 0, spacing), fix_position(params, item, len(code) - 1, spacing)
            old = windows.get(str(item["id"]))      # an id given twice (other codes): either group's fixes
            windows[str(item["id"])] = ReferenceWindow(min(lo, old.lo), max(hi, old.hi)) if old is not None else \
                ReferenceWindow(lo, hi)
        references = ReferenceTable(windows)
    return ErrorModel("lrl", "position", faults=("misread", "offset"), min_stddev=fix_sigma(params),
                      references=references)


SPEC = SensorSpec(
    node="lrl_scanner", sensor="lrl", simulator=LrlSimulator, decoder=LrlDecoder, params=PARAMS,
    description="on-board INKREFA LRL scanner: location reference lug codes -> position fix",
    seeds=("002", "000"), outputs=("position",), error_model=error_model,
)

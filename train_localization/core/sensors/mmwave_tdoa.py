"""Millimetre-wave radio positioning by time differences of arrival (TDOA), seed 002.

Physics (seed 002 section 2.2.2, MLX; docs/references.md): the mm-wave radio system
"locates the train using the difference of the propagation delay times of radio signals
between the train and the wayside base stations"; it serves position initialisation and
train protection, receives several base stations at once for safety, and the MLX position
system updates every 5 ms. This module is that scheme; mmwave.py (``mmwave_ranging``) is
the two-way-ranging alternative. A scenario selects one by listing its node.

Scheme (our reading of the seed, documented): downlink TDOA. The wayside base stations
are synchronised to a common time base by the fibre network (White-Rabbit / PTP-class
timing, sub-nanosecond) and transmit their beacons at every epoch tick T (the frame
period 1 / sample_rate, 5 ms) on their own codes; the on-board receiver timestamps each
arrival on its own free-running clock. The arrival of station i:

    t_i = T + r_i / C_AIR + b(T) + u_i + n_i,

r_i the antenna-station range (the geometry of mmwave.py: r_i = sqrt((x - s_i)^2 + d_i^2),
x the antenna chainage), b the vehicle clock bias (a per-run random phase, a frequency
offset drawn per run with 1-sigma ``clock_drift`` ppm (TCXO) and a random walk
``clock_walk``), u_i the station's synchronisation offset (constant, 1-sigma ``sync_sigma``:
it replaces the antenna-delay calibration bias of TWR) and n_i the timing noise (the SNR
model of mmwave.py, ``range_sigma``, / C_AIR). The receiver does not know T (no common
clock with the wayside), only its own time: the decoder takes each epoch's reference
station (the highest SNR of the valid ones) and forms the differences t_i - t_ref, in
which b (and T) cancel, so x follows from the range differences r_i(x) - r_ref(x).

Differences to TWR: no turnaround time at the station and no uplink (one broadcast
serves every train), but the stations must be synchronised, and one unknown more per
epoch (the clock bias) costs one station: TDOA needs 2 stations for a fix (no
redundancy), 3 to detect a fault and 4 to isolate one (counting unknowns; the 1-D
geometry asks more, see "Raw signal"), where 1-D TWR needs 1 (side ambiguity aside) and
2. A station alone on its side of the antenna cannot be checked by the others: its fault
moves x unseen, so such an epoch gives no fix (``stats["unbounded"]``).

The receiver's clock frequency offset f also scales the differences by (1 + f) over the
few microseconds between the arrivals of one epoch: f dr, 2 mm at 2 ppm over 1 km, below
the ranging noise: the simulator evaluates b at the epoch tick and the decoder does not
estimate f.

Track equipment: the ``mmwave_station`` items of mmwave.py (id, position, offset, height,
code), shared.

Raw signal (one row per epoch, default 200 Hz = 5 ms): the hand-over set of mmwave.py,
here the ``SLOTS`` = 6 nearest stations within ``max_range`` (all of them at the default
1 km range and 400 m spacing), slots by chainage. Six, not TWR's 4: in 1-D the difference
of two stations on the same side of the antenna hardly depends on x (r_i - r_j -> s_j -
s_i), so x comes from the pairs across the antenna and the stations on one side only
check each other; with 2 + 2 a single fault is detected but two candidates remain
(unidentifiable), a majority on one side (3 + 2) isolates it. Slot k has four channels:

    station_k       station code (0 = empty slot)
    arrival_k       arrival phase on the receiver clock within its frame [s]: the
                    receiver's coarse counter, a multiple of TICK = 2^-20 s, in
                    [0, period); -1 = no reply (dropout, below the detection threshold,
                    or an empty slot) -- the sentinel, raw data never contain NaN
    arrival_fine_k  the fine interpolator [s] in [0, TICK): phase = arrival_k +
                    arrival_fine_k, i.e. (r / c + b + u + n) modulo the period, which
                    wraps as the clock drifts; 0 with no reply
    snr_k           first-path SNR [dB]; 0 with no reply

The timestamp is split like a time-to-digital converter's coarse counter and fine
interpolator because raw samples are float32 (signals.py): one float32 of up to 5 ms
resolves only 0.5 ns (14 cm); the pair resolves 2^-44 s (17 um). 24 channels x 200 Hz =
4800 samples/s.

Errors modelled: those of mmwave.py on each arrival (SNR-dependent noise, free-space SNR
with fading, NLOS episodes with a positive excess path and an SNR loss, lost replies,
replies below ``snr_threshold``), the per-station synchronisation offsets, the receiver
clock (phase, frequency offset, random walk; cancels) and injected faults (``faults``,
';'-separated, times in s):

    ID@T0-T1:BIAS          range bias [m] of station ID (an excess path, a delay fault)
    ID@T0-T1:drop          station ID silent
    ID@T0-T1:sync=RATE     station ID loses its synchronisation at T0: its timing walks off
                           at RATE [ns/s] until it is re-synchronised at T1
    clock@T0-T1:jump=NS    the receiver clock steps by NS [ns] at T0 and back at T1
    clock@T0-T1:drift=PPM  the receiver clock runs PPM [ppm] off between T0 and T1

Decoder (vectorised over the epochs of a block and the subsets of its slots):
  * Reference and differences: per epoch the valid slot with the highest SNR is the
    reference; the differences of the other arrivals to it, unwrapped into (-period/2,
    period/2] (a valid difference is below 2 max_range / C_AIR, microseconds), times C_AIR
    are the measured range differences, free of the clock bias.
  * Solution: weighted Gauss-Newton on the antenna chainage x with the correct covariance
    of the differences (the reference's noise is common to all of them). Computed in the
    equivalent form that eliminates a common offset from the arrivals of the subset
    (pseudo-ranges rho_i = r_i(x) + beta): beta's least-squares elimination is the
    differencing against any one of the subset's stations with that covariance, so every
    subset -- also one without the reference station -- is solved alike. Started from the
    best (capped cost) of the pair solutions x = (s_i + s_ref - sign(s_i - s_ref) D_i) / 2,
    the exact solution between two stations on the track axis. Between stations on both
    sides the differences change at up to 2 m/m; beyond all stations on one side they
    flatten (r_i - r_j -> const) and the LS sigma grows; where the geometry cannot fix x
    (LS sigma beyond ``max_geometry_sigma``) there is no fix (``stats["geometry"]``), and a
    subset of such a geometry counts as no solution: where a fault of one station would
    leave only such a subset, the fault is unbounded and there is no fix either
    (``stats["unbounded"]``; e.g. the one station ahead of the antenna with the others
    behind it).
  * Fault detection and isolation: as mmwave.py (shared SolutionSeparation), with one
    degree of freedom fewer: the chi-square test of the weighted residuals (dof = stations
    - 2, ``outlier_probability``); if it fails, the subsets of at least 3 stations
    (``min_stations``) are solved and tested, one consistent largest subset isolates the
    fault, several that agree give the one whose widened sigma is smallest, several that
    disagree give no fix (``stats["unidentifiable"]``), none no fix
    (``stats["inconsistent"]``); a failing test with 3 stations in view has none to spare
    (unidentifiable). A fault of the reference station is no special case: the subsets
    without it are solved like any other (their own offset eliminated).
  * Protection: the published sigma is PL / k, k the normal quantile of
    ``protection_probability``, PL = max(k sd, max_j |x - x_without_j| + k sd_without_j)
    over the stations used (solution separation), at least ``min_fix_sigma``; after an
    isolation it also covers a second fault where NLOS episodes make one likely
    (mmwave.py). With 2 stations used nothing is left without one of them: no fix
    (``stats["unbounded"]``), unless ``min_stations`` = 2, where such a fix is published
    unchecked, with ``unchecked_sigma`` added. With 3 in view where two faults alike are
    a priori likelier than the interval's risk, no fix (``stats["unprotected"]``).
  * Common causes: stations served by one timing node or one fibre lose their
    synchronisation together and walk off the same way; they agree with each other, so the
    test passes (two on the same side of the antenna shift x and the clock bias alike: no
    residual at all) or isolates a good station instead. Each group the track declares
    (core/common_cause.py, prior above 1 - ``protection_probability``), or where it declares
    none every ``timing_neighbours`` neighbouring stations, is a fault of its own: the sigma
    also covers the solution without all of the group's stations in the chosen subset
    (``SolutionSeparation._group_protection``), and where that leaves x unfixed there is no
    fix. With pairs, a fix needs a station left on each side of the antenna after any two
    neighbours are removed: three on each side (``stats["common_cause"]`` counts the fixes
    whose sigma a group widened).
  * Output: one PositionFix per epoch; position = x + orientation * antenna_offset;
    reference_id = the stations used (ascending chainage), then the excluded ones with
    "!"; residuals = measured minus fitted pseudo-range (common offset of the used stations
    removed) [m], in the order of reference_id; direction = 0.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.special import chdtri

from ..common_cause import CommonCause
from ..measurements import PositionFix
from ..signals import InputRejected, RawBlock
from ..track import Track
from .base import Decoder, ErrorModel, Param, SensorSpec
from .mmwave import (C_AIR, MIN_RANGE_VAR, PARAMS as TWR_PARAMS, MmWaveSimulator, SolutionSeparation,
                     base_stations, group_excess, handover, item_picker, parse_range_faults, range_sigma,
                     station_references)

SLOTS = 6                # stations received at once (correlator channels of the receiver)
TICK = 2.0 ** -20        # coarse counter step of the receiver's timestamps [s] (~0.95 us)
NO_REPLY = -1.0          # arrival_k of a slot without a reply
CHUNK = 50               # epochs solved at once (memory of the subset arrays: 63 x 6 x CHUNK)
GN_ITERATIONS = 8        # Gauss-Newton steps from the pair start (linear within metres)
CLOCK = "clock"          # the receiver clock in ``faults``
_SHARED = ("snr_ref", "ref_range", "snr_fading", "snr_threshold", "range_sigma_floor",
           "range_sigma_snr", "nlos_rate", "nlos_duration", "nlos_bias_mean", "nlos_snr_loss", "dropout_prob",
           "station_height", "antenna_height", "antenna_offset", "orientation", "outlier_probability",
           "protection_probability")

PARAMS = {
    "max_range": Param(1000.0, "radio range of a base station [m]; the nearest 6 stations within it are "
                               "received (38 GHz line-of-sight radio link, seed 002 section 2.2.1; ~1 km cells)",
                       (1.0, 10000.0)),
    **{name: TWR_PARAMS[name] for name in _SHARED},
    "sync_sigma": Param(0.3, "1-sigma constant synchronisation offset of a station [ns] (0.3 ns = 9 cm; "
                             "White-Rabbit / PTP-class fibre timing of the wayside)", (0.0, 1000.0)),
    "clock_drift": Param(2.0, "1-sigma frequency offset of the receiver clock, drawn per run [ppm] (TCXO); "
                              "cancels in the differences", (0.0, 1000.0)),
    "clock_walk": Param(1e-9, "random walk of the receiver clock bias [s/sqrt(s)]; cancels", (0.0, 1e-3)),
    "clock_phase": Param(-1.0, "receiver clock phase at t = 0 as a fraction of the frame period [1]; "
                               "negative = drawn uniformly per run (a free-running clock)", (-1.0, 1.0)),
    "min_stations": Param(3, "least number of consistent stations for a fix [1]: 3 allow the test (2 = "
                             "also publish unchecked fixes of two stations); at most the 6 received",
                          (2, 6)),
    "unchecked_sigma": Param(0.5, "1-sigma added to a two-station fix (min_stations 2) [m]: without "
                                  "redundancy an NLOS bias (mean ~1 m) cannot be detected", (0.0, 50.0)),
    "max_geometry_sigma": Param(5.0, "largest LS 1-sigma of a fix [m]: beyond all stations on one side the "
                                     "range differences flatten and x is not fixed (no fix)", (0.01, 1000.0)),
    "timing_neighbours": Param(2, "where the track declares no common_cause group of its stations: every run "
                                  "of this many neighbouring stations (by chainage) may lose its "
                                  "synchronisation together, as stations served by one timing node or one "
                                  "fibre do, and is covered as one fault (1: each station on its own) [1]",
                               (1, 6)),
    "faults": Param("", "injected faults 'ID@T0-T1:BIAS' (range bias [m]), 'ID@T0-T1:drop', "
                        "'ID@T0-T1:sync=RATE' (station timing walks off [ns/s]), 'clock@T0-T1:jump=NS' "
                        "(receiver clock step [ns]) or 'clock@T0-T1:drift=PPM', separated by ';' (tests)"),
}


def channel_names() -> tuple[tuple[str, ...], tuple[str, ...]]:
    names, units = [], []
    for k in range(SLOTS):
        names += [f"station_{k}", f"arrival_{k}", f"arrival_fine_{k}", f"snr_{k}"]
        units += ["1", "s", "s", "dB"]
    return tuple(names), tuple(units)


CHANNELS, UNITS = channel_names()


def _split_faults(text: str):
    """(range faults 'ID@T0-T1:BIAS|drop' as mmwave's parse_range_faults, timing faults (id, t0, t1,
    kind, value) of the forms sync=, jump=, drift=)."""
    plain, timing = [], []
    for item in filter(None, (s.strip() for s in str(text).split(";"))):
        what = item.rsplit(":", 1)[-1].strip()
        kind = what.split("=", 1)[0].strip()
        if kind in ("sync", "jump", "drift"):
            try:
                sid, rest = item.split("@")
                t0, t1 = (float(v) for v in rest.rsplit(":", 1)[0].split("-"))
                value = float(what.split("=", 1)[1])
            except ValueError:
                value = None
            if value is None or (sid.strip() == CLOCK) != (kind != "sync"):
                raise ValueError(f"malformed mmwave_tdoa fault {item!r}; expected 'ID@T0-T1:sync=RATE', "
                                 f"'clock@T0-T1:jump=NS' or 'clock@T0-T1:drift=PPM'")
            timing.append((sid.strip(), t0, t1, kind, value))
        else:
            plain.append(item)
    return parse_range_faults(";".join(plain)), timing


def timing_groups(track: Track, ids, positions, neighbours: int) -> tuple[CommonCause, ...]:
    """The stations' implied common-cause groups: none where the track declares a group of
    these stations (core/common_cause.py), else every run of ``neighbours`` neighbouring
    stations by chainage ``positions`` [m] (``timing_neighbours``), each with prior 1 (always
    covered)."""
    mine = set(ids)
    if any(mine.intersection(group.members) for group in track.common_cause) or neighbours < 2:
        return ()
    order = [ids[k] for k in np.argsort(positions, kind="stable")]
    return tuple(CommonCause(f"timing:{','.join(order[k:k + neighbours])}", "timing node",
                             tuple(order[k:k + neighbours]), 1.0 - 1e-12)
                 for k in range(len(order) - neighbours + 1))


def sync_sigma_m(p: dict) -> float:
    """1-sigma synchronisation offset of a station as a range [m]."""
    return p["sync_sigma"] * 1e-9 * C_AIR


def arrival_variance_floor(p: dict) -> float:
    """Least variance [m^2] of one arrival (as a range) in the fit: the noise floor and the
    synchronisation offset, at least (1 mm)^2."""
    return max(p["range_sigma_floor"] ** 2 + sync_sigma_m(p) ** 2, MIN_RANGE_VAR)


def min_fix_sigma(p: dict) -> float:
    """Least 1-sigma [m] of a fix: SLOTS arrivals of the least variance whose partials
    about their mean are +-1 (two stations far on either side): var / SLOTS."""
    return math.sqrt(arrival_variance_floor(p) / SLOTS)


class MmWaveTdoaSimulator(MmWaveSimulator):
    """The radio channel of mmwave.py (ranges, NLOS, SNR, dropouts, hand-over set), timed by
    synchronised stations and received on a free-running clock."""

    sensor = "mmwave_tdoa"
    channels = CHANNELS
    units = UNITS

    def __init__(self, *args):
        super().__init__(*args)
        index = {sid: k for k, sid in enumerate(self.ids)}
        self.timing = []
        for sid, t0, t1, kind, value in self._timing_faults:
            if kind == "sync" and sid not in index:
                raise ValueError(f"mmwave_tdoa fault names unknown station {sid!r}")
            self.timing.append((index.get(sid, -1), t0, t1, kind, value))
        period = 1.0 / self.sample_rate
        drawn = self.rng.random()
        phase = self.params["clock_phase"]
        self.clock0 = (drawn if phase < 0.0 else phase) * period
        self.clock_freq = self.rng.normal(0.0, self.params["clock_drift"] * 1e-6)
        self.clock_walked = 0.0

    def _station_bias(self, n: int) -> np.ndarray:
        """Synchronisation offset of each station as a range [m]."""
        return self.rng.normal(0.0, sync_sigma_m(self.params), n)

    def _parse_faults(self, text):
        plain, self._timing_faults = _split_faults(text)
        return plain

    def _clock(self, times):
        """Receiver clock bias b [s] at the epochs ``times`` (phase, frequency, walk, faults)."""
        walk = self.rng.normal(0.0, self.params["clock_walk"] * math.sqrt(1.0 / self.sample_rate), len(times))
        walked = self.clock_walked + np.cumsum(walk)
        self.clock_walked = float(walked[-1])
        b = self.clock0 + self.clock_freq * times + walked
        for _, t0, t1, kind, value in self.timing:
            if kind == "jump":
                b = b + np.where((times >= t0) & (times < t1), value * 1e-9, 0.0)
            elif kind == "drift":
                b = b + value * 1e-6 * (np.clip(times, t0, t1) - t0)
        return b

    def samples(self, times, position, speed, acceleration):
        p = self.params
        n, m = len(times), len(self.ids)
        out = np.zeros((n, 4 * SLOTS))
        out[:, 1::4] = NO_REPLY
        b = self._clock(times)
        if m == 0:
            return out
        r, bias, noise, snr, lost = self._radio(times, position)
        path = r + self.cal[None, :] + bias + noise           # [m] as a range
        for k, t0, t1, kind, value in self.timing:
            if kind == "sync":
                path[:, k] += value * 1e-9 * C_AIR * np.clip(times - t0, 0.0, None) * (times < t1)
        period = 1.0 / self.sample_rate
        phase = np.mod(path / C_AIR + b[:, None], period)
        coarse = np.floor(phase / TICK) * TICK
        fine = phase - coarse
        replied = ~lost & (snr >= p["snr_threshold"])
        chosen, ok = handover(r, p["max_range"], SLOTS)
        rows = np.arange(n)
        for k in range(min(SLOTS, m)):
            j = chosen[:, k]
            rep = ok[:, k] & replied[rows, j]
            out[:, 4 * k] = np.where(ok[:, k], self.codes[j], 0)
            out[:, 4 * k + 1] = np.where(rep, coarse[rows, j], NO_REPLY)
            out[:, 4 * k + 2] = np.where(rep, np.minimum(fine[rows, j], TICK * (1.0 - 2.0 ** -23)), 0.0)
            out[:, 4 * k + 3] = np.where(rep, snr[rows, j], 0.0)
        return out


class MmWaveTdoaDecoder(SolutionSeparation, Decoder):
    """Decoder. Arrays over a block are slot-major (SLOTS, n); over the subsets of the
    slots (S, SLOTS, n) with S = 2^SLOTS - 1 (subset i: the slots of the bits of i + 1)."""

    sensor = "mmwave_tdoa"
    channels = CHANNELS

    def __init__(self, params: dict, track: Track):
        super().__init__(params, track)
        self.ids, self.pos, self.perp, self.codes = base_stations(track, params)
        self._lut = np.full(int(self.codes.max()) + 1 if len(self.codes) else 1, -1, dtype=np.int64)
        self._lut[self.codes] = np.arange(len(self.codes))
        self._perp2 = self.perp * self.perp
        self._sync2 = sync_sigma_m(params) ** 2
        self._min_sigma = min_fix_sigma(params)
        self._init_separation(params, SLOTS)
        self._init_groups(track, self.ids, timing_groups(track, self.ids, self.pos, params["timing_neighbours"]))
        self._tab = self._subsets(SLOTS)
        self._ref_cache: dict = {}
        self.stats.update(epochs=0, fixes=0, rejected_stations=0, no_fix=0, too_few=0, geometry=0,
                          unidentifiable=0, inconsistent=0, unbounded=0, unprotected=0,
                          common_cause=0)

    def _gate_dof(self, dof: int) -> float:
        """Gate of a subset of dof + 1 stations: its test has dof - 1 degrees of freedom (x and
        the clock bias estimated); inf where none is left."""
        if dof <= 1:
            return math.inf
        return float(chdtri(dof - 1, 1.0 - self.params["outlier_probability"]))

    # -- input checks -------------------------------------------------------------------
    def _check(self, codes_f, coarse, fine, snr, period):
        """Station index per slot (SLOTS, n; 0 for an empty slot); InputRejected for a bad block."""
        if not (np.isfinite(codes_f).all() and np.isfinite(coarse).all() and np.isfinite(fine).all()
                and np.isfinite(snr).all()):
            raise InputRejected("implausible", "a channel holds NaN or infinity")
        if np.any(codes_f != np.round(codes_f)) or np.any(codes_f < 0):
            raise InputRejected("unknown_id", "station channel holds a non-integer or negative code")
        beyond = codes_f > len(self._lut) - 1
        if beyond.any():
            raise InputRejected("unknown_id", f"station code {codes_f[beyond][0]:.0f} is not on track "
                                              f"{self.track.track_id}")
        codes = codes_f.astype(np.int64)
        present = codes > 0
        idx = self._lut[codes]
        if np.any(present & (idx < 0)):
            raise InputRejected("unknown_id", f"station code {int(codes[present & (idx < 0)][0])} is not on "
                                              f"track {self.track.track_id}")
        srt = np.sort(np.where(present, codes, -np.arange(1, SLOTS + 1)[:, None]), axis=0)
        if np.any(srt[1:] == srt[:-1]):
            raise InputRejected("implausible", "one station reported in two slots of an epoch")
        silent = coarse == NO_REPLY
        if np.any(silent & ((fine != 0.0) | (snr != 0.0))):
            raise InputRejected("implausible", "a no-reply slot (arrival -1) carries a fine time or an SNR")
        if np.any(~present & ~silent):
            raise InputRejected("implausible", "an empty slot carries an arrival")
        if np.any(~silent & ((coarse < 0.0) | (coarse >= period) | (np.floor(coarse / TICK) * TICK != coarse))):
            raise InputRejected("implausible", f"arrival outside 0..{period:.3e} s or off the {TICK:.3e} s "
                                               f"counter")
        if np.any(~silent & ((fine < 0.0) | (fine >= TICK))):
            raise InputRejected("implausible", f"fine arrival outside 0..{TICK:.3e} s")
        if np.any((snr < -30.0) | (snr > 100.0)):
            raise InputRejected("implausible", "SNR outside -30..100 dB")
        return np.where(present, idx, 0), ~silent

    # -- decoding -----------------------------------------------------------------------
    def decode(self, block: RawBlock):
        p = self.params
        data = block.data.T.astype(float)   # (4 SLOTS, n)
        codes_f, coarse, fine, snr = data[0::4], data[1::4], data[2::4], data[3::4]
        period = 1.0 / block.sample_rate
        idx, replied = self._check(codes_f, coarse, fine, snr, period)
        n = block.n_samples
        times = block.t0 + self.sample_offsets(n, block.sample_rate)
        self.stats["epochs"] += n
        valid = replied & (snr >= p["snr_threshold"])
        if not n:
            return []
        phase = coarse + fine
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            # in chunks of epochs: the subset arrays of a long block stay small
            parts = [self._solve(idx[:, a:a + CHUNK], phase[:, a:a + CHUNK], snr[:, a:a + CHUNK],
                                 valid[:, a:a + CHUNK], period) for a in range(0, n, CHUNK)]
        x, ok, used, resid, sigma = (np.concatenate([q[k] for q in parts], axis=-1) for k in range(5))
        n_ok = int(np.count_nonzero(ok))
        self.stats["no_fix"] += n - n_ok
        self.stats["rejected_stations"] += int(np.count_nonzero(valid & ~used & ok))
        self.stats["fixes"] += n_ok
        front = x + p["orientation"] * p["antenna_offset"]
        code = idx * 4 + used * 2 + valid
        fixes = []
        sensor, unit, track_id, cache = self.sensor, self.unit_id, self.track.track_id, self._ref_cache
        if len(cache) > 4096:
            cache.clear()
        for i in np.flatnonzero(ok).tolist():
            key = tuple(code[:, i].tolist())
            hit = cache.get(key)
            if hit is None:
                hit = cache[key] = self._ref_order(key)
            fixes.append(PositionFix(float(times[i]), sensor, unit, track_id, hit[0], float(front[i]),
                                     float(sigma[i]), 0, hit[1](resid[:, i].tolist())))
        return fixes

    def _ref_order(self, code):
        """reference_id of one epoch and the function picking its residuals (used stations by
        chainage, then the excluded ones) from the slots; code: per slot 4 x station index +
        2 x used + valid."""
        order = sorted((j for j in range(SLOTS) if code[j] & 2), key=lambda j: self.pos[code[j] >> 2])
        rej = sorted((j for j in range(SLOTS) if (code[j] & 3) == 1), key=lambda j: self.pos[code[j] >> 2])
        ids = self.ids
        ref = ",".join([ids[code[j] >> 2] for j in order] + ["!" + ids[code[j] >> 2] for j in rej])
        return ref, item_picker(order + rej)

    def _solve(self, idx, phase, snr, valid, period):
        """x (n,), ok (n,), used slots (SLOTS, n), residuals (SLOTS, n) and the published
        1-sigma (n,) of the epochs of a block."""
        p = self.params
        n = phase.shape[1]
        cols = self._columns(n)
        tab = self._tab
        s, d2 = self.pos[idx], self._perp2[idx]
        sig2 = np.maximum(range_sigma(snr, p) ** 2 + self._sync2, MIN_RANGE_VAR)
        w = np.where(valid, 1.0 / sig2, 0.0)
        nv = np.add.reduce(valid)
        # reference: the valid slot of the highest SNR; differences unwrapped into +-period/2
        ref = np.where(valid, snr, -np.inf).argmax(axis=0)
        diff = phase - phase[ref, cols]
        diff -= period * np.round(diff / period)
        rho = np.where(valid, diff * C_AIR, 0.0)       # pseudo-ranges less the reference's
        # start: the pair solutions with the reference, the best under a capped cost
        s_ref = s[ref, cols]
        cand = 0.5 * (s + s_ref - np.sign(s - s_ref) * rho)
        cand = np.clip(cand, np.minimum(s, s_ref), np.maximum(s, s_ref))
        dx = cand[:, None, :] - s[None]                 # (candidate, slot, n)
        e = rho - (np.sqrt(dx * dx + d2) - np.sqrt((cand - s_ref) ** 2 + d2[ref, cols])[:, None, :])
        cost = np.where(valid, np.add.reduce(np.minimum(w * e * e, 25.0), axis=1), np.inf)
        x0 = cand[cost.argmin(axis=0), cols]
        xs, var, chi2, es = self._subset_solutions(tab.maskf, x0, rho, s, d2, w)
        full = np.where(nv > 0, self._slot_bits @ valid - 1, -1)
        # a subset whose geometry does not fix x (its differences flatten) has no solution: not
        # a candidate, and a fault that leaves only it is unbounded
        var = np.where(var <= p["max_geometry_sigma"] ** 2, var, np.inf)
        chosen, ok, sd, unident, inconsistent = self._isolate(tab, xs, var, chi2, full, None)
        few = nv < 2
        weak = ~few & ~(var[np.maximum(full, 0), cols] < np.inf)
        self.stats["too_few"] += int(np.count_nonzero(few))
        self.stats["geometry"] += int(np.count_nonzero(weak))
        few |= weak
        ok &= ~few
        self.stats["unidentifiable"] += int(np.count_nonzero(unident & ~few))
        self.stats["inconsistent"] += int(np.count_nonzero(inconsistent & ~few))
        x = xs[chosen, cols]
        ls = var[chosen, cols]
        size = tab.size[chosen]
        if self._groups.shape[1]:
            # a common-cause group's stations may be wrong together: the rest must bound x
            group_sd = self._group_protection(tab, xs, var, chosen, self._group_bits(idx, valid))
            self.stats["common_cause"] += int(np.count_nonzero(ok & (group_sd > sd)))
            sd = np.maximum(sd, group_sd)
        if p["min_stations"] <= 2:
            # two stations: nothing left to check them, published unchecked
            sd = np.where(ok & (size == 2), np.sqrt(ls + p["unchecked_sigma"] ** 2), sd)
        if self._withhold_two:
            # two faults alike among three in view pass the one-dof test together
            unprotected = ok & (nv == 3) & (size == 3)
            self.stats["unprotected"] += int(np.count_nonzero(unprotected))
            ok &= ~unprotected
        unbounded = ok & ~(sd < np.inf)
        self.stats["unbounded"] += int(np.count_nonzero(unbounded))
        ok &= ~unbounded
        used = tab.mask[chosen].T & valid
        return x, ok, used, es[chosen, :, cols].T, np.maximum(sd, self._min_sigma)

    @staticmethod
    def _subset_solutions(maskf, x0, rho, s, d2, w):
        """Gauss-Newton of every subset (maskf (S, SLOTS)) of every epoch from x0 (n,), the
        common offset of the subset's pseudo-ranges eliminated (= differencing against one
        of its stations with the correct covariance): x, LS variance, chi-square (S, n) and the
        residuals of all slots (S, SLOTS, n) at each subset's solution (offset of the subset
        removed)."""
        wm = maskf[:, :, None] * w[None]
        sw = np.add.reduce(wm, axis=1)
        x = np.repeat(x0[None, :], len(maskf), axis=0)
        for it in range(GN_ITERATIONS + 1):
            dx = x[:, None, :] - s
            r = np.sqrt(dx * dx + d2)
            h = dx / np.maximum(r, 1e-9)
            e = rho - r
            e -= (np.add.reduce(wm * e, axis=1) / sw)[:, None, :]
            g = h - (np.add.reduce(wm * h, axis=1) / sw)[:, None, :]
            wg = wm * g
            info = np.add.reduce(wg * g, axis=1)
            if it == GN_ITERATIONS:
                break
            step = np.where(info > 1e-12, np.add.reduce(wg * e, axis=1) / info, 0.0)   # 0: no information
            x = x + np.clip(step, -50.0, 50.0)
            if not np.abs(step).max() > 1e-7:
                break
        chi2 = np.add.reduce(wm * e * e, axis=1)
        var = np.where(info > 1e-12, 1.0 / np.maximum(info, 1e-300), np.inf)
        return x, var, np.where(np.isfinite(chi2), chi2, np.inf), e


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """TDOA fixes for the fusion: besides the white timing noise, per-station errors persist
    from epoch to epoch, of two kinds:

    * the synchronisation offsets (``sync_sigma``), constant: one fix-bias state carries the
      position error they make, sync offset / sqrt(2) with at least one station on each side
      of the antenna (sigma / sqrt(sum (g_i - mean g)^2), the slopes g_i = +-1: 1 / sqrt(2)
      for one on each side, less with more; a poorer geometry shows in the fix's own sigma,
      whose excess the fusion does not average, below). It does not decorrelate in time (a
      standing or slow train keeps its stations and their offsets), only as the stations in
      view change: over the SLOTS stations received, SLOTS x the mean spacing;
    * NLOS excess paths that the test let pass, and the common-cause groups the decoder
      covers: the published sigma is the protection level that covers them; what a fix reports
      beyond its white noise lasts as long as its cause: an NLOS episode (``nlos_duration``, or
      while the station is in view), a group's loss of synchronisation (``group_excess``:
      minutes, while the group is in view).

    The receiver clock cancels and adds nothing."""
    spacing, references = station_references(track, params)
    implied = ()
    if track is not None:
        ids, pos, _, _ = base_stations(track, params)
        implied = timing_groups(track, ids, pos, params["timing_neighbours"])
    excess = {"fix_excess_length": spacing, "fix_excess_tau": params["nlos_duration"],
              **group_excess(track, params, implied)}
    return ErrorModel("mmwave_tdoa", "position",
                      fix_bias_sigma=sync_sigma_m(params) / math.sqrt(2.0),
                      fix_bias_length=SLOTS * spacing, fix_bias_tau=math.inf, **excess,
                      fix_white_sigma=math.hypot(params["range_sigma_floor"], params["range_sigma_snr"]),
                      faults=("nlos", "outage"), min_stddev=min_fix_sigma(params), references=references)


SPEC = SensorSpec(
    node="mmwave_tdoa", sensor="mmwave_tdoa", simulator=MmWaveTdoaSimulator, decoder=MmWaveTdoaDecoder,
    params=PARAMS, description="on-board mm-wave radio positioning by time differences of arrival from "
                               "synchronised wayside base stations: absolute position",
    seeds=("002",), outputs=("position",), error_model=error_model,
)

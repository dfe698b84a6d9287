"""Millimetre-wave radio ranging to wayside base stations (on-board), seed 002.

Physics (seed 002 section 2.2.2, MLX): the mm-wave radio system locates the train
from the propagation delays of radio signals exchanged between the train and
several wayside base stations; it serves for the initialisation of the position
and for train protection, receives several base stations at once for safety, and
the MLX position system updates every 5 ms. Seed 002 section 2.2.1: the Transrapid
exchanges position and speed over a 38 GHz radio link with the wayside. The +-5 deg
accuracy that seed 002 gives for the whole MLX system (LSM electrical angle, i.e.
centimetres) comes from its incremental sensors; the radio ranging serves
initialisation and protection, for which decimetre-level ranges suffice.

Ranging scheme (our choice, documented): two-way ranging (TWR). The on-board radio
polls each base station; the station answers after a fixed, calibrated turnaround
time, so the round-trip time gives the one-way propagation delay
``tau = r / c_air`` without a common clock between train and stations (no clock
offset to estimate, unlike one-way TDOA). The device reports tau [s] per station.
All stations of one epoch are ranged in parallel (own codes/channels) within
~100 us, i.e. 1.4 cm of travel at 500 km/h: all delays of an epoch refer to the
epoch time.

Geometry: station i at chainage s_i, lateral distance ``offset`` d_i from the track
centre line and antenna height ``height`` h_i above rail level; the train antenna
at height ``antenna_height`` and ``antenna_offset`` behind the front. Treating the
track as locally straight,

    r_i = sqrt((x - s_i)^2 + d_i^2 + (h_i - h_a)^2),    x = antenna chainage.

Track equipment (kind ``mmwave_station``)::

    mmwave_station:
      - {id: MW001, position: 1200.0, offset: 5.0, height: 6.0, code: 1}
      - {every: 400.0, start: 200.0, end: 9800.0, id: "MW{n:03d}", offset: 5.0, height: 6.0}

``offset`` [m] is required (lateral distance, either side), ``height`` [m] defaults to
the parameter ``station_height``; ``code`` (integer > 0) is the number the radio
reports in the station-id channel; default: 1-based order along the track (the
order of ``Track.items``, i.e. by chainage). Codes must be unique.

Raw signal (one row per ranging epoch, default 200 Hz = the 5 ms MLX update period
of seed 002 section 2.2.2): the radio tracks the ``N_SLOTS`` = 4 nearest stations
within ``max_range`` (a hand-over set, so the raw rate does not grow with the
number of stations on the line: 12 channels x 200 Hz = 2400 samples/s). Slot k
(k = 0..3, slots ordered by station chainage) has three channels:

    station_k  station code (0 = empty slot)
    delay_k    one-way propagation delay [s]; 0 = no reply this epoch (dropout or
               below the detection threshold) -- the sentinel for a missing value,
               raw data never contain NaN
    snr_k      first-path signal-to-noise ratio [dB]; 0 with a missing reply

Errors modelled:
  * ranging noise growing as the SNR falls: sigma^2 = floor^2 +
    (sigma_snr 10^((20 dB - SNR)/20))^2 (Cramer-Rao bound of a time-of-arrival estimate
    ~ 1/sqrt(SNR)), with floor = decimetre level like UWB/mm-wave TWR transceivers
    (Decawave DW1000 / Qorvo DW3000 datasheets: +-10 cm ranging accuracy);
  * SNR from free-space path loss 20 log10(r) around ``snr_ref`` at ``ref_range``,
    with log-normal fading;
  * a constant per-station bias (residual of the antenna-delay calibration,
    Decawave APS014: few cm);
  * NLOS / multipath episodes per station: the direct path is blocked, the first
    detected path is a reflection: positive range bias (exponential, mean
    ``nlos_bias_mean``; UWB NLOS bias 0.3-2 m, Decawave APS006 part 3) and a
    first-path SNR loss;
  * lost replies (``dropout_prob``), replies below ``snr_threshold``;
  * injected faults (``faults``) for tests: a fixed bias or a dropout of one station
    over a time window.

Decoder: per epoch a weighted least-squares fit of the 1-D antenna chainage x to
the valid ranges (SNR >= ``snr_threshold``), with sigma_i from the reported SNR
plus the calibration term.
  * Ambiguity: a single range is symmetric about the station's chainage (x = s_i +-
    sqrt(r^2 - d^2)). The fit starts from the best of the 2 x stations candidates
    s_i +- sqrt(r_i^2 - d_i^2) under a robust (capped) cost over all stations; two
    stations at different chainages remove the ambiguity. If the two best candidates
    fit (nearly) equally well -- one station only (``min_stations`` = 1), or a
    degenerate geometry -- the candidate nearer to the previous solution predicted
    with the previous speed is taken; without a recent previous solution the epoch
    gives no fix.
  * Gauss-Newton on x (the range model is non-linear near a station).
  * A single-station fix (``min_stations`` = 1) has no redundancy: it is accepted
    only if it agrees (3 sigma) with the prediction from a previous solution at most
    0.3 s old, which catches the jump at an NLOS onset, and its variance gets
    ``unchecked_sigma``^2 added for the small biases that pass the gate. A longer
    NLOS episode breaks the chain: no fix until two stations are in view again.
  * Fault detection and isolation (solution separation, as GNSS RAIM / ARAIM): the
    chi-square test of the weighted residuals (``outlier_probability`` quantile, dof =
    stations - 1) detects a fault (NLOS / multipath lengthening a range, a calibration
    fault). If it fails, every subset of the stations is solved and tested; the largest
    consistent subsets (at least max(2, ``min_stations``) stations) are the candidates.
    One candidate isolates the fault: the other stations are excluded. Several candidates
    that agree (their +-k sigma intervals overlap) give the one whose sigma, widened to
    cover all of them, is smallest. Several that disagree: the fault is not identifiable
    (with 2-3 stations the largest residual is often a good range) and the epoch gives no
    fix (``stats["unidentifiable"]``), as does a failing test with no station to spare (2
    stations); no consistent subset with a station to spare: no fix (more than one fault,
    ``stats["inconsistent"]``).
  * Protection: a bias below the detection threshold still moves the solution, most where
    the redundancy is low (a range with a large leverage hides its bias in the residuals).
    The published sigma is PL / k (k = normal quantile of ``protection_probability``,
    3.29) with the solution-separation protection level PL = max(k sd, max_j d_j + k sd_j)
    of the used stations: d_j is the separation of the solution without station j and sd_j
    that solution's sigma; under a fault of j of any size that passed the test the error is
    -d_j plus the error of the solution without j, so every single fault is covered with the
    probability of the interval (not discounted by a fault prior: a bias may persist over
    many epochs). Where a fault could move the solution without bound (the other ranges do
    not fix x) there is no fix (``stats["unbounded"]``).
  * A second fault: once the test has found one, a second is about ``nlos_rate`` x
    ``nlos_duration`` as likely (NLOS occupancy odds of a station), far above the
    interval's risk at the default 1/40. Two ranges lengthened alike pass the test
    together and isolate the good station instead; so an isolated solution's sigma also
    covers, for each pair of its stations, the solution of the stations in view without
    that pair (its separation / k + its sigma; none left: no fix). Without a detection a
    double fault is a priori about (``nlos_rate`` x ``nlos_duration``)^2, below the
    interval's risk at the default; where it is not (above 0.063 episodes/s of 0.5 s), an
    epoch with two stations in view, which no test can protect against two faults, gives
    no fix (``stats["unprotected"]``).
  * Output: one PositionFix per epoch (``fix_per_block`` false) or one per block. Per
    block the epochs' all-in-view solutions give the motion (a straight line in time);
    each station's mean residual about it over the block (noise averaged, calibration
    bias not) forms one virtual epoch at the block's mean time, which goes through the same
    detection, isolation and protection as an epoch -- so a small bias persisting over the
    block, which the single epochs cannot see, is found there. position = x + orientation
    * ``antenna_offset``; stddev = the protected sigma above, at least ``min_fix_sigma``
    (the error model's floor). ``reference_id`` =
    comma-separated ids of the stations used (ascending chainage) followed by the excluded
    ones prefixed with "!"; ``residuals`` = measured minus fitted range [m], one per entry
    of ``reference_id`` in the same order (per block: mean over the epochs). direction = 0
    (ranging gives no direction of travel).
"""
from __future__ import annotations

import itertools
import math
import operator

import numpy as np
from scipy.special import chdtri, ndtri

from ..common_cause import FAULT_PERSISTENCE, member_groups
from ..measurements import PositionFix
from ..signals import InputRejected, RawBlock
from ..track import Track, TrackError
from .base import COMMON_PARAMS, Decoder, ErrorModel, Param, ReferenceTable, ReferenceWindow, SensorSpec, Simulator

C_AIR = 299_792_458.0 / 1.0003  # speed of light in air (refractive index ~1.0003) [m/s]
STATION_KIND = "mmwave_station"
N_SLOTS = 4
PRED_SIGMA = 0.25        # 1-sigma of the previous solution used for a prediction [m]
PRED_SPEED_SIGMA = 0.5   # 1-sigma speed error of the prediction [m/s] (slope over the history)
PRED_ACCEL = 1.5         # largest acceleration of the train [m/s^2]
SINGLE_HOLD = 0.3        # a single-station fix needs a previous solution younger than this [s]
SUBSET_ITERATIONS = 3    # Gauss-Newton steps of the subset solutions from the all-in-view one
_BRANCH = np.array([-1.0, 1.0])[:, None, None]  # the two candidates s -+ along of a range
# ndarray.sum/any/max/min go through Python wrappers (numpy 2); the decoder, called for every
# block with small arrays, calls the ufunc reductions directly (axis 0 by default)
_sum, _any, _all = np.add.reduce, np.logical_or.reduce, np.logical_and.reduce
_max, _min = np.maximum.reduce, np.minimum.reduce
SNR_NOISE_REF = 20.0  # SNR [dB] at which the SNR-dependent ranging term equals range_sigma_snr
MIN_RANGE_VAR = 1e-6  # least variance of one range in the fit [m^2]: (1 mm)^2, float32 delays

PARAMS = {
    "max_range": Param(1000.0, "radio range of a base station [m]; the nearest 4 stations within it are ranged "
                               "(38 GHz line-of-sight radio link, seed 002 section 2.2.1; ~1 km cells)",
                       (1.0, 10000.0)),
    "snr_ref": Param(35.0, "first-path SNR at ref_range with line of sight [dB]; falls with free-space path "
                           "loss 20 log10(r) (15 dB at 1 km)", (-20.0, 60.0)),
    "ref_range": Param(100.0, "range at which the SNR equals snr_ref [m]", (1.0, 10000.0)),
    "snr_fading": Param(1.5, "1-sigma fading of the reported SNR [dB]", (0.0, 20.0)),
    "snr_threshold": Param(10.0, "replies below this SNR are not detected / not used [dB]", (-20.0, 60.0)),
    "range_sigma_floor": Param(0.08, "1-sigma ranging noise at high SNR [m] (UWB/mm-wave TWR transceivers: "
                                     "+-10 cm, Decawave DW1000 / Qorvo DW3000 datasheets)", (0.0, 10.0)),
    "range_sigma_snr": Param(0.10, "1-sigma SNR-dependent ranging noise at 20 dB SNR [m], scales as "
                                   "10^((20-SNR)/20) (time-of-arrival Cramer-Rao bound ~ 1/sqrt(SNR))",
                             (0.0, 10.0)),
    "cal_sigma": Param(0.03, "1-sigma constant range bias per station [m] (antenna-delay calibration "
                             "residual, Decawave APS014)", (0.0, 1.0)),
    "nlos_rate": Param(0.05, "NLOS/multipath episodes per station per second [1/s] (structures, passing trains)",
                       (0.0, 100.0)),
    "nlos_duration": Param(0.5, "mean NLOS episode length [s]", (0.0, 3600.0)),
    "nlos_bias_mean": Param(1.0, "mean positive range bias of an NLOS episode [m], exponential "
                                 "(UWB NLOS bias 0.3-2 m, Decawave APS006 part 3)", (0.0, 50.0)),
    "nlos_snr_loss": Param(6.0, "first-path SNR loss during NLOS [dB] (APS006 part 3: > 6 dB first-path "
                                "to total power difference indicates NLOS)", (0.0, 60.0)),
    "dropout_prob": Param(0.02, "probability that a reply is lost in an epoch (packet loss) [1]", (0.0, 1.0)),
    "station_height": Param(6.0, "default station antenna height above rail level [m] (mast)", (0.0, 50.0)),
    "antenna_height": Param(3.0, "train antenna height above rail level [m]", (0.0, 10.0)),
    "antenna_offset": Param(0.0, "train antenna distance behind the front [m]; within a train of up to 1 km",
                            (0.0, 1000.0)),
    "orientation": Param(1, "+1: the train front faces increasing chainage (antenna at front - offset), "
                            "-1: decreasing [1]", (-1, 1)),
    "min_stations": Param(2, "minimum number of consistent stations for a fix [1] (1 = allow single-station "
                             "fixes resolved by the previous solution); at most the 4 stations ranged", (1, 4)),
    "unchecked_sigma": Param(0.5, "1-sigma added to single-station fixes [m]: without redundancy an NLOS bias "
                                  "(exponential, mean ~1 m) cannot be detected", (0.0, 50.0)),
    "outlier_probability": Param(0.999, "chi-square gate probability of the NLOS test [1]", (0.0, 1.0)),
    "max_fault_bias": Param(10.0, "largest range error of one fault that the protection covers where a "
                                  "single range is left to tell the side of its station (two stations, one "
                                  "being passed) [m]: NLOS excess path (exponential, mean nlos_bias_mean 1 m: "
                                  "beyond 10 m with probability 5e-5), calibration faults", (0.0, 1000.0)),
    "protection_probability": Param(0.999, "probability of the interval +-k sigma (k its normal quantile, 3.29) "
                                           "that the published sigma is widened to cover under an undetected "
                                           "single range fault (the fused 99.9 % interval) [1]", (0.0, 1.0)),
    "fix_per_block": Param(False, "false: one PositionFix per epoch (5 ms, seed 002); true: one per block"),
    "hold_time": Param(1.0, "a previous solution older than this is not used to resolve ambiguity [s]",
                       (0.0, 60.0)),
    "faults": Param("", "injected faults 'ID@T0-T1:BIAS' (range bias [m]) or 'ID@T0-T1:drop', "
                        "separated by ';' (tests)"),
}


def base_stations(track: Track, params: dict):
    """(ids, chainage, perpendicular distance, code) arrays of the track's base stations."""
    items = track.items(STATION_KIND)
    ids, pos, perp, codes = [], [], [], []
    for k, it in enumerate(items):
        if "offset" not in it:
            raise TrackError(f"{STATION_KIND} '{it['id']}' has no 'offset' (lateral distance [m])")
        height = float(it.get("height", params["station_height"]))
        ids.append(it["id"])
        pos.append(it["position"])
        perp.append(math.hypot(float(it["offset"]), height - params["antenna_height"]))
        codes.append(int(it.get("code", k + 1)))
    if len(set(codes)) != len(codes):
        raise TrackError(f"{STATION_KIND} codes are not unique")
    if any(c <= 0 or c >= 2 ** 24 for c in codes):
        raise TrackError(f"{STATION_KIND} codes must be integers in 1..2^24-1")
    return ids, np.asarray(pos, float), np.asarray(perp, float), np.asarray(codes, np.int64)


def covered_groups(track: Track, ids, params: dict, implied=()) -> list[tuple[int, ...]]:
    """The common-cause groups a mm-wave decoder covers among the stations ``ids``: the track's
    and ``implied`` ones (a decoder's own fault model) whose prior exceeds the risk its interval
    allows, 1 - protection_probability; per group the indices into ``ids`` of its members."""
    return member_groups(tuple(track.common_cause) + tuple(implied), ids, 1.0 - params["protection_probability"])


def group_excess(track: Track | None, params: dict, implied=()) -> dict:
    """The ErrorModel's ``fix_excess_length`` / ``fix_excess_tau`` where the decoder covers
    common-cause groups of the track's stations (``covered_groups``): the excess of a fix may be
    a group's shared error, lasting ``FAULT_PERSISTENCE`` s and shared over twice the radio
    range; {} where it covers none (or without a track)."""
    if track is None or not covered_groups(track, base_stations(track, params)[0], params, implied):
        return {}
    return {"fix_excess_length": 2.0 * params["max_range"],
            "fix_excess_tau": max(FAULT_PERSISTENCE, params["nlos_duration"])}


def parse_range_faults(text: str) -> list[tuple[str, float, float, float | None]]:
    """'ID@T0-T1:BIAS' / 'ID@T0-T1:drop' items -> (id, t0, t1, bias or None for drop)."""
    faults = []
    for item in filter(None, (s.strip() for s in str(text).split(";"))):
        try:
            sid, rest = item.split("@")
            window, what = rest.split(":")
            t0, t1 = (float(v) for v in window.split("-"))
            faults.append((sid.strip(), t0, t1, None if what.strip() == "drop" else float(what)))
        except ValueError:
            raise ValueError(f"malformed mmwave fault {item!r}; expected 'ID@T0-T1:BIAS' or 'ID@T0-T1:drop'") from None
    return faults


def channel_names() -> tuple[tuple[str, ...], tuple[str, ...]]:
    names, units = [], []
    for k in range(N_SLOTS):
        names += [f"station_{k}", f"delay_{k}", f"snr_{k}"]
        units += ["1", "s", "dB"]
    return tuple(names), tuple(units)


CHANNELS, UNITS = channel_names()


def range_sigma(snr, p: dict):
    """1-sigma ranging noise [m] for a first-path SNR [dB] (without the calibration term)."""
    thermal = p["range_sigma_snr"] * 10.0 ** ((SNR_NOISE_REF - np.asarray(snr, float)) / 20.0)
    return np.sqrt(p["range_sigma_floor"] ** 2 + thermal ** 2)


def max_delay(p: dict) -> float:
    """Longest one-way delay [s] the decoder accepts: twice ``max_range`` (at least 1 m) and
    1 us; beyond it a block is implausible. C_AIR times it is the decoder's reach of a station."""
    return 2.0 * max(p["max_range"], 1.0) / C_AIR + 1e-6


def range_variance_floor(p: dict) -> float:
    """Least variance [m^2] of one range in the decoder's fit: range_sigma(snr)^2 + cal_sigma^2
    at an infinite SNR, at least (1 mm)^2 (the resolution of float32 delays)."""
    return max(p["range_sigma_floor"] ** 2 + p["cal_sigma"] ** 2, MIN_RANGE_VAR)


def min_fix_sigma(p: dict) -> float:
    """Least 1-sigma [m] of a published fix: the LS sigma of N_SLOTS ranges of the least
    variance (range_variance_floor), each along the track (|partial| 1); every sigma the
    decoder publishes (protected, isolated, single station) is at least its solution's LS
    sigma. One fix per block: a station's mean range averages the noise of at most
    max_block_duration x sample_rate epochs (the pipeline's longest block), not the
    calibration bias; the decoder publishes no less (a block with a hand-over, more than
    N_SLOTS stations, is raised to it)."""
    var = range_variance_floor(p)
    if p["fix_per_block"]:
        cal2 = p["cal_sigma"] ** 2
        longest = p.get("max_block_duration", COMMON_PARAMS["max_block_duration"].default)
        epochs = math.ceil(longest * (p.get("sample_rate") or MmWaveSimulator.default_sample_rate))
        var = max(var - cal2, 1e-12) / epochs + cal2
    return math.sqrt(var / N_SLOTS)


def station_window(p: dict, position: float) -> tuple[float, float]:
    """Chainages [m] of the train front while the radio ranges a station at ``position``: the
    antenna within the decoder's reach (C_AIR x max_delay) of it, the front ``antenna_offset``
    ahead of the antenna in either orientation."""
    reach = C_AIR * max_delay(p) + p["antenna_offset"]
    return position - reach, position + reach


class MmWaveSimulator(Simulator):
    sensor = "mmwave"
    channels = CHANNELS
    units = UNITS
    default_sample_rate = 200.0

    def __init__(self, *args):
        super().__init__(*args)
        self.ids, self.pos, self.perp, self.codes = base_stations(self.track, self.params)
        n = len(self.ids)
        self.cal = self._station_bias(n)
        self.nlos_left = np.zeros(n)
        self.nlos_bias = np.zeros(n)
        index = {sid: k for k, sid in enumerate(self.ids)}
        self.faults = []
        for sid, t0, t1, bias in self._parse_faults(self.params["faults"]):
            if sid not in index:
                raise ValueError(f"mmwave fault names unknown station {sid!r}")
            self.faults.append((index[sid], t0, t1, bias))

    def _station_bias(self, n: int) -> np.ndarray:
        """Constant range bias [m] of each of the n stations: the antenna-delay calibration."""
        return self.rng.normal(0.0, self.params["cal_sigma"], n)

    _parse_faults = staticmethod(parse_range_faults)

    def samples(self, times, position, speed, acceleration):
        p = self.params
        n, m = len(times), len(self.ids)
        out = np.zeros((n, 3 * N_SLOTS))
        if m == 0:
            return out
        r, bias, noise, snr, lost = self._radio(times, position)
        measured = r + self.cal[None, :] + bias + noise
        replied = ~lost & (snr >= p["snr_threshold"]) & (measured > 0.0)
        chosen, ok = handover(r, p["max_range"])
        for k in range(min(N_SLOTS, m)):
            j = chosen[:, k]
            valid = ok[:, k]
            rep = valid & replied[np.arange(n), j]
            out[:, 3 * k] = np.where(valid, self.codes[j], 0)
            out[:, 3 * k + 1] = np.where(rep, measured[np.arange(n), j] / C_AIR, 0.0)
            out[:, 3 * k + 2] = np.where(rep, snr[np.arange(n), j], 0.0)
        return out

    def _radio(self, times, position):
        """The radio channel of every station at the epochs ``times``: true range r [m], the
        NLOS and injected range bias [m], the ranging noise [m], the first-path SNR [dB] and
        the lost replies, all (n, stations) (the random draws in a fixed order)."""
        p = self.params
        n, m = len(times), len(self.ids)
        dt = 1.0 / self.sample_rate
        x = position - p["orientation"] * p["antenna_offset"]
        r = np.hypot(x[:, None] - self.pos[None, :], self.perp[None, :])  # (n, m)
        # NLOS episodes per station (all stations, so the random stream does not depend on the set)
        starts = self.rng.random((n, m)) < p["nlos_rate"] * dt
        lengths = self.rng.exponential(p["nlos_duration"], (n, m))
        biases = self.rng.exponential(p["nlos_bias_mean"], (n, m))
        nlos = np.zeros((n, m), dtype=bool)
        bias = np.zeros((n, m))
        for i in range(n):
            new = starts[i] & (self.nlos_left <= 0.0)
            self.nlos_left[new] = lengths[i, new]
            self.nlos_bias[new] = biases[i, new]
            on = self.nlos_left > 0.0
            nlos[i], bias[i] = on, np.where(on, self.nlos_bias, 0.0)
            self.nlos_left[on] -= dt
        lost = self.rng.random((n, m)) < p["dropout_prob"]
        for k, t0, t1, fbias in self.faults:
            window = (times >= t0) & (times < t1)
            if fbias is None:
                lost[window, k] = True
            else:
                bias[window, k] += fbias
        snr = (p["snr_ref"] - 20.0 * np.log10(np.maximum(r, 1.0) / p["ref_range"])
               - np.where(nlos, p["nlos_snr_loss"], 0.0) + self.rng.normal(0.0, p["snr_fading"], (n, m)))
        noise = self.rng.normal(0.0, 1.0, (n, m)) * range_sigma(snr, p)
        return r, bias, noise, snr, lost


def handover(r: np.ndarray, max_range: float, slots: int = N_SLOTS):
    """Hand-over set of the radio at each epoch: the ``slots`` nearest stations within
    ``max_range`` of the ranges r (n, stations), slots by chainage. Returns the station index
    per slot (n, slots) and whether the slot holds a station (fewer stations in range than
    slots: the rest stay empty)."""
    in_range = r <= max_range
    order = np.argsort(np.where(in_range, r, np.inf), axis=1, kind="stable")[:, :slots]
    rows = np.arange(len(r))[:, None]
    chosen = np.sort(order, axis=1)  # station index order = chainage order
    return chosen, in_range[rows, chosen]


class _Pattern:
    """What the station-code channels of a block determine (cached per code pattern).

    Slot-major like the decoder's arrays: idx: station index per slot (0 for an empty slot),
    s: its chainage [m], d2: its squared perpendicular distance [m^2], key: 4 x idx (the
    station part of the per-epoch cache key of reference_id), all (N_SLOTS, n); s4 / d4: s
    and d2 of station j repeated for every candidate, (N_SLOTS, 2, N_SLOTS, n) (same-shape
    operands are cheaper than broadcast ones); lo / hi: (3 N_SLOTS, n) bounds that every
    channel of a valid block with these codes meets (None for a block that took the
    detailed checks); stations / loc: the stations in the block (ascending index) and each
    slot's position in that list, epoch-major (n, N_SLOTS) (block fixes; set by _compact).
    """

    __slots__ = ("idx", "s", "d2", "s4", "d4", "key", "lo", "hi", "stations", "loc")


_POPCOUNT = np.array([bin(b).count("1") for b in range(256)])   # set bits of a slot mask (<= 8 slots)


class _Subsets:
    """The non-empty subsets of m rows (stations or slots): subset i holds the rows of the
    bits of i + 1, so the last one holds them all.

    mask (S, m) bool and maskf (S, m) float: rows of each subset; bits (S,): i + 1; size
    (S,); loo (S, m): index of the subset less row j, valid where loo_ok (row j in the
    subset, which has another row; 0 elsewhere); loo_row (S, m): the row left where
    the subset less row j has a single row, else -1; gate (S,): chi-square gate of the
    subset's consistency test (dof = size - 1; inf for one row).
    """

    __slots__ = ("mask", "maskf", "bits", "size", "loo", "loo_ok", "loo_row", "gate")

    def __init__(self, m: int, gate_dof):
        bits = np.arange(1, 2 ** m)
        row_bits = 1 << np.arange(m)
        mask = (bits[:, None] & row_bits) > 0
        size = mask.sum(axis=1)
        loo_ok = mask & (size[:, None] > 1)
        self.mask, self.maskf, self.bits, self.size = mask, mask.astype(float), bits, size
        self.loo, self.loo_ok = np.where(loo_ok, (bits[:, None] ^ row_bits) - 1, 0), loo_ok
        other = np.argmax(mask[:, None, :] & ~np.eye(m, dtype=bool), axis=2)   # a row other than j
        self.loo_row = np.where(loo_ok & (size[:, None] == 2), other, -1)
        self.gate = np.array([gate_dof(int(k) - 1) for k in size])


def item_picker(order: list[int]):
    """Function list -> tuple of its items at the positions ``order`` (not empty)."""
    if len(order) == 1:
        j = order[0]
        return lambda row: (row[j],)
    return operator.itemgetter(*order)


class SolutionSeparation:
    """Fault detection and isolation by solution separation over the subsets of the stations in
    view, shared by the ranging decoder and the TDOA one (mmwave_tdoa.py): see the module
    docstring, "Fault detection and isolation" and "Protection". ``_init_separation`` sets
    what it needs from the parameters (protection_probability, nlos_rate, nlos_duration; the
    methods read min_stations and max_fault_bias); ``_gate_dof`` gives the consistency test's
    gate for a subset of k rows from dof = k - 1 (a user with other unknowns overrides it)."""

    def _init_separation(self, params: dict, slots: int = N_SLOTS) -> None:
        self._cols: dict = {}
        self._k_cover = float(-ndtri(0.5 * (1.0 - params["protection_probability"])))
        self._subset_tabs: dict = {}
        self._slot_bits = 1 << np.arange(slots)
        self._slot_pairs = [int(a | b) for a, b in itertools.combinations(self._slot_bits.tolist(), 2)]
        busy = params["nlos_rate"] * params["nlos_duration"]   # NLOS occupancy odds p / (1 - p) of a station
        risk = 1.0 - params["protection_probability"]
        # given one fault, a second is about p / (1 - p) as likely: cover it after an isolation
        self._cover_second_fault = busy > risk
        # both of two stations at once, a priori: two in view give no fix where that is likely
        self._withhold_two = busy * busy > risk

    def _init_groups(self, track, ids, implied=()) -> None:
        """The common-cause groups of the stations ``ids`` that this decoder covers
        (``covered_groups``), kept as a (stations, groups) membership matrix."""
        rows = covered_groups(track, ids, self.params, implied)
        self._groups = np.zeros((max(len(ids), 1), len(rows)), dtype=bool)
        for g, members in enumerate(rows):
            self._groups[list(members), g] = True

    def _group_bits(self, idx, valid) -> np.ndarray:
        """(groups in view, n) int: per covered group with a station in view, the bits of the
        valid slots (idx: station index per slot (slots, n)) whose station belongs to it."""
        in_view = self._groups[idx] & valid[:, :, None]                     # (slots, n, groups)
        bits = np.add.reduce(in_view * self._slot_bits[:, None, None], axis=0).T   # (groups, n)
        return bits[np.add.reduce(bits, axis=1) > 0]

    def _group_protection(self, tab, xs, var, sub, group_bits) -> np.ndarray:
        """Published 1-sigma (n,) that covers a fault of every covered group with two or more of
        its stations in view and one inside the chosen subsets ``sub`` (n,): the solution without all of the
        group's stations is taken as ``_protection`` takes the one without a single station (its
        separation / k + its sigma), whatever the group's stations do together (their errors
        may agree: two stations on one timing node walk off the same way and pass every test);
        infinite where fewer than two stations are left or the rest does not fix x (no fix)."""
        cols = self._columns(len(sub))
        bits = tab.bits[sub]
        x_s = xs[sub, cols]
        sigma = np.zeros(len(sub))
        for group in group_bits:
            # a group with two stations in view is suspect wherever one of them is used: the others
            # may have been excluded as if they were the only faulty ones
            several = (_POPCOUNT[group] >= 2) & (_POPCOUNT[bits & group] >= 1)
            if not _any(several):
                continue
            rest = (bits & ~group) - 1                     # subset index of the stations left (-1: none)
            k = np.maximum(rest, 0)
            # a single station left cannot tell its side (a range's mirror image fits it as well)
            cover = np.where(_POPCOUNT[rest + 1] >= 2,
                             np.abs(xs[k, cols] - x_s) / self._k_cover + np.sqrt(var[k, cols]), np.inf)
            sigma = np.where(several, np.maximum(sigma, cover), sigma)
        return sigma

    def _group_downdate(self, idx, valid, wh, h, e, info) -> np.ndarray:
        """Published 1-sigma (n,) that covers every common-cause group with two or more ranges in
        a linearised all-in-view LS solution (slot-major wh = w h, h, residuals e; info its
        information): the solution without the group is one downdate, x - x_G = sum_G w h e /
        (info - sum_G w h^2), covered as ``_group_protection`` covers it."""
        sigma = np.zeros(idx.shape[1])
        slot = np.arange(idx.shape[0])[:, None]
        for group in self._group_bits(idx, valid):
            inside = ((group[None, :] >> slot) & 1).astype(bool) & valid
            several = np.add.reduce(inside) >= 2
            if not _any(several):
                continue
            rest = info - np.add.reduce(np.where(inside, wh * h, 0.0))
            sep = np.abs(np.add.reduce(np.where(inside, wh * e, 0.0))) / np.maximum(rest, 1e-300)
            left = np.add.reduce(valid & ~inside) >= 2     # one range left cannot tell its side
            cover = np.where(left & (rest > 1e-6), sep / self._k_cover + 1.0 / np.sqrt(np.maximum(rest, 1e-300)),
                             np.inf)
            sigma = np.where(several, np.maximum(sigma, cover), sigma)
        return sigma

    def _subsets(self, m: int) -> "_Subsets":
        """Table of the non-empty subsets of m rows (cached per m)."""
        tab = self._subset_tabs.get(m)
        if tab is None:
            tab = self._subset_tabs[m] = _Subsets(m, self._gate_dof)
        return tab

    def _gate_dof(self, dof: int) -> float:
        """Chi-square gate of the consistency test with ``dof`` degrees of freedom (inf for 0)."""
        if dof <= 0:
            return math.inf
        return float(chdtri(dof, 1.0 - self.params["outlier_probability"]))

    def _isolate(self, tab, xs, var, chi2, full, mirrors):
        """Fault detection and isolation by solution separation.

        xs, var, chi2: (n_subsets, n) solution, its LS variance and its chi-square per subset of
        the rows of ``tab`` and per epoch; full: (n,) index of the subset of the rows in view
        (-1: none); mirrors: see _subset_protection. Returns the chosen subset (n,), ok (n,),
        the published 1-sigma (n,; see _protection; infinite where a fault would be unbounded:
        to be withheld) and two masks (n,): unidentifiable (a fault that cannot be isolated,
        also a failing test without a station to spare) and inconsistent (no subset with a
        station to spare passes: more than one fault).

        * Detection: the rows in view are used if their chi-square test passes.
        * Isolation: else the largest subsets (at least max(2, min_stations) rows) that pass
          are the candidates; the largest positive residual is not necessarily the faulty
          row when the redundancy is low. One candidate: its complement is excluded.
          Several: if every two of them agree (their +-k sigma intervals overlap) the fix is
          the candidate whose sigma, widened to cover every candidate's interval, is
          smallest; if two of them disagree the fault cannot be identified: no fix (counted
          in ``stats["unidentifiable"]``). Publishing one wide fix covering the disagreeing
          candidates is not done: the truth is near one of them, not between them, and a
          sigma spanning both would dress a bimodal error as a Gaussian one. No candidate at
          all: no fix (``stats["inconsistent"]``).
        """
        n = xs.shape[1]
        kz = self._k_cover
        size = tab.size[:, None]
        fbits = (full + 1)[None, :]
        avail = (tab.bits[:, None] & fbits) == tab.bits[:, None]
        cons = avail & (chi2 <= tab.gate[:, None]) & (var < np.inf)
        n_full = tab.size[full] * (full >= 0)
        min_keep = max(2, self.params["min_stations"])
        eligible = cons & ((size == n_full) | (size >= min_keep))
        level = np.maximum.reduce(np.where(eligible, size, 0), axis=0)
        chosen = np.where(full >= 0, full, 0)
        ok = level > 0
        isolate = ok & (level < n_full)
        sigma = np.full(n, np.inf)
        keep = ok & ~isolate
        if _any(keep):
            ki = keep.nonzero()[0]
            sigma[ki] = self._subset_protection(tab, xs, var, chosen[ki], ki, mirrors)
        if _any(isolate):
            ci = isolate.nonzero()[0]
            cand = eligible[:, ci] & (size == level[ci])
            sub, col = cand.nonzero()
            p_c = np.full(cand.shape, np.inf)
            p_c[sub, col] = self._subset_protection(tab, xs, var, sub, ci[col], mirrors)
            x_c = xs[:, ci]
            dist = np.abs(x_c[:, None, :] - x_c[None, :, :])      # (S, S', k)
            pair = cand[:, None, :] & cand[None, :, :]
            disagree = _any((pair & (dist > kz * (p_c[:, None, :] + p_c[None, :, :]))).reshape(-1, len(ci)))
            cover = np.where(pair, dist / kz + p_c[None, :, :], -np.inf)
            cover = np.where(cand, np.maximum.reduce(cover, axis=1), np.inf)
            pick = cover.argmin(axis=0)
            chosen[ci] = pick
            sigma[ci] = cover[pick, self._columns(len(ci))]
            if self._cover_second_fault:
                sigma[ci] = np.maximum(sigma[ci], self._second_fault(tab, xs, var, chi2, pick, ci, full[ci] + 1))
            ok[ci] = ~disagree
            unident = np.zeros(n, dtype=bool)
            unident[ci] = disagree
        else:
            unident = isolate
        # nothing passes: a fault with no station to spare (2 stations: either may be the
        # faulty one) is not identifiable; with stations to spare, more than one is faulty
        none = (full >= 0) & (level == 0)
        spare = n_full > min_keep
        return chosen, ok, sigma, unident | (none & ~spare), none & spare

    def _second_fault(self, tab, xs, var, chi2, sub, col, full_bits):
        """Published 1-sigma (K,) that also covers two faults inside each chosen subset ``sub``
        (K,) at epochs ``col`` (K,): the isolation found one fault, and its leave-one-out
        protection covers one more, but two faults that agree (two NLOS ranges lengthened
        alike) pass the test together and isolate the one good station instead. Given one
        fault, such a pair is about p / (1 - p) as likely as the single fault, p the
        probability that a station is in NLOS at an epoch (``nlos_rate`` x ``nlos_duration``
        as an on/off occupancy). For each pair of the subset's stations, the solution of
        the stations in view without them (if consistent) is covered as the others are:
        its separation / k + its sigma; where none is left, or it is unbounded, the sigma is
        infinite (no fix)."""
        x_s = xs[sub, col]
        sigma = np.zeros(len(col))
        bits = tab.bits[sub]
        for pair in self._slot_pairs:
            inside = (bits & pair) == pair
            if not _any(inside):
                continue
            rest = (full_bits & ~pair) - 1            # subset index of the stations left (-1: none)
            k = np.maximum(rest, 0)
            fits = (rest >= 0) & (chi2[k, col] <= tab.gate[k])
            cover = np.where(fits, np.abs(xs[k, col] - x_s) / self._k_cover + np.sqrt(var[k, col]), np.inf)
            sigma = np.where(inside & ((rest < 0) | fits), np.maximum(sigma, cover), sigma)
        return sigma

    def _subset_protection(self, tab, xs, var, sub, col, mirrors):
        """Published 1-sigma (K,) of the solutions of subsets ``sub`` (K,) at epochs ``col``
        (K,), from the solutions without each of their rows (_protection).

        mirrors: (mirror (m, n), reach (m, m, n)): the mirror image of each row's
        single-row solution about its station, and whether a fault of row j within
        ``max_fault_bias`` could put the train there (reach[j, k]); where a fault of row j
        leaves row k alone, the separation covers that mirror too (_mirrors).
        """
        loo = tab.loo[sub].T                     # (m, K)
        has = tab.loo_ok[sub].T
        x_s = xs[sub, col]
        sep = np.abs(xs[loo, col] - x_s)
        k = tab.loo_row[sub].T
        if mirrors is not None and _any(k >= 0, axis=None):
            mirror, reach = mirrors
            kk = np.maximum(k, 0)
            far = (k >= 0) & reach[np.arange(len(k))[:, None], kk, col]
            sep = np.where(far, np.maximum(sep, np.abs(mirror[kk, col] - x_s)), sep)
        return self._protection(sep, np.sqrt(var[loo, col]), has, np.sqrt(var[sub, col]))

    def _mirrors(self, x_single, s, r_fn):
        """(mirror, reach) for _subset_protection. A single range leaves the side of its
        station open: x_single (m, n) is each row's single-row solution, s (m, n) its
        station's chainage, so the mirror image 2 s - x_single fits that range as well.
        r_fn(mirror) -> (m_j, m_k, n) residuals of every row j at the mirror images of every
        row k: a fault of row j can put the train at row k's mirror only with a bias of that
        size, so it counts up to ``max_fault_bias``."""
        mirror = 2.0 * s - x_single
        return mirror, np.abs(r_fn(mirror)) <= self.params["max_fault_bias"]

    def _protection(self, sep, sd_j, has, sd):
        """Published 1-sigma (K,) of a solution of LS sigma ``sd`` (K,) whose rows j (axis 0
        of the (m, K) arrays, where ``has``) may be faulty: ``sep`` is the separation from
        the solution without row j, ``sd_j`` that solution's sigma.

        Were row j biased by any amount that the test let pass, the solution without it is
        unbiased, so the error is -+sep_j plus that solution's own error: |error| <= sep_j +
        k sd_j with the probability of the +-k sigma interval (k = normal quantile of
        ``protection_probability``), for every size of the bias, seen by the test or not.
        The published sigma max(sd, max_j sep_j / k + sd_j) therefore puts the error of any
        single fault inside +-k sigma with that probability (solution-separation protection
        level, as ARAIM, with every fault mode covered in full: a fault here is no rare
        independent event but may persist over many epochs -- a biased calibration, a
        structure in the line of sight -- so the risk is not discounted by a prior). It is
        what the test cannot see at low redundancy: a row with a large leverage moves x and
        hides its bias in the residuals, and the solution without it is much less precise
        (large sd_j). A mode without a solution (sd_j infinite) gives no bound: infinite
        sigma, no fix.
        """
        reach = np.where(has, sep * (1.0 / self._k_cover) + sd_j, 0.0)
        return np.maximum(sd, np.maximum.reduce(reach, axis=0))

    def _columns(self, n):
        """np.arange(n), cached per block length."""
        cols = self._cols.get(n)
        if cols is None:
            cols = self._cols[n] = np.arange(n)
            cols.flags.writeable = False
        return cols


class MmWaveDecoder(SolutionSeparation, Decoder):
    """Decoder. Arrays over the epochs and slots of a block are slot-major, (N_SLOTS, n):
    per-epoch values (n,) then broadcast without reshaping, and sums over the slots (axis 0)
    add the slots in order, as a row sum does."""

    sensor = "mmwave"
    channels = CHANNELS
    caches = ("_patterns", "_offsets")

    def __init__(self, params: dict, track: Track):
        super().__init__(params, track)
        self.ids, self.pos, self.perp, self.codes = base_stations(track, params)
        self._code_index = {int(c): k for k, c in enumerate(self.codes)}
        self._lut = np.full(int(self.codes.max()) + 1 if len(self.codes) else 1, -1, dtype=np.int64)
        for c, k in self._code_index.items():
            self._lut[c] = k
        self._max_delay = max_delay(params)
        self._min_sigma = min_fix_sigma(params)
        self._neg_slots = -np.arange(1, N_SLOTS + 1)[:, None]
        self._lut0 = self._lut.copy()
        self._lut0[0] = 0
        self._perp2 = self.perp * self.perp
        # every predicted range is >= the station's perpendicular distance: with none below
        # 0.1 mm the 1e-9 m guard of the partials can never act and is skipped
        self._guard_pred = not (len(self.perp) and float(self.perp.min()) >= 1e-4)
        # stations strictly by chainage: a block fix lists them in index order
        self._pos_increasing = bool(np.all(self.pos[1:] > self.pos[:-1]))
        self._patterns: dict = {}
        self._ref_cache: dict = {}
        # range_sigma(snr)^2 + cal_sigma^2 = const + coef * exp(snr * expo)
        self._sig2_const = params["range_sigma_floor"] ** 2 + params["cal_sigma"] ** 2
        self._sig2_snr = (params["range_sigma_snr"] * 10.0 ** (SNR_NOISE_REF / 20.0)) ** 2
        self._sig2_exp = -math.log(10.0) / 10.0
        # the 1 mm floor of sigma^2 can only act if the constant part is below it
        self._sig2_floor = not self._sig2_const >= MIN_RANGE_VAR
        self._init_separation(params)
        self._init_groups(track, self.ids)
        self._block_loo: dict = {}   # per number of stations: all of them, then without each
        self._single_index = self._slot_bits - 1   # subset index of each slot alone
        self._gate_size = np.array([self._gate_dof(k - 1) for k in range(N_SLOTS + 1)])   # by stations
        self._prev_t: float | None = None
        self._prev_x: float | None = None
        self._prev_v = 0.0
        self._speed_src = None   # history the speed _prev_v is still to be computed from
        self._hist: list = []     # solutions of the last hold_time: per block (t, x, var, first t, last t)
        self._hist_n = 0
        self._hist_sorted = True  # history times ascending (blocks in time order)
        self.stats.update(epochs=0, fixes=0, rejected_stations=0, no_fix=0, ambiguous=0, inconsistent_single=0,
                          unidentifiable=0, inconsistent=0, unbounded=0, unprotected=0)

    # -- input checks -------------------------------------------------------------------
    def _check(self, data, codes_f, delay, snr) -> _Pattern:
        """Station pattern of a block (data: the channels, (3 N_SLOTS, n)); raises
        InputRejected for a bad block.

        The checks of the code channels depend on the codes only; they are cached per code
        pattern (the same stations are in view for many blocks) together with the bounds
        that every channel must then meet, so a good block costs one combined test. Only a
        block that fails it goes through the detailed checks, which give the reason.
        """
        key = codes_f.tobytes()
        pat = self._patterns.get(key)
        if pat is None:
            pat = self._code_pattern(codes_f)
            if pat is not None:
                if len(self._patterns) > 256:
                    self._patterns.clear()
                self._patterns[key] = pat
        if pat is not None and _all((data >= pat.lo) & (data <= pat.hi), axis=None):
            return pat
        # epoch-major views: the first offending sample in the messages is the first by time
        codes, present = self._check_detail(codes_f.T, delay.T, snr.T)
        return self._pattern(np.ascontiguousarray(np.where(present, self._lut[np.where(present, codes, 0)], 0).T))

    def _pattern(self, idx) -> _Pattern:
        pat = _Pattern()
        pat.idx, pat.s, pat.d2, pat.key = idx, self.pos[idx], self._perp2[idx], idx * 4
        shape = (N_SLOTS, 2, N_SLOTS, idx.shape[1])
        pat.s4 = np.ascontiguousarray(np.broadcast_to(pat.s[:, None, None, :], shape))
        pat.d4 = np.ascontiguousarray(np.broadcast_to(pat.d2[:, None, None, :], shape))
        pat.lo = pat.hi = pat.stations = pat.loc = None
        for a in (pat.idx, pat.s, pat.d2, pat.key, pat.s4, pat.d4):
            a.flags.writeable = False   # shared by the blocks of the pattern
        return pat

    @staticmethod
    def _compact(pat: _Pattern):
        """The pattern's stations (ascending index) and each slot's position among them,
        epoch-major (n, N_SLOTS): per-station sums over a block need no search."""
        if pat.loc is None:
            stations, loc = np.unique(pat.idx.T.ravel(), return_inverse=True)
            pat.stations, pat.loc = stations.tolist(), loc.reshape(pat.idx.shape[::-1])
        return pat.stations, pat.loc

    def _code_pattern(self, codes_f) -> _Pattern | None:
        """Pattern of valid code channels (N_SLOTS, n) (known integer codes, no station twice
        in an epoch) with the bounds of the other channels; None if the codes are not valid."""
        if not ((codes_f >= 0.0) & (codes_f <= len(self._lut) - 1.0)).all():
            return None
        codes = codes_f.astype(np.int64)
        k = self._lut0[codes]          # station index, 0 for an empty slot, -1 unknown code
        if not ((codes == codes_f).all() and (k >= 0).all()):
            return None
        present = codes > 0
        srt = np.sort(np.where(present, codes, self._neg_slots), axis=0)
        if (srt[1:] == srt[:-1]).any():
            return None
        pat = self._pattern(k)
        # a replying station: delay 0..max, SNR -30..100 dB; an empty slot: delay = SNR = 0
        shape = (3 * N_SLOTS, codes_f.shape[1])
        pat.lo, pat.hi = np.zeros(shape), np.zeros(shape)
        pat.lo[0::3] = pat.hi[0::3] = codes_f
        pat.hi[1::3] = np.where(present, self._max_delay, 0.0)
        pat.lo[2::3] = np.where(present, -30.0, 0.0)
        pat.hi[2::3] = np.where(present, 100.0, 0.0)
        pat.lo.flags.writeable = pat.hi.flags.writeable = False
        return pat

    def _check_detail(self, codes_f, delay, snr):
        if np.any(codes_f != np.round(codes_f)) or np.any(codes_f < 0):
            raise InputRejected("unknown_id", "station channel holds a non-integer or negative code")
        beyond = codes_f > len(self._lut) - 1   # before the cast: 1e19 would wrap to a negative int64
        if beyond.any():
            raise InputRejected("unknown_id", f"station code {codes_f[beyond][0]:.0f} is not on track "
                                              f"{self.track.track_id}")
        codes = codes_f.astype(np.int64)
        present = codes > 0
        bad = present & ((codes >= len(self._lut)) | (self._lut[np.minimum(codes, len(self._lut) - 1)] < 0))
        if bad.any():
            raise InputRejected("unknown_id", f"station code {int(codes[bad][0])} is not on track "
                                              f"{self.track.track_id}")
        if np.any(delay < 0.0) or np.any(delay > self._max_delay):
            raise InputRejected("implausible", f"propagation delay outside 0..{self._max_delay:.3e} s")
        if np.any(~present & ((delay != 0.0) | (snr != 0.0))):
            raise InputRejected("implausible", "empty slot carries a delay or SNR")
        if np.any((snr < -30.0) | (snr > 100.0)):
            raise InputRejected("implausible", "SNR outside -30..100 dB")
        srt = np.sort(np.where(present, codes, -np.arange(1, codes.shape[1] + 1)), axis=1)
        if np.any(np.diff(srt, axis=1) == 0):
            raise InputRejected("implausible", "one station reported in two slots of an epoch")
        return codes, present

    # -- decoding -----------------------------------------------------------------------
    def decode(self, block: RawBlock):
        p = self.params
        data = block.data.T.astype(float, order="C")   # channel-major, (3 N_SLOTS, n)
        codes_f, delay, snr = data[0::3], data[1::3], data[2::3]
        pat = self._check(data, codes_f, delay, snr)
        n = block.n_samples
        times = block.t0 + self.sample_offsets(n, block.sample_rate)   # = block.times()
        # an empty slot has delay 0 (checked), so a positive delay implies a station
        valid = (delay > 0.0) & (snr >= p["snr_threshold"])
        rng = delay * C_AIR
        # range_sigma(snr)^2 + cal_sigma^2, >= 1 mm (float32 delays)
        sig2 = self._sig2_const + self._sig2_snr * np.exp(snr * self._sig2_exp)
        if self._sig2_floor:
            sig2 = np.maximum(sig2, MIN_RANGE_VAR)
        self.stats["epochs"] += n
        if p["fix_per_block"]:
            return self._decode_block(times, rng, pat, sig2, valid)
        x, ok, used, resid, var = self._solve(times, rng, pat, sig2, valid, True)
        n_ok = int(np.count_nonzero(ok))
        if n_ok:
            if n_ok == n:
                self._remember(times, x, var)
            else:
                self._remember(times[ok], x[ok], var[ok])
        self.stats["no_fix"] += n - n_ok
        if used is not valid:  # else no station was excluded
            self.stats["rejected_stations"] += int(np.count_nonzero(valid & ~used & ok))
        if not n_ok:
            return []
        front = x + p["orientation"] * p["antenna_offset"]
        fixes = []
        # per slot one small integer, 4 x station index + 2 x used + valid: per epoch the
        # cache key of its reference_id and residual order
        code = pat.key + (valid * 3 if used is valid else used * 2 + valid)
        # (the LS sigma is never below min_fix_sigma; the floor only guards the round-off)
        sigma = np.maximum(np.sqrt(var), self._min_sigma)
        epochs = zip(times.tolist(), front.tolist(), sigma.tolist(), resid.T.tolist(), map(tuple, code.T.tolist()))
        if n_ok < n:
            epochs = itertools.compress(epochs, ok.tolist())
        sensor, unit, track_id = self.sensor, self.unit_id, self.track.track_id
        cache = self._ref_cache
        if len(cache) > 4096:
            cache.clear()
        for t_i, front_i, sigma_i, resid_i, key in epochs:
            hit = cache.get(key)
            if hit is None:
                hit = cache[key] = self._ref_order(key)
            fixes.append(PositionFix(t_i, sensor, unit, track_id, hit[0], front_i, sigma_i, 0, hit[1](resid_i)))
        self.stats["fixes"] += len(fixes)
        return fixes

    def _ref_order(self, code):
        """reference_id of one epoch and the function picking its residuals (used stations,
        then rejected ones) from the slots; code: per slot 4 x station index + 2 x used + valid."""
        order = [j for j in range(N_SLOTS) if code[j] & 2]
        rej = [j for j in range(N_SLOTS) if (code[j] & 3) == 1]
        ids = self.ids
        ref = ",".join([ids[code[j] >> 2] for j in order] + ["!" + ids[code[j] >> 2] for j in rej])
        return ref, item_picker(order + rej)

    # -- one fix per block ----------------------------------------------------------------
    def _decode_block(self, times, r, pat, sig2, valid):
        """One fix per block: the epochs' all-in-view solutions give the motion (a straight
        line in time); the ranges' mean residuals about it, per station, form one virtual
        epoch (noise averaged over the block, calibration bias not) that goes through the
        same fault detection and isolation as a single epoch (_isolate)."""
        p = self.params
        n = len(times)
        x0, ok0, _, _, _ = self._solve(times, r, pat, sig2, valid, False)
        n_ok = int(np.count_nonzero(ok0))
        if not n_ok:
            self.stats["no_fix"] += n
            return []
        t, x = times[ok0], x0[ok0]
        tm = float(t.mean())
        tt = t - tm
        den = float(np.dot(tt, tt))
        xm = float(x.mean())
        v = float(np.dot(tt, x - xm)) / den if den > 0.0 else 0.0
        stations, loc = self._compact(pat)
        sel = (valid & ok0).T   # epoch-major, like loc
        ks = loc[sel]
        m_all = len(stations)
        cnt = np.bincount(ks, minlength=m_all)
        rows = np.flatnonzero(cnt)
        m = len(rows)
        row_of = np.zeros(m_all, dtype=np.int64)
        row_of[rows] = np.arange(m)
        rk = row_of[ks]
        cnt = cnt[rows]
        # per station (row) the mean over the block of a per-epoch, per-slot value (epoch-major)
        avg = np.zeros((n * N_SLOTS, m))
        avg[sel.ravel().nonzero()[0], rk] = 1.0 / cnt[rk]
        cal2 = p["cal_sigma"] ** 2
        noise = np.bincount(rk, (sig2 - cal2).T[sel], minlength=m) / cnt
        w_bar = 1.0 / (np.maximum(noise, 1e-12) / cnt + cal2)
        line = xm + v * (times - tm)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            # the all-in-view block solution and those without each station
            sub = self._block_loo.get(m)
            if sub is None:
                sub = self._block_loo[m] = np.vstack([np.ones(m), 1.0 - np.eye(m)])
            member = self._groups[np.asarray(stations)[rows]]          # (m, groups)
            member = member[:, np.add.reduce(member, axis=0) >= 2].T   # groups with two rows or more
            if len(member):   # and without each common-cause group (_group_protection)
                sub = np.vstack([sub, 1.0 - member])
            delta, var, chi2, e_bar = self._block_solutions(sub, line, r, pat, w_bar, avg)
            if len(member):   # a group that leaves a single station: its side is open, no bound
                var[m + 1:] = np.where(m - member.sum(axis=1) >= 2, var[m + 1:], np.inf)
            if chi2[0] <= self._subsets(m).gate[-1] and var[0] < np.inf:
                has = np.full((len(sub) - 1, 1), m > 1)
                sep = np.abs(delta[1:] - delta[0])
                if m == 2:   # without one station the other is left alone: its mirror image
                    mirror, reach = self._block_mirrors(delta[[2, 1]], line, r, pat, avg, rows, stations, xm)
                    far = reach[[0, 1], [1, 0]]
                    sep[:2] = np.where(far, np.maximum(sep[:2], np.abs(mirror[[1, 0]] - delta[0])), sep[:2])
                sigma = float(self._protection(sep[:, None], np.sqrt(var[1:])[:, None], has, np.sqrt(var[:1]))[0])
                ok, c, used_rows = sigma < np.inf, 0, np.ones(m, dtype=bool)
                if not ok:
                    self.stats["unbounded"] += 1
                elif m == 2 and self._withhold_two:
                    ok = False   # as per epoch: two faults alike pass unseen, too likely to ignore
                    self.stats["unprotected"] += 1
            else:
                tab = self._subsets(m)
                delta, var, chi2, e_bar = self._block_solutions(tab.maskf, line, r, pat, w_bar, avg)
                full = np.array([len(tab.size) - 1])
                single = (1 << np.arange(m)) - 1
                mirror, reach = self._block_mirrors(delta[single], line, r, pat, avg, rows, stations, xm)
                chosen, good, sd, unident, inconsistent = self._isolate(tab, delta[:, None], var[:, None],
                                                                        chi2[:, None], full,
                                                                        (mirror[:, None], reach[:, :, None]))
                if self._groups.shape[1]:
                    bits = (member.astype(np.int64) << np.arange(m)).sum(axis=1)[:, None]   # (groups, 1)
                    sd = np.maximum(sd, self._group_protection(tab, delta[:, None], var[:, None], chosen, bits))
                ok, c, sigma = bool(good[0] and sd[0] < np.inf), int(chosen[0]), float(sd[0])
                used_rows = tab.mask[c]
                self.stats["unidentifiable"] += int(unident[0])
                self.stats["inconsistent"] += int(inconsistent[0])
                self.stats["unbounded"] += int(good[0] and not ok)
        if not ok:
            self.stats["no_fix"] += n
            return []
        if int(used_rows.sum()) == 1:
            sigma = math.hypot(sigma, p["unchecked_sigma"])   # no redundancy in the block
        sigma = max(sigma, self._min_sigma)
        x_fix = xm + float(delta[c])
        self._remember(t, x_fix + v * tt, np.full(n_ok, sigma ** 2))
        self.stats["no_fix"] += n - n_ok
        self.stats["rejected_stations"] += int(cnt[~used_rows].sum())
        self.stats["fixes"] += 1
        rank = list(range(m))   # rows: stations in view by index
        if not self._pos_increasing:
            # by chainage, then in order of first appearance (epoch, slot)
            first: dict = {}
            for j, k in enumerate(rk.tolist()):
                first.setdefault(k, j)
            rank.sort(key=lambda k: (float(self.pos[stations[rows[k]]]), first[k]))
        u_sel = [k for k in rank if used_rows[k]]
        r_sel = [k for k in rank if not used_rows[k]]
        ids = self.ids
        ref = ",".join([ids[stations[rows[k]]] for k in u_sel] + ["!" + ids[stations[rows[k]]] for k in r_sel])
        resid = e_bar[c].tolist()
        residuals = tuple(resid[k] for k in u_sel + r_sel)
        front = x_fix + p["orientation"] * p["antenna_offset"]
        return [PositionFix(tm, self.sensor, self.unit_id, self.track.track_id, ref, front, sigma, 0, residuals)]

    def _block_mirrors(self, delta_single, line, r, pat, avg, rows, stations, xm):
        """(mirror (m,), reach (m, m)) of the block's single-station solutions (offsets
        delta_single (m,) from ``line``) as _mirrors: the mirror image of the motion about
        station k, as an offset at the block's mean time, and whether the mean residual of
        station j there is within ``max_fault_bias``."""
        s_k = self.pos[np.asarray(stations)[rows]]
        m = len(rows)
        x_mirror = 2.0 * s_k[:, None] - (line + delta_single[:, None])        # (m_k, n)
        dx = x_mirror[:, None, :] - pat.s                                     # (m_k, N_SLOTS, n)
        e = (r - np.sqrt(dx * dx + pat.d2)).transpose(0, 2, 1).reshape(m, -1) @ avg    # (m_k, m_j)
        return 2.0 * (s_k - xm) - delta_single, np.abs(e.T) <= self.params["max_fault_bias"]

    def _block_solutions(self, maskf, line, r, pat, w_bar, avg):
        """Block solutions of subsets of the block's stations (maskf (S, m), 1 for a station in
        the subset): the offset delta (S,) from the motion ``line`` (n,) that fits the
        stations' mean residuals over the block (Gauss-Newton on the exact per-epoch ranges,
        averaged: the range of a station being passed is far from linear), its LS variance
        and chi-square (S,) and the mean residuals (S, m) there. w_bar: weights of the mean
        residuals; avg: (n N_SLOTS, m) averaging matrix of epoch-major per-slot values."""
        n_sub = len(maskf)

        def mean_residuals(delta):
            dx = (line + delta[:, None])[:, None, :] - pat.s       # (S, N_SLOTS, n)
            pred = np.sqrt(dx * dx + pat.d2)
            return ((dx / np.maximum(pred, 1e-9)).transpose(0, 2, 1).reshape(n_sub, -1) @ avg,
                    (r - pred).transpose(0, 2, 1).reshape(n_sub, -1) @ avg)
        return self._subsets_gauss_newton(np.zeros(n_sub), maskf * w_bar, mean_residuals)

    @staticmethod
    def _subsets_gauss_newton(x, wm, model):
        """Gauss-Newton of many subsets at once: x (S, ...) start, wm (S, rows, ...) weights
        (0 for a row not in the subset), model(x) -> partials and residuals (S, rows, ...)
        at x. SUBSET_ITERATIONS steps (each within 50 m) from the start; returns x, the LS
        variance, the chi-square (S, ...) and the residuals at x."""
        for it in range(SUBSET_ITERATIONS + 1):
            h, e = model(x)
            wh = wm * h
            info = np.add.reduce(wh * h, axis=1)
            if it == SUBSET_ITERATIONS:
                break
            step = np.add.reduce(wh * e, axis=1) / np.where(info > 1e-9, info, np.inf)
            x = x + np.clip(step, -50.0, 50.0)
        chi2 = np.add.reduce(wm * e * e, axis=1)
        var = np.where(info > 1e-6, 1.0 / np.maximum(info, 1e-300), np.inf)
        return x, var, chi2, e

    def _subset_solutions(self, maskf, x0, r, s, d2, w):
        """Gauss-Newton solutions of subsets of the slots (maskf: (S, N_SLOTS), 1 for a slot
        in the subset), started from the all-in-view solution x0 (n,): x, LS variance,
        chi-square (S, n) and the residuals of all slots at each subset's solution
        (S, N_SLOTS, n)."""
        def ranges(xs):
            dx = xs[:, None, :] - s
            pred = dx * dx
            pred += d2
            np.sqrt(pred, out=pred)
            return dx / np.maximum(pred, 1e-9), np.subtract(r, pred, out=pred)
        return self._subsets_gauss_newton(np.repeat(x0[None, :], len(maskf), axis=0), maskf[:, :, None] * w[None],
                                          ranges)

    # -- per-epoch solution ---------------------------------------------------------------
    def _solve(self, times, r, pat, sig2, valid, isolate):
        """Vectorised 1-D LS over the epochs of a block (arrays (N_SLOTS, n)).

        Returns x (n,), ok (n,), used (N_SLOTS, n; ``valid`` itself if no station was
        excluded), residuals (N_SLOTS, n) and the published variance (n,). ``isolate``
        false: the all-in-view solution without fault detection (the block fix tests the
        block's mean residuals instead); its variance is then the LS one.
        """
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            return self._solve_epochs(times, r, pat, sig2, valid, isolate)

    def _solve_epochs(self, times, r, pat, sig2, valid, isolate):
        p = self.params
        n = len(times)
        s, d2 = pat.s, pat.d2
        # sig2 > 0 and finite after the fast input check: valid / sig2 is 1 / sig2 or 0
        w = valid / sig2 if pat.lo is not None else np.where(valid, 1.0 / sig2, 0.0)
        nv = _sum(valid)
        # candidates s_k -+ along_k (2, N, n), robust capped cost over all valid stations j
        along = r * r
        along -= d2
        np.maximum(along, 0.0, out=along)
        np.sqrt(along, out=along)
        cand = s + along * _BRANCH
        q = cand - pat.s4                  # (N_j, 2, N_k, n)
        q *= q
        q += pat.d4
        np.sqrt(q, out=q)
        np.subtract(r[:, None, None, :], q, out=q)       # range residual
        q *= q
        q *= w[:, None, None, :]
        np.minimum(q, 25.0, out=q)
        cost = np.where(valid, np.add.reduce(q), np.inf).reshape(2 * N_SLOTS, n)
        cand = cand.reshape(2 * N_SLOTS, n)
        cols = self._columns(n)
        best = cost.argmin(axis=0)
        x = cand[best, cols]
        c1 = cost[best, cols]
        c2 = np.minimum.reduce(cost, axis=0, where=np.abs(cand - x) > 2.0, initial=np.inf)  # far ones
        # one station: always two branches; more: a distinct candidate fitting nearly as well
        # (no station: c1 = c2 = inf, not ambiguous)
        ambiguous = (c2 - c1 < 4.0) | (nv == 1)
        have_pred = self._prev_t is not None
        if _any(ambiguous):
            self.stats["ambiguous"] += int(ambiguous.sum())
            if have_pred:
                # candidates among the near-best: pick the one nearest to the prediction
                age, xp = self._prediction(times)
                near_best = cost - c1 < 4.0
                dist = np.where(near_best, np.abs(cand - xp), np.inf)
                pick = cand[dist.argmin(axis=0), cols]
                resolvable = ambiguous & (age <= p["hold_time"])
                x = np.where(resolvable, pick, x)
                ambiguous &= ~resolvable
        used = valid
        min_st = max(1, p["min_stations"])
        ok = (nv >= min_st) & ~ambiguous
        x, info, e, h = self._gauss_newton(x, r, s, d2, w)
        ok &= np.isfinite(x) & (info > 1e-6)
        var = 1.0 / info
        nu = nv
        unbounded = None
        if isolate and _any(ok) and not _any(ok & (_sum(w * e * e) > self._gate_size[nv])):
            # every epoch passes its test (the usual block): protect the all-in-view solutions
            # from the solutions without each station, here one linear downdate of the LS
            # solution (no bias large enough to leave the linear range passed the test)
            wh = w * h
            lev = wh * h * var                               # leverage of each range
            rest = info - wh * h                             # information without the range
            shift = wh * var * e / (1.0 - lev)               # x - x without range j
            sep = np.abs(shift)
            sd_j = np.where(rest > 1e-6, 1.0 / np.sqrt(np.maximum(rest, 1e-300)), np.inf)
            two = valid & (nv == 2)
            if _any(two, axis=None):
                # without range j one station k is left, which cannot tell its side: its
                # mirror image counts if a fault of j within max_fault_bias reaches it
                s_k = _sum(np.where(valid, s, 0.0)) - s         # the other station of each range
                mirror = 2.0 * s_k - (x - shift)
                need = r - np.sqrt((mirror - s) ** 2 + d2)
                far = two & (np.abs(need) <= p["max_fault_bias"])
                sep = np.where(far, np.maximum(sep, np.abs(mirror - x)), sep)
            var = self._protection(sep, sd_j, valid & (nv > 1), np.sqrt(var)) ** 2
            if self._groups.shape[1]:
                var = np.maximum(var, self._group_downdate(pat.idx, valid, wh, h, e, info) ** 2)
            unbounded = ok & ~(var < np.inf)
        elif isolate and _any(ok):
            tab = self._subsets(N_SLOTS)
            xs, vs, chi2, es = self._subset_solutions(tab.maskf, x, r, s, d2, w)
            full = np.where(nv > 0, self._slot_bits @ valid - 1, -1)
            single = self._single_index
            mirrors = self._mirrors(xs[single], s, lambda mx: r[:, None, :] - np.sqrt(
                (mx[None] - s[:, None]) ** 2 + d2[:, None]))
            chosen, good, sd, unident, inconsistent = self._isolate(tab, xs, vs, chi2, full, mirrors)
            self.stats["unidentifiable"] += int(np.count_nonzero(ok & unident))
            self.stats["inconsistent"] += int(np.count_nonzero(ok & inconsistent))
            ok &= good
            if self._groups.shape[1]:
                sd = np.maximum(sd, self._group_protection(tab, xs, vs, chosen, self._group_bits(pat.idx, valid)))
            var = sd * sd
            unbounded = ok & ~(var < np.inf)
            excluded = ok & (chosen != full)
            if _any(excluded):
                # the all-in-view solution where it is kept (converged), else the subset's
                x = np.where(excluded, xs[chosen, cols], x)
                used = tab.mask[chosen].T & valid
                nu = _sum(used)
                e = np.where(excluded, es[chosen, :, cols].T, e)
        if isolate and self._withhold_two:
            # two stations in view lengthened alike pass their one-dof test together, and nothing
            # is left to protect against them: too likely to ignore at this NLOS rate
            unprotected = ok & (nv == 2)
            self.stats["unprotected"] += int(np.count_nonzero(unprotected))
            ok &= ~unprotected
        if unbounded is not None and _any(unbounded):
            # a fault of one range could move x without bound (the others cannot fix x alone)
            self.stats["unbounded"] += int(np.count_nonzero(unbounded))
            ok &= ~unbounded
        var = np.where(ok, var, np.inf)
        if p["min_stations"] <= 1:  # else no epoch is left with a single station
            single = ok & (nu == 1)
            if _any(single):
                # no redundancy: check against the prediction instead (an NLOS onset is a jump)
                if have_pred:
                    age, xp = self._prediction(times)
                    a = np.abs(age)
                    spread = PRED_SIGMA + PRED_SPEED_SIGMA * a + 0.5 * PRED_ACCEL * a * a
                    consistent = (a <= SINGLE_HOLD) & (np.abs(x - xp) <= 3.0 * np.sqrt(var + spread ** 2))
                else:
                    consistent = np.zeros(n, dtype=bool)
                self.stats["inconsistent_single"] += int((single & ~consistent).sum())
                ok &= ~single | consistent
                if isolate:
                    var = np.where(single, var + p["unchecked_sigma"] ** 2, var)
        return x, ok, used, e, var

    def _prediction(self, times):
        """Age [s] of the previous solution and the position predicted from it at ``times``."""
        age = times - self._prev_t
        return age, self._prev_x + self._speed() * age

    def _speed(self) -> float:
        """Speed [m/s] of the predictions: weighted LS slope over the kept solutions.

        Only ambiguous or single-station epochs need it: it is computed on demand from the
        history kept by the last _remember that had a time spread.
        """
        if self._speed_src is not None:
            ht, hx, w = self._joined(self._speed_src)
            self._speed_src = None
            tt = ht - ht.mean()
            sw = w.sum()
            tm = np.dot(w, tt) / sw
            xm = np.dot(w, hx) / sw
            dt = tt - tm
            wdt = w * dt
            self._prev_v = float(np.dot(wdt, hx - xm) / np.dot(wdt, dt))
        return self._prev_v

    @staticmethod
    def _joined(chunks):
        """History chunks (t, x, var) -> arrays t, x, weight 1 / var."""
        return (np.concatenate([c[0] for c in chunks]), np.concatenate([c[1] for c in chunks]),
                1.0 / np.concatenate([c[2] for c in chunks]))

    def _remember(self, t, x, var):
        """Keep the solutions of the last hold_time (t ascending) for the speed (_speed).

        The history stays a list of per-block chunks (t, x, var, first t, last t), joined
        only when the speed is needed.
        """
        hist = self._hist
        t_first, t_last = float(t[0]), float(t[-1])
        cut = t_last - self.params["hold_time"]
        if not self._hist_sorted:   # blocks out of time order: one chunk, filtered as a whole
            if hist:
                ht, hx, hv = (np.concatenate([c[k] for c in hist]) for k in range(3))
                keep = ht > cut
                hist[:] = [(ht[keep], hx[keep], hv[keep], None, None)]
                self._hist_n = len(hist[0][0])
        else:
            while hist and not hist[0][4] > cut:   # the oldest chunk left as a whole
                self._hist_n -= len(hist.pop(0)[0])
            if hist and not hist[0][3] > cut:
                ht, hx, hv, _, last = hist[0]
                i0 = int(ht.searchsorted(cut, side="right"))
                hist[0] = (ht[i0:], hx[i0:], hv[i0:], float(ht[i0]), last)
                self._hist_n -= i0
            if hist and t_first < hist[-1][4]:
                self._hist_sorted = False
        hist.append((t, x, var, t_first, t_last))
        self._hist_n += len(t)
        self._prev_t, self._prev_x = t_last, float(x[-1])
        if self._hist_n >= 3 and self._time_spread():
            self._speed_src = list(hist)

    def _time_spread(self) -> bool:
        """Whether the history times, less their mean, are not all equal (a slope is defined)."""
        if self._hist_sorted:
            a, b = self._hist[0][3], self._hist[-1][4]
            # far above the round-off of the mean: the extremes stay apart after subtracting it
            if b - a > 1e-6 * (1.0 + abs(a) + abs(b)):
                return True
        ht = np.concatenate([c[0] for c in self._hist])
        tt = ht - ht.mean()
        return bool(tt.max() > tt.min())

    def _gauss_newton(self, x, r, s, d2, wu, iterations=6, tol=1e-9, start=None):
        """Gauss-Newton on x for all epochs at once (wu: weights, 0 for unused ranges).

        Stops early once every epoch's step is below ``tol`` [m] (converged to round-off:
        the next step would be ~tol^2). Returns x, the information sum(wu h^2), the
        residuals r - pred and the partials h, all at the final x. ``start``: (h, e) at x
        if known.
        """
        guard = self._guard_pred
        done = False
        for it in range(iterations + 1):
            if start is None:
                dx = x - s
                pred = dx * dx
                pred += d2
                np.sqrt(pred, out=pred)
                h = dx / (np.maximum(pred, 1e-9) if guard else pred)
                e = np.subtract(r, pred, out=pred)
            else:
                (h, e), start = start, None
            wh = wu * h
            info = _sum(wh * h)
            if done or it == iterations:
                return x, info, e, h
            step = _sum(wh * e) / info
            if not _min(info) > 1e-9:   # no step without information
                step = np.where(info > 1e-9, step, 0.0)
            biggest = _max(np.abs(step))
            if biggest > 50.0:
                step = np.minimum(np.maximum(step, -50.0), 50.0)
            x = x + step
            done = biggest <= tol


def station_references(track, params: dict) -> tuple[float, ReferenceTable | None]:
    """(mean spacing of the track's stations [m], inf with fewer than two; the references a fix
    can name: each station, and "!" + each for an excluded one, with the front's window while
    the radio hears it (station_window); None without a track)."""
    if track is None:
        return math.inf, None
    ids, pos, _, _ = base_stations(track, params)
    positions = np.sort(pos)
    spacing = float(positions[-1] - positions[0]) / (len(positions) - 1) if len(positions) > 1 else math.inf
    windows = {}
    for sid, x in zip(ids, pos.tolist()):
        windows[str(sid)] = windows["!" + str(sid)] = ReferenceWindow(*station_window(params, x))
    return spacing, ReferenceTable(windows, separator=",")


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """mm-wave fixes for the fusion: besides the white ranging noise, per-station errors
    persist from epoch to epoch: the calibration biases (``cal_sigma``) and NLOS biases
    small enough to pass the decoder's test (of the order of the ranging noise floor).
    One fix-bias state of hypot(cal_sigma, range_sigma_floor) carries them; it
    decorrelates as the stations in view change (the mean station spacing of the
    track) and as NLOS episodes end (``nlos_duration``). The white part of a fix is at most
    the noise of one range at 20 dB SNR: what a fix reports beyond it is the protection
    against an undetected fault (a biased range the test let pass), which lasts as long as
    its cause: the fusion does not average it over the fixes within that time. Where the
    decoder covers common-cause groups of the track (``SolutionSeparation._init_groups``), that
    cause may be a group's shared error: it lasts ``FAULT_PERSISTENCE`` and stays while the
    group is in view (twice the radio range)."""
    spacing, references = station_references(track, params)
    return ErrorModel("mmwave", "position", fix_bias_sigma=math.hypot(params["cal_sigma"],
                                                                      params["range_sigma_floor"]),
                      fix_bias_length=spacing, fix_bias_tau=params["nlos_duration"],
                      **group_excess(track, params),
                      fix_white_sigma=math.hypot(params["range_sigma_floor"], params["range_sigma_snr"]),
                      faults=("nlos", "outage"), min_stddev=min_fix_sigma(params), references=references)


SPEC = SensorSpec(
    node="mmwave_ranging", sensor="mmwave", simulator=MmWaveSimulator, decoder=MmWaveDecoder,
    params=PARAMS, description="on-board mm-wave radio ranging to wayside base stations: absolute position",
    seeds=("002",),
    outputs=("position",), error_model=error_model,
)

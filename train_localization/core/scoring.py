"""Scores of a fused state stream against ground truth (both TrainState streams).

Errors are fused minus truth at the fused stamps (truth interpolated linearly;
the truth rate is 100 Hz and the motion smooth). States in MODE_INITIALISING claim
no position and are not scored for position.

``score`` gives the error statistics and the integrity of a stream; ``run_scores``
adds what a Monte Carlo campaign (core/campaign.py) collects per run: excursions
of the truth out of [position_min, position_max], normalised errors, the ETCS
SUBSET-041 position envelope 5 m + 5 % of the distance run since the last reference
and the SUBSET-041 speed band (``speed_envelope``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import norm

from .convert import stamp_to_sec
from .fusion import MODE_NOMINAL

FIELDS = ("t", "position", "speed", "position_stddev", "speed_stddev", "position_min", "position_max", "mode")


@dataclass
class StateSeries:
    """Columns of a TrainState stream (seconds, metres, m/s)."""

    t: np.ndarray
    position: np.ndarray
    speed: np.ndarray
    position_stddev: np.ndarray
    speed_stddev: np.ndarray
    position_min: np.ndarray
    position_max: np.ndarray
    mode: np.ndarray

    @classmethod
    def from_msgs(cls, msgs) -> "StateSeries":
        rows = [(stamp_to_sec(m.header.stamp), m.position, m.speed, m.position_stddev, m.speed_stddev,
                 m.position_min, m.position_max, m.mode) for m in msgs]
        arr = np.array(rows, dtype=float).reshape(-1, len(FIELDS))
        return cls(*(arr[:, i] for i in range(len(FIELDS))))

    @classmethod
    def from_estimates(cls, estimates) -> "StateSeries":
        """Columns of core.fusion.Estimate objects."""
        rows = [(e.stamp, e.position, e.speed, e.position_stddev, e.speed_stddev, e.position_min,
                 e.position_max, e.mode) for e in estimates]
        arr = np.array(rows, dtype=float).reshape(-1, len(FIELDS))
        return cls(*(arr[:, i] for i in range(len(FIELDS))))

    @classmethod
    def of_truth(cls, t, position, speed) -> "StateSeries":
        """A ground-truth series (stddevs 0, interval = position, mode NOMINAL)."""
        t, position, speed = (np.asarray(a, dtype=float) for a in (t, position, speed))
        zero = np.zeros_like(t)
        return cls(t, position, speed, zero, zero, position, position, np.ones_like(t))


def _stats(err: np.ndarray) -> dict:
    if err.size == 0:
        return {"rms": None, "p95": None, "max": None, "n": 0}
    a = np.abs(err)
    return {"rms": float(np.sqrt(np.mean(err ** 2))), "p95": float(np.percentile(a, 95)),
            "max": float(a.max()), "n": int(err.size)}


def true_position(t, truth_t, truth_position, fused_position, circumference: float | None = None):
    """The true position [m] at the fused states' times ``t``, to compare with ``fused_position``.

    ``circumference`` [m] (a closed track, Track.closed): the truth (wrapped) is unwrapped
    before it is interpolated and then moved by whole laps to the fused position (which may be
    an unwrapped distance), so errors are compared modulo the circumference."""
    if not circumference:
        return np.interp(t, truth_t, truth_position)
    s_true = np.interp(t, truth_t, np.unwrap(truth_position, period=circumference))
    laps = np.round(np.nan_to_num(np.asarray(fused_position) - s_true) / circumference)
    return s_true + laps * circumference


def _aligned(truth: StateSeries, fused: StateSeries, circumference: float | None = None):
    """(fused columns within the truth's time span, true position and speed there, claimed mask).

    ``circumference`` [m] (a closed track): the truth is unwrapped before it is interpolated and
    then moved by whole laps to the fused position (the fused one may be an unwrapped distance)."""
    inside = (fused.t >= truth.t[0]) & (fused.t <= truth.t[-1])
    f = {k: getattr(fused, k)[inside] for k in FIELDS}
    s_true = true_position(f["t"], truth.t, truth.position, f["position"], circumference)
    v_true = np.interp(f["t"], truth.t, truth.speed)
    claimed = (f["mode"] != 0) & np.isfinite(f["position"])
    return f, s_true, v_true, claimed


def score(truth: StateSeries, fused: StateSeries, circumference: float | None = None) -> dict:
    """Position/speed error statistics, integrity and interval width; on a closed track of
    ``circumference`` [m] the position is compared modulo it (Track.closed)."""
    f, s_true, v_true, claimed = _aligned(truth, fused, circumference)
    pos_err = f["position"][claimed] - s_true[claimed]
    spd_err = f["speed"] - v_true
    in_interval = (s_true[claimed] >= f["position_min"][claimed]) & (s_true[claimed] <= f["position_max"][claimed])
    width = f["position_max"][claimed] - f["position_min"][claimed]
    modes = {str(int(m)): int(n) for m, n in zip(*np.unique(f["mode"], return_counts=True))}
    return {
        "states": int(f["t"].size),
        "states_with_position": int(claimed.sum()),
        "position_error_m": _stats(pos_err),
        "speed_error_mps": _stats(spd_err),
        "integrity": {
            "inside_fraction": float(in_interval.mean()) if in_interval.size else None,
            "outside_count": int((~in_interval).sum()),
            # the hazard a train protection acts on: the truth outside a NOMINAL interval
            "outside_nominal": int((~in_interval & (f["mode"][claimed] == MODE_NOMINAL)).sum()),
            "mean_interval_width_m": float(width.mean()) if width.size else None,
        },
        "modes": modes,
    }


SPEED_KNOWN = 10.0  # [m/s] speed 1-sigma below which the speed counts as measured (not the prior)
ENVELOPE_FIXED, ENVELOPE_RATE = 5.0, 0.05   # SUBSET-041 position accuracy: 5 m + 5 % of the distance [m, 1]
# bins of the normalised position error (error / position 1-sigma) kept per run
NORMALISED_EDGES = np.linspace(-8.0, 8.0, 65)


def speed_envelope(speed):
    """SUBSET-041 speed accuracy [m/s]: +-2 km/h below 30 km/h, linearly to +-12 km/h at 500 km/h."""
    kmh = np.abs(np.asarray(speed)) * 3.6
    return (2.0 + np.clip(kmh - 30.0, 0.0, 470.0) * 10.0 / 470.0) / 3.6


def distance_since(t, truth_t, truth_position, ref_times):
    """Distance run [m] (|ds| summed along the truth) at times ``t`` since the last of the
    sorted ``ref_times`` at or before each t; since the start of the truth before the first."""
    travelled = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(truth_position)))])
    dist = np.interp(t, truth_t, travelled)
    ref_times = np.asarray(ref_times, dtype=float)
    last = np.searchsorted(ref_times, t, side="right") - 1
    at_ref = np.where(last >= 0, np.interp(ref_times[np.maximum(last, 0)] if ref_times.size else t, truth_t,
                                           travelled), 0.0)
    return dist - at_ref


def passing_times(truth_t, truth_position, positions) -> np.ndarray:
    """Times [s] (truth samples) at which the true position reaches or leaves one of ``positions``
    (sorted chainages: balises, axle-counter heads), in time order; a reversal over one counts again."""
    positions = np.sort(np.asarray(positions, dtype=float))
    if not positions.size or len(truth_t) < 2:
        return np.empty(0)
    region = np.searchsorted(positions, np.asarray(truth_position), side="right")
    return np.asarray(truth_t)[1:][np.diff(region) != 0]


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[first, end) index ranges of the runs of True in a boolean array."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def run_scores(truth: StateSeries, fused: StateSeries, period: float, reference_times=None,
               max_pairs: int = 300, confidence: float = 0.999) -> dict:
    """``score`` plus the per-run figures of an integrity campaign.

    ``period``: spacing of the fused states [s] (an excursion of n consecutive states
    outside the interval lasts n x period). ``reference_times``: sorted times at which
    the true train front passed a position reference (core/campaign.py: balises and
    axle-counter heads); given, the ETCS SUBSET-041 envelope ratio |error| / (5 m + 5 %
    of the distance run since the last of them) is scored. ``max_pairs``: (error,
    interval half-width) pairs kept, evenly subsampled, plus states outside the interval.
    ``confidence``: the fusion's two-sided interval probability; the true speed is scored
    against speed +- z speed_stddev with the same z (``speed_interval``).
    """
    out = score(truth, fused)
    f, s_true, v_true, claimed = _aligned(truth, fused)
    t = f["t"][claimed]
    err = f["position"][claimed] - s_true[claimed]
    lo, hi, sd = f["position_min"][claimed], f["position_max"][claimed], f["position_stddev"][claimed]
    outside = (s_true[claimed] < lo) | (s_true[claimed] > hi)
    # excursions: consecutive published states (claimed, none skipped) with the truth outside
    outside_all = np.zeros(claimed.size, dtype=bool)
    outside_all[claimed] = outside
    runs = _runs(outside_all)
    longest = max(runs, key=lambda r: r[1] - r[0]) if runs else None
    ex = {"count": len(runs), "longest_s": 0.0, "longest_states": 0, "longest_start": None,
          "longest_max_error_m": None}
    if longest:
        a, b = longest
        ex.update(longest_s=(b - a) * period, longest_states=b - a, longest_start=float(f["t"][a]),
                  longest_max_error_m=float(np.max(np.abs(f["position"][a:b] - s_true[a:b]))))
    out["excursions"] = ex
    z = err / sd
    hist = np.histogram(np.clip(z, NORMALISED_EDGES[0], NORMALISED_EDGES[-1]), NORMALISED_EDGES)[0]
    out["normalised_error"] = {
        "edges": NORMALISED_EDGES.tolist(), "counts": hist.tolist(),
        "beyond": int(np.count_nonzero(np.abs(z) > NORMALISED_EDGES[-1])),
        "rms": float(np.sqrt(np.mean(z * z))) if z.size else None,
        "max_abs": float(np.max(np.abs(z))) if z.size else None}
    keep = np.zeros(t.size, dtype=bool)
    keep[::max(1, t.size // max_pairs)] = True
    keep[np.flatnonzero(outside)[:max_pairs]] = True
    out["error_vs_half_width"] = {"error_m": err[keep].tolist(), "half_width_m": (0.5 * (hi - lo))[keep].tolist(),
                                  "t": t[keep].tolist()}
    n = max(int(f["t"].size), 1)
    out["mode_fractions"] = {k: v / n for k, v in out["modes"].items()}
    out["first_position_s"] = float(t[0]) if t.size else None
    if reference_times is not None:
        since = distance_since(t, truth.t, truth.position, reference_times)
        ratio = np.abs(err) / (ENVELOPE_FIXED + ENVELOPE_RATE * since)
        out["etcs_envelope"] = {"states": int(ratio.size), "within": int(np.count_nonzero(ratio <= 1.0)),
                                "max_ratio": float(ratio.max()) if ratio.size else None,
                                "p95_ratio": float(np.percentile(ratio, 95)) if ratio.size else None,
                                "references_passed": int(np.size(reference_times))}
    known = f["speed_stddev"] < SPEED_KNOWN
    vratio = np.abs(f["speed"][known] - v_true[known]) / speed_envelope(v_true[known])
    # violations where the filter claimed NOMINAL (not DEGRADED, LOST or without a position yet)
    nominal = f["mode"][known] == MODE_NOMINAL
    out["speed_band"] = {"states": int(vratio.size), "violations": int(np.count_nonzero(vratio > 1.0)),
                         "violations_nominal": int(np.count_nonzero((vratio > 1.0) & nominal)),
                         "max_ratio": float(vratio.max()) if vratio.size else None}
    # a known speed claims v +- z sigma: the truth outside it is a confident wrong speed
    z = float(norm.ppf(0.5 + confidence / 2.0))
    dv = np.abs(f["speed"][known] - v_true[known])
    zs = dv / np.maximum(f["speed_stddev"][known], 1e-12)
    out["speed_interval"] = {"states": int(dv.size), "outside": int(np.count_nonzero(zs > z)),
                             "max_normalised": float(zs.max()) if zs.size else None}
    return out

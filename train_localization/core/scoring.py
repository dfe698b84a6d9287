"""Scores of a fused state stream against ground truth (both TrainState streams).

Errors are fused minus truth at the fused stamps (truth interpolated linearly;
the truth rate is 100 Hz and the motion smooth). States in MODE_INITIALISING claim
no position and are not scored for position.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .convert import stamp_to_sec

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


def _stats(err: np.ndarray) -> dict:
    if err.size == 0:
        return {"rms": None, "p95": None, "max": None, "n": 0}
    a = np.abs(err)
    return {"rms": float(np.sqrt(np.mean(err ** 2))), "p95": float(np.percentile(a, 95)),
            "max": float(a.max()), "n": int(err.size)}


def score(truth: StateSeries, fused: StateSeries) -> dict:
    """Position/speed error statistics, integrity and interval width."""
    inside = (fused.t >= truth.t[0]) & (fused.t <= truth.t[-1])
    f = {k: getattr(fused, k)[inside] for k in FIELDS}
    s_true = np.interp(f["t"], truth.t, truth.position)
    v_true = np.interp(f["t"], truth.t, truth.speed)
    claimed = (f["mode"] != 0) & np.isfinite(f["position"])
    pos_err = f["position"][claimed] - s_true[claimed]
    spd_err = f["speed"] - v_true
    in_interval = (s_true[claimed] >= f["position_min"][claimed]) & (s_true[claimed] <= f["position_max"][claimed])
    width = f["position_max"][claimed] - f["position_min"][claimed]
    modes = {str(int(m)): int(n) for m, n in zip(*np.unique(f["mode"], return_counts=True))}
    return {
        "states": int(inside.sum()),
        "states_with_position": int(claimed.sum()),
        "position_error_m": _stats(pos_err),
        "speed_error_mps": _stats(spd_err),
        "integrity": {
            "inside_fraction": float(in_interval.mean()) if in_interval.size else None,
            "outside_count": int((~in_interval).sum()),
            "mean_interval_width_m": float(width.mean()) if width.size else None,
        },
        "modes": modes,
    }

"""The availability oracle of the integrity campaign: a plain filter, told by the truth which
measurements are faulty, leaves them out.

An interval wider than it needs to be costs trains. The oracle runs the same sensor models
(their noise and error states) in a plain filter (``plain_config``: no fault mode, no fault
cover, no special case) on the same delivered measurements less those the truth shows faulty:
a measurement whose error against the true motion exceeds ``ORACLE_SIGMAS`` of its own
reported 1-sigma (a radar reading during its scale fault, a wheel increment in a slip, a
misread balise, an NLOS range). What is left is the interval a perfect fault detector would
allow; the campaign reports the fusion's width and error against it and the states the fusion
was LOST where the oracle knew the position within ``lost_stddev``.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from .fusion.config import FusionConfig
from .measurements import DistanceIncrement, PositionFix, SpeedMeasurement

# a measurement further from the truth than this many of its own 1-sigma is faulty
ORACLE_SIGMAS = 4.0


def truth_error(m, traj) -> float:
    """|measurement - truth| / its reported 1-sigma [1] (the truth: core/scenario.py Trajectory)."""
    if isinstance(m, PositionFix):
        return abs(m.position - float(np.interp(m.stamp, traj.t, traj.position))) / m.position_stddev
    if isinstance(m, SpeedMeasurement):
        return abs(m.speed - float(np.interp(m.stamp, traj.t, traj.speed))) / m.speed_stddev
    if isinstance(m, DistanceIncrement):
        run = float(np.interp(m.stamp, traj.t, traj.position) - np.interp(m.stamp - m.duration, traj.t, traj.position))
        return abs(m.distance - run) / m.distance_stddev
    return 0.0


def plain_config(config: FusionConfig) -> FusionConfig:
    """``config`` as a plain filter: every policy off (``FusionConfig.policies``) and no fault
    mode in any sensor's model (no slip episodes, no fault hypotheses, no offsets); the models'
    noise, error states and timeouts as they are."""
    overrides = {name: {**(config.overrides or {}).get(name, {}), "faults": ()} for name in config.models}
    return dataclasses.replace(config, policies=frozenset(), overrides=overrides)


def fault_free(delivered: list, traj) -> list:
    """The (arrival, measurement) pairs of ``delivered`` that the truth shows fault-free."""
    return [(t, m) for t, m in delivered if truth_error(m, traj) <= ORACLE_SIGMAS]


def availability(estimates: list, oracle: list, traj, lost_stddev: float) -> dict:
    """The fusion's ``estimates`` against the oracle's on the same output grid: over the states
    where both claim a position (not LOST), the sums of their interval widths [m] and squared
    errors against the truth [m^2]; and the states LOST while the oracle's 1-sigma was under
    ``lost_stddev`` (needlessly)."""
    by_stamp = {round(e.stamp, 6): e for e in oracle}
    out = {"states": 0, "width_m": 0.0, "oracle_width_m": 0.0, "error_sq": 0.0, "oracle_error_sq": 0.0,
           "lost_needlessly": 0}
    for e in estimates:
        o = by_stamp.get(round(e.stamp, 6))
        if o is None or not np.isfinite(o.position):
            continue
        if e.mode == 3 and o.position_stddev < lost_stddev:
            out["lost_needlessly"] += 1
        if np.isfinite(e.position) and e.mode != 3 and o.mode != 3:
            s = float(np.interp(e.stamp, traj.t, traj.position))
            out["states"] += 1
            out["width_m"] += e.position_max - e.position_min
            out["oracle_width_m"] += o.position_max - o.position_min
            out["error_sq"] += (e.position - s) ** 2
            out["oracle_error_sq"] += (o.position - s) ** 2
    return out


def ratios(runs: list[dict]) -> dict:
    """Availability over runs (their ``availability`` dicts): mean width / oracle mean width,
    RMS error / oracle RMS error, and the share of states LOST needlessly."""
    n = sum(r["states"] for r in runs)
    if not n:
        return {"states": 0, "width_ratio": None, "error_ratio": None, "lost_needlessly": 0}
    ow, oe = sum(r["oracle_width_m"] for r in runs), sum(r["oracle_error_sq"] for r in runs)
    return {"states": n,
            "width_ratio": sum(r["width_m"] for r in runs) / ow if ow > 0 else None,
            "error_ratio": float(np.sqrt(sum(r["error_sq"] for r in runs) / oe)) if oe > 0 else None,
            "mean_width_m": sum(r["width_m"] for r in runs) / n,
            "oracle_mean_width_m": ow / n,
            "lost_needlessly": sum(r["lost_needlessly"] for r in runs),
            "lost_needlessly_fraction": sum(r["lost_needlessly"] for r in runs) / n}

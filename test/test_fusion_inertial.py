"""The accelerometer's own dead reckoning (core/fusion/inertial.py): what it knows of the train
from the measured acceleration and the fixes, and the lone source's hypothesis it narrows
(core/fusion/lone.py, views.lone_interval)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from train_localization.core.fusion import inertial


def _run(bias: float, until: float, fix_every: float | None, seed: int = 1):
    """A train accelerating at 0.3 m/s^2 from 10 m/s, an accelerometer at 50 Hz reading it with a
    constant ``bias`` [m/s^2] and white noise 0.01 m/s^2, position fixes (1-sigma 0.3 m) every
    ``fix_every`` s. Returns [(t, view position, its variance, speed, its variance, true s, v)]."""
    rng = np.random.default_rng(seed)
    view = inertial.started(0.0, 0.0, 0.25, 10.0, 0.01, 0.0, bias_sigma=0.03)
    out, next_fix = [], fix_every
    for k in range(1, int(until * 50) + 1):
        t = k / 50.0
        s, v = 10.0 * t + 0.15 * t * t, 10.0 + 0.3 * t
        view = inertial.read(view, t, 0.3 + bias + float(rng.normal(0, 0.01)), 0.01)
        if next_fix is not None and t >= next_fix - 1e-9:
            view, _ = inertial.fixed(view, t, s + float(rng.normal(0, 0.3)), 0.09)
            next_fix += fix_every
        out.append((t, *inertial.at(view, t), s, v))
    return out


def test_without_fixes_the_bias_grows_the_position_error_as_its_prior_allows():
    """A bias of 2 sigma of the prior (0.06 m/s^2): after 30 s the train is 27 m from where the
    measured acceleration puts it, and the dead reckoning's 1-sigma has grown like the prior's
    0.03 x t^2 / 2 (13.5 m): the truth within 3 sigma all the way."""
    run = _run(0.06, 30.0, None)
    t, s, var, v, var_v, s_true, v_true = run[-1]
    assert s - s_true == pytest.approx(27.0, rel=0.05)
    assert math.sqrt(var) == pytest.approx(13.5, rel=0.05)
    assert all(abs(r[1] - r[5]) <= 3.0 * math.sqrt(r[2]) for r in run)


def test_fixes_teach_it_the_bias_and_the_speed_so_a_gap_grows_it_slowly():
    """Fixes every 5 s for 60 s, then none for 20 s: the bias is learnt from the fixes (its
    1-sigma from 0.03 to a few mm/s^2) and the position's 1-sigma 20 s into the gap stays within
    a few metres, the truth inside 3 sigma everywhere; with the prior only it would be 6 m."""
    run = _run(0.05, 80.0, 5.0)
    gap = [r for r in run if r[0] > 60.0]
    with_fixes = [r for r in run if r[0] <= 60.0]
    assert all(abs(r[1] - r[5]) <= 3.0 * math.sqrt(r[2]) for r in run)
    assert all(abs(r[3] - r[6]) <= 3.0 * math.sqrt(r[4]) for r in run)
    assert math.sqrt(with_fixes[-1][4]) < 0.05          # the speed learnt to a few cm/s
    assert math.sqrt(gap[-1][2]) < 3.0                   # 20 s on: metres, not tens


def test_moving_without_a_reading_keeps_the_last_acceleration():
    view = inertial.started(0.0, 0.0, 0.0, 10.0, 0.0, 0.0, bias_sigma=0.0)
    view = inertial.read(view, 0.0, 1.0, 0.0)
    s, var, v, var_v = inertial.at(view, 2.0)
    assert (s, v) == pytest.approx((22.0, 12.0)) and var == pytest.approx(0.0) and var_v == pytest.approx(0.0)

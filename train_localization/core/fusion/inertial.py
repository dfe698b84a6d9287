"""The accelerometer's own dead reckoning: the train's position and speed from its measured
acceleration alone, conditioned on the fixes, for a hypothesis under which the speed sources
are not to be trusted (the lone source's fault, lone.py).

State (s [m], v [m/s], b [m/s^2]): the acceleration read is a = true acceleration + b + white
noise, so between two readings

    s <- s + v dt + (a - b) dt^2 / 2,   v <- v + (a - b) dt,   b constant.

The bias is a constant with the accelerometer's prior 1-sigma (its ``bias_sigma``: turn-on bias,
temperature drift, gradient tolerance; core/sensors/accelerometer.py). The device's bias is a
Gauss-Markov process of that stationary 1-sigma, whose integral is never larger than a
constant's: the constant overbounds it. Each reading's white noise (its reported 1-sigma) is
held over the interval to the next. A fix the filter accepted updates s (H = [1, 0, 0]); the
speed and the bias are learnt through the covariance, so a gap in the fixes grows the interval
by the bias's residual x dt^2 / 2, not by the motion model's jerk.

Plain floats (a 3x3 covariance per reading of a 100 Hz device).
"""
from __future__ import annotations

import math
from typing import NamedTuple


class InertialView(NamedTuple):
    """The dead reckoning at ``stamp`` [s], with the acceleration last read (held until the next)."""

    stamp: float
    s: float            # position [m]
    v: float            # speed [m/s]
    b: float            # the accelerometer's bias [m/s^2]
    cov: tuple          # covariance of (s, v, b): (Pss, Psv, Psb, Pvv, Pvb, Pbb)
    a: float            # the acceleration last read [m/s^2]
    var_a: float        # its white-noise variance [m^2/s^4]
    read: float         # the stamp of that reading [s]


def started(stamp: float, s: float, var_s: float, v: float, var_v: float, cov_sv: float,
            bias_sigma: float) -> InertialView:
    """A dead reckoning from the filter's position and speed at ``stamp`` (their variances and
    covariance), the bias unknown within its prior 1-sigma ``bias_sigma`` [m/s^2], no
    acceleration read yet (0, the train's until the first reading)."""
    return InertialView(stamp, s, v, 0.0, (var_s, cov_sv, 0.0, var_v, 0.0, bias_sigma * bias_sigma), 0.0, 0.0,
                        -math.inf)


def moved(view: InertialView, t: float) -> InertialView:
    """The dead reckoning moved to t [s] with the acceleration last read."""
    dt = t - view.stamp
    if dt <= 0.0:
        return view
    pss, psv, psb, pvv, pvb, pbb = view.cov
    u, h = view.a - view.b, 0.5 * dt * dt
    # F = [[1, dt, -h], [0, 1, -dt], [0, 0, 1]]; the reading's noise held over dt: G = [h, dt, 0]
    fss = pss + 2 * dt * psv - 2 * h * psb + dt * dt * pvv - 2 * dt * h * pvb + h * h * pbb
    fsv = psv - dt * psb + dt * pvv - dt * dt * pvb - h * pvb + h * dt * pbb
    fsb = psb + dt * pvb - h * pbb
    fvv = pvv - 2 * dt * pvb + dt * dt * pbb
    fvb = pvb - dt * pbb
    q = view.var_a
    cov = (fss + q * h * h, fsv + q * h * dt, fsb, fvv + q * dt * dt, fvb, pbb)
    return view._replace(stamp=t, s=view.s + view.v * dt + u * h, v=view.v + u * dt, cov=cov)


def read(view: InertialView, stamp: float, acceleration: float, stddev: float) -> InertialView:
    """The dead reckoning after an acceleration reading [m/s^2] (1-sigma ``stddev``) at ``stamp`` [s]."""
    return moved(view, stamp)._replace(a=acceleration, var_a=stddev * stddev, read=stamp)


def fixed(view: InertialView, t: float, z: float, R: float) -> tuple[InertialView, float]:
    """(the dead reckoning after a fix z [m] of variance R [m^2] at t [s], the fix's normalised
    innovation squared against it before the update)."""
    view = moved(view, t)
    pss, psv, psb, pvv, pvb, pbb = view.cov
    S = pss + R
    nu = z - view.s
    ks, kv, kb = pss / S, psv / S, psb / S
    cov = (pss - ks * pss, psv - ks * psv, psb - ks * psb, pvv - kv * psv, pvb - kv * psb, pbb - kb * psb)
    return view._replace(s=view.s + ks * nu, v=view.v + kv * nu, b=view.b + kb * nu, cov=cov), nu * nu / S


def at(view: InertialView, t: float) -> tuple[float, float, float, float]:
    """(position [m], its variance [m^2], speed [m/s], its variance [m^2/s^2]) at t [s]."""
    m = moved(view, t)
    return m.s, m.cov[0], m.v, m.cov[3]

"""Process and measurement models of the along-track filter (scalar measurements).

Process model
  [s, v, a]   constant acceleration driven by white jerk (spectral density ``jerk_psd``);
              an acceleration that brings the speed to zero holds the train at rest there
              (``braking_stop``): a brake cannot drive a train backwards
  k (scale)   Gauss-Markov: the exact discretisation of an AR(1) error with correlation
              time tau and stationary 1-sigma (the Doppler radar, doppler.py); constant
              scales and biases: random walks from their priors
  e (fix bias) Gauss-Markov in the distance run and in time: phi = exp(-|v| dt / L - dt / tau)

Measurement models
  PositionFix        z = s (+ e)
  SpeedMeasurement   z = (1 + k + k0)(u + sign(z) b),  u = v
  Acceleration       z = a + c (the accelerometer's bias state), R: the reported variance less the
                     bias part the state carries (``reported_bias``)
  DistanceIncrement  z = distance / d = (1 + k + k0)(u + sign(z) b), u = v - a d/2: the mean
                     speed over the interval d ending at the stamp, R = (distance_stddev / d)^2.
                     A wheel under traction or braking turns faster or slower than the train
                     moves (creep): u becomes u + c a |u| with the model's creep coefficient c
                     (under traction only on a driven axle).
Honest noise: a decoder reports a measurement's 1-sigma including its slowly varying
errors as if white; the parts the states carry (``reported_*`` of the error model) are
removed from R (floored at 1 % of it); ``stddev_factor`` scales what is left. A fix reported
less certain than its model's ``fix_white_sigma`` (a decoder's protection level against an
undetected fault) has the excess weighted as shared by the fixes within its correlation
time (``fix_noise``).
"""
from __future__ import annotations

import math

import numpy as np

from ..measurements import Acceleration, PositionFix, SpeedMeasurement
from .layout import StateLayout


def braking_stop(v: float, a: float, dt: float) -> float | None:
    """The time [s] within a forward step dt [s] at which speed v [m/s] under an acceleration
    a [m/s^2] that opposes it reaches zero, or None. The motion model stops the train there:
    a brake holds a train at rest but cannot drive it backwards, and a train reverses only
    from rest; run on, the constant acceleration would reverse it through the standstill
    (a filter without a speed reading at a stop, a radar silent below its minimum speed)."""
    if v * a < 0.0 and dt > 0.0:
        t_stop = -v / a
        if t_stop < dt:
            return t_stop
    return None


def kinematic_mean(s: float, v: float, a: float, dt: float) -> tuple[float, float, float]:
    """(position [m], speed [m/s], acceleration [m/s^2]) dt [s] after (s, v, a) under constant
    acceleration, the train held at rest where a braking brings it there (``braking_stop``)."""
    stop = braking_stop(v, a, dt)
    if stop is not None:
        return s + v * stop + a * (0.5 * stop * stop), 0.0, 0.0
    return s + v * dt + a * (0.5 * dt * dt), v + a * dt, a


class ProcessModel:
    """F, Q over a time step (cached: the sensors' fixed rates repeat the same steps)."""

    def __init__(self, layout: StateLayout, jerk_psd: float):
        self.layout, self.q = layout, jerk_psd
        self._cache: dict[float, tuple] = {}

    def transition(self, dt: float):
        hit = self._cache.get(dt)
        if hit is not None:
            return hit
        n = self.layout.n
        F = np.eye(n)
        F[0, 1], F[0, 2], F[1, 2] = dt, 0.5 * dt * dt, dt
        Q = np.zeros((n, n))
        dt2 = dt * dt
        Q[:3, :3] = self.q * np.array([[dt2 * dt2 * dt / 20, dt2 * dt2 / 8, dt2 * dt / 6],
                                       [dt2 * dt2 / 8, dt2 * dt / 3, dt2 / 2],
                                       [dt2 * dt / 6, dt2 / 2, dt]])
        for i, tau, sigma in self.layout.gauss_markov:
            phi = math.exp(-dt / tau)
            F[i, i] = phi
            Q[i, i] = sigma * sigma * (1.0 - phi * phi)
        for i, psd in self.layout.random_walk:
            Q[i, i] = psd * dt
        FT = F.T.copy()
        if len(self._cache) > 4096:
            self._cache.clear()
        self._cache[dt] = (F, FT, Q)
        return F, FT, Q

    def predict(self, x, P, t0: float | None, t: float):
        """(x, P) moved from t0 to t (before t0: extrapolated back, uncertainty grown as forwards)."""
        if t0 is None or t == t0:
            return x, P
        F, FT, Q = self.transition(t - t0)
        if t < t0:
            Q = self.transition(t0 - t)[2]
        s0, v0, a0 = float(x[0, 0]), float(x[1, 0]), float(x[2, 0])
        # new arrays: snapshots share the old ones
        x, P = F.dot(x), F.dot(P).dot(FT) + Q
        if braking_stop(v0, a0, t - t0) is not None:
            x[0, 0], x[1, 0], x[2, 0] = kinematic_mean(s0, v0, a0, t - t0)
        if self.layout.fix_decay:
            dt = abs(t - t0)
            dist = abs(float(x[1, 0])) * dt
            for i, length, tau, sigma in self.layout.fix_decay:
                phi = math.exp(-dist / length - dt / tau)
                x[i, 0] *= phi
                P[i, :] *= phi
                P[:, i] *= phi
                P[i, i] += sigma * sigma * (1.0 - phi * phi)
        return x, P


def _direct(h: np.ndarray, x: list, k: int, bias: int | None) -> float:
    """h(x) of a reading of state k plus an additive bias state (None: without one); sets their
    entries of the H row h."""
    h[k] = 1.0
    if bias is None:
        return x[k]
    h[bias] = 1.0
    return x[k] + x[bias]


def measurement(layout: StateLayout, x_col, m, since: float = math.inf):
    """(z, R, H row (1-D), h(x)) of a measurement at the state x (n, 1); since: time [s]
    since its sensor's previous fix (``fix_noise``)."""
    model = layout.models[m.sensor]
    x = x_col[:, 0].tolist()   # plain floats: the same doubles, without numpy scalars
    h = np.zeros(layout.n)
    cls = m.sensor
    if isinstance(m, PositionFix):
        z, hx = m.position, _direct(h, x, 0, layout.fix.get(cls))
        R = fix_noise(layout, m, abs(x[1]), since)
    elif isinstance(m, Acceleration):
        z, hx = m.acceleration, _direct(h, x, 2, layout.accel_bias.get(cls))
        R = m.acceleration_stddev ** 2
        R = max(R - model.reported_bias ** 2, 0.01 * R)
    else:
        k_idx = layout.scale.get(cls)
        o_idx = layout.offset.get(cls)
        g = 1.0 + (x[k_idx] if k_idx is not None else 0.0) + (x[o_idx] if o_idx is not None else 0.0)
        if isinstance(m, SpeedMeasurement):
            z, sigma = m.speed, m.speed_stddev
            v, a, d = x[1], x[2], 0.0
            h[1] = g
        else:
            d = m.duration
            z, sigma = m.distance / d, m.distance_stddev / d
            a = x[2]
            v = x[1] - 0.5 * d * a
            h[1], h[2] = g, -0.5 * d * g
        c = model.creep_coefficient
        sv = 1.0 if v >= 0.0 else -1.0
        if c and (model.creep_in_traction or a * sv < 0.0):   # v (1 + c a sign v) = v + c a |v|
            h[1] += g * c * a * sv
            h[2] += g * c * (abs(v) - 0.5 * d * a * sv)
            v = v + c * a * abs(v)
        b_idx = layout.bias.get(cls)
        if b_idx is not None:
            sgn = 1.0 if z >= 0.0 else -1.0
            h[b_idx] = g * sgn
            v = v + sgn * x[b_idx]
        if k_idx is not None:
            h[k_idx] = v
        if o_idx is not None:
            h[o_idx] = v
        hx = g * v
        R = sigma * sigma
        R = max(R - (model.reported_scale * z) ** 2 - model.reported_bias ** 2, 0.01 * R)
    if model.stddev_factor != 1.0:
        R *= model.stddev_factor ** 2
    return z, R, h, hx


def fix_noise(layout: StateLayout, m, speed: float, since: float) -> float:
    """Variance [m^2] of a position fix as white noise: its reported variance without the
    fix-bias part the state carries (``reported_fix_bias``). What it reports beyond its
    model's ``fix_white_sigma`` (a decoder's protection against an undetected fault) persists
    as long as the fault's cause, its correlation time at this speed [m/s]
    (``fix_excess_tau``, ``fix_excess_length``; the fix bias's where not given): the fixes
    within it share one such error, so
    each of them counts for the fraction ``since`` / that time of one fix (R of the excess
    multiplied by the number of fixes that share it; since [s]: time since the sensor's
    previous fix)."""
    model = layout.models[m.sensor]
    R = m.position_stddev ** 2
    fixed = model.reported_fix_bias
    if fixed > 0.0 and m.sensor in layout.fix:
        R = max(R - fixed * fixed, 0.01 * R)
    white = model.fix_white_sigma ** 2
    if R <= white:
        return R
    tau = model.fix_bias_tau if math.isnan(model.fix_excess_tau) else model.fix_excess_tau
    length = model.fix_bias_length if math.isnan(model.fix_excess_length) else model.fix_excess_length
    return white + (R - white) * sharing(tau, length, speed, since)


def fixes_sharing(model, speed: float, since: float) -> float:
    """How many fixes of a sensor share one fix bias (at least 1): its correlation time at
    ``speed`` [m/s] (``fix_bias_tau``, ``fix_bias_length``) over ``since`` [s], the time since
    the sensor's previous fix."""
    return sharing(model.fix_bias_tau, model.fix_bias_length, speed, since)


def sharing(tau: float, length: float, speed: float, since: float) -> float:
    """How many fixes ``since`` [s] apart share one error of correlation time ``tau`` [s] and
    length ``length`` [m] at ``speed`` [m/s] (at least 1)."""
    rate = 1.0 / tau + speed / length
    shared = 1.0 / (rate * since) if rate > 0.0 and since > 0.0 else 1.0
    return max(shared, 1.0)


def implied_speed(layout: StateLayout, x_col, P, m, z: float, R: float) -> tuple[float, float, float]:
    """The speed measurement model inverted: (train speed [m/s], white variance, common
    variance [m^2/s^2]) that a speed or increment measurement (z, R of ``measurement``)
    implies with the sensor's current error-state estimates x (n, 1) and covariance P. The
    white part is the measurement noise; the common part, shared by the sensor's readings,
    is the error states' uncertainty and the creep the model would add."""
    cls = m.sensor
    k, o, b = layout.scale.get(cls), layout.offset.get(cls), layout.bias.get(cls)
    g = 1.0 + (x_col[k, 0] if k is not None else 0.0) + (x_col[o, 0] if o is not None else 0.0)
    var_g = (P[k, k] if k is not None else 0.0) + (P[o, o] if o is not None else 0.0)
    a = float(x_col[2, 0])
    sgn = 1.0 if z >= 0.0 else -1.0
    u = z / g - (sgn * x_col[b, 0] if b is not None else 0.0)
    if not isinstance(m, SpeedMeasurement):
        u += 0.5 * m.duration * a    # the interval's mean speed -> speed at its end
    creep = layout.models[cls].creep_coefficient * abs(a) * abs(u)
    common = var_g * u * u + (P[b, b] if b is not None else 0.0) + creep * creep
    return float(u), float(R / (g * g)), float(common)


def kinematics(s: float, v: float, a: float, p: tuple, dt: float, q: float) -> tuple:
    """(position [m], speed [m/s], acceleration [m/s^2], position and speed variances) dt [s]
    after (s, v, a) with the kinematic covariance p (``kinematic_covariance``), under the
    white-jerk motion model of spectral density q [m^2/s^5]: the first three rows of F and Q,
    the train held at rest where a braking brings it there (``kinematic_mean``). Plain floats:
    numpy's per-call overhead dominates 3x3 arithmetic at 200 estimates/s."""
    p00, p01, p02, p11, p12, p22 = p
    h, dt2 = 0.5 * dt * dt, dt * dt
    var_s = (p00 + 2 * dt * p01 + 2 * h * p02 + dt2 * p11 + 2 * dt * h * p12 + h * h * p22
             + q * dt2 * dt2 * dt / 20)
    var_v = p11 + 2 * dt * p12 + dt2 * p22 + q * dt2 * dt / 3
    return (*kinematic_mean(s, v, a, dt), var_s, var_v)


def kinematic_covariance(P) -> tuple:
    """(P00, P01, P02, P11, P12, P22) of the position, speed and acceleration states, as floats."""
    (p00, p01, p02), (_, p11, p12), (_, _, p22) = P[:3, :3].tolist()
    return p00, p01, p02, p11, p12, p22

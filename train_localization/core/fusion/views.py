"""The hypotheses the policies keep beside the filter, as functions of their records and the filter's
numbers: the motion model's (a coasting's ModelView, a MovedView), an excluded sensor's view and its
disagreement window, the lone source's interval, the covariance opened to the priors. Pure: they
change nothing, so every policy and cover may call them (bookkeeping.py holds the records)."""
from __future__ import annotations

import math

import numpy as np

from ..sensors import faults as fault_modes
from .bookkeeping import LoneView, ModelView, MovedView, View, WindowEntry
from . import inertial
from .models import kinematic_covariance, kinematic_mean, kinematics
from .separation import SPEED_GAP


def model_view(stamp: float, x: np.ndarray, P: np.ndarray) -> ModelView:
    """The motion model's hypothesis from the filter's kinematic state x (n, 1), P at ``stamp`` [s]."""
    return ModelView(stamp, *x[:3, 0].tolist(), kinematic_covariance(P))


def model_view_at(view: ModelView, t: float, process) -> tuple[np.ndarray, np.ndarray]:
    """(kinematic state [s, v, a], its 3x3 covariance) of a coasting's view predicted to t [s]
    (``process``: models.ProcessModel)."""
    dt = max(t - view.stamp, 0.0)
    F, _, Q = process.transition(dt)
    F, Q = F[:3, :3], Q[:3, :3]      # the kinematic block: the error states do not enter it
    p00, p01, p02, p11, p12, p22 = view.cov
    P = F @ np.array([[p00, p01, p02], [p01, p11, p12], [p02, p12, p22]]) @ F.T + Q
    return np.array(kinematic_mean(view.s, view.v, view.a, dt)), P


def motion_view(view: ModelView | MovedView, t: float, s_f: float, var_f: float, jerk_psd: float) -> tuple[float, float]:
    """(position [m], variance [m^2]) at t of a motion-model hypothesis: during its coasting
    the kinematic block from its start predicted with the white-jerk process noise (``jerk_psd``);
    after it moved with the filter (position s_f [m], variance var_f [m^2] at t), the distance
    scaled by 1 + r, r the common scale error of the speed sources in use
    (``MotionViews.coasting_ended``)."""
    if isinstance(view, MovedView):
        d = s_f - view.s_filter
        return (view.s + d * (1.0 + view.r),
                view.var + max(var_f - view.P00_filter, 0.0) + (view.var_r * d * d if d else 0.0))
    s_m, _, _, var, _ = kinematics(view.s, view.v, view.a, view.cov, max(t - view.stamp, 0.0), jerk_psd)
    return s_m, var


def motion_view_fixed(view: ModelView | MovedView, t: float, z: float, R: float, s_f: float, P00_f: float,
                      process, jerk_psd: float) -> ModelView | MovedView:
    """A motion-model hypothesis conditioned on a fix z [m] of variance R [m^2] at t [s] (the
    filter at s_f, P00_f after it): a coasting's kinematic state moved to t and updated
    (H = [1, 0, 0]); a moved one as a scalar update, moved with the filter from here."""
    if isinstance(view, MovedView):
        s_m, var_m = motion_view(view, t, s_f, P00_f, jerk_psd)
        k = var_m / (var_m + R)
        return view._replace(s=s_m + k * (z - s_m), var=(1.0 - k) * var_m, s_filter=s_f, P00_filter=P00_f)
    x, P = model_view_at(view, t, process)
    K = P[:, 0] / (P[0, 0] + R)
    x = x + K * (z - x[0])
    P = P - np.outer(K, P[0, :])
    return ModelView(t, float(x[0]), float(x[1]), float(x[2]), kinematic_covariance(P))


def alternative_spread(model, alt: View) -> tuple[float, float]:
    """(separation D [m], its variance [m^2]) of a relative alternative of a sensor of error ``model``."""
    scale = model.scale_sigma + model.scale_offset_sigma
    return alt.separation, alt.white_var + (scale * alt.run) ** 2


def windowed(window: tuple, m, e: float, S: float, slip_window: float, speed: float,
             common: float = 0.0) -> tuple[tuple, float]:
    """The disagreement window of a relative sensor with this measurement added, and its
    test statistic: the innovations summed over ``slip_window`` s (as distances), squared,
    over the variance of that sum (0 with fewer than 3). ``speed``: the filter's |speed| [m/s].
    common [m^2/s^2]: for a suspended sensor, whose error states are no longer learnt from its
    readings, the part of S from them (scale, bias): the same error in every reading of the
    window, so its standard deviations add up where the rest's variances do (its scale error
    is no disagreement beyond its model). A sensor in use has those states learnt: its
    innovations are white. Entries: WindowEntry."""
    d = getattr(m, "duration", 0.0) or 0.0
    weight = d if d > 0.0 else 1.0
    window = tuple(w for w in window if w.stamp > m.stamp - slip_window)
    window += (WindowEntry(m.stamp, e * weight, (S - common) * weight * weight, math.sqrt(common) * weight,
                           weight, speed),)
    if len(window) < 3:
        return window, 0.0
    var = sum(w.white_var for w in window) + sum(w.common_sd for w in window) ** 2
    return window, sum(w.distance for w in window) ** 2 / var


def fault_ended_shown(cls: str, layout, x: np.ndarray, P: np.ndarray, h: np.ndarray, e: float, S: float,
                      slip_gate: float) -> bool:
    """Whether relative sensor ``cls``, whose scale fault is being learnt, disagreeing by e [m/s]
    (innovation variance S, Jacobian row h at the state x, P) agrees with its model without the
    fault (its constant scale at its prior: within ``slip_gate``): the fault has ended rather
    than another source's begun."""
    i = layout.fault_scale[cls]
    e_raw = e + float(h[i] * x[i, 0])
    S_raw = S + float(h[i] * h[i]) * (layout.prior_sigma[i] ** 2 - float(P[i, i]))
    return not (S_raw <= 0.0 or e_raw * e_raw > slip_gate * S_raw)


def outlasted_by(m, aux, models: dict, in_use: list, bounded: frozenset, slip_window: float) -> bool:
    """Whether suspended sensor ``m.sensor`` (a scale-fault mode), kept as an undecided
    alternative in ``aux`` (Bookkeeping), still disagreeing, has outlasted the faults of the
    speed sources ``in_use``: each has only fault modes that end by themselves (a wheel's slip
    or slide, at most its ``fault_duration_max`` s: ``bounded``), has not been excluded since
    the view began, and the view is older than the longest of those episodes and
    ``slip_window`` [s]. Then the fault is ``m.sensor``'s: a wheel does not slip for longer."""
    alt = aux.relative_alternatives.get(m.sensor)
    if alt is None or "scale_fault" not in models[m.sensor].faults:
        return False
    if not in_use or not all(c in bounded for c in in_use):
        return False
    since = alt.since
    if any(aux.slip_until.get(c, -math.inf) > since for c in in_use):
        return False
    longest = max(models[c].fault_duration_max for c in in_use)
    return m.stamp - since > longest + slip_window


def agrees(z: float, R: float, s: float, P00: float, z_kept: float, R_kept: float, s_kept: float, P00_kept: float,
           gate: float) -> bool:
    """Whether a fix z [m] of variance R [m^2] agrees (within ``gate``, its sensor's) with a kept
    fix z_kept, R_kept moved by the dead reckoning since: the filter's position and its variance
    s, P00 now, s_kept, P00_kept when it was kept."""
    var = R_kept + R + max(P00 - P00_kept, 0.0)
    return (z - (z_kept + (s - s_kept))) ** 2 / var <= gate


def corroborated(m, z: float, R: float, alt, x: np.ndarray, P: np.ndarray, layout, branch_timeout: float,
                 gate: float) -> bool:
    """Whether the unexplained fix kept (``alt``: bookkeeping.UnexplainedFix, or None), of another,
    independent reference and younger than ``branch_timeout`` [s], agrees with fix m (z, R; the
    filter at x, P). Fixes of one sensor with a fix-bias state are not independent, whatever their
    reference ids (mm-wave ranging: overlapping sets of stations, one NLOS or calibration fault in
    all of them)."""
    if alt is None or m.stamp - alt.stamp > branch_timeout:
        return False
    if m.sensor == alt.sensor and (m.reference_id == alt.reference or m.sensor in layout.fix):
        return False
    return agrees(z, R, float(x[0, 0]), float(P[0, 0]), alt.z, alt.R, alt.s, alt.P00, gate)


def separated(view: View, m, e: float, S: float, v: float, P11: float) -> tuple[View, float]:
    """An excluded sensor's view after its reading m, of disagreement e [m/s] and innovation
    variance S [m^2/s^2], at the filter's speed v [m/s] of variance P11 [m^2/s^2]: how far it ran
    ahead [m], the white part of its variance and the distance run added (its scale error is
    common to all); and the reading's own noise [m^2/s^2], roughly."""
    d = getattr(m, "duration", 0.0)
    if not d:
        # a speed holds since the previous one, not across a silence (a radar below its
        # minimum speed at a stop): there the sensor told nothing, as in its own solution
        d = m.stamp - view.last if m.stamp - view.last <= SPEED_GAP else 0.0
    R = max(S - P11, 0.0)
    D = view.separation + e * d
    return view._replace(separation=D, white_var=view.white_var + R * d * d, last=m.stamp, run=view.run + abs(v) * d,
                         farthest=D if abs(D) > abs(view.farthest) else view.farthest), R


def merged(P: np.ndarray, spread: float) -> np.ndarray:
    """Covariance P with an excluded sensor's view that is no longer tracked of its own merged in:
    its squared separation (plus its own variance) ``spread`` [m^2] added to the position
    variance, the filter's mean kept (moment matching of the two views)."""
    P = P.copy()
    P[0, 0] += spread
    return P


def judged(cls: str, layout, models: dict, policies: frozenset) -> bool:
    """Whether a fault test may exclude relative sensor ``cls``: it has slip physics (a wheel's
    slip under traction stands out against the motion model), or another relative sensor
    is configured (whose episodes and suspensions the test arbitrates, with the coastings
    that keep both views). Not so the only relative sensor of a train without slip physics
    (a UTM's radar): suspended, nothing could show it agreeing again (its readings are the
    filter's speed; the fixes alone know the speed too poorly), and the filter would run on
    the motion model for good; its persistent faults are the lone solution's to cover and
    the fix drift test's to find (unless ``policies`` lacks ``lone_sensor_exempt``)."""
    return len(layout.relative) > 1 or bool(fault_modes.ADHESION & set(models[cls].faults)) \
        or "lone_sensor_exempt" not in policies


def raised(P: np.ndarray, faulty, layout, models: dict, speed: float) -> np.ndarray:
    """Covariance P with the relative error states at least as uncertain as their priors,
    and the constant scale of each sensor in ``faulty`` (with a scale-fault mode) by the
    fault's size (``scale_fault_sigma``) more; the speed (the filter's, ``speed`` [m/s]),
    learnt through the scales, as uncertain as they became. Rows and columns are rescaled,
    so the correlations stay."""
    idx = layout.relative_states
    if not len(idx):
        return P
    P = P.copy()
    floor = np.zeros(layout.n)
    floor[idx] = layout.prior_sigma[idx] ** 2
    for name in faulty:
        floor[layout.fault_scale[name]] += models[name].scale_fault_sigma ** 2
    var = np.diag(P).copy()
    scales = [*layout.scale.values(), *layout.offset.values()]
    P[1, 1] += float(np.sum(np.maximum(floor[scales] - var[scales], 0.0))) * speed ** 2
    ratio = np.sqrt(np.divide(np.maximum(var[idx], floor[idx]), var[idx], out=np.ones(len(idx)),
                              where=var[idx] > 0))
    P[idx, :] *= ratio[:, None]
    P[:, idx] *= ratio[None, :]
    return P


def lone_interval(lone: LoneView, t_state: float, t: float, s: float, var_s: float, v: float, var_v: float,
                  scale_fault_sigma: float, z: float, jerk_psd: float, inertial_timeout: float = 0.0) -> tuple:
    """(lo, hi [m], speed half-width [m/s], its position and variance) of the lone source's
    fault hypothesis at t (the filter, of time t_state [s], at s [m], var_s [m^2], v [m/s],
    var_v [m^2/s^2] at t): the motion model's interval, within what the sensor's scale fault
    (``scale_fault_sigma``) can have put into the filter's position (the lone view's bound:
    z x ``scale_fault_sigma`` x the distance run, less what the accepted fixes corrected, for
    a fault that began at any time since), and within the accelerometer's dead reckoning where
    it read within ``inertial_timeout`` s (the accelerometer is sound under this hypothesis:
    one fault at a time); all hold under the hypothesis: empty (lo > hi) where they do not meet."""
    bound = lone.bound + z * scale_fault_sigma * abs(v) * max(t - t_state, 0.0)
    view = lone.view
    s_m, v_m, _, var_m, var_vm = kinematics(view.s, view.v, view.a, view.cov, max(t - view.stamp, 0.0), jerk_psd)
    half, cap = z * math.sqrt(var_m), math.sqrt(z * z * var_s + bound * bound)
    half_v = min(abs(v_m - v) + z * math.sqrt(var_vm), z * math.sqrt(var_v + (scale_fault_sigma * v) ** 2))
    lo, hi = max(s_m - half, s - cap), min(s_m + half, s + cap)
    if lone.inertial is not None and t - lone.inertial.read <= inertial_timeout:
        s_i, var_i, v_i, var_vi = inertial.at(lone.inertial, t)
        half_i = z * math.sqrt(var_i)
        lo, hi = max(lo, s_i - half_i), min(hi, s_i + half_i)
        half_v = min(half_v, abs(v_i - v) + z * math.sqrt(var_vi))
    return lo, hi, half_v, s_m, var_m

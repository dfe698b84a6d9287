"""Solution separation over the relative sensors: a protection level for undetected faults.

Where two relative sensors disagree (a radar reading 7 % low, a wheel correct), the filter
explains the disagreement with their scale and bias states until one of them leaves its
plausible range. Until then every test passes, and the filter's position follows neither
sensor but a blend that its covariance calls precise: the truth leaves the interval while the
filter is NOMINAL (the fault is below what the tests can detect). GNSS integrity monitoring
meets the same problem with solution separation (ARAIM: Blanch et al., "Advanced RAIM user
algorithm description", 2012): besides the all-in-view solution it keeps one solution per
fault hypothesis, each without the measurements that fault would corrupt, and the protection
level covers every one of them. A faulty sensor cannot pull the solutions that exclude it.

Here each relative sensor j that another's fault could pull (``sub_models``) keeps its own
dead reckoning from the absolute fixes: the train's position s_j integrated from j's
readings alone, corrected by its own scale error k_j and bias b_j, which it learns only from
the fixes (a 3-state Kalman filter per sensor; the hypothesis "j is the healthy one"). The
published interval covers each of them with its own uncertainty; where the filter's own
interval would not have covered one (the separation beyond the test threshold) the filter
reports DEGRADED. A fix the filter accepts but sensor j's solution cannot explain refutes
that hypothesis: its solution starts again from the filter's. While j is silent, or the
filter has excluded it for its own fault (a wheel slip under traction, a radar it found
faulty), j's solution follows the filter's speed (``follow``).

Units: s [m], k [1], b [m/s], times [s]. A solution is the tuple ``Sub`` below; the
filter keeps them in its rolled-back bookkeeping (copy-on-write, never changed in place).
Plain floats: a 3x3 covariance per reading of a 200 Hz sensor, within the rollback.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

from ..measurements import SpeedMeasurement
from ..sensors import faults

# fault modes of a relative sensor that its error states can absorb before a test fires, and of
# those the ones that persist (core/sensors/faults.py)
ABSORBED = faults.SPEED
PERSISTENT = faults.PERSISTENT

# a speed sensor silent longer than this [s] is not interpolated across: the gap follows the filter
SPEED_GAP = 1.0


@dataclass(frozen=True)
class SubModel:
    """What one relative sensor's own solution needs of its error model."""

    key: str               # the solution's name: its sensor, or "sensor/mode" for the one whose
                           # constant scale is opened by the size of a calibration fault ``mode``
    sensor: str
    scale_var: float       # prior variance of its constant scale error (scale or offset state) [1]
    gm_var: float          # stationary variance of a Gauss-Markov scale error [1]
    gm_tau: float          # its correlation time [s] (inf: none)
    bias_var: float        # prior variance of its speed bias [m^2/s^2]
    creep: float           # creep coefficient [s^2/m]
    creep_in_traction: bool


class Main(NamedTuple):
    """The filter's own solution at a time, as the sensor solutions need it."""

    s: float               # position [m]
    P00: float             # its variance [m^2]
    v: float               # speed [m/s]
    var_v: float           # its variance [m^2/s^2]
    d: float               # its odometer (Bookkeeping.odometer): its position moved by its speed only [m]


class Sub(NamedTuple):
    """One sensor's own solution at time t."""

    t: float               # time of s [s]
    s: float               # position [m]
    k: float               # constant scale error [1]
    b: float               # bias [m/s]
    pss: float             # covariance of (s, k, b)
    psk: float
    psb: float
    pkk: float
    pkb: float
    pbb: float
    anchor_t: float        # time [s] of its last own reading or fix; its position [m] and variance
    anchor_s: float        # [m^2] then; a
    anchor_pss: float      # time without readings since follows the filter's motion from there:
    base_d: float          # the filter's odometer [m] and position variance [m^2] then
    base_P00: float
    own: bool              # whether it has integrated a reading of its own since it started
    t_v: float             # stamp of its last own speed [s] (-inf: following the filter)
    dv: float              # its speed less the filter's, averaged over ``window`` s [m/s]
    var_dv: float          # the white variance of that average [m^2/s^2]


def sub_models(models: dict) -> dict[str, SubModel]:
    """The solution models of the relative sensors that another relative sensor's fault could
    blend away (``ABSORBED``: faults its error states can take up before a test fires). Against
    a persistent fault (``PERSISTENT``: a radar's scale fault, a wheel worn beyond its tolerance,
    which no test of its own can tell from a scale error) every other relative sensor keeps one.
    Against a transient one (a wheel's
    slip or slide, which has physical tests and ends by itself, but is absorbed into a wheel
    scale that is not yet calibrated when it starts slowly) only the sensors without fault modes
    of their own do (contactless counters: coil counter, EMF observer, pattern belt): a
    solution of a sensor that has its own faults (the radar against the wheel) would be as wide
    as that sensor alone, for a fault the tests mostly catch. A sensor's solution protects
    against the others' faults, not against its own; except a calibration fault (``CALIBRATION``:
    a constant scale beyond the tolerance), against which the sensor keeps a second solution,
    keyed "sensor/mode", whose constant scale is opened by the fault's size (``scale_fault_sigma``)
    and learnt from the fixes: once two fixes have calibrated it, it is as narrow as the filter."""
    relative = {s: m for s, m in models.items() if m.relative}
    out = {}
    for name, m in relative.items():
        gm = math.isfinite(m.scale_tau) and m.scale_sigma > 0.0
        constant = m.scale_offset_sigma if gm else m.scale_sigma
        model = SubModel(name, name, constant ** 2, m.scale_sigma ** 2 if gm else 0.0,
                         m.scale_tau if gm else math.inf, m.bias_sigma ** 2,
                         m.creep_coefficient, m.creep_in_traction)
        clean = not ABSORBED & set(m.faults)
        others = [set(o.faults) for other, o in relative.items() if other != name]
        if any(PERSISTENT & f or (clean and ABSORBED & f) for f in others):
            out[name] = model
        if m.scale_fault_sigma > 0.0:
            for mode in sorted(faults.CALIBRATION & set(m.faults)):
                key = f"{name}/{mode}"
                out[key] = replace(model, key=key, scale_var=constant ** 2 + m.scale_fault_sigma ** 2)
    return out


def hypotheses(models: dict, subs: dict[str, SubModel]) -> dict[str, tuple[str, ...]]:
    """Fault hypothesis "sensor/mode" -> the keys of the solutions valid under it, for the relative
    sensors' fault modes that a solution covers (``sub_models``): under a persistent fault of
    sensor j every solution of another sensor, and j's own one opened to it if it is a calibration
    fault; under a transient one the solutions of the sensors without fault modes of their own.
    The interval covers, per hypothesis, the one of its solutions that widens it least (each is
    a bound under the hypothesis); a hypothesis without a solution is the other checks' to find."""
    out = {}
    for j, m in models.items():
        if not m.relative:
            continue
        for mode in sorted(ABSORBED & set(m.faults)):
            if mode in PERSISTENT:
                valid = [k for k, sm in subs.items() if sm.sensor != j or k == f"{j}/{mode}"]
            else:
                valid = [k for k, sm in subs.items() if sm.sensor != j and k == sm.sensor
                         and not ABSORBED & set(models[sm.sensor].faults)]
            if valid:
                out[f"{j}/{mode}"] = tuple(valid)
    return out


def seed(sm: SubModel, t: float, s: float, var_s: float, d: float) -> Sub:
    """A solution that starts at the filter's position s [m] (variance var_s [m^2]) at t [s], the
    filter's odometer then d [m] (Main.d), its error states at their priors."""
    return Sub(t, s, 0.0, 0.0, var_s, 0.0, 0.0, sm.scale_var, 0.0, sm.bias_var, t, s, var_s, d, var_s, False,
               -math.inf, 0.0, 0.0)


def _anchored(sub: Sub, main: Main) -> Sub:
    """The solution anchored here: a later time without readings follows the filter from ``main``."""
    return sub._replace(anchor_t=sub.t, anchor_s=sub.s, anchor_pss=sub.pss, base_d=main.d, base_P00=main.P00)


def follow(sub: Sub, t: float, main: Main, own: float = 0.0) -> Sub:
    """The solution moved to t [s] with the filter (``main`` at t): a time without a reading of
    its own, or one the filter excluded as its sensor's own fault. From its last own reading or
    fix it moves as the filter's odometer did (its motion by its speed, not the corrections other
    sensors make to its position: over a stop and a start as the filter ran, not at the mean of
    its speeds at both ends) and its variance grows as the filter's did (the filter's dead reckoning over
    that time; counted from there, so that the ups and downs of the filter's variance in between
    do not add up); ``own`` [s]: the part of it up to t that a reading of the sensor covers."""
    if t <= sub.t:
        return sub
    s, pss = _moved(sub, t, main.d, main.v, main.P00, main.var_v, own)
    return sub._replace(t=t, s=s, pss=pss)


def _moved(sub: Sub, t: float, d: float, v: float, P00: float, var_v: float, own: float = 0.0) -> tuple[float, float]:
    """(position [m], variance [m^2]) of ``follow`` at t > sub.t, the filter's odometer d [m],
    speed v [m/s], its variance var_v and its position variance P00 [m^2] at t; the last ``own``
    seconds (a reading's own increment) at the speed v."""
    # the variance of the filter's displacement since the anchor: its position variance's growth,
    # at most that of a persistent speed error over the time (the growth also holds what other
    # sensors taught it about where it was then)
    dt = t - sub.anchor_t
    grown = min(max(P00 - sub.base_P00, 0.0), var_v * dt * dt)
    return sub.anchor_s + (d - sub.base_d) - v * own, sub.anchor_pss + grown


def _advance(sub: Sub, sm: SubModel, t: float, dt: float, u: float, R: float) -> Sub:
    """Integrate the sensor's own speed u [m/s] (its corrected reading, white variance R) over
    dt [s] ending at t: s += u dt; the Jacobians -ds (scale) and -sign dt (bias)."""
    ds = u * dt
    sg = -dt if u < 0.0 else dt
    q = R * dt * dt + (2.0 * sm.gm_tau * sm.gm_var * u * u * dt if sm.gm_var > 0.0 else 0.0)
    pss = (sub.pss - 2.0 * ds * sub.psk - 2.0 * sg * sub.psb + ds * ds * sub.pkk + 2.0 * ds * sg * sub.pkb
           + sg * sg * sub.pbb + q)
    psk = sub.psk - ds * sub.pkk - sg * sub.pkb
    psb = sub.psb - ds * sub.pkb - sg * sub.pbb
    return sub._replace(t=t, s=sub.s + ds, pss=pss, psk=psk, psb=psb)


def reading(sub: Sub, sm: SubModel, m, R: float, a: float, main: Main, window: float) -> Sub:
    """The solution after a reading m of its sensor (speed or distance increment; R its white
    variance in speed units [m^2/s^2]); a [m/s^2]: the filter's acceleration (creep); ``main``:
    the filter at the reading's stamp, for the time the reading does not cover. Its speed less
    the filter's is averaged over ``window`` s (one reading's noise is no speed hypothesis)."""
    if isinstance(m, SpeedMeasurement):
        z, start = m.speed, m.stamp
    else:
        z, start = m.distance / m.duration, m.stamp - m.duration
    u = z / (1.0 + sub.k) - (sub.b if z >= 0.0 else -sub.b)
    sv = 1.0 if u >= 0.0 else -1.0
    if sm.creep and (sm.creep_in_traction or a * sv < 0.0):
        u /= 1.0 + sm.creep * a * sv          # creep: the wheel turns at u (1 + c a sign u)
    v = main.v
    if math.isfinite(sub.t_v) and m.stamp > sub.t_v:
        w = min((m.stamp - sub.t_v) / window, 1.0)
        dv, var_dv = sub.dv + w * (u - v - sub.dv), (1.0 - w) ** 2 * sub.var_dv + w * w * R
    else:
        dv, var_dv = u - v, R
    if isinstance(m, SpeedMeasurement):
        dt = m.stamp - sub.t
        if 0.0 < dt <= SPEED_GAP:
            # its own speed over the time since its last reading (the mean of this one and the
            # filter's then, less their averaged difference); after a start, this one alone: the
            # filter's motion since may carry the very fault the solution is kept against
            prev = 0.5 * (u + v + sub.dv) if math.isfinite(sub.t_v) else u
            sub = _anchored(_advance(sub, sm, m.stamp, dt, prev, R), main)
        else:
            sub = follow(sub, m.stamp, main)
        return sub._replace(own=True, t_v=m.stamp, dv=dv, var_dv=var_dv)
    dt = m.stamp - max(start, sub.t)
    if start > sub.t:
        sub = follow(sub, m.stamp, main, own=dt)._replace(t=start)
    if dt > 0.0:
        sub = _anchored(_advance(sub, sm, m.stamp, dt, u, R), main)
    return sub._replace(own=True, t_v=m.stamp, dv=dv, var_dv=var_dv)


def speed_half_width(sub: Sub, sm: SubModel, v: float, var_v: float, z: float) -> float:
    """Half-width [m/s] around the filter's speed v (variance var_v) that covers the sensor's
    own speed with its errors: scale (learnt and Gauss-Markov), bias, averaged noise."""
    u = v + sub.dv
    var = sub.var_dv + u * u * (sub.pkk + sm.gm_var) + sub.pbb + var_v
    return abs(sub.dv) + z * math.sqrt(var)


def fix(sub: Sub, t: float, z: float, R: float, before: Main, gate: float) -> Sub | None:
    """The solution after an absolute fix z [m] of variance R [m^2] at t [s], or None if it
    cannot explain the fix (normalised innovation squared beyond ``gate``); ``before``: the
    filter at t without the fix. While its sensor reads, the fix observes the solution's
    position at its own last time plus the filter's motion since, whose variance joins R: the
    solution stays at its own time, so that its sensor's next reading covers its whole interval
    with its own speed. After a longer silence, or while it follows the filter (its sensor
    excluded), the solution moves to the fix with the filter and is anchored there."""
    moved = follow(sub, t, before)
    if t - sub.t > SPEED_GAP or sub.t != sub.anchor_t:   # silent, or following the filter
        sub = moved._replace(anchor_t=t, anchor_s=moved.s, anchor_pss=moved.pss, base_d=before.d,
                             base_P00=before.P00)
    else:
        R += moved.pss - sub.pss
    nu, S = z - moved.s, sub.pss + R
    if nu * nu > gate * S:
        return None
    ks, kk, kb = sub.pss / S, sub.psk / S, sub.psb / S
    new = sub._replace(
        s=sub.s + ks * nu, k=sub.k + kk * nu, b=sub.b + kb * nu,
        pss=sub.pss - ks * sub.pss, psk=sub.psk - ks * sub.psk, psb=sub.psb - ks * sub.psb,
        pkk=sub.pkk - kk * sub.psk, pkb=sub.pkb - kk * sub.psb, pbb=sub.pbb - kb * sub.psb)
    return new._replace(anchor_s=new.s, anchor_pss=new.pss)


def at(sub: Sub, t: float, var_s: float, v: float, var_v: float, d: float) -> tuple[float, float]:
    """(position [m], variance [m^2]) of the solution at t [s], moved with the filter since its
    last reading (the filter's position variance var_s [m^2], speed v [m/s], its variance var_v
    and its odometer d [m] at t); the estimate's ``follow`` without a new solution."""
    if t <= sub.t:
        return sub.s, sub.pss
    return _moved(sub, t, d, v, var_s, var_v)


def separated(s_sub: float, var_sub: float, s: float, var_s: float, z: float) -> bool:
    """Whether a solution's separation from the filter's exceeds its test threshold: z times
    the standard deviation of the separation (var_sub - var_s for nested solutions; at least
    the filter's own, so that its interval alone would not have covered the solution)."""
    d = s_sub - s
    return d * d > z * z * max(var_sub - var_s, var_s)

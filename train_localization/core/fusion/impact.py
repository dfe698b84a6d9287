"""Fault impact: the protection level of a persistent fault of a relative sensor, by construction.

The filter is linear in the errors of what it takes in. A scale fault f of relative sensor j
(a Doppler radar reading 7 % low) adds f x v to each of j's speeds (f x d to each of its
distances), and the filter carries, whatever its policies decided to use or exclude, the
state error f x e with

    predict   e <- F e
    update    e <- e + K g,   g = delta - h e   (delta: the reading's own fault, v or d for j's
                                                 readings, 0 for every other sensor's)

g is also the mean of the update's innovation per unit fault, so the innovations test the
fault as they come (a generalised likelihood ratio): ``info`` = sum g^2 / S is the Fisher
information about f, ``score`` = sum g nu / S, and f_hat = score / info its least-squares
estimate with 1-sigma 1 / sqrt(info). The readings of other sensors count (fixes, another
speed source), the sensor's own only while another speed source in use checks them: against
the motion model alone a fault that ramps up, or down at its end, passes as an acceleration. The fault the data allows is f_hat (within the sensor's bound,
z x scale_fault_sigma) with 1-sigma 1 / sqrt(info), at most scale_fault_sigma (nothing has
tested it); the interval covers each hypothesis: |e_0 f_hat| + z sqrt(sigma^2 + (e_0
sigma_f)^2), ARAIM's bias + K sigma with the fault's spread taken with the filter's noise.

A wheel that was excluded through its slip episodes tested nothing, so a radar that carried
the speed meanwhile is covered up to its fault's size; a wheel in use tests the radar at every
increment, and the cover shrinks to what the two cannot tell apart. The onset is unknown: a
fault is followed from onsets ``fault_onset_spacing`` s apart (config.py); so is its end: at
each onset the hypothesis that matters most is also followed as ended there (its error stays
in the state while its sensor, right again, agrees with the others). At most ``fault_onsets``
per sensor: the newest active ones always, and the others whose cover is the largest.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

class Impact(NamedTuple):
    """One fault hypothesis: sensor ``sensor`` has had a constant scale fault since ``onset``
    (``active``), or had one from ``onset`` until it ended (the error it left is in the state)."""

    sensor: str
    onset: float         # [s]
    e: np.ndarray        # (n,) state error per unit fault [m, m/s, m/s^2, error-state units]
    info: float          # Fisher information about the fault from the innovations since the onset [1]
    score: float         # sum g nu / S [1]
    active: bool = True  # the fault goes on (its sensor's readings carry it)

    def fault(self, bound: float, z: float) -> tuple[float, float]:
        """(mean, 1-sigma) [1] of the fault the data allows: the least-squares estimate within
        +-bound, and 1 / sqrt(info), at most the prior bound / z (nothing tested: the sensor's
        own scale_fault_sigma)."""
        prior = bound / z
        if self.info <= 0.0:
            return 0.0, prior
        mean = self.score / self.info
        return max(-bound, min(bound, mean)), min(prior, 1.0 / math.sqrt(self.info))

    def excluded_beyond(self, bound: float, z: float) -> float:
        """The largest |fault| [1] the data has not excluded at z sigma, at most ``bound``."""
        mean, sigma = self.fault(bound, z)
        return min(bound, abs(mean) + z * sigma)


def started(impacts: tuple, bounds: dict[str, float], onset: float, n: int, max_onsets: int, z: float) -> tuple:
    """``impacts`` plus, per sensor of ``bounds`` (sensor -> fault bound), a new hypothesis from
    ``onset`` [s] (e = 0), and the fault that matters most so far ended at ``onset`` (a fault
    that ended leaves its error in the state, while its sensor's readings, right again, agree:
    followed as still going on, the data would exclude it). Beyond ``max_onsets`` for a sensor
    one is dropped: never one of the newest half of the active ones (a fault that began at a stop
    has put nothing in yet, and is the least tested once the train moves), else the one whose
    cover (|e_0| x the size not excluded) is smallest."""
    out = list(impacts)

    def cover(imp, bound):
        return abs(float(imp.e[0])) * imp.excluded_beyond(bound, z)
    for sensor, bound in bounds.items():
        active = [imp for imp in out if imp.sensor == sensor and imp.active]
        if active:
            largest = max(active, key=lambda imp: cover(imp, bound))
            if cover(largest, bound) > 0.0:
                out.append(largest._replace(active=False))
        out.append(Impact(sensor, onset, np.zeros(n), 0.0, 0.0))
        while True:
            own = [k for k, imp in enumerate(out) if imp.sensor == sensor]
            if len(own) <= max_onsets:
                break
            newest = [k for k in own if out[k].active][-max(1, max_onsets // 4):]
            older = [k for k in own if k not in newest]
            out.pop(min(older, key=lambda k: cover(out[k], bound)))
    return tuple(out)


def predicted(impacts: tuple, F: np.ndarray) -> tuple:
    """Each e moved by the transition F."""
    return tuple(imp._replace(e=F.dot(imp.e)) for imp in impacts)


def updated(impacts: tuple, fault_input: tuple | None, h: np.ndarray, K: np.ndarray, nu: float,
            S: float) -> tuple:
    """After a scalar update with row h, gain K (n,), innovation nu and its variance S, of a
    reading whose own fault per unit is ``fault_input`` = (sensor, v or d, whether another speed
    source in use checks it), None for a fix."""
    out = []
    for imp in impacts:
        own = fault_input is not None and fault_input[0] == imp.sensor
        g = (fault_input[1] if own and imp.active else 0.0) - float(h.dot(imp.e))
        if own and not fault_input[2]:   # against the motion model alone a ramp passes: no test
            out.append(imp._replace(e=imp.e + K * g))
        else:
            out.append(imp._replace(e=imp.e + K * g, info=imp.info + g * g / S, score=imp.score + g * nu / S))
    return tuple(out)


def states_set(impacts: tuple, idx, value: float = 0.0) -> tuple:
    """The states ``idx`` were set by a policy, not by the readings: their error per unit fault
    is ``value`` (0: set to what the fault-free filter would have set them to)."""
    out = []
    for imp in impacts:
        e = imp.e.copy()
        e[idx] = value
        out.append(imp._replace(e=e))
    return tuple(out)


def position_set_from_fix(impacts: tuple, fix_bias_index: int | None) -> tuple:
    """The position was taken from a fix alone (s = z - fix bias): its error per unit fault is
    minus that of the fix bias (0 without one)."""
    out = []
    for imp in impacts:
        e = imp.e.copy()
        e[0] = -e[fix_bias_index] if fix_bias_index is not None else 0.0
        out.append(imp._replace(e=e))
    return tuple(out)


def speed_set(impacts: tuple, speed: float) -> tuple:
    """The speed was set from readings that may include the faulty sensor's: its error per unit
    fault is taken as the whole speed while the fault goes on (the fault's full share), 0 once it
    ended; the acceleration's as 0."""
    out = []
    for imp in impacts:
        e = imp.e.copy()
        e[1], e[2] = abs(speed) if imp.active else 0.0, 0.0
        out.append(imp._replace(e=e))
    return tuple(out)


def cover(impacts: tuple, bounds: dict[str, float], dt: float, z: float, var_s: float,
          var_v: float) -> tuple[float, float]:
    """(position [m], speed [m/s]) half-widths of the interval that covers every hypothesis at dt
    [s] after the filter's state, whose own variances there are var_s [m^2], var_v [m^2/s^2]:
    per hypothesis the fault's mean effect plus z x (the filter's noise and the fault's spread,
    root-sum-squared), the largest over the hypotheses and the fault-free z sigma."""
    half_s, half_v = z * math.sqrt(var_s), z * math.sqrt(var_v)
    for imp in impacts:
        mean, sigma = imp.fault(bounds[imp.sensor], z)
        e0, e1, e2 = float(imp.e[0]), float(imp.e[1]), float(imp.e[2])
        p, v = e0 + e1 * dt + 0.5 * e2 * dt * dt, e1 + e2 * dt
        half_s = max(half_s, abs(p * mean) + z * math.sqrt(var_s + (p * sigma) ** 2))
        half_v = max(half_v, abs(v * mean) + z * math.sqrt(var_v + (v * sigma) ** 2))
    return half_s, half_v

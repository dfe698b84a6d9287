"""Along-track fusion: an extended Kalman filter (filterpy) with exact out-of-order handling.

State x = [s, v, a, k_1 .. k_n, k0_1 .., b_1 .. b_m, e_1 .. e_l]: chainage of the train
front [m], speed [m/s], acceleration [m/s^2], and the sensor errors that matter:
  k   relative scale error per incremental/speed sensor class in ``scale_sensors``
      (wheel diameter error, Doppler scale: the sensor measures (1 + k) times the true
      quantity);
  k0  a constant part of that scale for the classes in ``scale_offset_sigma`` (the
      Doppler radar: its AR(1) scale error averages to zero only if the radar has no
      mounting error, which the fusion does not take for granted);
  b   speed bias [m/s, along the direction of motion] per class in ``bias_sensors``
      (the Doppler radar's device bias);
  e   position-fix bias [m] per class in ``fix_bias_sensors``: mm-wave ranging
      (per-station calibration biases that persist while the same stations are in
      view, so its 200 fixes/s do not average them out) and INPO (at speed a fix's
      error is the survey/laying error of its section alone: the fixes of one section
      agree to 0.1 mm, so treating that bias as white noise would let the filter
      average it away).

Why an EKF (filterpy.kalman.ExtendedKalmanFilter holds x and P) and not a UKF: the
only nonlinearity is the product of a scale (or bias) state and the speed, which an
EKF linearises with negligible error at the accuracy of the sensors (the scale
errors are < 2 %, so the second-order term is < 2 % of the first-order one); and the
filter re-runs its history whenever a measurement arrives late, where one Jacobian
product per scalar update is several times cheaper than 2n+1 sigma points. The
update itself is our own scalar-measurement form of filterpy's
``ExtendedKalmanFilter.update`` (same equations, test/test_fusion.py checks that
they agree), written without filterpy's generic matrix bookkeeping because the
rollback re-applies every measurement of the last 200 ms or so many times
(``train_localization.tools.bench_fusion`` measures it).

Process model
  [s, v, a]   constant acceleration driven by white jerk (spectral density ``jerk_psd``)
  k (scale)   first-order Gauss-Markov process with correlation time ``scale_tau[sensor]``
              and stationary 1-sigma ``scale_sigma[sensor]`` -- the exact discretisation
              of the Doppler radar's AR(1) scale error (core/sensors/doppler.py
              ``scale_sigma`` 0.5 %, ``scale_tau`` 5 s) --, or, without a tau, a random
              walk (``scale_psd``) from a prior ``scale_sigma`` (wheel diameter: constant
              between re-calibrations, wear within +-1 %, i.e. 1-sigma 1 %/sqrt(3))
  k0          random walk (``scale_psd``) from a prior ``scale_offset_sigma[sensor]``
  b (bias)    random walk (``bias_psd``) from a prior ``bias_sigma[sensor]``
  e (fix bias) Gauss-Markov in the distance travelled and in time: phi = exp(-|v| dt / L
              - dt / tau) with ``fix_bias_length[sensor]`` L, ``fix_bias_tau[sensor]`` tau
              and stationary 1-sigma ``fix_bias_sigma``; for ``fix_bias_per_reference``
              classes (INPO) it is redrawn from its prior whenever the fix's
              reference_id (the section) changes

Measurement models (scalar updates)
  PositionFix        z = s (+ e)                          (balise, LRL, INPO, mm-wave, axle counter)
  SpeedMeasurement   z = (1 + k + k0)(u + sign(z) b),  u = v        (Doppler)
  DistanceIncrement  z = distance / d = (1 + k + k0)(u + sign(z) b), u = v - a d/2 (wheel,
                     pattern belt): the mean speed over the interval of length d ending
                     at the stamp, with R = (distance_stddev / d)^2
                     (without a k, k0 or b state that term is 0). A wheel under traction or braking
                     turns faster or slower than the train moves (creep, wheel.py): u is
                     replaced by u + c a |u| with the vehicle's ``creep_coefficient`` c.
                     (A creep state instead is not observable apart from the scale at a
                     constant acceleration, and the EKF let the pair drift along that
                     direction: tried and dropped.)
Honest noise: a decoder reports the 1-sigma of a measurement including its slowly
varying errors (the Doppler decoder adds 0.5 % of the speed for the scale and its
0.02 m/s bias, the wheel decoder the diameter tolerance times the distance) as if
they were white. Since the filter carries those errors as states, they are removed
from R: R = sigma^2 - (reported_scale[sensor] z)^2 - reported_bias[sensor]^2 (floored
at 1 % of sigma^2); ``stddev_factor[sensor]`` then scales what is left (1 = the
sensor's own figure). Likewise a fix's R loses the fixed part
``reported_fix_bias[sensor]`` that its fix-bias state carries (INPO).

Late and out-of-order measurements: every measurement is kept for ``history`` s with
the filter state after it (x, P and the bookkeeping: immutable snapshots that share
their arrays, no copying). One that arrives late is inserted at its stamp and the
measurements after it are re-applied from the state before it -- lazily, when an
estimate is next asked for, so that several late arrivals cost one replay. The
result equals in-order processing bit for bit (ties are ordered by a key built from
the measurement itself, never by arrival). ``estimate(t)`` for a t inside the history
uses the state after the last measurement stamped <= t, so the estimate of a past
time does not depend on the order in which the data came in.

Gating: a measurement whose normalised innovation squared exceeds the chi-square
quantile (1 dof) of ``gate_probabilities[sensor]`` (default ``gate_probability``) is
rejected and counted. Slip/slide: an increment of a ``slip_sensors`` class (the
wheel) whose NIS exceeds the ``slip_gate_probability`` quantile while another speed
source was accepted in the last ``slip_reference_timeout`` s starts a slip/slide
episode: that sensor is excluded until ``slip_holdoff`` s after its last
disagreement. Re-acquisition: when the gate rejects ``reacquire_count`` absolute fixes
in a row and none was accepted for ``reacquire_time`` s, the filter rather than the
fixes is wrong (a slip it missed, a bad reset): the last of them sets the position like
a first fix.

Modes: INITIALISING until the first absolute fix (no position is claimed: NaN and an
infinite interval), LOST when the position 1-sigma exceeds ``lost_stddev``, DEGRADED
when a sensor class of ``timeouts`` has not been accepted for longer than its
timeout, else NOMINAL. [position_min, position_max] is the two-sided ``confidence``
interval of the Gaussian position estimate.
"""
from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field, fields

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from scipy.stats import chi2, norm

from .measurements import PositionFix, SpeedMeasurement
from .sensors import doppler as _doppler
from .sensors import inpo as _inpo
from .sensors import wheel as _wheel
from .signals import InputRejected

MODE_INITIALISING, MODE_NOMINAL, MODE_DEGRADED, MODE_LOST = 0, 1, 2, 3

# error levels of the sensor models' defaults (core/sensors/*.py), so that the
# filter's noise model follows the devices
_DOPPLER_SCALE = float(_doppler.PARAMS["scale_sigma"].default)   # 0.005
_DOPPLER_TAU = float(_doppler.PARAMS["scale_tau"].default)       # 5 s
_DOPPLER_BIAS = float(_doppler.PARAMS["bias"].default)           # 0.02 m/s
# A Doppler radar's long-term scale is not exactly its datasheet mean: a 0.2 deg
# mounting-angle error at 45 deg changes cos(theta) by 0.35 %. The simulated radar has
# none, but a filter that takes the AR(1) model literally calibrates the wheel to
# 0.27 % after 35 s of Doppler alone, and one seed in ten (a 2.4-sigma AR excursion
# plus a 2.2-sigma balise) then left the 99.9 % interval before the second fix.
_DOPPLER_OFFSET = 0.0035
# mm-wave fix errors (measured on config/scenario_maglev_500.yaml, 12 seeds): besides the
# white ranging noise a component of ~2 cm rms from the per-station calibration biases
# (cal_sigma 3 cm) that decorrelates as the stations in view change (~3 s at 139 m/s,
# i.e. ~400 m), plus NLOS biases of 0.1-0.15 m lasting ~0.5 s that pass the decoder's
# chi-square test. One Gauss-Markov state of 5 cm, 400 m / 1 s covers both: normalised
# errors 0.4-0.64 rms, max 2.6 where only mm-wave fixes (without the time constant one
# seed in 12 left the 99.9 % interval)
_MMWAVE_BIAS, _MMWAVE_LENGTH, _MMWAVE_TAU = 0.05, 400.0, 1.0
# INPO: the decoder's fixed part, survey of the section start and mean loop-pair skew;
# measured: at 500 km/h a fix's error is this bias alone (spread 0.08 mm within a
# section, 2.07 mm rms over 36 sections)
_INPO_BIAS = math.hypot(float(_inpo.PARAMS["survey_sigma"].default),
                        float(_inpo.PARAMS["skew_sigma"].default) / math.sqrt(float(_inpo.PARAMS["n_pairs"].default)))
_WHEEL_CREEP = float(_wheel.PARAMS["creep_coefficient"].default)  # 0.002 s^2/m
_WHEEL_SCALE = float(_wheel.PARAMS["diameter_tolerance"].default) / math.sqrt(3.0)  # uniform +-1 %


def _doc(default, text: str, factory: bool = False):
    if factory:
        return field(default_factory=default, metadata={"doc": text})
    return field(default=default, metadata={"doc": text})


@dataclass
class FusionConfig:
    """Tuning of the filter; every field is a parameter of the fusion node (``metadata["doc"]``)."""

    track_id: str = _doc("", "track id of the published states")
    scale_sensors: tuple[str, ...] = _doc(("wheel", "doppler"), "sensor classes with a scale-error state")
    bias_sensors: tuple[str, ...] = _doc(("doppler",), "sensor classes with a speed-bias state [m/s]")
    slip_sensors: tuple[str, ...] = _doc(("wheel",), "sensor classes checked for slip/slide")
    jerk_psd: float = _doc(0.1, "white-jerk spectral density of the motion model [m^2/s^5] (0.1: the "
                                "profiles' 0.5 m/s^3 jerk-limited transitions stay consistent; 0.5 let more "
                                "Doppler noise into the speed while the wheel slips)")
    scale_psd: float = _doc(1e-9, "random-walk spectral density of a scale state without a tau [1/s]")
    scale_tau: dict[str, float] = _doc(lambda: {"doppler": _DOPPLER_TAU},
                                       "sensor -> correlation time of its Gauss-Markov scale state [s] "
                                       "(Doppler AR(1) scale error, doppler.py scale_tau)", True)
    scale_sigma: dict[str, float] = _doc(lambda: {"wheel": _WHEEL_SCALE, "doppler": _DOPPLER_SCALE},
                                         "sensor -> prior (Gauss-Markov: stationary) 1-sigma of its scale "
                                         "state [fraction] (wheel: 1 %/sqrt(3), doppler: 0.5 %)", True)
    scale_offset_sigma: dict[str, float] = _doc(lambda: {"doppler": _DOPPLER_OFFSET},
                                                "sensor -> prior 1-sigma of a constant scale error added to its "
                                                "Gauss-Markov one [fraction] (Doppler: mounting angle, not "
                                                "trusting the radar's long-term mean blindly)", True)
    initial_scale_stddev: float = _doc(0.01, "prior 1-sigma of a scale state not in scale_sigma [fraction]")
    bias_sigma: dict[str, float] = _doc(lambda: {"doppler": _DOPPLER_BIAS},
                                        "sensor -> prior 1-sigma of its bias state [m/s]", True)
    bias_psd: float = _doc(0.0, "random-walk spectral density of the bias states [m^2/s^3]")
    fix_bias_sensors: tuple[str, ...] = _doc(("mmwave", "inpo"), "position-fix sensor classes with a bias "
                                                                  "state [m] (errors that persist from fix to fix)")
    fix_bias_sigma: dict[str, float] = _doc(lambda: {"mmwave": _MMWAVE_BIAS, "inpo": _INPO_BIAS},
                                            "sensor -> stationary 1-sigma of its fix bias [m] (mm-wave: station "
                                            "calibration biases and the small NLOS biases its decoder cannot "
                                            "reject; INPO: survey of the section start and loop laying, inpo.py)",
                                            True)
    fix_bias_length: dict[str, float] = _doc(lambda: {"mmwave": _MMWAVE_LENGTH},
                                             "sensor -> correlation length of its fix bias along the track [m] "
                                             "(mm-wave: the set of stations in view changes over ~ the station "
                                             "spacing); none = no decorrelation with the distance", True)
    fix_bias_tau: dict[str, float] = _doc(lambda: {"mmwave": _MMWAVE_TAU},
                                          "sensor -> correlation time of its fix bias [s] (also at standstill; "
                                          "mm-wave: NLOS episodes, 0.5 s mean); none = no decorrelation in time",
                                          True)
    fix_bias_per_reference: tuple[str, ...] = _doc(("inpo",), "sensor classes whose fix bias belongs to the "
                                                             "reference (reference_id: the INPO section): a new "
                                                             "reference draws a new, independent bias")
    reported_fix_bias: dict[str, float] = _doc(lambda: {"inpo": _INPO_BIAS},
                                               "sensor -> fixed-error 1-sigma [m] that its decoder includes in the "
                                               "reported fix stddev; removed from R (the fix-bias state models "
                                               "it)", True)
    creep_coefficient: dict[str, float] = _doc(lambda: {"wheel": _WHEEL_CREEP},
                                               "sensor -> creep coefficient c [s^2/m] of its wheel (vehicle "
                                               "data; wheel speed = v (1 + c a sign v), wheel.py)", True)
    reported_scale: dict[str, float] = _doc(lambda: {"wheel": _WHEEL_SCALE, "doppler": _DOPPLER_SCALE},
                                            "sensor -> relative scale 1-sigma that its decoder includes in "
                                            "the reported stddev; removed from R (the state models it)", True)
    reported_bias: dict[str, float] = _doc(lambda: {"doppler": _DOPPLER_BIAS},
                                           "sensor -> bias 1-sigma [m/s] that its decoder includes in the "
                                           "reported stddev; removed from R", True)
    stddev_factor: dict[str, float] = _doc(dict, "sensor -> factor on its reported stddev (after the removal "
                                                 "above); 1 = the sensor's own figure", True)
    initial_speed_stddev: float = _doc(100.0, "prior 1-sigma of the speed [m/s] (unknown at start-up)")
    initial_accel_stddev: float = _doc(1.0, "prior 1-sigma of the acceleration [m/s^2]")
    gate_probability: float = _doc(0.9999, "chi-square gate (1 dof) of every measurement")
    gate_probabilities: dict[str, float] = _doc(dict, "sensor -> its own chi-square gate probability", True)
    slip_gate_probability: float = _doc(0.999, "chi-square quantile above which a slip sensor's "
                                                "increment starts/extends a slip or slide episode")
    slip_holdoff: float = _doc(0.5, "a slip sensor stays excluded this long after its last disagreement [s] "
                                    "(each disagreeing increment renews it; 2 s excluded good increments "
                                    "after the episodes and cost ~0.1 km/h of speed p95)")
    slip_reference_timeout: float = _doc(1.0, "slip is declared only if another speed source was accepted "
                                              "within this time [s]")
    reacquire_count: int = _doc(3, "the n-th absolute fix in a row (any class) that the gate rejects "
                                   "re-initialises the position instead, if none was accepted for "
                                   "reacquire_time (0 = never)")
    reacquire_time: float = _doc(5.0, "no absolute fix accepted for this long before a re-acquisition [s]")
    history: float = _doc(2.0, "how late a measurement may be [s]")
    confidence: float = _doc(0.999, "probability of [position_min, position_max]")
    lost_stddev: float = _doc(100.0, "position 1-sigma above which the mode is LOST [m]")
    timeouts: dict[str, float] = _doc(dict, "sensor class -> timeout [s]; a class past it -> DEGRADED", True)

    def __post_init__(self):
        for name in ("scale_sensors", "bias_sensors", "slip_sensors", "fix_bias_sensors", "fix_bias_per_reference"):
            setattr(self, name, tuple(getattr(self, name)))
        for f in fields(self):
            if isinstance(getattr(self, f.name), dict):
                setattr(self, f.name, {str(k): float(v) for k, v in getattr(self, f.name).items()})
        if not 0.0 < self.confidence < 1.0:
            raise ValueError("confidence must be in (0, 1)")
        if self.history <= 0.0:
            raise ValueError("history must be > 0 s")
        for name in ("scale_sensors", "bias_sensors", "fix_bias_sensors"):
            if len(set(getattr(self, name))) != len(getattr(self, name)):
                raise ValueError(f"{name} must not repeat a sensor")


@dataclass
class Estimate:
    stamp: float
    position: float
    speed: float
    acceleration: float
    position_stddev: float
    speed_stddev: float
    position_min: float
    position_max: float
    confidence: float
    mode: int
    scales: dict[str, float]
    biases: dict[str, float] = field(default_factory=dict)


def _order_key(m) -> tuple:
    """Deterministic total order of measurements: by stamp, then by content."""
    if isinstance(m, PositionFix):
        body = (0, m.position, m.position_stddev)
    elif isinstance(m, SpeedMeasurement):
        body = (1, m.speed, m.speed_stddev)
    else:
        body = (2, m.distance, m.duration)
    return (m.stamp, m.sensor, m.unit_id) + body


class _Aux:
    """Bookkeeping that rolls back with x and P. Copy-on-write: ``copy`` is shallow and
    the dicts/sets are never changed in place, only replaced."""

    __slots__ = ("initialised", "t", "last_accepted", "slip_until", "accepted", "gated", "slips",
                 "speed_sources", "nis", "fix_ref", "fix_gated_run", "last_fix_accepted", "reacquired")

    def __init__(self):
        self.initialised = False
        self.t: float | None = None           # time of x, P [s]
        self.last_accepted: dict[str, float] = {}
        self.slip_until: dict[str, float] = {}
        self.accepted: dict[str, int] = {}
        self.gated: dict[str, int] = {}
        self.slips = 0
        self.speed_sources: frozenset = frozenset()   # classes that gave speed/distance
        self.nis: dict[str, tuple[int, float]] = {}   # sensor -> (count, sum of NIS) of accepted ones
        self.fix_ref: dict[str, str] = {}              # sensor -> reference of its current fix bias
        self.fix_gated_run = 0                         # absolute fixes gated in a row
        self.last_fix_accepted = -math.inf
        self.reacquired = 0

    def copy(self) -> "_Aux":
        new = _new_aux(_Aux)
        (new.initialised, new.t, new.last_accepted, new.slip_until, new.accepted, new.gated, new.slips,
         new.speed_sources, new.nis, new.fix_ref, new.fix_gated_run, new.last_fix_accepted,
         new.reacquired) = (self.initialised, self.t, self.last_accepted, self.slip_until, self.accepted,
                            self.gated, self.slips, self.speed_sources, self.nis, self.fix_ref,
                            self.fix_gated_run, self.last_fix_accepted, self.reacquired)
        return new


_new_aux = object.__new__


def _inc(counter: dict, key: str) -> dict:
    new = dict(counter)
    new[key] = new.get(key, 0) + 1
    return new


class TrainFilter:
    """Feed measurements with ``add`` (any order within ``history``), query with ``estimate``."""

    def __init__(self, config: FusionConfig | None = None):
        cfg = self.cfg = config or FusionConfig()
        n = 3

        def block(names):
            nonlocal n
            idx = {name: n + i for i, name in enumerate(names)}
            n += len(idx)
            return idx
        self._scale_idx = block(cfg.scale_sensors)
        self._offset_idx = block([s for s in cfg.scale_sensors if cfg.scale_offset_sigma.get(s, 0.0) > 0.0])
        self._bias_idx = block(cfg.bias_sensors)
        self._fix_idx = block(cfg.fix_bias_sensors)
        self.n = n
        # fix biases: Gauss-Markov in the distance travelled and in time (applied in _predicted)
        self._per_ref = {s for s in cfg.fix_bias_per_reference if s in self._fix_idx}
        fixgm = [(i, cfg.fix_bias_length.get(s, math.inf), cfg.fix_bias_tau.get(s, math.inf),
                  cfg.fix_bias_sigma.get(s, 0.0)) for s, i in self._fix_idx.items()]
        self._fixgm = [g for g in fixgm if math.isfinite(g[1]) or math.isfinite(g[2])]   # others: constant
        self.ekf = ExtendedKalmanFilter(dim_x=self.n, dim_z=1)
        # scale states: Gauss-Markov (index, tau, sigma) or random walks (index, psd)
        self._gm = [(i, cfg.scale_tau[s], cfg.scale_sigma.get(s, cfg.initial_scale_stddev))
                    for s, i in self._scale_idx.items() if cfg.scale_tau.get(s, 0.0) > 0.0]
        self._rw = [(i, cfg.scale_psd) for s, i in self._scale_idx.items() if not cfg.scale_tau.get(s, 0.0) > 0.0]
        self._rw += [(i, cfg.scale_psd) for i in self._offset_idx.values()]
        self._rw += [(i, cfg.bias_psd) for i in self._bias_idx.values()]
        self._gate = float(chi2.ppf(cfg.gate_probability, 1))
        self._gates = {s: float(chi2.ppf(p, 1)) for s, p in cfg.gate_probabilities.items()}
        self._slip_gate = float(chi2.ppf(cfg.slip_gate_probability, 1))
        self._z = float(norm.ppf(0.5 + cfg.confidence / 2.0))
        self._cache: dict[float, tuple] = {}
        self._est_cache: tuple = (None, None)   # (x, P, x as floats, P[:3, :3] as floats) for estimate
        self._scale_terms = [(name, i, self._offset_idx.get(name)) for name, i in self._scale_idx.items()]
        self._eye = np.eye(self.n)
        self.rejected: dict[str, int] = {}
        self.rollbacks = 0        # measurements that arrived after one stamped later (out of order)
        self.applied = 0          # measurement updates run, replays included
        self._clear(self._initial_state())

    # -- state handling --------------------------------------------------------
    def _initial_state(self):
        cfg = self.cfg
        P = np.zeros((self.n, self.n))
        P[0, 0] = 1.0  # relative position until the first fix
        P[1, 1] = cfg.initial_speed_stddev ** 2
        P[2, 2] = cfg.initial_accel_stddev ** 2
        for s, i in self._scale_idx.items():
            P[i, i] = cfg.scale_sigma.get(s, cfg.initial_scale_stddev) ** 2
        for s, i in self._offset_idx.items():
            P[i, i] = cfg.scale_offset_sigma[s] ** 2
        for s, i in self._bias_idx.items():
            P[i, i] = cfg.bias_sigma.get(s, 0.0) ** 2
        for s, i in self._fix_idx.items():
            P[i, i] = cfg.fix_bias_sigma.get(s, 0.0) ** 2
        return np.zeros((self.n, 1)), P, _Aux()

    def _clear(self, base) -> None:
        self._keys: list[tuple] = []
        self._stamps: list[float] = []
        self._meas: list = []
        self._snaps: list[tuple] = []   # state after each applied measurement
        self._n_applied = 0
        self._base = base               # state before the first kept measurement
        self._base_key: tuple = (-math.inf,)
        self._set(base)

    def _set(self, snap) -> None:
        self.ekf.x, self.ekf.P, self.aux = snap

    def reset(self, position: float | None = None, position_stddev: float = 1.0,
              speed: float = 0.0, speed_stddev: float = 1.0, stamp: float | None = None) -> None:
        """Operator reset: forget everything; optionally set the position (then NOMINAL).

        Measurements stamped before ``stamp`` are rejected afterwards (``too_late``).
        """
        x, P, aux = self._initial_state()
        if position is not None:
            x[0, 0], x[1, 0] = position, speed
            P[0, 0], P[1, 1] = position_stddev ** 2, speed_stddev ** 2
            aux.initialised = True
            aux.last_accepted = {"operator": stamp if stamp is not None else 0.0}
        aux.t = stamp
        self._clear((x, P, aux))
        if stamp is not None:
            self._base_key = (stamp,)

    def _transition(self, dt: float):
        """F, Q over dt (cached: the replays and the fixed sensor rates repeat the same dt)."""
        hit = self._cache.get(dt)
        if hit is not None:
            return hit
        n = self.n
        F = np.eye(n)
        F[0, 1], F[0, 2], F[1, 2] = dt, 0.5 * dt * dt, dt
        q = self.cfg.jerk_psd
        Q = np.zeros((n, n))
        dt2 = dt * dt
        Q[:3, :3] = q * np.array([[dt2 * dt2 * dt / 20, dt2 * dt2 / 8, dt2 * dt / 6],
                                  [dt2 * dt2 / 8, dt2 * dt / 3, dt2 / 2],
                                  [dt2 * dt / 6, dt2 / 2, dt]])
        for i, tau, sigma in self._gm:
            phi = math.exp(-dt / tau)
            F[i, i] = phi
            Q[i, i] = sigma * sigma * (1.0 - phi * phi)
        for i, psd in self._rw:
            Q[i, i] = psd * dt
        FT = F.T.copy()
        if len(self._cache) > 4096:
            self._cache.clear()
        self._cache[dt] = (F, FT, Q)
        return F, FT, Q

    def _predicted(self, x, P, t0: float | None, t: float):
        if t0 is None or t == t0:
            return x, P
        F, FT, Q = self._transition(t - t0)
        if t < t0:   # before the kept history: extrapolate back, uncertainty grown as forwards
            Q = self._transition(t0 - t)[2]
        # new arrays: snapshots share the old ones (ndarray.dot: the same BLAS products as @,
        # with less per-call overhead on these small matrices)
        x, P = F.dot(x), F.dot(P).dot(FT) + Q
        if self._fixgm:   # fix biases decorrelate with the distance run (F, Q above leave them alone)
            dt = abs(t - t0)
            dist = abs(float(x[1, 0])) * dt
            for i, length, tau, sigma in self._fixgm:
                phi = math.exp(-dist / length - dt / tau)
                x[i, 0] *= phi
                P[i, :] *= phi
                P[:, i] *= phi
                P[i, i] += sigma * sigma * (1.0 - phi * phi)
        return x, P

    def _predict_to(self, t: float) -> None:
        aux = self.aux
        if aux.t is None:
            aux.t = t
            return
        if t > aux.t:
            self.ekf.x, self.ekf.P = self._predicted(self.ekf.x, self.ekf.P, aux.t, t)
            aux.t = t

    # -- measurement update ----------------------------------------------------
    def _model(self, m):
        """(z, R, H row (1-D), h(x)) of a measurement at the current state."""
        cfg = self.cfg
        x = self.ekf.x[:, 0].tolist()   # plain floats: the same doubles, without numpy scalars
        h = np.zeros(self.n)
        cls = m.sensor
        if isinstance(m, PositionFix):
            h[0] = 1.0
            R = m.position_stddev ** 2
            z, hx = m.position, x[0]
            f_idx = self._fix_idx.get(cls)
            if f_idx is not None:
                h[f_idx] = 1.0
                hx = hx + x[f_idx]
                fixed = cfg.reported_fix_bias.get(cls)
                if fixed is not None:
                    R = max(R - fixed * fixed, 0.01 * R)
        else:
            k_idx = self._scale_idx.get(cls)
            o_idx = self._offset_idx.get(cls)
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
            c = cfg.creep_coefficient.get(cls)
            if c is not None:   # v (1 + c a sign v) = v + c a |v|
                sv = 1.0 if v >= 0.0 else -1.0
                h[1] += g * c * a * sv
                h[2] += g * c * (abs(v) - 0.5 * d * a * sv)
                v = v + c * a * abs(v)
            b_idx = self._bias_idx.get(cls)
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
            removed = R - (cfg.reported_scale.get(cls, 0.0) * z) ** 2 - cfg.reported_bias.get(cls, 0.0) ** 2
            R = max(removed, 0.01 * R)
        f = cfg.stddev_factor.get(cls)
        if f is not None:
            R *= f * f
        return z, R, h, hx

    def _update(self, z: float, R: float, h, hx: float, PHt, S: float) -> None:
        """Scalar EKF update (filterpy ExtendedKalmanFilter.update, Joseph form, for one row H).

        PHt = P h and S = h P h + R are those of the gate test.
        """
        # np.outer(a, b) is a[:, None] * b[None, :]: written out, without its Python wrapper
        P = self.ekf.P
        K = PHt / S
        Kc = K[:, None]
        self.ekf.x = self.ekf.x + Kc * (z - hx)
        A = self._eye - Kc * h
        self.ekf.P = A.dot(P).dot(A.T) + Kc * (K * R)

    def _apply(self, m) -> None:
        aux = self.aux = self.aux.copy()
        self._predict_to(m.stamp)
        self.applied += 1
        cls = m.sensor
        is_fix = isinstance(m, PositionFix)
        if cls in self._per_ref and is_fix and aux.fix_ref.get(cls) != m.reference_id:
            self._new_fix_bias(cls)
            aux.fix_ref = {**aux.fix_ref, cls: m.reference_id}
        if is_fix and not aux.initialised:
            self._set_position(m)
            aux.initialised = True
            return
        z, R, h, hx = self._model(m)
        PHt = self.ekf.P.dot(h)
        S = float(h.dot(PHt)) + R
        nis = (z - hx) ** 2 / S
        if cls in self.cfg.slip_sensors:
            if aux.slip_until.get(cls, -math.inf) > m.stamp:
                if nis > self._slip_gate:   # still slipping
                    aux.slip_until = {**aux.slip_until, cls: m.stamp + self.cfg.slip_holdoff}
                aux.gated = _inc(aux.gated, cls + "/slip")
                return
            if nis > self._slip_gate and self._reference_ok(m.stamp):
                aux.slip_until = {**aux.slip_until, cls: m.stamp + self.cfg.slip_holdoff}
                aux.slips += 1
                aux.gated = _inc(aux.gated, cls + "/slip")
                return
        if nis > self._gates.get(cls, self._gate):
            if is_fix:
                run = aux.fix_gated_run + 1
                if 0 < self.cfg.reacquire_count <= run and \
                        m.stamp - aux.last_fix_accepted >= self.cfg.reacquire_time:
                    self._set_position(m)       # the filter, not the fixes, is wrong: re-acquire
                    aux.reacquired += 1
                    return
                aux.fix_gated_run = run
            aux.gated = _inc(aux.gated, cls)
            return
        self._update(z, R, h, hx, PHt, S)
        if is_fix:
            aux.fix_gated_run, aux.last_fix_accepted = 0, m.stamp
        count, total = aux.nis.get(cls, (0, 0.0))
        aux.nis = {**aux.nis, cls: (count + 1, total + nis)}
        aux.accepted = _inc(aux.accepted, cls)
        aux.last_accepted = {**aux.last_accepted, cls: m.stamp}
        if not is_fix and cls not in aux.speed_sources:
            aux.speed_sources = aux.speed_sources | {cls}

    def _set_position(self, m) -> None:
        """Take the position from a fix alone (first fix, re-acquisition): s = z - e."""
        aux, cls = self.aux, m.sensor
        z, R, _, _ = self._model(m)
        x = self.ekf.x.copy()
        P = self.ekf.P.copy()
        P[0, :] = 0.0
        P[:, 0] = 0.0
        P[0, 0] = R
        x[0, 0] = z
        f_idx = self._fix_idx.get(cls)
        if f_idx is not None:
            x[0, 0] -= x[f_idx, 0]
            P[0, 0] += P[f_idx, f_idx]
            P[0, f_idx] = P[f_idx, 0] = -P[f_idx, f_idx]
        self.ekf.x, self.ekf.P = x, P
        aux.accepted = _inc(aux.accepted, cls)
        aux.last_accepted = {**aux.last_accepted, cls: m.stamp}
        aux.fix_gated_run, aux.last_fix_accepted = 0, m.stamp

    def _new_fix_bias(self, cls: str) -> None:
        """A new reference: its fix bias is independent of the previous one."""
        i = self._fix_idx[cls]
        x, P = self.ekf.x.copy(), self.ekf.P.copy()
        x[i, 0] = 0.0
        P[i, :] = 0.0
        P[:, i] = 0.0
        P[i, i] = self.cfg.fix_bias_sigma.get(cls, 0.0) ** 2
        self.ekf.x, self.ekf.P = x, P

    def _reference_ok(self, stamp: float) -> bool:
        """Another speed source (not a slip sensor) was accepted recently."""
        aux = self.aux
        return any(aux.last_accepted.get(s, -math.inf) > stamp - self.cfg.slip_reference_timeout
                   for s in aux.speed_sources if s not in self.cfg.slip_sensors)

    def add(self, m) -> None:
        """Insert a measurement at its stamp (the filter catches up when next queried).

        Raises InputRejected for NaN or non-positive stddevs (``nan``/``stddev``), a
        measurement already seen (``duplicate``) or one older than the history or the
        last reset (``too_late``).
        """
        try:
            m.validate()
            key = _order_key(m)
            newest = self._stamps[-1] if self._stamps else None
            if newest is not None and m.stamp < newest - self.cfg.history:
                raise InputRejected("too_late", f"{m.sensor} measurement {newest - m.stamp:.3f} s late "
                                    f"(history {self.cfg.history} s)")
            if key <= self._base_key:
                raise InputRejected("too_late", f"{m.sensor} measurement at {m.stamp:.6f} s is before the "
                                    "kept history (or the last reset)")
            i = bisect.bisect_left(self._keys, key)
            if i < len(self._keys) and self._keys[i] == key:
                raise InputRejected("duplicate", f"{m.sensor} measurement at {m.stamp:.6f} s seen before")
        except InputRejected as exc:
            self.rejected[exc.reason] = self.rejected.get(exc.reason, 0) + 1
            raise
        if i < len(self._keys):
            self.rollbacks += 1        # arrived after a measurement stamped later
        self._keys.insert(i, key)
        self._stamps.insert(i, m.stamp)
        self._meas.insert(i, m)
        if i < self._n_applied:
            del self._snaps[i:]
            self._n_applied = i
        if len(self._meas) - self._n_applied > 10000:   # nobody asks: keep memory bounded
            self._catch_up()

    def _catch_up(self) -> None:
        """Apply the measurements not applied yet, from the state before the first of them."""
        n = len(self._meas)
        if self._n_applied == n:
            return
        self._set(self._snaps[self._n_applied - 1] if self._n_applied else self._base)
        snaps = self._snaps
        for j in range(self._n_applied, n):
            self._apply(self._meas[j])
            snaps.append((self.ekf.x, self.ekf.P, self.aux))
        self._n_applied = n
        self._prune()

    def _prune(self, batch: int = 64) -> None:
        """Forget the measurements older than ``history``, once ``batch`` of them have aged out."""
        stamps = self._stamps
        if len(stamps) <= batch or stamps[batch - 1] >= stamps[-1] - self.cfg.history:
            return
        cut = bisect.bisect_left(stamps, stamps[-1] - self.cfg.history)
        if cut > 0:
            self._base, self._base_key = self._snaps[cut - 1], self._keys[cut - 1]
            del self._keys[:cut], self._stamps[:cut], self._meas[:cut], self._snaps[:cut]
            self._n_applied -= cut

    # -- output ----------------------------------------------------------------
    @property
    def initialised(self) -> bool:
        self._catch_up()
        return self.aux.initialised

    def _kept(self, t: float | None):
        """(x (n, 1), P, bookkeeping) after every measurement stamped <= t (all if None)."""
        self._catch_up()
        if t is None or not self._stamps or t >= self._stamps[-1]:
            return self.ekf.x, self.ekf.P, self.aux
        j = bisect.bisect_right(self._stamps, t) - 1
        return self._snaps[j] if j >= 0 else self._base

    def state(self, t: float | None = None):
        """(x (n,), P (n, n), bookkeeping) valid at t: after every measurement stamped <= t.

        Default: after all measurements. Before the kept history the oldest state is
        extrapolated back.
        """
        x, P, aux = self._kept(t)
        if t is not None:
            x, P = self._predicted(x, P, aux.t, t)
        return x[:, 0], P, aux

    def estimate(self, t: float) -> Estimate:
        """State at time t [s] (does not change the filter).

        Forward from the kept state only [s, v, a] and their variances are needed:
        they are predicted from the 3x3 kinematic block (the error states do not
        enter F's first three rows), which is what ``state(t)`` gives for them,
        at a fraction of the cost of propagating all of P at 200 Hz.
        """
        xk, Pk, aux = self._kept(t)
        if aux.t is None or t < aux.t:
            x, P, aux = self.state(t)
            s, v, a, var_s, var_v = x[0], x[1], x[2], P[0, 0], P[1, 1]
            x_err = x.tolist()
        else:
            # plain floats: numpy's per-call overhead dominates 3x3 arithmetic; the floats
            # of a kept state are taken once (the 200 Hz grid asks the same state many times)
            c = self._est_cache
            if c[0] is not xk or c[1] is not Pk:
                c = self._est_cache = (xk, Pk, xk[:, 0].tolist(), Pk[:3, :3].tolist())
            x_err = c[2]
            (p00, p01, p02), (_, p11, p12), (_, _, p22) = c[3]
            x0, x1, a = x_err[0], x_err[1], x_err[2]
            dt = t - aux.t
            h = 0.5 * dt * dt
            q, dt2 = self.cfg.jerk_psd, dt * dt
            s, v = x0 + x1 * dt + a * h, x1 + a * dt
            var_s = (p00 + 2 * dt * p01 + 2 * h * p02 + dt2 * p11 + 2 * dt * h * p12 + h * h * p22
                     + q * dt2 * dt2 * dt / 20)
            var_v = p11 + 2 * dt * p12 + dt2 * p22 + q * dt2 * dt / 3
            if self._gm:
                x_err = list(x_err)
                for i, tau, _ in self._gm:
                    x_err[i] *= math.exp(-dt / tau)
        sd_s, sd_v = math.sqrt(max(var_s, 0.0)), math.sqrt(max(var_v, 0.0))
        scales = {name: x_err[i] + (x_err[o] if o is not None else 0.0) for name, i, o in self._scale_terms}
        biases = {name: x_err[i] for name, i in self._bias_idx.items()}
        if not aux.initialised:
            return Estimate(t, math.nan, float(v), float(a), math.inf, sd_v, -math.inf, math.inf,
                            self.cfg.confidence, MODE_INITIALISING, scales, biases)
        half = self._z * sd_s
        return Estimate(t, float(s), float(v), float(a), sd_s, sd_v, float(s) - half,
                        float(s) + half, self.cfg.confidence, self._mode(aux, t, sd_s), scales, biases)

    def _mode(self, aux: _Aux, t: float, position_stddev: float) -> int:
        if not aux.initialised:
            return MODE_INITIALISING
        if position_stddev > self.cfg.lost_stddev:
            return MODE_LOST
        for sensor, timeout in self.cfg.timeouts.items():
            if t - aux.last_accepted.get(sensor, -math.inf) > timeout:
                return MODE_DEGRADED
        return MODE_NOMINAL

    def mode(self, t: float, position_stddev: float) -> int:
        self._catch_up()
        return self._mode(self.aux, t, position_stddev)

    def counters(self) -> dict[str, dict]:
        self._catch_up()
        aux = self.aux
        return {"accepted": dict(aux.accepted), "gated": dict(aux.gated),
                "rejected": dict(self.rejected), "slips": {"episodes": aux.slips},
                "nis_mean": {k: total / count for k, (count, total) in aux.nis.items() if count},
                "position": {"reacquired": aux.reacquired},
                "rollbacks": {"late": self.rollbacks, "updates": self.applied}}

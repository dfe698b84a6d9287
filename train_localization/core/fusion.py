"""Along-track fusion: an extended Kalman filter (filterpy) with exact out-of-order handling.

State x = [s, v, a, k_1 .. k_n]: chainage of the front [m], speed [m/s], acceleration
[m/s^2] and one scale error per incremental/speed sensor class listed in
``scale_sensors`` (wheel diameter error, Doppler scale): such a sensor measures
(1 + k) times the true quantity.

Why an EKF (filterpy.kalman.ExtendedKalmanFilter) and not a UKF: the only
nonlinearity is the product of a scale state and the speed, which an EKF
linearises with negligible error at the accuracy of the sensors, and the filter has
to re-run its history whenever a measurement arrives late, where the EKF's single
Jacobian product per update is several times cheaper than 2n+1 sigma points.

Measurement models
  PositionFix        z = s                                   (balise, LRL, INPO, mm-wave, axle counter)
  SpeedMeasurement   z = (1 + k_sensor) v                    (Doppler)
  DistanceIncrement  z = distance/duration = (1 + k_sensor)(v - a d/2)
                     mean speed over the interval of length d ending at the stamp
Process model: constant acceleration driven by white jerk (spectral density
``jerk_psd``), scale errors as slow random walks.

Late and out-of-order measurements: every measurement is kept for ``history`` s with
a checkpoint of the filter after it; one that arrives late is inserted at its
stamp, the filter is restored to the checkpoint before it and the later ones are
re-applied. The result equals in-order processing (ties are ordered by a key built
from the measurement itself, not by arrival).

Gating: a measurement whose normalised innovation squared exceeds the chi-square
quantile ``gate_probability`` (1 dof) is rejected and counted. Slip/slide: a wheel
(``slip_sensors``) increment that disagrees with the filter while another speed
source was accepted in the last ``slip_reference_timeout`` s marks a slip/slide,
and that sensor is excluded for ``slip_holdoff`` s after the last disagreement.
"""
from __future__ import annotations

import bisect
import copy
import math
from dataclasses import dataclass, field

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from scipy.stats import chi2, norm

from .measurements import DistanceIncrement, PositionFix, SpeedMeasurement
from .signals import InputRejected

MODE_INITIALISING, MODE_NOMINAL, MODE_DEGRADED, MODE_LOST = 0, 1, 2, 3


@dataclass
class FusionConfig:
    """Tuning of the filter; every field is a parameter of the fusion node."""

    track_id: str = ""
    scale_sensors: tuple[str, ...] = ("wheel", "doppler")
    slip_sensors: tuple[str, ...] = ("wheel",)
    jerk_psd: float = 0.5              # white-jerk spectral density [m^2/s^5]
    scale_psd: float = 1e-8            # random walk of the scale errors [1/s]
    initial_speed_stddev: float = 1.0  # [m/s]
    initial_accel_stddev: float = 0.5  # [m/s^2]
    initial_scale_stddev: float = 0.01  # wheel wear up to 1 %, Doppler ~1 %
    gate_probability: float = 0.9999   # chi-square gate (1 dof)
    slip_holdoff: float = 2.0          # [s]
    slip_reference_timeout: float = 1.0  # [s]
    history: float = 2.0               # how late a measurement may be [s]
    confidence: float = 0.999          # probability of [position_min, position_max]
    lost_stddev: float = 100.0         # position 1-sigma above which the mode is LOST [m]
    timeouts: dict[str, float] = field(default_factory=dict)  # sensor class -> timeout [s]


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


def _order_key(m) -> tuple:
    """Deterministic total order of measurements: by stamp, then by content."""
    if isinstance(m, PositionFix):
        body = (0, m.position, m.position_stddev)
    elif isinstance(m, SpeedMeasurement):
        body = (1, m.speed, m.speed_stddev)
    else:
        body = (2, m.distance, m.duration)
    return (m.stamp, m.sensor, m.unit_id) + body


@dataclass
class _Aux:
    """Filter bookkeeping that rolls back together with x and P."""

    initialised: bool = False
    t: float | None = None              # time of x, P [s]
    last_accepted: dict[str, float] = field(default_factory=dict)
    slip_until: dict[str, float] = field(default_factory=dict)
    accepted: dict[str, int] = field(default_factory=dict)
    gated: dict[str, int] = field(default_factory=dict)
    slips: int = 0
    speed_sources: set = field(default_factory=set)  # sensor classes that gave speed/distance
    nis: dict[str, list] = field(default_factory=dict)  # sensor -> [count, sum of NIS]


class TrainFilter:
    """Feed measurements with ``add`` (any order within ``history``), query with ``estimate``."""

    def __init__(self, config: FusionConfig | None = None):
        self.cfg = config or FusionConfig()
        self.n = 3 + len(self.cfg.scale_sensors)
        self._scale_idx = {name: 3 + i for i, name in enumerate(self.cfg.scale_sensors)}
        self.ekf = ExtendedKalmanFilter(dim_x=self.n, dim_z=1)
        self._gate = float(chi2.ppf(self.cfg.gate_probability, 1))
        self._z = float(norm.ppf(0.5 + self.cfg.confidence / 2.0))
        self._reset_state()
        self._keys: list[tuple] = []
        self._meas: list = []
        self._checkpoints: list[tuple] = []   # state after each measurement
        self._base = self._snapshot()         # state before the first kept measurement
        self.rejected: dict[str, int] = {}
        self.rollbacks = 0

    # -- state handling --------------------------------------------------------
    def _reset_state(self):
        self.ekf.x = np.zeros((self.n, 1))
        P = np.zeros((self.n, self.n))
        P[1, 1] = self.cfg.initial_speed_stddev ** 2
        P[2, 2] = self.cfg.initial_accel_stddev ** 2
        for i in range(3, self.n):
            P[i, i] = self.cfg.initial_scale_stddev ** 2
        P[0, 0] = 1.0  # relative position until the first fix
        self.ekf.P = P
        self.aux = _Aux()

    def _snapshot(self):
        return (self.ekf.x.copy(), self.ekf.P.copy(), copy.deepcopy(self.aux))

    def _restore(self, snap):
        self.ekf.x, self.ekf.P, self.aux = snap[0].copy(), snap[1].copy(), copy.deepcopy(snap[2])

    def reset(self, position: float | None = None, position_stddev: float = 1.0,
              speed: float = 0.0, speed_stddev: float = 1.0, stamp: float | None = None) -> None:
        """Operator reset: forget everything; optionally set the position (then NOMINAL)."""
        self._reset_state()
        self._keys, self._meas, self._checkpoints = [], [], []
        if position is not None:
            self.ekf.x[0, 0], self.ekf.x[1, 0] = position, speed
            self.ekf.P[0, 0], self.ekf.P[1, 1] = position_stddev ** 2, speed_stddev ** 2
            self.aux.initialised = True
            self.aux.t = stamp
            self.aux.last_accepted["operator"] = stamp if stamp is not None else 0.0
        self._base = self._snapshot()

    @staticmethod
    def _transition(dt: float, n: int, jerk_psd: float, scale_psd: float):
        F = np.eye(n)
        F[0, 1], F[0, 2], F[1, 2] = dt, 0.5 * dt * dt, dt
        q = jerk_psd
        Q = np.zeros((n, n))
        Q[:3, :3] = q * np.array([[dt ** 5 / 20, dt ** 4 / 8, dt ** 3 / 6],
                                  [dt ** 4 / 8, dt ** 3 / 3, dt ** 2 / 2],
                                  [dt ** 3 / 6, dt ** 2 / 2, dt]])
        for i in range(3, n):
            Q[i, i] = scale_psd * dt
        return F, Q

    def _predict_to(self, t: float) -> None:
        if self.aux.t is None:
            self.aux.t = t
            return
        dt = t - self.aux.t
        if dt > 0:
            F, Q = self._transition(dt, self.n, self.cfg.jerk_psd, self.cfg.scale_psd)
            self.ekf.F, self.ekf.Q = F, Q
            self.ekf.predict()
            self.aux.t = t

    # -- measurement update ----------------------------------------------------
    def _model(self, m):
        """(z, R, H row, h(x)) of a measurement at the current state."""
        x = self.ekf.x[:, 0]
        H = np.zeros((1, self.n))
        if isinstance(m, PositionFix):
            H[0, 0] = 1.0
            return m.position, m.position_stddev ** 2, H, x[0]
        k_idx = self._scale_idx.get(m.sensor)
        k = x[k_idx] if k_idx is not None else 0.0
        if isinstance(m, SpeedMeasurement):
            H[0, 1] = 1.0 + k
            if k_idx is not None:
                H[0, k_idx] = x[1]
            return m.speed, m.speed_stddev ** 2, H, (1.0 + k) * x[1]
        d = m.duration
        mean_v = x[1] - 0.5 * d * x[2]
        H[0, 1], H[0, 2] = 1.0 + k, -0.5 * d * (1.0 + k)
        if k_idx is not None:
            H[0, k_idx] = mean_v
        return m.distance / d, m.speed_stddev ** 2, H, (1.0 + k) * mean_v

    def _apply(self, m) -> None:
        aux = self.aux
        self._predict_to(m.stamp)
        cls = m.sensor
        if isinstance(m, PositionFix) and not aux.initialised:
            self.ekf.x[0, 0] = m.position
            self.ekf.P[0, :] = 0.0
            self.ekf.P[:, 0] = 0.0
            self.ekf.P[0, 0] = m.position_stddev ** 2
            aux.initialised = True
            self._count(aux.accepted, cls)
            aux.last_accepted[cls] = m.stamp
            return
        if cls in self.cfg.slip_sensors and aux.slip_until.get(cls, -math.inf) > m.stamp:
            z, R, H, hx = self._model(m)
            if (z - hx) ** 2 / (H @ self.ekf.P @ H.T + R)[0, 0] > self._gate:
                aux.slip_until[cls] = m.stamp + self.cfg.slip_holdoff  # still slipping
            self._count(aux.gated, cls + "/slip")
            return
        z, R, H, hx = self._model(m)
        S = (H @ self.ekf.P @ H.T)[0, 0] + R
        nis = (z - hx) ** 2 / S
        if nis > self._gate:
            other_speed_ok = any(t > m.stamp - self.cfg.slip_reference_timeout
                                 for s, t in aux.last_accepted.items()
                                 if s not in self.cfg.slip_sensors and s not in ("operator",)
                                 and s in aux.speed_sources)
            if cls in self.cfg.slip_sensors and other_speed_ok:
                aux.slip_until[cls] = m.stamp + self.cfg.slip_holdoff
                aux.slips += 1
                self._count(aux.gated, cls + "/slip")
            else:
                self._count(aux.gated, cls)
            return
        self.ekf.update(np.array([[z]]), lambda _x, H=H: H, lambda _x, hx=hx: np.array([[hx]]),
                        R=np.array([[R]]))
        stats = aux.nis.setdefault(cls, [0, 0.0])
        stats[0] += 1
        stats[1] += nis
        self._count(aux.accepted, cls)
        aux.last_accepted[cls] = m.stamp
        if not isinstance(m, PositionFix):
            aux.speed_sources.add(cls)

    @staticmethod
    def _count(counter: dict, key: str) -> None:
        counter[key] = counter.get(key, 0) + 1

    def add(self, m) -> None:
        """Insert a measurement at its stamp and update the filter.

        Raises InputRejected for NaN or non-positive stddevs (``nan``/``stddev``), a
        measurement already seen (``duplicate``) or one older than the history
        (``too_late``).
        """
        try:
            m.validate()
            key = _order_key(m)
            newest = self._keys[-1][0] if self._keys else None
            if newest is not None and m.stamp < newest - self.cfg.history:
                raise InputRejected("too_late", f"{m.sensor} measurement {newest - m.stamp:.3f} s late "
                                    f"(history {self.cfg.history} s)")
            i = bisect.bisect_left(self._keys, key)
            if i < len(self._keys) and self._keys[i] == key:
                raise InputRejected("duplicate", f"{m.sensor} measurement at {m.stamp:.6f} s seen before")
            if self.aux.t is not None and not self._keys and m.stamp < self.aux.t:
                raise InputRejected("too_late", f"{m.sensor} measurement before the filter start")
        except InputRejected as exc:
            self.rejected[exc.reason] = self.rejected.get(exc.reason, 0) + 1
            raise
        self._keys.insert(i, key)
        self._meas.insert(i, m)
        if i < len(self._keys) - 1:
            self.rollbacks += 1
            self._restore(self._checkpoints[i - 1] if i > 0 else self._base)
            del self._checkpoints[i:]
            for j in range(i, len(self._meas)):
                self._apply(self._meas[j])
                self._checkpoints.append(self._snapshot())
        else:
            self._apply(m)
            self._checkpoints.append(self._snapshot())
        self._prune()

    def _prune(self) -> None:
        newest = self._keys[-1][0]
        cut = bisect.bisect_left(self._keys, (newest - self.cfg.history,))
        if cut > 0:
            self._base = self._checkpoints[cut - 1]
            del self._keys[:cut], self._meas[:cut], self._checkpoints[:cut]

    # -- output ----------------------------------------------------------------
    @property
    def initialised(self) -> bool:
        return self.aux.initialised

    def estimate(self, t: float) -> Estimate:
        """State predicted to time t [s] (does not change the filter)."""
        x, P = self.ekf.x[:, 0].copy(), self.ekf.P.copy()
        if self.aux.t is not None and t > self.aux.t:
            F, Q = self._transition(t - self.aux.t, self.n, self.cfg.jerk_psd, self.cfg.scale_psd)
            x, P = F @ x, F @ P @ F.T + Q
        sd_s, sd_v = math.sqrt(max(P[0, 0], 0.0)), math.sqrt(max(P[1, 1], 0.0))
        mode = self.mode(t, sd_s)
        scales = {name: float(x[i]) for name, i in self._scale_idx.items()}
        if not self.aux.initialised:
            return Estimate(t, math.nan, float(x[1]), float(x[2]), math.inf, sd_v, -math.inf, math.inf,
                            self.cfg.confidence, MODE_INITIALISING, scales)
        half = self._z * sd_s
        return Estimate(t, float(x[0]), float(x[1]), float(x[2]), sd_s, sd_v, float(x[0]) - half,
                        float(x[0]) + half, self.cfg.confidence, mode, scales)

    def mode(self, t: float, position_stddev: float) -> int:
        if not self.aux.initialised:
            return MODE_INITIALISING
        if position_stddev > self.cfg.lost_stddev:
            return MODE_LOST
        for sensor, timeout in self.cfg.timeouts.items():
            if t - self.aux.last_accepted.get(sensor, -math.inf) > timeout:
                return MODE_DEGRADED
        return MODE_NOMINAL

    def counters(self) -> dict[str, dict]:
        return {"accepted": dict(self.aux.accepted), "gated": dict(self.aux.gated),
                "rejected": dict(self.rejected), "slips": {"episodes": self.aux.slips},
                "nis_mean": {k: v[1] / v[0] for k, v in self.aux.nis.items() if v[0]}}

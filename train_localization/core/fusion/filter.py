"""The along-track filter: an extended Kalman filter (filterpy) with exact out-of-order
handling and a fault policy that never leaves it confidently wrong.

State, process and measurement models: layout.py and models.py, built from the error
models of the configured sensors (config.py). Late data: history.py; the bookkeeping that
rolls back with the state: bookkeeping.py. The update is our
own scalar form of filterpy's ``ExtendedKalmanFilter.update`` (Joseph form; a test
checks that they agree), because the rollback re-applies every measurement of the
last ~200 ms many times. Why an EKF and not a UKF: the only nonlinearity is the
product of a scale or bias state and the speed (scale errors < 2 %, so the
second-order term is < 2 % of the first-order one), and a Jacobian row per scalar
update is several times cheaper than 2n+1 sigma points in the rollback.

Fault policy (the rule of GNSS integrity monitoring: no hazardously misleading
information; the filter may say it does not know, never be confidently wrong):
  gate        a measurement whose normalised innovation squared (NIS) exceeds the
              chi-square quantile of its gate probability is rejected and counted.
The other policies, each in the docstring of its own module, run by the filter as
components (pipeline.py ``STAGES`` is the order in which they act on a measurement):
  episodes.py      episodes (slip, slide, scale-fault episodes of the relative sensors)
  plausibility.py  plausibility (an error state beyond its prior: re-learn)
  solutions.py     separation (each relative sensor's own solution)
  lone.py          lone source (the solution without a lone speed source)
  fixes.py         consistency, unexplained, recalibration, revisit (absolute fixes)
  arbitration.py   arbitration, merge (the excluded sensor's view, suspension)
  motion_views.py  blind, coasting (the motion model's own hypotheses)
  interval.py      the modes and the published interval, widened to cover them all
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from ..measurements import MAX_SPEED, YawRate
from ..signals import InputRejected
from ..sensors import faults
from .bookkeeping import Bookkeeping, is_coasting, speed_excluded
from .config import FusionConfig
from .history import History, order_key
from .layout import StateLayout
from .limits import Limits
from . import impact
from .models import ProcessModel, kinematic_covariance, kinematics, measurement
from .mode import Mode
from . import pipeline
# the policies (components)
from .arbitration import Arbitration
from .bank import FaultBank
from .episodes import Episodes, Lookback
from .fixes import Fixes
from .interval import Interval
from .lone import LoneSource
from .motion_views import MotionViews
from .plausibility import Plausibility
from .solutions import Solutions


MODE_INITIALISING, MODE_NOMINAL, MODE_DEGRADED, MODE_LOST = Mode


@dataclass(slots=True)
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
    scales: dict[str, float]   # shared by the estimates of one filter state: read only
    biases: dict[str, float] = field(default_factory=dict)


class CountingEKF(ExtendedKalmanFilter):
    """filterpy's EKF that counts the replacements of its covariance (``revision``): a policy
    that replaced it makes the pipeline compute the innovation again (pipeline.py)."""

    revision = 0

    @property
    def P(self) -> np.ndarray:
        return self._P

    @P.setter
    def P(self, value: np.ndarray) -> None:
        self._P = value
        self.revision += 1


class EstimateCache(NamedTuple):
    """What the estimates between two measurements share: read once per kept filter state."""

    x: np.ndarray | None        # the kept state (n, 1) it was read from
    P: np.ndarray | None        # its covariance (n, n)
    x_list: list | None         # x as plain floats
    kinematic: tuple | None     # the 3x3 kinematic block of P (models.kinematic_covariance)
    error_states: tuple | None  # ({sensor: scale error [1]}, {sensor: bias [m/s]})
    bank: object                # the fault cover prepared for the interval (impact.prepared)

    def holds(self, x, P) -> bool:
        """Whether this cache was read from the kept state (x, P) (the same arrays)."""
        return self.x is x and self.P is P


NO_CACHE = EstimateCache(None, None, None, None, None, None)


class TrainFilter:
    """Feed measurements with ``add`` (any order within ``history``), query with ``estimate``."""

    def __init__(self, config: FusionConfig | None = None):
        cfg = self.cfg = config or FusionConfig()
        self.models = cfg.models
        self.layout = StateLayout(self.models, cfg.scale_psd, cfg.bias_psd)
        self.n = self.layout.n
        self.process = ProcessModel(self.layout, cfg.jerk_psd)
        self.ekf = CountingEKF(dim_x=self.n, dim_z=1)
        self.limits = Limits.of(cfg, self.layout)
        self.timeouts = {s: m.timeout for s, m in self.models.items() if math.isfinite(m.timeout)}
        self.fault_input: impact.FaultInput | None = None   # of the reading being applied
        self._est_cache = NO_CACHE
        # of the reading being applied: (Kalman gain, innovation) of the last update, the filter's own
        # solution before it (separation.py), and for a fix the time since its sensor's previous one [s]
        self.last_update = (np.zeros(self.n), 0.0)
        self.before = None
        self.since_fix = math.inf
        self._eye = np.eye(self.n)
        self.rejected: dict[str, int] = {}
        self.applied = 0          # measurement updates run, replays included
        # the policies (one component each; they read and change the filter's state through it)
        self.bank = FaultBank(self)   # not a policy: the fault hypotheses' bank, which follows the state
        self.lone = LoneSource(self)
        self.solutions = Solutions(self)
        self.interval = Interval(self)
        self.motion = MotionViews(self)
        self.arbitration = Arbitration(self)
        self.episodes = Episodes(self)
        self.plausibility = Plausibility(self)
        self.fixes = Fixes(self)
        self._clear(self._initial_state())

    # -- state handling --------------------------------------------------------
    def _initial_state(self):
        P = self.layout.prior_covariance(self.cfg.initial_speed_stddev, self.cfg.initial_accel_stddev)
        return np.zeros((self.n, 1)), P, Bookkeeping()

    def _clear(self, base) -> None:
        self.hist = History(self.cfg.history, base)
        self._set(base)

    def _set(self, snap) -> None:
        self.ekf.x, self.ekf.P, self.aux = snap

    @property
    def rollbacks(self) -> int:
        return self.hist.rollbacks

    def reset(self, position: float | None = None, position_stddev: float = 1.0,
              speed: float = 0.0, speed_stddev: float = 1.0, stamp: float | None = None) -> None:
        """Operator reset: forget everything; optionally set the position (then NOMINAL).

        Measurements stamped before ``stamp`` are rejected afterwards (``too_late``).
        """
        x, P, aux = self._initial_state()
        aux.t = stamp
        self._set((x, P, aux))
        if position is not None:   # located as by a fix (Fixes.operator_position), the solutions seeded from it
            x[0, 0], x[1, 0] = position, speed
            P[0, 0], P[1, 1] = position_stddev ** 2, speed_stddev ** 2
            self.fixes.operator_position(stamp if stamp is not None else 0.0)
            self.solutions.seed_subs(stamp if stamp is not None else 0.0)
        self._clear((x, P, aux))
        if stamp is not None:
            self.hist.base_key = (stamp,)

    def predict_to(self, t: float) -> None:
        aux = self.aux
        if aux.t is None:
            aux.t = t
            return
        if t > aux.t:
            s0 = self.ekf.x[0, 0]
            self.bank.predicted(self.process.transition(t - aux.t)[0])
            self.ekf.x, self.ekf.P = self.process.predict(self.ekf.x, self.ekf.P, aux.t, t)
            aux.odometer += float(self.ekf.x[0, 0] - s0)
            aux.t = t
            self.bank.persistent_onset(t)
            self.lone.ran(float(self.ekf.x[0, 0] - s0))

    # -- measurement update ----------------------------------------------------
    def update(self, z: float, R: float, h, hx: float, PHt, S: float) -> None:
        """Scalar EKF update (filterpy ExtendedKalmanFilter.update, Joseph form, for one row H).

        PHt = P h and S = h P h + R are those of the gate test.
        """
        P = self.ekf.P
        K = PHt / S
        self.last_update = (K, z - hx)
        self.bank.updated(self.fault_input, h, K, z - hx, S)
        Kc = K[:, None]
        self.ekf.x = self.ekf.x + Kc * (z - hx)
        A = self._eye - Kc * h
        self.ekf.P = A.dot(P).dot(A.T) + Kc * (K * R)

    def _apply(self, m) -> None:
        pipeline.apply_reading(self, m)
        if self.aux.initialised:
            for key, sm in self.limits.sensor_subs.get(m.sensor, ()):
                self.solutions.sub_reading(m, key, sm)

    def fault_input_of(self, m, is_fix: bool) -> impact.FaultInput | None:
        """What reading ``m``'s own fault would add (impact.py), and whether another speed source in
        use checks it (then its own innovations test the fault too); None without a fault cover."""
        cls = m.sensor
        if is_fix:   # a fix's own offset per unit is its 1-sigma; the dead reckoning checks it
            return impact.FaultInput(cls, m.position_stddev if cls in self.limits.offset_bounds else 0.0, True,
                                     independent=cls not in self.layout.fix)
        if not (self.limits.persistent_bounds or self.limits.transient_bounds) or cls not in self.layout.relative:
            return None   # an acceleration carries none of the bank's faults; it tests them
        checkers = frozenset(self.in_use(m.stamp, but=cls)) | self.accelerometers_in_use(m.stamp)
        # a sensor whose common cause acts through adhesion (a wheel's slips) carries it only while the
        # train is driven or braked, and within its longest episode after (asked only where a group
        # is monitored: the flag touches group rows alone)
        model = self.models[cls]
        in_groups = not self.limits.group_members or not faults.ADHESION & set(model.faults) or (
            abs(float(self.ekf.x[2, 0])) >= self.cfg.slip_min_drive
            or m.stamp - self.aux.last_drive <= model.fault_duration_max)
        return impact.FaultInput(cls, m.distance / m.duration if hasattr(m, "distance") else m.speed,   # in its units
                                 bool(checkers), checkers, in_groups, relative=True)

    def measurement_of(self, m):
        """(z, R, H row, h(x)) of a measurement at the current state (models.measurement), with
        the time since its sensor's previous accepted fix (a fix's persistent error)."""
        since = m.stamp - self.aux.last_accepted.get(m.sensor, -math.inf)
        return measurement(self.layout, self.ekf.x, m, since)

    def innovation(self, m):
        """(z, R, H row, h(x), P H, innovation variance S) of a measurement at the current state."""
        z, R, h, hx = self.measurement_of(m)
        PHt = self.ekf.P.dot(h)
        return z, R, h, hx, PHt, float(h.dot(PHt)) + R

    # -- fault policy ----------------------------------------------------------

    def in_use(self, stamp: float, but: str | None = None) -> list[str]:
        """The speed sources in use at ``stamp`` [s]: accepted within ``slip_reference_timeout`` s
        and not excluded (in an episode, or suspended since), ``but`` left out."""
        aux, recent = self.aux, stamp - self.cfg.slip_reference_timeout
        return [s for s in aux.speed_sources if s != but and not speed_excluded(aux, s, stamp)
                and aux.last_accepted.get(s, -math.inf) > recent]

    def accelerometers_in_use(self, stamp: float) -> frozenset[str]:
        """The accelerometers accepted within ``slip_reference_timeout`` s of ``stamp`` [s]. They
        check a speed source's readings as another speed source does: a scale fault's step or ramp
        shows as a change of speed that the measured acceleration does not explain (beyond its
        bias state, which the fault bank's linear algebra carries)."""
        recent = stamp - self.cfg.slip_reference_timeout
        return frozenset(s for s in self.layout.accelerometers
                         if self.aux.last_accepted.get(s, -math.inf) > recent)

    def unseen_share(self, cls: str, stamp: float, speed: float, S: float) -> float:
        """The share [0, 1] of a transient fault of ``cls``'s bound (``slip_ratio_max`` x its reading's
        ``speed`` [m/s]) that the slip tests let pass at this reading (S: its innovation variance
        [m^2/s^2]). Another speed source in use checks it: up to the gate's radius of a fault that
        lasts through the n readings of the accumulated test's window (``views.windowed``),
        where it shows at sqrt(n) times its size in one reading's 1-sigma. Another one excluded as
        an undecided alternative reads beside it: the disagreement with its last reading (within
        ``slip_reference_timeout`` s) and that gate's radius. Else nothing but the motion model
        sees it, against which a slip that has begun is a speed: all of it. None where the train
        has not been driven or braked (``slip_min_drive``) within the sensor's longest episode."""
        bound = self.limits.transient_bounds[cls] * abs(speed)
        if bound <= 0.0 or stamp - self.aux.last_drive > self.models[cls].fault_duration_max:
            return 0.0
        if self.in_use(stamp, but=cls):
            n = max(len(self.aux.slip_window.get(cls, ())), 1)
            return min(1.0, math.sqrt(self.limits.slip_gate * S / n) / bound)
        recent = stamp - self.cfg.slip_reference_timeout
        beside = [r for c, r in self.aux.view_speeds.items() if c != cls and c in self.aux.relative_alternatives
                  and r.stamp > recent]
        if beside:
            return min(1.0, min(abs(abs(speed) - abs(r.speed)) + math.sqrt(self.limits.slip_gate * (S + r.var))
                                for r in beside) / bound)
        return 1.0

    def reference_ok(self, m) -> bool:
        """Another speed source is in use (``in_use``)."""
        return bool(self.in_use(m.stamp, but=m.sensor))

    def agreement_reference(self, m, S: float) -> bool:
        """Whether the filter's speed rests on more than ``m.sensor`` and the motion model:
        another speed source accepted within ``slip_reference_timeout`` s and not itself in
        an episode, or a speed known at least as well as the measurement's own noise (a
        stream of fixes). Only then can an excluded sensor be seen to agree again; the
        motion model alone, its speed uncertainty growing, would let a faulty sensor back in.
        S: the measurement's innovation variance (filter part + its own noise). While the filter
        coasts between excluded sources, its speed is theirs: no reference."""
        if is_coasting(self.aux):
            return self.reference_ok(m)
        return self.reference_ok(m) or float(self.ekf.P[1, 1]) <= 0.5 * S

    # -- input -----------------------------------------------------------------
    def add(self, m) -> None:
        """Insert a measurement at its stamp (the filter catches up when next queried).

        The measurement has passed admission (admission.py, run by FusionRunner.add); the
        history raises InputRejected for one already seen (``duplicate``) or one older than
        the history or the last reset (``too_late``). A turn rate (YawRate) tells which track,
        not where along it: refused ``not_used`` (the track selection on a network takes it,
        core/network/hypotheses.py).
        """
        if isinstance(m, YawRate):
            self.rejected["not_used"] = self.rejected.get("not_used", 0) + 1
            raise InputRejected("not_used", f"{m.sensor}: a turn rate serves the track selection on a network; "
                                            "along one track it is not used")
        try:
            self.hist.insert(m)
        except InputRejected as exc:
            self.rejected[exc.reason] = self.rejected.get(exc.reason, 0) + 1
            raise
        if self.hist.pending() > 10000:   # nobody asks: keep memory bounded
            self._catch_up()

    def _catch_up(self) -> None:
        """Apply the measurements not applied yet, from the state before the first of them."""
        hist = self.hist
        n = len(hist.meas)
        if hist.n_applied == n:
            return
        j = hist.n_applied
        self._set(hist.snapshot_before(j))
        while j < n:
            m = hist.meas[j]
            try:
                if hist.keys[j] in hist.excluded:
                    pipeline.apply_excluded(self, m, hist.excluded[hist.keys[j]][1])
                else:
                    self._apply(m)
            except Lookback as back:
                i = j
                while i > 0 and hist.stamps[i - 1] >= back.since:
                    i -= 1
                hist.drop_states(i)
                hist.exclude(i, j, back.sensor, back.shown)
                self._set(hist.snapshot_before(i))
                j = i
                continue
            hist.snaps.append((self.ekf.x, self.ekf.P, self.aux))
            hist.n_applied = j = j + 1
        hist.prune()

    # -- output ----------------------------------------------------------------
    @property
    def initialised(self) -> bool:
        self._catch_up()
        return self.aux.initialised

    def _kept(self, t: float | None):
        """(x (n, 1), P, bookkeeping) after every measurement stamped <= t (all if None)."""
        self._catch_up()
        stamps = self.hist.stamps
        if t is None or not stamps or t >= stamps[-1]:
            return self.ekf.x, self.ekf.P, self.aux
        return self.hist.state_at(t)

    def state(self, t: float | None = None):
        """(x (n,), P (n, n), bookkeeping) valid at t: after every measurement stamped <= t.

        Default: after all measurements. Before the kept history the oldest state is
        extrapolated back.
        """
        x, P, aux = self._kept(t)
        if t is not None:
            x, P = self.process.predict(x, P, aux.t, t)
        return x[:, 0], P, aux

    def estimate(self, t: float) -> Estimate:
        """State at time t [s] (does not change the filter).

        Forward from the kept state only [s, v, a] and their variances are needed: they are
        predicted from the 3x3 kinematic block (the error states do not enter F's first
        three rows), at a fraction of the cost of propagating all of P at 200 Hz.
        """
        xk, Pk, aux = self._kept(t)
        if aux.t is None or t < aux.t:
            x, P, aux = self.state(t)
            s, v, a, var_s, var_v = x[0], x[1], x[2], P[0, 0], P[1, 1]
            scales, biases = self._error_states(x.tolist())
        else:
            # plain floats: numpy's per-call overhead dominates 3x3 arithmetic; the error states
            # are read once per filter state (the estimates between two measurements share them)
            c = self._est_cache
            if not c.holds(xk, Pk):
                x_err = xk[:, 0].tolist()
                c = self._est_cache = EstimateCache(xk, Pk, x_err, kinematic_covariance(Pk), self._error_states(x_err),
                                                    impact.prepared(aux.impacts, self.limits.z))
            x_err = c.x_list
            dt = t - aux.t
            s, v, a, var_s, var_v = kinematics(x_err[0], x_err[1], x_err[2], c.kinematic, dt, self.cfg.jerk_psd)
            scales, biases = c.error_states
            if self.layout.gauss_markov:
                x_err = list(x_err)
                for i, tau, _ in self.layout.gauss_markov:
                    x_err[i] *= math.exp(-dt / tau)
                scales, biases = self._error_states(x_err)
        sd_s, sd_v = math.sqrt(max(var_s, 0.0)), math.sqrt(max(var_v, 0.0))
        if not all(map(math.isfinite, (s, v, a, sd_s, sd_v))) or abs(v) > 2.0 * MAX_SPEED:
            # input validation keeps the state finite and physical; should it ever not be, the
            # filter cannot stand behind any position
            return Estimate(t, math.nan, math.nan, math.nan, math.inf, math.inf, -math.inf, math.inf,
                            self.cfg.confidence, Mode.LOST, {}, {})
        if not aux.initialised:
            return Estimate(t, math.nan, float(v), float(a), math.inf, sd_v, -math.inf, math.inf,
                            self.cfg.confidence, Mode.INITIALISING, scales, biases)
        odometer = aux.odometer + float(s - xk[0, 0])   # the prediction from the kept state moves by speed only
        # the fault cover prepared for this kept state, if the cache holds it
        bank = self._est_cache.bank if self._est_cache.holds(xk, Pk) else aux.impacts
        lo, hi, sd_s, sd_v, mode = self.interval.cover(aux, t, s, v, var_s, var_v, sd_s, sd_v, bank, odometer)
        return Estimate(t, float(s), float(v), float(a), sd_s, sd_v, lo, hi, self.cfg.confidence,
                        mode, scales, biases)

    def _error_states(self, x_err: list) -> tuple[dict[str, float], dict[str, float]]:
        """({sensor: scale error [1]}, {sensor: bias [m/s]}) of the error states x_err."""
        scales = {name: x_err[i] + (x_err[o] if o is not None else 0.0) for name, i, o in self.layout.scale_terms}
        return scales, {name: x_err[i] for name, i in self.layout.bias.items()}

    def mode(self, t: float, position_stddev: float) -> Mode:
        self._catch_up()
        return self.interval.mode(self.aux, t, position_stddev)

    def counters(self) -> dict[str, dict]:
        self._catch_up()
        aux = self.aux
        return {"accepted": dict(aux.accepted), "gated": dict(aux.gated),
                "rejected": dict(self.rejected), "slips": {"episodes": aux.slips},
                "nis_mean": {k: seen.total / seen.count for k, seen in aux.nis.items() if seen.count},
                "integrity": dict(aux.events),
                "rollbacks": {"late": self.hist.rollbacks, "updates": self.applied}}


__all__ = ["Estimate", "Mode", "TrainFilter", "order_key", "MODE_INITIALISING", "MODE_NOMINAL",
           "MODE_DEGRADED", "MODE_LOST", "InputRejected"]

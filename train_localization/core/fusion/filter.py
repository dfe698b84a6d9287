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
components (``_apply_policy`` is the order in which they act on a measurement):
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

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from scipy.stats import chi2, norm

from ..measurements import MAX_SPEED, PositionFix, YawRate
from ..sensors import faults as fault_modes
from ..signals import InputRejected
from .bookkeeping import Bookkeeping, MovedView, NisSum, incremented, is_coasting, speed_excluded, without_key
from .config import FusionConfig, gate_probability
from .history import History, order_key
from .layout import StateLayout
from . import impact
from .models import ProcessModel, kinematic_covariance, kinematics, measurement
from .mode import Mode
from . import separation
# the policies (components)
from .arbitration import Arbitration
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


class TrainFilter:
    """Feed measurements with ``add`` (any order within ``history``), query with ``estimate``."""

    def __init__(self, config: FusionConfig | None = None):
        cfg = self.cfg = config or FusionConfig()
        self.models = cfg.models
        self.layout = StateLayout(self.models, cfg.scale_psd, cfg.bias_psd)
        self.n = self.layout.n
        self.process = ProcessModel(self.layout, cfg.jerk_psd)
        self.ekf = ExtendedKalmanFilter(dim_x=self.n, dim_z=1)
        self._gates = {s: float(chi2.ppf(gate_probability(cfg, m), 1)) for s, m in self.models.items()}
        self._slip_gate = float(chi2.ppf(cfg.slip_gate_probability, 1))
        self._consistency = float(chi2.ppf(cfg.consistency_probability, cfg.consistency_fixes)) / \
            cfg.consistency_fixes
        self._z = float(norm.ppf(0.5 + cfg.confidence / 2.0))
        # speed sources whose fault modes all end by themselves within a bounded time (a wheel)
        self._bounded = frozenset(s for s, m in self.models.items() if s in self.layout.episode_sensors
                                  and math.isfinite(m.fault_duration_max) and "scale_fault" not in m.faults)
        self.timeouts = {s: m.timeout for s, m in self.models.items() if math.isfinite(m.timeout)}
        self._subs = separation.sub_models(self.models)
        self._sensor_subs: dict[str, tuple] = {}   # sensor -> ((key, SubModel), ...) of its own solutions
        for key, sm in self._subs.items():
            self._sensor_subs[sm.sensor] = self._sensor_subs.get(sm.sensor, ()) + ((key, sm),)
        self._hypotheses = separation.hypotheses(self.models, self._subs)
        # relative sensors with a fault no test of their own can tell from motion, which may begin
        # at any time (a radar's scale fault growing slowly): while one carries the speed alone, the
        # interval covers the solution without it (``LoneSource.track``). A calibration fault (a worn
        # wheel) is a constant: the sensor's own solution with its scale opened covers it
        self._persistent = frozenset(n for n, m in self.models.items() if m.relative and
                                     (fault_modes.PERSISTENT - fault_modes.CALIBRATION) & set(m.faults))
        # relative sensors with a persistent fault of bounded size -> that bound (z x scale_fault_sigma):
        # the interval covers what such a fault, up to the size the data has not excluded, put into
        # the state (impact.py)
        self._fault_bounds = {n: self._z * m.scale_fault_sigma for n, m in self.models.items()
                              if n in self._persistent and m.scale_fault_sigma > 0.0}
        # relative sensors with a transient fault of bounded ratio (a wheel's slip or slide) that no
        # other sensor's own solution covers (separation.hypotheses: a contactless counter's does) ->
        # that ratio: the interval covers what one its tests could not see put into the state (impact.py)
        self._transient_bounds = {n: m.slip_ratio_max for n, m in self.models.items()
                                  if m.relative and m.slip_ratio_max > 0.0 and any(
                                      f"{n}/{mode}" not in self._hypotheses for mode in fault_modes.ADHESION & set(m.faults))}
        # position sensors whose runs of fixes may share an offset (faults.OFFSET) -> its bound in each
        # fix's own 1-sigma: the gate's radius (impact.py)
        self._offset_bounds = {n: math.sqrt(self._gates[n]) for n, m in self.models.items()
                               if m.measures == "position" and fault_modes.OFFSET & set(m.faults)}
        self._fault_input: impact.FaultInput | None = None   # of the reading being applied
        self._est_cache: tuple = (None, None, None, None, None, None)
        self._last_update = (np.zeros(self.n), 0.0)   # (Kalman gain, innovation) of the last update
        self._eye = np.eye(self.n)
        self.rejected: dict[str, int] = {}
        self.applied = 0          # measurement updates run, replays included
        # the policies (one component each; they read and change the filter's state through it)
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
        if position is not None:
            x[0, 0], x[1, 0] = position, speed
            P[0, 0], P[1, 1] = position_stddev ** 2, speed_stddev ** 2
            aux.initialised = True
            aux.last_accepted = {"operator": stamp if stamp is not None else 0.0}
            aux.s_last_fix = position
            aux.subs = {name: separation.seed(sm, stamp if stamp is not None else 0.0, position,
                                              position_stddev ** 2, aux.odometer) for name, sm in self._subs.items()}
        aux.t = stamp
        self._clear((x, P, aux))
        if stamp is not None:
            self.hist.base_key = (stamp,)

    def _predict_to(self, t: float) -> None:
        aux = self.aux
        if aux.t is None:
            aux.t = t
            return
        if t > aux.t:
            s0 = self.ekf.x[0, 0]
            aux.impacts = impact.predicted(aux.impacts, self.process.transition(t - aux.t)[0])
            self.ekf.x, self.ekf.P = self.process.predict(self.ekf.x, self.ekf.P, aux.t, t)
            aux.odometer += float(self.ekf.x[0, 0] - s0)
            aux.t = t
            if self._fault_bounds and aux.initialised and (
                    aux.impacts is None or
                    t - aux.impacts.last_onset_of(self._fault_bounds) >= self.cfg.fault_onset_spacing):
                aux.impacts = impact.started(aux.impacts, self._fault_bounds, t, self.n, self.cfg.fault_onsets,
                                             self._z)
            if aux.lone_view is not None:   # what a lone source's scale fault adds over the distance
                lone = aux.lone_view
                step = self._z * self.models[lone.sensor].scale_fault_sigma * abs(float(self.ekf.x[0, 0] - s0))
                aux.lone_view = lone._replace(bound=lone.bound + step)

    # -- measurement update ----------------------------------------------------
    def _update(self, z: float, R: float, h, hx: float, PHt, S: float) -> None:
        """Scalar EKF update (filterpy ExtendedKalmanFilter.update, Joseph form, for one row H).

        PHt = P h and S = h P h + R are those of the gate test.
        """
        P = self.ekf.P
        K = PHt / S
        self._last_update = (K, z - hx)
        self.aux.impacts = impact.updated(self.aux.impacts, self._fault_input, h, K, z - hx, S)
        Kc = K[:, None]
        self.ekf.x = self.ekf.x + Kc * (z - hx)
        A = self._eye - Kc * h
        self.ekf.P = A.dot(P).dot(A.T) + Kc * (K * R)

    def _apply(self, m) -> None:
        self._apply_policy(m)
        if self.aux.initialised:
            for key, sm in self._sensor_subs.get(m.sensor, ()):
                self.solutions.sub_reading(m, key, sm)

    def _apply_policy(self, m) -> None:
        aux = self.aux = self.aux.copy()
        self._predict_to(m.stamp)
        if self._subs:
            self._before = self.solutions.main()   # the filter before this measurement (separation.py)
        self.applied += 1
        cls = m.sensor
        is_fix = isinstance(m, PositionFix)
        # what this reading's own scale fault would add (impact.py), and whether another speed source
        # in use checks it (then its own innovations test the fault too)
        if is_fix:   # a fix's own offset per unit is its 1-sigma; the dead reckoning checks it
            self._fault_input = impact.FaultInput(cls, m.position_stddev if cls in self._offset_bounds else 0.0, True,
                                                  independent=cls not in self.layout.fix)
        else:
            self._fault_input = None if not (self._fault_bounds or self._transient_bounds) else impact.FaultInput(
                cls, m.distance / m.duration if hasattr(m, "distance") else m.speed,   # in the measurement's units
                bool(self._in_use(m.stamp, but=cls)), relative=True)
        if cls in self._offset_bounds and (aux.impacts is None or m.stamp - aux.impacts.last_onset_of((cls,))
                                           >= self.cfg.fault_onset_spacing):
            # a run of this sensor's fixes sharing an offset may begin with this one
            aux.impacts = impact.started(aux.impacts, {cls: self._offset_bounds[cls]}, m.stamp, self.n,
                                         self.cfg.fault_onsets, self._z, offset=True)
        if is_fix:   # since the sensor's previous fix, before this one counts (Solutions.located)
            self._since = m.stamp - aux.last_accepted.get(cls, -math.inf)
        if cls in self.layout.per_reference and is_fix and aux.fix_ref.get(cls) != m.reference_id:
            self.fixes.new_fix_bias(cls)
            aux.fix_ref = {**aux.fix_ref, cls: m.reference_id}
        if is_fix and not aux.initialised:
            self.fixes.initialise(m)
            return
        if is_coasting(aux) and not all(speed_excluded(aux, c, m.stamp) for c in aux.speed_sources):
            # a speed source is in use again: the coasting ends, its motion-model hypothesis moves
            # with the filter from now on until a fix rules it out
            aux.motion_views = aux.motion_views[:-1] + (self.motion.coasting_ended(aux.motion_views[-1], m.stamp),)
        if any(isinstance(v, MovedView) and v.until <= m.stamp for v in aux.motion_views):
            # past the longest episode of a transient fault the sources in use may share: their
            # common error no longer grows; the hypothesis moves with the filter from here
            s_f, P00 = float(self.ekf.x[0, 0]), float(self.ekf.P[0, 0])
            aux.motion_views = tuple(
                MovedView(*self.motion.motion_view(v, m.stamp, s_f, P00), s_f, P00, 0.0, 0.0, math.inf)
                if isinstance(v, MovedView) and v.until <= m.stamp else v for v in aux.motion_views)
        z, R, h, hx, PHt, S = self._innovation(m)
        if is_fix and aux.motion_views:
            # a fix rules out the motion-model hypotheses it does not fit
            s_f, P00 = float(self.ekf.x[0, 0]), float(self.ekf.P[0, 0])
            gate = self._gates[cls]
            kept = []
            for view in aux.motion_views:
                s_m, var_m = self.motion.motion_view(view, m.stamp, s_f, P00)
                if (z - s_m) ** 2 / (R + var_m) <= gate:
                    kept.append(view)
            aux.motion_views = tuple(kept)
        if not is_fix and speed_excluded(aux, cls, m.stamp) \
                and not self._agreement_reference(m, S) and self.motion.blind_speed(m, z, R):
            z, R, h, hx, PHt, S = self._innovation(m)   # at the re-acquired speed
        nis = (z - hx) ** 2 / S
        if is_fix and nis <= self._gates[cls] and any(isinstance(v, MovedView) for v in aux.motion_views):
            # the filter, on its speed sources again, explains an absolute fix: it is confirmed,
            # and an old coasting's motion-model hypothesis (however vague) is no longer needed
            aux.motion_views = tuple(v for v in aux.motion_views if not isinstance(v, MovedView))
        checked = self.ekf.P
        excluded = cls in aux.suspended and self.arbitration.suspended(m, z - hx, S, nis, self.episodes.common(cls, h))
        if not excluded and self.ekf.P is not checked:   # back with its scale opened (Episodes.relearn_fault)
            z, R, h, hx, PHt, S = self._innovation(m)
            nis = (z - hx) ** 2 / S
            checked = self.ekf.P
        excluded = excluded or (cls in self.layout.episode_sensors and self.episodes.slipping(m, z - hx, S, nis))
        if excluded:
            if cls in self._bounded:
                self.episodes.outlasted(m, z, R, hx, S, h)
            return
        if self.ekf.P is not checked:   # its learnt fault ended (Episodes.fault_ended)
            z, R, h, hx, PHt, S = self._innovation(m)
            nis = (z - hx) ** 2 / S
        if is_fix and aux.relative_alternatives and self.arbitration.decide_relative(m, z, R, hx, S, nis):
            return
        if is_fix and aux.alternative is not None and aux.alternative.opened and self.fixes.corroborated(m, z, R):
            # the kept fix, for which a scale was opened, and this one agree: the position from
            # them, also where the filter's opened interval would have taken this one (it would
            # learn the scale from this fix against a position the kept fix showed wrong)
            self.fixes.reacquire(m)
            return
        if nis > self._gates[cls]:
            aux.gated = incremented(aux.gated, cls)
            if is_fix and aux.initialised:
                self.fixes.unexplained(m, z, R)
            return
        if is_fix and self.fixes.remembered(m, R):
            return
        if abs(float(self.ekf.x[2, 0])) >= self.cfg.slip_min_drive:
            aux.last_drive = m.stamp
        if cls in self._transient_bounds and aux.initialised:   # a relative reading: its fault input is set above
            share = self._unseen_share(cls, m.stamp, self._fault_input.per_unit, S)
            self._fault_input = self._fault_input._replace(unseen=share)
            alone = share >= 1.0
            if aux.impacts is None or aux.impacts.episode_begins(cls, alone):
                aux.impacts = impact.episode_started(aux.impacts, cls, self._transient_bounds[cls], m.stamp, alone,
                                                     self.n, self.cfg.fault_onsets, self._z)
        x_before = self.ekf.x
        self._update(z, R, h, hx, PHt, S)
        if is_fix and nis > 1.0 and cls not in self.layout.fix:
            self.fixes.correction_unconfirmed(x_before, nis)
        seen = aux.nis.get(cls, NisSum(0, 0.0))
        aux.nis = {**aux.nis, cls: NisSum(seen.count + 1, seen.total + nis)}
        aux.accepted = incremented(aux.accepted, cls)
        aux.last_accepted = {**aux.last_accepted, cls: m.stamp}
        if cls in aux.episode_views or cls in aux.fault_windows:
            aux.episode_views = without_key(aux.episode_views, cls)
            aux.fault_windows = without_key(aux.fault_windows, cls)
        if is_fix:
            self.fixes.fix_accepted(m, nis, (z - hx) / math.sqrt(S), S)
        else:
            if cls not in aux.speed_sources:
                aux.speed_sources = aux.speed_sources | {cls}
            if self._persistent:
                self.lone.track(m.stamp)
        self.plausibility.check_plausible()

    def _measurement(self, m):
        """(z, R, H row, h(x)) of a measurement at the current state (models.measurement), with
        the time since its sensor's previous accepted fix (a fix's persistent error)."""
        since = m.stamp - self.aux.last_accepted.get(m.sensor, -math.inf)
        return measurement(self.layout, self.ekf.x, m, since)

    def _innovation(self, m):
        """(z, R, H row, h(x), P H, innovation variance S) of a measurement at the current state."""
        z, R, h, hx = self._measurement(m)
        PHt = self.ekf.P.dot(h)
        return z, R, h, hx, PHt, float(h.dot(PHt)) + R

    # -- fault policy ----------------------------------------------------------

    def _in_use(self, stamp: float, but: str | None = None) -> list[str]:
        """The speed sources in use at ``stamp`` [s]: accepted within ``slip_reference_timeout`` s
        and not excluded (in an episode, or suspended since), ``but`` left out."""
        aux, recent = self.aux, stamp - self.cfg.slip_reference_timeout
        return [s for s in aux.speed_sources if s != but and not speed_excluded(aux, s, stamp)
                and aux.last_accepted.get(s, -math.inf) > recent]

    def _unseen_share(self, cls: str, stamp: float, speed: float, S: float) -> float:
        """The share [0, 1] of a transient fault of ``cls``'s bound (``slip_ratio_max`` x its reading's
        ``speed`` [m/s]) that the slip tests let pass at this reading (S: its innovation variance
        [m^2/s^2]). Another speed source in use checks it: up to the gate's radius of a fault that
        lasts through the n readings of the accumulated test's window (``Episodes.windowed``),
        where it shows at sqrt(n) times its size in one reading's 1-sigma. Another one excluded as
        an undecided alternative reads beside it: the disagreement with its last reading (within
        ``slip_reference_timeout`` s) and that gate's radius. Else nothing but the motion model
        sees it, against which a slip that has begun is a speed: all of it. None where the train
        has not been driven or braked (``slip_min_drive``) within the sensor's longest episode."""
        bound = self._transient_bounds[cls] * abs(speed)
        if bound <= 0.0 or stamp - self.aux.last_drive > self.models[cls].fault_duration_max:
            return 0.0
        if self._in_use(stamp, but=cls):
            n = max(len(self.aux.slip_window.get(cls, ())), 1)
            return min(1.0, math.sqrt(self._slip_gate * S / n) / bound)
        recent = stamp - self.cfg.slip_reference_timeout
        beside = [r for c, r in self.aux.view_speeds.items() if c != cls and c in self.aux.relative_alternatives
                  and r.stamp > recent]
        if beside:
            return min(1.0, min(abs(abs(speed) - abs(r.speed)) + math.sqrt(self._slip_gate * (S + r.var))
                                for r in beside) / bound)
        return 1.0

    def _reference_ok(self, m) -> bool:
        """Another speed source is in use (``_in_use``)."""
        return bool(self._in_use(m.stamp, but=m.sensor))

    def _agreement_reference(self, m, S: float) -> bool:
        """Whether the filter's speed rests on more than ``m.sensor`` and the motion model:
        another speed source accepted within ``slip_reference_timeout`` s and not itself in
        an episode, or a speed known at least as well as the measurement's own noise (a
        stream of fixes). Only then can an excluded sensor be seen to agree again; the
        motion model alone, its speed uncertainty growing, would let a faulty sensor back in.
        S: the measurement's innovation variance (filter part + its own noise). While the filter
        coasts between excluded sources, its speed is theirs: no reference."""
        if is_coasting(self.aux):
            return self._reference_ok(m)
        return self._reference_ok(m) or float(self.ekf.P[1, 1]) <= 0.5 * S

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
                    self.episodes.excluded(m, hist.excluded[hist.keys[j]][1])
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
            if c[0] is not xk or c[1] is not Pk:
                x_err = xk[:, 0].tolist()
                c = self._est_cache = (xk, Pk, x_err, kinematic_covariance(Pk), self._error_states(x_err),
                                       impact.prepared(aux.impacts, self._z))
            x_err = c[2]
            dt = t - aux.t
            s, v, a, var_s, var_v = kinematics(x_err[0], x_err[1], x_err[2], c[3], dt, self.cfg.jerk_psd)
            scales, biases = c[4]
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
        lo, hi, sd_s, sd_v, mode = self.interval.cover(aux, t, s, v, var_s, var_v, sd_s, sd_v, xk, Pk, odometer)
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

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
  episodes    (episodes.py)
  plausibility (plausibility.py)
  separation  (solutions.py)
  lone source (lone.py)
  consistency the mean NIS of the last ``consistency_fixes`` accepted absolute fixes of
              sensors without a persistent fix error (balises, lugs, axle counters: one
              independent fix per reference) above its chi-square quantile means the
              covariance is too small: it is scaled by that mean. The same test over each
              sensor's own fixes with a fix-bias state (DGPS, mm-wave, INPO: the bias is a
              state, so the innovations are white if the model holds) means the fixes and the
              dead reckoning part faster than that bias can: a fault of the relative sensors
              (a lone radar's scale fault) was being absorbed into the fix bias, or the fix
              sensor has one beyond its model. Which, one cannot tell: the fix bias goes back
              to its prior, the relative error states keep their estimates with at least
              their prior uncertainty (after a drift, a scale with a scale-fault mode that
              of the fault's size), and the dead-reckoned position is kept as the
              alternative until an independent fix decides.
  unexplained an absolute fix the gate rejects is kept as an alternative hypothesis: the
              published interval covers it (moved with the filter's motion) until a fix of
              another reference decides: one the filter explains drops it (the fix was the
              outlier); one that agrees with it means the filter was wrong: the position is
              taken from the fixes and the relative error states are re-learnt.
  arbitration (arbitration.py)
  recalibration a fix of an independent reference whose innovation exceeds its expected
              size (NIS > 1) re-calibrates the speed and error states by more than the model
              expected: the covariance keeps that excess along the correction, so only the
              next fix can confirm it.
  merge       (arbitration.py)
  blind       (motion_views.py)
  coasting    (motion_views.py)
  revisit     a fix of a reference the filter accepted before (a reversal over a balise)
              carries the same installation error: not applied while the filter knows its
              position better than the fix.
Modes and the published interval: interval.py.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from scipy.stats import chi2, norm

from ..measurements import MAX_SPEED, PositionFix
from ..sensors import faults as fault_modes
from ..signals import InputRejected
from .bookkeeping import (Bookkeeping, Candidate, ModelView, MovedView, NisSum, UnexplainedFix, incremented,
                          is_coasting, speed_excluded, without_key)
from .config import FusionConfig, gate_probability
from .history import History, order_key
from .layout import StateLayout
from . import impact
from .models import ProcessModel, kinematic_covariance, kinematics, measurement
from .mode import Mode
from .episodes import Lookback
from . import separation
from .lone import LoneSource
from .solutions import Solutions
from .interval import Interval
from .motion_views import MotionViews
from .arbitration import Arbitration
from .episodes import Episodes
from .plausibility import Plausibility


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



# references whose fixes the filter remembers (a reversal passes the last few again)
_REMEMBERED_REFS = 32


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
        # interval covers the solution without it (``LoneSource.track_lone``). A calibration fault (a worn
        # wheel) is a constant: the sensor's own solution with its scale opened covers it
        self._persistent = frozenset(n for n, m in self.models.items() if m.relative and
                                     (fault_modes.PERSISTENT - fault_modes.CALIBRATION) & set(m.faults))
        # relative sensors with a persistent fault of bounded size -> that bound (z x scale_fault_sigma):
        # the interval covers what such a fault, up to the size the data has not excluded, put into
        # the state (impact.py)
        self._fault_bounds = {n: self._z * m.scale_fault_sigma for n, m in self.models.items()
                              if n in self._persistent and m.scale_fault_sigma > 0.0}
        self._fault_input: tuple | None = None   # (sensor, its fault per unit) of the reading being applied
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
                                              position_stddev ** 2, speed) for name, sm in self._subs.items()}
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
            aux.t = t
            if self._fault_bounds and aux.initialised and (
                    aux.impacts is None or t - aux.impacts.last_onset >= self.cfg.fault_onset_spacing):
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
        self._fault_input = None if is_fix or not self._fault_bounds else (
            cls, m.distance if hasattr(m, "distance") else m.speed, bool(self._in_use(m.stamp, but=cls)))
        if is_fix:   # since the sensor's previous fix, before this one counts (Solutions.located)
            self._since = m.stamp - aux.last_accepted.get(cls, -math.inf)
        if cls in self.layout.per_reference and is_fix and aux.fix_ref.get(cls) != m.reference_id:
            self._new_fix_bias(cls)
            aux.fix_ref = {**aux.fix_ref, cls: m.reference_id}
        if is_fix and not aux.initialised:
            self._initialise(m)
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
        if is_fix and aux.alternative is not None and aux.alternative.opened and self._corroborated(m, z, R):
            # the kept fix, for which a scale was opened, and this one agree: the position from
            # them, also where the filter's opened interval would have taken this one (it would
            # learn the scale from this fix against a position the kept fix showed wrong)
            self._reacquire(m)
            return
        if nis > self._gates[cls]:
            aux.gated = incremented(aux.gated, cls)
            if is_fix and aux.initialised:
                self._unexplained(m, z, R)
            return
        if is_fix and self._remembered(m, R):
            return
        x_before = self.ekf.x
        self._update(z, R, h, hx, PHt, S)
        if is_fix and nis > 1.0 and cls not in self.layout.fix:
            self._correction_unconfirmed(x_before, nis)
        seen = aux.nis.get(cls, NisSum(0, 0.0))
        aux.nis = {**aux.nis, cls: NisSum(seen.count + 1, seen.total + nis)}
        aux.accepted = incremented(aux.accepted, cls)
        aux.last_accepted = {**aux.last_accepted, cls: m.stamp}
        if cls in aux.episode_views or cls in aux.fault_windows:
            aux.episode_views = without_key(aux.episode_views, cls)
            aux.fault_windows = without_key(aux.fault_windows, cls)
        if is_fix:
            self._fix_accepted(m, nis, (z - hx) / math.sqrt(S), S)
        else:
            if cls not in aux.speed_sources:
                aux.speed_sources = aux.speed_sources | {cls}
            if self._persistent:
                self.lone.track_lone(m.stamp)
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

    def _correction_unconfirmed(self, x_before, nis: float) -> None:
        """A fix whose innovation exceeds its expected size (NIS > 1) corrected the speed and
        error states by d = K nu, more than the model expected (K S K^T): the excess may be the
        error states' doing (the model's reading) or a one-off the model lacks (an undetected slip
        onset, a fix error beyond its stddev). The covariance keeps that excess,
        (1 - 1/NIS) d d^T, along d (innovation-based covariance matching, Mehra 1972), so one
        fix cannot make the filter sure of a speed re-calibration that only the next fix can
        confirm. The position, which the fix itself gives, is left as updated. Only for fixes of
        independent references (no fix-bias state): a stream of fixes (mm-wave, INPO) confirms
        or undoes a re-calibration milliseconds later."""
        d = (self.ekf.x - x_before)[:, 0]   # a new array: zeroing its position entry changes nothing else
        d[0] = 0.0
        self.ekf.P = self.ekf.P + (1.0 - 1.0 / nis) * np.outer(d, d)

    def _remembered(self, m, R: float) -> bool:
        """A fix of a reference whose earlier fix the filter still holds: its error (a balise's
        or a head's installation error, part of R) is the same as then, so it is no new
        information while the filter knows its position better than the fix (P00 < R): not
        applied, counted (``reference_revisited``). Sensors with a fix-bias state model this
        themselves."""
        if m.sensor in self.layout.fix:
            return False
        aux = self.aux
        key = (m.sensor, m.reference_id)
        if key in aux.used_refs and float(self.ekf.P[0, 0]) < R:
            aux.events = incremented(aux.events, "reference_revisited")
            return True
        return False

    def _fix_accepted(self, m, nis: float, u: float, S: float) -> None:
        aux, cfg = self.aux, self.cfg
        if m.sensor not in self.layout.fix:
            key = (m.sensor, m.reference_id)
            aux.used_refs = tuple(k for k in aux.used_refs if k != key)[-(_REMEMBERED_REFS - 1):] + (key,)
        alt = aux.alternative
        if alt is not None and (m.sensor != alt.sensor or
                                (m.reference_id != alt.reference and m.sensor not in self.layout.fix)):
            # the filter explains an independent fix (not one of the same sensor with a fix-bias
            # state, whatever its reference: mm-wave station sets overlap): that one was wrong
            aux.alternative = None
            aux.events = incremented(aux.events, "outlier_fix")
        aux.unverified = ""
        aux.last_fix_accepted = m.stamp
        aux.s_last_fix = float(self.ekf.x[0, 0])
        self.solutions.hypotheses_take_fix(m)
        if m.sensor in self.layout.fix:
            self._fix_bias_consistency(m, nis, u, S)
            return   # a fix with a persistent error: not an independent test of the others
        window = (aux.fix_nis + (nis,))[-cfg.consistency_fixes:]
        mean = sum(window) / len(window)
        if len(window) == cfg.consistency_fixes and mean > self._consistency:
            # independent fixes disagree more than the covariance says: all of it is too small
            self.ekf.P = self.ekf.P * mean
            window = ()
            aux.events = incremented(aux.events, "inconsistent")
            aux.unverified = "inconsistent"
        aux.fix_nis = window

    def _fix_bias_consistency(self, m, nis: float, u: float, S: float) -> None:
        """Sensor m's accepted fixes (its fix bias a state: white innovations if the model holds)
        test the model: the mean NIS of its last ``consistency_fixes`` beyond its chi-square
        quantile, or their normalised innovations u (signed) summed with weights decaying over
        ``slip_window`` s, normalised by the root of the sum of the squared weights (standard
        normal if the model holds), beyond the slip gate (a drift shows as innovations of one
        sign long before their squares stand out). Either means the fixes and the dead
        reckoning part faster than the fix bias can (a lone radar's scale fault absorbed into a
        DGPS bias, or a fix fault beyond the sensor's model). The fix bias goes back to its
        prior, the relative error states keep their estimates with their prior uncertainty
        (after a drift alone, a scale with a scale-fault mode that of the fault's size,
        ``scale_fault_sigma``, and the speed with it), the position variance takes the bias the
        filter had estimated, and the dead-reckoned position is kept as the alternative (the
        interval covers it, DEGRADED) until a fix of an independent reference decides
        (``_fix_accepted``)."""
        aux, cls, cfg = self.aux, m.sensor, self.cfg
        # (last NIS values, stamp [s], the signed sum and the sum of its squared weights, both
        # decaying with time constant slip_window: a 200 Hz stream keeps O(1) state)
        last, t, summed, weights = aux.fix_bias_nis.get(cls, ((), m.stamp, 0.0, 0.0))
        decay = math.exp(-max(m.stamp - t, 0.0) / cfg.slip_window)
        last = (last + (nis,))[-cfg.consistency_fixes:]
        summed, weights = summed * decay + u, weights * decay * decay + 1.0
        noisy = len(last) == cfg.consistency_fixes and sum(last) / len(last) > self._consistency
        drift = weights >= 3.0 and summed * summed / weights > self._slip_gate
        if not (noisy or drift):
            aux.fix_bias_nis = {**aux.fix_bias_nis, cls: (last, m.stamp, summed, weights)}
            return
        if drift and not noisy:
            self._drift_from_slip(m, summed, weights, S)
        aux.fix_bias_nis = without_key(aux.fix_bias_nis, cls)
        # an alternative of this sensor is pending (an earlier inconsistency's view, or an
        # unexplained fix of it): the question is open already
        pending = aux.alternative is not None and aux.alternative.sensor == cls
        i = self.layout.fix[cls]
        bias = float(self.ekf.x[i, 0])
        s_dr, P_dr = float(self.ekf.x[0, 0]), float(self.ekf.P[0, 0])
        self._new_fix_bias(cls)
        P = self.ekf.P.copy()
        P[0, 0] += bias * bias
        # the relative error states keep their estimates, their variance raised to at least their
        # prior's: the fixes that follow tell whether they hold a fault (learnt beyond
        # plausibility, ``Plausibility.check_plausible`` suspends the sensor) or the fix bias did
        # a drift alone (small innovations of one sign: the dead reckoning parts at a rate, as a
        # scale fault makes it) raises a constant scale with a scale-fault mode to the fault's
        # size; not where the fixes are also noisier than their model (an NLOS step would pull a
        # scale opened that wide), nor again while the question is open (the same fixes would
        # pull the opened states again and again)
        faulty = () if noisy or pending else [c for c in self.layout.scale if "scale_fault" in self.models[c].faults]
        self.ekf.P = self._raised(P, faulty)
        aux.events = incremented(aux.events, "inconsistent_fix_bias")
        # the fixes pull the filter by about the bias it had estimated (s = z - e, e now 0): the
        # dead-reckoned view stays where it was, moving with the filter's motion from there
        if not pending:
            aux.alternative = UnexplainedFix(m.stamp, s_dr, P_dr, s_dr + bias, float(self.ekf.P[0, 0]), cls,
                                             m.reference_id, ())

    def _drift_from_slip(self, m, summed: float, weights: float, S: float) -> None:
        """The fixes drift from the dead reckoning (``_fix_bias_consistency``: innovations of one
        sign, their weighted sum ``summed`` over the root of ``weights``; S [m^2]: this fix's
        innovation variance, which scales them back to metres). A speed source in use
        whose transient fault mode fits the drift's direction under the present drive (a wheel
        turning fast under traction, slip; slow under braking, slide) may have been slipping
        too slowly for its own test: the filter followed it, so its readings agreed with the
        filter, and only the fixes could tell. Its readings of the last ``history`` s are taken
        out and the history is applied again without them (``Lookback``, as at a slip's onset
        that the window test found late): the fixes and the other sources carry the speed, and
        the sensor is back once it agrees. A reading the fault did not touch costs precision,
        not integrity; a slip left in would cost the interval."""
        stamp = m.stamp
        v, a = float(self.ekf.x[1, 0]), float(self.ekf.x[2, 0])
        sv = 1.0 if v >= 0.0 else -1.0
        drive = a * sv
        # fixes behind the dead reckoning along the motion: the filter ran ahead of the train, a
        # speed source read too fast
        ahead = summed * sv < 0.0
        limit = self.cfg.slip_min_drive
        for cls in self._in_use(stamp):
            if cls not in self._bounded:
                continue
            faults = self.models[cls].faults
            if ("slip" in faults and drive >= limit and ahead) or ("slide" in faults and drive <= -limit and not ahead):
                # the disagreement [m/s] the drift shows, about: the innovations' weighted mean [m]
                # over the test's time constant, as a reading of that sensor would differ
                shown = -summed / weights * math.sqrt(S) / self.cfg.slip_window
                raise Lookback(cls, stamp - self.cfg.history, shown)

    def _raised(self, P, faulty) -> np.ndarray:
        """Covariance P with the relative error states at least as uncertain as their priors,
        and the constant scale of each sensor in ``faulty`` (with a scale-fault mode) by the
        fault's size (``scale_fault_sigma``) more; the speed, learnt through the scales, as
        uncertain as they became. Rows and columns are rescaled, so the correlations stay."""
        lay = self.layout
        idx = lay.relative_states
        if not len(idx):
            return P
        P = P.copy()
        floor = np.zeros(self.n)
        floor[idx] = lay.prior_sigma[idx] ** 2
        for name in faulty:
            floor[lay.fault_scale[name]] += self.models[name].scale_fault_sigma ** 2
        var = np.diag(P).copy()
        scales = [*lay.scale.values(), *lay.offset.values()]
        P[1, 1] += float(np.sum(np.maximum(floor[scales] - var[scales], 0.0))) * float(self.ekf.x[1, 0]) ** 2
        ratio = np.sqrt(np.divide(np.maximum(var[idx], floor[idx]), var[idx], out=np.ones(len(idx)),
                                  where=var[idx] > 0))
        P[idx, :] *= ratio[:, None]
        P[:, idx] *= ratio[None, :]
        return P

    def _scale_faults_explaining(self, m, z: float, R: float) -> list[str]:
        """The speed sources in use with a scale-fault mode whose fault, over the distance run
        since the last accepted fix, would explain independent fix ``m`` (z, R) that the
        filter does not: the innovation inside the gate of its variance with that fault's
        (``scale_fault_sigma`` x distance) added."""
        aux, stamp = self.aux, m.stamp
        if m.sensor in self.layout.fix or not math.isfinite(aux.s_last_fix):
            return []
        s, P00 = float(self.ekf.x[0, 0]), float(self.ekf.P[0, 0])
        run = abs(s - aux.s_last_fix)
        return [c for c in sorted(self._in_use(stamp)) if c in self.layout.scale
                and "scale_fault" in self.models[c].faults
                and (z - s) ** 2 <= self._gates[m.sensor] * (P00 + R + (self.models[c].scale_fault_sigma * run) ** 2)]

    def _unexplained(self, m, z: float, R: float) -> None:
        """A gated absolute fix: keep it as the alternative, or let it confirm the one kept.
        Where a persistent scale fault of a speed source in use would explain it (a lone
        radar's, which nothing else measures), that source's scale is opened to the fault's
        size (``_raised``): under that hypothesis the filter's speed is wrong, and the interval
        of both the filter and the kept fix moves with the filter's motion. The next fix of
        another reference decides: one that agrees with the kept fix re-acquires the position
        from itself, the scale left open for the fixes after it to learn (``Plausibility.relearn``)."""
        aux = self.aux
        if self._corroborated(m, z, R):
            # two independent fixes agree with each other, not with the filter: it was wrong
            self._reacquire(m)
            return
        alt = aux.alternative
        if alt is not None and m.stamp - alt.stamp <= self.cfg.branch_timeout and \
                (m.sensor, m.reference_id) == (alt.sensor, alt.reference):
            return   # the kept reference read again confirms nothing and stays the alternative
        faulty = self._scale_faults_explaining(m, z, R)
        if faulty:
            self.ekf.P = self._raised(self.ekf.P, faulty)
            aux.events = incremented(aux.events, "scale_fault_suspected")
        aux.alternative = UnexplainedFix(m.stamp, z, R, float(self.ekf.x[0, 0]), float(self.ekf.P[0, 0]), m.sensor,
                                         m.reference_id, tuple(faulty))
        aux.events = incremented(aux.events, "unexplained_fix")

    def _reacquire(self, m) -> None:
        """Two independent fixes agree with each other, not with the filter (the kept
        alternative and ``m``): the position from ``m``, the relative error states re-learnt;
        a scale opened for the alternative stays open."""
        faulty = self.aux.alternative.opened
        self._set_position(m)
        self.plausibility.relearn("reacquired", faulty)
        self.aux.alternative = None

    def _corroborated(self, m, z: float, R: float) -> bool:
        """An unexplained fix of another, independent reference is kept and agrees with fix m
        (z, R). Fixes of one sensor with a fix-bias state are not independent, whatever their
        reference ids (mm-wave ranging: overlapping sets of stations, one NLOS or calibration
        fault in all of them)."""
        alt = self.aux.alternative
        if alt is None or m.stamp - alt.stamp > self.cfg.branch_timeout:
            return False
        if m.sensor == alt.sensor and (m.reference_id == alt.reference or m.sensor in self.layout.fix):
            return False
        return self._agrees(m, z, R, float(self.ekf.x[0, 0]), float(self.ekf.P[0, 0]), alt.z, alt.R, alt.s, alt.P00)

    def _agrees(self, m, z: float, R: float, s: float, P00: float,
                z_kept: float, R_kept: float, s_kept: float, P00_kept: float) -> bool:
        """Whether fix ``m`` (z, R) agrees with a kept fix moved by the dead reckoning since:
        filter position and its variance s, P00 now, s_kept, P00_kept when it was kept."""
        var = R_kept + R + max(P00 - P00_kept, 0.0)
        return (z - (z_kept + (s - s_kept))) ** 2 / var <= self._gates[m.sensor]

    def _initialise(self, m) -> None:
        """Claim the position from a fix. A fix of a sensor that can misread its reference (a
        balise telegram, a lug code) is only a candidate: the position is set when a fix of
        another reference agrees with it, moved by the dead reckoning since."""
        aux, cfg = self.aux, self.cfg
        if "misread" not in self.models[m.sensor].faults:
            # a reference that cannot be misidentified (wayside heads, loops, ranging): its decoder
            # withholds what it cannot tell (a miscounted axle, an unresolved NLOS)
            self._set_position(m)
            self._first_position(m.stamp)
            return
        z, R, _, _ = self._measurement(m)
        x0, P00 = float(self.ekf.x[0, 0]), float(self.ekf.P[0, 0])
        cand = aux.candidate
        if cand is not None and m.stamp - cand.stamp <= cfg.branch_timeout:
            if m.reference_id == cand.reference and m.sensor == cand.sensor:
                return                               # the same reference confirms nothing
            if self._agrees(m, z, R, x0, P00, cand.z, cand.R, cand.s, cand.P00):
                self._set_position(m)
                self._first_position(m.stamp)
                return
            aux.events = incremented(aux.events, "candidate_replaced")
        aux.candidate = Candidate(m.stamp, z, R, x0, m.sensor, m.reference_id, P00)

    def _first_position(self, stamp: float) -> None:
        """The position is claimed for the first time (``_set_position`` has just taken it from a
        fix). The motion model's hypotheses of coastings before it were kept in the frame of the
        dead reckoning from the start; the fix locates the train under each of them: a moved
        one adds nothing more and is dropped, a coasting in progress keeps its speed and
        acceleration hypothesis and takes the filter's position."""
        aux = self.aux
        aux.initialised = True
        aux.candidate = None
        views = []
        for view in aux.motion_views:
            if isinstance(view, ModelView):
                x, P = self.motion.model_view_at(view, stamp)
                views.append(ModelView(stamp, float(self.ekf.x[0, 0]), float(x[1]), float(x[2]),
                                       (float(self.ekf.P[0, 0]), 0.0, 0.0, float(P[1, 1]), float(P[1, 2]),
                                        float(P[2, 2]))))
        aux.motion_views = tuple(views)

    def _set_position(self, m) -> None:
        """Take the position from a fix alone (first fix, re-acquisition): s = z - e."""
        aux, cls = self.aux, m.sensor
        z, R, _, _ = self._measurement(m)
        x = self.ekf.x.copy()
        P = self.ekf.P.copy()
        P[0, :] = 0.0
        P[:, 0] = 0.0
        P[0, 0] = R
        x[0, 0] = z
        f_idx = self.layout.fix.get(cls)
        if f_idx is not None:   # s = z - e: its covariances are those of -e
            x[0, 0] -= x[f_idx, 0]
            P[0, :] = -P[f_idx, :]
            P[:, 0] = -P[:, f_idx]
            P[0, 0] = R + P[f_idx, f_idx]
        self.ekf.x, self.ekf.P = x, P
        aux.impacts = impact.position_set_from_fix(aux.impacts, f_idx)
        aux.accepted = incremented(aux.accepted, cls)
        aux.last_accepted = {**aux.last_accepted, cls: m.stamp}
        aux.last_fix_accepted = m.stamp
        aux.s_last_fix = float(x[0, 0])
        self.solutions.seed_subs(m.stamp)
        aux.lone_view = None      # the lone source's solution starts again from here (LoneSource.track_lone)

    def _new_fix_bias(self, cls: str) -> None:
        """A new reference: its fix bias is independent of the previous one."""
        i = self.layout.fix[cls]
        x, P = self.ekf.x.copy(), self.ekf.P.copy()
        x[i, 0] = 0.0
        P[i, :] = 0.0
        P[:, i] = 0.0
        P[i, i] = self.layout.prior_sigma[i] ** 2
        self.ekf.x, self.ekf.P = x, P
        self.aux.impacts = impact.states_set(self.aux.impacts, [i])

    # -- input -----------------------------------------------------------------
    def add(self, m) -> None:
        """Insert a measurement at its stamp (the filter catches up when next queried).

        The measurement has passed admission (admission.py, run by FusionRunner.add); the
        history raises InputRejected for one already seen (``duplicate``) or one older than
        the history or the last reset (``too_late``).
        """
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
        lo, hi, sd_s, sd_v, mode = self.interval.cover(aux, t, s, v, var_s, var_v, sd_s, sd_v, xk, Pk)
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

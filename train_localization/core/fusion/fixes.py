"""The policies on absolute fixes: initialisation, consistency, unexplained fixes, recalibration
and revisits.

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
  recalibration a fix of an independent reference whose innovation exceeds its expected
              size (NIS > 1) re-calibrates the speed and error states by more than the model
              expected: the covariance keeps that excess along the correction, so only the
              next fix can confirm it.
  revisit     a fix of a reference the filter accepted before (a reversal over a balise)
              carries the same installation error: not applied while the filter knows its
              position better than the fix.
"""
from __future__ import annotations

import math

import numpy as np

from .component import Component
from . import counts
from .bookkeeping import Candidate, UnexplainedFix, without_key
from . import impact, views
from .events import FirstPosition, LoneReset, Relearn, SeedSubs
from .episodes import Lookback



# references whose fixes the filter remembers (a reversal passes the last few again)
_REMEMBERED_REFS = 32


class Fixes(Component):
    """The policies on absolute fixes."""

    def fix_accepted(self, m, nis: float, u: float, S: float) -> None:
        aux, cfg = self.f.aux, self.f.cfg
        if m.sensor not in self.f.layout.fix:
            key = (m.sensor, m.reference_id)
            aux.used_refs = tuple(k for k in aux.used_refs if k != key)[-(_REMEMBERED_REFS - 1):] + (key,)
        alt = aux.alternative
        if alt is not None and (m.sensor != alt.sensor or
                                (m.reference_id != alt.reference and m.sensor not in self.f.layout.fix)):
            # the filter explains an independent fix (not one of the same sensor with a fix-bias
            # state, whatever its reference: mm-wave station sets overlap): that one was wrong
            aux.alternative = None
            counts.event(aux, "outlier_fix")
        aux.unverified = ""
        aux.last_fix_accepted = m.stamp
        aux.s_last_fix = float(self.f.ekf.x[0, 0])
        if m.sensor in self.f.layout.fix:
            self.fix_bias_consistency(m, nis, u, S)
            return   # a fix with a persistent error: not an independent test of the others
        window = (aux.fix_nis + (nis,))[-cfg.consistency_fixes:]
        mean = sum(window) / len(window)
        if len(window) == cfg.consistency_fixes and mean > self.f.limits.consistency:
            # independent fixes disagree more than the covariance says: all of it is too small
            self.f.ekf.P = self.f.ekf.P * mean
            window = ()
            counts.event(aux, "inconsistent")
            aux.unverified = "inconsistent"
        aux.fix_nis = window

    def fix_bias_consistency(self, m, nis: float, u: float, S: float) -> None:
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
        (``Fixes.fix_accepted``)."""
        aux, cls, cfg = self.f.aux, m.sensor, self.f.cfg
        # (last NIS values, stamp [s], the signed sum and the sum of its squared weights, both
        # decaying with time constant slip_window: a 200 Hz stream keeps O(1) state)
        last, t, summed, weights = aux.fix_bias_nis.get(cls, ((), m.stamp, 0.0, 0.0))
        decay = math.exp(-max(m.stamp - t, 0.0) / cfg.slip_window)
        last = (last + (nis,))[-cfg.consistency_fixes:]
        summed, weights = summed * decay + u, weights * decay * decay + 1.0
        noisy = len(last) == cfg.consistency_fixes and sum(last) / len(last) > self.f.limits.consistency
        drift = weights >= 3.0 and summed * summed / weights > self.f.limits.slip_gate
        if not (noisy or drift):
            aux.fix_bias_nis = {**aux.fix_bias_nis, cls: (last, m.stamp, summed, weights)}
            return
        if drift and not noisy:
            self.drift_from_slip(m, summed, weights, S)
        aux.fix_bias_nis = without_key(aux.fix_bias_nis, cls)
        # an alternative of this sensor is pending (an earlier inconsistency's view, or an
        # unexplained fix of it): the question is open already
        pending = aux.alternative is not None and aux.alternative.sensor == cls
        i = self.f.layout.fix[cls]
        bias = float(self.f.ekf.x[i, 0])
        s_dr, P_dr = float(self.f.ekf.x[0, 0]), float(self.f.ekf.P[0, 0])
        self.new_fix_bias(cls)
        P = self.f.ekf.P.copy()
        P[0, 0] += bias * bias
        # the relative error states keep their estimates, their variance raised to at least their
        # prior's: the fixes that follow tell whether they hold a fault (learnt beyond
        # plausibility, ``Plausibility.check_plausible`` suspends the sensor) or the fix bias did
        # a drift alone (small innovations of one sign: the dead reckoning parts at a rate, as a
        # scale fault makes it) raises a constant scale with a scale-fault mode to the fault's
        # size; not where the fixes are also noisier than their model (an NLOS step would pull a
        # scale opened that wide), nor again while the question is open (the same fixes would
        # pull the opened states again and again)
        faulty = () if noisy or pending else [c for c in self.f.layout.scale if "scale_fault" in self.f.models[c].faults]
        self.f.ekf.P = views.raised(P, faulty, self.f.layout, self.f.models, float(self.f.ekf.x[1, 0]))
        counts.event(aux, "inconsistent_fix_bias")
        # the fixes pull the filter by about the bias it had estimated (s = z - e, e now 0): the
        # dead-reckoned view stays where it was, moving with the filter's motion from there
        if not pending:
            aux.alternative = UnexplainedFix(m.stamp, s_dr, P_dr, s_dr + bias, float(self.f.ekf.P[0, 0]), cls,
                                             m.reference_id, ())

    def drift_from_slip(self, m, summed: float, weights: float, S: float) -> None:
        """The fixes drift from the dead reckoning (``Fixes.fix_bias_consistency``: innovations of one
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
        v, a = float(self.f.ekf.x[1, 0]), float(self.f.ekf.x[2, 0])
        sv = 1.0 if v >= 0.0 else -1.0
        drive = a * sv
        # fixes behind the dead reckoning along the motion: the filter ran ahead of the train, a
        # speed source read too fast
        ahead = summed * sv < 0.0
        limit = self.f.cfg.slip_min_drive
        for cls in self.f.in_use(stamp):
            if cls not in self.f.limits.bounded:
                continue
            faults = self.f.models[cls].faults
            if ("slip" in faults and drive >= limit and ahead) or ("slide" in faults and drive <= -limit and not ahead):
                # the disagreement [m/s] the drift shows, about: the innovations' weighted mean [m]
                # over the test's time constant, as a reading of that sensor would differ
                shown = -summed / weights * math.sqrt(S) / self.f.cfg.slip_window
                raise Lookback(cls, stamp - self.f.cfg.history, shown)

    def scale_faults_explaining(self, m, z: float, R: float) -> list[str]:
        """The speed sources in use with a scale-fault mode whose fault, over the distance run
        since the last accepted fix, would explain independent fix ``m`` (z, R) that the
        filter does not: the innovation inside the gate of its variance with that fault's
        (``scale_fault_sigma`` x distance) added."""
        aux, stamp = self.f.aux, m.stamp
        if "scale_fault_explanation" not in self.f.cfg.policies:
            return []
        if m.sensor in self.f.layout.fix or not math.isfinite(aux.s_last_fix):
            return []
        s, P00 = float(self.f.ekf.x[0, 0]), float(self.f.ekf.P[0, 0])
        run = abs(s - aux.s_last_fix)
        return [c for c in sorted(self.f.in_use(stamp)) if c in self.f.layout.scale
                and "scale_fault" in self.f.models[c].faults
                and (z - s) ** 2 <= self.f.limits.gates[m.sensor] * (P00 + R + (self.f.models[c].scale_fault_sigma * run) ** 2)]

    def unexplained(self, m, z: float, R: float) -> tuple:
        """A gated absolute fix: keep it as the alternative, or let it confirm the one kept.
        Where a persistent scale fault of a speed source in use would explain it (a lone
        radar's, which nothing else measures), that source's scale is opened to the fault's
        size (``views.raised``): under that hypothesis the filter's speed is wrong, and the interval
        of both the filter and the kept fix moves with the filter's motion. The next fix of
        another reference decides: one that agrees with the kept fix re-acquires the position
        from itself, the scale left open for the fixes after it to learn (``Plausibility.relearn``).
        Returns the effects on other policies (events.py)."""
        aux = self.f.aux
        if views.corroborated(m, z, R, self.f.aux.alternative, self.f.ekf.x, self.f.ekf.P, self.f.layout,
                              self.f.cfg.branch_timeout, self.f.limits.gates[m.sensor]):
            # two independent fixes agree with each other, not with the filter: it was wrong
            return self.reacquire(m)
        alt = aux.alternative
        if alt is not None and m.stamp - alt.stamp <= self.f.cfg.branch_timeout and \
                (m.sensor, m.reference_id) == (alt.sensor, alt.reference):
            return ()   # the kept reference read again confirms nothing and stays the alternative
        faulty = self.scale_faults_explaining(m, z, R)
        if faulty:
            self.f.ekf.P = views.raised(self.f.ekf.P, faulty, self.f.layout, self.f.models, float(self.f.ekf.x[1, 0]))
            counts.event(aux, "scale_fault_suspected")
        aux.alternative = UnexplainedFix(m.stamp, z, R, float(self.f.ekf.x[0, 0]), float(self.f.ekf.P[0, 0]), m.sensor,
                                         m.reference_id, tuple(faulty))
        counts.event(aux, "unexplained_fix")
        return ()

    def reacquire(self, m) -> tuple:
        """Two independent fixes agree with each other, not with the filter (the kept
        alternative and ``m``): the position from ``m``, the relative error states re-learnt
        (the effects returned: events.py); a scale opened for the alternative stays open."""
        faulty = self.f.aux.alternative.opened
        events = self.set_position(m)
        self.f.aux.alternative = None
        return events + (Relearn("reacquired", faulty),)

    def remembered(self, m, R: float) -> bool:
        """A fix of a reference whose earlier fix the filter still holds: its error (a balise's
        or a head's installation error, part of R) is the same as then, so it is no new
        information while the filter knows its position better than the fix (P00 < R): not
        applied, counted (``reference_revisited``). Sensors with a fix-bias state model this
        themselves."""
        if m.sensor in self.f.layout.fix:
            return False
        aux = self.f.aux
        key = (m.sensor, m.reference_id)
        if key in aux.used_refs and float(self.f.ekf.P[0, 0]) < R:
            counts.event(aux, "reference_revisited")
            return True
        return False

    def correction_unconfirmed(self, x_before, nis: float) -> None:
        """A fix whose innovation exceeds its expected size (NIS > 1) corrected the speed and
        error states by d = K nu, more than the model expected (K S K^T): the excess may be the
        error states' doing (the model's reading) or a one-off the model lacks (an undetected slip
        onset, a fix error beyond its stddev). The covariance keeps that excess,
        (1 - 1/NIS) d d^T, along d (innovation-based covariance matching, Mehra 1972), so one
        fix cannot make the filter sure of a speed re-calibration that only the next fix can
        confirm. The position, which the fix itself gives, is left as updated. Only for fixes of
        independent references (no fix-bias state): a stream of fixes (mm-wave, INPO) confirms
        or undoes a re-calibration milliseconds later."""
        d = (self.f.ekf.x - x_before)[:, 0]   # a new array: zeroing its position entry changes nothing else
        d[0] = 0.0
        self.f.ekf.P = self.f.ekf.P + (1.0 - 1.0 / nis) * np.outer(d, d)

    def initialise(self, m) -> tuple:
        """Claim the position from a fix. A fix of a sensor that can misread its reference (a
        balise telegram, a lug code) is only a candidate: the position is set when a fix of
        another reference agrees with it, moved by the dead reckoning since. Returns the effects
        on other policies (events.py)."""
        aux, cfg = self.f.aux, self.f.cfg
        if "misread" not in self.f.models[m.sensor].faults:
            # a reference that cannot be misidentified (wayside heads, loops, ranging): its decoder
            # withholds what it cannot tell (a miscounted axle, an unresolved NLOS)
            return self.set_position(m) + self.first_position(m.stamp)
        z, R, _, _ = self.f.measurement_of(m)
        x0, P00 = float(self.f.ekf.x[0, 0]), float(self.f.ekf.P[0, 0])
        cand = aux.candidate
        if cand is not None and m.stamp - cand.stamp <= cfg.branch_timeout:
            if m.reference_id == cand.reference and m.sensor == cand.sensor:
                return ()                            # the same reference confirms nothing
            if views.agrees(z, R, x0, P00, cand.z, cand.R, cand.s, cand.P00, self.f.limits.gates[m.sensor]):
                return self.set_position(m) + self.first_position(m.stamp)
            counts.event(aux, "candidate_replaced")
        aux.candidate = Candidate(m.stamp, z, R, x0, m.sensor, m.reference_id, P00)
        return ()

    def operator_position(self, stamp: float) -> None:
        """The operator set the position (``TrainFilter.reset``) at ``stamp`` [s]: the filter is
        initialised, located as by an accepted fix."""
        aux = self.f.aux
        aux.initialised = True
        aux.s_last_fix = float(self.f.ekf.x[0, 0])
        counts.in_use_from(aux, ("operator",), stamp)

    def first_position(self, stamp: float) -> tuple:
        """The position is claimed for the first time at ``stamp`` [s] (``Fixes.set_position`` has
        just taken it from a fix); the motion model's hypotheses from before take it (the effect
        returned: events.py)."""
        aux = self.f.aux
        aux.initialised = True
        aux.candidate = None
        return (FirstPosition(stamp),)

    def await_fix(self, reason: str, replace: bool = True) -> None:
        """The filter awaits a confirming fix for ``reason`` (an event name; DEGRADED until a fix is
        accepted: ``Fixes.fix_accepted``); ``replace`` False keeps an earlier reason."""
        aux = self.f.aux
        aux.unverified = reason if replace else (aux.unverified or reason)

    def set_position(self, m) -> tuple:
        """Take the position from a fix alone (first fix, re-acquisition): s = z - e. The sensors'
        own solutions start again from it: the effect returned (events.py)."""
        aux, cls = self.f.aux, m.sensor
        z, R, _, _ = self.f.measurement_of(m)
        x = self.f.ekf.x.copy()
        P = self.f.ekf.P.copy()
        P[0, :] = 0.0
        P[:, 0] = 0.0
        P[0, 0] = R
        x[0, 0] = z
        f_idx = self.f.layout.fix.get(cls)
        if f_idx is not None:   # s = z - e: its covariances are those of -e
            x[0, 0] -= x[f_idx, 0]
            P[0, :] = -P[f_idx, :]
            P[:, 0] = -P[:, f_idx]
            P[0, 0] = R + P[f_idx, f_idx]
        self.f.ekf.x, self.f.ekf.P = x, P
        self.f.bank.position_set_from_fix(
            f_idx, impact.FaultInput(cls, m.position_stddev, True) if cls in self.f.limits.offset_bounds else None)
        counts.accepted(aux, cls, m.stamp)
        aux.last_fix_accepted = m.stamp
        aux.s_last_fix = float(x[0, 0])
        # the sensors' own solutions and the lone source's start again from here
        return SeedSubs(m.stamp), LoneReset()

    def new_fix_bias(self, cls: str) -> None:
        """A new reference: its fix bias is independent of the previous one."""
        i = self.f.layout.fix[cls]
        x, P = self.f.ekf.x.copy(), self.f.ekf.P.copy()
        x[i, 0] = 0.0
        P[i, :] = 0.0
        P[:, i] = 0.0
        P[i, i] = self.f.layout.prior_sigma[i] ** 2
        self.f.ekf.x, self.f.ekf.P = x, P
        self.f.bank.states_set([i])

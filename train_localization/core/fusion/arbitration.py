"""Arbitration between disagreeing speed sources: the excluded sensor's view, its suspension, and
the fix that decides.

  arbitration a wheel slips only under traction and slides only under braking: a slip
              sensor's disagreement of another kind (it turns slower while the train
              accelerates, or any at a steady speed), and any of the radar, may be the other
              speed sources' fault. The filter still follows the majority view, but keeps the
              excluded sensor's distance as the alternative (the interval covers it, DEGRADED)
              (from its current separation to the farthest it reached: it may have slipped back
              since) and suspends the sensor: it is back only after agreeing for ``slip_window`` s
              without being applied (one reading that slips through the gate while the
              reference is quiet would be adopted at full weight). An absolute fix decides:
              if it agrees with the excluded sensor, the other speed sources are suspended
              until they agree again, the position is taken from the fix and the relative
              error states are re-learnt; if the filter explains it and the view does not, or
              far less well (likelihood ratio beyond the gate: a view wide with its own scale
              error), the sensor was faulty; if both explain it, the view is conditioned on
              the fix (it locates the train under either hypothesis) and, its sensor in use
              again, merged. An excluded or suspended sensor is only judged to agree again
              while the filter's speed rests on something else (another speed source, or fixes
              that give the speed better than the sensor's own noise), never on the motion
              model or a coasting alone; a suspended sensor's own scale and bias errors, no
              longer learnt, count as common to its readings in that test, and it agrees only
              where the fault it was suspended for would stand out of its noise (a radar scale
              fault agrees at standstill). A fix that only an
              excluded view explains overturns the filter only if a fix of another,
              independent reference agrees with it (not one of the same sensor with a fix-bias
              state: mm-wave fixes share stations), unless its sensor has no outlier fault mode.
  merge       an excluded sensor's view that stops being tracked (its episode ended with a
              separation its own errors explain) is merged into the position covariance.
"""
from __future__ import annotations

import math

from .component import Component
from ..sensors import faults as fault_modes
from . import counts
from .bookkeeping import Fault, Suspension, View, ViewSpeed, fault_at, is_coasting, speed_excluded, without_key
from . import views
from .events import (AwaitFix, EpisodeEnded, FaultEnded, OwnViewEnded, Relearn, RelearnFault, Separate, SetPosition,
                     SetSpeed, SlipWindow)
from .models import implied_speed
from . import separation


class Arbitration(Component):
    """Arbitration between disagreeing speed sources."""

    def decide_relative(self, m, z: float, R: float, hx: float, S: float, nis: float) -> tuple[bool, tuple]:
        """An absolute fix decides between the filter and the excluded sensors' views: (whether
        the fix was used for it (the position re-acquired), the effects on other policies:
        events.py). A fix that only an excluded view
        explains overturns the filter only if its sensor cannot produce outliers (NLOS,
        misread, miscount), or an unexplained fix of another reference agrees with it;
        otherwise it is kept as the unexplained alternative and the views stay undecided."""
        aux = self.f.aux
        gate = self.f.limits.gates[m.sensor]
        explained = nis <= gate
        keep, fitting, ruled_out, events, relearnt = {}, [], 0, (), set()
        for cls, alt in aux.relative_alternatives.items():
            D, var_D = views.alternative_spread(self.f.models[cls], alt)
            # the view's position: the filter's when it began (or was last located by a fix),
            # moved by its own sensor since; the filter's uncertainty from a coasting since is
            # not the view's
            S_v = min(S, R + alt.base) + var_D
            fits = (z - hx - D) ** 2 / S_v
            # -2 ln of the fix's likelihood under the view against under the filter: a view wide
            # with its own scale error still "fits" a precise fix that the filter explains far better
            worse = fits + math.log(S_v / S) - nis
            if fits <= gate and not (explained and worse > gate):
                # still explains the fix: undecided; where the filter takes the fix, the view takes
                # it too (it locates the train under either hypothesis): its separation and spread
                # conditioned on the fix, its scale error counted from here
                fitting.append((fits, cls))
                if nis > gate:
                    keep[cls] = alt
                    continue
                view = self.view_conditioned(alt, D, var_D, z - hx, S, R)
                if speed_excluded(aux, cls, m.stamp):
                    keep[cls] = view
                else:
                    # its sensor in use again and both located by the fix: merged (moment matching)
                    self.merge_view(view.separation ** 2 + view.white_var)
            elif explained or m.stamp - alt.since > self.f.cfg.branch_timeout:
                # the filter explains the fix and this excluded sensor's view does not (or far
                # worse): it was faulty
                counts.event(aux, "excluded_sensor_confirmed_faulty")
                ruled_out += 1
                if cls in self.f.layout.slip_sensors:
                    pass        # a slip ends by itself
                elif "scale_fault" in self.f.models[cls].faults and (
                        self.f.in_use(m.stamp, but=cls) or (relearnt & aux.speed_sources) - {cls}):
                    # a radar's scale fault, which the sources in use (shown right) can teach it (one
                    # relearnt above is in use from now: its episode's end is routed after this)
                    events += self.relearn_fault(cls)
                    relearnt.add(cls)
                else:                                      # a faulty radar may not recover
                    self.suspend(cls, self.view_fault(alt, m.stamp))
            else:
                keep[cls] = alt
        aux.relative_alternatives = keep
        if explained and ruled_out and len(fitting) == 1 and is_coasting(aux):
            # coasting between the excluded sensors, the fix rules out all views but one: that
            # sensor was right and is back (its view located by the fix merges into the filter's)
            cls = fitting[0][1]
            view = aux.relative_alternatives.pop(cls, None)
            aux.relative_alternatives = dict(aux.relative_alternatives)
            events += self.end_exclusion(cls, m.stamp)
            reading = aux.peer_speeds.get(cls)
            events += (SlipWindow(cls, None),)
            if reading is not None and reading.stamp > m.stamp - self.f.cfg.slip_reference_timeout:
                events += (SetSpeed([(reading.speed, reading.white_var + reading.common_var)]),)   # its speed, not the middle
            if view is not None:
                self.merge_view(view.separation ** 2 + view.white_var)
            counts.event(aux, "excluded_sensor_confirmed_right")
            return False, events
        if explained or not fitting:
            return False, events                   # the filter explains it, or nothing does
        if fault_modes.OUTLIER.intersection(self.f.models[m.sensor].faults) and not views.corroborated(
                m, z, R, aux.alternative, self.f.ekf.x, self.f.ekf.P, self.f.layout, self.f.cfg.branch_timeout,
                self.f.limits.gates[m.sensor]):
            return False, events
        # an excluded sensor was right: the other speed sources are faulty
        cls = min(fitting)[1]
        fault = self.view_fault(aux.relative_alternatives[cls], m.stamp)
        fault = None if fault is None else Fault(-fault.disagreement, fault.speed)   # the others ran behind it
        aux.relative_alternatives = {}
        events += self.end_exclusion(cls, m.stamp)
        for other in aux.speed_sources - {cls}:
            self.suspend(other, fault)
        return True, events + (SetPosition(m), Relearn("speed_source_faulty"))

    def swap(self, m, z: float, R: float, view: View, other: str) -> tuple:
        """The excluded sensor ``m.sensor`` was right and ``other``, the speed source in use, is
        faulty: the filter takes the excluded sensor's view (its separation D added to the
        position, the view's spread to the position variance, the speed from this reading), and
        ``other``'s view becomes the alternative (-D: where it puts the train) while it is
        suspended for the fault seen. The interval keeps covering both until a fix decides; the
        filter awaits one (DEGRADED: the effect on the fixes returned, events.py)."""
        aux, cls, stamp = self.f.aux, m.sensor, m.stamp
        D = view.separation
        var_D = views.alternative_spread(self.f.models[cls], view)[1]
        u, u_white, u_common = implied_speed(self.f.layout, self.f.ekf.x, self.f.ekf.P, m, z, R)
        x, P = self.f.ekf.x.copy(), self.f.ekf.P.copy()
        x[0, 0] += D
        P[0, 0] = max(P[0, 0], view.base + var_D)
        # its speed, a new error; the acceleration, which a scale error hardly changes, is kept
        x[1, 0] = u
        P[1, :] = 0.0
        P[:, 1] = 0.0
        P[1, 1] = u_white + u_common
        self.f.ekf.x, self.f.ekf.P = x, P
        self.f.bank.speed_set(u)
        aux.relative_alternatives = {**without_key(aux.relative_alternatives, cls),
                                     other: view._replace(separation=-D, farthest=-D)}
        aux.view_speeds = without_key(aux.view_speeds, cls)
        events = (OwnViewEnded(cls), SlipWindow(cls, None)) + self.end_exclusion(cls, stamp)
        self.suspend(other, self.view_fault(aux.relative_alternatives[other], stamp))
        counts.event(aux, "speed_sources_swapped")
        return events + (AwaitFix("speed_sources_swapped"),)

    def end_exclusion(self, cls: str, stamp: float) -> tuple:
        """Speed source ``cls`` found right by a fix: its suspension and its slip episode (the
        effect on the episodes returned: events.py) end, and it counts as in use from ``stamp`` (not
        as a sensor back from an episode that waits for a reference to agree with)."""
        aux = self.f.aux
        aux.suspended = without_key(aux.suspended, cls)
        counts.in_use_from(aux, (cls,), stamp)
        return (EpisodeEnded(cls, stamp),)

    def relearn_fault(self, cls: str) -> tuple:
        """Speed source ``cls`` has a scale fault that the others in use were shown not to have
        (``views.outlasted_by``, or a fix that the filter explains and its view does not): it is back
        in use, its constant scale opened by the fault's size (``scale_fault_sigma``) to learn
        the fault from them, and plausible up to that size. Suspended, it would never agree
        again, and would be no reference while the others' own faults come (a wheel's slide
        under braking would be seen against the motion model alone). The speed rests on the
        others: it keeps its variance. Returns the effects on the episodes (events.py)."""
        aux, lay = self.f.aux, self.f.layout
        i = lay.fault_scale[cls]
        floor = lay.prior_sigma[i] ** 2 + self.f.models[cls].scale_fault_sigma ** 2
        P = self.f.ekf.P
        if P[i, i] < floor:
            P = P.copy()
            r = math.sqrt(floor / P[i, i]) if P[i, i] > 0.0 else 0.0
            if r > 0.0:
                P[i, :] *= r
                P[:, i] *= r
            else:
                P[i, i] = floor
            self.f.ekf.P = P
        aux.scale_faults = aux.scale_faults | {cls}
        aux.view_speeds = without_key(aux.view_speeds, cls)
        events = (SlipWindow(cls, None),) + self.end_exclusion(cls, aux.t)
        counts.event(aux, "scale_fault_relearnt")
        return events

    def end_fault(self, cls: str) -> tuple:
        """The scale fault being learnt of speed source ``cls`` has ended: its constant scale back
        to its prior, its slip test's window started again (the effect on the episodes returned:
        events.py)."""
        aux, lay = self.f.aux, self.f.layout
        i = lay.fault_scale[cls]
        x, P = self.f.ekf.x.copy(), self.f.ekf.P.copy()
        x[i, 0] = 0.0
        P[i, :] = 0.0
        P[:, i] = 0.0
        P[i, i] = lay.prior_sigma[i] ** 2
        self.f.ekf.x, self.f.ekf.P = x, P
        self.f.bank.states_set([i])
        aux.scale_faults = aux.scale_faults - {cls}
        counts.event(aux, "scale_fault_ended")
        return (SlipWindow(cls, None),)

    def scale_faults_reset(self, keep) -> None:
        """The relative sensors' error states re-learnt from their priors (``Plausibility.relearn``):
        the scale faults being learnt end, but those of ``keep``."""
        aux = self.f.aux
        aux.scale_faults = aux.scale_faults & frozenset(keep)

    def merge_view(self, spread: float) -> None:
        """An excluded sensor's view no longer tracked of its own, merged into the filter's
        (``views.merged``) so the interval still covers it."""
        self.f.ekf.P = views.merged(self.f.ekf.P, spread)
        counts.event(self.f.aux, "alternative_merged")

    @staticmethod
    def view_conditioned(alt: View, D: float, var_D: float, nu: float, S: float, R: float) -> View:
        """An excluded sensor's view (separation D [m], variance var_D [m^2]) after a fix of
        innovation nu [m] and innovation variance S = A + R [m^2] that the filter applies: the
        view's position, predicted with variance A + var_D, and the filter's are both updated
        by the fix (scalar Kalman updates); the new separation and the difference of their
        posterior variances, and the filter's position variance after the fix (the view's base)."""
        A = max(S - R, 0.0)
        S_v = S + var_D
        D_new = D + (A + var_D) / S_v * (nu - D) - A / S * nu
        var_new = max(R * ((A + var_D) / S_v - A / S), 0.0)
        return View(D_new, var_new, alt.since, alt.last, 0.0, D_new, A * R / S if S > 0.0 else 0.0)

    def suspend(self, cls: str, fault: Fault | None) -> None:
        """Suspend speed source ``cls`` for the fault seen, or None if its size is not known, if
        its own error model explains it (within the slip gate of the spread its scale and bias
        priors give at that speed), or if the sensor has no persistent fault mode (a wheel: a
        slip or slide ends with the adhesion, and the others may have been the wrong ones): such
        a disagreement needs no proof of its absence before the sensor is back (a wheel that
        agrees at a standstill is back)."""
        persistent = "scale_fault" in self.f.models[cls].faults
        if fault is not None and (not persistent or
                                  fault.disagreement ** 2 <= self.f.limits.slip_gate * self.model_variance(cls, fault.speed)):
            fault = None
        self.f.aux.suspended = {**self.f.aux.suspended, cls: Suspension(math.inf, (), fault)}

    def suspensions_ended(self, sensors) -> None:
        """The speed is taken from ``sensors`` (``MotionViews.take_speed``): their suspensions end."""
        aux = self.f.aux
        aux.suspended = {c: v for c, v in aux.suspended.items() if c not in sensors}

    def undecided(self, cls: str, view: View) -> None:
        """Sensor ``cls``, excluded, may be the right one: its view kept as the undecided
        alternative until a fix decides."""
        aux = self.f.aux
        aux.relative_alternatives = {**aux.relative_alternatives, cls: view}

    def view_merged(self, cls: str) -> None:
        """Sensor ``cls``'s episode ended with a separation its own errors explain, merged into the
        position covariance (``Episodes.slipping``): its view is no longer tracked."""
        aux = self.f.aux
        aux.relative_alternatives = without_key(aux.relative_alternatives, cls)

    def view_dropped(self, cls: str) -> None:
        """Sensor ``cls`` gives the speed (``Episodes.refutes_model``): its view and last speed are
        no longer kept."""
        aux = self.f.aux
        aux.relative_alternatives = without_key(aux.relative_alternatives, cls)
        aux.view_speeds = without_key(aux.view_speeds, cls)

    def view_separates(self, m, e: float, S: float) -> None:
        """An excluded reading adds to its sensor's undecided view (``views.separated``), and is the
        speed it last read."""
        aux = self.f.aux
        v = float(self.f.ekf.x[1, 0])
        view, R = views.separated(aux.relative_alternatives[m.sensor], m, e, S, v, float(self.f.ekf.P[1, 1]))
        aux.view_speeds = {**aux.view_speeds, m.sensor: ViewSpeed(m.stamp, v + e, R)}
        aux.relative_alternatives = {**aux.relative_alternatives, m.sensor: view}

    def suspended(self, m, e: float, S: float, nis: float, common: float) -> tuple[bool, tuple]:
        """A speed source found or suspected faulty: excluded until it agrees again (neither its
        single nor its windowed disagreement test fires, with a reference to judge it by) for
        ``slip_window`` s, in a window where the fault seen would have shown (``Arbitration.would_show``).
        Returns (whether the reading is excluded, the effects on the episodes: events.py)."""
        aux, gate = self.f.aux, self.f.limits.slip_gate
        held = aux.suspended[m.sensor]
        since, fault = held.since, held.fault
        window, summed = views.windowed(held.window, m, e, S, self.f.cfg.slip_window, abs(float(self.f.ekf.x[1, 0])),
                                        common)
        disagrees = nis > gate or summed > gate
        if disagrees and m.sensor in aux.scale_faults and views.fault_ended_shown(
                m.sensor, self.f.layout, self.f.ekf.x, self.f.ekf.P, self.f.measurement_of(m)[2], e, S, gate):
            # judged from its next reading on, at the scale without the fault
            aux.suspended = {**aux.suspended, m.sensor: Suspension(math.inf, (), fault)}
            counts.gated(aux, m.sensor + "/suspended")
            return True, (FaultEnded(m.sensor), Separate(m, e, S))
        if disagrees and views.outlasted_by(m, aux, self.f.models, self.f.in_use(m.stamp, but=m.sensor),
                                            self.f.limits.bounded, self.f.cfg.slip_window):
            aux.relative_alternatives = without_key(aux.relative_alternatives, m.sensor)
            counts.event(aux, "fault_outlasted_the_others")
            return False, (RelearnFault(m.sensor),)
        if disagrees or not self.f.agreement_reference(m, S):
            since = math.inf
        elif since == math.inf:
            since = m.stamp
        if since != math.inf and m.stamp - since >= self.f.cfg.slip_window and self.would_show(fault, window):
            aux.suspended = without_key(aux.suspended, m.sensor)
            counts.event(aux, "speed_source_restored")
            # its readings of the agreement so far are the slip test's window from here
            return False, (SlipWindow(m.sensor, window),)
        aux.suspended = {**aux.suspended, m.sensor: Suspension(since, window, fault)}
        counts.gated(aux, m.sensor + "/suspended")
        return True, (Separate(m, e, S),)

    def would_show(self, fault: Fault | None, window: tuple) -> bool:
        """Whether the fault a sensor was suspended for, had it persisted, would stand out of the
        readings' white noise over ``window`` (noncentrality of the summed disagreement at least
        the slip gate, as when it was seen in use): agreement proves nothing where the fault
        cannot show. The fault seen, e0 at speed v0, may be a scale error (e0 v / v0) or a bias
        (e0); the smaller of the two at each reading's speed v counts. A radar reading 6 % low
        agrees at standstill."""
        if fault is None or len(window) < 3:
            return fault is None
        shown = sum(w.weight * fault_at(fault, w.speed) for w in window)
        return shown * shown >= self.f.limits.slip_gate * sum(w.white_var for w in window)

    def model_variance(self, cls: str, speed: float) -> float:
        """The variance [m^2/s^2] of relative sensor ``cls``'s reading at ``speed`` [m/s] that its
        error model's scale and bias priors allow."""
        lay, sigma = self.f.layout, self.f.layout.prior_sigma
        scale = sum(sigma[table[cls]] ** 2 for table in (lay.scale, lay.offset) if cls in table)
        bias = sigma[lay.bias[cls]] ** 2 if cls in lay.bias else 0.0
        return scale * speed * speed + bias

    @staticmethod
    def view_fault(alt: View, stamp: float) -> Fault | None:
        """The fault an excluded sensor's view shows: its mean disagreement [m/s] at the mean
        speed [m/s] since the view began."""
        dt = stamp - alt.since
        return Fault(alt.separation / dt, alt.run / dt) if dt > 0.0 else None

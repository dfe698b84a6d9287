"""Fault episodes of the relative sensors (slip, slide, radar scale faults): the tests that start
and end them.

  episodes    (slip, slide, radar scale faults) an increment or speed of a relative sensor
              with such fault modes that disagrees
              (NIS above ``slip_gate_probability``), or whose innovations summed over
              ``slip_window`` s disagree (a slip too small to show in one increment:
              low speed, slow onset), while another speed source was accepted recently,
              starts an episode: the sensor is excluded until ``slip_holdoff`` s after
              its last disagreement. The increments just before that already disagreed
              the same way (the onset of the slip) are excluded after the fact and the
              history re-applied without them, so the slip is not carried in the speed
              and scale states.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.stats import chi2

from .component import Component
from ..sensors import faults as fault_modes
from . import counts
from .bookkeeping import Fault, FaultWindow, is_coasting, new_view, without_key
from . import views
from .events import (CommonErrorEnded, FaultEnded, Separate, Suspend, Swap, TakeSpeed, Undecided, ViewDropped,
                     ViewMerged, ViewSeparates)
from .models import implied_speed


class Lookback(Exception):
    """Raised inside an update: exclude ``sensor``'s measurements from ``since`` and re-apply."""

    def __init__(self, sensor: str, since: float, shown: float):
        super().__init__(sensor)
        self.sensor, self.since, self.shown = sensor, since, shown


class Episodes(Component):
    """Fault episodes of the relative sensors."""

    def slipping(self, m, e: float, S: float, nis: float) -> tuple[bool, tuple]:
        """Slip/slide check of one increment: (whether it is excluded, the effects on other
        policies: events.py)."""
        aux, cfg, cls = self.f.aux, self.f.cfg, m.sensor
        alt = aux.relative_alternatives.get(cls)
        # excluded (a view of its own, or an episode) and not accepted since, and nothing to show
        # that it agrees again: the filter's speed rests on the motion model or on a coasting
        # between excluded sources (its holdoff may have passed without a measurement: a dropout)
        accepted = aux.last_accepted.get(cls, -math.inf)
        out = (alt is not None and accepted < alt.since) or \
            accepted < aux.slip_until.get(cls, -math.inf) - cfg.slip_holdoff
        undecided = out and not self.f.agreement_reference(m, S)
        if aux.slip_until.get(cls, -math.inf) > m.stamp or undecided:
            # still slipping, or undecided
            if nis > self.f.limits.slip_gate or undecided:
                aux.slip_until = {**aux.slip_until, cls: m.stamp + cfg.slip_holdoff}
            counts.gated(aux, cls + "/slip")
            return True, (Separate(m, e, S),)
        merged = ()
        if alt is not None and alt.farthest ** 2 <= self.f.limits.slip_gate * views.alternative_spread(self.f.models[cls], alt)[1]:
            # the episode ended with a separation that the sensor's own errors explain: no longer
            # tracked as a view of its own (the arbitration's), but merged into the position
            # covariance (moment matching of the two views, the filter's mean kept), so the
            # interval still covers it
            merged = (ViewMerged(cls),)
            self.f.ekf.P = views.merged(self.f.ekf.P, alt.farthest ** 2)
            counts.event(aux, "alternative_merged")
        window, summed = views.windowed(aux.slip_window.get(cls, ()), m, e, S, cfg.slip_window,
                                        abs(float(self.f.ekf.x[1, 0])))
        if (nis > self.f.limits.slip_gate or summed > self.f.limits.slip_gate) and not views.judged(cls, self.f.layout, self.f.models, cfg.policies):
            # the only speed source, without slip physics (``views.judged``): an outlying reading is
            # gated; a fault that persists is the lone solution's to cover (``LoneSource.track``) and
            # the fix drift test's to find (``Fixes.fix_bias_consistency``)
            aux.slip_window = {**aux.slip_window, cls: ()}
            if nis > self.f.limits.slip_gate:
                counts.gated(aux, cls)
                return True, merged
            return False, merged
        if nis > self.f.limits.slip_gate or summed > self.f.limits.slip_gate:
            aux.slip_window = {**aux.slip_window, cls: ()}
            # the disagreement that showed: this one, or the window's mean
            shown = e if nis > self.f.limits.slip_gate else sum(w.distance for w in window) / sum(w.weight for w in window)
            if cls in aux.scale_faults and self.fault_ended(m, e, S):
                return False, merged + (FaultEnded(cls),)
            refuted = self.refutes_model(m, shown)
            if refuted is not None:
                return False, merged + refuted
            # the onset: the increments before this one that already disagreed the same way were
            # absorbed (a slip ramps up): take them out and re-apply the history without them
            k = len(window) - 1
            while k > 0 and (window[k - 1].distance > 0.0) == (e > 0.0):
                k -= 1
            if k < len(window) - 1:
                raise Lookback(cls, window[k].stamp, shown)
            events = self.episode_starts(m, e, shown, alt is not None and not merged)
            aux.slip_until = {**aux.slip_until, cls: m.stamp + cfg.slip_holdoff}
            counts.gated(aux, cls + "/slip")
            return True, merged + events + (Separate(m, e, S),)
        aux.slip_window = {**aux.slip_window, cls: window}
        if out and len(window) < 3:
            # back from an episode: its first readings are judged together before one is applied
            # (a slide that goes on passes one reading's test while the reference is noisy, and
            # the precise sensor would be adopted at full weight)
            counts.gated(aux, cls + "/slip")
            return True, merged + (Separate(m, e, S),)
        return False, merged

    def slip_physics(self, cls: str, e: float) -> bool:
        """Whether sensor ``cls``'s own fault modes can give a disagreement e [m/s] with the
        filter's speed under the filter's drive (its acceleration along the motion): a wheel
        slips only under traction (it turns faster) and slides only under braking (slower),
        with at least ``slip_min_drive``."""
        faults = self.f.models[cls].faults
        v, a = float(self.f.ekf.x[1, 0]), float(self.f.ekf.x[2, 0])
        sv = 1.0 if v >= 0.0 else -1.0
        drive, excess, limit = a * sv, e * sv, self.f.cfg.slip_min_drive
        return ("slip" in faults and drive >= limit and excess > 0.0) or \
            ("slide" in faults and drive <= -limit and excess < 0.0)

    def refutes_model(self, m, e: float) -> tuple | None:
        """Slip sensor ``m.sensor``, with no other speed source in use, disagrees with the filter's
        speed (the motion model's, since nothing else measures it) by e [m/s] in a way its own
        fault modes cannot produce under the filter's drive: slower under traction (a driven
        wheel only slips, reading fast), faster under braking (a braked wheel only slides),
        either way with less drive than ``slip_min_drive``. Then the motion model is what is
        wrong (an acceleration that ended, a braking that eased): the speed is taken from the
        sensor, the acceleration back to its prior, its exclusion ends, and the motion model's
        hypothesis stays in the interval until the sensor's longest episode has passed and
        after, until a fix rules it out (``MotionViews.take_speed``: if the drive was misjudged, the truth
        lies between the two). If so, the effect on the motion views (events.py), else None."""
        cls, aux = m.sensor, self.f.aux
        if not fault_modes.ADHESION & set(self.f.models[cls].faults) or self.f.reference_ok(m) \
                or self.slip_physics(cls, e):
            return None
        z, R, _, _ = self.f.measurement_of(m)
        u, white, common = implied_speed(self.f.layout, self.f.ekf.x, self.f.ekf.P, m, z, R)
        aux.episode_views = without_key(aux.episode_views, cls)
        counts.event(aux, "motion_model_refuted")
        return ViewDropped(cls), TakeSpeed(m.stamp, [(u, white + common)], {cls})

    def fault_ended(self, m, e: float, S: float) -> bool:
        """Whether sensor ``m.sensor``, whose scale fault is being learnt (``Arbitration.relearn_fault``),
        disagreeing by e [m/s] (innovation variance S), shows that its fault has ended
        (``views.fault_ended_shown``; then ``Arbitration.end_fault``)."""
        h = self.f.measurement_of(m)[2]
        return views.fault_ended_shown(m.sensor, self.f.layout, self.f.ekf.x, self.f.ekf.P, h, e, S,
                                       self.f.limits.slip_gate)

    def common(self, cls: str, h) -> float:
        """The part [m^2/s^2] of a relative measurement's innovation variance that its sensor's
        own error states (scale, offset, bias) contribute: h_k P_kk h_k over their indices."""
        idx = self.f.layout.own_states.get(cls)
        if idx is None:
            return 0.0
        hk = h[idx]
        return max(float(hk.dot(self.f.ekf.P[np.ix_(idx, idx)]).dot(hk)), 0.0)

    def episode_starts(self, m, e: float, shown: float, undecided: bool) -> tuple:
        """A fault episode of ``m.sensor`` starts with the disagreement e [m/s] (``shown``: the
        disagreement the test saw, e or its mean over the window; ``undecided``: whether the sensor
        has an undecided view, the arbitration's, already). A wheel slips
        only under traction (it turns faster) and slides only under braking (slower); a
        disagreement of another kind, or of a sensor without slip physics (the radar), may
        be the other speed sources' fault: then the sensor's own view is kept as the
        alternative until an absolute fix decides, and the sensor suspended (the effect on the
        arbitration returned: events.py)."""
        aux = self.f.aux
        aux.slips += 1
        # without another speed source the disagreement is with the motion model alone
        physical = self.slip_physics(m.sensor, e) and self.f.reference_ok(m)
        view = new_view(m.stamp, float(self.f.ekf.P[0, 0]))
        if physical and m.sensor not in aux.episode_views and m.sensor in self.f.limits.bounded:
            aux.episode_views = {**aux.episode_views, m.sensor: view}   # its own fault: not in the interval
        events = ()
        if not physical and not undecided:
            events = (Undecided(m.sensor, view),)
            aux.episode_views = without_key(aux.episode_views, m.sensor)
            counts.event(aux, "ambiguous_slip")
        if not physical and m.sensor not in aux.suspended:
            # suspected faulty: back only after agreeing for slip_window s without being applied
            # (one reading that slips through the gate would be adopted at full weight)
            return events + (Suspend(m.sensor, Fault(shown, float(self.f.ekf.x[1, 0]))),)
        return events

    def separate(self, m, e: float, S: float) -> tuple:
        """An excluded reading adds to its sensor's view (``views.separated``): its own (a slip's:
        ``episode_views``) here; an undecided one is the arbitration's (the effect returned:
        events.py)."""
        aux = self.f.aux
        if m.sensor in aux.relative_alternatives:
            return (ViewSeparates(m, e, S),)
        own = aux.episode_views.get(m.sensor)
        if own is not None:
            view, _ = views.separated(own, m, e, S, float(self.f.ekf.x[1, 0]), float(self.f.ekf.P[1, 1]))
            aux.episode_views = {**aux.episode_views, m.sensor: view}
        return ()

    def own_view_ended(self, cls: str, fault_window: bool = True) -> None:
        """Sensor ``cls``'s own view ends (it is accepted, or its view becomes undecided), and with
        ``fault_window`` the fit of the other source's scale error to it (``Episodes.outlasted``)."""
        aux = self.f.aux
        if cls in aux.episode_views:
            aux.episode_views = without_key(aux.episode_views, cls)
        if fault_window and cls in aux.fault_windows:
            aux.fault_windows = without_key(aux.fault_windows, cls)

    def episode_ended(self, cls: str, stamp: float) -> None:
        """A fix found speed source ``cls`` right: its slip episode ends at ``stamp`` [s]."""
        aux = self.f.aux
        aux.slip_until = {**aux.slip_until, cls: stamp}

    def episodes_ended(self, stamp: float, sensors) -> None:
        """The speed is taken from ``sensors`` at ``stamp`` [s]: their slip episodes end, their slip
        tests' windows start again."""
        aux = self.f.aux
        aux.slip_until = {c: (min(t, stamp) if c in sensors else t) for c, t in aux.slip_until.items()}
        aux.slip_window = {c: w for c, w in aux.slip_window.items() if c not in sensors}

    def set_window(self, cls: str, window: tuple | None) -> None:
        """The slip test's window of ``cls`` from here (None: it starts again)."""
        aux = self.f.aux
        aux.slip_window = without_key(aux.slip_window, cls) if window is None else {**aux.slip_window, cls: window}

    def outlasted(self, m, z: float, R: float, hx: float, S: float, h) -> tuple:
        """Sensor ``m.sensor``, excluded, whose fault modes all end by themselves (a wheel's slip
        or slide, at most ``fault_duration_max`` s): if it has been excluded for longer and it
        still disagrees (its disagreements summed over ``slip_window`` s, its own error states
        common to them), its fault modes no longer explain the disagreement. The other side is
        one speed source with a persistent fault mode (a radar scale fault): the one in use,
        alone (the disagreement is the innovation), or, while the filter coasts between the
        two, the other excluded one (the disagreement is the difference of their readings).
        If the disagreement since fits one scale error of that source (weighted least squares
        of the disagreements against the speed, the residual inside the chi-square quantile of
        ``slip_gate_probability``: back-to-back slips of different ratios do not), that one is
        the faulty one: the two swap roles (``Arbitration.swap``), or the coasting ends on this sensor
        (``Episodes.coast_outlasted``). With more sources in use the majority stands. Returns
        the effects on the arbitration and the motion views (events.py)."""
        aux, cls, stamp = self.f.aux, m.sensor, m.stamp
        view = aux.relative_alternatives.get(cls) or aux.episode_views.get(cls)
        recent = stamp - self.f.cfg.slip_reference_timeout
        in_use = self.f.in_use(stamp, but=cls)
        peers = [c for c, p in aux.peer_speeds.items() if c != cls and p.stamp > recent]
        other = None
        if view is not None and len(in_use) == 1:
            other, e, v, var, common = in_use[0], z - hx, float(self.f.ekf.x[1, 0]), S, self.common(cls, h)
        elif view is not None and not in_use and is_coasting(aux) and len(peers) == 1 and cls in aux.peer_speeds:
            other = peers[0]
            own, peer = aux.peer_speeds[cls], aux.peer_speeds[other]
            v = peer.speed
            e, common = own.speed - v, own.common_var + peer.common_var
            var = own.white_var + peer.white_var + common
        if other is None or "scale_fault" not in self.f.models[other].faults:
            # the evidence counts only while it is one source with a persistent fault mode
            if cls in aux.fault_windows:
                aux.fault_windows = without_key(aux.fault_windows, cls)
            return ()
        record = aux.fault_windows.get(cls)
        if record is None or record.against != (other, bool(in_use)):
            record = FaultWindow((other, bool(in_use)), stamp, (), 0, 0.0, 0.0, 0.0)
        window, summed = views.windowed(record.window, m, e, var, self.f.cfg.slip_window,
                                        abs(float(self.f.ekf.x[1, 0])), common)
        record = record._replace(window=window, n=record.n + 1, sum_ev=record.sum_ev + e * v / var,
                                 sum_vv=record.sum_vv + v * v / var, sum_ee=record.sum_ee + e * e / var)
        aux.fault_windows = {**aux.fault_windows, cls: record}
        n, s_ev, s_vv = record.n, record.sum_ev, record.sum_vv
        # the whole window past the longest episode the sensor's model allows
        if summed <= self.f.limits.slip_gate or n < 3 or s_vv <= 0.0 or \
                stamp - self.f.cfg.slip_window - record.since <= self.f.models[cls].fault_duration_max:
            return ()
        # a scale error of the other source is one ratio throughout; a chain of slips is not
        # (their ratios differ, and each ramps down to none): the residual of that fit
        if record.sum_ee - s_ev * s_ev / s_vv <= chi2.ppf(self.f.cfg.slip_gate_probability, n - 1):
            if in_use:
                return (Swap(m, z, R, view, other),)
            return self.coast_outlasted(m, other, e, v)
        return ()

    def coast_outlasted(self, m, other: str, e: float, v: float) -> tuple:
        """The filter coasts between excluded ``m.sensor`` and ``other``, and the disagreement
        e [m/s] (at speed v [m/s]) has outlasted ``m.sensor``'s transient fault modes: the
        speed is taken from ``m.sensor``'s reading (its exclusion ends, as a re-acquisition)
        and ``other`` stays suspended for the fault seen. Both sensors' views stay in the
        interval until a fix decides, and so does the coasting's motion-model hypothesis (both
        may have been wrong the same way while it lasted), moving with the filter from here:
        ``m.sensor``'s fault cannot go on, so it shares no error with it from now on. The
        filter awaits a fix (DEGRADED). Returns the effects on the arbitration and the motion
        views (events.py)."""
        aux, cls, stamp = self.f.aux, m.sensor, m.stamp
        own = aux.peer_speeds[cls]
        events = (Suspend(other, Fault(-e, v)),) if other not in aux.suspended else ()
        aux.fault_windows = without_key(aux.fault_windows, cls)
        counts.event(aux, "transient_fault_outlasted")
        return events + (TakeSpeed(stamp, [(own.speed, own.white_var + own.common_var)], {cls}), CommonErrorEnded())

    def excluded(self, m, shown: float) -> tuple:
        """Apply a measurement that a fault check excluded after the fact (a slip's onset), the
        check having seen a disagreement of ``shown`` [m/s]; the effects on other policies
        returned (events.py)."""
        aux = self.f.aux = self.f.aux.copy()
        self.f.predict_to(m.stamp)
        cls = m.sensor
        z, R, h, hx, _, S = self.f.innovation(m)
        events = ()
        if not aux.slip_until.get(cls, -math.inf) > m.stamp:
            events = self.episode_starts(m, z - hx, shown, cls in aux.relative_alternatives)
            counts.event(aux, "slip_lookback")
        aux.slip_until = {**aux.slip_until, cls: m.stamp + self.f.cfg.slip_holdoff}
        aux.slip_window = {**aux.slip_window, cls: ()}
        counts.gated(aux, cls + "/slip")
        return events + (Separate(m, z - hx, S),)

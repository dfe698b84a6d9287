"""The motion model's own hypotheses: coasting between disagreeing speed sources, and a speed given
back while every source is excluded (blind).

  blind       every speed source excluded at once and the speed resting on the motion model
              alone: two excluded sources that agree with each other (reading by reading and
              in their mean) for ``slip_window`` s give the speed back; their views stay in
              the interval until a fix decides. A sensor whose view is undecided stays
              excluded while nothing can show that it agrees, also after a dropout.
  coasting    excluded sources that disagree: once the motion model knows the speed worse
              than the middle of their readings does, the filter coasts on that middle
              (not on the last acceleration). The motion model's own hypothesis from the
              start of the coasting stays in the interval (both sources may be wrong the same
              way) until a fix rules it out or, the filter back on its speed sources, a fix
              confirms the filter. After the coasting (or a re-acquisition from the motion
              model alone) it moves with the filter, its distance scaled by the scale error
              the sources back in use may share (a radar scale fault as large as a wheel's
              slide agrees with it): estimated from the motion model's speed against theirs
              with the smallest scale-fault prior among them, until the shortest of their
              transient faults must have ended. A fix the filter accepts locates the train
              under that hypothesis too: it is conditioned on the fix.
"""
from __future__ import annotations

import math

from .component import Component
from ..sensors import faults as fault_modes
from . import counts
from .bookkeeping import (MAX_MOTION_VIEWS, Fault, ModelView, MovedView, PeerRun, PeerSpeed, fault_at,
                          is_coasting, speed_excluded)
from . import views
from .events import AwaitFix, EpisodesEnded, SuspensionsEnded
from .models import implied_speed, kinematics


def _shows(fault: Fault | None, speed: float, variance: float, gate: float) -> bool:
    """Whether a fault (``fault_at``) at ``speed`` [m/s] stands out of a test statistic of
    ``variance`` [m^2/s^2] at the chi-square ``gate``; None (size unknown) counts as shown."""
    if fault is None:
        return True
    e = fault_at(fault, speed)
    return e * e >= gate * variance


class MotionViews(Component):
    """The motion model's own hypotheses."""

    def coast(self, stamp: float, readings: list) -> tuple | None:
        """The excluded speed sources disagree: one of them, or both, is wrong. Once the motion
        model knows the speed worse than the middle of their readings does (its variance beyond
        the squared half-range: it runs away with the last acceleration, a braking that ended,
        a reversal through a standstill), the filter coasts on that middle instead. The interval
        keeps every hypothesis: each sensor's view, and the motion model's own from the start
        of the coasting (both sensors may be wrong the same way, a radar scale fault during a
        wheel slip under traction). If the speed was set, the effect on the fixes (events.py),
        else None."""
        aux = self.f.aux
        coasting = is_coasting(aux)
        half_range = 0.5 * (max(u for u, _ in readings) - min(u for u, _ in readings))
        if not coasting and float(self.f.ekf.P[1, 1]) <= half_range * half_range:
            return None                     # a short slip: the motion model still knows better
        events = ()
        if not coasting:
            aux.motion_views = aux.motion_views[-(MAX_MOTION_VIEWS - 1):] + (views.model_view(stamp, self.f.ekf.x, self.f.ekf.P),)
            counts.event(aux, "coasting_between_speed_sources")
            events = (AwaitFix("speed_sources_disagree", replace=False),)
        self.set_speed(readings, middle=True)
        return events

    def coasting_ended(self, view: ModelView, stamp: float, back=frozenset()) -> MovedView:
        """The motion-model hypothesis of a coasting that ends at ``stamp`` [s], as it moves with
        the filter from here. The speed sources back in use were excluded for faults; that they
        now agree does not prove both right: a radar scale fault and a wheel slide of the same
        size agree. Under that hypothesis their common error persists as a scale error r
        (a slip ratio, a scale fault) until the shortest of their transient fault modes must
        have ended: r from the motion model's speed against theirs, combined with the prior of
        the smallest scale fault among them (a sensor without a speed fault mode rules the
        hypothesis out: r = 0). ``back``: sources whose exclusions end now (their end is routed
        after: events.py)."""
        s_m, v_m, _, var_m, var_v = kinematics(view.s, view.v, view.a, view.cov, max(stamp - view.stamp, 0.0),
                                               self.f.cfg.jerk_psd)
        s_f, v_f = float(self.f.ekf.x[0, 0]), float(self.f.ekf.x[1, 0])
        aux = self.f.aux
        in_use = [c for c in aux.speed_sources if c in back or not speed_excluded(aux, c, stamp)]
        models = [self.f.models[c] for c in in_use]
        r, var_r, until = 0.0, 0.0, math.inf
        if models and all(set(md.faults) & fault_modes.SPEED for md in models):
            # measured: r = (v_m - v_f) / v_f of variance var_v / v_f^2; prior N(0, prior)
            prior = min((md.scale_fault_sigma ** 2 for md in models if "scale_fault" in md.faults), default=math.inf)
            var_v = max(var_v, 1e-12)
            info = v_f * v_f / var_v + (1.0 / prior if prior > 0.0 else math.inf)
            var_r = 1.0 / info if info > 0.0 else math.inf
            r = var_r * (v_m - v_f) * v_f / var_v if math.isfinite(var_r) else 0.0
            until = stamp + min(md.fault_duration_max for md in models)
        return MovedView(s_m, var_m, s_f, float(self.f.ekf.P[0, 0]), r, var_r, until)

    def peer_run(self, cls: str, stamp: float, u: float, white: float, common: float,
                 peers: dict) -> str | None:
        """Extend the run of agreement of ``cls`` with an excluded peer: each reading inside the
        slip gate of the pair's variance, and their mean difference inside the slip gate of its
        own (white parts averaged, common parts not). The peer once it has lasted ``slip_window`` s,
        and only if the fault each of the two was suspended for would stand out of that mean
        difference's spread (``_shows``): two sources whose common errors are wider than a radar's
        scale fault "agree" with a slipping wheel as well."""
        aux, cfg, gate = self.f.aux, self.f.cfg, self.f.limits.slip_gate
        run = aux.peer_run
        fits = [c for c, p in peers.items()
                if (u - p.speed) ** 2 <= gate * (white + common + p.white_var + p.common_var)]
        if not fits:
            aux.peer_run = None
            return None
        pairs = {tuple(sorted((cls, c))): c for c in fits}
        pair = run.pair if run is not None and run.pair in pairs else next(iter(pairs))
        if run is None or run.pair != pair or run.last < stamp - cfg.slip_reference_timeout:
            run = PeerRun(pair, stamp, stamp, 0, 0.0, 0.0)
        p = peers[pairs[pair]]
        d = (u - p.speed) if pair[0] == cls else (p.speed - u)
        n, sum_d, sum_white = run.n + 1, run.sum_diff + d, run.sum_white + white + p.white_var
        if (sum_d / n) ** 2 > gate * (sum_white / (n * n) + common + p.common_var):
            aux.peer_run = None
            return None
        aux.peer_run = PeerRun(pair, run.first, stamp, n, sum_d, sum_white)
        if stamp - run.first < cfg.slip_window:
            return None
        spread = sum_white / (n * n) + common + p.common_var
        faults = [aux.suspended[c].fault for c in pair if c in aux.suspended]
        return pairs[pair] if all(_shows(f, u, spread, gate) for f in faults) else None

    def set_speed(self, readings: list, middle: bool = False) -> None:
        """Speed from readings [(speed, variance)]: their weighted mean (``middle``: the middle
        of their range), the largest distance to a reading added to its variance; the
        acceleration back to its prior. Agreeing readings (a re-acquisition) give a speed
        whose error is new: uncorrelated with the rest. The middle of disagreeing ones (a
        coasting) keeps the error it had, of the faults that persist while it lasts: its
        correlations are kept, rescaled to the new variance (a congruence, so P stays positive
        semi-definite), and the position variance grows with the square of the time, not as a
        sum of independent speed errors."""
        weights = [1.0 / v for _, v in readings]
        if middle:
            u_hat = 0.5 * (min(u for u, _ in readings) + max(u for u, _ in readings))
        else:
            u_hat = sum(w * u for w, (u, _) in zip(weights, readings)) / sum(weights)
        spread = max(abs(u - u_hat) for u, _ in readings)
        var = 1.0 / sum(weights) + spread * spread
        x, P = self.f.ekf.x.copy(), self.f.ekf.P.copy()
        if middle and P[1, 1] > 0.0:
            scale = math.sqrt(var / P[1, 1])
            P[1, :] *= scale
            P[:, 1] *= scale
        else:
            P[1, :] = 0.0
            P[:, 1] = 0.0
        P[2, :] = 0.0
        P[:, 2] = 0.0
        x[1, 0], P[1, 1] = u_hat, var
        x[2, 0], P[2, 2] = 0.0, self.f.cfg.initial_accel_stddev ** 2
        self.f.ekf.x, self.f.ekf.P = x, P
        self.f.bank.speed_set(u_hat)

    def take_speed(self, stamp: float, readings: list, sensors: set) -> tuple:
        """Speed from independent readings that agree (weighted); the exclusions of ``sensors``
        end. Returns the effects on the other policies (events.py)."""
        aux = self.f.aux
        coasting = is_coasting(aux)
        # the motion model's hypothesis: of the coasting, or the filter's own until now (its speed
        # rested on the motion model alone)
        view = aux.motion_views[-1] if coasting else views.model_view(stamp, self.f.ekf.x, self.f.ekf.P)
        self.set_speed(readings)
        counts.in_use_from(aux, sensors, stamp)
        aux.peer_speeds, aux.peer_run = {}, None
        moved = self.coasting_ended(view, stamp, back=sensors)
        if coasting or moved.var_r > 0.0:
            kept = aux.motion_views[:-1] if coasting else aux.motion_views[-(MAX_MOTION_VIEWS - 1):]
            aux.motion_views = kept + (moved,)
        counts.event(aux, "speed_reacquired")
        return SuspensionsEnded(sensors), EpisodesEnded(stamp, sensors), AwaitFix("speed_reacquired")

    def move(self, stamp: float) -> None:
        """The hypotheses that move with the filter from a reading at ``stamp`` [s] on: a coasting's
        once a speed source is in use again (``coasting_ended``), and a moved one's common error
        once past the longest episode of a transient fault the sources in use may share."""
        aux = self.f.aux
        if is_coasting(aux) and not all(speed_excluded(aux, c, stamp) for c in aux.speed_sources):
            # a speed source is in use again: the coasting ends, its motion-model hypothesis moves
            # with the filter from now on until a fix rules it out
            aux.motion_views = aux.motion_views[:-1] + (self.coasting_ended(aux.motion_views[-1], stamp),)
        if any(isinstance(v, MovedView) and v.until <= stamp for v in aux.motion_views):
            # past the longest episode of a transient fault the sources in use may share: their
            # common error no longer grows; the hypothesis moves with the filter from here
            s_f, P00 = float(self.f.ekf.x[0, 0]), float(self.f.ekf.P[0, 0])
            aux.motion_views = tuple(
                MovedView(*views.motion_view(v, stamp, s_f, P00, self.f.cfg.jerk_psd), s_f, P00, 0.0, 0.0, math.inf)
                if isinstance(v, MovedView) and v.until <= stamp else v for v in aux.motion_views)

    def rule_out(self, stamp: float, z: float, R: float, gate: float) -> None:
        """A fix at ``stamp`` [s] (z [m], variance R [m^2]) rules out the hypotheses it does not fit
        within ``gate`` (its NIS gate)."""
        aux = self.f.aux
        s_f, P00 = float(self.f.ekf.x[0, 0]), float(self.f.ekf.P[0, 0])
        aux.motion_views = tuple(view for view in aux.motion_views
                                 if (z - (mv := views.motion_view(view, stamp, s_f, P00, self.f.cfg.jerk_psd))[0]) ** 2
                                 / (R + mv[1]) <= gate)

    def confirmed(self) -> None:
        """A fix the filter explains on its speed sources again confirms it: the hypotheses that
        move with it (however vague) are no longer needed."""
        aux = self.f.aux
        if any(isinstance(v, MovedView) for v in aux.motion_views):
            aux.motion_views = tuple(v for v in aux.motion_views if not isinstance(v, MovedView))

    def first_position(self, stamp: float) -> None:
        """The position is claimed for the first time at ``stamp`` [s]. The hypotheses of coastings
        before it were kept in the frame of the dead reckoning from the start; the fix locates the
        train under each of them: a moved one adds nothing more and is dropped, a coasting in
        progress keeps its speed and acceleration hypothesis and takes the filter's position."""
        aux = self.f.aux
        kept = []
        for view in aux.motion_views:
            if isinstance(view, ModelView):
                x, P = views.model_view_at(view, stamp, self.f.process)
                kept.append(ModelView(stamp, float(self.f.ekf.x[0, 0]), float(x[1]), float(x[2]),
                                       (float(self.f.ekf.P[0, 0]), 0.0, 0.0, float(P[1, 1]), float(P[1, 2]),
                                        float(P[2, 2]))))
        aux.motion_views = tuple(kept)

    def keep(self, moved: MovedView) -> None:
        """A hypothesis that moves with the filter (a lone source's solution that got company) kept
        beside the others; a coasting's own hypothesis stays the last one."""
        aux = self.f.aux
        held = aux.motion_views
        if is_coasting(aux):
            aux.motion_views = held[-(MAX_MOTION_VIEWS - 1):-1] + (moved, held[-1])
        else:
            aux.motion_views = held[-(MAX_MOTION_VIEWS - 1):] + (moved,)

    def take_fix(self, m, z: float, R: float) -> None:
        """The hypotheses conditioned on a fix ``m`` the filter accepted, located at z [m] with
        variance R [m^2] (``Solutions.located``): it tells where the train is under each of them."""
        aux = self.f.aux
        x0, P00 = float(self.f.ekf.x[0, 0]), float(self.f.ekf.P[0, 0])
        aux.motion_views = tuple(views.motion_view_fixed(view, m.stamp, z, R, x0, P00, self.f.process, self.f.cfg.jerk_psd)
                                 for view in aux.motion_views)

    def common_error_ended(self) -> None:
        """The newest motion-model hypothesis, if it moves with the filter, no longer shares an
        error with the sources in use (a transient fault that cannot go on)."""
        aux = self.f.aux
        moved = aux.motion_views[-1] if aux.motion_views else None
        if isinstance(moved, MovedView):
            aux.motion_views = aux.motion_views[:-1] + (moved._replace(r=0.0, var_r=0.0, until=math.inf),)

    def blind_speed(self, m, z: float, R: float) -> tuple | None:
        """Every speed source excluded (slip episodes, suspensions) and the filter's speed resting
        on the motion model alone: the exclusions cannot end, since each excluded sensor waits
        for a reference to agree with, and the dead reckoning drifts without bound. The
        excluded sensors' own readings end it: two independent speed sources that give the same
        speed (each reading inside the slip gate of their combined variance, and their mean
        difference inside that of its own) for ``slip_window`` s without a break: a slip and a
        radar fault do not give the same speed for long. (A wheel whose readings show no
        acceleration is no such evidence: a slide can outlast the braking that started it.)
        Then the speed is taken from those sensors (the acceleration back to its prior) and
        their exclusions end; the excluded views stay in the interval until a fix decides
        between them, and the filter awaits a confirming fix (DEGRADED). If the speed was set
        (re-acquired, or coasting), the effects on the other policies (events.py), else None."""
        aux, cfg, cls, stamp = self.f.aux, self.f.cfg, m.sensor, m.stamp
        u, white, common = implied_speed(self.f.layout, self.f.ekf.x, self.f.ekf.P, m, z, R)
        recent = stamp - cfg.slip_reference_timeout
        peers = {c: p for c, p in aux.peer_speeds.items() if c != cls and p.stamp > recent}
        aux.peer_speeds = {**peers, cls: PeerSpeed(stamp, u, white, common)}
        peer = self.peer_run(cls, stamp, u, white, common, peers)
        if peer is None:
            if not peers:
                return None
            return self.coast(stamp, [(u, white + common)] +
                              [(p.speed, p.white_var + p.common_var) for p in peers.values()])
        p = peers[peer]
        return self.take_speed(stamp, [(u, white + common), (p.speed, p.white_var + p.common_var)], {cls, peer})

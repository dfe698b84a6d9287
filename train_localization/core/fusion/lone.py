"""The lone-source solution: the motion model without the relative sensor that carries the speed
alone.

  lone source while one relative sensor with a persistent fault mode (a radar's scale fault,
              growing too slowly for any reading to disagree with the motion model) carries the
              speed alone (the others not fitted, silent or suspended; a wheel in a slip
              episode still counts: the episode is short and ends with a cross-check), nothing
              but the fixes checks it. The interval also covers the solution without it: the
              motion model from the filter's state when it became the lone one, conditioned on
              the accepted fixes (one it cannot explain refutes it and it starts again from the
              filter's), within what the sensor's fault can do over the distance since the last
              accepted fix (z ``scale_fault_sigma`` x distance). DEGRADED where it separates
              from the filter as a sensor's solution does.
"""
from __future__ import annotations

import math

from .component import Component
from . import counts
from .bookkeeping import LoneView, ModelView, MovedView
from .events import KeepMotionView
from . import inertial, views


class LoneSource(Component):
    """The solution without a lone speed source."""

    def track(self, stamp: float) -> tuple:
        """Solution separation for the fault of a lone speed source. A relative sensor whose scale
        fault no test of its own can see (a Doppler radar's, growing slowly: the speed it reads
        drifts like an acceleration) may carry the speed alone: the only relative sensor, or the
        others excluded or silent. Nothing then checks it but the fixes, and between them a
        fault of a few percent runs the filter out of its interval while every test passes. The
        solution without that sensor is the motion model from the last time another source
        checked it, conditioned on the fixes the filter accepts (``LoneSource.take_fix``); the
        interval covers it (``views.lone_interval``). It starts when one such sensor is left in use
        (accepted within ``slip_reference_timeout`` s), and ends when another source is in use
        (``LoneSource.accompanied``). A wheel in a slip or slide episode still counts: the episode is
        short (its ``fault_duration_max``) and ends with the wheel agreeing with the filter
        again, which a drifting radar fails; a suspended sensor does not. Returns the effect on the
        motion views (events.py)."""
        if "lone_source" not in self.f.cfg.policies:
            return ()
        aux, timeout = self.f.aux, self.f.cfg.slip_reference_timeout
        in_use = [c for c in self.f.layout.relative if c not in aux.suspended
                  and max(aux.last_accepted.get(c, -math.inf), aux.slip_until.get(c, -math.inf)) >= stamp - timeout]
        lone = in_use[0] if len(in_use) == 1 and in_use[0] in self.f.limits.persistent else None
        if lone is None:
            if aux.lone_view is not None and in_use:
                return self.accompanied(stamp)
        elif aux.lone_view is None or aux.lone_view.sensor != lone:
            aux.lone_view = LoneView(self.lone_model_view(stamp, lone), lone, 0.0, self.inertial_start(stamp, lone),
                                     since=stamp)
        return ()

    def take_acceleration(self, m) -> None:
        """An accepted acceleration reading moves the accelerometer's dead reckoning of the lone
        source's hypothesis (inertial.py), started here if there is none yet."""
        aux = self.f.aux
        if aux.lone_view is None:
            return
        view = aux.lone_view.inertial or self.inertial_start(m.stamp, aux.lone_view.sensor, m.sensor)
        aux.lone_view = aux.lone_view._replace(
            inertial=inertial.read(view, m.stamp, m.acceleration, m.acceleration_stddev))

    def inertial_start(self, stamp: float, lone: str, accelerometer: str | None = None):
        """The accelerometer's dead reckoning of the hypothesis from the filter's state now (its
        speed's variance widened as ``lone_model_view`` widens it), the bias within the device's
        prior (the filter's bias estimate learnt from the lone source: not under its fault); None
        without an accelerometer."""
        names = [accelerometer] if accelerometer else sorted(self.f.layout.accelerometers)
        if not names:
            return None
        x, P = self.f.ekf.x, self.f.ekf.P
        var_v = float(P[1, 1]) + self.lone_speed_widening(stamp, lone)
        return inertial.started(stamp, float(x[0, 0]), float(P[0, 0]), float(x[1, 0]), var_v, float(P[0, 1]),
                                self.f.models[names[0]].bias_sigma)

    def ran(self, distance: float) -> None:
        """The filter's position moved by ``distance`` [m] in a prediction: what the lone source's
        scale fault can add to the position error over it."""
        aux = self.f.aux
        if aux.lone_view is not None:
            lone = aux.lone_view
            step = self.f.limits.z * self.f.models[lone.sensor].scale_fault_sigma * abs(distance)
            aux.lone_view = lone._replace(bound=lone.bound + step)

    def reset(self) -> None:
        """The position was taken from a fix alone: the lone source's solution starts again from the
        filter's (``LoneSource.track``)."""
        self.f.aux.lone_view = None

    def accompanied(self, stamp: float) -> tuple:
        """The lone source has company again: from ``stamp`` the sources in use check each other,
        so its fault adds nothing more, but what it may have put into the filter's position while
        it was alone stays there, unseen by the newcomer (a relative sensor tells the motion from
        now on, not the distance already run), until a fix locates the train. The lone solution
        (its interval at ``stamp``) therefore stays as a motion-model hypothesis that moves with
        the filter (a MovedView, as a coasting's that ended): conditioned on the fixes, ruled out by
        one it does not fit, no longer needed once the filter explains a fix. Returns the effect
        on the motion views (events.py)."""
        aux = self.f.aux
        if "lone_source_kept" not in self.f.cfg.policies:
            aux.lone_view = None
            return ()
        s, var_s = float(self.f.ekf.x[0, 0]), float(self.f.ekf.P[0, 0])
        v, var_v = float(self.f.ekf.x[1, 0]), float(self.f.ekf.P[1, 1])
        lo, hi, _, _, _ = views.lone_interval(aux.lone_view, aux.t, stamp, s, var_s, v, var_v,
                                              self.f.models[aux.lone_view.sensor].scale_fault_sigma, self.f.limits.z,
                                              self.f.cfg.jerk_psd, self.f.cfg.slip_reference_timeout)
        aux.lone_view = None
        half = self.f.limits.z * math.sqrt(var_s)
        if lo > hi or (lo >= s - half and hi <= s + half):
            return ()     # ruled out, or within the filter's own interval
        moved = MovedView(0.5 * (lo + hi), (0.5 * (hi - lo) / self.f.limits.z) ** 2, s, var_s, 0.0, 0.0, math.inf)
        counts.event(aux, "lone_source_accompanied")
        return (KeepMotionView(moved),)

    def lone_model_view(self, stamp: float, lone: str) -> ModelView:
        """The motion model's hypothesis without lone source ``lone``, from the filter's state
        now. Unless another speed source checked the filter's speed just before (accepted within
        twice ``slip_reference_timeout``: a lone view starts once the others have been silent
        that long), the speed is that sensor's own reading and its fault may have begun long
        before: the speed's variance then holds its scale fault, (``scale_fault_sigma`` x v)^2,
        for the fixes to narrow (``views.motion_view_fixed``)."""
        view = views.model_view(stamp, self.f.ekf.x, self.f.ekf.P)
        widening = self.lone_speed_widening(stamp, lone)
        if not widening:
            return view
        p00, p01, p02, p11, p12, p22 = view.cov
        return view._replace(cov=(p00, p01, p02, p11 + widening, p12, p22))

    def lone_speed_widening(self, stamp: float, lone: str) -> float:
        """What [m^2/s^2] the filter's speed variance lacks as the start of a hypothesis without
        ``lone``: 0 where another speed source checked it just before (accepted within twice
        ``slip_reference_timeout``), else its scale fault, (``scale_fault_sigma`` x v)^2."""
        checked = max((self.f.aux.last_accepted.get(c, -math.inf) for c in self.f.layout.relative if c != lone),
                      default=-math.inf)
        if checked >= stamp - 2.0 * self.f.cfg.slip_reference_timeout:
            return 0.0
        return (self.f.models[lone].scale_fault_sigma * float(self.f.ekf.x[1, 0])) ** 2

    def take_fix(self, m, z: float, R: float) -> None:
        """The lone source's fault hypothesis after a fix the filter accepted (z, R from
        ``Solutions.located``): conditioned on it; one it cannot explain refutes it (the train did move
        as the sensor said), and it starts again from the filter's."""
        aux = self.f.aux
        held = aux.lone_view
        view = held.view
        s_f, P00 = float(self.f.ekf.x[0, 0]), float(self.f.ekf.P[0, 0])
        s_m, var_m = views.motion_view(view, m.stamp, s_f, P00, self.f.cfg.jerk_psd)
        gate = self.f.limits.gates[m.sensor]
        dead = held.inertial
        if dead is not None:
            dead, nis = inertial.fixed(dead, m.stamp, z, R)
        since = held.since
        if (z - s_m) ** 2 > gate * (R + var_m) or (dead is not None and nis > gate):
            view, since = self.lone_model_view(m.stamp, held.sensor), m.stamp
            dead = dead and self.inertial_start(m.stamp, held.sensor)
            counts.event(aux, "lone_source_solution_refuted")
        else:
            view = views.motion_view_fixed(view, m.stamp, z, R, s_f, P00, self.f.process, self.f.cfg.jerk_psd)
        # the filter accepted the fix: its error before was at most the innovation and the fix's
        # own error; the update took its gain's share of it (a DGPS fix little, a tag nearly all)
        gain, nu = self.f.last_update
        before = min(held.bound, abs(nu) + self.f.limits.z * math.sqrt(R))
        aux.lone_view = LoneView(view, held.sensor, (1.0 - min(max(float(gain[0]), 0.0), 1.0)) * before, dead, since)

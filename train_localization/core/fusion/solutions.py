"""The relative sensors' own solutions (separation.py) kept beside the filter, and the fixes that
locate the train under every hypothesis.

  separation  each relative sensor that another's fault could pull (separation.py: against a
              radar scale fault or a worn wheel every other one, against a wheel slip the
              fault-free ones; against its own wear the wheel, its scale opened) keeps its own
              dead reckoning from the fixes; per fault hypothesis the interval and the speed
              cover the valid one that widens them least (interval.py ``Interval.hypotheses_cover``),
              DEGRADED where the filter's own interval would not have (a radar scale fault
              absorbed into both scale states before any test sees it).
"""
from __future__ import annotations

import math

from .component import Component
from . import counts
from .bookkeeping import speed_excluded
from .models import fixes_sharing
from . import separation
from .events import LoneTakeFix, MotionViewsTakeFix


class Solutions(Component):
    """The relative sensors' own solutions."""

    def seed_subs(self, stamp: float) -> None:
        """Every relative sensor's own solution starts again from the filter's position."""
        s, P00, d = float(self.f.ekf.x[0, 0]), float(self.f.ekf.P[0, 0]), self.f.aux.odometer
        self.f.aux.subs = {name: separation.seed(sm, stamp, s, P00, d) for name, sm in self.f.limits.subs.items()}

    def main(self) -> separation.Main:
        """The filter's own solution now, for the sensor solutions."""
        x, P = self.f.ekf.x, self.f.ekf.P
        return separation.Main(float(x[0, 0]), float(P[0, 0]), float(x[1, 0]), float(P[1, 1]), self.f.aux.odometer)

    def sub_reading(self, m, key: str, sm) -> None:
        """Sensor ``m.sensor``'s own solution ``key`` after its reading m; while the filter has
        excluded it for its own fault (not as an undecided alternative) it follows the filter."""
        aux, cls, before = self.f.aux, m.sensor, self.f.before
        sub = aux.subs.get(key)
        if sub is None:
            sub = separation.seed(sm, m.stamp, before.s, before.P00, before.d)
        elif speed_excluded(aux, cls, m.stamp) and cls not in aux.relative_alternatives:
            sub = separation.follow(sub, m.stamp, before)._replace(t_v=-math.inf)
        else:
            R = self.f.measurement_of(m)[1]
            sub = separation.reading(sub, sm, m, R, float(self.f.ekf.x[2, 0]), before, self.f.cfg.slip_window)
        aux.subs = {**aux.subs, key: sub}

    def located(self, m) -> tuple[float, float]:
        """(position [m], variance [m^2]) of the train front that an accepted fix m gives under
        any hypothesis. The filter's estimate of the fix's persistent error (fix bias) is not
        used: it is learnt together with the filter's own solution and may hold what the filter
        got wrong. Its prior variance is added, as shared by the sensor's fixes within its
        correlation time (each counts for the fraction of that time since the previous one, as
        ``models.fix_noise`` counts a decoder's excess)."""
        z, R, _, _ = self.f.measurement_of(m)
        f_idx = self.f.layout.fix.get(m.sensor)
        if f_idx is not None:
            shared = fixes_sharing(self.f.models[m.sensor], abs(float(self.f.ekf.x[1, 0])), self.f.since_fix)
            R += float(self.f.layout.prior_sigma[f_idx]) ** 2 * shared
        return z, R

    def hypotheses_take_fix(self, m) -> tuple:
        """An absolute fix the filter accepted locates the train under every hypothesis it
        keeps: each relative sensor's own solution (separation.py; one that cannot explain the
        fix is refuted and starts again from the filter's) and each motion-model hypothesis of
        a coasting (conditioned on it: a fix that both explain tells where the train is, not
        only which one is right). The lone source's hypothesis likewise: the effect returned
        (events.py)."""
        aux = self.f.aux
        if not aux.subs and not aux.motion_views and aux.lone_view is None:
            return ()
        z, R = self.located(m)
        events = (LoneTakeFix(m, z, R),) if aux.lone_view is not None else ()
        x0, P00 = float(self.f.ekf.x[0, 0]), float(self.f.ekf.P[0, 0])
        if aux.motion_views:
            events = (MotionViewsTakeFix(m, z, R),) + events
        if aux.subs:
            subs = {}
            for name, sub in aux.subs.items():
                new = separation.fix(sub, m.stamp, z, R, self.f.before, self.f.limits.gates[m.sensor])
                if new is None:
                    new = separation.seed(self.f.limits.subs[name], m.stamp, x0, P00, aux.odometer)
                    counts.event(aux, "sensor_solution_refuted")
                subs[name] = new
            aux.subs = subs
        return events

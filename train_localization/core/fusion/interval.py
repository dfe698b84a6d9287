"""The published interval and mode: the filter's ``confidence`` interval widened to cover every
pending hypothesis.

Modes: INITIALISING until the first absolute fix, or for sensors that can misread their
reference until two fixes of different references agree (NaN position, infinite interval);
LOST when the position 1-sigma exceeds ``lost_stddev``; DEGRADED while a continuous
sensor is past its timeout, an unexplained fix is pending, or the filter has not been
confirmed by an accepted fix since a re-learn or an inflation; else NOMINAL.
[position_min, position_max] is the two-sided ``confidence`` interval, widened to
cover a pending alternative.
"""
from __future__ import annotations

import math
from typing import NamedTuple

from .component import Component
from .bookkeeping import Bookkeeping, MovedView, is_coasting
from . import impact, views
from .models import kinematics
from .mode import Mode
from . import separation


class Placed(NamedTuple):
    """A sensor solution placed at the time of a published state."""

    s: float           # position [m]
    var: float         # its variance, at least the filter's [m^2]
    half: float        # z x its 1-sigma [m]
    half_v: float      # half-width [m/s] of the speeds it allows; 0 while its sensor does not read


class Interval(Component):
    """The published interval and mode."""

    def cover(self, aux: Bookkeeping, t: float, s, v, var_s, var_v, sd_s, sd_v, bank, odometer: float) -> tuple:
        """(lo, hi [m], position 1-sigma [m], speed 1-sigma [m/s], mode) at t [s] of the filter at
        s [m], v [m/s] (variances var_s [m^2], var_v [m^2/s^2]; 1-sigma sd_s, sd_v): its
        ``confidence`` interval widened to cover every pending hypothesis, in this order: the
        unexplained fix, the excluded sensors' views, their speeds, the motion-model hypotheses,
        the lone-source solution, the persistent-fault cover (impact.py; ``bank``: aux.impacts, or
        the same prepared by ``impact.prepared``; less the lone source's scale faults that began
        after its solution did, which that solution holds wherever it is not empty) and the sensors' own solutions (``odometer``: the
        filter's odometer at t, Bookkeeping.odometer)."""
        lo, hi = float(s) - self.f.limits.z * sd_s, float(s) + self.f.limits.z * sd_s
        alt = aux.alternative
        if alt is not None:   # the unexplained fix, moved with the filter's motion since
            p_alt = alt.z + (float(s) - alt.s)
            half = self.f.limits.z * math.sqrt(alt.R + max(var_s - alt.P00, 0.0))
            lo, hi = min(lo, p_alt - half), max(hi, p_alt + half)
            sd_s = max(sd_s, (hi - lo) / (2.0 * self.f.limits.z))
        mode = self.mode(aux, t, sd_s)
        for cls, rel in aux.relative_alternatives.items():   # the excluded sensors' views
            D, var_D = views.alternative_spread(self.f.models[cls], rel)
            half = self.f.limits.z * math.sqrt(var_s + var_D)
            # from its current separation to the farthest one: the excluded sensor is no more
            # trusted than the others (right until then, it may have slipped back since)
            near, far = sorted((D, rel.farthest))
            alt_lo, alt_hi = float(s) + near - half, float(s) + far + half
            if alt_lo < lo or alt_hi > hi:
                lo, hi, sd_s, mode = self.widen(aux, t, lo, hi, sd_s, mode, alt_lo, alt_hi)
                mode = Mode.DEGRADED if mode == Mode.NOMINAL else mode
        sd_v_views = self.speed_covering_views(aux, t, float(v), sd_v)
        if sd_v_views > sd_v:
            sd_v, mode = sd_v_views, (Mode.DEGRADED if mode == Mode.NOMINAL else mode)
        for view in aux.motion_views:   # the motion model's own hypotheses of coastings
            s_m, var_m = views.motion_view(view, t, float(s), var_s, self.f.cfg.jerk_psd)
            half = self.f.limits.z * math.sqrt(var_m)
            if s_m - half < lo or s_m + half > hi:
                lo, hi, sd_s, mode = self.widen(aux, t, lo, hi, sd_s, mode, s_m - half, s_m + half)
        left_to = None   # the lone source's scale faults since its solution began: that solution holds them
        if aux.lone_view is not None:   # the solution without a lone speed source (its fault)
            l_lo, l_hi, half_v, s_m, var_m = views.lone_interval(
                aux.lone_view, aux.t, t, float(s), var_s, float(v), var_v,
                self.f.models[aux.lone_view.sensor].scale_fault_sigma, self.f.limits.z, self.f.cfg.jerk_psd,
                self.f.cfg.slip_reference_timeout)
            if l_lo <= l_hi and (l_lo < lo or l_hi > hi):
                lo, hi, sd_s, mode = self.widen(aux, t, lo, hi, sd_s, mode, l_lo, l_hi)
                if mode == Mode.NOMINAL and separation.separated(s_m, var_m, float(s), var_s, self.f.limits.z):
                    mode = Mode.DEGRADED
            if half_v > self.f.limits.z * sd_v:
                sd_v = half_v / self.f.limits.z
            if l_lo <= l_hi:
                left_to = impact.LeftTo(aux.lone_view.sensor, aux.lone_view.since)
        if aux.impacts is not None:   # the persistent faults of the relative sensors the data has not excluded
            half_s, half_v = impact.cover(bank, t - aux.t, self.f.limits.z, max(var_s, 0.0), max(var_v, 0.0),
                                          left_to)
            if float(s) - half_s < lo or float(s) + half_s > hi:
                lo, hi, sd_s, mode = self.widen(aux, t, lo, hi, sd_s, mode, float(s) - half_s, float(s) + half_s)
            if half_v > self.f.limits.z * sd_v:
                sd_v = half_v / self.f.limits.z
        if aux.subs:   # the relative sensors' own solutions: per fault hypothesis (protection level)
            lo, hi, sd_s, sd_v, mode = self.hypotheses_cover(aux, t, float(s), var_s, float(v), var_v,
                                                             lo, hi, sd_s, sd_v, mode, odometer)
        lo, hi = self.on_track(lo, hi)
        return lo, hi, sd_s, sd_v, mode

    def on_track(self, lo: float, hi: float) -> tuple[float, float]:
        """[lo, hi] [m] cut to the track's ends: the train's front is on its track, whatever the
        hypotheses (a closed track, or a network's paths, which the track selection bounds: as
        they are; an interval wholly beyond an end, which no cut can mend: as it is)."""
        track = self.f.cfg.track
        if track is None or track.closed or hi < 0.0 or lo > track.length:
            return lo, hi
        return max(lo, 0.0), min(hi, track.length)

    def speed_covering_views(self, aux: Bookkeeping, t: float, v: float, sd_v: float) -> float:
        """The speed 1-sigma [m/s] to publish: the filter's, widened so that v +- z sd_v also
        covers the speed each excluded sensor with an undecided view last read (within
        ``slip_reference_timeout`` s), with its own noise: while no fix has decided which
        source is faulty, the speed of either may be the true one (the position interval
        covers their views the same way). While the filter coasts between disagreeing
        sources it also covers the motion model's speed from the start of the coasting: both
        sources may be wrong the same way (a slip during a radar scale fault), and the middle
        of two readings that happen to be close is no measurement. After a coasting or a
        re-acquisition, while the common error its motion-model hypothesis holds may still last
        (``MotionViews.coasting_ended``), it covers that error too."""
        half = base = self.f.limits.z * sd_v
        for cls in aux.relative_alternatives:
            reading = aux.view_speeds.get(cls)
            if reading is None or t - reading.stamp > self.f.cfg.slip_reference_timeout:
                continue
            half = max(half, abs(reading.speed - v) + self.f.limits.z * math.sqrt(reading.var + sd_v * sd_v))
        if is_coasting(aux):
            view = aux.motion_views[-1]
            _, v_m, _, _, var_m = kinematics(view.s, view.v, view.a, view.cov, max(t - view.stamp, 0.0),
                                             self.f.cfg.jerk_psd)
            half = max(half, abs(v_m - v) + self.f.limits.z * math.sqrt(var_m))
        for view in aux.motion_views:
            if isinstance(view, MovedView) and view.r and view.until > t:
                # a common error r of the sources in use that may still last: their speed x (1 + r)
                r, var_r = view.r, view.var_r
                half = max(half, abs(v * r) + self.f.limits.z * math.sqrt(sd_v * sd_v + v * v * var_r))
        return half / self.f.limits.z if half > base else sd_v   # (z sd_v) / z may differ from sd_v by an ulp

    def mode(self, aux: Bookkeeping, t: float, position_stddev: float) -> Mode:
        if not aux.initialised:
            return Mode.INITIALISING
        if position_stddev > self.f.cfg.lost_stddev:
            return Mode.LOST
        if aux.alternative is not None or aux.unverified or aux.suspended:
            return Mode.DEGRADED
        for sensor, timeout in self.f.timeouts.items():
            if t - aux.last_accepted.get(sensor, -math.inf) > timeout:
                return Mode.DEGRADED
        return Mode.NOMINAL

    def widen(self, aux: Bookkeeping, t: float, lo: float, hi: float, sd_s: float, mode: Mode,
              cover_lo: float, cover_hi: float) -> tuple[float, float, float, Mode]:
        """(lo, hi [m], position 1-sigma [m], mode) of the interval [lo, hi] widened to cover
        [cover_lo, cover_hi]: the 1-sigma at least the widened half-width / z, the mode
        ``widened``."""
        lo, hi = min(lo, cover_lo), max(hi, cover_hi)
        sd_s = max(sd_s, (hi - lo) / (2.0 * self.f.limits.z))
        return lo, hi, sd_s, self.widened(aux, t, sd_s, mode)

    def widened(self, aux: Bookkeeping, t: float, position_stddev: float, mode: Mode) -> Mode:
        """The mode after the interval was widened to position_stddev [m]: LOST beyond
        ``lost_stddev``, else ``mode`` as it was (a DEGRADED view is not undone)."""
        return Mode.LOST if self.mode(aux, t, position_stddev) == Mode.LOST else mode

    def hypotheses_cover(self, aux: Bookkeeping, t: float, s: float, var_s: float, v: float, var_v: float,
                         lo: float, hi: float, sd_s: float, sd_v: float, mode: Mode, odometer: float) -> tuple:
        """(lo, hi, position and speed 1-sigma, mode) widened to cover, per fault hypothesis of
        the relative sensors (separation.hypotheses), the valid solution that widens the interval
        least: each is a bound under that hypothesis. A solution whose sensor has not read since it
        started is the filter's own. DEGRADED where the filter's interval alone would not have
        covered the chosen solution (the separation beyond its test threshold). ``odometer``: the
        filter's at t (Bookkeeping.odometer), which a solution without readings follows."""
        z, placed = self.f.limits.z, {}
        for key, sub in aux.subs.items():
            if not sub.own:
                continue
            s_j, var_j = separation.at(sub, t, var_s, v, var_v, odometer)
            var_j = max(var_j, var_s)
            half_v = (separation.speed_half_width(sub, self.f.limits.subs[key], v, var_v, z)
                      if t - sub.t_v <= self.f.cfg.slip_reference_timeout else 0.0)
            placed[key] = Placed(s_j, var_j, z * math.sqrt(var_j), half_v)
        for valid in self.f.limits.hypotheses.values():
            # only a solution whose sensor reads is a bound of its own; one that follows the
            # filter (its sensor silent or excluded) may carry the fault: then each is covered
            # (one whose sensor has not read since it started is the filter's own: none)
            own = [k for k in valid if k in placed]
            reading = [k for k in own if placed[k].half_v > 0.0]
            chosen = [min(reading, key=lambda k: max(hi, placed[k].s + placed[k].half)
                          - min(lo, placed[k].s - placed[k].half))] if reading else own
            for k in chosen:
                p = placed[k]
                if p.s - p.half < lo or p.s + p.half > hi:
                    lo, hi, sd_s, mode = self.widen(aux, t, lo, hi, sd_s, mode, p.s - p.half, p.s + p.half)
                    if mode == Mode.NOMINAL and separation.separated(p.s, p.var, s, var_s, z):
                        mode = Mode.DEGRADED
            half_v = min((placed[k].half_v for k in reading), default=0.0)
            if half_v > z * sd_v:
                sd_v = half_v / z
        return lo, hi, sd_s, sd_v, mode

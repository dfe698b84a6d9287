"""The fault hypotheses' bank (impact.py ``Bank``) kept with the filter's state: its onsets, and the
bank following every change of the state (a prediction, an update, error states or the speed
set, the position taken from a fix).

The one writer of ``Bookkeeping.impacts``: the filter, the stages and the policies that change x
ask it to follow through the filter's ``bank``."""
from __future__ import annotations

import math

from .component import Component
from . import impact


class FaultBank(Component):
    """The bank of fault hypotheses that rolls back with x and P."""

    def predicted(self, F) -> None:
        """The state predicted with transition F."""
        aux = self.f.aux
        aux.impacts = impact.predicted(aux.impacts, F)

    def persistent_onset(self, t: float) -> None:
        """A persistent fault of the relative sensors may begin at ``t`` [s], ``fault_onset_spacing``
        s after the last onset."""
        f, aux = self.f, self.f.aux
        bounds = f.limits.persistent_bounds   # the sensors' own and the monitored common-cause groups'
        if bounds and aux.initialised and (
                aux.impacts is None or t - aux.impacts.last_onset_of(bounds) >= f.cfg.fault_onset_spacing):
            first = aux.impacts is None or aux.impacts.last_onset_of(bounds) == -math.inf
            aux.impacts = impact.started(aux.impacts, bounds, t, f.n, f.cfg.fault_onsets, f.limits.z,
                                         members=f.limits.group_members)
            if first and f.limits.group_members:
                aux.impacts = impact.begun_before(aux.impacts, t, float(f.ekf.x[1, 0]))

    def offset_onset(self, cls: str, stamp: float) -> None:
        """A run of offset fixes of ``cls`` may begin at ``stamp`` [s], ``fault_onset_spacing`` s after
        its last onset."""
        f, aux = self.f, self.f.aux
        if aux.impacts is None or stamp - aux.impacts.last_onset_of((cls,)) >= f.cfg.fault_onset_spacing:
            aux.impacts = impact.started(aux.impacts, {cls: f.limits.offset_bounds[cls]}, stamp, f.n,
                                         f.cfg.fault_onsets, f.limits.z, offset=True)

    def transient_onset(self, cls: str, stamp: float, alone: bool) -> None:
        """An episode of a transient fault of ``cls`` may begin at ``stamp`` [s] (``alone``: nothing
        but the motion model sees all of it)."""
        f, aux = self.f, self.f.aux
        if aux.impacts is None or aux.impacts.episode_begins(cls, alone):
            aux.impacts = impact.episode_started(aux.impacts, cls, f.limits.transient_bounds[cls], stamp, alone,
                                                 f.n, f.cfg.fault_onsets, f.limits.z)

    def updated(self, fault_input, h, K, nu: float, S: float) -> None:
        """The EKF update with gain K, innovation nu and its variance S of a reading (its fault input)."""
        aux = self.f.aux
        aux.impacts = impact.updated(aux.impacts, fault_input, h, K, nu, S)

    def states_set(self, idx) -> None:
        """The error states ``idx`` set (back to their priors)."""
        aux = self.f.aux
        aux.impacts = impact.states_set(aux.impacts, idx)

    def speed_set(self, speed: float) -> None:
        """The speed set to ``speed`` [m/s] from readings."""
        aux = self.f.aux
        aux.impacts = impact.speed_set(aux.impacts, speed)

    def position_set_from_fix(self, fix_bias_index: int | None, fault_input) -> None:
        """The position taken from a fix (its fix bias state, its fault input)."""
        aux = self.f.aux
        aux.impacts = impact.position_set_from_fix(aux.impacts, fix_bias_index, fault_input)

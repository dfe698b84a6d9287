"""Plausibility of the error states: a fault the filter absorbed, and the re-learn from the priors.

  plausibility an error state estimated beyond ``plausible_sigmas`` of its prior (and beyond
              the slip gate of its own variance: significantly) means a fault was absorbed
              (the filter explained a slip or a faulty sensor with a
              scale nobody has): every relative sensor's error states are re-learnt from
              their priors and the position and speed covariance widened by what the
              corrupted states can have caused since the last accepted fix.
"""
from __future__ import annotations

import math

import numpy as np

from .component import Component
from . import counts
from .bookkeeping import Fault, new_view
from . import views
from .events import AwaitFix, OwnViewEnded, ScaleFaultsReset, Suspend, Undecided


class Plausibility(Component):
    """Plausibility of the error states."""

    def check_plausible(self) -> tuple:
        """Re-learn the relative sensors' error states if one of them left its plausible range.

        If the states of one sensor alone left it, that sensor is outside its own error
        model (a radar scale fault with no other speed source to disagree with): it is also
        suspended until it agrees again, its view kept as the alternative if another speed source
        may be the faulty one; the only relative sensor of a train without slip physics keeps
        its readings in use, its scale opened to the fault's size. States of several sensors: a fault was absorbed between them (a
        slip learnt as scales), which one cannot be told. Returns the effect on the arbitration
        (events.py)."""
        idx = self.f.layout.relative_states
        if not len(idx):
            return ()
        x = self.f.ekf.x[idx, 0]
        sigma = self.f.layout.prior_sigma[idx]
        if self.f.aux.scale_faults:   # a scale fault being learnt: plausible up to its size
            lay = self.f.layout
            faulted = {lay.fault_scale.get(c): self.f.models[c].scale_fault_sigma
                       for c in self.f.aux.scale_faults}
            sigma = np.array([math.hypot(sg, faulted.get(i, 0.0)) for i, sg in zip(idx.tolist(), sigma)])
        # beyond the plausible range, and significantly so where a fix-bias inconsistency widened
        # the state past its prior (a noisy estimate of a scale that may hold a fault is no proof)
        bad = (np.abs(x) > self.f.cfg.plausible_sigmas * sigma) & \
            (x * x > self.f.limits.slip_gate * np.diag(self.f.ekf.P)[idx])
        if not bad.any():
            return ()
        owners = {self.f.layout.owner[i] for i in idx[bad]}
        x_before = self.f.ekf.x
        if len(owners) == 1 and not views.judged(next(iter(owners)), self.f.layout, self.f.models,
                                                       self.f.cfg.policies):
            # the only relative sensor, without slip physics: suspended, nothing could show it
            # agreeing again (``views.judged``); its scale may hold a fault, opened to the fault's size
            # for the fixes to teach, the lone solution covering it meanwhile
            return self.relearn("implausible_error_state", faulty=owners)
        events = self.relearn("implausible_error_state")
        if len(owners) == 1:
            (cls,) = owners
            events += (Suspend(cls, self.state_fault(cls, x_before)),)
            aux = self.f.aux
            counts.event(aux, "implausible_sensor_suspended")
            if aux.speed_sources - {cls} and cls not in aux.relative_alternatives:
                # which state absorbs a disagreement follows the priors, not the fault: the other
                # speed source may be the faulty one, so the suspended sensor's view is kept
                events += (Undecided(cls, new_view(aux.t, float(self.f.ekf.P[0, 0]))), OwnViewEnded(cls, False))
        return events

    def state_fault(self, cls: str, x) -> Fault:
        """The fault that relative sensor ``cls``'s error states in x had absorbed: its scale and
        bias error at the speed [m/s], the speed [m/s]."""
        lay, v = self.f.layout, float(x[1, 0])
        k = sum(float(x[i, 0]) + (float(x[o, 0]) if o is not None else 0.0)
                for name, i, o in lay.scale_terms if name == cls)
        b = float(x[lay.bias[cls], 0]) if cls in lay.bias else 0.0
        return Fault(k * v + (b if v >= 0.0 else -b), v)

    def relearn(self, reason: str, faulty=()) -> tuple:
        """Error states of the relative sensors back to their priors (the scales of ``faulty``
        sensors, suspected of a scale fault, by the fault's size more: ``views.raised``); the
        position and speed covariance widened by what the discarded estimates can have caused
        since the last accepted fix (scale x distance, scale x speed, bias x time). The filter awaits
        a confirming fix: the effect returned (events.py)."""
        aux, lay = self.f.aux, self.f.layout
        x, P = self.f.ekf.x.copy(), self.f.ekf.P.copy()
        scale = 0.0
        for _, i, o in lay.scale_terms:
            scale = max(scale, abs(x[i, 0] + (x[o, 0] if o is not None else 0.0)))
        bias = max([abs(x[i, 0]) for i in lay.bias.values()], default=0.0)
        dist = abs(x[0, 0] - aux.s_last_fix) if math.isfinite(aux.s_last_fix) else 0.0
        since = aux.t - aux.last_fix_accepted if math.isfinite(aux.last_fix_accepted) else 0.0
        P[0, 0] += (scale * dist + bias * since) ** 2
        P[1, 1] += (scale * x[1, 0]) ** 2 + bias ** 2
        idx = lay.relative_states
        x[idx, 0] = 0.0
        self.f.bank.states_set(idx)
        P[idx, :] = 0.0
        P[:, idx] = 0.0
        P[idx, idx] = lay.prior_sigma[idx] ** 2
        self.f.ekf.x = x
        self.f.ekf.P = views.raised(P, faulty, lay, self.f.models, float(x[1, 0])) if faulty else P
        counts.event(aux, reason)
        return ScaleFaultsReset(tuple(faulty)), AwaitFix(reason)

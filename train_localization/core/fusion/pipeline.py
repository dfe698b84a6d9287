"""One reading through the filter's policies: the ordered stages of ``STAGES``, each a function
(filter, Reading) -> Verdict, run by ``apply_reading``.

A stage reads and changes the filter through its components (filter.py) and says whether the
reading goes on to the next stage (``GO_ON``), is done with (``DONE``: used, gated or kept) or
excluded by a fault test (``EXCLUDED``: then ``excluded`` follows its sensor's episode), with
the effects it asks of other policies (events.py), which ``route`` applies right after it. The
innovation is computed by the ``innovation`` stage and again after a stage whose ``Step``
declares it (``renew``) if that stage replaced the covariance (the EKF's ``revision`` counts
the replacements).
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Callable, NamedTuple

from ..measurements import Acceleration, PositionFix
from . import views
from .events import (AwaitFix, CommonErrorEnded, EpisodeEnded, EpisodesEnded, FaultEnded, FirstPosition, KeepMotionView,
                     LoneReset, LoneTakeFix, MotionViewsTakeFix, OwnViewEnded, Relearn, RelearnFault, ScaleFaultsReset,
                     SeedSubs, Separate, SetPosition, SetSpeed, SlipWindow, Suspend, SuspensionsEnded, Swap, TakeSpeed,
                     Undecided, ViewDropped, ViewMerged, ViewSeparates)
from . import counts
from .bookkeeping import NisSum, speed_excluded


class Kind(enum.Enum):
    GO_ON = 0       # the next stage judges the reading
    DONE = 1        # used, gated or kept: no further stage
    EXCLUDED = 2    # excluded by a fault test (its sensor's episode follows it: ``excluded``)


class Verdict(NamedTuple):
    """A stage's verdict on a reading, and the effects it asks of other policies (events.py)."""

    kind: Kind
    events: tuple = ()


GO_ON, DONE, EXCLUDED = Verdict(Kind.GO_ON), Verdict(Kind.DONE), Verdict(Kind.EXCLUDED)


@dataclass(slots=True)
class Reading:
    """A reading being applied and its innovation at the current state."""

    m: object
    cls: str                   # its sensor
    is_fix: bool               # an absolute fix (PositionFix)
    z: float = math.nan        # the measurement [its units]
    R: float = math.nan        # its variance
    h: object = None           # the Jacobian row (n,)
    hx: float = math.nan       # h(x)
    PHt: object = None         # P h (n,)
    S: float = math.nan        # the innovation variance
    nis: float = math.nan      # (z - hx)^2 / S

    def innovate(self, f) -> None:
        """The innovation at the filter's current state."""
        self.z, self.R, self.h, self.hx, self.PHt, self.S = f.innovation(self.m)
        self.nis = (self.z - self.hx) ** 2 / self.S


def prepare(f, r: Reading) -> Verdict:
    """Predict to the reading, note the filter's own solution before it (separation.py) and what
    its own fault would add (impact.py); a run of offset fixes may begin with it."""
    m, cls, aux = r.m, r.cls, f.aux
    f.predict_to(m.stamp)
    if f.limits.subs:
        f.before = f.solutions.main()
    f.applied += 1
    f.fault_input = f.fault_input_of(m, r.is_fix)
    if cls in f.limits.offset_bounds:
        f.bank.offset_onset(cls, m.stamp)
    if r.is_fix:   # since the sensor's previous fix, before this one counts (Solutions.located)
        f.since_fix = m.stamp - aux.last_accepted.get(cls, -math.inf)
    return GO_ON


def fix_reference(f, r: Reading) -> Verdict:
    """A fix of a new reference starts its fix bias; the first fixes initialise the filter."""
    aux, m = f.aux, r.m
    if r.cls in f.layout.per_reference and r.is_fix and aux.fix_ref.get(r.cls) != m.reference_id:
        f.fixes.new_fix_bias(r.cls)
        aux.fix_ref = {**aux.fix_ref, r.cls: m.reference_id}
    if r.is_fix and not aux.initialised:
        return Verdict(Kind.DONE, f.fixes.initialise(m))
    return GO_ON


def motion_views_move(f, r: Reading) -> Verdict:
    """The motion model's hypotheses that move with the filter from this reading on (MotionViews.move)."""
    f.motion.move(r.m.stamp)
    return GO_ON


def innovation(f, r: Reading) -> Verdict:
    r.innovate(f)
    return GO_ON


def motion_views_fix(f, r: Reading) -> Verdict:
    """A fix rules out the motion-model hypotheses it does not fit (MotionViews.rule_out)."""
    if r.is_fix and f.aux.motion_views:
        f.motion.rule_out(r.m.stamp, r.z, r.R, f.limits.gates[r.cls])
    return GO_ON


def blind(f, r: Reading) -> Verdict:
    """An excluded speed source while nothing else gives the speed (MotionViews.blind_speed);
    then, a fix the filter explains on its speed sources again confirms it: an old coasting's
    motion-model hypothesis (however vague) is no longer needed."""
    events = ()
    if not r.is_fix and speed_excluded(f.aux, r.cls, r.m.stamp) and not f.agreement_reference(r.m, r.S):
        taken = f.motion.blind_speed(r.m, r.z, r.R)
        if taken is not None:
            events = taken
            r.innovate(f)   # at the re-acquired speed
    if r.is_fix and r.nis <= f.limits.gates[r.cls]:
        f.motion.confirmed()
    return Verdict(Kind.GO_ON, events)


def suspension(f, r: Reading) -> Verdict:
    """A suspended speed source is judged (Arbitration.suspended); it may come back with its scale
    opened (Arbitration.relearn_fault: a new covariance)."""
    if r.cls not in f.aux.suspended:
        return GO_ON
    excluded, events = f.arbitration.suspended(r.m, r.z - r.hx, r.S, r.nis, f.episodes.common(r.cls, r.h))
    return Verdict(Kind.EXCLUDED if excluded else Kind.GO_ON, events)


def slip(f, r: Reading) -> Verdict:
    """The slip and slide tests of a relative sensor (Episodes.slipping); a learnt fault that
    ended gives a new covariance (Episodes.fault_ended)."""
    if r.cls not in f.layout.episode_sensors:
        return GO_ON
    excluded, events = f.episodes.slipping(r.m, r.z - r.hx, r.S, r.nis)
    return Verdict(Kind.EXCLUDED if excluded else Kind.GO_ON, events)


def decide_views(f, r: Reading) -> Verdict:
    """A fix decides between the filter and the excluded sensors' views (Arbitration.decide_relative)."""
    if not (r.is_fix and f.aux.relative_alternatives):
        return GO_ON
    used, events = f.arbitration.decide_relative(r.m, r.z, r.R, r.hx, r.S, r.nis)
    return Verdict(Kind.DONE if used else Kind.GO_ON, events)


def reacquisition(f, r: Reading) -> Verdict:
    """The kept fix, for which a scale was opened, and this one agree: the position from them
    (Fixes.reacquire), also where the filter's opened interval would have taken this one (it
    would learn the scale from this fix against a position the kept fix showed wrong)."""
    aux, m = f.aux, r.m
    if r.is_fix and aux.alternative is not None and aux.alternative.opened and views.corroborated(
            m, r.z, r.R, aux.alternative, f.ekf.x, f.ekf.P, f.layout, f.cfg.branch_timeout, f.limits.gates[r.cls]):
        return Verdict(Kind.DONE, f.fixes.reacquire(m))
    return GO_ON


def gate(f, r: Reading) -> Verdict:
    """The NIS gate; a gated fix may be kept as the unexplained alternative, and a fix that
    revisits a remembered reference is judged by it (Fixes.remembered)."""
    aux = f.aux
    if r.nis > f.limits.gates[r.cls]:
        counts.gated(aux, r.cls)
        if r.is_fix and aux.initialised:
            return Verdict(Kind.DONE, f.fixes.unexplained(r.m, r.z, r.R))
        return DONE
    if r.is_fix and f.fixes.remembered(r.m, r.R):
        return DONE
    return GO_ON


def transient_onset(f, r: Reading) -> Verdict:
    """The train driven or braked; a relative reading's unseen share of a transient fault (impact.py)."""
    aux, cls, stamp = f.aux, r.cls, r.m.stamp
    if abs(float(f.ekf.x[2, 0])) >= f.cfg.slip_min_drive:
        aux.last_drive = stamp
    if cls in f.limits.transient_bounds and aux.initialised:   # a relative reading: its fault input is set
        share = f.unseen_share(cls, stamp, f.fault_input.per_unit, r.S)
        f.fault_input = f.fault_input._replace(unseen=share)
        f.bank.transient_onset(cls, stamp, share >= 1.0)
    return GO_ON


def update(f, r: Reading) -> Verdict:
    """The EKF update and its counts; a fix's correction of the speed states that its NIS does not
    confirm (Fixes.correction_unconfirmed)."""
    aux, cls, m = f.aux, r.cls, r.m
    x_before = f.ekf.x
    f.update(r.z, r.R, r.h, r.hx, r.PHt, r.S)
    if r.is_fix and r.nis > 1.0 and cls not in f.layout.fix:
        f.fixes.correction_unconfirmed(x_before, r.nis)
    seen = aux.nis.get(cls, NisSum(0, 0.0))
    aux.nis = {**aux.nis, cls: NisSum(seen.count + 1, seen.total + r.nis)}
    counts.accepted(aux, cls, m.stamp)
    f.episodes.own_view_ended(cls)
    return GO_ON


def locate(f, r: Reading) -> Verdict:
    """An accepted fix locates the train under every hypothesis kept (Solutions.hypotheses_take_fix)."""
    return Verdict(Kind.GO_ON, f.solutions.hypotheses_take_fix(r.m)) if r.is_fix else GO_ON


def accept(f, r: Reading) -> Verdict:
    """What follows an accepted reading: the fix policies, the speed sources and the lone source,
    the plausibility of the error states."""
    aux, cls, m = f.aux, r.cls, r.m
    if r.is_fix:
        f.fixes.fix_accepted(m, r.nis, (r.z - r.hx) / math.sqrt(r.S), r.S)
    elif cls in f.layout.accelerometers:
        f.lone.take_acceleration(m)
    elif cls in f.layout.relative:
        if cls not in aux.speed_sources:
            aux.speed_sources = aux.speed_sources | {cls}
        if f.limits.persistent:
            return Verdict(Kind.DONE, f.lone.track(m.stamp) + f.plausibility.check_plausible())
    return Verdict(Kind.DONE, f.plausibility.check_plausible())


def excluded(f, r: Reading) -> None:
    """After an exclusion: a sensor whose fault modes all end by themselves may have outlasted
    them (Episodes.outlasted)."""
    if r.cls in f.limits.bounded:
        route(f, f.episodes.outlasted(r.m, r.z, r.R, r.hx, r.S, r.h))


# event -> the policy that owns what it changes (each returns the events it asks in turn, if any)
ROUTES = {
    Separate: lambda f, ev: f.episodes.separate(ev.m, ev.e, ev.S),
    EpisodeEnded: lambda f, ev: f.episodes.episode_ended(ev.cls, ev.stamp),
    EpisodesEnded: lambda f, ev: f.episodes.episodes_ended(ev.stamp, ev.sensors),
    SlipWindow: lambda f, ev: f.episodes.set_window(ev.cls, ev.window),
    OwnViewEnded: lambda f, ev: f.episodes.own_view_ended(ev.cls, ev.fault_window),
    FaultEnded: lambda f, ev: f.arbitration.end_fault(ev.cls),
    ScaleFaultsReset: lambda f, ev: f.arbitration.scale_faults_reset(ev.keep),
    SuspensionsEnded: lambda f, ev: f.arbitration.suspensions_ended(ev.sensors),
    Undecided: lambda f, ev: f.arbitration.undecided(ev.cls, ev.view),
    ViewMerged: lambda f, ev: f.arbitration.view_merged(ev.cls),
    ViewDropped: lambda f, ev: f.arbitration.view_dropped(ev.cls),
    ViewSeparates: lambda f, ev: f.arbitration.view_separates(ev.m, ev.e, ev.S),
    RelearnFault: lambda f, ev: f.arbitration.relearn_fault(ev.cls),
    Suspend: lambda f, ev: f.arbitration.suspend(ev.cls, ev.fault),
    TakeSpeed: lambda f, ev: f.motion.take_speed(ev.stamp, ev.readings, ev.sensors),
    SetSpeed: lambda f, ev: f.motion.set_speed(ev.readings),
    CommonErrorEnded: lambda f, ev: f.motion.common_error_ended(),
    Swap: lambda f, ev: f.arbitration.swap(ev.m, ev.z, ev.R, ev.view, ev.other),
    SetPosition: lambda f, ev: f.fixes.set_position(ev.m),
    Relearn: lambda f, ev: f.plausibility.relearn(ev.reason, ev.faulty),
    SeedSubs: lambda f, ev: f.solutions.seed_subs(ev.stamp),
    LoneTakeFix: lambda f, ev: f.lone.take_fix(ev.m, ev.z, ev.R),
    LoneReset: lambda f, ev: f.lone.reset(),
    FirstPosition: lambda f, ev: f.motion.first_position(ev.stamp),
    KeepMotionView: lambda f, ev: f.motion.keep(ev.view),
    MotionViewsTakeFix: lambda f, ev: f.motion.take_fix(ev.m, ev.z, ev.R),
    AwaitFix: lambda f, ev: f.fixes.await_fix(ev.reason, ev.replace),
}


def route(f, events: tuple) -> None:
    """Apply ``events`` in order, each by the policy ``ROUTES`` names; the events a routed one
    returns come right after it, before those still waiting (as a call would)."""
    waiting = list(reversed(events))
    while waiting:
        event = waiting.pop()
        waiting.extend(reversed(ROUTES[type(event)](f, event) or ()))


class Step(NamedTuple):
    judge: Callable[..., Verdict]
    renew: bool = False   # the innovation is computed again after it if it replaced the covariance


# the order in which the policies act on a reading
STAGES = (Step(prepare), Step(fix_reference), Step(motion_views_move), Step(innovation), Step(motion_views_fix),
          Step(blind), Step(suspension, renew=True), Step(slip, renew=True), Step(decide_views), Step(reacquisition),
          Step(gate), Step(transient_onset), Step(update), Step(locate), Step(accept))


# an acceleration: no fix, speed-source or slip policy judges it; it moves the state and tests the
# fault hypotheses (impact.py) through the update
ACCELERATION_STAGES = (Step(prepare), Step(innovation), Step(gate), Step(update), Step(accept))


def apply_reading(f, m, stages: tuple | None = None) -> None:
    """Run ``m`` through ``stages`` on the filter ``f`` (its bookkeeping copied first: copy-on-write);
    by default ``STAGES``, an acceleration ``ACCELERATION_STAGES``."""
    f.aux = f.aux.copy()
    if stages is None:
        stages = ACCELERATION_STAGES if isinstance(m, Acceleration) else STAGES
    r = Reading(m, m.sensor, isinstance(m, PositionFix))
    for step in stages:
        revision = f.ekf.revision
        verdict = step.judge(f, r)
        route(f, verdict.events)
        if verdict.kind is Kind.EXCLUDED:
            excluded(f, r)
            return
        if verdict.kind is Kind.DONE:
            return
        if step.renew and f.ekf.revision != revision:   # the stage replaced the covariance
            r.innovate(f)


def apply_excluded(f, m, shown: float) -> None:
    """Apply ``m``, which a fault test excluded after the fact (a slip's onset, having seen a
    disagreement of ``shown`` [m/s]: Episodes.excluded), and route the effects it asks."""
    route(f, f.episodes.excluded(m, shown))

"""The filter's bookkeeping that rolls back with x and P (filter.py): ``Bookkeeping`` and the
records it holds. Copy-on-write: ``Bookkeeping.copy`` is shallow, and neither its containers
nor its records are changed in place, only replaced (a record by ``_replace``)."""
from __future__ import annotations

import math
from typing import NamedTuple

from .inertial import InertialView


class UnexplainedFix(NamedTuple):
    """An absolute fix the gate rejected (or the dead-reckoned position at a fix-bias
    inconsistency), kept as the alternative until a fix of another reference decides."""

    stamp: float        # [s]
    z: float            # the kept position [m]
    R: float            # its variance [m^2]
    s: float            # the filter's position then [m]
    P00: float          # the filter's position variance then [m^2]
    sensor: str
    reference: str      # the fix's reference id
    opened: tuple       # the speed sources whose scale was opened for it (a scale fault of theirs explains it)


class View(NamedTuple):
    """A relative sensor's view while it is excluded: where it puts the train against the filter
    (``Bookkeeping.relative_alternatives``, ``Bookkeeping.episode_views``)."""

    separation: float   # D: the distance it ran ahead of the filter [m]
    white_var: float    # the white variance of D [m^2]
    since: float        # when the view began [s]
    last: float         # its last reading [s]
    run: float          # the distance run since it began [m]
    farthest: float     # the D farthest from 0 so far [m]
    base: float         # the filter's position variance when it began or a fix last located it [m^2]


class Candidate(NamedTuple):
    """The first fix of a sensor that can misread its reference, awaiting confirmation."""

    stamp: float        # [s]
    z: float            # its position [m]
    R: float            # its variance [m^2]
    s: float            # the filter's (dead-reckoned) position then [m]
    sensor: str
    reference: str      # its reference id
    P00: float          # the filter's position variance then [m^2]


class ModelView(NamedTuple):
    """The motion model's hypothesis from the start of a coasting in progress (or of a lone
    source), conditioned on the fixes since: its kinematic state at ``stamp``."""

    stamp: float        # the time of s, v, a [s]
    s: float            # position [m]
    v: float            # speed [m/s]
    a: float            # acceleration [m/s^2]
    cov: tuple          # their covariance (P00, P01, P02, P11, P12, P22) [m^2, m^2/s, m^2/s^2, ...]


class MovedView(NamedTuple):
    """A motion-model hypothesis that moves with the filter (a coasting that ended, a lone
    source's solution that got company)."""

    s: float            # its position [m] when the filter was at s_filter
    var: float          # its variance [m^2]
    s_filter: float     # the filter's position then [m]
    P00_filter: float   # the filter's position variance then [m^2]
    r: float            # the common scale error of the sources in use [1]
    var_r: float        # its variance [1]
    until: float        # the end of that common error [s]


class LoneView(NamedTuple):
    """The solution without a lone speed source with a persistent fault mode."""

    view: ModelView     # the motion model since that sensor became the lone one
    sensor: str         # the lone sensor
    bound: float        # the position error [m] its scale fault can have put into the filter
    inertial: InertialView | None = None  # the accelerometer's dead reckoning since (inertial.py), if one reads
    since: float = -math.inf  # [s] the time it started from the filter's state: a fault of its sensor that
                              # began later is in it, not in its start


class NisSum(NamedTuple):
    """The accepted measurements of a sensor: how many and their summed NIS."""

    count: int
    total: float        # sum of NIS [1]


class Fault(NamedTuple):
    """A fault seen as a disagreement at a speed."""

    disagreement: float   # [m/s]
    speed: float          # [m/s]


class WindowEntry(NamedTuple):
    """One reading of a disagreement window (``views.windowed``)."""

    stamp: float        # [s]
    distance: float     # e d [m]: the disagreement e [m/s] times the weight d
    white_var: float    # its white variance [m^2]
    common_sd: float    # the stddev of its sensor's own error states' part [m]
    weight: float       # d: the increment's duration [s] (1 for a speed)
    speed: float        # the filter's |speed| [m/s]


class Suspension(NamedTuple):
    """A speed source found faulty, waiting to agree again."""

    since: float            # agreeing since [s] (inf while it does not)
    window: tuple           # its disagreement window (WindowEntry, ...)
    fault: Fault | None     # the fault seen, None if its size is unknown


class ViewSpeed(NamedTuple):
    """The last reading of a sensor with an undecided view."""

    stamp: float        # [s]
    speed: float        # [m/s]
    var: float          # its own variance [m^2/s^2]


class PeerSpeed(NamedTuple):
    """The last reading of an excluded speed source while none is in use."""

    stamp: float        # [s]
    speed: float        # [m/s]
    white_var: float    # [m^2/s^2]
    common_var: float   # the part of its own error states [m^2/s^2]


class PeerRun(NamedTuple):
    """A run of agreement of two excluded speed sources."""

    pair: tuple         # (sensor, sensor), sorted
    first: float        # its first stamp [s]
    last: float         # its last stamp [s]
    n: int              # readings
    sum_diff: float     # sum of the differences of their speeds [m/s]
    sum_white: float    # sum of their white variances [m^2/s^2]


class FaultWindow(NamedTuple):
    """An excluded sensor with a bounded fault duration: the fit of a scale error of the other
    source to their disagreements e [m/s] at its speeds v [m/s], variances S [m^2/s^2]."""

    against: tuple      # (the other source, whether it is in use)
    since: float        # its first excluded reading [s]
    window: tuple       # disagreement window (WindowEntry, ...)
    n: int              # readings
    sum_ev: float       # sum of e v / S [1]
    sum_vv: float       # sum of v^2 / S [1]
    sum_ee: float       # sum of e^2 / S [1]


class Bookkeeping:
    """Bookkeeping that rolls back with x and P. Copy-on-write: ``copy`` is shallow and the
    containers are never changed in place, only replaced.

    Each field is written from one module, its owner; the others ask it through the events the
    pipeline routes (events.py) or, for the owners that are not policies (counts, bank, the
    filter), through their functions (``tools/fusion_metrics.py`` counts the writers):

      filter.py        t, odometer
      counts.py        events, accepted, gated, last_accepted
      bank.py          impacts
      pipeline.py      nis, fix_ref, speed_sources, last_drive
      fixes.py         initialised, s_last_fix, last_fix_accepted, fix_nis, fix_bias_nis, alternative,
                       candidate, used_refs, unverified
      episodes.py      slips, slip_until, slip_window, episode_views, fault_windows
      arbitration.py   suspended, relative_alternatives, view_speeds, scale_faults
      motion_views.py  motion_views, peer_speeds, peer_run
      solutions.py     subs
      lone.py          lone_view
    """

    __slots__ = ("initialised", "t", "last_accepted", "slip_until", "accepted", "gated", "slips",
                 "speed_sources", "nis", "fix_ref", "last_fix_accepted", "fix_nis", "slip_window",
                 "alternative", "events", "unverified", "s_last_fix", "relative_alternatives", "suspended",
                 "candidate", "used_refs", "peer_speeds", "peer_run", "motion_views", "view_speeds",
                 "episode_views", "fault_windows", "subs", "fix_bias_nis", "lone_view", "scale_faults",
                 "impacts", "odometer", "last_drive")

    def __init__(self):
        self.initialised = False
        self.t: float | None = None           # time of x, P [s]
        self.last_accepted: dict[str, float] = {}
        self.slip_until: dict[str, float] = {}
        self.accepted: dict[str, int] = {}
        self.gated: dict[str, int] = {}
        self.slips = 0
        self.speed_sources: frozenset = frozenset()   # classes that gave speed/distance
        self.nis: dict[str, NisSum] = {}               # sensor -> its accepted ones
        self.fix_ref: dict[str, str] = {}              # sensor -> reference of its current fix bias
        self.last_fix_accepted = -math.inf
        self.fix_nis: tuple = ()                       # NIS of the last accepted absolute fixes
        self.fix_bias_nis: dict[str, tuple] = {}       # the same per sensor with a fix-bias state
        self.slip_window: dict[str, tuple] = {}        # sensor -> (WindowEntry, ...)
        # unexplained fix (or dead-reckoned position) kept as the alternative
        self.alternative: UnexplainedFix | None = None
        self.events: dict[str, int] = {}
        self.unverified = ""                           # why the filter awaits a confirming fix
        self.s_last_fix = math.nan                     # filter position after the last accepted fix
        # sensors excluded although their disagreement does not look like a slip: the other speed
        # sources may be the wrong ones: sensor -> its view
        self.relative_alternatives: dict[str, View] = {}
        # the speed each of those sensors last read: the published speed uncertainty covers it
        # while its view is undecided
        self.view_speeds: dict[str, ViewSpeed] = {}
        # a sensor excluded for a slip or slide (its own fault, not kept in the interval): its
        # view all the same; and each excluded sensor with a bounded fault duration: the fit of a
        # scale error of the other source (``Episodes.outlasted``)
        self.episode_views: dict[str, View] = {}
        self.fault_windows: dict[str, FaultWindow] = {}
        self.candidate: Candidate | None = None        # first fix awaiting confirmation
        self.used_refs: tuple = ()                     # (sensor, reference) of the last accepted fixes
        self.suspended: dict[str, Suspension] = {}     # speed sources found faulty
        # while no speed source is accepted: each excluded one's last reading, and the run of
        # agreement of a pair
        self.peer_speeds: dict[str, PeerSpeed] = {}
        self.peer_run: PeerRun | None = None
        # the motion model's own hypotheses of coastings between disagreeing speed sources: a
        # ModelView from the start of a coasting in progress, or a MovedView from its end
        self.motion_views: tuple = ()
        # each relative sensor's own solution from the fixes (separation.py): sensor -> Sub
        self.subs: dict = {}
        # while one relative sensor with a persistent fault mode carries the speed alone: the
        # solution without it (the fixes and the motion model, ``LoneSource.track``)
        self.lone_view: LoneView | None = None
        # speed sources whose scale fault the others showed and whose constant scale now learns
        # it (``Arbitration.relearn_fault``): their scale is plausible up to the fault's size
        self.scale_faults: frozenset = frozenset()
        # the persistent-fault hypotheses of the relative sensors (impact.py Bank), None before any
        self.impacts = None
        # the filter's position moved by its own speed only, without the corrections of updates [m]:
        # how far the filter believes the train ran between two times (separation.py follows it)
        self.odometer = 0.0
        # the last time [s] the train was driven or braked with at least ``slip_min_drive``: a wheel
        # slips or slides only then, and an episode ends within its ``fault_duration_max``
        self.last_drive = -math.inf

    def copy(self) -> "Bookkeeping":
        new = object.__new__(Bookkeeping)
        for name in Bookkeeping.__slots__:
            setattr(new, name, getattr(self, name))
        return new


def is_coasting(aux: Bookkeeping) -> bool:
    """Whether the filter coasts between disagreeing speed sources (a motion-model hypothesis
    of a coasting in progress)."""
    return bool(aux.motion_views) and isinstance(aux.motion_views[-1], ModelView)


def speed_excluded(aux: Bookkeeping, cls: str, stamp: float) -> bool:
    """Whether speed source ``cls`` is excluded at ``stamp`` (suspended, or in a slip episode)."""
    return cls in aux.suspended or aux.slip_until.get(cls, -math.inf) > stamp


def without_key(mapping: dict, key: str) -> dict:
    """A copy of ``mapping`` without ``key`` (the Bookkeeping containers are replaced, never changed)."""
    return {k: v for k, v in mapping.items() if k != key}


def new_view(stamp: float, P00: float) -> View:
    """A relative sensor's view as it begins at ``stamp`` [s], the filter's position variance
    P00 [m^2] its base."""
    return View(0.0, 0.0, stamp, stamp, 0.0, 0.0, P00)


def incremented(counter: dict, key: str) -> dict:
    """A copy of ``counter`` with ``key`` counted once more."""
    new = dict(counter)
    new[key] = new.get(key, 0) + 1
    return new


def fault_at(fault: Fault, speed: float) -> float:
    """The size [m/s] at ``speed`` [m/s] of a fault seen as a disagreement e0 at speed v0:
    a scale error (e0 v / v0) or a bias (e0), the smaller of the two."""
    e0, v0 = abs(fault.disagreement), abs(fault.speed)
    return e0 * (min(1.0, abs(speed) / v0) if v0 > 0.0 else 1.0)


# motion-model hypotheses kept at once (coastings between disagreeing speed sources)
MAX_MOTION_VIEWS = 4

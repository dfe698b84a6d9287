"""Effects a policy asks of another policy: returned with its verdict, routed by the pipeline
(pipeline.py ``ROUTES``) to the policy that owns what they change, in the order returned. A
routed effect may return effects of its own, routed right after it (before the ones waiting)."""
from __future__ import annotations

from typing import NamedTuple


class Separate(NamedTuple):
    """An excluded reading adds to its sensor's view (Episodes.separate: its own view; an undecided
    one is the arbitration's, ViewSeparates)."""

    m: object       # the reading
    e: float        # its disagreement [m/s]
    S: float        # its innovation variance [m^2/s^2]


class ViewSeparates(NamedTuple):
    """An excluded reading adds to its sensor's undecided view (Arbitration.view_separates)."""

    m: object       # the reading
    e: float        # its disagreement [m/s]
    S: float        # its innovation variance [m^2/s^2]


class Undecided(NamedTuple):
    """Excluded sensor ``cls`` may be the right one: ``view`` (bookkeeping.View) kept as the
    undecided alternative (Arbitration.undecided)."""

    cls: str
    view: object


class ViewMerged(NamedTuple):
    """Sensor ``cls``'s undecided view merged into the position covariance: no longer tracked
    (Arbitration.view_merged)."""

    cls: str


class ViewDropped(NamedTuple):
    """Sensor ``cls`` gives the speed: its undecided view and last speed dropped (Arbitration.view_dropped)."""

    cls: str


class SuspensionsEnded(NamedTuple):
    """The speed taken from ``sensors``: their suspensions end (Arbitration.suspensions_ended)."""

    sensors: set


class ScaleFaultsReset(NamedTuple):
    """The error states re-learnt from their priors: the scale faults being learnt end, but those of
    ``keep`` (Arbitration.scale_faults_reset)."""

    keep: tuple


class FaultEnded(NamedTuple):
    """The scale fault being learnt of speed source ``cls`` has ended (Arbitration.end_fault)."""

    cls: str


class EpisodeEnded(NamedTuple):
    """A fix found speed source ``cls`` right: its slip episode ends at ``stamp`` [s] (Episodes.episode_ended)."""

    cls: str
    stamp: float


class EpisodesEnded(NamedTuple):
    """The speed taken from ``sensors`` at ``stamp`` [s]: their slip episodes end, their slip tests'
    windows start again (Episodes.episodes_ended)."""

    stamp: float
    sensors: set


class SlipWindow(NamedTuple):
    """The slip test's window of ``cls`` from here: ``window`` ((WindowEntry, ...)), or None: it starts
    again (Episodes.set_window)."""

    cls: str
    window: tuple | None


class OwnViewEnded(NamedTuple):
    """Sensor ``cls``'s own view (a slip's) ends, and with ``fault_window`` the fit of the other
    source's scale error to it (Episodes.own_view_ended)."""

    cls: str
    fault_window: bool = True


class RelearnFault(NamedTuple):
    """Speed source ``cls`` is back in use, its scale opened to learn its fault (Arbitration.relearn_fault)."""

    cls: str


class Suspend(NamedTuple):
    """Speed source ``cls`` suspended for the fault seen (Arbitration.suspend)."""

    cls: str
    fault: object   # bookkeeping.Fault, or None if its size is not known


class TakeSpeed(NamedTuple):
    """The speed taken from ``readings`` ((speed [m/s], variance [m^2/s^2]), ...), the exclusions of
    ``sensors`` ended at ``stamp`` [s] (MotionViews.take_speed)."""

    stamp: float
    readings: list
    sensors: set


class SetSpeed(NamedTuple):
    """The speed taken from ``readings`` ((speed [m/s], variance [m^2/s^2]), ...) (MotionViews.set_speed)."""

    readings: list


class CommonErrorEnded(NamedTuple):
    """The newest motion-model hypothesis that moves with the filter no longer shares an error
    with the sources in use (MotionViews.common_error_ended)."""


class Swap(NamedTuple):
    """Excluded sensor ``m.sensor`` was right, ``other`` in use is faulty (Arbitration.swap)."""

    m: object       # the reading
    z: float        # its value
    R: float        # its variance
    view: object    # its view (bookkeeping.View)
    other: str


class SetPosition(NamedTuple):
    """The position from fix ``m`` alone (Fixes.set_position)."""

    m: object


class Relearn(NamedTuple):
    """The relative sensors' error states back to their priors, for ``reason`` (an event name), the
    scales of ``faulty`` opened to their fault's size (Plausibility.relearn)."""

    reason: str
    faulty: tuple = ()


class SeedSubs(NamedTuple):
    """Every relative sensor's own solution starts again from the filter's position at ``stamp`` [s]
    (Solutions.seed_subs)."""

    stamp: float


class FirstPosition(NamedTuple):
    """The position claimed for the first time at ``stamp`` [s]: the motion model's hypotheses from
    before take it (MotionViews.first_position)."""

    stamp: float


class KeepMotionView(NamedTuple):
    """A hypothesis that moves with the filter (bookkeeping.MovedView) kept among the motion
    model's own (MotionViews.keep)."""

    view: object


class MotionViewsTakeFix(NamedTuple):
    """The motion model's hypotheses conditioned on an accepted fix ``m`` located at z [m],
    variance R [m^2] (MotionViews.take_fix)."""

    m: object
    z: float
    R: float


class AwaitFix(NamedTuple):
    """The filter awaits a confirming fix for ``reason`` (an event name; Fixes.await_fix);
    ``replace`` False: an earlier reason stays."""

    reason: str
    replace: bool = True


class LoneReset(NamedTuple):
    """The position was taken from a fix alone: the lone source's solution starts again (LoneSource.reset)."""


class LoneTakeFix(NamedTuple):
    """The lone source's hypothesis conditioned on an accepted fix ``m`` located at z [m], variance
    R [m^2] (LoneSource.take_fix)."""

    m: object
    z: float
    R: float

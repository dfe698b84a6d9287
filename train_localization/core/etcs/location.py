"""The ETCS location report of one train from its fused state and its balise reads (SUBSET-026
section 3.6; docs/etcs.md): the functional core of the ``etcs_location`` node.

Safe front ends. The fused state's interval [position_min, position_max] is the protection
level of the integrity work: it contains the true front at the state's confidence, balise
location errors included (the Eurobalise reader's error model has each balise's Q_LOCACC as
the bound of its location error, core/sensors/eurobalise.py); its speed interval v_est +-
v_ura contains the true speed at the same confidence. So each state's interval since the LRBG,
moved on by the speed interval since, still holds the front: the min and max safe front ends
are the ends of the intersection of these with the state's own interval (core/etcs/carried.py,
restarted at each LRBG, never excluding the estimate), taken along the train's orientation, and

    L_DOUBTOVER  = estimated - min safe front end     (the odometer may have over-read)
    L_DOUBTUNDER = max safe front end - estimated     (it may have under-read)

asymmetric where the fusion's interval is (a slipping wheel over-reads). They play the part
of SUBSET-026 3.6.4's Q_LOCACC + over-/under-reading amount, and can be smaller than the
LRBG's Q_LOCACC when other groups and sensors locate the train better than the LRBG alone.
While the odometer monitoring (core/etcs/odometer.py) finds the odometer impaired they are
at least Q_LOCACC + 5 m + 5 % of the distance from the LRBG (SUBSET-041 5.3.1.1), the mode at
least DEGRADED. v_ura = z x speed_stddev, z the two-sided normal quantile of the state's
confidence.

LRBG. A balise fix (PositionFix of the Eurobalise reader, ``reference_id`` a balise id) is
taken once a fused state at or after its stamp has come (the interval at the read is then
known: the nearer of the two states around the stamp, widened to both). Its group becomes the
LRBG (event LRBG) when
  * the track has no linking, or there is no LRBG yet, or the LRBG's linking announces no
    group in the direction of travel (the event says "unlinked"); or
  * it is the group the linking expects and was read inside its expectation window
    (core/etcs/linking.py) in the link's direction.
A group that the linking does not announce (the first, after a reset, on a line without
linking) is placed before it is taken: its read must lie within the fused interval at the read
(the first claimed one after it, widened by how far the train can have gone since, when the
fusion claimed no position at the read) plus the group's Q_LOCACC plus ``reference_sigmas`` of
the read's 1-sigma, and name a balise at most ``max_reader_offset`` from the front it gives (the
LRBG's own offset, once there is one); otherwise it is refused (REFERENCE_REJECTED): one
spoofed read naming a group kilometres away never becomes the LRBG.
Otherwise it is not taken: a group outside its window (OUTSIDE_WINDOW), passed against its
link (WRONG_DIRECTION, reaction train trip), a group the linking does not announce
(NOT_LINKED), a balise the ETCS data do not know (UNKNOWN_GROUP). A read of the LRBG's own
group again (its second balise, a reversal over it) changes nothing. A linked group whose
window closed (the min safe front end past its end) ``fix_latency`` ago without a read is
missed (MISSED_LINKED_GROUP with the link's Q_LINKREACTION); the linking chains on from it.
The direction of travel is the fix's (the order of a group's balises) where it has one, else
the fused speed's sign where |v| > v_ura. The last ``PREVIOUS_LRBGS`` LRBGs are kept.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from ..measurements import PositionFix
from ..safety.plausibility import PARAMS as MOTION_PARAMS
from ..safety.plausibility import speed_bound
from ..sensors.base import Param, check_declared, resolve_params
from . import odometer
from .carried import CarriedInterval, CarriedStep
from .state_history import StateHistory
from .linking import Expectation, expect
from .records import EventKind, LocationEvent, LocationReport, QDirLrbg, Reaction
from .track_data import EtcsData

READER = "eurobalise"      # sensor class of the Eurobalise reader's fixes
PREVIOUS_LRBGS = 8          # LRBGs kept besides the current one (SUBSET-026 3.6.2.2.2: at least 7)
MODE_NOMINAL, MODE_DEGRADED = 1, 2
# [m/s^2] placing a read back from a later state: any train's acceleration (the plausibility's)
REACH_ACCELERATION = MOTION_PARAMS["max_acceleration"].default

PARAMS = {
    "orientation": Param(1, "direction the train's front faces: +1 increasing chainage, -1 decreasing", (-1, 1)),
    "fix_latency": Param(1.0, "longest a balise fix takes to arrive after its stamp [s]: a linked group is "
                              "missed this long after its window closed", (0.0, 30.0)),
    "history": Param(30.0, "fused states kept to place late balise fixes [s]; an older fix is refused",
                     (1.0, 600.0)),
    "max_reader_offset": Param(50.0, "largest distance between a balise read and the front it gives (the "
                                     "reader antenna's place on the train) [m]: a read naming a group further "
                                     "from its front is refused (REFERENCE_REJECTED)", (0.0, 1000.0)),
    "reference_sigmas": Param(5.0, "a group not announced by the linking is taken as the LRBG only if its read "
                                   "lies within the fused interval plus its Q_LOCACC plus this many of the "
                                   "read's 1-sigma [1]", (0.0, 100.0)),
    **odometer.PARAMS,
}
check_declared(PARAMS, "etcs location PARAMS")


def is_balise_fix(m) -> bool:
    """True for a PositionFix of the Eurobalise reader (what ``LocationTracker.on_fix`` takes)."""
    return isinstance(m, PositionFix) and m.sensor == READER


@dataclass(frozen=True)
class FusedState:
    """What the location function takes of a fused state (TrainState / core.fusion Estimate).
    On a network (``path_direction`` != 0) also the section ``track_id`` of ``position`` and the
    state as path distances [m] (TrainState path_*; core/etcs/network_location.py)."""
    t: float
    position: float
    position_min: float
    position_max: float
    speed: float
    speed_stddev: float
    confidence: float
    mode: int
    track_id: str = ""
    path_position: float = math.nan
    path_min: float = math.nan
    path_max: float = math.nan
    path_direction: int = 0

    @classmethod
    def from_estimate(cls, est) -> "FusedState":
        return cls(est.stamp, est.position, est.position_min, est.position_max, est.speed, est.speed_stddev,
                   est.confidence, est.mode, getattr(est, "track_id", ""), getattr(est, "path_position", math.nan),
                   getattr(est, "path_min", math.nan), getattr(est, "path_max", math.nan),
                   getattr(est, "path_direction", 0))

    @property
    def claimed(self) -> bool:
        return self.mode in (MODE_NOMINAL, MODE_DEGRADED)


@dataclass
class _Lrbg:
    nid_bg: str
    t: float
    direction: int          # of travel over it: +1 increasing chainage, -1, 0 unknown
    odometer: float         # odometer reading at the read [m]


class LocationTracker:
    """``on_fix`` takes balise fixes, ``on_state`` the fused states (in time order) and returns
    the report of that state and the events it completed; ``stats`` counts what was refused."""

    def __init__(self, data: EtcsData, params: dict | None = None):
        self.data = data
        self.params = resolve_params(PARAMS, params)
        self.orientation = 1 if int(self.params["orientation"]) >= 0 else -1
        self.monitor = odometer.OdometerMonitor(self.params)
        self.lrbg: _Lrbg | None = None
        self.previous: deque[str] = deque(maxlen=PREVIOUS_LRBGS)
        self.expected: Expectation | None = None
        self._missed_chain: tuple[str, float] = ("", 0.0)   # (group the links chain on from, distance to it)
        self._front_offset = 0.0
        self._closed_at: float | None = None
        self._states = StateHistory()   # the fused states with the odometer reading [m] at each
        self._odometer = 0.0
        self._pending: list[PositionFix] = []
        self.carried = CarriedInterval()
        # while True a linked group whose window closed is not declared missed yet (on a network:
        # a read waits for the followed path to reach its section, core/etcs/network_location.py)
        self.hold_missed = False
        self.stats = {"fixes": 0, "lrbg": 0, "outside_window": 0, "missed": 0, "wrong_direction": 0,
                      "not_linked": 0, "unknown_group": 0, "same_group": 0, "too_old": 0, "direction_unknown": 0,
                      "reference_rejected": 0}

    # ----------------------------------------------------------------------- inputs
    def on_fix(self, fix: PositionFix) -> None:
        """A balise fix; taken at the first fused state at or after its stamp."""
        self.stats["fixes"] += 1
        self._pending.append(fix)

    def on_state(self, state: FusedState) -> tuple[LocationReport, list[LocationEvent]]:
        """The report of one fused state (states in time order) and the events due by then."""
        if self._states:
            last, reading = self._states.last()
            self._odometer = reading + 0.5 * (last.speed + state.speed) * (state.t - last.t)
        self._states.append(state, self._odometer)
        self._states.forget_before(state.t - self.params["history"])
        events: list[LocationEvent] = []
        due = sorted((f for f in self._pending if f.stamp <= state.t), key=lambda f: f.stamp)
        self._pending = [f for f in self._pending if f.stamp > state.t]
        waiting = []
        for fix in due:
            taken = self._take(fix)
            if taken is None:
                waiting.append(fix)
            else:
                events += taken
        self._pending += waiting
        events += self._check_window(state)
        lo, hi = self.carried.advance(CarriedStep(state.t, state.position_min, state.position_max, state.speed,
                                                  self._v_ura(state)))
        return self._report(state, lo, hi), events

    # ----------------------------------------------------------------------- reads
    def _at(self, t: float) -> tuple[FusedState, float, float, float] | None:
        """(state nearest t, odometer at t [m], interval lo, hi around t) from the history, None if too old."""
        if not self._states or t < self._states.first_time() - 1e-9:
            return None
        (s0, o0), (s1, o1) = self._states.around(t)
        f = 0.0 if s1.t == s0.t else (t - s0.t) / (s1.t - s0.t)
        nearest = s1 if f >= 0.5 else s0
        lo, hi = min(s0.position_min, s1.position_min), max(s0.position_max, s1.position_max)
        return nearest, o0 + f * (o1 - o0), lo, hi

    def _travel_direction(self, state: FusedState) -> int:
        """+1 / -1 where the fused speed's sign is sure (|v| > v_ura), else 0."""
        if abs(state.speed) > self._v_ura(state):
            return 1 if state.speed > 0 else -1
        return 0

    def _direction(self, fix: PositionFix, state: FusedState) -> int:
        if fix.direction:
            return 1 if fix.direction > 0 else -1
        return self._travel_direction(state)

    def _event(self, t, kind, nid, reaction=Reaction.NONE, detail="") -> LocationEvent:
        return LocationEvent(float(t), EventKind(kind), nid, Reaction(reaction), detail)

    def _take(self, fix: PositionFix) -> list[LocationEvent] | None:
        """The events of a due fix; None to keep it waiting (an unannounced group, no claimed
        state yet to place it against)."""
        nid = self.data.group_of_balise.get(fix.reference_id)
        if nid is None:
            self.stats["unknown_group"] += 1
            return [self._event(fix.stamp, EventKind.UNKNOWN_GROUP, fix.reference_id,
                                detail=f"balise {fix.reference_id} is in no balise group of the ETCS data: ignored")]
        at = self._at(fix.stamp)
        if at is None:
            self.stats["too_old"] += 1
            return []
        state, reading, lo, hi = at
        if self.lrbg is not None and nid == self.lrbg.nid_bg:
            self.stats["same_group"] += 1
            if fix.direction and not self.lrbg.direction:
                self.lrbg.direction = 1 if fix.direction > 0 else -1
            return []
        direction = self._direction(fix, state)
        exp = self.expected
        if exp is not None and nid == exp.nid_bg:
            if fix.direction and (1 if fix.direction > 0 else -1) != exp.direction:
                self.stats["wrong_direction"] += 1
                return [self._event(fix.stamp, EventKind.WRONG_DIRECTION, nid, Reaction.TRAIN_TRIP,
                                    f"group {nid} passed towards {fix.direction:+d}, linked towards {exp.direction:+d}")]
            offset = fix.position - self._balise_chainage(fix.reference_id)
            window = (exp.window[0] + offset - self._front_offset, exp.window[1] + offset - self._front_offset)
            if not (lo <= window[1] and hi >= window[0]):
                self.stats["outside_window"] += 1
                return [self._event(fix.stamp, EventKind.OUTSIDE_WINDOW, nid, Reaction.NONE,
                                    f"group {nid} read with the front in [{lo:.2f}, {hi:.2f}] m, window "
                                    f"[{window[0]:.2f}, {window[1]:.2f}] m: rejected")]
            return self._new_lrbg(fix, nid, exp.direction, reading, exp, "linked")
        if exp is not None:
            self.stats["not_linked"] += 1
            return [self._event(fix.stamp, EventKind.NOT_LINKED, nid, Reaction.NONE,
                                f"group {nid} read while the linking expects {exp.nid_bg}: ignored")]
        placed = self._placed(fix, nid)
        if placed is None:
            return None
        if placed:
            self.stats["reference_rejected"] += 1
            return [self._event(fix.stamp, EventKind.REFERENCE_REJECTED, nid, Reaction.NONE, placed)]
        if direction == 0:
            self.stats["direction_unknown"] += 1
        return self._new_lrbg(fix, nid, direction, reading, None, "unlinked")

    def _placed(self, fix: PositionFix, nid: str) -> str | None:
        """Why the read ``fix`` of unannounced group ``nid`` cannot be where the location places
        the train ("" if it can; None: no claimed state yet to tell, keep it waiting)."""
        offset = fix.position - self._balise_chainage(fix.reference_id)
        if self.lrbg is not None:
            tolerance = self.params["reference_sigmas"] * fix.position_stddev + 1.0
            if abs(offset - self._front_offset) > tolerance:
                return (f"group {nid} read {offset:.2f} m from the front it gives, the LRBG's reads "
                        f"{self._front_offset:.2f} m: refused")
        elif abs(offset) > self.params["max_reader_offset"]:
            return (f"group {nid} read {offset:.2f} m from the front it gives (max_reader_offset "
                    f"{self.params['max_reader_offset']:g} m): refused")
        interval = self._claimed_interval(fix.stamp)
        if interval is None:
            return None
        lo, hi = interval
        margin = self.data.groups[nid].q_locacc + self.params["reference_sigmas"] * fix.position_stddev
        if not lo - margin <= fix.position <= hi + margin:
            return (f"group {nid} read with the front at {fix.position:.2f} m, the fused interval is "
                    f"[{lo:.2f}, {hi:.2f}] m (+- {margin:.2f} m): refused")
        return ""

    def _claimed_interval(self, t: float) -> tuple[float, float] | None:
        """The front's interval [m] at ``t`` [s]: the claimed states around it, or the first
        claimed one after it widened by the reach back to ``t``; None if none claims yet."""
        around = list(self._states.within(t, 0.5))
        claimed = [s for s in around if s.claimed]
        if claimed and len(claimed) == len(around):
            return min(s.position_min for s in claimed), max(s.position_max for s in claimed)
        later = self._states.first_claimed_from(t)
        if later is None:
            return None
        dt = later.t - t
        reach = (abs(later.speed) + self._v_ura(later)) * dt + 0.5 * REACH_ACCELERATION * dt * dt
        return later.position_min - reach, later.position_max + reach

    def _balise_chainage(self, balise: str) -> float:
        group = self.data.groups[self.data.group_of_balise[balise]]
        return group.positions[group.balises.index(balise)]

    def _new_lrbg(self, fix: PositionFix, nid: str, direction: int, reading: float, exp: Expectation | None,
                  how: str) -> list[LocationEvent]:
        events = []
        if exp is not None and self.lrbg is not None:
            measured = abs(reading - self.lrbg.odometer)
            verdict = self.monitor.add(odometer.PairError(fix.stamp, exp.distance, measured - exp.distance))
            if verdict is not None:
                kind = EventKind.ODOMETER_IMPAIRED if verdict else EventKind.ODOMETER_RESTORED
                events.append(self._event(fix.stamp, kind, "", detail=f"odometer {measured:.2f} m over "
                                          f"{exp.distance:.2f} m linked from {self.lrbg.nid_bg} to {nid}"))
        if self.lrbg is not None:
            self.previous.appendleft(self.lrbg.nid_bg)
        self.lrbg = _Lrbg(nid, fix.stamp, direction, reading)
        self.carried.restart()
        self._front_offset = fix.position - self._balise_chainage(fix.reference_id)
        self.stats["lrbg"] += 1
        self._missed_chain = (nid, 0.0)
        self._expect(direction)
        events.append(self._event(fix.stamp, EventKind.LRBG, nid, detail=f"{how} group {nid} is the LRBG"))
        return events

    def _expect(self, direction: int) -> None:
        self._closed_at = None
        if self.lrbg is None or direction == 0:
            self.expected = None
            return
        after, so_far = self._missed_chain
        self.expected = expect(self.data, self.data.groups[self.lrbg.nid_bg], after, direction, so_far,
                               self._front_offset)

    def rebase(self, data: EtcsData) -> None:
        """New ETCS data on the same axis (a network's followed path regrown or turned onto
        another way): the LRBG and the history kept, the expectation derived again from the new
        linking (chained on from a missed group only if the new data still have it); an
        unchanged expectation keeps its window's closing time."""
        self.data = data
        if self.lrbg is None:
            return
        if self._missed_chain[0] not in data.groups:
            self._missed_chain = (self.lrbg.nid_bg, 0.0)
        before, closed = self.expected, self._closed_at
        self._expect(self.lrbg.direction)
        if before is not None and before == self.expected:
            self._closed_at = closed

    def _retarget(self, direction: int) -> None:
        """The train runs towards ``direction`` over the LRBG: the linking that way on from it."""
        self.lrbg.direction = direction
        self._missed_chain = (self.lrbg.nid_bg, 0.0)
        self._expect(direction)

    def _check_window(self, state: FusedState) -> list[LocationEvent]:
        exp = self.expected
        if self.lrbg is None or not state.claimed:
            return []
        d = self._travel_direction(state)
        if exp is None:
            if self.data.linked and d and d != self.lrbg.direction:   # a reversal
                self._retarget(d)
            return []
        if d == -exp.direction:
            # the train runs the other way: expect the group linked that way instead
            self._retarget(d)
            return []
        if not exp.passed(state.position_min, state.position_max):
            self._closed_at = None
            return []
        if self._closed_at is None:
            self._closed_at = state.t
        if state.t < self._closed_at + self.params["fix_latency"] or self.hold_missed:
            return []
        self.stats["missed"] += 1
        event = self._event(self._closed_at, EventKind.MISSED_LINKED_GROUP, exp.nid_bg, exp.reaction,
                            f"linked group {exp.nid_bg} not read in its window [{exp.window[0]:.2f}, "
                            f"{exp.window[1]:.2f}] m")
        self._missed_chain = (exp.nid_bg, exp.distance)
        self._expect(exp.direction)
        return [event]

    # ----------------------------------------------------------------------- report
    @staticmethod
    def _v_ura(state: FusedState) -> float:
        return speed_bound(state.confidence, state.speed_stddev)

    def _report(self, state: FusedState, lo: float, hi: float) -> LocationReport:
        """The report of ``state`` with [``lo``, ``hi``] [m] its carried interval (core/etcs/carried.py)."""
        o = self.orientation
        est = state.position
        if math.isfinite(est):   # the safe front ends never exclude the estimate
            lo, hi = min(lo, est), max(hi, est)
        ahead_min, ahead_max = (lo, hi) if o > 0 else (hi, lo)
        over, under = abs(est - ahead_min), abs(ahead_max - est)
        lrbg = self.data.groups[self.lrbg.nid_bg] if self.lrbg is not None else None
        d_lrbg = (est - lrbg.reference) * lrbg.orientation if lrbg is not None else math.nan
        q = lrbg.q_locacc if lrbg is not None else math.nan
        mode = state.mode
        if self.monitor.impaired:
            fallback = (q if lrbg is not None else 0.0) + self.monitor.allowance(d_lrbg if lrbg is not None else 0.0)
            over, under = max(over, fallback), max(under, fallback)
            mode = MODE_DEGRADED if mode == MODE_NOMINAL else mode
        if lrbg is None:
            qdir = QDirLrbg.UNKNOWN
        else:
            qdir = QDirLrbg.NOMINAL if o == lrbg.orientation else QDirLrbg.REVERSE
        return LocationReport(
            t=state.t, track_id=self.data.track_id, nid_lrbg=lrbg.nid_bg if lrbg is not None else "",
            d_lrbg=d_lrbg, q_dirlrbg=qdir, q_locacc=q, l_doubtover=over, l_doubtunder=under,
            estimated_front_end=est, min_safe_front_end=est - o * over, max_safe_front_end=est + o * under,
            v_est=o * state.speed, v_ura=self._v_ura(state), odometer_impaired=self.monitor.impaired,
            previous_lrbgs=tuple(self.previous), mode=mode,
            lrbg_track_id=self.data.track_id if lrbg is not None else "")

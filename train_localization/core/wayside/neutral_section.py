"""Neutral-section changeover controller (seed 004 section 4.1, Fig. 5-6).

Seed 004 section 4.1: with no train in the sectioning track circuit ABB-1 is on and ABB-2
off, the neutral section is fed from substation A; when a train moves into it, ABB-1 goes
off and ABB-2 on, B feeds it; when the train has left, ABB-2 goes off and ABB-1 on. If the
switching is wrong the pantograph shorts the two phases; the detection must give the
condition in time. Section 4.2 lays two track circuits and three axle counters for both
directions (Fig. 6); here S1 = AC0..AC1 on the A side and S2 = AC1..AC2 on the B side, AC1
in the middle of the neutral section, AC0 / AC2 an approach distance before the air
sections (catenary.Layout).

The controller is driven by the combined occupancy of S1 and S2 (occupancy.py):

  A -> B (enters S1):    feed A while the train crosses air section 1; once its last axle
                         has passed AC1 (the first system to see S1 clear) ABB-1 opens,
                         once both systems see S1 clear ABB-2 closes: the train crosses
                         air section 2 on B; when S2 is clear (both systems), back to A.
  B -> A (enters S2):    ABB-1 opens and ABB-2 closes at once (the train is still an
                         approach distance before air section 2); after its last axle has
                         passed AC1 ABB-2 opens, with S2 clear ABB-1 closes: the train
                         crosses air section 1 on A; nothing switches when it leaves S1.

Opening an ABB at the first sign of a clear section and closing the other only when both
systems agree makes the middle changeover safe whichever system is wrong: a train still
in air section 1 meets a dead neutral (no short), never phase B. The price is dead time:
from the last axle at AC1 until the track circuit has picked up (half a tuned zone plus
its pick-up delay), against the time the train needs to cross an unfed neutral section.

Safe state: both ABBs open (the neutral section is dead; a train coasts through it as
through a conventional neutral section, no pantograph can join A and B through a fed
neutral). Entered, with the reason, on: a DISTURBED or silent section, a system that alone
decides (degraded), a contradiction (the systems disagree beyond the tolerance), an
occupancy sequence no single train makes (both sections occupied from idle, a section
occupied again during the changeover). Left when every section has been CLEAR in both
systems for ``recover_time``. A following train that enters the section behind a leader
that still holds the feed is held the same way (both open) until the leader has cleared,
then the feed is set for the follower ("hold", not latched).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from ..measurements import CLEAR, DISTURBED, OCCUPIED
from ..sensors.base import Param, check_declared, resolve_params
from .catenary import ABB1, ABB2
from .occupancy import STATE_NAMES, CombinedSection

PARAMS = {
    "changeover_gap": Param(0.1, "least time between opening one ABB and closing the other [s] (the opening "
                                 "semiconductor blocks at the next current zero, 8.3 ms at 60 Hz; assumption "
                                 "with margin)", (0.0, 10.0)),
    "recover_time": Param(5.0, "every section CLEAR in both systems for this long ends the safe state [s] "
                               "(assumption)", (0.0, 3600.0)),
}
check_declared(PARAMS, "neutral_section_controller")

FEEDS = {"A": (True, False), "B": (False, True), "OFF": (False, False)}
START = dict(zip((ABB1, ABB2), FEEDS["A"]))     # ABB states at power-up: the neutral fed from A
SAFE = "SAFE"


@dataclass(frozen=True)
class Command:
    """Close (on) or open an ABB, decided at ``stamp`` [s]."""

    stamp: float
    switch: str
    on: bool


class ChangeoverController:
    """State machine of the changeover (see module doc). ``update(now, sections)`` takes the
    combined sections (at least ``west`` = S1 and ``east`` = S2) and returns the ABB commands
    decided now."""

    def __init__(self, overrides: dict | None = None, west: str = "S1", east: str = "S2"):
        self.params = resolve_params(PARAMS, overrides)
        self.west, self.east = west, east
        self.mode = "IDLE"
        self.target = "A"
        self.abb = dict(START)
        self.reason = ""
        self.last_open = -math.inf
        self.safe_since = math.nan
        self._clear_since = math.nan
        self.commands: list[Command] = []
        self.transitions: list[tuple[float, str, str]] = []     # (stamp, mode, why)
        self.safe_entries: list[tuple[float, str]] = []

    @property
    def safe(self) -> bool:
        return self.mode == SAFE

    @property
    def feed(self) -> str:
        """What feeds the neutral now: A, B or OFF."""
        return "A" if self.abb[ABB1] else "B" if self.abb[ABB2] else "OFF"

    def _go(self, now: float, mode: str, target: str | None, why: str) -> None:
        if mode != self.mode:
            self.transitions.append((now, mode, why))
        self.mode = mode
        if target is not None:
            self.target = target

    def _enter_safe(self, now: float, why: str) -> None:
        if not self.safe:
            self.safe_entries.append((now, why))
            self.safe_since = now
        self.reason = why
        self._clear_since = math.nan
        self._go(now, SAFE, "OFF", why)

    def _hold(self, now: float, mode: str, why: str) -> None:
        self.safe_entries.append((now, why))
        self.reason = why
        self._go(now, mode, "OFF", why)

    def _apply(self, now: float) -> list[Command]:
        """Commands that move the ABBs towards the target feed: open first, close after the gap."""
        want = dict(zip((ABB1, ABB2), FEEDS[self.target]))
        out = []
        for sw in (ABB1, ABB2):
            if self.abb[sw] and not want[sw]:
                self.abb[sw] = False
                self.last_open = now
                out.append(Command(now, sw, False))
        for sw in (ABB1, ABB2):
            if want[sw] and not self.abb[sw] and not any(self.abb.values()) \
                    and now >= self.last_open + self.params["changeover_gap"] - 1e-9:
                self.abb[sw] = True
                out.append(Command(now, sw, True))
        self.commands.extend(out)
        return out

    def update(self, now: float, sections: list[CombinedSection]) -> list[Command]:
        by_id = {s.section_id: s for s in sections}
        w, e = by_id.get(self.west), by_id.get(self.east)
        problem = self._problem(w, e)
        if problem:
            self._enter_safe(now, problem)
        elif self.safe:
            if w.state == CLEAR and e.state == CLEAR:
                if math.isnan(self._clear_since):
                    self._clear_since = now
                if now - self._clear_since >= self.params["recover_time"] - 1e-9:
                    self.reason = ""
                    self._go(now, "IDLE", "A", "every section clear in both systems")
            else:
                self._clear_since = math.nan
        else:
            self._step(now, w, e)
        return self._apply(now)

    def _problem(self, w: CombinedSection | None, e: CombinedSection | None) -> str:
        for sid, s in ((self.west, w), (self.east, e)):
            if s is None:
                return f"no detection of section {sid}"
            if s.state == DISTURBED or s.degraded:
                return (f"{sid} {'DISTURBED' if s.state == DISTURBED else 'degraded'}: track circuit "
                        f"{STATE_NAMES[s.tc]}, axle counter {STATE_NAMES[s.ac]}")
            if s.contradiction:
                return (f"{sid} contradictory: track circuit {STATE_NAMES[s.tc]}, axle counter "
                        f"{STATE_NAMES[s.ac]} beyond the tolerance")
        return ""

    def _step(self, now: float, w: CombinedSection, e: CombinedSection) -> None:
        occ_w, occ_e = w.state == OCCUPIED, e.state == OCCUPIED
        clear_w, clear_e = w.state == CLEAR, e.state == CLEAR
        m = self.mode
        if m == "IDLE":
            if occ_w and occ_e:
                self._enter_safe(now, f"{self.west} and {self.east} occupied at once with no train entering")
            elif occ_w:
                self._go(now, "EAST_IN", "A", f"train entered {self.west} (A -> B)")
            elif occ_e:
                self._go(now, "WEST_IN", "B", f"train entered {self.east} (B -> A): neutral to B")
        elif m == "EAST_IN":
            if occ_e:
                self._go(now, "EAST_MID", None, f"train reached {self.east}")
            elif clear_w:
                self._go(now, "IDLE", "A", f"{self.west} clear again (train backed out)")
        elif m == "EAST_MID":
            if w.any_clear:
                self._go(now, "EAST_SWITCH", "OFF", f"last axle left {self.west}: ABB-1 opens")
            elif clear_e:
                self._go(now, "EAST_IN", None, f"{self.east} clear again (train backed)")
        elif m == "EAST_SWITCH":
            if clear_w:
                self._go(now, "EAST_OUT", "B", f"{self.west} clear in both systems: neutral to B")
            elif not w.any_clear:
                self._enter_safe(now, f"{self.west} occupied again during the changeover")
        elif m == "EAST_OUT":
            if occ_w:
                self._hold(now, "HOLD_EAST", f"following train entered {self.west} while the neutral is fed "
                                             f"from B for the leader")
            elif clear_e:
                self._go(now, "IDLE", "A", f"{self.east} clear in both systems: neutral back to A")
        elif m == "HOLD_EAST":
            if clear_e:
                self._go(now, "EAST_IN" if occ_w else "IDLE", "A", f"leader cleared {self.east}: neutral to A")
        elif m == "WEST_IN":
            if occ_w:
                self._go(now, "WEST_MID", None, f"train reached {self.west}")
            elif clear_e:
                self._go(now, "IDLE", "A", f"{self.east} clear again (train backed out)")
        elif m == "WEST_MID":
            if e.any_clear:
                self._go(now, "WEST_SWITCH", "OFF", f"last axle left {self.east}: ABB-2 opens")
            elif clear_w:
                self._go(now, "WEST_IN", None, f"{self.west} clear again (train backed)")
        elif m == "WEST_SWITCH":
            if clear_e:
                self._go(now, "WEST_OUT", "A", f"{self.east} clear in both systems: neutral to A")
            elif not e.any_clear:
                self._enter_safe(now, f"{self.east} occupied again during the changeover")
        elif m == "WEST_OUT":
            if occ_e:
                self._hold(now, "HOLD_WEST", f"following train entered {self.east} while the neutral is fed "
                                             f"from A for the leader")
            elif clear_w:
                self._go(now, "IDLE", "A", f"{self.west} clear in both systems")
        elif m == "HOLD_WEST":
            if clear_w:
                if occ_e:
                    self._go(now, "WEST_IN", "B", f"leader cleared {self.west}: neutral to B")
                else:
                    self._go(now, "IDLE", "A", f"leader cleared {self.west}")

    def status(self) -> dict:
        return {"mode": self.mode, "feed": self.feed, "ABB-1": "on" if self.abb[ABB1] else "off",
                "ABB-2": "on" if self.abb[ABB2] else "off", "safe": self.safe, "reason": self.reason,
                "safe_entries": len(self.safe_entries)}


class SeedMomentsController(ChangeoverController):
    """Seed 004 section 4.1's switching moments, per running direction (tl_neutral
    ``--controller seed``). The seed switches "in the running direction, from one phase to
    the other": with no train in the sectioning track circuit the neutral is fed from the
    phase behind the train, when a train enters it the phase ahead feeds, when it has left,
    back. Section 4.2 lays one circuit per running direction (Fig. 6); a train's sectioning
    circuit is the one it enters second (S2 for A -> B, S1 for B -> A), so it switches at
    the middle counting point, once the front is there:

      A -> B (enters S1):  fed from A; S2 occupied: B (ABB-1 opens, ABB-2 closes after the
                           gap); S1 clear, then S2 clear: back to A.
      B -> A (enters S2):  B feeds at once (the train is an approach distance before air
                           section 2); S1 occupied: A; S2 clear, then S1 clear: idle (A).

    Safe only where every raised pantograph is past the first air section when the front
    reaches the middle: less than half the neutral section behind the front
    (docs/changeover.md, "The seed's moments"). The same detection, safe state, gap and hold
    for a following train as ChangeoverController."""

    def _step(self, now: float, w: CombinedSection, e: CombinedSection) -> None:
        m = self.mode
        if m == "IDLE":
            if w.state == OCCUPIED and e.state == OCCUPIED:
                self._enter_safe(now, f"{self.west} and {self.east} occupied at once with no train entering")
            elif w.state == OCCUPIED:
                self._go(now, "AB_IN", "A", f"train entered {self.west} (A -> B)")
            elif e.state == OCCUPIED:
                self._go(now, "BA_IN", "B", f"train entered {self.east} (B -> A): neutral to B")
            return
        way, stage = m.split("_", 1)
        first, second = (w, e) if way == "AB" else (e, w)
        behind, ahead = ("A", "B") if way == "AB" else ("B", "A")
        name = second.section_id
        if stage == "IN":
            if second.state == OCCUPIED:
                self._go(now, f"{way}_SWITCHED", ahead, f"front entered {name}, its sectioning circuit: neutral "
                                                        f"to {ahead} (seed 004 section 4.1)")
            elif first.state == CLEAR:
                self._go(now, "IDLE", "A", f"{first.section_id} clear again (train backed out)")
        elif stage == "SWITCHED":
            if first.state == CLEAR:
                self._go(now, f"{way}_OUT", None, f"{first.section_id} clear in both systems")
            elif second.state == CLEAR:
                self._go(now, f"{way}_IN", behind, f"{name} clear again (train backed): neutral to {behind}")
        elif stage == "OUT":
            if first.state == OCCUPIED:
                self._hold(now, f"{way}_HOLD", f"following train entered {first.section_id} while the neutral is "
                                               f"fed from {ahead} for the leader")
            elif second.state == CLEAR:
                self._go(now, "IDLE", "A", f"train left {name}: neutral to A")
        elif stage == "HOLD" and second.state == CLEAR:
            if first.state == OCCUPIED:
                self._go(now, f"{way}_IN", behind, f"leader cleared {name}: neutral to {behind}")
            else:
                self._go(now, "IDLE", "A", f"leader cleared {name}")


# the controllers tl_neutral can run: ours (the default) and the seed's moments per direction
CONTROLLERS = {"staged": ChangeoverController, "seed": SeedMomentsController}

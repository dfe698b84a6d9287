"""On-board vs wayside cross-check: each train's fused position interval against the
combined occupancy of the sections (seed 004 section 4.2: the wayside detection as an
independent check of where the trains are).

A train claims an interval for its front, [front_min, front_max] (the fusion's confidence
interval), a length and an orientation o (+1: the front faces increasing chainage). Its
body then surely covers [front_max - L, front_min] (o = +1; mirrored for -1) when the
interval is shorter than the train, and may cover [front_min - L, front_max]. Two flags:

  * ``claims_clear``: the surely covered part reaches more than ``margin`` into a section
    that both wayside systems report CLEAR: the train claims to be where the line sees
    nobody (a fused position off by a section, or a train the wayside does not see);
  * ``unclaimed``: a section reported OCCUPIED that no valid train may cover (its possible
    body widened by ``margin``): something is there that no train claims (an unequipped
    or lost train, a failed track circuit).

The wayside lags the train by its delays: the margin grows by |speed| x ``lag``. A flag
is raised once its condition has held for ``persist`` seconds and cleared when it stops.

The ``crosscheck`` node admits its two inputs first (``CrossCheckInputs``, docs/reliability.md):
the train's fused states through core/safety/fused_state.py (stamps, values, sizes, kinematic
plausibility: a spoofed state far from the train is refused ``motion``) and the combined
occupancy as occupancy.py's systems (``admit_report``). A stream with nothing admitted for
its time-out (``input_timeout`` for the states, ``occupancy_timeout`` for the occupancy, which
comes on every change and every second) is stale, never OK: a WARN that says so. A stale
train claims what its last admitted state still allows now (its interval moved on by the
speed interval and ``max_acceleration``, as the plausibility gate's reach: the surely covered
body shrinks, the possible one grows); a stale occupancy is not compared with.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..measurements import CLEAR, OCCUPIED, SectionOccupancy
from ..safety.admission import StreamAdmission, StreamLimits
from ..sensors.base import Param, check_declared, resolve_params
from ..signals import InputRejected
from ..safety.fused_state import CLAIMED_MODES, PARAMS as STATE_PARAMS, FusedStateStream
from .occupancy import PARAMS as OCCUPANCY_PARAMS, admit_report

PARAMS = {
    "margin": Param(30.0, "overlap with a section that is not a contradiction [m]: half a tuned zone (12 m) of "
                          "the track circuits, axle offsets (2.5 m), with margin (assumption)", (0.0, 10000.0)),
    "lag": Param(2.5, "delay of the wayside report behind the train [s]: the track circuit's pick-up delay and "
                      "half a tuned zone at low speed (assumption)", (0.0, 600.0)),
    "persist": Param(2.0, "how long a condition must hold before it is flagged [s] (assumption)", (0.0, 600.0)),
    "train_length": Param(200.0, "length of the train [m] (vehicle data)", (1.0, 5000.0)),
    "orientation": Param(1, "+1: the train front faces increasing chainage, -1: decreasing [1]", (-1, 1)),
    **STATE_PARAMS,
    "occupancy_timeout": Param(2.5, "the combined occupancy with nothing admitted for this long is stale [s] "
                                    "(published on every change and every second)", (0.01, 600.0)),
    "max_sections": OCCUPANCY_PARAMS["max_sections"],
}
check_declared(PARAMS, "crosscheck")


@dataclass(frozen=True)
class Claim:
    """Where one train says it is at ``stamp``: its front's interval [m], length [m]."""

    train: str
    stamp: float
    front_min: float
    front_max: float
    length: float
    orientation: int = 1
    speed: float = 0.0
    valid: bool = True            # False: no position (initialising, lost): claims nothing surely

    def possible(self) -> tuple[float, float]:
        if self.orientation >= 0:
            return self.front_min - self.length, self.front_max
        return self.front_min, self.front_max + self.length

    def sure(self) -> tuple[float, float] | None:
        if self.orientation >= 0:
            lo, hi = self.front_max - self.length, self.front_min
        else:
            lo, hi = self.front_max, self.front_min + self.length
        return (lo, hi) if hi > lo else None


@dataclass
class Flag:
    kind: str                     # "claims_clear" or "unclaimed"
    section_id: str
    train: str                    # "" for unclaimed
    start: float
    end: float = math.nan

    def text(self) -> str:
        if self.kind == "claims_clear":
            return f"train {self.train} claims section {self.section_id}, which the wayside reports clear"
        return f"section {self.section_id} is occupied and no train claims it"


def _overlap(a: tuple[float, float], b: tuple[float, float]) -> float:
    return min(a[1], b[1]) - max(a[0], b[0])


@dataclass
class CrossCheck:
    params: dict = field(default_factory=lambda: resolve_params(PARAMS, {}))

    def __post_init__(self):
        self._pending: dict[tuple[str, str, str], float] = {}
        self.active: dict[tuple[str, str, str], Flag] = {}
        self.records: list[Flag] = []

    def update(self, now: float, claims: list[Claim], occupancy: SectionOccupancy) -> list[Flag]:
        """Conditions now; returns the flags that are active after this update."""
        p = self.params
        seen: set[tuple[str, str, str]] = set()
        for s in occupancy.sections:
            span = (min(s.start, s.end), max(s.start, s.end))
            if s.state == CLEAR:
                for c in claims:
                    sure = c.sure() if c.valid else None
                    if sure is not None and _overlap(sure, span) > p["margin"] + abs(c.speed) * p["lag"]:
                        seen.add(("claims_clear", s.section_id, c.train))
            elif s.state == OCCUPIED:
                claimed = False
                for c in claims:
                    if not c.valid:
                        claimed = True        # a train without a position may be anywhere
                        break
                    lo, hi = c.possible()
                    widen = p["margin"] + abs(c.speed) * p["lag"]
                    if _overlap((lo - widen, hi + widen), span) > 0.0:
                        claimed = True
                        break
                if not claimed:
                    seen.add(("unclaimed", s.section_id, ""))
        for key in seen:
            since = self._pending.setdefault(key, now)
            if key not in self.active and now - since >= p["persist"] - 1e-9:
                flag = Flag(key[0], key[1], key[2], since)
                self.active[key] = flag
                self.records.append(flag)
        for key in list(self._pending):
            if key not in seen:
                del self._pending[key]
                flag = self.active.pop(key, None)
                if flag is not None:
                    flag.end = now
        return list(self.active.values())


class CrossCheckInputs:
    """The ``crosscheck`` node's core (module doc): ``state(s, now, sizes)`` one of the train's
    fused states (core/association.py FusedState), ``occupancy(occ, now)`` a combined
    occupancy, each None (admitted) or the refusal, counted; ``evaluate(now)`` -> (the active
    flags, what is stale). ``now``: the node's clock [s]."""

    def __init__(self, train: str, params: dict | None = None):
        p = resolve_params(PARAMS, params)
        self.train, self.check = train, CrossCheck(p)
        self.states = FusedStateStream("localization/state", p)
        self.combined = StreamAdmission("wayside/combined", StreamLimits(
            float(p["future_tolerance"]), float(p["occupancy_timeout"]), int(p["max_sections"])))
        self.claim: Claim | None = None
        self.occ: SectionOccupancy | None = None

    def waiting_since(self, now: float) -> None:
        self.states.waiting_since(now)
        if now > 0.0:
            self.combined.waiting_since(now)

    def state(self, s, now: float | None, sizes: dict[str, int] | None = None) -> InputRejected | None:
        refusal = self.states.admit(s, now, sizes)
        if refusal is None:
            claimed = s.mode in CLAIMED_MODES
            self.claim = self._claim(s.stamp, s.position_min, s.position_max, s.speed if claimed else 0.0, claimed)
        return refusal

    def occupancy(self, occ: SectionOccupancy, now: float | None) -> InputRejected | None:
        refusal = admit_report(self.combined, occ, now)
        if refusal is None:
            self.occ = occ
        return refusal

    def evaluate(self, now: float) -> tuple[list[Flag], list[str]]:
        stale, claim = [], self.claim
        if claim is None or self.states.stale(now):
            stale.append(f"no fused state of train {self.train} admitted {_for(self.states.stream, now)}")
            r = self.states.reach(now) if claim is not None and claim.valid else None
            claim = (self._claim(now, -math.inf, math.inf, 0.0, False) if r is None
                     else self._claim(now, r.lo, r.hi, max(abs(r.v_lo), abs(r.v_hi)), True))
        occ = self.occ
        if occ is None or now > 0.0 and self.combined.stale(now):
            stale.append(f"no combined occupancy admitted {_for(self.combined, now)}")
            occ = SectionOccupancy(now, "combined", ())
        return self.check.update(now, [claim], occ), stale

    def _claim(self, stamp: float, lo: float, hi: float, speed: float, valid: bool) -> Claim:
        p = self.check.params
        return Claim(self.train, stamp, lo, hi, p["train_length"], int(p["orientation"]) or 1, speed, valid)


def _for(stream: StreamAdmission, now: float) -> str:
    return f"for {stream.silence(now):.1f} s" if stream.admitted else "yet"

"""Combined wayside detection: track circuits as the base, axle counters added, voted per
section (seed 004 section 4.2: "track circuits as the basis, axle counters in parallel";
section 5: a duplicated detection with axle counters at the block boundaries).

Each combined section pairs one track circuit with one axle-counter section (Fig. 6: TC1 /
TC2 and the sections between the three counting points). The circuit may cover only part
of the axle section (seed 004 section 4.2: AF circuits of about 400 m in blocks of at least
800 m; catenary.Layout): then the axle counter alone sees a train in the rest, and "track
circuit CLEAR, axle counter OCCUPIED" there is no disagreement (``PARTIAL``). The two
systems' states are voted (``vote``):

    track circuit \\ axle counter   CLEAR      OCCUPIED     DISTURBED / silent
    CLEAR                          CLEAR      OCCUPIED*    DISTURBED (d)
    OCCUPIED                       OCCUPIED*  OCCUPIED     OCCUPIED (d)
    DISTURBED / silent             DISTURBED (d)  OCCUPIED (d)  DISTURBED (d)

A section is clear only when both systems say so, occupied while either says so (the rule
of seed 004 section 4.2) and DISTURBED (unknown: occupied until a reset) when a system that
cannot tell is not overruled by an occupied one. * = a disagreement: normal for a moment
at every section boundary (the track circuit drops half a tuned zone earlier and picks up
later, after its pick-up delay), a contradiction once it lasts longer than
``disagree_tolerance``. (d) = degraded: one system alone decides. A system whose last
report is older than ``input_timeout`` counts as silent.

Each system's reports are a stream admitted through core/safety (``admit_report``,
docs/reliability.md): refused, counted by reason and changing nothing, are a report stamped
more than ``future_tolerance`` ahead of the consumer's clock (``future``) or before the
system's last admitted one (``stamp_back``: a replayed old report), a stamp or section end
that is not finite (``nan``), a section state that is none of CLEAR, OCCUPIED, DISTURBED
(``implausible``), an id longer than 64 characters (``too_long``) and more than
``max_sections`` sections (``too_large``). A report of the same stamp as the last is taken (a
decoder reports every change, and several may fall on one sample). A system is silent when
nothing of it was admitted for ``input_timeout`` of the consumer's clock, or its last admitted
report is that old: refused reports keep nobody alive, and a silent system's sections are
never CLEAR (the table above).

Disagreements are recorded (section, which system said what, from when to when) for the
diagnostics.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..measurements import CLEAR, DISTURBED, OCCUPIED, SectionOccupancy, SectionState
from ..safety import admission
from ..safety.admission import MAX_ITEMS, StreamAdmission, StreamLimits
from ..sensors.base import Param, check_declared, resolve_params
from ..signals import InputRejected

SILENT = -1        # a system with no report within the timeout
PARTIAL = 50.0     # [m] a track circuit this much shorter than its axle section covers part of it
STATE_NAMES = {CLEAR: "CLEAR", OCCUPIED: "OCCUPIED", DISTURBED: "DISTURBED", SILENT: "SILENT"}

PARAMS = {
    "disagree_tolerance": Param(3.0, "longest normal disagreement of the two systems on a section [s]: the "
                                     "track circuit drops half a tuned zone (12 m) before the counting point and "
                                     "picks up 12 m after it plus its pick-up delay (0.5 s here): 1.9 s at "
                                     "30 km/h (assumption: with margin)", (0.0, 600.0)),
    "input_timeout": Param(2.5, "a system whose last SectionOccupancy is older than this is silent [s] "
                                "(both report every 1 s without changes)", (0.01, 600.0)),
    "future_tolerance": admission.PARAMS["future_tolerance"],
    "max_sections": Param(MAX_ITEMS, "a report listing more sections than this is refused (too_large) [1]",
                          (1, 100000)),
}
check_declared(PARAMS, "wayside_occupancy")


def admit_report(stream: StreamAdmission, occ: SectionOccupancy, now: float | None) -> InputRejected | None:
    """Admit one SectionOccupancy of a stream (module doc): None or the refusal, counted in
    ``stream``. ``now``: the consumer's clock [s]; None or 0: none (offline), the report
    arrives at its stamp."""
    clock = now if now and now > 0.0 else None
    try:
        bad = next((s for s in occ.sections if s.state not in (CLEAR, OCCUPIED, DISTURBED)), None)
        if bad is not None:
            raise InputRejected("implausible", f"{stream.name}: section {bad.section_id[:64]!r} in state {bad.state}")
        listed = occ.sections[:stream.limits.max_items]     # more: too_large, and nothing else read
        stream.check(occ.stamp, clock, values={f"sections[{k}].{end}": x for k, s in enumerate(listed)
                                               for end, x in (("start", s.start), ("end", s.end))},
                     ids={"source": occ.source, **{f"sections[{k}]": s.section_id for k, s in enumerate(listed)}},
                     sizes={"sections": len(occ.sections)})
    except InputRejected as exc:
        if exc.reason != "duplicate":    # the same instant again: a further change of it
            return stream.refuse(exc)
    stream.accept(occ.stamp, clock if clock is not None else occ.stamp)
    return None


def vote(tc: int, ac: int) -> tuple[int, bool, bool]:
    """(combined state, disagreement, degraded) of one section from the track-circuit and
    axle-counter states (CLEAR, OCCUPIED, DISTURBED or SILENT)."""
    ok_tc, ok_ac = tc in (CLEAR, OCCUPIED), ac in (CLEAR, OCCUPIED)
    if ok_tc and ok_ac:
        if tc == ac:
            return tc, False, False
        return OCCUPIED, True, False
    if OCCUPIED in (tc, ac):
        return OCCUPIED, False, True
    return DISTURBED, False, True


@dataclass(frozen=True)
class CombinedSection:
    """Voted state of one section at ``stamp``."""

    section_id: str
    start: float
    end: float
    state: int                   # CLEAR / OCCUPIED / DISTURBED
    tc: int                      # the track circuit's state (or SILENT)
    ac: int                      # the axle counter's state (or SILENT)
    disagreement: bool           # the systems disagree now
    contradiction: bool          # ... for longer than disagree_tolerance
    degraded: bool               # one system disturbed or silent
    axle_count: int = 0

    @property
    def any_clear(self) -> bool:
        """At least one working system says CLEAR (the first sign that a train has left)."""
        return CLEAR in (self.tc, self.ac)


@dataclass
class Disagreement:
    section_id: str
    tc: int
    ac: int
    start: float
    end: float = math.nan        # NaN while it lasts

    @property
    def duration(self) -> float:
        return self.end - self.start

    def text(self) -> str:
        return (f"{self.section_id}: track circuit {STATE_NAMES[self.tc]}, axle counter {STATE_NAMES[self.ac]} "
                f"from {self.start:.2f} s" + (f" for {self.duration:.2f} s" if math.isfinite(self.end) else ""))


@dataclass
class SectionMap:
    """Combined section id -> (track circuit id, axle-counter section id)."""

    pairs: dict[str, tuple[str, str]]
    tc_source: str = "track_circuit"
    ac_source: str = "axle_counter"

    @classmethod
    def fig6(cls) -> "SectionMap":
        """Seed 004 Fig. 6 as laid by catenary.Layout.track_dict."""
        return cls({"S1": ("TC1", "S1"), "S2": ("TC2", "S2")})


@dataclass
class CombinedOccupancy:
    """Keeps the latest report of each system and votes per section (see module doc)."""

    sections: SectionMap
    params: dict = field(default_factory=lambda: resolve_params(PARAMS, {}))

    def __post_init__(self):
        self._tc: dict[str, SectionState] = {}
        self._ac: dict[str, SectionState] = {}
        p = self.params
        limits = StreamLimits(float(p["future_tolerance"]), float(p["input_timeout"]), int(p["max_sections"]))
        self.streams = {src: StreamAdmission(src, limits) for src in (self.sections.tc_source, self.sections.ac_source)}
        self.refusal: InputRejected | None = None   # why the last report was refused
        self._since: dict[str, float] = {}          # section -> start of the running disagreement
        self.records: list[Disagreement] = []
        self._open: dict[str, Disagreement] = {}
        self.ignored = 0                            # reports of other sources

    def update(self, occ: SectionOccupancy, now: float | None = None) -> bool:
        """Take one report of either system, arrived at the consumer's clock ``now`` [s] (None:
        at its stamp); False for a source that is not ours or a refused report (``refusal``
        says why; counted in ``streams[source].refused``)."""
        self.refusal = None
        if occ.source == self.sections.tc_source:
            store = self._tc
        elif occ.source == self.sections.ac_source:
            store = self._ac
        else:
            self.ignored += 1
            return False
        self.refusal = admit_report(self.streams[occ.source], occ, now)
        if self.refusal is not None:
            return False
        for s in occ.sections:
            store[s.section_id] = s
        return True

    def silent(self, source: str, now: float) -> bool:
        """Nothing of ``source`` admitted for ``input_timeout`` [s], or its last report that old."""
        stream = self.streams[source]
        return stream.last_stamp is None or stream.stale(now) or now - stream.last_stamp > stream.limits.timeout

    def _state(self, store: dict, sid: str, source: str, now: float) -> tuple[int, SectionState | None]:
        s = store.get(sid)
        if s is None or self.silent(source, now):
            return SILENT, s
        return s.state, s

    def contradictions(self) -> list[Disagreement]:
        """The recorded disagreements that lasted longer than ``disagree_tolerance`` (or last still)."""
        return [r for r in self.records if not r.duration <= self.params["disagree_tolerance"]]

    def evaluate(self, now: float) -> list[CombinedSection]:
        out = []
        for sid, (tc_id, ac_id) in self.sections.pairs.items():
            tc, s_tc = self._state(self._tc, tc_id, self.sections.tc_source, now)
            ac, s_ac = self._state(self._ac, ac_id, self.sections.ac_source, now)
            state, dis, degraded = vote(tc, ac)
            if dis and (tc, ac) == (CLEAR, OCCUPIED) and _partial(s_tc, s_ac):
                dis = False          # the train is where only the axle counter sees it
            if dis:
                since = self._since.setdefault(sid, now)
                rec = self._open.get(sid)
                if rec is None or (rec.tc, rec.ac) != (tc, ac):
                    if rec is not None:
                        rec.end = now
                    rec = self._open[sid] = Disagreement(sid, tc, ac, now)
                    self.records.append(rec)
            else:
                self._since.pop(sid, None)
                rec = self._open.pop(sid, None)
                if rec is not None:
                    rec.end = now
                since = now
            ref = s_tc or s_ac
            start = ref.start if ref else math.nan
            end = ref.end if ref else math.nan
            out.append(CombinedSection(sid, start, end, state, tc, ac, dis,
                                       dis and now - since > self.params["disagree_tolerance"], degraded,
                                       s_ac.axle_count if s_ac is not None else 0))
        return out


def _partial(tc: SectionState | None, ac: SectionState | None) -> bool:
    """The track circuit covers only part of the axle section (shorter by more than PARTIAL)."""
    return tc is not None and ac is not None and (tc.end - tc.start) < (ac.end - ac.start) - PARTIAL


def to_occupancy(stamp: float, sections: list[CombinedSection], source: str = "combined") -> SectionOccupancy:
    """The voted states as a SectionOccupancy (published like the systems' own)."""
    return SectionOccupancy(stamp, source, tuple(
        SectionState(s.section_id, s.start, s.end, s.state, s.axle_count, 0, 0) for s in sections))

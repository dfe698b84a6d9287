"""One train's fused-state stream as the wayside consumers admit it -- the association of
wayside fixes (core/association.py) and the on-board / wayside cross-check
(core/wayside/crosscheck.py); docs/reliability.md. core/safety's stream checks and kinematic
plausibility on a TrainState's numbers, with the claimed interval first restated on the axis of
the last admitted one: on a closed track across its seam; on a network across a change of
section (a state's chainage is that of its most probable hypothesis's section) as distance
run: the section is placed on the last one's axis through the nodes between them, a through
route continuing the axis, the branches that leave a node on the same side (a switch's B1
and B2) sharing it beyond the node, so that the most probable hypothesis changing between
them is no jump.

Refused, each counted by reason in ``stream.refused``, changing nothing:

  ``nan``          the stamp, or in a claimed state (NOMINAL, DEGRADED) the position, its
                   interval, the speed or its 1-sigma, not finite
  ``implausible``  a claimed interval upside down or beyond MAX_CHAINAGE, a speed beyond
                   MAX_SPEED, a 1-sigma below 0 or beyond MAX_SPEED
  ``too_long``     a track id longer than MAX_ID_LENGTH
  ``too_large``    more sensor names than MAX_ITEMS
  ``future``       stamped more than ``future_tolerance`` ahead of the consumer's clock
  ``duplicate``, ``stamp_back``  stamped at or before the last admitted state
  ``unknown_id``   (network) a section the network does not have
  ``motion``       a claimed interval or speed that the last admitted claimed state rules out
                   over the elapsed time (core/safety/plausibility.py), or a section that
                   no chain of sections within that reach places

A state that claims no position (initialising, lost) is admitted when its stamp passes, and is
no reference. The stream is stale once nothing was admitted for ``input_timeout`` of the
consumer's clock (refused and silent alike): the consumer then reacts as if it had no state.
"""
from __future__ import annotations

from ..network.model import THROUGH, SectionEnd
from ..sensors.base import resolve_params
from ..signals import InputRejected
from . import admission, plausibility
from .admission import MAX_ITEMS, StreamAdmission
from .plausibility import Motion, MotionGate, Reach, speed_bound
from .state_stream import claim_checks

PARAMS = {**admission.PARAMS, **plausibility.PARAMS}
CLAIMED_MODES = (1, 2)     # TrainState MODE_NOMINAL, MODE_DEGRADED: a position is claimed
MAX_PATHS = 256            # placements of sections a network search tries (on the reference's axis)


def stream_params(params: dict | None) -> dict:
    """PARAMS at their defaults, updated by those of ``params`` (other keys ignored)."""
    return resolve_params(PARAMS, {k: v for k, v in (params or {}).items() if k in PARAMS})


class FusedStateStream:
    """``admit(state, now, sizes)``: None (admitted) or the refusal, counted in
    ``stream.refused``. ``state``: anything with the TrainState's numbers as attributes
    (core/association.py FusedState: ``stamp``, ``track_id``, ``mode``, ``position``,
    ``position_min``, ``position_max``, ``speed``, ``speed_stddev``, ``confidence``); ``sizes``:
    its lists' lengths (``sensors``); ``now``: the consumer's clock [s] (0 or None: none yet,
    nothing is compared with it and no time-out runs).
    ``network``: the core/network Network the train runs on (its states' track ids are
    sections); ``circumference`` [m] of a closed track."""

    def __init__(self, name: str, params: dict | None = None, network=None, circumference: float | None = None):
        p = self.params = stream_params(params)
        self.stream = StreamAdmission(name, admission.limits_from(p, MAX_ITEMS))
        self.gate = MotionGate.from_params(p)
        self.network, self.circumference = network, circumference
        self.section: str | None = None     # on a network: the section of the reference's axis

    def admit(self, s, now: float | None, sizes: dict[str, int] | None = None) -> InputRejected | None:
        claimed = s.mode in CLAIMED_MODES
        checks = claim_checks(s) if claimed else {}
        clock = now if now and now > 0.0 else None
        own = Motion.of(s.stamp, claimed, s.position_min, s.position_max, s.speed,
                        speed_bound(s.confidence, s.speed_stddev) if claimed else 0.0)
        try:
            self.stream.check(s.stamp, clock, ids={"track_id": s.track_id}, sizes=sizes, **checks)
            if claimed and s.position_min > s.position_max:
                raise InputRejected("implausible", f"{self.stream.name}: interval [{s.position_min:.3f}, "
                                                   f"{s.position_max:.3f}] m upside down")
            self.gate.check(self._restated(own, s.track_id))
        except InputRejected as exc:
            return self.stream.refuse(exc)
        self.stream.accept(s.stamp, clock)
        if claimed:
            self.gate.accept(own)
            self.section = s.track_id
        return None

    def waiting_since(self, now: float) -> None:
        if now and now > 0.0:
            self.stream.waiting_since(now)

    def stale(self, now: float | None) -> bool:
        """Nothing admitted for the time-out (False while the consumer has no clock)."""
        return bool(now and now > 0.0) and self.stream.stale(now)

    def reach(self, t: float) -> Reach | None:
        """Where the last admitted claimed state allows the front to be at ``t`` [s] (its axis)."""
        return self.gate.reach(t)

    # ------------------------------------------------------------------ restating
    def _restated(self, m: Motion, track_id: str) -> Motion:
        """``m`` (on ``track_id``'s chainage) on the reference's axis: of its placements, the
        nearest to the reach; InputRejected for a section the network lacks or that no chain
        of sections within reach places."""
        if self.network is not None and track_id not in self.network.sections:
            raise InputRejected("unknown_id", f"{self.stream.name}: section {track_id[:64]!r} is not in network "
                                              f"{self.network.network_id}")
        r = self.gate.reach(m.t) if m.claimed else None
        if r is None:
            return m
        offsets, complete = self._offsets(track_id, r, m.hi - m.lo)
        if not offsets:
            if not complete:    # too many ways to search: nothing rules the section out
                return Motion(m.t, False, m.lo, m.hi, m.v_lo, m.v_hi)
            raise InputRejected("motion", f"{self.stream.name}: section {track_id[:64]!r} is not within reach of "
                                          f"the last admitted state on {self.section!r} ([{r.lo:.2f}, {r.hi:.2f}] m)")
        placed = [Motion(m.t, True, *sorted((o + d * m.lo, o + d * m.hi)), *sorted((d * m.v_lo, d * m.v_hi)))
                  for d, o in offsets]
        return min(placed, key=lambda c: max(r.lo - c.hi, c.lo - r.hi, 0.0))

    def _offsets(self, track_id: str, r: Reach, slack: float) -> tuple[list[tuple[int, float]], bool]:
        """([(d, o)]: chainage x of ``track_id`` is o + d x on the reference's axis], whether
        the search was complete). A line: itself; a closed track: itself a turn back or on; a
        network: the sections joined to the reference's through the nodes (a through route
        continues the axis; branches leaving a node on the same side, a switch's B1 and B2,
        share it: the distance run), from every section within ``slack`` [m] of the reach."""
        if self.network is None:
            turns = (-1, 0, 1) if self.circumference else (0,)
            return [(1, k * (self.circumference or 0.0)) for k in turns], True
        net, lo, hi = self.network, r.lo - self.gate.margin - slack, r.hi + self.gate.margin + slack
        work, seen, found = [(self.section, 1, 0.0)], set(), set()
        while work and len(seen) < MAX_PATHS:
            sid, d, o = work.pop()
            if (sid, d, round(o, 3)) in seen:
                continue
            seen.add((sid, d, round(o, 3)))
            if sid == track_id:
                found.add((d, o))
            length = net.sections[sid].length
            if max(o, o + d * length) < lo or min(o, o + d * length) > hi:
                continue        # beyond the reach: nothing joined to it is nearer
            for end, at in (("begin", o), ("end", o + d * length)):
                joint = net.joint(SectionEnd(sid, end))
                if joint is None:
                    continue
                node, port = joint
                routes = THROUGH[node.kind]
                away = d if end == "begin" else -d       # the axis's sign from the node into sid
                for q, x in node.ports.items():
                    if q == port:
                        continue
                    if q in routes[port]:
                        a = -away                         # through the node: the axis goes on
                    elif set(routes[q]) & set(routes[port]):
                        a = away                          # a sibling: the same side of the node
                    else:
                        continue
                    dx = a if x.end == "begin" else -a
                    work.append((x.section, dx, at if x.end == "begin" else at - dx * net.sections[x.section].length))
        return sorted(found), not work

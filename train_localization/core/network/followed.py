"""The path an on-board function follows through a network (docs/network.md, "ETCS on a
network"): the sections behind the train front, as the fused state places it, and ahead of
it, as the interlocking reports the switches.

Frame. The track-selective fusion gives the front's section, its chainage there, its path
distance and the direction its most probable hypothesis runs along the section (TrainState
``path_*``). Paths grown from the fusion's start share its origin, so a place passed before a
switch keeps its path distance on every way through it: the followed path is brought to the
front's place by keeping what it has in common with the hypothesis (cut back from its far end)
and growing from there (``follow``), and it runs on ahead through every node, at a facing switch
along the way the interlocking reports, until ``reach`` metres past the front or a switch whose
way is unknown (``ahead``).
"""
from __future__ import annotations

from .path import TrackPath

TOLERANCE = 1e-3   # [m] a path holds the front's place when it puts it this near its path distance


def holds(path: TrackPath, section: str, chainage: float, s: float, direction: int) -> bool:
    """True if ``path`` runs along ``section`` in ``direction`` with ``chainage`` [m] there at path
    distance ``s`` [m]."""
    return any(st.section == section and st.direction == direction and abs(st.distance(chainage) - s) <= TOLERANCE
               for st in path.steps)


def _grown(base: TrackPath, section: str, chainage: float, s: float, direction: int) -> TrackPath | None:
    """``base`` continued at either end (never further than path distance ``s``) until it holds
    the place; None if no continuation does."""
    work = [base]
    while work:
        path = work.pop()
        if holds(path, section, chainage, s, direction):
            return path
        if path.end <= s + TOLERANCE:
            work += [path.extended(c) for c in path.ahead()]
        if path.begin >= s - TOLERANCE:
            work += [path.prepended(c) for c in path.behind()]
    return None


def follow(path: TrackPath | None, network, section: str, chainage: float, s: float, direction: int) -> TrackPath:
    """The followed ``path`` brought to the front at ``chainage`` [m] on ``section``, path
    distance ``s`` [m], the path running along the section in ``direction``: ``path`` itself if
    it holds that place; else its longest part from its start that can be continued to it; else
    its part from the end cut from its start (a reversal); else a new path of that section alone,
    its origin placed so that it holds the place."""
    if path is not None:
        if holds(path, section, chainage, s, direction):
            return path
        for keep in range(len(path.steps), 0, -1):
            found = _grown(TrackPath(network, path.steps[:keep]), section, chainage, s, direction)
            if found is not None:
                return found
        for drop in range(1, len(path.steps)):
            found = _grown(TrackPath(network, path.steps[drop:]), section, chainage, s, direction)
            if found is not None:
                return found
    length = network.section(section).length
    return TrackPath.start(network, section, direction, s - (chainage if direction > 0 else length - chainage))


def ahead(path: TrackPath, s: float, switches: dict[str, str], reach: float) -> TrackPath:
    """``path`` cut after the section holding path distance ``s`` [m] (the front) and continued
    ahead until ``reach`` [m] past ``s``: through every node, at a facing switch along the way
    ``switches`` reports (switch -> "B1"/"B2"; unknown or absent: the path ends there)."""
    k = next((i for i, st in enumerate(path.steps) if st.start <= s < st.stop), len(path.steps) - 1)
    out = TrackPath(path.network, path.steps[:k + 1])
    while out.end < s + reach:
        options = out.ahead()
        if len(options) > 1:
            options = [c for c in options if c.way is not None and c.way == switches.get(c.node)]
        if len(options) != 1:
            break
        out = out.extended(options[0])
    return out

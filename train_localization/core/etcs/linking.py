"""Linking: the balise group expected next and its expectation window (SUBSET-026 section
3.4.4; docs/etcs.md).

After the LRBG, a train travelling in ``direction`` expects the group its link names, at the
linking distance from the LRBG's reference (after a missed group, the links chain on from it
and the distances add up). The window is the group's balises at their linked places
+- Q_LOCACC of the expected group, taken to the train front at each read by the reader's
antenna offset (the front at a read minus the balise's chainage, as the last read showed). It
is open while the interval of safe front ends overlaps it: opened when the max safe front
end reaches its start, closed when the min safe front end has passed its end.
"""
from __future__ import annotations

from dataclasses import dataclass

from .records import Reaction
from .track_data import BaliseGroup, EtcsData, Link


@dataclass(frozen=True)
class Expectation:
    """The linked group expected next: the link that announced it, the distance [m] from the
    LRBG's reference to its reference, and its window as front chainages [m] (low, high)."""
    link: Link
    distance: float
    window: tuple[float, float]

    @property
    def nid_bg(self) -> str:
        return self.link.to_bg

    @property
    def direction(self) -> int:
        return self.link.direction

    @property
    def reaction(self) -> Reaction:
        return self.link.reaction

    def passed(self, lo: float, hi: float) -> bool:
        """True once the min safe front end has passed the window's far end (in the direction of travel)."""
        return lo > self.window[1] if self.direction > 0 else hi < self.window[0]


def expect(data: EtcsData, lrbg: BaliseGroup, after: str, direction: int, distance_so_far: float,
           front_offset: float) -> Expectation | None:
    """The expectation of the group linked after group ``after`` (the LRBG, or the last group
    missed since it), for a train travelling in ``direction``; None if there is no link.
    ``distance_so_far`` [m]: from the LRBG's reference to ``after``'s; ``front_offset`` [m]:
    train front minus balise chainage at a read."""
    link = data.link_after(after, direction)
    if link is None:
        return None
    distance = distance_so_far + link.distance
    target = data.groups[link.to_bg]
    predicted = lrbg.reference + direction * distance          # the target's reference, by linking
    shift = predicted - target.reference                        # linked minus surveyed place
    first, last = target.positions[0] + shift, target.positions[-1] + shift
    q = target.q_locacc
    return Expectation(link, distance, (first + front_offset - q, last + front_offset + q))

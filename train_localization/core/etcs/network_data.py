"""ETCS data on a network: balise groups located on sections, and linking that follows the
routes (docs/network.md, "ETCS on a network"; SUBSET-026 sections 3.4.4 and 3.6).

A balise group is located on a section, in that section's chainage, as on a single line
(core/etcs/track_data.py: the section's ``eurobalise`` items, grouped by their ``group`` key,
with Q_LOCACC and orientation). The network's ``etcs`` block (beside ``sections`` and
``nodes``) gives the national value and the linking::

    etcs:
      q_nvlocacc: 12.0
      linking: auto               # each group linked to the next group on every path leaving it
      link_reaction: service_brake

**Linking follows the routes.** A group links, for each direction of travel along its
section, to the first group on each path leaving it: along its own section first, then across
the node at the section's end onto every continuation (both ways at a facing switch), and so on
up to ``reach`` metres. Each link carries its distance along that path (reference to
reference) and the path itself: its sections and the facing switches' ways, so an on-board
unit whose route (or whose most probable track hypothesis) takes one way expects that way's
group. A group with no group within reach on a path has no link on it.
"""
from __future__ import annotations

from dataclasses import dataclass

from ..network.model import Network
from ..network.path import TrackPath
from ..track import TrackError
from .records import Reaction
from .track_data import BaliseGroup, balise_groups, etcs_block, reaction_of

DEFAULT_REACH = 5000.0   # [m] linking looks no further for the next group on a path


@dataclass(frozen=True)
class LocatedGroup:
    """A balise group on ``section`` (its chainages are that section's)."""
    section: str
    group: BaliseGroup


@dataclass(frozen=True)
class RouteLink:
    """After group ``from_bg``, a train travelling ``direction`` (+1: along increasing chainage of
    the group's section) on ``path`` (the sections from the group's to the next group's, in
    order; ``ways``: (switch, way) of its facing switches) expects group ``to_bg`` at
    ``distance`` [m] along it, with ``reaction`` if it is missed."""
    from_bg: str
    to_bg: str
    distance: float
    direction: int
    reaction: Reaction
    path: tuple[str, ...]
    ways: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class NetworkEtcsData:
    """The balise groups of a network's sections and their linking along the routes."""
    network_id: str
    groups: dict[str, LocatedGroup]
    group_of_balise: dict[str, str]
    links: dict[tuple[str, int], tuple[RouteLink, ...]]   # (from group, direction) -> one per path
    q_nvlocacc: float | None = None

    @classmethod
    def from_network(cls, network: Network, reach: float = DEFAULT_REACH) -> "NetworkEtcsData":
        """The ETCS data of ``network``; TrackError in one line if it is inconsistent (a group id
        used on two sections, a group without Q_LOCACC where the network gives no national value,
        an unknown key, a linking other than ``auto``)."""
        block, national = etcs_block(network.etcs, f"network {network.network_id}")
        groups: dict[str, LocatedGroup] = {}
        group_of: dict[str, str] = {}
        for sid, section in network.sections.items():
            own, members = balise_groups(section, national)
            for nid, group in own.items():
                if nid in groups:
                    raise TrackError(f"balise group {nid} is on sections {groups[nid].section} and {sid}: a group "
                                     f"lies on one section")
                groups[nid] = LocatedGroup(sid, group)
            group_of.update(members)
        links: dict[tuple[str, int], tuple[RouteLink, ...]] = {}
        linking = block.get("linking")
        if linking is not None:
            if linking != "auto":
                raise TrackError(f"network {network.network_id}: etcs.linking must be 'auto' on a network (links "
                                 f"follow the routes)")
            reaction = reaction_of(block.get("link_reaction", "service_brake"),
                                 f"network {network.network_id}: etcs.link_reaction")
            for nid, located in groups.items():
                for direction in (1, -1):
                    found = next_groups(network, groups, located, direction, reach)
                    links[(nid, direction)] = tuple(
                        RouteLink(nid, to, distance, direction, reaction,
                                  tuple(st.section for st in path.steps), tuple(path.ways().items()))
                        for to, distance, path in found)
        return cls(network.network_id, groups, group_of, links, national)

    def links_after(self, nid_bg: str, direction: int) -> tuple[RouteLink, ...]:
        """The links from group ``nid_bg`` for a train travelling ``direction`` along its section,
        one per path leaving it (empty: none within reach)."""
        return self.links.get((nid_bg, int(direction)), ())

    def link_on(self, nid_bg: str, direction: int, sections: tuple[str, ...] | list[str]) -> RouteLink | None:
        """The link from ``nid_bg`` whose path a train running along ``sections`` (its route, or
        a track hypothesis's path, from the group's section on) follows; None if none."""
        for link in self.links_after(nid_bg, direction):
            n = min(len(link.path), len(sections))
            if tuple(sections[:n]) == link.path[:n]:
                return link
        return None


def next_groups(network: Network, groups: dict[str, LocatedGroup], start: LocatedGroup, direction: int,
                reach: float) -> list[tuple[str, float, TrackPath]]:
    """(next group id, distance [m] reference to reference, path) of the first group on every
    path leaving ``start`` in ``direction`` along its section, within ``reach``."""
    on: dict[str, list[LocatedGroup]] = {}
    for located in groups.values():
        on.setdefault(located.section, []).append(located)
    origin = TrackPath.start(network, start.section, direction)
    s0 = origin.steps[0].distance(start.group.reference)
    out: list[tuple[str, float, TrackPath]] = []
    work = [origin]
    while work:
        path = work.pop()
        step = path.steps[-1]
        ahead = [(step.distance(g.group.reference), g) for g in on.get(step.section, ())
                 if g.group.nid_bg != start.group.nid_bg and step.distance(g.group.reference) > s0]
        if ahead:
            s, nearest = min(ahead, key=lambda x: x[0])
            if s - s0 <= reach:
                out.append((nearest.group.nid_bg, s - s0, path))
            continue
        if path.end - s0 >= reach:
            continue
        for c in path.ahead():
            work.append(path.extended(c))
    return sorted(out, key=lambda x: (x[1], x[0]))

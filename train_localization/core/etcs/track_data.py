"""The track's data as ETCS has it: balise groups with their location accuracy Q_LOCACC, and
linking (docs/etcs.md; SUBSET-026 sections 3.4.4, 3.6.1, 7.5.1.113).

Balise groups are the track's ``eurobalise`` items: balises with the same ``group`` key form
one group named by it, a balise without one is a group of its own named by its id. A balise
may carry ``q_locacc`` [m] (the group's location accuracy; every balise of a group gives the
same) and ``orientation`` (+1: the group's nominal direction is increasing chainage, the
default; -1 the other way). The group's reference (its balise 1) is its first balise in its
nominal direction. The track's ``etcs`` block gives the rest::

    etcs:
      q_nvlocacc: 12.0        # national value of Q_LOCACC [m], for groups without q_locacc
                              # (SUBSET-026 A.3.2 default 12 m; leave it out to require each group's)
      linking: auto           # link each group to the next one both ways, at their chainage difference
      link_reaction: service_brake   # Q_LINKREACTION of auto links: train_trip | service_brake | none
      # or the links one by one, in a direction of travel:
      # linking:
      #   - {from: BG001, to: BG002, distance: 1000.0, reaction: train_trip}

A link's ``distance`` [m] is between the two groups' references; it must match their
chainages within LINK_TOLERANCE (the resolution of D_LINK at Q_SCALE 1 m), or the track is
refused. A track without an ``etcs`` block has no linking; its groups' Q_LOCACC is each
balise's ``q_locacc``, and ``EtcsData.from_track`` refuses a group without one.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..track import Track, TrackError
from .records import Reaction

KIND = "eurobalise"
LINK_TOLERANCE = 0.5     # [m] linking distance vs chainage difference (D_LINK resolution at Q_SCALE 1 m)
Q_LOCACC_MAX = 63.0      # [m] largest Q_LOCACC (6 bits, SUBSET-026 7.5.1.112)
REACTIONS = {"train_trip": Reaction.TRAIN_TRIP, "service_brake": Reaction.SERVICE_BRAKE, "none": Reaction.NONE}


@dataclass(frozen=True)
class BaliseGroup:
    """One balise group: its NID_BG (the ``group`` key or the balise id), reference chainage [m]
    (balise 1: its first balise in its nominal direction), nominal direction (+1/-1), Q_LOCACC
    [m], and its balises' ids and chainages [m] in chainage order."""
    nid_bg: str
    reference: float
    orientation: int
    q_locacc: float
    balises: tuple[str, ...]
    positions: tuple[float, ...]


@dataclass(frozen=True)
class Link:
    """A linking entry: after group ``from_bg`` a train travelling in ``direction`` (+1 towards
    increasing chainage) expects group ``to_bg`` at ``distance`` [m] (reference to reference),
    with the reaction ``reaction`` if it is missed or passed the wrong way."""
    from_bg: str
    to_bg: str
    distance: float
    direction: int
    reaction: Reaction


@dataclass(frozen=True)
class EtcsData:
    """The balise groups and linking of one track (``from_track``)."""
    track_id: str
    groups: dict[str, BaliseGroup]
    group_of_balise: dict[str, str]
    links: dict[tuple[str, int], Link] = field(default_factory=dict)   # (from group, direction) -> link
    q_nvlocacc: float | None = None

    @property
    def linked(self) -> bool:
        """True if the track gives linking."""
        return bool(self.links)

    def link_after(self, nid_bg: str, direction: int) -> Link | None:
        """The link from group ``nid_bg`` for a train travelling in ``direction``, None if none."""
        return self.links.get((nid_bg, int(direction)))

    @classmethod
    def from_track(cls, track: Track, national_default: float | None = None) -> "EtcsData":
        """The ETCS data of a track; TrackError in one line if it is inconsistent.
        ``national_default`` [m]: the national value of Q_LOCACC where the track gives none (the
        campaign scores a track without ETCS data with its reader's location bound)."""
        block, national = etcs_block(track.etcs, f"track {track.track_id}", national_default)
        groups, group_of = balise_groups(track, national)
        return cls(track.track_id, groups, group_of, _links(track.track_id, block, groups), national)


def etcs_block(block, where: str, national_default: float | None = None) -> tuple[dict, float | None]:
    """(the ``etcs`` block, its national Q_LOCACC [m] or ``national_default``) of a track or a
    network (``where`` names it); TrackError in one line for a block that is no mapping, an
    unknown key or a Q_LOCACC out of range."""
    block = block or {}
    if not isinstance(block, dict):
        raise TrackError(f"{where}: 'etcs' must be a mapping")
    unknown = set(block) - {"q_nvlocacc", "linking", "link_reaction"}
    if unknown:
        raise TrackError(f"{where}: unknown keys in 'etcs': {', '.join(sorted(unknown))}")
    national = block.get("q_nvlocacc")
    if national is None:
        national = national_default
    if national is not None:
        national = checked_q_locacc(national, f"{where}: etcs.q_nvlocacc")
    return block, national


def q_locacc_of_balise(track: Track, item: dict) -> float | None:
    """Q_LOCACC [m] that applies to one balise item of ``track`` (its own, else the national
    value of the track's ``etcs`` block), None if neither is given (the reader's error model
    then keeps its ``location_sigma``)."""
    if item.get("q_locacc") is not None:
        return checked_q_locacc(item["q_locacc"], f"balise {item['id']}: q_locacc")
    national = (track.etcs or {}).get("q_nvlocacc") if isinstance(track.etcs, dict) else None
    return None if national is None else checked_q_locacc(national, f"track {track.track_id}: etcs.q_nvlocacc")


def checked_q_locacc(value, what: str) -> float:
    try:
        q = float(value)
    except (TypeError, ValueError):
        raise TrackError(f"{what} {value!r} is not a number") from None
    if not 0.0 <= q <= Q_LOCACC_MAX:
        raise TrackError(f"{what} {q} m is outside 0..{Q_LOCACC_MAX:g} m")
    return q


def balise_groups(track: Track, national: float | None) -> tuple[dict[str, BaliseGroup], dict[str, str]]:
    members: dict[str, list[dict]] = {}
    for item in track.items(KIND):
        members.setdefault(str(item.get("group", item["id"])), []).append(item)
    groups, group_of = {}, {}
    for nid, items in members.items():
        orientations = {int(it.get("orientation", 1)) for it in items}
        if len(orientations) != 1 or orientations - {1, -1}:
            raise TrackError(f"balise group {nid}: orientation must be +1 or -1, the same for all its balises")
        accuracies = {it.get("q_locacc") for it in items}
        if len(accuracies) != 1:
            raise TrackError(f"balise group {nid}: its balises give different q_locacc {sorted(map(str, accuracies))}")
        own = accuracies.pop()
        if own is None and national is None:
            raise TrackError(f"balise group {nid} has no q_locacc and track {track.track_id} no national value "
                             f"(etcs.q_nvlocacc)")
        q = checked_q_locacc(own, f"balise group {nid}: q_locacc") if own is not None else national
        orientation = orientations.pop()
        ordered = sorted(items, key=lambda it: it["position"])
        reference = ordered[0] if orientation > 0 else ordered[-1]
        groups[nid] = BaliseGroup(nid, float(reference["position"]), orientation, q,
                                  tuple(str(it["id"]) for it in ordered),
                                  tuple(float(it["position"]) for it in ordered))
        for it in items:
            group_of[str(it["id"])] = nid
    return groups, group_of


def reaction_of(value, where: str) -> Reaction:
    if str(value) not in REACTIONS:
        raise TrackError(f"{where}: reaction {value!r} unknown; known: {', '.join(REACTIONS)}")
    return REACTIONS[str(value)]


def _links(track_id: str, block: dict, groups: dict[str, BaliseGroup]) -> dict[tuple[str, int], Link]:
    linking = block.get("linking")
    if linking is None:
        return {}
    links: dict[tuple[str, int], Link] = {}
    if linking == "auto":
        reaction = reaction_of(block.get("link_reaction", "service_brake"), f"track {track_id}: etcs.link_reaction")
        ordered = sorted(groups.values(), key=lambda g: g.reference)
        for a, b in zip(ordered, ordered[1:]):
            distance = b.reference - a.reference
            links[(a.nid_bg, 1)] = Link(a.nid_bg, b.nid_bg, distance, 1, reaction)
            links[(b.nid_bg, -1)] = Link(b.nid_bg, a.nid_bg, distance, -1, reaction)
        return links
    if not isinstance(linking, list):
        raise TrackError(f"track {track_id}: etcs.linking must be 'auto' or a list of links")
    for entry in linking:
        if not isinstance(entry, dict) or not {"from", "to", "distance"} <= set(entry):
            raise TrackError(f"track {track_id}: link {entry!r} needs 'from', 'to' and 'distance'")
        a, b = str(entry["from"]), str(entry["to"])
        for nid in (a, b):
            if nid not in groups:
                raise TrackError(f"track {track_id}: link {a} -> {b} names the unknown balise group {nid}")
        if a == b:
            raise TrackError(f"track {track_id}: link {a} -> {b} links a group to itself")
        distance = float(entry["distance"])
        span = groups[b].reference - groups[a].reference
        if not (math.isfinite(distance) and distance > 0.0) or abs(distance - abs(span)) > LINK_TOLERANCE:
            raise TrackError(f"track {track_id}: link {a} -> {b} distance {distance:g} m does not match the "
                             f"chainages ({abs(span):g} m apart, tolerance {LINK_TOLERANCE:g} m)")
        direction = 1 if span > 0 else -1
        if (a, direction) in links:
            raise TrackError(f"track {track_id}: group {a} is linked twice in direction {direction:+d}")
        links[(a, direction)] = Link(a, b, distance, direction,
                                     reaction_of(entry.get("reaction", "service_brake"), f"link {a} -> {b}"))
    return links

"""Common-cause groups: sources that can fail together (docs/fusion.md, "Common causes").

A track declares, in its ``common_cause`` block, which of its equipment shares a cause of
failure: base stations served by one timing node or one fibre ring (they lose their
synchronisation together and walk off the same way), balises laid by one survey, loops of one
feeder. Each group has a prior: the probability [1] that the group is in fault at a given time.
ARAIM's fault model (narrow faults of one source, wide faults of a group, each with its prior)
monitors the groups whose prior exceeds the integrity risk the consumer allots to unmonitored
faults; a sensor's decoder covers those by construction (the mm-wave decoders' solution
separation leaves the whole group out, core/sensors/mmwave.py ``SolutionSeparation``).

Two ways to name the members::

    common_cause:
      - {id: TN, cause: timing node, equipment: mmwave_station, size: 2, prior: 1.0e-4}
      - {id: RING1, cause: fibre ring, members: [MW004, MW005, MW006], prior: 1.0e-5}

``equipment`` + ``size`` cuts the items of that kind, by chainage, into consecutive groups of
``size`` (ids ``TN000``, ``TN001``, ...; the last one may be shorter); ``members`` lists ids of
any kind. A member may belong to several groups.
"""
from __future__ import annotations

import math
from dataclasses import dataclass


class CommonCauseError(ValueError):
    """A common_cause block that cannot be used, with the reason."""


@dataclass(frozen=True, slots=True)
class CommonCause:
    """One group of equipment that can fail together."""

    id: str
    cause: str                  # what the members share ("timing node", "fibre ring", "survey")
    members: tuple[str, ...]    # equipment ids
    prior: float                # probability that the group is in fault at a given time [1]

    def monitored(self, risk: float) -> bool:
        """Whether a consumer that allots ``risk`` [1] to unmonitored faults must cover this group."""
        return self.prior > risk


def parse(entries, equipment: dict[str, list[dict]]) -> tuple[CommonCause, ...]:
    """The groups of a track's ``common_cause`` block (module docstring); ``equipment``: the
    track's expanded equipment by kind. CommonCauseError names the first bad entry."""
    known = {item["id"] for items in equipment.values() for item in items}
    groups: list[CommonCause] = []
    for entry in entries or ():
        if not isinstance(entry, dict) or "id" not in entry or "prior" not in entry:
            raise CommonCauseError(f"common_cause entry {entry!r} needs at least 'id' and 'prior'")
        gid, cause = str(entry["id"]), str(entry.get("cause", ""))
        prior = float(entry["prior"])
        if not (math.isfinite(prior) and 0.0 < prior < 1.0):
            raise CommonCauseError(f"common_cause '{gid}': prior {prior} is not a probability in (0, 1)")
        if "members" in entry:
            members = tuple(str(m) for m in entry["members"])
            unknown = [m for m in members if m not in known]
            if unknown:
                raise CommonCauseError(f"common_cause '{gid}' names equipment the track does not have: {unknown[0]}")
            if len(members) < 2:
                raise CommonCauseError(f"common_cause '{gid}' has fewer than 2 members")
            groups.append(CommonCause(gid, cause, members, prior))
        elif "equipment" in entry:
            kind, size = str(entry["equipment"]), int(entry.get("size", 0))
            if size < 2:
                raise CommonCauseError(f"common_cause '{gid}': 'size' must be an integer >= 2")
            items = [item["id"] for item in equipment.get(kind, [])]
            if not items:
                raise CommonCauseError(f"common_cause '{gid}': the track has no {kind} equipment")
            for n, k in enumerate(range(0, len(items), size)):
                members = tuple(items[k:k + size])
                if len(members) >= 2:
                    groups.append(CommonCause(f"{gid}{n:03d}", cause, members, prior))
        else:
            raise CommonCauseError(f"common_cause '{gid}' names neither 'members' nor 'equipment' and 'size'")
    ids = [g.id for g in groups]
    if len(set(ids)) != len(ids):
        raise CommonCauseError("common_cause group ids are not unique")
    return tuple(groups)


def member_groups(groups, ids, risk: float) -> list[tuple[int, ...]]:
    """Per monitored group (prior above ``risk``) with at least two of ``ids``, the indices into
    ``ids`` of its members: the rows a decoder must be able to leave out together."""
    index = {i: k for k, i in enumerate(ids)}
    out = []
    for group in groups:
        rows = tuple(sorted(index[m] for m in group.members if m in index))
        if group.monitored(risk) and len(rows) >= 2:
            out.append(rows)
    return out


# How long a common-cause fault that a decoder's protection covers is taken to last [s]: a
# calibration or a timing node's loss of lock lasts minutes or more, and a standing train keeps
# the stations in view; the fusion counts the fixes of that time as sharing one such error
# (core/fusion/models.py fix_noise).
FAULT_PERSISTENCE = 60.0

"""Decoded fixes of a train on a network, in the network's terms (docs/network.md).

A train's on-board devices are simulated, and their blocks decoded, on its route line
(core/network/path.py ``route_track``): the equipment it passes is that of its route. A
reference fix (a balise, a tag) names the equipment it read, and that equipment has one
place in the network: the fix is restated on the equipment's section, in its chainage
(the train front's offset from the equipment kept, turned with the section's direction).
That is what a decoder looking the reference up in the network's tables would give; it
uses nothing of the route but the equipment's own place. A 2-D fix (DGPS) is projected
onto the whole network by its decoder (core/sensors/dgps.py) and passes unchanged, as do
speeds and distances, which know no track.
"""
from __future__ import annotations

from dataclasses import replace

from ..measurements import PositionFix
from ..signals import InputRejected
from ..track import Track


class SectionLabels:
    """Restates a route line's reference fixes on the sections of their equipment."""

    def __init__(self, route_line: Track):
        self.track_id = route_line.track_id
        self.items = {item["id"]: item for items in route_line.equipment.values() for item in items
                      if "section" in item}

    def __call__(self, m):
        if not isinstance(m, PositionFix) or m.is_map_fix or m.track_id != self.track_id:
            return m
        item = self.items.get(m.reference_id)
        if item is None:
            raise InputRejected("unknown_reference", f"{m.sensor} fix of {m.reference_id[:64]!r}, which no section "
                                                     f"of the network carries")
        d = int(item["section_direction"])
        return replace(m, track_id=str(item["section"]),
                       position=float(item["section_position"]) + d * (m.position - float(item["position"])),
                       direction=m.direction * d)

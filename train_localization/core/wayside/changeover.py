"""A changeover section on a line (seed 004 sections 4.1-4.2, Fig. 5-6): where it lies on
the line's track, the detection that drives it, the controller in the loop and the
catenary events of a run.

A line scenario declares it under ``wayside: changeover:`` (core/scenario.py)::

    changeover:
      counting_points: [AC01, AC02, AC03]     # three consecutive axle-counter heads of the track:
                                              # A side, middle of the neutral section, B side
      catenary: {air_length: 50.0, approach: 250.0}   # catenary.PARAMS (the neutral's length follows)
      occupancy: {}                           # occupancy.PARAMS
      controller: {}                          # neutral_section.PARAMS
      command_latency: 0.01                   # decision -> ABB gate signal [s]

The track must lay a track circuit in each half (AC0..AC1 and AC1..AC2, as Fig. 6) that
reaches AC1 (seed 004 section 4.2: about 400 m, inside the neutral section): the combined
sections are S1 = (that circuit, the axle section from AC0) on the A side and S2 on the B
side. The air sections lie ``approach`` inside the outer counting points.

``ChangeoverLoop`` is what the two wayside nodes (``wayside_occupancy``,
``neutral_section_controller``) do live, for the offline line simulation and replay: it
takes the wayside SectionOccupancy reports, votes, runs the controller and keeps its
commands; ``Site.events`` evaluates them against the trains' true motion.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..measurements import SectionOccupancy
from ..sensors import axle_counter as acm
from ..sensors.base import resolve_params
from ..sensors.track_circuit import KIND as TC_KIND
from ..track import Track, extent
from . import catenary, neutral_section, occupancy

KEYS = ("counting_points", "catenary", "occupancy", "controller", "command_latency")
ABB_TOPICS = {catenary.ABB1: "changeover/abb1", catenary.ABB2: "changeover/abb2"}   # std_msgs/Bool, true = closed
COMBINED_TOPIC = "wayside/combined"
LATENCY_LIMITS = (0.0, 1.0)


class ChangeoverError(ValueError):
    """A changeover that cannot be laid on the track, with the reason."""


@dataclass(frozen=True)
class Site:
    """A changeover section of a line: its catenary layout, the combined sections of its
    detection and the resolved parameters of the voting and the controller."""

    layout: catenary.Layout
    sections: occupancy.SectionMap
    occupancy: dict = field(repr=False)
    controller: dict = field(repr=False)
    command_latency: float = 0.01

    @classmethod
    def from_config(cls, config: dict, track: Track) -> "Site":
        """From a scenario's ``wayside: changeover:`` on its track (ChangeoverError if it
        cannot be laid: unknown keys or heads, heads not consecutive, no circuit over a half)."""
        if not isinstance(config, dict):
            raise ChangeoverError(f"changeover must be a mapping of {', '.join(KEYS)}")
        unknown = sorted(set(config) - set(KEYS))
        if unknown:
            raise ChangeoverError(f"changeover: unknown key(s) {', '.join(unknown)}; known: {', '.join(KEYS)}")
        ids = [str(h) for h in config.get("counting_points", ()) or ()]
        if len(ids) != 3:
            raise ChangeoverError("changeover: counting_points must name three axle-counter heads (A side, "
                                  f"middle, B side), not {ids!r}")
        heads = sorted(track.items(acm.HEAD_KIND), key=lambda h: h["position"])
        order = [h["id"] for h in heads]
        missing = [h for h in ids if h not in order]
        if missing:
            raise ChangeoverError(f"changeover: counting point(s) {', '.join(missing)} not on track {track.track_id}")
        k = order.index(ids[0])
        if order[k:k + 3] != ids:
            raise ChangeoverError(f"changeover: counting points {', '.join(ids)} are not consecutive heads along "
                                  f"the track (its heads: {', '.join(order)})")
        ac = tuple(float(heads[k + j]["position"]) for j in range(3))
        try:
            layout = catenary.Layout.around(ac, track.length, config.get("catenary"))
            occ = resolve_params(occupancy.PARAMS, config.get("occupancy"))
            ctrl = resolve_params(neutral_section.PARAMS, config.get("controller"))
        except ValueError as exc:
            raise ChangeoverError(f"changeover: {exc}") from None
        latency = float(config.get("command_latency", 0.01))
        if not LATENCY_LIMITS[0] <= latency <= LATENCY_LIMITS[1]:
            raise ChangeoverError(f"changeover: command_latency must be in {LATENCY_LIMITS} s, not {latency}")
        axle_sections = acm.section_ids(heads)
        pairs = {}
        for sid, lo, hi, j in (("S1", ac[0], ac[1], k), ("S2", ac[1], ac[2], k + 1)):
            circuits = [c["id"] for c in track.items(TC_KIND) if _covers(extent(TC_KIND, c), lo, hi, ac[1])]
            if not circuits:
                raise ChangeoverError(f"changeover: no track circuit of track {track.track_id} in {lo:g}..{hi:g} m "
                                      f"({ids[j - k]}..{ids[j - k + 1]}) reaches the middle counting point at "
                                      f"{ac[1]:g} m (seed 004 Fig. 6)")
            pairs[sid] = (str(circuits[0]), axle_sections[j])
        return cls(layout, occupancy.SectionMap(pairs), occ, ctrl, latency)

    def section_strings(self) -> list[str]:
        """The combined sections as the wayside nodes' ``sections`` parameter."""
        return [f"{sid}:{tc}:{ac}" for sid, (tc, ac) in self.sections.pairs.items()]

    def switching(self, stamp: float, switch: str, on: bool) -> catenary.Switching:
        """The ABB state change of a command decided (or received) at ``stamp`` [s]."""
        return catenary.effective(stamp, switch, on, self.command_latency, self.layout.params["supply_frequency"])

    def events(self, switchings: list[catenary.Switching], times: np.ndarray, fronts: dict[str, np.ndarray],
               orientations: dict[str, int], vehicles: dict) -> catenary.CatenaryReport:
        """Catenary events of a run: ``fronts`` train -> true front chainage [m] at ``times``
        [s]; each vehicle's raised pantographs (Vehicle.pantographs, offsets behind the front)."""
        pans = {name: catenary.pantograph_chainages(fronts[name], orientations[name], vehicles[name].pantographs)
                for name in fronts if vehicles[name].pantographs}
        roof = {name: vehicles[name].roof_bus for name in pans}
        return catenary.events(self.layout, switchings, times, pans, roof)


def _covers(span: tuple[float, float], lo: float, hi: float, middle: float) -> bool:
    """A circuit over ``span`` [m] lies in the block lo..hi and reaches the middle counting
    point (seed 004 section 4.2: about 400 m next to it; the whole block also serves)."""
    a, b = span
    return a >= lo - 1.0 and b <= hi + 1.0 and min(abs(a - middle), abs(b - middle)) <= 1.0 and b - a > 1.0


class ChangeoverLoop:
    """The combined occupancy and the changeover controller of a site, fed with the wayside
    reports: ``report(occ)`` takes one, ``evaluate(now)`` votes and steps the controller
    (at most every ``period`` seconds unless a report came in), keeping every command."""

    def __init__(self, site: Site, period: float = 0.05):
        self.site = site
        self.period = period
        self.combined = occupancy.CombinedOccupancy(site.sections, dict(site.occupancy))
        self.controller = neutral_section.ChangeoverController(dict(site.controller))
        self.commands: list[neutral_section.Command] = []
        self._last = -math.inf
        self._fresh = False

    def report(self, occ: SectionOccupancy) -> bool:
        """One wayside report; False if it is of neither system (ignored)."""
        taken = self.combined.update(occ)
        self._fresh |= taken
        return taken

    def evaluate(self, now: float) -> list[neutral_section.Command]:
        if not self._fresh and now - self._last < self.period - 1e-9:
            return []
        self._fresh = False
        self._last = now
        cmds = self.controller.update(now, self.combined.evaluate(now))
        self.commands.extend(cmds)
        return cmds

    def switchings(self) -> list[catenary.Switching]:
        return [self.site.switching(c.stamp, c.switch, c.on) for c in self.commands]

    def summary(self) -> dict:
        """Commands, safe-state entries and disagreements of the run (JSON-able)."""
        ctrl = self.controller
        return {"commands": [{"stamp": c.stamp, "switch": c.switch, "on": c.on} for c in self.commands],
                "safe_state": [{"stamp": t, "reason": why} for t, why in ctrl.safe_entries],
                "final": ctrl.status(),
                "disagreements": [d.text() for d in self.combined.records],
                "contradictions": [d.text() for d in self.combined.contradictions()]}


def report_dict(report: catenary.CatenaryReport, crossing: dict[str, float] | None = None) -> dict:
    """A CatenaryReport as JSON-able counts: short circuits, switchings in an air section,
    dead time per train [s] (and the time it needs to cross the neutral section, if given)."""
    out = {"short_circuits": len(report.short_circuits), "short_circuit_list": report.short_circuits,
           "air_section_switchings": len(report.air_switchings), "air_section_switching_list": report.air_switchings,
           "dead_time_s": dict(report.dead), "unfed_time_s": dict(report.unfed)}
    if crossing is not None:
        out["crossing_time_s"] = dict(crossing)
    return out


EVENT_GRID = 0.005      # [s] catenary event grid of a line run (0.42 m at 300 km/h; air sections are 50 m)


def line_events(site: Site, scenario, truth: dict[str, np.ndarray],
                switchings: list[catenary.Switching]) -> dict:
    """The catenary events of a line run (report_dict, plus per train the time its leading
    pantograph needed to cross the neutral section proper [s]).

    truth: train -> (n, 2) array of (stamp [s], true front chainage [m]); a train is off the
    line (no pantograph touches) outside its truth's time span."""
    spans = [a[:, 0] for a in truth.values() if len(a)]
    if not spans:
        return report_dict(catenary.CatenaryReport([], [], {}, {}, {}), {})
    times = np.arange(min(s[0] for s in spans), max(s[-1] for s in spans) + 1e-9, EVENT_GRID)
    fronts, orientations, vehicles, crossing = {}, {}, {}, {}
    b1, a2 = site.layout.air1[1], site.layout.air2[0]
    for name, arr in truth.items():
        train = scenario.train(name)
        if not len(arr) or not train.vehicle.pantographs:
            continue
        fronts[name] = np.interp(times, arr[:, 0], arr[:, 1], left=math.nan, right=math.nan)
        orientations[name], vehicles[name] = train.orientation(), train.vehicle
        lead = catenary.pantograph_chainages(fronts[name], orientations[name], [min(train.vehicle.pantographs)])[:, 0]
        crossing[name] = float(EVENT_GRID * np.count_nonzero((lead > b1) & (lead < a2)))
    return report_dict(site.events(switchings, times, fronts, orientations, vehicles), crossing)

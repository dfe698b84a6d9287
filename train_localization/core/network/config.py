"""Tuning of the track-selective fusion (core/network/hypotheses.py); every field is a
parameter of the fusion node on a network (docs/network.md)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ..fusion.config import FusionConfig, doc_field, check_limits, fusion_config, sensor_models
from ..sensors import spec as sensor_spec
from ..sensors.base import ReferenceWindow, sensor_params
from .wayside import network_references
from ..track import Track, extent


MAX_HYPOTHESES = 256   # the most a fusion may keep (max_hypotheses), and a TrackHypotheses message may list


@dataclass(frozen=True)
class NetworkConfig:
    """Where the train starts, and how evidence makes and removes track hypotheses."""

    start_section: str = doc_field("", "section the train front stands on when the fusion starts (a start of mission "
                                       "on a known track)")
    start_direction: int = doc_field(1, "direction of travel along start_section's chainage: +1 increasing, -1 "
                                        "decreasing", limits=(-1, 1))
    wrong_switch_probability: float = doc_field(1.0e-2, "prior probability that a switch lies otherwise than the "
                                                    "interlocking reports it (a detection fault): the reported way "
                                                    "gets 1 minus it at a facing switch", limits=(1.0e-9, 0.5))
    misread_probability: float = doc_field(1.0e-3, "probability that a reference fix (balise, tag) names equipment "
                                                   "the train did not pass (fault mode 'misread')",
                                                   limits=(1.0e-9, 0.5))
    exclusion_references: int = doc_field(2, "distinct references a hypothesis must fail to contain, within "
                                             "exclusion_window, to be excluded (sensors with a 'misread' fault mode; "
                                             "1 for the others)", limits=(1, 10))
    exclusion_window: float = doc_field(30.0, "time within which those references count together [s]",
                                        limits=(0.1, 3600.0))
    map_lateral_gate: float = doc_field(4.0, "a 2-D fix further than this many of its lateral 1-sigma from a "
                                             "hypothesis's path is off that path [1]", limits=(1.0, 100.0))
    map_exclusion_fixes: int = doc_field(5, "consecutive 2-D fixes of one receiver off a path (and on another) that "
                                            "exclude it: one fix may be a non-line-of-sight outlier", limits=(1, 1000))
    map_outlier_probability: float = doc_field(0.01, "share of 2-D fixes whose lateral offset is an outlier, in the "
                                                     "likelihood that ranks the hypotheses", limits=(1.0e-6, 0.5))
    map_reach: float = doc_field(300.0, "a 2-D fix is projected onto the sections of a path within this distance "
                                        "of where the hypothesis puts the receiver [m]", limits=(1.0, 1.0e5))
    branch_margin: float = doc_field(50.0, "a path is continued past a node once its interval's end comes this near "
                                           "to it [m] (plus 1 s at the hypothesis's speed)", limits=(0.0, 1000.0))
    max_hypotheses: int = doc_field(16, "most hypotheses kept; beyond it the state is LOST (the interval can no "
                                        "longer cover every path)", limits=(1, MAX_HYPOTHESES))

    def __post_init__(self):
        check_limits(self, dataclasses.fields(self))
        if self.start_direction not in (1, -1):
            raise ValueError(f"start_direction must be +1 or -1, not {self.start_direction}")


def mirror(section: Track) -> Track:
    """The section described the other way round (chainage c -> length - c), its equipment
    with it: what a train running against its chainage sees in its direction of travel."""
    equipment = {}
    for kind, items in section.equipment.items():
        moved = []
        for item in items:
            start, end = extent(kind, item, default_end=item["position"])
            copy = {k: v for k, v in item.items() if k not in ("start", "end", "length")}
            copy["position"] = section.length - end
            if end != start:
                copy["end"] = section.length - start
            moved.append(copy)
        equipment[kind] = sorted(moved, key=lambda it: it["position"])
    return Track(track_id=section.track_id, length=section.length, equipment=equipment)


def network_fusion_config(scenario, **overrides) -> tuple[FusionConfig, NetworkConfig]:
    """(FusionConfig, NetworkConfig) of one train of a network scenario (core/scenario.py).

    The error models are those of its sensors on its route line (their tuning), with the
    references their fixes may name gathered from every section of the network, each in its
    section's chainage (a fix names a section: admission checks it there). The start is the
    route's first section, its direction and the train's initial chainage on it, known to
    ``initial_position_stddev`` (a start of mission on a known track). ``overrides`` and the
    scenario's ``fusion:`` section may set any field of either."""
    values = dict(scenario.fusion or {})
    values.update(overrides)
    net_fields = {f.name for f in dataclasses.fields(NetworkConfig)}
    net_values = {k: values.pop(k) for k in list(values) if k in net_fields}
    first = scenario.route.steps[0]
    net_values.setdefault("start_section", first.section)
    net_values.setdefault("start_direction", first.direction)
    values.setdefault("initial_position", scenario.start_position + scenario.route.begin)
    values.setdefault("initial_position_stddev", 1.0)
    values.setdefault("track_id", "")
    values.setdefault("track", None)
    sensors = {**scenario.sensors, **scenario.wayside}
    models = sensor_models(sensors, scenario.track, scenario.vehicle)
    tables: dict[str, object] = {}    # sensor -> ReferenceTable of every section's references
    for section in scenario.network.sections.values():
        # a train may run along a section either way: the windows of both directions (the
        # sensors place their fixes along increasing chainage; the mirrored section's windows
        # are those of a train running against it)
        mirrored = sensor_models(sensors, mirror(section), scenario.vehicle)
        for name, model in sensor_models(sensors, section, scenario.vehicle).items():
            if model.references is None:
                continue
            known = tables.get(name)
            windows = dict(known.windows) if known else {}
            back = mirrored[name].references.windows
            for ref, w in model.references.windows.items():
                b = back.get(ref, w)
                windows[ref] = ReferenceWindow(min(w.lo, section.length - b.hi), max(w.hi, section.length - b.lo))
            tables[name] = dataclasses.replace(model.references, windows=windows)
    for node, params in scenario.wayside.items():   # fixes a device gives only over the network's nodes
        sp = sensor_spec(node)
        extra = network_references(sp, sensor_params(sp, params, scenario.vehicle), scenario.network)
        if extra and sp.sensor in tables:
            known = tables[sp.sensor]
            tables[sp.sensor] = dataclasses.replace(known, windows={**known.windows, **extra})
    models = {name: dataclasses.replace(m, references=tables.get(name)) if m.references is not None else m
              for name, m in models.items()}
    values.setdefault("sensors", models)
    return fusion_config(None, **values), NetworkConfig(**net_values)

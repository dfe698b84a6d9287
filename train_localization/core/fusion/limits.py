"""The fusion's derived constants: gates, the confidence's z and the fault bounds, from the
configuration (config.py) and the sensors' error models, built once per filter and read by every
policy. ``FusionConfig.policies`` switches the fault covers and the sensors' own solutions off here."""
from __future__ import annotations

import math
from dataclasses import dataclass

from scipy.stats import chi2, norm

from ..sensors import faults as fault_modes
from . import separation
from .config import FusionConfig, gate_probability
from .layout import StateLayout


@dataclass(frozen=True)
class Limits:
    """Thresholds [1] and bounds of one filter configuration."""

    gates: dict                 # sensor -> chi-square gate of one reading's NIS (1 dof)
    slip_gate: float            # chi-square quantile of ``slip_gate_probability`` (1 dof)
    consistency: float          # mean-NIS limit of the last ``consistency_fixes`` fixes
    z: float                    # the two-sided ``confidence`` quantile of the normal distribution
    bounded: frozenset          # speed sources whose fault modes all end by themselves (a wheel)
    persistent: frozenset       # relative sensors with a fault no own test tells from motion (a radar)
    fault_bounds: dict          # persistent-fault sensor -> z x scale_fault_sigma (impact.py)
    transient_bounds: dict      # relative sensor -> slip_ratio_max of a slip no own solution covers
    offset_bounds: dict         # position sensor -> shared offset bound in each fix's 1-sigma (the gate's radius)
    group_members: dict         # common-cause group ("doppler+wheel") -> its relative sensors (frozenset)
    persistent_bounds: dict     # fault_bounds and each monitored group -> its bound: the scale fault its members
                                # share, up to the smallest of their own bounds (impact.py)
    subs: dict                  # key -> SubModel of the relative sensors' own solutions (separation.py)
    sensor_subs: dict           # sensor -> ((key, SubModel), ...) of its own solutions
    hypotheses: dict            # fault hypothesis -> the own solutions valid under it (separation.hypotheses)

    @classmethod
    def of(cls, cfg: FusionConfig, layout: StateLayout) -> "Limits":
        models, on = cfg.models, cfg.policies
        gates = {s: float(chi2.ppf(gate_probability(cfg, m), 1)) for s, m in models.items()}
        z = float(norm.ppf(0.5 + cfg.confidence / 2.0))
        bounded = frozenset(s for s, m in models.items() if s in layout.episode_sensors
                            and math.isfinite(m.fault_duration_max) and "scale_fault" not in m.faults)
        subs = separation.sub_models(models) if "own_solutions" in on else {}
        sensor_subs: dict[str, tuple] = {}
        for key, sm in subs.items():
            sensor_subs[sm.sensor] = sensor_subs.get(sm.sensor, ()) + ((key, sm),)
        hypotheses = separation.hypotheses(models, subs)
        # relative sensors with a fault no test of their own can tell from motion, which may begin
        # at any time (a radar's scale fault growing slowly): while one carries the speed alone, the
        # interval covers the solution without it (``LoneSource.track``). A calibration fault (a worn
        # wheel) is a constant: the sensor's own solution with its scale opened covers it
        persistent = frozenset(n for n, m in models.items() if m.relative and
                               (fault_modes.PERSISTENT - fault_modes.CALIBRATION) & set(m.faults))
        # the interval covers what such a fault, up to the size the data has not excluded, put into
        # the state (impact.py)
        fault_bounds = {n: z * m.scale_fault_sigma for n, m in models.items()
                        if n in persistent and m.scale_fault_sigma > 0.0} if "persistent_fault_cover" in on else {}
        # relative sensors with a transient fault of bounded ratio (a wheel's slip or slide) that no
        # other sensor's own solution covers (separation.hypotheses: a contactless counter's does) ->
        # that ratio: the interval covers what one its tests could not see put into the state (impact.py)
        transient_bounds = {n: m.slip_ratio_max for n, m in models.items()
                            if m.relative and m.slip_ratio_max > 0.0 and any(
                                f"{n}/{mode}" not in hypotheses for mode in fault_modes.ADHESION & set(m.faults))
                            } if "transient_fault_cover" in on else {}
        # position sensors whose runs of fixes may share an offset (faults.OFFSET) -> its bound in each
        # fix's own 1-sigma: the gate's radius (impact.py)
        offset_bounds = {n: math.sqrt(gates[n]) for n, m in models.items()
                         if m.measures == "position" and fault_modes.OFFSET & set(m.faults)
                         } if "offset_fault_cover" in on else {}
        group_members, group_bounds = common_cause_groups(cfg, z)
        return cls(gates, float(chi2.ppf(cfg.slip_gate_probability, 1)),
                   float(chi2.ppf(cfg.consistency_probability, cfg.consistency_fixes)) / cfg.consistency_fixes,
                   z, bounded, persistent, fault_bounds, transient_bounds, offset_bounds, group_members,
                   {**fault_bounds, **group_bounds}, subs, sensor_subs, hypotheses)


def common_cause_groups(cfg: FusionConfig, z: float) -> tuple[dict, dict]:
    """({group: members}, {group: bound}) of the relative sensors that declare a common cause
    (``ErrorModel.common_causes``), two or more per cause, monitored where ``common_cause_prior``
    exceeds the risk the interval leaves (1 - ``confidence``; ARAIM's wide faults): their readings
    may carry one scale error, up to the smallest of the members' own bounds (a wheel's slips,
    ``slip_ratio_max``; a radar's scale fault, z x ``scale_fault_sigma``), which only a source outside the
    group tests (z: the confidence's quantile). Empty without the persistent-fault cover."""
    if "persistent_fault_cover" not in cfg.policies or cfg.common_cause_prior <= 1.0 - cfg.confidence:
        return {}, {}
    causes: dict[str, list[str]] = {}
    for name, m in sorted(cfg.models.items()):
        if m.relative:
            for cause in m.common_causes:
                causes.setdefault(cause, []).append(name)
    members, bounds = {}, {}
    for names in causes.values():
        own = [cfg.models[n].slip_ratio_max if fault_modes.ADHESION & set(cfg.models[n].faults)
               else z * cfg.models[n].scale_fault_sigma for n in names]
        if len(names) >= 2 and all(b > 0.0 for b in own):
            label = "+".join(names)
            members[label], bounds[label] = frozenset(names), min(own)
    return members, bounds

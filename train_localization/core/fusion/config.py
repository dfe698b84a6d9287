"""Fusion configuration: global tuning, and the error models of the configured sensors.

The filter's state layout, noise model, fault checks and timeouts come from the
``ErrorModel`` of each configured sensor (core/sensors/*.py ``error_model``, computed
from that sensor's resolved parameters); ``FusionConfig`` holds only the global
tuning plus per-sensor ``overrides`` of those models for users who know better.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

from ..sensors import NODE_NAMES, spec as sensor_spec
from ..sensors.base import ErrorModel, sensor_params


def doc_field(default, text: str, factory: bool = False, limits: tuple | None = None):
    """A field with its description and, for a number, its inclusive (lo, hi) limits."""
    if factory:
        return field(default_factory=default, metadata={"doc": text})
    return field(default=default, metadata={"doc": text, "limits": limits})


PROBABILITY = (1.0e-9, 1.0 - 1.0e-9)


def check_limits(obj, fields_) -> None:
    """ValueError naming the first of ``fields_`` (with a ``limits`` from ``doc_field``) whose value in
    ``obj`` lies outside its limits."""
    for f in fields_:
        value, limits = getattr(obj, f.name), f.metadata.get("limits")
        if limits is not None and not limits[0] <= value <= limits[1]:
            raise ValueError(f"{f.name} must be in {limits[0]:g} .. {limits[1]:g}, not {value}")


def sensor_models(sensors: dict[str, dict] | list[str], track, vehicle) -> dict[str, ErrorModel]:
    """Error models (sensor class -> ErrorModel) of sensor nodes and their parameter overrides.

    ``sensors``: sensor node names -> parameters, as a scenario's ``sensors:`` section,
    or a list of node names (default parameters).
    """
    if not isinstance(sensors, dict):
        sensors = {name: {} for name in sensors}
    models = {}
    for node, params in sensors.items():
        sp = sensor_spec(node)
        models[sp.sensor] = sp.errors(sensor_params(sp, params, vehicle), track, vehicle)
    return models


def default_models() -> dict[str, ErrorModel]:
    """Every sensor kind with its default parameters (no track equipment, standard vehicle)."""
    from ..scenario import Vehicle
    return sensor_models(list(NODE_NAMES), None, Vehicle())


# the policies that can be switched off (``FusionConfig.policies``): name -> what it does
POLICIES = {
    "persistent_fault_cover": "the interval covers what a relative sensor's persistent fault (a radar's scale "
                              "fault) up to its bound put into the state (impact.py)",
    "transient_fault_cover": "the interval covers what an unseen slip or slide put into the state (impact.py)",
    "offset_fault_cover": "the interval covers what a run of fixes sharing an offset put into the state (impact.py)",
    "own_solutions": "each relative sensor's own solution beside the filter, and the fixes under each fault "
                     "hypothesis (separation.py, solutions.py)",
    "lone_source": "while one speed source with a persistent fault mode carries the speed alone, the interval "
                   "covers the solution without it (lone.py)",
    "lone_source_kept": "that solution stays, moving with the filter, when another source comes back, until a fix "
                        "locates the train (lone.py)",
    "scale_fault_explanation": "a gated fix that a scale fault of a speed source in use explains opens that "
                               "source's scale (fixes.py)",
    "lone_sensor_exempt": "the only relative sensor of a train without slip physics is not excluded by the "
                          "disagreement tests (views.judged)",
}


@dataclass
class FusionConfig:
    """Global tuning of the filter; every field but ``sensors`` is a fusion node parameter."""

    track_id: str = doc_field("", "track id of the published states")
    sensors: dict = doc_field(default_models, "sensor class -> ErrorModel of the configured sensors "
                                              "(built from their parameters, not a node parameter)", True)
    overrides: dict = doc_field(dict, "sensor class -> {error-model field: value}: replaces what the sensor's "
                                      "own model says (core/sensors/base.py ErrorModel)", True)
    track: object = doc_field(None, "the track (core/track.py Track) whose ends bound the fixes taken (admission.py); "
                                    "None: not checked (not a node parameter)")
    jerk_psd: float = doc_field(0.1, "white-jerk spectral density of the motion model [m^2/s^5] (jerk-limited "
                                     "profiles, 0.5 m/s^3)", limits=(0.0, 100.0))
    scale_psd: float = doc_field(1e-9, "random-walk spectral density of the constant scale states [1/s]", limits=(0.0, 1.0e-3))
    bias_psd: float = doc_field(0.0, "random-walk spectral density of the bias states [m^2/s^3]", limits=(0.0, 1.0))
    initial_speed_stddev: float = doc_field(100.0, "prior 1-sigma of the speed [m/s] (unknown at start-up)", limits=(0.01, 1000.0))
    initial_accel_stddev: float = doc_field(1.0, "prior 1-sigma of the acceleration [m/s^2]", limits=(0.01, 10.0))
    gate_probability: float = doc_field(0.9999, "chi-square gate (1 dof) of every measurement (a sensor's error "
                                                "model may set its own)", limits=PROBABILITY)
    slip_gate_probability: float = doc_field(0.999, "chi-square quantile above which a slip sensor's increment, or "
                                                    "its disagreement accumulated over slip_window, starts or "
                                                    "extends a slip/slide episode", limits=PROBABILITY)
    slip_window: float = doc_field(1.0, "window of the accumulated slip test [s]: a slip too small to show in one "
                                        "increment (low speed, slow onset) shows in the sum; the increments of the "
                                        "window are then excluded retroactively", limits=(0.05, 30.0))
    slip_min_drive: float = doc_field(0.2, "|acceleration| [m/s^2] below which a wheel transmits too little "
                                           "traction or braking force to slip or slide (running resistance): a "
                                           "disagreement then is as likely the other speed sources' fault", limits=(0.0, 5.0))
    slip_holdoff: float = doc_field(0.5, "a slip sensor stays excluded this long after its last disagreement [s]", limits=(0.0, 30.0))
    slip_reference_timeout: float = doc_field(1.0, "a disagreement is taken as a slip or slide (not as ambiguous) "
                                                   "only if another speed source was accepted within this time [s]", limits=(0.0, 30.0))
    plausible_sigmas: float = doc_field(4.0, "an error state (scale, bias) estimated beyond this many of its prior "
                                             "1-sigma (and significantly so: beyond the slip gate of its own "
                                             "variance) is implausible: the filter absorbed a fault; the relative "
                                             "sensors' error states are re-learnt and the interval widened", limits=(1.0, 100.0))
    consistency_fixes: int = doc_field(5, "number of recent accepted absolute fixes whose mean NIS is monitored "
                                          "(those of sensors without a fix-bias state together: independent "
                                          "references; a sensor with one on its own)", limits=(2, 100))
    consistency_probability: float = doc_field(0.99, "chi-square quantile of that mean NIS above which the filter "
                                                     "is inconsistent: its covariance is scaled by the mean NIS "
                                                     "and the mode is DEGRADED until a fix agrees again",
                                                     limits=PROBABILITY)
    fault_onset_spacing: float = doc_field(5.0, "a persistent fault of a relative sensor (a radar's scale fault) is "
                                                "followed from onsets this far apart [s] (core/fusion/impact.py): the "
                                                "interval covers what it put into the state since each",
                                           limits=(0.05, 3600.0))
    fault_onsets: int = doc_field(8, "fault hypotheses followed per sensor with a persistent fault (the latest "
                                     "onsets, and older ones, going on or ended, whose effect is the largest)",
                                  limits=(2, 100))
    common_cause_prior: float = doc_field(1.0e-4, "probability that the relative sensors sharing a cause of failure "
                                                  "(the error models' common_causes: a wheel's slips and a radar's "
                                                  "echo on one wet or snowy track) are in fault together; above 1 - "
                                                  "confidence they are one fault hypothesis, their readings carrying "
                                                  "the same scale error (core/fusion/impact.py). Not monitored by "
                                                  "default: its price is 2-9x the mean width of a wheel-and-radar "
                                                  "train (docs/fusion.md); set it to 0.01 where wet or snowy track "
                                                  "and a degraded radar meet", limits=(0.0, 1.0))
    branch_timeout: float = doc_field(120.0, "longest time an unexplained (gated) fix is kept as an alternative "
                                             "hypothesis [s]", limits=(0.0, 3600.0))
    history: float = doc_field(2.0, "how late a measurement may be [s]", limits=(0.01, 60.0))
    confidence: float = doc_field(0.999, "probability of [position_min, position_max]", limits=(0.5, 1.0 - 1.0e-9))
    lost_stddev: float = doc_field(100.0, "position 1-sigma above which the mode is LOST [m]", limits=(0.01, 1.0e6))
    initial_position: float = doc_field(math.nan, "chainage [m] where the train stands when the fusion starts, if "
                                                  "known (a stabling mark; the seed 003 rig's reference mark): the "
                                                  "filter starts there at rest instead of waiting for absolute fixes; "
                                                  "NaN: unknown")
    initial_position_stddev: float = doc_field(0.01, "1-sigma of initial_position [m]", limits=(1.0e-4, 1.0e4))
    policies: frozenset = doc_field(lambda: frozenset(POLICIES), "the policies switched on (names of POLICIES; "
                                                                "all by default): a study or a test leaves one out "
                                                                "(not a node parameter)", True)

    def __post_init__(self):
        check_limits(self, self.tuning_fields())
        if math.isinf(self.initial_position):
            raise ValueError(f"initial_position must be a chainage [m] or NaN (unknown), not {self.initial_position}")
        self.policies = frozenset(self.policies)
        unknown = sorted(self.policies - POLICIES.keys())
        if unknown:
            raise ValueError(f"policies names unknown {', '.join(unknown)}; known: {', '.join(POLICIES)}")
        models = dict(self.sensors)
        for name, values in (self.overrides or {}).items():
            if name not in models:
                raise ValueError(f"overrides name sensor {name!r}, which is not configured; configured: "
                                 f"{', '.join(sorted(models))}")
            models[name] = models[name].overridden(values)
        self.models: dict[str, ErrorModel] = models

    @classmethod
    def tuning_fields(cls):
        """The fields that are global tuning (node parameters)."""
        return [f for f in fields(cls) if f.name not in ("sensors", "overrides", "track", "policies")]


# per-sensor tables that scenarios (and the bags recorded from them) carried before the
# sensors owned their error models; the sensors' models replace them
LEGACY_FUSION_KEYS = frozenset({
    "scale_sensors", "bias_sensors", "slip_sensors", "fix_bias_sensors", "fix_bias_per_reference", "timeouts",
    "scale_tau", "scale_sigma", "scale_offset_sigma", "initial_scale_stddev", "bias_sigma", "fix_bias_sigma",
    "fix_bias_length", "fix_bias_tau", "reported_fix_bias", "creep_coefficient", "reported_scale",
    "reported_bias", "stddev_factor", "gate_probabilities", "reacquire_count", "reacquire_time"})


def fusion_config(scenario, **overrides) -> FusionConfig:
    """FusionConfig of a (one train's) scenario (core/scenario.py Scenario, or None): the error
    models of its sensors (and of the wayside sensors of its line) on its track, and its
    ``fusion:`` section (global tuning and per-sensor ``overrides``), plus keyword overrides.
    Legacy per-sensor tables (``LEGACY_FUSION_KEYS``, in bags recorded before) are ignored."""
    values = {k: v for k, v in ((scenario.fusion if scenario else {}) or {}).items() if k not in LEGACY_FUSION_KEYS}
    values.update(overrides)
    if scenario is not None:
        values.setdefault("track_id", scenario.track.track_id)
        values.setdefault("track", scenario.track)
        # a train of a line also takes the wayside fixes associated with it
        values.setdefault("sensors", sensor_models({**scenario.sensors, **scenario.wayside}, scenario.track,
                                                   scenario.vehicle))
    return FusionConfig(**values)


def gate_probability(cfg: FusionConfig, model: ErrorModel) -> float:
    return cfg.gate_probability if math.isnan(model.gate_probability) else model.gate_probability

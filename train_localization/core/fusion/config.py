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


def _doc(default, text: str, factory: bool = False):
    if factory:
        return field(default_factory=default, metadata={"doc": text})
    return field(default=default, metadata={"doc": text})


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


@dataclass
class FusionConfig:
    """Global tuning of the filter; every field but ``sensors`` is a fusion node parameter."""

    track_id: str = _doc("", "track id of the published states")
    sensors: dict = _doc(default_models, "sensor class -> ErrorModel of the configured sensors "
                                         "(built from their parameters, not a node parameter)", True)
    overrides: dict = _doc(dict, "sensor class -> {error-model field: value}: replaces what the sensor's "
                                 "own model says (core/sensors/base.py ErrorModel)", True)
    jerk_psd: float = _doc(0.1, "white-jerk spectral density of the motion model [m^2/s^5] (jerk-limited "
                                "profiles, 0.5 m/s^3)")
    scale_psd: float = _doc(1e-9, "random-walk spectral density of the constant scale states [1/s]")
    bias_psd: float = _doc(0.0, "random-walk spectral density of the bias states [m^2/s^3]")
    initial_speed_stddev: float = _doc(100.0, "prior 1-sigma of the speed [m/s] (unknown at start-up)")
    initial_accel_stddev: float = _doc(1.0, "prior 1-sigma of the acceleration [m/s^2]")
    gate_probability: float = _doc(0.9999, "chi-square gate (1 dof) of every measurement (a sensor's error "
                                           "model may set its own)")
    slip_gate_probability: float = _doc(0.999, "chi-square quantile above which a slip sensor's increment, or "
                                               "its disagreement accumulated over slip_window, starts or "
                                               "extends a slip/slide episode")
    slip_window: float = _doc(1.0, "window of the accumulated slip test [s]: a slip too small to show in one "
                                   "increment (low speed, slow onset) shows in the sum; the increments of the "
                                   "window are then excluded retroactively")
    slip_min_drive: float = _doc(0.2, "|acceleration| [m/s^2] below which a wheel transmits too little "
                                      "traction or braking force to slip or slide (running resistance): a "
                                      "disagreement then is as likely the other speed sources' fault")
    slip_holdoff: float = _doc(0.5, "a slip sensor stays excluded this long after its last disagreement [s]")
    slip_reference_timeout: float = _doc(1.0, "a disagreement is taken as a slip or slide (not as ambiguous) "
                                              "only if another speed source was accepted within this time [s]")
    plausible_sigmas: float = _doc(4.0, "an error state (scale, bias) estimated beyond this many of its prior "
                                        "1-sigma is implausible: the filter absorbed a fault; the relative "
                                        "sensors' error states are re-learnt and the interval widened")
    consistency_fixes: int = _doc(5, "number of recent accepted absolute fixes whose mean NIS is monitored "
                                     "(fixes of sensors without a fix-bias state: independent references)")
    consistency_probability: float = _doc(0.99, "chi-square quantile of that mean NIS above which the filter "
                                                "is inconsistent: its covariance is scaled by the mean NIS "
                                                "and the mode is DEGRADED until a fix agrees again")
    branch_timeout: float = _doc(120.0, "longest time an unexplained (gated) fix is kept as an alternative "
                                        "hypothesis [s]")
    history: float = _doc(2.0, "how late a measurement may be [s]")
    confidence: float = _doc(0.999, "probability of [position_min, position_max]")
    lost_stddev: float = _doc(100.0, "position 1-sigma above which the mode is LOST [m]")

    def __post_init__(self):
        for f in self.tuning_fields():
            value = getattr(self, f.name)
            if f.name.endswith("probability") or f.name == "confidence":
                if not 0.0 < value < 1.0:
                    raise ValueError(f"{f.name} must be in (0, 1), not {value}")
            elif isinstance(value, (int, float)) and not isinstance(value, bool) and not value >= 0.0:
                raise ValueError(f"{f.name} must be >= 0, not {value}")
        if self.history <= 0.0:
            raise ValueError("history must be > 0 s")
        if self.consistency_fixes < 2:
            raise ValueError("consistency_fixes must be >= 2")
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
        return [f for f in fields(cls) if f.name not in ("sensors", "overrides")]


def gate_probability(cfg: FusionConfig, model: ErrorModel) -> float:
    return cfg.gate_probability if math.isnan(model.gate_probability) else model.gate_probability

"""Sensor parameters: every number has a physical range that holds its default, and
``resolve_params`` refuses a value beyond it (a scenario file as the node refuses a ROS
parameter); the scenarios, bags and campaign draws of the repository stay within."""
from __future__ import annotations

import copy
import math

import pytest
import yaml

from conftest import ROOT
from train_localization.core import campaign
from train_localization.core.campaign import FAMILIES, generate
from train_localization.core.scenario import Scenario
from train_localization.core.sensors import NODE_NAMES, spec
from train_localization.core.sensors.base import (COMMON_PARAMS, Param, SensorSpec, check_declared, resolve_params,
                                                  sensor_params)

NUMERIC = [(node, name) for node in NODE_NAMES for name, p in {**COMMON_PARAMS, **spec(node).params}.items()
           if p.numeric]


def _param(node: str, name: str) -> Param:
    return {**COMMON_PARAMS, **spec(node).params}[name]


def _resolve_all(data: dict) -> None:
    """Resolve every sensor's parameters of a scenario dict (raises on a value beyond its limits)."""
    sc = Scenario.from_dict(copy.deepcopy(data))
    for node, params in sc.sensors.items():
        sensor_params(spec(node), params, sc.vehicle)


# --------------------------------------------------------------------------- declarations
@pytest.mark.parametrize("node", NODE_NAMES)
def test_every_numeric_parameter_has_limits_that_hold_its_default(node):
    params = spec(node).params
    numeric = {n: p for n, p in params.items() if p.numeric}
    assert numeric, node
    for name, p in numeric.items():
        assert p.limits is not None and len(p.limits) == 2, (node, name)
        lo, hi = p.limits
        assert lo < hi, (node, name)
        if isinstance(p.default, int):
            assert type(lo) is int and type(hi) is int, (node, name)   # a count: integer limits
        else:
            assert isinstance(lo, float) and isinstance(hi, float), (node, name)
        # NaN only where the description says what it stands for (the vehicle's, drawn per device)
        assert lo <= p.default <= hi or (math.isnan(p.default) and "NaN (default)" in p.description), (node, name)
        assert "[" in p.description, f"{node}.{name}: no unit in brackets"
    for name, p in params.items():   # bools, strings and lists have none
        assert p.numeric or p.limits is None, (node, name)
    check_declared(params, node)
    check_declared(COMMON_PARAMS, "COMMON_PARAMS")


def test_a_declaration_without_limits_or_with_a_default_beyond_them_is_refused():
    with pytest.raises(ValueError, match="'gain' needs limits"):
        check_declared({"gain": Param(1.0, "gain [1]")}, "x")
    with pytest.raises(ValueError, match="'count' needs integer limits"):
        check_declared({"count": Param(3, "count [1]", (1.0, 5.0))}, "x")
    with pytest.raises(ValueError, match=r"x: default of parameter 'gain' must be in 0 \.\. 0\.5, not 1\.0"):
        check_declared({"gain": Param(1.0, "gain [1]", (0.0, 0.5))}, "x")
    good = spec("doppler_radar")
    bad = dict(good.params, spread=Param(2.0, "spread [1]", (0.0, 1.0)))
    with pytest.raises(ValueError, match="doppler_radar: default of parameter 'spread'"):
        SensorSpec(good.node, good.sensor, good.simulator, good.decoder, bad, good.description)


# --------------------------------------------------------------------------- resolve_params
@pytest.mark.parametrize("node,name", NUMERIC)
def test_resolve_params_accepts_the_bounds_and_refuses_beyond(node, name):
    p = _param(node, name)
    lo, hi = p.limits
    declared = spec(node).params
    for value in (lo, hi):
        assert resolve_params(declared, {name: value})[name] == value
    if isinstance(p.default, int):
        beyond = (lo - 1, hi + 1)
    else:
        beyond = (math.nextafter(float(lo), -math.inf), math.nextafter(float(hi), math.inf), 10.0 * hi + 1.0)
    for value in beyond:
        message = f"parameter {name!r} must be in {lo:g} .. {hi:g}, not {value!r}"
        with pytest.raises(ValueError) as exc:
            resolve_params(declared, {name: value})
        assert str(exc.value) == message and "\n" not in str(exc.value)


def test_a_value_is_checked_after_its_cast_and_nan_only_where_it_is_the_default():
    wheel = spec("wheel_sensor").params
    assert resolve_params(wheel, {"pulses_per_revolution": 100.0})["pulses_per_revolution"] == 100
    with pytest.raises(ValueError, match=r"^parameter 'pulses_per_revolution' must be in 1 \.\. 1000, not 0$"):
        resolve_params(wheel, {"pulses_per_revolution": 0.4})
    assert resolve_params(wheel, {"slip_rate": 1})["slip_rate"] == 1.0          # an integer for a double
    assert math.isnan(resolve_params(wheel, {"diameter_error": float("nan")})["diameter_error"])  # 'drawn'
    with pytest.raises(ValueError, match=r"^parameter 'slip_rate' must be in 0 \.\. 100, not nan$"):
        resolve_params(wheel, {"slip_rate": float("nan")})
    with pytest.raises(ValueError, match="'sample_rate' must be in 0 .. 1e[+]08, not -1.0"):
        resolve_params(wheel, {"sample_rate": -1.0})                             # the common ones too


def test_a_scenario_with_a_value_beyond_its_limits_is_refused_in_one_line():
    data = yaml.safe_load((ROOT / "config" / "scenario_faults.yaml").read_text())
    data["sensors"]["doppler_radar"]["dropout_rate"] = -0.3
    with pytest.raises(ValueError, match=r"^parameter 'dropout_rate' must be in 0 \.\. 100, not -0\.3$"):
        _resolve_all(data)


# --------------------------------------------------------------------------- values used in the repository
def test_the_scenario_files_and_bags_resolve():
    paths = sorted((ROOT / "config").glob("scenario_*.yaml"))
    assert paths
    for path in paths:
        sc = Scenario.from_yaml(path)
        for node, params in sc.sensors.items():
            sensor_params(spec(node), params, sc.vehicle)
    from train_localization.core.offline import scenario_from_bag
    for bag in sorted((ROOT / "bags").glob("*.mcap")):
        sc = scenario_from_bag(bag)
        for node, params in sc.sensors.items():
            sensor_params(spec(node), params, sc.vehicle)


@pytest.mark.parametrize("family", FAMILIES)
def test_campaign_draws_resolve(family):
    for seed in (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 123456789, campaign.run_seed(0, 0)):
        _resolve_all(generate(family, seed))


class _Extreme(campaign.Draw):
    """The campaign's draws at one end of every range: ``hi`` the upper, else the lower
    (uniform, log-uniform and integer draws; every chance taken, or none)."""

    hi = False

    def u(self, lo, hi):
        return campaign.rounded(hi if self.hi else lo)

    def logu(self, lo, hi):
        return campaign.rounded(hi if self.hi else lo)

    def chance(self, p):
        return self.hi

    def int(self, lo, hi):
        return hi if self.hi else lo


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("end", ["lo", "hi"])
def test_campaign_draws_at_the_ends_of_their_ranges_resolve(family, end, monkeypatch):
    """Every sensor parameter the campaign draws, at either end of its range (the wheel's top
    speed, the longest train's last axle, +-tolerance of the diameter error) is within limits."""
    monkeypatch.setattr(_Extreme, "hi", end == "hi")
    monkeypatch.setattr(campaign, "Draw", _Extreme)
    data = generate(family, 0)
    _resolve_all(data)
    if family == "conventional" and end == "hi":
        wheel, axle = data["sensors"]["wheel_sensor"], data["sensors"]["axle_counter"]
        assert wheel["max_speed"] == pytest.approx(1.05 * 300 / 3.6, rel=1e-4)
        # every chance taken: the wheel worn beyond its tolerance too (core/hard_conditions.py)
        assert wheel["diameter_tolerance"] == 0.012 and wheel["diameter_error"] == pytest.approx(3 * 0.012)
        assert axle["last_axle_offset"] == max(data["vehicle"]["axles"])

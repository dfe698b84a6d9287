"""The longitudinal accelerometer in the fusion (core/fusion/models.py ``Acceleration``, layout
``accel_bias``): a speed reference independent of adhesion and of the radar's beam, which tests
the speed sources' fault hypotheses (core/fusion/impact.py) through the filter's acceleration."""
from __future__ import annotations

from train_localization.core import campaign


def _run_with_accelerometer(family: str, seed: int, max_duration: float) -> dict:
    data = campaign.generate(family, seed, max_duration=max_duration)
    data["sensors"]["accelerometer"] = {}
    return campaign.run_scenario(data)


def test_a_radar_ramping_off_before_the_first_fix_is_caught_by_the_accelerometer():
    """Campaign run lzb:2375130506 (drawn without an accelerometer): the radar's scale ramps to
    -5.1 % over 25 s from 63 s while the wheel's readings, under traction, are taken for slips;
    the filter follows the radar, 313 states outside while DEGRADED (91.9 % inside). With an
    accelerometer the filter's acceleration does not follow the ramp, the radar's fault
    hypotheses see it, and every state is inside."""
    run = _run_with_accelerometer("lzb", 2375130506, max_duration=100.0)
    assert run["conditions"]["ramp"]["radar"].startswith("62.989-")
    assert run["fusion"]["accepted"]["accelerometer"] > 1000
    integrity = run["scores"]["integrity"]
    assert integrity["outside_count"] == 0


def test_the_lone_radars_hypothesis_is_narrowed_by_the_accelerometers_dead_reckoning():
    """Campaign run highspeed_maglev:2313234526 (drawn with an accelerometer): the radar is the
    only speed source, so the interval covers the solution without it (core/fusion/lone.py). As
    the motion model alone that solution spread over the gaps between fixes (mean width 23.4 m
    at 1a5b8b1); as the accelerometer's dead reckoning, which the fixes teach its speed and
    bias (core/fusion/inertial.py), it stays within a few metres, every state inside."""
    run = campaign.run_scenario(campaign.generate("highspeed_maglev", 2313234526))
    assert run["conditions"]["accelerometer"] is True
    integrity = run["scores"]["integrity"]
    assert integrity["outside_count"] == 0
    assert integrity["mean_interval_width_m"] < 3.0

"""Decoding simulated raw data and decoding the same raw data replayed from an MCAP
bag give identical measurements, for every sensor kind."""
from __future__ import annotations

import pytest
import yaml

from conftest import ROOT
from train_localization.core.offline import replay_bag, scenario_from_bag, simulate_scenario
from train_localization.core.scenario import Scenario
from train_localization.core.sensors import NODE_NAMES

CONVENTIONAL = {
    "name": "identity_conventional", "seed": 3, "duration": 25.0,
    "track": yaml.safe_load((ROOT / "config" / "track_test.yaml").read_text()),
    "vehicle": {"type": "conventional", "length": 60.0, "axles": [2.5, 5.0, 30.0, 32.5]},
    "initial": {"position": 880.0, "speed": 30.0},
    "profile": [{"speed": 40.0, "hold": 30.0}],
    "sensors": {"wheel_sensor": {"max_speed": 50.0, "sample_rate": 6000.0}, "doppler_radar": {},
                "eurobalise_reader": {}, "lrl_scanner": {"n_sensors": 2}, "mmwave_ranging": {},
                "axle_counter": {"heads": "AC00"}},
}
MAGLEV = {
    "name": "identity_maglev", "seed": 4, "duration": 15.0,
    "track": {"track_id": "loops", "length": 5000.0, "equipment": {
        "inpo_section": [{"id": "INPO01", "position": 100.0, "end": 3000.0, "period": 0.516}],
        "pattern_belt": [{"id": "PB01", "position": 0.0, "end": 5000.0}]}},
    "vehicle": {"type": "maglev_high_speed", "length": 50.0},
    "initial": {"position": 50.0, "speed": 25.0},  # the INPO count starts at the section entry
    "profile": [{"speed": 35.0, "hold": 30.0}],
    "sensors": {"inpo_receiver": {}, "pattern_belt": {}},
}


def test_the_two_scenarios_cover_every_sensor():
    assert set(CONVENTIONAL["sensors"]) | set(MAGLEV["sensors"]) == set(NODE_NAMES)


@pytest.mark.parametrize("data", [CONVENTIONAL, MAGLEV], ids=lambda d: d["name"])
def test_bag_replay_decodes_exactly_what_the_simulation_decoded(data, tmp_path):
    bag = tmp_path / f"{data['name']}.mcap"
    live = simulate_scenario(Scenario.from_dict(data), bag)
    replayed = replay_bag(bag, scenario_from_bag(bag))
    sensors_seen = {m.sensor if hasattr(m, "sensor") else m.source for m in live.measurements}
    assert len(sensors_seen) == len(data["sensors"]), sensors_seen
    assert replayed.blocks == live.blocks
    assert replayed.measurements == live.measurements

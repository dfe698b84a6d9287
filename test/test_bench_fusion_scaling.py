"""The fusion's scaling benchmark (tools/bench_fusion_scaling.py) measures the runs it names: a
lengthened run on a tiled track, and a line's fusion as simulate_line drives it."""
from __future__ import annotations

from train_localization.core.offline import simulate_scenario
from train_localization.core.scenario import Scenario
from train_localization.tools import bench_fusion, bench_fusion_scaling as scaling
from train_localization.tools.compare_estimates import same_estimates


def test_a_tiled_track_repeats_every_piece_of_equipment_one_track_length_on():
    sc = Scenario.from_yaml("config/scenario_maglev_500.yaml")
    base = sc.track
    three = Scenario.from_dict({**sc.description, "track": scaling.tiled_track(sc.description["track"], 3)}).track
    assert three.length == 3 * base.length == 42000.0
    for kind in base.equipment:
        items, tiled = base.items(kind), three.items(kind)
        assert len(tiled) == 3 * len(items)
        assert len({it["id"] for it in tiled}) == len(tiled)
        for k in range(3):
            assert [it["position"] for it in tiled[k * len(items):(k + 1) * len(items)]] == \
                [it["position"] + k * base.length for it in items]


def test_a_lengthened_run_keeps_its_last_speed_to_the_end_on_track():
    sc = Scenario.from_yaml("config/scenario_maglev_500.yaml")
    long_run = scaling.lengthened(sc, 400.0)
    truth = long_run.trajectory()
    end = truth.state_at(400.0)
    assert long_run.duration == 400.0
    assert abs(end.speed - 138.9) < 1e-6
    assert end.position < long_run.track.length
    assert long_run.track.length == 5 * sc.track.length   # ceil(138.9 x 400 / 14000) + 1 copies


def test_the_benchmarked_line_fusion_makes_the_states_of_simulate_line():
    line = scaling.line_of(Scenario.from_yaml("config/scenario_line_highspeed.yaml"), 2)
    assert list(line.trains) == ["train_a", "train_b"]
    simulated = simulate_scenario(line, t_end=2.0)
    fused, cpu = scaling.fuse_line(line, scaling.line_inputs(line, 2.0))
    assert cpu > 0.0
    for name in line.trains:
        assert len(fused.result.trains[name].estimates) == len(simulated.trains[name].estimates) > 300
        assert same_estimates(fused.result.trains[name].estimates, simulated.trains[name].estimates)


def test_with_accelerometer_adds_one_to_the_sensors():
    sc = bench_fusion.with_accelerometer(Scenario.from_yaml("config/scenario_maglev_500.yaml"))
    assert sorted(sc.sensors) == ["accelerometer", "doppler_radar", "inpo_receiver", "lrl_scanner", "mmwave_ranging"]

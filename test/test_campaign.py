"""tl_campaign: scenario generators, the per-run scorer, the campaign runners and --export.

The integrity figures themselves are the campaign's output (``tl_campaign --runs ...``),
not asserted here; neither are timings.
"""
from __future__ import annotations

import copy
import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import ROOT
from train_localization.core import campaign
from train_localization.core.campaign import ALL_FAMILIES, FAMILIES, generate, run_one
from train_localization.core.fusion import MODE_DEGRADED, MODE_INITIALISING, MODE_NOMINAL
from train_localization.core.measurements import PositionFix
from train_localization.core.offline import sensor_pipelines
from train_localization.core.scenario import Scenario
from train_localization.core.scoring import StateSeries, passing_times, run_scores
from train_localization.tools import campaign as tool

DRAWS = 200


@pytest.fixture(scope="module")
def draws():
    """DRAWS generated scenario dicts per family (seeds 0..DRAWS-1)."""
    return {f: [generate(f, seed) for seed in range(DRAWS)] for f in ALL_FAMILIES}


# --------------------------------------------------------------------------- generator
@pytest.mark.parametrize("family", ALL_FAMILIES)
def test_generator_is_deterministic_per_seed_and_seeds_differ(family, draws):
    assert generate(family, 7) == generate(family, 7) == draws[family][7]
    conditions = [json.dumps(d["campaign"]["conditions"], sort_keys=True) for d in draws[family][:20]]
    assert len(set(conditions)) == 20
    # a shorter run keeps every drawn condition
    short = generate(family, 7, max_duration=5.0)
    assert short["duration"] == 5.0
    assert short["campaign"] == draws[family][7]["campaign"] and short["sensors"] == draws[family][7]["sensors"]


@pytest.mark.parametrize("family", ALL_FAMILIES)
def test_generated_scenarios_load_their_sensors_construct_and_stay_on_the_track(family, draws):
    checked_in = []   # (profile, track) of every checked-in scenario, of each train of a line
    for p in sorted((ROOT / "config").glob("scenario_*.yaml")):
        c = yaml.safe_load(p.read_text())
        checked_in += [{"profile": t.get("profile"), "track": c.get("track")} for t in c.get("trains", [c])]
    for data in draws[family][:6]:
        sc = Scenario.from_dict(copy.deepcopy(data))
        pipes = sensor_pipelines(sc)                 # raises on an unknown or inconsistent parameter
        assert {p.spec.node for p in pipes} == set(data["sensors"])
        assert sc.fusion == {} and campaign.fusion_overrides(family, data) == {}
        assert all(data["profile"] != c["profile"] and data["track"] != c["track"] for c in checked_in)
        traj = campaign._coarse(data["profile"], sc.start_speed, sc.duration)
        front = traj.position + sc.start_position
        assert front.min() - sc.vehicle.length > 0.0 and front.max() < sc.track.length
    fine = sc.trajectory()   # the simulated motion (1 ms steps) of the last one stays on the track too
    assert fine.position.min() - sc.vehicle.length > 0.0 and fine.position.max() < sc.track.length
    if family == "conventional":   # the axle counter lists the heads the train passes
        data = draws[family][0]
        sc = Scenario.from_dict(copy.deepcopy(data))
        front = campaign._coarse(data["profile"], sc.start_speed, sc.duration).position + sc.start_position
        listed = set(data["sensors"]["axle_counter"]["heads"].split(","))
        passed = {h["id"] for h in sc.track.items("axle_counter_head")
                  if front.min() + 1.0 < h["position"] < front.max() - 1.0}
        assert passed <= listed


def test_the_later_families_draw_their_equipment_and_faults(draws):
    """LZB loops cover the line end to end, none longer than 12.7 km (seed 000 section 3.1);
    UTM structures lie over the line without overlapping, and one run in five loses its
    correction link; MLX coils run the whole guideway and a station is biased in ~30 %; HSST
    blocks cover the line; the M-Bahn stator pickup is set for the run's top speed."""
    for data in draws["lzb"]:
        loops = data["track"]["equipment"]["lzb_loop"]
        assert loops[0]["position"] == 0.0 and loops[-1]["end"] == data["track"]["length"]
        assert all(a["end"] == b["position"] for a, b in zip(loops, loops[1:]))
        assert all(lp["end"] - lp["position"] <= 12700.0 + 1e-6 for lp in loops)
        assert [lp["number"] for lp in loops] == list(range(1, len(loops) + 1))
    structures = [d["track"]["equipment"]["structure"] for d in draws["utm"]]
    for sts, data in zip(structures, draws["utm"]):
        assert all(0.0 <= st["start"] < st["end"] <= data["track"]["length"] for st in sts)
        assert all(a["end"] < b["start"] for a, b in zip(sts, sts[1:]))
    assert 100 < sum(bool(sts) for sts in structures)
    assert 20 < sum("faults" in d["sensors"]["dgps_receiver"] for d in draws["utm"]) < 65
    for data in draws["mlx"]:
        assert data["track"]["equipment"]["null_flux_coils"][0]["end"] == data["track"]["length"]
    radio = [d["sensors"].get("mmwave_ranging") or d["sensors"]["mmwave_tdoa"] for d in draws["mlx"]]
    common = [str(d["campaign"]["conditions"].get("common_cause", {}).get("calibration", "")).split(";")
              for d in draws["mlx"]]   # a group's shared bias (hard_conditions._common_cause) is no station fault
    biased = [[f for f in r["faults"].split(";") if f and "sync=" not in f and f not in c]
              for r, c in zip(radio, common)]
    assert 35 < sum(bool(b) for b in biased) < 85
    # HSST: touching check-in blocks from 0 to the end of the line (seed 000 section 2.2.1);
    # a failed rear transmitter in ~10 % of the runs
    for data in draws["hsst"]:
        blocks = data["track"]["equipment"]["checkin_block"]
        assert blocks[0]["start"] == 0.0 and blocks[-1]["end"] == data["track"]["length"]
        assert all(a["end"] == b["start"] for a, b in zip(blocks, blocks[1:]))
    assert 5 < sum("tx_failed" in d["sensors"]["checkin_loop"]["faults"] for d in draws["hsst"]) < 40
    for data in draws["mbahn"]:
        assert data["sensors"]["pole_position"]["top_speed"] >= 22.2
        assert data["track"]["equipment"]["transponder_tag"]


def test_mlx_runs_on_dense_stations_position_by_time_differences_in_half_of_them(draws):
    """mmwave_tdoa instead of mmwave_ranging in about half of the mlx runs whose stations are at
    most 500 m apart, never on sparser ones; a third of them with a station losing its
    synchronisation near the train; the long-stator families lay their stator sections."""
    dense = [d for d in draws["mlx"] if d["campaign"]["conditions"]["station_spacing"] <= 500.0]
    tdoa = [d for d in draws["mlx"] if "mmwave_tdoa" in d["sensors"]]
    assert all(d in dense and "mmwave_ranging" not in d["sensors"] for d in tdoa)
    assert all(d["campaign"]["conditions"]["ranging"] == "tdoa" for d in tdoa)
    assert 0.3 * len(dense) < len(tdoa) < 0.7 * len(dense)
    synced = [d for d in tdoa if "sync=" in d["sensors"]["mmwave_tdoa"]["faults"]]
    assert 0.1 * len(tdoa) < len(synced) < 0.6 * len(tdoa)
    for d in tdoa:
        spacing = d["campaign"]["conditions"]["station_spacing"]
        assert d["sensors"]["mmwave_tdoa"]["max_range"] == pytest.approx(2.6 * spacing + 100.0, rel=1e-5)
    for family in ("highspeed_maglev", "mlx"):
        for d in draws[family]:
            sections = d["track"]["equipment"]["stator_section"]
            assert sections[0]["position"] == 0.0 and sections[-1]["end"] == d["track"]["length"]
            assert all(a["end"] == b["position"] for a, b in zip(sections, sections[1:]))
    assert not any("stator_section" in d["track"]["equipment"] for d in draws["conventional"])


def test_a_tdoa_run_keeps_the_truth_inside_its_interval():
    seed = next(s for s in range(100) if "mmwave_tdoa" in generate("mlx", s)["sensors"])
    r = run_one("mlx", seed, max_duration=20.0)
    assert "error" not in r, r.get("traceback")
    assert r["devices"]["mmwave_tdoa"]["decoder"]["fixes"] > 0.5 * r["devices"]["mmwave_tdoa"]["decoder"]["epochs"]
    assert r["scores"]["integrity"]["inside_fraction"] == 1.0
    assert "mmwave_tdoa" in r["sensors"] and r["sensors"]["mmwave_tdoa"]["delivered"] > 1000


def _radar_hard_condition(conditions: dict) -> bool:
    """Whether a hard condition drew the radar's fault (core/hard_conditions.py)."""
    return ("tunnel_stop" in conditions or "radar" in conditions.get("ramp", {})
            or "low_adhesion" in conditions.get("common_cause", {}))


def test_radar_scale_faults_come_at_once_or_grow_over_a_ramp(draws):
    """One radar in six has a scale fault of 2-8 %, half of them growing over up to 20 s."""
    from train_localization.core.sensors import doppler
    faults = [d["sensors"]["doppler_radar"].get("faults", "") for f in ALL_FAMILIES for d in draws[f]
              if "doppler_radar" in d["sensors"] and not _radar_hard_condition(d["campaign"]["conditions"])]
    parsed = [doppler._parse_faults(text)[0] for text in faults if text]
    assert len(faults) / 10 < len(parsed) < len(faults) / 4
    assert all(0.02 <= abs(scale) <= 0.08 and 5.0 <= t1 - t0 <= 40.0 for t0, t1, scale, _ in parsed)
    ramps = [ramp for *_, ramp in parsed]
    assert 0.3 < sum(r > 0.0 for r in ramps) / len(ramps) < 0.7 and max(ramps) <= 20.0


def _c(draws, family, key):
    return np.array([d["campaign"]["conditions"][key] for d in draws[family]], dtype=float)


def _s(draws, family, sensor, key):
    return np.array([d["sensors"][sensor][key] for d in draws[family]], dtype=float)


def test_conventional_draws_cover_the_stated_ranges(draws):
    f = "conventional"
    top = _c(draws, f, "top_speed_kmh")
    assert top.max() > 280.0 and top.min() < 60.0 and top.max() <= 300.0 * 1.001
    assert 100.0 <= _c(draws, f, "duration").min() and _c(draws, f, "duration").max() <= 200.0
    length = _c(draws, f, "track_length")
    assert length.min() >= 8000.0 and length.max() > 35000.0 and length.max() <= 40000.0
    spacing = _c(draws, f, "balise_spacing")
    assert spacing.min() < 600.0 and spacing.max() > 1900.0
    heads = _c(draws, f, "head_spacing")
    assert heads.min() < 1200.0 and heads.max() > 3800.0
    reversal = [d["campaign"]["conditions"]["reversal_speed_kmh"] for d in draws[f]]
    assert 20 < sum(r is not None for r in reversal) < 120
    assert all(min(leg["speed"] for leg in d["profile"]) < 0 for d, r in zip(draws[f], reversal) if r is not None)
    assert (_c(draws, f, "stops") >= 1).sum() > 50
    accel = np.array([leg["accel"] for d in draws[f] for leg in d["profile"]])
    decel = np.array([leg["decel"] for d in draws[f] for leg in d["profile"]])
    assert 0.3 <= accel.min() and accel.max() <= 1.0 and 0.5 <= decel.min() and decel.max() <= 1.2
    assert _s(draws, f, "wheel_sensor", "slip_ratio_max").max() > 0.24
    assert _s(draws, f, "wheel_sensor", "slip_ratio_max").max() <= 0.25
    assert _s(draws, f, "wheel_sensor", "slip_rate").min() < 0.01 and _s(draws, f, "wheel_sensor", "slip_rate").max() > 0.1
    tol = _s(draws, f, "wheel_sensor", "diameter_tolerance")
    worn = np.array(["worn_wheel" in d["campaign"]["conditions"] for d in draws[f]])
    error = np.abs(_s(draws, f, "wheel_sensor", "diameter_error"))
    assert (error[~worn] <= tol[~worn]).all() and (error[worn] >= 1.5 * tol[worn]).all()
    assert (error[worn] <= 3.0 * tol[worn] * 1.001).all()
    rate = _s(draws, f, "wheel_sensor", "sample_rate")
    assert rate.min() < 4000.0 and rate.max() >= 10000.0     # the lowest rate that resolves the run
    assert _s(draws, f, "doppler_radar", "scale_sigma").max() > 0.009
    assert _s(draws, f, "eurobalise_reader", "telegram_error_rate").max() > 0.1
    for d in draws[f]:   # no axle-counter head under the train at the start
        start, length = d["initial"]["position"], d["vehicle"]["length"]
        assert not any(start - length <= h["position"] <= start for h in d["track"]["equipment"]["axle_counter_head"])
    faults = [d["sensors"]["axle_counter"]["faults"] for d in draws[f]]
    assert sum(":missed" in x for x in faults) > 20 and sum(":extra" in x for x in faults) > 5
    delay = _c(draws, f, "max_delay")
    assert (delay == 0).sum() > 20 and delay.max() > 0.45 and delay.max() <= 0.5
    assert _c(draws, f, "outages").max() >= 2


def test_urban_maglev_draws_cover_the_stated_ranges(draws):
    f = "urban_maglev"
    top = _c(draws, f, "top_speed_kmh")
    assert top.max() > 95.0 and top.max() <= 100.0 * 1.001
    spacing = _c(draws, f, "tag_spacing")
    assert spacing.min() < 60.0 and spacing.max() > 290.0
    assert (_c(draws, f, "stops") >= 2).sum() > 50
    assert 20 < sum(d["campaign"]["conditions"]["reversal_speed_kmh"] is not None for d in draws[f]) < 120
    assert (_c(draws, f, "belt_gaps") > 0).sum() > 50
    assert {tuple(sorted(set(d["sensors"]) - {"accelerometer"})) for d in draws[f]} == \
        {("doppler_radar", "eurobalise_reader", "pattern_belt")}


def test_highspeed_maglev_draws_cover_the_stated_ranges(draws):
    f = "highspeed_maglev"
    top = _c(draws, f, "top_speed_kmh")
    assert top.min() < 220.0 and top.max() > 480.0 and 200.0 <= top.min() and top.max() <= 500.0 * 1.001
    assert (_c(draws, f, "slow_speed_kmh") < top).all()
    spacing = _c(draws, f, "station_spacing")
    assert spacing.min() < 320.0 and spacing.max() > 780.0
    assert _c(draws, f, "inpo_gap_max").max() > 1500.0 and (_c(draws, f, "inpo_coverage") < 1.0).all()
    biased = [d["campaign"]["conditions"]["biased_station"] for d in draws[f]]
    assert 20 < sum(b is not None for b in biased) < 120
    assert all(1.0 <= b["bias"] <= 4.0 for b in biased if b)
    outages = [d["campaign"]["conditions"]["station_outage"] for d in draws[f]]
    assert 20 < sum(o is not None for o in outages) < 120 and all(len(o["stations"]) >= 2 for o in outages if o)
    assert _c(draws, f, "misread_probability").max() > 0.03
    offsets = np.array([st["offset"] for d in draws[f][:20] for st in d["track"]["equipment"]["mmwave_station"]])
    assert offsets.min() < -8.0 and offsets.max() > 8.0


# --------------------------------------------------------------------------- scorer
def _synthetic():
    """10 s at 200 Hz, truth at 10 m/s; INITIALISING for the first 100 states, then errors 0 except
    +5 m in states 400..549 (0.75 s, NOMINAL) and -6 m in 1200..1229 (0.15 s, DEGRADED), 1-sigma 1 m; speed error
    1.0 m/s in states 1500..1519."""
    t = np.arange(2001) * 0.005
    s_true, v_true = 10.0 * t, np.full(t.size, 10.0)
    err = np.zeros(t.size)
    err[400:550] = 5.0
    err[1200:1230] = -6.0
    pos = s_true + err
    mode = np.full(t.size, float(MODE_NOMINAL))
    mode[:100] = MODE_INITIALISING
    mode[1200:1230] = MODE_DEGRADED   # the second excursion is flagged
    pos[:100] = np.nan
    sd = np.ones(t.size)
    half = 3.2905
    speed = v_true.copy()
    speed[1500:1520] += 1.0
    sd_v = np.full(t.size, 0.1)
    sd_v[:100] = 100.0
    sd_v[1510:1520] = 0.5        # claims the 1.0 m/s error within 2 sigma: inside its speed interval
    fused = StateSeries(t, pos, speed, sd, sd_v, pos - half, pos + half, mode)
    return StateSeries.of_truth(t, s_true, v_true), fused


def test_scorer_exact_on_a_synthetic_series():
    truth, fused = _synthetic()
    out = run_scores(truth, fused, 0.005, reference_times=[1.0, 5.9])
    claimed = 2001 - 100
    assert out["states_with_position"] == claimed
    assert out["integrity"]["outside_count"] == 180
    assert out["integrity"]["outside_nominal"] == 150     # the DEGRADED excursion is not counted
    assert out["integrity"]["inside_fraction"] == pytest.approx(1 - 180 / claimed, abs=1e-12)
    ex = out["excursions"]
    assert ex["count"] == 2 and ex["longest_states"] == 150
    assert ex["longest_s"] == pytest.approx(0.75) and ex["longest_start"] == pytest.approx(2.0)
    assert ex["longest_max_error_m"] == pytest.approx(5.0)
    assert out["position_error_m"]["max"] == pytest.approx(6.0)
    assert out["integrity"]["mean_interval_width_m"] == pytest.approx(2 * 3.2905)
    ne = out["normalised_error"]
    assert sum(ne["counts"]) == claimed and ne["max_abs"] == pytest.approx(6.0)
    assert ne["rms"] == pytest.approx(math.sqrt((150 * 25 + 30 * 36) / claimed))
    # envelope: 5 m + 5 % of the distance since the last reference (1.0 s, then 5.9 s)
    env = out["etcs_envelope"]
    assert env["max_ratio"] == pytest.approx(6.0 / (5.0 + 0.05 * 1.0))
    assert env["within"] == claimed - 30 and env["states"] == claimed and env["references_passed"] == 2
    band = out["speed_band"]
    assert band["states"] == claimed and band["violations"] == 20 and band["violations_nominal"] == 20
    degraded = dataclasses.replace(fused, mode=np.where(np.arange(2001) >= 1510, float(MODE_DEGRADED), fused.mode))
    assert run_scores(truth, degraded, 0.005)["speed_band"]["violations_nominal"] == 10   # 1500..1509
    assert band["max_ratio"] == pytest.approx(1.0 / ((2.0 + 6.0 / 47.0) / 3.6))
    speed = out["speed_interval"]   # 1.0 m/s off at 0.1 m/s claimed: 10 sigma, beyond z = 3.29
    assert speed["states"] == 2001 - 100 and speed["outside"] == 10
    assert speed["max_normalised"] == pytest.approx(10.0)
    assert out["mode_fractions"] == {"0": 100 / 2001, "1": (claimed - 30) / 2001, "2": 30 / 2001}
    assert out["first_position_s"] == pytest.approx(0.5)
    pairs = out["error_vs_half_width"]
    assert 180 <= len(pairs["error_m"]) <= 600 and np.allclose(pairs["half_width_m"], 3.2905)
    assert np.count_nonzero(np.abs(pairs["error_m"]) > 3.2905) == 180   # every state outside is kept


def test_passing_times_of_references_in_both_directions():
    t = np.arange(0, 10.0001, 0.01)
    s = np.where(t < 5.0, 10.0 * t, 100.0 - 10.0 * t)  # out to 50 m and back
    times = passing_times(t, s, [44.95, 15.05])
    assert np.allclose(times, [1.51, 4.5, 5.51, 8.5], atol=0.011)


def test_run_one_reports_an_exception_as_an_error_entry(monkeypatch):
    def broken(family, seed, max_duration=None):
        raise RuntimeError("generator exploded")
    monkeypatch.setattr(campaign, "generate", broken)
    r = run_one("conventional", 3)
    assert r["family"] == "conventional" and r["seed"] == 3
    assert "generator exploded" in r["error"] and "Traceback" in r["traceback"]
    s = campaign.summarise([r])
    assert s["all"]["errors"] == 1 and s["checks"]["no_errors"] is False and s["passed"] is False


# --------------------------------------------------------------------------- runners
SHORT = "12"   # simulated seconds per run in the tiny campaigns


def _scores(out: Path) -> dict:
    runs = {}
    for p in sorted((out / "runs").glob("*.json")):
        r = json.loads(p.read_text())
        assert "error" not in r, r.get("traceback")
        runs[p.name] = {k: r[k] for k in ("scores", "fusion", "sensors", "devices", "conditions")}
    return runs


@pytest.fixture(scope="module")
def pool_campaign(tmp_path_factory):
    out = tmp_path_factory.mktemp("pool")
    rc = tool.main(["--runs", "3", "--seed", "5", "--max-duration", SHORT, "--workers", "2", "--out", str(out),
                    "--quiet", "--check"])
    return out, rc


def test_tiny_campaign_on_the_process_pool_writes_runs_summary_and_plots(pool_campaign, capsys):
    out, rc = pool_campaign
    jobs = campaign.jobs(3, FAMILIES, 5)
    assert sorted(p.name for p in (out / "runs").glob("*.json")) == sorted(f"{f}-{s}.json" for f, s in jobs)
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["families"]) == set(FAMILIES) and summary["all"]["runs"] == 3
    assert summary["all"]["errors"] == 0
    assert summary["all"]["states"] == sum(json.loads(p.read_text())["scores"]["states"]
                                           for p in (out / "runs").glob("*.json"))
    assert rc == (0 if summary["passed"] else 1)      # --check follows the targets
    for name in ("integrity.png", "error_vs_half_width.png", "normalised_error.png"):
        assert (out / name).stat().st_size > 1000


def test_tiny_campaign_on_a_dask_cluster_gives_the_pool_scores(pool_campaign, tmp_path):
    from dask.distributed import LocalCluster
    out = tmp_path / "dask"
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster:
        rc = tool.main(["--runs", "3", "--seed", "5", "--max-duration", SHORT, "--out", str(out), "--quiet",
                        "--scheduler", cluster.scheduler_address])
    assert rc == 0
    assert (out / "summary.json").exists()
    assert _scores(out) == _scores(pool_campaign[0])


def test_summarise_rebuilds_the_summary_from_the_run_files(pool_campaign, tmp_path, capsys):
    out, _ = pool_campaign
    again = tmp_path / "again"
    (again / "runs").mkdir(parents=True)
    for p in (out / "runs").glob("*.json"):
        (again / "runs" / p.name).write_text(p.read_text())
    assert tool.main(["--summarise", str(again)]) == 0
    first, second = (json.loads((d / "summary.json").read_text()) for d in (out, again))
    # the same figures; ties (which run holds the longest excursion) and float sums may differ in order
    a, b = first["all"], second["all"]
    assert {k: v for k, v in a.items() if k not in ("cpu_s", "longest_excursion")} == \
        {k: v for k, v in b.items() if k not in ("cpu_s", "longest_excursion")}
    assert a["longest_excursion"]["s"] == b["longest_excursion"]["s"]
    assert b["cpu_s"]["total"] == pytest.approx(a["cpu_s"]["total"]) and second["passed"] == first["passed"]
    assert tool.main(["--summarise", str(tmp_path / "empty")]) == 2


def test_a_state_outside_while_nominal_fails_the_campaign(pool_campaign):
    """The truth outside a NOMINAL interval, in any run, is a failed target (what a train
    protection would act on unwarned), however few such states there are."""
    out, _ = pool_campaign
    results = [json.loads(p.read_text()) for p in sorted((out / "runs").glob("*.json"))]
    clean = campaign.summarise(results)
    assert clean["checks"]["none_outside_nominal"] == (clean["all"]["outside_nominal"] == 0)
    hit = results[0]
    hit["scores"]["integrity"]["outside_nominal"] = 3
    s = campaign.summarise(results)
    assert s["all"]["outside_nominal"] == clean["all"]["outside_nominal"] + 3
    assert [hit["family"], hit["seed"], 3] in s["all"]["runs_outside_nominal"]
    assert s["checks"]["none_outside_nominal"] is False and s["passed"] is False


def test_export_round_trip(tmp_path, capsys):
    path = tmp_path / "run.yaml"
    assert tool.main(["--export", "highspeed_maglev:42", "-o", str(path), "--max-duration", "3"]) == 0
    data = yaml.safe_load(path.read_text())
    assert data == generate("highspeed_maglev", 42, max_duration=3.0)
    sc = Scenario.from_yaml(path)
    assert sc.duration == 3.0 and sc.name == "campaign_highspeed_maglev_42"
    assert sc.sensors == generate("highspeed_maglev", 42)["sensors"]
    # the existing tools take it as any scenario file
    from train_localization.tools import bench_fusion
    assert bench_fusion.main(["--figures", str(path)]) == 0
    assert "campaign_highspeed_maglev_42" in capsys.readouterr().out


# --------------------------------------------------------------------------- hard conditions
def test_hard_conditions_are_drawn_last_and_as_stated(draws, monkeypatch):
    """core/hard_conditions.py: drawn after everything else, so a run is the same but for them;
    a tunnel stop has no reference between its ends, its radar faulty from the restart."""
    from train_localization.core import hard_conditions
    counts = {k: sum(k in d["campaign"]["conditions"] for f in ALL_FAMILIES for d in draws[f])
              for k in ("tunnel_stop", "worn_wheel", "crawl", "adversarial", "common_cause", "ramp")}
    assert all(n > 0 for n in counts.values()), counts
    for f in ALL_FAMILIES:
        for d in draws[f]:
            tunnel = d["campaign"]["conditions"].get("tunnel_stop")
            if tunnel:   # on a network: in the chainage of the train's route line
                equipment = Scenario.from_dict(copy.deepcopy(d)).track.equipment if "route" in d \
                    else d["track"]["equipment"]
                refs = [b["position"] for kind in ("eurobalise", "axle_counter_head")
                        for b in equipment.get(kind, [])]
                assert not any(tunnel["from_m"] <= x <= tunnel["to_m"] for x in refs)
                t0 = float(d["sensors"]["doppler_radar"]["faults"].split("-")[0])
                assert tunnel["restart_s"] <= t0 <= tunnel["restart_s"] + 3.0
    monkeypatch.setattr(hard_conditions, "draw", lambda *args: None)
    for f in ALL_FAMILIES:
        for seed in range(0, DRAWS, 5):
            plain, hard = generate(f, seed), draws[f][seed]
            if not any(k in hard["campaign"]["conditions"] for k in counts):
                assert plain == hard
            assert plain["seed"] == hard["seed"] and plain["campaign"]["delivery"]["seed"] == \
                hard["campaign"]["delivery"]["seed"]


def test_adversarial_fixes_are_injected_as_drawn():
    from train_localization.core.hard_conditions import inject
    fixes = [(t, PositionFix(t, "eurobalise", "eb", "T", f"EB{k}", 100.0 * k, 0.3)) for k, t in enumerate(range(10))]
    attack = {"kind": "claims", "sensor": "eurobalise", "t0": 3.0, "count": 2, "offset": 50.0, "sign": -1}
    out = inject(fixes, attack)
    added = [m for _, m in out if m.position_stddev == 1e-6]
    assert len(out) == 12 and [m.position for m in added] == [250.0, 350.0]
    out = inject(fixes, {**attack, "kind": "unknown"})
    assert [m.reference_id for _, m in out if m.reference_id.startswith("ZZ")] == ["ZZEB3", "ZZEB4"]
    out = inject(fixes, {**attack, "kind": "offset", "offset": 2.0})
    assert len(out) == 10 and [m.position for _, m in out][3:6] == [299.4, 399.4, 500.0]


# --------------------------------------------------------------------------- network
def test_network_runs_are_drawn_through_station_throats(draws):
    """The family ``network`` (core/network/draw.py): a drawn station throat whose every switch
    has a clearance from its curve's geometry, a route that takes either way at the facing
    switches, from rest on its first section, the train staying on it; parallel tracks 4-5 m
    apart; each facing switch reported wrong or unknown in some of the runs."""
    from train_localization.core.network.draw import CLEARANCE_LIMITS, s_curve, s_curve_clearance
    runs = draws["network"]
    for data in runs[:20]:
        sc = Scenario.from_dict(copy.deepcopy(data))
        assert sc.network is not None and sc.start_speed == 0.0
        assert set(sc.sensors) - {"gyro"} == {"wheel_sensor", "doppler_radar", "eurobalise_reader", "dgps_receiver"}
        assert sc.route.steps[0].section == data["route"]["sections"][0]
        c = data["campaign"]["conditions"]
        assert c["network"]["switches"] == len(sc.network.switches()) and 2 <= c["network"]["switches"] <= 5
        assert all(CLEARANCE_LIMITS[0] <= n.clearance <= CLEARANCE_LIMITS[1] for n in sc.network.switches())
        assert c["facing_switches"] == len(sc.route.ways()) >= 1
        ids = [b["id"] for sec in sc.network.sections.values() for b in sec.items("eurobalise")]
        assert len(ids) == len(set(ids))
    gyros = sum("gyro" in d["sensors"] for d in runs)
    assert 0.6 * len(runs) < gyros < 0.9 * len(runs)   # a gyro in three runs of four
    ways = [w for d in runs for w in Scenario.from_dict(copy.deepcopy(d)).route.ways().values()]
    assert 0.3 < ways.count("B1") / len(ways) < 0.7
    wrong = sum(len(d["campaign"]["conditions"]["switches_reported_wrong"]) for d in runs)
    unknown = sum(len(d["campaign"]["conditions"]["switches_reported_unknown"]) for d in runs)
    assert 0.15 * len(ways) < wrong < 0.35 * len(ways) and 0.05 * len(ways) < unknown < 0.2 * len(ways)
    for d in runs:
        for node, way in d["route"].get("reported", {}).items():
            assert way in ("", "B1", "B2")
    elements = {e for d in runs for e in d["campaign"]["conditions"]["network"]["elements"]}
    assert elements == {"crossover", "turnout", "rejoin", "junction"}
    assert sum(d["campaign"]["conditions"]["network"]["reversed_sections"] > 0 for d in runs) > 100
    # an S-curve moves a track by 2R(1 - cos theta); its clearance point is 3.5 m from the track it left
    theta, extent, length = s_curve(4.5, 190.0)
    assert 2 * 190.0 * (1 - math.cos(theta)) == pytest.approx(4.5) and length == pytest.approx(58.5386, abs=1e-3)
    assert 20.0 < s_curve_clearance(4.5, 190.0) < length


@pytest.fixture(scope="module")
def network_run():
    """A short network run that passes a facing switch the interlocking reports the wrong way."""
    seed = next(s for s in range(200) if generate("network", s)["campaign"]["conditions"]["wrong_switches_reached"])
    return run_one("network", seed, max_duration=NETWORK_SHORT)


NETWORK_SHORT = 60.0


def test_a_short_network_run_scores_its_track_selectivity_and_switch_ways(network_run):
    r = network_run
    assert "error" not in r, r.get("traceback")
    net = r["network"]
    assert net["claimed"] > 0 and net["nominal_wrong_track"] == 0
    assert net["inside"] == 1.0 and r["scores"]["integrity"]["inside_fraction"] == 1.0
    assert "etcs" not in r and "stator" not in r
    s = campaign.summarise([r])
    n = s["all"]["network"]
    assert n["runs"] == 1 and n["nominal_wrong_track"] == 0 and n["switch_ways"] == net["switch_ways"]
    assert n["wrong_reports"] and n["wrong_reports"][0][:2] == ["network", r["seed"]]
    assert {"network_selectivity", "network_switch_ways", "network_none_nominal_wrong_track"} <= set(s["checks"])
    text = tool.summary_table(s)
    assert "network (1 runs" in text and "track selectivity" in text


# --------------------------------------------------------------------------- network with ETCS data
def test_network_etcs_runs_draw_the_network_runs_with_etcs_data(draws):
    """The family ``network_etcs``: the network, route, profile and train of the ``network`` run of
    the same seed, every balise group two balises 3 m apart with one Q_LOCACC of 1-5 m, a group in
    front of switches, linking ``auto``, the reader's location error bounded by Q_LOCACC; one group
    passed on the route not read in about a third of the runs."""
    from train_localization.core.etcs.network_data import NetworkEtcsData
    runs = draws["network_etcs"]
    for seed, data in enumerate(runs[:20]):
        plain = draws["network"][seed]
        assert all(data[k] == plain[k] for k in ("route", "profile", "vehicle", "initial"))
        assert [s["alignment"] for s in data["track"]["sections"]] == [s["alignment"] for s in plain["track"]["sections"]]
        assert data["track"]["etcs"]["linking"] == "auto" and "location_sigma" not in data["sensors"]["eurobalise_reader"]
        etcs = NetworkEtcsData.from_network(Scenario.from_dict(copy.deepcopy(data)).network)
        if "tunnel_stop" not in data["campaign"]["conditions"]:   # a tunnel stop takes balises away
            assert len(etcs.groups) == data["campaign"]["conditions"]["balise_groups"]
            for located in etcs.groups.values():
                g = located.group
                assert len(g.balises) == 2 and g.positions[1] - g.positions[0] == pytest.approx(3.0)
                assert g.q_locacc in campaign.Q_LOCACC_DRAWN
    signals = [d["campaign"]["conditions"]["signal_groups"] for d in runs]
    assert sum(signals) > 0.5 * sum(d["campaign"]["conditions"]["network"]["switches"] for d in runs)
    with_groups = [d for d in runs if d["campaign"]["conditions"]["groups_passed"]]
    silent = sum(bool(d["campaign"]["conditions"]["silent_group"]) for d in with_groups)
    assert 0.2 * len(with_groups) < silent < 0.45 * len(with_groups)


@pytest.fixture(scope="module")
def network_etcs_run():
    """A short network_etcs run with a group on its route not read."""
    seed = next(s for s in range(200) if generate("network_etcs", s)["campaign"]["conditions"]["silent_group"])
    return run_one("network_etcs", seed, max_duration=NETWORK_SHORT)


def test_a_short_network_etcs_run_scores_the_etcs_location_on_the_network(network_etcs_run):
    """The location function runs on the network: the true front within the safe front ends in
    >= 99.9 % of the reports, an LRBG, the group not read reported missed; the summary and the
    table carry an ETCS line besides the network one."""
    r = network_etcs_run
    assert "error" not in r, r.get("traceback")
    e, silent = r["etcs"], r["conditions"]["silent_group"]
    assert e["claimed"] > 0 and (e["claimed"] - e["outside"]) / e["claimed"] >= 0.999
    assert e["lrbgs"] and silent not in e["lrbgs"] and e["missed_groups"] == [silent]
    assert r["network"]["claimed"] > 0 and r["network"]["nominal_wrong_track"] == 0
    s = campaign.summarise([r])
    assert s["all"]["etcs"]["runs"] == 1 and s["all"]["network"]["runs"] == 1
    assert {"etcs_safe_front_ends", "network_selectivity"} <= set(s["checks"])
    text = tool.summary_table(s)
    assert "network_etcs: ETCS location (1 runs" in text and "network_etcs: network (1 runs" in text

"""UTM-02 urban maglev sensors against seed 002 section 2.1.2: DGPS fixes projected onto the
track alignment (outages and multipath under structures) and transponder tags about every
100 m read by the on-board reader; the UTM scenario (Doppler + DGPS + tags) through the
fusion."""
from __future__ import annotations

import copy
import dataclasses
import functools
import math
import pickle

import numpy as np
import pytest

from conftest import ROOT
from error_model_checks import (assert_forged_fixes_refused, assert_refused_below_half_the_floor, decoded, floor_runs,
                                lasting)
from train_localization.core.measurements import PositionFix
from train_localization.core.offline import simulate_scenario
from train_localization.core.pipeline import SensorPipeline, simulate_and_decode
from train_localization.core.scenario import Scenario, Vehicle
from train_localization.core.sensors import NODE_NAMES, dgps, spec, transponder
from train_localization.core.signals import InputRejected, RawBlock
from train_localization.core.track import Track
from train_localization.tools.bench_fusion import figures

DGPS, TAGS = "dgps_receiver", "tag_reader"
DP = {k: p.default for k, p in dgps.PARAMS.items()}
TP = {k: p.default for k, p in transponder.PARAMS.items()}
TRACK = {"track_id": "utm_test", "length": 4000.0, "origin": {"x": 100.0, "y": -50.0, "heading": 0.3},
         "alignment": [{"length": 800.0, "curvature": 0.0}, {"length": 700.0, "curvature": 0.002},
                       {"length": 2500.0, "curvature": -0.001}],
         "equipment": {"structure": [{"id": "ST1", "type": "station", "start": 2000.0, "end": 2100.0},
                                     {"id": "TN1", "type": "tunnel", "start": 3000.0, "length": 300.0}],
                       "transponder_tag": [{"every": 100.0, "start": 50.0, "end": 3950.0, "id": "TG{n:03d}"}]}}


def scenario(v0=20.0, pos=400.0, duration=40.0, profile=None, sensors=None, track=None) -> Scenario:
    return Scenario.from_dict({
        "name": "utm", "seed": 3, "duration": duration, "track": copy.deepcopy(track or TRACK),
        "vehicle": {"type": "maglev_urban", "length": 40.0}, "initial": {"position": pos, "speed": v0},
        "profile": profile or [{"speed": v0, "hold": 900.0}], "sensors": sensors or {DGPS: {}, TAGS: {}}})


def errors(run):
    """(fix error [m], its stddev [m], stamps [s]) of every fix against the truth."""
    traj = run.trajectory
    err = np.array([m.position - np.interp(m.stamp, traj.t, traj.position) for m in run.measurements])
    return err, np.array([m.position_stddev for m in run.measurements]), np.array([m.stamp for m in run.measurements])


def raw(run) -> tuple[np.ndarray, np.ndarray]:
    """(sample times, samples) of all blocks of a run."""
    return (np.concatenate([b.times() for b in run.blocks]), np.vstack([b.data for b in run.blocks]).astype(float))


@functools.lru_cache(maxsize=None)
def dgps_run():
    """20 m/s from 400 m over 160 s: the open curve, past the station roof (2000-2100 m) and
    through the tunnel (3000-3300 m)."""
    return simulate_and_decode(DGPS, scenario(duration=160.0))


# --------------------------------------------------------------------------- track geometry
def test_a_map_point_projects_onto_its_chainage_and_lateral_offset():
    track = Track.from_dict(TRACK)
    s = np.array([0.0, 10.0, 799.0, 1100.3, 1499.9, 2600.0, 4000.0])
    x, y = track.xy(s)
    chain, lateral = track.project(x, y)
    assert chain == pytest.approx(s, abs=1e-6) and lateral == pytest.approx(0.0, abs=1e-6)
    heading = np.array([track.pose(v)[2] for v in s[1:-1]])
    left = 1.5   # 1.5 m to the left of the reference direction, also in the curves
    chain, lateral = track.project(x[1:-1] - left * np.sin(heading), y[1:-1] + left * np.cos(heading))
    # (the polyline's 10 m chords turn by up to 0.02 rad against the arc's heading in the R = 500 m
    # curve: 1.5 m x 0.01 rad along the track)
    assert chain == pytest.approx(s[1:-1], abs=0.03) and lateral == pytest.approx(left, abs=0.01)
    chain, lateral = track.project(x[1] + 7.0 * np.sin(heading[0]), y[1] - 7.0 * np.cos(heading[0]))
    assert chain[0] == pytest.approx(10.0, abs=1e-6) and lateral[0] == pytest.approx(-7.0, abs=1e-6)


# --------------------------------------------------------------------------- DGPS
def test_dgps_fixes_lie_on_the_alignment_within_their_stated_stddev():
    run = dgps_run()
    traj = run.trajectory
    t, data = raw(run)
    good = data[:, 2] == 2
    ant = np.interp(t, traj.t, traj.position) - DP["antenna_offset"]
    x, y = run.pipe.track.xy(ant)
    d = np.hypot(data[good, 0] - x[good], data[good, 1] - y[good])
    assert np.sqrt(np.mean(d * d)) < 2.0          # the 2-D solution: about 1 m 2DRMS
    err, sd, stamps = errors(run)
    assert len(err) > 1000
    z = np.abs(err / sd)
    # Gaussian: 68 % within 1 sigma, 99.7 % within 3 (the epochs share the multipath: a margin)
    assert 0.55 < np.mean(z < 1.0) < 0.85 and np.mean(z < 3.0) > 0.99 and z.max() < 5.0
    assert 0.6 < np.sqrt(np.mean(z * z)) < 1.3    # the stddev is neither far too large nor too small
    open_sky = math.hypot(DP["white_sigma"], DP["multipath_sigma"])
    assert np.median(sd) == pytest.approx(open_sky, rel=1e-3)
    # near a structure: the 3x multipath and the doubled HDOP
    near_sd = math.hypot(DP["white_sigma"] * DP["structure_hdop_factor"],
                         DP["multipath_sigma"] * DP["structure_multipath_factor"])
    assert max(sd) == pytest.approx(near_sd, rel=1e-3) and np.sum(np.isclose(sd, near_sd)) >= 30
    # the epochs at the output rate, no direction from a fix, every fix on the track
    assert np.allclose(np.diff(t), 1.0 / dgps.DgpsSimulator.default_sample_rate)
    assert {m.direction for m in run.measurements} == {0}


def test_dgps_outage_under_a_structure_no_fix_and_counted():
    run = dgps_run()
    stats = run.pipe.decoder.stats
    traj = run.trajectory
    t, data = raw(run)
    ant = np.interp(t, traj.t, traj.position) - DP["antenna_offset"]
    for start, end in ((2000.0, 2100.0), (3000.0, 3300.0)):
        under = (ant >= start) & (ant <= end)
        assert under.sum() > 40 and np.all(data[under, 2] == 0) and np.allclose(data[under, 4], dgps.NO_FIX_HDOP)
        t_out = float(np.interp(end, ant, t))      # the sky is back: the receiver reacquires
        fixes = [m.stamp for m in run.measurements if m.stamp > t_out]
        assert fixes[0] - t_out == pytest.approx(DP["reacquisition_time"], abs=0.15)
        stamps = np.array([m.stamp for m in run.measurements])
        t_in = float(np.interp(start, ant, t))
        assert not np.any((stamps >= t_in) & (stamps < t_out + DP["reacquisition_time"] - 0.15))
    # two outages, their epochs all counted: under the structures plus the reacquisition
    rate = dgps.DgpsSimulator.default_sample_rate
    expected = (100.0 + 300.0) / 20.0 * rate + 2 * DP["reacquisition_time"] * rate
    assert stats["outages"] == 2 and abs(stats["no_fix"] - expected) <= 4
    assert stats["fixes"] == len(run.measurements) == stats["epochs"] - stats["no_fix"]


def test_dgps_multipath_is_a_bounded_correlated_bias_larger_near_structures_and_modelled():
    # without receiver noise the solution's error is the multipath alone
    run = simulate_and_decode(DGPS, scenario(duration=160.0), params={"white_sigma": 0.0})
    traj = run.trajectory
    t, data = raw(run)
    good = data[:, 2] == 2
    ant = np.interp(t, traj.t, traj.position)[good] - DP["antenna_offset"]
    x, y = run.pipe.track.xy(ant)
    ex, ey = data[good, 0] - x, data[good, 1] - y
    _, near = dgps.sky_zone(dgps.structures(run.pipe.track), ant, DP["structure_reach"])
    local = DP["multipath_sigma"] * np.where(near, DP["structure_multipath_factor"], 1.0)
    bound = DP["multipath_bound"] * local + 0.002
    assert np.all(np.abs(ex) <= bound) and np.all(np.abs(ey) <= bound)   # bounded by its envelope
    assert near.sum() >= 30          # approaching the two structures (leaving them: reacquiring)
    ratio = np.sqrt(np.mean(ex[near] ** 2 + ey[near] ** 2) / np.mean(ex[~near] ** 2 + ey[~near] ** 2))
    assert 1.5 < ratio < 6.0                                             # ~3x near the structures
    err, sd, stamps = errors(run)
    step = np.diff(stamps) < 0.15
    corr = np.corrcoef(err[:-1][step], err[1:][step])[0, 1]
    # Gauss-Markov over 2 m and 0.1 s between epochs: exp(-2/50 - 0.1/60) = 0.96
    assert corr > 0.85
    assert np.all(np.abs(err) <= DP["multipath_bound"] * sd + 0.01)   # the bound, in the reported stddev
    # the fusion carries it as a correlated fix bias with the same figures
    model = spec(DGPS).errors(DP, run.pipe.track, Vehicle())
    assert (model.fix_bias_sigma, model.fix_bias_length, model.fix_bias_tau) == (
        DP["multipath_sigma"], DP["multipath_length"], DP["multipath_tau"])
    assert model.reported_fix_bias == model.fix_bias_sigma and not model.fix_bias_per_reference
    assert model.fix_white_sigma == pytest.approx(DP["white_sigma"] * DP["structure_hdop_factor"])
    assert {"nlos", "outage"} <= set(model.faults) and math.isinf(model.timeout)
    # near a structure the decoder says more: the 3x multipath
    assert max(sd) == pytest.approx(DP["multipath_sigma"] * DP["structure_multipath_factor"], rel=1e-3)


def test_dgps_autonomous_and_off_track_fixes_are_withheld_and_counted():
    run = simulate_and_decode(DGPS, scenario(duration=30.0), params={"faults": "10-20:nocorr"})
    stats = run.pipe.decoder.stats
    stamps = np.array([m.stamp for m in run.measurements])
    assert stats["autonomous"] == 100 and not np.any((stamps >= 10.0) & (stamps < 20.0))
    # decoded against an alignment laid 10 m to the side: every fix is off the track
    moved = copy.deepcopy(TRACK)
    moved["origin"]["y"] += 10.0 / math.cos(0.3)
    dec = dgps.DgpsDecoder(run.pipe.params, Track.from_dict(moved))
    out = [m for b in run.blocks[:50] for m in dec.decode(b)]
    assert out == [] and dec.stats["off_track"] == 50


def test_a_dgps_fix_where_the_track_crosses_itself_is_withheld_as_ambiguous():
    """A flyover: 400 m east, a 270 degree left turn of R = 50 m, then south across the first
    straight at chainage 350 (the later part there: 685.6 m). Near the crossing a 2-D fix is as
    near both parts; the nearest, or the lower chainage, is 336 m off for the second passage.
    Such fixes are withheld and counted; every fix published is right within its stddev."""
    r = 50.0
    track = {"track_id": "flyover", "length": 400.0 + 1.5 * math.pi * r + 300.0,
             "origin": {"x": 0.0, "y": 0.0, "heading": 0.0},
             "alignment": [{"length": 400.0, "curvature": 0.0}, {"length": 1.5 * math.pi * r, "curvature": 1.0 / r},
                           {"length": 300.0, "curvature": 0.0}]}
    # the antenna (5 m behind the front) passes the crossing twice: front at 355 m and at 690.6 m
    run = simulate_and_decode(DGPS, scenario(v0=15.0, pos=300.0, duration=30.0, track=track))
    stats = run.pipe.decoder.stats
    err, sd, stamps = errors(run)
    assert stats["ambiguous"] > 0
    assert stats["fixes"] + stats["ambiguous"] + stats["off_track"] == stats["epochs"] == 300
    assert np.all(np.abs(err) < 5.0 * sd), np.abs(err).max()
    # withheld on both passages: no fix with the antenna within the gate of the crossing
    traj = run.trajectory
    antenna = np.interp(stamps, traj.t, traj.position) - DP["antenna_offset"]
    gate = DP["lateral_gate"] * math.hypot(DP["white_sigma"], DP["multipath_sigma"])
    assert not np.any(np.abs(antenna - 350.0) < 0.5 * gate) and not np.any(np.abs(antenna - 685.6) < 0.5 * gate)
    passing = [t for t in (355.0, 690.6) if np.interp(t, traj.position, traj.t) < 30.0]
    assert len(passing) == 2


def test_dgps_implausible_blocks_are_rejected_without_a_trace():
    run = dgps_run()
    sc = scenario()
    pipe = SensorPipeline(spec(DGPS), {}, sc.track, sc.vehicle, simulate=False)
    for b in run.blocks[:100]:
        pipe.on_block(b)
    before = pickle.dumps({k: v for k, v in vars(pipe.decoder).items() if k not in ("stats", "_offsets")})
    nxt = run.blocks[100]
    for col, value in ((2, 3.0), (2, 1.5), (3, 2.5), (3, -1.0), (4, 0.0), (4, -1.0), (4, 150.0)):
        data = nxt.data.copy()
        data[0, col] = value
        bad = RawBlock.from_samples(nxt.sensor, nxt.unit_id, nxt.seq, nxt.t0, nxt.sample_rate, nxt.channels,
                                    nxt.units, data)
        with pytest.raises(InputRejected, match="implausible"):
            pipe.decoder.decode(bad)
    assert pickle.dumps({k: v for k, v in vars(pipe.decoder).items() if k not in ("stats", "_offsets")}) == before
    again = SensorPipeline(spec(DGPS), {}, sc.track, sc.vehicle, simulate=False)
    assert [m for b in run.blocks for m in again.on_block(b)] == run.measurements


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_every_decoded_dgps_fix_passes_the_error_model(seed):
    """Randomised runs (2..8 m/s and 20..30 m/s both ways, past the station roof and through the
    tunnel at speed; antenna offset, receiver noise and multipath down to none, structure factors,
    correction outages): the model built from the run's parameters refuses no fix."""
    rng = np.random.default_rng(seed)
    total = 0
    for sign in (1, -1):
        for slow in (True, False):
            speed = sign * (rng.uniform(2.0, 8.0) if slow else rng.uniform(20.0, 30.0))
            params = {"antenna_offset": float(rng.uniform(0.0, 30.0)),
                      "white_sigma": float(rng.choice([0.0, 0.4, 1.0])),
                      "multipath_sigma": float(rng.choice([0.0, 0.3, 1.0])),
                      "structure_multipath_factor": float(rng.uniform(1.0, 5.0)),
                      "structure_hdop_factor": float(rng.uniform(1.0, 2.0)), "faults": "5-8:nocorr"}
            start = (1900.0 if sign > 0 else 2200.0) if slow else (400.0 if sign > 0 else 3900.0)
            duration = 30.0 if slow else 3300.0 / abs(speed)
            sc = scenario(v0=speed, pos=start + params["antenna_offset"], duration=duration, sensors={DGPS: params})
            run = simulate_and_decode(DGPS, dataclasses.replace(sc, seed=seed))
            model = run.pipe.spec.errors(run.pipe.params, run.pipe.track, sc.vehicle)
            assert model.min_stddev == max(params["multipath_sigma"], 1e-3) and model.references is None
            fixes = run.measurements
            assert [model.refusal(f) for f in fixes] == [None] * len(fixes)
            assert len(fixes) >= (60 if slow else 800)
            total += len(fixes)
    assert total > 2000


def test_forged_dgps_fixes_are_refused_below_the_floor():
    model = spec(DGPS).errors(DP, Track.from_dict(TRACK), Vehicle())
    # the decoder's stddev at HDOP -> 0 in the open: the open-sky multipath; no references (the
    # reference id is the receiver's unit id)
    assert model.min_stddev == pytest.approx(DP["multipath_sigma"]) and model.references is None
    honest = PositionFix(10.0, "dgps", "dgps", "utm_test", "dgps", 1000.0,
                         math.hypot(DP["white_sigma"], DP["multipath_sigma"]))
    assert model.refusal(honest) is None
    assert model.refusal(dataclasses.replace(honest, position_stddev=0.5 * model.min_stddev)).reason == "below_model"
    # the fix is not checked against equipment: any id and chainage pass the floor
    assert model.refusal(dataclasses.replace(honest, reference_id="other", position=99999.0)) is None
    # without multipath: the 1 mm resolution of the solution
    assert spec(DGPS).errors({**DP, "multipath_sigma": 0.0}, None, Vehicle()).min_stddev == pytest.approx(1e-3)


# --------------------------------------------------------------------------- transponder tags
def test_tags_every_100_m_and_a_reading_window_that_reads_them_at_utm_speeds():
    track = Track.from_yaml(ROOT / "config" / "track_utm.yaml")
    tags = np.array([it["position"] for it in track.items(transponder.KIND)])
    assert np.allclose(np.diff(tags), transponder.SEED_SPACING) and tags.size == 60   # seed 002: ~100 m
    codes = transponder.tag_codes(track.items(transponder.KIND))
    assert len(set(codes.values())) == tags.size and max(codes.values()) <= transponder.CODE_MAX
    # the window where the tag is powered: k(u_w) = activation level
    u_w = transponder.window_half_length(TP)
    assert float(transponder.coupling(TP, u_w)) == pytest.approx(TP["activation_level"])
    assert 2 * u_w == pytest.approx(0.71, abs=0.01)
    limit = transponder.speed_limit(TP)
    assert 110.0 / 3.6 < limit < 150.0 / 3.6      # above UTM-02's ~110 km/h (assumption)
    assert transponder.read_time(TP) == pytest.approx(0.002 + 2 * 64 / 8000.0)


def _tag_run(v0, pos, duration, **params):
    sensors = {TAGS: params}
    return simulate_and_decode(TAGS, scenario(v0=v0, pos=pos, duration=duration, sensors=sensors))


def _passed(run) -> list[str]:
    """Ids of the tags the antenna passed completely during the run."""
    traj = run.trajectory
    ant = traj.position - TP["antenna_offset"]
    lo, hi = ant.min() + 1.0, ant.max() - 1.0
    return [it["id"] for it in run.pipe.track.items(transponder.KIND) if lo < it["position"] < hi]


@pytest.mark.parametrize("v0", [25.0, -25.0], ids=["forward", "backward"])
def test_every_tag_is_read_in_both_directions_within_its_stddev(v0):
    run = _tag_run(v0, 1000.0, 30.0)
    passed = _passed(run)
    ids = [m.reference_id for m in run.measurements]
    assert len(passed) >= 7 and ids == (passed if v0 > 0 else passed[::-1])
    err, sd, _ = errors(run)
    assert np.all(np.abs(err) <= 4.0 * sd)
    assert np.all(sd >= TP["install_sigma"]) and np.all(sd < TP["install_sigma"] + 0.01)
    assert {m.direction for m in run.measurements} == {0}
    stats = run.pipe.decoder.stats
    assert stats["reads"] == len(passed) and stats["failed_reads"] == 0
    # the raw signal: the tag answers only inside the window, after its boot time
    t, data = raw(run)
    ant = np.interp(t, run.trajectory.t, run.trajectory.position) - TP["antenna_offset"]
    first = run.pipe.track.item(transponder.KIND, passed[0])["position"]
    u = np.abs(ant - first)
    assert data[(u > 0.5) & (u < 10.0), 0].max() < 0.03 < data[u < 0.2, 0].min()
    assert np.count_nonzero(data[:, 1]) == len(passed)


def test_a_tag_is_missed_above_the_readers_speed_limit_and_the_miss_counted():
    limit = transponder.speed_limit(TP)
    fast = _tag_run(1.25 * limit, 500.0, 10.0, coupling_sigma=0.0)
    passed = _passed(fast)
    assert len(passed) >= 5 and fast.measurements == []
    stats = fast.pipe.decoder.stats
    assert stats["answers"] == len(passed) == stats["failed_reads"] and stats["reads"] == 0
    slow = _tag_run(0.9 * limit, 500.0, 10.0, coupling_sigma=0.0)
    assert [m.reference_id for m in slow.measurements] == _passed(slow)


def test_a_stop_over_a_tag_gives_a_fix_when_the_reader_leaves_it():
    # the antenna (3 m behind the front) stops over TG010 at 1050 m: 2 s at 10 m/s (20 m), braking
    # at 1 m/s^2 (50 m; 80 m with the profile's ramps), 10 s standing, then on
    profile = [{"speed": 10.0, "hold": 2.0}, {"speed": 0.0, "decel": 1.0, "hold": 10.0},
               {"speed": 10.0, "accel": 1.0, "hold": 99.0}]
    run = simulate_and_decode(TAGS, scenario(v0=10.0, pos=1053.0 - 80.0, duration=30.0, profile=profile))
    traj = run.trajectory
    stop = traj.position[np.argmin(np.abs(traj.speed))] - TP["antenna_offset"]
    assert abs(stop - 1050.0) < 0.3                       # stood in the window
    fix = next(m for m in run.measurements if m.reference_id == "TG010")
    err, sd, _ = errors(run)
    assert np.all(np.abs(err) <= 4.0 * sd)
    assert fix.position_stddev > 0.3                      # the window's half length, not the timing


def test_tag_decoder_rejects_unknown_codes_and_implausible_blocks_without_a_trace():
    run = _tag_run(20.0, 1000.0, 10.0)
    sc = scenario()
    pipe = SensorPipeline(spec(TAGS), {}, sc.track, sc.vehicle, simulate=False)
    k = next(i for i, b in enumerate(run.blocks) if np.count_nonzero(b.data[:, 1]))
    for b in run.blocks[:k]:
        pipe.on_block(b)
    before = pickle.dumps({k: v for k, v in vars(pipe.decoder).items() if k not in ("stats", "_offsets")})
    nxt = run.blocks[k]

    def variant(col, value):
        data = nxt.data.copy()
        data[3, col] = value
        return RawBlock.from_samples(nxt.sensor, nxt.unit_id, nxt.seq, nxt.t0, nxt.sample_rate, nxt.channels,
                                     nxt.units, data)
    unused = next(c for c in range(1, 100) if c not in pipe.decoder._by_code)
    for (col, value), reason in (((1, float(unused)), "unknown_id"), ((1, 2.5), "implausible"),
                                 ((1, -3.0), "implausible"), ((0, -0.5), "implausible"),
                                 ((0, 5.0), "implausible")):
        with pytest.raises(InputRejected) as exc:
            pipe.decoder.decode(variant(col, value))
        assert exc.value.reason == reason
    assert pickle.dumps({k: v for k, v in vars(pipe.decoder).items() if k not in ("stats", "_offsets")}) == before
    out = [m for b in run.blocks[k:] for m in pipe.on_block(b)]
    assert out == [m for m in run.measurements if m.stamp >= nxt.t0 - 0.05]


def test_a_tags_installation_error_is_drawn_once_and_bounded():
    run = _tag_run(20.0, 1000.0, 2.0, install_sigma=0.2)
    sim = run.pipe.simulator
    nominal = np.array([it["position"] for it in run.pipe.track.items(transponder.KIND)])
    dev = sim._pos - nominal
    assert np.all(np.abs(dev) <= transponder.INSTALL_BOUND * 0.2) and 0.1 < np.std(dev) < 0.3
    model = spec(TAGS).errors(TP, run.pipe.track, Vehicle())
    assert model.measures == "position" and model.faults == ("misread", "offset") and model.fix_bias_sigma == 0.0


def test_the_two_kinds_are_registered_with_the_seed():
    assert {DGPS, TAGS} <= set(NODE_NAMES)
    for node, sensor in ((DGPS, "dgps"), (TAGS, "transponder")):
        s = spec(node)
        assert (s.sensor, s.seeds, s.outputs) == (sensor, ("002",), ("position",))


# --------------------------------------------------------------------------- the UTM scenario
def test_the_utm_scenario_through_the_fusion_keeps_the_truth_inside_the_interval():
    sc = Scenario.from_yaml(ROOT / "config" / "scenario_utm.yaml")
    assert set(sc.sensors) == {"doppler_radar", DGPS, TAGS}     # the sensors seed 002 names for UTM-02
    sc.duration = 215.0     # through the tunnel (3900-4400 m, left at ~210 s): the time budget of this file
    result = simulate_scenario(sc)
    fig = figures(sc, result)
    it = fig["integrity"]
    assert fig["states_with_position"] > 0.99 * fig["states"]
    assert it["inside_fraction"] >= 0.999, it
    assert it["mean_width_m"] < 5.0 and fig["position_error_m"]["rms"] < 1.0
    sensors = {m.sensor for m in result.measurements}
    assert {"dgps", "transponder", "doppler"} <= sensors
    # no DGPS fix while the antenna is under a structure (the tunnel: 500 m)
    truth = np.array([(s.stamp, s.position) for s in result.truth])
    antenna = np.array([np.interp(m.stamp, truth[:, 0], truth[:, 1]) - DP["antenna_offset"]
                        for m in result.measurements if m.sensor == "dgps"])
    assert not np.any((antenna > 3900.0) & (antenna < 4400.0))


# --------------------------------------------------------------------------- transponder: error model
def _tags_passed(run, offset) -> list[str]:
    """Ids of the tags the antenna (``offset`` behind the front) passed completely during the run."""
    ant = run.trajectory.position - offset
    lo, hi = ant.min() + 1.0, ant.max() - 1.0
    return [it["id"] for it in run.pipe.track.items(transponder.KIND) if lo < it["position"] < hi]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_every_decoded_tag_fix_passes_the_error_model(seed):
    """Randomised runs (1..5 m/s and 20..33 m/s both ways, a stop on the way, antenna offset,
    installation error and noise down to none): the model built from the run's parameters refuses
    no fix."""
    rng = np.random.default_rng(seed)
    total = expected = 0
    for sign in (1, -1):
        for kind in ("slow", "fast", "stop"):
            v = sign * (rng.uniform(1.0, 5.0) if kind == "slow" else rng.uniform(20.0, 33.0))
            params = {"antenna_offset": float(rng.uniform(0.0, 30.0)),
                      "install_sigma": float(rng.choice([0.0, 0.01, 0.05])),
                      "noise": float(rng.choice([0.0, 0.005]))}
            profile = None
            duration = 60.0 / abs(v) if kind == "slow" else 2300.0 / abs(v)
            if kind == "stop":
                profile = [{"speed": v, "hold": 2.0}, {"speed": 0.0, "decel": 1.0, "hold": 4.0},
                           {"speed": v, "accel": 1.0, "hold": 99.0}]
                duration = 20.0
            pos = (400.0 if sign > 0 else 3100.0) + params["antenna_offset"] + rng.uniform(0.0, 100.0)
            sc = scenario(v0=v, pos=pos, duration=duration, profile=profile, sensors={TAGS: params})
            sc.seed = seed
            run = simulate_and_decode(TAGS, sc)
            model = run.pipe.spec.errors(run.pipe.params, run.pipe.track, sc.vehicle)
            assert model.min_stddev == max(params["install_sigma"], 1e-3)
            assert [model.refusal(m) for m in run.measurements] == [None] * len(run.measurements)
            passed = _tags_passed(run, params["antenna_offset"])
            st = run.pipe.decoder.stats
            assert {m.reference_id for m in run.measurements} <= set(passed)
            assert len(run.measurements) == len(passed) - st["failed_reads"] - st["implausible"], st
            total += len(run.measurements)
            expected += len(passed)
    assert total >= expected - 3 and total > 50


def test_forged_tag_fixes_are_refused_with_their_reason():
    model = spec(TAGS).errors({**TP, "antenna_offset": 3.0}, Track.from_dict(copy.deepcopy(TRACK)), Vehicle())
    assert model.min_stddev == pytest.approx(TP["install_sigma"])
    assert model.references.windows["TG010"] == (1053.0, 1053.0)          # chainage + antenna offset
    assert len(model.references.windows) == 40                             # TG000 .. TG039, every 100 m
    honest = PositionFix(10.0, "transponder", "transponder", "utm_test", "TG010", 1053.0, TP["install_sigma"])
    assert_forged_fixes_refused(model, honest, "TG999", 1053.0 + 300.0)
    assert spec(TAGS).errors({**TP, "install_sigma": 0.0}, None, Vehicle()).min_stddev == pytest.approx(1e-3)


# --------------------------------------------------------------------------- Doppler radar: error model
DOPPLER = "doppler_radar"
DOPPLER_CASES = {   # name: (initial speed [m/s], duration [s], profile, radar parameters)
    "standstill": (0.0, 12.5, [{"speed": 0.0, "hold": 60.0}], {"min_speed": 0.0}),
    "crawl": (0.05, 12.5, [{"speed": 0.05, "hold": 60.0}], {"min_speed": 0.0}),
    "high_speed": (100.0, 3.0, [{"speed": 100.0, "hold": 60.0}], {}),
    "reversal": (10.0, 12.0, [{"speed": -10.0, "accel": 2.0, "decel": 2.0, "hold": 60.0}], {}),
}


def test_every_decoded_doppler_speed_passes_the_error_model_floor():
    """ErrorModel.min_stddev (the decoder's sigma at v = 0, |bias|, at least 1 cm/s) holds by
    construction: random seeds and biases, blocks of 10 ms .. 5 s and, every other run, a radar
    without spread, scale error or bias (its sigma 0), at a standstill and a crawl seen by a
    radar without clutter filter (min_speed 0), at 100 m/s and through a reversal; none is
    refused below_model, and the floor is reached (it is the decoder's own)."""
    def decode(case, params, seed):
        v0, duration, profile, _ = case
        sc = scenario(v0=v0, duration=lasting(duration, params), profile=profile, sensors={DOPPLER: params})
        return decoded(DOPPLER, dataclasses.replace(sc, seed=seed))

    def drawn(case, rng):   # the case's radar parameters and a random bias, drawn before the run's seed
        return {**case[3], "bias": float(rng.choice([0.005, 0.02, -0.05]))}

    n, lowest = floor_runs(DOPPLER_CASES, {"spread": 0.0, "scale_sigma": 0.0, "bias": 0.0}, decode, drawn)
    assert min(n.values()) > 10 and sum(n.values()) > 1000, n
    assert lowest == pytest.approx(1.0, abs=1e-9)


def test_a_doppler_speed_claiming_half_the_floor_is_refused_below_model():
    sc = scenario(v0=20.0, duration=1.0, sensors={DOPPLER: {}})
    run = simulate_and_decode(DOPPLER, sc)
    model = spec(DOPPLER).errors(run.pipe.params, sc.track, sc.vehicle)
    assert model.min_stddev == max(0.01, abs(run.pipe.params["bias"]))
    assert_refused_below_half_the_floor(model, run.measurements[5])

"""LZB cable loop receiver against seed 000 section 3.1 (Fig. 12): conductors crossing every
100 m, loops up to 12.7 km, feeder cases serving 300 m either side, the received level
dropping at each crossing, a loop number that makes the count absolute."""
from __future__ import annotations

import copy
import dataclasses
import functools
import math
import pickle

import numpy as np
import pytest

from error_model_checks import assert_forged_fixes_refused
from train_localization.core.measurements import PositionFix
from train_localization.core.pipeline import SensorPipeline, simulate_and_decode
from train_localization.core.scenario import Scenario, Vehicle
from train_localization.core.sensors import NODE_NAMES, lzb, spec
from train_localization.core.signals import InputRejected, RawBlock
from train_localization.core.track import Track, TrackError

NODE = "lzb_receiver"
OFFSET = lzb.PARAMS["antenna_offset"].default
R = lzb.PARAMS["antenna_height"].default
TRACK = {"track_id": "lzb_test", "length": 6000.0, "equipment": {"lzb_loop": [
    {"id": "L01", "position": 0.0, "end": 1000.0},
    {"id": "L02", "number": 7, "start": 1000.0, "end": 3050.0},     # a short last cell: 3000..3050
    {"id": "L03", "position": 3050.0, "end": 6000.0}]}}


def scenario(v0=30.0, pos=880.0, duration=40.0, profile=None, sensors=None) -> Scenario:
    return Scenario.from_dict({
        "name": "lzb", "seed": 1, "duration": duration, "track": copy.deepcopy(TRACK),
        "vehicle": {"type": "conventional", "length": 100.0}, "initial": {"position": pos, "speed": v0},
        "profile": profile or [{"speed": v0, "hold": 300.0}], "sensors": sensors or {NODE: {}}})


@functools.lru_cache(maxsize=None)
def forward_run():
    """30 m/s from 880 m (antenna 877.5 m) for 40 s: onto loop L02 at the joint at 1000 m."""
    return simulate_and_decode(NODE, scenario())


def errors(run):
    """(fix error [m], its stddev [m]) of every fix against the truth at its stamp."""
    traj = run.trajectory
    err = np.array([m.position - np.interp(m.stamp, traj.t, traj.position) for m in run.measurements])
    return err, np.array([m.position_stddev for m in run.measurements])


def antenna_span(run) -> tuple[float, float]:
    traj = run.trajectory
    t_end = run.blocks[-1].t_end
    return float(traj.position[0] - OFFSET), float(np.interp(t_end, traj.t, traj.position) - OFFSET)


# --------------------------------------------------------------------------- loops on the track
def test_loops_cross_every_100_m_are_fed_every_600_m_and_at_most_12_7_km_long():
    loops = lzb.loop_table(Track.from_dict(TRACK), {k: p.default for k, p in lzb.PARAMS.items()})
    l1, l2, l3 = loops
    assert [lp["number"] for lp in loops] == [1, 7, 3]     # default: order along the track
    assert np.allclose(np.diff(l1["crossings"]), 100.0) and l1["crossings"][[0, -1]].tolist() == [0.0, 1000.0]
    assert l2["crossings"][-2:].tolist() == [3000.0, 3050.0]   # the last cell is shorter
    assert l2["feeders"].tolist() == [1300.0, 1900.0, 2500.0, 3050.0]   # 300 m either side, the last at the end
    assert (l1["above"], l2["below"], l2["above"], l3["below"]) == (1, 0, 2, 1)   # joined
    params = {k: p.default for k, p in lzb.PARAMS.items()}

    def table(*entries, length=30000.0):
        return lzb.loop_table(Track.from_dict({"track_id": "T", "length": length,
                                               "equipment": {"lzb_loop": list(entries)}}), params)
    assert len(table({"id": "A", "position": 0.0, "length": 12700.0})[0]["crossings"]) == 128
    with pytest.raises(TrackError, match="12700 m"):
        table({"id": "A", "position": 0.0, "length": 12800.0})
    with pytest.raises(TrackError, match="overlaps"):
        table({"id": "A", "position": 0.0, "end": 2000.0}, {"id": "B", "position": 1900.0, "end": 3000.0})
    with pytest.raises(TrackError, match="more than 300 m from every feeder"):
        table({"id": "A", "position": 0.0, "end": 2000.0, "feeders": [300.0, 1700.0]})
    with pytest.raises(TrackError, match="number"):
        table({"id": "A", "position": 0.0, "end": 500.0, "number": 2}, {"id": "B", "position": 500.0, "end": 900.0})
    with pytest.raises(TrackError, match="has no 'position'"):
        Track.from_dict({"track_id": "T", "length": 100.0, "equipment": {"lzb_loop": [{"id": "A", "end": 50.0}]}})


# --------------------------------------------------------------------------- the raw signal
def test_the_level_drops_and_the_carrier_phase_reverses_at_each_crossing():
    run = forward_run()
    sim = run.pipe.simulator
    data = np.vstack([b.data for b in run.blocks])
    t = np.concatenate([b.times() for b in run.blocks])
    x = np.interp(t, run.trajectory.t, run.trajectory.position) - OFFSET
    level, phase, loop = data[:, 0], data[:, 1], data[:, 2]
    full = np.median(level)
    passed = [b for b, c in zip(sim._B, sim._is_cross) if c and x[0] + 3.0 < b < x[-1] - 3.0]
    assert len(passed) == 12                                               # 900 .. 2000 m
    for b in passed:
        u = x - b
        assert level[np.abs(u) < 0.01].max() < 0.15 * full                 # the drop ...
        assert level[(np.abs(u) > 1.0) & (np.abs(u) < 3.0)].min() > 0.8 * full
        before = np.angle(np.mean(np.exp(1j * phase[(u > -3.0) & (u < -1.0)])))
        after = np.angle(np.mean(np.exp(1j * phase[(u > 1.0) & (u < 3.0)])))
        step = math.degrees((after - before) % (2 * math.pi))
        assert abs(step - 180.0) < 20.0, (b, step)                         # ... and the phase reversal
    mid = (x > 1020.0) & (x < 1080.0)                                      # no change within a cell
    assert np.ptp(np.unwrap(phase[mid])) < math.radians(30.0)                # (the reference's slow drift)
    # the field of the conductor: -c f(u), f(u) = u / sqrt(u^2 + r^2) (Biot-Savart)
    b = passed[5]
    z = sim.field(np.array([b - 10 * R, b - R, b + R, b + 10 * R]), np.full(4, 20.0))
    assert abs(z[1]) / abs(z[0]) == pytest.approx(1.0 / math.sqrt(2.0) / (10 / math.sqrt(101.0)), rel=0.01)
    assert abs(z[2]) / abs(z[3]) == pytest.approx(1.0 / math.sqrt(2.0) / (10 / math.sqrt(101.0)), rel=0.01)
    # the telegrams name the loop under the antenna
    numbers = loop[loop > 0]
    assert set(numbers.tolist()) == {1.0, 7.0}
    assert np.all(x[loop == 1.0] < 1000.5) and np.all(x[loop == 7.0] > 999.5)


# --------------------------------------------------------------------------- counting and fixes
def test_the_crossings_counted_over_a_run_are_its_distance_over_100_m():
    run = forward_run()
    x0, x1 = antenna_span(run)
    assert (x0, x1) == pytest.approx((877.5, 2077.5), abs=0.1)    # both mid-cell
    assert run.pipe.decoder.stats["crossings"] == round((x1 - x0) / 100.0) == 12


def test_the_loop_number_makes_the_count_an_absolute_position_within_the_published_stddev():
    run = forward_run()
    fixes = run.measurements
    stats = run.pipe.decoder.stats
    # 900 m and the joint at 1000 m are seen before a telegram of L02: the count starts at the joint,
    # whose fix is published once the telegram confirmed it
    assert stats["anchors"] == 1 and stats["withheld_uncounted"] == 2
    assert [m.position - OFFSET for m in fixes] == pytest.approx([1000.0 + 100.0 * k for k in range(11)])
    assert {m.reference_id for m in fixes} == {"L02"} and {m.direction for m in fixes} == {1}
    err, sd = errors(run)
    assert np.all(np.abs(err) <= 4.0 * sd), err / sd
    # the stddev: installation and survey of the crossing (the timing adds millimetres)
    floor = math.hypot(lzb.PARAMS["crossing_sigma"].default, lzb.PARAMS["survey_sigma"].default)
    assert np.all(sd >= floor) and np.all(sd[1:] < floor + 0.005) and sd[0] > sd[1]   # the joint: two surveys
    assert np.sqrt(np.mean((err / sd) ** 2)) < 2.0


def test_running_backwards_the_count_is_gained_at_a_joint_and_counts_down():
    run = simulate_and_decode(NODE, scenario(v0=-40.0, pos=3500.0, duration=30.0))
    fixes = run.measurements
    assert fixes and {m.direction for m in fixes} == {-1}
    assert fixes[0].position - OFFSET == pytest.approx(3050.0) and fixes[0].reference_id == "L02"
    assert [m.position - OFFSET for m in fixes[1:4]] == pytest.approx([3000.0, 2900.0, 2800.0])
    err, sd = errors(run)
    assert np.all(np.abs(err) <= 4.0 * sd)


def test_decoding_the_simulated_raw_blocks_again_gives_the_same_fixes():
    run = forward_run()
    sc = scenario()
    pipe = SensorPipeline(spec(NODE), {}, sc.track, sc.vehicle, simulate=False)
    again = [m for b in run.blocks for m in pipe.on_block(b)]
    assert again == run.measurements and pipe.decoder.stats == run.pipe.decoder.stats


# --------------------------------------------------------------------------- faults: withheld, not wrong
def test_a_missed_crossing_is_counted_but_its_fix_withheld():
    run = simulate_and_decode(NODE, scenario(), params={"faults": "1697.5-1702.5:blank"})
    stats = run.pipe.decoder.stats
    assert stats["withheld_doubtful"] == 1 and stats["dropouts"] == 1 and stats["lost_dropout"] == 0
    positions = [m.position - OFFSET for m in run.measurements]
    assert 1700.0 not in [round(p) for p in positions]
    assert positions == pytest.approx([1000.0 + 100.0 * k for k in range(11) if k != 7])  # the count went on
    err, sd = errors(run)
    assert np.all(np.abs(err) <= 4.0 * sd)


def test_a_long_dropout_or_a_feeder_outage_loses_the_count_until_the_next_joint():
    # 250 m without carrier (a cable interruption): two crossings could have passed unseen
    run = simulate_and_decode(NODE, scenario(v0=40.0, duration=70.0), params={"faults": "1550-1800:blank"})
    stats = run.pipe.decoder.stats
    positions = [round(m.position - OFFSET) for m in run.measurements]
    assert stats["lost_dropout"] == 1 and stats["anchors"] == 2
    assert max(p for p in positions if p < 3050) == 1500 and min(p for p in positions if p > 1500) == 3050
    err, sd = errors(run)
    assert np.all(np.abs(err) <= 4.0 * sd)
    # feeder case L02/F1 (1900 m) off: its cable sections 1600..2200 m fall silent (300 m either side)
    run = simulate_and_decode(NODE, scenario(v0=40.0, duration=70.0), params={"faults": "L02/F1@0-100:off"})
    stats = run.pipe.decoder.stats
    data = np.vstack([b.data for b in run.blocks])
    x = np.interp(np.concatenate([b.times() for b in run.blocks]), run.trajectory.t, run.trajectory.position) - OFFSET
    assert data[(x > 1610.0) & (x < 2190.0), 0].max() < 0.1 < data[(x > 2210.0) & (x < 2290.0), 0].min()
    positions = [round(m.position - OFFSET) for m in run.measurements]
    assert stats["lost_dropout"] == 1
    assert max(p for p in positions if p < 3050) == 1500 and min(p for p in positions if p > 1500) == 3050
    err, sd = errors(run)
    assert np.all(np.abs(err) <= 4.0 * sd)


def test_a_stop_and_reversal_loses_the_count_and_gives_no_wrong_fix():
    """Stopped and turned back within a cell, the train passes the same crossing again, which
    looks like the next one: the decoder cannot rule it out from the speeds and drops the count."""
    profile = [{"speed": 20.0, "hold": 15.0}, {"speed": 0.0, "decel": 1.0, "hold": 5.0}, {"speed": -20.0, "hold": 99.0}]
    run = simulate_and_decode(NODE, scenario(v0=20.0, duration=80.0, profile=profile))
    stats = run.pipe.decoder.stats
    assert stats["lost_stop"] == 1 and stats["anchors"] == 2
    err, sd = errors(run)
    assert np.all(np.abs(err) <= 4.0 * sd)
    back = [m for m in run.measurements if m.direction < 0]
    assert back and back[0].position - OFFSET == pytest.approx(1000.0) and back[0].reference_id == "L01"


def test_a_telegram_that_contradicts_the_count_drops_it():
    """Decoded against a track whose joint L02/L03 lies 100 m further on, the count still says L02
    when the telegrams of L03 come: it is dropped (and taken again from the joint just seen)."""
    run = simulate_and_decode(NODE, scenario(v0=60.0, duration=40.0))
    assert run.pipe.decoder.stats["lost_telegram"] == 0 and run.pipe.decoder.stats["anchors"] == 1
    shifted = copy.deepcopy(TRACK)
    shifted["equipment"]["lzb_loop"][1]["end"] = 3150.0
    shifted["equipment"]["lzb_loop"][2]["position"] = 3150.0
    dec = lzb.LzbDecoder(run.pipe.params, Track.from_dict(shifted))
    for b in run.blocks:
        dec.decode(b)
    assert dec.stats["lost_telegram"] == 1 and dec.stats["anchors"] == 2


def test_implausible_blocks_and_unknown_loops_are_rejected_without_a_trace():
    run = forward_run()
    sc = scenario()
    pipe = SensorPipeline(spec(NODE), {}, sc.track, sc.vehicle, simulate=False)
    for b in run.blocks[:100]:
        pipe.on_block(b)
    before = pickle.dumps({k: v for k, v in vars(pipe.decoder).items() if k not in ("stats", "_offsets")})
    nxt = run.blocks[100]

    def variant(change):
        data = nxt.data.copy()
        change(data)
        return RawBlock.from_samples(nxt.sensor, nxt.unit_id, nxt.seq, nxt.t0, nxt.sample_rate, nxt.channels,
                                     nxt.units, data)
    cases = {"unknown_id": lambda d: d.__setitem__((5, 2), 99.0),
             "implausible": lambda d: d.__setitem__((5, 0), -0.5)}
    for reason, change in cases.items():
        with pytest.raises(InputRejected) as exc:
            pipe.decoder.decode(variant(change))
        assert exc.value.reason == reason
    for change in (lambda d: d.__setitem__((5, 0), 5.0), lambda d: d.__setitem__((5, 1), 4.0),
                   lambda d: d.__setitem__((5, 2), 1.5)):
        with pytest.raises(InputRejected, match="implausible"):
            pipe.decoder.decode(variant(change))
    assert pickle.dumps({k: v for k, v in vars(pipe.decoder).items() if k not in ("stats", "_offsets")}) == before
    assert pipe.on_block(nxt) is not None


# --------------------------------------------------------------------------- registration and error model
def test_the_sensor_is_registered_with_its_own_error_model():
    assert NODE in NODE_NAMES
    s = spec(NODE)
    assert (s.sensor, s.seeds, s.outputs) == ("lzb", ("000",), ("position",))
    params = {k: p.default for k, p in lzb.PARAMS.items()}
    model = s.errors(params, None, Vehicle())
    assert model.measures == "position" and "miscount" in model.faults and math.isinf(model.timeout)
    # a loop's survey error is common to its crossings: one fix bias per loop (reference_id)
    assert model.fix_bias_per_reference and model.fix_bias_sigma == model.reported_fix_bias == 0.05
    assert lzb.MAX_LOOP_LENGTH == 12700.0 and lzb.PARAMS["spacing"].default == 100.0
    assert lzb.PARAMS["feeder_reach"].default == 300.0


# --------------------------------------------------------------------------- error model: floor and references
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_every_decoded_fix_passes_the_error_model(seed):
    """Randomised runs over 2.25 km and two joints (18..30 m/s and 60..83 m/s, both ways; antenna
    offset, crossing spacing, installation and survey errors down to none, receiver noise): the
    model built from the run's parameters refuses no fix, the joints' fixes included."""
    rng = np.random.default_rng(seed)
    total = 0
    for sign in (1, -1):
        for slow in (True, False):
            speed = sign * (rng.uniform(18.0, 30.0) if slow else rng.uniform(60.0, 300 / 3.6))
            params = {"antenna_offset": float(rng.uniform(0.0, 30.0)), "spacing": float(rng.choice([50.0, 100.0])),
                      "crossing_sigma": float(rng.choice([0.0, 0.1])), "survey_sigma": float(rng.choice([0.0, 0.05])),
                      "noise": float(rng.choice([0.0, 0.01, 0.03]))}
            start = (880.0 if sign > 0 else 3170.0) + params["antenna_offset"]
            sc = dataclasses.replace(scenario(v0=speed, pos=start, duration=2250.0 / abs(speed),
                                              sensors={NODE: params}), seed=seed)
            run = simulate_and_decode(NODE, sc)
            model = run.pipe.spec.errors(run.pipe.params, run.pipe.track, sc.vehicle)
            assert model.min_stddev == pytest.approx(max(math.hypot(params["crossing_sigma"],
                                                                    params["survey_sigma"]), 1e-4))
            fixes = run.measurements
            assert [model.refusal(f) for f in fixes] == [None] * len(fixes)
            # forwards onto L02 at 1000 m and L03 at 3050 m; backwards onto L02 at 3050 m and L01 at 1000 m
            assert {f.reference_id for f in fixes} == ({"L02", "L03"} if sign > 0 else {"L01", "L02"})
            assert len(fixes) >= 1800.0 / params["spacing"]
            total += len(fixes)
    assert total > 80


def test_forged_lzb_fixes_are_refused_with_their_reason():
    params = {k: p.default for k, p in lzb.PARAMS.items()}
    model = spec(NODE).errors(params, Track.from_dict(TRACK), Vehicle())
    assert model.min_stddev == pytest.approx(math.hypot(params["crossing_sigma"], params["survey_sigma"]))
    # from the loop's start to its end (its joints), + the antenna offset
    assert model.references.windows["L01"] == pytest.approx((OFFSET, 1000.0 + OFFSET))
    assert model.references.windows["L02"] == pytest.approx((1000.0 + OFFSET, 3050.0 + OFFSET))
    assert set(model.references.windows) == {"L01", "L02", "L03"}
    honest = PositionFix(10.0, "lzb", "lzb", "lzb_test", "L02", 3050.0 + OFFSET, model.min_stddev, 1)
    assert_forged_fixes_refused(model, honest, "L09", 3050.0 + OFFSET + 300.0)
    # without installation and survey errors: the 0.1 mm floor; without a track: no references
    quiet = spec(NODE).errors({**params, "crossing_sigma": 0.0, "survey_sigma": 0.0}, None, Vehicle())
    assert quiet.min_stddev == pytest.approx(1e-4) and quiet.references is None

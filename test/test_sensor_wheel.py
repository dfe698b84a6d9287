"""Wheel pulse generator (seed 002 section 2.2.2): simulator physics and quadrature decoder."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from error_model_checks import assert_refused_below_half_the_floor, decoded, floor_runs, lasting
from train_localization.core.measurements import DistanceIncrement
from train_localization.core.pipeline import run_offline, simulate_and_decode
from train_localization.core.scenario import Scenario
from train_localization.core.sensors import spec
from train_localization.core.sensors.base import resolve_params
from train_localization.core.sensors.wheel import PARAMS, SPEC, WheelDecoder, resolvable_speed
from train_localization.core.signals import InputRejected, RawBlock
from train_localization.core.track import Track

NODE = "wheel_sensor"
D_NOM = 0.92
CLEAN = {"slip_rate": 0.0, "creep_coefficient": 0.0}


def scenario(profile, duration, sensors=None, seed=3, v0=0.0, s0=1000.0, diameter=D_NOM):
    return Scenario.from_dict({
        "name": "wheel_test", "seed": seed, "duration": duration,
        "track": {"track_id": "T1", "length": 60000.0},
        "vehicle": {"type": "conventional", "length": 100.0, "axles": [2.5, 17.5], "wheel_diameter": diameter},
        "initial": {"position": s0, "speed": v0}, "profile": profile,
        "sensors": {NODE: dict(sensors or {})},
    })


def truth_of(scen, ms):
    """True displacement and mean speed over each increment's interval."""
    traj = scen.trajectory()
    stamp = np.array([m.stamp for m in ms])
    dur = np.array([m.duration for m in ms])
    d_true = np.interp(stamp, traj.t, traj.position) - np.interp(stamp - dur, traj.t, traj.position)
    return stamp, dur, d_true, d_true / dur


def arrays(ms):
    return (np.array([m.distance for m in ms]), np.array([m.distance_stddev for m in ms]),
            np.array([m.speed for m in ms]), np.array([m.speed_stddev for m in ms]))


def drive(scen, params=None):
    """Simulate and decode, counting rejected blocks instead of stopping at the first."""
    run = simulate_and_decode(NODE, scen, params, keep_going=True)
    return run.measurements, run.rejected, run.pipe


def block_of(a, b, t0=0.0, seq=0, fs=10_000.0):
    return RawBlock.from_samples("wheel", "wheel", seq, t0, fs, ("A", "B"), ("level", "level"),
                                 np.column_stack([a, b]))


def quad_levels(states):
    """Levels (A, B) of forward-sequence positions 0..3 (00, 10, 11, 01)."""
    table = np.array([[0, 0], [1, 0], [1, 1], [0, 1]])
    return table[np.mod(states, 4)].T


def test_spec_and_registry():
    assert SPEC.node == "wheel_sensor" and SPEC.sensor == "wheel"
    assert spec(NODE) is SPEC
    assert "002" in SPEC.seeds
    for name, p in PARAMS.items():
        assert p.description, name


def test_default_rate_resolves_300_kmh_and_budget():
    p = resolve_params(PARAMS, {})
    fs = SPEC.simulator.default_sample_rate
    assert fs * len(SPEC.simulator.channels) <= 20_000
    v = resolvable_speed(fs, p["pulses_per_revolution"], D_NOM * (1 - p["diameter_tolerance"]),
                         p["phase_tolerance"], p["duty_tolerance"])
    assert v >= 300 / 3.6 >= p["max_speed"] - 0.1


def test_quadrature_decoding_counts_exactly_on_synthetic_block():
    rng = np.random.default_rng(0)
    # random walk of +-1 steps with dwell times: forwards 37, backwards 12, forwards 5
    path = np.concatenate([np.arange(0, 37), np.arange(37, 25, -1), np.arange(25, 31)])
    dwell = rng.integers(1, 6, len(path))
    states = np.repeat(path, dwell)
    a, b = quad_levels(states)
    dec = WheelDecoder(resolve_params(PARAMS, {}), Track("T", 100.0))
    (inc,) = dec.decode(block_of(a, b))
    assert dec.count == path[-1] - path[0] == 30
    edge = math.pi * D_NOM / (4 * PARAMS["pulses_per_revolution"].default)
    # from the first sample (inside state 0) to the last edge, into state 30 going forwards
    # (at 29.5 steps): the increment ends at an edge, not at the block's end
    t_edges = (np.cumsum(dwell)[:-1] - 0.5) / 10_000.0
    assert inc.distance == pytest.approx(29.5 * edge, rel=1e-12)
    assert inc.stamp == pytest.approx(t_edges[-1]) and inc.duration == pytest.approx(t_edges[-1])
    assert dec.stats["illegal_transitions"] == 0
    # the next block continues from that edge: 8 steps back end at the edge into state 22
    # (at 22.5 steps); no distance is lost or counted twice between the blocks
    a2, b2 = quad_levels(np.repeat(np.arange(path[-1], path[-1] - 9, -1), 3))
    (inc2,) = dec.decode(block_of(a2, b2, t0=len(states) / 10_000.0, seq=1))
    assert dec.count == 30 - 8
    assert inc2.distance == pytest.approx(-7 * edge) and inc2.speed < 0
    assert inc2.stamp == pytest.approx((len(states) + 3 * 8 - 0.5) / 10_000.0)
    assert inc2.stamp - inc2.duration == pytest.approx(inc.stamp)
    # a block without an edge: the train is somewhere inside state 22, half a step on
    a3, b3 = quad_levels(np.full(20, 22))
    (inc3,) = dec.decode(block_of(a3, b3, t0=(len(states) + len(a2)) / 10_000.0, seq=2))
    assert inc3.distance == pytest.approx(-0.5 * edge)
    assert inc.distance + inc2.distance + inc3.distance == pytest.approx(22 * edge)


def test_skipped_state_is_counted_as_illegal_in_last_direction():
    states = np.repeat(np.concatenate([np.arange(0, 10), np.arange(11, 20)]), 4)
    a, b = quad_levels(states)
    dec = WheelDecoder(resolve_params(PARAMS, {}), Track("T", 100.0))
    dec.decode(block_of(a, b))
    assert dec.stats["illegal_transitions"] == 1
    assert dec.count == 19


@pytest.mark.parametrize("bad", [0.5, 2.0, -1.0])
def test_levels_other_than_0_1_are_implausible(bad):
    a, b = quad_levels(np.repeat(np.arange(20), 3))
    a = a.astype(float)
    a[7] = bad
    dec = WheelDecoder(resolve_params(PARAMS, {}), Track("T", 100.0))
    with pytest.raises(InputRejected) as exc:
        dec.decode(block_of(a, b))
    assert exc.value.reason == "implausible"


def test_many_skipped_states_are_implausible():
    a, b = quad_levels(np.arange(0, 400, 2))   # every sample jumps two states
    dec = WheelDecoder(resolve_params(PARAMS, {}), Track("T", 100.0))
    with pytest.raises(InputRejected) as exc:
        dec.decode(block_of(a, b))
    assert exc.value.reason == "implausible"


def test_distance_and_speed_vs_truth_at_300_kmh_without_slip():
    err = 0.008   # the wheel is 0.8 % larger than nominal
    v0 = 300 / 3.6
    scen = scenario([{"speed": v0, "hold": 20}], 6.0, {**CLEAN, "diameter_error": err}, v0=v0)
    blocks, ms, pipe = run_offline(NODE, scen)
    assert not pipe.rejected and pipe.decoder.stats["illegal_transitions"] == 0
    assert all(isinstance(m, DistanceIncrement) for m in ms) and len(ms) == len(blocks)
    stamp, dur, d_true, v_true = truth_of(scen, ms)
    d, ds, v, vs = arrays(ms)
    # the nominal diameter is used: distance short by the factor 1/(1+err)
    assert d.sum() / d_true.sum() == pytest.approx(1 / (1 + err), abs=2e-5)
    # with the diameter error removed, only quantisation (+-1 edge) and vibration remain
    edge = math.pi * D_NOM / 240
    resid = d * (1 + err) - d_true
    assert np.abs(resid).max() < 2.5 * edge
    assert abs(np.sum(d * (1 + err)) - d_true.sum()) < 2 * edge   # anti-correlated: total exact to ~1 edge
    # honest stddevs: the diameter tolerance dominates and covers the actual 0.8 %
    z = (d - d_true) / ds
    assert np.abs(z).max() < 3.0
    assert np.abs((v - v_true) / vs).max() < 3.0
    assert np.abs(v * (1 + err) - v_true).max() < 0.01 * v0


def test_both_directions_with_reversal_tracks_truth():
    scen = scenario([{"speed": 12.0, "accel": 1.0, "hold": 3.0}, {"speed": -6.0, "decel": 1.2, "accel": 0.8,
                                                                   "hold": 3.0}, {"speed": 0.0, "hold": 3.0}],
                    55.0, {**CLEAN, "diameter_error": -0.005})
    _, ms, pipe = run_offline(NODE, scen)
    assert not pipe.rejected
    stamp, dur, d_true, v_true = truth_of(scen, ms)
    d, ds, v, vs = arrays(ms)
    moving = np.abs(v_true) > 0.5
    assert np.all(np.sign(d[moving]) == np.sign(v_true[moving]))
    assert np.all(np.sign(v[moving]) == np.sign(v_true[moving]))
    assert (v_true < -5).any() and (v_true > 11).any()
    # cumulative odometer vs truth displacement: within diameter error + 2 edges everywhere
    cum = np.cumsum(d)
    cum_true = np.cumsum(d_true)
    travelled = np.cumsum(np.abs(d_true))
    edge = math.pi * D_NOM / 240
    assert np.all(np.abs(cum * (1 - 0.005) - cum_true) < 2 * edge + 1e-4 * travelled)
    # net displacement ends 12 m/s leg minus 6 m/s leg: distinctly less than the path length
    assert cum[-1] == pytest.approx(cum_true[-1] / (1 - 0.005), abs=2 * edge)
    assert travelled[-1] > 1.5 * abs(cum_true[-1])
    # speed: errors consistent with the reported stddevs
    z = (v - v_true * (1 + 0.005)) / vs
    assert np.mean(np.abs(z) < 3) > 0.99
    # standstill at the end: zero distance and speed, tight stddev
    still = np.abs(v_true) < 1e-3
    assert still.sum() > 20 and np.all(d[still] == 0.0) and np.all(v[still] == 0.0)
    assert vs[still][-1] < 0.05


def test_slip_and_slide_episodes_show_up_as_speed_excess_and_deficit():
    episodes = [6.0, 3.0, 0.15, 27.0, 2.0, -0.12]  # traction slip +15 %, braking slide -12 %
    scen = scenario([{"speed": 20.0, "accel": 1.0, "hold": 6.0}, {"speed": 0.0, "decel": 1.0, "hold": 2.0}],
                    40.0, {**CLEAN, "diameter_error": 0.0, "slip_episodes": episodes})
    _, ms, _ = run_offline(NODE, scen)
    stamp, dur, d_true, v_true = truth_of(scen, ms)
    _, _, v, vs = arrays(ms)
    mid = stamp - dur / 2
    ratio = v / np.where(np.abs(v_true) > 0.1, v_true, np.nan) - 1
    in_slip = (mid > 6.5) & (mid < 8.5)
    in_slide = (mid > 27.5) & (mid < 28.5)
    calm = (np.abs(v_true) > 2) & ~((mid > 5.8) & (mid < 9.2)) & ~((mid > 26.8) & (mid < 29.2))
    assert np.nanmean(ratio[in_slip]) == pytest.approx(0.15, abs=0.01)
    assert np.nanmean(ratio[in_slide]) == pytest.approx(-0.12, abs=0.01)
    assert np.nanmax(np.abs(ratio[calm])) < 0.02
    # the decoder does not know about slip: the excess is far outside its stddevs
    assert np.all(np.abs(v - v_true)[in_slip] > 5 * vs[in_slip])


def test_random_slip_episodes_under_high_acceleration():
    scen = scenario([{"speed": 25.0, "accel": 1.0, "hold": 1.0}, {"speed": 0.0, "decel": 1.0, "hold": 1.0}],
                    55.0, {"slip_rate": 0.3, "creep_coefficient": 0.0, "diameter_error": 0.0}, seed=11)
    _, ms, pipe = run_offline(NODE, scen)
    log = pipe.simulator.slip_log
    assert len(log) >= 3
    traj = scen.trajectory()
    for t0, dur, ratio in log:
        a = np.interp(t0, traj.t, traj.acceleration)
        assert abs(a) >= PARAMS["slip_accel_threshold"].default - 1e-9
        assert np.sign(ratio) == np.sign(a * np.interp(t0, traj.t, traj.speed))  # slip on traction, slide on braking
        assert 0.02 <= abs(ratio) <= 0.2
    stamp, dur, d_true, v_true = truth_of(scen, ms)
    _, _, v, _ = arrays(ms)
    t0, dur_ep, ratio = max(log, key=lambda e: e[1])
    mid = stamp - dur / 2
    sel = (mid > t0 + 0.4) & (mid < t0 + dur_ep - 0.4) & (np.abs(v_true) > 1.0)
    assert sel.sum() >= 5
    assert np.median(v[sel] / v_true[sel] - 1) == pytest.approx(ratio, abs=0.01)


def test_creep_under_traction_and_braking():
    scen = scenario([{"speed": 15.0, "accel": 1.0, "hold": 2.0}, {"speed": 0.0, "decel": 1.0, "hold": 1.0}],
                    40.0, {"slip_rate": 0.0, "creep_coefficient": 0.004, "diameter_error": 0.0})
    _, ms, _ = run_offline(NODE, scen)
    stamp, dur, d_true, v_true = truth_of(scen, ms)
    _, _, v, _ = arrays(ms)
    traj = scen.trajectory()
    a = np.interp(stamp - dur / 2, traj.t, traj.acceleration)
    acc = (a > 0.99) & (v_true > 3)
    brk = (a < -0.99) & (v_true > 3)
    assert np.median(v[acc] / v_true[acc] - 1) == pytest.approx(0.004, abs=0.0015)
    assert np.median(v[brk] / v_true[brk] - 1) == pytest.approx(-0.004, abs=0.0015)


def test_over_speed_blocks_are_rejected_not_miscounted():
    # 540 km/h: far beyond the 10 kHz / 60 ppr resolution (up to ~120 m/s the decoder still
    # counts right by carrying skipped states on in the last direction)
    v0 = 150.0
    scen = scenario([{"speed": v0, "hold": 10}], 2.0, CLEAN, v0=v0)
    ms, rejected, pipe = drive(scen)
    assert rejected and all(reason == "implausible" for _, reason in rejected)
    assert len(rejected) > 0.5 * (len(rejected) + len(ms))
    stamp, dur, d_true, v_true = truth_of(scen, ms) if ms else (None, None, np.zeros(0), None)
    d = np.array([m.distance for m in ms])
    d_sigma = np.array([m.distance_stddev for m in ms])
    assert np.all(np.abs(d - d_true) < 4 * d_sigma + 0.02)


def test_configuration_checks():
    # the pipeline gives the decoder the vehicle's nominal diameter; a different
    # explicit value is a configuration error
    with pytest.raises(ValueError, match="wheel_diameter"):
        run_offline(NODE, scenario([{"speed": 1.0}], 1.0, {"wheel_diameter": 0.92}, diameter=0.86))
    # a smaller wheel turns faster: 10 kHz no longer resolves 300 km/h, but 270 km/h
    with pytest.raises(ValueError, match="max_speed"):
        run_offline(NODE, scenario([{"speed": 1.0}], 0.2, {"wheel_diameter": 0.86}, diameter=0.86))
    run_offline(NODE, scenario([{"speed": 1.0}], 0.2, {"wheel_diameter": 0.86, "max_speed": 75.0}, diameter=0.86))
    with pytest.raises(ValueError, match="max_speed"):
        run_offline(NODE, scenario([{"speed": 1.0}], 1.0, {"sample_rate": 4000.0}))


def test_determinism_same_seed_same_blocks():
    prof = [{"speed": 10.0, "accel": 1.0, "hold": 1.0}, {"speed": 0.0}]
    b1, m1, p1 = run_offline(NODE, scenario(prof, 8.0, {"slip_rate": 0.5}, seed=5))
    b2, m2, p2 = run_offline(NODE, scenario(prof, 8.0, {"slip_rate": 0.5}, seed=5))
    b3, _, p3 = run_offline(NODE, scenario(prof, 8.0, {"slip_rate": 0.5}, seed=6))
    assert len(b1) == len(b2) > 100
    assert all(np.array_equal(x.data, y.data) and x.t0 == y.t0 for x, y in zip(b1, b2))
    assert m1 == m2 and p1.simulator.diameter == p2.simulator.diameter
    assert p3.simulator.diameter != p1.simulator.diameter
    assert any(not np.array_equal(x.data, y.data) for x, y in zip(b1, b3))


def test_lost_block_does_not_corrupt_the_count():
    scen = scenario([{"speed": 10.0, "hold": 10}], 2.0, {**CLEAN, "diameter_error": 0.0}, v0=10.0)
    blocks, _, _ = run_offline(NODE, scen)
    dec = WheelDecoder(resolve_params(PARAMS, CLEAN), scen.track)
    out = []
    for blk in blocks[:10] + blocks[11:]:
        out.extend(dec.decode(blk))
    assert dec.stats["gaps"] == 1
    # after the gap the increment starts at the first sample of the next block (and ends at
    # its last edge)
    after = out[10]
    assert after.stamp - after.duration == pytest.approx(blocks[11].t0)
    assert blocks[11].t0 < after.stamp <= blocks[11].t_end
    assert after.distance == pytest.approx(10.0 * after.duration, abs=0.03)


@pytest.mark.parametrize("poison", ["stamp_ahead", "seq_near_wrap"])
def test_one_bad_block_does_not_blind_the_input(poison):
    """A block stamped 1e6 s ahead (or numbered 2^32 - 1) with valid samples is decoded; the
    device's next blocks then look repeated or back in time: the first RESYNC_BLOCKS - 1 of
    them are refused, then the guard takes the device's sequence again and every later
    block is decoded, with the count still right."""
    import dataclasses
    from train_localization.core.pipeline import SensorPipeline
    from train_localization.core.signals import RESYNC_BLOCKS
    scen = scenario([{"speed": 10.0, "hold": 10}], 3.0, {**CLEAN, "diameter_error": 0.0}, v0=10.0)
    blocks, _, _ = run_offline(NODE, scen)
    pipe = SensorPipeline(spec(NODE), {**CLEAN, "diameter_error": 0.0}, scen.track, scen.vehicle, simulate=False)
    for b in blocks[:20]:
        pipe.on_block(b)
    bad = dataclasses.replace(blocks[20], t0=blocks[20].t0 + 1e6) if poison == "stamp_ahead" else \
        dataclasses.replace(blocks[20], seq=2 ** 32 - 1)
    pipe.on_block(bad)
    refused = 0
    for b in blocks[21:]:
        try:
            pipe.on_block(b)
        except InputRejected as exc:
            assert exc.reason in ("stamp_back", "duplicate")
            refused += 1
    assert refused == RESYNC_BLOCKS - 1 and pipe.guard.resyncs == 1
    assert pipe.accepted == len(blocks) - refused


def test_absurd_sample_rates_and_huge_blocks_are_refused():
    """A sample rate of 1e-300 Hz (a block spanning ages: it overflowed the decoders) or a
    block of 10^7 samples is rejected before any decoding."""
    for rate in (1e-300, 1e12):
        with pytest.raises(InputRejected) as exc:
            RawBlock.from_samples("wheel", "wheel", 0, 0.0, rate, ("A", "B"), ("level", "level"), np.zeros((10, 2)))
        assert exc.value.reason == "sample_rate"
    with pytest.raises(InputRejected) as exc:
        RawBlock.from_samples("wheel", "wheel", 0, 0.0, 1e4, ("A", "B"), ("level", "level"), np.zeros((5_000_000, 2)))
    assert exc.value.reason == "too_large"


def test_a_resync_block_the_decoder_refuses_does_not_use_the_resync_up():
    """After a poison block (seq 2^32 - 1, accepted), the third refused block that continues the
    device's sequence passes the guard; if the decoder then refuses it (levels other than 0/1),
    the next block that continues the sequence passes too, instead of the input staying blind."""
    import dataclasses
    from train_localization.core.pipeline import SensorPipeline
    from train_localization.core.signals import RESYNC_BLOCKS
    scen = scenario([{"speed": 10.0, "hold": 10}], 3.0, {**CLEAN, "diameter_error": 0.0}, v0=10.0)
    blocks, _, _ = run_offline(NODE, scen)
    pipe = SensorPipeline(spec(NODE), {**CLEAN, "diameter_error": 0.0}, scen.track, scen.vehicle, simulate=False)
    for b in blocks[:20]:
        pipe.on_block(b)
    pipe.on_block(dataclasses.replace(blocks[20], seq=2 ** 32 - 1))
    reasons = []
    for k, b in enumerate(blocks[21:30]):
        if k == RESYNC_BLOCKS - 1:   # the block that completes the resync: undecodable
            b = dataclasses.replace(b, data=np.full_like(b.data, 0.5))
        try:
            pipe.on_block(b)
            reasons.append("ok")
        except InputRejected as exc:
            reasons.append(exc.reason)
    assert reasons == ["duplicate"] * (RESYNC_BLOCKS - 1) + ["implausible"] + ["ok"] * (9 - RESYNC_BLOCKS)
    assert pipe.guard.resyncs == 1


def test_blocks_of_another_unit_are_refused():
    """One pipeline decodes one device: the same block under another unit_id (it was decoded a
    second time, and the guard kept one reference per unit_id it saw) is refused."""
    import dataclasses
    from train_localization.core.pipeline import SensorPipeline
    scen = scenario([{"speed": 10.0, "hold": 10}], 1.0, CLEAN, v0=10.0)
    blocks, _, _ = run_offline(NODE, scen)
    pipe = SensorPipeline(spec(NODE), CLEAN, scen.track, scen.vehicle, simulate=False)
    pipe.on_block(blocks[0])
    with pytest.raises(InputRejected) as exc:
        pipe.on_block(dataclasses.replace(blocks[0], unit_id="wheel_2"))
    assert exc.value.reason == "unit_id" and list(pipe.guard._last) == [blocks[0].unit_id]
    assert len(pipe.on_block(blocks[1])) == 1


# --------------------------------------------------------------------------- error-model floor
FLOOR_CASES = {   # name: (profile, initial speed [m/s], duration [s])
    "standstill": ([{"speed": 0.0, "hold": 60.0}], 0.0, 25.0),
    "crawl": ([{"speed": 0.02, "hold": 60.0}], 0.02, 25.0),
    "high_speed": ([{"speed": 80.0, "hold": 60.0}], 80.0, 3.0),
    "reversal": ([{"speed": 8.0, "accel": 1.0, "hold": 1.0}, {"speed": -4.0, "decel": 1.0, "accel": 1.0, "hold": 1.0},
                  {"speed": 0.0, "decel": 1.0, "hold": 3.0}], 0.0, 22.0),
}


def test_every_decoded_increment_is_at_or_above_the_error_model_floor():
    """ErrorModel.min_stddev holds by construction: random seeds, blocks of 10 ms .. 5 s and, in
    every other run, an ideal disc (no edge scatter: an increment between two edges, or a
    standstill in 5 s blocks, would claim a mean speed below 1 mm/s), at a standstill, a crawl,
    80 m/s and through a reversal; none is refused below_model, and the floor is reached (it is
    the decoder's own)."""
    def decode(case, params, seed):
        profile, v0, duration = case
        return decoded(NODE, scenario(profile, lasting(duration, params), params, seed=seed, v0=v0))

    ideal = {"vibration": 0.0, "phase_tolerance": 0.0, "duty_tolerance": 0.0}
    n, lowest = floor_runs(FLOOR_CASES, ideal, decode, every_run_decodes=True)
    assert sum(n.values()) > 1000
    assert lowest == pytest.approx(1.0, abs=1e-9)


def test_an_increment_claiming_half_the_floor_is_refused_below_model():
    ms, _, model = decoded(NODE, scenario([{"speed": 10.0, "hold": 10.0}], 1.0, CLEAN, v0=10.0))
    assert_refused_below_half_the_floor(model, ms[5])


# --------------------------------------------------------------------------- wheels retracted at speed
def maglev(profile, duration, sensors=None, v0=0.0):
    """scenario() on an MLX-type maglev (its wheels retract at the lift-off speed)."""
    sc = scenario(profile, duration, sensors, v0=v0)
    sc.vehicle = dataclasses.replace(sc.vehicle, kind="maglev", axles=())
    return sc


@pytest.mark.parametrize("kmh, sent", [(149.0, True), (151.0, False)])
def test_a_maglevs_wheels_send_nothing_from_150_kmh(kmh, sent):
    """Seed 002 section 2.2.2: the MLX wheels serve the low-speed stretch (an EDS maglev lifts
    off at speed); a maglev's wheel sensor stops at 150 km/h (retract_speed, the vehicle's
    default): just below it every block is decoded, just above it none; a conventional
    vehicle's wheels and retract_speed 0 (never) run on."""
    v = kmh / 3.6
    ms, rejected, pipe = drive(maglev([{"speed": v, "hold": 10.0}], 2.0, CLEAN, v0=v))
    assert not rejected
    assert len(ms) == (40 if sent else 0)                    # 2 s of 50 ms blocks
    for sc in (scenario([{"speed": v, "hold": 10.0}], 2.0, CLEAN, v0=v),
               maglev([{"speed": v, "hold": 10.0}], 2.0, {**CLEAN, "retract_speed": 0.0}, v0=v)):
        assert len(drive(sc)[0]) == 40
    assert spec(NODE).error_model(resolve_params(PARAMS, {}), None, maglev([], 1.0).vehicle).timeout == math.inf


def test_the_wheels_restart_counting_when_they_are_down_again():
    """Up through 150 km/h and back: the wheel sends nothing while the train runs at 150 km/h or
    more, then restarts its count (one gap) and measures the distance as before."""
    sc = maglev([{"speed": 45.0, "accel": 1.0, "decel": 1.0, "hold": 5.0}, {"speed": 20.0, "decel": 1.0, "hold": 10.0}],
                70.0, CLEAN, v0=30.0)
    ms, rejected, pipe = drive(sc)
    assert not rejected and pipe.decoder.stats["gaps"] == 1
    traj = sc.trajectory()
    stamp, dur, d_true, _ = truth_of(sc, ms)
    speed = np.interp(stamp, traj.t, np.abs(traj.speed))
    assert np.all(speed < 150.0 / 3.6)
    before, after = stamp < 30.0, stamp > 30.0
    assert before.sum() > 100 and after.sum() > 100
    err = np.array([m.distance for m in ms]) - d_true
    assert np.max(np.abs(err[after])) < 0.05

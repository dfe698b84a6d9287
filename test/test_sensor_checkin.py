"""HF check-in / check-out block detection against seed 000 sections 2.2.1 and 3.2 and seed 002
section 2.1.1: a loop per block receives the transmitters at the front and the rear of the
train; a block is occupied from the front's check-in until the rear's check-out; two trains
following each other through the blocks; the boundary fixes against the truth; the failed
rear transmitter and the noise burst; the HSST scenario through the fusion."""
from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import pytest

from conftest import claimed_states
from error_model_checks import assert_forged_fixes_refused
from train_localization.core.measurements import CLEAR, OCCUPIED, PositionFix, SectionOccupancy
from train_localization.core.offline import simulate_scenario
from train_localization.core.pipeline import simulate_and_decode
from train_localization.core.scenario import Scenario, Vehicle
from train_localization.core.sensors import NODE_NAMES, checkin, spec
from train_localization.core.sensors.base import resolve_params
from train_localization.core.signals import InputRejected, RawBlock
from train_localization.core.track import Track, TrackError

NODE = "checkin_loop"
CHECKED_IN, CHECKED_OUT = checkin.CHECKED_IN, checkin.CHECKED_OUT
BLOCK = 100.0
TRACK = {"track_id": "checkin_test", "length": 2000.0,
         "equipment": {"checkin_block": [{"every": BLOCK, "start": 0.0, "end": 700.0, "id": "B{n}",
                                          "length": BLOCK}]}}
DEFAULTS = resolve_params(checkin.PARAMS, {})


def scenario(v0=20.0, pos=50.0, duration=30.0, profile=None, params=None, length=45.0, seed=1) -> Scenario:
    return Scenario.from_dict({
        "name": "checkin", "seed": seed, "duration": duration, "track": dict(TRACK),
        "vehicle": {"type": "maglev_urban", "length": length}, "initial": {"position": pos, "speed": v0},
        "profile": profile or [{"speed": v0, "hold": 300.0}], "sensors": {NODE: params or {}}})


def test_registered_with_seeds_000_002_occupancy_and_a_per_boundary_fix_bias():
    assert NODE in NODE_NAMES
    s = spec(NODE)
    assert s.seeds == ("000", "002") and s.outputs == ("position", "sections")
    model = s.errors(DEFAULTS, Track.from_dict(TRACK), Vehicle(kind="maglev_urban"))
    assert model.measures == "position" and model.fix_bias_per_reference
    assert model.fix_bias_sigma == model.reported_fix_bias == pytest.approx(checkin.fix_bias_sigma(DEFAULTS))
    assert model.fix_bias_sigma > 0.0 and "miscount" in model.faults


def test_loop_coupling_is_one_inside_half_at_a_boundary_and_falls_off_outside():
    blocks = checkin.block_table(Track.from_dict(TRACK), DEFAULTS)
    assert [b["id"] for b in blocks] == [f"B{n}" for n in range(8)]
    assert blocks[0]["below"] == -1 and blocks[0]["above"] == 1 and blocks[-1]["above"] == -1
    x = np.array([50.0, 100.0, 150.0, 120.0])
    nan = np.full(4, np.nan)
    lv = checkin.loop_levels(blocks, {**DEFAULTS, "loop_attenuation": 0.0, "adjust_length": BLOCK}, [x], [nan])
    # front antenna: the check-in carrier of B0 (mid), of B0 and B1 (boundary), of B1; never the check-out
    assert lv[0, 0] == pytest.approx(1.0) and lv[0, 2] < 0.01
    assert lv[1, 0] == pytest.approx(0.5, abs=1e-3) and lv[1, 2] == pytest.approx(0.5, abs=1e-3)
    assert lv[2, 2] == pytest.approx(1.0) and np.all(lv[:, 1::2] == 0.0)
    h = DEFAULTS["antenna_height"]
    # 20 m beyond the end of B0 (100 m long): h / (pi u) of each end, of opposite signs
    assert lv[3, 0] == pytest.approx(h / math.pi * (1.0 / 20.0 - 1.0 / 120.0), rel=5e-3)
    # the onset depth is where the level reaches threshold_on
    u = checkin.onset_depth(0.6, h)
    assert checkin.coupling(np.array(BLOCK + u), BLOCK, 1.0e6, h) == pytest.approx(0.6, abs=1e-6)


# --------------------------------------------------------------------------- two trains, core level
def two_train_states(speed=20.0, fs=200.0, block_samples=10):
    """Train A (150 m, longer than a block) and train B (60 m) at ``speed`` through blocks B0..B7;
    B's front 350 m behind A's. Noise-free loop levels from loop_levels, decoded block by block.
    Returns (times, states (n_blocks_decoded, 8), fronts, lengths)."""
    params = {**DEFAULTS, "max_train_length": 160.0}
    blocks = checkin.block_table(Track.from_dict(TRACK), params)
    n = int(round((1300.0 / speed) * fs / block_samples)) * block_samples
    t = np.arange(n) / fs
    fronts = [-10.0 + speed * t, -360.0 + speed * t]
    lengths = [150.0, 60.0]
    levels = checkin.loop_levels(blocks, params, fronts, [f - L for f, L in zip(fronts, lengths)])
    dec = checkin.CheckinDecoder(params, Track.from_dict(TRACK))
    names, units = checkin.channel_layout(blocks)
    states, stamps = [], []
    for k in range(0, n, block_samples):
        dec.decode(RawBlock.from_samples("checkin", "checkin", k // block_samples, t[k], fs, names, units,
                                         levels[k:k + block_samples]))
        states.append(list(dec.block_states))
        stamps.append(t[k + block_samples - 1])
    return np.array(stamps), np.array(states), [f[block_samples - 1::block_samples] for f in fronts], lengths, dec


@functools.lru_cache(maxsize=None)
def two_trains():
    return two_train_states()


def test_two_trains_give_the_exact_state_sequence_in_every_block():
    """A (longer than a block): its front checks in (CHECKED_IN), moves on (the body spans the
    block: OCCUPIED), its rear arrives (CHECKED_OUT) and checks out (CLEAR). B (shorter than a
    block): its rear arrives while its front is still in the block (CHECKED_IN stays), the front
    leaves (CHECKED_OUT), the rear checks out (CLEAR)."""
    _, states, _, _, dec = two_trains()
    a = [CLEAR, CHECKED_IN, OCCUPIED, CHECKED_OUT, CLEAR]
    b = [CHECKED_IN, CHECKED_OUT, CLEAR]
    for k in range(8):
        seq = [int(s) for i, s in enumerate(states[:, k]) if i == 0 or s != states[i - 1, k]]
        assert seq == a + b, (k, seq)
    assert dec.checkins == [2] * 8 and dec.checkouts == [2] * 8 and dec.stored == [0] * 8
    assert dec.stats["fixes"] == 2 * 7               # each front handed over at B0/B1 .. B6/B7
    assert dec.stats["integrity_confirmed"] == 2 * 7  # each rear checked out into the next block
    assert dec.stats["checkout_missing"] == 0 and dec.stats["noise_bursts"] == 0


def test_a_block_never_shows_clear_while_a_train_is_in_it():
    """Between the check-in's confirmation (burst_window after the front antenna's onset) and the
    end of the train: every block that any part of either train covers is not CLEAR."""
    t, states, fronts, lengths, _ = two_trains()
    blocks = checkin.block_table(Track.from_dict(TRACK), DEFAULTS)
    latency = 20.0 * DEFAULTS["burst_window"] + checkin.onset_depth(0.6, DEFAULTS["antenna_height"])
    checked = 0
    for front, length in zip(fronts, lengths):
        for k, b in enumerate(blocks):
            inside = (front - latency > b["start"]) & (front - length < b["end"])
            assert np.all(states[inside, k] != CLEAR), b["id"]
            checked += int(inside.sum())
    assert checked > 1000


def test_occupancy_messages_carry_the_stored_check_ins_and_the_counts():
    run = simulate_and_decode(NODE, scenario(duration=12.0))
    occ = [m for m in run.measurements if isinstance(m, SectionOccupancy)]
    assert occ[0].stamp == 0.0 and {s.section_id for s in occ[0].sections if s.state == OCCUPIED} == {"B0"}
    last = {s.section_id: s for s in occ[-1].sections}
    # 45 m train from 50 m at 20 m/s for 12 s: front at 290 m (B2), rear at 245 m (B2)
    assert [sid for sid, s in last.items() if s.state == OCCUPIED] == ["B2"]
    assert last["B2"].axle_count == 1 and last["B1"].axles_in == 1 and last["B1"].axles_out == 1
    assert all(s.state in (CLEAR, OCCUPIED) for m in occ for s in m.sections)


# --------------------------------------------------------------------------- fixes
@functools.lru_cache(maxsize=None)
def fix_run():
    """Accelerating from 2 to 25 m/s, then slowing down: hand-overs at many speeds."""
    profile = [{"speed": 25.0, "accel": 1.0, "hold": 5.0}, {"speed": 2.0, "decel": 1.0, "hold": 40.0}]
    return simulate_and_decode(NODE, scenario(v0=2.0, duration=60.0, profile=profile))


def test_boundary_fixes_are_the_train_front_within_their_stddev():
    run = fix_run()
    fixes = [m for m in run.measurements if isinstance(m, PositionFix)]
    traj = run.trajectory
    end = float(np.interp(60.0, traj.t, traj.position))
    crossed = [b for b in np.arange(BLOCK, 8 * BLOCK, BLOCK) if 50.0 < b < end]
    assert [f.reference_id for f in fixes] == [f"B{int(b // BLOCK) - 1}/B{int(b // BLOCK)}" for b in crossed]
    truth = np.interp([f.stamp for f in fixes], traj.t, traj.position)
    err = np.array([f.position for f in fixes]) - truth
    sd = np.array([f.position_stddev for f in fixes])
    assert np.all(np.abs(err) < 3.0 * sd), (err, sd)
    assert np.all(sd < 0.1) and all(f.direction == 1 for f in fixes)


def test_a_train_running_towards_decreasing_chainage_is_fixed_at_the_far_ends():
    run = simulate_and_decode(NODE, scenario(v0=-15.0, pos=480.0, duration=20.0,
                                             params={"orientation": -1}))
    fixes = [m for m in run.measurements if isinstance(m, PositionFix)]
    truth = np.interp([f.stamp for f in fixes], run.trajectory.t, run.trajectory.position)
    assert [f.reference_id for f in fixes] == ["B3/B4", "B2/B3", "B1/B2"]
    assert np.all(np.abs(np.array([f.position for f in fixes]) - truth) < 0.2)
    assert all(f.direction == -1 for f in fixes)


# --------------------------------------------------------------------------- faults
def test_failed_rear_transmitter_leaves_the_block_occupied_and_is_counted():
    """The rear transmitter fails at 3 s (the rear in B0): B0 and every later block keep their
    check-in (the safe side); each is reported once the front is a train length beyond it."""
    run = simulate_and_decode(NODE, scenario(duration=25.0, params={"faults": "rear@3:tx_failed",
                                                                    "max_train_length": 60.0}))
    dec = run.pipe.decoder
    # front from 50 m to 550 m: checked into B1..B5; B0..B4 held
    assert dec.stored[:5] == [1] * 5 and dec.checkouts[:5] == [0] * 5
    assert [dec.block_states[k] for k in range(4)] == [OCCUPIED] * 4
    assert dec.missing_checkout == ["B0", "B1", "B2", "B3"] and dec.stats["checkout_missing"] == 4
    occ = [m for m in run.measurements if isinstance(m, SectionOccupancy)][-1]
    assert [s.section_id for s in occ.sections if s.state == OCCUPIED] == ["B0", "B1", "B2", "B3", "B4", "B5"]
    # and the fixes go on: the front transmitter works
    assert sum(isinstance(m, PositionFix) for m in run.measurements) == 5


def test_noise_burst_is_occupied_while_it_lasts_gives_no_check_in_and_no_fix():
    """A 1 s burst at 4 s in B5, far ahead of the train (front 130 m .. 150 m meanwhile)."""
    run = simulate_and_decode(NODE, scenario(duration=8.0, params={"faults": "B5@4-5:noise_burst"}))
    dec = run.pipe.decoder
    assert dec.stats["noise_bursts"] == 1 and dec.checkins[5] == 0 and dec.stored[5] == 0
    assert dec.block_states[5] == CLEAR
    occ = [m for m in run.measurements if isinstance(m, SectionOccupancy)]
    b5 = [(m.stamp, m.sections[5].state) for m in occ]
    assert any(s == OCCUPIED and 4.0 < t < 5.3 for t, s in b5)
    assert all(s == CLEAR for t, s in b5 if t < 4.0 or t > 5.5)
    assert [f.reference_id for f in run.measurements if isinstance(f, PositionFix)] == ["B0/B1", "B1/B2"]


def test_malformed_fault_strings_and_block_tables_are_refused():
    for bad in ("rear3:tx_failed", "B9@1:noise_burst", "left@1:tx_failed", "B1@1:flood"):
        with pytest.raises(ValueError):
            checkin.parse_faults(bad, ["B1"])
    overlap = {"track_id": "x", "length": 500.0, "equipment": {"checkin_block": [
        {"id": "A", "start": 0.0, "end": 200.0}, {"id": "B", "start": 150.0, "end": 300.0}]}}
    with pytest.raises(TrackError, match="overlap"):
        checkin.block_table(Track.from_dict(overlap), DEFAULTS)
    with pytest.raises(TrackError, match="no checkin_block"):
        checkin.block_table(Track.from_dict({"track_id": "x", "length": 500.0}), DEFAULTS)


def test_decoder_rejects_malformed_blocks_and_keeps_its_state():
    run = simulate_and_decode(NODE, scenario(duration=6.0))
    good = run.blocks[-1]
    dec = run.pipe.decoder
    before = (list(dec.block_states), list(dec.stored), dec.up.copy(), dict(dec.stats))
    bad_channels = tuple(c.replace("B3", "B9") for c in good.channels)
    cases = [(RawBlock(good.sensor, good.unit_id, good.seq + 1, good.t_end, good.sample_rate, bad_channels,
                       good.units, good.data), "unknown_id"),
             (RawBlock(good.sensor, good.unit_id, good.seq + 1, good.t_end, good.sample_rate, good.channels[:-2],
                       good.units[:-2], good.data[:, :-2]), "channels"),
             (RawBlock(good.sensor, good.unit_id, good.seq + 1, good.t_end, good.sample_rate, good.channels,
                       good.units, good.data + np.float32(10.0)), "implausible")]
    for block, reason in cases:
        with pytest.raises(InputRejected) as exc:
            dec.decode(block)
        assert exc.value.reason == reason
    assert (list(dec.block_states), list(dec.stored), dict(dec.stats)) == (before[0], before[1], before[3])
    assert np.array_equal(dec.up, before[2])


# --------------------------------------------------------------------------- the scenario
def test_hsst_scenario_through_the_fusion_keeps_the_truth_inside_its_interval():
    """config/scenario_hsst.yaml, its first 50 s: start, the first two boundaries."""
    sc = Scenario.from_yaml("config/scenario_hsst.yaml")
    assert set(sc.sensors) == {"pattern_belt", NODE}
    sc.duration = 50.0
    result = simulate_scenario(sc)
    est, inside, _ = claimed_states(result, sc.trajectory())
    assert inside == 1.0 and len(est) > 0.5 * sc.duration * 200
    accepted = result.runner.filter.counters()["accepted"]
    assert accepted.get("checkin", 0) >= 2 and accepted.get("pattern_belt", 0) > 100, accepted


# --------------------------------------------------------------------------- error model
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_every_decoded_boundary_fix_passes_the_error_model(seed):
    """Randomised runs (2..5 m/s and 15..30 m/s both ways, the orientation of the run, front
    antenna offset, installation, gain, height and offset errors down to none): the model built
    from the run's parameters refuses no fix."""
    rng = np.random.default_rng(seed)
    total = expected = 0
    for o in (1, -1):
        for slow in (True, False):
            v = o * (rng.uniform(2.0, 5.0) if slow else rng.uniform(15.0, 30.0))
            zero = bool(rng.integers(2))
            params = {"orientation": o, "front_antenna_offset": float(rng.uniform(0.0, 20.0)),
                      **({"boundary_sigma": 0.0, "adjust_sigma": 0.0, "height_sigma": 0.0, "offset_sigma": 0.0}
                         if zero else {})}
            antenna = rng.uniform(20.0, 80.0) if o > 0 else 700.0 - rng.uniform(20.0, 80.0)
            run_to = antenna + o * (130.0 if slow else 560.0)
            sc = scenario(v0=v, pos=antenna + o * params["front_antenna_offset"],
                          duration=abs(run_to - antenna) / abs(v), params=params, seed=seed)
            run = simulate_and_decode(NODE, sc)
            model = run.pipe.spec.errors(run.pipe.params, run.pipe.track, sc.vehicle)
            fixes = [m for m in run.measurements if isinstance(m, PositionFix)]
            assert [model.refusal(f) for f in fixes] == [None] * len(fixes)
            if zero:
                assert model.min_stddev == pytest.approx(1e-3)
            depth = checkin.onset_depth(DEFAULTS["threshold_on"], DEFAULTS["antenna_height"])
            lo, hi = sorted((antenna, run_to))
            crossed = [b for b in np.arange(BLOCK, 8 * BLOCK, BLOCK) if lo < b - depth - 1.0 and b + depth + 1.0 < hi]
            names = [f"B{int(b // BLOCK) - 1}/B{int(b // BLOCK)}" for b in crossed][::o]
            assert [f.reference_id for f in fixes] == names
            total += len(fixes)
            expected += len(names)
    assert total == expected >= 12


def test_forged_boundary_fixes_are_refused_with_their_reason():
    track = Track.from_dict(TRACK)
    reach = checkin.onset_depth(DEFAULTS["threshold_on"], DEFAULTS["antenna_height"]) + 5.0
    model = spec(NODE).errors({**DEFAULTS, "front_antenna_offset": 5.0}, track, Vehicle(kind="maglev_urban"))
    floor = math.sqrt(checkin.fix_bias_sigma(DEFAULTS) ** 2 + checkin.depth_sigma(DEFAULTS) ** 2
                      + DEFAULTS["offset_sigma"] ** 2)
    assert model.min_stddev == pytest.approx(floor)
    # the block's extent moved by the reach of a fix beyond the boundary, in the running direction
    assert model.references.windows["B2"] == pytest.approx((200.0 + reach, 300.0 + reach))
    assert model.references.separator == "/" and len(model.references.windows) == 8      # B0..B7
    backwards = spec(NODE).errors({**DEFAULTS, "front_antenna_offset": 5.0, "orientation": -1}, track, None)
    assert backwards.references.windows["B2"] == pytest.approx((200.0 - reach, 300.0 - reach))
    honest = PositionFix(10.0, "checkin", "checkin", "checkin_test", "B2/B3", 300.0 + reach, floor, 1)
    assert backwards.refusal(dataclasses.replace(honest, position=300.0 - reach, direction=-1)) is None
    assert_forged_fixes_refused(model, honest, "B2/B9", 300.0 + reach + 300.0)
    assert model.refusal(dataclasses.replace(honest, reference_id="B9")).reason == "unknown_reference"
    # a boundary of two real blocks that are no neighbours: the fix lies outside one of them
    assert model.refusal(dataclasses.replace(honest, reference_id="B2/B5")).reason == "reference_mismatch"

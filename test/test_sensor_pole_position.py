"""M-Bahn pole-position transmitter against seed 000 section 2.1.3 (Fig. 7): the on-board
transmitter's signal induced in the long stator's phases marks the magnets' pole position; its
envelope's period follows the pole pitch (2 tau per electrical period), the motor control
derives the speed and the distance from it, at any speed and at a standstill; the M-Bahn
scenario through the fusion with the truth inside its interval."""
from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from conftest import claimed_states
from error_model_checks import assert_refused_below_half_the_floor, decoded, floor_runs, lasting
from train_localization.core.measurements import DistanceIncrement
from train_localization.core.offline import simulate_scenario
from train_localization.core.pipeline import SensorPipeline, simulate_and_decode
from train_localization.core.scenario import Scenario, Vehicle
from train_localization.core.sensors import NODE_NAMES, pole_position, spec
from train_localization.core.sensors.base import resolve_params
from train_localization.core.signals import InputRejected, RawBlock
from train_localization.core.track import Track

NODE = "pole_position"
DEFAULTS = resolve_params(pole_position.PARAMS, {})
TAU = DEFAULTS["pole_pitch"]
FC = DEFAULTS["carrier_frequency"]
TRACK = {"track_id": "mbahn_test", "length": 3000.0}


def scenario(v0=10.0, pos=100.0, duration=10.0, profile=None, params=None, seed=1) -> Scenario:
    return Scenario.from_dict({
        "name": "pole", "seed": seed, "duration": duration, "track": dict(TRACK),
        "vehicle": {"type": "maglev_urban", "length": 12.0}, "initial": {"position": pos, "speed": v0},
        "profile": profile or [{"speed": v0, "hold": 300.0}], "sensors": {NODE: params or {}}})


@functools.lru_cache(maxsize=None)
def run_at(v: float, duration: float = 6.0):
    return simulate_and_decode(NODE, scenario(v0=v, duration=duration))


def increments(run):
    return [m for m in run.measurements if isinstance(m, DistanceIncrement)]


def errors(run):
    """(distance error [m], its stddev, speed error vs the increment's mean speed [m/s], its stddev)."""
    ms = increments(run)
    traj = run.trajectory
    t1 = np.array([m.stamp for m in ms])
    t0 = t1 - np.array([m.duration for m in ms])
    true = np.interp(t1, traj.t, traj.position) - np.interp(t0, traj.t, traj.position)
    return (np.array([m.distance for m in ms]) - true, np.array([m.distance_stddev for m in ms]),
            np.array([m.speed for m in ms]) - true / (t1 - t0), np.array([m.speed_stddev for m in ms]))


def test_registered_with_seed_000_and_a_scale_error_model():
    assert NODE in NODE_NAMES
    s = spec(NODE)
    assert s.seeds == ("000",) and s.outputs == ("distance",)
    model = s.errors(DEFAULTS, Track.from_dict(TRACK), Vehicle(kind="maglev_urban"))
    assert model.measures == "distance" and not model.faults      # contactless: no slip
    assert model.scale_sigma == model.reported_scale == DEFAULTS["pitch_scale_sigma"] > 0.0
    assert math.isfinite(model.timeout)                             # no silence at a standstill


def envelope(blocks, phase: int) -> tuple[np.ndarray, np.ndarray]:
    """(time [s], |carrier amplitude| [V]) of one phase per carrier period (synchronous
    demodulation at the nominal carrier over one period: 4 samples at 20 kHz)."""
    t = np.concatenate([b.times() for b in blocks])
    u = np.concatenate([b.data[:, phase] for b in blocks]).astype(float)
    m = int(round(blocks[0].sample_rate / FC))
    n = (t.size // m) * m
    c = (u[:n] * np.exp(-2j * math.pi * FC * t[:n])).reshape(-1, m).sum(axis=1) * 2.0 / m
    return t[:n].reshape(-1, m).mean(axis=1), np.abs(c)


def test_induced_signal_envelope_has_the_period_of_the_pole_pitch():
    """At 10 m/s the envelope of each phase, A |cos(pi x / tau - 2 pi k / 3)|, has its zeros
    every tau / v (an electrical period 2 tau / v: f = v / (2 tau) = 50 Hz); V's zeros follow U's
    by 2 tau / 3 of travel (the phase sequence U -> V -> W forwards)."""
    run = run_at(10.0)
    zeros = []
    for phase in (0, 1):
        t, env = envelope(run.blocks, phase)
        mins = [i for i in range(1, env.size - 1) if env[i] < 0.15 and env[i] <= env[i - 1] and env[i] <= env[i + 1]]
        zeros.append(t[mins])
        spacing = np.diff(t[mins])
        assert np.median(spacing) == pytest.approx(TAU / 10.0, rel=0.01)
        assert env.max() == pytest.approx(DEFAULTS["amplitude"] * (1.0 + DEFAULTS["harmonic5"]), rel=0.08)
    lag = zeros[1][:, None] - zeros[0][None, :]
    lag = np.min(np.where(lag > 0, lag, np.inf), axis=1)
    assert np.median(lag) == pytest.approx(2.0 * TAU / 3.0 / 10.0, abs=3e-4)


def test_signal_is_there_at_a_standstill_with_the_same_amplitude():
    """The carrier's induction needs no motion (unlike the magnets' back-EMF)."""
    still = run_at(0.0)
    _, env0 = envelope(still.blocks, 0)
    x = 100.0 - DEFAULTS["transmitter_offset"]
    expected = abs(pole_position.coupling(np.array([math.pi * x / TAU]), DEFAULTS["harmonic5"])[0, 0])
    assert np.median(env0) == pytest.approx(expected * DEFAULTS["amplitude"], abs=0.02)
    d_err, d_sd, v_err, v_sd = errors(still)
    assert len(d_err) > 100 and np.all(np.abs(d_err) < 4.0 * d_sd) and np.all(np.abs(v_err) < 4.0 * v_sd)


@pytest.mark.parametrize("v", [-15.0, 0.5, 10.0, 22.2])
def test_distance_increments_and_speed_within_their_stddev_both_ways(v):
    run = run_at(v)
    ms = increments(run)
    assert len(ms) > 100 and all(np.sign(m.distance) == np.sign(v) for m in ms)
    for err, sd, what in (errors(run)[:2] + ("distance",), errors(run)[2:] + ("speed",)):
        z = err / sd
        assert np.sqrt(np.mean(z ** 2)) < 1.5 and np.abs(z).max() < 4.5, (what, z)
    # summed over the run: the pitch's scale error only (drawn per stator: 1e-4 1-sigma)
    total = sum(m.distance for m in ms)
    true = sum(m.distance for m in ms) - errors(run)[0].sum()
    assert abs(total - true) < 4.0 * DEFAULTS["pitch_scale_sigma"] * abs(true) + 0.005


def test_position_within_the_pole_pair_follows_the_magnets_up_to_the_polarity():
    """pole_position is the transmitter's place in the pole pair (0 .. 2 tau) up to the constant
    polarity (tau) that the carrier's unknown phase leaves: decoded minus true, modulo tau, holds
    still while the vehicle runs 30 m."""
    sc = scenario(v0=5.0, duration=6.0)
    s = spec(NODE)
    pipe = SensorPipeline(s, {}, sc.track, sc.vehicle, sc.rng(NODE, s.sensor))
    traj = sc.trajectory()
    offsets = []
    for k in range(int(sc.duration * sc.truth_rate) + 1):
        for block in pipe.on_truth(traj.state_at(k / sc.truth_rate)):
            pipe.on_block(block)
            dec = pipe.decoder
            x = float(np.interp(dec.pole_time, traj.t, traj.position)) - DEFAULTS["transmitter_offset"]
            offsets.append((dec.pole_position - x * pipe.simulator.pitch / TAU) % TAU)
    off = np.unwrap(np.array(offsets) * 2.0 * math.pi / TAU) * TAU / (2.0 * math.pi)
    assert len(off) > 100 and np.ptp(off) < 0.05 * TAU


def test_a_signal_too_weak_for_the_transmitter_is_dropped_and_malformed_blocks_rejected():
    weak = simulate_and_decode(NODE, scenario(duration=1.0, params={"amplitude": 0.1}))
    dec = pole_position.PolePositionDecoder(DEFAULTS, Track.from_dict(TRACK))
    out = [m for b in weak.blocks for m in dec.decode(b)]
    assert out == [] and dec.stats["increments"] == 0 and dec.stats["frames"] > 0
    good_run = run_at(10.0)
    dec = pole_position.PolePositionDecoder(DEFAULTS, Track.from_dict(TRACK))
    for b in good_run.blocks[:5]:
        dec.decode(b)
    before = (dec._angle, dec._phi2, dec._end, dict(dec.stats))
    g = good_run.blocks[5]
    cases = [(g.data + np.float32(0.5), "implausible"),                         # zero sequence
             (np.full_like(g.data, DEFAULTS["voltage_range"]), "implausible")]  # at the range
    for data, reason in cases:
        with pytest.raises(InputRejected) as exc:
            dec.decode(RawBlock(g.sensor, g.unit_id, g.seq, g.t0, g.sample_rate, g.channels, g.units, data))
        assert exc.value.reason == reason
    with pytest.raises(InputRejected, match="channels"):
        dec.decode(RawBlock(g.sensor, g.unit_id, g.seq, g.t0, g.sample_rate, ("w", "v", "u"), g.units, g.data))
    with pytest.raises(InputRejected) as exc:      # 20.1 kHz: no whole frames of carrier periods
        dec.decode(RawBlock(g.sensor, g.unit_id, g.seq, g.t0, 20100.0, g.channels, g.units, g.data))
    assert exc.value.reason == "sample_rate"
    assert (dec._angle, dec._phi2, dec._end, dict(dec.stats)) == before
    assert len(dec.decode(g)) == 1


def test_a_configuration_whose_frames_cannot_be_unwrapped_is_refused():
    with pytest.raises(ValueError, match="unwrapped"):
        pole_position.PolePositionDecoder({**DEFAULTS, "max_speed": 60.0}, Track.from_dict(TRACK))


def test_mbahn_scenario_through_the_fusion_keeps_the_truth_inside_its_interval():
    """config/scenario_mbahn.yaml, its first 60 s: the start, the run to the second station, the stop."""
    sc = Scenario.from_yaml("config/scenario_mbahn.yaml")
    assert set(sc.sensors) == {NODE, "tag_reader"}
    sc.duration = 60.0
    result = simulate_scenario(sc)
    est, inside, err = claimed_states(result, sc.trajectory())
    assert inside == 1.0 and len(est) > 0.5 * sc.duration * 200
    assert np.sqrt(np.mean(err ** 2)) < 0.1
    accepted = result.runner.filter.counters()["accepted"]
    assert accepted.get(NODE, 0) > 1000 and accepted.get("transponder", 0) >= 5, accepted


# --------------------------------------------------------------------------- error-model floor
FLOOR_CASES = {   # name: (initial speed [m/s], duration [s], profile)
    "standstill": (0.0, 12.5, None),
    "crawl": (0.005, 12.5, None),
    "high_speed": (29.0, 3.0, None),
    "reversal": (10.0, 8.0, [{"speed": -10.0, "accel": 4.0, "decel": 4.0, "hold": 60.0}]),
}


def test_every_decoded_increment_is_at_or_above_the_error_model_floor():
    """ErrorModel.min_stddev holds by construction: random seeds, blocks of 10 ms .. 5 s and,
    every other run, a winding without harmonic, noise or scale error (only the 12-bit
    converter's quantisation left: a long increment would claim a mean speed to micrometres per
    second), at a standstill, a crawl, 29 m/s (near max_speed) and through a reversal; none is
    refused below_model, and the floor is reached (it is the decoder's own)."""
    def decode(case, params, seed):
        v0, duration, profile = case
        return decoded(NODE, scenario(v0=v0, duration=lasting(duration, params), profile=profile, params=params,
                                      seed=seed))

    n, lowest = floor_runs(FLOOR_CASES, {"harmonic5": 0.0, "noise": 0.0, "pitch_scale_sigma": 0.0}, decode)
    assert min(n.values()) > 10 and sum(n.values()) > 1000, n
    assert lowest == pytest.approx(1.0, abs=1e-9)


def test_an_increment_claiming_half_the_floor_is_refused_below_model():
    run = run_at(10.0)
    model = spec(NODE).errors(run.pipe.params, Track.from_dict(TRACK), Vehicle(kind="maglev_urban"))
    assert_refused_below_half_the_floor(model, increments(run)[5])

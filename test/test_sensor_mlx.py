"""MLX coil counter and EMF observer against seed 002 section 2.2.2 (Fig. 3): counting the
null-flux coils along the guideway gives distance (count x pitch from a reference) and speed;
the LSM drive's back-EMF measured in the inverter gives the speed from its frequency,
f = v / (2 tau), and the position within a pole pair from its phase, to +-5 deg, at medium and
high speed only; the scenario through the fusion with the truth inside its interval."""
from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from conftest import claimed_states
from error_model_checks import assert_refused_below_half_the_floor, decoded, floor_runs, lasting
from train_localization.core.offline import simulate_scenario
from train_localization.core.pipeline import SensorPipeline, simulate_and_decode
from train_localization.core.scenario import Scenario, Vehicle
from train_localization.core.sensors import NODE_NAMES, coil_counter, emf_observer, spec
from train_localization.core.signals import InputRejected, RawBlock
from train_localization.core.track import Track, TrackError

COIL = "coil_counter"
EMF = "emf_observer"
PITCH = coil_counter.PARAMS["coil_pitch"].default
HEAD = coil_counter.PARAMS["head_offset"].default
TAU = emf_observer.PARAMS["pole_pitch"].default
MAGNET = emf_observer.PARAMS["magnet_offset"].default
MIN_SPEED = emf_observer.PARAMS["min_speed"].default
TRACK = {"track_id": "mlx_test", "length": 6000.0}


def scenario(node, v0=30.0, pos=100.0 + HEAD + PITCH / 8.0, duration=20.0, profile=None, track=None,
             params=None, seed=1) -> Scenario:
    return Scenario.from_dict({
        "name": "mlx", "seed": seed, "duration": duration, "track": track or dict(TRACK),
        "vehicle": {"type": "maglev", "length": 75.0, "axles": []}, "initial": {"position": pos, "speed": v0},
        "profile": profile or [{"speed": v0, "hold": 300.0}], "sensors": {node: params or {}}})


def increment_errors(run, measurements=None, traj=None):
    """(distance error [m], its stddev, speed error against the increment's mean speed [m/s], its
    stddev, truth speed at the stamp) of every increment of an offline run (or of the
    ``measurements`` given, against ``traj``)."""
    ms = run.measurements if measurements is None else measurements
    traj = run.trajectory if traj is None else traj
    t1 = np.array([m.stamp for m in ms])
    t0 = t1 - np.array([m.duration for m in ms])
    true = np.interp(t1, traj.t, traj.position) - np.interp(t0, traj.t, traj.position)
    d = np.array([m.distance for m in ms])
    v = np.array([m.speed for m in ms])
    return (d - true, np.array([m.distance_stddev for m in ms]), v - true / (t1 - t0),
            np.array([m.speed_stddev for m in ms]), np.interp(t1, traj.t, traj.speed))


def within_stddev(err, sd, what):
    z = err / sd
    assert np.sqrt(np.mean(z ** 2)) < 1.5, (what, np.sqrt(np.mean(z ** 2)))
    assert np.abs(z).max() < 4.5, (what, np.abs(z).max())


def test_both_kinds_are_registered_with_seed_002_and_an_error_model():
    for node, measures in ((COIL, "distance"), (EMF, "distance")):
        assert node in NODE_NAMES
        s = spec(node)
        assert s.seeds == ("002",) and s.outputs == ("distance",)
        params = {k: p.default for k, p in s.params.items()}
        model = s.errors(params, Track.from_dict(TRACK), Vehicle(kind="maglev"))
        assert model.measures == measures and not model.faults     # contactless: no slip, no slide
        assert model.scale_sigma == model.reported_scale > 0.0
    assert math.isinf(spec(EMF).errors({k: p.default for k, p in spec(EMF).params.items()}, None, None).timeout)


# --------------------------------------------------------------------------- coil counter
@functools.lru_cache(maxsize=None)
def coil_run():
    """30 m/s for 20 s: head A starts an eighth of a pitch past the first coil of 100 m."""
    return simulate_and_decode(COIL, scenario(COIL))


def switching_points(coils: np.ndarray) -> np.ndarray:
    """Chainages of head A at which a Schmitt output switches (nominal, half duty): A on/off a
    quarter pitch either side of a coil, B (a quarter pitch behind A) on at the coil, off half a
    pitch past it."""
    return np.sort(np.concatenate([coils - PITCH / 4, coils, coils + PITCH / 4, coils + PITCH / 2]))


def test_coil_count_is_exact_and_the_distance_is_count_times_pitch_from_the_reference():
    run = coil_run()
    sim = run.pipe.simulator
    traj = run.trajectory
    dec = spec(COIL).decoder(run.pipe.params, Track.from_dict(TRACK))
    x0 = float(traj.position[0]) - HEAD                       # head A at the first sample: the reference
    sw = switching_points(sim.coils)
    checked = 0
    for block in run.blocks:
        dec.decode(block)
        x = float(np.interp(block.t_end - 1.0 / block.sample_rate, traj.t, traj.position)) - HEAD
        if np.min(np.abs(sw - x)) < 0.02:       # coil tolerance, gain and noise move a switching point by mm
            continue
        checked += 1
        # every switching point passed is one step; four per coil
        assert dec.count == np.count_nonzero((sw > x0) & (sw <= x))
        assert abs(dec.coils_passed - np.count_nonzero((sim.coils > x0) & (sim.coils <= x))) <= 0.75
        # the reference plus count x pitch / 4 is the position, to within a step and the row's pitch error
        assert abs(x0 + dec.count * PITCH / 4 - x) < PITCH / 4 + 3 * 2e-4 * (x - x0)
    assert checked > 0.5 * len(run.blocks) and dec.count > 4 * 1300          # 600 m of 0.45 m coils
    assert dec.stats["illegal_transitions"] == 0
    # the increments add up to the count: from switching point to switching point
    total = sum(m.distance for m in run.measurements)
    assert abs(total - dec.count * PITCH / 4) <= PITCH / 4


def test_coil_counter_increments_and_speed_are_within_their_stddev_against_the_truth():
    run = simulate_and_decode(COIL, scenario(COIL, v0=5.0, pos=500.0, duration=40.0,
                                             profile=[{"speed": 140.0, "accel": 4.0, "jerk": 2.0, "hold": 30.0}]))
    ed, sd, ev, sv, vt = increment_errors(run)
    assert len(run.measurements) == len(run.blocks) and vt.max() > 135.0   # every block up to 500 km/h
    within_stddev(ed, sd, "distance")
    within_stddev(ev, sv, "speed")
    fast = vt > 100.0
    assert np.sqrt(np.mean(ed[fast] ** 2)) < 0.01 and np.sqrt(np.mean(ev[fast] ** 2)) < 0.2


def test_coil_counter_counts_backwards_and_stops_between_coil_rows():
    back = simulate_and_decode(COIL, scenario(COIL, v0=-20.0, pos=800.0, duration=10.0))
    assert back.pipe.decoder.count < 0
    assert all(m.distance < 0 and m.speed < 0 for m in back.measurements[1:])
    # two rows with 50 m without coils between them
    track = {**TRACK, "equipment": {"null_flux_coils": [{"id": "NF01", "position": 0.0, "end": 500.0},
                                                        {"id": "NF02", "position": 550.0, "end": 3000.0}]}}
    run = simulate_and_decode(COIL, scenario(COIL, v0=25.0, pos=400.0, duration=10.0, track=track))
    dec = run.pipe.decoder
    assert dec.stats["no_coil_samples"] > 0
    traj = run.trajectory
    stamps = np.array([m.stamp for m in run.measurements])
    head = np.interp(stamps, traj.t, traj.position) - HEAD
    assert not np.any((head > 500.0 + PITCH) & (head < 550.0 - PITCH))    # nothing to count in the gap
    ed, sd, *_ = increment_errors(run)
    after = head > 560.0
    assert after.sum() > 50 and np.all(np.abs(ed[after] / sd[after]) < 4.5)   # counting again on NF02
    with pytest.raises(TrackError, match="overlap"):
        coil_counter.coil_rows(Track.from_dict({**TRACK, "equipment": {"null_flux_coils": [
            {"id": "A", "position": 0.0, "end": 500.0}, {"id": "B", "position": 400.0, "end": 900.0}]}}), PITCH)


def test_coil_counter_raw_signal_peaks_at_each_coil_and_refuses_an_unresolvable_sample_rate():
    run = coil_run()
    sim = run.pipe.simulator
    u = np.linspace(-PITCH / 2, PITCH / 2, 401)
    c = sim.coils[2000]
    level = sim.output(c + u, np.full(u.shape, coil_counter.PARAMS["gap"].default))
    assert abs(u[np.argmax(level)]) < 0.005 and level.max() == pytest.approx(2.0, rel=0.02)   # peak_voltage
    _, half, valley = coil_counter.levels(PITCH, coil_counter.PARAMS["gap"].default, 2.0)
    assert abs(np.mean(level > half) - 0.5) < 0.02       # high for half a pitch: even quadrature states
    assert valley > coil_counter.PARAMS["loss_threshold"].default
    with pytest.raises(ValueError, match="max_speed"):
        simulate_and_decode(COIL, scenario(COIL, duration=1.0), {"sample_rate": 1000.0})


def test_coil_counter_rejects_malformed_blocks_without_changing_its_count():
    run = coil_run()
    dec = spec(COIL).decoder(run.pipe.params, Track.from_dict(TRACK))
    for b in run.blocks[:5]:
        dec.decode(b)
    count = dec.count
    good = run.blocks[5]
    for data, reason in ((good.data * 0 + 9.0, "implausible"), (good.data - 3.0, "implausible")):
        with pytest.raises(InputRejected) as exc:
            dec.decode(RawBlock(good.sensor, good.unit_id, good.seq, good.t0, good.sample_rate, good.channels,
                                good.units, data.astype(np.float32)))
        assert exc.value.reason == reason
    with pytest.raises(InputRejected, match="channels"):
        dec.decode(RawBlock(good.sensor, good.unit_id, good.seq, good.t0, good.sample_rate, ("b", "a"),
                            good.units, good.data))
    assert dec.count == count


# --------------------------------------------------------------------------- EMF observer
def test_emf_frequency_is_v_over_two_pole_pitches_and_amplitude_grows_with_speed():
    quiet = {"voltage_noise": 0.0, "current_noise": 0.0, "current_per_accel": 0.0, "current_cruise": 0.0,
             "harmonic5": 0.0}
    for v in (30.0, 100.0):
        run = simulate_and_decode(EMF, scenario(EMF, v0=v, duration=2.0), quiet)
        u = np.concatenate([b.channel("u") for b in run.blocks]).astype(float)
        t = np.concatenate([b.times() for b in run.blocks])
        up = np.flatnonzero((u[:-1] < 0) & (u[1:] >= 0))
        t_up = t[up] - u[up] / (u[up + 1] - u[up]) * (t[1] - t[0])
        f = (len(t_up) - 1) / (t_up[-1] - t_up[0])
        assert f == pytest.approx(v / (2 * TAU), rel=2e-3)           # 11.1 Hz and 37.0 Hz
        assert np.abs(u).max() == pytest.approx(emf_observer.PARAMS["emf_constant"].default * v, rel=0.01)


@pytest.mark.parametrize("v", [30.0, 80.0, 135.0, -60.0])
def test_emf_observer_speed_and_position_within_a_pole_pair_against_the_truth(v):
    sc = scenario(EMF, v0=v, pos=3000.0, duration=4.0)
    pipe = SensorPipeline(spec(EMF), {}, sc.track, sc.vehicle, sc.rng(EMF, "emf_observer"))
    traj = sc.trajectory()
    angle_err, ms = [], []
    for k in range(int(sc.duration * sc.truth_rate) + 1):
        for block in pipe.on_truth(traj.state_at(k / sc.truth_rate)):
            out = pipe.on_block(block)
            ms += out
            x = float(np.interp(pipe.decoder.pole_time, traj.t, traj.position)) - MAGNET
            truth = x % (2 * TAU)
            d = (pipe.decoder.pole_position - truth + TAU) % (2 * TAU) - TAU
            angle_err.append(math.degrees(d / TAU * math.pi))
    angle_err = np.array(angle_err[1:])
    assert np.abs(angle_err).max() <= 5.0, np.abs(angle_err).max()   # +-5 deg electrical, seed 002 2.2.2
    ed, sd, ev, sv, _ = increment_errors(None, ms, traj)
    assert len(ms) >= 75 and np.all(np.sign([m.speed for m in ms]) == np.sign(v))
    within_stddev(ed, sd, "distance")
    within_stddev(ev, sv, "speed")
    assert abs(np.mean([m.speed for m in ms]) - v) < 0.02 * abs(v)
    assert np.sqrt(np.mean(ed ** 2)) < 2 * TAU * 5.0 / 360.0     # within the +-5 deg of the seed


def test_emf_observer_is_silent_below_its_minimum_speed_and_cuts_in_above_it():
    # 0 -> 32 m/s and back to 0 at 2 m/s^2
    sc = scenario(EMF, v0=0.0, pos=200.0, duration=40.0,
                  profile=[{"speed": 32.0, "accel": 2.0, "decel": 2.0, "jerk": 2.0, "hold": 3.0},
                           {"speed": 0.0, "hold": 50.0}])
    run = simulate_and_decode(EMF, sc)
    ed, sd, ev, sv, vt = increment_errors(run)
    traj = run.trajectory
    stamps = np.array([m.stamp for m in run.measurements])
    assert vt.min() > 0.9 * MIN_SPEED                          # nothing below the cut-off
    # every block well above the cut-off gives an increment
    blocks_fast = [b for b in run.blocks if np.interp(b.t0, traj.t, traj.speed) > 1.1 * MIN_SPEED]
    assert len(run.measurements) >= len(blocks_fast) - 2
    assert run.pipe.decoder.stats["below_min_speed"] >= 1       # the track is dropped braking through it
    braking = traj.t > 20.0
    t_cut = float(traj.t[braking][np.argmax(traj.speed[braking] < 0.9 * MIN_SPEED)])
    assert stamps.max() < t_cut                                 # silent again once below it
    within_stddev(ed, sd, "distance")
    within_stddev(ev, sv, "speed")
    # the raw signal is still there below it: the decoder judges it, the device does not stop
    slow = [b for b in run.blocks if np.interp(b.t0, traj.t, traj.speed) < 0.5 * MIN_SPEED]
    assert slow and all(np.abs(b.channel("u")).max() > 0 for b in slow)


def test_emf_observer_drops_a_signal_that_is_not_the_trains_emf_and_rejects_malformed_blocks():
    # an EMF half of what the speed of its frequency gives: another section, a wrong constant
    run = simulate_and_decode(EMF, scenario(EMF, v0=60.0, duration=3.0), {"emf_constant": 10.0})
    dec = spec(EMF).decoder({**run.pipe.params, "emf_constant": 20.0}, Track.from_dict(TRACK))
    out = [m for b in run.blocks for m in dec.decode(b)]
    assert not out and dec.stats["increments"] == 0
    good = run.blocks[3]
    data = good.data.astype(float)
    broken = data.copy()
    broken[:, 0] += 2000.0                                      # a phase measurement offset: zero sequence
    beyond = data.copy()
    beyond[5, 4] = 5000.0                                       # a current beyond the range
    for bad in (broken, beyond):
        with pytest.raises(InputRejected) as exc:
            dec.decode(RawBlock(good.sensor, good.unit_id, good.seq, good.t0, good.sample_rate, good.channels,
                                good.units, bad.astype(np.float32)))
        assert exc.value.reason == "implausible"
    with pytest.raises(InputRejected, match="channels"):
        dec.decode(RawBlock(good.sensor, good.unit_id, good.seq, good.t0, good.sample_rate,
                            tuple(reversed(good.channels)), good.units, good.data))


# --------------------------------------------------------------------------- the scenario
def test_mlx_scenario_through_the_fusion_keeps_the_truth_inside_its_interval():
    """config/scenario_mlx.yaml, its first 35 s: from a standstill on the wheels, the EMF observer
    cutting in at 72 km/h (20 s), up to 120 km/h."""
    sc = Scenario.from_yaml("config/scenario_mlx.yaml")
    assert set(sc.sensors) == {"wheel_sensor", "coil_counter", "emf_observer", "mmwave_ranging"}
    sc.duration = 35.0
    result = simulate_scenario(sc)
    est, inside, err = claimed_states(result, sc.trajectory())
    assert len(est) > 0.95 * sc.duration * 200 and inside >= 0.999
    assert np.sqrt(np.mean(err ** 2)) < 0.1
    accepted = result.runner.filter.counters()["accepted"]
    for sensor in ("wheel", "coil_counter", "emf_observer", "mmwave"):
        assert accepted.get(sensor, 0) > 100, accepted


def test_the_mlx_scenarios_wheels_serve_the_low_speed_stretch_only():
    """Seed 002 section 2.2.2: the wheel rotation sensor serves the low-speed stretch, the EMF
    observer medium and high speed. config/scenario_mlx.yaml runs to 300 km/h: its wheel sensor
    sends nothing while the train runs at 150 km/h or more (the maglev's retract_speed), before
    and after that it counts, and the EMF observer covers the speeds in between from 72 km/h."""
    sc = Scenario.from_yaml("config/scenario_mlx.yaml")
    run = simulate_and_decode("wheel_sensor", sc)
    traj = sc.trajectory()
    stamps = np.array([m.stamp for m in run.measurements])
    speed = np.interp(stamps, traj.t, np.abs(traj.speed))
    assert np.abs(traj.speed).max() * 3.6 == pytest.approx(300.0, abs=0.5)
    assert np.all(speed < 150.0 / 3.6) and run.pipe.decoder.stats["gaps"] == 1
    up = traj.t[np.abs(traj.speed) >= 150.0 / 3.6]
    lo, hi = stamps[stamps < up[0]], stamps[stamps > up[-1]]
    assert up[-1] - up[0] > 100.0 and len(lo) > 700 and len(hi) > 700
    assert up[0] - lo.max() < 0.1 and hi.min() - up[-1] < 0.1      # silent from the first block up


# --------------------------------------------------------------------------- error-model floors
def _floor_runs(node, cases, ideal):
    """error_model_checks.floor_runs of ``node`` for cases (name: (initial speed [m/s], position
    [m], duration [s], profile)): (increments per case, lowest claimed 1-sigma / min_stddev)."""
    def decode(case, params, seed):
        v0, pos, duration, profile = case
        return decoded(node, scenario(node, v0=v0, pos=pos, duration=lasting(duration, params), profile=profile,
                                      params=params, seed=seed))
    return floor_runs(cases, ideal, decode)


def test_every_coil_counter_increment_is_at_or_above_the_error_model_floor():
    """ErrorModel.min_stddev holds by construction (wheel.IncrementEstimator's floor): random
    seeds, blocks of 10 ms .. 5 s and, every other run, coils and pickups without scatter or
    scale error (an increment between two switching points would claim 0 m), at a standstill,
    a crawl, 150 m/s and through a reversal; the floor is reached (it is the decoder's own)."""
    reversal = [{"speed": 10.0, "accel": 1.0, "hold": 1.0}, {"speed": -5.0, "decel": 1.0, "accel": 1.0, "hold": 1.0},
                {"speed": 0.0, "decel": 1.0, "hold": 3.0}]
    cases = {"standstill": (0.0, 300.0 + HEAD + PITCH / 8.0, 12.5, [{"speed": 0.0, "hold": 60.0}]),
             "crawl": (0.02, 300.0, 12.5, [{"speed": 0.02, "hold": 60.0}]),
             "high_speed": (150.0, 500.0, 3.0, None),
             "reversal": (0.0, 500.0, 22.0, reversal)}
    ideal = {"coil_sigma": 0.0, "gap_sigma": 0.0, "gain_sigma": 0.0, "noise": 0.0, "pitch_scale_sigma": 0.0}
    n, lowest = _floor_runs(COIL, cases, ideal)
    assert min(n.values()) > 10 and sum(n.values()) > 1000, n
    assert lowest == pytest.approx(1.0, abs=1e-9)


def test_a_coil_counter_increment_claiming_half_the_floor_is_refused_below_model():
    ms, _, model = decoded(COIL, scenario(COIL, duration=1.0), keep_going=False)
    assert_refused_below_half_the_floor(model, ms[5])


def test_every_emf_observer_increment_is_at_or_above_the_error_model_floor():
    """ErrorModel.min_stddev (pitch_scale_sigma x min_speed, at least 1 mm/s) holds by
    construction: random seeds, blocks of 10 ms .. 5 s and, every other run, an observer without
    angle error, noise, harmonic or scale error (only the converters' quantisation left: an
    increment would claim a mean speed to 0.5 mm/s), cutting in through min_speed, just above it,
    at 138 m/s and through a reversal (silent around the standstill); the floor is reached."""
    cases = {"cut_in": (0.0, 200.0, 16.0, [{"speed": 30.0, "accel": 2.0, "hold": 60.0}]),
             "near_min_speed": (1.03 * MIN_SPEED, 200.0, 4.0, None),
             "high_speed": (138.0, 200.0, 3.0, None),
             "reversal": (-40.0, 3000.0, 22.0, [{"speed": 40.0, "accel": 4.0, "decel": 4.0, "hold": 60.0}])}
    ideal = {"accuracy_deg": 0.0, "harmonic5": 0.0, "voltage_noise": 0.0, "current_noise": 0.0,
             "pitch_scale_sigma": 0.0, "resistance_tolerance": 0.0, "inductance_tolerance": 0.0}
    n, lowest = _floor_runs(EMF, cases, ideal)
    assert min(n.values()) > 3 and sum(n.values()) > 500, n
    assert lowest == pytest.approx(1.0, abs=1e-9)


def test_an_emf_observer_increment_claiming_half_the_floor_is_refused_below_model():
    ms, _, model = decoded(EMF, scenario(EMF, v0=60.0, duration=1.0), keep_going=False)
    assert_refused_below_half_the_floor(model, ms[5])

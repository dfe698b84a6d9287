"""mm-wave radio positioning by time differences of arrival (seed 002 section 2.2.2): simulator +
decoder against the truth."""
import math

import numpy as np
import pytest

from error_model_checks import assert_forged_fixes_refused
from train_localization.core.measurements import PositionFix
from train_localization.core.pipeline import SensorPipeline, simulate_and_decode
from train_localization.core.scenario import Scenario
from train_localization.core.sensors import NODE_NAMES, spec
from train_localization.core.sensors.base import resolve_params
from train_localization.core.sensors.mmwave_tdoa import CHANNELS, NO_REPLY, SLOTS, TICK
from train_localization.core.signals import InputRejected, RawBlock
from train_localization.core.track import Track, TrackError

NODE = "mmwave_tdoa"
V_MAX = 500.0 / 3.6
# MW000 at 200 m .. MW024 at 9800 m
STATIONS = [{"every": 400.0, "start": 200.0, "end": 9800.0, "id": "MW{n:03d}", "offset": 5.0, "height": 6.0}]
Z999 = 3.29
# the 6 nearest stations in view (three on each side of the antenna): a fix bounds a fault of
# two neighbours together (``timing_neighbours``) only with a station left on each side
RANGE = 1300.0


def scenario(speed=V_MAX, start=1000.0, duration=30.0, params=None, seed=1, stations=None, common_cause=()):
    return Scenario.from_dict({
        "name": "mmwave_tdoa", "seed": seed, "duration": duration,
        "track": {"track_id": "T1", "length": 10000.0, "equipment": {"mmwave_station": stations or STATIONS},
                  "common_cause": list(common_cause)},
        "vehicle": {"type": "maglev", "length": 150.0},
        "initial": {"position": start, "speed": speed},
        "profile": [{"speed": speed, "hold": 1000.0}],
        "sensors": {NODE: {"max_range": RANGE, **(params or {})}},
    })


def errors(sc, fixes):
    traj = sc.trajectory()
    err = np.array([f.position - np.interp(f.stamp, traj.t, traj.position) for f in fixes])
    return err, np.array([f.position_stddev for f in fixes])


def run(sc, params=None):
    return simulate_and_decode(NODE, sc, params)


@pytest.mark.parametrize("speed,start,seed", [(V_MAX, 1000.0, 1), (-V_MAX, 9000.0, 2), (30.0, 3000.0, 3)])
def test_fixes_hold_their_interval_against_the_truth(speed, start, seed):
    sc = scenario(speed, start, duration=30.0, seed=seed)
    r = run(sc)
    fixes = r.measurements
    for f in fixes:
        assert isinstance(f, PositionFix)
        f.validate()
    epochs = sum(b.n_samples for b in r.blocks)
    assert len(fixes) >= 0.8 * epochs                 # 5 ms fixes; no fix where a fault is unbounded
    err, sd = errors(sc, fixes)
    assert np.mean(np.abs(err) <= Z999 * sd) >= 0.999
    assert np.sqrt(np.mean(err ** 2)) < 0.12          # decimetre-level timing, 5 stations
    assert np.max(np.abs(err)) < 1.5
    assert 0.03 < np.median(sd) < 0.25
    for f in fixes[:100]:
        refs = f.reference_id.split(",")
        assert sum(not x.startswith("!") for x in refs) >= 3 and len(f.residuals) == len(refs)
    stats = r.pipe.decoder.stats
    assert stats["fixes"] == len(fixes) and stats["epochs"] == epochs
    assert stats["no_fix"] == epochs - len(fixes)
    assert sum(r.pipe.rejected.values()) == 0


def test_the_arrivals_are_the_geometry_on_the_receiver_clock():
    quiet = {"range_sigma_floor": 0.0, "range_sigma_snr": 0.0, "sync_sigma": 0.0, "nlos_rate": 0.0,
             "dropout_prob": 0.0, "snr_fading": 0.0, "clock_walk": 0.0, "clock_drift": 0.0, "clock_phase": 0.25,
             "antenna_offset": 2.0}
    sc = scenario(40.0, 3000.0, duration=3.0, params=quiet)
    r = run(sc)
    traj = sc.trajectory()
    pos = [it["position"] for it in sc.track.items("mmwave_station")]
    period = 1.0 / r.blocks[0].sample_rate
    for b in r.blocks[::7]:
        for i, t in enumerate(b.times()):
            x = np.interp(t, traj.t, traj.position) - 2.0
            for k in range(SLOTS):
                code = int(b.data[i, 4 * k])
                if code:
                    rng = math.hypot(x - pos[code - 1], math.hypot(5.0, 3.0))
                    arrival = float(b.data[i, 4 * k + 1]) + float(b.data[i, 4 * k + 2])
                    assert arrival == pytest.approx((rng / 299_792_458.0 * 1.0003 + 0.25 * period) % period,
                                                    abs=1e-12)
                    assert float(b.data[i, 4 * k + 1]) % TICK == 0.0
    err, _ = errors(sc, r.measurements)
    assert np.max(np.abs(err)) < 0.01       # the front, 2 m ahead of the antenna


def test_the_receiver_clock_cancels_even_when_it_jumps_drifts_and_wraps():
    """A clock phase at the frame's edge, a 1e-6 s/sqrt(s) walk, a 1.2 ms jump and 500 ppm for 10 s
    (the arrival phases wrap through the frame): the fixes equal those of a perfect clock."""
    sc = scenario(V_MAX, 1000.0, duration=25.0)
    ideal = run(sc, {"clock_phase": 0.0, "clock_drift": 0.0, "clock_walk": 0.0})
    wild = run(sc, {"clock_phase": 0.9999, "clock_drift": 2.0, "clock_walk": 1e-6,
                    "faults": "clock@5-8:jump=1234567;clock@10-20:drift=500"})
    period = 1.0 / wild.blocks[0].sample_rate
    arrivals = np.concatenate([b.data[:, 1::4] for b in wild.blocks])
    spread = np.array([a[a >= 0].max() - a[a >= 0].min() if np.any(a >= 0) else 0.0 for a in arrivals])
    assert np.any(spread > 0.5 * period)            # an epoch straddles the frame's wrap
    assert not np.array_equal(arrivals, np.concatenate([b.data[:, 1::4] for b in ideal.blocks]))
    a, b = ideal.measurements, wild.measurements
    assert len(a) > 3000 and [f.stamp for f in a] == [f.stamp for f in b]
    assert [f.reference_id for f in a] == [f.reference_id for f in b]
    assert np.max(np.abs(np.array([f.position for f in a]) - [f.position for f in b])) < 1e-3
    assert np.max(np.abs(np.array([f.position_stddev for f in a]) - [f.position_stddev for f in b])) < 1e-3


def _window(fixes, t0, t1, sid):
    return [f for f in fixes if t0 <= f.stamp < t1 and sid in f.reference_id.replace("!", "").split(",")]


def test_a_biased_station_is_isolated_or_the_epoch_gives_no_fix():
    # MW010 at 4200 m, passed at ~t = 11.5 s from 2600 m; 3 m of excess path from 6 to 16 s
    sc = scenario(V_MAX, 2600.0, duration=22.0, params={"faults": "MW010@6-16:3.0", "nlos_rate": 0.0})
    r = run(sc)
    fixes = r.measurements
    window = _window(fixes, 6.0, 16.0, "MW010")
    isolated = [f for f in window if "!MW010" in f.reference_id.split(",")]
    # (a few epochs at the moment of passing it, where its bias hides in x, use it -- inside their sigma)
    assert len(isolated) > 500 and len(isolated) >= 0.95 * len(window)
    for f in isolated:
        refs = f.reference_id.split(",")
        assert abs(f.residuals[refs.index("!MW010")]) > 1.5        # the fault's size shows
    err, sd = errors(sc, window)
    assert np.all(np.abs(err) <= Z999 * sd) and np.median(np.abs(err)) < 0.1
    after = _window(fixes, 16.5, 22.0, "MW010")
    assert after and all("!MW010" not in f.reference_id for f in after)
    assert r.pipe.decoder.stats["rejected_stations"] >= len(isolated)


def test_a_fault_detected_but_not_identified_gives_no_fix():
    """Four stations, two on either side of the antenna: a bias of one of the pair ahead shows in
    their difference, but either of the two may be the faulty one (each subset of three fits, and
    neither can be protected: its lone station ahead is unchecked): no fix, never a fix of the
    wrong candidate."""
    four = [{"id": f"S{k}", "position": p, "offset": 5.0} for k, p in enumerate((1000.0, 1400.0, 1800.0, 2200.0))]
    params = {"faults": "S3@1-3:3.0", "nlos_rate": 0.0, "dropout_prob": 0.0, "timing_neighbours": 1}
    sc = scenario(50.0, 1550.0, duration=4.0, params=params, stations=four)   # 1550 .. 1750 m
    r = run(sc)
    stats = r.pipe.decoder.stats
    during = [f for f in r.measurements if 1.0 <= f.stamp < 3.0]
    assert len(during) < 0.02 * 400 and stats["unidentifiable"] + stats["unbounded"] > 0.95 * 400
    outside = [f for f in r.measurements if f.stamp < 1.0 or f.stamp >= 3.0]
    assert len(outside) > 0.9 * 400
    err, sd = errors(sc, r.measurements)
    assert np.all(np.abs(err) <= Z999 * sd)


def test_a_station_losing_its_synchronisation_is_caught():
    # MW012 (5000 m) walks off at 20 ns/s (6 m/s of range) from 8 s: first hidden in the noise, then found
    sc = scenario(V_MAX, 3400.0, duration=20.0, params={"faults": "MW012@8-20:sync=20", "nlos_rate": 0.0})
    r = run(sc)
    fixes = r.measurements
    err, sd = errors(sc, fixes)
    assert np.mean(np.abs(err) <= Z999 * sd) >= 0.999 and np.median(np.abs(err)) < 0.1
    late = _window(fixes, 10.0, 20.0, "MW012")    # 12 m and more off by then
    excluded = [f for f in late if "!MW012" in f.reference_id.split(",")]
    assert len(excluded) > 300 and len(excluded) >= 0.98 * len(late)
    for f in excluded:
        refs = f.reference_id.split(",")
        assert abs(f.residuals[refs.index("!MW012")]) > 0.9 * 6.0 * (f.stamp - 8.0) - 1.0   # 6 m/s


def test_the_reference_station_may_be_the_faulty_one():
    """MW010 biased while the train passes it: it is the nearest station (the highest SNR), the
    reference of the differences, and is excluded all the same."""
    sc = scenario(V_MAX, 3800.0, duration=6.0, params={"faults": "MW010@0-6:4.0", "nlos_rate": 0.0,
                                                         "snr_fading": 0.0, "timing_neighbours": 1,
                                                         "max_range": 1000.0})
    r = run(sc)
    traj = sc.trajectory()
    near = [f for f in r.measurements if abs(np.interp(f.stamp, traj.t, traj.position) - 4200.0) < 60.0]
    assert len(near) > 100
    assert np.mean(["!MW010" in f.reference_id.split(",") for f in near]) >= 0.95
    err, sd = errors(sc, near)
    assert np.all(np.abs(err) <= Z999 * sd)


def test_beyond_the_last_station_the_geometry_gives_no_fix():
    sc = scenario(V_MAX, 9300.0, duration=4.0, params={"nlos_rate": 0.0})   # past MW024 at 9800 m at 3.6 s
    r = run(sc)
    traj = sc.trajectory()
    beyond = [f for f in r.measurements if np.interp(f.stamp, traj.t, traj.position) > 9850.0]
    assert not beyond
    stats = r.pipe.decoder.stats
    assert stats["geometry"] + stats["unbounded"] > 50


def _good_block():
    """A block of 5 stations in view: its sixth slot is empty."""
    sc = scenario(V_MAX, 3000.0, duration=0.2, params={"max_range": 1000.0})
    return sc, run(sc).blocks[0]


def _with(block, data):
    return RawBlock.from_samples(block.sensor, block.unit_id, block.seq, block.t0, block.sample_rate,
                                 block.channels, block.units, data)


def _set(i, k, values):
    def mutate(d):
        d[i, k:k + len(values)] = values
    return mutate


@pytest.mark.parametrize("mutate,reason", [
    (_set(0, 4, [99.0]), "unknown_id"),                          # station code not on the track
    (_set(0, 4, [2.5]), "unknown_id"),                           # not an integer
    (_set(0, 4, [1e19]), "unknown_id"),
    (_set(0, 5, [-2 * TICK]), "implausible"),                    # arrival before the frame
    (_set(0, 5, [1.0]), "implausible"),                          # beyond the frame period
    (_set(0, 5, [1.5 * TICK]), "implausible"),                   # off the coarse counter
    (_set(0, 6, [2 * TICK]), "implausible"),                     # fine part beyond its counter step
    (_set(0, 5, [NO_REPLY, 0.0, 20.0]), "implausible"),          # no-reply sentinel with an SNR
    (_set(0, 5, [NO_REPLY, 1e-7, 0.0]), "implausible"),          # sentinel with a fine time
    (_set(0, 0, [0.0, 1e-3, 0.0, 0.0]), "implausible"),          # an empty slot with an arrival
    (lambda d: d.__setitem__((0, slice(8, 12)), d[0, 4:8]), "implausible"),   # one station twice
    (_set(0, 7, [500.0]), "implausible"),                        # SNR
])
def test_bad_blocks_are_rejected_and_counted(mutate, reason):
    sc, block = _good_block()
    data = block.data.copy()
    assert data[0, 0] == 0.0 and np.all(data[0, 4::4] > 0) and np.all(data[0, 5:8] != 0.0)
    mutate(data)
    pipe = SensorPipeline(spec(NODE), {}, sc.track, sc.vehicle, simulate=False)
    with pytest.raises(InputRejected) as exc:
        pipe.on_block(_with(block, data))
    assert exc.value.reason == reason
    assert pipe.rejected[reason] == 1
    assert pipe.on_block(block)     # the good block still decodes


def test_nan_is_rejected_by_the_decoder():
    sc, block = _good_block()
    dec = spec(NODE).decoder(resolve_params(spec(NODE).params, {}), sc.track)
    bad = RawBlock.__new__(RawBlock)
    bad.__dict__.update(block.__dict__)
    data = block.data.copy()
    data[1, 2] = np.nan
    object.__setattr__(bad, "data", data)
    with pytest.raises(InputRejected) as exc:
        dec.decode(bad)
    assert exc.value.reason == "implausible"


def test_registered_deterministic_and_within_the_raw_rate():
    assert NODE in NODE_NAMES
    s = spec(NODE)
    assert (s.sensor, s.seeds, s.outputs) == ("mmwave_tdoa", ("002",), ("position",))
    sc = scenario(V_MAX, 3000.0, duration=2.0)
    a, b = run(sc), run(sc)
    assert all(np.array_equal(x.data, y.data) for x, y in zip(a.blocks, b.blocks))
    assert a.measurements == b.measurements
    assert a.blocks[0].channels == CHANNELS and a.blocks[0].sample_rate == 200.0
    assert len(CHANNELS) * 200.0 <= 20000.0
    for blk in a.blocks:
        assert np.all(np.isfinite(blk.data))


@pytest.mark.parametrize("seed", [1, 2])
def test_every_decoded_fix_passes_the_error_model(seed):
    rng = np.random.default_rng(seed)
    total = 0
    for sign in (1, -1):
        params = {"antenna_offset": float(rng.uniform(0.0, 30.0)), "orientation": int(rng.choice([-1, 1])),
                  "sync_sigma": float(rng.choice([0.0, 0.3])), "range_sigma_floor": float(rng.choice([0.0, 0.08])),
                  "min_stations": int(rng.choice([2, 3])), "nlos_rate": float(rng.choice([0.0, 0.05, 0.5]))}
        sc = scenario(sign * float(rng.uniform(5.0, V_MAX)), float(rng.uniform(1500.0, 8500.0)), duration=5.0,
                      params=params, seed=seed)
        r = run(sc)
        model = r.pipe.spec.errors(r.pipe.params, r.pipe.track, sc.vehicle)
        assert [model.refusal(f) for f in r.measurements] == [None] * len(r.measurements)
        total += len(r.measurements)
    assert total > 500


def test_forged_fixes_are_refused_with_their_reason():
    params = resolve_params(spec(NODE).params, {"antenna_offset": 2.0})
    track = Track.from_dict({"track_id": "T1", "length": 10000.0, "equipment": {"mmwave_station": STATIONS}})
    model = spec(NODE).errors(params, track, None)
    sync = 0.3e-9 * 299_792_458.0 / 1.0003
    assert model.min_stddev == pytest.approx(math.hypot(0.08, sync) / math.sqrt(SLOTS))
    honest = PositionFix(10.0, NODE, NODE, "T1", "MW001,MW002,!MW003", 900.0, 0.05, 0, (0.1, -0.1, 2.0))
    hi = model.references.windows["MW001"].hi
    assert_forged_fixes_refused(model, honest, "MW001,MW999", hi + 300.0, far_id="MW001")


# -- common-cause groups (core/common_cause.py) ------------------------------------------------
PAIR_DRIFT = "MW012@4-20:sync=5;MW013@4-20:sync=5"   # two neighbours on one timing node walk off together


def _held(sc, fixes) -> float:
    err, sd = errors(sc, fixes)
    return float(np.mean(np.abs(err) <= Z999 * sd))


def test_two_neighbours_walking_off_together_are_covered_as_one_fault():
    """Two neighbouring stations lose their synchronisation together, the same way (1.5 m/s of
    range each): they agree with each other, so a decoder that only knows single faults keeps
    them and publishes fixes metres off with a decimetre sigma; covering every two neighbours as
    one fault (the default, ``timing_neighbours`` 2) keeps every fix's interval on the truth."""
    params = {"faults": PAIR_DRIFT, "nlos_rate": 0.0}
    sc = scenario(V_MAX, 3400.0, duration=20.0, params=params)
    single = run(scenario(V_MAX, 3400.0, duration=20.0, params={**params, "timing_neighbours": 1})).measurements
    assert _held(sc, single) < 0.99                     # the single-fault model is fooled
    r = run(sc)
    assert len([f for f in r.measurements if f.stamp < 4.0]) > 0.9 * 800   # before the fault
    assert _held(sc, r.measurements) >= 0.999
    assert r.pipe.decoder.stats["common_cause"] > 0


def test_declared_groups_replace_the_neighbours():
    """A track that declares its timing groups: a group of two stations that are not neighbours
    (one fibre ring) is covered; without the declaration (neighbours only) it is not."""
    drift = "MW011@4-20:sync=5;MW013@4-20:sync=5"
    params = {"faults": drift, "nlos_rate": 0.0}
    ring = {"id": "RING", "cause": "fibre ring", "members": ["MW011", "MW013"], "prior": 0.01}
    neighbours = scenario(V_MAX, 3400.0, duration=20.0, params=params)
    assert _held(neighbours, run(neighbours).measurements) < 0.99
    declared = scenario(V_MAX, 3400.0, duration=20.0, params=params, common_cause=[ring])
    r = run(declared)
    assert len([f for f in r.measurements if f.stamp < 4.0]) > 0.9 * 800 and _held(declared, r.measurements) >= 0.999


@pytest.mark.parametrize("entry,message", [
    ({"id": "G", "members": ["MW001", "XX"], "prior": 0.01}, "does not have: XX"),
    ({"id": "G", "members": ["MW001", "MW002"], "prior": 1.5}, "is not a probability"),
    ({"id": "G", "equipment": "mmwave_station", "size": 1, "prior": 0.01}, "'size' must be"),
    ({"id": "G", "prior": 0.01}, "names neither"),
])
def test_a_bad_common_cause_block_is_refused_in_one_line(entry, message):
    data = {"track_id": "T1", "length": 10000.0, "equipment": {"mmwave_station": STATIONS},
            "common_cause": [entry]}
    with pytest.raises(TrackError, match=message):
        Track.from_dict(data)

"""Axle counter (seed 004 sections 2.2, 4.2): wheel sensor simulation, counting, occupancy."""

import dataclasses

import numpy as np
import pytest

from error_model_checks import assert_forged_fixes_refused
from train_localization.core.measurements import CLEAR, DISTURBED, OCCUPIED, PositionFix, SectionOccupancy
from train_localization.core.pipeline import SensorPipeline, run_offline
from train_localization.core.scenario import Scenario
from train_localization.core.sensors import spec
from train_localization.core.sensors.base import resolve_params
from train_localization.core.signals import InputRejected, RawBlock

NODE = "axle_counter"
V300 = 300.0 / 3.6
CAR = 25.0
HEADS = [{"every": 800.0, "start": 1000.0, "end": 3400.0, "id": "AC{n:02d}"}]   # AC00..AC03
SECTIONS = ["AC00-AC01", "AC01-AC02", "AC02-AC03"]
FIRST_AXLE = 3.0


def axles(cars=8):
    """4 axles per 25 m car: bogies 18 m apart, 2.5 m wheelbase."""
    return [a + CAR * k for k in range(cars) for a in (FIRST_AXLE, 5.5, 20.5, 23.0)]


def scenario(speed=V300, start=500.0, duration=30.0, profile=None, params=None, seed=1, cars=8, heads=None):
    return Scenario.from_dict({
        "name": "axle_counter", "seed": seed, "duration": duration,
        "track": {"track_id": "T1", "length": 5000.0, "equipment": {"axle_counter_head": heads or HEADS}},
        "vehicle": {"type": "emu", "length": CAR * cars, "axles": axles(cars)},
        "initial": {"position": start, "speed": speed},
        "profile": profile or [{"speed": speed, "hold": 1000.0}],
        "sensors": {NODE: {"first_axle_offset": FIRST_AXLE, **(params or {})}},
    })


def occupancies(ms):
    return [m for m in ms if isinstance(m, SectionOccupancy)]


def fixes_of(ms):
    return [m for m in ms if isinstance(m, PositionFix)]


def by_id(occ):
    return {s.section_id: s for s in occ.sections}


def check_fixes(sc, fixes):
    traj = sc.trajectory()
    for f in fixes:
        err = f.position - np.interp(f.stamp, traj.t, traj.position)
        assert abs(err) < 3.0 * f.position_stddev, (f, err)
        assert 0.02 < f.position_stddev < 0.1


@pytest.mark.parametrize("speed,start,order", [(V300, 500.0, 1), (-V300, 4000.0, -1)])
def test_counts_exact_at_300_kmh_both_directions(speed, start, order):
    sc = scenario(speed, start, duration=42.0)
    blocks, ms, pipe = run_offline(NODE, sc)
    for m in ms:
        m.validate()
    n_axles = len(sc.vehicle.axles)
    final = by_id(occupancies(ms)[-1])
    for sid in SECTIONS:
        s = final[sid]
        assert (s.axles_in, s.axles_out, s.axle_count, s.state) == (n_axles, n_axles, 0, CLEAR)
    assert pipe.decoder.stats["axles"] == 4 * n_axles   # 4 heads, every axle counted once per head
    # while the train runs through, the sections go CLEAR -> OCCUPIED -> CLEAR in running order
    first_occupied = {sid: min(o.stamp for o in occupancies(ms) if by_id(o)[sid].state == OCCUPIED)
                      for sid in SECTIONS}
    times = [first_occupied[sid] for sid in SECTIONS]
    assert times == sorted(times, reverse=(order < 0))
    assert all(by_id(o)[sid].state != DISTURBED for o in occupancies(ms) for sid in SECTIONS)
    # one front fix per head, in running order, with the direction of travel
    fixes = fixes_of(ms)
    assert [f.reference_id for f in fixes] == ["AC00", "AC01", "AC02", "AC03"][::order]
    assert all(f.direction == order for f in fixes)
    check_fixes(sc, fixes)
    assert sum(pipe.rejected.values()) == 0


def test_wheel_signal_physics():
    """Each wheel damps Sa then Sb (increasing direction), lag = spacing / speed."""
    quiet = {"noise_sigma": 0.0, "drift_sigma": 0.0, "spike_rate": 0.0, "damping_spread": 0.0,
             "gain_spread": 0.0, "head_position_sigma": 0.0}
    sc = scenario(V300, 900.0, duration=4.0, params=quiet, cars=1)
    blocks, ms, _ = run_offline(NODE, sc)
    data = np.vstack([b.data for b in blocks])
    t = np.concatenate([b.times() for b in blocks])
    a, b = data[:, 0], data[:, 1]      # AC00.a, AC00.b
    assert blocks[0].channels[:2] == ("AC00.a", "AC00.b")
    for ch in (a, b):
        assert ch.max() == pytest.approx(1.0, abs=0.05)
        assert abs(ch[t < 1.0]).max() < 1e-6
    # centroid of the first wheel's pulse on each system
    first = t < t[np.argmax(a > 0.5)] + 0.02
    ta = np.sum(t[first] * a[first]) / np.sum(a[first])
    tb = np.sum(t[first] * b[first]) / np.sum(b[first])
    assert tb - ta == pytest.approx(0.14 / V300, rel=0.05)
    # the 4 axles give 4 pulses per system, >= 4 samples above threshold each at 300 km/h
    rises = np.flatnonzero((a[1:] >= 0.5) & (a[:-1] < 0.5))
    assert len(rises) == 4
    widths = [np.argmax(a[r + 1:] < 0.5) for r in rises]
    assert min(widths) >= 4
    assert len(blocks[0].channels) * blocks[0].sample_rate <= 20000.0   # 4 heads x 2 systems x 2 kHz


DENSE = [{"every": 300.0, "start": 1000.0, "end": 1900.0, "id": "AC{n:02d}"}]   # AC00..AC03, 300 m sections


def test_stop_over_a_head_then_continue():
    # the 200 m train runs in at 30 m/s, stops with its front 80 m past AC01 (1300 m), straddling
    # the head, dwells 10 s, then runs on through AC03
    profile = [{"speed": 30.0, "hold": 10.0}, {"speed": 0.0, "decel": 0.8, "hold": 10.0},
               {"speed": 30.0, "accel": 1.0, "hold": 200.0}]
    probe = scenario(30.0, 0.0, duration=60.0, profile=profile, heads=DENSE).trajectory()
    stop_idx = np.argmax((probe.t > 10.0) & (np.abs(probe.speed) < 1e-6))
    t_stop = probe.t[stop_idx]
    sc = scenario(30.0, 1380.0 - probe.position[stop_idx], duration=t_stop + 55.0, profile=profile, heads=DENSE)
    assert sc.start_position < 1000.0 - 200.0   # the train starts outside the monitored area
    _, ms, pipe = run_offline(NODE, sc)
    occ = occupancies(ms)
    during = [by_id(o) for o in occ if t_stop + 1.0 < o.stamp < t_stop + 9.0]
    assert during   # periodic reports while nothing changes
    traj = sc.trajectory()
    front = np.interp(t_stop + 5.0, traj.t, traj.position)
    beyond = sum(1 for a in sc.vehicle.axles if front - a > 1300.0)
    for o in during:
        assert o["AC00-AC01"].state == OCCUPIED and o["AC00-AC01"].axle_count == 32 - beyond
        assert o["AC01-AC02"].state == OCCUPIED and o["AC01-AC02"].axle_count == beyond
        assert o["AC02-AC03"].state == CLEAR
    assert 0 < beyond < 32
    final = by_id(occ[-1])
    assert all(final[sid].state == CLEAR and final[sid].axles_in == 32 for sid in SECTIONS)
    check_fixes(sc, fixes_of(ms))
    assert [f.reference_id for f in fixes_of(ms)] == ["AC00", "AC01", "AC02", "AC03"]


def test_reversal_backs_out_without_disturbance():
    # enters AC00-AC01, front runs 60 m past AC01, stops, backs out past AC00
    profile = [{"speed": 20.0, "hold": 35.0}, {"speed": 0.0, "decel": 1.0, "hold": 5.0},
               {"speed": -20.0, "accel": 1.0, "hold": 200.0}]
    probe = scenario(20.0, 0.0, duration=80.0, profile=profile)
    tr = probe.trajectory()
    start = 1860.0 - tr.position.max()
    sc = scenario(20.0, start, duration=130.0, profile=profile,
                  params={"last_axle_offset": axles()[-1]})
    _, ms, pipe = run_offline(NODE, sc)
    occ = occupancies(ms)
    assert max(by_id(o)["AC01-AC02"].axle_count for o in occ) > 0   # it did cross AC01
    final = by_id(occ[-1])
    for sid in SECTIONS:
        s = final[sid]
        assert s.state == CLEAR and s.axles_in == s.axles_out and s.axle_count == 0
    assert final["AC00-AC01"].axles_in == 32 + (final["AC01-AC02"].axles_in)
    assert all(by_id(o)[sid].state != DISTURBED for o in occ for sid in SECTIONS)
    fixes = fixes_of(ms)
    # front fixes entering (AC00, AC01, front first), and one backing out of AC00 (last axle first)
    assert [(f.reference_id, f.direction) for f in fixes] == [("AC00", 1), ("AC01", 1), ("AC00", -1)]
    check_fixes(sc, fixes)


def _drive(sc, params=None, reset_at=None, reset_ids=()):
    """Like run_offline, with a section reset by the operator at ``reset_at``."""
    pipe = SensorPipeline(spec(NODE), {**sc.sensors[NODE], **(params or {})}, sc.track, sc.vehicle,
                          sc.rng(NODE, "axle_counter"))
    traj = sc.trajectory()
    ms = []
    for k in range(int(sc.duration * sc.truth_rate) + 1):
        t = k / sc.truth_rate
        if reset_at is not None and t >= reset_at:
            for sid in reset_ids:
                pipe.decoder.reset_section(sid)
            reset_at = None
        for block in pipe.on_truth(traj.state_at(t)):
            ms.extend(pipe.on_block(block))
    return ms, pipe


def test_missed_axle_disturbs_until_reset():
    # train (32 axles) at 300 km/h reaches AC01 at ~15.6 s; the sensor misses one wheel there
    sc = scenario(V300, 500.0, duration=50.0, params={"faults": "AC01@14.0:missed"})
    ms, pipe = _drive(sc, reset_at=45.0, reset_ids=("AC00-AC01", "AC01-AC02"))
    occ = occupancies(ms)
    before = by_id([o for o in occ if o.stamp < 44.9][-1])   # the reset acts from the block at 44.95 s
    # AC00-AC01 kept one axle although the train left it (rule B), AC01-AC02 counted one out
    # more than in (rule A); AC02-AC03 counted the train correctly
    assert before["AC00-AC01"].state == DISTURBED and before["AC00-AC01"].axle_count == 1
    assert before["AC01-AC02"].state == DISTURBED and before["AC01-AC02"].axle_count == -1
    assert before["AC02-AC03"].state == CLEAR and before["AC02-AC03"].axles_in == 32
    t_dist = min(o.stamp for o in occ if by_id(o)["AC00-AC01"].state == DISTURBED)
    assert all(by_id(o)["AC00-AC01"].state == DISTURBED for o in occ if t_dist <= o.stamp < 44.9)
    after = [by_id(o) for o in occ if o.stamp >= 44.9]
    assert after and all(a[sid].state == CLEAR and a[sid].axle_count == 0 for a in after for sid in SECTIONS)
    with pytest.raises(KeyError):
        pipe.decoder.reset_section("nope")


def test_extra_axle_disturbs():
    # a spurious axle at AC01 (e.g. a trolley) long before the train: AC00-AC01 goes negative
    sc = scenario(V300, 500.0, duration=45.0, params={"faults": "AC01@3.0:extra"})
    _, ms, _ = run_offline(NODE, sc)
    occ = occupancies(ms)
    early = by_id([o for o in occ if 3.2 < o.stamp < 5.0][0])
    assert early["AC00-AC01"].state == DISTURBED and early["AC00-AC01"].axle_count == -1
    assert early["AC01-AC02"].state == OCCUPIED and early["AC01-AC02"].axle_count == 1
    final = by_id(occ[-1])
    # after the train, AC01-AC02 still holds the extra axle while AC02-AC03 counted the train out
    assert final["AC01-AC02"].state == DISTURBED and final["AC01-AC02"].axle_count == 1
    assert final["AC00-AC01"].state == DISTURBED
    assert final["AC02-AC03"].state == CLEAR


def test_interference_spikes_do_not_count():
    # 1 spike/s on every system (100x the default): a spike on one system is no axle
    sc = scenario(0.0, 100.0, duration=20.0, params={"spike_rate": 1.0})
    _, ms, pipe = run_offline(NODE, sc)
    assert pipe.decoder.stats["axles"] == 0
    assert pipe.decoder.stats["rejected_sequences"] > 100   # single-system pulses seen and rejected
    assert all(s.state == CLEAR for o in occupancies(ms) for s in o.sections)
    assert not fixes_of(ms)


def _good_block():
    sc = scenario(V300, 500.0, duration=0.2)
    blocks, _, _ = run_offline(NODE, sc)
    return sc, blocks[0]


def test_bad_blocks_are_rejected():
    sc, block = _good_block()
    dec = spec(NODE).decoder(resolve_params(spec(NODE).params, sc.sensors[NODE]), sc.track)
    unknown = RawBlock.from_samples(block.sensor, block.unit_id, 1, block.t0, block.sample_rate,
                                    block.channels[:-2] + ("AC99.a", "AC99.b"), block.units, block.data)
    with pytest.raises(InputRejected) as exc:
        dec.decode(unknown)
    assert exc.value.reason == "unknown_id"
    missing = RawBlock.from_samples(block.sensor, block.unit_id, 1, block.t0, block.sample_rate,
                                    block.channels[:-2], block.units[:-2], block.data[:, :-2])
    with pytest.raises(InputRejected) as exc:
        dec.decode(missing)
    assert exc.value.reason == "channels"
    data = block.data.copy()
    data[10, 3] = 40.0
    with pytest.raises(InputRejected) as exc:
        dec.decode(RawBlock.from_samples(block.sensor, block.unit_id, 1, block.t0, block.sample_rate,
                                         block.channels, block.units, data))
    assert exc.value.reason == "implausible"
    assert dec.decode(block)   # the first block still decodes (initial occupancy report)
    # through the pipeline, rejections are counted
    pipe = SensorPipeline(spec(NODE), sc.sensors[NODE], sc.track, sc.vehicle, simulate=False)
    with pytest.raises(InputRejected):
        pipe.on_block(unknown)
    assert pipe.rejected["unknown_id"] == 1


def test_determinism():
    sc = scenario(V300, 500.0, duration=10.0)
    b1, m1, _ = run_offline(NODE, sc)
    b2, m2, _ = run_offline(NODE, sc)
    assert all(np.array_equal(x.data, y.data) for x, y in zip(b1, b2)) and m1 == m2
    b3, _, _ = run_offline(NODE, scenario(V300, 500.0, duration=10.0, seed=7))
    assert not all(np.array_equal(x.data, y.data) for x, y in zip(b1, b3))


def test_axles_counted_exactly_at_500_kmh():
    # (decode speed: python -m train_localization.tools.bench sensors)
    sc = scenario(500.0 / 3.6, 500.0, duration=25.0)
    _, _, pipe = run_offline(NODE, sc)
    assert pipe.decoder.stats["axles"] == 4 * 32


# -- first-axle identification: a miscount must not give a confident wrong front fix ----------
T_FIRST = FIRST_AXLE / V300 + 6.0   # the first axle reaches AC00 (1000 m) from 500 m at 300 km/h


def _covered(sc, fixes, cover=3.3):
    traj = sc.trajectory()
    for f in fixes:
        err = f.position - np.interp(f.stamp, traj.t, traj.position)
        assert abs(err) <= cover * f.position_stddev, (f, err)


BACKING = {"orientation": 1, "last_axle_offset": axles()[-1]}   # the train backs: its last axle leads


@pytest.mark.parametrize("speed,start,head,params", [(V300, 500.0, "AC00", {}), (-V300, 4000.0, "AC03", {}),
                                                     (20.0, 880.0, "AC00", {}),
                                                     (-V300, 3400.0 + axles()[-1] + 170.0, "AC03", BACKING)])
def test_missed_first_axle_gives_no_wrong_fix(speed, start, head, params):
    # the head misses the first wheel of the train: the first counted axle is the second
    sc = scenario(speed, start, duration=9.0, params={"faults": f"{head}@1.0:missed", **params})
    _, ms, pipe = run_offline(NODE, sc)
    fixes = [f for f in fixes_of(ms) if f.reference_id == head]
    _covered(sc, fixes)
    # the layout identifies the second axle: the fix is published for it, a few cm
    assert len(fixes) == 1 and fixes[0].position_stddev < 0.1 and fixes[0].direction == np.sign(speed)
    assert pipe.decoder.stats["front_identified_shifted"] >= 1


@pytest.mark.parametrize("speed,start,head,fault,params", [
    (V300, 500.0, "AC00", f"{T_FIRST - 0.2:.4f}:extra", {}),
    (-V300, 3400.0 + axles()[-1] + 2.0 * V300, "AC03", "1.8:extra-", BACKING)])   # last axle at 2.0 s
def test_extra_axle_before_the_first_gives_no_wrong_fix(speed, start, head, fault, params):
    # a spurious axle through the head 0.2 s before the train's first axle
    sc = scenario(speed, start, duration=9.0, params={"faults": f"{head}@{fault}", **params})
    _, ms, pipe = run_offline(NODE, sc)
    fixes = [f for f in fixes_of(ms) if f.reference_id == head]
    _covered(sc, fixes)
    assert len(fixes) == 1 and fixes[0].position_stddev < 0.1 and fixes[0].direction == np.sign(speed)
    assert pipe.decoder.stats["front_identified_shifted"] == 1


def test_lone_spurious_axle_gives_no_fix():
    # a spurious axle into an empty region with no train behind it: no fix at all
    sc = scenario(0.0, 100.0, duration=5.0, params={"faults": "AC01@1.0:extra"})
    _, ms, pipe = run_offline(NODE, sc)
    assert pipe.decoder.stats["axles"] == 1
    assert not fixes_of(ms)
    assert pipe.decoder.stats["front_unidentified"] == 1


@pytest.mark.parametrize("fault", ["AC03@1.0:extra-", "AC03@1.0:extra"])
def test_a_spurious_axle_before_any_train_does_not_set_the_orientation(fault):
    # orientation auto: a lone spurious axle (EMI, a trolley) counted the other way before the
    # first train took the train for one backing, and its front fixes were off by the train's
    # length (200 m); the orientation comes from the first passage identified as a train's
    sc = scenario(V300, 500.0, duration=18.0, params={"faults": fault, "last_axle_offset": axles()[-1]})
    _, ms, pipe = run_offline(NODE, sc)
    fixes = fixes_of(ms)
    assert [f.reference_id for f in fixes] == ["AC00", "AC01"] and all(f.direction == 1 for f in fixes)
    check_fixes(sc, fixes)
    assert pipe.decoder.stats["front_unidentified"] == 1     # the lone axle: no fix


@pytest.mark.parametrize("fault", ["", "AC00@1.0:missed", f"AC00@{T_FIRST - 0.2:.4f}:extra"])
def test_without_layout_the_stddev_covers_a_miscount(fault):
    sc = scenario(V300, 500.0, duration=9.0, params={"axle_offsets": [], "faults": fault})
    _, ms, pipe = run_offline(NODE, sc)
    fixes = [f for f in fixes_of(ms) if f.reference_id == "AC00"]
    assert len(fixes) == 1
    _covered(sc, fixes)
    assert fixes[0].position_stddev > 2.4 / 3.3   # the measured first spacing (>= 2.5 m) is covered


# ---------------------------------------------------------------- error model: floor and references

MANY_HEADS = [{"every": 300.0, "start": 1000.0, "end": 3400.0, "id": "AC{n:02d}"}]   # AC00..AC08

def _heads_passed(sc, params):
    """Heads that at least two axles of the train crossed during the run (the second identifies the
    first: a front fix is due at each)."""
    traj = sc.trajectory()
    o = params.get("orientation") or int(np.sign(traj.speed[np.flatnonzero(traj.speed)[0]]))   # auto: first motion
    wheels = traj.position[:, None] - o * np.asarray(sc.vehicle.axles)[None, :]
    lo, hi = wheels.min(axis=0), wheels.max(axis=0)
    return [h["id"] for h in sc.track.items("axle_counter_head")
            if np.count_nonzero((lo < h["position"] - 0.5) & (hi > h["position"] + 0.5)) >= 2]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_every_decoded_fix_passes_the_error_model(seed):
    """Randomised runs (2..8 m/s and 40..83 m/s both ways, a train backing with its last axle
    leading, orientation auto or given, short and long trains, survey and offset errors down to
    none): the model built from the run's parameters refuses no fix."""
    rng = np.random.default_rng(seed)
    total = expected = 0
    for sign, backing in ((1, False), (-1, False), (-1, True)):
        for slow in (True, False):
            speed = sign * (rng.uniform(2.0, 8.0) if slow else rng.uniform(40.0, V300))
            cars = int(rng.choice([2, 8]))
            params = {"head_position_sigma": float(rng.choice([0.0, 0.02])),
                      "axle_offset_sigma": float(rng.choice([0.0, 0.02])),
                      "orientation": int(rng.choice([0, sign]))}
            if backing:
                params.update(orientation=1, last_axle_offset=axles(cars)[-1])
            head = 1900.0 if sign > 0 else 2500.0
            if slow:      # the leading axle 5..20 m before a head, a train length and a bit to run
                lead = params["last_axle_offset"] if backing else 0.0
                start = head - sign * rng.uniform(5.0, 20.0) + lead
                duration = (CAR * cars + 30.0) / abs(speed)
            else:
                start, duration = (500.0, 3300.0 / abs(speed)) if sign > 0 else (4000.0, 3300.0 / abs(speed))
                if backing:
                    start += axles(cars)[-1]
            sc = scenario(speed, start, duration=duration, params=params, seed=seed, cars=cars, heads=MANY_HEADS)
            _, ms, pipe = run_offline(NODE, sc)
            model = pipe.spec.errors(pipe.params, pipe.track, sc.vehicle)
            assert model.min_stddev == pytest.approx(max(np.hypot(params["head_position_sigma"],
                                                                  params["axle_offset_sigma"]), 1e-3))
            fixes = fixes_of(ms)
            assert [model.refusal(f) for f in fixes] == [None] * len(fixes)
            heads = _heads_passed(sc, params)
            assert [f.reference_id for f in fixes] == heads[::sign]
            total += len(fixes)
            expected += len(heads)
    assert total == expected >= 30


def test_forged_front_fixes_are_refused_with_their_reason():
    p = resolve_params(spec(NODE).params, {"first_axle_offset": 3.0, "axle_offsets": axles(), "orientation": 1})
    model = spec(NODE).errors(p, scenario().track, None)
    assert model.min_stddev == pytest.approx(np.hypot(0.02, 0.02))
    # orientation +1, front leading: head + the first axle's offset, or + the wheelbase (first axle missed)
    assert model.references.windows["AC01"] == pytest.approx((1803.0, 1805.5))
    assert set(model.references.windows) == {"AC00", "AC01", "AC02", "AC03"}
    # orientation auto and a known last axle: either orientation, the front leading or the train backing
    auto = spec(NODE).errors({**p, "orientation": 0, "last_axle_offset": axles()[-1]}, scenario().track, None)
    assert auto.references.windows["AC01"] == pytest.approx((1800.0 - 198.0, 1800.0 + 198.0))
    honest = PositionFix(10.0, "axle_counter", "axle_counter", "T1", "AC01", 1803.0, 0.03, 1)
    assert_forged_fixes_refused(model, honest, "AC09", 1805.5 + 300.0)
    # a head not of this evaluation unit is unknown to it
    unit = spec(NODE).errors({**p, "heads": "AC00,AC01"}, scenario().track, None)
    assert unit.refusal(dataclasses.replace(honest, reference_id="AC02", position=2603.0)).reason == "unknown_reference"
    zero = spec(NODE).errors({**p, "head_position_sigma": 0.0, "axle_offset_sigma": 0.0}, None, None)
    assert zero.min_stddev == pytest.approx(1e-3) and zero.references is None

"""Fault impact (core/fusion/impact.py): the filter's exact sensitivity to a persistent fault
of a relative sensor or to an offset shared by a run of fixes, the fault sizes the innovations
have not excluded, and the cover."""
from __future__ import annotations

import math

import numpy as np
import pytest

from train_localization.core.fusion import MODE_NOMINAL, FusionConfig, TrainFilter, impact, sensor_models
from train_localization.core.measurements import Acceleration, PositionFix, SpeedMeasurement
from train_localization.core.scenario import Vehicle


def _radar_and_balises(fault: float, balise_every: float = 400.0, until: float = 60.0, onset_spacing=3600.0,
                       moved: tuple | None = None, overrides: dict | None = None, onsets: int = 8,
                       states: list | None = None, seed: int = 3):
    """A train at 25 m/s, a Doppler radar at 20 Hz reading (1 + fault) x the speed from t = 0,
    balise fixes (1-sigma 0.4 m) every ``balise_every`` m; the filter started at 0 m at
    rest-free speed. ``moved`` = (c, first, count): the balise fixes first .. first + count - 1
    (0 = the first one) moved by c x their 1-sigma, the same way (a run sharing an offset).
    ``states``: (t, estimate, true position) appended every 0.2 s."""
    models = sensor_models(["doppler_radar", "eurobalise_reader"], None, Vehicle())
    f = TrainFilter(FusionConfig(sensors=models, fault_onset_spacing=onset_spacing, fault_onsets=onsets,
                                 overrides=overrides or {}))
    f.reset(position=0.0, position_stddev=0.5, speed=25.0, speed_stddev=0.1, stamp=0.0)
    rng = np.random.default_rng(seed)
    next_balise, n_fix = balise_every, 0
    for k in range(1, int(until * 20) + 1):
        t = k / 20.0
        s = 25.0 * t
        f.add(SpeedMeasurement(t, "doppler", "d", 25.0 * (1.0 + fault) + float(rng.normal(0, 0.05)), 0.3))
        if s >= next_balise:
            shift = moved[0] * 0.4 if moved is not None and moved[1] <= n_fix < moved[1] + moved[2] else 0.0
            f.add(PositionFix(t, "eurobalise", "b", "T", f"EB{int(s)}",
                              next_balise + float(rng.normal(0, 0.3)) + shift, 0.4))
            next_balise += balise_every
            n_fix += 1
        if states is not None and k % 4 == 0:
            states.append((t, f.estimate(t), s))
    return f


def test_the_impact_is_the_filters_own_sensitivity_to_the_fault():
    """Run twice, with and without a 0.2 % radar scale fault (too small for any check to act):
    the difference of the states is the fault times the impact vector (the filter is linear in
    what it takes in; the scale x speed product makes it so to first order)."""
    fault = 0.002
    clean, faulty = _radar_and_balises(0.0), _radar_and_balises(fault)
    x0, _, aux0 = clean.state()
    x1, _, aux1 = faulty.state()
    assert aux0.events == aux1.events and aux0.gated == aux1.gated   # the same decisions
    (imp,) = tuple(i for i in aux1.impacts if not i.offset)         # one radar onset: at the start
    assert imp.sensor == "doppler" and imp.onset == pytest.approx(0.05)
    np.testing.assert_allclose((x1 - x0)[:2] / fault, imp.e[:2], rtol=0.02, atol=1e-3)
    # the fixes have told it: the fault estimate is about right, and its 1-sigma small
    assert abs(imp.score / imp.info - fault) < 3.0 / math.sqrt(imp.info)


def test_a_fault_no_reading_can_test_is_covered_up_to_its_size():
    """A lone radar between balises 2 km apart: nothing tests its scale fault but the fixes, so
    just before a fix the cover is near |e_0| x z x scale_fault_sigma; the data excludes large
    faults only as the fixes come."""
    f = _radar_and_balises(0.0, balise_every=2000.0, until=79.0, onset_spacing=5.0)
    est = f.estimate(79.0)
    bound = f.limits.fault_bounds["doppler"]
    assert bound == pytest.approx(f.limits.z * f.models["doppler"].scale_fault_sigma)
    _, _, aux = f.state()
    newest = max(aux.impacts, key=lambda imp: imp.onset)
    assert newest.excluded_beyond(bound, f.limits.z) == pytest.approx(bound, rel=0.2)
    x, P, _ = f.state()
    half_s, _ = impact.cover(aux.impacts, 79.0 - aux.t, f.limits.z, P[0, 0], P[1, 1])
    assert half_s > f.limits.z * math.sqrt(P[0, 0]) and est.position_max - est.position >= half_s - 1e-9
    assert len([imp for imp in aux.impacts if imp.sensor == "doppler"]) == f.cfg.fault_onsets


def test_each_onset_also_ends_the_fault_that_matters_most_and_a_full_bank_drops_the_least():
    n, bounds = 4, {"doppler": 0.1}
    bank = impact.started(None, bounds, 0.0, n, 4, 3.0)
    assert [(imp.onset, imp.active) for imp in bank] == [(0.0, True)]     # nothing to end yet
    bank = bank._replace(E=np.array([[10.0, 1.0, 0, 0]]))
    bank = impact.started(bank, bounds, 5.0, n, 4, 3.0)
    assert [(imp.onset, imp.active) for imp in bank] == [(0.0, True), (0.0, False), (5.0, True)]
    np.testing.assert_array_equal(bank[1].e, bank[0].e)                    # the same error, ended at 5 s
    # an ended fault's sensor reads right: its readings add nothing, they test what it left
    h, K = np.array([0.0, 0.05, 0.0, 0.0]), np.array([0.0, 0.5, 0.0, 0.0])
    after = impact.updated(bank, impact.FaultInput("doppler", 20.0, True), h, K, 0.0, 0.01)
    assert after[0].e[1] == pytest.approx(1.0 + 0.5 * (20.0 - 0.05))      # going on: its fault comes in
    assert after[1].e[1] == pytest.approx(1.0 - 0.5 * 0.05)                # ended: only corrected
    assert after[1].info == pytest.approx(0.05 ** 2 / 0.01) and not after[1].active
    unchecked = impact.updated(bank, impact.FaultInput("doppler", 20.0, False), h, K, 0.0, 0.01)
    assert unchecked[1].info == 0.0           # against the motion model alone its end tests nothing
    # a full bank: the newest active one stays, the smallest cover of the rest goes
    bank = bank._replace(E=np.array([[10.0, 0, 0, 0], [3.0, 0, 0, 0], [0.0, 0, 0, 0]]))
    bank = impact.started(bank, bounds, 10.0, n, 4, 3.0)                   # + (0, ended at 10), (10)
    assert [(imp.onset, imp.active) for imp in bank] == [(0.0, True), (0.0, False), (0.0, False), (10.0, True)]
    assert [float(imp.e[0]) for imp in bank] == [10.0, 3.0, 10.0, 0.0]    # (5.0, active, e 0) dropped


def test_the_innovations_exclude_fault_sizes_as_a_least_squares_fit():
    """Another sensor's readings whose innovations match g x f_true: the estimate is f_true, its
    1-sigma 1 / sqrt(sum g^2 / S); the faulty sensor's own readings test it only while another
    speed source in use checks them."""
    bank = impact.started(None, {"doppler": 1.0}, 0.0, 3, 4, 3.0)
    h, K = np.array([0.0, 1.0, 0.0]), np.zeros(3)   # K = 0: e stays
    for v in (10.0, 20.0, 30.0):                    # a unit fault has put v / 10 into the speed:
        bank = bank._replace(E=np.array([[0.0, v / 10.0, 0.0]]))   # another sensor's g = -v / 10
        bank = impact.updated(bank, impact.FaultInput("wheel", 0.0, True), h, K, -0.05 * v / 10.0, 0.04)
    own = impact.updated(bank, impact.FaultInput("doppler", 30.0, False), h, K, 1.5, 0.04)   # only the motion model checks it
    assert own[0].info == bank[0].info and own[0].score == bank[0].score
    checked = impact.updated(bank, impact.FaultInput("doppler", 30.0, True), h, K, 1.5, 0.04)   # the wheel in use checks it
    assert checked[0].info == pytest.approx(bank[0].info + (30.0 - 3.0) ** 2 / 0.04)
    imp = bank[0]
    assert imp.score / imp.info == pytest.approx(0.05)
    assert imp.info == pytest.approx((1 + 4 + 9) / 0.04)
    assert imp.fault(1.0, 3.0) == pytest.approx((0.05, 1.0 / math.sqrt(imp.info)))
    assert imp.excluded_beyond(1.0, 3.0) == pytest.approx(0.05 + 3.0 / math.sqrt(imp.info))
    assert imp.fault(0.03, 3.0) == pytest.approx((0.03, 0.01))    # within the sensor's bound
    assert imp.excluded_beyond(0.03, 3.0) == 0.03


def test_the_offset_impact_is_the_filters_own_sensitivity_to_a_run_of_offset_fixes():
    """Run twice, with and without the balise fixes 2, 3 and 4 moved by 0.5 of their 1-sigma
    (too little for any check to act): the difference of the states is 0.5 times the impact
    vector of the offset hypothesis that began at fix 2 (its onset: that fix's stamp)."""
    clean = _radar_and_balises(0.0, until=70.0, onset_spacing=1.0, onsets=24)
    moved = _radar_and_balises(0.0, until=70.0, onset_spacing=1.0, onsets=24, moved=(0.5, 1, 3))
    x0, _, aux0 = clean.state()
    x1, _, aux1 = moved.state()
    assert aux0.events == aux1.events and aux0.gated == aux1.gated   # the same decisions
    (imp,) = [i for i in aux1.impacts if i.offset and i.active and i.onset == pytest.approx(32.0)]
    assert imp.sensor == "eurobalise" and moved.limits.offset_bounds["eurobalise"] == pytest.approx(3.8906, abs=1e-4)
    np.testing.assert_allclose((x1 - x0)[:2] / 0.5, imp.e[:2], rtol=0.02, atol=1e-3)
    # per unit: about the fix's 1-sigma (0.4 m), and what the radar scale it mis-calibrated added since
    assert 0.3 < imp.e[0] < 0.5


def test_a_run_of_fixes_sharing_an_offset_within_the_gate_is_covered_whatever_its_size_and_place():
    """40 drawn runs: a run of 1-8 balise fixes (one every 200 m) moved by up to the gate's radius
    (3.89 of their 1-sigma) either way, from a drawn fix on. The radar's model has no scale fault
    here, so that no other cover hides this one. With the offset hypothesis the truth is inside in
    every state; the same filter whose balise model lacks it is confidently wrong in some runs.
    The cover costs width: nothing but the jump at a run's first fix tests an offset, against the
    dead reckoning, so it is covered up to the gate's radius (3.89 of the fix's 1-sigma times the
    state's sensitivity to it, on top of the filter's own 3.29 sigma): the mean width is at most
    twice the model's without it."""
    with_offset = {"doppler": {"faults": []}}
    plain = {"doppler": {"faults": []}, "eurobalise": {"faults": ["misread"]}}
    rng = np.random.default_rng(11)
    runs_outside_plain, ratios = 0, []
    for run in range(40):
        moved = (float(rng.uniform(-3.85, 3.85)), int(rng.integers(0, 6)), int(rng.integers(1, 9)))
        covered, uncovered = [], []
        _radar_and_balises(0.0, balise_every=200.0, until=70.0, onset_spacing=5.0, moved=moved,
                           states=covered, seed=run, overrides=with_offset)
        _radar_and_balises(0.0, balise_every=200.0, until=70.0, onset_spacing=5.0, moved=moved,
                           states=uncovered, seed=run, overrides=plain)
        assert all(e.position_min <= s <= e.position_max for _, e, s in covered), (run, moved)
        runs_outside_plain += any(not e.position_min <= s <= e.position_max for _, e, s in uncovered)
        ratios.append(np.mean([e.position_max - e.position_min for _, e, _ in covered]) /
                      np.mean([e.position_max - e.position_min for _, e, _ in uncovered]))
    assert runs_outside_plain >= 10
    assert 1.0 < min(ratios) and max(ratios) < 2.0


def test_a_run_of_lzb_fixes_sharing_an_offset_beyond_the_survey_prior_is_covered():
    """Campaign run lzb:296076971 of seed 0: 4 LZB fixes 3.3 sigma off from 96 s. The loop's
    survey state (0.05 m a priori) could not hold it: 79 states outside while NOMINAL (99.64 %)
    until the LZB declared the ``offset`` mode like the other fix sensors; now every state is
    inside, the mean width 50.4 -> 50.5 m."""
    from train_localization.core import campaign
    from train_localization.core.sensors import lzb
    assert "offset" in lzb.error_model(dict(survey_sigma=0.05, **{k: p.default for k, p in lzb.PARAMS.items()
                                                                   if k != "survey_sigma"}), None, None).faults
    run = campaign.run_one("lzb", 296076971)
    assert run["conditions"]["adversarial"]["kind"] == "offset" and run["conditions"]["adversarial"]["sensor"] == "lzb"
    assert run["scores"]["integrity"]["outside_count"] == 0


SLIP_RUN = 45.0   # simulated seconds of network:4262354916: its DGPS outage ends at 24.1 s, the excursion at 26.6 s


def test_a_slip_no_other_source_could_see_is_covered_through_the_fixes_that_follow():
    """Campaign run network:4262354916 (seed 0 of ``--families network``): a wheel slipping 2 % for
    7.4 s under traction while the radar's readings are lost for 2.9 s and then disagree, and the
    DGPS has no corrections for 14 s. The slip test, its reference the motion model since the radar
    fell silent, took the wheel back at a large gain; the filter ran 2.4 m ahead, and took the
    first differential fixes' disagreement for their multipath bias: 140 states outside while
    NOMINAL (98.38 %), all from 24.9 s (its first ``SLIP_RUN`` s hold them). The unseen slip's
    cover (the filter's own sensitivity to what the tests let pass, ``transient`` rows) keeps
    every NOMINAL state inside; without it (``FusionConfig.policies`` without
    ``transient_fault_cover``) the run fails again."""
    from train_localization.core import campaign
    from train_localization.core.fusion.config import POLICIES
    covered = campaign.run_one("network", 4262354916, max_duration=SLIP_RUN)
    assert covered["conditions"]["dgps_faults"].endswith("nocorr") and covered["conditions"]["slip_rate"] > 0.1
    assert covered["scores"]["integrity"]["outside_nominal"] == 0
    assert covered["scores"]["integrity"]["inside_fraction"] >= 0.995
    data = campaign.generate("network", 4262354916, SLIP_RUN)
    data["fusion"] = {**data["fusion"], "policies": frozenset(POLICIES) - {"transient_fault_cover"}}
    before = campaign.run_scenario(data)
    assert before["scores"]["integrity"]["outside_nominal"] > 50


def _radar_gap_run(accel: float) -> dict[int, float]:
    """A train from 10 m/s accelerating at ``accel`` [m/s^2], its wheel and radar reading every 50
    ms, the radar silent from 20 to 24 s, one balise fix at 35 s; the wheel's slip bound 10 %.
    Returns second -> the cover of its unseen slips, |e_0| x slip_ratio_max [m] (the largest row)."""
    from train_localization.core.measurements import DistanceIncrement
    models = sensor_models({"doppler_radar": {}, "wheel_sensor": {"slip_ratio_max": 0.1}, "eurobalise_reader": {}},
                           None, Vehicle())
    f = TrainFilter(FusionConfig(sensors=models))
    f.reset(position=0.0, position_stddev=0.1, speed=10.0, speed_stddev=0.1, stamp=0.0)
    rng = np.random.default_rng(2)
    s, v, covers = 0.0, 10.0, {}
    for j in range(1, 761):
        t = j * 0.05
        v_old = v
        v += accel * 0.05
        s += 0.5 * (v + v_old) * 0.05
        if not 20.0 <= t < 24.0:
            f.add(SpeedMeasurement(t - 0.025, "doppler", "doppler", v + rng.normal(0, 0.03), 0.1))
        f.add(DistanceIncrement(t, "wheel", "wheel", 0.05, 0.5 * (v + v_old) * 0.05 + rng.normal(0, 0.002), 0.005,
                                v, 0.6))
        if j == 700:
            f.add(PositionFix(t, "eurobalise", "eb", "T", "EB1", s + rng.normal(0, 0.3), 0.3))
        if j % 20 == 0:
            _, _, aux = f.state()
            bank = aux.impacts
            covers[round(t)] = max((abs(float(bank.E[k, 0])) * float(bank.bounds[k]) for k in range(len(bank))
                                    if bank.transient[k]), default=0.0)
    return covers


def test_an_unseen_slip_is_carried_only_while_no_other_source_sees_the_wheel():
    """While the radar reads beside the wheel, a slip shows as a disagreement: the cover of an
    unseen one stays within a few decimetres. While the radar is silent (20-24 s, about 85 m
    under traction) nothing but the motion model sees the wheel: the cover grows to what a slip
    of the wheel's bound could have put in, stays when the radar comes back (a speed source tells
    the motion from then on, not the distance already run), and a balise fix takes it out. A
    train that is neither driven nor braked (``slip_min_drive``) does not slip: nothing to cover."""
    driven = _radar_gap_run(0.5)
    assert max(c for t, c in driven.items() if t <= 20) < 0.5
    assert driven[24] > 0.4 * 0.1 * 85.0
    assert min(c for t, c in driven.items() if 25 <= t <= 34) > 0.4 * 0.1 * 85.0
    assert driven[36] < 0.2 * driven[34]
    coasting = _radar_gap_run(0.0)
    assert max(coasting.values()) < 0.5


def test_a_ramp_on_inpo_fixes_is_covered_by_the_offset_mode():
    """Campaign run highspeed_maglev:3387733988: 20 INPO fixes moved by an offset growing from
    nothing to 3.99 of their 1-sigma (the adversarial ``ramp``) from 26.4 s. The crossed loops'
    fixes are centimetre-precise and the filter's interval was as narrow: 13 states outside
    while NOMINAL until INPO declared the ``offset`` mode; now none, the interval covering the
    run's offset within the gate's radius."""
    from train_localization.core import campaign
    from train_localization.core.sensors import inpo
    assert "offset" in inpo.error_model({k: p.default for k, p in inpo.PARAMS.items()}, None, None).faults
    run = campaign.run_one("highspeed_maglev", 3387733988, max_duration=32.0)
    attack = run["conditions"]["adversarial"]
    assert (attack["kind"], attack["sensor"]) == ("ramp", "inpo") and attack["offset"] > 3.89
    assert run["scores"]["integrity"]["outside_count"] == 0


def test_a_common_cause_group_is_one_hypothesis_whose_members_readings_carry_it_and_do_not_test_it():
    """A wheel and a radar on one wet or snowy track (their error models' common cause
    ``track_surface``) are one fault hypothesis while ``common_cause_prior`` exceeds the risk the
    interval leaves: both readings carry the same scale error (delta = their speed), up to the
    smaller of their bounds (the wheel's slip_ratio_max, the radar's z x scale_fault_sigma). The
    members' readings test it only beside a speed source outside the group; a fix tests it."""
    from train_localization.core.fusion.limits import common_cause_groups
    models = sensor_models({"wheel_sensor": {"slip_ratio_max": 0.12}, "doppler_radar": {}}, None, Vehicle())
    cfg = FusionConfig(sensors=models, common_cause_prior=0.01)
    members, bounds = common_cause_groups(cfg, 3.29)
    assert members == {"doppler+wheel": frozenset({"doppler", "wheel"})}
    assert bounds == {"doppler+wheel": pytest.approx(min(0.12, 3.29 * models["doppler"].scale_fault_sigma))}
    assert common_cause_groups(FusionConfig(sensors=models), 3.29) == ({}, {})   # 1e-4 by default: not monitored
    bank = impact.started(None, bounds, 0.0, 3, 4, 3.29, members=members)
    assert list(bank.of("wheel")) == list(bank.of("doppler")) == [True] and not bank.of("eurobalise").any()
    h, K = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.5, 0.0])
    wheel = impact.updated(bank, impact.FaultInput("wheel", 20.0, True, frozenset({"doppler"}), relative=True),
                           h, K, 0.0, 0.01)
    assert wheel[0].e[1] == pytest.approx(0.5 * 20.0) and wheel[0].info == 0.0   # carried, not tested
    beside = impact.updated(bank, impact.FaultInput("wheel", 20.0, True, frozenset({"doppler", "lrl"}),
                                                    relative=True), h, K, 0.0, 0.01)
    assert beside[0].info == pytest.approx(20.0 ** 2 / 0.01)                     # a non-member checks it
    fix = impact.updated(wheel, impact.FaultInput("eurobalise", 0.0, True), np.array([1.0, 0.0, 0.0]),
                         np.zeros(3), 0.0, 1.0)
    assert fix[0].info == 0.0 and fix[0].e[0] == 0.0   # no position error yet: nothing for a fix to see


def test_a_low_adhesion_stretch_with_a_radar_reading_off_is_covered_as_one_fault():
    """Campaign run conventional:1045080295 (drawn without an accelerometer): on a wet stretch the
    wheel slips a third of the time and the radar reads 4.8 % high from 21.5 s, before the
    first fix (41.6 s); the two agree, so each one's readings passed the other's fault as
    tested: 76 states outside while NOMINAL (the default, ``common_cause_prior`` 1e-4: the group
    is not monitored). With the prior at 0.01 the two are one fault, which only the fixes test,
    and every state is inside."""
    from train_localization.core import campaign
    data = campaign.generate("conventional", 1045080295, max_duration=60.0)
    assert "low_adhesion" in data["campaign"]["conditions"]["common_cause"]
    assert not data["campaign"]["conditions"]["accelerometer"]
    data["fusion"] = {**data["fusion"], "common_cause_prior": 0.01}
    run = campaign.run_scenario(data)
    assert run["scores"]["integrity"]["outside_count"] == 0


def test_a_common_cause_that_began_before_the_first_fix_is_covered_beside_an_accelerometer():
    """The same run with an accelerometer: it checks the members' readings (a step or ramp of
    their common scale error is an acceleration it does not measure), but this fault began before
    the first fix, so the readings after it show no change. The group's first row is therefore a
    fault that may have begun before (``impact.begun_before``: the speed the filter learnt from
    the members carries it); as a step at the first fix the check took it for excluded and
    2,268 states were outside (DEGRADED) from 42.2 s to 53.5 s."""
    from train_localization.core import campaign
    data = campaign.generate("conventional", 1045080295, max_duration=60.0)
    data["sensors"]["accelerometer"] = {}
    data["fusion"] = {**data["fusion"], "common_cause_prior": 0.01}
    run = campaign.run_scenario(data)
    assert run["fusion"]["accepted"]["accelerometer"] > 1000
    assert run["scores"]["integrity"]["outside_count"] == 0


def _lone_radar_with_accelerometer(fault_at: float | None, accelerometer: bool, until: float = 79.0,
                                   fault: float = 0.03) -> tuple[TrainFilter, list]:
    """A train at a steady 25 m/s, a lone Doppler radar at 20 Hz, balise fixes every 2 km, and
    with ``accelerometer`` a longitudinal accelerometer at 20 Hz reading 0 (1-sigma 0.02 m/s^2);
    from ``fault_at`` [s] the radar reads ``fault`` high (a scale fault's step). Returns the
    filter and the (t, estimate, true position) of every 0.2 s."""
    names = ["doppler_radar", "eurobalise_reader"] + (["accelerometer"] if accelerometer else [])
    f = TrainFilter(FusionConfig(sensors=sensor_models(names, None, Vehicle()), fault_onset_spacing=5.0))
    f.reset(position=0.0, position_stddev=0.5, speed=25.0, speed_stddev=0.1, stamp=0.0)
    rng, states, next_balise = np.random.default_rng(5), [], 2000.0
    for k in range(1, int(until * 20) + 1):
        t, s = k / 20.0, 25.0 * k / 20.0
        scale = 1.0 + (fault if fault_at is not None and t >= fault_at else 0.0)
        f.add(SpeedMeasurement(t, "doppler", "d", 25.0 * scale + float(rng.normal(0, 0.05)), 0.3))
        if accelerometer:
            f.add(Acceleration(t, "accelerometer", "a", float(rng.normal(0, 0.02)), 0.02))
        if s >= next_balise:
            f.add(PositionFix(t, "eurobalise", "b", "T", f"EB{int(s)}", next_balise + float(rng.normal(0, 0.3)), 0.4))
            next_balise += 2000.0
        if k % 4 == 0:
            states.append((t, f.estimate(t), s))
    return f, states


def test_an_accelerometer_checks_a_lone_radar_so_its_untested_faults_shrink():
    """Between balises 2 km apart nothing but the fixes tests a lone radar's scale fault (the
    test above); with an accelerometer every radar reading tests it too: a step shows as a change
    of speed that no measured acceleration explains. The newest onset's fault the data has not
    excluded falls from about the bound to a small part of it, and the bank's cover with it (the
    lone-source solution, the motion model without the radar, still covers a ramp that the
    accelerometer's bias state could take up: core/fusion/lone.py)."""
    alone, _ = _lone_radar_with_accelerometer(None, accelerometer=False)
    checked, _ = _lone_radar_with_accelerometer(None, accelerometer=True)
    bound = alone.limits.fault_bounds["doppler"]
    z = alone.limits.z
    newest = {name: max(f.state()[2].impacts, key=lambda imp: imp.onset)
              for name, f in (("alone", alone), ("checked", checked))}
    assert newest["alone"].excluded_beyond(bound, z) == pytest.approx(bound, rel=0.2)
    assert newest["checked"].excluded_beyond(bound, z) < 0.25 * bound
    cover = {}
    for name, f in (("alone", alone), ("checked", checked)):
        _, P, aux = f.state()
        cover[name] = impact.cover(aux.impacts, 79.0 - aux.t, z, P[0, 0], P[1, 1])[0]
    assert cover["checked"] < 0.5 * cover["alone"]


def test_a_radar_scale_step_between_fixes_stays_covered_with_the_accelerometer_checking_it():
    """The same train, the radar 3 % high from 30 s (between the balises at 2,000 m and 4,000 m):
    the filter follows the radar until a fix, but the interval holds the truth in every state
    (the fault's step is what the accelerometer's check measures, not what it hides)."""
    f, states = _lone_radar_with_accelerometer(30.0, accelerometer=True)
    outside = [(t, est.position_min, s, est.position_max) for t, est, s in states
               if math.isfinite(est.position) and not est.position_min <= s <= est.position_max]
    assert not outside
    assert max(abs(est.position - s) for t, est, s in states if 30.0 < t < 80.0) > 5.0   # the fault did move it


def test_the_cover_leaves_out_the_scale_faults_another_cover_holds():
    """``impact.cover`` with ``left_to`` (sensor, since): that sensor's own scale-fault rows that
    began after ``since`` are left out; its earlier rows, and other sensors' rows, stay."""
    n, z = 4, 3.0
    bank = impact.started(None, {"doppler": 0.1, "wheel": 0.1}, 1.0, n, 8, z)
    bank = impact.started(bank, {"doppler": 0.1}, 5.0, n, 8, z)
    # what each row's fault put into the position per unit fault
    bank = bank._replace(E=np.array([[10.0, 0, 0, 0], [20.0, 0, 0, 0], [40.0, 0, 0, 0]]))
    assert [(row.sensor, row.onset) for row in bank] == [("doppler", 1.0), ("wheel", 1.0), ("doppler", 5.0)]
    untested = 0.1 / z   # the fault's 1-sigma while nothing has tested it: bound / z

    def half(left_to=None):
        return impact.cover(bank, 0.0, z, 0.0, 0.0, left_to)[0]
    assert half() == pytest.approx(z * 40.0 * untested)
    assert half(impact.LeftTo("doppler", 2.0)) == pytest.approx(z * 20.0 * untested)   # the wheel's row
    assert half(impact.LeftTo("doppler", 0.5)) == pytest.approx(z * 20.0 * untested)
    assert half(impact.LeftTo("wheel", 0.5)) == pytest.approx(z * 40.0 * untested)
    assert half(impact.LeftTo("doppler", 5.0)) == pytest.approx(z * 40.0 * untested)   # began at, not after


def _fast_lone_radar(fault: float, until: float = 40.0) -> tuple[TrainFilter, list]:
    """A maglev at a steady 100 m/s, a lone Doppler radar at 20 Hz, a position fix (1-sigma
    0.1 m) every 100 m but none from 2,000 m to 3,000 m (10 s); from 21 s the radar reads
    ``fault`` high (a scale fault's step after the last fix before the gap). Returns the
    filter at ``until`` [s] and the (t, estimate, true position) of every 0.2 s."""
    f = TrainFilter(FusionConfig(sensors=sensor_models(["doppler_radar", "eurobalise_reader"], None, Vehicle()),
                                 fault_onset_spacing=5.0))
    f.reset(position=0.0, position_stddev=0.5, speed=100.0, speed_stddev=0.1, stamp=0.0)
    rng, states = np.random.default_rng(7), []
    for k in range(1, int(until * 20) + 1):
        t, s = k / 20.0, 100.0 * k / 20.0
        scale = 1.0 + (fault if t >= 21.0 else 0.0)
        f.add(SpeedMeasurement(t, "doppler", "d", 100.0 * scale + float(rng.normal(0, 0.05)), 0.3))
        if k % 20 == 0 and not 2000.0 < s < 3000.0:
            f.add(PositionFix(t, "eurobalise", "b", "T", f"EB{int(s)}", s + float(rng.normal(0, 0.1)), 0.1))
        if k % 4 == 0:
            states.append((t, f.estimate(t), s))
    return f, states
    return f, states


def test_a_lone_radars_faults_since_its_solution_began_are_held_by_that_solution_alone():
    """A lone radar through a 10 s gap between fixes at 100 m/s: a scale fault that began after
    the solution without the radar did (the motion model, conditioned on the fixes, lone.py) is
    one that solution holds, so the bank's rows of such onsets are left to it. 8 s into the gap
    the interval is that solution's, 58 m half-wide, not the 100 m those rows need (z x the
    fault's untested 1-sigma x the distance since their onset; the earlier rows, tested by the
    fixes, need 10 m). A 2 % or 5 % scale step at 21 s, just after the last fix before the gap,
    stays inside in every state."""
    t = 28.0
    f, states = _fast_lone_radar(0.0, until=t)
    x, P, aux = f.state()
    z = f.limits.z
    assert aux.lone_view is not None and aux.lone_view.sensor == "doppler" and aux.lone_view.since < 1.0
    full = impact.cover(aux.impacts, t - aux.t, z, P[0, 0], P[1, 1])[0]
    left = impact.cover(aux.impacts, t - aux.t, z, P[0, 0], P[1, 1], impact.LeftTo("doppler", aux.lone_view.since))[0]
    _, est, s = states[-1]
    half = 0.5 * (est.position_max - est.position_min)
    assert est.stamp == pytest.approx(t) and est.mode == MODE_NOMINAL
    assert left < 0.2 * full and left < half < 0.7 * full
    for fault in (0.02, -0.05):
        _, states = _fast_lone_radar(fault)
        assert all(e.position_min <= s <= e.position_max for _, e, s in states)
        assert max(abs(e.position - s) for _, e, s in states) > 15.0   # the fault did move it

"""The seed 003 round experimental unit: loop field (eq. 1-4), resonance, antennas at p/3, the
21 cm adder, the closed track, the disc dynamics and the PID speed control through the fusion."""
import functools
import math

import numpy as np
import pytest

from train_localization.core.control import SpeedController, control_config, step_response
from train_localization.core.offline import closed_loop
from train_localization.core.dynamics import Dynamics
from train_localization.core.pipeline import simulate_and_decode
from train_localization.core.scenario import Scenario, ScenarioError
from train_localization.core.scoring import StateSeries, score
from train_localization.core.sensors import rig_loop
from train_localization.core.sensors.base import resolve_params
from train_localization.core.sensors.pattern_belt import rectangle_bz
from train_localization.core.track import Track
from train_localization.tools.rig import noisier

from conftest import ROOT
from error_model_checks import assert_refused_below_half_the_floor, decoded, floor_runs, lasting

CLOSED = ROOT / "config" / "scenario_rig.yaml"
OPEN = ROOT / "config" / "scenario_rig_open.yaml"
P = resolve_params(rig_loop.PARAMS, {})


@functools.lru_cache(maxsize=None)
def _open_run():
    return simulate_and_decode("rig_loop_receiver", Scenario.from_yaml(OPEN))


@functools.lru_cache(maxsize=None)
def _closed_run(noise: float = 1.0):
    sc = Scenario.from_yaml(CLOSED)
    return sc, closed_loop(noisier(sc, noise) if noise != 1.0 else sc)


# --------------------------------------------------------------------------- seed numbers
def test_loop_tuning_resonates_at_the_190_khz_carrier():
    f0 = rig_loop.resonance_frequency(P["loop_inductance"], P["tuning_capacitance"])  # 11.14 uH, 0.062 uF
    assert f0 == pytest.approx(191.5e3, rel=1e-3)
    assert abs(f0 / P["carrier_frequency"] - 1.0) < 0.01     # seed 003 section 3.1: 190 kHz


def _biot_savart_bz(points, wire_from, wire_to, n=20000):
    """B_z [T] per ampere of a straight wire, eq. 1 integrated numerically (midpoint rule)."""
    a, b = np.asarray(wire_from, float), np.asarray(wire_to, float)
    s = (np.arange(n) + 0.5) / n
    src = a + s[:, None] * (b - a)
    dl = (b - a) / n
    out = []
    for p in points:
        r = p - src
        cross_z = dl[0] * r[:, 1] - dl[1] * r[:, 0]
        out.append(1e-7 * np.sum(cross_z / np.linalg.norm(r, axis=1) ** 3))
    return np.array(out)


def test_eq2_is_the_biot_savart_field_of_the_long_sides():
    l, b, z = 0.1575, 0.04, 0.02
    pts = np.array([[0.0, 0.0, z], [0.1, 0.03, z], [-0.2, -0.05, 0.01], [0.3, 0.0, 0.05]])
    # the long sides of a counter-clockwise rectangle: +x at y = -b, -x at y = +b
    numeric = (_biot_savart_bz(pts, (-l, -b, 0), (l, -b, 0)) + _biot_savart_bz(pts, (l, b, 0), (-l, b, 0)))
    eq2 = rig_loop.eq2_bz(pts[:, 0], pts[:, 1], pts[:, 2], l, b)
    np.testing.assert_allclose(eq2, numeric, rtol=1e-4)
    # the simulator's field (pattern_belt.rectangle_bz) is eq. 2 plus the same for the short sides
    full = 1e-7 * rectangle_bz(pts[:, 0], pts[:, 1], pts[:, 2], 0.0, l, b)
    short = rig_loop.eq2_bz(pts[:, 1], pts[:, 0], pts[:, 2], b, l)
    np.testing.assert_allclose(full, eq2 + short, rtol=1e-9)


def test_induced_voltage_along_the_loop_eq3_eq4():
    x, psi = rig_loop.flux_profile(P)
    p = P["period"]
    assert x[-1] < p and p == pytest.approx(0.63)
    wide = (x > 0.1 * p) & (x < 0.4 * p)          # antenna over a wide part
    narrow = (x > 0.6 * p) & (x < 0.9 * p)        # over a narrow part: the two wires' fields cancel
    assert psi[wide].min() > 8 * np.abs(psi[narrow]).max()
    # eq. 4: V = -dpsi/dx dx/dt, linear in the speed, an odd function about the middle of a wide part
    v = 100 / 3.6
    _, vm = rig_loop.motional_voltage(P, v)
    _, vm2 = rig_loop.motional_voltage(P, 2 * v)
    np.testing.assert_allclose(vm2, 2 * vm)
    k = np.argmin(np.abs(x - 0.1 * p))
    assert vm[k] == pytest.approx(-(psi[k + 1] - psi[k - 1]) / (x[k + 1] - x[k - 1]) * v)
    # at the rig's top speed the motional term is far below the carrier's transformer EMF
    omega = 2 * math.pi * P["carrier_frequency"]
    assert np.abs(vm).max() < 1e-3 * omega * np.abs(psi).max()
    _, env = rig_loop.envelope(P, v)
    np.testing.assert_allclose(env, omega * np.abs(psi), rtol=1e-6, atol=1e-3 * env.max())


def test_schmitt_thresholds_straddle_the_half_duty_level():
    """Even p/6 states (an adder of 50 % duty) need the switching level where an antenna is high
    half of the period."""
    level = rig_loop.half_duty_level(P)
    assert P["threshold_off"] < level < P["threshold_on"]
    assert 0.5 * (P["threshold_on"] + P["threshold_off"]) == pytest.approx(level, abs=0.01)


def test_three_antennas_a_third_of_the_period_apart_and_the_21_cm_adder():
    run = _open_run()
    traj = run.trajectory
    # the hold at 55 km/h: the three envelopes are the same wave shifted by p/3 in distance
    hold = [b for b in run.blocks if 5.6 < b.t0 < 7.2]
    data = np.vstack([b.data for b in hold])
    t = np.concatenate([b.times() for b in hold])
    s = np.interp(t, traj.t, traj.position)
    grid = np.arange(s[0], s[-1], 0.002)
    ch = [np.interp(grid, s, data[:, k]) for k in range(3)]
    for k in (1, 2):
        corr = np.correlate(ch[k] - ch[k].mean(), ch[0][: grid.size - 315] - ch[0].mean(), "valid")[:315]
        shift = int(np.argmax(corr)) * 0.002
        assert shift == pytest.approx(k * P["period"] / 3, abs=0.01)      # seed 003 section 2
    # the adder output: one rising edge per 21 cm (seed 003 section 4.1)
    dec = run.pipe.decoder
    travelled = traj.position[-1] - traj.position[0]
    assert travelled / dec.stats["adder_edges"] == pytest.approx(rig_loop.ADDER_PERIOD, rel=0.005)
    assert dec.stats["invalid_states"] == 0 and dec.stats["illegal_transitions"] == 0


def test_count_follows_the_disc_round_and_round():
    run = _open_run()
    traj = run.trajectory
    assert traj.position[-1] > 50 * 3.15            # more than 50 turns of the closed loop
    t = np.array([m.stamp for m in run.measurements])
    counted = np.cumsum([m.distance for m in run.measurements])
    err = counted - np.interp(t, traj.t, traj.position)
    assert np.abs(err).max() <= P["period"] / 6 + 0.01   # within one p/6 state, never drifting


def test_fv_converter_gives_the_speed():
    sc = Scenario.from_yaml(OPEN)
    run = simulate_and_decode("rig_loop_receiver", sc, t_end=7.0)
    v_true = run.trajectory.state_at(7.0).speed
    assert v_true == pytest.approx(15.28, abs=0.01)
    # the F/V output at a steady speed: the mean of the RC output, within one pulse's ripple
    fv = run.pipe.decoder.stats["fv_speed"]
    ripple = P["period"] / 3 / P["fv_time_constant"]
    assert abs(fv - v_true) < 0.5 * ripple


def test_a_stuck_antenna_is_refused():
    run = _open_run()
    from train_localization.core.pipeline import SensorPipeline
    from train_localization.core.sensors import spec
    from train_localization.core.signals import InputRejected, RawBlock
    sc = Scenario.from_yaml(OPEN)
    pipe = SensorPipeline(spec("rig_loop_receiver"), sc.sensors["rig_loop_receiver"], sc.track, sc.vehicle,
                          simulate=False)
    for b in run.blocks[:400]:
        pipe.on_block(b)
    b = run.blocks[400]
    data = b.data.copy()
    data[:, :] = 2.0                                   # every antenna high: the adder cannot sum to 3
    bad = RawBlock.from_samples(b.sensor, b.unit_id, b.seq, b.t0, b.sample_rate, b.channels, b.units, data)
    with pytest.raises(InputRejected):
        pipe.on_block(bad)


# --------------------------------------------------------------------------- closed track
def test_closed_track_wraps_and_open_tracks_do_not():
    ring = Track.from_yaml(ROOT / "config" / "track_rig.yaml")
    assert ring.closed and ring.length == pytest.approx(15 * rig_loop.ADDER_PERIOD)
    assert ring.wrap(3.15 * 7 + 0.4) == pytest.approx(0.4)
    assert ring.difference(0.1, 3.1) == pytest.approx(0.15)
    assert ring.difference(3.1, 0.1) == pytest.approx(-0.15)
    assert ring.pose(0.5 + 3.15 * 3) == pytest.approx(ring.pose(0.5))
    x, y = ring.xy(np.linspace(0.0, 3.15, 50))                  # the map pose runs round the loop
    np.testing.assert_allclose(np.hypot(x, y), 3.15 / (2 * math.pi), rtol=1e-4)
    line = Track.from_yaml(ROOT / "config" / "track_test.yaml")
    assert not line.closed
    assert line.wrap(line.length + 5.0) == line.length + 5.0
    assert line.difference(10.0, line.length - 10.0) == pytest.approx(20.0 - line.length)


def test_scoring_compares_modulo_the_circumference():
    t = np.linspace(0, 10, 101)
    dist = 2.0 * t                                     # 20 m: six turns and more
    truth = StateSeries.of_truth(t, np.mod(dist, 3.15), np.full_like(t, 2.0))
    fused = StateSeries.of_truth(t, dist + 0.05, np.full_like(t, 2.0))
    fused.mode[:] = 1
    sc = score(truth, fused, circumference=3.15)
    assert sc["position_error_m"]["max"] == pytest.approx(0.05)


# --------------------------------------------------------------------------- dynamics
def test_the_lims_force_limit_bounds_the_acceleration():
    ring = Track.from_yaml(ROOT / "config" / "track_rig.yaml")
    dyn = Dynamics({}, ring)
    lever = dyn.params["lim_radius"] / (3.15 / (2 * math.pi))
    assert dyn.force_limit == pytest.approx(2 * 30.0 * lever)          # two 30 N LIMs, seed 003 3.1
    dyn.set_command(1e6)
    assert dyn.command == dyn.force_limit
    for _ in range(50):
        dyn.step(0.01)                                                  # the thrust builds up (lag)
    v0 = dyn.speed
    dyn.step(0.1)
    a = (dyn.speed - v0) / 0.1
    assert a == pytest.approx((dyn.force_limit - dyn.resistance(dyn.speed)) / dyn.mass, rel=0.02)
    assert a < dyn.force_limit / dyn.mass
    # top speed under full thrust: where the thrust equals the running resistance
    for _ in range(200):
        dyn.step(1.0)
    p = dyn.params
    c, b, a0 = p["resistance_c"], p["resistance_b"], p["resistance_a"] - dyn.force_limit
    v_max = (-b + math.sqrt(b * b - 4 * c * a0)) / (2 * c)
    assert dyn.speed == pytest.approx(v_max, rel=1e-3)
    assert v_max > 100 / 3.6                                            # the rig reaches 100 km/h
    # the chainage stays on the ring, the distance runs on
    assert 0 <= dyn.state().position < 3.15 and dyn.distance > 1000


def test_static_friction_holds_the_disc():
    dyn = Dynamics({}, Track.from_yaml(ROOT / "config" / "track_rig.yaml"))
    dyn.set_command(0.9 * dyn.params["resistance_a"])
    for _ in range(100):
        dyn.step(0.01)
    assert dyn.speed == 0.0 and dyn.distance == 0.0


def test_a_scenario_with_control_has_no_profile_trajectory():
    sc = Scenario.from_yaml(CLOSED)
    assert sc.control and not sc.legs
    with pytest.raises(ScenarioError):
        sc.trajectory()
    bad = dict(sc.description, control={"kind": "pid", "setpoints": [{"t": 1.0}]})
    with pytest.raises(ScenarioError):
        Scenario.from_dict(bad)


def test_controller_lets_go_without_a_usable_speed():
    params, sps = control_config({"setpoints": [{"t": 0.0, "speed": 10.0}]})
    ctrl = SpeedController(params, sps, 60.0)
    assert ctrl.update(0.0, 0.0) == 60.0
    assert ctrl.update(0.01, math.nan) == 0.0
    assert ctrl.update(0.02, 5.0, 0.0, speed_stddev=50.0) == 0.0


# --------------------------------------------------------------------------- closed loop
def test_closed_loop_tracks_the_speed_steps_through_the_localisation():
    """With the receiver's own noise; tools.rig runs it with 5 x the noise too."""
    sc, res = _closed_run()
    dyn = res.dynamics
    t = np.array([s.stamp for s in res.truth])
    v = np.array([s.speed for s in res.truth])
    band = res.controller.params["settling_band"]
    steps = step_response(t, v, res.setpoints, band)
    assert [round(f.v_to * 3.6) for f in steps] == [55, 100, 0]
    v_top = max(f.v_to for f in steps)
    # loop latency: a raw block, a fusion period and the thrust's lag to 95 %
    latency = sc.sensors["rig_loop_receiver"]["block_duration"] + 1 / 200 + 3 * dyn.params["force_lag"]
    for f in steps:
        dv = abs(f.v_to - f.v_from)
        up = f.v_to > f.v_from
        a_best = dyn.force_limit / dyn.mass + (0 if up else dyn.resistance(v_top) / dyn.mass)
        a_worst = (dyn.force_limit - (dyn.resistance(v_top) if up else 0.0)) / dyn.mass
        # settled, but not sooner than the thrust limit allows, and not much later
        assert f.settling_time is not None
        assert dv * (1 - band) / a_best <= f.settling_time <= dv / a_worst + 4.0
        # overshoot: what the disc gains at full thrust over the loop's latency, plus the band
        assert f.overshoot <= 100 * (a_best * latency + band * dv) / dv
    # the fused state the controller acted on: inside its interval, the position modulo the ring
    truth = StateSeries.of_truth(t, [s.position for s in res.truth], v)
    sc_ = score(truth, StateSeries.from_estimates(res.estimates), circumference=sc.track.length)
    assert sc_["integrity"]["inside_fraction"] == 1.0


def test_on_the_closed_track_both_streams_publish_the_chainage_wrapped_round_the_ring():
    """One convention for a closed track (TrainState.msg): the truth and the fused state give
    the position in [0, circumference); the fused interval moves with it (min <= position <=
    max, an end may pass the seam), and is scored from the messages as from the estimates.
    The fused messages gave the unwrapped distance (690 m on the 3.15 m ring)."""
    from train_localization.core.bagio import typestore_classes
    from train_localization.core.fusion.runner import estimate_to_msg
    sc, res = _closed_run()
    circ = sc.track.circumference
    mc = typestore_classes()
    msgs = [estimate_to_msg(mc, e, sc.track.track_id, [], sc.track) for e in res.estimates]
    claimed = [(e, m) for e, m in zip(res.estimates, msgs) if np.isfinite(e.position)]
    assert max(e.position for e, _ in claimed) > 10 * circ              # the filter's own distance runs on
    assert all(0.0 <= m.position < circ for _, m in claimed)
    assert all(m.position_min <= m.position <= m.position_max for _, m in claimed)
    assert all(m.position_max - m.position_min == pytest.approx(e.position_max - e.position_min)
               for e, m in claimed)
    assert any(m.position_min < 0.0 or m.position_max >= circ for _, m in claimed)   # across the seam
    assert all(0.0 <= s.position < circ for s in res.truth)
    t = np.array([s.stamp for s in res.truth])
    truth = StateSeries.of_truth(t, [s.position for s in res.truth], [s.speed for s in res.truth])
    from_msgs = score(truth, StateSeries.from_msgs(msgs), circumference=circ)
    from_estimates = score(truth, StateSeries.from_estimates(res.estimates), circumference=circ)
    assert from_msgs["integrity"]["inside_fraction"] == from_estimates["integrity"]["inside_fraction"] == 1.0
    assert from_msgs["position_error_m"]["max"] == pytest.approx(from_estimates["position_error_m"]["max"])


# --------------------------------------------------------------------------- error-model floor
FLOOR_CASES = {   # name: (initial speed [m/s], duration [s], profile)
    "standstill": (0.0, 12.5, [{"speed": 0.0, "hold": 60.0}]),
    "crawl": (0.02, 12.5, [{"speed": 0.02, "hold": 60.0}]),
    "high_speed": (27.78, 3.0, [{"speed": 27.78, "hold": 60.0}]),   # 100 km/h, seed 003 section 5
    "reversal": (6.0, 8.0, [{"speed": -6.0, "accel": 3.0, "decel": 3.0, "hold": 60.0}]),
}


def _rig_scenario(v0: float, duration: float, profile: list, params: dict, seed: int) -> Scenario:
    """The open-loop rig scenario with another profile and receiver parameters."""
    import yaml
    data = yaml.safe_load(OPEN.read_text(encoding="utf-8"))
    data.update(seed=seed, duration=duration, initial={"position": 0.0, "speed": v0}, profile=profile,
                sensors={"rig_loop_receiver": params})
    return Scenario.from_dict(data, source=OPEN)


def test_every_decoded_increment_is_at_or_above_the_error_model_floor():
    """ErrorModel.min_stddev (the pattern belt's wheel.IncrementEstimator floor) holds by
    construction: random seeds, blocks of 10 ms .. 5 s and, every other run, an ideal loop and
    receiver (no switching-point scatter or scale error: an increment between two switching
    points would claim 0 m), the disc standing, creeping, at 100 km/h and reversing; none is
    refused below_model, and the floor is reached (it is the decoder's own)."""
    def decode(case, params, seed):
        v0, duration, profile = case
        return decoded("rig_loop_receiver", _rig_scenario(v0, lasting(duration, params), profile, params, seed))

    ideal = {"noise": 0.0, "gap_sigma": 0.0, "gain_mismatch": 0.0, "detector_offset": 0.0, "spacing_error": 0.0,
             "transition_jitter": 0.0, "scale_sigma": 0.0}
    n, lowest = floor_runs(FLOOR_CASES, ideal, decode)
    assert min(n.values()) > 10 and sum(n.values()) > 1000, n
    assert lowest == pytest.approx(1.0, abs=1e-9)


def test_an_increment_claiming_half_the_floor_is_refused_below_model():
    run = _open_run()
    sc = Scenario.from_yaml(OPEN)
    assert_refused_below_half_the_floor(rig_loop.SPEC.errors(run.pipe.params, sc.track, sc.vehicle),
                                        run.measurements[400])

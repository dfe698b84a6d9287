"""Fusion unit tests (core/fusion/): measurement and process models, rollback of late
measurements, gating, slip, modes, reset and initialisation."""
from __future__ import annotations

import math
from dataclasses import fields

import numpy as np
import pytest
from filterpy.kalman import ExtendedKalmanFilter
from scipy.stats import chi2, norm

from train_localization.core import fusion
from train_localization.core.fusion import (MODE_DEGRADED, MODE_INITIALISING, MODE_LOST, MODE_NOMINAL,
                                            FusionConfig, TrainFilter, sensor_models)
from train_localization.core.measurements import DistanceIncrement, PositionFix, SpeedMeasurement
from train_localization.core.fusion.models import measurement
from train_localization.core.fusion import FusionRunner, fusion_config
from train_localization.core.scenario import Vehicle
from train_localization.core.scenario import Scenario
from train_localization.core.sensors import doppler, inpo, wheel
from train_localization.core.signals import InputRejected
from train_localization.core.offline import within_latency
from train_localization.tools import bench_fusion, compare_estimates

Z999 = norm.ppf(0.9995)   # half-width of the 99.9 % interval in sigmas
GATE_RADIUS = math.sqrt(chi2.ppf(0.9999, 1))   # the largest fix offset a fix's gate passes, in its 1-sigma


def untested_offset_stddev(sd: float, z: float = Z999) -> float:
    """The published 1-sigma [m] at a position taken from a balise fix of 1-sigma ``sd`` alone:
    the interval's half-width / z, its own z sd plus the untested offset a run of fixes may share,
    up to the gate's radius (faults.OFFSET, core/fusion/impact.py)."""
    return sd * (1.0 + GATE_RADIUS / z)


def config(*nodes, **tuning):
    """FusionConfig of the named sensor nodes with their default parameters."""
    return FusionConfig(sensors=sensor_models(list(nodes), None, Vehicle()), **tuning)


def model(f, m):
    """(z, R, H row, h(x)) of a measurement at the filter's current state."""
    return measurement(f.layout, f.ekf.x, m)


def fix(t, s, sd=0.3, sensor="eurobalise", ref="B1"):
    return PositionFix(t, sensor, sensor, "T", ref, s, sd)


DOPPLER_SCALE, DOPPLER_BIAS = doppler.PARAMS["scale_sigma"].default, doppler.PARAMS["bias"].default
WHEEL_SCALE = wheel.PARAMS["diameter_tolerance"].default / math.sqrt(3.0)


def speed(t, v, white=0.05, sensor="doppler"):
    """A Doppler speed whose stddev is made up like doppler.py's decoder does it."""
    return SpeedMeasurement(t, sensor, sensor, v, math.sqrt(white ** 2 + (DOPPLER_SCALE * v) ** 2 + DOPPLER_BIAS ** 2))


def inc(t, v, dur=0.05, q=0.004, sensor="wheel"):
    """A wheel increment whose stddev is made up like wheel.py's decoder does it."""
    sd = math.hypot(q, WHEEL_SCALE * v * dur)
    return DistanceIncrement(t, sensor, sensor, dur, v * dur, sd, v, sd / dur)


# --------------------------------------------------------------------------- models
def test_scalar_update_equals_filterpy_extended_kalman_filter_update():
    rng = np.random.default_rng(4)
    f = TrainFilter(FusionConfig())
    n = f.n
    for _ in range(20):
        a = rng.normal(size=(n, n))
        P = a @ a.T + n * np.eye(n)
        x = rng.normal(size=(n, 1))
        h = rng.normal(size=n)
        z, R = float(rng.normal()), float(rng.uniform(0.1, 2.0))
        hx = float(h @ x[:, 0]) + 0.3
        ref = ExtendedKalmanFilter(dim_x=n, dim_z=1)
        ref.x, ref.P = x.copy(), P.copy()
        ref.update(np.array([[z]]), lambda _x: h[None, :], lambda _x: np.array([[hx]]), R=np.array([[R]]))
        f.ekf.x, f.ekf.P = x.copy(), P.copy()
        PHt = P.dot(h)
        f.update(z, R, h, hx, PHt, float(h.dot(PHt)) + R)
        assert np.allclose(f.ekf.x, ref.x, rtol=0, atol=1e-12)
        assert np.allclose(f.ekf.P, ref.P, rtol=0, atol=1e-12)


@pytest.mark.parametrize("m", [
    speed(1.0, 30.0), speed(1.0, -12.0),
    inc(1.0, 25.0), inc(1.0, -8.0),
    fix(1.0, 100.0, sensor="mmwave"), fix(1.0, 100.0, sensor="inpo", ref="S1"), fix(1.0, 100.0)])
def test_measurement_jacobian_matches_numerical_derivative(m):
    f = TrainFilter(FusionConfig())
    rng = np.random.default_rng(1)
    x = np.zeros((f.n, 1))
    x[:3, 0] = (100.0, 30.0 if m.sensor != "wheel" or m.distance > 0 else -8.0, 0.7)
    if isinstance(m, SpeedMeasurement) and m.speed < 0:
        x[1, 0] = -12.0
    x[3:, 0] = rng.normal(0.0, 0.01, f.n - 3)
    f.ekf.x = x
    _, _, h, hx = measurement(f.layout, f.ekf.x, m)
    num = np.zeros(f.n)
    for i in range(f.n):
        eps = 1e-6 * max(1.0, abs(x[i, 0]))
        for sign in (1, -1):
            xp = x.copy()
            xp[i, 0] += sign * eps
            f.ekf.x = xp
            num[i] += sign * measurement(f.layout, f.ekf.x, m)[3] / (2 * eps)
    assert np.allclose(h, num, rtol=1e-6, atol=1e-8)
    f.ekf.x = x
    if isinstance(m, PositionFix):
        assert h[0] == 1.0
    else:
        assert abs(h[1]) > 0.9   # it measures the speed


def test_noise_that_a_state_carries_is_taken_out_of_r():
    f = TrainFilter(FusionConfig())
    p = doppler.PARAMS
    v, n = 40.0, 10
    white = (p["spread"].default * v) ** 2 / n
    sigma = math.sqrt(white + (p["scale_sigma"].default * v) ** 2 + p["bias"].default ** 2)   # doppler.py decoder
    _, R, _, _ = model(f, SpeedMeasurement(1.0, "doppler", "radar", v, sigma))
    assert R == pytest.approx(white, rel=1e-9)
    # wheel: quantisation stays, the diameter tolerance (a state) goes
    q, dist = 0.006, 2.0
    scale = wheel.PARAMS["diameter_tolerance"].default / math.sqrt(3.0)
    m = DistanceIncrement(1.0, "wheel", "wheel", 0.05, dist, math.hypot(q, scale * dist), dist / 0.05, 0.1)
    _, R, _, _ = measurement(f.layout, f.ekf.x, m)
    assert R * 0.05 ** 2 == pytest.approx(q * q, rel=1e-9)
    # INPO: the section's survey/laying error is the fix-bias state
    bias = math.hypot(inpo.PARAMS["survey_sigma"].default,
                      inpo.PARAMS["skew_sigma"].default / math.sqrt(inpo.PARAMS["n_pairs"].default))
    _, R, _, _ = model(f, fix(1.0, 10.0, math.hypot(0.0005, bias), sensor="inpo"))
    assert R == pytest.approx(0.0005 ** 2, rel=1e-6)
    # a sensor without such a state keeps its figure, scaled by stddev_factor
    assert model(f, fix(1.0, 10.0, 0.3))[1] == pytest.approx(0.09)
    g = TrainFilter(FusionConfig(overrides={"eurobalise": {"stddev_factor": 2.0}}))
    assert model(g, fix(1.0, 10.0, 0.3))[1] == pytest.approx(0.36)


def test_doppler_scale_state_is_the_exact_discretisation_of_the_radar_ar1():
    f = TrainFilter(FusionConfig())
    i = f.layout.scale["doppler"]
    sigma, tau = doppler.PARAMS["scale_sigma"].default, doppler.PARAMS["scale_tau"].default
    dt = 1.0 / 200.0                               # the radar's sample period
    F, _, Q = f.process.transition(dt)
    phi = math.exp(-dt / tau)                      # doppler.py DopplerSimulator.samples
    assert F[i, i] == pytest.approx(phi, rel=1e-12)
    assert Q[i, i] == pytest.approx(sigma ** 2 * (1 - phi * phi), rel=1e-12)
    # stationary: the variance stays sigma^2 however long the prediction
    x, P, _ = f.state(0.0)
    assert P[i, i] == pytest.approx(sigma ** 2)
    _, P1 = f.process.predict(x[:, None], P, 0.0, 100.0)
    assert P1[i, i] == pytest.approx(sigma ** 2, rel=1e-9)
    # the wheel's diameter error is a slow random walk, the constant Doppler offset too
    w, o = f.layout.scale["wheel"], f.layout.offset["doppler"]
    assert F[w, w] == 1.0 and F[o, o] == 1.0
    assert Q[w, w] == pytest.approx(f.cfg.scale_psd * dt)


def test_an_injected_radar_fault_grows_over_its_ramp_and_a_malformed_one_is_refused():
    """'T0-T1:SCALE:RAMP': the scale error grows linearly from T0 over RAMP s, holds until T1;
    without RAMP it is there at once."""
    faults = doppler._parse_faults("10-40:0.06:20; 50-60:-0.03")
    assert faults == [(10.0, 40.0, 0.06, 20.0), (50.0, 60.0, -0.03, 0.0)]
    got = doppler.fault_scale(faults, [5.0, 10.0, 15.0, 30.0, 39.9, 40.0, 50.0, 59.9, 60.0])
    assert got == pytest.approx([0.0, 0.0, 0.015, 0.06, 0.06, 0.0, -0.03, -0.03, 0.0])
    for bad in ("10-40", "10-40:0.06:-1", "10-40:0.06:5:5", "a-40:0.06"):
        with pytest.raises(ValueError, match="malformed doppler fault"):
            doppler._parse_faults(bad)


def test_mmwave_fix_bias_decorrelates_with_distance_and_time():
    cfg = FusionConfig(overrides={"mmwave": {"fix_bias_length": 400.0}})
    f = TrainFilter(cfg)
    mw = f.models["mmwave"]
    i = f.layout.fix["mmwave"]
    x = np.zeros((f.n, 1))
    x[1, 0], x[i, 0] = 100.0, 0.05
    P = np.eye(f.n) * 1e-4
    dt = 2.0
    x1, P1 = f.process.predict(x, P, 0.0, dt)
    phi = math.exp(-100.0 * dt / mw.fix_bias_length - dt / mw.fix_bias_tau)
    assert x1[i, 0] == pytest.approx(0.05 * phi, rel=1e-6)
    assert P1[i, i] == pytest.approx(1e-4 * phi ** 2 + mw.fix_bias_sigma ** 2 * (1 - phi ** 2), rel=1e-6)
    x[1, 0] = 0.0   # at standstill only the time constant
    x2, _ = f.process.predict(x, P, 0.0, dt)
    assert x2[i, 0] == pytest.approx(0.05 * math.exp(-dt / mw.fix_bias_tau), rel=1e-6)


def test_inpo_fix_bias_is_redrawn_for_a_new_section():
    """Fixes of one section agree to 0.1 mm (their error is the section's survey bias);
    the next section's fixes may differ by a few mm: with a bias per section that is a
    normal 1.4-sigma difference, with one bias for all it would be a gross outlier."""
    def feed(cfg):
        f = TrainFilter(cfg)
        f.reset(position=1000.0, position_stddev=1.0, speed=0.0, speed_stddev=0.001, stamp=-0.05)
        for k in range(20):
            f.add(fix(0.05 * k, 1000.0, 0.00215, sensor="inpo", ref="A"))
        f.add(fix(1.0, 1000.006, 0.00215, sensor="inpo", ref="B"))
        return f
    per_section = feed(FusionConfig())
    shared = feed(FusionConfig(overrides={"inpo": {"fix_bias_per_reference": False}}))
    assert per_section.counters()["accepted"]["inpo"] == 21
    assert 1000.002 < per_section.estimate(1.0).position < 1000.004   # about half of the jump
    assert shared.counters()["gated"] == {"inpo": 1}


def test_filter_is_consistent_on_data_drawn_from_its_own_model():
    """Truth with acceleration phases; Doppler with the radar's AR(1) scale and bias,
    wheel with a diameter error and creep, balises every 800 m: the position error
    normalised by the reported stddev has rms ~1 and stays in the 99.9 % interval. The model has
    no offset of runs of balise fixes (the data has none; its cover would widen the published
    stddev beyond the model's)."""
    cfg = config("doppler_radar", "wheel_sensor", "eurobalise_reader", overrides={"eurobalise": {"faults": ["misread"]}})
    zs, inside = [], []
    for seed in range(6):
        rng = np.random.default_rng(seed)
        f = TrainFilter(cfg)
        dt = 0.05
        s, v = 100.0, 0.0
        k_wheel = rng.uniform(-0.01, 0.01)
        k_dop = rng.normal(0.0, 0.005)
        phi = math.exp(-dt / 5.0)
        next_balise = 500.0
        for j in range(1, 3001):
            t = j * dt
            a = 0.6 if t < 60 else (0.0 if t < 110 else -0.5)
            s_prev = s
            v_new = max(v + a * dt, 0.0)
            a = (v_new - v) / dt
            s += 0.5 * (v + v_new) * dt
            v = v_new
            k_dop = phi * k_dop + math.sqrt(1 - phi * phi) * 0.005 * rng.normal()
            if v > 0.3:
                white = 0.02 * v / math.sqrt(10)
                f.add(speed(t - 0.025, (v - 0.5 * a * dt + 0.02) * (1 + k_dop) + rng.normal(0, white),
                            math.sqrt(white ** 2 + (0.005 * v) ** 2 + 0.02 ** 2)))
            d = (s - s_prev) * (1 + k_wheel) * (1 + 0.002 * a) + rng.normal(0, 0.005)
            f.add(DistanceIncrement(t, "wheel", "wheel", dt, d, math.hypot(0.005, 0.0058 * d), d / dt, 0.1))
            if s >= next_balise:
                t_b = t - (s - next_balise) / max(v, 1e-3)
                f.add(fix(t_b, next_balise + rng.normal(0, 0.3), 0.3, ref=str(next_balise)))
                next_balise += 800.0
            if j % 10 == 0:
                e = f.estimate(t)
                if e.mode != MODE_INITIALISING:
                    zs.append((e.position - s) / e.position_stddev)
                    inside.append(e.position_min <= s <= e.position_max)
    zs = np.array(zs)
    assert len(zs) > 1000
    assert 0.6 < np.sqrt(np.mean(zs ** 2)) < 1.3
    assert np.mean(inside) >= 0.995


# --------------------------------------------------------------------------- rollback
@pytest.fixture(scope="module")
def recorded():
    """Measurements (with arrival times) of the first seconds of both scenarios."""
    out = {}
    for name, t_end in (("scenario_maglev_500", 8.0), ("scenario_conventional_300", 24.0)):
        sc = Scenario.from_yaml(f"config/{name}.yaml")
        out[name] = (sc, bench_fusion.scenario_measurements(sc, t_end), t_end)
    return out


@pytest.mark.parametrize("name", ["scenario_maglev_500", "scenario_conventional_300"])
def test_late_and_shuffled_delivery_gives_the_in_order_estimates(recorded, name):
    sc, arrivals, t_end = recorded[name]
    cfg = fusion_config(sc)
    shuffled = bench_fusion.delayed(arrivals, 0.2, seed=3)
    # every estimate(T), asked once all data stamped <= T are in, agrees with in-order processing
    diff = bench_fusion.compare_history(cfg, arrivals, shuffled, t_end + 0.3, step=0.02)
    assert diff <= 1e-9
    # and so does the final state, bit for bit, with the same counters
    a, b = TrainFilter(cfg), TrainFilter(cfg)
    for _, m in sorted(arrivals, key=lambda item: fusion.order_key(item[1])):
        a.add(m)
    for _, m in shuffled:
        b.add(m)
    (xa, Pa, _), (xb, Pb, _) = a.state(), b.state()
    assert np.max(np.abs(xa - xb)) <= 1e-9 and np.max(np.abs(Pa - Pb)) <= 1e-9
    assert a.counters()["accepted"] == b.counters()["accepted"]
    assert a.counters()["gated"] == b.counters()["gated"]
    assert b.rollbacks > 0.3 * len(arrivals) and a.rollbacks == 0   # out of order: many arrived late
    if name == "scenario_conventional_300":   # the forced slip at 20 s rolls back too
        assert b.counters()["slips"]["episodes"] >= 1
    ea, eb = a.estimate(t_end), b.estimate(t_end)
    assert ea.mode == eb.mode and ea.speed == pytest.approx(eb.speed, abs=1e-9)
    assert ea.position == pytest.approx(eb.position, abs=1e-9, nan_ok=True)


def test_the_benchmark_runs_the_maglev_sensors_in_order_and_shuffled(recorded):
    """The fusion benchmark's two streams of the maglev scenario's measurements (in order, and
    delayed up to 0.2 s) give the 200 Hz grid of states; its speed is a benchmark figure
    (``python -m train_localization.tools.bench fusion``), not a test (shared hosts)."""
    sc, arrivals, t_end = recorded["scenario_maglev_500"]
    cfg = fusion_config(sc)
    for stream in (arrivals, bench_fusion.delayed(arrivals, 0.2, seed=1)):
        _, est, _, _ = bench_fusion.run(cfg, stream, t_end + 0.21)
        assert len(est) >= 200 * t_end


@pytest.mark.parametrize("name", ["scenario_maglev_500", "scenario_conventional_300"])
def test_a_holding_runner_applies_inputs_late_within_latency_in_order_and_rewinds_nothing(recorded, name):
    """Held for the sensors' declared latency (FusionRunner ``hold``), inputs arriving as the
    sensors publish them (stamped inside their 50 ms blocks) or shuffled within their latency give
    the estimates of the same inputs arriving at their stamps without holding, bit for bit, with
    one filter update per measurement; the runner without holding rewinds for the shuffled ones."""
    sc, arrivals, t_end = recorded[name]
    arrivals = [(t, m) for t, m in arrivals if m.stamp <= t_end - 0.1]   # every one in by t_end
    cfg = fusion_config(sc)
    at_stamp = sorted(((m.stamp, m) for _, m in arrivals), key=lambda item: fusion.order_key(item[1]))
    shuffled = within_latency(arrivals, {k: m.latency for k, m in cfg.models.items()}, seed=3)
    assert sum(a[1] is not b[1] for a, b in zip(arrivals, shuffled)) > 0.3 * len(arrivals)
    in_order, plain, _, _ = bench_fusion.run(cfg, at_stamp, t_end)
    # one update per measurement, and those a slip's exclusion after the fact re-applies
    updates = in_order.counters()["rollbacks"]["updates"]
    assert len(arrivals) <= updates <= 1.01 * len(arrivals)
    for stream in (at_stamp, arrivals, shuffled):
        runner, est, _, _ = bench_fusion.run(cfg, stream, t_end, runner=FusionRunner(cfg, hold=True))
        assert len(est) == len(plain) and compare_estimates.same_estimates(est, plain)
        assert runner.counters()["rollbacks"] == {"late": 0, "updates": updates, "late_beyond_latency": 0}
    rewound = bench_fusion.run(cfg, shuffled, t_end)[0].counters()["rollbacks"]
    assert rewound["late"] > 0.05 * len(arrivals) and rewound["updates"] > len(arrivals)


def test_a_holding_runner_publishes_each_state_the_declared_latency_after_its_time(recorded):
    """The estimate of grid time T comes from the advance at T + latency (the sensors' largest
    declared latency: one 50 ms block), not later."""
    sc, arrivals, t_end = recorded["scenario_maglev_500"]
    cfg = fusion_config(sc)
    runner = FusionRunner(cfg, hold=True)
    assert runner.latency == pytest.approx(0.05)
    lags, j = [], 0
    for k in range(int(round(t_end / 0.005)) + 1):
        now = k * 0.005
        while j < len(arrivals) and arrivals[j][0] <= now + 1e-12:
            runner.add(arrivals[j][1])
            j += 1
        lags += [now - est.stamp for est, _ in runner.advance(now)]
    assert len(lags) == int(round((t_end - 0.05) / 0.005)) + 1
    assert min(lags) == pytest.approx(0.05, abs=1e-9) and max(lags) == pytest.approx(0.05, abs=1e-9)


def test_a_holding_runner_counts_inputs_later_than_declared_and_still_takes_them(recorded):
    """Inputs delayed up to 0.2 s, beyond the 50 ms latency: those stamped before what was
    already released enter the filter at once (its history rewinds), counted; the final state is
    the in-order one."""
    sc, arrivals, t_end = recorded["scenario_maglev_500"]
    cfg = fusion_config(sc)
    stream = bench_fusion.delayed(arrivals, 0.2, seed=3)
    runner, _, _, _ = bench_fusion.run(cfg, stream, t_end + 0.21, runner=FusionRunner(cfg, hold=True))
    # released before an input is added at tick k: every stamp up to tick k-1 minus the latency
    released = [math.floor(t / 0.005 - 1e-12) * 0.005 - runner.latency for t, _ in stream]
    beyond = [m.stamp - r for (_, m), r in zip(stream, released)]
    counted = runner.counters()["rollbacks"]
    assert sum(d < -1e-9 for d in beyond) <= counted["late_beyond_latency"] <= sum(d <= 1e-9 for d in beyond)
    assert counted["late_beyond_latency"] > 0.3 * len(stream) and counted["late"] > 0
    ordered = TrainFilter(cfg)
    for _, m in sorted(arrivals, key=lambda item: fusion.order_key(item[1])):
        ordered.add(m)
    (xa, Pa, _), (xb, Pb, _) = ordered.state(), runner.filter.state()
    assert np.max(np.abs(xa - xb)) <= 1e-9 and np.max(np.abs(Pa - Pb)) <= 1e-9


def test_estimate_of_a_past_time_ignores_later_measurements():
    f = TrainFilter(FusionConfig())
    g = TrainFilter(FusionConfig())
    for t in np.arange(0.05, 3.0, 0.05):
        f.add(speed(t, 10.0))
        g.add(speed(t, 10.0))
    for h in (f, g):   # two balises agree: the position is claimed
        h.add(fix(1.0, 500.0, ref="B0"))
        h.add(fix(1.2, 502.0))
    f.add(fix(2.5, 515.3, ref="B2"))  # later, 0.3 m off the dead reckoning
    e_f, e_g = f.estimate(2.2), g.estimate(2.2)
    assert e_f.position == e_g.position and e_f.position_stddev == e_g.position_stddev
    assert f.estimate(2.9).position != g.estimate(2.9).position


def test_the_history_refuses_late_and_repeated_measurements():
    f = TrainFilter(FusionConfig(history=1.0))
    f.add(fix(10.0, 500.0, ref="B0"))
    f.add(fix(12.0, 520.0, ref="B2"))
    with pytest.raises(InputRejected) as exc:
        f.add(fix(10.5, 505.0))           # 1.5 s older than the newest, history 1 s
    assert exc.value.reason == "too_late"
    with pytest.raises(InputRejected) as exc:
        f.add(fix(12.0, 520.0))
    assert exc.value.reason == "duplicate"
    assert f.rejected == {"too_late": 1, "duplicate": 1}
    f.add(fix(11.5, 515.0))               # late but inside the history: inserted
    # the first is the candidate that the second (now the late one) confirms, the third is accepted
    assert f.rollbacks == 1 and f.counters()["accepted"]["eurobalise"] == 2


# --------------------------------------------------------------------------- gating, slip
def test_gate_threshold_is_a_per_sensor_parameter():
    def outlier(cfg, k_sigma):
        f = TrainFilter(cfg)
        for t in np.arange(0.05, 2.0, 0.05):
            f.add(speed(t, 20.0))
        f.add(fix(0.5, 990.0, 0.3, ref="B0"))
        f.add(fix(1.0, 1000.0, 0.3))
        e = f.estimate(2.0)
        # the innovation's sigma: the filter's own position variance (the published interval
        # also covers the lone radar's fault hypothesis) and the fix's
        s = math.sqrt(float(f.state(2.0)[1][0, 0]) + 0.3 ** 2)
        f.add(fix(2.0, e.position + k_sigma * s, 0.3, ref="B2"))
        return f, e
    f, before = outlier(FusionConfig(), 4.5)                   # gate 0.9999: 3.89 sigma
    assert f.counters()["gated"] == {"eurobalise": 1}
    assert f.estimate(2.0).position == before.position       # no effect on the state
    f, _ = outlier(FusionConfig(overrides={"eurobalise": {"gate_probability": 1 - 1e-7}}), 4.5)   # 5.33 sigma
    assert f.counters()["gated"] == {} and f.counters()["accepted"]["eurobalise"] == 2
    f, _ = outlier(FusionConfig(gate_probability=0.99), 3.0)   # 2.58 sigma
    assert f.counters()["gated"] == {"eurobalise": 1}


def _slip_run(cfg, with_doppler=True):
    f = TrainFilter(cfg)
    rng = np.random.default_rng(2)
    err = []
    for j in range(1, 301):
        t = j * 0.05
        ratio = 0.10 if 6.0 <= t < 9.0 else 0.0       # wheel 10 % fast for 3 s
        f.add(inc(t, 30.0 * (1 + ratio) + rng.normal(0, 0.05), q=0.004))
        if with_doppler:
            f.add(speed(t - 0.025, 30.0 + rng.normal(0, 0.2), 0.2))
        if j == 20:
            f.add(fix(t, 100.0 + 30.0 * t))
        if t > 2.0:
            err.append(f.estimate(t).speed - 30.0)
    return f, np.array(err)


def test_wheel_slip_is_detected_against_the_doppler_and_excluded():
    f, err = _slip_run(FusionConfig())
    c = f.counters()
    assert c["slips"]["episodes"] == 1
    # a slip at a steady speed is no slip physics (that needs traction): the wheel is suspected
    # faulty and comes back once it has agreed for slip_window s, its window clear of the slip
    window = int(FusionConfig().slip_window / 0.05)
    excluded = c["gated"].get("wheel/slip", 0) + c["gated"].get("wheel/suspended", 0)
    assert 60 <= excluded <= 60 + 2 * window                 # 3 s of increments, then the probation
    assert c["integrity"]["speed_source_restored"] == 1
    assert np.max(np.abs(err)) < 0.3                # the slipping wheel (+3 m/s) does not pull the speed
    assert "wheel" not in c["gated"]                 # slip, not counted as outliers
    # without slip detection (and no gate for the wheel) the filter follows the wheel
    g, err_off = _slip_run(FusionConfig(overrides={"wheel": {"faults": (), "gate_probability": 1.0}}))
    assert np.max(np.abs(err_off)) > 1.0
    h, _ = _slip_run(FusionConfig(), with_doppler=False)
    # without another speed source the wheel disagrees with the motion model alone, at a steady
    # speed, where its model has it slip only under traction: the motion model is taken to be
    # wrong (the speed from the wheel), its hypothesis kept (the radar is not there to tell)
    assert h.counters()["integrity"]["motion_model_refuted"] >= 1


# --------------------------------------------------------------------------- modes, init, reset
def test_initialising_until_two_fixes_agree_then_nominal_degraded_lost():
    f = TrainFilter(config("doppler_radar", "eurobalise_reader", lost_stddev=2.0, overrides={"doppler": {"timeout": 0.5}}))
    for t in np.arange(0.05, 5.0, 0.05):
        f.add(speed(t, 20.0))
    e = f.estimate(5.0)
    assert e.mode == MODE_INITIALISING and math.isnan(e.position)
    assert e.position_min == -math.inf and e.position_max == math.inf
    assert e.speed == pytest.approx(20.0, abs=0.1)            # speed is known before the position
    f.add(fix(4.0, 1214.0, 0.3, ref="B0"))   # a single fix may be a misread: no position yet
    assert f.estimate(4.5).mode == MODE_INITIALISING
    f.add(fix(5.0, 1234.0, 0.3))              # another balise agrees (20 m/s x 1 s)
    e = f.estimate(5.0)
    assert e.mode == MODE_NOMINAL and e.position == pytest.approx(1234.0, abs=1e-9)
    # nothing has tested the balises yet: they may share an offset up to the gate's radius
    assert e.position_stddev == pytest.approx(untested_offset_stddev(0.3), rel=1e-6)
    assert e.position_max - e.position == pytest.approx(Z999 * untested_offset_stddev(0.3), rel=1e-6)
    assert f.estimate(5.4).mode == MODE_NOMINAL
    assert f.estimate(5.6).mode == MODE_DEGRADED                # Doppler silent > 0.5 s
    f.add(speed(5.7, 20.0))
    assert f.estimate(5.7).mode == MODE_NOMINAL
    late = f.estimate(60.0)                                     # nothing for a minute
    assert late.position_stddev > 2.0 and late.mode == MODE_LOST


def test_confidence_sets_the_interval():
    f = TrainFilter(FusionConfig(confidence=0.95))
    f.add(fix(0.5, 50.0, 0.5, ref="B0"))
    f.add(fix(1.0, 50.0, 0.5))
    e = f.estimate(1.0)
    z = 1.959964
    assert (e.position_max - e.position_min) / 2 == pytest.approx(z * untested_offset_stddev(0.5, z), rel=1e-5)
    assert e.confidence == 0.95


def test_reset_sets_or_forgets_the_position():
    f = TrainFilter(config("eurobalise_reader"))
    f.add(fix(1.0, 50.0))
    f.reset(position=2000.0, position_stddev=0.5, speed=12.0, speed_stddev=0.2, stamp=10.0)
    e = f.estimate(10.0)
    assert e.mode == MODE_NOMINAL and e.position == 2000.0 and e.position_stddev == pytest.approx(0.5)
    assert f.estimate(11.0).position == pytest.approx(2012.0, abs=1e-6)
    with pytest.raises(InputRejected) as exc:
        f.add(fix(9.0, 1990.0))                                 # before the reset
    assert exc.value.reason == "too_late"
    f.add(fix(10.5, 2006.0))
    assert f.counters()["accepted"] == {"eurobalise": 1}        # counters restart too
    f.reset(stamp=20.0)
    assert f.estimate(20.0).mode == MODE_INITIALISING
    f.add(fix(21.0, 100.0, ref="B8"))
    f.add(fix(21.5, 100.0, ref="B9"))
    assert f.estimate(21.5).position == pytest.approx(100.0)


def test_a_known_start_position_starts_the_filter_there_at_rest():
    """``initial_position``: NOMINAL at that chainage from the first measurement (or output) on,
    counting from there; without it the same increments leave the filter INITIALISING."""
    def travelled(t):                           # at rest for 0.5 s, then a start with 0.5 m/s^3 [m]
        return 0.5 / 6.0 * max(t - 0.5, 0.0) ** 3
    stamps = [0.05 * k for k in range(1, 81)]
    increments = [inc(t, (travelled(t) - travelled(t - 0.05)) / 0.05) for t in stamps]
    known = FusionRunner(config("wheel_sensor", initial_position=120.0, initial_position_stddev=0.02))
    unknown = FusionRunner(config("wheel_sensor"))
    for m in increments:
        assert known.add(m) and unknown.add(m)
    first = known.advance(0.05)[0][0]
    assert first.mode == MODE_NOMINAL and first.position == pytest.approx(120.0, abs=0.01)
    assert first.position_stddev == pytest.approx(0.02, rel=0.05)
    e = known.filter.estimate(4.0)
    truth = 120.0 + travelled(4.0)
    assert e.mode == MODE_NOMINAL and e.position == pytest.approx(truth, abs=0.05)
    assert e.position_min <= truth <= e.position_max and e.speed == pytest.approx(0.25 * 3.5 ** 2, abs=0.1)
    assert unknown.filter.estimate(4.0).mode == MODE_INITIALISING
    with pytest.raises(ValueError, match="initial_position must be a chainage"):
        config("wheel_sensor", initial_position=math.inf)
    with pytest.raises(ValueError, match="initial_position_stddev must be in"):
        config("wheel_sensor", initial_position=0.0, initial_position_stddev=0.0)


def test_position_is_reacquired_when_two_independent_fixes_disagree_with_the_filter():
    """A wrong operator position with a small stddev: the first fix is gated and kept as the
    alternative (the interval covers it, DEGRADED); the next balise agrees with it, not
    with the filter: the position is taken from the fixes."""
    f = TrainFilter(config("doppler_radar", "eurobalise_reader"))
    f.reset(position=1000.0, position_stddev=0.2, speed=20.0, speed_stddev=0.1, stamp=0.0)
    truth = 1050.0                       # the operator was 50 m off
    for j in range(1, 400):
        t = j * 0.05
        f.add(speed(t, 20.0))
        if j % 100 == 0:                 # a balise every 5 s
            f.add(fix(t, truth + 20.0 * t, 0.3, ref=str(j)))
        if j == 150:                     # between the first two fixes: wrong, but it says so
            e = f.estimate(t)
            assert e.mode == MODE_DEGRADED and e.position_min <= truth + 20.0 * t <= e.position_max
    c = f.counters()
    assert c["gated"]["eurobalise"] == 2 and c["integrity"]["reacquired"] == 1
    assert c["accepted"]["eurobalise"] == 2          # the re-acquiring fix and the last one
    e = f.estimate(19.95)
    assert abs(e.position - (truth + 20.0 * 19.95)) < 1.0 and e.mode == MODE_NOMINAL


def test_a_single_wrong_fix_widens_the_interval_until_an_independent_fix_explains_the_filter():
    f = TrainFilter(config("doppler_radar", "eurobalise_reader"))
    f.reset(position=1000.0, position_stddev=0.2, speed=20.0, speed_stddev=0.1, stamp=0.0)
    for j in range(1, 400):
        t = j * 0.05
        f.add(speed(t, 20.0))
        if j % 100 == 0:
            wrong = 300.0 if j == 100 else 0.0        # a misread: a balise 300 m away
            f.add(fix(t, 1000.0 + 20.0 * t + wrong, 0.3, ref=str(j)))
        if j == 150:
            e = f.estimate(t)
            assert e.mode == MODE_DEGRADED and e.position_max > 1000.0 + 20.0 * t + 299.0
        if j == 301:          # just after the last balise (the lone radar's protection then
            e = f.estimate(t)  # grows with the distance: test_fusion_integrity)
            assert e.mode == MODE_NOMINAL and e.position_max - e.position_min < 5.0
    c = f.counters()
    assert c["gated"]["eurobalise"] == 1 and c["integrity"]["outlier_fix"] == 1
    assert f.estimate(19.95).mode == MODE_NOMINAL


def test_runner_publishes_on_a_fixed_grid_and_reports_rejections():
    r = FusionRunner(FusionConfig(), rate=200.0)
    assert r.add(fix(0.01, 10.0, 0.5)) and not r.add(fix(0.01, 10.0, 0.5))
    assert r.last_error.reason == "duplicate" and r.rejected == {"duplicate": 1}
    out = r.advance(0.0)
    out += r.advance(0.0213)
    assert [e.stamp for e, _ in out] == pytest.approx([0.0, 0.005, 0.01, 0.015, 0.02])
    assert out[0][1] == ["eurobalise"] and out[1][1] == []


def _balises_and_radar(r: FusionRunner, t0: float, t1: float) -> list:
    """Feed r a train at 20 m/s (radar at 20 Hz, a balise every 100 m) from t0 to t1 [s] and
    advance it every 50 ms; the estimates."""
    out = []
    for k in range(int(round(t0 * 20)) + 1, int(round(t1 * 20)) + 1):
        t = k / 20.0
        r.add(speed(t, 20.0), now=t)
        if k % 100 == 0:
            r.add(fix(t, 20.0 * t, 0.5, ref=f"B{k}"), now=t)
        out += [e for e, _ in r.advance(t)]
    return out


def test_a_clock_that_jumps_back_moves_the_grid_and_a_loop_restarts_the_filter():
    """One /clock message 1e6 s ahead: the runner had published one state there and then nothing
    for good (its grid stayed at 1e6 s). Its grid now follows the clock back and the filter,
    whose data lie before the clock, goes on; a clock back before the filter's data (a bag in a
    loop) starts the filter afresh and the data from the start are taken again."""
    r = FusionRunner(config("doppler_radar", "eurobalise_reader"), rate=20.0)
    before = _balises_and_radar(r, 0.0, 30.0)
    assert before[-1].mode == MODE_NOMINAL
    (far,) = [e for e, _ in r.advance(30.0 + 1e6)]          # time passing: predicted there
    assert far.mode == MODE_LOST
    after = _balises_and_radar(r, 30.0, 40.0)
    assert len(after) == 200 and after[0].stamp == pytest.approx(30.05)
    assert all(e.mode == MODE_NOMINAL for e in after)        # the filter went on
    assert r.counters()["clock"] == {"back": 1, "filter_reset": 0}
    looped = _balises_and_radar(r, 0.0, 30.0)                # the bag again from its start
    assert r.counters()["clock"] == {"back": 2, "filter_reset": 1}
    assert r.rejected.get("too_late", 0) == 0
    assert looped[0].mode == MODE_INITIALISING and looped[-1].mode == MODE_NOMINAL
    assert abs(looped[-1].position - 600.0) < 1.0


def test_every_tuning_field_is_a_documented_node_parameter():
    from train_localization.nodes.fusion import (_from_ros, _ros_value, error_model_parameters,
                                                 overrides_from_parameters)
    cfg = FusionConfig()
    for f in FusionConfig.tuning_fields():
        assert f.metadata.get("doc"), f"{f.name} has no description"
        value = getattr(cfg, f.name)
        back = _from_ros(value, _ros_value(value))
        assert back == value or (math.isnan(back) and math.isnan(value)), f.name
    # per-sensor error models as nested parameters: unchanged values are no override
    wheel = sensor_models(["wheel_sensor"], None, Vehicle())["wheel"]
    params = error_model_parameters(wheel)
    assert params["faults"] == "slip,slide,wear" and math.isnan(params["gate_probability"])
    assert overrides_from_parameters(wheel, params) == {}
    changed = {**params, "timeout": 2.0, "faults": "slide"}
    assert overrides_from_parameters(wheel, changed) == {"timeout": 2.0, "faults": ("slide",)}
    assert wheel.overridden(overrides_from_parameters(wheel, changed)).faults == ("slide",)


@pytest.mark.parametrize("bad", [
    PositionFix(1.0, "eurobalise", "b", "T", "EB1", 100.0, 1e200),          # stddev overflows the filter
    PositionFix(1.0, "eurobalise", "b", "T", "EB1", 1e12, 1.0),             # no line is that long
    PositionFix(1.0, "eurobalise", "b", "T", "EB1", 100.0, 1e-9),           # finer than any sensor
    SpeedMeasurement(1.0, "doppler", "d", 10.0, 1e200),
    SpeedMeasurement(1.0, "doppler", "d", 900.0, 0.1),                      # faster than any train
    DistanceIncrement(1.0, "wheel", "w", 1e-300, 0.5, 0.01, 10.0, 0.1),     # overflows as a speed
    DistanceIncrement(1.0, "wheel", "w", 0.05, 50.0, 0.01, 10.0, 0.1),      # 1000 m/s
])
def test_implausible_measurements_are_rejected_and_the_filter_stays_finite(bad):
    """One absurd value (issue: a speed stddev of 1e200 turned the state to NaN for good) is
    rejected with reason 'implausible'; the filter goes on with the next valid input."""
    runner = FusionRunner(config("doppler_radar", "wheel_sensor", "eurobalise_reader"))
    f = runner.filter
    f.reset(position=100.0, position_stddev=1.0, speed=10.0, speed_stddev=0.1, stamp=0.0)
    assert not runner.add(bad)
    assert runner.last_error.reason == "implausible" and runner.rejected == {"implausible": 1}
    assert runner.add(SpeedMeasurement(1.5, "doppler", "d", 10.0, 0.1))
    e = f.estimate(2.0)
    assert math.isfinite(e.position) and abs(e.position - 120.0) < 1.0 and e.mode != MODE_LOST


def test_the_interval_is_cut_to_the_tracks_ends():
    """A train placed 3 m from the track's start (a start of mission), told with 1-sigma 5 m: the
    filter's own interval reaches 13 m before chainage 0, where no train can be; the published
    one ends at 0, and at the track's far end at its length."""
    from conftest import ROOT
    from train_localization.core.fusion import FusionRunner, fusion_config
    from train_localization.core.scenario import Scenario
    sc = Scenario.from_yaml(ROOT / "config" / "scenario_demo.yaml")
    length = sc.track.length
    for place, low_end in ((3.0, True), (length - 3.0, False)):
        runner = FusionRunner(fusion_config(sc, initial_position=place, initial_position_stddev=5.0))
        e = runner.advance(0.1)[-1][0]
        assert e.position == pytest.approx(place) and e.position_stddev == pytest.approx(5.0, rel=0.01)
        if low_end:
            assert e.position_min == 0.0 and e.position_max > place + 16.0
        else:
            assert e.position_max == length and e.position_min < place - 16.0

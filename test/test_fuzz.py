"""Fuzz suite (hypothesis): arbitrary raw blocks into every sensor pipeline, arbitrary
measurements into the filter, in-process.

What must hold for any input a publisher can send:
- nothing but InputRejected escapes a pipeline or the filter;
- a rejected block or measurement changes no state (decoder, sequence guard, filter);
- what a decoder publishes passes the measurement checks (finite, physical);
- valid data after a bad block keeps flowing (at most RESYNC_BLOCKS refused);
- the filter's state stays finite with a symmetric positive semi-definite covariance, and
  it never reports NOMINAL for a state it cannot stand behind;
- a decoder's memory per block is bounded by its configured largest block.
Timing per block is measured by ``python -m train_localization.tools.fuzz`` and the
benchmarks, not asserted here (shared machines are noisy).
"""
from __future__ import annotations

import copy
import functools
import math
import pickle
import tracemalloc

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from train_localization.core.fusion import MODE_LOST, MODE_NOMINAL, FusionConfig, FusionRunner, TrainFilter, sensor_models
from train_localization.core.measurements import DistanceIncrement, PositionFix, SpeedMeasurement
from train_localization.core.pipeline import SensorPipeline, simulate_and_decode
from train_localization.core.scenario import Scenario, Vehicle
from train_localization.core.sensors import NODE_NAMES, spec
from train_localization.core.signals import RESYNC_BLOCKS, InputRejected, RawBlock

from conftest import ROOT

# a checked-in scenario that has each sensor
SCENARIO_OF = {"doppler_radar": "demo", "wheel_sensor": "demo", "eurobalise_reader": "demo",
               "axle_counter": "demo", "lrl_scanner": "maglev_500", "inpo_receiver": "maglev_500",
               "mmwave_ranging": "maglev_500", "mmwave_tdoa": "maglev_500", "pattern_belt": "urban_stops", "lzb_receiver": "lzb",
               "track_circuit_receiver": "track_circuit", "dgps_receiver": "utm", "tag_reader": "utm",
               "coil_counter": "mlx", "emf_observer": "mlx", "checkin_loop": "hsst", "pole_position": "mbahn", "rig_loop_receiver": "rig_open",
               "gyro": "demo", "accelerometer": "demo"}
# parameters beside the scenario's: TDOA on the maglev line's 500 m spacing hears six stations
# (three on each side: a fix bounds a fault of two neighbours together) from 1.4 km
PARAMS_OF = {"mmwave_tdoa": {"max_range": 1400.0}}
# simulated time that gives WARM_UP + RESYNC_BLOCKS + 2 blocks: 2 s, but the DGPS delivers one
# epoch per 0.1 s block
T_END = {"dgps_receiver": 3.0}
WARM_UP = 20            # valid blocks decoded before the fuzzed one
FUZZ = settings(max_examples=60, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@functools.lru_cache(maxsize=None)
def _device(node: str):
    """(pipeline after WARM_UP valid blocks, the valid blocks that follow) of one sensor."""
    scen = Scenario.from_yaml(ROOT / "config" / f"scenario_{SCENARIO_OF[node]}.yaml")
    blocks = simulate_and_decode(node, scen, t_end=T_END.get(node, 2.0)).blocks
    pipe = SensorPipeline(spec(node), scen.sensors.get(node, {}), scen.track, scen.vehicle, simulate=False)
    for b in blocks[:WARM_UP]:
        pipe.on_block(b)
    return pipe, tuple(blocks[WARM_UP:WARM_UP + RESYNC_BLOCKS + 2])


def _state(pipe: SensorPipeline) -> bytes:
    """What a rejected block must not change: the decoder (but its statistics and memo caches)
    and the guard's reference blocks."""
    skip = {"stats", *pipe.decoder.caches}
    dec = {k: v for k, v in vars(pipe.decoder).items() if k not in skip}
    return pickle.dumps((dec, pipe.guard._last, pipe.accepted, pipe.measurements_out))


ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True)
FLOAT32 = st.floats(width=32, allow_nan=True, allow_infinity=True)


@st.composite
def raw_messages(draw, base: RawBlock):
    """The fields of a RawBlock message as a publisher may send them: the next valid block
    with any of its fields replaced by something arbitrary or subtly wrong."""
    f = dict(sensor=base.sensor, unit_id=base.unit_id, seq=base.seq, t0=base.t0,
             sample_rate=base.sample_rate, channels=base.channels, units=base.units,
             flat=base.data.reshape(-1).copy())
    if draw(st.booleans()):
        f["sensor"] = draw(st.sampled_from(["", "doppler", "wheel", "mmwave", "x" * 300]) | st.text(max_size=8))
    if draw(st.booleans()):
        f["unit_id"] = draw(st.text(max_size=8))
    if draw(st.booleans()):
        f["seq"] = draw(st.sampled_from([0, base.seq - 1, base.seq, base.seq + 1000, 2 ** 32 - 1])
                        | st.integers(0, 2 ** 32 - 1))
    if draw(st.booleans()):
        f["t0"] = draw(st.sampled_from([base.t0 + 1e6, base.t0 - 1.0, -1e300, 1e300, base.t0 + 1e-7])
                       | ANY_FLOAT | st.floats(-1e4, 1e4).map(lambda d: base.t0 + d))
    if draw(st.booleans()):
        f["sample_rate"] = draw(st.sampled_from([0.0, -base.sample_rate, 1e-300, 1e300, 2 * base.sample_rate,
                                                 0.5 * base.sample_rate, base.sample_rate * (1 + 1e-6)])
                                | ANY_FLOAT)
    if draw(st.booleans()):
        names = list(base.channels) + ["x", ""]
        f["channels"] = tuple(draw(st.lists(st.sampled_from(names), max_size=len(base.channels) + 1)))
        f["units"] = draw(st.sampled_from([f["channels"], base.units[:len(f["channels"])],
                                           ("V",) * len(f["channels"])]))
    flat, n_ch = f["flat"], len(base.channels)
    how = draw(st.sampled_from(["keep", "scale", "offset", "one_value", "noise", "arbitrary", "length", "longest"]))
    if how == "scale":
        flat = flat * np.float32(draw(st.floats(-1e6, 1e6, width=32)))
    elif how == "offset":
        flat = flat + np.float32(draw(st.floats(-1e6, 1e6, width=32)))
    elif how == "one_value":
        flat[draw(st.integers(0, flat.size - 1))] = draw(FLOAT32)
    elif how == "noise":
        rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
        flat = (flat + rng.normal(0.0, draw(st.sampled_from([1e-3, 0.1, 10.0, 1e4])), flat.size)).astype(np.float32)
    elif how == "arbitrary":
        flat = np.asarray(draw(st.lists(FLOAT32, max_size=2 * flat.size)), dtype=np.float32)
    elif how == "length":
        k = draw(st.integers(0, 3 * base.n_samples))
        flat = np.resize(flat, k * n_ch + draw(st.sampled_from([0, 0, 1, -1]))) if k else flat[:0]
    elif how == "longest":   # one sample past the configured largest block, or exactly it
        k = _device_max_samples(base.sensor) + draw(st.sampled_from([0, 1]))
        flat = np.resize(flat, k * n_ch)
    f["flat"] = flat
    return f


@functools.lru_cache(maxsize=None)
def _device_max_samples(sensor: str) -> int:
    node = next(n for n in NODE_NAMES if spec(n).sensor == sensor)
    return _device(node)[0].max_block_samples


def _fuzz_one_device(node: str, msg: dict) -> None:
    pipe, following = _device(node)
    pipe = copy.deepcopy(pipe)
    try:
        block = RawBlock.from_flat(**msg)
    except InputRejected:
        accepted_fuzz = False        # refused at the message boundary: nothing reached the pipeline
    else:
        before, rejected = _state(pipe), sum(pipe.rejected.values())
        try:
            out = pipe.on_block(block)
        except InputRejected as exc:
            assert _state(pipe) == before, f"rejected block ({exc.reason}) changed the pipeline's state"
            assert sum(pipe.rejected.values()) == rejected + 1 and pipe.rejected[exc.reason] >= 1
            accepted_fuzz = False
        else:
            for m in out:
                m.validate()         # finite and physical, or this raises
            accepted_fuzz = True
    # valid data keeps flowing: at once after a rejected block; after an accepted bad one the
    # guard takes the device's sequence again within RESYNC_BLOCKS blocks
    results = []
    for b in following:
        try:
            pipe.on_block(b)
            results.append(True)
        except InputRejected as exc:
            results.append(exc.reason)
    if not accepted_fuzz:
        assert results[0] is True, f"the valid block after a rejected one was refused: {results[0]}"
    assert results[-2:] == [True, True], results


@pytest.mark.parametrize("node", NODE_NAMES)
def test_arbitrary_raw_blocks_are_decoded_or_rejected_and_leave_no_trace(node):
    base = _device(node)[1][0]

    @FUZZ
    @given(raw_messages(base))
    def run(msg):
        _fuzz_one_device(node, msg)

    run()


@pytest.mark.parametrize("node", NODE_NAMES)
def test_memory_per_block_is_bounded_by_the_configured_largest_block(node):
    """The largest block a pipeline accepts (max_block_duration x sample_rate samples; here the
    device simulated in blocks of that length, the block with the most measurements of 40 s)
    costs at most BYTES_PER_VALUE per raw value of transient memory; a block one sample longer
    is refused before the decoder sees it."""
    BYTES_PER_VALUE = 1000
    scen = Scenario.from_yaml(ROOT / "config" / f"scenario_{SCENARIO_OF[node]}.yaml")
    params = {**scen.sensors.get(node, {}), **PARAMS_OF.get(node, {}), "block_duration": 1.0,
              "max_block_duration": 1.0}
    run = simulate_and_decode(node, scen, params=params, t_end=40.0)
    per_block = np.bincount([min(int((m.stamp - run.blocks[0].t0) // 1.0), len(run.blocks) - 1)
                             for m in run.measurements], minlength=len(run.blocks))
    busiest = int(per_block.argmax())
    pipe = SensorPipeline(spec(node), params, scen.track, scen.vehicle, simulate=False)
    for b in run.blocks[:busiest]:
        pipe.on_block(b)
    big = run.blocks[busiest]
    assert big.n_samples == pipe.max_block_samples
    tracemalloc.start()
    try:
        out = pipe.on_block(big)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert len(out) == per_block[busiest] >= 1
    assert peak <= BYTES_PER_VALUE * big.data.size, f"{peak / 1e6:.1f} MB for {big.data.size} values"
    nxt = run.blocks[busiest + 1]
    over = RawBlock.from_samples(nxt.sensor, nxt.unit_id, nxt.seq, nxt.t0, nxt.sample_rate, nxt.channels,
                                 nxt.units, np.vstack([nxt.data, nxt.data[-1:]]))
    with pytest.raises(InputRejected) as exc:
        pipe.on_block(over)
    assert exc.value.reason == "too_large" and pipe.rejected == {"too_large": 1}


# -- the filter ------------------------------------------------------------------------------
FUSED = ("doppler_radar", "wheel_sensor", "eurobalise_reader", "mmwave_ranging")
TRUE_SPEED = 20.0


def _truth(t: float) -> float:
    return 1000.0 + TRUE_SPEED * t


@st.composite
def measurement_streams(draw):
    """A stream of measurements at increasing stamps (sometimes late, repeated or absurd): most
    near the truth (s = 1000 + 20 t), some with arbitrary fields."""
    out, t = [], 0.0
    for _ in range(draw(st.integers(1, 40))):
        t += draw(st.sampled_from([0.05, 0.05, 0.2, 1.0, -0.3, 0.0]))
        stamp = draw(st.sampled_from([t, t, t, t + 1e6, -1e300]) | ANY_FLOAT) if draw(st.booleans()) else t
        wild = draw(st.booleans())
        kind = draw(st.sampled_from(["fix", "speed", "distance"]))
        sensor = draw(st.sampled_from(["eurobalise", "mmwave", "doppler", "wheel", "unknown"]))
        err = draw(st.floats(-5.0, 5.0))
        if kind == "fix":
            pos = draw(ANY_FLOAT) if wild else _truth(stamp if math.isfinite(stamp) else 0.0) + err
            sd = draw(ANY_FLOAT | st.sampled_from([1e-9, 1e-6, 1e5, 1e200])) if wild else 0.5
            out.append(PositionFix(stamp, sensor, sensor, draw(st.sampled_from(["T", "", "other"])),
                                   f"R{draw(st.integers(0, 5))}", pos, sd))
        elif kind == "speed":
            v = draw(ANY_FLOAT) if wild else TRUE_SPEED + 0.05 * err
            sd = draw(ANY_FLOAT | st.sampled_from([1e-6, 1e200])) if wild else 0.1
            out.append(SpeedMeasurement(stamp, sensor, sensor, v, sd))
        else:
            dur = draw(ANY_FLOAT | st.sampled_from([1e-300, 1e-6, 60.0])) if wild else 0.05
            d = draw(ANY_FLOAT) if wild else TRUE_SPEED * 0.05 * (1 + 0.01 * err)
            out.append(DistanceIncrement(stamp, sensor, sensor, dur, d, 0.01, d / dur if dur else 0.0, 0.1))
    return out


def _filter_state(f: TrainFilter):
    x, P, _ = f.state()
    return x.copy(), P.copy(), len(f.hist.meas)


@settings(FUZZ, max_examples=200)
@given(measurement_streams())
def test_the_filter_stays_finite_and_honest_under_arbitrary_measurements(stream):
    runner = FusionRunner(FusionConfig(sensors=sensor_models(list(FUSED), None, Vehicle())))
    f = runner.filter
    f.reset(position=_truth(0.0), position_stddev=1.0, speed=TRUE_SPEED, speed_stddev=0.1, stamp=0.0)
    t_query = 0.0
    for m in stream:
        x0, P0, n0 = _filter_state(f)
        if not runner.add(m):   # admission and history (core/fusion/admission.py)
            x1, P1, n1 = _filter_state(f)
            assert n1 == n0 and np.array_equal(x1, x0) and np.array_equal(P1, P0), "a rejection changed the state"
            continue
        if math.isfinite(m.stamp):
            t_query = max(t_query, m.stamp)
        x, P, _ = f.state()
        assert np.all(np.isfinite(x)) and np.all(np.isfinite(P))
        assert np.allclose(P, P.T, rtol=1e-9, atol=1e-12 * max(1.0, np.abs(P).max()))
        assert np.linalg.eigvalsh(0.5 * (P + P.T)).min() >= -1e-9 * max(1.0, np.abs(P).max())
        e = f.estimate(t_query)
        if e.mode == MODE_LOST:
            continue
        assert math.isfinite(e.position) and e.position_min <= e.position <= e.position_max
        assert abs(e.speed) <= 200.0 or e.mode != MODE_NOMINAL

"""Figures of the accelerometer (core/sensors/accelerometer.py) against the truth, quoted in
docs/nodes.md ("Accelerometer"); test/test_sensor_accelerometer.py drives the device the same way.

  python -m train_localization.tools.accelerometer_figures [--runs 20]

Each run: a 5 km track, level to 1 km, 20 per mille up to 3 km, 10 per mille down beyond
(vertical curves R 5 km), a left curve of R 1200 m from 1.5 km; the train starts at rest at
900 m, accelerates at 0.7 m/s^2 to 35 m/s and cruises, 40 s, the decoder told the true position.
Every parameter at its default, a random stream per run (seed = run index). Printed: the RMS
error of the decoded acceleration, the median reported 1-sigma, the largest |error| / 1-sigma,
the spread of error / 1-sigma, the RMS over runs of each run's mean error (the drawn bias's
share), and the speed error that run-mean error integrates to in 10 s.
"""
from __future__ import annotations

import argparse

import numpy as np

from ..core.pipeline import SensorPipeline
from ..core.sensors import spec
from ..core.sensors.accelerometer import TrackPosition
from ..core.track import Track
from ..core.truth import TruthState
from ..core.vehicle import Vehicle

RATE = 100.0   # [Hz] the truth's and the device's (default) sample rate
BLOCK = 5      # samples a block (default block_duration 0.05 s)


def graded_track(**extra) -> Track:
    """5 km: level to 1 km, 20 per mille up to 3 km, 10 per mille down beyond (vertical curves of
    R 5 km: 100 m and 150 m long); ``extra`` keys of the track file (an alignment)."""
    return Track.from_dict({"track_id": "t", "length": 5000.0, **extra, "gradient": {
        "vertical_curve_radius": 5000.0, "profile": [{"position": 0.0, "gradient": 0.0},
                                                     {"position": 1000.0, "gradient": 20.0},
                                                     {"position": 3000.0, "gradient": -10.0}]}})


def motion(t: float, s0: float, accel: float, v_max: float) -> TruthState:
    """From rest at s0 [m], ``accel`` [m/s^2] up to ``v_max`` [m/s], then cruising; at t [s]."""
    t_up = v_max / accel
    if t <= t_up:
        return TruthState(t, s0 + 0.5 * accel * t * t, accel * t, accel)
    return TruthState(t, s0 + 0.5 * v_max * t_up + v_max * (t - t_up), v_max, 0.0)


def run(params: dict, track: Track, duration: float, moving, placed=lambda st: (st.position, 0.0),
        seed: int = 7):
    """Simulate and decode ``duration`` s of ``moving`` (t -> TruthState, sampled at RATE), the
    decoder told the position ``placed(state)`` ((chainage [m], 1-sigma [m]); None: not told) at
    every truth state. Returns (measurements, the truth over each one's block: the means of
    (position, speed, acceleration), the SensorPipeline)."""
    pipe = SensorPipeline(spec("accelerometer"), params, track, Vehicle(), np.random.default_rng(seed))
    out, states = [], []
    for k in range(int(round(duration * RATE)) + 1):
        st = moving(k / RATE)
        states.append((st.position, st.speed, st.acceleration))
        where = placed(st)
        if where is not None:
            pipe.on_position(TrackPosition(st.stamp, where[0], where[1], st.speed))
        for block in pipe.on_truth(st):
            out += pipe.on_block(block)
    per_block = np.array(states)[:len(out) * BLOCK].reshape(len(out), BLOCK, 3).mean(axis=1)
    return out, tuple(per_block.T), pipe


def errors(out, truth) -> tuple[np.ndarray, np.ndarray]:
    """(decoded - true acceleration, reported 1-sigma) [m/s^2] per measurement."""
    return np.array([m.acceleration for m in out]) - truth[2], np.array([m.acceleration_stddev for m in out])


def figures(runs: int) -> dict[str, float]:
    """The module docstring's figures over ``runs`` runs."""
    track = graded_track(alignment=[{"length": 1500.0}, {"length": 3500.0, "curvature": 1 / 1200}])
    errs, sigmas, means = [], [], []
    for seed in range(runs):
        out, truth, _ = run({}, track, 40.0, lambda t: motion(t, 900.0, 0.7, 35.0), seed=seed)
        e, s = errors(out, truth)
        errs.append(e)
        sigmas.append(s)
        means.append(float(np.mean(e)))
    e, s = np.concatenate(errs), np.concatenate(sigmas)
    bias = float(np.sqrt(np.mean(np.square(means))))
    return {"blocks": len(e), "rms_error": float(np.sqrt(np.mean(e * e))), "median_sigma": float(np.median(s)),
            "max_ratio": float(np.max(np.abs(e) / s)), "ratio_std": float(np.std(e / s)), "run_mean_rms": bias,
            "speed_error_10s": 10.0 * bias}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=20, help="runs (seeds 0 .. runs-1)")
    f = figures(ap.parse_args(argv).runs)
    print(f"{f['blocks']} blocks: RMS error {f['rms_error']:.4f} m/s^2, median 1-sigma {f['median_sigma']:.4f} m/s^2, "
          f"max |error| / 1-sigma {f['max_ratio']:.2f}, std of error / 1-sigma {f['ratio_std']:.2f}; RMS of the "
          f"runs' mean error {f['run_mean_rms']:.4f} m/s^2 ({f['speed_error_10s']:.2f} m/s of speed in 10 s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

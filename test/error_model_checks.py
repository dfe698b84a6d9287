"""Checks of a sensor's ErrorModel (min_stddev, references) shared by the sensor tests.

A relative sensor's floor is checked on a grid of runs (``floor_runs``) and against forged
measurements at half the floor (``assert_refused_below_half_the_floor``); a position sensor's
floor and references against forged fixes (``assert_forged_fixes_refused``)."""
from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np

from train_localization.core.pipeline import simulate_and_decode
from train_localization.core.sensors import spec

BLOCK_DURATIONS = (0.01, 0.05, 0.5, 5.0)   # [s]: 10 ms .. 5 s, every case in each


def claimed(m) -> float:
    """The 1-sigma [m/s] a speed or an increment claims for ErrorModel.refusal: its speed's and,
    for an increment, the lower of that and its mean speed's (distance_stddev / duration)."""
    if hasattr(m, "distance_stddev"):
        return min(m.speed_stddev, m.distance_stddev / m.duration)
    return m.speed_stddev


def lasting(duration: float, params: dict) -> float:
    """A case's ``duration`` [s], at least 2.5 of the run's blocks (``params["block_duration"]``)."""
    return max(duration, 2.5 * params["block_duration"])


def decoded(node: str, sc, keep_going: bool = True) -> tuple[list, list, object]:
    """Scenario ``sc`` simulated and decoded by sensor ``node``: (measurements, rejected blocks,
    the error model of the run's parameters); without ``keep_going`` a rejected block raises."""
    run = simulate_and_decode(node, sc, keep_going=keep_going)
    return run.measurements, run.rejected, spec(node).errors(run.pipe.params, sc.track, sc.vehicle)


def floor_runs(cases: dict, ideal: dict, decode: Callable, drawn: Callable | None = None,
               every_run_decodes: bool = False, seed: int = 2024) -> tuple[dict, float]:
    """Runs every case of ``cases`` (name: whatever ``decode`` takes) in blocks of each of
    BLOCK_DURATIONS, every other run (block index + case index even) with the ``ideal``
    parameters, each with a seed drawn from ``np.random.default_rng(seed)``.

    ``decode(case, params, seed)`` simulates and decodes one run with the sensor parameters
    ``params`` (block_duration, max_block_duration, ``drawn(case, rng)`` if given, drawn before
    the run's seed, then ``ideal`` on its turn) and returns (measurements, rejected, model).
    Asserts that no block is rejected, that the model refuses no measurement and, with
    ``every_run_decodes``, that each run gives one. Returns (measurements per case, the lowest
    ``claimed`` 1-sigma / model.min_stddev)."""
    rng = np.random.default_rng(seed)
    n, lowest = {name: 0 for name in cases}, math.inf
    for i, block in enumerate(BLOCK_DURATIONS):
        for k, (name, case) in enumerate(cases.items()):
            params = {"block_duration": block, "max_block_duration": max(1.0, block)}
            if drawn is not None:
                params.update(drawn(case, rng))
            if (i + k) % 2 == 0:
                params.update(ideal)
            ms, rejected, model = decode(case, params, int(rng.integers(1 << 30)))
            assert not rejected, (name, params, rejected[:3])
            assert ms or not every_run_decodes, (name, params)
            for m in ms:
                assert model.refusal(m) is None, (name, params, m)
            n[name] += len(ms)
            lowest = min([lowest] + [claimed(m) / model.min_stddev for m in ms])
    return n, lowest


def assert_refused_below_half_the_floor(model, honest) -> None:
    """The ``honest`` speed or increment is taken, and so is it claiming exactly the floor
    (model.min_stddev > 0); claiming half the floor it is refused below_model: its speed's
    1-sigma, for an increment also its distance's, alone and both."""
    floor = model.min_stddev
    assert floor > 0.0 and model.refusal(honest) is None
    if hasattr(honest, "distance_stddev"):
        m = dataclasses.replace(honest, speed_stddev=floor, distance_stddev=floor * honest.duration)
        forgeries = (dataclasses.replace(m, speed_stddev=floor / 2),
                     dataclasses.replace(m, distance_stddev=floor / 2 * m.duration),
                     dataclasses.replace(m, speed_stddev=floor / 2, distance_stddev=floor / 2 * m.duration))
    else:
        m = dataclasses.replace(honest, speed_stddev=floor)
        forgeries = (dataclasses.replace(m, speed_stddev=floor / 2),)
    assert model.refusal(m) is None                      # at the floor: taken
    for forged in forgeries:
        why = model.refusal(forged)
        assert why is not None and why.reason == "below_model", forged


def assert_forged_fixes_refused(model, honest, unknown_id: str, far_position: float, far_id: str | None = None) -> None:
    """The ``honest`` fix is taken; forged from it, it is refused with the reason: below_model at
    half model.min_stddev, unknown_reference naming ``unknown_id``, reference_mismatch at
    ``far_position`` [m] (naming ``far_id`` if given)."""
    assert model.refusal(honest) is None
    far = {"position": far_position} | ({"reference_id": far_id} if far_id is not None else {})
    cases = {"below_model": dataclasses.replace(honest, position_stddev=0.5 * model.min_stddev),
             "unknown_reference": dataclasses.replace(honest, reference_id=unknown_id),
             "reference_mismatch": dataclasses.replace(honest, **far)}
    for reason, forged in cases.items():
        assert model.refusal(forged).reason == reason

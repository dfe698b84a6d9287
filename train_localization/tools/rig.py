"""The seed 003 rig in closed loop: speed steps through the localisation, overshoot and settling.

    python -m train_localization.tools.rig [--scenario config/scenario_rig.yaml] [--noise 5]

Runs ``core.offline.closed_loop`` on the scenario with the loop receiver's own noise (the
seed's circuit as modelled, core/sensors/rig_loop.py) and again with every noise figure of the
receiver multiplied by ``--noise``; prints per set-point step the overshoot [%] and the settling
time [s] (2 % band of the step) of the disc's true speed, and the fused errors.
"""
from __future__ import annotations

import argparse
import copy
import sys

import numpy as np

from ..core.control import step_response
from ..core.offline import closed_loop
from ..core.scenario import Scenario
from ..core.scoring import StateSeries, score

NOISE_PARAMS = ("noise", "gain_mismatch", "detector_offset", "gap_sigma", "spacing_error")


def noisier(scenario: Scenario, factor: float) -> Scenario:
    """The scenario with the loop receiver's noise figures multiplied by ``factor`` (and its
    decoder's switching-point scatter, which they cause)."""
    sc = copy.copy(scenario)
    sc.sensors = {name: dict(params) for name, params in scenario.sensors.items()}
    from ..core.sensors import spec
    from ..core.sensors.base import resolve_params
    for name, params in sc.sensors.items():
        if spec(name).sensor != "rig_loop":
            continue
        resolved = resolve_params(spec(name).params, params)
        for key in NOISE_PARAMS + ("transition_jitter",):
            params[key] = resolved[key] * factor
    return sc


def run(scenario: Scenario) -> dict:
    res = closed_loop(scenario)
    t = np.array([s.stamp for s in res.truth])
    v = np.array([s.speed for s in res.truth])
    truth = StateSeries.of_truth(t, [s.position for s in res.truth], v)
    circ = scenario.track.circumference
    figures = step_response(t, v, res.setpoints, float(res.controller.params["settling_band"]))
    return {"steps": figures, "score": score(truth, StateSeries.from_estimates(res.estimates), circ),
            "rejected": dict(res.runner.rejected)}


def report(label: str, out: dict) -> None:
    print(f"{label}:")
    for f in out["steps"]:
        settle = f"{f.settling_time:6.2f} s" if f.settling_time is not None else "not settled"
        print(f"  {f.v_from * 3.6:5.1f} -> {f.v_to * 3.6:5.1f} km/h at t = {f.t:5.1f} s: overshoot "
              f"{f.overshoot:5.2f} %, settling time {settle}")
    sc = out["score"]
    pe, ve = sc["position_error_m"], sc["speed_error_mps"]
    print(f"  fused: position error RMS {pe['rms']:.3f} m, max {pe['max']:.3f} m (modulo the circumference); "
          f"speed error RMS {ve['rms']:.3f} m/s, max {ve['max']:.3f} m/s; truth inside the interval "
          f"{100 * (sc['integrity']['inside_fraction'] or 0):.1f} %")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="config/scenario_rig.yaml")
    ap.add_argument("--noise", type=float, default=5.0, help="factor on the receiver's noise figures for "
                    "the second run (0: only the first)")
    args = ap.parse_args(argv)
    sc = Scenario.from_yaml(args.scenario)
    report("seed circuit noise", run(sc))
    if args.noise > 0:
        report(f"noise x {args.noise:g}", run(noisier(sc, args.noise)))
    return 0


if __name__ == "__main__":
    sys.exit(main())

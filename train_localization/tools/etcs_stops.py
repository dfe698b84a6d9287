"""Supervised stops at an end of authority in closed loop (core/etcs/supervised_run.py;
docs/etcs.md): randomised runs, or one scenario.

    python -m train_localization.tools.etcs_stops --runs 40 --seed 0 [--attacks] [--workers 2] [--out DIR]
    python -m train_localization.tools.etcs_stops --scenario config/scenario_etcs_stop.yaml

Each randomised run draws a line, a speed, an EOA, the braking and faults (``draw_stop``),
runs dynamics, sensors, fusion, the ETCS location function, the ATP supervision and the
speed controller together and scores where the true front came closest to the EOA; with
``--attacks`` each run also draws attacks on the chain (core/etcs/supervised_run.py ATTACKS:
a state stamped ahead at a standstill, a standstill report during a brake, a fix naming a far
group, a flood of unknown balise ids, two silent linked groups) and counts what was refused and
the brake releases while moving. Printed:
one line per run and the summary (margins short of the EOA, overruns, trips, the safe front
ends' coverage); ``--out`` writes runs.json and summary.json. Exit code 0, or with ``--check``
1 if any run overran its EOA, tripped, released a brake while moving, failed or had the truth
outside its safe front ends.
"""
from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from functools import partial
from pathlib import Path

import numpy as np


def _line(r: dict) -> str:
    if "error" in r:
        return f"seed {r['seed']}: ERROR {r['error']}"
    d = r["draw"]
    return (f"seed {r['seed']}: {d['top_speed_kmh']:.0f} km/h, EOA {d['eoa_distance']:.0f} m ahead, braking "
            f"{d['deceleration']:.2f} m/s^2 (assumed {d['assumed_deceleration']:.2f}) -> first at rest "
            f"{r['first_stop_margin']:.1f} m short, closest {r['margin']:.1f} m short, trips {r['trips']}, "
            f"brake onsets {r['interventions']}, events {r['events']}"
            + (f", attacks {r['attacked']}, refused {r['refused']}, releases while moving "
               f"{r['releases_while_moving']}" if r.get("attacks") else ""))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=20, help="randomised runs (default 20)")
    ap.add_argument("--seed", type=int, default=0, help="base seed: run i has seed base + i")
    ap.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")
    ap.add_argument("--scenario", help="run this scenario YAML (with control and atp) instead")
    ap.add_argument("--out", help="directory for runs.json and summary.json")
    ap.add_argument("--attacks", action="store_true", help="draw attacks on the chain in every run")
    ap.add_argument("--check", action="store_true", help="exit 1 on an overrun, a trip, a failure or the truth "
                                                         "outside the safe front ends")
    args = ap.parse_args(argv)
    from ..core.etcs import supervised_run as sr
    if args.scenario:
        from ..core.scenario import Scenario
        res = sr.supervised_stop(Scenario.from_yaml(args.scenario))
        print(f"{args.scenario}: EOA {res.end_of_authority:.1f} m, first at rest {res.first_stop_margin:.2f} m short, "
              f"closest {res.margin:.2f} m short; trips {res.trips}, brake onsets "
              f"{res.interventions}, events {res.events}; truth - min safe front end >= "
              f"{res.min_truth_to_safe_front:.3f} m, truth - max safe front end <= {res.max_safe_front_overshoot:.3f} m")
        bad = res.margin < 0 or res.trips or res.min_truth_to_safe_front < 0 or res.max_safe_front_overshoot > 0
        return 1 if args.check and bad else 0
    seeds = [args.seed + i for i in range(args.runs)]
    with ProcessPoolExecutor(max(1, args.workers)) as pool:
        results = []
        for r in pool.map(partial(sr.run_stop, attacks=args.attacks), seeds):
            print(_line(r), flush=True)
            results.append(r)
    summary = sr.stop_summary(results)
    print(json.dumps(summary, indent=1))
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "runs.json").write_text(json.dumps(results, indent=1, default=float))
        (out / "summary.json").write_text(json.dumps(summary, indent=1))
    bad = summary["overruns"] or summary["trips"] or summary["errors"] or summary["safe_front_violations"] \
        or summary["releases_while_moving"] or summary["far_groups_taken"]
    return 1 if args.check and bad else 0


if __name__ == "__main__":
    sys.exit(main())

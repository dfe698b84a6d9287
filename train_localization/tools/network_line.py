"""Randomised runs of several trains through drawn station throats with wayside axle
counters: is every head's fix handed to the train that passed it, and does every train keep
its track and its interval? (core/network/line_campaign.py; docs/network.md)

  python -m train_localization.tools.network_line --runs 40 --seed 0 [--workers N] [--out FILE]
  python -m train_localization.tools.network_line --run SEED      # one run, its full result

Prints the fixes offered, used, ambiguous, unexplained and given to a train that did not
cause them, the states NOMINAL on a wrong track, the truth inside the interval (all states,
the worst train), track selectivity and switch ways, and the checks against the goals;
writes every run's result and the summary as JSON (default out/network_line.json). Exit code
0 (a campaign is a measurement) unless ``--check``: then 1 when a check fails. Runs go to
``--workers`` local processes (default: the CPU count).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from ..core.network.line_campaign import run, summarise


def report(summary: dict) -> str:
    a = summary["association"]
    lines = [f"{summary['runs']} runs, {summary['trains']} trains, {summary['states']} states; errors: "
             f"{summary['errors'] or 'none'}",
             f"head fixes offered {a['offered']}: used {a['used']}, ambiguous {a['ambiguous']}, unexplained "
             f"{a['unexplained']}; given to a train that did not cause them: {a['wrong_train']} "
             f"{summary['runs_wrong_train'] or ''}",
             f"states NOMINAL on a wrong track: {summary['nominal_wrong_track']} "
             f"{summary['trains_nominal_wrong_track'] or ''}",
             f"truth inside the interval: {100 * (summary['inside_fraction'] or 0.0):.3f} % (worst train "
             f"{summary['worst_train']}); outside its true hypothesis: {summary['true_hypothesis_outside']}",
             f"track selectivity {100 * (summary['selectivity'] or 0.0):.3f} %; switch ways resolved "
             f"{summary['switch_ways'][0]}/{summary['switch_ways'][1]}",
             f"checks: {summary['checks']}; CPU {summary['cpu_s']:.0f} s"]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0, help="the runs' seeds are seed, seed + 1, ...")
    ap.add_argument("--run", type=int, default=None, help="one run of this seed: print its full result")
    ap.add_argument("--workers", type=int, default=None, help="worker processes (CPU count)")
    ap.add_argument("--out", default="out/network_line.json")
    ap.add_argument("--check", action="store_true", help="exit 1 when a check fails")
    args = ap.parse_args(argv)
    if args.run is not None:
        print(json.dumps(run(args.run), indent=1))
        return 0
    seeds = list(range(args.seed, args.seed + args.runs))
    t0 = time.time()
    results = []
    with ProcessPoolExecutor(max_workers=args.workers or os.cpu_count() or 1) as pool:
        for fut in as_completed([pool.submit(run, s) for s in seeds]):
            results.append(fut.result())
            print(f"\r{len(results)}/{len(seeds)} runs", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    results.sort(key=lambda r: r["seed"])
    summary = summarise(results)
    print(report(summary))
    print(f"({time.time() - t0:.0f} s)")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"summary": summary, "runs": results}, indent=1), encoding="utf-8")
    print(f"written {out}")
    return 1 if args.check and not all(summary["checks"].values()) else 0


if __name__ == "__main__":
    sys.exit(main())

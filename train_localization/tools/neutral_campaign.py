"""tl_neutral: randomised passages through the neutral-section changeover (seed 004
sections 4.1-4.2, Fig. 5-6).

  tl_neutral --passages 200 --seed 0 [--faults] [--controller staged|seed] [--layout seed|blocks]
             [--jobs N] [--out FILE]

Draws the runs (core/wayside/changeover_campaign.py: speeds 30-330 km/h, both directions,
headways down to close following, detector noise; ``--faults``: one injected fault in half
of the runs), simulates each (core/wayside/passage.py: the track-circuit and axle-counter
models, the combined occupancy, the controller, the catenary), prints the counts (short
circuits, switchings with a pantograph in an air section, safe-state entries by reason)
and the dead time per passage (min / median / p95 / max) against the time the train needs
to cross the neutral section, and writes the summary as JSON (default
out/neutral_campaign.json). Exit code 0 (a campaign is a measurement) unless ``--check``:
then 1 when a nominal run has a short circuit or an air-section switching. ``--controller
seed`` runs the same passages with seed 004 section 4.1's switching moments per running
direction (core/wayside/neutral_section.py SeedMomentsController) instead of the staged
one. ``--layout blocks`` lays the two track circuits over the whole 800 m blocks instead of
seed 004 section 4.2's 400 m next to the middle (catenary.Layout; docs/changeover.md).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

from ..core.wayside.changeover_campaign import LAYOUTS, generate, summarise
from ..core.wayside.neutral_section import CONTROLLERS
from ..core.wayside.passage import simulate


def _row(name: str, d: dict) -> str:
    if not d:
        return f"  {name:<34} -"
    return (f"  {name:<34} min {d['min']:8.2f}  median {d['median']:8.2f}  p95 {d['p95']:8.2f}  "
            f"max {d['max']:8.2f}")


def report(summary: dict) -> str:
    lines = [f"{summary['passages']} passages in {summary['runs']} runs ({summary['directions']}), "
             f"{summary['simulated_s']:.0f} s simulated"]
    for part in ("nominal", "faulty"):
        c = summary[part]
        if not c["runs"]:
            continue
        lines.append(f"{part}: {c['runs']} runs, {c['passages']} passages: short circuits {c['short_circuits']}, "
                     f"switchings with a pantograph in an air section {c['air_section_switchings']}, "
                     f"contradictions {c['contradictions']}")
        for why, n in c["safe_state_entries"].items():
            lines.append(f"    safe state / hold: {why}: {n}")
    for kind, c in summary["faulty"].get("by_fault", {}).items():
        lines.append(f"  {kind}: {c['runs']} runs, safe state in {c['safe_state']}, without a safe state "
                     f"{c['hold_only_or_none']}, short circuits {c['short_circuits']}, air-section switchings "
                     f"{c['air_section_switchings']}")
    lines.append("per passage [s]:")
    lines.append(_row("dead time", summary["dead_time_s"]))
    lines.append(_row("crossing time of the neutral section", summary["crossing_time_s"]))
    lines.append(_row("dead time / crossing time", summary["dead_over_crossing"]))
    for band, d in summary["by_speed"].items():
        lines.append(_row(f"dead time {band} ({d['passages']})", d["dead_time"]))
    w = summary["worst_dead_time"]
    if w:
        lines.append(f"longest dead time: {w['dead_time']:.2f} s ({w['kind']} at {w['speed_kmh']:.0f} km/h, "
                     f"crossing time {w['crossing_time']:.1f} s)")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="tl_neutral", description=__doc__.split("\n\n")[0])
    ap.add_argument("--passages", type=int, default=200, help="number of train passages (200)")
    ap.add_argument("--seed", type=int, default=0, help="campaign seed (0)")
    ap.add_argument("--faults", action="store_true", help="inject one fault in half of the runs")
    ap.add_argument("--controller", choices=sorted(CONTROLLERS), default="staged",
                    help="staged (default): at the last axle, both systems agreeing; seed: seed 004 section "
                         "4.1's moments per running direction")
    ap.add_argument("--layout", choices=sorted(LAYOUTS), default="seed",
                    help="seed (default): 400 m track circuits next to the middle counting point (seed 004 "
                         "section 4.2); blocks: track circuits over the whole 800 m blocks")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (1)")
    ap.add_argument("--out", default="out/neutral_campaign.json", help="JSON summary (out/neutral_campaign.json)")
    ap.add_argument("--check", action="store_true", help="exit 1 on a short circuit or air-section switching in a "
                                                         "nominal run")
    args = ap.parse_args(argv)
    if args.passages < 1 or args.jobs < 1:
        ap.error("--passages and --jobs must be >= 1")
    runs = [dataclasses.replace(run, controller_kind=args.controller)
            for run in generate(args.passages, args.seed, args.faults, args.layout)]
    t0 = time.monotonic()
    if args.jobs > 1:
        from multiprocessing import get_context
        with get_context("spawn").Pool(args.jobs) as pool:
            results = pool.map(simulate, runs, chunksize=1)
    else:
        results = [simulate(run) for run in runs]
    summary = summarise(runs, results)
    summary.update(seed=args.seed, faults=args.faults, controller=args.controller, layout=args.layout,
                   wall_s=time.monotonic() - t0)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(summary, indent=1))
    print(report(summary))
    print(f"summary: {out} ({summary['wall_s']:.0f} s)")
    bad = summary["nominal"]["short_circuits"] or summary["nominal"]["air_section_switchings"]
    return 1 if args.check and bad else 0


if __name__ == "__main__":
    sys.exit(main())

"""tl_campaign: Monte Carlo integrity campaign of the fusion's confidence interval.

  tl_campaign --runs 600 [--families conventional,urban_maglev,highspeed_maglev] [--seed BASE]
      [--out DIR] [--workers N] [--scheduler tcp://HOST:PORT | local] [--max-duration S] [--check]
  tl_campaign --run FAMILY:SEED [FAMILY:SEED ...] [--out DIR]      one or more given runs again
  tl_campaign --export FAMILY:SEED [-o file.yaml]                   a run's scenario as YAML

Each run draws its own track, speed profile, adhesion, sensor noise, faults and
delivery of the measurements to the fusion from (family, seed) (core/campaign.py),
simulates the sensors once, fuses and scores the published states against the
truth. The runs are split evenly over the families; run i's seed is derived from
BASE and i and printed with its one-line result, so that any run can be
reproduced (``--run``, ``--export``).

Runs go to local worker processes (``--workers``, default: the CPU count), or with
``--scheduler`` to a dask.distributed scheduler (``local``: a LocalCluster on
127.0.0.1 with ``--workers`` single-threaded worker processes).

Output in DIR (default out/campaign): runs/<family>-<seed>.json per run, summary.json,
integrity.png (inside fraction per run, sorted), error_vs_half_width.png,
normalised_error.png (histogram with the N(0, 1) density). The summary table is
printed at the end. The exit code is 0 (a campaign is a measurement) unless
``--check``: then 1 if the truth is inside the interval in < 99.9 % of all states,
any run < 99.5 %, any excursion lasts > 2 s, any run failed, or (the long-stator
families, core/wayside/stator.py) a stator section switched off under a vehicle, or (runs with
a Eurobalise reader, core/etcs) the true front is within the ETCS safe front ends in < 99.9 %
of the location reports, or (the families ``network`` and ``network_etcs``, core/network) the
track selectivity on parallel track is < 99.9 %, < 99.5 % of the facing switches' ways are
resolved within their clearance, or a state is NOMINAL on a wrong track.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import yaml

from .workers import run_jobs
from ..core.campaign import (ALL_FAMILIES, EXCURSION_LIMIT, FAMILIES, INSIDE_TARGET, RUN_TARGET, SELECTIVITY_TARGET,
                             SWITCH_WAY_TARGET, generate, jobs, run_one, summarise)


def _family_seed(text: str) -> tuple[str, int]:
    try:
        family, seed = text.split(":")
        seed_value = int(seed)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected FAMILY:SEED, got {text!r}") from None
    if family not in ALL_FAMILIES:
        raise argparse.ArgumentTypeError(f"unknown family {family!r}; known: {', '.join(ALL_FAMILIES)}")
    return family, seed_value


def _families(text: str) -> tuple[str, ...]:
    names = tuple(f.strip() for f in text.split(",") if f.strip())
    unknown = [f for f in names if f not in ALL_FAMILIES]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"unknown families {unknown}; known: {', '.join(ALL_FAMILIES)}")
    return names


def one_line(i: int, n: int, r: dict) -> str:
    """The printed result of one run (family and seed reproduce it)."""
    head = f"[{i:>{len(str(n))}}/{n}] {r['family']}:{r['seed']}"
    if "error" in r:
        return f"{head} ERROR {r['error']} (cpu {r['cpu_s']:.1f} s)"
    s = r["scores"]
    inside = s["integrity"]["inside_fraction"]
    err = s["position_error_m"]["max"]
    net = r.get("network")
    network = (f", selectivity {_pct(net.get('selectivity'))}, ways {net.get('switch_ways_resolved', 0)}/"
               f"{net.get('switch_ways', 0)}, NOMINAL on a wrong track {net.get('nominal_wrong_track', 0)}"
               if net else "")
    return (f"{head} inside {'-' if inside is None else f'{100 * inside:.3f} %'} of "
            f"{s['states_with_position']} states, longest excursion {s['excursions']['longest_s']:.3f} s, "
            f"max |error| {'-' if err is None else f'{err:.3f} m'}, mean width "
            f"{s['integrity']['mean_interval_width_m'] or 0.0:.3f} m{network} (cpu {r['cpu_s']:.1f} s)")


def execute(todo: list[tuple[str, int]], workers: int | None = None, scheduler: str | None = None,
            max_duration: float | None = None, on_result=None, oracle: bool = False) -> list[dict]:
    """Run (family, seed) pairs with ``core.campaign.run_one`` in parallel; returns the results in
    completion order and calls ``on_result(result)`` as each arrives. ``workers``, ``scheduler``:
    where they run (tools/workers.py ``run_jobs``: a local process pool, a dask LocalCluster or
    a running dask.distributed scheduler)."""
    results = []

    def take(r: dict) -> None:
        results.append(r)
        if on_result:
            on_result(r)

    def lost(job: tuple, exc: BaseException) -> None:   # the worker itself died
        family, seed = job[0], job[1]
        take({"family": family, "seed": seed, "max_duration": max_duration, "cpu_s": 0.0,
              "error": f"{type(exc).__name__}: {exc}", "traceback": repr(exc)})

    run_jobs(run_one, [(f, s, max_duration, oracle) for f, s in todo], workers, scheduler,
             lambda job, r: take(r), lost)
    return results


def write_run(out: Path, r: dict) -> Path:
    path = out / "runs" / f"{r['family']}-{r['seed']}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(r, allow_nan=False, indent=1))
    return path


def plot(results: list[dict], summary: dict, out: Path) -> list[Path]:
    """integrity.png, error_vs_half_width.png, normalised_error.png; returns the files."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    ok = [r for r in results if "error" not in r and r["scores"]["integrity"]["inside_fraction"] is not None]
    colours = {f: f"C{i}" for i, f in enumerate(ALL_FAMILIES)}
    files = []

    def save(fig, name):
        files.append(out / name)
        fig.tight_layout()
        fig.savefig(files[-1], dpi=110)
        plt.close(fig)

    fig, ax = plt.subplots(figsize=(9, 4.5))
    rows = sorted(ok, key=lambda r: r["scores"]["integrity"]["inside_fraction"])
    y = np.array([100 * r["scores"]["integrity"]["inside_fraction"] for r in rows])
    for f in ALL_FAMILIES:
        k = [i for i, r in enumerate(rows) if r["family"] == f]
        if k:
            ax.scatter(np.array(k), y[k], s=8, color=colours[f], label=f)
    ax.axhline(100 * RUN_TARGET, color="tab:red", ls="--", lw=0.8, label="99.5 % (every run)")
    ax.axhline(100 * INSIDE_TARGET, color="k", ls=":", lw=0.8, label="99.9 % (all states)")
    ax.set_ylim(max(0.0, min(99.0, (y.min() if y.size else 100.0) - 0.2)), 100.05)
    ax.set_xlabel("runs, sorted by their inside fraction")
    ax.set_ylabel("truth inside [min, max] [% of the run's states]")
    ax.set_title(f"integrity per run ({len(rows)} runs): all states "
                 f"{100 * (summary['all']['inside_fraction'] or 0):.3f} %")
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3)
    save(fig, "integrity.png")

    fig, ax = plt.subplots(figsize=(6.5, 5.5))
    for f in ALL_FAMILIES:
        err = [abs(e) for r in ok if r["family"] == f for e in r["scores"]["error_vs_half_width"]["error_m"]]
        half = [h for r in ok if r["family"] == f for h in r["scores"]["error_vs_half_width"]["half_width_m"]]
        if err:
            ax.scatter(half, np.maximum(err, 1e-6), s=2, alpha=0.4, color=colours[f], label=f)
    ax.set_xscale("log")
    ax.set_yscale("log")
    lim = ax.get_xlim()
    ax.plot(lim, lim, "k--", lw=0.8, label="|error| = half-width (outside above)")
    ax.set_xlabel("interval half-width [m]")
    ax.set_ylabel("|position error| [m]")
    ax.set_title("error vs interval half-width (subsampled)")
    ax.legend(fontsize=8, markerscale=4)
    ax.grid(alpha=0.3, which="both")
    save(fig, "error_vs_half_width.png")

    fig, ax = plt.subplots(figsize=(8, 4.5))
    ne = summary["all"]["normalised_error"]
    if ne["counts"] and sum(ne["counts"]):
        edges, counts = np.array(ne["edges"]), np.array(ne["counts"], dtype=float)
        width = np.diff(edges)
        ax.stairs(counts / (counts.sum() * width), edges, label="error / position 1-sigma (all runs)")
        x = np.linspace(edges[0], edges[-1], 400)
        ax.plot(x, np.exp(-0.5 * x * x) / math.sqrt(2 * math.pi), "k--", lw=0.8, label="N(0, 1)")
        ax.set_yscale("log")
        ax.set_ylim(0.1 / counts.sum(), 1.0)
    ax.set_xlabel("normalised position error (end bins hold everything beyond)")
    ax.set_ylabel("density")
    ax.set_title(f"normalised errors: rms {ne['rms'] or 0:.3f}")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    save(fig, "normalised_error.png")
    return files


def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:.3f} %"


def summary_table(summary: dict) -> str:
    """The summary as a text table: one row per family and one over all runs."""
    cols = ("runs", "err", "states", "inside", "outside NOMINAL", "worst run", "<99.5 %", "longest exc.", "ETCS env.",
            "speed band viol. (NOMINAL)", "speed outside", "cpu s/run")
    lines = []
    rows = [(f, s) for f, s in summary["families"].items()] + [("all", summary["all"])]
    table = []
    for name, s in rows:
        worst = s["worst_run"]
        exc = s["longest_excursion"]
        env = s.get("etcs_envelope")
        table.append((name, str(s["runs"]), str(s["errors"]), str(s["states_with_position"]),
                      _pct(s["inside_fraction"]),
                      f"{s.get('outside_nominal', 0)} in {len(s.get('runs_outside_nominal', []))} runs",
                      f"{_pct(worst['inside_fraction'])} ({worst['seed']})" if worst else "-",
                      str(len(s["runs_below_99_5"])),
                      (f"{exc['s']:.3f} s ({exc['seed']})" if exc["s"] > 0 else "0 s") if exc else "-",
                      _pct(env["fraction"]) if env else "-",
                      f"{s['speed_band']['violations']} in {len(s['speed_band']['runs_with_violations'])} runs "
                      f"({s['speed_band'].get('violations_nominal', 0)})",
                      (f"{s['speed_interval']['outside']} in {len(s['speed_interval']['runs_with_outside'])} runs"
                       if "speed_interval" in s else "-"),
                      f"{s['cpu_s']['mean']:.1f}" if s["cpu_s"]["mean"] is not None else "-"))
    header = ("family",) + cols
    widths = [max(len(r[i]) for r in table + [header]) for i in range(len(header))]
    for r in [header] + table:
        lines.append("  ".join(c.ljust(w) for c, w in zip(r, widths)))
    lines.insert(1, "  ".join("-" * w for w in widths))
    checks = summary["checks"]
    for name, s in rows:
        if s.get("fusion_refused"):
            lines.append(f"{name}: fusion refused " + ", ".join(f"{k} {v}" for k, v in s["fusion_refused"].items()))
    for name, s in rows:
        a = s.get("availability")
        if a and a["states"]:
            lines.append(f"{name}: availability against the oracle: mean width {a['mean_width_m']:.3f} m / "
                         f"{a['oracle_mean_width_m']:.3f} m = {a['width_ratio']:.3f}, RMS error ratio "
                         f"{a['error_ratio']:.3f}, LOST where the oracle was not {a['lost_needlessly']} states "
                         f"({_pct(a['lost_needlessly_fraction'])})")
    for name, s in rows:
        st = s.get("stator")
        if st:
            pp = st["thrust_loss_per_passage_s"]
            lines.append(f"{name}: stator feeding ({st['runs']} runs, {st['section_passages']} section passages, "
                         f"{st['switchings']} switchings): switched off under the vehicle {st['switched_off_under_vehicle']}, "
                         f"switched on late (the vehicle over it) {st['switched_on_late']}, "
                         f"an inverter feeding two sections {st['double_feed']}, thrust lost {st['thrust_loss_s']:.3f} s "
                         f"in {len(st['runs_with_thrust_loss'])} runs; per passage median {pp['median']:.4f} s, "
                         f"p95 {pp['p95']:.4f} s, max {pp['max']:.4f} s")
    for name, s in rows:
        e = s.get("etcs")
        if e:
            r041, rfix = e["run_median_ratio_subset041"], e["run_median_ratio_fixed_rule"]
            ev = e["events"]
            lines.append(f"{name}: ETCS location ({e['runs']} runs, {e['reports_claimed']} reports): true front within "
                         f"the safe front ends {_pct(e['inside_share'])} ({e['outside']} outside); doubt / (5 m + 5 %) "
                         + (f"run medians: median {r041['median']:.3f}, p95 {r041['p95']:.3f}; doubt / (Q_LOCACC + "
                            f"1 %): median {rfix['median']:.3f}, p95 {rfix['p95']:.3f}; " if r041 else "- ; ")
                         + f"v_ura covers the speed {_pct(e['speed_inside_share'])}, within SUBSET-041's band "
                         f"{_pct(e['speed_within_subset041_share'])}; missed linked groups "
                         f"{ev.get('missed_linked_group', 0)} ({e['missed_but_read']} read), outside window "
                         f"{ev.get('outside_window', 0)}, wrong direction {ev.get('wrong_direction', 0)}, odometer "
                         f"impaired {ev.get('odometer_impaired', 0)}")
    for name, s in rows:
        n = s.get("network")
        if n:
            lines.append(f"{name}: network ({n['runs']} runs, {n['claimed']} states): track selectivity "
                         f"{_pct(n['selectivity'])} of {n['parallel_states']} states on parallel track (goal "
                         f">= {100 * SELECTIVITY_TARGET:.1f} %); switch ways resolved within the clearance "
                         f"{n['switch_ways_resolved']}/{n['switch_ways']} ({_pct(n['switch_way_share'])}, goal >= "
                         f"{100 * SWITCH_WAY_TARGET:.1f} %); NOMINAL on a wrong track {n['nominal_wrong_track']} "
                         f"(goal 0), on a wrong track {n['wrong_track_states']}; no hypothesis on the true route "
                         f"holding the truth {n['true_hypothesis_outside']}; DEGRADED {_pct(n['degraded_share'])}; "
                         f"switches reported the wrong way {len(n['wrong_reports'])}, found "
                         f"{n['wrong_reports_found']}, their way resolved "
                         f"{sum(1 for w in n['wrong_reports'] if w[4])}")
    lines.append(f"targets: all states >= {100 * INSIDE_TARGET:.1f} % inside: {checks['inside_fraction']}; "
                 f"every run >= {100 * RUN_TARGET:.1f} %: {checks['every_run_above_99_5']}; "
                 f"no excursion > {EXCURSION_LIMIT:.0f} s: {checks['excursions_within_2_s']}; "
                 f"no failed run: {checks['no_errors']}; "
                 f"none outside while NOMINAL: {checks.get('none_outside_nominal')}"
                 + (f"; no stator section switched off under a vehicle: "
                    f"{checks['stator_none_switched_off_under_vehicle']}"
                    if "stator_none_switched_off_under_vehicle" in checks else "")
                 + (f"; ETCS safe front ends >= {100 * INSIDE_TARGET:.1f} %: {checks['etcs_safe_front_ends']}"
                    if "etcs_safe_front_ends" in checks else "")
                 + (f"; network: selectivity >= {100 * SELECTIVITY_TARGET:.1f} %: {checks['network_selectivity']}, "
                    f"switch ways >= {100 * SWITCH_WAY_TARGET:.1f} %: {checks['network_switch_ways']}, none NOMINAL "
                    f"on a wrong track: {checks['network_none_nominal_wrong_track']}"
                    if "network_selectivity" in checks else "") + " -> "
                 f"{'PASSED' if summary['passed'] else 'FAILED'}")
    return "\n".join(lines)


def export(family: str, seed: int, path: str | None, max_duration: float | None) -> int:
    text = yaml.safe_dump(generate(family, seed, max_duration), sort_keys=False)
    if path:
        Path(path).write_text(text)
        print(f"wrote {path} ({family}:{seed})")
    else:
        sys.stdout.write(text)
    return 0


def report(results: list[dict], out: Path, campaign: dict, check: bool) -> int:
    """Write DIR/summary.json and the plots, print the table; the exit code of --check."""
    summary = summarise(results)
    summary["campaign"] = campaign
    (out / "summary.json").write_text(json.dumps(summary, allow_nan=False, indent=1))
    files = plot(results, summary, out)
    print(summary_table(summary))
    wall = campaign.get("wall_s")
    print((f"wall {wall:.0f} s; " if wall is not None else "") + f"wrote {out / 'summary.json'}, "
          f"{len(results)} run files in {out / 'runs'}, " + ", ".join(p.name for p in files))
    return 1 if check and not summary["passed"] else 0


def summarise_dir(out: Path, check: bool) -> int:
    """Summary and plots of the run files in ``out``/runs."""
    files = sorted((out / "runs").glob("*.json"))
    if not files:
        print(f"no run files in {out / 'runs'}", file=sys.stderr)
        return 2
    results = [json.loads(f.read_text()) for f in files]
    return report(results, out, {"runs": len(results), "families": sorted({r["family"] for r in results}),
                                 "summarised_from": str(out / "runs")}, check)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="tl_campaign", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="\n\n".join(__doc__.split("\n\n")[1:]))
    ap.add_argument("--runs", type=int, default=60, help="number of runs, split evenly over the families (60)")
    ap.add_argument("--families", type=_families, default=FAMILIES, help="comma-separated, of " + ", ".join(ALL_FAMILIES) +
                    " (default: the first three; the others are the later sensor kinds)")
    ap.add_argument("--seed", type=int, default=0, help="base seed BASE of the run seeds (0)")
    ap.add_argument("--run", type=_family_seed, nargs="+", metavar="FAMILY:SEED",
                    help="run these (family, seed) pairs instead of --runs")
    ap.add_argument("--out", default="out/campaign", help="output directory (out/campaign)")
    ap.add_argument("--workers", type=int, default=None, help="worker processes (CPU count)")
    ap.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT|local",
                    help="run on a dask.distributed scheduler; 'local' starts a LocalCluster on 127.0.0.1")
    ap.add_argument("--max-duration", type=float, default=None, metavar="S",
                    help="cut every run to at most S simulated seconds (quick checks; conditions unchanged)")
    ap.add_argument("--check", action="store_true", help="exit 1 when an integrity target fails or a run errors")
    ap.add_argument("--export", type=_family_seed, metavar="FAMILY:SEED", help="write this run's scenario YAML")
    ap.add_argument("-o", "--output", default=None, help="--export: file to write (default: stdout)")
    ap.add_argument("--summarise", metavar="DIR", help="summarise the run files already in DIR/runs (an "
                                                      "interrupted campaign, or runs gathered from several) "
                                                      "instead of running")
    ap.add_argument("--oracle", action="store_true", help="also run the availability oracle (the same fusion told "
                                                          "by the truth which measurements are faulty: "
                                                          "core/oracle.py) and report width and error against it")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    if args.export:
        return export(*args.export, args.output, args.max_duration)
    if args.summarise:
        return summarise_dir(Path(args.summarise), args.check)
    todo = list(args.run) if args.run else jobs(args.runs, args.families, args.seed)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"{len(todo)} runs ({', '.join(sorted({f for f, _ in todo}))}), base seed {args.seed}, "
          f"{'dask ' + args.scheduler if args.scheduler else f'{args.workers or os.cpu_count()} local processes'}"
          f" -> {out}", flush=True)
    from tqdm import tqdm
    bar = tqdm(total=len(todo), unit="run", disable=args.quiet, file=sys.stderr, smoothing=0.0)
    done = []

    def on_result(r: dict) -> None:
        done.append(r)
        write_run(out, r)
        bar.write(one_line(len(done), len(todo), r), file=sys.stdout)
        bar.update(1)

    t0 = time.perf_counter()
    try:
        results = execute(todo, args.workers, args.scheduler, args.max_duration, on_result, args.oracle)
    finally:
        bar.close()
    return report(results, out, {"runs": len(todo), "base_seed": args.seed,
                                 "families": sorted({f for f, _ in todo}), "max_duration": args.max_duration,
                                 "wall_s": time.perf_counter() - t0,
                                 "scheduler": args.scheduler or f"processes:{args.workers or os.cpu_count()}"},
                  args.check)


if __name__ == "__main__":
    sys.exit(main())

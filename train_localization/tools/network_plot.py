"""Plot a run through a network: per train, the track hypotheses' probabilities against time
and the track each state names against the true one (docs/network.md).

  python -m train_localization.tools.network_plot [--scenario config/scenario_throat.yaml]
         [--out docs/network_throat.png]

The scenario runs offline (core/offline/: simulate_scenario / simulate_line, the same code
as the live graph); the figure has one row per train: left, the probability of every
hypothesis (named by the ways it takes at the facing switches) around the switches, with the
DEGRADED states shaded; right, the section each published state names and the true one.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ..core.offline import simulate_scenario
from ..core.scenario import Scenario


def _windows(estimates, margin: float = 3.0) -> tuple[float, float]:
    """The time span [s] in which the train had more than one hypothesis (plus margins)."""
    several = [e.stamp for e in estimates if len(e.hypotheses) > 1]
    if not several:
        return estimates[0].stamp, estimates[-1].stamp
    return min(several) - margin, max(several) + margin


def plot(scenario: Scenario, out: Path, fusion_rate: float = 50.0) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    result = simulate_scenario(scenario, fusion_rate=fusion_rate)
    runs = result.trains if scenario.line else {scenario.train_name: result}
    fig, axes = plt.subplots(len(runs), 2, figsize=(12, 3.2 * len(runs)), squeeze=False)
    for row, (name, run) in enumerate(runs.items()):
        train = scenario.train(name)
        est = run.estimates
        t = np.array([e.stamp for e in est])
        lo, hi = _windows(est)
        ax = axes[row][0]
        series: dict[str, list] = {}
        for e in est:
            if not lo <= e.stamp <= hi:
                continue
            for h in e.hypotheses:
                label = ", ".join(f"{node} {way}" for node, way in h.ways) or "before the first switch"
                series.setdefault(label, []).append((e.stamp, h.probability))
        for label, pts in series.items():
            arr = np.array(pts)
            ax.plot(arr[:, 0], arr[:, 1], ".", ms=2, label=label)
        degraded = np.array([e.mode == 2 for e in est])
        sel = (t >= lo) & (t <= hi)
        ax.fill_between(t[sel], 0, 1, where=degraded[sel], color="0.85", step="mid", label="DEGRADED")
        ax.set(xlabel="time [s]", ylabel="probability", ylim=(-0.05, 1.05),
               title=f"{name}: track hypotheses (the ways each takes)")
        ax.legend(fontsize=7, loc="center left")
        ax = axes[row][1]
        sections = sorted(scenario.network.sections)
        index = {s: i for i, s in enumerate(sections)}
        truth_t = np.array([s.stamp for s in run.truth])
        truth_sec = [train.route.locate(s.position + train.route.begin)[0] for s in run.truth]
        ax.plot(truth_t, [index[s] for s in truth_sec], "-", color="k", lw=3, alpha=0.3, label="true section")
        ax.plot(t, [index.get(e.track_id, -1) for e in est], ".", ms=2, label="published track_id")
        ax.set_yticks(range(len(sections)), sections)
        ax.set(xlabel="time [s]", title=f"{name}: published track vs truth")
        ax.legend(fontsize=7)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="config/scenario_throat.yaml")
    ap.add_argument("--out", default="docs/network_throat.png")
    args = ap.parse_args(argv)
    scenario = Scenario.from_yaml(args.scenario)
    if scenario.network is None and not any(tr.network for tr in scenario.trains.values()):
        print(f"{args.scenario} does not run on a network", file=sys.stderr)
        return 2
    print(plot(scenario, Path(args.out)))
    return 0


if __name__ == "__main__":
    sys.exit(main())

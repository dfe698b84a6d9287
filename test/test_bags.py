"""Regression: every bag in bags/ replays offline within its stored bounds, and the
offline replay agrees with the live graph that recorded it."""
from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import ROOT
from train_localization.core import convert
from train_localization.core.offline import replay_bag, scenario_from_bag
from train_localization.core.report import evaluate
from train_localization.tools.make_bags import metric
from train_localization.tools.replay import recorded_run

BAGS = ROOT / "bags"
TABLE = json.loads((BAGS / "thresholds.json").read_text()) if (BAGS / "thresholds.json").exists() else {}


def test_every_bag_has_bounds_and_is_small():
    bags = sorted(p.stem for p in BAGS.glob("*.mcap"))
    assert len(bags) >= 5
    assert bags == sorted(TABLE), "bags/thresholds.json must list exactly the bags in bags/"
    for name in bags:
        assert (BAGS / f"{name}.mcap").stat().st_size < 5e6, f"{name}.mcap is over 5 MB"
        assert f"`{name}.mcap`" in (BAGS / "README.md").read_text(), f"{name} is not described in bags/README.md"


@pytest.fixture(scope="module", params=sorted(TABLE))
def replayed(request):
    """(bag name, offline replay of the bag, its report)."""
    name = request.param
    bag = BAGS / f"{name}.mcap"
    run = replay_bag(bag, scenario_from_bag(bag))
    report, _ = evaluate(run.truth, run.estimates, run.measurements)
    return name, run, report


def test_offline_replay_scores_stay_within_stored_bounds(replayed):
    name, _, report = replayed
    failures = []
    for key, bound in TABLE[name]["bounds"].items():
        value = metric(report, key)
        if "max" in bound and not value <= bound["max"]:
            failures.append(f"{name}.mcap: {key} = {value:.6g} is worse than the bound {bound['max']:.6g}")
        if "min" in bound and not value >= bound["min"]:
            failures.append(f"{name}.mcap: {key} = {value:.6g} is worse than the bound {bound['min']:.6g}")
    assert not failures, "\n".join(failures)


def test_offline_replay_matches_the_live_graph_within_the_filter_tolerance(replayed):
    name, run, _ = replayed
    _, live, _, _ = recorded_run(BAGS / f"{name}.mcap")
    offline = run.estimates
    off_t = np.array([e.stamp for e in offline])
    off_s = np.array([e.position for e in offline])
    live_t = np.array([convert.stamp_to_sec(m.header.stamp) for m in live])
    live_s = np.array([m.position for m in live])
    live_sd = np.array([m.position_stddev for m in live])
    both = np.isfinite(live_s) & (live_t >= off_t[0]) & (live_t <= off_t[-1])
    idx = np.searchsorted(off_t, live_t[both])
    idx = np.clip(idx, 0, len(off_t) - 1)
    same_time = np.abs(off_t[idx] - live_t[both]) < 1e-6
    diff = np.abs(off_s[idx][same_time] - live_s[both][same_time])
    sd = live_sd[both][same_time]
    ok = np.isfinite(diff)
    assert ok.sum() > 0.5 * both.sum(), f"{name}: too few common states"
    within = diff[ok] <= 3.0 * sd[ok]
    assert within.mean() >= 0.99, (f"{name}: offline and live fused position differ by more than 3 sigma in "
                                   f"{100 * (1 - within.mean()):.2f} % of the states")

"""Bit-for-bit comparison of the fusion's published estimates before and after a change.

  python -m train_localization.tools.compare_estimates record OUT.npz [--bags bags]
      [--per-family 2] [--max-duration 30] [--exported test/data] [--only PREFIX]
  python -m train_localization.tools.compare_estimates compare A.npz B.npz [--only PREFIX]

``record`` runs the fusion offline on every bag of ``--bags`` (``replay_bag``, serial; a line's
bag gives one run per train) and on the first ``--per-family`` campaign runs of every family
(core/campaign.py ``jobs`` with base seed 0, cut to ``--max-duration`` s) and on the campaign
runs exported to ``--exported`` (``campaign_*.yaml``: the fault cases the tests replay), and writes every
estimate's every field (a dict field per key; a tuple or string field as its repr) and the
filter's counters per run to an .npz. ``compare`` exits 1 at the first difference (run, field,
index, both values), 0 if the two files hold the same bits (``--only``: the runs whose name
starts with PREFIX, for a quick check against a full record).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

FLOAT_KINDS = "fiub"


def columns(estimates) -> dict[str, np.ndarray]:
    """Field name -> array over ``estimates`` (dataclasses): numbers as float64, dict fields
    one column per key (NaN where absent), any other value as its repr."""
    cols: dict[str, list] = {}
    n = len(estimates)
    for k, est in enumerate(estimates):
        for f in dataclasses.fields(est):
            value = getattr(est, f.name)
            if isinstance(value, dict):
                for key, v in value.items():
                    cols.setdefault(f"{f.name}.{key}", [np.nan] * n)[k] = float(v)
            elif isinstance(value, (int, float)) and not isinstance(value, bool):
                cols.setdefault(f.name, [np.nan] * n)[k] = float(value)
            else:
                cols.setdefault(f.name, [""] * n)[k] = repr(value)
    return {name: np.asarray(v) for name, v in cols.items()}


def same_estimates(a: list, b: list) -> bool:
    """Whether two lists of estimates hold the same values in every field, bit for bit."""
    ca, cb = columns(a), columns(b)
    return ca.keys() == cb.keys() and all(same_bits(ca[k], cb[k]) < 0 for k in ca)


def bag_runs(bags: Path, only: str = ""):
    """(run name, estimates, counters) of every bag in ``bags``, replayed serially."""
    from ..core.offline import LineResult, replay_bag
    for bag in sorted(bags.glob("*.mcap")):
        name = f"bag:{bag.stem}"
        if not name.startswith(only):
            continue
        result = replay_bag(bag)
        if isinstance(result, LineResult):
            for train, run in sorted(result.trains.items()):
                yield f"{name}/{train}", run.estimates, run.runner.counters()
        else:
            yield name, result.estimates, result.runner.counters()


def _fused(data: dict):
    """(estimates, counters) of a generated campaign scenario dict, delivered and fused as
    ``campaign.run_scenario`` does."""
    from ..core import campaign
    from ..core.offline import fuse_arrivals, fusion_runner, scenario_measurements, sensor_pipelines
    from ..core.scenario import Scenario
    sc = Scenario.from_dict(data)
    arrivals = scenario_measurements(sc, pipes=sensor_pipelines(sc), trajectory=sc.trajectory())
    delivered = campaign.deliver(arrivals, data.get("campaign", {}).get("delivery", {}))
    runner = fusion_runner(sc, campaign.FUSION_RATE)
    runner, estimates, _, _ = fuse_arrivals(runner.filter.cfg, delivered, sc.duration, campaign.FUSION_RATE,
                                            runner=runner)
    return estimates, runner.counters()


def campaign_runs(per_family: int, max_duration: float, only: str = ""):
    """(run name, estimates, counters) of the first ``per_family`` campaign runs of every family."""
    from ..core import campaign
    families = campaign.ALL_FAMILIES
    for family, seed in campaign.jobs(per_family * len(families), families):
        name = f"campaign:{family}:{seed}"
        if name.startswith(only):
            yield (name, *_fused(campaign.generate(family, seed, max_duration)))


def exported_runs(folder: Path, only: str = ""):
    """(run name, estimates, counters) of the campaign runs exported to ``folder`` (campaign_*.yaml)."""
    import yaml
    for path in sorted(folder.glob("campaign_*.yaml")):
        name = f"exported:{path.stem}"
        if name.startswith(only):
            yield (name, *_fused(yaml.safe_load(path.read_text())))


def record(out: Path, bags: Path, per_family: int, max_duration: float, exported: Path, only: str = "") -> int:
    arrays: dict[str, np.ndarray] = {}
    runs = []
    for source in (bag_runs(bags, only), campaign_runs(per_family, max_duration, only), exported_runs(exported, only)):
        for name, estimates, counters in source:
            runs.append(name)
            arrays[f"{name}|counters"] = np.asarray(json.dumps(counters, sort_keys=True, default=repr))
            arrays[f"{name}|n"] = np.asarray(len(estimates))
            for field, values in columns(estimates).items():
                arrays[f"{name}|{field}"] = values
            print(f"{name}: {len(estimates)} estimates", file=sys.stderr, flush=True)
    arrays["runs"] = np.asarray(runs)
    np.savez_compressed(out, **arrays)
    return 0


def same_bits(a: np.ndarray, b: np.ndarray) -> int:
    """-1 if ``a`` and ``b`` hold the same bits, else the first index that differs (0 for a
    shape or type mismatch)."""
    if a.shape != b.shape or (a.dtype.kind in FLOAT_KINDS) != (b.dtype.kind in FLOAT_KINDS):
        return 0
    if a.dtype.kind == "f":
        differ = a.view(np.uint64) != b.view(np.uint64)
    else:
        differ = a != b
    idx = np.flatnonzero(np.atleast_1d(differ))
    return int(idx[0]) if len(idx) else -1


def compare(a_path: Path, b_path: Path, only: str = "") -> int:
    a, b = np.load(a_path), np.load(b_path)
    keys_a, keys_b = ({k for k in x.files if k != "runs" and k.startswith(only)} | {"runs"} for x in (a, b))
    if keys_a != keys_b:
        print(f"different runs or fields: only in {a_path}: {sorted(keys_a - keys_b)[:5]}, "
              f"only in {b_path}: {sorted(keys_b - keys_a)[:5]}")
        return 1
    runs = [r for r in a["runs"].tolist() if r.startswith(only)]
    for key in ([] if only else ["runs"]) + sorted(keys_a - {"runs"}):
        x, y = a[key], b[key]
        i = same_bits(x, y)
        if i >= 0:
            xs, ys = np.atleast_1d(x), np.atleast_1d(y)
            show = (repr(xs[i]) if i < xs.size else "-", repr(ys[i]) if i < ys.size else "-")
            print(f"first difference: {key} at index {i}: {show[0]} != {show[1]}")
            return 1
    print(f"identical: {len(runs)} runs, {len(keys_a) - 1} arrays")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    rec = sub.add_parser("record", help="run the fusion and write its estimates to an .npz")
    rec.add_argument("out", type=Path)
    rec.add_argument("--bags", type=Path, default=Path("bags"))
    rec.add_argument("--per-family", type=int, default=2, help="campaign runs per family (jobs, base seed 0)")
    rec.add_argument("--max-duration", type=float, default=30.0, help="campaign runs cut to this [s]")
    rec.add_argument("--exported", type=Path, default=Path("test/data"), help="folder of exported campaign runs")
    rec.add_argument("--only", default="",
                     help="only the runs whose name starts with this (bag:x, campaign:family, exported:x)")
    cmp_ = sub.add_parser("compare", help="exit 1 at the first difference of two recorded files")
    cmp_.add_argument("a", type=Path)
    cmp_.add_argument("b", type=Path)
    cmp_.add_argument("--only", default="", help="only the runs whose name starts with this")
    args = parser.parse_args(argv)
    if args.cmd == "record":
        return record(args.out, args.bags, args.per_family, args.max_duration, args.exported, args.only)
    return compare(args.a, args.b, args.only)


if __name__ == "__main__":
    sys.exit(main())

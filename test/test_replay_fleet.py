"""tl_replay of a folder of bags (tools/replay.py fleet_reports): the same reports on a dask
cluster as replayed one after the other in this process."""
from __future__ import annotations

import json

import pytest

from train_localization.core.offline import simulate_scenario
from train_localization.core.scenario import Scenario
from train_localization.tools import replay


def _scores(report: dict) -> dict:
    return {k: v for k, v in report.items() if k not in replay.TIMING_KEYS}


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """A folder of two short bags of different trains."""
    folder = tmp_path_factory.mktemp("fleet")
    for name, t_end in (("scenario_demo", 6.0), ("scenario_mbahn", 4.0)):
        simulate_scenario(Scenario.from_yaml(f"config/{name}.yaml"), bag=folder / f"{name}.mcap", t_end=t_end)
    return folder


def test_a_folder_of_bags_gives_the_serial_reports_on_a_dask_cluster(fleet, tmp_path):
    from dask.distributed import LocalCluster
    serial = replay.fleet_reports(fleet, workers=1)
    assert list(serial) == ["scenario_demo.mcap", "scenario_mbahn.mcap"]
    assert all("error" not in r and r["states"] > 0 and r["cpu_s"] > 0 for r in serial.values())
    out = tmp_path / "reports"
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        rc = replay.main([str(fleet), "--report", str(out), "--scheduler", cluster.scheduler_address])
    assert rc == 0
    for name, report in serial.items():
        written = json.loads((out / name.removesuffix(".mcap") / "report.json").read_text())
        assert _scores(written) == json.loads(json.dumps(_scores(report)))
    summary = json.loads((out / "summary.json").read_text())
    assert summary["bags"] == 2 and summary["failed"] == 0
    assert [row["run"] for row in summary["rows"]] == list(serial)
    assert summary["log_s"] == pytest.approx(sum(r["duration_s"] for r in serial.values()))


def test_a_bag_that_cannot_be_scored_is_reported_as_failed_and_the_others_are_not(fleet, tmp_path):
    folder = tmp_path / "with_a_bad_one"
    folder.mkdir()
    (folder / "a.mcap").write_bytes((fleet / "scenario_mbahn.mcap").read_bytes())
    (folder / "b.mcap").write_bytes(b"not a bag")
    reports = replay.fleet_reports(folder, workers=1)
    assert "error" not in reports["a.mcap"] and "error" in reports["b.mcap"]
    summary = replay.fleet_summary(reports)
    assert summary["bags"] == 2 and summary["failed"] == 1

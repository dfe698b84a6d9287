"""The launch files run against a stand-in of the launch API (launch and launch_ros are not
on PyPI): each builds the Node actions of its graph with the arguments resolved as
``ros2 launch`` resolves them. The stand-in records what the files construct; the calls and
their keywords are those of launch/launch_ros (Jazzy)."""
from __future__ import annotations

import importlib.util
import sys
import types

import pytest

from conftest import ROOT


class _Recorded:
    """An action or substitution of the stand-in: its arguments, as given."""

    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


class _LaunchConfiguration(_Recorded):
    def perform(self, context: dict) -> str:
        return context[self.args[0]]


class _LaunchDescription(_Recorded):
    def entities(self) -> list:
        return list(self.args[0])


def _stand_in() -> dict[str, types.ModuleType]:
    modules = {}
    for name, members in {
        "launch": {"LaunchDescription": _LaunchDescription},
        "launch.actions": {n: type(n, (_Recorded,), {}) for n in (
            "DeclareLaunchArgument", "OpaqueFunction", "EmitEvent", "RegisterEventHandler",
            "SetEnvironmentVariable", "IncludeLaunchDescription")},
        "launch.substitutions": {"LaunchConfiguration": _LaunchConfiguration},
        "launch.event_handlers": {"OnProcessExit": type("OnProcessExit", (_Recorded,), {})},
        "launch.events": {"Shutdown": type("Shutdown", (_Recorded,), {})},
        "launch.launch_description_sources": {
            "PythonLaunchDescriptionSource": type("PythonLaunchDescriptionSource", (_Recorded,), {})},
        "launch_ros": {},
        "launch_ros.actions": {"Node": type("Node", (_Recorded,), {})},
    }.items():
        module = types.ModuleType(name)
        module.__dict__.update(members)
        modules[name] = module
    return modules


@pytest.fixture
def launch_file(monkeypatch):
    """Load launch/<name> against the stand-in, with the package's share directory at the
    repository root (its layout: config/, launch/); returns (arguments, nodes(overrides))."""
    for name, module in _stand_in().items():
        monkeypatch.setitem(sys.modules, name, module)
    import ament_index_python.packages
    monkeypatch.setattr(ament_index_python.packages, "get_package_share_directory", lambda package: str(ROOT))
    monkeypatch.delitem(sys.modules, "train_localization.launch_common", raising=False)

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name.replace(".", "_"), ROOT / "launch" / name)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        entities = module.generate_launch_description().entities()
        arguments = {e.args[0]: e.kwargs for e in entities if type(e).__name__ == "DeclareLaunchArgument"}
        opaque = next((e for e in entities if type(e).__name__ == "OpaqueFunction"), None)   # maglev: an include

        def nodes(**given) -> list:
            context = {k: v["default_value"] for k, v in arguments.items() if "default_value" in v}
            context.update(given)
            actions = opaque.kwargs["function"](context)
            return [a for a in actions if type(a).__name__ == "Node"]
        return arguments, nodes
    return load


def _params(node) -> dict:
    return node.kwargs["parameters"][0]


@pytest.mark.parametrize("name", ["demo.launch.py", "line.launch.py", "replay.launch.py", "onboard.launch.py",
                                  "maglev.launch.py"])
def test_every_launch_argument_is_described(launch_file, name):
    arguments, _ = launch_file(name)
    assert arguments and all(kw.get("description") for kw in arguments.values()), arguments


def test_the_onboard_graph_runs_on_the_hosts_clock_unless_told_otherwise(launch_file, tmp_path):
    """onboard.launch.py: the scenario's sensor nodes in ingest mode, the fusion and the
    recorder, no simulator; ``use_sim_time`` false by default and passed to every node."""
    arguments, nodes = launch_file("onboard.launch.py")
    assert "default_value" not in arguments["scenario"]         # required
    assert arguments["use_sim_time"]["default_value"] == "false"
    scenario = str(ROOT / "config" / "scenario_demo.yaml")
    bag = str(tmp_path / "onboard.mcap")
    host = nodes(scenario=scenario, bag=bag)
    executables = sorted(n.kwargs["executable"] for n in host)
    assert executables == sorted(["recorder", "fusion", "wheel_sensor", "doppler_radar", "eurobalise_reader",
                                  "axle_counter"])
    assert all(_params(n)["use_sim_time"] is False for n in host)
    assert all(_params(n)["mode"] == "ingest" for n in host if n.kwargs["executable"] not in ("recorder", "fusion"))
    played = nodes(scenario=scenario, bag=bag, use_sim_time="true")
    assert all(_params(n)["use_sim_time"] is True for n in played)


def test_the_onboard_graph_takes_standard_messages_through_standard_inputs(launch_file, tmp_path):
    """standard_inputs:=<its params file>: the node with those parameters (the launch's scenario
    and clock), no ingest node for the sensors whose measurements it publishes, the fusion on
    them; a params file naming only the GNSS keeps the other sensors' ingest nodes."""
    _, nodes = launch_file("onboard.launch.py")
    scenario = str(ROOT / "config" / "scenario_drivers.yaml")
    built = nodes(scenario=scenario, bag=str(tmp_path / "b.mcap"), standard_inputs="config/params/standard_inputs.yaml")
    assert sorted(n.kwargs["executable"] for n in built) == ["fusion", "recorder", "standard_inputs"]
    inputs = next(n for n in built if n.kwargs["executable"] == "standard_inputs")
    assert _params(inputs)["scenario"] == scenario and _params(inputs)["use_sim_time"] is False
    assert (_params(inputs)["navsat.topic"], _params(inputs)["odometry.topic"]) == ("/gnss/fix", "/wheel/odometry")
    fusion = next(n for n in built if n.kwargs["executable"] == "fusion")
    assert _params(fusion)["sensors"] == ["dgps", "gyro", "wheel"]
    gnss_only = tmp_path / "gnss.yaml"
    gnss_only.write_text("/**:\n  ros__parameters:\n    navsat: {topic: /fix, min_status: 0}\n")
    built = nodes(scenario=scenario, bag=str(tmp_path / "b.mcap"), standard_inputs=str(gnss_only))
    assert sorted(n.kwargs["executable"] for n in built) == ["fusion", "gyro", "recorder", "standard_inputs",
                                                             "wheel_sensor"]
    inputs = next(n for n in built if n.kwargs["executable"] == "standard_inputs")
    assert (_params(inputs)["navsat.topic"], _params(inputs)["navsat.min_status"]) == ("/fix", 0)
    assert _params(next(n for n in built if n.kwargs["executable"] == "fusion"))["sensors"] == ["gyro", "wheel",
                                                                                               "dgps"]


@pytest.mark.parametrize("name, given", [("demo.launch.py", {}), ("onboard.launch.py", {}),
                                         ("replay.launch.py", {"bag": "/nonexistent/recorded.mcap"})])
def test_a_relative_scenario_is_found_in_the_share_directory_from_any_current_directory(
        launch_file, name, given, tmp_path, monkeypatch):
    """scenario:=config/scenario_demo.yaml from a directory that has no config/: the
    package's share copy (the replay launch looked only in the current directory)."""
    monkeypatch.chdir(tmp_path)
    _, nodes = launch_file(name)
    built = nodes(scenario="config/scenario_demo.yaml", **given)
    fusion = next(n for n in built if n.kwargs["executable"] == "fusion")
    assert _params(fusion)["scenario"] == str(ROOT / "config" / "scenario_demo.yaml")
    (tmp_path / "config").mkdir()                              # a file of that name here comes first
    (tmp_path / "config" / "scenario_demo.yaml").write_text((ROOT / "config" / "scenario_demo.yaml").read_text())
    built = nodes(scenario="config/scenario_demo.yaml", **given)
    fusion = next(n for n in built if n.kwargs["executable"] == "fusion")
    assert _params(fusion)["scenario"] == str(tmp_path / "config" / "scenario_demo.yaml")


def test_the_simulated_graphs_run_on_the_drivers_clock(launch_file):
    """demo and line: every node but the simulator (which makes /clock) on use_sim_time."""
    for name, scenario in (("demo.launch.py", "config/scenario_demo.yaml"),
                           ("line.launch.py", "config/scenario_line_pair.yaml")):
        _, nodes = launch_file(name)
        built = nodes(scenario=str(ROOT / scenario))
        assert built and all(_params(n).get("use_sim_time") is True for n in built
                             if n.kwargs["executable"] != "simulator"), name


SAFETY_NODES = {"etcs_location", "atp_supervision", "speed_controller", "stator_section_controller",
                "wayside_occupancy", "neutral_section_controller", "crosscheck", "association", "fusion"}


@pytest.mark.parametrize("name, scenario, expected", [
    ("demo.launch.py", "config/scenario_etcs_stop.yaml", {"etcs_location", "atp_supervision", "speed_controller"}),
    ("line.launch.py", "config/scenario_line_changeover.yaml", {"wayside_occupancy", "neutral_section_controller"}),
    ("demo.launch.py", "config/scenario_maglev_500.yaml", {"stator_section_controller"})])
def test_every_safety_node_is_respawned_and_none_with_respawn_false(launch_file, name, scenario, expected):
    """Every consumer of the fused state is restarted like the fusion (and comes back in its
    safe state: the ATP braked until a confirmed standstill, the location without an LRBG);
    ``respawn:=false`` turns it off for all."""
    _, nodes = launch_file(name)
    built = nodes(scenario=str(ROOT / scenario))
    safety = [n for n in built if n.kwargs["executable"] in SAFETY_NODES]
    assert expected | {"fusion"} <= {n.kwargs["executable"] for n in safety}, [n.kwargs["executable"] for n in built]
    assert all(n.kwargs["respawn"] is True and n.kwargs["respawn_delay"] > 0 for n in safety)
    assert not any(n.kwargs["respawn"] for n in nodes(scenario=str(ROOT / scenario), respawn="false"))

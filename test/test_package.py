"""The package as ament sees it: colcon build, ament index, executables, launch file."""
from __future__ import annotations

import ast
import re
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from conftest import ROOT
from train_localization.core.sensors import NODE_NAMES

EXECUTABLES = ["simulator", "fusion", "recorder", "replayer", "speed_controller", *NODE_NAMES]


def test_colcon_build_registers_package_and_executables(tmp_path):
    """README's ``colcon build --base-paths <repo> <repo>/msg_defs``: colcon finds both packages and
    builds the Python one. The interface package is the one scripts/setup_env.sh built with colcon
    from the same msg_defs/ (its C type support takes 90 s of CPU to compile): here it is skipped
    and taken from that build, where its install is checked."""
    if shutil.which("colcon") is None:
        raise AssertionError("colcon is not on PATH: run the tests through scripts/test.sh")
    src = tmp_path / "src"
    shutil.copytree(ROOT, src / "train_localization",
                    ignore=shutil.ignore_patterns(".venv", ".git", "out", "build", "install", "log", "*.mcap"))
    env = dict(os.environ)
    proc = subprocess.run(
        # the repository root is itself a package, so colcon does not crawl into it:
        # msg_defs/ is named explicitly (README: Building with colcon)
        ["colcon", "build", "--base-paths", str(src / "train_localization"),
         str(src / "train_localization" / "msg_defs"), "--build-base", str(tmp_path / "build"),
         "--install-base", str(tmp_path / "install"), "--packages-skip", "train_localization_msgs",
         "--cmake-args", "-DBUILD_TESTING=OFF"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    # both base paths crawled: colcon names the interface package found in the workspace and taken
    # from the environment's build
    assert re.search(r"in the workspace but haven't been built:\s+- train_localization_msgs", proc.stderr), \
        proc.stderr[-3000:]
    install = tmp_path / "install"
    assert (install / "train_localization" / "share" / "ament_index" / "resource_index" / "packages" /
            "train_localization").exists()
    lib = install / "train_localization" / "lib" / "train_localization"
    for exe in EXECUTABLES:
        assert os.access(lib / exe, os.X_OK), f"{exe} missing in {lib}"
    share = install / "train_localization" / "share" / "train_localization"
    assert sorted(f.name for f in (share / "launch").glob("*.launch.py")) == \
        sorted(f.name for f in (ROOT / "launch").glob("*.launch.py"))
    assert (share / "config" / "params" / "fusion.yaml").exists()
    assert (share / "config" / "scenario_demo.yaml").exists()
    from ament_index_python.packages import get_package_prefix
    msgs = Path(get_package_prefix("train_localization_msgs"))
    assert (msgs / "share" / "ament_index" / "resource_index" / "packages" / "train_localization_msgs").exists()
    assert (msgs / "share" / "train_localization_msgs" / "msg" / "TrainState.msg").exists()


@pytest.mark.parametrize("launch_file, graph", [("demo.launch.py", "demo_graph"), ("replay.launch.py", "replay_graph"),
                                                  ("line.launch.py", "line_graph")])
def test_launch_file_is_a_list_of_node_actions_with_its_graph(launch_file, graph):
    """Node actions built from graph.py (the graph the tests run), a Shutdown when the driver
    (simulator, replayer) exits, every argument described."""
    tree = ast.parse((ROOT / "launch" / launch_file).read_text())
    common = ast.parse((ROOT / "train_localization" / "launch_common.py").read_text())
    names = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
    assert {graph, "graph_actions", "common_arguments", "LaunchDescription"} <= names
    assert {"Node", "Shutdown", "OnProcessExit", "DRIVERS"} <= {n.id for n in ast.walk(common) if isinstance(n, ast.Name)}
    args = [c for t in (tree, common) for c in ast.walk(t)
            if isinstance(c, ast.Call) and getattr(c.func, "id", "") == "DeclareLaunchArgument"]
    declared = {c.args[0].value for c in args if c.args and isinstance(c.args[0], ast.Constant)}
    assert {"scenario", "rate", "record", "bag" if graph != "replay_graph" else "out",
            "log_level", "respawn", "respawn_delay"} <= declared, declared
    assert all(any(k.arg == "description" for k in c.keywords) for c in args)


def test_package_xml_dependencies_are_rosdep_keys():
    """rosdep install --from-paths . --ignore-src resolves every key: each is a key of
    rosdistro's rosdep files or a Jazzy package (test/data/rosdep_keys.txt), except the
    interface package built from msg_defs/. The launch file's imports are declared."""
    import xml.etree.ElementTree as ET
    known = {line.strip() for line in (ROOT / "test" / "data" / "rosdep_keys.txt").read_text().splitlines()
             if line.strip() and not line.startswith("#")}
    root = ET.parse(ROOT / "package.xml").getroot()
    keys = {e.text.strip() for e in root if e.tag.endswith("depend")}
    assert keys - {"train_localization_msgs"} <= known, sorted(keys - known - {"train_localization_msgs"})
    for launch_file in [*sorted(str(f.relative_to(ROOT)) for f in (ROOT / "launch").glob("*.launch.py")),
                        "train_localization/launch_common.py"]:
        launch = ast.parse((ROOT / launch_file).read_text())
        imported = {(n.module or "").split(".")[0] for n in ast.walk(launch) if isinstance(n, ast.ImportFrom)}
        assert {"launch"} <= imported <= keys | {"train_localization"}, launch_file


def test_package_xml_declares_the_ros_packages_the_code_imports_and_no_other():
    """Every ROS package a module of the package imports (rclpy, ament_index_python, launch,
    interface packages) is an exec_depend of package.xml, and every interface package declared
    is imported somewhere: builtin_interfaces and rcl_interfaces were imported undeclared,
    std_srvs declared unused."""
    import xml.etree.ElementTree as ET
    root = ET.parse(ROOT / "package.xml").getroot()
    declared = {e.text.strip() for e in root if e.tag.endswith("depend")}
    ros = re.compile(r"^(rclpy|ament_index_python|launch|launch_ros|\w+_(msgs|srvs|interfaces))$")
    imported = set()
    for path in [*(ROOT / "train_localization").rglob("*.py"), *(ROOT / "launch").glob("*.py")]:
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module] if isinstance(node, ast.ImportFrom) and node.module and not node.level else []
            imported |= {n.split(".")[0] for n in names if ros.match(n.split(".")[0])}
    assert imported <= declared, sorted(imported - declared)
    interfaces = {d for d in declared if re.match(r"^\w+_(msgs|srvs|interfaces)$", d)}
    assert interfaces <= imported, sorted(interfaces - imported)


def test_no_node_changes_the_discovery_variables():
    """Confining DDS discovery is the user's choice (a train with several computers sets its
    own; an empty value is theirs too): nothing the nodes import writes ROS_DOMAIN_ID,
    ROS_AUTOMATIC_DISCOVERY_RANGE or ROS_STATIC_PEERS. Only the project's own scripts, tools
    and launch defaults set them, for what they start."""
    import re
    pattern = re.compile(r"(environ\s*(\[|\.setdefault|\.update)|putenv)[^\n]*"
                         r"(ROS_DOMAIN_ID|ROS_AUTOMATIC_DISCOVERY_RANGE|ROS_STATIC_PEERS)")
    files = [p for d in ("core", "nodes") for p in (ROOT / "train_localization" / d).rglob("*.py")]
    files += [ROOT / "train_localization" / "graph.py"]
    assert len(files) > 20
    offenders = [f"{p.relative_to(ROOT)}:{i}" for p in files
                 for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert offenders == []
    # the pattern finds what it is meant to find
    assert pattern.search('os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")')
    assert pattern.search('os.environ["ROS_DOMAIN_ID"] = "5"')


def test_a_ros_command_line_on_the_pip_environment_finds_the_package():
    """What ``ros2 run train_localization <node>`` looks up: the package's prefix by the ament index
    marker (share/ament_index/resource_index/packages/train_localization) on AMENT_PREFIX_PATH,
    then <prefix>/lib/train_localization/<node>; and its share directory (``ros2 launch``)."""
    import sys
    from ament_index_python.packages import get_package_prefix, get_package_share_directory
    prefix = get_package_prefix("train_localization")
    assert os.path.samefile(prefix, sys.prefix)
    assert all(os.access(os.path.join(prefix, "lib", "train_localization", exe), os.X_OK) for exe in EXECUTABLES)
    share = get_package_share_directory("train_localization")
    assert os.path.isfile(os.path.join(share, "package.xml")) and os.path.isdir(os.path.join(share, "launch"))

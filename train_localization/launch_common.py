"""What the launch files share (launch/*.launch.py): the supervision and logging arguments,
DDS confinement by default, and turning a graph.py graph into Node actions that shut the
launch down when the graph's driver (simulator, replayer) exits.

Needs a full ROS 2 install (launch and launch_ros are not on PyPI); only the launch files
import it.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, EmitEvent, RegisterEventHandler, SetEnvironmentVariable
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from train_localization.tools.domains import discovery_range

# nodes whose exit ends the run: not restarted, their exit shuts the launch down
DRIVERS = ("simulator", "replayer")


def common_arguments() -> list:
    """log_level, respawn, respawn_delay, and DDS discovery kept as the caller has it
    (LOCALHOST if unset): the nodes do not confine it themselves."""
    return [
        DeclareLaunchArgument("log_level", default_value="info",
                              choices=["debug", "info", "warn", "error", "fatal"],
                              description="log level of every node"),
        DeclareLaunchArgument("respawn", default_value="true", choices=["true", "false"],
                              description="restart a fusion or sensor node that exits or crashes (not the "
                                          "simulator, the replayer or the recorder)"),
        DeclareLaunchArgument("respawn_delay", default_value="2.0",
                              description="seconds before such a node is restarted (>= 0)"),
        SetEnvironmentVariable("ROS_AUTOMATIC_DISCOVERY_RANGE", discovery_range(os.environ)),
    ]


def scenario_path(value: str) -> str:
    """A scenario file given as a launch argument: an absolute path as given; a relative one
    from the current directory if it exists there (as the nodes resolve it), else from the
    package's share directory."""
    if os.path.isabs(value) or os.path.exists(value):
        return os.path.abspath(value)
    return os.path.join(get_package_share_directory("train_localization"), value)


def params_file_values(path: str) -> dict:
    """The parameters of a one-node ROS params file (``/**:`` or a node name, then
    ``ros__parameters``), a nested mapping flattened to dotted names as ROS reads it."""
    import yaml
    with open(path, encoding="utf-8") as fh:
        data = yaml.safe_load(fh) or {}
    if not isinstance(data, dict) or len(data) != 1:
        raise ValueError(f"{path}: a params file of one node (its key, then ros__parameters)")
    params = next(iter(data.values())).get("ros__parameters", {})

    def flat(prefix: str, values: dict) -> dict:
        out = {}
        for key, value in values.items():
            out.update(flat(f"{prefix}{key}.", value) if isinstance(value, dict) else {f"{prefix}{key}": value})
        return out
    return flat("", params)


def flag(context, name: str) -> bool:
    """A true/false launch argument."""
    return LaunchConfiguration(name).perform(context).lower() in ("true", "1", "yes")


def graph_actions(context, graph: list, namespace: str) -> list:
    """Node actions of a graph.py graph. An entry is (executable, node name, parameters), in
    ``namespace``, or (its own namespace, executable, node name, parameters) of a line graph
    (graph.line_graph: /<train>, /wayside, /). Supervision: a crashed
    fusion or sensor node is restarted after respawn_delay (the fusion comes back
    INITIALISING); not the driver (its exit ends the run) nor the recorder (a new one would
    start the bag afresh)."""
    log_level = LaunchConfiguration("log_level").perform(context)
    respawn = flag(context, "respawn")
    respawn_delay = float(LaunchConfiguration("respawn_delay").perform(context))
    actions = []
    for entry in graph:
        if len(entry) == 4:
            node_ns, exe, name, params = entry
        else:
            exe, name, params = entry
            node_ns = namespace
        supervised = respawn and exe not in DRIVERS + ("recorder",)
        node = Node(package="train_localization", executable=exe, name=name, namespace=node_ns,
                    parameters=[params], output="screen", arguments=["--ros-args", "--log-level", log_level],
                    respawn=supervised, respawn_delay=respawn_delay if supervised else None)
        actions.append(node)
        if exe in DRIVERS:
            actions.append(RegisterEventHandler(OnProcessExit(
                target_action=node, on_exit=[EmitEvent(event=Shutdown(reason=f"the {exe} has ended"))])))
    return actions

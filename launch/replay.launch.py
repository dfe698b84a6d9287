"""ros2 launch train_localization replay.launch.py bag:=<recorded.mcap> [rate:=...] [out:=...] ...

Drives the live nodes from a recorded bag: the replayer plays the bag's raw sensor topics
(with its ground truth and scenario) and publishes /clock from the bag's time line; the
bag's sensors run as nodes in ``mode:=ingest`` and the fusion fuses what they decode; the
recorder (unless record:=false) writes the re-fused run to ``out``. The sensors, track and
parameters are the bag's own (its scenario topic), or those of ``scenario:=``
(train_localization/graph.py: replay_graph). ``--show-args`` lists the arguments.

Shutdown: when the replayer has played the bag and exits, the launch shuts the whole graph
down (the recorder closes its bag). Ctrl-C (SIGINT) does the same at any time; the recorder
closes its bag within 2 s of SIGINT. Supervision: fusion and sensor nodes that exit or crash
are restarted after ``respawn_delay`` s (``respawn:=false`` to turn it off).

DDS discovery: the nodes do not confine it themselves; this launch keeps
ROS_AUTOMATIC_DISCOVERY_RANGE as the caller has it, LOCALHOST if unset.
"""
import os
import tempfile

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration

from train_localization.core.offline import scenario_from_bag
from train_localization.core.scenario import Scenario
from train_localization.graph import NAMESPACE, replay_graph
from train_localization.launch_common import common_arguments, flag, graph_actions, scenario_path


def _nodes(context):
    bag = os.path.abspath(LaunchConfiguration("bag").perform(context))
    given = LaunchConfiguration("scenario").perform(context)
    if given:
        scenario_file = scenario_path(given)
        scenario = Scenario.from_yaml(scenario_file)
    else:   # the bag's own scenario, written where the nodes can read it
        scenario = scenario_from_bag(bag)
        fd, scenario_file = tempfile.mkstemp(prefix="replay_scenario_", suffix=".yaml")
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(scenario.to_yaml())
    out = os.path.abspath(LaunchConfiguration("out").perform(context))
    rate = float(LaunchConfiguration("rate").perform(context))
    namespace = LaunchConfiguration("namespace").perform(context)
    graph = replay_graph(bag, scenario_file, list(scenario.sensors), out, rate,
                         record=flag(context, "record"), namespace=namespace)
    return graph_actions(context, graph, namespace)


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("bag", description="the recorded MCAP bag to play (raw topics under /train)"),
        DeclareLaunchArgument("scenario", default_value="",
                              description="scenario YAML for the nodes; empty = the bag's own (/train/scenario); a "
                                          "relative path is looked up in the current directory, then in the "
                                          "package's share"),
        DeclareLaunchArgument("rate", default_value="1.0",
                              description="playback speed as a multiple of real time (> 0)"),
        DeclareLaunchArgument("namespace", default_value=NAMESPACE,
                              description="namespace of every node and topic (the bag's topics are moved there)"),
        DeclareLaunchArgument("record", default_value="true", choices=["true", "false"],
                              description="record the re-fused run"),
        DeclareLaunchArgument("out", default_value="replay.mcap",
                              description="the recorder's output file (relative: to the current directory)"),
        *common_arguments(),
        OpaqueFunction(function=_nodes),
    ])

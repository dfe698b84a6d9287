"""ros2 launch train_localization demo.launch.py [scenario:=...] [rate:=...] [record:=...] ...

Starts the same graph as tools/demo.py (train_localization/graph.py): recorder (unless
record:=false), the scenario's sensor nodes in simulation mode, fusion, the speed controller
(a closed-loop scenario, with a ``control`` section: the seed 003 rig) and simulator,
with use_sim_time (the simulator publishes /clock). ``ros2 launch ... --show-args``
lists the arguments. Needs a full ROS 2 Jazzy install (launch is not on PyPI).

Shutdown: when the simulator has played the scenario and exits, the launch shuts the
whole graph down (the recorder closes its bag). Ctrl-C (SIGINT) does the same at any
time; the recorder closes its bag within 2 s of SIGINT. Supervision: fusion and sensor
nodes that exit or crash are restarted after ``respawn_delay`` s (``respawn:=false`` to
turn it off); the fusion comes back INITIALISING and claims a position again from fixes.

DDS discovery: the nodes do not confine it themselves (a multi-computer train sets its
own); this launch keeps ROS_AUTOMATIC_DISCOVERY_RANGE as the caller has it, LOCALHOST if
unset.
"""
import os

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration

from train_localization.core.scenario import Scenario
from train_localization.graph import NAMESPACE, demo_graph, graph_options
from train_localization.launch_common import common_arguments, flag, graph_actions, scenario_path


def _nodes(context):
    scenario = scenario_path(LaunchConfiguration("scenario").perform(context))
    bag = os.path.abspath(LaunchConfiguration("bag").perform(context))
    rate = float(LaunchConfiguration("rate").perform(context))
    namespace = LaunchConfiguration("namespace").perform(context)
    sc = Scenario.from_yaml(scenario)
    graph = demo_graph(scenario, list(sc.sensors), bag, rate, record=flag(context, "record"), **graph_options(sc))
    return graph_actions(context, graph, namespace)


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("scenario", default_value="config/scenario_demo.yaml",
                              description="scenario YAML (track, vehicle, profile, sensors); a relative path is "
                                          "looked up in the current directory, then in the package's share"),
        DeclareLaunchArgument("rate", default_value="1.0",
                              description="simulation speed as a multiple of real time (> 0)"),
        DeclareLaunchArgument("namespace", default_value=NAMESPACE,
                              description="namespace of every node and topic of the graph"),
        DeclareLaunchArgument("record", default_value="true", choices=["true", "false"],
                              description="run the recorder (MCAP bag of every topic)"),
        DeclareLaunchArgument("bag", default_value="demo.mcap",
                              description="the recorder's output file (relative: to the current directory)"),
        *common_arguments(),
        OpaqueFunction(function=_nodes),
    ])

"""ros2 launch train_localization line.launch.py [scenario:=...] [rate:=...] [record:=...] ...

A line of several trains (graph.line_graph, as ``tl_demo --scenario`` of a line runs it):
per train its sensor nodes and its fusion in /<train>, the wayside sensor nodes and the
association of their fixes with the trains in /wayside, the simulator (every train's truth
and every device's raw blocks) and the recorder in /. ``ros2 launch ... --show-args`` lists
the arguments. Needs a full ROS 2 Jazzy install (launch is not on PyPI).

No ``namespace`` argument: the trains' namespaces are the line's own (/<train>, /wayside, the
line scenario on /scenario), the topic layout that the offline replay of a line's bag reads;
to run two lines on one DDS domain, give them their own ROS_DOMAIN_ID.

Shutdown: when the simulator has played the scenario and exits, the launch shuts the
whole graph down (the recorder closes its bag); Ctrl-C (SIGINT) does the same at any time.
Supervision as in demo.launch.py (``respawn``, ``respawn_delay``).

DDS discovery: the nodes do not confine it themselves; this launch keeps
ROS_AUTOMATIC_DISCOVERY_RANGE as the caller has it, LOCALHOST if unset.
"""
import os

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration

from train_localization.graph import line_graph
from train_localization.launch_common import common_arguments, flag, graph_actions, scenario_path


def _nodes(context):
    scenario = scenario_path(LaunchConfiguration("scenario").perform(context))
    bag = os.path.abspath(LaunchConfiguration("bag").perform(context))
    rate = float(LaunchConfiguration("rate").perform(context))
    graph = line_graph(scenario, bag, rate, record=flag(context, "record"))
    return graph_actions(context, graph, "/")


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("scenario", default_value="config/scenario_line_highspeed.yaml",
                              description="line scenario YAML (trains, wayside); a relative path is looked up "
                                          "in the current directory, then in the package's share"),
        DeclareLaunchArgument("rate", default_value="1.0",
                              description="simulation speed as a multiple of real time (> 0)"),
        DeclareLaunchArgument("record", default_value="true", choices=["true", "false"],
                              description="run the recorder (MCAP bag of every topic)"),
        DeclareLaunchArgument("bag", default_value="line.mcap",
                              description="the recorder's output file (relative: to the current directory)"),
        *common_arguments(),
        OpaqueFunction(function=_nodes),
    ])

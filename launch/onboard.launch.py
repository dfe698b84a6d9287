"""ros2 launch train_localization onboard.launch.py scenario:=<train.yaml> [use_sim_time:=...] ...

The on-board graph of a real train, for hosting in a train-control stack: one sensor node per
sensor of the scenario in ``mode:=ingest`` (each decodes the raw blocks your device drivers
publish on ``<namespace>/sensors/<sensor>/raw``, RawBlock), the fusion (``localization/state``
and ``localization/odometry`` for the ATP, the interlocking or the changeover), and the
recorder (unless record:=false). The scenario gives the track, the train's sensors and their
parameters; its profile is not used (the vehicle is real). ``--show-args`` lists the
arguments (train_localization/graph.py: onboard_graph).

Drivers that publish standard messages (NavSatFix, Imu, Odometry, TwistWithCovarianceStamped):
``standard_inputs:=config/params/standard_inputs.yaml`` (a params file of that node, naming the
topics) adds the standard_inputs node; the scenario's sensors whose measurements it publishes
get no ingest node, and nothing of this project is needed on the input side
(docs/integration.md, "From your drivers").

Time: on the host's clock (``use_sim_time:=false``, the default), so the drivers stamp their
blocks with it; ``use_sim_time:=true`` takes it from /clock, for data played by an outside
player that publishes it (``ros2 bag play --clock``). The demo, line and replay launches run
on the simulator's or the replayer's /clock by construction and take no such argument.

Shutdown: Ctrl-C (SIGINT); every node exits 0 within launch's grace period, the recorder
closes its bag. Supervision: fusion and sensor nodes that exit or crash are restarted after
``respawn_delay`` s (``respawn:=false`` to turn it off).

DDS discovery: the nodes do not confine it themselves; this launch keeps
ROS_AUTOMATIC_DISCOVERY_RANGE as the caller has it, LOCALHOST if unset.
"""
import os

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration

from train_localization.core.scenario import Scenario
from train_localization.graph import NAMESPACE, onboard_graph
from train_localization.launch_common import common_arguments, flag, graph_actions, params_file_values, scenario_path


def _nodes(context):
    scenario = scenario_path(LaunchConfiguration("scenario").perform(context))
    bag = os.path.abspath(LaunchConfiguration("bag").perform(context))
    namespace = LaunchConfiguration("namespace").perform(context)
    sc = Scenario.from_yaml(scenario)
    standard = LaunchConfiguration("standard_inputs").perform(context)
    graph = onboard_graph(scenario, list(sc.sensors), bag, record=flag(context, "record"),
                          use_sim_time=flag(context, "use_sim_time"),
                          standard_inputs=params_file_values(scenario_path(standard)) if standard else None)
    return graph_actions(context, graph, namespace)


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("scenario",
                              description="scenario YAML of the train (track, sensors and their parameters); a "
                                          "relative path is looked up in the current directory, then in the "
                                          "package's share"),
        DeclareLaunchArgument("use_sim_time", default_value="false", choices=["true", "false"],
                              description="take the time from /clock (an outside player of recorded data) "
                                          "instead of the host's clock"),
        DeclareLaunchArgument("namespace", default_value=NAMESPACE,
                              description="namespace of every node and topic of the graph"),
        DeclareLaunchArgument("record", default_value="true", choices=["true", "false"],
                              description="run the recorder (MCAP bag of every topic)"),
        DeclareLaunchArgument("standard_inputs", default_value="",
                              description="params file of a standard_inputs node (the topics of your drivers' "
                                          "NavSatFix, Imu, Odometry, TwistWithCovarianceStamped) that feeds the "
                                          "fusion; empty: none (every sensor of the scenario ingests raw blocks)"),
        DeclareLaunchArgument("bag", default_value="onboard.mcap",
                              description="the recorder's output file (relative: to the current directory)"),
        *common_arguments(),
        OpaqueFunction(function=_nodes),
    ])

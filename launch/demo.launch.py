"""ros2 launch train_localization demo.launch.py [scenario:=...] [bag:=...] [rate:=...]

Starts the same graph as tools/demo.py (train_localization/graph.py): recorder,
the scenario's sensor nodes in simulation mode, fusion and simulator, in /train
with use_sim_time. Needs a full ROS 2 Jazzy install (launch is not on PyPI).
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import OpaqueFunction, DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from train_localization.core.scenario import Scenario
from train_localization.graph import NAMESPACE, demo_graph

SHARE = get_package_share_directory("train_localization")


def _nodes(context):
    scenario = LaunchConfiguration("scenario").perform(context)
    if not os.path.isabs(scenario):
        scenario = os.path.join(SHARE, scenario)
    bag = LaunchConfiguration("bag").perform(context)
    rate = float(LaunchConfiguration("rate").perform(context))
    sensors = list(Scenario.from_yaml(scenario).sensors)
    return [Node(package="train_localization", executable=exe, name=name, namespace=NAMESPACE,
                 parameters=[params], output="screen")
            for exe, name, params in demo_graph(scenario, sensors, bag, rate)]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("scenario", default_value="config/scenario_demo.yaml"),
        DeclareLaunchArgument("bag", default_value="demo.mcap"),
        DeclareLaunchArgument("rate", default_value="1.0"),
        OpaqueFunction(function=_nodes),
    ])

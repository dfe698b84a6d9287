"""ros2 launch train_localization maglev.launch.py [rate:=...] [record:=...] ...

The maglev graph: demo.launch.py with the 500 km/h maglev scenario (INPO crossed loop,
LRL lugs, mm-wave ranging and Doppler radar; config/scenario_maglev_500.yaml). Every
argument of demo.launch.py applies (``--show-args``); ``scenario:=`` picks another one.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration


def generate_launch_description():
    demo = os.path.join(get_package_share_directory("train_localization"), "launch", "demo.launch.py")
    return LaunchDescription([
        DeclareLaunchArgument("scenario", default_value="config/scenario_maglev_500.yaml",
                              description="scenario YAML (default: the 500 km/h maglev line)"),
        DeclareLaunchArgument("bag", default_value="maglev.mcap",
                              description="the recorder's output file (relative: to the current directory)"),
        IncludeLaunchDescription(PythonLaunchDescriptionSource(demo),
                                 launch_arguments={"scenario": LaunchConfiguration("scenario"),
                                                   "bag": LaunchConfiguration("bag")}.items()),
    ])

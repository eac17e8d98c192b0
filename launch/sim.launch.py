"""ROS 2 launch: the simulated DEM graph (plant_sim, estimator, controller, reference).

    ros2 launch dem_ros sim.launch.py
    ros2 launch dem_ros sim.launch.py params_file:=/path/to/my.yaml record:=true

Every node reads the same params file (default: the package's config/dem_ros.yaml).
With record:=true the rclpy-free recorder writes a rosbag2 MCAP bag under bag_dir;
``ros2 bag record -s mcap -a`` works as well.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node


def generate_launch_description():
    default_params = os.path.join(get_package_share_directory("dem_ros"), "config", "dem_ros.yaml")
    params = LaunchConfiguration("params_file")
    nodes = [
        Node(package="dem_ros", executable=name, name=name, output="screen", parameters=[params])
        for name in ("reference", "estimator", "controller", "plant_sim")
    ]
    recorder = ExecuteProcess(
        cmd=["ros2", "run", "dem_ros", "recorder", "--bag",
             PythonExpression(["'", LaunchConfiguration("bag_dir"), "/' + __import__('time').strftime('%Y%m%d-%H%M%S') + '_ros2'"])],
        output="screen",
        condition=IfCondition(LaunchConfiguration("record")),
    )
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=default_params, description="ROS 2 params file for every node"),
        DeclareLaunchArgument("record", default_value="false", description="record every topic to a bag"),
        DeclareLaunchArgument("bag_dir", default_value="bags", description="directory for the bag"),
        recorder,
        *nodes,
    ])

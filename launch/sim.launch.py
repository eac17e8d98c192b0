"""ROS 2 launch: the simulated DEM graph (plant_sim, estimator, controller, reference).

    ros2 launch dem_ros sim.launch.py
    ros2 launch dem_ros sim.launch.py params_file:=/path/to/my.yaml record:=true
    ros2 launch dem_ros sim.launch.py compose:=true
    ros2 launch dem_ros sim.launch.py compose:=true free_run:=true

Every node reads the same params file (default: the package's config/dem_ros.yaml).
With compose:=true the four nodes run in one ``container`` process on one
executor (same names, parameters and topics; see dem_ros/nodes/container.py).
With free_run:=true the plant runs free (``plant_sim.lockstep: false``, hardware-like timing:
late commands are held by the simulated board, at most ``hold_timeout``, then it lands the
plate); the default keeps the params file's value (lockstep: exact, offline-equal results).
With record:=true the rclpy-free recorder writes a rosbag2 MCAP bag under bag_dir;
``ros2 bag record -s mcap -a`` works as well.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, ExecuteProcess, OpaqueFunction
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node

from launch import LaunchDescription


def _loop_nodes(context):
    """The graph's nodes; free_run:=true adds ``lockstep: false`` on top of the params file."""
    params = [LaunchConfiguration("params_file").perform(context)]
    if LaunchConfiguration("free_run").perform(context).lower() in ("true", "1", "yes"):
        params.append({"lockstep": False})  # a /** override: only plant_sim declares it
    compose = LaunchConfiguration("compose")
    nodes = [
        Node(package="dem_ros", executable=name, name=name, output="screen", parameters=params,
             condition=UnlessCondition(compose))
        for name in ("reference", "estimator", "controller", "plant_sim")
    ]
    # one process, one executor; no name= (it would rename every node of the process)
    nodes.append(Node(package="dem_ros", executable="container", output="screen", parameters=params,
                      condition=IfCondition(compose)))
    return nodes


def generate_launch_description():
    default_params = os.path.join(get_package_share_directory("dem_ros"), "config", "dem_ros.yaml")
    recorder = ExecuteProcess(
        cmd=["ros2", "run", "dem_ros", "recorder", "--bag",
             PythonExpression(["'", LaunchConfiguration("bag_dir"),
                               "/' + __import__('time').strftime('%Y%m%d-%H%M%S') + '_ros2'"])],
        output="screen",
        condition=IfCondition(LaunchConfiguration("record")),
    )
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="ROS 2 params file for every node"),
        DeclareLaunchArgument("record", default_value="false", description="record every topic to a bag"),
        DeclareLaunchArgument("bag_dir", default_value="bags", description="directory for the bag"),
        DeclareLaunchArgument("compose", default_value="false",
                              description="run the nodes in one process (component-container style)"),
        DeclareLaunchArgument("free_run", default_value="false",
                              description="free-running plant (plant_sim.lockstep false), hardware-like timing"),
        recorder,
        OpaqueFunction(function=_loop_nodes),
    ])

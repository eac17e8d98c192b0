"""ROS 2 launch: the DEM graph on hardware (hw_driver in place of plant_sim).

    ros2 launch dem_ros hardware.launch.py link:=udp://192.168.1.50:47000
    ros2 launch dem_ros hardware.launch.py link:=serial:///dev/ttyACM0?baud=921600 record:=true
    ros2 launch dem_ros hardware.launch.py link:=rig            # also starts the emulator (dem-ros rig)
    ros2 launch dem_ros hardware.launch.py link:=rig auto_arm:=true compose:=true

Every node reads the same params file (default: the package's config/dem_ros.yaml); ``link``
overrides ``hw_driver.url``. The controller, estimator and reference are the simulator's nodes,
unchanged (one topic contract). The driver starts inactive: arm it with
``ros2 service call /hw_driver/arm std_srvs/srv/Trigger`` or ``dem-ros hw arm`` (``auto_arm:=true``
arms at start-up). With ``link:=rig`` the emulator listens on udp://127.0.0.1:47000 with the
scenario's plant (``scenario``). With record:=true the recorder writes an MCAP bag under bag_dir
(board state and link statistics on /dem/hw/state and /diagnostics included).
With compose:=true the estimator, controller and reference (and the recorder, with record:=true) run in one
``container`` process on one executor beside the driver's own process, as ``dem-ros launch --hardware ...
--compose`` does: the configuration that holds the rig on a 2-core machine (docs/manual/transports.md).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, ExecuteProcess, OpaqueFunction
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node
from launch_ros.substitutions import ExecutableInPackage

from launch import LaunchDescription

RIG_URL = "udp://127.0.0.1:47000"


def generate_launch_description():
    default_params = os.path.join(get_package_share_directory("dem_ros"), "config", "dem_ros.yaml")
    params = LaunchConfiguration("params_file")
    link = LaunchConfiguration("link")
    is_rig = PythonExpression(["'", link, "' == 'rig'"])
    url = PythonExpression(["'", RIG_URL, "' if '", link, "' == 'rig' else '", link, "'"])
    compose = LaunchConfiguration("compose")
    loop = [Node(package="dem_ros", executable=name, name=name, output="screen", parameters=[params],
                 condition=UnlessCondition(compose))
            for name in ("reference", "estimator", "controller")]
    driver = Node(package="dem_ros", executable="hw_driver", name="hw_driver", output="screen",
                  parameters=[params, {"url": url, "auto_arm": LaunchConfiguration("auto_arm")}])
    rig = ExecuteProcess(
        # the package's own dem-ros (lib/dem_ros; a colcon install puts none on PATH)
        cmd=[ExecutableInPackage("dem-ros", "dem_ros"), "rig", "--url", RIG_URL, "--params", params,
             "--scenario", LaunchConfiguration("scenario")],
        output="screen",
        condition=IfCondition(is_rig),
    )
    bag = PythonExpression(["'", LaunchConfiguration("bag_dir"),
                            "/' + __import__('time').strftime('%Y%m%d-%H%M%S') + '_hw'"])
    recorder = ExecuteProcess(
        cmd=["ros2", "run", "dem_ros", "recorder", "--bag", bag],
        output="screen",
        condition=IfCondition(PythonExpression(["'", LaunchConfiguration("record"), "'.lower() == 'true' and '",
                                                compose, "'.lower() != 'true'"])),
    )
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="ROS 2 params file for every node"),
        DeclareLaunchArgument("link", default_value="rig",
                              description="udp://HOST:PORT, serial:///dev/PATH[?baud=N], or rig (start the emulator)"),
        DeclareLaunchArgument("auto_arm", default_value="false", description="arm the driver at start-up"),
        DeclareLaunchArgument("scenario", default_value="S1", description="rig only: the emulated plant's scenario"),
        DeclareLaunchArgument("record", default_value="false", description="record every topic to a bag"),
        DeclareLaunchArgument("bag_dir", default_value="bags", description="directory for the bag"),
        DeclareLaunchArgument("compose", default_value="false",
                              description="estimator, controller, reference (and recorder) in one process"),
        recorder,
        rig,
        *loop,
        OpaqueFunction(function=_container, args=[params, bag]),
        driver,
    ])


def _container(context, params, bag):
    """compose:=true: the loop's nodes in one ``container`` process (the recorder too with record:=true); no
    name= (it would rename every node of the process)."""
    if LaunchConfiguration("compose").perform(context).lower() != "true":
        return []
    args = ["--nodes", "estimator,controller,reference"]
    if LaunchConfiguration("record").perform(context).lower() == "true":
        args += ["--bag", bag.perform(context)]
    return [Node(package="dem_ros", executable="container", output="screen", arguments=args,
                 parameters=[params.perform(context)])]

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
The command delay (``command_delay``, samples) of the controller, the driver and, with ``link:=rig``, the emulated
board: by default the params file's for a real board (its firmware's delay, stated in its hello), and for
``link:=rig`` the emulated rig's ``RIG_COMMAND_DELAY`` (3), as ``dem-ros launch --hardware rig`` runs it; the
controller's ``max_age`` is raised to (delay + 1) samples where it is shorter.
With compose:=true the estimator, controller and reference (and the recorder, with record:=true) run in one
``container`` process on one executor beside the driver's own process, as ``dem-ros launch --hardware ...
--compose`` does: the configuration that holds the rig on a 2-core machine (docs/manual/transports.md).
"""

import os
from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, ExecuteProcess, OpaqueFunction
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node
from launch_ros.substitutions import ExecutableInPackage

from launch import LaunchDescription

RIG_URL = "udp://127.0.0.1:47000"


def generate_launch_description():
    default_params = os.path.join(get_package_share_directory("dem_ros"), "config", "dem_ros.yaml")
    params = LaunchConfiguration("params_file")
    link = LaunchConfiguration("link")
    url = PythonExpression(["'", RIG_URL, "' if '", link, "' == 'rig' else '", link, "'"])
    bag = PythonExpression(["'", LaunchConfiguration("bag_dir"),
                            "/' + __import__('time').strftime('%Y%m%d-%H%M%S') + '_hw'"])
    recorder = ExecuteProcess(
        cmd=["ros2", "run", "dem_ros", "recorder", "--bag", bag],
        output="screen",
        condition=IfCondition(PythonExpression(["'", LaunchConfiguration("record"), "'.lower() == 'true' and '",
                                                LaunchConfiguration("compose"), "'.lower() != 'true'"])),
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
        DeclareLaunchArgument("command_delay", default_value="",
                              description="samples from a measurement to its command's period (default: the params"
                                          " file's; 3 with link:=rig, as dem-ros launch --hardware rig)"),
        recorder,
        OpaqueFunction(function=_graph, args=[params, url, bag]),
    ])


def _delay(context, params: str) -> str | None:
    """A params file (node name -> parameters) with the run's command delay for the controller and the driver;
    None: the params file's."""
    import tempfile

    from dem_ros.core.params import load_params_file
    from dem_ros.tools.launcher import RIG_COMMAND_DELAY

    given = LaunchConfiguration("command_delay").perform(context).strip()
    if not given and LaunchConfiguration("link").perform(context) != "rig":
        return None
    try:
        d = int(given) if given else RIG_COMMAND_DELAY
    except ValueError:
        raise RuntimeError(f"command_delay:={given!r}: not an integer number of samples") from None
    cfg = load_params_file(params)
    max_age = max(float(cfg["controller"]["max_age"]), (d + 1) * float(cfg["plant_sim"]["dt"]))
    with tempfile.NamedTemporaryFile("w", prefix="dem_ros_delay_", suffix=".yaml", delete=False) as f:
        f.write(f"controller:\n  ros__parameters:\n    command_delay: {d}\n    max_age: {max_age!r}\n"
                f"hw_driver:\n  ros__parameters:\n    command_delay: {d}\n")
    return f.name


def _read_delay(path: str) -> int:
    """The driver's command delay in a file written by :func:`_delay`."""
    from dem_ros.core.params import read_yaml

    return int(read_yaml(Path(path))["hw_driver"]["ros__parameters"]["command_delay"])


def _graph(context, params, url, bag):
    """The driver, the loop's nodes (a process each, or the container with compose:=true) and, with link:=rig,
    the emulated board, all with the run's command delay."""
    params_file = params.perform(context)
    delay_file = _delay(context, params_file)
    files = [params_file, *([delay_file] if delay_file else [])]
    compose = LaunchConfiguration("compose").perform(context).lower() == "true"
    actions = []
    if LaunchConfiguration("link").perform(context) == "rig":
        board = [f"--set=hw_driver.command_delay={_read_delay(delay_file)}"] if delay_file else []
        actions.append(ExecuteProcess(
            # the package's own dem-ros (lib/dem_ros; a colcon install puts none on PATH)
            cmd=[ExecutableInPackage("dem-ros", "dem_ros"), "rig", "--url", RIG_URL, "--params", params_file,
                 "--scenario", LaunchConfiguration("scenario"), *board],
            output="screen"))
    if compose:
        args = ["--nodes", "estimator,controller,reference"]
        if LaunchConfiguration("record").perform(context).lower() == "true":
            args += ["--bag", bag.perform(context)]
        actions.append(Node(package="dem_ros", executable="container", output="screen", arguments=args,
                            parameters=files))
    else:
        actions += [Node(package="dem_ros", executable=name, name=name, output="screen", parameters=files)
                    for name in ("reference", "estimator", "controller")]
    actions.append(Node(package="dem_ros", executable="hw_driver", name="hw_driver", output="screen",
                        parameters=[*files, {"url": url, "auto_arm": LaunchConfiguration("auto_arm")}]))
    return actions

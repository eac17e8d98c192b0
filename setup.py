"""ament_python package that also installs with plain pip.

Under a sourced ROS 2 (colcon build), every node gets its own console script
so that ``ros2 run dem_ros controller`` works. A plain ``pip install`` gets only
the namespaced ``dem-ros`` CLI, never bare names such as ``controller`` on PATH.
"""
import ast
import os
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

package_name = "dem_ros"


def _nodes() -> tuple:
    """dem_ros.nodes.NODES, read without importing the package (its dependencies may not be installed yet)."""
    tree = ast.parse((Path(__file__).parent / "dem_ros" / "nodes" / "__init__.py").read_text())
    for stmt in tree.body:
        targets = stmt.targets if isinstance(stmt, ast.Assign) else [getattr(stmt, "target", None)]
        if any(isinstance(t, ast.Name) and t.id == "NODES" for t in targets):
            return tuple(ast.literal_eval(stmt.value))
    raise RuntimeError("dem_ros/nodes/__init__.py defines no NODES")


NODES = _nodes()

scripts = ["dem-ros = dem_ros.tools.cli:main"]
if os.environ.get("AMENT_PREFIX_PATH") or os.environ.get("DEM_ROS_NODE_SCRIPTS"):
    scripts += [f"{n} = dem_ros.nodes.{n}:main" for n in NODES]

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["tests", "tests.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/launch", glob("launch/*.launch.py")),
    ],
    package_data={"dem_ros": ["data/*.yaml"]},
    python_requires=">=3.10",
    install_requires=[
        "numpy>=1.24",
        "scipy>=1.10",
        "numba>=0.58",
        "PyYAML>=6",
        "matplotlib>=3.7",
        "cyclonedds>=0.10.5",
        "rosbags>=0.10",
        # the chunk compressions of rosbag2 MCAP files (written and read by dem_ros.bag)
        "zstandard>=0.21",
        "lz4>=4",
        "dask[distributed]>=2024.1",
        "pyserial>=3.4",  # the device link over serial lines (dem_ros/hardware/channel.py)
    ],
    # mcap: an independent MCAP reader/writer the bag tests check our files against;
    # ruff and mypy: tests/tools/test_lint.py runs them
    # ros: ROS 2 Jazzy's rclpy on rmw_fastrtps_cpp and the message packages the nodes use, from the
    # package index (cp311 manylinux wheels): the rclpy transport with no ROS install (make test adds it)
    # view: dem-ros view (a Foxglove WebSocket server; websockets for its --check client); the tests run it
    extras_require={
        "test": ["pytest>=7", "sympy>=1.12", "hypothesis>=6", "mcap>=1.1", "ruff>=0.5", "mypy>=1.10", "types-PyYAML",
                 "foxglove-sdk>=0.30", "websockets>=12"],
        "ros": ["ros-jazzy-rclpy", "ros-jazzy-rmw-fastrtps-cpp", "ros-jazzy-std-msgs", "ros-jazzy-sensor-msgs",
                "ros-jazzy-diagnostic-msgs", "ros-jazzy-rcl-interfaces", "ros-jazzy-std-srvs",
                "ros-jazzy-lifecycle-msgs"],
        "view": ["foxglove-sdk>=0.30", "websockets>=12"],
    },
    zip_safe=True,
    maintainer="dem_ros maintainers",
    maintainer_email="dem-ros@example.com",
    description="Adaptive control of a double-electromagnet maglev suspension as a ROS 2 package.",
    license="Apache-2.0",
    entry_points={"console_scripts": scripts},
)

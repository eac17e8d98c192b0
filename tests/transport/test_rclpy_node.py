"""The rclpy implementation (runs only where a ROS 2 environment is sourced)."""

import pytest

rclpy = pytest.importorskip("rclpy", reason="rclpy not importable: no ROS 2 sourced; the rclpy transport is untested here")

from dem_ros import contract  # noqa: E402
from dem_ros.transport import make_node, serialize  # noqa: E402
from dem_ros.transport.dds import msgs  # noqa: E402


@pytest.fixture
def node():
    n = make_node("rclpy_test_controller", transport="rclpy", args=["--ros-args", "-p", "k1:=80.0"])
    yield n
    n.shutdown()


def test_parameters_declared_with_descriptors_and_group_validation(node):
    values = node.declare_parameters("controller", lambda v: "vetoed" if v["k1"] > 500 else None)
    assert values["k1"] == 80.0
    d = node.ros_node.describe_parameter("k1")
    assert d.floating_point_range and d.description
    assert node.ros_node.describe_parameter("dt").read_only
    assert "Hurwitz" in node.set_parameters({"k1": 0.5})
    assert node.set_parameters({"k1": 600.0}) == "vetoed"
    assert node.set_parameters({"k1": 60.0}) is None
    assert node.ros_node.get_parameter("k1").value == 60.0


def test_cdr_matches_dds_transport(node):
    JointState = node.msg("sensor_msgs/msg/JointState")
    m = JointState(name=["magnet_1"], position=[0.008], velocity=[], effort=[1.0])
    m.header.stamp.sec = 3
    d = msgs.JointState(name=["magnet_1"], position=[0.008], velocity=[], effort=[1.0])
    d.header.stamp.sec = 3
    assert serialize(m) == serialize(d)


def test_pub_sub_same_process(node):
    got = []
    node.subscribe(contract.RUN_INFO, got.append)
    pub = node.publisher(contract.RUN_INFO)
    pub.publish(node.msg("std_msgs/msg/String")(data="{}"))
    for _ in range(50):
        node.spin_once(0.05)
        if got:
            break
    assert got and got[0].data == "{}"

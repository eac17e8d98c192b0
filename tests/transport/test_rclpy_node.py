"""The rclpy transport (rclpy from the ``ros`` extra, which ``make test`` installs, or a sourced ROS 2)."""

import pytest

rclpy = pytest.importorskip("rclpy", reason="rclpy not importable: pip install -e '.[ros]' (make test does where "
                            "the wheels exist) or source a ROS 2 Jazzy")

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


def test_a_stock_rclpy_node_and_ours_read_each_others_joint_states(node):
    """Our node's messages (the project's classes and CDR codec) reach a stock rclpy subscription as
    the same values, and a stock rclpy publisher's reach ours. (Not byte equality: Fast CDR leaves
    alignment padding uninitialised, and rclpy.serialization.serialize_message returns 8 bytes past
    the message; on the wire the length is exact.)"""
    from sensor_msgs.msg import JointState as RosJointState

    assert node.msg("sensor_msgs/msg/JointState") is msgs.JointState  # the same classes on both transports
    stock = rclpy.create_node("rclpy_test_stock")
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor()
    ex.add_node(stock)
    try:
        theirs: list = []
        ours: list = []
        stock.create_subscription(RosJointState, contract.COMMAND.name, theirs.append, 10)
        stock_pub = stock.create_publisher(RosJointState, contract.MEASUREMENT.name, 10)
        node.subscribe(contract.MEASUREMENT, ours.append)
        pub = node.publisher(contract.COMMAND)
        _spin_until(_spinners(node, ex),
                    lambda: pub.subscription_count >= 1 and stock_pub.get_subscription_count() >= 1)
        d = msgs.JointState(name=["magnet_1", "magnet_2"], position=[0.008, 0.007], velocity=[], effort=[1.0, -2.5])
        d.header.stamp.sec, d.header.frame_id = 3, "rig"
        pub.publish(d)
        m = RosJointState(name=["magnet_1"], position=[0.008], velocity=[], effort=[1.0])
        m.header.stamp.sec, m.header.frame_id = 4, "plant"
        stock_pub.publish(m)
        _spin_until(_spinners(node, ex), lambda: bool(theirs) and bool(ours), 10.0)
        r = theirs[0]
        assert (r.header.stamp.sec, r.header.frame_id, list(r.name), list(r.position), len(r.velocity),
                list(r.effort)) == (3, "rig", ["magnet_1", "magnet_2"], [0.008, 0.007], 0, [1.0, -2.5])
        want = msgs.JointState(name=["magnet_1"], position=[0.008], velocity=[], effort=[1.0])
        want.header.stamp.sec, want.header.frame_id = 4, "plant"
        assert ours == [want]
    finally:
        ex.remove_node(stock)
        stock.destroy_node()


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


def _spin_until(spinners, done, timeout_s: float = 30.0) -> None:
    """Call each ``spin()`` in turn (a node's or an executor's bounded spin_once) until ``done()``."""
    import time

    end = time.monotonic() + timeout_s
    while not done() and time.monotonic() < end:
        for spin in spinners:
            spin()


def _spinners(node, ex=None):
    """Bounded spins of our node and, if given, of a second rclpy executor (the client's)."""
    out = [lambda: node.spin_once(0.02)]
    if ex is not None:
        out.append(lambda: ex.spin_once(timeout_sec=0.02))
    return out


def test_integer_literal_sets_a_double_over_the_parameter_service(node):
    """What `ros2 param set /controller w 60` sends: ParameterValue(type=INTEGER, 60) to the
    node's real set_parameters service; the double parameter takes 60.0 (Jazzy: pre-set callback)."""
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    from rclpy.executors import SingleThreadedExecutor

    node.declare_parameters("controller")
    client_node = rclpy.create_node("rclpy_test_param_client")
    ex = SingleThreadedExecutor()
    ex.add_node(client_node)
    try:
        cli = client_node.create_client(SetParameters, node.fully_qualified_name + "/set_parameters")
        _spin_until(_spinners(node, ex), cli.service_is_ready)
        assert cli.service_is_ready()
        req = SetParameters.Request(parameters=[
            Parameter(name="w", value=ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=60)),
            Parameter(name="k1", value=ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=0)),
        ])
        fut = cli.call_async(req)
        _spin_until(_spinners(node, ex), fut.done)
        ok, bad = fut.result().results
        assert ok.successful, ok.reason
        assert not bad.successful and "Hurwitz" in bad.reason
        assert node.parameters["w"] == 60.0 and isinstance(node.parameters["w"], float)
        assert node.ros_node.get_parameter("w").type_ == rclpy.Parameter.Type.DOUBLE
        assert node.parameters["k1"] == 80.0
    finally:
        ex.remove_node(client_node)
        client_node.destroy_node()


def test_service_answers_and_a_raising_callback_answers_false(node):
    from rclpy.executors import SingleThreadedExecutor
    from std_srvs.srv import SetBool, Trigger

    calls = []

    def arm(req, rep):
        calls.append(req.data)
        rep.success, rep.message = True, f"armed {req.data}"
        return rep

    def boom(req, rep):
        raise ValueError("no plate")

    node.service("arm", "std_srvs/srv/SetBool", arm)
    node.service("reset", "std_srvs/srv/Trigger", boom)
    client_node = rclpy.create_node("rclpy_test_srv_client")
    ex = SingleThreadedExecutor()
    ex.add_node(client_node)
    try:
        c_arm = client_node.create_client(SetBool, node.fully_qualified_name + "/arm")
        c_reset = client_node.create_client(Trigger, node.fully_qualified_name + "/reset")
        _spin_until(_spinners(node, ex), lambda: c_arm.service_is_ready() and c_reset.service_is_ready())
        f1, f2 = c_arm.call_async(SetBool.Request(data=True)), c_reset.call_async(Trigger.Request())
        _spin_until(_spinners(node, ex), lambda: f1.done() and f2.done())
        assert f1.result().success and f1.result().message == "armed True" and calls == [True]
        assert not f2.result().success and "no plate" in f2.result().message
        assert node.callback_errors == {f"service {node.fully_qualified_name}/reset": 1}
    finally:
        ex.remove_node(client_node)
        client_node.destroy_node()


def test_raw_subscription_gets_the_cdr_the_dds_transport_writes(node):
    from dem_ros.nodes.common import joint_state

    got: list[bytes] = []
    node.subscribe_raw(contract.COMMAND, got.append)
    pub = node.publisher(contract.COMMAND)
    JS = node.msg(contract.COMMAND.type)
    m = joint_state(JS, 1_700_000_000_123_456_789, effort=(1.5, -2.0))
    _spin_until(_spinners(node), lambda: pub.subscription_count >= 1, 10.0)
    pub.publish(m)
    _spin_until(_spinners(node), lambda: bool(got), 10.0)
    d = joint_state(msgs.JointState, 1_700_000_000_123_456_789, effort=(1.5, -2.0))
    assert got and bytes(got[0]) == serialize(d)


def test_callback_error_is_counted_and_the_node_keeps_running(node):
    seen = []

    def bad(msg):
        seen.append(msg.data)
        raise RuntimeError("bad sample")

    node.subscribe(contract.RUN_INFO, bad)
    pub = node.publisher(contract.RUN_INFO)
    String = node.msg("std_msgs/msg/String")
    pub.publish(String(data="a"))
    _spin_until(_spinners(node), lambda: bool(seen), 10.0)
    pub.publish(String(data="b"))
    _spin_until(_spinners(node), lambda: len(seen) >= 2, 10.0)
    assert seen == ["a", "b"]
    assert node.callback_errors == {f"subscription {contract.RUN_INFO.name}": 2}


def test_sources_name_the_writer_of_every_sample_among_two(node):
    """Each sample comes with its writer's GID (rcl's message info, taken through ctypes), the one
    publisher_gids lists for that writer's node and its publisher holds, also while two writers share the
    topic."""
    from dem_ros.nodes.common import joint_state
    from dem_ros.transport.api import GID_SIZE

    ctl = make_node("rclpy_test_ctl", transport="rclpy", args=[])
    rogue = make_node("rclpy_test_rogue", transport="rclpy", args=[])
    try:
        got: list[tuple[float, bytes]] = []
        node.subscribe_with_source(contract.COMMAND, lambda m, gid: got.append((m.effort[0], gid)))
        JS = node.msg(contract.COMMAND.type)
        p_ctl, p_rogue = ctl.publisher(contract.COMMAND), rogue.publisher(contract.COMMAND)
        spin = [*_spinners(node), lambda: ctl.spin_once(0.01), lambda: rogue.spin_once(0.01)]
        _spin_until(spin, lambda: p_ctl.subscription_count >= 1 and p_rogue.subscription_count >= 1)
        g_ctl = node.publisher_gids(contract.COMMAND, "/rclpy_test_ctl")
        g_rogue = node.publisher_gids(contract.COMMAND, "rclpy_test_rogue")
        assert len(g_ctl) == len(g_rogue) == 1 and g_ctl != g_rogue
        assert len(next(iter(g_ctl))) == GID_SIZE
        for k in range(3):
            p_ctl.publish(joint_state(JS, 2 * k + 1, effort=(float(2 * k + 1), 0.0)))
            p_rogue.publish(joint_state(JS, 2 * k + 2, effort=(float(2 * k + 2), 0.0)))
        _spin_until(spin, lambda: len(got) >= 6, 10.0)
        ctl_gid, rogue_gid = next(iter(g_ctl)), next(iter(g_rogue))
        assert (p_ctl.gid, p_rogue.gid) == (ctl_gid, rogue_gid)  # what in-memory delivery hands on, the same GID
        assert sorted(got) == [(float(v), ctl_gid if v % 2 else rogue_gid) for v in range(1, 7)]
    finally:
        rogue.shutdown()
        ctl.shutdown()


def test_log_lines_reach_a_stock_rosout_subscription_from_one_writer(node, capfd):
    """The node logs through the transport's logger (not rclpy's, whose lines cost the 1 kHz loop
    milliseconds): one stderr line in rcutils' console format, and the record on /rosout as rcl
    publishes it, from the node's one /rosout writer (rcl's own rosout is off)."""
    from rcl_interfaces.msg import Log
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    stock = rclpy.create_node("rclpy_test_rosout_reader")
    ex = SingleThreadedExecutor()
    ex.add_node(stock)
    try:
        got: list = []
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        stock.create_subscription(Log, "/rosout", lambda m: got.append(m) if m.name == node.logger_name else None, qos)
        writers = [i for i in stock.get_publishers_info_by_topic("/rosout") if i.node_name == node.name]
        assert len(writers) == 1
        _spin_until(_spinners(node, ex), lambda: stock.count_publishers("/rosout") >= 1 and
                    any(i.node_name == node.name for i in stock.get_publishers_info_by_topic("/rosout")))
        node.logger.warn("hold engaged")
        _spin_until(_spinners(node, ex), lambda: bool(got), 10.0)
        assert [(m.level, m.msg) for m in got] == [(30, "hold engaged")]
        err = capfd.readouterr().err
        assert "[WARN] [" in err and f"] [{node.logger_name}]: hold engaged" in err
    finally:
        ex.shutdown()
        stock.destroy_node()


def test_cyclone_instance_handle_gids_are_told_from_guids():
    """rmw_cyclonedds_cpp gives a sample's writer as its 8-byte instance handle (zero-padded), the graph
    lists its GUID: the take resolves the former (with a sourced Jazzy on rmw_cyclonedds_cpp,
    test_sources_name_the_writer_of_every_sample_among_two checks the resolution end to end)."""
    from dem_ros.transport.rclpy.take import CYCLONE, is_handle_gid

    handle = (0x94BAE4ADF3D114C1).to_bytes(8, "little") + bytes(8)
    guid = bytes.fromhex("0110b767817464d2574523b800005a03")
    assert is_handle_gid(CYCLONE, handle)
    assert not is_handle_gid(CYCLONE, guid)
    assert not is_handle_gid(b"rmw_fastrtps_cpp", handle)
    assert not is_handle_gid(CYCLONE, bytes(16))

"""Offline checks of the DDS wire conventions, CDR bytes and ROS argument parsing."""

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from dem_ros.core.params import ConfigError
from dem_ros.transport import TransportError, deserialize, serialize
from dem_ros.transport.dds import fastcdr, msgs, wire
from dem_ros.transport.rosargs import initial_parameters, parse_ros_args

JAZZY = get_typestore(Stores.ROS2_JAZZY)


# ----------------------------------------------------------------------------- CDR bytes
def _rb(typename, **kw):
    return JAZZY.types[typename](**kw)


def _time(sec, nanosec):
    return _rb("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec)


def test_joint_state_bytes_equal_rosbags():
    m = msgs.JointState(name=["magnet_1", "magnet_2"], position=[0.008, 0.0079], velocity=[], effort=[1.5, -2.0])
    m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id = 12, 345, "dem"
    ref = _rb(
        "sensor_msgs/msg/JointState",
        header=_rb("std_msgs/msg/Header", stamp=_time(12, 345), frame_id="dem"),
        name=["magnet_1", "magnet_2"], position=np.array([0.008, 0.0079]),
        velocity=np.array([], dtype=np.float64), effort=np.array([1.5, -2.0]),
    )
    data = serialize(m)
    assert data == bytes(JAZZY.serialize_cdr(ref, "sensor_msgs/msg/JointState"))
    assert data == m.serialize()  # fast codec == cyclonedds-python's generic one
    assert deserialize("sensor_msgs/msg/JointState", data, transport="dds") == m


def test_string_bytes_equal_rosbags():
    m = msgs.String(data='{"k1": 70}')
    ref = _rb("std_msgs/msg/String", data='{"k1": 70}')
    assert serialize(m) == bytes(JAZZY.serialize_cdr(ref, "std_msgs/msg/String"))


def test_diagnostic_array_bytes_equal_rosbags():
    st = msgs.DiagnosticStatus(level=msgs.DiagnosticStatus.WARN, name="controller: loop", message="late",
                               hardware_id="dem", values=[msgs.KeyValue(key="overruns", value="3")])
    m = msgs.DiagnosticArray(status=[st])
    m.header.stamp.sec = 7
    ref = _rb(
        "diagnostic_msgs/msg/DiagnosticArray",
        header=_rb("std_msgs/msg/Header", stamp=_time(7, 0), frame_id=""),
        status=[_rb("diagnostic_msgs/msg/DiagnosticStatus", level=1, name="controller: loop", message="late",
                    hardware_id="dem", values=[_rb("diagnostic_msgs/msg/KeyValue", key="overruns", value="3")])],
    )
    assert serialize(m) == bytes(JAZZY.serialize_cdr(ref, "diagnostic_msgs/msg/DiagnosticArray"))


def test_parameter_event_bytes_equal_rosbags():
    def rb_value(**kw):
        base = dict(type=0, bool_value=False, integer_value=0, double_value=0.0, string_value="",
                    byte_array_value=np.array([], dtype=np.uint8), bool_array_value=np.array([], dtype=bool),
                    integer_array_value=np.array([], dtype=np.int64),
                    double_array_value=np.array([], dtype=np.float64), string_array_value=[])
        base.update(kw)
        return _rb("rcl_interfaces/msg/ParameterValue", **base)

    m = msgs.ParameterEvent(
        stamp=msgs.Time(sec=1, nanosec=2), node="/controller",
        new_parameters=[msgs.Parameter(name="type", value=msgs.ParameterValue(type=4, string_value="adaptive"))],
        changed_parameters=[msgs.Parameter(name="k1", value=msgs.ParameterValue(type=3, double_value=60.0))],
    )
    ref = _rb(
        "rcl_interfaces/msg/ParameterEvent", stamp=_time(1, 2), node="/controller",
        new_parameters=[_rb("rcl_interfaces/msg/Parameter", name="type",
                            value=rb_value(type=4, string_value="adaptive"))],
        changed_parameters=[_rb("rcl_interfaces/msg/Parameter", name="k1", value=rb_value(type=3, double_value=60.0))],
        deleted_parameters=[],
    )
    assert serialize(m) == bytes(JAZZY.serialize_cdr(ref, "rcl_interfaces/msg/ParameterEvent"))


def test_fast_codec_matches_generic_on_random_messages():
    rng = np.random.default_rng(3)
    for _ in range(300):
        def seq():
            return rng.normal(size=int(rng.integers(0, 4))).tolist()

        m = msgs.JointState(name=["j" * int(rng.integers(0, 9)) for _ in range(int(rng.integers(0, 4)))],
                            position=seq(), velocity=seq(), effort=seq())
        m.header.frame_id = "f" * int(rng.integers(0, 8))
        m.header.stamp.sec, m.header.stamp.nanosec = int(rng.integers(0, 2**31 - 1)), int(rng.integers(0, 10**9))
        assert fastcdr.encode_joint_state(m) == m.serialize()
        assert fastcdr.decoder(msgs.JointState)(m.serialize()) == m


# ----------------------------------------------------------------------------- names and hashes
def test_ros_names():
    assert wire.topic_name("/dem/measurement") == "rt/dem/measurement"
    assert wire.service_topics("/dem/controller/set_parameters") == (
        "rq/dem/controller/set_parametersRequest", "rr/dem/controller/set_parametersReply")
    assert msgs.dds_type_name("sensor_msgs/msg/JointState") == "sensor_msgs::msg::dds_::JointState_"
    assert msgs.JointState.__idl_typename__ == "sensor_msgs::msg::dds_::JointState_"


def test_type_hash_std_msgs_string_matches_published_value():
    # published in the rmw_zenoh design document (key expression of the `chatter` talker)
    assert wire.type_hash("std_msgs/msg/String") == (
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18")
    assert wire.type_hash("std_msgs/msg/String", "humble") == ""
    assert wire.type_hash("rcl_interfaces/srv/SetParameters_Request").startswith("RIHS01_")
    assert wire.user_data_for_endpoint("std_msgs/msg/String", "jazzy", "serviceid=1;").startswith(
        b"serviceid=1;typehash=RIHS01_df668c74")


# ----------------------------------------------------------------------------- environment
@pytest.mark.parametrize("raw,ok", [(None, 0), ("", 0), ("7", 7), ("101", 101)])
def test_domain_id_ok(raw, ok):
    assert wire.parse_domain_id(raw) == ok


@pytest.mark.parametrize("raw", ["102", "-1", "abc", "1.5"])
def test_domain_id_bad(raw):
    with pytest.raises(TransportError, match="ROS_DOMAIN_ID"):
        wire.parse_domain_id(raw)


def test_discovery_config_localhost_mirrors_rmw_cyclonedds():
    s = wire.settings_from_env(env={"CYCLONEDDS_URI": "file:///tmp/x.xml"})
    assert (s.domain_id, s.distro, s.discovery_range, s.gid_size) == (0, "jazzy", "LOCALHOST", 16)
    rmw = (
        "<CycloneDDS><Domain><General><AllowMulticast>false</AllowMulticast></General>"
        "<Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>"
        '<Peers><Peer address="localhost"/></Peers></Discovery></Domain></CycloneDDS>,file:///tmp/x.xml'
    )
    assert wire.rmw_domain_config(s) == rmw
    # Cyclone >= 11 drops SPDP arriving on an unselected interface; rmw_cyclonedds' LOCALHOST
    # announcements arrive on lo, so dem_ros selects it explicitly in front of the rmw string
    lo = ('<CycloneDDS><Domain><General><Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces></General>'
          '</Domain></CycloneDDS>,')
    assert wire.domain_config(s) == lo + rmw


def test_localhost_interface_fragment_yields_to_user_and_peers(tmp_path):
    peers = wire.settings_from_env(env={"ROS_STATIC_PEERS": "192.0.2.7"})
    assert 'autodetermine="true"' in wire.interface_config(peers) and "127.0.0.1" in wire.interface_config(peers)
    inline = wire.settings_from_env(env={"CYCLONEDDS_URI": '<General><Interfaces><NetworkInterface name="eth1"/>'
                                                           '</Interfaces></General>'})
    assert wire.interface_config(inline) == ""
    f = tmp_path / "cyclone.xml"
    f.write_text('<CycloneDDS><Domain><General><Interfaces><NetworkInterface name="lo"/></Interfaces></General>'
                 '</Domain></CycloneDDS>')
    assert wire.interface_config(wire.settings_from_env(env={"CYCLONEDDS_URI": f"file://{f}"})) == ""
    for rng in ("SUBNET", "OFF", "SYSTEM_DEFAULT"):
        assert wire.interface_config(wire.settings_from_env(env={"ROS_AUTOMATIC_DISCOVERY_RANGE": rng})) == ""
    sub = wire.settings_from_env(env={"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "DEM_ROS_DISTRO": "humble"})
    assert sub.gid_size == 24
    assert "AllowMulticast" not in wire.domain_config(sub)
    with pytest.raises(TransportError, match="DEM_ROS_DISTRO"):
        wire.settings_from_env(env={"DEM_ROS_DISTRO": "foxy"})


# ----------------------------------------------------------------------------- ROS arguments
def test_ros_args_like_rcl(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text("/dem/controller:\n  ros__parameters:\n    k1: 80.0\n    type: paper\n")
    ra = parse_ros_args(["user", "--ros-args", "--params-file", str(f), "-p", "k2:=2000", "-r", "__node:=ctl",
                         "-r", "__ns:=/dem", "-r", "/dem/command:=/x/command", "--log-level", "info", "--", "tail"])
    assert (ra.node_name, ra.namespace, ra.user_args) == ("ctl", "/dem", ["user", "tail"])
    assert ra.resolve("command", "/dem") == ra.resolve("/dem/command") == "/x/command"
    assert ra.resolve("/dem/other", "/dem", "ctl") == "/dem/other"
    v = initial_parameters("controller", ra, "ctl")
    assert (v["k1"], v["k2"], v["type"], v["k3"]) == (80.0, 2000.0, "paper", 12000.0)


def test_node_targeted_rules_apply_to_their_node_only():
    """rcl's ``node:rule``: in a container every node sees the same arguments; each takes its own rules."""
    ra = parse_ros_args(["--ros-args", "-r", "controller:/dem/command:=/x", "-r", "/dem/reference:=/ref",
                         "-r", "plant_sim:__node:=rig", "-r", "estimator:__ns:=/est"])
    assert ra.resolve("/dem/command", node="controller") == "/x"
    assert ra.resolve("/dem/command", node="plant_sim") == "/dem/command"
    assert ra.resolve("/dem/command") == "/dem/command"
    assert ra.resolve("/dem/reference", node="plant_sim") == ra.resolve("/dem/reference", node="controller") == "/ref"
    assert (ra.name_for("plant_sim"), ra.name_for("controller")) == ("rig", "controller")
    assert (ra.namespace_for("estimator"), ra.namespace_for("controller")) == ("/est", "/")
    assert ra.node_name is None  # nothing global: a container may run these


def test_first_matching_remap_rule_wins_as_in_rcl():
    ra = parse_ros_args(["--ros-args", "-r", "controller:/t:=/first", "-r", "/t:=/second"])
    assert ra.resolve("/t", node="controller") == "/first" and ra.resolve("/t", node="plant_sim") == "/second"


def test_bad_params_file_gives_config_error(tmp_path):
    f = tmp_path / "bad.yaml"
    f.write_text("controller:\n  ros__parameters:\n    k1: 1.0\n")  # k1*k2 > k3 fails: not Hurwitz
    with pytest.raises(ConfigError, match="Hurwitz"):
        initial_parameters("controller", parse_ros_args(["--ros-args", "--params-file", str(f)]))
    with pytest.raises(ConfigError, match="no such file"):
        parse_ros_args(["--ros-args", "--params-file", str(tmp_path / "missing.yaml")])
    with pytest.raises(ConfigError, match="unknown ROS argument"):
        parse_ros_args(["--ros-args", "--bogus"])

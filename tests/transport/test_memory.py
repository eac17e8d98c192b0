"""The in-memory transport honours the node interface; every transport implements all of it."""

import inspect

import pytest

from dem_ros import contract
from dem_ros.nodes.common import joint_state, stamp_ns
from dem_ros.transport import api, serialize
from dem_ros.transport.dds.node import DdsNode, DdsPublisher
from dem_ros.transport.memory import MemoryBus, MemoryNode, MemoryPublisher


def _members(proto: type) -> set[str]:
    return {n for n in dir(proto) if not n.startswith("_")} | set(getattr(proto, "__annotations__", {}))


@pytest.mark.parametrize(("cls", "proto"), [(DdsNode, api.Node), (MemoryNode, api.Node),
                                            (DdsPublisher, api.Publisher), (MemoryPublisher, api.Publisher)])
def test_every_transport_implements_the_whole_protocol(cls, proto):
    """Node code never needs getattr / hasattr: everything it may use is on the Protocol and on each class."""
    missing = [m for m in _members(proto) if not hasattr(cls, m) and m not in _instance_attrs(cls)]
    assert missing == []


def _instance_attrs(cls: type) -> set[str]:
    src = inspect.getsource(cls)
    return {m for m in ("name", "namespace", "logger") if f"self.{m} =" in src}


def test_rclpy_node_implements_the_whole_protocol_in_its_source():
    """Checked in the source (also where rclpy is not installed): every member of the Protocols is defined."""
    import ast
    from pathlib import Path

    import dem_ros.transport as t

    tree = ast.parse((Path(t.__file__).parent / "rclpy" / "node.py").read_text())
    classes = {c.name: c for c in tree.body if isinstance(c, ast.ClassDef)}

    def defined(c: ast.ClassDef) -> set[str]:
        out = {f.name for f in c.body if isinstance(f, ast.FunctionDef)}
        out |= {t.attr for n in ast.walk(c) if isinstance(n, ast.Assign) for t in n.targets
                if isinstance(t, ast.Attribute) and isinstance(t.value, ast.Name) and t.value.id == "self"}
        out |= {t.id for n in c.body if isinstance(n, ast.Assign) for t in n.targets if isinstance(t, ast.Name)}
        return out

    assert _members(api.Node) - defined(classes["RclpyNode"]) == set()
    assert _members(api.Publisher) - defined(classes["RclpyPublisher"]) == set()


def test_delivery_is_fifo_in_publish_order_and_never_reentrant():
    bus = MemoryBus()
    a, b = bus.node("a"), bus.node("b")
    JS = a.msg("sensor_msgs/msg/JointState")
    seen = []
    pub_cmd = b.publisher(contract.COMMAND)

    def on_meas(m):
        seen.append(("meas", stamp_ns(m)))
        pub_cmd.publish(joint_state(JS, stamp_ns(m), effort=(1.0, 2.0)))  # delivered after what is queued already
        seen.append(("meas done", stamp_ns(m)))

    b.subscribe(contract.MEASUREMENT, on_meas)
    a.subscribe(contract.COMMAND, lambda m: seen.append(("cmd", stamp_ns(m))))
    pm = a.publisher(contract.MEASUREMENT)
    assert pm.subscription_count == 1 and pub_cmd.subscription_count == 1
    pm.publish(joint_state(JS, 1, position=(0.008, 0.008)))
    pm.publish(joint_state(JS, 2, position=(0.008, 0.008)))
    assert seen == []  # nothing runs until the bus spins
    assert bus.spin_once() == 4
    assert seen == [("meas", 1), ("meas done", 1), ("meas", 2), ("meas done", 2), ("cmd", 1), ("cmd", 2)]


def test_raw_subscribers_get_the_cdr_bytes_and_raw_publishers_reach_decoding_subscribers():
    bus = MemoryBus()
    n = bus.node("n")
    JS = n.msg("sensor_msgs/msg/JointState")
    raw, objs = [], []
    n.subscribe_raw(contract.COMMAND, raw.append)
    n.subscribe(contract.COMMAND, objs.append)
    msg = joint_state(JS, 7, effort=(1.5, -2.5))
    n.publisher(contract.COMMAND).publish(msg)
    n.publisher(contract.COMMAND).publish_raw(serialize(joint_state(JS, 8, effort=(3.0, 4.0))))
    bus.spin_once()
    assert raw[0] == serialize(msg) and objs[0] is msg  # the object itself: intra-process, no copy
    assert stamp_ns(objs[1]) == 8 and list(objs[1].effort) == [3.0, 4.0]
    assert n.intra_process and n.transport == "memory"


def test_timers_fire_at_absolute_deadlines_of_the_manual_clock():
    bus = MemoryBus(start_ns=0)
    n = bus.node("n")
    ticks = []
    n.timer(0.001, lambda: ticks.append(n.now_ns()))
    slow = n.timer(0.0025, lambda: ticks.append(-n.now_ns()))
    bus.advance(0.005)
    assert ticks == [1_000_000, 2_000_000, -2_500_000, 3_000_000, 4_000_000, 5_000_000, -5_000_000]
    slow.cancel()
    bus.advance(0.003)
    assert ticks[-3:] == [6_000_000, 7_000_000, 8_000_000] and bus.now_ns == 8_000_000


def test_remaps_namespace_and_parameters_as_on_the_other_transports(tmp_path):
    bus = MemoryBus()
    f = tmp_path / "p.yaml"
    f.write_text("controller:\n  ros__parameters:\n    k2: 1700.0\n")
    n = bus.node("controller", ["--ros-args", "--params-file", str(f), "-p", "k1:=80.0", "-r", "__ns:=/dem",
                                "-r", "/dem/command:=/x"])
    assert n.fully_qualified_name == "/dem/controller"
    assert n.publisher(contract.COMMAND).topic == "/x"
    vetoed = []
    v = n.declare_parameters("controller",
                             lambda new: vetoed.append(new["k1"]) or ("too big" if new["k1"] > 500 else None))
    assert (v["k1"], v["k2"]) == (80.0, 1700.0)
    assert "Hurwitz" in n.set_parameters({"k1": 0.5})
    assert n.set_parameters({"k1": 600.0}) == "too big"
    assert "read-only" in n.set_parameters({"dt": 0.002})
    assert "not declared" in n.set_parameters({"nope": 1.0})
    assert n.set_parameters({"k1": 60.0}) is None and n.parameters["k1"] == 60.0


def test_callback_errors_are_counted_logged_once_and_never_stop_the_graph():
    bus = MemoryBus(start_ns=0)
    n = bus.node("n")
    JS = n.msg("sensor_msgs/msg/JointState")
    got = []

    def bad(m):
        got.append(stamp_ns(m))
        raise ValueError(f"bad {stamp_ns(m)}")

    n.subscribe(contract.COMMAND, bad)
    n.subscribe(contract.COMMAND, lambda m: got.append(-stamp_ns(m)))  # the next subscriber still gets it
    n.timer(0.001, lambda: 1 / 0)
    n.service("arm", "std_srvs/srv/Trigger", lambda req, rep: (_ for _ in ()).throw(RuntimeError("no board")))
    n.service("enable", "std_srvs/srv/SetBool", lambda req, rep: setattr(rep, "success", req.data) or rep)
    pub = n.publisher(contract.COMMAND)
    for k in range(3):
        pub.publish(joint_state(JS, k, effort=(0.0, 0.0)))
    bus.advance(0.003)
    rep = bus.call("/n/arm")
    assert (rep.success, rep.message) == (False, "RuntimeError: no board")
    assert bus.call("/n/enable", data=True).success and not bus.call("/n/enable", data=False).success
    assert got == [0, 0, 1, -1, 2, -2]
    assert n.callback_errors == {"subscription /dem/command": 3, "timer 0.001 s": 3, "service /n/arm": 1}
    errors = [text for level, _, text in bus.log if level == "ERROR"]
    assert len(errors) == 3 and "ValueError: bad 0" in errors[0] and "Traceback" in errors[0]
    with pytest.raises(api.TransportError, match="no service /n/disarm"):
        bus.call("/n/disarm")

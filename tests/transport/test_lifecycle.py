"""The managed-node layer: lifecycle_msgs IDL types (the dds transport's) against the ROS definitions, and the
state machine against lifecycle_msgs' constants, rcl_lifecycle's default state machine and the managed-node
design, including transitions that end later (DEFERRED, finish) and faults outside a callback (error).

Unit tier, but for the comparison with rcl's own machine (rclpy.lifecycle, a graph test: it joins DDS). The
transports serving a machine: tests/transport/test_lifecycle_serve.py; hw_driver's: tests/hardware.
"""

from __future__ import annotations

import random
import typing

import pytest
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import sequence
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype

from dem_ros.transport.dds import fastcdr
from dem_ros.transport.dds import lifecycle_msgs as lm
from dem_ros.transport.lifecycle import (
    CALLBACKS,
    DEFERRED,
    GRAPH,
    RESULTS,
    STATES,
    TRANSITIONS,
    CallbackResult,
    LifecycleError,
    LifecycleMachine,
    describe,
    requested,
)

JAZZY = get_typestore(Stores.ROS2_JAZZY)
RMW_HEADER = "uint64 guid\nint64 seq\n"
#: lifecycle_msgs/srv/*.srv (Jazzy), types fully qualified for the parser
SRV_TEXT = {
    "lifecycle_msgs/srv/GetState": ("", "lifecycle_msgs/msg/State current_state"),
    "lifecycle_msgs/srv/ChangeState": ("lifecycle_msgs/msg/Transition transition", "bool success"),
    "lifecycle_msgs/srv/GetAvailableStates": ("", "lifecycle_msgs/msg/State[] available_states"),
    "lifecycle_msgs/srv/GetAvailableTransitions": ("",
                                                   "lifecycle_msgs/msg/TransitionDescription[] available_transitions"),
}


def _srv_store():
    ts = get_typestore(Stores.ROS2_JAZZY)
    types: dict = {}
    for srv, (req, rep) in SRV_TEXT.items():
        for suffix, text in (("_Request", req), ("_Response", rep)):
            body = text or "uint8 structure_needs_at_least_one_member"  # rosidl's member of an empty struct
            types.update(get_types_from_msg(RMW_HEADER + body + "\n", srv.replace("/srv/", "/msg/") + suffix))
    ts.register(types)
    return ts


SRV_STORE = _srv_store()


def _desc(tp) -> tuple:
    if tp is str:
        return ("string",)
    if tp is bool:
        return ("bool",)
    if isinstance(tp, type) and issubclass(tp, IdlStruct):
        return ("struct", tp.__idl_typename__.split("::")[-1][:-1])
    meta = typing.get_args(tp)[1]
    if isinstance(meta, sequence):
        return ("sequence", _desc(meta.subtype))
    return (meta,)


def _theirs(node) -> tuple:
    kind, detail = node
    if kind == Nodetype.BASE:
        return (detail[0],)
    if kind == Nodetype.NAME:
        return ("struct", detail.split("/")[-1])
    return ("sequence", _theirs(detail[0]))


def _fields(cls) -> list:
    return [(k, _desc(v)) for k, v in typing.get_type_hints(cls, include_extras=True).items()]


@pytest.mark.parametrize("ros_type", sorted(lm.MESSAGES))
def test_message_matches_ros_definition(ros_type):
    cls = lm.MESSAGES[ros_type]
    assert cls.__idl_typename__ == ros_type.replace("/msg/", "::msg::dds_::").replace("/", "::") + "_"
    assert _fields(cls) == [(k, _theirs(v)) for k, v in JAZZY.fielddefs[ros_type][1]]


@pytest.mark.parametrize("srv", sorted(lm.SERVICE_CLASSES))
def test_service_matches_srv_definition(srv):
    for cls, suffix in zip(lm.SERVICE_CLASSES[srv], ("_Request", "_Response"), strict=True):
        assert cls.__idl_typename__ == srv.replace("/srv/", "::srv::dds_::").replace("/", "::") + suffix + "_"
        name = srv.replace("/srv/", "/msg/") + suffix
        assert _fields(cls) == [(k, _theirs(v)) for k, v in SRV_STORE.fielddefs[name][1]]


def test_every_service_name_has_its_classes():
    assert set(lm.SERVICES.values()) == set(lm.SERVICE_CLASSES)
    assert set(lm.SERVICES) == {"get_state", "change_state", "get_available_states", "get_available_transitions",
                                "get_transition_graph"}


@pytest.mark.parametrize("little_endian", [True, False], ids=["le", "be"])
def test_transition_event_bytes_agree_with_rosbags(little_endian):
    rng = random.Random(24)
    T = JAZZY.types
    for _ in range(50):
        tid, sid, gid = rng.randrange(256), rng.randrange(256), rng.randrange(256)
        label = "".join(rng.choice("abc_xyz") for _ in range(rng.randrange(12)))
        theirs = T["lifecycle_msgs/msg/TransitionEvent"](
            timestamp=rng.randrange(2**64), transition=T["lifecycle_msgs/msg/Transition"](id=tid, label=label),
            start_state=T["lifecycle_msgs/msg/State"](id=sid, label=label[::-1]),
            goal_state=T["lifecycle_msgs/msg/State"](id=gid, label=""))
        raw = bytes(JAZZY.serialize_cdr(theirs, "lifecycle_msgs/msg/TransitionEvent", little_endian=little_endian))
        ours = fastcdr.decode(lm.TransitionEvent, raw)
        assert (ours.timestamp, ours.transition.id, ours.transition.label, ours.start_state.id,
                ours.start_state.label, ours.goal_state.id) == (theirs.timestamp, tid, label, sid, label[::-1], gid)
        if little_endian:
            assert bytes(ours.serialize()) == raw


# -- the state machine ----------------------------------------------------------------------------------------

def _constants(ros_type: str) -> dict[str, int]:
    return {name: value for name, _t, value in JAZZY.fielddefs[ros_type][0]}


def test_state_ids_and_labels_are_lifecycle_msgs_constants():
    consts = _constants("lifecycle_msgs/msg/State")
    assert {f"PRIMARY_STATE_{label.upper()}" if sid < 10 else f"TRANSITION_STATE_{label.upper()}": sid
            for sid, label in STATES.items()} == consts


def test_transition_ids_are_lifecycle_msgs_constants():
    consts = _constants("lifecycle_msgs/msg/Transition")
    requests = {1: "CONFIGURE", 2: "CLEANUP", 3: "ACTIVATE", 4: "DEACTIVATE", 5: "UNCONFIGURED_SHUTDOWN",
                6: "INACTIVE_SHUTDOWN", 7: "ACTIVE_SHUTDOWN"}
    for t in TRANSITIONS:
        assert consts[f"TRANSITION_{requests[t.id]}"] == t.id
        assert requests[t.id].lower().endswith(t.label)
    for (via, result), (tid, label, _goal) in RESULTS.items():  # TRANSITION_ON_CONFIGURE_SUCCESS = 10, ...
        assert consts[f"TRANSITION_ON_{CALLBACKS[via].removeprefix('on_').upper()}_{result.name}"] == tid
        assert label == f"transition_{result.name.lower()}"  # rcl's label of every result transition
    for r in CallbackResult:
        assert consts[f"TRANSITION_CALLBACK_{r.name}"] == r.value


class _Node:
    """A managed node's callbacks, answering what the test tells them to; records what ran."""

    def __init__(self):
        self.answers: dict[str, CallbackResult] = {}
        self.ran: list[tuple[str, int]] = []

    def callbacks(self):
        def make(name):
            def cb(previous: int) -> CallbackResult:
                self.ran.append((name, previous))
                answer = self.answers.get(name, CallbackResult.SUCCESS)
                if answer == "raise":
                    raise RuntimeError("link lost")
                return answer
            return cb
        return {name: make(name) for name in CALLBACKS.values()}


def _machine():
    node, events = _Node(), []
    m = LifecycleMachine(node.callbacks(), now_ns=lambda: 42, on_event=events.append)
    return m, node, events


def test_configure_activate_deactivate_cleanup_shutdown():
    m, node, events = _machine()
    assert m.label == "unconfigured" and [t.label for t in m.available()] == ["configure", "shutdown"]
    assert m.trigger("configure") and m.label == "inactive"
    assert m.trigger(3) and m.label == "active"
    assert [t.label for t in m.available()] == ["deactivate", "shutdown"]
    assert m.trigger("deactivate") and m.label == "inactive"
    assert m.trigger("cleanup") and m.label == "unconfigured"
    assert m.trigger(5) and m.label == "finalized" and m.available() == ()
    assert [n for n, _ in node.ran] == ["on_configure", "on_activate", "on_deactivate", "on_cleanup", "on_shutdown"]
    # each request: start -> transition state, then transition state -> goal
    assert [(e.transition_label, e.start, e.goal) for e in events[:2]] == [("configure", 1, 10),
                                                                            ("transition_success", 10, 2)]
    assert all(e.timestamp_ns == 42 for e in events) and len(events) == 10


def test_an_invalid_request_is_refused_with_what_is_valid():
    m, node, events = _machine()
    with pytest.raises(LifecycleError, match=r"'activate' is not valid from state unconfigured \(valid: 1 configure"):
        m.trigger("activate")
    assert m.label == "unconfigured" and not node.ran and not events


def test_a_failed_deactivate_stays_active():
    """hw_driver's deactivate succeeds only once the board reports LANDED: a failure keeps the node active."""
    m, node, _ = _machine()
    m.trigger("configure")
    m.trigger("activate")
    node.answers["on_deactivate"] = CallbackResult.FAILURE
    assert not m.trigger("deactivate") and m.label == "active"


@pytest.mark.parametrize(("on_error", "end"), [(CallbackResult.SUCCESS, "unconfigured"),
                                               (CallbackResult.FAILURE, "finalized")])
def test_an_error_goes_through_errorprocessing(on_error, end):
    m, node, events = _machine()
    m.trigger("configure")
    node.answers["on_activate"] = "raise"  # an exception in a callback is an ERROR
    node.answers["on_error"] = on_error
    assert not m.trigger("activate")
    assert m.label == end
    assert ("on_error", 2) in node.ran  # the error callback learns the state it came from
    assert [(e.start, e.goal) for e in events[-3:]] == [(2, 13), (13, 15), (15, 1 if end == "unconfigured" else 4)]


def test_unknown_callbacks_are_refused():
    with pytest.raises(LifecycleError, match="unknown lifecycle callbacks"):
        LifecycleMachine({"on_arm": lambda p: CallbackResult.SUCCESS}, now_ns=lambda: 0)


#: rcl_lifecycle's default state machine as rclpy.lifecycle's ``_state_machine.transition_graph`` lists it (Jazzy;
#: test_the_graph_is_rcl_s_own compares it with the live one where rclpy imports)
RCL_GRAPH = [
    (1, "configure", 1, 10), (10, "transition_success", 10, 2), (11, "transition_failure", 10, 1),
    (12, "transition_error", 10, 15),
    (2, "cleanup", 2, 11), (20, "transition_success", 11, 1), (21, "transition_failure", 11, 2),
    (22, "transition_error", 11, 15),
    (3, "activate", 2, 13), (30, "transition_success", 13, 3), (31, "transition_failure", 13, 2),
    (32, "transition_error", 13, 15),
    (4, "deactivate", 3, 14), (40, "transition_success", 14, 2), (41, "transition_failure", 14, 3),
    (42, "transition_error", 14, 15),
    (5, "shutdown", 1, 12), (6, "shutdown", 2, 12), (7, "shutdown", 3, 12), (50, "transition_success", 12, 4),
    (51, "transition_failure", 12, 4), (52, "transition_error", 12, 15),
    (60, "transition_success", 15, 1), (61, "transition_failure", 15, 4), (62, "transition_error", 15, 4),
]


def test_the_graph_and_the_descriptions_are_rcl_s():
    assert list(GRAPH) == RCL_GRAPH
    assert describe(GRAPH[:1]) == [(1, "configure", 1, "unconfigured", 10, "configuring")]
    m, _node, _events = _machine()
    assert m.available_edges() == ((1, "configure", 1, 10), (5, "shutdown", 1, 12))


def test_the_graph_is_rcl_s_own(domain_id):
    """The same graph, states and available transitions as rclpy.lifecycle's (rcl_lifecycle in the Jazzy wheels)."""
    rclpy = pytest.importorskip("rclpy", reason="rclpy not importable: pip install -e '.[ros]'")
    from rclpy.lifecycle import LifecycleNode

    rclpy.init(args=[], domain_id=domain_id)
    try:
        node = LifecycleNode("lifecycle_probe", enable_communication_interface=False)
        sm = node._state_machine
        assert describe(GRAPH) == list(sm.transition_graph)
        assert sorted(STATES.items()) == sorted(sm.available_states)
        m, _n, _e = _machine()
        assert describe(m.available_edges()) == list(sm.available_transitions)
        node.trigger_configure()
        m.trigger("configure")
        assert (m.state, m.label) == tuple(sm.current_state)
        assert describe(m.available_edges()) == list(sm.available_transitions)
        node.destroy_node()
    finally:
        rclpy.shutdown()


def test_a_request_names_its_transition_by_label_else_by_id():
    assert requested(4, "") == 4 and requested(0, "deactivate") == "deactivate"
    m, _node, _events = _machine()
    assert m.trigger(requested(1, "")) and m.trigger(requested(0, "activate")) and m.label == "active"


def test_a_deferred_transition_waits_in_its_transition_state_and_answers_when_finished():
    """A deactivate that lands the plate: the callback starts the landing (DEFERRED), the landing's end finishes it."""
    m, node, events = _machine()
    m.trigger("configure")
    m.trigger("activate")
    node.answers["on_deactivate"] = DEFERRED
    answers: list[bool] = []
    assert m.request("deactivate", answers.append) is None
    assert (m.label, m.pending, answers) == ("deactivating", 4, [])
    assert m.available() == ()  # nothing else may be requested meanwhile
    assert [e[1] for e in m.available_edges()] == ["transition_success", "transition_failure", "transition_error"]
    with pytest.raises(LifecycleError, match="not valid from state deactivating"):
        m.request("shutdown")
    assert m.finish(CallbackResult.SUCCESS) and m.label == "inactive" and m.pending is None and answers == [True]
    assert [(e.transition_id, e.start, e.goal) for e in events[-2:]] == [(4, 3, 14), (40, 14, 2)]
    with pytest.raises(LifecycleError, match="no transition is under way"):
        m.finish(CallbackResult.SUCCESS)


@pytest.mark.parametrize(("result", "end", "reached"), [(CallbackResult.FAILURE, "active", False),
                                                        (CallbackResult.ERROR, "unconfigured", False)])
def test_a_deferred_transition_that_fails_or_errs(result, end, reached):
    m, node, _ = _machine()
    m.trigger("configure")
    m.trigger("activate")
    node.answers["on_deactivate"] = DEFERRED
    answers: list[bool] = []
    m.request("deactivate", answers.append)
    assert m.finish(result) is reached and m.label == end and answers == [reached]
    assert ("on_error", 3) in node.ran or result != CallbackResult.ERROR


def test_a_deferred_answer_of_on_error_is_an_error():
    m, node, _ = _machine()
    m.trigger("configure")
    node.answers["on_activate"] = CallbackResult.ERROR
    node.answers["on_error"] = DEFERRED
    assert not m.trigger("activate") and m.label == "finalized"


def test_a_fault_while_active_goes_through_deactivating_and_errorprocessing():
    """ros2_control's hardware components: read()/write() answering ERROR -> on_error -> unconfigured."""
    m, node, events = _machine()
    m.trigger("configure")
    m.trigger("activate")
    node.ran.clear()
    assert m.error() and m.label == "unconfigured"
    assert node.ran == [("on_error", 3)]  # on_deactivate is not run: the fault is its result
    assert [(e.transition_id, e.transition_label, e.start, e.goal) for e in events[-3:]] == [
        (4, "deactivate", 3, 14), (42, "transition_error", 14, 15), (60, "transition_success", 15, 1)]


def test_a_fault_during_a_deferred_transition_is_its_result_and_elsewhere_nothing():
    m, node, _ = _machine()
    assert not m.error() and m.label == "unconfigured"  # nothing commanded: nothing to do
    node.answers["on_configure"] = DEFERRED
    answers: list[bool] = []
    m.request("configure", answers.append)
    assert m.error() and m.label == "unconfigured" and answers == [False]
    node.answers["on_configure"] = CallbackResult.SUCCESS
    m.trigger("configure")
    assert not m.error() and m.label == "inactive"


def test_every_listener_hears_every_step():
    m, _node, events = _machine()
    more: list = []
    m.listeners.append(more.append)
    m.trigger("configure")
    assert more == events and len(more) == 2

"""The ROS 2 managed-node (lifecycle) state machine, without middleware.

The machine of design.ros2.org "Managed nodes" as rclcpp_lifecycle / rclpy.lifecycle implement it (rcl_lifecycle's
``default_state_machine.c``), with the ids of ``lifecycle_msgs/msg/State`` and ``lifecycle_msgs/msg/Transition``:

* primary states: unconfigured (1), inactive (2), active (3), finalized (4);
* transition states: configuring (10), cleaningup (11), shuttingdown (12), activating (13),
  deactivating (14), errorprocessing (15);
* a request (``~/change_state``) names a transition by id (1 configure, 2 cleanup, 3 activate, 4 deactivate,
  5-7 shutdown from unconfigured / inactive / active) or by label; it is valid only from its start state
  (:data:`TRANSITIONS`); the machine enters the transition state, runs the node's callback, which answers
  success, failure or error, and the result picks the goal (:data:`RESULTS`): success the transition's goal,
  failure back to the start state, error to errorprocessing, whose own callback leads to unconfigured
  (success) or finalized.

Every step is reported as a ``lifecycle_msgs/msg/TransitionEvent`` (timestamp, transition, start, goal) to the
machine's listeners (a transport publishes them on ``~/transition_event``); a result step carries rcl's labels
(``transition_success``, ``transition_failure``, ``transition_error``), as ``ros2 lifecycle`` shows them for any
rclcpp or rclpy node.

Transitions that take time. rcl runs a transition callback to its end inside the ``~/change_state`` service
callback. A callback here may instead answer :data:`DEFERRED`: its work goes on (a landing: seconds) while the
executor runs, the machine stays in the transition state (``get_state`` says ``deactivating``; no other request
is valid meanwhile), and the node calls :meth:`LifecycleMachine.finish` with the result when the work ends; the
``~/change_state`` caller is answered then (the ``done`` of :meth:`LifecycleMachine.request`). errorprocessing's
callback answers at once. A fault outside any callback (a driver trip: what ros2_control's ``read()`` /
``write()`` report as ``ERROR``) is :meth:`LifecycleMachine.error`.

A transport serves one machine as the standard interface (:meth:`dem_ros.transport.api.Node.serve_lifecycle`):
``~/get_state``, ``~/change_state``, ``~/get_available_states``, ``~/get_available_transitions``,
``~/get_transition_graph`` and ``~/transition_event``, answering from :func:`describe`, :data:`STATES` and
:data:`GRAPH` as rcl's state machine answers rclpy.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from ..contract import QoS, Topic

__all__ = ["DEFERRED", "EVENT_QOS", "GRAPH", "RESULTS", "SERVICES", "STATES", "TRANSITIONS", "CallbackAnswer",
           "CallbackResult", "LifecycleError", "LifecycleInterface", "LifecycleMachine", "TransitionEvent",
           "describe", "event_topic", "requested"]


class LifecycleError(ValueError):
    """A transition that is not valid from the current state, or unknown."""


class CallbackResult(enum.IntEnum):
    """What a transition callback answers (rclcpp_lifecycle's ``CallbackReturn``; ids of ``Transition``)."""

    SUCCESS = 97  # TRANSITION_CALLBACK_SUCCESS
    FAILURE = 98  # TRANSITION_CALLBACK_FAILURE
    ERROR = 99  # TRANSITION_CALLBACK_ERROR


class _Deferred(enum.Enum):
    DEFERRED = "deferred"


#: a callback's answer meaning "under way": the node calls :meth:`LifecycleMachine.finish` when its work ends
DEFERRED = _Deferred.DEFERRED
#: what a transition callback returns
CallbackAnswer = CallbackResult | _Deferred

#: state id -> label (lifecycle_msgs/msg/State)
STATES: Mapping[int, str] = {
    0: "unknown", 1: "unconfigured", 2: "inactive", 3: "active", 4: "finalized",
    10: "configuring", 11: "cleaningup", 12: "shuttingdown", 13: "activating", 14: "deactivating",
    15: "errorprocessing",
}
PRIMARY = (1, 2, 3, 4)
#: ``~/transition_event``'s QoS (rcl_lifecycle's publisher: the default profile, reliable, volatile, depth 10)
EVENT_QOS = QoS(reliable=True, transient_local=False, depth=10)
#: the managed-node services: name under the node -> ROS service type (rcl_lifecycle's)
SERVICES: Mapping[str, str] = {
    "get_state": "lifecycle_msgs/srv/GetState",
    "change_state": "lifecycle_msgs/srv/ChangeState",
    "get_available_states": "lifecycle_msgs/srv/GetAvailableStates",
    "get_available_transitions": "lifecycle_msgs/srv/GetAvailableTransitions",
    "get_transition_graph": "lifecycle_msgs/srv/GetAvailableTransitions",
}


@dataclass(frozen=True)
class _Transition:
    id: int
    label: str
    start: int  # primary state
    via: int  # transition state
    goal: int  # primary state on success


#: the requests a client may make (id, label, start state, transition state, goal state)
TRANSITIONS: tuple[_Transition, ...] = (
    _Transition(1, "configure", 1, 10, 2),
    _Transition(2, "cleanup", 2, 11, 1),
    _Transition(3, "activate", 2, 13, 3),
    _Transition(4, "deactivate", 3, 14, 2),
    _Transition(5, "shutdown", 1, 12, 4),
    _Transition(6, "shutdown", 2, 12, 4),
    _Transition(7, "shutdown", 3, 12, 4),
)

_RESULT_LABEL = {CallbackResult.SUCCESS: "transition_success", CallbackResult.FAILURE: "transition_failure",
                 CallbackResult.ERROR: "transition_error"}
#: (transition state, callback result) -> (transition id, label, goal state) of the result's transition (ids of
#: ``TRANSITION_ON_CONFIGURE_SUCCESS`` ...; labels as rcl_lifecycle's default state machine names them)
RESULTS: Mapping[tuple[int, CallbackResult], tuple[int, str, int]] = {
    (via, r): (tid, _RESULT_LABEL[r], goal)
    for via, ids_goals in {
        10: ((10, 2), (11, 1), (12, 15)),  # configuring
        11: ((20, 1), (21, 2), (22, 15)),  # cleaningup
        13: ((30, 3), (31, 2), (32, 15)),  # activating
        14: ((40, 2), (41, 3), (42, 15)),  # deactivating
        12: ((50, 4), (51, 4), (52, 15)),  # shuttingdown
        15: ((60, 1), (61, 4), (62, 4)),  # errorprocessing
    }.items()
    for r, (tid, goal) in zip(CallbackResult, ids_goals, strict=True)
}

#: the whole graph (``~/get_transition_graph``): (id, label, start state, goal state), in rcl's order: each
#: request (its goal the transition state), then that state's results
GRAPH: tuple[tuple[int, str, int, int], ...] = tuple(
    edge
    for t in TRANSITIONS
    for edge in ((t.id, t.label, t.start, t.via),
                 *(((rid, rlabel, t.via, goal) for (via, _r), (rid, rlabel, goal) in RESULTS.items() if via == t.via)
                   if t.id not in (5, 6) else ()))  # shutdown's results once, after its last request
) + tuple((rid, rlabel, 15, goal) for (via, _r), (rid, rlabel, goal) in RESULTS.items() if via == 15)

#: transition state -> the name of the node's callback it runs
CALLBACKS: Mapping[int, str] = {10: "on_configure", 11: "on_cleanup", 12: "on_shutdown", 13: "on_activate",
                                14: "on_deactivate", 15: "on_error"}


def describe(edges: Iterable[tuple[int, str, int, int]]) -> list[tuple[int, str, int, str, int, str]]:
    """``lifecycle_msgs/msg/TransitionDescription`` fields: (id, label, start id, start label, goal id, goal
    label), as rcl's state machine gives them to rclpy."""
    return [(tid, label, start, STATES[start], goal, STATES[goal]) for tid, label, start, goal in edges]


def requested(transition_id: int, label: str) -> int | str:
    """What a ``ChangeState`` request names: its label when it has one (as rclpy reads it), else its id."""
    return label if label else int(transition_id)


@dataclass(frozen=True)
class TransitionEvent:
    """One step, as ``lifecycle_msgs/msg/TransitionEvent`` carries it (timestamp [ns])."""

    timestamp_ns: int
    transition_id: int
    transition_label: str
    start: int
    goal: int


@dataclass
class _Running:
    """A transition between its request and its result."""

    transition: _Transition
    start: int
    done: Callable[[bool], None] | None


class LifecycleMachine:
    """The managed-node state machine around the node's callbacks.

    ``callbacks``: transition-state name (``on_configure`` ... ``on_error``, :data:`CALLBACKS`) ->
    ``callback(previous_state_id) -> CallbackResult | DEFERRED``; a missing one succeeds, an exception is an
    ERROR, ``on_error`` answers at once (DEFERRED there is an ERROR). ``now_ns``: the node's clock;
    ``on_event(event)``: each step (more listeners: :attr:`listeners`).
    """

    def __init__(self, callbacks: Mapping[str, Callable[[int], CallbackAnswer]], *, now_ns: Callable[[], int],
                 on_event: Callable[[TransitionEvent], None] | None = None):
        unknown = set(callbacks) - set(CALLBACKS.values())
        if unknown:
            raise LifecycleError(f"unknown lifecycle callbacks {sorted(unknown)}; known: {sorted(CALLBACKS.values())}")
        self.callbacks = dict(callbacks)
        self.now_ns = now_ns
        self.listeners: list[Callable[[TransitionEvent], None]] = [on_event] if on_event is not None else []
        self.state = 1  # unconfigured (after create)
        self._running: _Running | None = None

    @property
    def label(self) -> str:
        return STATES[self.state]

    @property
    def pending(self) -> int | None:
        """The id of the requested transition whose callback answered DEFERRED (None: none under way)."""
        return self._running.transition.id if self._running is not None else None

    def available(self) -> tuple[_Transition, ...]:
        """The requests valid from the current state (none while a transition is under way)."""
        return tuple(t for t in TRANSITIONS if t.start == self.state)

    def available_edges(self) -> tuple[tuple[int, str, int, int], ...]:
        """``~/get_available_transitions``: the edges of :data:`GRAPH` leaving the current state (in a
        transition state: its results, as rcl lists them)."""
        return tuple(e for e in GRAPH if e[2] == self.state)

    def _find(self, transition: int | str) -> _Transition:
        for t in self.available():
            if transition in (t.id, t.label):
                return t
        valid = ", ".join(f"{t.id} {t.label}" for t in self.available()) or "none"
        raise LifecycleError(f"transition {transition!r} is not valid from state {self.label} (valid: {valid})")

    def _emit(self, tid: int, label: str, start: int, goal: int) -> None:
        if self.listeners:
            event = TransitionEvent(self.now_ns(), tid, label, start, goal)
            for listener in list(self.listeners):
                listener(event)

    def _run(self, via: int, previous: int) -> CallbackAnswer:
        cb = self.callbacks.get(CALLBACKS[via])
        if cb is None:
            return CallbackResult.SUCCESS
        try:
            answer = cb(previous)
            return answer if answer is DEFERRED else CallbackResult(answer)
        except Exception:
            return CallbackResult.ERROR

    def request(self, transition: int | str, done: Callable[[bool], None] | None = None) -> bool | None:
        """Run one requested transition (``~/change_state``): into its transition state, its callback, and
        (unless the callback answered DEFERRED) its result. True when it reached its goal state, False when
        not, None while it is under way; ``done(reached)`` is called when it ends, now or from :meth:`finish`.

        LifecycleError when it is not valid from the current state (the service answers success = false).
        """
        t = self._find(transition)
        start = self.state
        self._emit(t.id, t.label, start, t.via)
        self.state = t.via
        self._running = _Running(t, start, done)
        answer = self._run(t.via, start)
        if answer is DEFERRED:
            return None
        return self.finish(answer)

    def trigger(self, transition: int | str) -> bool | None:
        """:meth:`request` without a ``done``."""
        return self.request(transition)

    def finish(self, result: CallbackResult) -> bool:
        """The result of the transition under way: to its goal (SUCCESS), back to its start (FAILURE) or
        through errorprocessing (ERROR). True when it reached its goal state.

        LifecycleError when no transition is under way.
        """
        run = self._running
        if run is None:
            raise LifecycleError(f"no transition is under way (state {self.label})")
        t = run.transition
        rid, rlabel, goal = RESULTS[(t.via, CallbackResult(result))]
        self._emit(rid, rlabel, t.via, goal)
        self.state = goal
        if goal == 15:  # errorprocessing: its own callback decides between unconfigured and finalized
            answer = self._run(15, run.start)
            eid, elabel, egoal = RESULTS[(15, answer if answer is not DEFERRED else CallbackResult.ERROR)]
            self._emit(eid, elabel, 15, egoal)
            self.state = egoal
        self._running = None
        reached = self.state == t.goal
        if run.done is not None:
            run.done(reached)
        return reached

    def error(self) -> bool:
        """A fault outside any callback (a hardware trip): through errorprocessing, on the standard graph's edges.

        Active: a deactivate whose result is an error (active -> deactivating -> errorprocessing), its callback
        not run; a transition under way: its result is ERROR (its caller is answered false). False, nothing
        done, in any other state (inactive, unconfigured, finalized: nothing is commanded there).
        """
        if self._running is not None:
            self.finish(CallbackResult.ERROR)
            return True
        if self.state != 3:
            return False
        t = self._find("deactivate")
        self._emit(t.id, t.label, self.state, t.via)
        self._running = _Running(t, self.state, None)
        self.state = t.via
        self.finish(CallbackResult.ERROR)
        return True


def event_topic(node_fqn: str) -> Topic:
    """``<node>/transition_event`` (``~/transition_event``) of the node ``node_fqn`` (``/ns/name``)."""
    return Topic(node_fqn.rstrip("/") + "/transition_event", "lifecycle_msgs/msg/TransitionEvent", EVENT_QOS, None,
                 "a managed node (hw_driver)", ("ros2 lifecycle echo",), "each step of the node's state machine")


class LifecycleInterface:
    """The answers of the managed-node services for one machine, built with a transport's lifecycle_msgs classes
    (the IDL ones of :mod:`dem_ros.transport.dds.lifecycle_msgs`, or rclpy's rosidl ones): a transport registers
    each method as the service of the same name (:data:`SERVICES`) and publishes :meth:`event` of each step.

    ``log(text)``: where a refused request is said (the node's logger, WARN).
    """

    def __init__(self, machine: LifecycleMachine, *, State: Any, Transition: Any, TransitionDescription: Any,
                 TransitionEvent: Any, log: Callable[[str], None]):
        self.machine = machine
        self.State, self.Transition, self.Description, self.Event = State, Transition, TransitionDescription, \
            TransitionEvent
        self.log = log

    def _descriptions(self, edges: Iterable[tuple[int, str, int, int]]) -> list[Any]:
        return [self.Description(transition=self.Transition(id=tid, label=label),
                                 start_state=self.State(id=start, label=slabel),
                                 goal_state=self.State(id=goal, label=glabel))
                for tid, label, start, slabel, goal, glabel in describe(edges)]

    def get_state(self, req: Any, rep: Any) -> Any:
        rep.current_state = self.State(id=self.machine.state, label=self.machine.label)
        return rep

    def get_available_states(self, req: Any, rep: Any) -> Any:
        rep.available_states = [self.State(id=sid, label=label) for sid, label in STATES.items()]
        return rep

    def get_available_transitions(self, req: Any, rep: Any) -> Any:
        rep.available_transitions = self._descriptions(self.machine.available_edges())
        return rep

    def get_transition_graph(self, req: Any, rep: Any) -> Any:
        rep.available_transitions = self._descriptions(GRAPH)
        return rep

    def change_state(self, req: Any, rep: Any, send: Callable[[], None]) -> None:
        """Request the transition; ``send()`` the response (``success``: the goal reached) when it ends: at once,
        or when the node finishes a DEFERRED one. A request not valid now is answered false at once."""

        def done(reached: bool) -> None:
            rep.success = reached
            send()

        try:
            self.machine.request(requested(req.transition.id, req.transition.label), done)
        except LifecycleError as exc:
            self.log(f"change_state refused: {exc}")
            rep.success = False
            send()

    def event(self, e: TransitionEvent) -> Any:
        """The ``lifecycle_msgs/msg/TransitionEvent`` of one step."""
        return self.Event(timestamp=e.timestamp_ns, transition=self.Transition(id=e.transition_id,
                                                                               label=e.transition_label),
                          start_state=self.State(id=e.start, label=STATES[e.start]),
                          goal_state=self.State(id=e.goal, label=STATES[e.goal]))

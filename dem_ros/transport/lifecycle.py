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

Every step is reported as a ``lifecycle_msgs/msg/TransitionEvent`` (timestamp, transition, start, goal) to
``on_event`` (the node publishes them on ``~/transition_event``).

How a transport serves it (the plan for hw_driver on dds; rclpy has ``rclpy.lifecycle.Node``): the node
keeps one :class:`LifecycleMachine` and serves ``~/get_state`` (``GetState``: the current state),
``~/get_available_states`` (every state of :data:`STATES`), ``~/get_available_transitions`` (the
requests valid now: :meth:`LifecycleMachine.available`), ``~/get_transition_graph`` (all of
:data:`TRANSITIONS`) and ``~/change_state`` (``ChangeState``: :meth:`LifecycleMachine.trigger`), with the
IDL types of :mod:`dem_ros.transport.dds.lifecycle_msgs`; the callbacks are the driver's (configure: open
the link and handshake; activate: arm; deactivate: land, succeeding once the board reports LANDED; cleanup:
close the link; errorprocessing: land).

Open point for that wiring: :meth:`LifecycleMachine.trigger` runs the callback synchronously, as rcl does,
but a deactivate that succeeds only once the board reports LANDED waits for a landing (seconds); it
must not hold the executor (the driver's samples and the loop's topics run there). The node would
answer ``~/change_state`` later (the dds node already queues service replies) from a machine split into
``begin(transition)`` (into the transition state) and ``finish(result)`` (to the goal), the landing's
end calling ``finish``.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Mapping
from dataclasses import dataclass

__all__ = ["RESULTS", "STATES", "TRANSITIONS", "CallbackResult", "LifecycleError", "LifecycleMachine",
           "TransitionEvent"]


class LifecycleError(ValueError):
    """A transition that is not valid from the current state, or unknown."""


class CallbackResult(enum.IntEnum):
    """What a transition callback answers (rclcpp_lifecycle's ``CallbackReturn``; ids of ``Transition``)."""

    SUCCESS = 97  # TRANSITION_CALLBACK_SUCCESS
    FAILURE = 98  # TRANSITION_CALLBACK_FAILURE
    ERROR = 99  # TRANSITION_CALLBACK_ERROR


#: state id -> label (lifecycle_msgs/msg/State)
STATES: Mapping[int, str] = {
    0: "unknown", 1: "unconfigured", 2: "inactive", 3: "active", 4: "finalized",
    10: "configuring", 11: "cleaningup", 12: "shuttingdown", 13: "activating", 14: "deactivating",
    15: "errorprocessing",
}
PRIMARY = (1, 2, 3, 4)


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

#: (transition state, callback result) -> (transition id, label, goal state) of the result's transition (ids and
#: labels as rcl_lifecycle's default state machine names them: ``TRANSITION_ON_CONFIGURE_SUCCESS`` is
#: ``configure_success``)
RESULTS: Mapping[tuple[int, CallbackResult], tuple[int, str, int]] = {
    (10, CallbackResult.SUCCESS): (10, "configure_success", 2),
    (10, CallbackResult.FAILURE): (11, "configure_failure", 1),
    (10, CallbackResult.ERROR): (12, "configure_error", 15),
    (11, CallbackResult.SUCCESS): (20, "cleanup_success", 1),
    (11, CallbackResult.FAILURE): (21, "cleanup_failure", 2),
    (11, CallbackResult.ERROR): (22, "cleanup_error", 15),
    (13, CallbackResult.SUCCESS): (30, "activate_success", 3),
    (13, CallbackResult.FAILURE): (31, "activate_failure", 2),
    (13, CallbackResult.ERROR): (32, "activate_error", 15),
    (14, CallbackResult.SUCCESS): (40, "deactivate_success", 2),
    (14, CallbackResult.FAILURE): (41, "deactivate_failure", 3),
    (14, CallbackResult.ERROR): (42, "deactivate_error", 15),
    (12, CallbackResult.SUCCESS): (50, "shutdown_success", 4),
    (12, CallbackResult.FAILURE): (51, "shutdown_failure", 4),
    (12, CallbackResult.ERROR): (52, "shutdown_error", 15),
    (15, CallbackResult.SUCCESS): (60, "errorprocessing_success", 1),
    (15, CallbackResult.FAILURE): (61, "errorprocessing_failure", 4),
    (15, CallbackResult.ERROR): (62, "errorprocessing_error", 4),
}

#: transition state -> the name of the node's callback it runs
CALLBACKS: Mapping[int, str] = {10: "on_configure", 11: "on_cleanup", 12: "on_shutdown", 13: "on_activate",
                                14: "on_deactivate", 15: "on_error"}


@dataclass(frozen=True)
class TransitionEvent:
    """One step, as ``lifecycle_msgs/msg/TransitionEvent`` carries it (timestamp [ns])."""

    timestamp_ns: int
    transition_id: int
    transition_label: str
    start: int
    goal: int


class LifecycleMachine:
    """The managed-node state machine around the node's callbacks.

    ``callbacks``: transition-state name (``on_configure`` ... ``on_error``, :data:`CALLBACKS`) ->
    ``callback(previous_state_id) -> CallbackResult``; a missing one succeeds, an exception is an ERROR.
    ``now_ns``: the node's clock; ``on_event(event)``: each step.
    """

    def __init__(self, callbacks: Mapping[str, Callable[[int], CallbackResult]], *, now_ns: Callable[[], int],
                 on_event: Callable[[TransitionEvent], None] | None = None):
        unknown = set(callbacks) - set(CALLBACKS.values())
        if unknown:
            raise LifecycleError(f"unknown lifecycle callbacks {sorted(unknown)}; known: {sorted(CALLBACKS.values())}")
        self.callbacks = dict(callbacks)
        self.now_ns = now_ns
        self.on_event = on_event
        self.state = 1  # unconfigured (after create)

    @property
    def label(self) -> str:
        return STATES[self.state]

    def available(self) -> tuple[_Transition, ...]:
        """The requests valid from the current state (``~/get_available_transitions``)."""
        return tuple(t for t in TRANSITIONS if t.start == self.state)

    def _find(self, transition: int | str) -> _Transition:
        for t in self.available():
            if transition in (t.id, t.label):
                return t
        valid = ", ".join(f"{t.id} {t.label}" for t in self.available()) or "none"
        raise LifecycleError(f"transition {transition!r} is not valid from state {self.label} (valid: {valid})")

    def _emit(self, tid: int, label: str, start: int, goal: int) -> None:
        if self.on_event is not None:
            self.on_event(TransitionEvent(self.now_ns(), tid, label, start, goal))

    def _run(self, via: int, previous: int) -> CallbackResult:
        cb = self.callbacks.get(CALLBACKS[via])
        if cb is None:
            return CallbackResult.SUCCESS
        try:
            return CallbackResult(cb(previous))
        except Exception:
            return CallbackResult.ERROR

    def trigger(self, transition: int | str) -> bool:
        """Run one requested transition (``~/change_state``); True when it reached its goal state.

        LifecycleError when it is not valid from the current state (the service answers success = false).
        """
        t = self._find(transition)
        start = self.state
        self._emit(t.id, t.label, start, t.via)
        self.state = t.via
        result = self._run(t.via, start)
        rid, rlabel, goal = RESULTS[(t.via, result)]
        self._emit(rid, rlabel, t.via, goal)
        self.state = goal
        if goal == 15:  # errorprocessing: its own callback decides between unconfigured and finalized
            eid, elabel, egoal = RESULTS[(15, self._run(15, start))]
            self._emit(eid, elabel, 15, egoal)
            self.state = egoal
        return self.state == t.goal

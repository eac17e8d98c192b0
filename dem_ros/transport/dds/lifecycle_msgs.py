"""lifecycle_msgs as Cyclone DDS IDL structs: the managed-node interface on the dds transport.

Same rules as :mod:`.msgs` (final structs, real annotations: no ``from __future__ import annotations``), whose
table lists these messages too; service requests and replies carry rmw_cyclonedds' (guid, seq) header in front
of the ROS fields.

The services of a managed node ``/ns/node`` (what ``ros2 lifecycle`` calls):

=================================  ==========================================  ==============================
service                            type                                        request -> response
=================================  ==========================================  ==============================
``~/get_state``                    ``lifecycle_msgs/srv/GetState``             () -> State current_state
``~/change_state``                 ``lifecycle_msgs/srv/ChangeState``          Transition -> bool success
``~/get_available_states``         ``lifecycle_msgs/srv/GetAvailableStates``   () -> State[]
``~/get_available_transitions``    ``lifecycle_msgs/srv/GetAvailableTransitions``  () -> TransitionDescription[]
``~/get_transition_graph``         ``lifecycle_msgs/srv/GetAvailableTransitions``  () -> TransitionDescription[]
=================================  ==========================================  ==============================

and the topic ``~/transition_event`` (``lifecycle_msgs/msg/TransitionEvent``, reliable, volatile).
:data:`SERVICE_CLASSES` is merged into :data:`.srvs.SERVICE_CLASSES` (the dds node serves them, the dds client calls
them); the state machine and the answers: :mod:`dem_ros.transport.lifecycle`.
"""

from dataclasses import dataclass, field
from typing import Any

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import int64, sequence, uint8, uint64

from .. import lifecycle
from .fastcdr import strict

__all__ = ["MESSAGES", "SERVICES", "SERVICE_CLASSES"]


@strict
@dataclass
class State(IdlStruct, typename="lifecycle_msgs::msg::dds_::State_"):
    id: uint8 = 0
    label: str = ""


@strict
@dataclass
class Transition(IdlStruct, typename="lifecycle_msgs::msg::dds_::Transition_"):
    id: uint8 = 0
    label: str = ""


@strict
@dataclass
class TransitionDescription(IdlStruct, typename="lifecycle_msgs::msg::dds_::TransitionDescription_"):
    transition: Transition = field(default_factory=Transition)
    start_state: State = field(default_factory=State)
    goal_state: State = field(default_factory=State)


@strict
@dataclass
class TransitionEvent(IdlStruct, typename="lifecycle_msgs::msg::dds_::TransitionEvent_"):
    timestamp: uint64 = 0
    transition: Transition = field(default_factory=Transition)
    start_state: State = field(default_factory=State)
    goal_state: State = field(default_factory=State)


@strict
@dataclass
class GetState_Request(IdlStruct, typename="lifecycle_msgs::srv::dds_::GetState_Request_"):
    guid: uint64 = 0
    seq: int64 = 0
    structure_needs_at_least_one_member: uint8 = 0  # an empty ROS request


@strict
@dataclass
class GetState_Response(IdlStruct, typename="lifecycle_msgs::srv::dds_::GetState_Response_"):
    guid: uint64 = 0
    seq: int64 = 0
    current_state: State = field(default_factory=State)


@strict
@dataclass
class ChangeState_Request(IdlStruct, typename="lifecycle_msgs::srv::dds_::ChangeState_Request_"):
    guid: uint64 = 0
    seq: int64 = 0
    transition: Transition = field(default_factory=Transition)


@strict
@dataclass
class ChangeState_Response(IdlStruct, typename="lifecycle_msgs::srv::dds_::ChangeState_Response_"):
    guid: uint64 = 0
    seq: int64 = 0
    success: bool = False


@strict
@dataclass
class GetAvailableStates_Request(IdlStruct, typename="lifecycle_msgs::srv::dds_::GetAvailableStates_Request_"):
    guid: uint64 = 0
    seq: int64 = 0
    structure_needs_at_least_one_member: uint8 = 0


@strict
@dataclass
class GetAvailableStates_Response(IdlStruct, typename="lifecycle_msgs::srv::dds_::GetAvailableStates_Response_"):
    guid: uint64 = 0
    seq: int64 = 0
    available_states: sequence[State] = field(default_factory=list)


@strict
@dataclass
class GetAvailableTransitions_Request(IdlStruct,
                                      typename="lifecycle_msgs::srv::dds_::GetAvailableTransitions_Request_"):
    guid: uint64 = 0
    seq: int64 = 0
    structure_needs_at_least_one_member: uint8 = 0


@strict
@dataclass
class GetAvailableTransitions_Response(IdlStruct,
                                       typename="lifecycle_msgs::srv::dds_::GetAvailableTransitions_Response_"):
    guid: uint64 = 0
    seq: int64 = 0
    available_transitions: sequence[TransitionDescription] = field(default_factory=list)


#: ROS type -> IDL class (the messages)
MESSAGES: dict[str, type[Any]] = {
    "lifecycle_msgs/msg/State": State,
    "lifecycle_msgs/msg/Transition": Transition,
    "lifecycle_msgs/msg/TransitionDescription": TransitionDescription,
    "lifecycle_msgs/msg/TransitionEvent": TransitionEvent,
}

#: service name suffix -> ROS service type
SERVICES: dict[str, str] = dict(lifecycle.SERVICES)

#: ROS service type -> (request class, response class)
SERVICE_CLASSES: dict[str, tuple[type[Any], type[Any]]] = {
    "lifecycle_msgs/srv/GetState": (GetState_Request, GetState_Response),
    "lifecycle_msgs/srv/ChangeState": (ChangeState_Request, ChangeState_Response),
    "lifecycle_msgs/srv/GetAvailableStates": (GetAvailableStates_Request, GetAvailableStates_Response),
    "lifecycle_msgs/srv/GetAvailableTransitions": (GetAvailableTransitions_Request,
                                                   GetAvailableTransitions_Response),
}

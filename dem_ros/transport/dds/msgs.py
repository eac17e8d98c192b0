"""ROS 2 message and service types as Cyclone DDS IDL structs (no ROS needed).

Each class carries the DDS type name rmw_cyclonedds uses for the ROS type
(``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_``) and the same field names and
field order as the ROS definition, so the plain-CDR (XCDR1) bytes are the ones
a ROS 2 node sends and rosbag2 stores.

Rules for this module (do not break them):
    * The structs are *final* (the IdlStruct default): ``@appendable`` would
      switch to XCDR2 and stop matching ROS endpoints.
    * No ``from __future__ import annotations`` here: cyclonedds-python needs
      the real annotation objects (cyclonedds-python#305).
    * ``byte`` fields (``DiagnosticStatus.level``) are ints here and ``bytes``
      in rclpy; node code should use the class constants (``DiagnosticStatus.OK``).

Service requests and replies carry rmw_cyclonedds' request header in front of
the ROS fields (``cdds_request_header_t`` in rmw_cyclonedds_cpp/src/serdata.hpp):
``uint64 guid`` (the client's request-writer instance handle, used by the
client to pick its replies) and ``int64 seq`` (the request's sequence number).
"""

from dataclasses import dataclass, field
from typing import Any

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, bounded_str, float64, int32, int64, sequence, uint8, uint32, uint64

from . import lifecycle_msgs
from .fastcdr import strict as strict  # (the decorator every IDL class of the transport carries)

__all__ = [
    "MESSAGES",
    "SERVICES",
    "dds_type_name",
    "gid_types",
    "message_class",
    "strict",
]


def dds_type_name(ros_type: str) -> str:
    """``sensor_msgs/msg/JointState`` -> ``sensor_msgs::msg::dds_::JointState_``."""
    pkg, kind, name = ros_type.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


# --------------------------------------------------------------------------- std / builtin
@strict
@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@strict
@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@strict
@dataclass
class String(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str = ""


@strict
@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header = field(default_factory=Header)
    name: sequence[str] = field(default_factory=list)
    position: sequence[float64] = field(default_factory=list)
    velocity: sequence[float64] = field(default_factory=list)
    effort: sequence[float64] = field(default_factory=list)


# --------------------------------------------------------------------------- diagnostics
@strict
@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str = ""
    value: str = ""


@strict
@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: uint8 = 0
    name: str = ""
    message: str = ""
    hardware_id: str = ""
    values: sequence[KeyValue] = field(default_factory=list)


DiagnosticStatus.OK = 0
DiagnosticStatus.WARN = 1
DiagnosticStatus.ERROR = 2
DiagnosticStatus.STALE = 3


@strict
@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header = field(default_factory=Header)
    status: sequence[DiagnosticStatus] = field(default_factory=list)


# --------------------------------------------------------------------------- rcl_interfaces
@strict
@dataclass
class ParameterValue(IdlStruct, typename="rcl_interfaces::msg::dds_::ParameterValue_"):
    type: uint8 = 0
    bool_value: bool = False
    integer_value: int64 = 0
    double_value: float64 = 0.0
    string_value: str = ""
    byte_array_value: sequence[uint8] = field(default_factory=list)
    bool_array_value: sequence[bool] = field(default_factory=list)
    integer_array_value: sequence[int64] = field(default_factory=list)
    double_array_value: sequence[float64] = field(default_factory=list)
    string_array_value: sequence[str] = field(default_factory=list)


@strict
@dataclass
class Parameter(IdlStruct, typename="rcl_interfaces::msg::dds_::Parameter_"):
    name: str = ""
    value: ParameterValue = field(default_factory=ParameterValue)


@strict
@dataclass
class ParameterEvent(IdlStruct, typename="rcl_interfaces::msg::dds_::ParameterEvent_"):
    stamp: Time = field(default_factory=Time)
    node: str = ""
    new_parameters: sequence[Parameter] = field(default_factory=list)
    changed_parameters: sequence[Parameter] = field(default_factory=list)
    deleted_parameters: sequence[Parameter] = field(default_factory=list)


@strict
@dataclass
class FloatingPointRange(IdlStruct, typename="rcl_interfaces::msg::dds_::FloatingPointRange_"):
    from_value: float64 = 0.0
    to_value: float64 = 0.0
    step: float64 = 0.0


@strict
@dataclass
class IntegerRange(IdlStruct, typename="rcl_interfaces::msg::dds_::IntegerRange_"):
    from_value: int64 = 0
    to_value: int64 = 0
    step: uint64 = 0


@strict
@dataclass
class ParameterDescriptor(IdlStruct, typename="rcl_interfaces::msg::dds_::ParameterDescriptor_"):
    name: str = ""
    type: uint8 = 0
    description: str = ""
    additional_constraints: str = ""
    read_only: bool = False
    dynamic_typing: bool = False
    floating_point_range: sequence[FloatingPointRange, 1] = field(default_factory=list)
    integer_range: sequence[IntegerRange, 1] = field(default_factory=list)


@strict
@dataclass
class SetParametersResult(IdlStruct, typename="rcl_interfaces::msg::dds_::SetParametersResult_"):
    successful: bool = False
    reason: str = ""


@strict
@dataclass
class ListParametersResult(IdlStruct, typename="rcl_interfaces::msg::dds_::ListParametersResult_"):
    names: sequence[str] = field(default_factory=list)
    prefixes: sequence[str] = field(default_factory=list)


@strict
@dataclass
class Log(IdlStruct, typename="rcl_interfaces::msg::dds_::Log_"):
    stamp: Time = field(default_factory=Time)
    level: uint8 = 0
    name: str = ""
    msg: str = ""
    file: str = ""
    function: str = ""
    line: uint32 = 0


# --------------------------------------------------------------------------- parameter services
# Every request/reply starts with rmw_cyclonedds' header (guid, seq).
@strict
@dataclass
class GetParameters_Request(IdlStruct, typename="rcl_interfaces::srv::dds_::GetParameters_Request_"):
    guid: uint64 = 0
    seq: int64 = 0
    names: sequence[str] = field(default_factory=list)


@strict
@dataclass
class GetParameters_Response(IdlStruct, typename="rcl_interfaces::srv::dds_::GetParameters_Response_"):
    guid: uint64 = 0
    seq: int64 = 0
    values: sequence[ParameterValue] = field(default_factory=list)


@strict
@dataclass
class SetParameters_Request(IdlStruct, typename="rcl_interfaces::srv::dds_::SetParameters_Request_"):
    guid: uint64 = 0
    seq: int64 = 0
    parameters: sequence[Parameter] = field(default_factory=list)


@strict
@dataclass
class SetParameters_Response(IdlStruct, typename="rcl_interfaces::srv::dds_::SetParameters_Response_"):
    guid: uint64 = 0
    seq: int64 = 0
    results: sequence[SetParametersResult] = field(default_factory=list)


@strict
@dataclass
class SetParametersAtomically_Request(IdlStruct, typename="rcl_interfaces::srv::dds_::SetParametersAtomically_Request_"
):
    guid: uint64 = 0
    seq: int64 = 0
    parameters: sequence[Parameter] = field(default_factory=list)


@strict
@dataclass
class SetParametersAtomically_Response(
    IdlStruct, typename="rcl_interfaces::srv::dds_::SetParametersAtomically_Response_"
):
    guid: uint64 = 0
    seq: int64 = 0
    result: SetParametersResult = field(default_factory=SetParametersResult)


@strict
@dataclass
class ListParameters_Request(IdlStruct, typename="rcl_interfaces::srv::dds_::ListParameters_Request_"):
    guid: uint64 = 0
    seq: int64 = 0
    prefixes: sequence[str] = field(default_factory=list)
    depth: uint64 = 0


@strict
@dataclass
class ListParameters_Response(IdlStruct, typename="rcl_interfaces::srv::dds_::ListParameters_Response_"):
    guid: uint64 = 0
    seq: int64 = 0
    result: ListParametersResult = field(default_factory=ListParametersResult)


@strict
@dataclass
class DescribeParameters_Request(IdlStruct, typename="rcl_interfaces::srv::dds_::DescribeParameters_Request_"):
    guid: uint64 = 0
    seq: int64 = 0
    names: sequence[str] = field(default_factory=list)


@strict
@dataclass
class DescribeParameters_Response(IdlStruct, typename="rcl_interfaces::srv::dds_::DescribeParameters_Response_"):
    guid: uint64 = 0
    seq: int64 = 0
    descriptors: sequence[ParameterDescriptor] = field(default_factory=list)


@strict
@dataclass
class GetParameterTypes_Request(IdlStruct, typename="rcl_interfaces::srv::dds_::GetParameterTypes_Request_"):
    guid: uint64 = 0
    seq: int64 = 0
    names: sequence[str] = field(default_factory=list)


@strict
@dataclass
class GetParameterTypes_Response(IdlStruct, typename="rcl_interfaces::srv::dds_::GetParameterTypes_Response_"):
    guid: uint64 = 0
    seq: int64 = 0
    types: sequence[uint8] = field(default_factory=list)


# --------------------------------------------------------------------------- rmw_dds_common
# The Gid is 24 bytes on Humble and 16 from Iron on, under the same type name:
# build one set per size, pick with gid_types(size).
def _make_gid_types(size: int) -> dict[str, type[Any]]:
    @strict
    @dataclass
    class Gid(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
        data: array[uint8, size] = field(default_factory=lambda: [0] * size)

    @strict
    @dataclass
    class NodeEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
        node_namespace: bounded_str[256] = ""  # string<=256 in rmw_dds_common
        node_name: bounded_str[256] = ""
        reader_gid_seq: sequence[Gid] = field(default_factory=list)
        writer_gid_seq: sequence[Gid] = field(default_factory=list)

    @strict
    @dataclass
    class ParticipantEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"):
        gid: Gid = field(default_factory=Gid)
        node_entities_info_seq: sequence[NodeEntitiesInfo] = field(default_factory=list)

    return {
        "Gid": Gid,
        "NodeEntitiesInfo": NodeEntitiesInfo,
        "ParticipantEntitiesInfo": ParticipantEntitiesInfo,
    }


_GID_TYPES: dict[int, dict[str, type[Any]]] = {}


def gid_types(size: int) -> dict[str, type[Any]]:
    """The rmw_dds_common Gid / NodeEntitiesInfo / ParticipantEntitiesInfo classes for a GID size (16 or 24)."""
    if size not in (16, 24):
        raise ValueError(f"GID size must be 16 (Iron and later) or 24 (Humble), got {size}")
    if size not in _GID_TYPES:
        _GID_TYPES[size] = _make_gid_types(size)
    return _GID_TYPES[size]


MESSAGES: dict[str, type[Any]] = {
    "builtin_interfaces/msg/Time": Time,
    "std_msgs/msg/Header": Header,
    "std_msgs/msg/String": String,
    "sensor_msgs/msg/JointState": JointState,
    "diagnostic_msgs/msg/KeyValue": KeyValue,
    "diagnostic_msgs/msg/DiagnosticStatus": DiagnosticStatus,
    "diagnostic_msgs/msg/DiagnosticArray": DiagnosticArray,
    "rcl_interfaces/msg/ParameterValue": ParameterValue,
    "rcl_interfaces/msg/Parameter": Parameter,
    "rcl_interfaces/msg/ParameterEvent": ParameterEvent,
    "rcl_interfaces/msg/FloatingPointRange": FloatingPointRange,
    "rcl_interfaces/msg/IntegerRange": IntegerRange,
    "rcl_interfaces/msg/ParameterDescriptor": ParameterDescriptor,
    "rcl_interfaces/msg/SetParametersResult": SetParametersResult,
    "rcl_interfaces/msg/ListParametersResult": ListParametersResult,
    "rcl_interfaces/msg/Log": Log,
    **lifecycle_msgs.MESSAGES,  # the managed-node interface (hw_driver)
}

#: service name suffix -> (ROS service type, request class, response class)
SERVICES: dict[str, tuple[str, type[Any], type[Any]]] = {
    "get_parameters": ("rcl_interfaces/srv/GetParameters", GetParameters_Request, GetParameters_Response),
    "set_parameters": ("rcl_interfaces/srv/SetParameters", SetParameters_Request, SetParameters_Response),
    "set_parameters_atomically": (
        "rcl_interfaces/srv/SetParametersAtomically",
        SetParametersAtomically_Request,
        SetParametersAtomically_Response,
    ),
    "list_parameters": ("rcl_interfaces/srv/ListParameters", ListParameters_Request, ListParameters_Response),
    "describe_parameters": (
        "rcl_interfaces/srv/DescribeParameters",
        DescribeParameters_Request,
        DescribeParameters_Response,
    ),
    "get_parameter_types": (
        "rcl_interfaces/srv/GetParameterTypes",
        GetParameterTypes_Request,
        GetParameterTypes_Response,
    ),
}


def message_class(ros_type: str) -> type[Any]:
    """The IDL class for a ROS type name such as ``sensor_msgs/msg/JointState``."""
    try:
        return MESSAGES[ros_type]
    except KeyError:
        raise KeyError(
            f"message type {ros_type!r} is not available in the DDS transport; known: {', '.join(sorted(MESSAGES))}"
        ) from None

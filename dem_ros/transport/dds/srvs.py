"""std_srvs service types as Cyclone DDS IDL structs, and the one table of every service type.

Same rules as :mod:`.msgs` (final structs, real annotations: no
``from __future__ import annotations``); requests and replies carry
rmw_cyclonedds' (guid, seq) header in front of the ROS fields.
"""

from dataclasses import dataclass
from typing import Any

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import int64, uint8, uint64

from . import lifecycle_msgs, msgs

__all__ = ["SERVICE_CLASSES", "service_classes"]


@msgs.strict
@dataclass
class Trigger_Request(IdlStruct, typename="std_srvs::srv::dds_::Trigger_Request_"):
    guid: uint64 = 0
    seq: int64 = 0
    # an empty ROS request is one uint8 (structure_needs_at_least_one_member)
    structure_needs_at_least_one_member: uint8 = 0


@msgs.strict
@dataclass
class Trigger_Response(IdlStruct, typename="std_srvs::srv::dds_::Trigger_Response_"):
    guid: uint64 = 0
    seq: int64 = 0
    success: bool = False
    message: str = ""


@msgs.strict
@dataclass
class SetBool_Request(IdlStruct, typename="std_srvs::srv::dds_::SetBool_Request_"):
    guid: uint64 = 0
    seq: int64 = 0
    data: bool = False


@msgs.strict
@dataclass
class SetBool_Response(IdlStruct, typename="std_srvs::srv::dds_::SetBool_Response_"):
    guid: uint64 = 0
    seq: int64 = 0
    success: bool = False
    message: str = ""


#: ROS service type -> (request class, response class): std_srvs here, rcl_interfaces from :mod:`.msgs`,
#: lifecycle_msgs from :mod:`.lifecycle_msgs`
SERVICE_CLASSES: dict[str, tuple[type[Any], type[Any]]] = {
    "std_srvs/srv/Trigger": (Trigger_Request, Trigger_Response),
    "std_srvs/srv/SetBool": (SetBool_Request, SetBool_Response),
    **{srv_type: (req, rep) for srv_type, req, rep in msgs.SERVICES.values()},
    **lifecycle_msgs.SERVICE_CLASSES,
}


def service_classes(srv_type: str) -> tuple[type[Any], type[Any]]:
    """(request class, response class) of a ROS service type such as ``std_srvs/srv/Trigger``."""
    try:
        return SERVICE_CLASSES[srv_type]
    except KeyError:
        raise KeyError(f"service type {srv_type!r} is not available in the DDS transport;"
                       f" known: {', '.join(sorted(SERVICE_CLASSES))}") from None

"""The one rosbags typestore: ROS 2 message definitions without a ROS install.

rosbags ships the message definitions of each ROS 2 distribution; dem_ros uses
Jazzy's for everything that needs a definition rather than bytes:

* RIHS01 type-description hashes, on DDS endpoints (:mod:`.transport.dds.wire`,
  USER_DATA ``typehash=``) and in bags (``type_description_hash``);
* ``ros2msg`` schema text in bags (:func:`msgdef`);
* decoding bag messages (:mod:`.bag.reader`), with the types a bag defines in its
  own schemas added (:func:`extended`).

The hand-written codecs (:mod:`.transport.dds.fastcdr`) do not use it: they are
checked against it (tests/transport/test_msgs.py).

The request/response messages of the parameter services are added under
rosidl's names (``rcl_interfaces/srv/GetParameters_Request``): rmw_cyclonedds
puts their hashes on the service endpoints. So are ``std_srvs/srv/Trigger``'s
(the live view serves hw_driver's Trigger services with their schemas) and lifecycle_msgs' (hw_driver's
managed-node services).
"""

from __future__ import annotations

import functools
from collections.abc import Iterable
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # rosbags is imported on first use: a node that never needs a definition never loads it
    from rosbags.typesys.store import Typestore

__all__ = ["SCHEMA_SEPARATOR", "extended", "known", "msgdef", "rihs01", "typestore"]

#: the line between a ``ros2msg`` schema and each dependency section (then ``MSG: pkg/Type``)
SCHEMA_SEPARATOR = "=" * 80 + "\n"

_SRV_DEFS = {
    "rcl_interfaces/srv/GetParameters_Request": "string[] names",
    "rcl_interfaces/srv/GetParameters_Response": "rcl_interfaces/ParameterValue[] values",
    "rcl_interfaces/srv/SetParameters_Request": "rcl_interfaces/Parameter[] parameters",
    "rcl_interfaces/srv/SetParameters_Response": "rcl_interfaces/SetParametersResult[] results",
    "rcl_interfaces/srv/SetParametersAtomically_Request": "rcl_interfaces/Parameter[] parameters",
    "rcl_interfaces/srv/SetParametersAtomically_Response": "rcl_interfaces/SetParametersResult result",
    "rcl_interfaces/srv/ListParameters_Request": "string[] prefixes\nuint64 depth",
    "rcl_interfaces/srv/ListParameters_Response": "rcl_interfaces/ListParametersResult result",
    "rcl_interfaces/srv/DescribeParameters_Request": "string[] names",
    "rcl_interfaces/srv/DescribeParameters_Response": "rcl_interfaces/ParameterDescriptor[] descriptors",
    "rcl_interfaces/srv/GetParameterTypes_Request": "string[] names",
    "rcl_interfaces/srv/GetParameterTypes_Response": "uint8[] types",
    # std_srvs/srv/Trigger (hw_driver's arm | disarm | estop | status), served to Foxglove by dem_ros.view
    "std_srvs/srv/Trigger_Request": "",
    "std_srvs/srv/Trigger_Response": "bool success\nstring message",
    # lifecycle_msgs (hw_driver's managed-node services, dem_ros.transport.lifecycle)
    "lifecycle_msgs/srv/GetState_Request": "",
    "lifecycle_msgs/srv/GetState_Response": "lifecycle_msgs/State current_state",
    "lifecycle_msgs/srv/ChangeState_Request": "lifecycle_msgs/Transition transition",
    "lifecycle_msgs/srv/ChangeState_Response": "bool success",
    "lifecycle_msgs/srv/GetAvailableStates_Request": "",
    "lifecycle_msgs/srv/GetAvailableStates_Response": "lifecycle_msgs/State[] available_states",
    "lifecycle_msgs/srv/GetAvailableTransitions_Request": "",
    "lifecycle_msgs/srv/GetAvailableTransitions_Response":
        "lifecycle_msgs/TransitionDescription[] available_transitions",
}


def _build() -> Typestore:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for name, text in _SRV_DEFS.items():
        # rosbags would file "pkg/srv/X" under "pkg/srv/msg/X"; keep rosidl's name, it is hashed
        types[name] = list(get_types_from_msg(text, name).values())[-1]
    store.register(types)
    return store


@functools.cache
def typestore() -> Typestore:
    """The shared store (Jazzy definitions and the parameter services' messages). Do not register into it:
    use :func:`extended` for a store with more types."""
    return _build()


def known(ros_type: str) -> bool:
    """Whether ``ros_type`` (``pkg/msg/Name``) is defined in :func:`typestore`."""
    return ros_type in typestore().fielddefs


@functools.cache
def rihs01(ros_type: str) -> str:
    """``RIHS01_<hex>``: rosidl's type-description hash of ``ros_type``. KeyError if it is unknown."""
    if not known(ros_type):
        raise KeyError(ros_type)
    return str(typestore().hash_rihs01(ros_type))


@functools.cache
def msgdef(ros_type: str) -> str:
    """``ros2msg`` schema text of ``ros_type`` with its ``MSG:`` dependency sections. KeyError if unknown."""
    if not known(ros_type):
        raise KeyError(ros_type)
    return str(typestore().generate_msgdef(ros_type, ros_version=2)[0])


def extended(schemas: Iterable[tuple[str, str]]) -> Typestore:
    """A new store: :func:`typestore`'s types plus those defined by ``(type name, ros2msg text)`` schemas.

    A schema text is the type's definition, then per dependency :data:`SCHEMA_SEPARATOR` and
    ``MSG: pkg/Type`` (or ``pkg/msg/Type``) followed by that definition (rosbag2's layout).
    Types the store already has keep their definition.
    """
    from rosbags.typesys import get_types_from_msg

    store = _build()
    for type_name, text in schemas:
        if type_name in store.fielddefs:
            continue
        types = {}
        for i, section in enumerate(text.split(SCHEMA_SEPARATOR)):
            if i == 0:
                name, body = type_name, section
            else:
                head, _, body = section.partition("\n")
                name = head.removeprefix("MSG: ").strip()
                pkg, _, typ = name.partition("/")
                name = f"{pkg}/msg/{typ}" if "/msg/" not in name else name
            if name not in store.fielddefs:
                types.update(get_types_from_msg(body, name))
        store.register(types)
    return store

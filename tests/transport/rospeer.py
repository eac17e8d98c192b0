"""A ROS 2 process's own view, for tests that listen like one: its Cyclone configuration and types.

Independent of ``dem_ros.transport.dds.msgs``: the structs are written from the ROS 2 message
definitions, so a test reading our topics with them checks what a ROS 2 node would see.
No ``from __future__ import annotations`` here: this module defines IdlStructs.
"""

from dataclasses import dataclass, field

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import float64, int32, sequence, uint32

# rmw_cyclonedds' LOCALHOST configuration. A Jazzy process (Cyclone 0.10) accepts discovery
# arriving over lo whatever interface it selected; this reader runs on PyPI Cyclone 11, which
# drops discovery from unselected interfaces, so it selects lo explicitly to behave the same.
LOCALHOST_XML = (
    "<CycloneDDS><Domain><General><Interfaces><NetworkInterface address=\"127.0.0.1\"/></Interfaces>"
    "<AllowMulticast>false</AllowMulticast></General>"
    "<Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>"
    '<Peers><Peer address="localhost"/></Peers></Discovery></Domain></CycloneDDS>'
)



# --- a ROS 2 reader's own view of the types (independent of dem_ros.transport.dds.msgs)
@dataclass
class RTime(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class RHeader(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: RTime = field(default_factory=RTime)
    frame_id: str = ""


@dataclass
class RJointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: RHeader = field(default_factory=RHeader)
    name: sequence[str] = field(default_factory=list)
    position: sequence[float64] = field(default_factory=list)
    velocity: sequence[float64] = field(default_factory=list)
    effort: sequence[float64] = field(default_factory=list)

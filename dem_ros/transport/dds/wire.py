"""ROS 2 conventions on the DDS wire, as rmw_cyclonedds applies them.

Sources (ros2/rmw_cyclonedds, ``rmw_cyclonedds_cpp/src/rmw_node.cpp``):
    * ``check_create_domain``: the discovery XML fragment per
      ``ROS_AUTOMATIC_DISCOVERY_RANGE`` (Jazzy) / ``ROS_LOCALHOST_ONLY`` (Humble),
      followed by the user's ``CYCLONEDDS_URI``;
    * participant USER_DATA ``enclave=/;``; endpoint USER_DATA
      ``[clientid=..;|serviceid=..;]typehash=RIHS01_<hex>;``;
    * GIDs are the 16-byte DDS GUIDs, zero-padded to the GID size
      (24 on Humble, 16 from Iron on).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from functools import cache

from ...contract import DOMAIN_ID_MAX, QoS
from ..api import TransportError

__all__ = [
    "Settings",
    "domain_config",
    "interface_config",
    "rmw_domain_config",
    "service_topics",
    "settings_from_env",
    "topic_name",
    "type_hash",
    "user_data_for_endpoint",
]

#: GID size per distro (rmw_dds_common/msg/Gid: char[24] on Humble, uint8[16] from Iron on)
GID_SIZE = {"humble": 24, "iron": 16, "jazzy": 16, "kilted": 16, "rolling": 16}
_RANGES = ("SUBNET", "LOCALHOST", "OFF", "SYSTEM_DEFAULT")


@dataclass(frozen=True)
class Settings:
    """Process-wide DDS settings, read once from the environment."""

    domain_id: int
    distro: str
    discovery_range: str  # SUBNET | LOCALHOST | OFF | SYSTEM_DEFAULT | HUMBLE_LOCALHOST
    static_peers: tuple[str, ...]
    user_uri: str

    @property
    def gid_size(self) -> int:
        return GID_SIZE[self.distro]


def parse_domain_id(raw: str | None) -> int:
    """``ROS_DOMAIN_ID`` -> int; empty/unset is 0; anything outside 0..DOMAIN_ID_MAX is a TransportError."""
    if raw is None or raw.strip() == "":
        return 0
    try:
        value = int(raw.strip(), 10)
    except ValueError:
        raise TransportError(f"ROS_DOMAIN_ID={raw!r} is not an integer; use 0..{DOMAIN_ID_MAX}") from None
    if not 0 <= value <= DOMAIN_ID_MAX:
        raise TransportError(f"ROS_DOMAIN_ID={value} is outside 0..{DOMAIN_ID_MAX} (the range safe on every OS)")
    return value


def settings_from_env(domain_id: int | None = None, env: dict[str, str] | None = None) -> Settings:
    """Read ROS_DOMAIN_ID, DEM_ROS_DISTRO, ROS_AUTOMATIC_DISCOVERY_RANGE, ROS_LOCALHOST_ONLY,
    ROS_STATIC_PEERS and CYCLONEDDS_URI.

    Discovery range: ``ROS_AUTOMATIC_DISCOVERY_RANGE`` when set (any distro);
    otherwise Humble follows ``ROS_LOCALHOST_ONLY`` (1 -> loopback interface,
    else Cyclone's defaults) and Jazzy defaults to LOCALHOST.
    """
    env = dict(os.environ) if env is None else env
    if domain_id is None:
        domain_id = parse_domain_id(env.get("ROS_DOMAIN_ID"))
    elif not 0 <= int(domain_id) <= DOMAIN_ID_MAX:
        raise TransportError(f"domain id {domain_id} is outside 0..{DOMAIN_ID_MAX}")
    distro = env.get("DEM_ROS_DISTRO", "jazzy").strip().lower() or "jazzy"
    if distro not in GID_SIZE:
        raise TransportError(f"DEM_ROS_DISTRO={distro!r} is not one of {', '.join(GID_SIZE)}")
    rng = env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").strip().upper()
    if rng:
        if rng not in _RANGES:
            raise TransportError(
                f"ROS_AUTOMATIC_DISCOVERY_RANGE={rng!r} is not one of {', '.join(_RANGES)}"
            )
    elif distro == "humble":
        rng = "HUMBLE_LOCALHOST" if env.get("ROS_LOCALHOST_ONLY", "0").strip() == "1" else "SYSTEM_DEFAULT"
    else:
        rng = "LOCALHOST"
    peers = tuple(p.strip() for p in env.get("ROS_STATIC_PEERS", "").split(";") if p.strip())
    return Settings(int(domain_id), distro, rng, peers, env.get("CYCLONEDDS_URI", ""))


# Cyclone DDS >= 11 (the PyPI binding) ignores SPDP that arrives over a network interface it
# has not selected (cyclonedds a4937a96 "Ignore SPDP from non-selected interfaces"; relaxed
# again upstream by PR #2457, after 11.0.1). The 0.10.x under rmw_cyclonedds has no such
# check. Under LOCALHOST every rmw_cyclonedds participant unicasts its SPDP to 127.0.0.1
# (all 32 auto-index ports); that arrives over ``lo``, whereas Cyclone auto-selects only the
# best non-loopback interface (eth0, ...), so an 11.x participant with the rmw string alone
# drops every Jazzy announcement and Jazzy never learns of us. Hence, for LOCALHOST only,
# the loopback interface is selected explicitly (as Humble's ROS_LOCALHOST_ONLY did). With
# ROS_STATIC_PEERS the auto-selected interface is kept too, so that remote peers can reach
# the locators we advertise. Nothing is added when CYCLONEDDS_URI selects interfaces itself
# (Cyclone refuses an interface listed twice).
_LOOPBACK_ONLY = '<NetworkInterface address="127.0.0.1"/>'
_AUTO_AND_LOOPBACK = '<NetworkInterface autodetermine="true"/><NetworkInterface address="127.0.0.1"/>'
_SELECTS_INTERFACES = re.compile(r"NetworkInterface", re.IGNORECASE)


def _user_selects_interfaces(user_uri: str) -> bool:
    """Whether CYCLONEDDS_URI (inline XML and/or config files) already selects network interfaces."""
    if not user_uri.strip():
        return False
    if _SELECTS_INTERFACES.search(user_uri):
        return True
    for item in user_uri.split(","):
        item = os.path.expandvars(item.strip())
        if not item or item.startswith("<"):
            continue
        path = item[len("file://"):] if item.startswith("file://") else item
        try:
            with open(path, encoding="utf-8", errors="replace") as f:
                if _SELECTS_INTERFACES.search(f.read()):
                    return True
        except OSError:
            pass
    return False


def interface_config(s: Settings) -> str:
    """The interface-selection fragment dem_ros puts before the rmw_cyclonedds string (LOCALHOST only)."""
    if s.discovery_range != "LOCALHOST" or _user_selects_interfaces(s.user_uri):
        return ""
    ifs = _AUTO_AND_LOOPBACK if s.static_peers else _LOOPBACK_ONLY
    return f"<CycloneDDS><Domain><General><Interfaces>{ifs}</Interfaces></General></Domain></CycloneDDS>,"


def domain_config(s: Settings) -> str:
    """The Cyclone config string for ``dds_create_domain``: :func:`interface_config` followed by
    the string rmw_cyclonedds passes (see :func:`rmw_domain_config`)."""
    return interface_config(s) + rmw_domain_config(s)


def rmw_domain_config(s: Settings) -> str:
    """The Cyclone config string rmw_cyclonedds passes to ``dds_create_domain``."""
    if s.discovery_range == "HUMBLE_LOCALHOST":
        cfg = (
            '<CycloneDDS><Domain><General><Interfaces><NetworkInterface address="127.0.0.1"/>'
            "</Interfaces></General></Domain></CycloneDDS>,"
        )
        return cfg + s.user_uri
    localhost_peer = s.discovery_range == "LOCALHOST"
    add_peers = s.discovery_range in ("SUBNET", "LOCALHOST")
    no_multicast = s.discovery_range in ("LOCALHOST", "OFF")
    if not (localhost_peer or add_peers or no_multicast):
        return s.user_uri
    cfg = "<CycloneDDS><Domain>"
    if no_multicast:
        cfg += "<General><AllowMulticast>false</AllowMulticast></General>"
    if no_multicast and not localhost_peer and not add_peers:
        cfg += f"<Discovery><ParticipantIndex>none</ParticipantIndex><Tag>ros_discovery_off_{os.getpid()}</Tag>"
    else:
        cfg += "<Discovery><ParticipantIndex>auto</ParticipantIndex>"
        cfg += "<MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>"
    peers = (["localhost"] if localhost_peer else []) + (list(s.static_peers) if add_peers else [])
    if peers:
        cfg += "<Peers>" + "".join(f'<Peer address="{p}"/>' for p in peers) + "</Peers>"
    cfg += "</Discovery></Domain></CycloneDDS>,"
    return cfg + s.user_uri


def topic_name(ros_name: str) -> str:
    """ROS topic ``/a/b`` -> DDS topic ``rt/a/b``."""
    return "rt/" + ros_name.lstrip("/")


def service_topics(service: str) -> tuple[str, str]:
    """ROS service ``/node/set_parameters`` -> (request topic, reply topic)."""
    s = service.lstrip("/")
    return f"rq/{s}Request", f"rr/{s}Reply"


@cache
def type_hash(ros_type: str, distro: str = "jazzy") -> str:
    """``RIHS01_<hex>`` of a ROS type (rosidl's type-description hash, from :mod:`dem_ros.typestore`).

    ``""`` on Humble (no type hashes) or if the type is unknown (like an rmw without type descriptions).
    """
    if distro == "humble":
        return ""
    from ...typestore import rihs01  # rosbags: imported on first use, not with the transport

    try:
        return rihs01(ros_type)
    except KeyError:
        return ""


def user_data_for_endpoint(ros_type: str, distro: str, extra: str = "") -> bytes:
    """Endpoint USER_DATA: ``extra`` (``clientid=..;``/``serviceid=..;``) + ``typehash=RIHS01_..;``."""
    h = type_hash(ros_type, distro)
    return (extra + (f"typehash={h};" if h else "")).encode()


def dds_qos(q: QoS, user_data: bytes = b""):  # type: ignore[no-untyped-def]
    """contract.QoS -> cyclonedds Qos (reliability, durability, keep-last depth, user data)."""
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.util import duration

    policies = [
        Policy.Reliability.Reliable(duration(seconds=1)) if q.reliable else Policy.Reliability.BestEffort,
        Policy.Durability.TransientLocal if q.transient_local else Policy.Durability.Volatile,
        Policy.History.KeepLast(q.depth),
    ]
    if user_data:
        policies.append(Policy.Userdata(user_data))
    return Qos(*policies)

"""rosbag2 conventions: QoS strings, message definitions, ``metadata.yaml``.

Everything here follows the rosbag2 sources (ros2/rosbag2, branches humble and
jazzy):

* ``metadata.yaml`` version 8 (``rosbag2_storage/yaml.hpp`` on jazzy):
  ``custom_data`` (a string-to-string map) exists since version 6,
  ``type_description_hash`` per topic since 7, ``ros_distro`` since 8; Jazzy
  requires all three keys for version 8, Humble (``metadata_io.cpp``, writes
  version 5) ignores keys it does not know. ``compression_format`` and
  ``compression_mode`` stay empty: MCAP chunk compression is internal to the
  storage plugin, and a non-empty value would make rosbag2 look for its own
  file/message compression plugin.
* ``offered_qos_profiles`` in the v8 form is a *string* holding a YAML list of
  profiles with integer enums, as ``YAML::Dump`` writes it
  (``rosbag2_storage/src/rosbag2_storage/qos.cpp``,
  ``serialize_rclcpp_qos_vector``; Humble: ``rosbag2_transport/qos.cpp``).
  Enum values are those of ``rmw/types.h``.
* Schema data (``ros2msg``) is the ``.msg`` text followed, for each
  dependency, by a line of 80 ``=`` and ``MSG: pkg/Type``
  (``rosbag2_cpp/message_definitions/local_message_definition_source.cpp``);
  we take the text from the one typestore (:mod:`dem_ros.typestore`,
  rosbags' ``generate_msgdef``), which uses the same layout.
"""

from __future__ import annotations

import os
from typing import Any

import yaml

from dem_ros import typestore
from dem_ros.contract import QoS

from .errors import BagError

__all__ = [
    "METADATA_VERSION",
    "STORAGE_ID",
    "dump_metadata_yaml",
    "metadata_dict",
    "msgdef",
    "qos_from_string",
    "qos_to_v8_string",
    "type_hash",
]

METADATA_VERSION = 8
STORAGE_ID = "mcap"
#: rmw/types.h enum values.
HISTORY_KEEP_LAST = 1
RELIABILITY_RELIABLE, RELIABILITY_BEST_EFFORT = 1, 2
DURABILITY_TRANSIENT_LOCAL, DURABILITY_VOLATILE = 1, 2
LIVELINESS_AUTOMATIC = 1
#: RMW_DURATION_INFINITE as rmw_time_t {sec, nsec}; what discovery reports for unset policies.
_INF_SEC, _INF_NSEC = 9223372036, 854775807

_QOS_TEMPLATE = (
    "- history: {history}\n"
    "  depth: {depth}\n"
    "  reliability: {reliability}\n"
    "  durability: {durability}\n"
    "  deadline:\n    sec: {s}\n    nsec: {ns}\n"
    "  lifespan:\n    sec: {s}\n    nsec: {ns}\n"
    "  liveliness: {liveliness}\n"
    "  liveliness_lease_duration:\n    sec: {s}\n    nsec: {ns}\n"
    "  avoid_ros_namespace_conventions: false"
)


def qos_to_v8_string(qos: QoS) -> str:
    """One offered profile in the v8 ``offered_qos_profiles`` string form.

    Byte-for-byte what yaml-cpp's ``YAML::Dump`` gives for a one-element list
    (block style, no trailing newline).
    """
    return _QOS_TEMPLATE.format(
        history=HISTORY_KEEP_LAST,
        depth=int(qos.depth),
        reliability=RELIABILITY_RELIABLE if qos.reliable else RELIABILITY_BEST_EFFORT,
        durability=DURABILITY_TRANSIENT_LOCAL if qos.transient_local else DURABILITY_VOLATILE,
        liveliness=LIVELINESS_AUTOMATIC,
        s=_INF_SEC,
        ns=_INF_NSEC,
    )


_NAMES = {
    "reliability": {"reliable": 1, "best_effort": 2, "system_default": 0, "best_available": 4},
    "durability": {"transient_local": 1, "volatile": 2, "system_default": 0, "best_available": 4},
}


def qos_from_string(text: str | list[Any]) -> list[QoS]:
    """Parse ``offered_qos_profiles`` (v8 string or v9 list, int or named enums)."""
    if not text:
        return []
    try:
        items = yaml.safe_load(text) if isinstance(text, str) else text
    except yaml.YAMLError as exc:
        raise BagError(f"offered_qos_profiles is not valid YAML: {exc}") from None
    out = []
    for item in items or []:
        try:
            rel = item["reliability"]
            dur = item["durability"]
            rel = _NAMES["reliability"].get(str(rel).lower(), -1) if isinstance(rel, str) else rel
            dur = _NAMES["durability"].get(str(dur).lower(), -1) if isinstance(dur, str) else dur
            out.append(QoS(reliable=rel == RELIABILITY_RELIABLE,
                           transient_local=dur == DURABILITY_TRANSIENT_LOCAL,
                           depth=int(item.get("depth", 0))))
        except (TypeError, KeyError, AttributeError) as exc:
            raise BagError(f"offered_qos_profiles entry {item!r} is malformed: {exc}") from None
    return out


def _check_type(type_name: str) -> None:
    if not typestore.known(type_name):
        raise BagError(
            f"message type {type_name!r} is unknown to the rosbags typestore (ROS2_JAZZY); "
            "use a standard ROS 2 type in 'pkg/msg/Name' form"
        )


def msgdef(type_name: str) -> str:
    """``ros2msg`` schema text for ``type_name`` (with ``MSG:`` dependency sections)."""
    _check_type(type_name)
    return typestore.msgdef(type_name)


def type_hash(type_name: str) -> str:
    """RIHS01 type description hash, as Jazzy stores in ``type_description_hash``."""
    _check_type(type_name)
    return typestore.rihs01(type_name)


def metadata_dict(
    *,
    relative_file: str,
    topics: list[dict[str, Any]],
    start_ns: int,
    end_ns: int,
    custom_data: dict[str, str],
) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` mapping (metadata version 8).

    ``topics`` items: ``name``, ``type``, ``qos_string``, ``hash``, ``count``.
    """
    count = sum(int(t["count"]) for t in topics)
    duration = max(0, end_ns - start_ns) if count else 0
    start = start_ns if count else 0
    return {
        "version": METADATA_VERSION,
        "storage_identifier": STORAGE_ID,
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": count,
        "topics_with_message_count": [
            {
                "topic_metadata": {
                    "name": t["name"],
                    "type": t["type"],
                    "serialization_format": "cdr",
                    "offered_qos_profiles": t["qos_string"],
                    "type_description_hash": t["hash"],
                },
                "message_count": int(t["count"]),
            }
            for t in topics
        ],
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": [relative_file],
        "files": [
            {
                "path": relative_file,
                "starting_time": {"nanoseconds_since_epoch": start},
                "duration": {"nanoseconds": duration},
                "message_count": count,
            }
        ],
        "custom_data": {str(k): str(v) for k, v in custom_data.items()},
        "ros_distro": os.environ.get("ROS_DISTRO", ""),
    }


class _Dumper(yaml.SafeDumper):
    pass


def _str_representer(dumper: yaml.SafeDumper, value: str) -> yaml.ScalarNode:
    style = '"' if ("\n" in value or value == "") else None
    return dumper.represent_scalar("tag:yaml.org,2002:str", value, style=style)


_Dumper.add_representer(str, _str_representer)


def dump_metadata_yaml(info: dict[str, Any], *, wrap: bool = True) -> str:
    """YAML text; ``wrap`` puts it under ``rosbag2_bagfile_information`` (metadata.yaml)."""
    doc = {"rosbag2_bagfile_information": info} if wrap else info
    return yaml.dump(doc, Dumper=_Dumper, sort_keys=False, default_flow_style=False,
                     allow_unicode=True, width=1 << 16)

"""msgs.py against the ROS 2 definitions (rosbags' Jazzy and Humble type stores, rcl_interfaces .srv texts),
and its codec (fastcdr.decode) against rosbags' bytes and values, both byte orders.

A struct that drifts from its ROS definition (a field renamed, reordered,
retyped, a bound lost) would still round-trip with itself and silently
mis-decode what a ROS node sends; these tests compare with the definitions.
"""

from __future__ import annotations

import math
import random
import sys
import typing
from pathlib import Path
from typing import Any

import pytest
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, bounded_str, sequence
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype

from dem_ros.transport.dds import fastcdr, msgs

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "fuzz"))
from cdrfuzz import random_message

JAZZY = get_typestore(Stores.ROS2_JAZZY)
HUMBLE = get_typestore(Stores.ROS2_HUMBLE)

# rcl_interfaces/srv/*.srv as shipped in Humble and Jazzy (types fully qualified for the parser)
SRV_TEXT = {
    "rcl_interfaces/srv/GetParameters": ("string[] names", "rcl_interfaces/msg/ParameterValue[] values"),
    "rcl_interfaces/srv/SetParameters": ("rcl_interfaces/msg/Parameter[] parameters",
                                         "rcl_interfaces/msg/SetParametersResult[] results"),
    "rcl_interfaces/srv/SetParametersAtomically": ("rcl_interfaces/msg/Parameter[] parameters",
                                                   "rcl_interfaces/msg/SetParametersResult result"),
    "rcl_interfaces/srv/ListParameters": ("uint64 DEPTH_RECURSIVE=0\nstring[] prefixes\nuint64 depth",
                                          "rcl_interfaces/msg/ListParametersResult result"),
    "rcl_interfaces/srv/DescribeParameters": ("string[] names", "rcl_interfaces/msg/ParameterDescriptor[] descriptors"),
    "rcl_interfaces/srv/GetParameterTypes": ("string[] names", "uint8[] types"),
}
#: rmw_cyclonedds' request header in front of every request and reply (cdds_request_header_t)
RMW_HEADER = "uint64 guid\nint64 seq\n"

_SAME_WIRE = {"byte": "uint8", "char": "uint8"}  # ROS byte/char are one octet on the wire


def _srv_store() -> Any:
    """Jazzy's store plus every service request/response as a message with the rmw header in front."""
    ts = get_typestore(Stores.ROS2_JAZZY)
    types: dict = {}
    for srv, (req, rep) in SRV_TEXT.items():
        for suffix, text in (("_Request", req), ("_Response", rep)):
            name = srv.replace("/srv/", "/msg/") + suffix  # the parser wants msg names
            types.update(get_types_from_msg(RMW_HEADER + text + "\n", name))
    ts.register(types)
    return ts


SRV_STORE = _srv_store()


def ros_name(cls: type) -> str:
    pkg, kind, _, name = cls.__idl_typename__.split("::")
    return f"{pkg}/{kind}/{name[:-1]}"


def ours(tp: Any) -> Any:
    """A normalised description of one of our annotations."""
    if tp is str:
        return ("string", 0)
    if tp is bool:
        return ("bool",)
    if isinstance(tp, type) and issubclass(tp, IdlStruct):
        return ("struct", ros_name(tp).split("/")[-1])
    meta = typing.get_args(tp)[1]
    if isinstance(meta, str):
        return (meta,)
    if isinstance(meta, bounded_str):
        return ("string", meta.max_length)
    if isinstance(meta, sequence):
        return ("sequence", ours(meta.subtype), meta.max_length or 0)
    if isinstance(meta, array):
        return ("array", ours(meta.subtype), meta.length)
    raise AssertionError(f"unexpected annotation {tp!r}")


def theirs(node: Any) -> Any:
    """The same description of a rosbags field type."""
    kind, detail = node
    if kind == Nodetype.BASE:
        name, bound = detail
        return ("string", bound) if name == "string" else (_SAME_WIRE.get(name, name),)
    if kind == Nodetype.NAME:
        return ("struct", detail.split("/")[-1])
    sub, n = detail
    return ("sequence" if kind == Nodetype.SEQUENCE else "array", theirs(sub), n)


def fields_ours(cls: type) -> list:
    return [(k, ours(v)) for k, v in typing.get_type_hints(cls, include_extras=True).items()]


def fields_theirs(store: Any, name: str) -> list:
    return [(k, theirs(v)) for k, v in store.fielddefs[name][1]]


@pytest.mark.parametrize("ros_type", sorted(msgs.MESSAGES))
def test_message_matches_ros_definition(ros_type):
    cls = msgs.MESSAGES[ros_type]
    assert ros_name(cls) == ros_type
    assert fields_ours(cls) == fields_theirs(JAZZY, ros_type)
    assert fields_ours(cls) == fields_theirs(HUMBLE, ros_type)


@pytest.mark.parametrize(("size", "store"), [(16, JAZZY), (24, HUMBLE)], ids=["jazzy", "humble"])
def test_discovery_types_match_ros_definition(size, store):
    for name, cls in msgs.gid_types(size).items():
        assert fields_ours(cls) == fields_theirs(store, f"rmw_dds_common/msg/{name}"), name


@pytest.mark.parametrize("srv", sorted(msgs.SERVICES))
def test_service_matches_srv_definition(srv):
    ros_srv, req, rep = msgs.SERVICES[srv]
    assert ros_srv in SRV_TEXT
    for cls, suffix in ((req, "_Request"), (rep, "_Response")):
        assert ros_name(cls) == ros_srv + suffix
        assert fields_ours(cls) == fields_theirs(SRV_STORE, ros_srv.replace("/srv/", "/msg/") + suffix)


# --------------------------------------------------------------------------- values and bytes vs rosbags
def to_rosbags(store: Any, name: str, obj: Any) -> Any:
    """Our message as the rosbags dataclass of ``name`` (recursively)."""
    cls = store.types[name]
    kw = {}
    for field, node in store.fielddefs[name][1]:
        v = getattr(obj, field)
        kind, detail = node
        if kind == Nodetype.NAME:
            v = to_rosbags(store, detail, v)
        elif kind == Nodetype.BASE and detail[0] == "byte" and v > 127:
            v -= 256  # rosbags codes ROS byte as int8; the octet on the wire is the same
        elif kind in (Nodetype.SEQUENCE, Nodetype.ARRAY):
            sub_kind, sub = detail[0]
            if sub_kind == Nodetype.NAME:
                v = [to_rosbags(store, sub, x) for x in v]
            elif sub[0] != "string":
                import numpy as np

                dtype = {"bool": bool, "float64": np.float64, "float32": np.float32}.get(
                    sub[0], getattr(np, _SAME_WIRE.get(sub[0], sub[0]), None))
                v = np.array(list(v), dtype=dtype)
        kw[field] = v
    return cls(**kw)


def same(a: Any, b: Any) -> bool:
    """Field-wise equality of our message and a rosbags one (numpy arrays vs lists, NaN == NaN)."""
    if hasattr(a, "__dataclass_fields__"):
        return all(same(getattr(a, f), getattr(b, f)) for f in a.__dataclass_fields__ if f != "__msgtype__")
    if isinstance(a, (list, tuple, bytes)) or hasattr(b, "tolist"):
        b = b.tolist() if hasattr(b, "tolist") else b
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    if isinstance(a, int) and not isinstance(a, bool) and isinstance(b, int) and b < 0 <= a:
        return a == b + 256  # a ROS byte: uint8 here, int8 in rosbags (same octet)
    return a == b


def _all_types() -> list[tuple[str, type, Any]]:
    out = [(name, cls, JAZZY) for name, cls in sorted(msgs.MESSAGES.items())]
    for _, req, rep in msgs.SERVICES.values():
        for cls in (req, rep):
            out.append((ros_name(cls).replace("/srv/", "/msg/"), cls, SRV_STORE))
    out.append(("rmw_dds_common/msg/ParticipantEntitiesInfo", msgs.gid_types(16)["ParticipantEntitiesInfo"], JAZZY))
    return out


@pytest.mark.parametrize(("name", "cls", "store"), _all_types(), ids=[t[0] for t in _all_types()])
@pytest.mark.parametrize("little_endian", [True, False], ids=["le", "be"])
def test_codec_agrees_with_rosbags(name, cls, store, little_endian):
    """Random valid messages: rosbags' bytes decode to our values; ours (LE) are rosbags' bytes."""
    rng = random.Random(sum(map(ord, name)))  # a stable seed per type
    for _ in range(40):
        m = random_message(cls, rng)
        rb = to_rosbags(store, name, m)
        raw = bytes(store.serialize_cdr(rb, name, little_endian=little_endian))
        got = fastcdr.decode(cls, raw)
        assert same(got, rb), (got, rb)
        assert cls.deserialize(raw) == got
        if little_endian:
            assert bytes(m.serialize()) == raw
            assert same(m, store.deserialize_cdr(bytes(m.serialize()), name))


def test_joint_state_fast_path_is_the_generic_decoder():
    rng = random.Random(7)
    for _ in range(200):
        m = random_message(msgs.JointState, rng)
        b = fastcdr.encode_joint_state(m)
        assert b == m.serialize()
        assert fastcdr.decoder(msgs.JointState)(b) == fastcdr._decode_generic(msgs.JointState, b) == m


# --------------------------------------------------------------------------- each kind of bad input, by name
def _js(**kw: Any) -> bytes:
    return msgs.JointState(**kw).serialize()


GOOD = _js(name=["magnet_1", "magnet_2"], position=[0.008, 0.0079], effort=[1.0, 2.0])


@pytest.mark.parametrize(("data", "says"), [
    (b"", "shorter than the 4-byte encapsulation header"),
    (b"\x00\x01", "shorter than the 4-byte encapsulation header"),
    (b"\x00\x07\x00\x00" + GOOD[4:], "is not plain CDR"),
    (GOOD[:-5], "effort"),
    (GOOD + b"\0" * 16, "16 bytes left after the message"),
    (GOOD[:12] + b"\xff\xff\xff\x7f" + GOOD[16:], "header.frame_id: string length 2147483647 exceeds"),
    (GOOD[:20] + b"\xff\xff\xff\x7f" + GOOD[24:], "name: sequence count 2147483647 needs"),
    # a non-UTF-8 frame_id in otherwise well-formed CDR (what killed the estimator and reference)
    (b"\x00\x01\x00\x00" + b"\0" * 8 + b"\x02\x00\x00\x00\xff\x00\x00\x00" + b"\0" * 16,
     "header.frame_id: string is not UTF-8"),
    (b"\x00\x01\x00\x00" + b"\0" * 8 + b"\x02\x00\x00\x00ab\x00\x00" + b"\0" * 16, "not NUL-terminated"),
    (b"\x00\x01\x00\x00" + b"\0" * 8 + b"\x10\x00\x00\x00ab\x00\x00", "string length 16 exceeds"),
    ("not bytes", "expected bytes, got str"),
], ids=lambda v: v if isinstance(v, str) and " " in v else "")
def test_bad_joint_state_is_a_cdr_error_that_says_why(data, says):
    for decoder in (msgs.JointState.deserialize, lambda d: fastcdr._decode_generic(msgs.JointState, d)):
        with pytest.raises(fastcdr.CdrError, match="sensor_msgs/msg/JointState") as e:
            decoder(data)
        assert says in str(e.value)


def test_bad_bool_and_bounded_sequence_are_cdr_errors():
    d = msgs.ParameterDescriptor(name="k1", read_only=True,
                                 floating_point_range=[msgs.FloatingPointRange(0.0, 1.0, 0.0)]).serialize()
    i = d.index(b"\x01", 4 + 4 + 3 + 1 + 4 + 1 + 4 + 1)  # the read_only byte (after name, type, 2 strings)
    bad_bool = d[:i] + b"\x02" + d[i + 1:]
    with pytest.raises(fastcdr.CdrError, match="read_only: bool byte is 2"):
        msgs.ParameterDescriptor.deserialize(bad_bool)
    j = d.index(b"\x01\x00\x00\x00", i + 1)  # floating_point_range count
    over = d[:j] + b"\x02\x00\x00\x00" + d[j + 4:] + b"\0" * 24
    with pytest.raises(fastcdr.CdrError, match="floating_point_range: sequence count 2 exceeds its bound 1"):
        msgs.ParameterDescriptor.deserialize(over)


def test_non_utf8_parameter_name_in_a_set_request_is_a_cdr_error():
    req = msgs.SetParameters_Request(guid=1, seq=2, parameters=[msgs.Parameter(name="kk")]).serialize()
    bad = req.replace(b"kk\x00", b"k\xff\x00", 1)
    with pytest.raises(fastcdr.CdrError, match=r"parameters\[0\].name: string is not UTF-8"):
        msgs.SetParameters_Request.deserialize(bad)


def test_header_less_body_decodes():
    m = msgs.String(data="x")
    assert msgs.String.deserialize(m.serialize()[4:], has_header=False) == m

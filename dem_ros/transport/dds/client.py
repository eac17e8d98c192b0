"""A service client on plain DDS: the rcl_interfaces parameter services and std_srvs.

Talks to any ROS 2 node (rclpy, rclcpp or our DDS nodes) the way an
rmw_cyclonedds client does: request on ``rq/<node>/<srv>Request`` with the
(guid, seq) header, reply picked from ``rr/<node>/<srv>Reply`` by guid.
"""

from __future__ import annotations

import random
import time
from typing import Any

from cyclonedds._clayer import ddspy_take, ddspy_write
from cyclonedds.core import ReadCondition, WaitSet
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader

from .. import paramvalue as pv
from ..api import TransportError
from . import msgs, srvs, wire
from .executor import ANY_SAMPLE
from .node import QOS_SERVICES, Participant

__all__ = ["FASTDDS_VENDOR", "call_service", "param_get", "param_list", "param_set", "service_vendor", "set_bool",
           "trigger"]


def _node_fqn(node_name: str) -> str:
    n = node_name.strip()
    if not n:
        raise TransportError("empty node name")
    return n if n.startswith("/") else "/" + n


#: (domain id, node, service) -> [participant, writer, reader, wait set, condition, client guid, last seq]
_ENDPOINTS: dict[tuple[int, str, str], list[Any]] = {}


def _endpoints(p: Any, fqn: str, srv: str, srv_type: str) -> list[Any]:
    """The client's request writer / reply reader for one service, kept for the process.

    Reusing them means a second call needs no new endpoint discovery, which a node
    whose loop runs flat out can take a long time to process.
    """
    key = (p.settings.domain_id, fqn, srv)
    ep = _ENDPOINTS.get(key)
    if ep is None or ep[0] is not p:
        req_cls, rep_cls = srvs.service_classes(srv_type)
        rq, rr = wire.service_topics(fqn + "/" + srv)
        guid = random.getrandbits(63) | 1
        ud = f"clientid={guid:x}.{random.getrandbits(32):x};"
        distro = p.settings.distro
        writer = DataWriter(p.dp, p.topic(rq, req_cls),
                            qos=wire.dds_qos(QOS_SERVICES,
                                             wire.user_data_for_endpoint(srv_type + "_Request", distro, ud)))
        reader = DataReader(p.dp, p.topic(rr, rep_cls),
                            qos=wire.dds_qos(QOS_SERVICES,
                                             wire.user_data_for_endpoint(srv_type + "_Response", distro, ud)))
        ws = WaitSet(p.dp)
        cond = ReadCondition(reader, ANY_SAMPLE)
        ws.attach(cond)
        ep = [p, writer, reader, ws, cond, guid, 0]
        _ENDPOINTS[key] = ep
    return ep


#: eProsima Fast DDS's vendor id (the first two bytes of a GUID prefix; the OMG's list): the RMW of the registry's
#: rclpy, whose services take the request id from the sample identity, not from the payload as this client sends it
FASTDDS_VENDOR = b"\x01\x0f"


def service_vendor(node_name: str, srv: str = "get_parameters", *, srv_type: str | None = None,
                   domain_id: int | None = None, timeout_s: float = 2.0) -> bytes | None:
    """The DDS vendor id (two bytes) of the reader that takes ``<node>/<srv>``'s requests; None when none is found
    within ``timeout_s``. Tells which client reaches the node: :data:`FASTDDS_VENDOR` needs rclpy's own."""
    fqn = _node_fqn(node_name)
    if srv_type is None:
        srv_type = msgs.SERVICES[srv][0]
    p = Participant.get(domain_id)
    try:
        writer = _endpoints(p, fqn, srv, srv_type)[1]
        deadline = time.monotonic() + timeout_s
        while True:
            handles = writer.get_matched_subscriptions()
            if handles:
                return bytes(writer.get_matched_subscription_data(handles[0]).key.bytes[:2])
            if time.monotonic() > deadline:
                return None
            time.sleep(0.01)
    finally:
        _release(p)


def _release(p: Any) -> None:
    if not p.has_nodes:  # a one-shot client process: release everything, as we found it
        for key in [k for k, v in _ENDPOINTS.items() if v[0] is p]:
            del _ENDPOINTS[key]
        p.release_if_unused()


def call_service(node_name: str, srv: str, request: Any, *, srv_type: str | None = None,
                 domain_id: int | None = None, timeout_s: float = 2.0) -> Any:
    """Call ``<node>/<srv>`` and return the response message.

    ``srv_type``: the ROS service type (``std_srvs/srv/Trigger``, ...); by default
    ``srv`` names a parameter service (``get_parameters``, ...). ``request``: an
    instance of its request class (:func:`.srvs.service_classes`).
    Raises TransportError when no server answers within ``timeout_s``.
    """
    fqn = _node_fqn(node_name)
    if srv_type is None:
        if srv not in msgs.SERVICES:
            raise TransportError(f"{srv!r} is not a parameter service; give its srv_type")
        srv_type = msgs.SERVICES[srv][0]
    p = Participant.get(domain_id)
    try:
        return _call(p, fqn, srv, srv_type, request, timeout_s)
    finally:
        _release(p)


def _call(p: Any, fqn: str, srv: str, srv_type: str, request: Any, timeout_s: float) -> Any:
    _req_cls, rep_cls = srvs.service_classes(srv_type)
    ep = _endpoints(p, fqn, srv, srv_type)
    _, writer, reader, ws, _cond, guid, _ = ep
    deadline = time.monotonic() + timeout_s
    while not (writer.get_matched_subscriptions() and reader.get_matched_publications()):
        if time.monotonic() > deadline:
            raise TransportError(
                f"no {'parameter ' if srv_type.startswith('rcl_interfaces/') else ''}service {fqn}/{srv}"
                f" ({srv_type}) on ROS_DOMAIN_ID={p.settings.domain_id} "
                f"within {timeout_s:g} s (is the node running?)"
            )
        time.sleep(0.005)
    ep[6] += 1
    seq = ep[6]
    request.guid = guid
    request.seq = seq
    data = request.serialize()
    ddspy_write(writer._ref, data + b"\0" * (-len(data) % 4))
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            raise TransportError(f"{fqn}/{srv}: no reply within {timeout_s:g} s")
        ws.wait(int(min(left, 0.2) * 1e9))
        got = ddspy_take(reader._ref, ANY_SAMPLE, 16)
        if isinstance(got, int):
            continue
        for raw, info in got:
            if info.valid_data:
                rep = rep_cls.deserialize(raw)
                if rep.guid == guid and rep.seq == seq:
                    return rep


def param_get(node_name: str, name: str, *, domain_id: int | None = None, timeout_s: float = 2.0) -> Any:
    """Current value of parameter ``name`` of ``node_name``; TransportError if unreachable or undeclared."""
    rep = call_service(node_name, "get_parameters", msgs.GetParameters_Request(names=[name]),
                       domain_id=domain_id, timeout_s=timeout_s)
    if not rep.values or rep.values[0].type == pv.NOT_SET:
        raise TransportError(f"{_node_fqn(node_name)} has no parameter {name!r}")
    return pv.from_value_msg(rep.values[0])


def param_list(node_name: str, *, domain_id: int | None = None, timeout_s: float = 2.0) -> list[str]:
    """Names of the parameters of ``node_name``."""
    rep = call_service(node_name, "list_parameters", msgs.ListParameters_Request(prefixes=[], depth=0),
                       domain_id=domain_id, timeout_s=timeout_s)
    return list(rep.result.names)


def param_set(node_name: str, name: str, value: Any, *, domain_id: int | None = None,
              timeout_s: float = 2.0) -> tuple[bool, str]:
    """Set one parameter; ``(True, "")`` or ``(False, reason)``.

    The node's declared type is asked first so that ``60`` is sent as a double to
    a double parameter (rclpy rejects an integer for a double). Unreachable
    nodes give ``(False, reason)`` rather than an exception.
    """
    t0 = time.monotonic()
    try:
        types = call_service(node_name, "get_parameter_types", msgs.GetParameterTypes_Request(names=[name]),
                             domain_id=domain_id, timeout_s=timeout_s)
        ptype = int(types.types[0]) if types.types else pv.NOT_SET
        if ptype == pv.NOT_SET:
            return False, f"{_node_fqn(node_name)} has no parameter {name!r}"
        value = pv.for_declared(ptype, value)
        try:
            pval = pv.to_value_msg(msgs.ParameterValue, value)
        except TypeError as exc:
            return False, str(exc)
        left = max(0.1, timeout_s - (time.monotonic() - t0))
        rep = call_service(node_name, "set_parameters",
                           msgs.SetParameters_Request(parameters=[msgs.Parameter(name=name, value=pval)]),
                           domain_id=domain_id, timeout_s=left)
    except TransportError as exc:
        return False, str(exc)
    if not rep.results:
        return False, "empty reply"
    r = rep.results[0]
    return bool(r.successful), str(r.reason)


def trigger(node_name: str, service: str, *, domain_id: int | None = None, timeout_s: float = 2.0) -> tuple[bool, str]:
    """Call a ``std_srvs/srv/Trigger`` service ``<node>/<service>``: (success, message)."""
    req_cls, _ = srvs.service_classes("std_srvs/srv/Trigger")
    rep = call_service(node_name, service, req_cls(), srv_type="std_srvs/srv/Trigger", domain_id=domain_id,
                       timeout_s=timeout_s)
    return bool(rep.success), str(rep.message)


def set_bool(node_name: str, service: str, value: bool, *, domain_id: int | None = None,
             timeout_s: float = 2.0) -> tuple[bool, str]:
    """Call a ``std_srvs/srv/SetBool`` service ``<node>/<service>`` with ``data = value``: (success, message)."""
    req_cls, _ = srvs.service_classes("std_srvs/srv/SetBool")
    rep = call_service(node_name, service, req_cls(data=bool(value)), srv_type="std_srvs/srv/SetBool",
                       domain_id=domain_id, timeout_s=timeout_s)
    return bool(rep.success), str(rep.message)

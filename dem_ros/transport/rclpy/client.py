"""Service clients on rclpy: the rcl_interfaces parameter services and ``std_srvs/srv/Trigger``.

The dds transport's clients (:mod:`dem_ros.transport.dds.client`) speak rmw_cyclonedds' request header, which
a node on another RMW (the registry's rclpy runs on Fast DDS) does not read. A tool that joined the graph on
rclpy (``dem-ros view --transport rclpy``) calls the nodes' services through rclpy instead, as ``ros2 param``
does: one plain rclpy node of its own (rclpy initialised for it when the process has not), its clients kept per
service, each call spun to its end on the caller's thread (one call at a time: the caller serialises them).
"""

from __future__ import annotations

import time
from typing import Any

import rclpy
from rclpy.executors import SingleThreadedExecutor

from .. import paramvalue as pv
from ..api import TransportError

__all__ = ["RclpyServiceClient"]


def _fqn(node_name: str) -> str:
    n = node_name.strip()
    if not n:
        raise TransportError("empty node name")
    return n if n.startswith("/") else "/" + n


class RclpyServiceClient:
    """Parameter and Trigger calls to the graph's nodes over rclpy (the same answers as the dds client's)."""

    def __init__(self, name: str = "dem_ros_service_client"):
        self._own_context = not rclpy.ok()  # a process on the dds transport: rclpy for these calls only
        if self._own_context:
            rclpy.init(args=[])
        self._node = rclpy.create_node(name, enable_rosout=False)
        self._ex = SingleThreadedExecutor()
        self._ex.add_node(self._node)
        self._clients: dict[tuple[str, str], Any] = {}

    def close(self) -> None:
        self._ex.shutdown(timeout_sec=1.0)
        self._node.destroy_node()
        if self._own_context:
            rclpy.try_shutdown()

    def call(self, node_name: str, srv: str, srv_type: Any, request: Any, timeout_s: float) -> Any:
        """Call ``<node>/<srv>`` and return its response; TransportError when none comes within ``timeout_s``."""
        fqn = _fqn(node_name)
        key = (fqn, srv)
        cli = self._clients.get(key)
        if cli is None:
            cli = self._clients[key] = self._node.create_client(srv_type, f"{fqn}/{srv}")
        deadline = time.monotonic() + timeout_s
        if not cli.wait_for_service(timeout_sec=timeout_s):
            raise TransportError(f"no service {fqn}/{srv} within {timeout_s:g} s (is the node running?)")
        fut = cli.call_async(request)
        self._ex.spin_until_future_complete(fut, timeout_sec=max(0.0, deadline - time.monotonic()))
        if not fut.done():
            cli.remove_pending_request(fut)
            raise TransportError(f"{fqn}/{srv}: no reply within {timeout_s:g} s")
        return fut.result()

    # -- the parameter services ---------------------------------------------------------------------------
    def param_list(self, node_name: str, *, timeout_s: float = 2.0) -> list[str]:
        from rcl_interfaces.srv import ListParameters

        rep = self.call(node_name, "list_parameters", ListParameters, ListParameters.Request(), timeout_s)
        return list(rep.result.names)

    def param_values(self, node_name: str, names: list[str], *, timeout_s: float = 2.0) -> dict[str, Any]:
        """The values of ``names`` that the node has (unknown names left out)."""
        from rcl_interfaces.srv import GetParameters

        rep = self.call(node_name, "get_parameters", GetParameters, GetParameters.Request(names=list(names)),
                        timeout_s)
        return {n: pv.from_value_msg(v) for n, v in zip(names, rep.values, strict=False) if v.type != pv.NOT_SET}

    def param_set(self, node_name: str, name: str, value: Any, *, timeout_s: float = 2.0) -> tuple[bool, str]:
        """Set one parameter as the dds client does (the declared type asked first: ``60`` goes to a double
        parameter as 60.0); ``(True, "")`` or ``(False, reason)``, also when the node cannot be reached."""
        from rcl_interfaces.msg import Parameter, ParameterValue
        from rcl_interfaces.srv import GetParameterTypes, SetParameters

        t0 = time.monotonic()
        try:
            types = self.call(node_name, "get_parameter_types", GetParameterTypes,
                              GetParameterTypes.Request(names=[name]), timeout_s)
            ptype = int(types.types[0]) if types.types else pv.NOT_SET
            if ptype == pv.NOT_SET:
                return False, f"{_fqn(node_name)} has no parameter {name!r}"
            value = pv.for_declared(ptype, value)
            try:
                pval = pv.to_value_msg(ParameterValue, value)
            except TypeError as exc:
                return False, str(exc)
            left = max(0.1, timeout_s - (time.monotonic() - t0))
            rep = self.call(node_name, "set_parameters", SetParameters,
                            SetParameters.Request(parameters=[Parameter(name=name, value=pval)]), left)
        except TransportError as exc:
            return False, str(exc)
        if not rep.results:
            return False, "empty reply"
        return bool(rep.results[0].successful), str(rep.results[0].reason)

    def trigger(self, node_name: str, service: str, *, timeout_s: float = 2.0) -> tuple[bool, str]:
        """Call a ``std_srvs/srv/Trigger`` service ``<node>/<service>``: (success, message)."""
        from std_srvs.srv import Trigger

        rep = self.call(node_name, service, Trigger, Trigger.Request(), timeout_s)
        return bool(rep.success), str(rep.message)

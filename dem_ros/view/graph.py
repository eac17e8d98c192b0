"""The graph's parameters and hardware services, reached as ``dem-ros param`` and ``dem-ros hw`` reach them.

Parameters are named as foxglove_bridge names them: ``/<node>.<parameter>`` (``/controller.w``). A
value set from Foxglove goes the way ``dem-ros param set NODE NAME VALUE`` goes: checked against the
parameter schema first (:func:`dem_ros.tools.common.check_param_value`: a malformed value is refused with
the schema's reason before the node is asked), then sent to the node's own ``set_parameters`` service
(:func:`dem_ros.transport.param_set`), where the node's on-set callback validates it again and may refuse
it with its reason. Reads use the nodes' ``list_parameters`` / ``get_parameters`` services.

The nodes are found by asking each node of the graph (:data:`dem_ros.nodes.NODES`) for its parameter
list, again every :data:`PROBE_PERIOD_S` for those not found yet (a node that starts after the view);
a node that stops answering is dropped until it answers again.

The parameter and service clients are those that reach each node (:class:`RoutedServices`): the dds transport's
(:mod:`dem_ros.transport.dds.client`, rmw_cyclonedds' request header, as ``dem-ros param``) for a node on Cyclone,
rclpy's own (:class:`dem_ros.transport.rclpy.client.RclpyServiceClient`) for a node on the registry's rclpy, whose
Fast DDS services do not read that header. All calls go through one lock: the clients' endpoints are per process,
not per thread.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable
from typing import Any

from ..core.params import ConfigError
from ..transport import TransportError

__all__ = ["HW_NODE", "HW_SERVICES", "PROBE_PERIOD_S", "GraphAccess", "join_name", "split_name"]

#: the hardware driver and its ``std_srvs/srv/Trigger`` services (``dem-ros hw``), offered as Foxglove services
HW_NODE = "/hw_driver"
HW_SERVICES = ("arm", "disarm", "estop", "status")
#: how often nodes not found yet are asked again [s]
PROBE_PERIOD_S = 2.0


def split_name(full: str) -> tuple[str, str]:
    """``/controller.w`` -> (``/controller``, ``w``); ValueError when it has no node or no parameter."""
    node, dot, name = full.partition(".")
    if not dot or not name or not node.startswith("/") or len(node) < 2:
        raise ValueError(f"parameter {full!r}: expected /NODE.NAME, e.g. /controller.w")
    return node, name


def join_name(node: str, name: str) -> str:
    """(``/controller``, ``w``) -> ``/controller.w``."""
    return f"{node}.{name}"


class DdsServices:
    """The dds transport's service clients (:mod:`dem_ros.transport.dds.client`) behind :class:`GraphAccess`'s
    four calls (:class:`dem_ros.transport.rclpy.client.RclpyServiceClient` has the same)."""

    def param_list(self, node: str, *, timeout_s: float) -> list[str]:
        from ..transport.dds.client import param_list

        return param_list(node, timeout_s=timeout_s)

    def param_values(self, node: str, names: list[str], *, timeout_s: float) -> dict[str, Any]:
        from ..transport import paramvalue as pv
        from ..transport.dds import msgs
        from ..transport.dds.client import call_service

        rep = call_service(node, "get_parameters", msgs.GetParameters_Request(names=list(names)), timeout_s=timeout_s)
        return {n: pv.from_value_msg(v) for n, v in zip(names, rep.values, strict=False) if v.type != pv.NOT_SET}

    def param_set(self, node: str, name: str, value: Any, *, timeout_s: float) -> tuple[bool, str]:
        from ..transport.dds.client import param_set

        return param_set(node, name, value, timeout_s=timeout_s)

    def trigger(self, node: str, service: str, *, timeout_s: float) -> tuple[bool, str]:
        from ..transport.dds.client import trigger

        return trigger(node, service, timeout_s=timeout_s)

    def close(self) -> None:
        return None


class RoutedServices:
    """Each node's services through the client that reaches it, chosen by the vendor of the DDS reader that takes
    its requests (:func:`dem_ros.transport.dds.client.service_vendor`): a node on Fast DDS (the registry's rclpy)
    through rclpy's clients (``rclpy_client()`` makes them, once; None: rclpy is not installed), any other through
    the dds transport's. A graph launched on either transport is reached, whichever the view joined it on."""

    def __init__(self, rclpy_client: Callable[[], Any] | None = None):
        self._dds = DdsServices()
        self._make_rclpy = rclpy_client
        self._rclpy: Any = None
        self._route: dict[str, Any] = {}

    def _for(self, node: str, srv: str, srv_type: str | None, timeout_s: float) -> Any:
        from ..transport.dds.client import FASTDDS_VENDOR, service_vendor

        client = self._route.get(node)
        if client is None:
            vendor = service_vendor(node, srv, srv_type=srv_type, timeout_s=timeout_s)
            if vendor is None:  # not found (yet)
                raise TransportError(f"no service {node}/{srv} within {timeout_s:g} s (is the node running?)")
            client = self._dds
            if vendor == FASTDDS_VENDOR and self._make_rclpy is not None:
                if self._rclpy is None:
                    self._rclpy = self._make_rclpy()
                client = self._rclpy
            self._route[node] = client
        return client

    def param_list(self, node: str, *, timeout_s: float) -> list[str]:
        return self._for(node, "list_parameters", None, timeout_s).param_list(node, timeout_s=timeout_s)

    def param_values(self, node: str, names: list[str], *, timeout_s: float) -> dict[str, Any]:
        return self._for(node, "get_parameters", None, timeout_s).param_values(node, names, timeout_s=timeout_s)

    def param_set(self, node: str, name: str, value: Any, *, timeout_s: float) -> tuple[bool, str]:
        return self._for(node, "set_parameters", None, timeout_s).param_set(node, name, value, timeout_s=timeout_s)

    def trigger(self, node: str, service: str, *, timeout_s: float) -> tuple[bool, str]:
        client = self._for(node, service, "std_srvs/srv/Trigger", timeout_s)
        return client.trigger(node, service, timeout_s=timeout_s)

    def close(self) -> None:
        if self._rclpy is not None:
            self._rclpy.close()


class GraphAccess:
    """Parameters of the graph's nodes and hw_driver's services, over the nodes' own services.

    ``nodes``: the fully qualified names to look for; ``timeout_s``: per call; ``services``: the clients
    (default :class:`DdsServices`; ``dem-ros view`` gives :class:`RoutedServices`).
    """

    def __init__(self, nodes: Iterable[str], *, timeout_s: float = 5.0, probe_timeout_s: float = 0.5,
                 services: Any = None):
        self.services = services if services is not None else DdsServices()
        self.candidates = tuple(nodes)
        self.timeout_s = timeout_s
        self.probe_timeout_s = probe_timeout_s
        self._lock = threading.Lock()
        self._known: dict[str, list[str]] = {}  # node -> its parameter names
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- discovery -----------------------------------------------------------------------------------
    def start(self, on_found: Callable[[str], None] | None = None) -> None:
        """Look for the nodes now and every :data:`PROBE_PERIOD_S` in a thread; ``on_found(node)`` for each found."""

        def run() -> None:
            while not self._stop.is_set():
                for node in self.candidates:
                    if self._stop.is_set():
                        return
                    if node not in self.known() and self.probe(node) and on_found is not None:
                        on_found(node)
                self._stop.wait(PROBE_PERIOD_S)

        self._thread = threading.Thread(target=run, name="view-graph", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=self.probe_timeout_s * len(self.candidates) + PROBE_PERIOD_S + 1.0)
        with self._lock:
            self.services.close()

    def known(self) -> dict[str, list[str]]:
        """The nodes found so far and their parameter names (a copy)."""
        with self._lock:
            return {n: list(v) for n, v in self._known.items()}

    def probe(self, node: str) -> bool:
        """Ask ``node`` for its parameter names; True (and remembered) when it answers."""
        try:
            with self._lock:
                names = self.services.param_list(node, timeout_s=self.probe_timeout_s)
                self._known[node] = sorted(names)
        except TransportError:
            return False
        return True

    # -- parameters ---------------------------------------------------------------------------------
    def get(self, names: Iterable[str] = ()) -> dict[str, Any]:
        """Values by ``/node.name``: of ``names``, or of every parameter of every node found (``names`` empty).

        Unknown names and nodes that do not answer are left out (a node that stopped answering is
        dropped from :meth:`known` until it answers again).
        """
        wanted: dict[str, list[str]] = {}
        names = list(names)
        known = self.known()
        if not names:
            wanted = known
        for full in names:
            try:
                node, name = split_name(full)
            except ValueError:
                continue
            wanted.setdefault(node, []).append(name)
        out: dict[str, Any] = {}
        for node, params in wanted.items():
            if not params:
                continue
            try:
                values = self._get_values(node, params)
            except TransportError:
                with self._lock:
                    self._known.pop(node, None)
                continue
            out.update({join_name(node, n): v for n, v in values.items()})
        return out

    def _get_values(self, node: str, names: list[str]) -> dict[str, Any]:
        with self._lock:
            return self.services.param_values(node, names, timeout_s=self.timeout_s)

    def set(self, full: str, value: Any) -> str | None:
        """Set ``/node.name`` to ``value`` as ``dem-ros param set`` does: None, or the reason it was refused."""
        from ..tools.common import check_param_value, yaml_scalar

        try:
            node, name = split_name(full)
        except ValueError as exc:
            return str(exc)
        text = value if isinstance(value, str) else yaml_scalar(value)  # what the command line would pass
        try:
            check_param_value(node, name, text)
        except ConfigError as exc:
            return str(exc)
        with self._lock:
            ok, reason = self.services.param_set(node, name, text, timeout_s=self.timeout_s)
        return None if ok else (reason or "refused by the node")

    # -- services ----------------------------------------------------------------------------------
    def hw(self, verb: str) -> tuple[bool, str]:
        """Call hw_driver's ``verb`` service (one of :data:`HW_SERVICES`): (success, message).

        TransportError when the driver does not answer within the timeout.
        """
        if verb not in HW_SERVICES:
            raise ValueError(f"{verb!r} is not one of {', '.join(HW_SERVICES)}")
        with self._lock:
            return self.services.trigger(HW_NODE, verb, timeout_s=self.timeout_s)

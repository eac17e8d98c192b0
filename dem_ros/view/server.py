"""The Foxglove WebSocket server of the live view, on foxglove-sdk.

What a client (the Foxglove app, ``@foxglove/ws-protocol``, :mod:`.client`) gets:

* a channel per topic of :data:`FORWARDED` (every ``/dem`` topic of the contract and ``/diagnostics``):
  encoding ``cdr``, schema ``ros2msg`` named by the ROS type, its text the ``.msg`` definition with
  its dependencies (:func:`dem_ros.typestore.msgdef`, the text the bags carry). Each sample is passed on as
  the subscription received it (:meth:`~dem_ros.transport.api.Node.subscribe_raw`: CDR with its
  encapsulation header, never decoded), every sample of the 1 kHz streams;
* parameters (``/controller.w``): read from and set through the nodes' own parameter services
  (:class:`.graph.GraphAccess`); a refused set answers the parameter's unchanged value and an error
  status carrying the reason; a change made elsewhere (``dem-ros param set``) reaches subscribed
  clients from ``/parameter_events``;
* services ``/hw_driver/arm`` | ``disarm`` | ``estop`` | ``status`` (``std_srvs/srv/Trigger``, request
  and response in CDR): forwarded to hw_driver's services; a driver that does not answer fails the call
  with the reason.

The 1 kHz streams are subscribed best-effort (:func:`watched`): a reliable reader that falls behind (a view
starved of CPU) holds the writers' unacknowledged samples, and past Cyclone's writer-history watermark the
writer blocks in ``write`` for up to the reliability's blocking time: in a composed graph that writer is
the loop. A best-effort reader is never waited for; on loopback it loses a sample only when the view
itself cannot keep up (its socket overflows). The others (``/diagnostics``, the latched topics) keep
the contract's QoS.

A topic is subscribed on the graph when a client first subscribes to its channel (as foxglove_bridge
does), and stays subscribed: a topic nobody watches costs neither the view nor the graph anything (on
the dds transport a composed graph serialises a topic for DDS only while a remote reader is matched).
The subscriptions are made, and the samples arrive, on the thread that spins the node (the caller's
loop: :meth:`ViewServer.spin_once`); foxglove-sdk sends them to each client from its own threads, at most
``backlog`` samples queued per client (the oldest dropped beyond).
"""

from __future__ import annotations

import dataclasses
import queue
import threading
from typing import Any

import foxglove
from foxglove import Channel, MessageSchema, Parameter, Schema, Service, ServiceSchema, StatusLevel
from foxglove.websocket import Capability, ServerListener, WebSocketServer

from .. import contract, typestore
from ..contract import Topic
from ..transport import Node, TransportError
from .graph import HW_NODE, HW_SERVICES, GraphAccess, join_name

__all__ = ["BACKLOG", "FORWARDED", "TRIGGER", "ViewServer", "forwarded", "watched"]

TRIGGER = "std_srvs/srv/Trigger"
#: samples queued per client before the oldest is dropped: 2 s of the graph's 1 kHz streams
BACKLOG = 2 * 1000 * 7


def watched(topic: Topic) -> Topic:
    """The topic as the view subscribes it: best-effort for the 1 kHz streams (never waited for by a writer)."""
    if topic.rate_hz is not None and topic.rate_hz >= 100.0:
        return dataclasses.replace(topic, qos=dataclasses.replace(topic.qos, reliable=False))
    return topic


def forwarded(topics: tuple[Topic, ...] = contract.TOPICS) -> tuple[Topic, ...]:
    """The topics the view forwards: every ``/dem`` topic and ``/diagnostics``."""
    return tuple(t for t in topics if t.name.startswith("/dem/") or t is contract.DIAGNOSTICS)


FORWARDED = forwarded()


def _schema(type_name: str) -> Schema:
    return Schema(name=type_name, encoding="ros2msg", data=typestore.msgdef(type_name).encode())


def _parameter(name: str, value: Any) -> Parameter:
    if isinstance(value, list) and value and all(isinstance(v, float) for v in value):
        return Parameter(name, value=value, type=foxglove.ParameterType.Float64Array)
    return Parameter(name, value=value)


class ViewServer:
    """Forward the graph to Foxglove clients; stop with :meth:`stop`.

    ``node``: this process's node (the caller spins it); ``graph``: parameters and services (None: neither
    is offered). Raises TransportError when the server cannot listen (port taken, bad address).
    """

    def __init__(self, node: Node, *, host: str = "127.0.0.1", port: int = 8765, graph: GraphAccess | None = None,
                 backlog: int = BACKLOG):
        self.node = node
        self.graph = graph
        self.counts: dict[str, int] = {t.name: 0 for t in FORWARDED}
        self._channels: dict[str, Channel] = {}
        for t in FORWARDED:
            self._channels[t.name] = Channel(t.name, schema=_schema(t.type), message_encoding="cdr")
        caps = [Capability.Parameters, Capability.Services] if graph is not None else []
        services = [self._service(v) for v in HW_SERVICES] if graph is not None else []
        self._subscribed_params: set[str] = set()
        self._lock = threading.Lock()
        self._wanted: queue.SimpleQueue[str] = queue.SimpleQueue()  # topics a client asked for, not yet subscribed
        self.subscribed: set[str] = set()  # topics subscribed on the graph
        try:
            self.server: WebSocketServer = foxglove.start_server(
                name="dem_ros", host=host, port=port, capabilities=caps, server_listener=_Listener(self),
                supported_encodings=["cdr"], services=services, message_backlog_size=backlog)
        except Exception as exc:  # the SDK's error for a taken port or a bad address
            for ch in self._channels.values():
                ch.close()
            raise TransportError(f"cannot listen on {host}:{port}: {exc}") from None
        if graph is not None:
            node.subscribe(contract.PARAMETER_EVENTS, self._on_parameter_event)

    @property
    def port(self) -> int:
        """The port the server listens on (the one asked for, or the one the system chose for 0)."""
        return int(self.server.port)

    def want(self, topic: str) -> None:
        """A client subscribed to ``topic`` (any thread): subscribe it on the graph in the next :meth:`spin_once`."""
        self._wanted.put(topic)

    def spin_once(self, timeout_s: float) -> None:
        """Subscribe what clients asked for, then spin the node once (the thread that owns the node)."""
        while True:
            try:
                name = self._wanted.get_nowait()
            except queue.Empty:
                break
            topic = next((t for t in FORWARDED if t.name == name), None)
            if topic is not None and name not in self.subscribed:
                self.node.subscribe_raw(watched(topic), self._forward(name))
                self.subscribed.add(name)
        self.node.spin_once(timeout_s)

    def _forward(self, name: str) -> Any:
        log = self._channels[name].log
        counts = self.counts

        def forward(data: bytes) -> None:
            log(data)
            counts[name] += 1

        return forward

    def stop(self) -> None:
        """Close every client connection and the channels."""
        self.server.stop()
        for ch in self._channels.values():
            ch.close()

    # -- parameters ---------------------------------------------------------------------------------
    def get_parameters(self, names: list[str]) -> list[Parameter]:
        assert self.graph is not None
        return [_parameter(n, v) for n, v in sorted(self.graph.get(names).items())]

    def set_parameters(self, params: list[Parameter]) -> list[Parameter]:
        assert self.graph is not None
        for p in params:
            reason = self.graph.set(p.name, p.get_value())
            if reason is None:
                self.node.logger.info(f"{p.name} set to {p.get_value()!r} from Foxglove")
            else:
                self.node.logger.warn(f"{p.name} := {p.get_value()!r} from Foxglove refused: {reason}")
                self.server.publish_status(f"{p.name}: {reason}", StatusLevel.Error, id=f"param {p.name}")
        return self.get_parameters([p.name for p in params])

    def subscribe_parameters(self, names: list[str], on: bool) -> None:
        with self._lock:
            (self._subscribed_params.update if on else self._subscribed_params.difference_update)(names)

    def _on_parameter_event(self, msg: Any) -> None:
        from ..transport import paramvalue as pv

        node = msg.node if msg.node.startswith("/") else "/" + msg.node
        changed = [join_name(node, p.name) for p in (*msg.new_parameters, *msg.changed_parameters)]
        with self._lock:
            wanted = [n for n in changed if n in self._subscribed_params]
        if not wanted:
            return
        values = {join_name(node, p.name): pv.from_value_msg(p.value)
                  for p in (*msg.new_parameters, *msg.changed_parameters)}
        self.server.publish_parameter_values([_parameter(n, values[n]) for n in wanted])

    # -- services ----------------------------------------------------------------------------------
    def _service(self, verb: str) -> Service:
        req = MessageSchema(encoding="cdr", schema=_schema(TRIGGER + "_Request"))
        rep = MessageSchema(encoding="cdr", schema=_schema(TRIGGER + "_Response"))
        store = typestore.typestore()
        Response = store.types[TRIGGER + "_Response"]

        def handler(request: Any) -> bytes:
            assert self.graph is not None
            try:
                ok, message = self.graph.hw(verb)
            except TransportError as exc:
                raise RuntimeError(str(exc)) from None  # the call fails with this message
            self.node.logger.info(f"{HW_NODE}/{verb} from Foxglove: {message}")
            return bytes(store.serialize_cdr(Response(success=ok, message=message), TRIGGER + "_Response"))

        return Service(f"{HW_NODE}/{verb}", schema=ServiceSchema(TRIGGER, request=req, response=rep), handler=handler)


class _Listener(ServerListener):
    """foxglove-sdk's callbacks (on its threads), handed to the view."""

    def __init__(self, view: ViewServer):
        self.view = view

    def on_subscribe(self, client: Any, channel: Any) -> None:
        self.view.want(channel.topic)

    def on_get_parameters(self, client: Any, param_names: list[str], request_id: str | None = None) -> list[Parameter]:
        return self.view.get_parameters(param_names)

    def on_set_parameters(self, client: Any, parameters: list[Parameter],
                          request_id: str | None = None) -> list[Parameter]:
        return self.view.set_parameters(parameters)

    def on_parameters_subscribe(self, param_names: list[str]) -> None:
        self.view.subscribe_parameters(param_names, True)

    def on_parameters_unsubscribe(self, param_names: list[str]) -> None:
        self.view.subscribe_parameters(param_names, False)

"""A minimal client of the Foxglove WebSocket protocol, written from its specification.

The protocol (github.com/foxglove/ws-protocol, ``docs/spec.md``): after the handshake (subprotocol
:data:`~dem_ros.view.SUBPROTOCOL`) the server sends JSON text messages (``serverInfo``, ``advertise``,
``advertiseServices``, ``parameterValues``, ``status``, ``serviceCallFailure``) and binary ones: opcode 1
= message data (``u32`` subscription id, ``u64`` receive time [ns], payload), opcode 3 = service call
response (``u32`` service id, ``u32`` call id, ``u32`` encoding length, encoding, payload), all
little-endian. The client subscribes with ``{"op": "subscribe", "subscriptions": [{"id", "channelId"}]}``,
asks with ``getParameters`` / ``setParameters`` (an ``id`` to match the answer) and calls a service with
binary opcode 2 (the request's layout).

:class:`FoxgloveClient` is what ``dem-ros view --check`` and the tests use; it knows nothing of the
server's code.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import struct
import time
from dataclasses import dataclass, field
from typing import Any

from . import SUBPROTOCOL

__all__ = ["Channel", "FoxgloveClient", "Sample", "ServiceFailure"]

OP_MESSAGE_DATA = 1
OP_SERVICE_CALL_REQUEST = 2
OP_SERVICE_CALL_RESPONSE = 3


@dataclass(frozen=True)
class Channel:
    """One advertised channel."""

    id: int
    topic: str
    encoding: str
    schema_name: str
    schema_encoding: str
    schema: str


@dataclass(frozen=True)
class Sample:
    """One message: the channel's topic, the server's receive time [ns] and the payload as sent."""

    topic: str
    time_ns: int
    data: bytes


class ServiceFailure(RuntimeError):
    """The server answered a service call with ``serviceCallFailure``; the message is its reason."""


@dataclass
class FoxgloveClient:
    """``async with FoxgloveClient(url) as c: ...``: connects, collects the server's announcements."""

    url: str
    timeout_s: float = 10.0
    server_info: dict[str, Any] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    services: dict[str, dict[str, Any]] = field(default_factory=dict)
    statuses: list[dict[str, Any]] = field(default_factory=list)
    _ws: Any = None
    _subs: dict[int, int] = field(default_factory=dict)  # subscription id -> channel id
    _next_id: int = 1
    _queue: asyncio.Queue | None = None
    _replies: dict[str, asyncio.Future] = field(default_factory=dict)
    _calls: dict[int, asyncio.Future] = field(default_factory=dict)
    _reader: asyncio.Task | None = None
    subprotocol: str | None = None
    #: why the connection ended (the server closed it, e.g. a client too slow for its queue), None while open
    closed: str | None = None

    async def __aenter__(self) -> FoxgloveClient:
        import websockets
        from websockets.typing import Subprotocol

        self._ws = await asyncio.wait_for(websockets.connect(self.url, subprotocols=[Subprotocol(SUBPROTOCOL)],
                                                             max_size=None),
                                          self.timeout_s)
        self.subprotocol = self._ws.subprotocol
        self._queue = asyncio.Queue()
        self._reader = asyncio.create_task(self._read())
        return self

    async def __aexit__(self, *exc: object) -> None:
        import websockets

        if self._reader is not None:
            self._reader.cancel()
        if self._ws is not None:
            # a connection that already ended (the server stopped) has nothing left to close: say nothing,
            # so that what ended the session (an assertion, a timeout) is what the caller sees
            with contextlib.suppress(websockets.ConnectionClosed, TimeoutError, OSError):
                await asyncio.wait_for(self._ws.close(), self.timeout_s)

    async def _read(self) -> None:
        import websockets

        try:
            await self._read_all()
        except websockets.ConnectionClosed as exc:
            self.closed = f"connection closed: {exc}"
        except Exception as exc:  # a message this client cannot read: the session is over, say why
            self.closed = f"client error reading the server's messages: {type(exc).__name__}: {exc}"
        else:
            self.closed = "connection closed by the server"

    async def _read_all(self) -> None:
        assert self._queue is not None
        async for m in self._ws:
            if isinstance(m, bytes):
                op = m[0]
                if op == OP_MESSAGE_DATA:
                    sub, t = struct.unpack_from("<IQ", m, 1)
                    ch = self.channels.get(self._subs.get(sub, -1))
                    self._queue.put_nowait(Sample(ch.topic if ch else "", t, bytes(m[13:])))
                elif op == OP_SERVICE_CALL_RESPONSE:
                    _sid, call, n = struct.unpack_from("<III", m, 1)
                    fut = self._calls.pop(call, None)
                    if fut is not None and not fut.done():
                        fut.set_result(bytes(m[13 + n:]))
                continue
            msg = json.loads(m)
            op = msg.get("op")
            if op == "serverInfo":
                self.server_info = msg
            elif op == "advertise":
                for c in msg["channels"]:
                    self.channels[c["id"]] = Channel(c["id"], c["topic"], c["encoding"], c.get("schemaName", ""),
                                                     c.get("schemaEncoding", ""), c.get("schema", ""))
            elif op == "unadvertise":
                for cid in msg["channelIds"]:
                    self.channels.pop(cid, None)
            elif op == "advertiseServices":
                for s in msg["services"]:
                    self.services[s["name"]] = s
            elif op == "status":
                self.statuses.append(msg)
            elif op == "parameterValues" and msg.get("id") in self._replies:
                self._replies.pop(msg["id"]).set_result(msg["parameters"])
            elif op == "serviceCallFailure":
                fut = self._calls.pop(msg["callId"], None)
                if fut is not None and not fut.done():
                    fut.set_exception(ServiceFailure(msg["message"]))

    async def wait_channels(self, topics: set[str]) -> dict[str, Channel]:
        """The channels of ``topics`` once all are advertised (TimeoutError after ``timeout_s``)."""
        end = time.monotonic() + self.timeout_s
        while True:
            by_topic = {c.topic: c for c in self.channels.values()}
            if topics <= by_topic.keys():
                return {t: by_topic[t] for t in topics}
            if time.monotonic() > end:
                raise TimeoutError(f"channels not advertised within {self.timeout_s:g} s: "
                                   f"{', '.join(sorted(topics - by_topic.keys()))}")
            await asyncio.sleep(0.02)

    def _id(self) -> int:
        self._next_id += 1
        return self._next_id

    async def subscribe(self, channels: list[Channel]) -> None:
        subs = []
        for ch in channels:
            sid = self._id()
            self._subs[sid] = ch.id
            subs.append({"id": sid, "channelId": ch.id})
        await self._ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    async def next_sample(self, timeout_s: float) -> Sample | None:
        """The next message received, or None after ``timeout_s``; ConnectionError once the connection
        ended and every sample received before was taken."""
        assert self._queue is not None
        if self.closed is not None and self._queue.empty():
            raise ConnectionError(self.closed)
        try:
            return await asyncio.wait_for(self._queue.get(), timeout_s)
        except TimeoutError:
            if self.closed is not None:
                raise ConnectionError(self.closed) from None
            return None

    async def _ask(self, msg: dict[str, Any]) -> list[dict[str, Any]]:
        rid = f"r{self._id()}"
        fut: asyncio.Future = asyncio.get_running_loop().create_future()
        self._replies[rid] = fut
        await self._ws.send(json.dumps(msg | {"id": rid}))
        return await asyncio.wait_for(fut, self.timeout_s)

    async def get_parameters(self, names: list[str]) -> dict[str, Any]:
        """``getParameters``: values by name (all the server has for ``[]``)."""
        got = await self._ask({"op": "getParameters", "parameterNames": names})
        return {p["name"]: p.get("value") for p in got}

    async def set_parameters(self, values: dict[str, Any]) -> dict[str, Any]:
        """``setParameters``: the values the server answers with."""
        got = await self._ask({"op": "setParameters",
                               "parameters": [{"name": n, "value": v} for n, v in values.items()]})
        return {p["name"]: p.get("value") for p in got}

    async def call_service(self, name: str, payload: bytes, encoding: str = "cdr") -> bytes:
        """Call service ``name``; its response payload, or ServiceFailure with the server's reason."""
        sid = int(self.services[name]["id"])
        call = self._id()
        fut: asyncio.Future = asyncio.get_running_loop().create_future()
        self._calls[call] = fut
        enc = encoding.encode()
        await self._ws.send(struct.pack("<BIII", OP_SERVICE_CALL_REQUEST, sid, call, len(enc)) + enc + payload)
        return await asyncio.wait_for(fut, self.timeout_s)

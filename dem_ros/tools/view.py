"""``dem-ros view``: watch the running graph live in Foxglove (docs/manual/live-view.md).

    dem-ros view [--port 8765] [--host 127.0.0.1] [--domain-id N] [--transport dds]
        serve the graph on ws://HOST:PORT (the Foxglove app: Open connection -> Foxglove WebSocket);
        layout: config/foxglove/dem_ros.json
    dem-ros view --check SECONDS [--port ...] [--host ...]
        connect to a running view as a client, subscribe to everything, count for SECONDS and say whether
        /dem/measurement arrived in full (>= 95 % of the samples its stamps say were sent; exit 1 if not)

The server runs until Ctrl-C / SIGTERM; it then prints one line ``VIEW {...}`` (JSON: the samples
forwarded per topic). At start it prints ``VIEW {"listening": URL, "port": P}`` once it serves.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import ipaddress
import itertools
import json
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

from .common import UsageError, domain_id

__all__ = ["ViewOptions", "add_arguments", "check", "cmd_view", "main", "port", "serve"]

#: the share of /dem/measurement a check must receive
CHECK_MIN_FRACTION = 0.95
#: the line prefix of the view's structured output (listening, summary)
PREFIX = "VIEW "


@dataclass(frozen=True)
class ViewOptions:
    host: str = "127.0.0.1"
    port: int = 8765
    domain_id: int | None = None
    transport: str = "auto"
    timeout_s: float = 5.0
    check_s: float | None = None
    topics: tuple[str, ...] = ()


def port(text: str) -> int:
    """A TCP port for the server (argparse type)."""
    try:
        v = int(text)
    except ValueError:
        v = -1
    if not 0 <= v <= 65535:
        raise argparse.ArgumentTypeError(f"got {text!r}, expected a TCP port in [0, 65535] (0: any free port)")
    return v


def _seconds(text: str) -> float:
    from .common import seconds

    return seconds(text)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", type=port, default=8765,
                   help="TCP port of the WebSocket server (default 8765; 0: any free)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1, this machine only; another address lets anyone who "
                        "reaches it set parameters and arm / e-stop a rig)")
    p.add_argument("--domain-id", type=domain_id, default=None,
                   help="ROS_DOMAIN_ID of the graph (default: the environment's)")
    p.add_argument("--transport", default="auto", choices=["auto", "rclpy", "dds"],
                   help="how to join the graph (default auto: rclpy when it imports, else dds); parameters and "
                        "services reach nodes on either (the client that reaches each, as dem-ros param)")
    p.add_argument("--timeout", type=_seconds, default=5.0,
                   help="seconds a node has to answer a parameter or service call (default 5, as dem-ros param)")
    p.add_argument("--check", type=_seconds, default=None, metavar="SECONDS",
                   help="be a client instead: count what a running view at --host/--port sends for SECONDS")
    p.add_argument("--topics", default="", metavar="A,B",
                   help="--check: subscribe to these topics only (and /dem/measurement; default: every channel)")


def cmd_view(args: argparse.Namespace) -> int:
    opts = ViewOptions(host=args.host, port=args.port, domain_id=args.domain_id, transport=args.transport,
                       timeout_s=args.timeout, check_s=args.check,
                       topics=tuple(t.strip() for t in args.topics.split(",") if t.strip()))
    if opts.check_s is not None:
        url = f"ws://{_url_host(opts.host)}:{opts.port}"
        return _print_check(asyncio.run(check(url, opts.check_s, topics=opts.topics)))
    return serve(opts)


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


def _loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _rclpy_services() -> object:
    """rclpy's service clients, for the graph's nodes on Fast DDS (see :class:`dem_ros.view.graph.RoutedServices`)."""
    from ..transport.rclpy.client import RclpyServiceClient

    return RclpyServiceClient("dem_ros_view_services")


def serve(opts: ViewOptions, *, stop: threading.Event | None = None) -> int:
    """Run the view until SIGINT / SIGTERM (or ``stop``); 0, or UsageError for what cannot start."""
    try:
        from ..view.server import ViewServer
    except ImportError as exc:
        raise UsageError(f"dem-ros view needs the 'view' extra (pip install 'dem_ros[view]'): {exc}") from None
    from ..nodes import NODES
    from ..transport import TransportError, make_node, rclpy_available
    from ..view.graph import GraphAccess, RoutedServices

    if opts.domain_id is not None:
        os.environ["ROS_DOMAIN_ID"] = str(opts.domain_id)
    stop = stop or threading.Event()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    node = graph = view = None
    try:
        node = make_node("view", transport=opts.transport, args=[])
        graph = GraphAccess(["/" + n for n in NODES if n != "container"], timeout_s=opts.timeout_s,
                            services=RoutedServices(_rclpy_services if rclpy_available() else None))
        view = ViewServer(node, host=opts.host, port=opts.port, graph=graph)
        if graph is not None:
            graph.start()
        url = f"ws://{_url_host(opts.host)}:{view.port}"
        print(f"dem-ros view: serving the graph (ROS_DOMAIN_ID {os.environ.get('ROS_DOMAIN_ID', '0')}, "
              f"transport {node.transport}) on {url}; in Foxglove: Open connection -> Foxglove WebSocket -> {url}, "
              "layout config/foxglove/dem_ros.json", file=sys.stderr, flush=True)
        if not _loopback(opts.host):
            print(f"dem-ros view: WARNING: listening on {opts.host}, not on this machine only: anyone who reaches "
                  f"{url} can watch the run, set the nodes' parameters and arm, disarm or e-stop the hardware",
                  file=sys.stderr, flush=True)
        print(PREFIX + json.dumps({"listening": url, "port": view.port}), flush=True)
        while not stop.is_set() and not node.is_shutdown:
            view.spin_once(0.05)
    except TransportError as exc:
        raise UsageError(str(exc)) from None
    finally:
        if view is not None:
            view.stop()
        if graph is not None:
            graph.stop()
        if node is not None:
            node.shutdown()
        for s, h in previous.items():
            signal.signal(s, h)
    print(PREFIX + json.dumps({"forwarded": view.counts if view is not None else {}}), flush=True)
    return 0


async def check(url: str, seconds: float, *, topics: tuple[str, ...] = (), timeout_s: float = 10.0,
                wait_s: float = 300.0) -> dict[str, Any]:
    """Subscribe to every channel of the view at ``url`` and count for ``seconds`` from the first
    /dem/measurement sample (waited for up to ``wait_s``: a check may start with the graph): counts per
    topic and the /dem/measurement coverage: samples received / samples sent over the window (or over the span
    of the received stamps when longer: a backlog), dt from the stamps. ``topics``: subscribe to these only
    (/dem/measurement always), default all."""
    from .. import contract, typestore
    from ..view.client import FoxgloveClient

    store = typestore.typestore()
    counts: dict[str, int] = {}
    stamps: list[int] = []
    last_gaps: list[float] = []
    client = None
    give_up = time.monotonic() + wait_s
    while client is None:  # a check may start before the view listens (dem-ros launch --view starts it)
        try:
            client = await FoxgloveClient(url, timeout_s=timeout_s).__aenter__()
        except OSError as exc:
            if time.monotonic() > give_up:
                raise UsageError(f"no view at {url} within {wait_s:g} s: {exc}") from None
            await asyncio.sleep(0.2)
    async with contextlib.AsyncExitStack() as stack:
        c = client
        stack.push_async_exit(c.__aexit__)
        await c.wait_channels({contract.MEASUREMENT.name, *topics})
        chosen = {contract.MEASUREMENT.name, *topics}
        await c.subscribe([ch for ch in c.channels.values() if not topics or ch.topic in chosen])
        end = time.monotonic() + wait_s
        first = None
        while (left := end - time.monotonic()) > 0:  # the first sample starts the window
            first = await c.next_sample(left)
            if first is not None and first.topic == contract.MEASUREMENT.name:
                break
        end = time.monotonic() + seconds
        pending = [first] if first is not None else []
        closed = None
        while (left := end - time.monotonic()) > 0:
            try:
                s = pending.pop() if pending else await c.next_sample(left)
            except ConnectionError as exc:
                closed = str(exc)
                break
            if s is None:
                break
            counts[s.topic] = counts.get(s.topic, 0) + 1
            if s.topic == contract.MEASUREMENT.name:
                m: Any = store.deserialize_cdr(s.data, contract.MEASUREMENT.type)
                stamps.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec)
                last_gaps = [float(x) for x in m.position]
    out: dict[str, Any] = {"url": url, "seconds": seconds, "counts": counts, "measurement": None, "closed": closed}
    if len(stamps) >= 2:
        uniq = sorted(set(stamps))
        dt = min(b - a for a, b in itertools.pairwise(uniq))
        sent = max((uniq[-1] - uniq[0]) // max(dt, 1) + 1, round(seconds * 1e9 / max(dt, 1)))
        out["measurement"] = {"received": len(stamps), "sent": int(sent), "fraction": len(uniq) / sent,
                              "dt_ns": int(dt), "last_gaps_m": last_gaps}
    return out


def _print_check(r: dict[str, Any]) -> int:
    print(f"dem-ros view --check: {r['url']}, {r['seconds']:g} s")
    for topic, n in sorted(r["counts"].items()):
        print(f"  {topic:<28} {n:>7} samples  {n / r['seconds']:8.1f} /s")
    if r["closed"]:
        print(f"dem-ros view --check: FAILED: {r['closed']} (a client slower than the streams it asked for)",
              file=sys.stderr)
        return 1
    m = r["measurement"]
    if m is None:
        print("dem-ros view --check: FAILED: fewer than two /dem/measurement samples arrived (is the graph running?)",
              file=sys.stderr)
        return 1
    gaps = " / ".join(f"{g * 1e3:.3f}" for g in m["last_gaps_m"])
    print(f"  /dem/measurement: {m['received']} of {m['sent']} samples sent in the window "
          f"({100 * m['fraction']:.2f} %), last gaps {gaps} mm")
    if m["fraction"] < CHECK_MIN_FRACTION:
        print(f"dem-ros view --check: FAILED: {100 * m['fraction']:.2f} % of /dem/measurement < "
              f"{100 * CHECK_MIN_FRACTION:g} %", file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m dem_ros.tools.view`` (what ``dem-ros launch --view`` starts)."""
    from ..core.params import ConfigError

    p = argparse.ArgumentParser(prog="dem-ros view", description=__doc__.split("\n")[0])
    add_arguments(p)
    args = p.parse_args(argv)
    try:
        return cmd_view(args)
    except (UsageError, ConfigError) as exc:
        print(f"dem-ros view: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 0


if __name__ == "__main__":  # pragma: no cover
    with contextlib.suppress(BrokenPipeError):
        sys.exit(main())

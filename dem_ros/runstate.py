"""Run state of a node process for the process that started it: JSON lines on an inherited pipe.

``dem-ros launch`` opens a pipe, hands its write end to every node process (``pass_fds``) and names it in
the environment (:data:`ENV`). A node then says what the launcher waits for with :func:`announce`: that it
is set up (``ready``), that the board answered (``board``), that the experiment's t = 0 came (``t0``), that
the driver latched a fault (``fault``), that the run is over (``finished``). Each event is one JSON object
on one line (with ``time_ns``, the node's ROS time of the event), written with one ``write`` below ``PIPE_BUF`` bytes
(atomic: several processes share the pipe). Without the variable (a node started by hand or by ``ros2 run``),
:func:`announce` does nothing.

The launcher reads these events, never the nodes' log text (a log line is for people).
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from typing import Any

__all__ = ["ENV", "announce", "parse"]

ENV = "DEM_ROS_RUN_STATE_FD"
_MAX = 4000  # bytes of one event (below PIPE_BUF, 4096 on Linux: the write is atomic)


def announce(event: str, node: str, **values: Any) -> None:
    """Tell the launcher ``event`` of ``node`` (with ``values``: JSON-serialisable); a no-op without it."""
    fd = os.environ.get(ENV)
    if not fd:
        return
    line = json.dumps({"event": event, "node": node, "time_ns": time.time_ns(), **values},
                      default=str)[:_MAX - 1] + "\n"
    with contextlib.suppress(OSError, ValueError):  # the launcher is gone, or not a descriptor of ours
        os.write(int(fd), line.encode())


def parse(buffer: str) -> tuple[list[dict[str, Any]], str]:
    """The complete events in ``buffer`` and the incomplete rest (a line not yet ended)."""
    *lines, rest = buffer.split("\n")
    events = []
    for line in lines:
        try:
            ev = json.loads(line)
        except ValueError:
            continue
        if isinstance(ev, dict) and "event" in ev:
            events.append(ev)
    return events, rest

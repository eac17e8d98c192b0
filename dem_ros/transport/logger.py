"""The node logger of the DDS and in-memory transports (rclpy nodes use rcutils' own).

One line per message on stderr in rcutils' default console format,
``[LEVEL] [sec.nanosec] [logger name]: text``, and each record handed to a sink: the DDS
node publishes it on ``/rosout`` (``rcl_interfaces/msg/Log``), the in-memory bus keeps it
for the test to read. Logging never raises: a sink that fails loses that record only.
"""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Callable
from typing import ClassVar

__all__ = ["NodeLogger", "Sink"]

#: (level name, logger name, text, wall-clock stamp [ns]) -> None
Sink = Callable[[str, str, str, int], None]


class NodeLogger:
    """Implements :class:`dem_ros.transport.api.Logger` for one node.

    ``name()``: the logger name now (a remap may rename the node); ``sink``: where each record
    goes besides stderr; ``echo()``: whether stderr gets the line (default: always).
    """

    #: rcl_interfaces/msg/Log level of each level name
    LEVELS: ClassVar[dict[str, int]] = {"DEBUG": 10, "INFO": 20, "WARN": 30, "ERROR": 40, "FATAL": 50}

    def __init__(self, name: Callable[[], str], sink: Sink | None = None,
                 echo: Callable[[], bool] = lambda: True) -> None:
        self._name = name
        self.sink = sink
        self._echo = echo

    def _log(self, level: str, text: str) -> None:
        t = time.time_ns()
        name = self._name()
        if self._echo():
            sys.stderr.write(f"[{level}] [{t // 10**9}.{t % 10**9:09d}] [{name}]: {text}\n")
            sys.stderr.flush()
        if self.sink is not None:
            with contextlib.suppress(Exception):  # logging must never raise
                self.sink(level, name, text, t)

    def debug(self, msg: str) -> None:
        """Dropped: the nodes log at INFO and above (as rcutils by default)."""

    def info(self, msg: str) -> None:
        self._log("INFO", msg)

    def warn(self, msg: str) -> None:
        self._log("WARN", msg)

    warning = warn

    def error(self, msg: str) -> None:
        self._log("ERROR", msg)

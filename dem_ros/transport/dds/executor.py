"""The DDS transport's executor: one thread runs the callbacks of one or more nodes.

:class:`DdsExecutor` is the shared executor core (:mod:`dem_ros.transport.loop`: rate-monotonic
timers, intra-process delivery inside a container, background nodes, rounds) on one Cyclone DDS
wait set: every reader of every node attached, plus a guard condition. Intra-process DDS
endpoints carry ``IgnoreLocal.Participant`` so the process does not also receive its own
samples over DDS.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Any

from cyclonedds._clayer import ddspy_take
from cyclonedds.core import GuardCondition, InstanceState, SampleState, ViewState, WaitSet

from ..loop import MAX_WAIT_NS, LocalSubscription, LoopExecutor, Member
from ..loop import LoopTimer as DdsTimer

__all__ = ["ANY_SAMPLE", "MAX_WAIT_NS", "DdsExecutor", "DdsTimer", "LocalSubscription", "Member"]

#: take every sample, whatever its sample, view and instance state
ANY_SAMPLE = SampleState.Any | ViewState.Any | InstanceState.Any
_TAKE_N = 256


class DdsExecutor(LoopExecutor):
    """Dispatches the DDS readers, timers and intra-process queue of its nodes on one thread."""

    def __init__(self, participant: Any, *, intra_process: bool = False):
        super().__init__(intra_process=intra_process)
        self.participant = participant
        self.ws = WaitSet(participant.dp)
        self.guard = GuardCondition(participant.dp)
        self.ws.attach(self.guard)
        #: (DataReader ref, handler(data, info), ReadCondition, node)
        self.readers: list[tuple[Any, Callable[[bytes, Any], None], Any, Member]] = []

    def add_reader(self, reader: Any, handler: Callable[[bytes, Any], None], cond: Any, node: Member) -> None:
        self.ws.attach(cond)
        self.readers.append((reader._ref, handler, cond, node))

    def _forget_endpoints(self, node: Member) -> None:
        for entry in [e for e in self.readers if e[3] is node]:
            with contextlib.suppress(Exception):
                self.ws.detach(entry[2])
            self.readers.remove(entry)

    def wake(self) -> None:
        with contextlib.suppress(Exception):
            self.guard.set(True)

    def _wait(self, timeout_ns: int) -> bool:
        if self.ws.wait(timeout_ns):
            self.guard.set(False)
            return True
        return False

    def _take(self) -> None:
        """Run the callbacks of every sample waiting in a DDS reader (in the order the readers were
        made; a background node's samples from other processes are taken here too: deferring them
        made the loop's own reader history overflow behind a hardware driver over serial)."""
        for ref, handler, _cond, node in self.readers:
            while True:
                got = ddspy_take(ref, ANY_SAMPLE, _TAKE_N)
                if isinstance(got, int) or not got:
                    break
                for data, info in got:
                    if info.valid_data and not node.is_shutdown:
                        handler(data, info)
                if len(got) < _TAKE_N:
                    break

"""``dem-ros hw arm|disarm|estop|status``: an operator's requests to the running hardware driver.

The client of the ``hw_driver`` node (:mod:`dem_ros.nodes.hw_driver`), not part of it: requests go on
``/dem/hw/request`` (an e-stop on ``/dem/hw/estop``), and the answer is the driver's latched ``/dem/hw/state``
(docs/manual/hardware.md). It joins the graph through the dds transport, so it needs no ROS
install. :class:`HwClient` keeps one DDS participant for many requests (a test's operator); :func:`request` makes
one of its own for a single request (the command line).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

from .. import contract

__all__ = ["VERBS", "HwClient", "HwOptions", "add_arguments", "cmd_hw", "request"]

#: the requests the driver answers
VERBS = ("arm", "disarm", "estop", "status")
#: what the driver's answer to each request starts with (``HwDriver.arm/disarm/estop``)
_ANSWERS = {"arm": ("armed", "already active"), "disarm": ("disarmed",), "estop": ("e-stop",)}
#: the state's keys ``dem-ros hw`` prints (those present and not empty), in this order
_SHOWN = ("state", "reason", "answer", "board_mode", "t_sim_s", "lost", "late", "corrupt", "hold_samples", "trips",
          "latency_p50_us", "latency_p99_us")


def _check_verb(verb: str) -> None:
    if verb not in VERBS:
        raise ValueError(f"unknown request {verb!r}: {', '.join(VERBS)}")


class HwClient:
    """A client of the running hw_driver (``dem-ros hw``, a test's operator): one DDS participant for all its
    requests, so that discovery (seconds on a loaded host) is paid once, when it is made, not at each request.

    Requests go on ``/dem/hw/request`` (an e-stop on ``/dem/hw/estop``); the answer is the driver's latched
    ``/dem/hw/state`` (its key/values plus ``state`` and ``level``). A request is repeated until the state
    shows the answer (each is idempotent), for at most ``timeout_s``.
    """

    def __init__(self, domain_id: int | None = None):
        import os

        from ..transport import make_node

        if domain_id is not None:
            os.environ["ROS_DOMAIN_ID"] = str(domain_id)
        self.node = make_node("dem_ros_hw", transport="dds", args=[])
        self.states: list = []
        self.node.subscribe(contract.HW_STATE, self.states.append)
        self.pubs = {t.name: self.node.publisher(t) for t in (contract.HW_REQUEST, contract.HW_ESTOP)}
        self.String = self.node.msg("std_msgs/msg/String")

    @staticmethod
    def _values(st) -> dict[str, str]:
        out = {kv.key: kv.value for kv in st.values}
        out["state"] = st.message
        out["level"] = str(contract.status_level(st))
        return out

    def request(self, verb: str, reason: str = "", *, timeout_s: float = 5.0) -> dict[str, str]:
        """``arm``, ``disarm``, ``estop`` or ``status``: the driver's state once it shows the answer.

        Raises:
            ValueError: ``verb`` is none of :data:`VERBS`.
            TimeoutError: no hw_driver answered (or confirmed) within ``timeout_s``.
        """
        _check_verb(verb)
        deadline = time.monotonic() + timeout_s
        node = self.node
        while time.monotonic() < deadline and not self.states:  # discovery: the latched state arrives
            node.spin_once(0.05)
        if not self.states:
            raise TimeoutError(f"no hw_driver answered on {contract.HW_STATE.name} within {timeout_s:g} s")
        if verb == "status":
            node.spin_once(0.05)
            return self._values(self.states[-1])
        msg = self.String()
        msg.data = reason if verb == "estop" else verb
        if verb == "estop" and not reason:
            msg.data = "dem-ros hw estop"
        pub = self.pubs[(contract.HW_ESTOP if verb == "estop" else contract.HW_REQUEST).name]
        seen = len(self.states)  # an answer counts from a state published after the first send
        next_send = 0.0
        while time.monotonic() < deadline:
            if time.monotonic() >= next_send:
                pub.publish(msg)
                next_send = time.monotonic() + 0.3
            node.spin_once(0.05)
            for st in self.states[seen:]:
                v = self._values(st)
                if v.get("answer", "").startswith(_ANSWERS[verb]) or (verb == "estop" and v["state"] == "fault"):
                    return v
            seen = max(seen, len(self.states) - 1)
        raise TimeoutError(f"hw_driver did not confirm '{verb}' within {timeout_s:g} s"
                           f" (state {self._values(self.states[-1])['state']})")

    def close(self) -> None:
        self.node.shutdown()


def request(verb: str, reason: str = "", *, domain_id: int | None = None, timeout_s: float = 5.0) -> dict[str, str]:
    """One request to the running hw_driver (a :class:`HwClient` of its own): its state once it shows the answer.

    Raises:
        ValueError: ``verb`` is none of :data:`VERBS`.
        TimeoutError: no hw_driver answered within ``timeout_s``.
    """
    _check_verb(verb)
    client = HwClient(domain_id)
    try:
        return client.request(verb, reason, timeout_s=timeout_s)
    finally:
        client.close()


@dataclass(frozen=True)
class HwOptions:
    """The options of ``dem-ros hw``."""

    action: str  #: one of :data:`VERBS`
    reason: str = ""  #: estop: why (recorded with the fault)
    domain_id: int | None = None  #: ROS_DOMAIN_ID of the driver (None: the environment's)
    timeout_s: float = 5.0  #: to find the driver and get its answer [s]

    @classmethod
    def from_args(cls, a: argparse.Namespace) -> HwOptions:
        return cls(a.action, a.reason, a.domain_id, a.timeout)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from .common import domain_id

    p.add_argument("action", choices=list(VERBS))
    p.add_argument("reason", nargs="?", default="", help="estop: why (recorded with the fault)")
    p.add_argument("--domain-id", type=domain_id, default=None,
                   help="ROS_DOMAIN_ID of the driver (default: the environment's)")
    p.add_argument("--timeout", type=float, default=5.0,
                   help="seconds to find the driver and get its answer (default 5)")


def cmd_hw(args: argparse.Namespace) -> int:
    """Print the driver's state once it shows the answer; exit status 1 when it is in fault (but after an
    ``estop``), 2 (a one-line error) when no driver answered."""
    from .common import UsageError

    o = HwOptions.from_args(args)
    try:
        v = request(o.action, o.reason, domain_id=o.domain_id, timeout_s=o.timeout_s)
    except TimeoutError as exc:
        raise UsageError(str(exc)) from None
    for k in _SHOWN:
        if v.get(k, "") != "":
            print(f"  {k:<16} {v[k]}")
    return 0 if v["state"] != "fault" or o.action == "estop" else 1

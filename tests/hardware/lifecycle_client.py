"""A lifecycle client of ``/hw_driver`` in a process of its own (``python lifecycle_client.py rclpy|dds|nodes DOMAIN``).

``rclpy``: a stock client, plain rclpy and the Jazzy wheels' lifecycle_msgs / diagnostic_msgs on Fast DDS, as
``ros2 lifecycle get|list|set`` calls the node. ``dds``: the project's dds client (rmw_cyclonedds' wire), for a
node on the dds transport: a Fast DDS client's service calls do not reach a Cyclone DDS node (the request id
travels differently, docs/manual/transports.md), so a stock client there would be ``ros2 lifecycle`` under
``RMW_IMPLEMENTATION=rmw_cyclonedds_cpp``, which the wheels do not have.

The sequence: wait until the plate levitates (``/dem/hw/state``: driver active, board RUN), get_state,
get_available_transitions, change_state deactivate (answered once the board has landed the plate), get_state,
change_state activate, get_state, wait until the board runs the controller's commands again. Each step is a
``STEP {json}`` line; the last line is ``RESULT {json}`` with every step, the transition events heard and an
``error`` if one came.

``nodes``: what ``ros2 lifecycle nodes`` does, with stock rclpy on Fast DDS (the graph crosses vendors, the
service calls do not): the nodes that serve ``<node>/get_state`` of type ``lifecycle_msgs/srv/GetState``, and
``/hw_driver``'s lifecycle services with their types (``RESULT {json}``).
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable
from typing import Any

T0 = time.monotonic()


class RclpyClient:
    def __init__(self, domain: int) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticStatus
        from lifecycle_msgs.msg import TransitionEvent
        from lifecycle_msgs.srv import ChangeState, GetAvailableTransitions, GetState
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        self.rclpy = rclpy
        rclpy.init(args=[], domain_id=domain)
        self.node = rclpy.create_node("stock_lifecycle_client")
        self.ex = SingleThreadedExecutor()
        self.ex.add_node(self.node)
        self.ChangeState, self.GetState, self.GetAvailable = ChangeState, GetState, GetAvailableTransitions
        self.clients = {"get_state": self.node.create_client(GetState, "/hw_driver/get_state"),
                        "change_state": self.node.create_client(ChangeState, "/hw_driver/change_state"),
                        "get_available_transitions": self.node.create_client(
                            GetAvailableTransitions, "/hw_driver/get_available_transitions")}
        self.heard: list[dict[str, Any]] = []
        self.node.create_subscription(TransitionEvent, "/hw_driver/transition_event", self._event, 10)
        self.latest: dict[str, str] = {}
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.node.create_subscription(DiagnosticStatus, "/dem/hw/state", self._hw, latched)

    def _event(self, m: Any) -> None:
        self.heard.append({"id": m.transition.id, "label": m.transition.label, "start": m.start_state.label,
                           "goal": m.goal_state.label})

    def _hw(self, m: Any) -> None:
        self.latest = {kv.key: kv.value for kv in m.values} | {"state": m.message}

    def spin(self, s: float) -> None:
        self.ex.spin_once(timeout_sec=s)

    def ready(self) -> bool:
        return all(c.service_is_ready() for c in self.clients.values())

    def _call(self, name: str, req: Any, timeout_s: float) -> Any:
        fut = self.clients[name].call_async(req)
        end = time.monotonic() + timeout_s
        while not fut.done() and time.monotonic() < end:
            self.spin(0.01)
        if not fut.done():
            raise TimeoutError(f"/hw_driver/{name}: no answer within {timeout_s:g} s")
        return fut.result()

    def get_state(self) -> tuple[int, str]:
        s = self._call("get_state", self.GetState.Request(), 10.0).current_state
        return int(s.id), str(s.label)

    def available(self) -> list[str]:
        return [t.transition.label for t in
                self._call("get_available_transitions", self.GetAvailable.Request(), 10.0).available_transitions]

    def change(self, tid: int, timeout_s: float) -> bool:
        req = self.ChangeState.Request()
        req.transition.id = tid
        return bool(self._call("change_state", req, timeout_s).success)

    def close(self) -> None:
        self.node.destroy_node()
        self.rclpy.shutdown()


class DdsClient:
    def __init__(self, domain: int) -> None:
        from dem_ros import contract
        from dem_ros.transport import make_node
        from dem_ros.transport.dds import client
        from dem_ros.transport.dds import lifecycle_msgs as lm
        from dem_ros.transport.lifecycle import event_topic

        self.lm, self.client, self.domain = lm, client, domain
        self.node = make_node("dds_lifecycle_client", transport="dds", args=[])
        self.heard: list[dict[str, Any]] = []
        self.node.subscribe(event_topic("/hw_driver"), self._event)
        self.latest: dict[str, str] = {}
        self.node.subscribe(contract.HW_STATE, self._hw)

    def _event(self, m: Any) -> None:
        self.heard.append({"id": m.transition.id, "label": m.transition.label, "start": m.start_state.label,
                           "goal": m.goal_state.label})

    def _hw(self, m: Any) -> None:
        self.latest = {kv.key: kv.value for kv in m.values} | {"state": m.message}

    def spin(self, s: float) -> None:
        self.node.spin_once(s)

    def ready(self) -> bool:
        try:
            self.get_state(timeout_s=0.5)
        except Exception:
            return False
        return True

    def _call(self, srv: str, srv_type: str, req: Any, timeout_s: float) -> Any:
        rep = self.client.call_service("/hw_driver", srv, req, srv_type=srv_type, domain_id=self.domain,
                                       timeout_s=timeout_s)
        self.spin(0.0)
        return rep

    def get_state(self, timeout_s: float = 10.0) -> tuple[int, str]:
        s = self._call("get_state", "lifecycle_msgs/srv/GetState", self.lm.GetState_Request(), timeout_s).current_state
        return int(s.id), str(s.label)

    def available(self) -> list[str]:
        rep = self._call("get_available_transitions", "lifecycle_msgs/srv/GetAvailableTransitions",
                         self.lm.GetAvailableTransitions_Request(), 10.0)
        return [t.transition.label for t in rep.available_transitions]

    def change(self, tid: int, timeout_s: float) -> bool:
        req = self.lm.ChangeState_Request(transition=self.lm.Transition(id=tid, label=""))
        return bool(self._call("change_state", "lifecycle_msgs/srv/ChangeState", req, timeout_s).success)

    def close(self) -> None:
        self.node.shutdown()


def wait(c: Any, cond: Callable[[], bool], timeout_s: float, what: str) -> None:
    end = time.monotonic() + timeout_s
    while not cond() and time.monotonic() < end:
        c.spin(0.05)
    if not cond():
        raise TimeoutError(f"{what} not within {timeout_s:g} s (driver: {c.latest})")


def lifecycle_nodes(domain: int) -> int:
    """``ros2 lifecycle nodes`` (ros2lifecycle's ``_get_lifecycle_node_names``) and /hw_driver's services."""
    import rclpy

    rclpy.init(args=[], domain_id=domain)
    node = rclpy.create_node("stock_lifecycle_nodes")
    out: dict[str, Any] = {}
    end = time.monotonic() + 60.0
    while time.monotonic() < end:
        services = dict(node.get_service_names_and_types())
        names = [f"{ns.rstrip('/')}/{n}" for n, ns in node.get_node_names_and_namespaces()]
        out = {"nodes": sorted(n for n in names if "lifecycle_msgs/srv/GetState" in services.get(f"{n}/get_state", [])),
               "services": {k: v for k, v in services.items() if k.startswith("/hw_driver/")
                            and any(t.startswith("lifecycle_msgs/") for t in v)}}
        # the node's name comes from its participant's ros_discovery_info, which may trail its endpoints
        if len(out["services"]) == 5 and "/hw_driver" in out["nodes"]:
            break
        time.sleep(0.2)
    print("RESULT " + json.dumps(out), flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


def main() -> int:
    via, domain = sys.argv[1], int(sys.argv[2])
    if via == "nodes":
        return lifecycle_nodes(domain)
    c = RclpyClient(domain) if via == "rclpy" else DdsClient(domain)
    out: dict[str, Any] = {"steps": []}

    def step(what: str, **kw: Any) -> None:
        out["steps"].append({"what": what, "t": round(time.monotonic() - T0, 2), **kw})
        print("STEP " + json.dumps(out["steps"][-1]), flush=True)

    def hw() -> dict[str, str]:
        return {k: c.latest.get(k, "") for k in ("state", "board_mode", "lifecycle")}

    def levitating() -> bool:
        return c.latest.get("state") == "active" and c.latest.get("board_mode") == "run"

    try:
        wait(c, c.ready, 120.0, "the lifecycle services")
        wait(c, levitating, 180.0, "a levitating plate")
        step("levitating", lifecycle=c.get_state(), hw=hw())
        step("available", transitions=c.available())
        t = time.monotonic()
        ok = c.change(4, 60.0)
        step("deactivate", success=ok, s=round(time.monotonic() - t, 2), lifecycle=c.get_state())
        wait(c, lambda: c.latest.get("lifecycle") == "inactive", 10.0, "/dem/hw/state inactive")
        step("landed", hw=hw())
        ok = c.change(3, 30.0)
        step("activate", success=ok, lifecycle=c.get_state())
        wait(c, levitating, 120.0, "the plate levitating again")
        step("levitating again", lifecycle=c.get_state(), hw=hw())
        c.spin(0.5)
    except Exception as exc:
        out["error"] = repr(exc)
    out["events"] = c.heard
    print("RESULT " + json.dumps(out), flush=True)
    c.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())

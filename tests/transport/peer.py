"""Child-process roles for the transport tests (run as ``python peer.py ROLE ...``).

Every role uses the DDS transport through the public API only.
"""

import json
import sys
import time

from dem_ros import contract
from dem_ros.transport import make_node, run_node


def talker(n: int, tag: str) -> None:
    node = make_node(f"talker_{tag}", transport="dds", args=[])
    pub = node.publisher(contract.MEASUREMENT)
    JointState = node.msg("sensor_msgs/msg/JointState")
    t_end = time.monotonic() + 15
    while pub.subscription_count == 0 and time.monotonic() < t_end:
        node.spin_once(0.01)
    print("MATCHED", flush=True)
    node.spin_once(0.2)  # let the readers' side of discovery settle too
    sent = [0]

    def tick() -> None:
        if sent[0] >= n:
            node.shutdown()
            return
        m = JointState(name=list(contract.MAGNETS), position=[0.008, 0.008], velocity=[0.0, 0.0], effort=[1.0, 1.0])
        t = node.now_ns()
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(t, 10**9)
        pub.publish(m)
        sent[0] += 1

    node.timer(0.001, tick)
    node.spin()
    print(json.dumps({"sent": sent[0]}), flush=True)


def listener(n: int, tag: str) -> None:
    node = make_node(f"listener_{tag}", transport="dds", args=[])
    lat = []

    def cb(m) -> None:
        lat.append(time.time_ns() - (m.header.stamp.sec * 10**9 + m.header.stamp.nanosec))
        if len(lat) >= n:
            node.shutdown()

    node.subscribe(contract.MEASUREMENT, cb)
    print("READY", flush=True)
    t_end = time.monotonic() + 20
    c0 = time.process_time()
    while not node.is_shutdown and time.monotonic() < t_end:
        node.spin_once(0.1)
    cpu = time.process_time() - c0
    node.shutdown()
    lat.sort()
    out = {"count": len(lat), "cpu_s": cpu}
    if lat:
        lat_us = [x / 1000 for x in lat[len(lat) // 10:]]  # drop the first 10 % (warm-up)
        lat_us.sort()
        out.update(p50_us=lat_us[len(lat_us) // 2], p99_us=lat_us[int(len(lat_us) * 0.99)], max_us=lat_us[-1])
    print("STATS " + json.dumps(out), flush=True)


def params(args: list) -> int:
    def setup(node) -> None:
        def on_change(v):
            if v["k1"] > 500:
                return f"k1={v['k1']:g} is too aggressive for this rig"
            return None

        values = node.declare_parameters("controller", on_change)
        node.publisher(contract.COMMAND)
        print("READY " + json.dumps({"k1": values["k1"], "name": node.fully_qualified_name}), flush=True)

    return run_node("controller", setup, args=args, transport="dds")


def idle(args: list) -> int:
    def setup(node) -> None:
        node.subscribe(contract.COMMAND, lambda m: None)
        node.timer(1.0, lambda: None)
        c0 = time.process_time()
        w0 = time.monotonic()

        def report() -> None:
            print("IDLE " + json.dumps({"cpu_s": time.process_time() - c0, "wall_s": time.monotonic() - w0}),
                  flush=True)

        node.timer(2.0, report)
        print("READY", flush=True)

    return run_node("idle", setup, args=args, transport="dds")


def services(args: list) -> int:
    """Trigger / SetBool services, one of which raises, and a subscription and a timer that raise."""
    state = {"armed": False, "enabled": False, "got": 0}

    def setup(node) -> None:
        def arm(req, rep):
            state["armed"] = True
            rep.success, rep.message = True, "armed"
            return rep

        def enable(req, rep):
            state["enabled"] = bool(req.data)
            rep.success, rep.message = True, f"enabled={state['enabled']}"
            return rep

        def broken(req, rep):
            raise RuntimeError("the board did not answer")

        def bad_sub(msg):
            state["got"] += 1
            raise ValueError(f"bad sample {state['got']}")

        node.service("arm", "std_srvs/srv/Trigger", arm)
        node.service("enable", "std_srvs/srv/SetBool", enable)
        node.service("broken", "std_srvs/srv/Trigger", broken)
        node.subscribe(contract.COMMAND, bad_sub)
        node.timer(0.01, lambda: 1 / 0)
        node.timer(0.5, lambda: print("ERRORS " + json.dumps({**node.callback_errors, **state}), flush=True))
        print("READY " + node.fully_qualified_name, flush=True)

    return run_node("svc", setup, args=args, transport="dds")


if __name__ == "__main__":
    role = sys.argv[1]
    if role == "talker":
        talker(int(sys.argv[2]), sys.argv[3])
    elif role == "listener":
        listener(int(sys.argv[2]), sys.argv[3])
    elif role == "params":
        sys.exit(params(sys.argv[2:]))
    elif role == "idle":
        sys.exit(idle(sys.argv[2:]))
    elif role == "services":
        sys.exit(services(sys.argv[2:]))
    else:
        raise SystemExit(f"unknown role {role}")

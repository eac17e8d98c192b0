"""Services (std_srvs Trigger / SetBool) and callback errors on the DDS transport, across real processes."""

import json
import signal
import time

from dem_ros import contract
from dem_ros.transport import make_node, set_bool, trigger


def test_trigger_and_set_bool_served_and_called_over_dds(domain_id, spawn, wait_line):
    proc = spawn(domain_id, "services", "--ros-args", "-r", f"__node:=svc_{domain_id}")
    fqn = wait_line(proc, "READY ", timeout=30)
    assert fqn == f"/svc_{domain_id}"
    assert trigger(fqn, "arm", timeout_s=10) == (True, "armed")
    assert set_bool(fqn, "enable", True, timeout_s=10) == (True, "enabled=True")
    assert set_bool(fqn, "enable", False, timeout_s=10) == (True, "enabled=False")
    ok, message = trigger(fqn, "broken", timeout_s=10)  # the callback raised: a failure answer, not a dead node
    assert not ok and message == "RuntimeError: the board did not answer"

    # a subscription whose callback raises on every message, and a timer that raises every 10 ms
    node = make_node(f"feeder_{domain_id}", transport="dds", args=[])
    try:
        pub = node.publisher(contract.COMMAND)
        end = time.monotonic() + 20
        while pub.subscription_count < 1 and time.monotonic() < end:
            node.spin_once(0.05)
        JS = node.msg("sensor_msgs/msg/JointState")
        for _ in range(20):
            pub.publish(JS(name=list(contract.MAGNETS), effort=[1.0, 2.0]))
            node.spin_once(0.01)
        errors = {}
        end = time.monotonic() + 20
        while errors.get("got", 0) < 20 and time.monotonic() < end:
            errors = json.loads(wait_line(proc, "ERRORS ", timeout=20))
    finally:
        node.shutdown()
    assert errors["got"] == 20 and errors[f"subscription {contract.COMMAND.name}"] == 20
    assert errors["timer 0.01 s"] > 5 and errors[f"service {fqn}/broken"] == 1
    assert errors["armed"] and not errors["enabled"]
    assert trigger(fqn, "arm", timeout_s=10) == (True, "armed")  # still serving
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=10) == 0
    err = proc.stderr.read()
    # each failing callback is logged once, with the topic / service / timer it belongs to
    assert err.count(f"callback for subscription {contract.COMMAND.name} raised ValueError: bad sample 1") == 1
    assert "bad sample 2" not in err
    assert err.count("callback for timer 0.01 s raised ZeroDivisionError") == 1
    assert err.count(f"callback for service {fqn}/broken raised RuntimeError") == 1

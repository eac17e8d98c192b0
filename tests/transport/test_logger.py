"""The node logger (transport/logger.py): one line on stderr per message, and the record on /rosout (DDS) or
the bus's log (memory), at the rcl_interfaces/msg/Log level of its severity."""

import time

from dem_ros.contract import Topic
from dem_ros.transport import make_node
from dem_ros.transport.dds.node import QOS_ROSOUT
from dem_ros.transport.logger import NodeLogger
from dem_ros.transport.memory import MemoryBus

ROSOUT = Topic("/rosout", "rcl_interfaces/msg/Log", QOS_ROSOUT, None, "every node", (), "log records")


def test_a_dds_node_logs_on_stderr_and_publishes_on_rosout(domain_id, capfd):
    talker = make_node(f"talker_{domain_id}", transport="dds", args=[])
    listener = make_node(f"listener_{domain_id}", transport="dds", args=[])
    got = []
    listener.subscribe(ROSOUT, lambda m: got.append(m) if m.name == f"talker_{domain_id}" else None)
    try:
        talker.logger.warn("low battery")  # transient-local: the listener gets it however late it matches
        talker.logger.error("rail contact")
        end = time.monotonic() + 60
        while len(got) < 2 and time.monotonic() < end:
            listener.spin_once(0.1)
    finally:
        talker.shutdown()
        listener.shutdown()
    assert [(m.level, m.msg) for m in got[:2]] == [(30, "low battery"), (40, "rail contact")]
    err = capfd.readouterr().err
    assert "[WARN] [" in err and f"] [talker_{domain_id}]: low battery" in err


def test_a_memory_node_keeps_its_records_on_the_bus():
    bus = MemoryBus(echo=False)
    node = bus.node("ctl")
    node.logger.info("ready")
    node.logger.error("fault")
    assert bus.log == [("INFO", "/ctl", "ready"), ("ERROR", "/ctl", "fault")]


def test_a_failing_sink_loses_only_its_record(capfd):
    def sink(level, name, text, t_ns):
        raise OSError("disk full")

    log = NodeLogger(lambda: "n", sink)
    log.info("still printed")
    assert "[INFO] [" in capfd.readouterr().err

"""The graph's own writers for tests on the in-memory bus: every loop input is bound to its source node's writer
(nodes/common.Binding), so a test's stimulus is published by a node of the source's name, as the graph does."""

from __future__ import annotations

from typing import Any

from dem_ros import contract

#: the node that writes each loop input (contract.TOPICS: publisher)
WRITERS = {contract.MEASUREMENT.name: "plant_sim", contract.APPLIED.name: "plant_sim",
           contract.ESTIMATE.name: "estimator", contract.REFERENCE.name: "reference",
           contract.COMMAND.name: "controller"}
#: the 1 kHz topics each node publishes (contract.TOPICS: publisher), each with its "<node>: <topic> topic status"
STREAMS = {"plant_sim": (contract.MEASUREMENT, contract.APPLIED, contract.TRUTH),
           "hw_driver": (contract.MEASUREMENT, contract.APPLIED), "estimator": (contract.ESTIMATE,),
           "reference": (contract.REFERENCE,), "controller": (contract.COMMAND, contract.CONTROLLER_STATE)}


def publish(bus: Any, topic: contract.Topic, msg: Any) -> None:
    """Publish ``msg`` on ``topic`` from the writer of its source node (made once per bus and topic); topics
    without a bound source go out as ``bus.publish`` does."""
    name = WRITERS.get(topic.name)
    if name is None:
        bus.publish(topic, msg)
        return
    pubs = bus.__dict__.setdefault("_test_writers", {})
    pub = pubs.get(topic.name)
    if pub is None:
        nodes = bus.__dict__.setdefault("_test_nodes", {})
        node = nodes.get(name) or nodes.setdefault(name, bus.node(name))
        pub = pubs[topic.name] = node.publisher(topic)
    pub.publish(msg)

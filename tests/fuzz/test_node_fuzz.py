"""Fuzz through the node callbacks: 10^4 seeded mutated CDR samples per subscribed topic of each loop node, on
the in-memory transport (the nodes' real code, their real decode path, no middleware).

Each sample is either rejected by the decoder (``CdrError``, counted by the
transport as on DDS) or decoded and delivered to the node's callback. The
assertion is the transport's promise: nothing escapes (0 uncaught). What the
node's callbacks raised (caught, counted per callback by the transport's
guard) is printed: input validation inside the nodes is their owners' work.
"""

from __future__ import annotations

import os
import random
import sys
from pathlib import Path

import pytest

from dem_ros import contract
from dem_ros.transport.dds import fastcdr, msgs
from dem_ros.transport.memory import MemoryBus

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cdrfuzz import mutate, random_message

N = int(os.environ.get("DEM_ROS_FUZZ_N", "10000"))  # 10^4 by default; smaller only for a quick look
SEED = 20261124


def _nodes():
    from dem_ros.nodes.controller import ControllerNode
    from dem_ros.nodes.estimator import EstimatorNode
    from dem_ros.nodes.plant_sim import PlantSimNode
    from dem_ros.nodes.reference import ReferenceNode

    return {
        "estimator": (EstimatorNode, [contract.MEASUREMENT, contract.APPLIED]),
        "controller": (ControllerNode, [contract.REFERENCE, contract.APPLIED, contract.ESTIMATE]),
        "reference": (ReferenceNode, [contract.MEASUREMENT]),
        "plant_sim": (PlantSimNode, [contract.COMMAND]),
    }


def _plausible(bus: MemoryBus, k: int, rng: random.Random) -> bytes:
    """A JointState as the graph sends it (two magnets near hover, a current stamp), or a random one."""
    if rng.random() < 0.3:
        return random_message(msgs.JointState, rng).serialize()
    t = bus.now_ns + k * 1_000_000
    m = msgs.JointState(header=msgs.Header(stamp=msgs.Time(sec=t // 10**9, nanosec=t % 10**9), frame_id="dem"),
                        name=["magnet_1", "magnet_2"], position=[0.008 + 1e-5 * rng.random(), 0.008],
                        velocity=[0.0, 0.0], effort=[4.0 + rng.random(), 4.0])
    return fastcdr.encode_joint_state(m)


@pytest.mark.parametrize("name", ["estimator", "controller", "reference", "plant_sim"])
def test_mutated_samples_through_the_node_callbacks_never_escape(name, capsys):
    cls, topics = _nodes()[name]
    bus = MemoryBus()
    node = bus.node(name)
    cls(node)
    source = bus.node("fuzzer")
    pubs = [source.publisher(t) for t in topics]
    rng = random.Random(SEED + sum(map(ord, name)))
    uncaught: list[tuple[str, bytes, BaseException]] = []
    rejected = delivered = 0
    for pub, topic in zip(pubs, topics, strict=True):
        for k in range(N):
            data = mutate(_plausible(bus, k, rng), rng)
            try:
                pub.publish_raw(data)  # the memory bus decodes here, for the node's subscription
            except fastcdr.CdrError:
                rejected += 1
                continue
            except Exception as e:
                uncaught.append((topic.name, data, e))
                continue
            try:
                delivered += bus.spin_once()
            except Exception as e:
                uncaught.append((topic.name, data, e))
            if k % 1000 == 999:
                bus.advance(0.001)  # timers (diagnostics) run too
    errors = node.callback_errors
    with capsys.disabled():
        print(f"\n{name}: {len(topics) * N} mutated samples, {rejected} rejected by the decoder, {delivered} "
              f"callbacks run, exceptions caught in callbacks: {dict(errors) or 'none'}")
    assert not uncaught, f"{len(uncaught)} escaped, e.g. {uncaught[:2]!r}"
    assert rejected > N // 2 and delivered > N // 20

"""The plant's command source lock on the in-memory transport (the real node code, a manual clock): it waits for
the configured controller's /dem/command writer before its run starts, takes commands only from that writer,
and drops, counts and reports (WARN on /diagnostics, one log line) commands from any other writer."""

from __future__ import annotations

import time

import pytest

from dem_ros import contract
from dem_ros.core.params import ConfigError
from dem_ros.nodes.common import WARN, joint_state, stamp_ns
from dem_ros.nodes.plant_sim import PlantSimNode
from dem_ros.transport.memory import MemoryBus

ARGS = ["--ros-args", "-p", "start_delay:=0.0", "-p", "min_subscribers:=0", "-p", "preroll:=0.05",
        "-p", "lockstep:=true"]


def _level(st) -> int:
    return st.level if isinstance(st.level, int) else int.from_bytes(bytes(st.level), "little")


def _graph(*extra: str, source_name: str = "controller"):
    bus = MemoryBus()
    plant = PlantSimNode(bus.node("plant_sim", [*ARGS, *extra]))
    u0 = plant.plant.u0.tolist()
    JS = bus.msg("sensor_msgs/msg/JointState")
    ctl, rogue = bus.node(source_name), bus.node("rogue")
    p_ctl, p_rogue = ctl.publisher(contract.COMMAND), rogue.publisher(contract.COMMAND)
    applied: list[list[float]] = []
    diags: list[tuple[int, str, dict[str, str]]] = []

    def on_meas(m):  # the rogue answers first with 1e6 V, then the controller with the hover voltage
        t = stamp_ns(m)
        p_rogue.publish(joint_state(JS, t, effort=(1e6, 1e6)))
        p_ctl.publish(joint_state(JS, t, effort=u0))

    ctl.subscribe(contract.MEASUREMENT, on_meas)
    probe = bus.node("probe")
    probe.subscribe(contract.APPLIED, lambda m: applied.append(list(m.effort)))
    probe.subscribe(contract.DIAGNOSTICS, lambda m: diags.extend(
        (_level(s), s.message, {kv.key: kv.value for kv in s.values}) for s in m.status if s.name == contract.LOOP_STATUS))
    return bus, plant, u0, applied, diags


def _run(bus, applied, n: int) -> None:
    """Until ``n`` samples were applied: the plant paces its samples on the wall clock, the bus runs its timers."""
    end = time.monotonic() + 60.0
    while len(applied) < n and time.monotonic() < end:
        bus.advance(0.001)


def test_a_rogue_1e6_volt_command_changes_nothing_and_is_reported():
    bus, plant, u0, applied, diags = _graph()
    _run(bus, applied, 300)  # 50 ms pre-roll, then 250 samples of the run
    bus.advance(1.0)  # a diagnostics report
    assert plant.started and len(applied) >= 300
    assert all(a == pytest.approx(u0, abs=1e-9) for a in applied), max(max(a) for a in applied)
    n = plant.source.foreign
    assert n >= 250 and plant.source.values()["command_writers"] == 1
    warn = [d for d in diags if d[0] == WARN and "commands_foreign +" in d[1]]
    assert warn and int(warn[0][2]["commands_foreign"]) > 0, diags
    logged = [line for line in bus.log if "/dem/command from writer" in line[2]]
    assert len(logged) == 1 and "not 'controller'" in logged[0][2]  # once per writer, then counted


def test_the_run_waits_for_the_command_source():
    bus, plant, _u0, applied, diags = _graph(source_name="someone_else")  # no node named "controller"
    bus.advance(2.0)
    assert not plant.started and applied == []
    assert diags and all(d[0] == WARN and d[1] == "waiting for 'controller''s /dem/command writer" for d in diags)


def test_a_renamed_controller_is_configured_and_bad_names_are_refused():
    bus, plant, u0, applied, _ = _graph("-p", "command_source:=/ctl2", source_name="ctl2")
    _run(bus, applied, 100)
    assert plant.started and applied and all(a == pytest.approx(u0, abs=1e-9) for a in applied)
    with pytest.raises(ConfigError, match="not a ROS node name"):
        PlantSimNode(MemoryBus().node("plant_sim", ["--ros-args", "-p", "command_source:=a b"]))
    assert "command_source" in (plant.node.set_parameters({"command_source": "rogue"}) or "")  # read-only


def _count_lookups(node) -> list[int]:
    """Count ``node.publisher_gids`` calls (the graph look-ups of a CommandSource) in the returned [n]."""
    n = [0]
    real = node.publisher_gids

    def counted(topic, name):
        n[0] += 1
        return real(topic, name)

    node.publisher_gids = counted
    return n


def test_a_restarted_controller_is_accepted_as_soon_as_the_graph_lists_it():
    """Review defect: an unknown writer was looked up at most every refresh_s (0.1 s), so a restarted
    controller, whose graph information trails its first samples by a few ms, lost ~100 ms of commands
    (> hold_timeout 50 ms: the board landed). Now an unknown writer is looked up on its sample, a writer
    found foreign again after retry_s, then after twice as long each time (a look-up reads the graph: too
    dear for every sample of a foreign 1 kHz writer): the graph lists the new controller 5 ms after its
    first command, and it is accepted at the latest one doubling later, 5 ms + retry_s after the listing
    (whatever the machine's load)."""
    from dem_ros.nodes.common import CommandSource

    bus = MemoryBus()
    plant = bus.node("plant_sim")
    cs = CommandSource(plant, "controller")
    old = bus.node("controller")
    p_old = old.publisher(contract.COMMAND)
    assert cs.accepts(p_old.gid)
    old.shutdown()
    new = bus.node("controller")
    p_new = new.publisher(contract.COMMAND)
    entry = next(w for w in bus.writers if w[2] is p_new)
    bus.writers.remove(entry)  # its graph information has not arrived yet
    lookups = _count_lookups(plant)
    t0 = time.monotonic()
    t_graph = None
    sent = []  # (time sent, accepted)
    while time.monotonic() - t0 < 0.2 and not (sent and sent[-1][1]):
        now = time.monotonic()
        if t_graph is None and now - t0 >= 0.005:
            bus.writers.append(entry)  # the graph lists it now
            t_graph = now
        sent.append((now, cs.accepts(p_new.gid)))
        time.sleep(0.001)
    assert t_graph is not None and sent[-1][1], "never accepted"
    first = next(t for t, ok in sent if ok)
    before = [t for t, ok in sent if t < t_graph]
    assert not any(ok for t, ok in sent if t < t_graph)  # unknown to the graph: foreign
    # accepted at the latest one doubling after the listing: the waits 2, 4, 8 ms... sum to the time waited
    late = t_graph + (t_graph - t0) + cs.retry_s
    assert all(ok for t, ok in sent if t >= late) and first >= t_graph
    assert lookups[0] <= min(len(before) + 2, 8)  # at most one per sample, and a doubling wait between them
    assert cs.foreign == sum(not ok for _, ok in sent)
    print(f"graph info 5 ms after the first command; first accepted {(first - t_graph) * 1e3:.1f} ms after it,"
          f" {cs.foreign} commands dropped, {lookups[0]} look-ups")


def test_a_persistent_foreign_writer_costs_few_graph_lookups():
    """A foreign writer at 1 kHz for 1 s: every sample dropped and counted, the graph read about
    log2(refresh_s / retry_s) + 1 s / refresh_s times, not a thousand (each read walks the DDS
    graph: at 1 kHz it starved a loaded plant into a landing)."""
    from dem_ros.nodes.common import CommandSource

    bus = MemoryBus()
    plant = bus.node("plant_sim")
    cs = CommandSource(plant, "controller")
    rogue = bus.node("rogue").publisher(contract.COMMAND)
    lookups = _count_lookups(plant)
    t0 = time.monotonic()
    n = 0
    while time.monotonic() - t0 < 1.0:
        assert not cs.accepts(rogue.gid)
        n += 1
        time.sleep(0.001)
    assert cs.foreign == n
    assert lookups[0] <= 7 + 1.0 / cs.refresh_s + 2, lookups  # 2, 4, ..., 64 ms, then every 100 ms

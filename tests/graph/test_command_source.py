"""The plant's command source lock on the in-memory transport (the real node code, a manual clock): it waits for
the configured controller's /dem/command writer before its run starts, takes commands only from that writer,
refuses, counts and reports (WARN on the loop status, ERROR on the inputs status, one log line) commands from
any other writer, and holds (never drops) the commands of a controller whose graph information comes late."""

from __future__ import annotations

import time

import pytest

from dem_ros import contract
from dem_ros.core.params import ConfigError
from dem_ros.nodes.common import ERROR, WARN, joint_state, stamp_ns
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
        (_level(s), s.message, {kv.key: kv.value for kv in s.values})
        for s in m.status if s.name == contract.LOOP_STATUS))
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
    assert n >= 250 and plant.source.values()["command_writer"] == plant.source.binding.bound.hex() != ""
    warn = [d for d in diags if d[0] == WARN and "commands_foreign +" in d[1]]
    assert warn and int(warn[0][2]["commands_foreign"]) > 0, diags
    logged = [line for line in bus.log if "/dem/command from writer" in line[2]]
    assert len(logged) == 1 and "refused" in logged[0][2]  # once per writer, then counted


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
    """Count ``node.publisher_gids`` calls (the graph look-ups of a binding) in the returned [n]."""
    n = [0]
    real = node.publisher_gids

    def counted(topic, name):
        n[0] += 1
        return real(topic, name)

    node.publisher_gids = counted
    return n


def test_a_restarted_controller_whose_graph_information_comes_late_loses_no_command():
    """Issue #19 item 4: a per-process hardware run logged "/dem/command from writer 0110..., not 'controller''s:
    dropped" and its board landed on the link watchdog: the controller's commands came before the graph attributed
    its writer, and each was dropped. Now such a writer's latest command is held and delivered the moment the graph
    names it, without a further sample (a lockstep plant waits for exactly that one), and the hold is counted."""
    from dem_ros.nodes.common import CommandSource

    bus = MemoryBus()
    plant = bus.node("plant_sim")
    got: list = []
    cs = CommandSource(plant, "controller", got.append)
    JS = bus.msg("sensor_msgs/msg/JointState")
    old = bus.node("controller")
    p_old = old.publisher(contract.COMMAND)
    bus.advance(0.01)
    assert cs.matched and not cs.binding.bound  # bound by its first sample
    p_old.publish(joint_state(JS, 1, effort=(1.0, 1.0)))
    bus.spin_once()
    assert cs.binding.bound == p_old.gid and cs.values()["commands_late"] == 0
    old.shutdown()
    new = bus.node("controller")
    p_new = new.publisher(contract.COMMAND)
    entry = next(w for w in bus.writers if w[2] is p_new)
    bus.writers.remove(entry)  # its graph information has not arrived yet
    p_new.publish(joint_state(JS, 2, effort=(2.0, 2.0)))
    bus.advance(0.05)  # 50 ms: held, neither delivered nor dropped
    assert [stamp_ns(m) for m in got] == [1] and cs.binding.pending and cs.foreign == 0
    bus.writers.append(entry)  # the graph names it now: delivered within one look-up (<= 20 ms), no new sample
    bus.advance(0.025)
    assert [stamp_ns(m) for m in got] == [1, 2]
    v = cs.values()
    assert v["commands_late"] == 1 and v["commands_foreign"] == 0 and v["command_writer"] == p_new.gid.hex(), v
    assert cs.binding.rebinds == 1
    p_new.publish(joint_state(JS, 3, effort=(3.0, 3.0)))
    bus.spin_once()
    assert [stamp_ns(m) for m in got] == [1, 2, 3]


def test_an_unattributed_writer_is_refused_after_attribute_s():
    """Held at most attribute_s: a writer the graph never attributes to the source is then refused and counted
    (its held samples included)."""
    from dem_ros.nodes.common import CommandSource

    bus = MemoryBus()
    plant = bus.node("plant_sim")
    got: list = []
    cs = CommandSource(plant, "controller", got.append)
    JS = bus.msg("sensor_msgs/msg/JointState")
    stray = bus.node("stray").publisher(contract.COMMAND)
    for k in range(10):
        stray.publish(joint_state(JS, k, effort=(1.0, 1.0)))
        bus.advance(0.001)
    assert cs.binding.held == 10 and cs.foreign == 0
    bus.advance(2.1)
    assert got == [] and cs.foreign == 10 and stray.gid in cs.binding.refused_writers


def test_a_second_writer_named_controller_is_refused_while_the_bound_one_lives():
    """Impersonation: a second node named "controller" publishes 1e6 V while the real one runs. Its commands are
    refused (the bound GID stays), counted and reported: ERROR on the plant's inputs status naming its GID. Once
    the real controller is gone, the graph's single writer of "controller" is bound (the restart path)."""
    bus, plant, u0, applied, _diags = _graph()
    inputs: list[tuple[int, str, dict[str, str]]] = []
    probe = bus.node("probe2")
    probe.subscribe(contract.DIAGNOSTICS, lambda m: inputs.extend(
        (_level(s), s.message, {kv.key: kv.value for kv in s.values})
        for s in m.status if s.name == "plant_sim: inputs"))
    _run(bus, applied, 100)
    bound = plant.source.binding.bound
    JS = bus.msg("sensor_msgs/msg/JointState")
    fake = bus.node("controller")
    p_fake = fake.publisher(contract.COMMAND)
    fake.subscribe(contract.MEASUREMENT, lambda m: p_fake.publish(joint_state(JS, stamp_ns(m), effort=(1e6, 1e6))))
    n0 = len(applied)
    _run(bus, applied, n0 + 300)
    bus.advance(1.0)
    assert all(a == pytest.approx(u0, abs=1e-9) for a in applied)
    assert plant.source.binding.bound == bound and plant.source.foreign >= 300
    errors = [d for d in inputs if d[0] == ERROR]
    assert errors and p_fake.gid.hex() in errors[-1][1] and "a second writer of 'controller'" in errors[-1][1], inputs
    assert int(errors[-1][2]["command_refused"]) >= 300 and int(errors[-1][2]["refused"]) >= 300
    # the real controller leaves: the impersonator is now the only "controller" on the graph, and is bound
    real = next(n for t, n, p in bus.writers if t == contract.COMMAND.name and n is not None and p.gid == bound)
    real.shutdown()
    bus.advance(1.0)  # the bound writer is gone (looked up every refresh_s): unbound
    p_fake.publish(joint_state(JS, bus.now_ns, effort=(1e6, 1e6)))  # the next writer of "controller" to send
    bus.spin_once()
    assert plant.source.binding.bound == p_fake.gid and plant.source.binding.rebinds == 1


def test_a_malformed_command_from_the_bound_writer_is_rejected():
    """A 3-element effort from the bound controller is rejected (counted, WARN), not applied as its first two."""
    bus, plant, _u0, applied, _diags = _graph()
    _run(bus, applied, 60)
    ctl = next(p for t, n, p in bus.writers if t == contract.COMMAND.name and n is not None and n.name == "controller")
    JS = bus.msg("sensor_msgs/msg/JointState")
    b = plant.source.binding
    b.on_sample(joint_state(JS, bus.now_ns, effort=(50.0, 50.0, 50.0)), ctl.gid)
    b.on_sample(joint_state(JS, bus.now_ns, effort=(50.0,)), ctl.gid)
    assert b.malformed == 2 and plant.source.values()["commands_malformed"] == 2
    assert any("malformed sample from the bound writer rejected: 3 values in effort, expected 2" in line[2]
               for line in bus.log)


def test_a_persistent_foreign_writer_costs_few_graph_lookups():
    """A foreign writer at 1 kHz for 1 s beside the bound controller: every sample refused and counted, the graph
    read a few times per second (each read walks the DDS graph: at 1 kHz it starved a loaded plant), not a
    thousand."""
    from dem_ros.nodes.common import CommandSource

    bus = MemoryBus()
    plant = bus.node("plant_sim")
    got: list = []
    cs = CommandSource(plant, "controller", got.append)
    ctl = bus.node("controller").publisher(contract.COMMAND)
    rogue = bus.node("rogue").publisher(contract.COMMAND)
    JS = bus.msg("sensor_msgs/msg/JointState")
    ctl.publish(joint_state(JS, bus.now_ns, effort=(1.0, 1.0)))
    bus.advance(0.01)
    assert cs.matched and cs.binding.bound == ctl.gid and len(got) == 1
    got.clear()
    lookups = _count_lookups(plant)
    for _ in range(1000):
        rogue.publish(joint_state(JS, bus.now_ns, effort=(1e6, 1e6)))
        bus.advance(0.001)
    assert cs.foreign == 1000 and got == []
    assert lookups[0] <= 1 + 7 + 1.0 / 0.5 + 2, lookups  # the new writer: 2, 4, ... ms, then every refresh_s


def test_two_writers_named_controller_before_the_run_bind_the_first_to_send():
    """An impersonator already on the graph at start-up, silent: the plant starts (writers of "controller" are
    there), the first writer to send a command is bound, and the impersonator's later commands are refused."""
    bus, plant, u0, applied, _diags = _graph()
    JS = bus.msg("sensor_msgs/msg/JointState")
    fake = bus.node("controller")
    p_fake = fake.publisher(contract.COMMAND)
    _run(bus, applied, 100)
    b = plant.source.binding
    assert plant.started and b.bound and b.bound != p_fake.gid
    assert any("2 writers of 'controller'" in line[2] for line in bus.log)
    p_fake.publish(joint_state(JS, bus.now_ns, effort=(1e6, 1e6)))
    bus.spin_once()
    assert p_fake.gid in b.refused_writers and all(a == pytest.approx(u0, abs=1e-9) for a in applied)

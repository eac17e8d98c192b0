"""``dem-ros view``: the live view, tested with a client of the Foxglove WebSocket protocol.

Unit tier: the layout file is what :mod:`dem_ros.view.layout` builds from the contract and names only
forwarded topics and fields of their types; parameter names; bad options. Graph tier: ``dem-ros launch
--compose --free-run --view`` (the real graph, the real server in its own process) against
:class:`dem_ros.view.client.FoxgloveClient`, written from the protocol's specification: it connects, sees
the channels, subscribes, decodes every /dem/measurement sample with the schema the server advertised
and counts them over 10 s; sets controller.w (the controller's own parameter event is in the run's bag), is refused an
invalid value with the schema's reason and a read-only one with the node's; calls hw_driver's service
with no driver running and gets the failure's reason.
"""

from __future__ import annotations

import asyncio
import json
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("foxglove", reason="foxglove-sdk is not installed (the 'view' extra: pip install -e '.[view]')")
pytest.importorskip("websockets", reason="websockets is not installed (the 'view' extra: pip install -e '.[view]')")

from dem_ros import contract, typestore
from dem_ros.transport import rclpy_available
from dem_ros.view import SUBPROTOCOL, layout
from dem_ros.view.client import FoxgloveClient, ServiceFailure
from dem_ros.view.graph import HW_SERVICES, split_name
from dem_ros.view.server import FORWARDED

ROOT = Path(__file__).resolve().parents[2]
CLI = [sys.executable, "-m", "dem_ros.tools.cli"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


# -- unit tier ----------------------------------------------------------------------------------------------

def test_forwarded_topics_are_every_dem_topic_and_diagnostics():
    names = {t.name for t in FORWARDED}
    assert names == {t.name for t in contract.TOPICS if t.name.startswith("/dem/")} | {"/diagnostics"}
    assert contract.PARAMETER_EVENTS.name not in names


def test_the_view_never_holds_back_a_1khz_writer():
    """The 1 kHz streams are subscribed best-effort (a writer never waits for the view);
    the rest as the contract says."""
    from dem_ros.view.server import watched

    for t in FORWARDED:
        w = watched(t)
        assert (w.name, w.type, w.qos.depth, w.qos.transient_local) == (t.name, t.type, t.qos.depth,
                                                                        t.qos.transient_local)
        assert w.qos.reliable is (t.qos.reliable and t.rate_hz != 1000.0)
    assert watched(contract.MEASUREMENT).qos.reliable is False
    assert watched(contract.DIAGNOSTICS).qos == contract.DIAGNOSTICS.qos
    assert watched(contract.HW_STATE).qos == contract.HW_STATE.qos


def test_layout_file_is_the_one_built_from_the_contract():
    assert layout.LAYOUT_FILE == ROOT / "config" / "foxglove" / "dem_ros.json"
    assert layout.LAYOUT_FILE.read_text() == layout.render(), "run: python -m dem_ros.view.layout"


def test_layout_names_forwarded_topics_and_fields_of_their_types():
    doc = json.loads(layout.LAYOUT_FILE.read_text())
    paths = layout.plot_paths(doc)
    types = {t.name: t.type for t in FORWARDED}
    store = typestore.typestore()
    lengths = {contract.REFERENCE.name: len(contract.REFERENCE_NAMES),
               contract.CONTROLLER_STATE.name: len(contract.CONTROLLER_STATE_NAMES)}
    seen = set()
    for path in paths:
        if path.startswith(layout.LOOP_SCRIPT_TOPIC + "."):
            assert path.split(".", 1)[1] in layout.LOOP_KEYS
            continue
        topic = max((t for t in types if path.startswith(t + ".")), key=len, default=None)
        assert topic is not None, f"{path}: not a forwarded topic"
        seen.add(topic)
        field = re.match(r"[a-z_]+", path[len(topic) + 1:]).group(0)
        assert field in [f[0] for f in store.fielddefs[types[topic]][1]], path
        index = re.match(r"[a-z_]+\[(\d+)\]", path[len(topic) + 1:])
        if index and topic in lengths:
            assert int(index.group(1)) < lengths[topic], path
        elif index:  # per-magnet vectors: magnet_1, magnet_2
            assert int(index.group(1)) < len(contract.MAGNETS), path
    panels = {contract.MEASUREMENT.name, contract.REFERENCE.name, contract.CONTROLLER_STATE.name,
              contract.APPLIED.name, contract.HW_STATE.name}
    assert panels <= seen
    text = layout.LAYOUT_FILE.read_text()
    assert all(f"{'/hw_driver'}/{verb}" in text for verb in HW_SERVICES)
    assert '"panelType": "DiagnosticsSummary"' in text and '"panelType": "Parameters"' in text


@pytest.mark.parametrize("full, parts", [("/controller.w", ("/controller", "w")),
                                         ("/ns/controller.a.b", ("/ns/controller", "a.b"))])
def test_parameter_names_are_node_dot_name(full, parts):
    assert split_name(full) == parts


@pytest.mark.parametrize("bad", ["controller.w", "/controller", "/controller.", ".w"])
def test_a_malformed_parameter_name_is_refused(bad):
    with pytest.raises(ValueError, match=r"expected /NODE\.NAME"):
        split_name(bad)


def test_a_bad_port_is_one_line_and_exit_2():
    r = subprocess.run([*CLI, "view", "--port", "70000"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert "--port" in r.stderr and "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_a_taken_port_is_one_line_and_exit_2(domain_id):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        r = subprocess.run([*CLI, "view", "--port", str(port)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert "Traceback" not in r.stderr
    assert lines[-1].startswith("dem-ros view: error: cannot listen on 127.0.0.1:") and str(port) in lines[-1]


@pytest.mark.parametrize(("host", "local"), [("127.0.0.1", True), ("localhost", True), ("::1", True),
                                             ("127.0.0.2", True), ("0.0.0.0", False), ("192.168.1.20", False),
                                             ("rig-pc.lan", False)])
def test_only_a_loopback_address_is_this_machine_only(host, local):
    from dem_ros.tools.view import _loopback

    assert _loopback(host) is local


def test_the_view_says_where_it_listens_and_stops_cleanly_on_ctrl_c(domain_id):
    """No graph needed: the view starts, prints its structured line, and Ctrl-C ends it with exit 0 and its summary."""
    proc = subprocess.Popen([*CLI, "view", "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        line = proc.stdout.readline()  # blocks until the view serves (or exits: "")
        assert line.startswith("VIEW "), (line, proc.stderr.read() if proc.poll() is not None else "")
        info = json.loads(line[5:])
        assert info["listening"] == f"ws://127.0.0.1:{info['port']}" and info["port"] > 0
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert "WARNING" not in err and "Traceback" not in err
    assert json.loads(out.strip().splitlines()[-1][5:])["forwarded"][contract.MEASUREMENT.name] == 0


# -- graph tier ---------------------------------------------------------------------------------------------

def _decoder(schema_name: str, text: str):
    """A CDR decoder built only from the schema text the server advertised (rosbags, an empty store)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)
    types = {}
    for i, section in enumerate(text.split(typestore.SCHEMA_SEPARATOR)):
        if i == 0:
            name, body = schema_name, section
        else:
            head, _, body = section.partition("\n")
            pkg, _, typ = head.removeprefix("MSG: ").strip().partition("/")
            name = f"{pkg}/msg/{typ}"
        types.update(get_types_from_msg(body, name))
    store.register(types)
    return lambda data: store.deserialize_cdr(data, schema_name)


async def _wait_listening(port: int, proc: subprocess.Popen, timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if proc.poll() is not None:
            raise AssertionError(f"dem-ros launch ended (code {proc.returncode}) before the view listened")
        try:
            _r, w = await asyncio.open_connection("127.0.0.1", port)
            w.close()
            return
        except OSError:
            await asyncio.sleep(0.1)
    raise AssertionError(f"the view did not listen on port {port} within {timeout_s:g} s")


@pytest.mark.parametrize("transport", [
    "dds", pytest.param("rclpy", marks=pytest.mark.skipif(
        not rclpy_available(), reason="rclpy is not installed (the 'ros' extra: the registry's Jazzy wheels)"))])
def test_a_foxglove_client_watches_and_tunes_a_composed_free_running_graph(domain_id, tmp_path, transport):
    """On either transport: the view's parameters go through that transport's own service clients (the dds
    client's request header is rmw_cyclonedds'; rclpy's graph runs on Fast DDS)."""
    port = _free_port()
    # long enough for every check on a loaded machine; stopped (Ctrl-C) once they are done
    proc = subprocess.Popen([*CLI, "launch", "--compose", "--free-run", "--duration", "300", "--transport", transport,
                             "--domain-id", str(domain_id), "--view", str(port), "--bag-dir", str(tmp_path)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        result = asyncio.run(_watch_and_tune(port, proc))
    finally:
        proc.send_signal(signal.SIGINT)  # the graph stops cleanly (no bag is kept: --no-record)
        out, _ = proc.communicate(timeout=300)
    assert proc.returncode == 130, out[-3000:]  # interrupted, as asked
    # the controller's own parameter events, recorded by the graph: the one change is the client's
    from dem_ros.bag import BagReader

    bag = next(d for d in tmp_path.iterdir() if d.is_dir() and not d.name.endswith("_logs"))
    changes = [(e.node, p.name, p.value.double_value)
               for _, _, e in BagReader(bag).messages([contract.PARAMETER_EVENTS.name])
               for p in e.changed_parameters]
    assert changes == [("/controller", "w", 60.0)], changes
    assert f"live view on ws://127.0.0.1:{port}" in out

    m = result["measurement"]
    print(f"/dem/measurement through the view: {m}")
    assert m["sent"] >= 9000  # 10 s of a 1 kHz stream
    assert m["received"] >= 0.95 * m["sent"], m
    assert m["decoded"] == m["received"]
    first = m["first_gaps"]
    assert len(first) == 2 and all(abs(g - 8e-3) < 0.5e-3 for g in first), first  # S1 hovers at 8 mm first
    assert all(2e-3 < g < 12e-3 for g in m["gap_range"]), m["gap_range"]


async def _watch_and_tune(port: int, proc: subprocess.Popen) -> dict:
    await _wait_listening(port, proc, timeout_s=300)
    async with FoxgloveClient(f"ws://127.0.0.1:{port}", timeout_s=30) as c:
        assert c.subprotocol == SUBPROTOCOL
        chans = await c.wait_channels({t.name for t in FORWARDED})
        for t in FORWARDED:
            ch = chans[t.name]
            assert (ch.encoding, ch.schema_encoding, ch.schema_name) == ("cdr", "ros2msg", t.type)
        js = chans[contract.MEASUREMENT.name].schema
        assert js.startswith("std_msgs/Header header\n")
        assert typestore.SCHEMA_SEPARATOR + "MSG: std_msgs/Header\n" in js  # dependencies, concatenated
        decode = _decoder(contract.MEASUREMENT.type, js)
        # as the Foxglove app, only what a panel shows: here /dem/measurement (a client in Python on a loaded
        # machine cannot take all seven 1 kHz streams; the view subscribes a topic when a client first does)
        await c.subscribe([chans[contract.MEASUREMENT.name]])

        # the first measurement: the pre-roll's hover at 8 mm, or the run's start
        first = None
        end = time.monotonic() + 240
        while first is None and time.monotonic() < end:
            s = await c.next_sample(5.0)
            if s is not None and s.topic == contract.MEASUREMENT.name:
                first = decode(s.data)
        assert first is not None, "no /dem/measurement sample within 240 s"
        first_gaps = [float(x) for x in first.position]
        assert first.header.frame_id == contract.FRAME_PREROLL  # subscribed before the plant started its clock

        # 10 s of /dem/measurement, every sample decoded with the advertised schema
        stamps: list[int] = []
        lo, hi = 1.0, 0.0
        end = time.monotonic() + 10.0
        while (left := end - time.monotonic()) > 0:
            s = await c.next_sample(left)
            if s is None:
                break
            msg = decode(s.data)
            assert list(msg.name) == list(contract.MAGNETS) and len(msg.position) == 2
            stamps.append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)
            lo, hi = min(lo, *msg.position), max(hi, *msg.position)
        dt = 1_000_000
        sent = (max(stamps) - min(stamps)) // dt + 1

        # every other channel delivers what its schema decodes
        others = [ch for t, ch in chans.items() if t != contract.MEASUREMENT.name]
        await c.subscribe(others)
        wanted = {contract.APPLIED.name, contract.ESTIMATE.name, contract.REFERENCE.name, contract.COMMAND.name,
                  contract.CONTROLLER_STATE.name, contract.TRUTH.name, contract.DIAGNOSTICS.name}
        end = time.monotonic() + 30
        while wanted and time.monotonic() < end:
            s = await c.next_sample(1.0)
            if s is not None and s.topic in wanted:
                _decoder(chans[s.topic].schema_name, chans[s.topic].schema)(s.data)
                wanted.discard(s.topic)
        assert not wanted, f"no sample within 30 s on {sorted(wanted)}"

        # parameters: through the controller's own services, validated as dem-ros param set does
        assert (await c.get_parameters(["/controller.w"]))["/controller.w"] == 50.0
        everything = await c.get_parameters([])
        assert "/controller.k1" in everything and "/estimator.type" in everything
        # the answer is read back from the controller's get_parameters service (and the bag has its event)
        assert (await c.set_parameters({"/controller.w": 60.0}))["/controller.w"] == 60.0
        n0 = len(c.statuses)
        assert (await c.set_parameters({"/controller.w": -5.0}))["/controller.w"] == 60.0
        assert (await c.set_parameters({"/controller.dt": 0.002}))["/controller.dt"] == 0.001
        end = time.monotonic() + 10
        while len(c.statuses) < n0 + 2 and time.monotonic() < end:
            await asyncio.sleep(0.05)
        refusals = [s for s in c.statuses[n0:] if s["level"] == 2]
        assert len(refusals) == 2, c.statuses
        assert refusals[0]["message"] == "/controller.w: controller.w: got -5.0, expected a float in [0, 1e+09]"
        assert "read-only" in refusals[1]["message"] and "dt" in refusals[1]["message"]
        assert (await c.get_parameters(["/controller.w", "/controller.dt"])) == {"/controller.w": 60.0,
                                                                                "/controller.dt": 0.001}

        # hw_driver's services are offered; with no driver running a call fails with the reason
        assert set(c.services) == {f"/hw_driver/{v}" for v in HW_SERVICES}
        svc = c.services["/hw_driver/status"]
        assert svc["type"] == "std_srvs/srv/Trigger"
        with pytest.raises(ServiceFailure, match=r"no service /hw_driver/status"):
            await c.call_service("/hw_driver/status", b"\x00\x01\x00\x00\x00")
    return {"measurement": {"sent": int(sent), "received": len(stamps), "decoded": len(stamps),
                            "first_gaps": first_gaps, "gap_range": [lo, hi]}}


def test_the_client_speaks_only_the_protocol():
    """The test's client imports nothing of the server: it is a client of the protocol, not of our code."""
    src = (ROOT / "dem_ros" / "view" / "client.py").read_text()
    assert "foxglove" not in "\n".join(ln for ln in src.splitlines() if ln.startswith(("import", "from")))

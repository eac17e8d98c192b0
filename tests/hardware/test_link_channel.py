"""Real channels: UDP sockets on loopback and a real pty pair (os.openpty + pyserial) carrying frames.

No timing is asserted beyond "recv never returns before its deadline" (a lower
bound holds on any machine); the round-trip figures come from the benchmark
``python -m dem_ros.hardware.linkbench``.
"""

from __future__ import annotations

import contextlib
import os
import socket
import threading
import time
from collections.abc import Iterator

import pytest

from dem_ros.hardware.channel import ChannelError, PtyChannel, SerialChannel, UdpChannel, open_channel
from dem_ros.hardware.framing import wire_frame
from dem_ros.hardware.link import HELLO_REQUEST, CommandFrame, Hello, LinkError, Mode, SensorFrame, decode, encode

#: generous: a loaded 2-core machine can stall a process for tens of ms; the exchange is lockstep
WAIT_S = 5.0


def sensor(k: int) -> bytes:
    return encode(SensorFrame(k, 1000 * k, (2048, 2050), (1700, 1701), (50.0, 49.5), 150.0, 0, Mode.RUN))


def command(k: int) -> bytes:
    return encode(CommandFrame(k, (50.0 + k % 7, 49.0), Mode.RUN))


def lockstep(board: UdpChannel | PtyChannel, pc: UdpChannel | SerialChannel, n: int) -> None:
    """Board sends sensor k, PC answers command k, n times: every frame arrives, once, in order."""
    for k in range(n):
        assert board.send(sensor(k))
        got = pc.recv(WAIT_S)
        assert got is not None, f"sensor {k} lost"
        s = decode(got)
        assert isinstance(s, SensorFrame) and s.seq == k
        assert pc.send(command(s.seq))
        got = board.recv(WAIT_S)
        assert got is not None, f"command {k} lost"
        c = decode(got)
        assert isinstance(c, CommandFrame) and c.seq == k and c.u == (50.0 + k % 7, 49.0)


# --- UDP ---------------------------------------------------------------------------------------
@pytest.fixture
def udp_pair() -> Iterator[tuple[UdpChannel, UdpChannel]]:
    board = open_channel("udp://127.0.0.1:0", "board")
    assert isinstance(board, UdpChannel)
    pc = open_channel(f"udp://127.0.0.1:{board.local_address[1]}", "pc")
    assert isinstance(pc, UdpChannel)
    yield board, pc
    pc.close()
    board.close()


def test_udp_handshake_and_lockstep(udp_pair: tuple[UdpChannel, UdpChannel]) -> None:
    board, pc = udp_pair
    assert not board.send(sensor(0)) and board.stats["tx_no_peer"] == 1  # no PC has said hello yet
    assert pc.send(encode(HELLO_REQUEST))
    req = board.recv(WAIT_S)
    assert req is not None and decode(req) == HELLO_REQUEST and board.peer == pc.local_address
    assert board.send(encode(Hello(1, 42, 1000, 12, 3.0, 50)))
    got = pc.recv(WAIT_S)
    assert got is not None and decode(got) == Hello(1, 42, 1000, 12, 3.0, 50)
    lockstep(board, pc, 1000)
    assert pc.stats["rx_frames"] == 1001 and board.stats["rx_frames"] == 1001


def test_udp_board_ignores_foreign_senders(udp_pair: tuple[UdpChannel, UdpChannel]) -> None:
    """Commands from an address that did not open the link are dropped and counted; a new hello takes over."""
    board, pc = udp_pair
    pc.send(encode(HELLO_REQUEST))
    assert board.recv(WAIT_S) is not None
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as intruder:
        intruder.sendto(command(99), ("127.0.0.1", board.local_address[1]))
        intruder.sendto(b"garbage", ("127.0.0.1", board.local_address[1]))
        pc.send(command(1))
        got = board.recv(WAIT_S)
        assert got is not None and decode(got) == decode(command(1))
        assert board.stats["foreign"] == 2
        # a restarted PC (new port) reopens the link with a hello
        intruder.sendto(encode(HELLO_REQUEST), ("127.0.0.1", board.local_address[1]))
        assert board.recv(WAIT_S) == encode(HELLO_REQUEST)
        assert board.peer == ("127.0.0.1", intruder.getsockname()[1]) and board.stats["peer_changes"] == 2


def test_udp_recv_deadline_and_oversize(udp_pair: tuple[UdpChannel, UdpChannel]) -> None:
    board, pc = udp_pair
    t0 = time.monotonic()
    assert pc.recv(0.02) is None
    assert time.monotonic() - t0 >= 0.02  # never before the deadline
    assert pc.recv(0.0) is None  # a poll
    pc.send(encode(HELLO_REQUEST))
    assert board.recv(WAIT_S) is not None
    board.send(b"\x01" * 1500)  # an oversize datagram arrives whole and is rejected by decode
    got = pc.recv(WAIT_S)
    assert got is not None and len(got) == 1500
    with pytest.raises(LinkError) as e:
        decode(got)
    assert e.value.reason == "length"


def test_udp_pc_without_board_counts_refusals() -> None:
    """A PC whose board is not listening: sends and recvs never raise; the ICMP refusals are counted."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # a port nobody listens on once closed
    pc = open_channel(f"udp://127.0.0.1:{port}", "pc")
    try:
        for _ in range(5):
            pc.send(encode(HELLO_REQUEST))
            assert pc.recv(0.01) is None
        assert pc.stats["rx_refused"] + pc.stats["tx_refused"] >= 1
    finally:
        pc.close()


# --- serial over a pty pair ---------------------------------------------------------------------
@pytest.fixture
def pty_pair() -> Iterator[tuple[PtyChannel, SerialChannel]]:
    board = open_channel("pty://", "board")
    assert isinstance(board, PtyChannel) and board.peer_url.startswith("serial:///dev/")
    pc = open_channel(board.peer_url + "?baud=921600", "pc")
    assert isinstance(pc, SerialChannel)
    yield board, pc
    pc.close()
    board.close()


def test_serial_pty_lockstep(pty_pair: tuple[PtyChannel, SerialChannel]) -> None:
    board, pc = pty_pair
    lockstep(board, pc, 1000)
    assert sum(pc.deframer.dropped.values()) == 0 and sum(board.deframer.dropped.values()) == 0
    assert pc.stats["rx_bytes"] == 1000 * len(wire_frame(sensor(0)))


def test_serial_recv_waits_for_late_data(pty_pair: tuple[PtyChannel, SerialChannel]) -> None:
    """recv called before the board sends: it waits (an empty tty read is not mistaken for a hangup)."""
    board, pc = pty_pair
    timer = threading.Timer(0.05, lambda: board.send(sensor(1)))
    timer.start()
    try:
        got = pc.recv(WAIT_S)
    finally:
        timer.join()
    assert got == sensor(1) and pc.stats["rx_hangup"] == 0


def test_serial_noise_on_the_line_costs_no_frame(pty_pair: tuple[PtyChannel, SerialChannel]) -> None:
    """Line noise between frames (written raw into the pty) is dropped and counted; every frame survives."""
    board, pc = pty_pair
    for k in range(50):
        os.write(board.fileno(), bytes([0x55, 0x03, 0xFF]) * (k % 5) + (b"\x07\x00" if k % 3 == 0 else b""))
        board.send(sensor(k))
    got = []
    while (f := pc.recv(0.5)) is not None:
        got.append(f)
    frames = []
    for f in got:
        with contextlib.suppress(LinkError):  # noise that happened to be valid COBS: rejected here
            frames.append(decode(f))
    assert [s.seq for s in frames if isinstance(s, SensorFrame)] == list(range(50))
    assert sum(pc.deframer.dropped.values()) + (len(got) - len(frames)) > 0


def test_serial_pc_reopens(pty_pair: tuple[PtyChannel, SerialChannel]) -> None:
    """The PC closes and reopens the port (driver restart): the link carries frames again."""
    board, pc = pty_pair
    lockstep(board, pc, 10)
    pc.close()
    pc2 = open_channel(board.peer_url, "pc")
    assert isinstance(pc2, SerialChannel)
    try:
        lockstep(board, pc2, 10)
    finally:
        pc2.close()


def test_serial_hangup_is_a_timeout_not_an_error() -> None:
    """The board end vanishes: the PC's recv returns None at its deadline (counted), never raises or spins."""
    board = open_channel("pty://", "board")
    pc = open_channel(board.peer_url, "pc")  # type: ignore[union-attr]
    board.close()
    try:
        t0 = time.monotonic()
        assert pc.recv(0.05) is None
        assert time.monotonic() - t0 >= 0.05
        assert pc.stats["rx_hangup"] >= 1
    finally:
        pc.close()


# --- URLs -----------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("url", "side", "words"),
    [
        ("tcp://127.0.0.1:5", "pc", "unknown scheme 'tcp'"),
        ("udp://127.0.0.1", "pc", "expected udp://HOST:PORT"),
        ("udp://127.0.0.1:99999", "pc", "malformed URL"),
        ("udp://127.0.0.1:0", "pc", "the PC needs the board's port"),
        ("udp://no-such-host.invalid:5000", "pc", "cannot resolve"),
        ("serial://dev/ttyUSB0", "pc", "three slashes"),
        ("serial:///dev/ttyUSB0?baud=fast", "pc", "baud='fast'"),
        ("serial:///dev/ttyUSB0?parity=E", "pc", "unknown option"),
        ("serial:///dev/does-not-exist-dem", "pc", "cannot open"),
        ("pty://", "pc", "the PC opens its serial"),
        ("udp://127.0.0.1:5", "robot", "side must be"),
    ],
)
def test_bad_urls_give_clear_errors(url: str, side: str, words: str) -> None:
    with pytest.raises(ChannelError, match=words.replace("(", r"\(").replace("?", r"\?")):
        open_channel(url, side)


def test_udp_port_in_use_is_a_clear_error(udp_pair: tuple[UdpChannel, UdpChannel]) -> None:
    board, _ = udp_pair
    with pytest.raises(ChannelError, match="cannot bind"):
        open_channel(f"udp://127.0.0.1:{board.local_address[1]}", "board")


# --- the benchmark command runs (its figures are reported, not asserted) --------------------------
@pytest.mark.parametrize("transport", ["udp", "serial"])
def test_linkbench_runs(transport: str) -> None:
    """0.3 s at 1 kHz between two processes: every sample is accounted for (back or lost)."""
    from dem_ros.hardware.linkbench import run

    r = run(transport, 1000.0, 0.3)
    assert r["samples"] == 300
    back, lost = int(r["commands_received"]), int(r["lost"])  # type: ignore[call-overload]
    assert back + lost == 300
    assert back > 0 and r["rejected"] == 0


def test_linkbench_cli(capsys: pytest.CaptureFixture[str]) -> None:
    from dem_ros.hardware.linkbench import main

    assert main(["udp", "--duration", "0.2"]) == 0
    out = capsys.readouterr().out
    assert "link udp at 1000 Hz for 0.2 s (load average" in out and "round trip" in out
    with pytest.raises(SystemExit):
        main(["udp", "--rate", "0"])
    assert "--rate must be in" in capsys.readouterr().err

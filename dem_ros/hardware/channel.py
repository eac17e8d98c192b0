"""Channels that carry link frames between the PC and the board: UDP, serial, pty.

``open_channel(url, side)`` returns a :class:`Channel`: ``send(frame)`` never
blocks, ``recv(timeout_s)`` waits at most ``timeout_s`` seconds (0 polls) on a
monotonic deadline and returns one frame's bytes or ``None``. Frames are not
decoded here (pass them to :func:`dem_ros.hardware.link.decode`); only what
the transport itself can tell is counted, in ``stats``.

URLs:

``udp://HOST:PORT``
    One frame per datagram. ``side="board"`` binds HOST:PORT and answers the PC
    that sent the last valid :class:`~dem_ros.hardware.link.Hello` request
    (datagrams from any other address are dropped and counted ``foreign``);
    ``side="pc"`` connects to the board at HOST:PORT from an ephemeral port.
``serial:///dev/PATH[?baud=N]``
    A serial line (USB CDC or UART) via pyserial, raw 8N1, COBS-framed with a
    0x00 delimiter before and after each frame (:mod:`dem_ros.hardware.framing`).
    Default 921600 baud: a sensor frame is 51 bytes on the wire (49 COBS + 2
    delimiters), i.e. 510 kbit/s at 1 kHz with 10 bits per byte, so a UART needs ≥ 921600 baud (USB CDC
    ignores the rate).
``pty://``
    A new pseudo-terminal, for emulators (``side="board"`` only): the board
    holds the master end; ``channel.peer_url`` (``serial:///dev/pts/N``) is the
    URL the PC opens. Same COBS framing as serial.

Sending never blocks: a datagram the kernel will not take, or stream bytes the
line will not take beyond a backlog of :data:`TX_BACKLOG` bytes, are dropped
whole and counted (``tx_dropped``); a partly written frame is always completed
first, so the stream is never corrupted by a drop.
"""

from __future__ import annotations

import errno
import os
import select
import socket
import termios
import time
import tty
from collections import Counter, deque
from typing import Protocol
from urllib.parse import parse_qs, urlsplit

from .framing import Deframer, wire_frame
from .link import MAX_FRAME_SIZE, Hello, LinkError, decode

__all__ = [
    "DEFAULT_BAUD",
    "RX_QUEUE",
    "TX_BACKLOG",
    "Channel",
    "ChannelError",
    "PtyChannel",
    "SerialChannel",
    "UdpChannel",
    "check_link",
    "open_channel",
]

DEFAULT_BAUD = 921600
TX_BACKLOG = 4096
"""Bytes a stream channel may hold unsent before it drops new frames (~80 frames)."""
RX_QUEUE = 64
"""Deframed frames a stream channel keeps unread; beyond it the oldest is dropped (counted ``rx_overflow``)."""
_DGRAM_MAX = 2048  # larger than any frame: an oversize datagram is received whole and rejected by decode


class ChannelError(OSError):
    """A channel could not be opened (bad URL, port in use, no such device) or broke while open.

    The message names the URL and the cause, to be printed without a traceback.
    """


class Channel(Protocol):
    """What the driver and the board emulator need from a transport."""

    url: str
    stats: Counter[str]

    def send(self, frame: bytes) -> bool:
        """Queue one frame without blocking; False if it was dropped (counted)."""
        ...

    def recv(self, timeout_s: float = 0.0) -> bytes | None:
        """One frame's bytes, waiting at most ``timeout_s`` s (0: poll); None on timeout."""
        ...

    def fileno(self) -> int:
        """A descriptor that is readable when ``recv`` may have data (for select/poll)."""
        ...

    def close(self) -> None:
        """Release the socket or device (idempotent)."""
        ...


_FD_SETSIZE = 1024  # select() takes descriptors below this


def _wait_readable(fd: int, poller: select.poll, deadline: float) -> bool:
    """Wait until ``fd`` is readable or the monotonic ``deadline`` (s) passes.

    select() takes a timeout in µs; poll() only in whole ms, which would overshoot a
    sub-millisecond deadline by up to 1 ms (a whole period at 1 kHz), so poll() is only
    the fallback for descriptors select() cannot take (rounded up: never early).
    """
    while True:
        left = deadline - time.monotonic()
        if fd < _FD_SETSIZE:
            if select.select([fd], [], [], max(0.0, left))[0]:
                return True
        elif poller.poll(max(0, int(left * 1e3 + 0.999))):
            return True
        if time.monotonic() >= deadline:
            return False


class UdpChannel:
    """One frame per UDP datagram (see the module docstring for the board/PC roles)."""

    def __init__(self, host: str, port: int, side: str, url: str) -> None:
        self.url = url
        self.side = side
        self.stats: Counter[str] = Counter()
        try:
            infos = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
        except socket.gaierror as e:
            raise ChannelError(f"{url}: cannot resolve {host!r}: {e.strerror}") from None
        family, _, _, _, addr = infos[0]
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            if side == "board":
                self._sock.bind(addr)
                self.peer: tuple[object, ...] | None = None
            else:
                self._sock.connect(addr)
                self.peer = tuple(addr)
        except OSError as e:
            self._sock.close()
            raise ChannelError(f"{url}: cannot {'bind' if side == 'board' else 'connect'}: {e.strerror}") from None
        self._sock.setblocking(False)
        self._poll = select.poll()
        self._poll.register(self._sock.fileno(), select.POLLIN)

    @property
    def local_address(self) -> tuple[str, int]:
        """The (host, port) this end is bound to (the board's listen port; the PC's ephemeral port)."""
        host, port = self._sock.getsockname()[:2]
        return host, port

    def fileno(self) -> int:
        return self._sock.fileno()

    def send(self, frame: bytes) -> bool:
        try:
            if self.side == "board":
                if self.peer is None:
                    self.stats["tx_no_peer"] += 1
                    return False
                self._sock.sendto(frame, self.peer)
            else:
                self._sock.send(frame)
        except (BlockingIOError, ConnectionRefusedError, OSError) as e:
            # ECONNREFUSED: an ICMP "port unreachable" from an earlier datagram (no board yet)
            self.stats["tx_refused" if isinstance(e, ConnectionRefusedError) else "tx_dropped"] += 1
            return False
        self.stats["tx_frames"] += 1
        return True

    def recv(self, timeout_s: float = 0.0) -> bytes | None:
        deadline = time.monotonic() + max(0.0, timeout_s)
        while True:
            try:
                data, addr = self._sock.recvfrom(_DGRAM_MAX)
            except BlockingIOError:
                if not _wait_readable(self._sock.fileno(), self._poll, deadline):
                    return None
                continue
            except ConnectionRefusedError:
                self.stats["rx_refused"] += 1  # the board is not (yet) listening
                if time.monotonic() >= deadline:
                    return None
                continue
            if self.side == "board" and addr != self.peer:
                if not self._is_hello_request(data):
                    self.stats["foreign"] += 1
                    if time.monotonic() >= deadline:  # a flood of foreign datagrams cannot hold recv past its deadline
                        return None
                    continue
                self.peer = addr
                self.stats["peer_changes"] += 1
            self.stats["rx_frames"] += 1
            return data

    @staticmethod
    def _is_hello_request(data: bytes) -> bool:
        try:
            f = decode(data)
        except LinkError:
            return False
        return isinstance(f, Hello) and f.is_request

    def close(self) -> None:
        if self._sock.fileno() >= 0:
            self._poll.unregister(self._sock.fileno())
            self._sock.close()

    def __enter__(self) -> UdpChannel:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _StreamChannel:
    """COBS frames over a non-blocking byte-stream descriptor (serial port or pty master)."""

    def __init__(self, fd: int, url: str) -> None:
        self.url = url
        self.stats: Counter[str] = Counter()
        self.deframer = Deframer()
        self._fd = fd
        self._rx: deque[bytes] = deque()
        self._tx = bytearray()
        self._poll = select.poll()
        self._poll.register(fd, select.POLLIN)
        os.set_blocking(fd, False)

    def fileno(self) -> int:
        return self._fd

    def _flush(self) -> None:
        while self._tx:
            try:
                n = os.write(self._fd, self._tx)
            except BlockingIOError:
                return
            except OSError as e:
                if e.errno == errno.EIO:  # pty: nobody has the other end open
                    self.stats["tx_no_peer"] += 1
                    self._tx.clear()
                    return
                raise ChannelError(f"{self.url}: write failed: {e.strerror}") from None
            del self._tx[:n]

    def send(self, frame: bytes) -> bool:
        self._flush()
        wire = wire_frame(frame)
        if len(self._tx) + len(wire) > TX_BACKLOG:
            self.stats["tx_dropped"] += 1
            return False
        self._tx += wire
        self._flush()
        self.stats["tx_frames"] += 1
        return True

    def _read_available(self) -> str:
        """Read what the descriptor holds: "data", "none" (would block) or "hangup" (peer gone)."""
        try:
            data = os.read(self._fd, 4096)
        except BlockingIOError:
            return "none"
        except OSError as e:
            if e.errno == errno.EIO:  # pty: the other end is closed
                return "hangup"
            raise ChannelError(f"{self.url}: read failed: {e.strerror}") from None
        if not data:  # end of file: the far end hung up (ttys are set VMIN=1, so 0 bytes is not "none")
            return "hangup"
        self.stats["rx_bytes"] += len(data)
        for f in self.deframer.feed(data):
            if len(self._rx) >= RX_QUEUE:
                self._rx.popleft()
                self.stats["rx_overflow"] += 1
            self._rx.append(f)
        return "data"

    def recv(self, timeout_s: float = 0.0) -> bytes | None:
        if self._tx:
            self._flush()
        deadline = time.monotonic() + max(0.0, timeout_s)
        while not self._rx:
            got = self._read_available()
            if got == "data":
                continue
            if got == "hangup":
                # the far end is gone: poll() would say so at once, forever; wait out the deadline
                self.stats["rx_hangup"] += 1
                left = deadline - time.monotonic()
                if left > 0:
                    time.sleep(left)
                return None
            if not _wait_readable(self._fd, self._poll, deadline):
                return None
        self.stats["rx_frames"] += 1
        return self._rx.popleft()

    def close(self) -> None:
        if self._fd >= 0:
            self._poll.unregister(self._fd)
            self._close_fd()
            self._fd = -1

    def _close_fd(self) -> None:
        os.close(self._fd)

    def __enter__(self) -> _StreamChannel:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class SerialChannel(_StreamChannel):
    """A serial device opened with pyserial (raw 8N1, exclusive), COBS-framed."""

    def __init__(self, path: str, baud: int, url: str) -> None:
        try:
            import serial  # type: ignore[import-untyped]  # pyserial
        except ImportError:  # pragma: no cover - pyserial is a declared dependency
            raise ChannelError(f"{url}: pyserial is not installed (pip install pyserial)") from None
        try:
            self._port = serial.Serial(path, baudrate=baud, timeout=0, write_timeout=0, exclusive=True)
        except (serial.SerialException, ValueError) as e:
            raise ChannelError(f"{url}: cannot open: {e}") from None
        fd = self._port.fileno()
        # pyserial leaves VMIN=0/VTIME=0, under which an empty read means "no data"; with VMIN=1 and
        # O_NONBLOCK, "no data" is EAGAIN and an empty read means the line hung up
        attrs = termios.tcgetattr(fd)
        attrs[6][termios.VMIN], attrs[6][termios.VTIME] = 1, 0
        termios.tcsetattr(fd, termios.TCSANOW, attrs)
        super().__init__(fd, url)

    def _close_fd(self) -> None:
        self._port.close()


class PtyChannel(_StreamChannel):
    """The board end of a new pseudo-terminal; the PC opens :attr:`peer_url`.

    The slave end is set raw (no echo, no line editing) and kept open, so the
    pty survives the PC closing and reopening it.
    """

    def __init__(self, url: str) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        self._slave = slave
        self.slave_path = os.ttyname(slave)
        self.peer_url = f"serial://{self.slave_path}"
        super().__init__(master, url)

    def _close_fd(self) -> None:
        os.close(self._fd)
        os.close(self._slave)


def open_channel(url: str, side: str) -> UdpChannel | SerialChannel | PtyChannel:
    """Open the channel named by ``url`` for ``side`` ("pc" or "board").

    Raises:
        ChannelError: a malformed URL, an unknown scheme or an open failure, with the reason.
    """
    if side not in ("pc", "board"):
        raise ChannelError(f"side must be 'pc' or 'board', not {side!r}")
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as e:
        raise ChannelError(f"{url!r}: malformed URL: {e}") from None
    if parts.scheme == "udp":
        if not parts.hostname or port is None or parts.path not in ("", "/") or parts.query:
            raise ChannelError(f"{url!r}: expected udp://HOST:PORT (e.g. udp://127.0.0.1:47000)")
        if side == "pc" and port == 0:
            raise ChannelError(f"{url!r}: the PC needs the board's port, not 0")
        return UdpChannel(parts.hostname, port, side, url)
    if parts.scheme == "serial":
        if parts.netloc or not parts.path.startswith("/"):
            raise ChannelError(f"{url!r}: expected serial:///dev/PATH[?baud=N] (three slashes)")
        query = parse_qs(parts.query, strict_parsing=False)
        unknown = set(query) - {"baud"}
        if unknown:
            raise ChannelError(f"{url!r}: unknown option(s) {sorted(unknown)}; only baud=N")
        baud = DEFAULT_BAUD
        if "baud" in query:
            text = query["baud"][-1]
            if not text.isdigit() or int(text) <= 0:
                raise ChannelError(f"{url!r}: baud={text!r} is not a positive integer")
            baud = int(text)
        return SerialChannel(parts.path, baud, url)
    if parts.scheme == "pty":
        if side != "board":
            raise ChannelError(f"{url!r}: pty:// creates the board end; the PC opens its serial:///dev/pts/N")
        return PtyChannel(url)
    raise ChannelError(f"{url!r}: unknown scheme {parts.scheme!r}; use udp://HOST:PORT, serial:///dev/PATH or pty://")



def check_link(url: str) -> None:
    """Check the PC's end of the link ``url`` before anything starts, without talking to the board.

    ``udp://HOST:PORT``: well formed, HOST resolves, a socket connects to it (a route exists; nothing is
    sent). ``serial:///dev/PATH``: well formed, the device exists, is a character device and is readable
    and writable by this user (it is not opened: opening a serial port can reset a board).

    Raises:
        ChannelError: malformed or unreachable, with the reason (one line).
    """
    parts = urlsplit(url)
    if parts.scheme == "serial":
        if parts.netloc or not parts.path.startswith("/"):
            raise ChannelError(f"{url!r}: expected serial:///dev/PATH[?baud=N] (three slashes)")
        query = parse_qs(parts.query, strict_parsing=False)
        if set(query) - {"baud"} or not all(t.isdigit() and int(t) > 0 for t in query.get("baud", [])):
            raise ChannelError(f"{url!r}: the only option is baud=N, a positive integer")
        path = parts.path
        try:
            st = os.stat(path)
        except OSError as e:
            raise ChannelError(f"{url}: no such device {path} ({e.strerror}); is the board plugged in?") from None
        import stat

        if not stat.S_ISCHR(st.st_mode):
            raise ChannelError(f"{url}: {path} is not a character device (a serial port)")
        if not os.access(path, os.R_OK | os.W_OK):
            raise ChannelError(f"{url}: {path} is not readable and writable by this user (group dialout?)")
        return
    if parts.scheme == "pty":
        raise ChannelError(f"{url!r}: pty:// creates the board end; the PC opens its serial:///dev/pts/N")
    ch = open_channel(url, "pc")  # udp: parsed, resolved, connected (nothing sent); other schemes refused
    ch.close()


assert MAX_FRAME_SIZE < _DGRAM_MAX

r"""The PC side of the device link: lifecycle, calibration, time mapping, link health, safety.

Plain Python, no middleware (in the spirit of a ros2_control hardware component):
the ``hw_driver`` node feeds it the bytes it receives and sends what it returns.

Lifecycle (published on ``/dem/hw/state`` and in ``/diagnostics``)::

    INACTIVE --arm()--> ARMED --arm_samples controller commands in time--> ACTIVE
        ^                 |                                    |
        +---disarm()------+------------------------------------+  (a controlled landing, LAND)
    any --trip / e-stop / watchdog / link loss--> FAULT (latched: LAND is sent every sample)
    ARMED --no frame for link_timeout (a host stall)--> ARMED: handshakes again, counted (``stalls``), no fault
    FAULT --clear() (disarm) --> INACTIVE;  arm() clears a latched fault as well
    ACTIVE --arm()--> ARMED only while the board reports LANDED / FAULT: it landed the plate on its own
        (its hold_timeout is shorter than the driver's) and ignores commands until it is armed again

Configuration (docs/hardware-link.md, "Config"): the driver answers the board's hello with a CONFIG frame, the
board's configuration packed from this driver's parameters (``boardcfg.config_frame``: the board's safety specs,
nominal plant and dt, the sensors' calibration, the command delay), and reads the board's CONFIG_ACK. ARMED ->
ACTIVE only once the board reports that it runs exactly that configuration (the ack's CRC is the run's); until then
no command is forwarded, and (INACTIVE or ARMED) the CONFIG is sent again every ``CONFIG_RETRY_NS`` (a board that is
still landing answers ``busy``; an inactive driver lands a levitating board first). A board that refuses it (an
invalid configuration: its reason), accepts it but reports another CRC, or answers none of ``CONFIG_TRIES`` is a
fault: one reason, never armed. ``arm()`` packs the configuration again (parameters changed at run time reach the
board before the next flight).

What the driver sends the board, per sensor frame (the board is the clock):
    ACTIVE   the controller's command for that sample, mode RUN (voltages clipped to ``u_max``)
    ARMED    OFF while the board reports LANDED or FAULT (arming clears its latch), else nothing
    INACTIVE LAND while the board reports a levitating mode, nothing once it is OFF/LANDED
    FAULT    LAND (the board's landing law lowers the plate; never a 0 V cut at hover)

Calibration (counts n -> SI):
    gap_j     = sum_p c_{j,p} n^p, p = 0..3                      [m]   (or a lookup table: np.interp)
    i_j       = g_j (n - o_j)                                     [A]
    u_j       = applied_v_j                                       [V]   (``voltage_input: volts``)
              = applied_v_j * bus_v                               [V]   (``voltage_input: duty``, duty in [-1, 1])

Board time -> ROS time: stamp_k = offset + 1000 * board_time_us_k [ns]. The offset is the
minimum of (receive time - board time) over the first ``clock_sync_frames`` frames (the
frame cannot arrive before it was taken, so the minimum is the tightest bound), then held
fixed: stamps stay on the board's sample grid and strictly monotonic, which the graph's
stamp matching needs. The residual (receive - stamp) is the link latency; its drift over
a run (board-clock skew) is reported, not corrected.

Link health: lost (sequence gaps), duplicated (a sequence already seen), reordered (older),
late (latency above ``late_threshold``), corrupt (decode errors, counted by reason).
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .boardcfg import BUSY, OK, BoardConfigError, config_frame, result_text
from .link import (
    CONFIG_RESULTS,
    CommandFrame,
    ConfigAck,
    ConfigFrame,
    Hello,
    LinkError,
    Mode,
    SensorFrame,
    Status,
    decode,
    encode,
    seq_diff,
)

__all__ = ["CONFIG_RETRY_NS", "CONFIG_TRIES", "Calibration", "DriverError", "DriverState", "HwDriver", "Sample"]

SEQ_MOD = 1 << 32  # sequence numbers are uint32 on the wire
SENT_RING = 64
LEVITATING = (Mode.RUN, Mode.HOLD, Mode.LAND)
CONFIG_RETRY_NS = 100_000_000  # an unconfirmed configuration is sent again after this [ns]
CONFIG_TRIES = 10  # this many CONFIG frames without any answer: the board does not speak it (a fault)
#: status bits of hardware faults: trip_samples samples in a row trip the driver (the board lands the plate);
#: the controller cannot make up for a failed coil driver, a bus that cannot hold the plate or a gap sensor the
#: board found contradicting its coil fluxes (GAPj_IMPLAUSIBLE: the board lands on the flux)
HARDWARE_FAULTS = (Status.DRIVER0_FAULT | Status.DRIVER1_FAULT | Status.BUS_UNDERVOLTAGE | Status.CURRENT0_LIMIT
                   | Status.CURRENT1_LIMIT | Status.ESTOP | Status.ADC_FAULT | Status.GAP0_IMPLAUSIBLE
                   | Status.GAP1_IMPLAUSIBLE)


class DriverError(ValueError):
    """The driver's configuration is unusable (bad calibration table, rate mismatch); the message says why."""


class DriverState(enum.IntEnum):
    INACTIVE = 0
    ARMED = 1
    ACTIVE = 2
    FAULT = 3


@dataclass(frozen=True)
class Sample:
    """One sensor frame in SI units.

    Attributes:
        seq: the board's sample number.
        stamp_ns: ROS time of the sample [ns].
        gap (2,): gaps d1, d2 [m].
        current (2,): coil currents i1, i2 [A].
        applied (2,): voltages the board held over the interval ending at this sample [V].
        bus_v: measured bus voltage [V].
        mode: the board's mode; status: its status bits.
        latency_ns: receive time - stamp [ns].
    """

    seq: int
    stamp_ns: int
    gap: np.ndarray
    current: np.ndarray
    applied: np.ndarray
    bus_v: float
    mode: Mode
    status: int
    latency_ns: int


class Calibration:
    """Counts -> SI per sensor, from the ``hw_driver`` parameters (see the module docstring)."""

    def __init__(self, cfg: Mapping[str, Any]):
        self.poly = np.array([[cfg[f"gap{j}_c{p}"] for p in range(4)] for j in (1, 2)])  # (2, 4), c_{j,p}
        self.table: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        if cfg["gap_table"]:
            self.table = load_gap_table(cfg["gap_table"])
        self.i_gain = np.array([cfg["current1_gain"], cfg["current2_gain"]])
        self.i_offset = np.array([cfg["current1_offset"], cfg["current2_offset"]])
        self.duty = cfg["voltage_input"] == "duty"

    def gap(self, counts) -> np.ndarray:
        n = np.asarray(counts, dtype=float)
        if self.table is not None:
            xs, g1, g2 = self.table
            return np.array([np.interp(n[0], xs, g1), np.interp(n[1], xs, g2)])
        c = self.poly
        return c[:, 0] + n * (c[:, 1] + n * (c[:, 2] + n * c[:, 3]))  # Horner

    def current(self, counts) -> np.ndarray:
        return self.i_gain * (np.asarray(counts, dtype=float) - self.i_offset)

    def voltage(self, applied, bus_v: float) -> np.ndarray:
        a = np.asarray(applied, dtype=float)
        return a * bus_v if self.duty else a

    def command(self, u: np.ndarray, bus_v: float) -> tuple[float, float]:
        """Voltages [V] -> what the command frame carries (volts, or duty = u / bus_v clipped to [-1, 1])."""
        if not self.duty:
            return float(u[0]), float(u[1])
        if bus_v <= 0:
            return 0.0, 0.0
        d = np.clip(u / bus_v, -1.0, 1.0)
        return float(d[0]), float(d[1])


def load_gap_table(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A CSV of ``counts, gap1_m, gap2_m`` rows (``#`` comments), counts strictly increasing."""
    try:
        data = np.loadtxt(Path(path), delimiter=",", comments="#", ndmin=2)
    except (OSError, ValueError) as exc:
        raise DriverError(f"gap_table {path}: cannot read ({exc})") from None
    if data.shape[1] != 3 or data.shape[0] < 2:
        raise DriverError(f"gap_table {path}: expected rows 'counts, gap1_m, gap2_m' (at least 2), "
                          f"got shape {data.shape}")
    if not np.all(np.isfinite(data)) or not np.all(np.diff(data[:, 0]) > 0):
        raise DriverError(f"gap_table {path}: counts must be finite and strictly increasing")
    return data[:, 0], data[:, 1], data[:, 2]


class HwDriver:
    """State machine and conversions of the hardware driver (no I/O: bytes in, bytes out).

    Times: ``ros_ns`` is ROS (system) time, used for stamps and latency; ``steady_ns`` is a
    monotonic clock, used for every timeout (the command watchdog, link loss).
    """

    def __init__(self, cfg: Mapping[str, Any]):
        self.cfg = dict(cfg)
        self.cal = Calibration(cfg)
        self.dt_ns = round(cfg["dt"] * 1e9)
        self.state = DriverState.INACTIVE
        self.reason = ""
        self.hello: Hello | None = None
        self.board_mode = Mode.OFF
        self.board_status = 0
        self.bus_v = 0.0
        self.last_seq: int | None = None
        self.last_sample: Sample | None = None
        self.offset_ns: int | None = None  # ROS time - board time, fixed after clock sync
        self._sync: list[int] = []
        self._sync_residual = 0  # median latency during clock sync [ns]
        self.drift_ns = 0  # latency of the newest frame - that median: board clock skew plus jitter [ns]
        self.last_rx_steady: int | None = None
        self.last_cmd_steady: int | None = None
        self.last_cmd_seq: int | None = None
        self._sent = [-1] * SENT_RING  # the samples whose command was forwarded, by seq
        self._in_time = 0  # consecutive in-time controller commands while armed
        self.u_last = np.zeros(2)
        self._over = {"current": 0, "gap": 0}
        self._sensor_bad = [0, 0]  # consecutive out-of-range samples per gap channel
        self._gap_valid = np.full(2, np.nan)  # the last valid gap per channel [m]
        self.counters = {
            "frames": 0, "samples": 0, "lost": 0, "duplicated": 0, "reordered": 0, "late": 0, "corrupt": 0,
            "commands_sent": 0, "commands_dropped": 0, "commands_stale": 0, "clipped": 0, "hold_samples": 0,
            "land_sent": 0, "trips": 0, "watchdog": 0, "estops": 0, "link_loss": 0, "sensor_holds": 0, "stalls": 0,
        }
        self.longest_stall_ms = 0.0  # the longest silence an armed driver rode through (_stall) [ms]
        self.corrupt_reasons: dict[str, int] = {}
        self.status_counts: dict[str, int] = {}  # samples the board reported each status bit in
        self.counters.update({"config_sent": 0, "config_refused": 0})
        self.board_config: ConfigAck | None = None  # the board's newest answer to a CONFIG (None: none since hello)
        self._config: tuple[bytes, int] | None = None  # the run's configuration: its CONFIG frame and its CRC
        self._config_sent_ns: int | None = None  # when it was last sent (steady clock)
        self._config_unanswered = 0  # CONFIG frames sent since the board's last answer

    # -- lifecycle ---------------------------------------------------------------------------
    def arm(self) -> str:
        """INACTIVE or FAULT -> ARMED (clears a latched fault); ACTIVE stays, unless the board has landed on its
        own (LANDED / FAULT: e.g. its 50 ms command watchdog in a host stall shorter than the driver's): the driver
        would forward commands it ignores, so the operator's arm re-arms it too (OFF clears the board's latch,
        then the controller proves itself again). Returns what happened."""
        if self.state == DriverState.ACTIVE and self.board_mode not in (Mode.LANDED, Mode.FAULT):
            return "already active"
        was = self.state
        self.state = DriverState.ARMED
        self.reason = ""
        self._over = {"current": 0, "gap": 0}
        self.last_cmd_steady = None
        self._in_time = 0
        self._config = self._own_config()  # the parameters as they are now (they may have changed at run time)
        self._config_sent_ns = None
        self._config_unanswered = 0
        if self._config is None:
            return f"not armed: {self.reason}"
        then = "" if self.configured else ", once the board confirms the run's configuration (CONFIG)"
        return (f"armed (was {was.name.lower()}); active after {self.cfg['arm_samples']} controller commands in "
                f"time{then}")

    def disarm(self) -> str:
        """Any state -> INACTIVE (a fault is cleared); a levitating board is told to LAND."""
        was = self.state
        self.state = DriverState.INACTIVE
        self.reason = ""
        return f"disarmed (was {was.name.lower()})"

    clear = disarm

    def fault(self, reason: str) -> None:
        """Latch a fault (the first reason is kept until cleared)."""
        if self.state != DriverState.FAULT:
            self.state = DriverState.FAULT
            self.reason = reason

    def estop(self, reason: str = "e-stop") -> str:
        self.counters["estops"] += 1
        self.fault(f"e-stop: {reason}")
        return self.reason

    # -- board -> PC ---------------------------------------------------------------------------
    def on_bytes(self, data: bytes, ros_ns: int, steady_ns: int) -> tuple[Sample | None, bytes | None]:
        """Decode one frame; (the sample to publish or None, the frame to send back or None)."""
        try:
            frame = decode(data)
        except LinkError as exc:
            self.counters["corrupt"] += 1
            self.corrupt_reasons[exc.reason] = self.corrupt_reasons.get(exc.reason, 0) + 1
            return None, None
        self.counters["frames"] += 1
        self.last_rx_steady = steady_ns
        if isinstance(frame, Hello):
            return None, self._on_hello(frame, steady_ns)
        if isinstance(frame, SensorFrame):
            return self._on_sensor(frame, ros_ns, steady_ns)
        if isinstance(frame, ConfigAck):
            self._on_config_ack(frame)
            return None, None
        what = "config" if isinstance(frame, ConfigFrame) else "command"  # frames the board never sends
        self.counters["corrupt"] += 1
        self.corrupt_reasons[f"unexpected {what} frame"] = self.corrupt_reasons.get(f"unexpected {what} frame", 0) + 1
        return None, None

    def _on_hello(self, h: Hello, steady_ns: int) -> bytes | None:
        """The board's hello: its rate must be ours (a board does not change its clock); then the handshake's second
        step, the run's configuration (its command delay among it: a board that states another one is set to ours,
        and the answer's CRC proves it)."""
        self.hello = h
        rate = round(1e9 / self.dt_ns)
        if h.rate_hz != rate:
            self.fault(f"board samples at {h.rate_hz} Hz, the driver is configured for {rate} Hz (dt)")
            return None
        self.board_config = None  # a new handshake: the board may have restarted with its compiled-in defaults
        self._config = self._own_config()
        self._config_unanswered = 0
        return self._send_config(steady_ns)

    # -- the board's configuration -------------------------------------------------------------
    def _own_config(self) -> tuple[bytes, int] | None:
        """The run's configuration from the parameters now (frame, CRC); None after a fault that says why."""
        try:
            data = encode(config_frame(self.cfg))
        except (BoardConfigError, LinkError) as exc:
            self.fault(f"the board's configuration cannot be sent: {exc}")
            return None
        return data, int.from_bytes(data[-4:], "little")

    @property
    def configured(self) -> bool:
        """The board runs the run's configuration: its newest answer reports the CRC of ours."""
        return (self.board_config is not None and self._config is not None
                and self.board_config.active_crc == self._config[1])

    def _send_config(self, steady_ns: int) -> bytes | None:
        if self._config is None:
            self._config = self._own_config()
            if self._config is None:
                return None
        if self._config_unanswered >= CONFIG_TRIES:
            h = self.hello
            delay = (f"; its hello states command_delay {h.command_delay}, the run's is {self.cfg['command_delay']}"
                     if h is not None and h.command_delay and h.command_delay != self.cfg["command_delay"] else "")
            self.fault(f"the board does not answer the CONFIG frame ({self._config_unanswered} sent, none answered): "
                       f"its firmware predates the link's configuration (docs/hardware-link.md, Config){delay}")
            return None
        self._config_unanswered += 1
        self._config_sent_ns = steady_ns
        self.counters["config_sent"] += 1
        return self._config[0]

    def _on_config_ack(self, a: ConfigAck) -> None:
        """The board's answer: which configuration it runs; a refusal of ours (not a busy one) is a fault."""
        self._config_unanswered = 0
        self.board_config = a
        own = self._config[1] if self._config is not None else None
        if own is None or a.request_crc != own:
            return  # the answer to an older configuration: only the CRC it runs counts
        if a.result == OK and a.active_crc != own:
            self.fault(f"the board accepted the run's configuration (CRC {own:#010x}) but reports it runs "
                       f"{a.active_crc:#010x}")
        elif a.result not in (OK, BUSY):
            self.counters["config_refused"] += 1
            keeps = "the configuration set before" if a.configured else "its compiled-in defaults"
            self.fault(f"the board refuses the run's configuration: {result_text(a.result)}; it keeps {keeps} "
                       f"(CRC {a.active_crc:#010x})")

    def _config_state(self) -> str:
        a = self.board_config
        if a is None:
            return "not sent" if self._config_sent_ns is None else "not answered"
        if self.configured:
            return "confirmed"
        if a.result == BUSY:
            return "busy: the board is not OFF or LANDED"
        return f"not confirmed: {CONFIG_RESULTS[a.result]}"

    def _seq_check(self, seq: int) -> bool:
        """Count lost / duplicated / reordered frames; True when ``seq`` is new and in order."""
        if self.last_seq is None:
            self.last_seq = seq
            return True
        d = seq_diff(seq, self.last_seq)
        if d == 0:
            self.counters["duplicated"] += 1
            return False
        if d < 0:  # behind the newest
            self.counters["reordered"] += 1
            return False
        self.counters["lost"] += d - 1
        self.last_seq = seq
        return True

    def _on_sensor(self, f: SensorFrame, ros_ns: int, steady_ns: int) -> tuple[Sample | None, bytes | None]:
        if not self._seq_check(f.seq):
            return None, None
        self.board_mode = Mode(f.mode)
        self.board_status = f.status
        if f.status:
            bits = self.status_counts
            for flag in Status:
                if f.status & flag:
                    bits[str(flag.name)] = bits.get(str(flag.name), 0) + 1
        self.bus_v = f.bus_v
        board_ns = int(f.board_time_us) * 1000
        if self.offset_ns is None:
            self._sync.append(ros_ns - board_ns)
            if len(self._sync) < self.cfg["clock_sync_frames"]:
                return None, self._reply(f.seq, steady_ns)
            self.offset_ns = min(self._sync)
            self._sync_residual = int(np.median(self._sync)) - self.offset_ns
        stamp = self.offset_ns + board_ns
        latency = ros_ns - stamp
        self.drift_ns = latency - self._sync_residual
        if latency > self.cfg["late_threshold"] * 1e9:
            self.counters["late"] += 1
        gap = self._valid_gaps(self.cal.gap(f.gap_counts), f.status)
        s = Sample(f.seq, stamp, gap, self.cal.current(f.current_counts),
                   self.cal.voltage(f.applied_v, f.bus_v), float(f.bus_v), self.board_mode, f.status, latency)
        self.counters["samples"] += 1
        self.last_sample = s
        self._limits(s)
        return s, self._reply(f.seq, steady_ns)

    def _valid_gaps(self, gap: np.ndarray, status: int) -> np.ndarray:
        """A gap channel the board flags out of range (a dead, unplugged or saturated sensor: GAPj_RANGE)
        is never passed on as a gap: its last valid value is held (counted ``sensor_holds``); after
        ``trip_samples`` such samples in a row the driver trips (the controller cannot control blind)."""
        bad = [bool(status & Status.GAP0_RANGE), bool(status & Status.GAP1_RANGE)]
        for j in (0, 1):
            if bad[j]:
                self.counters["sensor_holds"] += 1
                self._sensor_bad[j] += 1
                gap[j] = self._gap_valid[j]
                if self._sensor_bad[j] >= self.cfg["trip_samples"] and self.state == DriverState.ACTIVE:
                    self.counters["trips"] += 1
                    self.fault(f"gap sensor {j + 1} out of range for {self._sensor_bad[j]} samples (dead or saturated)")
            else:
                self._sensor_bad[j] = 0
                self._gap_valid[j] = gap[j]
        return gap

    def _limits(self, s: Sample) -> None:
        """Trip on ``trip_samples`` consecutive samples beyond the current or gap limits (while levitating)."""
        if self.state not in (DriverState.ACTIVE,):
            self._over = {"current": 0, "gap": 0}
            return
        c = self.cfg
        i_bad = bool(np.any(np.abs(s.current) > c["i_max"]))
        g_bad = bool(np.any(s.gap < c["trip_gap_min"]) or np.any(s.gap > c["trip_gap_max"]))
        self._over["current"] = self._over["current"] + 1 if i_bad else 0
        self._over["gap"] = self._over["gap"] + 1 if g_bad else 0
        hw = s.status & HARDWARE_FAULTS
        self._over["board"] = self._over.get("board", 0) + 1 if hw else 0
        if self._over["board"] >= c["trip_samples"]:
            self.counters["trips"] += 1
            self.fault("board reports " + ", ".join(str(f.name) for f in Status if f & hw)
                       + f" for {self._over['board']} samples")
        elif self._over["current"] >= c["trip_samples"]:
            self.counters["trips"] += 1
            self.fault(f"current limit: |i| = {np.max(np.abs(s.current)):.3f} A > i_max = {c['i_max']:g} A")
        elif self._over["gap"] >= c["trip_samples"]:
            self.counters["trips"] += 1
            self.fault(f"gap limit: gaps {s.gap[0] * 1e3:.3f} / {s.gap[1] * 1e3:.3f} mm outside "
                       f"[{c['trip_gap_min'] * 1e3:g}, {c['trip_gap_max'] * 1e3:g}] mm")

    # -- PC -> board ---------------------------------------------------------------------------
    def _land_frame(self, seq: int) -> bytes:
        self.counters["land_sent"] += 1
        return encode(CommandFrame(seq, (0.0, 0.0), Mode.LAND))

    def _reply(self, seq: int, steady_ns: int) -> bytes | None:
        """What to send when sensor frame ``seq`` arrives (besides the controller's commands)."""
        self.check(steady_ns)
        if self.state == DriverState.FAULT:
            return self._land_frame(seq)
        if self.state == DriverState.INACTIVE and self.board_mode in LEVITATING:
            return self._land_frame(seq)
        if self.state in (DriverState.INACTIVE, DriverState.ARMED) and not self.configured and (
                self._config_sent_ns is None or steady_ns - self._config_sent_ns >= CONFIG_RETRY_NS):
            return self._send_config(steady_ns)  # the run's configuration first (a busy board: again, later)
        if self.state == DriverState.ARMED and self.board_mode in (Mode.LANDED, Mode.FAULT):
            return encode(CommandFrame(seq, (0.0, 0.0), Mode.OFF))  # the operator armed: clear the board's latch
        want = (seq - self.cfg["command_delay"]) % SEQ_MOD
        if self.state == DriverState.ACTIVE and self.last_cmd_seq is not None and self._sent[want % SENT_RING] != want:
            self.counters["hold_samples"] += 1  # the board starts this period without a fresh command: it holds
        return None

    def check(self, steady_ns: int) -> bytes | None:
        """Timeouts on the steady clock (also call it from a timer: a silent link must still trip).

        ACTIVE with no controller command for ``command_timeout`` (0: ``hold_timeout``, the board's) -> FAULT (the
        board lands);
        no sensor frame for ``link_timeout`` -> FAULT (the board's own watchdog lands it).
        """
        c = self.cfg
        if self.state == DriverState.ACTIVE and self.last_cmd_steady is not None:
            quiet = (steady_ns - self.last_cmd_steady) * 1e-9
            limit, name = ((c["command_timeout"], "command_timeout") if c.get("command_timeout")
                           else (c["hold_timeout"], "hold_timeout"))
            if quiet > limit:
                self.counters["watchdog"] += 1
                self.fault(f"command watchdog: no controller command for {quiet * 1e3:.1f} ms (> {name})")
        if self.state in (DriverState.ARMED, DriverState.ACTIVE) and self.last_rx_steady is not None:
            quiet = (steady_ns - self.last_rx_steady) * 1e-9
            if quiet > c["link_timeout"] and self.state == DriverState.ARMED:
                self._stall(quiet)
            elif quiet > c["link_timeout"]:
                self.counters["link_loss"] += 1
                self.fault(f"link lost: no sensor frame for {quiet * 1e3:.1f} ms (> link_timeout)")
        return None

    def _stall(self, quiet_s: float) -> None:
        """Armed, not yet active, and no frame for ``link_timeout``: a host stall (the process did not run) or
        a link that paused. The board has no command of ours to hold and levitates nothing for us yet, so
        nothing is at stake: no fault is latched. The driver handshakes again (hello: the node asks until the
        board answers; the loop proves itself again over ``arm_samples`` commands) and counts the stall
        (``stalls``, the longest in ``longest_stall_ms``: reported on /diagnostics)."""
        self.counters["stalls"] += 1
        self.longest_stall_ms = max(self.longest_stall_ms, round(quiet_s * 1e3, 1))
        self.hello = None
        self.board_config = None  # confirmed again after the new hello (the board may have restarted)
        self._in_time = 0
        self.last_rx_steady = None  # quiet from the next frame on

    def command(self, stamp_ns: int, u, steady_ns: int) -> bytes | None:
        """A controller command (voltages [V], stamped with its measurement) -> a RUN frame, or None.

        Forwarded only when ACTIVE (ARMED -> ACTIVE after ``arm_samples`` consecutive commands in time:
        the loop proves itself live before the board gets its first command), for a sample the board has not yet passed
        (newest seq - its seq < ``command_delay``: the board applies it at its tick seq + command_delay).
        A command too late to apply is counted ``commands_stale`` but still proves the controller
        alive: the watchdog measures the controller, the board's own watchdog the freshness.
        """
        if self.state not in (DriverState.ARMED, DriverState.ACTIVE):
            self.counters["commands_dropped"] += 1
            return None
        u = np.asarray(u, dtype=float)
        if u.shape != (2,) or not np.all(np.isfinite(u)) or self.offset_ns is None or self.last_seq is None:
            self.counters["commands_dropped"] += 1
            return None
        seq = self._seq_of(stamp_ns)
        behind = seq_diff(self.last_seq, seq)  # the board applies it at its tick seq + command_delay
        if behind < 0:
            self.counters["commands_dropped"] += 1  # from the future: not our clock
            return None
        if self.state == DriverState.ACTIVE:
            self.last_cmd_steady = steady_ns  # the controller is alive (the watchdog's question)
        if behind >= self.cfg["command_delay"]:
            self.counters["commands_stale"] += 1  # too late to be applied: the board holds (its own watchdog)
            self._in_time = 0
            return None
        if self.state == DriverState.ARMED:
            self._in_time += 1  # the loop proves itself live before the board gets its first command
            if self._in_time < self.cfg["arm_samples"] or not self.configured:  # ... and runs the run's configuration
                return None
            self.state = DriverState.ACTIVE
        self.last_cmd_steady = steady_ns
        self.last_cmd_seq = seq
        self._sent[seq % SENT_RING] = seq
        lim = self.cfg["u_max"]
        uc = np.clip(u, -lim, lim)
        if np.any(uc != u):
            self.counters["clipped"] += 1
        self.u_last = uc
        self.counters["commands_sent"] += 1
        return encode(CommandFrame(seq, self.cal.command(uc, self.bus_v), Mode.RUN))

    def _seq_of(self, stamp_ns: int) -> int:
        """The board sample a stamp belongs to (inverse of the clock map)."""
        assert self.offset_ns is not None and self.last_sample is not None
        k = round((stamp_ns - self.last_sample.stamp_ns) / self.dt_ns)
        return (self.last_sample.seq + k) % SEQ_MOD

    # -- reporting -----------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """Everything a status display or /diagnostics needs, as plain values."""
        a = self.board_config
        out: dict[str, Any] = {"state": self.state.name.lower(), "reason": self.reason,
                               "board_mode": Mode(self.board_mode).name.lower(), "board_status": self.board_status,
                               "bus_v": round(self.bus_v, 2), "clock_drift_us": round(self.drift_ns / 1e3, 1),
                               "board_id": self.hello.board_id if self.hello else -1,
                               "longest_stall_ms": self.longest_stall_ms, "board_config": self._config_state(),
                               "config_crc": f"{self._config[1]:08x}" if self._config is not None else "",
                               "board_config_crc": f"{a.active_crc:08x}" if a is not None else "",
                               "board_configured": bool(a is not None and a.configured)}
        out.update(self.counters)
        for k, v in sorted(self.corrupt_reasons.items()):
            out[f"corrupt: {k}"] = v
        for k, v in sorted(self.status_counts.items()):
            out[f"board: {k}"] = v
        return out

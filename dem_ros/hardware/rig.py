r"""``dem-ros rig``: an emulator of the I/O board and the DEM rig behind the device link.

Its own process, free-running at 1 kHz against absolute deadlines: what a real board
does, with the core plant (:class:`dem_ros.core.plant.DemPlant`, the scenario's true
parameters, disturbances and noise) in place of the rig.

Every period n (t_n = n T on the board's clock)::

    1. read every command frame received since the last tick (non-blocking)
    2. sample: gaps and currents of the plant at t_n -> sensor models -> ADC counts
    3. send SensorFrame(seq=n, board_time, counts, applied voltage over [t_n-1, t_n], bus, status, mode)
    4. the Supervisor (dem_ros.board, the board's limits, braking check, hold and landing
       law) turns the command answering sample n - d (d = ``hw_driver.command_delay``; none: it
       holds, then lands) into voltages, braking with at most the bus it measures -> actuator
       models -> the coils. ``rig.board=c``: the firmware's supervisor instead (firmware/supervisor.c,
       C99 float32, through dem_ros.hardware.cboard), the code a rig builder flashes
    5. integrate the plant over [t_n, t_n+1] with those voltages held (zero-order hold)

so a command computed from sample k acts over [t_k+d, t_k+d+1), as in ``plant_sim``.
A command frame's mode is a request: RUN, LAND (land now) or OFF (acknowledge a landing:
the Supervisor's ``clear()`` once LANDED). The board answers a hello request with its :class:`Hello` and streams only
after it (UDP: to the address of the newest hello).

Configuration (docs/hardware-link.md, "Config"): the board starts with the defaults it was "built" with (the
``plant_sim`` group's safety specs and nominal plant, the ``hw_driver`` group's calibration and command delay) and
answers every :class:`ConfigFrame` with a :class:`ConfigAck`, as the firmware does (``board.c``): taken only while
OFF or LANDED, only with its own ``dt`` and when the board's checks pass (``boardcfg.check_config``; ``rig.board=c``:
the firmware's own ``sup_init()``), else the active configuration stays. A new supervisor configuration restarts the
supervisor (OFF); the calibration converts the board's counts from then on (the sensors' physics stay the rig's).

Sensor and actuator models: :mod:`dem_ros.board.rig_io` (ADC counts of the gaps and currents, with the
``rig`` group's gain, offset and noise; a gap count at either end of the range: GAPj_RANGE; the bus with
its sag, the PWM bridges and their current limit).
Mechanics: the plate rests on a support at ``support_gap`` (gaps never exceed it).

Start (``start``): ``hover`` clamps the plate at the scenario's hover (x0, u0: what a
running rig looks like) until the first RUN command releases it — the emulator's stand-in
for plant_sim's pre-start hover; ``landed`` starts on the support with no current.

Faults (``--fault``, times in seconds after the release; see :func:`parse_fault`)::

    dropout:J@T[+D]   gap sensor J reads 0 counts (a dead sensor) for D s (default: to the end)
    stuck:J@T[+D]     gap sensor J repeats its last reading
    spike:J@T         one sample of gap sensor J at full scale
    corrupt@T[+D][:P] a fraction P (default 1) of sent frames get a flipped byte (CRC fails)
    linkloss@T+D      nothing sent or received for D s
    sag@T[+D][:V]     bus voltage drops to V volts (default 60)
    coil:J@T[+D]      coil driver J fails (open: no voltage; DRIVERj_FAULT)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import runstate
from ..core.hold import command_sample
from .boardcfg import BUSY, OK, check_config, config_crc, config_frame, python_sup_result
from .link import (
    CONFIG_SUP_KEYS,
    PROTOCOL_VERSION,
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
from .sensors import ShimInput, parse_shims

__all__ = ["FAULT_KINDS", "Board", "Fault", "RigError", "main", "parse_fault", "run_rig"]

CMD_RING = 16  # commands kept by sample number
FAULT_KINDS = ("dropout", "stuck", "spike", "corrupt", "linkloss", "sag", "coil")


class RigError(ValueError):
    """Bad rig configuration or fault specification; the message says what and how to write it."""


@dataclass
class Fault:
    """One injected fault: ``kind`` on ``channel`` (1 or 2; 0: not per channel) during [start, end) s."""

    kind: str
    channel: int
    start: float
    end: float
    value: float = math.nan
    hits: int = 0  # samples it acted on

    def active(self, t: float) -> bool:
        return self.start <= t < self.end

    def window(self, dt: float) -> tuple[int, float]:
        """[first, end) sample numbers after the release it acts on: its times rounded to the board's grid
        (a float sum such as 0.1 + 0.05 = 0.15000000000000002 must not add a sample); at least one sample."""
        k0 = round(self.start / dt)
        return k0, (max(k0 + 1, round(self.end / dt)) if math.isfinite(self.end) else math.inf)


def parse_fault(text: str) -> Fault:
    """``KIND[:J]@T[+D][:VALUE]`` -> Fault; RigError with the accepted forms otherwise."""
    usage = (f"fault {text!r}: expected KIND[:J]@T[+D][:VALUE], KIND one of {', '.join(FAULT_KINDS)} "
             "(e.g. dropout:1@5+0.5, linkloss@10+0.05, sag@3:60, corrupt@2+1:0.2)")
    try:
        head, _, rest = text.partition("@")
        kind, _, ch = head.partition(":")
        when, _, value = rest.partition(":")
        start_s, _, dur_s = when.partition("+")
        start = float(start_s)
        dur = float(dur_s) if dur_s else math.inf
        val = float(value) if value else math.nan
        channel = int(ch) if ch else 0
    except ValueError:
        raise RigError(usage) from None
    if kind not in FAULT_KINDS or not rest or start < 0 or dur <= 0 or not math.isfinite(start):
        raise RigError(usage)
    per_channel = kind in ("dropout", "stuck", "spike", "coil")
    if per_channel != (channel in (1, 2)):
        raise RigError(usage + (": this fault needs :1 or :2" if per_channel else ": this fault takes no channel"))
    if kind == "spike":
        dur = 1e-9  # one sample
    if kind == "linkloss" and not math.isfinite(dur):
        raise RigError(usage + ": linkloss needs a duration (+D)")
    if kind == "corrupt" and not (math.isnan(val) or 0 < val <= 1):
        raise RigError(usage + ": the corrupted fraction is in (0, 1]")
    if kind == "sag" and not (math.isnan(val) or val >= 0):
        raise RigError(usage + ": the sagged bus voltage is >= 0 V")
    return Fault(kind, channel, start, start + dur, val)


@dataclass
class BoardCounters:
    ticks: int = 0
    sent: int = 0
    rx_frames: int = 0
    rx_rejected: int = 0
    rx_reasons: dict[str, int] = field(default_factory=dict)
    commands_fresh: int = 0
    commands_stale: int = 0
    hellos: int = 0
    overruns: int = 0
    corrupted_tx: int = 0
    link_lost_ticks: int = 0
    configs: int = 0
    configs_refused: int = 0


class Board:
    """The board and the rig, one tick at a time (no clock, no socket: testable alone).

    Args:
        pc: the ``plant_sim`` group (true plant, scenario, and the board's safety specs).
        rig: the ``rig`` group (sensor, actuator, link settings).
        hw: the ``hw_driver`` group (the sensors' nominal calibration).
        faults: injected faults.
    """

    def __init__(self, pc: Mapping[str, Any], rig: Mapping[str, Any], hw: Mapping[str, Any],
                 faults: list[Fault] | None = None, preroll: float | None = None):
        from ..board import SafetyError, Supervisor
        from ..board.rig_io import CoilDrivers, CurrentSensors, GapSensors
        from ..core.model import IP, IQ
        from ..core.plant import DemPlant
        from .cboard import CSupervisor

        self.pc, self.rc = dict(pc), dict(rig)
        self.dt = pc["dt"]
        self.plant = DemPlant(pc, 0.0)
        self._pq = (float(self.plant.p[IP]), float(self.plant.p[IQ]))  # magnet gap delta = P d_near + Q d_far
        self.c_board = rig.get("board", "python") == "c"
        if self.c_board:  # the firmware's supervisor (C99, float32) through its binding
            self.sup: Supervisor | CSupervisor = CSupervisor(pc, self.dt)
            self.board_name = "c (firmware/supervisor.c)"
        else:
            self.sup = Supervisor(pc, self.dt)
            self.board_name = "python (dem_ros.board)"
        # the configuration it was built with (its firmware header): the plant's safety specs and nominal plant,
        # the sensors' data-sheet calibration and the command delay; a PC's CONFIG replaces it (receive)
        self.config = config_frame({**hw, **{k: pc[k] for k in CONFIG_SUP_KEYS}})
        self.config_crc = config_crc(self.config)
        self.configured = False
        self.bcfg = self.config.as_dict()  # the active values (float32, as the board stores them)
        self._cal: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # a calibration set over the link
        self.faults = list(faults or [])
        self.rng = np.random.default_rng(rig["seed"])
        try:
            self.gap_sensors = GapSensors(hw, rig["adc_bits"], rig["gap_gain_error"], rig["gap_offset_error"],
                                          rig["gap_curve"])
        except SafetyError as exc:
            raise RigError(str(exc)) from None
        self.full = self.gap_sensors.full
        self.current_sensors = CurrentSensors(hw, rig["adc_bits"])
        self.drivers = CoilDrivers(rig["bus_voltage"], rig["bus_resistance"], rig["pwm_bits"], rig["current_limit"])
        self.n = 0
        self.released_at: int | None = None
        self.delay = self.config.command_delay  # the command answering sample k is applied from tick k + delay
        self.n_pre = round((hw["preroll"] if preroll is None else preroll) / self.dt)
        self.cmds: list[CommandFrame | None] = [None] * CMD_RING
        self.request, self.request_seq = Mode.OFF, -1
        self.applied = np.zeros(2)
        self.u_next = np.zeros(2)
        if rig["start"] == "hover":
            self.applied = self.plant.u0.copy()
        else:
            g = rig["support_gap"]
            self.plant.x[:] = [g, 0.0, g, 0.0, 0.0, 0.0]
        self.last_counts = [0, 0]
        self.shims: tuple[float, float] | None = None  # resting on shims (d1, d2) [m]: hardware/sensors.py
        self.driver_fault = 0  # DRIVERj_FAULT bits seen while applying the last period's voltages
        self.streaming = False
        self.c = BoardCounters()
        self.failed: str | None = None  # the plant's failure (rail contact): the emulation stops moving
        self.min_gap = math.inf  # the true plate's smallest load-point or magnet gap since the release [m]
        self.land_speed_max = 0.0  # the true plate's fastest descent (a load point, away from the rail) while the
        #                            board lands it, up to and including the touch-down on the support [m/s]

    # -- time ----------------------------------------------------------------------------------
    def t_fault(self) -> float:
        """Seconds since the release (faults are scheduled on it); -1 before."""
        return -1.0 if self.released_at is None else (self.n - self.released_at) * self.dt

    def _fault(self, kind: str, channel: int = 0) -> Fault | None:
        if self.released_at is None:
            return None
        k = self.n - self.released_at  # on the sample grid: a D s fault acts on round(D / dt) samples
        for f in self.faults:
            if f.kind == kind and f.channel == channel:
                k0, k1 = f.window(self.dt)
                if k0 <= k < k1:
                    return f
        return None

    # -- link in -------------------------------------------------------------------------------
    def receive(self, data: bytes) -> bytes | None:
        """One received frame; returns the hello answer when it is a hello request."""
        if self._fault("linkloss"):
            self.c.link_lost_ticks += 0  # counted per tick in tick()
            return None
        try:
            f = decode(data)
        except LinkError as exc:
            self.c.rx_rejected += 1
            self.c.rx_reasons[exc.reason] = self.c.rx_reasons.get(exc.reason, 0) + 1
            self._rx_error = True
            return None
        self.c.rx_frames += 1
        if isinstance(f, Hello):
            self.c.hellos += 1
            self.streaming = True
            return encode(Hello(PROTOCOL_VERSION, self.rc["board_id"], round(1 / self.dt), self.rc["adc_bits"],
                                self.rc["adc_vref"], round(self.bcfg["hold_timeout"] * 1e3), self.delay))
        if isinstance(f, ConfigFrame):
            return encode(self.configure(f, int.from_bytes(data[-4:], "little")))
        if isinstance(f, CommandFrame):
            if f.mode == Mode.RUN:
                self.cmds[f.seq % CMD_RING] = f  # kept by the sample it answers
            if self.request_seq < 0 or seq_diff(f.seq, self.request_seq) >= 0:
                self.request, self.request_seq = Mode(f.mode), f.seq  # the newest frame's mode request
        return None

    def configure(self, f: ConfigFrame, crc: int) -> ConfigAck:
        """A configuration received over the link (its CRC: the frame's CRC field); the answer (module docstring)."""
        self.c.configs += 1
        mode = Mode(self.sup.mode)
        result = OK
        if mode not in (Mode.OFF, Mode.LANDED):
            result = BUSY  # never a change in flight (or with a latched fault)
        elif crc != self.config_crc:
            from .cboard import sup_config_result as c_sup_config_result

            result = check_config(f, self.bcfg["dt"], c_sup_config_result if self.c_board else python_sup_result)
            if result == OK:
                self._apply(f, crc)
        if result == OK:
            self.configured = True
        else:
            self.c.configs_refused += 1
        return ConfigAck(self.config_crc, crc, result, self.configured, Mode(self.sup.mode))

    def _apply(self, f: ConfigFrame, crc: int) -> None:
        from ..board import Supervisor
        from .cboard import CSupervisor

        n_sup = len(CONFIG_SUP_KEYS)
        if f.values[:n_sup] != self.config.values[:n_sup]:  # new limits or model: a restarted supervisor (OFF)
            sup_cfg = dict(zip(CONFIG_SUP_KEYS, f.values[:n_sup], strict=True))
            self.sup = CSupervisor(sup_cfg, self.dt) if self.c_board else Supervisor(sup_cfg, self.dt)
        if f.values[n_sup:] != self.config.values[n_sup:]:  # the board's conversion from now on (board.c's)
            v = f.as_dict()
            self._cal = (np.array([[v[f"gap{j}_c{p}"] for p in range(4)] for j in (1, 2)]),
                         np.array([v["current1_gain"], v["current2_gain"]]),
                         np.array([v["current1_offset"], v["current2_offset"]]))
        self.delay = f.command_delay
        self.config, self.config_crc, self.bcfg = f, crc, f.as_dict()

    # -- one period ------------------------------------------------------------------------------
    def tick(self, overrun: bool = False) -> bytes | None:
        """Sample, build the sensor frame, choose and apply the voltages, integrate one period."""
        n = self.n
        status = 0
        if overrun:
            status |= Status.OVERRUN
            self.c.overruns += 1
        if getattr(self, "_rx_error", False):
            status |= Status.RX_ERROR
            self._rx_error = False
        if self.shims is not None:  # on shims: coils off, the plate held at their thicknesses
            self.plant.x[:] = [self.shims[0], 0.0, self.shims[1], 0.0, 0.0, 0.0]
        x = self.plant.x
        z = self.plant.measurement() if self.released_at is not None else x.copy()
        gaps, currents = np.array([z[0], z[2]]), np.array([z[4], z[5]])
        gc, st = self._gap_counts(gaps)
        status |= st
        cc = self._current_counts(currents)
        bus = self._bus(x)
        if bus < self.rc["bus_min"]:
            status |= Status.BUS_UNDERVOLTAGE
        status |= self.driver_fault
        self.driver_fault = 0
        # the command answering sample n - delay (fresh) decides the next period
        want = command_sample(n, self.delay) % (1 << 32)  # the link numbers samples modulo 2^32
        cmd = self.cmds[want % CMD_RING]
        fresh = cmd is not None and cmd.seq == want and self.request == Mode.RUN
        if fresh:
            self.c.commands_fresh += 1
        requested = self.request
        if requested == Mode.OFF and self.sup.mode in (Mode.LANDED, Mode.FAULT):
            self.sup.clear()  # the operator armed the PC: acknowledge the latched landing
        if requested == Mode.RUN and not fresh and self.sup.mode in (Mode.OFF, Mode.LANDED):
            requested = Mode.OFF
        if self.sup.mode == Mode.RUN and not fresh:
            status |= Status.COMMAND_LATE
        if self._cal is None:  # the board sees what its ADC sees, converted with its calibration
            meas_y, meas_i = self.gap_sensors.gaps(gc), self.current_sensors.currents(cc)
        else:
            poly, gain, offset = self._cal
            n_g, n_c = np.array(gc, float), np.array(cc, float)
            meas_y = poly[:, 0] + n_g * (poly[:, 1] + n_g * (poly[:, 2] + n_g * poly[:, 3]))
            meas_i = gain * (n_c - offset)
        meas_y = self._board_gaps(meas_y, st)
        u_cmd = np.array(cmd.u, float) if fresh and cmd is not None else None
        u = self.sup.step(int(n * self.dt * 1e9), meas_y, meas_i, u_cmd, requested, bus=bus,
                          applied=self.plant.coil_voltage if self.released_at is not None else self.applied)
        mode = Mode(self.sup.mode)
        if mode == Mode.RUN and self.released_at is None:
            self.released_at = n
        frame = SensorFrame(n % (1 << 32), round(n * self.dt * 1e6), gc, cc,
                            (float(self.applied[0]), float(self.applied[1])), float(bus),
                            int(status | self._sup_status(u_cmd)), mode)
        held = (self.released_at is None and self.rc["start"] == "hover") or self.shims is not None  # clamped
        self.applied = self._actuate(np.asarray(u, float), bus, currents) if not held else self.applied
        if not held and self.failed is None:
            self._advance()
        self.n += 1
        self.c.ticks += 1
        if not self.streaming:
            return None
        lost = self._fault("linkloss")
        if lost is not None:
            lost.hits += 1  # a sample the link did not carry ("acted on N samples": the summary's count)
            self.c.link_lost_ticks += 1
            return None
        data = encode(frame)
        f = self._fault("corrupt")
        if f is not None and self.rng.random() < (1.0 if math.isnan(f.value) else f.value):
            f.hits += 1
            self.c.corrupted_tx += 1
            b = bytearray(data)
            b[int(self.rng.integers(4, len(b)))] ^= 0x5A
            data = bytes(b)
        self.c.sent += 1
        return data

    def _sup_status(self, u_cmd) -> int:
        s = 0
        if self.sup.mode in (Mode.LAND, Mode.LANDED) and self.sup.command_timeout:
            s |= Status.LINK_TIMEOUT
        if u_cmd is not None and np.any(np.abs(u_cmd) > self.bcfg["u_max"]):
            s |= Status.VOLTAGE_CLIPPED
        for j in (0, 1):
            if self.sup.implausible[j]:
                s |= Status.GAP0_IMPLAUSIBLE << j
        return s

    def _advance(self) -> None:
        p = self.plant
        k_run = self.n - (self.released_at if self.released_at is not None else self.n)
        if k_run < self.n_pre or self.released_at is None:
            p.hold(self.applied)  # pre-roll: true dynamics, no scenario disturbances yet
        else:
            p.advance(self.applied)
        x = p.x
        if self.released_at is not None:
            P, Q = self._pq
            self.min_gap = min(self.min_gap, x[0], x[2], P * x[0] + Q * x[2], Q * x[0] + P * x[2])
        if self.sup.mode == Mode.LAND:  # before the support clamps it: the touch-down speed counts
            self.land_speed_max = max(self.land_speed_max, x[1], x[3])
        sup = self.rc["support_gap"]
        for j in (0, 2):  # the support: the plate cannot move beyond it
            if x[j] >= sup:
                x[j] = sup
                x[j + 1] = min(x[j + 1], 0.0)
        if p.fault and "dropped" in p.fault:
            p.fault = None  # resting on the support is not a failure
        if p.fault:
            self.failed = p.fault

    # -- sensor and actuator models ---------------------------------------------------------------
    def _gap_counts(self, gaps: np.ndarray) -> tuple[tuple[int, int], int]:
        out, status = [], 0
        for j in (0, 1):
            f = self._fault("dropout", j + 1)
            if f is not None:
                f.hits += 1
                out.append(0)
                status |= Status.GAP0_RANGE << j
                continue
            f = self._fault("stuck", j + 1)
            if f is not None:
                f.hits += 1
                out.append(self.last_counts[j])
                continue
            f = self._fault("spike", j + 1)
            if f is not None:
                f.hits += 1
                out.append(self.full)
                status |= Status.GAP0_RANGE << j
                continue
            d = self.gap_sensors.sensed(j, float(gaps[j]))  # its curve (board/rig_io.py, rig.gap_curve)
            if self.rc["gap_noise"] > 0:
                d += self.rng.normal(0.0, self.rc["gap_noise"])
            c = self.gap_sensors.count(j, d)
            if self.gap_sensors.out_of_range(c):
                status |= Status.GAP0_RANGE << j
            out.append(c)
        self.last_counts = out
        return (out[0], out[1]), status

    def _board_gaps(self, y: np.ndarray, status: int) -> np.ndarray:
        """What the board's firmware feeds its supervisor: a channel out of range (GAPj_RANGE: dead or
        saturated) is no sample (NaN): the supervisor rides its observer through a few, then lands with that
        gap from its coil's flux (docs/manual/board.md, "Lost sensor samples"); it never steers by a dead sensor,
        nor by the other channel in its place."""
        for j in (0, 1):
            if status & (Status.GAP0_RANGE << j):
                y[j] = math.nan
        return y

    def _current_counts(self, currents: np.ndarray) -> tuple[int, int]:
        i = currents + (self.rng.normal(0.0, self.rc["current_noise"], 2) if self.rc["current_noise"] > 0 else 0.0)
        return self.current_sensors.counts(i)

    def _bus(self, x: np.ndarray) -> float:
        f = self._fault("sag")
        supply = None
        if f is not None:
            f.hits += 1
            supply = 60.0 if math.isnan(f.value) else f.value
        return self.drivers.bus(x[4], x[5], supply)

    def _actuate(self, u: np.ndarray, bus: float, currents: np.ndarray) -> np.ndarray:
        failed = [False, False]
        for j in (0, 1):
            f = self._fault("coil", j + 1)
            if f is not None:
                f.hits += 1
                self.driver_fault |= Status.DRIVER0_FAULT << j  # reported with the next sample
                failed[j] = True  # an open bridge: no voltage
        return self.drivers.apply(u, bus, currents, (failed[0], failed[1]))

    def summary(self) -> dict[str, Any]:
        c = self.c
        x = self.plant.x
        return {"board": self.board_name, "ticks": c.ticks, "sent": c.sent, "rx_frames": c.rx_frames,
                "rx_rejected": c.rx_rejected,
                "rx_reasons": dict(c.rx_reasons), "commands_fresh": c.commands_fresh, "hellos": c.hellos,
                "overruns": c.overruns, "corrupted_tx": c.corrupted_tx, "link_lost_ticks": c.link_lost_ticks,
                "config_crc": f"{self.config_crc:08x}", "configured": self.configured, "configs": c.configs,
                "configs_refused": c.configs_refused,
                "mode": Mode(self.sup.mode).name, "reason": getattr(self.sup, "reason", ""),
                "supervisor": self.sup.snapshot(),
                "gaps_mm": [round(x[0] * 1e3, 4), round(x[2] * 1e3, 4)], "failed": self.failed or "",
                "min_gap_mm": round(self.min_gap * 1e3, 4) if math.isfinite(self.min_gap) else None,
                "landings": self.sup.counters["landings"], "land_speed_max_mm_s": round(self.land_speed_max * 1e3, 3),
                "faults": [{"kind": f.kind, "channel": f.channel, "start": f.start, "hits": f.hits}
                           for f in self.faults]}


# -- the process ------------------------------------------------------------------------------------
def _realtime() -> str:
    """The board's loop under dem_ros.realtime's settings (SCHED_FIFO 10 above the graph's, mlockall,
    1 us timer slack) where permitted: the board is the clock, it must not wait for the PC's processes."""
    import dataclasses

    from ..realtime import apply, config_from_env

    cfg = config_from_env()
    cfg = dataclasses.replace(cfg, priority=min(cfg.priority + 10, 99))
    g = apply(cfg)
    return f"SCHED_FIFO {g.fifo_priority}" if g.fifo_priority else "normal priority (" + "; ".join(g.missing) + ")"


def _say(out: Any, event: str, **values: Any) -> None:
    """One event of the emulator: a ``RIG {json}`` line on ``out`` (for people and scripts) and the same event on a
    launcher's run-state pipe (:mod:`dem_ros.runstate`, node ``rig``; nothing when started by hand)."""
    print("RIG " + json.dumps({"event": event, **values}), file=out, flush=True)
    runstate.announce(event, "rig", **values)


def run_rig(cfg: Mapping[str, Mapping[str, Any]], faults: list[Fault], *, duration: float = 0.0,
            status_every: float = 1.0, stop: list[bool] | None = None, out=sys.stdout,
            shims: tuple[float, float] | None = None, shims_stdin: bool = False,
            summary_file: str | None = None) -> dict[str, Any]:
    """Open the board's end of the link and run the board at 1 kHz until ``duration`` (0: until stopped).

    Prints ``RIG {json}`` lines: ``listening`` (with the URL the PC opens), ``mode`` at each of the board's mode
    changes but RUN <-> HOLD (its time, the mode, the reason: the rig's log names every landing when it happens;
    holds are counted), a status every
    ``status_every`` s, and the summary at the end; each also as a run-state event for a launcher (:func:`_say`),
    the summary there as the name of ``summary_file`` (written with it as JSON: a summary can outgrow an event).
    ``stop``: a flag list a signal handler sets.
    """
    from .channel import open_channel

    warm = Board(cfg["plant_sim"], cfg["rig"], cfg["hw_driver"], [])  # compile every kernel before the clock starts
    for _ in range(3):
        warm.tick()
    # and the plant's kernel: a hover start holds the plate until the release, so the ticks above never ran it;
    # loading it at the release stalled the clock 32 ms after the Python supervisor had loaded numba, 1.2-2 s
    # with the C board (numba itself loaded then): the first commands arrived late, the board landed at once
    warm.plant.hold(warm.applied)
    board = Board(cfg["plant_sim"], cfg["rig"], cfg["hw_driver"], faults)
    board.shims = shims
    if shims_stdin:  # an emulated calibration session: 'shims MM[,MM]' lines place the plate on shims
        def place(v: tuple[float, float] | None) -> None:
            board.shims = v
            _say(out, "shims", mm=[round(x * 1e3, 6) for x in v] if v else None)

        ShimInput(sys.stdin, place, lambda m: _say(out, "input", message=m))
    ch = open_channel(cfg["rig"]["url"], "board")
    peer = getattr(ch, "peer_url", cfg["rig"]["url"])
    stop = stop if stop is not None else [False]
    import gc

    gc.collect()  # the start-up garbage now, at normal priority: a collection under SCHED_FIFO would stall
    gc.freeze()  # the board's clock (and every process below it) for tens of ms
    rt = _realtime()
    _say(out, "listening", url=peer, scheduling=rt, faults=len(faults), board=board.board_name)
    dt_ns = round(board.dt * 1e9)
    t0 = time.monotonic_ns()
    next_status = t0
    late_over_1ms = 0
    mode = int(board.sup.mode)
    try:
        while not stop[0]:
            due = t0 + board.n * dt_ns
            now = time.monotonic_ns()
            if now < due:
                time.sleep((due - now) * 1e-9)
                now = time.monotonic_ns()
            late = now - due
            if late > dt_ns:
                late_over_1ms += 1
            while True:  # every frame received since the last tick
                data = ch.recv(0.0)
                if data is None:
                    break
                reply = board.receive(data)
                if reply is not None:
                    ch.send(reply)
            frame = board.tick(overrun=late > dt_ns)
            if frame is not None:
                ch.send(frame)
            if int(board.sup.mode) != mode:  # (after the frame: the line is off the board's 1 ms path)
                was, mode = mode, int(board.sup.mode)
                if {was, mode} != {Mode.RUN, Mode.HOLD}:  # a late command held, or the next: counted, not logged
                    _say(out, "mode", t_s=round(board.n * board.dt, 3), mode=Mode(mode).name,
                         reason=getattr(board.sup, "reason", ""), wall_ns=time.time_ns())
            if now >= next_status:
                next_status += int(status_every * 1e9)
                s = board.summary()
                _say(out, "status", t_s=round(board.n * board.dt, 3), mode=s["mode"], gaps_mm=s["gaps_mm"],
                     late_over_1ms=late_over_1ms, rx_frames=s["rx_frames"], fresh=s["commands_fresh"],
                     landings=s["landings"], reason=s["reason"])
            if duration and board.n * board.dt >= duration:
                break
    finally:
        ch.close()
    s = board.summary()
    s["late_over_1ms"] = late_over_1ms
    s["channel"] = dict(ch.stats)
    print("RIG " + json.dumps({"event": "summary", **s}), file=out, flush=True)
    if summary_file:
        tmp = summary_file + ".tmp"
        with open(tmp, "w") as f:
            json.dump(s, f)
        os.replace(tmp, summary_file)  # whole or not at all
        runstate.announce("summary", "rig", file=summary_file)
    return s


def rig_config(scenario: str, params: str | None, sets: list[str]) -> dict[str, dict[str, Any]]:
    """The scenario's configuration, a params file on top, then GROUP.NAME=VALUE assignments (NAME alone: rig's)."""
    from ..core.scenarios import scenario_config

    return scenario_config(scenario, params, sets, default_group="rig")


def build_parser(p: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    p = p or argparse.ArgumentParser(prog="dem-ros rig",
                                     description="emulate the DEM rig and its I/O board behind the device link")
    p.add_argument("--url", default=None, help="udp://HOST:PORT or pty:// (default: rig.url)")
    p.add_argument("--scenario", default="S1", help="the true plant and its disturbances (default S1)")
    p.add_argument("--params", default=None, help="ROS 2 params file (the launch's: plant_sim, rig, hw_driver groups)")
    p.add_argument("--set", action="append", default=[], metavar="GROUP.NAME=VALUE",
                   help="override, e.g. rig.gap_noise=1e-6")
    p.add_argument("--fault", action="append", default=[], metavar="SPEC",
                   help="inject a fault, e.g. dropout:1@5+0.5 (see --help-faults)")
    p.add_argument("--duration", type=float, default=0.0,
                   help="stop after this many seconds of board time (0: until Ctrl-C)")
    p.add_argument("--help-faults", action="store_true", help="describe the fault specifications")
    p.add_argument("--shims", default=None, metavar="MM[,MM]", help="rest the plate on shims of these thicknesses "
                   "(coils off): a calibration session (dem-ros calibrate gaps --url)")
    p.add_argument("--shims-stdin", action="store_true", help="read 'shims MM[,MM]' / 'shims off' lines from stdin")
    p.add_argument("--summary-file", default=None, metavar="PATH",
                   help="also write the summary at the end to PATH as JSON (dem-ros launch reads it there)")
    return p


def main(argv: list[str] | None = None) -> int:
    return cmd_rig(build_parser().parse_args(argv))


def cmd_rig(args: argparse.Namespace) -> int:
    from ..board import SafetyError
    from ..core.params import ConfigError
    from .cboard import FirmwareError
    from .channel import ChannelError

    if args.help_faults:
        print(__doc__.split("Faults (")[1].split("\n", 1)[1])
        return 0
    try:
        faults = [parse_fault(t) for t in args.fault]
        cfg = rig_config(args.scenario, args.params, list(args.set) + ([f"rig.url={args.url}"] if args.url else []))
        cfg["plant_sim"]["measure_velocity"] = False  # a rig has no gap-rate sensors
        stop = [False]

        def on_signal(signum, frame):
            stop[0] = True

        for s in (signal.SIGINT, signal.SIGTERM):
            signal.signal(s, on_signal)
        try:
            shims = parse_shims(args.shims) if args.shims else None
        except ValueError as exc:
            raise RigError(str(exc)) from None
        summary = run_rig(cfg, faults, duration=args.duration, stop=stop, shims=shims, shims_stdin=args.shims_stdin,
                          summary_file=args.summary_file)
    except (RigError, ConfigError, ChannelError, FirmwareError, SafetyError) as exc:
        print(f"dem-ros rig: error: {exc}", file=sys.stderr)
        return 2
    return 1 if summary["failed"] else 0


if __name__ == "__main__":
    sys.exit(main())

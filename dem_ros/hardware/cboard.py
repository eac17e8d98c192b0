"""The board's firmware (``firmware/supervisor.c``, C99, float32) on the host, through ctypes.

:class:`CSupervisor` has the interface of :class:`dem_ros.board.Supervisor` (``step``, ``land``,
``estop``, ``clear``, ``mode``, ``reason``, ``fault``, ``counters``, ``estimate``, ``stop_gap``,
``implausible``, ``command_timeout``, ``snapshot``), so the rig emulator runs either board
(``rig.board``: ``python`` or ``c``) and the differential test (tests/firmware) holds one to the other.

The shared library is built with the host's C compiler at first use, into
``$XDG_CACHE_HOME/dem_ros/firmware-<hash of the sources>/`` (default ``~/.cache``): a rebuild only when the
firmware's sources change. No compiler: :class:`FirmwareError` says so.
"""

from __future__ import annotations

import ctypes
import hashlib
import math
import os
import shutil
import subprocess
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..board import PLANT_KEYS, SAFETY_KEYS, Mode, SafetyError
from ..board.config import hold_guard_text
from .boardcfg import RESULT_TEXT, BoardConfigError, config_frame
from .link import CONFIG_RESULTS, CONFIG_SUP_KEYS

__all__ = ["FIRMWARE_DIR", "SOURCES", "CSupervisor", "FirmwareError", "config_header", "library_path", "main",
           "sup_config_result"]

FIRMWARE_DIR = Path(__file__).resolve().parents[2] / "firmware"
SOURCES = ("supervisor.c", "supervisor.h")
CFLAGS = ("-std=c99", "-O2", "-fPIC", "-shared", "-Wall", "-Wextra", "-Werror", "-pedantic", "-Wconversion",
          "-Wdouble-promotion", "-Wshadow")


class FirmwareError(RuntimeError):
    """The firmware cannot be built or loaded on this host (no C compiler, no sources); the message says why."""


def _cache_dir() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "dem_ros"


def library_path() -> Path:
    """The shared library of the current firmware sources, built now if it is not in the cache."""
    missing = [s for s in SOURCES if not (FIRMWARE_DIR / s).is_file()]
    if missing:
        raise FirmwareError(f"the firmware's sources are not here: {FIRMWARE_DIR} lacks {', '.join(missing)}")
    h = hashlib.sha256(" ".join(CFLAGS).encode())
    for s in SOURCES:
        h.update((FIRMWARE_DIR / s).read_bytes())
    out = _cache_dir() / f"firmware-{h.hexdigest()[:16]}" / "libdemsup.so"
    if out.is_file():
        return out
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if cc is None:
        raise FirmwareError("no C compiler (cc, gcc or clang on PATH, or $CC): the C board (rig.board=c) is built on "
                            "the host at first use; install one (Debian: apt-get install gcc) or use rig.board=python")
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out.parent) as tmp:  # build aside, then rename: concurrent builders agree
        tmp_lib = Path(tmp) / out.name
        try:
            r = subprocess.run([cc, *CFLAGS, "-o", str(tmp_lib), "supervisor.c", "-lm"], cwd=FIRMWARE_DIR,
                               capture_output=True, text=True, timeout=120, check=False)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise FirmwareError(f"the C compiler {cc} does not run: {exc}") from None
        if r.returncode != 0:
            raise FirmwareError(f"the firmware does not build with {cc}: {r.stderr.strip()[:2000]}")
        os.replace(tmp_lib, out)
    return out


class _Why(ctypes.Structure):
    _fields_ = [("code", ctypes.c_uint8), ("ch", ctypes.c_uint8), ("sub", ctypes.c_uint8),
                ("a", ctypes.c_float * 4)]


_COUNTERS = ("holds", "hold_events", "longest_hold_us", "clipped", "rejected", "landings", "trips", "estops",
             "landed", "brakes", "brake_events", "sensor_gaps", "sensor_gap_events", "sensor_losses", "implausible")


class _Counters(ctypes.Structure):
    _fields_ = [(n, ctypes.c_uint32) for n in _COUNTERS]


class _View(ctypes.Structure):
    _fields_ = [("mode", ctypes.c_int32), ("command_timeout", ctypes.c_int32), ("implausible", ctypes.c_int32 * 2),
                ("reason", _Why), ("fault", _Why), ("counters", _Counters), ("est", (ctypes.c_float * 2) * 3),
                ("stop_gap", ctypes.c_float * 2), ("min_stop_gap", ctypes.c_float), ("u", ctypes.c_float * 2),
                ("ref", (ctypes.c_float * 2) * 3), ("ui", ctypes.c_float * 2), ("r_est", ctypes.c_float * 2)]


# sup_config_t: the schema's values in this order, then dt
_CONFIG_KEYS = SAFETY_KEYS + PLANT_KEYS


class _Config(ctypes.Structure):
    _fields_ = [(k if k != "I" else "I_", ctypes.c_float) for k in _CONFIG_KEYS] + [("dt", ctypes.c_float)]


_LIB: ctypes.CDLL | None = None
_F2 = ctypes.c_float * 2


def _lib() -> ctypes.CDLL:
    global _LIB
    if _LIB is None:
        lib = ctypes.CDLL(str(library_path()))
        vp, fp, i64, ci = ctypes.c_void_p, ctypes.POINTER(ctypes.c_float), ctypes.c_int64, ctypes.c_int
        lib.sup_init.argtypes = [vp, ctypes.POINTER(_Config), ci, fp]
        lib.sup_step.argtypes = [vp, i64, fp, fp, fp, ci, ctypes.c_float, fp, fp]
        lib.sup_step.restype = None
        lib.sup_view.argtypes = [vp, ctypes.POINTER(_View)]
        lib.sup_view.restype = None
        lib.sup_mode.argtypes = [vp]
        lib.sup_sizeof.restype = ctypes.c_uint32
        for f in (lib.sup_land, lib.sup_estop):
            f.argtypes = [vp, ci]
            f.restype = None
        lib.sup_clear.argtypes = [vp]
        lib.sup_clear.restype = None
        _LIB = lib
    return _LIB


_CFG_ERRORS = {code: RESULT_TEXT[CONFIG_RESULTS[code]] for code in range(1, 6)}  # sup_cfg_result's codes
_NAMES = ("gap sensor 1", "gap sensor 2", "current sensor 1", "current sensor 2")


def _why_text(w: _Why, external: str) -> str:
    """The firmware's reason (code, channel, numbers) as the Python board's text says it."""
    c, ch, sub, a = w.code, w.ch, w.sub, list(w.a)
    if c == 0:
        return ""
    if c == 1:
        return f"{Mode(ch).name} requested"
    if c == 2:
        return f"coil current {a[0]:.2f} A above i_max"
    if c == 3:
        return f"gap {a[0] * 1e3:.3f} mm above trip_gap_max"
    if c == 4:
        return (f"predicted stopping gap {a[0] * 1e3:.3f} mm below trip_gap_min at end {ch + 1} "
                f"(gap {a[1] * 1e3:.3f} mm, rate {a[2] * 1e3:+.1f} mm/s)")
    if c == 5 and sub == 1:
        return (f"no command for {a[0] * 1e3:.1f} ms and end {ch + 1} moves at {a[1] * 1e3:+.1f} mm/s "
                f"({hold_guard_text(a[2], a[3])})")
    if c == 5:
        return f"no command for {a[0] * 1e3:.1f} ms (hold_timeout)"
    if c == 6:
        return "command missing"
    if c == 7:
        return external
    if c == 8:
        return f"e-stop: {external}"
    if c == 9:
        why = "the plate is on its support" if sub == 0 else "no estimate possible"
        return f"non-finite sensor reading (gaps {a[0]!r}, {a[1]!r}; currents {a[2]!r}, {a[3]!r}): {why}"
    if c == 10:
        cause = (f"{_NAMES[2 + ch]} lost too (no finite sample for {a[1]:.0f} samples)",
                 f"{_NAMES[1 - ch]} without a finite sample for {a[1]:.0f} samples",
                 f"coil {ch + 1}'s current {a[1]:.2f} A at or under FLUX_GAP_MIN_CURRENT")[min(sub, 2)]
        return (f"{_NAMES[ch]} lost, gap {ch + 1} from coil {ch + 1}'s flux: none for {a[0]:.0f} samples: {cause}; "
                f"no landing without gap {ch + 1}: 0 V, the plate drops onto its support")
    if c == 11:
        k = 1 - ch
        why = (f"gap {k + 1} already from coil {k + 1}'s flux", f"{_NAMES[k]} lost too",
               f"{_NAMES[2 + ch]} lost too: no flux for gap {ch + 1}",
               f"coil {ch + 1}'s current {a[1]:.2f} A at or under FLUX_GAP_MIN_CURRENT: its flux tells too little "
               f"of gap {ch + 1}",
               f"no sample of {_NAMES[k]} and {_NAMES[2 + ch]} together within {a[0]:.0f} samples to start the flux "
               f"landing from")[min(sub, 4)]
        return (f"{_NAMES[ch]} lost: no finite sample for {a[0]:.0f} samples; {why}; no landing without it: 0 V, "
                f"the plate drops onto its support")
    if c == 12:
        return (f"{_NAMES[ch]} lost: no finite sample for {a[0]:.0f} samples: landing on gap {ch + 1} from coil "
                f"{ch + 1}'s flux")
    if c == 13:
        return f"{_NAMES[2 + ch]} lost: no finite sample for {a[0]:.0f} samples: landing on the board's coil model"
    if c == 14:
        return (f"{_NAMES[ch]} implausible: reads {a[0] * 1e3:.3f} mm, the coil fluxes say {a[1] * 1e3:.3f} mm (off "
                f"by more than {a[2] * 1e3:.3f} mm): landing on gap {ch + 1} from coil {ch + 1}'s flux")
    if c == 15:
        what = "at once" if sub == 2 else f"after gap sensor {sub + 1}"
        return (f"gap sensors 1 and 2 implausible ({what}): read {a[0] * 1e3:.3f}, {a[1] * 1e3:.3f} mm, the coil "
                f"fluxes say {a[2] * 1e3:.3f}, {a[3] * 1e3:.3f} mm; no landing without a gap: 0 V, the plate drops "
                f"onto its support")
    return f"firmware reason code {c}"


def sup_config_result(sup: Sequence[float]) -> int:
    """The firmware's own ``sup_init()`` verdict on the 17 supervisor values (``CONFIG_SUP_KEYS``: the safety specs,
    the nominal plant, dt): 0, or its ``sup_cfg_result`` code (the CONFIG result codes 1-5)."""
    if len(sup) != len(CONFIG_SUP_KEYS):
        raise ValueError(f"{len(sup)} supervisor values, expected {len(CONFIG_SUP_KEYS)}")
    lib = _lib()
    buf = ctypes.create_string_buffer(int(lib.sup_sizeof()))
    c = _Config(*(float(x) for x in sup))
    return int(lib.sup_init(ctypes.cast(buf, ctypes.c_void_p), ctypes.byref(c), int(Mode.OFF), None))


def _f2(v: Any) -> Any:
    return _F2(float(v[0]), float(v[1]))


class CSupervisor:
    """The C board's supervisor behind :class:`dem_ros.board.Supervisor`'s interface (module docstring).

    Args: as Supervisor: cfg (the safety specs and nominal plant, SI), dt [s], mode, u0 (2,) [V].
    Raises SafetyError for a configuration the firmware refuses, FirmwareError without a compiler.
    """

    name = "c"

    def __init__(self, cfg: Mapping[str, Any], dt: float, mode: Mode = Mode.OFF, u0: np.ndarray | None = None):
        missing = [k for k in _CONFIG_KEYS if k not in cfg]
        if missing:
            raise SafetyError(f"supervisor configuration lacks {missing}")
        try:
            vals = [float(cfg[k]) for k in _CONFIG_KEYS] + [float(dt)]
        except (TypeError, ValueError):
            raise SafetyError("supervisor configuration: not numbers") from None
        self.cfg = dict(zip(_CONFIG_KEYS, vals, strict=False))
        self.dt = float(dt)
        self._lib = _lib()
        self._buf = ctypes.create_string_buffer(int(self._lib.sup_sizeof()))
        self._s = ctypes.cast(self._buf, ctypes.c_void_p)
        c = _Config(*vals)
        r = self._lib.sup_init(self._s, ctypes.byref(c), int(mode), None if u0 is None else _f2(u0))
        if r != 0:
            raise SafetyError(f"the firmware refuses the configuration: {_CFG_ERRORS.get(r, r)}")
        self._y, self._i, self._u, self._cmd, self._applied = _F2(), _F2(), _F2(), _F2(), _F2()
        self._view = _View()
        self._external = ""  # the text of the last land()/estop() from outside (the firmware keeps a code)
        self._fault_external = ""

    # -- commands from outside -----------------------------------------------------------------
    def land(self, reason: str) -> None:
        if self.mode not in (Mode.LAND, Mode.LANDED, Mode.FAULT):
            self._external = reason
        self._lib.sup_land(self._s, 0)

    def estop(self, reason: str) -> None:
        if not self.fault:
            self._fault_external = reason
        if self.mode not in (Mode.LAND, Mode.LANDED, Mode.FAULT):
            self._external = reason
        self._lib.sup_estop(self._s, 0)

    def clear(self) -> None:
        self._lib.sup_clear(self._s)

    # -- the sample ------------------------------------------------------------------------------
    def step(self, t_ns: int, y: Sequence[float] | np.ndarray | None, i: Sequence[float] | np.ndarray | None,
             u_cmd: Sequence[float] | np.ndarray | None, requested: Mode = Mode.RUN, bus: float | None = None,
             applied: Sequence[float] | np.ndarray | None = None) -> np.ndarray:
        """As Supervisor.step; the firmware's clock is in microseconds (t_ns // 1000)."""
        yb, ib = self._y, self._i
        if y is None:
            yb[0] = yb[1] = math.nan
        else:
            yb[0], yb[1] = float(y[0]), float(y[1])
        if i is None:
            ib[0] = ib[1] = math.nan
        else:
            ib[0], ib[1] = float(i[0]), float(i[1])
        cmd = None
        if u_cmd is not None:
            cmd = self._cmd
            cmd[0], cmd[1] = float(u_cmd[0]), float(u_cmd[1])
        app = None
        if applied is not None:
            app = self._applied
            app[0], app[1] = float(applied[0]), float(applied[1])
        self._lib.sup_step(self._s, int(t_ns) // 1000, yb, ib, cmd, int(requested),
                           math.nan if bus is None else float(bus), app, self._u)
        return np.array((self._u[0], self._u[1]))

    # -- state -------------------------------------------------------------------------------------
    def _v(self) -> _View:
        self._lib.sup_view(self._s, ctypes.byref(self._view))
        return self._view

    @property
    def mode(self) -> Mode:
        return Mode(self._lib.sup_mode(self._s))

    @property
    def reason(self) -> str:
        return _why_text(self._v().reason, self._external)

    @property
    def fault(self) -> str:
        return _why_text(self._v().fault, self._fault_external or self._external)

    @property
    def counters(self) -> dict[str, int]:
        c = self._v().counters
        return {n: int(getattr(c, n)) for n in _COUNTERS}

    @property
    def estimate(self) -> np.ndarray:
        return np.array([[float(x) for x in row] for row in self._v().est])

    def internals(self) -> dict[str, np.ndarray]:
        """The landing reference (3, 2), the current loop's integral (2,) [V] and the coil model's R (2,) [ohm]."""
        v = self._v()
        return {"ref": np.array([[float(x) for x in row] for row in v.ref]), "ui": np.array(list(v.ui), float),
                "r_est": np.array(list(v.r_est), float)}

    @property
    def stop_gap(self) -> np.ndarray:
        v = self._v()
        return np.array((v.stop_gap[0], v.stop_gap[1]), dtype=float)

    @property
    def min_stop_gap(self) -> float:
        return float(self._v().min_stop_gap)

    @property
    def implausible(self) -> list[bool]:
        v = self._v()
        return [bool(v.implausible[0]), bool(v.implausible[1])]

    @property
    def command_timeout(self) -> bool:
        return bool(self._v().command_timeout)

    @property
    def u(self) -> np.ndarray:
        v = self._v()
        return np.array((v.u[0], v.u[1]), dtype=float)

    def snapshot(self) -> dict[str, Any]:
        """As Supervisor.snapshot, plus ``board``: "c"."""
        sg, low = self.stop_gap, self.min_stop_gap
        return {"board": "c", "mode": self.mode.name, "reason": self.reason, "fault": self.fault, **self.counters,
                "stop_gap_mm": [round(float(g) * 1e3, 4) if math.isfinite(g) else None for g in sg],
                "min_stop_gap_mm": round(low * 1e3, 4) if math.isfinite(low) else None}


def config_header(cfg: Mapping[str, Mapping[str, Any]]) -> str:
    """C99 source of ``static const board_config_t BOARD_CONFIG`` (firmware/board.h) with a launch's values: the
    configuration the driver sends over the link (:func:`dem_ros.hardware.boardcfg.config_frame` of the
    ``hw_driver`` group: the board's safety specs, nominal plant and dt, the sensors' calibration, the command
    delay) and the ``rig`` group's board id and ADC. The board's defaults until a PC configures it (firmware/README.md,
    "Configuration"); built from the same parameters as a launch, it reports the CRC that launch's driver expects.
    Every float is written as the float32 the link carries, so the compiled values are the same bits."""
    rig = cfg["rig"]
    try:
        frame = config_frame(cfg["hw_driver"])
    except BoardConfigError as exc:
        raise FirmwareError(str(exc)) from None
    v = frame.as_dict()

    def f(x: Any) -> str:
        return f"{float(x)!r}f"

    sup = ", ".join(f".{k} = {f(v[k])}" for k in CONFIG_SUP_KEYS)
    gaps = ", ".join("{" + ", ".join(f(v[f"gap{j}_c{p}"]) for p in range(4)) + "}" for j in (1, 2))
    return "\n".join([
        "/* Generated by python -m dem_ros.hardware.cboard from the launch's parameters: do not edit. */",
        "#include \"board.h\"",
        "",
        "static const board_config_t BOARD_CONFIG = {",
        f"    .sup = {{{sup}}},",
        f"    .gap_c = {{{gaps}}},",
        f"    .i_gain = {{{f(v['current1_gain'])}, {f(v['current2_gain'])}}},",
        f"    .i_offset = {{{f(v['current1_offset'])}, {f(v['current2_offset'])}}},",
        f"    .board_id = {int(rig['board_id'])}u,",
        f"    .adc_bits = {int(rig['adc_bits'])}u,",
        f"    .command_delay = {frame.command_delay}u,",
        f"    .adc_vref = {f(rig['adc_vref'])},",
        "};",
        ""])


def main(argv: list[str] | None = None) -> int:
    """``python -m dem_ros.hardware.cboard [--scenario S] [--params FILE] [--set G.N=V ...]``: the board's
    configuration header (config_header) on stdout."""
    import argparse
    import sys

    from ..core.params import ConfigError
    from ..core.scenarios import scenario_config

    p = argparse.ArgumentParser(prog="python -m dem_ros.hardware.cboard",
                                description="the C board's configuration header from a launch's parameters")
    p.add_argument("--scenario", default="S1")
    p.add_argument("--params", default=None, help="ROS 2 params file (the launch's rig_params.yaml)")
    p.add_argument("--set", action="append", default=[], metavar="GROUP.NAME=VALUE")
    args = p.parse_args(argv)
    try:
        sys.stdout.write(config_header(scenario_config(args.scenario, args.params, args.set, default_group="rig")))
    except (ConfigError, FirmwareError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

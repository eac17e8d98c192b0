"""The board firmware's own tests (firmware/test_board.c) on the host and on an emulated Cortex-M4F, its
portability rules, and the rig emulator running the C board (rig.board=c).

- host: ``make -C firmware test-host`` (sanitizers where the compiler has them): configuration checks,
  landings on a float32 nominal plant (lost commands, a lost current or gap sensor, a requested landing, a held
  plate falling back toward its support: the hold's speed guard),
  limits, the board's tick on a fake HAL (hello, streaming, command ring, link watchdog);
- target: ``make -C firmware test-arm``: the same tests built with arm-none-eabi-gcc (Cortex-M4F, hard float)
  and run on qemu-system-arm (mps2-an386, semihosting exit code), where the toolchain is installed;
- the sources use no libc beyond <string.h> and <math.h> (+ <stdint.h>, <stddef.h>), no malloc, and only
  float32 arithmetic (they build with -Wdouble-promotion -Werror);
- ``dem-ros rig`` with ``rig.board=c``: the emulated board answers, streams, and its summary names the C board;
- the board's configuration over the link: the firmware's board (board.c on a fake HAL, ``firmware/host_board.c``),
  the emulator's Python board and its C board (rig.board=c) give the same answer (result, configured flag, the CRC
  each runs) to the same CONFIG frames: accepted, refused for each rule, refused in flight.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from dem_ros.core.params import default_config
from dem_ros.hardware.boardcfg import config_crc, config_frame
from dem_ros.hardware.cboard import FIRMWARE_DIR, CSupervisor, FirmwareError, library_path
from dem_ros.hardware.link import CONFIG_RESULTS, CommandFrame, ConfigAck, ConfigFrame, Hello, Mode, decode, encode
from dem_ros.hardware.rig import Board, rig_config

FIRMWARE_SOURCES = ("supervisor.c", "supervisor.h", "board.c", "board.h", "hal.h")


def _make(target: str, tmp: Path, timeout: float) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["make", "-C", str(FIRMWARE_DIR), f"BUILD={tmp}", target], capture_output=True, text=True,
                          timeout=timeout, check=False)


def test_sources_use_only_string_and_math() -> None:
    """No libc beyond <string.h>/<math.h>, no dynamic memory, no double literals in the firmware."""
    for name in FIRMWARE_SOURCES:
        src = (FIRMWARE_DIR / name).read_text()
        includes = {line.split()[1] for line in src.splitlines() if line.startswith("#include")}
        assert includes <= {"<string.h>", "<math.h>", "<stdint.h>", "<stddef.h>", '"supervisor.h"', '"board.h"',
                             '"hal.h"', '"dem_link.h"'}, (name, includes)
        code = re.sub(r"/\*.*?\*/", "", src, flags=re.S)
        for banned in ("malloc(", "free(", "printf", "double", "stdlib"):
            assert banned not in code, (name, banned)


def test_host_unit_tests_pass(tmp_path: Path) -> None:
    if shutil.which("make") is None or (shutil.which("cc") is None and shutil.which("gcc") is None):
        pytest.skip("no make or C compiler on PATH: the firmware's host tests cannot be built here")
    r = _make("test-host", tmp_path, 300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "OK: 0 failed" in r.stdout and "FAIL" not in r.stdout


def test_unit_tests_pass_on_an_emulated_cortex_m4f(tmp_path: Path) -> None:
    missing = [t for t in ("make", "arm-none-eabi-gcc", "qemu-system-arm") if shutil.which(t) is None]
    if missing:
        pytest.skip(f"{', '.join(missing)} not installed (Debian: apt-get install gcc-arm-none-eabi "
                    "libnewlib-arm-none-eabi qemu-system-arm): the Cortex-M build is not run")
    r = _make("test-arm", tmp_path, 600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "OK: 0 failed" in r.stdout and "FAIL" not in r.stdout
    cost = re.search(r"worst sup_step (\d+) instructions, board_step (\d+) instructions", r.stdout)
    assert cost is not None, r.stdout[-2000:]
    # a step is a few thousand instructions: far inside a 1 ms period at any Cortex-M4F clock (>= 48 MHz)
    assert 100 < int(cost.group(1)) <= int(cost.group(2)) < 20_000, cost.group(0)


def test_the_rig_runs_the_c_board_and_names_it() -> None:
    """rig.board=c: the emulator's board is the firmware's supervisor; hello, stream, RUN on the first command,
    and (commands at the open-loop hover voltage, the unstable plate runs off) the same trip as the Python board."""
    try:
        library_path()
    except FirmwareError as exc:
        pytest.skip(f"the firmware cannot be built here: {exc}")
    seen = {}
    for name in ("python", "c"):
        cfg = rig_config("S1", None, [f"rig.board={name}"])
        cfg["plant_sim"]["measure_velocity"] = False
        b = Board(cfg["plant_sim"], cfg["rig"], cfg["hw_driver"], [])
        assert isinstance(b.sup, CSupervisor) == (name == "c")
        assert isinstance(decode(b.receive(encode(Hello(1, 0, 0, 0, 0.0))) or b""), Hello)
        u0 = b.plant.u0
        modes = []
        for _ in range(300):
            f = decode(b.tick() or b"")
            modes.append(int(f.mode))
            b.receive(encode(CommandFrame(f.seq, (float(u0[0]), float(u0[1])), Mode.RUN)))
        s = b.summary()
        assert s["board"].startswith(name) and s["supervisor"]["trips"] == 1, s
        seen[name] = (modes, s["commands_fresh"], s["landings"])
    assert seen["c"] == seen["python"]
    assert np.all(np.diff(seen["c"][0]) >= 0) and seen["c"][0][1] == Mode.RUN and seen["c"][0][-1] == Mode.LAND


def _rig_tests():
    """tests/hardware/test_rig.py's lockstep helpers (the board, the link codec, the driver and the graph's
    estimator and controller, one tick at a time)."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "hardware" / "test_rig.py"
    spec = importlib.util.spec_from_file_location("_rig_lockstep", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_s1_through_the_c_board_in_lockstep_tracks_as_offline() -> None:
    """tests/hardware/test_rig.py's lockstep S1 (rig sensors and actuators, the link codec, the driver, the graph's
    estimator and controller at command_delay 2) with the firmware's supervisor as the board: tracks within
    max(2x offline, offline + 10 um) RMS, never leaves RUN."""
    from dem_ros.core.simulate import simulate

    try:
        library_path()
    except FirmwareError as exc:
        pytest.skip(f"the firmware cannot be built here: {exc}")
    rt = _rig_tests()
    duration = 12.0
    b, cfg, _ = rt.make(board="c")
    assert isinstance(b.sup, CSupervisor)
    e, drv = rt.s1_lockstep(b, cfg, duration)
    assert b.failed is None and Mode(b.sup.mode) == Mode.RUN and drv.state.name == "ACTIVE"
    rms = np.sqrt(np.mean(np.square(e), axis=0)) * 1e6
    off = np.array(simulate(cfg, controller="adaptive", estimator="kf", duration=duration,
                            scenario="S1").metrics()["rms_error_um"])
    print(f"\nlockstep rig, C board: RMS {rms} um, offline {off} um")
    assert np.all(rms <= np.maximum(2 * off, off + 10.0)), (rms, off)


def test_a_stuck_gap_sensor_is_found_by_the_c_board_and_the_plate_landed() -> None:
    """The rig's stuck-sensor fault (gap 1 frozen 1.5 s after its step in S1) through the C board in lockstep: found
    implausible by the flux check, landed on coil 1's flux, never near the rail, descent within landing_speed."""
    try:
        library_path()
    except FirmwareError as exc:
        pytest.skip(f"the firmware cannot be built here: {exc}")
    rt = _rig_tests()
    b, cfg, _ = rt.make(["stuck:1@2.5+1"], board="c")
    rt.s1_lockstep(b, cfg, 5.0)
    s = b.summary()
    assert s["failed"] == "" and s["mode"] == "LANDED" and s["board"].startswith("c"), s
    assert s["supervisor"]["implausible"] == 1 and b.sup.implausible == [True, False]
    assert "gap sensor 1 implausible" in s["supervisor"]["fault"]
    assert s["min_gap_mm"] > 3.0 and s["land_speed_max_mm_s"] <= cfg["plant_sim"]["landing_speed"] * 1e3, s


def test_the_configuration_header_carries_the_launch_values_and_the_firmware_accepts_it(tmp_path: Path) -> None:
    """python -m dem_ros.hardware.cboard writes the board's configuration from the schema's values (a --set reaches
    it); it compiles against board.h and sup_init() accepts it, and refuses it when the values are inconsistent."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler on PATH: the header cannot be compiled here")
    from dem_ros.hardware.cboard import config_header
    from dem_ros.hardware.rig import rig_config

    prog = tmp_path / "cfg.c"
    prog.write_text('#include "board_config.h"\nint main(void) { static sup_t s; '
                    "return sup_init(&s, &BOARD_CONFIG.sup, SUP_OFF, 0); }\n")
    codes = []
    for sets in (["hw_driver.u_max=150"], ["hw_driver.trip_gap_min=0.0105", "hw_driver.landing_gap=0.0104"]):
        try:
            text = config_header(rig_config("S1", None, sets))
        except Exception as exc:  # the schema itself refuses inconsistent specs first: also a refusal
            codes.append(("schema", type(exc).__name__))
            continue
        (tmp_path / "board_config.h").write_text(text)
        if sets == ["hw_driver.u_max=150"]:
            assert ".u_max = 150.0f" in text and ".command_delay = 1u" in text
        r = subprocess.run([cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-Wdouble-promotion",
                            f"-I{FIRMWARE_DIR}", f"-I{tmp_path}", "-o", str(tmp_path / "cfg"), str(prog),
                            str(FIRMWARE_DIR / "supervisor.c"), "-lm"], capture_output=True, text=True, timeout=120,
                           check=False)
        assert r.returncode == 0, r.stderr
        codes.append(subprocess.run([str(tmp_path / "cfg")], timeout=30, check=False).returncode)
    assert codes[0] == 0 and codes[1] != 0, codes


# -- the board's configuration over the link: the C board and the Python board agree ------------------------------
#: CONFIG frames as changes of the defaults (the hw_driver group's), and the answer every board must give
CONFIG_CASES = [
    ("the_same_again", {}, "ok"),
    ("another_u_max", {"u_max": 150.0}, "ok"),
    ("another_calibration", {"gap1_c1": 2.6e-7, "current2_offset": 32700.0}, "ok"),
    ("the_longest_delay", {"command_delay": 15}, "ok"),
    ("a_lighter_plate", {"m": 10.0, "K": 3.5e-4}, "ok"),
    ("negative_resistance", {"R": -1.0}, "not_positive"),
    ("zero_force_coefficient", {"K": 0.0}, "not_positive"),
    ("zero_hold_timeout", {"hold_timeout": 0.0}, "not_positive"),
    ("trip_gap_min_above_landing", {"trip_gap_min": 0.012}, "gap_order"),
    ("landing_beyond_trip_gap_max", {"landing_gap": 0.014}, "gap_order"),
    ("negative_trip_gap_min", {"trip_gap_min": -1e-4}, "gap_order"),
    ("magnets_outside_the_load_points", {"l": 0.4}, "arms"),
    ("no_braking_at_end_2", {"N1": 500.0}, "no_braking"),
    ("no_braking_at_end_1", {"N2": 500.0}, "no_braking"),
    ("another_sample_period", {"dt": 2e-3}, "rate"),
    ("no_command_delay", {"command_delay": 0}, "delay"),
    ("a_delay_the_ring_cannot_hold", {"command_delay": 16}, "delay"),
]


@pytest.fixture(scope="module")
def host_board(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """firmware/host_board (board.c, supervisor.c, dem_link.c on a fake HAL), with sanitizers where available."""
    cc = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if cc is None:
        pytest.skip("no C compiler on PATH: the firmware's board cannot be built here")
    try:
        library_path()  # the emulator's C board (rig.board=c) too
    except FirmwareError as exc:
        pytest.skip(f"the firmware cannot be built here: {exc}")
    out = tmp_path_factory.mktemp("host_board") / "host_board"
    flags = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-Wno-conversion", "-Wdouble-promotion",
             "-Wshadow", "-O2"]
    sources = ["host_board.c", "board.c", "supervisor.c", "dem_link.c", "-lm"]
    for extra in (["-fsanitize=address,undefined", "-fno-sanitize-recover=all"], []):
        r = subprocess.run([cc, *flags, *extra, "-o", str(out), *sources], cwd=FIRMWARE_DIR, capture_output=True,
                           text=True, timeout=180, check=False)
        if r.returncode == 0:
            return out
    pytest.fail(f"firmware/host_board.c does not build with {cc}:\n{r.stderr}")


def _c_board(exe: Path, script: list[str]) -> list[str]:
    r = subprocess.run([str(exe)], input="\n".join(script) + "\n", capture_output=True, text=True, timeout=120,
                       check=False)
    assert r.returncode == 0, r.stdout + r.stderr
    return r.stdout.splitlines()


def _c_ack(line: str) -> tuple[str, bool, int, int]:
    word, result, configured, active, request, _mode = line.split()
    assert word == "ack", line
    return result, configured == "1", int(active, 16), int(request, 16)


def _py_ack(a: ConfigAck) -> tuple[str, bool, int, int]:
    return CONFIG_RESULTS[a.result], a.configured, a.active_crc, a.request_crc


def _frame(changes: dict) -> ConfigFrame:
    return config_frame(default_config()["hw_driver"] | changes)


def _emulated(board: str) -> Board:
    cfg = default_config()
    cfg["plant_sim"]["measure_velocity"] = False
    cfg["rig"]["board"] = board
    b = Board(cfg["plant_sim"], cfg["rig"], cfg["hw_driver"], [])
    assert b.config_crc == config_crc(_frame({})) and not b.configured  # built with the same defaults
    return b


def _configure(b: Board, f: ConfigFrame) -> ConfigAck:
    a = decode(b.receive(encode(f)) or b"")
    assert isinstance(a, ConfigAck)
    return a


def test_the_c_and_the_python_boards_answer_every_configuration_alike(host_board: Path) -> None:
    """Each case on a fresh board of each kind (at rest, OFF): the same result, configured flag and CRCs; the
    expected result; a refused configuration leaves the defaults' CRC active, an accepted one is the request's."""
    defaults = encode(_frame({})).hex()
    script = []
    for _, changes, _ in CONFIG_CASES:
        script += [f"init {defaults}", f"config {encode(_frame(changes)).hex()}"]
    lines = [line for line in _c_board(host_board, script) if not line.startswith("init")]
    crc0 = config_crc(_frame({}))
    for (name, changes, want), line in zip(CONFIG_CASES, lines, strict=True):
        f = _frame(changes)
        c = _c_ack(line)
        py, cb = _py_ack(_configure(_emulated("python"), f)), _py_ack(_configure(_emulated("c"), f))
        assert c == py == cb, (name, c, py, cb)
        assert c[0] == want and c[3] == config_crc(f), (name, c)
        assert c[2] == (config_crc(f) if want == "ok" else crc0) and c[1] == (want == "ok"), (name, c)


def test_a_refused_configuration_keeps_the_one_set_before_and_a_flying_board_takes_none(host_board: Path) -> None:
    """A sequence on one board of each kind: another u_max (taken), an invalid one (refused: the u_max one stays,
    the configured flag too), the first again (nothing changes); then levitating (RUN): any configuration is refused
    as busy, the active one stays."""
    seq = [_frame({"u_max": 150.0}), _frame({"u_max": 150.0, "R": -1.0}), _frame({"u_max": 150.0})]
    busy = _frame({"u_max": 120.0})
    lines = _c_board(host_board, [f"init {encode(_frame({})).hex()}", *(f"config {encode(f).hex()}" for f in seq),
                                  "hello", "run 20 80 80", f"config {encode(busy).hex()}"])
    c_acks = [_c_ack(x) for x in lines if x.startswith("ack")]
    assert lines[-2] == "mode RUN"
    crc150 = config_crc(seq[0])
    for kind in ("python", "c"):
        b = _emulated(kind)
        py = [_py_ack(_configure(b, f)) for f in seq]
        assert isinstance(decode(b.receive(encode(Hello(1, 0, 0, 0, 0.0))) or b""), Hello)
        u0 = b.plant.u0
        for _ in range(20):  # the PC's commands at the hover voltage: the board takes them (RUN)
            f = decode(b.tick() or b"")
            b.receive(encode(CommandFrame(f.seq, (float(u0[0]), float(u0[1])), Mode.RUN)))
        assert Mode(b.sup.mode) == Mode.RUN
        a = _configure(b, busy)
        py.append(_py_ack(a))
        assert a.mode == Mode.RUN and b.bcfg["u_max"] == 150.0, (kind, a)
        assert py == c_acks, (kind, py, c_acks)
    assert [a[0] for a in c_acks] == ["ok", "not_positive", "ok", "busy"]
    assert [a[2] for a in c_acks] == [crc150] * 4 and all(a[1] for a in c_acks)

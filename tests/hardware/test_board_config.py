"""The board's configuration over the device link (docs/hardware-link.md, "Config"), without a process:

- the one packing (``boardcfg.config_frame``, what the driver sends and the header generator compiles in), its CRC;
- the board's rules (``check_config``, ``sup_config_result``): refused with a reason code, in the firmware's order,
  and the Python board's own validation refusing the same configurations;
- the emulated board (``rig.Board``) answering CONFIG frames: taken at rest, refused in flight, refused when invalid
  (the active one stays), the same one again changes nothing, a new one reaches the hello, the limits and the
  board's conversion of its counts;
- the driver's handshake: the configuration after the hello, armed -> active only once the board confirms it, one
  clear reason otherwise; and the whole loop (board, codec, driver) in lockstep.

The C board gives the same answers to the same frames: tests/firmware/test_firmware_c.py.
"""

from __future__ import annotations

import math
import random
import struct

import numpy as np
import pytest

from dem_ros.board import SafetyError
from dem_ros.board.config import kernel_vector
from dem_ros.core.params import SCHEMA, default_config
from dem_ros.hardware import boardcfg
from dem_ros.hardware.boardcfg import (
    MAX_COMMAND_DELAY,
    BoardConfigError,
    check_config,
    config_crc,
    config_frame,
    python_sup_result,
    sup_config_result,
)
from dem_ros.hardware.cboard import config_header
from dem_ros.hardware.driver import CONFIG_RETRY_NS, CONFIG_TRIES, DriverState, HwDriver
from dem_ros.hardware.link import (
    CONFIG_KEYS,
    CONFIG_RESULTS,
    CONFIG_SUP_KEYS,
    HELLO_REQUEST,
    CommandFrame,
    ConfigAck,
    ConfigFrame,
    Hello,
    Mode,
    SensorFrame,
    decode,
    encode,
)
from dem_ros.hardware.rig import Board

MS = 1_000_000
HW = SCHEMA.defaults("hw_driver")
CODE = {name: k for k, name in enumerate(CONFIG_RESULTS)}


def frame(**changes) -> ConfigFrame:
    return config_frame(HW | changes)


# -- the packing and the CRC ------------------------------------------------------------------------------------
def test_the_configuration_is_the_hw_driver_groups_values_as_float32():
    f = frame()
    assert f.command_delay == HW["command_delay"] == 1
    for k, v in f.as_dict().items():
        want = HW[k]
        assert v == struct.unpack("<f", struct.pack("<f", want))[0], k  # what the board stores
    assert decode(encode(f)) == f  # float32 values survive the link exactly
    assert config_crc(f) == struct.unpack("<I", encode(f)[-4:])[0]  # the CRC is the frame's CRC field
    assert config_crc(frame(u_max=150.0)) != config_crc(f) and config_crc(frame()) == config_crc(f)


@pytest.mark.parametrize(("values", "words"), [
    (HW | {"gap_table": "cal.csv"}, "polynomials gapJ_c0..c3 only"),
    ({k: v for k, v in HW.items() if k != "N2"}, "lacks N2"),
    (HW | {"m": "heavy"}, "m = 'heavy' is not a number"),
    (HW | {"K": 1e39}, "does not fit a float32"),
    (HW | {"command_delay": 1.5}, "command_delay = 1.5"),
])
def test_what_cannot_be_packed_is_a_clear_error(values, words):
    with pytest.raises(BoardConfigError, match=words.replace(".", r"\.").replace("(", r"\(")):
        config_frame(values)


def test_the_firmware_header_compiles_in_exactly_the_frames_values():
    """python -m dem_ros.hardware.cboard and the driver pack one configuration: the header's literals are the
    frame's float32 values (so a board built from a launch's parameters reports the CRC its driver expects)."""
    cfg = default_config()
    cfg["hw_driver"]["u_max"] = 150.0
    text = config_header(cfg)
    f = config_frame(cfg["hw_driver"]).as_dict()
    for k in CONFIG_SUP_KEYS:
        assert f".{k} = {f[k]!r}f" in text, k
    gaps = ", ".join("{" + ", ".join(f"{f[f'gap{j}_c{p}']!r}f" for p in range(4)) + "}" for j in (1, 2))
    assert f".gap_c = {{{gaps}}}" in text and ".u_max = 150.0f" in text and ".command_delay = 1u" in text
    assert f".i_offset = {{{f['current1_offset']!r}f, {f['current2_offset']!r}f}}" in text


# -- the board's rules ------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("changes", "want"), [
    ({}, "ok"),
    ({"u_max": 0.0}, "not_positive"),
    ({"dt": 0.0}, "rate"),  # dt is checked against the board's period first
    ({"R": -20.0, "trip_gap_min": 0.02}, "not_positive"),  # the firmware's order: positivity before the gap order
    ({"trip_gap_min": 0.011}, "gap_order"),  # == landing_gap
    ({"landing_gap": 0.0131}, "gap_order"),
    ({"l": 0.3}, "arms"),  # == L
    ({"N1": 0.0, "N2": 400.0}, "no_braking"),
    ({"gap2_c3": math.inf}, "nonfinite"),
    ({"g": math.nan}, "nonfinite"),
    ({"command_delay": 0}, "delay"),
    ({"command_delay": MAX_COMMAND_DELAY + 1}, "delay"),
    ({"command_delay": MAX_COMMAND_DELAY}, "ok"),
    ({"dt": 1e-3 * (1 + 1e-6)}, "rate"),  # another float32: another clock
])
def test_the_board_checks_a_configuration_in_the_firmwares_order(changes, want):
    f = ConfigFrame(tuple(float(np.float32((HW | changes)[k])) for k in CONFIG_KEYS),
                    (HW | changes)["command_delay"])
    assert CONFIG_RESULTS[check_config(f, HW["dt"])] == want
    assert CONFIG_RESULTS[check_config(f, HW["dt"], python_sup_result)] == want


def test_the_firmwares_rules_and_the_python_boards_refuse_the_same_configurations():
    """2000 seeded random supervisor configurations around the defaults (each value scaled by 0.2..2.5, a quarter
    with one value negated or the loads unbalanced): sup_config_result (the firmware's checks in float32) refuses
    exactly those the Python board's kernel_vector refuses."""
    rng = random.Random(23)
    base = {k: HW[k] for k in CONFIG_SUP_KEYS}
    refused = 0
    for _ in range(2000):
        c = {k: v * rng.uniform(0.2, 2.5) for k, v in base.items()}
        c["dt"] = HW["dt"]
        if rng.random() < 0.25:
            c[rng.choice(CONFIG_SUP_KEYS[:-1])] *= -1
        if rng.random() < 0.25:
            c["N1"], c["N2"] = rng.uniform(0, 400), rng.uniform(0, 400)
        v = [float(np.float32(c[k])) for k in CONFIG_SUP_KEYS]
        code = sup_config_result(v)
        try:
            kernel_vector(dict(zip(CONFIG_SUP_KEYS, v, strict=True)), v[-1])
            python_ok = True
        except SafetyError:
            python_ok = False
        assert (code == 0) == python_ok, (c, CONFIG_RESULTS[code])
        refused += code != 0
    assert 300 < refused < 1900  # both kinds well represented
    for k in ("no_braking", "gap_order", "arms", "not_positive"):
        assert k in boardcfg.RESULT_TEXT


# -- the emulated board -----------------------------------------------------------------------------------------
def board(**plant) -> Board:
    cfg = default_config()
    cfg["plant_sim"]["measure_velocity"] = False
    cfg["plant_sim"].update(plant)
    b = Board(cfg["plant_sim"], cfg["rig"], cfg["hw_driver"])
    decode(b.receive(encode(HELLO_REQUEST)))
    return b


def answer(b: Board, f: ConfigFrame) -> ConfigAck:
    a = decode(b.receive(encode(f)) or b"")
    assert isinstance(a, ConfigAck)
    return a


def test_the_board_runs_its_defaults_until_configured_then_the_new_values():
    b = board(u_max=150.0)  # built with another u_max than the PC's
    crc0 = b.config_crc
    assert not b.configured and b.bcfg["u_max"] == 150.0
    sup0 = b.sup
    a = answer(b, frame())
    assert (a.result, a.configured, a.active_crc, a.request_crc, a.mode) == (0, True, config_crc(frame()),
                                                                            config_crc(frame()), Mode.OFF)
    assert a.active_crc != crc0 and b.bcfg["u_max"] == 200.0 and b.sup is not sup0  # a restarted supervisor
    sup1 = b.sup
    assert answer(b, frame()).result == 0 and b.sup is sup1  # the same again: nothing changes
    a = answer(b, frame(hold_timeout=0.02, command_delay=3))
    h = decode(b.receive(encode(HELLO_REQUEST)) or b"")
    assert a.result == 0 and isinstance(h, Hello) and (h.watchdog_ms, h.command_delay) == (20, 3) and b.delay == 3
    s = b.summary()
    assert s["config_crc"] == f"{a.active_crc:08x}" and s["configured"] and s["configs"] == 3
    assert s["configs_refused"] == 0


def test_an_invalid_configuration_is_refused_with_its_reason_and_the_active_one_stays():
    b = board()
    answer(b, frame(u_max=150.0))
    crc = b.config_crc
    for changes, want in (({"N1": 500.0}, "no_braking"), ({"dt": 5e-4}, "rate"), ({"command_delay": 0}, "delay"),
                          ({"l": 0.5}, "arms")):
        a = answer(b, frame(u_max=150.0, **changes))
        assert CONFIG_RESULTS[a.result] == want and a.active_crc == crc and a.configured, (changes, a)
        assert a.request_crc == config_crc(frame(u_max=150.0, **changes)) and b.bcfg["u_max"] == 150.0
    assert b.summary()["configs_refused"] == 4


def test_a_levitating_board_takes_no_configuration():
    b = board()
    u0 = b.plant.u0
    for _ in range(30):
        f = decode(b.tick() or b"")
        b.receive(encode(CommandFrame(f.seq, (float(u0[0]), float(u0[1])), Mode.RUN)))
    assert Mode(b.sup.mode) == Mode.RUN
    crc = b.config_crc
    a = answer(b, frame(u_max=150.0))
    assert CONFIG_RESULTS[a.result] == "busy" and a.mode == Mode.RUN and a.active_crc == crc
    assert b.bcfg["u_max"] == 200.0 and Mode(b.sup.mode) == Mode.RUN  # untouched, still flying
    assert answer(b, frame()).result == CODE["busy"]  # even the same one: never anything in flight


def test_a_calibration_set_over_the_link_converts_the_boards_counts():
    """The sensors' physics stay the rig's; the board reads its counts with the calibration it was sent: a gap
    polynomial 10 % steeper makes the board see gaps 10 % larger (its supervisor's input), the PC's view unchanged."""
    b = board()
    f0 = decode(b.tick() or b"")
    assert isinstance(f0, SensorFrame)
    g = {f"gap{j}_c{p}": HW[f"gap{j}_c{p}"] * 1.1 for j in (1, 2) for p in range(4)}
    assert answer(b, frame(**g)).result == 0
    seen = []
    step = b.sup.step

    def spy(t, y, i, *args, **kw):
        seen.append(np.array(y, float))
        return step(t, y, i, *args, **kw)

    b.sup.step = spy  # type: ignore[method-assign]
    f1 = decode(b.tick() or b"")
    assert isinstance(f1, SensorFrame) and f1.gap_counts == f0.gap_counts  # same plate, same counts
    n = np.array(f1.gap_counts, float)
    nominal = HW["gap1_c1"] * n + HW["gap1_c2"] * n * n
    assert seen[0] == pytest.approx(1.1 * nominal, rel=1e-6)


# -- the driver's handshake -------------------------------------------------------------------------------------
CFG = HW | {"arm_samples": 1, "clock_sync_frames": 1}


def sensor(seq: int, mode=Mode.OFF) -> bytes:
    return encode(SensorFrame(seq, seq * 1000, (19283, 19283), (40960, 40960), (0.0, 0.0), 200.0, 0, mode))


def ack(cfg, result="ok", active: int | None = None, request: int | None = None, configured=True) -> bytes:
    crc = config_crc(config_frame(cfg))
    return encode(ConfigAck(crc if active is None else active, crc if request is None else request, CODE[result],
                            configured, Mode.OFF))


def hello_then(d: HwDriver) -> ConfigFrame:
    _, reply = d.on_bytes(encode(Hello(1, 7, 1000, 16, 10.0, 50, 1)), 0, 0)
    f = decode(reply or b"")
    assert isinstance(f, ConfigFrame)
    return f


def test_the_driver_sends_the_runs_configuration_after_the_hello_and_arms_only_once_the_board_runs_it():
    d = HwDriver(CFG | {"u_max": 180.0})
    assert hello_then(d) == config_frame(CFG | {"u_max": 180.0})
    assert d.status()["board_config"] == "not answered" and not d.configured
    d.arm()
    s, _ = d.on_bytes(sensor(0), 10**18, 0)
    assert s is not None
    assert d.command(s.stamp_ns, [50.0, 50.0], 0) is None and d.state == DriverState.ARMED  # not confirmed yet
    d.on_bytes(ack(CFG, active=0x1234, request=0x1234, configured=False), 0, 0)  # an answer to someone else's
    assert not d.configured and d.state == DriverState.ARMED  # no fault: only the CRC it runs counts
    d.on_bytes(ack(CFG | {"u_max": 180.0}), 0, 0)
    st = d.status()
    assert d.configured and st["board_config"] == "confirmed" and st["board_configured"]
    assert st["config_crc"] == st["board_config_crc"] == f"{config_crc(config_frame(CFG | {'u_max': 180.0})):08x}"
    s, _ = d.on_bytes(sensor(1), 10**18 + MS, MS)
    assert decode(d.command(s.stamp_ns, [50.0, 50.0], MS) or b"").mode == Mode.RUN
    assert d.state == DriverState.ACTIVE


def test_a_refused_configuration_is_one_clear_fault_before_arming():
    d = HwDriver(CFG | {"N1": 500.0})
    hello_then(d)
    d.on_bytes(ack(CFG | {"N1": 500.0}, "no_braking", active=0xCAFE, configured=False), 0, 0)
    assert d.state == DriverState.FAULT and d.counters["config_refused"] == 1
    assert d.reason == ("the board refuses the run's configuration: no_braking: no braking away from the rail: with "
                        "N1, N2 the pull away from the rail at an end is not > 0; it keeps its compiled-in defaults "
                        "(CRC 0x0000cafe)")
    d.arm()  # the operator arms again: the configuration again, refused again
    _, reply = d.on_bytes(sensor(0), 10**18, 0)
    assert isinstance(decode(reply or b""), ConfigFrame)
    d.on_bytes(ack(CFG | {"N1": 500.0}, "no_braking", active=0xCAFE, configured=False), 0, 0)
    assert d.state == DriverState.FAULT and "refuses" in d.reason


def test_a_busy_board_is_asked_again_until_it_lands_and_takes_it():
    d = HwDriver(CFG)
    hello_then(d)
    d.on_bytes(ack(CFG, "busy", active=0xBEEF), 0, 0)  # landing under another configuration
    assert d.state == DriverState.INACTIVE and d.status()["board_config"].startswith("busy")
    d.arm()
    replies = [d.on_bytes(sensor(k, Mode.LAND), 10**18 + k * MS, k * MS)[1] for k in range(250)]
    sent = [k for k, r in enumerate(replies) if r is not None and isinstance(decode(r), ConfigFrame)]
    assert sent == [0, 100, 200]  # at once, then every CONFIG_RETRY_NS
    assert CONFIG_RETRY_NS == 100 * MS
    d.on_bytes(ack(CFG), 0, 250 * MS)  # landed: taken
    assert d.configured and d.state == DriverState.ARMED


def test_a_board_that_never_answers_the_configuration_is_a_fault():
    d = HwDriver(CFG)
    _, reply = d.on_bytes(encode(Hello(1, 7, 1000, 16, 10.0, 50, 2)), 0, 0)  # (an older firmware, delay 2)
    assert reply is not None
    d.arm()
    for k in range(CONFIG_TRIES * 100 + 1):
        d.on_bytes(sensor(k), 10**18 + k * MS, k * MS)
    assert d.state == DriverState.FAULT and d.counters["config_sent"] == 1 + CONFIG_TRIES  # the hello's, then armed
    assert d.reason.startswith(f"the board does not answer the CONFIG frame ({CONFIG_TRIES} sent, none answered)")
    assert d.reason.endswith("its hello states command_delay 2, the run's is 1")


def test_an_inactive_driver_asks_again_too_so_the_status_tells_the_operator_before_arming():
    d = HwDriver(CFG)
    hello_then(d)  # (this one lost)
    replies = [d.on_bytes(sensor(k), 10**18 + k * MS, k * MS)[1] for k in range(1, 1200)]
    sent = [k + 1 for k, r in enumerate(replies) if r is not None and isinstance(decode(r), ConfigFrame)]
    assert sent[:3] == [100, 200, 300] and d.state == DriverState.FAULT and "does not answer" in d.reason
    d = HwDriver(CFG)
    hello_then(d)
    for k in range(1, 150):
        _, reply = d.on_bytes(sensor(k, Mode.LAND), 10**18 + k * MS, k * MS)
        assert decode(reply or b"").mode == Mode.LAND  # type: ignore[union-attr]  # a levitating board: land it first


def test_a_board_that_accepts_but_runs_another_crc_is_a_fault():
    d = HwDriver(CFG)
    hello_then(d)
    d.on_bytes(ack(CFG, active=0x0BAD), 0, 0)
    assert d.state == DriverState.FAULT and "reports it runs 0x00000bad" in d.reason


def test_parameters_changed_at_run_time_reach_the_board_at_the_next_arm():
    d = HwDriver(CFG)
    hello_then(d)
    d.on_bytes(ack(CFG), 0, 0)
    assert d.configured
    d.cfg["hold_timeout"] = 0.03  # the node's on_change updates the driver's parameters
    assert "once the board confirms" in d.arm() and not d.configured
    _, reply = d.on_bytes(sensor(0), 10**18, 0)
    assert decode(reply or b"") == config_frame(CFG | {"hold_timeout": 0.03})


def test_a_gap_table_cannot_configure_a_board():
    d = HwDriver(CFG | {"gap_table": ""})
    d.cfg["gap_table"] = "cal.csv"  # (set after the start: the driver's own table is not read here)
    assert d.arm().startswith("not armed: the board's configuration cannot be sent: hw_driver.gap_table")
    assert d.state == DriverState.FAULT


def test_a_config_frame_from_the_board_is_counted_not_obeyed():
    d = HwDriver(CFG)
    assert d.on_bytes(encode(frame()), 0, 0) == (None, None)
    assert d.corrupt_reasons == {"unexpected config frame": 1}


def _lockstep(b: Board, d: HwDriver, n: int) -> list[Mode]:
    """The board and the driver one tick at a time, every frame each way (the board's hello first)."""
    _, reply = d.on_bytes(b.receive(encode(HELLO_REQUEST)) or b"", 10**18, 0)
    if reply is not None:
        d.on_bytes(b.receive(reply) or b"", 10**18, 0)
    u0 = b.plant.u0
    modes = []
    for _ in range(n):
        data = b.tick()
        if data is None:
            continue
        s, reply = d.on_bytes(data, 10**18 + b.n * MS, b.n * MS)
        if reply is not None:
            back = b.receive(reply)
            if back is not None:
                d.on_bytes(back, 10**18 + b.n * MS, b.n * MS)
        if s is not None:
            modes.append(s.mode)
            cmd = d.command(s.stamp_ns, u0, b.n * MS)
            if cmd is not None:
                b.receive(cmd)
    return modes


def test_in_lockstep_the_driver_configures_a_board_built_with_other_values_then_flies():
    b = board(u_max=150.0, hold_timeout=0.03)
    d = HwDriver(CFG | {"arm_samples": 5})
    d.arm()
    modes = _lockstep(b, d, 30)
    assert b.configured and b.config_crc == config_crc(config_frame(CFG)) and b.bcfg["u_max"] == 200.0
    assert d.configured and d.state == DriverState.ACTIVE and Mode.RUN in modes


def test_in_lockstep_a_configuration_the_board_refuses_never_arms():
    b = board()
    d = HwDriver(CFG | {"arm_samples": 5, "N1": 500.0})
    d.arm()
    modes = _lockstep(b, d, 100)
    assert d.state == DriverState.FAULT and "no_braking" in d.reason
    assert set(modes) == {Mode.OFF} and not b.configured and b.bcfg["N1"] == 36.5  # never flew; defaults kept


def test_the_drivers_own_command_watchdog_may_be_longer_than_the_boards_hold_timeout():
    """hold_timeout is the board's (it travels in the configuration); command_timeout, the PC's alone: a loaded host
    keeps the driver from faulting at 50 ms while the board still lands on its own after 50 ms without a command."""
    cfg = CFG | {"hold_timeout": 0.05, "command_timeout": 0.2}
    d = HwDriver(cfg)
    assert hello_then(d).as_dict()["hold_timeout"] == pytest.approx(0.05)  # the board's, not the PC's watchdog
    d.on_bytes(ack(cfg), 0, 0)
    d.arm()
    s, _ = d.on_bytes(sensor(0), 10**18, 0)
    assert decode(d.command(s.stamp_ns, [50.0, 50.0], 0) or b"").mode == Mode.RUN
    for k in range(1, 150):
        d.on_bytes(sensor(k, Mode.RUN), 10**18 + k * MS, k * MS)
    assert d.state == DriverState.ACTIVE  # 149 ms without a command: past the board's hold, not the PC's watchdog
    d.on_bytes(sensor(201, Mode.RUN), 10**18 + 201 * MS, 201 * MS)
    assert d.state == DriverState.FAULT and d.reason.endswith("(> command_timeout)")

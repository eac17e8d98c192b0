"""The firmware's supervisor (C99, float32, firmware/supervisor.c) against the Python board (dem_ros/board).

Every case runs the true plant (:class:`dem_ros.core.plant.DemPlant`, its own m, R, K, seeded noise) in closed
loop with the Python Supervisor; the C supervisor gets the same input sequence (gaps, currents, commands, the
requested mode, bus and applied voltages, land/estop calls) sample by sample. The grids are those of
tests/core/test_safety.py, seeded and randomised within them:

- ``landing``: level and tilted hovers (4-10 mm) with m, R, K off (+-25 %, R up to 1.4x, 3 kg added), landed
  after lost commands, a LAND or OFF request, land() or an e-stop, some with a kick toward or away from the rail;
- ``approach``: the rail approaches: a plate moving toward the rail at up to 100 mm/s under the worst commands
  (u_max on both or one coil, stuck, negative, alternating, rogue, lost), six plant variants;
- ``lost``: sensor samples lost at hover (NaN bursts of 1-15 samples or for good, on one or two channels);
- ``stuck``: gap sensors frozen at a plausible value, the plate pushed at 1 cm/s (the flux check);
- ``commands``: late and lost commands in bursts, non-finite and clipped commands, bus sags, a failed bridge
  (the applied voltage the board measures);
- ``cycle``: land (request, e-stop, watchdog, a lost gap sensor), clear(), levitate again, several times a case;
- ``liftoff``: the plate lifted off the rig's support (tests/liftoff.py) to 9.5-10.9 mm, rising at 0-6 mm/s (a third
  at 10-35 mm/s), its rise
  slowed or sped up, m, R, K off; then landed by a LAND request or by the watchdog (the commands stop: the hold's
  speed guard).

Asserted per case: the same mode sequence, each transition within one sample; the same latched decisions
(trips, landings, landed, implausible sensors, sensor losses, hold events, clips, rejections; the fault's
kind); and where both boards are in the same mode with no transition shifted, voltages within
``U_TOL`` (RUN, HOLD, brake) and ``U_TOL_LAND`` (the landing law). 0 decision differences over >= 1000 cases.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pytest
from liftoff import LiftOff

from dem_ros.board import LANDING_OVERSHOOT, Mode, Supervisor
from dem_ros.core.model import IP, IQ, equilibrium
from dem_ros.core.params import SCHEMA, TABLE2
from dem_ros.core.plant import DemPlant

try:
    from dem_ros.hardware.cboard import CSupervisor, FirmwareError, library_path
except ImportError as exc:  # pragma: no cover - the binding is part of the package
    raise RuntimeError(f"the firmware binding does not import: {exc}") from exc

T = 1e-3
T_NS = 1_000_000
SUPPORT = 0.0112  # m, the rig group's support_gap default
SEED = 2311
#: voltages [V] where both boards agree on the mode and no decision shifted: float32 against float64; RUN, HOLD
#: and the brake (the command, held or clipped, and the brake law: no state of the board's own in them)
U_TOL = 0.05
#: ... under the landing law (LAND, LANDED): in this test the C board's voltage does not drive the plant (the
#: Python board's does), so its current loop's integral (ui += T kc^2/5 (2K/delta) (i* - i)) runs open loop and
#: accumulates the float32 difference of the two current demands, and where float32 rounding moves the sample at
#: which the landing reference reaches its stop by one (a rate step of v_ref in the demand) keeps that
#: sample's difference; 1 % of u_max (measured: up to 1.25 V)
U_TOL_LAND = 2.0
#: counters that record decisions (brakes, holds and sensor_gaps are per-sample counts of the same decisions)
DECISIONS = ("trips", "landings", "landed", "implausible", "sensor_losses", "hold_events", "clipped", "rejected",
             "estops", "brake_events")
N_CASES = {"landing": 60, "approach": 640, "lost": 200, "stuck": 48, "commands": 100, "cycle": 12, "liftoff": 24}


@pytest.fixture(scope="module")
def firmware() -> None:
    """The firmware's shared library, built once (cached by the sources' hash)."""
    try:
        library_path()
    except FirmwareError as exc:
        pytest.skip(f"the firmware cannot be built here: {exc}")


def board_cfg() -> dict:
    return SCHEMA.defaults("plant_sim")


@dataclass
class Case:
    """One input sequence: the true plant, its start, and what happens per sample."""

    family: str
    seed: int
    variant: tuple[float, float, float, float]  # (fm, dm, fR, fK) of the true plant
    g: tuple[float, float]  # start gaps [m]
    v: tuple[float, float] = (0.0, 0.0)  # start gap rates [m/s]
    n: int = 600  # samples at most
    noise: float = 0.03
    command: Callable[[int, np.ndarray, np.random.Generator], np.ndarray | None] = lambda k, u0, rng: u0
    sense: Callable[[int, np.ndarray, np.ndarray], None] = lambda k, y, i: None
    push: Callable[[int, np.ndarray], None] = lambda k, x: None
    requested: Callable[[int], Mode] = lambda k: Mode.RUN
    bus: Callable[[int], float | None] = lambda k: None
    # the voltages the coils got over the last period, as the rig's board measures them: the true plant's (the
    # Python board's output), so the C board's flux and coil model integrate what was applied, not its own output
    applied: Callable[[int, np.ndarray], np.ndarray | None] = lambda k, u: u
    call: Callable[[int], tuple[str, str] | None] = lambda k: None  # ("land"|"estop", reason) before sample k
    x0: np.ndarray | None = None  # the true plant's start (None: the equilibrium at g, rates v)
    # the command from the true state instead of ``command`` (a controller that sees the plant): (k, x) -> u or None
    state_command: Callable[[int, np.ndarray], np.ndarray | None] | None = None
    until_done: bool = True  # stop 20 samples after LANDED or FAULT
    clear_after_done: bool = False  # instead, clear() both boards 20 samples after LANDED or FAULT and go on
    label: str = ""


@dataclass
class Result:
    case: Case
    samples: int
    diffs: list[str] = field(default_factory=list)
    shifted: int = 0  # transitions one sample apart
    max_du: float = 0.0  # RUN, HOLD and braking samples [V]
    max_du_land: float = 0.0  # under the landing law [V]
    compared: int = 0
    counters: dict[str, int] = field(default_factory=dict)
    modes: set[int] = field(default_factory=set)


def _kind(text: str) -> str:
    """A fault reason's kind: its words without numbers, up to the first colon or parenthesis (both boards)."""
    words = re.sub(r"[-+]?\d[\d.e+-]*", "#", text.split(":")[0].split("(")[0]).split()
    return " ".join(words[:4])


def _runs(modes: list[int]) -> list[tuple[int, int]]:
    out: list[tuple[int, int]] = []
    for k, m in enumerate(modes):
        if not out or out[-1][0] != m:
            out.append((m, k))
    return out


def run_case(case: Case) -> Result:
    fm, dm, fR, fK = case.variant
    cfg = board_cfg()
    pc = SCHEMA.defaults("plant_sim")
    pc.update(m=TABLE2["m"] * fm + dm, R=TABLE2["R"] * fR, K=TABLE2["K"] * fK, noise_scale=case.noise,
              seed=case.seed, measure_velocity=False)
    plant = DemPlant(pc, case.n * T)  # the noise and the (empty) schedule of the whole case at once
    P, Q = plant.p[IP], plant.p[IQ]
    x0, u0 = equilibrium(pc, case.g[0], case.g[1])
    x0[1], x0[3] = case.v
    plant.x[:] = x0 if case.x0 is None else case.x0
    py, c = Supervisor(cfg, T), CSupervisor(cfg, T)
    rng = np.random.default_rng(case.seed)
    mp: list[int] = []
    mc: list[int] = []
    du: list[float] = []
    landing_law: list[bool] = []
    k_done = None
    k = brakes = 0
    for k in range(case.n):
        case.push(k, plant.x)
        call = case.call(k)
        if call is not None:
            for sup in (py, c):
                getattr(sup, call[0])(call[1])
        z = plant.measurement()
        y, i = z[[0, 2]].copy(), z[[4, 5]].copy()
        case.sense(k, y, i)
        cmd = case.command(k, u0, rng) if case.state_command is None else case.state_command(k, plant.x)
        req, bus = case.requested(k), case.bus(k)
        app = case.applied(k, plant.coil_voltage)
        ua = py.step(k * T_NS, y, i, cmd, req, bus=bus, applied=app)
        ub = c.step(k * T_NS, y, i, cmd, req, bus=bus, applied=app)
        mp.append(int(py.mode))
        mc.append(int(c.mode))
        du.append(float(np.max(np.abs(ua - ub))) if mp[-1] == mc[-1] else math.nan)
        landing_law.append(mp[-1] in (Mode.LAND, Mode.LANDED) and py.counters["brakes"] == brakes)
        brakes = py.counters["brakes"]
        if k_done is None and py.mode in (Mode.LANDED, Mode.FAULT):
            k_done = k
        if case.until_done and k_done is not None and k - k_done >= 20:
            break
        if case.clear_after_done and k_done is not None and k - k_done >= 20:
            py.clear()  # the operator's acknowledgement (the rig: an OFF request once landed)
            c.clear()
            k_done = None
        plant.advance(ua)
        x = plant.x
        for j in (0, 2):
            if x[j] >= SUPPORT:
                x[j], x[j + 1] = SUPPORT, min(x[j + 1], 0.0)
        if (plant.fault and "dropped" not in plant.fault) or min(P * x[0] + Q * x[2], Q * x[0] + P * x[2]) <= 0:
            break  # rail contact: the Python board's own tests say whether it may happen; here both must agree
    r = Result(case, k + 1, counters=dict(py.counters), modes=set(mp))
    rp, rc = _runs(mp), _runs(mc)
    if [m for m, _ in rp] != [m for m, _ in rc]:
        r.diffs.append(f"mode sequence: python {[(Mode(m).name, k) for m, k in rp]} "
                       f"c {[(Mode(m).name, k) for m, k in rc]}")
    else:
        for (m, ka), (_, kb) in zip(rp, rc, strict=True):
            if abs(ka - kb) > 1:
                r.diffs.append(f"{Mode(m).name} at sample {ka} (python) and {kb} (c)")
            elif ka != kb:
                r.shifted += 1
    cp, cc = py.counters, c.counters
    for name in DECISIONS:
        if cp[name] != cc[name]:
            r.diffs.append(f"counter {name}: python {cp[name]} c {cc[name]}")
    if _kind(py.fault) != _kind(c.fault):
        r.diffs.append(f"fault: python {py.fault!r} c {c.fault!r}")
    if py.implausible != c.implausible or py.command_timeout != c.command_timeout:
        r.diffs.append(f"flags: python {py.implausible} {py.command_timeout} c {c.implausible} {c.command_timeout}")
    if not r.diffs and not r.shifted:
        d, law = np.array(du), np.array(landing_law)
        r.max_du = float(np.nanmax(d[~law], initial=0.0))
        r.max_du_land = float(np.nanmax(d[law], initial=0.0))
        r.compared = int(np.isfinite(d).sum())
    return r


# -- the grids -------------------------------------------------------------------------------------------------
VARIANTS = [(1.0, 0.0, 1.0, 1.0), (1.25, 3.0, 1.0, 1.0), (1.0, 0.0, 1.4, 1.0), (1.25, 3.0, 1.4, 1.0),
            (0.75, 0.0, 1.0, 1.25), (1.0, 0.0, 0.75, 0.75)]  # test_safety.VARIANTS
COMMANDS = ("both", "one", "one_off", "stuck", "negative", "alternating", "rogue", "lost")


def _feasible(g: float, fm: float, fR: float, fK: float, dm: float, u_max: float) -> bool:
    m = TABLE2["m"] * fm + dm
    i = (g + LANDING_OVERSHOOT) * math.sqrt((TABLE2["N1"] + m * TABLE2["g"] / 2) / (TABLE2["K"] * fK))
    return TABLE2["R"] * fR * i <= 0.95 * u_max


def _worst(kind: str, u_max: float) -> Callable[[int, np.ndarray, np.random.Generator], np.ndarray | None]:
    def f(k: int, u0: np.ndarray, rng: np.random.Generator) -> np.ndarray | None:
        if k < 30:
            return u0
        if kind == "both":
            return np.array([u_max, u_max])
        if kind == "one":
            return np.array([u_max, u0[1]])
        if kind == "one_off":
            return np.array([u_max, 0.0])
        if kind == "stuck":
            return 1.3 * u0
        if kind == "negative":
            return np.array([-u_max, -u_max])
        if kind == "alternating":
            return np.array([u_max, u_max]) * (1.0 if (k // 5) % 2 == 0 else -1.0)
        if kind == "rogue":
            return u0 + rng.uniform(-1.5, 1.5, 2) * u_max
        return None
    return f


def landing_cases(rng: np.random.Generator, n: int) -> list[Case]:
    out: list[Case] = []
    u_max = board_cfg()["u_max"]
    while len(out) < n:
        g1 = rng.uniform(0.004, 0.010)
        g2 = float(np.clip(g1 + rng.uniform(-0.0015, 0.0015), 0.004, 0.010))
        fm, fR, fK = rng.choice([0.75, 1.0, 1.25]), rng.choice([0.75, 1.0, 1.25, 1.4]), rng.choice([0.75, 1.0, 1.25])
        dm = float(rng.choice([0.0, 3.0]))
        if not _feasible(board_cfg()["landing_gap"], fm, fR, fK, dm, u_max):
            continue
        how = rng.choice(["watchdog", "LAND", "OFF", "land", "estop"])
        kick = float(rng.choice([0.0, 0.0, -0.03, 0.03]))
        k0 = int(rng.integers(20, 60))
        cmd: Callable = (lambda k, u0, r, k0=k0: u0 if k < k0 else None) if how == "watchdog" else (
            lambda k, u0, r: u0)
        req: Callable = (lambda k, k0=k0, how=how: Mode[how] if k >= k0 else Mode.RUN) if how in ("LAND", "OFF") \
            else (lambda k: Mode.RUN)
        call: Callable = (lambda k, k0=k0, how=how: (how, "test") if k == k0 else None) if how in ("land", "estop") \
            else (lambda k: None)

        def push(k: int, x: np.ndarray, k0: int = k0, kick: float = kick) -> None:
            if kick and k == k0:
                x[1] = x[3] = kick

        out.append(Case("landing", int(rng.integers(1 << 30)), (fm, dm, fR, fK), (g1, g2), n=4000, command=cmd,
                        requested=req, call=call, push=push, noise=float(rng.choice([0.0, 0.03, 0.1])),
                        label=f"{how} g {g1 * 1e3:.2f}/{g2 * 1e3:.2f} kick {kick}"))
    return out


def approach_cases(rng: np.random.Generator, n: int) -> list[Case]:
    out: list[Case] = []
    u_max = board_cfg()["u_max"]
    for idx in range(n):
        kind = COMMANDS[idx % len(COMMANDS)]
        variant = VARIANTS[(idx // len(COMMANDS)) % len(VARIANTS)]
        g0, v0 = rng.uniform(0.002, 0.008), rng.uniform(0.0, 0.1)
        tilt, v2 = rng.uniform(-0.001, 0.001), rng.choice([1.0, 0.5, -0.5])
        g1, g2 = max(g0 + 30 * T * v0, 0.002), max(g0 + tilt + 30 * T * v0 * v2, 0.002)
        out.append(Case("approach", int(rng.integers(1 << 30)), variant, (g1, g2), (-v0, -v0 * v2), n=180,
                        command=_worst(kind, u_max), until_done=False, label=f"{kind} {g0 * 1e3:.2f} mm {v0:.3f} m/s"))
    return out


def lost_cases(rng: np.random.Generator, n: int) -> list[Case]:
    out: list[Case] = []
    for _ in range(n):
        variant = VARIANTS[int(rng.integers(len(VARIANTS)))]
        chans = rng.choice(4, size=int(rng.integers(1, 3)), replace=False)
        starts = [int(rng.integers(100, 400)) for _ in chans]
        lengths = [int(rng.choice([1, 2, 3, 5, 6, 8, 12, 15, 10_000])) for _ in chans]

        def sense(k: int, y: np.ndarray, i: np.ndarray, chans=chans, starts=starts, lengths=lengths) -> None:
            for ch, k0, length in zip(chans, starts, lengths, strict=True):
                if k0 <= k < k0 + length:
                    (y if ch < 2 else i)[ch % 2] = np.nan

        out.append(Case("lost", int(rng.integers(1 << 30)), variant, (0.008, 0.008), n=500, sense=sense,
                        label=f"channels {list(chans)} from {starts} for {lengths}"))
    return out


def stuck_cases(rng: np.random.Generator, n: int) -> list[Case]:
    out: list[Case] = []
    stuck_variants = [(1.0, 0.0, 1.0, 1.0), (1.25, 0.0, 1.0, 0.75), (1.0, 3.0, 1.25, 1.0), (0.75, 0.0, 0.75, 1.25)]
    for idx in range(n):
        variant = stuck_variants[idx % 4]
        chan, both = int(rng.integers(2)), bool(rng.random() < 0.3)
        v0 = float(rng.choice([-0.01, 0.01]))
        k_freeze = int(rng.integers(450, 600))
        frozen: dict[int, float] = {}

        def sense(k: int, y: np.ndarray, i: np.ndarray, chan=chan, both=both, k0=k_freeze, frozen=frozen) -> None:
            if k >= k0:
                for j in ((0, 1) if both else (chan,)):
                    y[j] = frozen.setdefault(j, float(y[j]))

        def push(k: int, x: np.ndarray, chan=chan, k0=k_freeze, v0=v0) -> None:
            if k == k0 + 100:
                x[2 * chan + 1] = v0

        frozen.clear()
        out.append(Case("stuck", int(rng.integers(1 << 30)), variant, (0.008, 0.008), n=1100, sense=sense, push=push,
                        label=f"gap {chan + 1}{' and the other' if both else ''} frozen at {k_freeze}, push {v0}"))
    return out


def command_cases(rng: np.random.Generator, n: int) -> list[Case]:
    out: list[Case] = []
    u_max = board_cfg()["u_max"]
    for _ in range(n):
        variant = VARIANTS[int(rng.integers(len(VARIANTS)))]
        gaps = sorted(int(k) for k in rng.integers(50, 550, size=4))
        lens = [int(rng.choice([1, 2, 5, 10, 30, 45, 52, 80])) for _ in gaps]
        bad = set(int(k) for k in rng.integers(50, 550, size=3))
        wild = set(int(k) for k in rng.integers(50, 550, size=3))
        sag = (int(rng.integers(100, 500)), float(rng.choice([40.0, 60.0, 120.0])), int(rng.integers(5, 60)))
        open_coil = (int(rng.integers(0, 2)), int(rng.integers(200, 500))) if rng.random() < 0.3 else None

        def cmd(k: int, u0: np.ndarray, r: np.random.Generator, gaps=gaps, lens=lens, bad=bad,
                wild=wild) -> np.ndarray | None:
            if k < 3 or any(k0 <= k < k0 + ln for k0, ln in zip(gaps, lens, strict=True)):
                return None  # (OFF until the first command)
            if k in bad:
                return np.array([math.nan, u0[1]])
            if k in wild:
                return np.array([1.2 * u_max, u0[1]])
            return u0 + r.uniform(-2.0, 2.0, 2)

        def bus(k: int, sag=sag) -> float | None:
            return sag[1] if sag[0] <= k < sag[0] + sag[2] else 200.0

        def applied(k: int, v: np.ndarray, oc=open_coil) -> np.ndarray | None:
            if oc is not None and k >= oc[1]:
                a = v.copy()
                a[oc[0]] = 0.0
                return a
            return v

        out.append(Case("commands", int(rng.integers(1 << 30)), variant, (0.008, 0.0085), n=550, command=cmd, bus=bus,
                        applied=applied, label=f"gaps {list(zip(gaps, lens, strict=True))} sag {sag} open {open_coil}"))
    return out


def cycle_cases(rng: np.random.Generator, n: int) -> list[Case]:
    """Land (a LAND request, an e-stop, lost commands, a lost gap sensor), acknowledge (clear()), levitate again
    from the support under the commands: several landings and restarts per case."""
    out: list[Case] = []
    for idx in range(n):
        variant = VARIANTS[idx % len(VARIANTS)]
        how = ("LAND", "estop", "watchdog", "gap")[idx % 4]
        period = int(rng.integers(250, 400))

        def cmd(k: int, u0: np.ndarray, r: np.random.Generator, how=how, period=period) -> np.ndarray | None:
            if how == "watchdog" and k % period > 120:
                return None
            return u0 + r.uniform(-1.0, 1.0, 2)

        def req(k: int, how=how, period=period) -> Mode:
            return Mode.LAND if how == "LAND" and k % period == 150 else Mode.RUN

        def call(k: int, how=how, period=period) -> tuple[str, str] | None:
            return ("estop", "test") if how == "estop" and k % period == 150 else None

        def sense(k: int, y: np.ndarray, i: np.ndarray, how=how, period=period) -> None:
            if how == "gap" and 150 <= k % period < 170:
                y[0] = np.nan

        out.append(Case("cycle", int(rng.integers(1 << 30)), variant, (0.008, 0.008), n=3000, command=cmd,
                        requested=req, call=call, sense=sense, until_done=False, clear_after_done=True,
                        label=f"{how} every {period} samples"))
    return out


def liftoff_cases(rng: np.random.Generator, n: int) -> list[Case]:
    """The plate lifted off the rig's support (tests/liftoff.py) to a lift-off's state, then landed: requested (LAND)
    or by the command watchdog (the commands stop: the hold, its speed guard, LAND)."""
    out: list[Case] = []
    for idx in range(n):
        fm, dm, fR, fK = VARIANTS[idx % len(VARIANTS)]
        how = ("watchdog", "LAND")[(idx // len(VARIANTS)) % 2]
        fast = idx % 3 == 2  # a lift-off the controller drives faster than landing_speed (held through a late one)
        g, v, a = rng.uniform(0.0095, 0.0109), rng.uniform(-0.035, -0.01) if fast else rng.uniform(-0.006, 0.0), \
            rng.uniform(-0.3, 0.5)
        pc = SCHEMA.defaults("plant_sim")
        pc.update(m=TABLE2["m"] * fm + dm, R=TABLE2["R"] * fR, K=TABLE2["K"] * fK)
        lift = LiftOff(pc, g, v, a)

        def cmd(k: int, x: np.ndarray, lift=lift, how=how) -> np.ndarray | None:
            return lift.command(k, x) if k < lift.n or how == "LAND" else None

        def req(k: int, lift=lift, how=how) -> Mode:
            return Mode.LAND if how == "LAND" and k >= lift.n else Mode.RUN

        out.append(Case("liftoff", int(rng.integers(1 << 30)), (fm, dm, fR, fK), (g, g), n=lift.n + 1500,
                        x0=lift.x0(), state_command=cmd, requested=req,
                        label=f"{how} at {g * 1e3:.2f} mm {v * 1e3:+.1f} mm/s {a:+.2f} m/s^2"))
    return out


BUILDERS = {"landing": landing_cases, "approach": approach_cases, "lost": lost_cases, "stuck": stuck_cases,
            "commands": command_cases, "cycle": cycle_cases, "liftoff": liftoff_cases}


@pytest.fixture(scope="module")
def results(firmware: None) -> dict[str, list[Result]]:
    """Every case of every family, run once (seeded)."""
    out: dict[str, list[Result]] = {}
    for i, (family, build) in enumerate(BUILDERS.items()):
        rng = np.random.default_rng(SEED + i)
        t0 = time.perf_counter()
        out[family] = [run_case(c) for c in build(rng, N_CASES[family])]
        rs = out[family]
        print(f"\n{family}: {len(rs)} cases, {sum(r.samples for r in rs)} samples, "
              f"{sum(bool(r.diffs) for r in rs)} with decision differences, {sum(r.shifted for r in rs)} transitions "
              f"one sample apart, max |du| {max(r.max_du for r in rs):.4g} V (RUN, HOLD, brake), "
              f"{max(r.max_du_land for r in rs):.4g} V (landing law) over "
              f"{sum(r.compared for r in rs)} samples ({time.perf_counter() - t0:.1f} s)")
    return out


@pytest.mark.parametrize("family", list(BUILDERS))
def test_the_c_board_decides_as_the_python_board(results: dict[str, list[Result]], family: str) -> None:
    """Same mode sequence (transitions within one sample), same latched decisions, voltages within U_TOL."""
    rs = results[family]
    assert len(rs) == N_CASES[family]
    bad = [(r.case.label, r.diffs) for r in rs if r.diffs]
    assert not bad, f"{len(bad)} of {len(rs)} cases decide differently, e.g. {bad[:3]}"
    worst = max(rs, key=lambda r: r.max_du)
    assert worst.max_du <= U_TOL, (worst.case.label, worst.max_du)
    worst = max(rs, key=lambda r: r.max_du_land)
    assert worst.max_du_land <= U_TOL_LAND, (worst.case.label, worst.max_du_land)


def test_the_grids_cover_the_decisions(results: dict[str, list[Result]]) -> None:
    """>= 1000 cases; every decision the board makes occurs somewhere in them."""
    rs = [r for v in results.values() for r in v]
    assert len(rs) >= 1000
    modes = set().union(*(r.modes for r in rs))
    assert modes == set(Mode), modes
    for name in DECISIONS:
        assert sum(r.counters[name] for r in rs) > 0, name
    assert sum(r.counters["longest_hold_us"] > 0 for r in rs) > 0

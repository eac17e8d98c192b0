"""Benchmark of the device link: board-sample → command-received round trip at the board's rate.

Two processes, as on a rig: a *board* process that is the clock (sleeps to
absolute deadlines of period 1/rate, sends sensor frame k, applies whatever
command arrives before sample k+1) and a *PC* process that answers each sensor
frame at once with a command echoing its seq. The board measures, on its own
monotonic clock, the time from sending sensor k to receiving command k, and
counts command k *on time* when it was received before the board took sample
k+1 (so it could be applied there; a board that wakes late gives the command
more time, as a real board's timer interrupt would not)::

    python -m dem_ros.hardware.linkbench udp    --rate 1000 --duration 5
    python -m dem_ros.hardware.linkbench serial --rate 1000 --duration 5   # a pty pair + pyserial
    python -m dem_ros.hardware.linkbench serial --tty-workers-fifo 1       # tty workers at SCHED_FIFO 1
    python -m dem_ros.hardware.linkbench codec     # CPU cost of the Python codec per frame

Both processes take the graph's real-time settings (:mod:`dem_ros.realtime`, from the
``DEM_ROS_RT*`` environment): the PC at the nodes' SCHED_FIFO priority, the board 10 above it
(as ``dem-ros rig``). ``--tty-workers-fifo N`` also runs the kernel's tty workers at SCHED_FIFO
N for the run (:func:`dem_ros.realtime.tty_workers_fifo`): the serial link's latency on a
loaded machine is theirs (``docs/hardware-link.md``, "Serial latency").

Reports round-trip percentiles, the share of commands that reached the board
before its next sample (on time), late and lost commands, the board's wake-up
lateness, and the load average beside them (the figures mean nothing without it).
No control runs here: this is the link alone (codec + transport + scheduling).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import sys
import time
from multiprocessing.connection import Connection

import numpy as np

from ..realtime import apply, config_from_env, tty_workers_fifo
from .channel import ChannelError, open_channel
from .link import HELLO_REQUEST, CommandFrame, Hello, LinkError, Mode, SensorFrame, decode, encode

__all__ = ["main", "run"]


def _realtime(above: int) -> str:
    """This process under the graph's real-time settings, ``above`` the nodes' priority; what it got."""
    import dataclasses

    cfg = config_from_env()
    g = apply(dataclasses.replace(cfg, priority=min(cfg.priority + above, 99)), warn=lambda _line: None)
    return f"SCHED_FIFO {g.fifo_priority}" if g.fifo_priority else "normal priority"


def _board(url: str, rate: float, n: int, conn: Connection) -> None:
    scheduling = _realtime(10)
    ch = open_channel(url, "board")
    conn.send(getattr(ch, "peer_url", None) or f"udp://127.0.0.1:{ch.local_address[1]}")  # type: ignore[union-attr]
    deadline = time.monotonic() + 30.0
    while True:  # the handshake
        f = ch.recv(max(0.0, deadline - time.monotonic()))
        if f is None:
            conn.send({"error": "no hello from the PC within 30 s"})
            return
        try:
            if decode(f) == HELLO_REQUEST:
                break
        except LinkError:
            pass
    ch.send(encode(Hello(1, 0xBE7C4, int(rate), 12, 3.0, 50, 1)))
    period_ns = round(1e9 / rate)
    sent = np.zeros(n, dtype=np.int64)
    rtt = np.full(n, -1, dtype=np.int64)  # ns; -1: never arrived
    on_time = np.zeros(n, dtype=bool)
    wake_late = np.zeros(n, dtype=np.int64)
    rejected = 0
    t_next = time.monotonic_ns() + 50 * period_ns
    for k in range(n):
        # until sample k: take every command that arrives (always at least one poll, even when late)
        while True:
            left = t_next - time.monotonic_ns()
            f = ch.recv(max(0, left) / 1e9)
            if f is None:
                if t_next - time.monotonic_ns() <= 0:
                    break
                continue
            got = time.monotonic_ns()
            try:
                c = decode(f)
            except LinkError:
                rejected += 1
                continue
            if isinstance(c, CommandFrame) and 0 <= c.seq < k and rtt[c.seq] < 0:
                rtt[c.seq] = got - sent[c.seq]
                on_time[c.seq] = c.seq == k - 1  # in time to be applied at this sample
        now = time.monotonic_ns()
        wake_late[k] = now - t_next
        ch.send(encode(SensorFrame(k, now // 1000, (2048, 2048), (1700, 1700), (50.0, 50.0), 150.0, 0, Mode.RUN)))
        sent[k] = time.monotonic_ns()
        t_next += period_ns
    # collect stragglers for one more period
    end = time.monotonic_ns() + 20 * period_ns  # the last sample's command, and stragglers
    while (left := end - time.monotonic_ns()) > 0 and (f := ch.recv(left / 1e9)) is not None:
        try:
            c = decode(f)
        except LinkError:
            rejected += 1
            continue
        if isinstance(c, CommandFrame) and 0 <= c.seq < n and rtt[c.seq] < 0:
            rtt[c.seq] = time.monotonic_ns() - sent[c.seq]
            on_time[c.seq] = c.seq == n - 1 and rtt[c.seq] <= period_ns
    stats = dict(ch.stats)
    ch.close()
    conn.send({"rtt": rtt, "on_time": on_time, "wake_late": wake_late, "rejected": rejected, "stats": stats,
               "scheduling": scheduling})


def _pc_process(url: str, n: int, conn: Connection) -> None:
    """The PC side in a process of its own (its real-time settings stay out of the caller's)."""
    scheduling = _realtime(0)
    try:
        answered, stats = _pc(url, n)
    except (ChannelError, LinkError) as e:
        conn.send({"error": str(e)})
        return
    conn.send({"answered": answered, "stats": stats, "scheduling": scheduling})


def _pc(url: str, n: int) -> tuple[int, dict[str, int]]:
    ch = open_channel(url, "pc")
    try:
        for _ in range(300):  # say hello until the board answers (it may still be starting)
            ch.send(encode(HELLO_REQUEST))
            f = ch.recv(0.1)
            if f is not None and isinstance(decode(f), Hello):
                break
        else:
            raise ChannelError(f"{url}: the board did not answer the hello")
        answered = 0
        while answered < n and (f := ch.recv(2.0)) is not None:
            try:
                s = decode(f)
            except LinkError:
                continue
            if isinstance(s, SensorFrame):
                ch.send(encode(CommandFrame(s.seq, (50.0, 50.0), Mode.RUN)))
                answered += 1
        return answered, dict(ch.stats)
    finally:
        ch.close()


def run(transport: str, rate: float, duration: float, tty_workers: int = 0) -> dict[str, object]:
    """Run the board and PC processes; return the figures (µs where timed).

    ``tty_workers``: > 0 runs the kernel's tty workers at that SCHED_FIFO priority meanwhile.
    """
    if tty_workers > 0:
        with tty_workers_fifo(tty_workers) as changed:
            r = run(transport, rate, duration)
        r["tty_workers"] = (f"SCHED_FIFO {tty_workers} ({len(changed)} kworker/u threads)" if changed
                            else "not permitted")
        return r
    n = int(rate * duration)
    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe()
    url = "udp://127.0.0.1:0" if transport == "udp" else "pty://"
    board = ctx.Process(target=_board, args=(url, rate, n, child), daemon=True)
    board.start()
    pc_url = parent.recv()
    pc_parent, pc_child = ctx.Pipe()
    pc = ctx.Process(target=_pc_process, args=(pc_url, n, pc_child), daemon=True)
    pc.start()
    wait_s = 60.0 + 2.0 * duration
    if not pc_parent.poll(wait_s) or not parent.poll(wait_s):
        board.kill()
        pc.kill()
        raise RuntimeError("the board or PC process did not report")
    pc_res, res = pc_parent.recv(), parent.recv()
    board.join(5.0)
    pc.join(5.0)
    for r in (pc_res, res):
        if "error" in r:
            raise RuntimeError(r["error"])
    answered, pc_stats, pc_scheduling = pc_res["answered"], pc_res["stats"], pc_res["scheduling"]
    rtt = res["rtt"]
    ok = rtt >= 0
    us = rtt[ok] / 1e3
    load = os.getloadavg()
    return {
        "samples": n, "pc_answered": answered, "commands_received": int(ok.sum()),
        "on_time_pct": 100.0 * res["on_time"].sum() / n, "late": int(ok.sum() - res["on_time"].sum()),
        "lost": int(n - ok.sum()), "rejected": res["rejected"],
        "rtt_p50_us": float(np.percentile(us, 50)) if us.size else float("nan"),
        "rtt_p90_us": float(np.percentile(us, 90)) if us.size else float("nan"),
        "rtt_p99_us": float(np.percentile(us, 99)) if us.size else float("nan"),
        "rtt_max_us": float(us.max()) if us.size else float("nan"),
        "board_wake_late_p50_us": float(np.percentile(res["wake_late"], 50) / 1e3),
        "board_wake_late_p99_us": float(np.percentile(res["wake_late"], 99) / 1e3),
        "load1": load[0], "load5": load[1],
        "board_channel": res["stats"], "pc_channel": pc_stats,
        "board_scheduling": res["scheduling"], "pc_scheduling": pc_scheduling, "tty_workers": "normal priority",
    }


def codec_costs(number: int = 20000) -> dict[str, float]:
    """Best-of-5 CPU time per call [µs] of the Python codec's per-sample operations."""
    import timeit

    from .framing import Deframer, wire_frame

    s = encode(SensorFrame(7, 123456, (2048, 2050), (1700, 1701), (50.0, 49.5), 150.0, 0, Mode.RUN))
    c = CommandFrame(7, (50.0, 49.0), Mode.RUN)
    w = wire_frame(s)
    d = Deframer()
    ops = {
        "decode(sensor)": lambda: decode(s),
        "encode(command)": lambda: encode(c),
        "wire_frame(sensor)": lambda: wire_frame(s),
        "Deframer.feed(sensor wire)": lambda: d.feed(w),
    }
    return {k: min(timeit.repeat(f, number=number, repeat=5)) / number * 1e6 for k, f in ops.items()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m dem_ros.hardware.linkbench", description=__doc__.splitlines()[0])
    p.add_argument("transport", choices=["udp", "serial", "codec"],
                   help="udp on loopback, serial over a pty pair, or codec (CPU cost per frame)")
    p.add_argument("--rate", type=float, default=1000.0, help="board sample rate [Hz] (default 1000)")
    p.add_argument("--duration", type=float, default=5.0, help="seconds (default 5)")
    p.add_argument("--tty-workers-fifo", type=int, default=0, metavar="N",
                   help="serial: run the kernel's tty workers (kworker/u*) at SCHED_FIFO N for the run "
                        "(root; 0: leave them)")
    a = p.parse_args(argv)
    if not 0 <= a.tty_workers_fifo <= 99:
        p.error("--tty-workers-fifo must be in [0, 99]")
    if not (1.0 <= a.rate <= 20000.0) or not (0.1 <= a.duration <= 600.0):
        p.error("--rate must be in [1, 20000] Hz and --duration in [0.1, 600] s")
    if a.transport == "codec":
        costs = codec_costs()
        load = os.getloadavg()
        print(f"codec CPU time per call, best of 5 (load average {load[0]:.2f} {load[1]:.2f})")
        for k, v in costs.items():
            print(f"  {k:28s} {v:6.1f} us")
        return 0
    try:
        r = run(a.transport, a.rate, a.duration, a.tty_workers_fifo)
    except (ChannelError, RuntimeError) as e:
        print(f"linkbench: {e}", file=sys.stderr)
        return 1
    print(f"link {a.transport} at {a.rate:g} Hz for {a.duration:g} s (load average {r['load1']:.2f} {r['load5']:.2f});"
          f" board {r['board_scheduling']}, PC {r['pc_scheduling']}, tty workers {r['tty_workers']}")
    print(f"  samples {r['samples']}, commands back {r['commands_received']} "
          f"(on time {r['on_time_pct']:.2f} %, late {r['late']}, lost {r['lost']}, rejected {r['rejected']})")
    print(f"  round trip board-sample -> command at the board: p50 {r['rtt_p50_us']:.0f} us, "
          f"p90 {r['rtt_p90_us']:.0f} us, p99 {r['rtt_p99_us']:.0f} us, max {r['rtt_max_us']:.0f} us")
    print(f"  board wake-up lateness: p50 {r['board_wake_late_p50_us']:.0f} us, "
          f"p99 {r['board_wake_late_p99_us']:.0f} us")
    print(f"  board channel {r['board_channel']}")
    print(f"  pc channel    {r['pc_channel']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Real-time process settings for the 1 kHz loop, as ros2_control and realtime_tools apply them.

What each setting is for (a Python loop on a stock, non-RT Linux kernel):

* **SCHED_FIFO** (``priority``, 1..99; ros2_control's controller manager uses 50): the loop's
  thread preempts every normal (SCHED_OTHER) thread on its core the moment its timer fires,
  instead of waiting for the fair scheduler to give it a slice. On a loaded machine this is
  the difference between wake-ups > 1 ms late in ~5-10 % of periods and in < 1 % (measured
  here, see docs/manual/realtime.md and docs/results.md). Applied to the loop's thread (the one that calls
  :func:`enter_loop`) and to the DDS threads that receive and deliver samples (cyclonedds
  ``recv*`` / ``dq.*``), which sit on the same path in a process-per-node graph; its
  timed-event and collector threads (``tev``, ``gc``: heartbeats, acknowledgements, discovery)
  get ``priority - 1``, and so do the process's other Python threads (the bag writer): they share the GIL
  with the loop, and a helper thread preempted by a busy neighbour while it holds the GIL
  would keep the loop waiting for it (priority inversion); they sleep between their bursts.
* **off the loop's path** (``priority`` 0; the recorder): normal scheduling at nice
  :data:`OFF_LOOP_NICE`, every other setting as for the loop. A process that is not on the
  sample path must not spend the CPUs' real-time budget: the kernel lets real-time threads
  use at most ``sched_rt_runtime_us`` of each CPU per ``sched_rt_period_us`` (950 of 1000 ms)
  and then runs the starved normal threads for the rest of the period, so that *every*
  real-time thread on that CPU waits up to 50 ms. One process per node on the rig (driver,
  estimator, controller, reference, the emulated board and a recorder at SCHED_FIFO) took
  ~180 % of the 2 cores at real-time priority; its loop stalled for 50 ms ("runnable") about
  ten times in a 30 s run and the board's watchdog landed the plate; with the recorder at nice
  -10 instead, nothing stalled that long (docs/results.md). At nice -10 a busy normal
  process (weight 1024) still cannot take more than a tenth of a core from it (9548).
* **mlockall** (``lock_memory``; ``MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT``): no page the process
  has touched is paged out (or reclaimed and faulted in again) while the loop runs.
  ``MCL_ONFAULT`` (Linux >= 4.4) locks pages as they are used instead of populating every
  mapping at once: without it a composed graph (numba, LLVM, cyclonedds, thread stacks) locks
  ~0.9 GB, with it about what it uses (see docs/manual/realtime.md and docs/results.md).
* **timer slack** (``timer_slack_ns``, 1 us): a normal thread's sleeps may end up to 50 us
  late (the kernel's default slack, used to batch wake-ups); the loop sleeps to absolute
  deadlines and wants none of it. Needs no privilege.
* **CPU pinning** (``cpus``, optional): keep the loop's threads on chosen cores.
* **one BLAS thread** (always, with real time on): numpy's and scipy's OpenBLAS hand even a 4x4
  product or ``expm`` to worker threads and *spin* (``sched_yield``) until they are done. Those
  workers are not the loop's threads: they stay at normal priority, so behind the graph's
  real-time threads on a 2-core machine they may not run for tens of ms while the loop's FIFO
  thread spins for them without sleeping (priority inversion). Measured at SCHED_FIFO 50 beside
  two busy ``yes``: ``make_controller`` (one ``expm``) took 11 ms median, 111 ms at worst with
  OpenBLAS's threads, 0.17 / 0.51 ms with one; on the rig a controller's lift-off (a law built
  and hover-fitted on the 1 kHz path) spun 90 ms and 306 ms, the board landed the plate (no
  command for 50 ms) and the RT budget below put the controller back to normal scheduling.
  Every OpenBLAS the process has loaded is set to one thread (``openblas_set_num_threads``),
  and ``OPENBLAS_NUM_THREADS=1`` covers one loaded later (and the process's children).
* **garbage collector**: everything allocated during set-up (numba, the middleware, the nodes)
  is collected once and frozen (:func:`gc.freeze`), then automatic collection is disabled: a
  full collection of a Python process this size takes ~100 ms, which a 1 kHz loop cannot
  absorb. Reference counting still frees everything the loop allocates; the loop makes no
  reference cycles (``tests/test_realtime.py`` checks that a composed run leaves no cyclic
  garbage), so nothing accumulates.

The loop never spins: the executor sleeps until its next deadline or sample (a FIFO thread that
spins would starve every normal thread of its core; the kernel's RT throttling,
``sched_rt_runtime_us``, would then cut in: once the real-time threads on a CPU have run 950 ms
of a second, *every* real-time thread on that CPU, any process's, stops for the remaining 50 ms,
measured here). Two guards keep a process of ours from being that thread:

* **RT budget** (``RLIMIT_RTTIME``, :data:`RT_BUDGET_MS`): a real-time thread of the process that
  runs that long without sleeping gets ``SIGXCPU``; the handler puts the whole process back to
  normal scheduling and says so in one line (a healthy loop sleeps every period; a catch-up
  after a long stall runs a few tens of ms);
* **leaving the loop** (:func:`leave_loop`): when the loop ends, the process's threads go back to
  normal scheduling before the shutdown work (finalising a bag: hundreds of ms of compression
  and writing), which at SCHED_FIFO would hold the CPU against every other process's loop of
  the same priority.

Settings come from the environment, so that one switch reaches every node process and the
container alike (``dem-ros launch/bench --rt/--no-rt`` set it for their children):

==========================  =============  ============================================
variable                    default        meaning
==========================  =============  ============================================
``DEM_ROS_RT``              ``1``          ``0``: leave the process as it is
``DEM_ROS_RT_PRIORITY``     ``50``         SCHED_FIFO priority (1..99); 0: off the loop's path
``DEM_ROS_RT_LOCK_MEMORY``  ``1``          ``0``: no mlockall
``DEM_ROS_RT_CPUS``         (none)         e.g. ``1`` or ``0,1``: pin the loop's threads
``DEM_ROS_RT_STALL_MS``     ``5``          report loop stalls longer than this (ms)
==========================  =============  ============================================

Where a setting is not permitted (no ``CAP_SYS_NICE`` and ``RLIMIT_RTPRIO`` 0, a small
``RLIMIT_MEMLOCK``) the process prints ONE warning line that names what is missing and how to
grant it, and runs on without it.

**Stalls, and whose they are** (:class:`StallMonitor`). The executor tells the monitor when each
dispatch round was due and when it ended; a round that ends more than ``stall_ms`` after it was
due is a stall. The kernel's own accounting of the loop's thread over the stall
(``/proc/thread-self/schedstat``: time on a CPU, time runnable but waiting for one) and the
hypervisor's steal (``/proc/stat``) say where the time went:

* ``running``: the thread itself was computing (our code: a long callback, a collection);
* ``runnable``: ready but not given a CPU: a higher- or equal-priority real-time thread held it,
  the kernel's RT throttling (``sched_rt_runtime_us``: real-time threads together may use at
  most that share of each CPU per ``sched_rt_period_us``) or the host ran another guest;
* ``stolen``: neither, while the hypervisor's steal over the same stretch covers at least half
  of it: the host did not run this vCPU (the guest counts that time nowhere for the thread);
* ``blocked``: neither, without that steal: asleep past its deadline: the thread waited for the
  GIL, a page fault or I/O, or the timer fired late.

Each stall is one ``STALL {json}`` line on stderr (at most :data:`STALL_LINES_PER_S` a second);
at exit the process prints ``STALLS {json}`` on stdout: how many, how long in total and the
longest, per cause, with the steal and the RT throttling settings beside them.
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import ctypes.util
import errno
import gc
import json
import os
import resource
import sys
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

from .core.params import ConfigError

__all__ = ["ENV", "OFF_LOOP_NICE", "REPORT_PREFIX", "STALLS_PREFIX", "Granted", "RtConfig", "RtConfigError",
           "StallMonitor", "apply", "config_from_env", "enter_loop", "granted", "leave_loop", "loop_monitor",
           "tty_workers_fifo"]

#: environment variables read by :func:`config_from_env`
ENV = {"enabled": "DEM_ROS_RT", "priority": "DEM_ROS_RT_PRIORITY", "lock_memory": "DEM_ROS_RT_LOCK_MEMORY",
       "cpus": "DEM_ROS_RT_CPUS", "stall_ms": "DEM_ROS_RT_STALL_MS"}

_PR_SET_TIMERSLACK = 29
_MCL_CURRENT, _MCL_FUTURE, _MCL_ONFAULT = 1, 2, 4
#: DDS threads on the sample path: cyclonedds's receive (``recv``, ``recvUC``, ``recvMC``) and delivery
#: (``dq.*``); Fast DDS's (the rclpy transport) UDP and shared-memory receive (``dds.udp.*``, ``dds.shm.*``)
_DDS_PATH_THREADS = ("recv", "dq.", "dds.udp", "dds.shm")
#: cyclonedds's timed events (heartbeats, acknowledgements, discovery) and its garbage collector, Fast DDS's
#: events and asynchronous writer: starved at normal priority on a loaded machine, remote peers
#: (``dem-ros param``) cannot find the node in time
_DDS_SERVICE_THREADS = ("tev", "gc")
_FASTDDS_SERVICE_THREADS = ("dds.ev", "dds.asyn")
#: start of the line that reports what a process was granted (JSON follows; the launcher reads it)
REPORT_PREFIX = "REALTIME "
#: start of the line with the loop's stall summary, printed at exit (JSON follows)
STALLS_PREFIX = "STALLS "
#: at most this many ``STALL`` lines a second (the rest are counted in the summary)
STALL_LINES_PER_S = 5
#: a real-time thread that runs this long without sleeping puts the process back to normal scheduling
RT_BUDGET_MS = 200
#: nice value of a process off the loop's path (``priority`` 0): above every busy normal process, at no
#: cost to the CPUs' real-time budget
OFF_LOOP_NICE = -10
#: how to grant what is missing (one line)
HOW_TO_GRANT = ("grant it with '@realtime - rtprio 99' and '@realtime - memlock unlimited' in "
                "/etc/security/limits.conf (user in group realtime), or in a container "
                "--cap-add=sys_nice --ulimit rtprio=99 --ulimit memlock=-1; DEM_ROS_RT=0 silences this")


class RtConfigError(ConfigError):
    """A real-time setting has a value that cannot be applied (which variable, which value)."""


@dataclass(frozen=True)
class RtConfig:
    """What to ask for. ``cpus``: the cores to pin the loop's threads to (``()``: no pinning)."""

    enabled: bool = True
    priority: int = 50
    lock_memory: bool = True
    cpus: tuple[int, ...] = ()
    timer_slack_ns: int = 1000
    stall_ms: float = 5.0

    def __post_init__(self) -> None:
        if not self.stall_ms > 0:
            raise RtConfigError(f"stall threshold must be > 0 ms, got {self.stall_ms}")
        if not 0 <= self.priority <= 99:
            raise RtConfigError(f"SCHED_FIFO priority must be 1..99 (0: normal scheduling, off the loop's path),"
                                f" got {self.priority}")
        if self.timer_slack_ns < 1:
            raise RtConfigError(f"timer slack must be >= 1 ns, got {self.timer_slack_ns}")
        n = os.cpu_count() or 1
        bad = [c for c in self.cpus if not 0 <= c < n]
        if bad:
            raise RtConfigError(f"CPU(s) {bad} do not exist (this machine has 0..{n - 1})")


@dataclass
class Granted:
    """What the process got (reported by ``bench loop --json`` as ``rt``).

    Attributes:
        requested: the settings asked for (False: DEM_ROS_RT=0).
        fifo_priority: SCHED_FIFO priority of the loop's thread, or None (normal scheduling).
        fifo_threads: threads set to SCHED_FIFO (names, the loop's thread first).
        nice: the process's threads' nice value when off the loop's path (priority 0), or None.
        memory_locked: mlockall succeeded.
        timer_slack_ns: the loop thread's timer slack (ns), or None if not set.
        cpus: cores the loop's threads are pinned to, or None.
        gc_frozen: objects moved to the permanent generation; automatic collection disabled.
        rt_budget_ms: the RT budget (``RLIMIT_RTTIME``) armed, or None.
        blas_single_thread: the OpenBLAS libraries (file names) set to one thread.
        missing: what was asked for and refused, one short phrase each.
    """

    requested: bool = False
    fifo_priority: int | None = None
    fifo_threads: list[str] = field(default_factory=list)
    nice: int | None = None
    memory_locked: bool = False
    timer_slack_ns: int | None = None
    cpus: list[int] | None = None
    gc_frozen: bool = False
    rt_budget_ms: int | None = None
    blas_single_thread: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return asdict(self)


_GRANTED: Granted | None = None
_MONITOR: StallMonitor | None = None


def granted() -> Granted | None:
    """What :func:`enter_loop` applied in this process (None before it ran)."""
    return _GRANTED


def _flag(env: Mapping[str, str], key: str, default: bool) -> bool:
    v = env.get(ENV[key])
    if v is None or v.strip() == "":
        return default
    t = v.strip().lower()
    if t in ("1", "true", "yes", "on"):
        return True
    if t in ("0", "false", "no", "off"):
        return False
    raise RtConfigError(f"{ENV[key]}={v!r}: use 1 or 0")


def config_from_env(env: Mapping[str, str] | None = None) -> RtConfig:
    """The :class:`RtConfig` the environment asks for (see the module docstring); bad values raise."""
    env = os.environ if env is None else env
    enabled = _flag(env, "enabled", True)
    lock = _flag(env, "lock_memory", True)
    p = env.get(ENV["priority"], "").strip()
    try:
        priority = int(p) if p else 50
    except ValueError:
        raise RtConfigError(f"{ENV['priority']}={p!r}: not an integer (1..99, or 0)") from None
    c = env.get(ENV["cpus"], "").strip()
    try:
        cpus = tuple(int(x) for x in c.split(",") if x.strip()) if c else ()
    except ValueError:
        raise RtConfigError(f"{ENV['cpus']}={c!r}: use core numbers separated by commas, e.g. 1 or 0,1") from None
    m = env.get(ENV["stall_ms"], "").strip()
    try:
        stall_ms = float(m) if m else 5.0
    except ValueError:
        raise RtConfigError(f"{ENV['stall_ms']}={m!r}: not a number of milliseconds") from None
    try:
        return RtConfig(enabled=enabled, priority=priority, lock_memory=lock, cpus=cpus, stall_ms=stall_ms)
    except RtConfigError as exc:
        raise RtConfigError(f"{exc} (from the {', '.join(ENV.values())} environment)") from None


def _libc() -> ctypes.CDLL:
    return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)


def _threads() -> list[tuple[int, str]]:
    """(tid, name) of every thread of this process."""
    out = []
    try:
        for tid in os.listdir("/proc/self/task"):
            try:
                with open(f"/proc/self/task/{tid}/comm") as f:
                    out.append((int(tid), f.read().strip()))
            except OSError:
                pass
    except OSError:
        pass
    return out


def _loop_threads(priority: int) -> list[tuple[int, str, int]]:
    """(tid, name, FIFO priority): the loop's thread (the caller, first) and the DDS threads on the
    sample path at ``priority``; the process's other Python threads one below it."""
    me = threading.get_native_id()
    out = [(me, _thread_name(me), priority)]
    os_threads = [(t, n) for t, n in _threads() if t != me]
    out += [(t, n, priority) for t, n in os_threads if n.startswith(_DDS_PATH_THREADS)]
    out += [(t, n, max(1, priority - 1)) for t, n in os_threads
            if n in _DDS_SERVICE_THREADS or n.startswith(_FASTDDS_SERVICE_THREADS)]
    out += [(t.native_id, t.name, max(1, priority - 1)) for t in threading.enumerate()
            if t.native_id is not None and t.native_id != me and t.is_alive()]
    return out


def _thread_name(tid: int) -> str:
    try:
        with open(f"/proc/self/task/{tid}/comm") as f:
            return f.read().strip()
    except OSError:
        return str(tid)


def _set_fifo(priority: int, threads: list[tuple[int, str, int]], g: Granted) -> None:
    (tid, name, _), rest = threads[0], threads[1:]
    try:
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        lim = resource.getrlimit(resource.RLIMIT_RTPRIO)[0]
        shown = "unlimited" if lim == resource.RLIM_INFINITY else str(lim)
        g.missing.append(f"SCHED_FIFO {priority} (no CAP_SYS_NICE, RLIMIT_RTPRIO {shown})")
        return
    except OSError as exc:
        g.missing.append(f"SCHED_FIFO {priority} ({exc.strerror})")
        return
    g.fifo_priority = priority
    g.fifo_threads.append(name)
    for t, n, p in rest:
        try:
            os.sched_setscheduler(t, os.SCHED_FIFO, os.sched_param(p))
            g.fifo_threads.append(n if p == priority else f"{n} ({p})")
        except OSError:  # the thread has ended
            pass


def _set_nice(nice: int, g: Granted) -> None:
    """Every thread of this process (and so the threads they start) at ``nice``, normal scheduling."""
    for tid, _ in _threads():
        try:
            os.setpriority(os.PRIO_PROCESS, tid, nice)  # Linux: a thread's own nice value
        except PermissionError:
            lim = resource.getrlimit(resource.RLIMIT_NICE)[0]
            g.missing.append(f"nice {nice} (no CAP_SYS_NICE, RLIMIT_NICE {lim})")
            return
        except OSError:  # the thread has ended
            pass
    g.nice = nice


def _lock_memory(libc: ctypes.CDLL, g: Granted) -> None:
    if libc.mlockall(_MCL_CURRENT | _MCL_FUTURE | _MCL_ONFAULT) == 0:
        g.memory_locked = True
        return
    err = ctypes.get_errno()
    if err == errno.EINVAL and libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) == 0:  # a kernel before 4.4
        g.memory_locked = True
        return
    err = ctypes.get_errno()
    lim = resource.getrlimit(resource.RLIMIT_MEMLOCK)[0]
    shown = "unlimited" if lim == resource.RLIM_INFINITY else f"{lim // 1024} KiB"
    why = f"RLIMIT_MEMLOCK {shown}" if err in (errno.ENOMEM, errno.EPERM) else os.strerror(err)
    g.missing.append(f"mlockall ({why})")


#: what OpenBLAS builds call their thread-count setter (plain, numpy's and scipy's wheels: 32 / 64-bit ints)
_BLAS_SET_THREADS = ("openblas_set_num_threads", "openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
                     "scipy_openblas_set_num_threads64_")


def _single_thread_blas(g: Granted) -> None:
    """Every OpenBLAS loaded in this process computes on the calling thread only (module docstring)."""
    os.environ["OPENBLAS_NUM_THREADS"] = "1"  # an OpenBLAS loaded from now on reads it when it loads
    try:
        with open("/proc/self/maps") as f:
            paths = sorted({ln.split(None, 5)[5].strip() for ln in f
                            if "openblas" in ln.lower() and len(ln.split(None, 5)) == 6})
    except OSError:
        return
    for path in paths:
        try:
            lib = ctypes.CDLL(path)  # already loaded: the same handle, nothing runs
        except OSError:
            continue
        setter = next((getattr(lib, n) for n in _BLAS_SET_THREADS if hasattr(lib, n)), None)
        if setter is not None:
            setter.argtypes = [ctypes.c_int]
            setter.restype = None
            setter(1)
            g.blas_single_thread.append(os.path.basename(path))


def _arm_rt_budget(ms: int) -> int | None:
    """``RLIMIT_RTTIME`` soft limit ``ms`` with a SIGXCPU handler that leaves real time (see the
    module docstring); None where it cannot be armed (not the main thread, no such limit)."""
    import signal

    def over_budget(signum: int, frame: Any) -> None:
        n = leave_loop()
        with contextlib.suppress(Exception):
            sys.stderr.write(f"error: dem_ros real time: a real-time thread of this process ran {ms} ms without"
                             f" sleeping; {n} thread(s) back to normal scheduling (RT throttling would otherwise"
                             " stop every real-time thread on its CPU)\n")
            sys.stderr.flush()

    try:
        signal.signal(signal.SIGXCPU, over_budget)
        hard = resource.getrlimit(resource.RLIMIT_RTTIME)[1]
        soft = ms * 1000 if hard == resource.RLIM_INFINITY else min(ms * 1000, hard)
        resource.setrlimit(resource.RLIMIT_RTTIME, (soft, hard))
    except (ValueError, OSError, AttributeError):  # not the main thread; no RLIMIT_RTTIME here
        return None
    return ms


def leave_loop() -> int:
    """Put every real-time thread of this process back to normal scheduling; how many there were.

    Called when the loop ends (the shutdown work that follows must not hold a CPU at real-time
    priority) and by the RT budget's SIGXCPU handler. Idempotent.
    """
    n = 0
    for tid, _ in _threads():
        try:
            if os.sched_getscheduler(tid) in (os.SCHED_FIFO, os.SCHED_RR):
                os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
                n += 1
        except OSError:  # the thread has ended
            pass
    return n


def apply(cfg: RtConfig, *, warn=None) -> Granted:
    """Apply ``cfg`` to this process (the calling thread is the loop's); return what was granted.

    Never raises for a refused setting: each refusal is listed in ``Granted.missing`` and
    reported in one line through ``warn`` (default: stderr).
    """
    g = Granted(requested=cfg.enabled)
    if not cfg.enabled:
        return g
    libc = _libc()
    if libc.prctl(_PR_SET_TIMERSLACK, ctypes.c_ulong(cfg.timer_slack_ns), 0, 0, 0) == 0:
        g.timer_slack_ns = cfg.timer_slack_ns
    else:
        g.missing.append(f"timer slack ({os.strerror(ctypes.get_errno())})")
    _single_thread_blas(g)  # before any thread runs at real time: no FIFO thread may spin for a normal one
    threads = _loop_threads(cfg.priority)
    if cfg.cpus:
        try:
            for tid, _, _ in threads:
                os.sched_setaffinity(tid, cfg.cpus)
            g.cpus = sorted(cfg.cpus)
        except OSError as exc:
            g.missing.append(f"CPU pinning to {list(cfg.cpus)} ({exc.strerror})")
    if cfg.lock_memory:
        _lock_memory(libc, g)
    if cfg.priority == 0:
        _set_nice(OFF_LOOP_NICE, g)
    else:
        _set_fifo(cfg.priority, threads, g)
    if g.fifo_priority is not None:
        g.rt_budget_ms = _arm_rt_budget(RT_BUDGET_MS)
    if g.missing:
        line = (f"warning: dem_ros real time: running without {', '.join(g.missing)}; {HOW_TO_GRANT}")
        (warn or (lambda s: (sys.stderr.write(s + "\n"), sys.stderr.flush())))(line)
    return g


def enter_loop(cfg: RtConfig | None = None, *, warn=None, report: bool = True) -> Granted:
    """Call once, on the loop's thread, after set-up and right before spinning.

    Collects and freezes what set-up allocated, disables automatic garbage collection, then
    applies the real-time settings (``cfg``, default: from the environment). Returns (and
    remembers, see :func:`granted`) what was granted; with ``report``, also prints it on
    stdout as one ``REALTIME {json}`` line (what ``dem-ros bench loop`` reports as ``rt``).

    Raises:
        RtConfigError: a ``DEM_ROS_RT*`` variable has a bad value.
    """
    global _GRANTED, _MONITOR
    cfg = config_from_env() if cfg is None else cfg
    if _MONITOR is None:
        _MONITOR = StallMonitor(cfg.stall_ms)
        atexit.register(_MONITOR.report)
    gc.collect()
    gc.freeze()
    if cfg.enabled:
        gc.disable()
    g = apply(cfg, warn=warn)
    g.gc_frozen = True
    _GRANTED = g
    if report:
        sys.stdout.write(REPORT_PREFIX + json.dumps(g.as_dict()) + "\n")
        sys.stdout.flush()
    return g


def loop_monitor() -> StallMonitor | None:
    """The :class:`StallMonitor` of this process's loop, if the calling thread is the loop's
    (the one that called :func:`enter_loop`); else None."""
    m = _MONITOR
    return m if m is not None and m.tid == threading.get_native_id() else None


def _read_int(path: str) -> int | None:
    try:
        with open(path) as f:
            return int(f.read().strip())
    except (OSError, ValueError):
        return None


class StallMonitor:
    """The loop thread's stalls, and where the kernel says their time went (see the module docstring).

    Bound to the thread that creates it. The executor calls :meth:`round` once per dispatch
    round with the time the round was due (its timer deadline, or when its data arrived) and
    the time it ended (ns, ``time.monotonic_ns``). That costs a comparison and a read of the
    thread's CPU clock (< 1 us); every :data:`SNAPSHOT_NS` the monitor also reads the thread's
    ``schedstat`` (a few us) and every 10th time ``/proc/stat`` (steal). Times in the reports are ms.

    ``running`` is the thread's CPU time since the end of the previous round (exact);
    ``runnable`` and ``steal`` also cover the stretch since the last snapshot (< ``SNAPSHOT_NS``
    and 10 x that), in which a healthy loop waits for a CPU ~0 % of the time.
    """

    SNAPSHOT_NS = 20_000_000
    CAUSES = ("running", "runnable", "stolen", "blocked")

    def __init__(self, stall_ms: float = 5.0, *, write: Any = None) -> None:
        self.stall_ns = int(stall_ms * 1e6)
        self.tid = threading.get_native_id()
        self._write = write or (lambda s: (sys.stderr.write(s + "\n"), sys.stderr.flush()))
        try:  # /proc/thread-self resolves now, to the calling thread
            self._fd: int | None = os.open("/proc/thread-self/schedstat", os.O_RDONLY)
        except OSError:  # no schedstat (CONFIG_SCHED_INFO off): stalls are still timed
            self._fd = None
        self._tick_ms = 1000.0 / (os.sysconf("SC_CLK_TCK") or 100)
        self.rounds = 0
        self._snaps = 0
        self._cpu = time.thread_time_ns()  # the thread's CPU time at the end of the last round
        self.stalls = 0
        self.by_cause = {c: {"n": 0, "total_ms": 0.0, "max_ms": 0.0} for c in self.CAUSES}
        self.longest: dict[str, Any] | None = None
        self.steal_ms = 0.0
        self.lines_dropped = 0
        self._line_second = -1
        self._lines = 0
        now = time.monotonic_ns()
        self._snap_at, self._snap = now, self._sched()
        self._steal_at, self._steal = now, self._steal_now()

    def _sched(self) -> tuple[int, int]:
        """(time on a CPU, time runnable waiting for one) of the loop's thread so far (ns)."""
        if self._fd is None:
            return 0, 0
        try:
            run, wait = os.pread(self._fd, 64, 0).split()[:2]
            return int(run), int(wait)
        except (OSError, ValueError):
            return 0, 0

    def _steal_now(self) -> float:
        """CPU time the hypervisor has stolen from this VM so far, all CPUs (ms; 10 ms resolution)."""
        try:
            with open("/proc/stat", "rb") as f:
                v = f.readline().split()
            return int(v[8]) * self._tick_ms if len(v) > 8 else 0.0
        except (OSError, ValueError):
            return 0.0

    def round(self, due_ns: int, end_ns: int) -> None:
        """One dispatch round that was due at ``due_ns`` ended at ``end_ns`` (ns)."""
        self.rounds += 1
        cpu, self._cpu = self._cpu, time.thread_time_ns()
        if end_ns - due_ns > self.stall_ns:
            self._stall(end_ns - due_ns, end_ns, (self._cpu - cpu) / 1e6)
        elif end_ns - self._snap_at >= self.SNAPSHOT_NS:
            self._snap_at, self._snap = end_ns, self._sched()
            self._snaps += 1
            if self._snaps % 10 == 0:  # /proc/stat every 0.2 s: the steal before a stall
                self._steal_at, self._steal = end_ns, self._steal_now()

    def _stall(self, length_ns: int, end_ns: int, running: float) -> None:
        wait = self._sched()[1]
        steal = self._steal_now()
        ms = length_ns / 1e6
        runnable = (wait - self._snap[1]) / 1e6
        blocked = max(0.0, ms - running - runnable)
        parts = {"running": running, "runnable": runnable, "blocked": blocked}
        cause = max(parts, key=parts.__getitem__) if self._fd is not None else "blocked"
        stolen = steal - self._steal
        if cause == "blocked" and stolen >= 0.5 * blocked:
            cause = "stolen"
        e = {"t_s": round(end_ns / 1e9, 3), "ms": round(ms, 2), "cause": cause,
             **{f"{k}_ms": round(v, 2) for k, v in parts.items()},
             "steal_ms": round(stolen, 1), "steal_window_ms": round((end_ns - self._steal_at) / 1e6, 1)}
        self.stalls += 1
        self.steal_ms += stolen
        c = self.by_cause[cause]
        c["n"] += 1
        c["total_ms"] = round(c["total_ms"] + ms, 2)
        c["max_ms"] = max(c["max_ms"], round(ms, 2))
        if self.longest is None or ms > self.longest["ms"]:
            self.longest = e
        second = end_ns // 1_000_000_000
        if second != self._line_second:
            self._line_second, self._lines = second, 0
        if self._lines < STALL_LINES_PER_S:
            self._lines += 1
            self._write("STALL " + json.dumps(e))
        else:
            self.lines_dropped += 1
        now = time.monotonic_ns()  # the next stall's figures start here
        self._snap_at, self._snap = now, self._sched()
        self._steal_at, self._steal = now, self._steal_now()

    def summary(self) -> dict[str, Any]:
        """Stalls so far: count, per cause (n, total and longest ms), the longest one, the steal
        seen across them, and the kernel's RT throttling settings."""
        return {"threshold_ms": self.stall_ns / 1e6, "rounds": self.rounds, "stalls": self.stalls,
                "by_cause": self.by_cause, "longest": self.longest, "steal_ms": round(self.steal_ms, 1),
                "sched_rt_runtime_us": _read_int("/proc/sys/kernel/sched_rt_runtime_us"),
                "sched_rt_period_us": _read_int("/proc/sys/kernel/sched_rt_period_us"),
                "lines_dropped": self.lines_dropped}

    def report(self) -> None:
        """Print :meth:`summary` as one ``STALLS {json}`` line on stdout (at exit)."""
        if self.rounds:
            with contextlib.suppress(Exception):  # at exit: stdout may be gone
                sys.stdout.write(STALLS_PREFIX + json.dumps(self.summary()) + "\n")
                sys.stdout.flush()


#: kernel threads of the unbound workqueue: the tty layer pushes every byte a serial port or a pty
#: receives to its reader from one of them (``tty_flip_buffer_push`` -> ``system_unbound_wq``)
TTY_WORKERS_PREFIX = "kworker/u"


@contextlib.contextmanager
def tty_workers_fifo(priority: int) -> Iterator[list[int]]:
    """Run the unbound workqueue's kernel workers at SCHED_FIFO ``priority`` meanwhile (root only).

    Why: a byte written to a serial port or a pty reaches the reading process only after a
    kernel worker (``kworker/u*``, normal priority) has pushed it through the tty layer. On a
    loaded machine that worker waits behind every busy normal-priority process and every
    real-time thread, and the serial link's round trip grows from ~0.2 ms to several ms (see
    ``docs/hardware-link.md``, "Serial latency"). UDP does not take this detour.

    This changes kernel threads that the whole machine shares, so it is never done implicitly:
    ``linkbench --tty-workers-fifo N`` uses it. Workers that exist on entry get FIFO ``priority``
    and their previous policy back on exit; workers the kernel starts meanwhile are not touched.
    Yields the thread ids changed (empty where not permitted).
    """
    changed: list[tuple[int, int, int]] = []
    try:
        for pid in os.listdir("/proc"):
            if not pid.isdigit():
                continue
            try:
                with open(f"/proc/{pid}/comm") as f:
                    if not f.read().startswith(TTY_WORKERS_PREFIX):
                        continue
                tid = int(pid)
                policy, prio = os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
                changed.append((tid, policy, prio))
            except OSError:  # gone, or not permitted
                continue
        yield [t for t, _, _ in changed]
    finally:
        for tid, policy, prio in changed:
            with contextlib.suppress(OSError):
                os.sched_setscheduler(tid, policy, os.sched_param(prio))


def main(argv: list[str] | None = None) -> int:
    """``python -m dem_ros.realtime --tty-workers-fifo N -- COMMAND ...``: run COMMAND with the
    kernel's tty workers at SCHED_FIFO N (:func:`tty_workers_fifo`), restored when it ends; e.g.
    ``... -- dem-ros launch --hardware rig-serial --compose --scenario S1``."""
    import argparse
    import subprocess

    p = argparse.ArgumentParser(prog="python -m dem_ros.realtime", description=main.__doc__.splitlines()[0]
                                if main.__doc__ else None)
    p.add_argument("--tty-workers-fifo", type=int, required=True, metavar="N", help="SCHED_FIFO priority 1..99")
    p.add_argument("command", nargs=argparse.REMAINDER, help="-- COMMAND [ARGS...]")
    a = p.parse_args(argv)
    cmd = a.command[1:] if a.command[:1] == ["--"] else a.command
    if not cmd or not 1 <= a.tty_workers_fifo <= 99:
        p.error("give --tty-workers-fifo 1..99 and a command after --")
    with tty_workers_fifo(a.tty_workers_fifo) as changed:
        print(f"tty workers: {len(changed)} kworker/u thread(s) at SCHED_FIFO {a.tty_workers_fifo}" if changed
              else "tty workers: not permitted (needs root / CAP_SYS_NICE); running the command anyway",
              file=sys.stderr)
        try:
            return subprocess.call(cmd)
        except OSError as exc:
            print(f"error: {cmd[0]}: {exc.strerror}", file=sys.stderr)
            return 127


if __name__ == "__main__":
    sys.exit(main())

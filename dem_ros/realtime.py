"""Real-time process settings for the 1 kHz loop, as ros2_control and realtime_tools apply them.

What each setting is for (a Python loop on a stock, non-RT Linux kernel):

* **SCHED_FIFO** (``priority``, 1..99; ros2_control's controller manager uses 50): the loop's
  thread preempts every normal (SCHED_OTHER) thread on its core the moment its timer fires,
  instead of waiting for the fair scheduler to give it a slice. On a loaded machine this is
  the difference between wake-ups > 1 ms late in ~5-10 % of periods and in < 1 % (measured
  here, see the README's "Speed" section). Applied to the loop's thread (the one that calls
  :func:`enter_loop`) and to the DDS threads that receive and deliver samples (cyclonedds
  ``recv*`` / ``dq.*``), which sit on the same path in a process-per-node graph; its
  timed-event and collector threads (``tev``, ``gc``: heartbeats, acknowledgements, discovery)
  get ``priority - 1``, and so do the process's other Python threads (the bag writer): they share the GIL
  with the loop, and a helper thread preempted by a busy neighbour while it holds the GIL
  would keep the loop waiting for it (priority inversion); they sleep between their bursts.
* **mlockall** (``lock_memory``; ``MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT``): no page the process
  has touched is paged out (or reclaimed and faulted in again) while the loop runs.
  ``MCL_ONFAULT`` (Linux >= 4.4) locks pages as they are used instead of populating every
  mapping at once: without it a composed graph (numba, LLVM, cyclonedds, thread stacks) locks
  ~0.9 GB, with it about what it uses (see the README's "Speed" section).
* **timer slack** (``timer_slack_ns``, 1 us): a normal thread's sleeps may end up to 50 us
  late (the kernel's default slack, used to batch wake-ups); the loop sleeps to absolute
  deadlines and wants none of it. Needs no privilege.
* **CPU pinning** (``cpus``, optional): keep the loop's threads on chosen cores.
* **garbage collector**: everything allocated during set-up (numba, the middleware, the nodes)
  is collected once and frozen (:func:`gc.freeze`), then automatic collection is disabled: a
  full collection of a Python process this size takes ~100 ms, which a 1 kHz loop cannot
  absorb. Reference counting still frees everything the loop allocates; the loop makes no
  reference cycles (``tests/test_realtime.py`` checks that a composed run leaves no cyclic
  garbage), so nothing accumulates.

The loop never spins: the executor sleeps until its next deadline or sample (a FIFO thread that
spins would starve every normal thread of its core; the kernel's RT throttling,
``sched_rt_runtime_us``, would then cut in).

Settings come from the environment, so that one switch reaches every node process and the
container alike (``dem-ros launch/bench --rt/--no-rt`` set it for their children):

==========================  =============  ============================================
variable                    default        meaning
==========================  =============  ============================================
``DEM_ROS_RT``              ``1``          ``0``: leave the process as it is
``DEM_ROS_RT_PRIORITY``     ``50``         SCHED_FIFO priority (1..99)
``DEM_ROS_RT_LOCK_MEMORY``  ``1``          ``0``: no mlockall
``DEM_ROS_RT_CPUS``         (none)         e.g. ``1`` or ``0,1``: pin the loop's threads
==========================  =============  ============================================

Where a setting is not permitted (no ``CAP_SYS_NICE`` and ``RLIMIT_RTPRIO`` 0, a small
``RLIMIT_MEMLOCK``) the process prints ONE warning line that names what is missing and how to
grant it, and runs on without it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import gc
import json
import os
import resource
import sys
import threading
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field

from .core.params import ConfigError

__all__ = ["ENV", "REPORT_PREFIX", "Granted", "RtConfig", "RtConfigError", "apply", "config_from_env", "enter_loop", "granted"]

#: environment variables read by :func:`config_from_env`
ENV = {"enabled": "DEM_ROS_RT", "priority": "DEM_ROS_RT_PRIORITY", "lock_memory": "DEM_ROS_RT_LOCK_MEMORY",
       "cpus": "DEM_ROS_RT_CPUS"}

_PR_SET_TIMERSLACK = 29
_MCL_CURRENT, _MCL_FUTURE, _MCL_ONFAULT = 1, 2, 4
#: cyclonedds threads on the sample path: receive (``recv``, ``recvUC``, ``recvMC``) and delivery (``dq.*``)
_DDS_PATH_THREADS = ("recv", "dq.")
#: cyclonedds's timed events (heartbeats, acknowledgements, discovery) and its garbage collector: starved
#: at normal priority on a loaded machine, remote peers (``dem-ros param``) cannot find the node in time
_DDS_SERVICE_THREADS = ("tev", "gc")
#: start of the line that reports what a process was granted (JSON follows; the launcher reads it)
REPORT_PREFIX = "REALTIME "
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

    def __post_init__(self) -> None:
        if not 1 <= self.priority <= 99:
            raise RtConfigError(f"SCHED_FIFO priority must be 1..99, got {self.priority}")
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
        memory_locked: mlockall succeeded.
        timer_slack_ns: the loop thread's timer slack (ns), or None if not set.
        cpus: cores the loop's threads are pinned to, or None.
        gc_frozen: objects moved to the permanent generation; automatic collection disabled.
        missing: what was asked for and refused, one short phrase each.
    """

    requested: bool = False
    fifo_priority: int | None = None
    fifo_threads: list[str] = field(default_factory=list)
    memory_locked: bool = False
    timer_slack_ns: int | None = None
    cpus: list[int] | None = None
    gc_frozen: bool = False
    missing: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return asdict(self)


_GRANTED: Granted | None = None


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
        raise RtConfigError(f"{ENV['priority']}={p!r}: not an integer (1..99)") from None
    c = env.get(ENV["cpus"], "").strip()
    try:
        cpus = tuple(int(x) for x in c.split(",") if x.strip()) if c else ()
    except ValueError:
        raise RtConfigError(f"{ENV['cpus']}={c!r}: use core numbers separated by commas, e.g. 1 or 0,1") from None
    try:
        return RtConfig(enabled=enabled, priority=priority, lock_memory=lock, cpus=cpus)
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
    out += [(t, n, max(1, priority - 1)) for t, n in os_threads if n in _DDS_SERVICE_THREADS]
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
    _set_fifo(cfg.priority, threads, g)
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
    global _GRANTED
    cfg = config_from_env() if cfg is None else cfg
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

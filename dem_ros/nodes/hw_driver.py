"""``hw_driver``: the DEM rig's I/O board behind the device link, in place of ``plant_sim``.

Honours plant_sim's topic contract exactly (``/dem/measurement``, ``/dem/applied_voltage``
out, ``/dem/command`` in, ``/diagnostics``; no truth topic: a rig has none), so the
estimator and controller cannot tell. Everything but the I/O is
:class:`dem_ros.hardware.driver.HwDriver`; this node only moves bytes and messages.

The board is the clock. A reader thread waits on the link and, for every sensor frame,
publishes ``/dem/applied_voltage`` then ``/dem/measurement`` (gaps [m], currents [A]; no
rates) stamped with board time mapped to ROS time; ``/dem/command`` goes to the board
as it arrives (one lock serialises the driver between the two threads).

The experiment's t = 0 is ``preroll`` s after the driver became active (its first
forwarded command): frames before it carry ``frame_id = dem/preroll``. After ``duration``
s the node stops publishing, lands the plate (disarm: LAND) and exits once the board has
landed it. The loop status tells that end-of-run landing (``landing_reason`` "end of the
run: ...", ``failed`` False) from a failure (``failed`` True, ``fail_time_s`` and ``fault``:
when and why the driver first faulted during the experiment; ``landing_reason``: why the
board landed during it).

Stopped from outside (Ctrl-C / SIGTERM, e.g. the launcher at the end of a run): the driver
lands the plate *before* it lets go of the link: it disarms (LAND in reply to every sensor
frame) until the board reports LAND or LANDED, for at most ``STOP_LANDING_S``; only then does
the process exit. A driver that dies without that still lands the plate, by the board's own
link watchdog (hold, then LAND), which the run then reports as a watchdog landing. The reader
thread lives until then, on every transport: it uses nothing of the shut-down node but its
publishers, and a frame whose handling raises (a publisher the transport destroyed) is skipped,
not the end of the thread. While the node is up, a sample the transport fails to publish is
counted (``publish_errors`` on ``/diagnostics``: WARN) and the next one is published as usual.

State and link statistics: ``/dem/hw/state`` (DiagnosticStatus, latched, 10 Hz and on
every change) and ``/diagnostics`` (1 Hz). Requests: the services ``~/arm``, ``~/disarm``,
``~/estop``, ``~/status`` (std_srvs/Trigger), the topic ``/dem/hw/request`` (std_msgs/String:
``arm``, ``disarm``, ``estop [reason]``, ``clear``; what ``dem-ros hw``, :mod:`dem_ros.tools.hw`, sends) and
``/dem/hw/estop`` (any message: e-stop, its data the reason); answers and state changes go
to ``/dem/hw/state``. As the plant node of the graph, the driver also watches the recorder
(:class:`~dem_ros.nodes.recording_watch.RecordingWatch`, status ``hw_driver: recording``).

Managed node. The node is a ROS 2 lifecycle node on every transport (``~/get_state``, ``~/change_state``, ...,
``~/transition_event``: :meth:`dem_ros.transport.api.Node.serve_lifecycle`), its state machine
(:class:`~dem_ros.transport.lifecycle.LifecycleMachine`) mapped onto the driver's, and moved on the executor's
thread only (a transition that waits on the board is finished by :meth:`HwDriverNode.follow_driver`, every tick):

* configure: open the link (closed only by cleanup) and handshake; done once the board answered the hello. At
  start the node configures itself (as long as it takes) and, with ``auto_arm``, activates once configured;
* activate: arm (the board lifts off once the controller's commands come in time); ``active`` covers the
  driver's ARMED and ACTIVE;
* deactivate: disarm, the board lands the plate; done when it reports LANDED (or OFF: it never lifted off). Not
  confirmed within ``transition_timeout``: an error (a failed deactivate would return to active);
* cleanup: close the link; shutdown: land as deactivate, then finalized: the node ends as at the end of a run;
* errorprocessing (an error in a transition, or a driver fault while active or during a transition, as
  ros2_control's hardware components treat ``read()``/``write()`` errors): the plate is landed (the latched
  fault sends LAND, else the driver disarms), then unconfigured with the link open (the board's reports and
  the run's samples go on). A fault while inactive changes nothing but the driver (nothing is commanded there).

``dem-ros hw`` goes through it: ``arm`` is an activate (configure first when unconfigured; while active, a re-arm;
during a landing, the landing called off: the deactivate fails back to active), ``disarm`` / ``clear`` a
deactivate while active, else the driver's disarm (a latched fault cleared); the end-of-run disarm is followed as
a deactivate. The e-stop stays its own topic and service; its fault is reflected as above.
"""

from __future__ import annotations

import contextlib
import os
import select
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from .. import contract
from ..hardware.channel import Channel, ChannelError, open_channel
from ..hardware.driver import HARDWARE_FAULTS, DriverState, HwDriver, Sample
from ..hardware.link import HELLO_REQUEST, Mode, Status, encode
from ..realtime import config_from_env
from ..runstate import announce
from ..transport import Node, run_node
from ..transport.lifecycle import DEFERRED, STATES, CallbackAnswer, CallbackResult, LifecycleMachine, TransitionEvent
from .common import OK, WARN, CommandSource, Diagnostics, LatencyStats, diag_array, joint_state, stamp_ns, worth_logging
from .recording_watch import RecordingWatch

__all__ = ["HwDriverNode", "main"]

RING = 256  # receive times kept by sample number (latency: sample received -> command sent)
#: link and board counters whose growth makes the next /diagnostics report a WARN
WARN_ON = ("lost", "duplicated", "reordered", "late", "corrupt", "hold_samples", "commands_dropped", "sensor_holds",
           "link_loss", "watchdog", "commands_foreign", "publish_errors", "reader_errors", "stalls")
#: board modes that are reported as a standing WARN (the board is landing or has landed the plate)
BOARD_DOWN = (Mode.LAND, Mode.LANDED, Mode.FAULT)
STOP_LANDING_S = 1.0  # s: stopped from outside, the driver waits at most this for the board to take up LAND
#: frames the link reader handles in a row before it lets go of the lock and sleeps (a backlog: see _read_loop)
DRAIN_BATCH = 16
DRAIN_PAUSE_S = 1e-4


class HwDriverNode:
    def __init__(self, node: Node):
        self.node = node
        self.cfg = node.declare_parameters("hw_driver", self.on_change)
        c = self.cfg
        self.drv = HwDriver(c)
        self.lock = threading.Lock()
        self.ch: Channel | None = None
        self.stop = threading.Event()
        self.reader = threading.Thread(target=self._read_loop, name="hw_driver-link", daemon=True)
        self.JS = node.msg("sensor_msgs/msg/JointState")
        self.D = (node.msg("diagnostic_msgs/msg/DiagnosticArray"), node.msg("diagnostic_msgs/msg/DiagnosticStatus"),
                  node.msg("diagnostic_msgs/msg/KeyValue"))
        # /diagnostics (hw_driver: loop) through the one reporter: 1 Hz (status()), WARN when a link counter
        # grew, a latched ERROR while the driver is in FAULT (published at once)
        self.diag = Diagnostics(node, contract.HW_LOOP_STATUS, warn_on=WARN_ON, values=self.stats, timer=False)
        # the 1 kHz topics' frequency and stamp statuses; published from the link's reader thread, which outlives
        # the node: timed by the system clock
        self.pub_meas = self.diag.diagnosed(contract.MEASUREMENT, clock=time.time_ns)
        self.pub_applied = self.diag.diagnosed(contract.APPLIED, clock=time.time_ns)
        self.pub_state = node.publisher(contract.HW_STATE)
        # the command source lock: /dem/command only from command_source's writers (nodes/common.CommandSource)
        self.source = CommandSource(node, c["command_source"], self.on_command)
        node.subscribe(contract.HW_REQUEST, self.on_request)
        node.subscribe(contract.HW_ESTOP, self.on_estop)
        for verb in ("arm", "disarm", "estop", "status"):  # ~/arm ... (std_srvs/Trigger), as the request topic
            node.service(verb, "std_srvs/srv/Trigger", self._service(verb))
        self.n_pre = round(c["preroll"] / c["dt"])
        self.n_end = round(c["duration"] / c["dt"]) if c["duration"] > 0 else 0
        self.epoch_seq: int | None = None  # first sample of the experiment (t = 0)
        self.epoch_ns: int | None = None
        self.finished = False
        self.ended = False  # finish() ran: the node is ending
        self.t_finish = 0.0  # when the run ended and the landing began (monotonic s)
        self.failed = ""  # the first fault during the experiment
        self.fail_t: float | None = None  # when it came [s on the experiment clock]
        self.board_down: tuple[float, str] | None = None  # (t [s], why) the board landed during the experiment
        self.end_landed_s: float | None = None  # the end-of-run landing took this long [s] (None: not yet landed)
        self.board_run_samples = 0  # experiment samples at which the board was in RUN (or HOLD): the verdict's fact
        self.closing = False  # the node is shut down: no more publishing, the link lands the plate (close())
        self.stop_landed = False  # stopped from outside: LAND asked at the first frame after the node's shutdown
        self.publish_errors = 0  # samples the transport failed to publish while the node was up (not lost for good)
        self.reader_errors = 0  # frames whose handling raised in the reader thread (it carries on with the next)
        self.rx_ns = np.zeros(RING, dtype=np.int64)  # steady receive time of each sample, by seq
        self.lat = LatencyStats()
        self.t_boot = time.monotonic()
        self.cpu0: float | None = None
        self.last_state = (DriverState.INACTIVE, "", Mode.OFF)
        self.board_announced = False
        self.answer = ""
        # the managed node (module docstring, "Managed node"): the machine moves on the executor's thread only
        self.machine = LifecycleMachine({"on_configure": self.on_configure, "on_activate": self.on_activate,
                                         "on_deactivate": self.on_deactivate, "on_cleanup": self.on_cleanup,
                                         "on_shutdown": self.on_shutdown, "on_error": self.on_error},
                                        now_ns=node.now_ns, on_event=self._on_transition)
        node.serve_lifecycle(self.machine)
        #: what a DEFERRED transition waits for ("hello": the board's answer, "landed": the board down) and until
        #: when (monotonic s; None: as long as it takes); :meth:`follow_driver` finishes it
        self.waiting: tuple[str, float | None] | None = None
        self.activate_when_configured = False  # an arm (auto_arm, dem-ros hw arm) waits for the handshake
        # the reader thread must get the interpreter within the sample period, not after the default 5 ms
        sys.setswitchinterval(1e-4)
        try:
            self._open_link()
        except ChannelError as exc:
            raise SystemExit(f"error: hw_driver: {exc}") from None
        self.starting = True  # the start-up configure waits for the board as long as it takes
        if c["auto_arm"]:
            self.drv.arm()  # at once, as always: nothing is forwarded before the board streams
            self.activate_when_configured = True
        self.machine.request("configure")
        self.starting = False
        node.timer(0.1, self.tick)
        node.timer(1.0, self.status)
        # /diagnostics "hw_driver: recording": the recorder's liveness (the graph's plant node watches it)
        self.recording = RecordingWatch(node, contract.HW_RECORDING_STATUS, self.experiment_t)
        node.logger.info(f"link {c['url']}; ready")

    # -- the managed node: transition callbacks (executor thread) --------------------------------
    def _open_link(self) -> None:
        """Open the link and start its reader thread (ChannelError when it cannot be opened)."""
        self.ch = open_channel(self.cfg["url"], "pc")
        self.stop = threading.Event()
        self.reader = threading.Thread(target=self._read_loop, name="hw_driver-link", daemon=True)
        self.reader.start()

    def _close_link(self) -> None:
        self.stop.set()
        if self.reader.is_alive():
            self.reader.join(timeout=1.0)
        if self.ch is not None:
            self.ch.close()
            self.ch = None

    def _board_down(self) -> bool:
        """Nothing levitates under the board (it reports OFF or LANDED)."""
        return Mode(self.drv.board_mode) in (Mode.OFF, Mode.LANDED)

    def _wait_for(self, what: str) -> CallbackAnswer:
        self.waiting = (what, None if self.starting else time.monotonic() + self.cfg["transition_timeout"])
        return DEFERRED

    def on_configure(self, previous: int) -> CallbackAnswer:
        """Open the link (when cleanup closed it: a new link session, a new driver) and handshake: done once the
        board has answered the hello on this link."""
        if self.ch is None:
            with self.lock:
                self.drv = HwDriver(self.cfg)  # counters, clock map and handshake start afresh with the link
            try:
                self._open_link()
            except ChannelError as exc:
                self.node.logger.error(f"configure: {exc}")
                return CallbackResult.FAILURE
        with self.lock:
            if self.drv.hello is not None:
                return CallbackResult.SUCCESS
        return self._wait_for("hello")  # tick() asks until the board answers

    def on_activate(self, previous: int) -> CallbackAnswer:
        """Arm (clears a latched fault): the board lifts off once the controller's commands come in time."""
        with self.lock:
            if self.drv.state not in (DriverState.ARMED, DriverState.ACTIVE):  # armed already: auto_arm, an early arm
                self.answer = self.drv.arm()
        return CallbackResult.SUCCESS

    def on_deactivate(self, previous: int) -> CallbackAnswer:
        """Disarm (the board is told to LAND); done once the board reports LANDED (or OFF: it never lifted off)."""
        with self.lock:
            if self.drv.state != DriverState.INACTIVE:  # (the end of the run disarmed it already)
                self.answer = self.drv.disarm()
            if self._board_down():
                return CallbackResult.SUCCESS
        return self._wait_for("landed")

    def on_cleanup(self, previous: int) -> CallbackAnswer:
        """Close the link (the board is down: inactive is reached only so)."""
        self._close_link()
        return CallbackResult.SUCCESS

    def on_shutdown(self, previous: int) -> CallbackAnswer:
        """Land as a deactivate does; finalized, the node ends as at the end of a run (close() lets go of the link)."""
        with self.lock:
            if self.drv.state != DriverState.INACTIVE:
                self.answer = self.drv.disarm()
            if self.ch is None or self._board_down():
                return CallbackResult.SUCCESS
        return self._wait_for("landed")

    def on_error(self, previous: int) -> CallbackAnswer:
        """Errorprocessing: the plate is landed (a latched fault sends LAND; otherwise the driver disarms); the
        link stays open, so the board's reports and the run's samples go on. On to unconfigured."""
        with self.lock:
            if self.drv.state != DriverState.FAULT:
                self.answer = self.drv.disarm()
            self.node.logger.warn(f"lifecycle error from {STATES[previous]}: landing the plate"
                                  + (f" ({self.drv.reason})" if self.drv.reason else ""))
        return CallbackResult.SUCCESS

    def _on_transition(self, e: TransitionEvent) -> None:
        self.node.logger.info(f"lifecycle: {STATES[e.start]} -> {STATES[e.goal]} ({e.transition_label})")
        if e.goal == 4 and not self.node.is_shutdown:  # finalized (shutdown): the node ends
            self.finish("shut down (lifecycle)")

    def follow_driver(self) -> None:
        """The managed node follows the driver (executor thread, every tick and after a request): a DEFERRED
        transition ends when what it waits for came (or its time is up); a fault while active is an error
        (errorprocessing, then unconfigured); a driver disarmed while active (the end of the run) a deactivate."""
        m = self.machine
        with self.lock:
            d, hello, down, board_fault = (self.drv.state, self.drv.hello, self._board_down(),
                                           Mode(self.drv.board_mode) == Mode.FAULT)
        if m.pending is not None and self.waiting is not None:
            what, deadline = self.waiting
            result: CallbackResult | None = None
            if what == "hello":
                if d == DriverState.FAULT:  # the board's hello disagrees with the driver (rate, command delay)
                    result = CallbackResult.FAILURE
                elif hello is not None:
                    result = CallbackResult.SUCCESS
            elif d == DriverState.FAULT or board_fault:  # a fault during the landing
                result = CallbackResult.ERROR
            elif down:
                result = CallbackResult.SUCCESS
            if result is None and deadline is not None and time.monotonic() > deadline:
                awaited = "hello from the board" if what == "hello" else "LANDED"
                self.node.logger.error(f"{STATES[m.state]}: no {awaited} within transition_timeout ="
                                       f" {self.cfg['transition_timeout']:g} s")
                # a landing not confirmed is an error: a failed deactivate would claim a levitating plate again
                result = CallbackResult.FAILURE if what == "hello" else CallbackResult.ERROR
            if result is None:
                return
            self.waiting = None
            m.finish(result)
            if what == "hello":
                self._after_configure(result == CallbackResult.SUCCESS)
        elif m.state == 3 and d == DriverState.FAULT:
            m.error()
        elif m.state == 3 and d == DriverState.INACTIVE:
            m.request("deactivate")

    def _after_configure(self, configured: bool) -> None:
        """An arm that waited for the handshake: activate now, or (configure failed) drop it."""
        wanted, self.activate_when_configured = self.activate_when_configured, False
        if configured and wanted and self.machine.state == 2:
            self.machine.request("activate")
        elif not configured:
            with self.lock:
                if self.drv.state in (DriverState.ARMED, DriverState.ACTIVE):
                    self.answer = self.drv.disarm()

    def arm(self) -> None:
        """``dem-ros hw arm`` (request topic, ``~/arm``): an activate (configuring first when unconfigured); while
        active, the driver's arm (a re-arm after the board landed on its own); during a landing (deactivating),
        the landing called off: the deactivate fails (back to active) and the driver is armed again."""
        m = self.machine
        if m.pending == 4:
            self.waiting = None
            with self.lock:
                self.answer = self.drv.arm()
            m.finish(CallbackResult.FAILURE)
            return
        if m.state == 1:
            m.request("configure")
            if m.state == 2:
                self._after_configure(True)
        if m.pending == 1:  # the board has not answered yet: armed at once (as auto_arm), active once it has
            with self.lock:
                self.answer = self.drv.arm()
            self.activate_when_configured = True
        elif m.state == 2:
            m.request("activate")
        elif m.state == 3:
            with self.lock:
                self.answer = self.drv.arm()
        else:
            self.answer = f"refused: the managed node is {m.label}"

    def disarm(self) -> None:
        """``dem-ros hw disarm`` / ``clear``: a deactivate while active (the landing); otherwise the driver's disarm
        (clears a latched fault; drops an arm waiting for the handshake)."""
        if self.machine.state == 3:
            self.machine.request("deactivate")
            return
        self.activate_when_configured = False
        with self.lock:
            self.answer = self.drv.disarm()

    # -- parameters / requests -----------------------------------------------------------------
    def on_change(self, values) -> str | None:
        changed = [k for k in values if values[k] != self.cfg[k]]
        fixed = {"url", "dt", "command_delay", "preroll", "duration", "clock_sync_frames", "gap_table"}
        for key in changed:
            if key in fixed or key.startswith(("gap1_", "gap2_", "current")) or key == "voltage_input":
                return f"{key} cannot change while the link is open"
        with self.lock:
            self.cfg = dict(values)
            self.drv.cfg.update(values)  # limits and timeouts act from the next sample
        return None

    def on_request(self, msg) -> None:
        words = str(msg.data).strip().split(None, 1)
        verb = words[0].lower() if words else ""
        if verb == "arm":
            self.arm()
        elif verb in ("disarm", "clear"):
            self.disarm()
        elif verb == "estop":
            with self.lock:
                self.answer = self.drv.estop(words[1] if len(words) > 1 else "requested on /dem/hw/request")
        elif verb == "status":
            self.answer = "status"
        else:
            self.answer = f"unknown request {msg.data!r}: arm, disarm, clear, estop [reason], status"
        self.follow_driver()
        self.node.logger.info(f"request {msg.data!r}: {self.answer}")
        self.publish_state(force=True)

    def _service(self, verb: str) -> Callable[[Any, Any], Any]:
        """The service callback (request, response) -> response of ``verb``."""
        return lambda req, res: self.on_service(verb, res)

    def on_service(self, verb: str, res):
        if verb == "arm":
            self.arm()
        elif verb == "disarm":
            self.disarm()
        elif verb == "estop":
            with self.lock:
                self.answer = self.drv.estop("~/estop service")
        self.follow_driver()
        with self.lock:
            state = self.drv.state
        res.success = state != DriverState.FAULT or verb == "estop"
        res.message = f"{state.name.lower()}: {self.answer if verb != 'status' else self.drv.reason or 'no fault'}"
        self.node.logger.info(f"service {verb}: {res.message}")
        self.publish_state(force=True)
        return res

    def on_estop(self, msg) -> None:
        with self.lock:
            self.answer = self.drv.estop(str(getattr(msg, "data", "")) or "e-stop topic")
        self.follow_driver()
        self.node.logger.warn(self.answer)
        self.publish_state(force=True)

    # -- the link ---------------------------------------------------------------------------------
    def _read_loop(self) -> None:
        """Reader thread: every received frame goes through the driver; samples are published at once."""
        rt = config_from_env()  # the link's thread is on the loop's path: the loop's priority (dem_ros.realtime)
        if rt.enabled:
            with contextlib.suppress(OSError):  # not permitted: enter_loop() reports it once for the process
                os.sched_setscheduler(threading.get_native_id(), os.SCHED_FIFO, os.sched_param(rt.priority))
        ch = self.ch  # this thread's link (cleanup closes it after stopping the thread)
        assert ch is not None
        poller = select.poll()
        poller.register(ch.fileno(), select.POLLIN)
        # This thread outlives the node: close() runs after the node was shut down and needs it to reply LAND
        # to every frame. So nothing of the node is used here but its publishers (guarded, _publish_sample):
        # the board-to-ROS clock map reads ROS time off the system clock, as every transport's now_ns() does
        # (the DDS node's is time.time_ns(); the rclpy node's clock is gone with its node after shutdown).
        # A backlog (frames queued while the process started or stalled) is drained DRAIN_BATCH frames at a
        # time, each batch followed by a real sleep: drained in one go it held the lock throughout, so the
        # executor could forward no command on a loaded host (the board never left OFF), and at SCHED_FIFO it
        # never slept: the RT budget (200 ms) put the process back to normal scheduling, where it fell further
        # behind.
        while not self.stop.is_set():
            ready = poller.poll(5)
            batch = 0
            with self.lock:
                while ready and batch < DRAIN_BATCH:
                    batch += 1
                    try:
                        data = ch.recv(0.0)
                    except ChannelError as exc:
                        self.drv.fault(f"link: {exc}")
                        break
                    if data is None:
                        break
                    try:
                        self._on_frame(ch, data)
                    except Exception as exc:  # never the end of the thread that lands the plate: count, go on
                        self.reader_errors += 1
                        if worth_logging(self.reader_errors):
                            self.node.logger.error(f"link reader: a frame raised {exc!r} ({self.reader_errors} so far);"
                                                   " carrying on with the next")
                if not ready and not poller.poll(0):  # silent, still (a stall after the wait is no silence)
                    self.drv.check(time.monotonic_ns())
            if batch >= DRAIN_BATCH:
                # the executor's turn for the lock (on_command), and a sleep for the RT budget
                time.sleep(DRAIN_PAUSE_S)

    def _on_frame(self, ch: Channel, data: bytes) -> None:
        """One received frame (the lock held): through the driver, its reply to the board, its sample out."""
        steady = time.monotonic_ns()
        if not self.stop_landed and self.node.is_shutdown:  # stopped: LAND now, not after the process's teardown
            self._land_on_stop()
        sample, reply = self.drv.on_bytes(data, time.time_ns(), steady)
        if reply is not None:
            ch.send(reply)
        if sample is not None:
            self.rx_ns[sample.seq % RING] = steady
            if not self.closing:
                self._publish_sample(sample)

    def _publish_sample(self, s: Sample) -> None:
        """Publish a sample; a failure never stops the reader. The node shut down under us (SIGINT): no more
        publishing (the link stays up until close() has landed the plate). Otherwise a transport error of this
        sample (a DDS write error, or any transport's own exception) is counted (``publish_errors`` on
        /diagnostics: WARN) and the next sample is published as usual."""
        try:
            self._publish(s)
        except Exception as exc:  # TransportError, or the transport's own (rclpy's on a destroyed publisher)
            if self.node.is_shutdown:
                self.closing = True
                return
            self.publish_errors += 1
            n = self.publish_errors
            if worth_logging(n):
                self.node.logger.warn(f"sample {s.seq} not published: {exc!r} ({n} so far); carrying on")

    def _publish(self, s: Sample) -> None:
        if self.finished:
            return
        if self.epoch_seq is None:
            frame = contract.FRAME_PREROLL
        elif s.seq - self.epoch_seq >= 0:
            frame = contract.FRAME
            if s.seq == self.epoch_seq:
                self.epoch_ns = s.stamp_ns
                self.cpu0 = time.process_time()
                announce("t0", "hw_driver", epoch_ns=s.stamp_ns)
            if self.n_end and s.seq - self.epoch_seq >= self.n_end:
                self.finished = True
                self.t_finish = time.monotonic()
                self.drv.disarm()  # the run is over: land (LAND in reply to the next sensor frame)
                self.node.logger.info(f"finished {self.cfg['duration']:g} s: landing")
                return
        else:
            frame = contract.FRAME_PREROLL
        if frame == contract.FRAME:
            self._watch_experiment(s)
            if s.mode in (Mode.RUN, Mode.HOLD):
                self.board_run_samples += 1  # the board ran the controller's commands at this sample
        JS = self.JS
        self.pub_applied.publish(joint_state(JS, s.stamp_ns, effort=s.applied, frame=frame))
        self.pub_meas.publish(joint_state(JS, s.stamp_ns, position=s.gap, effort=s.current, frame=frame))

    def _watch_experiment(self, s: Sample) -> None:
        """The first driver fault and the first board landing during the experiment (what the summary reports)."""
        assert self.epoch_seq is not None
        t = (s.seq - self.epoch_seq) * self.cfg["dt"]
        d = self.drv
        if d.state == DriverState.FAULT and not self.failed:
            self.failed, self.fail_t = d.reason or "fault", t
        if self.board_down is None and Mode(d.board_mode) in BOARD_DOWN:
            hw = s.status & HARDWARE_FAULTS
            why = d.reason or ("its link watchdog (no command)" if s.status & Status.LINK_TIMEOUT
                               else "it reports " + ", ".join(str(f.name) for f in Status if f & hw) if hw
                               else "its own trip")
            self.board_down = (t, f"board {Mode(d.board_mode).name} at t = {t:.3f} s: {why}")

    def on_command(self, msg) -> None:
        t = stamp_ns(msg)
        with self.lock:
            was = self.drv.state
            data = self.drv.command(t, msg.effort[:2], time.monotonic_ns())
            if data is None or self.ch is None:
                return
            self.ch.send(data)
            seq = self.drv.last_cmd_seq
            if seq is None:  # pragma: no cover - command() set it when it returned a frame
                return
            self.lat.add(time.monotonic_ns() - int(self.rx_ns[seq % RING]))
            if was == DriverState.ARMED and self.epoch_seq is None:
                self.epoch_seq = seq + 1 + self.n_pre  # the board applies it from sample seq + 1
                self.node.logger.info(f"active: levitating under the controller; t = 0 in {self.cfg['preroll']:g} s")

    # -- timers -------------------------------------------------------------------------------------
    def tick(self) -> None:
        """10 Hz: hello until the board answers; state on /dem/hw/state; faults to /diagnostics; the end of the run."""
        if self.drv.hello is None and self.ch is not None:
            self.ch.send(encode(HELLO_REQUEST))
        self.follow_driver()
        self.publish_state()
        self.report_faults()
        if self.finished and self.drv.board_mode in (Mode.OFF, Mode.LANDED) and self.end_landed_s is None:
            self.end_landed_s = time.monotonic() - self.t_finish
        if self.finished and (self.end_landed_s is not None or time.monotonic() - self.t_finish > 5.0):
            self.finish(f"finished {self.cfg['duration']:g} s")

    def report_faults(self) -> None:
        """The driver's latched fault is a latched ERROR on /diagnostics (at once); the board landing, a WARN."""
        d = self.drv
        if d.state == DriverState.FAULT:
            self.diag.fault(d.reason or "fault")
        elif self.diag.faulted is not None:
            self.diag.clear_fault()  # re-armed
        board = Mode(d.board_mode)
        if board in BOARD_DOWN:
            self.diag.set_condition(WARN, f"{d.state.name.lower()}, board {board.name.lower()}")
        else:
            self.diag.set_condition(OK, d.state.name.lower())

    def publish_state(self, force: bool = False) -> None:
        d = self.drv
        key = (d.state, d.reason, d.board_mode)
        if key != self.last_state:
            self.node.logger.info(f"state {d.state.name.lower()}, board {Mode(d.board_mode).name.lower()}"
                                  + (f": {d.reason}" if d.reason else ""))
            if d.state == DriverState.FAULT and self.last_state[0] != DriverState.FAULT:
                announce("fault", "hw_driver", reason=d.reason, t0=self.epoch_ns is not None)
            self.last_state = key
        if d.hello is not None and not self.board_announced:  # the board answered the driver's hello
            self.board_announced = True
            self.diag.hardware_id = f"board {d.hello.board_id}"  # the device behind the driver's statuses
            announce("board", "hw_driver", url=self.cfg["url"], board_id=d.hello.board_id)
        st = diag_array(*self.D, self.node.now_ns(), contract.HW_STATE_STATUS, self._level(), d.state.name.lower(),
                        {**self.stats(), "answer": self.answer}, self.diag.hardware_id).status[0]
        self.pub_state.publish(st)

    def _level(self) -> int:
        if self.drv.state == DriverState.FAULT:
            return 2
        c = self.drv.counters
        return 1 if (c["lost"] or c["corrupt"] or c["hold_samples"] or self.source.foreign) else 0

    def experiment_t(self) -> float | None:
        """The experiment time of the newest sample from the board [s]; None before t = 0."""
        s, e = self.drv.last_sample, self.epoch_seq
        return (s.seq - e) * self.cfg["dt"] if s is not None and e is not None and s.seq >= e else None

    def stats(self) -> dict:
        with self.lock:
            st = self.drv.status()
        k = (0 if self.drv.last_sample is None or self.epoch_seq is None
             else max(self.drv.last_sample.seq - self.epoch_seq, 0))
        if self.n_end:
            k = min(k, self.n_end)  # the experiment's samples (the end-of-run landing is not part of it)
        lat = self.lat.summary_us()
        wall = k * self.cfg["dt"]
        cpu = time.process_time() - self.cpu0 if self.cpu0 is not None else 0.0
        epoch = {"epoch_ns": self.epoch_ns} if self.epoch_ns is not None else {}
        return {"cycles": k, "t_sim_s": round(k * self.cfg["dt"], 3),
                "deadline_misses": st["lost"] + st["hold_samples"], **epoch, "realtime_factor": 1.0, "lockstep": False,
                "cpu_s": round(cpu, 3), "wall_s": round(wall, 3),
                "latency_p50_us": round(lat["p50"], 1), "latency_p99_us": round(lat["p99"], 1),
                "latency_max_us": round(lat["max"], 1), "failed": bool(self.failed), "fault": self.failed,
                **({"fail_time_s": round(self.fail_t, 3)} if self.fail_t is not None else {}),
                "holds": st["hold_samples"], "board_run_samples": self.board_run_samples, **self._landing(), **st,
                "publish_errors": self.publish_errors, "reader_errors": self.reader_errors,
                "lifecycle": self.machine.label, **self.source.values()}

    def _landing(self) -> dict[str, Any]:
        """``landing`` / ``landing_reason`` of the loop status: a board landing during the experiment (its time and
        why), else the end-of-run landing (expected: ``failed`` stays False)."""
        if self.board_down is not None:
            return {"landing": True, "landing_reason": self.board_down[1], "landing_t_s": round(self.board_down[0], 3)}
        if not self.finished:
            return {"landing": False, "landing_reason": ""}
        end = f"end of the run: disarmed after {self.cfg['duration']:g} s, "
        end += (f"the board landed the plate in {self.end_landed_s:.2f} s" if self.end_landed_s is not None
                else f"board {Mode(self.drv.board_mode).name.lower()}")
        return {"landing": True, "landing_reason": end}

    def status(self) -> None:
        s = self.stats()
        g = self.drv.last_sample.gap if self.drv.last_sample is not None else (np.nan, np.nan)
        if self.epoch_ns is not None and not self.finished:
            print(f"t = {s['t_sim_s']:7.1f} s  gaps {g[0] * 1e3:6.3f} / {g[1] * 1e3:6.3f} mm  {s['state']}"
                  f" (board {s['board_mode']})  lost {s['lost']} late {s['late']} corrupt {s['corrupt']}"
                  f" holds {s['hold_samples']}"
                  f"  latency p50 {s['latency_p50_us']:.0f} us p99 {s['latency_p99_us']:.0f} us", flush=True)
        self.report_faults()
        self.diag.report()

    def finish(self, why: str) -> None:
        """The node ends (the run's end, or a lifecycle shutdown): its link reader stops, then the node."""
        if self.ended:
            return
        self.ended = True
        self.stop.set()
        s = self.stats()
        msg = f"{why}; board {s['board_mode']}" + (f"; fault: {self.failed}" if self.failed else "")
        self.node.logger.info(msg)
        self.diag.publish(2 if self.failed else 0, "finished: " + msg, s)
        announce("finished", "hw_driver", message=msg, failed=bool(self.failed))
        self.publish_state(force=True)
        self.node.timer(0.3, self.node.shutdown)

    def _land_on_stop(self) -> None:
        """Stopped from outside (the lock held): a levitating board is told to LAND, once. The reader does this
        at the first frame after the node's shutdown: the commands stopped with it, and the process's teardown
        (DDS entities, the participant) before close() outlasted the board's hold_timeout (50 ms), so the
        board landed the plate on its own watchdog ("no command") instead of the driver's LAND request."""
        self.stop_landed = True
        if Mode(self.drv.board_mode) in (Mode.RUN, Mode.HOLD):
            self.drv.disarm()
            with contextlib.suppress(Exception):  # the node's logger after its shutdown: best effort
                self.node.logger.info("stopped: landing the plate before closing the link")

    def close(self) -> None:
        """After the node is shut down: land the plate before letting go of the link (disarm: LAND in reply to
        every sensor frame, until the board reports LAND / LANDED / OFF / FAULT or ``STOP_LANDING_S``),
        then close it."""
        self.closing = True
        end = time.monotonic() + STOP_LANDING_S
        if self.reader.is_alive():
            with self.lock:
                if not self.stop_landed:
                    self._land_on_stop()
            while time.monotonic() < end and Mode(self.drv.board_mode) in (Mode.RUN, Mode.HOLD):
                time.sleep(0.005)
        self.stop.set()
        self.reader.join(timeout=1.0)
        if self.ch is not None:  # (closed after a cleanup)
            self.ch.close()


def main(args=None) -> int:
    made: list[HwDriverNode] = []

    def setup(node: Node) -> HwDriverNode:
        made.append(HwDriverNode(node))
        return made[-1]

    try:
        return run_node("hw_driver", setup, args=args)
    finally:
        for drv in made:  # stopped or finished: the plate is landed before the link is let go
            drv.close()


if __name__ == "__main__":
    sys.exit(main())

"""Topic statuses as ``diagnostic_updater`` (ros/diagnostics) reports them, without a middleware.

:class:`FrequencyStatus`, :class:`TimeStampStatus` and :class:`TopicDiagnostic` ("<topic> topic status": both
in one status) are counterparts of the classes of the same names in diagnostic_updater's Python package
(``_update_functions.py``, ``_publisher.py``): the same key names, value formats (``%d``, ``%f``), messages,
levels and window arithmetic, so that ``diagnostic_aggregator``, ``rqt_robot_monitor`` and whoever knows those
keys read ours. :class:`DiagnosedPublisher` is diagnostic_updater's ``DiagnosedPublisher``: a publisher that
ticks its topic's status with each message's ``header.stamp``. :class:`~dem_ros.nodes.common.Diagnostics`
reports them once a second with the node's own status (:meth:`~dem_ros.nodes.common.Diagnostics.diagnosed`).

Where this differs from diagnostic_updater, and why:

* No clock and no lock here: every time is a ``now_ns`` argument (the node's ROS time; a test's synthetic
  times). A tick is a counter increment and a min/max update, cheap at 1 kHz in Python; it is written by one
  thread (the one that publishes) and read by the reporter, so a report taken while a tick runs may leave that
  one stamp out of its delay range (diagnostic_updater takes a lock for that).
* A topic's window starts at its first publication, and a topic is reported once that is at least half a
  report period ago (:meth:`TopicDiagnostic.ready`): diagnostic_updater starts the window when the task is made
  and reports ERROR "No events recorded." until the first, which at 1 kHz would put every node at ERROR while
  the graph waits for its start (the node's own status says why it waits); and a first window of a few
  milliseconds has no rate to speak of (2 messages in 3 ms: "Frequency too low."). Once started, a topic that
  falls silent is ERROR "No events recorded." after a whole window, as there.
* A tick is counted after the publisher accepted the message (diagnostic_updater ticks before publishing): a
  sample the transport failed to send is no event of the topic. Its delay is taken when ``publish`` is called.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from ..contract import TOPIC_STATUS_SUFFIX

__all__ = ["DiagnosedPublisher", "FrequencyStatus", "TimeStampStatus", "TopicDiagnostic", "merge_summary"]

OK, WARN, ERROR = 0, 1, 2  # diagnostic_msgs/DiagnosticStatus levels (as nodes.common's)


def merge_summary(summary: tuple[int, str], level: int, message: str) -> tuple[int, str]:
    """``DiagnosticStatusWrapper.mergeSummary`` (Python): the worse level; the messages of two statuses that are
    both OK or both not OK joined with "; ", else the worse one's."""
    lv, msg = summary
    if (level > OK) == (lv > OK):
        msg = f"{msg}; {message}" if msg else message
    elif level > lv:
        msg = message
    return max(lv, level), msg


class FrequencyStatus:
    """The rate of :meth:`tick` over the last ``window_size`` reports (diagnostic_updater's ``FrequencyStatus``).

    Acceptable: ``min_hz * (1 - tolerance)`` to ``max_hz * (1 + tolerance)`` (``max_hz`` infinite: no upper
    bound). Each :meth:`run` (a report) compares the tick count and the time now with those of the report
    ``window_size`` reports ago (the first reports: with the start, :meth:`clear`).
    """

    def __init__(self, min_hz: float, max_hz: float = math.inf, *, tolerance: float = 0.1, window_size: int = 5,
                 now_ns: int = 0):
        self.min_hz = float(min_hz)
        self.max_hz = float(max_hz)
        self.tolerance = float(tolerance)
        self.window_size = int(window_size)
        self.clear(now_ns)

    def clear(self, now_ns: int) -> None:
        """Start again at ``now_ns``: no events, a window that begins there."""
        self.count = 0
        self.times = [now_ns] * self.window_size
        self.seq_nums = [0] * self.window_size
        self.hist_indx = 0

    def tick(self) -> None:
        """An event."""
        self.count += 1

    def run(self, now_ns: int) -> tuple[int, str, dict[str, str]]:
        """(level, message, key/values) of a report at ``now_ns``; the window moves on by one report."""
        curseq = self.count
        i = self.hist_indx
        events = curseq - self.seq_nums[i]
        window = (now_ns - self.times[i]) * 1e-9
        freq = events / window if window > 0 else (math.inf if events else 0.0)
        self.seq_nums[i] = curseq
        self.times[i] = now_ns
        self.hist_indx = (i + 1) % self.window_size
        lo, hi = self.min_hz * (1 - self.tolerance), self.max_hz * (1 + self.tolerance)
        if events == 0:
            level, message = ERROR, "No events recorded."
        elif freq < lo:
            level, message = WARN, "Frequency too low."
        elif math.isfinite(self.max_hz) and freq > hi:
            level, message = WARN, "Frequency too high."
        else:
            level, message = OK, "Desired frequency met"
        values = {"Events in window": f"{events:d}", "Events since startup": f"{curseq:d}",
                  "Duration of window (s)": f"{window:f}", "Actual frequency (Hz)": f"{freq:f}"}
        if self.min_hz == self.max_hz:
            values["Target frequency (Hz)"] = f"{self.min_hz:f}"
        if self.min_hz > 0:
            values["Minimum acceptable frequency (Hz)"] = f"{lo:f}"
        if math.isfinite(self.max_hz):
            values["Maximum acceptable frequency (Hz)"] = f"{hi:f}"
        return level, message, values


class TimeStampStatus:
    """How old the stamps of the events since the previous report were when they happened (now - stamp, s;
    diagnostic_updater's ``TimeStampStatus``): ERROR when one was more than ``max_acceptable`` s old, more than
    ``-min_acceptable`` s ahead, or zero; WARN when there was none. The counts of reports with late, early and
    zero stamps are kept."""

    def __init__(self, min_acceptable: float = -1.0, max_acceptable: float = 5.0):
        self.min_acceptable = float(min_acceptable)
        self.max_acceptable = float(max_acceptable)
        self.early_count = 0
        self.late_count = 0
        self.zero_count = 0
        self.zero_seen = False
        self.max_delta_ns = 0
        self.min_delta_ns = 0
        self.deltas_valid = False

    def tick(self, stamp_ns: int, now_ns: int) -> None:
        """An event stamped ``stamp_ns`` (ns since the epoch; 0: no stamp) at ``now_ns``."""
        if stamp_ns == 0:
            self.zero_seen = True
            return
        delta = now_ns - stamp_ns
        if not self.deltas_valid:
            self.min_delta_ns = self.max_delta_ns = delta
            self.deltas_valid = True
        elif delta > self.max_delta_ns:
            self.max_delta_ns = delta
        elif delta < self.min_delta_ns:
            self.min_delta_ns = delta

    def run(self) -> tuple[int, str, dict[str, str]]:
        """(level, message, key/values) of a report; the delays start afresh."""
        level, message = OK, "Timestamps are reasonable."
        lo, hi = self.min_delta_ns * 1e-9, self.max_delta_ns * 1e-9
        if not self.deltas_valid:
            level, message = WARN, "No data since last update."
        else:
            if lo < self.min_acceptable:
                level, message = ERROR, "Timestamps too far in future seen."
                self.early_count += 1
            if hi > self.max_acceptable:
                level, message = ERROR, "Timestamps too far in past seen."
                self.late_count += 1
            if self.zero_seen:
                level, message = ERROR, "Zero timestamp seen."
                self.zero_count += 1
        values = {"Earliest timestamp delay:": f"{lo:f}", "Latest timestamp delay:": f"{hi:f}",
                  "Earliest acceptable timestamp delay:": f"{self.min_acceptable:f}",
                  "Latest acceptable timestamp delay:": f"{self.max_acceptable:f}",
                  "Late diagnostic update count:": f"{self.late_count:d}",
                  "Early diagnostic update count:": f"{self.early_count:d}",
                  "Zero seen diagnostic update count:": f"{self.zero_count:d}"}
        self.deltas_valid = False
        self.min_delta_ns = self.max_delta_ns = 0
        self.zero_seen = False
        return level, message, values


class TopicDiagnostic:
    """A topic's frequency and timestamp status in one, named ``"<topic> topic status"`` (diagnostic_updater's
    ``TopicDiagnostic``, a composite task: the frequency's keys then the timestamp's, the summaries merged by
    :func:`merge_summary`). A topic with a nominal rate: ``TopicDiagnostic(topic, FrequencyStatus(rate, rate),
    TimeStampStatus())``."""

    def __init__(self, topic: str, freq: FrequencyStatus, stamp: TimeStampStatus):
        self.topic = topic
        self.name = topic + TOPIC_STATUS_SUFFIX
        self.freq = freq
        self.stamp = stamp
        self.first_ns: int | None = None  # when the topic was first published

    @property
    def started(self) -> bool:
        """The topic was published (the window starts at its first tick)."""
        return self.first_ns is not None

    def ready(self, now_ns: int, min_window_ns: int) -> bool:
        """Whether a report at ``now_ns`` has a window: the first publication at least ``min_window_ns`` ago."""
        return self.first_ns is not None and now_ns - self.first_ns >= min_window_ns

    def tick(self, stamp_ns: int, now_ns: int) -> None:
        """A message stamped ``stamp_ns`` published at ``now_ns``."""
        freq = self.freq
        if not freq.count:
            freq.clear(now_ns)
            self.first_ns = now_ns
        freq.count += 1
        self.stamp.tick(stamp_ns, now_ns)

    def run(self, now_ns: int) -> tuple[int, str, dict[str, str]]:
        """(level, message, key/values) of a report at ``now_ns``."""
        summary = (OK, "")
        values: dict[str, str] = {}
        for level, message, vals in (self.freq.run(now_ns), self.stamp.run()):
            summary = merge_summary(summary, level, message)
            values.update(vals)
        return summary[0], summary[1], values


class DiagnosedPublisher:
    """A publisher whose every message ticks a :class:`TopicDiagnostic` with its ``header.stamp`` (the time now
    from ``clock``, ns) once the publisher took it (diagnostic_updater's ``DiagnosedPublisher``). Anything else
    (``subscription_count``, ``publish_raw``: not ticked) is the publisher's."""

    __slots__ = ("_clock", "_pub", "_tick", "diagnostic")

    def __init__(self, publisher: Any, diagnostic: TopicDiagnostic, clock: Callable[[], int]):
        self._pub = publisher
        self._clock = clock
        self._tick = diagnostic.tick
        self.diagnostic = diagnostic

    def publish(self, msg: Any) -> None:
        now = self._clock()
        self._pub.publish(msg)
        s = msg.header.stamp
        self._tick(s.sec * 1_000_000_000 + s.nanosec, now)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._pub, name)

"""rosbag2-compatible MCAP recording, reading and checking (no middleware).

* :class:`BagWriter` writes a bag directory (``metadata.yaml`` v8 +
  ``NAME_0.mcap``) that Humble/Jazzy ``ros2 bag``, Foxglove and rosbags read.
* :class:`Recorder` is the middleware-free core of the recorder node: it
  takes CDR bytes from subscription callbacks and writes them on its own
  thread through a bounded queue, counting drops.
* :class:`BagReader` reads our bags, ``ros2 bag record -s mcap`` bags and bare
  ``.mcap`` files, including truncated ones, and extracts JointState streams
  as numpy arrays.
* :func:`check` says what a bag holds and what is missing or broken.
"""

from .check import CheckReport, check, main_check
from .errors import BagError
from .reader import BagReader, TopicInfo
from .recorder import Recorder, TopicCounters, finalize_on_signals
from .writer import BagWriter

__all__ = [
    "BagError",
    "BagReader",
    "BagWriter",
    "CheckReport",
    "Recorder",
    "TopicCounters",
    "TopicInfo",
    "check",
    "finalize_on_signals",
    "main_check",
]

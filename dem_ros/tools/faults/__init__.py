"""``dem-ros faults``: the fault catalogue of issue #12, injected into the real graph, one run per row.

Each row launches the graph (``dem-ros launch``: real processes over DDS, or ``--compose``), injects one
fault at t = ``--at`` s of the experiment and reads the outcome back from the run's bag:

* **outcome**: ``levitating`` (the board still runs the controller's commands at the end and the true
  gap is within 1 mm of the reference), ``landed safely`` (the board landed the plate, never nearer the
  rail than ``trip_gap_min``), or ``failed`` (rail contact, a plant failure, or a run cut short by an
  unexpected exit). The plant's truth (``/dem/plant/truth``) gives the minimum gap and the largest
  tracking error (true gap - reference) from the fault on.
* **reported**: the ``/diagnostics`` statuses at WARN or ERROR after the fault, and the nodes' ``/rosout`` records
  (``rcl_interfaces/msg/Log``) at WARN or above (count per logger), both from the bag and, marked "(live)", those
  heard live by this process that the bag lacks (a full disk stops the recording before the recorder's own
  ERROR). Structured records only: the node logs stay on disk for people, no log text is parsed.
* **data lost**: what the recorder dropped and what the bag reports about itself (truncated, recording
  stopped early, samples without a reference); "none" when the bag is complete.

A row passes when its outcome is one the row allows (messages, steps and spikes must leave the plate
levitating; a killed node may end in a safe landing where the outage outlasts the board's hold) and the
fault is reported. Injected messages come from this process, a foreign DDS participant on the graph's
domain (:class:`Injector`); nodes are killed with SIGKILL and restarted by the launcher's hook.

**Hardware rows** (``--hardware rig``, :data:`RIG_CATALOGUE`): ``dem-ros launch --hardware rig --compose`` (the
hardware driver, and the emulated board and rig ``dem-ros rig`` as its own free-running 1 kHz process, over UDP on
loopback; ``controller.command_delay=2``), one row per rig fault (``dem-ros rig --fault``, scheduled on the board's
clock at the experiment's t = ``--at``), an e-stop on ``/dem/hw/estop`` or a killed controller (for that row the
controller runs in a process of its own beside the container: ``--apart controller``). A rig has no truth topic, so
the plate's truth is the emulator's own (its summary at the end, as the launcher reads it: smallest true gap since
the release, fastest descent while the board landed it, rail contact):

* **outcome**: ``failed`` on rail contact (the emulated plant's failure, or a true gap at ``gap_min``), a board
  FAULT (0 V), a landing nearer the rail than ``trip_gap_min`` or descending faster than ``landing_speed`` (where
  the row's design bounds it: a failed coil's end or a bus below what holds the plate cannot be bounded); else
  ``landed safely`` when the driver's loop status says the board landed the plate (or the driver faulted) during
  the experiment, ``levitating`` when the measured gaps end within 1 mm of the reference (the max error column:
  measured gap - reference, from the fault on).
* **reported**: one of the row's words (``reports``) in a WARN/ERROR ``/diagnostics`` status or a WARN/ERROR
  ``/rosout`` record from the fault on (e.g. the driver's "e-stop: ..." ERROR, its "corrupt +48" WARN).
* **counted**: the row's counters (``counts``) of the driver (its last loop status in the bag), the board (the
  emulated board's Supervisor counters) or the estimator, each at least its minimum; the emulator's own hit
  count beside them.

A hardware row passes when its outcome is allowed, the fault is reported and counted, and the board did not land
the plate before the fault (a host stall on a loaded machine: that landing is not the fault's, the row says so).

Exit status: 0 when every row passes, 1 otherwise (2: usage).

The package: :mod:`.catalogue` (the rows), :mod:`.inject` (the injector, the injections, the kill hook),
:mod:`.judge` (a run's bag and records into an outcome), :mod:`.run` (one row's run, the command).
"""

from .catalogue import CATALOGUE, RIG_CATALOGUE
from .inject import Injector
from .run import Row, add_arguments, cmd_faults, run_row
from .spec import FaultSpec

__all__ = ["CATALOGUE", "RIG_CATALOGUE", "FaultSpec", "Injector", "Row", "add_arguments", "cmd_faults", "run_row"]

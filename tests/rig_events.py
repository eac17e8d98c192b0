"""The emulated board's events in a launched run, for the tests that script one (tests/hardware/test_hw_*.py).

``dem-ros rig`` announces its events on the launcher's run-state pipe (:mod:`dem_ros.runstate`, node ``rig``):
``listening``, ``mode`` at each mode change but RUN <-> HOLD (with its reason and wall time), ``status`` once a
second (mode, true gaps, landings), ``summary`` at the end. The launcher keeps every run-state event in its
workdir (:data:`dem_ros.tools.launcher.RUN_STATE_FILE`); this reads them back there.
"""

from __future__ import annotations

import json
from pathlib import Path

from dem_ros.tools.launcher import RUN_STATE_FILE


def rig_events(workdir: Path, event: str | None = None) -> list[dict]:
    """The emulator's events so far, in order (only those named ``event``, if given); [] before the first."""
    try:
        lines = (workdir / RUN_STATE_FILE).read_text(errors="replace").splitlines()
    except OSError:
        return []
    out = []
    for line in lines:
        try:
            ev = json.loads(line)
        except ValueError:
            continue  # a line being written
        if ev.get("node") == "rig" and (event is None or ev.get("event") == event):
            out.append(ev)
    return out

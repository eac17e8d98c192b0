"""``dem-ros study``: robustness of the controllers over plant truth, on Dask distributed.

A study runs every *cell* of a grid (or every sample of a Monte Carlo draw) over
the true plant, for each controller, as one closed-loop run of the offline
simulator (:func:`dem_ros.core.simulate.simulate`, i.e. the compiled
``_closed_loop`` kernel with the estimator, noise, delay and plant of the run's
validated configuration). Nothing of the plant is re-implemented here: a cell
is a set of schema overrides on top of the scenario.

One job per module:

:mod:`.spec`    the study's definition: axes (``--axis NAME=SPEC``, ``--preset``),
                seeds, cells, run ids and the plan of runs (:func:`plan_runs`).
:mod:`.run`     the runs on Dask distributed (:func:`run_study`, :func:`run_chunk`
                on the workers) into ``results.csv`` and ``study.json``; resumable.
:mod:`.report`  the robustness table and maps, and the section of ``dem-ros report``.
:mod:`.cli`     the command: :func:`add_arguments`, :func:`cmd_study`.

Every public name of these modules is importable from this package.
"""

from __future__ import annotations

from .cli import add_arguments, cmd_study
from .report import draw_maps, report_section, robustness_rows, robustness_table
from .run import RESULT_FIELDS, load_results, run_chunk, run_study
from .spec import (
    DERIVED,
    PRESETS,
    Axis,
    Derived,
    StudyError,
    StudySpec,
    core_digest,
    parse_axis,
    plan_runs,
    spec_from_args,
)

__all__ = [
    "DERIVED",
    "PRESETS",
    "RESULT_FIELDS",
    "Axis",
    "Derived",
    "StudyError",
    "StudySpec",
    "add_arguments",
    "cmd_study",
    "core_digest",
    "draw_maps",
    "load_results",
    "parse_axis",
    "plan_runs",
    "report_section",
    "robustness_rows",
    "robustness_table",
    "run_chunk",
    "run_study",
    "spec_from_args",
]

"""Helpers shared by the ``dem-ros`` commands (imported by them, importing none of them).

* :class:`UsageError`: a user-facing error, printed by the CLI as one line with exit status 2.
* :func:`load_config`: scenario + params file + ``--set`` assignments -> the run's configuration.
* :func:`yaml_scalar`: the one YAML emitter for parameter values (params files, launch files).
* :func:`fmt_pair`: two numbers (e.g. e1 / e2) as one table cell.
* ``CONTROLLER_TYPES`` / ``ESTIMATOR_TYPES``: the schema's choices, for argparse.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from typing import Any

from ..core.params import SCHEMA, apply_overrides, load_params_file, parse_assignment
from ..core.scenarios import Scenario, get_scenario

__all__ = ["CONTROLLER_TYPES", "ESTIMATOR_TYPES", "UsageError", "fmt_pair", "load_config", "yaml_scalar"]

#: the control laws and estimators a run can use: the parameter schema's choices (one source)
CONTROLLER_TYPES: tuple[str, ...] = tuple(SCHEMA.spec("controller", "type").choices or ())
ESTIMATOR_TYPES: tuple[str, ...] = tuple(SCHEMA.spec("estimator", "type").choices or ())


class UsageError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


def load_config(args: argparse.Namespace) -> tuple[dict[str, dict[str, Any]], Scenario]:
    """Scenario (+ optional params file + ``--set`` assignments) -> (config, scenario).

    ``args`` needs ``scenario``; ``params`` (a ROS 2 params file) and ``set``
    (``GROUP.NAME=VALUE`` strings) are optional. Every value is validated by the schema.
    """
    sc = get_scenario(args.scenario)
    base = load_params_file(args.params) if getattr(args, "params", None) else None
    cfg = sc.config(base)
    sets: dict[str, dict[str, Any]] = {}
    for text in getattr(args, "set", None) or []:
        g, n, v = parse_assignment(text)
        sets.setdefault(g, {})[n] = v
    if sets:
        cfg = apply_overrides(cfg, sets, "--set")
    return cfg, sc


def fmt_pair(v: Sequence[float] | None, nd: int = 2) -> str:
    """``[a, b]`` -> ``"a / b"`` with ``nd`` decimals (nan kept as ``nan``; None -> ``-``)."""
    if v is None:
        return "-"
    return " / ".join("nan" if x != x else f"{x:.{nd}f}" for x in v)


def yaml_scalar(v: Any) -> str:
    """A parameter value as a YAML scalar that reads back as the same type and value.

    Floats keep a decimal point (``1.0e-05``, not ``1e-05``, which YAML 1.1 reads
    as a string), strings are double-quoted (JSON escapes are valid YAML), bools
    are ``true`` / ``false``.
    """
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, float):
        text = repr(v)
        if "e" in text and "." not in text.split("e")[0]:
            mant, exp = text.split("e")
            text = f"{mant}.0e{exp}"
        return text
    return str(v)

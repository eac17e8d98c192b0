"""Helpers shared by the ``dem-ros`` commands (imported by them, importing none of them).

* :class:`UsageError`: a user-facing error, printed by the CLI as one line with exit status 2.
* :func:`load_config`: scenario + params file + ``--set`` assignments -> the run's configuration.
* :func:`check_param_value`: a parameter value checked against the schema (``dem-ros param set``, the live view).
* :func:`yaml_scalar`: the one YAML emitter for parameter values (params files, launch files).
* :func:`fmt_pair`: two numbers (e.g. e1 / e2) as one table cell.
* ``CONTROLLER_TYPES`` / ``ESTIMATOR_TYPES``: the schema's choices, for argparse.
* argparse ``type=`` checks that reject a mistake before anything starts: :func:`seconds`,
  :func:`seed`, :func:`domain_id`, :func:`out_file`, :func:`out_dir`; :func:`env_domain_id`.
* :func:`write_json`: the one JSON writer (standard JSON: ``null`` for NaN / inf, never bare ``NaN``).
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import math
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from ..contract import DOMAIN_ID_MAX
from ..core.params import SCHEMA, ConfigError, apply_overrides, load_params_file, parse_assignment

if TYPE_CHECKING:  # the scenarios (and numpy) load with the first configuration, not with every command
    from ..core.scenarios import Scenario

__all__ = ["CONTROLLER_TYPES", "ESTIMATOR_TYPES", "UsageError", "check_param_value", "domain_id", "env_domain_id",
           "fmt_pair", "json_safe", "json_text", "load_config", "out_dir", "out_file", "seconds", "seed",
           "warm_kernels", "write_json", "yaml_scalar"]


#: the control laws and estimators a run can use: the parameter schema's choices (one source)
CONTROLLER_TYPES: tuple[str, ...] = tuple(SCHEMA.spec("controller", "type").choices or ())
ESTIMATOR_TYPES: tuple[str, ...] = tuple(SCHEMA.spec("estimator", "type").choices or ())


class UsageError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


def load_config(scenario: str, params: str | None = None,
                assignments: Sequence[str] = ()) -> tuple[dict[str, dict[str, Any]], Scenario]:
    """Scenario (+ optional params file + ``--set`` assignments) -> (config, scenario).

    ``params`` is a ROS 2 params file, ``assignments`` are ``GROUP.NAME=VALUE`` strings (``--set``). Every value
    is validated by the schema.
    """
    from ..core.scenarios import get_scenario

    sc = get_scenario(scenario)
    base = load_params_file(params) if params else None
    cfg = sc.config(base)
    sets: dict[str, dict[str, Any]] = {}
    for text in assignments:
        g, n, v = parse_assignment(text)
        sets.setdefault(g, {})[n] = v
    if sets:
        cfg = apply_overrides(cfg, sets, "--set")
    return cfg, sc


def check_param_value(node: str, name: str, text: str) -> None:
    """A malformed value for one of our nodes' parameters is a usage error, found before the node is asked.

    ``dem-ros param set`` and the live view (:mod:`dem_ros.view.graph`) check a value with it. ConfigError
    with the schema's reason; a node or parameter the schema does not know is left to the node.
    """
    import yaml

    group = node.strip("/").rsplit("/", 1)[-1]
    if group not in SCHEMA.groups or name not in {p.name for p in SCHEMA.groups[group]}:
        return  # not one of ours (or not known here): the node answers
    spec = SCHEMA.spec(group, name)
    try:
        value = yaml.safe_load(text) if spec.type is not str else text
    except yaml.YAMLError:
        value = text
    spec.coerce(value, f"{group}.{name}")  # ConfigError: one line, exit 2


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


# -- argparse types: each mistake is one line (``argument --x: ...``) before anything starts ----------------------

def seconds(text: str) -> float:
    """A duration in seconds: a finite number > 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not math.isfinite(v) or v <= 0.0:
        raise argparse.ArgumentTypeError(f"expected a finite number of seconds > 0, got {text!r}")
    return v


def seed(text: str) -> int:
    """A seed for the noise generators, within the schema's ``plant_sim.seed`` bounds."""
    spec = SCHEMA.spec("plant_sim", "seed")
    try:
        return int(spec.coerce(int(text), "seed"))
    except (ValueError, ConfigError):
        raise argparse.ArgumentTypeError(f"got {text!r}, expected {spec.allowed()}") from None


def domain_id(text: str) -> int:
    """A ROS domain id, 0..DOMAIN_ID_MAX (``contract``)."""
    try:
        v = int(text)
    except ValueError:
        v = -1
    if not 0 <= v <= DOMAIN_ID_MAX:
        raise argparse.ArgumentTypeError(f"got {text!r}, expected an integer in [0, {DOMAIN_ID_MAX}]")
    return v


def env_domain_id() -> int | None:
    """``ROS_DOMAIN_ID`` from the environment (None if unset or empty); UsageError if malformed."""
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return None
    try:
        return domain_id(text)
    except argparse.ArgumentTypeError as exc:
        raise UsageError(f"ROS_DOMAIN_ID: {exc}") from None


def _writable_dir(d: Path, what: Path) -> None:
    if not d.is_dir():
        raise argparse.ArgumentTypeError(f"cannot write {what}: {d} is not a directory")
    if not os.access(d, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f"cannot write {what}: {d} is not writable")


def out_file(text: str) -> Path:
    """A file to write: its directory exists and is writable; it is not a directory."""
    p = Path(text)
    if p.is_dir():
        raise argparse.ArgumentTypeError(f"{p} is a directory, expected a file name")
    _writable_dir(p.parent if str(p.parent) else Path("."), p)
    return p


def out_dir(text: str) -> Path:
    """A directory to write into: an existing writable directory, or one that can be created."""
    p = Path(text)
    d = p
    while not d.exists():  # the nearest existing ancestor must be a writable directory
        if d.parent == d:
            break
        d = d.parent
    _writable_dir(d, p)
    if d != p:  # access() says yes for root on /proc: a directory made and removed there is the real test
        try:
            os.rmdir(tempfile.mkdtemp(prefix=".dem_ros_probe_", dir=d))
        except OSError as exc:
            raise argparse.ArgumentTypeError(f"cannot write {p}: cannot create a directory in {d}"
                                             f" ({exc.strerror or exc})") from None
    return p


def json_safe(obj: Any) -> Any:
    """``obj`` with every non-finite float replaced by None (JSON ``null``), numpy scalars as Python numbers."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if hasattr(obj, "item") and not isinstance(obj, (str, bytes)):  # numpy scalar
        with contextlib.suppress(TypeError, ValueError):
            obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def json_text(obj: Any) -> str:
    """Standard JSON (RFC 8259) of ``obj``: NaN / inf become ``null``."""
    return json.dumps(json_safe(obj), indent=2, allow_nan=False) + "\n"


def write_json(path: Path | str, obj: Any) -> Path:
    """Write ``obj`` as standard JSON (see :func:`json_text`)."""
    path = Path(path)
    path.write_text(json_text(obj))
    return path


def warm_kernels(prefix: str, stream: IO[str] | None = None,
                 offline: Sequence[tuple[str | None, str | None]] = ()) -> float:
    """Compile (first run) or load numba's cache of every kernel here, with progress on ``stream``.

    ``offline``: also the offline closed loop of these (control law, estimator) pairs (None: the
    configured default), for a command that simulates (see :func:`dem_ros.core.warmup.warm_up`).

    Reported through :class:`.progress.Progress`: nothing when the cache loads within a second;
    otherwise a line says whether the kernels compile (an empty cache: the first run after an
    install or an edit of ``dem_ros/core``) or load, names what, and a new line follows at least
    every 5 s, so a first run is never silent. Returns the seconds it took.
    """
    from ..core.numba_cache import configure
    from ..core.warmup import warm_up
    from .progress import Progress

    # numba keeps a source directory's kernels in <cache>/<dir name>_<sha1 of its absolute path> (its
    # _UserProvidedCacheLocator): another checkout of the same version shares the cache directory, not the kernels
    core = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, "core"))  # as numba: abspath, not resolve
    mine = Path(configure()) / f"core_{hashlib.sha1(core.encode()).hexdigest()}"
    cold = not (mine.is_dir() and any(mine.glob("*.nbi")))
    doing = ("compiling numba kernels (first run only; cached for later runs)" if cold
             else "loading the compiled numba kernels")
    bar = Progress(prefix, stream=stream, stage=f"{doing}: loading numba")
    try:
        warm_up(lambda what: bar.stage(f"{doing}: {what}"), offline)
    finally:
        dt = bar.close(f"{prefix}: kernels ready in {bar.elapsed:.0f} s")
    return dt

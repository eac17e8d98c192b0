"""ROS 2 command-line arguments (``--ros-args ...``), parsed the way rcl does.

Supported inside ``--ros-args`` (until ``--`` or the end):
    ``--params-file FILE``, ``-p/--param name:=value`` (value parsed as YAML,
    optionally ``node:name:=value``), ``-r/--remap [node:]from:=to`` with
    ``__node``/``__name`` and ``__ns`` as in rcl, plus topic remaps;
    ``--log-level``, ``-e/--enclave``, ``--disable-rosout-logs``, ``--enable-*``
    and ``--disable-*`` flags are accepted and ignored. Anything else is an error.

The parameter start values of a node are computed once, here, for both
transports: schema defaults, then each params file in order, then ``-p``
overrides, validated as a whole by :mod:`dem_ros.core.params`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..core.params import SCHEMA, ConfigError, apply_overrides, default_config, params_from_tree, read_yaml

__all__ = ["RosArgs", "initial_parameters", "parse_ros_args"]


@dataclass
class RosArgs:
    """What ``--ros-args`` asked for."""

    node_name: str | None = None
    namespace: str | None = None
    params_files: list[str] = field(default_factory=list)
    params: list[tuple[str | None, str, Any]] = field(default_factory=list)  # (node or None, name, value)
    remaps: dict[str, str] = field(default_factory=dict)  # topic remaps, absolute names
    user_args: list[str] = field(default_factory=list)

    def resolve(self, topic_name: str, namespace: str = "/") -> str:
        """Absolute topic name after ``-r from:=to`` remaps (relative names join ``namespace``)."""
        full = topic_name if topic_name.startswith("/") else namespace.rstrip("/") + "/" + topic_name
        return self.remaps.get(full, full)


_FLAGS_WITH_VALUE = {"--log-level", "-e", "--enclave", "--log-config-file", "--external-log-config"}
_FLAGS = {"--disable-rosout-logs", "--enable-rosout-logs", "--disable-stdout-logs", "--enable-stdout-logs",
          "--disable-external-lib-logs", "--enable-external-lib-logs", "--log-file-name"}


def _yaml_value(raw: str) -> Any:
    import yaml

    try:
        return yaml.safe_load(raw)
    except yaml.YAMLError:
        return raw


def parse_ros_args(args: Sequence[str] | None) -> RosArgs:
    """Parse a full argv tail; arguments outside ``--ros-args`` end up in ``user_args``."""
    out = RosArgs()
    if not args:
        return out
    it = iter(list(args))
    in_ros = False
    for a in it:
        if a == "--ros-args":
            in_ros = True
            continue
        if not in_ros:
            out.user_args.append(a)
            continue
        if a == "--":
            in_ros = False
            continue
        try:
            if a == "--params-file":
                path = next(it)
                if not Path(path).is_file():
                    raise ConfigError(f"--params-file {path}: no such file")
                out.params_files.append(path)
            elif a in ("-p", "--param"):
                rule = next(it)
                key, sep, raw = rule.partition(":=")
                if not sep or not key:
                    raise ConfigError(f"-p {rule!r}: expected name:=value")
                node, _, name = key.rpartition(":")
                out.params.append((node or None, name, _yaml_value(raw)))
            elif a in ("-r", "--remap"):
                rule = next(it)
                key, sep, to = rule.partition(":=")
                if not sep or not key or not to:
                    raise ConfigError(f"-r {rule!r}: expected from:=to")
                if key.count(":") and not key.startswith("/"):
                    key = key.split(":", 1)[1]  # node-targeted remap; we have one node per process
                if key in ("__node", "__name"):
                    out.node_name = to
                elif key == "__ns":
                    out.namespace = to if to.startswith("/") else "/" + to
                else:
                    out.remaps["/" + key.lstrip("/")] = "/" + to.lstrip("/")
            elif a in _FLAGS_WITH_VALUE:
                next(it)
            elif a in _FLAGS or a.startswith("--enable-") or a.startswith("--disable-") or a.startswith("--log-level="):
                pass
            else:
                raise ConfigError(f"unknown ROS argument {a!r} after --ros-args")
        except StopIteration:
            raise ConfigError(f"ROS argument {a!r} needs a value") from None
    return out


def initial_parameters(group: str, ros_args: RosArgs, node_name: str | None = None,
                       strict: bool = True) -> dict[str, Any]:
    """Schema defaults <- params files <- ``-p`` overrides, validated; raises ConfigError.

    ``strict=False`` (several nodes in one process): a global ``-p name:=value``
    that this group does not declare is left to the other nodes, as rcl does.
    """
    if group not in SCHEMA.groups:
        raise ConfigError(f"unknown parameter group {group!r}; known: {', '.join(SCHEMA.groups)}")
    cfg = default_config()
    for path in ros_args.params_files:
        cfg = apply_overrides(cfg, params_from_tree(read_yaml(path), path), path)
    cli = {
        name: value
        for node, name, value in ros_args.params
        if node is None or node.rstrip("/").split("/")[-1] in (group, node_name)
    }
    if not strict:
        declared = {p.name for p in SCHEMA.groups[group]}
        cli = {k: v for k, v in cli.items() if k in declared}
    if cli:
        cfg = apply_overrides(cfg, {group: cli}, "-p")
    return dict(cfg[group])

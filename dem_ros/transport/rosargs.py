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
    """What ``--ros-args`` asked for.

    Rules may target one node (``-r controller:/dem/command:=/x``, ``-r controller:__node:=ctl``):
    several nodes of one process share the arguments and each applies the global rules
    and those naming it (:meth:`name_for`, :meth:`namespace_for`, :meth:`resolve`).
    """

    node_name: str | None = None  # global -r __node:=
    namespace: str | None = None  # global -r __ns:=
    params_files: list[str] = field(default_factory=list)
    params: list[tuple[str | None, str, Any]] = field(default_factory=list)  # (node or None, name, value)
    #: topic remap rules in command-line order, (node or None, from, to), absolute names
    remaps: list[tuple[str | None, str, str]] = field(default_factory=list)
    node_renames: dict[str, str] = field(default_factory=dict)  # node-targeted __node
    node_namespaces: dict[str, str] = field(default_factory=dict)  # node-targeted __ns
    user_args: list[str] = field(default_factory=list)

    def name_for(self, node: str) -> str:
        """The name node ``node`` gets: its own ``node:__node:=`` rule, else the global one, else ``node``."""
        return self.node_renames.get(node) or self.node_name or node

    def namespace_for(self, node: str) -> str:
        """The namespace of node ``node`` (``/`` unless a ``__ns`` rule applies to it)."""
        return self.node_namespaces.get(node) or self.namespace or "/"

    def resolve(self, topic_name: str, namespace: str = "/", node: str | None = None) -> str:
        """Absolute topic name for node ``node`` (relative names join ``namespace``) after the first
        remap rule that matches it: a global rule, or one targeting ``node``, as rcl applies them."""
        full = topic_name if topic_name.startswith("/") else namespace.rstrip("/") + "/" + topic_name
        for target, src, dst in self.remaps:
            if src == full and (target is None or target == node):
                return dst
        return full


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
                target: str | None = None
                if ":" in key and not key.startswith("/"):  # node-targeted: applies to that node only
                    target, key = key.split(":", 1)
                if key in ("__node", "__name"):
                    if target is None:
                        out.node_name = to
                    else:
                        out.node_renames[target] = to
                elif key == "__ns":
                    ns = to if to.startswith("/") else "/" + to
                    if target is None:
                        out.namespace = ns
                    else:
                        out.node_namespaces[target] = ns
                else:
                    out.remaps.append((target, "/" + key.lstrip("/"), "/" + to.lstrip("/")))
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

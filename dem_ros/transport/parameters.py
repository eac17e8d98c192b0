"""A node's parameters: declared from one schema group, changed only through one validation.

Every transport keeps its node's parameters in a :class:`ParameterStore`, so a
change is accepted or rejected by the same rules whatever carries it (the DDS
parameter services, rclpy's on-set callback, the in-memory transport):

1. every name must be declared by the node, not read-only, not undeclared (``None``);
2. the whole group with the change must pass :meth:`Schema.merged` (bounds, types,
   cross-field rules such as a Hurwitz error polynomial);
3. the node's ``on_change(new_values)`` may still refuse with a reason (an
   exception in it refuses too, and never reaches the middleware).

Only then are the values replaced, all at once.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..core.params import SCHEMA, ConfigError, ParamSpec
from .api import OnChange

__all__ = ["ParameterStore"]


class ParameterStore:
    """The validated parameter values of one node (one schema ``group``)."""

    def __init__(self, group: str, values: Mapping[str, Any], on_change: OnChange | None = None):
        self.group = group
        self.specs: dict[str, ParamSpec] = {p.name: p for p in SCHEMA.groups[group]}
        self._values = dict(values)
        self._on_change = on_change

    @property
    def values(self) -> dict[str, Any]:
        """Current values (a copy)."""
        return dict(self._values)

    def __contains__(self, name: str) -> bool:
        return name in self._values

    def __getitem__(self, name: str) -> Any:
        return self._values[name]

    def check(self, changes: Mapping[str, Any], who: str = "this node") -> tuple[dict[str, Any] | None, str | None]:
        """(new values, None) if ``changes`` would be accepted, else (None, reason). Changes nothing."""
        for name, value in changes.items():
            spec = self.specs.get(name)
            if spec is None:
                return None, f"parameter '{name}' is not declared by {who}"
            if spec.read_only:
                return None, f"parameter '{name}' cannot be set because it is read-only"
            if value is None:
                return None, f"parameter '{name}' cannot be undeclared"
        try:
            new = SCHEMA.merged(self.group, self._values, changes)
        except ConfigError as exc:
            return None, str(exc)
        if self._on_change is not None:
            try:
                reason = self._on_change(dict(new))
            except Exception as exc:  # a broken callback rejects, never kills the node
                reason = f"on_change raised {type(exc).__name__}: {exc}"
            if reason:
                return None, str(reason)
        return new, None

    def commit(self, new: Mapping[str, Any]) -> None:
        """Replace the values by ``new`` (from :meth:`check`)."""
        self._values = dict(new)

    def set(self, changes: Mapping[str, Any], who: str = "this node") -> str | None:
        """Apply ``changes`` atomically: ``None``, or the rejection reason (values unchanged)."""
        new, reason = self.check(changes, who)
        if new is not None:
            self.commit(new)
        return reason

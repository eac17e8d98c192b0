"""Conversions between Python values, ParamSpecs and rcl_interfaces parameter messages.

Written against the field names of ``rcl_interfaces/msg/ParameterValue`` and
friends, so they work with the DDS IDL classes and the rclpy message classes.
"""

from __future__ import annotations

import sys
from typing import Any

from ..core.params import ParamSpec

__all__ = [
    "BOOL",
    "BOOL_ARRAY",
    "BYTE_ARRAY",
    "DOUBLE",
    "DOUBLE_ARRAY",
    "INTEGER",
    "INTEGER_ARRAY",
    "NOT_SET",
    "STRING",
    "STRING_ARRAY",
    "describe",
    "descriptor_fields",
    "for_declared",
    "from_value_msg",
    "spec_type",
    "to_value_msg",
]

# rcl_interfaces/msg/ParameterType
NOT_SET, BOOL, INTEGER, DOUBLE, STRING = 0, 1, 2, 3, 4
BYTE_ARRAY, BOOL_ARRAY, INTEGER_ARRAY, DOUBLE_ARRAY, STRING_ARRAY = 5, 6, 7, 8, 9

_TYPE_OF = {bool: BOOL, int: INTEGER, float: DOUBLE, str: STRING}
_FIELD = {
    BOOL: "bool_value", INTEGER: "integer_value", DOUBLE: "double_value", STRING: "string_value",
    BYTE_ARRAY: "byte_array_value", BOOL_ARRAY: "bool_array_value", INTEGER_ARRAY: "integer_array_value",
    DOUBLE_ARRAY: "double_array_value", STRING_ARRAY: "string_array_value",
}


def spec_type(spec: ParamSpec) -> int:
    """ParameterType of a ParamSpec."""
    return _TYPE_OF[spec.type]


def python_type(value: Any) -> int:
    """ParameterType of a plain Python value."""
    if isinstance(value, bool):
        return BOOL
    if isinstance(value, int):
        return INTEGER
    if isinstance(value, float):
        return DOUBLE
    if isinstance(value, str):
        return STRING
    if isinstance(value, (list, tuple)):
        if all(isinstance(v, bool) for v in value):
            return BOOL_ARRAY
        if all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            return INTEGER_ARRAY
        if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            return DOUBLE_ARRAY
        if all(isinstance(v, str) for v in value):
            return STRING_ARRAY
    raise TypeError(f"cannot express {value!r} as a ROS parameter value")


def for_declared(ptype: int, value: Any) -> Any:
    """A value given to ``param set`` as the node's declared type ``ptype`` takes it: a command line's text parsed
    as YAML (unless the parameter is a string), an integer for a double as a float (rclpy refuses an INTEGER for a
    DOUBLE parameter)."""
    if isinstance(value, str) and ptype != STRING:
        import yaml

        value = yaml.safe_load(value)
    if ptype == DOUBLE and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    return value


def to_value_msg(value_cls: type, value: Any, ptype: int | None = None) -> Any:
    """Python value -> ParameterValue message (``ptype`` forces the type, e.g. DOUBLE for 60)."""
    ptype = python_type(value) if ptype is None else ptype
    msg = value_cls()
    msg.type = ptype
    if ptype == DOUBLE:
        value = float(value)
    elif ptype == DOUBLE_ARRAY:
        value = [float(v) for v in value]
    elif ptype in (BOOL_ARRAY, INTEGER_ARRAY, STRING_ARRAY, BYTE_ARRAY):
        value = list(value)
    if ptype != NOT_SET:
        setattr(msg, _FIELD[ptype], value)
    return msg


def from_value_msg(msg: Any) -> Any:
    """ParameterValue message -> Python value (None for NOT_SET).

    Raises:
        ValueError: a type that rcl_interfaces/msg/ParameterType does not define (the message says which).
    """
    t = int(msg.type)
    if t == NOT_SET:
        return None
    if t not in _FIELD:
        raise ValueError(f"parameter value type {t} is not a ROS parameter type (0..9)")
    v = getattr(msg, _FIELD[t])
    if t >= BYTE_ARRAY:
        return list(v)
    return v


def descriptor_fields(spec: ParamSpec) -> dict[str, Any]:
    """ParameterDescriptor content for a spec (ranges returned separately as tuples)."""
    unit = f" [{spec.unit}]" if spec.unit else ""
    constraints = spec.allowed()
    return {
        "name": spec.name,
        "type": spec_type(spec),
        "description": f"{spec.description}{unit}",
        "additional_constraints": constraints,
        "read_only": spec.read_only,
    }


def numeric_range(spec: ParamSpec) -> tuple[str, Any, Any] | None:
    """``("float"|"int", from, to)`` for bounded numeric specs, else None."""
    if spec.type not in (int, float) or (spec.min is None and spec.max is None):
        return None
    if spec.type is float:
        lo = -sys.float_info.max if spec.min is None else float(spec.min)
        hi = sys.float_info.max if spec.max is None else float(spec.max)
        return ("float", lo, hi)
    lo_i = -(2**63) if spec.min is None else int(spec.min)
    hi_i = 2**63 - 1 if spec.max is None else int(spec.max)
    return ("int", lo_i, hi_i)


def describe(spec: ParamSpec, descriptor_cls: type, frange_cls: type, irange_cls: type) -> Any:
    """A ParameterDescriptor message for ``spec`` (description, type, range, read_only)."""
    d = descriptor_cls()
    for k, v in descriptor_fields(spec).items():
        setattr(d, k, v)
    rng = numeric_range(spec)
    if rng is not None:
        kind, lo, hi = rng
        if kind == "float":
            d.floating_point_range = [frange_cls(from_value=lo, to_value=hi, step=0.0)]
        else:
            d.integer_range = [irange_cls(from_value=lo, to_value=hi, step=0)]
    return d

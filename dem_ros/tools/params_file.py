"""Render the parameter schema as a ROS 2 params file (``config/dem_ros.yaml``).

The file is generated from the schema, never edited by hand for defaults;
``tests`` check that the committed file and the schema agree.
"""

from __future__ import annotations

from ..core.params import SCHEMA

__all__ = ["render_params_file"]

HEADER = """\
# dem_ros parameters, ROS 2 params-file format (ros2 run ... --ros-args --params-file).
# Generated from the schema by `dem-ros config params`; every value here is the schema default.
# Copy this file and edit the copy to tune a rig; units are given for each parameter.
"""


def _yaml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, float):
        text = repr(v)
        if "e" in text and "." not in text.split("e")[0]:
            mant, exp = text.split("e")
            text = f"{mant}.0e{exp}"
        return text
    return str(v)


def render_params_file() -> str:
    lines = [HEADER]
    for group, specs in SCHEMA.groups.items():
        lines.append(f"{group}:")
        lines.append("  ros__parameters:")
        for p in specs:
            unit = f" [{p.unit}]" if p.unit else ""
            lines.append(f"    # {p.description}{unit}; {p.allowed()}")
            lines.append(f"    {p.name}: {_yaml_value(p.default)}")
        lines.append("")
    return "\n".join(lines)

"""Render the parameter schema as a ROS 2 params file (``config/dem_ros.yaml``).

The file is generated from the schema, never edited by hand for defaults;
``tests/tools/test_params_file.py`` checks that the committed file and the schema agree.
"""

from __future__ import annotations

from ..core.params import SCHEMA
from .common import yaml_scalar

__all__ = ["render_params_file"]

HEADER = """\
# dem_ros parameters, ROS 2 params-file format (ros2 run ... --ros-args --params-file).
# Generated from the schema by `dem-ros config params`; every value here is the schema default.
# Copy this file and edit the copy to tune a rig; units are given for each parameter.
"""


def render_params_file() -> str:
    lines = [HEADER]
    for group, specs in SCHEMA.groups.items():
        lines.append(f"{group}:")
        lines.append("  ros__parameters:")
        for p in specs:
            unit = f" [{p.unit}]" if p.unit else ""
            lines.append(f"    # {p.description}{unit}; {p.allowed()}")
            lines.append(f"    {p.name}: {yaml_scalar(p.default)}")
        lines.append("")
    return "\n".join(lines)

"""The Foxglove layout of the live view, built from the topic contract (``config/foxglove/dem_ros.json``).

Panels (tab "run"): the gaps d_j with the reference model's output y_m,j; the tracking error e_j; the coil
voltages u_j (applied) and currents i_j; the estimates m_hat, R_hat, K_hat; the loop's latency and
deadline misses (from its status on /diagnostics, turned into numbers by a user script); the board
mode (hw_driver's state); the diagnostics. Tab "operate": the parameters and hw_driver's services.

The vector indices come from :mod:`dem_ros.contract` (``REFERENCE_NAMES``, ``CONTROLLER_STATE_NAMES``),
so the layout follows the contract. ``python -m dem_ros.view.layout`` writes the file;
tests/tools/test_view.py checks the shipped file is what this module builds.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import foxglove.layouts as fl

from .. import contract
from .graph import HW_NODE, HW_SERVICES

__all__ = ["LAYOUT_FILE", "LOOP_SCRIPT_TOPIC", "build", "plot_paths", "render"]

LAYOUT_FILE = Path(__file__).resolve().parents[2] / "config" / "foxglove" / "dem_ros.json"
#: the user script's output: the loop status's numbers
LOOP_SCRIPT_TOPIC = "/studio_script/dem_loop"
LOOP_KEYS = ("deadline_misses", "latency_p50_us", "latency_p99_us")

_M, _REF, _CS = contract.MEASUREMENT.name, contract.REFERENCE.name, contract.CONTROLLER_STATE.name


def _series(path: str, label: str, *, stamp: bool = True) -> fl.PlotSeries:
    return fl.PlotSeries(value=path, label=label, enabled=True,
                         timestamp_method="headerStamp" if stamp else "receiveTime")


def _named(topic: str, names: tuple[str, ...], name: str) -> str:
    return f"{topic}.position[{names.index(name)}]"


def _plot(title: str, series: list[fl.PlotSeries], y_label: str) -> fl.PlotPanel:
    return fl.PlotPanel(title=title, config=fl.PlotConfig(paths=series, show_legend=True, y_axis_label=y_label,
                                                           x_axis_val="timestamp", time_window_mode="sliding",
                                                           following_view_width=10.0))


def _loop_script() -> str:
    names = json.dumps([contract.LOOP_STATUS, contract.HW_LOOP_STATUS])
    fields = "\n".join(f"      {k}: num(\"{k}\")," for k in LOOP_KEYS)
    return f"""// The loop's status on /diagnostics ({contract.LOOP_STATUS} | {contract.HW_LOOP_STATUS}) \
as numbers to plot.
import {{ Input }} from "./types";

export const inputs = ["{contract.DIAGNOSTICS.name}"];
export const output = "{LOOP_SCRIPT_TOPIC}";

type Output = {{ {"; ".join(f"{k}: number" for k in LOOP_KEYS)} }};

export default function script(event: Input<"{contract.DIAGNOSTICS.name}">): Output | undefined {{
  for (const s of event.message.status) {{
    if (!{names}.includes(s.name)) continue;
    const num = (key: string) => Number(s.values.find((kv) => kv.key === key)?.value ?? NaN);
    return {{
{fields}
    }};
  }}
  return undefined;
}}
"""


def build() -> fl.Layout:
    gaps = _plot("gaps d and reference y_m [m]", [
        _series(f"{_M}.position[0]", "d1"), _series(f"{_M}.position[1]", "d2"),
        _series(_named(_REF, contract.REFERENCE_NAMES, "y_1"), "y_m1"),
        _series(_named(_REF, contract.REFERENCE_NAMES, "y_2"), "y_m2")], "m")
    error = _plot("tracking error e [m]", [
        _series(_named(_CS, contract.CONTROLLER_STATE_NAMES, "e_1"), "e1"),
        _series(_named(_CS, contract.CONTROLLER_STATE_NAMES, "e_2"), "e2")], "m")
    volts = _plot("coil voltages u [V] (applied)", [
        _series(f"{contract.APPLIED.name}.effort[0]", "u1"), _series(f"{contract.APPLIED.name}.effort[1]", "u2")], "V")
    amps = _plot("coil currents i [A]", [
        _series(f"{_M}.effort[0]", "i1"), _series(f"{_M}.effort[1]", "i2")], "A")
    estimates = [_plot(f"{label} [{unit}]", [_series(_named(_CS, contract.CONTROLLER_STATE_NAMES, name), label)], unit)
                 for name, label, unit in (("m_hat", "m_hat", "kg"), ("R_hat", "R_hat", "ohm"),
                                           ("K_hat", "K_hat", "N m^2/A^2"))]
    latency = _plot("loop latency, sensor stamp -> command at the plant [us]", [
        _series(f"{LOOP_SCRIPT_TOPIC}.latency_p50_us", "p50", stamp=False),
        _series(f"{LOOP_SCRIPT_TOPIC}.latency_p99_us", "p99", stamp=False)], "us")
    misses = _plot("loop deadline misses (count)", [
        _series(f"{LOOP_SCRIPT_TOPIC}.deadline_misses", "misses", stamp=False)], "samples")
    board = fl.StateTransitionsPanel(title="board mode and driver state", config=fl.StateTransitionsConfig(paths=[
        fl.StateTransitionsSeries(value=f'{contract.HW_STATE.name}.values[:]{{key=="board_mode"}}.value',
                                  label="board mode", timestamp_method="receiveTime"),
        fl.StateTransitionsSeries(value=f"{contract.HW_STATE.name}.message", label="driver state",
                                  timestamp_method="receiveTime")], show_legend=True))
    diagnostics = fl.DiagnosticsSummaryPanel(title="diagnostics", config=fl.DiagnosticsSummaryConfig(
        topic_to_render=contract.DIAGNOSTICS.name, sort_by_level=True, seconds_until_stale=5.0))

    def row(*panels: object, proportions: tuple[float, ...] | None = None) -> fl.SplitContainer:
        props = proportions or (1.0,) * len(panels)
        return fl.SplitContainer(direction="row", items=[fl.SplitItem(content=p, proportion=w)  # type: ignore[arg-type]
                                                         for p, w in zip(panels, props, strict=True)])

    def column(*panels: object) -> fl.SplitContainer:
        return fl.SplitContainer(direction="column", items=[fl.SplitItem(content=p) for p in panels])  # type: ignore[arg-type]

    run = column(row(gaps, error), row(volts, amps, column(*estimates)),
                 row(column(latency, misses), board, diagnostics))
    services = [fl.ServiceCallPanel(title=f"hw_driver {verb}", config=fl.ServiceCallConfig(
        service_name=f"{HW_NODE}/{verb}", request_payload="{}", button_text=verb, timeout_seconds=5.0))
        for verb in HW_SERVICES]
    operate = row(fl.ParametersPanel(title="parameters (/node.name)"), column(*services), proportions=(2.0, 1.0))
    return fl.Layout(content=fl.TabContainer(tabs=[fl.TabItem(title="run", content=run),
                                                   fl.TabItem(title="operate", content=operate)]),
                     user_scripts={"dem_loop": fl.UserScript(name="dem_ros loop status", source_code=_loop_script())})


def render() -> str:
    """The layout file's text (indented JSON)."""
    return json.dumps(json.loads(build().to_json()), indent=2, ensure_ascii=False) + "\n"


def plot_paths(layout: dict) -> list[str]:
    """Every message path (``value``) of the plot and state-transition series in a layout's JSON."""
    out: list[str] = []

    def walk(x: object) -> None:
        if isinstance(x, dict):
            for k, v in x.items():
                if k == "paths" and isinstance(v, list):
                    out.extend(s["value"] for s in v if isinstance(s, dict) and "value" in s)
                else:
                    walk(v)
        elif isinstance(x, list):
            for v in x:
                walk(v)

    walk(layout)
    return out


if __name__ == "__main__":  # pragma: no cover
    LAYOUT_FILE.parent.mkdir(parents=True, exist_ok=True)
    LAYOUT_FILE.write_text(render())
    print(f"written {LAYOUT_FILE}", file=sys.stderr)

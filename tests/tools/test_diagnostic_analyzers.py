"""config/diagnostic_analyzers.yaml (diagnostic_aggregator's params file) takes every status dem_ros publishes:
each by the analyzer of its node, the 1 kHz topics' statuses also by "streams"; matched as diagnostic_aggregator's
GenericAnalyzer matches (``startswith``, ``contains`` on the status name)."""

from __future__ import annotations

from pathlib import Path

import yaml
from loop_writers import STREAMS

from dem_ros import contract

CONFIG = Path(__file__).resolve().parents[2] / "config" / "diagnostic_analyzers.yaml"
GENERIC, GROUP = "diagnostic_aggregator/GenericAnalyzer", "diagnostic_aggregator/AnalyzerGroup"
#: the nodes with loop inputs bound to their writers (nodes/common.Inputs: "<node>: inputs")
WITH_INPUTS = ("plant_sim", "hw_driver", "estimator", "controller", "reference")


def _matches(analyzer: dict, name: str) -> bool:
    return (any(name.startswith(p) for p in analyzer.get("startswith", ()))
            or any(c in name for c in analyzer.get("contains", ())))


def _every_status() -> list[str]:
    names = [contract.LOOP_STATUS, contract.HW_LOOP_STATUS, contract.HW_STATE_STATUS, contract.ESTIMATOR_STATUS,
             contract.CONTROLLER_STATUS, contract.REFERENCE_STATUS, contract.RECORDING_STATUS,
             contract.HW_RECORDING_STATUS, contract.RECORDER_STATUS]
    names += [contract.inputs_status(n) for n in WITH_INPUTS]
    names += [contract.topic_status(n, t.name) for n, topics in STREAMS.items() for t in topics]
    return names


def test_the_params_file_is_the_ros2_aggregators():
    params = yaml.safe_load(CONFIG.read_text())["analyzers"]["ros__parameters"]  # the node is named "analyzers"
    assert params["path"] == "dem_ros"
    assert params["nodes"]["type"] == GROUP and params["streams"]["type"] == GENERIC
    for name, a in params["nodes"]["analyzers"].items():
        assert a["type"] == GENERIC and a["path"] == name and a["startswith"] == [f"{name}: "], a
        assert a["remove_prefix"] == [name]


def test_every_status_has_its_nodes_analyzer_and_the_streams_take_the_topic_statuses():
    params = yaml.safe_load(CONFIG.read_text())["analyzers"]["ros__parameters"]
    per_node = params["nodes"]["analyzers"]
    for name in _every_status():
        node = name.split(": ", 1)[0]
        assert [n for n, a in per_node.items() if _matches(a, name)] == [node], name
        assert _matches(params["streams"], name) == name.endswith(contract.TOPIC_STATUS_SUFFIX), name

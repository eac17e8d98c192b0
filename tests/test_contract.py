"""The topic contract: the manual's table is the contract's own (one fact in one place)."""

from pathlib import Path

from dem_ros import contract

DOC = Path(__file__).resolve().parents[1] / "docs" / "manual" / "topics.md"


def test_manual_table_is_generated_from_the_contract():
    text = DOC.read_text()
    start = (text.index("<!-- generated: contract.markdown_table() -->\n")
             + len("<!-- generated: contract.markdown_table() -->\n"))
    end = text.index("<!-- end generated -->")
    assert text[start:end] == contract.markdown_table(), "regenerate docs/manual/topics.md from dem_ros/contract.py"


def test_every_topic_is_a_row_and_every_name_is_unique():
    table = contract.markdown_table()
    names = [t.name for t in contract.TOPICS]
    assert len(names) == len(set(names))
    for n in names:
        assert f"| `{n}` |" in table
    assert table.count("\n") == len(names) + 2


def test_status_names_are_node_colon_task_and_former_names_map_to_them():
    import re

    names = [contract.LOOP_STATUS, contract.HW_LOOP_STATUS, contract.HW_STATE_STATUS, contract.ESTIMATOR_STATUS,
             contract.CONTROLLER_STATUS, contract.REFERENCE_STATUS, contract.RECORDING_STATUS,
             contract.HW_RECORDING_STATUS, contract.RECORDER_STATUS, contract.inputs_status("controller")]
    assert len(set(names)) == len(names)
    assert all(re.fullmatch(r"[a-z_]+: .+", n) for n in names), names
    assert contract.status_name("controller") == contract.CONTROLLER_STATUS  # a bag recorded before
    assert contract.status_name("recording") == contract.RECORDING_STATUS == "plant_sim: recording"
    assert contract.status_name("reference: recording") == contract.RECORDING_STATUS  # the watch left the reference
    assert contract.HW_RECORDING_STATUS == "hw_driver: recording"
    assert contract.status_name(contract.LOOP_STATUS) == contract.LOOP_STATUS  # the names now are themselves
    assert contract.status_name("plant_sim: inputs") == "plant_sim: inputs"

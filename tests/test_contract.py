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

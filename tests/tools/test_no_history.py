"""No history in code or tests: dates and machine loads belong in commit messages and docs/results.md.

A figure measured on a given day at a given load ages the moment the code changes; in a comment, a docstring,
a test name or a skip reason nobody updates it. Code says why (the mechanism); docs/results.md says what was
measured, when, at which commit, machine and load.
"""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: a calendar date (2026-11-27) or a machine load ("at load 17", "load 7-15", "(load 3.2)")
HISTORY = re.compile(r"\b20\d\d-[01]\d-[0-3]\d\b|\bat load \d|\bload \d+(\.\d+)?\s*-\s*\d|\(load \d")


def _sources():
    for top in ("dem_ros", "tests", "firmware", "launch"):
        for p in sorted((ROOT / top).rglob("*")):
            if p.suffix in (".py", ".c", ".h") and p.name != Path(__file__).name:
                yield p


def test_no_dates_or_loads_in_code_docstrings_tests_or_skip_reasons():
    found = [f"{p.relative_to(ROOT)}:{i}: {line.strip()}"
             for p in _sources() for i, line in enumerate(p.read_text(errors="replace").splitlines(), 1)
             if HISTORY.search(line)]
    assert not found, "history in the code (move it to docs/results.md or the commit message):\n" + "\n".join(found)


def test_the_pattern_finds_what_it_is_for():
    assert HISTORY.search("# measured at load 17: 9 rounds") and HISTORY.search("took 162 s (load 3.2)")
    assert HISTORY.search("at 2026-11-24 the probe") and HISTORY.search("2-3 minutes at load 10-25")
    assert not HISTORY.search("the board's load point") and not HISTORY.search("load_params(path)")

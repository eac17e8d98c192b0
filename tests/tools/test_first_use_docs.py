"""What a new user reads works: the README's and the manual's commands parse, and every link stays in the repository.

The commands are checked with the real ``dem-ros`` parser (argument names, choices, value checks), not run:
running each is the graph and CLI tests' job. A documented command the parser rejects (the manual said
``dem-ros config schema estimator`` before the command took a group) fails here.
"""

import re
import shlex
from pathlib import Path

import pytest

from dem_ros.tools.cli import build_parser

ROOT = Path(__file__).resolve().parents[2]
DOCS = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])
#: placeholders and alternatives in prose ("NAME", "get|set", "[REASON]", "...") are not commands to parse
_PLACEHOLDER = re.compile(r"\.\.\.|\||\[|\]|\b[A-Z][A-Z_]{2,}\b|<|>")


def _doc_commands() -> list[tuple[str, str, str]]:
    """(file, command, "block" | "inline") for each ``dem-ros ...`` line of a code block or inline code span.

    Continuation lines are joined. A code block shows whole commands; an inline span may name one
    without its required arguments (``dem-ros replay`` in a sentence).
    """
    out = []
    for md in DOCS:
        text = md.read_text().replace("\\\n", " ")
        blocks = re.findall(r"```[a-z]*\n(.*?)```", text, re.S)
        inline = re.findall(r"`([^`\n]+)`", re.sub(r"```.*?```", "", text, flags=re.S))
        for kind, span in [("block", b) for b in blocks] + [("inline", i) for i in inline]:
            for line in span.splitlines():
                m = re.search(r"(?:^|\s)(?:\.venv/bin/)?dem-ros\s+(.*)", line)
                if m is None:
                    continue
                cmd = m.group(1).split("#")[0].strip()
                if cmd and not _PLACEHOLDER.search(cmd):
                    out.append((str(md.relative_to(ROOT)), cmd, kind))
    return sorted(set(out))


COMMANDS = _doc_commands()


def test_the_docs_show_commands():
    assert len(COMMANDS) >= 30, COMMANDS  # the extraction itself works
    assert {c.split()[0] for _, c, _ in COMMANDS} >= {"sim", "launch", "replay", "report", "study", "bag",
                                                      "config", "hw"}


@pytest.mark.parametrize(("doc", "cmd", "kind"), COMMANDS, ids=[f"{d}: {c}"[:80] for d, c, _ in COMMANDS])
def test_a_documented_command_parses(doc, cmd, kind, monkeypatch, capsys):
    monkeypatch.chdir(ROOT)  # relative paths (bags/sample_S1, config/dem_ros.yaml) as the docs mean them
    try:
        build_parser().parse_args(shlex.split(cmd))
    except SystemExit as exc:
        err = capsys.readouterr().err.strip()
        if exc.code and not (kind == "inline" and "the following arguments are required" in err):  # --help: 0
            pytest.fail(f"{doc}: `dem-ros {cmd}` is rejected: {err}")


def test_no_link_points_outside_the_repository():
    bad = []
    for md in DOCS:
        for href in re.findall(r"\]\(([^)\s]+)\)", md.read_text()):
            path = href.split("#")[0]
            if not path or re.match(r"[a-z]+:", path):  # an anchor, or a web address
                continue
            target = (md.parent / path).resolve()
            if not target.is_relative_to(ROOT) or not target.exists():
                bad.append(f"{md.relative_to(ROOT)}: {href}")
    assert not bad, bad


def test_no_file_names_a_path_of_the_machine_it_was_written_on():
    hits = []
    for f in [*DOCS, *(ROOT / "dem_ros").rglob("*.py"), ROOT / "Makefile", *(ROOT / "config").glob("*.yaml")]:
        for n, line in enumerate(f.read_text(errors="replace").splitlines(), 1):
            if re.search(r"/work/|\.\./shared/|\bnotes? [0-9]", line):
                hits.append(f"{f.relative_to(ROOT)}:{n}: {line.strip()[:100]}")
    assert not hits, hits

"""BENCHMARKS.md is a curated page (issue 32): under 400 lines, every section's figures carry the command that
reproduces them, and every benchmark script it names exists."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: the page's length limit (issue 32: "BENCHMARKS.md is under 400 lines")
MAX_LINES = 400
#: what counts as a command in backticks: a script, the CLI, pytest, or the CI script (with an optional prefix)
COMMAND = re.compile(r"`(?:[A-Z_]+=\S+ )*(?:/usr/bin/time |taskset -c \S+ )?(?:python\s|metafovea\s|\.ci/run)")


def page_problems(text: str, repo: Path = REPO) -> list[str]:
    """What keeps ``text`` from being the curated page: too long, a section with figures but no command, a named
    benchmark script that does not exist."""
    problems = []
    n = text.count("\n") + (not text.endswith("\n"))
    if n >= MAX_LINES:
        problems.append(f"{n} lines (the page must stay under {MAX_LINES}; history lives in git)")
    parts = re.split(r"(?m)^(#{2,4} .*)$", text)
    for head, body in zip(parts[1::2], parts[2::2]):
        has_figures = re.search(r"\d\.\d|\d+ s\b|\d %", body) is not None
        if has_figures and not (COMMAND.search(body) or COMMAND.search(head)):
            problems.append(f"section {head.strip()!r} has figures but no command that reproduces them")
    for script in sorted(set(re.findall(r"benchmarks/(\w+\.py)", text))):
        if not (repo / "benchmarks" / script).is_file():
            problems.append(f"benchmarks/{script} is named but does not exist")
    return problems


def test_the_page_is_curated():
    problems = page_problems((REPO / "BENCHMARKS.md").read_text())
    assert not problems, "\n".join(problems)


def test_the_check_fails_on_a_long_page_a_figure_without_command_and_a_missing_script():
    ok = "## A stage\n\n`python benchmarks/bench_rcwa.py`: 0.026 s\n"
    assert page_problems(ok) == []
    assert any("lines" in p for p in page_problems(ok + "x\n" * MAX_LINES))
    assert any("no command" in p for p in page_problems("## A stage\n\nour solver took 0.026 s\n"))
    assert any("does not exist" in p for p in page_problems("## A\n\n`python benchmarks/bench_nothing.py`: 1.5 s\n"))

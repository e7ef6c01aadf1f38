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


#: one process asks every benchmark script for its usage (``--help``), each through ``runpy`` as ``__main__``
_HELP_ALL = r"""
import contextlib, io, runpy, sys
for s in sys.argv[1:]:
    sys.argv = [s, "--help"]
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out):
            runpy.run_path(s, run_name="__main__")
        print(f"{s}: ran instead of printing its usage")
    except SystemExit as e:
        if e.code not in (0, None) or "usage:" not in out.getvalue():
            print(f"{s}: exit {e.code}, no usage")
    except Exception as e:
        print(f"{s}: {type(e).__name__}: {e}")
"""


def help_problems(scripts: list[Path]) -> list[str]:
    """The scripts among ``scripts`` whose ``--help`` does not print a usage and exit 0 (a crash in a help
    string's formatting, or a script that runs its benchmark whatever its arguments)."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-c", _HELP_ALL, *map(str, scripts)], cwd=REPO, capture_output=True,
                       text=True, timeout=300)
    return [ln for ln in r.stdout.splitlines() if ln.strip()] + ([r.stderr[-500:]] if r.returncode else [])


def test_every_benchmark_script_prints_its_usage(tmp_path):
    assert help_problems(sorted((REPO / "benchmarks").glob("*.py"))) == []
    # a help string that %-formatting breaks, and a script with no argument parser, are both caught
    bad = tmp_path / "bench_bad.py"
    bad.write_text("import argparse\nap = argparse.ArgumentParser()\nap.add_argument('--x', help='20 %, 3 %')\n"
                   "ap.parse_args()\n")
    runs = tmp_path / "bench_runs.py"
    runs.write_text("print('benchmarking')\n")
    found = help_problems([bad, runs])
    assert len(found) == 2 and "ValueError" in found[0] and "ran instead" in found[1]

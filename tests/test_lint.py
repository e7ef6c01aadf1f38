"""The linter as a test: ``ruff check`` over the repository (the package, tests, benchmarks and notebooks) with
the configuration in pyproject.toml, so that CI runs it with the rest of the suite."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _ruff(*args: str, cwd: Path = REPO) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ruff", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=300)


@pytest.fixture(scope="module")
def ruff_installed() -> None:
    if importlib.util.find_spec("ruff") is None:
        pytest.skip("ruff is not installed (pip install -e '.[test]')")


def test_ruff_check_passes(ruff_installed):
    """``ruff check`` finds nothing anywhere in the repository."""
    r = _ruff("check", "--no-cache", "--output-format", "concise", str(REPO))
    assert r.returncode == 0, f"ruff check found problems:\n{r.stdout}{r.stderr}"


def test_ruff_check_can_fail(ruff_installed, tmp_path):
    """The same command, with the repository's configuration, fails on a planted file (a long line, two statements
    on a line, a lambda assigned to a name)."""
    (tmp_path / "pyproject.toml").write_text((REPO / "pyproject.toml").read_text())
    bad = tmp_path / "planted.py"
    bad.write_text("x = 1; y = 2\nf = lambda v: v\nz = '" + "a" * 130 + "'\n")
    r = _ruff("check", "--no-cache", "--output-format", "concise", str(tmp_path), cwd=tmp_path)
    assert r.returncode == 1, r.stdout + r.stderr
    for code in ("E702", "E731", "E501"):
        assert code in r.stdout, (code, r.stdout)

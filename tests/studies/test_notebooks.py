"""The notebooks (jupytext percent scripts in notebooks/) run from top to bottom at small size; an error in any
cell fails the test. Executed as plain scripts (runpy): the percent format is valid Python, and neither jupytext
nor a Jupyter kernel is needed in CI. ~10 s each on 2 cores."""

from __future__ import annotations

import runpy
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[2] / "notebooks").glob("[0-9][0-9]_*.py"))


def test_there_are_notebooks():
    names = [p.name for p in NOTEBOOKS]
    assert {"01_whole_chain.py", "02_study_frames.py", "03_recording.py"} <= set(names)


@pytest.mark.slow  # each notebook runs its study at a small size (METAFOVEA_NOTEBOOK_SMALL)
@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_runs(path, tmp_path, monkeypatch):
    monkeypatch.setenv("METAFOVEA_NOTEBOOK_SMALL", "1")
    monkeypatch.setenv("METAFOVEA_NOTEBOOK_OUT", str(tmp_path))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    text = path.read_text()
    assert text.startswith("# ---") and "# %%" in text  # jupytext percent format
    runpy.run_path(str(path), run_name="__main__")
    assert any(tmp_path.rglob("*.png"))

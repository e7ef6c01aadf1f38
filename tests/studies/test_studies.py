"""The paper's studies at --fast size: each writes its figure, JSON and HTML, and shows the paper's trend or says
why not; the same seed gives the same JSON; bad input is one line and exit status 2.

Budget (2 cores): focal-ratio ~27 s, frames ~12 s, realtime ~9 s (twice, for the same-seed check)."""

from __future__ import annotations

import json

import pytest

from metafovea.cli import main
from metafovea.studies import STUDIES, StudyOptions, run_study

#: with --fast a study's cases run in the command's own process unless --workers says otherwise: at the fast sizes
#: cheaper than worker processes that each import and compile the solvers again (the same JSON either way:
#: tests/parallel/test_dask.py). The frames study runs in two worker processes, so that path still runs
PROCESSES = ("--workers", "2")


def _run_cli(name: str, out, capsys, *flags: str) -> dict:
    rc = main(["study", name, "--fast", "--out", str(out), "-q", *flags])
    assert rc == 0
    printed = capsys.readouterr().out
    assert f"study {name}" in printed and "paper:" in printed
    for suffix in ("json", "png", "html"):
        f = out / f"{name}.{suffix}"
        assert f.is_file() and f.stat().st_size > 200, f
    html = (out / f"{name}.html").read_text()
    assert "What was modelled" in html and "Why" in html and "data:image/png;base64" in html
    rep = json.loads((out / f"{name}.json").read_text())
    assert rep["study"] == name and rep["modelled"] and rep["why"] and rep["paper"]
    assert {"expected", "observed", "holds"} <= set(rep["trend"])
    assert "nproc" in rep["timing"] and "load_average" in rep["timing"]
    return rep


@pytest.mark.slow  # a study, at its --fast size
def test_focal_ratio_fast(tmp_path, capsys):
    """Foveal PSNR nearly flat over the expansion (the paper's trend); the perifoveal one falls in the paper and, in
    this classical per-pixel model, does not: then the note says why and the texture per pixel it names grows."""
    rep = _run_cli("focal-ratio", tmp_path / "fr", capsys)
    assert rep["timing"]["workers"] == 1  # --fast without --workers: this process
    by_k = rep["results"]["by_expansion"]
    ks = sorted(by_k, key=float)
    p1 = [by_k[k]["alternating"]["psnr_x1"] for k in ks]
    assert max(p1) - min(p1) < 1.5  # foveal: flat
    assert by_k[ks[-1]]["texture_x2"] > by_k[ks[0]]["texture_x2"]  # the perifoveal texture grows with f1/f2
    assert by_k[ks[-1]]["texture_x1"] == pytest.approx(by_k[ks[0]]["texture_x1"], rel=0.02)  # the fovea's does not
    if not rep["trend"]["holds"]:
        assert "deep-prior" in rep["trend"]["note"]


@pytest.mark.slow  # a study, at its --fast size
def test_frames_fast(tmp_path, capsys):
    """4 frames leave alpha unidentified (channels mixed), the best window is 8-12 frames, longer ones blur."""
    rep = _run_cli("frames", tmp_path / "fm", capsys, *PROCESSES)
    rows = {r["window"]: r for r in rep["results"]["windows"]}
    assert rows[4]["alternating"]["alpha_mae"] > 10 * rows[8]["alternating"]["alpha_mae"]
    assert rep["trend"]["holds"] and 8 <= rep["trend"]["best_window"] <= 12
    assert rows[24]["alternating"]["psnr_x2"] < rows[8]["alternating"]["psnr_x2"] - 1.0  # motion blur


@pytest.mark.slow  # a study, at its --fast size
def test_realtime_fast_and_same_seed_same_json(tmp_path, capsys):
    """Least squares is far faster than the unknown-alpha solver at a similar error; a second run with the same
    seed gives the same JSON apart from its 'timing' key."""
    rep = _run_cli("realtime", tmp_path / "rt", capsys)
    speed = rep["timing"]["speed"]
    assert speed["lsq"]["fps"] > 5 * speed["alternating"]["fps"]
    assert rep["trend"]["holds"]
    again = run_study("realtime", StudyOptions(fast=True, seed=0)).to_json()

    def strip(r):
        return {k: v for k, v in r.items() if k != "timing"}

    assert json.dumps(strip(json.loads(json.dumps(again))), sort_keys=True) == \
        json.dumps(strip(rep), sort_keys=True)


@pytest.mark.parametrize("argv, flag", [
    (["study", "no-such-study"], "study"),
    (["study", "frames", "--seed", "minus-one"], "--seed"),
    (["study", "frames", "--seed", "-3"], "--seed"),
    (["study"], "NAME"),
])
def test_bad_input_is_one_line_exit_2(argv, flag, tmp_path, capsys):
    rc = main([*argv, "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert len(err.splitlines()) == 1 and flag in err
    assert not (tmp_path / "o").exists()


def test_list_names_every_study(capsys):
    assert main(["study", "--list"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in STUDIES)

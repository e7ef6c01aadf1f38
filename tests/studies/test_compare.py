"""``metafovea study compare`` at --fast size: its files, the paper's trend on a picture with detail at the foveal
sampling (this camera's foveal PSNR the best of the four at equal sensor and frames), and the note's account of
the full-field picture, where single-image SR wins because the fovea sees no detail beyond the wide sampling.

Budget (2 cores): ~10 s."""

from __future__ import annotations

import json

import pytest

from metafovea.studies import StudyOptions, compare
from metafovea.studies.common import write_study


@pytest.mark.slow  # a study, at its --fast size
def test_compare_fast(tmp_path):
    res = compare.run(StudyOptions(fast=True, seed=0))
    files = write_study(res, tmp_path / "cmp")
    for key in ("json", "figure", "html"):
        assert files[key].is_file() and files[key].stat().st_size > 200
    html = files["html"].read_text()
    assert "What was modelled" in html and "Why" in html and "data:image/png;base64" in html
    rep = json.loads(files["json"].read_text())
    assert rep["study"] == "compare" and rep["modelled"] and rep["why"] and rep["paper"]
    assert {"expected", "observed", "holds", "note"} <= set(rep["trend"])
    assert "nproc" in rep["timing"] and "load_average" in rep["timing"]
    fine, coarse = rep["results"]["by_fill"]["fill_0.333"], rep["results"]["by_fill"]["fill_1"]
    pf = {m: fine[m]["psnr_fovea"] for m in compare.METHODS}
    # the paper's trend: this camera's foveal detail beats side by side, Risley (same frames) and single-image SR
    assert rep["trend"]["holds"] and max(pf, key=pf.get) == "multiplexed"
    assert pf["multiplexed"] > pf["single_image_sr"] + 3.0  # SR cannot add detail beyond the wide sampling
    # the full-field picture: the note names single-image SR's win and its cause, and the numbers agree
    if rep["trend"]["best_foveal_full_field_picture"] != "multiplexed":
        assert "little detail beyond the wide sampling" in rep["trend"]["note"]
        assert coarse["single_image_sr"]["ssim_fovea"] > fine["single_image_sr"]["ssim_fovea"] - 0.1
        assert coarse["single_image_sr"]["psnr_fovea"] > coarse["multiplexed"]["psnr_fovea"]
    # every design integrates the same frames
    assert {fine[m]["frames_per_output"] for m in compare.METHODS} == {10}

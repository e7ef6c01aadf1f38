"""``metafovea study ablation --fast``: each reconstruction component removed in turn on one measurement (paper
point 5), and the same rows again from the same seed."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from metafovea.studies import StudyOptions, run_study
from metafovea.studies.ablation import FAST, FILTER, MULTI, QUANTITIES, SNAP, run_multi
from metafovea.studies.common import Stopwatch, rounded, simulated


def _finite(rows: list[dict]) -> bool:
    return all(math.isfinite(r[q]) and math.isfinite(r[f"delta_{q}"]) for r in rows for q in QUANTITIES)


@pytest.mark.slow  # a study: at its --fast size (64 x 64, DIP budgets of 30 and 60 steps), run twice
def test_ablation_fast_rows_physics_and_same_seed_same_json(tmp_path):
    res = run_study("ablation", StudyOptions(fast=True, seed=0), tmp_path / "abl")
    for suffix in ("json", "png", "html"):
        f = tmp_path / "abl" / f"ablation.{suffix}"
        assert f.is_file() and f.stat().st_size > 200, f
    html = (tmp_path / "abl" / "ablation.html").read_text()
    assert "What was modelled" in html and "data:image/png;base64" in html
    rep = json.loads((tmp_path / "abl" / "ablation.json").read_text())
    assert {"expected", "observed", "holds", "note"} <= set(rep["trend"])
    assert "single deep prior" in rep["modelled"] and "--fast" in rep["why"]
    assert "nproc" in rep["timing"] and "load_average" in rep["timing"]

    multi = {r["variant"]: r for r in rep["results"]["multi_frame"]}
    snap = {r["variant"]: r for r in rep["results"]["snapshot"]}
    assert list(multi) == list(MULTI) and list(snap) == list(SNAP)
    assert _finite(rep["results"]["multi_frame"]) and _finite(rep["results"]["snapshot"])
    assert multi["full"]["delta_psnr_x1"] == 0.0 and snap["full"]["delta_psnr_x2"] == 0.0
    assert all(math.isfinite(r["alpha_mae"]) for r in multi.values())
    assert set(rep["trend"]["component_helps"]) == {f"multi-frame {k}" for k in list(MULTI)[1:]} | {
        f"snapshot {k}" for k in list(SNAP)[1:]}

    # the fixed pattern (std ~23 DN on this crop) is larger than the foveal scene's whole range (~33 DN): left in,
    # it swamps the foveal image and also costs the perifoveal one
    assert multi["full"]["psnr_x1"] > multi["fpn_off"]["psnr_x1"] + 10.0
    assert multi["full"]["psnr_x2"] > multi["fpn_off"]["psnr_x2"] + 5.0
    # the TV prior lowers the foveal noise against plain least squares in the same gauge
    assert multi["tv_only"]["psnr_x1"] > multi["no_prior"]["psnr_x1"] + 0.5
    # frame-mean alpha labels the brighter (perifoveal, F/1) frames foveal: the swapped start, kept by the DIP loss
    assert multi["alpha_frame_means"]["alpha_mae"] > 0.3 > 0.01 > multi["full"]["alpha_mae"]
    # the snapshot's n1 = D^T y start beats the unseparated frame on both images
    assert snap["init_frame"]["psnr_x1"] < snap["full"]["psnr_x1"] - 1.0
    assert snap["init_frame"]["psnr_x2"] < snap["full"]["psnr_x2"] - 1.0
    # alternating's alpha, held by the warm-started DIP, enters its loss as estimated (no clip to [0.02, 0.98]): the
    # DIP's alpha error is the classical estimate's
    assert abs(multi["full"]["alpha_mae"] - multi["tv_only"]["alpha_mae"]) < 1e-6
    # the warm start keeps the classical estimate: in its steps the DIP moves its images from the TV prior alone's by a
    # small part of that estimate's error, so the deep prior's row is within 0.1 dB of TV alone (the note's evidence)
    ev = rep["results"]["warm_start_evidence"]
    assert all(ev[f"rms_dip_minus_tv_{x}"] < 0.1 * ev[f"rms_error_tv_{x}"] for x in ("x1", "x2"))
    assert abs(multi["tv_only"]["delta_psnr_x1"]) < 0.1 and abs(multi["tv_only"]["delta_psnr_x2"]) < 0.1
    # the random network start gets the DIP's data-driven TV weight (no longer 0); the warm starts keep 0.001
    assert multi["random_start"]["dip_tv_weight"] > 0 and multi["full"]["dip_tv_weight"] == 0.001

    # the same seed, the same rows: the measurement again and the full method's row (the DIP, warm-started) again,
    # rounded as the JSON holds them (the whole study twice took ~20 s more for the same check)
    meas, fpn = simulated(StudyOptions(fast=True, seed=0), FAST, Stopwatch(), FILTER)
    frame = int(np.argmin(np.abs(np.asarray(meas.alpha) - 0.5)))
    again = run_multi({"measurement": meas, "fpn": fpn, "p": FAST, "seed": 0, "frame": frame, "key": "full"})
    for q in QUANTITIES + ("alpha_mae",):
        assert rounded(again[q]) == multi["full"][q], q
    assert res.name == "ablation"

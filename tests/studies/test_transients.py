"""``metafovea study transients --fast``: the coil heater on for 5 s (paper point 6). ~12 s on 2 cores."""

from __future__ import annotations

import json

import numpy as np
import pytest

from metafovea.studies import STUDIES, StudyOptions, write_study
from metafovea.studies.transients import compare_series, pick_points, run


def test_pick_points_on_near_and_far():
    """On the wire's hottest pixel, near = 3-4 px off the wire's mask, indirect = the pixel farthest from it."""
    before = np.zeros((40, 40))
    peak = before.copy()
    peak[20, 5:35] = 100.0
    peak[20, 20] = 120.0
    pts = pick_points(peak, before, 3)
    assert pts["on_coil"] == (20, 20)
    assert abs(pts["near"][0] - 20) == 3 and pts["near"][1] == 20
    assert pts["indirect"][0] in (0, 39) and pts["wire_pixels"] == 30


def test_compare_series_against_a_known_error():
    t = np.linspace(0.0, 1.0, 50)
    truth = 100.0 + 200.0 * t
    c = compare_series(100.0 + 180.0 * t, truth)
    assert abs(c["peak_ratio"] - 0.9) < 1e-12 and c["correlation"] > 0.999999
    assert abs(c["rms_dn"] - np.sqrt(np.mean((20.0 * t) ** 2))) < 1e-9
    assert compare_series(truth[:1].repeat(50) + 0.1 * t, truth[:1].repeat(50))["peak_ratio"] is None


@pytest.mark.slow  # a study, at its --fast size
def test_transients_fast(tmp_path):
    """Both reconstructions follow the heating and cooling of the coil (correlation > 0.9, peak within 5 %); the
    foveal grid samples the wire finer; where the foveal peak is not closer to its truth, the note says why."""
    res = run(StudyOptions(fast=True))
    files = write_study(res, tmp_path / "tr")
    for key in ("json", "figure", "html"):
        assert files[key].is_file() and files[key].stat().st_size > 200
    html = files["html"].read_text()
    assert "What was modelled" in html and "data:image/png;base64" in html
    rep = json.loads(files["json"].read_text())
    assert rep["modelled"] and rep["why"] and "--fast" in rep["why"] and rep["paper"]
    assert {"expected", "observed", "holds", "note"} <= set(rep["trend"])
    assert rep["trend"]["holds"] and rep["trend"]["follows_transients"]
    (row,) = rep["results"]["scenes"]
    assert row["scene"] == "heater-5s" and row["seconds"] >= 1 + 5 + 2 * 4 - 0.1  # heating and cooling fit
    for ch in ("foveal", "perifoveal"):
        on = row[ch]["on_coil"]
        assert on["correlation"] > 0.9 and abs(on["peak_ratio"] - 1.0) < 0.05
        assert on["rms_dn"] < 0.05 * on["truth_rise_dn"]
        assert row[ch]["near"]["truth_rise_dn"] < on["truth_rise_dn"]
    assert row["foveal"]["wire_pixels"] > 3 * row["perifoveal"]["wire_pixels"]
    if not rep["trend"]["foveal_peak_closer"]:
        assert "common scene-referred scale" in rep["trend"]["note"]
    if "transients" in STUDIES:  # registered: the CLI's word reaches this module
        assert STUDIES["transients"][0] == "transients"

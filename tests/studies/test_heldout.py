"""metafovea.studies.heldout: one held-out case (the core of benchmarks/bench_generalise.py) at CI size."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from metafovea.config import SensorDesign, SystemDesign
from metafovea.errors import InputError
from metafovea.reconstruct.metrics import margin_summary
from metafovea.studies.heldout import CHANNELS, HeldOutCase, run_case


def test_a_case_scores_every_method_on_one_measurement_against_one_bound():
    """A 64 x 64 crop, 8 frames, Airy PSFs: the default method, then the same method named twice, on one recording
    each; the bound is computed once per recording and each row's margin is its PSNR minus the bound's."""
    system = replace(SystemDesign.paper(), sensor=replace(SensorDesign(), crop=(64, 64)))
    case = HeldOutCase("gen:sources:3", filter_enabled=True, frames=8, psf="airy", seed=3)
    res = run_case(system, case)
    rows = res["rows"]
    assert [r["channel"] for r in rows] == list(CHANNELS) and res["scene"] == "gen:sources:3"
    assert res["fpn_error_dn"] > 0 and res["bound_seconds"] > 0 and res["simulate_seconds"] > 0
    for r in rows:
        assert all(np.isfinite(r[k]) for k in ("psnr_db", "bound_db", "hazy_db", "seconds"))
        assert r["margin_db"] == pytest.approx(r["psnr_db"] - r["bound_db"])
        assert abs(r["margin_db"]) < 10 and r["seconds"] > 0
    method = rows[0]["method"]
    twice = run_case(system, case, methods=[method, method])["rows"]
    assert [r["method"] for r in twice] == [method] * 4
    for a, b in zip(twice[:2], twice[2:]):  # one measurement, one bound: the same method scores the same
        assert a["bound_db"] == b["bound_db"] and a["psnr_db"] == b["psnr_db"]
    for a, b in zip(rows, twice):  # the same seed: the same recording
        assert a["psnr_db"] == pytest.approx(b["psnr_db"]) and a["bound_db"] == pytest.approx(b["bound_db"])
    # options reach every method's run: another wavelet, the same recording and bound, other estimates
    other = run_case(system, case, methods=["wavelet"], options={"wavelet": "db2"})["rows"]
    assert [r["bound_db"] for r in other] == pytest.approx([r["bound_db"] for r in rows])
    assert any(abs(a["psnr_db"] - b["psnr_db"]) > 1e-6 for a, b in zip(rows, other))


def test_margin_summary_counts_cases_at_or_above_the_bound():
    s = margin_summary([-0.5, 0.0, 1.0, 2.0])
    assert s == {"cases": 4, "at_or_above": 0.75, "worst_db": -0.5, "median_db": 0.5}
    for bad in ([], [0.1, np.nan]):
        with pytest.raises(InputError, match="margins_db"):
            margin_summary(bad)

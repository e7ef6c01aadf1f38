"""Counts to kelvin: FLIR's Planck curve and its inverse, the band-model fit and its reported error, the two-point
calibration (per-pixel correction, bad pixels, global mode) and the split between the channels."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.radiometry import BandRadiance
from metafovea.reconstruct.deconvolve import temperatures
from metafovea.recordings.calibration import PlanckConstants, correct_frames, from_planck, two_point

FLIR = PlanckConstants(R1=21106.77, R2=0.012545258, B=1501.0, F=1.0, O=-7340.0)


def test_planck_curve_inverts_and_the_fit_error_is_the_true_one():
    t = np.linspace(280.0, 340.0, 61)
    np.testing.assert_allclose(FLIR.temperature(FLIR.counts(t)), t, rtol=1e-12)
    frames = FLIR.counts(t).reshape(1, 1, -1)
    model = from_planck(FLIR, frames, band_um=(7.5, 13.5))
    meta = model.meta()
    back = temperatures((FLIR.counts(t), FLIR.counts(t)), meta["dark_dn"], meta)[0]
    true_err = float(np.max(np.abs(back - t)))
    # the reported bound covers the range it was fitted over (the recording's +-10 K)
    assert model.info["fit_range_k"][0] <= 270.5 and model.info["fit_range_k"][1] >= 349.5
    assert true_err <= model.info["fit_max_error_k"] * 1.01 + 1e-3
    assert model.info["fit_max_error_k"] < 0.35  # 0.31 K over 270-350 K (0.11 K over 280-330 K)


def test_two_point_per_pixel_corrects_gain_and_offset_patterns():
    rng = np.random.default_rng(0)
    band = BandRadiance.from_band((8.0, 14.0))
    G, dark = 1e4, 1500.0
    pg, po = 1 + 0.1 * rng.standard_normal((6, 6)), 30 * rng.standard_normal((6, 6))
    pg[0, 0] = -0.2  # a dead pixel (inverted response)

    def cam(t):
        return po + pg * (dark + G * band(t))

    model, g, o, bad = two_point(cam(np.full((6, 6), 290.0)), 290.0, cam(np.full((6, 6), 330.0)), 330.0)
    assert bad[0, 0] and bad.sum() == 1 and model.info["bad_pixels"] == 1
    scene = 290.0 + 40.0 * rng.random((6, 6))
    fixed = correct_frames(cam(scene)[None], model, g, o, bad)[0]
    meta = model.meta()
    tk = temperatures((fixed, fixed), meta["dark_dn"], meta)[0]
    np.testing.assert_allclose(tk[~bad], scene[~bad], atol=2e-3)  # float32 frames: ~1e-3 K
    glob, g2, _, _ = two_point(cam(np.full((6, 6), 290.0)), 290.0, cam(np.full((6, 6), 330.0)), 330.0,
                               mode="global")
    assert g2 is None and glob.method == "two-point global"


def test_foveal_gain_splits_the_calibration_between_channels():
    model = from_planck(FLIR, FLIR.counts(np.linspace(290, 320, 8)).reshape(1, 1, -1), band_um=(7.5, 13.5))
    d = model.meta(foveal_gain=0.3)["dn_per_k_300K"]
    assert d["x1"] / d["x2"] == pytest.approx(0.3)
    assert (d["x1"] + d["x2"]) / 2 == pytest.approx(model.meta()["dn_per_k_300K"]["x1"])  # mean alpha 1/2

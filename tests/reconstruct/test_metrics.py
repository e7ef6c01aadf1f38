"""Image-quality metrics and the one scorer of a reconstruction against truth. The reference values first: PSNR of
known Gaussian noise, SSIM and PSNR of identical images."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.errors import InputError
from metafovea.reconstruct.metrics import level_free_image, psnr, score, ssim


def test_metrics(truth):
    x1, x2 = truth
    assert psnr(x1, x1) == np.inf and ssim(x1, x1) == pytest.approx(1.0)
    noisy = x1 + np.random.default_rng(0).normal(0, 0.01, x1.shape)
    assert psnr(noisy, x1, 1.0) == pytest.approx(40.0, abs=0.3)
    s = score((noisy, x2), x1, x2, 1.0)
    assert set(s) == {"psnr_x1", "ssim_x1", "psnr_x2", "ssim_x2"}
    with pytest.raises(InputError):
        psnr(x1[:5], x1)


def test_level_free_psnr_ignores_a_constant_offset(truth):
    """An image off by a constant (the alpha gauge / offset part of the error) is perfect once the mean error is
    removed; the plain PSNR shows the offset."""
    x1, x2 = truth
    s = score((x1 + 0.1, x2 - 0.05), x1, x2, level_free=True)
    assert s["psnr_x1"] == pytest.approx(20 * np.log10(np.ptp(x1) / 0.1), abs=1e-9)  # mse = 0.1^2
    assert s["psnr_x1_level_free"] > 200 and s["psnr_x2_level_free"] > 200
    noisy = x1 + np.random.default_rng(1).normal(0, 0.01, x1.shape)
    assert np.mean(level_free_image(noisy + 3.0, x1) - x1) == pytest.approx(0.0, abs=1e-12)


def test_video_is_scored_window_by_window(truth):
    x1, x2 = truth
    rng = np.random.default_rng(2)
    est = np.stack([x1 + rng.normal(0, s, x1.shape) for s in (0.01, 0.02)])
    per = [psnr(e, x1) for e in est]
    assert score((est, est), x1, None)["psnr_x1"] == pytest.approx(np.mean(per))
    refs = np.stack([x1, x1 + 0.02])
    assert score((est, est), refs, None)["psnr_x1"] == pytest.approx(np.mean([psnr(est[0], x1),
                                                                              psnr(est[1], x1 + 0.02)]))


def test_score_refuses_truth_with_another_number_of_frames():
    """A (5, H, W) truth against 2 outputs was broadcast silently (or failed inside numpy)."""
    x = np.zeros((2, 8, 8))
    with pytest.raises(InputError, match="truth_x1"):
        score((x, x), np.zeros((5, 8, 8)), None)
    with pytest.raises(InputError, match="truth_x1"):
        score((x, x), np.zeros((4, 4)), None)

"""Known mixing ratios: closed-form per-pixel least squares, its conditioning report, masking and the real-time
sliding window. The reference checks first: exact recovery without noise, and a noise gain that matches the
estimate's true error."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from metafovea.errors import InputError
from metafovea.reconstruct import SlidingLSQ, condition_number, lsq_known_alpha, video
from metafovea.reconstruct.metrics import psnr
from metafovea.reconstruct.synthetic import measure, polariser_alpha

N = 96


def test_lsq_exact_without_noise(truth, alpha8):
    x1, x2 = truth
    Y = measure(x1, x2, alpha8, sigma=0.0)
    r = lsq_known_alpha(Y, alpha8)
    assert np.allclose(r.x1, x1, atol=1e-9) and np.allclose(r.x2, x2, atol=1e-9)
    assert r.info["condition"] == pytest.approx(condition_number(alpha8))
    assert r.info["condition"] < 10


def test_lsq_accuracy_and_noise_gain(truth, alpha8):
    """The reported noise gain is the estimate's true error per unit frame noise (the conditioning is truthful)."""
    x1, x2 = truth
    Y = measure(x1, x2, alpha8, sigma=0.01, rng=0)
    r = lsq_known_alpha(Y, alpha8)
    for est, ref, g in ((r.x1, x1, r.info["noise_gain"][0]), (r.x2, x2, r.info["noise_gain"][1])):
        assert np.std(est - ref) == pytest.approx(0.01 * g, rel=0.05)
    assert psnr(r.x1, x1, 1.0) > 42.0 and psnr(r.x2, x2, 1.0) > 42.0


def test_slow_polariser_condition_in_the_hundreds(truth, caplog):
    a = polariser_alpha(8, rate_hz=0.5 / 360 * 12, phase=0.75)  # 0.5 deg/frame
    x1, x2 = truth
    Y = measure(x1, x2, a, sigma=0.001, rng=0)
    with caplog.at_level(logging.WARNING, logger="metafovea.reconstruct.lsq"):
        r = lsq_known_alpha(Y, a)
    assert 300 < r.info["condition"] < 1000
    assert "condition number" in caplog.text  # never silently amplified
    # correct in expectation: the error matches the reported noise gain
    g = r.info["noise_gain"]
    assert max(g) > 5
    assert np.std(r.x1 - x1) == pytest.approx(0.001 * g[0], rel=0.1)
    # a stricter limit turns it into an error
    with pytest.raises(InputError):
        lsq_known_alpha(Y, a, max_condition=100)


def test_lsq_float32_preserved(truth, alpha8):
    Y = measure(*truth, alpha8, sigma=0.01, rng=0, dtype=np.float32)
    r = lsq_known_alpha(Y, alpha8)
    assert r.x1.dtype == np.float32 and r.x2.dtype == np.float32


@pytest.mark.parametrize("T", [2, 3])
def test_two_and_three_frames(truth, T):
    a = np.array([0.9, 0.1, 0.5])[:T]
    x1, x2 = truth
    Y = measure(x1, x2, a, sigma=0.0)
    r = lsq_known_alpha(Y, a)
    assert np.allclose(r.x1, x1) and np.allclose(r.x2, x2)
    # denoising with T=2 cannot use the residual: noise estimated from the images instead
    r2 = lsq_known_alpha(measure(x1, x2, a, sigma=0.02, rng=1), a, denoise="tv")
    assert r2.info["noise_sigma"] > 0


def test_one_frame_refused(truth):
    with pytest.raises(InputError) as e:
        lsq_known_alpha(truth[0][None], [0.5])
    assert e.value.parameter == "frames"


def test_equal_alphas_singular_is_clear_error(truth):
    a = np.full(8, 0.6)
    Y = measure(*truth, a, sigma=0.01, rng=0)
    assert condition_number(a) == np.inf
    with pytest.raises(InputError, match="condition number"):
        lsq_known_alpha(Y, a)


def test_equal_alphas_regularised_by_stated_rule(truth):
    x1, x2 = truth
    a = np.full(8, 0.6)
    Y = measure(x1, x2, a, sigma=0.01, rng=0)
    r = lsq_known_alpha(Y, a, regularize="difference")
    # rule: difference ridge -> both channels fall back to the unseparated mixture, no amplified noise
    mix = 0.6 * x1 + 0.4 * x2
    assert np.allclose(r.x1, r.x2, atol=1e-3)
    assert np.std(r.x1 - mix) < 0.01
    assert r.info["condition_regularized"] <= 1e4 * 1.001
    assert r.info["regularization_lambda"] > 0


def test_alpha_near_one_for_all_frames(truth):
    a = 0.9 + 0.05 * np.cos(np.arange(8) * 1.1)
    x1, x2 = truth
    r = lsq_known_alpha(measure(x1, x2, a, sigma=0.0), a)
    assert np.allclose(r.x1, x1, atol=1e-8) and np.allclose(r.x2, x2, atol=1e-8)
    assert r.info["condition"] > 100 and r.info["noise_gain"][1] > 5


def test_bad_alpha_refused(truth):
    Y = measure(*truth, polariser_alpha(4), sigma=0.0)
    for bad, param in (([0.1, 0.2, 0.3], "alpha"), ([0.1, 1.5, 0.2, 0.3], "alpha"),
                       ([0.1, np.nan, 0.2, 0.3], "alpha")):
        with pytest.raises(InputError) as e:
            lsq_known_alpha(Y, bad)
        assert e.value.parameter == param


def test_frames_of_different_shapes_refused():
    with pytest.raises(InputError, match="same"):
        lsq_known_alpha([np.zeros((8, 8)), np.zeros((8, 9))], [0.1, 0.9])
    with pytest.raises(InputError):
        lsq_known_alpha(np.zeros((2, 3, 4, 5)), [0.1, 0.9])


def test_nan_and_saturated_pixels_masked(truth, alpha8):
    x1, x2 = truth
    Y = measure(x1, x2, alpha8, sigma=0.0)
    Y[0, 10, 10] = np.nan
    Y[3, 20, 30] = np.inf
    Y[:7, 40, 40] = np.nan  # only one valid sample left: unresolvable
    Y[2, 50, 50] = 5.0  # saturated
    r = lsq_known_alpha(Y, alpha8, saturation=2.0)
    good = np.ones_like(x1, bool)
    good[40, 40] = False
    assert np.allclose(r.x1[good], x1[good], atol=1e-9) and np.allclose(r.x2[good], x2[good], atol=1e-9)
    assert np.isnan(r.x1[40, 40]) and r.info["unresolved_pixels"] == 1
    assert r.info["masked_samples"] == 10
    # without the saturation level the saturated sample corrupts its pixel (and only it)
    r2 = lsq_known_alpha(Y, alpha8)
    assert abs(r2.x1[50, 50] - x1[50, 50]) > 0.1


def test_denoise_improves_noisy_lsq(truth, alpha8):
    x1, x2 = truth
    Y = measure(x1, x2, alpha8, sigma=0.05, rng=0)
    raw = lsq_known_alpha(Y, alpha8)
    for method in ("tv", "bilateral"):
        d = lsq_known_alpha(Y, alpha8, denoise=method)
        assert psnr(d.x1, x1, 1.0) > psnr(raw.x1, x1, 1.0) + 1.0, method
        assert d.info["noise_sigma"] == pytest.approx(0.05, rel=0.1)


def test_sliding_lsq_matches_batch(truth):
    x1, x2 = truth
    a = polariser_alpha(20)
    Y = measure(x1, x2, a, sigma=0.01, rng=3, dtype=np.float32)
    s = SlidingLSQ(window=8, refresh=5)
    outs = [s.update(Y[t], a[t]) for t in range(20)]
    assert all(o is None for o in outs[:7])
    v = video(Y, a, window=8)
    assert v.x1.shape == (13, N, N) and v.x1.dtype == np.float32
    for k in range(13):
        o1, o2, cond = outs[k + 7]
        ref = lsq_known_alpha(Y[k:k + 8], a[k:k + 8])
        assert np.allclose(o1, ref.x1, atol=2e-5) and np.allclose(o2, ref.x2, atol=2e-5)
        assert np.allclose(v.x1[k], ref.x1, atol=2e-5)
        assert cond == pytest.approx(v.info["condition"][k])
    with pytest.raises(InputError):
        s.push(np.zeros((5, 5)), 0.3)

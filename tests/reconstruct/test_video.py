"""Sliding windows over a sequence: every window equals the one-window solve, explicit window starts, conditioning
per window."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.errors import InputError
from metafovea.reconstruct import alternating, lsq_known_alpha, video
from metafovea.reconstruct.synthetic import measure, polariser_alpha

N = 96


def test_every_window_equals_the_one_window_solve(truth):
    a = polariser_alpha(12)
    Y = measure(*truth, a, sigma=0.01, rng=0)
    v = video(Y, a, window=6, stride=3)
    assert v.info["window_starts"] == [0, 3, 6] and v.method == "video/lsq"
    for k, s in enumerate(v.info["window_starts"]):
        ref = lsq_known_alpha(Y[s:s + 6], a[s:s + 6])
        assert np.allclose(v.x1[k], ref.x1) and np.allclose(v.x2[k], ref.x2)


def test_video_window_longer_than_sequence(truth):
    Y = measure(*truth, polariser_alpha(5), sigma=0.0)
    with pytest.raises(InputError) as e:
        video(Y, polariser_alpha(5), window=8)
    assert e.value.parameter == "window"
    v = video(Y, polariser_alpha(5), window=5)
    assert v.x1.shape == (1, N, N)


def test_video_stride_and_singular_window(truth):
    a = np.concatenate([polariser_alpha(8), np.full(8, 0.3)])  # polariser stops
    Y = measure(*truth, a, sigma=0.01, rng=0)
    with pytest.raises(InputError, match="window"):
        video(Y, a, window=8, stride=2)
    v = video(Y, a, window=8, stride=2, regularize="difference")
    assert v.x1.shape == (5, N, N) and v.info["window_starts"] == [0, 2, 4, 6, 8]
    assert v.info["condition"][0] < 10 and v.info["condition"][-1] == np.inf


def test_explicit_window_starts_and_unknown_alpha_per_window(truth):
    """Windows at given starts (irregular, as validate spreads them over a sequence); the alternating solver runs
    on each and reports alpha and whether its gauge was fixed, per window."""
    a = polariser_alpha(20)
    Y = measure(*truth, a, sigma=0.01, rng=0)
    v = video(Y, window=8, starts=[0, 5, 12], method="alternating", prior=None)
    assert v.x1.shape == (3, N, N) and v.info["window_starts"] == [0, 5, 12]
    assert v.info["window_alpha_identified"] == [True, True, True]
    one = alternating(Y[5:13], prior=None)
    assert np.allclose(v.x1[1], one.x1) and np.allclose(v.info["alpha_windows"][1], one.alpha)
    assert np.isnan(v.alpha).all()  # no sequence-wide alpha for unknown alpha
    for bad in ([13], [-1], []):
        with pytest.raises(InputError) as e:
            video(Y, a, window=8, starts=bad)
        assert e.value.parameter == "starts"


def test_video_denoise_uses_each_windows_noise_gain(truth):
    a = polariser_alpha(10)
    x1, x2 = truth
    Y = measure(x1, x2, a, sigma=0.05, rng=0)
    raw = video(Y, a, window=8)
    d = video(Y, a, window=8, denoise="tv")
    assert d.info["denoise"] == "tv" and d.info["noise_sigma"] == pytest.approx(0.05, rel=0.15)
    for k in range(d.x1.shape[0]):
        assert np.mean((d.x1[k] - x1) ** 2) < np.mean((raw.x1[k] - x1) ** 2)


def test_float32_fast_path_equals_the_float64_per_window_solve_incl_masked_pixels():
    """The throughput path (float32 frames: float32 weights, contiguous x1/x2 stacks, one product per image and
    window) equals the float64 per-window solve to 1e-5 of the images' range, with NaN and saturated samples."""
    rng = np.random.default_rng(7)
    T, H, W = 40, 33, 29
    x1 = 1700 + 60 * rng.random((H, W))
    x2 = 3300 + 400 * rng.random((H, W))
    a = polariser_alpha(T)
    Y64 = a[:, None, None] * x1 + (1 - a)[:, None, None] * x2 + 2 * rng.standard_normal((T, H, W))
    for masked in (False, True):
        Y = Y64.astype(np.float32)
        if masked:
            Y[3, 4, 5] = np.nan
            Y[10:14, 7, 8] = 5000.0  # saturated
        v = video(Y, a, window=8, stride=1, saturation=4900.0 if masked else None)
        assert v.x1.dtype == np.float32 and v.x1.flags.c_contiguous and v.x2.flags.c_contiguous
        assert v.x1.shape == (T - 7, H, W)
        for k in range(T - 7):
            ref = lsq_known_alpha(Y[k:k + 8].astype(np.float64), a[k:k + 8], saturation=4900.0 if masked else None)
            for got, want in ((v.x1[k], ref.x1), (v.x2[k], ref.x2)):
                assert np.array_equal(np.isnan(got), np.isnan(want))
                ok = ~np.isnan(want)
                assert np.max(np.abs(got[ok] - want[ok])) <= 1e-5 * np.ptp(Y64), (masked, k)

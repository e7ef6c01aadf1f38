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


def test_a_jittering_rotation_gives_every_window_the_sequences_gauge(truth):
    """A polariser whose angle jitters 2 deg rms from frame to frame: each 8-frame window alone fixes alpha's gauge
    from three phases of alpha only; windows that share frames are chained into one gauge, which the polariser fit
    over all 24 frames fixes: every window's alpha is then the whole sequence's (one-window solve) to the data-term
    noise (1e-5), its images still explain its frames, and over eight jitter draws the windows' alpha error is half
    what the windows alone make (stride = window: no shared frames, a planted case). A regular rotation is left to
    each window's own fit."""
    from metafovea.reconstruct.polarizer import PolarizerModel

    x1, x2 = truth
    T = 24
    t = np.arange(T) / 12.0
    kw = dict(window=8, method="alternating", polarizer=PolarizerModel(t, rate_hz=2.0), scale=6.0)

    def mae(v, a):
        return np.mean([np.mean(np.abs(np.asarray(w) - a[s:s + 8]))
                        for w, s in zip(v.info["alpha_windows"], v.info["window_starts"])])

    errors = []
    for seed in range(8):
        rng = np.random.default_rng(seed)
        a = np.cos(2 * np.pi * 2.0 * t + 0.3 + np.radians(2.0) * rng.standard_normal(T)) ** 2
        Y = measure(x1, x2, a, sigma=0.002, rng=seed)
        pooled, alone = video(Y, stride=1, **kw), video(Y, stride=8, **kw)
        assert pooled.info["gauge_pooled"]["chains"][0]["windows"] == 17 and "gauge_pooled" not in alone.info
        errors.append((mae(pooled, a), mae(alone, a)))
        if seed:
            continue
        whole = alternating(Y, polarizer=PolarizerModel(t, rate_hz=2.0), scale=6.0)
        assert whole.info["polarizer_gauge"]["alpha_from"] == "frames" and "irregular" in pooled.info["warnings"][0]
        for w, s in zip(pooled.info["alpha_windows"], pooled.info["window_starts"]):
            np.testing.assert_allclose(w, whole.alpha[s:s + 8], atol=1e-5)
        k = 8  # the window at frame 8: its images solve its frames with its alpha
        w8 = np.asarray(pooled.info["alpha_windows"][k])
        model = w8[:, None, None] * pooled.x1[k][None] + (1 - w8)[:, None, None] * pooled.x2[k][None]
        assert np.sqrt(np.mean((model - Y[k:k + 8]) ** 2)) < 0.0021  # the noise, 0.002 (an alpha 5e-3 off: 0.0026)
    e = np.mean(errors, axis=0)
    assert e[1] > 1.5 * e[0], errors
    steady = measure(x1, x2, polariser_alpha(T), sigma=0.002, rng=1)
    assert "gauge_pooled" not in video(steady, stride=1, **kw).info

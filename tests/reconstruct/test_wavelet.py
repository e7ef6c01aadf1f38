"""The non-linear step of the PSF-aware reconstruction (:mod:`metafovea.reconstruct.wavelet`): its FFT frame against
PyWavelets' own stationary transform, and its risk estimate against the true error of images whose noise-free
version is known (white and coloured noise)."""

from __future__ import annotations

import numpy as np
import pytest
import pywt
from scipy.fft import irfft2, rfft2

from metafovea.errors import InputError
from metafovea.reconstruct.wavelet import (
    WAVELETS,
    StationaryFrame,
    parent_of,
    shrink,
    shrink_jacobian,
    shrink_linearised,
    swt_levels,
)


@pytest.mark.parametrize("wavelet", WAVELETS)
def test_the_fft_frame_is_pywavelets_stationary_transform(wavelet):
    """Parseval (sum |F_b|^2 = 1, perfect reconstruction) and, subband by subband, the energies of
    ``pywt.swt2(..., norm=True)`` (periodic), which computes the transform by its own filter bank; the transfer
    function of a subband-diagonal map against the map applied to an image."""
    y = np.random.default_rng(0).standard_normal((64, 64))
    f = StationaryFrame(y.shape, wavelet, 3)
    assert np.max(np.abs(np.sum(np.abs(f.filters) ** 2, axis=0) - 1.0)) < 1e-9
    c = f.analysis(y)
    assert np.max(np.abs(f.synthesis(c) - y)) < 1e-9
    ref = pywt.swt2(y, wavelet, level=3, trim_approx=True, norm=True)
    e_ref = [float(np.sum(ref[0] ** 2))] + [float(np.sum(b ** 2)) for lev in ref[1:] for b in lev]
    e = [float(np.sum(x ** 2)) for x in c]
    assert np.allclose(sorted(e), sorted(e_ref), rtol=1e-9)
    # the noise variances from the draws' spectra are the subbands' mean squares, and the covariances with each
    # subband's parent (one level coarser, same orientation) the mean products, measured on the subbands themselves
    assert np.allclose(f.noise_variances(y[None]), [np.mean(x ** 2) for x in c], rtol=1e-9)
    cov = f.parent_covariances(y[None])
    assert np.allclose(cov[:4], 0.0) and np.all([parent_of(b) is None for b in range(4)])
    assert np.allclose(cov[4:], [np.mean(c[b] * c[parent_of(b)]) for b in range(4, c.shape[0])], rtol=1e-9, atol=1e-12)
    # a subband-diagonal map's transfer function (a sum of separable products) is what the map does to an image
    g = np.random.default_rng(1).uniform(0, 1.5, c.shape[0])
    assert np.allclose(irfft2(rfft2(y) * f.transfer(g), s=y.shape), f.synthesis(g[:, None, None] * c), atol=1e-9)
    # on a non-square grid too (the factors along y and x differ)
    f2 = StationaryFrame((48, 80), wavelet, 2)
    y2 = np.random.default_rng(2).standard_normal((48, 80))
    c2 = f2.analysis(y2)
    assert np.allclose(f2.synthesis(c2), y2, atol=1e-9)
    g2 = np.random.default_rng(3).uniform(0, 1.5, c2.shape[0])
    assert np.allclose(irfft2(rfft2(y2) * f2.transfer(g2), s=y2.shape), f2.synthesis(g2[:, None, None] * c2), atol=1e-9)


def _blocks(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    s = np.zeros((n, n))
    for _ in range(25):
        y, x = rng.integers(0, n - 4, 2)
        h, w = rng.integers(3, n // 3, 2)
        s[y:y + h, x:x + w] += rng.uniform(-20, 20)
    return s


def _coloured(rng: np.random.Generator, shape: tuple, corr_px: float) -> np.ndarray:
    """Gaussian noise of unit variance with a Gaussian autocorrelation of ``corr_px`` (0: white)."""
    n = rng.standard_normal(shape)
    if corr_px <= 0:
        return n
    fy = np.fft.fftfreq(shape[-2])[:, None]
    fx = np.fft.rfftfreq(shape[-1])[None, :]
    h = np.exp(-2 * (np.pi * corr_px) ** 2 * (fy ** 2 + fx ** 2))
    out = irfft2(rfft2(n, axes=(-2, -1)) * h, s=shape[-2:], axes=(-2, -1))
    return out / np.std(out)


@pytest.mark.parametrize("interscale", [True, False])
@pytest.mark.parametrize("sigma, corr_px", [(2.0, 0.0), (6.0, 0.0), (4.0, 1.5)])
def test_sure_is_the_true_error_and_shrinkage_removes_noise(sigma, corr_px, interscale):
    """Over repeated noise, SURE's mean is the true mean squared error (it is unbiased; the fitted coefficients
    make it a few per cent optimistic), and the estimate's error is well below the noise's: with the parent's split
    (eq. 1b, whose SURE counts the noise the parent shares with its child) and without (eq. 1)."""
    rng = np.random.default_rng(int(sigma * 10 + corr_px))
    clean = _blocks(96, 1)
    sures, errs = [], []
    for _ in range(6):
        y = clean + sigma * _coloured(rng, clean.shape, corr_px)
        draws = sigma * _coloured(rng, (4,) + clean.shape, corr_px)
        est, sure = shrink(y, draws, "haar", interscale=interscale)
        sures.append(sure)
        errs.append(float(np.mean((est - clean) ** 2)))
    assert abs(np.mean(sures) - np.mean(errs)) < 0.1 * np.mean(errs) + 0.01 * sigma ** 2, (sures, errs)
    assert np.mean(errs) < 0.5 * sigma ** 2


def _blue(rng: np.random.Generator, shape: tuple) -> np.ndarray:
    """Gaussian noise of unit variance whose power rises with frequency, as a deconvolution's does."""
    n = rng.standard_normal(shape)
    fy = np.fft.fftfreq(shape[-2])[:, None]
    fx = np.fft.rfftfreq(shape[-1])[None, :]
    out = irfft2(rfft2(n, axes=(-2, -1)) * (0.3 + (fy ** 2 + fx ** 2) / 0.05), s=shape[-2:], axes=(-2, -1))
    return out / np.std(out)


@pytest.mark.parametrize("sigma", [2.0, 4.0])
def test_the_parents_split_removes_more_noise_around_small_sources(sigma):
    """Small warm sources and blocks under a deconvolution's (blue) noise: a feature's coefficients persist from
    one level to the next, noise's do not, so eq. (1b) keeps the sources and shrinks the noise around them harder
    than eq. (1): at least 10 % less squared error on every draw (the same noise for both)."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(11)
    clean = np.zeros((128, 128))
    for _ in range(15):
        y, x = rng.integers(4, 124, 2)
        clean[y, x] += rng.uniform(30, 80)
    clean = gaussian_filter(clean, 1.0, mode="wrap") + 0.5 * _blocks(128, 5)
    ratios = []
    for _ in range(4):
        y = clean + sigma * _blue(rng, clean.shape)
        draws = sigma * _blue(rng, (4,) + clean.shape)
        e1, _ = shrink(y, draws, "haar", interscale=True)
        e0, _ = shrink(y, draws, "haar", interscale=False)
        ratios.append(float(np.mean((e1 - clean) ** 2) / np.mean((e0 - clean) ** 2)))
    assert max(ratios) < 0.9, ratios  # at most 0.83 here


def test_a_flat_image_is_returned_flat_and_bad_input_is_refused():
    rng = np.random.default_rng(3)
    y = 5.0 + rng.standard_normal((64, 64))
    est, _ = shrink(y, rng.standard_normal((4, 64, 64)))
    assert np.std(est) < 0.3 and abs(np.mean(est) - np.mean(y)) < 1e-6 * abs(np.mean(y))  # single-precision subbands
    with pytest.raises(InputError, match="wavelet"):
        shrink(y, rng.standard_normal((2, 64, 64)), "morlet")
    with pytest.raises(InputError, match="noise"):
        shrink(y, rng.standard_normal((2, 32, 32)))
    assert swt_levels((290, 290)) == 5 and swt_levels((16, 16)) == 1


@pytest.mark.parametrize("interscale", [True, False])
def test_degenerate_subbands_give_a_finite_risk_and_keep_the_image(interscale):
    """A noise-free checkerboard: every subband but the finest diagonal one is zero (up to single-precision
    rounding), so the parents split nothing and eq. (1)'s two atoms coincide; the image comes back as it is, with
    the risk of keeping it (the stated noise) rather than the 1e13 that a near-singular fit gave."""
    y = 5.0 * ((np.indices((64, 64)).sum(axis=0) % 2) - 0.5)
    draws = np.random.default_rng(0).standard_normal((4, 64, 64))
    est, sure = shrink(y, draws, "haar", interscale=interscale)
    assert np.max(np.abs(est - y)) < 1e-5
    assert 0.5 < sure < 1.5
    # the noisy checkerboard is still shrunk
    noisy = y + np.random.default_rng(1).standard_normal(y.shape)
    est2, _ = shrink(noisy, draws, "haar", interscale=interscale)
    assert np.mean((est2 - y) ** 2) < 0.1


def test_the_linear_fit_of_the_shrinkage_and_its_sure():
    """``shrink_linearised``: the same estimate and SURE as ``shrink``; its gains are the least-squares fit of the
    shrunk subbands on the noisy ones, and its linear SURE is eq. (3) computed by the frame's synthesis; over repeated
    noise that SURE's mean is the linear fit's true error (within a few per cent)."""
    rng = np.random.default_rng(5)
    clean = _blocks(64, 2)
    levels = swt_levels(clean.shape)
    frame = StationaryFrame(clean.shape, "haar", levels)
    sl, err = [], []
    for _ in range(16):
        y = clean + 4.0 * rng.standard_normal(clean.shape)
        draws = 4.0 * rng.standard_normal((4,) + clean.shape)
        est, sure, gains, sure_lin = shrink_linearised(y, draws, "haar", levels)
        e2, s2 = shrink(y, draws, "haar", levels)
        assert np.array_equal(est, e2) and sure == s2
        assert gains[0] == 1.0 and np.all(gains[1:] <= 1.5)
        c = frame.analysis(y)
        lin = frame.synthesis(gains[:, None, None] * c)
        var = frame.noise_variances(draws)
        tr = float(np.mean(np.sum(draws ** 2, axis=(1, 2))))
        direct = (np.sum((lin - y) ** 2) - tr + 2 * np.sum(gains * var) * y.size) / y.size
        assert np.isclose(sure_lin, direct, rtol=1e-6, atol=1e-6 * abs(direct))
        sl.append(sure_lin)
        err.append(np.mean((lin - clean) ** 2))
    assert abs(np.mean(sl) - np.mean(err)) < 0.05 * np.mean(err)


@pytest.mark.parametrize("sigma, corr_px", [(2.0, 0.0), (6.0, 0.0), (4.0, 1.5)])
def test_the_jacobian_gives_the_shrunk_estimates_noise(sigma, corr_px):
    """The noise draws through the shrinkage's Jacobian (what the foveal fusion takes as the foveal estimate's noise)
    against the truth it estimates: the variance of the shrunk estimate over repeated noise, per pixel and for 6 x 6
    block means (the fusion's grid), within 20 %; the draws before the shrinkage are ~2x too much. And the Jacobian
    is the estimate's derivative: finite differences along two draws agree (the refitted eq. (1) coefficients, which
    the Jacobian holds fixed, move them by a few per cent)."""
    rng = np.random.default_rng(5)
    clean = _blocks(96, 1)
    y = clean + sigma * _coloured(rng, clean.shape, corr_px)
    draws = sigma * _coloured(rng, (4,) + clean.shape, corr_px)
    jac = shrink_jacobian(y, draws, "haar")
    assert jac.shape == draws.shape
    e0, _ = shrink(y, draws, "haar")
    step = 1e-4
    fd = np.stack([(shrink(y + step * draws[k], draws, "haar")[0] - e0) / step for k in range(2)])
    assert np.sqrt(np.mean((fd - jac[:2]) ** 2) / np.mean(jac[:2] ** 2)) < 0.25
    ests = np.stack([shrink(clean + sigma * _coloured(rng, clean.shape, corr_px), draws, "haar")[0]
                     for _ in range(16)])

    def blocks(a):
        return a.reshape(a.shape[0], 16, 6, 16, 6).mean(axis=(2, 4))

    for f in (lambda a: a, blocks):
        true = float(np.mean(np.var(f(ests), axis=0, ddof=1)))
        assert abs(float(np.mean(f(jac) ** 2)) / true - 1.0) < 0.2
        assert float(np.mean(f(draws) ** 2)) > 1.3 * true

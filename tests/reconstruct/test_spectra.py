"""The scene prior's spectra (:mod:`metafovea.reconstruct.spectra`): the radial profile against its definition, the
periodogram's scale against white noise, the fitted power law against a scene drawn with a known one."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.reconstruct.spectra import (
    BETA_RANGE,
    F_MAX,
    RADIAL_BINS,
    crop_periodogram,
    fitted_spectrum,
    inverse_prior,
    noise_floor,
    radial_field,
    radial_mean,
    rfft_frequencies,
    whittle_level,
)


def test_radial_profile_is_the_mean_over_each_ring_and_spreads_back():
    f = rfft_frequencies((40, 30))
    assert f.shape == (40, 16) and f[0, 0] == 0.0 and f.max() <= F_MAX
    v = np.cos(7.0 * f) + f ** 2
    centres, means, counts = radial_mean(f, v, 16)
    edges = np.linspace(0.0, F_MAX, 17)
    for k in range(16):
        ring = (f >= edges[k]) & ((f < edges[k + 1]) | (k == 15))  # the last ring holds the corner F_MAX
        assert counts[k] == ring.sum()
        if counts[k]:
            assert means[k] == pytest.approx(v[ring].mean(), rel=1e-12)
        else:
            assert np.isnan(means[k])
    np.testing.assert_allclose(centres, 0.5 * (edges[1:] + edges[:-1]))
    back = radial_field(f, means)
    assert back.shape == f.shape
    # a function constant on each ring comes back as itself
    np.testing.assert_allclose(radial_field(f, radial_mean(f, back, 16)[1]), back, rtol=1e-12, atol=1e-12)


def test_the_periodogram_of_white_noise_is_its_variance():
    rng = np.random.default_rng(0)
    fc, power, counts = crop_periodogram(rng.normal(0.0, 2.0, (128, 128)))
    sel = (fc > 0.05) & (fc < 0.45)
    assert fc.size == RADIAL_BINS and counts.sum() == 128 * 65
    assert np.mean(power[sel]) == pytest.approx(4.0, rel=0.05)


def _power_law_scene(n: int, beta: float, rng: np.random.Generator) -> np.ndarray:
    f = np.hypot(np.fft.fftfreq(n)[:, None], np.fft.fftfreq(n)[None, :])
    amp = np.where(f > 0, np.maximum(f, 1.0 / n) ** (-beta / 2), 0.0)
    return np.real(np.fft.ifft2(amp * np.fft.fft2(rng.standard_normal((n, n)))))


@pytest.mark.parametrize("beta", [1.5, 2.5, 3.0])
def test_the_fitted_law_finds_a_known_exponent(beta):
    """A scene drawn with power spectrum ``|f|^-beta`` seen through no blur: the fitted exponent is beta."""
    n = 128
    z = 10.0 * _power_law_scene(n, beta, np.random.default_rng(int(10 * beta)))
    D = np.ones((n, n // 2 + 1))
    law, info = fitted_spectrum(z, z - z.mean(), D, 1e-6, "power-law")
    assert info["beta"] == pytest.approx(beta, abs=0.25) and BETA_RANGE[0] <= info["beta"] <= BETA_RANGE[1]
    assert law.shape == D.shape
    inv = inverse_prior([law, law])
    assert inv.shape == (2,) + D.shape and np.all(inv[:, 0, 0] == 0) and np.all(inv >= 0)


@pytest.mark.parametrize("snr_low", [3.0, 0.3, 0.03])
def test_whittle_level_recovers_the_level_also_below_the_noise(snr_low):
    """Ring periodograms drawn from ``mu_r = <|D|^2>_r c f^-2 + sigma^2`` (Gamma, ``m_r`` samples each): the level
    comes back within four of its standard errors whether the signal exceeds the noise in the first ring or stays
    below it in every ring (where a detection-based fit has nothing to fit, and a level tied to the noise is off by
    orders of magnitude)."""
    rng = np.random.default_rng(int(snr_low * 100))
    fc = (np.arange(1, 64) + 0.5) * (0.5 * np.sqrt(2) / 64)
    otf2 = 0.3 * np.exp(-(fc / 0.08) ** 2) + 1e-4
    counts = np.maximum((2 * np.pi * fc * 290 ** 2 * (0.5 * np.sqrt(2) / 64)).astype(int), 4)
    sigma2 = 2.0
    c = snr_low * sigma2 / (otf2[0] * fc[0] ** -2.0)
    mu = otf2 * c * fc ** -2.0 + sigma2
    power = mu * rng.gamma(counts, 1.0 / counts)
    logc = whittle_level(fc, power, otf2, counts, sigma2, 2.0)
    # the likelihood's own standard error of log c (Fisher information of eq. 4)
    se = 1.0 / np.sqrt(np.sum(counts * (otf2 * c * fc ** -2.0 / mu) ** 2))
    assert abs(logc - np.log(c)) < 4 * se, (np.exp(logc), c, se)
    # the level the noise alone would suggest (the fit's former fallback) is orders of magnitude off
    assert abs(np.log(sigma2) - np.log(c)) > 5.0 and abs(logc - np.log(c)) < 0.3 * abs(np.log(sigma2) - np.log(c))


def _blurred_scene(n: int, beta: float, width: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A ``|f|^-beta`` scene (rms 10) through a Gaussian OTF of 1/e width ``width`` cycles/px on its own periodic
    grid, and that OTF on the rfft half plane."""
    rng = np.random.default_rng(seed)
    f = np.hypot(np.fft.fftfreq(n)[:, None], np.fft.fftfreq(n)[None, :])
    otf = np.exp(-(f / width) ** 2)
    s = _power_law_scene(n, beta, rng)
    s *= 10.0 / s.std()
    z = np.real(np.fft.ifft2(otf * np.fft.fft2(s)))
    return z, otf[:, : n // 2 + 1]


@pytest.mark.parametrize("beta, width, seed", [(2.0, 0.15, 0), (3.0, 0.08, 1), (1.2, 0.25, 2), (0.5, 0.15, 3)])
def test_the_noise_floor_finds_the_noise_the_model_leaves_out(beta, width, seed):
    """Blurred scenes with white noise of variance 0.5: stated at a tenth of it, the data's flat excess is found
    (eq. 5) within 15 % of the true level; stated right, or above, nothing is raised. Brute-force reference: the
    noise drawn here."""
    n = 160
    z, D = _blurred_scene(n, beta, width, seed)
    z = z + np.random.default_rng(seed + 50).normal(0.0, np.sqrt(0.5), z.shape)
    v, info = noise_floor(z, D, (n, n), 0.05)
    assert info["used"] and v == pytest.approx(0.5, rel=0.15), info
    for stated in (0.5, 1.0):
        v, info = noise_floor(z, D, (n, n), stated)
        assert not info["used"] and v == stated, info


def test_a_white_scene_is_not_taken_for_noise():
    """A scene as flat as noise, seen through a PSF that passes every frequency alike, cannot be told from noise and
    must not be raised (nothing is amplified); through a blur, white noise added to it is still found."""
    rng = np.random.default_rng(7)
    n = 128
    s = rng.uniform(100.0, 200.0, (n, n))
    v, info = noise_floor(s, np.ones((n, n // 2 + 1)), (n, n), 1e-8)
    assert not info["used"] and v == 1e-8
    f = np.hypot(np.fft.fftfreq(n)[:, None], np.fft.fftfreq(n)[None, :])
    otf = np.exp(-(f / 0.12) ** 2)
    z = np.real(np.fft.ifft2(otf * np.fft.fft2(s))) + rng.normal(0.0, 0.3, (n, n))
    v, info = noise_floor(z, otf[:, : n // 2 + 1], (n, n), 1e-4)
    assert info["used"] and v == pytest.approx(0.09, rel=0.15), info


@pytest.mark.parametrize("beta, radius, n, seed", [(1.0, 4.0, 48, 0), (0.5, 3.0, 160, 1), (0.5, 5.0, 96, 2)])
def test_a_psfs_zeros_filled_by_the_taper_are_not_taken_for_noise(beta, radius, n, seed):
    """A defocus (disk) PSF's OTF has rings of zeros, which the Hann-tapered periodogram of a crop fills with the
    neighbouring frequencies' power: with the noise stated right that is no excess (the periodogram's expectation
    includes the taper's leakage; the spectrum sampled at the rings alone raised these three 3-13x); an excess
    of 9x the noise is still found (0.6-1.2 of the truth: a scene nearly as flat as noise takes up part of it)."""
    from scipy.special import j1

    rng = np.random.default_rng(seed)
    P = 2 * n
    f = np.hypot(np.fft.fftfreq(P)[:, None], np.fft.rfftfreq(P)[None, :])
    arg = np.where(f > 0, 2 * np.pi * radius * f, 1.0)
    otf = np.where(f > 0, 2 * j1(arg) / arg, 1.0)
    ff = np.where(f > 0, f, 1.0)
    s = np.fft.irfft2(np.fft.rfft2(rng.normal(size=(P, P))) * ff ** (-beta / 2) * otf, s=(P, P))
    z = 100.0 * s[:n, :n] / s.std()
    var = 1.0
    noisy = z + rng.normal(0.0, np.sqrt(var), z.shape)
    v, info = noise_floor(noisy, otf, (P, P), var)
    assert not info["used"] and v == var, info
    v, info = noise_floor(noisy + rng.normal(0.0, np.sqrt(9.0 * var), z.shape), otf, (P, P), var)
    assert info["used"] and 6.0 * var < v < 12.0 * var, info


def test_a_constant_crop_is_not_raised():
    """A constant crop (no scene, no noise) has nothing to fit: not raised, no error (a math domain error before)."""
    n = 64
    v, info = noise_floor(np.full((n, n), 300.0), np.ones((n, n // 2 + 1)), (n, n), 0.09)
    assert not info["used"] and v == 0.09, info


@pytest.mark.xfail(strict=True, reason="known: through a PSF that passes everything, an anisotropic scene's power in "
                   "the partial rings beyond 1/2 cycle per pixel (the diagonals) is taken for a flat excess; fitting "
                   "whole rings only fixes it but loses the excess on blurred crops (5 deconvolution tests fail)")
def test_an_anisotropic_scene_seen_sharply_is_not_taken_for_noise():
    """A stationary scene whose spectrum is elongated along the diagonal, (u'^2 + 0.05 v'^2)^-1 in axes turned by 45
    degrees, through a PSF that passes everything, noise stated right, should not be raised (an independent check
    found it raised 6e4-1.4e5x, costing 30-46 dB downstream)."""
    rng = np.random.default_rng(3)
    n = 128
    fy, fx = np.fft.fftfreq(n)[:, None], np.fft.fftfreq(n)[None, :]
    a = np.deg2rad(45.0)
    u, v = np.cos(a) * fx + np.sin(a) * fy, -np.sin(a) * fx + np.cos(a) * fy
    spec = np.where((u == 0) & (v == 0), 0.0, 1.0 / np.maximum(u ** 2 + 0.05 * v ** 2, 1e-12))
    s = np.real(np.fft.ifft2(np.fft.fft2(rng.normal(size=(n, n))) * np.sqrt(spec)))
    z = 100.0 * s / s.std() + rng.normal(0.0, 0.3, (n, n))
    v_, info = noise_floor(z, np.ones((n, n // 2 + 1)), (n, n), 0.09)
    assert not info["used"] and v_ == 0.09, info

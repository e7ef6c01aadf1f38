"""PSF-aware separation and deconvolution (:mod:`metafovea.reconstruct.deconvolve`): against scenes and PSFs built
here with numpy (an independent forward model: a larger scene blurred by direct convolution and cropped, so the
boundary is real), against the simulator's own truth, and bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import fftconvolve

from metafovea.errors import InputError
from metafovea.radiometry import BandRadiance
from metafovea.reconstruct import ChannelPSFs, separate_deconvolve, wiener_bound
from metafovea.reconstruct.metrics import psnr


def _disk(radius: float, n: int) -> np.ndarray:
    u = np.arange(n) - n // 2
    d = (np.hypot(u[:, None], u[None, :]) <= radius).astype(float)
    return d / d.sum()


def _gauss(sigma: float, n: int) -> np.ndarray:
    u = np.arange(n) - n // 2
    g = np.exp(-0.5 * (u[:, None] ** 2 + u[None, :] ** 2) / sigma ** 2)
    return g / g.sum()


def _scene(rng: np.random.Generator, n: int) -> np.ndarray:
    """Piecewise-constant rectangles on a level (DN above the dark level)."""
    s = np.full((n, n), 200.0)
    for _ in range(40):
        y, x = rng.integers(0, n - 8, 2)
        h, w = rng.integers(3, n // 4, 2)
        s[y:y + h, x:x + w] += rng.uniform(-60, 60)
    return s


def _case(seed: int, *, core: float = 0.3, sigma: float = 1.0, n: int = 96, T: int = 24):
    rng = np.random.default_rng(seed)
    big = 3 * n
    k1 = core * _gauss(1.2, 15)
    k1 = np.pad(k1, 10) + (1 - core) * _disk(12, 35)
    k2 = 0.7 * np.pad(_gauss(0.8, 9), 6) + 0.3 * _disk(6, 21)
    s1, s2 = _scene(rng, big), _scene(rng, big)
    c = slice(n, 2 * n)
    u1 = fftconvolve(s1, k1, mode="same")[c, c]
    u2 = fftconvolve(s2, k2, mode="same")[c, c]
    a = np.cos(np.linspace(0, 2 * np.pi, T, endpoint=False) + 0.3) ** 2
    frames = a[:, None, None] * u1 + (1 - a[:, None, None]) * u2 + rng.normal(0, sigma, (T, n, n))
    return frames, a, ChannelPSFs((k1, k2)), (s1[c, c], s2[c, c]), (u1, u2)


def test_brightness_temperature_inverts_band_radiance():
    band = BandRadiance.from_band((8.0, 14.0))
    t = np.linspace(250.0, 400.0, 31)
    assert np.max(np.abs(band.temperature(band(t)) - t)) < 0.01
    assert np.isnan(band.temperature(-1.0))


def test_identity_psfs_without_noise_give_the_separated_images():
    rng = np.random.default_rng(1)
    x1, x2 = rng.uniform(100, 200, (2, 32, 32))
    a = np.linspace(0.05, 0.95, 6)
    frames = a[:, None, None] * x1 + (1 - a[:, None, None]) * x2
    d = np.zeros((1, 1)) + 1.0
    res = separate_deconvolve(frames, a, ChannelPSFs((d, d)), sigma=1e-6)
    assert np.max(np.abs(res.scene[0] - x1)) < 1e-3 and np.max(np.abs(res.scene[1] - x2)) < 1e-3


@pytest.mark.parametrize("seed", [3, 8])
def test_wiener_recovers_the_scene_at_or_near_the_bound(seed):
    frames, a, psfs, truth, hazy = _case(seed)
    w = separate_deconvolve(frames, a, psfs, method="wiener")
    bound = wiener_bound(frames, a, psfs, truth, sigma=1.0)
    for i in range(2):
        p, pb, ph = psnr(w.scene[i], truth[i]), psnr(bound[i], truth[i]), psnr(hazy[i], truth[i])
        assert p > ph + 3.0, (i, p, ph)  # far better than the blurred image itself
        assert p > pb - 1.0, (i, p, pb)  # the fitted prior is within 1 dB of the true spectrum's
    # the noise estimate from the residuals is the frames' noise
    assert abs(w.info["sigma_dn"] - 1.0) < 0.05


def test_tv_beats_wiener_on_piecewise_constant_scenes():
    frames, a, psfs, truth, _ = _case(5)
    w = separate_deconvolve(frames, a, psfs, method="wiener")
    t = separate_deconvolve(frames, a, psfs, method="tv", iterations=60)
    gain = [psnr(t.scene[i], truth[i]) - psnr(w.scene[i], truth[i]) for i in range(2)]
    assert min(gain) > 0.5, gain
    assert t.info["admm_iterations"] == 60 and len(t.info["tv_weight"]) == 2


def test_bad_input_is_refused():
    frames, a, psfs, _, _ = _case(2, n=32, T=6)
    with pytest.raises(InputError, match="frames"):
        separate_deconvolve(frames[:2], a[:2], psfs)
    with pytest.raises(InputError, match="alpha"):
        separate_deconvolve(frames, a[:-1], psfs)
    with pytest.raises(InputError, match="alpha"):
        separate_deconvolve(frames, np.full(6, 0.5), psfs)
    with pytest.raises(InputError, match="psf_x1"):
        ChannelPSFs((np.ones((4, 4)), np.ones((3, 3))))
    with pytest.raises(InputError, match="pedestal_x2"):
        ChannelPSFs((np.ones((3, 3)), np.ones((3, 3))), pedestals=(0.0, -0.1))
    # a rounding residue below 0 (kernel sum minus its own sum) is a pedestal of 0
    assert ChannelPSFs((np.ones((3, 3)), np.ones((3, 3))), pedestals=(0.0, -2.2e-16)).pedestals == (0.0, 0.0)
    with pytest.raises(InputError, match="method"):
        separate_deconvolve(frames, a, psfs, method="richardson")


def test_simulator_psfs_reproduce_its_images(designs_dir):
    """The pixel-grid PSF the simulator writes is the operator it applied: its truth image is the scene truth
    convolved with it (edge-padded) to a few per cent of the image's contrast."""
    from metafovea.config import load_system
    from metafovea.imaging.simulate import simulate

    m = simulate(load_system(designs_dir / "system.toml"), "bars", rng=4, frames=4, filter_enabled=True, psf="airy",
                 noise=False, quantize=False, fpn_rank=0, calibration_frames=0)
    dark = m.meta["dark_dn"]
    k = m.extras["psf_x2"].astype(float)
    ped = m.meta["psf"]["pixel"]["x2"]["pedestal"]
    s = m.extras["scene_x2"].astype(float) - dark
    r = k.shape[0] // 2
    pred = m.extras["illumination_x2"] * (fftconvolve(np.pad(s, r, mode="edge"), k, mode="valid") + ped * s.mean())
    t = m.truth_x2.astype(float) - dark
    assert np.sqrt(np.mean((pred - t) ** 2)) < 0.05 * np.std(t)
    assert abs(k.sum() + ped - 1.0) < 0.01


@pytest.mark.parametrize("seed", [4, 12])
def test_the_fixed_patterns_error_counts_as_noise(seed):
    """A static error left by the FPN estimate (low-rank stripes, the same in every frame) does not average over the
    frames: counted in the noise model (``fpn_error_dn``) the estimate gains several dB; the bound computed with it
    is no better than the estimate by more than the usual margin."""
    frames, a, psfs, truth, _ = _case(seed, T=48)
    rng = np.random.default_rng(seed + 100)
    n = frames.shape[-1]
    e = rng.normal(0, 1, (n, 6)) @ rng.normal(0, 1, (6, n))
    e *= 0.5 / e.std()
    fr = frames + e[None]
    plain = separate_deconvolve(fr, a, psfs)
    counted = separate_deconvolve(fr, a, psfs, fpn_error_dn=0.5)
    assert counted.info["fpn_error_dn"] == 0.5
    bound = wiener_bound(fr, a, psfs, truth, sigma=1.0, fpn_error_dn=0.5)
    for i in range(2):
        p0, p1 = psnr(plain.scene[i], truth[i]), psnr(counted.scene[i], truth[i])
        assert p1 > p0 + 5.0, (i, p0, p1)
        assert p1 > psnr(bound[i], truth[i]) - 1.0
    with pytest.raises(InputError, match="fpn_error_dn"):
        separate_deconvolve(fr, a, psfs, fpn_error_dn=-1.0)


def _star(n: int, spokes: int) -> np.ndarray:
    u = np.arange(n) - (n - 1) / 2
    return 200.0 + 60.0 * np.sign(np.sin(spokes * np.arctan2(u[:, None], u[None, :])))


@pytest.mark.parametrize("n, spokes", [(96, 16), (128, 24)])
def test_the_measured_prior_is_the_padded_scenes_spectrum(n, spokes):
    """Where the hybrid prior is measured (strong signal below the fitted tail), it is the power spectrum of the
    scene the solve is posed on: the crop with its edge-extended padding, whose stripes hold most of the low
    frequencies' power (the quantity the Wiener bound takes from the truth). A haze-dominated PSF (5 % core) and a
    spoked scene, as the siemens star's foveal channel; the crop's own periodogram scaled by its share was 10-300x
    too low there."""
    from metafovea.reconstruct import deconvolve as dc

    rng = np.random.default_rng(n)
    k = 0.05 * np.pad(_gauss(1.2, 15), 10) + 0.95 * _disk(12, 35)
    s = _star(n, spokes) + rng.normal(0, 5, (n, n))
    g = dc._Grid((n, n), (k, k), (0.0, 0.0))
    S = g.rfft(g.padded(s - s.mean()))
    z = g.irfft(g.D[0] * S)[g.crop] + rng.normal(0, 0.5, (n, n))
    scale = np.sqrt(n * n / float(g.shape[0] * g.shape[1]))
    est, info = dc._fitted_spectrum(g, z, 0.25, g.D[0], "hybrid", scale)
    fc, truth = dc._radial_mean(g, np.abs(S) ** 2, nbins=64)
    _, prior = dc._radial_mean(g, est, nbins=64)
    sel = (fc > 0) & (fc < info["measured_below_cycles_per_px"])
    assert sel.sum() >= 5, info
    ratio = prior[sel] / truth[sel]
    assert 1 / 3 < np.exp(np.mean(np.log(ratio))) < 3, ratio
    assert np.all((ratio > 0.1) & (ratio < 10)), ratio


def test_the_foveal_surround_keeps_only_what_the_perifoveal_channel_resolves():
    """The predicted surround enters the foveal padding only below the perifoveal Nyquist frequency (0.5 / scale
    cycles per foveal pixel): a perifoveal estimate full of pixel-scale detail, magnified 6x, leaves < 1 % of the
    padding's added power above 1 / scale, and the padding meets the data's edge at the crop."""
    from metafovea.reconstruct import deconvolve as dc

    n, scale = 64, 6.0
    rng = np.random.default_rng(2)
    k = np.pad(_gauss(0.8, 9), 6)  # a sharp foveal PSF: the prediction's detail is not blurred away
    g = dc._Grid((n, n), (k, k), (0.0, 0.0))
    zc = np.stack([np.full((n, n), 100.0), np.full((n, n), 100.0)])
    pb = dc._Problem(g, zc, np.eye(2))
    s = np.zeros((2,) + g.shape)
    s[1][g.crop] = 100.0 + 20.0 * rng.standard_normal((n, n))
    before = pb.z[0].copy()
    dc._foveal_surround(pb, s, scale, 1.0)
    added = pb.z[0] - before
    assert np.array_equal(pb.z[0][g.crop], zc[0])
    P = np.abs(g.rfft(added)) ** 2
    P[0, 0] = 0.0
    assert np.sum(P[g.f > 1.0 / scale]) < 0.01 * np.sum(P), np.sum(P[g.f > 1.0 / scale]) / np.sum(P)
    assert np.std(added) > 1.0  # the surround did change the padding
    cy, cx = g.crop
    ring = np.abs(added[cy.start - 1, cx]).mean()
    assert ring < 0.5 * np.abs(added).max(), ring


def test_the_foveal_surround_continues_a_smooth_field_the_prediction_lacks():
    """Light from beyond the predicted surround (the PSF's widest disks) adds a smooth field over the crop: the
    padding continues the data's level and slope (a quadratic surface fitted to data less prediction) instead of
    stepping to the bare prediction."""
    from metafovea.reconstruct import deconvolve as dc

    n, scale = 64, 6.0
    k = np.zeros((61, 61))
    k[30, 30] = 1.0  # an identity PSF wide enough for 30 px of padding
    g = dc._Grid((n, n), (k, k), (0.0, 0.0))
    P, Q = g.shape
    v, u = np.meshgrid((np.arange(P) - g.pad - (n - 1) / 2) / n, (np.arange(Q) - g.pad - (n - 1) / 2) / n,
                       indexing="ij")
    field = 0.8 + 0.5 * v - 0.3 * u + 0.4 * u * u
    zc = np.stack([100.0 + field[g.crop], np.full((n, n), 100.0)])
    pb = dc._Problem(g, zc, np.eye(2))
    s = np.zeros((2,) + g.shape)
    s[1][g.crop] = 100.0  # the perifoveal scene predicts a uniform 100 DN surround
    rms = dc._foveal_surround(pb, s, scale, 1.0)
    assert rms == pytest.approx(np.sqrt(np.mean(field[g.crop] ** 2)), rel=1e-6)
    far = np.ones(g.shape, dtype=bool)
    cy, cx = g.crop
    far[cy.start - 12:cy.stop + 12, cx.start - 12:cx.stop + 12] = False
    far[:12] = far[P - 12:] = False  # the periodic grid's seam: the low-pass wraps around
    far[:, :12] = far[:, Q - 12:] = False
    assert far.sum() > 500
    err = np.abs(pb.z[0] - (100.0 + field))[far]
    assert err.max() < 0.05 * np.abs(field[far]).max(), (err.max(), np.abs(field[far]).max())

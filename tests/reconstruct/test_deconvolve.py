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
from tests.independent.forward import disk_kernel, gauss_kernel


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
    k1 = core * gauss_kernel(1.2, 15)
    k1 = np.pad(k1, 10) + (1 - core) * disk_kernel(12, 35)
    k2 = 0.7 * np.pad(gauss_kernel(0.8, 9), 6) + 0.3 * disk_kernel(6, 21)
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


def _texture_case(seed: int, *, sigma: float, n: int = 96, T: int = 24):
    """Gaussian scenes with a 1/f^2 power spectrum (natural images' [Field 1987]), where the linear estimate with
    the true spectrum is the best estimate there is: a non-linear method can only match it."""
    rng = np.random.default_rng(seed)
    big = 3 * n
    f = np.hypot(np.fft.fftfreq(big)[:, None], np.fft.fftfreq(big)[None, :])
    f[0, 0] = 1.0

    def scene():
        return 200.0 + 3.0 * np.real(np.fft.ifft2(np.fft.fft2(rng.standard_normal((big, big))) / f))

    k1 = np.pad(0.3 * gauss_kernel(1.2, 15), 10) + 0.7 * disk_kernel(12, 35)
    k2 = 0.7 * np.pad(gauss_kernel(0.8, 9), 6) + 0.3 * disk_kernel(6, 21)
    s1, s2 = scene(), scene()
    c = slice(n, 2 * n)
    u1 = fftconvolve(s1, k1, mode="same")[c, c]
    u2 = fftconvolve(s2, k2, mode="same")[c, c]
    a = np.cos(np.linspace(0, 2 * np.pi, T, endpoint=False) + 0.3) ** 2
    frames = a[:, None, None] * u1 + (1 - a[:, None, None]) * u2 + rng.normal(0, sigma, (T, n, n))
    return frames, a, ChannelPSFs((k1, k2)), (s1[c, c], s2[c, c])


@pytest.mark.parametrize("seed, sigma", [(3, 1.0), (8, 1.0), (5, 3.0)])
def test_wavelet_beats_the_linear_bound_on_piecewise_constant_scenes(seed, sigma):
    """The Fourier-wavelet estimate sits well above the best linear estimate (true spectrum, true noise) where the
    scene has edges and flat regions, with its regularisation chosen from the data alone."""
    frames, a, psfs, truth, _ = _case(seed, sigma=sigma)
    w = separate_deconvolve(frames, a, psfs, method="wavelet")
    bound = wiener_bound(frames, a, psfs, truth, sigma=sigma)
    margin = [psnr(w.scene[i], truth[i]) - psnr(bound[i], truth[i]) for i in range(2)]
    assert min(margin) > 1.0, margin
    assert w.info["wavelet"] == "haar" and [r["tau"] for r in w.info["risk_curve"]["x1"]][0] == 1.0
    assert len(w.info["tau"]) == 2 and all(0 < t <= 1 for t in w.info["tau"])


@pytest.mark.parametrize("seed, sigma", [(1, 1.0), (2, 3.0)])
def test_wavelet_matches_the_linear_bound_on_gaussian_textures(seed, sigma):
    frames, a, psfs, truth = _texture_case(seed, sigma=sigma)
    w = separate_deconvolve(frames, a, psfs, method="wavelet")
    bound = wiener_bound(frames, a, psfs, truth, sigma=sigma)
    margin = [psnr(w.scene[i], truth[i]) - psnr(bound[i], truth[i]) for i in range(2)]
    assert min(margin) > -0.3, margin


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
    with pytest.raises(InputError, match="pad_mode"):  # numpy's own ValueError before
        separate_deconvolve(frames, a, psfs, pad_mode="bogus")
    with pytest.raises(InputError, match="1 x 1 px"):  # a crop without a frequency: numpy's ValueError before
        separate_deconvolve(frames[:, :1, :1], a, psfs)
    with pytest.raises(InputError, match="pad_mode"):  # pads towards 0 DN: hundreds of DN off before
        separate_deconvolve(frames, a, psfs, pad_mode="constant")
    with pytest.raises(InputError, match="1 x 32 px"):  # TV's weight has no gradient to scale by: all NaN before
        separate_deconvolve(frames[:, :1, :], a, psfs, method="tv")


def test_a_one_pixel_psf_takes_nothing_from_beyond_the_crop():
    """A perifoveal PSF of one pixel: no light from beyond the crop reaches it, so the edge values stay and the
    output says why (the ring had width 0 and its misfit was taken over the whole crop, said to be its edge)."""
    frames, a, psfs, _, _ = _case(4, n=32, T=6)
    one = ChannelPSFs((psfs.kernels[0], np.ones((1, 1))))
    d = separate_deconvolve(frames, a, one, method="wiener")
    padded = separate_deconvolve(frames, a, one, method="wiener", boundary="padded")
    assert d.info["exterior"]["kept"] == "padded" and "one pixel" in d.info["exterior"]["why"]
    assert np.array_equal(d.scene, padded.scene)


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
    frames: counted in the noise model (``fpn_error_dn``), or left unstated and found in the data's flat excess
    (spectra eq. 5; before it, the unstated error cost over 5 dB), the estimate is within the usual margin of the
    bound computed with it."""
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
    assert plain.info["noise_floor"]["raised"] == [True, True]
    assert counted.info["noise_floor"]["raised"] == [False, False]
    for i in range(2):
        p0, p1, pb = psnr(plain.scene[i], truth[i]), psnr(counted.scene[i], truth[i]), psnr(bound[i], truth[i])
        assert p1 > pb - 1.0 and p0 > pb - 1.0, (i, p0, p1, pb)
    with pytest.raises(InputError, match="fpn_error_dn"):
        separate_deconvolve(fr, a, psfs, fpn_error_dn=-1.0)



def _star(n: int, spokes: int) -> np.ndarray:
    u = np.arange(n) - (n - 1) / 2
    return np.sign(np.sin(spokes * np.arctan2(u[:, None], u[None, :])))


def _radial(power: np.ndarray, shape: tuple[int, int], nbins: int = 64) -> np.ndarray:
    """Radial mean of an rfft2-shaped ``power`` in ``nbins`` bins of |f| up to 0.5 sqrt 2 cycles/px."""
    f = np.hypot(np.fft.fftfreq(shape[0])[:, None], np.fft.rfftfreq(shape[1])[None, :])
    idx = np.clip(np.digitize(f.ravel(), np.linspace(0.0, 0.5 * np.sqrt(2), nbins + 1)) - 1, 0, nbins - 1)
    cnt = np.bincount(idx, minlength=nbins)
    return np.bincount(idx, weights=power.ravel(), minlength=nbins) / np.maximum(cnt, 1)


@pytest.mark.parametrize("n, spokes", [(96, 16), (128, 24)])
def test_the_measured_prior_is_the_padded_scenes_spectrum(n, spokes):
    """Where the hybrid prior is measured (strong signal below the fitted tail), it is the power spectrum of the
    scene the solve is posed on: the crop with its edge-extended padding, whose stripes hold most of the low
    frequencies' power (what the Wiener bound takes from the truth; computed here with numpy from the true scene).
    A spoked scene wider than the crop behind a haze-dominated PSF (5 % core), as the siemens star's foveal
    channel; the crop's own periodogram scaled by its share (the prior before 2026-12-03) was 10-300x too low in
    most of those bins."""
    rng = np.random.default_rng(n)
    T = 24
    big = 200.0 + 60.0 * _star(3 * n, spokes) + rng.normal(0, 5, (3 * n, 3 * n))
    k = 0.05 * np.pad(gauss_kernel(1.2, 15), 10) + 0.95 * disk_kernel(12, 35)
    c = slice(n, 2 * n)
    u = fftconvolve(big, k, mode="same")[c, c]
    a = np.cos(np.linspace(0, 2 * np.pi, T, endpoint=False) + 0.3) ** 2
    frames = a[:, None, None] * u + (1 - a[:, None, None]) * u[::-1] + rng.normal(0, 0.5, (T, n, n))
    w = separate_deconvolve(frames, a, ChannelPSFs((k, k)))
    P, Q = w.info["grid"]
    p = w.info["pad_px"]
    t = big[c, c] - big[c, c].mean()
    truth = _radial(np.abs(np.fft.rfft2(np.pad(t, ((p, P - n - p), (p, Q - n - p)), mode="edge"))) ** 2, (P, Q))
    rad = w.info["prior_radial"]
    fc, prior = np.asarray(rad["cycles_per_px"]), np.asarray(rad["x1"])
    sel = (fc > 0) & (fc < w.info["prior_fit"][0]["measured_below_cycles_per_px"])
    assert sel.sum() >= 5, w.info["prior_fit"][0]
    # (the lowest bins are the edge stripes of a sharp scene against those of its hazy image: a few x low)
    ratio = prior[sel] / truth[sel]
    assert 1 / 4 < np.exp(np.mean(np.log(ratio))) < 4, ratio  # the former prior: 0.034 and 0.082
    assert 1 / 3 < np.median(ratio) < 3, ratio


def _zoomed_pair(seed: int, foveal: str, *, n: int = 96, field_dn: float = 0.0, core: float = 0.05, T: int = 48):
    """Frames of a foveal channel that images the centre of the perifoveal field magnified 6x (an independent
    forward model: cubic zoom, direct convolution of scenes 3x wider than the crop). ``foveal='zoom'``: the foveal
    scene is the perifoveal field's (all its detail is resolved by the perifoveal channel); ``'spokes'``: a spoked
    pattern finer than the perifoveal channel resolves near the centre. ``field_dn``: a smooth quadratic field added
    to the foveal image (light from beyond the surround), its mean level in DN."""
    from scipy.ndimage import gaussian_filter, map_coordinates

    rng = np.random.default_rng(seed)
    N, scale = 3 * n, 6.0
    g = np.arange(N) - (N - 1) / 2
    if foveal == "zoom":
        S2 = _scene(rng, N) + 40.0 * gaussian_filter(rng.standard_normal((N, N)), 1.5)
        t = g / scale + (N - 1) / 2
        S1 = map_coordinates(S2, np.meshgrid(t, t, indexing="ij"), order=3)
    else:
        S1 = 200.0 + 40.0 * _star(N, 32)
        t = g * scale + (N - 1) / 2
        S2 = map_coordinates(S1, np.meshgrid(t, t, indexing="ij"), order=1, mode="nearest")
    k1 = core * np.pad(gauss_kernel(1.2, 15), 10) + (1 - core) * disk_kernel(12, 35)
    k2 = 0.7 * np.pad(gauss_kernel(0.8, 9), 6) + 0.3 * disk_kernel(6, 21)
    c = slice(n, 2 * n)
    v, u = np.meshgrid((np.arange(n) - (n - 1) / 2) / n, (np.arange(n) - (n - 1) / 2) / n, indexing="ij")
    field = field_dn * (1.0 + 1.5 * v - 1.0 * u + 2.0 * u * u)
    u1 = fftconvolve(S1, k1, mode="same")[c, c] + field
    u2 = fftconvolve(S2, k2, mode="same")[c, c]
    a = np.cos(np.linspace(0, 2 * np.pi, T, endpoint=False) + 0.3) ** 2
    frames = a[:, None, None] * u1 + (1 - a[:, None, None]) * u2 + rng.normal(0, 1.0, (T, n, n))
    return frames, a, ChannelPSFs((k1, k2)), (S1[c, c], S2[c, c]), field


@pytest.mark.parametrize("seed", [1, 2])
def test_the_foveal_surround_follows_what_the_perifoveal_channel_resolves(seed):
    """Where the perifoveal channel resolves all of the foveal surround's detail, the padding is its prediction
    (x1 10 dB and more above the edge-padded estimate; joining the data's edge stripes cost 10-16 dB here); where
    the foveal scene has detail finer than that (spokes crossing the crop's edge), the data's edge values join it.
    The choice is the one whose solution explains the foveal data better."""
    fr, a, psfs, truth, _ = _zoomed_pair(seed, "zoom")
    w = separate_deconvolve(fr, a, psfs, foveal_scale=6.0, foveal_ratio=1.0)
    w0 = separate_deconvolve(fr, a, psfs)
    assert w.info["foveal_surround_join"] is False
    assert psnr(w.scene[0], truth[0]) > psnr(w0.scene[0], truth[0]) + 10.0
    fr, a, psfs, truth, _ = _zoomed_pair(seed, "spokes", core=0.3)
    # the linear step alone (the wavelet step's tau may differ between the two boundaries: that is not the point)
    w = separate_deconvolve(fr, a, psfs, foveal_scale=6.0, foveal_ratio=1.0, method="wiener")
    w0 = separate_deconvolve(fr, a, psfs, method="wiener")
    assert w.info["foveal_surround_join"] is True
    assert psnr(w.scene[0], truth[0]) > psnr(w0.scene[0], truth[0]) - 0.3


def test_the_foveal_surround_carries_a_smooth_field_the_prediction_lacks():
    """Light from beyond the predicted surround adds a smooth field over the foveal crop: the quadratic surface
    fitted to data less prediction recovers it (its rms against the field added here), and the padding continues
    it instead of stepping to the bare prediction."""
    fr, a, psfs, truth, field = _zoomed_pair(3, "zoom", field_dn=3.0)
    w = separate_deconvolve(fr, a, psfs, foveal_scale=6.0, foveal_ratio=1.0)
    w0 = separate_deconvolve(fr, a, psfs)
    true_rms = float(np.sqrt(np.mean(field ** 2)))
    assert w.info["foveal_surround_surface_rms_dn"] == pytest.approx(true_rms, rel=0.1)
    assert psnr(w.scene[0], truth[0]) > psnr(w0.scene[0], truth[0]) + 3.0


@pytest.mark.parametrize("seed", [1, 2])
def test_the_foveal_fusion_weighs_the_perifoveal_estimate_by_what_the_foveal_noise_explains(seed):
    """Eq. (5) on the independent zoomed pair: where the perifoveal channel resolves the fovea's detail and the
    foveal channel is hazy (5 % of its light in the core), the foveal estimate's coarse detail gains from the
    perifoveal estimate and the perifoveal crop from the foveal one; where the fovea holds detail finer than the
    perifoveal channel resolves (spokes), the two disagree and the foveal weights fall to ~0, the estimate unchanged
    (this model's perifoveal spokes are point samples, aliased, not the pixel means the relation holds for: there the
    perifoveal crop may lose a little); with the scale stated 5 % off, or the gain ratio 10 % off, the foveal weights
    drop and nothing is lost."""
    def both(fr, a, psfs, scale=6.0, ratio=1.0):
        on = separate_deconvolve(fr, a, psfs, foveal_scale=scale, foveal_ratio=ratio)
        off = separate_deconvolve(fr, a, psfs, foveal_scale=scale, foveal_ratio=ratio, foveal_fusion=False)
        assert "foveal_fusion" not in off.info
        return on, off

    fr, a, psfs, truth, _ = _zoomed_pair(seed, "zoom")
    on, off = both(fr, a, psfs)
    w = np.array(on.info["foveal_fusion"]["weights_x1"])
    assert w[0] == 0.0 and np.all((w >= 0) & (w <= 1)) and w[1:].max() > 0.02
    gain = psnr(on.scene[0], truth[0]) - psnr(off.scene[0], truth[0])
    assert gain > 0.1 and psnr(on.scene[1], truth[1]) > psnr(off.scene[1], truth[1]) + 0.01
    assert any(line.startswith("foveal fusion, ") and f"{w[1]:.2f}" in line for line in on.lines())
    assert on.summary()["foveal_fusion"]["weights_x1"] == list(w)
    for scale, ratio in ((6.3, 1.0), (6.0, 1.1)):
        bad_on, bad_off = both(fr, a, psfs, scale, ratio)
        for i in range(2):
            assert psnr(bad_on.scene[i], truth[i]) > psnr(bad_off.scene[i], truth[i]) - 0.01
    assert np.mean(bad_on.info["foveal_fusion"]["weights_x1"][1:]) < np.mean(w[1:])  # the gain ratio's error
    small = separate_deconvolve(fr[:, :40, :40], a, psfs, foveal_scale=6.0, foveal_ratio=1.0)
    assert small.info["foveal_fusion"]["applied"] is False  # under 8 perifoveal pixels of fovea: no rings to weigh
    fr, a, psfs, truth, _ = _zoomed_pair(seed, "spokes", core=0.3)
    on, off = both(fr, a, psfs)
    assert max(on.info["foveal_fusion"]["weights_x1"]) < 0.02
    assert abs(psnr(on.scene[0], truth[0]) - psnr(off.scene[0], truth[0])) < 0.02
    assert psnr(on.scene[1], truth[1]) > psnr(off.scene[1], truth[1]) - 0.15


def test_boundary_names_say_what_they_do():
    """``boundary='solved'`` (the perifoveal scene beyond the crop solved for) is the default and says so;
    ``'padded'`` (the crop extended by its edge values) is the option, the former name ``'mirror'`` still gives
    its result, with a DeprecationWarning; an unknown name is refused."""
    frames, a, psfs, _, _ = _case(6, n=32, T=6)
    default = separate_deconvolve(frames, a, psfs)
    assert default.info["boundary"] == "solved" and default.info["exterior"]["channel"] == "x2"
    padded = separate_deconvolve(frames, a, psfs, boundary="padded")
    assert padded.info["boundary"] == "padded" and "exterior" not in padded.info
    with pytest.warns(DeprecationWarning, match="padded"):
        old = separate_deconvolve(frames, a, psfs, boundary="mirror")
    assert old.info["boundary"] == "padded"
    assert all(np.array_equal(x, y) for x, y in zip(old.scene, padded.scene))
    with pytest.raises(InputError, match="boundary"):
        separate_deconvolve(frames, a, psfs, boundary="periodic")
    for name, v in (("exterior_px", 0), ("exterior_iterations", -1)):
        with pytest.raises(InputError, match=name):
            separate_deconvolve(frames, a, psfs, **{name: v})


def test_a_field_the_camera_does_not_see_is_refused_with_its_cause():
    """A relative illumination of 0 (a train that vignettes part of the field to nothing) is refused naming the
    fraction of the crop and the cause, not deconvolved into a division by zero."""
    import numpy as np
    import pytest

    from metafovea.errors import InputError
    from metafovea.reconstruct import ChannelPSFs, separate_deconvolve

    rng = np.random.default_rng(0)
    H = W = 16
    k = np.zeros((5, 5))
    k[2, 2] = 1.0
    dark = np.ones((H, W))
    dark[:, :4] = 0.0
    psfs = ChannelPSFs(kernels=(k, k), pedestals=(0.0, 0.0), illumination=(dark, None))
    alpha = np.linspace(0.1, 0.9, 6)
    frames = rng.normal(100.0, 1.0, (6, H, W))
    with pytest.raises(InputError, match=r"illumination_x1.*25\.0 % of the crop.*vignettes"):
        separate_deconvolve(frames, alpha, psfs, method="wiener")


@pytest.mark.parametrize("seed", [2, 9])
def test_the_perifoveal_scene_beyond_the_crop_is_solved_for_not_padded(seed):
    """A scene that does not continue its edge beyond the crop (a warmer surround all round, as a raster scene's
    background meets its edge): the default ``boundary='solved'`` (the scene beyond the crop solved for in a ring)
    recovers the perifoveal channel far better than the edge-padded solve, and beats the linear bound, which pads
    with edge values; a scene that continues beyond the crop loses nothing by it."""
    rng = np.random.default_rng(seed)
    n, T, sigma = 96, 24, 0.5
    big = 3 * n
    c = slice(n, 2 * n)
    k1 = gauss_kernel(1.0, 9)
    k2 = 0.6 * np.pad(gauss_kernel(0.7, 9), 6) + 0.4 * disk_kernel(4, 21)
    s1, s2 = _scene(rng, big), _scene(rng, big)
    surround = s2.copy()
    surround[:n] += 150.0
    surround[2 * n:] += 150.0
    surround[:, :n] += 150.0
    surround[:, 2 * n:] += 150.0
    a = np.cos(np.linspace(0, 2 * np.pi, T, endpoint=False) + 0.3) ** 2
    noise = rng.normal(0, sigma, (T, n, n))
    u1 = fftconvolve(s1, k1, mode="same")[c, c]
    psfs = ChannelPSFs((k1, k2))
    gains = []
    for scene2 in (surround, s2):
        u2 = fftconvolve(scene2, k2, mode="same")[c, c]
        frames = a[:, None, None] * u1 + (1 - a[:, None, None]) * u2 + noise
        truth = (s1[c, c], scene2[c, c])
        solved = separate_deconvolve(frames, a, psfs)
        padded = separate_deconvolve(frames, a, psfs, boundary="padded")
        bound = wiener_bound(frames, a, psfs, truth, sigma=sigma)
        p_solved, p_padded = psnr(solved.scene[1], truth[1]), psnr(padded.scene[1], truth[1])
        assert p_solved > psnr(bound[1], truth[1]), (p_solved, psnr(bound[1], truth[1]))
        gains.append(p_solved - p_padded)
        ex = solved.info["exterior"]
        assert ex["iterations"] >= 1 and ex["kept"] in ("solved", "padded") and ex["why"]
        assert any(line.startswith(f"beyond the perifoveal crop ({ex['kept']})") for line in solved.lines())
        if scene2 is surround:  # the edge values misfit the data the surround's light reaches through the core
            assert ex["kept"] == "solved", ex
            assert ex["edge_misfit_dn2"]["padded"] - ex["edge_misfit_dn2"]["solved"] > ex["misfit_standard_error_dn2"]
    assert gains[0] > 3.0 and gains[1] > -0.3, gains


@pytest.mark.parametrize("method", ["wiener", "wavelet"])
def test_the_mean_of_a_flat_scene_is_not_shrunk(method):
    """A flat scene, as the convolution of an independent model makes it: its fitted prior is tiny at every
    frequency (no detected signal), and still the estimate's mean is the scene's (the solve's numerical floor is
    set by the data term, not by the prior's inverse, which made the Wiener estimate 2-3 % low)."""
    rng = np.random.default_rng(5)
    n, T = 64, 48
    k1 = 0.3 * np.pad(gauss_kernel(1.2, 15), 10) + 0.7 * disk_kernel(12, 35)
    k2 = 0.7 * np.pad(gauss_kernel(0.8, 9), 6) + 0.3 * disk_kernel(6, 21)
    level = (1000.0, 800.0)
    a = np.cos(np.linspace(0, 2 * np.pi, T, endpoint=False) + 0.3) ** 2
    u = [fftconvolve(np.full((3 * n, 3 * n), v), k, mode="same")[n:2 * n, n:2 * n] for v, k in zip(level, (k1, k2))]
    frames = a[:, None, None] * u[0] + (1 - a[:, None, None]) * u[1] + rng.normal(0, 1.0, (T, n, n))
    res = separate_deconvolve(frames, a, ChannelPSFs((k1, k2)), method=method)
    for est, v in zip(res.scene, level):
        assert abs(float(np.mean(est)) - v) < 0.5, (method, float(np.mean(est)), v)


@pytest.mark.parametrize("seed", [0, 3])
def test_noise_the_model_leaves_out_is_taken_from_the_data(seed):
    """Frames with almost no temporal noise but a white error the same in every frame (undithered rounding, a fixed
    pattern subtracted with a larger error than stated): the residuals see 0.02 DN, the data hold 0.5 DN. Unmodelled,
    the deconvolution amplifies it into an image 30-50 dB below the Wiener bound with the true noise; the data's flat
    excess (spectra eq. 5) raises the noise model to within 20 % of the truth, said in the output, and the Wiener
    estimate is within 1.5 dB of that bound (its prior is estimated, the bound's is the truth). Frames with the noise
    their model states are left as they were."""
    frames, a, psfs, truth, _ = _case(seed, sigma=0.02, T=48)
    fr = frames + np.random.default_rng(seed + 300).normal(0.0, 0.5, frames.shape[1:])[None]
    bound = wiener_bound(fr, a, psfs, truth, sigma=0.02, fpn_error_dn=0.5)
    for method in ("wiener", None):
        res = separate_deconvolve(fr, a, psfs, **({"method": method} if method else {}))
        nf = res.info["noise_floor"]
        assert nf["raised"] == [True, True] and "noise raised to what the data show" in "\n".join(res.lines())
        for i in range(2):
            assert nf[f"x{i + 1}"]["fitted_dn2"] == pytest.approx(0.25, rel=0.2)
            # the default method at this low noise: see test_low_noise_crops_of_a_wider_scene_lose_the_default_method
            margin = psnr(res.scene[i], truth[i]) - psnr(bound[i], truth[i])
            assert margin > (-1.5 if method else -15.0), (method, i, margin)
    plain = separate_deconvolve(*_case(seed, sigma=1.0)[:3])
    assert plain.info["noise_floor"]["raised"] == [False, False]
    assert "noise raised" not in "\n".join(plain.lines())


@pytest.mark.xfail(strict=True, reason="known (issue 31): the padding's model error enters the wavelet step's risk "
                   "(joint eq. 4) with the wrong sign, magnified by 1/|D|^2, and at low noise it picks a small tau; "
                   "the difference of two padding rules as its estimate fixed this case but lost 0.02-0.26 dB on "
                   "average on the tuning scenes")
@pytest.mark.parametrize("seed", [0, 5])
def test_low_noise_crops_of_a_wider_scene_lose_the_default_method(seed):
    """Piecewise-constant crops of a wider scene through a hazy PSF at 0.3 DN of noise: the default method should be
    within 1 dB of the Wiener bound on both channels, as the Wiener filter is."""
    frames, a, psfs, truth, _ = _case(seed, sigma=0.3, T=48)
    bound = wiener_bound(frames, a, psfs, truth, sigma=0.3)
    res = separate_deconvolve(frames, a, psfs)
    for i in range(2):
        assert psnr(res.scene[i], truth[i]) > psnr(bound[i], truth[i]) - 1.0, i

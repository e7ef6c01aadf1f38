"""metafovea.imaging.kernels: PSF kernels (Gaussian, Airy, explicit, optics with its disk cache), the chromatic
haze and the field-patch decision."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import j0, j1

from metafovea.config import SystemDesign
from metafovea.errors import InputError
from metafovea.imaging import simulate
from metafovea.imaging.channel import channels_for
from metafovea.imaging.kernels import (
    ExplicitPSF,
    Kernel,
    OpticsPSFProvider,
    airy_kernel,
    airy_provider,
    build_channel_optics,
    disk_mixture_kernel,
    gaussian_kernel,
    resolve_provider,
)
from metafovea.radiometry import BandRadiance


def _axis_variance(k: np.ndarray) -> float:
    x = np.arange(k.shape[0]) - k.shape[0] // 2
    return float((k.sum(0) * x ** 2).sum() / k.sum())


# ---------------------------------------------------------------------------------------------
# physics references
# ---------------------------------------------------------------------------------------------
def test_airy_kernel_holds_the_encircled_energy_of_its_window():
    """An Airy kernel's sum is the power inside its square window: between Rayleigh's encircled energy
    ``1 - J0(v)^2 - J1(v)^2`` of the inscribed and of the circumscribed circle; its centre sample is the peak
    ``pi / 4 (p / (lambda N))^2`` of the normalised pattern."""
    size, pitch, lam, n_f = 201, 1.0, 10.0, 1.0
    k = airy_kernel(n_f, lam, pitch, size)

    def ee(r_um):
        v = np.pi * r_um / (lam * n_f)
        return 1 - j0(v) ** 2 - j1(v) ** 2

    half = 0.5 * size * pitch
    assert ee(half) < k.sum() < ee(half * np.sqrt(2))
    assert k[size // 2, size // 2] == pytest.approx(np.pi / 4 * (pitch / (lam * n_f)) ** 2, rel=1e-2)
    np.testing.assert_allclose(k, k.T, rtol=1e-12)
    np.testing.assert_allclose(k, k[::-1], rtol=1e-12)


@pytest.mark.parametrize("sigma", [0.6, 1.5, 3.0])
def test_sample_integrated_gaussian_has_variance_sigma2_plus_one_twelfth(sigma):
    """Integrating a Gaussian over unit samples convolves it with a unit box: variance sigma^2 + 1/12 (less a
    little for the +-4 sigma truncation); the kernel is normalised."""
    k = gaussian_kernel(sigma)
    assert k.shape[0] % 2 == 1 and k.sum() == pytest.approx(1.0, abs=1e-12)
    assert _axis_variance(k) == pytest.approx(sigma ** 2 + 1 / 12, rel=5e-3)


@pytest.mark.parametrize("radius", [3.0, 10.0, 30.0])
def test_disk_kernel_second_moment_is_r2_over_2(radius):
    """A uniform disk of radius r has <x^2 + y^2> = r^2 / 2 (+ 2/12 for the unit samples); normalised."""
    d = disk_mixture_kernel(np.array([radius]), np.array([1.0]), 1.0)
    x = np.arange(d.shape[0]) - d.shape[0] // 2
    m2 = float((d * (x[None, :] ** 2 + x[:, None] ** 2)).sum())
    assert d.sum() == pytest.approx(1.0, abs=1e-12)
    assert m2 == pytest.approx(radius ** 2 / 2 + 1 / 6, rel=3e-3)


def test_disk_mixture_is_the_weighted_sum_of_its_disks():
    d = disk_mixture_kernel(np.array([5.0, 20.0]), np.array([0.25, 0.75]), 1.0)
    x = np.arange(d.shape[0]) - d.shape[0] // 2
    m2 = float((d * (x[None, :] ** 2 + x[:, None] ** 2)).sum())
    assert m2 == pytest.approx(0.25 * 25 / 2 + 0.75 * 400 / 2 + 1 / 6, rel=2e-3)


def test_airy_kernel_is_computed_in_blocks_equal_to_the_plain_grid():
    """--psf-size up to 4097 was accepted and asked the Airy model for a (4097*7)^2 grid (tens of GB)."""
    # block-wise evaluation (size 251 > one block) equals the plain one
    size, sub, pitch, lam, n_f = 251, 7, 3.0, 10.0, 2.0
    u = (np.arange(size * sub) + 0.5) / sub - size / 2.0
    x = u * pitch
    v = np.pi * np.hypot(x[None, :], x[:, None]) / (lam * n_f)
    a = np.where(v > 1e-9, (2 * j1(v) / np.where(v > 1e-9, v, 1.0)) ** 2, 1.0)
    ref = a.reshape(size, sub, size, sub).mean(axis=(1, 3)) / (4.0 / np.pi * (lam * n_f) ** 2 / pitch ** 2)
    np.testing.assert_allclose(airy_kernel(n_f, lam, pitch, size, sub), ref, rtol=1e-12, atol=1e-15)


# ---------------------------------------------------------------------------------------------
# haze and field dependence
# ---------------------------------------------------------------------------------------------
def test_haze_without_filter_and_airy_model(small_system, quiet):
    s = small_system(40)
    m = simulate(s, "siemens-star", frames=2, psf="airy", **quiet)
    for c in ("foveal", "perifoveal"):
        assert m.meta["psf"][c]["haze"]["fraction"] > 0.9
    mf = simulate(s, "siemens-star", frames=2, psf="airy", filter_enabled=True, **quiet)
    # the filter keeps more power near focus: more contrast in the perifoveal image
    assert mf.truth_x2.std() / mf.truth_x2.mean() > m.truth_x2.std() / m.truth_x2.mean()
    assert np.all(np.isfinite(m.frames))


def test_channel_optics_conserve_power_kernel_plus_haze():
    """The kernel (with the near haze folded in) and the far haze together carry the channel's power: 1."""
    s = SystemDesign.paper()
    br = BandRadiance.for_system(s)
    for ch in channels_for(s, shape=(40, 40)):
        o = build_channel_optics(ch, airy_provider, br, ss=2)
        assert o.kernels[0].sum() + o.far_weight == pytest.approx(1.0, abs=1e-9)
        assert o.info["haze"]["fraction"] == pytest.approx(1.0 - o.info["kernel_sum"], abs=1e-12)
        no_haze = build_channel_optics(ch, airy_provider, br, ss=2, haze=False)
        assert no_haze.far_kernel is None and no_haze.kernels[0].sum() == pytest.approx(o.info["kernel_sum"])


def test_field_dependent_psf_patches_decided_and_reported(small_system, gauss_psf, quiet):
    s = small_system(36)
    wide = {"foveal": lambda fld: gaussian_kernel(0.5 + 0.2 * fld, 9), "perifoveal":
            lambda fld: gaussian_kernel(0.5 + 0.3 * fld, 9)}
    m = simulate(s, "bars", frames=1, psf=wide, supersample=1, field_patches="auto", **quiet)
    assert m.meta["psf"]["perifoveal"]["mode"] == "3 x 3 patches"
    assert m.meta["psf"]["foveal"]["mode"] == "shift-invariant"
    assert "TV distance" in m.meta["psf"]["perifoveal"]["patch_decision"]
    # constant kernels in patches give the same image as shift-invariant
    g = gauss_psf()
    a = simulate(s, "camera", frames=1, psf=g, supersample=1, field_patches=1, **quiet)
    b = simulate(s, "camera", frames=1, psf=g, supersample=1, field_patches=3, **quiet)
    np.testing.assert_allclose(a.truth_x2, b.truth_x2, rtol=1e-5)
    assert "a simplification" in a.meta["psf"]["foveal"]["patch_decision"]
    assert b.meta["psf"]["foveal"]["patch_decision"] == "field_patches = 3: 3 x 3 patches"


# ---------------------------------------------------------------------------------------------
# providers
# ---------------------------------------------------------------------------------------------
def test_resolve_provider_names_and_bad_choices():
    assert resolve_provider("airy")[1] == "airy"
    gauss, name = resolve_provider("gaussian:12")
    assert name == "gaussian:12"
    ch1, ch2 = channels_for(SystemDesign.paper())
    k = gauss(ch2, pitch_um=17.0, field_deg=0.0, wavelengths_um=np.array([10.0]), weights=np.array([1.0]),
              size_px=31)
    assert isinstance(k, Kernel) and k.intensity.sum() == pytest.approx(1.0, abs=1e-6)
    assert _axis_variance(k.intensity) == pytest.approx((12 / 17) ** 2 + 1 / 12, rel=5e-3)
    assert isinstance(resolve_provider({"foveal": np.ones((1, 1)), "perifoveal": np.ones((1, 1))})[0], ExplicitPSF)
    for bad in ("magic", "gaussian:wide", "gaussian:-1"):
        with pytest.raises(InputError, match="psf"):
            resolve_provider(bad)
    with pytest.raises(InputError, match="foveal"):
        ExplicitPSF({"foveal": np.ones((1, 1))})
    with pytest.raises(InputError, match="psf kernel"):
        ExplicitPSF({"foveal": -np.ones((3, 3)), "perifoveal": np.ones((1, 1))})(
            ch1, pitch_um=1.0, field_deg=0.0, wavelengths_um=np.array([10.0]), weights=np.array([1.0]), size_px=3)


def test_optics_provider_caches_kernels_on_disk(tmp_path, monkeypatch, caplog):
    """The optics provider writes each kernel to cache_dir('psf') keyed by its inputs, reads it back instead of
    recomputing, and recomputes an unreadable entry."""
    import metafovea.optics

    calls = []

    class FakePSF:
        intensity = gaussian_kernel(1.0, 7) * 0.9
        engine = "fake"
        error_estimate = 1e-5

    def fake_sensor_psf(lens, **kw):
        calls.append(kw["field_deg"])
        return FakePSF()

    monkeypatch.setenv("METAFOVEA_CACHE", str(tmp_path))
    monkeypatch.setattr(metafovea.optics, "sensor_psf", fake_sensor_psf)
    _, ch2 = channels_for(SystemDesign.paper())
    kw = dict(pitch_um=17.0, field_deg=0.5, wavelengths_um=np.array([9.0, 10.0]), weights=np.array([1.0, 1.0]),
              size_px=7)
    k1 = OpticsPSFProvider()(ch2, **kw)
    files = sorted((tmp_path / "psf").glob("psf_perifoveal_*.npz"))
    assert len(files) == 1 and calls == [0.5]
    assert k1.source == "metafovea.optics.sensor_psf (fake)" and k1.error_estimate == 1e-5
    k2 = OpticsPSFProvider()(ch2, **kw)  # a new provider: from the disk
    assert calls == [0.5] and np.array_equal(k1.intensity, k2.intensity) and k2.source == k1.source
    OpticsPSFProvider()(ch2, **{**kw, "field_deg": 1.0})  # another input, another entry
    assert calls == [0.5, 1.0] and len(list((tmp_path / "psf").glob("*.npz"))) == 2
    files[0].write_bytes(b"junk")
    k3 = OpticsPSFProvider()(ch2, **kw)
    assert calls == [0.5, 1.0, 0.5] and np.array_equal(k3.intensity, k1.intensity)
    assert "unreadable PSF cache" in caplog.text


def test_glare_does_not_coarsen_the_chromatic_haze():
    """Regression: the other lens' glare (0.2 % in disks of up to 44 mm) once shared the chromatic haze's coarse
    grid, 39 pixels instead of 3, and changed the filtered foveal image by +-18 DN on a 47 DN range. The glare
    now has grids of its own: it adds a smooth, nearly uniform background and leaves the haze as it was."""
    from metafovea.config import SystemDesign
    from metafovea.imaging.channel import channels_for
    from metafovea.imaging.kernels import build_channel_optics, resolve_provider
    from metafovea.imaging.render import ChannelRenderer
    from metafovea.imaging.scene import SceneGeometry, make_scene
    from metafovea.radiometry import BandRadiance

    system = SystemDesign.paper()
    ch = channels_for(system)[0]
    radiance = BandRadiance.for_system(system, filter_enabled=True)
    provider, _ = resolve_provider("airy")
    leaks = [(0.001, 700.0), (0.001, 12000.0), (0.0004, 44000.0)]
    plain = build_channel_optics(ch, provider, radiance, ss=2)
    glare = build_channel_optics(ch, provider, radiance, ss=2, leaks=leaks)
    assert glare.far_coarse == plain.far_coarse and np.array_equal(glare.far_kernel, plain.far_kernel)
    assert sum(w for w, _, _ in glare.extra_far) == pytest.approx(sum(p for p, _ in leaks))
    assert len(glare.extra_far) >= 2  # disks of 0.7 and 44 mm are not drawn on one grid
    geom = SceneGeometry(fov_rad=2 * channels_for(system)[1].half_fov_rad[1], expansion=system.expansion,
                         duration_s=1.0)
    sc = make_scene("siemens-star", geom)
    a = ChannelRenderer(sc, plain, radiance).render(0.0)
    b = ChannelRenderer(sc, glare, radiance).render(0.0)
    d = b - a
    assert float(d.mean()) == pytest.approx(0.0024 * float(a.mean()), rel=0.5)  # about the glare's share
    assert float(d.std()) < 0.05 * float(np.abs(d.mean()))  # and smooth over the foveal crop


@pytest.mark.parametrize("f_um,d_um,band,n,q", [(3000.0, 2000.0, (9.5, 10.5), 9, 3),
                                                  (2500.0, 2500.0, (9.7, 10.3), 7, 5)])
def test_the_kernel_error_model_bounds_the_exact_engine(f_um, d_um, band, n, q):
    """The kernels' error request assumes ``|dK|_1 <= e sum(K)`` (``e`` the engine's estimate relative to the peak,
    the error where the kernel's light is) and a pixel change ``<= |dK|_1 x the scene's range`` (the haze takes up the
    power the kernel misses). Against the exact engine integrated over the same pixels (F/1.5 and F/1 lenses, a band
    on axis, 17 um pixels; an odd number of fine samples per pixel, centred as the sensor's) on a random scene: the
    model bounds the true l1 error (30-200x) and the true largest pixel change. The check can fail: without the Debye
    part of the estimate it is not a bound."""
    import warnings

    from scipy.signal import fftconvolve

    from metafovea.config import LensDesign
    from metafovea.errors import NotConvergedWarning
    from metafovea.optics import box_integrate, psf, sensor_psf
    from metafovea.radiometry import psf_wavelengths

    lens = LensDesign("small", f_um, d_um)
    wl, w = psf_wavelengths(band, design_um=10.0, n=n, temperature_k=300.0)
    size, p = 21, 17.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        S = sensor_psf(lens, pixel_pitch_um=p, wavelengths_um=wl, weights=w, size_px=size, error=1e-4)
    R = psf(lens, engine="rs", wavelengths_um=wl, weights=w, window_um=size * p - 1e-6, pitch_um=p / q, error=1e-5,
            allow_truncation=True, quantize=True, lattice=True)
    o = (R.shape[0] - size * q) // 2
    ref = box_integrate(R.intensity[o:o + size * q, o:o + size * q], q)
    d = S.intensity - ref
    d -= np.median(d)  # the haze orders: a uniform floor over this small window
    l1 = float(np.abs(d).sum())
    model = S.error_estimate * float(S.intensity.sum())
    assert l1 <= model
    assert l1 > (S.error_estimate - S.info["debye_error_estimate"]) * float(S.intensity.sum())
    scene = np.random.default_rng(0).uniform(0.0, 1.0, (80, 80))  # range 1
    change = fftconvolve(scene - scene.mean(), d, mode="valid")  # the haze: the kernel's missing power at the mean
    assert float(np.abs(change).max()) <= model * float(np.ptp(scene))


def test_kernel_error_request_follows_the_allowed_change():
    """``allowed_k / (contrast_k x kernel_sum)`` rounded down to a 1-2-5 step within the range; the constant where
    nothing bounds it; a tighter allowance or a larger range or sum asks for more."""
    from metafovea.imaging.kernels import DEFAULT_KERNEL_ERROR, KERNEL_ERROR_RANGE, KernelAccuracy, kernel_error_request

    a = KernelAccuracy(0.0816, 25.7, "noise")
    assert kernel_error_request(a, 0.0946) == pytest.approx(0.02)  # 0.0336 -> 0.02
    assert kernel_error_request(KernelAccuracy(0.05, 1.0, "x"), 1.0) == pytest.approx(0.05)
    assert kernel_error_request(a, 0.2) < kernel_error_request(a, 0.0946)
    assert kernel_error_request(KernelAccuracy(1e-3, 25.7, "x"), 0.0946) < kernel_error_request(a, 0.0946)
    assert kernel_error_request(None, 1.0) == kernel_error_request(KernelAccuracy(None, 3.0, "x"), 1.0) \
        == DEFAULT_KERNEL_ERROR
    assert kernel_error_request(KernelAccuracy(100.0, 0.1, "x"), 0.01) == KERNEL_ERROR_RANGE[1]
    assert kernel_error_request(KernelAccuracy(1e-12, 100.0, "x"), 1.0) == KERNEL_ERROR_RANGE[0]


def test_fftconvolve_is_scipys():
    """The convolution the renderer and the planner use is scipy.signal.fftconvolve's, to the bit, in every mode,
    for odd and even shapes, float32 and float64, and a 'valid' call with the larger array second."""
    from scipy.signal import fftconvolve as scipy_fftconvolve

    from metafovea.imaging.kernels import fftconvolve

    rng = np.random.default_rng(3)
    for (h, w), (p, q) in [((64, 50), (7, 7)), ((33, 40), (6, 9)), ((5, 5), (5, 5)), ((8, 9), (20, 21)),
                           ((12, 10), (1, 1))]:
        for dt in (np.float64, np.float32):
            a, b = rng.normal(size=(h, w)).astype(dt), rng.normal(size=(p, q))
            for mode in ("full", "same", "valid"):
                np.testing.assert_array_equal(fftconvolve(a, b, mode), scipy_fftconvolve(a, b, mode=mode))

"""Sensor (pixel-integrated) PSFs: the pixel integral against the analytic one, the batched engines against
per-wavelength references, every error estimate against the true error (an estimate must bound it), then the
contract (normalisation, haze, pass-through polarisation), QA regressions and bad input."""

import math
import warnings

import numpy as np
import pytest

from metafovea.config import LensDesign
from metafovea.errors import InputError, NotConvergedWarning
from metafovea.optics import box_integrate, build_pupils, disk_pixels, sensor_psf
from metafovea.optics import propagate as prop
from metafovea.radiometry import psf_wavelengths

F1 = LensDesign.perifoveal()  # F/1, D = 25 mm
F2 = LensDesign.foveal()  # F/2, D = 75 mm


@pytest.mark.parametrize("n_sub", [3, 4])
def test_box_integrate_matches_the_analytic_pixel_integral(n_sub):
    """A band-limited intensity 1 + cos(2 pi f x) integrated over pixels of n_sub samples: n (n + n sinc(f n)
    cos(2 pi f x_c)) (np.sinc is sin(pi x)/(pi x)), odd and even n_sub (pixel centres on and between samples).
    The window edge rings (the sensor engine bounds that with 0.05 x the edge intensity); inside it is exact."""
    size, f = 21, 0.07
    N = size * n_sub
    x = np.arange(N) - (N - 1) / 2
    I = np.ones((N, 1)) * (1 + np.cos(2 * np.pi * f * x))[None, :]
    out = box_integrate(I, n_sub)
    assert out.shape == (size, size)
    xc = (np.arange(size) - (size - 1) / 2) * n_sub
    ref = n_sub * (n_sub + n_sub * np.sinc(f * n_sub) * np.cos(2 * np.pi * f * xc))
    inner = np.abs(out - ref[None, :])[5:-5, 5:-5]
    assert inner.max() / ref.max() < 1e-4
    assert np.abs(out - ref[None, :]).max() / ref.max() > 1e-3  # the edge term is real: the check can fail


def test_batched_hankel_broadband_on_axis_matches_per_wavelength():
    wl = np.array([8.5, 9.9, 10.0, 10.02, 10.3, 12.0])
    w = np.array([0.1, 0.2, 0.3, 0.1, 0.2, 0.1])
    S = sensor_psf(F1, pixel_pitch_um=17.0, wavelengths_um=wl, weights=w, size_px=21, error=1e-4)
    assert S.info["engines"] == {"hankel": 6}
    n_sub, dx = S.info["n_sub"], S.info["fine_pitch_um"]
    ax = (np.arange(21 * n_sub) - (21 * n_sub - 1) / 2) * dx
    # each wavelength directly, with the focal-shift correction (Pupil.li_wolf: the model at z_D, radii m r, x m^2)
    models = [build_pupils(F1, float(l)).focus.li_wolf() for l in wl]
    assert any(m != 1.0 for _, m in models)
    tot = sum(wk * m * m * np.abs(prop.hankel_grid(mo, m * ax, m * ax, error=1e-9)) ** 2
              for (mo, m), wk in zip(models, w))
    ref = box_integrate(tot, n_sub) * dx * dx / (math.pi * F1.radius_um ** 2)
    d = S.intensity - ref
    d -= np.median(d)  # the haze orders: a uniform floor over this small window
    err = np.abs(d).max() / S.intensity.max()
    # the quadrature and spline part of the estimate is small; the Debye part (the model, which this reference
    # shares) is checked against the exact engine in test_debye_pixel_error_bounds_the_exact_engine
    assert err < 1e-6 and err <= S.error_estimate and S.error_estimate - S.info["debye_error_estimate"] <= 1e-3


@pytest.mark.parametrize("lens,lam", [(F1, 10.0), (F1, 10.02), (F1, 10.1), (F2, 10.0)])
def test_radial_lattice_error_bound(lens, lam):
    """The on-axis radial engine averages the 4-fold lattice factor azimuthally; the 2-D MFT keeps it."""
    a = sensor_psf(lens, pixel_pitch_um=17.0, wavelengths_um=[lam], size_px=31, engine="hankel")
    b = sensor_psf(lens, pixel_pitch_um=17.0, wavelengths_um=[lam], size_px=31, engine="mft", error=1e-6)
    d = np.abs(a.intensity - b.intensity).max() / b.intensity.max()
    assert d <= a.error_estimate and a.error_estimate - a.info["debye_error_estimate"] < 1e-3


@pytest.mark.parametrize("lens,field,lam", [(F1, 0.0, 10.3), (F1, 0.0, 10.6), (F2, 0.0, 10.2), (F1, 3.0, 10.3),
                                             (F2, 0.0, 10.03), (F1, 0.0, 10.05)])
def test_geometric_engine_against_wave_defocused(lens, field, lam):
    """Defocused by W020 ~ 1-6 waves: the geometric blur disk holds the right power (O(1/W020)), but the
    brightest pixels (axial Poisson spot, coma cusp) stay O(1) wrong: the estimate must bound it."""
    wave = sensor_psf(lens, pixel_pitch_um=17.0, field_deg=field, wavelengths_um=[lam], error=1e-4,
                      engine="mft" if field else "hankel", size_px=45)
    geo = sensor_psf(lens, pixel_pitch_um=17.0, field_deg=field, wavelengths_um=[lam], engine="geometric",
                     size_px=45)
    diff = np.abs(geo.intensity - wave.intensity).max()
    assert diff > 0.05 * wave.intensity.max()  # the geometric engine is not exact: the check can fail
    assert geo.error_estimate * geo.intensity.max() >= diff
    assert geo.energy_fraction == pytest.approx(wave.energy_fraction, rel=0.03)


def test_off_axis_broadband_error_estimate_is_a_bound():
    """Hybrid (wave engines for the near-focus wavelengths, rays for the rest) against all-wave."""
    wl, w = psf_wavelengths((9.7, 10.3), design_um=10.0, n=7, temperature_k=300.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = sensor_psf(F2, pixel_pitch_um=17.0, field_deg=1.0, wavelengths_um=wl, weights=w, size_px=41,
                         engine="mft", error=1e-3)
        for budget in (2e7, 4e8):
            H = sensor_psf(F2, pixel_pitch_um=17.0, field_deg=1.0, wavelengths_um=wl, weights=w, size_px=41,
                           budget=budget)
            actual = np.abs(H.intensity - ref.intensity).max() / ref.intensity.max()
            assert actual <= H.error_estimate
    assert "geometric" in H.engine or H.error_estimate < 1e-2  # an informative bound (1 % of the peak)


def test_sensor_psf_contract_and_haze():
    S = sensor_psf(F1, pixel_pitch_um=17.0, size_px=15)
    assert S.intensity.shape == (15, 15) and S.intensity.dtype == np.float64
    assert S.intensity.sum() == pytest.approx(S.energy_fraction)
    c = np.unravel_index(np.argmax(S.intensity), S.intensity.shape)
    assert c == (7, 7)
    assert 0.85 < S.energy_fraction < 0.9  # quantisation + lattice losses (~0.90) and tails
    wl, w = psf_wavelengths(design_um=10.0, n=61, temperature_k=300.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        B = sensor_psf(F1, pixel_pitch_um=17.0, wavelengths_um=wl, weights=w, size_px=31)
    # broadband: only a small fraction of the in-band power in the central pixel (haze)
    assert B.intensity[15, 15] < 0.05
    assert B.energy_fraction < 0.5


@pytest.mark.parametrize("field", [0.0, 3.0])
def test_sensor_psf_pass_through_polarisation_has_no_focus(field):
    # the other polarisation passes the ideal lens unfocused: haze only, no wave or ray engine
    S = sensor_psf(F1, pixel_pitch_um=17.0, field_deg=field, polarization="x", size_px=21)
    assert S.info["engines"] == {} and 0 < S.energy_fraction < 1e-3 and S.error_estimate == 0.0


@pytest.mark.parametrize("r,cx,cy", [(0.3, 0.1, -0.2), (2.0, 8.4, 8.4), (5.0, 0.0, 0.0), (40.0, 3.0, -7.0)])
def test_disk_pixels_conserve_power(r, cx, cy):
    """A haze disk smaller than a pixel missed every pixel centre or, hitting one, was multiplied by
    (pixel / disk area); disks now deposit their power by sub-pixel coverage."""
    p, size = 17.0, 11
    x0 = y0 = -size * p / 2
    d = disk_pixels((cx, cy), r, x0, y0, p, size)
    assert d.sum() == pytest.approx(1.0, rel=0.03)
    assert d.max() <= 1.0 + 1e-12
    # a disk half outside the window keeps only its inside share; one wholly outside leaves nothing
    if r >= 1.0:
        e = disk_pixels((x0, cy), r, x0, y0, p, size)
        assert e.sum() == pytest.approx(0.5, rel=0.1)
    assert disk_pixels((x0 - r - 1, cy), r, x0, y0, p, size).sum() == 0


@pytest.mark.parametrize("f_um,d_um,m", [(20000.0, 2000.0, 2), (5000.0, 5000.0, 2), (8000.0, 3000.0, 3)])
def test_sensor_psf_where_another_order_focuses_is_finite(f_um, d_um, m):
    """At lambda0 / m the focusing order vanishes and order m focuses on the sensor: it was drawn as a
    1e-9 um disk, giving pixel values of ~1e19 (fractions of the incident power!)."""
    lens = LensDesign("t", f_um, d_um)
    with pytest.warns(NotConvergedWarning):  # the disk stand-in for a focused order is flagged as rough
        P = sensor_psf(lens, pixel_pitch_um=17.0, wavelengths_um=[lens.wavelength_um / m], size_px=41)
    assert np.all(np.isfinite(P.intensity)) and P.intensity.min() >= 0
    assert 0 < P.intensity.sum() <= 1.0 + 1e-9 and P.intensity.max() <= 1.0
    assert P.error_estimate > 1e-3


def test_sensor_psf_capped_window_warning_says_so():
    """Pixels far below the PSF size truncate the window at max_size_px; the warning blamed 'geometric haze'."""
    lens = LensDesign("t", 20000.0, 2000.0)
    with pytest.warns(NotConvergedWarning, match="capped at 31 pixels"):
        sensor_psf(lens, pixel_pitch_um=2.0, max_size_px=31)


@pytest.mark.parametrize("kw,match", [
    (dict(wavelengths_um=[0.0]), "wavelengths_um"),
    (dict(wavelengths_um=[-10.0]), "wavelengths_um"),
    (dict(field_deg=40.0), "field_deg"),
    (dict(weights=[1.0, 2.0]), "weights"),
    (dict(error=0.0), "error"),
])
def test_bad_input(kw, match):
    with pytest.raises(InputError, match=match):
        sensor_psf(F1, pixel_pitch_um=17.0, **kw)


def test_sensor_psf_of_a_corrected_lens_uses_the_exact_engine_and_says_when_it_cannot():
    """A lens with phase_poly_rad: 'auto' integrates the exact (RS) field over the pixels, with a finite estimate
    that holds against the same integral at a tighter error; an explicit direction-sine engine, or the ray
    engine 'auto' falls back to past the cost budget, is said to be unbounded (inf, model_note)."""
    lens = LensDesign("c", 2000.0, 1000.0, phase_poly_rad=(-4.0, 6.0))  # F/2, D = 1 mm, f_local ~ 0.93-1.04 f
    kw = dict(pixel_pitch_um=17.0, wavelengths_um=[10.0, 11.5], size_px=9, quantize=False, lattice=False)
    a = sensor_psf(lens, error=1e-3, **kw)
    assert a.engine == "rs" and math.isfinite(a.error_estimate) and "model_note" not in a.info
    b = sensor_psf(lens, error=1e-6, **kw)
    assert np.abs(a.intensity - b.intensity).max() / a.intensity.max() <= a.error_estimate + b.error_estimate
    for eng, kw2 in (("mft", {}), ("auto", {"budget": 1.0})):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotConvergedWarning)
            c = sensor_psf(lens, error=1e-3, engine=eng, **kw, **kw2)
        assert math.isinf(c.error_estimate) and "phase_poly_rad" in c.info["model_note"]
        assert c.engine == ("mft" if eng == "mft" else "geometric")
        # the light is there (the Debye model of this lens puts 4-12 % of it in wide wings the exact field lacks)
        assert np.all(c.intensity >= 0) and 0.5 < c.intensity.sum() <= 1.0 + 1e-9


@pytest.mark.parametrize("pitch", [17.0, 40.0])
def test_debye_pixel_error_bounds_the_exact_engine(pitch):
    """debye_pixel_error (the rim wave's error over a pixel) against the exact engine integrated over pixels, on
    lenses it was not derived on (F/1.5 and F/1, N_F 33 and 62) at wavelengths 0.5-8 % off focus; the check can fail:
    the pixel errors are far above the quadrature part of the estimate."""
    from metafovea.optics import debye_pixel_error, psf

    worst = 0.0
    q = int(math.ceil(pitch / 4.4))  # fine samples per pixel (the F/1 lens' Nyquist pitch is 5.6 um)
    for lens in (LensDesign("d15", 3000.0, 2000.0), LensDesign("d1", 2500.0, 2500.0)):
        for wl in (10.05, 10.2, 10.4, 9.6, 10.8):
            half = max(3 * pitch, 1.3 * lens.radius_um * abs(1 - lens.wavelength_um / wl) + 2 * pitch)
            n = 2 * int(math.ceil(half / pitch)) + 1
            kw = dict(wavelengths_um=[wl], window_um=n * pitch, pitch_um=pitch / q, error=1e-3,
                      allow_truncation=True, quantize=False)
            h, r = psf(lens, engine="hankel", **kw), psf(lens, engine="rs", **kw)
            m = (h.shape[0] // q) * q
            ph = h.intensity[:m, :m].reshape(m // q, q, m // q, q).sum((1, 3))
            pr = r.intensity[:m, :m].reshape(m // q, q, m // q, q).sum((1, 3))
            true = np.abs(ph - pr).max()
            pu = build_pupils(lens, wl, quantize=False, lattice=False).focus
            est = debye_pixel_error(pu, h.intensity.max() / (pitch / q) ** 2, pitch)  # fractions of the power
            assert true <= est + r.error_estimate * pr.max(), (lens.name, wl, true / pr.max(), est / pr.max())
            worst = max(worst, true / pr.max())
    assert worst > 1e-2


def test_on_axis_band_estimate_bounds_the_exact_engine():
    """A band on axis (F/1.5 lens, 9.7-10.3 um, 7 bins, 17 um pixels): sensor_psf's estimate against the exact engine
    integrated over the same pixels (box filter), and the Debye part is what makes it a bound."""
    from metafovea.optics import psf

    lens = LensDesign("d15", 3000.0, 2000.0)
    wl, w = psf_wavelengths((9.7, 10.3), design_um=10.0, n=7, temperature_k=300.0)
    size, q, p = 21, 3, 17.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        S = sensor_psf(lens, pixel_pitch_um=p, wavelengths_um=wl, weights=w, size_px=size, error=1e-4)
    kw = dict(wavelengths_um=wl, weights=w, window_um=size * p - 1e-6, pitch_um=p / q, error=1e-5,
              allow_truncation=True, quantize=True, lattice=True)
    R = psf(lens, engine="rs", **kw)
    n = size * q
    o = (R.shape[0] - n) // 2
    ref = box_integrate(R.intensity[o:o + n, o:o + n], q)
    d = S.intensity - ref
    d -= np.median(d)  # the haze orders: a uniform floor over this small window
    true = np.abs(d).max() / S.intensity.max()
    assert true <= S.error_estimate
    assert true > S.error_estimate - S.info["debye_error_estimate"]  # without the Debye part: not a bound

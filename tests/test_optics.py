"""Optics: references from /work/shared/REFERENCES.md ("PSF references"), conventions, engines, bad input.

Tolerances: the reference figures are quoted to 3-4 digits; the Debye/stationary-phase model they come from
is what the engines implement, so agreement is asked to the last quoted digit (+-1 in it).
"""

import math
import warnings

import numpy as np
import pytest

from metafovea.config import LensDesign
from metafovea.errors import InputError
from metafovea.library import PostSet
from metafovea.optics import (
    PSF,
    asm_propagate,
    build_pupils,
    diffraction_mtf,
    encircled_energy,
    fwhm_um,
    hankel_field,
    mft_field,
    psf,
    pupil_mtf,
    sensor_psf,
    strehl,
)
from metafovea.optics import propagate as prop
from metafovea.optics.propagate import AliasingWarning, SamplingError
from metafovea.radiometry import check_band, planck_radiance, psf_wavelengths

F1 = LensDesign.perifoveal()  # F/1, D = 25 mm
F2 = LensDesign.foveal()  # F/2, D = 75 mm


def _airy_peak(lens):
    return (math.pi * lens.radius_um ** 2 / (lens.wavelength_um * lens.f_um)) ** 2


def _radial(lens, r):
    pu = build_pupils(lens, lens.wavelength_um, quantize=False, lattice=False).focus
    return np.abs(hankel_field(pu, r, error=1e-10)) ** 2


@pytest.mark.parametrize("lens,zero,peak,ee17,ee24", [
    (F1, 13.24, 0.7967, 0.8216, 0.8878),
    (F2, 24.94, 0.9409, 0.7611, 0.8277),
])
def test_nonparaxial_flat_lens_references(lens, zero, peak, ee17, ee24):
    r = np.linspace(0, 40, 40001)
    I = _radial(lens, r)
    assert I[0] / _airy_peak(lens) == pytest.approx(peak, abs=1.5e-4)
    i = np.argmax(np.diff(I) > 0)
    assert r[i] == pytest.approx(zero, abs=0.011)
    # encircled energy: int 2 pi r I dr / (pi R^2), radial Gauss quadrature to 17 and 24 um
    for rr, ref in ((17.0, ee17), (24.0, ee24)):
        x, w = np.polynomial.legendre.leggauss(400)
        rs = 0.5 * rr * (x + 1)
        ee = np.sum(0.5 * rr * w * 2 * np.pi * rs * _radial(lens, rs)) / (math.pi * lens.radius_um ** 2)
        assert ee == pytest.approx(ref, abs=1.5e-4)


@pytest.mark.parametrize("lens,cut,m10,m29", [(F1, 89.44, 0.8346, 0.5654), (F2, 48.51, 0.7320, 0.2797)])
def test_mtf_references(lens, cut, m10, m29):
    m = pupil_mtf(lens, [10.0, 29.4, cut * 0.995, cut * 1.005])
    assert m[0] == pytest.approx(m10, abs=1.5e-4)
    assert m[1] == pytest.approx(m29, abs=1.5e-4)
    assert 0 < m[2] < 1e-3 and m[3] == 0.0
    assert 2 * lens.na / lens.wavelength_um * 1000 == pytest.approx(cut, abs=0.01)


def test_paraxial_limit_airy_and_diffraction_mtf():
    # a slow lens (F/20): non-paraxial corrections < 1e-3
    lens = LensDesign("slow", 100_000.0, 5_000.0)
    r = np.linspace(0, 300, 30001)
    I = _radial(lens, r)
    assert I[0] / _airy_peak(lens) == pytest.approx(1.0, abs=1e-3)
    zero = r[np.argmax(np.diff(I) > 0)]
    assert zero == pytest.approx(1.21967 * 10 * 20, rel=1e-3)
    cut = 1000 * lens.diameter_um / (lens.wavelength_um * lens.f_um)
    nu = np.array([0.1, 0.3, 0.6, 0.9]) * cut
    assert np.allclose(pupil_mtf(lens, nu), diffraction_mtf(nu, cut), atol=2e-3)


def test_engines_agree_mft_hankel_on_axis():
    for lens in (F1, F2):
        pu = build_pupils(lens, 10.0, quantize=False, lattice=False).focus
        xs = np.linspace(-100, 100, 101)
        a = np.abs(mft_field(pu, xs, xs, error=1e-6)) ** 2
        b = np.abs(prop.hankel_grid(pu, xs, xs, error=1e-8)) ** 2
        assert np.abs(a - b).max() / b.max() < 1e-4


def test_mft_node_rule_converged_off_axis():
    pu = build_pupils(F1, 10.0, field_deg=5.0, quantize=False, lattice=False).focus
    c = pu.chief_ray_um()
    xs = c[0] + np.arange(-100, 1201, 8.0)
    ys = np.arange(-400, 401, 8.0)
    nt, nr = prop.mft_nodes(pu, xs, ys, 1e-5)
    a = np.abs(mft_field(pu, xs, ys, nodes=(nt, nr))) ** 2
    b = np.abs(mft_field(pu, xs, ys, nodes=(int(1.6 * nt), int(1.6 * nr)))) ** 2
    assert np.abs(a - b).max() / b.max() < 1e-5


def test_off_axis_coma_references():
    P = psf(F1, field_deg=5.0, pitch_um=5.0, error=1e-5)
    on = _airy_peak(F1) * 0.7967 * 25.0 / (math.pi * F1.radius_um ** 2)  # on-axis peak per 5 um cell
    assert 0.015 < P.intensity.max() / on < 0.025  # ~2 %
    c = P.info["chief_ray_um"]
    assert c[0] == pytest.approx(F1.f_um * math.tan(math.radians(5.0)), rel=1e-9)
    xs, ys = P.coords()
    m = (np.abs(xs - c[0]) <= 300)[None, :] & (np.abs(ys) <= 300)[:, None]
    I = P.intensity * m
    assert I.sum() == pytest.approx(0.63, abs=0.01)  # 600 um window holds 63 %
    assert (I.sum(0) * xs).sum() / I.sum() - c[0] == pytest.approx(142, abs=3)  # centroid outward


def test_tilt_sign_moves_spot_to_plus_x():
    P = psf(F2, field_deg=0.5, pitch_um=2.0, window_um=200, allow_truncation=True)
    cx, cy = P.centroid_um()
    assert cx > 1000 and abs(cy) < 1
    P2 = psf(F2, field_deg=(0.0, -0.5), pitch_um=2.0, window_um=200, allow_truncation=True)
    assert P2.centroid_um()[1] < -1000


def test_energy_conservation_and_quadrature():
    # window holding every ray: the PSF's power equals the power through the aperture (Parseval)
    P = psf(F2, field_deg=1.0, error=1e-5, window_um=3000, pitch_um=10.0, allow_truncation=True)
    assert P.energy_fraction == pytest.approx(1.0, abs=4e-3)  # tails beyond 1.5 mm: ~0.3 %
    S = sensor_psf(F2, pixel_pitch_um=17.0, quantize=False, lattice=False, size_px=61)
    P2 = psf(F2, window_um=61 * 17.0, pitch_um=17.0 / 3, allow_truncation=True)
    assert S.energy_fraction == pytest.approx(P2.energy_fraction, abs=3e-3)


def test_asm_reference_against_debye_small_lens():
    # F/2, D = 4 mm: Fresnel number 100; the Debye engine and the exact ASM agree to ~1e-2 of the peak
    lens = LensDesign("small", 8000.0, 4000.0)
    pu = build_pupils(lens, 10.0, quantize=False, lattice=False).focus
    u0, ax = prop.sampled_lens_field(pu, 10.0)
    res = asm_propagate(u0, 10.0, 10.0, lens.f_um, pad=2.0)
    I = np.abs(res.field) ** 2
    c = ax.size // 2
    sl = slice(c - 10, c + 11)
    ref = np.abs(mft_field(pu, ax[sl], ax[sl])) ** 2
    assert np.abs(I[sl, sl] - ref).max() / ref.max() < 3e-2
    # energy: |U|^2 dx^2 over the plane = power through the aperture
    assert (np.abs(res.field) ** 2).sum() * 100 == pytest.approx((np.abs(u0) ** 2).sum() * 100, rel=2e-2)


def test_asm_aliasing_detected():
    lens = LensDesign("small", 2000.0, 2000.0)  # F/1, rim gradient 0.447/lambda -> needs pitch < 11 um
    pu = build_pupils(lens, 10.0, quantize=False, lattice=False).focus
    u0, _ = prop.sampled_lens_field(pu, 16.0)
    with pytest.warns(AliasingWarning):
        asm_propagate(u0, 16.0, 10.0, lens.f_um)


def test_quantisation_point_sampled_sinc2():
    # continuous-space N-level quantisation: focal peak ratio sinc^2(pi/N)
    for n in (4, 8, 16):
        lens = F1.with_(levels=n)
        ps = build_pupils(lens, 10.0, quantize=True, lattice=False)
        assert ps.info["order_efficiency"] == pytest.approx(np.sinc(1 / n) ** 2, rel=1e-12)
    assert np.sinc(1 / 8) ** 2 == pytest.approx(0.9496, abs=1e-4)


@pytest.mark.parametrize("lens,levels,ref", [(F2, 8, 0.935), (F1, 8, 0.899), (F2, 16, 0.97), (F1, 16, 0.93)])
def test_lattice_quantisation_peak_ratio(lens, levels, ref):
    L = lens.with_(levels=levels)
    a = psf(L, window_um=120, pitch_um=2.0, quantize=True, lattice=True, allow_truncation=True)
    b = psf(L, window_um=120, pitch_um=2.0, quantize=False, lattice=False, allow_truncation=True)
    assert a.intensity.max() / b.intensity.max() == pytest.approx(ref, abs=0.006)


def test_post_set_transmission_and_pass_through():
    ps = PostSet.ideal(8, polarization="y")
    t_focus = ps.t_y * 0.9
    ps2 = PostSet(ps.polarization, ps.period_um, ps.height_um, ps.wavelength_um, ps.widths_um, ps.t_x, t_focus)
    a = build_pupils(F1, 10.0, post_set=ps2, lattice=False)
    assert a.info["order_efficiency"] == pytest.approx(0.81 * np.sinc(1 / 8) ** 2, rel=1e-9)
    other = build_pupils(F1, 10.0, post_set=ps, polarization="x")
    assert other.focus is None  # uniform pass-through does not focus
    assert other.coefficients[0] == pytest.approx(1.0)


def test_chromatic_focal_shift_and_order_efficiency():
    ps = build_pupils(F1, 12.0, quantize=True, lattice=False)
    assert ps.info["order_efficiency"] < 0.95 * np.sinc(1 / 8) ** 2
    # f(lambda) = f0 lambda0 / lambda (paraxial): a slow lens at z = f(8 um) is in focus at 8 um
    slow = LensDesign("slow", 100_000.0, 5_000.0)
    f8 = slow.f_um * 10.0 / 8.0
    P = psf(slow, wavelengths_um=[8.0], z_um=f8, window_um=1000, pitch_um=5.0, allow_truncation=True)
    assert strehl(P) > 0.98
    Q = psf(slow, wavelengths_um=[8.0], window_um=1000, pitch_um=5.0, allow_truncation=True)
    assert strehl(Q) < 0.3  # ~0.8 waves of defocus
    # at F/1 the hyperbolic phase used at 8 um also has strong spherical aberration
    P1 = psf(F1, wavelengths_um=[8.0], z_um=F1.f_um * 1.25, window_um=200, pitch_um=1.0, allow_truncation=True)
    assert strehl(P1) < 0.5
    # geometric blur at 8 um on the 10 um focal plane: ~5 mm (F/1)
    pu = build_pupils(F1, 8.0, quantize=False, lattice=False).focus
    e = prop.ray_extent(pu)
    assert e[1] - e[0] == pytest.approx(5000, rel=0.2)  # paraxial 5 mm; spherical aberration widens it (5.8)


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


def test_psf_save_load(tmp_path):
    S = sensor_psf(F2, pixel_pitch_um=24.0, size_px=9)
    p = S.save(tmp_path / "psf.npz")
    L = PSF.load(p)
    assert np.array_equal(L.intensity, S.intensity) and L.engine == S.engine and L.center_um == S.center_um


def test_metrics_fwhm_and_ee():
    P = psf(F1, window_um=200, pitch_um=0.5, allow_truncation=True)
    fx, fy = fwhm_um(P)
    assert fx == pytest.approx(fy, rel=1e-6)
    assert 0.5 * 10 / F1.na < fx < 0.53 * 10 / F1.na
    ee = encircled_energy(P, [17.0, 24.0], center_um=(0.0, 0.0))
    assert ee == pytest.approx([0.8216, 0.8878], abs=2e-3)


def test_planck_and_band():
    b = planck_radiance([10.0], 300.0)
    assert b[0] == pytest.approx(9.923, rel=1e-3)  # W / (m^2 sr um)
    with pytest.raises(InputError, match="reversed"):
        check_band((14.0, 8.0))


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


def test_window_too_small_and_undersampled():
    with pytest.raises(SamplingError, match="window_um"):
        psf(F1, field_deg=5.0, window_um=600, pitch_um=5.0, error=1e-4)
    with pytest.raises(SamplingError, match="window_um"):
        psf(F1, window_um=10)
    with pytest.raises(SamplingError, match="pitch_um"):
        psf(F1, pitch_um=8.0, window_um=200)
    with pytest.raises(InputError, match="pixel_pitch_um"):
        sensor_psf(F1, pixel_pitch_um=0)


@pytest.mark.slow
def test_asm_full_lens_f1_agrees_with_debye():
    """Full 25 mm F/1 lens, BL-ASM vs the direction-sine engine (REFERENCES: 10 um sampling with 2x padding
    1.4e-4; 5 um 2.8e-5). Small size by default (10 um, ~0.4 GB); METAFOVEA_FULL=1: 5 um, pad 1.5 (~1 GB)."""
    import os
    dx, pad = (5.0, 1.5) if os.environ.get("METAFOVEA_FULL") else (10.0, 2.0)
    pu = build_pupils(F1, 10.0, quantize=False, lattice=False).focus
    u0, ax = prop.sampled_lens_field(pu, dx)
    res = asm_propagate(u0, dx, 10.0, F1.f_um, pad=pad)
    c = ax.size // 2
    sl = slice(c - 20, c + 21)
    ref = np.abs(mft_field(pu, ax[sl], ax[sl])) ** 2
    I = np.abs(res.field[sl, sl]) ** 2
    assert np.abs(I - ref).max() / _airy_peak(F1) < 3e-4


# ----------------------------------------------------------------------------------------------
# broadband sensor PSFs: batched engines against per-wavelength references, honest error estimates
# ----------------------------------------------------------------------------------------------
def test_batched_hankel_broadband_on_axis_matches_per_wavelength():
    from metafovea.optics.psf import _box_integrate
    wl = np.array([8.5, 9.9, 10.0, 10.02, 10.3, 12.0])
    w = np.array([0.1, 0.2, 0.3, 0.1, 0.2, 0.1])
    S = sensor_psf(F1, pixel_pitch_um=17.0, wavelengths_um=wl, weights=w, size_px=21, error=1e-4)
    assert S.info["engines"] == {"hankel": 6}
    n_sub, dx = S.info["n_sub"], S.info["fine_pitch_um"]
    ax = (np.arange(21 * n_sub) - (21 * n_sub - 1) / 2) * dx
    tot = sum(wk * np.abs(prop.hankel_grid(build_pupils(F1, float(l)).focus, ax, ax, error=1e-9)) ** 2
              for l, wk in zip(wl, w))
    ref = _box_integrate(tot, n_sub) * dx * dx / (math.pi * F1.radius_um ** 2)
    d = S.intensity - ref
    d -= np.median(d)  # the haze orders: a uniform floor over this small window
    err = np.abs(d).max() / S.intensity.max()
    assert err < 1e-6 and err <= S.error_estimate <= 1e-3


def test_mft_intensity_multi_matches_single_wavelength_engine():
    ps = [build_pupils(F2, l, field_deg=1.3).focus for l in (9.95, 10.0, 10.04)]
    c = ps[0].chief_ray_um()
    xs = c[0] + np.arange(-200, 200, 5.0)
    ys = np.arange(-150, 150, 5.0)
    w = [0.3, 0.5, 0.2]
    I = prop.mft_intensity_multi(ps, w, xs, ys, error=1e-8)
    R = sum(wk * np.abs(mft_field(p, xs, ys, error=1e-8)) ** 2 for p, wk in zip(ps, w))
    assert np.abs(I - R).max() / R.max() < 1e-9


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


@pytest.mark.parametrize("lens,mono,filt,band", [(F2, 0.7130, 0.03132, 0.003045), (F1, 0.7442, 0.08153, 0.008224)])
def test_on_axis_energy_within_one_pixel_radius(lens, mono, filt, band):
    """REFERENCES: 10 um ~0.72-0.78, the 0.5 um filter ~0.03-0.09, the 8-14 um band ~0.003-0.008 within
    17 um (quantised, lattice). Pinned values from this model; the ranges are the reference."""
    from metafovea.optics.psf import encircled_energy_on_axis
    e = encircled_energy_on_axis(lens, 17.0)
    assert e == pytest.approx(mono, abs=2e-4) and 0.70 < e < 0.78
    wl, w = psf_wavelengths(design_um=10.0, filter_um=(10.0, 0.5), n=61)
    e = encircled_energy_on_axis(lens, 17.0, wavelengths_um=wl, weights=w)
    assert e == pytest.approx(filt, rel=3e-3) and 0.03 < e < 0.09
    wl, w = psf_wavelengths(design_um=10.0, n=61)
    e = encircled_energy_on_axis(lens, 17.0, wavelengths_um=wl, weights=w)
    assert e == pytest.approx(band, rel=3e-3) and 0.003 < e < 0.0086
    # the sensor PSF's centre pixel (17 x 17 um) holds less than the 17 um radius circle
    S = sensor_psf(lens, pixel_pitch_um=17.0, wavelengths_um=wl, weights=w, size_px=31)
    assert 0.2 * band < S.intensity[15, 15] < band


@pytest.mark.parametrize("lens,lam", [(F1, 10.0), (F1, 10.02), (F1, 10.1), (F2, 10.0)])
def test_radial_lattice_error_bound(lens, lam):
    """The on-axis radial engine averages the 4-fold lattice factor azimuthally; the 2-D MFT keeps it."""
    a = sensor_psf(lens, pixel_pitch_um=17.0, wavelengths_um=[lam], size_px=31, engine="hankel")
    b = sensor_psf(lens, pixel_pitch_um=17.0, wavelengths_um=[lam], size_px=31, engine="mft", error=1e-6)
    d = np.abs(a.intensity - b.intensity).max() / b.intensity.max()
    assert d <= a.error_estimate < 1e-3


@pytest.mark.parametrize("field", [0.0, 3.0])
def test_sensor_psf_pass_through_polarisation_has_no_focus(field):
    # the other polarisation passes the ideal lens unfocused: haze only, no wave or ray engine
    S = sensor_psf(F1, pixel_pitch_um=17.0, field_deg=field, polarization="x", size_px=21)
    assert S.info["engines"] == {} and 0 < S.energy_fraction < 1e-3 and S.error_estimate == 0.0


@pytest.mark.parametrize("lens,ee17,ee24", [(F1, 0.8216, 0.8878), (F2, 0.7611, 0.8277)])
def test_encircled_energy_of_default_sampled_psf(lens, ee17, ee24):
    # the default pitch is near the intensity Nyquist pitch: EE must interpolate, not treat samples as squares
    P = psf(lens)
    assert P.pitch_um > 4.0
    e = encircled_energy(P, [17.0, 24.0])
    assert e[0] == pytest.approx(ee17, abs=2e-3)
    assert e[1] == pytest.approx(ee24, abs=2e-3)

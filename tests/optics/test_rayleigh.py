"""The Rayleigh-Sommerfeld engines: the brute-force reference against a closed form, the windowed engine and the
PSF's error_estimate against the reference on off-axis cases of scaled lenses (the estimate must be at least
the true error), and what the direction-sine engine says off axis."""

import math
import os

import numpy as np
import pytest

from metafovea.config import LensDesign
from metafovea.errors import InputError
from metafovea.optics import build_pupils, mft_field, psf, sensor_psf
from metafovea.optics.rayleigh import rs_field, rs_reference, zone_radii


def _on_axis_focus_exact(lens: LensDesign, wl: float) -> complex:
    """RS field of the continuous hyperbolic lens at its focus on axis (lambda = lambda0): there r = L(rho), so
    U = (2 pi f / (i lambda)) e^{ikf} [ln(L_a / f) + (1/L_a - 1/f) / (i k)]."""
    k = 2 * np.pi / wl
    f, a = lens.f_um, lens.radius_um
    La = math.hypot(a, f)
    return (2 * np.pi * f / (1j * wl)) * np.exp(1j * k * f) * (math.log(La / f) + (1 / La - 1 / f) / (1j * k))


@pytest.mark.parametrize("f, d", [(2000.0, 1000.0), (1500.0, 1500.0)])
def test_reference_and_windowed_engine_at_the_focus_against_the_closed_form(f, d):
    lens = LensDesign("cf", f, d)
    pu = build_pupils(lens, 10.0, quantize=False, lattice=False).focus
    exact = _on_axis_focus_exact(lens, 10.0)
    ref = rs_reference(pu, [0.0], [0.0])[0, 0]
    # the reference keeps the absolute phase; the windowed engine's per-block phase is arbitrary (intensity)
    assert abs(ref - exact) / abs(exact) < 1e-9
    U, info = rs_field(pu, np.linspace(-20, 20, 9), np.linspace(-20, 20, 9), error=1e-6)
    true = abs(abs(U[4, 4]) ** 2 - abs(exact) ** 2)
    assert true <= info["intensity_error"] <= 1e-6 * abs(exact) ** 2
    assert zone_radii(pu)[-1] == lens.radius_um


def test_reference_is_converged():
    lens = LensDesign("cv", 2000.0, 2000.0)
    pu = build_pupils(lens, 10.0, field_deg=6.0, quantize=True, lattice=True).focus
    c = pu.chief_ray_um()
    xs, ys = c[0] + np.linspace(-30, 60, 7), np.linspace(-40, 40, 5)
    a = rs_reference(pu, xs, ys)
    b = rs_reference(pu, xs, ys, nodes_per_zone=28, phi_margin=160)
    assert np.abs(a - b).max() / np.abs(b).max() < 1e-9


# (f um, D um, field deg, fabricated lens (8 levels + lattice), wavelength um): F/1 and F/2, fields up to near
# each lens' field, one off the design wavelength (chromatic defocus)
CASES = [(2000.0, 1000.0, 5.0, False, 10.0), (2000.0, 2000.0, 3.0, False, 10.0), (2000.0, 2000.0, 8.0, True, 10.0),
         (3000.0, 1500.0, 10.0, True, 10.0), (1500.0, 1500.0, 15.0, False, 10.0), (4000.0, 2000.0, 2.0, True, 9.0),
         (2500.0, 1250.0, 1.0, False, 10.5)]


@pytest.mark.parametrize("f, d, field, fab, wl", CASES)
def test_psf_error_estimate_bounds_the_true_error_off_axis(f, d, field, fab, wl):
    lens = LensDesign("sc", f, d)
    P = psf(lens, field_deg=field, wavelengths_um=[wl], quantize=fab, lattice=fab, error=1e-4)
    assert P.engine == "rs" and math.isfinite(P.error_estimate)
    assert P.error_estimate <= 1e-4  # the engine met the requested error by its own account
    xs, ys = P.coords()
    pu = build_pupils(lens, wl, field_deg=field, quantize=fab, lattice=fab).focus
    # the reference (its cost: sources x points) on every 6th sample over the whole window and on the 9 x 9 samples
    # around the peak, where the engine's error is largest: on every 3rd sample the largest error was the same in six
    # of the seven cases and 3 % larger in the seventh (4000/2000 um at 2 deg), each below half the estimate. The
    # largest window (127 px, 1500/1500 um at 15 deg) takes every 12th: the same largest error as every 6th there
    # (4.13e-6 against an estimate of 1.77e-5), at 361 reference points instead of 841
    step = 6 if P.shape[0] < 120 else 12
    j, i = np.unravel_index(int(np.argmax(P.intensity)), P.shape)
    rows = sorted(set(range(0, P.shape[0], step)) | set(range(max(0, j - 4), min(P.shape[0], j + 5))))
    cols = sorted(set(range(0, P.shape[1], step)) | set(range(max(0, i - 4), min(P.shape[1], i + 5))))
    U = rs_reference(pu, xs[cols], ys[rows])
    ref = np.abs(U) ** 2 * P.pitch_um ** 2 / (math.pi * lens.radius_um ** 2)
    true = float(np.abs(P.intensity[np.ix_(rows, cols)] - ref).max() / ref.max())
    assert true <= P.error_estimate
    # the direction-sine model on the same points is far off: the edge diffraction it leaves out
    Um = mft_field(pu, xs[cols], ys[rows], error=1e-8)
    mft_err = np.abs(np.abs(Um) ** 2 * P.pitch_um ** 2 / (math.pi * lens.radius_um ** 2) - ref).max() / ref.max()
    assert mft_err > 10 * true


def test_windowed_engine_estimate_grows_when_blocks_are_forced_large():
    # one 64-sample block over a strongly aberrated PSF of a small, short lens: the Taylor remainder is large,
    # and the engine splits the block until its evaluated remainder meets the budget
    lens = LensDesign("tb", 1500.0, 1500.0)
    pu = build_pupils(lens, 10.0, field_deg=12.0, quantize=False, lattice=False).focus
    c = pu.chief_ray_um()
    xs, ys = c[0] + np.linspace(-20, 180, 64), np.linspace(-100, 100, 64)
    U, info = rs_field(pu, xs, ys, error=1e-4, block_px=64)
    assert info["splits"] >= 1 and info["blocks"] > 1
    ref = rs_reference(pu, xs[::7], ys[::7])
    true = np.abs(np.abs(U[::7, ::7]) ** 2 - np.abs(ref) ** 2).max()
    assert true <= info["intensity_error"] <= 1e-4 * (np.abs(U) ** 2).max()


def test_direction_sine_engine_off_axis_says_it_is_not_bounded():
    lens = LensDesign("nb", 2000.0, 1000.0)
    P = psf(lens, field_deg=4.0, engine="mft")
    assert math.isinf(P.error_estimate) and "edge" in P.info["model_note"]
    on = psf(lens, field_deg=0.0, engine="mft")
    assert math.isfinite(on.error_estimate) and "model_note" not in on.info
    S = sensor_psf(lens, pixel_pitch_um=17.0, field_deg=4.0, engine="mft")
    assert "edge" in S.info["model_note"]
    with pytest.raises(InputError, match="engine"):
        sensor_psf(lens, pixel_pitch_um=17.0, field_deg=4.0, engine="rs")


# ----------------------------------------------------------------------------------------------
# lenses with a phase beyond the hyperbola (LensDesign.phase_poly_rad)
# ----------------------------------------------------------------------------------------------
def _corrected(f: float, d: float, eps: float, shape: str) -> LensDesign:
    """A lens whose added phase spreads the local focal length by about +-eps: ``psi'(r) / r = eps k0 R^2 / f x
    P(u) / R^2`` with P a fixed polynomial in u = (r / R)^2 of range about [-1, 1] (quadratic or cubic)."""
    scale = 2 * np.pi / 10.0 * (d / 2) ** 2 / f
    p = {"q": (-1.0, 6.0, -6.0), "t3": (-1.0, 18.0, -48.0, 32.0)}[shape]
    return LensDesign("corrected", f, d, phase_poly_rad=tuple(round(eps * scale * c / (2 * (j + 1)), 3)
                                                              for j, c in enumerate(p)))


# held-out corrected lenses (not the ones the engines were developed on): D 2 and 5 mm, F/1 and F/2, on axis and
# off axis, 9-12 um, continuous and fabricated; local focal length spread 0.88-1.14 f, coefficients up to 565 rad,
# ray maps monotone (the first) and not (the others: rays cross near the rim, which only the exact engine takes)
# (the 5 mm F/1 lens off axis, ~30 s, with METAFOVEA_FULL=1 only)
POLY_CASES = [(2000.0, 2000.0, 0.09, "q", 0.0, 10.0, False), (4000.0, 2000.0, -0.09, "q", 3.0, 12.0, True),
              (10000.0, 5000.0, 0.08, "t3", 0.0, 9.0, False)]
if os.environ.get("METAFOVEA_FULL"):
    POLY_CASES.append((5000.0, 5000.0, 0.09, "t3", 2.0, 10.5, False))


@pytest.mark.parametrize("f, d, eps, shape, field, wl, fab", POLY_CASES)
def test_psf_of_a_corrected_lens_within_its_error_estimate_of_the_reference(f, d, eps, shape, field, wl, fab):
    """psf(engine='auto') of a lens with phase_poly_rad runs the exact engine on and off axis, and its
    error_estimate bounds the true error against the brute-force reference (which integrates the lens field with
    the added phase); the direction-sine model on the same points is far off (its defocused zones)."""
    from metafovea.lens import direction_sine_over_r

    lens = _corrected(f, d, eps, shape)
    r = np.linspace(1.0, lens.radius_um, 400)
    g = r * direction_sine_over_r(lens, r)
    f_local = r * np.sqrt(1 - g * g) / g / f
    assert f_local.max() - f_local.min() > 0.12  # the case is what it claims: a spread of ~ +-10 % of f
    P = psf(lens, field_deg=field, wavelengths_um=[wl], quantize=fab, lattice=fab, error=1e-4)
    assert P.engine == "rs" and P.error_estimate <= 1e-4 and "model_note" not in P.info
    xs, ys = P.coords()
    pu = build_pupils(lens, wl, field_deg=field, quantize=fab, lattice=fab).focus
    # every 6th sample, every 12th on the 5 mm lens' 157 px window (its largest error 4.79e-6 there against 4.99e-6 on
    # every 6th, the estimate 4.9e-5; 529 reference points instead of 1,225: the reference was 2/3 of the test's time)
    step = 6 if P.shape[0] < 120 else 12
    j, i = np.unravel_index(int(np.argmax(P.intensity)), P.shape)
    rows = sorted(set(range(0, P.shape[0], step)) | set(range(max(0, j - 4), min(P.shape[0], j + 5))))
    cols = sorted(set(range(0, P.shape[1], step)) | set(range(max(0, i - 4), min(P.shape[1], i + 5))))
    ref = np.abs(rs_reference(pu, xs[cols], ys[rows])) ** 2 * P.pitch_um ** 2 / (math.pi * lens.radius_um ** 2)
    true = float(np.abs(P.intensity[np.ix_(rows, cols)] - ref).max() / ref.max())
    assert true <= P.error_estimate
    if field == 0.0 and not fab:  # the Debye model, where it applies (a monotone ray map), is not within it
        from metafovea.optics.pupil import ray_map_monotone

        if ray_map_monotone(lens):
            Um = mft_field(pu, xs[cols], ys[rows], error=1e-8)
            dm = np.abs(np.abs(Um) ** 2 * P.pitch_um ** 2 / (math.pi * lens.radius_um ** 2) - ref).max() / ref.max()
            assert dm > 100 * P.error_estimate


def test_reference_with_added_phase_is_converged_and_zones_follow_the_full_phase():
    lens = _corrected(4000.0, 2000.0, -0.09, "q")
    pu = build_pupils(lens, 11.0, field_deg=2.0, quantize=False, lattice=False).focus
    c = pu.chief_ray_um()
    xs, ys = c[0] + np.linspace(-60, 60, 5), np.linspace(-60, 60, 5)
    a = rs_reference(pu, xs, ys)
    b = rs_reference(pu, xs, ys, nodes_per_zone=28, phi_margin=160)
    assert np.abs(a - b).max() / np.abs(b).max() < 1e-9
    # zone edges: the full design phase passes a multiple of 2 pi there
    from metafovea.lens import design_phase

    z = zone_radii(pu)
    ph = design_phase(lens, z[:-1], 0.0)
    assert np.allclose(np.abs(np.diff(ph)) / (2 * np.pi), 1.0, atol=1e-4)  # (the quadrature needs no more)
    assert z[-1] == lens.radius_um


def test_windowed_engine_with_a_zero_added_phase_matches_the_hyperbola():
    """phase_poly_rad = (0,) takes the general code path; it must agree with the hyperbola's to rounding."""
    lens = LensDesign("h", 2000.0, 1000.0)
    zero = lens.with_(phase_poly_rad=(0.0,))
    xs = np.linspace(-30, 30, 13) + 35.0
    ys = np.linspace(-30, 30, 13)
    out = []
    for ln in (lens, zero):
        pu = build_pupils(ln, 10.5, field_deg=1.0, quantize=True, lattice=True).focus
        out.append((rs_field(pu, xs, ys, error=1e-5)[0], rs_reference(pu, xs[::4], ys[::4])))
    for a, b in zip(*out):
        assert np.abs(np.abs(a) ** 2 - np.abs(b) ** 2).max() < 1e-10 * (np.abs(a) ** 2).max()

"""Pupils: the N-level quantisation's order efficiency (sinc^2(pi/N)) and the post-set transmission of the
focusing and the pass-through polarisation."""

import numpy as np
import pytest

from metafovea.config import LensDesign
from metafovea.library import PostSet
from metafovea.optics import build_pupils

F1 = LensDesign.perifoveal()  # F/1, D = 25 mm


def test_quantisation_point_sampled_sinc2():
    # continuous-space N-level quantisation: focal peak ratio sinc^2(pi/N)
    for n in (4, 8, 16):
        lens = F1.with_(levels=n)
        ps = build_pupils(lens, 10.0, quantize=True, lattice=False)
        assert ps.info["order_efficiency"] == pytest.approx(np.sinc(1 / n) ** 2, rel=1e-12)
    assert np.sinc(1 / 8) ** 2 == pytest.approx(0.9496, abs=1e-4)


def test_post_set_transmission_and_pass_through():
    ps = PostSet.ideal(8, polarization="y")
    t_focus = ps.t_y * 0.9
    ps2 = PostSet(ps.polarization, ps.period_um, ps.height_um, ps.wavelength_um, ps.widths_um, ps.t_x, t_focus)
    a = build_pupils(F1, 10.0, post_set=ps2, lattice=False)
    assert a.info["order_efficiency"] == pytest.approx(0.81 * np.sinc(1 / 8) ** 2, rel=1e-9)
    other = build_pupils(F1, 10.0, post_set=ps, polarization="x")
    assert other.focus is None  # uniform pass-through does not focus
    assert other.coefficients[0] == pytest.approx(1.0)


# ----------------------------------------------------------------------------------------------
# the pupil of a lens with a phase beyond the hyperbola (LensDesign.phase_poly_rad)
# ----------------------------------------------------------------------------------------------
SMALL = LensDesign("small", 2000.0, 2000.0)  # F/1, D = 2 mm


def _points(pu, n=9):
    t = np.linspace(-0.999, 0.999, n)
    return pu.s0[0] + pu.radius * t, pu.s0[1] + 0.5 * pu.radius * t[::-1]


@pytest.mark.parametrize("wl, field", [(10.0, 0.0), (12.5, 2.0), (8.5, 0.0)])
def test_general_pupil_map_with_a_zero_added_phase_is_the_hyperbola(wl, field):
    """phase_poly_rad = (0,) takes the numerical stationary-point path (inverse ray map, Jacobian amplitude); it
    must give the hyperbola's analytic phase, amplitude, ray landing points and disk."""
    a = build_pupils(SMALL, wl, field_deg=field).focus
    b = build_pupils(SMALL.with_(phase_poly_rad=(0.0,)), wl, field_deg=field).focus
    sx, sy = _points(a)
    assert abs(b.radius - a.radius) < 1e-14
    assert np.abs(b.phase(sx, sy) - a.phase(sx, sy)).max() < 1e-8  # rad, of phases ~1e3 rad
    assert np.abs(b.amplitude(sx, sy) / a.amplitude(sx, sy) - 1).max() < 1e-10
    assert np.abs(np.subtract(b.ray_landing(sx, sy), a.ray_landing(sx, sy))).max() < 1e-7  # um


def test_corrected_pupil_inverse_map_landing_and_energy():
    """A corrected lens: the inverse ray map returns the lens radius it came from; the landing point of a
    direction is that of the lens point traced forwards; the pupil's power equals the power through the aperture
    (the Jacobian amplitude conserves energy: lambda^2 int |P|^2 d^2 s = pi R^2 |c_1|^2)."""
    from metafovea.lens import direction_sine_over_r, ray_map_check
    from metafovea.optics import propagate as prop
    from metafovea.optics.pupil import design_na, radius_of_direction_sine

    lens = SMALL.with_(phase_poly_rad=(-14.0, 30.0, -12.0))
    ok, gmax, _ = ray_map_check(lens)
    assert ok and gmax == pytest.approx(design_na(lens)) and abs(gmax - SMALL.na) > 0.01
    rho = np.linspace(0.0, lens.radius_um, 50)
    g = rho * direction_sine_over_r(lens, rho)
    assert np.abs(radius_of_direction_sine(lens, g) - rho).max() < 1e-9
    pu = build_pupils(lens, 11.0, field_deg=1.5, quantize=False, lattice=False).focus
    sx, sy = pu.s0[0] - g / pu.alpha, pu.s0[1] + 0 * g  # the direction of lens point (rho, 0)
    x, y = pu.ray_landing(sx, sy)
    xf, yf = pu.lens_ray_landing(rho, 0 * rho)
    assert np.abs(x - xf).max() < 1e-6 and np.abs(y - yf).max() < 1e-6
    u, v, w = prop.disk_nodes(pu.center, pu.radius, 200, 200)
    vv = np.broadcast_to(v[:, None], u.shape)
    power = float(np.sum(w * np.abs(pu.amplitude(u, vv)) ** 2)) * pu.wavelength_um ** 2
    assert power == pytest.approx(np.pi * lens.radius_um ** 2, rel=1e-6)


def test_direction_sine_engines_refuse_a_lens_whose_rays_cross():
    """Rays that cross inside the lens' directions (dg/dr < 0 near the rim) have no pupil in direction sines: the
    direction-sine engines refuse them by name (psf's exact engine takes them: test_rayleigh)."""
    from metafovea.errors import InputError
    from metafovea.lens import ray_map_check
    from metafovea.optics import hankel_field

    lens = SMALL.with_(f_um=4000.0, phase_poly_rad=(7.069, -21.206, 14.137))  # +-10 % of f, rays cross at the rim
    assert not ray_map_check(lens)[0]
    pu = build_pupils(lens, 10.0, quantize=False, lattice=False).focus
    with pytest.raises(InputError, match="phase_poly_rad"):
        hankel_field(pu, [0.0, 5.0])


def test_added_phase_follows_the_phase_sign_convention():
    """phase_poly_rad is added to the design phase as is; under phase_sign = +1 the design phase is the conjugate
    convention's, so the lens (+1, a) is physically the lens (-1, -a): the same pupil, and conjugate layout phases."""
    from metafovea.lens import design_phase

    a = (-14.0, 30.0, -12.0)
    p1 = build_pupils(SMALL.with_(phase_sign=1, phase_poly_rad=a), 11.0, field_deg=1.0).focus
    p2 = build_pupils(SMALL.with_(phase_poly_rad=tuple(-v for v in a)), 11.0, field_deg=1.0).focus
    sx, sy = _points(p1)
    assert np.array_equal(p1.phase(sx, sy), p2.phase(sx, sy))
    assert np.array_equal(p1.amplitude(sx, sy), p2.amplitude(sx, sy))
    r = np.linspace(0, SMALL.radius_um, 7)
    assert np.allclose(design_phase(p1.lens, r, 0.0), -design_phase(p2.lens, r, 0.0), rtol=0, atol=1e-9)

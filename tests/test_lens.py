"""Analytic and brute-force checks of metafovea.lens."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from metafovea.config import LensDesign
from metafovea.errors import InputError
from metafovea.lens import (
    EMPTY,
    count_posts,
    design_warnings,
    hyperbolic_phase,
    iter_tiles,
    lattice_efficiency,
    level_phase,
    paraxial_phase,
    posts_per_2pi,
    quantize_phase,
    radius_below_posts,
    scalar_efficiency,
    site_positions_um,
    summarize,
    wrap_phase,
    zone_width_um,
)

TWO_PI = 2 * math.pi


def small(f_mm=1.0, d_mm=0.3, **kw):
    return LensDesign("t", f_mm * 1000, d_mm * 1000, **kw)


def test_phase_zero_at_centre_and_rim_value():
    f, wl = 150_000.0, 10.0
    assert hyperbolic_phase(0.0, f, wl) == 0.0
    R = 37_500.0
    expect = -(TWO_PI / wl) * (math.sqrt(R * R + f * f) - f)
    assert hyperbolic_phase(R, f, wl) == pytest.approx(expect, rel=1e-13)
    # sign convention: focusing phase decreases outward; +1 flips it
    assert hyperbolic_phase(R, f, wl, sign=+1) == pytest.approx(-expect, rel=1e-13)


def test_phase_is_stable_for_small_radius():
    # naive sqrt(r^2+f^2)-f loses all digits here; the stable form matches the Taylor series
    r, f, wl = 1e-3, 1e6, 10.0
    taylor = -(TWO_PI / wl) * (r * r / (2 * f) - r ** 4 / (8 * f ** 3))
    assert hyperbolic_phase(r, f, wl) == pytest.approx(taylor, rel=1e-12)


def test_paraxial_agrees_near_axis_and_departs_at_rim():
    f, wl = 25_000.0, 10.0
    assert hyperbolic_phase(100.0, f, wl) == pytest.approx(paraxial_phase(100.0, f, wl), rel=1e-4)
    # at the F/1 rim the paraxial profile is off by ~17 waves: k (R^2/2f - (sqrt(R^2+f^2) - f))
    R = 12_500.0
    diff = (TWO_PI / wl) * (R * R / (2 * f) - (math.hypot(R, f) - f))
    assert hyperbolic_phase(R, f, wl) - paraxial_phase(R, f, wl) == pytest.approx(diff, rel=1e-12)
    assert diff > 17 * TWO_PI


def test_na_fnumber_zone_width():
    fov = LensDesign.foveal()
    assert fov.na == pytest.approx(0.2425356, abs=1e-6)
    assert fov.f_um / fov.diameter_um == 2.0
    # zone width = lambda / NA at the rim for the hyperbolic lens
    assert zone_width_um(fov, fov.radius_um) == pytest.approx(10.0 / fov.na, rel=1e-12)
    assert posts_per_2pi(fov, fov.radius_um) == pytest.approx(10.3078, abs=1e-4)
    per = LensDesign.perifoveal()
    assert per.na == pytest.approx(1 / math.sqrt(5), rel=1e-12)
    assert posts_per_2pi(per, per.radius_um) == pytest.approx(5.5902, abs=1e-4)
    # radius where a zone spans exactly n posts
    r4 = radius_below_posts(per, 4.0)
    assert posts_per_2pi(per, r4) == pytest.approx(4.0, rel=1e-10)


def test_zone_width_from_phase_derivative():
    d = LensDesign.perifoveal()
    r, h = 9_000.0, 1e-3
    dphi = (hyperbolic_phase(r + h, d.f_um, 10.0) - hyperbolic_phase(r - h, d.f_um, 10.0)) / (2 * h)
    assert zone_width_um(d, r) == pytest.approx(TWO_PI / abs(dphi), rel=1e-6)


def brute_force_count(design: LensDesign) -> int:
    o = 0.0 if design.lattice == "integer" else 0.5
    m = int(design.radius_um / design.period_um) + 2
    i = np.arange(-m, m + 1)
    x = (i + o) * design.period_um
    X, Y = np.meshgrid(x, x)
    return int((X * X + Y * Y <= design.radius_um ** 2).sum())


@pytest.mark.parametrize("d_mm,period,lattice", [
    (0.3, 4.0, "integer"), (0.3, 4.0, "half"), (0.2, 3.0, "integer"), (0.1234, 0.7, "half"),
    (0.4, 4.0, "integer"), (0.25, 2.5, "half"), (0.0401, 4.0, "integer"),
])
def test_exact_post_count_against_brute_force(d_mm, period, lattice):
    d = small(d_mm=d_mm, period_um=period, lattice=lattice)
    assert count_posts(d) == brute_force_count(d)


def test_post_count_boundary_sites_counted():
    # R = 5 periods exactly: sites with r == R (e.g. (5,0), (3,4)) are inside
    d = LensDesign("t", 1000.0, 40.0, period_um=4.0)
    assert count_posts(d) == brute_force_count(d) == 81


def test_paper_post_counts():
    assert count_posts(LensDesign.foveal()) == 276_116_425
    assert count_posts(LensDesign.perifoveal()) == 30_679_505
    assert count_posts(LensDesign.foveal().with_(lattice="half")) == 276_116_916
    assert count_posts(LensDesign.perifoveal().with_(lattice="half")) == 30_679_776


@given(st.floats(-1e6, 1e6, allow_nan=False))
def test_wrap_range_and_congruence(phi):
    w = float(wrap_phase(phi))
    assert 0.0 <= w < TWO_PI
    assert math.isclose(math.cos(w), math.cos(phi), abs_tol=1e-9)
    assert math.isclose(math.sin(w), math.sin(phi), abs_tol=1e-9)


@given(st.floats(-1e4, 1e4, allow_nan=False), st.integers(2, 64))
def test_quantize_error_bounded(phi, n):
    k = int(quantize_phase(phi, n))
    assert 0 <= k < n
    err = (float(level_phase(k, n)) - phi + math.pi) % TWO_PI - math.pi
    assert abs(err) <= math.pi / n + 1e-9


def test_quantize_rejects_bad_levels():
    with pytest.raises(InputError, match="levels"):
        quantize_phase(0.3, 1)


def test_tiles_cover_aperture_exactly():
    d = small(d_mm=0.5, period_um=4.0, levels=8)
    total = 0
    seen = set()
    for t in iter_tiles(d, tile_sites=17, with_phase=True):
        total += t.count
        assert (t.iy0, t.ix0) not in seen
        seen.add((t.iy0, t.ix0))
        iy, ix = np.nonzero(t.levels >= 0)
        x, y = site_positions_um(d, ix + t.ix0, iy + t.iy0)
        assert np.all(x * x + y * y <= d.radius_um ** 2)
        # levels agree with the quantised wrapped phase
        k = quantize_phase(t.phase[iy, ix], 8)
        assert np.array_equal(k, t.levels[iy, ix])
        assert np.all(t.levels[t.levels < 0] == EMPTY)
    assert total == count_posts(d) == brute_force_count(d)


def test_scalar_efficiency_values():
    assert scalar_efficiency(8) == pytest.approx(0.949641, abs=1e-6)
    assert scalar_efficiency(2) == pytest.approx(4 / math.pi ** 2, rel=1e-12)


def test_lattice_efficiency_point_sampled_limit():
    # a slow lens on a fine lattice: the sinc factors vanish and the quantisation loss -> sinc^2(pi/N)
    d = LensDesign("slow", 50_000.0, 2_000.0, period_um=0.5, levels=8)
    e = lattice_efficiency(d, samples=1 << 18, rng=1)
    assert e.value == pytest.approx(scalar_efficiency(8), abs=3e-3)


def test_lattice_efficiency_exact_vs_sampled():
    d = small(f_mm=0.5, d_mm=0.5, period_um=4.0, levels=4)
    exact = lattice_efficiency(d, exact=True)
    sampled = lattice_efficiency(d, exact=False, samples=200_000, rng=3)
    assert exact.exact and exact.stderr == 0.0
    assert abs(exact.value - sampled.value) < 5 * sampled.stderr + 1e-3


def test_paper_lattice_efficiency_reference():
    # REFERENCES.md: 8 levels on the 4 um lattice ~0.935 (F/2) and ~0.899 (F/1)
    assert lattice_efficiency(LensDesign.foveal(), samples=1 << 18).value == pytest.approx(0.935, abs=0.004)
    assert lattice_efficiency(LensDesign.perifoveal(), samples=1 << 18).value == pytest.approx(0.899, abs=0.006)


def test_warnings():
    fov = LensDesign.foveal()
    w = design_warnings(fov)
    assert any("substrate" in m for m in w)
    assert not any("posts per 2 pi" in m for m in w)
    fast = LensDesign("fast", 5_000.0, 10_000.0)  # F/0.5 on 4 um: < 4 posts per zone at the rim
    assert any("posts per 2 pi" in m for m in design_warnings(fast))
    fine = LensDesign("fine", 5_000.0, 1_000.0, period_um=2.0)
    assert design_warnings(fine) == []


def test_summary_paper_numbers():
    s = summarize(LensDesign.foveal(), samples=1 << 16, emit_warnings=False)
    assert s.posts_in_aperture == 276_116_425
    assert s.na == pytest.approx(0.2425, abs=1e-4)
    assert s.f_number == 2.0
    assert s.rim_zone_width_um == pytest.approx(41.23, abs=0.01)
    assert s.substrate_orders
    assert s.mtf_cutoff_cyc_per_mm == pytest.approx(48.51, abs=0.01)
    assert s.airy_first_zero_paraxial_um == pytest.approx(24.393, abs=1e-3)


def test_lens_without_lattice_sites_is_a_clear_error():
    d = LensDesign("tiny", 1000.0, 2.0, lattice="half")  # D = 2 um < half a period: no site inside
    assert count_posts(d) == 0
    with pytest.raises(InputError, match="diameter_um"):
        summarize(d, samples=1000, emit_warnings=False)


# ----------------------------------------------------------------------------------------------
# the phase beyond the hyperbola (LensDesign.phase_poly_rad)
# ----------------------------------------------------------------------------------------------
def test_design_phase_adds_the_polynomial_and_the_empty_tuple_is_the_hyperbola():
    from metafovea.lens import added_phase, design_phase

    lens = small()
    x, y = np.meshgrid(np.linspace(-150, 150, 31), np.linspace(-150, 150, 31))
    r = np.hypot(x, y)
    hyp = hyperbolic_phase(r, lens.f_um, lens.wavelength_um, lens.phase_sign)
    assert np.array_equal(design_phase(lens, x, y), hyp)  # bit for bit
    a = (3.0, -120.0, 40.5)
    c = lens.with_(phase_poly_rad=a)
    u = (r / c.radius_um) ** 2
    want = hyp + a[0] * u + a[1] * u ** 2 + a[2] * u ** 3  # added as is, whatever the sign convention
    assert np.allclose(design_phase(c, x, y), want, rtol=0, atol=1e-11)
    assert np.allclose(added_phase(c.with_(phase_sign=1), r), want - hyp, rtol=0, atol=1e-11)


def test_zone_widths_follow_the_actual_phase_gradient():
    from metafovea.lens import design_phase

    c = small(phase_poly_rad=(-25.0, -2.0))
    r = np.linspace(5.0, c.radius_um, 40)
    h = 1e-4
    slope = (design_phase(c, r + h, 0.0) - design_phase(c, r - h, 0.0)) / (2 * h)
    assert np.allclose(zone_width_um(c, r), 2 * np.pi / np.abs(slope), rtol=1e-6)
    assert np.allclose(posts_per_2pi(c, r) * c.period_um, zone_width_um(c, r))
    r4 = radius_below_posts(c, 4.0)
    assert r4 < c.radius_um and float(posts_per_2pi(c, r4)) == pytest.approx(4.0, rel=1e-6)
    assert math.isinf(radius_below_posts(small(phase_poly_rad=(-1.0,)), 4.0))  # 16.8 posts at the rim


def test_a_correction_that_narrows_zones_below_the_posts_is_warned_about():
    """The plain lens has 16.8 posts per 2 pi at its rim (no warning); added phases that steepen the rim's slope
    to 3.6 and to 1.8 posts per zone are warned about, naming phase_poly_rad (and the aliasing below 2); one that
    bends the rim's rays outwards (ray directions not monotone) is warned about too."""
    assert not any("posts per 2 pi" in w for w in design_warnings(small()))
    w1 = design_warnings(small(phase_poly_rad=(-25.0,)))
    assert any("phase_poly_rad" in w and "narrower than the posts allow" in w for w in w1)
    assert not any("fewer than 2 posts" in w for w in w1)
    w2 = design_warnings(small(phase_poly_rad=(-60.0,)))
    assert any("fewer than 2 posts" in w for w in w2)
    w3 = design_warnings(small(phase_poly_rad=(60.0,)))
    assert any("not monotone" in w for w in w3)
    assert not any("not monotone" in w for w in w1)


def test_summary_and_lattice_efficiency_of_a_corrected_lens():
    plain = small()
    zero = small(phase_poly_rad=(0.0,))
    a, b = lattice_efficiency(plain, exact=True), lattice_efficiency(zero, exact=True)
    assert b.value == pytest.approx(a.value, rel=1e-12)
    steep = small(phase_poly_rad=(-25.0,))  # 3.6 posts per zone at the rim: the lattice samples it worse
    assert lattice_efficiency(steep, levels=0, exact=True).value < lattice_efficiency(plain, levels=0, exact=True).value
    s = summarize(steep, samples=4096, emit_warnings=False)
    assert s.phase_poly_rad == (-25.0,)
    assert s.rim_phase_rad == pytest.approx(float(hyperbolic_phase(150.0, 1000.0, 10.0)) - 25.0)
    assert s.narrowest_posts_per_2pi == pytest.approx(s.rim_posts_per_2pi) and s.narrowest_posts_per_2pi < 4
    assert summarize(plain, samples=4096, emit_warnings=False).narrowest_posts_per_2pi is None

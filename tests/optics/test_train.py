"""The optical train per channel against independent references: a bounce-by-bounce sum for the wafer, a
Monte Carlo area for the ring, site enumeration for the level fractions and the coherent pass-through, and an
exact ray trace through both lenses' phase gradients for the glare disks."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from metafovea.config import LensDesign, PlatformDesign, SystemDesign
from metafovea.lens import design_phase, quantize_phase, site_positions_um
from metafovea.library import PostSet
from metafovea.optics.train import (
    bare_face_reflectance,
    camera_trains,
    channel_train,
    circle_overlap_fraction,
    level_fractions,
    silicon_absorption_per_cm,
    throughput_lines,
    wafer_transmission,
)


def _bounces(t1, r1, t2, r2, a, n=400):
    """Incoherent slab by explicit bounces: each round trip multiplies by r2 a r1 a."""
    total, amp = 0.0, t1 * a
    for _ in range(n):
        total += amp * t2
        amp *= r2 * a * r1 * a
    return total


def test_wafer_transmission_is_the_sum_of_its_bounces():
    rng = np.random.default_rng(0)
    for _ in range(20):
        r1, r2 = rng.uniform(0, 0.9, 2)
        t1, t2 = (1 - r1) * rng.uniform(0.5, 1), (1 - r2) * rng.uniform(0.5, 1)
        a = rng.uniform(0.3, 1.0)
        assert float(wafer_transmission(t1, r1, t2, r2, a)) == pytest.approx(_bounces(t1, r1, t2, r2, a), rel=1e-12)
    # a bare silicon slab, lossless: 2 n / (n^2 + 1)
    n = 3.42
    r = bare_face_reflectance(n)
    assert float(wafer_transmission(1 - r, r, 1 - r, r, 1.0)) == pytest.approx(2 * n / (n * n + 1), rel=1e-12)


def test_free_carrier_absorption_follows_the_cited_law():
    # Schroder et al. 1978: alpha = C lambda^2 N; 10 ohm cm p-type: N = 1 / (q rho mu_p) = 1.39e15 /cm^3
    a = silicon_absorption_per_cm(10.0, 10.0, "p")
    assert float(a) == pytest.approx(2.7e-18 * 100 * 1 / (1.602176634e-19 * 10 * 450), rel=1e-9)
    assert float(silicon_absorption_per_cm(20.0, 10.0, "p") / a) == pytest.approx(4.0)
    assert float(silicon_absorption_per_cm(10.0, 10.0, "n")) < float(a) / 5  # electrons: lower C, higher mobility
    assert float(silicon_absorption_per_cm(10.0, 10.0, "n", 0.5)) == pytest.approx(
        float(silicon_absorption_per_cm(10.0, 10.0, "n")) + 0.5)


@pytest.mark.parametrize("a,b,d", [(1.0, 3.0, 0.0), (1.0, 3.0, 1.5), (1.0, 3.0, 2.5), (1.0, 3.0, 3.5),
                                   (2.0, 1.0, 0.3), (2.0, 1.0, 1.8), (1.0, 1.0, 1.0), (1.0, 3.0, 4.5)])
def test_circle_overlap_against_monte_carlo(a, b, d):
    g = np.random.default_rng(1)
    n = 400_000
    r = a * np.sqrt(g.random(n))
    t = 2 * np.pi * g.random(n)
    inside = np.hypot(d + r * np.cos(t), r * np.sin(t)) <= b
    p = inside.mean()
    assert float(circle_overlap_fraction(a, b, d)) == pytest.approx(p, abs=4 * math.sqrt(p * (1 - p) / n) + 1e-9)


def _small_lens(name="a", f_mm=1.0, d_mm=1.0, pol="x", levels=8):
    return LensDesign(name, f_mm * 1000, d_mm * 1000, polarization=pol, levels=levels)


def _sites(lens, radius_um, centre=(0.0, 0.0)):
    """Every lattice site of ``lens`` inside the footprint disk and the aperture, with its level."""
    n = int(math.ceil((abs(centre[0]) + radius_um) / lens.period_um)) + 2
    i = np.arange(-n, n + 1)
    ix, iy = np.meshgrid(i, i)
    x, y = site_positions_um(lens, ix.ravel(), iy.ravel())
    ok = (np.hypot(x - centre[0], y - centre[1]) <= radius_um) & (np.hypot(x, y) <= lens.radius_um)
    return quantize_phase(design_phase(lens, x[ok], y[ok]), lens.levels)


@pytest.mark.parametrize("radius_um,centre", [(500.0, (0.0, 0.0)), (200.0, (0.0, 0.0)), (150.0, (300.0, 100.0))])
def test_level_fractions_sample_the_sites(radius_um, centre):
    lens = _small_lens()
    k = _sites(lens, radius_um, centre)
    exact = np.bincount(k, minlength=lens.levels) / k.size
    p, m = level_fractions(lens, radius_um, centre, samples=1 << 16, rng=3)
    assert np.all(np.abs(p - exact) <= 5 * np.sqrt(exact * (1 - exact) / m) + 1e-12)


def _posts(rng, pol, levels=8):
    """A post set with rough pass-through (amplitude 0.7-0.95, phase spread ~0.6 rad) and reflections."""
    t_f = rng.uniform(0.75, 0.95, levels) * np.exp(2j * np.pi * np.arange(levels) / levels
                                                   + 1j * rng.normal(0, .1, levels))
    t_p = rng.uniform(0.7, 0.95, levels) * np.exp(1j * rng.uniform(-0.3, 0.3, levels))
    r = rng.uniform(0.02, 0.2, levels)
    t_x, t_y = (t_f, t_p) if pol == "x" else (t_p, t_f)
    base = PostSet.ideal(levels, polarization=pol)
    return PostSet(pol, 4.0, 10.0, 10.0, base.widths_um, t_x, t_y, source="test", R_x=r, R_y=r[::-1])


def _small_system():
    """Scaled paper camera: F/2 front lens (f 6 mm, D 3 mm), F/1 back lens (f 1 mm, D 1 mm), 5 mm apart."""
    fov = _small_lens("foveal", 6.0, 3.0, "x")
    per = _small_lens("perifoveal", 1.0, 1.0, "y")
    return SystemDesign(foveal=fov, perifoveal=per, lens_to_sensor_um=(6000.0, 1000.0))


@pytest.mark.parametrize("channel", ["foveal", "perifoveal"])
def test_coherent_pass_through_is_the_site_average(channel):
    rng = np.random.default_rng(5)
    system = _small_system()
    posts = {"x": _posts(rng, "x"), "y": _posts(rng, "y")}
    tr = channel_train(system, channel, posts, [10.0], [1.0], posts="test")
    L, O = (system.foveal, system.perifoveal) if channel == "foveal" else (system.perifoveal, system.foveal)
    # the bundle's footprint on the other lens: the converging cone (front lens focusing) or the parallel one
    r_foot = L.radius_um * (1 - 5000 / 6000) if channel == "foveal" else L.radius_um
    t_p = posts[O.polarization].transmission(L.polarization)
    ko = _sites(O, r_foot)
    d0 = t_p[ko].mean()
    sigma = np.std(t_p[ko]) / math.sqrt(1 << 16)
    got = tr.factors[f"{O.name} lens: pass-through, coherent"]
    assert got == pytest.approx(abs(d0) ** 2, abs=2 * 5 * sigma * abs(d0))
    kl = _sites(L, L.radius_um)
    t_f = posts[L.polarization].transmission(L.polarization)
    p_kl = np.abs(t_f[kl]) ** 2
    assert tr.metasurface_transmission == pytest.approx(np.mean(p_kl), abs=5 * np.std(p_kl) / 256)
    # the wafer factors: bare face, and G = A / (1 - R_b R_ms A^2) with the footprint's mean reflectance
    rb = bare_face_reflectance(system.platform.n_substrate)
    a = math.exp(-float(silicon_absorption_per_cm(10.0, 15.0, "p")) * 500e-4)
    r_ms = posts[L.polarization].reflectance(L.polarization)[0][kl].mean()
    assert tr.factors[f"{L.name} lens: wafer reflections and absorption"] == pytest.approx(
        a / (1 - rb * r_ms * a * a), rel=2e-3)
    prod = np.prod(list(tr.factors.values()))
    assert tr.throughput == pytest.approx(prod, rel=1e-12)  # one wavelength: the throughput is the product
    # what leaks is the ripple: the other lens' zero-order power minus its coherent part (all orders reach the
    # focal plane in this geometry for the foveal channel)
    ripple = np.mean(np.abs(t_p[ko]) ** 2) - abs(d0) ** 2
    assert ripple > 1e-3
    if channel == "foveal":
        assert tr.leak_fraction * tr.throughput == pytest.approx(
            prod / tr.factors[f"{O.name} lens: pass-through, coherent"] * ripple, rel=0.05)


def _exact_rim_ray(front, back, gap_um, last_um, m_front, m_back, lam, h):
    """Trace one ray of height ``h`` (on axis, zero incidence) through two lenses using the exact direction
    change of order m of a hyperbolic phase: ds = -m (lambda / lambda0) r / sqrt(r^2 + f^2)."""
    def kick(lens, m, r, s):
        return s - m * (lam / lens.wavelength_um) * r / math.hypot(r, lens.f_um)
    s = kick(front, m_front, h, 0.0)
    x2 = h + gap_um * s / math.sqrt(1 - s * s)
    s = kick(back, m_back, x2, s)
    return x2, x2 + last_um * s / math.sqrt(1 - s * s)


@pytest.mark.parametrize("channel", ["foveal", "perifoveal"])
def test_glare_disks_against_an_exact_ray_trace(channel):
    """Slow scaled lenses (F/20, F/10), where the paraxial trace of the glare disks is accurate."""
    fov = _small_lens("foveal", 60.0, 3.0, "x")
    per = _small_lens("perifoveal", 10.0, 1.0, "y")
    system = SystemDesign(foveal=fov, perifoveal=per, lens_to_sensor_um=(60000.0, 10000.0))
    rng = np.random.default_rng(7)
    posts = {"x": _posts(rng, "x"), "y": _posts(rng, "y")}
    tr = channel_train(system, channel, posts, [9.0], [1.0], posts="test")
    L, O = (fov, per) if channel == "foveal" else (per, fov)
    front, back = (fov, per)
    assert {abs(lk.order) for lk in tr.leaks} >= {1, 2, 3, 4}
    for lk in tr.leaks:
        if abs(lk.order) > 4:
            continue  # paraxial: ray slopes up to 0.1 here (3 % off at order 8, 0.18)
        m_front, m_back = (1, lk.order) if channel == "foveal" else (lk.order, 1)
        # the rim of the part of the front lens whose rays pass the back lens' ring
        lo, hi = 0.0, front.radius_um
        if abs(_exact_rim_ray(front, back, 50000, 10000, m_front, m_back, 9.0, hi)[0]) > back.radius_um:
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                if abs(_exact_rim_ray(front, back, 50000, 10000, m_front, m_back, 9.0, mid)[0]) > back.radius_um:
                    hi = mid
                else:
                    lo = mid
        _, hs = _exact_rim_ray(front, back, 50000, 10000, m_front, m_back, 9.0, hi)
        expect = max(abs(hs), 0.61 * 9.0 / L.na)
        assert lk.radius_um == pytest.approx(expect, rel=0.02), lk


def test_ideal_posts_leave_the_bare_wafers_and_say_so():
    system = SystemDesign.paper()
    ideal = {lens.polarization: PostSet.ideal(8, polarization=lens.polarization)
             for lens in (system.foveal, system.perifoveal)}
    f, p = camera_trains(system, ideal, [10.0], [1.0], posts="ideal")
    rb = bare_face_reflectance(3.42)
    a = math.exp(-float(silicon_absorption_per_cm(10.0, 15.0, "p")) * 0.05)
    for tr in (f, p):
        assert tr.throughput == pytest.approx(((1 - rb) * a) ** 2, rel=1e-9)  # no reflection at the posts
        assert tr.leaks == ()
        assert tr.lens_transmission["focusing"]["x"] == pytest.approx((1 - rb) * a, rel=1e-9)
    lines = throughput_lines([f.summary(), p.summary()])
    assert any("simplified model" in ln for ln in lines)
    # the perifoveal channel's parallel bundle (radius 12.5 mm) crosses the foveal ring (37.5 mm) 125 mm in
    # front: clipped beyond atan(25 / 125) = 11.3 deg, partly clipped at the sensor corner (15.6 deg)
    assert p.clipping_starts_deg() == pytest.approx(math.degrees(math.atan(25 / 125)))
    v = p.clear_fraction(np.tan(np.radians([0.0, 11.0, 15.6])))
    assert v[0] == 1.0 and v[1] == 1.0 and 0.4 < v[2] < 0.8


def test_thicker_lossier_wafers_transmit_less():
    system = SystemDesign.paper()
    ideal = {lens.polarization: PostSet.ideal(8, polarization=lens.polarization)
             for lens in (system.foveal, system.perifoveal)}
    base = camera_trains(system, ideal, [10.0], [1.0], posts="ideal")[0].throughput
    lossy = replace(system, platform=replace(PlatformDesign(), substrate_extra_absorption_per_cm=2.0,
                                             substrate_thickness_um=1000.0))
    t = camera_trains(lossy, ideal, [10.0], [1.0], posts="ideal")[0].throughput
    a0 = math.exp(-float(silicon_absorption_per_cm(10.0, 15.0, "p")) * 0.05)
    a1 = math.exp(-(float(silicon_absorption_per_cm(10.0, 15.0, "p")) + 2.0) * 0.1)
    assert t / base == pytest.approx((a1 / a0) ** 2, rel=1e-9)


def test_oblique_incidence_factor_against_posts_solved_at_the_corner():
    """The perifoveal channel's throughput at its sensor corner (15.6 deg, field along x) relative to the axis: the
    focusing order of the perifoveal posts and the coherent pass-through of the foveal posts, both solved directly
    by RCWA at that angle, against the train's interpolated field factor."""
    from metafovea.library import oblique_response, system_post_sets
    from metafovea.optics.pupil import order_coefficients
    from metafovea.optics.train import system_trains
    from metafovea.rcwa.geometry import Layer, Rectangle, Stack
    from metafovea.rcwa.solve import solve

    system = SystemDesign.paper()
    posts, name = system_post_sets(system)
    fov_tr, per_tr = system_trains(system, posts, name)
    theta = math.degrees(math.atan(0.5 * math.hypot(290, 290) * 34.0 / 25000.0))
    assert per_tr.oblique is not None and "applied" in per_tr.oblique_note

    def solved(ps, pol):
        out = []
        for wx, wy in ps.widths_um:
            st = Stack(4.0, 4.0, (Layer(10.0, 1.0, (Rectangle(wx, wy, 3.42),)),), 3.42, 1.0)
            th = math.degrees(math.asin(math.sin(math.radians(theta)) / 3.42))
            j = solve(st, 10.0, harmonics=5, theta_deg=th, incidence="substrate", check_energy=False).t00("substrate")
            j0 = solve(st, 10.0, harmonics=5, check_energy=False).t00("substrate")
            out.append(j[0, 0] / j0[0, 0] if pol == "x" else j[1, 1] / j0[1, 1])  # xz plane: x is p, y is s
        return ps.transmission(pol) * np.array(out)

    per, fov = posts["y"], posts["x"]

    def c(t):
        return abs(complex(order_coefficients(t, 8, np.array([1]))[0])) ** 2

    focus = c(solved(per, "y")) / c(per.transmission("y"))
    p_fov, _ = level_fractions(system.foveal, system.perifoveal.radius_um, samples=1 << 16, rng=2)
    d0 = abs(complex(p_fov @ solved(fov, "y"))) ** 2 / abs(complex(p_fov @ fov.transmission("y"))) ** 2
    expect = focus * d0
    got = float(per_tr.oblique_factor(math.tan(math.radians(theta)), 0.0))
    err = max(oblique_response(per, system.platform).error, oblique_response(fov, system.platform).error)
    assert expect < 0.99  # a few per cent at the corner: worth modelling
    assert got == pytest.approx(expect, abs=4 * err)
    # the foveal channel's light crosses the perifoveal posts as a converging cone (up to 14 deg)
    src = fov_tr.sources["perifoveal lens: pass-through, coherent"]
    assert "converging cone" in src

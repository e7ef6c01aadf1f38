"""The differentiable imaging model (metafovea.optics.jaxpsf) against the production PSF engines (hyperbola),
against an independent brute-force Rayleigh-Sommerfeld integral written here (added radial phase), and its
gradients against finite differences of itself and of the brute-force reference."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import scipy.special as sp

jax = pytest.importorskip("jax")
import jax.numpy as jnp  # noqa: E402

from metafovea.config import LensDesign, SystemDesign, load_system  # noqa: E402
from metafovea.errors import InputError  # noqa: E402
from metafovea.library import PostSet  # noqa: E402
from metafovea.optics import jaxpsf as J  # noqa: E402
from metafovea.optics import max_field_deg, mtf_2d, psf, sensor_psf  # noqa: E402
from metafovea.optics.train import channel_train  # noqa: E402

TOL = 1e-3  # of the peak: the target


@pytest.fixture(autouse=True)
def _x64():
    with J.x64():
        yield


def _rel(a, b):
    b = np.asarray(b)
    return float(np.abs(np.asarray(a) - b).max() / b.max())


def _posts(rng, pol, levels=8):
    """A non-ideal post set (phase errors, amplitudes < 1, a rippled pass-through): the haze orders are non-zero."""
    ph = 2 * np.pi * np.arange(levels) / levels + rng.normal(0, 0.25, levels)
    t_f = rng.uniform(0.75, 0.95, levels) * np.exp(1j * ph)
    t_p = rng.uniform(0.8, 0.95, levels) * np.exp(1j * rng.normal(0, 0.3, levels))
    t_x, t_y = (t_f, t_p) if pol == "x" else (t_p, t_f)
    base = PostSet.ideal(levels, polarization=pol)
    return PostSet(pol, 4.0, 10.0, 10.0, base.widths_um, t_x, t_y, source="test",
                   R_x=rng.uniform(0.02, 0.2, levels), R_y=rng.uniform(0.02, 0.2, levels))


# ----------------------------------------------------------------------------------------------
# an independent brute-force reference with the added phase (polar quadrature, exact kernel)
# ----------------------------------------------------------------------------------------------
def _phase(lens, a, rho):
    """phi(rho) of the contract: hyperbola + sum a_j (rho / R)^(2 j)."""
    k0 = 2 * np.pi / lens.wavelength_um
    u = (rho / lens.radius_um) ** 2
    return -k0 * (np.sqrt(rho * rho + lens.f_um ** 2) - lens.f_um) + sum(c * u ** (j + 1) for j, c in enumerate(a))


def _brute_rs(lens, a, wavelength_um, field_deg, xs, ys, c1=1.0, per_zone=20):
    """First Rayleigh-Sommerfeld integral of c1 exp(i phi(rho)) exp(i k s0.rho) over the aperture at (ys, xs):
    Gauss-Legendre per 2 pi of the full phase radially, trapezoid azimuthally (nodes from the kernel's slope
    along the ring), exact kernel at every node."""
    R, z, lam = lens.radius_um, lens.f_um, wavelength_um
    k = 2 * np.pi / lam
    t = math.tan(math.radians(field_deg))
    s0 = np.array([t, 0.0]) / math.sqrt(1 + t * t)
    rr = np.linspace(0, R, 20001)
    ph = np.abs(_phase(lens, a, rr))
    turns = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(ph)))]) / (2 * np.pi)
    edges = np.unique(np.concatenate([np.interp(np.arange(math.ceil(turns[-1])), turns, rr), [R]]))
    xg, wg = sp.roots_legendre(per_zone)
    X, Y = np.meshgrid(xs, ys)
    ox, oy = X.ravel(), Y.ravel()
    out = np.zeros(ox.size, complex)
    ring = np.linspace(0, 2 * np.pi, 2048, endpoint=False)
    for r0, r1 in zip(edges[:-1], edges[1:]):
        rho = 0.5 * (r1 - r0) * xg + 0.5 * (r1 + r0)
        wr = 0.5 * (r1 - r0) * wg
        cx, cy = r1 * np.cos(ring), r1 * np.sin(ring)
        th = k * (s0[0] * cx)[None] + k * np.sqrt((ox[[0, -1], None] - cx) ** 2 + (oy[[0, -1], None] - cy) ** 2 + z * z)
        slope = np.abs(np.angle(np.exp(1j * (np.roll(th, -1, 1) - th)))).max() * ring.size / (2 * np.pi)
        n_phi = int(2 * slope + 64)
        phi = np.arange(n_phi) * 2 * np.pi / n_phi
        Rg, P = np.meshgrid(rho, phi)
        W = (np.meshgrid(wr, phi)[0] * Rg * 2 * np.pi / n_phi).ravel()
        qx, qy = (Rg * np.cos(P)).ravel(), (Rg * np.sin(P)).ravel()
        src = c1 * W * np.exp(1j * (_phase(lens, a, np.hypot(qx, qy)) + k * s0[0] * qx))
        r = np.sqrt((ox[:, None] - qx) ** 2 + (oy[:, None] - qy) ** 2 + z * z)
        K = z / (1j * lam) * (1 - 1 / (1j * k * r)) * np.exp(1j * k * (r - z)) / (r * r)
        out += K @ src
    return out.reshape(X.shape)


def _brute_psf(lens, a, wl, w, field_deg, xs, ys, pitch):
    tot = sum(wi * np.abs(_brute_rs(lens, a, lam, field_deg, xs, ys)) ** 2 for lam, wi in zip(wl, w))
    return tot * pitch * pitch / (math.pi * lens.radius_um ** 2)


# ----------------------------------------------------------------------------------------------
# building blocks
# ----------------------------------------------------------------------------------------------
def test_bessel_j0_and_its_derivative_match_scipy():
    x = np.concatenate([np.linspace(0, 30, 3001), np.linspace(30, 5000, 4001)])
    assert np.abs(np.asarray(J.bessel_j0(jnp.asarray(x))) - sp.j0(x)).max() < 1e-11
    d = jax.vmap(jax.grad(J.bessel_j0))(jnp.asarray(x))
    assert np.abs(np.asarray(d) + sp.j1(x)).max() < 1e-11


def test_refuses_float32():
    lens = LensDesign("s", 2000.0, 1000.0)
    m = J.imaging_model(lens, pitch_um=4.0, size=5)
    with jax.enable_x64(False), pytest.raises(InputError, match="float64"):
        m.band_psf(np.zeros(0))


def test_refuses_coefficients_beyond_the_bound_the_nodes_were_sized_for():
    lens = LensDesign("s", 2000.0, 1000.0)
    m = J.imaging_model(lens, pitch_um=4.0, size=5, n_coefficients=2, phase_bound_rad=1.0)
    m.band_psf(np.array([0.5, -1.0]))
    with pytest.raises(InputError, match="phase_bound_rad"):
        m.band_psf(np.array([0.5, -1.5]))


# ----------------------------------------------------------------------------------------------
# the hyperbola against production's engines
# ----------------------------------------------------------------------------------------------
def test_on_axis_fine_grid_matches_production_hankel():
    lens = LensDesign("s", 4000.0, 2000.0)
    wl, w = np.array([8.5, 10.0, 12.5]), np.array([1.0, 2.0, 1.5])
    P = psf(lens, wavelengths_um=wl, weights=w, engine="hankel", quantize=True, lattice=True, window_um=250,
            pitch_um=5.0, center_um=(0, 0), allow_truncation=True, error=1e-6)
    m = J.imaging_model(lens, wavelengths_um=wl, weights=w, pitch_um=5.0, size=P.shape[0])
    assert m.engine == "debye"
    got = m.band_psf(np.zeros(0), J.level_table(lens, None, None, wl))
    assert _rel(got, P.intensity) < TOL * 1e-2  # measured 3e-7


@pytest.mark.filterwarnings("ignore::metafovea.errors.NotConvergedWarning")  # production's estimate is loose
def test_on_axis_sensor_grid_matches_sensor_psf_with_haze():
    rng = np.random.default_rng(3)
    lens = LensDesign("s", 4000.0, 2000.0)
    ps = _posts(rng, "x")
    wl, w = np.array([9.0, 10.0, 13.0]), np.array([1.0, 1.0, 0.5])
    S = sensor_psf(lens, pixel_pitch_um=17.0, wavelengths_um=wl, weights=w, post_set=ps, size_px=21, error=1e-5)
    assert S.info["haze_power"] > 1e-3  # the haze is exercised
    m = J.imaging_model(lens, wavelengths_um=wl, weights=w, pitch_um=17.0, size=21, sensor=True)
    got = np.asarray(m.band_psf(np.zeros(0), J.level_table(lens, ps, None, wl)))
    assert _rel(got, S.intensity) < TOL * 1e-2
    assert got.sum() == pytest.approx(S.intensity.sum(), rel=1e-5)


def test_at_the_edge_field_matches_production_rs():
    """At the lens' field limit (pupil.max_field_deg, 49 deg for F/2) the PSF spreads over ~40 mm for this 1 mm lens;
    both engines are compared on a window around the chief ray (production with allow_truncation)."""
    lens = LensDesign("e", 2000.0, 1000.0)
    wl, w = np.array([9.5, 10.0, 11.0]), np.array([1.0, 1.0, 1.0])
    fld = max_field_deg(lens, float(wl.max()))
    chief = (lens.f_um * math.tan(math.radians(fld)), 0.0)
    P = psf(lens, wavelengths_um=wl, weights=w, engine="rs", field_deg=fld, quantize=True, lattice=True,
            window_um=110, pitch_um=5.0, center_um=chief, allow_truncation=True, error=1e-4)
    m = J.imaging_model(lens, wavelengths_um=wl, weights=w, field_deg=fld, pitch_um=5.0, size=P.shape[0],
                        center_um=chief)
    assert m.engine == "rs"
    got = m.band_psf(np.zeros(0), J.level_table(lens, None, None, wl))
    assert _rel(got, P.intensity) < TOL * 0.1


def test_the_comparison_fails_when_undersampled():
    """The 1e-3 check is not vacuous: too few quadrature nodes break it (measured: debye 16 nodes 3e-7, 12 nodes
    2e-5, 8 nodes 5e-3 of the peak; rs (10, 10) nodes 0.6)."""
    lens = LensDesign("s", 4000.0, 2000.0)
    wl = np.array([9.0, 10.0])
    P = psf(lens, wavelengths_um=wl, engine="hankel", quantize=True, lattice=True, window_um=250, pitch_um=5.0,
            center_um=(0, 0), allow_truncation=True, error=1e-6)
    good = J.imaging_model(lens, wavelengths_um=wl, pitch_um=5.0, size=P.shape[0])
    bad = J.imaging_model(lens, wavelengths_um=wl, pitch_um=5.0, size=P.shape[0], nodes=8)
    tf = J.level_table(lens, None, None, wl)
    assert good.info["nodes"] > 8
    assert _rel(good.band_psf(np.zeros(0), tf), P.intensity) < TOL
    assert _rel(bad.band_psf(np.zeros(0), tf), P.intensity) > TOL
    rs = J.imaging_model(lens, wavelengths_um=wl, pitch_um=5.0, size=P.shape[0], engine="rs")
    rs_bad = J.imaging_model(lens, wavelengths_um=wl, pitch_um=5.0, size=P.shape[0], engine="rs", nodes=(10, 10))
    assert _rel(rs_bad.band_psf(np.zeros(0), tf), rs.band_psf(np.zeros(0), tf)) > TOL


def test_train_gains_reproduce_the_channel_throughput():
    rng = np.random.default_rng(5)
    fov = LensDesign("foveal", 6000.0, 3000.0, polarization="x")
    per = LensDesign("perifoveal", 1000.0, 1000.0, polarization="y")
    system = SystemDesign(foveal=fov, perifoveal=per, lens_to_sensor_um=(6000.0, 1000.0))
    posts = {"x": _posts(rng, "x"), "y": _posts(rng, "y")}
    wl, w = np.array([8.0, 10.0, 12.0]), np.array([0.2, 0.5, 0.3])
    for channel in ("foveal", "perifoveal"):
        tr = channel_train(system, channel, posts, wl, w, posts="test")
        g = J.train_gains(system, channel, posts, wl)
        L, O = (fov, per) if channel == "foveal" else (per, fov)
        tp = J.level_table(O, posts[O.polarization], L.polarization, wl)
        d0 = tp @ g.pass_fractions
        assert g.metasurface_transmission == pytest.approx(tr.metasurface_transmission, rel=1e-12)
        assert float(w @ (g.gain * np.abs(d0) ** 2)) * g.metasurface_transmission == pytest.approx(tr.throughput,
                                                                                                   rel=1e-10)


def test_train_multiplies_each_wavelength():
    rng = np.random.default_rng(2)
    fov = LensDesign("foveal", 4000.0, 2000.0, polarization="x")
    per = LensDesign("perifoveal", 1000.0, 1000.0, polarization="y")
    system = SystemDesign(foveal=fov, perifoveal=per, lens_to_sensor_um=(4000.0, 1000.0))
    posts = {"x": _posts(rng, "x"), "y": _posts(rng, "y")}
    wl = np.array([9.0, 11.0])
    g = J.train_gains(system, "foveal", posts, wl)
    tf = J.level_table(fov, posts["x"], None, wl)
    tp = J.level_table(per, posts["y"], "x", wl)
    bare = J.imaging_model(fov, wavelengths_um=wl, pitch_um=17.0, size=9, sensor=True)
    withtrain = J.imaging_model(fov, wavelengths_um=wl, pitch_um=17.0, size=9, sensor=True, train=g)
    a = np.asarray(bare.psf_per_wavelength(np.zeros(0), tf))
    b = np.asarray(withtrain.psf_per_wavelength(np.zeros(0), tf, tp))
    fac = g.gain * np.abs(tp @ g.pass_fractions) ** 2
    np.testing.assert_allclose(b, a * fac[:, None, None], rtol=1e-12, atol=0)
    with pytest.raises(InputError, match="t_pass"):
        withtrain.band_psf(np.zeros(0), tf)


# ----------------------------------------------------------------------------------------------
# the added phase against the brute-force reference
# ----------------------------------------------------------------------------------------------
A_TEST = np.array([6.0, -4.0])  # rad at the design wavelength: ~1 wave of defocus and of spherical aberration


@pytest.mark.parametrize("field_deg", [0.0, 12.0])
def test_added_phase_rs_engine_matches_the_brute_force_integral(field_deg):
    lens = LensDesign("a", 2000.0, 1000.0)
    wl, w = np.array([9.0, 10.0, 11.5]), np.array([1.0, 1.0, 1.0]) / 3
    c = (lens.f_um * math.tan(math.radians(field_deg)), 0.0)
    m = J.imaging_model(lens, wavelengths_um=wl, weights=w, field_deg=field_deg, pitch_um=4.0, size=21, center_um=c,
                        engine="rs", n_coefficients=2, phase_bound_rad=8.0, lattice=False)
    xs, ys = c[0] + (np.arange(21) - 10) * 4.0, (np.arange(21) - 10) * 4.0
    ref = _brute_psf(lens, A_TEST, wl, w, field_deg, xs, ys, 4.0)
    got = np.asarray(m.band_psf(A_TEST))
    assert _rel(got, ref) < TOL * 0.1
    # and the added phase matters at this size: the hyperbola is far from it
    assert _rel(np.asarray(m.band_psf(np.zeros(2))), ref) > 0.1


def test_added_phase_debye_engine_converges_to_the_brute_force_integral_as_one_over_fresnel_number():
    """The Debye (production's on-axis) model with the added phase against the exact integral at the design
    wavelength. Its model error is O(W / N_F) (W the aberration in waves, N_F = a^2 / (lambda f) the Fresnel
    number; measured with A_TEST: 0.12 at N_F 12.5, 0.032 at 50, 0.013 at 125, 0.0065 at 250, i.e. ~1.6 / N_F:
    ~2e-3 for the paper's lenses, N_F 625-937). The test checks that law (a wrong Debye phase or weight would not
    converge); the rs engine is the one that meets 1e-3 for any lens."""
    errs = []
    for d in (1000.0, 4000.0):
        lens = LensDesign("a", 2 * d, d)
        m = J.imaging_model(lens, pitch_um=4.0, size=15, n_coefficients=2, phase_bound_rad=8.0, lattice=False)
        xs = (np.arange(15) - 7) * 4.0
        ref = _brute_psf(lens, A_TEST, [10.0], [1.0], 0.0, xs, xs, 4.0)
        nf = (d / 2) ** 2 / (10.0 * 2 * d)
        errs.append(_rel(m.band_psf(A_TEST), ref) * nf)
    assert 0.5 < errs[0] < 2.5 and 0.5 < errs[1] < 2.5  # error x N_F: 1.5 and 1.6


# ----------------------------------------------------------------------------------------------
# gradients
# ----------------------------------------------------------------------------------------------
def _fd(f, x, h, idx=None):
    """Central differences of f at x along the flat indices ``idx`` (all by default)."""
    idx = range(x.size) if idx is None else idx
    g = np.zeros(len(idx))
    for n, i in enumerate(idx):
        e = np.zeros_like(x)
        e.flat[i] = h
        g[n] = (f(x + e) - f(x - e)) / (2 * h)
    return g


@pytest.mark.parametrize("engine", ["debye", "rs"])
def test_gradients_match_finite_differences_of_the_model(engine):
    rng = np.random.default_rng(7)
    fov = LensDesign("foveal", 2000.0, 1000.0, polarization="x")
    per = LensDesign("perifoveal", 1000.0, 1000.0, polarization="y")
    system = SystemDesign(foveal=fov, perifoveal=per, lens_to_sensor_um=(2000.0, 1000.0))
    posts = {"x": _posts(rng, "x"), "y": _posts(rng, "y")}
    wl = np.array([9.0, 10.5])
    g = J.train_gains(system, "foveal", posts, wl)
    tf0 = J.level_table(fov, posts["x"], None, wl)
    tp0 = J.level_table(per, posts["y"], "x", wl)
    m = J.imaging_model(fov, wavelengths_um=wl, pitch_um=8.5, size=7, sensor=True, n_coefficients=2,
                        phase_bound_rad=8.0, train=g, engine=engine, field_deg=0.0)
    W = jnp.asarray(rng.uniform(0, 1, (7, 7)))

    def obj(a, tr, ti, pr, pi):
        return jnp.sum(W * m.band_psf(a, tr + 1j * ti, pr + 1j * pi)) + m.mtf_area(a, tr + 1j * ti, pr + 1j * pi)

    args = [np.array([1.5, -2.0]), tf0.real, tf0.imag, tp0.real, tp0.imag]
    grads = jax.grad(obj, argnums=(0, 1, 2, 3, 4))(*[jnp.asarray(x) for x in args])
    obj_jit = jax.jit(obj)  # the same function, compiled once for its ~36 evaluations
    for i, (x, gr) in enumerate(zip(args, grads)):
        def f(v, i=i):
            a = list(args)
            a[i] = v
            return float(obj_jit(*[jnp.asarray(t) for t in a]))
        idx = rng.choice(x.size, size=min(x.size, 4), replace=False)  # a few entries of each input
        fd = _fd(f, x, 1e-5, idx)
        assert np.abs(np.asarray(gr).ravel()[idx] - fd).max() <= 1e-5 * np.abs(fd).max() + 1e-12, i


def test_phase_gradient_matches_finite_differences_of_the_brute_force_reference():
    lens = LensDesign("a", 2000.0, 1000.0)
    xs = (np.arange(7) - 3) * 6.0
    rng = np.random.default_rng(1)
    W = rng.uniform(0, 1, (7, 7))
    m = J.imaging_model(lens, pitch_um=6.0, size=7, engine="rs", n_coefficients=2, phase_bound_rad=8.0,
                        lattice=False)
    a0 = np.array([2.0, -1.0])
    g = np.asarray(jax.grad(lambda a: jnp.sum(W * m.band_psf(a)))(jnp.asarray(a0)))
    fd = _fd(lambda a: float(np.sum(W * _brute_psf(lens, a, [10.0], [1.0], 0.0, xs, xs, 6.0))), a0, 1e-3)
    assert np.abs(g - fd).max() < 1e-3 * np.abs(fd).max()


# ----------------------------------------------------------------------------------------------
# the objective
# ----------------------------------------------------------------------------------------------
def test_mtf_area_of_a_point_is_one_and_a_blur_lowers_it():
    p = np.zeros((15, 15))
    p[7, 7] = 1.0
    assert float(J.mtf_area(p, 17.0, 1 / 34.0)) == pytest.approx(1.0, abs=1e-12)
    blur = np.ones((3, 3)) / 9.0
    q = np.zeros((15, 15))
    q[6:9, 6:9] = blur
    assert float(J.mtf_area(q, 17.0, 1 / 34.0)) < 0.7


def test_mtf_area_is_the_mean_of_production_mtf_2d_over_the_disk():
    lens = LensDesign("s", 4000.0, 2000.0)
    S = sensor_psf(lens, pixel_pitch_um=17.0, wavelengths_um=[9.0, 10.0, 11.0], size_px=15, error=1e-3)
    fx, fy, M = mtf_2d(S)  # cycles/mm, normalised at zero frequency
    f_max = 0.999 / 34.0  # cycles/um (off the frequency grid: no sample on the rim)
    inside = (fx[None, :] ** 2 + fy[:, None] ** 2) <= (f_max * 1000) ** 2
    assert float(J.mtf_area(S.intensity, 17.0, f_max)) == pytest.approx(M[inside].mean(), rel=1e-9)


def test_defocus_lowers_the_in_focus_mtf_area():
    lens = LensDesign("s", 4000.0, 2000.0)
    m = J.imaging_model(lens, pitch_um=8.5, size=15, sensor=True, n_coefficients=1, phase_bound_rad=20.0)
    assert float(m.mtf_area(np.array([15.0]))) < float(m.mtf_area(np.array([0.0])))


# ----------------------------------------------------------------------------------------------
# the paper's lenses (slow)
# ----------------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("channel", ["foveal", "perifoveal"])
def test_paper_lenses_on_axis_sensor_psf_over_the_band(channel):
    system = _paper_system()
    lens = system.foveal if channel == "foveal" else system.perifoveal
    wl = np.linspace(8.0, 14.0, 13)
    rng = np.random.default_rng(0)
    w = rng.uniform(0.5, 1.0, wl.size)
    ps = _posts(rng, lens.polarization)
    S = sensor_psf(lens, pixel_pitch_um=34.0, wavelengths_um=wl, weights=w, post_set=ps, size_px=41, error=1e-4)
    m = J.imaging_model(lens, wavelengths_um=wl, weights=w, pitch_um=34.0, size=41, sensor=True)
    got = np.asarray(m.band_psf(np.zeros(0), J.level_table(lens, ps, None, wl)))
    assert _rel(got, S.intensity) < TOL


def _paper_system():
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    return load_system(root / "designs" / "system.toml")



def test_debye_engine_refuses_a_phase_whose_rays_cross():
    """A strong negative-curvature term folds the ray map (a caustic inside the aperture): the stationary phase of
    the debye engine does not hold, the rs engine does."""
    lens = LensDesign("s", 2000.0, 1000.0)
    assert J.ray_map_is_monotonic(lens, [6.0, -4.0])
    fold = [60.0]  # phi'/rho = -k0 / L + 2 a_1 / R^2 > 0 near the centre
    assert not J.ray_map_is_monotonic(lens, fold)
    m = J.imaging_model(lens, pitch_um=4.0, size=5, n_coefficients=1, phase_bound_rad=100.0)
    with pytest.raises(InputError, match="rays do not cross"):
        m.band_psf(np.array(fold))


def test_phase_sign_plus_one_is_the_conjugate_convention():
    """phase_sign = +1 flips the hyperbola and the time convention together: the same PSF with -a_j."""
    lens = LensDesign("s", 2000.0, 1000.0)
    plus = replace(lens, phase_sign=1)
    a = np.array([3.0, -2.0])
    m = J.imaging_model(lens, pitch_um=4.0, size=9, n_coefficients=2, phase_bound_rad=5.0, lattice=False)
    mp = J.imaging_model(plus, pitch_um=4.0, size=9, n_coefficients=2, phase_bound_rad=5.0, lattice=False)
    np.testing.assert_allclose(np.asarray(mp.band_psf(-a)), np.asarray(m.band_psf(a)), rtol=1e-12)
    assert _rel(mp.band_psf(a), m.band_psf(a)) > 0.01


@pytest.mark.slow
@pytest.mark.parametrize("channel", ["foveal", "perifoveal"])
def test_paper_lenses_at_the_channel_corner_match_production_rs(channel):
    """The paper's lenses at their channel's sensor corner (2.66 deg foveal, 15.58 deg perifoveal; measured 3.5e-7
    and 9.3e-6 of the peak), a window of 21 samples around the chief ray."""
    system = _paper_system()
    lens, fld, pitch, wl = ((system.foveal, 2.66, 8.0, np.array([9.9, 10.0, 10.1])) if channel == "foveal" else
                            (system.perifoveal, 15.58, 4.0, np.array([10.0])))
    c = (lens.f_um * math.tan(math.radians(fld)), 0.0)
    P = psf(lens, wavelengths_um=wl, engine="rs", field_deg=fld, quantize=True, lattice=True, window_um=21 * pitch,
            pitch_um=pitch, center_um=c, allow_truncation=True, error=1e-4)
    m = J.imaging_model(lens, wavelengths_um=wl, field_deg=fld, pitch_um=pitch, size=P.shape[0], center_um=c)
    assert _rel(m.band_psf(np.zeros(0), J.level_table(lens, None, None, wl)), P.intensity) < TOL * 0.1


@pytest.mark.filterwarnings("ignore::metafovea.errors.NotConvergedWarning")
def test_channel_model_is_the_production_kernel_times_the_throughput():
    """One wavelength: the channel's PSF is sensor_psf of its lens at its distance times the train's throughput over
    T_ms (the convention of imaging.kernels: kernels divided by T_ms, gains times the throughput)."""
    rng = np.random.default_rng(11)
    fov = LensDesign("foveal", 4000.0, 2000.0, polarization="x")
    per = LensDesign("perifoveal", 1000.0, 1000.0, polarization="y")
    system = SystemDesign(foveal=fov, perifoveal=per, lens_to_sensor_um=(4000.0, 1000.0))
    posts = {"x": _posts(rng, "x"), "y": _posts(rng, "y")}
    pitch = system.sensor.pixel_pitch_um / system.relay_magnification
    for channel, lens, z in (("foveal", fov, 4000.0), ("perifoveal", per, 1000.0)):
        m = J.channel_model(system, channel, posts, wavelengths_um=[10.5], size_px=9)
        tf, tp = J.channel_level_tables(system, channel, posts, [10.5])
        S = sensor_psf(lens, pixel_pitch_um=pitch, wavelengths_um=[10.5], post_set=posts[lens.polarization],
                       size_px=9, z_um=z, error=1e-5)
        tr = channel_train(system, channel, posts, [10.5], [1.0], posts="test")
        want = S.intensity * tr.throughput / tr.metasurface_transmission
        assert _rel(m.band_psf(np.zeros(0), tf, tp), want) < TOL * 1e-2
        assert 0 < float(m.mtf_area(np.zeros(0), tf, tp, per_wavelength=True)) <= 1.0


def test_the_lens_coefficients_are_the_default():
    """Without coefficients the model is the plain hyperbola (n = 0); a design carrying ``phase_poly_rad`` (issue 33's
    LensDesign field, when present) is the default of the functions."""
    lens = LensDesign("s", 2000.0, 1000.0)
    m = J.imaging_model(lens, pitch_um=4.0, size=9, lattice=False)
    assert m.n_coefficients == 0
    np.testing.assert_array_equal(np.asarray(m.band_psf()), np.asarray(m.band_psf(np.zeros(0))))

    class WithPhase:  # stands for a LensDesign with phase_poly_rad, whatever else it carries
        def __init__(self, base, coeffs):
            self._base, self.phase_poly_rad = base, coeffs

        def __getattr__(self, name):
            return getattr(self._base, name)

    lp = WithPhase(lens, (2.0, -1.0))
    assert J.lens_coefficients(lp).tolist() == [2.0, -1.0]
    mp = J.imaging_model(lp, pitch_um=4.0, size=9, lattice=False)
    assert mp.n_coefficients == 2 and mp.phase_bound_rad.tolist() == [4.0, 2.0]
    np.testing.assert_array_equal(np.asarray(mp.band_psf()), np.asarray(mp.band_psf(np.array([2.0, -1.0]))))

"""The general RCWA solver (metafovea.rcwa.solve) against physics: uniform slabs (Airy, Fresnel), energy
conservation, reciprocity, mirror symmetry, hard limits, bad input, and an independent solver (grcwa)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from metafovea.errors import InputError, NotConvergedWarning
from metafovea.materials import check_index
from metafovea.rcwa import Layer, Rectangle, Stack, solve

NSI = 3.42


def airy(n1, n2, n3, d, wl):
    """Field r, t (E ratios, reference planes at the layer faces) for a slab n2 between n1 and n3."""
    r12, r23 = (n1 - n2) / (n1 + n2), (n2 - n3) / (n2 + n3)
    t12, t23 = 2 * n1 / (n1 + n2), 2 * n2 / (n2 + n3)
    ph = np.exp(1j * 2 * np.pi / wl * n2 * d)
    den = 1 + r12 * r23 * ph ** 2
    return (r12 + r23 * ph ** 2) / den, t12 * t23 * ph / den


# --- uniform slabs: analytic ----------------------------------------------------------------------

def test_uniform_slab_matches_airy_and_references():
    st = Stack(4.0, 4.0, [Layer(10.0, NSI)], NSI, 1.0)
    res = solve(st, 10.0, harmonics=2)
    r_a, t_a = airy(NSI, NSI, 1.0, 10.0, 10.0)
    T_a = abs(t_a) ** 2 / NSI
    for p in (0, 1):
        assert abs(res.total_T()[p] - T_a) < 1e-12
        assert abs(res.total_R()[p] - abs(r_a) ** 2) < 1e-12
        assert abs(res.t00_field()[p, p] - t_a) < 1e-12
    assert abs(res.total_R()[0] - 0.299769) < 1e-6 and abs(res.total_T()[0] - 0.700231) < 1e-6
    # REFERENCES.md: field t from the substrate side and from air (exp(-i omega t))
    assert abs(res.t00_field("substrate")[0, 0] - (-1.356095 + 0.745519j)) < 2e-6
    assert abs(res.t00_field("superstrate")[0, 0] - (-0.396519 + 0.217988j)) < 2e-6
    # power normalisation: |t|^2 is the efficiency
    assert abs(abs(res.t00()[0, 0]) ** 2 - T_a) < 1e-12


def test_free_standing_slab_and_empty_stack():
    st = Stack(4.0, 4.0, [Layer(10.0, NSI)], 1.0, 1.0)
    res = solve(st, 10.0, harmonics=1)
    assert abs(res.t00_field()[0, 0] - (-0.559025 + 0.570460j)) < 2e-6
    assert abs(res.total_T()[0] - 0.637933) < 2e-6
    # fill factor 0: a bare Si/air interface
    bare = solve(Stack(4.0, 4.0, [], NSI, 1.0), 10.0, harmonics=1)
    assert abs(bare.t00_field("substrate")[0, 0] - 1.547511) < 1e-6
    assert abs(bare.t00_field("superstrate")[0, 0] - 0.452489) < 1e-6


def test_uniform_slab_oblique_matches_fresnel_s_and_p():
    n1, n2, n3, d, wl, th = NSI, 2.0, 1.0, 1.3, 10.0, np.radians(10.0)
    st = Stack(4.0, 4.0, [Layer(d, n2)], n1, n3)
    res = solve(st, wl, harmonics=1, theta_deg=10.0, phi_deg=30.0)
    kx = n1 * np.sin(th)
    c = [np.sqrt(n ** 2 - kx ** 2 + 0j) for n in (n1, n2, n3)]
    # s: use kz as the "index"; p: use n^2/kz
    for pol, eff in (("s", lambda i: c[i]), ("p", lambda i: (n1, n2, n3)[i] ** 2 / c[i])):
        e1, e2, e3 = eff(0), eff(1), eff(2)
        r12, r23 = (e1 - e2) / (e1 + e2), (e2 - e3) / (e2 + e3)
        ph = np.exp(1j * 2 * np.pi / wl * c[1] * d)
        r = (r12 + r23 * ph ** 2) / (1 + r12 * r23 * ph ** 2)
        ip = 0 if pol == "p" else 1
        assert abs(res.total_R()[ip] - abs(r) ** 2) < 1e-12


# --- conservation, reciprocity, symmetry ----------------------------------------------------------

@pytest.mark.parametrize("fact", ["li", "laurent"])
def test_energy_conservation_lossless(fact, two_layer_asymmetric):
    st = two_layer_asymmetric
    res = solve(st, np.array([6.0, 10.0]), harmonics=3, theta_deg=12.0, phi_deg=25.0, factorization=fact)
    for side in ("substrate", "superstrate"):
        tot = res.total_T(side) + res.total_R(side)
        assert np.max(np.abs(tot - 1)) < 1e-10
    # higher orders do carry power at 6 um (several propagating orders)
    assert res.T["substrate"][0].max() < res.total_T()[0].max()


def test_absorbing_layer_loses_power():
    st = Stack(4.0, 4.0, [Layer(2.0, 1.0, [Rectangle(2.0, 2.0, 3.42 + 0.05j)])], NSI, 1.0)
    res = solve(st, 10.0, harmonics=3)
    tot = res.total_T() + res.total_R()
    assert np.all(tot < 1 - 1e-4) and np.all(tot > 0.5)


def test_reciprocity_normal_incidence_jones_transpose(two_layer_asymmetric):
    st = two_layer_asymmetric
    res = solve(st, 10.0, harmonics=3)
    J_up, J_down = res.t00("substrate"), res.t00("superstrate")
    assert abs(J_up[0, 1]) > 1e-3  # the structure does couple x and y
    np.testing.assert_allclose(J_up, J_down.T, atol=1e-10)


def test_reciprocity_oblique_efficiencies(two_layer_asymmetric):
    st = two_layer_asymmetric
    a = solve(st, 9.0, harmonics=3, theta_deg=15.0, phi_deg=40.0, incidence="substrate")
    # reversed path: from the superstrate with the opposite in-plane wave vector
    kpar = NSI * np.sin(np.radians(15.0))
    th_b = np.degrees(np.arcsin(kpar / 1.0))
    b = solve(st, 9.0, harmonics=3, theta_deg=th_b, phi_deg=40.0 + 180.0, incidence="superstrate")
    Ta = np.abs(a.t00("substrate")) ** 2
    Tb = np.abs(b.t00("superstrate")) ** 2
    np.testing.assert_allclose(Ta, Tb.T, atol=1e-10)


def test_symmetric_basis_equals_full_basis(post_stack):
    st = post_stack(2.4, 1.3)
    for fact in ("li", "laurent"):
        a = solve(st, 10.0, harmonics=4, factorization=fact)
        b = solve(st, 10.0, harmonics=4, factorization=fact, symmetry="none")
        assert a.info["symmetric"] and not b.info["symmetric"]
        np.testing.assert_allclose(a.t["substrate"], b.t["substrate"], atol=1e-10)
        np.testing.assert_allclose(a.r["superstrate"], b.r["superstrate"], atol=1e-10)


def test_no_cross_polarisation_for_centred_rectangles(post_stack):
    res = solve(post_stack(2.6, 1.1), 10.0, harmonics=4, symmetry="none")
    J = res.t00()
    assert abs(J[0, 1]) < 1e-12 and abs(J[1, 0]) < 1e-12
    assert abs(J[0, 0]) > 0.5
    # an off-centre post is the same post (translation): still no cross-polarisation, same |t|
    res2 = solve(post_stack(2.6, 1.1, cx=0.7, cy=-0.4), 10.0, harmonics=4)
    assert abs(res2.t00()[0, 1]) < 1e-12
    assert abs(abs(res2.t00()[0, 0]) - abs(J[0, 0])) < 1e-10


# --- limits and hard cases ------------------------------------------------------------------------

@pytest.mark.parametrize("contrast", [1e-12, 1e-8, 1e-5])
@pytest.mark.parametrize("n_b", [NSI, 1.0])
def test_nearly_uniform_patterned_layer(contrast, n_b):
    """A patterned layer with (almost) no contrast, matched to a half-space: degenerate modes."""
    st = Stack(4.0, 4.0, [Layer(10.0, n_b, [Rectangle(2.0, 2.0, n_b + contrast)])], NSI, 1.0)
    ref = solve(Stack(4.0, 4.0, [Layer(10.0, n_b)], NSI, 1.0), 10.0, harmonics=3)
    with warnings.catch_warnings():
        warnings.simplefilter("error", NotConvergedWarning)
        for sym in ("auto", "none"):
            for th in (0.0, 4.0):
                res = solve(st, 10.0, harmonics=3, symmetry=sym, theta_deg=th)
                tot = res.total_R() + res.total_T()
                assert np.max(np.abs(tot - 1)) < 1e-9
                assert np.max(res.total_R()) < 0.5
                if th == 0.0:
                    assert np.max(np.abs(res.total_R() - ref.total_R())) < 1e-4


def test_rayleigh_anomaly_wavelength_is_stable(post_stack):
    # (1,1) order grazing in Si: lambda = n_Si p / sqrt(2) = 9.673 um
    wl = NSI * 4.0 / np.sqrt(2.0)
    res = solve(post_stack(2.0, 2.0), np.array([wl, wl * (1 + 1e-9)]), harmonics=3)
    assert np.all(np.isfinite(res.total_T()))
    assert abs(res.total_T()[0, 0] - res.total_T()[1, 0]) < 1e-6
    assert np.max(np.abs(res.total_T() + res.total_R() - 1)) < 1e-6


def test_diffraction_orders_paper_platform(post_stack):
    """Only (0,0) propagates in air; first orders propagate in Si (~47 deg), (1,1) does not."""
    res = solve(post_stack(2.0, 2.0), 10.0, harmonics=2)
    Rsub = res.R["substrate"][:, 0]
    Tair = res.T["substrate"][:, 0]
    ords = [tuple(o) for o in res.orders]
    assert np.count_nonzero(Tair > 0) == 1 and Tair[res.zero] > 0.5
    assert Rsub[ords.index((1, 0))] > 0 and Rsub[ords.index((0, 1))] > 0  # x-pol: both couple
    assert Rsub[ords.index((1, 1))] == 0
    kz10 = res.kz_sub[ords.index((1, 0))]
    assert abs(np.degrees(np.arccos(kz10.real / NSI)) - 47.0) < 0.5
    # from air, the first orders are transmitted into the wafer instead
    assert res.T["superstrate"][ords.index((1, 0)), 0] > 0


# --- bad input ------------------------------------------------------------------------------------

def test_bad_geometry_raises_input_error():
    with pytest.raises(InputError):
        Rectangle(0.0, 1.0, NSI)
    with pytest.raises(InputError):
        Stack(4.0, 4.0, [Layer(1.0, 1.0, [Rectangle(4.0, 1.0, NSI)])], NSI, 1.0)
    with pytest.raises(InputError):
        Layer(-1.0, 1.0)
    with pytest.raises(InputError):
        Stack(4.0, 4.0, [], NSI + 0.1j, 1.0)
    with pytest.raises(InputError):
        solve(Stack(4.0, 4.0, [], NSI, 1.0), 10.0, harmonics=0)
    with pytest.raises(InputError):
        solve(Stack(4.0, 4.0, [], NSI, 1.0), -1.0)
    with pytest.raises(InputError):
        check_index("n", 0.0)


# --- independent solver ---------------------------------------------------------------------------

def test_cross_check_grcwa_laurent_identical_harmonics(post_stack):
    """grcwa (plain Laurent rule, FFT of a grid) at the same rectangular harmonic set.

    The grid is chosen so that the sampled rectangle has an odd number of samples centred on the
    origin: its DFT coefficients equal the analytic ones to ~(pi k / N)^2 / 6.
    """
    grcwa = pytest.importorskip("grcwa")
    p, Ng, M = 4.0, 500, 3
    w = (2.008, 1.208)  # 251 and 151 samples of 0.008 um
    x = np.arange(Ng) * p / Ng
    x = np.where(x >= p / 2, x - p, x)
    X, Y = np.meshgrid(x, x, indexing="ij")
    grid = np.where((np.abs(X) <= w[0] / 2 + 1e-9) & (np.abs(Y) <= w[1] / 2 + 1e-9), NSI ** 2, 1.0)
    st = post_stack(*w)
    for theta, pol in ((0.0, "p"), (0.0, "s"), (0.25, "p")):
        obj = grcwa.obj((2 * M + 1) ** 2, [p, 0], [0, p], 1 / 10.0, theta, 0.3, verbose=0)
        obj.Add_LayerUniform(1.0, NSI ** 2)
        obj.Add_LayerGrid(10.0, Ng, Ng)
        obj.Add_LayerUniform(1.0, 1.0)
        obj.Init_Setup(Gmethod=1)
        obj.GridLayer_geteps(grid.ravel())
        obj.MakeExcitationPlanewave(*((1, 0, 0, 0) if pol == "p" else (0, 0, 1, 0)), order=0)
        R, T = obj.RT_Solve(normalize=1, byorder=1)
        ours = solve(st, 10.0, harmonics=M, factorization="laurent", theta_deg=np.degrees(theta),
                     phi_deg=np.degrees(0.3))
        ip = 0 if pol == "p" else 1
        assert abs(ours.total_T()[ip] - np.sum(T)) < 5e-5
        assert abs(ours.T["substrate"][ours.zero, ip] - T[0]) < 5e-5
        assert abs(ours.total_R()[ip] - np.sum(R)) < 5e-5


def _grcwa_rt(layers, p, Ng, M, wl):
    """grcwa's zero-order and total efficiencies (p and s incidence from the substrate side at normal incidence)
    of a stack of grid layers ``[(thickness, eps map (Ng, Ng)), ...]`` on Si under air."""
    grcwa = pytest.importorskip("grcwa")
    out = {}
    for pol in ("p", "s"):
        obj = grcwa.obj((2 * M + 1) ** 2, [p, 0], [0, p], 1 / wl, 0.0, 0.0, verbose=0)
        obj.Add_LayerUniform(1.0, NSI ** 2)
        for d, _ in layers:
            obj.Add_LayerGrid(d, Ng, Ng)
        obj.Add_LayerUniform(1.0, 1.0)
        obj.Init_Setup(Gmethod=1)
        obj.GridLayer_geteps(np.concatenate([e.ravel() for _, e in layers]))
        obj.MakeExcitationPlanewave(*((1, 0, 0, 0) if pol == "p" else (0, 0, 1, 0)), order=0)
        R, T = obj.RT_Solve(normalize=1, byorder=1)
        out[pol] = (np.sum(R), np.sum(T), T[0])
    return out


def test_full_basis_where_the_mirror_symmetry_fails_matches_grcwa(monkeypatch):
    """Two stacked posts off the cell centre in different directions have no mirror plane: solve() must take the
    full basis (x and y couple) and then agrees with grcwa (Laurent rule, the same harmonic set, a grid on which
    the sampled rectangles' DFT equals the analytic coefficients to ~(pi k / N)^2 / 6). Planted case: the same
    stack declared mirror symmetric is solved in the parity basis and misses grcwa by far more than the
    tolerance, so this comparison would catch a wrong choice of path."""
    p, Ng, M, wl = 4.0, 500, 3, 9.0
    x = np.arange(Ng) * p / Ng
    x = np.where(x >= p / 2, x - p, x)
    X, Y = np.meshgrid(x, x, indexing="ij")
    # widths of odd pixel counts (0.008 um pixels) centred on pixels
    rects = [(2.008, 1.208, 0.4, -0.24, 1.5), (1.608, 2.408, -0.8, 0.48, 2.0)]
    layers, grids = [], []
    for wx, wy, cx, cy, d in rects:
        inside = (np.abs(X - cx) <= wx / 2 + 1e-9) & (np.abs(Y - cy) <= wy / 2 + 1e-9)
        grids.append((d, np.where(inside, NSI ** 2, 1.0)))
        layers.append(Layer(d, 1.0, [Rectangle(wx, wy, NSI, cx, cy)]))
    st = Stack(p, p, layers, NSI, 1.0)
    ref = _grcwa_rt(grids, p, Ng, M, wl)

    def mismatch(res):
        return max(max(abs(res.total_R()[i] - ref[pol][0]), abs(res.total_T()[i] - ref[pol][1]),
                       abs(res.T["substrate"][res.zero, i] - ref[pol][2])) for i, pol in enumerate(("p", "s")))

    res = solve(st, wl, harmonics=M, factorization="laurent")
    assert not st.mirror_symmetric and not res.info["symmetric"]
    assert np.max(np.abs(res.t00()[[0, 1], [1, 0]])) > 1e-3          # x and y couple: no parity split exists
    assert mismatch(res) < 5e-5
    monkeypatch.setattr(Stack, "mirror_symmetric", property(lambda self: True))
    planted = solve(st, wl, harmonics=M, factorization="laurent", check_energy=False)
    assert planted.info["symmetric"] and mismatch(planted) > 100 * 5e-5

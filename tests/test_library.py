"""Tests of the scatterer library (RCWA sweep, cache, resume), birefringent post selection and the library of a
platform (metafovea.library)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from metafovea.config import LensDesign, PlatformDesign
from metafovea.errors import InputError, NotConvergedWarning
from metafovea.io import atomic_save_npz
from metafovea.lens import summarize
from metafovea.library import (
    Library,
    LibraryOptions,
    PlatformSweep,
    PostSet,
    compute_library,
    platform_post_sets,
    postset_table,
    select_posts,
    usable_posts,
    width_grid,
)
from metafovea.rcwa.posts import post_response

W3 = [1.0, 2.0, 3.0]
M = 5


@pytest.fixture(scope="module")
def small_lib(tmp_path_factory):
    d = tmp_path_factory.mktemp("cache")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        lib = compute_library(W3, None, [10.0], harmonics=M, cache_dir=d, workers=1, progress=False)
    return lib, d


def test_library_values_match_direct_solves(small_lib):
    lib, _ = small_lib
    assert lib.t_x.shape == (1, 3, 3)
    r = post_response(2.0, 3.0, 10.0, harmonics=M)
    assert abs(lib.t_x[0, 1, 2] - r.t_x) < 1e-12
    assert abs(lib.t_y[0, 1, 2] - r.t_y) < 1e-12   # y from the swapped x solve
    assert abs(lib.T_x[0, 1, 2] - abs(r.t_x) ** 2) < 1e-12
    np.testing.assert_allclose(lib.t_y[0], lib.t_x[0].T)
    # energy: T + R + other - (reflected zero order counted in R) = 1
    assert np.all(lib.R_x + lib.T_x <= 1 + 1e-9) and np.all(lib.other_x >= -1e-12)
    assert np.all(np.isfinite(lib.err_x)) and np.all(lib.err_x > 0)


def test_cache_hit_and_key_depends_on_inputs(small_lib):
    lib, d = small_lib
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        again = compute_library(W3, None, [10.0], harmonics=M, cache_dir=d, workers=1, progress=False)
        assert again.meta.get("from_cache")
        np.testing.assert_array_equal(again.t_x, lib.t_x)
        other = compute_library(W3, None, [10.0], harmonics=M, height_um=9.0, cache_dir=d, workers=1,
                                progress=False)
    assert other.meta["key"] != lib.meta["key"]
    assert not np.allclose(other.t_x, lib.t_x)


def test_options_and_keyword_overrides_are_one_interface(small_lib):
    """``options=LibraryOptions(...)`` and keyword overrides name the same sweep (the same cache entry)."""
    lib, d = small_lib
    opts = LibraryOptions(harmonics=M, cache_dir=d, workers=1, progress=False, tol=None)
    assert compute_library(W3, None, [10.0], options=opts).meta["key"] == lib.meta["key"]
    a = compute_library(W3, None, [10.0], options=opts, height_um=9.0)
    b = compute_library(W3, None, [10.0], harmonics=M, height_um=9.0, cache_dir=d, workers=1, progress=False,
                        tol=None)
    assert a.meta["key"] == b.meta["key"] != lib.meta["key"] and b.meta.get("from_cache")
    with pytest.raises(TypeError):
        compute_library(W3, None, [10.0], options=opts, harmonic=5)
    plat = PlatformDesign(period_um=5.0, post_height_um=8.0, n_post=3.0)
    stack = LibraryOptions(harmonics=M).with_platform(plat)
    assert (stack.period_um, stack.height_um, stack.n_post, stack.harmonics) == (5.0, 8.0, 3.0, M)


def test_resume_uses_finished_rows(tmp_path):
    kw = dict(harmonics=M, cache_dir=tmp_path, workers=1, progress=False, tol=None)
    ref = compute_library([1.5, 2.5], None, [10.0], **kw)
    final = tmp_path / f"library-{ref.meta['key']}.npz"
    final.unlink()
    # a finished row left by an interrupted run (marked so that we can see it is reused)
    parts = tmp_path / f"library-{ref.meta['key']}.parts"
    row = {k: ref.arrays[k][0, 1, :] for k in ("t_x", "T_x", "R_x", "other_x", "err_x")}
    row["t_x"] = row["t_x"] * 0 + 0.123
    atomic_save_npz(parts / "row-0-1.npz", None, **row)
    lib = compute_library([1.5, 2.5], None, [10.0], **kw)
    assert lib.meta["rows_computed"] == 1
    assert np.all(lib.t_x[0, 1, :] == 0.123)
    np.testing.assert_allclose(lib.t_x[0, 0, :], ref.t_x[0, 0, :])
    assert not parts.exists()


def test_rectangular_grid_multi_wavelength_and_workers(tmp_path):
    lib = compute_library([1.2, 2.8], [2.0], [9.5, 10.5], harmonics=M, cache_dir=tmp_path, workers=2,
                          progress=False, tol=None)
    assert lib.t_x.shape == (2, 2, 1)
    r = post_response(2.8, 2.0, 10.5, harmonics=M)
    assert abs(lib.t_x[1, 1, 0] - r.t_x) < 1e-12 and abs(lib.t_y[1, 1, 0] - r.t_y) < 1e-12
    lib2 = Library.load(tmp_path / f"library-{lib.meta['key']}.npz")
    np.testing.assert_array_equal(lib2.t_y, lib.t_y)


def test_not_converged_warning(tmp_path):
    with pytest.warns(NotConvergedWarning):
        compute_library([3.5], None, [10.0], harmonics=5, tol=1e-6, cache_dir=tmp_path, workers=1,
                        progress=False)


@pytest.mark.parametrize("kw", [dict(wx_um=[0.0, 1.0]), dict(wx_um=[4.0]), dict(wavelengths_um=[-1.0]),
                                dict(harmonics=2), dict(period_um=0.0), dict(height_um=-1.0),
                                dict(n_post=0.5 - 0.2j), dict(factorization="x"), dict(incidence="left")])
def test_library_bad_input(kw, tmp_path):
    args = dict(wx_um=W3, wy_um=None, wavelengths_um=[10.0], cache_dir=tmp_path, workers=1, progress=False)
    args.update(kw)
    with pytest.raises(InputError):
        compute_library(args.pop("wx_um"), args.pop("wy_um"), args.pop("wavelengths_um"), **args)


def test_width_grid():
    w = width_grid(4.0, 0.1, 0.5)
    assert w.size == 31 and w[0] == 0.5 and w[-1] == 3.5
    with pytest.raises(InputError):
        width_grid(4.0, 0.0)
    with pytest.raises(InputError):
        width_grid(4.0, 0.1, 2.5)


@pytest.mark.parametrize("period,mf", [(4.0, 0.5), (4.0, 1.5), (3.0, 0.2), (6.0, 1.9), (2.5, 0.01)])
def test_width_grid_allowed_step_is_stated_and_exact(period, mf):
    """The error said 'grid_step_um <= 4' for p = 4 although 1.5 already failed, or 'fit posts between
    4 and 0 um'; the stated maximum is now the real one."""
    max_step = period / 3 if mf <= period / 3 else period - 2 * mf
    w = width_grid(period, max_step * 0.999, mf)
    assert len(w) >= 2 and w[0] >= mf and w[-1] <= period - mf + 1e-9
    with pytest.raises(InputError) as e:
        width_grid(period, max_step * 1.01, mf, name="--grid-step-um")
    assert e.value.parameter == "--grid-step-um" and f"{max_step:.6g}" in e.value.allowed


@pytest.mark.parametrize("damage", ["truncate", "garbage", "empty"])
def test_damaged_library_cache_is_recomputed(tmp_path, damage):
    """A damaged cached library (library-<key>.npz) made every later run fail instead of recomputing."""
    kw = dict(harmonics=5, cache_dir=tmp_path, workers=1, progress=False, tol=None)
    w = width_grid(4.0, 1.0, 0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a = compute_library(w, None, [10.0], **kw)
        (f,) = tmp_path.glob("library-*.npz")
        data = f.read_bytes()
        f.write_bytes({"truncate": data[: len(data) // 2], "garbage": b"\x00junk" * 50, "empty": b""}[damage])
        b = compute_library(w, None, [10.0], **kw)
        assert not b.meta.get("from_cache")
        np.testing.assert_allclose(b.t_x, a.t_x)
        c = compute_library(w, None, [10.0], **kw)  # the cache was rewritten
    assert c.meta.get("from_cache")


def synthetic_library(n=16):
    """t_x phase = 2 pi i / n along wx (unit |t|), t_y phase = 0.3 j along wy, |t_y| rises with wy."""
    wx = np.linspace(0.5, 3.5, n)
    wy = np.linspace(0.5, 3.5, n)
    ix, iy = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    t_x = np.exp(2j * np.pi * ix / n)
    t_y = np.sqrt(0.5 + 0.5 * iy / (n - 1)) * np.exp(0.3j * iy)
    arrays = {"t_x": t_x[None], "t_y": t_y[None], "err_x": np.zeros((1, n, n)), "err_y": np.zeros((1, n, n))}
    return Library(wx, wy, np.array([10.0]), arrays, {"period_um": 4.0, "height_um": 10.0})


def test_select_posts_synthetic_exact():
    lib = synthetic_library()
    ps = select_posts(lib, "x", 8)
    assert ps.polarization == "x" and ps.levels == 8 and ps.source == "rcwa"
    assert ps.info["max_abs_phase_error_rad"] < 1e-9
    assert ps.info["pass_phase_spread_rad"] < 1e-9            # one wy for all levels
    assert np.all(ps.widths_um[:, 1] == 3.5)                   # the highest-transmission pass column
    # wx steps by 2 grid cells per level (any starting cell: the offset is free)
    idx = np.round((ps.widths_um[:, 0] - 0.5) / 0.2).astype(int)
    assert np.all(np.diff(idx) % 16 == 2)
    # stored t has the offset removed: arg t_focus = 2 pi k / N
    np.testing.assert_allclose(np.angle(ps.t_focus * np.exp(-2j * np.pi * np.arange(8) / 8)), 0, atol=1e-9)
    assert abs(ps.info["expected_focusing_efficiency"] - np.sinc(1 / 8) ** 2) < 1e-9
    assert abs(ps.info["pass_coherent_transmission"] - 1.0) < 1e-9


def test_select_posts_both_lenses_on_rcwa_library(small_lib, tmp_path):
    lib, _ = small_lib
    px = select_posts(lib, "x", 2, max_error=None)
    py = select_posts(lib, "y", 2, max_error=None)
    # the y lens is the mirror image of the x lens on a square grid
    np.testing.assert_allclose(py.widths_um, px.widths_um[:, ::-1])
    assert abs(py.info["expected_focusing_efficiency"] - px.info["expected_focusing_efficiency"]) < 1e-12
    rows = postset_table(px)
    assert len(rows) == 2 and rows[1]["target_phase_rad"] == pytest.approx(np.pi)
    p = px.save(tmp_path / "ps.npz")
    back = PostSet.load(p)
    np.testing.assert_array_equal(back.widths_um, px.widths_um)
    assert back.info["phase_error_rad"] == px.info["phase_error_rad"]
    with pytest.raises(InputError):
        select_posts(lib, "x", 16, max_error=None)  # more levels than posts
    with pytest.raises(InputError):
        select_posts(lib, "z", 2)


@pytest.mark.parametrize("content", ["toml", "empty", "truncated", "other_npz"])
def test_postset_load_of_wrong_file_is_input_error(tmp_path, content):
    """--post-set design.toml was a numpy 'pickled data' ValueError traceback."""
    good = tmp_path / "good.npz"
    PostSet.ideal(4).save(good)
    bad = tmp_path / "bad.npz"
    if content == "toml":
        bad.write_text('name = "x"\nf_mm = 1.0\n')
    elif content == "empty":
        bad.write_bytes(b"")
    elif content == "truncated":
        bad.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    else:
        np.savez(bad, widths_um=np.ones((4, 2)))
    for cls in (PostSet, Library):
        with pytest.raises(InputError) as e:
            cls.load(bad)
        assert e.value.parameter == "path"
    assert PostSet.load(good).levels == 4


# --- the library of a platform -----------------------------------------------------------------------

def test_platform_post_sets_coarse(tmp_path):
    # a coarse library (7 x 7 widths, 121 plane waves) exercises the design-side path quickly
    sets, lib = platform_post_sets(PlatformDesign(), 4, grid_step_um=0.5, harmonics=5, cache_dir=tmp_path, workers=1)
    assert set(sets) == {"x", "y"} and lib.wx_um.size == 7
    s = summarize(LensDesign.perifoveal().with_(levels=4), post_set=sets["y"], samples=5000, emit_warnings=False)
    eff = s.post_set["expected_focusing_efficiency"]
    assert 0.2 < eff <= 1.0
    assert s.post_set["expected_lens_efficiency"] == pytest.approx(eff * s.lattice_sampling_efficiency)
    # second call loads from the cache: identical post sets
    again, _ = platform_post_sets(PlatformDesign(), 4, grid_step_um=0.5, harmonics=5, cache_dir=tmp_path, workers=1)
    assert again["y"].widths_um.tolist() == sets["y"].widths_um.tolist()


def test_platform_sweep_checks_before_any_work():
    """A platform whose min feature leaves no post or gap, or a grid step that leaves fewer than 2 widths, is an
    error on construction (the CLI checks before it creates --out), naming the platform file."""
    with pytest.raises(InputError) as e:
        PlatformSweep(PlatformDesign(period_um=3.0, min_feature_um=1.6), source="plat.toml")
    assert e.value.parameter == "min_feature_um" and e.value.source == "plat.toml" and "1.5" in e.value.allowed
    with pytest.raises(InputError) as e:
        PlatformSweep(grid_step_um=1.5)
    assert e.value.parameter == "grid_step_um"
    sweep = PlatformSweep(grid_step_um=0.5, wavelengths_um=(9.0, 11.0))
    assert sweep.widths_um.size == 7 and sweep.design_wavelength_um == 9.0   # 10 um not swept: the first
    assert PlatformSweep(wavelengths_um=(9.0, 10.0)).design_wavelength_um == 10.0


def test_too_few_converged_posts_is_an_error_on_levels(small_lib):
    """select_posts said 'library = 4 is invalid'; a platform sweep names the levels and what to change."""
    lib, _ = small_lib
    n_ok = int(np.count_nonzero(usable_posts(lib, 10.0)))
    assert n_ok == int(np.count_nonzero(np.fmax(lib.err_x[0], lib.err_y[0]) <= 0.05)) < 9
    with pytest.raises(InputError) as e:
        PlatformSweep(levels=n_ok + 1).select(lib)
    assert e.value.parameter == "levels" and e.value.value == n_ok + 1
    assert f"at most the {n_ok} of 3 x 3 posts" in e.value.allowed and "--harmonics" in e.value.allowed


def test_oblique_response_against_direct_solves_at_unseen_angles(tmp_path):
    """The posts off axis: the interpolated ratio t(theta) / t(0) and its error estimate against direct RCWA solves
    at angles and azimuths the response was not computed at, with more Fourier orders (the converged side)."""
    import math

    from metafovea.library import oblique_response
    from metafovea.rcwa.geometry import Layer, Rectangle, Stack
    from metafovea.rcwa.solve import solve

    widths = np.array([[1.3, 2.9], [2.7, 1.1]])  # two birefringent posts of the paper's range
    ps = PostSet("x", 4.0, 10.0, 10.0, widths, np.ones(2), np.ones(2), source="rcwa")
    ob = oblique_response(ps, cache_dir=tmp_path)
    assert np.allclose(ob.factor("x", 0.0, 0.3), 1.0) and np.allclose(ob.factor("y", 0.0, 1.1), 1.0)
    assert 0 < ob.error < 0.1
    for theta, az in ((4.3, 0.0), (9.7, 0.5 * math.pi), (14.2, 0.0), (15.6, 0.5 * math.pi)):
        for k, (wx, wy) in enumerate(widths):
            st = Stack(4.0, 4.0, (Layer(10.0, 1.0, (Rectangle(wx, wy, 3.42),)),), 3.42, 1.0)
            th_si = math.degrees(math.asin(math.sin(math.radians(theta)) / 3.42))
            j = solve(st, 10.0, harmonics=7, theta_deg=th_si, phi_deg=math.degrees(az), incidence="substrate",
                      check_energy=False).t00("substrate")
            j0 = solve(st, 10.0, harmonics=7, check_energy=False).t00("substrate")
            tx, ty = (j[0, 0], j[1, 1]) if az == 0.0 else (j[1, 1], j[0, 0])
            assert abs(ob.factor("x", theta, az)[k] - tx / j0[0, 0]) <= ob.error
            assert abs(ob.factor("y", theta, az)[k] - ty / j0[1, 1]) <= ob.error
    # cached: the same numbers from the file
    again = oblique_response(ps, cache_dir=tmp_path)
    assert again.error == ob.error and np.array_equal(again.ratio["x"], ob.ratio["x"])


def test_selection_keeps_to_the_platform_fabrication_rules():
    """A stricter etch (aspect ratio at most 12) excludes the thin posts: none is chosen, and the count is reported."""
    from dataclasses import replace as dc_replace

    from metafovea.config import PlatformDesign
    from metafovea.library import platform_post_sets

    strict = dc_replace(PlatformDesign(), max_aspect_ratio=12.0)
    sets, _ = platform_post_sets(strict, 8, grid_step_um=0.5, harmonics=5)
    for ps in sets.values():
        assert ps.widths_um.min() >= 10.0 / 12.0 - 1e-9
        assert strict.fabrication_violations(ps.widths_um) == []
        assert ps.info["fabrication_rules"]["posts_excluded"] > 0


def test_edge_bias_table_against_direct_solves():
    """The +-delta table of a post set: at zero bias it is the set's own numbers; at a bias off the library grid
    (interpolated) the biased posts' expected efficiency and phase errors agree with RCWA solved directly at the
    biased widths."""
    from metafovea.library import bias_table, platform_post_sets
    from metafovea.rcwa.posts import post_response

    ps, lib = platform_post_sets()
    x = ps["x"]
    nominal = bias_table(lib, x.widths_um, "x", 0.05)["per_bias"]["0"]
    assert nominal["rms_phase_error_rad"] == pytest.approx(x.info["rms_phase_error_rad"], abs=1e-9)
    assert nominal["expected_focusing_efficiency"] == pytest.approx(x.info["expected_focusing_efficiency"], rel=1e-9)
    delta = 0.03  # widths +-60 nm: between the library's 0.1 um grid points
    tab = bias_table(lib, x.widths_um, "x", delta)
    N = x.levels
    targets = 2 * np.pi * np.arange(N) / N
    for name, sgn in (("-", -1), ("+", 1)):
        w = x.widths_um + sgn * 2 * delta
        r = post_response(w[:, 0], w[:, 1], 10.0, harmonics=int(lib.meta["harmonics"]), polarizations=("x",))
        eff = abs(np.mean(r.t_x * np.exp(-1j * targets))) ** 2 * np.sinc(1 / N) ** 2
        got = tab["per_bias"][name]
        assert got["expected_focusing_efficiency"] == pytest.approx(eff, abs=0.02)
        shift = np.angle(np.sum(np.exp(1j * (np.angle(r.t_x) - targets))))
        err = np.angle(np.exp(1j * (np.angle(r.t_x) - shift - targets)))
        assert got["rms_phase_error_rad"] == pytest.approx(float(np.sqrt(np.mean(err ** 2))), abs=0.05)


# ------------------------------------------------------------------------------------------------
# Tolerant post selection: the joint search over the -delta / 0 / +delta edge-bias cases
# ------------------------------------------------------------------------------------------------

def _grid_library(t_x, t_y, step=0.1):
    """A hand-made library on widths 0.5, 0.5 + step, ... (both axes), posts 2 um tall (no aspect-ratio limit)."""
    n = t_x.shape[0]
    w = np.round(0.5 + step * np.arange(n), 10)
    arrays = {"t_x": t_x[None], "t_y": t_y[None], "err_x": np.zeros((1, n, n)), "err_y": np.zeros((1, n, n))}
    return Library(w, w, np.array([10.0]), arrays, {"period_um": 4.0, "height_um": 2.0})


def _rough_library(seed, n):
    """Random phases about a ramp and random transmissions 0.6..1: a rugged cost with many local minima."""
    rng = np.random.default_rng(seed)
    ix, iy = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")

    def t():
        ph = 2 * np.pi * (0.9 * ix + 0.3 * iy) / n + rng.normal(0, 0.6, (n, n))
        return np.sqrt(rng.uniform(0.6, 1.0, (n, n))) * np.exp(1j * ph)
    return _grid_library(t(), t())


def _exhaustive_joint_costs(lib, N, w, pw=1.0, tw=0.5, n_grid=720):
    """The joint cost of every combination of N interior posts (the edge bias +-0.05 um per side moves a post to its
    diagonal neighbours (ix +- 1, iy +- 1) on this 0.1 um grid), each case's offsets the best of ``n_grid`` values:
    (combinations (M, N) of interior (ix, iy) pairs, costs (M,))."""
    import itertools

    n = lib.wx_um.size
    cand = np.array([(a, b) for a in range(1, n - 1) for b in range(1, n - 1)])
    combos = np.array(list(itertools.product(range(len(cand)), repeat=N)))
    wrap = lambda a: np.mod(a + np.pi, 2 * np.pi) - np.pi  # noqa: E731
    targets = 2 * np.pi * np.arange(N) / N
    grid = 2 * np.pi * np.arange(n_grid) / n_grid
    total = np.zeros(len(combos))
    for s, ws in ((-1, w), (0, 1.0), (1, w)):
        tf = lib.t_x[0][cand[:, 0] + s, cand[:, 1] + s][combos]
        tp = lib.t_y[0][cand[:, 0] + s, cand[:, 1] + s][combos]
        f = sum(wrap(np.angle(tf[:, k, None]) - targets[k] - grid) ** 2 for k in range(N))
        p = sum(wrap(np.angle(tp[:, k, None]) - grid) ** 2 for k in range(N))
        loss = tw * ((1 - abs(tf) ** 2) + (1 - abs(tp) ** 2)).sum(1)
        total += ws * (f.min(1) + pw * p.min(1) + loss)
    return cand[combos], total


@pytest.mark.parametrize("N, n, seed", [(3, 6, 0), (3, 6, 1), (3, 6, 2), (2, 8, 3), (2, 8, 4)])
def test_tolerant_selection_finds_the_exhaustive_optimum(N, n, seed):
    """The joint search's cost is the exhaustive optimum over every combination of posts (each case's offsets on a
    fine grid, so that optimum is at most ``eps`` above the exact one) on rugged random libraries, where a coordinate
    descent from the nominal grid search's starts alone misses it (in 4 of these 5); and the cost it reports is the
    true cost of the posts it chose."""
    lib = _rough_library(seed, n)
    for w in (0.5, 2.0):
        combos, costs = _exhaustive_joint_costs(lib, N, w)
        eps = (1 + 2 * w) * 2 * N * (np.pi / 720) ** 2  # offsets at most half a grid step from the best
        ps = select_posts(lib, "x", N, platform=PlatformDesign(), bias_weight=w)
        tol = ps.info["tolerance"]
        assert costs.min() - eps <= tol["joint_cost"] <= costs.min() + 1e-9
        idx = np.round((ps.widths_um - 0.5) / 0.1).astype(int)
        mine = costs[np.flatnonzero(np.all(combos == idx[None], axis=(1, 2)))[0]]
        assert mine - eps <= tol["joint_cost"] <= mine + 1e-9
        assert tol["joint_cost"] <= tol["nominal_choice_joint_cost"] + 1e-12
        assert tol["posts_excluded"] == n * n - (n - 2) ** 2  # the edge posts' biased widths leave the grid


def _tolerant_library(n=12):
    """Two families of unit-transmission posts, the pass-through phase 0 everywhere. Below the diagonal (ix >= iy)
    the focusing phase depends on u = ix - iy only, which a uniform edge bias (ix, iy) -> (ix +- 1, iy +- 1) keeps:
    level k = u mod 4 has the phase pi k / 2 + 0.12 (-1)^k (0.12 rad nominal error, none added by the bias). Above it
    the nominal phase is exact on one diagonal (m = 0), and the bias moves level k's to its neighbours m = +-1, phase
    +-0.4 (-1)^k (not a common shift). The edge posts and the rest of the upper family (|m| > 1) transmit 1 %, so they
    are never chosen and every chosen post has its biased neighbours on the grid."""
    ix, iy = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    u, v = ix - iy, ix + iy
    k = np.mod(np.abs(u), 4)
    sign = np.where(k % 2 == 0, 1.0, -1.0)
    m = (v - (n - 1) - (u % 2 == 0)) // 2
    tolerant = np.pi / 2 * k + 0.12 * sign
    sensitive = np.pi / 2 * k + 0.4 * sign * m
    junk = (ix % (n - 1) == 0) | (iy % (n - 1) == 0) | ((u < 0) & (np.abs(m) > 1))
    amp = np.where(junk, 0.1, 1.0)
    return _grid_library(amp * np.exp(1j * np.where(u >= 0, tolerant, sensitive)), amp + 0j)


def _biased_rms_error(lib, ps, s):
    """rms focusing phase error of ``ps``' posts moved by s = +-1 grid step on both axes, the common shift removed
    (as bias_table does, from the library's own grid values)."""
    N = ps.levels
    idx = np.round((ps.widths_um - 0.5) / 0.1).astype(int) + s
    ph = np.angle(lib.t_x[0][idx[:, 0], idx[:, 1]]) - 2 * np.pi * np.arange(N) / N
    err = np.angle(np.exp(1j * (ph - np.angle(np.sum(np.exp(1j * ph))))))
    return float(np.sqrt(np.mean(err ** 2)))


def test_bias_weight_chooses_posts_that_keep_their_phase_under_edge_bias():
    """Nominally the exact but bias-sensitive posts win (0 rad error, 0.4 rad under bias); with a bias weight the
    tolerant ones (0.12 rad in every case): the biased phase error falls, the nominal one rises (the trade-off)."""
    lib = _tolerant_library()
    plat = PlatformDesign()
    nominal = select_posts(lib, "x", 4, platform=plat)
    tolerant = select_posts(lib, "x", 4, platform=plat, bias_weight=1.0)
    for s in (-1, 1):
        assert _biased_rms_error(lib, nominal, s) == pytest.approx(0.4, abs=1e-6)
        assert _biased_rms_error(lib, tolerant, s) == pytest.approx(0.12, abs=1e-6)
    assert nominal.info["rms_phase_error_rad"] < 1e-9
    assert tolerant.info["rms_phase_error_rad"] == pytest.approx(0.12, abs=1e-6)
    # info['tolerance'] (the library's interpolation at the biased widths) says the same
    for ps, worst in ((nominal, 0.4), (tolerant, 0.12)):
        tol = ps.info["tolerance"]
        assert tol["worst_rms_phase_error_rad"] == pytest.approx(worst, abs=1e-6)
        assert set(tol["cases"]) == {"-", "0", "+"} and len(tol["cases"]["+"]["phase_error_rad"]) == 4
    assert tolerant.info["method"].startswith("joint search") and nominal.info["method"].startswith("grid search")
    assert tolerant.info["tolerance"]["joint_cost"] < tolerant.info["tolerance"]["nominal_choice_joint_cost"]


def test_bias_weight_needs_a_bias():
    with pytest.raises(InputError, match="bias_weight"):
        PlatformSweep(PlatformDesign(edge_bias_um=0.0), bias_weight=1.0)
    with pytest.raises(InputError, match="bias_weight"):
        select_posts(synthetic_library(), "x", 4, bias_weight=-1.0)

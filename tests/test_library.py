"""Tests of the scatterer library (RCWA sweep, cache, resume) and birefringent post selection."""

from __future__ import annotations

import argparse
import json
import warnings

import numpy as np
import pytest

from metafovea.errors import InputError, NotConvergedWarning
from metafovea.io import atomic_save_npz, load_npz
from metafovea.library import Library, PostSet, compute_library, postset_table, select_posts, width_grid
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


def test_cli_library_writes_figures_and_json(tmp_path, capsys):
    from metafovea.cli.library import add_parser
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers()
    add_parser(sub)
    out = tmp_path / "out"
    args = ap.parse_args(["library", "--grid-step-um", "1.0", "--harmonics", "5", "--levels", "2",
                          "--cache-dir", str(tmp_path / "c"), "--out", str(out), "--json", "--no-progress",
                          "--workers", "1"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        assert args.func(args) == 0
    data = json.loads(capsys.readouterr().out)
    assert set(data["post_sets"]) == {"x", "y"}
    assert data["post_sets"]["x"]["lens"] == "foveal" and len(data["post_sets"]["y"]["levels"]) == 2
    for f in ("library.npz", "postset_x.npz", "postset_y.npz", "fig7b_phase_maps.png",
              "fig7c_selected_posts.png", "library.json"):
        assert (out / f).is_file()
    assert PostSet.load(out / "postset_y.npz").polarization == "y"
    arrays, meta = load_npz(out / "library.npz")
    assert meta["harmonics"] == 5 and arrays["t_x"].shape == (1, 3, 3)
    # existing output is not overwritten without --force
    args = ap.parse_args(["library", "--grid-step-um", "1.0", "--harmonics", "5", "--cache-dir",
                          str(tmp_path / "c"), "--out", str(out), "--no-progress", "--workers", "1"])
    with pytest.raises(InputError):
        args.func(args)
    args = ap.parse_args(["library", "--grid-step-um", "-1", "--no-progress"])
    with pytest.raises(InputError):
        args.func(args)

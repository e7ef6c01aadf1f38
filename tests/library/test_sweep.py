"""Tests of the scatterer library: the RCWA sweep, its cache and resume, the width grid (metafovea.library.sweep)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from metafovea.config import PlatformDesign
from metafovea.errors import InputError, NotConvergedWarning
from metafovea.io import atomic_save_npz
from metafovea.library import Library, LibraryOptions, compute_library, width_grid
from metafovea.rcwa.posts import post_response

#: the small library's sweep (the package fixture ``small_lib``, conftest.py)
W3 = [1.0, 2.0, 3.0]
M = 5


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

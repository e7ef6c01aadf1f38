"""Tests of the shipped seed of the library cache (metafovea.library.seed, metafovea/data/): it holds exactly what the
current defaults use, its numbers are what the solver gives today, and it serves only its own key."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import pytest

import metafovea.io
from metafovea.config import PlatformDesign, SystemDesign
from metafovea.io import DATA_DIR, load_npz, seed_file
from metafovea.library import Library, PostSet, compute_library, library_key, oblique_response, width_grid
from metafovea.library.seed import REGENERATE, library_file_name, seed_names

STALE = f"the shipped seed (metafovea/data/) is stale: run `{REGENERATE}` and commit metafovea/data/"


def shipped() -> list[str]:
    return sorted(p.name for p in DATA_DIR.glob("*.npz"))


def test_the_seed_holds_exactly_the_files_of_the_current_defaults():
    """The key rule is the cache's: a change of the defaults, the solver settings or the key makes the names differ
    and this test fail with the command that regenerates the seed."""
    assert library_file_name() in shipped(), STALE  # before seed_names, which would compute a missing library
    assert shipped() == seed_names(), STALE
    # planted: another stack or solver setting names another file, which the seed does not hold
    planted = SystemDesign(platform=replace(PlatformDesign(), post_height_um=9.9))
    assert library_file_name(planted) not in shipped()


@pytest.fixture(scope="module")
def seed_library() -> Library:
    return Library.load(seed_file(library_file_name()))


def test_the_seed_library_is_what_the_solver_gives(seed_library):
    """A handful of posts (thin, wide, square, both orientations; both polarisations) solved again at the shipped
    settings: every array within 1e-9 of the shipped one."""
    from metafovea.parallel import blas_threads
    from metafovea.rcwa.posts import post_response

    lib, m = seed_library, seed_library.meta
    n = lib.wx_um.size
    picks = [(0, n - 1), (n - 1, 0), (n // 2, n // 2), (3, n // 3), (2 * n // 3, 5)]
    ix, iy = (np.array(v) for v in zip(*picks))
    with blas_threads(1):  # OpenBLAS' threads take 50x longer on a loaded machine for these small eigenproblems
        got = post_response(lib.wx_um[ix], lib.wy_um[iy], float(lib.wavelengths_um[0]), estimate=m["estimate"],
                            polarizations=("x", "y"), period_um=m["period_um"], height_um=m["height_um"],
                            **{k: complex(*m[k]) for k in ("n_post", "n_surround", "n_substrate", "n_superstrate")},
                            harmonics=m["harmonics"], factorization=m["factorization"], incidence=m["incidence"])
    for k in ("t_x", "t_y", "T_x", "T_y", "R_x", "R_y", "err_x", "err_y"):
        np.testing.assert_allclose(getattr(got, k), lib.arrays[k][0, ix, iy], rtol=0, atol=1e-9,
                                   err_msg=f"{k}: {STALE}")


def test_the_seed_oblique_responses_are_what_the_solver_gives(tmp_path):
    """Two posts of a shipped oblique-incidence response solved again: the same ratios within 1e-9."""
    name = next(n for n in shipped() if n.startswith("oblique_"))
    arrays, meta = load_npz(seed_file(name))
    key = meta["key"]
    plat = replace(PlatformDesign(), period_um=key["period_um"], post_height_um=key["height_um"],
                   n_post=key["n_post"], n_substrate=key["n_substrate"], n_superstrate=key["n_superstrate"])
    k = [0, len(key["widths_um"]) - 1]
    widths = np.array(key["widths_um"])[k]
    ps = PostSet("x", key["period_um"], key["height_um"], key["wavelength_um"], widths, np.ones(2), np.ones(2))
    ob = oblique_response(ps, plat, angles_deg=key["angles_deg"], harmonics=key["harmonics"], cache_dir=tmp_path)
    for q, pol in enumerate("xy"):
        np.testing.assert_allclose(ob.ratio[pol], arrays["ratios"][:, :, q, k], rtol=0, atol=1e-9, err_msg=STALE)


def test_a_cache_miss_reads_the_seed_of_its_own_key_only(tmp_path, monkeypatch, caplog):
    """The default library from an empty cache comes from the seed (nothing computed, nothing announced); a seed
    file planted under another sweep's name but holding the default library is refused and that sweep computed."""
    with caplog.at_level(logging.INFO, logger="metafovea"):
        sweep_lib = compute_library(width_grid(), cache_dir=tmp_path / "a")
    assert sweep_lib.meta.get("from_seed") and not any("computing" in r.message for r in caplog.records)
    assert not (tmp_path / "a").exists() or not any((tmp_path / "a").iterdir())

    small = dict(wx_um=[1.0, 3.0], wavelengths_um=[10.0], harmonics=5, workers=1, progress=False, tol=None)
    planted = tmp_path / "data"
    planted.mkdir()
    (planted / f"library-{library_key(**small)}.npz").write_bytes(seed_file(library_file_name()).read_bytes())
    monkeypatch.setattr(metafovea.io, "DATA_DIR", planted)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="metafovea"):
        lib = compute_library(cache_dir=tmp_path / "b", **small)
    assert not lib.meta.get("from_seed") and lib.wx_um.tolist() == [1.0, 3.0]
    assert any("ignoring the library seed" in r.message for r in caplog.records)
    assert any("computing the RCWA scatterer library: 2 x 2 posts" in r.message for r in caplog.records)


def test_the_default_oblique_responses_come_from_the_seed(tmp_path, caplog):
    """Both default post sets' oblique responses from an empty cache: the shipped numbers, nothing solved."""
    from metafovea.library.seed import default_post_sets

    with caplog.at_level(logging.WARNING, logger="metafovea"):
        for ps in default_post_sets():
            ob = oblique_response(ps, cache_dir=tmp_path)
            assert ob.ratio["x"].shape == (4, 2, ps.levels)
    assert not any("computing" in r.message for r in caplog.records)
    assert not any(tmp_path.iterdir())

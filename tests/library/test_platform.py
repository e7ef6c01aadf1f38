"""Tests of the library of a platform and its post sets (metafovea.library.platform)."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.config import LensDesign, PlatformDesign
from metafovea.errors import InputError
from metafovea.lens import summarize
from metafovea.library import PlatformSweep, platform_post_sets, usable_posts


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



def _same_sets(a, b) -> bool:
    import dataclasses

    return all(np.array_equal(getattr(a[p], f.name), getattr(b[p], f.name)) if isinstance(getattr(a[p], f.name),
                                                                                          np.ndarray)
               else getattr(a[p], f.name) == getattr(b[p], f.name) for p in a for f in dataclasses.fields(a[p]))


def test_the_selection_is_cached_on_disk_read_back_the_same_and_a_damaged_file_is_redone(tmp_path, monkeypatch):
    """A new process reads both post sets from the cache (0.9 s of grid search per process before); every field is
    the selection's; a damaged file is selected again and rewritten; without use_cache nothing is written."""
    import metafovea.library.platform as platform
    from metafovea.library import PostSet
    from metafovea.library.platform import clear_selection_cache

    clear_selection_cache()
    sets, _ = platform_post_sets(cache_dir=tmp_path)  # the paper's library (the package's seed), 8 levels
    files = sorted(tmp_path.glob("posts_*.npz"))
    assert [f.name[-6:] for f in files] == ["_x.npz", "_y.npz"]

    def no_selection(*a, **k):
        raise AssertionError("selected again")

    clear_selection_cache()
    monkeypatch.setattr(platform, "select_posts", no_selection)
    assert _same_sets(platform_post_sets(cache_dir=tmp_path)[0], sets)

    files[1].write_bytes(b"not a post set")  # damaged: selected again, rewritten
    monkeypatch.undo()
    clear_selection_cache()
    assert _same_sets(platform_post_sets(cache_dir=tmp_path)[0], sets)
    assert np.array_equal(PostSet.load(files[1]).widths_um, sets["y"].widths_um)

    clear_selection_cache()
    other = tmp_path / "no_cache"
    platform_post_sets(PlatformDesign(), 4, grid_step_um=0.5, harmonics=5, cache_dir=other, use_cache=False,
                       workers=1)  # a coarse library: it is swept again without a cache
    assert not list(other.glob("*"))

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
    assert f"at most the {n_ok} of 3 x 3 posts" in e.value.allowed and "harmonics=..." in e.value.allowed

"""Tests of the post set and the checked loading of the library's files (metafovea.library.postset)."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.errors import InputError
from metafovea.io import atomic_save_npz, load_npz
from metafovea.library import Library, PostSet
from metafovea.library.sweep import LIBRARY_STACK_KEYS


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


def _without(path, key, out):
    """A copy of the file at ``path`` whose metadata lacks ``key``."""
    arrays, meta = load_npz(path)
    del meta[key]
    return atomic_save_npz(out, meta, **arrays)


@pytest.mark.parametrize("key", ["period_um", "height_um", "wavelength_um"])
def test_postset_file_without_a_physical_parameter_names_the_file_and_the_key(tmp_path, key):
    """A post set file without its period (or post height, wavelength) is refused with the file and the key named;
    no paper value is put in its place."""
    good = PostSet.ideal(4, period_um=5.0).save(tmp_path / "good.npz")
    bad = _without(good, key, tmp_path / "bad.npz")
    with pytest.raises(InputError) as e:
        PostSet.load(bad, name="--post-set")
    assert e.value.parameter == "--post-set" and e.value.value == str(bad) and repr(key) in e.value.detail
    assert PostSet.load(good).period_um == 5.0


@pytest.mark.parametrize("key", LIBRARY_STACK_KEYS)
def test_library_file_without_a_physical_parameter_names_the_file_and_the_key(tmp_path, key):
    """A library file without its period (or post height, a refractive index of its stack) was read with the paper's
    value (``period_um`` 4 um); now it is refused with the file and the key named."""
    n = 3
    w = np.linspace(1.0, 3.0, n)
    arrays = {"t_x": np.ones((1, n, n), complex), "t_y": np.ones((1, n, n), complex)}
    meta = {"period_um": 5.0, "height_um": 8.0, "n_post": [3.0, 0.0], "n_surround": [1.0, 0.0],
            "n_substrate": [3.0, 0.0], "n_superstrate": [1.0, 0.0]}
    good = Library(w, w, np.array([10.0]), arrays, meta).save(tmp_path / "good.npz")
    bad = _without(good, key, tmp_path / "bad.npz")
    with pytest.raises(InputError) as e:
        Library.load(bad, name="--library")
    assert e.value.parameter == "--library" and e.value.value == str(bad) and repr(key) in e.value.detail
    assert Library.load(good).meta["period_um"] == 5.0

"""Tests of the post set and the checked loading of the library's files (metafovea.library.postset)."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.errors import InputError
from metafovea.library import Library, PostSet


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

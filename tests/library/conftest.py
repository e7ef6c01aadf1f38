"""Fixtures of the library stage's tests."""

from __future__ import annotations

import warnings

import pytest

from metafovea.errors import NotConvergedWarning
from metafovea.library import compute_library

#: the small library's widths (um) and harmonics (test_sweep.py's W3 and M name the same sweep)
W3 = [1.0, 2.0, 3.0]
M = 5


@pytest.fixture(scope="package")
def small_lib(tmp_path_factory):
    """A 3 x 3 library at 10 um (M = 5) and its cache folder."""
    d = tmp_path_factory.mktemp("cache")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        lib = compute_library(W3, None, [10.0], harmonics=M, cache_dir=d, workers=1, progress=False)
    return lib, d

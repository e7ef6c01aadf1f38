"""Radiometry test found in tests/test_optics.py (moved verbatim; not collected): merge into
tests/test_radiometry.py."""

import pytest

from metafovea.errors import InputError
from metafovea.radiometry import check_band, planck_radiance


def test_planck_and_band():
    b = planck_radiance([10.0], 300.0)
    assert b[0] == pytest.approx(9.923, rel=1e-3)  # W / (m^2 sr um)
    with pytest.raises(InputError, match="reversed"):
        check_band((14.0, 8.0))

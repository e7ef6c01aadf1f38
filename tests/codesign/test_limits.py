"""The bandwidth-limit figures against the issue's own (independently computed) numbers for the paper's lenses."""

from __future__ import annotations

import pytest

from metafovea.codesign.limits import bandwidth_limit
from metafovea.config import SystemDesign


def test_the_paper_lenses_limits():
    s = SystemDesign.paper()
    fov = bandwidth_limit(s.foveal, s.platform, (8.0, 14.0))
    per = bandwidth_limit(s.perifoveal, s.platform, (8.0, 14.0))
    # issue 33: 24 um of post path; 4.6 mm (F/2, 191x short) and 3.0 mm (F/1); ~0.5 % achromatic band; 8-14 um is
    # ~55 % of the centre frequency; the focus moves ~80 mm; posts 1-2 mm tall for a true achromat
    assert fov.post_path_um == pytest.approx(24.2, abs=0.05)
    assert fov.marginal_delay_um == pytest.approx(4620, rel=0.01) and fov.shortfall == pytest.approx(191, abs=1)
    assert per.marginal_delay_um == pytest.approx(2950, rel=0.01)
    assert fov.achromatic_fraction == pytest.approx(0.0052, abs=2e-4)
    assert fov.band_fraction == pytest.approx(0.54, abs=0.01)
    assert fov.focal_shift_um == pytest.approx(80_400, rel=0.01)
    assert 1000 < fov.post_height_for_achromat_um < 2000 and 1000 < per.post_height_for_achromat_um < 2000
    assert fov.depths_of_focus > 100 and per.depths_of_focus > 100
    assert any("191x short" in line for line in fov.lines())

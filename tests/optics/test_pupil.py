"""Pupils: the N-level quantisation's order efficiency (sinc^2(pi/N)) and the post-set transmission of the
focusing and the pass-through polarisation."""

import numpy as np
import pytest

from metafovea.config import LensDesign
from metafovea.library import PostSet
from metafovea.optics import build_pupils

F1 = LensDesign.perifoveal()  # F/1, D = 25 mm


def test_quantisation_point_sampled_sinc2():
    # continuous-space N-level quantisation: focal peak ratio sinc^2(pi/N)
    for n in (4, 8, 16):
        lens = F1.with_(levels=n)
        ps = build_pupils(lens, 10.0, quantize=True, lattice=False)
        assert ps.info["order_efficiency"] == pytest.approx(np.sinc(1 / n) ** 2, rel=1e-12)
    assert np.sinc(1 / 8) ** 2 == pytest.approx(0.9496, abs=1e-4)


def test_post_set_transmission_and_pass_through():
    ps = PostSet.ideal(8, polarization="y")
    t_focus = ps.t_y * 0.9
    ps2 = PostSet(ps.polarization, ps.period_um, ps.height_um, ps.wavelength_um, ps.widths_um, ps.t_x, t_focus)
    a = build_pupils(F1, 10.0, post_set=ps2, lattice=False)
    assert a.info["order_efficiency"] == pytest.approx(0.81 * np.sinc(1 / 8) ** 2, rel=1e-9)
    other = build_pupils(F1, 10.0, post_set=ps, polarization="x")
    assert other.focus is None  # uniform pass-through does not focus
    assert other.coefficients[0] == pytest.approx(1.0)

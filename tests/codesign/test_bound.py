"""The line bound of the band-integrated MTF against a brute-force Fresnel propagation (written here, numpy only):
random radial phase profiles never beat it, the plain hyperbola sits at its first-order value, and the lens
refocused on the bound's best wavelength reaches it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import j0

from metafovea.codesign.bound import band_mtf_bound
from metafovea.config import LensDesign
from metafovea.errors import InputError
from metafovea.radiometry import planck_radiance

#: a small F/2 lens whose 8-14 um band spans ~40 depths of focus (the bound's broadband regime)
LENS = LensDesign(name="small", f_um=12_000.0, diameter_um=6_000.0, polarization="x", levels=8)
BAND = (8.0, 14.0)
NU = np.array([5.0, 8.0, 12.0, 16.0])  # cyc/mm


def _band_otf(extra_phase, lam0_focus=10.0, n_lam=121, n_rho=300, n_r=300):
    """Brute force: the band-integrated OTF (real: radial PSF) of a paraxial thin lens with the structural phase
    -k0 rho^2 / (2 f') + extra (f' = f lam0 / lam0_focus), Fresnel to z = f, Hankel transforms both ways."""
    f, radius, lam0 = LENS.f_um, LENS.diameter_um / 2, LENS.wavelength_um
    lam = np.linspace(*BAND, n_lam)
    s = planck_radiance(lam, 300.0)
    s = s / np.trapezoid(s, lam)
    u = (np.arange(n_rho) + 0.5) / n_rho
    rho = radius * np.sqrt(u)  # equal-area nodes
    d_area = np.pi * radius**2 / n_rho
    f_design = f * lam0_focus / lam0
    phi = -2 * np.pi / lam0 * rho**2 / (2 * f_design) + extra_phase(rho / radius)
    r = np.linspace(0.0, 1.5 * radius * 0.3, n_r)  # beyond the largest blur disk the band can make
    hank = j0(2 * np.pi * (NU * 1e-3)[:, None] * r[None, :]) * r[None, :] * 2 * np.pi
    otf = np.zeros(NU.size)
    for lk, sk in zip(lam, s):
        k = 2 * np.pi / lk
        g = np.exp(1j * (phi + k * rho**2 / (2 * f)))
        field = (g[None, :] * j0(k * rho[None, :] * r[:, None] / f)).sum(1) * d_area / (lk * f)
        otf += sk * np.trapezoid(hank * np.abs(field)[None, :] ** 2, r, axis=1)
    return otf * (lam[1] - lam[0]) / (np.pi * radius**2)


@pytest.fixture(scope="module")
def bound():
    return band_mtf_bound(LENS, BAND, NU)


def test_the_hyperbola_sits_at_its_first_order_value(bound):
    brute = _band_otf(lambda q: 0.0 * q)
    np.testing.assert_allclose(brute, bound.hyperbola, rtol=0.12)
    assert np.all(brute <= bound.bound * 1.05)


def test_no_random_radial_phase_beats_the_bound(bound):
    rng = np.random.default_rng(7)
    for _ in range(2):
        a = rng.normal(0.0, [30.0, 20.0, 10.0])  # rad: focal spreads of +-10 % and more (extended depth of focus)
        brute = _band_otf(lambda q, a=a: a[0] * q**2 + a[1] * q**4 + a[2] * q**6)
        assert np.all(brute <= bound.bound * 1.05), (a, brute / bound.bound)


def test_the_refocused_lens_reaches_the_bound(bound):
    assert 11.0 < bound.best_wavelength_um < 13.0 and 1.0 < bound.gain_limit < 1.2
    brute = _band_otf(lambda q: 0.0 * q, lam0_focus=bound.best_wavelength_um)
    np.testing.assert_allclose(brute, bound.bound, rtol=0.12)
    assert np.mean(brute) > np.mean(_band_otf(lambda q: 0.0 * q))


def test_bad_frequencies_are_refused():
    with pytest.raises(InputError, match="nu_cyc_per_mm"):
        band_mtf_bound(LENS, BAND, [5.0, 0.0])

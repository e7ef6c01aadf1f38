"""metafovea.radiometry: Planck radiance, the band radiance table and the PSF wavelength bins."""

from __future__ import annotations

import math

import numpy as np
import pytest

from metafovea.config import SystemDesign
from metafovea.errors import InputError
from metafovea.radiometry import (
    BandRadiance,
    check_band,
    planck_radiance,
    psf_wavelengths,
    spectral_transmission,
    spectral_weights,
)


# ---------------------------------------------------------------------------------------------
# physics references
# ---------------------------------------------------------------------------------------------
def test_planck_matches_independent_formula_and_stefan_boltzmann():
    lam = np.array([8.0, 10.0, 12.0])
    c1, c2 = 2 * 6.62607015e-34 * 299792458.0 ** 2, 6.62607015e-34 * 299792458.0 / 1.380649e-23
    direct = c1 / (lam * 1e-6) ** 5 / np.expm1(c2 / (lam * 1e-6 * 300.0)) * 1e-6
    np.testing.assert_allclose(planck_radiance(lam, 300.0), direct, rtol=1e-4)
    # the whole spectrum integrates to sigma T^4 / pi
    lam_w, w = spectral_weights((0.5, 2000.0), n=40001)
    w = np.where((lam_w > 0.5) & (lam_w < 2000.0), 1.0, 0.0)
    L = np.trapezoid(planck_radiance(lam_w, 300.0) * w, lam_w)
    assert L == pytest.approx(5.670374e-8 * 300.0 ** 4 / math.pi, rel=5e-3)


def test_band_radiance_table_and_derivative():
    br = BandRadiance.for_system(SystemDesign.paper())
    t = np.array([250.0, 300.0, 333.3, 600.0])
    np.testing.assert_allclose(br(t), br.exact(t), rtol=1e-5)
    # dL/dT by finite difference of the table
    assert (br(300.5) - br(299.5)) == pytest.approx(br.derivative(300.0), rel=1e-3)
    # filter passes less than the band; emissivity mixes in the reflected surroundings
    brf = BandRadiance.for_system(SystemDesign.paper(), filter_enabled=True)
    assert brf(300.0) < 0.2 * br(300.0)
    assert br.apparent(320.0, 0.5, 300.0) == pytest.approx(0.5 * (br(320.0) + br(300.0)))
    with pytest.raises(InputError, match="temperature"):
        br(-1.0)


@pytest.mark.parametrize("filter_um", [None, (10.0, 0.5)])
def test_the_table_holds_its_stated_error_down_to_100_k(filter_um):
    """The docstring's 1e-5 at T >= 100 K: log-linear interpolation of the 1 K grid was 2.7e-4 off at 100 K (3.5e-4
    with the filter; a cold sky's radiance), the cubic spline 3.5e-6 (5.5e-6); every fraction of a kelvin checked."""
    br = BandRadiance.from_band((8.0, 14.0), filter_um=filter_um)
    for lo in (100.0, 150.0, 200.0, 300.0, 1000.0, 2990.0):
        t = np.linspace(lo, lo + 1.0, 81)
        assert np.max(np.abs(br(t) / br.exact(t) - 1.0)) < 1e-5, lo


def test_psf_bins_carry_the_bands_weighted_mean_wavelength():
    """Each bin's weight is its integral and its wavelength the mean inside it, so the weights' mean wavelength is the
    band's: against scipy's adaptive quadrature with the raised-cosine edges as break points, 5e-7 um (the 16-point
    midpoint rule under-resolved the 0.1 um edges inside the 1.75 um outer bins: 3.9e-3 um off)."""
    from scipy.integrate import quad

    from metafovea.radiometry import spectral_support_um, spectral_transmission

    lb, wb = psf_wavelengths((8.0, 14.0), design_um=10.0, temperature_k=300.0, n=31)

    def f(x):
        return float(spectral_transmission(np.array([x]), (8.0, 14.0))[0] * planck_radiance(np.array([x]), 300.0)[0])

    lo, hi = spectral_support_um((8.0, 14.0))
    pts = [7.95, 8.0, 8.05, 13.95, 14.0, 14.05]
    mean = quad(lambda x: x * f(x), lo, hi, limit=1000, points=pts)[0] / quad(f, lo, hi, limit=1000, points=pts)[0]
    assert abs(float(wb @ lb) - mean) < 1e-5


# ---------------------------------------------------------------------------------------------
# PSF wavelength bins
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("filter_um", [None, (10.0, 0.5)])
@pytest.mark.parametrize("n", [1, 2, 3, 31, 61, 481])
def test_psf_wavelength_weights_sum_to_one(n, filter_um):
    lam, w = psf_wavelengths((8.0, 14.0), design_um=10.0, filter_um=filter_um, n=n)
    assert lam.shape == w.shape and 1 <= lam.size <= n
    assert np.all(w > 0) and w.sum() == pytest.approx(1.0, abs=1e-12)
    assert np.all(np.diff(lam) > 0) and 7.0 < lam.min() and lam.max() < 15.0


def _planck_weighted_mean_um(band_um, filter_um, temperature_k=300.0) -> float:
    """The band's Planck x transmission weighted mean wavelength by dense trapezoidal quadrature (0.025 nm steps)."""
    x = np.linspace(6.0, 16.0, 400_001)
    f = spectral_transmission(x, band_um, filter_um=filter_um) * planck_radiance(x, temperature_k)
    return float(np.trapezoid(f * x, x) / np.trapezoid(f, x))


@pytest.mark.parametrize("filter_enabled", [False, True])
def test_psf_wavelength_planck_weight_converges_with_the_bins(filter_enabled):
    """61 bins (the psf default) and 481 give the same Planck-weighted mean wavelength, and it is the band's.

    Measured for the paper's lenses (design 10 um, 300 K): |mean(61) - mean(481)| = 8.7e-5 um without the
    filter, 4e-14 um with it; mean(481) is within 6e-7 um of mean(3841) and of the dense quadrature."""
    s = SystemDesign.paper()
    br = BandRadiance.for_system(s, filter_enabled=filter_enabled)
    means = {}
    for n in (61, 481):
        lam, w = br.psf_wavelengths(s.perifoveal.wavelength_um, s.scene_temperature_k, n)
        means[n] = float(np.sum(lam * w))
    assert abs(means[61] - means[481]) < 1e-3
    ref = _planck_weighted_mean_um(br.band_um, br.filter_um, s.scene_temperature_k)
    assert abs(means[481] - ref) < 1e-5 and abs(means[61] - ref) < 1e-3


def test_planck_matches_colour_science_planck_law():
    """The hand-written law against colour-science's ``planck_law`` (its reference) over 0.3-100 um and 1-3000 K,
    tiny and huge exponents included, in the broadcast shapes the tables use. colour's defaults are the CIE's
    rounded radiation constants (c2 = 1.4388e-2 m K); the SI-exact ones (h, c and k are exact since 2019) are
    passed to it here, and the CIE's rounding is shown to be what the defaults' difference is."""
    from colour.colorimetry import planck_law
    from scipy import constants as sc

    c1 = 2 * math.pi * sc.h * sc.c**2  # colour's c1 is the exitance constant: radiance = c1 / pi ...
    c2 = sc.h * sc.c / sc.k

    lam = np.geomspace(0.3, 100.0, 41)
    t = np.array([1.0, 20.0, 77.0, 250.0, 300.0, 340.0, 1000.0, 3000.0])
    with np.errstate(over="ignore"):
        ref = np.asarray(planck_law(lam * 1e-6, t, c1=c1, c2=c2), dtype=np.float64).reshape(lam.size, t.size) * 1e-6
        cie = float(planck_law(10e-6, 300.0)) * 1e-6
    got = planck_radiance(lam[:, None], t[None, :])
    assert got.shape == (lam.size, t.size)
    big = ref > 1e-250
    np.testing.assert_allclose(got[big], ref[big], rtol=1e-12)
    assert np.all(got[~big] < 1e-240) and np.all(got >= 0)
    # at 10 um, 300 K: d ln B / d ln c2 = x e^x / (e^x - 1), x = c2 / (lambda T) = 4.80, times the CIE rounding
    x = c2 / (10e-6 * 300.0)
    rel = x * math.exp(x) / math.expm1(x) * (1.4388e-2 - c2) / c2
    assert float(planck_radiance(10.0, 300.0)) * (1 - rel) == pytest.approx(cie, rel=2e-6)


def test_planck_value_and_band_checks():
    """B(10 um, 300 K) = 9.923 W m^-2 sr^-1 um^-1; a reversed band is refused with a reason."""
    b = planck_radiance([10.0], 300.0)
    assert b[0] == pytest.approx(9.923, rel=1e-3)  # W / (m^2 sr um)
    with pytest.raises(InputError, match="reversed"):
        check_band((14.0, 8.0))


def test_the_si_constants_are_scipys():
    """The exact SI values written out (scipy.constants' import cost ~0.1 s in every process) are CODATA's."""
    from scipy import constants

    from metafovea.radiometry import BOLTZMANN_J_K, LIGHT_SPEED_M_S, PLANCK_J_S

    assert (PLANCK_J_S, LIGHT_SPEED_M_S, BOLTZMANN_J_K) == (constants.h, constants.c, constants.k)

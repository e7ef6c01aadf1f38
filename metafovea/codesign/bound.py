"""The most that any phase profile can give a lens' band-integrated MTF: the through-band line bound.

A camera without a filter records the band-integrated PSF, so what the reconstruction can invert is the OTF of
that sum, ``H(nu) = int s(lambda) eta(lambda) OTF_lambda(nu) d lambda`` (``s`` the detected spectral density,
normalised to 1; ``eta`` the focusing order's efficiency). For a thin lens of pupil amplitude ``A`` and structural
phase ``phi`` (the same radians at every wavelength: the focusing order of a wrapped lens), on the plane ``z``,
in the paraxial (Fresnel) model the OTF is the pupil's autocorrelation at the shear ``s = lambda z nu``:

    OTF_lambda(nu) = (1 / |A|^2) int A(x + s/2) A(x - s/2) exp(i [2 pi x.nu + phi(x + s/2) - phi(x - s/2)]) d^2x

To first order in the shear the bracket is ``2 pi t nu + lambda z nu d_t phi(x)`` (``t = x.nu / |nu|``): linear
in ``lambda``. Over a band many depths of focus wide the integral over ``lambda`` is then a delta function: a point
of the pupil contributes where its zone focuses the wavelength ``lambda*(x)`` on the plane ``z`` (``lambda* =
lambda0 f_local / z``), with the weight ``lambda* s(lambda*) eta(lambda*) / nu`` per unit length of the line
``t = 0`` through the centre (the only points where a radial phase focuses at all: there ``|x + s/2| = |x - s/2|``),
so

    |H(nu)| <= (1 / |A|^2) int_{t=0} max_lambda [ lambda s(lambda) eta(lambda) A(x + s/2) A(x - s/2) ] dl / nu

for every radially symmetric phase, and a phase that is not radially symmetric only adds phase factors to the line
integral (it can only lose). The hyperbola focused at ``lambda0`` on ``z = f`` reaches the same expression with
``lambda = lambda0`` instead of the maximum: the ratio of the two is all that a phase profile can win. For a 300 K
scene over 8-14 um, ``lambda s(lambda)`` peaks near 12 um and is only ~9 % above its value at 10 um: an extended
depth of focus spreads the same line integral over more wavelengths, it does not raise it (the through-focus
integral of the OTF is fixed by the aperture: the ambiguity function's invariance). What the co-design can change
is where and how evenly the MTF is spread, the efficiency ``eta``, the haze and the boundary, not the
band-integrated MTF's size.

Valid where the band spans many depths of focus (the bound's 1/nu form fails at the lowest frequencies, where
the MTF is bounded by 1 instead; :func:`band_mtf_bound` takes the smaller) and on axis. ``tests/codesign/
test_bound.py`` checks it against a brute-force Fresnel propagation of random radial phases over a fine band.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from metafovea.config import LensDesign
from metafovea.errors import InputError, check_int
from metafovea.radiometry import check_band, planck_radiance, spectral_transmission


@dataclass(frozen=True)
class MTFBound:
    """The line bound of a lens' band-integrated MTF and the plain hyperbola's first-order value.

    ``nu_cyc_per_mm`` (n,); ``bound`` and ``hyperbola`` (n,): MTF values (dimensionless, at most 1);
    ``best_wavelength_um``: the wavelength a lens focused on the plane ``z`` everywhere would take to reach the
    bound (the argmax of ``lambda s(lambda) eta(lambda)``); ``gain_limit``: ``max(bound / hyperbola)`` over the
    frequencies where both are below 1; ``area_bound``, ``area_hyperbola``: the mean MTF over ``[0, nu_max]``
    (the MTF area the co-design objective uses, 1 for a point)."""

    nu_cyc_per_mm: np.ndarray
    bound: np.ndarray
    hyperbola: np.ndarray
    best_wavelength_um: float
    gain_limit: float
    area_bound: float
    area_hyperbola: float

    def lines(self, name: str = "lens") -> list[str]:
        return [f"{name}: no phase profile raises the band-integrated MTF above the line bound: at most "
                f"{self.gain_limit:.2f}x the hyperbola's at any frequency (MTF area to "
                f"{self.nu_cyc_per_mm[-1]:.3g} cyc/mm: bound {self.area_bound:.4f}, hyperbola "
                f"{self.area_hyperbola:.4f}); reached by focusing {self.best_wavelength_um:.2f} um on the sensor"]


def detected_density(wavelengths_um: np.ndarray, band_um: tuple[float, float], *, temperature_k: float = 300.0,
                     filter_um: tuple[float, float] | None = None) -> np.ndarray:
    """The detected spectral density ``s(lambda) = B(lambda, T) x band x filter`` on ``wavelengths_um`` (uniform,
    increasing), normalised to integrate to 1 (trapezoid rule), per um."""
    s = planck_radiance(wavelengths_um, temperature_k) * spectral_transmission(wavelengths_um, band_um,
                                                                                filter_um=filter_um)
    return s / np.trapezoid(s, wavelengths_um)


def band_mtf_bound(lens: LensDesign, band_um: tuple[float, float], nu_cyc_per_mm: ArrayLike, *,
                   z_um: float | None = None, temperature_k: float = 300.0,
                   filter_um: tuple[float, float] | None = None,
                   efficiency: Callable[[np.ndarray], np.ndarray] | None = None,
                   n_wavelengths: int = 2001, n_line: int = 2001) -> MTFBound:
    """The line bound of the band-integrated MTF on axis (see the module docstring).

    Parameters
    ----------
    lens : LensDesign
        Its clear aperture (a disk of ``diameter_um``), focal length and design wavelength.
    band_um : (lo, hi), um
        The band (with ``filter_um`` and a scene at ``temperature_k`` it sets the detected density ``s``).
    nu_cyc_per_mm : array_like, (n,), cycles/mm on the plane ``z``, > 0, increasing
    z_um : float, optional
        The sensor plane's distance (default the focal length).
    filter_um : (centre, FWHM), um, optional
        A narrow-band filter (:func:`metafovea.radiometry.spectral_transmission`'s convention).
    efficiency : callable, optional
        ``eta(lambda_um)``, the focusing order's efficiency (default 1: an ideal lens).
    n_wavelengths, n_line : int
        Quadrature over the band and along the line.

    Returns
    -------
    MTFBound
    """
    nu = np.asarray(nu_cyc_per_mm, dtype=np.float64).ravel()
    if nu.size == 0 or np.any(~np.isfinite(nu)) or np.any(nu <= 0) or np.any(np.diff(nu) <= 0):
        raise InputError("nu_cyc_per_mm", "not > 0 and increasing", "increasing spatial frequencies > 0 cyc/mm")
    n_wavelengths = check_int("n_wavelengths", n_wavelengths, 101, 10**6)
    n_line = check_int("n_line", n_line, 101, 10**6)
    z = float(lens.f_um if z_um is None else z_um)
    lam = np.linspace(*check_band(band_um), n_wavelengths)
    s = detected_density(lam, band_um, temperature_k=temperature_k, filter_um=filter_um)
    eta = np.ones_like(lam) if efficiency is None else np.clip(np.asarray(efficiency(lam), dtype=float), 0.0, 1.0)
    weight = lam * s * eta
    radius = 0.5 * lens.diameter_um
    l_um = np.linspace(-radius, radius, n_line)
    nu_um = nu * 1e-3
    lam_h = lens.wavelength_um * lens.f_um / z  # the wavelength the plain hyperbola focuses on the plane z
    w_h = float(np.interp(lam_h, lam, weight, left=0.0, right=0.0))
    bound, hyper = np.empty(nu.size), np.empty(nu.size)
    for i, v in enumerate(nu_um):
        half_shear = 0.5 * lam * z * v
        inside = l_um[None, :] ** 2 + half_shear[:, None] ** 2 <= radius**2  # A(x + s/2) A(x - s/2) for a disk
        best = np.max(weight[:, None] * inside, axis=0)
        bound[i] = np.trapezoid(best, l_um) / (v * np.pi * radius**2)
        inside_h = l_um**2 + (0.5 * lam_h * z * v) ** 2 <= radius**2
        hyper[i] = w_h * np.trapezoid(inside_h.astype(float), l_um) / (v * np.pi * radius**2)
    bound, hyper = np.minimum(bound, 1.0), np.minimum(hyper, 1.0)
    both = (bound < 1.0) & (hyper > 0)
    gain = float(np.max(bound[both] / hyper[both])) if np.any(both) else 1.0
    grid = np.concatenate([[0.0], nu])
    area_b = float(np.trapezoid(np.concatenate([[1.0], bound]), grid) / nu[-1])
    area_h = float(np.trapezoid(np.concatenate([[1.0], hyper]), grid) / nu[-1])
    return MTFBound(nu, bound, hyper, float(lam[np.argmax(weight)]), gain, area_b, area_h)

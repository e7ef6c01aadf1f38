"""Spectral weights: Planck radiance of the scene (colour-science), spectral filter, sensor response.

Wavelengths in um, temperatures in kelvin. Importable by the imaging stage (no optics dependencies).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from metafovea.errors import InputError, check_int, check_positive

#: Default LWIR band (um).
BAND_UM = (8.0, 14.0)


def planck_radiance(wavelength_um: Any, temperature_k: float) -> np.ndarray:
    """Spectral radiance B_lambda(T) in W / (m^2 sr um) at wavelengths in um (colour-science's planck_law)."""
    from colour.colorimetry import planck_law

    wl = np.asarray(wavelength_um, dtype=float)
    if np.any(~np.isfinite(wl)) or np.any(wl <= 0):
        raise InputError("wavelength_um", wl.tolist() if wl.size < 8 else "array", "wavelengths > 0 um")
    t = check_positive("temperature_k", temperature_k, "K", hi=1e5)
    return np.asarray(planck_law(wl * 1e-6, t), dtype=float).reshape(wl.shape) * 1e-6  # per m -> per um


def photon_radiance(wavelength_um: Any, temperature_k: float) -> np.ndarray:
    """Spectral photon radiance (photons / (s m^2 sr um)): for photon-counting detectors."""
    h, c = 6.62607015e-34, 2.99792458e8
    wl = np.asarray(wavelength_um, dtype=float)
    return planck_radiance(wl, temperature_k) * (wl * 1e-6) / (h * c)


def check_band(band_um: Any, name: str = "band_um") -> tuple[float, float]:
    """(lo, hi) with 0 < lo < hi (um)."""
    try:
        lo, hi = (float(v) for v in band_um)
    except (TypeError, ValueError):
        raise InputError(name, band_um, "two numbers (lo, hi) in um") from None
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo <= 0:
        raise InputError(name, band_um, "0 < lo < hi (um)")
    if hi <= lo:
        raise InputError(name, band_um, "lo < hi (um): the band is reversed or empty")
    return lo, hi


def gaussian_filter(center_um: float, fwhm_um: float) -> Callable[[np.ndarray], np.ndarray]:
    """Transmission of a Gaussian narrow-band filter (peak 1)."""
    c = check_positive("filter_center_um", center_um, "um")
    w = check_positive("filter_width_um", fwhm_um, "um")
    sig = w / (2 * np.sqrt(2 * np.log(2)))
    return lambda wl: np.exp(-0.5 * ((np.asarray(wl, float) - c) / sig) ** 2)


def box_filter(lo_um: float, hi_um: float) -> Callable[[np.ndarray], np.ndarray]:
    lo, hi = check_band((lo_um, hi_um))
    return lambda wl: ((np.asarray(wl, float) >= lo) & (np.asarray(wl, float) <= hi)).astype(float)


def flat_response(wl: np.ndarray) -> np.ndarray:
    """A flat (thermal, bolometer-like) sensor response."""
    return np.ones_like(np.asarray(wl, dtype=float))


def spectral_weights(*, band_um: Any = BAND_UM, n: int = 61, temperature_k: float = 300.0,
                     filter_um: tuple[float, float] | None = None,
                     sensor_response: Callable[[np.ndarray], np.ndarray] | None = None,
                     photons: bool = False, cluster_um: float | None = None,
                     cluster_min_um: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Wavelengths (um) and normalised weights (sum 1) for a polychromatic PSF.

    Weight = Planck radiance at ``temperature_k`` x filter x sensor response x wavelength step
    (trapezoid). ``filter_um = (center, fwhm)``: a Gaussian filter; the wavelengths are then placed over
    center +- 1.5 fwhm (clipped to the band) so that the filter is resolved. ``cluster_um`` (the design
    wavelength) adds points log-spaced in distance from it, down to ``cluster_min_um`` (a fraction of the
    depth-of-focus bandwidth lambda0 * DOF / f), so that the near-focus wavelengths are not over- or
    under-weighted by a uniform grid that happens to hit (or miss) lambda0.
    """
    lo, hi = check_band(band_um)
    n = check_int("n_wavelengths", n, 1, 100000)
    filt = None
    if filter_um is not None:
        c, w = filter_um
        filt = gaussian_filter(c, w)
        lo2, hi2 = max(lo, c - 1.5 * w), min(hi, c + 1.5 * w)
        if hi2 <= lo2:
            raise InputError("filter_um", filter_um, f"a filter centre inside the band {lo:g}-{hi:g} um")
        lo, hi = lo2, hi2
    wl = np.array([0.5 * (lo + hi)]) if n == 1 else np.linspace(lo, hi, n)
    if cluster_um is not None and n > 1:
        # the PSF changes on the scale of the depth of focus near the design wavelength: add points
        # log-spaced in |lambda - lambda0| from cluster_min_um outwards so the spectral sum resolves it
        c0 = float(cluster_um)
        dmin = check_positive("cluster_min_um", cluster_min_um or 1e-3, "um")
        d = np.geomspace(dmin, max(hi - lo, 2 * dmin), max(8, n // 2))
        extra = np.concatenate([c0 - d[::-1], [c0], c0 + d])
        wl = np.unique(np.concatenate([wl, extra[(extra >= lo) & (extra <= hi)]]))
    b = photon_radiance(wl, temperature_k) if photons else planck_radiance(wl, temperature_k)
    if filt is not None:
        b = b * filt(wl)
    if sensor_response is not None:
        b = b * np.asarray(sensor_response(wl), dtype=float)
    if n > 1:
        dw = np.gradient(wl)
        dw[0] *= 0.5
        dw[-1] *= 0.5
        b = b * dw
    s = b.sum()
    if not s > 0:
        raise InputError("band_um", band_um, "a band where the weights (radiance x filter x response) are > 0")
    return wl, b / s

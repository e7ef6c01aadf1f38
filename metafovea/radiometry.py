"""The one radiometry of metafovea: Planck radiance, the band and filter model, spectral weights and the
wavelength bins of polychromatic PSFs. Used by ``metafovea psf`` (optics), ``metafovea simulate`` (imaging)
and ``metafovea validate``, so a lens is weighted the same way everywhere.

Wavelengths in um, temperatures in kelvin, radiance in W m^-2 sr^-1 (spectral: per um).

Model
-----
The sensor responds to the in-band radiance ``L(T) = integral B(lambda, T) w(lambda) d lambda`` with

* ``B``: Planck's spectral radiance (:func:`planck_radiance`, colour-science's ``planck_law`` per um);
* ``w(lambda) = band(lambda) * filter(lambda) * response(lambda)`` (:func:`spectral_transmission`):

  - ``band``: the optics' pass band ``band_um = (lo, hi)`` (``SystemDesign.band_um``, 8-14 um): a top-hat with
    raised-cosine edges of width ``min(0.1 um, (hi - lo) / 4)`` centred on ``lo`` and ``hi`` (half transmission
    at the stated limits, so the integrated width is ``hi - lo``; no window or package has a vertical edge);
  - ``filter``: an optional narrow-band filter ``filter_um = (centre, FWHM)``, a Gaussian (e.g. 10 um / 0.5 um);
  - ``response``: the microbolometer's relative spectral absorption (flat by default; a callable of um).

:func:`spectral_weights` tabulates ``w`` on a quadrature grid over its support (used for ``L(T)``,
:class:`BandRadiance`); :func:`psf_wavelengths` cuts the support into bins for a polychromatic PSF, weighted by
``B(lambda, T_scene) w(lambda)``, geometric in ``|lambda / lambda0 - 1|`` around the design wavelength where a
metalens' chromatic focal shift changes the PSF fastest. A surface of emissivity ``eps`` at ``T`` in
surroundings at ``T_refl`` has apparent radiance ``eps L(T) + (1 - eps) L(T_refl)`` (:meth:`BandRadiance.apparent`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.config import PAPER_BAND_UM, SystemDesign
from metafovea.errors import InputError, check_int, check_positive, check_range

log = logging.getLogger(__name__)

#: default LWIR band (um): the paper's
BAND_UM = PAPER_BAND_UM
#: highest temperature the radiance tables cover (K)
T_MAX_K = 3000.0
#: innermost PSF wavelength bin, as a relative distance from the design wavelength: 1e-4 is below a quarter of the
#: depth-of-focus bandwidth (lambda0 / (2 NA^2 f)) of both paper lenses (1.4e-4 for F/2 at 150 mm, 2.5e-4 for F/1
#: at 25 mm), so the near-focus wavelengths are resolved
PSF_BIN_MIN_REL = 1e-4

Response = Callable[[np.ndarray], np.ndarray]

#: the SI's defining constants (exact since 2019; the values of :mod:`scipy.constants`, whose import costs ~0.1 s
#: in every process): Planck's constant (J s), the speed of light (m/s), Boltzmann's constant (J/K)
PLANCK_J_S = 6.62607015e-34
LIGHT_SPEED_M_S = 299792458.0
BOLTZMANN_J_K = 1.380649e-23
#: Planck's radiation constants: 2 h c^2 (W m^2, per steradian) and h c / k (m K)
_C1_W_M2 = 2.0 * PLANCK_J_S * LIGHT_SPEED_M_S**2
_C2_M_K = PLANCK_J_S * LIGHT_SPEED_M_S / BOLTZMANN_J_K


def planck_radiance(wavelength_um: ArrayLike, temperature_k: ArrayLike) -> np.ndarray:
    """Planck spectral radiance ``B(lambda, T) = 2 h c^2 / lambda^5 / (exp(h c / (lambda k T)) - 1)`` in
    W m^-2 sr^-1 um^-1 (the SI's exact h, c and k).

    Written out rather than taken from colour-science's ``planck_law`` (the reference it is tested against, to
    1e-12): importing colour loads its plotting package, 1.2 s of every command's start for one formula.

    Parameters
    ----------
    wavelength_um : array_like, um
        Wavelengths > 0.
    temperature_k : array_like, K
        Temperatures >= 0 (0 K gives 0), broadcast against ``wavelength_um``.

    Returns
    -------
    ndarray, the broadcast shape, W m^-2 sr^-1 um^-1
    """
    lam = np.asarray(wavelength_um, dtype=np.float64)
    t = np.asarray(temperature_k, dtype=np.float64)
    if t.size and (np.any(t < 0) or not np.all(np.isfinite(t))):
        raise InputError("temperature_k", float(np.nanmin(t)) if np.any(t < 0) else "non-finite",
                         "finite temperatures >= 0 K")
    lam_b, _ = np.broadcast_arrays(lam, t)
    if lam_b.size and (not np.all(np.isfinite(lam_b)) or np.any(lam_b <= 0)):
        raise InputError("wavelength_um", float(np.nanmin(lam_b)), "finite wavelengths > 0 um")
    if not lam_b.size:
        return np.zeros(lam_b.shape)
    # evaluated on the unique values of the inputs and picked for the broadcast pairs (a table's (n_lambda, n_T)
    # grid has n_lambda + n_T distinct values, not n_lambda x n_T)
    ul, il = np.unique(lam, return_inverse=True)
    ut, it = np.unique(t, return_inverse=True)
    table = np.zeros((ul.size, ut.size))
    pos = ut > 0
    if np.any(pos):
        lam_m = ul[:, None] * 1e-6
        with np.errstate(over="ignore"):
            x = _C2_M_K / (lam_m * ut[None, pos])
            table[:, pos] = _C1_W_M2 / lam_m**5 / np.expm1(x) * 1e-6  # per m -> per um; expm1 -> inf gives 0
    return table[il.reshape(lam.shape), it.reshape(t.shape)]


def check_band(band_um: Sequence[float], name: str = "band_um") -> tuple[float, float]:
    """``(lo, hi)`` with ``0 < lo < hi`` (um), or an InputError naming ``name``."""
    try:
        lo, hi = (float(v) for v in band_um)
    except (TypeError, ValueError):
        raise InputError(name, band_um, "two numbers (lo, hi) in um") from None
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo <= 0:
        raise InputError(name, band_um, "0 < lo < hi (um)")
    if hi <= lo:
        raise InputError(name, band_um, "lo < hi (um): the band is reversed or empty")
    return lo, hi


def check_filter(filter_um: Sequence[float] | None, name: str = "filter_um") -> tuple[float, float] | None:
    """``(centre, FWHM)`` in um, both > 0, or None (no filter)."""
    if filter_um is None:
        return None
    try:
        c, w = (float(v) for v in filter_um)
    except (TypeError, ValueError):
        raise InputError(name, filter_um, "two numbers (centre, FWHM) in um") from None
    return check_positive(f"{name} centre", c, "um"), check_positive(f"{name} width", w, "um")


def band_edge_um(band_um: tuple[float, float]) -> float:
    """Width of the raised-cosine edges of the band (um)."""
    return min(0.1, 0.25 * (band_um[1] - band_um[0]))


def spectral_transmission(wavelength_um: ArrayLike, band_um: tuple[float, float] = BAND_UM, *,
                          filter_um: tuple[float, float] | None = None, response: Response | None = None) -> np.ndarray:
    """``w(lambda) = band x filter x response`` (dimensionless, peak <= 1 for a response <= 1); see module notes."""
    lam = np.asarray(wavelength_um, dtype=np.float64)
    lo, hi = check_band(band_um)
    edge = band_edge_um((lo, hi))
    w = np.ones_like(lam)
    for x in (lo - lam, lam - hi):
        s = np.clip(x / edge + 0.5, 0.0, 1.0)
        w = w * 0.5 * (1 + np.cos(np.pi * s))
    filt = check_filter(filter_um)
    if filt is not None:
        sig = filt[1] / (2 * np.sqrt(2 * np.log(2)))
        w = w * np.exp(-0.5 * ((lam - filt[0]) / sig) ** 2)
    if response is not None:
        r = np.asarray(response(lam), dtype=np.float64)
        if r.shape != lam.shape or np.any(r < 0) or not np.all(np.isfinite(r)):
            raise InputError("response", "callable", "a function of wavelength (um) returning finite values >= 0")
        w = w * r
    return w


def spectral_support_um(band_um: tuple[float, float] = BAND_UM, *,
                        filter_um: tuple[float, float] | None = None) -> tuple[float, float]:
    """The wavelength interval (um) that holds ``w``: the band plus one edge width on each side, narrowed to
    +-3 FWHM of the filter (weight < 4e-11 outside)."""
    lo, hi = check_band(band_um)
    edge = band_edge_um((lo, hi))
    a, b = lo - edge, hi + edge
    filt = check_filter(filter_um)
    if filt is not None:
        c, fw = filt
        a, b = max(a, c - 3 * fw), min(b, c + 3 * fw)
        if not a < b:
            raise InputError("filter_um", list(filt), f"a filter centre inside the band {lo:g}-{hi:g} um")
    return a, b


def spectral_weights(band_um: tuple[float, float] = BAND_UM, *, filter_um: tuple[float, float] | None = None,
                     response: Response | None = None, n: int = 241) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature grid over the support and ``w`` on it.

    Returns
    -------
    wavelengths_um : ndarray, shape (n,), um
    weights : ndarray, shape (n,), dimensionless ``band x filter x response`` (integrate with the trapezoid rule)
    """
    n = check_int("n_wavelengths", n, 2, 1_000_000)
    a, b = spectral_support_um(band_um, filter_um=filter_um)
    lam = np.linspace(a, b, n)
    w = spectral_transmission(lam, band_um, filter_um=filter_um, response=response)
    if not np.any(w > 0):
        raise InputError("band_um", list(band_um), "a band/filter/response combination with non-zero weight")
    return lam, w


def psf_wavelengths(band_um: tuple[float, float] = BAND_UM, *, design_um: float, temperature_k: float = 300.0,
                    filter_um: tuple[float, float] | None = None, response: Response | None = None,
                    n: int = 31) -> tuple[np.ndarray, np.ndarray]:
    """Wavelength bins of a polychromatic PSF and their weights (sum 1).

    Each bin's weight is the integral of ``B(lambda, T) w(lambda)`` over the bin (midpoint sub-samples, 8 per band
    edge width), its wavelength the weighted mean inside it. The bin edges are geometric in
    ``|lambda / design_um - 1|`` from :data:`PSF_BIN_MIN_REL` outwards on both sides of a central bin at the design
    wavelength, where the chromatic blur of a metalens changes fastest; uniform when the design wavelength is outside
    the support (or ``n < 3``).

    Returns
    -------
    wavelengths_um : ndarray, shape (m,), um, m <= n (bins without weight are dropped)
    weights : ndarray, shape (m,)
    """
    n = check_int("n_wavelengths", n, 1, 100_000)
    t = check_positive("temperature_k", temperature_k, "K", hi=1e5)
    design_um = check_positive("design_um", design_um, "um")
    lo, hi = spectral_support_um(band_um, filter_um=filter_um)
    if n >= 3 and lo < design_um < hi:
        # n bins: a central one over design_um (1 +- d0), then geometric steps out to the support's ends
        d_lo, d_hi = 1.0 - lo / design_um, hi / design_um - 1.0
        d0 = min(PSF_BIN_MIN_REL, 0.5 * d_lo, 0.5 * d_hi)
        n_left = (n + 1) // 2
        left = design_um * (1 - np.geomspace(d0, d_lo, n_left))[::-1]
        right = design_um * (1 + np.geomspace(d0, d_hi, n + 1 - n_left))
        edges = np.concatenate([left, right])
    else:
        edges = np.linspace(lo, hi, n + 1)
    # sub-samples per bin: 16, or 8 per band-edge width where a bin is wide (the raised-cosine edge resolved)
    m = int(min(4096, max(16, np.ceil(8 * float(np.max(np.diff(edges))) / band_edge_um(check_band(band_um))))))
    u = (np.arange(m) + 0.5) / m
    x = edges[:-1, None] + (edges[1:] - edges[:-1])[:, None] * u[None, :]
    with np.errstate(over="ignore", under="ignore"):
        f = spectral_transmission(x, band_um, filter_um=filter_um, response=response) * planck_radiance(x, t)
    wb = f.mean(1) * (edges[1:] - edges[:-1])
    lb = (f * x).sum(1) / np.maximum(f.sum(1), 1e-300)
    keep = wb > 0
    if not np.any(keep) or not wb[keep].sum() > 0:
        raise InputError("band_um", list(band_um), "a band where the weights (radiance x filter x response) are > 0")
    return lb[keep], wb[keep] / wb[keep].sum()


#: where :class:`BandRadiance`'s table switches from log-linear to a cubic spline of the 1 K quadrature grid (below,
#: the 8-14 um radiance is under 1e-13 W m^-2 sr^-1 and its logarithm too steep for a spline through the clamp)
SPLINE_FROM_K = 30.0


@dataclass(frozen=True)
class BandRadiance:
    """In-band radiance ``L(T)`` (W m^-2 sr^-1) of one spectral weighting, tabulated for fast conversion.

    ``wavelengths_um`` / ``weights`` are the grid and ``w`` of :func:`spectral_weights`; ``band_um``,
    ``filter_um`` and ``response`` the model they came from (kept so PSF bins use the same weighting).
    """

    wavelengths_um: np.ndarray
    weights: np.ndarray
    band_um: tuple[float, float] = BAND_UM
    filter_um: tuple[float, float] | None = None
    response: Response | None = None
    t_step_k: float = 0.05
    _t: np.ndarray = field(init=False, repr=False, compare=False)
    _l: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        from scipy.interpolate import CubicSpline

        t = np.arange(0.0, T_MAX_K + self.t_step_k, self.t_step_k)
        # radiance on a 1 K grid by quadrature, then interpolation in log space: a cubic spline from SPLINE_FROM_K up
        # (a log-linear one errs by ~|d^2 ln L / dT^2| / 8 K^2, growing as 1/T^3), log-linear below, where the
        # radiance is under 1e-13 of its 300 K value
        tc = np.arange(0.0, T_MAX_K + 1.0, 1.0)
        lc = self.exact(tc)
        with np.errstate(divide="ignore"):
            ll = np.log(np.maximum(lc, 1e-300))
        l_fine = np.exp(np.interp(t, tc[1:], ll[1:]))
        hi = tc >= SPLINE_FROM_K
        l_fine[t >= SPLINE_FROM_K] = np.exp(CubicSpline(tc[hi], ll[hi])(t[t >= SPLINE_FROM_K]))
        l_fine[t < 1.0] = np.interp(t[t < 1.0], [0.0, 1.0], [0.0, lc[1]])
        object.__setattr__(self, "_t", t)
        object.__setattr__(self, "_l", l_fine)

    @classmethod
    def from_band(cls, band_um: tuple[float, float] = BAND_UM, *, filter_um: tuple[float, float] | None = None,
                  response: Response | None = None) -> BandRadiance:
        lam, w = spectral_weights(band_um, filter_um=filter_um, response=response)
        return cls(lam, w, tuple(band_um), filter_um, response)

    @classmethod
    def for_system(cls, system: SystemDesign, *, filter_enabled: bool | None = None,
                   response: Response | None = None) -> BandRadiance:
        """The weighting of a :class:`~metafovea.config.SystemDesign` (its band and, if enabled, filter)."""
        return cls.from_band(system.band_um, filter_um=system_filter_um(system, filter_enabled), response=response)

    def psf_wavelengths(self, design_um: float, temperature_k: float = 300.0,
                        n: int = 31) -> tuple[np.ndarray, np.ndarray]:
        """:func:`psf_wavelengths` of this weighting."""
        return psf_wavelengths(self.band_um, design_um=design_um, temperature_k=temperature_k,
                               filter_um=self.filter_um, response=self.response, n=n)

    def exact(self, temperature_k: ArrayLike) -> np.ndarray:
        """Band radiance by trapezoidal quadrature over the wavelength grid (no table)."""
        t = np.asarray(temperature_k, dtype=np.float64)
        b = planck_radiance(self.wavelengths_um[:, None], t.reshape(1, -1))  # (n_lambda, n_T)
        return np.trapezoid(b * self.weights[:, None], self.wavelengths_um, axis=0).reshape(t.shape)

    def __call__(self, temperature_k: ArrayLike) -> np.ndarray:
        """``L(T)`` from the table (relative error < 1e-5 for T >= 100 K against :meth:`exact`,
        ``tests/test_radiometry.py``); temperatures in [0, 3000] K."""
        t = np.asarray(temperature_k, dtype=np.float64)
        if t.size:
            lo, hi = float(np.min(t)), float(np.max(t))
            if not (np.isfinite(lo) and np.isfinite(hi)) or lo < 0.0 or hi > T_MAX_K:
                raise InputError("temperature_k", lo if lo < 0 or not np.isfinite(lo) else hi,
                                 f"finite temperatures in [0, {T_MAX_K:g}] K")
        return np.interp(t, self._t, self._l)

    def temperature(self, radiance: ArrayLike) -> np.ndarray:
        """The brightness temperature (K) of in-band radiance ``radiance`` (W m^-2 sr^-1): the inverse of ``L(T)``
        on the same table (a black body at that temperature gives that radiance; below 0 or above the table's
        3000 K the result is NaN)."""
        lv = np.asarray(radiance, dtype=np.float64)
        out = np.interp(lv, self._l, self._t)
        return np.where((lv < 0) | (lv > self._l[-1]) | ~np.isfinite(lv), np.nan, out)

    def derivative(self, temperature_k: float) -> float:
        """dL/dT (W m^-2 sr^-1 K^-1) at one temperature (central difference of the quadrature)."""
        t = check_range("temperature_k", temperature_k, 1.0, T_MAX_K - 1.0)
        h = 0.01
        return float((self.exact(t + h) - self.exact(t - h)) / (2 * h))

    def apparent(self, temperature_k: ArrayLike, emissivity: ArrayLike = 1.0,
                 reflected_k: float = 293.15) -> np.ndarray:
        """``eps L(T) + (1 - eps) L(T_refl)`` (grey opaque surfaces)."""
        eps = np.asarray(emissivity, dtype=np.float64)
        if eps.size and (np.min(eps) < 0 or np.max(eps) > 1):
            raise InputError("emissivity", float(np.min(eps) if np.min(eps) < 0 else np.max(eps)),
                             "0 <= emissivity <= 1")
        l_t = self(temperature_k)
        if np.all(eps == 1.0):
            return l_t
        return eps * l_t + (1.0 - eps) * float(self(reflected_k))

    def summary(self) -> dict[str, Any]:
        lam, w = self.wavelengths_um, self.weights
        return {"wavelength_range_um": [float(lam[0]), float(lam[-1])],
                "mean_wavelength_um": float(np.trapezoid(lam * w, lam) / np.trapezoid(w, lam)),
                "L_300K_W_m2_sr": float(self(300.0)), "dL_dT_300K": self.derivative(300.0)}


def system_filter_um(system: SystemDesign, filter_enabled: bool | None = None) -> tuple[float, float] | None:
    """``(centre, FWHM)`` of a SystemDesign's filter when enabled (its own flag unless ``filter_enabled``)."""
    fe = system.filter_enabled if filter_enabled is None else bool(filter_enabled)
    return (float(system.filter_center_um), float(system.filter_bandwidth_um)) if fe else None

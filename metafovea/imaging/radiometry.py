"""In-band radiance from temperature (Planck's law via colour-science).

The sensor responds to the *effective in-band radiance*

    L(T) = integral B(lambda, T) w(lambda) d lambda          [W m^-2 sr^-1]

with ``B`` Planck's spectral radiance (colour-science's ``planck_law``, W m^-2 sr^-1 m^-1 converted to
per um) and ``w(lambda) = band(lambda) * filter(lambda) * response(lambda)``:

* ``band``: the optics' pass band (``SystemDesign.band_um``, e.g. 8-14 um), a top-hat with 0.1 um
  cosine edges (germanium window / sensor package).
* ``filter``: the optional narrow-band filter (centre and FWHM, e.g. 10 um / 0.5 um), a Gaussian.
* ``response``: the microbolometer's relative spectral absorption (flat by default; pass a callable).

A surface of emissivity ``eps`` at temperature ``T`` in surroundings at ``T_refl`` has apparent radiance
``eps L(T) + (1 - eps) L(T_refl)`` (opaque grey body, Kirchhoff). :class:`BandRadiance` tabulates ``L``
once (0.05 K steps) so a frame of temperatures converts with one ``np.interp``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from metafovea.errors import InputError, check_positive, check_range

log = logging.getLogger(__name__)

T_MAX_K = 3000.0


def planck_radiance_um(wavelength_um: Any, temperature_k: Any) -> np.ndarray:
    """Planck spectral radiance ``B(lambda, T)`` in W m^-2 sr^-1 um^-1 (colour-science's planck_law).

    Broadcasts ``wavelength_um`` against ``temperature_k``; 0 K gives 0.
    """
    from colour.colorimetry import planck_law

    lam = np.asarray(wavelength_um, dtype=np.float64)
    t = np.asarray(temperature_k, dtype=np.float64)
    if np.any(t < 0) or not np.all(np.isfinite(t)):
        raise InputError("temperature_k", float(np.nanmin(t)), "finite temperatures >= 0 K")
    lam_b, t_b = np.broadcast_arrays(lam, t)
    if np.any(lam_b <= 0):
        raise InputError("wavelength_um", float(lam_b.min()), "wavelengths > 0 um")
    # colour's planck_law returns the outer product (wavelengths x temperatures): evaluate it on the
    # unique values and pick the broadcast pairs
    ul, il = np.unique(lam_b, return_inverse=True)
    ut, it = np.unique(t_b, return_inverse=True)
    table = np.zeros((ul.size, ut.size))
    pos = ut > 0
    if np.any(pos):
        with np.errstate(over="ignore"):
            vals = np.asarray(planck_law(ul * 1e-6, ut[pos]), dtype=np.float64) * 1e-6
        table[:, pos] = vals.reshape(ul.size, int(pos.sum()))
    return table[il.reshape(-1), it.reshape(-1)].reshape(lam_b.shape)


def spectral_weights(band_um: tuple[float, float], *, filter_center_um: float | None = None,
                     filter_bandwidth_um: float | None = None,
                     response: Callable[[np.ndarray], np.ndarray] | None = None,
                     n: int = 241) -> tuple[np.ndarray, np.ndarray]:
    """Wavelength grid (um) and weights ``band x filter x response`` (dimensionless, peak <= 1).

    With a filter the grid is concentrated on +-3 FWHM around its centre (clipped to the band), so
    a 0.5 um filter is resolved with ``n`` samples as well as the whole band is.
    """
    lo, hi = (check_positive("band_um", b, "um") for b in band_um)
    if not lo < hi:
        raise InputError("band_um", list(band_um), "[low, high] with 0 < low < high")
    edge = min(0.1, 0.25 * (hi - lo))
    if filter_center_um is not None:
        c = check_positive("filter_center_um", filter_center_um, "um")
        fw = check_positive("filter_bandwidth_um", filter_bandwidth_um, "um")
        a, b = max(lo - edge, c - 3 * fw), min(hi + edge, c + 3 * fw)
        if not a < b:
            raise InputError("filter_center_um", c, f"a filter centre inside the band {lo:g}-{hi:g} um")
        lam = np.linspace(a, b, n)
    else:
        lam = np.linspace(lo - edge, hi + edge, n)
    # top-hat band with raised-cosine edges of width `edge`
    w = np.ones_like(lam)
    for side, x in (("lo", lo - lam), ("hi", lam - hi)):
        s = np.clip(x / edge + 0.5, 0.0, 1.0)
        w *= 0.5 * (1 + np.cos(np.pi * s))
    if filter_center_um is not None:
        sig = fw / (2 * np.sqrt(2 * np.log(2)))
        w = w * np.exp(-0.5 * ((lam - c) / sig) ** 2)
    if response is not None:
        r = np.asarray(response(lam), dtype=np.float64)
        if r.shape != lam.shape or np.any(r < 0) or not np.all(np.isfinite(r)):
            raise InputError("response", "callable", "a function of wavelength (um) returning finite values >= 0")
        w = w * r
    if not np.any(w > 0):
        raise InputError("band_um", list(band_um), "a band/filter/response combination with non-zero weight")
    return lam, w


@dataclass(frozen=True)
class BandRadiance:
    """Effective in-band radiance ``L(T)`` (W m^-2 sr^-1), tabulated for fast conversion.

    ``wavelengths_um`` / ``weights`` describe the spectral weighting (see module docstring).
    """

    wavelengths_um: np.ndarray
    weights: np.ndarray
    t_step_k: float = 0.05
    _t: np.ndarray = field(init=False, repr=False, compare=False)
    _l: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        t = np.arange(0.0, T_MAX_K + self.t_step_k, self.t_step_k)
        # radiance on a coarse 1 K grid by quadrature, then cubic-accurate interpolation in log space
        tc = np.arange(0.0, T_MAX_K + 1.0, 1.0)
        lc = self.exact(tc)
        with np.errstate(divide="ignore"):
            ll = np.log(np.maximum(lc, 1e-300))
        l_fine = np.exp(np.interp(t, tc[1:], ll[1:]))
        l_fine[t < 1.0] = np.interp(t[t < 1.0], [0.0, 1.0], [0.0, lc[1]])
        object.__setattr__(self, "_t", t)
        object.__setattr__(self, "_l", l_fine)

    @classmethod
    def for_system(cls, system: Any, *, filter_enabled: bool | None = None,
                   response: Callable[[np.ndarray], np.ndarray] | None = None) -> "BandRadiance":
        """The weighting of a :class:`~metafovea.config.SystemDesign` (its band and, if enabled, filter)."""
        fe = system.filter_enabled if filter_enabled is None else bool(filter_enabled)
        lam, w = spectral_weights(system.band_um,
                                  filter_center_um=system.filter_center_um if fe else None,
                                  filter_bandwidth_um=system.filter_bandwidth_um if fe else None,
                                  response=response)
        return cls(lam, w)

    def exact(self, temperature_k: Any) -> np.ndarray:
        """Band radiance by trapezoidal quadrature over the wavelength grid (no table)."""
        t = np.asarray(temperature_k, dtype=np.float64)
        b = planck_radiance_um(self.wavelengths_um[:, None], t.reshape(1, -1))  # (n_lambda, n_T)
        return np.trapezoid(b * self.weights[:, None], self.wavelengths_um, axis=0).reshape(t.shape)

    def __call__(self, temperature_k: Any) -> np.ndarray:
        """``L(T)`` from the table (relative error < 1e-5 for T >= 100 K). Temperatures must be in
        [0, 3000] K."""
        t = np.asarray(temperature_k, dtype=np.float64)
        if t.size:
            lo, hi = float(np.min(t)), float(np.max(t))
            if not (np.isfinite(lo) and np.isfinite(hi)) or lo < 0.0 or hi > T_MAX_K:
                raise InputError("temperature_k", lo if lo < 0 or not np.isfinite(lo) else hi,
                                 f"finite temperatures in [0, {T_MAX_K:g}] K")
        return np.interp(t, self._t, self._l)

    def derivative(self, temperature_k: float) -> float:
        """dL/dT (W m^-2 sr^-1 K^-1) at one temperature (central difference of the quadrature)."""
        t = check_range("temperature_k", temperature_k, 1.0, T_MAX_K - 1.0)
        h = 0.01
        return float((self.exact(t + h) - self.exact(t - h)) / (2 * h))

    def apparent(self, temperature_k: Any, emissivity: Any = 1.0, reflected_k: float = 293.15) -> np.ndarray:
        """``eps L(T) + (1 - eps) L(T_refl)`` (grey opaque surfaces)."""
        eps = np.asarray(emissivity, dtype=np.float64)
        if eps.size and (np.min(eps) < 0 or np.max(eps) > 1):
            raise InputError("emissivity", float(np.min(eps) if np.min(eps) < 0 else np.max(eps)), "0 <= emissivity <= 1")
        l_t = self(temperature_k)
        if np.all(eps == 1.0):
            return l_t
        return eps * l_t + (1.0 - eps) * float(self(reflected_k))

    def summary(self) -> dict[str, Any]:
        lam, w = self.wavelengths_um, self.weights
        return {"wavelength_range_um": [float(lam[0]), float(lam[-1])],
                "mean_wavelength_um": float(np.trapezoid(lam * w, lam) / np.trapezoid(w, lam)),
                "L_300K_W_m2_sr": float(self(300.0)), "dL_dT_300K": self.derivative(300.0)}

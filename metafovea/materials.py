"""Optical materials: refractive indices as constants or functions of wavelength.

Convention: ``exp(-i omega t)``, so an absorbing material has ``Im(n) > 0``. An index is accepted if
it is finite with ``Re(n) > 0`` and ``Im(n) >= 0`` (no gain). Lengths in micrometres.
"""

from __future__ import annotations

import numbers
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from metafovea.errors import InputError

#: Silicon at 10 um (the paper's value; weak dispersion over 8-12 um is neglected unless a table is given).
N_SI_10UM = 3.42
N_AIR = 1.0


@dataclass(frozen=True)
class Material:
    """A named material with index ``n(wavelength_um)``.

    ``index`` is a number (non-dispersive) or a callable of wavelength in um (array in, array out).
    """

    name: str
    index: complex | float | Callable[[np.ndarray], np.ndarray]

    def n(self, wavelength_um) -> np.ndarray:
        wl = np.asarray(wavelength_um, dtype=float)
        if callable(self.index):
            val = np.asarray(self.index(wl), dtype=complex)
        else:
            val = np.full(wl.shape, complex(self.index))
        return check_index(self.name, val)

    @classmethod
    def table(cls, name: str, wavelengths_um, n_values) -> Material:
        """Linearly interpolated table (real and imaginary parts separately); no extrapolation."""
        wl = np.asarray(wavelengths_um, dtype=float)
        nv = np.asarray(n_values, dtype=complex)
        if wl.ndim != 1 or wl.shape != nv.shape or wl.size < 2 or np.any(np.diff(wl) <= 0):
            raise InputError("wavelengths_um", wl.tolist(), "a strictly increasing 1-D table matching n_values")
        check_index(name, nv)

        def f(x):
            x = np.asarray(x, dtype=float)
            if np.any(x < wl[0]) or np.any(x > wl[-1]):
                raise InputError("wavelength_um", x.tolist(), f"within the {name} table {wl[0]:g}..{wl[-1]:g} um")
            return np.interp(x, wl, nv.real) + 1j * np.interp(x, wl, nv.imag)

        return cls(name, f)


SILICON = Material("Si", N_SI_10UM)
AIR = Material("air", N_AIR)

IndexLike = float | complex | Material


def check_index(name: str, n) -> np.ndarray:
    """Validate refractive index values (finite, Re > 0, Im >= 0); returns a complex array."""
    if isinstance(n, bool):
        raise InputError(name, n, "a refractive index (number with Re(n) > 0, Im(n) >= 0)")
    try:
        arr = np.asarray(n, dtype=complex)
    except (TypeError, ValueError):
        raise InputError(name, n, "a refractive index (number with Re(n) > 0, Im(n) >= 0)") from None
    if not np.all(np.isfinite(arr)) or np.any(arr.real <= 0) or np.any(arr.imag < 0):
        raise InputError(name, n if np.ndim(n) == 0 else arr.tolist(),
                         "finite refractive index with Re(n) > 0 and Im(n) >= 0 (exp(-i omega t): loss is Im > 0)")
    return arr


def index_of(name: str, value: IndexLike, wavelength_um) -> np.ndarray:
    """Index of ``value`` (number or :class:`Material`) at ``wavelength_um`` (broadcast)."""
    if isinstance(value, Material):
        return value.n(wavelength_um)
    if isinstance(value, numbers.Number) and not isinstance(value, bool):
        return check_index(name, np.full(np.shape(wavelength_um), complex(value)))
    if isinstance(value, np.ndarray):
        return check_index(name, np.broadcast_to(value, np.shape(wavelength_um)))
    raise InputError(name, value, "a refractive index number or a metafovea.materials.Material")


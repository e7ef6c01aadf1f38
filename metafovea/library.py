"""Scatterer library (RCWA sweeps of post widths) and the post sets chosen from it.

A :class:`PostSet` is what the later stages (lens, layout, optics) consume: the N posts actually used
by one lens, level ``k`` targeting the wrapped phase ``2 pi k / N`` for the lens' own polarisation.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.errors import InputError, check_int, check_positive, check_choice
from metafovea.io import atomic_save_npz, load_npz

POLARIZATIONS = ("x", "y")


@dataclass(frozen=True)
class PostSet:
    """N posts for one lens.

    Attributes
    ----------
    polarization: 'x' or 'y', the polarisation this lens focuses (the other passes through).
    period_um, height_um, wavelength_um: platform and design wavelength.
    widths_um: (N, 2) float, [wx, wy] side widths of level k's post (x and y extent, um).
    t_x, t_y: (N,) complex, zero-order field transmission for x- and y-polarised light (power
        normalised, exp(-i omega t); see metafovea.rcwa for reference planes).
    source: 'rcwa' (selected from a computed library) or 'ideal' (exact phases, unit transmission,
        widths a monotonic ramp: for layout and optics tests only; not a physical design).
    info: free-form numbers (phase errors, pass-through spread, efficiency estimates).
    """

    polarization: str
    period_um: float
    height_um: float
    wavelength_um: float
    widths_um: np.ndarray
    t_x: np.ndarray
    t_y: np.ndarray
    source: str = "rcwa"
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        check_choice("polarization", self.polarization, POLARIZATIONS)
        w = np.asarray(self.widths_um, dtype=float)
        if w.ndim != 2 or w.shape[1] != 2 or w.shape[0] < 2:
            raise InputError("widths_um", w.shape, "an (N, 2) array with N >= 2")
        if np.any(w <= 0) or np.any(w >= self.period_um):
            raise InputError("widths_um", w.tolist(), f"0 < width < period_um = {self.period_um:g}")
        object.__setattr__(self, "widths_um", w)
        object.__setattr__(self, "t_x", np.asarray(self.t_x, dtype=complex).reshape(-1))
        object.__setattr__(self, "t_y", np.asarray(self.t_y, dtype=complex).reshape(-1))
        if self.t_x.shape[0] != w.shape[0] or self.t_y.shape[0] != w.shape[0]:
            raise InputError("t_x/t_y", (self.t_x.shape, self.t_y.shape), f"length N = {w.shape[0]}")

    @property
    def levels(self) -> int:
        return int(self.widths_um.shape[0])

    @property
    def t_focus(self) -> np.ndarray:
        """(N,) transmission of the focusing polarisation."""
        return self.t_x if self.polarization == "x" else self.t_y

    @property
    def t_pass(self) -> np.ndarray:
        """(N,) transmission of the pass-through (other) polarisation."""
        return self.t_y if self.polarization == "x" else self.t_x

    @classmethod
    def ideal(cls, levels: int, *, period_um: float = 4.0, height_um: float = 10.0,
              wavelength_um: float = 10.0, polarization: str = "x") -> "PostSet":
        """Exact phases 2 pi k / N, unit transmission, pass-through phase 0; widths a ramp.

        The widths (0.2 p .. 0.85 p along the focusing axis, 0.5 p along the other) are not physical
        phase responses; use this for layout and optics tests that need a valid post set.
        """
        n = check_int("levels", levels, 2, 256)
        period_um = check_positive("period_um", period_um, "um")
        ramp = np.linspace(0.2, 0.85, n) * period_um
        other = np.full(n, 0.5 * period_um)
        pol = check_choice("polarization", polarization, POLARIZATIONS)
        widths = np.stack([ramp, other], 1) if pol == "x" else np.stack([other, ramp], 1)
        phases = 2 * np.pi * np.arange(n) / n
        t_f = np.exp(1j * phases)
        t_p = np.ones(n, dtype=complex)
        t_x, t_y = (t_f, t_p) if pol == "x" else (t_p, t_f)
        return cls(pol, period_um, float(height_um), float(wavelength_um), widths, t_x, t_y,
                   source="ideal", info={"note": "ideal phases; widths are a ramp, not a physical design"})

    def save(self, path: str | Path) -> Path:
        meta = {"type": "PostSet", "polarization": self.polarization, "period_um": self.period_um,
                "height_um": self.height_um, "wavelength_um": self.wavelength_um,
                "source": self.source, "info": self.info, "units": "um"}
        return atomic_save_npz(path, meta, widths_um=self.widths_um, t_x=self.t_x, t_y=self.t_y)

    @classmethod
    def load(cls, path: str | Path) -> "PostSet":
        arrays, meta = load_npz(path)
        if meta.get("type") != "PostSet":
            raise InputError("path", str(path), "a PostSet file written by PostSet.save")
        return cls(meta["polarization"], meta["period_um"], meta["height_um"], meta["wavelength_um"],
                   arrays["widths_um"], arrays["t_x"], arrays["t_y"], source=meta["source"],
                   info=meta.get("info", {}))

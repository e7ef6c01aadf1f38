"""The post set: the N posts one lens uses, and the checked loading of the library's files.

A :class:`PostSet` is what the later stages (lens, layout, optics) consume: level ``k`` targets the wrapped phase
``2 pi k / N`` for the lens' own polarisation. Polarisation naming (the paper's text and equations disagree on "s"
and "p"; we avoid both): 'x' is light with E along the lattice x axis, 'y' along y. The foveal lens focuses 'x' and
passes 'y'; the perifoveal lens focuses 'y' and passes 'x'.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from metafovea.config import PAPER_PERIOD_UM, PAPER_POST_HEIGHT_UM, PAPER_WAVELENGTH_UM, POLARIZATIONS
from metafovea.errors import InputError, check_choice, check_int, check_positive
from metafovea.io import atomic_save_npz, load_npz

if TYPE_CHECKING:
    from collections.abc import Sequence

    from matplotlib.axes import Axes
    from matplotlib.figure import Figure


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
    R_x, R_y: (N,) zero-order (specular) power reflectance back into the wafer, or None when unknown
        (an ideal set has 0; a file written before they were stored has None).
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
    R_x: np.ndarray | None = None
    R_y: np.ndarray | None = None

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
        for name in ("R_x", "R_y"):
            r = getattr(self, name)
            if r is not None:
                r = np.asarray(r, dtype=float).reshape(-1)
                if r.shape[0] != w.shape[0] or not np.all((r >= 0) & (r <= 1)):
                    raise InputError(name, r.tolist(), f"N = {w.shape[0]} reflectances in [0, 1]")
                object.__setattr__(self, name, r)

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

    def transmission(self, polarization: str) -> np.ndarray:
        """(N,) zero-order field transmission of ``polarization`` light."""
        return self.t_x if check_choice("polarization", polarization, POLARIZATIONS) == "x" else self.t_y

    def plot(self, ax: Axes | Sequence[Axes] | None = None) -> Figure:
        """Phase (rad) and power transmission of each level's post for both polarisations, and the posts'
        cross-sections (um).

        Parameters
        ----------
        ax : matplotlib Axes, sequence of 3 Axes, or None
            None: a new figure with the three panels; one Axes: the phase panel only.

        Returns
        -------
        matplotlib Figure
        """
        from metafovea.plotting import plot_postset

        return plot_postset(self, ax)

    def _repr_html_(self) -> str:
        from metafovea.plotting import postset_html

        return postset_html(self)

    def reflectance(self, polarization: str) -> tuple[np.ndarray, str]:
        """(N,) specular power reflectance back into the wafer for ``polarization`` light and where it comes
        from: the RCWA value, or ``1 - |t|^2`` (every loss taken as specular reflection: an upper bound) when
        the set does not carry it."""
        r = self.R_x if check_choice("polarization", polarization, POLARIZATIONS) == "x" else self.R_y
        if r is not None:
            return r, "ideal posts: none" if self.source == "ideal" else f"{self.source} zero-order reflection"
        return np.clip(1.0 - np.abs(self.transmission(polarization)) ** 2, 0.0, 1.0), "1 - |t|^2 (upper bound)"

    @classmethod
    def ideal(cls, levels: int, *, period_um: float = PAPER_PERIOD_UM, height_um: float = PAPER_POST_HEIGHT_UM,
              wavelength_um: float = PAPER_WAVELENGTH_UM, polarization: str = "x") -> PostSet:
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
                   source="ideal", info={"note": "ideal phases; widths are a ramp, not a physical design"},
                   R_x=np.zeros(n), R_y=np.zeros(n))

    def save(self, path: str | Path) -> Path:
        meta = {"type": "PostSet", "polarization": self.polarization, "period_um": self.period_um,
                "height_um": self.height_um, "wavelength_um": self.wavelength_um,
                "source": self.source, "info": self.info, "units": "um"}
        extra = {k: getattr(self, k) for k in ("R_x", "R_y") if getattr(self, k) is not None}
        return atomic_save_npz(path, meta, widths_um=self.widths_um, t_x=self.t_x, t_y=self.t_y, **extra)

    @classmethod
    def load(cls, path: str | Path, name: str = "path") -> PostSet:
        """Read a file written by :meth:`save`; errors name the file as ``name`` (a CLI passes its flag)."""
        arrays, meta = _load_checked(path, "PostSet", name)
        try:
            return cls(meta["polarization"], meta["period_um"], meta["height_um"], meta["wavelength_um"],
                       arrays["widths_um"], arrays["t_x"], arrays["t_y"], source=meta["source"],
                       info=meta.get("info", {}), R_x=arrays.get("R_x"), R_y=arrays.get("R_y"))
        except KeyError as e:
            raise InputError(name, str(path), "a PostSet file written by PostSet.save",
                             detail=f"missing {e.args[0]!r}") from None


def _load_checked(path: str | Path, kind: str, name: str = "path") -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """``load_npz`` of a file that must be a ``kind`` ('PostSet' or 'Library') file: anything else (a TOML
    passed by mistake, a truncated or pickled .npz) is an :class:`InputError`, not a numpy/zip traceback."""
    import zipfile

    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
    except OSError:
        magic = b"PK\x03\x04"  # let load_npz report a missing or unreadable file
    if magic != b"PK\x03\x04":
        raise InputError(name, str(path), f"a {kind} .npz file written by {kind}.save",
                         detail="not an .npz (zip) file") from None
    try:
        arrays, meta = load_npz(path, name)
    except InputError:
        raise
    except (ValueError, OSError, EOFError, KeyError, zipfile.BadZipFile, UnicodeDecodeError) as e:
        raise InputError(name, str(path), f"a {kind} .npz file written by {kind}.save",
                         detail=" ".join(str(e).split())[:120] or type(e).__name__) from None
    if not isinstance(meta, dict) or meta.get("type") != kind:
        raise InputError(name, str(path), f"a {kind} file written by {kind}.save")
    return arrays, meta


def postset_table(ps: PostSet) -> list[dict[str, float]]:
    """Per-level rows (for `metafovea design` and reports): widths, phases, transmissions."""
    rows = []
    for k in range(ps.levels):
        rows.append({"level": k, "wx_um": float(ps.widths_um[k, 0]), "wy_um": float(ps.widths_um[k, 1]),
                     "target_phase_rad": float(2 * np.pi * k / ps.levels),
                     "phase_focus_rad": float(np.angle(ps.t_focus[k]) % (2 * np.pi)),
                     "T_focus": float(abs(ps.t_focus[k]) ** 2),
                     "phase_pass_rad": float(np.angle(ps.t_pass[k])), "T_pass": float(abs(ps.t_pass[k]) ** 2)})
    return rows

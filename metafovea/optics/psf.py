"""Point spread functions of the metalenses on a fine grid: the :class:`PSF` type, :func:`psf` (the field PSF,
monochromatic or polychromatic) and :func:`encircled_energy_on_axis` (exact radial integral, no grid). The PSF
integrated over sensor pixels is :func:`metafovea.optics.sensor.sensor_psf`.

Normalisation: ``PSF.intensity[i, j]`` is the fraction of the power incident on the lens aperture (in the
polarisation considered, unit-intensity plane wave) that falls into sample cell (i, j) (a cell of
``pitch_um`` x ``pitch_um``); ``intensity.sum()`` is therefore the fraction that lands in the window and
equals ``energy_fraction``. Arrays are (H, W), row = y, x and y increasing with the index; the array
centre sits at ``center_um`` on the focal plane.

Engine choice (``engine='auto'``), per wavelength:

* ``hankel``  on axis, when the pupil is rotationally symmetric to within the requested error and the
  direction-sine (Debye) model is right to within it (:func:`debye_error_bound`). The model is corrected for the
  focal shift (:meth:`Pupil.li_wolf`: the amplitude, scale and defocus ``f'/z`` of a wavelength or plane away from
  focus, exact in the Fresnel approximation); what is left is the rim wave's phase beyond that approximation, which
  on the axis of a defocused PSF reaches O(0.1) of its peak for the F/1 lens at a few % of focal shift;
* ``mft``     on axis when the pupil is not rotationally symmetric (same model and bound);
* ``rs``      on axis where the Debye bound exceeds the requested error;
* ``rs``      off axis: the windowed exact Rayleigh-Sommerfeld engine over the hard-edged aperture
  (:mod:`metafovea.optics.rayleigh`). ``engine='mft'`` off axis is the direction-sine (Debye) model, which
  misses part of the aperture edge's diffraction there (0.6-5 % of the peak at 1-5 deg for the paper's
  lenses): its ``error_estimate`` is then ``inf`` (not bounded) and ``info['model_note']`` says why;
* ``geometric`` (sensor PSFs only, :mod:`metafovea.optics.sensor`).

A lens with a phase beyond the hyperbola (``LensDesign.phase_poly_rad``) goes to ``rs`` on and off axis: the
direction-sine model of such a lens (the stationary point of the full radial phase, :mod:`pupil`) misses the fine
structure of its defocused zones by tens of % of the peak (tests/optics/test_rayleigh.py), so ``hankel`` and ``mft``
asked for by name say so (``error_estimate`` ``inf``, ``info['model_note']``); a lens whose rays cross (ray
directions not monotone in radius) has no direction-sine pupil at all, and only ``rs`` takes it.

``error_estimate`` is the largest absolute intensity error relative to the PSF's peak, against the scalar
thin-element lens field propagated exactly (first Rayleigh-Sommerfeld integral over the aperture): quadrature,
Taylor remainders and the model of the engine. Not in it: vector (polarisation) effects at the rim, post
coupling beyond the library's periodic model, and the haze orders (reported separately as ``haze_power``).
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.config import LensDesign
from metafovea.errors import InputError, check_choice, check_int, check_positive, check_range
from metafovea.io import atomic_save_npz, jsonable, load_npz
from metafovea.library.postset import PostSet

from . import propagate as prop
from . import rayleigh
from .pupil import Pupil, PupilSet, build_pupils, design_na, field_direction, max_field_deg, ray_map_monotone

if TYPE_CHECKING:
    from collections.abc import Sequence

    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

log = logging.getLogger(__name__)

#: engine choices of psf and sensor_psf (the CLI's words; psf refuses 'geometric', sensor_psf 'rs')
ENGINES = ("auto", "hankel", "mft", "rs", "geometric")

#: What the direction-sine engine leaves out off axis (said in the result instead of a bound).
MFT_OFF_AXIS_NOTE = ("direction-sine (Debye) model off axis: part of the aperture edge's diffraction is not modelled "
                     "(0.6-5 % of the peak at 1-5 deg for the paper's lenses); error not bounded - use engine 'rs'")


#: What the direction-sine engines leave out for a lens with a phase beyond the hyperbola (said instead of a bound).
POLY_NOTE = ("direction-sine (Debye) or ray model of a lens with phase_poly_rad: the fine structure of its "
             "defocused zones is not modelled (against the exact Rayleigh-Sommerfeld integral: tens of % of the fine-"
             "grid peak for +-10 % of local focal length on a 1-2 mm lens); error not bounded - use engine 'rs' "
             "(what 'auto' picks)")


@dataclass(frozen=True)
class PSF:
    """A sampled PSF (see the module docstring for the normalisation)."""

    intensity: np.ndarray
    pitch_um: float
    center_um: tuple[float, float]
    wavelengths_um: np.ndarray
    weights: np.ndarray
    field_deg: tuple[float, float]
    polarization: str
    engine: str
    error_estimate: float
    energy_fraction: float
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        a = np.asarray(self.intensity, dtype=np.float64)
        if a.ndim != 2:
            raise InputError("intensity", a.shape, "a 2-D (H, W) array")
        object.__setattr__(self, "intensity", a)
        object.__setattr__(self, "wavelengths_um", np.atleast_1d(np.asarray(self.wavelengths_um, float)))
        object.__setattr__(self, "weights", np.atleast_1d(np.asarray(self.weights, float)))
        object.__setattr__(self, "center_um", tuple(float(v) for v in self.center_um))
        object.__setattr__(self, "field_deg", tuple(float(v) for v in self.field_deg))

    @property
    def shape(self) -> tuple[int, int]:
        return self.intensity.shape  # type: ignore[return-value]

    def coords(self) -> tuple[np.ndarray, np.ndarray]:
        """(xs, ys) of the sample centres on the focal plane (um)."""
        H, W = self.shape
        xs = self.center_um[0] + (np.arange(W) - 0.5 * (W - 1)) * self.pitch_um
        ys = self.center_um[1] + (np.arange(H) - 0.5 * (H - 1)) * self.pitch_um
        return xs, ys

    def centroid_um(self) -> tuple[float, float]:
        xs, ys = self.coords()
        s = self.intensity.sum()
        return float((self.intensity.sum(0) * xs).sum() / s), float((self.intensity.sum(1) * ys).sum() / s)

    def plot(self, ax: Axes | Sequence[Axes] | None = None, *, log: bool = True) -> Figure:
        """The PSF on the focal plane (x, y in um; colour bar in fraction of the incident power per um^2) and its
        cuts through the peak.

        Parameters
        ----------
        ax : matplotlib Axes, sequence of 2 Axes, or None
            None: a new figure with both panels; one Axes: the image only.
        log : bool
            Logarithmic colour scale over 4 decades below the peak (default); False: linear.

        Returns
        -------
        matplotlib Figure
        """
        from metafovea.plotting import plot_psf

        return plot_psf(self, ax, log=log)

    def _repr_html_(self) -> str:
        from metafovea.plotting import psf_html

        return psf_html(self)

    def save(self, path: str | Path) -> Path:
        meta = {"type": "PSF", "pitch_um": self.pitch_um, "center_um": list(self.center_um),
                "field_deg": list(self.field_deg), "polarization": self.polarization, "engine": self.engine,
                "error_estimate": self.error_estimate, "energy_fraction": self.energy_fraction,
                "info": jsonable(self.info), "units": "um; intensity = fraction of incident power per cell"}
        return atomic_save_npz(path, meta, intensity=self.intensity, wavelengths_um=self.wavelengths_um,
                               weights=self.weights)

    @classmethod
    def load(cls, path: str | Path) -> PSF:
        arrays, meta = load_npz(path)
        if meta.get("type") != "PSF":
            raise InputError("path", str(path), "a PSF file written by PSF.save")
        return cls(arrays["intensity"], meta["pitch_um"], tuple(meta["center_um"]), arrays["wavelengths_um"],
                   arrays["weights"], tuple(meta["field_deg"]), meta["polarization"], meta["engine"],
                   meta["error_estimate"], meta["energy_fraction"], meta.get("info", {}))


# ----------------------------------------------------------------------------------------------
# input checks
# ----------------------------------------------------------------------------------------------
def _field_pair(field_deg: ArrayLike) -> tuple[float, float]:
    s = field_direction(field_deg)  # validates
    del s
    if np.ndim(field_deg) == 0:
        return float(field_deg), 0.0
    a = np.asarray(field_deg, float).reshape(-1)
    return float(a[0]), float(a[1])


def _no_focus_error(lens: LensDesign, wl: np.ndarray, polarization: str | None) -> None:
    """Raise the InputError for a PSF whose focusing order vanishes at every wavelength.

    For the lens' own polarisation that happens where the wrapped phase is a whole number of extra
    turns per zone (lambda0 / lambda an integer other than 1, e.g. lambda0 / 2): the light goes into
    another order. For the pass-through polarisation a lens with a level-independent t_pass focuses
    nothing.
    """
    if polarization is None or polarization == lens.polarization:
        shown = wl.tolist() if wl.size < 6 else f"{wl.size} wavelengths {wl.min():g}-{wl.max():g}"
        raise InputError("wavelengths_um", shown,
                         f"a wavelength at which the focusing order of lens '{lens.name}' (lambda0 = "
                         f"{lens.wavelength_um:g} um) carries light: its efficiency is 0 where lambda0 / lambda "
                         "is an integer other than 1 (e.g. lambda0 / 2)")
    raise InputError("polarization", polarization, "a polarisation with a focusing component")


def check_wavelengths(lens: LensDesign, wavelengths_um: ArrayLike | None,
                      weights: ArrayLike | None) -> tuple[np.ndarray, np.ndarray]:
    """Wavelength array (um, > 0) and weights (>= 0, normalised to sum 1)."""
    if wavelengths_um is None:
        wl = np.array([lens.wavelength_um])
    else:
        try:
            wl = np.atleast_1d(np.asarray(wavelengths_um, dtype=float)).reshape(-1)
        except (TypeError, ValueError):
            raise InputError("wavelengths_um", wavelengths_um, "positive numbers (um)") from None
    if wl.size == 0 or np.any(~np.isfinite(wl)) or np.any(wl <= 0) or np.any(wl > 1e4):
        raise InputError("wavelengths_um", wl.tolist() if wl.size < 10 else f"array of {wl.size}",
                         "wavelengths 0 < lambda <= 1e4 um")
    if weights is None:
        w = np.full(wl.size, 1.0 / wl.size)
    else:
        try:
            w = np.atleast_1d(np.asarray(weights, dtype=float)).reshape(-1)
        except (TypeError, ValueError):
            raise InputError("weights", weights, "non-negative numbers, one per wavelength") from None
        if w.size != wl.size or np.any(~np.isfinite(w)) or np.any(w < 0) or not w.sum() > 0:
            raise InputError("weights", w.tolist() if w.size < 10 else f"array of {w.size}",
                             f"{wl.size} non-negative numbers with a positive sum")
        w = w / w.sum()
    return wl, w


def _check_field(lens: LensDesign, field_deg: ArrayLike, wl: np.ndarray) -> None:
    s0 = field_direction(field_deg)
    lim = max_field_deg(lens, float(wl.max()))
    ang = math.degrees(math.asin(min(1.0, float(np.hypot(*s0)))))
    if ang > lim:
        raise InputError("field_deg", field_deg,
                         f"|field| <= {lim:.3f} deg for lens '{lens.name}' (NA {lens.na:.4f}) at "
                         f"{wl.max():g} um: beyond it the rim of the lens sends light into evanescent directions")


def checked_inputs(lens: LensDesign, *, wavelengths_um: ArrayLike | None, weights: ArrayLike | None, error: float,
                   engine: str, refused: str, allowed: str, field_deg: ArrayLike, post_set: PostSet | None,
                   polarization: str | None, quantize: bool, lattice: bool, z_um: float | None
                   ) -> tuple[np.ndarray, np.ndarray, float, str, tuple[float, float], list[PupilSet]]:
    """The input checks psf() and sensor_psf() share: (wavelengths, weights, error, engine, field pair, the
    pupil sets per wavelength). ``refused``: the engine this caller does not run (``allowed`` says what it does)."""
    if not isinstance(lens, LensDesign):  # a name or a path: Python's AttributeError deep in the pupil otherwise
        raise InputError("lens", lens if isinstance(lens, (str, Path)) else type(lens).__name__,
                         "a LensDesign (load_lens(path) reads a lens file)")
    if post_set is not None and not hasattr(post_set, "polarization"):
        raise InputError("post_set", type(post_set).__name__, "a PostSet (or None: ideal posts)")
    wl, w = check_wavelengths(lens, wavelengths_um, weights)
    error = check_range("error", error, 0.0, 0.5)
    engine = check_choice("engine", engine, ENGINES)
    if engine == refused:
        raise InputError("engine", engine, allowed)
    _check_field(lens, field_deg, wl)
    fpair = _field_pair(field_deg)
    sets = [build_pupils(lens, float(l), field_deg=field_deg, post_set=post_set, polarization=polarization,
                         quantize=quantize, lattice=lattice, z_um=z_um) for l in wl]
    return wl, w, error, engine, fpair, sets


def _centre(center_um: Any) -> np.ndarray:
    """``center_um`` as a finite ``(x, y)`` in um, else an InputError naming it."""
    try:
        c = np.asarray(center_um, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        c = np.full(3, np.nan)
    if c.shape != (2,) or not np.all(np.isfinite(c)):
        raise InputError("center_um", center_um, "a finite (x, y) in um on the focal plane")
    return c


def diffraction_radius_um(lens: LensDesign) -> float:
    """First-zero radius of the focusing order (um): 0.61 lambda0 / NA, the same at every wavelength."""
    return 0.60983 * lens.wavelength_um / lens.na


def depth_of_focus_um(lens: LensDesign) -> float:
    """Half-width of the focal depth (um): 2 lambda0 (f/D)^2 (+-80 um for the F/2 lens, +-20 um for F/1)."""
    return 2.0 * lens.wavelength_um * (lens.f_um / lens.diameter_um) ** 2


def defocus_note(lens: LensDesign, z_um: float) -> str | None:
    """A warning line when the lens-to-sensor distance ``z_um`` is beyond the depth of focus (None otherwise)."""
    dz = float(z_um) - lens.f_um
    dof = depth_of_focus_um(lens)
    if abs(dz) <= dof:
        return None
    return (f"lens '{lens.name}': lens-to-sensor distance {z_um / 1000:g} mm differs from its focal length "
            f"{lens.f_mm:g} mm by {dz:+.1f} um, beyond the depth of focus +-{dof:.1f} um: the PSFs are defocused")


def nyquist_pitch_um(lens: LensDesign) -> float:
    """Largest sample pitch that samples the intensity without aliasing: lambda0 / (4 NA) (with ``phase_poly_rad``
    the pupil's radius in design direction sines, :func:`metafovea.optics.pupil.design_na`, instead of the NA)."""
    return lens.wavelength_um / (4.0 * design_na(lens))


# ----------------------------------------------------------------------------------------------
# one wavelength on a grid
# ----------------------------------------------------------------------------------------------
def debye_error_bound(pupil: Pupil) -> float:
    """Bound on the direction-sine (Debye) engines' intensity error on axis at defocus, relative to the PSF's own
    peak, with their focal-shift correction (:meth:`Pupil.li_wolf`, exact in the Fresnel approximation). Two parts:
    (i) the rim wave ``U_r`` (``|U_r|^2`` at most the peak) is off in phase by ``delta``
    (:meth:`Pupil.rim_phase_error`, what the correction leaves), so ``|dU| <= t |U_r|``, ``t = 2 |sin(delta / 2)|``,
    and ``|dI| <= 2 |U| |dU| + |dU|^2 <= (2 t + t^2) x peak``; (ii) the amplitude ``(f'/z)^2`` and the scale
    ``f'/z`` beyond the Fresnel approximation, ``2 |e| NA^2`` of the peak each (:meth:`Pupil.focal_shift_ratio`
    ``e``: the corrected terms times the paraxial expansion's next order). 0 in focus; tested against the exact
    engine on lenses and wavelengths it was not derived on (tests/optics/test_psf.py)."""
    t, scale = debye_error_parts(pupil)
    return 2.0 * t + t * t + scale


def debye_error_parts(pupil: Pupil) -> tuple[float, float]:
    """The two parts of :func:`debye_error_bound`: ``t = 2 |sin(delta / 2)|`` of the rim wave and the amplitude and
    scale part ``4 |e| NA^2`` (relative to the peak), which :func:`metafovea.optics.sensor.debye_pixel_error` also
    integrates over pixels."""
    t = 2.0 * abs(math.sin(0.5 * pupil.rim_phase_error()))
    return t, 4.0 * abs(pupil.focal_shift_ratio()) * pupil.lens.na ** 2


def _wave_engine(pupil: Pupil, xs: np.ndarray, ys: np.ndarray, error: float, engine: str) -> tuple[str, float]:
    """(engine, cost) for a wave-optical evaluation at this pupil and grid."""
    on_axis = float(np.hypot(*pupil.s0)) == 0.0
    if engine == "auto" and (pupil.lens.phase_poly_rad or (on_axis and debye_error_bound(pupil) > error)):
        # the direction-sine model is not bounded for such lenses, or its rim wave is off at this defocus
        return "rs", float(xs.size * ys.size)
    aniso = pupil.lattice_anisotropy()
    if engine == "hankel" or (engine == "auto" and on_axis and aniso * 0.1 <= error):
        if not on_axis:
            raise InputError("engine", engine, "'hankel' only on axis (field_deg = 0)")
        return "hankel", float(xs.size * ys.size / 8 * prop.hankel_nodes(pupil, 1.0, error))
    nt, nr = prop.mft_nodes(pupil, xs, ys, error * 1e-3)
    cost = float(nt * nr * xs.size + nt * xs.size * ys.size)
    if engine == "rs" or (engine == "auto" and not on_axis):
        return "rs", cost
    return "mft", cost


def focus_intensity(pupil: Pupil, xs: np.ndarray, ys: np.ndarray, *, error: float = 1e-4,
                    engine: str = "auto", debye: bool = True) -> tuple[np.ndarray, str, float]:
    """Intensity (power per um^2 for unit incident intensity) of the focusing order on the grid.

    Returns (I, engine, error estimate relative to the ideal in-focus peak); ``inf`` where the engine's model
    is not bounded (the direction-sine engine off axis). ``debye=False`` leaves the direction-sine model's defocus
    term (:func:`debye_error_bound`) out of the estimate, for a caller that bounds it over pixels instead.
    """
    eng, _ = _wave_engine(pupil, xs, ys, error, engine)
    model, m = pupil.li_wolf() if eng != "rs" else (pupil, 1.0)  # the direction-sine model's focal shift on axis
    if eng == "hankel":
        U = prop.hankel_grid(model, m * xs, m * ys, error=error * 1e-3)
        est = 0.1 * pupil.lattice_anisotropy() + error * 1e-3
    elif eng == "rs":
        U, info = rayleigh.rs_field(pupil, xs, ys, error=error)
        est = info["intensity_error"] / _ideal_peak(pupil)
    else:
        U = prop.mft_field(model, m * xs, m * ys, error=error * 1e-3)
        est = error * 1e-3 if float(np.hypot(*pupil.s0)) == 0.0 else math.inf
    intensity = (m * m) * (U.real ** 2 + U.imag ** 2)
    if eng != "rs" and pupil.lens.phase_poly_rad:
        est = math.inf  # the Debye model of an aberrated lens: POLY_NOTE
    elif debye and eng != "rs" and intensity.size:  # the rim wave at defocus, relative to this PSF's own peak
        est += debye_error_bound(pupil) * float(intensity.max()) / _ideal_peak(pupil)
    return intensity, eng, est


def _ideal_peak(pupil: Pupil) -> float:
    """In-focus on-axis peak intensity of an aberration-free pupil with this support (upper bound)."""
    lens = pupil.lens
    a = pupil.alpha
    if lens.phase_poly_rad:
        # int |P| d^2 s = (2 pi / (lambda alpha)) int_0^R sqrt(rho g g') d rho (pupil.py's amplitude and Jacobian)
        from metafovea.lens import direction_sine_over_r, direction_sine_slope  # lens stage (rank 3): allowed

        x, wq = prop._gl(256)
        rho = 0.5 * lens.radius_um * (x + 1.0)
        dens = rho * np.sqrt(np.abs(direction_sine_over_r(lens, rho) * direction_sine_slope(lens, rho)))
        val = 2 * math.pi / (pupil.wavelength_um * a) * 0.5 * lens.radius_um * float(wq @ dens)
        return (abs(pupil.amplitude_factor) * val) ** 2
    # |int P d^2s| with |P| = f0 alpha / (lambda c_w^2) over |w| <= NA: (pi f0 / (lambda alpha)) (-ln(1-NA^2))
    val = math.pi * lens.f_um / (pupil.wavelength_um * a) * (-math.log(1.0 - lens.na ** 2))
    return (abs(pupil.amplitude_factor) * val) ** 2


def _diffraction_limited_peak(pupil: Pupil) -> float:
    """Peak intensity of the aberration-free pupil with this pupil's amplitude (lattice factor included):
    ``|int |P| d^2 s|^2`` by Gauss quadrature over the disk (the Strehl ratio's denominator). For a lens whose ray
    map is not monotone (no pupil amplitude in direction sines) the ideal peak without the lattice factor."""
    if not ray_map_monotone(pupil.lens):
        return _ideal_peak(pupil)
    u, v, wq = prop.disk_nodes(np.zeros(2), pupil.radius, 48, 48)
    vv = np.broadcast_to(v[:, None], u.shape)
    return float(np.sum(wq * np.abs(pupil.amplitude(pupil.s0[0] + u, pupil.s0[1] + vv)))) ** 2


def _auto_window(pupils: list[Pupil], lens: LensDesign, margin_um: float) -> tuple[np.ndarray, float]:
    """Centre and half-size (um) of a window holding every ray plus a diffraction margin."""
    boxes = np.array([prop.ray_extent(p) for p in pupils])
    x0, x1 = boxes[:, 0].min(), boxes[:, 1].max()
    y0, y1 = boxes[:, 2].min(), boxes[:, 3].max()
    c = np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1)])
    half = max(x1 - x0, y1 - y0) / 2 + margin_um
    return c, half


def psf(lens: LensDesign, *, wavelengths_um: ArrayLike | None = None, weights: ArrayLike | None = None,
        field_deg: float | tuple[float, float] = 0.0, window_um: float | None = None,
        center_um: tuple[float, float] | None = None,
        pitch_um: float | None = None, post_set: PostSet | None = None, polarization: str | None = None,
        quantize: bool = False, lattice: bool = False, z_um: float | None = None, error: float = 1e-4,
        engine: str = "auto", allow_truncation: bool = False, max_samples: int = 1200) -> PSF:
    """Wave-optical PSF of the focusing order on a fine square grid.

    Defaults model the continuous-phase lens (``quantize=False, lattice=False``); set them (or pass a
    post set) for the fabricated lens: the focal peak then drops by the order efficiency. The window is
    centred on the geometric spot and sized from the ray aberration plus 8 diffraction radii unless
    ``window_um`` (full width) is given; ``pitch_um`` defaults to a third of the diffraction radius
    (below the intensity Nyquist pitch lambda0/(4 NA)).

    Raises :class:`InputError` for bad input and :class:`metafovea.optics.propagate.SamplingError` when
    ``pitch_um`` undersamples the intensity or ``window_um`` truncates the PSF above ``error`` (unless
    ``allow_truncation``).

    Parameters
    ----------
    lens : LensDesign
    wavelengths_um, weights : array_like, shape (K,), um and relative weights, optional
        Polychromatic PSF as the weighted sum (default: the design wavelength alone).
    field_deg : float or (float, float), deg
        Field angle of the source (one number: along x).
    window_um, pitch_um : float, um, optional
        Full width of the square window and the sample pitch (defaults: see above).
    center_um : (float, float), um, optional
        Centre of the window on the focal plane (default: the geometric spot).
    post_set : PostSet, optional
        The fabricated lens' posts: each level's transmission (amplitude and phase) sets the focusing order's
        strength (the quantised lens, whatever ``quantize``); default: ideal posts when ``quantize``.
    polarization : {'x', 'y'}, optional
        Incident polarisation (default: the lens' own).
    quantize, lattice, z_um : bool, bool, float (um, optional)
        Quantise the phase to the lens' levels; sample it on the post lattice; plane distance (default f).
    error, engine, allow_truncation, max_samples : float, {'auto', 'hankel', 'mft', 'rs'}, bool, int
        Requested error (relative to the peak), engine, truncation accepted, most samples per side.

    Returns
    -------
    PSF
        ``intensity`` ``(n, n)``: fraction of the incident power per sample cell of ``pitch_um`` x ``pitch_um``;
        the engine, the error estimate and the energy in the window (see the module docstring).
    """
    t0 = time.perf_counter()
    wl, w, error, engine, fpair, sets = checked_inputs(
        lens, wavelengths_um=wavelengths_um, weights=weights, error=error, engine=engine, refused="geometric",
        allowed="'auto', 'hankel', 'mft' or 'rs' for a fine-grid PSF (geometric: sensor_psf)", field_deg=field_deg,
        post_set=post_set, polarization=polarization, quantize=quantize, lattice=lattice, z_um=z_um)
    pupils = [s.focus for s in sets if s.focus is not None]
    if not pupils:
        _no_focus_error(lens, wl, polarization)
    r_diff = diffraction_radius_um(lens)
    nyq = nyquist_pitch_um(lens)
    if pitch_um is None:
        pitch = min(nyq, r_diff / 3.0)
    else:
        pitch = check_positive("pitch_um", pitch_um, "um")
        if pitch > nyq * (1 + 1e-9):
            raise prop.SamplingError("pitch_um", pitch, f"<= lambda0/(4 NA) = {nyq:.4g} um (the intensity's "
                                     "Nyquist pitch); use sensor_psf for pixel-integrated PSFs")
    c_auto, half_auto = _auto_window(pupils, lens, 8 * r_diff)
    c = c_auto if center_um is None else _centre(center_um)
    if window_um is None:
        half = half_auto
        if center_um is not None:
            half += float(np.abs(c - c_auto).max())
    else:
        half = 0.5 * check_positive("window_um", window_um, "um")
        if half < 2 * r_diff:
            raise prop.SamplingError("window_um", window_um,
                                     f">= {4 * r_diff:.3g} um (4 diffraction radii) to resolve the PSF core")
    n = int(math.ceil(2 * half / pitch))
    n += (n % 2 == 0)
    if n > max_samples:
        raise prop.SamplingError("window_um", 2 * half, f"a window of at most {max_samples} samples at "
                                 f"{pitch:.3g} um (= {max_samples * pitch:.4g} um); the aberrated PSF needs "
                                 f"{2 * half:.4g} um: use sensor_psf (pixel grid) or a coarser window")
    ax = (np.arange(n) - (n - 1) / 2) * pitch
    xs, ys = c[0] + ax, c[1] + ax
    total = np.zeros((n, n))
    engines, est = [], 0.0
    ideal_peak = 0.0
    dl_peak = 0.0
    for wi, s in zip(w, sets):
        if s.focus is None:
            continue
        I, eng, e = focus_intensity(s.focus, xs, ys, error=error, engine=engine)
        ip = _ideal_peak(s.focus)
        ideal_peak = max(ideal_peak, ip)
        dl_peak += wi * _diffraction_limited_peak(s.focus)
        total += wi * I
        est = math.inf if math.isinf(e) or math.isinf(est) else est + wi * e * ip
        engines.append(eng)
    P_in = math.pi * lens.radius_um ** 2
    inten = total * pitch * pitch / P_in
    peak = float(inten.max())
    est_rel = est * pitch * pitch / P_in / peak if peak > 0 else float("inf")
    edge = max(inten[0].max(), inten[-1].max(), inten[:, 0].max(), inten[:, -1].max()) / peak
    if window_um is not None and edge > error and not allow_truncation:
        raise prop.SamplingError("window_um", window_um,
                                 f">= {2 * half_auto:.4g} um for error {error:g}: the PSF at the window edge is "
                                 f"{edge:.2g} of its peak (pass allow_truncation=True to accept)")
    eng_name = "+".join(sorted(set(engines)))
    info = {"window_um": float(n * pitch), "samples": n, "edge_to_peak": float(edge),
            "engines": engines, "seconds": time.perf_counter() - t0, "requested_error": error,
            "order_efficiency": [s.info["order_efficiency"] for s in sets],
            "haze_power": [s.info["haze_power"] for s in sets], "quantize": quantize, "lattice": lattice,
            "ideal_peak_fraction": ideal_peak * pitch * pitch / P_in,
            "diffraction_limited_peak_fraction": dl_peak * pitch * pitch / P_in,
            "chief_ray_um": pupils[0].chief_ray_um().tolist(), "z_um": pupils[0].z_um,
            "error_definition": "max abs intensity error / PSF peak against the exact (Rayleigh-Sommerfeld) "
                                "propagation of the thin-element lens field"}
    if math.isinf(est_rel):
        info["model_note"] = POLY_NOTE if lens.phase_poly_rad and "rs" not in engines else MFT_OFF_AXIS_NOTE
    log.info("psf %s: %s, %d^2 samples at %.3g um, %.3f s", lens.name, eng_name, n, pitch, info["seconds"])
    return PSF(inten, pitch, (float(c[0]), float(c[1])), wl, w, fpair, sets[0].info["polarization"],
               eng_name, float(max(est_rel, 1e-16)), float(inten.sum()), info)


#: the phase (rad) of |U|^2 r over one radial panel of :func:`encircled_energy_on_axis` when an interval is split
#: (nodes_for_phase gives ~64 nodes for it at 1e-10)
EE_PANEL_PHASE_RAD = 60.0


def _radial_nodes(edges: np.ndarray, n: int, k_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss nodes, weights and interval index over ``[edges[j], edges[j+1]]``: ``n`` nodes on an interval whose
    ``|U|^2 r`` (phase slope up to ``2 k_s``) ``n`` nodes resolve, else panels of :data:`EE_PANEL_PHASE_RAD`."""
    rs, ws, js = [], [], []
    for j, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
        beta = k_s * (b - a)  # 2 k_s times the half-width
        if prop.nodes_for_phase(beta, 1e-10) <= n:
            m, q = 1, n
        else:
            m = int(math.ceil(beta / EE_PANEL_PHASE_RAD))
            q = prop.nodes_for_phase(beta / m, 1e-10)
        x, gw = prop._gl(q)
        lo = a + (b - a) * np.arange(m) / m
        h = 0.5 * (b - a) / m
        rs.append((lo[:, None] + h * (x[None, :] + 1.0)).ravel())
        ws.append(np.tile(h * gw, m))
        js.append(np.full(m * q, j))
    return np.concatenate(rs), np.concatenate(ws), np.concatenate(js)


def encircled_energy_on_axis(lens: LensDesign, radius_um: ArrayLike, *, wavelengths_um: ArrayLike | None = None,
                             weights: ArrayLike | None = None, post_set: PostSet | None = None, quantize: bool = True,
                             lattice: bool = True, z_um: float | None = None, n: int = 400) -> float | np.ndarray:
    """Fraction of the incident power within ``radius_um`` of the axis for an on-axis source (exact).

    Radial Gauss quadrature of the batched Hankel profiles of every wavelength's focusing order (lattice
    factor azimuthally averaged) plus the haze orders (uniform disks). No pixel grid involved. ``radius_um``: a
    number (returns a float) or an array of radii (returns an array; one Hankel pass for all of them: ``n``
    Gauss nodes on [0, r_1] and on each interval between consecutive sorted radii). An interval wider than ``n``
    nodes resolve (``|U|^2 r`` oscillates at up to twice the pupil's band limit ``k S``: the Gauss-Legendre count
    for that phase, :func:`~metafovea.optics.propagate.nodes_for_phase`, exceeds ``n``) is split into panels of a
    phase of :data:`EE_PANEL_PHASE_RAD` each, with that count's nodes on each.
    """
    scalar = np.ndim(radius_um) == 0
    radii = np.atleast_1d(np.asarray(radius_um, dtype=float)).reshape(-1)
    for r0 in radii:
        check_positive("radius_um", float(r0), "um")
    wl, w = check_wavelengths(lens, wavelengths_um, weights)
    sets = [build_pupils(lens, float(l), post_set=post_set, quantize=quantize, lattice=lattice, z_um=z_um)
            for l in wl]
    n = check_int("n", n, 8, 100000)
    order = np.argsort(radii)
    edges = np.concatenate([[0.0], radii[order]])
    idx = [i for i, s in enumerate(sets) if s.focus is not None]
    seg = np.zeros(radii.size)
    if idx:
        k_s = max(sets[i].focus.k * sets[i].focus.radius for i in idx)  # the pupil's band limit (rad/um)
        r, rw, which = _radial_nodes(edges, n, k_s)
        U = prop.hankel_profiles([sets[i].focus for i in idx], r, error=1e-9)
        dens = (U.real ** 2 + U.imag ** 2) * (2 * math.pi * r * rw) / (math.pi * lens.radius_um ** 2)
        seg = np.cumsum(np.bincount(which, weights=w[idx] @ dens, minlength=radii.size))
    total = np.empty(radii.size)
    total[order] = seg
    for wk, s in zip(w, sets):
        for h in s.haze:
            total += wk * h.power_fraction * np.minimum(1.0, (radii / h.radius_um) ** 2)
    return float(total[0]) if scalar else total

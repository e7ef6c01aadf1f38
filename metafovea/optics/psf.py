"""Point spread functions of the metalenses: monochromatic, polychromatic, and on the sensor pixel grid.

Normalisation: ``PSF.intensity[i, j]`` is the fraction of the power incident on the lens aperture (in the
polarisation considered, unit-intensity plane wave) that falls into sample cell (i, j) (a cell of
``pitch_um`` x ``pitch_um``); ``intensity.sum()`` is therefore the fraction that lands in the window and
equals ``energy_fraction``. Arrays are (H, W), row = y, x and y increasing with the index; the array
centre sits at ``center_um`` on the focal plane.

Engine choice (``engine='auto'``), per wavelength:

* ``hankel``  on axis, when the pupil is rotationally symmetric to within the requested error;
* ``mft``     otherwise (any field, any window; nodes from the aberration and the window);
* ``geometric`` (sensor PSFs only) when the wavelength's share of the error budget allows it, or the wave
  engines would exceed the cost budget (then a warning states the achieved error).

Broadband sensor PSFs. On axis every wavelength is computed wave-optically: the Bessel matrix
``J0(k S t r)`` is the same for all wavelengths (``k S = 2 pi NA / lambda0``), so all radial profiles are one
matrix product and the weighted radial intensity is put on the pixel grid once. Off axis the
wavelengths near focus go to one batched MFT (shared kernels in design direction sines) and the rest to
one shared ray trace. The geometric engine is *not* accurate to O(1/W020) at the brightest pixels: the
axial (Poisson) spot of a defocused circular pupil and the coma cusp keep an O(1) relative error however
many waves of defocus (measured 0.27-0.82 of the pixel peak, :data:`GEO_ERROR`); only its pixel-averaged
power is (to ~1 %). Its error estimate is therefore ``GEO_ERROR x`` each geometric wavelength's own peak.
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.config import LensDesign
from metafovea.errors import (
    InputError,
    NotConvergedWarning,
    check_choice,
    check_int,
    check_positive,
    check_range,
)
from metafovea.io import atomic_save_npz, jsonable, load_npz
from metafovea.library import PostSet

from . import propagate as prop
from .pupil import Pupil, PupilSet, build_pupils, field_direction, max_field_deg

log = logging.getLogger(__name__)

ENGINES = ("auto", "hankel", "mft", "geometric")
#: Largest complex-exponential work (nodes x outputs) the auto engine spends on one wavelength.
MFT_BUDGET = 4e8
#: Total wave-engine work (nodes x outputs) one off-axis broadband ``sensor_psf`` spends before the remaining
#: wavelengths go to the geometric engine (whose error bound then shows in ``error_estimate``).
SENSOR_BUDGET = 1.2e9


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

    def normalized(self) -> np.ndarray:
        """Intensity scaled to unit sum (for convolution kernels)."""
        s = self.intensity.sum()
        return self.intensity / s if s > 0 else self.intensity

    def centroid_um(self) -> tuple[float, float]:
        xs, ys = self.coords()
        s = self.intensity.sum()
        return float((self.intensity.sum(0) * xs).sum() / s), float((self.intensity.sum(1) * ys).sum() / s)

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
def _field_pair(field_deg: Any) -> tuple[float, float]:
    s = field_direction(field_deg)  # validates
    del s
    if np.ndim(field_deg) == 0:
        return float(field_deg), 0.0
    a = np.asarray(field_deg, float).reshape(-1)
    return float(a[0]), float(a[1])


def _no_focus_error(lens: LensDesign, wl: np.ndarray, polarization: Any) -> None:
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


def check_wavelengths(lens: LensDesign, wavelengths_um: Any, weights: Any) -> tuple[np.ndarray, np.ndarray]:
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


def _check_field(lens: LensDesign, field_deg: Any, wl: np.ndarray) -> None:
    s0 = field_direction(field_deg)
    lim = max_field_deg(lens, float(wl.max()))
    ang = math.degrees(math.asin(min(1.0, float(np.hypot(*s0)))))
    if ang > lim:
        raise InputError("field_deg", field_deg,
                         f"|field| <= {lim:.3f} deg for lens '{lens.name}' (NA {lens.na:.4f}) at "
                         f"{wl.max():g} um: beyond it the rim of the lens sends light into evanescent directions")


def diffraction_radius_um(lens: LensDesign) -> float:
    """First-zero radius of the focusing order (um): 0.61 lambda0 / NA, the same at every wavelength."""
    return 0.60983 * lens.wavelength_um / lens.na


def nyquist_pitch_um(lens: LensDesign) -> float:
    """Largest sample pitch that samples the intensity without aliasing: lambda0 / (4 NA)."""
    return lens.wavelength_um / (4.0 * lens.na)


# ----------------------------------------------------------------------------------------------
# one wavelength on a grid
# ----------------------------------------------------------------------------------------------
def _wave_engine(pupil: Pupil, xs: np.ndarray, ys: np.ndarray, error: float, engine: str) -> tuple[str, float]:
    """(engine, cost) for a wave-optical evaluation at this pupil and grid."""
    on_axis = float(np.hypot(*pupil.s0)) == 0.0
    aniso = pupil.lattice_anisotropy()
    if engine == "hankel" or (engine == "auto" and on_axis and aniso * 0.1 <= error):
        if not on_axis:
            raise InputError("engine", engine, "'hankel' only on axis (field_deg = 0)")
        return "hankel", float(xs.size * ys.size / 8 * prop.hankel_nodes(pupil, 1.0, error))
    nt, nr = prop.mft_nodes(pupil, xs, ys, error * 1e-3)
    return "mft", float(nt * nr * xs.size + nt * xs.size * ys.size)


def focus_intensity(pupil: Pupil, xs: np.ndarray, ys: np.ndarray, *, error: float = 1e-4,
                    engine: str = "auto") -> tuple[np.ndarray, str, float]:
    """Intensity (power per um^2 for unit incident intensity) of the focusing order on the grid.

    Returns (I, engine, error estimate relative to the ideal in-focus peak).
    """
    eng, _ = _wave_engine(pupil, xs, ys, error, engine)
    if eng == "hankel":
        U = prop.hankel_grid(pupil, xs, ys, error=error * 1e-3)
        est = 0.1 * pupil.lattice_anisotropy() + error * 1e-3
    else:
        U = prop.mft_field(pupil, xs, ys, error=error * 1e-3)
        est = error * 1e-3
    return np.abs(U) ** 2, eng, est


def _ideal_peak(pupil: Pupil) -> float:
    """In-focus on-axis peak intensity of an aberration-free pupil with this support (upper bound)."""
    lens = pupil.lens
    # |int P d^2s| with |P| = f0 alpha / (lambda c_w^2) over |w| <= NA: (pi f0 / (lambda alpha)) (-ln(1-NA^2))
    a = pupil.alpha
    val = math.pi * lens.f_um / (pupil.wavelength_um * a) * (-math.log(1.0 - lens.na ** 2))
    return (abs(pupil.amplitude_factor) * val) ** 2


def _auto_window(pupils: list[Pupil], lens: LensDesign, margin_um: float) -> tuple[np.ndarray, float]:
    """Centre and half-size (um) of a window holding every ray plus a diffraction margin."""
    boxes = np.array([prop.ray_extent(p) for p in pupils])
    x0, x1 = boxes[:, 0].min(), boxes[:, 1].max()
    y0, y1 = boxes[:, 2].min(), boxes[:, 3].max()
    c = np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1)])
    half = max(x1 - x0, y1 - y0) / 2 + margin_um
    return c, half


def psf(lens: LensDesign, *, wavelengths_um: Any = None, weights: Any = None, field_deg: Any = 0.0,
        window_um: float | None = None, center_um: tuple[float, float] | None = None,
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
    """
    t0 = time.perf_counter()
    wl, w = check_wavelengths(lens, wavelengths_um, weights)
    error = check_range("error", error, 0.0, 0.5)
    engine = check_choice("engine", engine, ENGINES)
    if engine == "geometric":
        raise InputError("engine", engine, "'auto', 'hankel' or 'mft' for a fine-grid PSF (geometric: sensor_psf)")
    _check_field(lens, field_deg, wl)
    fpair = _field_pair(field_deg)
    sets = [build_pupils(lens, float(l), field_deg=field_deg, post_set=post_set, polarization=polarization,
                         quantize=quantize, lattice=lattice, z_um=z_um) for l in wl]
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
    c = c_auto if center_um is None else np.asarray(center_um, float)
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
    for wi, s in zip(w, sets):
        if s.focus is None:
            continue
        I, eng, e = focus_intensity(s.focus, xs, ys, error=error, engine=engine)
        ip = _ideal_peak(s.focus)
        ideal_peak = max(ideal_peak, ip)
        total += wi * I
        est += wi * e * ip
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
            "chief_ray_um": pupils[0].chief_ray_um().tolist(), "z_um": pupils[0].z_um,
            "error_definition": "max abs error / PSF peak (quadrature bound)"}
    log.info("psf %s: %s, %d^2 samples at %.3g um, %.3f s", lens.name, eng_name, n, pitch, info["seconds"])
    return PSF(inten, pitch, (float(c[0]), float(c[1])), wl, w, fpair, sets[0].info["polarization"],
               eng_name, float(max(est_rel, 1e-16)), float(inten.sum()), info)


# ----------------------------------------------------------------------------------------------
# sensor PSF (pixel-integrated)
# ----------------------------------------------------------------------------------------------
def _box_integrate(I: np.ndarray, n_sub: int) -> np.ndarray:
    """Integrate a band-limited intensity sampled n_sub times per pixel over the pixels (sum of cells).

    The samples sit at the centres of n_sub x n_sub sub-cells of each pixel. The box filter of one pixel
    is applied exactly in the Fourier domain (valid for intensities band-limited below the sample
    Nyquist frequency), then every pixel's value is read at its centre.
    """
    out = I
    for axis in (0, 1):
        N = out.shape[axis]
        pad = N + 2 * n_sub
        f = np.fft.rfftfreq(pad)  # cycles per sample
        # box of width n_sub samples, centred between samples when n_sub is even
        shift = 0.5 if n_sub % 2 == 0 else 0.0
        H = n_sub * np.sinc(f * n_sub) * np.exp(2j * np.pi * f * shift)
        spec = np.fft.rfft(out, n=pad, axis=axis)
        shape = [1, 1]
        shape[axis] = -1
        conv = np.fft.irfft(spec * H.reshape(shape), n=pad, axis=axis)
        conv = np.take(conv, np.arange(N), axis=axis)
        start = (n_sub - 1) // 2
        out = np.take(conv, np.arange(start, N, n_sub), axis=axis)
    return out


def _sunflower(n: int) -> tuple[np.ndarray, np.ndarray]:
    """n points uniformly covering the unit disk (golden-angle spiral), equal area each."""
    i = np.arange(n) + 0.5
    r = np.sqrt(i / n)
    th = i * (math.pi * (3.0 - math.sqrt(5.0)))
    return r * np.cos(th), r * np.sin(th)


@lru_cache(maxsize=8)
def _sunflower_cached(n: int) -> tuple[np.ndarray, np.ndarray]:
    x, y = _sunflower(n)
    x.setflags(write=False)
    y.setflags(write=False)
    return x, y


def geometric_pixels(pupil: Pupil, x_edges0: float, y_edges0: float, pitch: float, size: int,
                     n_rays: int) -> np.ndarray:
    """Geometric PSF binned on pixels: power (unit incident intensity, um^2 units) per pixel."""
    return geometric_pixels_multi([pupil], [1.0], x_edges0, y_edges0, pitch, size, n_rays)


def geometric_pixels_multi(pupils: list[Pupil], weights: Any, x_edges0: float, y_edges0: float, pitch: float,
                           size: int, n_rays: int, each: bool = False) -> np.ndarray:
    """Weighted sum of the geometric PSFs of several wavelengths (same lens and field) binned on pixels.

    One ray set serves every wavelength: a lens point sends its ray into the design direction sine w
    (scaled by lambda / lambda0), so the sunflower sampling of the aperture, the obliquity ``c_w`` and the
    lattice factor are computed once; only the landing points change with the wavelength.
    """
    if not pupils:
        return np.zeros((size, size))
    lens = pupils[0].lens
    R = lens.radius_um
    px, py = _sunflower_cached(int(n_rays))
    rx, ry = R * px, R * py
    r0 = np.sqrt(rx * rx + ry * ry + lens.f_um ** 2)
    wx, wy = -rx / r0, -ry / r0  # design direction sines
    cw = np.sqrt(1.0 - wx * wx - wy * wy)
    base = np.ones_like(wx)
    if any(pu.lattice for pu in pupils):
        q = lens.period_um / lens.wavelength_um
        lat = (np.sinc(q * wx) * np.sinc(q * wy)) ** 2
    per_ray = math.pi * R * R / n_rays
    out = np.zeros((len(pupils) if each else 1, size * size))
    for i, (pu, wk) in enumerate(zip(pupils, weights)):
        if wk == 0:
            continue
        a = pu.alpha
        sx = pu.s0[0] + wx / a
        sy = pu.s0[1] + wy / a
        s2 = sx * sx + sy * sy
        ok = s2 < 1.0
        cs = np.sqrt(np.where(ok, 1.0 - s2, 1.0))
        # Pupil.ray_landing: -f0 w / c_w + z s / c_s
        X = -lens.f_um * wx / cw + pu.z_um * sx / cs
        Y = -lens.f_um * wy / cw + pu.z_um * sy / cs
        ix = np.floor((X - x_edges0) / pitch)
        iy = np.floor((Y - y_edges0) / pitch)
        m = ok & (ix >= 0) & (ix < size) & (iy >= 0) & (iy < size)
        amp2 = (lat if pu.lattice else base)[m] * (abs(pu.amplitude_factor) ** 2 * per_ray * wk)
        out[i if each else 0] += np.bincount((iy[m] * size + ix[m]).astype(np.int64), weights=amp2,
                                             minlength=size * size)
    return out.reshape(-1, size, size) if each else out.reshape(size, size)


def _spread_um(pupil: Pupil) -> float:
    e = prop.ray_extent(pupil, 16)
    c = pupil.chief_ray_um()
    return float(max(abs(e[0] - c[0]), abs(e[1] - c[0]), abs(e[2] - c[1]), abs(e[3] - c[1])))


#: Error of the geometric engine relative to the wavelength's own largest pixel, as a bound: measured
#: max |geometric - wave| / wave peak on 17 um pixels = 0.27-0.80 for the F/1 lens on axis (10.3-13 um) and
#: 0.40-0.82 at 5 deg (9.5-11 um). Diffraction at the caustics (the axial Poisson spot of a defocused
#: circular pupil, the coma cusp) stays O(1) of the pixel peak however many waves of defocus: the
#: O(1/W020) accuracy of the blur disk holds for its pixel-averaged interior, not for its brightest pixel.
GEO_ERROR = 1.0


def _union(boxes: list[tuple[float, float, float, float]]) -> tuple[float, float, float, float]:
    return (min(b[0] for b in boxes), max(b[1] for b in boxes), min(b[2] for b in boxes), max(b[3] for b in boxes))


def _box_area(b: tuple[float, float, float, float], margin: float) -> float:
    return (b[1] - b[0] + 2 * margin) * (b[3] - b[2] + 2 * margin)


#: Smallest ray spread (in diffraction radii) at which GEO_ERROR was validated (measured: 64-790).
GEO_MIN_SPREAD = 40.0


def _geo_bound(pupil: Pupil, gpeak: float, spread_um: float, r_diff: float, p: float, P_in: float) -> float:
    """Bound on max |geometric - wave| over the pixels for one wavelength (fraction of incident power).

    Beyond ``GEO_MIN_SPREAD`` diffraction radii: ``GEO_ERROR`` x the geometric peak pixel (calibrated).
    Nearer focus the wave PSF can be much brighter than the ray histogram (F/2 at 10.03 um: 1.6 x the
    geometric peak), so the bound is the larger of the geometric peak and the brightest pixel any wave
    field of this pupil can make (|U| <= int |P|: the ideal in-focus peak times the pixel area).
    """
    if spread_um >= GEO_MIN_SPREAD * r_diff:
        return GEO_ERROR * gpeak
    return max(gpeak, _ideal_peak(pupil) * p * p / P_in)


def _n_rays(spread_um: float, pitch: float) -> int:
    area = math.pi * (spread_um + pitch) ** 2
    n = int(min(3e5, max(2e4, 50 * area / (pitch * pitch))))
    return -(-n // 10000) * 10000  # a few distinct ray sets (cached)


def _wave_cost(pupil: Pupil, xs: np.ndarray, ys: np.ndarray, r_diff: float, p: float, error: float) -> float:
    """MFT cost (nodes x outputs) of one wavelength on the part of the window its light reaches."""
    ex = prop.ray_extent(pupil, 16)
    mg = 30 * r_diff + 2 * p
    sub_x = xs[(xs >= ex[0] - mg) & (xs <= ex[1] + mg)]
    sub_y = ys[(ys >= ex[2] - mg) & (ys <= ex[3] + mg)]
    if sub_x.size == 0 or sub_y.size == 0:
        return 0.0
    return _wave_engine(pupil, sub_x, sub_y, error, "mft")[1]


def _radial_sensor(lens: LensDesign, pupils: list[Pupil], weights: np.ndarray, ax: np.ndarray,
                   total_f: np.ndarray, error: float, dx: float, P_in: float, engines: dict[str, int]) -> float:
    """On-axis broadband intensity on the fine grid (added to ``total_f``, weighted) from one batched
    Hankel evaluation of every wavelength and a cubic spline of the weighted radial intensity.

    Returns the absolute error estimate per fine cell (fraction of the incident power); the caller scales
    it to pixels and adds the box-filter term. The spline error is measured against the exact profile at
    256 midpoints (x 2 as the bound).
    """
    from scipy.interpolate import CubicSpline

    r2 = ax[None, :] ** 2 + ax[:, None] ** 2
    r_max = math.sqrt(float(r2.max()))
    f_int = 2 * lens.na / lens.wavelength_um  # intensity band limit (cycles/um), the same at every lambda
    # cubic-spline error of a sinusoid ~ (5/384)(2 pi f h)^4 of its amplitude: 10 % of the budget
    h = min(dx, (0.1 * error * 384 / 5) ** 0.25 / (2 * math.pi * f_int))
    rr = np.arange(0.0, r_max + 2.5 * h, h)
    qerr = error * 1e-3
    n = max(prop.hankel_nodes(pu, float(rr[-1]), qerr) for pu in pupils)
    U = prop.hankel_profiles(pupils, rr, error=qerr, n=n)
    I = weights @ (U.real ** 2 + U.imag ** 2)
    spl = CubicSpline(rr, I, bc_type=((1, 0.0), "not-a-knot"))
    idx = np.unique(np.linspace(0, rr.size - 2, 256).astype(int))
    mids = rr[idx] + 0.5 * h
    Um = prop.hankel_profiles(pupils, mids, error=qerr, n=n)
    spl_err = float(np.abs(spl(mids) - weights @ (np.abs(Um) ** 2)).max())
    total_f += spl(np.sqrt(r2))
    engines["hankel"] = len(pupils)
    # quadrature (error * 1e-3 of each ideal peak), azimuthal averaging of the lattice factor and the
    # measured spline error x 2, per fine cell. Lattice: the 4-fold part the average leaves out was measured
    # (hankel vs 2-D mft, 17 um pixels, both lenses, 10-10.4 um) at <= 0.0037 x anisotropy of the ideal peak
    # and <= 0.27 x anisotropy of the wavelength's own peak pixel: bound min(0.01 ideal, 1.0 own peak) per
    # fine cell, times n_sub^2 cells per pixel by the caller (test_radial_lattice_error_bound checks it).
    own = (U.real ** 2 + U.imag ** 2).max(axis=1)
    quad = sum(wk * (qerr * _ideal_peak(pu) + pu.lattice_anisotropy() * min(0.01 * _ideal_peak(pu), float(ok)))
               for pu, wk, ok in zip(pupils, weights, own))
    log.debug('radial sensor: quad+lattice %.3g, spline %.3g (power per um^2)', quad, 2 * spl_err)
    return (quad + 2 * spl_err) * dx * dx / P_in


def sensor_psf(lens: LensDesign, *, pixel_pitch_um: float, field_deg: float | tuple[float, float] = 0.0,
               wavelengths_um: Any = None, weights: Any = None, post_set: PostSet | None = None,
               size_px: int | None = None, error: float = 1e-4, polarization: str | None = None,
               quantize: bool = True, lattice: bool = True, z_um: float | None = None,
               engine: str = "auto", max_size_px: int = 255, budget: float | None = None) -> PSF:
    """PSF integrated over square pixels of ``pixel_pitch_um`` on the lens' focal plane.

    The pixel grid is centred on the chief ray (``center_um`` = chief ray landing point; with an odd
    ``size_px`` a pixel is centred on it). ``intensity.sum()`` is the fraction of the incident power in
    the polarisation (default: the lens' own) that lands in the window, including the diffraction orders
    other than the focusing one (uniform geometric disks) and the quantisation / lattice / chromatic
    losses, so broadband haze shows as a small sum. ``size_px=None`` sizes the window from the ray spread
    of the wavelengths that carry 99 % of the weight (capped at ``max_size_px``).

    On axis (``engine='auto'`` or ``'hankel'``) all wavelengths are wave-optical (batched Hankel). Off axis
    wavelengths are traced as rays (``geometric``) when their error bound (``GEO_ERROR`` x their own peak
    pixel) fits in half the error budget, or when the wave engines would exceed ``budget`` (work units,
    nodes x outputs; default :data:`SENSOR_BUDGET`); the most error removed per unit of work goes to the
    batched MFT first. The achieved error (max abs / peak pixel, a bound) is in ``error_estimate`` and a
    :class:`NotConvergedWarning` is raised when it exceeds ``error``.
    """
    t0 = time.perf_counter()
    p = check_positive("pixel_pitch_um", pixel_pitch_um, "um", hi=1e4)
    budget = SENSOR_BUDGET if budget is None else check_positive("budget", budget)
    wl, w = check_wavelengths(lens, wavelengths_um, weights)
    error = check_range("error", error, 0.0, 0.5)
    engine = check_choice("engine", engine, ENGINES)
    _check_field(lens, field_deg, wl)
    fpair = _field_pair(field_deg)
    sets: list[PupilSet] = [build_pupils(lens, float(l), field_deg=field_deg, post_set=post_set,
                                         polarization=polarization, quantize=quantize, lattice=lattice,
                                         z_um=z_um) for l in wl]
    pol = sets[0].info["polarization"]
    z = lens.f_um if z_um is None else float(z_um)
    s0 = field_direction(field_deg)
    chief = z * s0 / math.sqrt(1.0 - float(s0 @ s0))
    r_diff = diffraction_radius_um(lens)
    spreads = np.array([_spread_um(s.focus) if s.focus is not None else 0.0 for s in sets])
    if size_px is None:
        order = np.argsort(-w)
        keep = order[: int(np.searchsorted(np.cumsum(w[order]), 0.99) + 1)]
        half = float(spreads[keep].max()) + 6 * r_diff + p
        size = min(max_size_px, 2 * int(math.ceil(half / p)) + 1)
    else:
        size = check_int("size_px", size_px, 1, 8192)
    L = size * p
    x_e0, y_e0 = chief[0] - L / 2, chief[1] - L / 2
    nyq = nyquist_pitch_um(lens)
    n_sub = max(1, int(math.ceil(p / (0.95 * nyq))))
    nf = size * n_sub
    dx = p / n_sub
    ax = (np.arange(nf) - (nf - 1) / 2) * dx
    xs, ys = chief[0] + ax, chief[1] + ax
    P_in = math.pi * lens.radius_um ** 2

    engines: dict[str, int] = {}
    est_abs = 0.0  # absolute error estimate, fraction of incident power per pixel
    pix = np.zeros((size, size))
    total_f = np.zeros((nf, nf))
    active = [k for k in range(wl.size) if sets[k].focus is not None and w[k] > 0]
    on_axis = float(np.hypot(*s0)) == 0.0
    radial = on_axis and engine in ("auto", "hankel") and active and (
        engine == "hankel" or all(sets[k].focus.lattice_anisotropy() * 0.1 <= error for k in active))
    if radial:
        # every wavelength wave-optically: the focusing order is rotationally symmetric on axis, the Bessel
        # matrix is shared by all wavelengths, and the weighted radial intensity is pixelised once
        est_abs += n_sub * n_sub * _radial_sensor(lens, [sets[k].focus for k in active], w[active], ax, total_f, error,
                                  dx, P_in, engines)
    else:
        geo_k: list[int] = []
        wave_k: list[int] = []
        if engine in ("hankel", "mft"):
            wave_k = list(active)
        elif engine == "geometric":
            geo_k = list(active)
        elif active:
            # geometric maps of every wavelength (one shared ray set): their pixel peaks bound the error a
            # geometric treatment would make (GEO_ERROR x own peak, calibrated against the wave engines)
            n_est = min(150_000, _n_rays(float(spreads[active].max()), p))
            gmaps = dict(zip(active, geometric_pixels_multi([sets[k].focus for k in active], np.ones(len(active)),
                                                            x_e0, y_e0, p, size, n_est, each=True) / P_in))
            gpeak = {k: float(gmaps[k].max()) for k in active}
            gbound = {k: _geo_bound(sets[k].focus, gpeak[k], spreads[k], r_diff, p, P_in) for k in active}
            gsum = sum(w[k] * gmaps[k] for k in active)
            target = 0.5 * error * 0.5 * float(gsum.max())  # half the error budget; peak bound from below
            costs = {k: _wave_cost(sets[k].focus, xs, ys, r_diff, p, error) for k in active}
            # most error removed per unit of wave-engine cost first
            order = sorted(active, key=lambda k: -w[k] * gbound[k] / max(costs[k], 1.0))
            remaining = sum(w[k] * gbound[k] for k in active)
            budget_used = 0.0
            for k in order:
                cost = costs[k]
                if remaining <= target or budget_used + cost > budget or cost > MFT_BUDGET:
                    geo_k.append(k)  # accurate enough, or over the cost budget: the estimate says so
                    continue
                budget_used += cost
                wave_k.append(k)
                remaining -= w[k] * gbound[k]
        if geo_k:
            if engine == "auto":  # the estimation pass already traced them
                pix += sum(w[k] * gmaps[k] for k in geo_k)
                est_abs += sum(w[k] * gbound[k] for k in geo_k)
            else:
                n_rays = max(_n_rays(spreads[k], p) for k in geo_k)
                gm = geometric_pixels_multi([sets[k].focus for k in geo_k], np.ones(len(geo_k)), x_e0, y_e0, p,
                                            size, n_rays, each=True) / P_in
                pix += np.tensordot(w[geo_k], gm, axes=1)
                gp = gm.reshape(len(geo_k), -1).max(axis=1)
                est_abs += sum(w[k] * _geo_bound(sets[k].focus, float(g), spreads[k], r_diff, p, P_in)
                               for k, g in zip(geo_k, gp))
            engines["geometric"] = len(geo_k)
        # compute only where light lands: the ray boxes plus a diffraction margin (tails beyond
        # 30 diffraction radii carry < 0.3 % of the power)
        mg = 30 * r_diff + 2 * p
        boxes = {k: prop.ray_extent(sets[k].focus, 16) for k in wave_k}
        wave_k = [k for k in wave_k if boxes[k][1] + mg > xs[0] and boxes[k][0] - mg < xs[-1]
                  and boxes[k][3] + mg > ys[0] and boxes[k][2] - mg < ys[-1]]
        # batches of similar ray boxes share one window and one node set
        batches: list[list[int]] = []
        for k in sorted(wave_k, key=lambda k: _box_area(boxes[k], mg)):
            # the union window may grow to 1.5x the area of the batch's smallest member (the MFT work grows
            # with the window's area times its node counts)
            if batches and (engine == "hankel" or _box_area(_union([boxes[j] for j in batches[-1]] + [boxes[k]]), mg)
                            <= 1.5 * _box_area(boxes[batches[-1][0]], mg)):
                batches[-1].append(k)
            else:
                batches.append([k])
        for bk in batches:
            ub = _union([boxes[k] for k in bk])
            i0 = int(np.searchsorted(xs, ub[0] - mg)); i1 = int(np.searchsorted(xs, ub[1] + mg))
            j0 = int(np.searchsorted(ys, ub[2] - mg)); j1 = int(np.searchsorted(ys, ub[3] + mg))
            if engine == "hankel":
                for k in bk:
                    I, _, e = focus_intensity(sets[k].focus, xs[i0:i1], ys[j0:j1], error=error, engine="hankel")
                    total_f[j0:j1, i0:i1] += w[k] * I
                    est_abs += w[k] * e * _ideal_peak(sets[k].focus) * dx * dx / P_in * n_sub * n_sub
            else:
                # one batched MFT (shared kernels in design direction sines)
                total_f[j0:j1, i0:i1] += prop.mft_intensity_multi([sets[k].focus for k in bk], w[bk],
                                                                  xs[i0:i1], ys[j0:j1], error=error * 1e-3)
                # quadrature, and the light left outside the window (30 diffraction radii beyond the ray box:
                # the Airy envelope 8 / (pi x^3), x = 3.83 x 30, of the ideal peak)
                tail = 8.0 / (math.pi * (3.8317 * 30) ** 3)
                est_abs += sum(w[k] * (error * 1e-3 + tail) * _ideal_peak(sets[k].focus) for k in bk) \
                    * dx * dx / P_in * n_sub * n_sub
        if wave_k:
            engines["hankel" if engine == "hankel" else "mft"] = len(wave_k)
    if total_f.any():
        pix += _box_integrate(total_f, n_sub) * dx * dx / P_in
        edge = max(total_f[0].max(), total_f[-1].max(), total_f[:, 0].max(), total_f[:, -1].max())
        est_abs += 0.05 * edge * dx * dx / P_in * n_sub  # truncation of the band-limited box filter
    # haze orders: uniform disks
    xc = x_e0 + (np.arange(size) + 0.5) * p
    yc = y_e0 + (np.arange(size) + 0.5) * p
    haze_total = 0.0
    for wi, s in zip(w, sets):
        for h in s.haze:
            d = wi * h.power_fraction * _disk_pixels(h.center_um, h.radius_um, x_e0, y_e0, p, size)
            pix += d
            haze_total += wi * h.power_fraction
            if h.order != 0 and h.radius_um < 3 * diffraction_radius_um(lens) / abs(h.order):
                # an order focusing near this plane: the uniform disk is only a rough stand-in for its
                # diffraction-limited spot, wrong by up to its own peak
                est_abs += float(d.max())
    peak = float(pix.max())
    est_rel = est_abs / peak if peak > 0 else float("inf")
    if est_rel > error:
        capped = size_px is None and size == max_size_px and 2 * half > L
        why = (f"the window is capped at {max_size_px} pixels = {L:.4g} um, the PSF spreads over {2 * half:.4g} um: "
               "use larger pixels" if capped else "geometric haze or cost budget")
        warnings.warn(f"sensor PSF of '{lens.name}' at field {fpair} deg: estimated error {est_rel:.2g} of the "
                      f"peak exceeds the requested {error:g} ({why}); raise error or "
                      "reduce wavelengths", NotConvergedWarning, stacklevel=2)
    eng_name = "+".join(f"{k}" for k in sorted(engines))
    info = {"engines": engines, "n_sub": n_sub, "fine_pitch_um": dx, "size_px": size,
            "haze_power": haze_total, "seconds": time.perf_counter() - t0, "requested_error": error,
            "order_efficiency": float(np.dot(w, [s.info["order_efficiency"] for s in sets])),
            "quantize": quantize, "lattice": lattice, "z_um": z,
            "error_definition": "max abs error / PSF peak pixel (estimate)"}
    log.info("sensor_psf %s field %s: %s, %d px, sum %.4g, err %.2g, %.3f s", lens.name, fpair, eng_name, size,
             pix.sum(), est_rel, info["seconds"])
    return PSF(pix, p, (float(chief[0]), float(chief[1])), wl, w, fpair, pol, eng_name, float(est_rel),
               float(pix.sum()), info)


def _disk_pixels(center_um: Any, radius_um: float, x_e0: float, y_e0: float, p: float, size: int) -> np.ndarray:
    """Fraction of a uniform disk's area falling in each pixel of a ``size`` x ``size`` grid.

    Pixels are sub-sampled finely enough to resolve the disk (at least ~8 samples across its
    radius), so a disk smaller than a pixel deposits its power instead of missing every pixel centre
    or, hitting one, being multiplied by (pixel / disk area). Only the pixels under the disk's
    bounding box are evaluated.
    """
    out = np.zeros((size, size))
    cx, cy = float(center_um[0]), float(center_um[1])
    r = float(radius_um)
    if not r > 0:
        return out
    i0 = max(0, int(math.floor((cx - r - x_e0) / p)))
    i1 = min(size, int(math.ceil((cx + r - x_e0) / p)))
    j0 = max(0, int(math.floor((cy - r - y_e0) / p)))
    j1 = min(size, int(math.ceil((cy + r - y_e0) / p)))
    if i1 <= i0 or j1 <= j0:
        return out
    if 16 * r < p:  # far below a pixel: all of it in the pixel holding the centre (if inside the window)
        i, j = int(math.floor((cx - x_e0) / p)), int(math.floor((cy - y_e0) / p))
        if 0 <= i < size and 0 <= j < size:
            out[j, i] = 1.0
        return out
    ns = int(min(64, max(1, math.ceil(8.0 * p / r))))
    while (i1 - i0) * (j1 - j0) * ns * ns > 4_000_000 and ns > 1:
        ns = max(1, ns // 2)
    sub = (np.arange(ns) + 0.5) / ns * p
    xs = (x_e0 + np.arange(i0, i1)[:, None] * p + sub[None, :]).reshape(-1) - cx
    ys = (y_e0 + np.arange(j0, j1)[:, None] * p + sub[None, :]).reshape(-1) - cy
    inside = (ys[:, None] ** 2 + xs[None, :] ** 2) <= r * r
    cnt = inside.reshape(j1 - j0, ns, i1 - i0, ns).sum(axis=(1, 3))
    out[j0:j1, i0:i1] = cnt * (p / ns) ** 2 / (math.pi * r * r)
    return out


def encircled_energy_on_axis(lens: LensDesign, radius_um: float, *, wavelengths_um: Any = None, weights: Any = None,
                             post_set: PostSet | None = None, quantize: bool = True, lattice: bool = True,
                             z_um: float | None = None, n: int = 400) -> float:
    """Fraction of the incident power within ``radius_um`` of the axis for an on-axis source (exact).

    Radial Gauss quadrature of the batched Hankel profiles of every wavelength's focusing order (lattice
    factor azimuthally averaged) plus the haze orders (uniform disks). No pixel grid involved.
    """
    r0 = check_positive("radius_um", radius_um, "um")
    wl, w = check_wavelengths(lens, wavelengths_um, weights)
    sets = [build_pupils(lens, float(l), post_set=post_set, quantize=quantize, lattice=lattice, z_um=z_um)
            for l in wl]
    x, gw = prop._gl(check_int("n", n, 8, 100000))
    r = 0.5 * r0 * (x + 1.0)
    rw = 0.5 * r0 * gw
    idx = [i for i, s in enumerate(sets) if s.focus is not None]
    total = 0.0
    if idx:
        U = prop.hankel_profiles([sets[i].focus for i in idx], r, error=1e-9)
        ee = (U.real ** 2 + U.imag ** 2) @ (2 * math.pi * r * rw) / (math.pi * lens.radius_um ** 2)
        total += float(np.dot(w[idx], ee))
    for wk, s in zip(w, sets):
        for h in s.haze:
            total += wk * h.power_fraction * min(1.0, (r0 / h.radius_um) ** 2)
    return total

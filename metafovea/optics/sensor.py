"""Sensor PSFs: the PSF integrated over the pixels of the sensor, broadband, on and off axis.

Normalisation as :class:`metafovea.optics.psf.PSF`, with one cell per pixel: ``intensity[i, j]`` is the
fraction of the incident power (in the polarisation considered) that falls on pixel (i, j), the diffraction
orders other than the focusing one (uniform geometric disks, "haze") included. The grid is centred on the
chief ray.

Engine choice (``engine='auto'``), per wavelength:

* ``hankel``    on axis, every wavelength wave-optically: the Bessel matrix ``J0(k S t r)`` is the same for
  all wavelengths (``k S = 2 pi NA / lambda0``), so all radial profiles are one matrix product and the
  weighted radial intensity is put on the pixel grid once (:func:`_radial_sensor`; each wavelength's profile
  corrected for its focal shift, :meth:`Pupil.li_wolf`, by a spline per wavelength). This is the direction-sine
  (Debye) model, whose error at the defocused wavelengths (the rim wave's phase, the amplitude and scale beyond the
  Fresnel approximation: :func:`metafovea.optics.psf.debye_error_bound`) is in ``error_estimate`` over pixels
  (:func:`debye_pixel_error`, conservative: BENCHMARKS.md, "PSF engines") and in ``info['debye_error_estimate']``;
  the exact engine is ``psf(engine='rs')`` on a fine grid;
* ``mft``       off axis, the wavelengths near focus: one batched MFT (shared kernels in design direction
  sines) per group of similar ray boxes, on a grid of ``n_sub`` samples per pixel, then integrated over the
  pixels exactly (:func:`box_integrate`);
* ``geometric`` the rest: one shared ray trace (:func:`geometric_pixels_multi`), chosen when a wavelength's
  share of the error budget allows it, or when the wave engines would exceed the cost budget (then a
  warning states the achieved error).

A lens with ``phase_poly_rad`` (a phase beyond the hyperbola): ``engine='auto'`` integrates the exact (``rs``)
field of every wavelength over the pixels while the wave engines' cost (``budget``) allows, else traces every
wavelength as rays (forwards from the lens: any ray map); the direction-sine and ray engines are not bounded for such
a lens (``error_estimate`` ``inf``, ``info['model_note']``).

The geometric engine is *not* accurate to O(1/W020) at the brightest pixels: the axial (Poisson) spot of a
defocused circular pupil and the coma cusp keep an O(1) relative error however many waves of defocus
(:data:`GEO_ERROR`: BENCHMARKS.md, "PSF engines"); only its pixel-averaged power is (to ~1 %). Its
error estimate is therefore ``GEO_ERROR x`` each geometric wavelength's own peak (:func:`_geo_bound`).
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy import special

from metafovea.config import LensDesign
from metafovea.errors import NotConvergedWarning, check_int, check_positive
from metafovea.library.postset import PostSet

from . import propagate as prop
from .psf import (
    MFT_OFF_AXIS_NOTE,
    POLY_NOTE,
    PSF,
    _ideal_peak,
    _wave_engine,
    checked_inputs,
    debye_error_parts,
    diffraction_radius_um,
    focus_intensity,
    nyquist_pitch_um,
)
from .pupil import Pupil, PupilSet, design_na, field_direction

log = logging.getLogger(__name__)

#: The light left outside a wave engine's window 30 diffraction radii beyond the ray box, relative to the ideal
#: peak: the Airy envelope 8 / (pi x^3), x = 3.83 x 30.
RS_TAIL = 8.0 / (math.pi * (3.8317 * 30) ** 3)
#: Largest complex-exponential work (nodes x outputs) the auto engine spends on one wavelength.
MFT_BUDGET = 4e8
#: Total wave-engine work (nodes x outputs) one off-axis broadband ``sensor_psf`` spends before the remaining
#: wavelengths go to the geometric engine (whose error bound then shows in ``error_estimate``).
SENSOR_BUDGET = 1.2e9


# ----------------------------------------------------------------------------------------------
# pixel integration
# ----------------------------------------------------------------------------------------------
def box_integrate(I: np.ndarray, n_sub: int) -> np.ndarray:
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


def disk_pixels(center_um: tuple[float, float], radius_um: float, x_e0: float, y_e0: float, p: float,
                size: int) -> np.ndarray:
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


# ----------------------------------------------------------------------------------------------
# the geometric engine and its error bound
# ----------------------------------------------------------------------------------------------
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


def geometric_pixels_multi(pupils: list[Pupil], weights: np.ndarray, x_edges0: float, y_edges0: float, pitch: float,
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
    if lens.phase_poly_rad:  # the direction sine of the full phase (g / rho), traced forwards: any ray map
        from metafovea.lens import direction_sine_over_r  # lens stage (rank 3): allowed

        hr = direction_sine_over_r(lens, np.hypot(rx, ry))
        wx, wy = -rx * hr, -ry * hr
    else:
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
        if lens.phase_poly_rad:  # Pupil.ray_landing: the lens point plus z s / c_s
            X = rx + pu.z_um * sx / cs
            Y = ry + pu.z_um * sy / cs
        else:  # Pupil.ray_landing: -f0 w / c_w + z s / c_s
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


def _n_rays(spread_um: float, pitch: float) -> int:
    area = math.pi * (spread_um + pitch) ** 2
    n = int(min(3e5, max(2e4, 50 * area / (pitch * pitch))))
    return -(-n // 10000) * 10000  # a few distinct ray sets (cached)


#: Error of the geometric engine relative to the wavelength's own largest pixel, as a bound: measured
#: max |geometric - wave| / wave peak on 17 um pixels = 0.27-0.80 for the F/1 lens on axis (10.3-13 um) and
#: 0.40-0.82 at 5 deg (9.5-11 um). Diffraction at the caustics (the axial Poisson spot of a defocused
#: circular pupil, the coma cusp) stays O(1) of the pixel peak however many waves of defocus: the
#: O(1/W020) accuracy of the blur disk holds for its pixel-averaged interior, not for its brightest pixel.
GEO_ERROR = 1.0


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


# ----------------------------------------------------------------------------------------------
# the wave engines' cost and windows; the on-axis radial engine
# ----------------------------------------------------------------------------------------------
def _wave_cost(pupil: Pupil, xs: np.ndarray, ys: np.ndarray, r_diff: float, p: float, error: float) -> float:
    """MFT cost (nodes x outputs) of one wavelength on the part of the window its light reaches."""
    ex = prop.ray_extent(pupil, 16)
    mg = 30 * r_diff + 2 * p
    sub_x = xs[(xs >= ex[0] - mg) & (xs <= ex[1] + mg)]
    sub_y = ys[(ys >= ex[2] - mg) & (ys <= ex[3] + mg)]
    if sub_x.size == 0 or sub_y.size == 0:
        return 0.0
    return _wave_engine(pupil, sub_x, sub_y, error, "mft")[1]


def _union(boxes: list[tuple[float, float, float, float]]) -> tuple[float, float, float, float]:
    return (min(b[0] for b in boxes), max(b[1] for b in boxes), min(b[2] for b in boxes), max(b[3] for b in boxes))


def _box_area(b: tuple[float, float, float, float], margin: float) -> float:
    return (b[1] - b[0] + 2 * margin) * (b[3] - b[2] + 2 * margin)


def _radial_sensor(lens: LensDesign, pupils: list[Pupil], weights: np.ndarray, ax: np.ndarray,
                   total_f: np.ndarray, error: float, dx: float, n_sub: int, P_in: float,
                   engines: dict[str, int]) -> tuple[float, float]:
    """On-axis broadband intensity on the fine grid (added to ``total_f``, weighted) from one batched
    Hankel evaluation of every wavelength and a cubic spline of the weighted radial intensity.

    Returns the absolute error estimates per pixel (fraction of the incident power): quadrature, lattice and
    spline; the direction-sine model's rim wave at the defocused wavelengths (:func:`debye_pixel_error`). The
    caller adds the box-filter term. The spline error is measured against the exact profile at 256 midpoints
    (x 2 as the bound).
    """
    from scipy.interpolate import CubicSpline

    r2 = ax[None, :] ** 2 + ax[:, None] ** 2
    r_max = math.sqrt(float(r2.max()))
    f_int = 2 * design_na(lens) / lens.wavelength_um  # intensity band limit (cycles/um), the same at every lambda
    # cubic-spline error of a sinusoid ~ (5/384)(2 pi f h)^4 of its amplitude: 10 % of the budget
    h = min(dx, (0.1 * error * 384 / 5) ** 0.25 / (2 * math.pi * f_int))
    rr = np.arange(0.0, r_max + 2.5 * h, h)
    qerr = error * 1e-3
    # the focal-shift correction (Pupil.li_wolf): wavelength k's intensity at r is m_k^2 times its model's at m_k r;
    # the models share k S, so one batched evaluation on a grid reaching max(m) r_max, then a spline per wavelength
    lw = [pu.li_wolf() for pu in pupils]
    models, ms = [mo for mo, _ in lw], np.array([m for _, m in lw])
    rr_ext = np.arange(0.0, r_max * max(1.0, float(ms.max())) + 4.5 * h, h)
    n = max(prop.hankel_nodes(mo, float(rr_ext[-1]), qerr) for mo in models)
    U_ext = prop.hankel_profiles(models, rr_ext, error=qerr, n=n)
    I_ext = U_ext.real ** 2 + U_ext.imag ** 2
    if np.all(ms == 1.0):
        I_each = I_ext[:, :rr.size]
        each = None
    else:
        each = [CubicSpline(rr_ext, Ik, bc_type=((1, 0.0), "not-a-knot")) for Ik in I_ext]
        I_each = np.array([m * m * sp(m * rr) for sp, m in zip(each, ms)])
    I = weights @ I_each
    spl = CubicSpline(rr, I, bc_type=((1, 0.0), "not-a-knot"))
    idx = np.unique(np.linspace(0, rr.size - 2, 256).astype(int))
    mids = rr[idx] + 0.5 * h
    if each is None:
        exact_mid = weights @ (np.abs(prop.hankel_profiles(models, mids, error=qerr, n=n)) ** 2)
        spl_err = float(np.abs(spl(mids) - exact_mid).max())
    else:
        # the two interpolations, each against what it interpolates: every wavelength's spline against its exact
        # profile at midpoints of the shared grid (one batched evaluation), the weighted spline against the sum
        # of the wavelengths' splines at their scaled radii
        idx_e = np.unique(np.linspace(0, rr_ext.size - 2, 256).astype(int))
        mids_e = rr_ext[idx_e] + 0.5 * h
        I_mid = np.abs(prop.hankel_profiles(models, mids_e, error=qerr, n=n)) ** 2
        err_each = sum(wk * m * m * float(np.abs(sp(mids_e) - Ik).max())
                       for sp, Ik, m, wk in zip(each, I_mid, ms, weights))
        summed = sum(wk * m * m * sp(m * mids) for sp, m, wk in zip(each, ms, weights))
        spl_err = err_each + float(np.abs(spl(mids) - summed).max())
    total_f += spl(np.sqrt(r2))
    engines["hankel"] = len(pupils)
    # quadrature (error * 1e-3 of each ideal peak), azimuthal averaging of the lattice factor and the
    # measured spline error x 2, per fine cell. Lattice: the 4-fold part the average leaves out was measured
    # (hankel vs 2-D mft, 17 um pixels, both lenses, 10-10.4 um) at <= 0.0037 x anisotropy of the ideal peak
    # and <= 0.27 x anisotropy of the wavelength's own peak pixel: bound min(0.01 ideal, 1.0 own peak) per
    # fine cell, times n_sub^2 cells per pixel by the caller (test_radial_lattice_error_bound checks it).
    own = I_each.max(axis=1)
    quad = sum(wk * (qerr * _ideal_peak(pu) + pu.lattice_anisotropy() * min(0.01 * _ideal_peak(pu), float(ok)))
               for pu, wk, ok in zip(pupils, weights, own))
    p = n_sub * dx
    debye = sum(wk * debye_pixel_error(pu, float(ok), p, _largest_pixel(rr, Ik, p))
                for pu, wk, ok, Ik in zip(pupils, weights, own, I_each))
    log.debug('radial sensor: quad+lattice %.3g, spline %.3g (power per um^2), debye %.3g (power per pixel)',
              quad, 2 * spl_err, debye)
    return (quad + 2 * spl_err) * dx * dx * n_sub * n_sub / P_in, debye / P_in


def _largest_pixel(r: np.ndarray, intensity: np.ndarray, pitch_um: float, n: int = 16) -> float:
    """Largest power of a pixel (``intensity`` x um^2) of a rotationally symmetric intensity sampled at radii ``r``
    on a grid of ``pitch_um`` pixels centred on the axis: the pixels along the axis and the diagonal, each integrated
    on ``n`` x ``n`` points (an estimate of the peak pixel; the Debye estimate's amplitude and scale part)."""
    J = max(1, int(r[-1] // pitch_um))
    c = np.arange(J) * pitch_um
    x = ((np.arange(n) + 0.5) / n - 0.5) * pitch_um
    best = 0.0
    for cy_scale in (0.0, 1.0):  # along the axis, along the diagonal
        X = c[:, None, None] + x[None, :, None]
        Y = cy_scale * c[:, None, None] + x[None, None, :]
        vals = np.interp(np.hypot(X, Y), r, intensity).sum(axis=(1, 2)) * (pitch_um / n) ** 2
        best = max(best, float(vals.max()))
    return best


def debye_pixel_error(pupil: Pupil, own_peak: float, pitch_um: float, own_pixel_peak: float | None = None) -> float:
    """Estimated largest error of a pixel (power, in the units of ``own_peak`` x um^2) of the direction-sine engines'
    on-axis PSF at defocus: the rim wave's phase error ``delta`` (:meth:`Pupil.rim_phase_error`) on the wave the rim
    sends to the axis, ``U_r = a_r J0(kappa r)`` (``kappa = k S``, S the rim's direction sine), against the rest of
    the field ``U_c``: ``|dP| <= 2 t |a_c a_r| |int_pix J0| + t^2 |a_r|^2 int_pix J0^2`` (``t = 2|sin(delta/2)|``), with
    ``|a_c|, |a_r| <= sqrt(own_peak)`` and the integrals over the pixel centred on the axis (where the rim waves
    meet in phase). A pixel several times the rim wave's ring spacing (``2 pi / kappa``) averages most of it out:
    this is what keeps the band PSF's error small on pixels although the fine-grid error is O(1) at the axis. Plus
    the amplitude and scale the Debye model misses (:func:`metafovea.optics.psf.debye_error_bound`, part ii) of
    ``own_pixel_peak`` (the PSF's largest pixel at this wavelength; ``own_peak`` x the pixel's area if not given)."""
    t, scale_rel = debye_error_parts(pupil)
    pix = own_peak * pitch_um * pitch_um if own_pixel_peak is None else own_pixel_peak
    scale = scale_rel * pix  # psf.debye_error_bound's (ii)
    if t == 0.0:
        return scale
    # the rim wave's amplitude on the axis: the end point of U(0) = int_0^S 2 pi s P(s) exp(i Phi(s)) ds,
    # 2 pi S |P(S)| / |Phi'(S)|, and never more than the field's own peak amplitude
    S = pupil.radius
    h = 1e-6 * S
    zero = np.zeros(2)
    dphi = float(np.diff(pupil.li_wolf()[0].phase(np.array([S - 2 * h, S]), zero))[0]) / (2 * h)
    a_c = math.sqrt(own_peak)
    p_rim = float(np.abs(pupil.amplitude(np.array([S]), zero[:1]))[0])
    a_r = min(a_c, 2 * math.pi * S * p_rim / max(abs(dphi), 1e-300))
    kappa = pupil.k * pupil.radius
    n = max(32, int(math.ceil(8 * kappa * pitch_um / math.pi)))  # 16 samples per period of J0
    x = ((np.arange(n) + 0.5) / n - 0.5) * pitch_um
    j = special.j0(kappa * np.hypot(x[None, :], x[:, None]))
    cell = (pitch_um / n) ** 2
    i1, i2 = abs(float(j.sum())) * cell, float((j * j).sum()) * cell
    return 2.0 * t * a_c * a_r * i1 + t * t * a_r * a_r * i2 + scale


# ----------------------------------------------------------------------------------------------
# sensor_psf and its steps
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Grid:
    """The pixel window (``size`` x ``size`` pixels of ``pitch``, lower-left pixel edge ``x0``, ``y0``) and the
    fine grid the wave engines sample it on (``n_sub`` x ``n_sub`` samples of ``dx`` per pixel, centres ``xs``,
    ``ys``; ``ax`` relative to the chief ray)."""

    pitch: float
    size: int
    x0: float
    y0: float
    n_sub: int
    dx: float
    ax: np.ndarray
    xs: np.ndarray
    ys: np.ndarray
    #: full width (um) the ray spread asked for when the window was sized automatically, else None
    wanted_um: float | None

    @property
    def width_um(self) -> float:
        return self.size * self.pitch


@dataclass
class _Tally:
    """What the engines add up: power per pixel, the wave intensity on the fine grid (integrated over the pixels
    at the end), the absolute error bound (fraction of the incident power per pixel) and the engines used."""

    pix: np.ndarray
    fine: np.ndarray
    est_abs: float = 0.0
    engines: dict[str, int] = field(default_factory=dict)


def _sensor_grid(lens: LensDesign, chief: np.ndarray, p: float, w: np.ndarray, spreads: np.ndarray, r_diff: float,
                 size_px: int | None, max_size_px: int) -> _Grid:
    """The window: ``size_px`` pixels, or enough for the ray spread of the wavelengths carrying 99 % of the weight
    plus 6 diffraction radii (capped at ``max_size_px``); sub-sampled below the intensity's Nyquist pitch."""
    wanted = None
    if size_px is None:
        order = np.argsort(-w)
        keep = order[: int(np.searchsorted(np.cumsum(w[order]), 0.99) + 1)]
        half = float(spreads[keep].max()) + 6 * r_diff + p
        size = min(max_size_px, 2 * int(math.ceil(half / p)) + 1)
        wanted = 2 * half
    else:
        size = check_int("size_px", size_px, 1, 8192)
    L = size * p
    n_sub = max(1, int(math.ceil(p / (0.95 * nyquist_pitch_um(lens)))))
    nf = size * n_sub
    dx = p / n_sub
    ax = (np.arange(nf) - (nf - 1) / 2) * dx
    return _Grid(p, size, chief[0] - L / 2, chief[1] - L / 2, n_sub, dx, ax, chief[0] + ax, chief[1] + ax, wanted)


def _auto_engines(sets: list[PupilSet], active: list[int], w: np.ndarray, spreads: np.ndarray, g: _Grid,
                  r_diff: float, P_in: float, error: float, budget: float
                  ) -> tuple[list[int], list[int], dict[int, np.ndarray], dict[int, float]]:
    """Split the wavelengths ``active`` between the geometric and the wave engines (``engine='auto'``).

    Geometric maps of every wavelength (one shared ray set): their pixel peaks bound the error a geometric
    treatment would make (GEO_ERROR x own peak, calibrated against the wave engines). The wavelengths that
    remove the most error per unit of wave-engine cost go to the wave engines first, until the remaining bound
    fits in half the error budget or the cost budget is spent. Returns (geometric, wave, geometric maps,
    geometric bounds); the maps and bounds are reused for the geometric ones.
    """
    p = g.pitch
    n_est = min(150_000, _n_rays(float(spreads[active].max()), p))
    gmaps = dict(zip(active, geometric_pixels_multi([sets[k].focus for k in active], np.ones(len(active)),
                                                    g.x0, g.y0, p, g.size, n_est, each=True) / P_in))
    gpeak = {k: float(gmaps[k].max()) for k in active}
    gbound = {k: _geo_bound(sets[k].focus, gpeak[k], spreads[k], r_diff, p, P_in) for k in active}
    gsum = sum(w[k] * gmaps[k] for k in active)
    target = 0.5 * error * 0.5 * float(gsum.max())  # half the error budget; peak bound from below
    costs = {k: _wave_cost(sets[k].focus, g.xs, g.ys, r_diff, p, error) for k in active}
    # most error removed per unit of wave-engine cost first
    order = sorted(active, key=lambda k: -w[k] * gbound[k] / max(costs[k], 1.0))
    remaining = sum(w[k] * gbound[k] for k in active)
    budget_used = 0.0
    geo_k: list[int] = []
    wave_k: list[int] = []
    for k in order:
        cost = costs[k]
        if remaining <= target or budget_used + cost > budget or cost > MFT_BUDGET:
            geo_k.append(k)  # accurate enough, or over the cost budget: the estimate says so
            continue
        budget_used += cost
        wave_k.append(k)
        remaining -= w[k] * gbound[k]
    return geo_k, wave_k, gmaps, gbound


def _add_geometric(t: _Tally, sets: list[PupilSet], geo_k: list[int], w: np.ndarray, spreads: np.ndarray, g: _Grid,
                   r_diff: float, P_in: float, traced: tuple[dict[int, np.ndarray], dict[int, float]] | None) -> None:
    """Ray-traced pixels of the wavelengths ``geo_k`` and their error bounds (``traced``: the maps and bounds of
    the auto engine's estimation pass, which already traced them)."""
    if not geo_k:
        return
    p = g.pitch
    if traced is not None:
        gmaps, gbound = traced
        t.pix += sum(w[k] * gmaps[k] for k in geo_k)
        t.est_abs += sum(w[k] * gbound[k] for k in geo_k)
    else:
        n_rays = max(_n_rays(spreads[k], p) for k in geo_k)
        gm = geometric_pixels_multi([sets[k].focus for k in geo_k], np.ones(len(geo_k)), g.x0, g.y0, p,
                                    g.size, n_rays, each=True) / P_in
        t.pix += np.tensordot(w[geo_k], gm, axes=1)
        gp = gm.reshape(len(geo_k), -1).max(axis=1)
        t.est_abs += sum(w[k] * _geo_bound(sets[k].focus, float(gv), spreads[k], r_diff, p, P_in)
                         for k, gv in zip(geo_k, gp))
    t.engines["geometric"] = len(geo_k)


def _add_wave(t: _Tally, sets: list[PupilSet], wave_k: list[int], w: np.ndarray, g: _Grid, r_diff: float,
              P_in: float, error: float, engine: str) -> None:
    """Wave-optical intensity of the wavelengths ``wave_k`` on the fine grid, only where their light lands.

    The ray boxes plus a diffraction margin (tails beyond 30 diffraction radii carry < 0.3 % of the power);
    batches of similar ray boxes share one window and one node set (one batched MFT each), or with
    ``engine='hankel'`` one Hankel evaluation per wavelength. On axis the MFT runs one wavelength at a time through
    :func:`metafovea.optics.psf.focus_intensity` (the focal-shift correction and the Debye bound need each
    wavelength's own scaled coordinates).
    """
    xs, ys, dx, n_sub = g.xs, g.ys, g.dx, g.n_sub
    mg = 30 * r_diff + 2 * g.pitch
    if wave_k and engine not in ("hankel", "rs") and not sets[wave_k[0]].focus.lens.phase_poly_rad and \
            all(float(np.hypot(*sets[k].focus.s0)) == 0.0 for k in wave_k):
        engine = "mft"  # on axis one wavelength at a time, with the focal-shift correction and its Debye bound
    boxes = {k: prop.ray_extent(sets[k].focus, 16) for k in wave_k}
    wave_k = [k for k in wave_k if boxes[k][1] + mg > xs[0] and boxes[k][0] - mg < xs[-1]
              and boxes[k][3] + mg > ys[0] and boxes[k][2] - mg < ys[-1]]
    batches: list[list[int]] = []
    for k in sorted(wave_k, key=lambda k: _box_area(boxes[k], mg)):
        # the union window may grow to 1.5x the area of the batch's smallest member (the MFT work grows
        # with the window's area times its node counts)
        per_wavelength = engine in ("hankel", "rs", "mft")
        if batches and (per_wavelength or _box_area(_union([boxes[j] for j in batches[-1]] + [boxes[k]]), mg)
                        <= 1.5 * _box_area(boxes[batches[-1][0]], mg)):
            batches[-1].append(k)
        else:
            batches.append([k])
    for bk in batches:
        ub = _union([boxes[k] for k in bk])
        i0, i1 = int(np.searchsorted(xs, ub[0] - mg)), int(np.searchsorted(xs, ub[1] + mg))
        j0, j1 = int(np.searchsorted(ys, ub[2] - mg)), int(np.searchsorted(ys, ub[3] + mg))
        if engine in ("hankel", "rs", "mft"):
            for k in bk:
                pu = sets[k].focus
                # on axis the Debye part over pixels (debye_pixel_error) in place of the fine grid's bound
                on_pixels = engine != "rs" and float(np.hypot(*pu.s0)) == 0.0 and not pu.lens.phase_poly_rad
                I, _, e = focus_intensity(pu, xs[i0:i1], ys[j0:j1], error=error, engine=engine, debye=not on_pixels)
                t.fine[j0:j1, i0:i1] += w[k] * I
                if on_pixels and I.size:
                    t.est_abs += w[k] * debye_pixel_error(pu, float(I.max()), g.pitch) / P_in
                t.est_abs += w[k] * e * _ideal_peak(pu) * dx * dx / P_in * n_sub * n_sub
                if engine in ("rs", "mft"):  # the light beyond the window, as for the batched MFT below
                    t.est_abs += w[k] * RS_TAIL * _ideal_peak(pu) * dx * dx / P_in * n_sub * n_sub
        else:
            # one batched MFT (shared kernels in design direction sines)
            t.fine[j0:j1, i0:i1] += prop.mft_intensity_multi([sets[k].focus for k in bk], w[bk],
                                                             xs[i0:i1], ys[j0:j1], error=error * 1e-3)
            # quadrature, and the light left outside the window (30 diffraction radii beyond the ray box:
            # the Airy envelope 8 / (pi x^3), x = 3.83 x 30, of the ideal peak)
            t.est_abs += sum(w[k] * (error * 1e-3 + RS_TAIL) * _ideal_peak(sets[k].focus) for k in bk) \
                * dx * dx / P_in * n_sub * n_sub
    if wave_k:
        t.engines[engine if engine in ("hankel", "rs") else "mft"] = len(wave_k)


def _add_fine(t: _Tally, g: _Grid, P_in: float) -> None:
    """Integrate the fine-grid wave intensity over the pixels, with the box filter's truncation error."""
    if not t.fine.any():
        return
    f, dx, n_sub = t.fine, g.dx, g.n_sub
    t.pix += box_integrate(f, n_sub) * dx * dx / P_in
    edge = max(f[0].max(), f[-1].max(), f[:, 0].max(), f[:, -1].max())
    t.est_abs += 0.05 * edge * dx * dx / P_in * n_sub  # truncation of the band-limited box filter


def _add_haze(t: _Tally, lens: LensDesign, sets: list[PupilSet], w: np.ndarray, g: _Grid) -> float:
    """The diffraction orders other than the focusing one as uniform disks; returns their total power."""
    haze_total = 0.0
    for wi, s in zip(w, sets):
        for h in s.haze:
            d = wi * h.power_fraction * disk_pixels(h.center_um, h.radius_um, g.x0, g.y0, g.pitch, g.size)
            t.pix += d
            haze_total += wi * h.power_fraction
            if h.order != 0 and h.radius_um < 3 * diffraction_radius_um(lens) / abs(h.order):
                # an order focusing near this plane: the uniform disk is only a rough stand-in for its
                # diffraction-limited spot, wrong by up to its own peak
                t.est_abs += float(d.max())
    return haze_total


def field_text(fpair: tuple[float, float]) -> str:
    """A field for people: ``0.3245`` (along x) or ``(0.3245, 0.1)`` (deg, 4 significant digits)."""
    fx, fy = (float(v) for v in fpair)
    return f"{fx:.4g}" if fy == 0.0 else f"({fx:.4g}, {fy:.4g})"


def _accuracy(lens: LensDesign, fpair: tuple[float, float], est_rel: float, error: float, g: _Grid,
              max_size_px: int, main: str, engine: str) -> dict[str, Any]:
    """Why a sensor PSF missed ``error`` (``main``: the part of the estimate that dominates, 'haze', 'geometric'
    or 'wave') and which parameters would change that: the data of its :class:`NotConvergedWarning`, also kept
    as ``info['accuracy']``."""
    L = g.width_um
    detail = ""
    if g.wanted_um is not None and g.size == max_size_px and g.wanted_um > L:
        reason = f"the window is capped at {max_size_px} pixels, narrower than the PSF"
        detail = f"it spreads over {g.wanted_um / 1000:.3g} mm, the window is {L / 1000:.3g} mm"
        advice = {"band_um": "a narrower band", "filter_um": "a narrow-band filter",
                  "pixel_pitch_um": "larger pixels, so a wider window", "max_size_px": "a larger window"}
    elif main == "haze":
        reason = "other diffraction orders focus near this plane (modelled as uniform disks)"
        advice = {}
    elif main == "poly":
        reason = ("the lens has a phase beyond the hyperbola (phase_poly_rad), which the direction-sine and ray "
                  "engines do not bound")
        advice = {"engine": "'auto' (the exact engine, within the cost budget)", "budget": "a larger cost budget"}
    elif main == "geometric" and engine == "geometric":
        reason = "the geometric engine asked for bounds its error loosely"
        advice = {"engine": "the wave engines ('auto')"}
    elif main == "geometric":
        reason = "wavelengths traced as rays (the wave engines' cost budget is spent)"
        advice = {"wavelengths_um": "fewer wavelengths", "budget": "a larger cost budget"}
    elif main == "debye":
        reason = ("the direction-sine (Debye) model at the defocused wavelengths (rim wave, amplitude and scale; a "
                  "conservative estimate: 8-13x the error measured against the exact engine for the paper's lenses "
                  "over the 10 um filter's band)")
        advice = {"filter_um": "a narrower band"}
    else:
        reason = "the wave engines' own error estimate"
        advice = {}
    advice["error"] = "accept the estimate"
    subject = f"sensor PSF of '{lens.name}'"
    msg = (f"{subject} at field {field_text(fpair)} deg: estimated error {est_rel:.2g} of the peak exceeds the "
           f"requested error {error:g}: {reason}{f' ({detail})' if detail else ''}; what changes it: "
           + ", ".join(f"{k} ({v})" for k, v in advice.items()))
    return {"subject": subject, "field_deg": float(np.hypot(*fpair)), "estimate": float(est_rel),
            "requested": float(error), "reason": reason, "advice": advice, "message": msg}


def sensor_psf(lens: LensDesign, *, pixel_pitch_um: float, field_deg: float | tuple[float, float] = 0.0,
               wavelengths_um: ArrayLike | None = None, weights: ArrayLike | None = None,
               post_set: PostSet | None = None, size_px: int | None = None, error: float = 1e-4,
               polarization: str | None = None,
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
    wl, w, error, engine, fpair, sets = checked_inputs(
        lens, wavelengths_um=wavelengths_um, weights=weights, error=error, engine=engine, refused="rs",
        allowed="'auto', 'hankel', 'mft' or 'geometric' for a sensor PSF (rs: psf)", field_deg=field_deg,
        post_set=post_set, polarization=polarization, quantize=quantize, lattice=lattice, z_um=z_um)
    z = lens.f_um if z_um is None else float(z_um)
    s0 = field_direction(field_deg)
    chief = z * s0 / math.sqrt(1.0 - float(s0 @ s0))
    r_diff = diffraction_radius_um(lens)
    spreads = np.array([_spread_um(s.focus) if s.focus is not None else 0.0 for s in sets])
    g = _sensor_grid(lens, chief, p, w, spreads, r_diff, size_px, max_size_px)
    P_in = math.pi * lens.radius_um ** 2

    t = _Tally(np.zeros((g.size, g.size)), np.zeros((g.ax.size, g.ax.size)))
    est_geo = est_debye = 0.0
    active = [k for k in range(wl.size) if sets[k].focus is not None and w[k] > 0]
    on_axis = float(np.hypot(*s0)) == 0.0
    poly = bool(lens.phase_poly_rad)
    rs_cost = 0.0
    radial = on_axis and engine in ("auto", "hankel") and active and (engine == "hankel" or (
        not poly and all(sets[k].focus.lattice_anisotropy() * 0.1 <= error for k in active)))
    if radial:
        # every wavelength wave-optically: the focusing order is rotationally symmetric on axis, the Bessel
        # matrix is shared by all wavelengths, and the weighted radial intensity is pixelised once
        est_radial, est_debye = _radial_sensor(lens, [sets[k].focus for k in active], w[active], g.ax, t.fine,
                                               error, g.dx, g.n_sub, P_in, t.engines)
        t.est_abs += est_radial + est_debye
    else:
        traced = None
        wave_engine = engine
        rs_cost = sum(_wave_cost(sets[k].focus, g.xs, g.ys, r_diff, p, error) for k in active) if poly else 0.0
        if engine == "auto" and poly:
            # every wavelength by the exact engine (the direction-sine model of an aberrated lens is not bounded);
            # over the cost budget, every wavelength traced as rays (any ray map; not bounded either: POLY_NOTE)
            geo_k, wave_k, wave_engine = ([], list(active), "rs") if rs_cost <= budget else (list(active), [], engine)
        elif engine in ("hankel", "mft"):
            geo_k, wave_k = [], list(active)
        elif engine == "geometric":
            geo_k, wave_k = list(active), []
        elif active:
            geo_k, wave_k, gmaps, gbound = _auto_engines(sets, active, w, spreads, g, r_diff, P_in, error, budget)
            traced = (gmaps, gbound)
        else:
            geo_k, wave_k = [], []
        est_before_geo = t.est_abs
        _add_geometric(t, sets, geo_k, w, spreads, g, r_diff, P_in, traced)
        est_geo = t.est_abs - est_before_geo
        _add_wave(t, sets, wave_k, w, g, r_diff, P_in, error, wave_engine)
    _add_fine(t, g, P_in)
    if poly and any(e in t.engines for e in ("hankel", "mft", "geometric")):
        t.est_abs = math.inf  # the direction-sine and ray models of an aberrated lens: POLY_NOTE
    est_before_haze = t.est_abs
    haze_total = _add_haze(t, lens, sets, w, g)

    pix = t.pix
    peak = float(pix.max())
    est_rel = t.est_abs / peak if peak > 0 else float("inf")
    accuracy = None
    if est_rel > error:
        main = max((("haze", t.est_abs - est_before_haze), ("geometric", est_geo), ("debye", est_debye),
                    ("wave", 0.0)), key=lambda kv: kv[1])
        accuracy = _accuracy(lens, fpair, est_rel, error, g, max_size_px,
                             "poly" if poly and math.isinf(est_rel) else
                             main[0] if main[1] > 0.5 * t.est_abs else "wave", engine)
        warnings.warn(NotConvergedWarning(accuracy["message"], accuracy), stacklevel=2)
    eng_name = "+".join(f"{k}" for k in sorted(t.engines))
    info = {"engines": t.engines, "n_sub": g.n_sub, "fine_pitch_um": g.dx, "size_px": g.size,
            "haze_power": haze_total, "seconds": time.perf_counter() - t0, "requested_error": error,
            "order_efficiency": float(np.dot(w, [s.info["order_efficiency"] for s in sets])),
            "quantize": quantize, "lattice": lattice, "z_um": z,
            "error_definition": "max abs error / PSF peak pixel (estimate)",
            "debye_error_estimate": est_debye / peak if peak > 0 else 0.0}
    if accuracy is not None:
        info["accuracy"] = accuracy
    if poly and math.isinf(t.est_abs):
        info["model_note"] = POLY_NOTE.replace("use engine 'rs' (what 'auto' picks)", (
            f"the exact engine would cost {rs_cost:.3g} work units, over the budget {budget:.3g}" if engine == "auto"
            else "engine 'auto' uses the exact (rs) engine within the cost budget"))
    elif not on_axis and t.engines.get("mft"):
        info["model_note"] = MFT_OFF_AXIS_NOTE.replace("use engine 'rs'", "not in error_estimate; psf() with "
                                                       "engine 'rs' gives the fine-grid PSF exactly")
    log.info("sensor_psf %s field %s deg: %s, %d px, sum %.4g, err %.2g, %.3f s", lens.name, field_text(fpair),
             eng_name, g.size, pix.sum(), est_rel, info["seconds"])
    return PSF(pix, p, (float(chief[0]), float(chief[1])), wl, w, fpair, sets[0].info["polarization"], eng_name,
               float(est_rel), float(pix.sum()), info)

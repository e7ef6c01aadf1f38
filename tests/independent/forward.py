"""An independent forward model of the two-lens, polarisation-multiplexed thermal camera, with what a real camera
gets wrong, for testing the reconstruction on recordings that its own simulator did not make.

Nothing here comes from ``metafovea``: the radiometry, optics, geometry, polariser, sensor and file writer are this
module's own, from the physics and the documented file format (``docs/measurement_format.md``). The model, in the
order the light meets it:

1. **Scene** (:class:`Scene`): a continuous temperature field ``T(y, x)`` in kelvin, in perifoveal pixels from the
   optical axis (``y`` down the rows), made of smooth primitives (polynomial background, Gaussian blobs, boxes and
   box lattices with Gaussian-softened edges, a 1/f texture of plane waves, or a raster of the user's). The
   generators of :data:`SCENES` keep it within 250-345 K.
2. **Radiance**: ``L(T) = int B_lambda(lambda, T) dlambda`` over the band (8-14 um, or a top-hat filter), by
   Gauss-Legendre quadrature of Planck's law (:func:`band_radiance`), tabulated for speed (:class:`RadianceTable`).
3. **Optics**: each channel's PSF is that of a circular pupil of its numerical aperture (the foveal F/2 lens NA1,
   the perifoveal F/1 lens NA2), polychromatic over the band, with optional defocus ``W020`` in waves at 10 um,
   from the Hankel integral of the pupil (:func:`psf_profile`), and integrated over the pixel
   (:func:`pixel_kernel`).
4. **Geometry**: the perifoveal image sees the scene at one sensor pixel per scene unit, centred; the foveal image
   sees it magnified ``s`` times about the centre ``c`` and rotated by ``rho``: the scene point ``q`` lands on the
   sensor at ``p = s R(rho) (q - c)`` (``(x, y)`` vectors, ``R`` the rotation matrix, ``p`` from the sensor
   centre; the convention of docs/measurement_format.md, "The foveal geometry", which the reconstruction's
   calibration and foveal operator share). Each pixel value is the scene's radiance convolved with the
   pixel-integrated PSF, computed on a supersampled grid (``Camera.supersample_x*`` samples per pixel) and read at
   the pixel centres (:func:`render_channels`).
5. **Sensor signal** of channel i: ``X_i = dark + (1 + e) k g_i V (L_i / L'(300 K))``: ``k`` DN per kelvin at 300 K
   (perifoveal), ``g_1 = (NA1/NA2)^2 (1 + gain_ratio_error)``, ``g_2 = 1``, ``V`` the vignetting
   (``(1 + (r/r0)^2)^-2``, a cos^4 law, ``1 - vignetting`` at the corner), ``1 + e`` the polariser's leak gain.
6. **Polariser** (:func:`polarizer_alpha`): angle ``theta(t) = theta_0 + 2 pi f t + j(t)`` (``f`` off nominal by
   ``rate_error``, optional linear ``rate_drift``, ``j`` an Ornstein-Uhlenbeck jitter); Malus ``cos^2 theta`` with
   the leak ``e``; the bolometer's first-order lag ``tau`` integrated exactly on a fine time grid (piecewise-linear
   input); an optional integration window per frame. Since the scene is static and the lag linear, every pixel
   sees the same effective ratio, so ``frames = alpha X_1 + (1 - alpha) X_2 + fpn_t + noise`` holds exactly.
7. **Sensor defects**: fixed pattern (pixel and column offsets) with a slow linear drift, white temporal noise
   ``NETD k``, dead (stuck in range) and saturated (stuck at full scale) pixels, 14-bit quantisation and clipping.

The file (:meth:`Recording.write`) carries only documented keys (docs/measurement_format.md and the issue's
schema; ``test_forward.py`` holds the list), the camera's *nominal* constants (never the deviated truth) and, for
scoring only, the true effective ``alpha``, ``truth_x1``/``truth_x2`` (the noise-free channel images in DN, so
that ``frames = alpha truth_x1 + (1 - alpha) truth_x2 + fpn_t + noise`` away from bad pixels), ``fpn`` and
``meta['truth']`` (every deviation and what was realised).

File map: radiometry, optics, scene primitives and generators, :class:`Camera` and :class:`Deviations`, the
polariser, rendering, the sensor, :func:`record` / :func:`write`.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage, signal, special

# ---------------------------------------------------------------------------------------------------------------
# Radiometry
# ---------------------------------------------------------------------------------------------------------------
H_PLANCK = 6.62607015e-34  # J s
C_LIGHT = 2.99792458e8  # m / s
K_BOLTZMANN = 1.380649e-23  # J / K
C2_UM_K = H_PLANCK * C_LIGHT / K_BOLTZMANN * 1e6  # second radiation constant, um K


def planck_radiance(wavelength_um: Any, temperature_k: Any) -> np.ndarray:
    """Blackbody spectral radiance ``B_lambda``, W m^-2 sr^-1 um^-1 (broadcast over both arguments)."""
    lam_m = np.asarray(wavelength_um, dtype=np.float64) * 1e-6
    t = np.asarray(temperature_k, dtype=np.float64)
    x = H_PLANCK * C_LIGHT / (lam_m * K_BOLTZMANN * t)
    return 2 * H_PLANCK * C_LIGHT ** 2 / lam_m ** 5 / np.expm1(x) * 1e-6


def _band_nodes(band_um: Sequence[float], filter_um: Sequence[float] | None, nodes: int) -> tuple[np.ndarray, ...]:
    """Gauss-Legendre nodes and weights (um) over the band, or over the top-hat filter ``(centre, width)`` cut to
    the band."""
    lo, hi = float(band_um[0]), float(band_um[1])
    if filter_um is not None:
        c, w = float(filter_um[0]), float(filter_um[1])
        lo, hi = max(lo, c - w / 2), min(hi, c + w / 2)
    if not 0 < lo < hi:
        raise ValueError(f"empty band {band_um} with filter {filter_um}")
    x, w = _leggauss(nodes)
    return 0.5 * (hi - lo) * x + 0.5 * (hi + lo), 0.5 * (hi - lo) * w


def band_radiance(temperature_k: Any, band_um: Sequence[float] = (8.0, 14.0), filter_um: Sequence[float] | None = None,
                  nodes: int = 64) -> np.ndarray:
    """In-band radiance ``int B_lambda dlambda``, W m^-2 sr^-1, by Gauss-Legendre quadrature (any shape)."""
    lam, w = _band_nodes(band_um, filter_um, nodes)
    t = np.asarray(temperature_k, dtype=np.float64)
    return np.tensordot(planck_radiance(lam, t[..., None]), w, axes=([-1], [0]))


def band_radiance_derivative(temperature_k: Any, band_um: Sequence[float] = (8.0, 14.0),
                             filter_um: Sequence[float] | None = None, nodes: int = 64) -> np.ndarray:
    """``dL/dT`` of :func:`band_radiance`, W m^-2 sr^-1 K^-1: ``dB/dT = B x / (T (1 - e^-x))``,
    ``x = c2 / (lambda T)``."""
    lam, w = _band_nodes(band_um, filter_um, nodes)
    t = np.asarray(temperature_k, dtype=np.float64)[..., None]
    x = C2_UM_K / (lam * t)
    return np.tensordot(planck_radiance(lam, t) * x / (t * -np.expm1(-x)), w, axes=([-1], [0]))


@dataclass(frozen=True)
class RadianceTable:
    """``L(T)`` tabulated every ``step_k`` over ``[lo_k, hi_k]`` and interpolated linearly (relative error ~1e-7)."""

    band_um: tuple[float, float] = (8.0, 14.0)
    filter_um: tuple[float, float] | None = None
    lo_k: float = 150.0
    hi_k: float = 450.0
    step_k: float = 0.02

    def __post_init__(self) -> None:
        t = np.arange(self.lo_k, self.hi_k + self.step_k / 2, self.step_k)
        object.__setattr__(self, "_t", t)
        object.__setattr__(self, "_l", band_radiance(t, self.band_um, self.filter_um))

    def __call__(self, temperature_k: np.ndarray) -> np.ndarray:
        t = np.asarray(temperature_k, dtype=np.float64)
        if t.size and (t.min() < self.lo_k or t.max() > self.hi_k):
            raise ValueError(f"scene temperatures {t.min():.1f}-{t.max():.1f} K outside the table "
                             f"{self.lo_k}-{self.hi_k} K")
        return np.interp(t, self._t, self._l)


@lru_cache(maxsize=32)
def _leggauss(n: int) -> tuple[np.ndarray, np.ndarray]:
    return np.polynomial.legendre.leggauss(n)


@lru_cache(maxsize=4)
def _table(band: tuple) -> RadianceTable:
    return RadianceTable(*band)


# ---------------------------------------------------------------------------------------------------------------
# Optics
# ---------------------------------------------------------------------------------------------------------------
def psf_profile(r_um: Any, wavelength_um: float, na: float, defocus_waves: float = 0.0,
                nodes: int | None = None) -> np.ndarray:
    """Intensity PSF of a circular pupil at radius ``r_um``, per um^2 (integrates to 1 over the plane).

    ``I(v) = |2 int_0^1 exp(i 2 pi W rho^2) J0(v rho) rho drho|^2``, ``v = 2 pi NA r / lambda``, ``W`` the defocus in
    waves (``I(0) = 1`` in focus, ``sinc^2(W)`` defocused); the area of ``I`` is ``lambda^2 / (pi NA^2)``.
    Gauss-Legendre quadrature in ``rho`` with ``nodes`` (default: enough for the largest ``v``)."""
    r = np.asarray(r_um, dtype=np.float64)
    v = 2 * np.pi * na * r / wavelength_um
    if nodes is None:
        nodes = int(np.max(v, initial=0.0)) + 48 + int(8 * abs(defocus_waves))
    rho, w = _leggauss(nodes)
    rho, w = 0.5 * (rho + 1), 0.5 * w
    pupil = np.exp(2j * np.pi * defocus_waves * rho ** 2) * rho * w
    amp = 2 * (special.j0(v[..., None] * rho) @ pupil)
    return np.abs(amp) ** 2 * np.pi * na ** 2 / wavelength_um ** 2


def airy(r_um: Any, wavelength_um: float, na: float) -> np.ndarray:
    """The in-focus Airy pattern ``[2 J1(v) / v]^2`` (peak 1), ``v = 2 pi NA r / lambda``: the reference of
    :func:`psf_profile`."""
    v = 2 * np.pi * na * np.asarray(r_um, dtype=np.float64) / wavelength_um
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (2 * special.j1(v) / v) ** 2
    return np.where(v == 0, 1.0, out)


def _band_psf(r_um: np.ndarray, na: float, band: tuple, defocus_waves: float, wavelengths: int) -> np.ndarray:
    """The polychromatic PSF (per um^2) at radii ``r_um``: wavelengths weighted by the band radiance at 300 K."""
    band_um, filter_um = band
    lam, w = _band_nodes(band_um, filter_um, wavelengths)
    w = w * planck_radiance(lam, 300.0)
    w = w / w.sum()
    r_tab = np.linspace(0.0, float(r_um.max()) + 1.0, 6000)
    if defocus_waves:
        prof = sum(wk * psf_profile(r_tab, lk, na, defocus_waves * 10.0 / lk) for lk, wk in zip(lam, w))
    else:  # in focus: the Airy pattern (what psf_profile gives, faster)
        prof = sum(wk * airy(r_tab, lk, na) * np.pi * na ** 2 / lk ** 2 for lk, wk in zip(lam, w))
    return np.interp(r_um, r_tab, prof)


@lru_cache(maxsize=16)
def disk_kernel(radius_px: float, n: int) -> np.ndarray:
    """(n, n) uniform disk of ``radius_px`` pixels on the pixel grid, centred, sum 1 (a defocus-like haze)."""
    u = np.arange(n) - n // 2
    d = (np.hypot(u[:, None], u[None, :]) <= radius_px).astype(float)
    return d / d.sum()


def gauss_kernel(sigma_px: float, n: int) -> np.ndarray:
    """(n, n) isotropic Gaussian of ``sigma_px`` pixels, centred, sum 1."""
    u = np.arange(n) - n // 2
    g = np.exp(-0.5 * (u[:, None] ** 2 + u[None, :] ** 2) / sigma_px ** 2)
    return g / g.sum()


def pixel_kernel(na: float, pitch_um: float, supersample: int, radius_px: int, *, band: tuple = ((8.0, 14.0), None),
                 defocus_waves: float = 0.0, wavelengths: int = 9, box_nodes: int = 8) -> np.ndarray:
    """The pixel-integrated PSF ``K(p) = int_pixel PSF(p - u) du`` on a grid of ``1 / supersample`` pixel steps,
    ``(2 m + 1, 2 m + 1)`` with ``m = radius_px * supersample``, normalised to sum 1 (the energy beyond the radius,
    ~2 % for an Airy tail, is dropped). The pixel box is integrated by Gauss-Legendre quadrature."""
    m = int(radius_px * supersample)
    g = np.arange(-m, m + 1) / supersample  # px
    u, wu = _leggauss(box_nodes)
    u, wu = 0.5 * u, 0.5 * wu
    py = (g[:, None, None, None] - u[None, None, :, None]) * pitch_um
    px = (g[None, :, None, None] - u[None, None, None, :]) * pitch_um
    r = np.sqrt(py ** 2 + px ** 2)
    k = np.einsum("abij,i,j->ab", _band_psf(r, na, band, defocus_waves, wavelengths), wu, wu)
    k = k / k.sum()
    k.setflags(write=False)
    return k


def file_psf(kernel: np.ndarray, supersample: int) -> np.ndarray:
    """The pixel-grid PSF (odd size, centred, sum 1) of a supersampled pixel kernel: its samples at whole pixels."""
    m = kernel.shape[0] // 2
    k = kernel[m % supersample::supersample, m % supersample::supersample]
    return (k / k.sum()).astype(np.float32)


# ---------------------------------------------------------------------------------------------------------------
# Scene primitives: value(y, x) in kelvin, added into an output on a tensor grid (ys, xs) or at points (Y, X)
# ---------------------------------------------------------------------------------------------------------------
EDGE_SIGMA_PX = 0.15  # Gaussian softening of every edge, perifoveal px (0.9 foveal px): sampled without aliasing


def _softbox(u: np.ndarray, a: float, b: float, s: float) -> np.ndarray:
    k = 1.0 / (math.sqrt(2.0) * s)
    return 0.5 * (special.erf((u - a) * k) - special.erf((u - b) * k))


def _train(u: np.ndarray, a: float, b: float, period: float | None, width: float | None, s: float) -> np.ndarray:
    """A soft box over ``[a, b]``, or a train of soft pulses of ``width`` every ``period`` starting at ``a``."""
    if not period:
        return _softbox(u, a, b, s)
    n = max(int((b - a - width) // period) + 1, 1)
    k0 = np.clip(np.floor((u - a) / period), 0, n - 1)
    out = np.zeros_like(u, dtype=np.float64)
    for d in (-1.0, 0.0, 1.0):
        k = k0 + d
        ok = (k >= 0) & (k <= n - 1)
        lo = a + k * period
        out += np.where(ok, _softbox(u - lo, 0.0, width, s), 0.0)
    return out


def _span(v: np.ndarray, lo: float, hi: float) -> slice:
    return slice(int(np.searchsorted(v, lo)), int(np.searchsorted(v, hi, side="right")))


@dataclass(frozen=True)
class Poly:
    """``t0 + gy y + gx x + qyy y^2 + qxx x^2 + qxy x y`` (K; y, x in px)."""

    t0: float = 0.0
    gy: float = 0.0
    gx: float = 0.0
    qyy: float = 0.0
    qxx: float = 0.0
    qxy: float = 0.0

    def scaled(self, k: float) -> Poly:
        return Poly(*(k * v for v in (self.t0, self.gy, self.gx, self.qyy, self.qxx, self.qxy)))

    def value(self, y: np.ndarray, x: np.ndarray) -> np.ndarray:
        return self.t0 + self.gy * y + self.gx * x + self.qyy * y * y + self.qxx * x * x + self.qxy * x * y

    def add_grid(self, out: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> None:
        out += self.value(ys[:, None], xs[None, :])

    def add_points(self, out: np.ndarray, y: np.ndarray, x: np.ndarray) -> None:
        out += self.value(y, x)


@dataclass(frozen=True)
class Blob:
    """A Gaussian ``amp exp(-r^2 / 2 sigma^2)`` about ``(y0, x0)``."""

    y0: float
    x0: float
    sigma: float
    amp: float

    def scaled(self, k: float) -> Blob:
        return replace(self, amp=k * self.amp)

    def _reach(self) -> float:
        return 6.5 * self.sigma

    def add_grid(self, out: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> None:
        r = self._reach()
        sy, sx = _span(ys, self.y0 - r, self.y0 + r), _span(xs, self.x0 - r, self.x0 + r)
        ey = np.exp(-0.5 * ((ys[sy] - self.y0) / self.sigma) ** 2)
        ex = np.exp(-0.5 * ((xs[sx] - self.x0) / self.sigma) ** 2)
        out[sy, sx] += self.amp * ey[:, None] * ex[None, :]

    def add_points(self, out: np.ndarray, y: np.ndarray, x: np.ndarray) -> None:
        r = self._reach()
        m = (np.abs(y - self.y0) < r) & (np.abs(x - self.x0) < r)
        out[m] += self.amp * np.exp(-0.5 * ((y[m] - self.y0) ** 2 + (x[m] - self.x0) ** 2) / self.sigma ** 2)


@dataclass(frozen=True)
class Box:
    """``amp`` over ``[y0, y1] x [x0, x1]`` with soft edges; along an axis with a ``period`` the box is a lattice of
    pulses ``width`` wide (windows of a facade, the bars of a chart)."""

    y0: float
    y1: float
    x0: float
    x1: float
    amp: float
    period_y: float | None = None
    width_y: float | None = None
    period_x: float | None = None
    width_x: float | None = None
    edge: float = EDGE_SIGMA_PX

    def scaled(self, k: float) -> Box:
        return replace(self, amp=k * self.amp)

    def _fy(self, y: np.ndarray) -> np.ndarray:
        return _train(y, self.y0, self.y1, self.period_y, self.width_y, self.edge)

    def _fx(self, x: np.ndarray) -> np.ndarray:
        return _train(x, self.x0, self.x1, self.period_x, self.width_x, self.edge)

    def add_grid(self, out: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> None:
        r = 6.5 * self.edge
        sy, sx = _span(ys, self.y0 - r, self.y1 + r), _span(xs, self.x0 - r, self.x1 + r)
        out[sy, sx] += self.amp * self._fy(ys[sy])[:, None] * self._fx(xs[sx])[None, :]

    def add_points(self, out: np.ndarray, y: np.ndarray, x: np.ndarray) -> None:
        r = 6.5 * self.edge
        m = (y > self.y0 - r) & (y < self.y1 + r) & (x > self.x0 - r) & (x < self.x1 + r)
        out[m] += self.amp * self._fy(y[m]) * self._fx(x[m])


@dataclass(frozen=True)
class Texture:
    """``sum_m amp_m cos(ky_m y + kx_m x + phase_m)``: plane waves of log-uniform frequency and equal amplitude (a 1/f
    amplitude spectrum)."""

    ky: tuple[float, ...]
    kx: tuple[float, ...]
    phase: tuple[float, ...]
    amp: tuple[float, ...]

    def scaled(self, k: float) -> Texture:
        return replace(self, amp=tuple(k * a for a in self.amp))

    def add_grid(self, out: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> None:
        ky, kx, ph, a = (np.asarray(v) for v in (self.ky, self.kx, self.phase, self.amp))
        ay = ys[:, None] * ky[None, :] + ph[None, :]
        ax = xs[:, None] * kx[None, :]
        out += (np.cos(ay) * a) @ np.cos(ax).T - (np.sin(ay) * a) @ np.sin(ax).T

    def add_points(self, out: np.ndarray, y: np.ndarray, x: np.ndarray) -> None:
        for ky, kx, ph, a in zip(self.ky, self.kx, self.phase, self.amp):
            out += a * np.cos(ky * y + kx * x + ph)


@dataclass(frozen=True)
class Raster:
    """A kelvin raster ``(h, w)`` spanning the perifoveal field ``[-H/2, H/2] x [-W/2, W/2]`` (pixel centres at
    ``(i + 1/2) H / h - H / 2``), interpolated by cubic splines (clamped at its border)."""

    values: np.ndarray = field(compare=False)
    field_shape: tuple[int, int] = (280, 290)

    def scaled(self, k: float) -> Raster:
        return replace(self, values=k * np.asarray(self.values))

    def add_points(self, out: np.ndarray, y: np.ndarray, x: np.ndarray) -> None:
        h, w = np.shape(self.values)
        H, W = self.field_shape
        iy = (y + H / 2) * h / H - 0.5
        ix = (x + W / 2) * w / W - 0.5
        out += ndimage.map_coordinates(np.asarray(self.values, dtype=np.float64), [iy.ravel(), ix.ravel()], order=3,
                                       mode="nearest").reshape(out.shape)

    def add_grid(self, out: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> None:
        Y, X = np.meshgrid(ys, xs, indexing="ij")
        self.add_points(out, Y, X)


@dataclass(frozen=True)
class Scene:
    """``offset + sum(primitives)`` in kelvin; ``token`` names it for the render cache."""

    primitives: tuple
    offset: float = 0.0
    token: str = ""

    def grid(self, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
        out = np.full((len(ys), len(xs)), self.offset, dtype=np.float64)
        for p in self.primitives:
            p.add_grid(out, np.asarray(ys, dtype=np.float64), np.asarray(xs, dtype=np.float64))
        return out

    def points(self, y: np.ndarray, x: np.ndarray) -> np.ndarray:
        y, x = np.broadcast_arrays(np.asarray(y, dtype=np.float64), np.asarray(x, dtype=np.float64))
        out = np.full(y.shape, self.offset, dtype=np.float64)
        for p in self.primitives:
            p.add_points(out, y, x)
        return out

    def about(self, mean: float, k: float) -> Scene:
        """``mean + k (T - mean)``."""
        return Scene(tuple(p.scaled(k) for p in self.primitives), mean + k * (self.offset - mean), self.token)


# ---------------------------------------------------------------------------------------------------------------
# Scene generators: (rng, half_h, half_w, fovea) -> Scene, half sizes and the fovea's half size in perifoveal px
# ---------------------------------------------------------------------------------------------------------------
SCENE_RANGE_K = (252.0, 343.0)


def _texture(rng: np.random.Generator, n: int, f_lo: float, f_hi: float, rms: float) -> Texture:
    f = np.exp(rng.uniform(np.log(f_lo), np.log(f_hi), n))
    ang = rng.uniform(0, np.pi, n)
    k = 2 * np.pi * f
    return Texture(tuple(k * np.sin(ang)), tuple(k * np.cos(ang)), tuple(rng.uniform(0, 2 * np.pi, n)),
                   tuple(np.full(n, rms * math.sqrt(2.0 / n))))


def _gradient(rng, hh, hw, fov):
    prims = [Poly(0.0, 20.0 / hh, 10.0 / hw, -4.0 / hh ** 2, 5.0 / hw ** 2, 3.0 / (hh * hw))]
    for _ in range(3):
        prims.append(Blob(rng.uniform(-hh, hh), rng.uniform(-hw, hw), rng.uniform(0.2, 0.4) * hh,
                          rng.choice([-1, 1]) * rng.uniform(4, 9)))
    return prims, 296.0


def _hotspots(rng, hh, hw, fov):
    prims = [Poly(0.0, 8.0 / hh, -4.0 / hw)]
    for _ in range(24):
        prims.append(Blob(rng.uniform(-hh, hh), rng.uniform(-hw, hw), rng.uniform(0.6, 5.0), rng.uniform(8, 45)))
    for _ in range(7):  # detail only the foveal channel resolves
        prims.append(Blob(rng.uniform(-0.8, 0.8) * fov, rng.uniform(-0.8, 0.8) * fov, rng.uniform(0.15, 0.6),
                          rng.uniform(10, 35)))
    return prims, 286.0


def _buildings(rng, hh, hw, fov):
    horizon = 0.25 * hh
    prims: list = [Poly(0.0, 12.0 / hh), Box(horizon, 2 * hh, -2 * hw, 2 * hw, 26.0)]  # sky, ground
    x = -hw - 10.0
    while x < hw + 10:
        w = rng.uniform(12, 45)
        top = horizon - rng.uniform(25, 1.2 * hh)
        amp = rng.uniform(18, 40)
        prims.append(Box(top, horizon, x, x + w, amp))
        py, px = rng.uniform(2.0, 3.5), rng.uniform(2.0, 3.5)  # windows
        prims.append(Box(top + 1.5, horizon - 3, x + 1.5, x + w - 1.5, rng.choice([-1, 1]) * rng.uniform(4, 12),
                         py, 0.45 * py, px, 0.5 * px))
        x += w + rng.uniform(-3, 8)
    for _ in range(5):  # hot windows and vents
        prims.append(Blob(rng.uniform(-hh, horizon), rng.uniform(-hw, hw), rng.uniform(0.3, 1.5), rng.uniform(15, 40)))
    prims.append(Box(-0.5 * fov, 0.4 * fov, -0.45 * fov, 0.55 * fov, 10.0, 1.1, 0.5, 0.9, 0.45))  # a window grid
    return prims, 262.0


def _texture_scene(rng, hh, hw, fov):
    return [_texture(rng, 128, 1.0 / (4 * max(hh, hw)), 2.5, 12.0)], 297.0


def _glyphs(rng, y0, x0, size, n, amp):
    """A line of ``n`` text-like glyphs (two to four strokes each) of height ``size`` starting at ``(y0, x0)``."""
    out = []
    s = size / 5.0
    for g in range(n):
        gx = x0 + g * 4 * s
        for _ in range(rng.integers(2, 5)):
            if rng.random() < 0.5:  # vertical stroke
                c = gx + rng.integers(0, 3) * s
                out.append(Box(y0, y0 + size, c, c + 0.8 * s, amp))
            else:
                r = y0 + rng.integers(0, 3) * 2 * s
                out.append(Box(r, r + 0.8 * s, gx, gx + 3 * s, amp))
    return out


def _bars(rng, hh, hw, fov):
    prims: list = [Poly(0.0, 6.0 / hh, 6.0 / hw)]
    periods = (8.0, 5.0, 3.0, 2.0, 1.4)
    for i, p in enumerate(periods):  # bar groups in the periphery
        y = -0.85 * hh + i * 0.33 * hh
        prims.append(Box(y, y + 0.25 * hh, -0.9 * hw, -0.9 * hw + 6 * p, 22.0, None, None, p, p / 2))
        prims.append(Box(-0.9 * hh, -0.9 * hh + 6 * p, 0.2 * hw + i * 0.14 * hw, 0.3 * hw + i * 0.14 * hw, -18.0,
                         p, p / 2, None, None))
    for i, p in enumerate((1.0, 0.7, 0.5, 0.35)):  # finer ones in the fovea
        y = -0.8 * fov + i * 0.4 * fov
        prims.append(Box(y, y + 0.3 * fov, -0.8 * fov, -0.8 * fov + 5 * p, 20.0, None, None, p, p / 2))
        prims.append(Box(-0.1 * fov, -0.1 * fov + 5 * p, 0.1 * fov + i * 0.2 * fov, 0.25 * fov + i * 0.2 * fov,
                         -15.0, p, p / 2, None, None))
    for row in range(4):  # text lines: large in the periphery, small in the fovea
        prims += _glyphs(rng, 0.3 * hh + row * 0.15 * hh, -0.3 * hw, 8.0, 10, 25.0)
    prims += _glyphs(rng, 0.45 * fov, -0.7 * fov, 2.5, 7, 24.0)
    return prims, 292.0


def _mixed(rng, hh, hw, fov):
    prims, _ = _buildings(rng, hh, hw, fov)
    prims.append(_texture(rng, 96, 1.0 / (4 * max(hh, hw)), 2.5, 3.0))
    for _ in range(5):
        prims.append(Blob(rng.uniform(-0.8, 0.8) * fov, rng.uniform(-0.8, 0.8) * fov, rng.uniform(0.2, 0.8),
                          rng.uniform(10, 30)))
    prims += _glyphs(rng, 0.5 * fov, -0.6 * fov, 3.0, 5, -12.0)
    return prims, 262.0


#: the scene generators by name (``record(scene=name)``): smooth gradients (little texture in the fovea), hot spots,
#: buildings (edges, window lattices), a 1/f texture, text-like bars (resolution-chart groups and glyphs), and a mix
SCENES: dict[str, Callable] = {"gradient": _gradient, "hotspots": _hotspots, "buildings": _buildings,
                               "texture": _texture_scene, "bars": _bars, "mixed": _mixed}


def scene_range(scene: Scene, half: tuple[float, float], fov: float) -> tuple[float, float]:
    """The scene's min and max on a 0.5 px grid over the field and a 0.05 px grid over the fovea."""
    hh, hw = half
    coarse = scene.grid(np.arange(-hh - 4, hh + 4, 0.5), np.arange(-hw - 4, hw + 4, 0.5))
    fine = scene.grid(np.arange(-1.3 * fov, 1.3 * fov, 0.05), np.arange(-1.3 * fov, 1.3 * fov, 0.05))
    return float(min(coarse.min(), fine.min())), float(max(coarse.max(), fine.max()))


def make_scene(name: str, seed: int = 0, shape: tuple[int, int] = (280, 290), scale: float = 6.0) -> Scene:
    """The scene ``name`` of :data:`SCENES` for a sensor ``shape``, drawn with ``seed``, fitted into
    :data:`SCENE_RANGE_K` (scaled about its mean when it overshoots)."""
    if name not in SCENES:
        raise KeyError(f"scene {name!r}: one of {sorted(SCENES)}")
    rng = np.random.default_rng([seed, 1])
    hh, hw = shape[0] / 2, shape[1] / 2
    fov = min(hh, hw) / scale
    prims, offset = SCENES[name](rng, hh, hw, fov)
    s = Scene(tuple(prims), offset, f"{name}:{seed}:{shape}:{scale}")
    lo, hi = scene_range(s, (hh, hw), fov)
    mean = 0.5 * (SCENE_RANGE_K[0] + SCENE_RANGE_K[1])
    k = min(1.0, (SCENE_RANGE_K[1] - mean) / max(hi - mean, 1e-9), (mean - SCENE_RANGE_K[0]) / max(mean - lo, 1e-9))
    return s if k >= 1.0 else s.about(mean, 0.999 * k)


# ---------------------------------------------------------------------------------------------------------------
# The camera (nominal) and what the real one does differently
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Camera:
    """The camera's specification: what its file states (nominal values).

    The lenses: foveal ``f1_mm``/``d1_mm`` (150/75 mm, F/2), perifoveal ``f2_mm``/``d2_mm`` (25/25 mm, F/1) on
    one sensor: ``scale = f1 / f2`` and the foveal gain ``(NA1 / NA2)^2``, ``NA = sin(atan(D / 2 f))``.
    ``extinction`` and ``tau_s`` are what the datasheet states (the camera's true ones are
    :class:`Deviations`' fields of those names): ``state_device`` writes them into the file
    (``polarizer_extinction``, ``bolometer_tau_s``); a camera that does not know them leaves them out (the
    default). ``polarizer_phase_deg`` is stated in sync mode (and realised there unless ``Deviations.phase_deg``
    says otherwise)."""

    shape: tuple[int, int] = (280, 290)
    f1_mm: float = 150.0
    d1_mm: float = 75.0
    f2_mm: float = 25.0
    d2_mm: float = 25.0
    pixel_pitch_um: float = 17.0
    frame_rate_hz: float = 12.0
    polarizer_hz: float = 2.0
    polarizer_mode: str = "free"
    polarizer_phase_deg: float = 0.0  # sync: the polariser's angle at t = 0
    extinction: float = 0.0  # nominal (datasheet)
    tau_s: float = 0.0  # nominal (datasheet)
    state_device: bool = False
    integration_s: float = 0.0  # each frame averages the lagged signal over this window ending at its time
    band_um: tuple[float, float] = (8.0, 14.0)
    filter_um: tuple[float, float] | None = None
    counts_per_k: float = 40.0  # DN per K at 300 K through the perifoveal channel
    dark_dn: float = 1000.0
    adc_bits: int = 14
    quantize: bool = True
    netd_k: float = 0.05
    shutter_k: float = 300.0  # the closed shutter's temperature (calibration frames)
    supersample_x1: int = 3
    supersample_x2: int = 5
    psf_radius_px: tuple[int, int] = (10, 7)
    psf_wavelengths: int = 9
    time_substeps: int = 1000  # polariser time steps per frame interval

    def __post_init__(self) -> None:
        if self.polarizer_mode not in ("free", "sync"):
            raise ValueError(f"polarizer_mode {self.polarizer_mode!r}: 'free' or 'sync'")
        if self.supersample_x1 % 2 == 0 or self.supersample_x2 % 2 == 0:
            raise ValueError("supersampling must be odd (pixel centres are samples)")

    @property
    def na(self) -> tuple[float, float]:
        return (math.sin(math.atan(self.d1_mm / (2 * self.f1_mm))), math.sin(math.atan(self.d2_mm / (2 * self.f2_mm))))

    @property
    def scale(self) -> float:
        return self.f1_mm / self.f2_mm

    @property
    def foveal_gain(self) -> float:
        n1, n2 = self.na
        return (n1 / n2) ** 2

    @property
    def full_scale_dn(self) -> float:
        return float(2 ** self.adc_bits - 1)

    @property
    def noise_dn(self) -> float:
        return self.netd_k * self.counts_per_k

    @property
    def band(self) -> tuple:
        return (tuple(self.band_um), None if self.filter_um is None else tuple(self.filter_um))


@dataclass(frozen=True)
class Deviations:
    """How the real camera differs from its specification (every default 0: the nominal camera).

    Polariser: ``jitter_deg`` rms angle jitter (an Ornstein-Uhlenbeck process of correlation time
    ``jitter_corr_s``), ``rate_error`` (fraction of the nominal rate), ``rate_drift`` (fractional change of the rate
    over the recording), ``phase_deg`` (the realised angle at t = 0: None draws it for a free-running polariser, the
    stated one for sync), ``extinction`` (leak), ``tau_s`` (bolometer). Sensor: ``fpn_dn`` (rms of the pixel and
    column offsets), ``fpn_drift_dn`` (rms of a smooth pattern that grows linearly to this at the last frame),
    ``vignetting`` (relative loss at the corner), ``bad_pixels`` (fraction: half dead, stuck in range; half
    saturated). Foveal geometry: ``scale_error`` (fraction), ``centre_px`` ``(dy, dx)`` (the centre of the foveal
    field, perifoveal px from the axis), ``rotation_deg``; ``gain_ratio_error`` (fraction of the foveal gain);
    ``defocus_waves`` (both channels' PSF, waves at 10 um)."""

    jitter_deg: float = 0.0
    jitter_corr_s: float = 0.03
    rate_error: float = 0.0
    rate_drift: float = 0.0
    phase_deg: float | None = None
    extinction: float = 0.0
    tau_s: float = 0.0
    fpn_dn: float = 0.0
    fpn_drift_dn: float = 0.0
    vignetting: float = 0.0
    bad_pixels: float = 0.0
    scale_error: float = 0.0
    centre_px: tuple[float, float] = (0.0, 0.0)
    rotation_deg: float = 0.0
    gain_ratio_error: float = 0.0
    defocus_waves: float = 0.0

    def __post_init__(self) -> None:
        for name in ("jitter_deg", "extinction", "tau_s", "fpn_dn", "fpn_drift_dn", "vignetting", "bad_pixels",
                     "defocus_waves"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0")
        if self.jitter_corr_s <= 0 or not self.vignetting < 1 or not self.bad_pixels < 1:
            raise ValueError("jitter_corr_s > 0, vignetting < 1 and bad_pixels < 1")
        object.__setattr__(self, "centre_px", tuple(float(v) for v in self.centre_px))

    @property
    def changed(self) -> dict[str, Any]:
        """The fields that differ from the nominal camera."""
        nominal = Deviations()
        return {k: v for k, v in asdict(self).items() if k != "jitter_corr_s" and v != getattr(nominal, k)}


#: the ends of the issue's ranges, one deviation each (the grid's single cases)
RANGE_ENDS: dict[str, Deviations] = {
    "jitter 2 deg": Deviations(jitter_deg=2.0),
    "rate +5 %": Deviations(rate_error=0.05),
    "rate -5 %": Deviations(rate_error=-0.05),
    "extinction 1 %": Deviations(extinction=0.01),
    "extinction 5 %": Deviations(extinction=0.05),
    "tau 12 ms": Deviations(tau_s=0.012),
    "fpn 8 DN + drift 4 DN": Deviations(fpn_dn=8.0, fpn_drift_dn=4.0),
    "vignetting 20 %": Deviations(vignetting=0.2),
    "bad pixels 0.1 %": Deviations(bad_pixels=0.001),
    "scale +3 %": Deviations(scale_error=0.03),
    "scale -3 %": Deviations(scale_error=-0.03),
    "centre (3, -3) px": Deviations(centre_px=(3.0, -3.0)),
    "rotation 0.5 deg": Deviations(rotation_deg=0.5),
    "gain ratio +10 %": Deviations(gain_ratio_error=0.10),
    "gain ratio -10 %": Deviations(gain_ratio_error=-0.10),
    "defocus 1/4 wave": Deviations(defocus_waves=0.25),
}

#: combinations (a camera that does several things at once, each within range)
COMBINED: dict[str, Deviations] = {
    "polariser (jitter 1, rate +3 %, ext 3 %, tau 10 ms)": Deviations(jitter_deg=1.0, rate_error=0.03,
                                                                     extinction=0.03, tau_s=0.010),
    "geometry (scale +2 %, centre (1.5, 2) px, rot 0.3 deg)": Deviations(scale_error=0.02, centre_px=(1.5, 2.0),
                                                                         rotation_deg=0.3),
    "sensor (fpn 4+2 DN, vignetting 15 %, bad 0.1 %)": Deviations(fpn_dn=4.0, fpn_drift_dn=2.0, vignetting=0.15,
                                                                  bad_pixels=0.001),
    "everything, mid-range": Deviations(jitter_deg=1.0, rate_error=-0.02, extinction=0.02, tau_s=0.008, fpn_dn=4.0,
                                        fpn_drift_dn=2.0, vignetting=0.1, bad_pixels=0.001, scale_error=0.015,
                                        centre_px=(-1.0, 1.5), rotation_deg=-0.25, gain_ratio_error=0.05,
                                        defocus_waves=0.125),
}


# ---------------------------------------------------------------------------------------------------------------
# The polariser: effective alpha per frame
# ---------------------------------------------------------------------------------------------------------------
def first_order_lag(u: np.ndarray, dt: float, tau_s: float) -> np.ndarray:
    """``tau y' = u - y`` for ``u`` linear between samples ``dt`` apart, exactly; ``y_0 = u_0``."""
    if tau_s <= 0:
        return np.asarray(u, dtype=np.float64).copy()
    a = math.exp(-dt / tau_s)
    b0 = 1.0 - tau_s * (1.0 - a) / dt
    b1 = (1.0 - a) - b0
    zi = signal.lfiltic([b0, b1], [1.0, -a], [u[0]], [u[0]])
    return signal.lfilter([b0, b1], [1.0, -a], u, zi=zi)[0]


def polarizer_alpha(times_s: np.ndarray, camera: Camera, dev: Deviations,
                    rng: np.random.Generator) -> tuple[np.ndarray, dict[str, Any]]:
    """The effective mixing ratio ``alpha`` at each frame time (see the module docstring, step 6), and what was
    realised (rate, phase, jitter rms at the frames, the lag's phase and amplitude)."""
    t_frames = np.asarray(times_s, dtype=np.float64)
    dt = 1.0 / (camera.frame_rate_hz * camera.time_substeps)
    pre = max(0.5, 12 * dev.tau_s + camera.integration_s)
    t0, t1 = float(t_frames.min()) - pre, float(t_frames.max())
    n = int(math.ceil((t1 - t0) / dt)) + 2
    t = t1 - dt * np.arange(n)[::-1]  # the grid ends on the last frame
    rate = camera.polarizer_hz * (1.0 + dev.rate_error)
    if dev.phase_deg is not None:
        theta0 = math.radians(dev.phase_deg)
    elif camera.polarizer_mode == "sync":
        theta0 = math.radians(camera.polarizer_phase_deg)
    else:
        theta0 = float(rng.uniform(0.0, math.pi))
    duration = max(float(t_frames.max() - t_frames.min()), 1e-9)
    theta = theta0 + 2 * np.pi * rate * (t + 0.5 * dev.rate_drift * t * t / duration)
    jit = np.zeros(n)
    if dev.jitter_deg > 0:
        s = math.radians(dev.jitter_deg)
        r = math.exp(-dt / dev.jitter_corr_s)
        xi = rng.standard_normal(n)
        jit[0] = s * xi[0]
        jit[1:] = s * math.sqrt(1 - r * r) * xi[1:]
        jit = signal.lfilter([1.0], [1.0, -r], jit, zi=[0.0])[0] if n > 1 else jit
    c = np.cos(theta + jit) ** 2
    e = dev.extinction
    y = first_order_lag((c + e * (1 - c)) / (1 + e), dt, dev.tau_s)
    if camera.integration_s > 0:
        k = max(int(round(camera.integration_s / dt)), 1)
        cs = np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]))])
        y = np.concatenate([np.full(k, np.nan), (cs[k:] - cs[:-k]) / k])
    alpha = np.interp(t_frames, t, y)
    omega = 4 * np.pi * rate
    info = {"rate_hz": rate, "phase_deg": math.degrees(theta0) % 180.0,
            "jitter_rms_deg_at_frames": float(np.degrees(np.sqrt(np.mean(np.interp(t_frames, t, jit) ** 2)))),
            "lag_rad": math.atan(omega * dev.tau_s), "lag_amplitude": 1 / math.sqrt(1 + (omega * dev.tau_s) ** 2),
            "extinction": e, "tau_s": dev.tau_s, "rate_drift": dev.rate_drift}
    return np.clip(alpha, 0.0, 1.0), info


# ---------------------------------------------------------------------------------------------------------------
# Rendering: each channel's radiance image on the sensor (W m^-2 sr^-1), cached
# ---------------------------------------------------------------------------------------------------------------
_CACHE: OrderedDict = OrderedDict()
_CACHE_SIZE = 12


def _cached(key: tuple, make: Callable[[], np.ndarray]) -> np.ndarray:
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    v = make()
    v.setflags(write=False)
    _CACHE[key] = v
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return v


def _fine_axis(n: int, ss: int, margin: int) -> np.ndarray:
    """Sample positions (px from the sensor centre) of ``n`` pixels at ``ss`` samples each, plus ``margin``
    samples on either side; pixel ``i``'s centre is sample ``margin + i ss + ss // 2``."""
    k = np.arange(-margin, n * ss + margin)
    return (k + 0.5) / ss - n / 2


@dataclass(frozen=True)
class Geometry:
    """The foveal field: scale (f1/f2, true), centre ``(dy, dx)`` in perifoveal px, rotation (deg)."""

    scale: float = 6.0
    centre_px: tuple[float, float] = (0.0, 0.0)
    rotation_deg: float = 0.0


def _channel(scene: Scene, camera: Camera, channel: int, geometry: Geometry, defocus_waves: float,
             perfect: bool) -> np.ndarray:
    H, W = camera.shape
    ss = camera.supersample_x1 if channel == 1 else camera.supersample_x2
    if perfect:  # the pixel box alone
        kern = np.full((ss, ss), 1.0 / ss ** 2)
    else:
        kern = pixel_kernel(camera.na[channel - 1], camera.pixel_pitch_um, ss, camera.psf_radius_px[channel - 1],
                            band=camera.band, defocus_waves=defocus_waves, wavelengths=camera.psf_wavelengths)
    m = kern.shape[0] // 2
    py, px = _fine_axis(H, ss, m), _fine_axis(W, ss, m)
    if channel == 2:
        temp = scene.grid(py, px)
    else:
        s, (cy, cx), rho = geometry.scale, geometry.centre_px, math.radians(geometry.rotation_deg)
        if rho == 0.0:
            temp = scene.grid(cy + py / s, cx + px / s)
        else:  # q - c = R(-rho) p / s, (x, y) vectors
            Y, X = np.meshgrid(py, px, indexing="ij")
            cr, sr = math.cos(rho), math.sin(rho)
            temp = scene.points(cy + (-sr * X + cr * Y) / s, cx + (cr * X + sr * Y) / s)
    rad = _table(camera.band)(temp)
    conv = signal.fftconvolve(rad, kern, mode="valid")  # (H ss, W ss)
    return conv[ss // 2::ss, ss // 2::ss].copy()


def render_channels(scene: Scene, camera: Camera, geometry: Geometry, defocus_waves: float = 0.0, *,
                    perfect: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Both channels' in-band radiance on the sensor pixels, ``(H, W)`` each, W m^-2 sr^-1 (step 4); ``perfect``:
    through perfect lenses (the pixel box, no PSF)."""
    optics = (camera.shape, camera.na, camera.pixel_pitch_um, camera.band, camera.psf_radius_px,
              camera.psf_wavelengths, float(defocus_waves), perfect)
    token = scene.token or id(scene)
    r2 = _cached(("x2", token, optics, camera.supersample_x2),
                 lambda: _channel(scene, camera, 2, geometry, defocus_waves, perfect))
    r1 = _cached(("x1", token, optics, camera.supersample_x1, geometry),
                 lambda: _channel(scene, camera, 1, geometry, defocus_waves, perfect))
    return r1, r2


def vignetting_map(shape: tuple[int, int], corner_loss: float) -> np.ndarray:
    """``V = (1 + (r / r0)^2)^-2`` (cos^4 law) with ``V = 1 - corner_loss`` at the corner pixels' centres."""
    H, W = shape
    y = np.arange(H) + 0.5 - H / 2
    x = np.arange(W) + 0.5 - W / 2
    r2 = y[:, None] ** 2 + x[None, :] ** 2
    if corner_loss <= 0:
        return np.ones(shape)
    rc2 = float(r2.max())
    q = (1.0 - corner_loss) ** -0.5 - 1.0  # (rc / r0)^2
    return (1.0 + q * r2 / rc2) ** -2


# ---------------------------------------------------------------------------------------------------------------
# The sensor: fixed pattern, bad pixels, noise, ADC
# ---------------------------------------------------------------------------------------------------------------
def _unit_rms(a: np.ndarray) -> np.ndarray:
    a = a - a.mean()
    s = float(np.sqrt(np.mean(a * a)))
    return a / s if s > 0 else a


def fixed_pattern(shape: tuple[int, int], dev: Deviations, rng: np.random.Generator
                  ) -> tuple[np.ndarray, np.ndarray] | None:
    """``(static, drift)`` (H, W) DN: pixel and column offsets of rms ``fpn_dn``; a smooth pattern with row stripes of
    rms ``fpn_drift_dn`` (reached at the last frame). None without either."""
    if dev.fpn_dn <= 0 and dev.fpn_drift_dn <= 0:
        return None
    H, W = shape
    static = _unit_rms(0.8 * rng.standard_normal(shape) + 0.6 * rng.standard_normal(W)[None, :])
    y = (np.arange(H) + 0.5) / H - 0.5
    x = (np.arange(W) + 0.5) / W - 0.5
    c = rng.standard_normal(4)
    smooth = c[0] * y[:, None] + c[1] * x[None, :] + c[2] * (y[:, None] * x[None, :]) + c[3] * x[None, :] ** 2
    drift = _unit_rms(_unit_rms(smooth) + 0.5 * rng.standard_normal(H)[:, None])
    return dev.fpn_dn * static, dev.fpn_drift_dn * drift


def bad_pixel_sets(shape: tuple[int, int], fraction: float, camera: Camera, rng: np.random.Generator
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(dead flat indices, their stuck values, saturated flat indices)``: ``round(fraction H W)`` pixels, half dead
    (stuck within range, near the dark level), half saturated (stuck at full scale)."""
    n = int(round(fraction * shape[0] * shape[1]))
    idx = rng.choice(shape[0] * shape[1], size=n, replace=False)
    nd = (n + 1) // 2
    dead = np.sort(idx[:nd])
    values = np.round(camera.dark_dn * rng.uniform(0.95, 1.05, nd))
    return dead, values, np.sort(idx[nd:])


def _adc(v: np.ndarray, camera: Camera) -> np.ndarray:
    if camera.quantize:
        v = np.clip(np.round(v), 0.0, camera.full_scale_dn)
    return v.astype(np.float32)


# ---------------------------------------------------------------------------------------------------------------
# Recording and file
# ---------------------------------------------------------------------------------------------------------------
def jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(float(obj)) else None
    return obj


@dataclass
class Recording:
    """A recording's arrays and metadata, as the file will hold them."""

    arrays: dict[str, np.ndarray]
    meta: dict[str, Any]

    def write(self, path: str | Path) -> Path:
        """An uncompressed ``.npz`` with the metadata as JSON bytes under ``__meta__`` (the documented format)."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        text = json.dumps(jsonable(self.meta), indent=None, allow_nan=False)
        with open(p, "wb") as fh:
            np.savez(fh, **self.arrays, __meta__=np.frombuffer(text.encode(), dtype=np.uint8))
        return p

    @property
    def truth(self) -> dict[str, Any]:
        return self.meta["truth"]


def _scene_of(scene: str | Scene | np.ndarray, seed: int, camera: Camera) -> tuple[Scene, str]:
    if isinstance(scene, Scene):
        return scene, scene.token or "custom"
    if isinstance(scene, str):
        return make_scene(scene, seed, camera.shape, camera.scale), scene
    values = np.asarray(scene, dtype=np.float64)
    if values.ndim != 2:
        raise ValueError("a raster scene is one (h, w) kelvin image")
    token = "raster:" + hashlib.sha1(values.tobytes()).hexdigest()[:16]
    return Scene((Raster(values, tuple(camera.shape)),), 0.0, token), token


def record(scene: str | Scene | np.ndarray = "mixed", deviations: Deviations | None = None,
           camera: Camera | None = None, *, frames: int = 24, seed: int = 0, calibration_frames: int = 0,
           psf: bool = False, bad_pixel_map: bool = False, flat_field: bool = False, scene_truth: bool = False,
           legacy_polarizer_block: bool = False) -> Recording:
    """A recording of ``scene`` by ``camera`` doing ``deviations``.

    Parameters
    ----------
    scene : str, Scene or ndarray
        A name of :data:`SCENES`, a :class:`Scene`, or a kelvin raster spanning the perifoveal field.
    deviations : Deviations
        Default: none.
    camera : Camera
        Default: the paper's camera at 280 x 290 pixels.
    frames : int
        Number of frames, at ``camera.frame_rate_hz`` from t = 0.
    seed : int
        Every random draw (scene, phase, jitter, fixed pattern, bad pixels, noise) comes from its own stream of
        ``seed``: a deviation changes nothing else.
    calibration_frames : int
        Closed-shutter frames (at ``camera.shutter_k``, before the recording: the fixed pattern of frame 0).
    psf : bool
        Write the NOMINAL pixel PSFs ``psf_x1``/``psf_x2`` (the data use the defocused ones when
        ``defocus_waves`` > 0).
    bad_pixel_map, flat_field : bool
        Write the true ``bad_pixels`` map / the true vignetting as ``flat_field``.
    scene_truth : bool
        Write ``scene_x1``/``scene_x2``: the scene through perfect lenses (no PSF, no vignetting), DN, scoring only;
        the pixel box is then the supersampling's midpoint rule (approximate above ~1 cycle per pixel).
    legacy_polarizer_block : bool
        Add the simulator's private ``polarizer`` dict (``{mode: free, rate_hz, extinction: 0, tau_s: 0}``) that
        today's reconstruction reads (NOT documented: for comparison only).

    Returns
    -------
    Recording
    """
    dev = deviations or Deviations()
    cam = camera or Camera()
    if frames < 1:
        raise ValueError("frames >= 1")
    H, W = cam.shape
    scn, scene_name = _scene_of(scene, seed, cam)
    streams = {name: np.random.default_rng([seed, k]) for k, name in enumerate(
        ("scene", "phase", "fpn", "bad", "noise", "calibration"), start=1)}
    times = np.arange(frames) / cam.frame_rate_hz
    alpha, pol = polarizer_alpha(times, cam, dev, streams["phase"])
    geo = Geometry(cam.scale * (1 + dev.scale_error), dev.centre_px, dev.rotation_deg)
    r1, r2 = render_channels(scn, cam, geo, dev.defocus_waves)
    dldt = float(band_radiance_derivative(300.0, *cam.band))
    vig = vignetting_map(cam.shape, dev.vignetting)
    g1 = cam.foveal_gain * (1 + dev.gain_ratio_error)
    leak = 1.0 + dev.extinction
    x1 = cam.dark_dn + leak * cam.counts_per_k * g1 * vig * r1 / dldt
    x2 = cam.dark_dn + leak * cam.counts_per_k * vig * r2 / dldt
    data = alpha[:, None, None] * x1[None] + (1 - alpha)[:, None, None] * x2[None]
    pattern = fixed_pattern(cam.shape, dev, streams["fpn"])
    arrays: dict[str, np.ndarray] = {}
    if pattern is not None:
        static, drift = pattern
        ramp = (times - times[0]) / max(times[-1] - times[0], 1e-12)
        data += static[None] + ramp[:, None, None] * drift[None]
        arrays["fpn"] = static.astype(np.float32)
    data += cam.noise_dn * streams["noise"].standard_normal(data.shape)
    dead, dead_values, sat = bad_pixel_sets(cam.shape, dev.bad_pixels, cam, streams["bad"])
    flat = data.reshape(frames, -1)
    flat[:, dead] = dead_values
    flat[:, sat] = cam.full_scale_dn
    arrays = {"frames": _adc(data, cam), "times_s": times, "alpha": alpha,
              "truth_x1": x1.astype(np.float32), "truth_x2": x2.astype(np.float32), **arrays}
    if calibration_frames:
        level = cam.dark_dn + cam.counts_per_k * float(band_radiance(cam.shutter_k, *cam.band)) / dldt
        cal = np.full((calibration_frames, H, W), level)
        if pattern is not None:
            cal += pattern[0][None]
        cal += cam.noise_dn * streams["calibration"].standard_normal(cal.shape)
        cal.reshape(calibration_frames, -1)[:, dead] = dead_values
        cal.reshape(calibration_frames, -1)[:, sat] = cam.full_scale_dn
        arrays["calibration"] = _adc(cal, cam)
    if psf:
        for ch, ss in ((1, cam.supersample_x1), (2, cam.supersample_x2)):
            k = pixel_kernel(cam.na[ch - 1], cam.pixel_pitch_um, ss, cam.psf_radius_px[ch - 1], band=cam.band,
                             wavelengths=cam.psf_wavelengths)
            arrays[f"psf_x{ch}"] = file_psf(k, ss)
    if bad_pixel_map:
        bp = np.zeros(H * W, dtype=bool)
        bp[dead] = True
        bp[sat] = True
        arrays["bad_pixels"] = bp.reshape(H, W)
    if flat_field:
        arrays["flat_field"] = vig.astype(np.float32)
    if scene_truth:
        s1, s2 = render_channels(scn, cam, geo, perfect=True)  # no PSF, no vignetting
        arrays["scene_x1"] = (cam.dark_dn + leak * cam.counts_per_k * g1 * s1 / dldt).astype(np.float32)
        arrays["scene_x2"] = (cam.dark_dn + leak * cam.counts_per_k * s2 / dldt).astype(np.float32)
    meta = _meta(cam, dev, pol, geo, g1, dldt, scene_name, seed, frames, dead, sat, pattern, calibration_frames)
    if legacy_polarizer_block:
        meta["polarizer"] = {"mode": "free", "rate_hz": cam.polarizer_hz, "extinction": 0.0, "tau_s": 0.0}
    return Recording(arrays, meta)


def _meta(cam: Camera, dev: Deviations, pol: dict, geo: Geometry, g1: float, dldt: float, scene: str, seed: int,
          frames: int, dead: np.ndarray, sat: np.ndarray, pattern: tuple | None, calibration_frames: int
          ) -> dict[str, Any]:
    """The file's metadata: the camera's nominal constants, and the truth for scoring."""
    g = cam.foveal_gain
    W = cam.shape[1]
    meta: dict[str, Any] = {
        "kind": "measurement", "schema_version": 1, "units": "DN", "frame_rate_hz": cam.frame_rate_hz,
        "pixel_pitch_um": cam.pixel_pitch_um, "netd_k": cam.netd_k, "scale": cam.scale,
        "foveal_constraint": {"scale": cam.scale, "gain": g, "offset_dn": (1 - g) * cam.dark_dn},
        "polarizer_hz": cam.polarizer_hz, "polarizer_mode": cam.polarizer_mode, "dark_dn": cam.dark_dn,
        "saturation_dn": cam.full_scale_dn, "floor_dn": 0.0, "channel_gain": {"x1": g, "x2": 1.0},
        "dn_per_k_300K": {"x1": cam.counts_per_k * g, "x2": cam.counts_per_k},
        "radiometry": {"band_um": list(cam.band_um), "filter": None if cam.filter_um is None else list(cam.filter_um),
                       "dL_dT_300K": dldt},
    }
    if cam.polarizer_mode == "sync":
        meta["polarizer_phase_deg"] = cam.polarizer_phase_deg
    if cam.state_device:
        meta["polarizer_extinction"] = cam.extinction
        meta["bolometer_tau_s"] = cam.tau_s
    meta["truth"] = {
        "model": "tests/independent/forward.py", "scene": scene, "seed": seed, "frames": frames,
        "deviations": {k: v for k, v in asdict(dev).items()}, "changed": dev.changed,
        "polarizer": pol,
        "foveal": {"scale": geo.scale, "centre_px": list(geo.centre_px), "rotation_deg": geo.rotation_deg,
                   "convention": "scene point q lands on the sensor at p = scale R(rotation) (q - centre); (x, y), "
                                 "y down, perifoveal px from the optical axis; centre is (dy, dx) "
                                 "(docs/measurement_format.md, 'The foveal geometry')",
                   "gain": g1, "gain_nominal": g, "offset_dn": (1 - g1) * cam.dark_dn},
        "vignetting_corner": dev.vignetting, "defocus_waves": dev.defocus_waves,
        "bad_pixels": {"dead": [[int(i) // W, int(i) % W] for i in dead],
                       "saturated": [[int(i) // W, int(i) % W] for i in sat]},
        "fpn": None if pattern is None else {"static_rms_dn": dev.fpn_dn, "drift_rms_dn_at_end": dev.fpn_drift_dn,
                                             "calibration_frames": calibration_frames},
        "noise_dn": cam.noise_dn, "leak_gain": 1.0 + dev.extinction,
    }
    return meta


def write(path: str | Path, scene: str | Scene | np.ndarray = "mixed", deviations: Deviations | None = None,
          camera: Camera | None = None, **kw: Any) -> Path:
    """:func:`record` and :meth:`Recording.write` in one call."""
    return record(scene, deviations, camera, **kw).write(path)

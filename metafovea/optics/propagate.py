"""Propagation engines: sampled-field angular spectrum, windowed direction-sine transform, 1-D Hankel.

Conventions: um, ``exp(-i omega t)`` (a plane wave towards +z is ``exp(+i k z)``), arrays ``(H, W)`` with
row = y and column = x, x and y increasing with the index.

Engines
-------
``asm``      band-limited angular spectrum of a *sampled* field with the exact kernel
             ``exp(i z sqrt(k^2 - kx^2 - ky^2))``, zero padding and the evanescent cut-off; the
             transfer function is limited to the band the padded window can represent without
             wrap-around aliasing (Matsushima & Shimobaba 2009). Reference engine for small apertures.
``mft``      the field on an arbitrary output window from a pupil given in direction-sine space
             (:class:`metafovea.optics.pupil.Pupil`): ``U(x) = int P(s) exp(i[Phi(s) + k s.x]) d^2s``
             evaluated as a matrix Fourier transform on Gauss-Legendre nodes of the pupil disk (the disk is
             mapped to a rectangle by ``v = R sin t, u = R cos t tau`` so the hard edge costs nothing and the
             quadrature converges spectrally). The ideal spherical term is removed analytically (it is not
             in Phi), so the number of nodes is set by the aberration and the window, not by the lens.
``hankel``   the same integral for a rotationally symmetric pupil on axis, ``2 pi int P J0(k s r) s ds``:
             1-D, milliseconds.

Node counts come from the phase the integrand accumulates across the pupil, which is bounded by
``k * R_s * max |x_ray - x_window|`` (ray landing points from the analytic ray map of the pupil).
"""

from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy import special

from metafovea.errors import InputError, check_positive, check_range
from metafovea.parallel import blas_threads

from .pupil import Pupil, design_na

log = logging.getLogger(__name__)


class AliasingWarning(UserWarning):
    """The sampling of a field or a window cannot represent the result to the requested error."""


class SamplingError(InputError):
    """The requested accuracy cannot be met with the sampling or window given."""


# ----------------------------------------------------------------------------------------------
# quadrature
# ----------------------------------------------------------------------------------------------
@lru_cache(maxsize=256)
def _gl(n: int) -> tuple[np.ndarray, np.ndarray]:
    # scipy's roots_legendre is O(n^2) (banded eigenvalues + Newton polish); numpy's leggauss is a dense
    # O(n^3) eigenproblem (1-10 s at the 1000-2000 nodes of wide defocused windows)
    x, w = special.roots_legendre(n)
    x.setflags(write=False)
    w.setflags(write=False)
    return x, w


def nodes_for_phase(beta: float, error: float, extra: int = 0) -> int:
    """Gauss-Legendre nodes on [-1, 1] for ``exp(i beta x)`` times a smooth amplitude to ``error``.

    Calibrated on exp(i beta x): 1e-6 needs n = 0.8 beta at beta = 30, 0.56 beta at 300, 0.526 beta at 1000;
    ``beta / 2 + 3 beta^(1/3) + 2 log10(1/error) + 6`` is above these with a margin (tests check the
    result against 1.6 times as many nodes). ``beta`` is an upper bound on the phase slope times the
    half-length, so the estimate is conservative for phases whose slope varies.
    """
    beta = abs(beta)
    n = int(math.ceil(0.5 * beta + 3.0 * beta ** (1.0 / 3.0) + 2.0 * math.log10(1.0 / error) + 6)) + extra
    # round up to a multiple of 8 (>= 64: of 32) so that the node sets repeat and hit the cache
    q = 8 if n < 64 else 32
    return -(-n // q) * q


def disk_nodes(center: np.ndarray, radius: float, n_t: int, n_r: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss nodes over the disk |s - center| <= radius: (u (n_t, n_r), v (n_t,), weights (n_t, n_r)).

    ``v = c_v + R sin t`` (t Gauss-Legendre on [-pi/2, pi/2]), ``u = c_u + R cos t * tau`` (tau GL on [-1, 1]);
    the Jacobian ``R^2 cos^2 t`` is smooth, so the hard pupil edge does not slow convergence.
    """
    xt, wt = _gl(n_t)
    xr, wr = _gl(n_r)
    t = 0.5 * np.pi * xt
    ct = np.cos(t)
    v = center[1] + radius * np.sin(t)
    u = center[0] + radius * ct[:, None] * xr[None, :]
    w = (0.5 * np.pi) * (radius * ct) ** 2
    weights = w[:, None] * wt[:, None] * wr[None, :]
    return u, v, weights


# ----------------------------------------------------------------------------------------------
# ray extents -> node counts
# ----------------------------------------------------------------------------------------------
def ray_extent(pupil: Pupil, n: int = 24) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax) of the geometric ray landing points over the pupil disk (um).

    For a lens with ``phase_poly_rad`` the rays are traced forwards from lens points (Gauss nodes of the aperture
    and its rim: :meth:`Pupil.lens_ray_landing`), which needs no inverse ray map.
    """
    if pupil.lens.phase_poly_rad:
        R = pupil.lens.radius_um
        u, v, _ = disk_nodes(np.zeros(2), R, 2 * n, 2 * n)
        th = np.linspace(0, 2 * np.pi, 8 * n, endpoint=False)
        rx = np.concatenate([u.ravel(), R * np.cos(th), [0.0]])
        ry = np.concatenate([np.broadcast_to(v[:, None], u.shape).ravel(), R * np.sin(th), [0.0]])
        x, y = pupil.lens_ray_landing(rx, ry)
        return float(x.min()), float(x.max()), float(y.min()), float(y.max())
    u, v, _ = disk_nodes(pupil.center, pupil.radius, n, n)
    vv = np.broadcast_to(v[:, None], u.shape)
    th = np.linspace(0, 2 * np.pi, 4 * n, endpoint=False)
    ur = pupil.center[0] + pupil.radius * np.cos(th)
    vr = pupil.center[1] + pupil.radius * np.sin(th)
    sx = np.concatenate([u.ravel(), ur])
    sy = np.concatenate([vv.ravel(), vr])
    x, y = pupil.ray_landing(sx, sy)
    return float(x.min()), float(x.max()), float(y.min()), float(y.max())


def _reach(ext_lo: float, ext_hi: float, win_lo: float, win_hi: float) -> float:
    return max(abs(ext_hi - win_lo), abs(win_hi - ext_lo))


def mft_nodes(pupil: Pupil, xs: np.ndarray, ys: np.ndarray, error: float,
              extent: tuple[float, float, float, float] | None = None) -> tuple[int, int]:
    """(n_t, n_r) Gauss nodes the MFT needs for output coordinates xs, ys at ``error``."""
    e = ray_extent(pupil) if extent is None else extent
    k, R = pupil.k, pupil.radius
    bx = k * R * _reach(e[0], e[1], float(xs.min()), float(xs.max()))
    by = k * R * _reach(e[2], e[3], float(ys.min()), float(ys.max())) * (0.5 * np.pi)
    # amplitude smoothness (1/c_w^2 near NA) needs a few extra nodes
    return nodes_for_phase(by, error, 4), nodes_for_phase(bx, error, 4)


# ----------------------------------------------------------------------------------------------
# MFT engine (2-D, any window, any field)
# ----------------------------------------------------------------------------------------------
def mft_field(pupil: Pupil, xs: ArrayLike, ys: ArrayLike, *, error: float = 1e-6, nodes: tuple[int, int] | None = None,
              max_bytes: float = 64e6) -> np.ndarray:
    """Complex field (len(ys), len(xs)) on the plane z at coordinates xs (columns), ys (rows), um.

    ``|U|^2`` is the intensity for a unit-intensity incident plane wave (power per um^2).
    """
    xs = np.asarray(xs, dtype=float).reshape(-1)
    ys = np.asarray(ys, dtype=float).reshape(-1)
    n_t, n_r = mft_nodes(pupil, xs, ys, error) if nodes is None else nodes
    u, v, wts = disk_nodes(pupil.center, pupil.radius, n_t, n_r)
    vv = np.broadcast_to(v[:, None], u.shape)
    k = pupil.k
    xc = 0.5 * (xs.min() + xs.max())
    yc = 0.5 * (ys.min() + ys.max())
    q = wts * pupil.amplitude(u, vv) * np.exp(1j * (pupil.phase(u, vv) + k * (u * xc + vv * yc)))
    dx = xs - xc
    ey = np.exp(1j * k * np.outer(ys - yc, v))  # (My, n_t)
    g = np.empty((n_t, xs.size), dtype=complex)
    step = max(1, int(max_bytes // (16 * n_r * xs.size)))
    h = np.diff(dx)
    uniform = dx.size > 2 and np.allclose(h, h[0], rtol=0, atol=1e-9 * max(1.0, abs(h[0])))
    for j0 in range(0, n_t, step):
        j1 = min(n_t, j0 + step)
        if uniform:
            # exp(i k u x_m) = exp(i k u x_0) exp(i k u h)^m by a running product (no exp per element)
            e = np.empty((j1 - j0, n_r, dx.size), dtype=complex)
            e[..., 0] = np.exp(1j * k * u[j0:j1] * dx[0])
            e[..., 1:] = np.exp(1j * k * u[j0:j1] * h[0])[..., None]
            np.cumprod(e, axis=-1, out=e)
        else:
            e = np.exp(1j * (u[j0:j1, :, None] * (k * dx)[None, None, :]))
        g[j0:j1] = np.einsum("ji,jim->jm", q[j0:j1], e, optimize=False)
    return ey @ g


def mft_intensity_multi(pupils: list[Pupil], weights: ArrayLike, xs: ArrayLike, ys: ArrayLike, *, error: float = 1e-6,
                        max_bytes: float = 64e6) -> np.ndarray:
    """``sum_k weights[k] |U_k|^2`` on the grid (len(ys), len(xs)) for pupils of one lens and field.

    In the design direction sines ``w = alpha (s - s0)`` every wavelength's pupil is the same disk
    ``|w| <= NA`` and the kernel ``exp(i k s.x)`` is ``exp(i k s0.x) exp(i (2 pi / lambda0) w.x)``: the
    first factor is a phase per output point (no effect on the intensity), the second is shared, so the
    exponentials are built once and each wavelength costs two matrix products. Nodes: the most any pupil
    needs on this window.
    """
    xs = np.asarray(xs, dtype=float).reshape(-1)
    ys = np.asarray(ys, dtype=float).reshape(-1)
    pupils = list(pupils)
    wts_in = np.asarray(weights, dtype=float).reshape(-1)
    out = np.zeros((ys.size, xs.size))
    if not pupils:
        return out
    lens, order = pupils[0].lens, pupils[0].order
    s0 = np.asarray(pupils[0].s0, float)
    for pu in pupils:
        if pu.lens is not lens and pu.lens != lens or pu.order != order or not np.array_equal(pu.s0, s0):
            raise InputError("pupils", "mixed", "pupils of one lens, order and field")
    nt = nr = 0
    for pu in pupils:
        a, b = mft_nodes(pu, xs, ys, error)
        nt, nr = max(nt, a), max(nr, b)
    uw, vw, wq = disk_nodes(np.zeros(2), design_na(lens) / order, nt, nr)
    vvw = np.broadcast_to(vw[:, None], uw.shape)
    kap = 2 * np.pi * order / lens.wavelength_um
    xc = 0.5 * (xs.min() + xs.max())
    yc = 0.5 * (ys.min() + ys.max())
    Q = np.empty((nt, len(pupils), nr), dtype=complex)
    for i, pu in enumerate(pupils):
        a = pu.alpha
        sx = s0[0] + uw / a
        sy = s0[1] + vvw / a
        Q[:, i, :] = ((wq / (a * a)) * pu.amplitude(sx, sy)
                      * np.exp(1j * (pu.phase(sx, sy) + pu.k * (sx * xc + sy * yc))))
    ey = np.exp(1j * kap * np.outer(ys - yc, vw))  # (My, nt)
    dx = xs - xc
    h = np.diff(dx)
    uniform = dx.size > 2 and np.allclose(h, h[0], rtol=0, atol=1e-9 * max(1.0, abs(h[0])))
    bx = max(1, min(xs.size, int(max_bytes // (16 * nt * max(len(pupils), 4)))))
    with blas_threads(1):  # many small products: threaded OpenBLAS is ~10x slower on a loaded 2-core machine
        _mft_multi_blocks(Q, ey, uw, kap, dx, h, uniform, bx, nt, nr, wts_in, out, max_bytes)
    return out


def _mft_multi_blocks(Q: np.ndarray, ey: np.ndarray, uw: np.ndarray, kap: float, dx: np.ndarray, h: np.ndarray,
                      uniform: bool, bx: int, nt: int, nr: int, wts_in: np.ndarray, out: np.ndarray,
                      max_bytes: float) -> None:
    P = Q.shape[1]
    for x0 in range(0, dx.size, bx):
        x1 = min(dx.size, x0 + bx)
        G = np.empty((P, nt, x1 - x0), dtype=complex)
        step = max(1, int(max_bytes // (16 * nr * (x1 - x0))))
        for j0 in range(0, nt, step):
            j1 = min(nt, j0 + step)
            if uniform:
                e = np.empty((j1 - j0, nr, x1 - x0), dtype=complex)
                e[..., 0] = np.exp(1j * kap * uw[j0:j1] * dx[x0])
                if x1 - x0 > 1:
                    e[..., 1:] = np.exp(1j * kap * uw[j0:j1] * h[0])[..., None]
                np.cumprod(e, axis=-1, out=e)
            else:
                e = np.exp(1j * kap * uw[j0:j1, :, None] * dx[None, None, x0:x1])
            G[:, j0:j1, :] = np.matmul(Q[j0:j1], e).transpose(1, 0, 2)
        for i in range(P):
            U = ey @ G[i]
            out[:, x0:x1] += wts_in[i] * (U.real ** 2 + U.imag ** 2)


# ----------------------------------------------------------------------------------------------
# Hankel engine (1-D, on axis, rotationally symmetric)
# ----------------------------------------------------------------------------------------------
def hankel_nodes(pupil: Pupil, r_max: float, error: float) -> int:
    e = ray_extent(pupil)
    reach = max(abs(e[0]), abs(e[1]), abs(e[2]), abs(e[3])) + r_max
    return nodes_for_phase(pupil.k * pupil.radius * reach * 0.5, error, 8)


def hankel_field(pupil: Pupil, r: ArrayLike, *, error: float = 1e-6, n: int | None = None) -> np.ndarray:
    """Complex field at radii ``r`` (um) for an on-axis pupil (s0 = 0), azimuthally averaged amplitude."""
    if float(np.hypot(*pupil.s0)) > 0:
        raise InputError("field_deg", pupil.s0.tolist(), "0 for the Hankel engine (on axis only)")
    r = np.asarray(r, dtype=float)
    n = hankel_nodes(pupil, float(np.max(r)) if r.size else 0.0, error) if n is None else n
    x, w = _gl(n)
    S = pupil.radius
    s = 0.5 * S * (x + 1.0)
    ws = 0.5 * S * w
    zero = np.zeros_like(s)
    if pupil.lattice:
        # azimuthal average of the lattice factor (the 4-fold part is accounted in the error estimate)
        th = (np.arange(16) + 0.5) * (np.pi / 32)  # one octant is enough by symmetry
        amp = np.mean([pupil.amplitude(s * np.cos(a), s * np.sin(a)) for a in th], axis=0)
    else:
        amp = pupil.amplitude(s, zero)
    q = ws * 2 * np.pi * s * amp * np.exp(1j * pupil.phase(s, zero))
    flat = r.reshape(-1)
    out = np.empty(flat.size, dtype=complex)
    step = max(1, int(8e6 // (8 * n)))
    for i0 in range(0, flat.size, step):
        rr = flat[i0:i0 + step]
        out[i0:i0 + step] = special.j0(pupil.k * np.outer(rr, s)) @ q
    return out.reshape(r.shape)


def _hankel_weights(pupil: Pupil, t: np.ndarray, wt: np.ndarray) -> np.ndarray:
    """Quadrature weights q(t) of ``U(r) = sum q J0(k S t r)`` (t in [0, 1], S = pupil radius)."""
    S = pupil.radius
    s = S * t
    zero = np.zeros_like(s)
    if pupil.lattice:
        th = (np.arange(16) + 0.5) * (np.pi / 32)
        amp = np.mean([pupil.amplitude(s * np.cos(a), s * np.sin(a)) for a in th], axis=0)
    else:
        amp = pupil.amplitude(s, zero)
    return (S * S) * wt * 2 * np.pi * t * amp * np.exp(1j * pupil.phase(s, zero))


def hankel_profiles(pupils: list[Pupil], r: ArrayLike, *, error: float = 1e-6, n: int | None = None,
                    max_bytes: float = 48e6) -> np.ndarray:
    """Complex fields (len(pupils), len(r)) of several on-axis pupils at radii ``r`` in one pass.

    For the focusing order of one lens ``k S`` (wavenumber times the pupil radius in direction sines) is
    ``2 pi NA / lambda0`` at every wavelength, so the Bessel matrix ``J0(k S t r)`` on Gauss nodes ``t`` of
    [0, 1] is shared: the fields of all wavelengths are one matrix product (``n`` nodes: the most any of
    the pupils needs). Pupils of different ``k S`` fall back to one evaluation each.
    """
    r = np.asarray(r, dtype=float).reshape(-1)
    if not pupils:
        return np.zeros((0, r.size), dtype=complex)
    for p in pupils:
        if float(np.hypot(*p.s0)) > 0:
            raise InputError("field_deg", p.s0.tolist(), "0 for the Hankel engine (on axis only)")
    ks = np.array([p.k * p.radius for p in pupils])
    if np.ptp(ks) > 1e-12 * ks.max():
        return np.array([hankel_field(p, r, error=error, n=n) for p in pupils])
    r_max = float(r.max()) if r.size else 0.0
    if n is None:
        n = max(hankel_nodes(p, r_max, error) for p in pupils)
    x, w = _gl(n)
    t = 0.5 * (x + 1.0)
    wt = 0.5 * w
    Q = np.array([_hankel_weights(p, t, wt) for p in pupils])  # (P, n)
    out = np.empty((len(pupils), r.size), dtype=complex)
    step = max(1, int(max_bytes // (8 * n)))
    kS = float(ks[0])
    with blas_threads(1):
        for i0 in range(0, r.size, step):
            J = special.j0(kS * np.outer(r[i0:i0 + step], t))  # (m, n) real
            out[:, i0:i0 + step] = (Q @ J.T)
    return out


def hankel_grid(pupil: Pupil, xs: np.ndarray, ys: np.ndarray, *, error: float = 1e-6) -> np.ndarray:
    """Hankel engine on a Cartesian grid: evaluated once per distinct radius (grid symmetry)."""
    r2 = (xs[None, :] ** 2 + ys[:, None] ** 2)
    key = np.round(r2, 9)
    uniq, inv = np.unique(key, return_inverse=True)
    vals = hankel_field(pupil, np.sqrt(uniq), error=error)
    return vals[inv].reshape(r2.shape)


# ----------------------------------------------------------------------------------------------
# Angular spectrum engine (sampled fields)
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ASMResult:
    field: np.ndarray
    pitch_um: float
    band_limit_cyc_per_um: float
    info: dict[str, Any] = field(default_factory=dict)


def asm_propagate(u0: np.ndarray, pitch_um: float, wavelength_um: float, z_um: float, *, pad: float = 2.0,
                  band_limit: bool = True, required_band: float | None = None) -> ASMResult:
    """Band-limited angular spectrum propagation of a sampled field by ``z_um`` (exact kernel).

    ``u0``: (H, W) complex field, sample pitch ``pitch_um``; the result has the same grid (the padding is
    cropped). ``pad``: the computational window is ``pad`` times the field (>= 1). Directions beyond
    ``k`` are evanescent and dropped (their decay over z >> lambda is complete). With ``band_limit`` the
    transfer function is cut where its phase can no longer be sampled by the padded window (|fx| >
    1 / (lambda sqrt((2 df z)^2 + 1))); ``required_band`` (cycles/um) is the band the field must keep:
    if the cut removes part of it, :class:`AliasingWarning` is raised as a warning (pad more).
    A phase step of more than pi between neighbouring samples anywhere the field is non-negligible is
    reported as aliasing too.
    """
    u0 = np.asarray(u0)
    if u0.ndim != 2:
        raise InputError("u0", u0.shape, "a 2-D (H, W) array")
    dx = check_positive("pitch_um", pitch_um, "um")
    wl = check_positive("wavelength_um", wavelength_um, "um", hi=1e4)
    z = check_range("z_um", z_um, 0.0, None, lo_inclusive=True, unit="um")
    pad = check_range("pad", pad, 1.0, 16.0, lo_inclusive=True)
    H, W = u0.shape
    NH, NW = int(math.ceil(H * pad)), int(math.ceil(W * pad))
    NH, NW = _fft_size(NH), _fft_size(NW)
    # aliasing check of the input: phase steps between neighbours
    mag = np.abs(u0)
    thr = 1e-3 * float(mag.max()) if mag.size else 0.0
    with np.errstate(invalid="ignore"):
        dpx = np.abs(np.angle(u0[:, 1:] * np.conj(u0[:, :-1])))[(mag[:, 1:] > thr) & (mag[:, :-1] > thr)]
        dpy = np.abs(np.angle(u0[1:, :] * np.conj(u0[:-1, :])))[(mag[1:, :] > thr) & (mag[:-1, :] > thr)]
    worst = max(float(dpx.max()) if dpx.size else 0.0, float(dpy.max()) if dpy.size else 0.0)
    if worst > 0.9 * np.pi:
        warnings.warn(f"input field phase changes by {worst:.2f} rad between samples (> 0.9 pi): the field is "
                      f"undersampled at pitch {dx:g} um; the result is aliased", AliasingWarning, stacklevel=2)
    buf = np.zeros((NH, NW), dtype=complex)
    buf[:H, :W] = u0
    fx = np.fft.fftfreq(NW, dx)
    fy = np.fft.fftfreq(NH, dx)
    kz2 = (1.0 / wl) ** 2 - fx[None, :] ** 2 - fy[:, None] ** 2
    prop = kz2 > 0
    kz = 2 * np.pi * np.sqrt(np.where(prop, kz2, 0.0))
    h = np.where(prop, np.exp(1j * kz * z), 0.0)
    lim = 1.0 / wl
    if band_limit and z > 0:
        limx = 1.0 / (wl * math.sqrt((2.0 * z / (NW * dx)) ** 2 + 1.0))
        limy = 1.0 / (wl * math.sqrt((2.0 * z / (NH * dx)) ** 2 + 1.0))
        h = h * ((np.abs(fx)[None, :] < limx) & (np.abs(fy)[:, None] < limy))
        lim = min(limx, limy)
        if required_band is not None and required_band > lim:
            warnings.warn(f"band limit {lim:.4g} cycles/um of the padded window (pad = {pad:g}) is below the "
                          f"field's band {required_band:.4g}: increase pad or the result misses light",
                          AliasingWarning, stacklevel=2)
    out = np.fft.ifft2(np.fft.fft2(buf) * h)[:H, :W]
    return ASMResult(out, dx, lim, {"pad": pad, "fft_shape": (NH, NW), "max_phase_step": worst})


def _fft_size(n: int) -> int:
    """Smallest 2^a 3^b 5^c >= n."""
    best = 1 << (int(n - 1).bit_length())
    a = 1
    while a < best:
        b = a
        while b < best:
            c = b
            while c < best:
                if c >= n:
                    best = c
                c *= 5
            b *= 3
        a *= 2
    return best


def sampled_lens_field(pupil: Pupil, pitch_um: float, *, quantize_levels: int | None = None,
                       lattice_sites: bool = False, extent_um: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The lens-plane field (H, W) of the pupil's lens on a square grid centred on the axis, and its axis.

    Continuous phase by default; ``quantize_levels`` rounds the wrapped phase to N levels point by point;
    ``lattice_sites`` holds each sample at the value of its lattice site (needs pitch = period / integer).
    The field is the order-1 lens under the pupil's wavelength and field angle (incident tilt included).
    """
    from metafovea.lens import (  # lens stage (rank 3): allowed
        design_phase,
        level_phase,
        quantize_phase,
    )

    lens = pupil.lens
    R = lens.radius_um
    L = 2 * R if extent_um is None else extent_um
    n = int(math.ceil(L / pitch_um))
    n += n % 2 == 0
    ax = (np.arange(n) - n // 2) * pitch_um
    x, y = ax[None, :], ax[:, None]
    if lattice_sites:
        p = lens.period_um
        m = p / pitch_um
        if abs(m - round(m)) > 1e-9:
            raise InputError("pitch_um", pitch_um, f"period_um / integer (period {p:g} um)")
        o = 0.0 if lens.lattice == "integer" else 0.5
        xs = (np.floor(x / p - o + 0.5) + o) * p
        ys = (np.floor(y / p - o + 0.5) + o) * p
    else:
        xs, ys = x, y
    phi = design_phase(lens, xs, ys)
    if quantize_levels:
        phi = level_phase(quantize_phase(phi, quantize_levels), quantize_levels)
    alpha = lens.wavelength_um / pupil.wavelength_um
    inside = (xs ** 2 + ys ** 2) <= R * R
    k = pupil.k
    u0 = np.where(inside, np.exp(1j * (phi * alpha + k * (pupil.s0[0] * x + pupil.s0[1] * y))), 0)
    return u0, ax

"""The joint separation-deconvolution problem of both channels on a padded periodic grid, and its linear solves.

Per pixel and frame the frames are (DN, after the fixed pattern)::

    y_t = a_t u_1 + (1 - a_t) u_2 + n_t,    u_i = offset + r_i (K_i * s_i + p_i mean(s_i))            (1)

with ``K_i`` channel ``i``'s PSF on the pixel grid, ``p_i`` its pedestal, ``r_i`` its relative illumination
(:class:`ChannelPSFs`) and ``s_i`` the scene in DN above the dark level. The per-pixel normal equations
(:func:`normal_equations`) are a sufficient statistic: with ``A = [a, 1 - a]`` (``T x 2``) and ``N = A^T A``,

    u_hat = N^-1 A^T y,    cov(u_hat) = sigma^2 N^-1                                                  (2)

so the problem is ``z = M D s + e`` on the grid (:class:`Grid`: the crop padded by the kernels' radius, FFT size),
``z_i = (u_hat_i - offset) / r_i``, ``D = diag(D_1, D_2)`` the OTFs, ``M`` the data region and ``e`` of per-pixel
covariance ``C = (sigma^2 N^-1 + e_fpn^2 [[1, 1], [1, 1]]) o (rho rho^T)`` (``e_fpn``: the rms error of the
subtracted fixed pattern, the same in every frame; ``rho_i = rms(1 / r_i)`` over the crop; :func:`prepare_problem`).
With a prior ``P`` (per FFT bin) the Wiener estimate solves

    (D^H M^T C^-1 M D + P^-1) s = D^H M^T C^-1 z                                                        (3)

by preconditioned conjugate gradients (:func:`linear_solve`); with ``boundary='padded'`` the data are extended over
the whole grid (``M = I``) and (3) is one 2 x 2 system per frequency, with ``'unknown'`` only the crop is data.
Total variation replaces ``P^-1`` by ``sum_i lambda_i TV(s_i)``, solved by ADMM (:func:`tv_admm`).

Measured figures: BENCHMARKS.md, section "PSF-aware reconstruction against the scene".
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.errors import InputError, check_choice
from metafovea.measurement import check_illumination, check_kernel, check_patches
from metafovea.reconstruct.spectra import common_excess, noise_floor, rfft_frequencies, rfft_weights

if TYPE_CHECKING:
    from collections.abc import Callable

    from metafovea.measurement import Measurement

#: how the data are extended beyond the crop (:func:`prepare_problem` ``boundary``): ``'padded'`` pads each channel
#: with its edge values (or ``pad_mode``'s) and solves a periodic problem; ``'solved'`` does too, once the
#: perifoveal channel's padding is replaced by its data extended through the scene beyond the crop solved for in a
#: ring (:func:`solved_exterior`, in :func:`metafovea.reconstruct.deconvolve.separate_deconvolve`); ``'unknown'``
#: solves for the scene beyond the crop over the whole padding (seen only through the PSFs' tails: far less
#: determined, and slow)
BOUNDARIES = ("solved", "padded", "unknown")
#: ``numpy.pad`` modes the padding of a periodic problem takes (:func:`prepare_problem` ``pad_mode``; ``'reflect'``
#: becomes ``'symmetric'`` where the padding is wider than the crop): the crop's own values continued; numpy's
#: ``'constant'`` and ``'linear_ramp'`` pad towards 0 DN, a scene the data do not show (errors of hundreds of DN)
PAD_MODES = ("edge", "reflect", "symmetric", "wrap", "mean", "median")
#: the default: the perifoveal scene beyond the crop solved for in a ring (:func:`solved_exterior`)
DEFAULT_BOUNDARY = "solved"
#: old spellings of :data:`BOUNDARIES` still accepted: ``'mirror'`` padded with edge values, not a mirror image
DEPRECATED_BOUNDARIES = {"mirror": "padded"}
#: ``alpha`` whose 2 x 2 normal matrix is worse conditioned than this cannot separate the channels
MAX_CONDITION = 1e8
#: :func:`solved_exterior`'s ring beyond the crop, px (``exterior_px``): the PSF's core, which carries the ring's
#: scene into the crop's edge pixels (the PSF's wider part gathers from beyond any ring: from the edge-padded solve)
EXTERIOR_PX = 16
#: :func:`solved_exterior`'s iterations at most (``exterior_iterations``): its speed against error in BENCHMARKS.md
EXTERIOR_ITERATIONS = 100
#: :func:`solved_exterior` stops early only once its preconditioned residual has fallen by this factor (numerical
#: convergence in single precision): the objective's decrease per iteration is no guide, CG's steps stall and resume
EXTERIOR_RESIDUAL_REDUCTION = 1e-5


def check_boundary(boundary: str) -> str:
    """``boundary`` as one of :data:`BOUNDARIES` (a deprecated spelling mapped, with a DeprecationWarning).

    Parameters
    ----------
    boundary : {'padded', 'unknown'}
        ``'mirror'`` is accepted for ``'padded'``.

    Returns
    -------
    str
    """
    if boundary in DEPRECATED_BOUNDARIES:
        new = DEPRECATED_BOUNDARIES[boundary]
        warnings.warn(f"boundary={boundary!r} is deprecated (it pads with the crop's edge values): use "
                      f"boundary={new!r}", DeprecationWarning, stacklevel=3)
        return new
    if boundary not in BOUNDARIES:
        raise InputError("boundary", boundary, "one of " + ", ".join(BOUNDARIES))
    return boundary


@dataclass(frozen=True)
class ChannelPSFs:
    """Both channels' PSFs on the pixel grid, the ``K_i``, ``p_i`` and ``r_i`` of eq. (1).

    Attributes
    ----------
    kernels : tuple of 2 ndarray, shape (n_i, n_i)
        Odd size, centred, values >= 0 with a positive sum.
    pedestals : tuple of 2 float
        Power beyond the kernels (disks wider than the crop), spread uniformly; in [0, 1).
    illumination : tuple of 2 (ndarray, shape (H, W), or None)
        Relative illumination per channel (None: 1).
    source : str
        Where they came from.
    patches : tuple of 2 (ndarray, shape (p, p, n, n), or None)
        A field-dependent PSF per channel (the Measurement format's ``psf_patches_x*``): the kernels at the centres
        of ``p x p`` equal patches of the crop, interpolated bilinearly between them
        (:func:`metafovea.measurement.patch_weights`); None: shift-invariant (``kernels``). Both channels' ``p``
        agree when both are given.
    """

    kernels: tuple[np.ndarray, np.ndarray]
    pedestals: tuple[float, float] = (0.0, 0.0)
    illumination: tuple[np.ndarray | None, np.ndarray | None] = (None, None)
    source: str = "given"
    patches: tuple[np.ndarray | None, np.ndarray | None] = (None, None)

    def __post_init__(self) -> None:
        ks = [check_kernel(f"psf_x{i}", k) for i, k in enumerate(self.kernels, start=1)]
        object.__setattr__(self, "kernels", tuple(ks))
        object.__setattr__(self, "illumination", tuple(
            None if v is None else check_illumination(f"illumination_x{i}", v, None)
            for i, v in enumerate(self.illumination, start=1)))
        peds = []
        for i, p in enumerate(self.pedestals, start=1):
            if not (math.isfinite(p) and -1e-9 <= p < 1):
                raise InputError(f"pedestal_x{i}", p, "a power fraction in [0, 1)")
            peds.append(max(0.0, float(p)))  # a rounding residue below 0 is 0
        object.__setattr__(self, "pedestals", tuple(peds))
        pts = []
        for i, k in enumerate(self.patches, start=1):
            if k is None:
                pts.append(None)
                continue
            pts.append(check_patches(f"psf_patches_x{i}", k))
        if pts[0] is not None and pts[1] is not None and pts[0].shape[0] != pts[1].shape[0]:
            raise InputError("psf_patches_x2", f"{pts[1].shape[0]} x {pts[1].shape[0]} patches",
                             f"the same grid as psf_patches_x1 ({pts[0].shape[0]} x {pts[0].shape[0]})")
        object.__setattr__(self, "patches", tuple(pts))

    @property
    def n_patches(self) -> int:
        """Patches a side of the field-dependent PSF (1: shift-invariant)."""
        return max([1] + [int(p.shape[0]) for p in self.patches if p is not None])

    def _common(self, c: int, k: np.ndarray) -> np.ndarray:
        """``k`` zero-padded to channel ``c``'s largest kernel (on axis or any patch): every patch's solve and the
        on-axis one then share one padded grid."""
        p = self.patches[c]
        n = max(self.kernels[c].shape[0], 0 if p is None else p.shape[2])
        o = (n - k.shape[0]) // 2
        return np.pad(k, o) if o else k

    def patch(self, i: int, j: int) -> ChannelPSFs:
        """The shift-invariant PSFs of patch ``(i, j)`` (a channel without patches keeps its kernel)."""
        ks = tuple(self._common(c, self.kernels[c] if p is None else p[i, j]) for c, p in enumerate(self.patches))
        return ChannelPSFs(ks, self.pedestals, self.illumination,  # type: ignore[arg-type]
                           source=f"{self.source}, patch ({i}, {j})")

    def on_axis(self) -> ChannelPSFs:
        """The same without the field dependence (``kernels``: the kernel nearest the axis, on the patches' grid)."""
        ks = tuple(self._common(c, k) for c, k in enumerate(self.kernels))
        return ChannelPSFs(ks, self.pedestals, self.illumination, source=self.source)  # type: ignore[arg-type]

    @classmethod
    def from_measurement(cls, m: Measurement) -> ChannelPSFs:
        """The PSFs a Measurement carries, as :func:`metafovea.imaging.simulate.simulate` writes them.

        Parameters
        ----------
        m : Measurement
            With the arrays ``psf_x1``, ``psf_x2`` (and optionally ``illumination_x1``, ``illumination_x2``);
            the pedestals are :attr:`Measurement.psf_pedestals`.

        Returns
        -------
        ChannelPSFs
        """
        ex = m.extras
        if "psf_x1" not in ex or "psf_x2" not in ex:
            raise InputError("measurement", m.source or "in memory", "a file with the channel PSFs 'psf_x1' and "
                             "'psf_x2' (metafovea simulate writes them), or a PSF file (psf=PATH)", source=m.source)
        ill = tuple(ex.get(f"illumination_x{i}") for i in (1, 2))
        pts = tuple(ex.get(f"psf_patches_x{i}") for i in (1, 2))
        return cls((ex["psf_x1"], ex["psf_x2"]), m.psf_pedestals, ill, source=m.source or "measurement",
                   patches=pts)  # type: ignore[arg-type]

    @classmethod
    def from_file(cls, path: str | Path, name: str = "psf") -> ChannelPSFs:
        """PSFs from a user's ``.npz``.

        Parameters
        ----------
        path : str or Path
            An ``.npz`` with ``psf_x1``, ``psf_x2`` (pixel grid, odd, centred) and optionally ``pedestal_x1`` /
            ``_x2`` (scalars) and ``illumination_x1`` / ``_x2`` (H, W).
        name : str
            The parameter an error names.

        Returns
        -------
        ChannelPSFs
        """
        p = Path(path)
        if not p.is_file() or p.suffix.lower() != ".npz":
            raise InputError(name, str(p), "an existing .npz file with arrays psf_x1 and psf_x2")
        try:
            with np.load(p, allow_pickle=False) as z:
                if "psf_x1" not in z.files or "psf_x2" not in z.files:
                    raise InputError(name, str(p), "an .npz file with arrays psf_x1 and psf_x2")
                ks = (z["psf_x1"], z["psf_x2"])
                ped = tuple(float(z[f"pedestal_x{i}"]) if f"pedestal_x{i}" in z.files else 0.0 for i in (1, 2))
                ill = tuple(z[f"illumination_x{i}"] if f"illumination_x{i}" in z.files else None for i in (1, 2))
                pts = tuple(z[f"psf_patches_x{i}"] if f"psf_patches_x{i}" in z.files else None for i in (1, 2))
        except (OSError, ValueError) as e:
            raise InputError(name, str(p), f"a readable .npz file ({e})") from None
        return cls(ks, ped, ill, source=str(p), patches=pts)  # type: ignore[arg-type]


def normal_equations(frames: np.ndarray, alpha: ArrayLike) -> tuple[np.ndarray, np.ndarray, float, int]:
    """The per-pixel least-squares separation of the frames, eq. (2).

    Parameters
    ----------
    frames : ndarray, shape (T, H, W)
    alpha : array_like, shape (T,)

    Returns
    -------
    u_hat : ndarray, shape (2, H, W)
        Both channels' separated images.
    N : ndarray, shape (2, 2)
        The normal matrix ``A^T A``.
    sigma : float
        The residuals' noise estimate, ``sqrt(sum r^2 / (T - 2) / (H W))`` (NaN for ``T = 2``).
    dof : int
        ``T - 2``.
    """
    a = np.asarray(alpha, dtype=np.float64)
    A = np.stack([a, 1.0 - a], axis=1)  # (T, 2)
    N = A.T @ A
    if np.linalg.cond(N) > MAX_CONDITION:
        raise InputError("alpha", "nearly constant mixing ratios", "a sequence whose alpha varies (the 2 x 2 normal "
                         "matrix is singular)")
    T, H, W = frames.shape
    y = frames.reshape(T, -1).astype(np.float64)
    u = np.linalg.solve(N, A.T @ y)
    dof = T - 2
    sigma = float(np.sqrt(np.mean((y - A @ u) ** 2) * T / dof)) if dof > 0 else float("nan")
    return u.reshape(2, H, W), N, sigma, dof


class Grid:
    """The padded periodic grid of the solve: the crop padded by the larger kernel's radius to an FFT-friendly
    size, both channels' OTFs ``D`` ``(2, P, Q // 2 + 1)`` (pedestal at DC), ``|f|`` and the forward differences'
    transfer functions (``gy``, ``gx``, ``lap = |gy|^2 + |gx|^2``) for total variation."""

    def __init__(self, shape: tuple[int, int], kernels: tuple[np.ndarray, np.ndarray], pedestals: tuple[float, float]):
        from scipy.fft import next_fast_len

        H, W = shape
        r = max(k.shape[0] // 2 for k in kernels)
        self.pad = min(r, 3 * max(H, W))
        self.shape = (next_fast_len(H + 2 * self.pad, real=True), next_fast_len(W + 2 * self.pad, real=True))
        self.crop = (slice(self.pad, self.pad + H), slice(self.pad, self.pad + W))
        P, Q = self.shape
        self.D = np.stack([self._otf(k, p) for k, p in zip(kernels, pedestals)])  # (2, P, Q//2+1)
        fy = np.fft.fftfreq(P)[:, None]
        fx = np.fft.rfftfreq(Q)[None, :]
        self.f = rfft_frequencies(self.shape)
        # the forward-difference operator's transfer functions (periodic): TV's gradient
        self.gy = np.exp(2j * np.pi * fy) - 1.0
        self.gx = np.exp(2j * np.pi * fx) - 1.0
        self.lap = np.abs(self.gy) ** 2 + np.abs(self.gx) ** 2

    def _otf(self, k: np.ndarray, pedestal: float) -> np.ndarray:
        from scipy.fft import rfft2

        P, Q = self.shape
        n = k.shape[0]
        if n > min(P, Q):  # a kernel wider than the grid: fold it (periodic), its power kept
            c = n // 2
            kk = np.zeros((P, Q))
            iy, ix = (np.arange(n) - c) % P, (np.arange(n) - c) % Q
            np.add.at(kk, (iy[:, None], ix[None, :]), k)
        else:
            kk = np.zeros((P, Q))
            kk[:n, :n] = k
            kk = np.roll(kk, (-(n // 2), -(n // 2)), axis=(0, 1))
        D = rfft2(kk)
        D[0, 0] += pedestal
        return D

    def padded(self, img: np.ndarray, mode: str = "edge") -> np.ndarray:
        """``img`` (H, W) on the grid (P, Q), padded by ``numpy.pad``'s ``mode`` (``'reflect'`` becomes
        ``'symmetric'`` where the padding is wider than the image)."""
        H, W = img.shape
        P, Q = self.shape
        p = self.pad
        if mode == "reflect" and max(p, P - H - p, Q - W - p) >= min(H, W):
            mode = "symmetric"
        return np.pad(img, ((p, P - H - p), (p, Q - W - p)), mode=mode)

    def rfft(self, imgs: np.ndarray) -> np.ndarray:
        from scipy.fft import rfft2

        return rfft2(imgs, axes=(-2, -1), workers=-1)

    def irfft(self, spec: np.ndarray) -> np.ndarray:
        from scipy.fft import irfft2

        return irfft2(spec, s=self.shape, axes=(-2, -1), workers=-1)

    def irfft_crop(self, spec: np.ndarray) -> np.ndarray:
        """``irfft(spec)`` on the crop only: the inverse along the rows kept for the crop's rows, then along the
        columns (about a third of the full inverse's work saved; single precision in, single out)."""
        from scipy.fft import ifft, irfft

        rows = ifft(spec, axis=-2, workers=-1)[..., self.crop[0], :]
        return irfft(rows, n=self.shape[1], axis=-1, workers=-1)[..., self.crop[1]]


def _det2(m11: np.ndarray, m12: np.ndarray, m22: np.ndarray) -> np.ndarray:
    """The determinants of the Hermitian 2 x 2 systems ``[[m11, m12], [conj(m12), m22]]``, inf where one is 0 (its
    solution then 0)."""
    det = m11 * m22 - np.abs(m12) ** 2
    return np.where(np.abs(det) > 0, det, np.inf)


def _solve2(m11: Any, m12: Any, m22: Any, det: Any, b: np.ndarray) -> np.ndarray:
    """Per-frequency solve of the systems ``[[m11, m12], [conj(m12), m22]] x = b`` (``det``: :func:`_det2`) for
    right-hand sides ``b`` ``(..., 2, P, Q // 2 + 1)``: ``[(m22 b0 - m12 b1) / det, (m11 b1 - conj(m12) b0) / det]``,
    those operations in that order, written into one output (right-hand sides of 5 x 2 grids: temporaries and a
    stack's copy were half of a solve's time)."""
    b0, b1 = b[..., 0, :, :], b[..., 1, :, :]
    out = np.empty(np.broadcast_shapes(b.shape, (2,) + np.shape(det)), dtype=np.result_type(m11, m12, det, b))
    o0, o1 = out[..., 0, :, :], out[..., 1, :, :]
    tmp = np.multiply(m12, b1)
    np.multiply(m22, b0, out=o0)
    np.subtract(o0, tmp, out=o0)
    np.divide(o0, det, out=o0)
    np.multiply(np.conj(m12), b0, out=tmp)
    np.multiply(m11, b1, out=o1)
    np.subtract(o1, tmp, out=o1)
    np.divide(o1, det, out=o1)
    return out


class Problem:
    """The joint problem on the grid: data ``zc`` (2, H, W) on the crop with per-pixel noise covariance ``C``
    (2, 2). With ``boundary='padded'`` (or ``'solved'``) the data are extended onto the padding (``pad_mode``) and
    the problem is periodic (``region``: the whole grid); with ``'unknown'`` only the crop is data (``region``: the
    crop)."""

    def __init__(self, g: Grid, z: np.ndarray, C: np.ndarray, boundary: str = "padded", pad_mode: str = "edge"):
        self.g, self.Cinv, self.boundary, self.pad_mode = g, np.linalg.inv(C), boundary, pad_mode
        self.crop, self.zc = g.crop, z
        #: data on the whole grid (padded or solved beyond the crop): the problem is periodic
        self.periodic = boundary != "unknown"
        if self.periodic:
            self.z = np.stack([g.padded(zi, pad_mode) for zi in z])
            self.region = (slice(None), slice(None))
        else:
            self.z = z
            self.region = g.crop

    def blur(self, s: np.ndarray) -> np.ndarray:
        """``D s``: both channels through their OTFs."""
        return self.g.irfft(self.g.D * self.g.rfft(s))

    def blur_t(self, v: np.ndarray) -> np.ndarray:
        """``D^H v``."""
        return self.g.irfft(np.conj(self.g.D) * self.g.rfft(v))

    def weighted(self, r: np.ndarray) -> np.ndarray:
        """``M^T C^-1 M r`` for a residual on the grid (zero outside the data region)."""
        out = np.zeros_like(r)
        cy, cx = self.region
        out[:, cy, cx] = np.einsum("ij,jhw->ihw", self.Cinv, r[:, cy, cx])
        return out

    def data_rhs(self) -> np.ndarray:
        """``D^H M^T C^-1 z``: the right-hand side of eq. (3)."""
        v = np.zeros((2,) + self.g.shape)
        cy, cx = self.region
        v[:, cy, cx] = self.z
        return self.blur_t(self.weighted(v))


def linear_solve(pb: Problem, prior_inv: np.ndarray, x0: np.ndarray | None, iterations: int = 200,
                 tol: float = 1e-6) -> tuple[np.ndarray, int]:
    """The Wiener estimate, eq. (3), by preconditioned conjugate gradients.

    Parameters
    ----------
    pb : Problem
    prior_inv : ndarray, shape (2, P, Q // 2 + 1)
        The prior's inverse spectrum per unnormalised FFT bin, 0 at DC
        (:func:`metafovea.reconstruct.spectra.inverse_prior`).
    x0 : ndarray, shape (2, P, Q), or None
        The start (None: 0).
    iterations : int
        At most this many iterations.
    tol : float
        Stop when the residual's norm is below ``tol`` times the right-hand side's.

    Returns
    -------
    s : ndarray, shape (2, P, Q)
        Both channels' scene on the grid (DN above the dark level).
    iterations : int
        Iterations run.

    Notes
    -----
    The preconditioner is the same system without the mask ``M`` (the data region's share of the grid in its
    place): one 2 x 2 solve per frequency, exact for ``boundary='padded'``, where it is applied once (CG's first
    step) and ``x0`` is not needed.
    """
    g = pb.g
    n_bins = g.shape[0] * g.shape[1]
    D1, D2 = g.D
    Ci = pb.Cinv
    cy, cx = pb.region
    frac = float(np.ones(g.shape)[cy, cx].size) / n_bins  # the data region's share: the preconditioner's weight
    Mpre = (Ci[0, 0] * frac * np.abs(D1) ** 2 + prior_inv[0] * n_bins, Ci[0, 1] * frac * np.conj(D1) * D2,
            Ci[1, 1] * frac * np.abs(D2) ** 2 + prior_inv[1] * n_bins)
    # a floor far below the data's own weight (not the prior's, whose floor reaches 1e9 of its least value: an eps
    # scaled by it shrank the unregularised mean of a flat scene by several per cent)
    eps = 1e-12 * float(np.max(Ci[0, 0] * frac * np.abs(D1) ** 2) + np.max(Ci[1, 1] * frac * np.abs(D2) ** 2))
    Mpre = (Mpre[0] + eps, Mpre[1], Mpre[2] + eps)

    def op(s: np.ndarray) -> np.ndarray:
        S = g.rfft(s)
        return pb.blur_t(pb.weighted(g.irfft(g.D * S))) + g.irfft(prior_inv * n_bins * S)

    det_pre = _det2(*Mpre)

    def pre(r: np.ndarray) -> np.ndarray:
        return g.irfft(_solve2(*Mpre, det_pre, g.rfft(r)))

    b = pb.data_rhs()
    if pb.periodic:  # the preconditioner is the system itself: CG's one step, done directly
        return pre(b), 1
    x = np.zeros_like(b) if x0 is None else x0.copy()
    r = b - op(x)
    zz = pre(r)
    p = zz.copy()
    rz = float(np.vdot(r, zz))
    bn = float(np.linalg.norm(b)) or 1.0
    for it in range(1, iterations + 1):
        Ap = op(p)
        step = rz / float(np.vdot(p, Ap))
        x += step * p
        r -= step * Ap
        if float(np.linalg.norm(r)) < tol * bn:
            return x, it
        zz = pre(r)
        rz_new = float(np.vdot(r, zz))
        p = zz + (rz_new / rz) * p
        rz = rz_new
    return x, iterations


def solved_exterior(g: Grid, channel: int, z: np.ndarray, kernel: np.ndarray, noise_var: float,
                    inverse_prior_on: Callable[[Grid], np.ndarray], estimate: np.ndarray,
                    width_px: int = EXTERIOR_PX, iterations: int = EXTERIOR_ITERATIONS,
                    padding: np.ndarray | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """One channel's data extended over the grid ``g`` by the scene beyond the crop solved for, not padded.

    The PSF is split into its core (the kernel within ``width_px`` of its centre) and the rest (wider disks,
    pedestal): the rest carries the scene from far beyond the crop into it, smoothly, and is taken from ``estimate``
    (the edge-padded solve's scene on ``g``): ``R = (D - D_core) estimate``. The core's part of the data,
    ``z - R``, is then solved for with only the crop as data (eq. 3 with ``M``, the Wiener estimate) on a small
    periodic grid, the crop and a ring of ``width_px`` around it, by conjugate gradients preconditioned by the
    periodic system and started from the edge-padded core data's estimate; blurred by the core and ``R`` added
    back, it is the data the ring would hold. The crop keeps its data, the ring gets the prediction and the rest
    of ``g``'s padding the crop's edge values (as ``boundary='padded'``). It stops after ``iterations`` (a cap: its
    speed against error in BENCHMARKS.md) or once the preconditioned residual has fallen by
    :data:`EXTERIOR_RESIDUAL_REDUCTION`.

    Parameters
    ----------
    g : Grid
        The full solve's grid.
    channel : int
        0 or 1: the channel (``g.D[channel]`` is its transfer function).
    z : ndarray, shape (H, W)
        Its data on the crop (DN above the dark level).
    kernel : ndarray, shape (n, n)
        Its PSF on the pixel grid.
    noise_var : float
        The data's noise variance per pixel, DN^2.
    inverse_prior_on : callable
        ``Grid -> ndarray (P, Q // 2 + 1)``: the channel's inverse prior per unnormalised bin of a grid, 0 at DC.
    estimate : ndarray, shape (P, Q)
        The channel's scene on ``g`` from the edge-padded data (DN above the dark level).
    width_px : int
        The ring's width and the core's radius.
    iterations : int
        At most this many iterations.
    padding : ndarray, shape (P, Q), optional
        The data beyond the ring (default: the crop's edge values).

    Returns
    -------
    data : ndarray, shape (P, Q)
        On ``g``.
    info : dict
        ``width_px``, ``core_power`` (the core's share of the PSF's power), ``grid`` (the ring's), ``iterations``,
        ``residual_reduction`` (the preconditioned residual's norm over its start) and ``seconds``.
    """
    from scipy.fft import irfft2, rfft2

    t0 = time.perf_counter()
    H, W = z.shape
    c = kernel.shape[0] // 2
    r = min(int(width_px), c, g.pad)
    core = kernel[c - r:c + r + 1, c - r:c + r + 1]
    rest = g.irfft((g.D[channel] - g._otf(core, 0.0)) * g.rfft(estimate))
    z_core = z - rest[g.crop]
    gs = Grid((H, W), (core, core), (0.0, 0.0))
    P, Q = gs.shape
    D = gs.D[0]
    q = P * Q * inverse_prior_on(gs)
    w = np.abs(D) ** 2 / noise_var
    data = np.zeros((P, Q), dtype=bool)
    data[gs.crop] = True
    eps = 1e-12 * float(np.max(w))
    # single precision: the solve's rounding (~1e-7 of the data's range) is far below the noise
    Df, Dc = D.astype(np.complex64), np.conj(D).astype(np.complex64) / np.float32(noise_var)
    qf = q.astype(np.float32)
    pre_f = (1.0 / (float(np.mean(data)) * w + q + eps)).astype(np.float32)

    def op(s: np.ndarray) -> np.ndarray:
        S = rfft2(s, workers=-1)
        blurred = irfft2(Df * S, s=(P, Q), workers=-1)
        blurred[~data] = 0.0
        return irfft2(Dc * rfft2(blurred, workers=-1) + qf * S, s=(P, Q), workers=-1)

    def pre(v: np.ndarray) -> np.ndarray:
        return irfft2(pre_f * rfft2(v, workers=-1), s=(P, Q), workers=-1)

    zz = np.zeros((P, Q), dtype=np.float32)
    zz[gs.crop] = z_core
    b = irfft2(Dc * rfft2(zz, workers=-1), s=(P, Q), workers=-1)
    x = irfft2((1.0 / (w + q + eps)).astype(np.float32) * Dc * rfft2(gs.padded(z_core).astype(np.float32),
                                                                      workers=-1), s=(P, Q), workers=-1)
    res = b - op(x)
    y = pre(res)
    p = y.copy()
    ry = ry0 = float(np.vdot(res, y))
    it = 0
    while it < int(iterations) and ry > EXTERIOR_RESIDUAL_REDUCTION ** 2 * ry0:
        it += 1
        Ap = op(p)
        a = ry / float(np.vdot(p, Ap))
        x += a * p
        res -= a * Ap
        y = pre(res)
        ry_new = float(np.vdot(res, y))
        p = y + (ry_new / ry) * p
        ry = ry_new
    pred = irfft2(Df * rfft2(x, workers=-1), s=(P, Q), workers=-1).astype(np.float64)
    out = g.padded(z) if padding is None else padding.copy()
    ring = (slice(g.pad - r, g.pad + H + r), slice(g.pad - r, g.pad + W + r))
    out[ring] = pred[:H + 2 * r, :W + 2 * r] + rest[ring]
    out[g.crop] = z
    return out, {"width_px": r, "core_power": float(np.sum(core) / np.sum(kernel)), "grid": [P, Q],
                 "iterations": it, "residual_reduction": math.sqrt(max(ry, 0.0) / ry0) if ry0 > 0 else 0.0,
                 "seconds": time.perf_counter() - t0}


class PeriodicFilter:
    """The linear estimate of eq. (3) on the periodic grid, one 2 x 2 solve per frequency, with the prior's inverse
    weighted by ``tau``: ``S = M_tau^-1 B``, ``B = D^H C^-1 Z`` (:meth:`rhs`, independent of ``tau``) and
    ``M_tau = D^H C^-1 D + tau n prior_inv``; and its squared bias as the prior predicts it (:meth:`bias2`).

    With ``boundary='padded'`` (data on the whole grid) the filter is the exact solve of eq. (3); with
    ``'unknown'`` it is the periodic approximation that :func:`linear_solve` preconditions with.

    Parameters
    ----------
    pb : Problem
    prior_inv : ndarray, shape (2, P, Q // 2 + 1)
        The prior's inverse spectrum per unnormalised FFT bin, 0 at DC.
    """

    def __init__(self, pb: Problem, prior_inv: np.ndarray):
        g = pb.g
        self.g, self.n = g, g.shape[0] * g.shape[1]
        Ci, D = pb.Cinv, g.D
        self.Ci, self.D, self.prior_inv = Ci, D, prior_inv
        self.d11 = Ci[0, 0] * np.abs(D[0]) ** 2
        self.d22 = Ci[1, 1] * np.abs(D[1]) ** 2
        self.d12 = Ci[0, 1] * np.conj(D[0]) * D[1]
        #: the prior's power per bin (0 at DC, which is not shrunk)
        self.P = np.where(prior_inv > 0, 1.0 / np.where(prior_inv > 0, prior_inv, 1.0), 0.0)

    def rhs(self, Z: np.ndarray) -> np.ndarray:
        """``D^H C^-1 Z`` for data spectra ``Z`` ``(..., 2, P, Q // 2 + 1)``, in ``Z``'s precision."""
        Ci, D = self.Ci, (self.D.astype(np.complex64) if Z.dtype == np.complex64 else self.D)
        return np.stack([np.conj(D[0]) * (Ci[0, 0] * Z[..., 0, :, :] + Ci[0, 1] * Z[..., 1, :, :]),
                         np.conj(D[1]) * (Ci[1, 0] * Z[..., 0, :, :] + Ci[1, 1] * Z[..., 1, :, :])], axis=-3)

    def _m(self, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        w = tau * self.n * self.prior_inv
        return self.d11 + w[0], self.d12, self.d22 + w[1]

    def solve(self, tau: float, B: np.ndarray) -> np.ndarray:
        """``M_tau^-1 B`` for right-hand sides ``B`` ``(..., 2, P, Q // 2 + 1)`` (:meth:`rhs`), in ``B``'s
        precision."""
        m11, m12, m22 = self._m(tau)
        det = _det2(m11, m12, m22)
        if B.dtype == np.complex64:
            m11, m12, m22, det = (np.asarray(v).astype(np.complex64 if np.iscomplexobj(v) else np.float32)
                                  for v in (m11, m12, m22, det))
        return _solve2(m11, m12, m22, det, B)

    def bias2(self, tau: float) -> np.ndarray:
        """The mean squared bias per pixel of each channel, ``(2,)``: ``E |((I - G D) S)_i|^2`` per bin, ``(I - G D) =
        M_tau^-1 tau n prior_inv``, with ``E |S_k|^2`` the prior's power, summed over the grid (Parseval)."""
        m11, m12, m22 = self._m(tau)
        det = _det2(m11, m12, m22)
        w = tau * self.n * self.prior_inv
        minv = ((m22, -m12), (-np.conj(m12), m11))
        b2 = np.stack([sum(np.abs(minv[i][k] * w[k] / det) ** 2 * self.P[k] for k in range(2)) for i in range(2)])
        return mean_square(self.g, b2)


    def risk_data(self, Z: np.ndarray, noise: np.ndarray, detection_snr: float) -> dict[str, Any]:
        """What :meth:`linear_risk` needs of the data, the same for every ``tau``.

        Parameters
        ----------
        Z : ndarray, shape (2, P, Q // 2 + 1)
            The data's spectra on the grid (``rfft`` of :attr:`Problem.z`).
        noise : ndarray, shape (K, 2, P, Q // 2 + 1)
            Spectra of ``K`` draws of the data's noise, padded as the data are: their mean cross-power is the noise
            covariance per bin ``N_f`` (the padding's repeated edge noise included).
        detection_snr : float
            The split between the data's estimate and the prior's (eq. 4 of :meth:`linear_risk`).

        Returns
        -------
        dict
            ``Z``; ``cross``: ``z_k conj(z_i) - N_ki`` as ``cross[k][i]``; ``seen``: per channel, the bins where the
            prior predicts the data's signal at least ``detection_snr`` times their noise.
        """
        C = np.linalg.inv(self.Ci)
        cross = [[Z[k] * np.conj(Z[i]) - np.mean(noise[:, k] * np.conj(noise[:, i]), axis=0) for i in range(2)]
                 for k in range(2)]
        seen = [np.abs(self.D[i]) ** 2 * self.P[i] >= detection_snr * self.n * C[i, i] for i in range(2)]
        return {"Z": Z, "cross": cross, "seen": seen}

    def linear_risk(self, tau: float, gain: np.ndarray, data: dict[str, Any]) -> np.ndarray:
        """The mean squared error per pixel of each channel's linear estimate ``L_i (G_tau z)_i`` against the scene,
        less a part that does not depend on ``tau`` or ``L``, ``(2,)``: eq. (4) on the bins where the prior predicts
        the data's signal at least ``detection_snr`` times their noise, its expectation under the prior elsewhere.

        Parameters
        ----------
        tau : float
            The prior's weight.
        gain : ndarray, shape (2, P, Q // 2 + 1)
            Each channel's real filter ``L_i(f)`` applied after the solve (1: the solve alone).
        data : dict
            :meth:`risk_data` of the data and their noise draws.

        Returns
        -------
        ndarray, shape (2,)

        Notes
        -----
        Per bin, ``z = D s + n`` and ``E z z^H = D s s^H D^H + N``, so ``(z z^H - N) / (D_k conj(D_i))`` is an
        unbiased estimate of ``s_k conj(s_i)`` wherever ``D`` is not 0. The error of ``s_hat_i = L_i (G z)_i`` is
        ``|((L G D - I) s)_i + (L G n)_i|^2``; its expectation, with that estimate in place of ``s s^H`` and the
        terms free of ``tau`` and ``L`` dropped, is (the generalised SURE of Y. C. Eldar, IEEE Trans. Signal
        Process. 57, 471 (2009), for a linear estimate)

            T_i = L_i^2 |(G z)_i|^2 - 2 L_i Re sum_k H_ik (z_k conj(z_i) - N_ki),    H_ik = G_ik / conj(D_i)   (4)

        (``G_ik`` carries the factor ``conj(D_i)``, so ``H`` is finite). It needs no prior, but its variance grows
        as ``1 / |D|^2``, and the padded grid's data differ from ``D s + n`` by the padding's model error, which
        ``1 / |D|^2`` magnifies where the PSF passes almost nothing; there (``|D_i|^2 P_i`` below ``detection_snr``
        times the noise ``n C_ii``) ``T_i`` is replaced by its expectation under the prior ``P`` (channels
        independent): ``L_i^2 E|(G z)_i|^2 - 2 L_i Re(G_ii D_i) P_i``.

        A padding error ``p`` left in a seen bin enters ``T`` with the wrong sign: for one channel and
        ``G = conj(D) / (|D|^2 + t)``, its part of ``T`` is ``-|p|^2 (|D|^2 + 2 t) / (|D|^2 + t)^2`` where the true
        error holds ``+|p|^2 |D|^2 / (|D|^2 + t)^2``, both near ``|p|^2 / |D|^2`` for ``t << |D|^2``: where ``p``
        outweighs the noise in bins that the split still counts as seen (low noise, a PSF with near zeros, a crop of a
        wider scene with sharp edges), the estimate prefers a small ``t`` that in truth amplifies ``p``. Subtracting
        ``|p|^2`` from ``z_i conj(z_i)``, like the noise, would remove it, given an estimate of ``|p|^2`` that does not
        overstate it (the difference of two padding rules overstates it where the padding is a solved or predicted
        one: see the strict xfail in ``tests/reconstruct/test_deconvolve.py``).
        """
        m11, m12, m22 = self._m(tau)
        det = _det2(m11, m12, m22)
        Ci, D, n, Z = self.Ci, self.D, self.n, data["Z"]
        C = np.linalg.inv(Ci)
        mi = ((m22 / det, -m12 / det), (-np.conj(m12) / det, m11 / det))
        out = np.empty(2)
        for i in range(2):
            j = 1 - i
            G = [sum(mi[i][q] * np.conj(D[q]) * Ci[q, k] for q in range(2)) for k in range(2)]
            # the coefficients of L_i^2 and of -2 L_i: the data's (eq. 4) where seen, the prior's expectation elsewhere;
            # each computed on its own bins only (element by element: the same numbers as on the whole grid)
            s = data["seen"][i]
            u = ~s
            a, b = np.empty(s.shape), np.empty(s.shape)
            a[s] = np.abs(G[0][s] * Z[0][s] + G[1][s] * Z[1][s]) ** 2
            # H_ik = G_ik / conj(D_i): the other channel's term of G_ik carries conj(D_i) in m12
            H = [mi[i][i][s] * Ci[i, k] - Ci[i, j] * np.abs(D[j][s]) ** 2 / det[s] * Ci[j, k] for k in range(2)]
            b[s] = np.real(sum(H[k] * data["cross"][k][i][s] for k in range(2)))
            Gu = [G[k][u] for k in range(2)]
            a[u] = (sum(np.abs(Gu[k] * D[k][u]) ** 2 * self.P[k][u] for k in range(2))
                    + n * np.real(sum(Gu[k] * np.conj(Gu[m]) * C[k, m] for k in range(2) for m in range(2))))
            b[u] = np.real(Gu[i] * D[i][u]) * self.P[i][u]
            out[i] = float(mean_square(self.g, gain[i] ** 2 * a - 2.0 * gain[i] * b))
        return out

def mean_square(g: Grid, spec: np.ndarray) -> np.ndarray:
    """The mean over the grid's pixels of a field whose power per unnormalised rfft bin is ``spec``.

    Parameters
    ----------
    g : Grid
    spec : ndarray, shape (..., P, Q // 2 + 1)

    Returns
    -------
    ndarray, shape (...)
        ``sum_f spec(f) / n^2`` over the full plane (the half plane's inner columns counted twice; Parseval).
    """
    P, Q = g.shape
    return np.sum(spec * rfft_weights(g.shape), axis=(-2, -1)) / float(P * Q) ** 2


def _shrink(gy: np.ndarray, gx: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mag = np.sqrt(gy ** 2 + gx ** 2)
    f = np.maximum(1.0 - t / np.maximum(mag, 1e-30), 0.0)
    return gy * f, gx * f


def tv_admm(pb: Problem, s0: np.ndarray, lam: np.ndarray, iterations: int) -> tuple[np.ndarray, int]:
    """Total-variation regularised least squares by ADMM.

    Parameters
    ----------
    pb : Problem
    s0 : ndarray, shape (2, P, Q)
        The start (the Wiener estimate).
    lam : ndarray, shape (2,)
        Each channel's TV weight.
    iterations : int

    Returns
    -------
    s : ndarray, shape (2, P, Q)
    iterations : int

    Notes
    -----
    Minimises ``1/2 ||M D s - z||^2_{C^-1} + sum_i lam_i TV_iso(s_i)`` with the splits ``v = D s`` and
    ``w = grad s`` (S. Boyd et al., Found. Trends Mach. Learn. 3, 1 (2011)): the ``s`` step is diagonal per
    frequency, the ``v`` step a 2 x 2 solve per pixel, the ``w`` step isotropic shrinkage.
    """
    g = pb.g
    cy, cx = pb.region
    rho1 = float(np.max(np.abs(pb.Cinv)))
    rho2 = rho1 * 0.1
    den = rho1 * np.abs(g.D) ** 2 + rho2 * g.lap[None]
    den[:, 0, 0] = np.maximum(den[:, 0, 0], 1e-12 * rho1)
    # the data step inside the crop: (C^-1 + rho1 I) v = C^-1 z + rho1 q
    Kd = np.linalg.inv(pb.Cinv + rho1 * np.eye(2))
    Ciz = np.einsum("ij,jhw->ihw", pb.Cinv, pb.z)
    s = s0.copy()
    S = g.rfft(s)
    v = g.irfft(g.D * S)
    wy, wx = g.irfft(g.gy * S), g.irfft(g.gx * S)
    d1 = np.zeros_like(v)
    dy, dx = np.zeros_like(wy), np.zeros_like(wx)
    t = (lam / rho2)[:, None, None]
    for _ in range(iterations):
        S = (rho1 * np.conj(g.D) * g.rfft(v - d1)
             + rho2 * (np.conj(g.gy) * g.rfft(wy - dy) + np.conj(g.gx) * g.rfft(wx - dx))) / den
        As = g.irfft(g.D * S)
        gy_s, gx_s = g.irfft(g.gy * S), g.irfft(g.gx * S)
        q = As + d1
        v = q.copy()
        v[:, cy, cx] = np.einsum("ij,jhw->ihw", Kd, Ciz + rho1 * q[:, cy, cx])
        wy, wx = _shrink(gy_s + dy, gx_s + dx, t)
        d1 += As - v
        dy += gy_s - wy
        dx += gx_s - wx
    return g.irfft(S), iterations


def _floor_info(fits: list[dict[str, Any]], shared: float) -> dict[str, Any]:
    """``info['noise_floor']``: both channels' fits (:func:`~metafovea.reconstruct.spectra.noise_floor`) and why
    the noise model was or was not raised."""
    used = [i for i, f in enumerate(fits) if f["used"]]
    if used:
        why = "; ".join(
            f"x{i + 1}: the data hold {fits[i]['ratio']:.3g}x the modelled noise ({fits[i]['modelled_dn2']:.3g} DN^2) "
            f"flat in frequency (likelihood ratio {fits[i]['statistic']:.3g} > {fits[i]['threshold']:.4g})"
            for i in used) + (f", {shared:.3g} DN^2 of it shared by both channels" if shared > 0 else "") + (
            "; used as noise: something the noise model leaves out (undithered rounding, a fixed pattern subtracted "
            "with a larger error than stated, a PSF that differs from the data's)")
    else:
        why = ("the data's power flat in frequency is what the noise model predicts (likelihood ratio "
               + ", ".join(f"{f['statistic']:.3g}" for f in fits) + f" <= {fits[0]['threshold']:.4g}): kept")
    return {"raised": [f["used"] for f in fits], "x1": fits[0], "x2": fits[1], "shared_dn2": shared, "why": why}


def prepare_problem(frames: ArrayLike, alpha: ArrayLike, psfs: ChannelPSFs, offset: float, sigma: float | None,
                    boundary: str = "padded", pad_mode: str = "edge",
                    fpn_error_dn: float = 0.0) -> tuple[Problem, np.ndarray, dict[str, Any]]:
    """The problem of eq. (3) from the frames: separated, offset-removed, illumination-divided channels.

    Parameters
    ----------
    frames : array_like, shape (T, H, W)
        DN, fixed pattern removed; ``T >= 3``.
    alpha : array_like, shape (T,)
        Mixing ratios.
    psfs : ChannelPSFs
    offset : float
        The frames' dark level, DN.
    sigma : float or None
        The frames' temporal noise, DN (None: from the residuals of eq. 2).
    boundary : {'padded', 'unknown'}
        (Already checked by :func:`check_boundary`.)
    pad_mode : str
        ``numpy.pad`` mode of the padding (:data:`PAD_MODES`).
    fpn_error_dn : float
        The rms error (DN) of the fixed pattern subtracted from the frames.

    Returns
    -------
    problem : Problem
    C : ndarray, shape (2, 2)
        The separated channels' per-pixel noise covariance, DN^2.
    info : dict
        ``sigma_dn``, ``sigma_source`` (``'residuals'`` or ``'given'``), ``fpn_error_dn``, ``noise_std_dn``,
        ``noise_correlation``, ``grid``, ``pad_px``, ``psf_source``, ``boundary``.

    Notes
    -----
    The fixed pattern's error is the same in every frame, so it does not average out and enters both separated
    channels in full (``u + [1, 1] e``): ``C += e^2 [[1, 1], [1, 1]]``.
    """
    fr = np.asarray(frames, dtype=np.float64)
    if fr.ndim != 3 or fr.shape[0] < 3:
        raise InputError("frames", f"array of shape {fr.shape}", "(T, H, W) frames with T >= 3")
    T, H, W = fr.shape
    pad_mode = check_choice("pad_mode", pad_mode, PAD_MODES)
    a = np.asarray(alpha, dtype=np.float64).reshape(-1)
    if a.shape != (T,) or not np.all(np.isfinite(a)):
        raise InputError("alpha", f"array of shape {a.shape}", f"({T},) finite mixing ratios")
    u, N, sig_fit, dof = normal_equations(fr, a)
    sig = sig_fit if sigma is None else float(sigma)
    if not (math.isfinite(sig) and sig > 0):
        raise InputError("sigma", sig, "a frame noise level > 0 (DN)")
    z = np.empty_like(u)
    r_rms = []
    for i in range(2):
        r = psfs.illumination[i]
        r = np.ones((H, W)) if r is None else np.asarray(r, dtype=np.float64)
        if r.shape != (H, W):
            raise InputError(f"illumination_x{i + 1}", f"array of shape {r.shape}", f"(H, W) = {(H, W)} values > 0")
        if not np.all(r > 0):  # a deconvolution divides by it: a field the camera does not see cannot be recovered
            dark = float(np.mean(~(r > 0)))
            raise InputError(f"illumination_x{i + 1}", f"0 on {100 * dark:.1f} % of the crop",
                             "values > 0 everywhere (the channel's optical train vignettes part of the field to "
                             "nothing: a smaller crop, or a clear aperture that passes the whole field)")
        z[i] = (u[i] - offset) / r
        r_rms.append(float(np.sqrt(np.mean(r ** -2.0))))
    g = Grid((H, W), psfs.kernels, psfs.pedestals)
    fe = float(fpn_error_dn or 0.0)
    if not (math.isfinite(fe) and fe >= 0):
        raise InputError("fpn_error_dn", fpn_error_dn, "the rms error (DN) of the subtracted fixed pattern, >= 0")
    # the separated channels' noise covariance: temporal noise through the 2 x 2 fit, plus the FPN estimate's error
    C = (sig ** 2 * np.linalg.inv(N) + fe ** 2 * np.ones((2, 2))) * np.outer(r_rms, r_rms)
    # what the data show beyond that model: an excess flat in frequency (eq. 5 of metafovea.reconstruct.spectra)
    floors = [noise_floor(z[i], g.D[i], g.shape, float(C[i, i])) for i in range(2)]
    excess = (floors[0][0] - C[0, 0], floors[1][0] - C[1, 1])
    shared = common_excess(z[0], z[1], float(C[0, 1]), excess)  # an error in every frame alike: in both (eq. 6)
    C = C + np.array([[excess[0], shared], [shared, excess[1]]])
    info = {"sigma_dn": sig, "sigma_source": "residuals" if sigma is None else "given",
            "noise_floor": _floor_info([f[1] for f in floors], shared), "fpn_error_dn": fe,
            "noise_std_dn": [float(math.sqrt(C[0, 0])), float(math.sqrt(C[1, 1]))],
            "noise_correlation": float(C[0, 1] / math.sqrt(C[0, 0] * C[1, 1])),
            "grid": list(g.shape), "pad_px": g.pad, "psf_source": psfs.source,
            "boundary": boundary}
    return Problem(g, z, C, boundary, pad_mode), C, info

"""Known mixing ratios: closed-form per-pixel least squares over a window of frames.

Model per pixel ``p`` and frame ``t``::

    y_tp = alpha_t x1_p + (1 - alpha_t) x2_p + noise                                                    (1)

With ``A = [alpha, 1 - alpha]`` (``T x 2``) the normal matrix ``N = A^T A`` is the same for every pixel, so the
solution is two weighted sums of the frames (one small BLAS call)::

    [x1; x2] = N^-1 A^T Y                                                                                (2)

Conditioning
------------
``cond(N)`` is always reported. Noise on the frames (std ``sigma``) becomes noise of std
``sigma * sqrt((N^-1)_ii)`` on channel ``i`` (``info['noise_gain']``). Above ``max_condition`` (equal or
nearly equal alphas, a stopped polariser) the solve is refused with :class:`InputError` unless
``regularize`` is given:

* ``regularize='difference'``: ridge penalty ``lam ||x1 - x2||^2``, i.e. ``[x1; x2] = (N + lam L)^-1 A^T Y``
  (3), with the smallest ``lam`` that brings ``cond(N + lam L)`` down to ``max_condition``
  (``L = [[1, -1], [-1, 1]]``, :func:`difference_ridge`). The data
  determine ``alpha x1 + (1 - alpha) x2``; the penalty fills the undetermined difference with zero,
  i.e. both channels fall back to the unseparated mixture rather than amplified noise.
* a float: that ``lam`` (same penalty).

Invalid samples (NaN/inf, or ``>= saturation``) are masked per pixel; each pixel then has its own
normal matrix and pixels whose valid samples cannot separate the channels come back as NaN and are
counted in ``info['unresolved_pixels']``.

:class:`SlidingLSQ` keeps the sums of (2) running over a sliding window for a live camera.

Measured figures: BENCHMARKS.md, section "Reconstruction".
"""

from __future__ import annotations

import inspect
import logging
import math
from collections import deque
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, DTypeLike

from metafovea.errors import InputError, as_float, check_int, check_range
from metafovea.reconstruct._common import (
    Timings,
    as_alpha,
    as_frames,
    check_keywords,
    estimate_noise,
    image_dtype,
    valid_mask,
)
from metafovea.reconstruct.denoise import denoise as denoise_image
from metafovea.reconstruct.result import Reconstruction

log = logging.getLogger(__name__)

#: Default refusal threshold for cond(N) (a slow 0.5 deg/frame polariser gives ~633 over 8 frames).
MAX_CONDITION = 1e4
#: Above this cond(N) a warning is logged (noise is amplified by ~sqrt(cond)).
WARN_CONDITION = 100.0
_L = np.array([[1.0, -1.0], [-1.0, 1.0]])


def normal_matrix(alpha: np.ndarray) -> np.ndarray:
    """The normal matrix of eq. (2).

    Parameters
    ----------
    alpha : array_like, shape (T,)

    Returns
    -------
    ndarray, shape (2, 2)
        ``N = A^T A`` for ``A = [alpha, 1 - alpha]``.
    """
    a = np.asarray(alpha, dtype=np.float64)
    A = np.stack([a, 1 - a], axis=1)
    return A.T @ A


def condition_number(alpha: np.ndarray) -> float:
    """The 2-norm condition number of the normal matrix of eq. (2).

    Parameters
    ----------
    alpha : array_like, shape (T,)

    Returns
    -------
    float
        ``inf`` when singular.
    """
    ev = np.linalg.eigvalsh(normal_matrix(alpha))
    return float(ev[1] / ev[0]) if ev[0] > ev[1] * 1e-15 else math.inf


def _cond(M: np.ndarray) -> float:
    ev = np.linalg.eigvalsh(M)
    return float(ev[1] / ev[0]) if ev[0] > ev[1] * 1e-15 else math.inf


def difference_ridge(N: np.ndarray, max_condition: float) -> float:
    """The ridge weight of ``regularize='difference'``, eq. (3).

    Parameters
    ----------
    N : ndarray, shape (2, 2)
    max_condition : float

    Returns
    -------
    float
        The smallest ``lam >= 0`` with ``cond(N + lam L) <= max_condition`` (``L`` penalises ``x1 - x2``).

    Notes
    -----
    ``cond(N + lam L)`` first falls and then rises with ``lam``; the search (a log-spaced scan, then bisection)
    stays on the falling branch, and if even its minimum exceeds ``max_condition`` the minimiser is returned.
    """
    if _cond(N) <= max_condition:
        return 0.0
    scale = max(np.trace(N), 1e-300)
    # log-spaced scan to bracket the minimum, then bisection on the falling branch
    grid = scale * np.logspace(-12, 3, 301)
    conds = np.array([_cond(N + g * _L) for g in grid])
    imin = int(np.argmin(conds))
    if conds[imin] > max_condition:
        return float(grid[imin])
    lo, hi = (grid[imin - 1] if imin > 0 else 0.0), grid[imin]
    j = np.nonzero(conds[: imin + 1] <= max_condition)[0][0]
    hi = grid[j]
    lo = grid[j - 1] if j > 0 else 0.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _cond(N + mid * _L) <= max_condition:
            hi = mid
        else:
            lo = mid
    return float(hi)


def solve_weights(alpha: np.ndarray, *, max_condition: float = MAX_CONDITION,
                  regularize: str | float | None = None, quiet: bool = False) -> tuple[np.ndarray, dict[str, Any]]:
    """The weights of eq. (2) (or (3)) and a conditioning report.

    Parameters
    ----------
    alpha : array_like, shape (T,)
    max_condition : float
        Refuse (or regularise) above this ``cond(N)``.
    regularize : {'difference'} or float or None
        None: refuse an ill-conditioned ``N`` (:class:`InputError`); ``'difference'``: :func:`difference_ridge`;
        a float: that ridge ``lam``.
    quiet : bool
        Do not log a warning above :data:`WARN_CONDITION`.

    Returns
    -------
    Wt : ndarray, shape (2, T)
        ``[x1; x2] = Wt @ Y``.
    report : dict
        ``condition``, ``condition_regularized``, ``regularization_lambda``, ``noise_gain`` (each channel's noise
        std per unit frame noise, ``sqrt(diag(Wt Wt^T))``).
    """
    a = np.asarray(alpha, dtype=np.float64)
    N = normal_matrix(a)
    cond = _cond(N)
    lam = 0.0
    if regularize is None:
        if not cond <= max_condition:
            raise InputError(
                "alpha", [round(float(v), 4) for v in a],
                f"mixing ratios that vary within the window (normal-matrix condition number <= {max_condition:g})",
                detail=f"condition number {cond:.3g}: the channels cannot be separated without amplifying "
                       f"noise; pass regularize='difference' or a "
                       f"longer window / faster polariser")
    elif isinstance(regularize, str):
        if regularize.lower() not in ("difference", "auto"):
            raise InputError("regularize", regularize, "None, 'difference' or a non-negative float")
        lam = difference_ridge(N, max_condition)
    else:
        lam = as_float("regularize", regularize)
        if lam < 0:
            raise InputError("regularize", regularize, "None, 'difference' or a non-negative float")
    Nr = N + lam * _L
    A = np.stack([a, 1 - a], axis=1)
    Ninv = np.linalg.inv(Nr)
    Wt = Ninv @ A.T
    # noise std gain per channel: sqrt(diag(Wt Wt^T)) (white noise of unit std on every frame)
    gain = np.sqrt(np.sum(Wt ** 2, axis=1))
    if cond > WARN_CONDITION and not quiet:
        log.warning("known-alpha LSQ: normal-matrix condition number %.3g (noise gain x1 %.3g, x2 %.3g)%s",
                    cond, gain[0], gain[1], f"; difference ridge lam={lam:.3g}" if lam else "")
    report = {"condition": cond, "condition_regularized": _cond(Nr), "regularization_lambda": lam,
              "noise_gain": gain.tolist()}
    return Wt, report


def _lsq_masked(Y: np.ndarray, a: np.ndarray, M: np.ndarray, max_condition: float, lam: float,
                dt: np.dtype) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Per-pixel normal equations using only valid samples (``M`` True = valid)."""
    T, H, W = Y.shape
    Mf = M.reshape(T, -1).astype(np.float64)
    Y0 = np.where(M, Y, 0.0).reshape(T, -1).astype(np.float64)
    b_ = 1 - a
    n11 = (a * a) @ Mf + lam
    n12 = (a * b_) @ Mf - lam
    n22 = (b_ * b_) @ Mf + lam
    r1 = a @ Y0
    r2 = b_ @ Y0
    det = n11 * n22 - n12 * n12
    tr = n11 + n22
    disc = np.sqrt(np.maximum((n11 - n22) ** 2 + 4 * n12 * n12, 0.0))
    ev_hi, ev_lo = 0.5 * (tr + disc), 0.5 * (tr - disc)
    with np.errstate(divide="ignore", invalid="ignore"):
        cond = np.where(ev_lo > ev_hi * 1e-15, ev_hi / ev_lo, np.inf)
        ok = cond <= max_condition
        x1 = np.where(ok, (n22 * r1 - n12 * r2) / det, np.nan)
        x2 = np.where(ok, (n11 * r2 - n12 * r1) / det, np.nan)
    info = {"masked_samples": int(M.size - M.sum()), "unresolved_pixels": int((~ok).sum()),
            "pixel_condition_max": float(np.max(cond[ok])) if ok.any() else math.inf}
    if info["unresolved_pixels"]:  # (info: a summary's nonfinite_pixels says it once, not once per window)
        log.info("known-alpha LSQ: %d pixel(s) lack enough valid samples to separate the channels (NaN)",
                 info["unresolved_pixels"])
    return x1.reshape(H, W).astype(dt), x2.reshape(H, W).astype(dt), info


def lsq_known_alpha(frames: ArrayLike, alpha: ArrayLike, *, max_condition: float = MAX_CONDITION,
                    regularize: str | float | None = None, saturation: float | None = None,
                    denoise: str | None = None, denoise_kw: dict[str, Any] | None = None,
                    noise_sigma: float | None = None) -> Reconstruction:
    """Per-pixel least-squares separation with known mixing ratios, eq. (2).

    Parameters
    ----------
    frames : array_like, shape (T, H, W)
        ``T >= 2``; float32 preserved.
    alpha : array_like, shape (T,)
    max_condition : float
        Refuse (or regularise) when ``cond(A^T A)`` exceeds this.
    regularize : {'difference'} or float or None
        None: refuse; ``'difference'``: the ridge on ``x1 - x2`` by the stated rule; a float: that ridge ``lam``
        (module docstring, eq. 3).
    saturation : float, optional
        Samples ``>=`` this value are invalid (as NaN/inf) and masked per pixel.
    denoise : {'tv', 'bilateral', 'nlm'}, optional
        A denoiser for both outputs (:func:`metafovea.reconstruct.denoise.denoise`), its noise level
        ``noise_sigma`` times the channel's noise gain.
    denoise_kw : dict, optional
        Keywords of the denoiser.
    noise_sigma : float, optional
        The frames' noise std (default: from the LSQ residual when ``T > 2`` and nothing is masked, else from the
        images).

    Returns
    -------
    Reconstruction
        ``info``: ``condition``, ``condition_regularized``, ``regularization_lambda``, ``noise_gain``, ``frames``;
        with masking ``masked_samples``, ``unresolved_pixels``, ``pixel_condition_max``; with denoising
        ``noise_sigma``, ``denoise``.
    """
    tm = Timings()
    with tm.measure("solve"):
        Y = as_frames(frames, min_frames=2)
        T, H, W = Y.shape
        a = as_alpha(alpha, T)
        max_condition = check_range("max_condition", max_condition, 1.0, None, lo_inclusive=True)
        if noise_sigma is not None:
            noise_sigma = check_range("noise_sigma", noise_sigma, 0.0, None)
        if denoise_kw:
            check_keywords(dict(denoise_kw), tuple(inspect.signature(denoise_image).parameters)[3:],
                           f"denoise '{denoise}'")
        Wt, info = solve_weights(a, max_condition=max_condition, regularize=regularize)
        dt = image_dtype(Y)
        M = valid_mask(Y, saturation)
        if M is None:
            X = Wt.astype(dt) @ Y.reshape(T, -1)
            x1, x2 = X[0].reshape(H, W), X[1].reshape(H, W)
        else:
            x1, x2, minfo = _lsq_masked(Y, a, M, max_condition, info["regularization_lambda"], dt)
            info.update(minfo)
    info["frames"] = T
    if denoise:
        with tm.measure("denoise"):
            sig = noise_sigma
            if sig is None and T > 2 and M is None:
                sig = residual_sigma(Y, a, x1, x2)
            if sig is None:
                sig = float(np.mean([estimate_noise(x1), estimate_noise(x2)]))
                gains = (1.0, 1.0)
            else:
                gains = tuple(info["noise_gain"])
            info["noise_sigma"] = float(sig)
            kw = dict(denoise_kw or {})
            x1 = denoise_image(x1, denoise, sigma=sig * gains[0], **kw)
            x2 = denoise_image(x2, denoise, sigma=sig * gains[1], **kw)
        info["denoise"] = denoise
    return Reconstruction(x1=x1, x2=x2, alpha=a, fpn=None, method="lsq", timings=dict(tm), info=info)


def residual_sigma(Y: np.ndarray, a: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> float:
    """The frames' noise std from the residual of eq. (1).

    Parameters
    ----------
    Y : ndarray, shape (T, H, W)
        ``T > 2``.
    a : ndarray, shape (T,)
    x1, x2 : ndarray, shape (H, W)

    Returns
    -------
    float
        ``sqrt(mean r^2 T / (T - 2))`` (``T - 2`` degrees of freedom per pixel).
    """
    T = Y.shape[0]
    if T <= 2:
        raise InputError("frames", f"{T} frames", "more than 2 frames to estimate the noise from the residual")
    r = Y - a[:, None, None] * x1[None] - (1 - a)[:, None, None] * x2[None]
    return float(np.sqrt(np.nanmean(r.astype(np.float64) ** 2) * T / (T - 2)))


class SlidingLSQ:
    """Real-time known-alpha reconstruction over a sliding window (incremental sums).

    Parameters
    ----------
    window : int
        Frames held (>= 2).
    max_condition : float
    regularize : {'difference'} or float or None
        As :func:`solve_weights`.
    refresh : int
        Rebuild the sums from the held frames every so many pushes (bounds round-off drift).
    out_dtype : dtype, optional
        Of the images (default: float32 for float32 frames, else float64).

    Notes
    -----
    ``push(frame, alpha)`` adds a frame, drops the oldest once ``window`` frames are held, and updates the running
    sums ``sum alpha y`` and ``sum y`` (float64) in O(H W) per frame, independent of the window length. The rows
    of ``Wt`` in eq. (2) are affine in alpha, ``u alpha + v``, so ``solve()`` is a 2 x 2 solve plus two scaled
    adds. Frames with NaN/inf are refused here (use :func:`lsq_known_alpha` with masking for those).
    """

    def __init__(self, window: int = 8, *, max_condition: float = MAX_CONDITION,
                 regularize: str | float | None = None, refresh: int = 4096,
                 out_dtype: DTypeLike = None) -> None:
        self.window = check_int("window", window, 2, 100000)
        self.max_condition = as_float("max_condition", max_condition)
        self.regularize = regularize
        self.refresh = check_int("refresh", refresh, 1)
        self._frames: deque[np.ndarray] = deque()
        self._alpha: deque[float] = deque()
        self._say: np.ndarray | None = None
        self._sy: np.ndarray | None = None
        self._pushes = 0
        self._out_dtype = out_dtype
        self.shape: tuple[int, int] | None = None

    def __len__(self) -> int:
        return len(self._frames)

    @property
    def ready(self) -> bool:
        """True once ``window`` frames are held."""
        return len(self._frames) == self.window

    def _rebuild(self) -> None:
        F = np.stack(self._frames).astype(np.float64)
        a = np.asarray(self._alpha)
        self._say = np.tensordot(a, F, axes=1)
        self._sy = F.sum(axis=0)

    def push(self, frame: ArrayLike, alpha: float) -> None:
        """Add ``frame`` (H, W), finite, with its mixing ratio; drop the oldest beyond ``window``."""
        f = np.asarray(frame)
        if f.ndim != 2:
            raise InputError("frame", f"array of shape {f.shape}", "one 2-D (H, W) frame")
        if self.shape is None:
            self.shape = f.shape
            self._say = np.zeros(f.shape)
            self._sy = np.zeros(f.shape)
            if self._out_dtype is None:
                self._out_dtype = np.float32 if f.dtype == np.float32 else np.float64
        elif f.shape != self.shape:
            raise InputError("frame", f"frame of shape {f.shape}", f"frames of the first frame's shape {self.shape}")
        if not np.all(np.isfinite(f)):
            raise InputError("frame", "frame with NaN/inf", "finite frames (mask with lsq_known_alpha instead)")
        a = float(as_alpha([alpha], 1)[0])
        self._frames.append(f)
        self._alpha.append(a)
        self._say += a * f
        self._sy += f
        if len(self._frames) > self.window:
            old = self._frames.popleft()
            ao = self._alpha.popleft()
            self._say -= ao * old
            self._sy -= old
        self._pushes += 1
        if self._pushes % self.refresh == 0:
            self._rebuild()

    def solve(self) -> tuple[np.ndarray, np.ndarray, float]:
        """The images for the frames currently held (at least 2).

        Returns
        -------
        x1, x2 : ndarray, shape (H, W)
        condition : float
            ``cond(N)`` of the held alphas.
        """
        if len(self._frames) < 2:
            raise InputError("window", len(self._frames), "at least 2 frames pushed before solve()")
        a = np.asarray(self._alpha)
        Wt, rep = solve_weights(a, max_condition=self.max_condition, regularize=self.regularize)
        # x = Wt @ Y = c_a * sum(alpha y) + c_1 * sum(y) because Wt is affine in alpha:
        # rows of Wt are (N^-1 [alpha; 1 - alpha]) = u * alpha + v
        Ni = np.linalg.inv(normal_matrix(a) + rep["regularization_lambda"] * _L)
        u = Ni[:, 0] - Ni[:, 1]
        v = Ni[:, 1]
        dt = self._out_dtype
        x1 = (u[0] * self._say + v[0] * self._sy).astype(dt, copy=False)
        x2 = (u[1] * self._say + v[1] * self._sy).astype(dt, copy=False)
        return x1, x2, rep["condition"]

    def update(self, frame: ArrayLike, alpha: float) -> tuple[np.ndarray, np.ndarray, float] | None:
        """:meth:`push`, then :meth:`solve` once the window is full.

        Returns
        -------
        tuple or None
            ``(x1, x2, condition)``; None before the window is full.
        """
        self.push(frame, alpha)
        return self.solve() if self.ready else None

"""Fixed-pattern noise (FPN): a low-rank, bounded, additive pattern ``f`` constant over time.

Identifiability
---------------
``y_t = alpha_t x1 + (1 - alpha_t) x2 + f``: the columns ``[alpha_t, 1 - alpha_t, 1]`` have rank 2
(``1 = alpha + (1 - alpha)``), so ``(x1 + f, x2 + f)`` explains the frames exactly as well as
``(x1, x2)``. The mixture alone cannot identify ``f``. This module therefore uses, in order:

1. **calibration frames** (a closed shutter or a uniform scene): ``f`` = their temporal mean minus its
   spatial mean (the mean of ``f`` is never identifiable and is set to 0), low-rank by optimal singular-value
   shrinkage (default, :func:`shrink_lowrank`: M. Gavish and D. L. Donoho, "Optimal shrinkage of singular
   values", IEEE Trans. Inf. Theory 63, 2137 (2017), Frobenius loss, the noise of the mean known from the
   frames' scatter, plus, for frames of whole counts, the rounding that noise below a count does not dither:
   :func:`quantisation_bias_variance`) or projected on rank ``rank`` when one is given (the paper's 20), and
   clipped to ``+-bound``;
   identified up to that constant and the calibration noise. ``info['error_rms_dn']`` estimates the estimate's
   rms error: Stein's unbiased risk estimate of the shrinkage (E. J. Candes, C. A. Sing-Long and J. D. Trzasko,
   IEEE Trans. Signal Process. 61, 4643 (2013)), or split halves for a fixed rank.
2. **blind, from the foveal constraint** (``method='foveal'``, the default without calibration frames;
   ``--fpn prior`` at the CLI). The separated images carry the pattern, ``x1' = x1 + f``, ``x2' = x2 + f``,
   and the constraint ``D x1 = g C x2 + o`` then reads ``D x1' - g C x2' - o = (D - g C) f``: the data
   **observe** ``(D - g C) f``, one number per constraint pixel (48 x 48 for 290 x 290 frames and scale 6),
   and nothing else of ``f``. The rest comes from one stated **assumption**: the foveal image has no detail
   finer than the constraint's boxes, ``x1 = U D x1`` (``U``: each box's value spread over its box). Then
   ``x1' - U(g C x2' + o) = (I - g U C) f``, solved exactly for ``f`` (the ``U C`` part only couples the
   central crop, a small fixed-point problem), then projected on rank ``rank``. Where the assumption fails
   the error is known in closed form: ``f_hat - f = (I - g U C)^-1 (I - U D) x1`` (the foveal image's
   sub-box detail) plus the constraint's own mismatch (PSF differences) spread over its boxes; the low-rank
   projection removes the part of that error which is not low rank. The contrast gain ``g`` and offset ``o``
   are fitted by least squares of ``D x1'`` on ``C x2'`` (the pattern is uncorrelated with the scene, so the
   fit is consistent; the stored radiometric gain holds for the mean level, not the contrast), unless
   ``fit_gain=False`` or the fitted gain is
   not significant (:data:`GAIN_SIGNIFICANCE` standard errors; a crop without contrast), when the stored
   ``foveal_gain`` / ``foveal_offset`` are used.
   It needs ``0 < g < 0.98`` (:data:`MAX_FOVEAL_GAIN`): at ``g >= 1`` the magnification-invariant part of
   ``f`` in the crop is not identified, and the estimate falls back to the TV prior (``info['fallback']``).
   ``info['identified']`` is ``'foveal'``; ``info['observed']``, ``info['assumed']`` and
   ``info['unidentified']`` say the above in words.
3. **the TV low-rank prior** (``method='tv'``; paper: rank 20, bounded to +-0.1) applied to the separated
   images: ``f`` minimises the (Charbonnier-smoothed) total variation of ``x1' - f`` and ``x2' - f`` plus the
   foveal misfit ``||D(x1' - f) - C(x2' - f)||^2``, subject to ``rank f <= rank``, ``|f| <= bound`` and
   ``mean f = 0`` (projected gradient). This removes stripe-like patterns that raise the TV of both images;
   scene content that is itself low rank and common to both images cannot be told apart from FPN
   (``info['identified'] = 'prior'``).

Neither motion nor the polariser's alpha diversity adds to this without a motion model: every window's
separated images carry the same ``f`` but each ``(x1_k + f, x2_k + f)`` fits its frames as well as
``(x1_k, x2_k)``; averaging the per-window images (a static scene) only lowers the noise of ``x1'``, ``x2'``,
and where the scene moves it averages the foveal detail that the assumption above neglects.

Measured figures: BENCHMARKS.md, sections "Blind fixed-pattern noise" and "PSF-aware reconstruction against the
scene" (the shutter-frame estimate).
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.errors import InputError, as_float, check_choice, check_int
from metafovea.reconstruct._common import as_frames
from metafovea.reconstruct.operators import FovealOperator, tv_charbonnier

log = logging.getLogger(__name__)


def project_lowrank(f: np.ndarray, rank: int, bound: float) -> np.ndarray:
    """A pattern's zero-mean, best rank-``rank`` approximation, clipped.

    Parameters
    ----------
    f : ndarray, shape (H, W)
    rank : int
    bound : float
        Clip to ``[-bound, bound]``.

    Returns
    -------
    ndarray, shape (H, W)
        Mean 0 (after the clip).
    """
    f = f - f.mean()
    if rank < min(f.shape):
        U, s, Vt = np.linalg.svd(f, full_matrices=False)
        f = (U[:, :rank] * s[:rank]) @ Vt[:rank]
    f = np.clip(f, -bound, bound)
    return f - f.mean()


#: blind estimates of :func:`estimate_fpn` (the CLI's ``--fpn prior`` uses the first)
BLIND_METHODS = ("foveal", "tv")
#: rank of the blind foveal estimate unless told: measured on the simulated 290 x 290 siemens star and bars
#: (BENCHMARKS.md, FPN): rank 3-6 beat the true rank 20, whose extra freedom keeps more of the foveal detail
FOVEAL_RANK = 4
#: the foveal estimate solves (I - g U C) f = z by a fixed point that contracts as g; above this, the TV prior
MAX_FOVEAL_GAIN = 0.98


def estimate_fpn(*, calibration: ArrayLike | None = None, x1: np.ndarray | None = None, x2: np.ndarray | None = None,
                 rank: int | None = None, bound: float | None = None, scale: float = 6.0,
                 offset: tuple[float, float] = (0.0, 0.0), iterations: int = 150, eps: float | None = None,
                 foveal_weight: float = 1.0, foveal_gain: float = 1.0, foveal_offset: float = 0.0,
                 method: str = "foveal", fit_gain: bool = True) -> tuple[np.ndarray, dict[str, Any]]:
    """Estimate the additive fixed pattern (module docstring: what each way identifies).

    Parameters
    ----------
    calibration : array_like, shape (T, H, W) or (H, W), optional
        Frames of a closed shutter or a uniform scene: used when given (item 1).
    x1, x2 : ndarray, shape (H, W), optional
        Otherwise the separated images (both contain ``+ f``), for a blind estimate by ``method``.
    rank : int, optional
        With calibration frames: None is optimal singular-value shrinkage (one frame: the paper's 20), an integer
        a projection. ``'foveal'``: default :data:`FOVEAL_RANK`. ``'tv'``: default ``min(20, min(H, W) // 16)``
        (with more freedom the prior starts to absorb scene content).
    bound : float, optional
        The pattern's amplitude limit; default: the paper's 0.1 of the images' dynamic range for the blind
        estimates (scale-invariant: frames in DN or in [0, 1]), no clipping for calibration frames.
    scale, offset : float, tuple of 2 float
        The foveal constraint's geometry.
    iterations, eps, foveal_weight : int, float, float
        ``'tv'``: projected-gradient steps, the Charbonnier smoothing (default 2 % of the images' range), the
        weight of the foveal misfit.
    foveal_gain, foveal_offset : float
        The stored radiometric gain and offset of the constraint.
    method : {'foveal', 'tv'}
        ``'foveal'`` (item 2): exact solve under ``x1 = U D x1`` with ``D x1 = g C x2 + o`` (``g``, ``o`` fitted
        unless ``fit_gain=False``; a gain >= :data:`MAX_FOVEAL_GAIN` falls back to ``'tv'``); ``'tv'``: the TV
        low-rank prior (item 3).
    fit_gain : bool
        Fit the constraint's contrast gain and offset (:func:`foveal_contrast`).

    Returns
    -------
    fpn : ndarray, shape (H, W)
        Mean 0.
    info : dict
        ``identified`` (``'calibration'``, ``'foveal'`` or ``'prior'``), ``rank``, ``bound``, ``rms``; the
        calibration's ``error_rms_dn`` with ``error_rms_from`` (``'sure'`` or ``'split-halves'``) and
        ``rank_rule`` (``'shrinkage'``, ``'given'`` or ``'paper'``); the blind estimates' ``observed``,
        ``assumed`` and ``unidentified`` in words.
    """
    shape = np.shape(calibration)[-2:] if calibration is not None else np.shape(x1)[-2:]
    tv_rank = rank if rank is not None else max(1, min(20, min(shape) // 16)) if len(shape) == 2 else 20
    if calibration is None and rank is None:
        rank = FOVEAL_RANK if method == "foveal" else tv_rank
    if rank is not None:  # (None with calibration frames: optimal shrinkage)
        rank = check_int("rank", rank, 1, 100000)
    if bound is None:
        if calibration is not None:
            bound = float("inf")
        else:
            bound = 0.1 * max(float(np.ptp(np.asarray(x1, dtype=np.float64))) if x1 is not None else 0.0,
                              float(np.ptp(np.asarray(x2, dtype=np.float64))) if x2 is not None else 0.0, 1e-300)
    if not (isinstance(bound, float) and bound == math.inf):
        bound = as_float("bound", bound)
    if bound <= 0:
        raise InputError("bound", bound, "bound > 0 (the FPN amplitude limit, paper: 0.1)")
    if calibration is not None:
        return _from_calibration(calibration, rank, bound)
    if x1 is None or x2 is None:
        raise InputError("calibration", None, "calibration frames, or both separated images x1 and x2",
                         detail="FPN is not identifiable from the mixture alone (columns [alpha, 1-alpha, 1] have "
                                "rank 2)")
    method = check_choice("method", method, BLIND_METHODS)
    a1 = np.asarray(x1, dtype=np.float64)
    a2 = np.asarray(x2, dtype=np.float64)
    if a1.shape != a2.shape or a1.ndim != 2:
        raise InputError("x2", f"array of shape {a2.shape}", f"a 2-D image of x1's shape {a1.shape}")
    if not (np.all(np.isfinite(a1)) and np.all(np.isfinite(a2))):
        raise InputError("x1", "images with NaN/inf", "finite separated images for a blind FPN estimate")
    if method == "foveal":
        op = FovealOperator(a1.shape, scale, offset)
        g, o, se = foveal_contrast(a1, a2, op) if fit_gain else (float(foveal_gain), float(foveal_offset), 0.0)
        if not (0.0 < g < MAX_FOVEAL_GAIN and g > GAIN_SIGNIFICANCE * se):
            g, o, fit_gain = float(foveal_gain), float(foveal_offset), False
        if 0.0 < g < MAX_FOVEAL_GAIN:
            return _foveal(a1, a2, op, rank, bound, g, o, fit_gain)
        # at gain >= 1 the pattern's magnification-invariant part (e.g. any function of the angle about the centre)
        # solves (I - g U C) f = 0: not identified, and the fixed point diverges; the TV prior makes no such claim
        f, info = _tv_prior(a1, a2, check_int("rank", tv_rank, 1, 100000), bound, scale, offset, iterations, eps,
                            foveal_weight, foveal_gain, foveal_offset)
        return f, {**info, "fallback": f"TV prior: foveal contrast gain {g:.3g} outside (0, {MAX_FOVEAL_GAIN})"}
    return _tv_prior(a1, a2, rank, bound, scale, offset, iterations, eps, foveal_weight, foveal_gain, foveal_offset)


def _from_calibration(calibration: ArrayLike, rank: int | None, bound: float) -> tuple[np.ndarray, dict[str, Any]]:
    C = as_frames(calibration, min_frames=1, name="calibration")
    if not np.all(np.isfinite(C)):
        raise InputError("calibration", "frames with NaN/inf", "finite calibration frames")
    T = int(C.shape[0])
    Cf = C.astype(np.float64)
    raw = Cf.mean(axis=0)
    clipped = float(np.mean(np.abs(raw - raw.mean()) > bound))
    info: dict[str, Any] = {"identified": "calibration", "bound": bound, "calibration_frames": T,
                            "unidentified": "the mean of the pattern (set to 0) and the calibration noise "
                                            f"(~sigma/sqrt({T}) per pixel)", "clipped_fraction": clipped}
    if rank is None and T >= 2:
        # the noise of the mean from the frames' scatter (white, the same at every pixel), and for frames of whole
        # counts the rounding that the scatter does not show (noise far below one count does not dither it)
        v = float(np.mean(Cf.var(axis=0, ddof=1)))
        step = quantiser_step(Cf)
        q = 0.0 if step is None else step ** 2 * quantisation_bias_variance(noise_variance(v / step ** 2))
        noise = float(np.sqrt(v / T + q))
        f, kept, err = shrink_lowrank(raw, noise)
        f = np.clip(f, -bound, bound)
        f = f - f.mean()
        info.update(rank=kept, rank_rule="shrinkage", noise_of_mean_dn=noise, error_rms_dn=err, error_rms_from="sure",
                    rounding_dn=math.sqrt(q))
    else:
        rank = 20 if rank is None else rank  # one frame: no noise estimate to shrink with; the paper's rank
        f = project_lowrank(raw, rank, bound)
        info.update(rank=rank, rank_rule="given" if T >= 2 else "paper")
        err = calibration_error_rms(C, rank, bound)
        if err is not None:
            info["error_rms_dn"] = err
            info["error_rms_from"] = "split-halves"
    info["rms"] = float(np.sqrt(np.mean(f ** 2)))
    return f, info


def shrink_lowrank(f: np.ndarray, noise: float) -> tuple[np.ndarray, int, float]:
    """Optimal shrinkage of the singular values of a low-rank matrix in white noise, with its risk estimate.

    Parameters
    ----------
    f : ndarray, shape (H, W)
        Low rank plus white noise (its mean is removed first).
    noise : float
        The noise std per entry (<= 0 or non-finite: nothing is shrunk).

    Returns
    -------
    estimate : ndarray, shape (H, W)
        Zero mean.
    kept : int
        Components kept.
    error_rms : float
        The estimate's rms error, from SURE (eq. 2).

    Notes
    -----
    With ``y = s / (sqrt(n) noise)``, ``n = max(H, W)``, ``beta = min / max``, the Frobenius-loss shrinker [1]_ is

        eta(y) = sqrt((y^2 - beta - 1)^2 - 4 beta) / y   above the bulk edge 1 + sqrt(beta), 0 below   (1)

    and Stein's unbiased risk estimate of that spectral estimator [2]_

        SURE = -H W noise^2 + sum (eta_i - s_i)^2 + 2 noise^2 div,
        div = sum_i (eta'(s_i) + |H - W| eta_i / s_i) + 2 sum_{i != j} s_i eta_i / (s_i^2 - s_j^2)        (2)

    References
    ----------
    .. [1] M. Gavish and D. L. Donoho, "Optimal shrinkage of singular values", IEEE Trans. Inf. Theory 63, 2137
       (2017).
    .. [2] E. J. Candes, C. A. Sing-Long and J. D. Trzasko, "Unbiased risk estimates for singular value
       thresholding and spectral estimators", IEEE Trans. Signal Process. 61, 4643 (2013).
    """
    g = np.asarray(f, dtype=np.float64)
    g = g - g.mean()
    H, W = g.shape
    sig = float(noise)
    U, s, Vt = np.linalg.svd(g, full_matrices=False)
    if not (math.isfinite(sig) and sig > 0):  # noise-free frames: nothing to shrink
        return g, int(np.sum(s > 0)), 0.0
    n, beta = max(H, W), min(H, W) / max(H, W)
    c = math.sqrt(n) * sig
    y = s / c
    keep = y > 1.0 + math.sqrt(beta)
    q = np.where(keep, (y ** 2 - beta - 1.0) ** 2 - 4.0 * beta, 1.0)
    eta = np.where(keep, np.sqrt(np.maximum(q, 0.0)) / np.maximum(y, 1e-300), 0.0) * c
    # d eta / d s = d eta_n / d y (the scale c cancels)
    d_eta = np.where(keep,
                     (2.0 * y ** 2 * (y ** 2 - beta - 1.0) / np.sqrt(q) - np.sqrt(q)) / np.maximum(y, 1e-300) ** 2,
                     0.0)
    s2 = s ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        cross = (s * eta)[:, None] / (s2[:, None] - s2[None, :])
    np.fill_diagonal(cross, 0.0)
    cross = np.where(np.isfinite(cross), cross, 0.0)
    div = float(np.sum(d_eta + abs(H - W) * np.where(s > 0, eta / np.maximum(s, 1e-300), 0.0)) + 2.0 * np.sum(cross))
    sure = -H * W * sig ** 2 + float(np.sum((eta - s) ** 2)) + 2.0 * sig ** 2 * div
    est = (U * eta) @ Vt
    return est - est.mean(), int(keep.sum()), math.sqrt(max(sure, 0.0) / (H * W))


def quantiser_step(frames: np.ndarray) -> float | None:
    """The step of the quantiser the frames went through, from their values: the greatest common divisor of the
    differences between their distinct values when these are whole numbers (1 for counts, 16 for 12-bit counts
    stored in the top bits of 16), None for frames of fractional values (no rounding known) or a single value.

    Parameters
    ----------
    frames : ndarray

    Returns
    -------
    float or None
    """
    a = np.asarray(frames, dtype=np.float64)
    if not np.all(a == np.round(a)):
        return None
    u = np.unique(a)
    if u.size < 2:
        return None
    step = int(np.gcd.reduce(np.diff(u).astype(np.int64)))
    return float(step) if step > 0 else None


def noise_variance(rounded_var: float) -> float:
    """The variance ``s^2`` of Gaussian noise (in steps^2) whose samples, rounded to whole steps from values spread
    across the step, scatter with variance ``rounded_var``: the inverse of ``s^2 + 1/12 - q(s^2)``
    (:func:`quantisation_bias_variance` ``q``: the rounding adds its own 1/12 less the part that stays in the mean),
    which rises monotonically from 0 at ``s = 0``.

    Parameters
    ----------
    rounded_var : float
        >= 0, steps^2.

    Returns
    -------
    float
        steps^2.
    """
    from scipy.optimize import brentq

    v = max(float(rounded_var), 0.0)
    if v <= 0.0:
        return 0.0
    return float(brentq(lambda s2: s2 + 1.0 / 12.0 - quantisation_bias_variance(s2) - v, 0.0, v, xtol=1e-12))


def quantisation_bias_variance(noise_var: float, terms: int = 256) -> float:
    """The variance, over values spread across the quantiser's step, of the mean error that rounding to whole steps
    leaves in the average of many samples with Gaussian noise of variance ``noise_var`` (steps^2).

    The rounding error ``e(c) = Q(c) - c`` is a sawtooth, ``sum_k (-1)^k sin(2 pi k c) / (pi k)``; noise of
    standard deviation ``s`` averages each harmonic by ``exp(-2 pi^2 k^2 s^2)`` (its characteristic function), so
    the mean error's variance over ``c`` is

        sum_k exp(-4 pi^2 k^2 s^2) / (2 pi^2 k^2)                                                      (1)

    ``1/12`` without noise (the plain rounding error, which no number of frames averages away), below 2e-3 from
    ``s = 0.3`` steps on (the noise dithers it). ``s^2`` from the rounded frames' scatter: :func:`noise_variance`.

    Parameters
    ----------
    noise_var : float
        >= 0, in steps^2.
    terms : int
        Harmonics summed (the rest is below ``1 / (2 pi^2 terms)``, 2e-4 steps^2 at the default).

    Returns
    -------
    float
        steps^2.
    """
    k = np.arange(1, int(terms) + 1, dtype=np.float64)
    s2 = max(float(noise_var), 0.0)
    return float(np.sum(np.exp(-4.0 * math.pi ** 2 * k ** 2 * s2) / (2.0 * math.pi ** 2 * k ** 2)))


def calibration_error_rms(calibration: np.ndarray, rank: int, bound: float = math.inf) -> float | None:
    """The rms error that the calibration noise leaves in a rank-``rank`` calibration estimate, from split halves.

    Parameters
    ----------
    calibration : ndarray, shape (T, H, W)
    rank : int
    bound : float

    Returns
    -------
    float or None
        Frame units; None with fewer than 2 frames.

    Notes
    -----
    The estimates from the even and the odd frames each carry about twice the full estimate's noise variance, so
    ``rms(f_even - f_odd) / 2`` (weighted by the halves' frame counts) estimates the full estimate's error, the
    rank projection's choice of the noisiest directions included (which a per-frame formula
    ``sigma / sqrt(T) sqrt(r (H + W - r) / (H W))`` misses). Not included: drift of the pattern between the
    shutter frames and the scene frames.
    """
    C = np.asarray(calibration, dtype=np.float64)
    if C.shape[0] < 2:
        return None
    fa = project_lowrank(C[0::2].mean(axis=0), rank, bound)
    fb = project_lowrank(C[1::2].mean(axis=0), rank, bound)
    na, nb = C[0::2].shape[0], C[1::2].shape[0]
    # var(fa - fb) = v (T/na + T/nb) with v the full estimate's error variance (noise variance scales as 1/frames)
    T = C.shape[0]
    return float(np.sqrt(np.mean((fa - fb) ** 2) / (T / na + T / nb)))


#: the fitted contrast gain replaces the stored one only when it is this many standard errors from zero (a crop
#: without scene contrast, as the simulated bars' centre, fits g ~ 0.001 from the pattern alone)
GAIN_SIGNIFICANCE = 20.0


def foveal_contrast(x1: np.ndarray, x2: np.ndarray, op: FovealOperator) -> tuple[float, float, float]:
    """The foveal constraint's contrast gain and offset, fitted.

    Parameters
    ----------
    x1, x2 : ndarray, shape (H, W)
    op : FovealOperator

    Returns
    -------
    g, o, se_g : float
        The least-squares fit ``D x1 ~ g C x2 + o`` and the gain's standard error.
    """
    c = op.C(x2).ravel()
    d = op.D(x1).ravel()
    A = np.stack([c, np.ones_like(c)], axis=1)
    (g, o), *_ = np.linalg.lstsq(A, d, rcond=None)
    res = d - A @ np.array([g, o])
    sxx = float(np.sum((c - c.mean()) ** 2))
    se = math.sqrt(float(np.sum(res ** 2)) / max(c.size - 2, 1) / sxx) if sxx > 0 else math.inf
    return float(g), float(o), se


def _foveal(a1: np.ndarray, a2: np.ndarray, op: FovealOperator, rank: int, bound: float, gain: float, bias: float,
            fitted: bool) -> tuple[np.ndarray, dict[str, Any]]:
    """The blind estimate from the foveal constraint (module docstring, item 2) with contrast gain ``0 < g <
    MAX_FOVEAL_GAIN`` and offset ``o`` (``fitted``: from :func:`foveal_contrast`, else the stored ones)."""
    g, o = float(gain), float(bias)
    # (I - g U C) f = z: only the crop couples, c = C f solves c = C z + g (C U) c (a contraction: ||C U|| <= 1)
    z = a1 - op.upsample(g * op.C(a2) + o)
    cz = op.C(z)
    c = cz.copy()
    for it in range(1, 2001):  # noqa: B007 (the count is reported after the loop)
        c_new = cz + g * op.C(op.upsample(c))
        done = np.max(np.abs(c_new - c)) <= 1e-10 * max(float(np.max(np.abs(cz))), 1e-300)
        c = c_new
        if done:
            break
    f_full = z + g * op.upsample(c)
    f = project_lowrank(f_full, rank, bound)
    observed = op.D(f) - g * op.C(f)
    r_data = op.D(a1) - g * op.C(a2) - o
    info = {"identified": "foveal", "rank": rank, "bound": bound, "foveal_gain": g, "foveal_offset": o,
            "foveal_gain_fitted": bool(fitted), "fixed_point_iterations": it,
            "low_shape": list(op.low_shape),
            "observed": f"(D - g C) f: {op.low_shape[0]} x {op.low_shape[1]} foveal-constraint values "
                        "(D x1' - g C x2' - o), up to the constraint's own mismatch",
            "assumed": "the foveal image has no detail finer than the constraint's boxes (x1 = U D x1); the "
                       f"pattern has rank <= {rank}",
            "unidentified": "the mean of the pattern (set to 0); the foveal image's sub-box detail, which enters "
                            "the estimate as (I - g U C)^-1 (I - U D) x1 where not removed by the rank limit",
            "observed_rms_misfit": float(np.sqrt(np.mean((observed - (r_data - r_data.mean())) ** 2))),
            "rms": float(np.sqrt(np.mean(f ** 2)))}
    return f, info


def _tv_prior(a1: np.ndarray, a2: np.ndarray, rank: int, bound: float, scale: float, offset: tuple[float, float],
              iterations: int, eps: float | None, foveal_weight: float, foveal_gain: float,
              foveal_offset: float) -> tuple[np.ndarray, dict[str, Any]]:
    """The TV low-rank prior (module docstring, item 3)."""
    iterations = check_int("iterations", iterations, 1, 100000)
    op = FovealOperator(a1.shape, scale, offset, gain=foveal_gain, bias=foveal_offset)
    if eps is None:
        eps = 0.02 * max(float(np.ptp(a1)), float(np.ptp(a2)), 1e-6)
    # step: Charbonnier TV gradient is 8/eps-Lipschitz per image; foveal term ~2 mu
    mu = as_float("foveal_weight", foveal_weight) * a1.size / max(op.low_shape[0] * op.low_shape[1], 1)
    step = 1.0 / (2 * 8.0 / eps + 2 * mu * 2.0)
    f = np.zeros_like(a1)
    hist = []
    for _ in range(iterations):
        v1, g1 = tv_charbonnier(a1 - f, eps)
        v2, g2 = tv_charbonnier(a2 - f, eps)
        r = op.residual(a1 - f, a2 - f)
        grad = -(g1 + g2) - 2 * mu * (op.DT(r) - op.gain * op.CT(r))
        hist.append(v1 + v2 + mu * float(np.sum(r ** 2)))
        f = project_lowrank(f - step * grad, rank, bound)
    info = {"identified": "prior", "rank": rank, "bound": bound, "iterations": iterations,
            "unidentified": "the mean of the pattern (set to 0) and any low-rank scene content common to both "
                            "images; the mixture alone cannot identify FPN",
            "loss_history": hist[:: max(1, iterations // 50)], "rms": float(np.sqrt(np.mean(f ** 2)))}
    return f, info

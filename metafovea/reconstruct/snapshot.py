"""Snapshot (single-frame) recovery: registration of the two channels, then separation.

In one frame ``y = a x1 + (1 - a) x2`` the foveal image ``x1`` appears twice: at full size, and
``scale`` times smaller in the centre of ``x2`` (``D x1 = C x2``). So the downsampled frame ``D y``
(containing ``a D x1``) and the frame's centre ``C y`` (containing ``(1 - a) D x1``) share content.

Registration (:func:`register`), as in the paper:
1. normalised cross-correlation (scikit-image ``match_template``) of ``D y`` against the centre of
   ``y`` at the nominal scale gives the integer translation of the crop;
2. intensity-based refinement: scale and sub-pixel translation maximise the NCC between ``D_s y``
   and ``C_o y`` (Powell, over the exact area-weighted operators).

Separation (:func:`snapshot`): ``x2`` is eliminated through the data term
(``x2 = (y - a x1) / (1 - a)``) and ``x1`` minimises

    mu ||D x1 - C x2||^2 + lam_tv (TV(x1) + TV(x2)) + lam_ex * exclusion(x1, x2)

(L-BFGS), where the exclusion loss ([1]_, used by the paper) is the squared Frobenius
norm of ``tanh(|grad x1| / g0) * tanh(|grad x2| / g0)`` at two scales, penalising edges present in
both images. Initialisation as in the paper: ``n1`` = the registered centre crop of ``y`` spread back
onto the full grid (``D^T``, normalised), ``n2 = (y - a n1) / (1 - a)``; ``init='frame'`` starts from the
unseparated frame instead (``n1 = n2 = y``), the ablation of that initialisation (``metafovea study ablation``).

Weights: foveal 1, TV 0.01, exclusion 0.001, with TV normalised by the frame's mean gradient (the best of a small
grid on the 96 x 96 test scene at sigma 0.01).

One frame holds half the information of two images: the constraint only fixes ``x1``'s low
frequencies (``1/scale`` of its band), so the result keeps residual overlap (the paper says so too);
``info`` reports the foveal misfit and the loss history, and tests measure the gain over the
initialisation rather than claim a clean separation.

Measured figures: BENCHMARKS.md, section "Reconstruction".

References
----------
.. [1] X. Zhang, R. Ng and Q. Chen, "Single image reflection separation with perceptual losses", CVPR (2018) 4786.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.errors import InputError, as_float, check_choice, check_int
from metafovea.reconstruct._common import Timings, image_dtype
from metafovea.reconstruct.operators import FovealOperator, grad2d, grad2d_adjoint, tv_charbonnier
from metafovea.reconstruct.result import Reconstruction

log = logging.getLogger(__name__)

#: starts of :func:`snapshot`'s separation: the paper's ``n1 = D^T y`` (registered crop), or the unseparated frame
INITS = ("crop", "frame")


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    den = math.sqrt(float(np.sum(a * a) * np.sum(b * b)))
    return float(np.sum(a * b) / den) if den > 0 else 0.0


def _as_frame(frame: ArrayLike) -> np.ndarray:
    y = np.asarray(frame)
    if y.ndim == 3 and y.shape[0] == 1:
        y = y[0]
    if y.ndim != 2 or not np.issubdtype(y.dtype, np.number):
        raise InputError("frame", f"array of shape {y.shape}", "one 2-D (H, W) numeric frame")
    if not np.all(np.isfinite(y)):
        raise InputError("frame", "frame with NaN/inf", "a finite frame (snapshot recovery cannot mask pixels)")
    return y if y.dtype in (np.float32, np.float64) else y.astype(np.float64)


def register(frame: ArrayLike, *, scale: float = 6.0, search: int | None = None, refine: bool = True,
             refine_scale: bool = True, max_scale_change: float = 0.03, min_gain: float = 0.02) -> dict[str, Any]:
    """Locate the foveal content in the frame's centre (Registration, module docstring).

    Parameters
    ----------
    frame : array_like, shape (H, W)
        One finite frame.
    scale : float
        The nominal scale f1 / f2.
    search : int, optional
        The largest integer shift (x2 pixels) searched by NCC; default half the constraint size.
    refine, refine_scale : bool
        Refine the offset (and the scale) by maximising the NCC (Powell).
    max_scale_change : float
        The refinement's bound on the scale, relative, around the nominal one (the offset's: +-1 px around the
        NCC shift).
    min_gain : float
        The refinement is accepted only when it raises the NCC by more than this: in a single mixed frame the
        two views share only part of their content, which biases the intensity optimum.

    Returns
    -------
    dict
        ``offset`` ``(dy, dx)``, ``scale``, ``ncc``, ``low_shape``; ``offset_ncc`` and ``ncc_coarse`` of the
        integer search, ``refine_evaluations``.
    """
    from scipy.optimize import minimize
    from skimage.feature import match_template

    y = _as_frame(frame).astype(np.float64)
    H, W = y.shape
    op0 = FovealOperator((H, W), scale)
    h, w = op0.low_shape
    tmpl = op0.D(y)
    if search is None:
        search = max(2, min(h, w) // 2)
    search = check_int("search", search, 0, 100000)
    y0, x0 = (H - h) // 2, (W - w) // 2
    sy0, sy1 = max(0, y0 - search), min(H, y0 + h + search)
    sx0, sx1 = max(0, x0 - search), min(W, x0 + w + search)
    ncc_map = match_template(y[sy0:sy1, sx0:sx1], tmpl)
    iy, ix = np.unravel_index(int(np.argmax(ncc_map)), ncc_map.shape)
    # offset of the crop relative to the centred crop (FovealOperator's convention)
    c_y = H / 2.0 - h / 2.0
    c_x = W / 2.0 - w / 2.0
    off = (float(sy0 + iy - c_y), float(sx0 + ix - c_x))
    res: dict[str, Any] = {"offset_ncc": off, "ncc_coarse": float(ncc_map[iy, ix]), "scale": float(op0.scale)}
    off = tuple(float(np.clip(o, -(n - m) / 2.0, (n - m) / 2.0)) for o, n, m in ((off[0], H, h), (off[1], W, w)))
    best = {"offset": off, "scale": float(op0.scale)}
    if refine:
        def cost(p: np.ndarray) -> float:
            s = p[2] if refine_scale else op0.scale
            try:
                op = FovealOperator((H, W), s, (p[0], p[1]), low=(h, w))
            except InputError:
                return 1.0
            if op.low_shape != (h, w):
                return 1.0
            return -_ncc(op.D(y), op.C(y))

        p0 = np.array([off[0], off[1], op0.scale])
        bounds = [(off[0] - 1.0, off[0] + 1.0), (off[1] - 1.0, off[1] + 1.0),
                  (op0.scale * (1 - max_scale_change), op0.scale * (1 + max_scale_change))]
        r = minimize(cost, p0, method="Powell", bounds=bounds, options={"xtol": 1e-3, "ftol": 1e-7, "maxfev": 600})
        # accept only a clear improvement: the mixture's other content biases the NCC optimum a little
        if r.fun < cost(p0) - min_gain:
            best = {"offset": (float(r.x[0]), float(r.x[1])),
                    "scale": float(r.x[2]) if refine_scale else float(op0.scale)}
        res["refine_evaluations"] = int(r.nfev)
    op = FovealOperator((H, W), best["scale"], best["offset"], low=(h, w))
    res.update(best, ncc=_ncc(op.D(y), op.C(y)), low_shape=(h, w))
    return res


def _pool(z: np.ndarray) -> np.ndarray:
    H, W = z.shape
    return z[: H // 2 * 2, : W // 2 * 2].reshape(H // 2, 2, W // 2, 2).mean(axis=(1, 3))


def _poolT(u: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    out = np.zeros(shape)
    out[: u.shape[0] * 2, : u.shape[1] * 2] = np.repeat(np.repeat(u, 2, 0), 2, 1) / 4.0
    return out


def exclusion_loss(x1: np.ndarray, x2: np.ndarray, g0: float,
                   levels: int = 2) -> tuple[float, np.ndarray, np.ndarray]:
    """The exclusion loss [1]_ and its gradients.

    Parameters
    ----------
    x1, x2 : ndarray, shape (H, W)
    g0 : float
        The gradient scale of ``tanh(|grad x| / g0)``.
    levels : int
        Dyadic scales (2 x 2 mean pooling between them).

    Returns
    -------
    value : float
        ``sum_levels sum_directions mean(tanh(|grad x1| / g0)^2 tanh(|grad x2| / g0)^2)``.
    grad_x1, grad_x2 : ndarray, shape (H, W)
    """
    val = 0.0
    g1_tot = np.zeros_like(x1)
    g2_tot = np.zeros_like(x2)
    a, b = x1, x2
    chain = []
    for _ in range(levels):
        if min(a.shape) < 4:
            break
        ga, gb = grad2d(a), grad2d(b)
        da = [np.zeros_like(a), np.zeros_like(a)]
        db = [np.zeros_like(b), np.zeros_like(b)]
        n = a.size
        for k in range(2):
            ta = np.tanh(np.abs(ga[k]) / g0)
            tb = np.tanh(np.abs(gb[k]) / g0)
            val += float(np.sum(ta ** 2 * tb ** 2)) / n
            da[k] = 2 * ta * tb ** 2 * (1 - ta ** 2) * np.sign(ga[k]) / g0 / n
            db[k] = 2 * tb * ta ** 2 * (1 - tb ** 2) * np.sign(gb[k]) / g0 / n
        ga_x = grad2d_adjoint(*da)
        gb_x = grad2d_adjoint(*db)
        for shape in reversed(chain):
            ga_x = _poolT(ga_x, shape)
            gb_x = _poolT(gb_x, shape)
        g1_tot += ga_x
        g2_tot += gb_x
        chain.append(a.shape)
        a, b = _pool(a), _pool(b)
    return val, g1_tot, g2_tot


def mean_charbonnier_tv(z: np.ndarray, eps: float) -> tuple[float, np.ndarray]:
    """The snapshot loss's TV term: :func:`~metafovea.reconstruct.operators.tv_charbonnier` per pixel.

    Parameters
    ----------
    z : ndarray, shape (H, W)
    eps : float

    Returns
    -------
    value : float
    gradient : ndarray, shape (H, W)
        Both divided by ``z.size`` (independent of the image size).
    """
    val, g = tv_charbonnier(z, eps)
    return val / z.size, g / z.size


def snapshot(frame: ArrayLike, *, alpha: float | None = None, scale: float = 6.0,
             offset: tuple[float, float] | None = None, register_frame: bool = True,
             foveal_gain: float = 1.0, foveal_offset: float = 0.0,
             foveal_weight: float = 1.0, tv_weight: float = 0.01, exclusion_weight: float = 0.001,
             iterations: int = 200, init: str = "crop") -> Reconstruction:
    """Separate one frame ``y = alpha x1 + (1 - alpha) x2`` (Separation, module docstring).

    Parameters
    ----------
    frame : array_like, shape (H, W)
    alpha : float, optional
        Default 0.5 (polariser at 45 degrees): one frame cannot tell it from the image contrasts.
    scale, offset : float, tuple of 2 float, optional
        The crop's geometry: from :func:`register` unless ``offset`` is given or ``register_frame`` is false.
    foveal_gain, foveal_offset : float
        The constraint's radiometry ``D x1 = gain C x2 + offset``.
    foveal_weight, tv_weight, exclusion_weight : float
        ``mu``, ``lam_tv``, ``lam_ex``, relative to the frame's own contrast (frames in DN and in [0, 1] give the
        same separation).
    iterations : int
        L-BFGS iterations.
    init : {'crop', 'frame'}
        The paper's ``n1 = D^T`` of the registered crop, or the unseparated frame (an ablation).

    Returns
    -------
    Reconstruction
        ``info``: ``registration``, ``alpha_assumed``, ``iterations``, ``loss_history``, ``foveal_rms``.
    """
    from scipy.optimize import minimize

    tm = Timings()
    y = _as_frame(frame)
    dt = image_dtype(y)
    yd = y.astype(np.float64)
    H, W = y.shape
    a = 0.5 if alpha is None else as_float("alpha", alpha)
    if not 0.0 < a < 1.0:
        raise InputError("alpha", alpha, "0 < alpha < 1 (both channels must be present in a snapshot)")
    iterations = check_int("iterations", iterations, 1, 100000)
    init = check_choice("init", init, INITS)
    info: dict[str, Any] = {"alpha_assumed": alpha is None, "init": init}
    with tm.measure("register"):
        if offset is not None:
            op = FovealOperator((H, W), scale, offset, gain=foveal_gain, bias=foveal_offset)
            info["registration"] = {"offset": list(op.offset), "scale": op.scale, "given": True}
        elif register_frame:
            FovealOperator((H, W), scale, gain=foveal_gain, bias=foveal_offset)  # validate before registering
            reg = register(yd, scale=scale)
            op = FovealOperator((H, W), reg["scale"], reg["offset"], low=reg["low_shape"], gain=foveal_gain,
                                bias=foveal_offset)
            info["registration"] = reg
        else:
            op = FovealOperator((H, W), scale, gain=foveal_gain, bias=foveal_offset)
            info["registration"] = {"offset": [0.0, 0.0], "scale": op.scale, "given": False}
    with tm.measure("separate"):
        # work on the frame normalised to zero mean and unit range (scale invariance: the weights and
        # L-BFGS's absolute tolerances then mean the same for frames in DN and in [0, 1]);
        # x = ym + span xn turns D x1 = g C x2 + bias into D x1n = g C x2n + (bias + (g - 1) ym) / span
        op_raw = op
        ym = float(yd.mean())
        span = float(np.ptp(yd)) or 1.0
        yd = (yd - ym) / span
        op = FovealOperator((H, W), op_raw.scale, op_raw.offset, low=op_raw.low_shape, gain=op_raw.gain,
                            bias=(op_raw.bias + (op_raw.gain - 1.0) * ym) / span)
        # paper's initialisation: n1 = D^T (registered crop of y), normalised; n2 = (y - a n1) / (1 - a)
        cy = op.C(yd)
        b = 1.0 - a
        # AC: the crop holds (1 - a) C x2 = (1 - a) (D x1 - bias) / gain; DC: the level at which the mean
        # foveal misfit vanishes given x2 = (y - a x1) / (1 - a)
        u = op.gain * op.upsample(cy)
        u = u - u.mean()
        lvl = float(np.mean(op.gain * op.C((yd - a * u) / b) + op.bias - op.D(u))) / (1.0 + op.gain * a / b)
        # the paper's level (the frame mean) when the constraint is the identity (measured: +0.6 dB on
        # the 96 x 96 test scene over the constraint-consistent level, which a gain/offset needs)
        n1 = u + (float(yd.mean()) if (op_raw.gain == 1.0 and op_raw.bias == 0.0) else lvl)
        if init == "frame":  # no initialisation: start from the unseparated frame (x1 = x2 = y)
            n1 = yd.copy()
        gy, gx = grad2d(yd)
        g0 = float(np.mean(np.abs(gy)) + np.mean(np.abs(gx))) / 2
        g0 = g0 if g0 > 0 else 1e-6 * max(float(np.abs(yd).max()), 1e-300)
        eps = 0.1 * g0
        m = op.low_shape[0] * op.low_shape[1]
        mu = as_float("foveal_weight", foveal_weight)
        lt = as_float("tv_weight", tv_weight)
        le = as_float("exclusion_weight", exclusion_weight)
        hist: list[float] = []

        def fg(v: np.ndarray) -> tuple[float, np.ndarray]:
            x1 = v.reshape(H, W)
            x2 = (yd - a * x1) / b
            r = op.residual(x1, x2)
            f = mu * float(np.sum(r * r)) / m
            g1 = mu * 2 * op.DT(r) / m
            g2 = -mu * 2 * op.gain * op.CT(r) / m
            t1, tg1 = mean_charbonnier_tv(x1, eps)
            t2, tg2 = mean_charbonnier_tv(x2, eps)
            e, eg1, eg2 = exclusion_loss(x1, x2, g0)
            f += lt * (t1 + t2) / g0 + le * e
            g1 = g1 + lt * tg1 / g0 + le * eg1
            g2 = g2 + lt * tg2 / g0 + le * eg2
            # chain rule through x2 = (y - a x1) / b
            g = g1 - (a / b) * g2
            hist.append(f)
            return f, g.ravel()

        r = minimize(fg, n1.ravel(), jac=True, method="L-BFGS-B", options={"maxiter": iterations})
        yd = y.astype(np.float64)
        x1 = ym + span * r.x.reshape(H, W)
        x2 = (yd - a * x1) / b
        op = op_raw
    info.update(foveal_gain=op.gain, foveal_offset=op.bias, iterations=int(r.nit),
                loss_history=hist[:: max(1, len(hist) // 100)],
                foveal_rms=float(np.sqrt(np.mean(op.residual(x1, x2) ** 2))))
    return Reconstruction(x1=x1.astype(dt), x2=x2.astype(dt), alpha=np.array([a]), fpn=None, method="snapshot",
                          timings=dict(tm), info=info)

"""Snapshot (single-frame) recovery: registration of the two channels, then separation.

In one frame ``y = a x1 + (1 - a) x2`` the foveal image ``x1`` appears twice: at full size, and
``scale`` times smaller in the centre of ``x2`` (``D x1 = g C x2 + o``, gain ``g`` and offset ``o`` the channels'
radiometry). So the downsampled frame ``D y`` (containing ``a D x1``) and the frame's centre ``C y`` (containing
``(1 - a) C x2``) share content.

Registration (:func:`register`): where in the frame's centre the foveal content sits.
1. The whitened normalised cross-correlation (NCC of the two images' gradients, both directions averaged: a scene
   whose amplitude spectrum falls as 1/f has a flat gradient spectrum, so the statistic is not ruled by the few
   large structures every smooth image shares) of ``D y`` against every crop of ``y`` shifted by whole pixels, over
   half the constraint's size either way (scikit-image ``match_template``).
2. A test: the map's median and spread (1.4826 x its median absolute deviation: nearly every shift in it is a wrong
   one) are the statistic's null distribution; the peak within :data:`REGISTER_SEARCH_PX` of the nominal crop is
   significant when it exceeds the median by ``z`` spreads, ``z`` the normal quantile of
   :data:`REGISTER_FALSE_ALARM` over the number of shifts tried (Bonferroni). The nominal geometry is left only when
   the peak is significant and beats the nominal crop's own value by that margin too; then its offset is refined to
   a sub-pixel one by a parabola through the peak and its neighbours. Otherwise the stated geometry is kept and
   the result says why (``identified``, ``moved``, ``reason``). In one mixed frame of the paper's camera the foveal
   channel's contrast is often a few percent of the perifoveal one's (haze, the larger f-number, a fovea of 1/36 of
   the field): its content is then not identifiable and the stated geometry is the better guess. The scale is kept
   unless asked (``refine_scale``); no rotation is modelled.

Separation (:func:`snapshot`), ``separation='constraint'`` (default). One frame holds half the information of two
images: the constraint fixes only ``x1``'s low frequencies (``1/scale`` of its band), and nothing in one frame
tells the rest of ``x1`` from ``x2``. So ``x1`` is the constraint's low-pass and ``x2`` the rest:

1. ``u = D x1`` from the constraint with ``x2 = (y - a x1) / (1 - a)`` and ``x1 = U u``: the linear system
   ``(I + (a g / b) C U) u = (g / b) C y + o`` (``b = 1 - a``; GMRES), ``U`` the cubic spline through the boxes'
   centres, back-projected so that ``D U u = u``;
2. ``u`` Wiener-filtered (:func:`wiener_lowpass`): its noise is ``C y``'s through the constraint, ``g sigma / b``
   per pixel (``sigma`` the frame's noise, estimated from the frame, :func:`~metafovea.reconstruct._common.
   estimate_noise`), its signal spectrum the image's own periodogram less that noise: the gain ``S / (S + N)`` is
   computed from the data, with no weight to choose;
3. ``x1 = U u``, ``x2 = (y - a x1) / b``, then TV-denoised with its noise ``sigma / b``
   (:func:`~metafovea.reconstruct.denoise.denoise`, whose weight follows the noise and is checked by SURE).

``separation='paper'``: the paper's loss. ``x2`` is eliminated through the data term (``x2 = (y - a x1) / (1 - a)``)
and ``x1`` minimises

    mu ||D x1 - C x2||^2 + lam_tv (TV(x1) + TV(x2)) + lam_ex * exclusion(x1, x2)

(L-BFGS), where the exclusion loss ([1]_, used by the paper) is the squared Frobenius norm of ``tanh(|grad x1| / g0)
* tanh(|grad x2| / g0)`` at two scales, penalising edges present in both images. Initialisation as in the paper:
``n1`` = the registered centre crop of ``y`` spread back onto the full grid (``D^T``, normalised), ``n2 = (y - a n1)
/ (1 - a)``; ``init='frame'`` starts from the unseparated frame instead (``n1 = n2 = y``), the ablation of that
initialisation (``metafovea study ablation``). Weights: foveal 1, TV 0.01, exclusion 0.001, with TV normalised by
the frame's mean gradient: the best of a small grid on the 96 x 96 synthetic pair of photographs at noise 0.01
(:func:`~metafovea.reconstruct.synthetic.scene`), not on the camera's scenes. With the data term held exactly, every
bit of noise the TV removes from one image goes to the other: on the camera's frames, whose foveal contrast is a
few DN, it lands in ``x1``. The default separation beats it on the generator's tuning scenes and on that synthetic
pair too (``benchmarks/bench_snapshot.py --separation paper`` compares them); it is kept for the paper's ablation.

Constants: :data:`REGISTER_SEARCH_PX` (the lenses' alignment; the calibration's own search),
:data:`REGISTER_FALSE_ALARM` (a stated test level), :data:`REGISTER_SCALE_STEPS` (the optional scale search's grid),
:data:`GMRES_RESTART`, :data:`GMRES_MAXITER`, :data:`BACKPROJECT_ITERATIONS` (numerical: each says what it
reaches); the paper's weights above (from its synthetic scene, used only by ``separation='paper'``). None is tuned
to a generator scene, test or tuning.

``info`` reports the foveal misfit and, for the registration, the test's figures; the residual overlap (the
correlation of the foveal error with the perifoveal image) is measured by :mod:`metafovea.studies.snapshot_heldout`.

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

#: :func:`snapshot`'s separations (Separation, module docstring): the foveal constraint's (default), the paper's loss
SEPARATIONS = ("constraint", "paper")
#: starts of the paper's separation: its ``n1 = D^T y`` (registered crop), or the unseparated frame
INITS = ("crop", "frame")
#: the constraint's linear solve (GMRES): restart length and restarts; its matrix is ``I + (a g / b) C U``, within
#: ``a g / b`` of the identity, so a few iterations reach the tolerance (1e-10 relative)
GMRES_RESTART = 20
GMRES_MAXITER = 20
#: back-projections of the cubic interpolation of ``D x1`` (:class:`_Interpolator`): each divides the misfit
#: ``u - D U u`` by about 10 (measured), three leave it far below the constraint's noise
BACKPROJECT_ITERATIONS = 3
#: the largest crop offset :func:`register` searches (x2 pixels either way): the two lenses share one axis to within
#: a few pixels (the multi-frame calibration's coarse search, ``COARSE_SHIFT_PX`` of
#: :mod:`~metafovea.reconstruct.calibrate`, is the same); a wider search only adds chances of a false peak
REGISTER_SEARCH_PX = 5
#: the probability that :func:`register` accepts a crop in a frame without foveal content (over the whole search)
REGISTER_FALSE_ALARM = 0.01
#: scales :func:`register` tries either side of the nominal one (steps of ``max_scale_change / 2``: 1.5 %, which
#: moves the constraint's edge by a third of a pixel at 48 x 48)
REGISTER_SCALE_STEPS = 2


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


def _grad_pair(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forward differences of ``z`` along y and x, both ``(H - 1, W - 1)`` and anchored at the same pixel: the
    whitening of :func:`register` (a scene whose amplitude spectrum falls as 1/f has a flat gradient spectrum)."""
    return z[1:, :-1] - z[:-1, :-1], z[:-1, 1:] - z[:-1, :-1]


def _parabola_peak(vm: float, v0: float, vp: float) -> float:
    """The offset in (-0.5, 0.5) of the vertex of the parabola through (-1, vm), (0, v0), (1, vp) (0 if not a
    maximum)."""
    den = vm - 2.0 * v0 + vp
    return float(np.clip(0.5 * (vm - vp) / den, -0.5, 0.5)) if den < 0 else 0.0


def _rises_beyond(mp: np.ndarray, iy: int, ix: int, centre: tuple[int, int], search: int) -> bool:
    """Whether the peak ``(iy, ix)`` of map ``mp``, found within ``+-search`` of ``centre``, has a higher neighbour
    outside that window: then it is no located maximum (a false peak on a slope, or a crop further away than
    searched)."""
    oy, ox = centre
    return any(mp[iy + dy, ix + dx] > mp[iy, ix] for dy in (-1, 0, 1) for dx in (-1, 0, 1)
               if (abs(iy + dy - oy) > search or abs(ix + dx - ox) > search)
               and 0 <= iy + dy < mp.shape[0] and 0 <= ix + dx < mp.shape[1])


def register(frame: ArrayLike, *, scale: float = 6.0, search: int | None = None, refine: bool = True,
             refine_scale: bool = False, max_scale_change: float = 0.03,
             false_alarm: float = REGISTER_FALSE_ALARM) -> dict[str, Any]:
    """Locate the foveal content in the frame's centre (Registration, module docstring).

    Parameters
    ----------
    frame : array_like, shape (H, W)
        One finite frame.
    scale : float
        The nominal scale f1 / f2.
    search : int, optional
        The largest integer shift (x2 pixels) searched, either way: default :data:`REGISTER_SEARCH_PX` (at most
        what the frame allows).
    refine : bool
        Sub-pixel offset of an identified crop: the vertex of a parabola through the whitened NCC at the peak and
        its neighbours.
    refine_scale : bool
        Search the scale too, on :data:`REGISTER_SCALE_STEPS` steps either way up to ``max_scale_change``, and
        refine it by a parabola through the peaks. Off by default: in one mixed frame of the simulated camera (tuning
        scenes) the whitened NCC prefers the smoother template of a scale off the grid of whole pixels, so the scale
        found is biased towards the range's ends; the stated scale is better kept.
    max_scale_change : float
        The scale's search range, relative, around the nominal one.
    false_alarm : float
        The test's probability of accepting a crop in a frame without foveal content, over the whole search.

    Returns
    -------
    dict
        ``identified`` (the test passed; else the nominal geometry is returned and ``reason`` says why),
        ``moved`` (the peak beats the nominal geometry by the same margin and is a maximum of the correlation, not
        the edge of a slope that rises beyond the search, ``peak_on_edge``: only then is the geometry found
        returned),
        ``offset`` ``(dy, dx)``, ``scale``, ``rotation_deg`` (0: the constraint has no rotation, none is
        estimated), ``ncc`` (intensity NCC of ``D y`` and ``C y`` at the returned geometry), ``low_shape``; the
        test's ``z`` (the whitened NCC's peak over its null spread), ``z_critical``, ``null_sd``, ``tests`` (shifts
        x scales searched), ``search``; ``offset_ncc`` and ``ncc_coarse``: the integer peak and its whitened NCC.
    """
    from scipy.stats import norm
    from skimage.feature import match_template

    y = _as_frame(frame).astype(np.float64)
    H, W = y.shape
    op0 = FovealOperator((H, W), scale)
    h, w = op0.low_shape
    lim = max(0, min((H - h) // 2, (W - w) // 2))
    search = min(check_int("search", REGISTER_SEARCH_PX if search is None else search, 0, 100000), lim)
    false_alarm = as_float("false_alarm", false_alarm)
    if not 0.0 < false_alarm < 1.0:
        raise InputError("false_alarm", false_alarm, "a probability in (0, 1)")
    dscale = as_float("max_scale_change", max_scale_change)
    steps = REGISTER_SCALE_STEPS if refine_scale and dscale > 0 else 0
    scales = [op0.scale * (1.0 + dscale * k / max(steps, 1)) for k in range(-steps, steps + 1)]
    # the whitened NCC over a wide region (half the constraint either way): its spread at the nominal scale is the
    # statistic's null distribution (nearly every shift there is a wrong one); the peak is taken within +-search
    wide = max(search, min(max(2, min(h, w) // 2), lim))
    y0, x0 = (H - h) // 2, (W - w) // 2
    sy0, sy1 = max(0, y0 - wide), min(H, y0 + h + wide)
    sx0, sx1 = max(0, x0 - wide), min(W, x0 + w + wide)
    region = _grad_pair(y[sy0:sy1, sx0:sx1])
    oy, ox = y0 - sy0, x0 - sx0  # the nominal crop's index in the maps
    ly, lx = max(0, oy - search), max(0, ox - search)
    maps, peaks = [], []
    for s in scales:
        tmpl = FovealOperator((H, W), s, low=(h, w)).D(y)
        mp = 0.5 * sum(match_template(r, t) for r, t in zip(region, _grad_pair(tmpl)))
        local = mp[ly:oy + search + 1, lx:ox + search + 1]
        iy, ix = np.unravel_index(int(np.argmax(local)), local.shape)
        maps.append(mp)
        peaks.append((float(local[iy, ix]), iy + ly, ix + lx))
    null_map = maps[steps]
    med = float(np.median(null_map))
    null_sd = 1.4826 * float(np.median(np.abs(null_map - med)))
    k = int(np.argmax([p[0] for p in peaks]))
    peak, iy, ix = peaks[k]
    tests = (min(oy + search, null_map.shape[0] - 1) - ly + 1) * (min(ox + search, null_map.shape[1] - 1) - lx + 1)
    tests *= len(scales)
    z = (peak - med) / null_sd if null_sd > 0 else 0.0
    z_crit = float(norm.isf(false_alarm / tests))
    # offset of the crop relative to the centred crop (FovealOperator's convention)
    c_y = H / 2.0 - h / 2.0
    c_x = W / 2.0 - w / 2.0
    off = (float(sy0 + iy - c_y), float(sx0 + ix - c_x))
    # the nominal geometry is left only for a peak that beats it by the test's margin too
    z_move = (peak - float(null_map[oy, ox])) / null_sd if null_sd > 0 else 0.0
    edge = _rises_beyond(maps[k], iy, ix, (oy, ox), search)
    res: dict[str, Any] = {"offset_ncc": off, "ncc_coarse": peak, "z": z, "z_move": z_move, "z_critical": z_crit,
                           "null_sd": null_sd, "tests": tests, "search": search, "identified": bool(z >= z_crit),
                           "moved": bool(z >= z_crit and z_move >= z_crit and not edge), "peak_on_edge": bool(edge)}
    best: dict[str, Any] = {"offset": (0.0, 0.0), "scale": float(op0.scale), "rotation_deg": 0.0}
    if not res["identified"]:
        res["reason"] = (f"no significant foveal content in the frame (whitened NCC peak z = {z:.2f} < {z_crit:.2f}, "
                         f"false-alarm probability {false_alarm:g} over {tests} shifts and scales): the nominal "
                         "geometry is kept")
    elif edge and z_move >= z_crit:  # significant, but the correlation rises beyond the search
        res["reason"] = (f"the peak lies on the search's edge ({search} x2 pixels from the nominal crop) and the "
                         "correlation rises beyond it: no located maximum, the nominal geometry is kept (a larger "
                         "search if the lenses' axes may be further apart)")
    elif not res["moved"]:
        res["reason"] = (f"the peak does not beat the nominal geometry significantly (by {z_move:.2f} null spreads < "
                         f"{z_crit:.2f}): the nominal geometry is kept")
    else:
        mp = maps[k]
        if refine:  # sub-pixel: the parabola's vertex along each axis (a shift at the map's edge stays whole)
            if 0 < iy < mp.shape[0] - 1:
                off = (off[0] + _parabola_peak(mp[iy - 1, ix], mp[iy, ix], mp[iy + 1, ix]), off[1])
            if 0 < ix < mp.shape[1] - 1:
                off = (off[0], off[1] + _parabola_peak(mp[iy, ix - 1], mp[iy, ix], mp[iy, ix + 1]))
        s_best = scales[k]
        if 0 < k < len(scales) - 1:
            s_best += _parabola_peak(peaks[k - 1][0], peak, peaks[k + 1][0]) * (scales[1] - scales[0])
        off = tuple(float(np.clip(o, -(n - m) / 2.0, (n - m) / 2.0)) for o, n, m in ((off[0], H, h), (off[1], W, w)))
        best.update(offset=off, scale=float(s_best))
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
             foveal_gain: float = 1.0, foveal_offset: float = 0.0, separation: str = "constraint",
             noise_sigma: float | None = None, denoise: bool = True,
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
    separation : {'constraint', 'paper'}
        :data:`SEPARATIONS`: the foveal constraint's low-pass for ``x1`` and the frame's rest for ``x2``
        (default), or the paper's loss (Separation, module docstring).
    noise_sigma : float, optional
        ``'constraint'``: the frame's temporal noise std (frame units); default estimated from the frame
        (:func:`~metafovea.reconstruct._common.estimate_noise`).
    denoise : bool
        ``'constraint'``: TV-denoise ``x2`` (:func:`~metafovea.reconstruct.denoise.denoise`, its noise
        ``noise_sigma / (1 - alpha)``); False keeps ``a x1 + (1 - a) x2 = y`` exactly.
    foveal_weight, tv_weight, exclusion_weight : float
        ``'paper'``: ``mu``, ``lam_tv``, ``lam_ex``, relative to the frame's own contrast (frames in DN and in
        [0, 1] give the same separation).
    iterations : int
        ``'paper'``: L-BFGS iterations.
    init : {'crop', 'frame'}
        ``'paper'``: the paper's ``n1 = D^T`` of the registered crop, or the unseparated frame (an ablation).

    Returns
    -------
    Reconstruction
        ``info``: ``registration``, ``alpha_assumed``, ``separation``, ``foveal_rms``; ``'constraint'``:
        ``noise_sigma``, ``constraint_noise`` (the noise std of ``D x1`` as the constraint gives it),
        ``x2_denoised``; ``'paper'``: ``init``, ``iterations``, ``loss_history``.
    """
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
    separation = check_choice("separation", separation, SEPARATIONS)
    if noise_sigma is not None and not as_float("noise_sigma", noise_sigma) >= 0:
        raise InputError("noise_sigma", noise_sigma, "a noise std >= 0 in the frame's units")
    info: dict[str, Any] = {"alpha_assumed": alpha is None, "separation": separation}
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
        if separation == "paper":
            x1, x2, sinfo = _separate_paper(y, a, op, foveal_weight=foveal_weight, tv_weight=tv_weight,
                                            exclusion_weight=exclusion_weight, iterations=iterations, init=init)
        else:
            x1, x2, sinfo = _separate_constraint(y, a, op, noise_sigma, denoise)
    info.update(sinfo, foveal_gain=op.gain, foveal_offset=op.bias,
                foveal_rms=float(np.sqrt(np.mean(op.residual(x1, x2) ** 2))))
    return Reconstruction(x1=x1.astype(dt), x2=x2.astype(dt), alpha=np.array([a]), fpn=None, method="snapshot",
                          timings=dict(tm), info=info)


class _Interpolator:
    """``U``: a constraint image ``(h, w)`` to the frame's grid ``(H, W)`` by cubic splines through the boxes'
    centres, back-projected (:data:`BACKPROJECT_ITERATIONS`) so that ``D U u`` is ``u``: a smooth ``x1`` whose
    down-sampling is the constraint's. Linear in ``u``."""

    def __init__(self, op: FovealOperator):
        from scipy.ndimage import map_coordinates

        self.op = op
        mats = []
        for n, m in zip(op.shape, op.low_shape):
            # frame pixel centre i + 1/2 in constraint coordinates (box k spans [n/2 + (k - m/2) s, ... + s))
            c = (np.arange(n) + 0.5 - n / 2.0) / op.scale + m / 2.0 - 0.5
            eye = np.eye(m)
            mats.append(np.stack([map_coordinates(eye[j], [c], order=3, mode="nearest") for j in range(m)], axis=1))
        self.my, self.mx = mats  # (H, h), (W, w): the cubic spline is separable

    def _spline(self, u: np.ndarray) -> np.ndarray:
        return self.my @ u @ self.mx.T

    def __call__(self, u: np.ndarray) -> np.ndarray:
        x = self._spline(u)
        for _ in range(BACKPROJECT_ITERATIONS):
            x = x + self._spline(u - self.op.D(x))
        return x


def wiener_lowpass(u: ArrayLike, noise_std: float) -> np.ndarray:
    """The Wiener estimate of an image seen in white noise, its signal spectrum from the image itself.

    Parameters
    ----------
    u : array_like, shape (h, w)
    noise_std : float
        The white noise's std per pixel.

    Returns
    -------
    ndarray, shape (h, w)
        ``mean + F^-1 [ max(0, 1 - N / P(|f|)) F(u - mean) ]`` on the image mirrored to twice its size (no
        wrap-around edges), ``P`` the periodogram averaged over rings of ``|f|`` (one per frequency step) and ``N``
        the noise's flat periodogram level ``noise_std^2``.

    Notes
    -----
    The Wiener gain ``S / (S + N)`` with ``S = P - N`` the signal's power: no constant beyond the noise level,
    which the caller knows (the frame's noise through the constraint).
    """
    u = np.asarray(u, dtype=np.float64)
    h, w = u.shape
    mu = float(u.mean())
    z = np.pad(u - mu, ((0, h), (0, w)), mode="symmetric")
    f = np.fft.fft2(z)
    p = np.abs(f) ** 2 / z.size
    r = np.hypot(np.fft.fftfreq(z.shape[0])[:, None], np.fft.fftfreq(z.shape[1])[None, :])
    step = 1.0 / max(z.shape)
    ring = np.minimum((r / step).astype(int), int(r.max() / step))
    n = ring.max() + 1
    pr = np.bincount(ring.ravel(), p.ravel(), n) / np.maximum(np.bincount(ring.ravel(), None, n), 1)
    gain = np.clip(1.0 - float(noise_std) ** 2 / np.maximum(pr[ring], 1e-300), 0.0, 1.0)
    gain.flat[0] = 1.0
    return mu + np.real(np.fft.ifft2(f * gain))[:h, :w]


def _separate_paper(y: np.ndarray, a: float, op: FovealOperator, *, foveal_weight: float, tv_weight: float,
                    exclusion_weight: float, iterations: int, init: str
                    ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """The paper's separation (Separation, 'paper'): ``(x1, x2, info)``, float64."""
    from scipy.optimize import minimize

    H, W = y.shape
    yd = y.astype(np.float64)
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
    yd = y.astype(np.float64)
    x1 = ym + span * r.x.reshape(H, W)
    x2 = (yd - a * x1) / b
    return x1, x2, {"iterations": int(r.nit), "loss_history": hist[:: max(1, len(hist) // 100)], "init": init}


def _separate_constraint(y: np.ndarray, a: float, op: FovealOperator, sigma: float | None, denoise_x2: bool
                         ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """The constraint's separation (Separation, 'constraint'): ``(x1, x2, info)``, float64."""
    from scipy.sparse.linalg import LinearOperator, gmres

    from metafovea.reconstruct._common import estimate_noise
    from metafovea.reconstruct.denoise import denoise

    yd = y.astype(np.float64)
    b = 1.0 - a
    sig = estimate_noise(yd) if sigma is None else as_float("noise_sigma", sigma)
    h, w = op.low_shape
    up = _Interpolator(op)
    k = a * op.gain / b

    def mv(v: np.ndarray) -> np.ndarray:
        u = v.reshape(h, w)
        return (u + k * op.C(up(u))).ravel()

    # u = D x1 with x2 = (y - a x1) / b and x1 = U u:  (I + (a g / b) C U) u = (g / b) C y + o
    rhs = (op.gain / b) * op.C(yd) + op.bias
    u, _ = gmres(LinearOperator((h * w, h * w), matvec=mv, dtype=np.float64), rhs.ravel(), x0=rhs.ravel(),
                 rtol=1e-10, atol=0.0, restart=GMRES_RESTART, maxiter=GMRES_MAXITER)
    u = u.reshape(h, w)
    noise_u = op.gain * sig / b  # the noise of u: C y's, through the constraint
    uw = wiener_lowpass(u, noise_u)
    x1 = up(uw)
    x2 = (yd - a * x1) / b
    info: dict[str, Any] = {"noise_sigma": sig, "constraint_noise": noise_u}
    if denoise_x2 and sig > 0:
        x2 = np.asarray(denoise(x2, "tv", sigma=sig / b), dtype=np.float64)
        info["x2_denoised"] = "tv"
    return x1, x2, info

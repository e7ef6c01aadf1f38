"""What a real camera gets wrong, calibrated from its recording: the foveal geometry, the channels' gain ratio and
the polariser's effective amplitude.

Model
-----
Once the polariser model has fixed alpha's mean (1/2, whatever the extinction, lag and phase:
:mod:`metafovea.polarizer`), the separated images are known up to one number, the ratio ``rho = s / s_0`` of the
true amplitude of alpha to the one the stated device constants give (a polariser that leaks more, or a slower
bolometer, than the file says):

    x1 = m + u d_0 / 2,   x2 = m - u d_0 / 2,   u = 1 / rho,                                          (1)

``m`` the mean image (exact: the frames' average over the rotation) and ``d_0`` the difference image in the stated
gauge. The foveal constraint ties the two: the foveal image, scaled down by ``scale``, turned back by ``rotation``
and centred on the foveal centre ``c``, is the centre of the perifoveal one up to the channels' gain ratio ``g`` and
an offset ``o``:

    G_1 x1(c_s + scale R(-phi) (p - c_s - c)) = g G_2 x2(p) + o                                        (2)

for the perifoveal pixels ``p`` of the fovea (``(row, column)`` vectors, ``c_s`` the sensor's centre,
``R(phi) = [[cos, -sin], [sin, cos]]``), in the geometry convention of docs/measurement_format.md ("The foveal
geometry"): ``c`` in perifoveal pixels from the sensor's centre (the point of the perifoveal image that the foveal
image's centre shows), ``phi = rotation_deg`` positive from ``+x`` (columns) towards ``+y`` (rows); the
reconstruction's :class:`~metafovea.reconstruct.operators.FovealOperator` takes the same ``(scale, c, phi)`` as its
``(scale, offset, rotation_deg)``. The gain ``g + h r^2`` varies with the
foveal sample's radius on the sensor (vignetting: the foveal image samples the whole sensor, the perifoveal one only
its centre).
Both sides are low-passed by a common Gaussian (``G_2``: ``blur_px`` perifoveal pixels; ``G_1``: the same in foveal
pixels, with the pixel box of the down-scaling), so that the channels' different PSFs matter little; with the
channels' PSFs each side is also blurred by the other's. What PSF difference is left (in perifoveal pixels the F/1
perifoveal lens blurs several times more than the F/2 foveal lens seen 6x reduced; PSFs the file does not give, a
defocus) still biases the fit, the amplitude most: a relative blur ``b_r`` is fitted too, a Gaussian of ``b_r``
perifoveal pixels added to the foveal side (``b_r > 0``) or to the perifoveal side (``b_r < 0``), the one that
explains (2) best at the fitted geometry, and the relation is fitted again with it. (2) is solved for the eight
parameters ``(scale, c_y, c_x, phi, u, g, o, h)`` by non-linear least squares (:func:`fit_foveal`), started from the
stated constraint, where it is linear in ``(g, o, h)`` at each ``u`` (a 1-D search gives the start).

Uncertainty: the Gauss-Newton covariance ``s_r^2 (J^T J)^-1`` of the fit, inflated by the residual's correlation area
(the low-pass makes neighbouring samples share their error: ``4 pi blur_px^2`` samples count as one). A parameter is
*identified* when its standard error is below its tolerance (:data:`TOLERANCES`); a fovea without texture leaves the
geometry and ``u`` unidentified, and the caller keeps the stated values and says so.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.errors import InputError

#: Gaussian low-pass of both sides of (2), in perifoveal pixels: the channels' PSFs (foveal F/2 at 6x, perifoveal
#: F/1, chromatic haze) differ below this scale
BLUR_PX = 1.5
#: perifoveal pixels left out at the fovea's border (the low-pass and the geometry's search reach that far)
MARGIN_PX = 3
#: how far the geometry is searched from the stated one: relative scale, centre (perifoveal pixels), rotation (degrees)
SEARCH = {"scale": 0.06, "centre_px": 6.0, "rotation_deg": 2.0}
#: the drop of chi^2 (4 geometry parameters) above which the fitted geometry replaces the stated one (p < 1e-4)
GEOMETRY_CHI2 = 23.5
#: the largest relative standard error of the scale with which the fitted geometry is used
GEOMETRY_SE_MAX = 0.01
#: the coarse search of the centre: whole perifoveal pixels either way
COARSE_SHIFT_PX = 5
#: the amplitude's model error per unit of the fit's relative misfit (residual rms over the perifoveal side's
#: contrast): where the relation (2) does not hold (haze from outside the fovea, PSFs unknown) the amplitude is
#: biased by up to this times that misfit (set on the simulator's paper camera, three scenes, 8-14 um and the 10 um
#: filter, stated constants right: bias / misfit <= 0.027 without the radial gain); a departure from the stated
#: amplitude within it is not taken as evidence against them (BENCHMARKS.md, "Real recordings": no false alarm)
AMPLITUDE_MODEL_ERROR = 0.03
#: and never less than this: a fit that explains the fovea closely still rests on the PSFs given (small hot sources
#: seen through unstated PSFs: 0.4 % off at a misfit of 0.017, independent camera model), and an amplitude left
#: this far off costs alpha at most 2/pi x 1/2 x 0.005 = 1.6e-3 mean absolute error
AMPLITUDE_FLOOR = 0.005
#: the largest relative blur of the two sides searched (perifoveal pixels): several times the F/1 lens' Airy core
#: (0.42 lambda N = 0.25-0.35 px over 8-14 um at 17 um pixels), room for a defocus or haze
RELATIVE_BLUR_MAX = 2.0
#: the swapped channels are the recording's when their relation's misfit is below this share of the other's
SWAP_RATIO = 0.8
#: blocks per axis of the fovea for the amplitude's jackknife error
JACKKNIFE_BLOCKS = 3
#: the standard error under which a fitted quantity counts as identified (scale: relative; centre: perifoveal
#: pixels)
TOLERANCES = {"scale": 0.005, "centre_px": 0.3, "rotation_deg": 0.1, "amplitude": 0.004, "gain": 0.01}


@dataclass(frozen=True)
class FovealFit:
    """The calibrated foveal relation (2) and the amplitude ratio (1), with standard errors.

    Attributes
    ----------
    scale : float
        f1 / f2 as the recording shows it.
    centre_px : tuple of 2 float
        The foveal centre ``(dy, dx)``: the point of the perifoveal image that the foveal image's centre shows,
        perifoveal pixels from the sensor's centre ``((H - 1) / 2, (W - 1) / 2)`` (docs/measurement_format.md, "The
        foveal geometry"; the ``offset`` of :class:`~metafovea.reconstruct.operators.FovealOperator`).
    rotation_deg : float
        The foveal image's rotation against the perifoveal one, degrees, positive from ``+x`` (columns) towards
        ``+y`` (rows): a scene point ``q`` lands in the foveal image at ``scale R(-rotation) (q - centre)``.
    amplitude : float
        ``rho``: the true amplitude of alpha over the stated one.
    gain, offset : float
        ``g`` and ``o`` of (2) (the frames' units).
    vignetting : float
        ``-h / g``: the relative loss of the foveal side at the sensor's corner against its centre (the relation's
        gain ``g + h r^2``, ``r`` 1 at the corner): the sensor's vignetting, which the foveal image samples over the
        whole sensor and the perifoveal one only at its centre.
    se : dict
        Standard errors of ``scale``, ``centre_px`` (the larger axis), ``rotation_deg``, ``amplitude``, ``gain``.
    residual_rms : float
        Of (2), in the frames' units.
    identified : dict
        Per quantity: its standard error is within :data:`TOLERANCES`.
    samples : int
        Constraint samples used.
    relative_misfit : float
        ``residual_rms`` over the perifoveal side's contrast (times the gain): how far (2) is from holding.
    geometry_fit : dict
        The fit with the geometry free (scale, centre, rotation, amplitude, their errors, its residual and the
        stated geometry's, the chi^2 drop), whether or not it was kept.
    relative_blur_px : float
        The Gaussian blur (perifoveal pixels) added to the foveal side (> 0) or to the perifoveal side (< 0) that
        explains (2) best: the channels' PSF difference the sides' common low-pass leaves.
    """

    scale: float
    centre_px: tuple[float, float]
    rotation_deg: float
    amplitude: float
    gain: float
    offset: float
    vignetting: float = 0.0
    se: dict[str, float] = field(default_factory=dict)
    residual_rms: float = math.nan
    identified: dict[str, bool] = field(default_factory=dict)
    samples: int = 0
    relative_misfit: float = math.nan
    geometry_fit: dict[str, Any] = field(default_factory=dict)
    relative_blur_px: float = 0.0

    def summary(self) -> dict[str, Any]:
        """JSON-ready: every field."""
        return {"scale": self.scale, "centre_px": list(self.centre_px), "rotation_deg": self.rotation_deg,
                "amplitude": self.amplitude, "gain": self.gain, "offset": self.offset, "vignetting": self.vignetting,
                "se": dict(self.se), "residual_rms": self.residual_rms, "relative_misfit": self.relative_misfit,
                "identified": dict(self.identified), "samples": self.samples, "geometry_fit": dict(self.geometry_fit),
                "relative_blur_px": self.relative_blur_px}


def _rescaled_psf(psf: np.ndarray, zoom: float) -> np.ndarray:
    """A pixel-grid PSF on a grid ``zoom`` times finer (``zoom`` < 1: coarser), odd-sized, centred, sum 1."""
    from scipy.ndimage import map_coordinates

    k = np.asarray(psf, dtype=np.float64)
    r_in = (k.shape[0] - 1) / 2.0
    r = max(int(math.ceil(r_in * zoom)), 0)
    # the PSF's value at a new pixel: the old kernel's area-weighted average there (linear interpolation of the
    # cumulative kernel would be exact; a finely supersampled bilinear read is close and simple)
    sub = max(1, int(math.ceil(3 / zoom))) if zoom < 1 else 1
    off = (np.arange(sub) + 0.5) / sub - 0.5
    g = np.arange(-r, r + 1, dtype=np.float64)
    pts = (g[:, None] + off[None, :]).ravel() / zoom + r_in
    Y, X = np.meshgrid(pts, pts, indexing="ij")
    v = map_coordinates(k, [Y, X], order=1, mode="constant", cval=0.0)
    v = v.reshape(2 * r + 1, sub, 2 * r + 1, sub).mean(axis=(1, 3))
    tot = v.sum()
    return v / tot if tot > 0 else np.ones((1, 1))


def _cropped(psf: np.ndarray, radius: int) -> np.ndarray:
    """A centred PSF cut to ``radius`` pixels: beyond the image's size a kernel only adds a level, which the
    relation's offset takes."""
    k = np.asarray(psf, dtype=np.float64)
    r0 = k.shape[0] // 2
    r = min(r0, max(int(radius), 0))
    return k[r0 - r:r0 + r + 1, r0 - r:r0 + r + 1]


def _psf_sides(mean: np.ndarray, diff: np.ndarray, scale: float,
               psfs: tuple[np.ndarray, np.ndarray] | None) -> tuple[np.ndarray, ...]:
    """The images of :func:`_sides` before its Gaussian: foveal side (mean, diff), perifoveal side (mean, diff), NaNs
    filled; with the channels' PSFs each side blurred by the other channel's (the foveal side by the perifoveal PSF
    magnified ``scale`` times, the perifoveal side by the foveal PSF shrunk as much; each cut to the image's size
    first). They do not depend on the blurs: :func:`_relative_blur` makes them once for all its trials."""
    from scipy.signal import fftconvolve

    n = max(mean.shape)
    kernels = (None, None) if psfs is None else (
        _rescaled_psf(_cropped(psfs[1], math.ceil(n / (2 * scale))), scale),
        _rescaled_psf(_cropped(psfs[0], n), 1.0 / scale))
    out = []
    for side in (0, 1):
        for v in (mean, diff):
            u = np.nan_to_num(v, nan=float(np.nanmean(v)))
            k = kernels[side]
            if k is not None:
                r = k.shape[0] // 2
                u = fftconvolve(np.pad(u, r, mode="edge"), k, mode="valid")
            out.append(u)
    return tuple(out)


def _sides(mean: np.ndarray, diff: np.ndarray, scale: float, blur_px: float,
           psfs: tuple[np.ndarray, np.ndarray] | None, relative_px: float = 0.0,
           pre: tuple[np.ndarray, ...] | None = None) -> tuple[np.ndarray, ...]:
    """The low-passed images of (2): foveal side (mean, diff) and perifoveal side (mean, diff). With the channels'
    PSFs both sides carry both blurs (:func:`_psf_sides`; ``pre``: its result for these images, when made
    already). ``relative_px``: the relative blur ``b_r`` (module docstring)."""
    from scipy.ndimage import gaussian_filter

    # the pixel box of the down-scaling, then G (and the relative blur, on its side)
    s1 = scale * math.sqrt(1.0 / 12.0 + blur_px ** 2 + max(relative_px, 0.0) ** 2)
    s2 = math.hypot(blur_px, min(relative_px, 0.0))
    pre = _psf_sides(mean, diff, scale, psfs) if pre is None else pre
    return tuple(gaussian_filter(u, s, mode="nearest", truncate=3.0) for u, s in zip(pre, (s1, s1, s2, s2)))


def _grid(shape: tuple[int, int], scale: float) -> np.ndarray:
    """The perifoveal pixels ``p`` of the fovea, less :data:`MARGIN_PX` at its border: ``(2, N)`` (row, column)."""
    H, W = shape
    hy, hx = (n / (2.0 * scale) - MARGIN_PX for n in (H, W))
    if min(hy, hx) < 3:
        raise InputError("scale", scale, f"a fovea of at least 6 x 6 perifoveal pixels in frames of {shape}")
    cy, cx = (H - 1) / 2.0, (W - 1) / 2.0
    ys = np.arange(math.ceil(cy - hy), math.floor(cy + hy) + 1)
    xs = np.arange(math.ceil(cx - hx), math.floor(cx + hx) + 1)
    Y, X = np.meshgrid(ys, xs, indexing="ij")
    return np.stack([Y.ravel(), X.ravel()]).astype(np.float64)


#: the edge padding scipy's ``map_coordinates`` gives an image before its spline filter in mode 'nearest' (scipy
#: 1.6+): :func:`_fit_once` filters the foveal sides once with the same padding
_SPLINE_PAD = 12


def _foveal_points(p: np.ndarray, shape: tuple[int, int], scale: float, cy: float, cx: float,
                   phi: float) -> np.ndarray:
    """``c_s + scale R(-phi) (p - c_s - c)``: where each perifoveal pixel ``p`` falls in the foveal image (``c_s``
    the sensor's centre, ``c = (cy, cx)`` the foveal centre)."""
    H, W = shape
    cs = np.array([(H - 1) / 2.0, (W - 1) / 2.0])[:, None]
    co, si = math.cos(phi), math.sin(phi)
    R = np.array([[co, si], [-si, co]])
    return cs + scale * (R @ (p - cs - np.array([cy, cx])[:, None]))


def _linear_part(u: float, a_m: np.ndarray, a_d: np.ndarray, b_m: np.ndarray, b_d: np.ndarray,
                 r2: np.ndarray) -> tuple[float, float, float, float]:  # r2 = 0: no radial gain
    """``(g, o, h, rss)`` of (2) at amplitude ``1 / u`` and fixed geometry: ``lhs = (g + h r2) rhs + o`` is linear
    in ``(g, o, h)`` (``h``: the radial gain, vignetting, that the foveal side sees over the sensor; on the right,
    so that the foveal side keeps its unit weight and no shrinking of both sides fits better)."""
    lhs, rhs = a_m + 0.5 * u * a_d, b_m - 0.5 * u * b_d
    X = np.stack([rhs, np.ones_like(rhs), r2 * rhs], axis=1)
    coef, *_ = np.linalg.lstsq(X, lhs, rcond=None)
    return float(coef[0]), float(coef[1]), float(coef[2]), float(np.sum((lhs - X @ coef) ** 2))


def _amplitude_u(a_m: np.ndarray, a_d: np.ndarray, b_m: np.ndarray, b_d: np.ndarray, r2: np.ndarray) -> float:
    """``u`` of (1) at fixed geometry: (g, o, k) by linear least squares inside a bounded 1-D search."""
    from scipy.optimize import minimize_scalar

    return float(minimize_scalar(lambda u: _linear_part(u, a_m, a_d, b_m, b_d, r2)[3], bounds=(0.5, 2.0),
                                 method="bounded", options={"xatol": 1e-7}).x)


def _block_jackknife(p: np.ndarray, a_m: np.ndarray, a_d: np.ndarray, b_m: np.ndarray, b_d: np.ndarray,
                     r2: np.ndarray, blocks: int = JACKKNIFE_BLOCKS) -> float:
    """The delete-one-block jackknife standard error of ``u`` over ``blocks x blocks`` blocks of the fovea: unlike
    the Gauss-Newton error it sees a misfit that varies across the field (the channels' PSFs, haze, vignetting)."""
    edges = [np.quantile(p[i], np.linspace(0, 1, blocks + 1)[1:-1]) for i in (0, 1)]
    label = np.searchsorted(edges[0], p[0], side="right") * blocks + np.searchsorted(edges[1], p[1], side="right")
    us = []
    for b in range(blocks * blocks):
        keep = label != b
        if keep.sum() < 0.5 * keep.size:
            continue
        us.append(_amplitude_u(a_m[keep], a_d[keep], b_m[keep], b_d[keep], r2[keep]))
    n = len(us)
    if n < 3:
        return math.inf
    us_a = np.asarray(us)
    return float(math.sqrt((n - 1) / n * np.sum((us_a - us_a.mean()) ** 2)))


def _errors(J: np.ndarray, r: np.ndarray, inflate: float) -> tuple[np.ndarray, float]:
    """Gauss-Newton standard errors ``sqrt(diag((J^T J)^-1) s^2 inflate)`` of a least-squares fit with Jacobian ``J``
    and residual ``r`` (``s^2`` its variance per degree of freedom, returned too); inf where singular."""
    var = float(np.sum(r ** 2)) / max(r.size - J.shape[1], 1)
    try:
        return np.sqrt(np.maximum(np.diag(np.linalg.inv(J.T @ J)) * var * inflate, 0.0)), var
    except np.linalg.LinAlgError:
        return np.full(J.shape[1], math.inf), var


def _coarse_centre(p: np.ndarray, f2m: np.ndarray, f2d: np.ndarray, a_m: np.ndarray, a_d: np.ndarray,
                   r2: np.ndarray, u: float) -> tuple[float, float] | None:
    """The foveal centre (perifoveal pixels): the whole-pixel shift ``delta`` of the perifoveal samples, within
    :data:`COARSE_SHIFT_PX`, that fits (2) best at the stated scale; None if no shift fits."""
    H, W = f2m.shape
    iy, ix = p.astype(int)
    best, arg = math.inf, None
    for dy in range(-COARSE_SHIFT_PX, COARSE_SHIFT_PX + 1):
        for dx in range(-COARSE_SHIFT_PX, COARSE_SHIFT_PX + 1):
            jy, jx = iy + dy, ix + dx
            if jy.min() < 0 or jx.min() < 0 or jy.max() >= H or jx.max() >= W:
                continue
            rss = _linear_part(u, a_m, a_d, f2m[jy, jx], f2d[jy, jx], r2)[3]
            if rss < best:
                best, arg = rss, (dy, dx)
    return None if arg is None else (float(arg[0]), float(arg[1]))


def _coarse_start(foveal: Any, p: np.ndarray, f2m: np.ndarray, f2d: np.ndarray, b_m: np.ndarray, b_d: np.ndarray,
                  theta0: np.ndarray, fit_amplitude: bool) -> np.ndarray:
    """Stage 1b of :func:`fit_foveal`: the start moved to the best whole-pixel centre (:func:`_coarse_centre`), where
    a mounted camera's axis can sit far from the stated one, if it fits (2) better than the stated geometry."""
    scale = float(theta0[0])
    a_m, a_d, r2 = foveal(theta0)
    t = _coarse_centre(p, f2m, f2d, a_m, a_d, r2, float(theta0[4]))
    if t is None:
        return theta0
    a_m1, a_d1, r21 = foveal(np.array([scale, t[0], t[1], 0.0]))
    u1 = _amplitude_u(a_m1, a_d1, b_m, b_d, r21) if fit_amplitude else 1.0
    g1, o1, k1, rss1 = _linear_part(u1, a_m1, a_d1, b_m, b_d, r21)
    if rss1 < _linear_part(float(theta0[4]), a_m, a_d, b_m, b_d, r2)[3]:
        return np.array([scale, t[0], t[1], 0.0, u1, g1, o1, k1])
    return theta0


def _relative_blur(m: np.ndarray, d: np.ndarray, fit: FovealFit, *, scale: float, blur_px: float,
                   psfs: tuple[np.ndarray, np.ndarray] | None, fit_amplitude: bool,
                   pre: tuple[np.ndarray, ...] | None = None) -> float:
    """The relative blur ``b_r`` (module docstring) that explains (2) best at ``fit``'s geometry, within
    :data:`RELATIVE_BLUR_MAX`: the relative misfit (:attr:`FovealFit.relative_misfit`: the residual over the
    perifoveal side's contrast times the gain), with ``u`` (a 1-D search) and ``(g, o, h)`` (linear) fitted at each
    trial, minimised by a bounded 1-D search. (Not the residual itself: blurring the foveal side lowers it with the
    side's contrast, and the gain follows it down.) ``pre``: :func:`_psf_sides` of ``(m, d)``, when made already."""
    from scipy.ndimage import map_coordinates
    from scipy.optimize import minimize_scalar

    H, W = m.shape
    p = _grid(m.shape, scale)
    iy, ix = p.astype(int)
    q = _foveal_points(p, m.shape, fit.scale, fit.centre_px[0], fit.centre_px[1], math.radians(fit.rotation_deg))
    r2 = ((q[0] - (H - 1) / 2.0) ** 2 + (q[1] - (W - 1) / 2.0) ** 2) / (((H - 1) / 2.0) ** 2 + ((W - 1) / 2.0) ** 2)
    # the PSF blurs do not depend on b: made once (each trial re-made them: 80 PSF rescalings, 9 of a 17 s fit)
    pre = _psf_sides(m, d, scale, psfs) if pre is None else pre

    def misfit(b: float) -> float:  # FovealFit.relative_misfit at this blur
        f1m, f1d, f2m, f2d = _sides(m, d, scale, blur_px, psfs, b, pre)
        a_m, a_d = (map_coordinates(v, q, order=3, mode="nearest") for v in (f1m, f1d))
        b_m, b_d = f2m[iy, ix], f2d[iy, ix]
        u = _amplitude_u(a_m, a_d, b_m, b_d, r2) if fit_amplitude else 1.0
        g, _, _, rss = _linear_part(u, a_m, a_d, b_m, b_d, r2)
        return math.sqrt(rss / b_m.size) / max(abs(g) * float(np.std(b_m - 0.5 * u * b_d)), 1e-300)

    return float(minimize_scalar(misfit, bounds=(-RELATIVE_BLUR_MAX, RELATIVE_BLUR_MAX), method="bounded",
                                 options={"xatol": 0.01}).x)


def _correlation_area(blur_px: float) -> float:
    """How many low-passed samples share one error (module docstring, "Uncertainty"): ``4 pi blur_px^2``, at least
    1."""
    return max(1.0, 4.0 * math.pi * blur_px ** 2)


def fit_foveal(mean: ArrayLike, diff: ArrayLike, *, scale: float = 6.0, gain: float = 1.0, offset: float = 0.0,
               blur_px: float = BLUR_PX, fit_amplitude: bool = True, psfs: tuple[ArrayLike, ArrayLike] | None = None,
               both_assignments: bool = False) -> FovealFit:
    """Fit the foveal relation (2) and the amplitude ratio (1) to a recording's separated images, with and without
    the radial gain (vignetting): the fit with it, its amplitude's error widened by the two fits' difference as far
    as the data cannot tell the two models apart (``se['amplitude_model']``, the models' spread when averaged by
    their likelihoods: how much the amplitude rests on how the relation is modelled; 0 where the data reject the
    model without the radial gain, as they do wherever the foveal side is vignetted). Both are fitted with the relative
    blur that explains the first fit best (:func:`_relative_blur`).

    ``both_assignments``: also fit the channels swapped (``-diff``); the assignment the relation explains better
    is returned (``identified['swapped']`` True when it is the swapped one). Other parameters and the result: as
    :func:`_fit_once`.
    """
    m = np.asarray(mean, dtype=np.float64)
    d = np.asarray(diff, dtype=np.float64)
    if m.ndim != 2 or d.shape != m.shape:
        raise InputError("diff", f"array of shape {d.shape}", f"the mean image's (H, W) = {m.shape}")
    pair = None if psfs is None else (np.asarray(psfs[0], np.float64), np.asarray(psfs[1], np.float64))
    pre = _psf_sides(m, d, scale, pair)
    sides = _sides(m, d, scale, blur_px, pair, pre=pre)
    kw = dict(scale=scale, gain=gain, offset=offset, blur_px=blur_px, fit_amplitude=fit_amplitude)
    fit = _fit_once(m.shape, sides, vignetting=True, **kw)
    swapped = False
    if both_assignments:  # the swapped channels: the difference image's sides negated (the sides are linear in it)
        neg = (sides[0], -sides[1], sides[2], -sides[3])
        other = _fit_once(m.shape, neg, vignetting=True, **kw)
        # clearly better, and a relation at all (a positive gain, a misfit below the perifoveal side's own
        # contrast): else the solver's choice stands
        if other.gain > 0 and other.residual_rms < SWAP_RATIO * fit.residual_rms and other.relative_misfit < 1.0:
            fit, sides, swapped = other, neg, True
    if swapped:
        d = -d
        pre = _psf_sides(m, d, scale, pair)
    b_r = _relative_blur(m, d, fit, scale=scale, blur_px=blur_px, psfs=pair, fit_amplitude=fit_amplitude, pre=pre)
    sides = _sides(m, d, scale, blur_px, pair, b_r, pre)
    fit = replace(_fit_once(m.shape, sides, vignetting=True, **kw), relative_blur_px=b_r)
    without = _fit_once(m.shape, sides, vignetting=False, **kw)
    # the two models averaged by their likelihoods (Bayesian model averaging: the spread between them is the
    # between-model variance w (1 - w) delta^2): a relation that needs the radial gain (the data reject the model
    # without it by chi^2, counted in independent samples) leaves no model error; one it does not need, the
    # difference (w = 1/2: delta / 2, doubled in the amplitude's error as before)
    delta = abs(fit.amplitude - without.amplitude)
    n_eff = fit.samples / _correlation_area(blur_px)
    var = fit.residual_rms ** 2
    dchi2 = max(n_eff * (without.residual_rms ** 2 - var) / var, 0.0) if var > 0 else math.inf
    w = 1.0 / (1.0 + math.exp(min(0.5 * dchi2, 700.0)))  # the model without the radial gain's weight
    spread = 2.0 * math.sqrt(w * (1.0 - w)) * delta
    se = {**fit.se, "amplitude_model": spread,
          "amplitude": max(fit.se["amplitude"], 2.0 * spread)}
    ok = {**fit.identified, "amplitude": bool(se["amplitude"] <= TOLERANCES["amplitude"]), "swapped": swapped}
    return replace(fit, se=se, identified=ok)


def _foveal_sampler(p: np.ndarray, shape: tuple[int, int], f1m: np.ndarray, f1d: np.ndarray,
                    vignetting: bool) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``foveal(theta) -> (a_m, a_d, r2)``: the foveal sides (mean, diff) where the perifoveal pixels ``p`` fall for
    the geometry ``theta[:4]`` (:func:`_foveal_points`), and their squared distance from the sensor's centre over
    the half-diagonal's (0 without ``vignetting``)."""
    from scipy.ndimage import map_coordinates, spline_filter

    H, W = shape
    norm = ((H - 1) / 2.0) ** 2 + ((W - 1) / 2.0) ** 2
    # the foveal sides' cubic-spline coefficients, once: map_coordinates' own prefilter (edge padding of
    # _SPLINE_PAD, the spline filter) on each of the fit's hundreds of evaluations filtered the whole images again;
    # the same coefficients at the same shifted points give the same values bit for bit
    c1m, c1d = (spline_filter(np.pad(f, _SPLINE_PAD, mode="edge"), 3, output=np.float64, mode="nearest")
                for f in (f1m, f1d))
    # the last geometry's samples: of the 9 evaluations of a finite-difference Jacobian, the 4 that move (u, g, o, h)
    # sample the foveal sides at the same points (half of a fit's interpolations)
    last: list[Any] = [None, None]

    def foveal(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        key = np.asarray(theta[:4], dtype=np.float64).tobytes()
        if key == last[0]:
            return last[1]
        q = _foveal_points(p, shape, theta[0], theta[1], theta[2], math.radians(theta[3]))
        r2 = ((q[0] - (H - 1) / 2.0) ** 2 + (q[1] - (W - 1) / 2.0) ** 2) / norm * float(vignetting)
        qp = q + _SPLINE_PAD
        last[:] = key, (map_coordinates(c1m, qp, order=3, mode="nearest", prefilter=False),
                        map_coordinates(c1d, qp, order=3, mode="nearest", prefilter=False), r2)
        return last[1]

    return foveal


def _fit_once(shape: tuple[int, int], sides: tuple[np.ndarray, ...], *, scale: float = 6.0, gain: float = 1.0,
              offset: float = 0.0, blur_px: float = BLUR_PX, fit_amplitude: bool = True,
              vignetting: bool = True) -> FovealFit:
    """One fit of the foveal relation (2) and the amplitude ratio (1) to the low-passed sides (:func:`_sides`), with
    the radial gain or without (``vignetting``).

    Parameters
    ----------
    shape : tuple of 2 int
        The images' ``(H, W)``.
    sides : tuple of 4 ndarray
        Foveal side (mean, diff), perifoveal side (mean, diff), :func:`_sides`.
    scale, gain, offset : float
        The stated constraint (the start).
    blur_px : float
        The common low-pass, perifoveal pixels (the residual's correlation area).
    fit_amplitude : bool
        Fit ``u = 1 / rho`` (else held at 1).

    Returns
    -------
    FovealFit
    """
    from scipy.optimize import least_squares

    f1m, f1d, f2m, f2d = sides
    p = _grid(shape, scale)
    iy, ix = p.astype(int)
    b_m, b_d = f2m[iy, ix], f2d[iy, ix]

    foveal = _foveal_sampler(p, shape, f1m, f1d, vignetting)

    def residual(theta: np.ndarray) -> np.ndarray:
        a_m, a_d, r2 = foveal(theta)
        u = theta[4] if fit_amplitude else 1.0
        g, o, h = theta[5], theta[6], theta[7]
        return (a_m + 0.5 * u * a_d) - (g + h * r2) * (b_m - 0.5 * u * b_d) - o

    # stage 1, the stated geometry: (g, o, k) linear there, u by a 1-D search
    a_m, a_d, r2 = foveal(np.array([scale, 0.0, 0.0, 0.0]))
    u0 = _amplitude_u(a_m, a_d, b_m, b_d, r2) if fit_amplitude else 1.0
    g0, o0, k0, _ = _linear_part(u0, a_m, a_d, b_m, b_d, r2)
    theta0 = np.array([scale, 0.0, 0.0, 0.0, u0, g0, o0, k0])
    theta_s = _coarse_start(foveal, p, f2m, f2d, b_m, b_d, theta0, fit_amplitude)
    # stage 2, the geometry too, within the bounds a mounted camera stays in (SEARCH)
    spread = float(np.std(b_m)) or 1.0
    x_scale = np.array([0.01 * scale, 0.3 / scale, 0.3 / scale, 0.1, 0.01, 0.01 * max(abs(g0), 1e-3), 0.01 * spread,
                        0.01 * max(abs(g0), 1e-3)])
    lo = np.array([scale * (1 - SEARCH["scale"]), -SEARCH["centre_px"], -SEARCH["centre_px"],
                   -SEARCH["rotation_deg"], 0.5, 1e-6, -np.inf, -np.inf])
    hi = np.array([scale * (1 + SEARCH["scale"]), SEARCH["centre_px"], SEARCH["centre_px"], SEARCH["rotation_deg"],
                   2.0, np.inf, np.inf, np.inf])
    if not fit_amplitude:
        lo[4], hi[4] = 1.0 - 1e-12, 1.0 + 1e-12
    sol = least_squares(residual, np.clip(theta_s, lo, hi), x_scale=x_scale, bounds=(lo, hi), method="trf",
                        max_nfev=200)
    th = sol.x
    r = sol.fun
    n = r.size
    inflate = _correlation_area(blur_px)  # neighbouring samples share their error through the low-pass
    se_all, var = _errors(sol.jac if fit_amplitude else np.delete(sol.jac, 4, axis=1), r, inflate)
    if not fit_amplitude:
        se_all = np.insert(se_all, 4, 0.0)
    u = float(th[4]) if fit_amplitude else 1.0
    se = {"scale": float(se_all[0]), "centre_px": float(max(se_all[1], se_all[2])),
          "rotation_deg": float(se_all[3]), "amplitude": float(se_all[4] / u ** 2) if fit_amplitude else 0.0,
          "gain": float(se_all[5])}
    ok = {key: bool(math.isfinite(v) and v <= TOLERANCES[key] * (th[0] if key == "scale" else 1.0))
          for key, v in se.items()}
    r_stated = residual(theta0)
    stage2 = {"scale": float(th[0]), "centre_px": [float(th[1]), float(th[2])], "rotation_deg": float(th[3]),
              "amplitude": 1.0 / float(th[4]), "rss": float(np.sum(r ** 2)), "se": dict(se),
              "rss_stated": float(np.sum(r_stated ** 2))}
    # the fitted geometry is used when it explains the fovea significantly better than the stated one: the drop of
    # the residual beyond what 4 more parameters fit to noise (chi^2, in units of its correlated variance)
    gain_chi2 = (stage2["rss_stated"] - stage2["rss"]) / max(var * inflate, 1e-300)
    stage2["chi2_drop"] = float(gain_chi2)
    inside = abs(th[0] / scale - 1) < 0.95 * SEARCH["scale"] and max(abs(th[1]), abs(th[2])) < 0.95 * SEARCH[
        "centre_px"] and abs(th[3]) < 0.95 * SEARCH["rotation_deg"]
    if not (gain_chi2 > GEOMETRY_CHI2 and inside and se["scale"] < GEOMETRY_SE_MAX * th[0]):
        # the geometry is not pinned down (no significant gain, a bound reached, or its scale uncertain by more
        # than GEOMETRY_SE_MAX): keep the stated one (stage 1)
        r = r_stated
        u0_, g0_, h0_ = theta0[4], theta0[5], theta0[7]
        J = np.stack([0.5 * a_d + 0.5 * (g0_ + h0_ * r2) * b_d, -(b_m - 0.5 * u0_ * b_d), -np.ones_like(b_m),
                      -r2 * (b_m - 0.5 * u0_ * b_d)], axis=1)
        se1, _ = _errors(J if fit_amplitude else J[:, 1:], r, inflate)
        th = theta0
        u = float(th[4])
        se.update(amplitude=float(se1[0] / u ** 2) if fit_amplitude else 0.0, gain=float(se1[-3]))
        ok.update(gain=bool(se["gain"] <= TOLERANCES["gain"]), geometry_kept=True)
    if fit_amplitude:  # the spread of the amplitude over the fovea's blocks: what a structured misfit costs
        a_m, a_d, r2 = foveal(th)
        se["amplitude_blocks"] = _block_jackknife(p, a_m, a_d, b_m, b_d, r2) / u ** 2
        se["amplitude"] = max(se["amplitude"], se["amplitude_blocks"])
    ok["amplitude"] = bool(se["amplitude"] <= TOLERANCES["amplitude"])
    x2_side = b_m - 0.5 * (float(th[4]) if fit_amplitude else 1.0) * b_d
    return FovealFit(scale=float(th[0]), centre_px=(float(th[1]), float(th[2])), rotation_deg=float(th[3]),
                     amplitude=1.0 / u, gain=float(th[5]), offset=float(th[6]),
                     vignetting=-float(th[7]) / float(th[5]) if th[5] else 0.0, se=se,
                     residual_rms=math.sqrt(float(np.mean(r ** 2))), identified=ok, samples=int(n),
                     relative_misfit=math.sqrt(float(np.mean(r ** 2))) / max(abs(float(th[5])) *
                                                                              float(np.std(x2_side)), 1e-300),
                     geometry_fit=stage2)


__all__ = ["AMPLITUDE_FLOOR", "AMPLITUDE_MODEL_ERROR", "BLUR_PX", "MARGIN_PX", "RELATIVE_BLUR_MAX", "SEARCH",
           "TOLERANCES", "FovealFit", "fit_foveal"]

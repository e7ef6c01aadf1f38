"""Unknown mixing ratios: a fast classical solver (subspace initialisation, gauge fix, alternating minimisation
with a TV prior).

Gauge
-----
The mixture ``y_t = x2 + alpha_t (x1 - x2)`` is unchanged by the two-parameter family

    x1' = x2 + p d,   x2' = x2 + c d,   alpha_t' = (alpha_t - c) / (p - c),   d = x1 - x2,          (1)

so no data term, however it is minimised, fixes ``(p, c)``: alternating minimisation started from the paper's
frame-mean initialisation converges to a mixed pair. Two things fix it: the polariser's model (alpha's known mean
and amplitude, :mod:`metafovea.reconstruct.polarizer`, :func:`polarizer_gauge_step`) and the foveal constraint
``D x1 = g C x2 + b`` (radiometric gain ``g = foveal_gain``, offset ``b = foveal_offset``; 1 and 0 for images in
common units), which is linear in ``(p, c)``:

    p D d - c g C d = g C x2 + b - D x2,                                                             (2)

a two-column least-squares problem over the ``(H/scale) x (W/scale)`` constraint pixels, solved in closed form
(:func:`foveal_gauge`). On real data the relation holds only up to the channels' PSF difference, so the foveal
side is blurred by the perifoveal crop's extra blur (fitted over :data:`PSF_GRID`, ``foveal_psf='fit'``), a border
margin is left out, both sides can be low-passed further (``foveal_blur``, default 0) and the mean level is one
extra equation.

Guard
-----
The fix uses noisy estimates as regressors; when one channel is barely observed (``alpha`` near 0 or 1 in every
frame) ``d`` is dominated by amplified noise and the fix can make things worse. With ``gauge='auto'`` it is applied
only if all of these hold (the reasons are in ``info['gauge']``):

1. the 2 x 2 gauge problem is well conditioned (``cond <= GAUGE_MAX_COND``) and ``p - c`` is not tiny;
2. the fixed ``alpha`` is physical: within ``[-ALPHA_TOL, 1 + ALPHA_TOL]`` (``cos^2`` lies in [0, 1]);
3. it improves the fit: the foveal misfit drops by more than noise alone explains (``Delta chi^2 > 6 var``: the
   mean of a 2-parameter ``chi^2`` is ``2 var``), the constraint then explains the images (misfit rms halved, or
   within 2x the expected noise rms: a wrong ``scale``/``offset`` leaves a large misfit and is rejected), **and**
   the objective ``foveal misfit + TV`` (misfit in units of its noise variance, TV relative to its current value)
   decreases;
4. no scale 5-10 % off (:data:`SCALE_PROBES`) halves the misfit (the geometry is right).

A fix applied because it halved the misfit, which still leaves it above :data:`FOVEAL_UNEXPLAINED` times its noise,
does not make alpha identified (``info['gauge']['warning']``): the constraint's offset, gain or geometry is not the
recording's. ``gauge='foveal'`` applies the fix whenever it is computable, ``'none'`` never. With the polariser model,
frames with under :data:`FRAME_VALID_MIN` of the window's typical valid samples are left out of its fit.

Algorithm
---------
1. ``alpha``'s initial guess from frame means, rescaled to [0, 1] (paper), or (``init='svd'``, default) the exact
   data-term optimum: the leading left singular vector of the temporally centred frames spans
   ``alpha - mean(alpha)``; it is put into the frame-mean gauge by a 2-parameter regression. This is the global
   minimiser of the data term, so the alternating stage cannot stall in a poor local solution of the data fit;
   only the gauge is left, which step 2 fixes.
2. Gauge fix: the polariser model when given (and its fit holds), else the guarded foveal fix.
3. Alternating minimisation: x-step = per-pixel LSQ, alpha-step = closed-form per-frame least squares (clipped to
   [0, 1] once the gauge is absolute); stops when alpha moves less than ``tol``. The prior (``prior='tv'``) is the
   proximal step applied to the x-step's images with the weight set by the estimated noise level. By default
   (``alpha_from='data'``) the alpha-step uses the un-regularised LSQ images: TV shrinks contrast, so alpha taken
   from the TV-smoothed images (``alpha_from='prior'``, the textbook alternating scheme) is biased.
4. If the gauge could not be fixed and ``strict`` is true, :class:`InputError` is raised: alpha is then only known
   up to the affine map (1) and the images are mixtures of each other; ``strict=False`` returns that result
   flagged ``info['alpha_identified'] = False`` instead.

Measured figures: BENCHMARKS.md, section "Reconstruction" ("Simulated paper measurement" for the gauge's PSF
allowance and low-pass).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.errors import InputError, as_float, check_choice, check_int
from metafovea.reconstruct._common import Timings, as_frames, image_dtype, valid_mask, with_overrides
from metafovea.reconstruct.denoise import denoise
from metafovea.reconstruct.lsq import MAX_CONDITION, _lsq_masked, normal_matrix, solve_weights
from metafovea.reconstruct.operators import FovealOperator, lowpass, lowpass_noise_factor
from metafovea.reconstruct.polarizer import ALPHA_SE_MAX, PolarizerModel
from metafovea.reconstruct.result import Reconstruction

log = logging.getLogger(__name__)

#: the gauge fit's 2 x 2 problem must be better conditioned than this (guard, condition 1)
GAUGE_MAX_COND = 1e3
#: how far outside [0, 1] the fixed alpha may reach before the guard rejects the fix (guard, condition 2)
ALPHA_TOL = 0.1
#: default extra low-pass (Gaussian sigma, constraint pixels) of both sides of the gauge fit; see foveal_gauge
FOVEAL_BLUR = 0.0
#: candidate extra blur (Gaussian sigma, constraint pixels) of the perifoveal crop, psf_blur='fit'
PSF_GRID = (0.0, 0.5, 0.75, 1.0, 1.25, 1.5)
#: relative scale changes probed by the guard's geometry check (rejects when one halves the misfit)
SCALE_PROBES = (0.9, 0.95, 1.05, 1.1)
#: a frame with fewer valid samples than this share of the window's median (saturated, dropped) is left out of the
#: polariser model's fit, and its alpha is the fitted rotation's: its own rests on another part of the image than the
#: other frames', whose errors differ
FRAME_VALID_MIN = 0.9
#: a foveal gauge fix whose constraint misfit stays above this many times its noise is applied where it explains the
#: images far better than before, but alpha is not called identified by it: the constraint itself (its offset, gain
#: or geometry) does not describe the recording (the channels' PSF difference leaves a few times the noise)
FOVEAL_UNEXPLAINED = 10.0


def _add_warning(rep: dict[str, Any], text: str) -> None:
    """``text`` appended to ``rep['warning']`` (``'; '`` between warnings)."""
    rep["warning"] = f"{rep['warning']}; {text}" if rep.get("warning") else text


def frame_mean_alpha(Y: np.ndarray) -> np.ndarray:
    """The paper's initial alpha: the frame means rescaled to span [0, 1].

    Parameters
    ----------
    Y : ndarray, shape (T, H, W)

    Returns
    -------
    ndarray, shape (T,)
    """
    m = np.nanmean(Y.reshape(Y.shape[0], -1), axis=1).astype(np.float64)
    span = m.max() - m.min()
    if not span > 1e-12 * max(1.0, np.abs(m).max()):
        raise InputError("frames", "frames with equal means",
                         "frames whose brightness varies with the polariser (alpha not constant)",
                         detail="the frame-mean initialisation needs varying mixing ratios")
    return (m - m.min()) / span


def subspace_alpha(Y: np.ndarray, a0: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
    """The data-optimal alpha in ``a0``'s gauge (Algorithm, step 1).

    Parameters
    ----------
    Y : ndarray, shape (T, H, W)
    a0 : ndarray, shape (T,)
        Alpha in the gauge wanted (:func:`frame_mean_alpha`).

    Returns
    -------
    alpha : ndarray, shape (T,)
        ``c0 + c1 u``, ``u`` the leading left singular vector of the temporally centred frames, ``(c0, c1)``
        regressed on ``a0``.
    info : dict
        ``singular_values`` and ``subspace_snr`` (the leading eigenvalue of the frames' Gram matrix over the
        next one).
    """
    T = Y.shape[0]
    Yc = Y.reshape(T, -1).astype(np.float64)
    Yc = Yc - Yc.mean(axis=0, keepdims=True)
    G = Yc @ Yc.T
    ev, V = np.linalg.eigh(G)
    ev = ev[::-1]
    u = V[:, -1]
    B = np.stack([np.ones(T), u], axis=1)
    coef, *_ = np.linalg.lstsq(B, a0, rcond=None)
    a = B @ coef
    noise_floor = ev[1] if T > 2 else 0.0
    snr = float(ev[0] / noise_floor) if noise_floor > 0 else math.inf
    return a, {"singular_values": np.sqrt(np.maximum(ev, 0)).tolist(), "subspace_snr": snr}


def _lsq(Y: np.ndarray, a: np.ndarray, M: np.ndarray | None, dt: np.dtype,
         max_condition: float) -> tuple[np.ndarray, np.ndarray, float]:
    T, H, W = Y.shape
    if M is None:
        Wt, rep = solve_weights(a, max_condition=max_condition, regularize="difference", quiet=True)
        X = Wt.astype(dt) @ Y.reshape(T, -1)
        return X[0].reshape(H, W), X[1].reshape(H, W), rep["condition"]
    x1, x2, _ = _lsq_masked(Y, a, M, max_condition, 0.0, dt)
    x1 = np.nan_to_num(x1, nan=float(np.nanmean(x1)))
    x2 = np.nan_to_num(x2, nan=float(np.nanmean(x2)))
    ev = np.linalg.eigvalsh(normal_matrix(a))
    return x1, x2, float(ev[1] / max(ev[0], 1e-300))


def _alpha_step(Y: np.ndarray, x1: np.ndarray, x2: np.ndarray, M: np.ndarray | None) -> np.ndarray:
    d = (x1 - x2).astype(np.float64).ravel()
    r = (Y.reshape(Y.shape[0], -1) - x2.ravel()[None]).astype(np.float64)
    if M is None:
        return (r @ d) / max(d @ d, 1e-300)
    Mf = M.reshape(M.shape[0], -1)
    r = np.where(Mf, r, 0.0)
    return (r @ d) / np.maximum(Mf.astype(np.float64) @ (d * d), 1e-300)


def anisotropic_tv(x: np.ndarray) -> float:
    """Anisotropic total variation of one image: the guard's smoothness term (not smoothed, no gradient).

    Parameters
    ----------
    x : ndarray, shape (H, W)

    Returns
    -------
    float
        ``sum |x[i+1, j] - x[i, j]| + |x[i, j+1] - x[i, j]|``.
    """
    return float(np.abs(np.diff(x, axis=0)).sum() + np.abs(np.diff(x, axis=1)).sum())


@dataclass(frozen=True)
class _GaugeBand:
    """Where the gauge is fitted: the constraint grid without ``margin`` border pixels (``inner``), low-passed by
    ``blur``; the spatial structure compared with contrast gain ``gam``, the mean level with ``gain``/``bias`` as
    one extra row of weight ``w_mean``."""

    inner: tuple[slice, slice]
    n_px: int
    blur: float
    w_mean: float
    gam: float
    gain: float
    bias: float

    def parts(self, u: np.ndarray, sig: float) -> tuple[np.ndarray, float]:
        """(mean-free low-pass band, mean) of a constraint-grid image, the border left out."""
        m = float(u[self.inner].mean())
        return (lowpass(u, sig)[self.inner] - m).ravel(), m

    def fit(self, o: FovealOperator, x2d: np.ndarray, d: np.ndarray,
            psis: tuple[float, ...]) -> tuple[float, float, np.ndarray, np.ndarray, np.ndarray]:
        """Best ``(chi^2, psi, R0, Rp, Rc)`` over the extra blurs ``psis`` for the geometry ``o``: the residual of
        the gauge ``(p, c)`` is ``R0 + p Rp + c Rc`` (band rows, then the weighted mean row)."""
        Dx2, Dd_full, Cx2, Cd_full = o.D(x2d), o.D(d), o.C(x2d), o.C(d)
        Cd, Cd_m = self.parts(Cd_full, self.blur)
        C2, C2_m = self.parts(Cx2, self.blur)
        g, gam, w = self.gain, self.gam, self.w_mean
        best = None
        for psi in psis:
            # the foveal side is blurred by psi more (the perifoveal PSF's extra blur in the crop)
            sd = math.hypot(self.blur, psi)
            Dd, Dd_m = self.parts(Dd_full, sd)
            D2, D2_m = self.parts(Dx2, sd)
            R0 = np.concatenate([D2 - gam * C2, [w * (D2_m - g * C2_m - self.bias)]])
            Rp = np.concatenate([Dd, [w * Dd_m]])
            Rc = np.concatenate([-gam * Cd, [-w * g * Cd_m]])
            (pt, ct), *_ = np.linalg.lstsq(np.stack([Rp, Rc], axis=1), -R0, rcond=None)
            chi = float(np.sum((R0 + pt * Rp + ct * Rc) ** 2))
            if best is None or chi < best[0]:
                best = (chi, float(psi), R0, Rp, Rc)
        return best


def _gauge_band(op: FovealOperator, blur: float, mean_weight: float, contrast_gain: float | None,
                margin: int | None) -> _GaugeBand:
    h, w = op.low_shape
    mg = min(int(math.ceil(2.0 * blur)) + 2, min(h, w) // 8) if margin is None else int(margin)
    mg = max(0, min(mg, (min(h, w) - 2) // 2))
    n_px = (h - 2 * mg) * (w - 2 * mg)
    gam = op.gain if contrast_gain is None else float(contrast_gain)
    if not gam > 0:
        raise InputError("foveal_contrast", contrast_gain, "a positive contrast gain (None: foveal_gain)")
    return _GaugeBand(inner=(slice(mg, h - mg), slice(mg, w - mg)), n_px=n_px, blur=float(blur),
                      w_mean=math.sqrt(max(float(mean_weight), 0.0) * n_px), gam=float(gam), gain=op.gain,
                      bias=op.bias)


def foveal_gauge(x1: np.ndarray, x2: np.ndarray, alpha: np.ndarray, op: FovealOperator, *,
                 noise: tuple[float, float] | None = None, mode: str = "auto", blur: float = FOVEAL_BLUR,
                 mean_weight: float = 1.0, contrast_gain: float | None = None, margin: int | None = None,
                 psf_blur: float | str = "fit") -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """Fix the ``(p, c)`` gauge of eq. (1) with the foveal constraint, eq. (2).

    Parameters
    ----------
    x1, x2 : ndarray, shape (H, W)
        The images in the current gauge.
    alpha : ndarray, shape (T,)
    op : FovealOperator
        Scale, registration offset, gain ``g`` and bias ``b`` of the constraint.
    noise : tuple of 2 float, optional
        The noise std of ``(x1, x2)`` (the guard's expected misfit).
    mode : {'auto', 'foveal', 'none'}
        ``'auto'``: apply the fix when the guard (module docstring) accepts it; ``'foveal'``: whenever computable.
    blur : float
        A Gaussian low-pass (sigma, constraint pixels) of both sides: removes the fine detail the perifoveal
        channel's PSF does not resolve.
    mean_weight : float
        The weight of the mean-level equation relative to all constraint pixels (0 ignores it).
    contrast_gain : float, optional
        The gain with which the band's spatial structure (mean removed) is compared (default ``op.gain``). Stray
        light and haze can scale the channels' contrasts differently from their mean levels, but a free contrast
        gain is not identifiable together with the gauge: it admits the trivial fit ``D x1' -> 0``.
    margin : int, optional
        Border pixels of the constraint region left out (default ``min(ceil(2 blur) + 2, min(h, w) // 8)``): at
        the edge of the foveal field the perifoveal PSF mixes in scene content the foveal image does not see.
    psf_blur : float or 'fit'
        The perifoveal crop's extra blur relative to the downsampled foveal image (Gaussian sigma, constraint
        pixels), applied to the foveal side; ``'fit'`` picks the value of :data:`PSF_GRID` with the smallest misfit.

    Returns
    -------
    x1, x2 : ndarray, shape (H, W)
        The images in the fixed gauge (unchanged when the fix is not applied).
    alpha : ndarray, shape (T,)
    report : dict
        ``applied``, ``reason``, ``p``, ``c``, ``condition``, ``psf_blur``, the misfits before and after, the
        guard's figures.
    """
    rep: dict[str, Any] = {"mode": mode, "applied": False, "blur": float(blur), "mean_weight": float(mean_weight)}
    if mode == "none":
        rep["reason"] = "gauge='none'"
        return x1, x2, alpha, rep
    x1d, x2d = x1.astype(np.float64), x2.astype(np.float64)
    d = x1d - x2d
    band = _gauge_band(op, blur, mean_weight, contrast_gain, margin)
    rep["margin"] = band.inner[0].start
    rep["contrast_gain"] = band.gam
    if isinstance(psf_blur, str):
        if psf_blur != "fit":
            raise InputError("foveal_psf", psf_blur, "'fit' or the extra blur (Gaussian sigma, constraint pixels)")
        grid: tuple[float, ...] = PSF_GRID
    else:
        grid = (float(psf_blur),)
    _, psi, R0, Rp, Rc = band.fit(op, x2d, d, grid)
    rep["psf_blur"] = float(psi)
    B = np.stack([Rp, Rc], axis=1)
    # conditioning of the spatial structure (translation invariant: a dark level in the data would
    # otherwise dominate both columns)
    sv = np.linalg.svd(B[:-1], compute_uv=False)
    cond = float(sv[0] / sv[1]) if sv[1] > 0 else math.inf
    rep["condition"] = cond
    if not cond < GAUGE_MAX_COND:
        rep["reason"] = f"gauge problem ill-conditioned (cond {cond:.3g} >= {GAUGE_MAX_COND:g})"
        return x1, x2, alpha, rep
    (p, c), *_ = np.linalg.lstsq(B, -R0, rcond=None)
    rep["p"], rep["c"] = float(p), float(c)
    if abs(p - c) < 1e-3:
        rep["reason"] = f"degenerate gauge (p - c = {p - c:.3g})"
        return x1, x2, alpha, rep
    a_new = (alpha - c) / (p - c)
    n1 = x2d + p * d
    n2 = x2d + c * d
    # x1 = x2 + 1 d: the current gauge is (p, c) = (1, 0)
    chi_old, chi_new = float(np.sum((R0 + Rp) ** 2)), float(np.sum((R0 + p * Rp + c * Rc) ** 2))
    rep["foveal_rms_before"] = float(np.sqrt(chi_old / band.n_px))
    rep["foveal_rms_after"] = float(np.sqrt(chi_new / band.n_px))
    rep["alpha_range_after"] = [float(a_new.min()), float(a_new.max())]
    if mode == "foveal":
        rep.update(applied=True, reason="gauge='foveal'")
        return n1.astype(x1.dtype), n2.astype(x2.dtype), a_new, rep
    reasons = _guard(rep, band, op, (x1d, x2d), (n1, n2), a_new, (chi_old, chi_new), noise, psi, d)
    if reasons:
        rep["reason"] = "; ".join(reasons)
        log.info("foveal gauge fix rejected: %s", rep["reason"])
        return x1, x2, alpha, rep
    rep.update(applied=True, reason="improves the fit")
    if rep["foveal_rms_after"] > FOVEAL_UNEXPLAINED * rep["foveal_rms_expected"]:
        rep["unexplained"] = True
        rep["warning"] = (f"the foveal constraint fixed alpha's gauge but does not explain the images (misfit "
                          f"{rep['foveal_rms_after']:.3g} against a noise of {rep['foveal_rms_expected']:.3g}): its "
                          "offset, gain or geometry is not the recording's (scale, foveal_gain, foveal_offset); alpha "
                          "is not identified")
    return n1.astype(x1.dtype), n2.astype(x2.dtype), a_new, rep


def _guard(rep: dict[str, Any], band: _GaugeBand, op: FovealOperator, old: tuple[np.ndarray, np.ndarray],
           new: tuple[np.ndarray, np.ndarray], a_new: np.ndarray, chis: tuple[float, float],
           noise: tuple[float, float] | None, psi: float, d: np.ndarray) -> list[str]:
    """The reasons (module docstring, "Guard") not to apply the fix ``old -> new``; none: apply it. Records the
    expected misfit, the objectives and the TV ratio in ``rep``."""
    chi_old, chi_new = chis
    n_eff = band.n_px
    reasons = []
    if a_new.min() < -ALPHA_TOL or a_new.max() > 1 + ALPHA_TOL:
        reasons.append(f"alpha would leave [0, 1] ({a_new.min():.3f}..{a_new.max():.3f})")
    # noise level of the constraint residual: D averages scale^2 pixels of x1, C picks one of x2
    # (times the gain); the low-pass averages further
    s1, s2 = noise if noise is not None else (0.0, 0.0)
    var_r = max((s1 ** 2 / op.scale ** 2 + band.gam ** 2 * s2 ** 2) * lowpass_noise_factor(band.blur, op.low_shape),
                1e-300)
    rep["foveal_rms_expected"] = float(math.sqrt(var_r))
    if chi_old - chi_new <= 6.0 * var_r:  # Delta chi^2 of 2 parameters: mean 2 var_r under "no change"
        reasons.append("foveal misfit reduction within noise")
    consistent = chi_new / n_eff <= 4.0 * var_r
    if not (chi_new <= 0.25 * chi_old or consistent):
        reasons.append(f"the constraint does not explain the images after the fix (rms "
                       f"{math.sqrt(chi_new / n_eff):.3g} vs {math.sqrt(chi_old / n_eff):.3g} before, noise "
                       f"{math.sqrt(var_r):.3g}): wrong scale/offset/gain?")
    # objective: foveal misfit (chi^2 / n in units of var_r) + TV (relative to the current value)
    tv_old = anisotropic_tv(old[0]) + anisotropic_tv(old[1])
    tv_new = anisotropic_tv(new[0]) + anisotropic_tv(new[1])
    vr = max(var_r, 1e-300)
    j_old = chi_old / vr / n_eff + tv_old / max(tv_old, 1e-300)
    j_new = chi_new / vr / n_eff + tv_new / max(tv_old, 1e-300)
    rep["objective_before"], rep["objective_after"] = float(j_old), float(j_new)
    rep["tv_ratio"] = float(tv_new / max(tv_old, 1e-300))
    if not j_new < j_old:
        reasons.append("objective (foveal misfit + TV) does not decrease")
    # geometry self-consistency: with PSF differences allowed for, a wrong scale can still explain the
    # images "better than before"; a scale 5-10 % off that halves the misfit means the geometry is wrong
    # (periodic scenes such as bar targets have flat misfit-vs-scale curves, hence "halves")
    for f_s in SCALE_PROBES:
        try:
            o2 = FovealOperator(op.shape, op.scale * f_s, op.offset, low=op.low_shape, gain=op.gain, bias=op.bias,
                                rotation_deg=op.rotation_deg)
        except InputError:
            continue
        if o2.low_shape != op.low_shape:
            continue
        chi2 = band.fit(o2, old[1], d, (psi,))[0]
        if chi2 < 0.5 * chi_new:
            reasons.append(f"scale {o2.scale:.4g} fits the foveal constraint better than {op.scale:.4g} "
                           f"(misfit {math.sqrt(chi2 / n_eff):.3g} vs {math.sqrt(chi_new / n_eff):.3g}): wrong scale?")
            break
    return reasons


#: what fixes alpha's gauge when a window's frames do not (``strict``'s error; the CLI names its flags instead)
GAUGE_ADVICE = ("frames whose alpha gauge the polariser model (polarizer) or the foveal constraint "
                "(scale, foveal_gain, foveal_offset) fixes; or the file's alpha (method='lsq'); or strict=False: alpha "
                "up to an affine map (flagged alpha_identified: false)")


@dataclass(frozen=True)
class AlternatingOptions:
    """The knobs of :func:`alternating` (each is also a keyword argument of it).

    Attributes
    ----------
    scale : float
        The foveal constraint's scale f1 / f2.
    offset : tuple of 2 float
        Registration offset of the crop in x2 pixels: the foveal centre (docs/measurement_format.md, "The foveal
        geometry").
    rotation_deg : float
        The foveal image's rotation against the perifoveal one, degrees (the same convention).
    foveal_gain, foveal_offset : float
        The constraint's radiometry ``D x1 = foveal_gain C x2 + foveal_offset`` (a Measurement's
        :class:`~metafovea.measurement.FovealConstraint`).
    foveal_blur, foveal_mean : float
        The gauge fit's low-pass sigma (constraint pixels) and the weight of its mean-level equation.
    foveal_contrast : float or None
        The gauge fit's contrast gain (None: ``foveal_gain``).
    foveal_psf : float or 'fit'
        Extra blur of the perifoveal crop (``'fit'``: estimated); see :func:`foveal_gauge`.
    gauge : {'auto', 'polarizer', 'foveal', 'none'}
        ``'auto'``: the polariser model when given and its fit holds, else the guarded foveal fix;
        ``'polarizer'``: the polariser model only; ``'foveal'``: always the foveal fix.
    polarizer : PolarizerModel or None
        Frame times, rate, mode, extinction (:class:`~metafovea.reconstruct.polarizer.PolarizerModel`): fixes the
        gauge from alpha's known mean and amplitude (:func:`polarizer_gauge_step`).
    polarizer_alpha : {'auto', 'model', 'frames'}
        ``'model'``: alpha of the fitted constant-rate rotation (the images are then its least-squares images, no
        alternation); ``'frames'``: each frame's own alpha in the fixed gauge, then alternation; ``'auto'``
        (default): ``'frames'`` when the fit finds the rotation irregular beyond the noise, else ``'model'``.
    prior : {'tv', 'nlm', 'bilateral'} or None
        The x-step's denoiser (None: plain alternating least squares).
    init : {'svd', 'means'}
        The data-optimal subspace (default) or the paper's frame means.
    iterations : int
        Alternating iterations.
    tol : float
        Stop when ``max |delta alpha| < tol``.
    saturation : float or None
        Samples ``>=`` this are invalid (as NaN/inf).
    noise_sigma : float or None
        The frames' noise std (None: from the rank-2 fit's residual).
    max_condition : float
        Of the x-step's normal matrix.
    alpha_from : {'data', 'prior'}
        The alpha-step on the un-regularised images or on the prior's.
    strict : bool
        Refuse (:class:`InputError`) when the gauge cannot be fixed, instead of a flagged result.
    """

    scale: float = 6.0
    offset: tuple[float, float] = (0.0, 0.0)
    rotation_deg: float = 0.0
    foveal_gain: float = 1.0
    foveal_offset: float = 0.0
    foveal_blur: float = FOVEAL_BLUR
    foveal_mean: float = 1.0
    foveal_contrast: float | None = None
    foveal_psf: float | str = "fit"
    gauge: str = "auto"
    polarizer: PolarizerModel | None = None
    polarizer_alpha: str = "auto"
    prior: str | None = "tv"
    init: str = "svd"
    iterations: int = 10
    tol: float = 1e-4
    saturation: float | None = None
    noise_sigma: float | None = None
    max_condition: float = MAX_CONDITION
    alpha_from: str = "data"
    strict: bool = True


@dataclass
class _Window:
    """The frames being separated: ``Y`` as given, ``Yf`` with invalid samples filled (refilled from the model
    while iterating), ``M`` the valid-sample mask (``None``: all valid), ``dt`` the output dtype."""

    Y: np.ndarray
    Yf: np.ndarray
    M: np.ndarray | None
    dt: np.dtype

    def residual(self, a: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
        r = self.Yf - a[:, None, None] * x1[None] - (1 - a)[:, None, None] * x2[None]
        return r if self.M is None else np.where(self.M, r, 0.0)


#: the grid of blocks (per side) whose own alpha estimates tell a polariser's deviation, shared by the whole image,
#: from scene motion's (:func:`deviation_shared`): 16 blocks put the decision near the irregularity test's 3 sigma
DEVIATION_BLOCKS = 4


def _channel_noise_gain(a: np.ndarray) -> np.ndarray:
    """Noise std of (x1, x2) per unit frame noise for mixing ratios ``a``."""
    return np.sqrt(np.diag(np.linalg.inv(normal_matrix(a) + 1e-12 * np.eye(2))))


def _window(frames: ArrayLike, saturation: float | None) -> _Window:
    Y = as_frames(frames, min_frames=3)
    dt = image_dtype(Y)
    M = valid_mask(Y, saturation)
    Yf = Y
    if M is not None:
        # fill invalid samples with the per-pixel mean of the valid ones (refilled from the model later); a pixel
        # with none (dead in every frame) gets the frames' mean: computed without nanmean's empty-slice warning
        valid = M.sum(axis=0)
        fill = np.where(M, Y, 0).sum(axis=0, dtype=np.float64) / np.maximum(valid, 1)
        fill = np.where(valid > 0, fill, float(np.where(M, Y, 0).sum(dtype=np.float64) / max(int(M.sum()), 1)))
        Yf = np.where(M, Y, fill[None]).astype(dt)
    return _Window(Y=Y, Yf=Yf, M=M, dt=dt)


def _initial_alpha(win: _Window, init: str, info: dict[str, Any]) -> np.ndarray:
    """Step 1: alpha from the frame means, or the data-optimal subspace in the frame-mean gauge."""
    a0 = frame_mean_alpha(win.Yf)
    if init != "svd":
        return a0.copy()
    a, sinfo = subspace_alpha(win.Yf, a0)
    info.update(sinfo)
    if sinfo["subspace_snr"] < 2.0:
        raise InputError("frames", f"{win.Y.shape[0]} frames whose variation is at the noise level "
                         f"(subspace SNR {sinfo['subspace_snr']:.3g})",
                         "frames in which the polariser visibly changes the mixture",
                         detail="alpha is not identifiable: the polariser is stopped or one channel is dark")
    return a


def _alternate(win: _Window, x1: np.ndarray, x2: np.ndarray, a: np.ndarray, cond: float, opt: AlternatingOptions,
               prior: str | None, sig: float, gain: np.ndarray,
               absolute: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, list[float], int]:
    """Step 3: x-step (LSQ, then the prior) and alpha-step until alpha moves less than ``tol``; returns
    ``(x1, x2, alpha, condition, loss history, iterations)``. ``absolute``: the gauge was fixed (alpha clipped to
    [0, 1]); ``gain``: the channels' noise gain for the prior when no iteration runs."""
    history: list[float] = []
    it_done = 0
    if absolute:
        a = np.clip(a, 0.0, 1.0)
    for it in range(opt.iterations):
        a_prev = a
        x1, x2, cond = _lsq(win.Yf, a, win.M, win.dt, opt.max_condition)
        if prior is not None:
            gain = _channel_noise_gain(a)
            x1p = denoise(x1, prior, sigma=sig * gain[0])
            x2p = denoise(x2, prior, sigma=sig * gain[1])
            a = _alpha_step(win.Yf, *((x1p, x2p) if opt.alpha_from == "prior" else (x1, x2)), win.M)
            x1, x2 = x1p, x2p
        else:
            a = _alpha_step(win.Yf, x1, x2, win.M)
        if absolute:
            a = np.clip(a, 0.0, 1.0)
        if win.M is not None:
            model = a[:, None, None] * x1[None] + (1 - a)[:, None, None] * x2[None]
            win.Yf = np.where(win.M, win.Y, model).astype(win.dt)
        r = win.residual(a, x1, x2)
        history.append(float(np.sqrt(np.mean(r.astype(np.float64) ** 2))))
        it_done = it + 1
        if np.max(np.abs(a - a_prev)) < opt.tol:
            break
    if opt.iterations == 0 and prior is not None:
        x1 = denoise(x1, prior, sigma=sig * gain[0])
        x2 = denoise(x2, prior, sigma=sig * gain[1])
    return x1, x2, a, cond, history, it_done


def deviation_shared(win: _Window, x1: np.ndarray, x2: np.ndarray, fitted: np.ndarray) -> float:
    """The fraction of the frames' deviation from the fitted rotation that the image's parts share.

    Every block of a :data:`DEVIATION_BLOCKS` x :data:`DEVIATION_BLOCKS` grid estimates each frame's alpha on its own
    (the alpha-step on its pixels); ``A_bt``, weighted by the block's ``sum d^2`` (its Fisher information, ``d = x1 -
    x2``), has the whole image's alpha as its weighted mean ``a_t``. A polariser that jitters moves every block's
    alpha alike; scene motion or a drifting fixed pattern moves each part by its own amount. Returns

        shared = C / (C + S),  C = mean_t (a_t - fitted_t)^2,  S = mean_t sum_b w_b (A_bt - a_t)^2 / sum_b w_b

    With no jitter, white noise gives ``S ~ (B - 1) C`` (``B`` blocks: each block's noise is ``sqrt B`` times the
    whole image's), so ``shared ~ 1 / B``; it passes 1/2 when the shared deviation exceeds ``sqrt(B - 2)`` times the
    whole image's noise, about :data:`~metafovea.reconstruct.polarizer.JITTER_FACTOR` x it for 16 blocks: on a
    static scene this is the irregularity test again; under motion it is what tells them apart.

    Parameters
    ----------
    win : _Window
    x1, x2 : ndarray, shape (H, W)
        The images in the gauge of ``fitted``.
    fitted : ndarray, shape (T,)
        The fitted rotation's alpha in that gauge.

    Returns
    -------
    float
        In [0, 1]; 1 when there is no deviation at all.
    """
    H, W = x1.shape
    ny, nx = min(DEVIATION_BLOCKS, max(H // 2, 1)), min(DEVIATION_BLOCKS, max(W // 2, 1))
    ys, xs = np.linspace(0, H, ny + 1).astype(int), np.linspace(0, W, nx + 1).astype(int)
    d = (x1 - x2).astype(np.float64)
    blocks, weights = [], []
    for i in range(ny):
        for j in range(nx):
            sl = (slice(ys[i], ys[i + 1]), slice(xs[j], xs[j + 1]))
            Mb = None if win.M is None else win.M[:, sl[0], sl[1]]
            d2 = d[sl] ** 2
            w = float(np.sum(d2)) if Mb is None else float(np.mean(np.sum(np.where(Mb, d2[None], 0.0), axis=(1, 2))))
            if w > 0:
                blocks.append(_alpha_step(win.Yf[:, sl[0], sl[1]], x1[sl], x2[sl], Mb))
                weights.append(w)
    if len(blocks) < 2:
        return 1.0
    A, wb = np.asarray(blocks), np.asarray(weights)[:, None]
    mean = np.sum(wb * A, axis=0) / wb.sum()
    common = float(np.mean((mean - fitted) ** 2))
    scatter = float(np.mean(np.sum(wb * (A - mean[None]) ** 2, axis=0) / wb.sum()))
    return common / (common + scatter) if common + scatter > 0 else 1.0


def polarizer_gauge_step(win: _Window, x1: np.ndarray, x2: np.ndarray, alpha: np.ndarray, op: FovealOperator,
                         model: PolarizerModel, sig: float, use: str = "model"
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """Fix the gauge with the polariser model (:func:`~metafovea.reconstruct.polarizer.polarizer_gauge`).

    Parameters
    ----------
    win : _Window
        The frames (valid-sample mask).
    x1, x2 : ndarray, shape (H, W)
        The images in the current gauge.
    alpha : ndarray, shape (T,)
    op : FovealOperator
        Tells a free-running polariser's two candidates apart (the sign of ``a`` swaps the channels) by the foveal
        constraint's misfit.
    model : PolarizerModel
    sig : float
        The frames' noise std (alpha's data-term noise: ``sig / ||d||``).
    use : {'auto', 'model', 'frames'}
        ``auto``: ``frames`` when the fit finds the rotation irregular (beyond the noise) and the image's parts
        share most of the deviation (:func:`deviation_shared`: a polariser's, not scene motion's), else ``model``.
        Return the fitted rotation's alpha (:func:`~metafovea.reconstruct.polarizer.model_alpha`) or each frame's
        own (:func:`~metafovea.reconstruct.polarizer.gauged_alpha`).

    Returns
    -------
    x1, x2 : ndarray, shape (H, W)
        The images in the fixed gauge.
    alpha : ndarray, shape (T,)
    report : dict
        ``applied``, ``reason``, the fit, ``sign``, ``alpha_se`` (each frame's standard error), ``alpha_se_max``,
        ``foveal_rms``, ``deviation_shared`` (an irregular rotation), ``images_gauge_se`` (the standard errors of
        ``x1`` and ``x2`` that the gauge's uncertainty leaves, the frames' units:
        :func:`~metafovea.reconstruct.polarizer.gauge_image_factors`);
        ``channel_assignment`` (the misfit ratio) when the sign was open.
    """
    from metafovea.reconstruct.polarizer import gauge_image_factors, gauged_alpha, model_alpha, polarizer_gauge

    x1d, x2d = x1.astype(np.float64), x2.astype(np.float64)
    d = x1d - x2d
    # data-term noise of alpha_hat: the per-frame alpha-step's std, sig / ||d|| over the valid pixels
    n_valid = d.size if win.M is None else float(np.mean(win.M.sum(axis=(1, 2))))
    dnorm = math.sqrt(float(np.mean(d ** 2)) * n_valid)
    # frames with under FRAME_VALID_MIN of the window's typical valid samples (a saturated or dropped frame) say
    # little or nothing of their alpha (a frame without any gives 0): the rotation is fitted without them, and
    # their alpha is the fitted rotation's
    keep = np.ones(alpha.shape[0], dtype=bool)
    if win.M is not None:
        counts = win.M.sum(axis=(1, 2)).astype(np.float64)
        keep = counts >= FRAME_VALID_MIN * float(np.median(counts))
    fit = polarizer_gauge(alpha[keep], model if keep.all() else replace(model, times_s=model.times_s[keep]),
                          alpha_noise=sig / dnorm if dnorm > 0 else None)
    rep: dict[str, Any] = {"applied": False, "fit": {k: v for k, v in fit.items() if k != "cov"}}
    if not keep.all():
        rep["frames_left_out"] = [int(k) for k in np.flatnonzero(~keep)]
    if fit["status"] != "ok":
        rep["reason"] = fit.get("reason", fit["status"])
        return x1, x2, alpha, rep
    cands = []
    for sign in ((1.0, -1.0) if fit["swap_ambiguous"] else (1.0,)):
        al, se = gauged_alpha(alpha, fit, sign)
        a_, b_ = (fit["a"], fit["b"]) if sign > 0 else (-fit["a"], fit["b"] + fit["a"])
        n1, n2 = x2d + (a_ + b_) * d, x2d + b_ * d
        mis = float(np.sqrt(np.mean(op.residual(n1, n2) ** 2)))
        cands.append((mis, sign, al, se, n1, n2))
    cands.sort(key=lambda c: c[0])
    mis, sign, al, se, n1, n2 = cands[0]
    shared = None
    if fit.get("irregular"):  # how much of the deviation the image's parts share (a polariser's) or not (motion)
        fitted_abs, _ = model_alpha(model, fit, 1.0)
        shared = deviation_shared(win, x1d, x2d, fit["a"] * fitted_abs + fit["b"])
        rep["deviation_shared"] = shared
    if use == "auto":  # a rotation that jitters beyond the noise, alike in every part of the image: follow each frame
        use = "frames" if fit.get("irregular") and shared is not None and shared > 0.5 else "model"
    if use == "frames" and dnorm > 0:  # each frame's alpha carries its data-term noise, not the jitter it follows
        al, se = gauged_alpha(alpha, fit, sign, frame_noise=sig / dnorm)
    if use == "model":
        al_f = al
        al, se = model_alpha(model, fit, sign)
        rep["frames_vs_model_rms"] = float(np.sqrt(np.mean((al_f - al)[keep] ** 2)))
    elif not keep.all():  # the frames left out of the fit: the fitted rotation's alpha
        al_m, se_m = model_alpha(model, fit, sign)
        al, se = np.where(keep, al, al_m), np.where(keep, se, se_m)
    f1, f2 = gauge_image_factors(fit, sign, use)
    rms_d = math.sqrt(float(np.mean(d ** 2)))
    rep.update(applied=True, reason="polariser model (known mean and amplitude of alpha)", sign=sign, alpha_from=use,
               alpha_se=se.tolist(), alpha_se_max=float(se.max()), foveal_rms=mis,
               images_gauge_se=[f1 * rms_d, f2 * rms_d])
    if fit.get("irregular"):
        why = (f"the image's parts share {shared:.0%} of it: " + ("an irregular polariser" if shared > 0.5 else
                                                                  "scene motion or a drifting pattern"))
        rep["warning"] = (f"alpha deviates from a constant-rate rotation by {fit['jitter_rms']:.2g} rms beyond the "
                          f"noise ({fit['alpha_noise_absolute']:.2g}); {why}; "
                          + ("using the fitted rotation" if use == "model" else "following each frame"))
    if not keep.all():
        left = rep["frames_left_out"]
        said = ", ".join(str(k) for k in left[:8]) + (f" and {len(left) - 8} more" if len(left) > 8 else "")
        _add_warning(rep, f"frame(s) {said} left out of the polariser's fit (under {FRAME_VALID_MIN:.0%} of their "
                          "samples valid: saturated or dropped); their alpha is the fitted rotation's")
    if fit.get("rate_at_search_edge"):
        _add_warning(rep, f"the polariser's fitted rate {fit['rate_hz']:.4g} Hz is at the end of the search, "
                          f"{model.rate_hz:.4g} Hz +- {100 * model.rate_tolerance:.3g} %: it may run outside that "
                          "range, and alpha's error is not estimated (state the rate: rate_hz=...)")
    if len(cands) > 1:
        rep["channel_assignment"] = {"by": "foveal constraint", "misfit_ratio": cands[1][0] / max(mis, 1e-300)}
    return n1.astype(x1.dtype), n2.astype(x2.dtype), al, rep


def alternating(frames: ArrayLike, options: AlternatingOptions | None = None, **overrides: Any) -> Reconstruction:
    """Unknown-alpha separation of the frames (Algorithm, module docstring).

    Parameters
    ----------
    frames : array_like, shape (T, H, W)
        ``T >= 3``; float32 preserved.
    options : AlternatingOptions, optional
        The foveal constraint, the gauge fit and guard, the prior, the initialisation and the stopping rule.
    **overrides
        Fields of ``options`` (``alternating(Y, scale=6, strict=False)``).

    Returns
    -------
    Reconstruction
        ``info``: ``alpha_identified`` (True when the gauge was fixed, i.e. alpha is absolute, and, by the
        polariser, its standard error is below ``ALPHA_SE_MAX``), ``alpha_gauge``, the gauge reports (``gauge``,
        ``polarizer_gauge``), ``noise_sigma``, ``noise_gain``, ``loss_history``, ``iterations``, ``foveal_rms``.
    """
    opt = with_overrides(AlternatingOptions, options, overrides)
    tm = Timings()
    gauge = check_choice("gauge", opt.gauge, ("auto", "polarizer", "foveal", "none"))
    init = check_choice("init", opt.init, ("svd", "means"))
    prior = opt.prior
    if prior is not None:
        prior = check_choice("prior", prior, ("tv", "nlm", "bilateral", "none"))
        prior = None if prior == "none" else prior
    opt = replace(opt, iterations=check_int("iterations", opt.iterations, 0, 10000),
                  alpha_from=check_choice("alpha_from", opt.alpha_from, ("data", "prior")),
                  tol=as_float("tol", opt.tol))
    with tm.measure("init"):
        win = _window(frames, opt.saturation)
        T, H, W = win.Y.shape
        op = FovealOperator((H, W), opt.scale, opt.offset, gain=opt.foveal_gain, bias=opt.foveal_offset,
                            rotation_deg=opt.rotation_deg)
        foveal_blur = as_float("foveal_blur", opt.foveal_blur)
        if not 0.0 <= foveal_blur <= 0.25 * min(op.low_shape):
            raise InputError("foveal_blur", foveal_blur, f"0 <= foveal_blur <= {0.25 * min(op.low_shape):g} "
                             f"(Gaussian sigma in constraint pixels; the constraint is {op.low_shape})")
        info: dict[str, Any] = {"init": init, "prior": prior, "scale": op.scale, "offset": list(op.offset),
                                "rotation_deg": op.rotation_deg, "foveal_gain": op.gain, "foveal_offset": op.bias}
        a = _initial_alpha(win, init, info)
        x1, x2, cond = _lsq(win.Yf, a, win.M, win.dt, opt.max_condition)
    sig = opt.noise_sigma
    if sig is None:  # noise level: residual of the rank-2 fit
        r = win.residual(a, x1, x2)
        n_valid = r.size if win.M is None else int(win.M.sum())
        sig = float(np.sqrt(np.sum(r.astype(np.float64) ** 2) / max(n_valid - 2 * H * W, 1)))
    info["noise_sigma"] = sig
    with tm.measure("gauge"):
        prep = None
        if opt.polarizer is not None and gauge in ("auto", "polarizer"):
            use = check_choice("polarizer_alpha", opt.polarizer_alpha, ("auto", "model", "frames"))
            x1, x2, a, prep = polarizer_gauge_step(win, x1, x2, a, op, opt.polarizer, sig, use)
            info["polarizer_gauge"] = prep
        gain = _channel_noise_gain(a)
        fmode = "none" if (prep is not None and prep["applied"]) or gauge == "polarizer" else gauge
        x1, x2, a, grep = foveal_gauge(x1, x2, a, op, noise=(sig * gain[0], sig * gain[1]), mode=fmode,
                                      blur=foveal_blur, mean_weight=as_float("foveal_mean", opt.foveal_mean),
                                      contrast_gain=None if opt.foveal_contrast is None else
                                      as_float("foveal_contrast", opt.foveal_contrast),
                                      psf_blur=opt.foveal_psf if isinstance(opt.foveal_psf, str) else
                                      as_float("foveal_psf", opt.foveal_psf))
        if prep is not None and prep["applied"]:
            grep["reason"] = ("not needed: the polariser model fixed the gauge (the foveal constraint chose the "
                              "channels)")
    info["gauge"] = grep
    fixed = bool(grep["applied"] or (prep is not None and prep["applied"]))
    if opt.strict and gauge != "none" and not fixed:
        pol = "no polariser model" if prep is None else f"polariser model: {prep.get('reason')}"
        raise InputError("frames", f"{T} frames", GAUGE_ADVICE,
                         detail=f"alpha's gauge not fixed: {pol}; foveal constraint: {grep.get('reason')}")
    with tm.measure("alternate"):
        by_pol = prep is not None and prep["applied"]
        if by_pol and prep["alpha_from"] == "model":  # alpha is the rotation's: the images are its LSQ images
            x1, x2, cond = _lsq(win.Yf, a, win.M, win.dt, opt.max_condition)
            x1, x2, a, cond, history, it_done = _alternate(win, x1, x2, a, cond, replace(opt, iterations=0), prior,
                                                           sig, _channel_noise_gain(a), fixed)
        else:
            x1, x2, a, cond, history, it_done = _alternate(win, x1, x2, a, cond, opt, prior, sig, gain, fixed)
    se_max = prep["alpha_se_max"] if by_pol else None
    info.update(iterations=it_done, loss_history=history, condition=float(cond),
                alpha_identified=bool((grep["applied"] and not grep.get("unexplained"))
                                      or (by_pol and se_max <= ALPHA_SE_MAX)),
                alpha_se_max=se_max, alpha_se_threshold=ALPHA_SE_MAX,
                images_gauge_se=prep.get("images_gauge_se") if by_pol else None,
                noise_gain=_channel_noise_gain(np.asarray(a, dtype=np.float64)).tolist(),
                alpha_gauge="absolute (polariser model)" if by_pol else "absolute (foveal constraint)"
                if grep["applied"] else "relative: frame means rescaled to [0, 1] (foveal fix not applied)",
                foveal_rms=float(np.sqrt(np.mean(op.residual(x1.astype(np.float64), x2.astype(np.float64)) ** 2))))
    if win.M is not None:
        info["masked_samples"] = int(win.M.size - win.M.sum())
        none = win.M.sum(axis=0) < 2  # pixels without two valid samples: not separable (NaN, as lsq leaves them)
        if none.any():
            x1, x2 = (np.where(none, np.nan, v).astype(win.dt) for v in (x1, x2))
            info["unseparated_pixels"] = int(none.sum())
    return Reconstruction(x1=np.asarray(x1, dtype=win.dt), x2=np.asarray(x2, dtype=win.dt),
                          alpha=np.asarray(a, dtype=np.float64), fpn=None, method="alternating", timings=dict(tm),
                          info=info)

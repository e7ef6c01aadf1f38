"""PSF-aware reconstruction: joint separation and deconvolution of the two channels, to scene radiance and kelvin.

The frames of a static scene through the camera are, per pixel and frame (DN, after the fixed pattern)::

    y_t = a_t u_1 + (1 - a_t) u_2 + n_t,    u_i = offset + r_i (K_i * s_i + p_i mean(s_i))            (1)

with ``a_t`` the mixing ratios, ``K_i`` channel ``i``'s PSF on the pixel grid (core, chromatic haze and glare,
:func:`metafovea.imaging.kernels.pixel_psf`), ``p_i`` its pedestal (the power of disks wider than the crop, a
uniform level), ``r_i`` its relative illumination, ``offset`` the sensor's dark level and ``s_i`` the scene in DN
above it as a perfect lens would image it. The per-pixel separation ``u_hat = N^-1 A^T y`` (``A = [a, 1 - a]``,
``N = A^T A``) is a sufficient statistic: it carries all of the frames' information about ``s``, with noise
covariance ``C = sigma^2 N^-1`` correlated between the channels (plus ``e^2 [[1, 1], [1, 1]]`` for a subtracted
fixed pattern of rms error ``e``, the same in every frame). With ``z_i = (u_hat_i - offset) / r_i`` and ``D_i`` the
OTFs, both channels are solved jointly on a grid padded by the kernels' radius:

* ``method='wiener'``: the linear minimum-mean-square-error estimate [1]_

      s_hat = (D^H C^-1 D + P^-1)^-1 D^H C^-1 z                                                         (2)

  with ``P_i`` the scene's power spectrum, estimated from the crop (:func:`metafovea.reconstruct.spectra.
  fitted_spectrum`, ``prior``) as a density per pixel and spread over the grid's ``n_grid`` bins as
  ``n_grid^(1 - k) n_crop^k x PSD`` (``prior_scale``: ``'grid'`` k = 0, ``'geometric'`` k = 1/2, ``'crop'``
  k = 1: the padding carries the crop's edge values, no texture); the mean is not shrunk;
* ``method='wavelet'`` (default): the Fourier-wavelet estimate (:mod:`metafovea.reconstruct.wavelet`): (2) with the
  prior's weight ``tau <= 1`` (sharper, noisier), then each channel's noise shrunk in a stationary wavelet frame by
  SURE-LET (each coefficient's shrinkage split by its parent's size, eq. (1b) there), ``tau`` per channel by its
  estimated risk (the risk of the shrinkage's linear fit estimated from the
  data where they show signal, plus Stein's unbiased risk estimate of what the non-linear shrinkage changes): the
  largest ``tau`` within one standard error of the lowest; non-linear, so not bound by the best linear estimate;
* ``method='tv'``: total variation [2]_, started from the Wiener estimate and solved by ADMM [3]_,

      min_s 1/2 ||z - D s||^2_{C^-1} + sum_i lambda_i TV(s_i),    lambda_i = 1 / mean |grad s_i|          (3)

  (the scale of a Laplace prior on the Wiener estimate's gradients).

Boundary (``boundary='solved'``, default): each channel's crop is padded with its edge values (``pad_mode``) and
(2) is one 2 x 2 system per frequency. The perifoveal channel's padding next to the crop is then replaced by what
the scene beyond the crop, solved for, puts there: the PSF split into its core (radius ``EXTERIOR_PX``) and the
rest, the rest's light taken from the edge-padded solve, the core's part of the data solved for with only the crop as
data in a ring of that width (:func:`~metafovea.reconstruct.joint.solved_exterior`). A raster scene's edge meeting
its surround, or a hot object just outside the field, shows in the crop's edge pixels through the core; edge values
continue the crop instead. Both are hypotheses: the solved ring is kept where it explains the data within its width
of the crop's edge better than the edge values by more than that misfit's standard error (``info['exterior']``),
else the edge values stay (``boundary='padded'``: always). The foveal channel's padding is then replaced by what
the perifoveal estimate predicts there, ``ratio s_2(p / scale)`` through ``K_1`` (the foveal haze gathers light from
several crop widths around the fovea, which the perifoveal channel images; ``foveal_scale``, ``foveal_ratio``), plus
the quadratic surface that levels it with the data, alone or joined to the data's edge values below the perifoveal
Nyquist frequency ``0.5 / scale``, whichever solution explains the foveal data better.
``boundary='unknown'`` solves for the scene beyond the crop over the whole padding instead (masked data, conjugate
gradients; slow).

Foveal fusion (``method='wavelet'`` with ``foveal_scale``, ``foveal_fusion=True``): inside the fovea both channels
image the same scene, the perifoveal one at 1/scale the resolution. On the foveal constraint's grid (``A = D s_1``,
the foveal estimate averaged over the perifoveal pixels it covers; ``B = ratio C s_2``, the perifoveal estimate's
crop), per ring ``k`` of frequency,

    A <- A + w_1(k) (B - A),  B <- B + w_2(k) (A - B),   w_i(k) = V_i(k) / E|A - B|^2(k)                 (5)

(the foveal change spread over its pixels and low-passed as the surround), ``V_i`` each estimate's noise (the
wavelet step's noise draws through the shrinkage's Jacobian, :func:`metafovea.reconstruct.wavelet.shrink_jacobian`):
the mean-square-optimal weight when an estimate's error is its noise alone, and lower than optimal when it holds
more. ``E|A - B|^2`` holds the other estimate's whole error, so a weight falls wherever the two disagree by more
than that noise explains (blur, a stated scale or gain ratio that is off). The foveal channel gains where its
chromatic haze leaves its coarse detail noisy, the perifoveal one in its crop's detail.

Temperatures: ``L_i = s_i (dL/dT)(300 K) / g_i`` is in-band radiance (``g_i``: DN per kelvin at 300 K) and

    T_i = L^-1(L_i)                                                                                       (4)

its brightness temperature (:class:`metafovea.measurement.RadiometricCalibration`).

Files: this module (:func:`separate_deconvolve`, :func:`deconvolve_measurement`, :func:`deconvolve_result`,
:func:`temperatures`); :mod:`~metafovea.reconstruct.joint` (:class:`ChannelPSFs`, the grid, the linear solves);
:mod:`~metafovea.reconstruct.spectra` (the scene prior); :mod:`~metafovea.reconstruct.metrics`
(:func:`~metafovea.reconstruct.metrics.wiener_bound`, the scores against the scene); :mod:`~metafovea.reconstruct.
psf_refine` (the PSFs refined from the data, ``refine_psf``).

Constants of the PSF-aware step and where each comes from (none is tuned to a named scene; "tuning seeds": the
scene generator's, :data:`metafovea.imaging.generator.TUNING_SEED_START` and up, disjoint from the held-out set the
benchmarks judge on):

=====================================  =======================================================================
``SURROUND_SIGMA_PER_SCALE`` (here)    derived: half power at the perifoveal Nyquist frequency
``PRIOR_SCALES`` (``prior_scale``)     an option; with the default method on the tuning seeds its default
                                       ``'geometric'`` left the fewest channel cases far below the bound
                                       (BENCHMARKS.md, the tuning sweep)
``WAVELET_NOISE_SEED`` (here)          any fixed seed: the same data give the same estimate
``FUSION_RING_STEPS`` (here)           eq. (5)'s rings, 4 frequency steps wide: dozens of bins per ring; on
                                       tuning seeds 2 steps tie with it, 8 gain less (BENCHMARKS.md)
``joint.MAX_CONDITION``                numerical: alpha that cannot separate the channels
``joint.EXTERIOR_PX``                  the PSF's core and the solved ring (``exterior_px``, an option): the
                                       filtered perifoveal PSF's core, nearly all of its power (the 8-14 um
                                       one's haze reaches further: from the edge-padded solve); its share in
                                       ``info['exterior']['core_power']``, its effect in BENCHMARKS.md
``joint.EXTERIOR_ITERATIONS``          a cap on the ring's CG (``exterior_iterations``): speed against error
                                       in BENCHMARKS.md
``joint.EXTERIOR_RESIDUAL_REDUCTION``  numerical: the ring's CG has converged in single precision
one standard error (the exterior)      the solved ring is kept only where it lowers the edge band's misfit by
                                       more than the misfit's standard error for white noise
``spectra.RADIAL_BINS``,               derived from the crop's and the grid's frequency steps (several
``spectra.TRUTH_RADIAL_BINS``          periodogram samples per ring)
``spectra.BETA_RANGE``,                natural scenes' power spectra, ``|f|^-2`` (Field 1987), the fit clipped
``spectra.DEFAULT_BETA``               to 1-4
``spectra.DETECTION_SNR``              derived: a ring whose periodogram is twice the noise; the wavelet step's
                                       risk takes the data's estimate on the bins where the prior predicts signal
                                       above the noise by the same factor (``PeriodicFilter.linear_risk``;
                                       checked against 1/4 and 4 on the tuning seeds: BENCHMARKS.md)
``spectra.MIN_FIT_BINS``               derived: two parameters and one degree of freedom; with fewer detected
                                       rings the level is the Whittle likelihood's (``spectra.whittle_level``,
                                       its search range 1e-8 to 1e8 of the noise's level: numerical)
``spectra.MEASURED_SNR``,              the hybrid prior's: where the measured spectrum replaces the power law
``spectra.MIN_HYBRID_BINS``            and when the tail alone is fitted; set with the
                                       prior on built-in scenes (issue 13), kept because the default method
                                       picks its regularisation by its risk on top of it; not re-swept
``spectra.PRIOR_FLOOR``                numerical: a bin without signal gets the largest penalty, not none
``spectra.NOISE_FLOOR_CRITICAL``       derived: the noise model is raised to the data's flat excess (eq. 5 of
                                       ``spectra``) at a false-alarm rate of 5e-4 (chi^2, one degree of freedom)
``spectra.NOISE_FLOOR_INFLATION``      derived: the Hann taper's variance inflation (Percival and Walden 1993)
``spectra.NOISE_FLOOR_BETA_RANGE``,    derived: from a white scene (never taken for noise) to ``BETA_RANGE``'s
``spectra.NOISE_FLOOR_BETA_STEP``      steepest, in steps of 0.1 (numerical: the slope's likelihood is smooth)
1/2 in ``spectra`` eq. (6)             derived: the nearer of the two causes of an excess, shared by both
                                       channels (correlation 1) or each channel's own (0)
``wavelet.WAVELETS``,                  an option; with eq. (1b) Haar leads db2 and sym4 in median and mean
``wavelet.DEFAULT_WAVELET``            margin on the tuning seeds (BENCHMARKS.md), with the shortest filters
``wavelet.NOISE_SAMPLES``              derived: the subband variances' standard error (its comment)
``wavelet.TAUS``                       a search range: the Wiener filter down to 1/64 of its prior weight
                                       (the chosen tau reached 1/64 on the tuning seeds; with the range extended
                                       to 8 the criterion chose none above 1 there)
``wavelet.MIN_COARSEST_PX``            the coarsest atoms fit 8 times across the crop
12 in ``wavelet`` eq. (1), (1b)        derived: SURE-LET's thresholds ``sqrt(6) sigma`` (Luisier, Blu and
                                       Unser 2007), for a coefficient and for its parent
one standard error (tau's choice)      the one-standard-error rule: the largest tau within one standard error
                                       (the noise draws' spread of the mean squared noise) of the lowest risk
=====================================  =======================================================================

Measured figures: BENCHMARKS.md, sections "PSF-aware reconstruction against the scene" and "PSF-aware
reconstruction on scenes never seen".

References
----------
.. [1] N. Wiener, *Extrapolation, Interpolation, and Smoothing of Stationary Time Series* (MIT Press, 1949).
.. [2] L. I. Rudin, S. Osher and E. Fatemi, "Nonlinear total variation based noise removal algorithms",
   Physica D 60, 259 (1992).
.. [3] S. Boyd, N. Parikh, E. Chu, B. Peleato and J. Eckstein, "Distributed optimization and statistical learning
   via the alternating direction method of multipliers", Found. Trends Mach. Learn. 3, 1 (2011).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.errors import InputError, check_choice, check_int
from metafovea.measurement import RadiometricCalibration
from metafovea.reconstruct._common import DECONVOLUTION_METHODS, DEFAULT_DECONVOLUTION
from metafovea.reconstruct.field import FIELD_MODES, PatchContext, field_deconvolve
from metafovea.reconstruct.joint import (
    BOUNDARIES,
    DEFAULT_BOUNDARY,
    EXTERIOR_ITERATIONS,
    EXTERIOR_PX,
    ChannelPSFs,
    Grid,
    PeriodicFilter,
    Problem,
    check_boundary,
    linear_solve,
    prepare_problem,
    solved_exterior,
    tv_admm,
)
from metafovea.reconstruct.metrics import score_deconvolution, true_fpn_error_dn, wiener_bound
from metafovea.reconstruct.spectra import (
    BETA_RANGE,
    DETECTION_SNR,
    PRIORS,
    fitted_spectrum,
    inverse_prior,
    radial_mean,
)
from metafovea.reconstruct.wavelet import (
    DEFAULT_WAVELET,
    NOISE_SAMPLES,
    TAUS,
    WAVELETS,
    shrink_jacobian,
    shrink_linearised,
    stationary_frame,
    swt_levels,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

    from metafovea.measurement import Measurement
    from metafovea.reconstruct.psf_refine import PSFFamily
    from metafovea.reconstruct.result import PipelineResult

__all__ = ["BETA_RANGE", "BOUNDARIES", "DECONVOLUTION_METHODS", "DEFAULT_DECONVOLUTION", "PRIORS", "PRIOR_SCALES",
           "SURROUND_SIGMA_PER_SCALE", "ChannelPSFs", "Deconvolution", "deconvolve_measurement", "deconvolve_result",
           "separate_deconvolve", "temperatures", "true_fpn_error_dn", "wiener_bound"]

#: the foveal surround's low-pass (Gaussian sigma, px per unit of the channels' scale): half power at the perifoveal
#: channel's Nyquist frequency 0.5 / scale cycles per foveal pixel (sigma = sqrt(ln 2 / 2) / (pi f))
SURROUND_SIGMA_PER_SCALE = math.sqrt(math.log(2.0) / 2.0) / (math.pi * 0.5)

#: the foveal fusion's rings (eq. 5) are this many frequency steps of the foveal constraint's grid wide, so that each
#: ring's mean is over dozens of bins (the innermost ring excepted)
FUSION_RING_STEPS = 4
#: what ``info['foveal_fusion']`` says where the PSFs are solved patch by patch
NO_FUSION_WITH_PATCHES = {"applied": False, "reason": "field patches: each patch's solve has its own noise; the "
                                                      "fusion runs on shift-invariant solves"}
#: the seed of the noise draws that measure the wavelet step's subband noise (fixed: the same data give the same
#: estimate)
WAVELET_NOISE_SEED = 0
#: how the crop's fitted spectrum (per pixel) becomes the padded grid's (per FFT bin) in :func:`separate_deconvolve`
#: (``prior_scale``): ``'grid'`` as if the whole grid carried the crop's texture (n_grid x PSD), ``'crop'`` as if only
#: the crop did (n_crop x PSD; the edge padding adds stripes along the axes only), ``'geometric'`` their geometric
#: mean (default; BENCHMARKS.md "PSF-aware": chosen on 8 cases, checked on 4 more)
PRIOR_SCALES = ("geometric", "grid", "crop")


@dataclass
class Deconvolution:
    """Scene estimates of both channels.

    Attributes
    ----------
    scene : tuple of 2 ndarray, shape (H, W)
        ``(s_1, s_2)`` in the frames' DN: a perfect lens' image, the dark level added back.
    temperature_k : tuple of 2 ndarray, shape (H, W), or None
        Their brightness temperatures, eq. (4), K; None without a radiometric calibration.
    info : dict
        What was chosen (noise, grid, priors, surround, weights, iterations), timings and, when scored, ``scores``.
    """

    scene: tuple[np.ndarray, np.ndarray]
    temperature_k: tuple[np.ndarray, np.ndarray] | None
    info: dict[str, Any] = field(default_factory=dict)

    #: the entries of ``info`` a summary (``metafovea reconstruct --json``'s ``scene``) carries
    SUMMARY_KEYS = ("method", "alpha_from", "sigma_dn", "noise_floor", "scores", "boundary", "exterior",
                    "foveal_surround", "foveal_fusion", "seconds", "psf_source", "psf_refinement", "field")

    def summary(self) -> dict[str, Any]:
        """The entries of ``info`` named in :attr:`SUMMARY_KEYS` that it has."""
        return {k: v for k, v in self.info.items() if k in self.SUMMARY_KEYS}

    def lines(self) -> list[str]:
        """What a person reads: the method, alpha's source, the time and the scores against the scene (when
        scored), what was taken beyond the perifoveal crop and why (``boundary='solved'``), the field-dependent PSF's
        choice (when the PSFs have one) and the PSF refinement's lines."""
        sc = self.info.get("scores") or {}
        out = [f"scene ({self.info['method']}, alpha from {self.info.get('alpha_from', 'given')}, "
               f"{self.info['seconds']:.1f} s)" + ("" if not sc else ": against the scene " + ", ".join(
                   f"{k} {v:.4g}" for k, v in sc.items() if isinstance(v, float) and "second" not in k))]
        nf = self.info.get("noise_floor")
        if nf and any(nf["raised"]):
            out.append(f"noise raised to what the data show: {nf['why']}")
        ex = self.info.get("exterior")
        if ex:
            out.append(f"beyond the perifoveal crop ({ex['kept']}): {ex['why']}")
        fld = self.info.get("field") or {}
        if fld.get("patches", 1) > 1:
            out.append(f"field-dependent PSF ({fld['patches']} x {fld['patches']} patches): {fld['mode']}; "
                       f"{fld['why']}")
        fus = self.info.get("foveal_fusion")
        if fus and fus["applied"]:
            w1, w2 = (", ".join(f"{v:.2f}" for v in fus[f"weights_x{i}"]) for i in (1, 2))
            out.append(f"foveal fusion, per ring of {2 * fus['ring_cycles_per_sample'][0]:.2g} cycles per perifoveal "
                       f"pixel (each estimate's noise over the two estimates' disagreement): the perifoveal "
                       f"estimate's weight in the fovea's coarse detail {w1}, the foveal estimate's in the perifoveal "
                       f"crop {w2}; corrections {fus['correction_rms_dn'][0]:.3g} / {fus['correction_rms_dn'][1]:.3g} "
                       "DN rms")
        elif fus:
            out.append(f"foveal fusion: {fus['reason']}")
        return out + list((self.info.get("psf_refinement") or {}).get("lines", []))


def temperatures(scene_dn: tuple[ArrayLike, ArrayLike], offset: float,
                 meta: dict[str, Any] | RadiometricCalibration | None) -> tuple[np.ndarray, np.ndarray] | None:
    """Brightness temperatures of both channels' images, eq. (4).

    Parameters
    ----------
    scene_dn : tuple of 2 array_like
        Channel 1's and 2's images, DN (any shape, e.g. ``(K, H, W)`` videos).
    offset : float
        The dark level, DN.
    meta : dict, RadiometricCalibration or None
        A Measurement's metadata (``dn_per_k_300K``, ``radiometry``: read by
        :meth:`~metafovea.measurement.RadiometricCalibration.from_meta`) or the calibration itself.

    Returns
    -------
    tuple of 2 ndarray (K), or None
        None when ``meta`` holds no radiometric calibration.
    """
    cal = meta if isinstance(meta, RadiometricCalibration) else RadiometricCalibration.from_meta(meta)
    if cal is None:
        return None
    return cal.temperatures(scene_dn, offset)


def _foveal_surround(pb: Problem, s: np.ndarray, scale: float, ratio: float, join: bool = True,
                     perifoveal: np.ndarray | None = None) -> float:
    """Replace the foveal channel's padding (``pb.z[0]``) by what the perifoveal estimate ``s`` predicts there.

    The foveal field at focal-plane position ``p`` is the perifoveal one at ``p / scale`` (both channels share the
    focal-plane pitch), ``s_1 = ratio s_2`` (the channels' radiometric gains), blurred by the foveal PSF. Light the
    prediction cannot hold (the PSF's disks wider than the grid and its pedestal gather the scene far beyond it)
    adds a smooth field over the crop: the prediction is corrected by the quadratic surface fitted to the data less
    the prediction on the crop, so that the padding continues the data's level and slope.

    ``join=False``: the padding is that corrected prediction. ``join=True``: the prediction enters only below the
    perifoveal channel's Nyquist frequency, ``0.5 / scale`` cycles per foveal pixel, as its difference from the
    edge-extended data, zero on the crop and low-passed (a Gaussian of ``SURROUND_SIGMA_PER_SCALE x scale`` px, half
    power at that frequency): far out the padding is the prediction's low-pass, at the crop's edge it joins the
    data's edge values, which carry detail finer than the perifoveal channel resolves, but wrong detail where the
    scene has none finer than that. ``perifoveal`` (the crop, DN above the dark level): the perifoveal estimate
    to predict from in place of ``s``'s (a field patch's solve: the on-axis one's). Returns the surface's rms on
    the crop (DN).
    """
    from scipy.ndimage import gaussian_filter, map_coordinates

    g = pb.g
    P, Q = g.shape
    H, W = pb.zc.shape[1:]
    p = g.pad
    # grid index j -> foveal pixel j - p -> offset from the crop centre -> perifoveal pixel
    yy = ((np.arange(P) - p) - (H - 1) / 2) / scale + (H - 1) / 2
    xx = ((np.arange(Q) - p) - (W - 1) / 2) / scale + (W - 1) / 2
    s2 = s[1][g.crop] if perifoveal is None else perifoveal
    ext = ratio * map_coordinates(s2, np.meshgrid(yy, xx, indexing="ij"), order=1, mode="nearest")
    pred = g.irfft(g.D[0] * g.rfft(ext))
    # the smooth field the prediction lacks: a quadratic surface in the crop's normalised coordinates
    v, u = np.meshgrid((np.arange(P) - p - (H - 1) / 2) / H, (np.arange(Q) - p - (W - 1) / 2) / W, indexing="ij")
    basis = [np.ones_like(v), v, u, v * v, u * u, u * v]
    A = np.stack([b[g.crop].ravel() for b in basis], axis=1)
    coef = np.linalg.lstsq(A, (pb.zc[0] - pred[g.crop]).ravel(), rcond=None)[0]
    field = sum(c * b for c, b in zip(coef, basis))
    if join:
        edge = g.padded(pb.zc[0], pb.pad_mode)
        diff = pred + field - edge
        diff[g.crop] = 0.0
        z1 = edge + gaussian_filter(diff, SURROUND_SIGMA_PER_SCALE * scale, mode="wrap")
    else:
        z1 = pred + field
    z1[g.crop] = pb.zc[0]
    pb.z[0] = z1
    return float(np.sqrt(np.mean(field[g.crop] ** 2)))


def _surround_solve(pb: Problem, s: np.ndarray, prior_inv: np.ndarray, scale: float, ratio: float,
                    perifoveal: np.ndarray | None = None) -> tuple[np.ndarray, int, dict[str, Any]]:
    """Both forms of the foveal surround, each solved; the one whose solution explains the foveal data on the crop
    better is kept (``pb.z[0]`` left at it). Returns ``(s, CG iterations, info entries)``."""
    g = pb.g
    n_cg = 0
    cands = []
    for join in (True, False):
        smooth = _foveal_surround(pb, s, scale, ratio, join=join, perifoveal=perifoveal)
        s_j, n_j = linear_solve(pb, prior_inv, s)
        n_cg += n_j
        r = pb.zc[0] - g.irfft(g.D[0] * g.rfft(s_j[0]))[g.crop]
        cands.append((float(np.mean(r ** 2)), join, s_j, pb.z[0].copy(), smooth))
    res2, join, s, pb.z[0], smooth = min(cands, key=lambda c: c[0])
    surround = {"scale": scale, "gain_ratio": ratio, "form": "joined" if join else "prediction",
                "residual_dn2": res2, "other_form_residual_dn2": max(c[0] for c in cands)}
    if join:
        surround["joined_below_cycles_per_px"] = 0.5 / scale
    return s, n_cg, {"foveal_surround": surround, "foveal_surround_join": bool(join),
                     "foveal_surround_surface_rms_dn": smooth}


def _foveal_fusion(x: np.ndarray, scale: float, ratio: float,
                   noise: Sequence[np.ndarray]) -> tuple[np.ndarray, dict[str, Any]]:
    """Both channels' estimates combined where they image the same scene, eq. (5) of the module docstring.

    ``x``: both crops' estimates ``(2, H, W)``, DN above the dark level; ``noise``: draws of each estimate's noise,
    ``(S, H, W)`` each. On the grid of the foveal constraint (``A = D x_1``: the foveal estimate averaged over the
    perifoveal pixels it covers; ``B = ratio C x_2``: the perifoveal crop in the foveal channel's units), per ring
    ``k`` of frequency of that grid the weights

        w_1(k) = V_1(k) / E|A - B|^2(k),    w_2(k) = V_2(k) / E|A - B|^2(k),    clipped to [0, 1]               (5)

    move ``A`` towards ``B`` and ``B`` towards ``A``. ``w_1`` is the mean-square-optimal weight of ``B`` in
    ``A + w (B - A)`` when ``A``'s error is its noise alone (``V_1``: the foveal noise draws through ``D``) and
    independent of ``B``'s: ``E|A - B|^2`` is then ``V_1`` plus ``B``'s whole error (noise, blur, any error of the
    stated scale or gain ratio), so the weight falls wherever the two disagree by more than the foveal noise explains.
    Where ``A``'s error holds more than its noise (the shrinkage's bias), the optimal weight is larger: ``w_1`` errs
    low, never high. ``w_2`` is the same for ``B`` (its noise ``V_2``, the perifoveal draws through ``C``). The means
    (the ring at 0) are kept: each level is its own data's. The foveal correction ``w_1 (B - A)`` is spread back over
    the foveal pixels and low-passed as the surround's (``SURROUND_SIGMA_PER_SCALE``); the perifoveal one
    ``w_2 (A - B) / ratio`` is put back into the crop's pixels (the least-norm change that gives ``C x_2`` it). The
    rings are :data:`FUSION_RING_STEPS` frequency steps of that grid wide. Returns both estimates and the info entry.
    """
    from metafovea.reconstruct.operators import FovealOperator, lowpass

    H, W = x.shape[1:]
    if min(H, W) / scale < 2 * FUSION_RING_STEPS:  # fewer than two rings beside the mean
        return x, {"applied": False, "reason": f"a crop of {H} x {W} px holds fewer than {2 * FUSION_RING_STEPS} "
                                               f"perifoveal pixels of the fovea across at scale {scale:g}"}
    op = FovealOperator((H, W), scale)
    h, w = op.low_shape
    A = np.fft.fft2(op.D(x[0]))
    B = np.fft.fft2(ratio * op.C(x[1]))
    k = np.hypot(*np.meshgrid(np.fft.fftfreq(h), np.fft.fftfreq(w), indexing="ij"))
    width = FUSION_RING_STEPS / min(h, w)
    ring = np.minimum((k / width).astype(int), int(k.max() / width))
    n_rings = int(ring.max()) + 1

    def per_ring(power: np.ndarray) -> np.ndarray:
        return np.bincount(ring.ravel(), power.ravel(), n_rings)

    dd = np.maximum(per_ring(np.abs(A - B) ** 2), 1e-300)
    weights = []
    for draws in (op.D(noise[0]), ratio * op.C(noise[1])):
        wk = np.clip(per_ring(np.mean(np.abs(np.fft.fft2(draws)) ** 2, axis=0)) / dd, 0.0, 1.0)
        wk[0] = 0.0
        weights.append(wk)
    c1 = lowpass(op.upsample(np.real(np.fft.ifft2(weights[0][ring] * (B - A)))), SURROUND_SIGMA_PER_SCALE * scale)
    c2 = op.C_pinv(np.real(np.fft.ifft2(weights[1][ring] * (A - B))) / ratio)
    info = {"applied": True, "scale": scale, "gain_ratio": ratio, "grid": [h, w],
            "ring_cycles_per_sample": [float(width * (i + 0.5)) for i in range(n_rings)],
            "weights_x1": [float(v) for v in weights[0]], "weights_x2": [float(v) for v in weights[1]],
            "correction_rms_dn": [float(np.sqrt(np.mean(c ** 2))) for c in (c1, c2)]}
    return np.stack([x[0] + c1, x[1] + c2]), info


def _tv_step(pb: Problem, s: np.ndarray, tv_weight: float | None, iterations: int) -> tuple[np.ndarray,
                                                                                             dict[str, Any]]:
    """TV, eq. (3), from the Wiener estimate ``s``: the weights ``tv_weight / mean |grad s_i|`` on the crop."""
    cy, cx = pb.g.crop
    H, W = pb.zc.shape[1:]
    if min(H, W) < 2:  # no gradient in both directions: the weight's scale is undefined (it was NaN)
        raise InputError("frames", f"a crop of {H} x {W} px", "at least 2 x 2 px for method='tv' (its weight is the "
                         "scale of the image's gradients); 'wiener' or 'wavelet' take thinner crops")
    grad = [float(np.mean(np.hypot(np.diff(s[i][cy, cx], axis=0)[:, :-1], np.diff(s[i][cy, cx], axis=1)[:-1])))
            for i in range(2)]
    mult = 1.0 if tv_weight is None else float(tv_weight)
    if not (math.isfinite(mult) and mult > 0):
        raise InputError("tv_weight", tv_weight, "a multiplier > 0 of the automatic weight")
    lam = np.array([mult / max(gr, 1e-12) for gr in grad])
    s, its = tv_admm(pb, s, lam, iterations)
    return s, {"tv_weight": [float(v) for v in lam], "tv_weight_multiplier": mult, "admm_iterations": its}


def _wavelet_step(pb: Problem, C: np.ndarray, prior_inv: np.ndarray, surround: bool, wavelet: str,
                  noise_out: bool = False) -> tuple[np.ndarray, list[np.ndarray] | None, dict[str, Any]]:
    """The Fourier-wavelet estimate (:mod:`metafovea.reconstruct.wavelet`): per channel, the ``tau`` of
    :data:`~metafovea.reconstruct.wavelet.TAUS` whose shrunk estimate has the lowest estimated risk, eq. (2) there.

    ``surround``: the foveal channel's padding is the perifoveal channel's prediction, not its own edge values, so
    its noise draws are 0 there (the prediction's noise is the perifoveal estimate's, low-passed: neglected). The
    perifoveal channel's draws keep its edge values' noise (with ``boundary='solved'`` its padding is edge values
    beyond a ring of :data:`~metafovea.reconstruct.joint.EXTERIOR_PX`).
    With ``boundary='unknown'`` (no periodic data) the risk is eq. (2b) there: the prior's predicted bias plus SURE.
    Returns the crop's estimates ``(2, H, W)`` (DN above the dark level), with ``noise_out`` draws of each
    estimate's noise to first order (its noise draws at its ``tau`` through the shrinkage's Jacobian,
    ``(NOISE_SAMPLES, H, W)`` each; else None) and the info entries.
    """
    g = pb.g
    H, W = pb.zc.shape[1:]
    rng = np.random.default_rng(WAVELET_NOISE_SEED)
    chol = np.linalg.cholesky(C)
    periodic = pb.periodic
    filt = PeriodicFilter(pb, prior_inv)
    draws = []
    for _ in range(NOISE_SAMPLES):
        nk = np.einsum("ij,jhw->ihw", chol, rng.standard_normal((2, H, W)))
        if periodic:
            grid = np.stack([g.padded(nk[i], pb.pad_mode) for i in range(2)])
            if surround:
                grid[0] = 0.0
                grid[0][g.crop] = nk[0]
            draws.append(grid)
        else:
            draws.append(nk)
    levels = swt_levels((H, W))
    spec = B = grid_frame = risk_data = None
    if periodic:
        # the data and the noise draws through the filter: one right-hand side each, the same for every tau
        # (single precision for the solves: the estimate's rounding, ~1e-7 of its range, is far below its noise;
        # double for the risk, whose terms cancel)
        spec = g.rfft(np.stack([pb.z] + draws))
        B = filt.rhs(spec.astype(np.complex64))
        grid_frame = stationary_frame(g.shape, wavelet, levels)  # its |F_b(f)|^2 on the grid
        risk_data = filt.risk_data(spec[0], spec[1:], DETECTION_SNR)
    best: list[tuple[float, float, np.ndarray] | None] = [None, None]
    curve: list[list[dict[str, float]]] = [[], []]
    estimates: list[list[np.ndarray]] = [[], []]
    pre: list[list[tuple[np.ndarray, np.ndarray]]] = [[], []]  # each image and its noise draws before the shrinkage
    for tau in TAUS:
        if periodic:
            sol = g.irfft_crop(filt.solve(tau, B)).astype(np.float64)
            x, noise = sol[0], sol[1:]
        else:
            x = linear_solve(pb, tau * prior_inv, None)[0][:, g.crop[0], g.crop[1]]
            z0 = pb.z
            noise_list = []
            for nk in draws:
                pb.z = nk
                noise_list.append(linear_solve(pb, tau * prior_inv, None)[0][:, g.crop[0], g.crop[1]])
            pb.z = z0
            noise = np.stack(noise_list)
        parts = [shrink_linearised(x[i], noise[:, i], wavelet, levels) for i in range(2)]
        for i in range(2 if noise_out else 0):
            pre[i].append((x[i], noise[:, i]))
        if periodic:
            gain = np.stack([grid_frame.transfer(p[2]) for p in parts])  # type: ignore[union-attr]
            lin = filt.linear_risk(tau, gain, risk_data)
        else:
            lin = filt.bias2(tau)
        for i in range(2):
            est, sure, _, sure_lin = parts[i]
            # periodic: eq. (2) of metafovea.reconstruct.wavelet, the linearised estimate's risk (eq. 4 of joint)
            # plus what the non-linear shrinkage changes (SURE less its linear fit's SURE); else eq. (2b)
            risk = float(lin[i]) + (sure - sure_lin if periodic else sure)
            # the estimate's standard error: the spread over the noise draws of a mean of squared noise over the
            # crop (its spatial correlation included; for white noise of variance v it is v sqrt(2 / n))
            ms = np.mean(noise[:, i] ** 2, axis=(1, 2))
            se = float(max(np.std(ms, ddof=1), np.mean(ms) * math.sqrt(2.0 / (H * W))))
            curve[i].append({"tau": tau, "risk_dn2": risk, "linear_risk_dn2": float(lin[i]), "sure_dn2": sure,
                             "sure_linear_dn2": sure_lin, "standard_error_dn2": se})
            estimates[i].append(est)
    # the one-standard-error rule (Hastie, Tibshirani and Friedman, Elements of Statistical Learning, 7.10): the
    # most regularised tau (the largest: the Wiener filter at 1) whose risk is within one standard error of the
    # lowest; a smaller tau is taken only when the data say it is better by more than the estimate's noise
    for i in range(2):
        risks = [c["risk_dn2"] for c in curve[i]]
        k_min = int(np.argmin(risks))
        k = next(j for j in range(len(TAUS)) if risks[j] <= risks[k_min] + curve[i][k_min]["standard_error_dn2"])
        best[i] = (risks[k], TAUS[k], estimates[i][k])
    out = np.stack([b[2] for b in best])  # type: ignore[index]
    # each estimate's noise: its draws through the shrinkage's Jacobian at its tau (the foveal fusion's V_1, V_2)
    jac = [shrink_jacobian(*pre[i][TAUS.index(best[i][1])], wavelet, levels)  # type: ignore[index]
           for i in range(2)] if noise_out else None
    info = {"wavelet": wavelet, "wavelet_levels": levels, "noise_samples": NOISE_SAMPLES,
            "tau": [b[1] for b in best],  # type: ignore[index]
            # the criterion at the chosen tau, up to a constant of each channel (periodic): a ranking, not an error
            "risk_criterion_dn2": [b[0] for b in best],  # type: ignore[index]
            "risk_curve": {"x1": curve[0], "x2": curve[1]}}
    return out, jac, info


def _fit_priors(pb: Problem, C: np.ndarray, prior: str, scale: float,
                patch: PatchContext | None) -> list[tuple[np.ndarray, dict[str, Any]]]:
    """Each channel's scene spectrum on the solve's grid (:func:`fitted_spectrum`), through the on-axis kernels'
    OTFs for a field patch's solve (``patch.prior_psfs``, on the same grid)."""
    g = pb.g
    D_fit = g.D
    if patch is not None:
        gp = Grid(pb.zc.shape[1:], patch.prior_psfs.kernels, patch.prior_psfs.pedestals)
        if gp.shape != g.shape:
            raise InputError("patch", "on-axis kernels of other sizes", f"kernels padded as psfs' (grid {g.shape})")
        D_fit = gp.D
    return [fitted_spectrum(pb.zc[i], g.padded(pb.zc[i] - np.mean(pb.zc[i])), D_fit[i], C[i, i], prior, scale)
            for i in range(2)]


def _priors(pb: Problem, C: np.ndarray, prior: str, prior_scale: str, patch: PatchContext | None,
            info: dict[str, Any]) -> tuple[np.ndarray, list[tuple[np.ndarray, dict[str, Any]]]]:
    """Both channels' scene priors fitted on the crop and spread over the grid by ``prior_scale``
    (:data:`PRIOR_SCALES`); their radial profiles go into ``info``. Returns the inverse prior and the fits."""
    g = pb.g
    scale = _prior_scale_factor(prior_scale, pb.zc.shape[1:], g)
    fits = _fit_priors(pb, C, prior, scale, patch)
    radial = [radial_mean(g.f, f[0]) for f in fits]  # (ring centres, mean, counts) per channel
    info.update(prior_scale=prior_scale, prior_scale_factor=scale,
                prior_radial={"cycles_per_px": radial[0][0].tolist(),
                              "x1": radial[0][1].tolist(), "x2": radial[1][1].tolist()})
    return inverse_prior([f[0] for f in fits]), fits


def _prior_scale_factor(prior_scale: str, crop: tuple[int, int], g: Grid) -> float:
    """``prior_scale`` (:data:`PRIOR_SCALES`) as the factor on the crop's per-pixel spectrum for grid ``g``."""
    frac = crop[0] * crop[1] / float(g.shape[0] * g.shape[1])  # the crop's share of the grid
    return {"grid": 1.0, "crop": frac, "geometric": math.sqrt(frac)}[prior_scale]


def _solve_exterior(pb: Problem, C: np.ndarray, c: int, kernel: np.ndarray, prior_inv: np.ndarray,
                    options: tuple[str, str, int, int], current: tuple[np.ndarray, int]) -> tuple[np.ndarray, int,
                                                                                               dict[str, Any]]:
    """``boundary='solved'``: channel ``c``'s padding next to the crop (``pb.z[c]``, edge values; the perifoveal
    channel's) replaced by its data extended through the scene beyond the crop solved for
    (:func:`~metafovea.reconstruct.joint.solved_exterior`, its prior fitted as the full solve's on the ring's grid,
    the PSF's wide part from the edge-padded solve), where that explains the crop's data better. ``options``: prior,
    prior scale, ring width, iterations; ``current``: the Wiener solve on the edge values and its CG iterations.
    Returns the solve on the padding kept, the CG iterations and the info entry.

    Both paddings are hypotheses about the scene beyond the crop (it continues the crop's edge values; it is what
    the data near the edge say through the PSF's core): the solved one is kept when the channel's data within the
    ring's width of the crop's edge (where the ring's scene reaches through the core) misfit its solve by less than
    the edge values' solve, by more than the misfit's standard error there (``C_cc sqrt(2 / n)`` for ``n`` pixels of
    white noise: the one-standard-error rule, as for ``tau``); otherwise the edge values stay.
    """
    prior, prior_scale, width_px, iterations = options
    width_px = check_int("exterior_px", width_px, 1, 10_000)
    iterations = check_int("exterior_iterations", iterations, 0, 100_000)
    g, z = pb.g, pb.zc[c]
    before, n_before = current
    if min(width_px, kernel.shape[0] // 2, g.pad) < 1:  # a one-pixel PSF: nothing beyond the crop reaches it
        return before, n_before, {"channel": f"x{c + 1}", "width_px": 0, "kept": "padded", "why": (
            "the PSF is one pixel wide: no light from beyond the crop reaches it, the edge values kept")}

    def inverse_prior_on(gs: Grid) -> np.ndarray:
        spec, _ = fitted_spectrum(z, gs.padded(z - np.mean(z)), gs.D[c], C[c, c], prior,
                                  _prior_scale_factor(prior_scale, z.shape, gs))
        return inverse_prior([spec, spec])[c]

    kept_padding = pb.z[c].copy()
    pb.z[c], ex = solved_exterior(g, c, z, kernel, float(C[c, c]), inverse_prior_on, before[c], width_px,
                                  iterations, padding=kept_padding)
    solved, n_sol = linear_solve(pb, prior_inv, None)
    w = ex["width_px"]
    band = np.ones(z.shape, dtype=bool)
    band[w:-w, w:-w] = False
    misfit = [float(np.mean((z - g.irfft(g.D[c] * g.rfft(e[c]))[g.crop])[band] ** 2)) for e in (before, solved)]
    se = float(C[c, c]) * math.sqrt(2.0 / int(np.sum(band)))
    kept = misfit[0] - misfit[1] > se
    if not kept:
        pb.z[c] = kept_padding
    ex.update(kept="solved" if kept else "padded", edge_band_px=w,
              edge_misfit_dn2={"padded": misfit[0], "solved": misfit[1]}, misfit_standard_error_dn2=se)
    seen = (f"the scene beyond the crop seen through the PSF's core (radius {w} px, {100 * ex['core_power']:.0f} % of "
            f"its power), solved for in a ring of that width (masked data, {ex['iterations']} conjugate-gradient "
            "iterations, the PSF's wider part from the edge-padded solve)")
    ex["why"] = (f"{seen}: it explains the data within {w} px of the crop's edge better than the edge values (misfit "
                 f"{misfit[1]:.4g} against {misfit[0]:.4g} DN^2, standard error {se:.2g}), so it is kept, the edge "
                 "values beyond the ring" if kept else
                 f"{seen}: it does not explain the data within {w} px of the crop's edge better than the edge values "
                 f"by more than its standard error (misfit {misfit[1]:.4g} against {misfit[0]:.4g} DN^2, standard "
                 f"error {se:.2g}): the edge values kept")
    return (solved if kept else before), n_before + n_sol, {"channel": f"x{c + 1}", **ex}


def _linear_estimate(pb: Problem, C: np.ndarray, psfs: ChannelPSFs, prior_inv: np.ndarray, info: dict[str, Any],
                     exterior: tuple[str, str, int, int], foveal: tuple[float, float] | None,
                     patch: PatchContext | None) -> tuple[np.ndarray, int]:
    """The Wiener estimate of eq. (3) on the boundary asked (``pb.boundary``): the perifoveal exterior solved for
    (``'solved'``: ``exterior`` = prior, prior scale, ring width, iterations), then the foveal surround predicted
    (``foveal`` = scale, gain ratio; not with ``'unknown'``). Returns the estimate on the grid and the CG iterations;
    ``info`` gets what each step chose."""
    s, n_cg = linear_solve(pb, prior_inv, None)
    if pb.boundary == "solved":
        s, n_cg, info["exterior"] = _solve_exterior(pb, C, 1, psfs.kernels[1], prior_inv, exterior, (s, n_cg))
    if foveal is not None and pb.boundary != "unknown":
        s, n_sur, sur = _surround_solve(pb, s, prior_inv, *foveal, None if patch is None else patch.perifoveal_dn)
        n_cg += n_sur
        info.update(sur)
    return s, n_cg


def _shift_invariant_info(p: int) -> dict[str, Any]:
    """``info['field']`` of a shift-invariant solve: the PSFs have no field dependence, or it was left out."""
    if p > 1:
        return {"mode": "on-axis", "patches": p, "why": f"asked (field_psf='on-axis'): the PSFs' {p} x {p} field "
                "patches are left out (the shift-invariant approximation)"}
    return {"mode": "shift-invariant", "patches": 1, "why": "the PSFs carry no field dependence (no psf_patches_x1 "
            "/ psf_patches_x2)"}


def separate_deconvolve(frames: ArrayLike, alpha: ArrayLike, psfs: ChannelPSFs, *, method: str = DEFAULT_DECONVOLUTION,
                        offset: float = 0.0, sigma: float | None = None, iterations: int = 100,
                        tv_weight: float | None = None, meta: dict[str, Any] | RadiometricCalibration | None = None,
                        boundary: str = DEFAULT_BOUNDARY, pad_mode: str = "edge", prior: str = "hybrid",
                        foveal_scale: float | None = None, foveal_ratio: float = 1.0, fpn_error_dn: float = 0.0,
                        prior_scale: str = "geometric", wavelet: str = DEFAULT_WAVELET,
                        field_psf: str = "auto", patch: PatchContext | None = None,
                        foveal_fusion: bool = True, exterior_px: int = EXTERIOR_PX,
                        exterior_iterations: int = EXTERIOR_ITERATIONS) -> Deconvolution:
    """The scene radiance of both channels from their mixed frames and PSFs.

    Parameters
    ----------
    frames : array_like, shape (T, H, W)
        DN, fixed pattern removed; ``T >= 3``.
    alpha : array_like, shape (T,)
        Mixing ratios (known, or a solver's estimate).
    psfs : ChannelPSFs
        Both channels' PSFs on the pixel grid, pedestals and relative illumination.
    method : {'wavelet', 'wiener', 'tv'}
        The Fourier-wavelet estimate (:mod:`metafovea.reconstruct.wavelet`), eq. (2), or eq. (3) started from
        eq. (2); default :data:`DEFAULT_DECONVOLUTION`.
    offset : float
        The frames' dark level, DN.
    sigma : float, optional
        The frames' temporal noise, DN (default: from the residuals of the per-pixel fit).
    iterations : int
        ADMM iterations of ``'tv'``.
    tv_weight : float, optional
        A multiplier of the automatic TV weights ``1 / mean |grad s_i|``.
    meta : dict or RadiometricCalibration, optional
        A Measurement's metadata, for the temperatures (:func:`temperatures`).
    boundary : {'solved', 'padded', 'unknown'}
        The crop extended by its edge values (``pad_mode``), the foveal surround predicted, and with ``'solved'``
        (default) the perifoveal scene beyond the crop solved for in a ring of ``exterior_px`` at most
        ``exterior_iterations`` CG iterations (the module docstring; ``info['exterior']``); ``'unknown'``: solved
        for over the whole padding (slow). ``'mirror'``: deprecated spelling of ``'padded'``.
    pad_mode : str
        ``numpy.pad`` mode of the padding (``'edge'``).
    prior : {'hybrid', 'power-law', 'empirical'}
        The scene spectrum's model (:func:`metafovea.reconstruct.spectra.fitted_spectrum`).
    foveal_scale : float, optional
        The channels' scale f1 / f2: predict the foveal surround from the perifoveal estimate (``'padded'`` only).
    foveal_ratio : float
        ``s_1 / s_2`` of a uniform scene (the channels' radiometric gain ratio).
    fpn_error_dn : float
        The rms error (DN) of the fixed pattern already subtracted from ``frames`` (for calibration frames,
        :func:`metafovea.reconstruct.fpn.estimate_fpn`'s ``info['error_rms_dn']``): a static error that the frames
        do not average, counted in the noise model.
    prior_scale : {'geometric', 'grid', 'crop'}
        How the crop's per-pixel spectrum is spread over the padded grid (:data:`PRIOR_SCALES`).
    wavelet : {'haar', 'db2', 'sym4'}
        The wavelet of ``method='wavelet'`` (:data:`metafovea.reconstruct.wavelet.WAVELETS`).
    foveal_fusion : bool
        ``method='wavelet'`` with ``foveal_scale``: eq. (5) of the module docstring (``info['foveal_fusion']``).
    field_psf : {'auto', 'patches', 'on-axis'}
        A field-dependent PSF (``psfs.patches``): the patches the data need, every one, or none, blended
        (:mod:`metafovea.reconstruct.field`); ``info['field']`` says what was modelled and why.
    patch : PatchContext, optional
        A field patch's solve (:func:`~metafovea.reconstruct.field.field_deconvolve`): what it keeps of the on-axis.

    Returns
    -------
    Deconvolution
        ``info``: the noise (``sigma_dn``, ``sigma_source``, ``noise_std_dn``, ``noise_correlation``,
        ``fpn_error_dn``), the grid (``grid``, ``pad_px``, ``boundary``), each channel's prior fit (``prior_fit``),
        the prior radially averaged (``prior_radial``: per unnormalised bin of the padded grid, 64 rings of
        ``cycles_per_px``), the foveal surround (``foveal_surround``: scale, gain ratio, form and residuals;
        ``foveal_surround_join``, ``foveal_surround_surface_rms_dn``), ``tv_weight`` and ``admm_iterations`` for
        TV, for ``'wavelet'`` ``wavelet``, ``wavelet_levels``, ``noise_samples``, ``tau`` (per channel),
        ``risk_criterion_dn2`` and ``risk_curve`` (per channel: ``tau``, ``risk_dn2``, ``linear_risk_dn2``,
        ``sure_dn2``, ``sure_linear_dn2``; up to a constant per channel), ``cg_iterations`` and ``seconds``.

    Notes
    -----
    Eqs. (1)-(3) of the module docstring; the linear solves in :mod:`metafovea.reconstruct.joint`.

    References
    ----------
    See the module docstring, [1]_ to [3]_.
    """
    method = check_choice("method", method, DECONVOLUTION_METHODS)
    field_psf = check_choice("field_psf", field_psf, FIELD_MODES)
    if psfs.n_patches > 1 and field_psf != "on-axis":  # each patch shift-invariant (field.py)
        kw = dict(method=method, offset=offset, sigma=sigma, iterations=iterations, tv_weight=tv_weight, meta=meta,
                  boundary=boundary, pad_mode=pad_mode, prior=prior, foveal_scale=foveal_scale, wavelet=wavelet,
                  exterior_px=exterior_px, exterior_iterations=exterior_iterations, foveal_ratio=foveal_ratio,
                  fpn_error_dn=fpn_error_dn, prior_scale=prior_scale, field_psf="on-axis")
        res = field_deconvolve(psfs, lambda p, c: separate_deconvolve(frames, alpha, p, patch=c, **kw), field_psf,
                               offset, lambda sc: temperatures(sc, offset, meta))
        if method == "wavelet" and foveal_fusion and foveal_scale is not None:
            res.info.setdefault("foveal_fusion", dict(NO_FUSION_WITH_PATCHES))
        return res
    if field_psf == "patches":
        raise InputError("field_psf", field_psf, "'auto' or 'on-axis' for PSFs without psf_patches_x1 / _x2")
    wavelet = check_choice("wavelet", wavelet, WAVELETS)
    prior = check_choice("prior", prior, PRIORS)
    prior_scale = check_choice("prior_scale", prior_scale, PRIOR_SCALES)
    iterations = check_int("iterations", iterations, 1, 100_000)
    boundary = check_boundary(boundary)
    t0 = time.perf_counter()
    pb, C, info = prepare_problem(frames, alpha, psfs, offset, sigma, boundary, pad_mode, fpn_error_dn)
    prior_inv, fits = _priors(pb, C, prior, prior_scale, patch, info)
    s, n_cg = _linear_estimate(pb, C, psfs, prior_inv, info, (prior, prior_scale, exterior_px, exterior_iterations),
                               None if foveal_scale is None else (float(foveal_scale), float(foveal_ratio)), patch)
    info.update(method=method, prior=prior, prior_fit=[f[1] for f in fits], cg_iterations=n_cg)
    if method == "tv":
        s, tv_info = _tv_step(pb, s, tv_weight, iterations)
        info.update(tv_info)
    if method == "wavelet":
        fuse = foveal_fusion and foveal_scale is not None and patch is None
        crop, noise, w_info = _wavelet_step(pb, C, prior_inv, "foveal_surround" in info, wavelet, fuse)
        if fuse:
            crop, w_info["foveal_fusion"] = _foveal_fusion(crop, float(foveal_scale), float(foveal_ratio), noise)
        info.update(w_info)
        scene = (crop[0] + offset, crop[1] + offset)
    else:
        scene = (s[0][pb.g.crop] + offset, s[1][pb.g.crop] + offset)
    info.update(field=_shift_invariant_info(psfs.n_patches), seconds=time.perf_counter() - t0)
    return Deconvolution(scene, temperatures(scene, offset, meta), info)


def _frames_for(m: Measurement, fpn: ArrayLike | None) -> np.ndarray:
    """The frames in float64 with ``fpn`` (H, W) subtracted and the invalid samples (ADC range, bad pixels) set to
    their pixel's mean of valid samples."""
    fr = np.asarray(m.frames, dtype=np.float64)
    bad = m.invalid_samples()
    if bad is not None:
        fr = np.where(bad, np.nan, fr)
        mean = np.nanmean(fr, axis=0)
        fr = np.where(np.isnan(fr), np.where(np.isnan(mean), np.nanmean(mean), mean)[None], fr)
    if fpn is not None:
        f = np.asarray(fpn, dtype=np.float64)
        if f.shape != fr.shape[1:]:
            raise InputError("fpn", f"array of shape {f.shape}", f"the frames' (H, W) = {fr.shape[1:]}",
                             source=m.source)
        fr = fr - f
    return fr


def deconvolve_measurement(m: Measurement, *, alpha: ArrayLike | None = None, fpn: ArrayLike | None = None,
                           method: str = DEFAULT_DECONVOLUTION, psfs: ChannelPSFs | None = None,
                           score_truth: bool = True, refine_psf: str | Sequence[PSFFamily] | None = None,
                           **kw: Any) -> Deconvolution:
    """:func:`separate_deconvolve` of a static Measurement, scored against its scene truth when it has one.

    Parameters
    ----------
    m : Measurement
        A static sequence, frames ``(T, H, W)`` in DN. Samples outside the ADC range or on bad pixels are replaced
        by their pixel's mean; its dark level (:attr:`~metafovea.measurement.Measurement.dark_dn`), radiometric
        calibration and, when it states one, the channels' scale and gain ratio (the foveal surround) are used.
    alpha : array_like, shape (T,), optional
        Mixing ratios (default: the file's).
    fpn : array_like, shape (H, W), optional
        Fixed pattern to subtract, DN.
    method : {'wavelet', 'wiener', 'tv'}
    psfs : ChannelPSFs, optional
        Each channel's PSF on the pixel grid and relative illumination (default:
        :meth:`ChannelPSFs.from_measurement`).
    score_truth : bool
        With the file's scene truth (``scene_x1``, ``scene_x2``), ``info['scores']``:
        :func:`metafovea.reconstruct.metrics.score_deconvolution` (PSNR against the scene, the hazy images' and
        the Wiener bound's, brightness-temperature error).
    refine_psf : {'defocus', 'focal-length'} or sequence of PSFFamily, optional
        Refine the PSFs from the data first (:func:`metafovea.reconstruct.psf_refine.refine_measurement`: a family
        kind built for the paper's camera, or the families); ``info['psf_refinement']`` says what was chosen, by
        how much, and when a mismatch is likely. The Wiener bound is then computed with the refined PSFs.
    **kw
        Keywords of :func:`separate_deconvolve`.

    Returns
    -------
    Deconvolution
        ``scene`` ``(s_1, s_2)``, each ``(H, W)`` in DN; ``temperature_k`` their brightness temperatures (K) or
        None without a radiometric calibration; ``info`` (choices, timings, ``scores``).
    """
    a = m.alpha if alpha is None else alpha
    if a is None:
        raise InputError("alpha", None, "mixing ratios: the file's, or an unknown-alpha solver's estimate "
                         "(method=alternating first)", source=m.source)
    psfs = psfs or ChannelPSFs.from_measurement(m)
    offset = m.dark_dn
    frames = _frames_for(m, fpn)
    refined = None
    if refine_psf is not None:
        from metafovea.reconstruct.psf_refine import refine_measurement

        def wiener(p: ChannelPSFs) -> tuple[np.ndarray, np.ndarray]:  # the refinement's foveal-relation check
            return separate_deconvolve(frames, a, p, method="wiener", offset=offset, sigma=kw.get("sigma"),
                                       fpn_error_dn=kw.get("fpn_error_dn", 0.0)).scene

        refined = refine_measurement(m, frames, a, psfs, refine_psf, offset=offset, sigma=kw.get("sigma"),
                                     fpn_error_dn=kw.get("fpn_error_dn", 0.0), estimate=wiener)
        psfs = refined.psfs
    kw["boundary"] = check_boundary(kw.get("boundary", DEFAULT_BOUNDARY))
    if "foveal_scale" not in kw and m.recorded_scale:
        g1, g2 = m.channel_gains
        kw.update(foveal_scale=m.recorded_scale, foveal_ratio=g1 / g2)
    res = separate_deconvolve(frames, a, psfs, method=method, offset=offset, meta=m.radiometric_calibration, **kw)
    if refined is not None:
        res.info["psf_refinement"] = refined.summary()
    if score_truth and m.scene_truth is not None:
        res.info["scores"] = score_deconvolution(m, res.scene, res.temperature_k, frames=frames,
                                                 alpha=np.asarray(a, dtype=np.float64), psfs=psfs, offset=offset,
                                                 boundary=kw["boundary"], pad_mode=kw.get("pad_mode", "edge"), fpn=fpn)
    return res


def deconvolve_result(m: Measurement, res: PipelineResult, method: str = DEFAULT_DECONVOLUTION,
                      psf: str | Path | None = None, **kw: Any) -> Deconvolution:
    """The PSF-aware step after a reconstruction of ``m``.

    Parameters
    ----------
    m : Measurement
    res : PipelineResult
        The reconstruction: its alpha (the file's when it used them, else its estimate over the sequence, which
        must cover every frame) and its fixed pattern (and that pattern's estimated error) are used.
    method : {'wavelet', 'wiener', 'tv'}
    psf : str or Path, optional
        A PSF file (:meth:`ChannelPSFs.from_file`; default: the file's PSFs).
    **kw
        Keywords of :func:`deconvolve_measurement`.

    Returns
    -------
    Deconvolution
        As :func:`deconvolve_measurement`; ``info['alpha_from']`` says which alpha.
    """
    m = m.as_recording()  # the recording schema only (docs/measurement_format.md)
    rec = res.reconstruction
    alpha = rec.alpha_per_frame(m.shape[0])
    if not np.all(np.isfinite(alpha)):
        raise InputError("res", rec.method, f"a reconstruction whose alpha covers all {m.shape[0]} frames "
                         "(one window over all frames, or a stride that reaches every frame)")
    known = m.alpha is not None and bool(np.array_equal(alpha, np.asarray(m.alpha, dtype=np.float64)))
    psfs = ChannelPSFs.from_file(psf) if psf is not None else None
    err = ((rec.info or {}).get("fpn") or {}).get("error_rms_dn")
    if err is not None and "fpn_error_dn" not in kw:
        kw["fpn_error_dn"] = float(err)
    d = deconvolve_measurement(m, alpha=alpha, fpn=rec.fpn, method=method, psfs=psfs, **kw)
    d.info["alpha_from"] = "the file" if known else f"the {rec.method} estimate"
    return d

"""Scores against truth: image-quality metrics (PSNR, SSIM) on top of scikit-image, :func:`score` (the one scorer
of a reconstruction against the noise-free images: the CLI, ``validate`` and the benchmarks use it), and the
PSF-aware reconstruction against the scene with its reference, :func:`wiener_bound` (:func:`score_deconvolution`),
and the spread of a method's margins over that reference across cases (:func:`margin_summary`).

    PSNR = 10 log10(R^2 / mean((est - ref)^2)),    R = max(ref) - min(ref) unless given

SSIM: Z. Wang, A. C. Bovik, H. R. Sheikh and E. P. Simoncelli, IEEE Trans. Image Process. 13, 600 (2004), through
``skimage.metrics.structural_similarity``.
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.errors import InputError

if TYPE_CHECKING:
    from metafovea.measurement import Measurement
    from metafovea.reconstruct.joint import ChannelPSFs
    from metafovea.reconstruct.result import Reconstruction


def _pair(est: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    est = np.asarray(est, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    if est.shape != ref.shape:
        raise InputError("estimate", f"array of shape {est.shape}", f"the reference's shape {ref.shape}")
    return est, ref


def _data_range(ref: np.ndarray, data_range: float | None) -> float:
    if data_range is not None:
        return float(data_range)
    r = float(np.nanmax(ref) - np.nanmin(ref))
    return r if r > 0 else 1.0


def psnr(est: np.ndarray, ref: np.ndarray, data_range: float | None = None) -> float:
    """Peak signal-to-noise ratio (module docstring).

    Parameters
    ----------
    est, ref : array_like, same shape
        The estimate must be finite: a non-finite pixel is refused (:class:`InputError`; mask it first), since any
        floor reported for it would hide it.
    data_range : float, optional
        ``R``; default the reference's range (1 when it is flat).

    Returns
    -------
    float
        dB; ``inf`` for an exact estimate.
    """
    est, ref = _pair(est, ref)
    return float(_psnr_stack(est[None], ref[None], data_range)[0])


def ssim(est: np.ndarray, ref: np.ndarray, data_range: float | None = None) -> float:
    """Structural similarity (scikit-image, uniform 7 x 7 window, smaller for a smaller image).

    Parameters
    ----------
    est, ref : array_like, shape (H, W)
        The estimate must be finite.
    data_range : float, optional
        Default the reference's range.

    Returns
    -------
    float
    """
    from skimage.metrics import structural_similarity

    est, ref = _pair(est, ref)
    if not np.all(np.isfinite(est)):
        raise InputError("estimate", "array with NaN/inf", "finite values (mask invalid pixels first)")
    win = min(7, *(s if s % 2 else s - 1 for s in ref.shape[-2:]))
    return float(structural_similarity(ref, est, data_range=_data_range(ref, data_range), win_size=win))


def level_free_image(est: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """An estimate with its mean error against the reference removed: what is left when the alpha gauge or an
    offset is off.

    Parameters
    ----------
    est, ref : array_like, same shape

    Returns
    -------
    ndarray
        float64, ``est - mean(est - ref)``.
    """
    est, ref = _pair(est, ref)
    return est - float(np.mean(est - ref))


#: a video's SSIM is the mean over at most this many evenly spaced outputs (PSNR over all of them)
SSIM_MAX_OUTPUTS = 8


def _psnr_stack(ests: np.ndarray, refs: np.ndarray, data_range: float | None) -> np.ndarray:
    """PSNR (dB) of each ``ests[k]`` against ``refs[k]`` (same definition as :func:`psnr`), output by output in
    float64 without a float64 copy of the stack; a broadcast (static) reference's range computed once."""
    if not np.all(np.isfinite(ests)):
        raise InputError("estimate", "array with NaN/inf", "finite values (mask invalid pixels first)")
    static = refs.ndim == 3 and refs.strides[0] == 0
    out = np.empty(len(ests))
    dr = None
    for k in range(len(ests)):
        r = refs[k]
        d = np.subtract(ests[k], r, dtype=np.float64)
        mse = float(np.mean(d * d))
        if dr is None or not static:
            dr = _data_range(r, data_range)
        out[k] = 10 * np.log10(dr * dr / mse) if mse > 0 else np.inf
    return out


def score(rec: Reconstruction | tuple[ArrayLike, ArrayLike], truth_x1: np.ndarray | None = None,
          truth_x2: np.ndarray | None = None, data_range: float | None = None, *,
          level_free: bool = False) -> dict[str, float]:
    """PSNR and SSIM of a reconstruction against the noise-free images: the one scorer.

    Parameters
    ----------
    rec : Reconstruction or tuple of 2 array_like
        ``x1``, ``x2``: ``(H, W)`` or, for a video, ``(K, H, W)`` (scored output by output and averaged).
    truth_x1, truth_x2 : array_like, shape (H, W) or (K, H, W), optional
        One image, or one per output; None skips that image.
    data_range : float, optional
        Default: each reference's own range.
    level_free : bool
        Add ``psnr_x1_level_free`` / ``psnr_x2_level_free``: the PSNR after removing the mean error
        (:func:`level_free_image`).

    Returns
    -------
    dict
        ``psnr_x1``, ``ssim_x1``, ``psnr_x2``, ``ssim_x2`` for the images scored.

    Notes
    -----
    A video's PSNR is the mean over every output, its SSIM over :data:`SSIM_MAX_OUTPUTS` evenly spaced ones
    (SSIM costs ~10 ms per 290 x 290 image, the LSQ solve ~0.2 ms).
    """
    x1, x2 = (rec.x1, rec.x2) if hasattr(rec, "x1") else rec
    out: dict[str, float] = {}
    for name, est, ref in (("x1", x1, truth_x1), ("x2", x2, truth_x2)):
        if ref is None:
            continue
        est = np.asarray(est)
        ests = est if est.ndim == 3 else est[None]
        ref = np.asarray(ref)
        if ref.ndim == 3:
            if ref.shape != ests.shape:
                raise InputError(f"truth_{name}", f"array of shape {ref.shape}",
                                 f"one reference per output, shape {ests.shape} (or one (H, W) image)")
            refs = ref
        elif ref.shape == ests.shape[-2:]:
            refs = np.broadcast_to(ref, ests.shape)
        else:
            raise InputError(f"truth_{name}", f"array of shape {ref.shape}", f"the estimate's shape {ests.shape[-2:]}")
        if ests.shape != refs.shape:
            raise InputError("estimate", f"array of shape {ests.shape}", f"the reference's shape {refs.shape}")
        out[f"psnr_{name}"] = float(np.mean(_psnr_stack(ests, refs, data_range)))
        pick = np.unique(np.linspace(0, len(ests) - 1, min(len(ests), SSIM_MAX_OUTPUTS)).round().astype(int))
        out[f"ssim_{name}"] = float(np.mean([ssim(ests[k], refs[k], data_range) for k in pick]))
        if level_free:
            e64 = ests.astype(np.float64)
            lf = e64 - np.mean(e64 - refs, axis=(-2, -1), keepdims=True)
            out[f"psnr_{name}_level_free"] = float(np.mean(_psnr_stack(lf, refs, data_range)))
    return out


# -- the PSF-aware reconstruction against the scene -------------------------------------------------------------
def wiener_bound(frames: ArrayLike, alpha: ArrayLike, psfs: ChannelPSFs, truth: tuple[ArrayLike, ArrayLike], *,
                 offset: float = 0.0, sigma: float, boundary: str = "padded", pad_mode: str = "edge",
                 fpn_error_dn: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The best stationary linear reconstruction: the reference of
    :func:`~metafovea.reconstruct.deconvolve.separate_deconvolve`.

    Parameters
    ----------
    frames : array_like, shape (T, H, W)
        DN, fixed pattern removed.
    alpha : array_like, shape (T,)
        Mixing ratios.
    psfs : ChannelPSFs
        The true PSFs.
    truth : tuple of 2 array_like, shape (H, W)
        Both channels' scene images, DN (a perfect lens' images).
    offset : float
        The dark level, DN.
    sigma : float
        The frames' true temporal noise, DN. With ``fpn_error_dn`` the noise model, raised like the estimate's to the
        data's flat excess where a likelihood ratio shows one (:func:`~metafovea.reconstruct.spectra.noise_floor`):
        what the data hold beyond the stated truth (the ADC's rounding, a kernel error the stored PSF lacks) is noise
        to any linear estimate, the best one included.
    boundary : {'padded', 'unknown'}
        As :func:`~metafovea.reconstruct.deconvolve.separate_deconvolve` (``'mirror'``: deprecated ``'padded'``).
    pad_mode : str
        ``numpy.pad`` mode of the padding.
    fpn_error_dn : float
        The true rms error (DN) of the subtracted fixed pattern, counted as noise.

    Returns
    -------
    tuple of 2 ndarray, shape (H, W)
        Both channels' estimates, DN.

    Notes
    -----
    The joint Wiener estimate, eq. (2) of :mod:`metafovea.reconstruct.deconvolve`, with the true scene's power
    spectrum in place of the fitted one: each channel's truth padded with its own edge values, its periodogram on the
    grid averaged over :data:`~metafovea.reconstruct.spectra.TRUTH_RADIAL_BINS` rings. It is a reference, not a limit
    that a non-linear or a joint-boundary method (the foveal surround) obeys.
    """
    from metafovea.reconstruct.joint import check_boundary, linear_solve, prepare_problem
    from metafovea.reconstruct.spectra import TRUTH_RADIAL_BINS, inverse_prior, radial_field, radial_mean

    boundary = check_boundary(boundary)
    pb, _, _ = prepare_problem(frames, alpha, psfs, offset, sigma, boundary, pad_mode, fpn_error_dn)
    g = pb.g
    spectra = []
    for t in truth:
        st = g.rfft(g.padded(np.asarray(t, dtype=np.float64) - offset))
        spectra.append(radial_field(g.f, radial_mean(g.f, np.abs(st) ** 2, TRUTH_RADIAL_BINS)[1]))
    s, _ = linear_solve(pb, inverse_prior(spectra), None)
    return s[0][g.crop] + offset, s[1][g.crop] + offset


def true_fpn_error_dn(m: Measurement, fpn: ArrayLike | None) -> float:
    """The rms error of a fixed pattern against the file's true one, means removed.

    Parameters
    ----------
    m : Measurement
        With the true pattern ``fpn`` (else the error is 0).
    fpn : array_like, shape (H, W), or None
        The pattern subtracted (None: nothing subtracted).

    Returns
    -------
    float
        DN rms; the patterns' means are removed (the mean of a pattern is the dark level's, not identifiable).
    """
    if m.fpn is None:
        return 0.0
    t = np.asarray(m.fpn, dtype=np.float64)
    e = -(t - t.mean()) if fpn is None else (np.asarray(fpn, np.float64) - np.mean(fpn)) - (t - t.mean())
    return float(np.sqrt(np.mean(e ** 2)))


def score_deconvolution(m: Measurement, scene: tuple[np.ndarray, np.ndarray],
                        temperature_k: tuple[np.ndarray, np.ndarray] | None, *, frames: np.ndarray,
                        alpha: np.ndarray, psfs: ChannelPSFs, offset: float, boundary: str = "padded",
                        pad_mode: str = "edge", fpn: ArrayLike | None = None) -> dict[str, Any]:
    """A PSF-aware reconstruction of ``m`` against its scene truth, beside the hazy images and the Wiener bound.

    Parameters
    ----------
    m : Measurement
        With :attr:`~metafovea.measurement.Measurement.scene_truth`.
    scene : tuple of 2 ndarray, shape (H, W)
        The estimates, DN.
    temperature_k : tuple of 2 ndarray, or None
        Their brightness temperatures, K.
    frames : ndarray, shape (T, H, W)
        The frames the estimate was made from (``fpn`` subtracted), DN.
    alpha : ndarray, shape (T,)
    psfs : ChannelPSFs
    offset : float
        The dark level, DN.
    boundary, pad_mode : str
        As the estimate's.
    fpn : array_like, shape (H, W), optional
        The subtracted pattern (its true error: :func:`true_fpn_error_dn`).

    Returns
    -------
    dict
        ``against`` (``'scene'``); ``psnr_x1``, ``psnr_x2`` (dB, the truth's range as data range);
        ``psnr_x*_hazy_image``: the file's noise-free sensor images against the same scene; with a radiometric
        calibration ``temperature_rmse_x*_k``; with the file's true noise (:attr:`~metafovea.measurement.
        Measurement.true_noise_dn`) ``wiener_bound_psnr_x*``, ``wiener_bound_seconds`` and
        ``wiener_bound_fpn_error_dn``.

    Notes
    -----
    The bound (:func:`wiener_bound`) is computed with and without the subtracted pattern's true error counted as
    noise, and the better of the two is reported per channel: the error is low-rank stripes, not the white noise
    the linear model assumes, so counting it can lose.
    """
    truth = tuple(np.asarray(t, np.float64) for t in m.scene_truth)
    out: dict[str, Any] = {"against": "scene"}
    for i, t in enumerate(truth, start=1):
        out[f"psnr_x{i}"] = psnr(scene[i - 1], t)
        hz = getattr(m, f"truth_x{i}")
        if hz is not None and np.ndim(hz) == 2:
            out[f"psnr_x{i}_hazy_image"] = psnr(np.asarray(hz, np.float64), t)
    cal = m.radiometric_calibration
    if cal is not None and temperature_k is not None:
        tt = cal.temperatures(truth, offset)
        for i in (1, 2):
            e = temperature_k[i - 1] - tt[i - 1]
            out[f"temperature_rmse_x{i}_k"] = float(np.sqrt(np.nanmean(e ** 2)))
    sig = m.true_noise_dn
    if sig is not None and sig > 0:
        t0 = time.perf_counter()
        fe = true_fpn_error_dn(m, fpn)
        best = [-math.inf, -math.inf]
        for e in ((0.0, fe) if fe > 0 else (0.0,)):
            def bound(p: ChannelPSFs, e: float = e) -> tuple[np.ndarray, np.ndarray]:
                return wiener_bound(frames, alpha, p, truth, offset=offset, sigma=sig, boundary=boundary,
                                    pad_mode=pad_mode, fpn_error_dn=e)

            if psfs.n_patches > 1:  # a field-dependent PSF: the bound sectioned like the estimate
                from metafovea.reconstruct.field import blend_patches

                wb = blend_patches(psfs, bound)
                out["wiener_bound_psf"] = f"sectioned: {psfs.n_patches} x {psfs.n_patches} patches' kernels, blended"
            else:
                wb = bound(psfs)
            best = [max(best[i], psnr(wb[i], truth[i])) for i in range(2)]
        out.update(wiener_bound_psnr_x1=best[0], wiener_bound_psnr_x2=best[1],
                   wiener_bound_seconds=time.perf_counter() - t0, wiener_bound_fpn_error_dn=fe)
    return out


def margin_summary(margins_db: ArrayLike) -> dict[str, float]:
    """How a method's PSNR margins over a reference (the Wiener bound) are spread over a set of cases.

    Parameters
    ----------
    margins_db : array_like, shape (N,)
        ``PSNR(method) - PSNR(reference)`` per case, dB; at least one, all finite.

    Returns
    -------
    dict
        ``cases`` (N), ``at_or_above`` (the fraction of cases with a margin >= 0), ``worst_db``, ``median_db``.
    """
    m = np.asarray(margins_db, dtype=np.float64).ravel()
    if m.size == 0 or not np.all(np.isfinite(m)):
        raise InputError("margins_db", f"{m.size} values" if m.size else "none", "at least one, all finite")
    return {"cases": int(m.size), "at_or_above": float(np.mean(m >= 0)), "worst_db": float(m.min()),
            "median_db": float(np.median(m))}

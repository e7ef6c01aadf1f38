"""Image-quality metrics (PSNR, SSIM) on top of scikit-image, and :func:`score`, the one scorer of a
reconstruction against truth (the CLI, ``validate`` and the benchmarks use it)."""

from __future__ import annotations

from typing import Any

import numpy as np

from metafovea.errors import InputError


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
    """Peak signal-to-noise ratio in dB (``data_range`` defaults to the reference's range).

    Non-finite estimate pixels count as errors (the result is ``-inf`` dB... reported as 0 dB floor
    would hide them), so they are refused: mask them before calling.
    """
    est, ref = _pair(est, ref)
    return float(_psnr_stack(est[None], ref[None], data_range)[0])


def ssim(est: np.ndarray, ref: np.ndarray, data_range: float | None = None) -> float:
    """Structural similarity (scikit-image, Gaussian-free default 7x7 window)."""
    from skimage.metrics import structural_similarity

    est, ref = _pair(est, ref)
    if not np.all(np.isfinite(est)):
        raise InputError("estimate", "array with NaN/inf", "finite values (mask invalid pixels first)")
    win = min(7, *(s if s % 2 else s - 1 for s in ref.shape[-2:]))
    return float(structural_similarity(ref, est, data_range=_data_range(ref, data_range), win_size=win))


def level_free_image(est: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """``est`` with its mean error against ``ref`` removed (float64): what is left when the alpha gauge or an offset
    is off."""
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


def score(rec: Any, truth_x1: np.ndarray | None = None, truth_x2: np.ndarray | None = None,
          data_range: float | None = None, *, level_free: bool = False) -> dict[str, float]:
    """PSNR/SSIM of a :class:`~metafovea.reconstruct.Reconstruction` (or ``(x1, x2)`` tuple) against
    truth; a video (``(K, H, W)``) is scored window by window and averaged (PSNR over every output, SSIM over
    :data:`SSIM_MAX_OUTPUTS` evenly spaced ones: SSIM costs ~10 ms per 290 x 290 image, the solve ~0.2 ms).

    ``truth_x*``: one ``(H, W)`` image, or one per output ``(K, H, W)``; ``None`` skips that image.
    ``data_range`` defaults to each reference's own range. ``level_free`` adds ``psnr_x1_level_free`` /
    ``psnr_x2_level_free``: the PSNR after removing the mean error (see :func:`level_free_image`)."""
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

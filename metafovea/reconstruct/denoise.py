"""Denoisers for reconstructed images (scikit-image based).

Every method takes the noise std ``sigma`` of the image it cleans (the LSQ stage knows it: frame noise
times the channel's noise gain), so weights follow a stated rule instead of a hand-tuned constant:

* ``'tv'``: Chambolle total variation, weight ``0.75 sigma``, 20 iterations. Measured (``benchmarks/bench_denoise.py``
  and a grid of factors 0.5-2 x iterations 10-100 on 5 images x sigma 0.01-0.05, 160 x 160): the previous
  ``0.5 sigma``, 10 iterations was 0.59 dB below the best factor on average and 5.4 dB at worst (a smooth image at
  sigma 0.05); 0.75 sigma, 20 iterations is 0.32 dB on average and 1.0 dB at worst (~5 ms), but 0.8-1.5 dB below
  the best factor on textured images it was not chosen on (text, brick, grass: they want 0.5). NLM is the better
  choice for texture and thermal images. A per-image choice by
  Stein's unbiased risk (Monte-Carlo divergence) was tried and dropped: with one or two probes its estimate was
  erratic (up to 4 dB lost), with enough probes it costs 15x the denoising.
* ``'bilateral'``: as in the paper; colour sigma ``2 sigma``, spatial sigma 1.5 px (~35 ms): 1-10 dB below TV and
  NLM on every image measured, kept for comparison with the paper.
* ``'nlm'``: non-local means (fast mode, patch 5, distance 5, h = sigma: 0.19 dB below its best h on average,
  0.6 at worst; 0.8 sigma was 1.5 at worst): the best PSNR of these on textured and thermal images (up to +4 dB
  over TV on the blurred thermal star) at ~8x the cost of TV.
"""

from __future__ import annotations

import numpy as np

from metafovea.errors import InputError, as_float, check_choice
from metafovea.reconstruct._common import estimate_noise

#: the denoisers (``--denoise``)
DENOISERS = ("tv", "bilateral", "nlm")
METHODS = DENOISERS + ("none",)
#: TV weight = TV_FACTOR x sigma, TV_ITERATIONS iterations (measured, see the module docstring); TV_FACTORS: the grid
TV_FACTOR = 0.75
TV_FACTORS = (0.5, 0.75, 1.0, 1.5, 2.0)
TV_ITERATIONS = 20


def denoise(x: np.ndarray, method: str = "tv", *, sigma: float | None = None, weight: float | None = None,
            iterations: int = TV_ITERATIONS) -> np.ndarray:
    """Denoise a 2-D image (or each image of a ``(K, H, W)`` stack); dtype preserved.

    ``sigma`` is the noise std (estimated from the image when ``None``); ``weight`` overrides the
    method's strength rule.
    """
    method = check_choice("denoise", method, METHODS)
    x = np.asarray(x)
    if method == "none":
        return x
    if x.ndim == 3:
        return np.stack([denoise(xi, method, sigma=sigma, weight=weight, iterations=iterations) for xi in x])
    if x.ndim != 2:
        raise InputError("x", f"array of shape {x.shape}", "a 2-D image or a (K, H, W) stack")
    bad = ~np.isfinite(x)
    if bad.all():
        raise InputError("image to denoise", "no finite pixel", "an image with finite pixels")
    if bad.any():
        # unresolved pixels (e.g. dead ones the masked LSQ leaves NaN): denoise with them filled from their
        # nearest finite neighbour, so that they do not spread, and leave them NaN in the result
        from scipy.ndimage import distance_transform_edt

        idx = distance_transform_edt(bad, return_distances=False, return_indices=True)
        out = denoise(x[tuple(idx)], method, sigma=sigma, weight=weight, iterations=iterations)
        out[bad] = np.nan
        return out
    if sigma is None:
        sigma = estimate_noise(x)
    sigma = as_float("sigma", sigma)
    if sigma <= 0:
        return x
    dt = x.dtype
    if method == "tv":
        from skimage.restoration import denoise_tv_chambolle

        w = TV_FACTOR * sigma if weight is None else as_float("weight", weight)
        out = denoise_tv_chambolle(x, weight=w, max_num_iter=int(iterations))
    elif method == "bilateral":
        from skimage.restoration import denoise_bilateral

        lo = float(x.min())
        out = denoise_bilateral(x - lo, sigma_color=2 * sigma if weight is None else weight,
                                sigma_spatial=1.5) + lo
    else:
        from skimage.restoration import denoise_nl_means

        h = 1.0 * sigma if weight is None else as_float("weight", weight)
        out = denoise_nl_means(x, h=h, sigma=sigma, patch_size=5, patch_distance=5, fast_mode=True)
    return np.asarray(out, dtype=dt)

"""Denoisers for reconstructed images (scikit-image based).

Every method takes the noise std ``sigma`` of the image it cleans (the LSQ stage knows it: frame noise times the
channel's noise gain; otherwise estimated from the image, :func:`~metafovea.reconstruct._common.estimate_noise`),
so its strength follows a stated rule instead of a hand-tuned constant:

* ``'tv'``: Chambolle's total variation [1]_, weight ``TV_FACTOR sigma``, ``TV_ITERATIONS`` iterations; the
  factor was chosen on a grid (:data:`TV_FACTORS`) over test images and noise levels;
* ``'bilateral'``: as in the paper; colour sigma ``2 sigma``, spatial sigma 1.5 px (kept for comparison with the
  paper);
* ``'nlm'``: non-local means [2]_ (fast mode, patch 5, distance 5, ``h = sigma``): the better choice for texture
  and thermal images, at several times TV's cost.

Measured figures: BENCHMARKS.md, section "Denoising".

References
----------
.. [1] A. Chambolle, "An algorithm for total variation minimization and applications", J. Math. Imaging Vis. 20,
   89 (2004).
.. [2] A. Buades, B. Coll and J.-M. Morel, "A non-local algorithm for image denoising", CVPR (2005) 60.
"""

from __future__ import annotations

import numpy as np

from metafovea.errors import InputError, as_float, check_choice
from metafovea.reconstruct._common import estimate_noise

#: the denoisers (``--denoise``)
DENOISERS = ("tv", "bilateral", "nlm")
METHODS = DENOISERS + ("none",)
#: TV weight = TV_FACTOR x sigma, TV_ITERATIONS iterations (chosen on the grid TV_FACTORS: BENCHMARKS.md, "Denoising")
TV_FACTOR = 0.75
TV_FACTORS = (0.5, 0.75, 1.0, 1.5, 2.0)
TV_ITERATIONS = 20


def denoise(x: np.ndarray, method: str = "tv", *, sigma: float | None = None, weight: float | None = None,
            iterations: int = TV_ITERATIONS) -> np.ndarray:
    """Denoise a 2-D image, or each image of a stack.

    Parameters
    ----------
    x : ndarray, shape (H, W) or (K, H, W)
        Non-finite pixels are filled from their nearest finite neighbour for the denoiser and left NaN.
    method : {'tv', 'bilateral', 'nlm', 'none'}
    sigma : float, optional
        The image's noise std (default: estimated from the image); ``<= 0`` returns ``x``.
    weight : float, optional
        Overrides the method's strength rule (TV weight, bilateral colour sigma, NLM ``h``).
    iterations : int
        TV iterations.

    Returns
    -------
    ndarray
        Same shape and dtype as ``x``.
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

"""Denoisers for reconstructed images (scikit-image based).

Every method takes the noise std ``sigma`` of the image it cleans (the LSQ stage knows it: frame noise times the
channel's noise gain; otherwise estimated from the image, :func:`~metafovea.reconstruct._common.estimate_noise`),
so its strength follows a stated rule instead of a hand-tuned constant:

* ``'tv'``: Chambolle's total variation [1]_, weight ``TV_FACTOR sigma`` (the factor chosen on a grid,
  :data:`TV_FACTORS`, over test images and noise levels), ``TV_ITERATIONS`` iterations, kept only where Stein's
  unbiased risk estimate says it lowers the error (else a weaker weight, else none: :func:`_tv_sure`);
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
#: SURE's check of the TV weight (:func:`_tv_sure`): the weaker weight tried (a fraction of the rule's), the
#: Monte-Carlo probe's step (a fraction of sigma) and its seed
SURE_FALLBACK = 0.3
SURE_PROBE = 0.01
SURE_SEED = 20081


def _tv_sure(x: np.ndarray, sigma: float, iterations: int) -> np.ndarray:
    """TV at the first weight of ``TV_FACTOR sigma``, then :data:`SURE_FALLBACK` times it, whose Stein unbiased risk
    estimate beats leaving the image as it is (risk ``N sigma^2``); the image itself when none does.

    ``SURE(w) = ||f_w(x) - x||^2 - N sigma^2 + 2 sigma^2 div f_w(x)`` is an unbiased estimate of the squared error
    of ``f_w(x)`` against the noise-free image for white Gaussian noise of std ``sigma`` (Stein 1981); the
    divergence is estimated by one Monte-Carlo probe (Ramani, Blu and Unser 2008). A denoiser thus never costs,
    in expectation, more than the noise it removes: on a textured image whose detail TV would flatten it is
    weakened or skipped."""
    from skimage.restoration import denoise_tv_chambolle

    xd = x.astype(np.float64)
    n = xd.size
    rng = np.random.default_rng(SURE_SEED)  # a fixed probe: the same image gives the same result
    b = rng.standard_normal(xd.shape)
    eps = SURE_PROBE * sigma
    for w in (TV_FACTOR * sigma, SURE_FALLBACK * TV_FACTOR * sigma):
        o = denoise_tv_chambolle(xd, weight=w, max_num_iter=iterations)
        div = float(np.sum(b * (denoise_tv_chambolle(xd + eps * b, weight=w, max_num_iter=iterations) - o))) / eps
        sure = float(np.sum((o - xd) ** 2)) - n * sigma ** 2 + 2 * sigma ** 2 * div
        if sure < n * sigma ** 2:
            return o
    return xd


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

        if weight is not None:
            out = denoise_tv_chambolle(x, weight=as_float("weight", weight), max_num_iter=int(iterations))
        else:
            out = _tv_sure(x, sigma, int(iterations))
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

"""Synthetic scenes and measurements for tests and benchmarks.

:func:`scene` makes a foveal/perifoveal pair from scikit-image's bundled images with the foveal
constraint ``D x1 == C x2`` holding exactly (the centre crop of ``x2`` is replaced by the downsampled
``x1``); :func:`measure` mixes them as the sensor does.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, DTypeLike

from metafovea.config import PAPER_FRAME_RATE_HZ
from metafovea.errors import InputError, as_rng, check_int
from metafovea.polarizer import RotatingPolarizer
from metafovea.reconstruct._common import as_alpha
from metafovea.reconstruct.operators import FovealOperator


def gray_image(name: str) -> np.ndarray:
    """A scikit-image bundled picture as a grey image.

    Parameters
    ----------
    name : str
        A function of ``skimage.data`` (``'camera'``, ``'astronaut'``, ...).

    Returns
    -------
    ndarray
        float64 in [0, 1].
    """
    from skimage import color, data

    img = getattr(data, name)()
    if img.ndim == 3:
        img = color.rgb2gray(img[..., :3])
    img = img.astype(np.float64)
    return (img - img.min()) / max(img.max() - img.min(), 1e-12)


def _fit(img: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    from skimage.transform import resize

    H, W = shape
    h, w = img.shape
    s = min(h / H, w / W)
    ch, cw = int(round(H * s)), int(round(W * s))
    y0, x0 = (h - ch) // 2, (w - cw) // 2
    return resize(img[y0:y0 + ch, x0:x0 + cw], shape, order=1, anti_aliasing=True)


def scene(shape: tuple[int, int] | int = 96, scale: float = 6.0, *, offset: tuple[float, float] = (0.0, 0.0),
          foveal: str = "camera", perifoveal: str = "astronaut", lo: float = 0.0, hi: float = 1.0,
          foveal_gain: float = 1.0, foveal_offset: float = 0.0,
          dtype: DTypeLike = np.float64) -> tuple[np.ndarray, np.ndarray]:
    """A foveal/perifoveal pair for which the foveal constraint holds exactly.

    Parameters
    ----------
    shape : int or tuple of 2 int
    scale : float
    offset : tuple of 2 float
        The crop's offset in x2 pixels.
    foveal, perifoveal : str
        scikit-image pictures (:func:`gray_image`).
    lo, hi : float
        ``x1``'s range; ``x2`` spans ``[(lo - b) / g, (hi - b) / g]`` outside its centre crop.
    foveal_gain, foveal_offset : float
        ``g`` and ``b``.
    dtype : dtype

    Returns
    -------
    x1, x2 : ndarray, shape (H, W)
        ``D x1 == g C x2 + b`` exactly: ``x2``'s centre crop is replaced through ``C``'s pseudo-inverse.
    """
    if isinstance(shape, (int, np.integer)):
        shape = (int(shape), int(shape))
    H, W = (check_int("shape", v, 8, 8192) for v in shape)
    g, b = float(foveal_gain), float(foveal_offset)
    if not g > 0:
        raise InputError("foveal_gain", foveal_gain, "a positive gain")
    x1 = lo + (hi - lo) * _fit(gray_image(foveal), (H, W))
    lo2, hi2 = (lo - b) / g, (hi - b) / g  # x2's range in its own units
    x2 = lo2 + (hi2 - lo2) * _fit(gray_image(perifoveal), (H, W))
    op = FovealOperator((H, W), scale, offset, gain=foveal_gain, bias=foveal_offset)
    # replace C x2 by (D x1 - b) / g: x2 += C^+ ((D x1 - b) / g - C x2), C^+ the pseudo-inverse (exact for any offset)
    r = (op.D(x1) - op.bias) / op.gain - op.C(x2)
    x2 = x2 + op.C_pinv(r)
    return x1.astype(dtype), x2.astype(dtype)


def polariser_alpha(n: int, *, rate_hz: float = 2.0, fps: float = PAPER_FRAME_RATE_HZ, phase: float = 0.3,
                    start: int = 0) -> np.ndarray:
    """The reference anchors' polariser.

    Parameters
    ----------
    n : int
        Frames.
    rate_hz, fps, phase : float
    start : int
        The first frame's index.

    Returns
    -------
    ndarray, shape (n,)
        ``alpha_t = cos^2(2 pi rate t / fps + phase)``
        (:class:`~metafovea.polarizer.RotatingPolarizer`, ideal and instantaneous).
    """
    t = np.arange(start, start + n, dtype=np.float64)
    theta = 2 * np.pi * rate_hz * t / fps + phase  # in frame units, in this order: the anchors' alphas to the bit
    return RotatingPolarizer(rate_hz).nominal_alpha(theta)


def measure(x1: np.ndarray, x2: np.ndarray, alpha: ArrayLike, *, sigma: float = 0.01, fpn: np.ndarray | None = None,
            rng: np.random.Generator | int | None = None, dtype: DTypeLike = None) -> np.ndarray:
    """Mix two images as the sensor does.

    Parameters
    ----------
    x1, x2 : ndarray, shape (H, W)
    alpha : array_like, shape (T,)
    sigma : float
        White noise std.
    fpn : ndarray, shape (H, W), optional
    rng : int or numpy.random.Generator
    dtype : dtype, optional
        Default ``x1``'s.

    Returns
    -------
    ndarray, shape (T, H, W)
        ``alpha_t x1 + (1 - alpha_t) x2 + fpn + N(0, sigma^2)``.
    """
    rng = as_rng(rng)
    a = as_alpha(alpha, np.size(alpha))
    if x1.shape != x2.shape:
        raise InputError("x2", f"array of shape {x2.shape}", f"x1's shape {x1.shape}")
    y = a[:, None, None] * x1[None] + (1 - a)[:, None, None] * x2[None]
    if fpn is not None:
        y = y + fpn[None]
    if sigma > 0:
        y = y + rng.normal(0.0, sigma, size=y.shape)
    return y.astype(dtype or x1.dtype)


def lowrank_fpn(shape: tuple[int, int], *, rank: int = 3, amplitude: float = 0.05,
                rng: np.random.Generator | int | None = None) -> np.ndarray:
    """A zero-mean, low-rank fixed pattern: column offsets (readout stripes) plus ``rank - 1`` outer products.

    Parameters
    ----------
    shape : tuple of 2 int
    rank : int
    amplitude : float
        ``max |fpn|``.
    rng : int or numpy.random.Generator

    Returns
    -------
    ndarray, shape (H, W)
    """
    rng = as_rng(rng)
    H, W = shape
    f = np.zeros(shape)
    f += rng.normal(size=(1, W))  # column offsets (the usual readout stripes)
    for _ in range(max(rank - 1, 0)):
        f += 0.5 * np.outer(rng.normal(size=H), rng.normal(size=W)) / 2
    f -= f.mean()
    return amplitude * f / np.abs(f).max()

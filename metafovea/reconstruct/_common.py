"""Shared helpers of the reconstruction stage: input validation, options with keyword overrides, the noise
estimator, timers."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

import numpy as np
from numpy.typing import ArrayLike

from metafovea.errors import InputError, as_float

#: methods of the PSF-aware step (:func:`metafovea.reconstruct.deconvolve.separate_deconvolve`), named here so that
#: the command line lists them without loading that step
DECONVOLUTION_METHODS = ("tv", "wavelet", "wiener")
#: the method :func:`~metafovea.reconstruct.deconvolve.separate_deconvolve` (and ``metafovea reconstruct
#: --deconvolve`` without a name) runs: the Fourier-wavelet estimate, chosen over the linear one on the scene
#: generator's tuning seeds (BENCHMARKS.md, "PSF-aware reconstruction on scenes never seen"); ``'wiener'`` is the
#: fast linear alternative
DEFAULT_DECONVOLUTION = "wavelet"
#: frames per window of :func:`~metafovea.reconstruct.reconstruct_measurement` unless told; a sequence shorter than
#: SHORT_SEQUENCE frames is one window of all its frames (importable from ``metafovea.reconstruct.api`` as well)
DEFAULT_WINDOW = 8
SHORT_SEQUENCE = 2 * DEFAULT_WINDOW
#: frames of the unknown-alpha pipeline's calibration pass (the first ones): 24 frames are 2 s, four turns of the
#: paper's polariser
CALIBRATION_FRAMES = 24

O = TypeVar("O")


def image_dtype(a: np.ndarray) -> np.dtype:
    """float32 stays float32; everything else computes in float64."""
    return np.dtype(np.float32) if a.dtype == np.float32 else np.dtype(np.float64)


def as_frames(frames: ArrayLike, *, min_frames: int = 1, name: str = "frames") -> np.ndarray:
    """Validate a frame stack and return it as a float ``(T, H, W)`` array (float32 preserved).

    A list of 2-D arrays is stacked (all must have one shape); a single 2-D frame becomes ``T = 1``.
    NaN/inf values are *not* refused here (solvers mask them); non-numeric input is.
    """
    if isinstance(frames, (list, tuple)):
        if len(frames) == 0:
            raise InputError(name, "[]", "a non-empty sequence of 2-D frames")
        arrs = [np.asarray(f) for f in frames]
        shapes = sorted({a.shape for a in arrs})
        if len(shapes) != 1:
            raise InputError(name, f"frames of shapes {shapes}", "frames that all have the same (H, W) shape")
        if arrs[0].ndim != 2:
            raise InputError(name, f"frames of shape {shapes[0]}", "a sequence of 2-D (H, W) frames")
        frames = np.stack(arrs)
    a = np.asarray(frames)
    if a.dtype == object or not (np.issubdtype(a.dtype, np.number) or a.dtype == np.bool_):
        raise InputError(name, f"array of dtype {a.dtype}", "a numeric array")
    if np.iscomplexobj(a):
        raise InputError(name, f"array of dtype {a.dtype}", "a real-valued array")
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3:
        raise InputError(name, f"array of shape {a.shape}", "an array of shape (T, H, W) or (H, W)")
    if a.shape[1] < 2 or a.shape[2] < 2:
        raise InputError(name, f"array of shape {a.shape}", "frames at least 2 x 2 pixels")
    if a.shape[0] < min_frames:
        raise InputError(name, f"{a.shape[0]} frame(s)", f"at least {min_frames} frames")
    if a.dtype not in (np.float32, np.float64):
        a = a.astype(np.float64)
    return a


def as_alpha(alpha: ArrayLike, n: int, *, name: str = "alpha", tol: float = 1e-6) -> np.ndarray:
    """Mixing ratios ``(T,)`` in [0, 1] (float64), one per frame."""
    if np.iscomplexobj(alpha) or (isinstance(alpha, np.ndarray) and alpha.dtype == bool):
        raise InputError(name, f"array of dtype {np.asarray(alpha).dtype}", "real numbers in [0, 1]")
    try:
        a = np.asarray(alpha, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(name, alpha, "a sequence of real numbers in [0, 1]") from None
    if a.ndim == 0:
        a = np.full(n, float(a))
    if a.ndim != 1 or a.shape[0] != n:
        raise InputError(name, f"array of shape {a.shape}", f"one value per frame, shape ({n},)")
    if not np.all(np.isfinite(a)):
        raise InputError(name, a.tolist(), "finite values in [0, 1]")
    if a.min() < -tol or a.max() > 1 + tol:
        raise InputError(name, [round(float(v), 6) for v in a], "values in [0, 1] (alpha = cos^2 theta)")
    return np.clip(a, 0.0, 1.0)


def valid_mask(frames: np.ndarray, saturation: float | None = None) -> np.ndarray | None:
    """Boolean ``(T, H, W)`` mask of usable samples, or ``None`` when every sample is usable."""
    bad = ~np.isfinite(frames)
    if saturation is not None:
        saturation = as_float("saturation", saturation)
        with np.errstate(invalid="ignore"):
            bad |= frames >= saturation
    if not bad.any():
        return None
    return ~bad


class Timings(dict):
    """A dict of named wall-clock durations in seconds, filled by :meth:`measure`."""

    @contextmanager
    def measure(self, name: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self[name] = self.get(name, 0.0) + (time.perf_counter() - t0)


#: the foveal constraint's keywords, which the pipeline hands every solver and the known-alpha ones do not use
GEOMETRY_KEYWORDS = ("scale", "foveal_gain", "foveal_offset")


def check_keywords(kw: dict[str, Any], allowed: Any, where: str) -> None:
    """Refuse the first keyword of ``kw`` not in ``allowed`` (a typo such as ``windw=4``), naming ``where`` and what
    it takes."""
    for k, v in kw.items():
        if k not in allowed:
            takes = ", ".join(sorted(allowed)) or "no further keywords"
            raise InputError(k, v, f"a keyword that {where} takes ({takes})")


def with_overrides(cls: type[O], options: O | None, overrides: dict[str, Any]) -> O:
    """``options`` (default ``cls()``) with the fields named in ``overrides`` replaced; an unknown name is an
    :class:`InputError` that lists the known ones (the solvers' keyword arguments are these fields)."""
    import dataclasses

    opt = cls() if options is None else options
    if not isinstance(opt, cls):
        raise InputError("options", type(opt).__name__, f"a {cls.__name__}")
    if not overrides:
        return opt
    fields = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    bad = sorted(set(overrides) - fields)
    if bad:
        raise InputError("option", bad[0], f"a field of {cls.__name__}: " + ", ".join(sorted(fields)))
    return dataclasses.replace(opt, **overrides)  # type: ignore[type-var]


def estimate_noise(img: np.ndarray) -> float:
    """Gaussian noise std of one image (Immerkaer 1996, fast Laplacian-difference estimator)."""
    from scipy.signal import convolve2d

    x = np.asarray(img, dtype=np.float64)
    if x.shape[0] < 3 or x.shape[1] < 3 or not np.all(np.isfinite(x)):
        x = np.nan_to_num(x)
    k = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], dtype=np.float64)
    r = convolve2d(x, k, mode="valid")
    return float(np.sqrt(np.pi / 2) * np.abs(r).sum() / (6.0 * r.size))

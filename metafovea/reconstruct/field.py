"""A field-dependent PSF in the PSF-aware reconstruction: solved patch by patch and blended.

Off axis a metalens' PSF spreads and loses light from its kernel window (coma and astigmatism of the hyperbolic
phase; the perifoveal lens' corners at 10 um keep ~3/4 of the on-axis light in the window). A camera that states
it (the Measurement format's ``psf_patches_x*``, a ``p x p`` grid of kernels at the centres of equal patches of the
crop, as ``metafovea simulate --field-patches`` renders it) images, per channel ``i``,

    u_i = sum_j w_j (K_ij * s_i)                                                                        (1)

with ``w_j`` the bilinear patch weights (:func:`metafovea.measurement.patch_weights`, a partition of unity). The
estimate is sectioned (Trussell and Hunt [1]_): the shift-invariant estimate ``s_ij`` with patch ``j``'s kernels
over the whole crop (both channels together, as the joint solve needs), blended with the same weights,

    s_i = sum_j w_j s_ij                                                                                (2)

exact where one patch's weight is 1, between neighbouring centres the interpolation of two estimates each made
for the PSF at its own centre; every ``s_ij`` sees the whole crop, so no patch has a boundary of its own. Each
patch's solve keeps two things of the on-axis solve (:class:`PatchContext`): the scene's spectrum, fitted through
the on-axis kernels, and the perifoveal estimate from which the foveal surround is predicted (the perifoveal
channel's centre, which a corner patch's kernels image wrong).

What is modelled is chosen from the data (``field_psf='auto'``): the on-axis estimate ``s_0`` first; patch ``j``'s
kernels change the data it predicts by ``d_ij = (K_ij - K_i0) * s_0i`` (the separated channel, illumination divided
out), and channel ``i`` takes patch ``j``'s own solve only where the rms of ``d_ij`` under the patch's weight exceeds
:data:`FIELD_NOISE_SHARE` of that channel's noise; elsewhere the on-axis estimate, whose model error there is below
that share of the noise (an independent error of half the noise adds at most 12 % to it). ``field_psf='patches'``
solves every patch, ``'on-axis'`` none (the shift-invariant approximation: the output says so).

Constants: :data:`FIELD_NOISE_SHARE` is :data:`metafovea.imaging.kernels.KERNEL_NOISE_SHARE`, the share of the
noise a kernel's own error may reach in the simulator, for the same reason; :data:`MAX_THREADS` (memory: each solve
holds a few hundred MB at the paper's crop). The patches are solved on threads, the same numbers as one by one.

References
----------
.. [1] H. J. Trussell and B. R. Hunt, "Sectioned methods for image restoration", IEEE Trans. Acoust., Speech,
   Signal Process. 26(2), 157-164 (1978).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from metafovea.errors import InputError, check_choice, check_int
from metafovea.imaging.kernels import KERNEL_NOISE_SHARE
from metafovea.measurement import patch_weights

if TYPE_CHECKING:
    from metafovea.reconstruct.deconvolve import Deconvolution
    from metafovea.reconstruct.joint import ChannelPSFs

__all__ = ["FIELD_MODES", "FIELD_NOISE_SHARE", "MAX_THREADS", "PatchContext", "blend_patches", "field_deconvolve",
           "model_change"]

#: ``field``: ``'auto'`` (the patches the data need), ``'patches'`` (every patch), ``'on-axis'`` (none)
FIELD_MODES = ("auto", "patches", "on-axis")
#: a patch is solved when its kernels change the predicted data by more than this share of the noise (rms)
FIELD_NOISE_SHARE = KERNEL_NOISE_SHARE
#: threads of the patches' solves at most: each holds a few hundred MB at the paper's 290 px crop (a grid padded by
#: the 581 px haze kernel); two threads on two cores: 27 -> 21 s for eight wavelet solves, the same numbers
MAX_THREADS = 4


@dataclass(frozen=True)
class PatchContext:
    """What a patch's shift-invariant solve takes from the on-axis one (:func:`field_deconvolve`).

    Attributes
    ----------
    prior_psfs : ChannelPSFs
        The on-axis kernels, through which the scene's spectrum is fitted: through a patch's kernels over the
        whole crop, data that a narrower kernel made elsewhere look like a scene of far more detail.
    perifoveal_dn : ndarray, shape (H, W)
        The perifoveal estimate (DN above the dark level) that predicts the foveal surround: the surround is the
        perifoveal channel's centre, which the on-axis solve images right and a corner patch's solve does not.
    """

    prior_psfs: ChannelPSFs
    perifoveal_dn: np.ndarray


def _weights(p: int, shape: tuple[int, int]) -> list[list[np.ndarray]]:
    wy, wx = patch_weights(p, shape[0]), patch_weights(p, shape[1])
    return [[np.outer(wy[i], wx[j]) for j in range(p)] for i in range(p)]


def _conv_same(img: np.ndarray, k: np.ndarray) -> np.ndarray:
    """``k * img`` on the crop, the crop extended by its edge values (the padding of the joint solve)."""
    from scipy.signal import fftconvolve  # scipy.signal takes ~0.6 s to import: only field-dependent PSFs need it

    h = k.shape[0] // 2
    return fftconvolve(np.pad(img, h, mode="edge"), k, mode="valid")


def _blend(p: int, image_of: Callable[[int, int], tuple[np.ndarray, np.ndarray]]) -> list[np.ndarray]:
    """Eq. (2): ``sum_j w_j image_of(j)`` per channel, the patches in row-major order."""
    out: list[np.ndarray] = []
    for i in range(p):
        for j in range(p):
            e = image_of(i, j)
            if not out:
                out = [np.zeros(np.shape(e[0])), np.zeros(np.shape(e[1]))]
                w = _weights(p, out[0].shape)
            for c in range(2):
                out[c] += w[i][j] * np.asarray(e[c], dtype=np.float64)
    return out


def blend_patches(psfs: ChannelPSFs, estimate: Callable[[ChannelPSFs], tuple[np.ndarray, np.ndarray]]
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (2) with every patch: ``sum_j w_j estimate(psfs.patch(j))`` per channel (a shift-invariant ``estimate``
    made sectioned, e.g. the Wiener bound's)."""
    b = _blend(psfs.n_patches, lambda i, j: estimate(psfs.patch(i, j)))
    return b[0], b[1]


def model_change(psfs: ChannelPSFs, scene: tuple[np.ndarray, np.ndarray], offset: float,
                 noise_std_dn: tuple[float, float]) -> np.ndarray:
    """How much each patch's kernels change the data of ``scene``, over the noise: ``(p, p, 2)``.

    Parameters
    ----------
    psfs : ChannelPSFs
        With a field-dependent PSF (``psfs.n_patches > 1``).
    scene : tuple of 2 ndarray, shape (H, W)
        Both channels' estimates (DN, the dark level included) with the on-axis kernels.
    offset : float
        The dark level, DN.
    noise_std_dn : tuple of 2 float
        The separated channels' noise (DN, illumination divided out: ``info['noise_std_dn']``).

    Returns
    -------
    ndarray, shape (p, p, 2)
        rms of ``(K_ij - K_i0) * s_i`` under patch ``j``'s weight, over channel ``i``'s noise.
    """
    p = psfs.n_patches
    H, W = scene[0].shape
    w = _weights(p, (H, W))
    out = np.zeros((p, p, 2))
    k0 = psfs.on_axis().kernels  # on the patches' common size, as psfs.patch's
    for i in range(p):
        for j in range(p):
            kj = psfs.patch(i, j).kernels
            for c in range(2):
                dk = kj[c] - k0[c]
                if psfs.patches[c] is None or not np.any(dk):
                    continue
                d = _conv_same(np.asarray(scene[c], dtype=np.float64) - offset, dk)
                rms = math.sqrt(float(np.sum(w[i][j] * d ** 2) / np.sum(w[i][j])))
                out[i, j, c] = rms / max(float(noise_std_dn[c]), 1e-300)
    return out


def _solve_all(solve: Callable[[ChannelPSFs, PatchContext | None], Deconvolution], patches: list[ChannelPSFs],
               ctx: PatchContext, workers: int) -> list[Deconvolution]:
    """``solve(patch, ctx)`` of every patch, in order, on ``workers`` threads (NumPy and SciPy's FFTs release the
    GIL; a Ctrl-C stops the running solves: :class:`metafovea.parallel.StoppableThreadPool`)."""
    if workers <= 1 or len(patches) <= 1:
        return [solve(q, ctx) for q in patches]
    from metafovea.parallel import StoppableThreadPool

    with StoppableThreadPool(min(workers, len(patches)), "metafovea-field") as pool:
        futures = [pool.submit(solve, q, ctx) for q in patches]
        return [f.result() for f in futures]


def field_deconvolve(psfs: ChannelPSFs, solve: Callable[[ChannelPSFs, PatchContext | None], Deconvolution], mode: str,
                     offset: float, temperatures: Callable[[tuple[np.ndarray, np.ndarray]], Any],
                     workers: int | None = None) -> Deconvolution:
    """Eq. (2): the shift-invariant ``solve`` per patch the data need, blended.

    Parameters
    ----------
    psfs : ChannelPSFs
        With a field-dependent PSF (``psfs.n_patches > 1``).
    solve : callable
        ``solve(ChannelPSFs, PatchContext or None) -> Deconvolution``: the shift-invariant reconstruction with the
        given kernels (the context None for the on-axis solve).
    mode : {'auto', 'patches'}
        Which patches are solved (module docstring; ``field_psf`` of
        :func:`~metafovea.reconstruct.deconvolve.separate_deconvolve`).
    offset : float
        The dark level, DN.
    temperatures : callable
        Scene (DN) to brightness temperatures (or None), for the blended scene.
    workers : int, optional
        Threads the patches' solves run on (default one per core, at most :data:`MAX_THREADS`).

    Returns
    -------
    Deconvolution
        The on-axis solve's ``info`` with ``field``: ``mode``, ``patches`` (p), ``solved`` (``[i, j, channels]``:
        the patches solved with their own kernels and the channels that take that solve), ``change_over_noise``
        (p, p, 2) and ``why``; ``seconds`` the whole; with ``boundary='solved'``, ``exterior`` gets
        ``kept_per_patch`` (``'i,j'`` -> ``'solved'`` or ``'padded'``, each patch's own choice) and says it.
    """
    mode = check_choice("field_psf", mode, FIELD_MODES[:2])
    p = psfs.n_patches
    if p < 2:
        raise InputError("field_psf", mode, "PSFs with a field dependence (psf_patches_x1 / psf_patches_x2)")
    t0 = time.perf_counter()
    axis = psfs.on_axis()
    base = solve(axis, None)
    ctx = PatchContext(axis, np.asarray(base.scene[1], dtype=np.float64) - offset)
    change = model_change(psfs, base.scene, offset, tuple(base.info["noise_std_dn"]))  # type: ignore[arg-type]
    # per patch and channel: its own kernels where they change the channel's data beyond the share of the noise
    # (the joint solve of a patch uses both channels' kernels; a channel whose kernels barely change keeps the
    # on-axis estimate there)
    need = (change > FIELD_NOISE_SHARE) if mode == "auto" else (change > 0)
    todo = [(i, j) for i in range(p) for j in range(p) if np.any(need[i, j])]
    n_threads = min(MAX_THREADS, os.cpu_count() or 1) if workers is None else check_int("workers", workers, 1, 64)
    results = dict(zip(todo, _solve_all(solve, [psfs.patch(i, j) for i, j in todo], ctx, n_threads)))
    solved = [[i, j, [c + 1 for c in range(2) if need[i, j, c]]] for i, j in todo]
    taus = {f"{i},{j}": r.info["tau"] for (i, j), r in results.items() if "tau" in r.info}
    scene = _blend(p, lambda i, j: tuple((results[i, j] if need[i, j, c] else base).scene[c] for c in range(2)))
    # a channel no patch changed is the on-axis estimate itself (the weights' sum is 1 only to rounding)
    blended = tuple(scene[c] if need[..., c].any() else np.asarray(base.scene[c], dtype=np.float64)
                    for c in range(2))
    worst = float(change.max())
    n_need = len(solved)
    if mode == "patches":
        why = f"asked (field_psf='patches'): all {p} x {p} patches with their own kernels"
    elif n_need:
        why = (f"{n_need} of {p * p} patches' kernels change the predicted data by more than {FIELD_NOISE_SHARE:g} x "
               f"the noise (up to {worst:.3g} x): solved with their own kernels, the others on axis")
    else:
        why = (f"no patch's kernels change the predicted data by more than {FIELD_NOISE_SHARE:g} x the noise "
               f"(up to {worst:.3g} x): the on-axis kernels everywhere")
    info = dict(base.info)
    kept = {f"{i},{j}": r.info["exterior"]["kept"] for (i, j), r in results.items() if "exterior" in r.info}
    if kept and "exterior" in info:  # each patch's solve chose its own padding beyond the perifoveal crop
        ex = info["exterior"]
        n_solved = sum(k == "solved" for k in kept.values())
        info["exterior"] = {**ex, "kept_per_patch": kept, "why": (
            f"{ex['why']} (the on-axis solve; of the {len(kept)} patches solved with their own kernels, "
            f"{n_solved} kept the solved ring and {len(kept) - n_solved} the edge values, each by the same test)")}
    info["field"] = {"mode": f"{p} x {p} patches" if n_need else "on-axis (field variation below the noise)",
                     "patches": p, "solved": solved, "change_over_noise": change.round(4).tolist(), "why": why,
                     **({"tau_per_patch": taus} if taus else {})}
    info["seconds"] = time.perf_counter() - t0
    return type(base)(blended, temperatures(blended), info)

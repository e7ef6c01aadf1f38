"""Video: sliding windows over a whole sequence, and the real-time known-alpha path.

:func:`video` reconstructs every window ``frames[k*stride : k*stride + window]``. With known alpha
and ``method='lsq'`` each window is two ``(window,) @ (window, H*W)`` BLAS calls into preallocated,
contiguous ``x1`` and ``x2`` stacks (the per-window weights ``N^-1 A^T`` are computed once per window from the
scalars), which is the throughput path. For a live camera use :class:`~metafovea.reconstruct.lsq.SlidingLSQ`, which
updates running sums frame by frame.

Unknown alpha with a polariser model (``method='alternating'``): each window fixes alpha's gauge (the affine map
from its data-term alpha to the absolute one) by fitting the polariser model to its own frames. Where the rotation
is irregular (a jittering polariser: each window follows its frames' own alpha), a short window's fit rests on a few
frames whose jitter it cannot average out (an 8-frame window at 12 frames/s and 2 Hz samples alpha at three phases
only). The gauge belongs to the recording, not to the window: windows that share frames must give those frames the
same alpha, so their gauges are chained through the shared frames (an affine map fitted on them, at least
:data:`POOL_MIN_SHARED`) into one common gauge, the polariser model is fitted once to every frame of the chain, and
each window's alpha and images are mapped to that fit (:func:`_pooled_gauge`; ``info['gauge_pooled']``).

Measured figures: BENCHMARKS.md, sections "Reconstruction" and "`metafovea reconstruct` file to file".
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.errors import InputError, check_choice, check_int
from metafovea.parallel import progress_iter
from metafovea.reconstruct._common import (
    GEOMETRY_KEYWORDS,
    Timings,
    as_alpha,
    as_frames,
    check_keywords,
    image_dtype,
    valid_mask,
)
from metafovea.reconstruct.denoise import denoise as denoise_image
from metafovea.reconstruct.lsq import MAX_CONDITION, lsq_known_alpha, residual_sigma, solve_weights
from metafovea.reconstruct.result import Reconstruction

log = logging.getLogger(__name__)

#: the frames two windows must share for their gauges to be chained: two fix the affine map between them, one more
#: checks it
POOL_MIN_SHARED = 3


def window_starts(n_frames: int, window: int, stride: int, starts: Sequence[int] | None = None) -> np.ndarray:
    """The first frame of each window.

    Parameters
    ----------
    n_frames, window, stride : int
    starts : sequence of int, optional
        Given starts (checked to fit the sequence); default every ``stride``-th frame.

    Returns
    -------
    ndarray of int, shape (K,)
    """
    window = check_int("window", window, 2, 1_000_000)
    stride = check_int("stride", stride, 1, 1_000_000)
    if window > n_frames:
        raise InputError("window", window, f"2 <= window <= number of frames ({n_frames})")
    if starts is None:
        return np.arange(0, n_frames - window + 1, stride)
    out = np.array([check_int("starts", s, 0, n_frames - window) for s in np.atleast_1d(starts)], dtype=int)
    if out.size == 0:
        raise InputError("starts", list(starts), f"at least one window start in 0..{n_frames - window}")
    return out


def _lsq_windows(Y: np.ndarray, a: np.ndarray, starts: np.ndarray, window: int, it: Iterable[int], M: np.ndarray | None,
                 max_condition: float, regularize: str | float | None,
                 saturation: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Known-alpha LSQ of every window: ``(x1 (K, H*W), x2 (K, H*W), condition (K,))``.

    Each image is one ``(window,) @ (window, H*W)`` product of the window's weights (float32 for float32
    frames) written straight into its row of a C-contiguous stack, which :meth:`Reconstruction.save` then writes
    without a copy. Running sums (one frame in and one out per window) were slower here: the product reads a few
    frames that stay in cache (BENCHMARKS.md, "`metafovea reconstruct` file to file").
    """
    T, H, W = Y.shape
    dt = image_dtype(Y)
    x1 = np.empty((len(starts), H * W), dtype=dt)
    x2 = np.empty((len(starts), H * W), dtype=dt)
    conds = np.empty(len(starts))
    Yf = Y.reshape(T, -1)
    for k in it:
        s = starts[k]
        try:
            Wt, rep = solve_weights(a[s:s + window], max_condition=max_condition, regularize=regularize, quiet=True)
        except InputError as e:
            raise _in_window(e, k, s, window, "alpha") from None
        conds[k] = rep["condition"]
        if M is None:
            Wt = Wt.astype(dt)
            np.matmul(Wt[0], Yf[s:s + window], out=x1[k])
            np.matmul(Wt[1], Yf[s:s + window], out=x2[k])
        else:
            r = lsq_known_alpha(Y[s:s + window], a[s:s + window], max_condition=max_condition,
                                regularize=regularize, saturation=saturation)
            x1[k], x2[k] = r.x1.ravel(), r.x2.ravel()
    return x1, x2, conds


def _in_window(e: InputError, k: int, s: int, window: int, parameter: str = "frames") -> InputError:
    """``e`` (raised by a window's solver) placed in window ``k`` (frames ``s`` to ``s + window - 1``): one message,
    the window in the value when ``e`` is about ``parameter`` (``frames``: the window is the value), else in the
    detail."""
    where = f"window {k} (frames {s}..{s + window - 1})"
    if e.parameter == parameter:
        value = where if parameter == "frames" else f"{where}: {e.value}"
        return InputError(parameter, value, e.allowed, source=e.source, detail=e.detail)
    return InputError(e.parameter, e.value, e.allowed, source=e.source,
                      detail=where if not e.detail else f"{where}: {e.detail}")


def _dip_window(dip: Callable[..., Reconstruction], Y: np.ndarray, alpha: ArrayLike | None, kw: dict[str, Any], s: int,
                window: int, max_seconds: float | None) -> Reconstruction:
    """The DIP of the window of frames ``s`` to ``s + window - 1``, with ``max_seconds`` of the run's time budget
    (what is left of it over the windows left; at least a step)."""
    pol = kw.get("polarizer")
    wkw = {**kw, "polarizer": pol.window(s, window)} if pol is not None else dict(kw)
    if max_seconds is not None:
        wkw["max_seconds"] = max(float(max_seconds), 1e-3)
    return dip(Y[s:s + window], alpha=None if alpha is None else np.asarray(alpha)[s:s + window], **wkw)


def _chain(aw: list, starts: np.ndarray) -> list[tuple[list[int], np.ndarray, list[tuple[float, float]]]]:
    """The windows' alphas in one gauge per chain of windows that share at least :data:`POOL_MIN_SHARED` frames:
    ``(windows, z, maps)`` per chain, ``z`` each frame's alpha in the chain's gauge (its first window's; NaN outside
    the chain), ``maps[i] = (A, B)`` with ``alpha_window = A z + B`` on the window's frames."""
    T = max(int(s) + len(a) for s, a in zip(starts, aw))
    order = np.argsort(starts, kind="stable")
    chains: list[tuple[list[int], np.ndarray, list[tuple[float, float]]]] = []
    acc = cnt = None
    for k in order:
        a = np.asarray(aw[k], dtype=np.float64)
        idx = np.arange(int(starts[k]), int(starts[k]) + a.size)
        shared = np.zeros(a.size, bool) if cnt is None else cnt[idx] > 0
        if shared.sum() >= POOL_MIN_SHARED:
            z = acc[idx][shared] / cnt[idx][shared]
            (A, B), *_ = np.linalg.lstsq(np.stack([z, np.ones_like(z)], axis=1), a[shared], rcond=None)
        else:  # a new chain, in this window's gauge
            acc, cnt = np.zeros(T), np.zeros(T)
            chains.append(([], acc, []))
            A, B = 1.0, 0.0
        if not abs(A) > 1e-6:
            return []
        chains[-1][0].append(int(k))
        chains[-1][2].append((float(A), float(B)))
        acc[idx] += (a - B) / A
        cnt[idx] += 1
    out = []
    for ks, acc_c, maps in chains:
        c = np.zeros(T)
        for k in ks:
            c[int(starts[k]):int(starts[k]) + len(aw[k])] += 1
        out.append((ks, np.where(c > 0, acc_c / np.maximum(c, 1), np.nan), maps))
    return out


def _pooled_gauge(aw: list, reports: list, starts: np.ndarray,
                  model: Any) -> tuple[list[tuple[float | None, float]], list[float | None], dict[str, Any]] | None:
    """One alpha gauge for the windows of a jittering rotation (module docstring): None unless every window's gauge
    was fixed by the polariser model following its frames' own alpha (an irregular rotation) and some windows
    share frames. Returns per window the map ``(P, Q)`` of its alpha to the pooled gauge's (``alpha' = P alpha +
    Q``; ``(None, 0)``: left as it is), its largest standard error there, and the report."""
    from metafovea.reconstruct.polarizer import gauged_alpha, polarizer_gauge

    if len(aw) < 2 or not all(isinstance(r, dict) and r.get("applied") and r.get("alpha_from") == "frames"
                              for r in reports):
        return None
    noise = float(np.median([r["fit"].get("alpha_noise_absolute", 0.0) for r in reports]))
    maps: list[tuple[float | None, float]] = [(None, 0.0)] * len(aw)
    se_w: list[float | None] = [None] * len(aw)
    rep: dict[str, Any] = {"chains": [], "why": "an irregular rotation: the windows' gauges chained through their "
                           "shared frames and fixed by one polariser fit to all their frames"}
    for ks, z, chain_maps in _chain(aw, starts):
        if len(ks) < 2:
            continue
        span = np.flatnonzero(np.isfinite(z))
        lo, hi = int(span[0]), int(span[-1]) + 1
        if span.size != hi - lo:  # a chain's frames are contiguous (windows are); guard anyway
            continue
        fit = polarizer_gauge(z[lo:hi], model.window(lo, hi - lo), alpha_noise=noise)
        if fit.get("status") != "ok" or not fit["a"] > 0:  # the windows' channel assignment stands: a > 0
            rep["chains"].append({"windows": len(ks), "frames": [lo, hi], "applied": False,
                                  "reason": fit.get("reason", "the pooled fit swaps the channels")})
            continue
        al, se = gauged_alpha(z[lo:hi], fit, 1.0, frame_noise=noise)
        a, b = fit["a"], fit["b"]
        for k, (A, B) in zip(ks, chain_maps):  # alpha_k = A z + B, z = a alpha' + b
            maps[k] = (1.0 / (A * a), -(B + A * b) / (A * a))
            s0 = int(starts[k]) - lo
            se_w[k] = float(np.max(se[s0:s0 + len(aw[k])]))
        rep["chains"].append({"windows": len(ks), "frames": [lo, hi], "applied": True, "a": a, "b": b,
                              "jitter_rms": fit.get("jitter_rms"), "alpha_se_max": float(se.max())})
        if fit.get("irregular"):
            rep["warning"] = (f"alpha deviates from a constant-rate rotation by {fit['jitter_rms']:.2g} rms beyond the "
                              f"noise over frames {lo}..{hi - 1}: an irregular polariser (or scene motion); each "
                              f"frame's own alpha is followed, its gauge uncertain by up to {float(se.max()):.2g}")
    if not any(P is not None for P, _ in maps):
        return None
    return maps, se_w, rep


def _apply_pooled_gauge(x1: np.ndarray, x2: np.ndarray, aw: list, se_w: list, identified: list, infos: list,
                        starts: np.ndarray, model: Any, info: dict[str, Any]) -> None:
    """The windows' alphas, images, standard errors and identification mapped, in place, to the gauge that
    :func:`_pooled_gauge` finds (when it finds one: ``model``, the polariser, given; ``infos``, the windows'
    solver reports); its report in ``info['gauge_pooled']``."""
    from metafovea.reconstruct.polarizer import ALPHA_SE_MAX

    pooled = None if model is None else _pooled_gauge(aw, [i.get("polarizer_gauge") for i in infos], starts, model)
    if pooled is None:
        return
    maps, se_p, info["gauge_pooled"] = pooled
    if "warning" in info["gauge_pooled"]:
        info["warnings"] = [info["gauge_pooled"]["warning"]]
    for k, (P, Q) in enumerate(maps):
        if P is None:
            continue
        d = (x1[k].astype(np.float64) - x2[k]) / P  # y = x2 + alpha d = x2' + (P alpha + Q) d'
        n2 = x2[k] - Q * d
        x1[k], x2[k] = (n2 + d).astype(x1.dtype), n2.astype(x2.dtype)
        aw[k] = (P * np.asarray(aw[k]) + Q).tolist()
        se_w[k] = se_p[k]
        identified[k] = bool(se_p[k] <= ALPHA_SE_MAX)


def _window_errors(infos: list, se_w: list, info: dict[str, Any]) -> None:
    """``info['alpha_se_max']`` (the windows' largest) and ``info['images_gauge_se']``: the largest over the windows
    of what each window's own gauge leaves uncertain in its images (a pooled gauge is at least as good), where every
    window has them."""
    if all(v is not None for v in se_w):
        info["alpha_se_max"] = float(max(se_w))
    gse = [i.get("images_gauge_se") for i in infos]
    if gse and all(v is not None for v in gse):
        info["images_gauge_se"] = np.max(np.asarray(gse, dtype=np.float64), axis=0).tolist()


def video(frames: ArrayLike, alpha: ArrayLike | None = None, *, window: int = 8, stride: int = 1,
          starts: Sequence[int] | None = None, method: str = "lsq", denoise: str | None = None,
          max_condition: float = MAX_CONDITION, regularize: str | float | None = None, saturation: float | None = None,
          progress: bool = False, **kw: Any) -> Reconstruction:
    """Reconstruct every sliding window of the frames.

    Parameters
    ----------
    frames : array_like, shape (T, H, W)
    alpha : array_like, shape (T,), optional
        Needed by ``'lsq'``.
    window, stride, starts : int, int, sequence of int
        ``frames[k stride : k stride + window]``, or the windows that begin at ``starts``.
    method : {'lsq', 'alternating', 'dip'}
        Alpha known, or estimated per window (extra keywords go to the method's function). ``'dip'``: ``max_seconds``
        is the whole sequence's budget, shared over the windows left; none left: the windows done are returned.
    denoise : {'tv', 'bilateral', 'nlm'}, optional
    max_condition, regularize, saturation
        As :func:`~metafovea.reconstruct.lsq.lsq_known_alpha` (an ill-conditioned window's error names it).
    progress : bool
        A progress bar over the windows.

    Returns
    -------
    Reconstruction
        ``x1``, ``x2`` ``(K, H, W)``; ``info``: ``window_starts``, per-window ``condition``; for unknown alpha
        ``alpha_windows``, for alternating ``window_alpha_identified``.
    """
    method = check_choice("method", method, ("lsq", "alternating", "dip"))
    tm = Timings()
    Y = as_frames(frames, min_frames=2)
    T, H, W = Y.shape
    starts = window_starts(T, window, stride, starts)
    K = len(starts)
    dt = image_dtype(Y)
    info: dict[str, Any] = {"window": int(window), "stride": int(stride), "window_starts": starts.tolist()}
    it = progress_iter(range(K), f"reconstruct ({method})", "window", enabled=progress)
    gains = None
    if method == "lsq":
        check_keywords({k: v for k, v in kw.items() if k not in GEOMETRY_KEYWORDS}, (), "video with method='lsq'")
        if alpha is None:
            raise InputError("alpha", None, "mixing ratios (T,) for method='lsq' (or use method='alternating')")
        a = as_alpha(alpha, T)
        M = valid_mask(Y, saturation)
        with tm.measure("solve"):
            x1, x2, conds = _lsq_windows(Y, a, starts, window, it, M, max_condition, regularize, saturation)
        x1, x2 = x1.reshape(K, H, W), x2.reshape(K, H, W)
        info["condition"] = conds.tolist()
        if denoise:
            with tm.measure("denoise"):
                s0 = starts[0]
                sig = (residual_sigma(Y[s0:s0 + window], a[s0:s0 + window], x1[0], x2[0])
                       if window > 2 and M is None else None)
                if sig is not None:
                    gains = [solve_weights(a[s:s + window], max_condition=max_condition, regularize=regularize,
                                           quiet=True)[1]["noise_gain"] for s in starts]
                    info["noise_sigma"] = sig
        if np.max(conds) > 100:
            log.warning("video: %d window(s) with condition number > 100 (max %.3g)", int(np.sum(conds > 100)),
                        float(np.max(conds)))
        alpha_out = a
    else:
        from metafovea.reconstruct.alternating import alternating  # imported here: an lsq run starts without them
        from metafovea.reconstruct.deep_prior import dip

        x1 = np.empty((K, H, W), dtype=dt)
        x2 = np.empty((K, H, W), dtype=dt)
        aw, runs, infos = [], [], []
        kw = dict(kw)
        budget = kw.pop("max_seconds", None) if method == "dip" else None  # the whole sequence's
        t_run = time.perf_counter()
        with tm.measure("solve"):
            for k in it:
                s = starts[k]
                if method == "alternating":
                    try:
                        pol = kw.get("polarizer")
                        wkw = {**kw, "polarizer": pol.window(s, window)} if pol is not None else kw
                        r = alternating(Y[s:s + window], saturation=saturation, **wkw)
                    except InputError as e:  # the same error, placed in its window (one message, not nested)
                        raise _in_window(e, k, s, window) from None
                    infos.append(r.info)
                else:
                    left = None if budget is None else budget - (time.perf_counter() - t_run)
                    if k and left is not None and left <= 0:  # the time cap: stop, keep the windows done
                        break
                    r = _dip_window(dip, Y, alpha, kw, s, window, None if left is None else left / (K - k))
                    runs.append({n: r.info.get(n) for n in ("steps", "steps_run", "stopped", "kept_step",
                                                                "max_seconds")})
                x1[k], x2[k] = r.x1, r.x2
                aw.append(np.asarray(r.alpha).tolist())
        info["alpha_windows"] = aw  # (the pooled gauge maps its entries in place)
        if method == "alternating":
            identified, se_w = ([i.get(n) for i in infos] for n in ("alpha_identified", "alpha_se_max"))
            _apply_pooled_gauge(x1, x2, aw, se_w, identified, infos, starts, kw.get("polarizer"), info)
            info["window_alpha_identified"] = [bool(v) for v in identified]
            info["window_alpha_se_max"] = se_w
            info["alpha_identified"] = bool(all(identified))
            info["alpha_gauge"] = sorted({str(i.get("alpha_gauge")) for i in infos})
            _window_errors(infos, se_w, info)
        else:
            info.update(dip_windows=runs, max_seconds=budget, windows_planned=K)
            if len(runs) < K:  # stopped by the time cap: the windows done
                K, starts = len(runs), starts[:len(runs)]
                x1, x2, info["window_starts"] = x1[:K], x2[:K], starts.tolist()
        alpha_out = np.asarray(alpha, dtype=np.float64) if alpha is not None else np.full(T, np.nan)
    if denoise:
        with tm.measure("denoise"):
            if gains is not None:
                x1 = np.stack([denoise_image(x1[k], denoise, sigma=sig * gains[k][0]) for k in range(K)])
                x2 = np.stack([denoise_image(x2[k], denoise, sigma=sig * gains[k][1]) for k in range(K)])
            else:
                x1 = denoise_image(x1, denoise)
                x2 = denoise_image(x2, denoise)
        info["denoise"] = denoise
    total = sum(tm.values())
    info["windows"] = K
    info["windows_per_s"] = float(K / total) if total > 0 else None
    return Reconstruction(x1=x1, x2=x2, alpha=alpha_out, fpn=None, method=f"video/{method}",
                          timings=dict(tm), info=info)

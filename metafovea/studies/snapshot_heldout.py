"""The snapshot (one-frame) mode judged on held-out generated scenes: what ``benchmarks/bench_snapshot.py`` runs per
case.

A case is a :class:`~metafovea.studies.heldout.HeldOutCase` (a scene ``gen:KIND:SEED`` of test seeds, one band),
simulated as a user records it (:func:`~metafovea.studies.heldout.simulate_case`: the recording, known alpha and the
closed-shutter frames). :func:`score_snapshot` then runs, on that one measurement and through
:func:`~metafovea.reconstruct.api.reconstruct_measurement` (the fixed pattern from the shutter frames, as
``fpn='auto'`` chooses):

* ``snapshot``: the one-frame mode on the frame whose alpha is nearest 0.5 (the snapshot's design point, the
  polariser at 45 degrees; the file's alpha for that frame is used);
* ``frame``: the same frame (fixed pattern subtracted) taken as both images: no separation at all;
* ``frame_level``: that frame moved to each truth's mean (an oracle: the level a separation must find, given);
* ``lsq``: the multi-frame result, known alpha, the whole recording as one window.

Each is scored against the truth the multi-frame pipeline is scored against: the noise-free sensor images
``truth_x1`` / ``truth_x2`` (through the lenses, haze included; not the perfect-lens ``scene_x*``, which no method
here deconvolves towards), PSNR with the truth's own range.

Residual overlap (one number per channel and method): in a frame the two images overlap pixel by pixel, ``y = a x1 +
(1 - a) x2`` on one sensor grid, so what a separation fails to remove from the foveal estimate is the perifoveal
image at the same pixels. With ``e1 = x1_hat - truth_x1`` the foveal estimate's error,

    overlap_x1 = corr(e1 - P e1, t2 - P t2),   P the projection onto (1, t1 - mean t1)

over every pixel: the correlation of the error with the perifoveal truth ``t2``, both with the foveal truth ``t1``
(and the mean) regressed out, so that an error which is only the foveal image's own loss of detail or contrast (a
blur, a gain) counts 0 even where ``t1`` and ``t2`` share structure (an edge through the centre of the field looks
the same at both magnifications). ``overlap_x2 = corr(e2 - P' e2, t1 - P' t1)`` likewise, ``P'`` onto ``(1, t2)``.
0: the error holds no trace of the other channel (noise, its own blur); 1: the unseparated frame, whose foveal error
is ``(1 - a) (t2 - t1)``; negative: the other channel over-subtracted. (The perifoveal image's centre crop, resampled
onto the foveal grid, is the same part of the scene as the foveal image at 1/6 of its resolution: its correlation
with ``e1`` measures a level or contrast error of ``x1_hat``'s own low frequencies, not the other channel's content,
so it is not the overlap.)

Registration error: :func:`~metafovea.reconstruct.snapshot.register`'s scale, crop offset (the crop's centre, x2
pixels, relative to the centred crop) and rotation against the true geometry: the file's ``meta['truth']['geometry']``
(``scale``, ``offset``, ``rotation_deg``) when the simulator realised one, else the nominal geometry it renders (the
design's ``scale`` = f1 / f2, offset (0, 0), rotation 0), reported with its source.

:func:`run_case` is :func:`~metafovea.studies.heldout.simulate_case` then :func:`score_snapshot`, for a process pool.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.config import SystemDesign
from metafovea.measurement import Measurement
from metafovea.studies.heldout import HeldOutCase, simulate_and_score

#: the rows of a case, in order: the one-frame mode, the unseparated frame, the same frame moved to each truth's mean
#: (an oracle baseline: it knows the truth's level), the multi-frame result
METHODS = ("snapshot", "frame", "frame_level", "lsq")
#: what every PSNR here is scored against (the multi-frame pipeline's truth: ``reconstruct_measurement``'s metrics)
TRUTH = "truth_x1/truth_x2: the noise-free sensor images (through the lenses, haze included)"


def overlap(err: np.ndarray, other: np.ndarray, own: np.ndarray | None = None) -> float:
    """The residual overlap: the correlation of an estimate's error with the other channel's true image, both with
    the estimated channel's own truth regressed out (module docstring).

    Parameters
    ----------
    err : array_like, shape (H, W)
        ``x_hat - truth`` of one channel.
    other : array_like, shape (H, W)
        The other channel's true image on the same sensor grid.
    own : array_like, shape (H, W), optional
        The estimated channel's true image; None: the plain correlation.

    Returns
    -------
    float
        In [-1, 1]; 0 when either is flat (after the regression).
    """
    e = np.asarray(err, np.float64).ravel()
    o = np.asarray(other, np.float64).ravel()
    basis = [np.ones_like(e)]
    if own is not None:
        t = np.asarray(own, np.float64).ravel()
        if np.ptp(t) > 0:
            basis.append(t - t.mean())
    q, _ = np.linalg.qr(np.stack(basis, axis=1))
    e0, o0 = float(e @ e), float(o @ o)
    e = e - q @ (q.T @ e)
    o = o - q @ (q.T @ o)
    ee, oo = float(e @ e), float(o @ o)
    if ee <= 1e-20 * e0 or oo <= 1e-20 * o0 or ee * oo == 0.0:  # nothing left but rounding
        return 0.0
    return float(e @ o / math.sqrt(ee * oo))


def true_geometry(m: Measurement) -> dict[str, Any]:
    """The geometry the file's foveal view was rendered with: ``scale``, ``offset`` ``(dy, dx)`` (x2 pixels),
    ``rotation_deg`` and ``source`` (``'truth'``: the simulator's realised geometry; ``'nominal'``: none realised,
    the design's)."""
    g = (m.meta.get("truth") or {}).get("geometry")
    if g:
        return {"scale": float(g.get("scale", m.scale)), "offset": tuple(float(v) for v in g.get("offset", (0, 0))),
                "rotation_deg": float(g.get("rotation_deg", 0.0)), "source": "truth"}
    return {"scale": float(m.scale), "offset": (0.0, 0.0), "rotation_deg": 0.0, "source": "nominal"}


def snapshot_frame(m: Measurement) -> int:
    """The frame the study separates: the first whose alpha is nearest 0.5 (the polariser at 45 degrees)."""
    a = np.asarray(m.alpha, np.float64)
    return int(np.argmin(np.abs(a - 0.5)))


def registration_error(reg: dict[str, Any], truth: dict[str, Any]) -> dict[str, Any]:
    """The registration's error against ``truth`` (:func:`true_geometry`): ``scale_error`` (relative),
    ``offset_error_px`` (Euclidean, x2 pixels), ``rotation_error_deg`` (None when the registration gave none), and
    the estimates themselves, with the test's verdict (``identified``, ``moved``, ``peak_on_edge``) and figures."""
    off = tuple(float(v) for v in reg["offset"])
    rot = reg.get("rotation_deg")
    return {"scale": float(reg["scale"]), "offset": off, "rotation_deg": rot,
            **{k: reg[k] for k in ("identified", "moved", "peak_on_edge", "z", "z_move", "z_critical") if k in reg},
            "scale_error": float(reg["scale"]) / truth["scale"] - 1.0,
            "offset_error_px": math.hypot(off[0] - truth["offset"][0], off[1] - truth["offset"][1]),
            "rotation_error_deg": None if rot is None else float(rot) - truth["rotation_deg"]}


def score_snapshot(m: Measurement, *, frame: int | None = None, solver: dict[str, Any] | None = None) -> dict[str, Any]:
    """The snapshot mode, the unseparated frame and the multi-frame result on one measurement (module docstring).

    Parameters
    ----------
    m : Measurement
        Static, known alpha, with the noise-free truth (``truth_x1``, ``truth_x2``); shutter frames when it has a
        fixed pattern.
    frame : int, optional
        The frame to separate; default :func:`snapshot_frame`.
    solver : dict, optional
        Keywords of :func:`~metafovea.reconstruct.snapshot.snapshot`.

    Returns
    -------
    dict
        ``frame``, ``alpha`` (the frame's), ``truth`` (:data:`TRUTH`), ``geometry`` (:func:`true_geometry`),
        ``registration`` (:func:`registration_error`) and ``rows``: per method (:data:`METHODS`) ``method``,
        ``psnr_x1``, ``psnr_x2`` (dB against the truth), ``overlap_x1``, ``overlap_x2`` (:func:`overlap`) and
        ``seconds``.
    """
    from metafovea.reconstruct.api import reconstruct_measurement
    from metafovea.reconstruct.metrics import psnr

    k = snapshot_frame(m) if frame is None else int(frame)
    t1, t2 = (np.asarray(t, np.float64) for t in (m.truth_x1, m.truth_x2))
    t0 = time.perf_counter()
    snap = reconstruct_measurement(m, "snapshot", known_alpha=True, frame=k, solver=solver)
    s_snap = time.perf_counter() - t0
    rec = snap.reconstruction
    f = np.zeros(m.shape[1:]) if rec.fpn is None else np.asarray(rec.fpn, np.float64)
    y = np.asarray(m.frames[k], np.float64) - f  # the frame the snapshot separated
    t0 = time.perf_counter()
    multi = reconstruct_measurement(m, "lsq", window=m.shape[0])
    s_multi = time.perf_counter() - t0
    rows = []
    level = (y - float(np.mean(y - t1)), y - float(np.mean(y - t2)))  # the frame at each truth's mean: an oracle
    for name, (e1, e2), secs in (("snapshot", (rec.x1, rec.x2), s_snap), ("frame", (y, y), 0.0),
                                 ("frame_level", level, 0.0),
                                 ("lsq", (multi.reconstruction.x1, multi.reconstruction.x2), s_multi)):
        e1, e2 = np.asarray(e1, np.float64), np.asarray(e2, np.float64)
        rows.append({"method": name, "psnr_x1": psnr(e1, t1), "psnr_x2": psnr(e2, t2),
                     "overlap_x1": overlap(e1 - t1, t2, t1), "overlap_x2": overlap(e2 - t2, t1, t2),
                     "seconds": secs})
    geo = true_geometry(m)
    return {"frame": k, "alpha": float(m.alpha[k]), "truth": TRUTH, "geometry": geo,
            "registration": registration_error(rec.info["registration"], geo), "rows": rows,
            "snapshot_info": {key: rec.info[key] for key in ("iterations", "foveal_rms") if key in rec.info}}


def run_case(system: SystemDesign | str | Path, case: HeldOutCase, *, solver: dict[str, Any] | None = None,
             threads: int | None = None) -> dict[str, Any]:
    """:func:`~metafovea.studies.heldout.simulate_case` then :func:`score_snapshot`: a process pool's task.

    Parameters
    ----------
    system : SystemDesign, str or Path
        A design or its TOML file.
    case : HeldOutCase
    solver : dict, optional
        As :func:`score_snapshot`.
    threads : int, optional
        BLAS threads inside the case (1 when the cases run one per core); None: the library's.

    Returns
    -------
    dict
        The case's fields, ``simulate_seconds`` and :func:`score_snapshot`'s result.
    """
    return simulate_and_score(system, case, lambda m: score_snapshot(m, solver=solver), threads=threads)

"""The reconstruction stage's two entry points: :func:`reconstruct` (arrays in, one solver) and
:func:`reconstruct_measurement` (a Measurement in: the pipeline's rules, used by ``metafovea reconstruct``,
``metafovea validate`` and notebooks alike).

The pipeline of :func:`reconstruct_measurement`, in order: the foveal constraint and (unknown alpha) the polariser
model from the file; the fixed pattern (a given array subtracted, or estimated from calibration frames or from the
separated images, once for all windows); the file's invalid samples left out; the solver, over one window or window
by window (:func:`~metafovea.reconstruct.video.video`), with denoising; scores against the truth each output shows
and, when alpha was estimated, its error.

Measured figures: BENCHMARKS.md, section "Reconstruction".
"""

from __future__ import annotations

import contextlib
import inspect
import math
import time
import warnings
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.errors import InputError, check_choice
from metafovea.measurement import FovealConstraint, Measurement, PolarizerSpec
from metafovea.reconstruct._common import (
    CALIBRATION_FRAMES,
    DEFAULT_WINDOW,
    GEOMETRY_KEYWORDS,
    SHORT_SEQUENCE,
    check_keywords,
)
from metafovea.reconstruct.auto import choose_method
from metafovea.reconstruct.denoise import denoise as denoise_image
from metafovea.reconstruct.fpn import estimate_fpn
from metafovea.reconstruct.lsq import lsq_known_alpha
from metafovea.reconstruct.metrics import score
from metafovea.reconstruct.polarizer import PolarizerModel
from metafovea.reconstruct.result import PipelineResult, Reconstruction
from metafovea.reconstruct.video import video

#: the solvers, in the CLI's words (``--method``)
METHODS = ("lsq", "alternating", "dip", "snapshot")
#: the alternating solver's own keywords of ``solver``, which ``auto`` passes on only when it chooses that solver
ALTERNATING_KEYWORDS = ("polarizer", "polarizer_alpha", "strict")
#: what :func:`reconstruct_measurement` accepts: a solver, or ``auto``
#: (:func:`~metafovea.reconstruct.auto.choose_method`: from the recording's motion and the time allowed)
METHOD_CHOICES = (*METHODS, "auto")
#: fixed-pattern noise handling of :func:`reconstruct_measurement` (``--fpn``); ``auto`` picks one from the file
#: (:func:`fpn_mode`)
FPN_MODES = ("auto", "none", "prior", "calibration")
#: noise gain (x_i's noise std per unit frame noise) above which the summary warns
NOISE_GAIN_WARN = 10.0
#: the deep image prior's default time budget for a whole run (all windows), in seconds (``solver={'max_seconds':
#: None}`` or ``--max-seconds 0``: none). A random start at 290 x 290 takes ~0.7 s per step on a 2-core CPU (16
#: channels; BENCHMARKS.md), so its 2,000-step budget alone would run ~23 minutes per window, and a 96-frame file is
#: 89 windows: without a cap a default run never ends in a session. Ten minutes bound it; a run that hits the cap
#: keeps each window's lowest-loss images and the summary says so
DIP_MAX_SECONDS = 600.0
#: the frames a stuck pixel must keep one value over to be left out as dead or saturated
STUCK_MIN_FRAMES = 6
#: the share of saturated or invalid samples in the fovea above which the summary warns
FOVEA_INVALID_MAX = 0.5
#: alpha's amplitude's relative error where the recording does not state its polariser's extinction and bolometer
#: lag and the calibration cannot measure it: the rms departure from the ideal device's amplitude of one anywhere in
#: extinction 0-5 % and tau 0-12 ms at 2 Hz (issue 30's ranges of real devices: amplitude 0.866-1 of the ideal,
#: uniformly: rms 0.134 / sqrt(3))
ASSUMED_AMPLITUDE_SE = 0.077
#: the nominal alpha disagrees with the frames when their rms difference exceeds this many times its noise plus
#: NOMINAL_TOL (a rotation's phase off by 0.1 deg moves alpha by up to 0.0035)
NOMINAL_FACTOR = 3.0
NOMINAL_TOL = 2e-3


def reconstruct(frames: ArrayLike, alpha: ArrayLike | None = None, method: str = "lsq", *,
                fpn: str | ArrayLike | None = None, calibration: ArrayLike | None = None,
                **kw: Any) -> Reconstruction:
    """Separate the foveal and perifoveal images from the frames with one solver.

    Parameters
    ----------
    frames : array_like, shape (T, H, W)
        (One frame, ``(H, W)`` or ``(1, H, W)``, for ``'snapshot'``.)
    alpha : array_like, shape (T,), optional
        Mixing ratios: required by ``'lsq'``, refused by ``'alternating'``, optional for ``'dip'`` (held fixed)
        and ``'snapshot'``.
    method : {'lsq', 'alternating', 'dip', 'snapshot'}
        Known alpha (:func:`~metafovea.reconstruct.lsq.lsq_known_alpha`), unknown alpha, classical
        (:func:`~metafovea.reconstruct.alternating.alternating`), double deep image prior
        (:func:`~metafovea.reconstruct.deep_prior.dip`, JAX), one frame
        (:func:`~metafovea.reconstruct.snapshot.snapshot`).
    fpn : {'calibration', 'prior'} or array_like, shape (H, W), optional
        An array is subtracted; ``'calibration'`` estimates it from ``calibration``; ``'prior'`` blindly, from the
        separated images (:func:`~metafovea.reconstruct.fpn.estimate_fpn`: the foveal estimate, the TV low-rank
        prior where the foveal contrast gain is >= 0.98). None: no FPN handling.
    calibration : array_like, shape (Tc, H, W), optional
        Frames of a uniform source (``fpn='calibration'``).
    **kw
        Keywords of the method's function; ``fpn_kw``: keywords of :func:`~metafovea.reconstruct.fpn.estimate_fpn`.
        The foveal constraint ``D x1 = foveal_gain C x2 + foveal_offset`` (``scale``, ``foveal_gain``,
        ``foveal_offset``; a Measurement's :class:`~metafovea.measurement.FovealConstraint`) is used by
        alternating, dip, snapshot and the FPN prior.

    Returns
    -------
    Reconstruction
        With ``fpn`` and ``info['fpn']`` when a pattern was subtracted.
    """
    method = check_choice("method", method, METHODS)
    # the foveal constraint, kept for the FPN prior (lsq below drops these keywords)
    geo = {k: kw[k] for k in ("scale", "foveal_gain", "foveal_offset") if k in kw}
    f = None
    finfo: dict[str, Any] = {}
    fpn_kw = dict(kw.pop("fpn_kw", None) or {})
    if isinstance(fpn, str):
        mode = check_choice("fpn", fpn, ("calibration", "prior"))
        if mode == "calibration":
            if calibration is None:
                raise InputError("calibration", None, "calibration frames (T, H, W) when fpn='calibration'")
            f, finfo = estimate_fpn(calibration=calibration, **fpn_kw)
    elif fpn is not None:
        f = np.asarray(fpn, dtype=np.float64)
        finfo = {"identified": "given"}
    if f is not None:
        fr = np.asarray(frames)
        if fr.shape[-2:] != f.shape:
            raise InputError("fpn", f"array of shape {f.shape}", f"the frames' (H, W) = {fr.shape[-2:]}")
        frames = (fr - f).astype(fr.dtype if fr.dtype in (np.float32, np.float64) else np.float64)
    if method == "lsq":
        if alpha is None:
            raise InputError("alpha", None, "mixing ratios (T,) for method='lsq'; use method='alternating' or 'dip' "
                             "when they are unknown")
        kw = {k: v for k, v in kw.items() if k not in GEOMETRY_KEYWORDS}
        check_keywords(kw, tuple(inspect.signature(lsq_known_alpha).parameters)[2:], "lsq_known_alpha")
        rec = lsq_known_alpha(frames, alpha, **kw)
    elif method == "alternating":
        if alpha is not None:
            raise InputError("alpha", "given",
                             "alpha=None for method='alternating' (use method='lsq' with known alpha)")
        from metafovea.reconstruct.alternating import alternating

        rec = alternating(frames, **kw)
    elif method == "dip":
        from metafovea.reconstruct.deep_prior import dip

        rec = dip(frames, alpha=alpha, **kw)
    else:
        fr = np.asarray(frames)
        if fr.ndim == 3:
            if fr.shape[0] != 1:
                raise InputError("frames", f"{fr.shape[0]} frames", "exactly one frame for method='snapshot'")
            fr = fr[0]
        a = None if alpha is None else float(np.ravel(alpha)[0])
        from metafovea.reconstruct.snapshot import snapshot

        rec = snapshot(fr, alpha=a, **kw)
    if isinstance(fpn, str) and fpn.lower() == "prior":
        f, finfo = estimate_fpn(x1=rec.x1, x2=rec.x2, **{**geo, **fpn_kw})
        rec = Reconstruction(x1=(rec.x1 - f).astype(rec.x1.dtype), x2=(rec.x2 - f).astype(rec.x2.dtype),
                             alpha=rec.alpha, fpn=f, method=rec.method, timings=rec.timings,
                             info={**rec.info, "fpn": finfo})
    elif f is not None:
        rec = Reconstruction(x1=rec.x1, x2=rec.x2, alpha=rec.alpha, fpn=f, method=rec.method,
                             timings=rec.timings, info={**rec.info, "fpn": finfo})
    return rec


def fpn_mode(m: Measurement) -> tuple[str, str]:
    """What ``fpn='auto'`` does with ``m``: ``(mode, why)``. The file's shutter frames when it has them
    (``calibration``); otherwise the blind estimate (``prior``) when the file declares a fixed pattern
    (:attr:`Measurement.fpn_rank` > 0: a simulated sensor with FPN, no shutter frames); otherwise ``none`` (a
    recording that says nothing, or a sensor without FPN: the prior would only add its error, 1.5 dB on x1 of
    the default simulation without FPN)."""
    if "calibration" in m.extras:
        n = int(np.shape(m.extras["calibration"])[0]) if np.ndim(m.extras["calibration"]) == 3 else 1
        return "calibration", f"from the file's {n} shutter frames"
    rank = m.fpn_rank
    if rank:
        return "prior", (f"blind estimate (the file declares a rank-{rank} fixed pattern and has no shutter "
                         "frames)")
    return "none", ("not corrected (the file has no shutter frames and declares no fixed pattern)" if rank is None
                    else "not corrected (the file's sensor has no fixed pattern)")


def reconstruct_measurement(m: Measurement, method: str = "lsq", *, known_alpha: bool = False,
                            window: int | None = None, stride: int = 1, starts: Sequence[int] | None = None,
                            fpn: str | np.ndarray = "auto", denoise: str | None = None, frame: int | None = None,
                            constraint: FovealConstraint | None = None, solver: dict[str, Any] | None = None,
                            level_free: bool = False, progress: bool = False,
                            score_truth: bool = True, polarizer: dict[str, Any] | None = None,
                            calibrate: bool = True, refine_alpha: bool = False, time_s: float | None = None,
                            deconvolve: str | None = None) -> PipelineResult:
    """Reconstruct a Measurement by the pipeline's rules and score it against its truth.

    Parameters
    ----------
    m : Measurement
    method : {'lsq', 'alternating', 'dip', 'snapshot', 'auto'}
        ``lsq`` uses the file's alpha; ``snapshot`` separates the single frame ``frame`` (default: the frame whose
        file alpha is nearest 1/2, both channels most evenly mixed; frame 0 where the file has none); ``auto`` chooses
        the solver,
        window and stride (and the PSF-aware step to run after: ``deconvolve``) from what the file knows of alpha,
        the scene's motion and ``time_s`` (:func:`~metafovea.reconstruct.auto.choose_method`), and records the
        choice, why, and the time it took in ``reconstruction.info['auto']`` (a given ``window`` or a ``stride``
        other than 1 is kept).
    known_alpha : bool
        Use the file's alpha with ``dip`` (held fixed) or ``snapshot`` (implied by ``lsq``; refused with
        ``alternating``, which estimates it).
    window, stride, starts : int, int, sequence of int
        Frames per window (default: :data:`DEFAULT_WINDOW`; a sequence of fewer than :data:`SHORT_SEQUENCE`
        frames is one window of all of them: more frames per window lower the noise, and a short recording has
        little motion to follow). A sequence longer than the window, or explicit window ``starts``, is
        reconstructed window by window (:func:`~metafovea.reconstruct.video`), every ``stride``-th frame or at
        ``starts``; otherwise the whole sequence is one window.
    fpn : {'auto', 'none', 'prior', 'calibration'} or ndarray, shape (H, W)
        Fixed-pattern noise: ``auto`` (default) chooses by the file (:func:`fpn_mode`: its shutter frames, else the
        blind estimate when it declares a pattern, else none) and records the choice in
        ``reconstruction.info['fpn']`` (``mode``, ``auto``); an array (the user's pattern, e.g. from a dark-frame
        calibration) is subtracted;
        ``calibration`` estimates it from the file's ``calibration`` frames and ``prior`` from the separated images
        (for a sequence of several windows: once, from the windows' images averaged over the windows, then
        subtracted from every frame before the windows are solved again). The file's own ``fpn`` array is the
        simulator's true pattern: it only scores an estimate (``metrics['fpn_rms_error']``, mean removed), it is
        never subtracted.
    denoise : {'tv', 'bilateral', 'nlm'} or None
        Denoise the outputs: inside LSQ (noise level from its residual), after the other methods (noise level
        estimated from each image).
    constraint : FovealConstraint
        Default: the file's (:attr:`Measurement.foveal_constraint`).
    solver : dict
        Keywords of the method's function (``regularize`` for lsq; ``strict`` for alternating; ``steps``,
        ``channels``, ``rng``, ``init``, ``max_seconds`` for dip: the whole run's time budget, default
        :data:`DIP_MAX_SECONDS`, None for none (``progress`` shows its steps); ``iterations`` for snapshot).
    level_free : bool
        Add the level-free PSNRs to the metrics (see :func:`~metafovea.reconstruct.metrics.score`).
    score_truth : bool
        Score against the file's truth (default); False leaves ``metrics`` None (file-to-file speed).
    polarizer : dict, optional
        Polariser values (:class:`~metafovea.measurement.PolarizerSpec` keywords) before the file's keys and the
        defaults; the spec used, each value's source and what was assumed: ``info['polarizer_spec']``.
    refine_alpha : bool
        ``lsq``: alpha fitted from the frames (``alternating``) instead of the nominal alpha of a synchronised
        polariser, which ``lsq`` uses without a file alpha and checks against the frames (``info['alpha_nominal']``).
    calibrate : bool
        Unknown alpha: calibrate the camera from the recording first (:func:`_calibrated`; ``info['calibration']``).
    time_s : float, s, optional
        ``auto``: the time allowed (None: no limit).
    deconvolve : {'wavelet', 'wiener', 'tv', 'none'}, optional
        ``auto``: the PSF-aware step the caller runs after (:func:`~metafovea.reconstruct.deconvolve.deconvolve_result`)
        counted in the time; None lets ``auto`` choose it (``info['auto']['chose']['deconvolve']``).

    Notes
    -----
    The pipeline reads only the recording schema (:meth:`Measurement.as_recording`).

    Returns
    -------
    PipelineResult
        The reconstruction, the frames each output covers, the time taken, metrics against the truth each output
        shows (a video truth averaged over the output's frames) and, when alpha was estimated, its error.
    """
    method = check_choice("method", method, METHOD_CHOICES)
    kw = dict(known_alpha=known_alpha, window=window, stride=stride, starts=starts, fpn=fpn, denoise=denoise,
              frame=frame, constraint=constraint, solver=solver, level_free=level_free, progress=progress,
              score_truth=score_truth, polarizer=polarizer, calibrate=calibrate, refine_alpha=refine_alpha)
    if method == "auto":
        return _auto(m, time_s, deconvolve, kw)
    for name, v in (("time_s", time_s), ("deconvolve", deconvolve)):
        if v is not None:
            raise InputError(name, v, "only with method='auto' (which chooses the method from it)")
    return _pipeline(m, method, **kw)


def _pipeline(m: Measurement, method: str, *, known_alpha: bool, window: int | None, stride: int,
              starts: Sequence[int] | None, fpn: str | np.ndarray, denoise: str | None, frame: int,
              constraint: FovealConstraint | None, solver: dict[str, Any] | None, level_free: bool, progress: bool,
              score_truth: bool, polarizer: dict[str, Any] | None, calibrate: bool,
              refine_alpha: bool) -> PipelineResult:
    """:func:`reconstruct_measurement` with a solver (``method`` checked)."""
    m = m.as_recording()
    spec = m.polarizer_spec(**(polarizer or {}))
    T = m.shape[0]
    fc = constraint if constraint is not None else m.foveal_constraint
    if method != "snapshot" and T < 2:
        raise InputError("frames", f"{T} frame", "at least 2 frames (or method='snapshot' for a single frame)",
                         source=m.source)
    window = _window_size(T, method, window)
    if method == "lsq" and refine_alpha:  # alpha from the frames: the rotation's phase and rate fitted
        method, spec = "alternating", m.polarizer_spec(**{**(polarizer or {}), "mode": "free"})
    alpha, nominal = _file_alpha(m, method, known_alpha, spec)
    kw = _polarizer_model(m, method, alpha, spec, {**fc.as_kwargs(), **(solver or {})})
    if "regularize" in kw and method != "lsq":
        raise InputError("regularize", kw["regularize"], "only with method='lsq'")
    if method == "dip":
        kw.setdefault("max_seconds", DIP_MAX_SECONDS)  # the whole run's, split over its windows
    cap = kw.get("max_seconds")
    fpn_auto = None
    if isinstance(fpn, str) and fpn.strip().lower() == "auto":
        fpn, fpn_auto = fpn_mode(m)
    frames, fpn_kw = _fpn(m, fpn)
    frames, mask_info = _masked(m, frames, method)
    calib = None
    if isinstance(kw.get("polarizer"), PolarizerModel) and calibrate:
        kw["polarizer"], calib = _calibrated(m, frames, kw, fpn_kw, method,
                                             assumed=any(spec.sources.get(k) == "default" for k in
                                                         ("extinction", "tau_s")))
    video_out = method != "snapshot" and (T > window or starts is not None)
    t0 = time.perf_counter()
    from metafovea.parallel import blas_threads

    # the classical solvers' products are small (2 x window, 2 x 2 per pixel): OpenBLAS threads only contend
    # (measured on the 2-core machine: 0.03 s for 89 windows single-threaded, 0.6-2 s with two threads under load)
    video_fpn = None
    with blas_threads(1) if method != "dip" else contextlib.nullcontext():
        if video_out and fpn_kw:
            frames, video_fpn = _video_fpn(m, method, frames, alpha, kw, fpn_kw, window, stride, starts, progress)
            fpn_kw = {}
            if kw.get("max_seconds") is not None:  # what the first pass left of the time budget
                kw["max_seconds"] = max(kw["max_seconds"] - (time.perf_counter() - t0), 1e-3)
        rec, spans = _solve(m, method, frames, alpha, kw, fpn_kw, window, stride, starts, denoise, frame, video_out,
                            progress)
    seconds = time.perf_counter() - t0
    if video_out and starts is None and spans and spans[-1][1] < T:
        rec = replace(rec, info={**rec.info, "warnings": [*(rec.info.get("warnings") or []),
                                                          _uncovered(T, window, stride, spans[-1][1])]})
    if video_fpn is not None:
        rec = replace(rec, fpn=video_fpn[0].astype(np.float32), info={**rec.info, "fpn": video_fpn[1]})
    if method == "dip":
        rec = replace(rec, info={**rec.info, "max_seconds": cap})  # the run's cap (the solver saw what was left)
    rec = _flat_fielded(m, rec)
    rec = _with_fpn_info(replace(rec, info={**rec.info, "invalid_samples": mask_info}) if mask_info else rec,
                         fpn, fpn_auto)
    rec = _with_polarizer_info(rec, m, frames, alpha if nominal else None, spec, calib, window,
                               isinstance(kw.get("polarizer"), PolarizerModel))
    res = PipelineResult(reconstruction=rec, spans=spans, seconds=seconds, constraint=fc, frames=T, source=m.source)
    return replace(res, metrics=_metrics(m, res, level_free) if score_truth else None,
                   alpha_mae=_alpha_mae(m, res, alpha is None or nominal))


def _uncovered(T: int, window: int, stride: int, end: int) -> str:
    """The warning for the frames ``end``..``T - 1`` that no window reaches, naming the largest stride up to
    ``stride`` whose windows end on the last frame."""
    ok = max(s for s in range(1, stride + 1) if (T - window) % s == 0)
    frames = f"frame {end}" if end == T - 1 else f"frames {end} to {T - 1}"
    return (f"{frames} of {T} in no window (window={window}, stride={stride}: the last window ends at frame "
            f"{end - 1}); stride={ok} reaches the last frame")


def _auto(m: Measurement, time_s: float | None, deconvolve: str | None, kw: dict[str, Any]) -> PipelineResult:
    """``method='auto'``: :func:`~metafovea.reconstruct.auto.choose_method`, the pipeline with its choice, and the
    choice in ``info['auto']`` with the seconds the pipeline took and, where the solver reports its noise gain, the
    images' expected noise (DN rms: the frames' noise times the gain; the worst window's)."""
    choice = choose_method(m.as_recording(), time_s, known_alpha=kw["known_alpha"], window=kw["window"],
                           stride=None if kw["stride"] == 1 else kw["stride"], denoise=kw["denoise"],
                           deconvolve=deconvolve, polarizer=kw["polarizer"])
    solver = {k: v for k, v in (kw["solver"] or {}).items()
              if choice.method == "alternating" or k not in ALTERNATING_KEYWORDS}  # those of the solver chosen
    t0 = time.perf_counter()
    res = _pipeline(m, choice.method, **{**kw, "window": choice.window, "stride": choice.stride,
                                         "denoise": choice.denoise, "solver": solver})
    rec = res.reconstruction
    info = {**choice.summary(), "seconds": time.perf_counter() - t0}  # the whole pipeline (its calibration pass too)
    gain = rec.info.get("noise_gain")
    if gain is not None and np.size(gain) >= 2 and np.size(gain) % 2 == 0:  # the worst window's
        info["noise_dn"] = [choice.motion.noise_dn * float(g) for g in np.nanmax(np.reshape(gain, (-1, 2)), axis=0)]
    return replace(res, reconstruction=replace(rec, info={**rec.info, "auto": info}))


def _flat_fielded(m: Measurement, rec: Reconstruction) -> Reconstruction:
    """``rec`` with the file's flat field (``flat_field``: each pixel's relative gain, the optics' vignetting)
    divided out of both images above the dark level: the frames are ``dark + v (alpha s1 + (1 - alpha) s2)``, so
    the separated images are ``dark + v s_i`` whatever alpha is."""
    v = m.extras.get("flat_field")
    if v is None:
        return rec
    v = np.asarray(v, dtype=np.float64)
    dark = m.dark_dn
    x1, x2 = (dark + (np.asarray(x, np.float64) - dark) / v for x in (rec.x1, rec.x2))
    return replace(rec, x1=x1.astype(np.asarray(rec.x1).dtype), x2=x2.astype(np.asarray(rec.x2).dtype),
                   info={**rec.info, "flat_field": "divided out (the file's flat_field, above its dark level)"})


def _window_size(T: int, method: str, window: int | None) -> int:
    """The frames per window: as given (checked), else :data:`DEFAULT_WINDOW`, or all of a short sequence."""
    window = (T if T < SHORT_SEQUENCE else DEFAULT_WINDOW) if window is None else window
    if method != "snapshot" and not 2 <= window <= T:
        raise InputError("window", window, f"2 <= window <= number of frames ({T})")
    return window


def _with_fpn_info(rec: Reconstruction, fpn: str | np.ndarray, fpn_auto: str | None) -> Reconstruction:
    """``rec`` with the fixed-pattern mode used (and why, when ``fpn='auto'`` chose it), or the user's pattern as
    subtracted."""
    if not isinstance(fpn, str):
        if rec.fpn is None and not rec.is_video:
            rec = replace(rec, fpn=np.asarray(fpn, dtype=np.float32), info={**rec.info, "fpn": {"identified": "given"}})
        return rec
    finfo = {**(rec.info.get("fpn") or {}), "mode": fpn.strip().lower()}
    return replace(rec, info={**rec.info, "fpn": finfo if fpn_auto is None else {**finfo, "auto": fpn_auto}})


def _with_polarizer_info(rec: Reconstruction, m: Measurement, frames: np.ndarray, nominal: np.ndarray | None,
                         spec: PolarizerSpec, calib: dict[str, Any] | None, window: int,
                         modelled: bool) -> Reconstruction:
    """``rec`` with what the pipeline knew of the polariser: a nominal alpha's check against the frames
    (:func:`_nominal_check`), the spec with each value's source, the calibration, and the warnings for what the
    recording leaves unknown (:func:`_unidentifiable`)."""
    info, warns = dict(rec.info), list(rec.info.get("warnings") or [])
    if nominal is not None and not rec.is_video:
        chk = _nominal_check(m, frames, nominal, rec)
        info.update(alpha_nominal=chk, polarizer_spec=spec.summary())
        warns += [chk["warning"]] if "warning" in chk else []
    if modelled:
        info.update(polarizer_spec=spec.summary(), calibration=calib)
        warns += _unidentifiable(m, window, spec)
    return replace(rec, info={**info, "warnings": warns})


def _unidentifiable(m: Measurement, window: int, spec: PolarizerSpec) -> list[str]:
    """What the recording leaves unknown for an unknown-alpha reconstruction, one sentence each: a window shorter
    than half a turn of the polariser (alpha's period: its phase, rate and amplitude are then not separable), and a
    fovea whose samples are mostly saturated or invalid (the foveal relation, which chooses the channels and
    calibrates the camera, then rests on few pixels)."""
    out = []
    if m.shape[0] > 1 and spec.rate_hz > 0:
        dt = float(np.median(np.diff(m.times_s)))
        span = dt * window
        if span < 0.5 / spec.rate_hz:
            need = math.ceil(0.5 / spec.rate_hz / dt - 1e-9)
            longer = (f"a window of at least {need} frames (window={need})"
                      if need <= m.shape[0] else f"a recording of at least {need} frames")
            out.append(f"a window of {window} frames spans {span:.3g} s, less than half a turn of the polariser "
                       f"({0.5 / spec.rate_hz:.3g} s at {spec.rate_hz:g} Hz): alpha's phase, rate and amplitude "
                       f"are not separable in it; use {longer}")
    bad = m.invalid_samples()
    if bad is not None:
        H, W = m.shape[1:]
        s = m.scale
        h, w = max(int(H / (2 * s)), 1), max(int(W / (2 * s)), 1)
        frac = float(bad[:, H // 2 - h:H // 2 + h, W // 2 - w:W // 2 + w].mean())
        if frac > FOVEA_INVALID_MAX:
            out.append(f"{100 * frac:.0f} % of the fovea's samples are saturated or invalid: the foveal relation, "
                       "which chooses the channels and calibrates the camera, rests on the rest")
    return out


def _calibrated(m: Measurement, frames: np.ndarray, kw: dict[str, Any], fpn_kw: dict[str, Any],
                method: str, assumed: bool = False) -> tuple[PolarizerModel, dict[str, Any]]:
    """The polariser model with alpha's amplitude calibrated from the recording, and what the calibration found.

    One pass of the classical solver (no prior: least-squares images) over the first :data:`CALIBRATION_FRAMES`
    frames gives the images in the stated gauge; :func:`~metafovea.reconstruct.calibrate.fit_foveal` fits the foveal
    relation to them (each side blurred by the other channel's PSF when the file has both), for both channel
    assignments: the one it explains better is the recording's, and its relation (gain, offset; for the alternating
    solver the geometry, scale, centre and rotation, where the fit moved it) is what the solver then tells the
    channels apart by (``kw`` updated). The amplitude is used
    where it departs from the stated one by more than twice its standard error, the fit's model
    error (:data:`~metafovea.reconstruct.calibrate.AMPLITUDE_MODEL_ERROR` times its relative misfit) and
    :data:`~metafovea.reconstruct.calibrate.AMPLITUDE_FLOOR` (also where that error is too large for the amplitude to
    count as identified: a departure that large is evidence against the stated constants all the same); its standard
    error includes the calibration pass's own (the polariser fit's uncertainty in alpha's amplitude, which a
    jittering rotation makes large: only a departure beyond it is then taken for a leak or a lag).

    The returned model's ``amplitude_se`` carries what is known of the amplitude into every frame's alpha error:
    the calibration's error where it was used; where the stated constants are used, 0 if the recording (or the
    caller) states them, else (``assumed``: the paper's defaults stand in) the calibration's error where it checked
    them, and :data:`ASSUMED_AMPLITUDE_SE` where nothing could."""
    model, info = _calibration_fit(m, frames, kw, fpn_kw, method)
    if not info.get("applied"):
        checked = info.get("checked_se")
        eps = 0.0 if not assumed else ASSUMED_AMPLITUDE_SE if checked is None else min(checked, ASSUMED_AMPLITUDE_SE)
        model = replace(model, amplitude_se=eps)
        if assumed:
            info["amplitude_se_used"] = eps
            info["amplitude_se_why"] = (
                "the recording does not state its polariser's extinction or bolometer lag and the calibration could "
                "not measure alpha's amplitude: the paper's constants stand in, with the spread of real devices "
                f"(extinction 0-5 %, tau 0-12 ms: +- {ASSUMED_AMPLITUDE_SE:.2g})" if checked is None else
                "the recording does not state its polariser's constants: the paper's stand in, checked by the "
                f"calibration to +- {eps:.2g}")
            if checked is None:  # alpha's amplitude, and with it the images' contrast, is a guess: say so
                info["warning"] = "; ".join(w for w in (info.get("warning"), info["amplitude_se_why"] + (
                    " (state them: --extinction, --tau)")) if w)
    else:
        info["amplitude_se_used"] = model.amplitude_se
    return model, info


def _calibration_fit(m: Measurement, frames: np.ndarray, kw: dict[str, Any], fpn_kw: dict[str, Any],
                     method: str) -> tuple[PolarizerModel, dict[str, Any]]:
    """:func:`_calibrated`'s fit and verdict (``info['checked_se']``: the amplitude's error where the fit checked
    the stated constants and kept them)."""
    from metafovea.reconstruct.calibrate import AMPLITUDE_FLOOR, AMPLITUDE_MODEL_ERROR, fit_foveal

    model: PolarizerModel = kw["polarizer"]
    n = min(frames.shape[0], CALIBRATION_FRAMES)
    sub = replace(model, times_s=model.times_s[:n])
    geo = {k: kw[k] for k in ("scale", "foveal_gain", "foveal_offset") if k in kw}
    info: dict[str, Any] = {"frames": n, "frames_in_recording": int(frames.shape[0]), "applied": False}
    try:
        first = reconstruct(frames[:n], None, method="alternating", polarizer=sub, prior=None, strict=False,
                            **geo, **fpn_kw)
    except InputError as e:
        info["reason"] = f"the calibration pass failed: {e}"
        return model, info
    pg = first.info.get("polarizer_gauge") or {}
    if not pg.get("applied"):
        info["reason"] = f"the polariser model did not fix alpha in the calibration pass ({pg.get('reason')})"
        return model, info
    first = _flat_fielded(m, first)
    x1, x2 = np.asarray(first.x1, np.float64), np.asarray(first.x2, np.float64)
    psfs = (m.extras["psf_x1"], m.extras["psf_x2"]) if {"psf_x1", "psf_x2"} <= set(m.extras) else None
    try:  # both channel assignments: the one the relation explains is the recording's (the stated gain can mislead)
        fit = fit_foveal(0.5 * (x1 + x2), x1 - x2, scale=geo.get("scale", 6.0), gain=geo.get("foveal_gain", 1.0),
                         offset=geo.get("foveal_offset", 0.0), psfs=psfs, both_assignments=True)
    except InputError as e:
        info["reason"] = f"the foveal fit failed: {e}"
        return model, info
    swapped = fit.identified["swapped"]
    info.update(fit.summary(), psf_cross_blur=psfs is not None, channels_swapped=swapped)
    if ((fit.identified["gain"] and method == "alternating") or swapped) and fit.gain > 0:
        # the solver then tells the channels apart by the calibrated relation (a swap found here is kept even where
        # the gain is not pinned down to 1 %; the deep prior keeps its stated relation, a term of its loss)
        kw.update(foveal_gain=fit.gain, foveal_offset=fit.offset)
        if not fit.identified.get("geometry_kept") and method == "alternating":
            # the fit's geometry is the operator's: the same convention (docs/measurement_format.md, "The foveal
            # geometry"); the deep prior's foveal term has no registration
            kw.update(scale=fit.scale, offset=tuple(fit.centre_px), rotation_deg=fit.rotation_deg)
        info["constraint_used"] = {k: kw[k] for k in ("scale", "offset", "rotation_deg", "foveal_gain",
                                                       "foveal_offset") if k in kw}
    rho, se = fit.amplitude, fit.se["amplitude"]
    # the amplitude is measured against the calibration pass's images, whose gauge the polariser fit fixed: that
    # fit's own uncertainty in alpha's amplitude (a jittering rotation's, mostly) is the amplitude's too
    pfit = pg.get("fit") or {}
    se_gauge = float(pfit.get("a_se", 0.0)) / max(abs(float(pfit.get("a", 1.0))), 1e-300)
    info["se"]["amplitude_gauge"] = se_gauge
    se = float(np.hypot(se, se_gauge))
    if fit.relative_misfit > 1.0:
        info["reason"] = (f"the foveal relation does not hold in this recording (its misfit is "
                          f"{fit.relative_misfit:.2g} times the perifoveal side's contrast): the channels' "
                          "assignment rests on the stated relation and alpha's amplitude on the stated polariser; an "
                          "uncorrected fixed pattern (no shutter frames: fpn='prior' if the sensor has one) or a "
                          "wrong scale or gain are the likely causes")
        info["warning"] = info["reason"]
    elif fpn_kw.get("fpn") == "prior":
        info["reason"] = ("the fixed pattern is estimated blind, from the separated images and the stated foveal "
                          "relation: it takes a polariser that departs from the stated one for a pattern, so alpha's "
                          "amplitude cannot be calibrated (shutter frames, fpn='calibration', let it be)")
        info["warning"] = info["reason"]
    else:
        model, info = _amplitude_verdict(model, info, rho, se, max(AMPLITUDE_MODEL_ERROR * fit.relative_misfit,
                                                                   AMPLITUDE_FLOOR))
        if not fit.identified["amplitude"]:
            info["reason"] = (f"alpha's amplitude is identified by the foveal constraint only to +- {se:.2g} (too "
                              "little texture in the fovea, or a misfit): " + info["reason"])
            info["warning"] = info["reason"]
    return model, info


def _amplitude_verdict(model: PolarizerModel, info: dict[str, Any], rho: float, se: float,
                       model_error: float) -> tuple[PolarizerModel, dict[str, Any]]:
    """The calibrated amplitude ``rho`` (of the stated constants', standard error ``se``; the fit's model error
    ``model_error``) used, or not, by :func:`_calibrated`: used where it departs from 1 by more than
    ``tol = max(2 se, model_error)``, and then known to ``max(se, model_error)`` (the model's ``amplitude_se``). No
    polariser leaks less than an ideal one and no bolometer lags less than an instantaneous one, so alpha's amplitude
    is at most the ideal device's,
    ``rho_max`` times the stated one: a fit beyond it by more than ``tol`` is the foveal relation's bias (an
    uncorrected fixed pattern, haze), not the polariser's, and is said so; ``min(rho, rho_max)`` is what is used."""
    from metafovea.polarizer import RotatingPolarizer

    tol = max(2.0 * se, model_error)
    known = max(se, model_error)
    rho_max = RotatingPolarizer(model.rate_hz).amplitude / model.physics.amplitude
    info["amplitude_max"] = rho_max
    above = rho > rho_max + tol
    beyond = (f"alpha's amplitude comes out {rho:.4f} +- {se:.2g} of the stated constants', above the {rho_max:.4f} "
              "of an ideal polariser and an instantaneous bolometer: not the polariser's doing, the foveal relation "
              "is biased (an uncorrected fixed pattern, stray light); ") if above else ""
    rho_used = min(rho, rho_max)
    if abs(rho_used - 1.0) <= tol:
        info["reason"] = (beyond + "the stated polariser constants are used" if above else
                          f"alpha's amplitude agrees with the stated polariser constants ({rho:.4f} +- {se:.2g} of "
                          f"it, within {tol:.2g}: twice its error or the fit's model error; the error includes the "
                          f"calibration pass's own gauge, +- {info['se'].get('amplitude_gauge', 0.0):.2g}): they are "
                          "used")
        if above:
            info["warning"] = info["reason"]
        info["checked_se"] = known
        return model, info
    info.update(applied=True, amplitude_used=rho_used, reason=beyond + (
        f"alpha's amplitude is {rho_used:.4f} of the stated constants' ({rho:.4f} +- {se:.2g} fitted): the "
        "recording's polariser leaks more (extinction) or its bolometer is slower (tau) than stated; the calibrated "
        "amplitude is used"))
    info["warning"] = info["reason"]
    return replace(model, amplitude_scale=rho_used, amplitude_se=min(known / rho_used, 1.0)), info


def _polarizer_model(m: Measurement, method: str, alpha: np.ndarray | None, spec: PolarizerSpec,
                     kw: dict[str, Any]) -> dict[str, Any]:
    """``kw`` with ``polarizer``: for an unknown alpha (alternating, dip) the model of the polariser the file states
    (its keys, the caller's values, else the paper's: ``spec.assumed`` says which), unless ``polarizer='none'``."""
    if method in ("alternating", "dip") and alpha is None and kw.get("polarizer", "auto") == "auto":
        if not spec.rate_hz > 0:  # a stopped polariser: named where its rate came from (file key or keyword)
            file = spec.sources.get("rate_hz") == "file"
            raise InputError("polarizer_hz" if file else "rate_hz", spec.rate_hz, "a rotating polariser, 0 Hz < rate "
                             "<= 1000 Hz, for an unknown alpha (a stopped one fixes no alpha: method='lsq' with the "
                             "file's alpha)", source=m.source if file else None)
        kw["polarizer"] = PolarizerModel.from_spec(spec, m.times_s)
    elif kw.get("polarizer") in ("none", "auto"):
        kw["polarizer"] = None
    return kw


def snapshot_frame(m: Measurement) -> tuple[int, str]:
    """The frame a snapshot separates when none is asked: the one whose file alpha is nearest 1/2 (both channels
    most evenly mixed, the best-conditioned split of one frame), or frame 0 where the file states no alpha.
    Returns ``(index, why)``."""
    a = None if m.alpha is None else np.asarray(m.alpha, dtype=np.float64)
    if a is None or a.size == 0 or not np.all(np.isfinite(a)):
        return 0, "the first: the file states no alpha"
    k = int(np.argmin(np.abs(a - 0.5)))
    return k, f"the file's frame nearest alpha 1/2 (alpha {a[k]:.2f}): both channels most evenly mixed"


def _solve(m: Measurement, method: str, frames: np.ndarray, alpha: np.ndarray | None, kw: dict[str, Any],
           fpn_kw: dict[str, Any], window: int, stride: int, starts: Sequence[int] | None, denoise: str | None,
           frame: int | None, video_out: bool, progress: bool) -> tuple[Reconstruction, tuple]:
    """The solver call of :func:`reconstruct_measurement`: ``(reconstruction, spans)``."""
    T = m.shape[0]
    if method == "snapshot":
        why = None
        if frame is None:
            frame, why = snapshot_frame(m)
        if not 0 <= frame < T:
            raise InputError("frame", frame, f"0 <= frame < {T}")
        a = None if alpha is None else alpha[frame:frame + 1]
        if a is not None and not 0.0 < float(a[0]) < 1.0:
            raise InputError("alpha", f"{float(a[0]):g} (the file's, frame {frame})", "0 < alpha < 1: a snapshot needs "
                             "both channels in its frame (this one holds only one; choose another frame=N)",
                             source=m.source)
        rec = _denoised(reconstruct(frames[frame][None], a, method="snapshot", **kw, **fpn_kw), denoise)
        rec.info["frame"] = {"index": int(frame), "why": why or "as asked (frame)"}
        spans = ((frame, frame + 1),)
    elif video_out:
        rec = video(frames, alpha, window=window, stride=stride, starts=starts, method=method, denoise=denoise,
                    progress=progress, **kw)
        spans = tuple((s, s + window) for s in rec.info["window_starts"])
    else:
        if denoise and method == "lsq":
            kw["denoise"] = denoise
        if method == "dip":  # step, loss and ETA on stderr (a 290 x 290 random start runs for minutes)
            kw.setdefault("progress", progress)
        rec = reconstruct(frames, alpha, method=method, **kw, **fpn_kw)
        rec = rec if method == "lsq" else _denoised(rec, denoise)
        spans = ((0, T),)
    return rec, spans


def _video_fpn(m: Measurement, method: str, frames: np.ndarray, alpha: np.ndarray | None, kw: dict[str, Any],
               fpn_kw: dict[str, Any], window: int, stride: int, starts: Sequence[int] | None,
               progress: bool) -> tuple[np.ndarray, tuple[np.ndarray, dict[str, Any]]]:
    """The FPN of a sequence reconstructed window by window, estimated once for all windows, and the frames with it
    subtracted: from the calibration frames, or blind (``'prior'``) from the windows' separated images averaged over
    the windows. Every window's images carry the same pattern, while a moving scene's foveal detail (the foveal
    estimate's error term, :mod:`~metafovea.reconstruct.fpn`) changes from window to window and averages down; a
    static scene gains only the lower noise of the mean. Returns ``(frames - f, (f, info))``."""
    if fpn_kw.get("fpn") == "calibration":
        f, finfo = estimate_fpn(calibration=fpn_kw["calibration"])
    else:
        if kw.get("max_seconds") is not None:  # the first pass gets half the time budget
            kw = {**kw, "max_seconds": kw["max_seconds"] / 2}
        first = video(frames, alpha, window=window, stride=stride, starts=starts, method=method, progress=progress,
                      **kw)
        with warnings.catch_warnings():  # a dead pixel is NaN in every window: filled below
            warnings.simplefilter("ignore", RuntimeWarning)
            x1m = np.nanmean(np.asarray(first.x1, dtype=np.float64), axis=0)
            x2m = np.nanmean(np.asarray(first.x2, dtype=np.float64), axis=0)
        geo = {k: kw[k] for k in ("scale", "foveal_gain", "foveal_offset") if k in kw}
        f, finfo = estimate_fpn(x1=np.nan_to_num(x1m, nan=float(np.nanmean(x1m))),
                                x2=np.nan_to_num(x2m, nan=float(np.nanmean(x2m))), **geo)
        # estimated once from the separated images averaged over the windows (a first pass without FPN), then
        # subtracted from every frame before the windows are solved again
        finfo = {**finfo, "windows_averaged": int(np.shape(first.x1)[0]), "video": "windows-mean"}
    return (np.asarray(frames, dtype=np.float64) - f[None]).astype(np.float32), (f, finfo)


def _stuck_pixels(frames: np.ndarray) -> np.ndarray | None:
    """(H, W) bool: pixels whose every sample is the same value (dead, or stuck at the ADC's full scale), in a
    sequence where the other pixels change (the rotating polariser modulates every live pixel, and its noise
    alone moves it by a level in a few frames); None when there are none or fewer than :data:`STUCK_MIN_FRAMES`."""
    if frames.shape[0] < STUCK_MIN_FRAMES:
        return None
    with warnings.catch_warnings():  # a pixel without one finite sample: NaN, masked anyway
        warnings.simplefilter("ignore", RuntimeWarning)
        ptp = np.nanmax(frames, axis=0) - np.nanmin(frames, axis=0)
    stuck = ptp == 0
    if not stuck.any() or not np.nanmedian(ptp) > 0:
        return None
    return stuck


def _masked(m: Measurement, frames: np.ndarray, method: str) -> tuple[np.ndarray, dict[str, Any] | None]:
    """The frames with the samples :meth:`Measurement.invalid_samples` names left out: NaN for the solvers that
    mask (lsq, alternating and their video), filled for those that cannot (dip: each pixel's mean of its valid
    samples; snapshot: the mean of the valid pixels around it, widening until found)."""
    bad = m.invalid_samples()
    stuck = _stuck_pixels(frames) if method != "snapshot" else None
    if stuck is not None:
        bad = (np.zeros(frames.shape, bool) if bad is None else bad) | stuck[None]
    if bad is None:
        return frames, None
    lo, hi = m.valid_range_dn
    info = {"count": int(bad.sum()), "fraction": float(bad.mean()), "valid_range_dn": [lo, hi],
            "how": "masked" if method in ("lsq", "alternating") else "filled",
            "stuck_pixels": 0 if stuck is None else int(stuck.sum()),
            "bad_pixel_map": int(np.asarray(m.extras["bad_pixels"]).sum()) if "bad_pixels" in m.extras else 0}
    f = np.where(bad, np.nan, frames).astype(np.float32)
    if method == "dip":
        with warnings.catch_warnings():  # a pixel with no valid sample: the frames' mean below
            warnings.simplefilter("ignore", RuntimeWarning)
            mean = np.nanmean(f, axis=0)
        mean = np.where(np.isfinite(mean), mean, np.nanmean(f))
        f = np.where(bad, mean[None], f).astype(np.float32)
    elif method == "snapshot":
        from scipy.ndimage import uniform_filter

        for t in range(f.shape[0]):
            ok = np.isfinite(f[t])
            size = 3
            while not ok.all() and size < 4 * max(f.shape[1:]):
                num = uniform_filter(np.where(ok, f[t], 0.0).astype(np.float64), size)
                den = uniform_filter(ok.astype(np.float64), size)
                fill = (den > 1e-9) & ~ok
                f[t][fill] = (num[fill] / den[fill]).astype(np.float32)
                ok = np.isfinite(f[t])
                size = 2 * size + 1
    return f, info


def _file_alpha(m: Measurement, method: str, known_alpha: bool,
                spec: PolarizerSpec) -> tuple[np.ndarray | None, bool]:
    """``(alpha, nominal)``: the file's alpha when the method uses it (lsq, or ``known_alpha``; snapshot whenever the
    file has it: one frame cannot tell alpha, and the file knows it), else, for a polariser synchronised to the
    frames (rate and phase stated), the model's nominal alpha (``nominal`` True); None otherwise."""
    if method == "alternating" and known_alpha:
        raise InputError("known_alpha", True, "not with method 'alternating' (it estimates alpha; use lsq)")
    if method == "snapshot" and m.alpha_known:
        return m.alpha, False
    if not (known_alpha or method == "lsq"):
        return None, False
    if m.alpha is None:
        if spec.mode == "sync":
            return PolarizerModel.from_spec(spec, m.times_s).alpha(), True
        raise InputError("alpha", "absent", f"an 'alpha' array in the measurement, or a polariser synchronised to "
                         f"the frames (polarizer_mode sync, with its phase), for "
                         f"{'known_alpha=True' if known_alpha else 'method=lsq'} (or method=alternating, "
                         f"method=dip or method=snapshot for unknown alpha)", source=m.source)
    return m.alpha, False


def _nominal_check(m: Measurement, frames: np.ndarray, alpha: np.ndarray, rec: Reconstruction) -> dict[str, Any]:
    """Does the nominal alpha of a synchronised polariser (its stated rate and phase) explain the frames? Each
    frame's least-squares alpha given the separated images, against the nominal one: their rms difference and the
    noise it would have if the nominal alpha were right (the residual over the images' difference)."""
    x1, x2 = np.asarray(rec.x1, np.float64), np.asarray(rec.x2, np.float64)
    d = x1 - x2
    y = np.asarray(frames, np.float64) - x2[None]
    ok = np.isfinite(y) & np.isfinite(d)[None]
    dd = np.where(ok, d[None], 0.0)
    a_hat = np.sum(np.where(ok, y, 0.0) * dd, axis=(1, 2)) / np.maximum(np.sum(dd ** 2, axis=(1, 2)), 1e-300)
    r = np.where(ok, y - alpha[:, None, None] * d[None], 0.0)
    sig = float(np.sqrt(np.sum(r ** 2) / max(ok.sum(), 1)))
    noise = sig / max(float(np.sqrt(np.mean(np.sum(dd ** 2, axis=(1, 2))))), 1e-300)
    rms = float(np.sqrt(np.mean((a_hat - alpha) ** 2)))
    out = {"alpha_from": "nominal: the stated synchronised polariser (rate and phase)", "frames_vs_nominal_rms": rms,
           "noise": noise}
    if rms > NOMINAL_FACTOR * noise + NOMINAL_TOL:
        out["warning"] = (f"the nominal alpha of the stated polariser (synchronised, its rate and phase) differs "
                          f"from the frames' by {rms:.2g} rms (noise {noise:.2g}): the phase or rate is off; "
                          "refine_alpha=True fits them from the data")
    return out


def _fpn(m: Measurement, fpn: str | np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
    """The frames with a given pattern subtracted, and the keywords of :func:`reconstruct` for an estimated one."""
    pattern = None
    if isinstance(fpn, str):
        if fpn.strip().lower() == "file":
            raise InputError("fpn", "file", "auto, none, prior, calibration or a pattern of your own (an (H, W) "
                             "array): the file's 'fpn' is the simulator's true pattern, kept for scoring",
                             source=m.source)
        mode = check_choice("fpn", fpn, FPN_MODES)
        if mode == "prior":
            return m.frames, {"fpn": "prior"}
        if mode == "calibration":
            if "calibration" not in m.extras:
                raise InputError("fpn", "calibration", "a measurement with shutter frames (a 'calibration' "
                                 "array: simulate(calibration_frames)), or fpn='auto' (what the file allows)",
                                 detail=f"{m.source or 'this measurement'} has none")
            return m.frames, {"fpn": "calibration", "calibration": m.extras["calibration"]}
    else:
        pattern = np.asarray(fpn)
        if pattern.shape != m.shape[1:] or not np.all(np.isfinite(pattern)):
            raise InputError("fpn", f"array of shape {pattern.shape}", f"a finite (H, W) = {m.shape[1:]} pattern")
    if pattern is None:
        return m.frames, {}
    return (m.frames - pattern[None]).astype(np.float32), {}


def _denoised(rec: Reconstruction, method: str | None) -> Reconstruction:
    """``rec`` with both images denoised (noise level estimated from each image)."""
    if not method:
        return rec
    return Reconstruction(x1=denoise_image(rec.x1, method), x2=denoise_image(rec.x2, method), alpha=rec.alpha,
                          fpn=rec.fpn, method=rec.method, timings=rec.timings, info={**rec.info, "denoise": method})


def _metrics(m: Measurement, res: PipelineResult, level_free: bool) -> dict[str, float] | str | None:
    """Scores against the truth each output shows; None without truth."""
    if m.truth_x1 is None and m.truth_x2 is None:
        return None
    if res.nonfinite_pixels:
        return "not computed: NaN pixels in the reconstruction"
    # a video truth: the mean over each output's frames
    t1, t2 = (t if t is None or t.ndim == 2 or res.reconstruction.is_video else t[0] for t in m.truth_over(res.spans))
    out = score(res.reconstruction, t1, t2, level_free=level_free)
    f = res.reconstruction.fpn
    if f is not None and m.fpn is not None and np.shape(f) == m.fpn.shape:
        d = np.asarray(f, dtype=np.float64) - m.fpn
        out["fpn_rms_error"] = float(np.sqrt(np.mean((d - d.mean()) ** 2)))
        out["fpn_rms_true"] = float(np.std(m.fpn))
    return out


def _alpha_mae(m: Measurement, res: PipelineResult, estimated: bool) -> float | None:
    """Mean over outputs of the mean |alpha estimate - file alpha| over the output's frames."""
    rec = res.reconstruction
    if not (estimated and m.alpha_known) or rec.info.get("alpha_assumed"):
        return None
    per_output = rec.info.get("alpha_windows") if rec.is_video else [rec.alpha]
    if per_output is None:
        return None
    return float(np.mean([np.mean(np.abs(np.asarray(ae) - m.alpha[a:b])) for ae, (a, b) in zip(per_output, res.spans)]))

"""The reconstruction method from the recording's motion and the time allowed: ``reconstruct_measurement(m, 'auto',
time_s=T)``, ``metafovea reconstruct --method auto --time-s T``.

Motion (:func:`motion_of`)
--------------------------
A static scene seen through the rotating polariser gives every pixel ``y_t = x2 + alpha_t (x1 - x2)`` (+ the fixed
pattern, + noise): the frames, each pixel's mean removed, are one image times one number per frame (rank one),
whatever alpha is, and whatever the polariser's leak, lag or jitter do to it. A moving scene is not. The first
principal component of the centred frames is removed (at most :data:`MOTION_MAX_FRAMES` frames, spread over the
recording) and each pixel's residual variance (``T - 2`` degrees of freedom) is compared with the noise variance:
from the file's shutter frames (their temporal variance, the median over the pixels) when it has them, else from
the residual frames themselves (Immerkaer's estimator, which a moving edge barely moves). A pixel *changes* when
its residual variance exceeds :data:`MOTION_VARIANCE_FACTOR` times the noise's, or the chi-square quantile of
false-alarm rate :data:`MOTION_FALSE_ALARM` for few frames; the recording is *moving* when more than
:data:`MOTION_FRACTION` of its valid pixels change. Pixels with an invalid sample (clipped, bad, non-finite) are
left out.

Cost (:func:`predicted_seconds`)
--------------------------------
Each method's wall time as a fixed cost per run plus a linear model in the work it does (:data:`SECONDS_PER`):
frame-pixels of the one-window solve, window-frame-pixels of the sliding windows, frame-pixels of the unknown-alpha
calibration pass, window-pixels of the denoising, pixels of the PSF-aware step. The constants are each method's
speed on the development machine (their source beside them, ``benchmarks/bench_auto.py`` reruns them): a
prediction, not a promise, and the summary reports the time taken.

The choice (:func:`choose_method`)
----------------------------------
The solver is the file's: ``lsq`` when alpha is known (the file's, a synchronised polariser's nominal one, or
``known_alpha``), else ``alternating`` (the polariser model fixes its gauge). The deep image prior is not a candidate:
its gain over the classical solvers depends on the scene and it costs minutes per window (ask for it by name).
The candidates, most accurate first; the first whose predicted time fits ``time_s`` is chosen (with no ``time_s``
the first), and when none fits the fastest, said so:

========== ========================================================================================================
static     one window of all frames (the lowest noise), then the PSF-aware scene (``deconvolve_result``) with
           ``wavelet``, else ``wiener``, else none (only when the file holds the channels' PSFs)
moving     sliding windows of :data:`~metafovea.reconstruct.api.DEFAULT_WINDOW` frames (each follows the scene) at
           stride 1, 2, 4, then one window's length (disjoint windows); a sequence no longer than one window is one
========== ========================================================================================================

A window, stride or PSF-aware method the caller gives is kept, and the choice says so.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from metafovea.errors import InputError, check_choice, check_int, check_positive
from metafovea.measurement import Measurement
from metafovea.reconstruct._common import (
    CALIBRATION_FRAMES,
    DECONVOLUTION_METHODS,
    DEFAULT_WINDOW,
    estimate_noise,
)

#: a pixel changes when its residual variance exceeds this many times the noise variance (a residual above
#: sqrt(3) noise standard deviations): robust to a noise estimate that is off by tens of percent
MOTION_VARIANCE_FACTOR = 4.0
#: ... or, for few frames, the chi-square quantile of this false-alarm rate per pixel
MOTION_FALSE_ALARM = 1e-4
#: the share of valid pixels that must change for the recording to be moving (a car of 20 pixels in 96 x 96)
MOTION_FRACTION = 2e-3
#: the motion test reads at most this many frames, spread evenly over the recording
MOTION_MAX_FRAMES = 128
#: the PSF-aware methods auto considers, most accurate first (BENCHMARKS.md, "PSF-aware reconstruction on scenes
#: never seen": wavelet above wiener against the Wiener bound)
SCENE_METHODS = ("wavelet", "wiener")
#: seconds per unit of work (see :func:`predicted_seconds`): twice what 192 x 192 simulated recordings of 48 frames
#: took on the 2-core development machine (benchmarks/bench_auto.py, BENCHMARKS.md: the best of 5 repeats; the
#: factor 2 for a busier machine and larger frames); the snapshot's and TV's from BENCHMARKS.md at 290 x 290
SECONDS_PER = {
    "call": 0.02,                     # every run: masks, the fixed pattern, the windows' set-up (0.02-0.03 s)
    "lsq_frame_px": 2e-8,             # lsq, one window: per frame and pixel (9.6e-9)
    "lsq_window_frame_px": 3e-9,      # lsq, sliding windows: per window, frame and pixel (1.6e-9)
    "alternating_frame_px": 2e-7,     # alternating, per window, frame and pixel (1.06e-7)
    "calibration_frame_px": 5e-7,     # alternating's calibration pass: per frame and pixel (2.1e-7)
    "snapshot_px": 4e-5,              # one frame (100 L-BFGS iterations: 2.7 s at 290^2, BENCHMARKS.md)
    "denoise_window_px": 1.5e-6,      # TV denoising of both images, per window and pixel (6e-7 to 7e-7)
    "deconvolve_wiener_px": 1e-5,     # the PSF-aware step, per pixel (4.9e-6)
    "deconvolve_wavelet_px": 5.5e-5,  # (2.7e-5)
    "deconvolve_tv_px": 5e-4,         # (100 ADMM iterations: 13-19 s at 290^2, BENCHMARKS.md)
}


@dataclass(frozen=True)
class Motion:
    """How much of a recording changes beyond its noise (module docstring): ``moving``; ``fraction`` of the valid
    pixels that change; ``threshold`` (residual over noise variance above which a pixel changes); ``noise_dn`` and
    where it came from (``noise_from``); ``excess`` (rms residual over the noise: 1 for a static scene);
    ``frames`` and ``pixels`` read."""

    moving: bool
    fraction: float
    threshold: float
    noise_dn: float
    noise_from: str
    excess: float
    frames: int
    pixels: int

    def summary(self) -> dict[str, Any]:
        return {"moving": self.moving, "changing_fraction": self.fraction, "changing_above": MOTION_FRACTION,
                "variance_threshold": self.threshold, "noise_dn": self.noise_dn, "noise_from": self.noise_from,
                "residual_over_noise": self.excess, "frames": self.frames, "pixels": self.pixels}

    @property
    def why(self) -> str:
        if self.frames < 3:
            return f"static {self.noise_from}"
        return (f"{'moving' if self.moving else 'static'}: {100 * self.fraction:.3g} % of the pixels change beyond "
                f"{self.threshold:.3g} x the noise variance (limit {100 * MOTION_FRACTION:g} %; noise "
                f"{self.noise_dn:.3g} DN {self.noise_from})")


def motion_of(m: Measurement) -> Motion:
    """The motion of a recording's scene beyond its noise (module docstring).

    Parameters
    ----------
    m : Measurement
        Its frames ``(T, H, W)``, the shutter frames ``extras['calibration']`` when it has them.

    Returns
    -------
    Motion
        Fewer than 3 frames cannot tell (one image and one number per frame fit any 2): static, said so.
    """
    from scipy.stats import chi2

    F = np.asarray(m.frames)
    T = F.shape[0]
    if T < 3:
        return Motion(False, 0.0, float("nan"), float("nan"), f"(not measured: {T} frame(s) cannot tell)",
                      float("nan"), T, 0)
    idx = np.unique(np.linspace(0, T - 1, min(T, MOTION_MAX_FRAMES)).round().astype(int))
    X = np.asarray(F[idx], dtype=np.float64).reshape(idx.size, -1)
    bad = m.invalid_samples()
    ok = np.all(np.isfinite(X), axis=0) if bad is None else ~np.any(bad[idx].reshape(idx.size, -1), axis=0)
    X = X[:, ok] - X[:, ok].mean(axis=0)
    n = idx.size
    _, vecs = np.linalg.eigh(X @ X.T)
    v = vecs[:, -1:]
    R = X - v @ (v.T @ X)
    var = np.sum(R ** 2, axis=0) / max(n - 2, 1)
    noise, src = _noise(m, R, ok, n)
    thr = max(MOTION_VARIANCE_FACTOR, float(chi2.ppf(1 - MOTION_FALSE_ALARM, max(n - 2, 1))) / max(n - 2, 1))
    frac = float(np.mean(var > thr * noise ** 2)) if var.size else 0.0
    excess = float(np.sqrt(np.mean(var)) / noise) if var.size and noise > 0 else float("nan")
    return Motion(frac > MOTION_FRACTION, frac, thr, noise, src, excess, n, int(ok.sum()))


def _noise(m: Measurement, R: np.ndarray, ok: np.ndarray, n: int) -> tuple[float, str]:
    """The frames' temporal noise (DN) and where it came from: the shutter frames, else the residual frames."""
    cal = m.extras.get("calibration")
    if cal is not None and np.ndim(cal) == 3 and np.shape(cal)[0] >= 2:
        c = np.asarray(cal, dtype=np.float64).reshape(np.shape(cal)[0], -1)[:, ok]
        return float(np.sqrt(np.median(np.var(c, axis=0, ddof=1)))), \
            f"from the file's {np.shape(cal)[0]} shutter frames"
    H, W = m.shape[1:]
    if not ok.all():  # the residual on the image grid, left-out pixels at 0 (a few edges in the estimator)
        full = np.zeros((R.shape[0], H * W))
        full[:, ok] = R
        R = full
    est = np.median([estimate_noise(r.reshape(H, W)) for r in R])
    return float(est * np.sqrt(n / max(n - 2, 1))), "from the frames (Immerkaer's estimator on the residual)"


def windows_of(frames: int, window: int, stride: int) -> int:
    """The number of sliding windows of ``window`` frames at ``stride`` over ``frames`` frames."""
    return (frames - window) // stride + 1


def predicted_seconds(method: str, frames: int, pixels: int, window: int, stride: int = 1, *,
                      denoise: str | None = None, deconvolve: str | None = None, field_patches: int = 1) -> float:
    """The predicted wall seconds of a reconstruction (:data:`SECONDS_PER`).

    Parameters
    ----------
    method : {'lsq', 'alternating', 'snapshot'}
    frames, pixels : int
        The recording's frames and pixels per frame.
    window, stride : int
        Frames per window (``window == frames``: one window) and the windows' stride.
    denoise : str or None
        Denoising of each window's images (costed as TV).
    deconvolve : {'wavelet', 'wiener', 'tv'} or None
        The PSF-aware step after a one-window reconstruction.
    field_patches : int
        Patches a side of the file's field-dependent PSF (``psf_patches_x*``): the PSF-aware step may solve each
        (:mod:`metafovea.reconstruct.field`), so it is costed ``field_patches^2`` times (at most).
    """
    method = check_choice("method", method, ("lsq", "alternating", "snapshot"))
    k = windows_of(frames, window, stride)
    s = SECONDS_PER
    if method == "snapshot":
        t = s["snapshot_px"] * pixels
    elif method == "lsq":
        t = s["lsq_frame_px"] * frames * pixels if k == 1 else s["lsq_window_frame_px"] * k * window * pixels
    else:
        t = (s["calibration_frame_px"] * min(frames, CALIBRATION_FRAMES) + s["alternating_frame_px"] * k * window) \
            * pixels
    t += s["call"]
    if denoise is not None:
        t += s["denoise_window_px"] * k * pixels
    if deconvolve is not None:
        t += (s[f"deconvolve_{check_choice('deconvolve', deconvolve, DECONVOLUTION_METHODS)}_px"] * pixels
              * check_int("field_patches", field_patches, 1, 9) ** 2)
    return float(t)


@dataclass(frozen=True)
class MethodChoice:
    """What :func:`choose_method` chose: the solver (``method``), ``window``, ``stride`` and ``denoise``, the PSF-aware
    step to run after it (``deconvolve``, None for none), the motion it saw, the time allowed and predicted, the
    candidates (``rows``: each with its predicted seconds and whether it fits), why, and what was ``given``."""

    method: str
    window: int
    stride: int
    denoise: str | None
    deconvolve: str | None
    motion: Motion
    time_s: float | None
    predicted_s: float
    rows: tuple[dict[str, Any], ...]
    why: str
    given: tuple[str, ...] = field(default=())

    def summary(self) -> dict[str, Any]:
        """The choice as JSON (``info['auto']`` of the reconstruction, the ``--json`` summary)."""
        return {"stage": "reconstruct", "tolerance_s": self.time_s,
                "chose": {"method": self.method, "window": self.window, "stride": self.stride,
                          "denoise": self.denoise, "deconvolve": self.deconvolve},
                "predicted_s": self.predicted_s, "why": self.why, "motion": self.motion.summary(),
                "given": list(self.given), "rows": [dict(r) for r in self.rows]}


def choose_method(m: Measurement, time_s: float | None = None, *, known_alpha: bool = False,
                  window: int | None = None, stride: int | None = None, denoise: str | None = None,
                  deconvolve: str | None = None, polarizer: dict[str, Any] | None = None) -> MethodChoice:
    """The reconstruction of ``m`` that fits the time allowed: the solver from what the file knows of alpha, one
    window or sliding windows from the scene's motion, the stride, the denoising and the PSF-aware step from the
    time (module docstring).

    Parameters
    ----------
    m : Measurement
    time_s : float, s, optional
        The time allowed for the reconstruction (and the PSF-aware step); None: no limit.
    known_alpha : bool
        Alpha is known (as :func:`~metafovea.reconstruct.reconstruct_measurement`'s).
    window, stride : int, optional
        Given: kept (the choice says so).
    denoise : {'tv', 'bilateral', 'nlm', 'none'}, optional
        Given: kept; None: ``'tv'`` (kept by the pipeline only where its risk estimate says it lowers the error)
        or none, by the time.
    deconvolve : {'wavelet', 'wiener', 'tv', 'none'}, optional
        Given: kept (``'none'``: no PSF-aware step); None: chosen.
    polarizer : dict, optional
        Polariser values before the file's (a synchronised polariser's nominal alpha counts as known).

    Returns
    -------
    MethodChoice
    """
    tmax = None if time_s is None else check_positive("time_s", time_s, "s")
    T, H, W = m.shape
    spec = m.polarizer_spec(**(polarizer or {}))
    solver = ("snapshot" if T == 1 else
              "lsq" if (known_alpha or m.alpha_known or spec.mode == "sync") else "alternating")
    mo = motion_of(m)
    given = tuple(k for k, v in (("window", window), ("stride", stride), ("denoise", denoise),
                                 ("deconvolve", deconvolve)) if v is not None)
    fp = max([1] + [int(np.shape(m.extras[k])[0]) for k in ("psf_patches_x1", "psf_patches_x2") if k in m.extras])
    rows = [{"method": solver, "window": w, "stride": s, "denoise": dn, "deconvolve": d,
             "predicted_s": predicted_seconds(solver, T, H * W, w, s, denoise=dn, deconvolve=d, field_patches=fp)}
            for w, s, dn, d in _candidates(m, mo.moving, T, window, stride, denoise, deconvolve)]
    for r in rows:
        r["fits"] = tmax is None or r["predicted_s"] <= tmax
    pick = next((r for r in rows if r["fits"]), None) or min(rows, key=lambda r: r["predicted_s"])
    return MethodChoice(solver, pick["window"], pick["stride"], pick["denoise"], pick["deconvolve"], mo, tmax,
                        pick["predicted_s"], tuple(rows), _why(solver, pick, rows, mo, tmax, T, given), given)


def _candidates(m: Measurement, moving: bool, T: int, window: int | None, stride: int | None, denoise: str | None,
                deconvolve: str | None) -> list[tuple[int, int, str | None, str | None]]:
    """``(window, stride, denoise, deconvolve)`` of each candidate, most accurate first. The PSF-aware step is a
    candidate for a static scene (one window of all frames) whose file holds the channels' PSFs, or when given."""
    from metafovea.reconstruct.denoise import DENOISERS

    if deconvolve is not None:
        d = check_choice("deconvolve", deconvolve, (*DECONVOLUTION_METHODS, "none"))
        scene: tuple[str | None, ...] = (None if d == "none" else d,)
    elif not moving and T > 1 and "psf_x1" in m.extras and "psf_x2" in m.extras:
        scene = (*SCENE_METHODS, None)
    else:
        scene = (None,)
    if denoise is not None:
        dn = check_choice("denoise", denoise, (*DENOISERS, "none"))
        plain: tuple[str | None, ...] = (None if dn == "none" else dn,)
    else:
        plain = ("tv", None)
    if window is not None or stride is not None:
        w = window if window is not None else (DEFAULT_WINDOW if moving and T > DEFAULT_WINDOW else T)
        if not 2 <= w <= T:
            raise InputError("window", w, f"2 <= window <= number of frames ({T})")
        paths = [(w, stride or 1)]
    elif not moving or T <= DEFAULT_WINDOW:  # (one frame: the snapshot of frame 0)
        paths = [(T, 1)]
    else:
        paths = [(DEFAULT_WINDOW, s) for s in (1, 2, 4, DEFAULT_WINDOW)]
    # the denoised images first (the stride barely changes each frame's error: its nearest window is at most half a
    # stride away), then the PSF-aware steps, most accurate first, each after the first denoising
    out = [(w, s, plain[0], d) for d in scene for w, s in paths]
    out += [(w, s, dn, None) for dn in plain[1:] for w, s in paths]
    return out


def _why(solver: str, pick: dict[str, Any], rows: list[dict[str, Any]], mo: Motion, tmax: float | None, T: int,
         given: tuple[str, ...]) -> str:
    alpha = {"lsq": "alpha known", "alternating": "alpha unknown", "snapshot": "one frame"}[solver]
    path = (f"one window of all {T} frames" if pick["window"] == T else
            f"sliding windows of {pick['window']} frames at stride {pick['stride']}")
    steps = "".join(f", {k} {pick[k]}" for k in ("denoise", "deconvolve") if pick[k])
    time = ("no time limit: the most accurate candidate" if tmax is None else
            f"predicted {pick['predicted_s']:.3g} s <= {tmax:g} s allowed" if pick["fits"] else
            f"no candidate fits {tmax:g} s: the fastest, predicted {pick['predicted_s']:.3g} s")
    better = [r for r in rows[:rows.index(pick)] if not r["fits"]]
    if better:
        time += f" (a more accurate one needs {better[-1]['predicted_s']:.3g} s)"
    kept = f"; kept as given: {', '.join(given)}" if given else ""
    return f"{solver} ({alpha}), {path}{steps}: {mo.why}; {time}{kept}"


def auto_lines(auto: dict[str, Any] | None, scene: Any = None) -> list[str]:
    """What ``metafovea reconstruct --method auto`` prints: the choice and why, the time predicted and taken (the
    PSF-aware step's, ``scene`` a :class:`~metafovea.reconstruct.deconvolve.Deconvolution`, included) and the images'
    expected noise; nothing for a run that was not ``auto`` (``auto`` None)."""
    if not auto:
        return []
    took = auto["seconds"] + (float(scene.info.get("seconds", 0.0)) if scene is not None else 0.0)
    allowed = "no limit" if auto["tolerance_s"] is None else f"{auto['tolerance_s']:g} s allowed"
    line = f"auto: predicted {auto['predicted_s']:.3g} s ({allowed}), took {took:.3g} s"
    if auto.get("noise_dn"):
        line += (f"; expected noise x1 {auto['noise_dn'][0]:.3g} DN, x2 {auto['noise_dn'][1]:.3g} DN rms (the frames' "
                 "noise through the solver, before denoising)")
    return [f"auto: {auto['why']}", line]

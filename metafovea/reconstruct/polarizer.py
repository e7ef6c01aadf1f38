"""What the reconstruction knows about the rotating polariser, and the alpha gauge it fixes.

The data term leaves ``alpha`` known only up to an affine map (``alpha_hat = a alpha + b``, see
:mod:`metafovea.reconstruct.alternating`). The polariser fixes it: the sensor sees the effective ratio

    alpha_t = 1/2 + s cos(Omega t + phi),   Omega = 4 pi f_p,   s = A (1 - e) / (2 (1 + e)),

(:mod:`metafovea.polarizer`, the one model of the device that the simulator uses too: extinction leak ``e``,
bolometer lag ``tau`` with amplitude ``A = 1 / sqrt(1 + (Omega tau)^2)`` and phase lag ``atan(Omega tau)``), whose
mean (1/2) and amplitude ``s`` are known from the system, whatever the rotation's phase. Fitting
``alpha_hat_t = A0 + B cos(Omega t) + C sin(Omega t)`` gives ``a = +-hypot(B, C) / s`` and ``b = A0 - a / 2``. A
synchronised polariser (``mode='sync'``: rate and phase known) regresses ``alpha_hat`` on the model directly; a
free-running one (``'free'``) also fits ``Omega`` within ``rate_tolerance`` of the nominal rate and leaves the sign
of ``a`` open (the sign swaps the two channels), which the caller settles with the foveal constraint.

Two ways to use the fit: the fitted rotation's alpha (:func:`model_alpha`, the default: a motor turns at a
constant rate, and a frame's own ``alpha_hat`` is biased wherever the scene moves between frames), or each frame's
own ``alpha_t = (alpha_hat_t - b) / a`` (:func:`gauged_alpha`: follows a rotation that jitters). The fit's residual
gives the uncertainty of ``(a, b)``, of the phase and frequency and of every ``alpha_t`` (delta method), and
flags a stopped polariser (amplitude at the noise level) or an irregular sequence (residual well above the
data-term noise of ``alpha_hat``: scene motion or a jittering rotation; the default follows each frame only where the
image's parts share the deviation, :func:`metafovea.reconstruct.alternating.deviation_shared`). Measured accuracies:
BENCHMARKS.md, "Unknown alpha with the polariser model".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.errors import InputError, check_range
from metafovea.measurement import PolarizerSpec
from metafovea.polarizer import ALPHA_MEAN, RotatingPolarizer, check_mode

#: alpha counts as identified when its standard error (gauge and per-frame) is below this in every frame
ALPHA_SE_MAX = 5e-3
#: residual rms above this many times the data-term noise of alpha_hat: an irregular rotation
JITTER_FACTOR = 3.0
#: a free-running polariser's rate is searched on this many points over +- ``rate_tolerance`` (numerical: the
#: parabolic refinement resolves the minimum far below the step), and this many steps past either end, so that a
#: rate at the tolerance's very end is refined and its error estimated like any other
RATE_GRID_POINTS = 201
RATE_GRID_MARGIN = 3


@dataclass(frozen=True)
class PolarizerModel:
    """The polariser as the reconstruction knows it: frame times, nominal rate, mode (phase known or not),
    extinction leak and bolometer time constant (see module docstring)."""

    times_s: np.ndarray
    rate_hz: float = 2.0
    mode: str = "free"
    phase_rad: float | None = None  # sync: the rotation's phase at t = 0
    extinction: float = 0.0
    tau_s: float = 0.0
    rate_tolerance: float = 0.05  # free: the actual rate is searched within +- this fraction of rate_hz
    #: the amplitude of alpha over the one the device's constants give, calibrated from the recording
    #: (:mod:`metafovea.reconstruct.calibrate`: a polariser that leaks more, or a slower bolometer, than stated)
    amplitude_scale: float = 1.0
    #: the relative standard error of the amplitude (``amplitude_scale`` x the constants'): 0 where the stated
    #: constants are taken as exact; the calibration's error where it measured the amplitude; it widens every
    #: frame's alpha error (:func:`polarizer_gauge`'s ``(a, b)`` covariance, :func:`model_alpha`)
    amplitude_se: float = 0.0

    def __post_init__(self) -> None:
        t = np.asarray(self.times_s, dtype=np.float64).reshape(-1)
        if not np.all(np.isfinite(t)):
            raise InputError("times_s", "non-finite", "finite frame times (s)")
        object.__setattr__(self, "times_s", t)
        check_range("polarizer rate_hz", self.rate_hz, 0.0, 1000.0, unit="Hz")  # a stopped one fixes no gauge
        object.__setattr__(self, "mode", check_mode(self.mode))
        if self.mode == "sync" and self.phase_rad is None:
            raise InputError("polarizer phase_rad", None, "the rotation's phase for a synchronised polariser")
        RotatingPolarizer(self.rate_hz, self.extinction, self.tau_s)  # checks the device's constants
        check_range("rate_tolerance", self.rate_tolerance, 0.0, 0.5, lo_inclusive=True)
        check_range("amplitude_scale", self.amplitude_scale, 0.0, 2.0)
        check_range("amplitude_se", self.amplitude_se, 0.0, 1.0, lo_inclusive=True)

    @classmethod
    def from_spec(cls, spec: PolarizerSpec, times_s: ArrayLike) -> PolarizerModel:
        """The model of a recording's polariser (:class:`~metafovea.measurement.PolarizerSpec`: its documented keys,
        flags, defaults) at the frame times ``times_s``."""
        phase = None if spec.phase_deg is None else math.radians(math.fmod(spec.phase_deg, 360.0))  # fmod: exact
        return cls(times_s, rate_hz=spec.rate_hz, mode=spec.mode, phase_rad=phase, extinction=spec.extinction,
                   tau_s=spec.tau_s)

    def window(self, start: int, n: int) -> PolarizerModel:
        return replace(self, times_s=self.times_s[start:start + n])

    @property
    def physics(self) -> RotatingPolarizer:
        """The device's constants and the model of alpha (:class:`~metafovea.polarizer.RotatingPolarizer`)."""
        return RotatingPolarizer(self.rate_hz, self.extinction, self.tau_s)

    @property
    def omega(self) -> float:
        """Angular frequency of alpha (rad/s): twice the rotation's."""
        return self.physics.omega

    @property
    def lag_rad(self) -> float:
        """The bolometer's phase lag at :attr:`omega` (rad)."""
        return self.physics.lag_rad

    @property
    def amplitude(self) -> float:
        """``s``: half the peak-to-peak range of the effective alpha."""
        return self.physics.amplitude * self.amplitude_scale

    def alpha(self, times_s: ArrayLike | None = None, omega: float | None = None,
              phase: float | None = None) -> np.ndarray:
        """The model's effective alpha at ``times_s`` (default the frames'), for a phase of alpha ``phase``
        (default that of the rotation's phase ``phase_rad``, 0 when unknown)."""
        t = self.times_s if times_s is None else times_s
        ph = self.physics.alpha_phase(self.phase_rad or 0.0) if phase is None else phase
        return ALPHA_MEAN + self.amplitude_scale * (self.physics.alpha(t, ph, omega) - ALPHA_MEAN)


def _design(t: np.ndarray, w: float) -> np.ndarray:
    return np.stack([np.ones_like(t), np.cos(w * t), np.sin(w * t)], axis=1)


def _free_omega(t: np.ndarray, y: np.ndarray, model: PolarizerModel) -> tuple[float, float, bool]:
    """The alpha frequency within the model's tolerance with the smallest sinusoid-fit residual (grid, then a
    parabolic refinement), the residual's curvature there (d^2 rss / d omega^2; 0 when not resolved) and whether the
    minimum lies on the search's edge (the rate may be outside the tolerance). The grid runs
    :data:`RATE_GRID_MARGIN` steps past either end of the tolerance, so that a rate at its very end is bracketed and
    refined like any other."""
    w0 = model.omega
    tol = model.rate_tolerance
    if tol == 0:
        return w0, 0.0, False
    step_rel = 2 * tol / (RATE_GRID_POINTS - 1)
    span = tol + RATE_GRID_MARGIN * step_rel
    grid = w0 * (1 + np.linspace(-span, span, RATE_GRID_POINTS + 2 * RATE_GRID_MARGIN))

    def rss(w: float) -> float:
        X = _design(t, w)
        coef, *_ = np.linalg.lstsq(X, y, rcond=None)
        return float(np.sum((y - X @ coef) ** 2))

    r = np.array([rss(w) for w in grid])
    i = int(np.argmin(r))
    step = float(grid[1] - grid[0])
    if 0 < i < len(grid) - 1:
        den = r[i - 1] - 2 * r[i] + r[i + 1]
        if den > 0:
            w = float(grid[i] + 0.5 * step * (r[i - 1] - r[i + 1]) / den)
            h = 0.25 * step
            curv = (rss(w - h) - 2 * rss(w) + rss(w + h)) / (h * h)
            return w, max(curv, 0.0), False
    return float(grid[i]), 0.0, i in (0, len(grid) - 1)


def polarizer_gauge(alpha_hat: np.ndarray, model: PolarizerModel, *,
                    alpha_noise: float | None = None) -> dict[str, Any]:
    """Fit the model to the data-term ``alpha_hat`` (any affine gauge): returns ``a``, ``b`` (``alpha_hat = a alpha
    + b``; free mode: the ``a > 0`` candidate, ``swap_ambiguous`` True), their covariance (and standard errors
    ``a_se``, ``b_se``), the residual rms, the
    fitted frequency and phase, ``status`` ('ok', 'stopped', 'too few frames') and, with ``alpha_noise`` (the
    data-term noise std of ``alpha_hat`` in its gauge), the rotation's irregularity (``jitter_rms``, in the
    absolute gauge) and ``irregular`` when the residual exceeds :data:`JITTER_FACTOR` times that noise."""
    y = np.asarray(alpha_hat, dtype=np.float64).reshape(-1)
    t = model.times_s
    if t.shape != y.shape:
        raise InputError("times_s", f"{t.size} times", f"one time per frame ({y.size})")
    T = y.size
    s = model.amplitude
    out: dict[str, Any] = {"mode": model.mode, "amplitude_model": s, "frames": T}
    n_par = 2 if model.mode == "sync" else 4
    if T < n_par + 2:
        out.update(status="too few frames", reason=f"{T} frames for {n_par} parameters (need {n_par + 2})")
        return out
    if model.mode == "sync":
        m = model.alpha()
        X = np.stack([m, np.ones_like(m)], axis=1)
        coef, *_ = np.linalg.lstsq(X, y, rcond=None)
        res = y - X @ coef
        var = float(np.sum(res ** 2)) / (T - 2)
        cov = var * np.linalg.inv(X.T @ X)
        a, b = float(coef[0]), float(coef[1])
        out.update(omega=model.omega, phase=model.physics.alpha_phase(model.phase_rad), swap_ambiguous=False,
                   t_centre=float(t.mean()), var_phase_centre=0.0, var_omega=0.0)
        out["phase_centre"] = out["phase"] + model.omega * out["t_centre"]
    else:
        tm = float(t.mean())
        tc = t - tm  # centred: the phase at the window's middle and the frequency are nearly uncorrelated
        w, curv, edge = _free_omega(tc, y, model)
        X = _design(tc, w)
        coef, *_ = np.linalg.lstsq(X, y, rcond=None)
        res = y - X @ coef
        var = float(np.sum(res ** 2)) / (T - 4)
        S = var * np.linalg.inv(X.T @ X)  # cov of (A0, B, C)
        A0, B, C = (float(v) for v in coef)
        R = math.hypot(B, C)
        g = np.array([0.0, B / R, C / R]) if R > 0 else np.zeros(3)
        # a = R / s, b = A0 - a / 2: their covariance from (A0, B, C)'s by the Jacobian
        J = np.array([g / s, np.array([1.0, 0.0, 0.0]) - ALPHA_MEAN * g / s])
        cov = J @ S @ J.T
        a, b = R / s, A0 - ALPHA_MEAN * R / s
        # alpha_hat = A0 + R cos(w tc - atan2(C, B)); alpha = 1/2 + s cos(w tc + phi_c) for a > 0
        gp = np.array([0.0, C / (R * R), -B / (R * R)]) if R > 0 else np.zeros(3)
        var_w = 2 * var / curv if curv > 0 else math.inf
        if math.isfinite(var_w) and R > 0:  # (a, b) move with the fitted frequency too: add that spread
            sw = math.sqrt(var_w)
            ab = []
            for ww in (w - sw, w + sw):
                cf, *_ = np.linalg.lstsq(_design(tc, ww), y, rcond=None)
                rr = math.hypot(cf[1], cf[2]) / s
                ab.append((rr, cf[0] - ALPHA_MEAN * rr))
            dab = 0.5 * (np.array(ab[1]) - np.array(ab[0]))
            cov = cov + np.outer(dab, dab)
        phi_c = -math.atan2(C, B)
        out.update(omega=w, rate_hz=w / (4 * math.pi), phase=phi_c - w * tm, phase_centre=phi_c, t_centre=tm,
                   var_phase_centre=float(gp @ S @ gp), var_omega=var_w, swap_ambiguous=True,
                   rate_at_search_edge=edge)
    rms = math.sqrt(float(np.mean(res ** 2)))
    # few degrees of freedom: the residual variance is itself uncertain; scale the covariance so that 1.96 SE is
    # the two-sided 95 % t interval of T - n_par degrees of freedom
    from scipy.stats import t as student_t

    infl = (float(student_t.ppf(0.975, T - n_par)) / 1.959964) ** 2
    cov = cov * infl
    for k in ("var_phase_centre", "var_omega"):
        out[k] = out[k] * infl
    out["t_inflation"] = infl
    sa = math.sqrt(max(cov[0][0], 0.0))  # the data's own: a stopped polariser is judged by it
    if model.amplitude_se > 0:  # s known to a relative eps: a = R / s, b = A0 - a / 2 move by (-a eps, a eps / 2)
        ga = np.array([-a, ALPHA_MEAN * a]) * model.amplitude_se
        cov = cov + np.outer(ga, ga)
        out["amplitude_se"] = model.amplitude_se
    out.update(a=a, b=b, cov=cov.tolist(), a_se=math.sqrt(max(float(cov[0][0]), 0.0)),
               b_se=math.sqrt(max(float(cov[1][1]), 0.0)), residual_rms=rms,
               residual_rms_absolute=rms / abs(a) if a else math.inf)
    if not abs(a) > 0 or sa > 0.2 * abs(a):
        out.update(status="stopped", reason=f"alpha's variation at the noise level (amplitude {a * s:.3g} of the "
                                           f"data-term alpha, uncertainty {sa * s:.3g}): the polariser is stopped, "
                                           "too slow for the window, or one channel is dark")
        return out
    out["status"] = "ok"
    if alpha_noise is not None:
        out["alpha_noise_absolute"] = alpha_noise / abs(a)
        out["jitter_rms"] = math.sqrt(max(rms ** 2 - alpha_noise ** 2, 0.0)) / abs(a)
        out["irregular"] = bool(rms > JITTER_FACTOR * alpha_noise * math.sqrt(T / max(T - n_par, 1)))
    return out


def _signed_gauge(fit: dict[str, Any], sign: float) -> tuple[float, float, np.ndarray]:
    """The fit's ``(a, b)`` and their covariance for the channel assignment ``sign`` (-1: the other candidate of a
    free-running fit; ``A0 = b + a / 2`` stays, ``a -> -a``, so ``b' = b + a``)."""
    a, b = float(fit["a"]), float(fit["b"])
    cov = np.asarray(fit["cov"], dtype=np.float64)
    if sign < 0:
        Jm = np.array([[-1.0, 0.0], [1.0, 1.0]])  # (a', b') from (a, b)
        return -a, b + a, Jm @ cov @ Jm.T
    return a, b, cov


def gauged_alpha(alpha_hat: np.ndarray, fit: dict[str, Any], sign: float = 1.0,
                 frame_noise: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``alpha_t = (alpha_hat_t - b) / a`` for the fit's ``(a, b)`` (``sign`` -1: the other candidate of a
    free-running fit, ``a -> -a``, ``b -> A0 + a / 2``), and each frame's standard error: the gauge's uncertainty
    (delta method) and the per-frame scatter (the fit's residual, conservative: it also holds any jitter; or
    ``frame_noise``, the data-term noise of ``alpha_hat`` in its gauge, when the frames' own alpha is used)."""
    y = np.asarray(alpha_hat, dtype=np.float64)
    a, b, cov = _signed_gauge(fit, sign)
    al = (y - b) / a
    var_frame = fit["residual_rms"] ** 2 * fit.get("t_inflation", 1.0) * fit["frames"] / max(
        fit["frames"] - (2 if fit["mode"] == "sync" else 4), 1)
    if frame_noise is not None:  # each frame's own alpha, which follows a jitter: only its data-term noise
        var_frame = frame_noise ** 2 * fit.get("t_inflation", 1.0)
    var = (var_frame + cov[1, 1] + al ** 2 * cov[0, 0] + 2 * al * cov[0, 1]) / (a * a)
    return al, np.sqrt(np.maximum(var, 0.0))


def gauge_image_factors(fit: dict[str, Any], sign: float = 1.0, alpha_from: str = "frames") -> tuple[float, float]:
    """How far the gauge's uncertainty leaves the separated images: the standard errors of ``x1`` and ``x2``, each
    in units of the rms of ``d = x1 - x2``.

    An error ``(da, db)`` of the fitted ``(a, b)`` gives ``alpha' = (1 + k) alpha + c`` (``k = -da / a``,
    ``c = -db / a``) and, to first order, the images ``x1' = x1 - (c + k) d`` and ``x2' = x2 - c d`` (the mixture
    ``x2 + alpha d`` unchanged), so ``sd(x1) = sd(c + k) rms(d)`` and ``sd(x2) = sd(c) rms(d)``. ``alpha_from``
    'model' (the fitted rotation's alpha, ``1/2 + s cos``): only the amplitude's relative error ``eps`` counts,
    ``k = eps``, ``c = -eps / 2``.
    """
    if alpha_from == "model":
        e = 0.5 * float(fit.get("amplitude_se", 0.0))
        return e, e
    a, _, cov = _signed_gauge(fit, sign)
    v2 = cov[1, 1] / (a * a)
    v1 = (cov[0, 0] + 2 * cov[0, 1] + cov[1, 1]) / (a * a)
    return math.sqrt(max(v1, 0.0)), math.sqrt(max(v2, 0.0))


def model_alpha(model: PolarizerModel, fit: dict[str, Any], sign: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The fitted rotation's alpha, ``1/2 + s cos(omega t + phi)`` (``sign`` -1: the other channel assignment, phase
    + pi), and each frame's standard error from the phase and frequency (a synchronised polariser's are known: 0;
    the model's mean is exact; its amplitude is known to ``model.amplitude_se``, relative)."""
    t = model.times_s
    ph = fit["phase_centre"] + (math.pi if sign < 0 else 0.0)
    u = fit["omega"] * (t - fit["t_centre"]) + ph
    al = model.alpha(t - fit["t_centre"], omega=fit["omega"], phase=ph)
    var = (model.amplitude * np.sin(u)) ** 2 * (fit["var_phase_centre"] + (t - fit["t_centre"]) ** 2 * fit["var_omega"])
    var = var + (model.amplitude * model.amplitude_se * np.cos(u)) ** 2
    return al, np.sqrt(np.maximum(var, 0.0))


__all__ = ["ALPHA_SE_MAX", "JITTER_FACTOR", "PolarizerModel", "gauge_image_factors", "gauged_alpha", "model_alpha",
           "polarizer_gauge"]

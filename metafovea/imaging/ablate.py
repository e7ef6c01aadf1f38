"""The truth a plan's estimates are tested against: the full model with and without each effect.

:func:`effect_errors` runs the full model of :func:`~metafovea.imaging.simulate.simulate` and, for each effect of
:data:`~metafovea.imaging.plan.EFFECTS` the full model has, the same model with that one effect replaced by its
alternative (``reduce=(effect,)``), same seed; the difference is measured as the plan measures it
(:func:`image_error_k`: each channel's noise-free image, :func:`frame_error_k`: the frames, for the effects that act
on the frames only). The camera is built once and varied for the effects that change it, so a sweep costs one
rendering per effect. :func:`model_error_k` is the realised error of any model against the full one.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.config import SystemDesign
from metafovea.imaging.plan import EFFECTS, check_effects, check_tolerance
from metafovea.imaging.scene import Scene
from metafovea.imaging.simulate import SimulationOptions, _options, _simulate_with, _with_effects_replaced, camera_for
from metafovea.measurement import Measurement


def _dn_per_k(ref: Measurement) -> tuple[float, float]:
    d = ref.meta["model"]["dn_per_k"]
    return float(d["x1"]), float(d["x2"])


def image_error_k(m: Measurement, ref: Measurement) -> float:
    """The larger channel's rms difference of the noise-free images ``truth_x1``/``truth_x2`` of ``m`` from ``ref``'s,
    in kelvin at the scene temperature (``ref``'s DN per kelvin, ``meta['model']['dn_per_k']``)."""
    out = 0.0
    for a, b, d in zip((m.truth_x1, m.truth_x2), (ref.truth_x1, ref.truth_x2), _dn_per_k(ref)):
        diff = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
        out = max(out, float(np.sqrt(np.mean(diff ** 2))) / d)
    return out


def frame_error_k(m: Measurement, ref: Measurement) -> float:
    """The rms difference of the frames of ``m`` from ``ref``'s, each frame in kelvin with ``ref``'s frame DN per
    kelvin ``a' D_1 + (1 - a') D_2`` (``a'`` its effective mixing ratio)."""
    d1, d2 = _dn_per_k(ref)
    a = np.asarray(ref.alpha, dtype=np.float64)
    d = (a * d1 + (1 - a) * d2)[:, None, None]
    diff = (np.asarray(m.frames, dtype=np.float64) - np.asarray(ref.frames, dtype=np.float64)) / d
    return float(np.sqrt(np.mean(diff ** 2)))


def model_error_k(m: Measurement, ref: Measurement) -> float:
    """The realised error of a model ``m`` against the full model ``ref``: :func:`image_error_k`."""
    return image_error_k(m, ref)


def _camera_variant(camera: Any, effect: str) -> Any:
    """The full model's camera with ``effect`` replaced (those effects that live in the camera)."""
    s, p = camera.sensor, camera.polarizer
    if effect == "train":
        return replace(camera, trains=None)
    if effect == "extinction":
        return replace(camera, polarizer=replace(p, extinction=0.0))
    if effect == "bolometer_lag":
        return replace(camera, polarizer=replace(p, tau_s=0.0))
    if effect == "noise":
        return replace(camera, sensor=replace(s, noise=False))
    if effect == "fpn":
        return replace(camera, sensor=replace(s, fpn_rank=0))
    if effect == "quantisation":
        return replace(camera, sensor=replace(s, quantize=False))
    return camera


@dataclass(frozen=True)
class EffectErrors:
    """:func:`effect_errors`' result: the full model's Measurement, each effect's measured contribution (K rms;
    image or frame measure by the effect's kind), the seconds each run took, and with a tolerance the plan's reduced
    Measurement and its realised error (K rms, :func:`model_error_k`)."""

    full: Measurement
    errors: dict[str, float]
    seconds: dict[str, float]
    reduced: Measurement | None = None

    @property
    def plan(self) -> dict[str, Any] | None:
        return None if self.reduced is None else self.reduced.meta["model"]["plan"]

    @property
    def realised_error_k(self) -> float | None:
        return None if self.reduced is None else model_error_k(self.reduced, self.full)

    def estimates(self) -> dict[str, float | None]:
        """The plan's estimate of each effect (None where the full model does not have it)."""
        return {} if self.plan is None else {r["effect"]: r["estimate_k_rms"] for r in self.plan["rows"]}


def effect_errors(system: SystemDesign, scene: str | Path | Scene | np.ndarray,
                  options: SimulationOptions | None = None, *, effects: tuple[str, ...] | None = None,
                  tolerance_k: float | None = None, camera: Any = None, rng: int = 0,
                  **overrides: Any) -> EffectErrors:
    """Each effect's measured contribution: the full model against the full model with that effect replaced.

    Parameters
    ----------
    system : SystemDesign
    scene : str, Path, Scene or ndarray
        As :func:`~metafovea.imaging.simulate.simulate`.
    options : SimulationOptions, optional
        The full model's options (no ``tolerance_k``, no ``reduce``).
    effects : tuple of str, optional
        Names of :data:`~metafovea.imaging.plan.EFFECTS` (default: all); an effect the full model does not have
        measures 0.
    tolerance_k : float, K, optional
        Also run the plan for this tolerance (``simulate(..., tolerance_k=...)``): :attr:`EffectErrors.reduced`.
    camera : Camera, optional
        ``camera_for(system, options)``, when a sweep builds it once for many scenes.
    rng : int
        The seed of every run.
    **overrides
        Fields of ``options`` to replace.

    Returns
    -------
    EffectErrors
    """
    opt = _options(options, overrides)
    names = check_effects(EFFECTS if effects is None else effects)
    t0 = time.perf_counter()
    camera = camera_for(system, opt) if camera is None else camera
    cache: dict = {}  # optics and renders that several of the models share (the same numbers, computed once)
    full = _simulate_with(system, camera, scene, opt, (), None, rng, t0, cache)
    seconds = {"full": time.perf_counter() - t0}
    errors = {}
    for e in names:
        t0 = time.perf_counter()
        m = _simulate_with(system, _camera_variant(camera, e), scene, _with_effects_replaced(opt, (e,)), (e,), None,
                           rng, t0, cache)
        seconds[e] = time.perf_counter() - t0
        errors[e] = frame_error_k(m, full) if EFFECTS[e].kind != "optics" else image_error_k(m, full)
    reduced = None
    if tolerance_k is not None:
        t0 = time.perf_counter()
        reduced = _simulate_with(system, camera, scene, opt, (), check_tolerance(tolerance_k), rng, t0, cache)
        seconds["reduced"] = time.perf_counter() - t0
    return EffectErrors(full, errors, seconds, reduced)

"""End-to-end simulation: scene -> radiance -> two channel images -> polariser mixing -> sensor frames.

:func:`simulate` returns a :class:`~metafovea.measurement.Measurement` in digital numbers with
the true mixing ratios and the noise-free foveal/perifoveal images, so that (exactly, before noise,
FPN and quantisation)

    frames[t] = alpha[t] * truth_x1 + (1 - alpha[t]) * truth_x2

Its steps, in order: the camera (sensor, channels, band radiance, polariser: :func:`camera_for`), the scene and
the memory check, the channel optics (PSF kernels and haze; the kernels asked for the error the recording can show,
:func:`kernel_accuracy`), the noise-free truth images, the polariser's alphas, the fixed pattern, the mixed frames
with noise and ADC (a block of frames at a time), closed-shutter calibration frames, the metadata. The random
streams (polariser, FPN, noise; calibration from the noise stream after the frames) are drawn from ``rng`` in a
fixed order, so the same seed gives identical frames.

The full model is the default. ``tolerance_k`` (an error budget, K rms of the sensor image referred to the scene) asks
the planner (:mod:`metafovea.imaging.plan`) for the cheapest model within it, after the full model's optics are built:
the replaced effects (``reduce``, also an option) change the optics, the renderers' sampling or the options; the
metadata's ``model`` says REDUCED and holds the plan. The random streams are the same, so a reduced model's frames
differ from the full model's only through the replaced effects.

:func:`simulate_to_files` is what ``metafovea simulate`` runs: simulate, then write the Measurement ``.npz``,
the TIFF stack (:func:`write_tiff`) and the preview PNG (:func:`write_preview`, the "iron" palette), never over
a file the run reads.
"""

from __future__ import annotations

import copy
import functools
import io as _io
import json
import logging
import math
import os
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.config import SystemDesign, load_system
from metafovea.errors import InputError, as_float, as_rng, check_int
from metafovea.imaging.channel import Channel, channels_for
from metafovea.imaging.kernels import (
    KERNEL_NOISE_SHARE,
    ChannelOptics,
    KernelAccuracy,
    build_channel_optics,
    glare_as_pedestal,
    pixel_psf,
    pixel_psf_patches,
    resample_optics,
    resolve_provider,
)
from metafovea.imaging.plan import (
    BUDGET_SHARE,
    REDUCED_PSF_WAVELENGTHS,
    Plan,
    PlanInputs,
    check_effects,
    check_tolerance,
    plan_cells,
    plan_lines,
    plan_model,
)
from metafovea.imaging.polarizer import Polarizer
from metafovea.imaging.render import ChannelRenderer
from metafovea.imaging.scene import Scene, SceneGeometry, make_scene
from metafovea.imaging.sensor import FixedPattern, SensorModel
from metafovea.io import atomic_write_bytes, prepare_output
from metafovea.library import system_post_sets
from metafovea.measurement import Measurement
from metafovea.optics.train import system_trains
from metafovea.parallel import heartbeat, progress_iter
from metafovea.radiometry import BandRadiance
from metafovea.report import FIGURE_DPI, fig_to_png

log = logging.getLogger(__name__)


#: frames per block of the sensor's noise draws (:meth:`SensorModel.add_noise_and_digitise`'s chunk: the random
#: stream depends on it)
NOISE_CHUNK = 8
#: closed-shutter frames a simulation records by default, for the reconstruction's FPN calibration (``fpn='auto'``
#: uses them): 16 frames estimate the default camera's pattern (10.7 DN rms) within 0.14 DN rms, for 17 % more
#: memory than the 96 frames; without them the default reconstruction falls back to the blind estimate, 0.75 dB
#: lower on x1 (measured on the default `metafovea simulate`)
CALIBRATION_FRAMES = 16


@dataclass(frozen=True)
class SimulationOptions:
    """Knobs of :func:`simulate`; ``None`` means "from the system design" (or the documented default)."""

    frames: int = 96
    supersample: int | None = None  # samples per pixel per axis: default 3 (static), 2 (video)
    psf: Any = "auto"  # 'auto' | 'optics' | 'airy' | 'gaussian:SIGMA_UM' | {channel: kernel} | callable
    psf_cache_dir: str | None = None
    psf_size_px: int | None = None
    field_patches: int | str = 1  # 1 = shift-invariant, n = n x n patches, 'auto' = decide from the PSFs
    patch_threshold: float = 0.2
    haze: bool = True
    relative_illumination: bool = True
    filter_enabled: bool | None = None
    pixel_pitch_um: float | None = None
    relay_magnification: float | None = None
    polarizer_mode: str = "sync"
    polarizer_phase_deg: float | None = None
    polarizer_hz: float | None = None
    extinction: float | None = None
    bolometer_tau_s: float = 0.0
    netd_k: float | None = None
    counts_per_k: float = 40.0
    dark_dn: float = 1000.0
    fpn_rank: int | None = None
    fpn_amplitude: float | None = None
    fpn_drift: float = 0.0
    noise: bool = True
    quantize: bool = True
    t0_s: float = 0.0
    scene_params: dict[str, Any] = field(default_factory=dict)
    scene_unit: str = "kelvin"  # a scene file's or array's temperatures: 'kelvin' | 'celsius' (+273.15 K, stated)
    calibration_frames: int = CALIBRATION_FRAMES  # closed-shutter frames (same FPN and noise), as 'calibration'
    progress: bool = False
    posts: Any = "rcwa"  # 'rcwa' (the fabricated lenses, library cached) | 'ideal' (simplified) | {pol: PostSet}
    optical_train: bool = True  # False: each lens alone (no wafers, other lens or ring): a simplified model
    #: an error budget (K rms of the sensor image referred to the scene): the planner (metafovea.imaging.plan)
    #: replaces the effects that fit it by cheaper alternatives: a REDUCED model. None: the full model
    tolerance_k: float | None = None
    #: effects to replace by their cheaper alternative (names of metafovea.imaging.plan.EFFECTS; what a plan sets)
    reduce: tuple[str, ...] = ()


def _child_rngs(rng: np.random.Generator | int | None, n: int) -> list[np.random.Generator]:
    g = as_rng(rng)
    seeds = g.integers(0, 2 ** 63 - 1, size=n)
    return [np.random.default_rng(int(s)) for s in seeds]


def available_memory_bytes() -> int | None:
    """Memory available for new allocations: Linux's MemAvailable (free + reclaimable cache), else the
    total physical memory (sysconf), else None when unknown. (MemFree alone would count the page cache
    as used and refuse runs that fit.)"""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):
        return None


def check_memory(n_frames: int, shape: tuple[int, int], *, video: bool, calibration_frames: int = 0,
                 available: int | None = None) -> None:
    """Refuse, before any work, a sequence whose (T, H, W) float32 arrays (frames, per-frame truth of a
    video scene, calibration frames; twice, for the copies made while saving) cannot fit in memory
    (``available`` bytes; default :func:`available_memory_bytes`)."""
    H, W = shape
    per_frame = 4 * H * W * (3 if video else 1)
    need = 2 * (per_frame * n_frames + 4 * H * W * calibration_frames)
    avail = available_memory_bytes() if available is None else available
    if avail is not None and need > 0.8 * avail:
        most = max(1, int((0.8 * avail / 2 - 4 * H * W * calibration_frames) // per_frame))
        raise InputError("frames", n_frames, f"at most about {most} frames of {H}x{W} here (the sequence needs "
                         f"~{need / 2**30:.1f} GiB, {avail / 2**30:.1f} GiB of memory is available)")


@dataclass(frozen=True)
class Camera:
    """The simulated camera: sensor, the (foveal, perifoveal) channels, band radiance and polariser.

    ``na_gains``: each channel's radiometric gain ``(NA_i / NA_2)^2`` relative to the perifoveal (F/1) one;
    ``optical_gains``: the same times the channel's optical-train throughput (:mod:`metafovea.optics.train`:
    wafers, both lenses' posts, the aperture ring; 1 without a train); ``gains``: those times the polariser's
    extinction gain ``1 + eps`` (what the frames see). ``post_sets``/``posts``: the lenses' posts and their source.
    """

    sensor: SensorModel
    channels: tuple[Channel, Channel]
    filter_enabled: bool
    radiance: BandRadiance
    polarizer: Polarizer
    trains: tuple[Any, Any] | None = None
    post_sets: dict[str, Any] | None = None
    posts: str = "ideal"

    @property
    def na_gains(self) -> list[float]:
        ch2 = self.channels[1]
        return [(ch.na / ch2.na) ** 2 for ch in self.channels]

    @property
    def optical_gains(self) -> list[float]:
        t = [1.0, 1.0] if self.trains is None else [tr.throughput for tr in self.trains]
        return [g * ti for g, ti in zip(self.na_gains, t)]

    @property
    def gains(self) -> list[float]:
        ext_gain = self.polarizer.physics.gain  # 1 + e
        return [g * ext_gain for g in self.optical_gains]

    def train_summaries(self) -> list[dict[str, Any]] | None:
        return None if self.trains is None else [tr.summary() for tr in self.trains]


def camera_for(system: SystemDesign, opt: SimulationOptions) -> Camera:
    """The camera of ``system`` with the overrides of ``opt`` (sensor, relay, filter, polariser)."""
    sensor = SensorModel.from_design(system.sensor, pixel_pitch_um=opt.pixel_pitch_um, netd_k=opt.netd_k,
                                     fpn_rank=opt.fpn_rank, fpn_amplitude=opt.fpn_amplitude, fpn_drift=opt.fpn_drift,
                                     counts_per_k=opt.counts_per_k, dark_dn=opt.dark_dn, noise=opt.noise,
                                     quantize=opt.quantize)
    channels = channels_for(system, pixel_pitch_um=sensor.pixel_pitch_um,
                            relay_magnification=opt.relay_magnification, shape=sensor.shape)
    fe = system.filter_enabled if opt.filter_enabled is None else bool(opt.filter_enabled)
    if isinstance(opt.posts, str) and _hashable(system):
        radiance, post_sets, posts, trains = _camera_optics(system, fe, opt.posts, bool(opt.optical_train))
    else:
        radiance, post_sets, posts, trains = _camera_optics.__wrapped__(system, fe, opt.posts, opt.optical_train)
    pol = Polarizer(rate_hz=system.polarizer_hz if opt.polarizer_hz is None else opt.polarizer_hz,
                    mode=opt.polarizer_mode,
                    phase_rad=None if opt.polarizer_phase_deg is None else math.radians(
                        math.fmod(opt.polarizer_phase_deg, 360.0)),  # exact: 1e20 deg plus t's angle would not turn
                    extinction=system.polarizer_extinction if opt.extinction is None else opt.extinction,
                    tau_s=opt.bolometer_tau_s)
    return Camera(sensor, channels, fe, radiance, pol, trains, post_sets, posts)


def clear_caches() -> None:
    """Forget the cameras and haze kernels kept in this process (after changing the files they were read from:
    the RCWA library, the post caches)."""
    from metafovea.imaging.kernels import clear_disk_kernels
    from metafovea.library.platform import clear_selection_cache

    _camera_optics.cache_clear()
    clear_disk_kernels()
    clear_selection_cache()


def _hashable(x: Any) -> bool:
    try:
        hash(x)
    except TypeError:
        return False
    return True


@functools.lru_cache(maxsize=8)
def _camera_optics(system: SystemDesign, filter_enabled: bool, posts: Any, optical_train: bool) -> tuple[Any, ...]:
    """The camera's band radiance, post sets and optical trains (frozen; 0.1 s for the paper's camera, the posts'
    library read from the disk cache): kept for the last few systems, as every simulation of a sweep, a benchmark or
    ``validate`` asks for the same ones."""
    radiance = BandRadiance.for_system(system, filter_enabled=filter_enabled)
    post_sets, posts = system_post_sets(system, posts)
    trains = system_trains(system, post_sets, posts, filter_enabled=filter_enabled) if optical_train else None
    return radiance, post_sets, posts, trains


def kernel_accuracy(system: SystemDesign, camera: Camera, scene: Scene, times: np.ndarray,
                    tolerance_k: float | None = None) -> list[KernelAccuracy]:
    """What each channel's PSF kernels must resolve in this recording
    (:class:`~metafovea.imaging.kernels.KernelAccuracy`, the derivation in :mod:`metafovea.imaging.kernels`).

    ``allowed_k``: :data:`~metafovea.imaging.kernels.KERNEL_NOISE_SHARE` of one frame's noise, ``sqrt(sigma^2 + 1/12)``
    DN (temporal noise, the ADC step), referred to the scene through the channel (its DN per kelvin at the design's
    scene temperature); with ``tolerance_k``, the share of it the planner leaves as margin,
    ``(1 - BUDGET_SHARE) T``, where that is looser (the plan's tolerance is against the full model, whose kernels a
    reduced model shares: it never tightens the request); None without noise, ADC or tolerance. ``contrast_k``: the
    scene's radiance range over the channel's field (its pixel centres and a margin of 8 pixels; a video at its first,
    middle and last frame) in kelvin at the scene temperature. Structure finer than a pixel that the pixel centres
    miss is not in the range."""
    sensor, radiance = camera.sensor, camera.radiance
    dldt = radiance.derivative(system.scene_temperature_k)
    dldt300 = radiance.derivative(300.0)
    sig_dn = math.sqrt(sensor.noise_sigma_dn ** 2 + (1.0 / 12.0 if sensor.quantize else 0.0))
    n = times.size
    ts = [float(times[0])] if scene.static else [float(times[i]) for i in sorted({0, n // 2, n - 1})]
    out = []
    for ch, gain in zip(camera.channels, camera.gains):
        H, W = ch.shape
        ya = np.arctan(ch.positions_um(H, 1, 8) / ch.focal_length_um)
        xa = np.arctan(ch.positions_um(W, 1, 8) / ch.focal_length_um)
        ax, ay = np.broadcast_to(xa[None, :], (ya.size, xa.size)), np.broadcast_to(ya[:, None], (ya.size, xa.size))
        lo, hi = math.inf, -math.inf
        for t in ts:
            temp, eps = scene.sample(ax, ay, t)
            L = radiance.apparent(temp, eps, scene.reflected_k)
            lo, hi = min(lo, float(L.min())), max(hi, float(L.max()))
        contrast = (hi - lo) / dldt
        dn_per_k = sensor.counts_per_k * gain * dldt / dldt300
        noise_k = KERNEL_NOISE_SHARE * sig_dn / dn_per_k
        margin_k = None if tolerance_k is None else (1.0 - BUDGET_SHARE) * float(tolerance_k)
        if margin_k is not None and margin_k > noise_k:
            out.append(KernelAccuracy(margin_k, contrast, f"{1 - BUDGET_SHARE:.0%} of the tolerance "
                                      f"{float(tolerance_k):g} K, the margin the plan leaves, looser than the noise"))
        elif noise_k > 0:
            out.append(KernelAccuracy(noise_k, contrast, f"{KERNEL_NOISE_SHARE:g} x one frame's noise "
                                      f"{sig_dn:.3g} DN rms (NETD {sensor.netd_k if sensor.noise else 0:g} K, ADC "
                                      f"{'on' if sensor.quantize else 'off'}) at {dn_per_k:.3g} DN/K"))
        else:
            out.append(KernelAccuracy(None, contrast, "no noise, ADC or tolerance bounds what the recording shows"))
    return out


def _channel_optics(system: SystemDesign, camera: Camera, provider: Any, provider_name: str, trains: Any, ss: int,
                    opt: SimulationOptions, accuracy: list[KernelAccuracy] | None = None,
                    **changes: Any) -> list[ChannelOptics]:
    """Each channel's optics (PSF kernels and haze; the metasurface transmission and glare leaks of its train).

    ``changes``: ``haze``, ``field_patches``, ``n_psf_wavelengths`` in place of the options'; ``kernel_from_full``:
    the provider's kernel of the full model's wavelengths whatever ``n_psf_wavelengths`` (the haze's bins alone
    change: what the planner's spectral estimate computes without a new PSF); ``no_glare``: without the train's
    glare (variants whose kernel or haze alone the planner needs)."""
    if changes.pop("kernel_from_full", False):
        provider = _kernel_at_full_spectrum(provider, camera.radiance, system.scene_temperature_k)
    glare = not changes.pop("no_glare", False)
    kw = {"haze": opt.haze, "field_patches": opt.field_patches, **changes}
    acc = accuracy or [None, None]
    return [build_channel_optics(ch, provider, camera.radiance, ss=ss, psf_size_px=opt.psf_size_px,
                                 patch_threshold=opt.patch_threshold,
                                 scene_temperature_k=system.scene_temperature_k,
                                 transmitted=1.0 if tr is None or provider_name != "optics"
                                 else tr.metasurface_transmission,
                                 leaks=() if tr is None or not glare else [(lk.power_fraction / tr.throughput,
                                                                            lk.radius_um) for lk in tr.leaks],
                                 accuracy=a, **kw)
            for ch, tr, a in zip(camera.channels, trains, acc)]


def _kernel_at_full_spectrum(provider: Any, radiance: BandRadiance, temperature_k: float) -> Any:
    """``provider`` asked for the full model's wavelength bins whatever bins it is given."""
    def call(channel: Channel, *, pitch_um: float, field_deg: float, wavelengths_um: np.ndarray, weights: np.ndarray,
             size_px: int, **ask: Any) -> Any:
        lam, w = radiance.psf_wavelengths(channel.lens.wavelength_um, temperature_k)
        return provider(channel, pitch_um=pitch_um, field_deg=field_deg, wavelengths_um=lam, weights=w,
                        size_px=size_px, **ask)
    call.takes_error = bool(getattr(provider, "takes_error", False))  # type: ignore[attr-defined]
    return call


#: the options each replaced effect of a reduced model sets (the others act on the optics and the renderers)
_EFFECT_OPTIONS: dict[str, dict[str, Any]] = {
    "haze": {"haze": False}, "train": {"optical_train": False},
    "relative_illumination": {"relative_illumination": False}, "field_patches": {"field_patches": 1},
    "extinction": {"extinction": 0.0}, "bolometer_lag": {"bolometer_tau_s": 0.0},
    "noise": {"noise": False}, "fpn": {"fpn_rank": 0}, "quantisation": {"quantize": False}}


def _with_effects_replaced(opt: SimulationOptions, reduce: tuple[str, ...]) -> SimulationOptions:
    """The options of the model with ``reduce``'s effects replaced (those that are options)."""
    changes: dict[str, Any] = {}
    for e in reduce:
        changes.update(_EFFECT_OPTIONS.get(e, {}))
    return replace(opt, **changes) if changes else opt


def _reduced_optics(optics: list[ChannelOptics], reduce: tuple[str, ...]) -> list[ChannelOptics]:
    """The optics with the glare as a uniform level and the kernels binned to 1 sample per pixel, as asked."""
    out = []
    for o in optics:
        if "glare" in reduce:
            o = glare_as_pedestal(o)
        if "supersample" in reduce and o.ss > 1:
            o = resample_optics(o, 1)
        out.append(o)
    return out


def _options(options: SimulationOptions | None, overrides: dict[str, Any]) -> SimulationOptions:
    opt = options or SimulationOptions()
    if overrides:
        bad = set(overrides) - set(SimulationOptions.__dataclass_fields__)
        if bad:
            raise InputError("option", sorted(bad)[0], "a field of SimulationOptions")
        opt = replace(opt, **overrides)
    for name in ("polarizer_phase_deg", "t0_s"):  # checked before the work (NaN would make every frame NaN)
        v = getattr(opt, name)
        if v is not None:
            as_float(name, v)
    return opt


def _scene_for(scene: str | Path | Scene, system: SystemDesign, camera: Camera, times: np.ndarray,
               opt: SimulationOptions) -> Scene:
    """The scene laid out for the perifoveal field and the recording's duration."""
    sensor, ch2 = camera.sensor, camera.channels[1]
    geom = SceneGeometry(fov_rad=2 * ch2.half_fov_rad[1], expansion=system.expansion,
                         duration_s=float(times[-1] - times[0]) + 1.0 / sensor.frame_rate_hz)
    return make_scene(scene, geom, scene_unit=opt.scene_unit, **opt.scene_params)


def _truth_images(renderers: list[ChannelRenderer], camera: Camera, times: np.ndarray, *, static: bool,
                  progress: bool, name: str, plan: Plan | None = None,
                  rendered: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free DN images ``(x1, x2)`` float32: ``(H, W)`` each for a static scene, ``(T, H, W)`` for a video (a
    static scene's parts that ``plan``'s pilot computed at the model's sampling are reused; ``rendered``: the
    renderers' images by time, filled and reused across models of one sweep that render alike)."""
    sensor = camera.sensor
    dl_dt = camera.radiance.derivative(300.0)
    gains = camera.gains

    def truth_at(t: float) -> tuple[np.ndarray, np.ndarray]:
        if rendered is not None and t not in rendered:
            rendered[t] = [rd.render(t) for rd in renderers]
        images = rendered[t] if rendered is not None else [rd.render(t) for rd in renderers]
        out = [sensor.to_dn(im, gi, dl_dt).astype(np.float32) for im, gi in zip(images, gains)]
        return out[0], out[1]

    if static and plan is not None:
        t0 = float(times[0])
        out = [sensor.to_dn(rd.render_static(t0, **plan.reusable(i)), gi, dl_dt).astype(np.float32)
               for i, (rd, gi) in enumerate(zip(renderers, gains))]
        return out[0], out[1]
    if static:
        return truth_at(float(times[0]))
    n_frames = times.size
    H, W = sensor.shape
    x1 = np.empty((n_frames, H, W), np.float32)
    x2 = np.empty((n_frames, H, W), np.float32)
    for k in progress_iter(range(n_frames), f"rendering {name}", "frame", enabled=progress, leave=False):
        x1[k], x2[k] = truth_at(float(times[k]))
    return x1, x2


def _fpn_per_frame(fpn: FixedPattern, fpn0: np.ndarray | None = None) -> Callable[[int], np.ndarray | None]:
    """``k -> the fixed pattern added to frame k`` (None without one): a drifting pattern changes per frame, a
    fixed one is computed once (``fpn0``: already computed, ``fpn.frame(None)``)."""
    if fpn.w is not None and fpn.rank > 0:
        return fpn.frame
    if fpn0 is None and fpn.rank:
        fpn0 = fpn.frame(None)
    return lambda k: fpn0


def _mixed_frames(x1: np.ndarray, x2: np.ndarray, alpha: np.ndarray, fpn: FixedPattern, *,
                  sensor: SensorModel | None = None, rng: np.random.Generator | None = None,
                  fpn0: np.ndarray | None = None) -> np.ndarray:
    """``alpha x1 + (1 - alpha) x2 + FPN`` per frame, float32 ``(T, H, W)``; with ``sensor`` and ``rng``, the noise and
    the ADC added (:meth:`SensorModel.add_noise_and_digitise`) to each block of :data:`NOISE_CHUNK` frames as soon as
    it is mixed, while it is in the cache: the same draws, in the same order, as on the whole stack."""
    n_frames = alpha.size
    H, W = x1.shape[-2:]
    static = x1.ndim == 2
    pattern = _fpn_per_frame(fpn, fpn0)
    frames = np.empty((n_frames, H, W), np.float32)
    a32 = alpha.astype(np.float32)
    for k in range(n_frames):
        f = frames[k]
        a = a32[k]
        np.multiply(x1 if static else x1[k], a, out=f)
        f += (np.float32(1) - a) * (x2 if static else x2[k])
        p = pattern(k)
        if p is not None:
            f += p
        if sensor is not None and ((k + 1) % NOISE_CHUNK == 0 or k + 1 == n_frames):
            k0 = k - k % NOISE_CHUNK
            sensor.add_noise_and_digitise(frames[k0:k + 1], rng, chunk=NOISE_CHUNK)
    return frames


def _shutter_frames(n_cal: int, x1: np.ndarray, x2: np.ndarray, fpn: FixedPattern, sensor: SensorModel,
                    r_noise: np.random.Generator, fpn0: np.ndarray | None = None) -> np.ndarray | None:
    """Closed-shutter calibration frames, or None when none are asked for.

    A closed shutter in front of the sensor: a uniform source at the scene's mean level, seen without the
    optics, plus the same fixed pattern (of frame 0) and temporal noise (its own random stream, drawn from the
    noise stream after the frames: the frames are unchanged)."""
    if not n_cal:
        return None
    H, W = sensor.shape
    r_cal = np.random.default_rng(int(r_noise.integers(0, 2 ** 63 - 1)))
    level = np.float32(0.5 * (float(np.mean(x1)) + float(np.mean(x2))))
    calibration = np.full((n_cal, H, W), level, np.float32)
    p = _fpn_per_frame(fpn, fpn0)(0)
    if p is not None:
        calibration += p
    sensor.add_noise_and_digitise(calibration, r_cal)
    return calibration


def _extras(theta: np.ndarray, calibration: np.ndarray | None, fpn: FixedPattern,
            n_frames: int) -> dict[str, np.ndarray]:
    """The Measurement's extra arrays: polariser angles, calibration frames, the FPN factors (and drift weights)."""
    extras: dict[str, np.ndarray] = {"theta_rad": theta}
    if calibration is not None:
        extras["calibration"] = calibration
    if fpn.rank:
        extras.update(fpn_u=fpn.u, fpn_v=fpn.v, fpn_s=fpn.s)
        if fpn.w is not None:
            extras["fpn_weights"] = np.stack([fpn.weights(k) for k in range(n_frames)])
    return extras


def _psf_extras(renderers: list[ChannelRenderer], camera: Camera, times: np.ndarray, *,
                static: bool) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """What a PSF-aware reconstruction needs and is scored against: each channel's PSF on the pixel grid
    (``psf_x1``/``psf_x2``: :func:`~metafovea.imaging.kernels.pixel_psf`; in field patches also every patch's,
    ``psf_patches_x*``: :func:`~metafovea.imaging.kernels.pixel_psf_patches`) and relative illumination
    (``illumination_x1``/``_x2``, (H, W)): known properties of the camera; for a static scene, the scene seen
    through a perfect lens (``scene_x1``/``_x2``, DN: :meth:`ChannelRenderer.scene_image` on the frames' DN scale):
    truth, for scoring only. Also the metadata ``{x1: {pedestal, size}, x2: ...}`` (the power beyond the kernels'
    window, a uniform level over the crop)."""
    out: dict[str, np.ndarray] = {}
    info: dict[str, Any] = {}
    sensor, dl_dt = camera.sensor, camera.radiance.derivative(300.0)
    for i, (rd, gain) in enumerate(zip(renderers, camera.gains), start=1):
        k, pedestal = pixel_psf(rd.optics)
        out[f"psf_x{i}"] = k.astype(np.float32)
        info[f"x{i}"] = {"size": int(k.shape[0]), "kernel_sum": float(k.sum()), "pedestal": pedestal}
        kp = pixel_psf_patches(rd.optics)
        if kp is not None:  # a field-dependent PSF: every patch's kernel (the Measurement format's psf_patches_x*)
            out[f"psf_patches_x{i}"] = kp.astype(np.float32)
            info[f"x{i}"]["patches"] = int(kp.shape[0])
        ri = rd.ri if rd.ri is not None else np.ones(sensor.shape)
        out[f"illumination_x{i}"] = np.asarray(ri, dtype=np.float32)
        if static:
            out[f"scene_x{i}"] = sensor.to_dn(rd.scene_image(float(times[0])), gain, dl_dt).astype(np.float32)
    return out, info


def _saturated_fraction(frames: np.ndarray, sensor: SensorModel) -> float:
    saturated = float(np.mean(frames >= sensor.full_scale_dn)) if sensor.quantize else 0.0
    if saturated > 0:
        log.warning("%.2f %% of the pixels are saturated at %d DN", 100 * saturated, sensor.full_scale_dn)
    return saturated


def _measurement_meta(system: SystemDesign, camera: Camera, sc: Scene, opt: SimulationOptions, *,
                      rng: np.random.Generator | int | None, ss: int, provider_name: str,
                      optics: list[ChannelOptics], pol_info: dict[str, Any],
                      alpha_nominal: np.ndarray, saturated: float, timing_s: dict[str, float]) -> dict[str, Any]:
    """The Measurement's metadata: units, scene, foveal constraint, gains, sensor, polariser, radiometry, PSFs."""
    sensor, pol, radiance, fe = camera.sensor, camera.polarizer, camera.radiance, camera.filter_enabled
    ch1, ch2 = camera.channels
    g, gains = camera.optical_gains, camera.gains
    # the gain a flat-field calibration measures: a uniform scene fills each channel's glare disks too
    glare = [1.0, 1.0] if camera.trains is None else [1.0 + tr.leak_fraction for tr in camera.trains]
    r = g[0] * glare[0] / (g[1] * glare[1])
    return {
        "kind": "measurement",
        "units": "DN",
        "units_note": "ADC digital numbers: DN = dark_dn + counts_per_k * gain * L / dL_dT_300K "
                      "(L = in-band radiance W m^-2 sr^-1 after the PSF; gain per channel below)",
        "scene": sc.name,
        "scene_info": sc.summary(),
        "seed": rng if isinstance(rng, (int, np.integer)) else None,
        "scale": system.expansion,
        "foveal_constraint": {
            "scale": system.expansion, "gain": r, "offset_dn": (1.0 - r) * sensor.dark_dn,
            "relation": "downsample(truth_x1, scale) ~= gain * centre_crop(truth_x2) + offset_dn",
            "gain_note": "flat-field ratio of the channels: (NA_1 / NA_2)^2, the trains' throughputs and their glare",
        },
        "channel_gain": {"x1": gains[0], "x2": gains[1]},
        "channel_gain_note": "(NA_i / NA_F1)^2 x optical-train throughput x (1 + polariser extinction leak)",
        "optical_train": camera.train_summaries() or {"note": "off: each lens alone, no wafers, other lens or "
                                                               "ring (a simplified model)"},
        "posts": camera.posts,
        "dn_per_k_300K": {"x1": sensor.counts_per_k * gains[0], "x2": sensor.counts_per_k * gains[1]},
        "netd_effective_k": {"x1": sensor.netd_k / gains[0], "x2": sensor.netd_k / gains[1]},
        "pixel_pitch_um": sensor.pixel_pitch_um,
        "frame_rate_hz": sensor.frame_rate_hz,
        # the polariser in the recording schema's keys (a free-running one's phase and rate are truth, below)
        "polarizer_hz": pol.rate_hz,
        "polarizer_mode": pol.mode,
        **({"polarizer_phase_deg": math.degrees(pol_info["phase_rad"])} if pol.mode == "sync" else {}),
        "polarizer_extinction": pol.extinction,
        "bolometer_tau_s": pol.tau_s,
        **({"floor_dn": 0.0, "saturation_dn": float(sensor.full_scale_dn)} if sensor.quantize else {}),
        "fpn_rank": int(sensor.fpn_rank),
        # scoring only: what the simulator knows and a camera would not record
        "truth": {"polarizer": {**pol_info, "alpha_nominal_range": [float(alpha_nominal.min()),
                                                                    float(alpha_nominal.max())]},
                  "noise_dn": math.sqrt(sensor.noise_sigma_dn ** 2 + (1.0 / 12.0 if sensor.quantize else 0.0))},
        "netd_k": sensor.netd_k,
        "sensor": sensor.summary(),
        "dark_dn": sensor.dark_dn,
        "counts_per_k": sensor.counts_per_k,
        "radiometry": {**radiance.summary(), "filter_enabled": fe,
                       "band_um": list(system.band_um),
                       "filter": [system.filter_center_um, system.filter_bandwidth_um] if fe else None},
        "relay_magnification": sensor.pixel_pitch_um / ch1.focal_pitch_um,
        "supersample": ss,
        "relative_illumination": opt.relative_illumination,
        "psf": {"provider": provider_name, "foveal": optics[0].info, "perifoveal": optics[1].info},
        "system": {"foveal": ch1.summary(), "perifoveal": ch2.summary(), "expansion": system.expansion,
                   "band_um": list(system.band_um), "filter_enabled": fe},
        "saturated_fraction": saturated,
        "truth_is_video": not sc.static,
        "timing_s": timing_s,
    }


def simulate(system: SystemDesign | str | Path, scene: str | Path | Scene | np.ndarray,
             options: SimulationOptions | None = None, rng: np.random.Generator | int | None = 0,
             **overrides: Any) -> Measurement:
    """Simulate ``options.frames`` frames of ``scene`` through ``system``.

    Parameters
    ----------
    system : SystemDesign, or str or Path
        The camera (both lenses, distances, relay, polariser, sensor, band), or a system TOML file of it.
    scene : str, Path, Scene or ndarray, shape (h, w) or (T, h, w)
        A bundled scene (:func:`~metafovea.imaging.list_scenes`), ``skimage:NAME``, a file of temperatures or a
        picture, a Scene, or temperatures (one channel; :func:`~metafovea.imaging.make_scene`). Temperatures are
        kelvin unless ``scene_unit='celsius'`` (an option: +273.15 K, stated in ``meta['scene_info']``); a colour
        or multi-channel image, or one whose hottest value is below 200 K, is an input error.
    options : SimulationOptions, optional
        Every knob (frames, PSF provider, posts, optical train, noise, FPN, polariser, ...).
    rng : int or numpy.random.Generator
        Seed (same seed -> identical frames).
    **overrides
        Fields of ``options`` to replace (``simulate(sys, 'bars', frames=12, noise=False)``,
        ``simulate(sys, 'room_celsius.npy', scene_unit='celsius')``).

    Returns
    -------
    Measurement
        ``frames`` ``(T, H, W)`` float32 in DN, ``times_s`` ``(T,)`` s, the true ``alpha`` ``(T,)``, the noise-free
        ``truth_x1`` / ``truth_x2`` ``(H, W)`` (``(T, H, W)`` for a video scene), the fixed pattern, the channels'
        pixel PSFs and the metadata (camera, scene, timings).
    """
    t_start = time.perf_counter()
    if isinstance(system, (str, Path)):
        system = load_system(system)
    elif not isinstance(system, SystemDesign):
        raise InputError("system", type(system).__name__, "a SystemDesign or a system TOML file")
    opt = _options(options, overrides)
    check_int("frames", opt.frames, 1, 100_000)
    tol = None if opt.tolerance_k is None else check_tolerance(opt.tolerance_k)
    reduce = check_effects(opt.reduce)
    if tol is not None and reduce:
        raise InputError("reduce", list(reduce), "no effects when tolerance_k is given (the plan chooses them)")
    opt = _with_effects_replaced(opt, reduce)
    with heartbeat("simulate: the lenses' posts and optical train (the RCWA library and the posts at oblique "
                   "incidence: computed on a first run, then cached)", enabled=opt.progress):
        camera = camera_for(system, opt)
    return _simulate_with(system, camera, scene, opt, reduce, tol, rng, t_start)


def _model_optics(system: SystemDesign, camera: Camera, sc: Scene, times: np.ndarray, opt: SimulationOptions,
                  ss: int, reduce: tuple[str, ...], tol: float | None, r_pol: np.random.Generator,
                  cache: dict | None = None
                  ) -> tuple[str, list[ChannelOptics], Plan | None, tuple[str, ...], SimulationOptions]:
    """The channels' optics of the model: the full model's, then the plan's (``tol``) or ``reduce``'s replacements.
    Returns the provider's name, the optics, the plan (None without ``tol``), the replaced effects and the
    options (with a plan's replacements). ``cache``: optics already built for the same camera (a sweep of models,
    :mod:`metafovea.imaging.ablate`), keyed by what they depend on."""
    provider, provider_name = resolve_provider(opt.psf, opt.psf_cache_dir, camera.post_sets)
    trains = camera.trains or (None, None)
    accuracy = kernel_accuracy(system, camera, sc, times, tol) if getattr(provider, "takes_error", False) else None

    def optics_for(o: SimulationOptions = opt, **changes: Any) -> list[ChannelOptics]:
        key = ("optics", ss, o.haze, o.field_patches, o.psf_size_px, o.patch_threshold, id(o.psf),
               camera.trains is None, tuple(sorted(changes.items())),
               None if accuracy is None else tuple((a.allowed_k, a.contrast_k) for a in accuracy))
        if cache is not None and key in cache:
            return cache[key]
        out = _channel_optics(system, camera, provider, provider_name, trains, ss, o, accuracy, **changes)
        if cache is not None:
            cache[key] = out
        return out

    with heartbeat(f"simulate: the channels' PSFs ({provider_name}; computed on a first run, then cached)",
                   enabled=opt.progress):
        optics = optics_for(**({"n_psf_wavelengths": REDUCED_PSF_WAVELENGTHS} if "spectral" in reduce else {}))
    plan = None
    if tol is not None:
        inputs = PlanInputs(camera, sc, times, optics, opt.relative_illumination, optics_for, copy.deepcopy(r_pol),
                            system.scene_temperature_k, noise=camera.sensor.noise, quantize=camera.sensor.quantize)
        plan = plan_model(inputs, tol, ss)
        log.info("plan: %s", "; ".join(plan.lines()))
        reduce = plan.reduce
        if "field_patches" in reduce:
            opt = _with_effects_replaced(opt, ("field_patches",))
            optics = optics_for(opt)
    return provider_name, _reduced_optics(optics, reduce), plan, reduce, opt


def _model_meta(reduce: tuple[str, ...], plan: Plan | None) -> dict[str, Any]:
    """The Measurement's ``meta['model']``: full or REDUCED, the replaced effects and the plan."""
    if not reduce:
        return {"reduced": False, "reduce": [], "note": "the full model" + (
            " (the plan kept every effect)" if plan is not None else ""),
                **({"plan": plan.summary()} if plan is not None else {})}
    return {"reduced": True, "reduce": list(reduce),
            "note": "REDUCED MODEL: " + ", ".join(reduce) + " replaced by cheaper alternatives "
                    "(metafovea.imaging.plan.EFFECTS)" + (f", within {plan.tolerance_k:g} K rms of the full model "
                                                          "by the plan's estimates" if plan is not None else ""),
            **({"plan": plan.summary()} if plan is not None else {})}


def _warn_if_looped(sc: Scene, times: np.ndarray) -> None:
    """A video raster shorter than the recording repeats from its start (:class:`RasterScene`): said, since a
    user who gave 5 frames for 24 sees their scene run through about five times."""
    tk = getattr(sc, "temperature_k", None)
    if tk is None or np.ndim(tk) != 3 or sc.static or not len(times):
        return
    rate = float(sc.frame_rate_hz)
    used = math.floor(float(times[-1]) * rate + 1e-9) + 1  # scene frames the recording runs through
    if used > tk.shape[0]:
        warnings.warn(f"the scene's {tk.shape[0]} frames at {rate:g} frames/s last {tk.shape[0] / rate:.3g} s, "
                      f"shorter than the recording ({len(times)} frames, {float(times[-1]):.3g} s): it plays "
                      f"{used / tk.shape[0]:.2g} times, from its start again each time", UserWarning, stacklevel=3)


def _simulate_with(system: SystemDesign, camera: Camera, scene: str | Path | Scene | np.ndarray,
                   opt: SimulationOptions, reduce: tuple[str, ...], tol: float | None,
                   rng: np.random.Generator | int | None, t_start: float, cache: dict | None = None) -> Measurement:
    """:func:`simulate` with its camera built (``opt``: the options with ``reduce``'s option effects replaced).
    ``cache``: what a sweep of models of one camera and scene shares (:mod:`metafovea.imaging.ablate`): the optics
    by what they depend on, the rendered images by the optics and the rendering's switches."""
    n_frames = opt.frames
    r_pol, r_fpn, r_noise = _child_rngs(rng, 3)
    sensor, pol = camera.sensor, camera.polarizer

    times = sensor.frame_times(n_frames, opt.t0_s)
    sc = _scene_for(scene, system, camera, times, opt)
    _warn_if_looped(sc, times)
    ss = check_int("supersample", opt.supersample if opt.supersample is not None else (3 if sc.static else 2), 1, 8)
    n_cal = check_int("calibration_frames", opt.calibration_frames, 0, 100_000)
    check_memory(n_frames, sensor.shape, video=not sc.static, calibration_frames=n_cal)

    t_psf = time.perf_counter()
    provider_name, optics, plan, reduce, opt = _model_optics(system, camera, sc, times, opt, ss, reduce, tol, r_pol,
                                                             cache)
    t_psf = time.perf_counter() - t_psf
    for o in optics:
        log.info("%s channel PSF: %s", o.channel.name, o.info)

    t_render = time.perf_counter()
    trains = camera.trains or (None, None)
    renderers = [ChannelRenderer(sc, o, camera.radiance, opt.relative_illumination,
                                 None if tr is None or "train_field" in reduce else tr.field_factor,
                                 sub=1 if "far_sampling" in reduce else None,
                                 far_cache=None if cache is None else cache.setdefault("far", {}),
                                 ri=None if plan is None or "train_field" in reduce else plan.illumination(i))
                 for i, (o, tr) in enumerate(zip(optics, trains))]
    rendered = None
    if cache is not None and plan is None:
        key = ("render", ss, opt.haze, opt.field_patches, opt.psf_size_px, opt.patch_threshold, id(opt.psf),
               opt.relative_illumination, camera.trains is None,
               tuple(e for e in reduce if e in ("supersample", "far_sampling", "glare", "train_field", "spectral")))
        rendered = cache.setdefault(key, {})
    x1, x2 = _truth_images(renderers, camera, times, static=sc.static, progress=opt.progress, name=sc.name,
                           plan=plan, rendered=rendered)
    t_render = time.perf_counter() - t_render

    theta, pol_info = pol.angles(times, r_pol)
    alpha_nominal, alpha, _ = pol.mixing(theta)
    # the scene's dynamic range as seen by the sensor: the larger of the two channels' own ranges
    fpn = sensor.make_fpn(max(float(x1.max() - x1.min()), float(x2.max() - x2.min())), times, r_fpn)
    t_mix = time.perf_counter()
    fpn0 = fpn.frame(None) if fpn.rank else None
    frames = _mixed_frames(x1, x2, alpha, fpn, sensor=sensor, rng=r_noise, fpn0=fpn0)
    calibration = _shutter_frames(n_cal, x1, x2, fpn, sensor, r_noise, fpn0)
    t_mix = time.perf_counter() - t_mix

    saturated = _saturated_fraction(frames, sensor)
    timing = {"psf": t_psf, "render": t_render, "mix_noise": t_mix, "total": time.perf_counter() - t_start}
    if plan is not None:
        timing["plan"] = plan.seconds
    meta = _measurement_meta(system, camera, sc, opt, rng=rng, ss=optics[0].ss, provider_name=provider_name,
                             optics=optics, pol_info=pol_info, alpha_nominal=alpha_nominal, saturated=saturated,
                             timing_s=timing)
    meta["model"] = _model_meta(reduce, plan)
    ratio = camera.radiance.derivative(system.scene_temperature_k) / camera.radiance.derivative(300.0)
    meta["model"]["dn_per_k"] = {"x1": sensor.counts_per_k * camera.gains[0] * ratio,
                                 "x2": sensor.counts_per_k * camera.gains[1] * ratio,
                                 "scene_temperature_k": float(system.scene_temperature_k)}
    psf_arrays, meta["psf"]["pixel"] = _psf_extras(renderers, camera, times, static=sc.static)
    meta["psf_pedestal"] = {c: float((meta["psf"]["pixel"].get(c) or {}).get("pedestal", 0.0)) for c in ("x1", "x2")}
    extras = {**_extras(theta, calibration, fpn, n_frames), **psf_arrays}
    return Measurement(frames=frames, times_s=times, alpha=alpha, truth_x1=x1, truth_x2=x2,
                       fpn=fpn0, meta=meta, extras=extras)


# ----------------------------------------------------------------------------------------------
# simulate and write the files (what `metafovea simulate` runs)
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SimulationRun:
    """What :func:`simulate_to_files` made: the measurement, the files written (``measurement``, ``tiff``,
    ``preview``) and the seconds it took (``simulate``; ``total`` with the writing)."""

    measurement: Measurement
    files: dict[str, Path]
    seconds: dict[str, float] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        """The run in numbers (the ``--json`` output of ``metafovea simulate``)."""
        m = self.measurement
        psf = m.meta["psf"]
        conversion = m.meta.get("scene_info", {}).get("conversion")
        return {**m.summary(), "scene": m.meta["scene"], **({"scene_conversion": conversion} if conversion else {}),
                "seed": m.meta["seed"], "psf": psf["provider"],
                "psf_mode": {c: psf[c]["mode"] for c in ("foveal", "perifoveal")},
                **({"psf_field": {c: psf[c]["patch_decision"] for c in ("foveal", "perifoveal")}}
                   if all("patch_decision" in psf[c] for c in ("foveal", "perifoveal")) else {}),
                "haze_fraction": {c: psf[c]["haze"].get("fraction", 0.0) for c in ("foveal", "perifoveal")},
                **({"psf_request": {c: psf[c]["psf_request"] for c in ("foveal", "perifoveal")}}
                   if all("psf_request" in psf[c] for c in ("foveal", "perifoveal")) else {}),
                "foveal_constraint": m.meta["foveal_constraint"], "saturated_fraction": m.meta["saturated_fraction"],
                "seconds": {k: round(v, 3) for k, v in self.seconds.items()},
                "files": {k: str(v) for k, v in self.files.items()}, **_model_summary(m.meta.get("model"))}


def _model_summary(model: dict[str, Any] | None) -> dict[str, Any]:
    """The run summary's ``model`` (full or REDUCED, what was replaced) and ``plan`` (when a tolerance was given)."""
    if not model:
        return {}
    out: dict[str, Any] = {"model": {"reduced": model["reduced"], "reduce": model["reduce"], "note": model["note"]}}
    if "plan" in model:
        out["plan"] = model["plan"]
    return out


def output_paths(out: str | Path, *, tiff: bool = True, preview: bool = True) -> dict[str, Path]:
    """The files a run writes for the Measurement ``out`` (``.npz``): ``<out>.tif`` and ``<out>_preview.png``
    next to it."""
    out = Path(out)
    if out.suffix.lower() != ".npz":
        raise InputError("out", str(out), "a file name ending in .npz")
    paths = {"measurement": out}
    if tiff:
        paths["tiff"] = out.with_suffix(".tif")
    if preview:
        paths["preview"] = out.with_name(out.stem + "_preview.png")
    return paths


def _refuse_to_overwrite_inputs(outputs: list[Path], inputs: list[Path]) -> None:
    """An output that is one of the files the run reads is refused, even with ``force``."""
    for o in outputs:
        for src in inputs:
            if o.resolve() == src.resolve() or (o.exists() and os.path.samefile(o, src)):
                raise InputError("out", str(o), f"a path other than the input {src} (it would be overwritten)")


def simulate_to_files(system: SystemDesign | str | Path | None, scene: str | Path | Scene | np.ndarray,
                      out: str | Path, options: SimulationOptions | None = None, *,
                      rng: np.random.Generator | int | None = 0, force: bool = False, tiff: bool = True,
                      preview: bool = True) -> SimulationRun:
    """Simulate (:func:`simulate`) and write the Measurement ``out`` (``.npz``), its TIFF stack and its preview.

    ``system``: a design, a system TOML file, or None for the paper's prototype. Every output is checked before
    the (long) simulation starts: nothing is overwritten without ``force``, and never the system or scene file
    the run reads, even with ``force``.
    """
    if system is None or isinstance(system, SystemDesign):
        design, system_file = system or SystemDesign.paper(), None
    else:
        design, system_file = load_system(system), Path(system)
    paths = output_paths(out, tiff=tiff, preview=preview)
    scene_file = scene if isinstance(scene, (str, Path)) else None
    inputs = [Path(p) for p in (system_file, scene_file) if p and Path(p).is_file()]
    _refuse_to_overwrite_inputs(list(paths.values()), inputs)
    names = {"measurement": "out", "tiff": "out (TIFF)", "preview": "out (preview)"}
    for kind, p in paths.items():
        prepare_output(p, force, name=names[kind])
    t0 = time.perf_counter()
    m = simulate(design, scene, options, rng=rng)
    t_sim = time.perf_counter() - t0
    m.save(paths["measurement"], force=force)
    files = {"measurement": paths["measurement"]}
    if tiff:
        files["tiff"] = write_tiff(m, paths["tiff"], force=force)
    if preview:
        files["preview"] = write_preview(m, paths["preview"], force=force)
    return SimulationRun(m, files, {"simulate": t_sim, "total": time.perf_counter() - t0})


# ----------------------------------------------------------------------------------------------
# exports
# ----------------------------------------------------------------------------------------------
def write_tiff(m: Measurement, path: str | Path, force: bool = False) -> Path:
    """ImageJ-compatible TIFF stack (T, H, W): uint16 DN when the frames are integers in range, else
    float32. The JSON summary (times, alpha) goes into the ImageJ 'Info' property."""
    import tifffile

    p = prepare_output(path, force, name="path")
    f = m.frames
    data = f
    if float(f.min()) >= 0 and float(f.max()) <= 65535 and np.array_equal(f, np.rint(f)):
        data = f.astype(np.uint16)
    info = {"units": m.meta.get("units", "DN"), "scene": m.meta.get("scene"), "times_s": m.times_s.tolist(),
            "alpha": None if m.alpha is None else np.round(m.alpha, 6).tolist()}
    fps = m.meta.get("frame_rate_hz")  # else the frame times give the interval (a recording may state no rate)
    dt = 1.0 / float(fps) if fps else float(np.median(np.diff(m.times_s))) if m.times_s.size > 1 else 0.0
    buf = _io.BytesIO()
    tifffile.imwrite(buf, data, imagej=True,
                     metadata={"axes": "TYX", **({"finterval": dt} if dt > 0 else {}), "Info": json.dumps(info)})
    return atomic_write_bytes(p, buf.getvalue())


def write_preview(m: Measurement, path: str | Path, force: bool = False, dpi: int = FIGURE_DPI) -> Path:
    """:func:`preview_figure` as a PNG (nothing overwritten without ``force``)."""
    p = prepare_output(path, force, name="path")
    return atomic_write_bytes(p, fig_to_png(preview_figure(m, dpi), dpi=dpi, trim=False))  # laid out to fit


def preview_figure(m: Measurement, dpi: int = FIGURE_DPI) -> Any:
    """The preview of a recording: four frames (highest, middle and lowest alpha) and the two truth images
    (noise-free, each channel alone) in the iron palette with colour bars in the file's units, alpha(t) and the
    frame mean; under them, a reduced model's plan. Returns the matplotlib ``Figure``."""
    from matplotlib.figure import Figure

    from metafovea.plotting import image

    T = m.frames.shape[0]
    units = m.meta.get("units", "DN")
    if m.alpha is not None and np.all(np.isfinite(m.alpha)):
        # highest and lowest alpha and two in between, preferring distinct alpha values
        order = [int(k) for k in np.argsort(m.alpha)[::-1]]
        picks = []
        for k in order:
            if all(abs(m.alpha[k] - m.alpha[j]) > 1e-3 for j in picks):
                picks.append(k)
        if len(picks) > 4:
            picks = [picks[0], picks[len(picks) // 3], picks[(2 * len(picks)) // 3], picks[-1]]
        for k in [int(v) for v in np.linspace(0, T - 1, 4)]:
            if len(picks) < 4 and k not in picks:
                picks.append(k)
        while len(picks) < 4:
            picks.append(picks[-1])
    else:
        picks = [int(v) for v in np.linspace(0, T - 1, 4)]
    model = m.meta.get("model") or {}
    plan = model.get("plan")
    text_in = 0.14 * (len(plan["rows"]) + 3) if plan else 0.0
    # a fixed grid that fits the figure (the constrained layout took 1-1.5 s more to draw; trimming, 0.3-0.5 s)
    h = 7.2 + text_in
    fig = Figure(figsize=(15, h), dpi=dpi)
    gs = fig.add_gridspec(2, 4, left=0.02, right=0.96, top=1 - 0.6 / h, bottom=(text_in + 0.5) / h, hspace=0.35,
                          wspace=0.45)
    for j, k in enumerate(picks):
        # per-frame automatic gain control (0.5-99.5 % percentiles), as a thermal camera displays
        lab = f"frame {k}, t = {m.times_s[k]:.2f} s" + ("" if m.alpha is None else f"\nalpha = {m.alpha[k]:.2f}")
        ax = fig.add_subplot(gs[0, j])
        image(ax, m.frames[k], label=units, title=lab)
        ax.set_axis_off()  # pixel ticks on every panel cost half the drawing time and say little here
    tr = m.truth(picks[0])
    if tr is not None:
        lower = ((tr[0], "truth x1: foveal (x-pol)\nnoise-free"), (tr[1], "truth x2: perifoveal (y-pol)\nnoise-free"))
    else:  # a recording: per pixel, the frames' mean and spread (the spread is the polariser's modulation, where the
        # two channels differ: the foveal content shows there); at most 256 frames, evenly spaced, one at a time
        n = np.zeros(m.frames.shape[1:])
        s1, s2 = np.zeros_like(n), np.zeros_like(n)
        for k in np.unique(np.linspace(0, T - 1, min(T, 256)).astype(int)):
            f = np.asarray(m.frames[k], dtype=np.float64)
            ok = np.isfinite(f)
            f = np.where(ok, f, 0.0)
            n += ok
            s1 += f
            s2 += f * f
        with np.errstate(invalid="ignore", divide="ignore"):  # a pixel never valid stays NaN (shown blank)
            mean = s1 / n
            lower = ((mean, "mean over the frames"), (np.sqrt(np.maximum(s2 / n - mean * mean, 0.0)),
                                                      "spread (std) over the frames\nthe polariser's modulation"))
    for j, (img, name) in enumerate(lower):
        ax = fig.add_subplot(gs[1, j])
        image(ax, img, label=units, title=name)
        ax.set_axis_off()
    a = fig.add_subplot(gs[1, 2])
    if m.alpha is not None:
        a.plot(m.times_s, m.alpha, ".-", lw=0.8, ms=3)
    else:
        a.text(0.5, 0.5, "not in the file:\nreconstruct estimates it", ha="center", va="center", transform=a.transAxes)
    a.set_xlabel("t (s)")
    a.set_ylabel("alpha")
    a.set_ylim(-0.05, 1.05)
    a.set_title("mixing ratio", fontsize=10)
    a = fig.add_subplot(gs[1, 3])
    a.plot(m.times_s, m.frames.reshape(T, -1).mean(1), lw=0.8)
    a.set_xlabel("t (s)")
    a.set_ylabel(f"mean ({units})")
    a.set_title("frame mean", fontsize=10)
    src = m.meta.get("source")
    origin = (f"recording {src.get('file')} ({src.get('format')})" if isinstance(src, dict) and "seed" not in m.meta
              else f"metafovea simulate: scene '{m.meta.get('scene', '?')}'")
    fig.suptitle(f"{origin}, {T} frames {m.frames.shape[1]}x{m.frames.shape[2]}"
                 + (f", seed {m.meta['seed']}" if m.meta.get("seed") is not None else "")
                 + ("   [REDUCED MODEL: " + ", ".join(model["reduce"]) + " replaced]" if model.get("reduced") else ""),
                 fontsize=11, color="darkred" if model.get("reduced") else "black")
    if plan:
        _plan_block(fig, plan, (text_in + 0.05) / h)
    return fig


def _plan_block(fig: Any, plan: dict[str, Any], top: float) -> None:
    """The plan table under the preview's panels from ``top`` (figure fraction) down: its headline, then effect,
    estimate, included and cost in columns (one text per column, in the figure's own font: a monospaced table took
    longer to draw than a reduced model saves); the reasons are in the command's output and the file's meta."""
    rows = [("effect", "estimate (K rms)", "included", "cost")] + plan_cells(plan)
    colour = "darkred" if plan["reduce"] else "black"
    fig.text(0.02, top, plan_lines(plan, why=False)[0], fontsize=7.5, va="top", ha="left", color=colour)
    step = 0.14 / fig.get_size_inches()[1]  # one row, 7 pt and its leading, as a figure fraction
    for i, cells in enumerate(rows):  # one text per cell: a multi-line text's rows are as tall as their glyphs
        for (x, ha), v in zip(((0.02, "left"), (0.25, "right"), (0.27, "left"), (0.36, "right")), cells):
            fig.text(x, top - (i + 1.2) * step, v, fontsize=7, va="top", ha=ha, color=colour)
    fig.text(0.02, top - (len(rows) + 1.4) * step, "why each: the command's output and the file's meta "
             "'model.plan'", fontsize=7, va="top", ha="left", color=colour)


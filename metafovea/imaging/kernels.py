"""PSF kernels per channel: the PSF providers, the chromatic haze, and what the renderer gets (ChannelOptics).

Image formation per channel (linear in radiance, not temperature)::

    L_i(x) = [ K_i * L_scene ](x)  +  h_i [ H_i * L_scene ](x)

* ``K_i``: the PSF kernel from the PSF provider, at the simulation's sample pitch ``p / (m s)`` (``s``
  = supersampling), integrated over the samples; ``sum(K_i) <= 1`` is the power inside its window.
  The sampled image is box-averaged over ``s x s`` samples: pixel integration
  (:mod:`~metafovea.imaging.render`).
* ``H_i``: the haze. A metalens focuses wavelength ``lambda`` at ``f lambda0 / lambda``, so at the
  design focal plane it spreads it over a disk of radius ``a |lambda / lambda0 - 1|`` (``a`` = lens
  radius; on a plane at ``z != f``: ``a |z lambda / (f lambda0) - 1|``): 7.5 mm for the foveal lens at 8 um,
  hundreds of pixels. ``H_i`` is the band-weighted
  mixture of those disks for the wavelengths blurred beyond the kernel's window, ``h_i = 1 - sum(K_i)``.
  Disks up to ``NEAR_HAZE_PX`` pixels are folded into the kernel; larger ones are convolved on a coarse
  grid over a field extended by the haze radius and interpolated back. With the 0.5 um filter the haze
  is a few pixels wide; without it (8-14 um) nearly all the power is haze.

Providers (:func:`resolve_provider`): ``OpticsPSFProvider`` (``metafovea.optics.sensor_psf``, cached on disk in
``metafovea.io.cache_dir("psf")``), ``airy_provider`` (analytic Airy core + haze), ``gaussian:SIGMA_UM``,
``ExplicitPSF`` (fixed or field-dependent kernels), or any callable with the :class:`PSFProvider` signature.

The kernels' error request (:class:`KernelAccuracy`, :func:`kernel_error_request`): what a PSF engine is asked for
comes from what the recording can show, not a constant. An engine's error estimate ``e`` is relative to the kernel's
peak; the error is where the kernel's light is (the rim wave and the defocused disks), so its l1 norm is modelled as
``|dK|_1 <= e peak N_eff = e sum(K)`` (``N_eff = sum(K) / peak``, the peak-normalised kernel's l1 norm; a model,
tested against the exact engine in tests/imaging/test_kernels.py). The haze takes up the power the kernel misses
(``h = 1 - sum K``), so a pixel changes by ``sum_j dK_j (L(x - j) - (H * L)(x))``, at most ``|dK|_1`` times the
scene's radiance range, in kelvin ``e sum(K) dT_scene``. Required: at most ``allowed_k``, a share
``KERNEL_NOISE_SHARE`` of one frame's noise (NETD and the ADC step) referred to the scene through the channel (an
independent error of that size adds at most 12 % to the noise rms); with a tolerance, the share of it the planner
leaves as margin where that is looser. So ``e_request = allowed_k / (dT_scene S)``, with ``S >= sum(K)`` bounded
before the kernel exists (:func:`kernel_sum_bound`), rounded down to a 1-2-5 step so that scenes of similar contrast
share the PSF cache. The engine is asked for that or :data:`DEFAULT_KERNEL_ERROR`, the tighter (the kernels are
computed once and cached; a looser request would only let it pick a cheaper engine). A kernel whose own bound
``e sum(K) dT_scene`` exceeds ``allowed_k`` gives a ``NotConvergedWarning``, a cached one too; ``info['psf_request']``
holds the request, why, what the engine was asked and that bound.

Field dependence: by default each channel is shift-invariant (the on-axis kernel). With
``field_patches='auto'`` the provider is asked for the kernel at the channel's field corner too; when it
differs from the on-axis one by more than ``patch_threshold`` (total-variation distance of the
normalised kernels), the image is computed in ``n x n`` patches with kernels at the patch centres,
blended with bilinear (partition-of-unity) weights. The decision and distance are reported.

Cheaper optics for a reduced model (:mod:`~metafovea.imaging.plan`): :func:`resample_optics` bins every kernel to fewer
samples per pixel (:func:`bin_kernel`: the same PSF and haze, the scene sampled more coarsely), and
:func:`glare_as_pedestal` spreads the far glare's power as a uniform level over the crop.
"""

from __future__ import annotations

import functools
import logging
import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from metafovea.errors import InputError, NotConvergedWarning, check_int, check_positive
from metafovea.imaging.channel import Channel
from metafovea.io import cache_dir as io_cache_dir
from metafovea.radiometry import BandRadiance

log = logging.getLogger(__name__)

#: largest PSF window (samples per side) a provider is asked for: wider windows only cost memory and time
MAX_PSF_SIZE = 1025
#: haze disks up to this radius (sensor pixels) are folded into the kernel; larger ones use a coarse grid
NEAR_HAZE_PX = 6.0
#: coarse-grid haze kernels are kept within this radius (coarse samples)
FAR_HAZE_SAMPLES = 48
#: glare disks are rendered in bands of radii within this factor, each on its own coarse grid
GLARE_BAND = 4.0
#: the kernels' error may change a pixel by at most this share of one frame's noise rms (referred to the scene):
#: an independent error of half the noise adds at most 12 % to the rms (sqrt(1 + 0.5^2) = 1.118)
KERNEL_NOISE_SHARE = 0.5
#: the error request (relative to the kernel's peak) where nothing bounds what the recording shows (no noise, no
#: ADC, no tolerance) and the request's limits (an engine's estimate beyond 0.1 of the peak means little)
DEFAULT_KERNEL_ERROR = 1e-4
KERNEL_ERROR_RANGE = (1e-6, 0.1)


@dataclass(frozen=True)
class KernelAccuracy:
    """What a channel's kernels must resolve (see the module docstring): ``allowed_k`` the largest change of a pixel
    (K, referred to the scene) their error may cause, None where nothing bounds it; ``contrast_k`` the scene's range
    (K: radiance range over ``dL/dT`` at the scene temperature) that the error acts on; ``why`` where ``allowed_k``
    comes from."""

    allowed_k: float | None
    contrast_k: float
    why: str


def _floor_125(x: float) -> float:
    """The largest of 1, 2, 5 x 10^k at most ``x`` (``x > 0``)."""
    k = math.floor(math.log10(x))
    m = x / 10.0 ** k
    return (5.0 if m >= 5 - 1e-9 else 2.0 if m >= 2 - 1e-9 else 1.0) * 10.0 ** k


def kernel_sum_bound(channel: Channel, wavelengths_um: np.ndarray, weights: np.ndarray, window_radius_um: float
                     ) -> float:
    """An upper bound, before the kernel is computed, on the share of the light leaving the lens that its window
    holds: each wavelength's geometric blur disk (radius :func:`chromatic_blur_radius_um`) puts at most
    ``2 x (4 / pi) (R / rho)^2`` of its power in a square window of half width ``R`` (the area ratio, doubled for the
    diffraction rings), at most 1."""
    w = np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    rho = chromatic_blur_radius_um(channel, np.asarray(wavelengths_um, dtype=np.float64))
    share = np.minimum(1.0, 8.0 / math.pi * (window_radius_um / np.maximum(rho, 1e-300)) ** 2)
    return float(min(1.0, np.sum(w * share)))


def kernel_error_request(accuracy: KernelAccuracy | None, kernel_sum: float) -> float:
    """The error (max abs error / the kernel's peak) a PSF engine is asked for: ``allowed_k / (contrast_k x
    kernel_sum)`` (the module docstring's derivation), rounded down to a 1-2-5 step and kept within
    :data:`KERNEL_ERROR_RANGE`; :data:`DEFAULT_KERNEL_ERROR` where nothing bounds it."""
    if accuracy is None or accuracy.allowed_k is None:
        return DEFAULT_KERNEL_ERROR
    lo, hi = KERNEL_ERROR_RANGE
    denom = max(accuracy.contrast_k, 1e-12) * max(kernel_sum, 1e-12)
    return float(min(hi, max(lo, _floor_125(max(accuracy.allowed_k / denom, lo)))))


def fftconvolve(in1: np.ndarray, in2: np.ndarray, mode: str = "full") -> np.ndarray:
    """``scipy.signal.fftconvolve(in1, in2, mode)`` of two real 2-D arrays, the same operations (``scipy.fft``'s real
    transforms at ``next_fast_len`` sizes, the mode's centred part), without importing ``scipy.signal``, which
    imports ``scipy.stats`` (half a second of every ``metafovea simulate``). Other inputs go to scipy's.

    Parameters
    ----------
    in1, in2 : ndarray, shape (M, N) and (P, Q), real
    mode : {'full', 'valid', 'same'}

    Returns
    -------
    ndarray
        The convolution, ``(M + P - 1, N + Q - 1)``, ``(M - P + 1, N - Q + 1)`` or ``(M, N)``.
    """
    import scipy.fft as sp_fft

    a, b = np.asarray(in1), np.asarray(in2)
    if a.ndim == 2 and b.shape == (1, 1) and mode in ("full", "valid", "same"):
        return a * b  # as scipy: a length-1 axis is a broadcast product, no transform
    if (a.ndim != 2 or b.ndim != 2 or not (np.isrealobj(a) and np.isrealobj(b)) or min(a.shape + b.shape) < 2
            or a.dtype.kind not in "f" or b.dtype.kind not in "f" or mode not in ("full", "valid", "same")):
        from scipy.signal import fftconvolve as scipy_fftconvolve

        return scipy_fftconvolve(in1, in2, mode=mode)
    if mode == "valid" and not all(x >= y for x, y in zip(a.shape, b.shape)):
        if all(x <= y for x, y in zip(a.shape, b.shape)):
            a, b = b, a  # as scipy: convolution commutes
        else:
            raise InputError("fftconvolve shapes", f"{a.shape} and {b.shape}",
                             "one at least as large as the other in every dimension for mode 'valid'")
    s1, s2 = a.shape, b.shape
    shape = [s1[i] + s2[i] - 1 for i in range(2)]
    fshape = [sp_fft.next_fast_len(n, True) for n in shape]
    ret = sp_fft.irfftn(sp_fft.rfftn(a, fshape, axes=[0, 1]) * sp_fft.rfftn(b, fshape, axes=[0, 1]), fshape,
                        axes=[0, 1])
    ret = ret[:shape[0], :shape[1]]
    if mode == "full":
        return ret.copy()
    out = list(s1) if mode == "same" else [s1[i] - s2[i] + 1 for i in range(2)]
    y0, x0 = (shape[0] - out[0]) // 2, (shape[1] - out[1]) // 2
    return ret[y0:y0 + out[0], x0:x0 + out[1]].copy()


# ----------------------------------------------------------------------------------------------
# PSF providers
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Kernel:
    """A PSF kernel at the simulation's sample pitch and where its window ends.

    ``intensity``: (k, k), k odd, centred on the chief ray, ``sum <= 1``. ``window_radius_um``: the
    haze model takes over for blur beyond this radius (focal plane). ``source``: provenance string.
    """

    intensity: np.ndarray
    pitch_um: float
    window_radius_um: float
    source: str
    error_estimate: float | None = None


class PSFProvider(Protocol):
    def __call__(self, channel: Channel, *, pitch_um: float, field_deg: float, wavelengths_um: np.ndarray,
                 weights: np.ndarray, size_px: int) -> Kernel: ...


def _as_odd_kernel(a: np.ndarray) -> np.ndarray:
    """``a`` checked (2-D, finite, >= 0) as float64, zero-padded at the end to an odd size per axis."""
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 2:
        raise InputError("psf kernel", f"array of shape {a.shape}", "a 2-D kernel")
    if not np.all(np.isfinite(a)) or a.min() < 0:
        raise InputError("psf kernel", "array", "finite values >= 0")
    pad = ((0, 1 - a.shape[0] % 2), (0, 1 - a.shape[1] % 2))
    if any(p[1] for p in pad):
        a = np.pad(a, pad)
    return a


def gaussian_kernel(sigma_px: float, size: int | None = None) -> np.ndarray:
    """A normalised, sample-integrated Gaussian kernel (sigma in samples)."""
    from scipy.special import erf

    s = check_positive("sigma_px", sigma_px)
    n = size or (2 * int(math.ceil(4 * s)) + 1)
    n += 1 - n % 2
    e = np.arange(n + 1) - n / 2.0
    c = 0.5 * (1 + erf(e / (s * math.sqrt(2))))
    g = np.diff(c)
    k = np.outer(g, g)
    return k / k.sum()


def airy_kernel(f_number: float, wavelength_um: float, pitch_um: float, size: int, sub: int = 7) -> np.ndarray:
    """Airy pattern ``[2 J1(v) / v]^2``, ``v = pi r / (lambda N)``, integrated over square samples,
    normalised to its total power (so the sum is the power inside the window, < 1)."""
    from scipy.special import j1

    size += 1 - size % 2
    u = (np.arange(size * sub) + 0.5) / sub - size / 2.0
    x = u * pitch_um
    k = np.empty((size, size))
    # a few output rows at a time: the (size * sub)^2 sub-sample grid of a large window would need GBs
    step = max(1, 2_000_000 // (size * sub * sub))
    for r0 in range(0, size, step):
        r1 = min(size, r0 + step)
        r = np.hypot(x[None, :], x[r0 * sub:r1 * sub, None])
        v = math.pi * r / (wavelength_um * f_number)
        with np.errstate(invalid="ignore", divide="ignore"):
            a = np.where(v > 1e-9, (2 * j1(v) / np.where(v > 1e-9, v, 1.0)) ** 2, 1.0)
        k[r0:r1] = a.reshape(r1 - r0, sub, size, sub).mean(axis=(1, 3))
    # total power of the Airy pattern: peak * lambda^2 N^2 * 4 / pi  (per unit area) -> per sample
    total = 4.0 / math.pi * (wavelength_um * f_number) ** 2 / pitch_um ** 2
    return k / total


def chromatic_blur_radius_um(channel: Channel, wavelengths_um: np.ndarray) -> np.ndarray:
    """Geometric blur radius on the channel's focal plane, at ``z`` (``channel.focal_length_um``) behind the lens:
    ``a |z lambda / (f0 lambda0) - 1|`` (order 1 focuses ``lambda`` at ``f0 lambda0 / lambda``); at the design
    focal plane ``z = f0`` this is ``a |lambda / lambda0 - 1|``."""
    lens = channel.lens
    z_over_f = channel.focal_length_um / lens.f_um
    return channel.radius_um * np.abs(z_over_f * np.asarray(wavelengths_um) / lens.wavelength_um - 1.0)


def airy_provider(channel: Channel, *, pitch_um: float, field_deg: float, wavelengths_um: np.ndarray,
                  weights: np.ndarray, size_px: int) -> Kernel:
    """Analytic fallback: diffraction-limited Airy core for the wavelengths the chromatic focal shift
    keeps within the Airy radius; the rest is haze. Shift-invariant (no off-axis aberrations)."""
    lam = np.asarray(wavelengths_um, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    n_f = channel.focal_length_um / (2 * channel.radius_um)
    rho = chromatic_blur_radius_um(channel, lam)
    core = rho <= 1.22 * lam * n_f
    k = np.zeros((size_px + 1 - size_px % 2,) * 2)
    if np.any(core):
        lam_c = float(np.sum(lam[core] * w[core]) / np.sum(w[core]))
        k = airy_kernel(n_f, lam_c, pitch_um, size_px) * float(np.sum(w[core]))
    return Kernel(k, pitch_um, 0.5 * k.shape[0] * pitch_um, f"analytic Airy F/{n_f:.2f} + chromatic haze")


class ExplicitPSF:
    """Fixed kernels per channel (tests, measured PSFs): ``{"foveal": K1, "perifoveal": K2}``, each at
    the simulation's sample pitch (focal-plane pitch / supersample). A callable value
    ``fn(field_deg) -> array`` gives field-dependent kernels (along +x; rotated for other azimuths)."""

    def __init__(self, kernels: dict[str, Any], window_radius_um: float | None = None):
        for k in ("foveal", "perifoveal"):
            if k not in kernels:
                raise InputError("psf kernels", sorted(kernels), "a dict with keys 'foveal' and 'perifoveal'")
        self.kernels = kernels
        self.window_radius_um = window_radius_um

    def __call__(self, channel: Channel, *, pitch_um: float, field_deg: float, wavelengths_um: np.ndarray,
                 weights: np.ndarray, size_px: int) -> Kernel:
        k = self.kernels[channel.name]
        k = _as_odd_kernel(k(field_deg) if callable(k) else k)
        r = self.window_radius_um if self.window_radius_um is not None else 0.5 * k.shape[0] * pitch_um
        return Kernel(k, pitch_um, r, "explicit")


class OpticsPSFProvider:
    """Calls ``metafovea.optics.sensor_psf`` (imported lazily) and caches each kernel on disk, keyed by
    a hash of all its inputs (lens, pitch, field, wavelengths, weights, window, error). ``error``: the request
    (relative to the peak) when a call does not give one (:func:`build_channel_optics` gives the derived one)."""

    #: takes the keyword ``error`` (the request derived by build_channel_optics)
    takes_error = True

    def __init__(self, cache_dir: str | Path | None = None, error: float = 1e-4, post_sets: dict | None = None):
        self.cache_dir = Path(cache_dir) if cache_dir else io_cache_dir("psf")
        self.error = error
        self.post_sets = post_sets or {}  # {'x': PostSet, 'y': PostSet}: the fabricated lenses (None: ideal posts)

    @staticmethod
    def available() -> bool:
        try:
            from metafovea.optics import sensor_psf  # noqa: F401 - imported only to see that it imports
        except Exception:  # noqa: BLE001 - any import problem means "not available"
            return False
        return True

    def __call__(self, channel: Channel, *, pitch_um: float, field_deg: float, wavelengths_um: np.ndarray,
                 weights: np.ndarray, size_px: int, error: float | None = None) -> Kernel:
        from dataclasses import asdict

        from metafovea.io import atomic_save_npz, input_hash, load_npz

        size_px += 1 - size_px % 2
        error = self.error if error is None else float(error)
        ps = self.post_sets.get(channel.lens.polarization)
        if ps is not None and ps.source == "ideal":
            ps = None  # the same PSF as sensor_psf's ideal posts
        posts = None if ps is None else {"t_x": np.round(np.stack([ps.t_x.real, ps.t_x.imag]), 9).tolist(),
                                         "t_y": np.round(np.stack([ps.t_y.real, ps.t_y.imag]), 9).tolist()}
        lens_key = asdict(channel.lens)
        if not lens_key["phase_poly_rad"]:
            del lens_key["phase_poly_rad"]  # the plain hyperbola: the cache keys of before the field existed
        key = {"lens": lens_key, "posts": posts, "pitch_um": round(float(pitch_um), 9),
               "field_deg": round(float(field_deg), 9),
               "z_um": round(float(channel.focal_length_um), 6),
               "wavelengths_um": np.round(np.asarray(wavelengths_um, dtype=float), 9).tolist(),
               "weights": np.round(np.asarray(weights, dtype=float) / np.sum(weights), 12).tolist(),
               "size_px": int(size_px), "error": error, "kind": "sensor_psf",
               "model": "direction-sine with focal shift"}  # the on-axis engine's model (Pupil.li_wolf)
        h = input_hash(key)
        path = self.cache_dir / f"psf_{channel.name}_{h}.npz"
        if path.is_file():
            try:
                arrays, meta = load_npz(path)
                log.info("PSF cache hit %s", path)
                return Kernel(arrays["intensity"], pitch_um, 0.5 * size_px * pitch_um, meta.get("source", "optics"),
                              meta.get("error_estimate"))
            except Exception as e:  # noqa: BLE001 - a corrupt cache entry is recomputed
                log.warning("ignoring unreadable PSF cache %s: %s", path, e)
        from metafovea.optics import sensor_psf

        psf = sensor_psf(channel.lens, pixel_pitch_um=pitch_um, field_deg=field_deg,
                         wavelengths_um=np.asarray(wavelengths_um), weights=np.asarray(weights),
                         size_px=size_px, error=error, z_um=channel.focal_length_um, post_set=ps)
        k = _as_odd_kernel(np.asarray(psf.intensity, dtype=np.float64))
        src = f"metafovea.optics.sensor_psf ({getattr(psf, 'engine', '?')})"
        err = getattr(psf, "error_estimate", None)
        err = float(err) if err is not None and np.isfinite(err) else None
        try:
            atomic_save_npz(path, {"kind": "psf-cache", "source": src, "error_estimate": err, "key": key},
                            intensity=k)
        except OSError as e:
            log.warning("could not cache PSF in %s: %s", path, e)
        return Kernel(k, pitch_um, 0.5 * size_px * pitch_um, src, err)


def resolve_provider(psf: str | PSFProvider | dict | None, cache_dir: str | Path | None = None,
                     post_sets: dict | None = None) -> tuple[PSFProvider, str]:
    """``psf``: 'auto' (optics if importable, else analytic Airy), 'optics', 'airy', 'gaussian:SIGMA_UM',
    a dict of kernels, or a provider callable. ``post_sets``: the lenses' posts for the optics provider.
    Returns (provider, name)."""
    if psf is None or psf == "auto":
        if OpticsPSFProvider.available():
            return OpticsPSFProvider(cache_dir, post_sets=post_sets), "optics"
        log.warning("metafovea.optics.sensor_psf is not available: using the analytic Airy + haze PSF model")
        return airy_provider, "airy"
    if isinstance(psf, dict):
        return ExplicitPSF(psf), "explicit"
    if callable(psf):
        return psf, getattr(psf, "__name__", type(psf).__name__)
    if isinstance(psf, str):
        s = psf.strip().lower()
        if s == "optics":
            if not OpticsPSFProvider.available():
                raise InputError("psf", psf,
                                 "'auto', 'airy' or 'gaussian:SIGMA_UM' (metafovea.optics is not installed)")
            return OpticsPSFProvider(cache_dir, post_sets=post_sets), "optics"
        if s == "airy":
            return airy_provider, "airy"
        if s.startswith("gaussian"):
            try:
                sig_um = float(s.split(":", 1)[1]) if ":" in s else 10.0
            except ValueError:
                raise InputError("psf", psf, "gaussian:SIGMA_UM with a number, e.g. gaussian:10") from None
            check_positive("psf gaussian sigma_um", sig_um, "um")

            def gauss(channel, *, pitch_um, field_deg, wavelengths_um, weights, size_px):
                k = gaussian_kernel(sig_um / pitch_um, size_px)
                return Kernel(k, pitch_um, 0.5 * k.shape[0] * pitch_um, f"gaussian sigma {sig_um:g} um")
            return gauss, f"gaussian:{sig_um:g}"
    raise InputError("psf", psf, "'auto', 'optics', 'airy', 'gaussian:SIGMA_UM', a dict of kernels or a callable")


# ----------------------------------------------------------------------------------------------
# haze kernels
# ----------------------------------------------------------------------------------------------
def disk_mixture_kernel(radii: np.ndarray, weights: np.ndarray, step: float, sub: int = 4) -> np.ndarray:
    """Normalised mixture of uniform disks (radii and step in the same unit), integrated over samples (read-only:
    the last few are kept, as every simulation of one camera asks for the same haze and glare disks)."""
    radii = np.ascontiguousarray(radii, dtype=np.float64)
    w = np.ascontiguousarray(weights, dtype=np.float64)
    return _disk_mixture_kernel(radii.tobytes(), w.tobytes(), float(step), int(sub))


def clear_disk_kernels() -> None:
    """Forget the disk kernels :func:`disk_mixture_kernel` keeps."""
    _disk_mixture_kernel.cache_clear()


@functools.lru_cache(maxsize=64)
def _disk_mixture_kernel(radii_bytes: bytes, weights_bytes: bytes, step: float, sub: int) -> np.ndarray:
    radii = np.frombuffer(radii_bytes, dtype=np.float64)
    w = np.frombuffer(weights_bytes, dtype=np.float64)
    rmax = float(radii.max())
    n = 2 * int(math.ceil(rmax / step + 0.5)) + 1
    u = ((np.arange(n * sub) + 0.5) / sub - n / 2.0) * step
    r = np.hypot(u[None, :], u[:, None])
    # intensity of the mixture at radius r: sum over disks containing r of w / (pi rho^2)
    order = np.argsort(radii)
    rs, dens = radii[order], (w / (np.pi * np.maximum(radii, 1e-12) ** 2))[order]
    tail = np.concatenate([np.cumsum(dens[::-1])[::-1], [0.0]])  # tail[i] = sum_{j >= i} dens_j
    idx = np.searchsorted(rs, r, side="left")
    img = tail[idx].reshape(n, sub, n, sub).mean(axis=(1, 3))
    img /= img.sum()
    img.flags.writeable = False
    return img


@dataclass
class ChannelOptics:
    """Everything the renderer needs for one channel (kernels at the sample pitch)."""

    channel: Channel
    ss: int
    kernels: list[np.ndarray]  # one per patch (1 when shift-invariant); includes the near haze
    patch_centres: list[tuple[float, float]]  # (row, col) in sensor pixels of each patch centre
    n_patches: int
    far_weight: float
    far_kernel: np.ndarray | None  # on the coarse grid
    far_coarse: int  # coarse sample = far_coarse sensor pixels
    info: dict[str, Any] = field(default_factory=dict)
    #: further far components on their own coarse grids, ``(weight, kernel, coarse)``: the glare of the other
    #: lens' pass-through (disks of mm, which on the haze's grid would blur the haze)
    extra_far: tuple[tuple[float, np.ndarray, int], ...] = ()
    #: power spread as a uniform level over the crop (the scene's mean radiance over the crop times this weight):
    #: the glare of a reduced model (:func:`glare_as_pedestal`); 0 in the full model
    pedestal_weight: float = 0.0

    def far_parts(self) -> list[tuple[float, np.ndarray, int]]:
        """Every far component ``(weight, normalised kernel on its coarse grid, coarse sample in pixels)``."""
        parts = [(self.far_weight, self.far_kernel, self.far_coarse)] if (
            self.far_kernel is not None and self.far_weight > 0) else []
        return parts + [p for p in self.extra_far if p[0] > 0]

    @property
    def margin(self) -> int:
        return max(k.shape[0] for k in self.kernels) // 2


def _rotate(k: np.ndarray, azimuth_rad: float) -> np.ndarray:
    """Kernel ``k`` (computed along +x) rotated to the azimuth of its field point, its sum kept."""
    if abs(azimuth_rad) < 1e-9:
        return k
    from scipy.ndimage import rotate

    r = rotate(k, -math.degrees(azimuth_rad), reshape=False, order=1, mode="constant")
    r = np.clip(r, 0, None)
    return r * (k.sum() / max(r.sum(), 1e-300))


def _kernel_tv_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Total-variation distance ``0.5 sum |a/sum(a) - b/sum(b)|`` of two centred square kernels (0: same shape,
    1: disjoint); the smaller one is zero-padded to the larger."""
    n = max(a.shape[0], b.shape[0])

    def pad(x):
        p = (n - x.shape[0]) // 2
        return np.pad(x, p) / max(x.sum(), 1e-300)
    return 0.5 * float(np.abs(pad(a) - pad(b)).sum())


def build_channel_optics(channel: Channel, provider: PSFProvider, radiance: BandRadiance, *, ss: int = 1,
                         psf_size_px: int | None = None, field_patches: int | str = 1,
                         patch_threshold: float = 0.2, scene_temperature_k: float = 300.0,
                         haze: bool = True, n_psf_wavelengths: int = 31, transmitted: float = 1.0,
                         leaks: Sequence[tuple[float, float]] = (),
                         accuracy: KernelAccuracy | None = None) -> ChannelOptics:
    """Ask the provider for the channel's kernel(s) and build the haze model (see module docstring).

    ``transmitted``: the fraction of the incident power the focusing metasurface transmits (the optical
    train's ``T_ms``; 1 for ideal posts): kernels are divided by it, so that kernels and haze share out the light
    that left the lens (the train's throughput counts the rest). ``leaks``: ``(power, radius_um)`` pairs of
    broad disks on top (the other lens' pass-through ripple, :class:`metafovea.optics.train.Leak`), power relative
    to the channel's throughput. ``accuracy``: what the kernels must resolve; a provider that takes ``error``
    (``takes_error``) is asked for :func:`kernel_error_request` of it (None: :data:`DEFAULT_KERNEL_ERROR`, the
    provider's own for others); ``info['psf_request']`` says which request and why."""
    tr = check_positive("transmitted", transmitted, hi=1.0)
    ss = check_int("supersample", ss, 1, 8)
    pitch = channel.focal_pitch_um / ss
    size = 2 * int(math.ceil(3 * ss)) + 1 if psf_size_px is None else psf_size_px  # 0 is not "the default"
    size = check_int("psf_size_px", size, 1, MAX_PSF_SIZE)
    if size % 2 == 0:
        raise InputError("psf_size_px", size, f"an odd number of samples 1 <= psf_size_px <= {MAX_PSF_SIZE} (the "
                         "PSF's centre is a sample)")
    lam_psf, w_psf = radiance.psf_wavelengths(channel.lens.wavelength_um, scene_temperature_k, n_psf_wavelengths)
    get, request, s_bound = _kernel_getter(channel, provider, pitch, lam_psf, w_psf, size, tr, accuracy)
    k0 = get(0.0)
    info: dict[str, Any] = {"source": k0.source, "sample_pitch_um": pitch, "kernel_size": int(k0.intensity.shape[0]),
                            "kernel_sum": float(k0.intensity.sum()), "error_estimate": k0.error_estimate}
    if request is not None:
        info["psf_request"] = _request_info(request, accuracy, s_bound, k0)
    # ---- field dependence -------------------------------------------------------------------------
    H, W = channel.shape
    n = 1
    if field_patches == "auto":
        corner = math.degrees(channel.corner_field_rad)
        kc = get(corner)
        d = _kernel_tv_distance(k0.intensity, kc.intensity)
        info["field_tv_distance_corner"] = d
        info["corner_field_deg"] = corner
        n = 3 if d > patch_threshold else 1
        info["patch_decision"] = (f"TV distance {d:.3f} between on-axis and corner ({corner:.2f} deg) kernels "
                                  f"{'>' if n > 1 else '<='} {patch_threshold:g}: "
                                  f"{'3 x 3 patches' if n > 1 else 'shift-invariant'}")
    else:
        n = check_int("field_patches", field_patches, 1, 9)
        info["patch_decision"] = (f"field_patches = {n}: " + (
            "the on-axis kernel over the whole field, a simplification (off axis the PSF spreads and loses light "
            "from its window; field_patches='auto' models it where it matters)" if n == 1 else f"{n} x {n} patches"))
    kernels, centres = [], []
    if n == 1:
        kernels.append(k0.intensity)
        centres.append(((H - 1) / 2, (W - 1) / 2))
    else:
        for i in range(n):
            for j in range(n):
                r = (i + 0.5) * H / n - 0.5
                c = (j + 0.5) * W / n - 0.5
                y = (r - (H - 1) / 2) * channel.focal_pitch_um
                x = (c - (W - 1) / 2) * channel.focal_pitch_um
                fld = math.degrees(math.atan(math.hypot(x, y) / channel.focal_length_um))
                kk = k0 if fld < 1e-9 else get(fld)
                same = kk.intensity.shape == k0.intensity.shape and np.array_equal(kk.intensity, k0.intensity)
                # a field-independent kernel is used as is (rotating it would only resample it)
                kernels.append(kk.intensity if same else _rotate(kk.intensity, math.atan2(y, x)))
                centres.append((r, c))
    info["mode"] = "shift-invariant" if n == 1 else f"{n} x {n} patches"
    # ---- haze and glare: disks (radius in sensor pixels, weight); near ones in the kernel, far ones coarse ------
    ksum = float(k0.intensity.sum())
    haze_w = max(0.0, 1.0 - ksum) if haze else 0.0
    rho = chromatic_blur_radius_um(channel, lam_psf)
    out = rho > k0.window_radius_um
    far_w, far_kernel, coarse = 0.0, None, 1
    extra: list[tuple[float, np.ndarray, int]] = []
    leak_list = [(float(p), float(r)) for p, r in leaks if p > 0]
    comps = []
    if haze_w > 1e-9 and np.any(out):
        comps.append(("haze", rho[out] / channel.focal_pitch_um, haze_w * w_psf[out] / w_psf[out].sum()))
    if leak_list:
        # glare disks span 0.5-50 mm: bands of radii within a factor GLARE_BAND, each on a grid its disks resolve
        g_rho = np.array([r for _, r in leak_list]) / channel.focal_pitch_um
        g_w = np.array([p for p, _ in leak_list])
        band = np.floor(np.log(np.maximum(g_rho, NEAR_HAZE_PX) / NEAR_HAZE_PX) / math.log(GLARE_BAND)).astype(int)
        for b in np.unique(band):
            comps.append(("glare", g_rho[band == b], g_w[band == b]))
    for name, rho_px, w_all in comps:
        near = rho_px <= NEAR_HAZE_PX
        if np.any(near):
            kn = disk_mixture_kernel(rho_px[near] * ss, w_all[near], 1.0)
            kernels = [_embed_add(k, kn, float(np.sum(w_all[near]))) for k in kernels]
        if np.any(~near):
            q = max(1, int(math.ceil(float(rho_px[~near].max()) / FAR_HAZE_SAMPLES)))
            kf = disk_mixture_kernel(rho_px[~near] / q, w_all[~near], 1.0)
            if name == "haze":
                far_w, far_kernel, coarse = float(np.sum(w_all[~near])), kf, q
            else:
                extra.append((float(np.sum(w_all[~near])), kf, q))
    if haze_w > 1e-9 and np.any(out):
        h_rho = rho[out] / channel.focal_pitch_um
        h_near = float(np.sum(w_psf[out][h_rho <= NEAR_HAZE_PX]) / w_psf[out].sum())
        info["haze"] = {"fraction": haze_w, "near_fraction": haze_w * h_near, "far_fraction": haze_w * (1 - h_near),
                        "max_radius_px": float(h_rho.max()), "far_coarse_px": coarse}
    elif haze_w > 1e-9:
        info["haze"] = {"fraction": 0.0, "lost_fraction": haze_w,
                        "note": "power outside the kernel window is not redistributed (no chromatic blur beyond it)"}
    else:
        info["haze"] = {"fraction": 0.0}
    if leak_list:
        info["glare"] = {"fraction": float(sum(p for p, _ in leak_list)),
                         "max_radius_px": float(max(r for _, r in leak_list) / channel.focal_pitch_um),
                         "source": "the other lens' pass-through ripple (metafovea.optics.train)"}
    if tr != 1.0:
        info["kernel_divided_by_metasurface_transmission"] = tr
    return ChannelOptics(channel, ss, kernels, centres, n, far_w, far_kernel, coarse, info, tuple(extra))


def _kernel_getter(channel: Channel, provider: PSFProvider, pitch: float, lam_psf: np.ndarray, w_psf: np.ndarray,
                   size: int, tr: float, accuracy: KernelAccuracy | None
                   ) -> tuple[Callable[[float], Kernel], float | None, float]:
    """``(get, request, s_bound)``: ``get(field_deg)`` the provider's kernel at a field (divided by ``tr``, checked,
    its warnings passed on by :func:`_check_request`), the error request the recording derives (None: a provider that
    takes none) and the a-priori bound on the kernel's sum. The engine is asked for the request or
    :data:`DEFAULT_KERNEL_ERROR`, the tighter: a looser request only lets it pick a cheaper engine with a larger
    estimate (the kernels are computed once and cached), and the default keeps the kernels the same as other callers'
    (the reconstruction's PSF family)."""
    s_bound = kernel_sum_bound(channel, lam_psf, w_psf, 0.5 * size * pitch)
    takes_error = bool(getattr(provider, "takes_error", False))
    request = kernel_error_request(accuracy, s_bound) if takes_error else None
    ask = {} if request is None else {"error": min(request, DEFAULT_KERNEL_ERROR)}

    def get(field_deg: float) -> Kernel:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", NotConvergedWarning)
            k = provider(channel, pitch_um=pitch, field_deg=field_deg, wavelengths_um=lam_psf, weights=w_psf,
                         size_px=size, **ask)
        if not isinstance(k, Kernel):
            arr = _as_odd_kernel(k)
            k = Kernel(arr, pitch, 0.5 * arr.shape[0] * pitch, "callable")
        if tr != 1.0:
            k = Kernel(k.intensity / tr, k.pitch_um, k.window_radius_um, k.source, k.error_estimate)
        s = float(k.intensity.sum())
        if s > 1.0 + 1e-6:
            raise InputError("psf kernel sum", s, "<= 1 (the fraction of the channel's power inside the window)")
        _check_request(channel, field_deg, k, request, accuracy, caught)
        return k

    return get, request, s_bound


def _check_request(channel: Channel, field_deg: float, k: Kernel, request: float | None,
                   accuracy: KernelAccuracy | None, caught: list[warnings.WarningMessage]) -> None:
    """Pass on the provider's warnings; where the recording's allowance is known, its verdict replaces the engine's
    ``NotConvergedWarning`` (which compares with what the engine was asked): none where the kernel's bound
    ``e sum(K) dT_scene`` is within ``allowed_k``, a ``NotConvergedWarning`` where it is not, for a cached kernel too
    (the engine warns only when it computes)."""
    e = k.error_estimate
    checked = (request is not None and accuracy is not None and accuracy.allowed_k is not None and e is not None
               and math.isfinite(e))
    engine: dict[str, Any] = {}
    for w in caught:
        if checked and issubclass(w.category, NotConvergedWarning):
            engine = dict(getattr(w.message, "data", {}) or {})
            continue
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if not checked:
        return
    bound = _pixel_change_k(float(e), k, accuracy)
    if bound <= accuracy.allowed_k:
        log.info("%s kernel at %.3g deg: estimate %.2g of the peak, pixel change <= %.2g K, within the %.2g K allowed",
                 channel.name, field_deg, e, bound, accuracy.allowed_k)
        return
    verdict = (f"pixel change up to {bound:.2g} K, more than the {accuracy.allowed_k:.2g} K allowed ({accuracy.why})")
    reason = f"{engine['reason']}; {verdict}" if engine.get("reason") else verdict
    msg = (f"PSF kernel of '{channel.name}' at field {field_deg:.4g} deg: estimated error {float(e):.2g} of the peak "
           f"exceeds the {request:g} the recording asks for: {reason}")
    warnings.warn(NotConvergedWarning(msg, {
        "subject": f"PSF kernel of '{channel.name}'", "field_deg": float(field_deg), "estimate": float(e),
        "requested": float(request), "reason": reason, "advice": engine.get("advice", {}), "message": msg}),
        stacklevel=3)


def _pixel_change_k(error: float, k: Kernel, accuracy: KernelAccuracy) -> float:
    """The largest change of a pixel (K) that a kernel's peak-relative error ``error`` allows: ``e sum(K) dT_scene``
    (the module docstring's derivation)."""
    return error * float(k.intensity.sum()) * accuracy.contrast_k


def _request_info(request: float, accuracy: KernelAccuracy | None, s_bound: float, k0: Kernel) -> dict[str, Any]:
    """``info['psf_request']``: the request, why, and the pixel change the kernel's estimate allows with its own sum
    (``bound_k``, K; met when at most ``allowed_k``)."""
    out: dict[str, Any] = {"error": request, "engine_error": min(request, DEFAULT_KERNEL_ERROR),
                           "kernel_sum_bound": s_bound}
    if accuracy is None or accuracy.allowed_k is None:
        out["why"] = (f"{DEFAULT_KERNEL_ERROR:g} of the peak: nothing bounds what the recording shows"
                      if accuracy is None else accuracy.why)
        return out
    out.update(allowed_k=accuracy.allowed_k, contrast_k=accuracy.contrast_k,
               why=f"{request:g} of the peak = {accuracy.allowed_k:.3g} K allowed ({accuracy.why}) / (scene range "
                   f"{accuracy.contrast_k:.3g} K x kernel sum <= {s_bound:.3g}), rounded down to a 1-2-5 step")
    e = k0.error_estimate
    if e is not None and math.isfinite(e):
        b = _pixel_change_k(float(e), k0, accuracy)
        out.update(bound_k=b, met=b <= accuracy.allowed_k)
    return out


def _embed_add(a: np.ndarray, b: np.ndarray, wb: float) -> np.ndarray:
    """``a + wb b`` of two centred square kernels, on the larger one's grid."""
    n = max(a.shape[0], b.shape[0])
    out = np.zeros((n, n))
    pa, pb = (n - a.shape[0]) // 2, (n - b.shape[0]) // 2
    out[pa:pa + a.shape[0], pa:pa + a.shape[1]] += a
    out[pb:pb + b.shape[0], pb:pb + b.shape[1]] += wb * b
    return out




def pixel_psf(optics: ChannelOptics, max_radius_px: int | None = None,
              patch: int | None = None) -> tuple[np.ndarray, float]:
    """The channel's PSF on the sensor's pixel grid and its pedestal: ``(K, pedestal)``, ``K`` ``(n, n)``, ``n``
    odd, centred, ``sum(K) + pedestal`` = the power the channel keeps (kernel + haze + glare, ~1), what
    :class:`~metafovea.imaging.render.ChannelRenderer` does to a scene that is uniform within each pixel (before
    relative illumination).

    The kernel at the sample pitch (near haze folded in) becomes, for pixel offset ``d``,
    ``(K * tri)[d s] / s^2`` with ``tri`` the ``(2s-1)^2`` self-correlation of the ``s x s`` pixel box; each far
    component (haze, glare: a normalised kernel on a grid of ``q`` pixels) is the linear interpolation back to
    pixels of its coarse kernel, blurred by the coarse sample's ``q``-pixel average. A channel computed in
    field patches contributes the kernel of the patch nearest the axis (the shift-invariant approximation), or of
    patch ``patch`` (row-major, :func:`pixel_psf_patches`).
    The coarse grid's interpolation is the model's, so this is the operator the simulator applies up to the
    sub-pixel structure of the scene.

    ``max_radius_px`` (default: the crop's larger side): the kernel is cut to ``|dx|, |dy| <= max_radius_px``; the
    power beyond (glare disks of several crop widths) is the ``pedestal``, a uniform level over the crop (its
    transfer function is the DC term only).
    """
    s = optics.ss
    H, W = optics.channel.shape
    centre = ((H - 1) / 2, (W - 1) / 2)
    if patch is None:
        i0 = int(np.argmin([math.hypot(r - centre[0], c - centre[1]) for r, c in optics.patch_centres]))
    else:
        i0 = check_int("patch", patch, 0, len(optics.kernels) - 1)
    k = np.asarray(optics.kernels[i0], dtype=np.float64)
    tri1 = np.convolve(np.ones(s), np.ones(s))
    kt = fftconvolve(k, np.outer(tri1, tri1), mode="full")
    c = (k.shape[0] - 1) // 2 + (s - 1)
    n_half = c // s
    core = kt[c - n_half * s:c + n_half * s + 1:s, c - n_half * s:c + n_half * s + 1:s] / s ** 2
    r = check_int("max_radius_px", max(H, W) if max_radius_px is None else max_radius_px, 1, 100_000)
    out = core
    total = float(core.sum()) + optics.pedestal_weight
    for weight, kf, q in optics.far_parts():
        far = np.asarray(kf, dtype=np.float64)
        total += weight
        full = float(far.sum()) * q ** 4  # the interpolated (q^2 per sample) and box-averaged (q^2) kernel's sum
        if q > 1:
            from scipy.ndimage import map_coordinates

            # only the pixels within the cut (plus the box's half width) are interpolated: glare disks are
            # thousands of pixels wide
            cc = (far.shape[0] - 1) / 2
            n = min((int(cc) + 1) * q, r + q)
            d = np.arange(-n, n + 1) / q + cc
            yy, xx = np.meshgrid(d, d, indexing="ij")
            far = map_coordinates(far, [yy, xx], order=1, mode="constant", cval=0.0)
            # the coarse sample's average over q pixels (symmetric taps: half weights at the ends for even q)
            box = np.ones(q + 1 - q % 2)
            if q % 2 == 0:
                box[[0, -1]] = 0.5
            far = fftconvolve(far, np.outer(box, box), mode="same")
        else:
            full = float(far.sum())
        h = far.shape[0] // 2
        if h > r:
            far = far[h - r:h + r + 1, h - r:h + r + 1]
        out = _embed_add(out, np.clip(far, 0.0, None) / full, weight)
    h = out.shape[0] // 2
    if h > r:
        out = out[h - r:h + r + 1, h - r:h + r + 1]
    # the power beyond the cut (0 when every component fits: never a rounding residue below 0)
    return out, max(0.0, total - float(out.sum()))


def pixel_psf_patches(optics: ChannelOptics, max_radius_px: int | None = None) -> np.ndarray | None:
    """A channel computed in ``p x p`` field patches: every patch's :func:`pixel_psf`, ``(p, p, n, n)`` (row-major,
    zero-padded to one size), the ``psf_patches_x*`` of the Measurement format; None for a shift-invariant
    channel."""
    p = optics.n_patches
    if p == 1:
        return None
    ks = [pixel_psf(optics, max_radius_px, patch=j)[0] for j in range(p * p)]
    n = max(k.shape[0] for k in ks)
    out = np.zeros((p * p, n, n))
    for j, k in enumerate(ks):
        o = (n - k.shape[0]) // 2
        out[j, o:o + k.shape[0], o:o + k.shape[0]] = k
    return out.reshape(p, p, n, n)


# ----------------------------------------------------------------------------------------------
# cheaper versions of a channel's optics (the reduced models of metafovea.imaging.plan)
# ----------------------------------------------------------------------------------------------
def bin_kernel(k: np.ndarray, factor: int) -> np.ndarray:
    """A centred kernel at sample pitch ``p`` integrated over samples of pitch ``factor p``, centred on the same
    point: ``B K B^T`` with ``B[j, i]`` the overlap of sample ``i`` (``[i - 1/2, i + 1/2]`` about the centre) with the
    coarse sample ``j`` (``[j f - f/2, j f + f/2]``). Exact for a kernel uniform within its samples; the sum is kept.
    For an odd ``factor`` the coarse samples are unions of whole samples (no interpolation)."""
    k = np.asarray(k, dtype=np.float64)
    f = check_int("factor", factor, 1, 64)
    if f == 1:
        return k
    n = k.shape[0]
    c = (n - 1) // 2
    h = int(math.ceil((c + 0.5) / f - 0.5))  # coarse half-width that holds every sample
    i = np.arange(n) - c
    j = np.arange(-h, h + 1)
    lo = np.maximum(i[None, :] - 0.5, j[:, None] * f - 0.5 * f)
    hi = np.minimum(i[None, :] + 0.5, j[:, None] * f + 0.5 * f)
    b = np.clip(hi - lo, 0.0, None)
    return b @ k @ b.T


def resample_optics(optics: ChannelOptics, ss: int) -> ChannelOptics:
    """``optics`` at ``ss`` samples per pixel (a divisor of ``optics.ss``): every kernel (near haze and glare
    included) binned by :func:`bin_kernel`; the far components, which do not depend on the sampling, unchanged. The
    PSF and haze model is the same: only the scene's sampling within a pixel changes."""
    ss = check_int("supersample", ss, 1, optics.ss)
    if optics.ss % ss:
        raise InputError("supersample", ss, f"a divisor of the full model's {optics.ss} samples per pixel")
    f = optics.ss // ss
    info = {**optics.info, "sample_pitch_um": optics.channel.focal_pitch_um / ss,
            "resampled": f"kernels of {optics.ss} samples per pixel binned {f} x {f}"}
    return replace(optics, ss=ss, kernels=[bin_kernel(k, f) for k in optics.kernels], info=info)


def glare_as_pedestal(optics: ChannelOptics) -> ChannelOptics:
    """``optics`` with its far glare components (:attr:`ChannelOptics.extra_far`: disks of mm) replaced by a uniform
    level of the same power over the crop (:attr:`ChannelOptics.pedestal_weight`); the haze and the near glare
    folded into the kernel are kept."""
    w = float(sum(p[0] for p in optics.extra_far))
    info = {**optics.info, "glare_pedestal": w}
    return replace(optics, extra_far=(), pedestal_weight=optics.pedestal_weight + w, info=info)


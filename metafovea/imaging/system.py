"""System model: the two channels, their PSFs and haze, and the rotating polariser.

Geometry
--------
Both lenses share the optical axis and image onto the same focal plane, which a relay of
magnification ``m`` images onto the sensor. A sensor pixel of pitch ``p`` therefore covers
``p / m`` at the focal plane; at focal-plane position ``(x, y)`` (0 at the axis, the crop centre) the
channel with focal length ``f`` sees field angles ``(atan(x / f), atan(y / f))`` (chief ray through
the lens centre). The foveal channel (``f1 = 150 mm``, x-polarised) thus sees the centre of the
perifoveal channel's (``f2 = 25 mm``, y-polarised) field magnified ``f1 / f2 = 6`` times.

Image formation per channel (linear in radiance, not temperature)::

    L_i(x) = [ K_i * L_scene ](x)  +  h_i [ H_i * L_scene ](x)

* ``K_i``: the PSF kernel from the PSF provider, at the simulation's sample pitch ``p / (m s)`` (``s``
  = supersampling), integrated over the samples; ``sum(K_i) <= 1`` is the power inside its window.
  The sampled image is box-averaged over ``s x s`` samples: pixel integration.
* ``H_i``: the haze. A metalens focuses wavelength ``lambda`` at ``f lambda0 / lambda``, so at the
  design focal plane it spreads it over a disk of radius ``a |lambda / lambda0 - 1|`` (``a`` = lens
  radius): 7.5 mm for the foveal lens at 8 um, hundreds of pixels. ``H_i`` is the band-weighted
  mixture of those disks for the wavelengths blurred beyond the kernel's window, ``h_i = 1 - sum(K_i)``.
  Disks up to ``NEAR_HAZE_PX`` pixels are folded into the kernel; larger ones are convolved on a coarse
  grid over a field extended by the haze radius and interpolated back. With the 0.5 um filter the haze
  is a few pixels wide; without it (8-14 um) nearly all the power is haze.
* Relative illumination ``cos^4`` of the field angle (optional).

Field dependence: by default each channel is shift-invariant (the on-axis kernel). With
``field_patches='auto'`` the provider is asked for the kernel at the channel's field corner too; when it
differs from the on-axis one by more than ``patch_threshold`` (total-variation distance of the
normalised kernels), the image is computed in ``n x n`` patches with kernels at the patch centres,
blended with bilinear (partition-of-unity) weights. The decision and distance are reported.

Polariser
---------
``theta(t) = 2 pi f_p t + phase`` (``f_p = 2 Hz``). ``alpha_t = cos^2 theta_t`` of the x (foveal) power
reaches the sensor and ``1 - alpha_t`` of the y (perifoveal). ``sync`` mode: the phase is given
(default 0.3 rad, three distinct alphas per cycle) and the rotation is locked to the frames; ``free`` mode: the phase is drawn from ``rng``
(unknown to a reconstruction) and the rate is off by a random relative error (``rate_error``). A
finite extinction leaks ``eps`` of the blocked polarisation: weights ``alpha + eps (1 - alpha)`` and
``1 - alpha + eps alpha``, which the simulator writes as ``(1 + eps) [a' x1 + (1 - a') x2]``.
An optional bolometer time constant ``tau`` low-passes alpha (amplitude ``1/sqrt(1 + (w tau)^2)``,
lag ``atan(w tau)``, ``w = 4 pi f_p``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from metafovea.config import LensDesign, SystemDesign
from metafovea.errors import InputError, check_choice, check_int, check_positive, check_range
from metafovea.io import cache_dir as io_cache_dir
from metafovea.radiometry import BandRadiance
from metafovea.imaging.scene import Scene

log = logging.getLogger(__name__)

#: largest PSF window (samples per side) a provider is asked for: wider windows only cost memory and time
MAX_PSF_SIZE = 1025
#: haze disks up to this radius (sensor pixels) are folded into the kernel; larger ones use a coarse grid
NEAR_HAZE_PX = 6.0
#: coarse-grid haze kernels are kept within this radius (coarse samples)
FAR_HAZE_SAMPLES = 48
#: default polariser phase in sync mode: 0.3 rad gives three distinct alphas per 2 Hz / 12 fps cycle
#: (0.913, 0.049, 0.538); phase 0 would give only two (1, 0.25, 0.25) and a repeated value
SYNC_PHASE_RAD = 0.3


# ----------------------------------------------------------------------------------------------
# channels
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Channel:
    """One imaging channel on the sensor crop."""

    name: str  # "foveal" or "perifoveal"
    lens: LensDesign
    focal_length_um: float  # lens to focal plane
    focal_pitch_um: float  # sensor pitch / relay magnification
    shape: tuple[int, int]

    @property
    def polarization(self) -> str:
        return self.lens.polarization

    @property
    def ifov_rad(self) -> float:
        """Angle per pixel at the axis."""
        return self.focal_pitch_um / self.focal_length_um

    @property
    def half_fov_rad(self) -> tuple[float, float]:
        """(vertical, horizontal) half field of view to the crop's edges."""
        H, W = self.shape
        return (math.atan(0.5 * H * self.focal_pitch_um / self.focal_length_um),
                math.atan(0.5 * W * self.focal_pitch_um / self.focal_length_um))

    @property
    def corner_field_rad(self) -> float:
        H, W = self.shape
        return math.atan(0.5 * math.hypot(H, W) * self.focal_pitch_um / self.focal_length_um)

    @property
    def radius_um(self) -> float:
        return self.lens.radius_um

    @property
    def na(self) -> float:
        return self.lens.na

    def positions_um(self, n: int, ss: int, margin: int, coarse: float = 1.0) -> np.ndarray:
        """Sample positions (um, focal plane) along one axis: ``n`` pixels, ``ss`` samples each, plus
        ``margin`` samples on both sides; pixel centres are symmetric about 0."""
        step = self.focal_pitch_um / ss * coarse
        m = int(round(n * ss / coarse))
        k = np.arange(-margin, m + margin, dtype=np.float64)
        return (k + 0.5 - m / 2.0) * step

    def angles(self, ss: int = 1, margin: int = 0, coarse: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Field-angle grids ``(ax, ay)`` of shape ``(H ss + 2 margin, W ss + 2 margin)``."""
        H, W = self.shape
        ya = np.arctan(self.positions_um(H, ss, margin, coarse) / self.focal_length_um)
        xa = np.arctan(self.positions_um(W, ss, margin, coarse) / self.focal_length_um)
        return np.broadcast_to(xa[None, :], (ya.size, xa.size)), np.broadcast_to(ya[:, None], (ya.size, xa.size))

    def summary(self) -> dict[str, Any]:
        hv, hh = self.half_fov_rad
        return {"name": self.name, "polarization": self.polarization, "f_mm": self.focal_length_um / 1000,
                "diameter_mm": self.lens.diameter_um / 1000, "na": self.na,
                "focal_plane_pitch_um": self.focal_pitch_um, "ifov_mrad": 1000 * self.ifov_rad,
                "fov_deg": [2 * math.degrees(hv), 2 * math.degrees(hh)]}


def channels_for(system: SystemDesign, *, pixel_pitch_um: float | None = None,
                 relay_magnification: float | None = None,
                 shape: tuple[int, int] | None = None) -> tuple[Channel, Channel]:
    """The (foveal, perifoveal) channels of ``system`` on the sensor's working crop."""
    pitch = check_positive("pixel_pitch_um", pixel_pitch_um if pixel_pitch_um is not None
                           else system.sensor.pixel_pitch_um, "um", hi=1000)
    m = check_positive("relay_magnification", relay_magnification if relay_magnification is not None
                       else system.relay_magnification, hi=10)
    shp = tuple(int(v) for v in (shape or system.sensor.crop))
    for v in shp:
        check_int("sensor crop (rows, columns)", v, 8, 8192)
    fp = pitch / m
    f1, f2 = system.lens_to_sensor_um
    return (Channel("foveal", system.foveal, f1, fp, shp), Channel("perifoveal", system.perifoveal, f2, fp, shp))


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


def _odd(a: np.ndarray) -> np.ndarray:
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
    """Geometric blur radius at the design focal plane: ``a |lambda / lambda0 - 1|``."""
    return channel.radius_um * np.abs(np.asarray(wavelengths_um) / channel.lens.wavelength_um - 1.0)


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
        k = _odd(k(field_deg) if callable(k) else k)
        r = self.window_radius_um if self.window_radius_um is not None else 0.5 * k.shape[0] * pitch_um
        return Kernel(k, pitch_um, r, "explicit")


class OpticsPSFProvider:
    """Calls ``metafovea.optics.sensor_psf`` (imported lazily) and caches each kernel on disk, keyed by
    a hash of all its inputs (lens, pitch, field, wavelengths, weights, window, error)."""

    def __init__(self, cache_dir: str | Path | None = None, error: float = 1e-4):
        self.cache_dir = Path(cache_dir) if cache_dir else io_cache_dir("psf")
        self.error = error

    @staticmethod
    def available() -> bool:
        try:
            from metafovea.optics import sensor_psf  # noqa: F401
        except Exception:  # noqa: BLE001 - any import problem means "not available"
            return False
        return True

    def __call__(self, channel: Channel, *, pitch_um: float, field_deg: float, wavelengths_um: np.ndarray,
                 weights: np.ndarray, size_px: int) -> Kernel:
        from dataclasses import asdict

        from metafovea.io import atomic_save_npz, input_hash, load_npz

        size_px += 1 - size_px % 2
        key = {"lens": asdict(channel.lens), "pitch_um": round(float(pitch_um), 9), "field_deg": round(float(field_deg), 9),
               "wavelengths_um": np.round(np.asarray(wavelengths_um, dtype=float), 9).tolist(),
               "weights": np.round(np.asarray(weights, dtype=float) / np.sum(weights), 12).tolist(),
               "size_px": int(size_px), "error": self.error, "kind": "sensor_psf"}
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
                         size_px=size_px, error=self.error)
        k = _odd(np.asarray(psf.intensity, dtype=np.float64))
        src = f"metafovea.optics.sensor_psf ({getattr(psf, 'engine', '?')})"
        err = getattr(psf, "error_estimate", None)
        err = float(err) if err is not None and np.isfinite(err) else None
        try:
            atomic_save_npz(path, {"kind": "psf-cache", "source": src, "error_estimate": err, "key": key},
                            intensity=k)
        except OSError as e:
            log.warning("could not cache PSF in %s: %s", path, e)
        return Kernel(k, pitch_um, 0.5 * size_px * pitch_um, src, err)


def resolve_provider(psf: str | PSFProvider | dict | None, cache_dir: str | Path | None = None) -> tuple[Any, str]:
    """``psf``: 'auto' (optics if importable, else analytic Airy), 'optics', 'airy', 'gaussian:SIGMA_UM',
    a dict of kernels, or a provider callable. Returns (provider, name)."""
    if psf is None or psf == "auto":
        if OpticsPSFProvider.available():
            return OpticsPSFProvider(cache_dir), "optics"
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
                raise InputError("psf", psf, "'auto', 'airy' or 'gaussian:SIGMA_UM' (metafovea.optics is not installed)")
            return OpticsPSFProvider(cache_dir), "optics"
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
    """Normalised mixture of uniform disks (radii and step in the same unit), integrated over samples."""
    radii = np.asarray(radii, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
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
    return img / img.sum()


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

    @property
    def margin(self) -> int:
        return max(k.shape[0] for k in self.kernels) // 2


def _rotate(k: np.ndarray, azimuth_rad: float) -> np.ndarray:
    if abs(azimuth_rad) < 1e-9:
        return k
    from scipy.ndimage import rotate

    r = rotate(k, -math.degrees(azimuth_rad), reshape=False, order=1, mode="constant")
    r = np.clip(r, 0, None)
    return r * (k.sum() / max(r.sum(), 1e-300))


def _tv(a: np.ndarray, b: np.ndarray) -> float:
    n = max(a.shape[0], b.shape[0])

    def pad(x):
        p = (n - x.shape[0]) // 2
        return np.pad(x, p) / max(x.sum(), 1e-300)
    return 0.5 * float(np.abs(pad(a) - pad(b)).sum())


def build_channel_optics(channel: Channel, provider: Any, radiance: BandRadiance, *, ss: int = 1,
                         psf_size_px: int | None = None, field_patches: int | str = 1,
                         patch_threshold: float = 0.2, scene_temperature_k: float = 300.0,
                         haze: bool = True, n_psf_wavelengths: int = 31) -> ChannelOptics:
    """Ask the provider for the channel's kernel(s) and build the haze model (see module docstring)."""
    ss = check_int("supersample", ss, 1, 8)
    pitch = channel.focal_pitch_um / ss
    size = psf_size_px or (2 * int(math.ceil(3 * ss)) + 1)
    size = check_int("psf_size_px", size, 1, MAX_PSF_SIZE)
    size += 1 - size % 2
    lam_psf, w_psf = radiance.psf_wavelengths(channel.lens.wavelength_um, scene_temperature_k, n_psf_wavelengths)

    def get(field_deg: float) -> Kernel:
        k = provider(channel, pitch_um=pitch, field_deg=field_deg, wavelengths_um=lam_psf, weights=w_psf,
                     size_px=size)
        if not isinstance(k, Kernel):
            arr = _odd(k)
            k = Kernel(arr, pitch, 0.5 * arr.shape[0] * pitch, "callable")
        s = float(k.intensity.sum())
        if s > 1.0 + 1e-6:
            raise InputError("psf kernel sum", s, "<= 1 (the fraction of the channel's power inside the window)")
        return k

    k0 = get(0.0)
    info: dict[str, Any] = {"source": k0.source, "sample_pitch_um": pitch, "kernel_size": int(k0.intensity.shape[0]),
                            "kernel_sum": float(k0.intensity.sum()), "error_estimate": k0.error_estimate}
    # ---- field dependence -------------------------------------------------------------------------
    H, W = channel.shape
    n = 1
    if field_patches == "auto":
        corner = math.degrees(channel.corner_field_rad)
        kc = get(corner)
        d = _tv(k0.intensity, kc.intensity)
        info["field_tv_distance_corner"] = d
        info["corner_field_deg"] = corner
        n = 3 if d > patch_threshold else 1
        info["patch_decision"] = (f"TV distance {d:.3f} between on-axis and corner ({corner:.2f} deg) kernels "
                                  f"{'>' if n > 1 else '<='} {patch_threshold:g}: "
                                  f"{'3 x 3 patches' if n > 1 else 'shift-invariant'}")
    else:
        n = check_int("field_patches", field_patches, 1, 9)
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
    # ---- haze ---------------------------------------------------------------------------------------
    ksum = float(k0.intensity.sum())
    haze_w = max(0.0, 1.0 - ksum) if haze else 0.0
    rho = chromatic_blur_radius_um(channel, lam_psf)
    out = rho > k0.window_radius_um
    far_w, far_kernel, coarse = 0.0, None, 1
    if haze_w > 1e-9 and np.any(out):
        rho_px = rho[out] / channel.focal_pitch_um  # sensor pixels
        w_out = w_psf[out] / w_psf[out].sum()
        near = rho_px <= NEAR_HAZE_PX
        fn = float(np.sum(w_out[near]))
        if np.any(near):
            kn = disk_mixture_kernel(rho_px[near] * ss, w_out[near], 1.0)
            kernels = [_embed_add(k, kn, haze_w * fn) for k in kernels]
        if np.any(~near):
            far_w = haze_w * (1.0 - fn)
            coarse = max(1, int(math.ceil(float(rho_px[~near].max()) / FAR_HAZE_SAMPLES)))
            far_kernel = disk_mixture_kernel(rho_px[~near] / coarse, w_out[~near], 1.0)
        info["haze"] = {"fraction": haze_w, "near_fraction": haze_w * fn, "far_fraction": far_w,
                        "max_radius_px": float(rho_px.max()), "far_coarse_px": coarse}
    elif haze_w > 1e-9:
        info["haze"] = {"fraction": 0.0, "lost_fraction": haze_w,
                        "note": "power outside the kernel window is not redistributed (no chromatic blur beyond it)"}
    else:
        info["haze"] = {"fraction": 0.0}
    return ChannelOptics(channel, ss, kernels, centres, n, far_w, far_kernel, coarse, info)


def _embed_add(a: np.ndarray, b: np.ndarray, wb: float) -> np.ndarray:
    n = max(a.shape[0], b.shape[0])
    out = np.zeros((n, n))
    pa, pb = (n - a.shape[0]) // 2, (n - b.shape[0]) // 2
    out[pa:pa + a.shape[0], pa:pa + a.shape[1]] += a
    out[pb:pb + b.shape[0], pb:pb + b.shape[1]] += wb * b
    return out


# ----------------------------------------------------------------------------------------------
# rendering
# ----------------------------------------------------------------------------------------------
def _conv_valid(img: np.ndarray, k: np.ndarray) -> np.ndarray:
    from scipy.signal import fftconvolve

    if k.shape == (1, 1):
        return img * k[0, 0]
    return fftconvolve(img, k, mode="valid")


def _patch_weights(n: int, size: int, ss_centres: list[float]) -> list[np.ndarray]:
    """1-D tent weights (partition of unity) for n patch centres along an axis of ``size`` samples."""
    x = np.arange(size, dtype=np.float64)
    c = np.asarray(ss_centres)
    out = []
    for i in range(n):
        w = np.zeros(size)
        if n == 1:
            w[:] = 1
        else:
            left = c[i - 1] if i > 0 else -np.inf
            right = c[i + 1] if i < n - 1 else np.inf
            w = np.where(x <= c[i], 1 - (c[i] - x) / (c[i] - left) if i > 0 else 1.0,
                         1 - (x - c[i]) / (right - c[i]) if i < n - 1 else 1.0)
            w = np.clip(w, 0, 1)
        out.append(w)
    return out


class ChannelRenderer:
    """Renders one channel's noise-free image of a scene (see module docstring for the model).

    For video scenes that declare their static background and the boxes that change
    (:meth:`Scene.dynamic_regions`), the background is rendered once and each frame adds only the
    change inside those boxes (convolution is linear): the cost follows the moving objects' size.
    """

    SUB = 3  # supersampling of each coarse haze sample (small hot objects must not be missed)

    def __init__(self, scene: Scene, optics: ChannelOptics, radiance: BandRadiance,
                 relative_illumination: bool = True):
        self.scene, self.optics, self.radiance = scene, optics, radiance
        ch, ss = optics.channel, optics.ss
        H, W = ch.shape
        m = optics.margin
        self.ya = np.arctan(ch.positions_um(H, ss, m) / ch.focal_length_um)
        self.xa = np.arctan(ch.positions_um(W, ss, m) / ch.focal_length_um)
        self.ri = relative_illumination_map(ch) if relative_illumination else None
        self.far = optics.far_kernel is not None and optics.far_weight > 0
        if self.far:
            q, km = optics.far_coarse, optics.far_kernel.shape[0] // 2
            self.yc = np.arctan(ch.positions_um(H, self.SUB, km * self.SUB, coarse=q) / ch.focal_length_um)
            self.xc = np.arctan(ch.positions_um(W, self.SUB, km * self.SUB, coarse=q) / ch.focal_length_um)
            nh, nw = round(H * self.SUB / q), round(W * self.SUB / q)
            # output sample o of the valid convolution sits at ((o + 0.5) - n_fine / (2 SUB)) q pixels
            self.ry = (np.arange(H) + 0.5 - H / 2.0) / q + nh / (2.0 * self.SUB) - 0.5
            self.rx = (np.arange(W) + 0.5 - W / 2.0) / q + nw / (2.0 * self.SUB) - 0.5
        self.incremental = (not scene.static and optics.n_patches == 1
                            and scene.dynamic_regions(0.0) is not None)
        self._bg: dict[str, np.ndarray] | None = None

    # -- pieces ----------------------------------------------------------------------------------
    def _radiance(self, ya: np.ndarray, xa: np.ndarray, t: float | None) -> np.ndarray:
        ax, ay = np.broadcast_to(xa[None, :], (ya.size, xa.size)), np.broadcast_to(ya[:, None], (ya.size, xa.size))
        if t is None:
            temp, eps = self.scene.sample_background(ax, ay)
        else:
            temp, eps = self.scene.sample(ax, ay, t)
        return self.radiance.apparent(temp, eps, self.scene.reflected_k)

    def _coarse_radiance(self, r0: int, r1: int, c0: int, c1: int, t: float | None) -> np.ndarray:
        """Coarse samples [r0, r1) x [c0, c1), each the mean of SUB x SUB samples."""
        S = self.SUB
        L = self._radiance(self.yc[r0 * S:r1 * S], self.xc[c0 * S:c1 * S], t)
        return L.reshape(r1 - r0, S, c1 - c0, S).mean(axis=(1, 3))

    def _fine_image(self, L: np.ndarray) -> np.ndarray:
        o = self.optics
        if o.n_patches == 1:
            return _conv_valid(L, o.kernels[0])
        ch, ss, m = o.channel, o.ss, o.margin
        H, W = ch.shape
        n = o.n_patches
        rows = sorted({c[0] for c in o.patch_centres})
        cols = sorted({c[1] for c in o.patch_centres})
        wy = _patch_weights(n, H * ss, [(r + 0.5) * ss - 0.5 for r in rows])
        wx = _patch_weights(n, W * ss, [(c + 0.5) * ss - 0.5 for c in cols])
        img = np.zeros((H * ss, W * ss))
        for p, k in enumerate(o.kernels):
            i, j = divmod(p, n)
            km = k.shape[0] // 2
            sub = L[m - km: L.shape[0] - (m - km), m - km: L.shape[1] - (m - km)]
            img += wy[i][:, None] * wx[j][None, :] * _conv_valid(sub, k)
        return img

    def _finish(self, fine: np.ndarray, hz: np.ndarray | None) -> np.ndarray:
        from scipy.ndimage import map_coordinates

        ch, ss = self.optics.channel, self.optics.ss
        H, W = ch.shape
        img = fine.reshape(H, ss, W, ss).mean(axis=(1, 3)) if ss > 1 else fine.copy()
        if hz is not None:
            yy, xx = np.meshgrid(self.ry, self.rx, indexing="ij")
            img += self.optics.far_weight * map_coordinates(hz, [yy.ravel(), xx.ravel()], order=1,
                                                            mode="nearest").reshape(H, W)
        if self.ri is not None:
            img *= self.ri
        return img

    def _full(self, t: float | None) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray | None]:
        L = self._radiance(self.ya, self.xa, t)
        fine = self._fine_image(L)
        hz = Lc = None
        if self.far:
            S = self.SUB
            Lc = self._coarse_radiance(0, self.yc.size // S, 0, self.xc.size // S, t)
            hz = _conv_valid(Lc, self.optics.far_kernel)
        return fine, hz, L, Lc

    @staticmethod
    def _range(axis: np.ndarray, lo: float, hi: float, group: int = 1) -> tuple[int, int]:
        """Index range [i0, i1) (in groups of ``group`` samples) covering angles [lo, hi], padded by 1."""
        i0 = int(np.searchsorted(axis, lo, side="left")) // group - 1
        i1 = -(-int(np.searchsorted(axis, hi, side="right")) // group) + 1
        n = axis.size // group
        return max(i0, 0), min(i1, n)

    @staticmethod
    def _add_full(out: np.ndarray, d: np.ndarray, k: np.ndarray, r0: int, c0: int, m: int) -> None:
        """Add the full convolution of ``d`` (placed at input index r0, c0 of a valid convolution with
        margin m) into ``out``."""
        from scipy.signal import fftconvolve

        f = fftconvolve(d, k, mode="full")
        y0, x0 = r0 - 2 * m, c0 - 2 * m
        ys, xs = max(0, -y0), max(0, -x0)
        ye = min(f.shape[0], out.shape[0] - y0)
        xe = min(f.shape[1], out.shape[1] - x0)
        if ye > ys and xe > xs:
            out[y0 + ys:y0 + ye, x0 + xs:x0 + xe] += f[ys:ye, xs:xe]

    # -- public ---------------------------------------------------------------------------------------
    def render(self, t: float = 0.0) -> np.ndarray:
        """The image at time ``t``: in-band radiance (W m^-2 sr^-1) after PSF, haze, pixel integration and
        relative illumination, ``(H, W)`` float64."""
        if not self.incremental:
            fine, hz, _, _ = self._full(t)
            return self._finish(fine, hz)
        if self._bg is None:
            fine, hz, L, Lc = self._full(None)
            self._bg = {"fine": fine, "hz": hz, "L": L, "Lc": Lc}
        bg = self._bg
        fine = bg["fine"].copy()
        hz = None if bg["hz"] is None else bg["hz"].copy()
        k = self.optics.kernels[0]
        m = k.shape[0] // 2
        boxes = self.scene.dynamic_regions(t) or []
        fine_boxes = _merge([self._range(self.ya, y0, y1) + self._range(self.xa, x0, x1)
                             for (x0, y0, x1, y1) in boxes])
        for r0, r1, c0, c1 in fine_boxes:
            d = self._radiance(self.ya[r0:r1], self.xa[c0:c1], t) - bg["L"][r0:r1, c0:c1]
            self._add_full(fine, d, k, r0, c0, m)
        if hz is not None:
            S = self.SUB
            kf = self.optics.far_kernel
            for q0, q1, p0, p1 in _merge([self._range(self.yc, y0, y1, S) + self._range(self.xc, x0, x1, S)
                                          for (x0, y0, x1, y1) in boxes]):
                dc = self._coarse_radiance(q0, q1, p0, p1, t) - bg["Lc"][q0:q1, p0:p1]
                self._add_full(hz, dc, kf, q0, p0, kf.shape[0] // 2)
        return self._finish(fine, hz)


def _merge(boxes: list[tuple[int, int, int, int]]) -> list[tuple[int, int, int, int]]:
    """Index boxes (r0, r1, c0, c1), empty ones dropped and overlapping ones merged into their union,
    so that no sample is counted twice."""
    out = [b for b in boxes if b[1] > b[0] and b[3] > b[2]]
    merged = True
    while merged:
        merged = False
        for i in range(len(out)):
            for j in range(i + 1, len(out)):
                a, b = out[i], out[j]
                if a[0] < b[1] and b[0] < a[1] and a[2] < b[3] and b[2] < a[3]:
                    out[i] = (min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3]))
                    del out[j]
                    merged = True
                    break
            if merged:
                break
    return out


def render_channel(scene: Scene, optics: ChannelOptics, radiance: BandRadiance, t: float = 0.0,
                   relative_illumination: bool = True) -> np.ndarray:
    """The channel's noise-free image of ``scene`` at time ``t`` (see :class:`ChannelRenderer`)."""
    return ChannelRenderer(scene, optics, radiance, relative_illumination).render(t)


def relative_illumination_map(ch: Channel) -> np.ndarray:
    """``cos^4`` of the field angle at each pixel centre."""
    H, W = ch.shape
    y = ch.positions_um(H, 1, 0)
    x = ch.positions_um(W, 1, 0)
    r2 = (x[None, :] ** 2 + y[:, None] ** 2) / ch.focal_length_um ** 2
    return 1.0 / (1.0 + r2) ** 2


# ----------------------------------------------------------------------------------------------
# polariser
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Polarizer:
    """Rotating polariser: ``theta(t) = 2 pi rate t + phase``; see module docstring."""

    rate_hz: float = 2.0
    mode: str = "sync"  # 'sync' or 'free'
    phase_rad: float | None = None  # sync: default 0; free: drawn from rng when None
    rate_error: float = 0.002  # free mode: relative std of the actual rotation rate
    extinction: float = 0.0
    tau_s: float = 0.0

    def __post_init__(self) -> None:
        check_range("polarizer rate_hz", self.rate_hz, 0.0, 1000.0, lo_inclusive=True, unit="Hz")
        object.__setattr__(self, "mode", check_choice("polarizer mode", self.mode, ("sync", "free")))
        check_range("rate_error", self.rate_error, 0.0, 0.5, lo_inclusive=True)
        check_range("extinction", self.extinction, 0.0, 0.5, lo_inclusive=True)
        check_range("tau_s", self.tau_s, 0.0, 10.0, lo_inclusive=True, unit="s")

    def angles(self, times_s: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, dict[str, Any]]:
        """Polariser angles (rad) at ``times_s`` and the realised parameters."""
        rate = self.rate_hz
        if self.mode == "free":
            phase = float(rng.uniform(0, 2 * np.pi)) if self.phase_rad is None else float(self.phase_rad)
            rate = rate * (1.0 + self.rate_error * float(rng.standard_normal()))
        else:
            phase = SYNC_PHASE_RAD if self.phase_rad is None else float(self.phase_rad)
        return 2 * np.pi * rate * np.asarray(times_s) + phase, {"mode": self.mode, "rate_hz": rate, "phase_rad": phase}

    def mixing(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """(nominal alpha, effective alpha a', gain 1 + eps) so that the sensor sees
        ``(1 + eps) [a' I1 + (1 - a') I2]``."""
        if self.tau_s > 0:
            wt = 2 * np.pi * 2 * self.rate_hz * self.tau_s
            amp, lag = 1 / math.sqrt(1 + wt * wt), math.atan(wt)
            alpha = 0.5 + 0.5 * amp * np.cos(2 * theta - lag)
        else:
            alpha = np.cos(theta) ** 2
        e = self.extinction
        a_eff = (alpha + e * (1 - alpha)) / (1 + e)
        return alpha, a_eff, 1.0 + e

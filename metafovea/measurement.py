"""The Measurement file: frames from the camera (simulated or real) plus what is known about them.

Written with :func:`metafovea.io.atomic_save_npz` (uncompressed ``.npz`` + JSON metadata under
``__meta__``); the format is documented in ``docs/measurement_format.md``. Arrays:

``frames`` (T, H, W) float32 (required)
    Sensor frames in ``meta['units']`` (simulator: ADC digital numbers, DN).
``times_s`` (T,) float64 (required)
    Frame times in seconds.
``alpha`` (T,) float64 (optional: absent or NaN when unknown)
    Effective mixing ratio of the foveal (x-polarised) image per frame, so that
    ``frames = alpha * truth_x1 + (1 - alpha) * truth_x2 + fpn + noise``.
``truth_x1``, ``truth_x2`` (H, W) or (T, H, W) float32 (optional)
    Noise-free foveal and perifoveal images on the sensor, same units as ``frames`` ((T, H, W) for
    scenes that change in time).
``fpn`` (H, W) float32 (optional)
    The fixed pattern (of frame 0 when it drifts); ``fpn_u`` (H, r), ``fpn_v`` (W, r), ``fpn_s`` (r,)
    its factors, ``fpn_weights`` (T, r) the per-frame weights when it drifts
    (``fpn_t = (fpn_u * fpn_weights[t]) @ fpn_v.T``).
``theta_rad`` (T,) (optional)
    Polariser angle per frame.
``calibration`` (N, H, W) (optional)
    Frames of a uniform source for the fixed-pattern calibration.
``bad_pixels`` (H, W) bool (optional)
    Pixels whose samples are left out (dead or hot pixels of the camera's map).
``psf_x1``, ``psf_x2`` (n, n) (optional)
    Each channel's PSF on the pixel grid (odd ``n``, centred, sum ~1: core, haze and glare), and
``illumination_x1``, ``illumination_x2`` (H, W) (optional)
    its relative illumination: what a PSF-aware reconstruction (:mod:`metafovea.reconstruct.deconvolve`) uses.
``psf_patches_x1``, ``psf_patches_x2`` (p, p, n, n) (optional)
    A field-dependent PSF: the kernels at the centres of a ``p x p`` grid of equal patches of the crop (row-major,
    patch ``(i, j)`` centred on pixel ``((i + 1/2) H / p - 1/2, (j + 1/2) W / p - 1/2)``), the PSF between them
    interpolated bilinearly (:func:`patch_weights`; ``psf_x*`` stays the kernel nearest the axis).
``scene_x1``, ``scene_x2`` (H, W) (optional)
    Truth for scoring only: the scene through a perfect lens (no PSF, haze or relative illumination), in DN.

Samples at or beyond the ADC's range (:attr:`Measurement.valid_range_dn`: ``meta['saturation_dn']`` /
``meta['floor_dn']``, or the simulator's ``meta['sensor']`` ``adc_bits``) are left out by the reconstruction too.

Metadata (``meta``): ``units``, ``foveal_constraint`` ``{scale, gain, offset_dn}`` (the relation
``D x1 = gain C x2 + offset`` between the two images, see :class:`FovealConstraint`), and whatever the writer
records. This module is the one reader of the metadata the reconstruction uses:
:class:`FovealConstraint.from_meta` (the foveal constraint), :class:`RadiometricCalibration.from_meta` (DN to
kelvin: ``dark_dn``, ``dn_per_k_300K``, ``radiometry``) and the :class:`Measurement` properties
:attr:`~Measurement.valid_range_dn`, :attr:`~Measurement.dark_dn`, :attr:`~Measurement.channel_gains`,
:attr:`~Measurement.recorded_scale`, :attr:`~Measurement.psf_pedestals`, :attr:`~Measurement.true_noise_dn` and
:attr:`~Measurement.scene_truth`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.errors import InputError
from metafovea.io import atomic_save_npz, load_npz, prepare_output

KIND = "measurement"
#: The recording schema: the metadata keys a recording may carry and the only ones the reconstruction reads
#: (docs/measurement_format.md, "The recording schema"; a test strips every other key and finds the
#: reconstruction unchanged)
RECORDING_META = ("units", "frame_rate_hz", "pixel_pitch_um", "netd_k", "scale", "foveal_constraint",
                  "polarizer_hz", "polarizer_mode", "polarizer_phase_deg", "polarizer_extinction", "bolometer_tau_s",
                  "dark_dn", "saturation_dn", "floor_dn", "channel_gain", "dn_per_k_300K", "radiometry", "fpn_rank",
                  "psf_pedestal")
#: the arrays the reconstruction reads (``alpha``: the camera's logged mixing ratio, which ``lsq`` uses and the
#: unknown-alpha methods only score against)
RECORDING_ARRAYS = ("frames", "times_s", "alpha", "theta_rad", "calibration", "bad_pixels", "flat_field", "psf_x1",
                    "psf_x2", "illumination_x1", "illumination_x2", "psf_patches_x1", "psf_patches_x2")
#: truth for scoring only: arrays, and the metadata key ``truth`` (a dict of what the writer knows and a camera
#: would not record: the simulator's realised polariser phase and rate, its noise level, ...)
SCORING_ARRAYS = ("truth_x1", "truth_x2", "scene_x1", "scene_x2", "fpn", "fpn_u", "fpn_v", "fpn_s", "fpn_weights")
TRUTH_KEY = "truth"
#: what a recording that says nothing about its polariser is taken to be: the paper's, turning freely at 2 Hz, with
#: an ideal polariser and an instantaneous sensor (PolarizerSpec.from_meta says so in ``assumed``)
POLARIZER_DEFAULTS = {"rate_hz": 2.0, "mode": "free", "phase_deg": None, "extinction": 0.0, "tau_s": 0.0}
#: each polariser quantity's key in a recording (and the flag of ``import`` / ``reconstruct`` that sets it)
POLARIZER_KEYS = {"rate_hz": "polarizer_hz", "mode": "polarizer_mode", "phase_deg": "polarizer_phase_deg",
                  "extinction": "polarizer_extinction", "tau_s": "bolometer_tau_s"}
OPTIONAL = ("alpha", "truth_x1", "truth_x2", "fpn", "fpn_u", "fpn_v", "fpn_s", "fpn_weights", "theta_rad",
            "calibration", "bad_pixels", "flat_field", "psf_x1", "psf_x2", "illumination_x1", "illumination_x2",
            "scene_x1", "scene_x2", "psf_patches_x1", "psf_patches_x2")


def patch_weights(n: int, size: int, centres: Sequence[float] | None = None) -> list[np.ndarray]:
    """1-D tent weights along an axis of ``size`` samples for ``n`` patch centres (default: the centres of ``n``
    equal patches, ``(i + 1/2) size / n - 1/2``): a partition of unity, linear between neighbouring centres and
    constant beyond the outer ones. ``w_i(y) w_j(x)`` is patch ``(i, j)``'s weight: the interpolation of a
    field-dependent PSF (``psf_patches_x*``) that the simulator renders and the reconstruction inverts."""
    x = np.arange(size, dtype=np.float64)
    c = np.asarray([(i + 0.5) * size / n - 0.5 for i in range(n)] if centres is None else centres, dtype=np.float64)
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


def _real(a: np.ndarray) -> bool:
    """Real numbers (not complex, not bool, not objects or strings)."""
    return np.issubdtype(a.dtype, np.number) and not np.iscomplexobj(a)


#: the largest value a kernel or an illumination may hold: the solves run partly in single precision (largest
#: 3.4e38), where a kernel of 1e300 overflowed into "estimate: array with NaN/inf" and an illumination of 1e300
#: made the noise covariance singular (found by tampering with a file)
MAX_ARRAY_VALUE = 1e30


def check_kernel(name: str, k: Any, source: str | None = None) -> np.ndarray:
    """A channel's PSF on the pixel grid (``psf_x*``): real numbers, a square kernel of odd size (centred), finite
    values >= 0 with a positive sum; float64, else an InputError naming ``name`` (and the file ``source``). The one
    check of a kernel, for a recording's arrays and a PSF file's (:class:`~metafovea.reconstruct.joint.ChannelPSFs`)."""
    a = np.asarray(k)
    if not _real(a):
        raise InputError(name, str(a.dtype), "real numbers: a square kernel of odd size, centred", source=source)
    a = a.astype(np.float64)
    if a.ndim != 2 or a.shape[0] != a.shape[1] or a.shape[0] % 2 == 0:
        raise InputError(name, f"array of shape {a.shape}", "a square kernel of odd size, centred", source=source)
    a = _rounding_to_zero(a)
    if not np.all(np.isfinite(a)) or a.min() < 0 or a.sum() <= 0 or a.max() > MAX_ARRAY_VALUE:
        raise InputError(name, "kernel", f"finite values >= 0 with a positive sum, at most {MAX_ARRAY_VALUE:g}",
                         source=source)
    return a


def _rounding_to_zero(a: np.ndarray) -> np.ndarray:
    """``a`` with negative values of rounding size (down to -1e-9 of its largest: an FFT-resampled kernel's
    -1.6e-17, seen in the simulator's reduced model) set to 0; larger negative values are left for the caller."""
    if a.size and np.all(np.isfinite(a)) and 0 > a.min() >= -1e-9 * max(float(a.max()), 0.0):
        return np.maximum(a, 0.0)
    return a


def check_patches(name: str, k: Any, source: str | None = None) -> np.ndarray:
    """A field-dependent PSF (``psf_patches_x*``): real ``(p, p, n, n)``, 2 <= p <= 9, odd n, finite values >= 0,
    each kernel with a positive sum; float64, else an InputError naming ``name``."""
    a = np.asarray(k)
    if not _real(a):
        raise InputError(name, str(a.dtype), "real numbers: (p, p, n, n) kernels", source=source)
    a = a.astype(np.float64)
    if (a.ndim != 4 or a.shape[0] != a.shape[1] or not 2 <= a.shape[0] <= 9 or a.shape[2] != a.shape[3]
            or a.shape[2] % 2 == 0):
        raise InputError(name, f"array of shape {a.shape}",
                         "(p, p, n, n): 2 <= p <= 9 patches a side, square kernels of odd size n", source=source)
    a = _rounding_to_zero(a)
    if not np.all(np.isfinite(a)) or a.min() < 0 or a.sum(axis=(2, 3)).min() <= 0 or a.max() > MAX_ARRAY_VALUE:
        raise InputError(name, "kernels", f"finite values >= 0, each with a positive sum, at most {MAX_ARRAY_VALUE:g}",
                         source=source)
    return a


def check_illumination(name: str, a: Any, shape: tuple[int, int] | None, source: str | None = None) -> np.ndarray:
    """A channel's relative illumination (``illumination_x*``): real, finite, >= 0, of the frames' ``shape``
    (None: any 2-D shape); float64, else an InputError naming ``name``."""
    v = np.asarray(a)
    want = f"(H, W) = {shape}" if shape is not None else "(H, W)"
    if not _real(v) or v.ndim != 2 or (shape is not None and v.shape != tuple(shape)):
        raise InputError(name, f"array of shape {v.shape}, dtype {v.dtype}", f"real values of {want}",
                         source=source)
    v = v.astype(np.float64)
    if not np.all(np.isfinite(v)) or v.min() < 0 or v.max() > MAX_ARRAY_VALUE:  # 0: refused where solved
        raise InputError(name, "array", f"a finite relative illumination >= 0, at most {MAX_ARRAY_VALUE:g}",
                         source=source)
    return v


@dataclass(frozen=True)
class FovealConstraint:
    """``D x1 = gain * C x2 + offset``: the foveal image ``x1``, downsampled by ``scale`` (``D``), equals the
    centre crop ``C`` of the perifoveal image ``x2`` up to a radiometric ``gain`` (NA1^2/NA2^2 for the simulator's
    lenses) and an ``offset`` in the frames' units."""

    scale: float = 6.0
    gain: float = 1.0
    offset: float = 0.0

    @classmethod
    def from_meta(cls, meta: dict[str, Any], *, scale: float | None = None, gain: float | None = None,
                  offset: float | None = None) -> FovealConstraint:
        """Explicit values first, then ``meta['foveal_constraint']`` (``scale``, ``gain``, ``offset_dn``), then
        ``meta['scale']`` with gain 1 and offset 0 (older files, real recordings), then scale 6.

        A bad explicit ``scale`` names ``scale``; a bad one from the file names the file's key."""
        fc = meta.get("foveal_constraint")
        if fc is not None and not isinstance(fc, dict):
            raise InputError("meta.foveal_constraint", fc, "a mapping {scale, gain, offset_dn}")
        fc = fc or {}

        def pick(given: float | None, key: str, fallback: Any) -> float:
            v = given if given is not None else fc.get(key, fallback)
            name = {"offset_dn": "offset"}.get(key, key) if given is not None else f"foveal_constraint.{key}"
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise InputError(name, v, "a number") from None
            if not np.isfinite(v):
                raise InputError(name, v, "a finite number")
            return v

        out = cls(scale=pick(scale, "scale", meta.get("scale", 6.0)), gain=pick(gain, "gain", 1.0),
                  offset=pick(offset, "offset_dn", 0.0))
        if not 1.0 <= out.scale <= 1000.0:
            raise InputError("foveal_constraint.scale" if scale is None else "scale", out.scale,
                             "1 <= scale <= 1000 (f1/f2 of the two lenses, 6 for the paper's)",
                             detail=None if scale is not None else "from the file's meta; override with scale=...")
        if not out.gain > 0:
            raise InputError("gain" if gain is not None else "foveal_constraint.gain", out.gain,
                             "a positive radiometric gain (NA1^2/NA2^2)")
        return out

    def as_kwargs(self) -> dict[str, float]:
        """``{scale, foveal_gain, foveal_offset}``: the keyword names of the reconstruction solvers."""
        return {"scale": self.scale, "foveal_gain": self.gain, "foveal_offset": self.offset}


@dataclass(frozen=True)
class PolarizerSpec:
    """The rotating polariser as a recording states it: rate, mode, phase (sync), extinction leak and the bolometer's
    time constant, each with its source.

    Attributes
    ----------
    rate_hz : float, Hz
        Revolutions per second (``polarizer_hz``).
    mode : {'free', 'sync'}
        ``'sync'``: the rotation is locked to the frames and its phase is known (``polarizer_mode``).
    phase_deg : float or None, degrees
        Sync mode: the polariser's angle at ``t = 0`` (``polarizer_phase_deg``); None when free-running.
    extinction : float
        Leaked fraction of the blocked polarisation (``polarizer_extinction``).
    tau_s : float, s
        The bolometer's first-order time constant (``bolometer_tau_s``).
    sources : dict
        Per quantity: ``"file"`` (the recording's key), ``"given"`` (an explicit value: a flag or keyword), or
        ``"default"`` (:data:`POLARIZER_DEFAULTS`, the paper's camera).
    """

    rate_hz: float
    mode: str
    phase_deg: float | None
    extinction: float
    tau_s: float
    sources: dict[str, str] = field(default_factory=dict)

    @classmethod
    def from_meta(cls, meta: dict[str, Any], **given: Any) -> PolarizerSpec:
        """Explicit values (``rate_hz``, ``mode``, ``phase_deg``, ``extinction``, ``tau_s``; None: not given) first,
        then the recording's keys (:data:`POLARIZER_KEYS`), then :data:`POLARIZER_DEFAULTS`. A sync mode without a
        phase is refused; a phase given to a free-running polariser is ignored (``sources`` says so)."""
        from metafovea.polarizer import RotatingPolarizer, check_mode

        unknown = set(given) - set(POLARIZER_KEYS)
        if unknown:
            raise InputError("polarizer", sorted(unknown), "keywords among " + ", ".join(POLARIZER_KEYS))
        vals: dict[str, Any] = {}
        sources: dict[str, str] = {}
        for name, key in POLARIZER_KEYS.items():
            if given.get(name) is not None:
                vals[name], sources[name] = given[name], "given"
            elif meta.get(key) is not None:
                vals[name], sources[name] = meta[key], "file"
            else:
                vals[name], sources[name] = POLARIZER_DEFAULTS[name], "default"
        where = {n: (n if sources[n] == "given" else POLARIZER_KEYS[n]) for n in POLARIZER_KEYS}
        for name in ("rate_hz", "extinction", "tau_s") + (("phase_deg",) if vals["phase_deg"] is not None else ()):
            try:
                vals[name] = float(vals[name])
            except (TypeError, ValueError):
                raise InputError(where[name], vals[name], "a number") from None
            if not math.isfinite(vals[name]):
                raise InputError(where[name], vals[name], "a finite number")
        vals["mode"] = check_mode(str(vals["mode"]).lower())
        if vals["mode"] == "sync" and vals["phase_deg"] is None:
            raise InputError(where["phase_deg"], None, "the polariser's angle at t = 0 (degrees) for a polariser "
                             "synchronised to the frames (or polarizer_mode free)")
        if vals["mode"] == "free" and vals["phase_deg"] is not None:
            vals["phase_deg"], sources["phase_deg"] = None, "ignored (free-running: the phase is fitted)"
        try:
            RotatingPolarizer(vals["rate_hz"], vals["extinction"], vals["tau_s"])
        except InputError as e:  # name the key or keyword the value came from
            name = {"polarizer rate_hz": "rate_hz"}.get(e.parameter, e.parameter)
            raise InputError(where.get(name, e.parameter), e.value, e.allowed) from None
        return cls(sources=sources, **vals)

    @property
    def assumed(self) -> list[str]:
        """The quantities taken from :data:`POLARIZER_DEFAULTS` because neither the file nor the caller gave
        them, each as ``"key = value (why)"``."""
        why = "the recording does not say: the paper's camera"
        return [f"{POLARIZER_KEYS[n]} = {getattr(self, n)} ({why})" for n, src in self.sources.items()
                if src == "default" and n != "phase_deg"]

    def summary(self) -> dict[str, Any]:
        """``{rate_hz, mode, phase_deg, extinction, tau_s, sources, assumed}`` (JSON-ready)."""
        return {"rate_hz": self.rate_hz, "mode": self.mode, "phase_deg": self.phase_deg,
                "extinction": self.extinction, "tau_s": self.tau_s, "sources": dict(self.sources),
                "assumed": self.assumed}

    def as_meta(self) -> dict[str, Any]:
        """The recording's keys for the values that were given or read (what ``metafovea import`` writes; a
        default stays unwritten, so that a reader still sees it as an assumption)."""
        return {POLARIZER_KEYS[n]: getattr(self, n) for n, src in self.sources.items()
                if src in ("given", "file") and getattr(self, n) is not None}


#: the recording schema's plain numbers: key -> (lowest, highest, open at the low end, what it is); the polariser's
#: keys and ``foveal_constraint`` are checked where they are read (PolarizerSpec / FovealConstraint.from_meta), as
#: a flag of ``reconstruct`` may replace them
_META_NUMBERS = {
    "frame_rate_hz": (0.0, 1e6, True, "frames per second"),
    "pixel_pitch_um": (0.0, 1e4, True, "the pixel pitch in um"),
    "netd_k": (0.0, 1e3, False, "the NETD in K (0: a noiseless camera, e.g. simulate --netd 0 or --no-noise)"),
    "scale": (1.0, 1000.0, False, "f1 / f2 of the two lenses (6 for the paper's)"),
    "dark_dn": (-1e15, 1e15, False, "the dark level in the frames' unit"),
    "saturation_dn": (-1e15, 1e15, False, "the ADC's full scale in the frames' unit"),
    "floor_dn": (-1e15, 1e15, False, "the ADC's floor in the frames' unit"),
}
#: the schema's ``{x1, x2}`` mappings: key -> (lowest, open at the low end, what each value is)
_META_PAIRS = {
    "channel_gain": (0.0, True, "the channel's relative radiometric gain"),
    "dn_per_k_300K": (0.0, True, "the channel's DN per kelvin at 300 K"),
    "psf_pedestal": (0.0, False, "the power of the channel's PSF beyond its kernel"),
}


def _meta_number(key: str, v: Any, lo: float, hi: float, open_low: bool, what: str, source: str | None) -> float:
    """``v`` as a float within ``lo..hi`` (``lo`` excluded when ``open_low``), else an InputError naming ``key``."""
    rng = f"{lo:g} < {key.split('.')[-1]} <= {hi:g}" if open_low else f"{lo:g} <= {key.split('.')[-1]} <= {hi:g}"
    allowed = f"a finite number, {rng}: {what} (docs/measurement_format.md, the recording schema)"
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise InputError(f"meta.{key}", v, allowed, source=source)
    x = float(v)
    if not (math.isfinite(x) and (x > lo if open_low else x >= lo) and x <= hi):
        raise InputError(f"meta.{key}", v, allowed, source=source)
    return x


def check_recording_meta(meta: Any, source: str | None = None) -> None:
    """Check the recording schema's keys that ``meta`` holds (absent or null: not stated) against their types and
    ranges (docs/measurement_format.md); the first bad one is an :class:`InputError` naming ``meta.KEY`` and the
    file ``source``. Keys outside the schema are not read, so not checked."""
    if not isinstance(meta, dict):
        raise InputError("meta", type(meta).__name__, "a mapping of the recording schema's keys", source=source)
    units = meta.get("units")
    if units is not None and (not isinstance(units, str) or not units.strip()):
        raise InputError("meta.units", units, "a label of the frames' unit, e.g. DN", source=source)
    vals = {k: _meta_number(k, meta[k], *spec, source) for k, spec in _META_NUMBERS.items()
            if meta.get(k) is not None}
    if "floor_dn" in vals and "saturation_dn" in vals and not vals["floor_dn"] < vals["saturation_dn"]:
        raise InputError("meta.floor_dn", meta["floor_dn"], f"below meta.saturation_dn = {meta['saturation_dn']:g} "
                         "(the ADC's floor under its full scale)", source=source)
    for key, (lo, open_low, what) in _META_PAIRS.items():
        d = meta.get(key)
        if d is None:
            continue
        if not isinstance(d, dict):
            raise InputError(f"meta.{key}", d, "a mapping {x1, x2}: " + what, source=source)
        for ch in ("x1", "x2"):  # a channel left out takes its default (dn_per_k_300K needs both); null is not one
            if ch in d or key == "dn_per_k_300K":
                _meta_number(f"{key}.{ch}", d.get(ch), lo, 1e15, open_low, what, source)
    rank = meta.get("fpn_rank")
    if rank is not None and (isinstance(rank, bool) or not isinstance(rank, (int, float)) or not math.isfinite(rank)
                             or rank != int(rank) or not 0 <= rank <= 10000):
        raise InputError("meta.fpn_rank", rank, "an integer 0 <= fpn_rank <= 10000 (0: no fixed pattern)",
                         source=source)
    rad = meta.get("radiometry")
    if rad is not None:
        if not isinstance(rad, dict):
            raise InputError("meta.radiometry", rad, "a mapping {band_um, filter, dL_dT_300K}", source=source)
        band = rad.get("band_um")  # the band the kelvin conversion integrates: needed
        ok = isinstance(band, (list, tuple)) and len(band) == 2
        b = [_meta_number("radiometry.band_um", x, 0.0, 1e4, True, "a wavelength in um", source)
             for x in band] if ok else []  # type: ignore[union-attr]
        if not ok or not b[0] < b[1]:
            raise InputError("meta.radiometry.band_um", band, "[lowest, highest] wavelength in um, lowest < highest",
                             source=source)
        filt = rad.get("filter")
        if filt:
            if not isinstance(filt, (list, tuple)) or len(filt) != 2:
                raise InputError("meta.radiometry.filter", filt, "null, or [centre, bandwidth] in um",
                                 source=source)
            for x in filt:
                _meta_number("radiometry.filter", x, 0.0, 1e4, True, "the filter's centre and bandwidth in um",
                             source)
        if rad.get("dL_dT_300K") is not None:
            _meta_number("radiometry.dL_dT_300K", rad["dL_dT_300K"], 0.0, 1e15, True,
                         "the band radiance's derivative at 300 K, W m^-2 sr^-1 K^-1", source)


def recording_view(meta: dict[str, Any]) -> dict[str, Any]:
    """The part of ``meta`` the reconstruction may read: the keys of the recording schema
    (:data:`RECORDING_META`) and the scoring-only ``truth`` dict."""
    return {k: v for k, v in meta.items() if k in RECORDING_META or k in (TRUTH_KEY, "kind", "schema_version")}


@dataclass(frozen=True)
class RadiometricCalibration:
    """The sensor's radiometric model, ``DN_i = dark_dn + g_i L(T) / (dL/dT)(300 K)``, inverted to brightness
    temperature.

    Attributes
    ----------
    dn_per_k_300k : tuple of 2 float
        ``g_i``: DN per kelvin at 300 K through each channel (``meta['dn_per_k_300K']``).
    dl_dt_300k : float
        ``dL/dT`` of the band's in-band radiance at 300 K, W m^-2 sr^-1 K^-1 (``meta['radiometry']
        ['dL_dT_300K']``, else computed from the band).
    band_um : tuple of 2 float
        The spectral band, um.
    filter_um : tuple of 2 float or None
        ``(centre, bandwidth)`` of a band-pass filter, um.
    """

    dn_per_k_300k: tuple[float, float]
    dl_dt_300k: float
    band_um: tuple[float, float]
    filter_um: tuple[float, float] | None = None

    @classmethod
    def from_meta(cls, meta: dict[str, Any] | None) -> RadiometricCalibration | None:
        """The calibration a Measurement's metadata records (``dn_per_k_300K`` ``{x1, x2}`` and ``radiometry``
        ``{band_um, filter, dL_dT_300K}``), or None when it records none.

        Parameters
        ----------
        meta : dict or None

        Returns
        -------
        RadiometricCalibration or None
        """
        if not meta or meta.get("dn_per_k_300K") is None or meta.get("radiometry") is None:
            return None
        rad = meta["radiometry"]
        filt = rad.get("filter")
        band_um = tuple(rad["band_um"])
        filter_um = tuple(filt) if filt else None
        d = meta["dn_per_k_300K"]
        dl_dt = rad.get("dL_dT_300K") or cls._band(band_um, filter_um).derivative(300.0)
        return cls((float(d["x1"]), float(d["x2"])), float(dl_dt), band_um, filter_um)  # type: ignore[arg-type]

    @staticmethod
    def _band(band_um: tuple[float, float], filter_um: tuple[float, float] | None) -> Any:
        from metafovea.radiometry import BandRadiance

        return BandRadiance.from_band(band_um, filter_um=filter_um)

    def temperatures(self, scene_dn: Sequence[Any], offset: float) -> tuple[np.ndarray, np.ndarray]:
        """Brightness temperatures of both channels' images.

        Parameters
        ----------
        scene_dn : sequence of 2 array_like
            Channel 1's and 2's images, DN (any shape).
        offset : float
            The dark level, DN.

        Returns
        -------
        tuple of 2 ndarray, K
            ``T = L^-1((s - offset) (dL/dT)(300 K) / g_i)``, ``L^-1`` the band's inverse
            (:meth:`metafovea.radiometry.BandRadiance.temperature`); NaN where the radiance is not positive.
        """
        band = self._band(self.band_um, self.filter_um)
        return tuple(band.temperature((np.asarray(s, dtype=np.float64) - offset) * self.dl_dt_300k / k)
                     for s, k in zip(scene_dn, self.dn_per_k_300k))  # type: ignore[return-value]


@dataclass(frozen=True)
class Measurement:
    """Frames plus known mixing ratios, ground truth and metadata (see module docstring).

    Every array is checked on construction (shape against the frames, real numbers, finite where a NaN would
    make it meaningless); ``source`` (the file :meth:`load` read, if any) is named in those errors."""

    frames: np.ndarray
    times_s: np.ndarray
    alpha: np.ndarray | None = None
    truth_x1: np.ndarray | None = None
    truth_x2: np.ndarray | None = None
    fpn: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    extras: dict[str, np.ndarray] = field(default_factory=dict)  # fpn_u, fpn_v, fpn_s, fpn_weights, theta_rad, ...
    source: str | None = field(default=None, compare=False)  #: the file this was loaded from

    def __post_init__(self) -> None:
        src = self.source
        f = np.asarray(self.frames)
        if f.ndim == 2:
            f = f[None]
        if f.ndim != 3 or f.shape[0] < 1 or min(f.shape[1:]) < 1:
            raise InputError("frames", f"array of shape {np.shape(self.frames)}", "a (T, H, W) array with T >= 1",
                             source=src)
        if not _real(f):
            raise InputError("frames", str(f.dtype), "real numbers", source=src)
        if not np.any(np.isfinite(f)):
            raise InputError("frames", "no finite value", "frames with finite pixel values (NaN/inf pixels are "
                             "masked, but all of them are non-finite)", source=src)
        with np.errstate(over="ignore"):  # beyond float32's range: inf, masked as every non-finite sample is
            f = f.astype(np.float32, copy=False)
        T, H, W = f.shape
        t = np.asarray(self.times_s)
        t = t.astype(np.float64).reshape(-1) if _real(t) else np.full(np.shape(t), np.nan).reshape(-1)
        if t.shape != (T,) or not np.all(np.isfinite(t)):
            raise InputError("times_s", f"array of shape {t.shape}", f"({T},) finite times in seconds", source=src)
        if T > 1 and not np.all(np.diff(t) > 0):  # the polariser model and the video windows read time's order
            k = int(np.argmax(~(np.diff(t) > 0)))
            raise InputError("times_s", f"{t[k]:g} s then {t[k + 1]:g} s (frames {k} and {k + 1})",
                             "strictly increasing times in seconds, one per frame (metafovea import removes a "
                             "recording's duplicated frames)", source=src)
        object.__setattr__(self, "frames", f)
        object.__setattr__(self, "times_s", t)
        if self.alpha is not None:
            object.__setattr__(self, "alpha", self._checked_alpha(T))
        for name in ("truth_x1", "truth_x2"):
            v = getattr(self, name)
            if v is not None:
                v = np.asarray(v)
                if not _real(v) or v.shape not in ((H, W), (T, H, W)):
                    raise InputError(name, f"array of shape {v.shape}, dtype {v.dtype}",
                                     f"real values of shape (H, W) = {(H, W)} or (T, H, W) = {(T, H, W)}", source=src)
                if not np.all(np.isfinite(v)):
                    raise InputError(name, "array with NaN/inf", "finite truth images", source=src)
                object.__setattr__(self, name, v.astype(np.float32, copy=False))
        if self.fpn is not None:
            v = np.asarray(self.fpn)
            if not _real(v) or v.shape != (H, W):
                raise InputError("fpn", f"array of shape {v.shape}, dtype {v.dtype}",
                                 f"real values of the frames' (H, W) = {(H, W)}", source=src)
            if not np.all(np.isfinite(v)):
                raise InputError("fpn", "array with NaN/inf", "a finite fixed pattern", source=src)
            object.__setattr__(self, "fpn", v.astype(np.float32, copy=False))
        bad = set(self.extras) - set(OPTIONAL)
        if bad:
            raise InputError("extras", sorted(bad), "keys among " + ", ".join(OPTIONAL[4:]), source=src)
        ff = self.extras.get("flat_field")
        if ff is not None and (not _real(np.asarray(ff)) or np.shape(ff) != (H, W)
                               or not np.all(np.isfinite(ff)) or not np.all(np.asarray(ff) > 0)
                               or np.max(ff) > MAX_ARRAY_VALUE):
            raise InputError("flat_field", f"array of shape {np.shape(ff)}",
                             f"a finite, positive (H, W) = {(H, W)} relative gain, at most {MAX_ARRAY_VALUE:g}",
                             source=src)
        cal = self.extras.get("calibration")
        if cal is not None and (not _real(np.asarray(cal)) or np.ndim(cal) not in (2, 3)
                                or np.shape(cal)[-2:] != (H, W)):
            raise InputError("calibration", f"array of shape {np.shape(cal)}",
                             f"(Tc, H, W) or (H, W) frames with (H, W) = {(H, W)}", source=src)
        for name in ("psf_x1", "psf_x2"):
            if name in self.extras:
                check_kernel(name, self.extras[name], src)
        for name in ("psf_patches_x1", "psf_patches_x2"):
            if name in self.extras:
                check_patches(name, self.extras[name], src)
        for name in ("illumination_x1", "illumination_x2"):
            if name in self.extras:
                check_illumination(name, self.extras[name], (H, W), src)
        th = self.extras.get("theta_rad")
        if th is not None and (not _real(np.asarray(th)) or np.shape(th) != (T,)):
            raise InputError("theta_rad", f"array of shape {np.shape(th)}", f"({T},) real angles in radians, one per "
                             "frame", source=src)
        bp = self.extras.get("bad_pixels")
        if bp is not None:
            bpa = np.asarray(bp)
            if (bpa.shape != (H, W) or not (bpa.dtype == bool or _real(bpa))
                    or (bpa.dtype != bool and not np.all(np.isfinite(bpa)))):
                raise InputError("bad_pixels", f"array of shape {bpa.shape}, dtype {bpa.dtype}",
                                 f"an (H, W) = {(H, W)} map, true (non-zero) where a pixel is bad", source=src)
            if np.all(bpa.astype(bool)):
                raise InputError("bad_pixels", "every pixel marked bad", "a map that leaves pixels to read",
                                 source=src)
        check_recording_meta(self.meta, src)
        left_out = self.invalid_samples()
        if left_out is not None and left_out.all():
            lo, hi = self.valid_range_dn
            raise InputError("frames", "every sample at or beyond the ADC's range",
                             f"samples between meta.floor_dn = {lo} and meta.saturation_dn = {hi} (the ADC's "
                             "floor and full scale: samples at or beyond them carry no information)", source=src)

    def _checked_alpha(self, T: int) -> np.ndarray:
        """``alpha`` as ``(T,)`` float64: real, one per frame, finite values in [0, 1] (NaN = unknown)."""
        raw = np.asarray(self.alpha)
        if not _real(raw) or raw.ndim == 0 or raw.size != T:
            raise InputError("alpha", f"array of shape {raw.shape}, dtype {raw.dtype}",
                             f"one real mixing ratio per frame, shape ({T},)", source=self.source)
        a = raw.astype(np.float64).reshape(-1)
        fin = a[np.isfinite(a)]
        if fin.size and (fin.min() < -1e-9 or fin.max() > 1 + 1e-9):
            raise InputError("alpha", float(fin.min() if fin.min() < 0 else fin.max()), "values in [0, 1]",
                             source=self.source)
        return a

    # ----------------------------------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.frames.shape)  # type: ignore[return-value]

    @property
    def alpha_known(self) -> bool:
        return self.alpha is not None and bool(np.all(np.isfinite(self.alpha)))

    @property
    def valid_range_dn(self) -> tuple[float | None, float | None]:
        """``(floor, full scale)``: samples at or beyond either are clipped by the ADC and carry no information
        (``meta['floor_dn']`` / ``meta['saturation_dn']``; ``None`` where the file does not say)."""
        hi, lo = self.meta.get("saturation_dn"), self.meta.get("floor_dn")
        return (None if lo is None else float(lo)), (None if hi is None else float(hi))

    @property
    def dark_dn(self) -> float:
        """The frames' dark level, DN (``meta['dark_dn']``; 0 when the file records none)."""
        return float(self.meta.get("dark_dn", 0.0))

    @property
    def channel_gains(self) -> tuple[float, float]:
        """Both channels' relative radiometric gains ``(g_1, g_2)`` (``meta['channel_gain']`` ``{x1, x2}``; 1 for
        a channel the file does not state)."""
        cg = self.meta.get("channel_gain") or {}
        return float(cg.get("x1", 1.0)), float(cg.get("x2", 1.0))

    @property
    def recorded_scale(self) -> float | None:
        """The foveal expansion f1 / f2 the file states (``meta['scale']``), or None when it states none
        (:attr:`scale` then falls back to the foveal constraint's default)."""
        v = self.meta.get("scale")
        return float(v) if v else None

    @property
    def psf_pedestals(self) -> tuple[float, float]:
        """The power of each channel's PSF beyond its kernel ``psf_x*`` (``meta['psf_pedestal']`` ``{x1, x2}``; 0
        where not recorded)."""
        ped = self.meta.get("psf_pedestal") or {}
        return float(ped.get("x1", 0.0)), float(ped.get("x2", 0.0))

    @property
    def radiometric_calibration(self) -> RadiometricCalibration | None:
        """The file's DN-to-kelvin calibration (:meth:`RadiometricCalibration.from_meta`), or None."""
        return RadiometricCalibration.from_meta(self.meta)

    @property
    def true_noise_dn(self) -> float | None:
        """The frames' true temporal noise, DN, for scoring only (``meta['truth']['noise_dn']``, which the simulator
        writes: the sensor's noise and the ADC's 1/12 DN^2 in quadrature); None when not recorded (a recording)."""
        v = (self.meta.get(TRUTH_KEY) or {}).get("noise_dn")
        return None if v is None else float(v)

    @property
    def scene_truth(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The scene through a perfect lens, ``(scene_x1, scene_x2)`` (H, W) in DN, for scoring only; None unless
        the file holds both."""
        if "scene_x1" not in self.extras or "scene_x2" not in self.extras:
            return None
        return self.extras["scene_x1"], self.extras["scene_x2"]

    @property
    def fpn_rank(self) -> int | None:
        """The rank of the sensor's fixed pattern that the file declares (``meta['fpn_rank']``; 0: none), or None
        when the file does not say."""
        rank = self.meta.get("fpn_rank")
        return None if rank is None else int(rank)

    def polarizer_spec(self, **given: Any) -> PolarizerSpec:
        """The polariser the file states, with ``given`` values first (:meth:`PolarizerSpec.from_meta`); a bad
        value of the file's names the file."""
        try:
            return PolarizerSpec.from_meta(self.meta, **given)
        except InputError as e:
            if e.parameter in POLARIZER_KEYS.values() and e.source is None:
                raise InputError(e.parameter, e.value, e.allowed, source=self.source, detail=e.detail) from None
            raise

    def as_recording(self) -> Measurement:
        """This measurement with only the recording schema's metadata (:func:`recording_view`): what the
        reconstruction reads."""
        from dataclasses import replace

        return replace(self, meta=recording_view(self.meta), source=self.source)

    def invalid_samples(self) -> np.ndarray | None:
        """(T, H, W) bool: samples to leave out: non-finite, clipped at the ADC's floor or full scale
        (:attr:`valid_range_dn`), or on a pixel of ``extras['bad_pixels']`` (H, W); None when all are valid."""
        f = self.frames
        bad = ~np.isfinite(f)
        lo, hi = self.valid_range_dn
        if hi is not None:
            bad |= f >= hi
        if lo is not None:
            bad |= f <= lo
        bp = self.extras.get("bad_pixels")  # (H, W): checked on construction
        if bp is not None:
            bad |= np.asarray(bp).astype(bool)[None]
        return bad if bad.any() else None

    @property
    def foveal_constraint(self) -> FovealConstraint:
        """The file's :class:`FovealConstraint` (see :meth:`FovealConstraint.from_meta`)."""
        return FovealConstraint.from_meta(self.meta)

    @property
    def scale(self) -> float:
        """Foveal expansion f1 / f2 (6 for the paper): ``foveal_constraint.scale``."""
        return self.foveal_constraint.scale

    def fpn_frame(self, k: int) -> np.ndarray | None:
        """The fixed pattern in frame ``k`` (drifting or not), or None if not stored."""
        w = self.extras.get("fpn_weights")
        if w is not None and "fpn_u" in self.extras and "fpn_v" in self.extras:
            return ((self.extras["fpn_u"] * w[k]) @ self.extras["fpn_v"].T).astype(np.float32)
        return self.fpn

    def truth(self, k: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Noise-free (x1, x2) for frame ``k``, or None."""
        if self.truth_x1 is None or self.truth_x2 is None:
            return None
        x1 = self.truth_x1[k] if self.truth_x1.ndim == 3 else self.truth_x1
        x2 = self.truth_x2[k] if self.truth_x2.ndim == 3 else self.truth_x2
        return x1, x2

    def truth_over(self, spans: Sequence[tuple[int, int]]) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The noise-free ``(x1, x2)`` that outputs made from frames ``start:stop`` (one ``(start, stop)`` per output)
        show: a static truth as stored ``(H, W)``; a video truth averaged over each output's frames, ``(K, H, W)``
        float64; ``None`` for an image the file does not hold."""
        return tuple(t if t is None or t.ndim == 2 else
                     np.stack([t[a:b].mean(axis=0, dtype=np.float64) for a, b in spans])
                     for t in (self.truth_x1, self.truth_x2))  # type: ignore[return-value]

    # ----------------------------------------------------------------------------------------------
    def save(self, path: str | Path, force: bool = False) -> Path:
        """Write atomically (refuses to overwrite unless ``force``)."""
        p = prepare_output(path, force)
        arrays: dict[str, np.ndarray] = {"frames": self.frames, "times_s": self.times_s}
        for name in ("alpha", "truth_x1", "truth_x2", "fpn"):
            v = getattr(self, name)
            if v is not None:
                arrays[name] = v
        arrays.update(self.extras)
        meta = dict(self.meta)
        meta["kind"] = KIND
        meta.setdefault("units", "DN")
        return atomic_save_npz(p, meta, compress=False, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> Measurement:
        """Read a file written by :meth:`save` (or converted from a real camera, see the docs).

        Every way a file can fail to be a Measurement (unreadable, no frames, arrays that do not fit the frames)
        is an :class:`InputError`; one about an array names the file as its ``source``."""
        p = Path(path)
        if not p.is_file():
            raise InputError("measurement", str(p), "an existing measurement .npz file")
        arrays, meta = load_npz(p, name="measurement")
        if "frames" not in arrays:
            raise InputError("measurement", str(p), "a Measurement .npz holding a 'frames' (T, H, W) array")
        times = arrays.get("times_s")
        if times is None:  # the frame rate gives the times; none is assumed
            if meta.get("frame_rate_hz") is None:
                raise InputError("times_s", None, "a (T,) array of frame times, or frame_rate_hz in the metadata",
                                 source=str(p))
            rate = _meta_number("frame_rate_hz", meta["frame_rate_hz"], *_META_NUMBERS["frame_rate_hz"], str(p))
            times = np.arange(np.shape(arrays["frames"])[0] if np.ndim(arrays["frames"]) else 1) / rate
        extras = {k: arrays[k] for k in OPTIONAL[4:] if k in arrays}
        return cls(frames=arrays["frames"], times_s=times, alpha=arrays.get("alpha"), truth_x1=arrays.get("truth_x1"),
                   truth_x2=arrays.get("truth_x2"), fpn=arrays.get("fpn"), meta=meta, extras=extras, source=str(p))

    def plot(self, ax: Any = None, *, frame: int = 0) -> Any:
        """Frame ``frame`` in the iron palette (colour bar in the frames' unit, DN for the simulator) and alpha (or
        the mean frame level when alpha is unknown) against time (s).

        Parameters
        ----------
        ax : matplotlib Axes, sequence of 2 Axes, or None
            None: a new figure with both panels; one Axes: the frame only.
        frame : int
            Index of the frame shown.

        Returns
        -------
        matplotlib Figure
        """
        from metafovea.plotting import plot_measurement

        return plot_measurement(self, ax, frame=frame)

    def _repr_html_(self) -> str:
        from metafovea.plotting import measurement_html

        return measurement_html(self)

    def summary(self) -> dict[str, Any]:
        T, H, W = self.shape
        out = {"frames": T, "shape": [H, W], "units": self.meta.get("units", "DN"),
               "duration_s": float(self.times_s[-1] - self.times_s[0]) if T > 1 else 0.0,
               "alpha_known": self.alpha_known, "has_truth": self.truth_x1 is not None,
               "frame_min": float(self.frames.min()), "frame_max": float(self.frames.max())}
        if self.alpha_known:
            out["alpha_range"] = [float(self.alpha.min()), float(self.alpha.max())]
        if not math.isfinite(out["frame_min"]):
            out["frame_min"] = None
        return out

"""A recording into a :class:`~metafovea.measurement.Measurement`: :func:`to_measurement` (in memory) and
:func:`import_recording` (file to file, what ``metafovea import`` calls).

The steps, in order: read (:func:`metafovea.recordings.read.read_recording`); samples at the integer dtype's full
scale (a 16-bit camera's 65535) become NaN, which the reconstruction leaves out; times from the file, else
``frame_rate_hz``; the timing check, duplicated frames removed (:mod:`metafovea.recordings.timestamps`); the
polariser state (``alpha`` as is, or angles into ``theta_rad`` and the rotation's rate and phase for the
polariser model of ``reconstruct --method alternating``); the radiometric calibration
(:mod:`metafovea.recordings.calibration`: a user's two-point blackbody frames first, then ``--planck``, then the
file's Planck constants, else none: frames in camera counts; a FLIR file's emissivity, reflected temperature,
air and window go with the Planck constants, the blackbody calibration needs none of them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.errors import InputError, as_float, check_choice, check_int
from metafovea.measurement import FovealConstraint, Measurement, PolarizerSpec
from metafovea.radiometry import BAND_UM, check_band, check_filter, spectral_support_um
from metafovea.recordings.calibration import (
    GAIN_MODES,
    PlanckConstants,
    Radiometric,
    SceneParameters,
    correct_frames,
    from_planck,
    parse_two_point,
    two_point,
)
from metafovea.recordings.read import FORMATS, FRAME_AXES, TIME_UNITS, Recording, existing_recording, read_recording
from metafovea.recordings.timestamps import check_timing, frame_times

#: ``--polarizer-unit`` choices: angles in radians or degrees, or the mixing ratio alpha itself
POLARIZER_UNITS = ("rad", "deg", "alpha")


@dataclass(frozen=True)
class ImportOptions:
    """What ``metafovea import`` sets (its flags, same names); see :func:`import_recording`."""

    format: str = "auto"
    frames_key: str | None = None
    frame_axis: str = "first"
    times: str | None = None
    time_unit: str | None = None
    frame_rate_hz: float | None = None
    polarizer_key: str | None = None
    polarizer_unit: str | None = None  # default: 'alpha' if the key's name has 'alpha', 'deg' if 'deg', else 'rad'
    calibration: str | None = None  # 'two-point:T1=FILE1,T2=FILE2'
    calibration_gain: str = "per-pixel"
    planck: str | None = None  # 'R,B,F,O'
    band_um: tuple[float, float] = BAND_UM
    filter_um: tuple[float, float] | None = None
    foveal_gain: float | None = None
    scale: float | None = None
    #: the polariser (:class:`~metafovea.measurement.PolarizerSpec` keywords: rate_hz, mode, phase_deg, extinction,
    #: tau_s): written as the recording schema's keys, before what the recorded angles give
    polarizer: dict[str, Any] | None = None
    #: the camera's ADC bits: samples at its full scale, 2^bits - 1, are saturated (default: the full scale of the
    #: file's integer type, e.g. 65535 for 16-bit counts, which a 14-bit camera never reaches)
    adc_bits: int | None = None

    @property
    def full_scale(self) -> float | None:
        """The camera's full scale in counts, ``2^adc_bits - 1`` (None: the file's integer type's)."""
        return None if self.adc_bits is None else float(2 ** self.adc_bits - 1)

    def __post_init__(self) -> None:
        """The options checked when made, whether or not the file has a calibration or times to apply them to."""
        if self.adc_bits is not None:
            object.__setattr__(self, "adc_bits", check_int("adc_bits", self.adc_bits, 1, 32))
        for name in ("frame_rate_hz", "foveal_gain", "scale"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, as_float(name, v))
        gain_mode = check_choice("calibration_gain", self.calibration_gain, GAIN_MODES)
        object.__setattr__(self, "calibration_gain", gain_mode)
        check_choice("format", self.format, FORMATS)
        check_choice("frame_axis", self.frame_axis, FRAME_AXES)
        if self.time_unit is not None:
            check_choice("time_unit", self.time_unit, tuple(TIME_UNITS))


def _polarizer(rec: Recording, kept: np.ndarray, times: np.ndarray, unit: str | None) -> tuple[dict[str, Any],
                                                                                              dict[str, Any]]:
    """``(Measurement keywords/extras, meta)`` of the recorded polariser state."""
    if rec.polarizer is None:
        return {}, {}
    key = (rec.polarizer_key or "").lower()
    unit = check_choice("polarizer_unit", unit or ("alpha" if "alpha" in key else "deg" if "deg" in key else "rad"),
                        POLARIZER_UNITS)
    v = rec.polarizer[kept]
    if not np.all(np.isfinite(v)):
        raise InputError("polarizer_key", rec.polarizer_key, "finite polariser values (NaN/inf found)")
    if unit == "alpha":
        if v.min() < -1e-9 or v.max() > 1 + 1e-9:
            raise InputError("polarizer_key", rec.polarizer_key, "mixing ratios alpha in [0, 1] (or set "
                             "polarizer_unit=rad|deg for angles)", detail=f"range {v.min():.4g} to {v.max():.4g}")
        return {"alpha": np.clip(v, 0.0, 1.0)}, {"polarizer_record": {"recorded": "alpha", "key": rec.polarizer_key}}
    theta = np.deg2rad(v) if unit == "deg" else v
    meta: dict[str, Any] = {"recorded": f"angle ({unit})", "key": rec.polarizer_key}
    un = np.unwrap(2 * theta) / 2  # alpha has period pi in theta
    if times.size >= 3 and np.ptp(times) > 0:
        slope, phase = np.polyfit(times, un, 1)
        resid = float(np.max(np.abs(un - (slope * times + phase))))
        meta.update(rate_fit_residual_rad=resid)
        if resid < 0.05 and abs(slope) > 0:
            # a uniform rotation: the model reconstruct --method alternating uses (alpha = cos^2(2 pi f t + phase))
            return {"theta_rad": theta}, {"polarizer_record": meta, "polarizer_mode": "sync",
                                          "polarizer_hz": float(slope / (2 * math.pi)),
                                          "polarizer_phase_deg": math.degrees(float(phase))}
    return {"theta_rad": theta}, {"polarizer_record": meta}


def _calibration_frames(path: str, opt: ImportOptions, shape: tuple[int, int]) -> np.ndarray:
    """The mean frame (H, W) of one blackbody file, read as the recording was."""
    p = Path(path)
    if not p.is_file():
        raise InputError("calibration", path, "an existing file of blackbody frames")
    try:
        r = read_recording(p, frames_key=opt.frames_key, frame_axis=opt.frame_axis)
    except InputError as e:
        raise InputError("calibration", path, f"a readable blackbody file ({e})") from None
    if r.frames.shape[1:] != shape:
        raise InputError("calibration", path, f"blackbody frames of the recording's size {shape}",
                         detail=f"they are {r.frames.shape[1:]}")
    return np.nanmean(_saturated_as_nan(r.frames, path, opt.full_scale)[0], axis=0)


def _saturated_as_nan(frames: np.ndarray, source: str | None = None,
                      full_scale: float | None = None) -> tuple[np.ndarray, int]:
    """float32 frames with the full-scale samples as NaN (``full_scale``, else an integer dtype's largest value),
    and their count. Frames that float32 cannot hold to 1/1000 of their range (counts on a large offset, e.g. int64
    near 2^40) are an error naming ``source``: cast, they would be silently flattened."""
    f = np.asarray(frames)
    if f.dtype.itemsize > 2 and f.size:
        with np.errstate(invalid="ignore", over="ignore"):
            fin = f[np.isfinite(f)] if f.dtype.kind == "f" else f.reshape(-1)
            if fin.size:
                lo, hi = float(fin.min()), float(fin.max())
                ulp = float(np.spacing(np.float32(max(abs(lo), abs(hi)))))
                if ulp > 1e-3 * (hi - lo) and hi > lo:
                    raise InputError("frames", f"{f.dtype} values {lo:.15g} to {hi:.15g}", "values that float32 "
                                     "holds to 1/1000 of their range (subtract the offset before importing: here "
                                     f"float32 steps by {ulp:.3g})", source=source)
    out = f.astype(np.float32)
    if full_scale is not None or f.dtype.kind in "iu":
        with np.errstate(invalid="ignore"):
            sat = f >= (np.iinfo(f.dtype).max if full_scale is None else full_scale)
        n = int(sat.sum())
        if n:
            out[sat] = np.nan
        return out, n
    return out, 0


def _radiometry(frames: np.ndarray, rec: Recording, opt: ImportOptions) -> tuple[np.ndarray, Radiometric | None,
                                                                                 np.ndarray | None]:
    """``(frames, model or None, bad pixels or None)`` after the calibration the options and the file give."""
    band = check_band(opt.band_um, "band_um")
    filt = check_filter(opt.filter_um, "filter_um")
    if filt is not None:  # a filter outside the band passes nothing: refused with or without a calibration
        spectral_support_um(band, filter_um=filt)
    if opt.calibration is not None:
        (t1, f1), (t2, f2) = parse_two_point(opt.calibration)
        mode = opt.calibration_gain  # checked by ImportOptions
        cold, hot = (_calibration_frames(f, opt, frames.shape[1:]) for f in (f1, f2))
        model, g, o, bad = two_point(cold, t1, hot, t2, mode=mode, band_um=band, filter_um=filt, spec=opt.calibration)
        if g is not None:
            frames = correct_frames(frames, model, g, o, bad)
        return frames, model, bad if bad.any() else None
    if opt.planck is not None:
        pc, src = PlanckConstants.parse(opt.planck), "given"
    elif rec.planck is not None:
        try:
            pc, src = PlanckConstants(**rec.planck), f"{Path(rec.source).name} (Planck constants)"
        except InputError as e:
            raise InputError(e.parameter, e.value, e.allowed, source=rec.source) from None
    else:
        return frames, None, None
    try:  # a FLIR file's emissivity, reflected temperature, air and window, with whichever constants are used
        scene = SceneParameters(**rec.scene) if rec.scene else None
    except InputError as e:
        raise InputError(e.parameter, e.value, e.allowed, source=rec.source) from None
    if scene is not None:
        src = f"{src}; object parameters from {Path(rec.source).name}" if src == "given" else src
    return frames, from_planck(pc, frames, band_um=band, filter_um=filt, source=src, scene=scene), None


def to_measurement(rec: Recording, options: ImportOptions | None = None) -> tuple[Measurement, dict[str, Any]]:
    """``(Measurement, summary)`` of a read recording (module docstring); the summary lists what was found
    (``warnings``: dropped/duplicated frames, non-uniform timing, saturated samples, a poor Planck fit)."""
    opt = options or ImportOptions()
    times, t_from = frame_times(rec.times_s, rec.frames.shape[0], opt.frame_rate_hz, rec.times_from)
    kept, timing = check_timing(rec.frames, times, times_from=t_from,
                                frame_rate_hz=opt.frame_rate_hz if rec.times_s is not None else None)
    full = opt.full_scale
    frames, n_sat = _saturated_as_nan(rec.frames[kept], str(rec.source), full)
    if min(frames.shape[1:]) < 2:  # what reconstruct needs: refused here, not after the file is written
        raise InputError("recording", str(rec.source), "frames of at least 2 x 2 pixels",
                         detail=f"its frames are {frames.shape[1]} x {frames.shape[2]}")
    times = times[kept]
    pol_kw, pol_meta = _polarizer(rec, kept, times, opt.polarizer_unit)
    frames, model, bad = _radiometry(frames, rec, opt)
    r = 1.0 if opt.foveal_gain is None else float(opt.foveal_gain)
    if not (math.isfinite(r) and r > 0):
        raise InputError("foveal_gain", opt.foveal_gain, "a positive flat-field ratio of the channels")
    if opt.scale is not None:  # the range the reconstruction reads back (one home: FovealConstraint), checked here
        FovealConstraint.from_meta({}, scale=float(opt.scale))
    meta: dict[str, Any] = {
        "units": "DN" if model is not None else "counts",
        "units_note": ("camera counts, linear in radiance: DN = dark_dn + G_i L(T) (see calibration)" if model
                       else "camera counts as recorded (no radiometric calibration: no kelvin)"),
        "source": {"file": str(rec.source), "format": rec.format, "frames_key": rec.frames_key,
                   "dtype": str(rec.frames.dtype), "attrs": rec.attrs},
        "timing": timing.meta(),
        "saturated_samples": n_sat,
        **pol_meta,
    }
    if timing.frame_rate_hz:
        meta["frame_rate_hz"] = timing.frame_rate_hz
    spec = None
    if opt.polarizer:  # the user's values first, then what the recorded angles gave
        spec = PolarizerSpec.from_meta(meta, **opt.polarizer)
        meta.update(spec.as_meta())
    elif "polarizer_mode" in meta:
        spec = PolarizerSpec.from_meta(meta)
    if model is not None:
        meta.update(model.meta(r))
    if opt.foveal_gain is not None or opt.scale is not None:
        fc = {"gain": r, "offset_dn": (1.0 - r) * (model.dark_dn if model else 0.0)}
        if opt.scale is not None:
            fc["scale"] = float(opt.scale)
            meta["scale"] = float(opt.scale)
        meta["foveal_constraint"] = fc
    extras = {k: v for k, v in pol_kw.items() if k != "alpha"}
    if bad is not None:
        extras["bad_pixels"] = bad
    m = Measurement(frames=frames, times_s=times, alpha=pol_kw.get("alpha"), meta=meta, extras=extras)
    warn = timing.warnings()
    if n_sat:
        warn.append(f"{n_sat} sample(s) at the " + (f"{rec.frames.dtype} full scale" if full is None else
                    f"{opt.adc_bits}-bit full scale ({full:.0f})") + ": left out (NaN) as saturated")
    if model is not None and model.info.get("fit_max_error_k", 0) > 0.25:
        warn.append(f"the Planck curve departs from the {model.band_um[0]:g}-{model.band_um[1]:g} um band model by "
                    f"up to {model.info['fit_max_error_k']:.2g} K: set band_um=... to the camera's band")
    summary = {"frames_in": timing.frames_in, "frames": m.shape[0], "shape": list(m.shape[1:]),
               "times_from": t_from, "frame_rate_hz": timing.frame_rate_hz, "n_dropped": timing.n_dropped,
               "duplicates_removed": len(timing.duplicates_removed), "uniform_timing": timing.uniform,
               "alpha_known": m.alpha_known, "theta_rad": "theta_rad" in extras, "units": meta["units"],
               "polarizer": None if spec is None else spec.summary(),
               "calibration": None if model is None else {"method": model.method, "dark_dn": model.dark_dn,
                                                          **{k: v for k, v in model.info.items()
                                                             if k in ("fit_max_error_k", "bad_pixels")}},
               "warnings": warn}
    return m, summary


def import_recording(path: str | Path, out: str | Path | None = None, options: ImportOptions | None = None, *,
                     force: bool = False, preview: bool = True) -> tuple[Path, dict[str, Any]]:
    """Read ``path``, convert it (:func:`to_measurement`) and write the Measurement ``.npz`` to ``out`` (default:
    the recording's name with ``.npz``) and, with ``preview``, ``<out>_preview.png`` (frames in the iron palette with
    colour bars in the file's units, the frames' mean and spread per pixel, alpha and the frame mean over time:
    :func:`metafovea.imaging.simulate.write_preview`); ``(path written, summary)``, the summary's ``preview`` the
    PNG. Nothing is written on any error, nothing overwritten without ``force``."""
    from metafovea.io import prepare_output

    opt = options or ImportOptions()
    src = existing_recording(path)  # before the default output's name is made from it ('.' has none)
    dest = Path(out) if out is not None else src.with_suffix(".npz")
    if dest.suffix.lower() != ".npz":
        raise InputError("out", str(dest), "a file name ending in .npz")
    if src.exists() and dest.exists() and dest.resolve() == src.resolve():
        raise InputError("out", str(dest), "a path other than the recording itself")
    png = dest.with_name(dest.stem + "_preview.png") if preview else None
    prepare_output(dest, force)  # refuse an existing file before reading anything
    if png is not None:
        prepare_output(png, force, name="out (preview)")
    rec = read_recording(src, format=opt.format, frames_key=opt.frames_key, times=opt.times,
                         time_unit=opt.time_unit, frame_axis=opt.frame_axis, polarizer_key=opt.polarizer_key)
    m, summary = to_measurement(rec, opt)
    written = m.save(dest, force=force)
    summary["out"] = str(written)
    if png is not None:
        from metafovea.imaging.simulate import write_preview

        summary["preview"] = str(write_preview(m, png, force=force))
    return written, summary

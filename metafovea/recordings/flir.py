"""FLIR's radiometric files as a :class:`FlirFile` (what :func:`metafovea.recordings.read.read_recording` makes its
:class:`~metafovea.recordings.read.Recording` of): a thin wrapper over the packages that parse them
(``pip install "metafovea[flir]"``).

* **Radiometric JPEG** (``.jpg``, ``.jpeg``; one still): flyr (EUPL-1.2) finds the APP1 "FLIR" segments, the FFF
  record directory, the ``RawData`` record (raw 16-bit or PNG) and the ``CameraInfo`` record. flyr's public
  ``unpack`` hands out temperatures only, so its record parsers (``flyr.records``, ``flyr.thermal``, what
  ``unpack`` itself calls) give the counts and the constants.
* **FFF** (``.fff``, one frame) and **SEQ** (``.seq``, FFF frames one after the other): flirpy (MIT) walks the
  frames (``flirpy.io.seq.Seq``) and their records (``flirpy.io.fff.Fff``): the counts, the Planck constants and
  the object parameters. Three fields flirpy does not hand out as stored are read from the ``CameraInfo`` record
  it located, at ExifTool's offsets (FLIR tag table): the reflected, air and window temperatures in kelvin
  (0x28, 0x2c, 0x30; flirpy converts them to Celsius with 273.14) and the frame time's milliseconds (0x388).
  Frames whose raw data is not plain 16-bit (a PNG or JPEG-family stream) are refused.

What a :class:`FlirFile` holds: the frames as the camera's counts (uint16, never converted: the separation mixes
radiances), FLIR's ``R1, R2, B, F, O`` as ``planck`` and the emissivity, reflected apparent temperature, air
temperature, object distance, humidity (a percentage above 2 is divided by 100, as ExifTool does) and IR window
as ``scene`` (:class:`~metafovea.recordings.calibration.SceneParameters`, the one home of the conversion to
kelvin), the camera's other fields as ``attrs``. Times: a still is one frame at t = 0; a sequence's frames carry
their ``DateTimeOriginal`` stamps (1 ms resolution), put on the camera's frame-rate grid when every stamp is
within 1.5 ms of it (so a 30 Hz recording's 33/34 ms steps are not taken for jitter, while a dropped frame still
shows as a gap), else kept as stamped; a sequence without increasing stamps is timed by its frame rate.
"""

from __future__ import annotations

import importlib
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.errors import InputError

#: the suffixes this module reads and the package that parses each
READERS = {".jpg": "flyr", ".jpeg": "flyr", ".fff": "flirpy", ".seq": "flirpy"}
#: ``pip install`` advice for a missing reader
INSTALL = 'pip install "metafovea[flir]"'
#: ExifTool's CameraInfo offsets (FLIR tag table) of the fields read from the record itself
_KELVIN_AT = {"reflected_k": 0x28, "atmosphere_k": 0x2C, "window_k": 0x30}
_STAMP_AT = 0x384
#: how far (s) a 1 ms frame stamp may be from the frame-rate grid and still be put on it
STAMP_SNAP_S = 1.5e-3
#: what a raw-data record may start with that is not plain 16-bit counts (at the record's offset + 0x20)
_COMPRESSED = {b"\x89PNG": "PNG", b"\xff\xd8": "JPEG-family"}


@dataclass
class FlirFile:
    """One FLIR file: ``frames`` (T, H, W) uint16 counts, ``planck`` ``{R1, R2, B, F, O}``, ``scene`` (the fields
    of :class:`~metafovea.recordings.calibration.SceneParameters`), ``times_s`` (T,) or None and where they came
    from, ``attrs`` (the camera's other fields, the reader and its version)."""

    frames: np.ndarray
    planck: dict[str, float]
    scene: dict[str, float]
    times_s: np.ndarray | None
    times_from: str | None
    attrs: dict[str, Any] = field(default_factory=dict)


def _missing(path: Path, package: str, err: ImportError) -> InputError:
    return InputError("recording", str(path), f"a FLIR file with its reader installed: {INSTALL} ({package} reads "
                      f"{path.suffix} files)", detail=str(err))


def _unreadable(path: Path, package: str, err: Exception) -> InputError:
    return InputError("recording", str(path), f"a FLIR radiometric file that {package} can read, else a TIFF or "
                      "MAT export of the camera software", detail=f"{type(err).__name__}: {str(err)[:160]}")


def _version(package: str) -> str:
    try:
        return f"{package} {version(package)}"
    except PackageNotFoundError:  # pragma: no cover - imported, so installed
        return package


def _humidity(v: float) -> float:
    return float(v) / 100.0 if v > 2 else float(v)


def read_flir(path: str | Path) -> FlirFile:
    """Read a FLIR radiometric JPEG, FFF or SEQ file (module docstring).

    Parameters
    ----------
    path : str or Path
        ``.jpg``/``.jpeg`` (flyr), ``.fff`` or ``.seq`` (flirpy).

    Returns
    -------
    FlirFile
        ``frames`` (T, H, W) uint16 counts, ``planck`` ``{R1, R2, B, F, O}``, ``scene`` (the object parameters),
        ``times_s`` (T,), ``attrs`` (camera fields, the reader and its version).

    Notes
    -----
    A missing reader is an :class:`~metafovea.errors.InputError` naming the file and ``pip install
    "metafovea[flir]"``; a file the reader cannot parse is one naming the file and the camera software's export.
    """
    p = Path(path)
    package = READERS.get(p.suffix.lower())
    if package is None:
        raise InputError("recording", str(p), f"a FLIR file ({', '.join(READERS)})")
    return _read_jpeg(p) if package == "flyr" else _read_fff(p)


def _read_jpeg(path: Path) -> FlirFile:
    try:
        from flyr.records import RecordIndex, extract_flir_app1, parse_flir_records
        from flyr.thermal import parse_camera_info, parse_raw_data
    except ImportError as e:
        raise _missing(path, "flyr", e) from None
    try:
        with open(path, "rb") as fh:
            app1 = extract_flir_app1(fh)
            records = parse_flir_records(app1)
            raw_rec = records[RecordIndex.RAW_DATA.value]
            _, _, raw = parse_raw_data(app1, raw_rec)
            info = parse_camera_info(app1, records[RecordIndex.CAMERA_INFO.value])
    except (ValueError, KeyError, IndexError, OverflowError, OSError, struct.error) as e:
        raise _unreadable(path, "flyr", e) from None
    raw = np.asarray(raw)
    if raw.ndim != 2 or raw.dtype.kind not in "iu" or raw.min() < 0 or raw.max() > 65535:
        raise _unreadable(path, "flyr", ValueError(f"the raw thermal image is not 16-bit counts ({raw.dtype}, "
                                                   f"shape {raw.shape})"))
    planck = {"R1": info["planck_r1"], "R2": info["planck_r2"], "B": info["planck_b"], "F": info["planck_f"],
              "O": float(info["planck_o"])}
    scene = {"emissivity": info["emissivity"], "reflected_k": info["reflected_apparent_temperature"],
             "atmosphere_k": info["atmospheric_temperature"], "distance_m": info["object_distance"],
             "humidity": _humidity(info["relative_humidity"]), "window_k": info["ir_window_temperature"],
             "window_transmission": info["ir_window_transmission"],
             "alpha1": info["atmospheric_trans_alpha1"], "alpha2": info["atmospheric_trans_alpha2"],
             "beta1": info["atmospheric_trans_beta1"], "beta2": info["atmospheric_trans_beta2"],
             "x": info["atmospheric_trans_x"]}
    attrs = {f"flir.{k}": v for k, v in info.items() if isinstance(v, (int, float))}
    attrs["reader"] = _version("flyr")
    return FlirFile(frames=raw.astype(np.uint16)[None], planck={k: float(v) for k, v in planck.items()},
                    scene={k: float(v) for k, v in scene.items()}, times_s=np.zeros(1),
                    times_from="one still (t = 0)", attrs=attrs)


def _frames_of(path: Path) -> Iterator[Any]:
    """flirpy's frames (``Fff`` objects) of an FFF or SEQ file, one at a time (each holds a copy of its bytes)."""
    from flirpy.io.fff import Fff
    from flirpy.io.seq import Seq

    if path.suffix.lower() == ".fff":
        yield Fff(str(path))
        return
    seq = Seq(str(path))
    for i in range(len(seq)):
        yield seq[i]


def _record(fff: Any, record_type: int) -> Any:
    for r in fff.records:
        if r.record_type == record_type:
            return r
    raise ValueError(f"no record of type 0x{record_type:02x}")


def _image(fff: Any) -> np.ndarray:
    """One frame's counts: flirpy's image, after checking that the raw data is plain 16-bit; byte-swapped when
    the record's byte-order flag (its first int16u, 0x0002 in the record's order) says big-endian, the flag flirpy
    reads the image size by but not the image."""
    rec = _record(fff, 0x01)
    head = bytes(fff.data[rec.record_offset: rec.record_offset + 0x24])
    for magic, kind in _COMPRESSED.items():
        if head[0x20:].startswith(magic):
            raise ValueError(f"its raw frames are {kind} compressed, which flirpy does not decode")
    img = np.asarray(fff.get_image())
    return img if int.from_bytes(head[:2], "little") == 2 else img.byteswap()


def _camera_fields(fff: Any) -> tuple[dict[str, float], dict[str, float], float]:
    """``(planck, scene, time stamp s)`` of one flirpy frame."""
    m = fff.meta
    rec = _record(fff, 0x20)
    data = bytes(fff.data[rec.record_offset: rec.record_offset + rec.record_length])
    order = "<" if int.from_bytes(data[:2], "little") == 2 else ">"
    kelvin = {k: struct.unpack_from(order + "f", data, at)[0] for k, at in _KELVIN_AT.items()}
    secs, ms = struct.unpack_from(order + "II", data, _STAMP_AT)
    planck = {"R1": m["Planck R1"], "R2": m["Planck R2"], "B": m["Planck B"], "F": m["Planck F"], "O": m["Planck O"]}
    scene = {"emissivity": m["Emissivity"], "distance_m": m["Object Distance"],
             "humidity": _humidity(m["Relative Humidity"]), "window_transmission": m["IR Window Transmission"],
             "alpha1": m["Atmospheric Trans Alpha 1"], "alpha2": m["Atmospheric Trans Alpha 2"],
             "beta1": m["Atmospheric Trans Beta 1"], "beta2": m["Atmospheric Trans Beta 2"],
             "x": m["Atmospheric Trans X"], **kelvin}
    return ({k: float(v) for k, v in planck.items()}, {k: float(v) for k, v in scene.items()},
            float(secs) + float(ms & 0xFFFF) / 1e3)


def stamp_times(stamps_s: np.ndarray, frame_rate_hz: float | None) -> tuple[np.ndarray | None, str | None]:
    """Frame times (s, from 0) of a sequence's 1 ms stamps: on the frame-rate grid when every stamp is within
    :data:`STAMP_SNAP_S` of it, else as stamped; times from the rate when the stamps do not increase; None when
    neither serves (module docstring)."""
    t = np.asarray(stamps_s, dtype=np.float64) - float(stamps_s[0])
    rate = frame_rate_hz if frame_rate_hz and frame_rate_hz > 0 else None
    if t.size > 1 and not np.all(np.diff(t) > 0):
        if rate is None:
            return None, None
        return np.arange(t.size) / rate, f"the file's frame rate {rate:g} Hz (its frame stamps do not increase)"
    if rate is not None:
        k = np.round(t * rate)
        if np.all(np.abs(t - k / rate) <= STAMP_SNAP_S) and np.all(np.diff(k) > 0):
            return k / rate, f"the frames' 1 ms stamps on the file's {rate:g} Hz grid"
    return t, "the frames' stamps (1 ms resolution)"


def _read_fff(path: Path) -> FlirFile:
    try:  # the missing reader is reported before any work
        importlib.import_module("flirpy.io.seq")
    except ImportError as e:
        raise _missing(path, "flirpy", e) from None
    images, fields, meta = [], [], {}
    try:
        for f in _frames_of(path):
            images.append(_image(f))
            fields.append(_camera_fields(f))
            meta = meta or dict(f.meta)
        if not images:
            raise ValueError("no FFF frame found")
    except (ValueError, KeyError, IndexError, OverflowError, OSError, struct.error, AttributeError) as e:
        raise _unreadable(path, "flirpy", e) from None
    planck, scene, _ = fields[0]
    changed = [i for i, (pc, _, _) in enumerate(fields) if pc != planck]
    if changed:
        raise InputError("recording", str(path), "one set of Planck constants for the whole recording (split it "
                         "where the camera changed its range)",
                         detail=f"frame {changed[0]} has {fields[changed[0]][0]}")
    shapes = {im.shape for im in images}
    if len(shapes) != 1:
        raise _unreadable(path, "flirpy", ValueError(f"frames of different sizes {sorted(shapes)}"))
    rate = float(meta.get("FrameRate") or 0) or None
    times, times_from = stamp_times(np.array([f[2] for f in fields]), rate)
    attrs: dict[str, Any] = {}
    for k, v in meta.items():
        v = v.split(b"\0")[0].decode("latin-1").strip() if isinstance(v, bytes) else v
        if isinstance(v, (int, float, str)) and k not in ("Width", "Height"):
            attrs[f"flir.{k}"] = v
    attrs["reader"] = _version("flirpy")
    if rate:
        attrs["frame_rate_hz"] = rate
    return FlirFile(frames=np.stack(images).astype(np.uint16, copy=False), planck=planck, scene=scene, times_s=times,
                    times_from=times_from, attrs=attrs)

"""Readers of camera recordings: 16-bit TIFF stacks (tifffile), HDF5 (h5py), MATLAB files (scipy.io for v5,
h5py for v7.3, which is HDF5) and FLIR's radiometric files (:mod:`metafovea.recordings.flir`: JPEG through flyr,
FFF and SEQ through flirpy), into one :class:`Recording`: the frames as stored plus what the file says about
them (timestamps, polariser state, the camera's Planck constants and object parameters, its other scalar
metadata). Formats no maintained reader serves (:data:`UNSUPPORTED`: InfraTec's IRB, FLIR's CSQ) are refused
with the export to make instead.

Every file is a *store* of named arrays and scalar attributes:

* TIFF: the image stack is the frames; the names are the keys of tifffile's JSON description (``metadata=`` of
  ``tifffile.imwrite``) and of ImageJ's (``finterval``: the frame interval in s);
* HDF5: every dataset by its path (``group/name``); the attributes of the root and of the frames' dataset;
* MAT v5: every top-level numeric variable; v7.3: every dataset, transposed to MATLAB's axis order (MATLAB
  writes column-major, h5py reads the reversed shape).

A key not given is looked for under the usual names (:data:`FRAME_KEYS`, :data:`TIME_KEYS`); a key given and not
there is an :class:`~metafovea.errors.InputError` naming its flag and the keys the file has.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.errors import InputError, check_choice

#: ``--format`` choices
FORMATS = ("auto", "tiff", "hdf5", "mat", "flir")
#: file name suffix -> format for ``--format auto``
SUFFIXES = {".tif": "tiff", ".tiff": "tiff", ".h5": "hdf5", ".hdf5": "hdf5", ".hdf": "hdf5", ".he5": "hdf5",
            ".nc": "hdf5", ".mat": "mat", ".jpg": "flir", ".jpeg": "flir", ".fff": "flir", ".seq": "flir"}
#: camera formats that no maintained Python reader serves: suffix -> what it is and why it is not read
UNSUPPORTED = {
    ".irb": "InfraTec IRBIS files (.irb), which no maintained Python reader reads",
    ".csq": "FLIR CSQ files (.csq), which neither flyr nor flirpy reads",
}
#: what to do with an :data:`UNSUPPORTED` file
EXPORT_ADVICE = ("export the recording from the camera software (IRBIS, ResearchIR, Thermal Studio) as a 16-bit "
                 "TIFF stack or a MAT file of raw counts, with the Planck constants if it offers them "
                 "(README, 'Reconstructing a real recording')")
#: ``--time-unit`` choices and their length in seconds
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
#: ``--frame-axis`` choices: where the frame index is in a stored 3-D array
FRAME_AXES = ("first", "last")
#: names tried, in order, for the frames when ``--frames-key`` is not given (else the file's only 3-D array)
FRAME_KEYS = ("frames", "images", "data", "raw", "counts", "video")
#: names tried, in order, for the timestamps when ``--times`` is not given
TIME_KEYS = ("times_s", "timestamps_s", "timestamps", "timestamp", "times", "time", "t")
#: scalar metadata names of the frame rate (Hz) and the frame interval (s)
RATE_KEYS = ("frame_rate_hz", "frame_rate", "fps")
INTERVAL_KEYS = ("finterval", "frame_interval_s")
#: FLIR's names of the Planck constants (ExifTool, flyr), matched case-insensitively
PLANCK_NAMES = ("planckr1", "planckr2", "planckb", "planckf", "plancko")


@dataclass
class Recording:
    """What a reader found: ``frames`` (T, H, W) as stored (dtype kept: saturation is judged on it), ``times_s``
    (T,) or None, ``polarizer`` (T,) raw values of the polariser key or None, ``planck`` FLIR's constants
    ``{R1, R2, B, F, O}`` or None, ``scene`` a FLIR file's object parameters (the fields of
    :class:`~metafovea.recordings.calibration.SceneParameters`) or None, ``attrs`` the file's other scalar
    metadata (kept in the Measurement's meta)."""

    frames: np.ndarray
    source: str
    format: str
    frames_key: str | None = None
    times_s: np.ndarray | None = None
    times_from: str | None = None
    polarizer: np.ndarray | None = None
    polarizer_key: str | None = None
    planck: dict[str, float] | None = None
    attrs: dict[str, Any] = field(default_factory=dict)
    scene: dict[str, float] | None = None


@dataclass
class _Store:
    """Named arrays (read on demand) and scalar attributes of one file."""

    keys: list[str]
    get: Callable[[str], np.ndarray]
    attrs: dict[str, Any]
    frames: Callable[[], np.ndarray] | None = None  # TIFF: the image stack, which has no key
    ndims: dict[str, int] = field(default_factory=dict)  # each key's number of dimensions (without reading it)


def existing_recording(path: str | Path) -> Path:
    """``path`` as a Path when it is an existing file, else an InputError naming it (a folder, ``''``)."""
    if not Path(path).is_file():
        raise InputError("recording", str(path), "an existing recording file (.tif, .h5, .mat, FLIR .jpg/.seq/.fff)")
    return Path(path)


def detect_format(path: Path, fmt: str = "auto") -> str:
    """The reader for ``path``: ``fmt`` unless ``'auto'``, else from the suffix (:data:`SUFFIXES`)."""
    fmt = check_choice("format", fmt, FORMATS)
    if path.suffix.lower() in UNSUPPORTED:
        raise InputError("recording", str(path), f"a format metafovea reads; for {UNSUPPORTED[path.suffix.lower()]}, "
                         + EXPORT_ADVICE)
    if fmt != "auto":
        return fmt
    got = SUFFIXES.get(path.suffix.lower())
    if got is None:
        raise InputError("format", "auto", "tiff, hdf5, mat or flir (the suffix " + repr(path.suffix) + " of "
                         f"{path.name} is none of {', '.join(sorted(SUFFIXES))})")
    return got


def _scalar(v: Any) -> Any:
    """A JSON-able scalar or short string of a metadata value, or None."""
    if isinstance(v, bytes):
        v = v.decode("utf-8", "replace")
    if isinstance(v, str):
        return v if len(v) <= 200 else None
    a = np.asarray(v)
    if a.dtype.kind in "biuf" and a.size == 1:
        return a.reshape(-1)[0].item()
    return None


@contextlib.contextmanager
def _quiet_tifffile() -> Iterator[None]:
    """tifffile's own log warnings (``invalid offset`` and the like) kept off stderr: a file it cannot read is one
    line of ours (:func:`open_store`, :func:`read_recording`), not its log lines first."""
    log = logging.getLogger("tifffile")
    level = log.level
    log.setLevel(logging.CRITICAL + 1)  # its ERROR lines too: our one line follows
    try:
        yield
    finally:
        log.setLevel(level)


def _tiff_store(path: Path) -> _Store:
    import tifffile

    with _quiet_tifffile(), tifffile.TiffFile(path) as tif:
        attrs: dict[str, Any] = {}
        for md in (tif.imagej_metadata or {}, *(tif.shaped_metadata or ())):
            attrs.update({k: v for k, v in md.items() if k not in ("shape", "axes")})
        series_shape = tif.series[0].shape if tif.series else ()
    arrays = {k: np.asarray(v) for k, v in attrs.items() if isinstance(v, (list, tuple)) and len(v) > 1}
    scalars = {k: s for k, v in attrs.items() if (s := _scalar(v)) is not None}

    def frames() -> np.ndarray:
        with _quiet_tifffile():
            try:
                a = tifffile.imread(path)
            except (OSError, ValueError, KeyError, TypeError, IndexError) as e:
                raise InputError("recording", str(path), "a readable TIFF stack", detail=str(e)[:200]) from None
        if a.ndim not in (2, 3):
            raise InputError("recording", str(path), "a TIFF stack of (T, H, W) grey frames",
                             detail=f"its first series has shape {series_shape}")
        return a

    return _Store(sorted(arrays), lambda k: arrays[k], scalars, frames)


def _hdf5_store(path: Path, transpose: bool = False) -> _Store:
    import h5py

    ndims: dict[str, int] = {}
    attrs: dict[str, Any] = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: ndims.update({name: obj.ndim}) if isinstance(obj, h5py.Dataset) else None)
        attrs.update({k: s for k, v in f.attrs.items() if (s := _scalar(v)) is not None})

    def get(key: str) -> np.ndarray:
        with h5py.File(path, "r") as f:
            ds = f[key]
            attrs.update({f"{key}.{k}": s for k, v in ds.attrs.items() if (s := _scalar(v)) is not None})
            a = ds[()]
        a = np.asarray(a)
        return a.T if transpose else a

    return _Store(sorted(ndims), get, attrs, ndims=ndims)


def _mat_store(path: Path) -> _Store:
    with open(path, "rb") as fh:
        head = fh.read(128)
    if b"MATLAB 7.3" in head[:116] or head[:8] == b"\x89HDF\r\n\x1a\n":
        return _hdf5_store(path, transpose=True)
    import scipy.io

    try:
        d = scipy.io.loadmat(path, squeeze_me=False)
    except (ValueError, TypeError, NotImplementedError) as e:
        raise InputError("recording", str(path), "a readable MAT file (v5 or v7.3)", detail=str(e)[:200]) from None
    arrays = {k: np.asarray(v) for k, v in d.items() if not k.startswith("__") and np.asarray(v).dtype.kind in "biuf"}
    scalars = {k: s for k, v in arrays.items() if (s := _scalar(v)) is not None}
    return _Store(sorted(k for k, v in arrays.items() if v.size > 1), lambda k: arrays[k], scalars,
                  ndims={k: v.ndim for k, v in arrays.items()})


def open_store(path: Path, fmt: str) -> _Store:
    """The store of ``path`` in format ``fmt`` (resolved); unreadable files are an InputError naming the file."""
    readers = {"tiff": _tiff_store, "hdf5": _hdf5_store, "mat": _mat_store}
    try:
        return readers[fmt](path)
    except InputError:
        raise
    except ImportError as e:
        raise InputError("format", fmt, "a format whose reader is installed (HDF5 and MAT v7.3 need h5py: "
                         "pip install 'metafovea[recordings]')", detail=str(e)) from None
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise InputError("recording", str(path), f"a readable {fmt} file", detail=str(e)[:200]) from None


def _pick(store: _Store, key: str | None, names: tuple[str, ...], parameter: str, path: Path,
          want_ndim: int | None = None) -> str | None:
    """``key`` if the file has it (else an error naming ``parameter``), or the first of ``names`` it has, or (with
    ``want_ndim``) its only array of that many dimensions; None when nothing fits."""
    if key is not None:
        if key in store.keys:
            return key
        have = ", ".join(store.keys[:12]) + (" ..." if len(store.keys) > 12 else "") or "none"
        raise InputError(parameter, key, f"a key of {path.name} (its arrays: {have})")
    lower = {k.lower().split("/")[-1]: k for k in store.keys}
    for n in names:
        if n in lower:
            return lower[n]
    return None


def _frames(store: _Store, key: str | None, path: Path, axis: str) -> tuple[np.ndarray, str | None]:
    if store.frames is not None and key is None:  # a TIFF's image stack: (T, H, W) as stored, or (H, W, T)
        a, k = store.frames(), None
        a = a if a.ndim == 3 else a[None] if axis == "first" else a[..., None]
        if a.dtype.kind not in "iuf":
            raise InputError("recording", str(path), "a TIFF stack of real grey values (integer or float)",
                             detail=f"its pixels are {a.dtype}")
    else:
        k = _pick(store, key, FRAME_KEYS, "frames_key", path)
        if k is None:
            three = [n for n in store.keys if store.ndims.get(n) == 3]
            if len(three) != 1:
                raise InputError("frames_key", None, f"the name of the frames' array in {path.name} (it has "
                                 f"{len(three)} 3-D arrays: {', '.join(three) or 'none'})")
            k = three[0]
        a = np.asarray(store.get(k))
        if a.ndim == 2:
            a = a[None] if axis == "first" else a[..., None]
        if a.ndim != 3 or a.dtype.kind not in "iuf":
            raise InputError("frames_key", k, f"a 3-D array of real numbers (integer or float) in {path.name}",
                             detail=f"it has shape {a.shape}, dtype {a.dtype}")
    return (np.moveaxis(a, -1, 0) if axis == "last" else a), k


def _times(store: _Store, times: str | None, unit: str | None, n: int,
           path: Path) -> tuple[np.ndarray | None, str | None]:
    """Timestamps in seconds: ``times`` a key of the file or a file of its own (.npy, or text with one time per
    line, first column), else a key of :data:`TIME_KEYS`, else the file's frame interval or rate; None if none."""
    if times is not None and times not in store.keys and Path(times).suffix.lower() in (".npy", ".txt", ".csv"):
        p = Path(times)
        if not p.is_file():
            raise InputError("times", times, "a key of the recording or an existing .npy/.txt/.csv file of times")
        try:
            t = np.load(p) if p.suffix.lower() == ".npy" else np.loadtxt(p, delimiter="," if p.suffix.lower() == ".csv"
                                                                         else None, ndmin=2)[:, 0]
        except (OSError, ValueError) as e:
            raise InputError("times", times, "a readable file of one time per frame", detail=str(e)[:200]) from None
        src = f"file {p.name}"
    else:
        k = _pick(store, times, TIME_KEYS, "times", path)
        if k is None:
            return _times_from_rate(store.attrs, n)
        t, src = store.get(k), f"key {k}"
        unit = unit or _unit_attr(store.attrs, k, str(path))
    t = np.asarray(t, dtype=np.float64).reshape(-1) * TIME_UNITS[check_choice("time_unit", unit or "s",
                                                                              tuple(TIME_UNITS))]
    if t.size != n or not np.all(np.isfinite(t)):
        raise InputError("times", times or src, f"{n} finite timestamps, one per frame",
                         detail=f"{src} has {t.size}{'' if np.all(np.isfinite(t)) else ' with NaN/inf'}")
    return t - t[0], src


#: spellings of :data:`TIME_UNITS` met in files' ``units`` attributes
UNIT_ALIASES = {"sec": "s", "secs": "s", "second": "s", "seconds": "s", "msec": "ms", "millisecond": "ms",
                "milliseconds": "ms", "\u00b5s": "us", "\u03bcs": "us", "usec": "us", "microsecond": "us",
                "microseconds": "us", "nsec": "ns", "nanosecond": "ns", "nanoseconds": "ns"}


def _unit_attr(attrs: dict[str, Any], key: str, source: str | None = None) -> str | None:
    """The ``units`` attribute of an HDF5 dataset as a key of :data:`TIME_UNITS` (None where it has none); a unit
    that is not a time is an error naming the attribute (read as seconds it would be silently wrong)."""
    for a in ("units", "unit"):
        v = attrs.get(f"{key}.{a}")
        if isinstance(v, str) and v.strip():
            u = v.strip().lower()
            u = UNIT_ALIASES.get(u, u)
            if u not in TIME_UNITS:
                raise InputError(f"{key}.{a}", v, f"a time unit ({', '.join(TIME_UNITS)}); --time-unit states it "
                                 "instead", source=source)
            return u
    return None


def _times_from_rate(attrs: dict[str, Any], n: int) -> tuple[np.ndarray | None, str | None]:
    low = {k.lower(): v for k, v in attrs.items()}
    for k in INTERVAL_KEYS:
        if isinstance(low.get(k), (int, float)) and low[k] > 0:
            return np.arange(n) * float(low[k]), f"file's {k}"
    for k in RATE_KEYS:
        if isinstance(low.get(k), (int, float)) and low[k] > 0:
            return np.arange(n) / float(low[k]), f"file's {k}"
    return None, None


def _planck(attrs: dict[str, Any]) -> dict[str, float] | None:
    """FLIR's Planck constants among the file's scalars (any key whose last part is PlanckR1 ... PlanckO)."""
    got = {}
    for k, v in attrs.items():
        name = k.split(".")[-1].split("/")[-1].lower()
        if name in PLANCK_NAMES and isinstance(v, (int, float)):
            got[name[6:].upper()] = float(v)
    if "R1" not in got or "B" not in got:
        return None
    return {"R1": got["R1"], "R2": got.get("R2", 1.0), "B": got["B"], "F": got.get("F", 1.0), "O": got.get("O", 0.0)}


def read_recording(path: str | Path, *, format: str = "auto", frames_key: str | None = None,
                   times: str | None = None, time_unit: str | None = None, frame_axis: str = "first",
                   polarizer_key: str | None = None) -> Recording:
    """Read a recording (see the module docstring).

    Parameters
    ----------
    path : str or Path
        The recording file.
    format : {'auto', 'tiff', 'hdf5', 'mat', 'flir'}
        Reader; ``'auto'`` from the suffix (``.jpg``/``.jpeg``/``.fff``/``.seq``: FLIR's radiometric files).
    frames_key, times, polarizer_key : str, optional
        Keys of the frames (default: :data:`FRAME_KEYS`, else the only 3-D array), the timestamps (or a file of
        them; default :data:`TIME_KEYS`, else the file's frame interval or rate) and the polariser state.
    time_unit : {'s', 'ms', 'us', 'ns'}, optional
        Of the timestamps (default: the dataset's ``units`` attribute, else s).
    frame_axis : {'first', 'last'}
        Where the frame index is in the stored array (MATLAB videos are usually H x W x T: ``'last'``).
    """
    p = existing_recording(path)
    fmt = detect_format(p, format)
    axis = check_choice("frame_axis", frame_axis, FRAME_AXES)
    if fmt == "flir":
        return _flir_recording(p, frames_key, times, time_unit, polarizer_key)
    store = open_store(p, fmt)
    frames, fkey = _frames(store, frames_key, p, axis)
    t, t_src = _times(store, times, time_unit, frames.shape[0], p)
    pol = None
    if polarizer_key is not None:
        k = _pick(store, polarizer_key, (), "polarizer_key", p)
        pol = np.asarray(store.get(k), dtype=np.float64).reshape(-1)
        if pol.size != frames.shape[0]:
            raise InputError("polarizer_key", polarizer_key, f"one polariser value per frame ({frames.shape[0]})",
                             detail=f"it has {pol.size}")
    return Recording(frames=frames, source=str(p), format=fmt, frames_key=fkey, times_s=t, times_from=t_src,
                     polarizer=pol, polarizer_key=polarizer_key, planck=_planck(store.attrs), attrs=dict(store.attrs))


def _flir_recording(path: Path, frames_key: str | None, times: str | None, time_unit: str | None,
                    polarizer_key: str | None) -> Recording:
    """A FLIR file through :func:`metafovea.recordings.flir.read_flir`; ``times`` may name a file of times (the
    FLIR file has no keys: a frames or polariser key is an error naming it)."""
    from metafovea.recordings.flir import read_flir

    for name, key in (("frames_key", frames_key), ("polarizer_key", polarizer_key)):
        if key is not None:
            raise InputError(name, key, f"nothing for a FLIR file ({path.name} holds one image per frame and no "
                             "named arrays; a polariser state has to come from the polariser flags)")
    f = read_flir(path)
    t, t_from = f.times_s, f.times_from
    if times is not None:
        t, t_from = _times(_Store([], lambda k: np.empty(0), {}), times, time_unit, f.frames.shape[0], path)
    return Recording(frames=f.frames, source=str(path), format="flir", times_s=t, times_from=t_from,
                     planck=f.planck, scene=f.scene, attrs=f.attrs)

"""The reconstruction stage's result types: :class:`Reconstruction` (the images, alpha and what the solver found;
saved as an uncompressed ``.npz`` with JSON metadata, :func:`save_npz_stored`) and :class:`PipelineResult` (a
Reconstruction of a Measurement with the frames each output covers and its scores)."""

from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from metafovea.errors import InputError
from metafovea.io import SCHEMA_VERSION, atomic_open, jsonable, load_npz, to_json

if TYPE_CHECKING:
    from collections.abc import Sequence

    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from metafovea.measurement import FovealConstraint

KIND = "metafovea.Reconstruction"


def save_npz_stored(path: str | os.PathLike, meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
    """Write arrays and metadata to an uncompressed ``.npz`` atomically, in one pass.

    Parameters
    ----------
    path : str or PathLike
    meta : dict
        JSON metadata, stored under ``__meta__`` as :func:`metafovea.io.atomic_save_npz` does.
    arrays : dict of str to ndarray
        Numeric arrays (no pickled objects).

    Notes
    -----
    Each contiguous array goes to its zip member as one memoryview (one CRC pass, one write), where ``np.savez``
    copies it in 16 MiB ``nditer`` chunks through ``tobytes``. Readable by ``np.load`` and
    :func:`metafovea.io.load_npz`.
    """
    # 89 windows of 290 x 290 (60 MB) on the 2-core VM: np.savez 80-130 ms, this ~50 ms, both without the fsync
    m = {**meta}
    m.setdefault("schema_version", SCHEMA_VERSION)
    payload = {**arrays, "__meta__": np.frombuffer(to_json(m, indent=None).encode(), dtype=np.uint8)}
    with atomic_open(path, "wb") as fh, zipfile.ZipFile(fh, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
        for name, arr in payload.items():
            a = np.asarray(arr)
            if a.dtype.hasobject:
                raise InputError(name, f"array of dtype {a.dtype}", "a numeric array (no pickled objects)")
            a = np.ascontiguousarray(a) if not (a.flags.c_contiguous or a.flags.f_contiguous) else a
            header = np.lib.format.header_data_from_array_1_0(a)  # fortran_order for an F-contiguous array
            with zf.open(f"{name}.npy", "w", force_zip64=True) as member:
                try:
                    np.lib.format.write_array_header_1_0(member, header)
                except ValueError:  # a header over 64 KiB (very many dimensions): format 2.0, as np.save
                    np.lib.format.write_array_header_2_0(member, header)
                if a.size:
                    member.write((a.T if header["fortran_order"] else a).reshape(-1).view(np.uint8))


@dataclass(frozen=True)
class Reconstruction:
    """Foveal and perifoveal images recovered from polarisation-multiplexed frames.

    Attributes
    ----------
    x1, x2 : ndarray, shape (H, W) or (K, H, W)
        Foveal and perifoveal images: one window, or one image per window of a video.
    alpha : ndarray, shape (T,)
        Mixing ratios used or estimated (a video: the whole sequence's values; an unknown-alpha video's
        per-window estimates are in ``info['alpha_windows']``).
    fpn : ndarray, shape (H, W), or None
        The additive fixed pattern subtracted (zero mean).
    method : str
        ``lsq``, ``alternating``, ``dip``, ``snapshot`` or ``video/<method>``.
    timings : dict
        Wall-clock seconds per named stage.
    info : dict
        Condition numbers, what was identified, iterations, loss history, warnings.
    """

    x1: np.ndarray
    x2: np.ndarray
    alpha: np.ndarray
    fpn: np.ndarray | None = None
    method: str = "lsq"
    timings: dict[str, float] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def is_video(self) -> bool:
        """True for one image per window, ``(K, H, W)``."""
        return np.ndim(self.x1) == 3

    def plot(self, ax: Axes | Sequence[Axes] | None = None, *, window: int = 0, units: str = "DN") -> Figure:
        """The foveal (x1) and perifoveal (x2) images in the iron palette, colour bars in ``units``.

        Parameters
        ----------
        ax : matplotlib Axes, sequence of 2 Axes, or None
            None: a new figure with both images; one Axes: the foveal image only.
        window : int
            For a video, the output shown.
        units : str
            The images' unit: the frames' (DN for the simulator's).

        Returns
        -------
        matplotlib Figure
        """
        from metafovea.plotting import plot_reconstruction

        return plot_reconstruction(self, ax, window=window, units=units)

    def _repr_html_(self) -> str:
        from metafovea.plotting import reconstruction_html

        return reconstruction_html(self)

    def alpha_per_frame(self, n_frames: int) -> np.ndarray:
        """Mixing ratios for every frame of the sequence.

        Parameters
        ----------
        n_frames : int

        Returns
        -------
        ndarray, shape (n_frames,)
            The sequence's own where finite, else each window's estimate (``info['window_starts']`` /
            ``info['alpha_windows']`` of a windowed unknown-alpha run), NaN where none.
        """
        a = np.full(n_frames, np.nan)
        own = np.asarray(self.alpha, dtype=np.float64).reshape(-1)
        if own.shape == (n_frames,):
            a[:] = own
        for start, aw in zip(self.info.get("window_starts") or [], self.info.get("alpha_windows") or []):
            aw = np.asarray(aw, dtype=np.float64).reshape(-1)[:max(0, n_frames - start)]
            seg = a[start:start + aw.size]
            a[start:start + aw.size] = np.where(np.isfinite(seg), seg, aw)
        return a

    def save(self, path: str | os.PathLike) -> None:
        """Write atomically to ``path`` (``.npz``; info and timings as JSON metadata, :func:`save_npz_stored`).
        The file's ``alpha`` is :meth:`alpha_per_frame` (an unknown-alpha video's window estimates where the
        sequence has none: a reader of the file sees the estimate, not NaN)."""
        alpha = np.asarray(self.alpha)
        alpha = self.alpha_per_frame(alpha.size) if alpha.ndim == 1 else alpha
        arrays = {"x1": np.asarray(self.x1), "x2": np.asarray(self.x2), "alpha": alpha}
        if self.fpn is not None:
            arrays["fpn"] = np.asarray(self.fpn)
        meta = {"kind": KIND, "method": self.method, "timings": jsonable(self.timings),
                "info": jsonable(self.info)}
        # float32 images of noisy scenes hardly compress: zlib cost 3.6 s for 89 windows of 290 x 290 (60 MB)
        save_npz_stored(path, meta, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike) -> Reconstruction:
        """Read a file written by :meth:`save` (an :class:`InputError` for any other)."""
        arrays, meta = load_npz(path)
        if meta.get("kind") != KIND or not {"x1", "x2", "alpha"} <= set(arrays):
            raise InputError("path", str(path), "a Reconstruction file written by Reconstruction.save")
        return cls(x1=arrays["x1"], x2=arrays["x2"], alpha=arrays["alpha"], fpn=arrays.get("fpn"),
                   method=meta.get("method", "?"), timings=dict(meta.get("timings", {})),
                   info=dict(meta.get("info", {})))


@dataclass(frozen=True)
class PipelineResult:
    """What :func:`~metafovea.reconstruct.reconstruct_measurement` made of a Measurement.

    Attributes
    ----------
    reconstruction : Reconstruction
        One window, or a video of ``(K, H, W)`` images.
    spans : tuple of (int, int)
        ``(start, stop)`` frames each output covers (``stop`` exclusive; one frame for a snapshot).
    seconds : float
        Wall-clock of the reconstruction (FPN estimation and denoising included, file reading not).
    constraint : FovealConstraint
        The foveal constraint the solvers used.
    frames : int
        Frames of the measurement.
    source : str or None
        Its file, if it was read from one.
    metrics : dict, str or None
        :func:`~metafovea.reconstruct.metrics.score` against the truth each output shows (None without truth; a
        sentence saying why when it could not be computed).
    alpha_mae : float or None
        Mean absolute error of the estimated mixing ratios against the file's (window mean; None when alpha was
        given or the file does not know it).
    """

    reconstruction: Reconstruction
    spans: tuple[tuple[int, int], ...]
    seconds: float
    constraint: FovealConstraint
    frames: int
    source: str | None = None
    metrics: dict[str, float] | str | None = None
    alpha_mae: float | None = None

    @property
    def outputs(self) -> int:
        """The number of outputs (windows)."""
        return len(self.spans)

    def plot(self, ax: Axes | Sequence[Axes] | None = None, *, window: int = 0, units: str = "DN") -> Figure:
        """The reconstruction's images: :meth:`Reconstruction.plot`."""
        return self.reconstruction.plot(ax, window=window, units=units)

    def _repr_html_(self) -> str:
        from metafovea.plotting import fmt, reconstruction_html

        rows = [("frames", f"{self.frames} in {self.outputs} output(s)"),
                ("time", fmt(self.seconds, "s", 3))]
        if isinstance(self.metrics, dict):
            rows += [(k.replace("_", " "), fmt(v, "dB" if k.startswith("psnr") else ""))
                     for k, v in self.metrics.items()]
        elif isinstance(self.metrics, str):
            rows.append(("metrics", self.metrics))
        if self.alpha_mae is not None:
            rows.append(("alpha mean abs. error", fmt(self.alpha_mae)))
        return reconstruction_html(self.reconstruction, extra=rows)

    @property
    def x1s(self) -> np.ndarray:
        """Foveal images, one per output: ``(K, H, W)``."""
        x = np.asarray(self.reconstruction.x1)
        return x if x.ndim == 3 else x[None]

    @property
    def x2s(self) -> np.ndarray:
        """Perifoveal images, one per output: ``(K, H, W)``."""
        x = np.asarray(self.reconstruction.x2)
        return x if x.ndim == 3 else x[None]

    @property
    def nonfinite_pixels(self) -> int:
        """NaN/inf values in x1 and x2 (pixels without valid samples, e.g. dead pixels)."""
        r = self.reconstruction
        return int(np.sum(~np.isfinite(r.x1)) + np.sum(~np.isfinite(r.x2)))

    def summary(self, files: list[str] | None = None) -> dict[str, Any]:
        """A JSON-ready summary: method, frames, outputs, timings, conditioning, gauge, FPN, metrics."""
        rec = self.reconstruction
        out: dict[str, Any] = {"measurement": self.source, "method": rec.method, "frames": int(self.frames),
                               "foveal_constraint": self.constraint.as_kwargs(), "outputs": self.outputs,
                               "seconds": self.seconds, "ms_per_output": 1e3 * self.seconds / max(self.outputs, 1),
                               "timings": rec.timings, "files": list(files or [])}
        for key in ("condition", "alpha_identified", "iterations"):
            if key in rec.info:
                v = rec.info[key]
                out[key] = float(np.nanmax(np.asarray(v, dtype=float))) if isinstance(v, list) else v
        if "gauge" in rec.info:
            out["gauge"] = {k: rec.info["gauge"].get(k) for k in ("applied", "reason")}
        ng = rec.info.get("noise_gain")
        if ng is not None and np.size(ng) == 2:
            out["noise_gain"] = [float(v) for v in np.ravel(ng)]
        if rec.info.get("invalid_samples"):
            out["invalid_samples"] = rec.info["invalid_samples"]
        for key in ("alpha_gauge", "alpha_se_max", "alpha_se_threshold", "images_gauge_se"):
            if rec.info.get(key) is not None:
                out[key] = rec.info[key]
        pg = rec.info.get("polarizer_gauge")
        if pg is not None:
            fit = pg.get("fit", {})
            out["polarizer"] = {"applied": pg["applied"], "reason": pg.get("reason"), "mode": fit.get("mode"),
                                "rate_hz": fit.get("rate_hz"), "irregular": fit.get("irregular"),
                                "warning": pg.get("warning"), "alpha_from": pg.get("alpha_from"),
                                "deviation_shared": pg.get("deviation_shared"),
                                **({"frames_left_out": pg["frames_left_out"]} if pg.get("frames_left_out") else {})}
        if rec.info.get("polarizer_spec") is not None:  # the model used: each value with its source
            out.setdefault("polarizer", {})["model"] = rec.info["polarizer_spec"]
        if rec.info.get("gauge_pooled"):  # windows whose gauges were chained into one polariser fit
            out["gauge_pooled"] = rec.info["gauge_pooled"]
        cal = rec.info.get("calibration")
        if cal:  # what the recording showed of its camera (geometry, gain, amplitude), with standard errors
            out["calibration"] = dict(cal)
        warns = list(rec.info.get("warnings") or [])
        warns += [w for w in (pg.get("warning") if pg else None, (cal or {}).get("warning"),
                              (rec.info.get("gauge") or {}).get("warning")) if w]
        if warns:
            out["warnings"] = warns
        if "fpn" in rec.info:
            fi = rec.info["fpn"]
            out["fpn"] = fi.get("identified") or fi.get("mode")
            out.update({f"fpn_{k}": fi[k] for k in ("mode", "auto") if fi.get(k)})  # auto: why fpn='auto' chose it
        dip = _dip_summary(rec)
        if dip is not None:
            out["dip"] = dip
        if self.nonfinite_pixels:
            out["nonfinite_pixels"] = self.nonfinite_pixels
        if self.metrics is not None:  # with the estimated alpha's error against the file's, where both exist
            add = isinstance(self.metrics, dict) and self.alpha_mae is not None
            out["metrics"] = {**self.metrics, "alpha_mae": self.alpha_mae} if add else self.metrics
        if rec.info.get("frame"):  # the snapshot's frame, and why it was that one
            out["frame"] = rec.info["frame"]
        if rec.info.get("auto"):  # what method='auto' chose, why, and the time it took
            out["auto"] = rec.info["auto"]
        return out


def _dip_summary(rec: Reconstruction) -> dict[str, Any] | None:
    """How the deep image prior's windows stopped: ``windows`` (done; ``windows_planned`` when the time cap stopped
    the run earlier), ``steps`` (the budget), ``steps_run_mean``, ``stopped`` (count per reason: steps, converged,
    time), ``max_seconds`` (the run's time cap) and ``first_step_seconds`` (the longest first step of a window: the
    network's compilation where it was new); None for the other methods."""
    runs = rec.info.get("dip_windows")
    if runs is None and rec.method == "dip" and "steps_run" in rec.info:
        runs = [rec.info]
    if not runs:
        return None
    stopped: dict[str, int] = {}
    for r in runs:
        stopped[str(r.get("stopped"))] = stopped.get(str(r.get("stopped")), 0) + 1
    return {"windows": len(runs), "windows_planned": rec.info.get("windows_planned", len(runs)),
            "steps": runs[0].get("steps"),
            "steps_run_mean": float(np.mean([r.get("steps_run") or 0 for r in runs])), "stopped": stopped,
            "max_seconds": rec.info.get("max_seconds"),
            "first_step_seconds": max(float(r.get("first_step_seconds") or 0.0) for r in runs)}

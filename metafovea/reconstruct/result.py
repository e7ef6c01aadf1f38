"""The :class:`Reconstruction` result type (saved as ``.npz`` + JSON metadata)."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from metafovea.errors import InputError
from metafovea.io import atomic_save_npz, jsonable, load_npz

KIND = "metafovea.Reconstruction"


@dataclass(frozen=True)
class Reconstruction:
    """Foveal and perifoveal images recovered from polarisation-multiplexed frames.

    Attributes
    ----------
    x1, x2: foveal / perifoveal images, ``(H, W)`` for one window or ``(K, H, W)`` for a video
        (one image per window).
    alpha: mixing ratios used or estimated, ``(T,)`` (for a video: the whole sequence's values; for an
        unknown-alpha video, each window's estimate is in ``info['alpha_windows']``).
    fpn: estimated additive fixed-pattern noise ``(H, W)`` (zero mean) or ``None``.
    method: solver name (``lsq``, ``alternating``, ``dip``, ``snapshot``, ``video/<method>``).
    timings: wall-clock seconds per named stage.
    info: condition numbers, what was identified, iterations, loss history, warnings.
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
        return np.ndim(self.x1) == 3

    def save(self, path: str | os.PathLike) -> None:
        """Write atomically to ``path`` (``.npz``; info and timings as JSON metadata)."""
        arrays = {"x1": np.asarray(self.x1), "x2": np.asarray(self.x2), "alpha": np.asarray(self.alpha)}
        if self.fpn is not None:
            arrays["fpn"] = np.asarray(self.fpn)
        meta = {"kind": KIND, "method": self.method, "timings": jsonable(self.timings),
                "info": jsonable(self.info)}
        atomic_save_npz(path, meta=meta, **arrays)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Reconstruction":
        arrays, meta = load_npz(path)
        if meta.get("kind") != KIND or not {"x1", "x2", "alpha"} <= set(arrays):
            raise InputError("path", str(path), "a Reconstruction file written by Reconstruction.save")
        return cls(x1=arrays["x1"], x2=arrays["x2"], alpha=arrays["alpha"], fpn=arrays.get("fpn"),
                   method=meta.get("method", "?"), timings=dict(meta.get("timings", {})),
                   info=dict(meta.get("info", {})))

"""Sensor PSFs over fields and wavelength sets as one sweep through the project's executor.

:func:`sensor_psf_sweep` runs one :func:`~metafovea.optics.sensor.sensor_psf` per (field, wavelength set) pair
through :func:`metafovea.parallel.run_tasks`: in this process (``workers=1``), in local threads or processes
(``executor``), or on a Dask cluster (``scheduler``). Each task runs with one BLAS thread, so the arrays do not
depend on where it ran (bit for bit; ``tests/parallel/test_dask.py`` checks a LocalCluster against the serial
path). The PSF report (:func:`metafovea.optics.report.psf_report`) computes its sensor PSFs across the field
with it, which is how ``metafovea psf --scheduler`` spreads them.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.config import LensDesign
from metafovea.errors import InputError, NotConvergedWarning
from metafovea.library.postset import PostSet
from metafovea.parallel import DaskExecutor, blas_threads, run_tasks

from .psf import PSF
from .sensor import sensor_psf


@dataclass(frozen=True)
class PSFSweep:
    """The PSFs of a sweep: ``psfs[i][j]`` is field ``fields_deg[i]`` with wavelength set ``j``;
    ``warnings``: the message of every warning the PSFs raised (each names its field), in field order, except a
    PSF's own :class:`~metafovea.errors.NotConvergedWarning` with data: that is its ``info['accuracy']``
    (:meth:`accuracy` lists them)."""

    fields_deg: list[float]
    psfs: list[list[PSF]]
    warnings: list[str] = field(default_factory=list)

    def accuracy(self) -> list[dict[str, Any]]:
        """``info['accuracy']`` of every PSF that missed its requested error (why, and which parameters would
        change that: :func:`metafovea.optics.sensor.sensor_psf`), in field order."""
        return [p.info["accuracy"] for row in self.psfs for p in row if "accuracy" in p.info]

    def intensities(self) -> list[list[np.ndarray]]:
        """The pixel arrays, ``[field][wavelength set]`` (fraction of incident power per pixel)."""
        return [[p.intensity for p in row] for row in self.psfs]


def _one(lens: LensDesign, common: dict[str, Any], alone: bool,
         item: tuple[float, ArrayLike, ArrayLike | None, PostSet | None]) -> tuple[PSF, list[str]]:
    """One sensor PSF. ``alone`` (the task has its process to itself: serial, process pool, Dask worker): one BLAS
    thread, and its warnings come back as data (a worker's would stay in the worker's log). In threads neither:
    threadpoolctl's limit and catch_warnings are process-wide (a thread leaving them would undo them under its
    neighbour), so the sweep sets both once around all the threads."""
    fd, wl, w, posts = item
    if not alone:
        return sensor_psf(lens, field_deg=fd, wavelengths_um=wl, weights=w, post_set=posts, **common), []
    with blas_threads(1), warnings.catch_warnings(record=True) as ws:
        warnings.simplefilter("always")
        P = sensor_psf(lens, field_deg=fd, wavelengths_um=wl, weights=w, post_set=posts, **common)
    return P, [str(x.message) for x in ws if not _on_the_psf(x)]


def _on_the_psf(w: warnings.WarningMessage) -> bool:
    """A PSF's NotConvergedWarning with data: its ``info['accuracy']`` holds the same (not repeated)."""
    return isinstance(w.message, NotConvergedWarning) and bool(w.message.data)


def sensor_psf_sweep(lens: LensDesign, fields_deg: Sequence[float], bands: Sequence[tuple[ArrayLike, ArrayLike | None]],
                     *, pixel_pitch_um: float, post_sets: PostSet | Sequence[PostSet | None] | None = None,
                     error: float = 1e-4, z_um: float | None = None, workers: int | None = 1,
                     scheduler: str | None = None, executor: cf.Executor | DaskExecutor | None = None,
                     on_field: Callable[[float], None] | None = None, **kwargs: Any) -> PSFSweep:
    """Sensor PSFs of ``lens`` at every field of ``fields_deg`` (deg) for every wavelength set of ``bands``.

    Parameters
    ----------
    lens : LensDesign
    fields_deg : sequence of float, deg
    bands : sequence of (wavelengths_um, weights or None)
        e.g. ``[([10.0], None), (wl, w)]`` for the design wavelength and a weighted band.
    pixel_pitch_um : float, um
        the pixel pitch at the focal plane.
    post_sets : PostSet, sequence of PostSet (one per field) or None
        the lens' posts (None: ideal posts).
    error, z_um, **kwargs
        passed to :func:`~metafovea.optics.sensor.sensor_psf` (e.g. ``size_px``).
    workers, scheduler, executor
        where the tasks run (:func:`metafovea.parallel.run_tasks`): ``workers=1`` in this process, a Dask
        ``scheduler`` address (or ``local:N``), or an ``executor`` already open (local threads: the warnings are
        then recorded around the whole sweep).
    on_field : callable(field_deg), optional
        called when all PSFs of a field are done (a progress tick; fields may finish out of order).

    Returns
    -------
    PSFSweep
        in the order of ``fields_deg`` and ``bands``, wherever the tasks ran.
    """
    fields = [float(fd) for fd in fields_deg]
    if not fields or not bands:
        raise InputError("fields_deg" if not fields else "bands", [] if not fields else list(bands),
                         "at least one field and one wavelength set")
    if post_sets is None or not isinstance(post_sets, (list, tuple)):
        posts = [post_sets] * len(fields)
    else:
        posts = list(post_sets)
        if len(posts) != len(fields):
            raise InputError("post_sets", f"{len(posts)} post sets", f"one per field ({len(fields)})")
    items = [(fd, wl, w, posts[i]) for i, fd in enumerate(fields) for wl, w in bands]
    threads = isinstance(executor, cf.ThreadPoolExecutor)
    common = dict(pixel_pitch_um=pixel_pitch_um, error=error, z_um=z_um, **kwargs)
    out: list[Any] = [None] * len(items)
    left = [len(bands)] * len(fields)
    ws: list[Any] = []
    with contextlib.ExitStack() as stack:
        if threads:  # the tasks in threads neither limit BLAS nor capture (see _one): done here, once
            stack.enter_context(blas_threads(1))
            ws = stack.enter_context(warnings.catch_warnings(record=True))
            warnings.simplefilter("always")
        for k, res in run_tasks(partial(_one, lens, common, not threads), items, workers=workers,
                                scheduler=scheduler, executor=executor):
            out[k] = res
            i = k // len(bands)
            left[i] -= 1
            if left[i] == 0 and on_field is not None:
                on_field(fields[i])
    msgs = [m for _, task_msgs in out for m in task_msgs] + [str(x.message) for x in ws if not _on_the_psf(x)]
    psfs = [[out[i * len(bands) + j][0] for j in range(len(bands))] for i in range(len(fields))]
    return PSFSweep(fields, psfs, msgs)


__all__ = ["PSFSweep", "sensor_psf_sweep"]

"""The scatterer library: an RCWA sweep of rectangular posts over a (wx, wy) width grid, cached and resumable.

Physical set-up (:mod:`metafovea.rcwa.posts`): Si posts on the Si wafer, air above; light enters through the wafer
by default (posts face the sensor) so only the zero order is transmitted into air at 10 um. Phases are referenced at
the post-layer faces; t is power normalised (|t|^2 = zero-order efficiency). At normal incidence with azimuth 0,
:mod:`metafovea.rcwa` calls x-polarised light 'p' and y-polarised light 's'.

:func:`compute_library` runs the sweep (settings in :class:`LibraryOptions`) through
:func:`metafovea.parallel.run_tasks`, one task per (wavelength, wx) row; the result is cached under a hash of every
input (:func:`library_key`) and finished rows are kept, so an interrupted sweep resumes; a cache miss whose key is
that of a library shipped with the package (:mod:`metafovea.library.seed`) reads that file instead, and a library
that is computed is announced on the log with its expected time. :func:`width_grid` is the grid a platform's min
feature allows.
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.config import PAPER_PERIOD_UM, PAPER_POST_HEIGHT_UM, PAPER_WAVELENGTH_UM, PlatformDesign
from metafovea.errors import InputError, NotConvergedWarning, check_choice, check_int, check_positive, check_range
from metafovea.io import atomic_save_npz, cache_lock, input_hash, load_npz, seed_file
from metafovea.io import cache_dir as io_cache_dir
from metafovea.materials import N_AIR, N_SI_10UM
from metafovea.parallel import run_tasks

from .postset import _load_checked

log = logging.getLogger(__name__)

LIBRARY_ARRAYS = ("t_x", "t_y", "T_x", "T_y", "R_x", "R_y", "other_x", "other_y", "err_x", "err_y")
DEFAULT_HARMONICS = 10
#: the physical parameters of a library's stack (keys of its meta): a library file without one is an error naming
#: it, never the paper's value
LIBRARY_STACK_KEYS = ("period_um", "height_um", "n_post", "n_surround", "n_substrate", "n_superstrate")


@dataclass
class Library:
    """Zero-order responses of posts on a (wx, wy) grid for one or more wavelengths.

    Arrays of shape (n_wavelengths, n_wx, n_wy): ``t_x``/``t_y`` complex power-normalised
    transmission for x/y-polarised light (exp(-i omega t), reference planes at the post-layer faces),
    ``T_*`` = |t|^2, ``R_*`` total reflection, ``other_*`` power in all other orders (mostly reflected
    first orders inside the wafer), ``err_*`` convergence estimate |t(M) - t(M-2)|.
    ``meta``: every input (platform, harmonics, factorisation, entry side), timing, cache key.
    """

    wx_um: np.ndarray
    wy_um: np.ndarray
    wavelengths_um: np.ndarray
    arrays: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)

    def __getattr__(self, name: str) -> np.ndarray:
        arrays = self.__dict__.get("arrays", {})
        if name in arrays:
            return arrays[name]
        raise AttributeError(name)

    def index_of_wavelength(self, wavelength_um: float) -> int:
        d = np.abs(self.wavelengths_um - wavelength_um)
        i = int(np.argmin(d))
        if d[i] > 1e-9:
            raise InputError("wavelength_um", wavelength_um,
                             f"one of the library wavelengths {self.wavelengths_um.tolist()}")
        return i

    def save(self, path: str | Path) -> Path:
        meta = dict(self.meta, type="Library", units="um")
        return atomic_save_npz(path, meta, wx_um=self.wx_um, wy_um=self.wy_um,
                               wavelengths_um=self.wavelengths_um, **self.arrays)

    @classmethod
    def load(cls, path: str | Path, name: str = "path") -> Library:
        """Read a file written by :meth:`save`; errors name the file as ``name`` (a CLI passes its flag), and a file
        without a key of :data:`LIBRARY_STACK_KEYS` is one of them."""
        arrays, meta = _load_checked(path, "Library", name)
        missing = [k for k in LIBRARY_STACK_KEYS if meta.get(k) is None]
        if missing:
            raise InputError(name, str(path), "a Library file written by Library.save",
                             detail=f"missing {missing[0]!r}: a physical parameter is never assumed")
        try:
            return cls(arrays.pop("wx_um"), arrays.pop("wy_um"), arrays.pop("wavelengths_um"), arrays, meta)
        except KeyError as e:
            raise InputError(name, str(path), "a Library file written by Library.save",
                             detail=f"missing {e.args[0]!r}") from None


def _stack(lib: Library, key: str) -> Any:
    """``lib.meta[key]``, a physical parameter of the library's stack (:data:`LIBRARY_STACK_KEYS`); a library without
    it (one made by hand) is an :class:`InputError` naming the key, never the paper's value."""
    value = lib.meta.get(key)
    if value is None:
        raise InputError(key, None, "stated in the library's meta (compute_library and Library.load give it; no "
                         "paper value is assumed)")
    return value


def width_grid(period_um: float = PAPER_PERIOD_UM, step_um: float = 0.1, min_feature_um: float = 0.5, *,
               name: str = "grid_step_um") -> np.ndarray:
    """Post widths from ``min_feature`` to ``period - min_feature`` (both posts and gaps >= min feature).

    ``name``: the step's name in error messages (the CLI passes ``--grid-step-um``).
    """
    p = check_positive("period_um", period_um, "um")
    mf = check_range("min_feature_um", min_feature_um, 0.0, p / 2, hi_inclusive=False)
    # widths run from max(mf, step) to p - max(mf, step): at least 2 of them need p - 2 max(mf, step) >= step,
    # i.e. step <= p / 3 (when mf <= p / 3) or step <= p - 2 mf (a min feature above p / 3)
    max_step = p / 3 if mf <= p / 3 else p - 2 * mf
    rng = (f"0 um < {name} <= {max_step:.6g} um (at least 2 widths between the min feature {mf:g} um and "
           f"period {p:g} um - min feature)")
    step = check_range(name, step_um, 0.0, None, unit="um")
    if step > max_step * (1 + 1e-9):
        raise InputError(name, step_um, rng)
    lo, hi = max(mf, step), p - max(mf, step)
    n = int(math.floor((hi - lo) / step + 1e-9)) + 1
    if n < 2:
        raise InputError(name, step_um, rng)
    if n > 2001:
        raise InputError(name, step_um, f"a step of at least {(hi - lo) / 2000:.4g} um (at most 2001 widths per axis)")
    return np.round(lo + step * np.arange(n), 10)


def _material_key(v: Any, wl: np.ndarray) -> Any:
    from metafovea.materials import Material, index_of
    if isinstance(v, Material):
        n = index_of(v.name, v, wl)
        return {"material": v.name, "n": [[float(z.real), float(z.imag)] for z in n]}
    z = complex(v)
    return [z.real, z.imag]


def _row_task(job: dict) -> dict:
    """One sweep task: x-polarised (and y if needed) responses for one wx at all wy, one wavelength."""
    from metafovea.parallel import blas_threads
    from metafovea.rcwa.posts import post_response
    with warnings.catch_warnings(), blas_threads(1):
        warnings.simplefilter("ignore", NotConvergedWarning)
        kw = job["kw"]
        out: dict[str, np.ndarray] = {}
        pols = ("x",) if job["symmetric"] else ("x", "y")
        r = post_response(job["wx"], job["wy"], job["wl"], estimate=job["estimate"], polarizations=pols, **kw)
        for k in LIBRARY_ARRAYS:
            if k.endswith("_y") and job["symmetric"]:
                continue
            out[k] = np.asarray(getattr(r, k))
        out["energy_error"] = np.array(r.info.get("energy_error") or 0.0)
    return out


@dataclass(frozen=True)
class LibraryOptions:
    """Every knob of a library sweep except the width grid and the wavelengths.

    The stack: ``period_um``, ``height_um`` (um), refractive indices (numbers or
    :class:`metafovea.materials.Material`) of the posts, their surroundings, the substrate (the wafer) and the
    superstrate (air). The solver: ``harmonics`` M (|m|, |n| <= M), ``factorization`` {'li', 'laurent'},
    ``incidence`` {'substrate', 'superstrate'} (the side light enters from), ``estimate`` (also solve at M - 2
    for the convergence estimate). The run: ``tol`` (a :class:`NotConvergedWarning` for posts whose estimate
    exceeds it; None: no warning), ``cache_dir`` (default ``$METAFOVEA_CACHE/library``), ``use_cache``,
    ``workers`` (local processes; default all cores), ``scheduler`` (a Dask scheduler address), ``progress``.
    """

    period_um: float = PAPER_PERIOD_UM
    height_um: float = PAPER_POST_HEIGHT_UM
    n_post: Any = N_SI_10UM
    n_surround: Any = N_AIR
    n_substrate: Any = N_SI_10UM
    n_superstrate: Any = N_AIR
    harmonics: int = DEFAULT_HARMONICS
    factorization: str = "li"
    incidence: str = "substrate"
    estimate: bool = True
    tol: float | None = 0.02
    cache_dir: str | Path | None = None
    use_cache: bool = True
    workers: int | None = None
    scheduler: str | None = None
    progress: bool = True

    def with_platform(self, platform: PlatformDesign) -> LibraryOptions:
        """These options with the stack (period, post height, indices) of ``platform``."""
        return replace(self, period_um=platform.period_um, height_um=platform.post_height_um,
                       n_post=platform.n_post, n_substrate=platform.n_substrate,
                       n_superstrate=platform.n_superstrate)


@dataclass(frozen=True)
class _Sweep:
    """The checked inputs of one library sweep and the hash that names its cache files."""

    wx: np.ndarray
    wy: np.ndarray
    wls: np.ndarray
    solver_kw: dict[str, Any]  #: keyword arguments of post_response (checked values)
    estimate: bool
    tol: float | None
    symmetric: bool  #: wx and wy grids coincide: only x-polarised light is solved
    inputs: dict[str, Any]
    key: str


def _checked_sweep(wx_um: ArrayLike, wy_um: ArrayLike | None, wavelengths_um: ArrayLike,
                   opts: LibraryOptions) -> _Sweep:
    """Every input checked (clear errors before any work is queued) and hashed."""
    from metafovea.materials import index_of
    from metafovea.rcwa.solve import FACTORIZATIONS, SIDES

    period = check_positive("period_um", opts.period_um, "um")
    height = check_positive("height_um", opts.height_um, "um")
    wx = np.asarray(wx_um, dtype=float).ravel()
    wy = wx.copy() if wy_um is None else np.asarray(wy_um, dtype=float).ravel()
    for name, w in (("wx_um", wx), ("wy_um", wy)):
        if w.size < 1 or not np.all(np.isfinite(w)) or np.any(w <= 0) or np.any(w >= period):
            raise InputError(name, w.tolist()[:5], f"widths with 0 < w < period_um = {period:g} um")
    wls = np.asarray(list(np.atleast_1d(wavelengths_um)), dtype=float).ravel()
    if np.unique(wls).size != wls.size:  # each repeat solved the whole library again
        raise InputError("wavelengths_um", wls.tolist(), "distinct wavelengths (um): each is a library of its own")
    if wls.size < 1 or not np.all(np.isfinite(wls)) or np.any(wls <= 0):
        raise InputError("wavelengths_um", wls.tolist(), "positive wavelengths (um)")
    M = check_int("harmonics", opts.harmonics, 5 if opts.estimate else 3, 40)
    factorization = check_choice("factorization", opts.factorization, FACTORIZATIONS)
    incidence = check_choice("incidence", opts.incidence, SIDES)
    tol = None if opts.tol is None else check_positive("tol", opts.tol)
    media = {"n_post": opts.n_post, "n_surround": opts.n_surround, "n_substrate": opts.n_substrate,
             "n_superstrate": opts.n_superstrate}
    for nm, v in media.items():
        index_of(nm, v, wls)
    inputs = {"schema": 1, "wx_um": wx, "wy_um": wy, "wavelengths_um": wls, "period_um": period,
              "height_um": height, **{nm: _material_key(v, wls) for nm, v in media.items()}, "harmonics": M,
              "factorization": factorization, "incidence": incidence, "estimate": bool(opts.estimate)}
    solver_kw = dict(period_um=period, height_um=height, **media, harmonics=M, factorization=factorization,
                     incidence=incidence)
    return _Sweep(wx, wy, wls, solver_kw, bool(opts.estimate), tol,
                  wx.shape == wy.shape and bool(np.all(wx == wy)), inputs, input_hash(inputs))


def compute_library(wx_um: Sequence[float], wy_um: Sequence[float] | None = None,
                    wavelengths_um: Iterable[float] = (PAPER_WAVELENGTH_UM,), *, options: LibraryOptions | None = None,
                    **overrides: Any) -> Library:
    """Sweep the post widths (wx, wy) for each wavelength with :func:`metafovea.rcwa.posts.post_response`.

    Parameters
    ----------
    wx_um, wy_um : array_like, um
        Post widths along x and y (``wy_um=None``: the same grid as ``wx_um``).
    wavelengths_um : iterable of float, um
    options : LibraryOptions, optional
        The stack, solver and run settings (default ``LibraryOptions()``).
    **overrides
        Fields of :class:`LibraryOptions` that replace those of ``options`` (``harmonics=5, workers=1``).

    The result is cached in ``options.cache_dir`` under a hash of every input; finished rows are written as
    they arrive (``<key>.parts/``), so an interrupted sweep resumes where it stopped. Work runs through
    :func:`metafovea.parallel.run_tasks` (local processes, or Dask with ``scheduler``). When the wx and
    wy grids coincide (square lattice), only x-polarised light is solved and
    ``t_y(wx, wy) = t_x(wy, wx)``. With ``tol``, a :class:`NotConvergedWarning` reports posts whose
    convergence estimate exceeds it.
    """
    opts = replace(options if options is not None else LibraryOptions(), **overrides)
    sweep = _checked_sweep(wx_um, wy_um, wavelengths_um, opts)
    cdir = Path(opts.cache_dir) if opts.cache_dir is not None else io_cache_dir("library")
    final = cdir / f"library-{sweep.key}.npz"
    lib = (_cached_library(final) or _seed_library(final.name, sweep.key)) if opts.use_cache else None
    if lib is None and opts.use_cache:
        # one process computes, others (test workers, a second command) wait for its file
        with cache_lock(final):
            lib = _cached_library(final)
            if lib is None:
                _announce(sweep, opts, final)
                lib = _run_sweep(sweep, opts, cdir / f"library-{sweep.key}.parts")
                lib.save(final)
                _remove_parts(cdir / f"library-{sweep.key}.parts")
    elif lib is None:
        _announce(sweep, opts, None)
        lib = _run_sweep(sweep, opts, cdir / f"library-{sweep.key}.parts")
    _warn_convergence(lib, sweep.tol)
    return lib


def library_key(wx_um: Sequence[float], wy_um: Sequence[float] | None = None,
                wavelengths_um: Iterable[float] = (PAPER_WAVELENGTH_UM,), *, options: LibraryOptions | None = None,
                **overrides: Any) -> str:
    """The cache key of the library :func:`compute_library` gives for these arguments: a hash of every input that
    changes its numbers (the grid, wavelengths, stack and solver settings; not the run settings ``tol``,
    ``cache_dir``, ``use_cache``, ``workers``, ``scheduler``, ``progress``). The cache file is
    ``library-<key>.npz``."""
    opts = replace(options if options is not None else LibraryOptions(), **overrides)
    return _checked_sweep(wx_um, wy_um, wavelengths_um, opts).key


#: CPU seconds per post at 10 harmonics with the M - 2 estimate (measured here on one core: 0.057 s; 3.2 ms at
#: M = 5, 24 ms at 8, 0.14 s at 12, i.e. about (2M + 1)^4.5)
_POST_SECONDS_M10 = 0.057


def _expected_seconds(sweep: _Sweep, workers: int) -> float:
    """Wall seconds a sweep takes on ``workers`` idle cores (the cost model of :data:`_POST_SECONDS_M10`; a grid
    that is not square solves y-polarised light too, twice the work)."""
    m = sweep.solver_kw["harmonics"]
    per_post = _POST_SECONDS_M10 * ((2 * m + 1) / 21) ** 4.5 * (1.0 if sweep.estimate else 0.7)
    per_post *= 1.0 if sweep.symmetric else 2.0
    rows = sweep.wls.size * sweep.wx.size
    return per_post * rows * sweep.wy.size / max(1, min(workers, rows))


def _announce(sweep: _Sweep, opts: LibraryOptions, final: Path | None) -> None:
    """Say on the log (a warning: the CLI shows it on stderr) that a library is computed, on what and for about
    how long."""
    from metafovea.parallel import default_workers

    what = (f"computing the RCWA scatterer library: {sweep.wx.size} x {sweep.wy.size} posts x {sweep.wls.size} "
            f"wavelength(s), harmonics {sweep.solver_kw['harmonics']}")
    def about(seconds: float) -> str:
        return "under 1 s" if seconds < 1 else f"about {seconds:.0f} s"

    if opts.scheduler is None:
        workers = opts.workers or default_workers()
        what += f", {workers} worker process(es): {about(_expected_seconds(sweep, workers))} on idle cores"
    else:
        what += f" on the Dask scheduler {opts.scheduler}: {about(_expected_seconds(sweep, 1))} of one core"
    log.warning("%s (%s)", what, f"then cached in {final.parent}" if final is not None else "use_cache=False")


def _seed_library(name: str, key: str) -> Library | None:
    """The library shipped with the package under the cache file name ``name`` (:func:`metafovea.io.seed_file`),
    when its key is ``key``; None otherwise."""
    path = seed_file(name)
    if path is None:
        return None
    try:
        lib = Library.load(path)
    except InputError as e:  # a damaged installation: computed as if there were no seed
        log.warning("ignoring the damaged library seed %s (%s)", path, e)
        return None
    if lib.meta.get("key") != key:
        log.warning("ignoring the library seed %s: its key %s is not %s", path, lib.meta.get("key"), key)
        return None
    log.info("library loaded from the package's seed %s", path)
    lib.meta.update(from_cache=True, from_seed=True)
    return lib


def _cached_library(final: Path) -> Library | None:
    """The cached library at ``final``; None when there is none or it is damaged (then it is recomputed)."""
    if not final.is_file():
        return None
    try:
        lib = Library.load(final)
    except InputError as e:  # a damaged cache file (disk full, killed copy) is recomputed, not fatal
        log.warning("recomputing damaged library cache %s (%s)", final, e)
        return None
    log.info("library loaded from cache %s", final)
    lib.meta["from_cache"] = True
    return lib


def _run_sweep(sweep: _Sweep, opts: LibraryOptions, parts: Path) -> Library:
    """Solve every (wavelength, wx) row not already in ``parts`` (one task each) and assemble the library."""
    wx, wy, wls = sweep.wx, sweep.wy, sweep.wls
    shape = (wls.size, wx.size, wy.size)
    arrays = {k: np.full(shape, np.nan, dtype=complex if k.startswith("t_") else float) for k in LIBRARY_ARRAYS}
    energy = 0.0
    jobs, todo = [], []
    for il, wl in enumerate(wls):
        for ix, a in enumerate(wx):
            pf = parts / f"row-{il}-{ix}.npz"
            row_energy = _finished_row(pf, arrays, il, ix) if opts.use_cache else None
            if row_energy is not None:
                energy = max(energy, row_energy)
                continue
            jobs.append(dict(wx=np.full(wy.size, a), wy=wy, wl=float(wl), kw=sweep.solver_kw,
                             estimate=sweep.estimate, symmetric=sweep.symmetric, il=il, ix=ix))
            todo.append(pf)
    log.info("library %s: %d of %d rows to compute (M=%d, %s)", sweep.key, len(jobs), wls.size * wx.size,
             sweep.solver_kw["harmonics"], sweep.solver_kw["factorization"])
    t0 = time.perf_counter()
    for i, res in run_tasks(_row_task, jobs, workers=opts.workers, scheduler=opts.scheduler,
                            progress=opts.progress, desc="RCWA library"):
        _store(arrays, res, jobs[i]["il"], jobs[i]["ix"])
        energy = max(energy, float(res.get("energy_error", 0.0)))
        if opts.use_cache:
            atomic_save_npz(todo[i], None, **res)
    elapsed = time.perf_counter() - t0
    if sweep.symmetric:
        for k in LIBRARY_ARRAYS:
            if k.endswith("_y"):
                arrays[k] = np.swapaxes(arrays[k[:-2] + "_x"], 1, 2).copy()
    meta = dict(sweep.inputs, key=sweep.key, elapsed_s=elapsed, rows_computed=len(jobs), energy_error=energy,
                symmetric_grid=sweep.symmetric, workers=opts.workers, scheduler=opts.scheduler,
                conventions="exp(-i omega t); power-normalised zero-order t; phase planes at the post-layer faces; "
                            f"light enters from the {sweep.solver_kw['incidence']}")
    meta = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in meta.items()}
    return Library(wx, wy, wls, arrays, meta)


def _finished_row(pf: Path, arrays: dict[str, np.ndarray], il: int, ix: int) -> float | None:
    """Store the row left by an interrupted sweep in ``arrays``; returns its energy error, or None when there
    is none or it is damaged (then it is recomputed)."""
    if not pf.is_file():
        return None
    try:
        got, _ = load_npz(pf)
        _store(arrays, got, il, ix)
        return float(got.get("energy_error", 0.0))
    except Exception:  # noqa: BLE001 - a damaged part is recomputed
        log.warning("recomputing damaged cache part %s", pf)
        return None


def _remove_parts(parts: Path) -> None:
    """Delete the finished rows of a sweep whose library has been saved."""
    for pf in parts.glob("row-*.npz"):
        try:
            pf.unlink()
        except FileNotFoundError:
            pass
    try:
        parts.rmdir()
    except OSError:
        pass


def _store(arrays: dict, res: dict, il: int, ix: int) -> None:
    for k in LIBRARY_ARRAYS:
        if k in res:
            arrays[k][il, ix, :] = res[k]


def _warn_convergence(lib: Library, tol: float | None) -> None:
    err = np.fmax(lib.err_x, lib.err_y)
    if np.all(np.isnan(err)):
        lib.meta["max_error_estimate"] = None
        return
    worst = float(np.nanmax(err))
    lib.meta["max_error_estimate"] = worst
    lib.meta["median_error_estimate"] = float(np.nanmedian(err))
    if tol is not None and worst > tol:
        n_bad = int(np.sum(err > tol))
        warnings.warn(f"library: {n_bad} of {err.size} posts are not converged to {tol:g} "
                      f"(estimate up to {worst:.3g}; increase harmonics)", NotConvergedWarning, stacklevel=3)

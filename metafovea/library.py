"""Scatterer library (RCWA sweeps of post widths) and the post sets chosen from it.

A :class:`PostSet` is what the later stages (lens, layout, optics) consume: the N posts actually used
by one lens, level ``k`` targeting the wrapped phase ``2 pi k / N`` for the lens' own polarisation.

* :func:`compute_library` sweeps a (wx, wy) grid (settings in :class:`LibraryOptions`), cached and resumable;
  :func:`width_grid` is the grid a platform's min feature allows.
* :func:`select_posts` chooses one lens' posts from a :class:`Library` (the paper's Fig. 7c), for the nominal widths
  or (``bias_weight`` > 0) jointly for the platform's -/0/+ edge bias; :func:`bias_table` solves a set under it.
* :class:`PlatformSweep` / :func:`platform_post_sets`: a platform's library and both lenses' post sets, the
  path ``metafovea library``, ``design --library`` and ``validate`` share; :mod:`metafovea.library_report`
  turns it into numbers, figures and files.
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.config import POLARIZATIONS, PlatformDesign
from metafovea.errors import InputError, NotConvergedWarning, check_choice, check_int, check_positive, check_range
from metafovea.io import atomic_save_npz, cache_lock, input_hash, load_npz
from metafovea.io import cache_dir as io_cache_dir
from metafovea.parallel import run_tasks

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PostSet:
    """N posts for one lens.

    Attributes
    ----------
    polarization: 'x' or 'y', the polarisation this lens focuses (the other passes through).
    period_um, height_um, wavelength_um: platform and design wavelength.
    widths_um: (N, 2) float, [wx, wy] side widths of level k's post (x and y extent, um).
    t_x, t_y: (N,) complex, zero-order field transmission for x- and y-polarised light (power
        normalised, exp(-i omega t); see metafovea.rcwa for reference planes).
    R_x, R_y: (N,) zero-order (specular) power reflectance back into the wafer, or None when unknown
        (an ideal set has 0; a file written before they were stored has None).
    source: 'rcwa' (selected from a computed library) or 'ideal' (exact phases, unit transmission,
        widths a monotonic ramp: for layout and optics tests only; not a physical design).
    info: free-form numbers (phase errors, pass-through spread, efficiency estimates).
    """

    polarization: str
    period_um: float
    height_um: float
    wavelength_um: float
    widths_um: np.ndarray
    t_x: np.ndarray
    t_y: np.ndarray
    source: str = "rcwa"
    info: dict[str, Any] = field(default_factory=dict)
    R_x: np.ndarray | None = None
    R_y: np.ndarray | None = None

    def __post_init__(self) -> None:
        check_choice("polarization", self.polarization, POLARIZATIONS)
        w = np.asarray(self.widths_um, dtype=float)
        if w.ndim != 2 or w.shape[1] != 2 or w.shape[0] < 2:
            raise InputError("widths_um", w.shape, "an (N, 2) array with N >= 2")
        if np.any(w <= 0) or np.any(w >= self.period_um):
            raise InputError("widths_um", w.tolist(), f"0 < width < period_um = {self.period_um:g}")
        object.__setattr__(self, "widths_um", w)
        object.__setattr__(self, "t_x", np.asarray(self.t_x, dtype=complex).reshape(-1))
        object.__setattr__(self, "t_y", np.asarray(self.t_y, dtype=complex).reshape(-1))
        if self.t_x.shape[0] != w.shape[0] or self.t_y.shape[0] != w.shape[0]:
            raise InputError("t_x/t_y", (self.t_x.shape, self.t_y.shape), f"length N = {w.shape[0]}")
        for name in ("R_x", "R_y"):
            r = getattr(self, name)
            if r is not None:
                r = np.asarray(r, dtype=float).reshape(-1)
                if r.shape[0] != w.shape[0] or not np.all((r >= 0) & (r <= 1)):
                    raise InputError(name, r.tolist(), f"N = {w.shape[0]} reflectances in [0, 1]")
                object.__setattr__(self, name, r)

    @property
    def levels(self) -> int:
        return int(self.widths_um.shape[0])

    @property
    def t_focus(self) -> np.ndarray:
        """(N,) transmission of the focusing polarisation."""
        return self.t_x if self.polarization == "x" else self.t_y

    @property
    def t_pass(self) -> np.ndarray:
        """(N,) transmission of the pass-through (other) polarisation."""
        return self.t_y if self.polarization == "x" else self.t_x

    def transmission(self, polarization: str) -> np.ndarray:
        """(N,) zero-order field transmission of ``polarization`` light."""
        return self.t_x if check_choice("polarization", polarization, POLARIZATIONS) == "x" else self.t_y

    def plot(self, ax: Any = None) -> Any:
        """Phase (rad) and power transmission of each level's post for both polarisations, and the posts'
        cross-sections (um).

        Parameters
        ----------
        ax : matplotlib Axes, sequence of 3 Axes, or None
            None: a new figure with the three panels; one Axes: the phase panel only.

        Returns
        -------
        matplotlib Figure
        """
        from metafovea.plotting import plot_postset

        return plot_postset(self, ax)

    def _repr_html_(self) -> str:
        from metafovea.plotting import postset_html

        return postset_html(self)

    def reflectance(self, polarization: str) -> tuple[np.ndarray, str]:
        """(N,) specular power reflectance back into the wafer for ``polarization`` light and where it comes
        from: the RCWA value, or ``1 - |t|^2`` (every loss taken as specular reflection: an upper bound) when
        the set does not carry it."""
        r = self.R_x if check_choice("polarization", polarization, POLARIZATIONS) == "x" else self.R_y
        if r is not None:
            return r, "ideal posts: none" if self.source == "ideal" else f"{self.source} zero-order reflection"
        return np.clip(1.0 - np.abs(self.transmission(polarization)) ** 2, 0.0, 1.0), "1 - |t|^2 (upper bound)"

    @classmethod
    def ideal(cls, levels: int, *, period_um: float = 4.0, height_um: float = 10.0,
              wavelength_um: float = 10.0, polarization: str = "x") -> PostSet:
        """Exact phases 2 pi k / N, unit transmission, pass-through phase 0; widths a ramp.

        The widths (0.2 p .. 0.85 p along the focusing axis, 0.5 p along the other) are not physical
        phase responses; use this for layout and optics tests that need a valid post set.
        """
        n = check_int("levels", levels, 2, 256)
        period_um = check_positive("period_um", period_um, "um")
        ramp = np.linspace(0.2, 0.85, n) * period_um
        other = np.full(n, 0.5 * period_um)
        pol = check_choice("polarization", polarization, POLARIZATIONS)
        widths = np.stack([ramp, other], 1) if pol == "x" else np.stack([other, ramp], 1)
        phases = 2 * np.pi * np.arange(n) / n
        t_f = np.exp(1j * phases)
        t_p = np.ones(n, dtype=complex)
        t_x, t_y = (t_f, t_p) if pol == "x" else (t_p, t_f)
        return cls(pol, period_um, float(height_um), float(wavelength_um), widths, t_x, t_y,
                   source="ideal", info={"note": "ideal phases; widths are a ramp, not a physical design"},
                   R_x=np.zeros(n), R_y=np.zeros(n))

    def save(self, path: str | Path) -> Path:
        meta = {"type": "PostSet", "polarization": self.polarization, "period_um": self.period_um,
                "height_um": self.height_um, "wavelength_um": self.wavelength_um,
                "source": self.source, "info": self.info, "units": "um"}
        extra = {k: getattr(self, k) for k in ("R_x", "R_y") if getattr(self, k) is not None}
        return atomic_save_npz(path, meta, widths_um=self.widths_um, t_x=self.t_x, t_y=self.t_y, **extra)

    @classmethod
    def load(cls, path: str | Path, name: str = "path") -> PostSet:
        """Read a file written by :meth:`save`; errors name the file as ``name`` (a CLI passes its flag)."""
        arrays, meta = _load_checked(path, "PostSet", name)
        try:
            return cls(meta["polarization"], meta["period_um"], meta["height_um"], meta["wavelength_um"],
                       arrays["widths_um"], arrays["t_x"], arrays["t_y"], source=meta["source"],
                       info=meta.get("info", {}), R_x=arrays.get("R_x"), R_y=arrays.get("R_y"))
        except KeyError as e:
            raise InputError(name, str(path), "a PostSet file written by PostSet.save",
                             detail=f"missing {e.args[0]!r}") from None


def _load_checked(path: str | Path, kind: str, name: str = "path") -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """``load_npz`` of a file that must be a ``kind`` ('PostSet' or 'Library') file: anything else (a TOML
    passed by mistake, a truncated or pickled .npz) is an :class:`InputError`, not a numpy/zip traceback."""
    import zipfile

    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
    except OSError:
        magic = b"PK\x03\x04"  # let load_npz report a missing or unreadable file
    if magic != b"PK\x03\x04":
        raise InputError(name, str(path), f"a {kind} .npz file written by {kind}.save",
                         detail="not an .npz (zip) file") from None
    try:
        arrays, meta = load_npz(path, name)
    except InputError:
        raise
    except (ValueError, OSError, EOFError, KeyError, zipfile.BadZipFile, UnicodeDecodeError) as e:
        raise InputError(name, str(path), f"a {kind} .npz file written by {kind}.save",
                         detail=" ".join(str(e).split())[:120] or type(e).__name__) from None
    if not isinstance(meta, dict) or meta.get("type") != kind:
        raise InputError(name, str(path), f"a {kind} file written by {kind}.save")
    return arrays, meta


# ================================================================================================
# Scatterer library: RCWA sweep of (wx, wy) posts
# ================================================================================================
#
# Polarisation naming (the paper's text and equations disagree on "s" and "p"; we avoid both):
# 'x' is light with E along the lattice x axis, 'y' along y. The foveal lens focuses 'x' and passes
# 'y'; the perifoveal lens focuses 'y' and passes 'x'. (At normal incidence with azimuth 0, metafovea.rcwa
# calls x 'p' and y 's'.)
#
# Physical set-up (metafovea.rcwa.posts): Si posts on the Si wafer, air above; light enters through
# the wafer by default (posts face the sensor) so only the zero order is transmitted into air at 10 um.
# Phases are referenced at the post-layer faces; t is power normalised (|t|^2 = zero-order efficiency).

LIBRARY_ARRAYS = ("t_x", "t_y", "T_x", "T_y", "R_x", "R_y", "other_x", "other_y", "err_x", "err_y")
DEFAULT_HARMONICS = 10


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
    def load(cls, path: str | Path) -> Library:
        arrays, meta = _load_checked(path, "Library")
        try:
            return cls(arrays.pop("wx_um"), arrays.pop("wy_um"), arrays.pop("wavelengths_um"), arrays, meta)
        except KeyError as e:
            raise InputError("path", str(path), "a Library file written by Library.save",
                             detail=f"missing {e.args[0]!r}") from None


def width_grid(period_um: float = 4.0, step_um: float = 0.1, min_feature_um: float = 0.5, *,
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

    period_um: float = 4.0
    height_um: float = 10.0
    n_post: Any = 3.42
    n_surround: Any = 1.0
    n_substrate: Any = 3.42
    n_superstrate: Any = 1.0
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


def _checked_sweep(wx_um: Any, wy_um: Any, wavelengths_um: Any, opts: LibraryOptions) -> _Sweep:
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
                    wavelengths_um: Iterable[float] = (10.0,), *, options: LibraryOptions | None = None,
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
    lib = _cached_library(final) if opts.use_cache else None
    if lib is None and opts.use_cache:
        # one process computes, others (test workers, a second command) wait for its file
        with cache_lock(final):
            lib = _cached_library(final)
            if lib is None:
                lib = _run_sweep(sweep, opts, cdir / f"library-{sweep.key}.parts")
                lib.save(final)
                _remove_parts(cdir / f"library-{sweep.key}.parts")
    elif lib is None:
        lib = _run_sweep(sweep, opts, cdir / f"library-{sweep.key}.parts")
    _warn_convergence(lib, sweep.tol)
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


# ================================================================================================
# Birefringent post selection (the paper's Fig. 7c)
# ================================================================================================

def _wrap(a: np.ndarray) -> np.ndarray:
    """Wrap to (-pi, pi]."""
    return np.angle(np.exp(1j * a))


def _wavelength_index(lib: Library, wavelength_um: float | None) -> int:
    """Index of ``wavelength_um`` in the library (None: its only wavelength, else its design wavelength)."""
    if wavelength_um is None and lib.wavelengths_um.size == 1:
        return 0
    return lib.index_of_wavelength(float(lib.meta.get("design_wavelength_um", 10.0) if wavelength_um is None
                                         else wavelength_um))


def usable_posts(lib: Library, wavelength_um: float | None = None, *, max_error: float | None = 0.05) -> np.ndarray:
    """(n_wx, n_wy) bool: posts :func:`select_posts` may use at ``wavelength_um`` (finite t for both
    polarisations and, with ``max_error``, a convergence estimate of at most ``max_error``)."""
    il = _wavelength_index(lib, wavelength_um)
    ok = np.isfinite(lib.t_x[il]) & np.isfinite(lib.t_y[il])
    if max_error is not None:
        ok &= ~(np.fmax(lib.err_x[il], lib.err_y[il]) > max_error)
    return ok


def _fabricable(lib: Library, platform: PlatformDesign, WX: np.ndarray, WY: np.ndarray) -> np.ndarray:
    """(n_wx, n_wy) bool: posts that meet the platform's fabrication rules."""
    h = float(lib.meta.get("height_um", platform.post_height_um))
    fab = np.array([not platform.fabrication_violations([[a, b]], h) for a, b in zip(WX.ravel(), WY.ravel())])
    return fab.reshape(WX.shape)


#: the edge-bias cases of the tolerant selection and of :func:`bias_table`: name and sign of the per-side bias
BIAS_CASES = (("-", -1.0), ("0", 0.0), ("+", 1.0))
#: most coordinate-descent rounds of the joint search; a start whose round does not lower the cost stops (on the
#: paper's 31 x 31 library, 8 levels, the last of ~900 starts stops after 13-18 rounds)
JOINT_MAX_ROUNDS = 50
#: ends of the coordinate descent that the swap search of the joint search starts from (the best ones)
JOINT_POLISH = 8


def _candidates(lib: Library, wavelength_um: float | None, max_error: float | None, platform: PlatformDesign | None,
                N: int, WX: np.ndarray, WY: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """(n_wx, n_wy) bool masks of the usable (converged) posts and of those :func:`select_posts` may choose (usable
    and, with ``platform``, within its fabrication rules), and how many the rules excluded; fewer than ``N``
    candidates is an :class:`InputError`."""
    usable = usable_posts(lib, wavelength_um, max_error=max_error)
    ok = usable.copy()
    n_rules = 0
    if platform is not None:
        fab = _fabricable(lib, platform, WX, WY)  # posts that break a fabrication rule are never chosen
        n_rules = int(np.count_nonzero(ok & ~fab))
        ok &= fab
    if np.count_nonzero(ok) < N:
        raise InputError("library", int(np.count_nonzero(ok)), f"at least levels = {N} usable (converged) posts"
                         + (" that meet the platform's fabrication rules" if platform is not None else ""))
    return usable, ok, n_rules


def _wrap_fast(a: np.ndarray) -> np.ndarray:
    """Wrap to [-pi, pi) in real arithmetic, for squared costs (5x faster than :func:`_wrap`, which the nominal
    search keeps: its numbers must not move by a rounding)."""
    return np.mod(a + np.pi, 2 * np.pi) - np.pi


def _best_offsets(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of ``a`` (M, N) the phi that minimises ``sum_k wrap(a_k - phi)^2``, and that minimum, exactly:
    between the antipodes of the points the sum is a quadratic in phi and at an antipode it has a peak, so its
    minimum is the plain mean of one of the N unwrappings of the sorted angles (each starting at one of them)."""
    s = np.sort(np.mod(np.asarray(a, dtype=float), 2 * np.pi), axis=-1)
    n = s.shape[-1]
    # unwrapping j of a row starts at its j-th angle: the angles before it go up by 2 pi
    means = (s[:, None, :] + 2 * np.pi * (np.arange(n)[None, :] < np.arange(n)[:, None])).mean(-1)  # (M, N)
    cost = np.sum(_wrap_fast(s[:, None, :] - means[:, :, None]) ** 2, -1)
    j = np.argmin(cost, -1)
    rows = np.arange(s.shape[0])
    return _wrap(means[rows, j]), cost[rows, j]


def _biased_t(lib: Library, tf_all: np.ndarray, tp_all: np.ndarray, usable: np.ndarray, WX: np.ndarray,
              WY: np.ndarray, delta: float) -> tuple[np.ndarray, np.ndarray]:
    """(3, n_wx, n_wy) focusing and pass-through t of every library post in the cases of :data:`BIAS_CASES`
    (widths -2 delta, 0, +2 delta), the library interpolated bilinearly: exact where 2 delta is a multiple of the
    grid step (the biased posts are grid points, as for the paper's 50 nm on a 0.1 um grid). NaN where a biased
    post leaves the grid or needs a post that is not usable (not converged)."""
    out_f, out_p = [], []
    for _, sgn in BIAS_CASES:
        if sgn == 0:
            out_f.append(tf_all)
            out_p.append(tp_all)
            continue
        wx, wy = np.round(WX + sgn * 2 * delta, 9), np.round(WY + sgn * 2 * delta, 9)
        # every corner with weight must be usable (NaN outside the grid compares False)
        inside = _interp_t(lib, usable.astype(float), wx, wy).real > 1 - 1e-9
        for t_all, out in ((tf_all, out_f), (tp_all, out_p)):
            out.append(np.where(inside, _interp_t(lib, np.where(usable, t_all, 0), wx, wy), np.nan))
    return np.stack(out_f), np.stack(out_p)


def _offset_grid_search(af: np.ndarray, ap: np.ndarray, loss: np.ndarray, targets: np.ndarray, offs: np.ndarray,
                        pw: float) -> tuple[np.ndarray, np.ndarray]:
    """The nominal search: for each focusing offset ``offs[i]`` the best pass-through offset on the same grid, its
    total cost ``vals[i]`` and each level's post ``choices[i]`` (argmin of the per-level cost)."""
    cp = pw * _wrap(ap[None, :] - offs[:, None]) ** 2 + loss[None, :]  # pass-through cost for every psi: (n_off, C)
    vals = np.empty(offs.size)
    choices = np.empty((offs.size, targets.size), dtype=int)
    for i0, phi0 in enumerate(offs):
        cf = _wrap(af[None, :] - phi0 - targets[:, None]) ** 2          # (N, C)
        tot = cf[None, :, :] + cp[:, None, :]                            # (n_off psi, N, C)
        idx = np.argmin(tot, axis=-1)                                    # (n_off, N)
        val = np.take_along_axis(tot, idx[..., None], -1)[..., 0].sum(-1)
        j = int(np.argmin(val))
        vals[i0], choices[i0] = val[j], idx[j]
    return vals, choices


@dataclass(frozen=True)
class _JointCost:
    """The joint cost of :func:`select_posts` over the bias cases: candidates' phases ``af``, ``ap`` and
    transmission losses ``loss`` (each (3, C), cases in :data:`BIAS_CASES` order), case weights ``wts``."""

    af: np.ndarray
    ap: np.ndarray
    loss: np.ndarray
    targets: np.ndarray
    pw: float
    wts: tuple[float, float, float]

    def best_posts(self, offsets: np.ndarray, chunk: int = 64) -> np.ndarray:
        """(M, N) each level's cheapest candidate for each row of case offsets ``(phi_b, psi_b)`` (M, 3, 2); a
        candidate's cost at level k is the sum over cases of
        ``w_b [wrap(arg t_f - phi_b - 2 pi k/N)^2 + pw wrap(arg t_p - psi_b)^2 + loss]``."""
        out = np.empty((offsets.shape[0], self.targets.size), dtype=int)
        for i in range(0, offsets.shape[0], chunk):
            off = offsets[i:i + chunk]
            cost = np.zeros((off.shape[0], self.targets.size, self.af.shape[1]))
            for b, w in enumerate(self.wts):
                cost += w * _wrap_fast(self.af[b] - off[:, b, 0, None, None] - self.targets[:, None]) ** 2
                cost += w * (self.pw * _wrap_fast(self.ap[b] - off[:, b, 1, None]) ** 2 + self.loss[b])[:, None, :]
            out[i:i + chunk] = np.argmin(cost, -1)
        return out

    def of(self, choices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The cost (M,) of each row of ``choices`` (M, N candidate indices) with each case's best offsets (exact),
        and those offsets (M, 3, 2)."""
        cost = np.zeros(choices.shape[0])
        offsets = np.zeros((choices.shape[0], len(self.wts), 2))
        for b, w in enumerate(self.wts):
            offsets[:, b, 0], f = _best_offsets(self.af[b][choices] - self.targets[None, :])
            offsets[:, b, 1], p = _best_offsets(self.ap[b][choices])
            cost += w * (f + self.pw * p + self.loss[b][choices].sum(-1))
        return cost, offsets

    def descend(self, choices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Coordinate descent from each row of ``choices`` (M, N candidate indices): the cases' offsets for the
        chosen posts (exact), then each level's post for those offsets (exact), while the cost falls (so it ends);
        the ends (M, N) and their costs (M,)."""
        choices = np.array(choices, dtype=int)
        cost, off = self.of(choices)
        active = np.arange(choices.shape[0])
        for _ in range(JOINT_MAX_ROUNDS):
            if active.size == 0:
                break
            new = self.best_posts(off[active])
            new_cost, new_off = self.of(new)
            down = new_cost < cost[active]
            moved = active[down]
            choices[moved], cost[moved], off[moved] = new[down], new_cost[down], new_off[down]
            active = moved
        return choices, cost

    def swap(self, choice: np.ndarray, cost: float) -> tuple[np.ndarray, float]:
        """Local search from ``choice``: the best change of one level's post (every level, every candidate, the
        offsets re-optimised), then coordinate descent, while the cost falls; the end and its cost."""
        n, n_c = choice.size, self.af.shape[1]
        for _ in range(JOINT_MAX_ROUNDS):
            trial = np.repeat(choice[None, :], n * n_c, 0)
            trial[np.arange(n * n_c), np.repeat(np.arange(n), n_c)] = np.tile(np.arange(n_c), n)
            costs = self.of(trial)[0]
            i = int(np.argmin(costs))
            if not costs[i] < cost - 1e-12:
                break
            ends, end_cost = self.descend(trial[i:i + 1])
            choice, cost = ends[0], float(end_cost[0])
        return choice, float(cost)

    def search(self, starts: np.ndarray, n_polish: int = JOINT_POLISH) -> dict[str, Any]:
        """The lowest cost found: coordinate descent from every start (rows of ``starts``, N candidate indices each;
        repeated rows once) and from each candidate as the anchor of level 0 (its own phases in every case as the
        offsets: the optimum's offsets lie within the residuals of each of its posts), then the swap search
        from the ``n_polish`` best ends. The first start wins a tie."""
        anchors = self.best_posts(np.stack([self.af, self.ap], -1).transpose(1, 0, 2))
        rows = np.concatenate([np.asarray(starts, dtype=int).reshape(-1, self.targets.size), anchors])
        rows = rows[np.sort(np.unique(rows, axis=0, return_index=True)[1])]
        ends, cost = self.descend(rows)
        first = np.sort(np.unique(ends, axis=0, return_index=True)[1])  # each distinct end at its first start
        best = first[np.argsort(cost[first], kind="stable")[:n_polish]]
        polished = [self.swap(ends[i], float(cost[i])) for i in best]
        k = min(range(len(polished)), key=lambda j: polished[j][1])
        return {"cost": polished[k][1], "choice": polished[k][0], "starts": int(rows.shape[0]), "ends": int(first.size),
                "polished": int(best.size)}


def _case_figures(tf: np.ndarray, tp: np.ndarray, targets: np.ndarray) -> dict[str, Any]:
    """Figures of merit of N posts in one bias case: focusing phase error after removing the shift common to all
    levels (a lens does not see it; ``shift_rad``), expected focusing efficiency, pass-through phase about its
    mean (per level and its spread) and mean transmissions."""
    shift = np.angle(np.sum(np.exp(1j * (np.angle(tf) - targets))))
    err = _wrap(np.angle(tf) - shift - targets)
    pp = _wrap(np.angle(tp) - np.angle(np.mean(tp)))
    return {"rms_phase_error_rad": float(np.sqrt(np.mean(err ** 2))),
            "max_abs_phase_error_rad": float(np.max(np.abs(err))),
            "expected_focusing_efficiency": float(abs(np.mean(tf * np.exp(-1j * targets))) ** 2
                                                  * np.sinc(1.0 / targets.size) ** 2),
            "pass_phase_spread_rad": float(np.max(pp) - np.min(pp)),
            "mean_T_focus": float(np.mean(np.abs(tf) ** 2)), "mean_T_pass": float(np.mean(np.abs(tp) ** 2)),
            "shift_rad": float(shift), "phase_error_rad": err.tolist(), "pass_phase_rad": pp.tolist()}


def _tolerance_info(tf3: np.ndarray, tp3: np.ndarray, targets: np.ndarray, delta: float, bias_weight: float,
                    n_excluded: int, search: dict[str, Any] | None) -> dict[str, Any]:
    """``info['tolerance']`` of a selection: the chosen posts' figures in each bias case (tf3, tp3: (3, N)) as the
    library's interpolation sees them (None for a case whose biased posts leave the library), the worst case, and
    the joint search's cost (and that of the nominal choice), its starts, distinct descent ends and polished ends."""
    cases: dict[str, Any] = {}
    for b, (name, _) in enumerate(BIAS_CASES):
        ok = bool(np.all(np.isfinite(tf3[b])) and np.all(np.isfinite(tp3[b])))
        cases[name] = {k: v for k, v in _case_figures(tf3[b], tp3[b], targets).items() if k != "shift_rad"} if ok else None
    done = [c for c in cases.values() if c is not None]
    out = {"delta_um": delta, "bias_weight": bias_weight, "case_weights": {"-": bias_weight, "0": 1.0, "+": bias_weight},
           "source": "library, bilinear (exact where 2 delta is a multiple of the grid step)", "cases": cases,
           "worst_expected_focusing_efficiency": min(c["expected_focusing_efficiency"] for c in done),
           "worst_rms_phase_error_rad": max(c["rms_phase_error_rad"] for c in done),
           "worst_max_abs_phase_error_rad": max(c["max_abs_phase_error_rad"] for c in done),
           "worst_pass_phase_spread_rad": max(c["pass_phase_spread_rad"] for c in done),
           "posts_excluded": n_excluded}
    if search is not None:
        out.update(joint_cost=search["cost"], nominal_choice_joint_cost=search["start_cost"], starts=search["starts"],
                   descent_ends=search["ends"], polished=search["polished"])
    return out


def select_posts(lib: Library, polarization: str, levels: int = 8, *, wavelength_um: float | None = None,
                 pass_weight: float = 1.0, transmission_weight: float = 0.5, max_error: float | None = 0.05,
                 n_offsets: int = 72, platform: PlatformDesign | None = None,
                 bias_weight: float = 0.0) -> PostSet:
    """Choose ``levels`` posts for the lens that focuses ``polarization``.

    Level k must give the focusing polarisation the phase ``phi0 + 2 pi k / N`` (phi0 free), while the
    pass-through polarisation keeps a phase ``psi`` (free) as constant as possible and both
    transmissions are high. For every (phi0, psi) on an ``n_offsets`` x ``n_offsets`` grid each level
    takes the post minimising

        wrap(arg t_f - phi0 - 2 pi k/N)^2 + pass_weight * wrap(arg t_p - psi)^2
        + transmission_weight * ((1 - |t_f|^2) + (1 - |t_p|^2))

    and the (phi0, psi) with the smallest total wins. Posts whose convergence estimate exceeds
    ``max_error`` are not used. The stored t are rotated by the offsets (``t_f e^{-i phi0}``,
    ``t_p e^{-i psi}``), so level k has arg t_focus ~ 2 pi k / N; the offsets and figures of merit are
    in ``info``: per-level phase errors (rad), pass-through phase spread (max - min, rad, and rms),
    zero-order efficiencies, and the expected focusing efficiency
    ``|mean_k t_f,k e^{-i 2 pi k/N}|^2 sinc^2(1/N)`` (equal-area levels; the sinc is the N-level
    quantisation loss) and pass-through coherent transmission ``|mean_k t_p,k|^2``.

    With ``platform``, posts that break its fabrication rules are not used, and ``info['tolerance']`` gives the
    chosen posts in the three cases of its edge bias delta = ``edge_bias_um`` per side (widths -2 delta, 0,
    +2 delta; :data:`BIAS_CASES`) as the library sees them (:func:`bias_table` solves them by RCWA).

    ``bias_weight`` = w > 0 (with such a platform) chooses jointly over the three cases: the cost is the sum over
    the cases of the cost above, each case with its own t (the biased posts) and its own free offsets
    (phi0_b, psi_b) (a shift common to all levels does no harm), the nominal case weighted 1, each biased one w.
    Posts whose biased widths leave the library are not used (``info['tolerance']['posts_excluded']``). It is
    minimised by coordinate descent (each case's offsets for the chosen posts, exactly; then each level's post for
    those offsets, exactly; while the cost falls) from the grid search's best psi of each phi0 and from every post
    as the anchor of level 0, then a one-post swap search from the best ends (on small libraries: the exhaustive
    optimum). The trade-off on the paper's library (RCWA at the biased widths, BENCHMARKS.md): w >= 0.5 raises the
    worst biased focusing efficiency from 0.623 to 0.639 and lowers the worst biased rms phase error from 0.32 to
    0.23 rad for 0.020 of nominal efficiency (0.699 -> 0.679); w = 0.11-0.25: 0.641 and 0.25 rad for 0.013; below
    0.11 the nominal choice. w = 0 (the default) is the nominal grid search alone.
    """
    pol = check_choice("polarization", polarization, POLARIZATIONS)
    N = check_int("levels", levels, 2, 64)
    pw = check_range("pass_weight", pass_weight, 0.0, None, lo_inclusive=True)
    tw = check_range("transmission_weight", transmission_weight, 0.0, None, lo_inclusive=True)
    n_off = check_int("n_offsets", n_offsets, 4, 720)
    bias_weight = check_range("bias_weight", bias_weight, 0.0, None, lo_inclusive=True)
    il = _wavelength_index(lib, wavelength_um)
    tf_all = (lib.t_x if pol == "x" else lib.t_y)[il]
    tp_all = (lib.t_y if pol == "x" else lib.t_x)[il]
    WX, WY = np.meshgrid(lib.wx_um, lib.wy_um, indexing="ij")
    usable, ok, n_rules = _candidates(lib, wavelength_um, max_error, platform, N, WX, WY)
    delta = 0.0 if platform is None else platform.edge_bias_um
    tf3 = tp3 = None
    n_bias = 0
    if delta > 0:
        tf3, tp3 = _biased_t(lib, tf_all, tp_all, usable, WX, WY, delta)
        if bias_weight > 0:  # the joint search needs every case of every candidate
            inside = np.all(np.isfinite(tf3) & np.isfinite(tp3), axis=0)
            n_bias = int(np.count_nonzero(ok & ~inside))
            ok &= inside
            if np.count_nonzero(ok) < N:
                raise InputError("edge_bias_um", delta, f"a bias that leaves at least levels = {N} posts inside the library")
    tf, tp = tf_all[ok], tp_all[ok]
    wxc, wyc = WX[ok], WY[ok]
    specular = _specular(lib, il, ok)
    af, ap = np.angle(tf), np.angle(tp)
    loss = tw * ((1 - np.abs(tf) ** 2) + (1 - np.abs(tp) ** 2))
    targets = 2 * np.pi * np.arange(N) / N
    offs = 2 * np.pi * np.arange(n_off) / n_off
    vals, choices = _offset_grid_search(af, ap, loss, targets, offs, pw)
    choice = choices[int(np.argmin(vals))]
    search = None
    if tf3 is not None and bias_weight > 0:
        tfc, tpc = tf3[:, ok], tp3[:, ok]
        joint = _JointCost(np.angle(tfc), np.angle(tpc), tw * ((1 - np.abs(tfc) ** 2) + (1 - np.abs(tpc) ** 2)),
                           targets, pw, (bias_weight, 1.0, bias_weight))
        search = {**joint.search(choices[np.argsort(vals, kind="stable")]), "start_cost": float(joint.of(choice[None])[0][0])}
        choice = search["choice"]
    tfs, tps, figures = _rotated_figures(tf[choice], tp[choice], targets)
    widths = np.stack([wxc[choice], wyc[choice]], 1)
    t_x, t_y = (tfs, tps) if pol == "x" else (tps, tfs)
    info = {
        "method": ("grid search over (phi0, psi); per-level argmin of phase + pass + transmission cost" if search is None
                   else "joint search over the -delta/0/+delta edge-bias cases (each with free offsets; biased cases "
                        "weighted bias_weight): coordinate descent from the grid search's best psi of each phi0 and "
                        "from every post as the anchor of level 0, then a one-post swap search from the best ends"),
        "wavelength_um": float(lib.wavelengths_um[il]), "levels": N, **figures,
        "weights": {"pass": pw, "transmission": tw}, "max_error": max_error,
        "bias_weight": bias_weight,
        "tolerance": None if tf3 is None else _tolerance_info(
            tf3[:, ok][:, choice], tp3[:, ok][:, choice], targets, delta, bias_weight, n_bias, search),
        "fabrication_rules": None if platform is None else {
            "min_feature_um": platform.min_feature_um,
            "min_gap_um": platform.min_feature_um if platform.min_gap_um is None else platform.min_gap_um,
            "max_aspect_ratio": platform.max_aspect_ratio, "posts_excluded": n_rules},
        "library_key": lib.meta.get("key"), "harmonics": lib.meta.get("harmonics"),
        "incidence": lib.meta.get("incidence"),
    }
    return PostSet(pol, float(lib.meta.get("period_um", 4.0)), float(lib.meta.get("height_um", 10.0)),
                   float(lib.wavelengths_um[il]), widths, t_x, t_y, source="rcwa", info=info,
                   R_x=None if specular["x"] is None else specular["x"][choice],
                   R_y=None if specular["y"] is None else specular["y"][choice])


def _rotated_figures(tf: np.ndarray, tp: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
    """The chosen posts' t (N,) rotated by their offsets (circular means: arg t_f ~ 2 pi k / N, arg t_p ~ 0) and
    the figures of merit :func:`select_posts` puts in ``info``."""
    phi0 = float(np.angle(np.sum(np.exp(1j * (np.angle(tf) - targets)))))
    psi = float(np.angle(np.sum(np.exp(1j * np.angle(tp)))))
    tfs = tf * np.exp(-1j * phi0)
    tps = tp * np.exp(-1j * psi)
    ph_err = _wrap(np.angle(tfs) - targets)
    pass_ph = _wrap(np.angle(tps))
    return tfs, tps, {
        "phase_offset_focus_rad": phi0 % (2 * np.pi), "phase_offset_pass_rad": psi % (2 * np.pi),
        "phase_error_rad": ph_err.tolist(), "max_abs_phase_error_rad": float(np.max(np.abs(ph_err))),
        "rms_phase_error_rad": float(np.sqrt(np.mean(ph_err ** 2))),
        "pass_phase_rad": pass_ph.tolist(),
        "pass_phase_spread_rad": float(np.max(pass_ph) - np.min(pass_ph)),
        "pass_phase_rms_rad": float(np.sqrt(np.mean(pass_ph ** 2))),
        "T_focus": (np.abs(tfs) ** 2).tolist(), "T_pass": (np.abs(tps) ** 2).tolist(),
        "mean_T_focus": float(np.mean(np.abs(tfs) ** 2)), "mean_T_pass": float(np.mean(np.abs(tps) ** 2)),
        "expected_focusing_efficiency": float(abs(np.mean(tfs * np.exp(-1j * targets))) ** 2
                                              * np.sinc(1.0 / targets.size) ** 2),
        "pass_coherent_transmission": float(abs(np.mean(tps)) ** 2)}


def _specular(lib: Library, il: int, ok: np.ndarray) -> dict[str, np.ndarray | None]:
    """Per polarisation the candidates' specular reflection back into the entry side, None for a library without
    reflections (hand-made: :meth:`PostSet.reflectance` bounds it). Entering through the wafer, 'other' is the
    reflected higher orders (only the zero order exists in air), so R_00 = R - other; entering from air, R is
    specular."""
    specular: dict[str, np.ndarray | None] = {}
    for q in POLARIZATIONS:
        if f"R_{q}" not in lib.arrays or f"other_{q}" not in lib.arrays:
            specular[q] = None
            continue
        R_all, oth_all = lib.arrays[f"R_{q}"][il], lib.arrays[f"other_{q}"][il]
        spec = R_all if lib.meta.get("incidence") == "superstrate" else R_all - oth_all
        specular[q] = np.clip(np.nan_to_num(spec[ok]), 0.0, 1.0)
    return specular


def _interp_t(lib: Library, t: np.ndarray, wx: np.ndarray, wy: np.ndarray) -> np.ndarray:
    """Complex ``t`` on the library's (wx, wy) grid at other widths (bilinear in the real and imaginary parts);
    NaN outside the grid."""
    from scipy.interpolate import RegularGridInterpolator

    pts = np.stack([np.ravel(wx), np.ravel(wy)], -1)
    grid = (lib.wx_um, lib.wy_um)
    re = RegularGridInterpolator(grid, np.real(t), bounds_error=False, fill_value=np.nan)(pts)
    im = RegularGridInterpolator(grid, np.imag(t), bounds_error=False, fill_value=np.nan)(pts)
    return (re + 1j * im).reshape(np.shape(wx))


def _solve_like(lib: Library, wx: np.ndarray, wy: np.ndarray, wavelength_um: float) -> tuple[np.ndarray, np.ndarray]:
    """(t_x, t_y) of posts (wx, wy), solved by RCWA with the library's stack and settings (its cache meta)."""
    from metafovea.rcwa.posts import post_response

    m = lib.meta

    def idx(name: str, default: float) -> complex:
        v = m.get(name)
        return complex(v[0], v[1]) if isinstance(v, (list, tuple)) else complex(default if v is None else v)

    kw = {}
    for name, default in (("n_post", 3.42), ("n_surround", 1.0), ("n_substrate", 3.42), ("n_superstrate", 1.0)):
        v = idx(name, default)
        kw[name] = v.real if v.imag == 0 else v
    r = post_response(np.asarray(wx), np.asarray(wy), wavelength_um, period_um=float(m.get("period_um", 4.0)),
                      height_um=float(m.get("height_um", 10.0)), harmonics=int(m.get("harmonics", DEFAULT_HARMONICS)),
                      factorization=m.get("factorization", "li"), incidence=m.get("incidence", "substrate"), **kw)
    return r.t_x, r.t_y


def bias_table(lib: Library, widths_um: np.ndarray, polarization: str, delta_um: float, il: int = 0) -> dict[str, Any]:
    """How posts ``widths_um`` (N, 2) respond to a uniform edge bias of -delta, 0, +delta per side (widths -2 delta,
    0, +2 delta), each post solved by RCWA with the library's settings: per level the focusing and pass-through
    phase error after removing the common shift (which a lens does not see), and per bias the expected focusing
    efficiency and the pass-through phase spread."""
    N = widths_um.shape[0]
    wl = float(lib.wavelengths_um[il])
    targets = 2 * np.pi * np.arange(N) / N
    w_all = np.concatenate([widths_um + sgn * 2 * delta_um for _, sgn in BIAS_CASES])
    tx, ty = _solve_like(lib, w_all[:, 0], w_all[:, 1], wl)
    tf_all, tp_all = (tx, ty) if polarization == "x" else (ty, tx)
    rows, summary = [], {}
    ph0 = float(np.angle(np.sum(np.exp(1j * (np.angle(tf_all[N:2 * N]) - targets)))))  # the offset select_posts removes
    for j, (name, _) in enumerate(BIAS_CASES):
        f = _case_figures(tf_all[j * N:(j + 1) * N], tp_all[j * N:(j + 1) * N], targets)
        summary[name] = {k: f[k] for k in ("rms_phase_error_rad", "max_abs_phase_error_rad")}
        summary[name].update(common_shift_rad=float(_wrap(np.array(f["shift_rad"] - ph0))),
                             expected_focusing_efficiency=f["expected_focusing_efficiency"],
                             pass_phase_spread_rad=f["pass_phase_spread_rad"])
        rows.append({"bias": name, "phase_error_rad": f["phase_error_rad"], "pass_phase_rad": f["pass_phase_rad"]})
    return {"delta_um": delta_um, "per_bias": summary, "levels": rows, "method": "RCWA at the biased widths"}


def postset_table(ps: PostSet) -> list[dict[str, float]]:
    """Per-level rows (for `metafovea design` and reports): widths, phases, transmissions."""
    rows = []
    for k in range(ps.levels):
        rows.append({"level": k, "wx_um": float(ps.widths_um[k, 0]), "wy_um": float(ps.widths_um[k, 1]),
                     "target_phase_rad": float(2 * np.pi * k / ps.levels),
                     "phase_focus_rad": float(np.angle(ps.t_focus[k]) % (2 * np.pi)),
                     "T_focus": float(abs(ps.t_focus[k]) ** 2),
                     "phase_pass_rad": float(np.angle(ps.t_pass[k])), "T_pass": float(abs(ps.t_pass[k]) ** 2)})
    return rows


@dataclass(frozen=True)
class PlatformSweep:
    """The library of a platform and the post sets chosen from it: what to sweep, checked on construction.

    Parameters
    ----------
    platform : PlatformDesign
        The stack (period, post height, indices), the min feature that bounds the width grid and the design
        wavelength the posts are chosen at.
    levels : int
        Phase levels per lens (2..64).
    grid_step_um : float, um
        Step of the width grid, from the min feature to ``period - min feature`` on both axes.
    wavelengths_um : tuple of float, um, optional
        Wavelengths to sweep (default: the platform's design wavelength). The posts are chosen at the design
        wavelength when it is swept, else at the first one.
    options : LibraryOptions
        Solver and run settings; the stack is always the platform's.
    source : str, optional
        Where the platform came from (its file), named in errors about it.
    bias_weight : float
        Weight of the platform's +-``edge_bias_um`` cases in the post selection (:func:`select_posts`; 0: the
        nominal selection).
    """

    platform: PlatformDesign = field(default_factory=PlatformDesign)
    levels: int = 8
    grid_step_um: float = 0.1
    wavelengths_um: tuple[float, ...] | None = None
    options: LibraryOptions = field(default_factory=LibraryOptions)
    source: str | None = None
    bias_weight: float = 0.0

    def __post_init__(self) -> None:
        plat = self.platform
        if not plat.min_feature_um < plat.period_um / 2:
            raise InputError("min_feature_um", plat.min_feature_um,
                             f"0 < min_feature_um < period_um / 2 = {plat.period_um / 2:g} um (posts and gaps both "
                             "at least the min feature)", source=self.source)
        check_int("levels", self.levels, 2, 64)
        if check_range("bias_weight", self.bias_weight, 0.0, None, lo_inclusive=True) > 0 and plat.edge_bias_um == 0:
            raise InputError("bias_weight", self.bias_weight, "0 for a platform with edge_bias_um = 0 (no bias to "
                             "tolerate)", source=self.source)
        if self.wavelengths_um is not None:
            object.__setattr__(self, "wavelengths_um", tuple(
                check_positive("wavelengths_um", w, "um", hi=1e4) for w in self.wavelengths_um))
        width_grid(plat.period_um, self.grid_step_um, plat.min_feature_um)  # the grid step, before any work

    @property
    def widths_um(self) -> np.ndarray:
        """The width grid (the same on both axes)."""
        plat = self.platform
        return width_grid(plat.period_um, self.grid_step_um, plat.min_feature_um)

    @property
    def wavelengths(self) -> tuple[float, ...]:
        return self.wavelengths_um or (float(self.platform.wavelength_um),)

    @property
    def design_wavelength_um(self) -> float:
        """The wavelength the posts are chosen at."""
        wl = float(self.platform.wavelength_um)
        return wl if wl in self.wavelengths else self.wavelengths[0]

    def library(self) -> Library:
        """The swept library (computed once, then loaded from the cache)."""
        return compute_library(self.widths_um, None, self.wavelengths,
                               options=self.options.with_platform(self.platform))

    def select(self, lib: Library) -> dict[str, PostSet]:
        """Both post sets, ``{'x': foveal lens' set, 'y': perifoveal lens' set}``.

        Too few converged posts for ``levels`` is an :class:`InputError` on ``levels`` that says what to change.
        """
        wl = self.design_wavelength_um
        n_ok = int(np.count_nonzero(usable_posts(lib, wl)))
        if n_ok < self.levels:
            plat = self.platform
            diffracts = (f" (the wavelength is not above the period {plat.period_um:g} um: the posts diffract, "
                         "not a zero-order library)" if wl <= plat.period_um * plat.n_superstrate else "")
            raise InputError("levels", self.levels,
                             f"at most the {n_ok} of {lib.wx_um.size} x {lib.wy_um.size} posts converged at {wl:g} um "
                             "(convergence estimate <= 0.05): use more --harmonics, a finer --grid-step-um or fewer "
                             f"--levels{diffracts}")
        return {pol: select_posts(lib, pol, self.levels, wavelength_um=wl, platform=self.platform,
                                  bias_weight=self.bias_weight) for pol in POLARIZATIONS}


def platform_post_sets(platform: PlatformDesign | None = None, levels: int = 8, *, grid_step_um: float = 0.1,
                       wavelengths_um: Sequence[float] | None = None, options: LibraryOptions | None = None,
                       bias_weight: float = 0.0, **overrides: Any) -> tuple[dict[str, PostSet], Library]:
    """The library of a platform (computed once, then loaded from the cache) and both post sets.

    See :class:`PlatformSweep`. The paper's library (the defaults, 31 x 31 widths at 10 harmonics) takes ~35 s on 2
    cores on a first run; the workers are separate processes, so a script calling this needs the usual
    ``if __name__ == "__main__":`` guard.

    Parameters
    ----------
    platform : PlatformDesign, optional
        The stack and fabrication rules (default: the paper's ``PlatformDesign()``).
    levels : int
        Phase levels per lens.
    grid_step_um : float, um
        Step of the width grid on both axes (from the min feature to ``period - min feature``).
    wavelengths_um : sequence of float, um, optional
        Wavelengths to sweep (default: the platform's design wavelength).
    options : LibraryOptions, optional
        Solver and run settings (default: ``LibraryOptions(progress=False)``).
    bias_weight : float
        Weight of the platform's +-edge-bias cases in the selection (see :func:`select_posts`).
    **overrides
        Fields of :class:`LibraryOptions` that replace those of ``options`` (``harmonics=5, cache_dir=...``).

    Returns
    -------
    post_sets : dict of {'x', 'y'} to PostSet
        The x set is the foveal lens', the y set the perifoveal lens' (each lens focuses its own polarisation and
        passes the other).
    library : Library
        The swept library (transmissions ``(n_wavelengths, n_wx, n_wy)`` per polarisation).
    """
    opts = replace(options if options is not None else LibraryOptions(progress=False), **overrides)
    sweep = PlatformSweep(platform if platform is not None else PlatformDesign(), levels, grid_step_um,
                          None if wavelengths_um is None else tuple(wavelengths_um), opts, bias_weight=bias_weight)
    lib = sweep.library()
    return sweep.select(lib), lib


#: what :func:`system_post_sets` accepts for ``posts``
POST_SOURCES = ("rcwa", "ideal")


def system_post_sets(system: Any, posts: Any = "rcwa", *, options: LibraryOptions | None = None
                     ) -> tuple[dict[str, PostSet], str]:
    """Both lenses' post sets ``{'x': ..., 'y': ...}`` of a :class:`~metafovea.config.SystemDesign` and their
    source: ``'rcwa'`` (the platform's RCWA library, computed once and cached: the fabricated lenses; the
    default), ``'ideal'`` (:meth:`PostSet.ideal`: a simplified model), or a dict of PostSets given (named by their
    common ``source``)."""
    lenses = (system.foveal, system.perifoveal)
    if isinstance(posts, dict):
        for lens in lenses:
            ps = posts.get(lens.polarization)
            if not isinstance(ps, PostSet) or ps.polarization != lens.polarization or ps.levels != lens.levels:
                raise InputError("posts", sorted(posts), f"a PostSet for the {lens.name} lens ('{lens.polarization}', "
                                 f"{lens.levels} levels) under key '{lens.polarization}'")
        srcs = {posts[lens.polarization].source for lens in lenses}
        return {lens.polarization: posts[lens.polarization] for lens in lenses}, srcs.pop() if len(srcs) == 1 else "given"
    src = check_choice("posts", posts, POST_SOURCES)
    if src == "ideal":
        return {lens.polarization: PostSet.ideal(lens.levels, period_um=lens.period_um, height_um=lens.post_height_um,
                                                 wavelength_um=lens.wavelength_um, polarization=lens.polarization)
                for lens in lenses}, "ideal"
    sets = rcwa_post_sets(system.platform, lenses, options=options)
    return {lens.polarization: sets[(lens.polarization, lens.levels)] for lens in lenses}, "rcwa"


def rcwa_post_sets(platform: PlatformDesign, lenses: Iterable[Any], *, options: LibraryOptions | None = None
                   ) -> dict[tuple[str, int], PostSet]:
    """The platform's RCWA post set for each lens' (polarisation, levels): one library, one selection per number
    of levels."""
    out: dict[tuple[str, int], PostSet] = {}
    for lens in lenses:
        key = (lens.polarization, lens.levels)
        if key not in out:
            sets, _ = platform_post_sets(platform, lens.levels, options=options)
            out.update({(pol, lens.levels): ps for pol, ps in sets.items()})
    return out


# ================================================================================================
# Oblique incidence: the chosen posts' response off axis
# ================================================================================================
#: field angles in air (deg) at which the posts are solved off axis; between them the ratio is interpolated in
#: angle^2 (the change is quadratic at small angles), beyond the last one it is extrapolated that way
OBLIQUE_ANGLES_DEG = (0.0, 6.0, 11.0, 16.0)
#: Fourier orders of the oblique solves: only the ratio t(theta) / t(0) at the same truncation is used, which
#: converges much faster than t itself (harmonics 5 is within 5e-4 of harmonics 8 for the paper's posts)
OBLIQUE_HARMONICS = 5


@dataclass(frozen=True)
class ObliqueResponse:
    """How a post set's transmissions change off axis, as the ratio ``t(theta) / t(0)`` per level.

    ``ratio``: ``{'x' | 'y': (n_angles, 2, N) complex}`` for x/y-polarised light, plane of incidence xz (index
    0: the field along x) or yz (index 1); angles in air (``angles_deg``), the light entering through the wafer
    (refracted to ``asin(sin theta / n_Si)``). ``error``: the larger of max |ratio(M) - ratio(M - 1)| (truncation)
    and the interpolation's error at the midpoints of the upper segments (solved there).
    """

    angles_deg: np.ndarray
    ratio: dict[str, np.ndarray]
    error: float
    harmonics: int

    def factor(self, polarization: str, theta_deg: Any, azimuth_rad: Any = 0.0) -> np.ndarray:
        """``(..., N)`` ratio at field angle(s) ``theta_deg`` and azimuth(s) of the plane of incidence (from +x):
        interpolated in ``theta^2`` between the solved angles, the two planes blended as ``cos^2 / sin^2`` of
        the azimuth (exact in the planes, second order between them)."""
        r = self.ratio[check_choice("polarization", polarization, POLARIZATIONS)]
        th2 = np.square(np.asarray(theta_deg, dtype=float))[..., None]
        a2 = self.angles_deg ** 2
        out = []
        for plane in (0, 1):
            re = np.stack([np.interp(th2[..., 0], a2, r[:, plane, k].real) for k in range(r.shape[2])], -1)
            im = np.stack([np.interp(th2[..., 0], a2, r[:, plane, k].imag) for k in range(r.shape[2])], -1)
            # beyond the last angle: continue the last segment's slope in theta^2
            over = th2[..., 0] > a2[-1]
            if np.any(over):
                slope = (r[-1, plane] - r[-2, plane]) / (a2[-1] - a2[-2])
                ext = r[-1, plane] + (th2 - a2[-1]) * slope
                re = np.where(over[..., None], ext.real, re)
                im = np.where(over[..., None], ext.imag, im)
            out.append(re + 1j * im)
        c2 = np.cos(np.asarray(azimuth_rad, dtype=float))[..., None] ** 2
        return c2 * out[0] + (1 - c2) * out[1]

    def post_set_at(self, post_set: PostSet, theta_deg: float, azimuth_rad: float = 0.0) -> PostSet:
        """``post_set`` with its transmissions at that field (reflectances kept)."""
        fx = self.factor("x", theta_deg, azimuth_rad)
        fy = self.factor("y", theta_deg, azimuth_rad)
        return replace(post_set, t_x=post_set.t_x * fx, t_y=post_set.t_y * fy,
                       info={**post_set.info, "oblique_incidence_deg": float(theta_deg)})


def _oblique_ratios(widths_um: np.ndarray, platform: PlatformDesign, angles_deg: Sequence[float], wavelength_um: float,
                    harmonics: int) -> np.ndarray:
    """(n_angles, 2 planes, 2 pols, N) ratios t(theta) / t(0) of posts ``widths_um`` (N, 2)."""
    from tqdm.auto import tqdm

    from metafovea.rcwa.geometry import Layer, Rectangle, Stack
    from metafovea.rcwa.solve import solve

    n_sub = platform.n_substrate
    out = np.ones((len(angles_deg), 2, 2, widths_um.shape[0]), complex)
    for k, (wx, wy) in enumerate(tqdm(widths_um, desc=f"posts off axis (M={harmonics})", unit="post", leave=False,
                                      disable=None)):
        st = Stack(platform.period_um, platform.period_um,
                   (Layer(platform.post_height_um, platform.n_superstrate, (Rectangle(wx, wy, platform.n_post),)),),
                   n_sub, platform.n_superstrate)

        def jones(theta_air: float, phi: float) -> np.ndarray:
            th = math.degrees(math.asin(math.sin(math.radians(theta_air)) / n_sub))
            return solve(st, wavelength_um, harmonics=harmonics, theta_deg=th, phi_deg=phi, incidence="substrate",
                         check_energy=False).t00("substrate")

        j0 = jones(0.0, 0.0)  # (p, s) = (x, y) at normal incidence
        for i, th in enumerate(angles_deg):
            if th == 0.0:
                continue
            for plane, phi in ((0, 0.0), (1, 90.0)):
                j = jones(th, phi)
                # xz plane: x is p, y is s; yz plane: y is p, x is s
                tx, ty = (j[0, 0], j[1, 1]) if plane == 0 else (j[1, 1], j[0, 0])
                out[i, plane, 0, k] = tx / j0[0, 0]
                out[i, plane, 1, k] = ty / j0[1, 1]
    return out


def oblique_response(post_set: PostSet, platform: PlatformDesign | None = None, *,
                     angles_deg: Sequence[float] = OBLIQUE_ANGLES_DEG, harmonics: int = OBLIQUE_HARMONICS,
                     cache_dir: str | Path | None = None) -> ObliqueResponse:
    """The :class:`ObliqueResponse` of ``post_set``'s posts on ``platform`` (RCWA off axis at ``harmonics`` and one
    less for the error estimate; cached on disk in the library cache)."""
    plat = platform or PlatformDesign()
    m = check_int("harmonics", harmonics, 3, 12)
    angles = np.asarray(sorted({0.0, *(float(a) for a in angles_deg)}), dtype=float)
    if angles.size < 2 or angles[-1] >= 60.0 or angles[0] < 0:
        raise InputError("angles_deg", list(angles_deg), "angles in [0, 60) deg, at least one above 0")
    key = {"kind": "oblique", "widths_um": np.round(post_set.widths_um, 9).tolist(), "angles_deg": angles.tolist(),
           "harmonics": m, "wavelength_um": post_set.wavelength_um, "period_um": plat.period_um,
           "height_um": plat.post_height_um, "n_post": plat.n_post, "n_substrate": plat.n_substrate,
           "n_superstrate": plat.n_superstrate}
    path = Path(cache_dir) if cache_dir else io_cache_dir("library")
    path = path / f"oblique_{input_hash(key)}.npz"
    ratios, err = _cached_oblique(path)
    lock = cache_lock(path) if ratios is None else contextlib.nullcontext()
    with lock:
        if ratios is None:
            ratios, err = _cached_oblique(path)  # another process may have written it meanwhile
        if ratios is None:
            ratios, err = _solve_oblique(post_set, plat, angles, m, key, path)
    return ObliqueResponse(angles, {"x": ratios[:, :, 0, :], "y": ratios[:, :, 1, :]}, err, m)


def _cached_oblique(path: Path) -> tuple[np.ndarray | None, float | None]:
    if path.is_file():
        try:
            arrays, meta = load_npz(path)
            return arrays["ratios"], float(meta["error"])
        except Exception as e:  # noqa: BLE001 - a damaged cache entry is recomputed
            log.warning("ignoring unreadable oblique-incidence cache %s: %s", path, e)
    return None, None


def _solve_oblique(post_set: PostSet, plat: PlatformDesign, angles: np.ndarray, m: int, key: dict[str, Any],
                   path: Path) -> tuple[np.ndarray, float]:
    """The ratios at ``m`` harmonics and their error estimate (truncation, interpolation), written to ``path``."""
    ratios = _oblique_ratios(post_set.widths_um, plat, angles, post_set.wavelength_um, m)
    lower = _oblique_ratios(post_set.widths_um, plat, angles, post_set.wavelength_um, m - 1)
    err = float(np.max(np.abs(ratios - lower)))
    # interpolation: solve at the midpoints (in angle^2) of the upper segments and compare
    mids = np.sqrt(0.5 * (angles[1:] ** 2 + angles[:-1] ** 2))[-2:]
    solved = _oblique_ratios(post_set.widths_um, plat, np.concatenate([[0.0], mids]), post_set.wavelength_um, m)
    trial = ObliqueResponse(angles, {"x": ratios[:, :, 0, :], "y": ratios[:, :, 1, :]}, err, m)
    for i, th in enumerate(mids, start=1):
        for plane, az in ((0, 0.0), (1, 0.5 * math.pi)):
            for q, pol in enumerate(POLARIZATIONS):
                err = max(err, float(np.max(np.abs(trial.factor(pol, th, az) - solved[i, plane, q]))))
    try:
        atomic_save_npz(path, {"kind": "oblique-cache", "key": key, "error": err}, ratios=ratios)
    except OSError as e:
        log.warning("could not cache the oblique-incidence response in %s: %s", path, e)
    return ratios, err

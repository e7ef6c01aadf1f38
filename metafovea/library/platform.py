"""The library of a platform and both lenses' post sets: the path ``metafovea library``, ``design`` and
``validate`` share.

:class:`PlatformSweep` holds what to sweep (checked on construction); :func:`platform_post_sets` computes (or loads
from the cache) the library and selects both post sets; :func:`system_post_sets` gives a system's two lenses their
posts (``'rcwa'``, ``'ideal'`` or given: :data:`POST_SOURCES`); :func:`rcwa_post_sets` one RCWA set per lens.
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.config import POLARIZATIONS, PlatformDesign
from metafovea.errors import InputError, check_choice, check_int, check_positive, check_range

from .postset import PostSet
from .select import select_posts, usable_posts
from .sweep import Library, LibraryOptions, compute_library, library_key, width_grid

log = logging.getLogger(__name__)


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
        """The swept library (computed once, then loaded from the cache or the package's seed)."""
        return compute_library(self.widths_um, None, self.wavelengths,
                               options=self.options.with_platform(self.platform))

    def cache_key(self) -> str:
        """The key of :meth:`library` in the cache (:func:`~metafovea.library.sweep.library_key`)."""
        return library_key(self.widths_um, None, self.wavelengths, options=self.options.with_platform(self.platform))

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
                             "(convergence estimate <= 0.05): use more harmonics=..., a finer grid_step_um=... or "
                             f"fewer levels=...{diffracts}")
        key = (_library_digest(lib), self.platform, self.levels, wl, self.bias_weight)
        if key not in _SELECTED:
            if len(_SELECTED) >= _SELECTED_MAX:
                _SELECTED.pop(next(iter(_SELECTED)))
            path = _selection_path(key, self.options) if self.options.use_cache else None
            sets = _cached_selection(path)
            if sets is None:
                sets = {pol: select_posts(lib, pol, self.levels, wavelength_um=wl, platform=self.platform,
                                          bias_weight=self.bias_weight) for pol in POLARIZATIONS}
                if path is not None:
                    _write_selection(path, sets)
            _SELECTED[key] = sets
        return copy.deepcopy(_SELECTED[key])


def clear_selection_cache() -> None:
    """Forget the post sets selected in this process (the files cached on disk stay: they are named by everything
    they were made from)."""
    _SELECTED.clear()


def _selection_path(key: tuple, options: LibraryOptions) -> Path | None:
    """The cache file of a selection: next to the library's cache, named by a hash of the library's content, the
    selection's inputs and the code it runs (:mod:`metafovea.library.select`, ``postset``, ``sweep`` and the RCWA
    solver, which the selection calls for posts off the library's grid: a change to any is a new file, never a stale
    one); None where that code cannot be read (a zipped install): no disk cache then."""
    import hashlib
    from dataclasses import asdict

    import metafovea.rcwa
    from metafovea.io import cache_dir, input_hash

    from . import postset, select, sweep

    try:
        files = [Path(m.__file__) for m in (select, postset, sweep)]
        files += sorted(Path(metafovea.rcwa.__file__).parent.glob("*.py"))
        code = hashlib.sha256(b"".join(f.read_bytes() for f in files)).hexdigest()[:16]
    except (OSError, TypeError):
        return None
    digest, platform, levels, wl, bias = key
    name = input_hash({"library": digest, "platform": asdict(platform), "levels": levels, "wavelength_um": wl,
                       "bias_weight": bias, "code": code})
    root = Path(options.cache_dir) if options.cache_dir is not None else cache_dir("library")
    return root / f"posts_{name}.npz"


def _cached_selection(path: Path | None) -> dict[str, PostSet] | None:
    """Both post sets from the cache file ``path`` ({pol}: the file's stem + ``_x`` / ``_y``); None when there is
    none or one is damaged (then the selection runs again and rewrites them)."""
    if path is None:
        return None
    files = {pol: path.with_name(f"{path.stem}_{pol}.npz") for pol in POLARIZATIONS}
    if not all(f.is_file() for f in files.values()):
        return None
    try:
        return {pol: PostSet.load(f) for pol, f in files.items()}
    except InputError as e:  # a damaged cache file (disk full, killed copy) is recomputed, not fatal
        log.warning("selecting the posts again: damaged cache %s (%s)", path.parent, e)
        return None


def _write_selection(path: Path, sets: dict[str, PostSet]) -> None:
    """Write both sets (atomic writes; a cache that cannot be written is skipped with a warning)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        for pol, ps in sets.items():
            ps.save(path.with_name(f"{path.stem}_{pol}.npz"))
    except OSError as e:
        log.warning("post selection not cached in %s (%s)", path.parent, e)


#: the post sets :meth:`PlatformSweep.select` chose in this process, by the library's content and the selection's
#: inputs (a deterministic function of them: every simulation, report and study case asks for the same sets, and the
#: grid search takes ~0.9 s); callers get copies. They are also cached on disk next to the library
#: (:func:`_selection_path`), so that a new process reads them (~10 ms) instead of selecting again
_SELECTED: dict[tuple, dict[str, PostSet]] = {}
_SELECTED_MAX = 16


def _library_digest(lib: Library) -> str:
    """A digest of a library's content: its grid, wavelengths, every array and its metadata."""
    import hashlib

    from metafovea.io import to_json

    h = hashlib.sha1()
    named = [("wx_um", lib.wx_um), ("wy_um", lib.wy_um), ("wavelengths_um", lib.wavelengths_um)]
    for name, a in named + sorted(lib.arrays.items()):
        a = np.ascontiguousarray(a)
        h.update(f"{name} {a.dtype} {a.shape}".encode())
        h.update(a.tobytes())
    h.update(to_json(lib.meta, indent=None).encode())
    return h.hexdigest()


def platform_post_sets(platform: PlatformDesign | None = None, levels: int = 8, *, grid_step_um: float = 0.1,
                       wavelengths_um: Sequence[float] | None = None, options: LibraryOptions | None = None,
                       bias_weight: float = 0.0, **overrides: Any) -> tuple[dict[str, PostSet], Library]:
    """The library of a platform (computed once, then loaded from the cache) and both post sets.

    See :class:`PlatformSweep`. The paper's library (the defaults, 31 x 31 widths at 10 harmonics) ships with the
    package (:mod:`metafovea.library.seed`); another takes ~35 s on 2 cores on a first run (announced on the log), in
    worker processes, so a script calling this needs the usual ``if __name__ == "__main__":`` guard.

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
        given = {lens.polarization: posts[lens.polarization] for lens in lenses}
        return given, srcs.pop() if len(srcs) == 1 else "given"
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

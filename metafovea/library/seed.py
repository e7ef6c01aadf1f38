"""The library cache's seed: what the default system needs from this stage, shipped with the package.

The default platform's RCWA library (31 x 31 posts at 10 harmonics) and the oblique-incidence responses of the
default system's two post sets are in ``metafovea/data/`` (:data:`metafovea.io.DATA_DIR`) under their cache file
names: the work a first ``design``, ``psf``, ``simulate`` or ``validate`` would otherwise start with (their cost:
BENCHMARKS.md, "First run on an empty cache"). :func:`~metafovea.library.compute_library` and
:func:`~metafovea.library.oblique_response` read a seed file when the user's cache has no file of that name, and
only when the file's key is the key of the inputs (a hash of every input that changes the numbers): any other
setting is computed as before, and says so on the log.

:func:`seed_names` lists the files the current defaults need; :func:`write_seed` recomputes them
(``python -m metafovea.library.seed``, the command :data:`REGENERATE`). Run it after changing what the seed depends
on: the RCWA solver, the default platform or :class:`~metafovea.library.LibraryOptions`, the post selection, or the
oblique settings. ``tests/library/test_seed.py`` fails until it is run: it checks that the shipped files are
exactly the ones :func:`seed_names` gives and recomputes some of their posts.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from metafovea.config import SystemDesign
from metafovea.io import DATA_DIR

from .oblique import OBLIQUE_ANGLES_DEG, OBLIQUE_HARMONICS, _checked, _oblique_key, _solve_oblique, oblique_cache_name
from .platform import PlatformSweep
from .postset import PostSet
from .sweep import Library, compute_library

log = logging.getLogger(__name__)

#: the command that recomputes the shipped seed
REGENERATE = "python -m metafovea.library.seed"


def default_sweeps(system: SystemDesign | None = None) -> list[tuple[PlatformSweep, str]]:
    """``(sweep, polarization)`` of each lens of ``system`` (default: ``SystemDesign()``): the library and the post
    set the commands use for it (``rcwa_post_sets``)."""
    system = system or SystemDesign()
    return [(PlatformSweep(system.platform, lens.levels), lens.polarization)
            for lens in (system.foveal, system.perifoveal)]


def library_file_name(system: SystemDesign | None = None) -> str:
    """The cache file name of the default system's library (``library-<key>.npz``)."""
    return f"library-{default_sweeps(system)[0][0].cache_key()}.npz"


def default_post_sets(library: Library | None = None, system: SystemDesign | None = None) -> list[PostSet]:
    """The default system's two post sets, chosen from ``library`` (default: the library of
    :func:`library_file_name`, from the cache or the seed)."""
    sweeps = default_sweeps(system)
    lib = library if library is not None else sweeps[0][0].library()
    return [sweep.select(lib)[pol] for sweep, pol in sweeps]


def seed_names(library: Library | None = None, system: SystemDesign | None = None) -> list[str]:
    """The file names the seed must hold for the current defaults: the library's and both post sets' oblique
    responses (sorted)."""
    plat = (system or SystemDesign()).platform
    obliques = {oblique_cache_name(ps, plat) for ps in default_post_sets(library, system)}
    return sorted({library_file_name(system), *obliques})


def write_seed(out_dir: str | Path = DATA_DIR, *, workers: int | None = None, progress: bool = True) -> list[Path]:
    """Recompute the seed into ``out_dir`` (default: the package's data folder), never reading a cache or the old
    seed, and remove the library and oblique files there that the current defaults no longer use.

    Returns
    -------
    list of Path
        The files written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    system = SystemDesign()
    sweep = default_sweeps(system)[0][0]
    lib = compute_library(sweep.widths_um, None, sweep.wavelengths, options=sweep.options.with_platform(sweep.platform),
                          use_cache=False, workers=workers, progress=progress)
    lib.meta.pop("from_cache", None)
    written = [lib.save(out / library_file_name(system))]
    plat, angles, m = _checked(system.platform, OBLIQUE_ANGLES_DEG, OBLIQUE_HARMONICS)
    for ps in default_post_sets(lib, system):
        path = out / oblique_cache_name(ps, plat)
        if path not in written:
            _solve_oblique(ps, plat, angles, m, _oblique_key(ps, plat, angles, m), path)
            written.append(path)
    for old in [*out.glob("library-*.npz"), *out.glob("oblique_*.npz")]:
        if old not in written:
            old.unlink()
    return written


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog=REGENERATE, description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=DATA_DIR, help=f"folder to write to (default {DATA_DIR})")
    p.add_argument("--workers", type=int, default=None, help="worker processes of the library sweep (default: all "
                   "cores)")
    args = p.parse_args(argv)
    logging.basicConfig(format="%(levelname)s %(name)s: %(message)s", level=logging.INFO)
    t0 = time.perf_counter()
    for path in write_seed(args.out, workers=args.workers):
        print(f"{path} ({path.stat().st_size / 1024:.0f} KiB)")
    print(f"seed written in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

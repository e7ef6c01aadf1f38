"""`metafovea library`: compute (or load from cache) the RCWA post library, select both post sets,
write the paper's Fig. 7b/7c maps and JSON numbers.

    metafovea library [designs/platform.toml] [--wavelengths-um 10] [--grid-step-um 0.1]
                      [--levels 8] [--harmonics 10 | --tolerance-rad T] [--bias-weight 0] [--out DIR] [--json] ...

Outputs in --out: library.npz (Library.save), postset_x.npz (foveal lens, focuses x) and
postset_y.npz (perifoveal lens, focuses y) for `metafovea design --post-set`, fig7b_phase_maps.png,
fig7c_selected_posts.png and library.json (:mod:`metafovea.library.report`).
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from metafovea.cli.options import add_shared, alias, show_progress, workers_arg
from metafovea.errors import InputError, check_int, check_positive, check_range

if TYPE_CHECKING:
    from metafovea.library import LibraryOptions, PlatformSweep


def register(subparsers: argparse._SubParsersAction) -> None:
    from metafovea.rcwa.solve import FACTORIZATIONS, SIDES

    p = subparsers.add_parser("library", help="RCWA scatterer library and birefringent post selection (Fig. 7)")
    p.add_argument("platform_file", nargs="?", help="platform TOML (default: the paper's Si-post platform)")
    p.add_argument("--wavelengths-um", nargs="+", default=None,
                   help="wavelengths to sweep in um (default: the platform's design wavelength)")
    p.add_argument("--grid-step-um", default="0.1", help="width grid step in um (default 0.1: 31 x 31 posts)")
    p.add_argument("--levels", default="8", help="phase levels per lens (default 8)")
    p.add_argument("--harmonics", default=None, help="Fourier orders M, |m|,|n| <= M (default 10: 441 plane waves)")
    p.add_argument("--tolerance-rad", default=None, help="choose the harmonics instead: the smallest M whose estimated "
                   "zero-order phase error (probe posts) is at most this many rad; says what it chose and why")
    p.add_argument("--factorization", default="li", choices=FACTORIZATIONS, help="Fourier factorisation rule")
    p.add_argument("--incidence", default="substrate", choices=SIDES,
                   help="side light enters from (default substrate: through the wafer, posts face the sensor)")
    p.add_argument("--bias-weight", default="0",
                   help="weight of the platform's +-edge_bias_um cases in the post selection (default 0: nominal; "
                        "> 0: chosen jointly for -bias, nominal and +bias, the nominal case weighted 1)")
    p.add_argument("--tol", default="0.02", help="convergence tolerance on t for the warning (default 0.02)")
    add_shared(p, "--workers", "--scheduler")
    p.add_argument("--cache-dir", default=None, help="library cache directory (default $METAFOVEA_CACHE/library, "
                                                     "i.e. ~/.cache/metafovea/library)")
    p.add_argument("--no-cache", action="store_true", help="recompute even if a cached library exists")
    p.add_argument("--out", default=None, help="write library, post sets, figures and JSON into this directory")
    add_shared(p, "--force", "--json")
    alias(p, "--no-progress", "--quiet", "quiet", const=True)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from metafovea.config import PlatformDesign, load_platform
    from metafovea.io import prepare_output, to_json
    from metafovea.library import LibraryOptions, PlatformSweep, choose_harmonics
    from metafovea.library.report import LibraryReport, library_report
    from metafovea.library.select import MAX_BIAS_WEIGHT

    src = args.platform_file
    plat = load_platform(src) if src else PlatformDesign()
    wls = (tuple(check_positive("--wavelengths-um", w, "um", hi=1e4) for w in args.wavelengths_um)
           if args.wavelengths_um else None)
    step = check_positive("--grid-step-um", args.grid_step_um, "um")
    levels = check_int("--levels", args.levels, 2, 64)
    if args.harmonics is not None and args.tolerance_rad is not None:
        raise InputError("--harmonics", args.harmonics, "not with --tolerance-rad (which chooses the harmonics)")
    options = LibraryOptions(harmonics=check_int("--harmonics", args.harmonics or "10", 5, 40),
                             factorization=args.factorization, incidence=args.incidence,
                             tol=check_positive("--tol", args.tol), cache_dir=args.cache_dir,
                             use_cache=not args.no_cache,
                             workers=workers_arg(args.workers), scheduler=args.scheduler,
                             progress=show_progress(args))
    bias_weight = check_range("--bias-weight", args.bias_weight, 0.0, MAX_BIAS_WEIGHT, lo_inclusive=True)
    sweep = PlatformSweep(plat, levels, step, wls, options, source=src,  # checks the platform and the grid
                          bias_weight=bias_weight)
    out = (prepare_output(args.out, args.force or LibraryReport.stopped_write(args.out), is_dir=True)  # completes
           if args.out else None)  # a write a Ctrl-C stopped (no library.json yet): not someone else's files
    choice = choose_harmonics(args.tolerance_rad, sweep) if args.tolerance_rad is not None else None
    sweep = choice.applied(sweep) if choice is not None else sweep
    check_sweep_cost(args, sweep, sweep.options)
    rep = library_report(sweep, harmonics_choice=choice)  # warnings: one line each, by metafovea.cli.main's printer
    if out is not None:
        rep.write(out)
    if args.json:
        numbers = rep.numbers()
        if out is not None:
            numbers["files"] = sorted(p.name for p in out.iterdir())
        print(to_json(numbers))
    else:
        print(rep.format())
        if out is not None:
            print(f"\nwritten to {out}")
    return 0


#: the longest sweep started on this machine without a --scheduler (an estimate from the sizes; cached rows are
#: not counted, so a resumed sweep is judged as a fresh one)
MAX_SWEEP_HOURS = 24.0


def check_sweep_cost(args: argparse.Namespace, sweep: PlatformSweep, options: LibraryOptions) -> None:
    """Refuse a sweep that cannot finish here (time or memory, from the number of posts and the harmonics), naming
    --harmonics when it is above the default, else --grid-step-um; warn about one that takes over 15 minutes."""
    import os
    import warnings

    from metafovea.errors import human_bytes
    from metafovea.imaging.simulate import available_memory_bytes
    from metafovea.rcwa.solve import solve_cost

    n = len(sweep.widths_um) ** 2 * len(sweep.wavelengths)
    workers = options.workers or os.cpu_count() or 1
    core_s, per_worker = solve_cost(options.harmonics, n)
    hours = core_s / workers / 3600
    flag, value = (("--harmonics", args.harmonics or options.harmonics) if int(options.harmonics) > 10
                   else ("--grid-step-um", args.grid_step_um))
    avail = available_memory_bytes()
    need = f"{n:,} post solves at {options.harmonics} harmonics: ~{hours:.3g} h on {workers} workers, " \
           f"{human_bytes(per_worker)} each"
    if avail is not None and per_worker * workers > 0.8 * avail:
        raise InputError(flag, value, f"a sweep that fits in memory ({human_bytes(avail)} available)", detail=need)
    if hours > MAX_SWEEP_HOURS and args.scheduler is None:
        raise InputError(flag, value, f"a sweep of at most ~{MAX_SWEEP_HOURS:g} h here (fewer harmonics, a coarser "
                         "grid, fewer wavelengths, or a --scheduler cluster)", detail=need)
    if hours > 0.25 and args.scheduler is None:
        warnings.warn(f"this sweep needs {need} (unless cached)", UserWarning, stacklevel=2)

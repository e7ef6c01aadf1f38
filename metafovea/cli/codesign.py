"""`metafovea codesign`: co-design a system's lenses' added radial phase for the band, write the co-designed
design files (the same format as ``designs/``), the production check and the report."""

from __future__ import annotations

import argparse
import re
from typing import Any

from metafovea.cli.flags import flag_map, in_flags
from metafovea.cli.options import add_shared, show_progress


def register(sub: Any) -> None:
    p = sub.add_parser("codesign", help="co-design the lenses' phase for the whole band (band MTF to Nyquist)",
                       description="Optimise each chosen lens' added radial phase (phase_poly_rad) for its "
                                   "channel's band-integrated MTF to the sensor's Nyquist frequency, through the "
                                   "camera's train and post sets; state the achromatic limit and the line bound "
                                   "(the most any phase can win) beside the result. A stopped run resumes from "
                                   "its checkpoints in --out.")
    p.add_argument("system_file", nargs="?", help="system TOML (default: the built-in paper prototype)")
    p.add_argument("--objective", default="mtf", help="mtf: the band PSF's MTF area to Nyquist (default)")
    p.add_argument("--band", nargs=2, metavar=("LO_UM", "HI_UM"), help="band in um (default: the system's)")
    p.add_argument("--lenses", default="foveal", help="foveal, perifoveal or foveal,perifoveal (default foveal)")
    p.add_argument("--coefficients", default="3", help="added-phase terms a_j (rho/R)^(2j) per lens (1-8; default 3)")
    p.add_argument("--steps", default="80", help="optimiser steps per lens (default 80)")
    p.add_argument("--learning-rate", default="0.1", help="Adam's step in waves (default 0.1)")
    p.add_argument("--size-px", default="31", help="sensor window of the objective's PSF, odd pixels (default 31)")
    p.add_argument("--max-wavelengths", default=None,
                   help="most spectral samples a run may take (the lens sets how many it needs; default 400)")
    p.add_argument("--no-check", action="store_true", help="skip the production engine's re-propagation")
    p.add_argument("--out", default="codesign", help="output folder (default ./codesign); resumed when it holds "
                                                     "this run's checkpoints")
    add_shared(p, "--posts", "--force", "--json")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from metafovea.codesign import CodesignOptions, OptimizeOptions, run_codesign
    from metafovea.errors import InputError, check_int, check_positive
    from metafovea.io import to_json

    default_cap = CodesignOptions.max_wavelengths
    band = None if args.band is None else tuple(check_positive("--band", v, "um") for v in args.band)
    opts = CodesignOptions(objective=args.objective, band_um=band, lenses=tuple(args.lenses.split(",")),
                           n_coefficients=check_int("--coefficients", args.coefficients, 1, 8),
                           size_px=check_int("--size-px", args.size_px, 9, 255),
                           max_wavelengths=check_int("--max-wavelengths", args.max_wavelengths or default_cap, 3,
                                                     100_000),
                           posts=args.posts,
                           optimize=OptimizeOptions(steps=check_int("--steps", args.steps, 1, 100_000),
                                                    learning_rate=check_positive("--learning-rate",
                                                                                 args.learning_rate),
                                                    progress=show_progress(args)))
    try:
        summary = run_codesign(args.system_file, opts, args.out, force=args.force, check=not args.no_check)
    except InputError as e:  # the cap refused was the default, not a value the user typed: say so
        if e.parameter != "max_wavelengths" or args.max_wavelengths is not None:
            raise
        need = re.match(r">= (\d+)", e.allowed)
        raise InputError(e.parameter, e.value, e.allowed, source=e.source, detail=(
            f"{default_cap} is the default cap" + (f"; --max-wavelengths {need.group(1)} lifts it (time and memory "
                                                   "grow with the count)" if need else ""))) from None
    if args.json:
        print(to_json(summary))
        return 0
    for name, d in summary["lenses"].items():
        print(f"{name}: band MTF area to Nyquist {d['mtf_area_hyperbolic']:.4g} (hyperbolic) -> {d['mtf_area']:.4g} "
              f"(co-designed): {d['gain']:.3f}x; no phase profile can exceed {d['line_bound_gain_limit']:.3f}x")
        for line in d["bandwidth_limit"]:
            print(f"  {line}")
        print(f"  {d['sampling']['why']}" + "".join(f"\n  warning: {in_flags(w, flag_map('codesign'))}"
                                                     for w in d.get("warnings") or []))
        if "production_check" in d:
            print(f"  production engine: {d['production_check']['gain_production']:.3f}x")
    print(f"written to {args.out}: system.toml, foveal.toml, perifoveal.toml, platform.toml, codesign.json, "
          "report.html")
    return 0

"""`metafovea design`: design one metalens (or both lenses of a system file) and print the numbers a designer
checks; ``--out DIR`` writes the design bundle."""

from __future__ import annotations

import argparse
from dataclasses import MISSING, fields
from typing import Any

from metafovea.cli.options import progress
from metafovea.errors import InputError


def register(sub: Any) -> None:
    p = sub.add_parser("design", help="design a metalens (or both lenses of a system) and report its numbers",
                       description="Design a hyperbolic metalens on a square nanopost lattice. Give a lens or "
                                   "system TOML file, or --f and --d (millimetres).")
    p.add_argument("design_file", nargs="?", help="lens or system TOML (e.g. designs/foveal.toml)")
    p.add_argument("--f", dest="f_mm", metavar="F_MM", help="focal length in mm")
    p.add_argument("--d", dest="d_mm", metavar="D_MM", help="lens diameter in mm")
    p.add_argument("--wavelength-um", help="design wavelength in um (default 10)")
    p.add_argument("--period-um", help="lattice period in um (default 4)")
    p.add_argument("--levels", help="number of phase levels (default 8)")
    p.add_argument("--polarization", help="polarisation the lens focuses: x or y (default x)")
    p.add_argument("--lattice", help="site positions: integer (post at the centre) or half")
    p.add_argument("--name", help="lens name (default: lens)")
    p.add_argument("--post-set", help="a PostSet .npz (from `metafovea library`) to list posts per level")
    p.add_argument("--posts", default="rcwa", choices=("rcwa", "ideal"),
                   help="rcwa (default): select the posts from the platform's RCWA library (computed on first use, "
                        "~35 s on 2 cores, then cached) and list post widths per level and the expected efficiency; "
                        "ideal: no post set (quantisation and lattice only, a simplified model)")
    p.add_argument("--library", action="store_true", help="the same as --posts rcwa (the default)")
    p.add_argument("--samples", default=str(1 << 20), help="sites sampled for the lattice efficiency (default 2^20)")
    p.add_argument("--out", help="write the design bundle (JSON, TOML, CSV, PNG figures) into this directory")
    p.add_argument("--force", action="store_true", help="overwrite existing output")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=run)


def design_from_args(args: argparse.Namespace) -> list:
    """Build the LensDesign(s) the design command acts on (file, overridden by flags)."""
    from metafovea.config import LATTICES, POLARIZATIONS, LensDesign, SystemDesign, load_design, validate_lens_numbers
    from metafovea.errors import check_choice, check_int, check_positive
    from metafovea.units import UM_PER_MM

    lenses: list[LensDesign] = []
    if args.design_file:
        d = load_design(args.design_file)
        if isinstance(d, SystemDesign):
            lenses = [d.foveal, d.perifoveal]
            for flag, v in (("--f", args.f_mm), ("--d", args.d_mm), ("--polarization", args.polarization),
                            ("--name", args.name)):
                if v is not None:
                    raise InputError(flag, v, "no value with a system file (it holds two different lenses: "
                                              "give a lens file or no file)")
        elif isinstance(d, LensDesign):
            lenses = [d]
        else:
            raise InputError("design_file", args.design_file, "a lens or system TOML (a platform file has no lens)")
    elif args.f_mm is None or args.d_mm is None:
        missing = "--f" if args.f_mm is None else "--d"
        raise InputError(missing, None, "a positive number of millimetres (or give a design TOML file)")
    overrides: dict[str, Any] = {}
    if args.f_mm is not None:
        overrides["f_um"] = check_positive("--f", args.f_mm, "mm") * UM_PER_MM
    if args.d_mm is not None:
        overrides["diameter_um"] = check_positive("--d", args.d_mm, "mm") * UM_PER_MM
    if args.wavelength_um is not None:
        overrides["wavelength_um"] = check_positive("--wavelength-um", args.wavelength_um, "um", hi=1e4)
    if args.period_um is not None:
        overrides["period_um"] = check_positive("--period-um", args.period_um, "um", hi=1e4)
    if args.levels is not None:
        overrides["levels"] = check_int("--levels", args.levels, 2, 256)
    if args.polarization is not None:
        overrides["polarization"] = check_choice("--polarization", args.polarization, POLARIZATIONS)
    if args.lattice is not None:
        overrides["lattice"] = check_choice("--lattice", args.lattice, LATTICES)
    if lenses:
        base = [dict(lens.__dict__) for lens in lenses]
        if args.name:
            overrides["name"] = args.name
    else:  # checked under the flags' names (and --d in mm) before a LensDesign is made
        base = [{**{f.name: f.default for f in fields(LensDesign) if f.default is not MISSING},
                 "name": args.name or "lens", "f_um": overrides.pop("f_um"),
                 "diameter_um": overrides.pop("diameter_um")}]
    out = []
    for b in base:
        merged = {**b, **overrides}
        validate_lens_numbers(merged["f_um"], merged["diameter_um"], merged["wavelength_um"], merged["period_um"],
                              merged["levels"], merged["polarization"],
                              names=("--f", "--d", "--wavelength-um", "--period-um", "--levels", "--polarization"))
        out.append(LensDesign(**merged))
    return out


def run(args: argparse.Namespace) -> int:
    from metafovea.design_report import design_lenses, format_summary, summary_dict, write_design_bundles
    from metafovea.errors import check_int
    from metafovea.io import prepare_output, to_json
    from metafovea.library.postset import PostSet

    lenses = design_from_args(args)
    samples = check_int("--samples", args.samples, 1000, 1 << 26)
    if args.post_set and args.library:
        raise InputError("--library", True, "either --post-set FILE or --library, not both")
    post_set = PostSet.load(args.post_set, name="--post-set") if args.post_set else None
    out_root = prepare_output(args.out, args.force, is_dir=True) if args.out else None
    if args.library and args.posts == "ideal":
        raise InputError("--library", True, "not together with --posts ideal")
    summaries = design_lenses(lenses, post_set=post_set, from_library=post_set is None and args.posts == "rcwa",
                              samples=samples, progress=progress(args))
    if out_root is not None:
        write_design_bundles(lenses, summaries, out_root)
    if args.json:
        payload = [summary_dict(s) for s in summaries]
        print(to_json(payload[0] if len(payload) == 1 else payload))
    else:
        print("\n\n".join(format_summary(s) for s in summaries))
        if out_root is not None:
            print(f"\ndesign bundle written to {out_root}")
    return 0

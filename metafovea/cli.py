"""Command-line interface: a thin layer over the library functions.

Every subcommand parses its arguments, calls one function, prints a summary (or JSON with ``--json``)
and writes files atomically. Bad input prints one line naming the parameter and the allowed range and
exits with status 2; a failed check (``verify``) exits 1.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import logging
import sys
import warnings
from typing import Any, Sequence

from metafovea import __version__
from metafovea.errors import InputError

log = logging.getLogger("metafovea")


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump) and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        sys.stderr.write(f"{self.prog}: error: {message} (see --help)\n")
        raise SystemExit(2)


# ----------------------------------------------------------------------------------------------
# design
# ----------------------------------------------------------------------------------------------
def _add_design(sub: Any) -> None:
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
    p.add_argument("--library", action="store_true",
                   help="select the posts from the platform's RCWA library (computed on first use, ~1 min on "
                        "2 cores, then cached) and list post widths per level and the expected efficiency")
    p.add_argument("--samples", default=str(1 << 20), help="sites sampled for the lattice efficiency (default 2^20)")
    p.add_argument("--out", help="write the design bundle (JSON, TOML, CSV, PNG figures) into this directory")
    p.add_argument("--force", action="store_true", help="overwrite existing output")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=_run_design)


def design_from_args(args: argparse.Namespace) -> list:
    """Build the LensDesign(s) the design command acts on (file, overridden by flags)."""
    from metafovea.config import LensDesign, SystemDesign, load_design, validate_lens_numbers
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
        overrides["polarization"] = check_choice("--polarization", args.polarization, ("x", "y"))
    if args.lattice is not None:
        overrides["lattice"] = check_choice("--lattice", args.lattice, ("integer", "half"))
    if not lenses:
        lenses = [LensDesign(args.name or "lens", overrides.pop("f_um"), overrides.pop("diameter_um"))]
    elif args.name:
        overrides["name"] = args.name
    out = []
    for lens in lenses:
        merged = {**lens.__dict__, **overrides}
        validate_lens_numbers(merged["f_um"], merged["diameter_um"], merged["wavelength_um"], merged["period_um"],
                              merged["levels"], merged["polarization"],
                              names=("--f", "--d", "--wavelength-um", "--period-um", "--levels", "--polarization"))
        out.append(lens.with_(**overrides))
    return out


def _run_design(args: argparse.Namespace) -> int:
    from metafovea.design_report import format_summary, summary_dict, write_design_bundle
    from metafovea.errors import check_int
    from metafovea.io import prepare_output, to_json
    from metafovea.lens import summarize

    lenses = design_from_args(args)
    samples = check_int("--samples", args.samples, 1000, 1 << 26)
    post_set = None
    if args.post_set and args.library:
        raise InputError("--library", True, "either --post-set FILE or --library, not both")
    if args.post_set:
        from metafovea.library import PostSet
        post_set = PostSet.load(args.post_set)
    out_root = prepare_output(args.out, args.force, is_dir=True) if args.out else None
    lib_sets = None
    if args.library:
        from metafovea.config import PlatformDesign
        from metafovea.library import platform_post_sets
        l0 = lenses[0]
        for lens in lenses[1:]:
            if (lens.period_um, lens.post_height_um, lens.wavelength_um, lens.levels) != \
                    (l0.period_um, l0.post_height_um, l0.wavelength_um, l0.levels):
                raise InputError("--library", True, "lenses sharing one platform (period, height, wavelength, levels)")
        plat = PlatformDesign(period_um=l0.period_um, post_height_um=l0.post_height_um,
                              wavelength_um=l0.wavelength_um, n_substrate=l0.n_substrate, n_post=l0.n_substrate,
                              min_feature_um=min(0.5, 0.125 * l0.period_um))
        lib_sets, _ = platform_post_sets(plat, l0.levels, progress=sys.stderr.isatty())
    results = []
    for lens in lenses:
        if lib_sets is not None:
            post_set = lib_sets[lens.polarization]
        ps = post_set if (post_set is not None and post_set.polarization == lens.polarization) else None
        if post_set is not None and ps is None and len(lenses) == 1:
            raise InputError("--post-set", args.post_set, f"a post set for {lens.polarization}-polarisation "
                                                          f"(this one focuses {post_set.polarization})")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            s = summarize(lens, post_set=ps, samples=samples)
        results.append((lens, s))
        if out_root is not None:
            d = out_root / lens.name if len(lenses) > 1 else out_root
            write_design_bundle(lens, s, d)
    if args.json:
        payload = [summary_dict(s) for _, s in results]
        print(to_json(payload[0] if len(payload) == 1 else payload))
    else:
        for i, (_, s) in enumerate(results):
            if i:
                print()
            print(format_summary(s))
        if out_root is not None:
            print(f"\ndesign bundle written to {out_root}")
    return 0


# ----------------------------------------------------------------------------------------------
# validate (the README's main job)
# ----------------------------------------------------------------------------------------------
def _add_validate(sub: Any) -> None:
    p = sub.add_parser("validate", help="end-to-end validation of a system (default: the paper's prototype)")
    p.add_argument("system_file", nargs="?", help="system TOML (default: built-in paper prototype)")
    p.add_argument("--out", help="write the report into this directory")
    p.add_argument("--force", action="store_true", help="overwrite existing output")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--seed", default="0", help="random seed (default 0)")
    p.add_argument("--scene", default="siemens-star", help="bundled scene to simulate (default siemens-star; "
                                                          "see `metafovea simulate --list-scenes`)")
    p.add_argument("--frames", default="96", help="frames to simulate (default 96: 8 s at 12 frames/s)")
    p.add_argument("--filter", default="both", choices=("off", "on", "both"),
                   help="spectral cases: 8-14 um as designed (off), the 10 um / 0.5 um filter (on), or both")
    p.add_argument("--dip-steps", default="20", help="deep-image-prior steps, warm-started from the classical "
                                                      "solution (default 20; more change nothing measurable here)")
    p.set_defaults(func=_run_validate)


def _run_validate(args: argparse.Namespace) -> int:
    from metafovea.validate import run_validate
    return run_validate(args)


# ----------------------------------------------------------------------------------------------
# other stages: their CLI modules register themselves
# ----------------------------------------------------------------------------------------------
_STAGE_MODULES = [
    ("metafovea.cli_library", ["add_parser"]),
    ("metafovea.cli_layout", ["add_export_parser", "add_verify_parser"]),
    ("metafovea.cli_psf", ["add_parser"]),
    ("metafovea.cli_simulate", ["add_parser"]),
    ("metafovea.cli_reconstruct", ["add_parser"]),
]


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="metafovea", description="Polarisation-multiplexed foveated meta-optics for LWIR cameras. "
                                                   "Lengths in um (lens f and D in mm), angles in degrees at the CLI.")
    parser.add_argument("--version", action="version", version=f"metafovea {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    _add_design(sub)
    _add_validate(sub)
    for mod_name, adders in _STAGE_MODULES:
        if importlib.util.find_spec(mod_name) is None:
            continue
        mod = importlib.import_module(mod_name)
        for a in adders:
            getattr(mod, a)(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2), format="%(levelname)s %(name)s: %(message)s")
    # warnings as one line each ("Category: message"), without Python's source line
    warnings.formatwarning = lambda m, c, f, n, line=None: f"{c.__name__}: {m}\n"
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    try:
        rc = args.func(args)
    except InputError as e:
        sys.stderr.write(f"metafovea {args.command}: error: {e}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("interrupted\n")
        return 130
    except BrokenPipeError:
        return 0
    except OSError as e:
        sys.stderr.write(f"metafovea {args.command}: error: {e.strerror or e}: {getattr(e, 'filename', '') or ''}\n")
        return 2
    return int(rc or 0)


if __name__ == "__main__":
    raise SystemExit(main())

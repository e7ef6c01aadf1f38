"""``metafovea validate``: the end-to-end validation of a system (default: the paper's prototype), the README's
main job.

``run(args)`` checks the flags (a bad ``--scene`` before minutes of library and PSF work), calls
:func:`metafovea.validate.validate_system` (which writes ``validate.json``, ``validate.html`` and the figures into
``--out``) and prints :func:`metafovea.validate.format_report` (``--json``: the report as JSON). Exit status 0, or 2
on bad input.
"""

from __future__ import annotations

import argparse

from metafovea.cli.options import add_shared, seed_arg, show_progress
from metafovea.cli.output import out_dir
from metafovea.errors import check_int
from metafovea.io import prepare_output, to_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("validate", help="end-to-end validation of a system (default: the paper's prototype)")
    p.add_argument("system_file", nargs="?", help="system TOML (default: built-in paper prototype)")
    p.add_argument("--out", help="write the report into this directory")
    add_shared(p, "--force", "--json", "--seed", "--scene", "--scene-unit", "--frames")
    p.add_argument("--filter", default="both", choices=("off", "on", "both"),
                   help="spectral cases: 8-14 um as designed (off), the 10 um / 0.5 um filter (on), or both")
    p.add_argument("--polarizer", default="free", choices=("free", "sync"),
                   help="free (default, the paper's): turning with a phase and rate the unknown-alpha solvers "
                        "estimate; "
                        "sync: locked to the frames with a known phase (alpha then known)")
    p.add_argument("--dip-steps", default="20", help="deep-image-prior steps, warm-started from the classical "
                                                      "solution (default 20; more change nothing measurable here)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from metafovea.config import SystemDesign, load_system
    from metafovea.imaging.scene import make_scene
    from metafovea.validate import ValidateOptions, format_report, validate_system

    seed = seed_arg(args.seed)
    frames = check_int("--frames", args.frames, 3, 100_000)  # the unknown-alpha solver needs 3 frames
    dip_steps = check_int("--dip-steps", args.dip_steps, 1, 100_000)
    system = load_system(args.system_file) if args.system_file else SystemDesign.paper()
    # a bad --scene (or a scene file in the wrong unit) is reported before minutes of library and PSF work
    make_scene(args.scene, scene_unit=args.scene_unit)
    out = prepare_output(out_dir(args, "validate"), args.force, is_dir=True)
    opts = ValidateOptions(seed=seed, frames=frames, scene=args.scene, scene_unit=args.scene_unit,
                           dip_steps=dip_steps,
                           polarizer_mode=args.polarizer,
                           progress=show_progress(args),
                           filters=(False, True) if args.filter == "both" else (args.filter == "on",))
    rep = validate_system(system, opts, out)
    summaries = rep.pop("_summaries")
    if args.json:
        print(to_json(rep))
    else:
        print(format_report(rep, summaries, args.system_file or "built-in paper prototype", out))
    return 0

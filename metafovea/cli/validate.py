"""`metafovea validate`: the end-to-end validation of a system (default: the paper's prototype), the README's
main job."""

from __future__ import annotations

import argparse
from typing import Any


def register(sub: Any) -> None:
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
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from metafovea.validate import run_validate
    return run_validate(args)

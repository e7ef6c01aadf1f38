"""``metafovea bench``: speed against error of every stage on this machine (:mod:`metafovea.studies.bench`).

``run(args)`` checks the flags, calls :func:`metafovea.studies.bench.run_bench` (which writes ``index.html`` and
``bench.json`` into ``--out``, default ``out/bench-<time>/``), prints one line per step while it works and a summary
per stage at the end (``--json``: the JSON file's content). Exit status 0, or 2 on bad input (an unknown stage, an
output folder that holds files without ``--force``), 130 on Ctrl-C (nothing written).
"""

from __future__ import annotations

import argparse
import shlex

from metafovea.cli.options import add_shared
from metafovea.cli.output import out_dir, stage_printer
from metafovea.io import to_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="speed against error of every stage on this machine (HTML page, JSON)")
    p.add_argument("--quick", action="store_true", help="small sweeps (CI, ~20 s on 2 cores); the page says so")
    p.add_argument("--stages", nargs="+", metavar="STAGE", default=None,
                   help="run only these stages: rcwa psf simulate reconstruct export (default: all)")
    p.add_argument("--out", help="output directory (default out/bench-<time>/)")
    add_shared(p, "--force", "--json")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from metafovea.studies.bench import run_bench

    out = out_dir(args, "bench")  # not created yet: run_bench checks the stages first
    command = " ".join(["metafovea bench", *(["--quick"] if args.quick else []),
                        *(["--stages", *args.stages] if args.stages else []), "--out", shlex.quote(str(out)),
                        *(["--force"] if args.force else [])])
    res = run_bench(out, quick=args.quick, stages=args.stages, force=args.force, progress=stage_printer(args, "bench"),
                    command=command)
    if args.json:
        print(to_json(res))
        return 0
    m = res["machine"]
    print(f"bench{' (--quick)' if args.quick else ''}: {m['nproc']} cores ({m['cpu_model']}), "
          f"commit {res['git_commit'] or 'n/a'}, {res['seconds']:.1f} s")
    for name, st in res["stages"].items():
        print(f"  {name:<12} {st['seconds']:6.1f} s  {len(st['rows'])} points  load {st['load_before']} -> "
              f"{st['load_after']}")
    print(f"files: {res['files']['html']}, {res['files']['json']}")
    return 0

"""``metafovea study NAME``: one of the paper's studies (:mod:`metafovea.studies`), run through the real chain.

``run(args)`` checks the flags, calls :func:`metafovea.studies.run_study` (which writes ``NAME.json``,
``NAME.png`` and ``NAME.html`` into ``--out``, default ``out/study-NAME-<time>/``) and prints the study's trend
against the paper and its main table (``--json``: the JSON file's content). ``--list`` names the studies.
Exit status 0, or 2 on bad input (an unknown study, a bad ``--seed``, an output in the way).
"""

from __future__ import annotations

import argparse
from typing import Any

from metafovea.cli.output import out_dir
from metafovea.errors import InputError, check_int
from metafovea.io import prepare_output, to_json


def register(sub: Any) -> None:
    p = sub.add_parser("study", help="run one of the paper's studies (figure, JSON, HTML page)")
    p.add_argument("name", nargs="?", help="the study (see --list)")
    p.add_argument("--list", action="store_true", help="list the studies and exit")
    p.add_argument("--fast", action="store_true", help="small sizes (CI): fewer cases, frames and pixels; the "
                                                       "page says which")
    p.add_argument("--seed", default="0", help="random seed (default 0): the same seed gives the same JSON "
                                               "(apart from its 'timing' key)")
    p.add_argument("--out", help="output directory (default out/study-NAME-<time>/)")
    p.add_argument("--force", action="store_true", help="write into an existing, non-empty --out")
    p.add_argument("--json", action="store_true", help="print the JSON instead of a summary")
    p.add_argument("--workers", default="1", help="local processes for the sweep (default 1; 0 = every core)")
    p.add_argument("--scheduler", help="Dask scheduler address (tcp://host:8786) to spread the sweep")
    p.set_defaults(func=run)


def _table(t: dict[str, Any]) -> list[str]:
    from metafovea.report import fmt

    rows = [[str(h) for h in t["header"]]] + [[v if isinstance(v, str) else fmt(v) for v in r] for r in t["rows"]]
    widths = [max(len(r[j]) for r in rows) for j in range(len(rows[0]))]
    return [f"  {t['caption']}"] + ["  " + " ".join(v.rjust(w) for v, w in zip(r, widths)) for r in rows]


def run(args: argparse.Namespace) -> int:
    from metafovea.studies import STUDIES, StudyOptions, run_study, study_module

    if args.list:
        for name, (_, line) in STUDIES.items():
            print(f"{name:<12} {line}")
        return 0
    if not args.name:
        raise InputError("NAME", None, "a study: " + ", ".join(STUDIES) + " (see --list)")
    study_module(args.name)  # an unknown name before anything is created
    seed = check_int("--seed", args.seed, 0, 2**32 - 1)
    workers = check_int("--workers", args.workers, 0, 4096) or None
    out = prepare_output(out_dir(args, "study", args.name), args.force, is_dir=True)
    progress = not args.json and not getattr(args, "quiet", False)
    opts = StudyOptions(fast=args.fast, seed=seed, workers=workers, scheduler=args.scheduler, progress=progress)
    res = run_study(args.name, opts, out, force=True)
    if args.json:
        print(to_json(res.to_json()))
        return 0
    tr = res.trend
    print(f"study {res.name}: {res.title}{' (--fast)' if args.fast else ''}, seed {seed}")
    print(f"  paper:    {tr.get('expected', '')}")
    print(f"  observed: {tr.get('observed', '')}")
    print(f"  trend {'holds' if tr.get('holds') else 'differs (see the note on the page)'}")
    for t in res.tables:
        print("\n".join(_table(t)))
    print(f"files: {', '.join(str(p) for p in res.files.values())}; {res.timing.get('seconds_total', 0.0):.1f} s")
    return 0

"""``metafovea study NAME``: one of the paper's studies (:mod:`metafovea.studies`), run through the real chain.

``run(args)`` checks the flags, calls :func:`metafovea.studies.run_study` (which writes ``NAME.json``,
``NAME.png`` and ``NAME.html`` into ``--out``, default ``out/study-NAME-<time>/``) and prints the study's trend
against the paper and its main table (``--json``: the JSON file's content). ``--list`` names the studies.
Exit status 0, or 2 on bad input (an unknown study, a bad ``--seed``, an output in the way).
"""

from __future__ import annotations

import argparse
from typing import Any

from metafovea.cli.options import SHARED_OPTIONS, add_shared, seed_arg, show_progress, workers_arg
from metafovea.cli.output import out_dir
from metafovea.errors import InputError
from metafovea.io import prepare_output, to_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("study", help="run one of the paper's studies (figure, JSON, HTML page)")
    p.add_argument("name", nargs="?", help="the study (see --list)")
    p.add_argument("--list", action="store_true", help="list the studies and exit")
    p.add_argument("--fast", action="store_true", help="small sizes (CI): fewer cases, frames and pixels; the "
                                                       "page says which")
    add_shared(p, "--seed")  # the same seed gives the same JSON, apart from its 'timing' key
    p.add_argument("--out", help="output directory (default out/study-NAME-<time>/)")
    add_shared(p, "--force", "--json", "--scheduler")
    p.add_argument("--workers", **{**SHARED_OPTIONS["--workers"], "help": (
        "local workers (default: one per core, never more than the cases; with --fast 1, the cases in this process: "
        "at the fast sizes they cost less than worker processes that each import and compile the solvers again)")})
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
    seed = seed_arg(args.seed)
    workers = workers_arg(None if str(args.workers).strip() == "0" else args.workers)  # 0: its old "every core"
    if args.workers is None and args.fast:  # the library's own default (StudyOptions): fast cases in this process
        workers = 1
    out = prepare_output(out_dir(args, "study", args.name), args.force, is_dir=True)
    opts = StudyOptions(fast=args.fast, seed=seed, workers=workers, scheduler=args.scheduler,
                        progress=show_progress(args))
    from metafovea.parallel import heartbeat

    with heartbeat(f"study {args.name}", enabled=show_progress(args)):  # a full-size study's first minutes
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

"""``metafovea reconstruct`` file to file, as a user runs it: a simulated 96-frame 290 x 290 measurement (the paper's
camera, 10 um filter), 8-frame windows at stride 1 (89 outputs); each command in its own process, timed from
start to exit (interpreter start, reading, solving, writing and fsync included). Rows: lsq without scoring and
figures (the issue's >= 200 windows/s), lsq with scoring, alternating (unknown alpha, polariser model) per window.

    python benchmarks/bench_reconstruct_cli.py --reps 3 --dir /tmp/bench_rec

``--compare TREE`` (a source tree holding another version's ``metafovea/``, e.g. from
``git archive HEAD~3 metafovea | tar -x -C /tmp/base``) times that version and this one side by side, the two
alternating rep by rep so that a shared machine's load falls on both alike; both then run with ``python -S`` and
``PYTHONPATH=<tree>:<site-packages>`` (the editable install would otherwise load this tree for both), so their
seconds include a slightly different start-up than the rows above.
"""

from __future__ import annotations

import argparse
import os
import site
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]

CASES = (("lsq, --no-score --no-figures", ["--method", "lsq", "--no-score", "--no-figures"]),
         ("lsq, scored, --no-figures", ["--method", "lsq", "--no-figures"]),
         ("lsq, scored, figures", ["--method", "lsq"]),
         ("alternating (polariser model), scored", ["--method", "alternating", "--no-figures"]))


def _time(cmd: list[str], env: dict[str, str] | None = None) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, env=env)
    return time.perf_counter() - t0


def _load() -> str:
    return " ".join(open("/proc/loadavg").read().split()[:3])


def _compare(tree: Path, meas: Path, d: Path, reps: int, n_out: int) -> None:
    """This tree against ``tree``, rep by rep, on the first case (lsq, no scoring, no figures)."""
    sp = os.pathsep.join(site.getsitepackages())
    flags = ["reconstruct", str(meas), "--window", "8", "--out", str(d / "rec.npz"), "--force", *CASES[0][1]]
    times: dict[str, list[float]] = {}
    trees = [("this tree", HERE), (f"{tree}", tree)]
    for rep in range(reps):
        for name, root in trees if rep % 2 == 0 else trees[::-1]:  # alternate who goes first
            env = {**os.environ, "PYTHONPATH": f"{root}{os.pathsep}{sp}"}
            times.setdefault(name, []).append(_time([sys.executable, "-S", "-m", "metafovea", *flags], env))
    print(f"\nside by side ({CASES[0][0]}, python -S, {reps} reps each, load {_load()}):")
    print("| tree | best s | windows/s | median s | windows/s |")
    print("|---|---|---|---|---|")
    for name, t in times.items():
        b, med = min(t), statistics.median(t)
        print(f"| {name} | {b:.3f} | {n_out / b:.0f} | {med:.3f} | {n_out / med:.0f} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--dir", default="/tmp/bench_rec")
    ap.add_argument("--frames", type=int, default=96)
    ap.add_argument("--compare", default=None, help="a source tree of another version to time side by side")
    ap.add_argument("--cases", type=int, default=len(CASES), help="run only the first N rows")
    a = ap.parse_args(argv)
    d = Path(a.dir)
    d.mkdir(parents=True, exist_ok=True)
    meas = d / "meas.npz"
    exe = [sys.executable, "-m", "metafovea"]
    if not meas.exists():
        subprocess.run([*exe, "simulate", "--frames", str(a.frames), "--seed", "3", "--filter", "--out", str(meas),
                        "--no-tiff", "--no-preview"], check=True, capture_output=True)
    n_out = a.frames - 8 + 1
    print(f"{n_out} windows of 8 frames; {os.cpu_count()} CPUs; load {_load()}")
    print(f"| command | seconds (best of {a.reps}) | windows/s | median s | windows/s | s/window (best) |")
    print("|---|---|---|---|---|---|")
    for name, flags in CASES[:a.cases]:
        cmd = [*exe, "reconstruct", str(meas), "--window", "8", "--out", str(d / "rec.npz"), "--force", *flags]
        t = [_time(cmd) for _ in range(a.reps)]
        best, med = min(t), statistics.median(t)
        print(f"| {name} | {best:.2f} | {n_out / best:.0f} | {med:.2f} | {n_out / med:.0f} | {best / n_out:.4f} |",
              flush=True)
    if a.compare:
        _compare(Path(a.compare).resolve(), meas, d, a.reps, n_out)
    print(f"load after: {_load()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

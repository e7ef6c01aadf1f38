"""``metafovea reconstruct`` file to file, as a user runs it: a simulated 96-frame 290 x 290 measurement (the paper's
camera, 10 um filter), 8-frame windows at stride 1 (89 outputs); each command in its own process, timed from
start to exit (interpreter start, reading, solving, writing and fsync included). Rows: lsq without scoring and
figures (the issue's >= 200 windows/s), lsq with scoring, alternating (unknown alpha, polariser model) per window.

    python benchmarks/bench_reconstruct_cli.py --reps 3 --dir /tmp/bench_rec
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

CASES = (("lsq, --no-score --no-figures", ["--method", "lsq", "--no-score", "--no-figures"]),
         ("lsq, scored, --no-figures", ["--method", "lsq", "--no-figures"]),
         ("lsq, scored, figures", ["--method", "lsq"]),
         ("alternating (polariser model), scored", ["--method", "alternating", "--no-figures"]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--dir", default="/tmp/bench_rec")
    ap.add_argument("--frames", type=int, default=96)
    a = ap.parse_args(argv)
    d = Path(a.dir)
    d.mkdir(parents=True, exist_ok=True)
    meas = d / "meas.npz"
    exe = [sys.executable, "-m", "metafovea"]
    if not meas.exists():
        subprocess.run([*exe, "simulate", "--frames", str(a.frames), "--seed", "3", "--filter", "--out", str(meas),
                        "--no-tiff", "--no-preview"], check=True, capture_output=True)
    n_out = a.frames - 8 + 1
    print(f"{n_out} windows of 8 frames; {os.cpu_count()} CPUs; load {' '.join(open('/proc/loadavg').read().split()[:3])}")
    print("| command | seconds (best of %d) | windows/s | s/window |" % a.reps)
    print("|---|---|---|---|")
    for name, flags in CASES:
        best = float("inf")
        for _ in range(a.reps):
            t0 = time.perf_counter()
            subprocess.run([*exe, "reconstruct", str(meas), "--window", "8", "--out", str(d / "rec.npz"), "--force",
                            *flags], check=True, capture_output=True)
            best = min(best, time.perf_counter() - t0)
        print(f"| {name} | {best:.2f} | {n_out / best:.0f} | {best / n_out:.4f} |", flush=True)
    print(f"load after: {' '.join(open('/proc/loadavg').read().split()[:3])}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The JAX paths on whatever device JAX finds (a GPU when one is present, else the CPU): per-step times of the double
deep image prior at the paper's sizes, the compilation, and the device, so that one script gives the GPU figures for
BENCHMARKS.md on a GPU machine and the CPU baseline here.

    python benchmarks/bench_gpu.py [--sizes 128,290] [--channels 16,32,128] [--steps 20] [--frames 8]

The same code path as the CPU (no GPU-specific branch in metafovea): the device is JAX's default one, reported per
row (``info['device']`` of the reconstruction).
"""

from __future__ import annotations

import argparse
import os

from metafovea.reconstruct import dip
from metafovea.reconstruct.synthetic import measure, polariser_alpha, scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="128,290")
    ap.add_argument("--channels", default="16,32")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--frames", type=int, default=8)
    args = ap.parse_args()
    import jax

    print(f"jax {jax.__version__}, devices {[str(d) for d in jax.devices()]}, nproc {os.cpu_count()}, "
          f"load {open('/proc/loadavg').read().split()[:3]}")
    print("| size | channels | device | compile + first step (s) | per step (s) | steps |")
    print("|---|---|---|---|---|---|")
    for n in (int(v) for v in args.sizes.split(",")):
        x1, x2 = scene(n)
        a = polariser_alpha(args.frames)
        Y = measure(x1, x2, a, sigma=0.01, rng=0)
        for ch in (int(v) for v in args.channels.split(",")):
            r = dip(Y, alpha=a, channels=ch, steps=args.steps, rng=0, init="random", tol=0.0)
            t = r.timings
            steps = int(r.info.get("steps_run", args.steps))
            per = t.get("steps", float("nan")) / max(steps - 1, 1)
            print(f"| {n} | {ch} | {r.info.get('device')} | {t.get('compile', float('nan')):.2f} | {per:.3f} | "
                  f"{steps} |", flush=True)


if __name__ == "__main__":
    main()

"""The double deep image prior against the classical solvers on synthetic scenes (Markdown table to stdout).

    python benchmarks/bench_dip.py [--size 64] [--frames 8] [--sigmas 0.01,0.05] [--scenes camera:astronaut,...]
        [--steps 1500] [--channels 16] [--starts random,classical] [--alphas known,unknown] [--seed 0]

Scene: :func:`metafovea.reconstruct.synthetic.scene` (foveal:perifoveal scikit-image pictures in [0, 1], the
foveal constraint ``D x1 = C x2`` exact at scale 6), alpha_t = cos^2(2 pi 2 t / 12 + 0.3), Gaussian noise sigma
(seeded by ``--seed``, which also seeds the networks). PSNR with data range 1.

Like with like: with known alpha the DIP holds the true alpha and is compared with the known-alpha LSQ
(``lsq_known_alpha``, no denoising); with unknown alpha it is compared with ``alternating`` (foveal-constraint
gauge, its default TV prior; the last column: without a prior), and the DIP holds alternating's alpha
(``alpha_init='classical'``). Columns: the
start, channels, steps run of the budget (why it stopped), seconds per step and of the first step (compilation),
PSNR of x1 / x2, the classical solver's, and the mean |alpha error|.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from metafovea.reconstruct import alternating, dip, lsq_known_alpha
from metafovea.reconstruct.metrics import psnr
from metafovea.reconstruct.synthetic import measure, polariser_alpha, scene


def _row(label: str, r, x1, x2, a, cl, extra: str, plain: str) -> str:
    i = r.info
    p = (psnr(r.x1, x1, 1.0), psnr(r.x2, x2, 1.0))
    mae = float(np.mean(np.abs(r.alpha - a)))
    return (f"| {label} | {extra} | {i['channels']} | {i['steps_run']} / {i['steps']} ({i['stopped']}) | "
            f"{i['seconds_per_step']:.3f} | {r.timings['compile']:.1f} | {p[0]:.2f} / {p[1]:.2f} | "
            f"{cl[0]:.2f} / {cl[1]:.2f} | {p[0] - cl[0]:+.2f} / {p[1] - cl[1]:+.2f} | {mae:.4f} | {plain} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=64, help="scene size in pixels (square)")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--sigmas", default="0.01,0.05", help="noise levels, comma-separated")
    ap.add_argument("--scenes", default="camera:astronaut,chelsea:coffee", help="foveal:perifoveal pictures")
    ap.add_argument("--steps", type=int, default=1500, help="the DIP's step budget")
    ap.add_argument("--channels", type=int, default=16)
    ap.add_argument("--starts", default="random,classical", help="DIP starts to run")
    ap.add_argument("--alphas", default="known,unknown", help="known (true alpha held) and/or unknown")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-seconds", type=float, default=None)
    args = ap.parse_args()
    import jax

    print(f"machine: {platform.machine()}, nproc {os.cpu_count()}, load {open('/proc/loadavg').read().split()[:3]}, "
          f"JAX {jax.__version__} on {jax.devices()[0].platform}; {args.size} x {args.size}, {args.frames} frames, "
          f"budget {args.steps} steps, seed {args.seed}")
    print("\n| scene, sigma, alpha | start | channels | steps run / budget | s/step | compile (s) | PSNR x1 / x2 "
          "| classical x1 / x2 | DIP - classical | alpha MAE | alternating, no prior |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    a = polariser_alpha(args.frames)
    for sc in args.scenes.split(","):
        fov, peri = sc.split(":")
        x1, x2 = scene(args.size, foveal=fov, perifoveal=peri)
        for sigma in (float(s) for s in args.sigmas.split(",")):
            Y = measure(x1, x2, a, sigma=sigma, rng=args.seed, dtype=np.float32)
            for kind in args.alphas.split(","):
                known = kind == "known"
                t0 = time.perf_counter()
                ref = lsq_known_alpha(Y, a) if known else alternating(Y, scale=6, strict=False)
                t_cl = time.perf_counter() - t0
                cl = (psnr(ref.x1, x1, 1.0), psnr(ref.x2, x2, 1.0))
                plain = "-"
                if not known:
                    r0 = alternating(Y, scale=6, strict=False, prior="none")
                    plain = f"{psnr(r0.x1, x1, 1.0):.2f} / {psnr(r0.x2, x2, 1.0):.2f}"
                solver = "lsq" if known else "alternating + TV"
                label = f"{fov}:{peri}, {sigma:g}, {kind} ({solver} {1e3 * t_cl:.0f} ms)"
                for start in args.starts.split(","):
                    kw = {"alpha": a} if known else {"alpha_init": "classical", "scale": 6}
                    r = dip(Y, init=start, steps=args.steps, channels=args.channels, rng=args.seed,
                            max_seconds=args.max_seconds, **kw)
                    print(_row(label, r, x1, x2, a, cl, start, plain), flush=True)


if __name__ == "__main__":
    main()

"""Speed against error of the reconstruction methods (writes a Markdown table to stdout).

    /work/venv/bin/python benchmarks/bench_reconstruct.py [--size 290] [--frames 200] [--quick]

Synthetic scene (scikit-image camera / astronaut, foveal constraint exact), 8-frame windows,
alpha_t = cos^2(2 pi 2 t / 12 + 0.3), Gaussian noise sigma. PSNR with data range 1.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from functools import partial

import numpy as np

from metafovea.reconstruct import SlidingLSQ, alternating, snapshot, video
from metafovea.reconstruct.metrics import psnr
from metafovea.reconstruct.synthetic import measure, polariser_alpha, scene


def best_of(fn, n=3):
    best = np.inf
    out = None
    for _ in range(n):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def sliding(Y, a, window=8):
    """Push every frame of `Y` through a `SlidingLSQ` and solve each full window (the real-time path)."""
    s = SlidingLSQ(window)
    for t in range(len(Y)):
        s.push(Y[t], a[t])
        if s.ready:
            s.solve()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=290)
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--quick", action="store_true", help="small sizes (CI smoke run)")
    ap.add_argument("--dip-steps", type=int, default=3)
    args = ap.parse_args()
    n, T = (96, 40) if args.quick else (args.size, args.frames)
    x1, x2 = scene(n)
    a = polariser_alpha(T)
    rows = []
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, {platform.python_version()}; "
          f"scene {n}x{n}, {T} frames, window 8, stride 1")
    for sigma in (0.01, 0.05):
        Y = measure(x1, x2, a, sigma=sigma, rng=0, dtype=np.float32)
        K = T - 7
        # known alpha: throughput over the whole sequence
        dt, v = best_of(partial(video, Y, a, window=8))
        p1 = np.mean([psnr(v.x1[k], x1, 1.0) for k in range(0, K, max(1, K // 10))])
        p2 = np.mean([psnr(v.x2[k], x2, 1.0) for k in range(0, K, max(1, K // 10))])
        rows.append(("known alpha, video LSQ (batched)", sigma, K / dt, 1e3 * dt / K, p1, p2))
        dt, _ = best_of(partial(sliding, Y, a), 2)
        rows.append(("known alpha, SlidingLSQ (real time)", sigma, K / dt, 1e3 * dt / K, p1, p2))
        Ksub = min(K, 40)
        for dn in ("tv", "nlm") if sigma == 0.05 or not args.quick else ("tv",):
            Kd = Ksub if dn == "tv" else 5
            dt, vd = best_of(partial(video, Y[:Kd + 7], a[:Kd + 7], window=8, denoise=dn), 1)
            rows.append((f"known alpha, video LSQ + {dn}", sigma, Kd / dt, 1e3 * dt / Kd,
                         psnr(vd.x1[0], x1, 1.0), psnr(vd.x2[0], x2, 1.0)))
        W8 = Y[:8]
        for prior in (None, "tv"):
            dt, r = best_of(partial(alternating, W8, prior=prior), 3)
            rows.append((f"unknown alpha, alternating ({prior or 'no prior'}) + foveal gauge", sigma, 1 / dt, 1e3 * dt,
                         psnr(r.x1, x1, 1.0), psnr(r.x2, x2, 1.0)))
        dt, r = best_of(partial(alternating, W8, prior=None, gauge="none", init="means"), 3)
        rows.append(("unknown alpha, alternating, no gauge fix (paper init)", sigma, 1 / dt, 1e3 * dt,
                     psnr(r.x1, x1, 1.0), psnr(r.x2, x2, 1.0)))
        if sigma == 0.01:
            y0 = measure(x1, x2, [0.5], sigma=sigma, rng=0)[0]
            dt, r = best_of(partial(snapshot, y0, iterations=100), 1)
            rows.append(("snapshot (1 frame, 100 L-BFGS its)", sigma, 1 / dt, 1e3 * dt,
                         psnr(r.x1, x1, 1.0), psnr(r.x2, x2, 1.0)))
            rows.append(("  (unseparated frame as both images)", sigma, float("nan"), float("nan"),
                         psnr(y0, x1, 1.0), psnr(y0, x2, 1.0)))
            if args.dip_steps:
                from metafovea.reconstruct import dip

                r = dip(W8, channels=32, depth=3, steps=args.dip_steps, rng=0)
                sps = r.info["seconds_per_step"]
                rows.append((f"DIP 32 ch, s/step (PSNR after {args.dip_steps} steps meaningless)", sigma,
                             1 / sps, 1e3 * sps, float("nan"), float("nan")))
    print("\n| method | sigma | windows/s | ms per window | PSNR x1 (dB) | PSNR x2 (dB) |")
    print("|---|---|---|---|---|---|")
    for name, s, fps, ms, p1, p2 in rows:
        print(f"| {name} | {s:g} | {fps:,.1f} | {ms:.3f} | {p1:.2f} | {p2:.2f} |")


if __name__ == "__main__":
    main()

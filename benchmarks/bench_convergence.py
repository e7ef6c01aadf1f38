"""How well the library's convergence estimates bound the true truncation error: random posts of the paper's
platform solved at harmonics 4-14 and at a high-truncation reference (default 22; minutes on 2 cores).

    python benchmarks/bench_convergence.py [--posts 96] [--seed 2026] [--reference 22]
"""

from __future__ import annotations

import argparse
import os

import numpy as np

from metafovea.rcwa.posts import convergence_bound, post_response


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--posts", type=int, default=96)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--reference", type=int, default=22)
    a = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}; {a.posts} posts, seed {a.seed}, reference M = {a.reference}")
    g = np.random.default_rng(a.seed)
    wx, wy = np.round(g.uniform(0.5, 3.5, a.posts), 3), np.round(g.uniform(0.5, 3.5, a.posts), 3)
    t = {M: post_response(wx, wy, 10.0, harmonics=M, polarizations=("x",)).t_x
         for M in (*range(4, 15), a.reference)}
    ref = t[a.reference]
    print(f"reference check |t(14) - t(ref)|: median {np.median(np.abs(t[14] - ref)):.2g}, "
          f"max {np.max(np.abs(t[14] - ref)):.2g}")
    for M in (8, 10, 12):
        true = np.abs(t[M] - ref)
        step = np.abs(t[M] - t[M - 2])
        both = np.maximum(step, np.abs(t[M] - t[M - 4]))
        bound = convergence_bound(t[M], t[M - 2], t[M - 4])
        print(f"M = {M}: true error median {np.median(true):.2g} max {true.max():.2g}; holds: step "
              f"{np.mean(true <= step):.3f}, max(step, step4) {np.mean(true <= both):.3f}, "
              f"2x {np.mean(true <= 2 * both):.3f}, "
              f"bound (3x) {np.mean(true <= bound):.3f}; true/step median {np.median(true / step):.2f} "
              f"q95 {np.quantile(true / step, 0.95):.1f} max {np.max(true / step):.1f}")


if __name__ == "__main__":
    main()

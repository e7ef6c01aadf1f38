"""Blind fixed-pattern-noise estimates against no handling and the true pattern (BENCHMARKS.md, "Blind fixed-pattern
noise"): for each simulated Measurement file, known-alpha LSQ over all frames, then `estimate_fpn` (foveal at ranks
2-20, with the stored gain, and, with `tv`, the TV low-rank prior); FPN rms error (mean removed), level-free PSNR of
x1/x2, seconds. Make the files with

    python -c "from metafovea.config import SystemDesign; from metafovea.imaging.simulate import simulate; \
        simulate(SystemDesign.paper(), 'bars', frames=96, rng=5, filter_enabled=True).save('/tmp/bars.npz')"

    python benchmarks/bench_fpn_blind.py /tmp/bars.npz [more.npz ...] [--tv]
"""
import time
from functools import partial
from pathlib import Path

import numpy as np

from metafovea.measurement import Measurement
from metafovea.parallel import blas_threads
from metafovea.reconstruct import lsq_known_alpha
from metafovea.reconstruct.fpn import estimate_fpn
from metafovea.reconstruct.metrics import psnr


def row(est, truth, name, F, sec=None, extra=""):
    """Print one table row: the FPN rms error of `F` (mean removed) and the level-free PSNR of x1/x2 after
    subtracting `F` from the LSQ estimates `est` = (x1, x2), against `truth` = (x1, x2, pattern)."""
    (x1p, x2p), (t1, t2, Ft) = est, truth
    d = F - Ft
    err = np.sqrt(np.mean((d - d.mean())**2))
    e1, e2 = x1p - F, x2p - F
    # level-free PSNR (the pattern's mean is not identified: each image's mean error removed)
    print(f"| {name} | {err:.2f} | {psnr(e1 - (e1-t1).mean(), t1):.2f} | {psnr(e2-(e2-t2).mean(), t2):.2f} | "
          f"{'-' if sec is None else f'{sec:.2f}'} | {extra}", flush=True)


def timed_fpn(x1p, x2p, fc, **kw):
    """`estimate_fpn` on one BLAS thread; returns (pattern, info, seconds)."""
    with blas_threads(1):
        t0 = time.perf_counter()
        F, info = estimate_fpn(x1=x1p, x2=x2p, **fc.as_kwargs(), **kw)
        return F, info, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> None:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+", type=Path, help="simulated Measurement files (.npz, with the FPN truth)")
    ap.add_argument("--tv", action="store_true", help="also the TV low-rank prior (slow)")
    args = ap.parse_args(argv)
    for path in args.files:
        m = Measurement.load(path)
        fc = m.foveal_constraint
        with blas_threads(1):
            r = lsq_known_alpha(m.frames.astype(np.float64), m.alpha)
        x1p, x2p = r.x1, r.x2
        t1, t2 = m.truth_x1.astype(float), m.truth_x2.astype(float)
        if t1.ndim == 3:
            t1, t2 = t1.mean(0), t2.mean(0)
        Ft = m.fpn.astype(float)
        print(f"\n{path}: {m.meta['scene']} {m.shape}, FPN rms {Ft.std():.2f} DN, x1 range {np.ptp(t1):.1f}, "
              f"x2 {np.ptp(t2):.1f}")
        rep = partial(row, (x1p, x2p), (t1, t2, Ft))
        rep("none", np.zeros_like(Ft))
        rep("true pattern subtracted", Ft - Ft.mean())
        for rk in (2, 4, 6, 10, 20):
            F, info, s = timed_fpn(x1p, x2p, fc, rank=rk)
            rep(f"foveal, rank {rk}" + (" (default)" if rk == 4 else ""), F, s,
                f"g {info.get('foveal_gain', float('nan')):.3f} {info.get('fallback', '')}")
        F, info, _ = timed_fpn(x1p, x2p, fc, fit_gain=False)
        rep("foveal, rank 4, stored gain", F, None, f"g {info.get('foveal_gain', float('nan')):.3f}")
        if args.tv:
            F, info, s = timed_fpn(x1p, x2p, fc, method="tv")
            rep("TV prior (previous --fpn prior)", F, s, f"rank {info['rank']}")


if __name__ == "__main__":
    main()

"""PSF-aware reconstruction against the scene: the joint Wiener (and TV) estimate of
:mod:`metafovea.reconstruct.deconvolve` beside the Wiener bound and the hazy sensor image, per scene and spectral
case (known alpha, the simulator's true FPN subtracted, so that only the deconvolution is measured).

    python benchmarks/bench_deconvolve.py [--scenes siemens-star bars coins] [--frames 48] [--tv]
        [--prior-scales geometric grid]

Each prior scale (``separate_deconvolve``'s ``prior_scale``) runs on the same simulated measurement, side by side.
"""

from __future__ import annotations

import argparse
import os
import time
import warnings
from pathlib import Path

from metafovea.config import load_system
from metafovea.imaging.simulate import simulate
from metafovea.reconstruct.deconvolve import deconvolve_measurement


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["siemens-star", "bars", "coins"])
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--tv", action="store_true", help="also the TV estimate (~20x slower)")
    ap.add_argument("--prior-scales", nargs="+", default=["geometric"], help="prior_scale values, side by side")
    args = ap.parse_args()
    system = load_system(Path(__file__).resolve().parents[1] / "designs" / "system.toml")
    print(f"nproc {os.cpu_count()}, load {open('/proc/loadavg').read().split()[:3]}")
    print(f"{'scene':<14} {'band':<8} {'method':<7} {'scale':<9} {'s':>6}  x1: {'est':>6} {'bound':>6} {'hazy':>6}   "
          f"x2: {'est':>6} {'bound':>6} {'hazy':>6}   T rms x1, x2 (K)")
    for scene in args.scenes:
        for filt in (False, True):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                m = simulate(system, scene, rng=args.seed, frames=args.frames, filter_enabled=filt)
            for method, scale in ((me, sc) for me in (("wiener", "tv") if args.tv else ("wiener",))
                                  for sc in args.prior_scales):
                t = time.perf_counter()
                d = deconvolve_measurement(m, fpn=m.fpn, method=method, prior_scale=scale)
                sec = time.perf_counter() - t
                sc = d.info["scores"]
                print(f"{scene:<14} {'10 um' if filt else '8-14 um':<8} {method:<7} {scale:<9} {sec:>6.1f}      "
                      f"{sc['psnr_x1']:>6.2f} {sc['wiener_bound_psnr_x1']:>6.2f} {sc['psnr_x1_hazy_image']:>6.2f}"
                      f"       {sc['psnr_x2']:>6.2f} {sc['wiener_bound_psnr_x2']:>6.2f} "
                      f"{sc['psnr_x2_hazy_image']:>6.2f}   {sc['temperature_rmse_x1_k']:.2f}, "
                      f"{sc['temperature_rmse_x2_k']:.2f}", flush=True)


if __name__ == "__main__":
    main()

"""PSF-aware reconstruction against the scene: the joint Wiener (and TV) estimate of
:mod:`metafovea.reconstruct.deconvolve` beside the Wiener bound and the hazy sensor image, per scene and spectral
case (known alpha; the simulator's true FPN subtracted, so that only the deconvolution is measured, or with
``--calibration-frames N`` the FPN estimated from N shutter frames and its error counted, as ``metafovea validate``
does).

    python benchmarks/bench_deconvolve.py [--scenes siemens-star bars coins] [--frames 48] [--seeds 5] [--tv]
        [--prior-scales geometric grid] [--calibration-frames 16] [--polarizer free]

Each prior scale (``separate_deconvolve``'s ``prior_scale``) runs on the same simulated measurement, side by side.
The last line counts the channel cases below the bound, the worst and the mean margin (dB) per method and scale.
To compare two trees on the same cases, run the script of one with ``PYTHONPATH`` set to the other.
"""

from __future__ import annotations

import argparse
import os
import time
import warnings
from pathlib import Path

import numpy as np

from metafovea.config import load_system
from metafovea.imaging.simulate import simulate
from metafovea.reconstruct.deconvolve import deconvolve_measurement
from metafovea.reconstruct.fpn import estimate_fpn


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["siemens-star", "bars", "coins"])
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--seeds", type=int, nargs="+", default=[5])
    ap.add_argument("--tv", action="store_true", help="also the TV estimate (~20x slower)")
    ap.add_argument("--prior-scales", nargs="+", default=["geometric"], help="prior_scale values, side by side")
    ap.add_argument("--calibration-frames", type=int, default=0,
                    help="estimate the FPN from this many shutter frames (its error counted) instead of the true one")
    ap.add_argument("--polarizer", default="sync", choices=("sync", "free"), help="the simulated polariser's mode")
    args = ap.parse_args()
    margins: dict[tuple[str, str], list[float]] = {}
    system = load_system(Path(__file__).resolve().parents[1] / "designs" / "system.toml")
    print(f"nproc {os.cpu_count()}, load {open('/proc/loadavg').read().split()[:3]}")
    print(f"{'scene':<14} {'seed':>3} {'band':<8} {'method':<7} {'scale':<9} {'s':>6}  "
          f"x1: {'est':>6} {'bound':>6} {'hazy':>6}   "
          f"x2: {'est':>6} {'bound':>6} {'hazy':>6}   T rms x1, x2 (K)")
    for scene, seed in ((sc, se) for sc in args.scenes for se in args.seeds):
        for filt in (False, True):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                m = simulate(system, scene, rng=seed, frames=args.frames, filter_enabled=filt,
                             calibration_frames=args.calibration_frames, polarizer_mode=args.polarizer)
            fpn, fe = m.fpn, 0.0
            if args.calibration_frames:
                fpn, info = estimate_fpn(calibration=m.extras["calibration"])
                fe = info.get("error_rms_dn") or 0.0
            for method, scale in ((me, sc) for me in (("wiener", "tv") if args.tv else ("wiener",))
                                  for sc in args.prior_scales):
                t = time.perf_counter()
                d = deconvolve_measurement(m, fpn=fpn, fpn_error_dn=fe, method=method, prior_scale=scale)
                sec = time.perf_counter() - t
                sc = d.info["scores"]
                margins.setdefault((method, scale), []).extend(
                    sc[f"psnr_x{i}"] - sc[f"wiener_bound_psnr_x{i}"] for i in (1, 2))
                print(f"{scene:<14} {seed:>3} {'10 um' if filt else '8-14 um':<8} {method:<7} {scale:<9} {sec:>6.1f}  "
                      f"{sc['psnr_x1']:>6.2f} {sc['wiener_bound_psnr_x1']:>6.2f} {sc['psnr_x1_hazy_image']:>6.2f}"
                      f"       {sc['psnr_x2']:>6.2f} {sc['wiener_bound_psnr_x2']:>6.2f} "
                      f"{sc['psnr_x2_hazy_image']:>6.2f}   {sc['temperature_rmse_x1_k']:.2f}, "
                      f"{sc['temperature_rmse_x2_k']:.2f}", flush=True)
    for (method, scale), v in margins.items():
        r = np.array(v)
        print(f"{method} {scale}: below the bound in {int(np.sum(r < 0))} of {r.size} channel cases, worst "
              f"{r.min():+.2f} dB, mean {r.mean():+.2f} dB")


if __name__ == "__main__":
    main()

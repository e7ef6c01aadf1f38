"""``reconstruct --method auto``: the motion test, the cost model and the choice, against what each candidate does.

For each scene (static: bars, siemens-star; moving: hand, parking-lot), a small simulated recording (the paper's
camera with Airy PSFs and each lens alone, ``--size`` pixels square, ``--frames`` frames, 16 shutter frames) is
reconstructed with every candidate of :func:`metafovea.reconstruct.auto.choose_method` (the file's solver, one window
or sliding windows of 8 frames at strides 1/2/4/8, with and without TV) and the PSF-aware steps; the table gives each
candidate's wall seconds (the best of ``--repeats`` after a warm-up) against the cost model's prediction, and its
error per frame: each frame's nearest output against that frame's truth (PSNR, dB; for a moving scene one window's
images are a mean over time, which the pipeline's own score, against the truth averaged over each output's frames,
does not penalise). The motion test's verdict and the choice with no time limit close each scene.

    python benchmarks/bench_auto.py                          # 96 x 96, 24 frames
    python benchmarks/bench_auto.py --size 192 --frames 48 --json auto.json
    python benchmarks/bench_auto.py --unknown-alpha          # free-running polariser, alpha not logged: alternating
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from dataclasses import replace

import numpy as np


def per_frame_psnr(m, res) -> tuple[float, float]:
    """Each frame's nearest output against that frame's truth: PSNR over all frames (dB), x1 and x2."""
    T = m.shape[0]
    mid = np.array([(a + b - 1) / 2 for a, b in res.spans])
    out = []
    for est, truth in ((res.x1s, m.truth_x1), (res.x2s, m.truth_x2)):
        t = truth if truth.ndim == 3 else np.broadcast_to(truth, (T,) + truth.shape)
        err = [np.mean((est[int(np.argmin(np.abs(mid - f)))].astype(np.float64) - t[f]) ** 2) for f in range(T)]
        out.append(float(10 * np.log10(np.ptp(t) ** 2 / np.mean(err))))
    return out[0], out[1]


def _best(fn, repeats: int):
    fn()  # warm-up
    best, out = float("inf"), None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return out, best


def run_scene(system, scene: str, frames: int, repeats: int, unknown_alpha: bool = False) -> dict:
    from metafovea.imaging import simulate
    from metafovea.reconstruct import reconstruct_measurement
    from metafovea.reconstruct.auto import choose_method, motion_of, predicted_seconds
    from metafovea.reconstruct.deconvolve import deconvolve_result

    m = simulate(system, scene, frames=frames, psf="airy", optical_train=False, rng=1,
                 polarizer_mode="free" if unknown_alpha else "sync")
    if unknown_alpha:  # a free-running polariser whose angle the camera does not log
        m = replace(m, alpha=None)
    T, H, W = m.shape
    mo = motion_of(m)
    choice = choose_method(m)
    rows = []
    for window, strides in ((T, (1,)), (8, (1, 2, 4, 8))):
        for stride in strides:
            for denoise in ("tv", None):
                res, sec = _best(lambda w=window, s=stride, d=denoise: reconstruct_measurement(
                    m, choice.method, window=w, stride=s, denoise=d, score_truth=False), repeats)
                pred = predicted_seconds(choice.method, T, H * W, window, stride, denoise=denoise)
                rows.append({"method": choice.method, "window": window, "stride": stride, "denoise": denoise,
                             "seconds": sec, "predicted_s": pred, "psnr_per_frame": per_frame_psnr(m, res)})
    one = reconstruct_measurement(m, choice.method, window=T, score_truth=False)
    for dec in ("wiener", "wavelet"):
        _, sec = _best(lambda d=dec: deconvolve_result(m, one, d), 1)
        rows.append({"method": f"scene {dec}", "window": T, "stride": 1, "denoise": None, "seconds": sec,
                     "predicted_s": predicted_seconds(choice.method, T, H * W, T, 1, deconvolve=dec)
                     - predicted_seconds(choice.method, T, H * W, T, 1), "psnr_per_frame": None})
    return {"scene": scene, "shape": [T, H, W], "motion": mo.summary(), "choice": choice.summary(), "rows": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=96)
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--scenes", nargs="+", default=["bars", "siemens-star", "hand", "parking-lot"])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--unknown-alpha", action="store_true", help="free-running polariser, alpha not in the file "
                    "(the alternating solver)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    from metafovea.config import SystemDesign

    s = SystemDesign.paper()
    n = args.size
    px = (max(n, s.sensor.pixels[0]), max(n, s.sensor.pixels[1]))
    s = replace(s, sensor=replace(s.sensor, crop=(n, n), pixels=px))
    load0 = open("/proc/loadavg").read().split()[:3]
    out = []
    for scene in args.scenes:
        r = run_scene(s, scene, args.frames, args.repeats, args.unknown_alpha)
        out.append(r)
        mo = r["motion"]
        print(f"\n{scene} {r['shape']}: {'moving' if mo['moving'] else 'static'}, "
              f"{100 * mo['changing_fraction']:.2g} % of the pixels changing, residual / noise "
              f"{mo['residual_over_noise']:.3g}; auto: {r['choice']['why']}")
        print(f"  {'candidate':40s} {'seconds':>9s} {'predicted':>9s}  per-frame PSNR x1 / x2 (dB)")
        for row in r["rows"]:
            name = (f"{row['method']} window {row['window']} stride {row['stride']}"
                    + (f" + {row['denoise']}" if row["denoise"] else ""))
            ps = row["psnr_per_frame"]
            print(f"  {name:40s} {row['seconds']:9.4f} {row['predicted_s']:9.4f}  "
                  + ("" if ps is None else f"{ps[0]:.2f} / {ps[1]:.2f}"))
    print(f"\nload average {load0} -> {open('/proc/loadavg').read().split()[:3]}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()

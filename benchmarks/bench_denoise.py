"""Denoiser defaults by measurement: Chambolle TV (weight = c sigma, iterations), non-local means (h = c sigma) and
the bilateral filter on natural and thermal-like images at sigma 0.01-0.05 (images in [0, 1]); each method's
PSNR-optimal factor per image and noise level, and what the module's default rule loses against it.

    python benchmarks/bench_denoise.py [--size 256] [--seeds 2]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

SIGMAS = (0.01, 0.02, 0.03, 0.05)
IMAGES = ("camera", "astronaut", "coins", "moon", "thermal")


def _image(name: str, n: int) -> np.ndarray:
    from skimage.transform import resize

    if name == "thermal":  # a simulated sensor image of the paper's Siemens star (PSF-blurred, smooth)
        y, x = np.mgrid[-1:1:n * 1j, -1:1:n * 1j]
        r, th = np.hypot(x, y), np.arctan2(y, x)
        star = 0.5 + 0.5 * np.sign(np.sin(18 * th)) * (r < 0.9)
        from scipy.ndimage import gaussian_filter

        return gaussian_filter(0.2 + 0.6 * star, 1.5)
    from metafovea.reconstruct.synthetic import gray_image

    return resize(gray_image(name), (n, n), anti_aliasing=True)


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(np.ptp(b) ** 2 / np.mean((a - b) ** 2)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--seeds", type=int, default=2)
    a = ap.parse_args(argv)
    from skimage.restoration import denoise_bilateral, denoise_nl_means, denoise_tv_chambolle

    from metafovea.reconstruct.denoise import denoise

    tv_c = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0)
    nlm_c = (0.6, 0.8, 1.0, 1.2)
    print(f"load {os.getloadavg()[0]:.2f}; {a.size}^2 images, {a.seeds} noise seeds")
    print("| image | sigma | noisy | default tv | best tv (c, iters) | default nlm | best nlm (c) | bilateral | "
          "ms tv / nlm / bilateral (default) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in IMAGES:
        x = _image(name, a.size)
        for sig in SIGMAS:
            res: dict = {}
            ms: dict = {}
            for seed in range(a.seeds):
                y = x + np.random.default_rng(seed).normal(0, sig, x.shape)
                res.setdefault("noisy", []).append(_psnr(y, x))
                for m in ("tv", "nlm", "bilateral"):
                    t0 = time.perf_counter()
                    res.setdefault(m, []).append(_psnr(denoise(y, m, sigma=sig), x))
                    ms[m] = 1e3 * (time.perf_counter() - t0)
                for c in tv_c:
                    for it in (10, 50, 200):
                        res.setdefault(("tv", c, it), []).append(
                            _psnr(denoise_tv_chambolle(y, weight=c * sig, max_num_iter=it), x))
                for c in nlm_c:
                    res.setdefault(("nlm", c), []).append(
                        _psnr(denoise_nl_means(y, h=c * sig, sigma=sig, patch_size=5, patch_distance=5,
                                               fast_mode=True), x))
            mean = {k: float(np.mean(v)) for k, v in res.items()}
            btv = max((k for k in mean if isinstance(k, tuple) and k[0] == "tv"), key=mean.get)
            bnl = max((k for k in mean if isinstance(k, tuple) and k[0] == "nlm"), key=mean.get)
            print(f"| {name} | {sig:g} | {mean['noisy']:.2f} | {mean['tv']:.2f} | {mean[btv]:.2f} ({btv[1]:g}, "
                  f"{btv[2]}) | {mean['nlm']:.2f} | {mean[bnl]:.2f} ({bnl[1]:g}) | {mean['bilateral']:.2f} | "
                  f"{ms['tv']:.0f} / {ms['nlm']:.0f} / {ms['bilateral']:.0f} |", flush=True)
    _ = denoise_bilateral  # the module's bilateral rule is the one measured
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

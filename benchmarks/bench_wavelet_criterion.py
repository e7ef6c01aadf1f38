"""How the Fourier-wavelet estimate's regularisation, chosen from the data by its risk criterion
(:mod:`metafovea.reconstruct.wavelet`, eq. 2), follows the noise and the PSF, against the linear Wiener bound.

An independent forward model (as tests/reconstruct/test_deconvolve.py's): piecewise-constant scenes and Gaussian
1/f^2 textures three times the crop, blurred by direct convolution with a foveal kernel (a Gaussian core holding
``core`` of the power, the rest a 12 px disk: the haze) and a perifoveal one, cropped, mixed with alpha over 24
frames, white noise ``sigma``. Per case: the ``tau`` chosen per channel, the wavelet and Wiener margins to the bound
(dB), and the tau whose estimate is truly best (the criterion's regret, dB).

    python benchmarks/bench_wavelet_criterion.py [--n 96] [--seeds 1 2]
"""

from __future__ import annotations

import argparse
import os

import numpy as np
from scipy.signal import fftconvolve

import metafovea.reconstruct.deconvolve as dc
from metafovea.reconstruct import ChannelPSFs, separate_deconvolve, wiener_bound
from metafovea.reconstruct.metrics import psnr
from metafovea.reconstruct.wavelet import TAUS


def _disk(radius: float, n: int) -> np.ndarray:
    u = np.arange(n) - n // 2
    d = (np.hypot(u[:, None], u[None, :]) <= radius).astype(float)
    return d / d.sum()


def _gauss(sigma: float, n: int) -> np.ndarray:
    u = np.arange(n) - n // 2
    g = np.exp(-0.5 * (u[:, None] ** 2 + u[None, :] ** 2) / sigma ** 2)
    return g / g.sum()


def scene(kind: str, rng: np.random.Generator, big: int) -> np.ndarray:
    if kind == "blocks":
        s = np.full((big, big), 200.0)
        for _ in range(40 * big // 288):
            y, x = rng.integers(0, big - 8, 2)
            h, w = rng.integers(3, big // 12, 2)
            s[y:y + h, x:x + w] += rng.uniform(-60, 60)
        return s
    f = np.hypot(np.fft.fftfreq(big)[:, None], np.fft.fftfreq(big)[None, :])
    f[0, 0] = 1.0
    return 200.0 + 3.0 * np.real(np.fft.ifft2(np.fft.fft2(rng.standard_normal((big, big))) / f))


def case(kind: str, seed: int, sigma: float, core: float, n: int, T: int = 24):
    rng = np.random.default_rng(seed)
    big = 3 * n
    k1 = np.pad(core * _gauss(1.2, 15), 10) + (1 - core) * _disk(12, 35)
    k2 = 0.7 * np.pad(_gauss(0.8, 9), 6) + 0.3 * _disk(6, 21)
    s1, s2 = scene(kind, rng, big), scene(kind, rng, big)
    c = slice(n, 2 * n)
    u1 = fftconvolve(s1, k1, mode="same")[c, c]
    u2 = fftconvolve(s2, k2, mode="same")[c, c]
    a = np.cos(np.linspace(0, 2 * np.pi, T, endpoint=False) + 0.3) ** 2
    frames = a[:, None, None] * u1 + (1 - a[:, None, None]) * u2 + rng.normal(0, sigma, (T, n, n))
    return frames, a, ChannelPSFs((k1, k2)), (s1[c, c], s2[c, c])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=96)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1])
    args = ap.parse_args()
    print(f"nproc {os.cpu_count()}, load {open('/proc/loadavg').read().split()[:3]}")
    print(f"{'scene':<8} {'seed':>4} {'sigma':>5} {'core':>5}   {'tau x1':>7} {'tau x2':>7}   "
          f"{'wavelet x1':>10} {'x2':>6}   {'wiener x1':>9} {'x2':>6}   {'best tau x1':>11} {'x2':>6}   regret x1, x2")
    for kind in ("blocks", "texture"):
        for seed in args.seeds:
            for sigma in (0.3, 1.0, 3.0, 10.0):
                for core in (0.6, 0.3, 0.1):
                    fr, a, psfs, truth = case(kind, seed, sigma, core, args.n)
                    bound = wiener_bound(fr, a, psfs, truth, sigma=sigma)
                    pb = [psnr(bound[i], truth[i]) for i in range(2)]
                    w = separate_deconvolve(fr, a, psfs, method="wavelet")
                    li = separate_deconvolve(fr, a, psfs, method="wiener")
                    mw = [psnr(w.scene[i], truth[i]) - pb[i] for i in range(2)]
                    ml = [psnr(li.scene[i], truth[i]) - pb[i] for i in range(2)]
                    # each tau alone: the truly best one (the criterion's regret)
                    best = [(-np.inf, None), (-np.inf, None)]
                    saved = dc.TAUS
                    try:
                        for tau in TAUS:
                            dc.TAUS = (tau,)
                            e = separate_deconvolve(fr, a, psfs, method="wavelet")
                            for i in range(2):
                                p = psnr(e.scene[i], truth[i]) - pb[i]
                                if p > best[i][0]:
                                    best[i] = (p, tau)
                    finally:
                        dc.TAUS = saved
                    tw, regret = w.info["tau"], [best[i][0] - mw[i] for i in range(2)]
                    print(f"{kind:<8} {seed:>4} {sigma:>5.1f} {core:>5.1f}   {tw[0]:>7.4g} {tw[1]:>7.4g}   "
                          f"{mw[0]:>+10.2f} {mw[1]:>+6.2f}   {ml[0]:>+9.2f} {ml[1]:>+6.2f}   "
                          f"{best[0][1]:>11.4g} {best[1][1]:>6.4g}   {regret[0]:.2f}, {regret[1]:.2f}", flush=True)
    print(f"load {open('/proc/loadavg').read().split()[:3]}")


if __name__ == "__main__":
    main()

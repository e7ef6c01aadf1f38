"""The production on-axis engine ('hankel', the direction-sine / Debye model) against the exact Rayleigh-Sommerfeld
engine ('rs') at defocused wavelengths of the paper's lenses (continuous phase, the sensor plane at f): the largest
difference relative to the peak on the fine grid and over 34 um pixels (17 um through the 0.5x relay), beside the
hankel engine's own error estimates (fine grid: psf.debye_error_bound plus quadrature; pixels:
sensor.debye_pixel_error), which must be at least the differences.

    python benchmarks/bench_debye_defocus.py [--wavelengths 10.05 10.3 11] [--max-window-um 2500]
"""

from __future__ import annotations

import argparse
import os

import numpy as np

from metafovea.config import SystemDesign
from metafovea.optics import build_pupils, debye_pixel_error
from metafovea.optics.psf import psf


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--wavelengths", type=float, nargs="+", default=[10.05, 10.3, 11.0])
    ap.add_argument("--max-window-um", type=float, default=2500.0)
    args = ap.parse_args(argv)
    s = SystemDesign.paper()
    print(f"nproc {os.cpu_count()}, load {os.getloadavg()[0]:.2f}")
    for name, lens in (("perifoveal", s.perifoveal), ("foveal", s.foveal)):
        for wl in args.wavelengths:
            win = max(300.0, 2.6 * lens.radius_um * abs(1 - lens.wavelength_um / wl))  # the blur disk, twice over
            if win > args.max_window_um:
                print(f"{name} {wl} um: window {win:.0f} um > --max-window-um, skipped")
                continue
            res = {eng: psf(lens, wavelengths_um=[wl], engine=eng, window_um=win, pitch_um=34.0 / 7, error=1e-3,
                            allow_truncation=True) for eng in ("hankel", "rs")}
            a, b = res["hankel"].intensity, res["rs"].intensity
            n = (a.shape[0] // 7) * 7
            pa = a[:n, :n].reshape(n // 7, 7, n // 7, 7).sum((1, 3))
            pb = b[:n, :n].reshape(n // 7, 7, n // 7, 7).sum((1, 3))
            est_pix = debye_pixel_error(build_pupils(lens, wl).focus, a.max() / (34.0 / 7) ** 2, 34.0) / pb.max()
            print(f"{name} {wl} um: fine max|diff|/peak {np.abs(a - b).max() / b.max():.3f} (estimate "
                  f"{res['hankel'].error_estimate:.3f}), 34 um pixels {np.abs(pa - pb).max() / pb.max():.4f} "
                  f"(estimate {est_pix:.3f})")
    print(f"load {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The production on-axis engine ('hankel', the direction-sine / Debye model) against the exact Rayleigh-Sommerfeld
engine ('rs') at defocused wavelengths of the paper's lenses (continuous phase, the sensor plane at f): the largest
difference relative to the peak on the fine grid and over 34 um pixels (17 um through the 0.5x relay), beside the
hankel engine's own error estimates (fine grid: psf.debye_error_bound plus quadrature; pixels:
sensor.debye_pixel_error), which must be at least the differences. Then the band: sensor_psf on axis over the
10 um filter's band (9.75-10.25 um, 11 bins, 300 K) against the exact engine over the same 34 um pixels (box filter),
beside its error estimate.

    python benchmarks/bench_debye_defocus.py [--wavelengths 10.05 10.3 11] [--max-window-um 2500] [--no-band]
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
    ap.add_argument("--no-band", action="store_true", help="skip the band comparison (~1 min)")
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
    if not args.no_band:
        band(s)
    print(f"load {os.getloadavg()[0]:.2f}")
    return 0


def band(s: SystemDesign) -> None:
    """sensor_psf over the filter's band against the exact engine, both lenses."""
    import warnings

    from metafovea.errors import NotConvergedWarning
    from metafovea.optics import box_integrate, sensor_psf
    from metafovea.radiometry import psf_wavelengths

    wl, w = psf_wavelengths((9.75, 10.25), design_um=10.0, n=11, temperature_k=300.0)
    for name, size in (("perifoveal", 21), ("foveal", 31)):
        lens = getattr(s, name)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotConvergedWarning)
            S = sensor_psf(lens, pixel_pitch_um=34.0, wavelengths_um=wl, weights=w, size_px=size, error=1e-4)
        kw = dict(wavelengths_um=wl, weights=w, window_um=size * 34.0 - 1e-6, pitch_um=34.0 / 7, error=1e-5,
                  allow_truncation=True, quantize=True, lattice=True)
        R = psf(lens, engine="rs", **kw)
        n = size * 7
        o = (R.shape[0] - n) // 2
        d = S.intensity - box_integrate(R.intensity[o:o + n, o:o + n], 7)
        d -= np.median(d)  # the haze orders: a uniform floor over the window
        print(f"{name} band 9.75-10.25 um, 34 um pixels: max|diff|/peak {np.abs(d).max() / S.intensity.max():.1e} "
              f"(estimate {S.error_estimate:.1e}, of which Debye {S.info['debye_error_estimate']:.1e})")


if __name__ == "__main__":
    raise SystemExit(main())

"""Speed against error of the PSF engines for the paper's lenses, and the two-lens report time.

Sections (all errors: max |I - I_ref| / peak of the reference):
1. monochromatic, 10 um, continuous phase: hankel and mft against the same engine at 1e-12 / 1.6x nodes;
2. broadband sensor PSFs (17 um pixels, 8-14 um, 61 wavelength bins geometric around lambda0, quantised + lattice):
   on axis the batched Hankel (all wavelengths wave-optical) against per-wavelength ``hankel_grid`` (with the
   focal-shift correction, ``Pupil.li_wolf``); off axis
   the hybrid (batched MFT for the near-focus wavelengths, rays for the rest) against all-wave at 9.7-10.3 um;
3. the geometric engine against the wave engines at single defocused wavelengths;
4. with --report: ``metafovea psf designs/foveal.toml designs/perifoveal.toml`` (default 9 fields), timed.
With --asm: the full-lens BL-ASM rows (~10 s and ~1 GB).

Usage: python benchmarks/bench_psf.py [--report] [--asm]
"""
import math
import os
import subprocess
import sys
import tempfile
import time
import warnings

import numpy as np

from metafovea.config import LensDesign
from metafovea.optics import (
    asm_propagate,
    box_integrate,
    build_pupils,
    hankel_field,
    mft_field,
    sensor_psf,
)
from metafovea.optics import propagate as prop
from metafovea.radiometry import psf_wavelengths

warnings.simplefilter("ignore")


def timed(f, *a, **k):
    t = time.perf_counter()
    r = f(*a, **k)
    return r, time.perf_counter() - t


def mono() -> None:
    print("| lens | case | engine | setting | seconds | error |\n|---|---|---|---|---|---|")
    for lens in (LensDesign.perifoveal(), LensDesign.foveal()):
        pu = build_pupils(lens, 10.0, quantize=False, lattice=False).focus
        xs = np.arange(-100, 100.1, 1.0)
        ref = np.abs(prop.hankel_grid(pu, xs, xs, error=1e-12)) ** 2
        peak = ref.max()
        for err in (1e-4, 1e-6):
            for name, f in (("hankel", prop.hankel_grid), ("mft", mft_field)):
                U, dt = timed(f, pu, xs, xs, error=err)
                print(f"| {lens.name} | on axis 201^2 at 1 um | {name} | error={err:g} | {dt:.4f} | "
                      f"{np.abs(np.abs(U) ** 2 - ref).max() / peak:.1e} |")
        fd = 5.0 if lens.na > 0.3 else 1.0
        pu5 = build_pupils(lens, 10.0, field_deg=fd, quantize=False, lattice=False).focus
        e = prop.ray_extent(pu5)
        xo = np.arange(e[0] - 100, e[1] + 100, 5.0)
        yo = np.arange(e[2] - 100, e[3] + 100, 5.0)
        n = prop.mft_nodes(pu5, xo, yo, 1e-12)
        R = np.abs(mft_field(pu5, xo, yo, nodes=(int(1.6 * n[0]), int(1.6 * n[1])))) ** 2
        for err in (1e-3, 1e-5, 1e-7):
            U, dt = timed(mft_field, pu5, xo, yo, error=err)
            print(f"| {lens.name} | {fd:g} deg, {xo.size}x{yo.size} at 5 um | mft | error={err:g} | {dt:.3f} | "
                  f"{np.abs(np.abs(U) ** 2 - R).max() / peak:.1e} |")


def _weights(lens, band=(8.0, 14.0), n=61):
    return psf_wavelengths(band, design_um=lens.wavelength_um, n=n, temperature_k=300.0)


def broadband() -> None:
    print("\n| lens | case | engine(s) | seconds | estimate | actual error | reference (seconds) |\n"
          "|---|---|---|---|---|---|---|")
    for lens in (LensDesign.perifoveal(), LensDesign.foveal()):
        wl, w = _weights(lens)
        S, dt = timed(sensor_psf, lens, pixel_pitch_um=17.0, wavelengths_um=wl, weights=w)
        size = 41  # per-wavelength reference on the central 41 x 41 pixels
        T, _ = timed(sensor_psf, lens, pixel_pitch_um=17.0, wavelengths_um=wl, weights=w, size_px=size)
        n_sub, dx = T.info["n_sub"], T.info["fine_pitch_um"]
        ax = (np.arange(size * n_sub) - (size * n_sub - 1) / 2) * dx
        t0 = time.perf_counter()
        # each wavelength directly, with the focal-shift correction (Pupil.li_wolf) the batched engine applies
        models = [build_pupils(lens, float(l)).focus.li_wolf() for l in wl]
        tot = sum(wk * m * m * np.abs(prop.hankel_grid(mo, m * ax, m * ax, error=1e-9)) ** 2
                  for (mo, m), wk in zip(models, w))
        ref = box_integrate(tot, n_sub) * dx * dx / (math.pi * lens.radius_um ** 2)
        tref = time.perf_counter() - t0
        d = T.intensity - ref
        d -= np.median(d)  # haze orders: uniform floor (not in the reference)
        print(f"| {lens.name} | on axis, {wl.size} wl, {S.shape[0]}^2 px | {S.engine} ({S.info['engines']}) | "
              f"{dt:.2f} | {S.error_estimate:.1e} | {np.abs(d).max() / T.intensity.max():.1e} (41^2 px) | "
              f"per-wavelength hankel_grid ({tref:.1f}) |")
    lens = LensDesign.foveal()
    wl, w = _weights(lens, band=(9.7, 10.3), n=7)
    R, tref = timed(sensor_psf, lens, pixel_pitch_um=17.0, field_deg=1.0, wavelengths_um=wl, weights=w, size_px=41,
                    engine="mft", error=1e-3)
    for budget in (2e7, 1e8):
        H, dt = timed(sensor_psf, lens, pixel_pitch_um=17.0, field_deg=1.0, wavelengths_um=wl, weights=w,
                      size_px=41, budget=budget)
        print(f"| foveal | 1 deg, 9.7-10.3 um ({wl.size} wl), 41^2 px, budget {budget:g} | {H.info['engines']} | "
              f"{dt:.2f} | {H.error_estimate:.2g} | "
              f"{np.abs(H.intensity - R.intensity).max() / R.intensity.max():.2g} | "
              f"all-wave mft ({tref:.1f}) |")
    for lens, fd in ((LensDesign.foveal(), 1.3), (LensDesign.perifoveal(), 3.8), (LensDesign.perifoveal(), 7.6)):
        wl, w = _weights(lens)
        H, dt = timed(sensor_psf, lens, pixel_pitch_um=17.0, field_deg=fd, wavelengths_um=wl, weights=w)
        print(f"| {lens.name} | {fd:g} deg, {wl.size} wl, {H.shape[0]}^2 px | {H.info['engines']} | {dt:.2f} | "
              f"{H.error_estimate:.2g} | (bound) | - |")


def geometric() -> None:
    print("\n| lens | field | wavelength | spread um | geometric vs wave (max / wave peak) | power ratio |\n"
          "|---|---|---|---|---|---|")
    for lens, fd, lam in ((LensDesign.perifoveal(), 0.0, 10.3), (LensDesign.perifoveal(), 0.0, 11.0),
                          (LensDesign.perifoveal(), 0.0, 13.0), (LensDesign.foveal(), 0.0, 10.2),
                          (LensDesign.perifoveal(), 3.0, 10.3), (LensDesign.perifoveal(), 5.0, 10.0)):
        wave = sensor_psf(lens, pixel_pitch_um=17.0, field_deg=fd, wavelengths_um=[lam], error=1e-4,
                          engine="mft" if fd else "hankel", max_size_px=101)
        geo = sensor_psf(lens, pixel_pitch_um=17.0, field_deg=fd, wavelengths_um=[lam], engine="geometric",
                         size_px=wave.shape[0])
        pu = build_pupils(lens, lam, field_deg=fd).focus
        e = prop.ray_extent(pu, 16)
        print(f"| {lens.name} | {fd:g} | {lam:g} | {max(e[1] - e[0], e[3] - e[2]):.0f} | "
              f"{np.abs(geo.intensity - wave.intensity).max() / wave.intensity.max():.2f} | "
              f"{geo.energy_fraction / wave.energy_fraction:.4f} |")


def report() -> None:
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with tempfile.TemporaryDirectory() as d:
        cmd = [os.path.join(os.path.dirname(sys.executable), "metafovea"), "psf",
               os.path.join(repo, "designs/foveal.toml"), os.path.join(repo, "designs/perifoveal.toml"),
               "--band-um", "8", "14", "--wavelengths", "61", "--out", os.path.join(d, "r")]
        t0 = time.perf_counter()
        c0 = os.times()
        out = subprocess.run(cmd, capture_output=True, text=True, check=True)
        c1 = os.times()
        print(f"\nreport: {time.perf_counter() - t0:.1f} s wall, "
              f"{c1.children_user - c0.children_user + c1.children_system - c0.children_system:.1f} s CPU, "
              f"load average {os.getloadavg()[0]:.1f}\n{out.stdout}")


def asm() -> None:
    lens = LensDesign.perifoveal()
    pu = build_pupils(lens, 10.0, quantize=False, lattice=False).focus
    for dx, pad in ((10.0, 1.0), (10.0, 2.0)):
        u0, ax = prop.sampled_lens_field(pu, dx)
        res, dt = timed(asm_propagate, u0, dx, 10.0, lens.f_um, pad=pad)
        c = ax.size // 2
        sl = slice(c - 10, c + 11)
        ref = np.abs(hankel_field(pu, np.hypot(ax[sl][None, :], ax[sl][:, None]), error=1e-12)) ** 2
        I = np.abs(res.field[sl, sl]) ** 2
        print(f"| {lens.name} | on axis | asm | dx={dx:g} pad={pad:g} | {dt:.2f} | "
              f"{np.abs(I - ref).max() / ref.max():.1e} |")


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--report", action="store_true", help="also time `metafovea psf` on both lenses (section 4)")
    ap.add_argument("--asm", action="store_true", help="also the full-lens BL-ASM rows (~10 s and ~1 GB)")
    args = ap.parse_args()
    print(f"load average at start: {os.getloadavg()[0]:.1f}")
    mono()
    broadband()
    geometric()
    if args.asm:
        asm()
    if args.report:
        report()

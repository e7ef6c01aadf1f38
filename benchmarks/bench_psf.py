"""Speed against error of the PSF engines for the paper's lenses (on axis and 5 deg off axis).

Reference ("brute force"): the same engine with 1.6x the nodes (converged quadrature) for mft/hankel, and
the Hankel profile (exact Debye) for the full-lens BL-ASM (only with --asm: ~10 s and ~1 GB).
Error: max |I - I_ref| over the window / on-axis peak.  Usage: python benchmarks/bench_psf.py [--asm]
"""
import sys
import time

import numpy as np

from metafovea.config import LensDesign
from metafovea.optics import build_pupils, hankel_field, mft_field, asm_propagate
from metafovea.optics import propagate as prop


def timed(f, *a, **k):
    t = time.perf_counter()
    r = f(*a, **k)
    return r, time.perf_counter() - t


def main() -> None:
    print("| lens | case | engine | setting | seconds | error |\n|---|---|---|---|---|---|")
    for lens in (LensDesign.perifoveal(), LensDesign.foveal()):
        pu = build_pupils(lens, 10.0, quantize=False, lattice=False).focus
        xs = np.arange(-100, 100.1, 1.0)
        ref = np.abs(prop.hankel_grid(pu, xs, xs, error=1e-12)) ** 2
        peak = ref.max()
        for err in (1e-3, 1e-4, 1e-6):
            U, dt = timed(prop.hankel_grid, pu, xs, xs, error=err)
            print(f"| {lens.name} | on axis 200 um | hankel | error={err:g} | {dt:.4f} | "
                  f"{np.abs(np.abs(U) ** 2 - ref).max() / peak:.1e} |")
            U, dt = timed(mft_field, pu, xs, xs, error=err)
            print(f"| {lens.name} | on axis 200 um | mft | error={err:g} | {dt:.4f} | "
                  f"{np.abs(np.abs(U) ** 2 - ref).max() / peak:.1e} |")
        pu5 = build_pupils(lens, 10.0, field_deg=5.0 if lens.na > 0.3 else 1.0, quantize=False, lattice=False).focus
        e = prop.ray_extent(pu5)
        xo = np.arange(e[0] - 100, e[1] + 100, 5.0)
        yo = np.arange(e[2] - 100, e[3] + 100, 5.0)
        n = prop.mft_nodes(pu5, xo, yo, 1e-12)
        R = np.abs(mft_field(pu5, xo, yo, nodes=(int(1.6 * n[0]), int(1.6 * n[1])))) ** 2
        for err in (1e-3, 1e-5, 1e-7):
            U, dt = timed(mft_field, pu5, xo, yo, error=err)
            print(f"| {lens.name} | off axis {np.degrees(np.arcsin(pu5.s0[0])):.0f} deg, {xo.size}x{yo.size} | mft | "
                  f"error={err:g} | {dt:.3f} | {np.abs(np.abs(U) ** 2 - R).max() / peak:.1e} |")
    if "--asm" in sys.argv:
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
    main()

"""Off-axis PSFs of the paper's lenses against the brute-force Rayleigh-Sommerfeld reference over the true aperture.

For the full-size F/2 (75 mm) lens at 1 and 2.5 deg and the F/1 (25 mm) lens at 5 deg (10 um, continuous phase),
on the window and pitch ``psf()`` chooses by default: the exact windowed engine (``rs``, at requested errors
1e-3 and 1e-4, 2 threads) and the direction-sine engine (``mft``, the old off-axis default), each timed, and
their error max |I - I_ref| / peak(I_ref) against ``rs_reference`` (polar Gauss-Legendre per Fresnel zone,
the exact kernel at every node and point) on a subset of the window: the 11 x 11 samples around the peak and
every ``--stride``-th sample of the rest. The reference is the slow part (minutes per field).

Usage: python benchmarks/bench_offaxis.py [--stride 8] [--fields f2:1,f2:2.5,f1:5]
"""
import argparse
import math
import os
import time
import warnings

import numpy as np

from metafovea.config import LensDesign
from metafovea.optics import build_pupils, mft_field
from metafovea.optics.psf import _auto_window, diffraction_radius_um, nyquist_pitch_um
from metafovea.optics.rayleigh import rs_field, rs_reference

warnings.simplefilter("ignore")


def window(lens: LensDesign, pu) -> tuple[np.ndarray, np.ndarray]:
    """psf()'s default window and pitch for this pupil."""
    rd = diffraction_radius_um(lens)
    pitch = min(nyquist_pitch_um(lens), rd / 3.0)
    c, half = _auto_window([pu], lens, 8 * rd)
    n = int(math.ceil(2 * half / pitch))
    n += n % 2 == 0
    ax = (np.arange(n) - (n - 1) / 2) * pitch
    return c[0] + ax, c[1] + ax


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--stride", type=int, default=8)
    ap.add_argument("--fields", default="f2:1,f2:2.5,f1:5")
    a = ap.parse_args()
    lenses = {"f2": LensDesign.foveal(), "f1": LensDesign.perifoveal()}
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at start")
    print("| lens | field | window | engine | seconds | error vs reference | claimed |")
    print("|---|---|---|---|---|---|---|")
    for item in a.fields.split(","):
        key, fd = item.split(":")
        lens, field = lenses[key], float(fd)
        pu = build_pupils(lens, 10.0, field_deg=field, quantize=False, lattice=False).focus
        xs, ys = window(lens, pu)
        rows = {}
        for name, kw in (("rs 1e-3", {"error": 1e-3}), ("rs 1e-4", {"error": 1e-4}), ("mft", None)):
            t = time.perf_counter()
            if kw is None:
                U, claim = mft_field(pu, xs, ys, error=1e-7), float("inf")
            else:
                U, info = rs_field(pu, xs, ys, **kw)
                claim = info["intensity_error"] / float((np.abs(U) ** 2).max())
            rows[name] = (np.abs(U) ** 2, time.perf_counter() - t, claim)
        I0 = rows["rs 1e-4"][0]
        j, i = np.unravel_index(int(np.argmax(I0)), I0.shape)
        r_idx = sorted(set(range(0, ys.size, a.stride)) | set(range(max(0, j - 5), min(ys.size, j + 6))))
        c_idx = sorted(set(range(0, xs.size, a.stride)) | set(range(max(0, i - 5), min(xs.size, i + 6))))
        t = time.perf_counter()
        ref = np.abs(rs_reference(pu, xs[c_idx], ys[r_idx])) ** 2
        t_ref = time.perf_counter() - t
        for name, (I, dt, claim) in rows.items():
            err = float(np.abs(I[np.ix_(r_idx, c_idx)] - ref).max() / ref.max())
            print(f"| {lens.name} F/{lens.f_um / lens.diameter_um:g} | {field:g} deg | {xs.size}^2 at "
                  f"{xs[1] - xs[0]:.2f} um | {name} | {dt:.2f} | {err:.1e} | {claim:.1e} |", flush=True)
        print(f"| {lens.name} | {field:g} deg | {len(r_idx)} x {len(c_idx)} points | rs_reference | "
              f"{t_ref:.0f} | - | - |", flush=True)
    print(f"load average {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()

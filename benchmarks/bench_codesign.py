"""Broadband co-design against its line bound on small F/2 cameras: the band MTF area to Nyquist of the
hyperbolic and the co-designed foveal lens (the differentiable model and the production engine), the line bound's
gain limit, the per-wavelength mean MTF area, and the time.

    python benchmarks/bench_codesign.py                       # D = 1, 2 and 3 mm at F/2, 3 coefficients, 60 steps
    python benchmarks/bench_codesign.py --diameters-mm 2 --steps 20 --coefficients 2
"""

from __future__ import annotations

import argparse
import json
import os
import time

from metafovea.codesign import CodesignOptions, OptimizeOptions, codesign, production_check
from metafovea.config import LensDesign, SystemDesign


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--diameters-mm", type=float, nargs="+", default=[1.0, 2.0, 3.0])
    ap.add_argument("--coefficients", type=int, default=3)
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--size-px", type=int, default=21)
    ap.add_argument("--out", help="write the rows as JSON here")
    args = ap.parse_args(argv)
    print(f"nproc {os.cpu_count()}, load {os.getloadavg()[0]:.2f}")
    rows = []
    for d_mm in args.diameters_mm:
        fov = LensDesign("foveal", 2000.0 * d_mm, 1000.0 * d_mm, polarization="x")
        per = LensDesign("perifoveal", 1000.0, 1000.0, polarization="y")
        system = SystemDesign(foveal=fov, perifoveal=per, lens_to_sensor_um=(fov.f_um, 1000.0))
        opts = CodesignOptions(n_coefficients=args.coefficients, size_px=args.size_px,
                               optimize=OptimizeOptions(steps=args.steps, learning_rate=0.1, progress=False))
        t0 = time.perf_counter()
        r = codesign(system, opts).lenses["foveal"]
        t_run = time.perf_counter() - t0
        pc = production_check(system, r, opts.posts)
        s = r.summary()
        row = {"diameter_mm": d_mm, "wavelengths": s["sampling"]["wavelengths"],
               "depths_of_focus": r.limit.depths_of_focus, "area_hyperbolic": s["mtf_area_hyperbolic"],
               "area_codesigned": s["mtf_area"], "gain_model": s["gain"], "gain_production": pc["gain_production"],
               "gain_limit": s["line_bound_gain_limit"], "per_wavelength_hyperbolic":
               s["mtf_area_per_wavelength_hyperbolic"], "per_wavelength_codesigned": s["mtf_area_per_wavelength"],
               "phase_poly_rad": s["phase_poly_rad"], "seconds": t_run}
        rows.append(row)
        print(f"D {d_mm:g} mm F/2: {row['wavelengths']} wavelengths, {row['depths_of_focus']:.0f} depths of focus; "
              f"band MTF area {row['area_hyperbolic']:.4f} -> {row['area_codesigned']:.4f}: "
              f"gain {row['gain_model']:.3f} (production {row['gain_production']:.3f}; "
              f"line bound <= {row['gain_limit']:.3f}); per-wavelength {row['per_wavelength_hyperbolic']:.4f} -> "
              f"{row['per_wavelength_codesigned']:.4f}; {t_run:.0f} s")
    print(f"load {os.getloadavg()[0]:.2f}")
    if args.out:
        with open(args.out, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Time per band PSF and per gradient of the differentiable imaging model (metafovea.optics.jaxpsf).

The paper's foveal lens (f 150 mm, D 75 mm, F/2) on axis, 13 Planck-weighted wavelengths over 8-14 um (300 K, no
filter; radiometry.psf_wavelengths), ideal posts, on the sensor grid of the foveal channel (34 um focal-plane
pixels: 17 um behind the 0.5x relay; 4 fine samples per pixel), 4 added-phase coefficients. Rows:

1. build (nodes, grids, haze maps: numpy), first call (jit compile) and steady state of ``band_psf``;
2. ``jax.value_and_grad`` of the MTF area to Nyquist with respect to (a_j, Re/Im t_focus): first call and steady
   state;
3. production ``sensor_psf`` (engine hankel, same grid) for scale, and the largest difference / peak (a_j = 0).

Usage: python benchmarks/bench_jaxpsf.py [--size 255] [--repeat 3] [--lens foveal|perifoveal] [--uniform]
(prints nproc and the load average before and after)
"""
import argparse
import os
import time
import warnings

import numpy as np

warnings.simplefilter("ignore")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=255, help="pixels per side (sensor_psf's cap: 255)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--lens", default="foveal", choices=("foveal", "perifoveal"))
    ap.add_argument("--wavelengths", type=int, default=13)
    ap.add_argument("--uniform", action="store_true", help="equal weights on a uniform 8-14 um grid instead of "
                    "the Planck-weighted bins")
    args = ap.parse_args()
    print(f"nproc {os.cpu_count()}, load average before: {open('/proc/loadavg').read().split()[:3]}")

    import jax
    import jax.numpy as jnp

    from metafovea.config import load_system
    from metafovea.optics import jaxpsf as J
    from metafovea.optics import sensor_psf
    from metafovea.radiometry import psf_wavelengths

    root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
    system = load_system(os.path.join(root, "designs", "system.toml"))
    lens = system.foveal if args.lens == "foveal" else system.perifoveal
    pitch = system.sensor.pixel_pitch_um / system.relay_magnification
    if args.uniform:
        wl = np.linspace(*system.band_um, args.wavelengths)
        w = np.full(wl.size, 1.0 / wl.size)
    else:
        wl, w = psf_wavelengths(system.band_um, design_um=lens.wavelength_um, temperature_k=300.0,
                                n=args.wavelengths)
    print(f"lens {lens.name}: f {lens.f_mm:g} mm, D {lens.diameter_mm:g} mm; {wl.size} wavelengths "
          f"{wl.min():.2f}-{wl.max():.2f} um; {args.size} px of {pitch:g} um; device {jax.devices()[0]}")

    with J.x64():
        t = time.perf_counter()
        m = J.imaging_model(lens, wavelengths_um=wl, weights=w, pitch_um=pitch, size=args.size, sensor=True,
                            n_coefficients=4, phase_bound_rad=30.0)
        t_build = time.perf_counter() - t
        tf = jnp.asarray(J.level_table(lens, None, None, wl))
        a = jnp.asarray([3.0, -2.0, 1.0, 0.5])
        print(f"build {t_build:.2f} s; info {m.info}")

        def run(f):
            t = time.perf_counter()
            out = jax.block_until_ready(f())
            first = time.perf_counter() - t
            ts = []
            for _ in range(args.repeat):
                t = time.perf_counter()
                jax.block_until_ready(f())
                ts.append(time.perf_counter() - t)
            return out, first, min(ts)

        _, first, steady = run(lambda: m.band_psf(a, tf))
        print(f"band_psf: first call {first:.2f} s (compile), steady {steady:.3f} s")

        def obj(a_, tr, ti):
            return m.mtf_area(a_, tr + 1j * ti)

        vg = jax.jit(jax.value_and_grad(obj, argnums=(0, 1, 2)))
        (val, grads), first, steady = run(lambda: vg(a, tf.real, tf.imag))
        print(f"value_and_grad(mtf_area) wrt a_j and t_focus: first call {first:.2f} s, steady {steady:.3f} s; "
              f"MTF area {float(val):.4f}, |d/da| {np.abs(np.asarray(grads[0])).max():.3g}")

        t = time.perf_counter()
        S = sensor_psf(lens, pixel_pitch_um=pitch, wavelengths_um=wl, weights=w, size_px=args.size, error=1e-4)
        t_prod = time.perf_counter() - t
        got = np.asarray(m.band_psf(jnp.zeros(4), tf))
        d = float(np.abs(got - S.intensity).max() / S.intensity.max())
        print(f"production sensor_psf (hankel): {t_prod:.2f} s; jaxpsf (a = 0) against it: {d:.2e} of the peak")
    import resource

    print(f"peak resident memory {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6:.2f} GB; "
          f"load average after: {open('/proc/loadavg').read().split()[:3]}")


if __name__ == "__main__":
    main()

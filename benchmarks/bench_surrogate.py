"""Surrogate benchmark: fit the differentiable surrogate of the scatterer library over the platform's whole
fabrication range and the 8-14 um band, and measure its error against fresh RCWA solves at held-out posts and
wavelengths (random, seeded, off the fitting grid), both polarisations, with a breakdown by wavelength.

    python benchmarks/bench_surrogate.py [--width-step 0.1] [--n-wavelengths 31] [--band 8 14] [--harmonics 10]
        [--points 300] [--seed 0] [--workers 2] [--out BENCH.json]

The RCWA sweep is the library's (compute_library: cached in $METAFOVEA_CACHE/library, resumable), so a second run
only fits (or loads the cached fit) and re-solves the held-out points. Printed: the grid, the sweep's and the fit's
seconds (the sweep's as recorded when it was computed), the fit's own error estimate, the held-out errors per
polarisation and per wavelength bin against the goal (0.02 rad rms phase, 1 % rms amplitude), the worst points,
the RCWA seconds of the reference, the same sweep interpolated at step 2h (stride 2) on the same posts (the observed
convergence order and the grid-step factor that order gives for the goal), and the surrogate's evaluation and
gradient times for 100 000 points (jit,
after compilation). nproc and /proc/loadavg before and after are printed: on a shared machine the seconds measure
the other jobs too.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from metafovea.config import PlatformDesign
from metafovea.library import GOAL_AMPLITUDE_RMS_PCT, GOAL_PHASE_RMS_RAD, error_report, fit_surrogate, held_out_points


def _loadavg() -> str:
    try:
        return Path("/proc/loadavg").read_text().strip()
    except OSError:
        return "n/a"


def _eval_times(s, n: int = 100_000) -> dict[str, float]:
    """Seconds of one jitted evaluation of t_x, t_y and of one jitted gradient of a phase sum, at n points."""
    import jax
    import jax.numpy as jnp

    pts = jnp.asarray(held_out_points(s, n, rng=123))
    f = jax.jit(lambda p: s.transmission(p[:, 0], p[:, 1], p[:, 2]))
    g = jax.jit(jax.grad(lambda p: jnp.sum(jnp.angle(s.transmission(p[:, 0], p[:, 1], p[:, 2])[0]))))
    out = {}
    for name, fn in (("eval_s", f), ("grad_s", g)):
        jax.block_until_ready(fn(pts))
        t0 = time.perf_counter()
        jax.block_until_ready(fn(pts))
        out[name] = time.perf_counter() - t0
    out["points"] = n
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--width-step", type=float, default=0.1, help="width grid step (um)")
    ap.add_argument("--n-wavelengths", type=int, default=31, help="wavelengths of the grid (uniform in 1/lambda)")
    ap.add_argument("--band", type=float, nargs=2, default=(8.0, 14.0), help="band (um)")
    ap.add_argument("--harmonics", type=int, default=10, help="RCWA harmonics M")
    ap.add_argument("--points", type=int, default=300, help="held-out points")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=None, help="processes of the sweep and the reference solves")
    ap.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    args = ap.parse_args()

    load0 = _loadavg()
    print(f"nproc {os.cpu_count()}  loadavg before: {load0}", flush=True)
    t0 = time.perf_counter()
    s = fit_surrogate(PlatformDesign(), band_um=args.band, width_step_um=args.width_step,
                      n_wavelengths=args.n_wavelengths, harmonics=args.harmonics, workers=args.workers)
    fit_wall = time.perf_counter() - t0
    m = s.meta
    est_ph, est_amp = (m.get(k) if m.get(k) is not None else np.nan
                       for k in ("estimated_phase_rms_rad", "estimated_amplitude_rms_pct"))
    print(f"grid: {s.widths_um.size} x {s.widths_um.size} widths {s.widths_um[0]:g}-{s.widths_um[-1]:g} um (step "
          f"{m['width_step_um']:g}), {s.wavelengths_um.size} wavelengths {s.band_um[0]:g}-{s.band_um[1]:g} um "
          f"(uniform in 1/lambda), harmonics {m['harmonics']}; library {m['library_key']}, surrogate {m['key']}")
    print(f"sweep {m.get('sweep_s', 0):.0f} s when computed; fit_surrogate this run {fit_wall:.1f} s"
          f"{' (from cache)' if m.get('from_cache') else ''}; self-estimate phase rms "
          f"{est_ph:.4f} rad, amplitude rms {est_amp:.3f} %", flush=True)
    err = error_report(s, args.points, rng=args.seed, workers=args.workers, progress=True)
    print(f"held-out: {args.points} points (seed {args.seed}); goal {GOAL_PHASE_RMS_RAD} rad rms, "
          f"{GOAL_AMPLITUDE_RMS_PCT} % rms: {'MET' if err.meets() else 'NOT MET'}")
    print(err.summary())
    print("worst points:")
    for w in err.worst:
        print("  " + ", ".join(f"{k} {v:.4g}" for k, v in w.items()))
    half = fit_surrogate(PlatformDesign(), band_um=args.band, width_step_um=args.width_step,
                         n_wavelengths=args.n_wavelengths, harmonics=args.harmonics, workers=args.workers, stride=2)
    err2 = error_report(half, reference=err)
    e1 = max(max(err.phase_rms_rad.values()) / GOAL_PHASE_RMS_RAD,
             max(err.amplitude_rms_pct.values()) / GOAL_AMPLITUDE_RMS_PCT)
    e2 = max(max(err2.phase_rms_rad.values()) / GOAL_PHASE_RMS_RAD,
             max(err2.amplitude_rms_pct.values()) / GOAL_AMPLITUDE_RMS_PCT)
    order = float(np.log2(e2 / e1)) if e1 > 0 and e2 > e1 else float("nan")
    scale = e1 ** (-1 / order) if np.isfinite(order) and order > 0 else float("nan")
    print(f"the same sweep at step 2h (stride 2, the same held-out posts): phase rms "
          f"{max(err2.phase_rms_rad.values()):.4f} rad, amplitude rms {max(err2.amplitude_rms_pct.values()):.3f} %; "
          f"observed order {order:.2f}; grid steps x {scale:.2f} for the goal (worse of phase and amplitude)")
    print(err2.summary())
    times = _eval_times(s)
    print(f"RCWA reference: {err.seconds['rcwa_s']:.1f} s for {args.points} posts x 2 polarisations; surrogate "
          f"{times['points']} points: eval {times['eval_s'] * 1e3:.1f} ms, grad {times['grad_s'] * 1e3:.1f} ms")
    load1 = _loadavg()
    print(f"loadavg after: {load1}")
    if args.out is not None:
        rec = dict(args={k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
                   nproc=os.cpu_count(), loadavg_before=load0, loadavg_after=load1, fit_wall_s=fit_wall,
                   meta={k: v for k, v in m.items() if not isinstance(v, np.ndarray)},
                   phase_rms_rad=err.phase_rms_rad, phase_max_rad=err.phase_max_rad,
                   amplitude_rms_pct=err.amplitude_rms_pct, amplitude_max_pct=err.amplitude_max_pct,
                   by_band=err.by_band, worst=err.worst, seconds=err.seconds, eval=times, met=err.meets(),
                   half_grid=dict(phase_rms_rad=err2.phase_rms_rad, amplitude_rms_pct=err2.amplitude_rms_pct,
                                  by_band=err2.by_band), observed_order=order, grid_scale_for_goal=scale)
        args.out.write_text(json.dumps(rec, indent=2, default=str) + "\n")


if __name__ == "__main__":
    main()

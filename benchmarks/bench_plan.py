"""Error-budgeted simulation: the full model against ``simulate(..., tolerance_k=T)``, side by side in one process.

For each scene (default: a smooth scene and the Siemens star, the paper's camera at 8-14 um, 96 frames of
290 x 290, PSFs cached), both models are run alternately ``--repeats`` times after a warm-up (imports, the PSF and
post caches); the table gives the median wall and CPU seconds of each, their ratio, the seconds of the parts the
planner governs (optics, plan and rendering: ``timing_s['psf'] + ['render']``; the rest, the camera's posts and
train, the noise and ADC of every frame and the file's PSFs, is the same in both), the realised error of the reduced
model against the full one (K rms, :func:`metafovea.imaging.ablate.model_error_k`), each model's seconds by stage
(median wall: plan, optics, rendering, mixing with noise and ADC, camera and scene, the file's PSFs and metadata) and
the plan table.

    python benchmarks/bench_plan.py                      # smooth scene and siemens-star, T = 0.05 K
    python benchmarks/bench_plan.py --tolerance-k 0.1 --scenes siemens-star --filter --repeats 5
    python benchmarks/bench_plan.py --quick              # 96 x 96 crop, 12 frames, 1 repeat (a smoke test)

The smooth scenes are :func:`metafovea.studies.bench.smooth_scene`: ``smooth``, a 256 x 256 raster of 296-305 K (a
warm blob on a linear gradient) filling the perifoveal field, the simulator's ambient 294 K beyond it (a step at the
field's edge); ``smooth-fade``, a warm blob that fades into the ambient.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

from metafovea.studies.bench import smooth_scene


def _timed(fn):
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def run_scene(system, name: str, scene, tolerance_k: float, repeats: int, kw: dict) -> dict:
    from metafovea.imaging import simulate
    from metafovea.imaging.ablate import model_error_k

    simulate(system, scene, **{**kw, "frames": 2})  # warm-up: imports, PSF and post caches
    simulate(system, scene, tolerance_k=tolerance_k, **{**kw, "frames": 2})
    full_w, full_c, red_w, red_c, full_part, red_part = [], [], [], [], [], []
    stages: dict[str, list[dict[str, float]]] = {"full": [], "reduced": []}
    full = red = None
    for _ in range(repeats):
        full, w, c = _timed(lambda: simulate(system, scene, **kw))
        full_w.append(w)
        full_c.append(c)
        full_part.append(full.meta["timing_s"]["psf"] + full.meta["timing_s"]["render"])
        stages["full"].append(_stages(full.meta["timing_s"], w))
        red, w, c = _timed(lambda: simulate(system, scene, tolerance_k=tolerance_k, **kw))
        red_w.append(w)
        red_c.append(c)
        red_part.append(red.meta["timing_s"]["psf"] + red.meta["timing_s"]["render"])
        stages["reduced"].append(_stages(red.meta["timing_s"], w))
    med = statistics.median
    return {"scene": name, "tolerance_k": tolerance_k,
            "full_wall_s": med(full_w), "reduced_wall_s": med(red_w), "wall_ratio": med(full_w) / med(red_w),
            "full_cpu_s": med(full_c), "reduced_cpu_s": med(red_c), "cpu_ratio": med(full_c) / med(red_c),
            "full_optics_render_s": med(full_part), "reduced_plan_optics_render_s": med(red_part),
            "optics_render_ratio": med(full_part) / med(red_part),
            "realised_error_k": model_error_k(red, full), "within_budget": model_error_k(red, full) <= tolerance_k,
            "reduce": red.meta["model"]["reduce"], "plan": red.meta["model"]["plan"],
            "stages_wall_s": {k: {s: med(r[s] for r in v) for s in v[0]} for k, v in stages.items()}}


def _stages(t: dict, wall: float) -> dict[str, float]:
    """A run's wall seconds by stage: the plan, the optics (PSF kernels and haze), the rendering, the frames' mixing,
    noise and ADC, the camera and scene before them and the file's PSFs and metadata after."""
    plan = t.get("plan", 0.0)
    return {"plan": plan, "optics": t["psf"] - plan, "render": t["render"], "mix_noise_adc": t["mix_noise"],
            "camera_scene": t["total"] - t["psf"] - t["render"] - t["mix_noise"], "psf_files_meta": wall - t["total"]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tolerance-k", type=float, default=0.05)
    ap.add_argument("--scenes", nargs="+", default=["smooth", "siemens-star"])
    ap.add_argument("--filter", action="store_true", help="the 10 um filter (default: the whole 8-14 um band)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--frames", type=int, default=96)
    ap.add_argument("--quick", action="store_true", help="96 x 96 crop, 12 frames, 1 repeat")
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    from metafovea.config import SystemDesign
    from metafovea.imaging.plan import plan_lines

    system = SystemDesign.paper()
    frames, repeats = args.frames, args.repeats
    if args.quick:
        system = replace(system, sensor=replace(system.sensor, crop=(96, 96)))
        frames, repeats = 12, 1
    kw = {"frames": frames, "filter_enabled": args.filter}
    load0 = os.getloadavg()
    print(f"machine: {os.cpu_count()} CPUs, load average {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}; "
          f"{'10 um filter' if args.filter else '8-14 um'}, {frames} frames of {system.sensor.crop[0]} x "
          f"{system.sensor.crop[1]}, T = {args.tolerance_k:g} K rms, {repeats} repeat(s) each, medians")
    rows = []
    for name in args.scenes:
        scene = smooth_scene(name) if name in ("smooth", "smooth-fade") else name
        r = run_scene(system, name, scene, args.tolerance_k, repeats, kw)
        rows.append(r)
        print(f"\n== {name}: full {r['full_wall_s']:.2f} s ({r['full_cpu_s']:.2f} s CPU), reduced "
              f"{r['reduced_wall_s']:.2f} s ({r['reduced_cpu_s']:.2f} s CPU): x{r['wall_ratio']:.2f} wall, "
              f"x{r['cpu_ratio']:.2f} CPU; optics + rendering {r['full_optics_render_s']:.2f} s against plan + "
              f"optics + rendering {r['reduced_plan_optics_render_s']:.2f} s: x{r['optics_render_ratio']:.2f}; "
              f"realised error {r['realised_error_k']:.4f} K rms ({'within' if r['within_budget'] else 'OVER'} "
              f"{args.tolerance_k:g} K); replaced: {', '.join(r['reduce']) or 'nothing'}")
        for k, v in r["stages_wall_s"].items():
            print(f"   {k} by stage (wall s): " + ", ".join(f"{s} {x:.3f}" for s, x in v.items()))
        print("\n".join(plan_lines(r["plan"])))
    load1 = os.getloadavg()
    print(f"\nload average at the end {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"load_start": load0, "load_end": load1, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

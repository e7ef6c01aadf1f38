"""The perifoveal scene beyond the crop (``boundary='solved'``): speed against error of its options, on scenes that
continue beyond the field and on the same scenes as rasters whose edge meets the simulator's surround.

Each case is a tuning scene of the seeded generator (``gen:KIND:SEED``, seeds from 10000: no default is judged on
them) in two forms: as generated (it continues beyond the crop) and as a raster of its field (``RasterScene``: the
simulator's 294 K background beyond the raster's edge, as a user's picture or array meets it), x band (8-14 um, the
10 um filter), recorded as a user does (48 frames, 16 shutter frames, ``designs/system.toml``). On each recording the
default PSF-aware method runs with the edge-padded boundary and with the solved exterior at each ring width and
iteration cap asked; margin = PSNR against the scene minus the Wiener bound's (which pads with edge values).

    python benchmarks/bench_exterior.py [--scenes 4] [--bands 8-14um 10um] [--widths 8 16 32]
        [--iterations 25 50 100 200] [--workers 1] [--json out.json] [--quick]

Prints per recording and setting the perifoveal and foveal margins (dB), which boundary was kept and the method's
time (s); per form, band and setting the mean and worst perifoveal gain over the edge-padded boundary.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from metafovea.config import load_system
from metafovea.imaging.generator import tuning_scenes
from metafovea.imaging.scene import AMBIENT_K, RasterScene, SceneGeometry
from metafovea.parallel import run_tasks
from metafovea.reconstruct.joint import EXTERIOR_ITERATIONS, EXTERIOR_PX
from metafovea.studies.bench import load_average

SYSTEM = Path(__file__).resolve().parents[1] / "designs" / "system.toml"
BANDS = {"8-14um": False, "10um": True}
#: the raster's pixels across the perifoveal field (finer than the sensor's crop)
RASTER_PX = 600


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=4, help="tuning scenes (default 4), the kinds in turn")
    ap.add_argument("--bands", nargs="+", choices=sorted(BANDS), default=list(BANDS))
    ap.add_argument("--widths", type=int, nargs="+", default=[8, EXTERIOR_PX, 32], help="ring widths, px")
    ap.add_argument("--iterations", type=int, nargs="+", default=[25, 50, EXTERIOR_ITERATIONS, 200],
                    help="iteration caps at the default width")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--quick", action="store_true", help="one scene, the 10 um band, the defaults only (CI)")
    return ap.parse_args(argv)


def raster_of(scene, n: int = RASTER_PX) -> RasterScene:
    """``scene``'s temperatures on an ``n x n`` raster spanning the perifoveal field, the surround beyond it."""
    half = SceneGeometry().half
    a = (np.arange(n) - (n - 1) / 2) * (2 * half / n)
    ax, ay = np.meshgrid(a, a)
    temp, _ = scene.sample(ax, ay)
    return RasterScene(temperature_k=temp, half_width_rad=half, background_k=AMBIENT_K, name=f"raster of {scene.name}")


def settings(args: argparse.Namespace) -> list[dict]:
    out = [{"boundary": "padded"}]
    out += [{"exterior_px": EXTERIOR_PX, "exterior_iterations": it} for it in args.iterations]
    out += [{"exterior_px": w, "exterior_iterations": EXTERIOR_ITERATIONS} for w in args.widths if w != EXTERIOR_PX]
    return out


def run_case(item: tuple[str, str, str, list[dict]]) -> list[dict]:
    """One recording: every setting side by side."""
    from metafovea.imaging.generator import generated_scene, parse_scene_name
    from metafovea.imaging.simulate import simulate
    from metafovea.reconstruct.deconvolve import deconvolve_measurement
    from metafovea.reconstruct.fpn import estimate_fpn
    from metafovea.reconstruct.metrics import psnr

    name, form, band, sets = item
    scene = generated_scene(*parse_scene_name(name))
    if form == "raster":
        scene = raster_of(scene)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = simulate(load_system(SYSTEM), scene, frames=48, calibration_frames=16, filter_enabled=BANDS[band], rng=0)
    fpn, info = estimate_fpn(calibration=m.extras["calibration"])
    fe = float(info.get("error_rms_dn") or 0.0)
    rows, bound = [], None
    for s in sets:
        t0 = time.perf_counter()
        d = deconvolve_measurement(m, fpn=fpn, fpn_error_dn=fe, score_truth=bound is None, **s)
        sec = time.perf_counter() - t0
        if bound is None:
            sec -= d.info["scores"]["wiener_bound_seconds"]
            bound = [d.info["scores"][f"wiener_bound_psnr_x{i}"] for i in (1, 2)]
        ex = d.info.get("exterior") or {}
        rows.append({"scene": name, "form": form, "band": band, "setting": _label(s),
                     "margin_x1_db": psnr(d.scene[0], m.scene_truth[0]) - bound[0],
                     "margin_x2_db": psnr(d.scene[1], m.scene_truth[1]) - bound[1],
                     "kept": ex.get("kept", "padded"), "iterations": ex.get("iterations"), "seconds": sec})
    return rows


def _label(s: dict) -> str:
    if s.get("boundary") == "padded":
        return "padded"
    return f"ring {s['exterior_px']} px, <= {s['exterior_iterations']} it"


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.quick:
        args.scenes, args.bands, args.widths, args.iterations = 1, ["10um"], [EXTERIOR_PX], [EXTERIOR_ITERATIONS]
    print(f"nproc {len(os.sched_getaffinity(0))}, load {load_average()}, "
          f"{datetime.datetime.now(datetime.UTC).isoformat(timespec='seconds')}")
    sets = settings(args)
    items = [(name, form, band, sets) for name, _ in tuning_scenes(args.scenes)
             for form in ("generated", "raster") for band in args.bands]
    t0 = time.time()
    print(f"{'scene':<22} {'form':<9} {'band':<6} {'setting':<24} {'peri':>7} {'foveal':>7} {'kept':<7} {'s':>5}")
    rows: list[dict] = []
    for _, res in run_tasks(run_case, items, workers=args.workers):
        for r in res:
            rows.append(r)
            print(f"{r['scene']:<22} {r['form']:<9} {r['band']:<6} {r['setting']:<24} {r['margin_x2_db']:+7.2f} "
                  f"{r['margin_x1_db']:+7.2f} {r['kept']:<7} {r['seconds']:5.2f}", flush=True)
    print("perifoveal gain over the edge-padded boundary (dB): mean / worst; median time (s)")
    summary = []
    for form in ("generated", "raster"):
        for band in args.bands:
            pad = {r["scene"]: r["margin_x2_db"] for r in rows if (r["form"], r["band"], r["setting"]) ==
                   (form, band, "padded")}
            for s in sets[1:]:
                sel = [r for r in rows if (r["form"], r["band"], r["setting"]) == (form, band, _label(s))]
                gain = [r["margin_x2_db"] - pad[r["scene"]] for r in sel]
                t = float(np.median([r["seconds"] for r in sel]))
                summary.append({"form": form, "band": band, "setting": _label(s), "mean_gain_db": float(np.mean(gain)),
                                "worst_gain_db": float(min(gain)), "median_seconds": t,
                                "kept_solved": sum(r["kept"] == "solved" for r in sel), "cases": len(sel)})
                x = summary[-1]
                print(f"  {form:<9} {band:<6} {x['setting']:<24} {x['mean_gain_db']:+6.2f} / {x['worst_gain_db']:+6.2f}"
                      f"  {t:5.2f} s  solved kept {x['kept_solved']} of {x['cases']}")
    print(f"load {load_average()}; wall {time.time() - t0:.0f} s")
    if args.json:
        args.json.write_text(json.dumps({"meta": {"load": load_average(), "argv": sys.argv[1:]}, "rows": rows,
                                         "summary": summary}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

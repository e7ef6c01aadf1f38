"""Benchmark `metafovea simulate`: 96 frames of 290 x 290 for the paper's system.

Run:  python benchmarks/bench_simulate.py [--frames 96] [--scenes siemens-star,hand] [--psf airy|optics|auto]

Reports, per scene: the simulation time (PSFs cached: the first, uncached call is timed separately),
the time to write the Measurement .npz, the TIFF stack and the preview PNG, and the peak memory
(tracemalloc: numpy allocations) against the size of the frames.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import tracemalloc
from pathlib import Path

from metafovea.config import SystemDesign
from metafovea.imaging import simulate, write_preview, write_tiff


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=96)
    ap.add_argument("--scenes", default="siemens-star,bars,astronaut,heater-5s,parking-lot,hand")
    ap.add_argument("--psf", default="auto")
    ap.add_argument("--filter", action="store_true")
    a = ap.parse_args()
    system = SystemDesign.paper()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        simulate(system, "uniform", frames=1, psf=a.psf, filter_enabled=a.filter)  # fill the PSF cache
        first = time.perf_counter() - t
        for name in a.scenes.split(","):
            tracemalloc.start()
            t = time.perf_counter()
            m = simulate(system, name, frames=a.frames, psf=a.psf, filter_enabled=a.filter, rng=0)
            t_sim = time.perf_counter() - t
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
            t = time.perf_counter()
            m.save(Path(tmp) / f"{name}.npz")
            t_npz = time.perf_counter() - t
            t = time.perf_counter()
            write_tiff(m, Path(tmp) / f"{name}.tif")
            t_tif = time.perf_counter() - t
            t = time.perf_counter()
            write_preview(m, Path(tmp) / f"{name}.png")
            t_png = time.perf_counter() - t
            fb = m.frames.nbytes
            rows.append({"scene": name, "frames": list(m.frames.shape), "psf": m.meta["psf"]["provider"],
                         "simulate_s": round(t_sim, 2), "npz_s": round(t_npz, 2), "tiff_s": round(t_tif, 2),
                         "preview_s": round(t_png, 2), "total_s": round(t_sim + t_npz + t_tif + t_png, 2),
                         "peak_MB": round(peak / 2 ** 20, 1), "frames_MB": round(fb / 2 ** 20, 1),
                         "peak_over_frames": round(peak / fb, 2)})
            print(json.dumps(rows[-1]))
    print(json.dumps({"first_call_with_psf_s": round(first, 2)}))


if __name__ == "__main__":
    main()

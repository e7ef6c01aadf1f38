"""Scale evidence for the one executor (issue 16): the same library sweep and the same layout export on 1 and 2
workers, locally and on a Dask LocalCluster, side by side in one run, with the per-task costs docs/scale.md
projects from.

    python benchmarks/bench_scale.py [--library-posts 12] [--harmonics 8] [--export-mm 6] [--psf-fields 4]
                                     [--only library|export|psf ...]

On Dask the export's workers write tile files that the client stitches in band order (metafovea.layout.tilefiles);
the stitch is timed with the run.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path


def _load() -> list[str]:
    return open("/proc/loadavg").read().split()[:3]


def _timed(kw: dict, job):
    """``job(**kw)`` timed, on a LocalCluster started (and closed) outside the timing when ``kw`` names one."""
    from metafovea.parallel import DaskExecutor

    ex = DaskExecutor(kw["scheduler"]) if "scheduler" in kw else None
    try:
        t = time.perf_counter()
        out = job(**(dict(scheduler=ex.address) if ex else kw))
        return out, time.perf_counter() - t
    finally:
        if ex is not None:
            ex.close()


LOCAL_AND_DASK = (("scheduler", "local:1", "Dask LocalCluster, 1 worker"),
                  ("scheduler", "local:2", "Dask LocalCluster, 2 workers"))


def library_runs(n: int, harmonics: int) -> list[dict]:
    import numpy as np

    from metafovea.library import compute_library

    widths = list(np.linspace(0.5, 3.5, n))
    rows, ref = [], None
    runs = (("workers", 1, "serial (1 process)"), ("workers", 2, "local processes, 2")) + LOCAL_AND_DASK
    with tempfile.TemporaryDirectory() as d:
        for key, val, label in runs:
            cache_dir = Path(d) / label.replace(" ", "_")

            def sweep(cache: Path = cache_dir, **kw):
                return compute_library(widths, None, (10.0,), harmonics=harmonics, use_cache=False, progress=False,
                                       tol=None, cache_dir=cache, **kw)

            lib, sec = _timed({key: val}, sweep)
            same = ref is None or bool(np.array_equal(np.asarray(lib.t_x), np.asarray(ref.t_x)))
            ref = ref or lib
            rows.append({"job": f"library {n} x {n} posts, M = {harmonics}", "run": label, "seconds": sec,
                         "tasks": n, "seconds_per_task": sec / n, "identical_to_serial": same})
    return rows


def export_runs(mm: float) -> list[dict]:
    from metafovea.config import LensDesign
    from metafovea.layout import ExportOptions, export_file, make_spec

    spec = make_spec(LensDesign("scale", 2.0 * mm * 1000, mm * 1000, polarization="x"), band_rows=32)
    rows, ref = [], None
    runs = (("workers", 1, "1 thread"), ("workers", 2, "2 threads (default)")) + LOCAL_AND_DASK
    with tempfile.TemporaryDirectory() as d:
        for key, val, label in runs:
            out = Path(d) / f"{label.replace(' ', '_')}.oas"
            def export(path: Path = out, **kw):
                return export_file(spec, path, "oas", ExportOptions(**kw))

            res, sec = _timed({key: val}, export)
            data = out.read_bytes()
            same = ref is None or data == ref
            ref = ref or data
            rows.append({"job": f"OASIS export, {mm:g} mm lens ({res['posts']:,} posts)", "run": label,
                         "seconds": sec, "posts_per_s": res["posts"] / sec, "bytes": len(data),
                         "bands": res["bands"], "identical_to_serial": same})
    return rows


def psf_runs(n_fields: int) -> list[dict]:
    """The paper's perifoveal lens: sensor PSFs at ``n_fields`` fields (0 to 15 deg), at the design wavelength and
    over 8-14 um in 9 bins, one task per (field, wavelength set): the sweep ``metafovea psf --scheduler`` spreads.
    Timed on warm workers (pool or cluster started and used once before)."""
    import numpy as np

    from metafovea.config import SystemDesign
    from metafovea.optics.sweep import sensor_psf_sweep
    from metafovea.radiometry import psf_wavelengths

    lens = SystemDesign.paper().perifoveal
    wl, w = psf_wavelengths((8.0, 14.0), design_um=lens.wavelength_um, n=9)
    fields = list(np.linspace(0.0, 15.0, n_fields))
    from metafovea.parallel import get_executor

    rows, ref = [], None
    runs = (("workers", 1, "serial (1 process)"), ("workers", 2, "local processes, 2")) + LOCAL_AND_DASK
    for key, val, label in runs:
        # warm workers (started, metafovea imported, one PSF done): the per-task cost, not the pool's start
        with get_executor(**{key: val}) as ex:
            sensor_psf_sweep(lens, [0.0] * 2, [([lens.wavelength_um], None)], pixel_pitch_um=34.0, executor=ex)
            t = time.perf_counter()
            sw = sensor_psf_sweep(lens, fields, [([lens.wavelength_um], None), (wl, w)], pixel_pitch_um=34.0,
                                  executor=ex)
            sec = time.perf_counter() - t
        arrays = [p.intensity for row in sw.psfs for p in row]
        same = ref is None or all(np.array_equal(a, b) for a, b in zip(arrays, ref))
        ref = ref or arrays
        rows.append({"job": f"sensor PSFs, perifoveal lens, {n_fields} fields x 2 ({2 * n_fields} tasks)",
                     "run": label, "seconds": sec, "tasks": 2 * n_fields, "seconds_per_task": sec / (2 * n_fields),
                     "identical_to_serial": same})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--library-posts", type=int, default=12)
    ap.add_argument("--harmonics", type=int, default=8)
    ap.add_argument("--export-mm", type=float, default=6.0)
    ap.add_argument("--psf-fields", type=int, default=4)
    ap.add_argument("--only", choices=("library", "export", "psf"), action="append", default=None,
                    help="run only this job (repeatable)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    head = {"nproc": os.cpu_count(), "load_before": _load()}
    only = set(args.only or ("library", "export", "psf"))
    rows = ((library_runs(args.library_posts, args.harmonics) if "library" in only else [])
            + (export_runs(args.export_mm) if "export" in only else [])
            + (psf_runs(args.psf_fields) if "psf" in only else []))
    head["load_after"] = _load()
    print(f"nproc {head['nproc']}, load {head['load_before']} -> {head['load_after']}")
    for r in rows:
        rate = (f"{r['seconds_per_task']:.2f} s/task" if "seconds_per_task" in r
                else f"{r['posts_per_s'] / 1e6:.2f} M posts/s")
        print(f"  {r['job']:<50} {r['run']:<30} {r['seconds']:7.2f} s  {rate:>16}  "
              f"identical {r['identical_to_serial']}")
    if args.json:
        Path(args.json).write_text(json.dumps({**head, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()

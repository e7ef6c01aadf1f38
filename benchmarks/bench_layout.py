"""Layout export benchmark: 25 mm (perifoveal) and 75 mm (foveal) lenses, GDSII and OASIS.

Each measurement runs in its own Python process (peak memory = that process's max RSS, encoder
threads included; worker processes, if any, reported as the largest child's max RSS). Per lens: the
disk's sequential write speed (a file of --disk-gb GB, fsynced), our GDSII export (fsynced) and its
streaming verification, the hierarchical GDSII (--max-refs, default 8192) and its verification, gdstk's
streamed GDSII writer (--gdstk lenses only: GdsWriter, one cell per band holding one reference per post
type with an explicit-offset repetition, which gdstk writes as one SREF per post), our OASIS export and
its read-back (gdstk; klayout with --klayout-oas). The load average before/after each step is recorded.
Files go to --dir (default /tmp) and are deleted after each step.

    python benchmarks/bench_layout.py --lens perifoveal foveal --dir /tmp/bench_layout --json out.json
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, os, resource, sys, time
args = json.loads(sys.argv[1])
kind = args["kind"]
out = {}
t0 = time.perf_counter()
if kind == "disk":
    import mmap
    buf = mmap.mmap(-1, 64 << 20)  # page-aligned (O_DIRECT)
    buf.write(os.urandom(1 << 20) * 64)
    n = int(args["gb"] * (1 << 30)) // len(buf)
    t0 = time.perf_counter()
    if args.get("direct"):
        fd = os.open(args["path"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_DIRECT, 0o644)
        for _ in range(n):
            os.write(fd, buf)
        os.fsync(fd); os.close(fd)
    else:
        with open(args["path"], "wb") as fh:
            for _ in range(n):
                fh.write(buf)
            fh.flush(); os.fsync(fh.fileno())
    out["bytes"] = n * len(buf)
else:
    from metafovea.config import load_lens
    from metafovea.layout import ExportOptions, make_spec, export_layout
    d = load_lens(args["design"])
    spec = make_spec(d)
    if kind == "export":
        r = export_layout(spec, args["path"], args["fmt"],
                          ExportOptions(workers=args.get("workers", 1), force=True, max_refs=args.get("max_refs"),
                                        threads=args.get("threads", True)))
        out.update(posts=r.posts, bytes=r.bytes, extra=r.extra)
    elif kind == "verify":
        from metafovea.layout.verify import verify_layout
        r = verify_layout(args["path"], spec, reader=args["reader"], workers=args.get("workers", 1),
                          max_refs=args.get("max_refs"))
        out.update(ok=r.ok, posts=r.posts, mismatches=r.mismatches[:5], seconds_read=r.seconds_read,
                   seconds_expected=r.seconds_expected, structures=r.structures,
                   max_elements_per_structure=r.max_elements_per_structure)
    elif kind == "gdstk":
        import gdstk, numpy as np
        from metafovea.layout.gds import band_sites
        names = spec.post_names
        sz = spec.post_sizes_nm / 1000.0
        w = gdstk.GdsWriter(args["path"], unit=1e-6, precision=1e-9)
        cells = []
        for nm, (wx, wy) in zip(names, sz):
            c = gdstk.Cell(nm)
            c.add(gdstk.rectangle((-wx / 2, -wy / 2), (wx / 2, wy / 2), layer=1))
            w.write(c)
            cells.append(c)
        top = gdstk.Cell(spec.top_name)
        n = 0
        for i, band in enumerate(spec.bands()):
            k, x, y = band_sites(spec, band)
            bc = gdstk.Cell(f"B{i:05d}")
            order = np.argsort(k, kind="stable")
            k, x, y = k[order], x[order] / 1000.0, y[order] / 1000.0
            bounds = np.searchsorted(k, np.arange(len(names) + 1))
            for t in range(len(names)):
                a, b = bounds[t], bounds[t + 1]
                if b > a:
                    offs = np.stack([x[a:b] - x[a], y[a:b] - y[a]], 1)
                    ref = gdstk.Reference(cells[t], (x[a], y[a]))
                    if b - a > 1:
                        ref.repetition = gdstk.Repetition(offsets=offs)
                    bc.add(ref)
            w.write(bc)
            top.add(gdstk.Reference(bc))
            n += len(k)
        w.write(top)
        w.close()
        fd = os.open(args["path"], os.O_RDONLY); os.fsync(fd); os.close(fd)
        out.update(posts=n, bytes=os.path.getsize(args["path"]))
out["seconds"] = time.perf_counter() - t0
# main process (threads included) and worker processes (largest child), max RSS
out["peak_rss_gb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
out["peak_rss_children_gb"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 2**20
print("RESULT " + json.dumps(out))
"""


def child(**kw) -> dict:
    la0 = os.getloadavg()[0]
    r = subprocess.run([sys.executable, "-c", CHILD, json.dumps(kw)], capture_output=True, text=True, cwd=ROOT)
    for line in r.stdout.splitlines():
        if line.startswith("RESULT "):
            out = json.loads(line[7:])
            out["load_before_after"] = [round(la0, 2), round(os.getloadavg()[0], 2)]
            return out
    raise RuntimeError(f"{kw['kind']} failed:\n{r.stdout[-2000:]}\n{r.stderr[-4000:]}")


def rm(p: Path) -> None:
    if p.exists():
        p.unlink()


def _rates(r: dict, disk_MBps: float | None = None, direct_MBps: float | None = None) -> dict:
    r["posts_per_s"] = r["posts"] / r["seconds"]
    r["bytes_per_post"] = r["bytes"] / r["posts"]
    if disk_MBps:  # the disk-write limit: a buffered write of random bytes, fsynced
        r["disk_limit_s"] = r["bytes"] / (disk_MBps * 1e6)
        r["x_disk_limit"] = r["seconds"] / r["disk_limit_s"]
    if direct_MBps:  # the same with O_DIRECT (what the exporter does)
        r["direct_limit_s"] = r["bytes"] / (direct_MBps * 1e6)
        r["x_direct_limit"] = r["seconds"] / r["direct_limit_s"]
    return r


def bench_lens(name: str, d: Path, disk_gb: float, klayout_oas: bool, workers: int, oas_workers: int,
               log, gdstk_ref: bool = True, max_refs: int | None = 8192, klayout_gds: bool = False) -> dict:
    design = str(ROOT / "designs" / f"{name}.toml")
    res: dict = {"lens": name, "cpus": os.cpu_count(), "load_start": os.getloadavg()}
    p = d / f"{name}.disk"
    r = child(kind="disk", path=str(p), gb=disk_gb)
    rm(p)
    res["disk_MBps"] = r["bytes"] / r["seconds"] / 1e6
    res["disk"] = r
    r = child(kind="disk", path=str(p), gb=disk_gb, direct=True)
    rm(p)
    res["disk_direct_MBps"] = r["bytes"] / r["seconds"] / 1e6
    res["disk_direct"] = r
    log(f"{name}: disk {res['disk_MBps']:.0f} MB/s buffered, {res['disk_direct_MBps']:.0f} MB/s O_DIRECT")
    p = d / f"{name}.gds"
    r = child(kind="export", design=design, path=str(p), fmt="gds", workers=workers)
    res["gds"] = _rates(r, res["disk_MBps"], res["disk_direct_MBps"])
    log(f"{name}: gds {r}")
    v = child(kind="verify", design=design, path=str(p), reader="stream", workers=workers)
    res["gds_verify_stream"] = v
    log(f"{name}: gds verify (stream) {v}")
    rm(p)
    if max_refs:
        p = d / f"{name}_h.gds"
        r = child(kind="export", design=design, path=str(p), fmt="gds", workers=workers, max_refs=max_refs)
        res["gds_hier"] = _rates(r, res["disk_MBps"], res["disk_direct_MBps"])
        log(f"{name}: gds --max-refs {max_refs} {r}")
        v = child(kind="verify", design=design, path=str(p), reader="stream", workers=workers, max_refs=max_refs)
        res["gds_hier_verify_stream"] = v
        log(f"{name}: gds --max-refs verify (stream) {v}")
        if klayout_gds:
            v = child(kind="verify", design=design, path=str(p), reader="klayout", workers=workers,
                      max_refs=max_refs)
            res["gds_hier_verify_klayout"] = v
            log(f"{name}: gds --max-refs verify (klayout) {v}")
        rm(p)
    if gdstk_ref:
        p = d / f"{name}_gdstk.gds"
        r = child(kind="gdstk", design=design, path=str(p))
        res["gdstk_gds"] = _rates(r)
        log(f"{name}: gdstk streamed gds {r}")
        rm(p)
    p = d / f"{name}.oas"
    r = child(kind="export", design=design, path=str(p), fmt="oas", workers=oas_workers)
    res["oas"] = _rates(r)
    log(f"{name}: oas {r}")
    v = child(kind="verify", design=design, path=str(p), reader="gdstk", workers=workers)
    res["oas_verify_gdstk"] = v
    log(f"{name}: oas verify (gdstk) {v}")
    if klayout_oas:
        v = child(kind="verify", design=design, path=str(p), reader="klayout", workers=workers)
        res["oas_verify_klayout"] = v
        log(f"{name}: oas verify (klayout) {v}")
    rm(p)
    res["load_end"] = os.getloadavg()
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--lens", nargs="+", default=["perifoveal"], choices=["perifoveal", "foveal"])
    ap.add_argument("--dir", default="/tmp/bench_layout")
    ap.add_argument("--disk-gb", type=float, default=3.0)
    ap.add_argument("--workers", type=int, default=2, help="GDSII export threads and verify workers")
    ap.add_argument("--oas-workers", type=int, default=2, help="OASIS export threads")
    ap.add_argument("--max-refs", type=int, default=8192, help="also export/verify hierarchical GDSII (0: skip)")
    ap.add_argument("--gdstk", nargs="*", default=["perifoveal"],
                    help="lenses for which gdstk's streamed GDSII writer is timed too (slow, 4 GB for 75 mm)")
    ap.add_argument("--klayout-gds", nargs="*", default=[],
                    help="lenses whose hierarchical GDSII is also read back by klayout (slow: one Python "
                         "iteration per post)")
    ap.add_argument("--klayout-oas", nargs="*", default=["perifoveal"],
                    help="lenses whose OASIS is also read back by klayout (slow, GBs for the 75 mm lens)")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    d = Path(a.dir)
    d.mkdir(parents=True, exist_ok=True)
    free = shutil.disk_usage(d).free / 1e9
    need = 12.0 if "foveal" in a.lens else 4.0
    if free < need:
        print(f"only {free:.0f} GB free in {d}; need ~{need:.0f} GB", file=sys.stderr)
        return 2
    out = []
    log = lambda s: print(s, flush=True)  # noqa: E731
    for name in a.lens:
        out.append(bench_lens(name, d, a.disk_gb, name in a.klayout_oas, a.workers, a.oas_workers, log,
                              gdstk_ref=name in a.gdstk, max_refs=a.max_refs or None,
                              klayout_gds=name in a.klayout_gds))
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

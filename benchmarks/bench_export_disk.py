"""GDSII export against the disk, side by side in one run: for the same bytes, (a) an ``O_DIRECT`` write of a
pre-filled buffer in 32 MiB writes, fsynced (what the disk can take: the floor of any exporter), (b) the post
encoding alone (the export's encoder threads, results dropped: what the CPU can make), (c) the export itself
(encoders + writer + fsync). The export can be no faster than max(a, b); "overlap" = c / max(a, b) says how well
the pipeline hides the slower of the two behind the other, "vs disk" = c / a is the issue's figure (<= 1.1 where
the disk is the bottleneck). Steps alternate (a b c a b c ...) so that load changes hit all three alike.

    python benchmarks/bench_export_disk.py --lens foveal --reps 2 --dir /tmp/bench_disk --json out.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def disk_write(path: Path, nbytes: int) -> float:
    """The disk's own time for ``nbytes`` (O_DIRECT, fsynced): :func:`metafovea.studies.bench.disk_write_seconds`."""
    from metafovea.studies.bench import disk_write_seconds

    return disk_write_seconds(path, nbytes)[0]


def encode_only(spec, workers: int) -> tuple[float, int]:
    """The export's own encoding of every task (in place into its aligned buffers, given back at once), no disk."""
    from metafovea.layout.export import ExportOptions, _encoded, _encoder, _Placed

    header, footer, _, _, enc = _encoder(spec, "gds", False, 1, None)
    t0 = time.perf_counter()
    n = len(header) + len(footer)
    for pieces, _, _ in _encoded(spec, "gds", ExportOptions(workers=workers), enc, spec.tasks(), len(header)):
        if isinstance(pieces, _Placed):
            n += pieces.n
            pieces.done()
        else:
            n += sum(p.nbytes for p in pieces)
    return time.perf_counter() - t0, n


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lens", default="foveal", choices=("foveal", "perifoveal"))
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--dir", default="/tmp/bench_disk")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    from metafovea.layout.export import ExportOptions, export_layout
    from metafovea.layout.tiling import load_spec

    d = Path(a.dir)
    d.mkdir(parents=True, exist_ok=True)
    spec = load_spec(ROOT / "designs" / f"{a.lens}.toml")
    rows = []
    print(f"{a.lens}: {len(spec.tasks())} tasks; {platform.node()}, {os.cpu_count()} CPUs, load "
          f"{' '.join(open('/proc/loadavg').read().split()[:3])}", flush=True)
    for rep in range(a.reps):
        t_enc, nbytes = encode_only(spec, a.workers)
        t_disk = disk_write(d / "disk.bin", nbytes)
        p = d / "lens.gds"
        t0 = time.perf_counter()
        res = export_layout(spec, p, "gds", ExportOptions(workers=a.workers, force=True, resume=False))
        t_exp = time.perf_counter() - t0
        assert res.bytes == nbytes == p.stat().st_size, (res.bytes, nbytes)
        p.unlink()
        load = " ".join(open("/proc/loadavg").read().split()[:3])
        r = {"rep": rep, "bytes": nbytes, "posts": res.posts, "disk_o_direct_s": t_disk, "encode_only_s": t_enc,
             "export_s": t_exp, "vs_disk": t_exp / t_disk, "overlap": t_exp / max(t_disk, t_enc), "load": load}
        rows.append(r)
        print(f"rep {rep}: {nbytes / 1e9:.2f} GB; O_DIRECT write {t_disk:.2f} s ({nbytes / t_disk / 1e6:.0f} MB/s), "
              f"encode only {t_enc:.2f} s, export {t_exp:.2f} s: {r['vs_disk']:.2f} x the disk, "
              f"{r['overlap']:.2f} x max(disk, encode); load {load}", flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps({"lens": a.lens, "workers": a.workers, "cpus": os.cpu_count(),
                                            "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

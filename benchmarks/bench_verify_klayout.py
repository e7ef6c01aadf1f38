"""KLayout reader benchmark: `metafovea verify FILE --reader klayout` on the 25 mm perifoveal lens's OASIS.

Exports ``designs/perifoveal.toml`` as OASIS (default RCWA post set, cached in ~/.cache/metafovea) to --dir
(default /tmp), then runs ``metafovea verify FILE --design ... --reader klayout --json`` in its own process and
prints its wall time, the reader's time (``seconds_read``), its peak memory (the largest max RSS among the verify
process and its children) and the load average before and after. ``--file`` verifies an
existing file instead (``--design`` then names its design); ``--format gds`` exports GDSII, ``--max-refs`` a
hierarchical GDSII, ``--flat`` a flat one. The exported file is deleted afterwards (``--keep`` keeps it).

    python benchmarks/bench_verify_klayout.py
    python benchmarks/bench_verify_klayout.py --format gds --json /tmp/bench_kl_gds.json
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: runs one command and prints its wall seconds and peak memory (the largest max RSS among the command and its
#: descendants) as JSON
CHILD = r"""
import json, resource, subprocess, sys, time
t0 = time.perf_counter()
p = subprocess.run(sys.argv[1:], capture_output=True, text=True)
dt = time.perf_counter() - t0
rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024
print(json.dumps({"rc": p.returncode, "seconds": dt, "max_rss": rss, "stdout": p.stdout[-20000:],
                  "stderr": p.stderr[-2000:]}))
"""


def _load() -> str:
    """``/proc/loadavg`` (1, 5 and 15 minute load averages, runnable/all tasks, last pid)."""
    p = Path("/proc/loadavg")
    return p.read_text().strip() if p.exists() else "?"


def _timed(cmd: list[str]) -> dict:
    """Run ``cmd`` from a fresh interpreter that reports its wall time and peak memory."""
    out = subprocess.run([sys.executable, "-c", CHILD, *cmd], capture_output=True, text=True, cwd=ROOT, check=True)
    return json.loads(out.stdout)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--design", default=str(ROOT / "designs" / "perifoveal.toml"))
    ap.add_argument("--file", help="verify this file (no export)")
    ap.add_argument("--format", default="oas", choices=("oas", "gds"))
    ap.add_argument("--max-refs", type=int, help="GDSII: hierarchical export")
    ap.add_argument("--flat", action="store_true", help="GDSII: one rectangle per post")
    ap.add_argument("--dir", default="/tmp")
    ap.add_argument("--keep", action="store_true", help="keep the exported file")
    ap.add_argument("--json", help="write the figures here")
    a = ap.parse_args(argv)
    metafovea = [sys.executable, "-m", "metafovea"]
    rows: dict = {"design": a.design}
    tmp = None
    if a.file:
        path = Path(a.file)
    else:
        tmp = Path(tempfile.mkdtemp(prefix="bench_kl_", dir=a.dir))
        path = tmp / f"lens.{a.format}"
        cmd = metafovea + ["export", a.design, "--format", a.format, "--out", str(path), "--quiet", "--force"]
        if a.max_refs:
            cmd += ["--max-refs", str(a.max_refs)]
        if a.flat:
            cmd += ["--flat"]
        r = _timed(cmd)
        if r["rc"]:
            print(r["stderr"], file=sys.stderr)
            return 1
        rows["export"] = {"seconds": round(r["seconds"], 2), "max_rss_gb": round(r["max_rss"] / 1e9, 3)}
    try:
        rows["file"] = str(path)
        rows["bytes"] = path.stat().st_size
        rows["load_before"] = _load()
        r = _timed(metafovea + ["verify", str(path), "--design", a.design, "--reader", "klayout", "--json",
                                "--quiet"])
        rows["load_after"] = _load()
        rep = json.loads(r["stdout"]) if r["stdout"].strip().startswith("{") else {}
        rows["verify"] = {"rc": r["rc"], "ok": rep.get("ok"), "posts": rep.get("posts"),
                          "seconds": round(r["seconds"], 2), "seconds_read": rep.get("seconds_read"),
                          "seconds_expected": rep.get("seconds_expected"),
                          "max_rss_gb": round(r["max_rss"] / 1e9, 3), "mismatches": rep.get("mismatches", [])[:5]}
        if r["rc"] and not rep:
            rows["verify"]["stderr"] = r["stderr"][-500:]
    finally:
        if tmp is not None and not a.keep:
            path.unlink(missing_ok=True)
            os.rmdir(tmp)
    v = rows["verify"]
    for k in ("seconds_read", "seconds_expected"):
        v[k] = None if v[k] is None else round(v[k], 2)
    print(f"{path.name}: {rows['bytes']:,} bytes; verify --reader klayout: {v['seconds']} s "
          f"(read {v['seconds_read']} s, expected {v['seconds_expected']} s), peak memory {v['max_rss_gb']} GB, "
          f"ok={v['ok']}, posts={v['posts']}; load {rows['load_before']} -> {rows['load_after']}")
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))
    return 0 if v["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())

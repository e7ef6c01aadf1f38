"""The reconstruction on recordings of an independent forward model (``tests/independent/forward.py``) that does
what a real camera does: one deviation at a time at the end of the issue's range, and a few combinations.

    python benchmarks/bench_real_recordings.py [--quick] [--frames 24] [--seed 0] [--scene mixed]
        [--window 8] [--stride 1] [--legacy-polarizer-block] [--prior none] [--json PATH] [--keep DIR]

Each recording (the paper's 280 x 290 pixels, 12 frames/s, a free-running 2 Hz polariser; documented keys only) is
written to a file, loaded with ``Measurement.load`` and reconstructed twice per window mode (the whole recording as
one window, and ``--window``-frame windows every ``--stride`` frames):

* unknown alpha: ``reconstruct_measurement(m, method="alternating")``;
* the oracle: ``reconstruct_measurement(m, method="lsq")`` on the file's TRUE effective alpha.

Reported: the alpha MAE against the true alpha (and the MAE of ``1 - alpha``, to catch a swapped gauge), each
image's PSNR against the noise-free truth (range of the truth as peak, the file's bad pixels and any non-finite
output pixel left out, the same pixels for both methods) and its difference to the oracle, the time of each
reconstruction and the status (an ``InputError`` is a failure with its message). A case passes when the issue's
targets hold: MAE <= 2e-3 and both images within 1 dB of the oracle (combined cases: 5e-3 and 1.5 dB).
``--legacy-polarizer-block`` adds the simulator's private ``polarizer`` dict that today's reconstruction reads
(``{mode: free, rate_hz, extinction: 0, tau_s: 0}``), to compare both ways; ``--prior none`` runs the
alternating solver without its image prior (its images are then the least-squares ones on its alpha).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.errors import InputError
from metafovea.measurement import Measurement
from metafovea.reconstruct import reconstruct_measurement

REPO = Path(__file__).resolve().parents[1]


def load_forward() -> Any:
    """``tests/independent/forward.py`` as a module (the name ``tests`` is taken by an installed package)."""
    path = REPO / "tests" / "independent" / "forward.py"
    spec = importlib.util.spec_from_file_location("independent_forward", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


F = load_forward()
QUICK = ("nominal", "jitter 2 deg", "tau 12 ms", "vignetting 20 %", "centre (3, -3) px")


def cases(quick: bool) -> list[tuple[str, Any, bool]]:
    """``(name, deviations, combined)`` of the grid."""
    out = [("nominal", F.Deviations(), False)]
    out += [(k, d, False) for k, d in F.RANGE_ENDS.items()]
    out += [(k, d, True) for k, d in F.COMBINED.items()]
    return [c for c in out if c[0] in QUICK] if quick else out


def psnr(est: np.ndarray, ref: np.ndarray, ok: np.ndarray) -> float:
    """PSNR over the pixels ``ok`` of every output (``est`` (H, W) or (K, H, W)), peak = the truth's range."""
    est = est if est.ndim == 3 else est[None]
    ref = ref.astype(np.float64)
    peak = float(ref[ok].max() - ref[ok].min())
    vals = []
    for e in est:
        m = ok & np.isfinite(e)
        mse = float(np.mean((e[m].astype(np.float64) - ref[m]) ** 2))
        vals.append(10 * np.log10(peak ** 2 / mse) if mse > 0 else np.inf)
    return float(np.mean(vals))


def estimated_alpha(res: Any) -> list[tuple[np.ndarray, tuple[int, int]]]:
    rec = res.reconstruction
    per = rec.info.get("alpha_windows") if rec.is_video else [rec.alpha]
    return list(zip([np.asarray(a, dtype=np.float64) for a in per], res.spans))


def run_one(m: Measurement, method: str, window: int, stride: int, ok: np.ndarray,
            solver: dict[str, Any] | None = None) -> dict[str, Any]:
    """One reconstruction: status, time, images' PSNR, alpha errors and the solver's own account."""
    out: dict[str, Any] = {"method": method}
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = reconstruct_measurement(m, method, window=window, stride=stride, score_truth=False,
                                          solver=solver)
    except InputError as e:
        out.update(status="InputError", message=str(e).splitlines()[0][:300], seconds=time.perf_counter() - t0)
        return out
    except Exception as e:  # noqa: BLE001 - a crash is a result of the grid, reported with its type
        out.update(status=f"crash ({type(e).__name__})", message=str(e).splitlines()[0][:300] if str(e) else "",
                   seconds=time.perf_counter() - t0)
        return out
    rec = res.reconstruction
    out.update(status="ok", seconds=res.seconds, wall_seconds=time.perf_counter() - t0,
               warnings=[str(w.message).splitlines()[0][:200] for w in caught])
    x1, x2 = np.asarray(rec.x1), np.asarray(rec.x2)
    out["nan_pixels"] = int(np.sum(~np.isfinite(x1)) + np.sum(~np.isfinite(x2)))
    out["psnr_x1"] = psnr(x1, m.truth_x1, ok)
    out["psnr_x2"] = psnr(x2, m.truth_x2, ok)
    if method != "lsq":
        errs = [(np.mean(np.abs(a - m.alpha[s:e])), np.mean(np.abs(1 - a - m.alpha[s:e]))) for a, (s, e) in
                estimated_alpha(res)]
        out["alpha_mae"] = float(np.mean([e[0] for e in errs]))
        out["alpha_mae_swapped"] = float(np.mean([e[1] for e in errs]))
        out["library_alpha_mae"] = res.alpha_mae
        info = rec.info
        out["alpha_identified"] = info.get("alpha_identified")
        gauge = info.get("alpha_gauge")
        out["alpha_gauge"] = gauge if isinstance(gauge, (str, list)) or gauge is None else str(gauge)
        pg = info.get("polarizer_gauge")
        out["polarizer_gauge_applied"] = pg.get("applied") if isinstance(pg, dict) else None
        if not rec.is_video:
            out["_alpha"] = np.asarray(rec.alpha, dtype=np.float64)
    return out


def verdict(alt: dict[str, Any], ora: dict[str, Any], combined: bool) -> tuple[bool, str]:
    mae_max, db = (5e-3, 1.5) if combined else (2e-3, 1.0)
    if alt["status"] != "ok":
        return False, alt["status"]
    if ora["status"] != "ok":
        return False, "oracle " + ora["status"]
    why = []
    if not alt["alpha_mae"] <= mae_max:
        why.append("MAE")
    for k in ("x1", "x2"):
        if not alt[f"psnr_{k}"] - ora[f"psnr_{k}"] >= -db:
            why.append(k)
    return not why, ", ".join(why) if why else "pass"


def run_case(name: str, dev: Any, combined: bool, a: argparse.Namespace, folder: Path) -> list[dict[str, Any]]:
    t0 = time.perf_counter()
    rec = F.record(a.scene, dev, frames=a.frames, seed=a.seed, legacy_polarizer_block=a.legacy_polarizer_block)
    path = rec.write(folder / f"{name.replace(' ', '_').replace('/', '_')}.npz")
    record_s = time.perf_counter() - t0
    m = Measurement.load(path)
    ok = np.ones(m.shape[1:], dtype=bool)
    for y, x in rec.truth["bad_pixels"]["dead"] + rec.truth["bad_pixels"]["saturated"]:
        ok[y, x] = False
    solver = None if a.prior == "default" else {"prior": None if a.prior == "none" else a.prior}
    rows = []
    for label, window, stride in (("whole", a.frames, a.frames), (f"{a.window}-frame", a.window, a.stride)):
        alt = run_one(m, "alternating", window, stride, ok, solver)
        ora = run_one(m, "lsq", window, stride, ok)
        if label == "whole" and alt["status"] == "ok":  # how much of the loss the alpha error explains
            alt["lsq_on_estimate"] = run_one(replace(m, alpha=np.clip(alt.pop("_alpha"), 0, 1)), "lsq", window,
                                             stride, ok)
        alt.pop("_alpha", None)
        passed, why = verdict(alt, ora, combined)
        rows.append({"scene": a.scene, "case": name, "combined": combined, "windows": label, "window": window,
                     "stride": stride, "deviations": dev.changed, "alternating": alt, "oracle": ora, "pass": passed,
                     "verdict": why, "record_seconds": record_s, "truth": {
                         "phase_deg": rec.truth["polarizer"]["phase_deg"],
                         "jitter_rms_deg_at_frames": rec.truth["polarizer"]["jitter_rms_deg_at_frames"]}})
    return rows


def fmt(v: float | None, spec: str) -> str:
    return "-" if v is None or not np.isfinite(v) else format(v, spec)


def verdict_cell(r: dict[str, Any]) -> str:
    return "pass" if r["pass"] else f"FAIL ({r['verdict']})"


def table(rows: list[dict[str, Any]]) -> str:
    head = ("| case | windows | status | alpha MAE | MAE of 1-alpha | x1 PSNR (vs oracle) | x2 PSNR (vs oracle) "
            "| LSQ on alpha-hat x1 / x2 (vs oracle) | time alt / lsq (s) | gauge | verdict |")
    out = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        alt, ora = r["alternating"], r["oracle"]
        if alt["status"] != "ok":
            cell = f"{alt['status']}: {alt.get('message', '')}".replace("|", "/")
            out.append(f"| {r['case']} | {r['windows']} | {cell} | - | - | - | - | - | {alt['seconds']:.2f} / "
                       f"{ora.get('seconds', 0):.2f} | - | FAIL ({r['verdict']}) |")
            continue
        d = {k: alt[f"psnr_{k}"] - ora[f"psnr_{k}"] if ora["status"] == "ok" else np.nan for k in ("x1", "x2")}
        gauge = alt.get("alpha_gauge")
        gauge = "/".join(gauge) if isinstance(gauge, list) else str(gauge)
        ident = "" if alt.get("alpha_identified") is None else (" (identified)" if alt["alpha_identified"]
                                                                 else " (not identified)")
        nan = f", {alt['nan_pixels']} NaN px" if alt["nan_pixels"] else ""
        le = alt.get("lsq_on_estimate")
        on_est = "-" if not le or le["status"] != "ok" else (
            f"{fmt(le['psnr_x1'] - ora['psnr_x1'], '+.1f')} / {fmt(le['psnr_x2'] - ora['psnr_x2'], '+.1f')}")
        out.append(f"| {r['case']} | {r['windows']} | ok{nan} | {fmt(alt['alpha_mae'], '.1e')} | "
                   f"{fmt(alt['alpha_mae_swapped'], '.2f')} | {fmt(alt['psnr_x1'], '.1f')} ({fmt(d['x1'], '+.1f')}) | "
                   f"{fmt(alt['psnr_x2'], '.1f')} ({fmt(d['x2'], '+.1f')}) | {on_est} | {alt['seconds']:.2f} / "
                   f"{ora.get('seconds', 0):.2f} | {gauge}{ident} | {verdict_cell(r)} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a small grid: " + ", ".join(QUICK).replace("%", "%%"))
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scene", nargs="+", default=["mixed"], choices=sorted(F.SCENES), help="one table each")
    ap.add_argument("--window", type=int, default=8)
    ap.add_argument("--stride", type=int, default=1)
    ap.add_argument("--legacy-polarizer-block", action="store_true",
                    help="add the simulator's private polarizer dict {mode: free, rate_hz, extinction: 0, tau_s: 0}")
    ap.add_argument("--prior", default="default", choices=("default", "none", "tv", "nlm", "bilateral"),
                    help="the alternating solver's image prior (default: the library's)")
    ap.add_argument("--json", type=Path, help="write the rows and the run's context as JSON")
    ap.add_argument("--keep", type=Path, help="keep the recordings in this folder")
    a = ap.parse_args(argv)
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True,
                                check=False).stdout.strip()
    except OSError:
        commit = ""
    context = {"date": time.strftime("%Y-%m-%d %H:%M %Z"), "cores": os.cpu_count(),
               "load_before": os.getloadavg()[0], "commit": commit, "command": " ".join(sys.argv),
               "scene": a.scene, "frames": a.frames, "seed": a.seed, "shape": list(F.Camera().shape),
               "legacy_polarizer_block": a.legacy_polarizer_block, "prior": a.prior}
    print(f"{context['date']}; {context['cores']} cores; load average {context['load_before']:.2f}; commit {commit}; "
          f"scenes {', '.join(a.scene)}, {a.frames} frames at {F.Camera().frame_rate_hz:g} frames/s, "
          f"{F.Camera().shape[0]} x {F.Camera().shape[1]} px, seed {a.seed}; "
          f"{'WITH' if a.legacy_polarizer_block else 'without'} the legacy polarizer block; alternating prior "
          f"{a.prior}")
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = a.keep or Path(tmp)
        for scene in a.scene:
            one = argparse.Namespace(**{**vars(a), "scene": scene})
            these: list[dict[str, Any]] = []
            for name, dev, combined in cases(a.quick):
                these += run_case(name, dev, combined, one, folder / scene)
                print(f"  {scene} / {name}: " + "; ".join(f"{r['windows']} {r['verdict']}" for r in these[-2:]),
                      file=sys.stderr)
            print(f"\nScene '{scene}':\n")
            print(table(these))
            rows += these
    n_pass = sum(r["pass"] for r in rows)
    print(f"\n{n_pass} of {len(rows)} rows pass; load average after: {os.getloadavg()[0]:.2f}")
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(F.jsonable({"context": context, "rows": rows}), indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

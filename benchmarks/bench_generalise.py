"""PSF-aware reconstruction on held-out generated scenes against the linear Wiener bound (issue 31, part 5).

Each case is a scene of the seeded generator (``gen:KIND:SEED``, test seeds, :func:`metafovea.imaging.generator.
held_out_scenes`) x band (8-14 um unfiltered, the 10 um filter) x noise (the system's NETD, twice it), simulated as a
user records it (48 frames, 16 shutter frames, ``designs/system.toml``), the fixed pattern estimated from the shutter
frames (its error counted), then each method of ``deconvolve_measurement`` on that one measurement, side by side
(:func:`metafovea.studies.heldout.run_case`).

    python benchmarks/bench_generalise.py [--scenes 64] [--seed-offset 0] [--tuning] [--noise default|high|both]
        [--bands 8-14um 10um] [--methods NAME ...] [--wavelet haar|db2|sym4] [--workers 1] [--json out.json]
        [--plot margins.png] [--quick]

Prints per case and channel: scene, kind, band, noise, channel, method PSNR, bound PSNR, margin (dB) and the method's
time (s); per scene and noise the foveal PSNR of 8-14 um minus that of the 10 um filter; and per method the fraction
of channel cases at or above the bound, the worst and the median margin (dB). To compare two trees on the same
cases, run the script of one with ``PYTHONPATH`` set to the other.
"""

from __future__ import annotations

import argparse
import datetime
import functools
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from metafovea.config import load_system
from metafovea.imaging.generator import held_out_scenes, parse_scene_name, tuning_scenes
from metafovea.parallel import run_tasks
from metafovea.reconstruct.deconvolve import DECONVOLUTION_METHODS
from metafovea.reconstruct.metrics import margin_summary
from metafovea.studies.heldout import CASE_CALIBRATION_FRAMES, CASE_FRAMES, HeldOutCase, run_case

SYSTEM = Path(__file__).resolve().parents[1] / "designs" / "system.toml"
#: band name -> filter_enabled
BANDS = {"8-14um": False, "10um": True}
#: the high noise level's NETD, a multiple of the system's
HIGH_NETD_FACTOR = 2.0


def _load() -> str:
    try:
        with open("/proc/loadavg") as f:
            return " ".join(f.read().split()[:3])
    except OSError:
        return "n/a"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=64, help="generated scenes (default 64), the kinds in turn")
    ap.add_argument("--seed-offset", type=int, default=0, help="first test seed (scene i has seed offset + i)")
    ap.add_argument("--tuning", action="store_true",
                    help="the tuning scenes (seeds from 10000 + offset) instead of the held-out test scenes")
    ap.add_argument("--noise", choices=("default", "high", "both"), default="default",
                    help=f"the system's NETD, {HIGH_NETD_FACTOR:g}x it, or both (default: default)")
    ap.add_argument("--bands", nargs="+", choices=tuple(BANDS), default=list(BANDS),
                    help="8-14um (no filter) and/or 10um (the filter); default both")
    ap.add_argument("--methods", nargs="+", default=None,
                    help="deconvolve_measurement's method names, passed unchanged, side by side on each measurement "
                         f"(known today: {', '.join(DECONVOLUTION_METHODS)}); default: its default method")
    ap.add_argument("--wavelet", default=None, help="the wavelet of method 'wavelet' (default: its default)")
    ap.add_argument("--frames", type=int, default=CASE_FRAMES, help=f"frames per recording (default {CASE_FRAMES})")
    ap.add_argument("--calibration-frames", type=int, default=CASE_CALIBRATION_FRAMES,
                    help=f"shutter frames for the FPN (default {CASE_CALIBRATION_FRAMES})")
    ap.add_argument("--quick", action="store_true", help="4 scenes, the first band only, 12 frames")
    ap.add_argument("--workers", type=int, default=1, help="processes over the cases (default 1)")
    ap.add_argument("--json", type=Path, default=None, help="write the cases and the summary here")
    ap.add_argument("--plot", type=Path, default=None, help="write the margins against scene here (PNG)")
    args = ap.parse_args(argv)
    if args.quick:
        args.scenes, args.bands, args.frames = min(args.scenes, 4), args.bands[:1], 12
    return args


def make_cases(args: argparse.Namespace, netd_k: float) -> list[tuple[str, HeldOutCase]]:
    """``(noise label, case)`` for every scene x band x noise level."""
    levels = {"default": [("default", None)], "high": [("high", HIGH_NETD_FACTOR * netd_k)]}
    levels["both"] = levels["default"] + levels["high"]
    cases = []
    for name, _ in (tuning_scenes if args.tuning else held_out_scenes)(args.scenes, args.seed_offset):
        seed = parse_scene_name(name)[1]
        for label, netd in levels[args.noise]:
            for band in args.bands:
                cases.append((label, HeldOutCase(name, BANDS[band], netd, args.frames, args.calibration_frames,
                                                 seed)))
    return cases


def _band(filter_enabled: bool) -> str:
    return next(k for k, v in BANDS.items() if v == filter_enabled)


def case_rows(label: str, res: dict) -> list[dict]:
    """A case's result as flat rows, one per method and channel."""
    kind = parse_scene_name(res["scene"])[0]
    return [{"scene": res["scene"], "kind": kind, "band": _band(res["filter_enabled"]), "noise": label,
             "netd_k": res["netd_k"], **r} for r in res["rows"]]


def print_row(r: dict) -> None:
    print(f"{r['scene']:<22} {r['kind']:<11} {r['band']:<6} {r['noise']:<7} {r['channel']:<10} {r['method']:<10} "
          f"{r['psnr_db']:>7.2f} {r['bound_db']:>7.2f} {r['margin_db']:>+7.2f} {r['seconds']:>6.2f}", flush=True)


def foveal_gaps(rows: list[dict]) -> list[dict]:
    """Per scene, noise and method: foveal PSNR of 8-14 um minus that of the 10 um filter (dB)."""
    by = {}
    for r in rows:
        if r["channel"] == "foveal":
            by.setdefault((r["scene"], r["noise"], r["method"]), {})[r["band"]] = r["psnr_db"]
    return [{"scene": s, "noise": n, "method": m, "unfiltered_db": v["8-14um"], "filtered_db": v["10um"],
             "gap_db": v["8-14um"] - v["10um"]} for (s, n, m), v in by.items() if len(v) == 2]


def summaries(rows: list[dict]) -> dict:
    """Per method (and per method and noise level): :func:`margin_summary` of the channel cases, and the time."""
    out = {}
    for key in sorted({(r["method"], None) for r in rows} | {(r["method"], r["noise"]) for r in rows},
                      key=lambda k: (k[0], k[1] or "")):
        sel = [r for r in rows if r["method"] == key[0] and (key[1] is None or r["noise"] == key[1])]
        secs = [r["seconds"] for r in sel if r["channel"] == "foveal"]
        out[f"{key[0]}" + (f" / noise {key[1]}" if key[1] else " / all")] = {
            **margin_summary([r["margin_db"] for r in sel]), "median_seconds": float(np.median(secs)),
            "max_seconds": float(np.max(secs))}
    return out


def below_by_kind(rows: list[dict]) -> dict:
    """Per method and scene kind: channel cases below the bound, of how many, and the kind's median margin (dB)."""
    out: dict = {}
    for r in rows:
        out.setdefault(r["method"], {}).setdefault(r["kind"], []).append(r["margin_db"])
    return {m: {k: {"below": int(np.sum(np.array(v) < 0)), "cases": len(v), "median_db": float(np.median(v))}
                for k, v in sorted(by.items())} for m, by in out.items()}


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from metafovea.report import fig_to_png

    methods = sorted({r["method"] for r in rows})
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    fig, axes = plt.subplots(len(methods), 1, figsize=(max(8, 0.22 * len(scenes) + 3), 3.6 * len(methods)),
                             squeeze=False)
    markers = {("8-14um", "foveal"): "o", ("8-14um", "perifoveal"): "s", ("10um", "foveal"): "^",
               ("10um", "perifoveal"): "D"}
    for ax, method in zip(axes[:, 0], methods):
        for (band, channel), mk in markers.items():
            for noise, fill in (("default", True), ("high", False)):
                sel = [r for r in rows if (r["method"], r["band"], r["channel"], r["noise"]) ==
                       (method, band, channel, noise)]
                if sel:
                    x = [scenes.index(r["scene"]) for r in sel]
                    ax.plot(x, [r["margin_db"] for r in sel], mk, ms=5, ls="none", mfc=None if fill else "none",
                            label=f"{band} {channel}, {noise} noise")
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_xticks(range(len(scenes)))
        ax.set_xticklabels([s.removeprefix("gen:") for s in scenes], rotation=90, fontsize=6)
        ax.set_ylabel("margin over the Wiener bound (dB)")
        ax.set_title(f"{method}: PSNR against the scene minus the linear bound's")
        ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    path.write_bytes(fig_to_png(fig))
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    t0 = time.perf_counter()
    load0 = _load()
    print(f"nproc {os.cpu_count()}, load {load0}, {datetime.datetime.now().isoformat(timespec='seconds')}")
    system = load_system(SYSTEM)
    cases = make_cases(args, system.sensor.netd_k)
    first = parse_scene_name(cases[0][1].scene)[1]
    print(f"{len(cases)} cases: {args.scenes} {'tuning' if args.tuning else 'held-out test'} scenes (seeds {first}-"
          f"{first + args.scenes - 1})"
          f" x {len(args.bands)} bands x noise {args.noise}; {args.frames} frames, {args.calibration_frames} shutter "
          f"frames; methods {args.methods or 'default'}{'' if args.wavelet is None else ', wavelet ' + args.wavelet}; "
          f"{args.workers} worker(s)")
    print(f"{'scene':<22} {'kind':<11} {'band':<6} {'noise':<7} {'channel':<10} {'method':<10} "
          f"{'PSNR':>7} {'bound':>7} {'margin':>7} {'s':>6}")
    fn = functools.partial(run_case, SYSTEM, methods=args.methods, threads=1 if args.workers > 1 else None,
                           options=None if args.wavelet is None else {"wavelet": args.wavelet})
    results: list[dict | None] = [None] * len(cases)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the simulator's notes on the scenes (cold sky pixels and the like)
        done = (enumerate(map(fn, (c for _, c in cases))) if args.workers == 1 else  # in order, as each ends
                run_tasks(fn, [c for _, c in cases], workers=args.workers))
        for i, res in done:
            results[i] = res
            for r in case_rows(cases[i][0], res):
                print_row(r)
    rows = [r for (label, _), res in zip(cases, results) for r in case_rows(label, res)]
    gaps = foveal_gaps(rows)
    if gaps:
        print("\nfoveal PSNR, 8-14 um minus the 10 um filter (dB):")
        for g in gaps:
            print(f"  {g['scene']:<22} {g['noise']:<7} {g['method']:<10} {g['unfiltered_db']:>7.2f} "
                  f"{g['filtered_db']:>7.2f} {g['gap_db']:>+7.2f}")
        gv = np.array([g["gap_db"] for g in gaps])
        print(f"  gap: median {np.median(gv):+.2f} dB, worst {gv.min():+.2f} dB, within 3 dB in "
              f"{int(np.sum(gv >= -3))} of {gv.size}")
    summ = summaries(rows)
    print("\nper method: channel cases at or above the bound, worst and median margin (dB), method time (s)")
    for k, s in summ.items():
        print(f"  {k:<28} {s['at_or_above']:6.1%} of {s['cases']:>4}  worst {s['worst_db']:+6.2f}  median "
              f"{s['median_db']:+6.2f}  time median {s['median_seconds']:.2f} max {s['max_seconds']:.2f}")
    kinds = below_by_kind(rows)
    for m, by in kinds.items():
        print(f"  {m}: below the bound by kind: " + ", ".join(
            f"{k} {v['below']} of {v['cases']} (median {v['median_db']:+.2f})" for k, v in by.items()))
    wall = time.perf_counter() - t0
    load1 = _load()
    print(f"nproc {os.cpu_count()}, load {load1}; wall {wall:.0f} s")
    if args.json:
        meta = {"command": " ".join([Path(sys.argv[0]).name, *(argv if argv is not None else sys.argv[1:])]),
                "nproc": os.cpu_count(), "load_start": load0, "load_end": load1, "wall_seconds": wall,
                "date": datetime.date.today().isoformat(), "args": {k: str(v) for k, v in vars(args).items()}}
        args.json.write_text(json.dumps({"meta": meta, "summary": summ, "below_by_kind": kinds, "foveal_gaps": gaps,
                                         "rows": rows, "cases": results}, indent=1, default=float))
    if args.plot:
        plot(rows, args.plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

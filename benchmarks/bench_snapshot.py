"""The snapshot (one-frame) mode on held-out generated scenes, beside the unseparated frame and the multi-frame result
(issue 31, part 6).

Each case is a scene of the seeded generator (``gen:KIND:SEED``, test seeds, :func:`metafovea.imaging.generator.
held_out_scenes`) x band (8-14 um unfiltered, the 10 um filter), simulated as a user records it (48 frames, 16
shutter frames, ``designs/system.toml``, the system's NETD); on that one recording
(:func:`metafovea.studies.snapshot_heldout.run_case`): the snapshot mode on the frame whose alpha is nearest 0.5, the
same frame taken as both images (no separation), and least squares with known alpha over the whole recording, the
fixed pattern from the shutter frames for all three.

    python benchmarks/bench_snapshot.py [--scenes 64] [--seed-offset 0] [--bands 8-14um 10um] [--frames 48]
        [--separation constraint|paper] [--tuning] [--workers 1] [--json out.json] [--quick]

Prints per case: PSNR of the foveal (x1) and perifoveal (x2) images of each method against the noise-free sensor
images (the truth ``reconstruct_measurement`` scores the multi-frame pipeline against), the residual overlap of each
(the correlation of a channel's error with the other channel's true image, the channel's own truth regressed out:
0 = separated, ~1 = the unseparated frame; :func:`metafovea.studies.snapshot_heldout.overlap`) and the
registration's error against the true geometry (the nominal one: the simulator realises none); then on how many
scenes the snapshot beats the unseparated frame (both channels, every band), in how many cases it also beats that
frame moved to each truth's mean (an oracle baseline), and the medians.
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

from metafovea.imaging.generator import held_out_scenes, parse_scene_name, tuning_scenes
from metafovea.parallel import run_tasks
from metafovea.reconstruct.snapshot import SEPARATIONS
from metafovea.studies.heldout import CASE_CALIBRATION_FRAMES, CASE_FRAMES, HeldOutCase
from metafovea.studies.snapshot_heldout import TRUTH, run_case

SYSTEM = Path(__file__).resolve().parents[1] / "designs" / "system.toml"
#: band name -> filter_enabled
BANDS = {"8-14um": False, "10um": True}


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
    ap.add_argument("--bands", nargs="+", choices=tuple(BANDS), default=list(BANDS),
                    help="8-14um (no filter) and/or 10um (the filter); default both")
    ap.add_argument("--frames", type=int, default=CASE_FRAMES, help=f"frames per recording (default {CASE_FRAMES})")
    ap.add_argument("--calibration-frames", type=int, default=CASE_CALIBRATION_FRAMES,
                    help=f"shutter frames for the FPN (default {CASE_CALIBRATION_FRAMES})")
    ap.add_argument("--separation", choices=SEPARATIONS, default=SEPARATIONS[0],
                    help=f"the snapshot's separation (default {SEPARATIONS[0]}; 'paper': the paper's loss)")
    ap.add_argument("--tuning", action="store_true",
                    help="the tuning scenes (seeds from 10000 + offset) instead of the held-out test scenes")
    ap.add_argument("--quick", action="store_true", help="4 scenes, both bands, 12 frames")
    ap.add_argument("--workers", type=int, default=1, help="processes over the cases (default 1)")
    ap.add_argument("--json", type=Path, default=None, help="write the cases and the summary here")
    args = ap.parse_args(argv)
    if args.quick:
        args.scenes, args.frames = min(args.scenes, 4), 12
    return args


def make_cases(args: argparse.Namespace) -> list[HeldOutCase]:
    """Every scene x band."""
    return [HeldOutCase(name, BANDS[band], None, args.frames, args.calibration_frames, parse_scene_name(name)[1])
            for name, _ in (tuning_scenes if args.tuning else held_out_scenes)(args.scenes, args.seed_offset)
            for band in args.bands]


def _band(filter_enabled: bool) -> str:
    return next(k for k, v in BANDS.items() if v == filter_enabled)


def case_row(res: dict) -> dict:
    """A case's result as one flat row."""
    rows = {r["method"]: r for r in res["rows"]}
    reg = res["registration"]
    out = {"scene": res["scene"], "kind": parse_scene_name(res["scene"])[0], "band": _band(res["filter_enabled"]),
           "frame": res["frame"], "alpha": res["alpha"], "identified": reg.get("identified"),
           "moved": reg.get("moved"), "scale_error": reg["scale_error"], "offset_error_px": reg["offset_error_px"],
           "rotation_error_deg": reg["rotation_error_deg"], "snapshot_seconds": rows["snapshot"]["seconds"]}
    for m, r in rows.items():
        for q in ("psnr_x1", "psnr_x2", "overlap_x1", "overlap_x2"):
            out[f"{m}_{q}"] = r[q]
    out["beats_frame"] = bool(out["snapshot_psnr_x1"] > out["frame_psnr_x1"]
                              and out["snapshot_psnr_x2"] > out["frame_psnr_x2"])
    out["beats_frame_level"] = bool(out["snapshot_psnr_x1"] > out["frame_level_psnr_x1"]
                                    and out["snapshot_psnr_x2"] > out["frame_level_psnr_x2"])
    return out


HEADER = (f"{'scene':<22} {'band':<6} {'a':>5} | {'snapshot x1':>11} {'x2':>6} | {'frame x1':>8} {'x2':>6} | "
          f"{'lsq x1':>6} {'x2':>6} | {'ovl snap':>8} {'frame':>6} {'lsq':>6} | {'reg':>3} {'dscale':>7} "
          f"{'doff px':>7} {'drot':>5} | {'s':>5}")


def print_row(r: dict) -> None:
    rot = "n/a" if r["rotation_error_deg"] is None else f"{r['rotation_error_deg']:+.2f}"
    reg = "mov" if r["moved"] else ("id" if r["identified"] else "nom")
    print(f"{r['scene']:<22} {r['band']:<6} {r['alpha']:5.2f} | {r['snapshot_psnr_x1']:11.2f} "
          f"{r['snapshot_psnr_x2']:6.2f} | {r['frame_psnr_x1']:8.2f} {r['frame_psnr_x2']:6.2f} | "
          f"{r['lsq_psnr_x1']:6.2f} {r['lsq_psnr_x2']:6.2f} | {r['snapshot_overlap_x1']:+8.2f} "
          f"{r['frame_overlap_x1']:+6.2f} {r['lsq_overlap_x1']:+6.2f} | {reg:>3} {r['scale_error']:+7.4f} "
          f"{r['offset_error_px']:7.2f} {rot:>5} | {r['snapshot_seconds']:5.1f}", flush=True)


def summary(rows: list[dict]) -> dict:
    """Scenes on which the snapshot beats the unseparated frame (both channels, every band run), and the medians."""
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    beats = [s for s in scenes if all(r["beats_frame"] for r in rows if r["scene"] == s)]
    out: dict = {"scenes": len(scenes), "cases": len(rows), "scenes_snapshot_beats_frame": len(beats),
                 "cases_snapshot_beats_frame": int(sum(r["beats_frame"] for r in rows)),
                 "cases_snapshot_beats_frame_level": int(sum(r["beats_frame_level"] for r in rows)),
                 "scenes_not_beaten": [s for s in scenes if s not in beats],
                 "registration_identified": int(sum(bool(r["identified"]) for r in rows)),
                 "registration_moved": int(sum(bool(r["moved"]) for r in rows)),
                 "max_offset_error_px": float(max(r["offset_error_px"] for r in rows)),
                 "max_abs_scale_error": float(max(abs(r["scale_error"]) for r in rows))}
    for band in dict.fromkeys(r["band"] for r in rows):
        sel = [r for r in rows if r["band"] == band]
        for key in ("snapshot_psnr_x1", "snapshot_psnr_x2", "frame_psnr_x1", "frame_psnr_x2",
                    "frame_level_psnr_x1", "frame_level_psnr_x2", "lsq_psnr_x1",
                    "lsq_psnr_x2", "snapshot_overlap_x1", "snapshot_overlap_x2", "frame_overlap_x1",
                    "lsq_overlap_x1", "snapshot_seconds"):
            out[f"{band} median {key}"] = float(np.median([r[key] for r in sel]))
        for ch in ("x1", "x2"):
            m = np.array([r[f"snapshot_psnr_{ch}"] - r[f"frame_psnr_{ch}"] for r in sel])
            out[f"{band} snapshot minus frame {ch} min_db"] = float(m.min())
    return out


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    t0 = time.perf_counter()
    load0 = _load()
    print(f"nproc {os.cpu_count()}, load {load0}, {datetime.datetime.now().isoformat(timespec='seconds')}")
    cases = make_cases(args)
    first = parse_scene_name(cases[0].scene)[1]
    print(f"{len(cases)} cases: {args.scenes} {'tuning' if args.tuning else 'held-out test'} scenes (seeds {first}-"
          f"{first + args.scenes - 1}) x {len(args.bands)} bands; {args.frames} frames, {args.calibration_frames} "
          f"shutter frames; snapshot separation '{args.separation}'; {args.workers} worker(s)")
    print(f"PSNR (dB) against {TRUTH}; overlap: corr(x1_hat - truth_x1, truth_x2), truth_x1 regressed out; "
          "registration against the nominal "
          "geometry (reg: nom = not identified, nominal kept; id = identified at the nominal; mov = moved)")
    print(HEADER)
    fn = functools.partial(run_case, SYSTEM, solver={"separation": args.separation},
                           threads=1 if args.workers > 1 else None)
    results: list[dict | None] = [None] * len(cases)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the simulator's notes on the scenes (cold sky pixels and the like)
        done = enumerate(map(fn, cases)) if args.workers == 1 else run_tasks(fn, cases, workers=args.workers)
        for i, res in done:
            results[i] = res
            print_row(case_row(res))
    rows = [case_row(res) for res in results]
    summ = summary(rows)
    print(f"\nsnapshot beats the unseparated frame (both channels, every band) on {summ['scenes_snapshot_beats_frame']}"
          f" of {summ['scenes']} scenes ({summ['cases_snapshot_beats_frame']} of {summ['cases']} cases)"
          + (f"; not on: {', '.join(summ['scenes_not_beaten'])}" if summ["scenes_not_beaten"] else ""))
    print(f"  and the frame moved to each truth's mean (an oracle level) in {summ['cases_snapshot_beats_frame_level']}"
          f" of {summ['cases']} cases")
    print(f"registration: identified in {summ['registration_identified']} of {summ['cases']} frames, moved from the "
          f"nominal geometry in {summ['registration_moved']}; largest offset error {summ['max_offset_error_px']:.2f} "
          f"px, largest scale error {summ['max_abs_scale_error']:.4f} (rotation: not estimated, the constraint has "
          "none; the simulator realises none)")
    for k, v in summ.items():
        if " median " in k or " min_db" in k:
            print(f"  {k:<44} {v:+8.2f}")
    wall = time.perf_counter() - t0
    load1 = _load()
    print(f"nproc {os.cpu_count()}, load {load1}; wall {wall:.0f} s")
    if args.json:
        meta = {"command": " ".join([Path(sys.argv[0]).name, *(argv if argv is not None else sys.argv[1:])]),
                "nproc": os.cpu_count(), "load_start": load0, "load_end": load1, "wall_seconds": wall,
                "date": datetime.date.today().isoformat(), "truth": TRUTH,
                "args": {k: str(v) for k, v in vars(args).items()}}
        args.json.write_text(json.dumps({"meta": meta, "summary": summ, "rows": rows, "cases": results}, indent=1,
                                        default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

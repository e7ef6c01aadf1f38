"""``metafovea reconstruct``: separate a Measurement file into foveal and perifoveal images.

Wired into :mod:`metafovea.cli` by ``add_parser(subparsers)``; ``run(args)`` returns the exit status
(0 ok, 2 bad input with a one-line message).

The Measurement file is an ``.npz`` written by :func:`metafovea.io.atomic_save_npz` with arrays
``frames (T, H, W)``, ``times_s (T,)``, optionally ``alpha (T,)``, ``truth_x1``, ``truth_x2``,
``calibration (Tc, H, W)``, and JSON meta (``scale``, pixel pitch, ...).
"""

from __future__ import annotations

import argparse
import io
import logging
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.errors import InputError
from metafovea.io import to_json

log = logging.getLogger(__name__)

HELP = "separate foveal and perifoveal images from a measurement (.npz)"


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser("reconstruct", help=HELP, description=HELP)
    p.add_argument("measurement", help="Measurement .npz (frames, times_s, optional alpha / truth_x1 / truth_x2)")
    p.add_argument("--method", default="lsq", choices=("lsq", "alternating", "dip", "snapshot"),
                   help="solver (default lsq; lsq needs the file's alpha)")
    p.add_argument("--known-alpha", action="store_true",
                   help="use the file's alpha (implied by --method lsq; holds alpha fixed for dip)")
    p.add_argument("--window", type=int, default=None, help="frames per window (default 8, or all frames of a "
                   "shorter sequence); longer sequences are reconstructed window by window")
    p.add_argument("--stride", type=int, default=1, help="window stride in frames (default 1)")
    p.add_argument("--denoise", default=None, choices=("tv", "bilateral", "nlm"), help="denoise the outputs")
    p.add_argument("--fpn", default="none", choices=("none", "prior", "calibration", "file"),
                   help="fixed-pattern noise handling (calibration uses the file's 'calibration' frames; file "
                   "subtracts the file's 'fpn' pattern, e.g. a dark-frame calibration)")
    p.add_argument("--scale", type=float, default=None, help="f1/f2 of the foveal constraint (default: file meta "
                   "'foveal_constraint.scale', else 'scale', else 6)")
    p.add_argument("--foveal-gain", type=float, default=None, help="radiometric gain of the foveal constraint "
                   "D x1 = gain C x2 + offset (default: file meta 'foveal_constraint.gain', else 1)")
    p.add_argument("--foveal-offset", type=float, default=None, help="offset of the foveal constraint, in the "
                   "frames' units (default: file meta 'foveal_constraint.offset_dn', else 0)")
    p.add_argument("--regularize", default=None, help="lsq: 'difference' (ridge on x1 - x2, the smallest that "
                   "meets the condition limit) or a ridge weight >= 0, for windows whose alpha barely varies")
    p.add_argument("--no-strict", action="store_true", help="alternating: when the foveal constraint cannot fix "
                   "alpha's gauge, return the frame-mean-gauge result (flagged alpha_identified: false) instead of "
                   "an error")
    p.add_argument("--frame", type=int, default=0, help="frame index for --method snapshot (default 0)")
    p.add_argument("--steps", type=int, default=2000, help="DIP optimisation steps (default 2000)")
    p.add_argument("--channels", type=int, default=32, help="DIP network channels (default 32)")
    p.add_argument("--seed", type=int, default=0, help="random seed (DIP)")
    p.add_argument("--out", default=None, help="output .npz (default: <measurement>_rec.npz); figures next to it")
    p.add_argument("--no-figures", action="store_true", help="do not write PNG figures")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--force", action="store_true", help="overwrite existing output")
    p.set_defaults(func=run)
    return p


def foveal_constraint(meta: dict[str, Any], *, scale: float | None = None, gain: float | None = None,
                      offset: float | None = None) -> dict[str, float]:
    from metafovea.measurement import FovealConstraint
    return FovealConstraint.from_meta(meta, scale=scale, gain=gain, offset=offset).as_kwargs()


def _figure(x1: np.ndarray, x2: np.ndarray, title: str) -> bytes:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, 2, figsize=(9, 4.2), constrained_layout=True)
    for ax, img, name in ((axs[0], x1, "foveal x1"), (axs[1], x2, "perifoveal x2")):
        im = ax.imshow(img, cmap="inferno")
        ax.set_title(name)
        ax.set_axis_off()
        fig.colorbar(im, ax=ax, shrink=0.8)
    fig.suptitle(title)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()


def _image_png(img: np.ndarray) -> bytes:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    x = np.nan_to_num(np.asarray(img, dtype=np.float64))
    plt.imsave(buf, x, cmap="inferno", format="png")
    return buf.getvalue()


def _summary(args: argparse.Namespace) -> dict[str, Any]:
    from metafovea.io import atomic_write_bytes, prepare_output
    from metafovea.reconstruct import reconstruct, video
    from metafovea.reconstruct.metrics import score

    src = Path(args.measurement)
    arrays, meta = _load(src)
    if "frames" not in arrays:
        raise InputError("measurement", str(src), "a Measurement .npz holding a 'frames' (T, H, W) array")
    frames = arrays["frames"]
    if frames.ndim != 3:
        raise InputError("frames", f"array of shape {frames.shape}", "(T, H, W)", source=str(src))
    T = frames.shape[0]
    if T < 1 or min(frames.shape[1:]) < 1:
        raise InputError("frames", f"array of shape {frames.shape}", "at least one (H, W) frame", source=str(src))
    if np.issubdtype(frames.dtype, np.number) and not np.iscomplexobj(frames) and not np.any(np.isfinite(frames)):
        raise InputError("frames", "no finite value", "frames with finite pixel values (NaN/inf pixels are "
                         "masked, but all of them are non-finite)", source=str(src))
    truths = _check_truth(arrays, frames.shape, src)
    if args.method != "snapshot" and T < 2:
        raise InputError("frames", f"{T} frame", "at least 2 frames (or --method snapshot for a single frame)",
                         source=str(src))
    if args.window is None:  # the default: 8 frames, or all of a shorter sequence
        args.window = min(8, T)
    if args.method != "snapshot" and not 2 <= args.window:
        raise InputError("--window", args.window, f"2 <= window <= number of frames ({T})")
    if args.stride < 1:
        raise InputError("--stride", args.stride, "an integer >= 1")
    if args.seed < 0:
        raise InputError("--seed", args.seed, "an integer >= 0")
    out = Path(args.out) if args.out else src.with_name(src.stem + "_rec.npz")
    if out.suffix.lower() != ".npz":
        raise InputError("--out", str(out), "a file name ending in .npz")
    if out.resolve() == src.resolve() or (out.exists() and os.path.samefile(out, src)):
        raise InputError("--out", str(out), "a path other than the measurement itself (it would be overwritten)")
    out = prepare_output(out, args.force)
    stem = out.with_suffix("")
    figures = [] if args.no_figures else [f"{stem}_x1.png", f"{stem}_x2.png", f"{stem}.png"]
    for name in figures:  # all outputs are checked before anything is computed or written
        prepare_output(name, args.force)
    geo = foveal_constraint(meta, scale=args.scale, gain=args.foveal_gain, offset=args.foveal_offset)
    scale = geo["scale"]
    use_alpha = args.known_alpha or args.method == "lsq"
    alpha = None
    if use_alpha:
        if "alpha" not in arrays:
            raise InputError("alpha", "absent", f"an 'alpha' array in the measurement for "
                             f"{'--known-alpha' if args.known_alpha else '--method lsq'} (or --method alternating / "
                             f"dip / snapshot for unknown alpha)", source=str(src))
        alpha = arrays["alpha"]
        if alpha.shape != (T,) or not np.issubdtype(alpha.dtype, np.number) or np.iscomplexobj(alpha):
            raise InputError("alpha", f"array of shape {alpha.shape}, dtype {alpha.dtype}",
                             f"one real mixing ratio per frame, shape ({T},)", source=str(src))
    if args.method == "alternating" and args.known_alpha:
        raise InputError("--known-alpha", True, "not with --method alternating (it estimates alpha; use lsq)")
    fpn_kw: dict[str, Any] = {}
    if args.fpn == "calibration":
        if "calibration" not in arrays:
            raise InputError("--fpn", "calibration", "a measurement with a 'calibration' frame array", source=str(src))
        cal = arrays["calibration"]
        if cal.ndim not in (2, 3) or cal.shape[-2:] != frames.shape[1:]:
            raise InputError("calibration", f"array of shape {cal.shape}",
                             f"(Tc, H, W) or (H, W) frames with (H, W) = {frames.shape[1:]}", source=str(src))
        fpn_kw = {"fpn": "calibration", "calibration": cal}
    elif args.fpn == "prior":
        fpn_kw = {"fpn": "prior"}
    elif args.fpn == "file":
        if "fpn" not in arrays:
            raise InputError("--fpn", "file", "a measurement with an 'fpn' (H, W) array", source=str(src))
        f = arrays["fpn"]
        if f.shape != frames.shape[1:] or not np.issubdtype(f.dtype, np.number) or np.iscomplexobj(f):
            raise InputError("fpn", f"array of shape {f.shape}, dtype {f.dtype}",
                             f"real values of the frames' (H, W) = {frames.shape[1:]}", source=str(src))
        f = np.asarray(f, dtype=np.float32)
        if not np.all(np.isfinite(f)):
            raise InputError("fpn", "array with NaN/inf", "a finite fixed pattern", source=str(src))
        frames = (frames - f[None]).astype(np.float32)
    t0 = time.perf_counter()
    if args.method == "snapshot":
        if not 0 <= args.frame < T:
            raise InputError("--frame", args.frame, f"0 <= frame < {T}")
        a = None if alpha is None else alpha[args.frame:args.frame + 1]
        rec = reconstruct(frames[args.frame][None], a, method="snapshot", scale=scale,
                          foveal_gain=geo["foveal_gain"], foveal_offset=geo["foveal_offset"], **fpn_kw)
        if args.denoise:
            from metafovea.reconstruct import Reconstruction, denoise

            rec = Reconstruction(x1=denoise(rec.x1, args.denoise), x2=denoise(rec.x2, args.denoise),
                                 alpha=rec.alpha, fpn=rec.fpn, method=rec.method, timings=rec.timings,
                                 info={**rec.info, "denoise": args.denoise})
        n_out = 1
    else:
        method_kw: dict[str, Any] = {}
        if args.method == "alternating":
            method_kw = dict(geo)
            if args.no_strict:
                method_kw["strict"] = False
        elif args.method == "dip":
            method_kw = {"steps": args.steps, "channels": args.channels, "rng": args.seed, **geo}
        elif args.fpn == "prior":
            method_kw = dict(geo)  # for the FPN prior's foveal term
        if args.regularize is not None:
            if args.method != "lsq":
                raise InputError("--regularize", args.regularize, "only with --method lsq")
            reg = args.regularize.strip().lower()
            if reg != "difference":
                from metafovea.errors import as_float

                reg = as_float("--regularize", args.regularize)
                if reg < 0:
                    raise InputError("--regularize", args.regularize, "'difference' or a ridge weight >= 0")
            method_kw["regularize"] = reg
        if args.window > T:
            raise InputError("--window", args.window, f"2 <= window <= number of frames ({T})", source=str(src))
        if T > args.window:
            if args.fpn not in ("none", "file"):
                raise InputError("--fpn", args.fpn, "'none' or 'file' for multi-window sequences (estimate FPN on "
                                 "one window)")
            rec = video(frames, alpha, window=args.window, stride=args.stride, method=args.method,
                        denoise=args.denoise, progress=sys.stderr.isatty(), **method_kw)
        else:
            if args.denoise and args.method == "lsq":
                method_kw["denoise"] = args.denoise
            rec = reconstruct(frames, alpha, method=args.method, **method_kw, **fpn_kw)
            if args.denoise and args.method != "lsq":
                from metafovea.reconstruct import Reconstruction, denoise

                rec = Reconstruction(x1=denoise(rec.x1, args.denoise), x2=denoise(rec.x2, args.denoise),
                                     alpha=rec.alpha, fpn=rec.fpn, method=rec.method, timings=rec.timings,
                                     info=rec.info)
        n_out = rec.x1.shape[0] if rec.is_video else 1
    elapsed = time.perf_counter() - t0
    rec.save(out)
    files = [str(out)]
    x1_last = rec.x1[-1] if rec.is_video else rec.x1
    x2_last = rec.x2[-1] if rec.is_video else rec.x2
    if figures:
        for name, data in zip(figures, (_image_png(x1_last), _image_png(x2_last),
                                        _figure(x1_last, x2_last, f"{rec.method}: {src.name}"))):
            atomic_write_bytes(name, data)
            files.append(name)
    summary: dict[str, Any] = {"measurement": str(src), "method": rec.method, "frames": int(T),
                               "foveal_constraint": geo,
                               "outputs": int(n_out), "seconds": elapsed,
                               "ms_per_output": 1e3 * elapsed / max(n_out, 1),
                               "timings": rec.timings, "files": files}
    for key in ("condition", "alpha_identified", "iterations"):
        if key in rec.info:
            v = rec.info[key]
            summary[key] = (float(np.nanmax(np.asarray(v, dtype=float))) if isinstance(v, list) else v)
    if "gauge" in rec.info:
        summary["gauge"] = {k: rec.info["gauge"].get(k) for k in ("applied", "reason")}
    if "fpn" in rec.info:
        summary["fpn"] = rec.info["fpn"].get("identified")
    n_bad = int(np.sum(~np.isfinite(rec.x1)) + np.sum(~np.isfinite(rec.x2)))
    if n_bad:
        summary["nonfinite_pixels"] = n_bad
    if truths:
        finite = n_bad == 0
        if finite:
            # the truth each output shows: the mean over its window (video truth), or the snapshot's frame
            if args.method == "snapshot":
                spans = [(args.frame, args.frame + 1)]
            elif rec.is_video:
                w = int(rec.info.get("window", args.window))
                spans = [(int(s0), int(s0) + w) for s0 in rec.info["window_starts"]]
            else:
                spans = [(0, T)]

            def at(t: np.ndarray | None) -> np.ndarray | None:
                if t is None or t.ndim == 2:
                    return t
                per_output = np.stack([t[a:b].mean(axis=0) for a, b in spans])
                return per_output if rec.is_video else per_output[0]

            summary["metrics"] = score(rec, at(truths.get("truth_x1")), at(truths.get("truth_x2")))
        else:
            summary["metrics"] = "not computed: NaN pixels in the reconstruction"
    return summary


def _load(src: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """:func:`metafovea.io.load_npz` with every way a file can fail to be a Measurement as an InputError."""
    import zipfile
    import zlib

    from metafovea.io import load_npz

    try:
        arrays, meta = load_npz(src)
    except InputError:
        raise
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error, UnicodeDecodeError) as e:
        detail = " ".join(str(e).split())[:160] or type(e).__name__
        raise InputError("measurement", str(src), "a Measurement .npz (numpy arrays, JSON '__meta__')",
                         detail=detail) from None
    if not isinstance(meta, dict):
        raise InputError("__meta__", type(meta).__name__, "a JSON object (mapping)", source=str(src))
    return arrays, meta


def _check_truth(arrays: dict[str, np.ndarray], shape: tuple[int, ...], src: Path) -> dict[str, np.ndarray]:
    """The file's truth images, checked against the frames: (H, W) or (T, H, W), finite."""
    T, H, W = shape
    out = {}
    for key in ("truth_x1", "truth_x2"):
        if key not in arrays:
            continue
        t = arrays[key]
        if not (np.issubdtype(t.dtype, np.number) and not np.iscomplexobj(t)) or \
                t.shape not in ((H, W), (T, H, W)):
            raise InputError(key, f"array of shape {t.shape}, dtype {t.dtype}",
                             f"real values of shape (H, W) = {(H, W)} or (T, H, W) = {(T, H, W)}", source=str(src))
        if not np.all(np.isfinite(t)):
            raise InputError(key, "array with NaN/inf", "finite truth images", source=str(src))
        out[key] = np.asarray(t, dtype=np.float64)
    return out


def run(args: argparse.Namespace) -> int:
    """Run the subcommand; 0 on success, 2 on bad input (one-line message on stderr)."""
    try:
        s = _summary(args)
    except InputError as e:
        print(f"metafovea reconstruct: error: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(to_json(s))
    else:
        print(f"{s['method']}: {s['frames']} frames -> {s['outputs']} reconstruction(s) in {s['seconds']:.3f} s "
              f"({s['ms_per_output']:.3f} ms each)")
        if "condition" in s:
            print(f"  normal-matrix condition number: {s['condition']:.3g}")
        if "gauge" in s:
            print(f"  alpha gauge fixed by the foveal constraint: {s['gauge']['applied']} ({s['gauge']['reason']})")
        if s.get("nonfinite_pixels"):
            print(f"  {s['nonfinite_pixels']} NaN value(s) in x1/x2: pixels without valid samples (e.g. dead pixels)")
        if isinstance(s.get("metrics"), dict):
            print("  " + ", ".join(f"{k} {v:.4g}" for k, v in s["metrics"].items()))
        print("  wrote " + ", ".join(s["files"]))
    return 0


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry point (``python -m metafovea.cli_reconstruct``) until cli.py wires it in."""
    parser = argparse.ArgumentParser(prog="metafovea")
    sub = parser.add_subparsers(dest="command", required=True)
    add_parser(sub)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    return run(args)


if __name__ == "__main__":
    raise SystemExit(main())


def register(subparsers: Any) -> None:
    add_parser(subparsers)

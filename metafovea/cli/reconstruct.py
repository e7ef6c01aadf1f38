"""``metafovea reconstruct``: separate a Measurement file into foveal and perifoveal images.

``run(args)`` reads the file (:meth:`metafovea.measurement.Measurement.load`, which checks it), checks the outputs,
calls :func:`metafovea.reconstruct.reconstruct_measurement` (windows, FPN, denoising, scoring against the truth),
prints a summary (``--json``: JSON), writes the Reconstruction ``.npz`` and figures; exit 0, or 2 on bad input.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from metafovea.cli.flags import warnings_in_flags
from metafovea.cli.options import add_shared, only_with, seed_arg, show_progress
from metafovea.cli.output import out_file
from metafovea.cli.polarizer import polarizer_args, polarizer_lines
from metafovea.errors import InputError, as_float
from metafovea.io import to_json

HELP = "separate foveal and perifoveal images from a measurement (.npz)"


def register(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    from metafovea.reconstruct import DECONVOLUTION_METHODS, DEFAULT_DECONVOLUTION, DENOISERS, FAMILY_KINDS
    from metafovea.reconstruct.api import METHOD_CHOICES

    p = subparsers.add_parser("reconstruct", help=HELP, description=HELP)
    p.add_argument("measurement", help="Measurement .npz (frames, times_s, optional alpha / truth_x1 / truth_x2)")
    p.add_argument("--method", default="lsq", choices=METHOD_CHOICES, help="solver (default lsq; lsq needs the file's "
                   "alpha); auto: chosen from the file's alpha, the scene's motion and --time-s, saying why")
    p.add_argument("--time-s", type=float, default=None, help="--method auto: the time allowed (s; default no limit)")
    p.add_argument("--known-alpha", action="store_true", help="use the file's alpha (implied by lsq; dip: held fixed)")
    p.add_argument("--refine-alpha", action="store_true", help="lsq: alpha fitted from the frames, not the nominal one")
    p.add_argument("--window", type=int, default=None, help="frames per window (default 8; under 16 frames: all)")
    p.add_argument("--stride", type=int, default=1, help="window stride in frames (default 1)")
    p.add_argument("--denoise", default=None, choices=DENOISERS, help="denoise the outputs")
    p.add_argument("--fpn", default="auto", metavar="auto|none|prior|calibration|PATTERN",
                   help="fixed-pattern noise: auto (default: the file's shutter frames, else the blind estimate when "
                        "it declares a pattern (fpn_rank), else none; the summary says which), none, prior (blind), "
                        "calibration (the file's shutter frames) or a pattern file (.npy/.npz/.tif, subtracted)")
    p.add_argument("--scale", type=float, default=None, help="f1/f2 of the foveal constraint (default: file meta "
                   "'foveal_constraint.scale', else 'scale', else 6)")
    p.add_argument("--foveal-gain", type=float, default=None, help="radiometric gain of the foveal constraint "
                   "D x1 = gain C x2 + offset (default: file meta 'foveal_constraint.gain', else 1)")
    p.add_argument("--foveal-offset", type=float, default=None, help="offset of the foveal constraint, in the "
                   "frames' units (default: file meta 'foveal_constraint.offset_dn', else 0)")
    p.add_argument("--regularize", default=None, help="lsq: 'difference' (ridge on x1 - x2, the smallest that "
                   "meets the condition limit) or a ridge weight >= 0, for windows whose alpha barely varies")
    p.add_argument("--no-strict", action="store_true", help="alternating: when the foveal constraint cannot fix "
                   "alpha's gauge, the frame-mean-gauge result (alpha_identified: false), not an error")
    p.add_argument("--polarizer", default="auto", choices=("auto", "none"),
                   help="alternating: fix alpha's gauge with the polariser model (the file's keys, the flags "
                        "below, else the paper's free-running 2 Hz polariser: auto, default) or not (none: the "
                        "foveal constraint alone)")
    add_shared(p, "--polarizer-hz", "--polarizer-mode", "--polarizer-phase-deg", "--extinction", "--tau")
    p.add_argument("--polarizer-alpha", default="auto", choices=("auto", "model", "frames"),
                   help="alternating with the polariser model: alpha of the fitted constant-rate rotation (model), "
                        "each frame's own (frames: follows a jittering polariser), or auto (default: frames when the "
                        "rotation is irregular beyond the noise)")
    p.add_argument("--frame", type=int, default=None, help="--method snapshot's frame (default: alpha nearest 1/2)")
    p.add_argument("--steps", type=int, default=2000, help="DIP step budget: at most this many (default 2000)")
    p.add_argument("--channels", type=int, default=None, help="DIP network channels (default 16)")
    p.add_argument("--init", default="random", choices=("random", "classical"), help="DIP start: random (the "
                   "paper's, default) or classical (warm start from alternating, or LSQ + TV with --known-alpha)")
    p.add_argument("--max-seconds", type=float, default=None, help="DIP time budget of the whole run (default 600; "
                   "0: no cap); a window it stops keeps its lowest-loss images, and the summary says so")
    add_shared(p, "--seed")  # the DIP's weights and inputs
    p.add_argument("--deconvolve", nargs="?", const=DEFAULT_DECONVOLUTION, default=None, choices=DECONVOLUTION_METHODS,
                   help=f"also the scene (PSF-aware, static): <out>_scene.npz, .png in K ({DEFAULT_DECONVOLUTION})")
    p.add_argument("--psf", default=None, help="for --deconvolve: a PSF file (.npz: psf_x1, psf_x2) (not the file's)")
    p.add_argument("--refine-psf", choices=FAMILY_KINDS, help="for --deconvolve: refine the PSFs from the data")
    p.add_argument("--field-psf", default=None, choices=("auto", "patches", "on-axis"), help="for --deconvolve, a "
                   "field-dependent PSF (psf_patches_x*): the patches the data need (auto), every one, or none")
    p.add_argument("--out", default=None, help="output .npz (default: <measurement>_rec.npz); figures next to it")
    p.add_argument("--no-figures", action="store_true", help="do not write PNG figures")
    p.add_argument("--no-score", action="store_true", help="do not score against the file's truth (faster)")
    add_shared(p, "--json", "--force")
    p.set_defaults(func=run)
    return p


def _solver_options(args: argparse.Namespace) -> dict[str, Any]:
    """The method's own keywords from the flags that set them."""
    if args.stride < 1:
        raise InputError("--stride", args.stride, "an integer >= 1")
    only_with("--deconvolve", args.deconvolve is not None or args.method == "auto",  # auto may choose it
              {"--psf": args.psf, "--refine-psf": args.refine_psf, "--field-psf": args.field_psf})
    seed = seed_arg(args.seed)
    kw: dict[str, Any] = {}
    if args.regularize is not None:
        reg = args.regularize.strip().lower()
        if reg != "difference":
            reg = as_float("--regularize", args.regularize)
            if reg < 0:
                raise InputError("--regularize", args.regularize, "'difference' or a ridge weight >= 0")
        kw["regularize"] = reg
    if args.method in ("alternating", "auto"):  # auto: used if it chooses alternating
        kw.update(polarizer=args.polarizer, polarizer_alpha=args.polarizer_alpha, **({"strict": False}
                                                                                    if args.no_strict else {}))
    if args.max_seconds is not None and not args.max_seconds >= 0:  # a bad value is an error whatever the method
        raise InputError("--max-seconds", args.max_seconds, "a time budget in seconds >= 0 (0: no cap)")
    if args.method == "dip":
        kw.update(steps=args.steps, rng=seed, init=args.init, alpha_init="classical")
        kw.update({"channels": args.channels} if args.channels is not None else {})
        if args.max_seconds is not None:
            kw["max_seconds"] = args.max_seconds or None
    return kw


def _fpn_arg(v: str) -> Any:
    """A mode name as is; anything else is a pattern file, loaded."""
    from metafovea.reconstruct import FPN_MODES, files
    return v.strip().lower() if v.strip().lower() in (*FPN_MODES, "file") else files.load_pattern(v)


def run(args: argparse.Namespace) -> int:
    """Reconstruct, print the summary, write the outputs; 0 on success (an InputError is reported by main)."""
    from metafovea.measurement import FovealConstraint, Measurement
    from metafovea.reconstruct import auto_lines, reconstruct_measurement
    from metafovea.reconstruct.files import prepare_outputs, scene_paths, write_outputs, write_scene

    m = Measurement.load(args.measurement)
    solver = _solver_options(args)
    out, figures = prepare_outputs(m.source, out_file(args, None), figures=not args.no_figures, force=args.force)
    fc = FovealConstraint.from_meta(m.meta, scale=args.scale, gain=args.foveal_gain, offset=args.foveal_offset)
    res = reconstruct_measurement(m, args.method, known_alpha=args.known_alpha, window=args.window,
                                  stride=args.stride, fpn=_fpn_arg(args.fpn), denoise=args.denoise, frame=args.frame,
                                  constraint=fc, solver=solver, progress=show_progress(args),
                                  score_truth=not args.no_score, polarizer=polarizer_args(args),
                                  refine_alpha=args.refine_alpha, time_s=args.time_s,
                                  **({"deconvolve": args.deconvolve} if args.method == "auto" else {}))
    auto = res.reconstruction.info.get("auto")
    decon = auto["chose"]["deconvolve"] if auto else args.deconvolve  # what auto chose (or was given)
    scene_out = scene_paths(out, not args.no_figures, args.force) if decon else []  # before any file is written
    dec = None
    if decon:  # before any file is written: a PSF or option it refuses leaves nothing behind
        from metafovea.parallel import heartbeat
        from metafovea.reconstruct.deconvolve import deconvolve_result  # only here: a plain run starts faster

        with heartbeat(f"deconvolve ({decon})", enabled=show_progress(args)):  # field patches: tens of seconds
            dec = deconvolve_result(m, res, decon, args.psf, score_truth=not args.no_score,
                                    refine_psf=args.refine_psf, field_psf=args.field_psf or "auto")
    files = write_outputs(res, out, figures, title=f"{res.reconstruction.method}: {Path(m.source).name}",
                          units=m.meta.get("units") or "DN")
    files += write_scene(dec, scene_out) if dec is not None else []
    s = warnings_in_flags(res.summary(files) | ({"scene": dec.summary()} if dec is not None else {}), "reconstruct")
    if args.json:
        print(to_json(s))
        return 0
    print(f"{s['method']}: {s['frames']} frames -> {s['outputs']} reconstruction(s) in {s['seconds']:.3f} s "
          f"({s['ms_per_output']:.3f} ms each)\n" + "".join(f"  {line}\n" for line in auto_lines(auto, dec))
          + ("  frame {index}: {why}\n".format(**s["frame"]) if "frame" in s else ""), end="")
    if "condition" in s:
        print(f"  normal-matrix condition number: {s['condition']:.3g}")
    _print_dip(s.get("dip"), args)
    if "fpn_mode" in s:
        print(f"  fixed-pattern noise: {s['fpn_mode']}" + f", {s.get('fpn_auto')} (--fpn auto)" * ("fpn_auto" in s))
    if "alpha_gauge" in s:
        se, ig = s.get("alpha_se_max"), s.get("images_gauge_se")
        print(f"  alpha gauge: {s['alpha_gauge']}; identified: {s.get('alpha_identified')}"
              + (f" (standard error <= {se:.2g}, threshold {s.get('alpha_se_threshold', 5e-3):.2g})" if se else "")
              + (f"\n  what alpha's gauge leaves uncertain in the images: +- {ig[0]:.3g} (x1), +- {ig[1]:.3g} (x2) "
                 "rms, the frames' units (one standard error)" if ig else ""))
    ng = s.get("noise_gain")
    if ng and max(ng) > 10:
        print(f"  warning: noise amplified {ng[0]:.3g} x in x1, {ng[1]:.3g} x in x2 (alpha barely varies, or one "
              "channel is barely passed, in this window)")
    if s.get("invalid_samples"):
        iv = s["invalid_samples"]
        print(f"  {iv['count']:,} samples ({100 * iv['fraction']:.2g} %) {iv['how']}: outside the ADC range "
              f"{iv['valid_range_dn']} DN, non-finite, on the file's {iv.get('bad_pixel_map', 0)} bad pixel(s) or "
              f"on {iv.get('stuck_pixels', 0)} stuck (dead or saturated) pixel(s) found")
    if (s.get("polarizer") or {}).get("model"):
        print(polarizer_lines(s["polarizer"]["model"], s.get("calibration")))
    print("".join(f"  warning: {w}\n" for w in s.get("warnings") or []), end="")  # polariser, calibration, ...
    if s.get("nonfinite_pixels"):
        print(f"  {s['nonfinite_pixels']} NaN value(s) in x1/x2: pixels without valid samples (e.g. dead pixels)")
    if isinstance(s.get("metrics"), dict):
        print("  " + ", ".join(f"{k} {v:.4g}" for k, v in s["metrics"].items()))
    print("".join(f"  {line}\n" for line in (dec.lines() if dec is not None else [])), end="")
    print("  wrote " + ", ".join(s["files"]))
    return 0


def _print_dip(d: dict[str, Any] | None, args: argparse.Namespace) -> None:
    """The DIP's stopping: one line, a warning when the time cap stopped a window."""
    if not d:
        return
    how = ", ".join(f"{n} by {why}" for why, n in d["stopped"].items())
    line = (f"  dip: {d['windows']} window(s), {d['steps_run_mean']:.0f} of {d['steps']} steps on average "
            f"(stopped: {how})")
    if d["stopped"].get("time") or d["windows"] < d["windows_planned"]:
        short = d["windows"] < d["windows_planned"]
        done = f"after {d['windows']} of {d['windows_planned']} windows (the output holds those), " if short else ""
        line += (f"\n  warning: the time cap (--max-seconds {d['max_seconds']:g}) stopped the run {done}"
                 f"{d['stopped'].get('time', 0)} window(s) before their steps were done (each keeps its lowest-loss "
                 f"images; the first step took {d['first_step_seconds']:.3g} s: it compiles a new shape's network); "
                 "--max-seconds 0 for no cap, or fewer windows (--window, --stride)")
    print(line)

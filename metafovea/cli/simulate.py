"""``metafovea simulate``: simulate camera frames of a scene through a system design.

Writes a Measurement ``.npz`` (see docs/measurement_format.md), a TIFF stack (``<out>.tif``) and a
preview PNG (``<out>_preview.png``); nothing is overwritten without ``--force``, and never the system or scene
file the run reads. The run is :func:`metafovea.imaging.simulate.simulate_to_files`.

Exit status: 0 on success, 2 on bad input (one line naming the option).
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from metafovea.cli.options import add_shared, alias, seed_arg, show_progress
from metafovea.cli.output import out_file
from metafovea.errors import InputError, as_float, check_int
from metafovea.io import to_json

if TYPE_CHECKING:
    from metafovea.imaging.simulate import SimulationOptions


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "simulate", help="simulate polariser-multiplexed camera frames of a scene",
        description="Simulate frames of a scene (temperatures in K) through the two-channel system: Planck "
                    "band radiance, PSFs and haze, rotating polariser, microbolometer noise, FPN and 14-bit ADC. "
                    "Writes a Measurement .npz, a TIFF stack and a preview PNG.")
    p.add_argument("system_file", nargs="?", help="system TOML (default: the built-in paper prototype)")
    add_shared(p, "--scene", "--scene-unit")
    p.add_argument("--list-scenes", action="store_true", help="list the built-in scenes and exit")
    add_shared(p, "--frames", "--seed")
    p.add_argument("--out", default=None, help="Measurement file (default meas.npz)")
    add_shared(p, "--force", "--json")
    p.add_argument("--no-tiff", action="store_true", help="do not write the TIFF stack")
    p.add_argument("--no-preview", action="store_true", help="do not write the preview PNG")
    g = p.add_argument_group("optics")
    g.add_argument("--psf", default="auto",
                   help="auto (metafovea.optics if available, else airy), optics, airy, gaussian:SIGMA_UM")
    g.add_argument("--psf-cache",
                   help="PSF cache directory (default $METAFOVEA_CACHE/psf, i.e. ~/.cache/metafovea/psf)")
    g.add_argument("--psf-size", help="PSF window in samples (odd, at most 1025; default 6 x supersample + 1)")
    g.add_argument("--field-patches", default="1", help="1 (shift-invariant), N (N x N patches) or auto")
    g.add_argument("--filter", nargs="?", const="on", default=None, choices=("on", "off"),
                   help="the system's narrow-band filter: on (also a bare --filter) or off (the whole band, with "
                        "haze); default: the system file's spectral.filter_enabled")
    alias(g, "--no-filter", "--filter off", "filter", const="off")
    g.add_argument("--no-haze", action="store_true", help="drop the chromatic haze (power outside the PSF window)")
    g.add_argument("--supersample", help="samples per pixel per axis (default 3 static, 2 video scenes)")
    add_shared(g, "--relay", "--posts")
    g.add_argument("--no-train", action="store_true",
                   help="each lens alone: no wafers, other lens or aperture ring (a simplified model)")
    s = p.add_argument_group("polariser and sensor")
    s.add_argument("--polarizer", default="sync", choices=("sync", "free"),
                   help="sync: locked to the frames, known phase; free: running with an unknown random phase")
    s.add_argument("--phase-deg", help="polariser phase at t = 0 (degrees; sync default 17.19 = 0.3 rad)")
    add_shared(s, "--extinction", "--tau")
    add_shared(s, "--pixel-um")
    alias(s, "--pitch", "--pixel-um", "pixel_um")
    s.add_argument("--netd", help="NETD in K at 300 K through the F/1 channel (default from the system)")
    s.add_argument("--fpn-rank", help="rank of the fixed-pattern noise (default from the system)")
    s.add_argument("--fpn-amplitude", help="max |FPN| as a fraction of the dynamic range (default from the system)")
    s.add_argument("--drift", default="0", help="relative slow drift of the FPN weights (default 0)")
    s.add_argument("--calibration-frames", default=None,
                   help="closed-shutter frames (same FPN and noise) stored as 'calibration', which reconstruct "
                        "uses for the fixed-pattern noise (default 16; 0: none)")
    s.add_argument("--no-noise", action="store_true", help="no temporal noise")
    s.add_argument("--no-fpn", action="store_true", help="no fixed-pattern noise")
    s.add_argument("--no-quantize", action="store_true", help="no ADC rounding/clipping")
    b = p.add_argument_group("error budget")
    b.add_argument("--tolerance-k", default=None,
                   help="accuracy asked, K rms of the sensor image referred to the scene (0 < T <= 100): a planner "
                        "replaces the effects that fit the budget by cheaper ones (a REDUCED model) and prints its "
                        "plan; default: the full model")
    p.set_defaults(func=run)
    return p


def _num(name: str, v: Any) -> float | None:
    return None if v is None else as_float(name, v)


def _odd(name: str, v: Any, hi: int) -> int:
    n = check_int(name, v, 1, hi)
    if n % 2 == 0:
        raise InputError(name, v, f"an odd integer 1 <= {name} <= {hi} (the PSF's centre is a sample)")
    return n


def _options(args: argparse.Namespace, frames: int) -> SimulationOptions:
    """The flags as :class:`~metafovea.imaging.simulate.SimulationOptions`, each checked under its flag."""
    from metafovea.imaging.kernels import MAX_PSF_SIZE
    from metafovea.imaging.plan import check_tolerance
    from metafovea.imaging.simulate import CALIBRATION_FRAMES, SimulationOptions

    fp = args.field_patches
    fp = "auto" if str(fp).strip().lower() == "auto" else check_int("--field-patches", fp, 1, 9)
    return SimulationOptions(
        frames=frames,
        supersample=None if args.supersample is None else check_int("--supersample", args.supersample, 1, 8),
        psf=args.psf, psf_cache_dir=args.psf_cache,
        psf_size_px=None if args.psf_size is None else _odd("--psf-size", args.psf_size, MAX_PSF_SIZE),
        field_patches=fp, haze=not args.no_haze, filter_enabled=None if args.filter is None else args.filter == "on",
        pixel_pitch_um=_num("--pixel-um", args.pixel_um), relay_magnification=_num("--relay", args.relay),
        polarizer_mode=args.polarizer, polarizer_phase_deg=_num("--phase-deg", args.phase_deg),
        extinction=_num("--extinction", args.extinction),
        bolometer_tau_s=_num("--tau", "0" if args.tau is None else args.tau),
        netd_k=_num("--netd", args.netd),
        fpn_rank=0 if args.no_fpn else (None if args.fpn_rank is None else
                                        check_int("--fpn-rank", args.fpn_rank, 0, 10000)),
        fpn_amplitude=_num("--fpn-amplitude", args.fpn_amplitude), fpn_drift=_num("--drift", args.drift),
        noise=not args.no_noise, quantize=not args.no_quantize, progress=show_progress(args),
        posts=args.posts, optical_train=not args.no_train, scene_unit=args.scene_unit,
        calibration_frames=CALIBRATION_FRAMES if args.calibration_frames is None else
        check_int("--calibration-frames", args.calibration_frames, 0, 10000),
        tolerance_k=None if args.tolerance_k is None else check_tolerance(args.tolerance_k))


def _print_scenes(as_json: bool) -> None:
    from metafovea.imaging.scene import list_scene_families, list_scenes

    scenes = list_scenes()
    if as_json:
        print(to_json(scenes))
    else:
        for k, v in {**scenes, "skimage:NAME": "a scikit-image picture, 288-312 K", **list_scene_families()}.items():
            print(f"{k:14s} {v}")


def run(args: argparse.Namespace) -> int:
    from metafovea.imaging.plan import plan_lines
    from metafovea.imaging.scene import make_scene
    from metafovea.imaging.simulate import simulate_to_files
    from metafovea.optics.train import throughput_lines

    if getattr(args, "list_scenes", False):
        _print_scenes(args.json)
        return 0
    frames = check_int("--frames", args.frames, 1, 100_000)
    seed = seed_arg(args.seed)
    opts = _options(args, frames)
    make_scene(args.scene, scene_unit=opts.scene_unit)  # a bad --scene is reported before the camera's posts
    result = simulate_to_files(args.system_file, args.scene, out_file(args, "meas.npz"), opts, rng=seed,
                               force=args.force, tiff=not args.no_tiff, preview=not args.no_preview)
    summary = result.summary()
    if args.json:
        print(to_json(summary))
    else:
        T, H, W = result.measurement.shape
        if "plan" in summary:
            print("\n".join(plan_lines(summary["plan"])))
        print(f"scene {summary['scene']}: {T} frames {H}x{W} ({summary['units']}), "
              f"alpha {summary.get('alpha_range', 'unknown')}, PSF {summary['psf']} {summary['psf_mode']}")
        fld = summary.get("psf_field", {})
        if fld:
            same = fld["foveal"] == fld["perifoveal"]
            print("field dependence of the PSFs: " + (fld["foveal"] if same else "; ".join(
                f"{c} {v}" for c, v in fld.items())))
        if "scene_conversion" in summary:
            print(f"scene values: {summary['scene_conversion']}")
        print(f"haze fraction foveal {summary['haze_fraction']['foveal']:.3f}, "
              f"perifoveal {summary['haze_fraction']['perifoveal']:.3f}; "
              f"simulated in {result.seconds['simulate']:.2f} s, total {result.seconds['total']:.2f} s")
        for c, r in summary.get("psf_request", {}).items():
            print(f"{c} PSF kernels: the recording asks for {r['error']:g} of the peak (the engines for "
                  f"{r['engine_error']:g}): {r['why']}"
                  + (f"; estimate {result.measurement.meta['psf'][c]['error_estimate']:.2g} of the peak: pixel "
                     f"change <= {r['bound_k']:.2g} K, {'within' if r['met'] else 'OVER'} the {r['allowed_k']:.2g} K "
                     "allowed" if "bound_k" in r else ""))
        train = result.measurement.meta["optical_train"]
        print("\n".join(throughput_lines(train)) if isinstance(train, list) else f"optical train {train['note']}")
        for k, v in summary["files"].items():
            print(f"  {k}: {v}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    add_parser(subparsers)

"""Command-line interface: one thin module per command over the library functions.

``metafovea COMMAND ...``: every command module (``design``, ``library``, ``layout`` (export, verify), ``psf``,
``simulate``, ``reconstruct``, ``validate``) has ``register(subparsers)``, which adds its parser(s) with
``set_defaults(func=run)``; ``run(args)`` parses the values, calls one library function, prints a summary (or
JSON with ``--json``) and writes files.

Exit status: 0 on success; 1 when a check fails (``verify``); 2 on bad input, printed as one line that names the
flag the user typed (a library parameter is mapped to its flag here, in :data:`PARAMETER_FLAGS`, the one place
that knows both names); 130 on Ctrl-C.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
import warnings
from collections.abc import Sequence

from metafovea import __version__
from metafovea.cli.stop import install_stop_handlers
from metafovea.errors import InputError

log = logging.getLogger("metafovea")

#: command modules under ``metafovea.cli``, in the order ``--help`` lists them
COMMAND_MODULES = ("validate", "design", "library", "layout", "psf", "simulate", "import_", "reconstruct", "study")

#: library parameter name -> the flag a user typed, per command (an InputError raised deep in a stage names the
#: parameter; the CLI reports the flag, and the flags of the parameters a message mentions, :func:`as_flag_error`).
#: :data:`EVERY_COMMAND`: the ground floor's parameters, which every command shares.
EVERY_COMMAND = {"out": "--out", "force": "--force", "scheduler": "--scheduler"}
_LAYOUT = {"band_rows": "--band-rows", "grid_nm": "--grid-nm", "ring_width_um": "--ring-width-um", "block": "--block",
           "patch_mm": "--patch", "levels": "--levels", "post_set": "--post-set", "posts": "--posts", "date": "--date",
           "workers": "--workers", "substrate_thickness_um": "--substrate-um", "max_refs": "--max-refs", "dwl": "--dwl",
           "compress": "--compress", "fmt": "--format", "path": "--out", "flat": "--flat", "test_array": "--test-array",
           "tiles_dir": "--tiles-dir", "reader": "--reader"}
PARAMETER_FLAGS: dict[str, dict[str, str]] = {
    "design": {"post_set": "--post-set", "from_library": "--library", "samples": "--samples", "f_um": "--f",
               "diameter_um": "--d", "period_um": "--period-um", "wavelength_um": "--wavelength-um"},
    "library": {"grid_step_um": "--grid-step-um", "levels": "--levels", "harmonics": "--harmonics",
                "wavelengths_um": "--wavelengths-um", "workers": "--workers", "tol": "--tol"},
    "export": _LAYOUT, "verify": _LAYOUT,
    "psf": {"band_um": "--band-um", "filter_um": "--filter-um", "pixel_pitch_um": "--pixel-um",
            "field_deg": "--field-deg", "fields_deg": "--field-deg", "error": "--error",
            "temperature_k": "--temperature-k", "n_wavelengths": "--wavelength-bins",
            "wavelength_um": "--wavelength-um",
            "window_um": "--window-um", "relay_magnification": "--relay", "jobs": "--workers"},
    "reconstruct": {"window": "--window", "frame": "--frame", "fpn": "--fpn", "known_alpha": "--known-alpha",
                    "regularize": "--regularize", "steps": "--steps", "channels": "--channels", "stride": "--stride",
                    "max_seconds": "--max-seconds", "seed": "--seed", "rng": "--seed", "scale": "--scale",
                    "gain": "--foveal-gain", "offset": "--foveal-offset", "denoise": "--denoise"},
    "simulate": {"extinction": "--extinction", "tau_s": "--tau", "bolometer_tau_s": "--tau", "fpn_drift": "--drift",
                 "netd_k": "--netd", "frames": "--frames", "calibration_frames": "--calibration-frames",
                 "supersample": "--supersample", "psf_size_px": "--psf-size", "scene": "--scene",
                 "pixel_pitch_um": "--pixel-um", "psf gaussian sigma_um": "--psf", "psf": "--psf",
                 "relay_magnification": "--relay", "fpn_rank": "--fpn-rank", "fpn_amplitude": "--fpn-amplitude",
                 "polarizer_phase_deg": "--phase-deg", "field_patches": "--field-patches", "rng": "--seed",
                 "out (TIFF)": "--out (TIFF)", "out (preview)": "--out (preview)"},
    "validate": {"frames": "--frames", "seed": "--seed", "rng": "--seed", "scene": "--scene",
                 "dip_steps": "--dip-steps"},
    "import": {"format": "--format", "frames_key": "--frames-key", "frame_axis": "--frame-axis", "times": "--times",
               "time_unit": "--time-unit", "frame_rate_hz": "--frame-rate", "polarizer_key": "--polarizer-key",
               "polarizer_unit": "--polarizer-unit", "calibration": "--calibration", "planck": "--planck",
               "calibration_gain": "--calibration-gain", "band_um": "--band-um", "filter_um": "--filter-um",
               "foveal_gain": "--foveal-gain", "scale": "--scale"},
}

#: library parameters that are a key of a file the user named, per command: parameter -> the option (or
#: positional argument's dest) holding that file; the error then names the file (``--scene hot.npy: ...``)
FILE_KEYS: dict[str, dict[str, str]] = {
    "simulate": {"temperature_k": "scene", "emissivity": "scene", "image": "scene"},
}


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump) and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        sys.stderr.write(f"{self.prog}: error: {message} (see --help)\n")
        raise SystemExit(2)


def flag_map(command: str) -> dict[str, str]:
    """Parameter -> flag for ``command``: its :data:`PARAMETER_FLAGS` over :data:`EVERY_COMMAND`."""
    return {**EVERY_COMMAND, **PARAMETER_FLAGS.get(command, {})}


def as_flag_error(command: str, err: InputError, args: argparse.Namespace | None = None) -> InputError:
    """``err`` renamed to the flag of ``command`` that sets its parameter, or (:data:`FILE_KEYS`) placed in the
    file the user gave; unchanged when there is none, or when the error already names a file's key. Parameters
    its range and detail mention are written as flags too (:func:`~metafovea.cli.options.in_flags`)."""
    if err.source is not None:
        return err
    dest = FILE_KEYS.get(command, {}).get(err.parameter)
    if dest is not None and args is not None and getattr(args, dest, None) is not None:
        return err.located(f"--{dest.replace('_', '-')} {getattr(args, dest)}")
    from metafovea.cli.options import in_flags

    flags = flag_map(command)
    err = err.renamed(flags[err.parameter]) if err.parameter in flags else err
    err = InputError(err.parameter, err.value, in_flags(err.allowed, flags), source=err.source,
                     detail=None if err.detail is None else in_flags(err.detail, flags))
    typed = {new: old for old, new in getattr(args, "deprecated_options", [])}  # the spelling the user typed
    return err.renamed(typed[err.parameter]) if err.parameter in typed else err


#: each command's module (``layout`` holds two): :func:`build_parser` imports only the one a command line names
COMMANDS = {"validate": "validate", "design": "design", "library": "library", "export": "layout", "verify": "layout",
            "psf": "psf", "simulate": "simulate", "import": "import_", "reconstruct": "reconstruct", "study": "study"}


def _command_in(argv: Sequence[str] | None) -> str | None:
    """The command a command line names: its first word that is not an option (the global options take no value)."""
    for tok in argv or ():
        if not tok.startswith("-"):
            return tok if tok in COMMANDS else None
    return None


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The ``metafovea`` parser: every command's, or with ``argv`` naming a command only that command's (its
    module alone is imported: a command line's start-up without the other commands' imports, e.g. ~0.1 s of the
    RCWA, recordings and study modules for ``reconstruct``)."""
    from metafovea.cli.options import add_common, iter_subparsers

    parser = Parser(prog="metafovea", description="Polarisation-multiplexed foveated meta-optics for LWIR cameras. "
                                                  "Lengths in um (lens f and D in mm), angles in degrees at the CLI; "
                                                  "README.md, 'Command-line options', has every option.")
    parser.add_argument("--version", action="version", version=f"metafovea {__version__}")
    parser.add_argument("-v", "--verbose", dest="global_verbose", action="count", default=0, help="more log output")
    parser.add_argument("-q", "--quiet", dest="global_quiet", action="store_true", help="no progress bars")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    only = _command_in(argv)
    for name in COMMAND_MODULES if only is None else (COMMANDS[only],):
        importlib.import_module(f"metafovea.cli.{name}").register(sub)
    for _, p in iter_subparsers(parser):
        add_common(p)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``metafovea`` with ``argv`` (default ``sys.argv[1:]``); returns the exit status."""
    from metafovea.cli.options import warning_printer

    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    args.quiet = bool(getattr(args, "quiet", False) or args.global_quiet)
    args.verbose = int(getattr(args, "verbose", 0) or 0) + args.global_verbose
    logging.basicConfig(format="%(levelname)s %(name)s: %(message)s")  # a handler, once per process
    log.setLevel(logging.WARNING - 10 * min(args.verbose, 2))  # each run its own level
    with warnings.catch_warnings():
        # every warning once, on one line, under the command's name (a warnings.showwarning hook)
        warnings.showwarning = warning_printer(args.command)
        for old, new in getattr(args, "deprecated_options", []):
            log.info("%s is a deprecated spelling: use %s", old, new)
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    try:
        rc = args.func(args)
    except InputError as e:
        sys.stderr.write(f"metafovea {args.command}: error: {as_flag_error(args.command, e, args)}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("interrupted\n")
        return 130
    except BrokenPipeError:
        return 0
    except OSError as e:
        sys.stderr.write(f"metafovea {args.command}: error: {e.strerror or e}: {getattr(e, 'filename', '') or ''}\n")
        return 2
    return int(rc or 0)


def console_main() -> int:
    """The ``metafovea`` command: :func:`main` with SIGINT and SIGTERM both stopping the run (exit 130, the
    resumable state kept, :func:`install_stop_handlers`)."""
    install_stop_handlers()
    rc = main()
    if rc == 130 and "jax" in sys.modules:
        # an interrupted JAX computation leaves XLA's threads mid-flight: interpreter finalisation then crashes
        # (SIGSEGV); everything worth keeping is written and cleaned up by now, so leave without it
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130)
    return rc


if __name__ == "__main__":
    raise SystemExit(console_main())

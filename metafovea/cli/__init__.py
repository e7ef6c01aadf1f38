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
import sys
import warnings
from typing import Sequence

from metafovea import __version__
from metafovea.errors import InputError

log = logging.getLogger("metafovea")

#: command modules under ``metafovea.cli``, in the order ``--help`` lists them
COMMAND_MODULES = ("validate", "design", "library", "layout", "psf", "simulate", "reconstruct")

#: library parameter name -> the flag a user typed, per command (an InputError raised deep in a stage names the
#: parameter; the CLI reports the flag). Only names that differ from their flag need an entry.
PARAMETER_FLAGS: dict[str, dict[str, str]] = {
    "design": {"post_set": "--post-set", "from_library": "--library"},
    "library": {"grid_step_um": "--grid-step-um", "levels": "--levels"},
    "psf": {"band_um": "--band-um", "filter_um": "--filter-um", "pixel_pitch_um": "--pixel-um",
            "field_deg": "--field-deg", "error": "--error", "temperature_k": "--temperature-k",
            "n_wavelengths": "--wavelengths", "wavelength_um": "--wavelength-um", "window_um": "--window-um",
            "relay_magnification": "--relay"},
    "reconstruct": {"window": "--window", "frame": "--frame", "fpn": "--fpn", "known_alpha": "--known-alpha",
                    "regularize": "--regularize", "steps": "--steps", "channels": "--channels"},
    "simulate": {"extinction": "--extinction", "tau_s": "--tau", "fpn_drift": "--drift", "netd_k": "--netd"},
}


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump) and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        sys.stderr.write(f"{self.prog}: error: {message} (see --help)\n")
        raise SystemExit(2)


def as_flag_error(command: str, err: InputError) -> InputError:
    """``err`` renamed to the flag of ``command`` that sets its parameter (unchanged when there is none, or when
    the error names a file's key)."""
    flag = PARAMETER_FLAGS.get(command, {}).get(err.parameter)
    return err.renamed(flag) if flag and err.source is None else err


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="metafovea", description="Polarisation-multiplexed foveated meta-optics for LWIR cameras. "
                                                  "Lengths in um (lens f and D in mm), angles in degrees at the CLI.")
    parser.add_argument("--version", action="version", version=f"metafovea {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for name in COMMAND_MODULES:
        importlib.import_module(f"metafovea.cli.{name}").register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``metafovea`` with ``argv`` (default ``sys.argv[1:]``); returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2), format="%(levelname)s %(name)s: %(message)s")
    # warnings as one line each ("Category: message"), without Python's source line
    warnings.formatwarning = lambda m, c, f, n, line=None: f"{c.__name__}: {m}\n"
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    try:
        rc = args.func(args)
    except InputError as e:
        sys.stderr.write(f"metafovea {args.command}: error: {as_flag_error(args.command, e)}\n")
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


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def console_main() -> int:
    """The ``metafovea`` command: :func:`main` with SIGINT and SIGTERM both stopping the run (exit 130, the
    resumable state kept), also when the shell started it with SIGINT ignored (a background job)."""
    import signal

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _interrupt)
    return main()


if __name__ == "__main__":
    raise SystemExit(console_main())

"""Command-line interface: one thin module per command over the library functions.

``metafovea COMMAND ...``: every command module (``design``, ``library``, ``layout`` (export, verify), ``psf``,
``simulate``, ``reconstruct``, ``validate``, ``study``, ``bench``) has ``register(subparsers)``, which adds its
parser(s) with ``set_defaults(func=run)``; ``run(args)`` parses the values, calls one library function, prints a
summary (or JSON with ``--json``) and writes files.

Exit status: 0 on success; 1 when a check fails (``verify``); 2 on bad input, printed as one line that names the
flag the user typed (a library parameter is mapped to its flag in :mod:`metafovea.cli.flags`, the one place
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
from metafovea.cli.flags import as_flag_error, flag_map
from metafovea.cli.stop import install_stop_handlers
from metafovea.errors import InputError

log = logging.getLogger("metafovea")

#: command modules under ``metafovea.cli``, in the order ``--help`` lists them
COMMAND_MODULES = ("validate", "design", "library", "layout", "psf", "simulate", "import_", "reconstruct", "codesign",
                   "study", "bench")

class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump) and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        sys.stderr.write(f"{self.prog}: error: {message} (see --help)\n")
        raise SystemExit(2)


#: each command's module (``layout`` holds two): :func:`build_parser` imports only the one a command line names
COMMANDS = {"validate": "validate", "design": "design", "library": "library", "export": "layout", "verify": "layout",
            "psf": "psf", "simulate": "simulate", "import": "import_", "reconstruct": "reconstruct",
            "codesign": "codesign", "study": "study", "bench": "bench"}


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
        # every warning once, on one line, under the command's name (a warnings.showwarning hook); the results
        # that missed their requested error as one line at the end, naming this command's options
        show = warning_printer(args.command, flags=flag_map(args.command))
        warnings.showwarning = show
        for old, new in getattr(args, "deprecated_options", []):
            log.info("%s is a deprecated spelling: use %s", old, new)
        try:
            rc = _run(args)
        except BaseException:
            show.flush()
            raise
        if rc != 130:  # a stopped run says 'interrupted' and nothing more: it dropped the results the summary is about
            show.flush()
        return rc


def _masks_a_stop(e: BaseException) -> bool:
    """Whether ``e`` was raised while a stop (KeyboardInterrupt) was being handled: a library's cleanup that fails
    when the signal lands mid-write (``zipfile`` closing with a writing handle open raises a ValueError, seen in CI)
    replaces the stop with its own error; the stop is what happened."""
    seen = set()
    c: BaseException | None = e
    while c is not None and id(c) not in seen:
        if isinstance(c, KeyboardInterrupt):
            return True
        seen.add(id(c))
        c = c.__cause__ or c.__context__
    return False


def _interrupted() -> int:
    from metafovea import stopping

    stopping.clear()  # handled: the request does not outlive this command (tests run several in one process)
    sys.stderr.write("interrupted\n")
    return 130


def _run(args: argparse.Namespace) -> int:
    try:
        if getattr(args, "scheduler", None) is not None:  # every command's --scheduler, before its first work
            from metafovea.cli.options import scheduler_arg

            args.scheduler = scheduler_arg(args.scheduler)
        rc = args.func(args)
    except InputError as e:
        sys.stderr.write(f"metafovea {args.command}: error: {as_flag_error(args.command, e, args)}\n")
        return 2
    except KeyboardInterrupt:
        return _interrupted()
    except BrokenPipeError:
        return 0
    except Exception as e:
        if _masks_a_stop(e):
            return _interrupted()
        if not isinstance(e, OSError):
            raise
        sys.stderr.write(f"metafovea {args.command}: error: {e.strerror or e}: {getattr(e, 'filename', '') or ''}\n")
        return 2
    return int(rc or 0)


#: seconds a stopped command waits for its other threads (a process pool's manager, ...) before it leaves without them
STOP_GRACE_S = 5.0


def _threads_left(grace_s: float) -> bool:
    """Whether a thread other than the main one that interpreter exit would wait for is still running ``grace_s``
    after a stop. A process pool whose worker died as the stop arrived (a SIGTERM to the whole process group) left
    its manager thread joining a queue-feeder thread blocked on a full pipe (CPython gh-94777; seen once, on
    ``metafovea study ablation`` under ``timeout``): the command had said 'interrupted' and never exited."""
    import threading
    import time

    deadline = time.monotonic() + grace_s
    others = [t for t in threading.enumerate() if t is not threading.main_thread() and not t.daemon]
    try:
        for t in others:
            t.join(max(0.0, deadline - time.monotonic()))
    except KeyboardInterrupt:  # a second stop: leave now
        return True
    return any(t.is_alive() for t in others)


def console_main() -> int:
    """The ``metafovea`` command: :func:`main` with SIGINT and SIGTERM both stopping the run (exit 130, the
    resumable state kept, :func:`install_stop_handlers`)."""
    install_stop_handlers()
    rc = main()
    if rc == 130 and ("jax" in sys.modules or _threads_left(STOP_GRACE_S)):
        # an interrupted JAX computation leaves XLA's threads mid-flight: interpreter finalisation then crashes
        # (SIGSEGV); a thread that does not end would hold the exit for ever; everything worth keeping is written
        # and cleaned up by now (the stop unwound every task), so leave without them
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130)
    return rc


if __name__ == "__main__":
    raise SystemExit(console_main())

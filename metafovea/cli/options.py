"""What every command shares: ``-q/--quiet`` and ``-v/--verbose``, the options several commands take (one default
and one help text each: :data:`SHARED_OPTIONS`, :func:`add_shared`), hidden deprecated spellings of renamed
options, whether to show progress, the one-line warning printer, and the check of an ``--out`` file's suffix
(default outputs and progress lines: :mod:`metafovea.cli.output`).

The vocabulary (one name, unit and meaning per option across commands) is the table "Command-line options" in
README.md; an option renamed to fit it keeps its old spelling as a hidden alias that still works (``-v`` says
what to type instead).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from metafovea.errors import InputError, NotConvergedWarning

#: the options that several commands take: one default and one help text each, whichever command it is (values
#: stay strings here; each command checks them under the flag, e.g. :func:`workers_arg`, :func:`seed_arg`)
SHARED_OPTIONS: dict[str, dict[str, Any]] = {
    "--workers": dict(default=None, metavar="N",
                      help="local workers (default: one per core, never more than the work needs; 1 runs in this "
                           "process)"),
    "--scheduler": dict(default=None, metavar="ADDRESS",
                        help="a Dask scheduler to run the work on: tcp://host:8786, or local:N for N local worker "
                             "processes (pip install 'metafovea[dask]'; docs/scale.md)"),
    "--seed": dict(default="0", help="random seed, an integer >= 0 (default 0): the same seed gives the same result"),
    "--force": dict(action="store_true", help="overwrite existing output (never an input)"),
    "--json": dict(action="store_true", help="print the result as JSON instead of a summary"),
    "--frames": dict(default="96", help="frames to simulate (default 96: 8 s at 12 frames/s)"),
    "--scene": dict(default="siemens-star", help="the scene: a built-in name (metafovea simulate --list-scenes; "
                                                 "default siemens-star), skimage:NAME, gen:KIND:SEED (a generated "
                                                 "held-out scene), or a file (.npy/.npz in kelvin, .tif, .png)"),
    "--scene-unit": dict(default="kelvin", choices=("kelvin", "celsius"),
                         help="the unit of a --scene file of temperatures (.npy, .npz, float TIFF): kelvin (default; a "
                              "file whose hottest value is below 200 K is refused) or celsius (+273.15 K, stated in "
                              "the output)"),
    "--pixel-um": dict(default=None, help="sensor pixel pitch in um (default: the system's, 17 um in the paper's "
                                          "camera)"),
    "--relay": dict(default=None, help="relay magnification between the focal plane and the sensor (default: the "
                                       "system's, 0.5 in the paper's camera)"),
    "--posts": dict(default="rcwa", choices=("rcwa", "ideal"),
                    help="the lenses' posts: rcwa (the platform's RCWA post set, the fabricated lens; the default "
                         "platform's library ships with metafovea, another is computed on first use and cached; "
                         "default) or ideal (an idealised, simplified model, named as such in the output)"),
    # the rotating polariser, in the recording schema's words (simulate: the camera simulated; import: written to
    # the file; reconstruct: instead of the file's)
    "--polarizer-hz": dict(default=None, metavar="HZ", help="polariser revolutions per second (default: the "
                           "file's, else the paper's 2, said in the output)"),
    "--polarizer-mode": dict(default=None, choices=("free", "sync"), help="free: free-running, its phase fitted from "
                             "the frames; sync: locked to the frames at --polarizer-phase-deg (default: the file's, "
                             "else free)"),
    "--polarizer-phase-deg": dict(default=None, metavar="DEG", help="sync: the polariser's angle at t = 0, degrees"),
    "--extinction": dict(default=None, help="the polariser's leaked fraction of the blocked polarisation, 0 to 0.5 "
                                            "(default: the file's or the system's, else 0)"),
    "--tau": dict(default=None, metavar="SECONDS", help="the bolometer's time constant in s, 0 to 10 (it low-passes "
                  "alpha; default: the file's, else 0)"),
}

def add_shared(p: Any, *flags: str) -> None:
    """Add the shared options ``flags`` (keys of :data:`SHARED_OPTIONS`) to the parser or argument group ``p``."""
    for flag in flags:
        p.add_argument(flag, **SHARED_OPTIONS[flag])


def workers_arg(value: Any) -> int | None:
    """``--workers`` checked: an integer >= 1, or None (absent: one per core)."""
    from metafovea.errors import check_int

    return None if value is None else check_int("--workers", value, 1, 4096)


def scheduler_arg(value: Any) -> str | None:
    """``--scheduler`` checked before the command's work starts (:func:`metafovea.parallel.check_scheduler`), or
    None (absent: local processes)."""
    from metafovea.parallel import check_scheduler

    return None if value is None else check_scheduler(value)


def seed_arg(value: Any) -> int:
    """``--seed`` checked: an integer 0 <= seed < 2**63."""
    from metafovea.errors import check_int

    return check_int("--seed", value, 0, 2 ** 63 - 1)


def only_with(needed: str, on: bool, given: dict[str, Any]) -> None:
    """Refuse the first flag of ``given`` (flag -> its value, falsy when not typed) that does nothing unless
    ``needed`` is ``on``: a flag that changes nothing must not look as if it had."""
    from metafovea.errors import InputError

    for flag, value in given.items():
        if value and not on:
            raise InputError(flag, value, f"only with {needed} (without it, {flag} changes nothing)")


def add_common(p: argparse.ArgumentParser) -> None:
    """``-q/--quiet`` and ``-v/--verbose`` on a command's parser (absent from the namespace unless given, so that
    ``metafovea -v design`` and ``metafovea design -v`` both count)."""
    known = {s for a in p._actions for s in a.option_strings}  # argparse keeps its options here
    if "--quiet" not in known:
        p.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                       help="no progress bars (warnings and errors are still shown)")
    if "--verbose" not in known:
        p.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                       help="more log output (-v: info, -vv: debug)")


def alias(p: Any, old: str, new: str, dest: str, *, const: Any = None, nargs: Any = None, **kw: Any) -> None:
    """A hidden ``old`` spelling of ``new`` (same ``dest``) that still works (``-v`` logs that it is deprecated).
    ``const``: the value a flag without an argument stores (``nargs=0``)."""
    class Deprecated(argparse.Action):
        def __call__(self, parser: Any, namespace: Any, values: Any, option_string: Any = None) -> None:
            # silent by default (old scripts keep working); main logs it at info level (-v)
            namespace.deprecated_options = [*getattr(namespace, "deprecated_options", []), (old, new)]
            setattr(namespace, self.dest, const if self.nargs == 0 else values)

    p.add_argument(old, dest=dest, action=Deprecated, nargs=0 if const is not None else nargs,
                   default=argparse.SUPPRESS, help=argparse.SUPPRESS, **kw)


def verbosity(args: argparse.Namespace, global_verbose: int = 0) -> tuple[bool, int]:
    """``(quiet, verbose count)`` of parsed ``args``."""
    return bool(getattr(args, "quiet", False)), int(getattr(args, "verbose", 0) or 0) + global_verbose


def show_progress(args: argparse.Namespace) -> bool:
    """Progress on stderr unless ``--quiet`` or ``--json``: the library draws a bar on a terminal and writes a log
    line every 10 s otherwise (:func:`metafovea.parallel.progress_bar`), so that a long run in a log or a pipe is
    not silent."""
    return not getattr(args, "quiet", False) and not getattr(args, "json", False)


def progress(args: argparse.Namespace) -> bool:
    """Progress bars on a terminal only, unless ``--quiet`` or ``--json``: for commands whose library code draws
    tqdm bars itself (``export``, ``verify``, ``psf``); the others use :func:`show_progress`."""
    return show_progress(args) and sys.stderr.isatty()


class warning_printer:  # lower case: a function to its callers (``warnings.showwarning``), with state
    """A ``warnings.showwarning`` that prints each distinct warning once, on one line:
    ``metafovea COMMAND: warning: MESSAGE``. A :class:`~metafovea.errors.NotConvergedWarning` with data is held
    back: :meth:`flush` prints all of them as one summary line (:func:`~metafovea.cli.output.accuracy_summary`)
    whose advice names
    the command's options (``flags``: library parameter -> flag, :data:`metafovea.cli.flags.PARAMETER_FLAGS`)."""

    def __init__(self, command: str, stream: Any = None, flags: dict[str, str] | None = None):
        self.command, self.stream, self.flags = command, stream, dict(flags or {})
        self.seen: set[tuple[type, str]] = set()
        self.held: list[dict[str, Any]] = []

    def __call__(self, message: Any, category: type, filename: str, lineno: int, file: Any = None,
                 line: Any = None) -> None:
        if isinstance(message, NotConvergedWarning) and message.data.get("subject"):
            self.held.append(message.data)
            return
        self._print(" ".join(str(message).split()), category)

    def _print(self, text: str, category: type) -> None:
        from metafovea.cli.flags import in_flags

        text = in_flags(text, self.flags)  # a library keyword (scene_unit='celsius') as the flag to type
        if (category, text) in self.seen:
            return
        self.seen.add((category, text))
        (self.stream or sys.stderr).write(f"metafovea {self.command}: warning: {text}\n")

    def flush(self) -> None:
        """Print the held NotConvergedWarnings as one line (nothing when there are none)."""
        from metafovea.cli.output import accuracy_summary

        held, self.held = self.held, []
        line = accuracy_summary(held, self.flags, self.command)
        if line:
            self._print(line, NotConvergedWarning)


def emit(messages: Sequence[str], category: type = UserWarning) -> None:
    """Warnings collected elsewhere (a worker process, a result's list) through the same printer."""
    for m in messages:
        warnings.warn(m, category, stacklevel=2)


def check_out_suffix(out: str | None, suffixes: Sequence[str], why: str, flag: str = "--out") -> None:
    """An ``--out`` file must end in one of ``suffixes`` (it is never renamed silently)."""
    if out is None:
        return
    if Path(out).suffix.lower() not in tuple(s.lower() for s in suffixes):
        raise InputError(flag, out, f"a file name ending in {' or '.join(suffixes)} ({why})")


def iter_subparsers(parser: argparse.ArgumentParser) -> Iterator[tuple[str, argparse.ArgumentParser]]:
    for a in parser._actions:  # argparse keeps the subcommands here
        if isinstance(a, argparse._SubParsersAction):
            yield from a.choices.items()

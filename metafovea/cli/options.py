"""What every command shares: ``-q/--quiet`` and ``-v/--verbose``, hidden deprecated spellings of renamed options,
the one-line warning printer, progress lines, the default output folder and the check of an ``--out`` file's suffix.

Output folders, one rule for every command that writes one (``validate``, ``study``, ``psf``): ``--out DIR`` (new
or empty, or ``--force``), else a new ``out/<command>-<time>/`` (:func:`default_out_dir`), so that running a
command twice never collides. A command that writes one file for the next command to read (``simulate`` and
``import``: ``meas.npz``; ``reconstruct``: ``<measurement>_rec.npz``) keeps that fixed name; when it exists, the
error says that it is the default output (:data:`DEFAULT_OUT`), not that an ``--out`` nobody typed is invalid.

The vocabulary (one name, unit and meaning per option across commands) is the table "Command-line options" in
README.md; an option renamed to fit it keeps its old spelling as a hidden alias that still works (``-v`` says
what to type instead).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

from metafovea.errors import InputError, NotConvergedWarning


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


def progress(args: argparse.Namespace) -> bool:
    """Progress bars: on a terminal, unless ``--quiet`` or ``--json`` (the same rule for every command)."""
    return not getattr(args, "quiet", False) and not getattr(args, "json", False) and sys.stderr.isatty()


class warning_printer:  # noqa: N801 - a function to its callers (``warnings.showwarning``), with state
    """A ``warnings.showwarning`` that prints each distinct warning once, on one line:
    ``metafovea COMMAND: warning: MESSAGE``. A :class:`~metafovea.errors.NotConvergedWarning` with data is held
    back: :meth:`flush` prints all of them as one summary line (:func:`accuracy_summary`) whose advice names
    the command's options (``flags``: library parameter -> flag, :data:`metafovea.cli.PARAMETER_FLAGS`)."""

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
        if (category, text) in self.seen:
            return
        self.seen.add((category, text))
        (self.stream or sys.stderr).write(f"metafovea {self.command}: warning: {text}\n")

    def flush(self) -> None:
        """Print the held NotConvergedWarnings as one line (nothing when there are none)."""
        held, self.held = self.held, []
        line = accuracy_summary(held, self.flags, self.command)
        if line:
            self._print(line, NotConvergedWarning)


def accuracy_summary(items: Sequence[dict[str, Any]], flags: dict[str, str], command: str) -> str | None:
    """One line for the results that missed their requested error (``NotConvergedWarning.data`` dicts): what
    and where, how far, why, and which options of ``command`` change that (the items' library parameters
    through ``flags``; a parameter the command has no option for is left out, and the line says when none is
    left). None when there are no items."""
    if not items:
        return None
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for it in items:
        groups.setdefault((it["subject"], it["reason"]), []).append(it)
    parts, advice = [], {}
    for (subject, reason), its in groups.items():
        fields = sorted({round(float(it.get("field_deg", 0.0)), 6) for it in its})
        where = (f"field {fields[0]:.3g} deg" if len(fields) == 1 else
                 f"{len(fields)} fields ({fields[0]:.3g}-{fields[-1]:.3g} deg)")
        est = sorted(float(it["estimate"]) for it in its)
        span = f"{est[0]:.2g}" if f"{est[0]:.2g}" == f"{est[-1]:.2g}" else f"{est[0]:.2g} to {est[-1]:.2g}"
        parts.append(f"{subject} at {where}: estimated error {span} of the peak ({reason})")
        for k, v in its[0].get("advice", {}).items():
            advice.setdefault(k, v)
    requested = min(float(it["requested"]) for it in items)
    worst = max(float(it["estimate"]) for it in items)
    todo = []
    for param, what in advice.items():
        flag = flags.get(param)
        if flag is None:
            continue
        todo.append(f"{flag} {worst:.2g} accepts them" if param == "error" else f"{flag} ({what})")
    n = len(items)
    head = f"{n} result{'s' if n > 1 else ''} less accurate than the requested error {requested:g}: "
    tail = ("; what changes it: " + ", ".join(todo)) if todo else \
        f"; no option of '{command}' changes it (each result carries its error estimate)"
    return head + "; ".join(parts) + tail


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


#: the name under which an output the user did not name is reported (set on ``args.out_default`` by the command)
DEFAULT_OUT = "default output"


def default_out_dir(command: str, label: str | None = None, root: str | Path = "out",
                    now: datetime | None = None) -> Path:
    """A new folder name for a command's output when no ``--out`` was given: ``out/<command>[-<label>]-<time>/``
    (time to the second, ``-2``, ``-3``, ... appended while the name exists). Not created: the command makes it
    after its checks (a refused run leaves nothing behind)."""
    stamp = (now or datetime.now()).strftime("%Y%m%d-%H%M%S")
    base = Path(root) / "-".join(x for x in (command, label, stamp) if x)
    p, k = base, 1
    while p.exists():
        k += 1
        p = base.with_name(f"{base.name}-{k}")
    return p


def out_file(args: argparse.Namespace, default: str | None) -> str | None:
    """``--out`` as given, or ``default`` (a fixed name the next command reads, or None: the library derives it from
    the input); then ``args.out_default`` is set, as :func:`out_dir` does."""
    if getattr(args, "out", None):
        return args.out
    args.out_default = True
    return default


def out_dir(args: argparse.Namespace, command: str, label: str | None = None) -> Path:
    """``--out`` as given, or :func:`default_out_dir` (then ``args.out_default`` is set, so that an error about it
    names the default output rather than an ``--out`` the user did not type)."""
    if getattr(args, "out", None):
        return Path(args.out)
    args.out_default = True
    return default_out_dir(command, label)


def stage_printer(args: argparse.Namespace, command: str, stream: Any = None) -> Callable[[str], None]:
    """A ``say(msg)`` that prints one line per stage, ``metafovea COMMAND: [  12.3 s] MSG``, on stderr, on a
    terminal or not (a long first run says what it is doing), unless ``--quiet`` or ``--json``."""
    t0 = time.perf_counter()
    on = not getattr(args, "quiet", False) and not getattr(args, "json", False)

    def say(msg: str) -> None:
        if on:
            out = stream or sys.stderr
            out.write(f"metafovea {command}: [{time.perf_counter() - t0:6.1f} s] {msg}\n")
            out.flush()

    return say

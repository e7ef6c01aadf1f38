"""What every command shares: ``-q/--quiet`` and ``-v/--verbose``, hidden deprecated spellings of renamed options,
the one-line warning printer, the check of an ``--out`` file's suffix, and a stage's message in the flags' words.

The vocabulary (one name, unit and meaning per option across commands) is the table "Command-line options" in
README.md; an option renamed to fit it keeps its old spelling as a hidden alias that still works (``-v`` says
what to type instead).
"""

from __future__ import annotations

import argparse
import re
import sys
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from metafovea.errors import InputError


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


def warning_printer(command: str, stream: Any = None) -> Callable[..., None]:
    """A ``warnings.showwarning`` that prints each distinct warning once, on one line:
    ``metafovea COMMAND: warning: MESSAGE``."""
    seen: set[tuple[type, str]] = set()

    def show(message: Any, category: type, filename: str, lineno: int, file: Any = None, line: Any = None) -> None:
        text = " ".join(str(message).split())
        if (category, text) in seen:
            return
        seen.add((category, text))
        (stream or sys.stderr).write(f"metafovea {command}: warning: {text}\n")

    return show


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


def in_flags(text: str, flags: dict[str, str]) -> str:
    """A stage's message ``text`` in the words of a command's flags (``flags``: parameter -> flag,
    :func:`metafovea.cli.flag_map`): a parameter written as a keyword argument, ``name=value``, becomes ``--flag
    value`` (a quoted value unquoted; ``True`` and ``...`` leave the flag alone: ``fmt='gds'`` -> ``--format gds``,
    ``max_refs=...`` -> ``--max-refs``). A bare name is left alone: it may be a file's key or an English word."""
    def flag(m: re.Match, to: str) -> str:
        value = m.group(1)
        value = value[1:-1] if value[:1] in "'\"" else value
        return to if value in ("True", "...") else f"{to} {value}"

    for name, to in flags.items():
        if name.isidentifier():
            text = re.sub(rf"(?<![\w.'-]){name}=('[^']*'|\"[^\"]*\"|[^\s,;)\]]+)", lambda m, t=to: flag(m, t), text)
    return text


def iter_subparsers(parser: argparse.ArgumentParser) -> Iterator[tuple[str, argparse.ArgumentParser]]:
    for a in parser._actions:  # argparse keeps the subcommands here
        if isinstance(a, argparse._SubParsersAction):
            yield from a.choices.items()

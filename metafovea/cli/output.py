"""What a command writes when the user did not say where, and what it says while it works.

Output folders, one rule for every command that writes one (``validate``, ``study``, ``psf``): ``--out DIR`` (new or
empty, or ``--force``), else a new ``out/<command>-<time>/`` (:func:`default_out_dir`), so that running a command
twice never collides. A command that writes one file for the next command or the fab to read (``simulate``:
``meas.npz``; ``import``: the recording's name; ``reconstruct``: ``<measurement>_rec.npz``; ``export``:
``gds_export/<lens>.<format>``) keeps that fixed name (:func:`out_file`); when it exists, the error says that it is
the default output (:data:`DEFAULT_OUT`), not that an ``--out`` nobody typed is invalid.

Progress: :func:`stage_printer`, one line per stage on stderr, on a terminal or not. Results less accurate than
asked: :func:`accuracy_summary`, one line whose advice names the command's own options.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any, TextIO

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


def stage_printer(args: argparse.Namespace, command: str, stream: TextIO | None = None) -> Callable[[str], None]:
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

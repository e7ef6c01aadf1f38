"""Errors raised for bad user input, and small validators that produce them.

Every validator names the parameter, shows the offending value and states the allowed range, so that
the CLI can print a one-line message (exit status 2) instead of a traceback from deep inside numpy.
"""

from __future__ import annotations

import math
import numbers
import re
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np


class InputError(ValueError):
    """Bad input from a user: the message names the parameter, the value and the allowed range.

    Attributes
    ----------
    parameter: the parameter (or file key) that was wrong.
    value: the value given.
    allowed: a human-readable description of the allowed range.
    source: optional origin (a file path) shown before the parameter.
    """

    def __init__(self, parameter: str, value: Any, allowed: str, source: str | None = None,
                 detail: str | None = None):
        self.parameter = parameter
        self.value = value
        self.allowed = allowed
        self.source = source
        self.detail = detail
        where = f"{source}: " if source else ""
        # None: the value was not given (a required option, a file without the key)
        stated = "is missing" if value is None else f"= {_shown(value)} is invalid"
        msg = f"{where}{parameter} {stated}; allowed: {allowed}"
        if detail:
            msg += f" ({detail})"
        super().__init__(msg)

    def renamed(self, parameter: str) -> InputError:
        """The same error, reported under another name (the CLI flag a user typed for a library parameter); the
        name is replaced in the allowed range too (``0 K <= netd_k <= 10 K`` -> ``0 K <= --netd <= 10 K``)."""
        name = re.escape(self.parameter)  # where a range states it: "lo <= name", "name <= hi"
        allowed = re.sub(rf"(?<=[<>=] ){name}(?![\w-])|(?<![\w-]){name}(?= [<>]=? )", lambda m: parameter,
                         self.allowed)
        return InputError(parameter, self.value, allowed, source=self.source, detail=self.detail)

    def located(self, source: str) -> InputError:
        """The same error, placed in ``source`` (a file the user named: the parameter is its key)."""
        return InputError(self.parameter, self.value, self.allowed, source=source, detail=self.detail)


def _shown(value: Any) -> str:
    """A value as an error message shows it: a float to 6 significant digits (``6274.5``, not
    ``6274.495703445411``), anything else as its repr."""
    if isinstance(value, float) or type(value).__name__ in ("float64", "float32"):
        return f"{float(value):.6g}"
    if isinstance(value, (list, tuple)) and len(value) > 8:  # a recording's 96 alphas: the first few and the count
        return "[" + ", ".join(_shown(v) for v in value[:4]) + f", ... ({len(value)} values)]"
    return repr(value)


class NotConvergedWarning(UserWarning):
    """A numerical result did not reach the requested tolerance.

    ``data`` (where the raiser knows it): ``subject`` (what, e.g. "sensor PSF of 'foveal'"), ``field_deg``,
    ``estimate`` and ``requested`` (the achieved and the requested error), ``reason`` and ``advice`` (``{library
    parameter: what changing it does}``). A command folds such warnings into one summary line that names its own
    options for these parameters (:func:`metafovea.cli.options.accuracy_summary`).
    """

    def __init__(self, message: str = "", data: dict[str, Any] | None = None):
        super().__init__(message)
        self.data = dict(data or {})


class PhysicsWarning(UserWarning):
    """A design is valid but physically questionable (undersampled zones, substrate orders, ...)."""


def human_bytes(n: float) -> str:
    """``n`` bytes as ``1.8 TiB`` (binary prefixes), for messages about memory and disk."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"):
        if abs(n) < 1024 or unit == "EiB":
            return f"{n:.3g} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    return f"{n:.3g} EiB"  # pragma: no cover


def as_float(name: str, value: Any, source: str | None = None) -> float:
    """Convert ``value`` to a finite float or raise :class:`InputError` naming ``name``."""
    if isinstance(value, bool) or value is None:
        raise InputError(name, value, "a finite real number", source)
    if isinstance(value, numbers.Real):
        x = float(value)
    elif isinstance(value, str):
        try:
            x = float(value.strip())
        except ValueError:
            raise InputError(name, value, "a finite real number", source) from None
    else:
        raise InputError(name, value, "a finite real number", source)
    if not math.isfinite(x):
        raise InputError(name, value, "a finite real number", source)
    return x


def check_range(name: str, value: Any, lo: float | None = None, hi: float | None = None, *,
                lo_inclusive: bool = False, hi_inclusive: bool = True, unit: str = "",
                source: str | None = None) -> float:
    """Return ``value`` as float if ``lo < value <= hi`` (inclusiveness configurable), else raise.

    ``None`` for a bound means unbounded on that side.
    """
    x = as_float(name, value, source)
    ok = True
    if lo is not None:
        ok &= (x >= lo) if lo_inclusive else (x > lo)
    if hi is not None:
        ok &= (x <= hi) if hi_inclusive else (x < hi)
    if not ok:
        u = f" {unit}" if unit else ""
        left = "" if lo is None else (f"{lo:g}{u} <= " if lo_inclusive else f"{lo:g}{u} < ")
        right = "" if hi is None else (f" <= {hi:g}{u}" if hi_inclusive else f" < {hi:g}{u}")
        raise InputError(name, value, f"{left}{name}{right}".strip(), source)
    return x


def check_positive(name: str, value: Any, unit: str = "", source: str | None = None,
                   hi: float | None = None) -> float:
    """Finite and strictly positive (optionally ``<= hi``)."""
    return check_range(name, value, 0.0, hi, unit=unit, source=source)


def check_int(name: str, value: Any, lo: int | None = None, hi: int | None = None,
              source: str | None = None) -> int:
    """An integer (bools and non-integral floats refused) within ``[lo, hi]``."""
    if isinstance(value, bool):
        raise InputError(name, value, "an integer", source)
    if isinstance(value, numbers.Integral):
        n = int(value)
    elif isinstance(value, numbers.Real) and float(value).is_integer():
        n = int(value)
    elif isinstance(value, str):
        try:
            n = int(value.strip())
        except ValueError:
            raise InputError(name, value, "an integer", source) from None
    else:
        raise InputError(name, value, "an integer", source)
    if (lo is not None and n < lo) or (hi is not None and n > hi):
        rng = f"{'' if lo is None else f'{lo} <= '}{name}{'' if hi is None else f' <= {hi}'}"
        raise InputError(name, value, f"integer {rng}", source)
    return n


def check_choice(name: str, value: Any, choices: tuple[str, ...], source: str | None = None) -> str:
    """One of ``choices`` (case-insensitive for strings); returns the canonical choice."""
    if isinstance(value, str):
        for c in choices:
            if value.strip().lower() == c.lower():
                return c
    raise InputError(name, value, "one of " + ", ".join(repr(c) for c in choices), source)


def as_rng(rng: np.random.Generator | int | str | None, name: str = "seed") -> np.random.Generator:
    """A :class:`numpy.random.Generator` from a seed (an integer >= 0, or its decimal string), ``None`` (fresh
    entropy) or a generator (returned as is). ``name`` is the parameter an error names (a CLI passes its flag)."""
    import numpy as np

    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, str):
        try:
            rng = int(rng)
        except ValueError:
            raise InputError(name, rng, "an integer seed >= 0") from None
    if rng is None or (isinstance(rng, (int, np.integer)) and not isinstance(rng, bool)):
        if rng is not None and int(rng) < 0:
            raise InputError(name, rng, "an integer >= 0")
        return np.random.default_rng(rng)
    raise InputError(name, rng, "an integer seed >= 0, None or a numpy.random.Generator")


"""The rotating polariser's options (``--polarizer-hz``, ``--polarizer-mode``, ``--polarizer-phase-deg``,
``--extinction``, ``--tau``; defined once in :data:`metafovea.cli.options.SHARED_OPTIONS`): what ``import`` writes to
a file and ``reconstruct`` uses instead of the file's, as :class:`~metafovea.measurement.PolarizerSpec` keywords, and
the lines that say which model a command used."""

from __future__ import annotations

import argparse
from typing import Any

#: the polariser options and the keywords of :class:`~metafovea.measurement.PolarizerSpec` they set
POLARIZER_OPTIONS = {"--polarizer-hz": "rate_hz", "--polarizer-mode": "mode", "--polarizer-phase-deg": "phase_deg",
                     "--extinction": "extinction", "--tau": "tau_s"}


def _with_flag(assumed: str) -> str:
    """An assumption ``"key = value (why)"`` with the flag that states the value instead: ``"... (why; --tau states
    it)"``."""
    from metafovea.measurement import POLARIZER_KEYS

    flag = {POLARIZER_KEYS[name]: f for f, name in POLARIZER_OPTIONS.items()}.get(assumed.split(" = ")[0])
    return f"{assumed[:-1]}; {flag} states it)" if flag and assumed.endswith(")") else assumed


def polarizer_lines(spec: dict[str, Any], calibration: dict[str, Any] | None = None) -> str:
    """The polariser model a command used (:meth:`~metafovea.measurement.PolarizerSpec.summary`): one line, with each
    value's source, one line per assumption, and what the recording's calibration found (geometry, gain, alpha's
    amplitude, with standard errors: :mod:`metafovea.reconstruct.calibrate`)."""
    phase = "" if spec.get("phase_deg") is None else f", phase {spec['phase_deg']:g} deg"
    src = ", ".join(f"{k} {v}" for k, v in spec["sources"].items() if not v.startswith("ignored"))
    lines = [f"  polariser model: {spec['mode']} at {spec['rate_hz']:g} Hz{phase}, extinction {spec['extinction']:g}, "
             f"bolometer tau {spec['tau_s']:g} s ({src})"]
    lines += [f"  assumed: {_with_flag(a)}" for a in spec.get("assumed") or []]
    c = calibration or {}
    if "scale" in c:
        se = c.get("se") or {}
        of = f"the first {c['frames']} of {c['frames_in_recording']}" if c.get("frames_in_recording", 0) > c["frames"] \
            else str(c["frames"])
        lines.append(f"  calibrated from the recording ({of} frames): foveal scale {c['scale']:.4f} "
                     f"+- {se.get('scale', 0):.2g}, centre ({c['centre_px'][0]:.2f}, {c['centre_px'][1]:.2f}) "
                     f"+- {se.get('centre_px', 0):.2g} perifoveal px, rotation {c['rotation_deg']:.3f} +- "
                     f"{se.get('rotation_deg', 0):.2g} deg, channel gain ratio {c['gain']:.4g} +- "
                     f"{se.get('gain', 0):.2g}, "
                     f"alpha's amplitude {c['amplitude']:.4f} +- {se.get('amplitude', 0):.2g} of the stated "
                     f"({'used' if c.get('applied') else 'stated kept'})")
    elif c.get("reason"):
        lines.append(f"  calibration: {c['reason']}")
    return "\n".join(lines)


def polarizer_args(args: argparse.Namespace) -> dict[str, Any]:
    """The polariser options the user typed, as :class:`~metafovea.measurement.PolarizerSpec` keywords (numbers
    checked under the flag's name; the ranges are checked by the spec, whose errors name the keywords, which
    :mod:`metafovea.cli.flags` maps back to these flags)."""
    from metafovea.errors import as_float, check_range

    out: dict[str, Any] = {}
    ranges = {"--polarizer-hz": (0.0, 1000.0), "--extinction": (0.0, 0.5), "--tau": (0.0, 10.0),
              "--polarizer-phase-deg": (-1e6, 1e6)}
    for flag, name in POLARIZER_OPTIONS.items():
        v = getattr(args, flag[2:].replace("-", "_"), None)
        if v is None:
            continue
        if flag in ranges:
            v = as_float(flag, v)
            check_range(flag, v, *ranges[flag], lo_inclusive=flag != "--polarizer-hz")
        out[name] = v
    return out

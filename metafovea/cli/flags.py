"""The one map between the library's parameter names and the flags a user types.

Stage code raises :class:`~metafovea.errors.InputError` naming its Python parameter (``band_um``), never a flag: a
Python caller never typed one. The CLI turns the parameter back into the flag of the command that was run
(:func:`as_flag_error`, with :data:`PARAMETER_FLAGS`), places a file's key in the file the user named
(:data:`FILE_KEYS`) and writes the library keywords of an error's advice as that command's flags
(:data:`KEYWORD_ADVICE`).
"""

from __future__ import annotations

import argparse
import re
from typing import Any

from metafovea.errors import InputError

#: library parameter name -> the flag a user typed, per command (an InputError raised deep in a stage names the
#: parameter; the CLI reports the flag, and the flags of the parameters a message mentions, :func:`as_flag_error`).
#: :data:`EVERY_COMMAND`: the ground floor's parameters, which every command shares.
EVERY_COMMAND = {"out": "--out", "force": "--force", "scheduler": "--scheduler"}
_LAYOUT = {"band_rows": "--band-rows", "grid_nm": "--grid-nm", "ring_width_um": "--ring-width-um", "block": "--block",
           "patch_mm": "--patch", "levels": "--levels", "post_set": "--post-set", "posts": "--posts", "date": "--date",
           "workers": "--workers", "substrate_thickness_um": "--substrate-um", "max_refs": "--max-refs", "dwl": "--dwl",
           "compress": "--compress", "fmt": "--format", "path": "--out", "flat": "--flat", "test_array": "--test-array",
           "tiles_dir": "--tiles-dir", "reader": "--reader"}
#: the polariser's keywords (metafovea.measurement.PolarizerSpec) and the flags of import and reconstruct
_POLARIZER = {"rate_hz": "--polarizer-hz", "mode": "--polarizer-mode", "phase_deg": "--polarizer-phase-deg",
              "extinction": "--extinction", "tau_s": "--tau"}
PARAMETER_FLAGS: dict[str, dict[str, str]] = {
    "design": {"post_set": "--post-set", "from_library": "--library", "samples": "--samples", "f_um": "--f",
               "diameter_um": "--d", "period_um": "--period-um", "wavelength_um": "--wavelength-um"},
    "library": {"grid_step_um": "--grid-step-um", "levels": "--levels", "harmonics": "--harmonics",
                "wavelengths_um": "--wavelengths-um", "workers": "--workers", "tol": "--tol",
                "tolerance_rad": "--tolerance-rad"},
    "export": _LAYOUT, "verify": _LAYOUT,
    "psf": {"band_um": "--band-um", "filter_um": "--filter-um", "pixel_pitch_um": "--pixel-um",
            "field_deg": "--field-deg", "fields_deg": "--field-deg", "error": "--error",
            "temperature_k": "--temperature-k", "n_wavelengths": "--wavelength-bins",
            "wavelength_um": "--wavelength-um", "window_um": "--window-um", "relay_magnification": "--relay",
            "jobs": "--workers", "out_dir": "--out", "posts": "--posts"},
    "reconstruct": {"window": "--window", "frame": "--frame", "fpn": "--fpn", "known_alpha": "--known-alpha",
                    "regularize": "--regularize", "steps": "--steps", "channels": "--channels", "stride": "--stride",
                    "max_seconds": "--max-seconds", "seed": "--seed", "rng": "--seed", "scale": "--scale",
                    "gain": "--foveal-gain", "offset": "--foveal-offset", "denoise": "--denoise",
                    "psf": "--psf", "res": "--deconvolve", "method": "--method", "refine_alpha": "--refine-alpha",
                    "time_s": "--time-s", "deconvolve": "--deconvolve",
                    **_POLARIZER},
    "simulate": {"extinction": "--extinction", "tau_s": "--tau", "bolometer_tau_s": "--tau", "fpn_drift": "--drift",
                 "netd_k": "--netd", "frames": "--frames", "calibration_frames": "--calibration-frames",
                 "supersample": "--supersample", "psf_size_px": "--psf-size", "scene": "--scene",
                 "pixel_pitch_um": "--pixel-um", "psf gaussian sigma_um": "--psf", "psf": "--psf",
                 "relay_magnification": "--relay", "fpn_rank": "--fpn-rank", "fpn_amplitude": "--fpn-amplitude",
                 "polarizer_phase_deg": "--phase-deg", "field_patches": "--field-patches", "rng": "--seed",
                 "scene_unit": "--scene-unit", "tolerance_k": "--tolerance-k",
                 "out (TIFF)": "--out (TIFF)", "out (preview)": "--out (preview)"},
    "bench": {"stages": "--stages", "quick": "--quick"},
    "validate": {"frames": "--frames", "seed": "--seed", "rng": "--seed", "scene": "--scene",
                 "scene_unit": "--scene-unit", "dip_steps": "--dip-steps"},
    "import": {"format": "--format", "frames_key": "--frames-key", "frame_axis": "--frame-axis", "times": "--times",
               "time_unit": "--time-unit", "frame_rate_hz": "--frame-rate", "polarizer_key": "--polarizer-key",
               "polarizer_unit": "--polarizer-unit", "calibration": "--calibration", "planck": "--planck",
               "calibration_gain": "--calibration-gain", "band_um": "--band-um", "filter_um": "--filter-um",
               "foveal_gain": "--foveal-gain", "scale": "--scale", "adc_bits": "--adc-bits", **_POLARIZER},
    "codesign": {"objective": "--objective", "band_um": "--band", "lenses": "--lenses",
                 "n_coefficients": "--coefficients", "size_px": "--size-px", "max_wavelengths": "--max-wavelengths",
                 "steps": "--steps", "learning_rate": "--learning-rate", "out": "--out", "posts": "--posts"},
}

#: library keyword expressions in an error's advice -> what to type at the command, per command: a Python caller
#: reads ``strict=False``, a command-line user ``--no-strict`` (the advice's words are written once, in the library)
KEYWORD_ADVICE: dict[str, dict[str, str]] = {
    "reconstruct": {"the polariser model (polarizer)": "the file's polariser model (--polarizer auto)",
                    "(scale, foveal_gain, foveal_offset)": "(--scale, --foveal-gain, --foveal-offset)",
                    "wrong scale/offset/gain?": "wrong --scale, --foveal-offset or --foveal-gain?",
                    "wrong scale?": "wrong --scale?", "method='lsq'": "--method lsq", "strict=False": "--no-strict",
                    "fpn='auto'": "--fpn auto", "simulate(calibration_frames)": "simulate --calibration-frames",
                    "refine_alpha=True": "--refine-alpha", "window=...": "--window"},
}

#: library parameters that are a key of a file the user named, per command: parameter -> the option (or
#: positional argument's dest) holding that file; the error then names the file (``--scene hot.npy: ...``)
FILE_KEYS: dict[str, dict[str, str]] = {
    "simulate": {"temperature_k": "scene", "emissivity": "scene", "image": "scene"},
    "validate": {"temperature_k": "scene", "emissivity": "scene", "image": "scene"},
    "reconstruct": {**{k: "measurement" for k in ("frames", "alpha", "times_s", "calibration", "flat_field",
                                                  "theta_rad", "bad_pixels", "polarizer mode",
                                                  "foveal_constraint.scale", "foveal_constraint.gain",
                                                  "foveal_constraint.offset_dn")},
                    "psf_x1": "psf", "psf_x2": "psf"},
}
#: the dests of FILE_KEYS that are positional arguments (the error names the file alone, not an option)
POSITIONAL_FILES = {"measurement"}


def flag_map(command: str) -> dict[str, str]:
    """Parameter -> flag for ``command``: its :data:`PARAMETER_FLAGS` over :data:`EVERY_COMMAND`."""
    return {**EVERY_COMMAND, **PARAMETER_FLAGS.get(command, {})}


def in_flags(text: str, flags: dict[str, str]) -> str:
    """A stage's message ``text`` in the words of a command's flags (``flags``: parameter -> flag,
    :func:`flag_map`): a parameter written as a keyword argument, ``name=value``, becomes ``--flag value`` (a quoted
    value unquoted; ``True`` and ``...`` leave the flag alone: ``fmt='gds'`` -> ``--format gds``, ``max_refs=...``
    -> ``--max-refs``). A bare name is left alone: it may be a file's key or an English word."""
    def flag(m: re.Match, to: str) -> str:
        value = m.group(1)
        value = value[1:-1] if value[:1] in "'\"" else value
        return to if value in ("True", "...") else f"{to} {value}"

    for name, to in flags.items():
        if name.isidentifier():
            text = re.sub(rf"(?<![\w.'-]){name}=('[^']*'|\"[^\"]*\"|[^\s,;)\]]+)", lambda m, t=to: flag(m, t), text)
    return text


def warnings_in_flags(summary: dict[str, Any], command: str) -> dict[str, Any]:
    """``summary`` with its ``'warnings'`` in the words of ``command``'s flags (:func:`in_flags`), for what the
    command prints and writes as JSON."""
    if not summary.get("warnings"):
        return summary
    return {**summary, "warnings": [in_flags(w, flag_map(command)) for w in summary["warnings"]]}


def as_flag_error(command: str, err: InputError, args: argparse.Namespace | None = None) -> InputError:
    """``err`` renamed to the flag of ``command`` that sets its parameter, or (:data:`FILE_KEYS`) placed in the
    file the user gave; unchanged when there is none, or when the error already names a file's key. Library keywords
    in its advice become the command's flags (:data:`KEYWORD_ADVICE`), and so do the parameters its range and
    detail mention (:func:`in_flags`)."""
    flags = flag_map(command)
    err = _advice_in_flags(command, err)
    err = InputError(err.parameter, err.value, in_flags(err.allowed, flags), source=err.source,
                     detail=None if err.detail is None else in_flags(err.detail, flags))
    if err.source is not None:
        return err
    dest = FILE_KEYS.get(command, {}).get(err.parameter)
    if dest is not None and args is not None and getattr(args, dest, None) is not None:
        value = getattr(args, dest)
        return err.located(str(value) if dest in POSITIONAL_FILES else f"--{dest.replace('_', '-')} {value}")
    head, _, rest = err.parameter.partition(" ")  # a part of a parameter ('filter_um width') names the flag too
    flag = flags.get(err.parameter) or (flags.get(head) if rest else None)
    if flag not in (None, "--out") and _not_typed(flag, args):  # from a file or a default (--out: its own words)
        note = f"not typed: the file's value or the default; {flag} sets it"
        if flag not in (err.detail or ""):  # a detail that already names the flag says it (codesign's cap)
            err = InputError(err.parameter, err.value, err.allowed, source=err.source,
                             detail=note if err.detail is None else f"{err.detail}; {note}")
    elif err.parameter in flags:
        err = err.renamed(flags[err.parameter])
    elif rest and head in flags:
        err = err.renamed(f"{flags[head]} {rest}")
    if getattr(args, "out_default", False) and err.parameter.split(" ")[0] == "--out":
        # the command chose the path (no --out typed): say so, and what to type instead
        from metafovea.cli.output import DEFAULT_OUT

        return InputError(DEFAULT_OUT + err.parameter[len("--out"):], err.value, err.allowed, source=err.source,
                          detail="the command's default: --out PATH writes elsewhere")
    typed = {new: old for old, new in getattr(args, "deprecated_options", [])}  # the spelling the user typed
    return err.renamed(typed[err.parameter]) if err.parameter in typed else err


def _not_typed(flag: str, args: argparse.Namespace | None) -> bool:
    """Whether ``flag`` is an option of ``args`` that the user left unset (None): an error about its parameter
    then concerns a value from a file or a default, and must not read as if the user had typed the flag."""
    dest = flag.split(" ")[0].lstrip("-").replace("-", "_")
    return args is not None and flag.startswith("--") and hasattr(args, dest) and getattr(args, dest) is None


def _advice_in_flags(command: str, err: InputError) -> InputError:
    """``err`` with the library keywords of its advice replaced by what to type at ``command``."""
    advice = KEYWORD_ADVICE.get(command, {})
    words = [err.allowed, err.detail]
    for keyword, typed in advice.items():
        words = [w.replace(keyword, typed) if w else w for w in words]
    return InputError(err.parameter, err.value, words[0], source=err.source, detail=words[1]) if advice else err

"""``metafovea import``: a camera recording (TIFF stack, HDF5, MAT) into a Measurement ``.npz``.

``run(args)`` builds :class:`metafovea.recordings.ImportOptions` from the flags, calls
:func:`metafovea.recordings.import_recording` (read, timing check, polariser state, counts to kelvin, write),
prints a summary (``--json``: as JSON) and its warnings (dropped or duplicated frames, non-uniform timing,
saturated samples). Exit status 0, or 2 on bad input (one line naming the flag or the file; nothing written).
"""

from __future__ import annotations

import argparse
from typing import Any

from metafovea.cli.options import add_shared
from metafovea.cli.output import out_file
from metafovea.cli.polarizer import polarizer_args
from metafovea.io import to_json

HELP = "import a camera recording (TIFF stack, HDF5, MAT, FLIR JPEG/SEQ/FFF) as a measurement (.npz) for reconstruct"


def register(subparsers: Any) -> argparse.ArgumentParser:
    from metafovea.recordings import FORMATS, FRAME_AXES, GAIN_MODES, POLARIZER_UNITS, TIME_UNITS

    p = subparsers.add_parser("import", help=HELP, description=HELP + ". README.md, 'Reconstructing a real "
                              "recording', has the recipe and the calibration model.")
    p.add_argument("recording", help="the recording: .tif/.tiff stack, .h5/.hdf5, .mat (v5 or v7.3), FLIR "
                   ".jpg/.seq/.fff (pip install 'metafovea[flir]')")
    p.add_argument("--format", default="auto", choices=FORMATS, help="reader (default auto: from the suffix)")
    g = p.add_argument_group("what the file holds")
    g.add_argument("--frames-key", default=None, metavar="KEY", help="HDF5/MAT: the frames' array (default: "
                   "frames, images, data, raw, counts or video, else the file's only 3-D array)")
    g.add_argument("--frame-axis", default="first", choices=FRAME_AXES, help="where the frame index is in that "
                   "array (default first, T x H x W; MATLAB videos are usually H x W x T: last)")
    g.add_argument("--times", default=None, metavar="KEY|FILE", help="the timestamps: a key of the recording or a "
                   "file (.npy, .txt or .csv, one time per frame); default: times_s, timestamps, times, time or t, "
                   "else the file's frame interval or rate, else --frame-rate")
    g.add_argument("--time-unit", default=None, choices=tuple(TIME_UNITS), help="of the timestamps (default: the "
                   "dataset's 'units' attribute, else s)")
    g.add_argument("--frame-rate", type=float, default=None, metavar="HZ", help="frame rate in Hz: the times when "
                   "the file has none; with the file's times, the nominal rate dropped frames are judged by")
    g.add_argument("--polarizer-key", default=None, metavar="KEY", help="the polariser state per frame: angles "
                   "(stored as theta_rad; a uniform rotation also gives the polariser model) or alpha")
    g.add_argument("--polarizer-unit", default=None, choices=POLARIZER_UNITS, help="of --polarizer-key (default: "
                   "alpha if its name contains 'alpha', deg if 'deg', else rad)")
    pg = p.add_argument_group("the polariser (written to the file as the recording schema's keys)")
    add_shared(pg, "--polarizer-hz", "--polarizer-mode", "--polarizer-phase-deg", "--extinction", "--tau")
    c = p.add_argument_group("counts to kelvin (default: the file's Planck constants, else none)")
    cal = c.add_mutually_exclusive_group()
    cal.add_argument("--calibration", default=None, metavar="two-point:T1=FILE1,T2=FILE2",
                     help="two blackbodies filling the field at T1 and T2 kelvin (files of frames, read as the "
                          "recording), e.g. two-point:293.15=cold.tif,323.15=hot.tif")
    cal.add_argument("--planck", default=None, metavar="R,B,F,O", help="the camera's Planck constants, counts = "
                     "R / (exp(B / T) - F) - O (FLIR's sign of O; R = R1 / R2); instead of the file's")
    c.add_argument("--calibration-gain", default="per-pixel", choices=GAIN_MODES, help="two-point: per-pixel "
                   "(default; also corrects the frames' non-uniformity) or one global gain and offset")
    c.add_argument("--band-um", nargs=2, type=float, default=None, metavar=("LO", "HI"),
                   help="the camera's spectral band in um (default 8 14) for the radiance model L(T)")
    c.add_argument("--filter-um", nargs=2, type=float, default=None, metavar=("C", "FWHM"),
                   help="a narrow-band filter in front of the camera: centre and FWHM in um")
    c.add_argument("--foveal-gain", type=float, default=None, help="flat-field ratio of the channels G1/G2 (the "
                   "foveal constraint's gain; default 1): splits the calibration between the channels")
    c.add_argument("--scale", type=float, default=None, help="f1/f2 of the two lenses (default: reconstruct's 6)")
    g.add_argument("--adc-bits", type=int, default=None, metavar="N", help="the camera's ADC bits: samples at 2^N - 1 "
                   "are saturated, left out (default: the file's integer full scale, 65535 for 16-bit)")
    p.add_argument("--out", default=None, help="output .npz (default: the recording's name with .npz)")
    p.add_argument("--no-preview", action="store_true", help="do not write the preview PNG (<out>_preview.png)")
    add_shared(p, "--force", "--json")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Import, print the summary, write the Measurement; 0 on success (an InputError is reported by main)."""
    import warnings

    from metafovea.cli.flags import flag_map, in_flags
    from metafovea.radiometry import BAND_UM
    from metafovea.recordings import ImportOptions, import_recording

    opt = ImportOptions(format=args.format, frames_key=args.frames_key, frame_axis=args.frame_axis, times=args.times,
                        time_unit=args.time_unit, frame_rate_hz=args.frame_rate, polarizer_key=args.polarizer_key,
                        polarizer_unit=args.polarizer_unit, calibration=args.calibration,
                        calibration_gain=args.calibration_gain, planck=args.planck,
                        band_um=tuple(args.band_um) if args.band_um else BAND_UM,
                        filter_um=tuple(args.filter_um) if args.filter_um else None, foveal_gain=args.foveal_gain,
                        scale=args.scale, polarizer=polarizer_args(args), adc_bits=args.adc_bits)
    out, s = import_recording(args.recording, out_file(args, None), opt, force=args.force,
                              preview=not args.no_preview)
    s["warnings"] = [in_flags(w, flag_map("import")) for w in s["warnings"]]  # the flags for the options they advise
    for w in s["warnings"]:
        warnings.warn(w, UserWarning, stacklevel=1)
    if args.json:
        print(to_json(s))
        return 0
    rate = f"{s['frame_rate_hz']:.4g} Hz" if s["frame_rate_hz"] else "one frame"
    print(f"{args.recording}: {s['frames']} of {s['frames_in']} frames of {s['shape'][0]} x {s['shape'][1]}, "
          f"{rate} (times from {s['times_from']}); {s['n_dropped']} dropped, {s['duplicates_removed']} duplicated "
          f"(removed), timing {'uniform' if s['uniform_timing'] else 'non-uniform'}")
    pol = "alpha" if s["alpha_known"] else "angles (theta_rad)" if s["theta_rad"] else "no per-frame state"
    ps = s.get("polarizer")
    if ps:
        pol += (f"; {ps['mode']} at {ps['rate_hz']:g} Hz" + (f", phase {ps['phase_deg']:g} deg"
                                                             if ps.get("phase_deg") is not None else "")
                + f", extinction {ps['extinction']:g}, tau {ps['tau_s']:g} s")
    elif not s["alpha_known"]:
        pol += " (reconstruct will assume the paper's free-running 2 Hz polariser: --polarizer-hz, --polarizer-mode)"
    cal = s["calibration"]
    how = "none: frames in camera counts, no kelvin" if cal is None else (
        f"{cal['method']}, dark level {cal['dark_dn']:.6g} DN"
        + (f", Planck fit within {cal['fit_max_error_k']:.2g} K" if "fit_max_error_k" in cal else "")
        + (f", {cal['bad_pixels']} bad pixel(s)" if cal.get("bad_pixels") else ""))
    print(f"  polariser: {pol}; calibration: {how}")
    print(f"  wrote {out}" + (f", {s['preview']}" if s.get("preview") else ""))
    return 0

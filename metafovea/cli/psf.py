"""``metafovea psf DESIGN.toml``: PSF/MTF report (PNG, JSON, one HTML page) for one or more lenses."""

from __future__ import annotations

import argparse
import logging
import os
from pathlib import Path
from typing import Any

from metafovea.config import load_lens
from metafovea.errors import InputError, check_int, check_positive
from metafovea.io import prepare_output, to_json

log = logging.getLogger(__name__)


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser("psf", help="PSF/MTF report of metalens designs",
                              description="PSF, MTF, encircled energy and chromatic behaviour of lens designs; "
                                          "writes PNG figures, JSON numbers and a self-contained HTML page.")
    p.add_argument("designs", nargs="+", help="lens TOML files (e.g. designs/foveal.toml)")
    p.add_argument("--field-deg", type=float, nargs="+", default=None,
                   help="field angles in degrees (default: 9 points from 0 to the sensor corner / lens field)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--band-um", type=float, nargs=2, metavar=("LO", "HI"), default=None,
                   help="spectral band in um (default 8 14)")
    g.add_argument("--filter-um", type=float, nargs=2, metavar=("CENTER", "FWHM"), default=None,
                   help="narrow-band filter (Gaussian) centre and width in um")
    p.add_argument("--temperature-k", type=float, default=300.0, help="scene temperature for Planck weights")
    p.add_argument("--wavelengths", type=int, default=61, help="wavelength bins across the band (geometric "
                   "around the design wavelength; metafovea.radiometry.psf_wavelengths)")
    p.add_argument("--pixel-um", type=float, default=17.0, help="sensor pixel pitch (um)")
    p.add_argument("--wavelength-um", type=float, default=None,
                   help="wavelength of the monochromatic PSFs in um (default: the design wavelength)")
    p.add_argument("--window-um", type=float, default=None,
                   help="full width of the fine monochromatic PSF windows in um (default: sized from the rays); "
                        "a window that truncates the PSF above --error is an error")
    p.add_argument("--error", type=float, default=1e-4, help="requested max abs error relative to the peak")
    p.add_argument("--out", default="psf_report", help="output directory (must be new or empty)")
    p.add_argument("--force", action="store_true", help="overwrite existing output")
    p.add_argument("--json", action="store_true", help="print the numbers as JSON")
    p.add_argument("--jobs", type=int, default=None,
                   help="processes, one lens each (default: min(2, lenses, CPUs))")
    p.set_defaults(func=run)
    return p


#: library parameter names -> the options they come from (errors name what the user typed)
_CLI_NAMES = {"band_um": "--band-um", "filter_um": "--filter-um", "pixel_pitch_um": "--pixel-um",
              "field_deg": "--field-deg", "error": "--error", "temperature_k": "--temperature-k",
              "n_wavelengths": "--wavelengths", "wavelength_um": "--wavelength-um"}
MAX_WAVELENGTHS = 2001


def _report_one(lens: Any, out: str, kw: dict[str, Any]) -> tuple[str, Any]:
    from metafovea.optics.report import psf_report

    try:
        res = psf_report(lens, out, **kw)
    except InputError as e:
        return "input_error", (e.parameter, e.value, e.allowed)
    return "ok", {k: res[k] for k in ("seconds", "monochromatic", "sensor", "warnings")}


def _check_weights(band: tuple[float, float], filt: tuple[float, float] | None, temperature_k: float) -> None:
    """The band, filter and scene temperature must give some light (clear errors before any work)."""
    import warnings

    import numpy as np

    from metafovea.radiometry import psf_wavelengths

    lo, hi = band
    if filt is not None and not (lo - 1.5 * filt[1] < filt[0] < hi + 1.5 * filt[1]):
        raise InputError("--filter-um", list(filt), f"a filter overlapping the band {lo:g}-{hi:g} um "
                         "(centre within 1.5 widths of it)")
    with warnings.catch_warnings(), np.errstate(over="ignore", under="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        try:
            psf_wavelengths(band, design_um=0.5 * (lo + hi), n=5, temperature_k=temperature_k, filter_um=filt)
        except InputError as e:
            if e.parameter != "band_um":
                raise
            raise InputError("--temperature-k", temperature_k, f"a scene temperature at which the scene emits in "
                             f"the band {lo:g}-{hi:g} um (its Planck radiance there underflows to 0)") from None


def run(args: argparse.Namespace) -> int:
    from metafovea.optics.pupil import EVANESCENT_MARGIN, max_field_deg
    from metafovea.radiometry import check_band

    band = check_band(args.band_um, "--band-um") if args.band_um is not None else (8.0, 14.0)
    filt = None
    if args.filter_um is not None:
        c = check_positive("--filter-um center", args.filter_um[0], "um")
        w = check_positive("--filter-um width", args.filter_um[1], "um")
        filt = (c, w)
    check_positive("--temperature-k", args.temperature_k, "K", hi=1e5)
    check_positive("--error", args.error, hi=0.5)
    check_positive("--pixel-um", args.pixel_um, "um", hi=1e4)
    check_int("--wavelengths", args.wavelengths, 1, MAX_WAVELENGTHS)
    _check_weights(band, filt, args.temperature_k)
    if args.wavelength_um is not None:
        check_positive("--wavelength-um", args.wavelength_um, "um", hi=1e4)
    if args.window_um is not None:
        check_positive("--window-um", args.window_um, "um")
    lenses = [load_lens(d) for d in args.designs]
    from metafovea.optics.report import file_stem
    seen: dict[str, str] = {}
    for d, lens in zip(args.designs, lenses):  # the report files are named after the lens
        if file_stem(lens.name) in seen:
            raise InputError("designs", d, f"lenses with distinct names: {seen[file_stem(lens.name)]} is also named "
                             f"'{lens.name}' (as a file name) and its report files would be overwritten "
                             "(change 'name' in one)")
        seen[file_stem(lens.name)] = d
    for lens in lenses:  # every field must lie inside each lens' field at the longest wavelength used
        wl_max = max(band[1] if filt is None else min(band[1], filt[0] + 1.5 * filt[1]),
                     args.wavelength_um or lens.wavelength_um)
        wl_lim = lens.wavelength_um * (1.0 - EVANESCENT_MARGIN) / lens.na
        if not wl_max < wl_lim:  # even on axis the rim's first order would be evanescent
            if args.wavelength_um is not None and args.wavelength_um >= wl_max:
                opt, val = "--wavelength-um", args.wavelength_um
            elif filt is not None:
                opt, val = "--filter-um", list(filt)
            else:
                opt, val = "--band-um", list(band)
            raise InputError(opt, val, f"wavelengths below {wl_lim:.4g} um for lens '{lens.name}' (NA {lens.na:.4f}, "
                             f"lambda0 {lens.wavelength_um:g} um): longer ones leave the rim of the lens evanescent")
        lim = max_field_deg(lens, wl_max)
        for fd in args.field_deg or []:
            if not abs(fd) <= lim:
                raise InputError("--field-deg", fd, f"|field| <= {lim:.3f} deg for lens '{lens.name}' "
                                 f"(NA {lens.na:.4f}) at {wl_max:g} um")
    jobs = check_int("--jobs", args.jobs, 1, 64) if args.jobs is not None else min(2, len(lenses), os.cpu_count() or 1)
    out = prepare_output(args.out, args.force, is_dir=True)
    kw = dict(fields_deg=args.field_deg, band_um=band, filter_um=filt, temperature_k=args.temperature_k,
              n_wavelengths=args.wavelengths, pixel_pitch_um=args.pixel_um, error=args.error,
              wavelength_um=args.wavelength_um, window_um=args.window_um)
    if jobs > 1 and len(lenses) > 1:
        # one process per lens (the report of a lens is single-threaded); errors come back as data
        # because InputError does not survive pickling
        from concurrent.futures import ProcessPoolExecutor
        with ProcessPoolExecutor(max_workers=min(jobs, len(lenses))) as ex:
            outcomes = list(ex.map(_report_one, lenses, [str(out)] * len(lenses), [kw] * len(lenses)))
    else:
        outcomes = [_report_one(lens, str(out), kw) for lens in lenses]
    summary = {}
    for lens, (kind, val) in zip(lenses, outcomes):
        if kind == "input_error":
            parameter, value, allowed = val
            if parameter == "window_um":
                allowed = allowed.replace("(pass allow_truncation=True to accept)", "(or a larger --error)")
                raise InputError("--window-um", args.window_um, allowed)
            if parameter == "wavelengths_um" and args.wavelength_um is not None:
                raise InputError("--wavelength-um", args.wavelength_um, allowed)
            raise InputError(_CLI_NAMES.get(parameter, parameter), value, allowed)
        res = val
        summary[lens.name] = {"seconds": res["seconds"], "monochromatic": res["monochromatic"],
                              "sensor": res["sensor"], "warnings": res["warnings"],
                              "html": str(Path(out) / f"{file_stem(lens.name)}_psf_report.html")}
    if args.json:
        print(to_json(summary))
    else:
        for name, s in summary.items():
            m0 = s["monochromatic"][0]
            print(f"{name}: on-axis {m0['engine']} (err {m0['error_estimate']:.1g}), "
                  f"{len(s['sensor'])} fields, {s['seconds']:.1f} s -> {s['html']}"
                  + (f"  [{len(set(s['warnings']))} warnings]" if s["warnings"] else ""))
    return 0


def register(subparsers: Any) -> None:
    add_parser(subparsers)

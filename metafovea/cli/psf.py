"""``metafovea psf DESIGN.toml ...``: PSF/MTF report (PNG, JSON, one HTML page) for one or more lenses, or both
lenses of a system file.

Prints, per lens and field, the key figures (Strehl ratio, focusing efficiency, FWHM, encircled energy within the
first dark ring and within one pixel), the camera's throughput and the whole run's time by stage; one line per
stage on stderr as it starts, and one summary warning for the results less accurate than ``--error``. Writes into
``--out`` or a new ``out/psf-<time>/``. Exit status: 0 on success, 2 on bad input (one line naming the option).
The pipeline and its rules (distinct lens names, wavelengths and fields each lens can take, worker processes) are
:func:`metafovea.optics.report.psf_reports`.
"""

from __future__ import annotations

import argparse
import time
import warnings
from typing import Any

from metafovea.cli.flags import flag_map, in_flags
from metafovea.cli.options import add_shared, alias, emit, progress, show_progress, workers_arg
from metafovea.cli.output import out_dir, stage_printer
from metafovea.errors import InputError, NotConvergedWarning, PhysicsWarning, check_int, check_positive
from metafovea.io import to_json


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser("psf", help="PSF/MTF report of metalens designs",
                              description="PSF, MTF, encircled energy and chromatic behaviour of lens designs; "
                                          "writes PNG figures, JSON numbers and a self-contained HTML page.")
    p.add_argument("designs", nargs="+", help="lens TOML files (e.g. designs/foveal.toml), or a system TOML "
                   "(designs/system.toml: both its lenses, with its sensor, relay and distances)")
    p.add_argument("--field-deg", type=float, nargs="+", default=None,
                   help="field angles in degrees (default: 9 points from 0 to the sensor corner / lens field)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--band-um", type=float, nargs=2, metavar=("LO", "HI"), default=None,
                   help="spectral band in um (default 8 14)")
    g.add_argument("--filter-um", type=float, nargs=2, metavar=("CENTER", "FWHM"), default=None,
                   help="narrow-band filter (Gaussian) centre and width in um")
    p.add_argument("--filter", default=None, choices=("on", "off"),
                   help="the system's narrow-band filter (10 um / 0.5 um in the paper's camera): on, or off (the "
                        "band; default)")
    p.add_argument("--temperature-k", type=float, default=300.0, help="scene temperature for Planck weights")
    p.add_argument("--wavelength-bins", type=int, default=61, help="wavelength bins across the band (geometric "
                   "around the design wavelength; metafovea.radiometry.psf_wavelengths)")
    alias(p, "--wavelengths", "--wavelength-bins", "wavelength_bins", type=int)
    add_shared(p, "--pixel-um", "--relay")
    p.add_argument("--system", default=None,
                   help="system TOML (e.g. designs/system.toml): sensor pitch, relay and the lens-to-sensor "
                        "distances of its two lenses (matched by lens name; default: the paper's camera)")
    add_shared(p, "--posts")
    p.add_argument("--wavelength-um", type=float, default=None,
                   help="wavelength of the monochromatic PSFs in um (default: the design wavelength)")
    p.add_argument("--window-um", type=float, default=None,
                   help="full width of the fine monochromatic PSF windows in um (default: sized from the rays); "
                        "a window that truncates the PSF above --error is an error")
    p.add_argument("--error", "--tolerance", dest="error", type=float, default=1e-4, action=_Typed,
                   help="the accuracy asked of every PSF: max abs error relative to the peak (default 1e-4; "
                        "--tolerance is the same): each PSF's engine and sampling are chosen for it, and the output "
                        "names them with their error estimates")
    p.add_argument("--out", default=None, help="output directory, new or empty (default: a new out/psf-<time>/)")
    add_shared(p, "--force", "--json", "--workers", "--scheduler")  # workers: one lens each
    alias(p, "--jobs", "--workers", "workers")
    p.set_defaults(func=run)
    return p


class _Typed(argparse.Action):
    """Stores the value and the spelling typed (``--error`` or ``--tolerance``), which an error then names."""

    def __call__(self, parser: Any, namespace: Any, values: Any, option_string: Any = None) -> None:
        setattr(namespace, self.dest, values)
        namespace.error_flag = option_string


#: most wavelength bins --wavelength-bins may ask for
MAX_WAVELENGTHS = 2001
#: most field angles --field-deg may list: each is an exact off-axis PSF and a sensor PSF over the band (seconds to
#: a minute each for the paper's lenses), so 64 fields are already an hour's work
MAX_FIELDS = 64


def _designs(paths: list[str], system_flag: str | None) -> tuple[list[Any], str | None]:
    """The lenses the design files name (a lens file stays a path: the report loads it) and the system file, when
    one of them is a system (both its lenses, as ``design`` takes it)."""
    from metafovea.config import LensDesign, SystemDesign, load_design

    lenses: list[Any] = []
    system_file = None
    for path in paths:
        d = load_design(path)
        if isinstance(d, SystemDesign):
            if system_flag is not None:
                raise InputError("--system", system_flag, f"no --system with a system file among the designs ({path} "
                                 "is the system: its lenses, sensor, relay and distances)")
            if system_file is not None:
                raise InputError("designs", path, f"one system file ({system_file} is one)")
            system_file = path
            lenses += [d.foveal, d.perifoveal]
        elif isinstance(d, LensDesign):
            lenses.append(path)
        else:
            raise InputError("designs", path, "a lens or system TOML (a platform file has no lens)")
    return lenses, system_file


def run(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    from metafovea.config import SystemDesign, load_system
    from metafovea.optics.report import psf_reports
    from metafovea.radiometry import check_band

    designs, system_file = _designs(args.designs, args.system)
    system_file = system_file or args.system
    band = check_band(args.band_um, "--band-um") if args.band_um is not None else (8.0, 14.0)
    filt = None
    if args.filter_um is not None:
        c = check_positive("--filter-um center", args.filter_um[0], "um")
        w = check_positive("--filter-um width", args.filter_um[1], "um")
        filt = (c, w)
    system = load_system(system_file) if system_file is not None else SystemDesign.paper()
    if args.filter == "on":
        if args.band_um is not None or args.filter_um is not None:
            raise InputError("--filter", "on", "not together with --band-um or --filter-um (the system's filter)")
        filt = (system.filter_center_um, system.filter_bandwidth_um)
    check_positive("--temperature-k", args.temperature_k, "K", hi=1e5)
    check_positive(getattr(args, "error_flag", "--error"), args.error, hi=0.5)
    pixel_um = (system.sensor.pixel_pitch_um if args.pixel_um is None else
                check_positive("--pixel-um", args.pixel_um, "um", hi=1e4))
    relay = system.relay_magnification if args.relay is None else check_positive("--relay", args.relay, hi=10.0)
    distances = ({system.foveal.name: system.lens_to_sensor_um[0], system.perifoveal.name: system.lens_to_sensor_um[1]}
                 if system_file is not None else None)
    check_int("--wavelength-bins", args.wavelength_bins, 1, MAX_WAVELENGTHS)
    if args.field_deg is not None and len(args.field_deg) > MAX_FIELDS:
        raise InputError("--field-deg", f"{len(args.field_deg)} angles", f"at most {MAX_FIELDS} angles (each is an "
                         "exact off-axis PSF and a sensor PSF over the band: seconds to a minute each)")
    if args.wavelength_um is not None:
        check_positive("--wavelength-um", args.wavelength_um, "um", hi=1e4)
    if args.window_um is not None:
        check_positive("--window-um", args.window_um, "um")
    jobs = workers_arg(args.workers)
    from metafovea.parallel import heartbeat

    with heartbeat("psf reports", enabled=show_progress(args)):  # minutes (a far-defocused sensor): a line per 10 s
        summary = psf_reports(designs, out_dir(args, "psf"), force=args.force, fields_deg=args.field_deg,
                              band_um=band, filter_um=filt, temperature_k=args.temperature_k,
                              n_wavelengths=args.wavelength_bins, pixel_pitch_um=pixel_um, error=args.error,
                              wavelength_um=args.wavelength_um, window_um=args.window_um, jobs=jobs,
                              relay_magnification=relay, distances_um=distances, progress=progress(args),
                              system=system, posts=args.posts, scheduler=args.scheduler,
                              say=stage_printer(args, "psf"))
    lenses = {k: v for k, v in summary.items() if k not in ("optical_train", "timing")}
    for name, s in lenses.items():  # each distinct one once, on one line (also those from worker processes)
        emit([f"{name}: {in_flags(w, flag_map('psf'))}" for w in s["warnings"]], PhysicsWarning)
        for item in s["accuracy"]:  # one summary line for all of them, naming this command's options
            warnings.warn(NotConvergedWarning(item["message"], item), stacklevel=1)
    summary["timing"]["seconds"]["total"] = time.perf_counter() - t0  # the whole run, start and checks included
    if args.json:
        print(to_json(summary))
        return 0
    from metafovea.optics.report import lens_lines, timing_line
    from metafovea.optics.train import throughput_lines

    for name, s in lenses.items():
        print("\n".join(lens_lines(name, s)))
    print("\n".join(throughput_lines(summary["optical_train"])))
    print(timing_line(summary["timing"]))
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    add_parser(subparsers)

"""``metafovea psf DESIGN.toml ...``: PSF/MTF report (PNG, JSON, one HTML page) for one or more lenses.

Exit status: 0 on success, 2 on bad input (one line naming the option). The pipeline and its rules (distinct lens
names, wavelengths and fields each lens can take, worker processes) are
:func:`metafovea.optics.report.psf_reports`.
"""

from __future__ import annotations

import argparse
from typing import Any

from metafovea.cli.options import alias, emit, progress
from metafovea.errors import InputError, PhysicsWarning, check_int, check_positive
from metafovea.io import to_json


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
    p.add_argument("--filter", default=None, choices=("on", "off"),
                   help="the system's narrow-band filter (10 um / 0.5 um in the paper's camera): on, or off (the "
                        "band; default)")
    p.add_argument("--temperature-k", type=float, default=300.0, help="scene temperature for Planck weights")
    p.add_argument("--wavelength-bins", type=int, default=61, help="wavelength bins across the band (geometric "
                   "around the design wavelength; metafovea.radiometry.psf_wavelengths)")
    alias(p, "--wavelengths", "--wavelength-bins", "wavelength_bins", type=int)
    p.add_argument("--pixel-um", type=float, default=None,
                   help="sensor pixel pitch in um (default: the system's, 17 um in the paper's camera)")
    p.add_argument("--relay", type=float, default=None,
                   help="relay magnification between the focal plane and the sensor (default: the system's, 0.5 in "
                        "the paper's camera: a 17 um pixel covers 34 um of the focal plane)")
    p.add_argument("--system", default=None,
                   help="system TOML (e.g. designs/system.toml): sensor pitch, relay and the lens-to-sensor "
                        "distances of its two lenses (matched by lens name; default: the paper's camera)")
    p.add_argument("--posts", default="rcwa", choices=("rcwa", "ideal"),
                   help="the lenses' posts: rcwa (the platform's RCWA post set for each lens' polarisation and "
                        "levels, library cached: the fabricated lens; default) or ideal (a simplified model)")
    p.add_argument("--wavelength-um", type=float, default=None,
                   help="wavelength of the monochromatic PSFs in um (default: the design wavelength)")
    p.add_argument("--window-um", type=float, default=None,
                   help="full width of the fine monochromatic PSF windows in um (default: sized from the rays); "
                        "a window that truncates the PSF above --error is an error")
    p.add_argument("--error", type=float, default=1e-4, help="requested max abs error relative to the peak")
    p.add_argument("--out", default="psf_report", help="output directory (must be new or empty)")
    p.add_argument("--force", action="store_true", help="overwrite existing output")
    p.add_argument("--json", action="store_true", help="print the numbers as JSON")
    p.add_argument("--workers", type=int, default=None,
                   help="processes, one lens each (default: min(2, lenses, CPUs))")
    alias(p, "--jobs", "--workers", "workers", type=int)
    p.add_argument("--scheduler", default=None,
                   help="Dask scheduler address (tcp://host:8786, or local:N for N local worker processes): the "
                        "sensor PSFs across the field of each lens are spread over the cluster (pip install "
                        "'metafovea[dask]')")
    p.set_defaults(func=run)
    return p


#: most wavelength bins --wavelength-bins may ask for
MAX_WAVELENGTHS = 2001
#: most field angles --field-deg may list: each is an exact off-axis PSF and a sensor PSF over the band (seconds to
#: a minute each for the paper's lenses), so 64 fields are already an hour's work
MAX_FIELDS = 64


def run(args: argparse.Namespace) -> int:
    from metafovea.config import SystemDesign, load_system
    from metafovea.optics.report import psf_reports
    from metafovea.radiometry import check_band

    band = check_band(args.band_um, "--band-um") if args.band_um is not None else (8.0, 14.0)
    filt = None
    if args.filter_um is not None:
        c = check_positive("--filter-um center", args.filter_um[0], "um")
        w = check_positive("--filter-um width", args.filter_um[1], "um")
        filt = (c, w)
    system = load_system(args.system) if args.system is not None else SystemDesign.paper()
    if args.filter == "on":
        if args.band_um is not None or args.filter_um is not None:
            raise InputError("--filter", "on", "not together with --band-um or --filter-um (the system's filter)")
        filt = (system.filter_center_um, system.filter_bandwidth_um)
    check_positive("--temperature-k", args.temperature_k, "K", hi=1e5)
    check_positive("--error", args.error, hi=0.5)
    pixel_um = system.sensor.pixel_pitch_um if args.pixel_um is None else check_positive("--pixel-um", args.pixel_um,
                                                                                         "um", hi=1e4)
    relay = system.relay_magnification if args.relay is None else check_positive("--relay", args.relay, hi=10.0)
    distances = ({system.foveal.name: system.lens_to_sensor_um[0], system.perifoveal.name: system.lens_to_sensor_um[1]}
                 if args.system is not None else None)
    check_int("--wavelength-bins", args.wavelength_bins, 1, MAX_WAVELENGTHS)
    if args.field_deg is not None and len(args.field_deg) > MAX_FIELDS:
        raise InputError("--field-deg", f"{len(args.field_deg)} angles", f"at most {MAX_FIELDS} angles (each is an "
                         "exact off-axis PSF and a sensor PSF over the band: seconds to a minute each)")
    if args.wavelength_um is not None:
        check_positive("--wavelength-um", args.wavelength_um, "um", hi=1e4)
    if args.window_um is not None:
        check_positive("--window-um", args.window_um, "um")
    jobs = check_int("--workers", args.workers, 1, 64) if args.workers is not None else None
    summary = psf_reports(args.designs, args.out, force=args.force, fields_deg=args.field_deg, band_um=band,
                          filter_um=filt, temperature_k=args.temperature_k, n_wavelengths=args.wavelength_bins,
                          pixel_pitch_um=pixel_um, error=args.error, wavelength_um=args.wavelength_um,
                          window_um=args.window_um, jobs=jobs, relay_magnification=relay, distances_um=distances,
                          progress=progress(args), system=system, posts=args.posts, scheduler=args.scheduler)
    for name, s in summary.items():  # each distinct one once, on one line (also those from worker processes)
        emit([f"{name}: {w}" for w in (s.get("warnings", ()) if name != "optical_train" else ())], PhysicsWarning)
    if args.json:
        print(to_json(summary))
    else:
        from metafovea.optics.train import throughput_lines

        trains = summary.pop("optical_train")
        for name, s in summary.items():
            m0 = s["monochromatic"][0]
            print(f"{name}: on-axis {m0['engine']} (err {m0['error_estimate']:.1g}), "
                  f"{len(s['sensor'])} fields, pixels {s['pixel_pitch_um']:.4g} um at the focal plane "
                  f"({pixel_um:g} um / {relay:g}x relay), sensor at {s['z_um'] / 1000:g} mm, "
                  f"{s['seconds']:.1f} s -> {s['html']}"
                  + (f"  [{len(set(s['warnings']))} warnings, on stderr]" if s["warnings"] else ""))
        print("\n".join(throughput_lines(trains)))
    return 0


def register(subparsers: Any) -> None:
    add_parser(subparsers)

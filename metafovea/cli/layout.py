"""``metafovea export`` and ``metafovea verify``: lens layouts to GDSII/OASIS (or a mesh) and back.

``export`` writes one file through :func:`metafovea.layout.export.export_file` (exit 0); ``verify`` reads it
back through :func:`metafovea.layout.verify.verify_layout` (exit 0 when it matches the design, 1 on any
mismatch). Both read the design (and post set) with :func:`metafovea.layout.tiling.load_spec`. Bad input is
an :class:`InputError` (exit 2, see :mod:`metafovea.cli`).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path
from typing import Any

from metafovea.cli.options import add_shared, check_out_suffix, progress, workers_arg
from metafovea.cli.output import out_file
from metafovea.errors import InputError, check_choice, check_range


def _patch(s: str | None):
    try:
        v = None if s is None else tuple(float(x) for x in s.split(","))
    except ValueError:
        v = ()
    if v is not None and len(v) != 3:
        raise InputError("--patch", s, "X,Y,W in mm (three numbers: patch centre and width)")
    return v


def _common(p: argparse.ArgumentParser, command: str) -> None:
    """The layout's options (design, post set, frame, patch), export's and verify's; the help is ``command``'s."""
    p.add_argument("--levels", type=int, default=None, help="phase levels N (default: the design's)")
    p.add_argument("--post-set", default=None, help="PostSet .npz (default: the platform's RCWA post set, see --posts)")
    add_shared(p, "--posts")  # without --post-set; ideal: an idealised width ramp, named in the label
    p.add_argument("--patch", default=None, metavar="X,Y,W",
                   help="only sites with centre in the square of width W around (X, Y), mm from the lens centre")
    p.add_argument("--grid-nm", type=int, default=5, help="manufacturing grid for positions and sizes (nm)")
    p.add_argument("--ring-width-um", type=float, default=1000.0, help="aluminium aperture ring width (um)")
    p.add_argument("--test-array", action="store_true", help="calibration layout: each post type in its own block")
    p.add_argument("--block", type=int, default=50, help="posts per side of a calibration block")
    add_shared(p, "--workers", "--scheduler", "--json")  # export: encoder threads and tiles on the cluster


def add_export_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("export", help="write the lens layout (GDSII/OASIS) or a patch mesh (STL/GLB)",
                              description="Stream a lens layout to GDSII or OASIS (1 nm database unit; lens "
                                          "centre at the positive offset written in the label; see "
                                          "gds_export/README.md).")
    p.add_argument("design", help="lens design TOML (designs/foveal.toml)")
    p.add_argument("--tiles-dir", default=None, help="with --scheduler: where the workers write their tiles, on a "
                   "file system the client and every worker share (default .<out>.tiles next to the output)")
    p.add_argument("--format", default=None, help="gds | oas | stl | glb (stl/glb need --patch; default: the --out "
                                                  "file's suffix, else gds)")
    p.add_argument("--flat", action="store_true", help="GDSII with one rectangle per post (no references)")
    p.add_argument("--out", default=None, help="output file, ending in the format's suffix: .gds/.gdsii, .oas/.oasis, "
                                               ".stl, .glb (default gds_export/<name>.<format>)")
    add_shared(p, "--force")
    p.add_argument("--no-resume", action="store_true", help="start over even if a partial export exists")
    p.add_argument("--compress", type=int, default=1, help="OASIS CBLOCK deflate level 0-9 (default 1)")
    p.add_argument("--band-rows", type=int, default=32,
                   help="site rows per task (each task writes these rows and their mirror rows)")
    p.add_argument("--max-refs", type=int, default=None, metavar="N",
                   help="GDSII: hierarchical, at most N elements per structure (Heidelberg DWL 66: 8192); "
                        "posts in leaf structures, intermediate structures, top cell")
    p.add_argument("--date", default=None, metavar="YYYY-MM-DD",
                   help="date in the labels (default: SOURCE_DATE_EPOCH if set, else today, UTC)")
    p.add_argument("--dwl", action="store_true",
                   help="GDSII for the Heidelberg DWL 66: posts as rectangles in one structure per band side, at "
                        "most 8192 structure definitions and 8192 references per structure")
    p.add_argument("--substrate-um", type=float, default=None, help="mesh substrate thickness (um)")
    _common(p, "export")
    p.set_defaults(func=run_export)
    return p


def add_verify_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("verify", help="read a layout back and compare it with the design",
                              description="Read FILE with an independent reader and compare post counts per "
                                          "type, post sizes, lattice positions, bounding boxes and layers with "
                                          "the design. Exit status 1 on any mismatch.")
    p.add_argument("file", help="GDSII or OASIS file")
    p.add_argument("--design", required=True, help="lens design TOML the file was exported from")
    p.add_argument("--reader", default="auto", help="auto | klayout | gdstk | stream (GDSII scanner)")
    p.add_argument("--max-refs", type=int, default=None, metavar="N",
                   help="also fail when a structure holds more than N elements (references and shapes)")
    p.add_argument("--dwl", action="store_true",
                   help="also fail beyond the Heidelberg DWL 66 limits (8192 structures, 8192 references each)")
    _common(p, "verify")
    p.set_defaults(func=run_verify)
    return p


def register(subparsers: Any) -> None:
    add_export_parser(subparsers)
    add_verify_parser(subparsers)


def _inputs(args, design_path: str):
    """The layout spec and (``--test-array``) the calibration array the flags describe."""
    from metafovea.layout.export import TestArraySpec
    from metafovea.layout.tiling import load_spec

    if args.test_array and args.patch:
        raise InputError("--patch", args.patch, "not together with --test-array")
    from metafovea.layout.frame import layout_date

    spec = load_spec(design_path, args.post_set, args.levels, grid_nm=args.grid_nm, patch_mm=_patch(args.patch),
                     band_rows=getattr(args, "band_rows", 32), ring_width_um=args.ring_width_um, posts=args.posts,
                     date=layout_date(getattr(args, "date", None)))
    return spec, (TestArraySpec(spec, block=args.block) if args.test_array else None)


def _format(args) -> str:
    """--format, or the --out file's suffix; an --out of another suffix is an error (it is never renamed)."""
    from metafovea.layout.export import SUFFIXES

    fmt = args.format
    if fmt is None:
        suffix = Path(args.out).suffix.lower() if args.out else ""
        fmt = next((f for f, sx in SUFFIXES.items() if suffix in sx), "gds")
    fmt = check_choice("--format", fmt, tuple(SUFFIXES))
    if args.out and not Path(args.out).suffix:  # no suffix: added, and said (a wrong one is an error)
        warnings.warn(f"--out {args.out} has no layout suffix: writing {args.out}.{fmt}", UserWarning, stacklevel=2)
    else:
        check_out_suffix(args.out, SUFFIXES[fmt], f"--format {fmt}")
    return fmt


def run_export(args) -> int:
    from metafovea.layout.export import FORMATS, ExportOptions, export_file, output_path, size_notice

    fmt = _format(args)
    if args.substrate_um is not None:  # checked whatever the format (a layout format has no use for it: said)
        check_range("--substrate-um", args.substrate_um, 0.0, 1e5, unit="um", lo_inclusive=True)
        if fmt in FORMATS:
            warnings.warn(f"--substrate-um is the STL/GLB patch mesh's substrate: --format {fmt} has none (ignored)",
                          UserWarning, stacklevel=2)
    spec, ta = _inputs(args, args.design)
    out = out_file(args, None)
    opt = ExportOptions(flat=args.flat, max_refs=args.max_refs, dwl=args.dwl, compress=args.compress, force=args.force,
                        resume=not args.no_resume, workers=workers_arg(args.workers), scheduler=args.scheduler,
                        tiles_dir=args.tiles_dir, progress=progress(args))
    dest = output_path(spec, fmt, out, flat=opt.flat, max_refs=opt.max_refs, dwl=opt.dwl) if fmt in FORMATS else out
    if dest is not None and args.design and Path(dest).resolve() == Path(args.design).resolve():  # --force too
        raise InputError("--out", str(dest), f"a path other than the design {args.design} (it would be overwritten)")
    notice = None if fmt not in FORMATS or ta is not None or args.quiet else size_notice(
        spec, output_path(spec, fmt, out, flat=opt.flat, max_refs=opt.max_refs, dwl=opt.dwl), fmt, opt)
    if notice:  # a multi-GB file is announced before its write starts
        print(f"metafovea export: {notice}", file=sys.stderr)
    res = export_file(spec, out, fmt, opt, test_array=ta, substrate_thickness_um=args.substrate_um)
    if args.json:
        from metafovea.io import to_json
        print(to_json(res))
    elif "posts_per_s" in res:
        print(f"wrote {res['path']}: {res['posts']:,} posts, {res['bytes']:,} bytes, {res['seconds']:.2f} s"
              + (f" (resumed after {res['resumed_bands']} bands)" if res.get("resumed_bands") else ""))
        print(f"  posts: {spec.post_set.source} post set, widths (um) "
              + " ".join(f"{a:.2f}x{b:.2f}" for a, b in spec.post_set.widths_um)
              + ("  [idealised ramp, not a physical design]" if spec.post_set.source == "ideal" else ""))
        from metafovea.layout.tiling import drc_line
        print("  " + drc_line(res["drc"]))
        extra = res.get("extra") or {}
        if extra.get("printed_label"):
            print(f"  printed label: {extra['printed_label']}")
            print(f"  {extra['tone']}")
    else:
        print(f"wrote {res['path']}: {res['triangles']:,} triangles, {res['bytes']:,} bytes")
    return 0


def run_verify(args) -> int:
    from metafovea.layout.verify import verify_layout

    spec, ta = _inputs(args, args.design)
    rep = verify_layout(args.file, spec, reader=args.reader, test_array=ta,
                        workers=workers_arg(args.workers), scheduler=args.scheduler,
                        progress=progress(args), max_refs=args.max_refs, dwl=args.dwl)
    from metafovea.cli.flags import flag_map, in_flags
    mismatches = [in_flags(m, flag_map("verify")) for m in rep.mismatches]  # the flags for the parameters they name
    if args.json:
        from metafovea.io import to_json
        print(to_json({**rep.as_dict(), "mismatches": mismatches}))
    else:
        status = "OK" if rep.ok else "MISMATCH"
        print(f"{status}: {rep.file} ({rep.format}, read by {rep.reader} in {rep.seconds_read:.1f} s): "
              f"{rep.posts:,} posts, expected {rep.expected_posts:,}")
        if rep.drc is not None:
            from metafovea.layout.tiling import drc_line
            print("  " + drc_line(rep.drc))
        for m in mismatches:
            print(f"  - {m}", file=sys.stderr)
    return 0 if rep.ok else 1

"""``metafovea export`` and ``metafovea verify``: lens layouts to GDSII/OASIS (or a mesh) and back.

Wired into :mod:`metafovea.cli` by ``add_export_parser`` / ``add_verify_parser``; each ``run_*``
returns the exit status (verify: 1 on any mismatch) and raises :class:`InputError` for bad input.
"""

from __future__ import annotations

from typing import Any

import argparse
import os
import sys
from pathlib import Path

from metafovea.errors import InputError

DEFAULT_DIR = Path("gds_export")


def _patch(s: str | None):
    if s is None:
        return None
    try:
        v = tuple(float(x) for x in s.split(","))
    except ValueError:
        raise InputError("--patch", s, "X,Y,W in mm (three numbers: patch centre and width)") from None
    if len(v) != 3:
        raise InputError("--patch", s, "X,Y,W in mm (three numbers: patch centre and width)")
    return v


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--levels", type=int, default=None, help="phase levels N (default: the design's)")
    p.add_argument("--post-set", default=None, help="PostSet .npz (default: ideal N-level post set)")
    p.add_argument("--patch", default=None, metavar="X,Y,W",
                   help="only sites with centre in the square of width W around (X, Y), mm from the lens centre")
    p.add_argument("--grid-nm", type=int, default=5, help="manufacturing grid for positions and sizes (nm)")
    p.add_argument("--ring-width-um", type=float, default=1000.0, help="aluminium aperture ring width (um)")
    p.add_argument("--test-array", action="store_true", help="calibration layout: each post type in its own block")
    p.add_argument("--block", type=int, default=50, help="posts per side of a calibration block")
    p.add_argument("--workers", type=int, default=None,
                   help="export: encoder threads (default 2, at most the CPU count); verify: processes for "
                        "the expected counts (default 1)")
    p.add_argument("--scheduler", default=None, help="Dask scheduler address (tcp://host:8786)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def add_export_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("export", help="write the lens layout (GDSII/OASIS) or a patch mesh (STL/GLB)",
                              description="Stream a lens layout to GDSII or OASIS (1 nm database unit; lens "
                                          "centre at the positive offset written in the label; see "
                                          "gds_export/README.md).")
    p.add_argument("design", help="lens design TOML (designs/foveal.toml)")
    p.add_argument("--format", default="gds", help="gds | oas | stl | glb (stl/glb need --patch)")
    p.add_argument("--flat", action="store_true", help="GDSII with one rectangle per post (no references)")
    p.add_argument("--out", default=None, help="output file (default gds_export/<name>.<format>)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    p.add_argument("--no-resume", action="store_true", help="start over even if a partial export exists")
    p.add_argument("--compress", type=int, default=1, help="OASIS CBLOCK deflate level 0-9 (default 1)")
    p.add_argument("--band-rows", type=int, default=32,
                   help="site rows per task (each task writes these rows and their mirror rows)")
    p.add_argument("--max-refs", type=int, default=None, metavar="N",
                   help="GDSII: hierarchical, at most N elements per structure (Heidelberg DWL 66: 8192); "
                        "posts in leaf structures, intermediate structures, top cell")
    p.add_argument("--substrate-um", type=float, default=None, help="mesh substrate thickness (um)")
    _common(p)
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
    _common(p)
    p.set_defaults(func=run_verify)
    return p


def _spec(args, design_path: str):
    from metafovea.config import LensDesign, load_design
    from metafovea.layout.tiling import make_spec
    from metafovea.library import PostSet

    d = load_design(design_path)
    if not isinstance(d, LensDesign):
        raise InputError("design", design_path, "a lens design file (with f_mm, diameter_mm, ...)")
    ps = None
    if args.post_set:
        try:
            ps = PostSet.load(args.post_set)
        except InputError as e:
            raise InputError("--post-set", args.post_set, e.allowed, detail=str(e).partition("allowed: ")[2]
                             .removeprefix(e.allowed).strip(" ()") or None) from None
        if args.levels is not None and args.levels != ps.levels:
            raise InputError("--levels", args.levels, f"the number of posts in {args.post_set} ({ps.levels})")
        if ps.polarization != d.polarization:
            raise InputError("--post-set", args.post_set, f"a post set for polarisation {d.polarization!r}")
    levels = args.levels if args.levels is not None else (ps.levels if ps is not None else None)
    if args.test_array and args.patch:
        raise InputError("--patch", args.patch, "not together with --test-array")
    return make_spec(d, ps, levels, grid_nm=args.grid_nm, patch_mm=_patch(args.patch),
                     band_rows=getattr(args, "band_rows", 32), ring_width_um=args.ring_width_um)


def _test_array(args, spec):
    from metafovea.errors import check_int
    from metafovea.layout.export import TestArraySpec

    return TestArraySpec(spec, block=check_int("--block", args.block, 1, 4096))


def run_export(args) -> int:
    from metafovea.layout.export import export_layout, export_test_array
    from metafovea.layout.mesh import MESH_FORMATS, export_mesh

    fmt = str(args.format).lower()
    if fmt not in ("gds", "oas") + MESH_FORMATS:
        raise InputError("--format", args.format, "one of 'gds', 'oas', 'stl', 'glb'")
    spec = _spec(args, args.design)
    stem = "".join(ch if (ch.isalnum() or ch in "-_.") else "_" for ch in spec.design.name).lstrip(".") or "lens"
    name = stem + ("_cal" if args.test_array else "") + ("_patch" if spec.patch_um else "") + \
        ("_flat" if args.flat else "") + (f"_h{args.max_refs}" if args.max_refs else "")
    out = Path(args.out) if args.out else DEFAULT_DIR / name
    suffixes = {"gds": (".gds", ".gdsii"), "oas": (".oas", ".oasis"), "stl": (".stl",), "glb": (".glb",)}
    known = tuple(x for v in suffixes.values() for x in v)
    if out.suffix.lower() not in known:
        out = out.with_name(out.name + "." + fmt)
    elif out.suffix.lower() not in suffixes[fmt]:
        # a .oas name with GDSII inside (or the reverse) would mislead every tool that trusts the suffix
        raise InputError("--out", str(out), f"a file name ending in {' or '.join(suffixes[fmt])} for --format {fmt} "
                         "(or no suffix: it is added)")
    if args.max_refs is not None and (fmt != "gds" or args.test_array):
        raise InputError("--max-refs", args.max_refs, "only with --format gds for a lens (not --test-array)")
    if fmt in MESH_FORMATS:
        if args.flat or args.test_array:
            raise InputError("--format", fmt, "gds or oas with --flat/--test-array")
        res = export_mesh(spec, out, fmt, force=args.force, substrate_thickness_um=args.substrate_um)
    elif args.test_array:
        res = export_test_array(_test_array(args, spec), out, fmt, flat=args.flat, force=args.force).as_dict()
    else:
        if not 0 <= args.compress <= 9:
            raise InputError("--compress", args.compress, "an integer 0..9")
        if args.workers is not None and args.workers < 1:
            raise InputError("--workers", args.workers, "an integer >= 1")
        workers = args.workers if args.workers is not None else max(1, min(2, os.cpu_count() or 1))
        res = export_layout(spec, out, fmt, flat=args.flat, force=args.force, resume=not args.no_resume,
                            workers=workers, scheduler=args.scheduler, progress=not (args.quiet or args.json),
                            compress=args.compress, max_refs=args.max_refs).as_dict()
    if args.json:
        from metafovea.io import to_json
        print(to_json(res))
    else:
        if "posts_per_s" in res:
            print(f"wrote {res['path']}: {res['posts']:,} posts, {res['bytes']:,} bytes, {res['seconds']:.2f} s"
                  + (f" (resumed after {res['resumed_bands']} bands)" if res.get("resumed_bands") else ""))
        else:
            print(f"wrote {res['path']}: {res['triangles']:,} triangles, {res['bytes']:,} bytes")
    return 0


def run_verify(args) -> int:
    from metafovea.layout.verify import verify_layout

    spec = _spec(args, args.design)
    ta = _test_array(args, spec) if args.test_array else None
    if args.workers is not None and args.workers < 1:
        raise InputError("--workers", args.workers, "an integer >= 1")
    if args.max_refs is not None and args.max_refs < 1:
        raise InputError("--max-refs", args.max_refs, "an integer >= 1")
    rep = verify_layout(args.file, spec, reader=args.reader, test_array=ta, workers=args.workers or 1,
                        progress=not (args.quiet or args.json), max_refs=args.max_refs)
    if args.json:
        from metafovea.io import to_json
        print(to_json(rep.as_dict()))
    else:
        status = "OK" if rep.ok else "MISMATCH"
        print(f"{status}: {rep.file} ({rep.format}, read by {rep.reader} in {rep.seconds_read:.1f} s): "
              f"{rep.posts:,} posts, expected {rep.expected_posts:,}")
        for m in rep.mismatches:
            print(f"  - {m}", file=sys.stderr)
    return 0 if rep.ok else 1


def main(argv=None) -> int:
    """Stand-alone entry (``python -m metafovea.cli_layout export|verify ...``) until cli.py wires these."""
    p = argparse.ArgumentParser(prog="metafovea")
    sub = p.add_subparsers(dest="cmd", required=True)
    add_export_parser(sub)
    add_verify_parser(sub)
    args = p.parse_args(argv)
    try:
        return args.func(args)
    except InputError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())


def register(subparsers: Any) -> None:
    add_export_parser(subparsers)
    add_verify_parser(subparsers)

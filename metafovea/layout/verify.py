"""Read an exported layout back with an independent reader and compare it with the design.

:func:`verify_layout` picks a reader from :mod:`metafovea.layout.read` (``auto``: KLayout for GDSII up to
:data:`STREAM_THRESHOLD_BYTES` and OASIS under 16 MiB, the streaming scanner for larger GDSII, gdstk for larger
OASIS), computes the :class:`~metafovea.layout.tiling.Expected` content from the design (or the calibration
array) and :func:`compare` s the two into a :class:`VerifyReport`.

Checks: one top cell with the expected name; database unit 1 nm; each post cell holds exactly one
rectangle on the posts layer of the expected size, centred at the cell origin; posts per type equal
the design's counts; post by post (:class:`SiteCheck`): every post on a lattice site inside the aperture, of the
type the design gives that site, no site taken twice and none left empty; bounding box of the posts and (full
lens) of the whole layout; the set of layers used; with ``max_refs``, the elements per structure.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.errors import InputError, check_choice
from metafovea.layout.frame import expected_frame, expected_frame_moments, frame_bbox_nm
from metafovea.layout.read import Observed, lattice_of, read_gdstk, read_klayout, read_stream, sniff_format
from metafovea.layout.tiling import DBU_UM, Expected, LayoutSpec, drc_line, drc_summary, expected_content, has_frame

READERS = ("auto", "klayout", "gdstk", "stream")
STREAM_THRESHOLD_BYTES = 256 << 20


@dataclass
class VerifyReport:
    ok: bool
    file: str
    reader: str
    format: str
    posts: int
    expected_posts: int
    counts: list[int]
    expected_counts: list[int]
    posts_bbox_nm: Any
    expected_posts_bbox_nm: Any
    bbox_nm: Any
    layers: list[list[int]]
    mismatches: list[str]
    seconds_read: float
    seconds_expected: float
    file_bytes: int
    structures: int = 0
    max_elements_per_structure: int = 0
    sites: dict[str, int] | None = None  #: the post-by-post check's counts (SiteCheck), None when not run
    drc: dict[str, Any] | None = None  #: the post cells read against the platform's rules (tiling.drc_summary)

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


class SiteCheck:
    """Post-by-post comparison with the design: the readers hand over every post they find (absolute centre in
    nm and type index, -1 for a cell or size that is no post type) and each is checked against its lattice site.

    Per post: on a lattice site, inside the aperture (and the patch), its type the level the design gives that
    site (:func:`metafovea.lens.quantize_phase` of the design phase at the site), and the site not taken yet
    (an occupancy bitmap over the site index box: 44 MB for the 75 mm lens). :meth:`mismatches` adds the sites
    the file leaves empty. Memory and time are linear in the posts handed over, in chunks.
    """

    EXAMPLES = 3

    def __init__(self, spec: LayoutSpec):
        from metafovea.lens import site_index_range

        self.spec = spec
        d = spec.design
        self.P = spec.period_nm
        self.C = spec.centre_nm
        self.o = 0 if d.lattice == "integer" else self.P // 2
        self.lo, self.hi = site_index_range(d)
        self.n = self.hi - self.lo + 1
        self.bits = np.zeros((self.n * self.n + 7) // 8, dtype=np.uint8)
        self.window = spec.window()
        from metafovea.lens import row_half_counts

        # each row's aperture columns, once (exact arithmetic per row)
        self.row_lo, self.row_hi = row_half_counts(d, np.arange(self.lo, self.hi + 1))
        self.counts = {"posts": 0, "sites": 0, "off_lattice": 0, "outside": 0, "wrong_type": 0, "unknown_type": 0,
                       "duplicates": 0}
        self.examples: dict[str, list[str]] = {k: [] for k in self.counts}
        self._buf: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._nbuf = 0

    def _example(self, kind: str, x: np.ndarray, y: np.ndarray, what: str = "") -> None:
        ex = self.examples[kind]
        for xi, yi in zip(x[: self.EXAMPLES - len(ex)].tolist(), y[: self.EXAMPLES - len(ex)].tolist()):
            ex.append(f"({(xi - self.C) / 1000:.3f}, {(yi - self.C) / 1000:.3f}) um{what}")

    #: posts buffered before a check (readers hand over one reference at a time in hierarchical files)
    CHUNK = 1 << 20

    def __call__(self, x_nm: np.ndarray, y_nm: np.ndarray, kind: np.ndarray) -> None:
        self._buf.append((np.asarray(x_nm, dtype=np.int64).ravel(), np.asarray(y_nm, dtype=np.int64).ravel(),
                          np.asarray(kind, dtype=np.int64).ravel()))
        self._nbuf += self._buf[-1][0].size
        if self._nbuf >= self.CHUNK:
            self._flush()

    def _flush(self) -> None:
        if self._buf:
            x, y, k = (np.concatenate(v) for v in zip(*self._buf))
            self._buf, self._nbuf = [], 0
            self._check(x, y, k)

    def _check(self, x: np.ndarray, y: np.ndarray, k: np.ndarray) -> None:
        from metafovea.lens import design_phase, quantize_phase, site_positions_um

        c = self.counts
        c["posts"] += x.size
        unk = k < 0
        if unk.any():
            c["unknown_type"] += int(unk.sum())
            self._example("unknown_type", x[unk], y[unk])
        ux, uy = x - self.C - self.o, y - self.C - self.o
        on = (ux % self.P == 0) & (uy % self.P == 0)
        if not on.all():
            c["off_lattice"] += int((~on).sum())
            self._example("off_lattice", x[~on], y[~on])
        x, y, k, ix, iy = x[on], y[on], k[on], ux[on] // self.P, uy[on] // self.P
        iy_lo, iy_hi, ix_lo, ix_hi = self.window
        inside = (iy >= iy_lo) & (iy <= iy_hi) & (ix >= ix_lo) & (ix <= ix_hi)
        if inside.any():
            r = np.clip(iy, self.lo, self.hi) - self.lo
            inside &= (ix >= self.row_lo[r]) & (ix <= self.row_hi[r])
        if not inside.all():
            c["outside"] += int((~inside).sum())
            self._example("outside", x[~inside], y[~inside])
        x, y, k, ix, iy = x[inside], y[inside], k[inside], ix[inside], iy[inside]
        if x.size == 0:
            return
        # the site's level from the design
        xs, ys = site_positions_um(self.spec.design, ix, iy)
        want = quantize_phase(design_phase(self.spec.design, xs, ys), self.spec.levels)
        wrong = (k >= 0) & (k != want)
        if wrong.any():
            c["wrong_type"] += int(wrong.sum())
            w = np.flatnonzero(wrong)[: self.EXAMPLES]
            for i in w.tolist():
                if len(self.examples["wrong_type"]) < self.EXAMPLES:
                    self.examples["wrong_type"].append(
                        f"({(int(x[i]) - self.C) / 1000:.3f}, {(int(y[i]) - self.C) / 1000:.3f}) um: "
                        f"{self.spec.post_names[int(k[i])]}, the design has {self.spec.post_names[int(want[i])]}")
        # occupancy: a site taken twice (within this chunk or by an earlier one) is a duplicate
        f = (iy - self.lo) * self.n + (ix - self.lo)
        order = np.argsort(f, kind="stable")
        fs = f[order]
        first = np.concatenate([[True], fs[1:] != fs[:-1]])
        dup_in = ~first
        byte, bit = fs >> 3, (np.uint8(1) << (fs & 7).astype(np.uint8))
        taken = (self.bits[byte] & bit) != 0
        dup = dup_in | taken
        if dup.any():
            c["duplicates"] += int(dup.sum())
            self._example("duplicates", x[order][dup], y[order][dup])
        new = first & ~taken
        fn = fs[new]
        bn, bb = fn >> 3, (np.uint8(1) << (fn & 7).astype(np.uint8))
        if bn.size:
            starts = np.flatnonzero(np.concatenate([[True], bn[1:] != bn[:-1]]))
            self.bits[bn[starts]] |= np.bitwise_or.reduceat(bb, starts)
        c["sites"] += int(new.sum())

    def mismatches(self, expected_total: int) -> list[str]:
        """One sentence per kind of error found, with up to three example positions (um from the lens centre)."""
        self._flush()
        c, ex = self.counts, self.examples
        out = []
        texts = {"off_lattice": "posts off their lattice site", "outside": "posts outside the aperture or patch",
                 "wrong_type": "posts of the wrong type for their site", "unknown_type": "posts of no post type",
                 "duplicates": "posts on a site already taken (duplicates)"}
        for key, text in texts.items():
            if c[key]:
                out.append(f"{c[key]:,} {text}, e.g. " + "; ".join(ex[key]))
        missing = expected_total - c["sites"]
        if missing > 0:
            out.append(f"{missing:,} of the design's {expected_total:,} sites hold no post")
        return out

    def summary(self) -> dict[str, Any]:
        self._flush()
        return dict(self.counts)


def compare(ob: Observed, spec: LayoutSpec, exp: Expected, *, top_name: str | None = None,
            frame: bool | None = None, expected_layers: set | None = None) -> tuple[list[str], np.ndarray]:
    """Mismatches between what was read and what the design implies, and the counts per type."""
    mm: list[str] = []
    top_name = top_name or spec.top_name
    frame = has_frame(spec) if frame is None else frame
    if abs(ob.dbu_um - DBU_UM) > 1e-12:
        mm.append(f"database unit {ob.dbu_um:g} um, expected 0.001 um (1 nm)")
    tops = [t for t in ob.top_cells if t not in spec.post_names]  # an unused post cell of a small lens is harmless
    if tops != [top_name]:
        mm.append(f"top cells {ob.top_cells}, expected exactly one named {top_name!r}")
    sizes = spec.post_sizes_nm
    names = spec.post_names
    counts = np.zeros(spec.levels, dtype=np.int64)
    hier = bool(ob.ref_counts)
    if hier:
        for nm, n in ob.ref_counts.items():
            if nm not in names:
                mm.append(f"{n} references to an unexpected cell {nm!r}")
                continue
            k = names.index(nm)
            counts[k] += n
            rects = ob.cell_rects.get(nm, [])
            want = (spec.layers.posts[0], spec.layers.posts[1], int(sizes[k, 0]), int(sizes[k, 1]), 0, 0)
            if [tuple(int(v) for v in r) for r in rects] != [want]:
                mm.append(f"post cell {nm}: shapes {rects}, expected one rectangle {want[2]}x{want[3]} nm "
                          f"on layer {want[0]}/{want[1]} centred at the origin")
    if ob.flat_counts:
        if hier:
            mm.append("both references and flat rectangles on the posts layer in the top cell")
        lookup = {(int(w), int(h)): k for k, (w, h) in enumerate(sizes.tolist())}
        if len(lookup) != spec.levels:
            mm.append("two post types have the same size: flat counts per type are ambiguous")
        for wh, n in ob.flat_counts.items():
            k = lookup.get((int(wh[0]), int(wh[1])))
            if k is None:
                mm.append(f"{n} posts of unexpected size {wh[0]}x{wh[1]} nm")
            else:
                counts[k] += n
    for k in range(spec.levels):
        if counts[k] != exp.counts[k]:
            mm.append(f"{names[k]}: {counts[k]:,} posts, expected {exp.counts[k]:,}")
    if ob.off_lattice:
        mm.append(f"{ob.off_lattice:,} posts off the lattice")
    if ob.posts_bbox != (None if exp.posts_bbox_nm is None else tuple(exp.posts_bbox_nm)):
        mm.append(f"posts bounding box {ob.posts_bbox} nm, expected {exp.posts_bbox_nm}")
    if frame:
        fb = frame_bbox_nm(spec)
        if ob.bbox != fb:
            mm.append(f"layout bounding box {ob.bbox} nm, expected {fb} (the wafer outline)")
        mm += frame_mismatches(ob, spec)
    if ob.bbox is not None and min(ob.bbox[:2]) < 0:
        mm.append(f"negative coordinates in the layout bounding box {ob.bbox}")
    L = spec.layers
    if expected_layers is None:
        expected_layers = {L.posts, L.label} | (set(expected_frame(spec)) if frame else set())
    if set(ob.layers) != set(expected_layers):
        mm.append(f"layers {sorted(ob.layers)}, expected {sorted(expected_layers)}")
    mm += ob.anomalies[:20]
    return mm, counts


def frame_mismatches(ob: Observed, spec: LayoutSpec) -> list[str]:
    """The frame layers as read (polygons and bounding box per layer, top cell through the hierarchy) against the
    frame the design implies (:func:`metafovea.layout.frame.expected_frame`): a missing, extra or moved ring
    sector, mark, vernier bar, label glyph, die or wafer outline piece. Skipped (with no sentence) by a reader that
    does not report per-layer shapes."""
    if ob.frame_layers is None:
        return []
    names = {v: k for k, v in vars(spec.layers).items()}
    moms = expected_frame_moments(spec) if ob.frame_moments is not None else {}
    out = []
    for lay, (n, bb) in expected_frame(spec).items():
        got = ob.frame_layers.get(lay)
        if got is None:
            out.append(f"layer {lay[0]}/{lay[1]} ({names.get(lay, '?')}): missing, expected {n} polygons")
        elif (got[0], tuple(got[1])) != (n, bb):
            out.append(f"layer {lay[0]}/{lay[1]} ({names.get(lay, '?')}): {got[0]} polygons in {tuple(got[1])} nm, "
                       f"expected {n} in {bb}")
        elif ob.frame_moments is not None and lay in moms:
            bad = moment_mismatch(ob.frame_moments.get(lay), moms[lay])
            if bad:
                out.append(f"layer {lay[0]}/{lay[1]} ({names.get(lay, '?')}): {bad}")
    return out


#: the frame's area moments as read against the design's: relative area, and centroid shift in nm. The vertices
#: are integers in nm on both sides (the layout's grid), so only the floating-point sums differ (~1e-12 relative,
#: ~1e-3 nm far from the origin); a mark of a quarter of its layer's area moved by 1 nm shifts the centroid 0.25 nm
FRAME_AREA_RTOL = 1e-9
FRAME_CENTROID_NM = 0.1


def moment_mismatch(got: Any, want: tuple[float, float, float]) -> str | None:
    """What differs between a layer's moments as read (``(A, Sx, Sy)`` or None) and as designed, as a sentence, or
    None when they agree within :data:`FRAME_AREA_RTOL` and :data:`FRAME_CENTROID_NM`."""
    if got is None:
        return None
    a, sx, sy = (float(v) for v in got)
    wa, wx, wy = want
    if not abs(a - wa) <= FRAME_AREA_RTOL * abs(wa) + 1.0:
        return f"polygons of {a:.10g} nm^2 in all, expected {wa:.10g}: a shape resized, added or removed"
    cx, cy, wcx, wcy = sx / a, sy / a, wx / wa, wy / wa
    if max(abs(cx - wcx), abs(cy - wcy)) > FRAME_CENTROID_NM:
        return (f"the polygons' centroid at ({cx:.1f}, {cy:.1f}) nm, expected ({wcx:.1f}, {wcy:.1f}): a shape moved "
                "inside the layer's bounding box")
    return None


def choose_reader(reader: str, fmt: str, size: int) -> str:
    """The reader ``'auto'`` stands for, for a ``fmt`` file of ``size`` bytes (any other name unchanged)."""
    if reader != "auto":
        return reader
    if fmt == "gds":
        return "stream" if size > STREAM_THRESHOLD_BYTES else "klayout"
    return "klayout" if size < (16 << 20) else "gdstk"


#: the GDSII end-of-library record (length 4, ENDLIB, no data)
ENDLIB = b"\x00\x04\x04\x00"


def trailing_bytes(path: Path, span: int = 1 << 20) -> list[str]:
    """The mismatch for bytes after a GDSII file's last ENDLIB record that are not zero padding (tape-block padding
    to 2048 bytes is zeros; anything else was appended), read from the file's last ``span`` bytes; none when the
    file ends as written (or holds no ENDLIB there: the readers report a truncated file)."""
    size = path.stat().st_size
    with open(path, "rb") as fh:
        fh.seek(max(0, size - span))
        tail = fh.read()
    end = tail.rfind(ENDLIB)
    if end < 0:
        return []
    rest = tail[end + len(ENDLIB):]
    junk = len(rest) - rest.count(0)
    return [f"{len(rest):,} bytes after the library's end record (ENDLIB), {junk:,} of them not zero padding: "
            "appended to the file"] if junk else []


def label_spec(path: Path, spec: LayoutSpec) -> tuple[LayoutSpec, list[str]]:
    """``spec`` as the file's text label completes it (its date, which the printed label shows, and the patch when
    ``spec`` has none), and the mismatches the label shows: no label, a patch other than ``spec``'s, a content
    hash other than the design's (another design, post set, frame or pre-bias)."""
    from dataclasses import replace

    from metafovea.layout.frame import content_hash, parse_label
    from metafovea.layout.read.base import read_label

    text = read_label(path)
    if text is None:
        return spec, ["no metafovea text label (layer 10) in the file's first or last 4 MiB"]
    lab = parse_label(text)
    mm = []
    if lab["date"]:
        spec = replace(spec, date=lab["date"])
    if lab["patch_um"] is not None and spec.patch_um is None:
        spec = replace(spec, patch_um=lab["patch_um"])
    elif spec.patch_um is not None and (lab["patch_um"] is None
                                        or not np.allclose(lab["patch_um"], spec.patch_um, rtol=0, atol=1e-3)):
        mm.append(f"the label's patch {lab['patch_um']} um, expected {spec.patch_um} um (patch_mm=...)")
    if lab["hash"] != content_hash(spec):
        mm.append(f"the label's content hash {lab['hash']}, the design gives {content_hash(spec)} (another design, "
                  "post set, frame or write bias)")
    if not mm:  # the hash fits: every other word of the label must be the design's too (an edited f=, D=, ...)
        want = (replace(spec, patch_um=lab["patch_um"]) if lab["patch_um"] is not None else spec).label_text()
        got_words, want_words = text.strip().split(" "), want.strip().split(" ")
        if got_words != want_words:
            diff = [w for w in got_words if w not in want_words][:3]
            mm.append(f"the label reads {' '.join(diff) or 'other words'} where the design writes "
                      f"{' '.join(w for w in want_words if w not in got_words)[:120] or 'them in another order'}")
    return spec, mm


def verify_layout(path: str | os.PathLike, spec: LayoutSpec, *, reader: str = "auto", test_array: Any = None,
                  workers: int | None = None, scheduler: str | None = None, progress: bool = False,
                  expected: Expected | None = None, max_refs: int | None = None, dwl: bool = False) -> VerifyReport:
    """Read ``path`` back and compare it with ``spec`` (or with the calibration array ``test_array``, a
    :class:`~metafovea.layout.export.TestArraySpec`).

    Hierarchical files are counted through the hierarchy (cells not named like post cells are
    expanded); ``max_refs``: also a mismatch when a structure holds more elements than that; ``dwl``: also a
    mismatch beyond the Heidelberg DWL 66 limits (structure definitions, references per structure);
    ``workers`` / ``scheduler`` (a Dask scheduler address, or ``local:N``): processes for the expected counts.
    The file's text label gives the date (shown by the printed label) and, when ``spec`` has none, the patch; its
    content hash must be the design's."""
    if workers is not None and workers < 1:
        raise InputError("workers", workers, "an integer >= 1")
    if max_refs is not None and max_refs < 1:
        raise InputError("max_refs", max_refs, "an integer >= 1")
    path = Path(path)
    if not path.is_file():
        raise InputError("FILE", str(path), "an existing GDSII or OASIS file")
    reader = check_choice("reader", reader, READERS)
    fmt = sniff_format(path)
    size = path.stat().st_size
    reader = choose_reader(reader, fmt, size)
    label_mm: list[str] = trailing_bytes(path) if fmt == "gds" else []
    if test_array is None:
        spec, more = label_spec(path, spec)
        label_mm += more
    lat = lattice_of(spec)
    t0 = time.perf_counter()
    if test_array is not None:
        exp = test_array.expected()
        lat = None
    else:
        exp = expected or expected_content(spec, workers=workers, scheduler=scheduler, progress=progress)
    t_exp = time.perf_counter() - t0
    t0 = time.perf_counter()
    names = spec.post_names
    check = SiteCheck(spec) if (test_array is None and lat is not None) else None
    sizes = {(int(w), int(h)): k for k, (w, h) in enumerate(spec.post_sizes_nm.tolist())}
    try:
        if reader == "klayout":
            ob = read_klayout(path, lat, spec.layers.posts, names, sink=check, sizes=sizes)
        elif reader == "gdstk":
            ob = read_gdstk(path, lat, spec.layers.posts, names, sink=check, sizes=sizes)
        else:
            ob = read_stream(path, lat, spec.layers.posts, progress, names, sink=check, sizes=sizes)
    except InputError:
        raise
    except (RuntimeError, OSError, ValueError, EOFError) as e:
        # a truncated or damaged file: the reader libraries raise RuntimeError (klayout, gdstk) or OSError
        detail = " ".join(str(e).split())[:200] or type(e).__name__
        raise InputError("FILE", str(path), f"a complete, readable {'OASIS' if fmt == 'oas' else 'GDSII'} file "
                         f"(the {reader} reader failed)", detail=detail) from None
    t_read = time.perf_counter() - t0
    if test_array is not None:
        mm, counts = compare(ob, spec, exp, top_name=test_array.top_name, frame=False,
                             expected_layers={spec.layers.posts, spec.layers.label})
    else:
        mm, counts = compare(ob, spec, exp)
    mm += label_mm
    if check is not None:
        mm += check.mismatches(exp.total)
    drc = drc_summary(spec)
    if not drc["ok"]:
        mm.append(drc_line(drc))
    if max_refs is not None and ob.max_refs > max_refs:
        mm.append(f"a structure holds {ob.max_refs:,} elements (references and shapes), more than "
                  f"max_refs={max_refs}")
    if dwl:
        from metafovea.layout.export import DWL_LIMIT
        if ob.structures > DWL_LIMIT:
            mm.append(f"{ob.structures:,} structure definitions, more than the DWL 66 limit of {DWL_LIMIT}")
        if ob.max_references > DWL_LIMIT:
            mm.append(f"a structure holds {ob.max_references:,} references, more than the DWL 66 limit of {DWL_LIMIT}")
    return VerifyReport(not mm, str(path), ob.reader, fmt, int(counts.sum()), exp.total, counts.tolist(),
                        exp.counts.tolist(), ob.posts_bbox, exp.posts_bbox_nm, ob.bbox,
                        sorted([list(x) for x in ob.layers]), mm, t_read, t_exp, size, ob.structures, ob.max_refs,
                        None if check is None else check.summary(), drc)


__all__ = ["READERS", "STREAM_THRESHOLD_BYTES", "SiteCheck", "VerifyReport", "choose_reader", "compare",
           "verify_layout"]

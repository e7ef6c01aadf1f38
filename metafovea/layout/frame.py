"""The frame around a lens layout: everything a fab needs besides the posts, in nm, absolute file coordinates.

Two exposures make a lens (see ``gds_export/README.md``): exposure 1 writes the posts and is etched into the
silicon (deep reactive ion etching); exposure 2 writes the aluminium aperture ring (lift-off) aligned to marks
etched by exposure 1. Layers (:class:`~metafovea.layout.tiling.Layers`):

=========  ===========  ==========================================================================================
layer      exposure     content
=========  ===========  ==========================================================================================
1/0        1            posts (polygons = silicon kept)
2/0        2            aluminium aperture ring (polygons = aluminium kept)
3/0        1            alignment crosses at the four compass points, the verniers' main scales
4/0        2            the matching exposure-2 marks (four squares in the quadrants of each cross,
                        ``mark_clearance_um`` from its arms) and the verniers' second scales
5/0        1            die frame: the dicing outline (a square scribe lane, or a circle when the square does not fit
                        the wafer)
6/0        1            printed label (polygon text: lens, post set, date, content hash)
10/0       none         text label (a non-printing record with every parameter, the resist tone and the exposures)
11/0       none         wafer outline with its primary flat (reference only)
=========  ===========  ==========================================================================================

Verniers: next to each cross, one for x (vertical bars) and one for y (horizontal bars). The main scale has
``vernier_bars`` bars at pitch ``p`` (exposure 1), the second scale the same number at pitch ``p + s`` (exposure 2)
abutting it; the centre bars are longer. An overlay error ``d`` of exposure 2 makes bar ``i = -d / s`` of both scales
line up, so the error is read as ``-i s`` to a resolution ``s`` over +-``(vernier_bars - 1) / 2 * s``
(:func:`vernier_readout`).

Every polygon has at most :data:`MAX_POINTS` vertices (arcs are split into sectors), so GDSII (where gdstk would
otherwise fracture them) and OASIS hold the same polygons and a reader's count per layer is comparable.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from metafovea.errors import InputError
from metafovea.layout.bbox import moments, union_bbox
from metafovea.units import NM_PER_UM

if TYPE_CHECKING:  # pragma: no cover
    from metafovea.layout.tiling import LayoutSpec

MAX_POINTS = 199  #: most vertices in one frame polygon (the GDSII limit gdstk writes with)
STANDARD_WAFERS_MM = (50.8, 76.2, 100.0, 150.0, 200.0, 300.0)  #: SEMI wafer diameters, for the advice in errors
#: SEMI M1 primary flat lengths (mm) per wafer diameter; 200/300 mm wafers have a notch (no flat drawn)
SEMI_FLAT_MM = {50.8: 15.9, 76.2: 22.2, 100.0: 32.5, 125.0: 42.5, 150.0: 57.5}


@dataclass(frozen=True)
class Shape:
    """One frame polygon: ``layer`` (layer, datatype), ``role`` (what it is) and its ``(n, 2)`` int64 nm vertices."""

    layer: tuple[int, int]
    role: str
    points: np.ndarray


def layout_date(date: str | None = None) -> str:
    """The date written in the labels: ``date`` (YYYY-MM-DD), else ``SOURCE_DATE_EPOCH`` (reproducible builds),
    else today (UTC)."""
    import datetime
    import os

    if date:
        try:
            return datetime.date.fromisoformat(str(date)).isoformat()
        except ValueError:
            raise InputError("date", date, "a date YYYY-MM-DD") from None
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    if epoch:
        try:
            return datetime.datetime.fromtimestamp(int(epoch), datetime.UTC).date().isoformat()
        except (ValueError, OverflowError, OSError):
            raise InputError("SOURCE_DATE_EPOCH", epoch, "seconds since 1970 (an integer)") from None
    return datetime.datetime.now(datetime.UTC).date().isoformat()


def parse_label(text: str | None) -> dict[str, Any]:
    """The fields of a text label (:meth:`LayoutSpec.label_text`) a verifier needs: ``date``, ``hash`` and
    ``patch_um`` (None when absent)."""
    import re

    out: dict[str, Any] = {"date": None, "hash": None, "patch_um": None}
    if not text:
        return out
    m = re.search(r"\bdate=(\d{4}-\d{2}-\d{2})", text)
    out["date"] = m.group(1) if m else None
    m = re.search(r"\bhash=([0-9a-f]{12})", text)
    out["hash"] = m.group(1) if m else None
    m = re.search(r"\bpatch=\(([-+0-9.eE]+),([-+0-9.eE]+),([-+0-9.eE]+)\)um", text)
    out["patch_um"] = tuple(float(v) for v in m.groups()) if m else None
    return out


def content_hash(spec: LayoutSpec) -> str:
    """12 hex digits of SHA-256 over everything that fixes the layout's content (:meth:`LayoutSpec.key`, the date
    excluded): printed on the wafer and written in the label, so a die can be matched to its file."""
    key = dict(spec.key())
    key.pop("date", None)
    return hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()[:12]


def _box(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.int64)


def annulus_sectors(spec: LayoutSpec, c: tuple[int, int], r_in_um: float, r_out_um: float, a0: float, a1: float,
                    tolerance_um: float) -> list[np.ndarray]:
    """The annulus ``r_in..r_out`` (um) around ``c`` (nm) between angles ``a0..a1`` as sectors of at most
    :data:`MAX_POINTS` vertices, each arc within ``tolerance_um`` of the circle, vertices snapped to the grid."""
    step = 2 * math.acos(max(-1.0, 1 - tolerance_um / max(r_out_um, 1e-9)))  # chord sagitta = tolerance
    n_arc = max(2, math.ceil((a1 - a0) / max(step, 1e-9)) + 1)
    per = (MAX_POINTS // 2) - 1  # arc segments per sector (each sector has 2 (per + 1) vertices)
    n_sec = max(1, math.ceil((n_arc - 1) / per))
    out = []
    edges = np.linspace(a0, a1, n_sec + 1)
    for s in range(n_sec):
        m = max(2, math.ceil((n_arc - 1) / n_sec) + 1)
        a = np.linspace(edges[s], edges[s + 1], m)
        outer = np.stack([np.cos(a), np.sin(a)], 1) * r_out_um
        inner = (np.stack([np.cos(a), np.sin(a)], 1) * r_in_um)[::-1]
        pts = spec.snap(np.concatenate([outer, inner]) * NM_PER_UM) + np.asarray(c, dtype=np.int64)
        keep = np.ones(len(pts), bool)
        keep[1:] = np.any(pts[1:] != pts[:-1], axis=1)
        out.append(pts[keep])
    return out


def ring_polygons_nm(spec: LayoutSpec, tolerance_um: float = 0.05) -> list[np.ndarray]:
    """The aluminium ring as annulus sectors (each (n, 2) int64 nm, snapped, at most :data:`MAX_POINTS` vertices)."""
    c = spec.centre_nm
    return annulus_sectors(spec, (c, c), spec.ring_inner_um, spec.ring_outer_um, 0.0, 2 * math.pi, tolerance_um)


def mark_centres_nm(spec: LayoutSpec) -> list[tuple[int, int]]:
    """The four alignment crosses' centres (east, west, north, south of the lens)."""
    c = spec.centre_nm
    d = int(round((spec.ring_outer_um + spec.mark_offset_um) * NM_PER_UM))
    return [(c + d, c), (c - d, c), (c, c + d), (c, c - d)]


def mark_boxes_nm(spec: LayoutSpec) -> list[tuple[int, int, int, int]]:
    """Exposure-1 alignment crosses (two boxes each) at the four compass points outside the ring."""
    a = int(round(spec.mark_size_um * NM_PER_UM / 2))
    w = int(round(spec.mark_width_um * NM_PER_UM / 2))
    boxes = []
    for mx, my in mark_centres_nm(spec):
        boxes.append((mx - a, my - w, mx + a, my + w))
        boxes.append((mx - w, my - a, mx + w, my + a))
    return boxes


def mark2_boxes_nm(spec: LayoutSpec) -> list[tuple[int, int, int, int]]:
    """Exposure-2 marks: per cross, four squares filling its quadrants ``mark_clearance_um`` from the arms."""
    a = int(round(spec.mark_size_um * NM_PER_UM / 2))
    g = int(round((spec.mark_width_um / 2 + spec.mark_clearance_um) * NM_PER_UM))
    boxes = []
    for mx, my in mark_centres_nm(spec):
        for sx in (-1, 1):
            for sy in (-1, 1):
                xs = sorted((mx + sx * g, mx + sx * a))
                ys = sorted((my + sy * g, my + sy * a))
                boxes.append((xs[0], ys[0], xs[1], ys[1]))
    return boxes


def _vernier_bars(spec: LayoutSpec, x0: int, y0: int, axis: str) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """One vernier (main scale, second scale) with its origin (the centre bars' meeting point) at ``(x0, y0)`` nm:
    ``axis`` 'x' measures x (vertical bars side by side in x, main scale below), 'y' the transpose."""
    n = (spec.vernier_bars - 1) // 2
    p = spec.vernier_pitch_um * NM_PER_UM
    s = spec.vernier_step_um * NM_PER_UM
    hw = spec.vernier_pitch_um * NM_PER_UM / 4  # bar half-width: half the pitch is bar
    L = spec.vernier_length_um * NM_PER_UM
    main, second = [], []
    for i in range(-n, n + 1):
        ext = L / 2 if i == 0 else 0.0
        for pitch, lo, hi, dst in ((p, -L - ext, 0.0, main), (p + s, 0.0, L + ext, second)):
            u = i * pitch
            pts = _box(*spec.snap([u - hw, lo]), *spec.snap([u + hw, hi]))
            if axis == "y":
                pts = pts[:, ::-1][::-1]
            dst.append(pts + np.array([x0, y0], dtype=np.int64))
    return main, second


def vernier_origins_nm(spec: LayoutSpec) -> list[tuple[str, int, int]]:
    """``(axis, x, y)`` of the eight verniers: beside each cross, an x vernier above it and a y vernier to its right."""
    a = spec.mark_size_um / 2
    off = int(round((a + spec.vernier_length_um * 1.5 + 20.0) * NM_PER_UM))
    out = []
    for mx, my in mark_centres_nm(spec):
        out.append(("x", mx, my + off))
        out.append(("y", mx + off, my))
    return out


def vernier_readout(main_centres_nm: np.ndarray, second_centres_nm: np.ndarray, step_nm: float) -> float:
    """The overlay error (nm) a vernier shows: ``-i s`` for the bar pair ``i`` that lines up best (centres given in
    bar order, ``i = 0`` in the middle). Independent of how the file was written: give it the bars read back."""
    m = np.asarray(main_centres_nm, dtype=float)
    v = np.asarray(second_centres_nm, dtype=float)
    i = int(np.argmin(np.abs(v - m)))
    return -(i - (len(m) - 1) // 2) * step_nm


def _label_polygons(spec: LayoutSpec) -> list[np.ndarray]:
    """The printed label (polygon text from gdstk) centred under the south cross, on the 1 nm grid."""
    import gdstk

    h = spec.label_height_um
    polys = gdstk.text(spec.printed_text(), h, (0.0, 0.0))
    if not polys:
        return []
    bb = np.array([p.bounding_box() for p in polys])
    w = float(bb[:, 1, 0].max() - bb[:, 0, 0].min())
    top = float(bb[:, 1, 1].max())
    c = spec.centre_nm
    _, sy = mark_centres_nm(spec)[3]
    y_top = sy - (spec.mark_size_um / 2 + 150.0) * NM_PER_UM
    dx = c - (bb[:, 0, 0].min() + w / 2) * NM_PER_UM
    dy = y_top - top * NM_PER_UM
    return [np.rint(p.points * NM_PER_UM + np.array([dx, dy])).astype(np.int64) for p in polys]


def _extent_nm(shapes: list[Shape], c: int) -> tuple[float, float]:
    """Largest |x - c|, |y - c| and largest distance from the centre of any vertex."""
    pts = np.concatenate([s.points for s in shapes]) - c
    return float(np.abs(pts).max()), float(np.hypot(pts[:, 0], pts[:, 1]).max())


def die_outline(spec: LayoutSpec, inner: list[Shape]) -> tuple[str, float]:
    """``('square', half side)`` or ``('circle', radius)`` (um) of the dicing outline's outer edge around the shapes
    ``inner``: a square when it fits the wafer inside the edge exclusion and above the flat, else a circle (cut by
    laser or core drill); an :class:`InputError` naming ``wafer_diameter_mm`` when neither fits."""
    c = spec.centre_nm
    box_nm, rad_nm = _extent_nm(inner, c)
    m = spec.die_margin_um + spec.scribe_width_um
    R = spec.wafer_diameter_mm * 500.0 - spec.wafer_edge_exclusion_mm * 1000.0  # usable radius (um)
    flat_y = spec.wafer_flat_distance_um - spec.wafer_edge_exclusion_mm * 1000.0
    half = box_nm / NM_PER_UM + m
    if half * math.sqrt(2) <= R and half <= flat_y:
        return "square", half
    r = rad_nm / NM_PER_UM + m
    if r <= R and r <= flat_y:
        return "circle", r
    need = 2 * (r + spec.wafer_edge_exclusion_mm * 1000.0) / 1000.0
    std = next((d for d in STANDARD_WAFERS_MM if d * 500.0 - spec.wafer_edge_exclusion_mm * 1000.0 >= r * 1.03), None)
    raise InputError("wafer_diameter_mm", spec.wafer_diameter_mm,
                     f"a wafer of at least {need:.1f} mm for this lens (die outline radius {r / 1000:.2f} mm + "
                     f"{spec.wafer_edge_exclusion_mm:g} mm edge exclusion)"
                     + (f", e.g. {std:g} mm" if std else "") + "; set it in the platform file")


def _die_shapes(spec: LayoutSpec, inner: list[Shape]) -> list[Shape]:
    kind, outer = die_outline(spec, inner)
    c = spec.centre_nm
    w = spec.scribe_width_um
    L = spec.layers.die
    if kind == "circle":
        return [Shape(L, "die", p) for p in annulus_sectors(spec, (c, c), outer - w, outer, 0.0, 2 * math.pi, 0.5)]
    o, i = outer * NM_PER_UM, (outer - w) * NM_PER_UM
    boxes = [(-o, -o, o, -i), (-o, i, o, o), (-o, -i, -i, i), (i, -i, o, i)]
    return [Shape(L, "die", _box(*spec.snap(np.array(b)) + c)) for b in boxes]


def _wafer_shapes(spec: LayoutSpec) -> list[Shape]:
    """The wafer's edge as a 200 um band with the primary flat at the bottom (non-printing)."""
    c = spec.centre_nm
    R = spec.wafer_diameter_mm * 500.0
    w = 200.0
    L = spec.layers.wafer
    yf = spec.wafer_flat_distance_um
    if yf >= R:  # no flat
        return [Shape(L, "wafer", p) for p in annulus_sectors(spec, (c, c), R - w, R, 0.0, 2 * math.pi, 1.0)]
    phi = math.acos(yf / R)  # half-angle of the flat seen from the centre
    arcs = annulus_sectors(spec, (c, c), R - w, R, -math.pi / 2 + phi, 3 * math.pi / 2 - phi, 1.0)
    half = R * math.sin(phi)
    flat = _box(*spec.snap(np.array([-half, -yf, half, -yf + w]) * NM_PER_UM) + c)
    return [Shape(L, "wafer", p) for p in arcs] + [Shape(L, "wafer", flat)]


def frame_shapes(spec: LayoutSpec) -> list[Shape]:
    """Every frame polygon of a full-lens layout, in writing order (none for a patch: a patch is a piece of the
    lens, its file has the text label only)."""
    if spec.patch_um is not None:
        return []
    L = spec.layers
    shapes = [Shape(L.aperture, "ring", p) for p in ring_polygons_nm(spec)]
    shapes += [Shape(L.marks, "mark", _box(*b)) for b in mark_boxes_nm(spec)]
    shapes += [Shape(L.marks2, "mark2", _box(*b)) for b in mark2_boxes_nm(spec)]
    for axis, x, y in vernier_origins_nm(spec):
        main, second = _vernier_bars(spec, x, y, axis)
        shapes += [Shape(L.marks, f"vernier_{axis}", p) for p in main]
        shapes += [Shape(L.marks2, f"vernier_{axis}", p) for p in second]
    shapes += [Shape(L.printed, "printed_label", p) for p in _label_polygons(spec)]
    shapes += _die_shapes(spec, shapes)
    shapes += _wafer_shapes(spec)
    return shapes


def expected_frame(spec: LayoutSpec) -> dict[tuple[int, int], tuple[int, tuple[int, int, int, int]]]:
    """Per frame layer: (polygons, bounding box in nm) as an independent reader should find them."""
    out: dict[tuple[int, int], list[Any]] = {}
    for s in frame_shapes(spec):
        x0, y0 = s.points.min(0).tolist()
        x1, y1 = s.points.max(0).tolist()
        e = out.setdefault(s.layer, [0, None])
        e[0] += 1
        e[1] = union_bbox(e[1], (x0, y0, x1, y1))
    return {k: (v[0], tuple(v[1])) for k, v in out.items()}


def expected_frame_moments(spec: LayoutSpec) -> dict[tuple[int, int], tuple[float, float, float]]:
    """Per frame layer: the polygons' area and its first moments ``(A, Sx, Sy)`` (nm^2, nm^3,
    :func:`~metafovea.layout.bbox.moments`) as an independent reader should find them: a mark moved, resized or
    replaced inside its layer's bounding box changes them."""
    out: dict[tuple[int, int], np.ndarray] = {}
    for s in frame_shapes(spec):
        out[s.layer] = out.get(s.layer, 0.0) + moments(s.points)
    return {k: (float(v[0]), float(v[1]), float(v[2])) for k, v in out.items()}


def frame_bbox_nm(spec: LayoutSpec) -> tuple[int, int, int, int] | None:
    """Bounding box of the whole frame (the wafer outline for a full lens), None for a patch."""
    ef = expected_frame(spec)
    if not ef:
        return None
    bs = np.array([b for _, b in ef.values()])
    return int(bs[:, 0].min()), int(bs[:, 1].min()), int(bs[:, 2].max()), int(bs[:, 3].max())


__all__ = ["MAX_POINTS", "SEMI_FLAT_MM", "Shape", "annulus_sectors", "content_hash", "die_outline", "expected_frame",
           "expected_frame_moments",
           "layout_date", "parse_label",
           "frame_bbox_nm", "frame_shapes", "mark2_boxes_nm", "mark_boxes_nm", "mark_centres_nm", "ring_polygons_nm",
           "vernier_origins_nm", "vernier_readout"]

"""GDSII: library header, post cells and the frame through gdstk; the posts as streamed records.

gdstk writes a small library (post cells, top cell with ring, marks and label). Its last two records
are the top cell's ENDSTR and the ENDLIB; the exporter cuts them off, appends one SREF (28 bytes:
SREF, SNAME of 4 characters, XY, ENDEL) or, with ``flat``, one 5-point BOUNDARY (64 bytes) per post,
encoded band by band with numpy as big-endian records, and appends ENDSTR/ENDLIB.
"""

from __future__ import annotations

import datetime
import os
import tempfile

import numpy as np

from metafovea.layout.tiling import LayoutSpec, band_levels, has_frame, mark_boxes_nm, ring_polygons_nm
from metafovea.units import NM_PER_UM

ENDSTR_ENDLIB = bytes.fromhex("00040700") + bytes.fromhex("00040400")
_SREF = 0x00040A00
_SNAME4 = 0x00081206
_XY1 = 0x000C1003
_ENDEL = 0x00041100
_BOUNDARY = 0x00040800
_LAYER = 0x00060D02
_DATATYPE = 0x00060E02
_XY5 = 0x002C1003

SREF_BYTES = 28
BOUNDARY_BYTES = 64

_BOUNDARY_DTYPE = np.dtype({
    "names": ["h", "lh", "layer", "dh", "dt", "xyh", "xy", "end"],
    "formats": [">u4", ">u4", ">i2", ">u4", ">i2", ">u4", (">i4", (10,)), ">u4"],
    "offsets": [0, 4, 8, 10, 14, 16, 20, 60], "itemsize": 64})

FIXED_TIMESTAMP = datetime.datetime(2024, 1, 1)


def _library(spec: LayoutSpec, flat: bool):
    import gdstk

    lib = gdstk.Library(name=spec.design.name.upper()[:32] or "LIB", unit=1e-6, precision=1e-9)
    pl, pd = spec.layers.posts
    sz = spec.post_sizes_nm / NM_PER_UM
    if not flat:
        for name, (wx, wy) in zip(spec.post_names, sz):
            c = lib.new_cell(name)
            c.add(gdstk.rectangle((-wx / 2, -wy / 2), (wx / 2, wy / 2), layer=pl, datatype=pd))
    top = lib.new_cell(spec.top_name)
    if has_frame(spec):
        al, ad = spec.layers.aperture
        for pts in ring_polygons_nm(spec):
            top.add(gdstk.Polygon(pts / NM_PER_UM, layer=al, datatype=ad))
        ml, md = spec.layers.marks
        for x0, y0, x1, y1 in mark_boxes_nm(spec):
            top.add(gdstk.rectangle((x0 / NM_PER_UM, y0 / NM_PER_UM), (x1 / NM_PER_UM, y1 / NM_PER_UM),
                                    layer=ml, datatype=md))
    tl, tt = spec.layers.label
    lx, ly = spec.label_position_nm()
    top.add(gdstk.Label(spec.label_text(), (lx / NM_PER_UM, ly / NM_PER_UM), layer=tl, texttype=tt))
    return lib


def gds_header(spec: LayoutSpec, flat: bool = False) -> bytes:
    """Everything up to (not including) the top cell's ENDSTR, written by gdstk."""
    lib = _library(spec, flat)
    fd, tmp = tempfile.mkstemp(suffix=".gds")
    os.close(fd)
    try:
        lib.write_gds(tmp, max_points=199, timestamp=FIXED_TIMESTAMP)
        with open(tmp, "rb") as fh:
            data = fh.read()
    finally:
        os.unlink(tmp)
    if not data.endswith(ENDSTR_ENDLIB):
        raise RuntimeError("unexpected gdstk output: the library does not end with ENDSTR ENDLIB")
    return data[:-len(ENDSTR_ENDLIB)]


def gds_footer() -> bytes:
    return ENDSTR_ENDLIB


def _name_words(spec: LayoutSpec) -> np.ndarray:
    words = []
    for n in spec.post_names:
        b = n.encode("ascii")
        if len(b) != 4:
            raise ValueError("post cell names must have 4 characters")
        words.append(int.from_bytes(b, "big"))
    return np.array(words, dtype=np.uint32)


def band_index(spec: LayoutSpec, band: tuple[int, int, int, int]):
    """Posts of one band restricted to the window, row-major: ``(k, r, c, xs, ys)`` with post type
    ``k`` (uint8), row/column indices into the band and the site positions ``xs`` (per column) and
    ``ys`` (per row) in nm (int64)."""
    iy0, rows, ix0, cols = band
    lev = band_levels(spec.design, iy0, rows, ix0, cols, spec.levels)
    _, _, ix_lo, ix_hi = spec.window()
    if ix0 < ix_lo or ix0 + cols - 1 > ix_hi:
        a, b = max(ix0, ix_lo), min(ix0 + cols - 1, ix_hi)
        lev = np.ascontiguousarray(lev[:, a - ix0:b - ix0 + 1])
        ix0 = a
    ncol = lev.shape[1]
    flat = lev.reshape(-1)
    fi = np.flatnonzero(flat >= 0)
    k = flat[fi].astype(np.uint8)
    r = fi // ncol
    c = fi - r * ncol
    xs = spec.site_x_nm(np.arange(ix0, ix0 + ncol))
    ys = spec.site_y_nm(np.arange(iy0, iy0 + rows))
    return k, r, c, xs, ys


def band_sites(spec: LayoutSpec, band: tuple[int, int, int, int]):
    """Posts of one band: ``(k, x_nm, y_nm)`` (row-major)."""
    k, r, c, xs, ys = band_index(spec, band)
    return k.astype(np.intp), xs[c], ys[r]


def encode_band_gds(spec: LayoutSpec, flat: bool, band: tuple[int, int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """GDSII records of one band's posts (a uint8 array) and the number of posts per type."""
    k, r, c, xs, ys = band_index(spec, band)
    n = k.size
    counts = np.bincount(k, minlength=spec.levels)
    if not flat:
        rec = np.empty((n, 7), dtype=">u4")
        rec[:] = np.array([_SREF, _SNAME4, 0, _XY1, 0, 0, _ENDEL], dtype=">u4")
        rec[:, 2] = _name_words(spec).astype(">u4")[k]
        rec[:, 4] = xs.astype(">i4").view(">u4")[c]
        rec[:, 5] = ys.astype(">i4").view(">u4")[r]
        return rec.view(np.uint8).reshape(-1), counts
    x, y = xs[c], ys[r]
    k = k.astype(np.intp)
    rec = np.empty(n, dtype=_BOUNDARY_DTYPE)
    rec["h"] = _BOUNDARY
    rec["lh"] = _LAYER
    rec["layer"] = spec.layers.posts[0]
    rec["dh"] = _DATATYPE
    rec["dt"] = spec.layers.posts[1]
    rec["xyh"] = _XY5
    rec["end"] = _ENDEL
    hw = spec.post_sizes_nm[:, 0] // 2
    hh = spec.post_sizes_nm[:, 1] // 2
    x0, x1 = x - hw[k], x + hw[k]
    y0, y1 = y - hh[k], y + hh[k]
    xy = rec["xy"]
    xy[:, 0], xy[:, 1] = x0, y0
    xy[:, 2], xy[:, 3] = x1, y0
    xy[:, 4], xy[:, 5] = x1, y1
    xy[:, 6], xy[:, 7] = x0, y1
    xy[:, 8], xy[:, 9] = x0, y0
    return rec.view(np.uint8).reshape(-1), counts

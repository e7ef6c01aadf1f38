"""GDSII: library header, post cells and the frame through gdstk; the posts as streamed records.

gdstk writes a small library (post cells, top cell with ring, marks and label). Its last two records
are the top cell's ENDSTR and the ENDLIB; the exporter cuts them off, appends one SREF (28 bytes:
SREF, SNAME of 4 characters, XY, ENDEL) or, with ``flat``, one 5-point BOUNDARY (64 bytes) per post,
encoded task by task with numpy as big-endian records, and appends ENDSTR/ENDLIB.

Hierarchical (``max_refs``): the posts go into leaf structures of at most ``max_refs`` records written
after the post cells; intermediate structures and the top cell (gdstk's frame elements plus references)
follow at the end (:func:`hierarchy_footer`).
"""

from __future__ import annotations

import datetime
import os
import tempfile

import numpy as np

from metafovea.layout.frame import frame_shapes
from metafovea.layout.tiling import LayoutSpec, task_levels, task_rows, used_levels, window_levels
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


def _boundary_headers(spec, n: int) -> np.ndarray:
    """``n`` flat-post BOUNDARY records with every field set but the coordinates."""
    rec = np.empty(n, dtype=_BOUNDARY_DTYPE)
    rec["h"] = _BOUNDARY
    rec["lh"] = _LAYER
    rec["layer"] = spec.layers.posts[0]
    rec["dh"] = _DATATYPE
    rec["dt"] = spec.layers.posts[1]
    rec["xyh"] = _XY5
    rec["end"] = _ENDEL
    return rec


def _library(spec: LayoutSpec, flat: bool):
    import gdstk

    lib = gdstk.Library(name=spec.design.name.upper()[:32] or "LIB", unit=1e-6, precision=1e-9)
    pl, pd = spec.layers.posts
    sz = spec.post_sizes_nm / NM_PER_UM
    if not flat:
        for k in used_levels(spec):
            wx, wy = sz[k]
            c = lib.new_cell(spec.post_names[k])
            c.add(gdstk.rectangle((-wx / 2, -wy / 2), (wx / 2, wy / 2), layer=pl, datatype=pd))
    top = lib.new_cell(spec.top_name)
    for sh in frame_shapes(spec):
        top.add(gdstk.Polygon(sh.points / NM_PER_UM, layer=sh.layer[0], datatype=sh.layer[1]))
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
    iy0, rows = band[:2]
    lev, ix0 = window_levels(spec, band)
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


def task_index(spec: LayoutSpec, task: tuple[int, int, int, int, int]):
    """Posts of the task's quadrant rows, row-major: ``(k, r, c, xs, sides)`` with post type ``k``
    (uint8), local row/column indices (int32), column positions ``xs`` (nm, int64) and
    :func:`task_rows` ``sides`` [(row mask, row y positions), ...]."""
    lev, ix0 = task_levels(spec, task)
    ncol = lev.shape[1]
    flat = lev.reshape(-1)
    fi = np.flatnonzero(flat >= 0)
    k = flat[fi].astype(np.uint8)
    fi = fi.astype(np.int32)
    r = fi // np.int32(ncol)
    c = fi - r * np.int32(ncol)
    xs = spec.site_x_nm(np.arange(ix0, ix0 + ncol))
    return k, r, c, xs, task_rows(spec, task)


def _sides(r: np.ndarray, sides):
    """Per side: (element selection or None for all, y per local row)."""
    out = []
    for _, mask, ys in sides:
        out.append((None if mask.all() else np.flatnonzero(mask[r]), ys))
    return out


def encode_task_records(spec: LayoutSpec, flat: bool, task) -> tuple[list[np.ndarray], np.ndarray]:
    """GDSII element records of one task: one uint8 array per row side (SREF: 28 bytes per post,
    ``flat``: 64-byte BOUNDARY), and the number of posts per type (both sides)."""
    k, r, c, xs, sides = task_index(spec, task)
    sel = _sides(r, sides)
    n = k.size
    counts = np.zeros(spec.levels, dtype=np.int64)
    kc = np.bincount(k, minlength=spec.levels)
    out = []
    if not flat:
        base = np.empty((n, 7), dtype=">u4")
        base[:] = np.array([_SREF, _SNAME4, 0, _XY1, 0, 0, _ENDEL], dtype=">u4")
        base[:, 2] = _name_words(spec).astype(">u4")[k]
        base[:, 4] = xs.astype(">i4").view(">u4")[c]
        for i, (idx, ys) in enumerate(sel):
            last = i == len(sel) - 1
            if idx is None:
                rec = base if last else base.copy()
                counts += kc
                rec[:, 5] = ys.astype(">i4").view(">u4")[r]
            else:
                rec = base[idx]
                counts += np.bincount(k[idx], minlength=spec.levels)
                rec[:, 5] = ys.astype(">i4").view(">u4")[r[idx]]
            out.append(rec.view(np.uint8).reshape(-1))
        return out, counts
    ki = k.astype(np.intp)
    base = _boundary_headers(spec, n)
    hw = spec.post_sizes_nm[:, 0] // 2
    hh = spec.post_sizes_nm[:, 1] // 2
    x = xs[c]
    x0, x1 = x - hw[ki], x + hw[ki]
    xy = base["xy"]
    xy[:, 0], xy[:, 2], xy[:, 4], xy[:, 6], xy[:, 8] = x0, x1, x1, x0, x0
    del x, x0, x1
    for i, (idx, ys) in enumerate(sel):
        last = i == len(sel) - 1
        if idx is None:
            rec = base if last else base.copy()
            y, h = ys[r], hh[ki]
            counts += kc
        else:
            rec = base[idx]
            y, h = ys[r[idx]], hh[ki[idx]]
            counts += np.bincount(k[idx], minlength=spec.levels)
        y0, y1 = y - h, y + h
        xy = rec["xy"]
        xy[:, 1], xy[:, 3], xy[:, 5], xy[:, 7], xy[:, 9] = y0, y0, y1, y1, y0
        out.append(rec.view(np.uint8).reshape(-1))
    return out, counts


def encode_task_into(spec: LayoutSpec, flat: bool, task, out: np.ndarray) -> np.ndarray:
    """:func:`encode_task_records`' bytes written into ``out`` (uint8, exactly their size:
    :func:`~metafovea.layout.tiling.task_post_counts` times the record size) instead of new arrays, so that an
    aligned buffer can go to the disk as it is; returns the posts per type.

    Row by row (a row's records, ~0.5 MB, stay in the cache while both its sides are written: the mirrored side is
    a copy of the first with another y): the sites inside the aperture and the window are one run of columns per
    row, so a row's posts are a slice of the levels and of the column positions, with no index arrays."""
    lev, ix0 = task_levels(spec, task)
    sides = task_rows(spec, task)
    size = BOUNDARY_BYTES if flat else SREF_BYTES
    valid = lev >= 0
    a = np.argmax(valid, axis=1)
    n = np.where(valid.any(axis=1), lev.shape[1] - np.argmax(valid[:, ::-1], axis=1) - a, 0)
    if int(n.sum()) != int(np.count_nonzero(valid)):
        raise RuntimeError(f"task {task}: the posts of a row are not one run of columns")
    starts, pos = [], 0  # per side: the byte offset of each row's records
    for _, mask, ys in sides:
        nr = np.where(mask, n, 0) * size
        starts.append((mask, ys, pos + np.cumsum(nr) - nr))
        pos += int(nr.sum())
    if pos != out.size:
        raise RuntimeError(f"task {task}: {pos} bytes of posts, expected {out.size}")
    xs = spec.site_x_nm(np.arange(ix0, ix0 + lev.shape[1]))
    if not flat:
        head = np.array([_SREF, _SNAME4, 0, _XY1, 0, 0, _ENDEL], dtype=">u4")
        names = _name_words(spec).astype(">u4")
        xw = xs.astype(">i4").view(">u4")
    else:
        hw = spec.post_sizes_nm[:, 0] // 2
        hh = spec.post_sizes_nm[:, 1] // 2
    counts = np.zeros(spec.levels, dtype=np.int64)
    for r in np.flatnonzero(n).tolist():
        ar, br = int(a[r]), int(a[r] + n[r])
        k = lev[r, ar:br]
        first = None
        for mask, ys, st in starts:
            if not mask[r]:
                continue
            seg = out[st[r]:st[r] + (br - ar) * size]
            rec = seg.view(">u4").reshape(-1, 7) if not flat else seg.view(_BOUNDARY_DTYPE)
            if first is not None:
                rec[:] = first
            elif not flat:
                rec[:] = head
                rec[:, 2] = names[k]
                rec[:, 4] = xw[ar:br]
            else:
                for name, v in (("h", _BOUNDARY), ("lh", _LAYER), ("layer", spec.layers.posts[0]),
                                ("dh", _DATATYPE), ("dt", spec.layers.posts[1]), ("xyh", _XY5), ("end", _ENDEL)):
                    rec[name] = v
                x, hx = xs[ar:br], hw[k]
                x0, x1 = x - hx, x + hx
                xy = rec["xy"]
                xy[:, 0], xy[:, 2], xy[:, 4], xy[:, 6], xy[:, 8] = x0, x1, x1, x0, x0
            if not flat:
                rec[:, 5] = ys[r:r + 1].astype(">i4").view(">u4")
            else:
                hy = hh[k]
                y0, y1 = ys[r] - hy, ys[r] + hy
                xy = rec["xy"]
                xy[:, 1], xy[:, 3], xy[:, 5], xy[:, 7], xy[:, 9] = y0, y0, y1, y1, y0
            first = rec
            counts += np.bincount(k, minlength=spec.levels)
    return counts


# ----------------------------------------------------------------------------------------------
# hierarchical GDSII (at most N references per structure)
# ----------------------------------------------------------------------------------------------
_BGNSTR = 0x001C0502
_ENDSTR = bytes.fromhex("00040700")


def _strname(name: str) -> bytes:
    b = name.encode("ascii")
    if len(b) % 2:
        b += b"\0"
    return (4 + len(b)).to_bytes(2, "big") + b"\x06\x06" + b


def bgnstr(name: str) -> bytes:
    """BGNSTR (fixed timestamps, as gdstk writes them) and STRNAME."""
    t = FIXED_TIMESTAMP
    stamp = np.array([t.year, t.month, t.day, t.hour, t.minute, t.second] * 2, dtype=">i2").tobytes()
    return _BGNSTR.to_bytes(4, "big") + stamp + _strname(name)


def sref(name: str, x: int = 0, y: int = 0) -> bytes:
    nm = name.encode("ascii")
    if len(nm) % 2:
        nm += b"\0"
    return (_SREF.to_bytes(4, "big") + (4 + len(nm)).to_bytes(2, "big") + b"\x12\x06" + nm
            + _XY1.to_bytes(4, "big") + int(x).to_bytes(4, "big", signed=True)
            + int(y).to_bytes(4, "big", signed=True) + _ENDEL.to_bytes(4, "big"))


def leaf_name(task: int, i: int) -> str:
    return f"L{task:05d}_{i:05d}"


def encode_task_hier(spec: LayoutSpec, flat: bool, leaf_max: int | None, task):
    """The task's posts as leaf structures ``L<task>_<i>`` of at most ``leaf_max`` posts each (SREFs, or
    BOUNDARYs with ``flat``; ``None``: one leaf per task and side): ``(pieces, counts, leaves)``."""
    recs, counts = encode_task_records(spec, flat, task)
    size = BOUNDARY_BYTES if flat else SREF_BYTES
    pieces: list = []
    i = 0
    end = _ENDSTR
    for rec in recs:
        n = rec.size // size
        step = n if leaf_max is None else leaf_max
        for a in range(0, n, max(step, 1)):
            pieces.append(bgnstr(leaf_name(task[0], i)))
            pieces.append(rec[a * size:min(n, a + step) * size])
            pieces.append(end)
            i += 1
    return pieces, counts, i


def split_top(header: bytes) -> tuple[bytes, bytes, list[bytes]]:
    """A gdstk library without its last ENDSTR/ENDLIB -> (everything before the top structure, the top
    structure's opening records (BGNSTR, STRNAME), its elements' records one per element)."""
    pos, last = 0, None
    while pos < len(header):
        ln = int.from_bytes(header[pos:pos + 2], "big")
        if header[pos + 2] == 0x05:
            last = pos
        pos += ln
    if last is None:
        raise RuntimeError("unexpected gdstk output: no structure")
    pos, head_end, elements, start = last, None, [], None
    while pos < len(header):
        ln = int.from_bytes(header[pos:pos + 2], "big")
        rt = header[pos + 2]
        if head_end is None and rt not in (0x05, 0x06):
            head_end = pos
        if start is None and head_end is not None:
            start = pos
        pos += ln
        if rt == 0x11:  # ENDEL
            elements.append(header[start:pos])
            start = None
    return header[:last], header[last:head_end if head_end is not None else pos], elements


def frame_name(i: int) -> str:
    return f"F{i:05d}"


def hierarchy_footer(spec: LayoutSpec, top_open: bytes, frame_elements: list[bytes], leaves: list[str],
                     max_refs: int, frame_max: int | None = None) -> bytes:
    """The frame's elements in structures ``F<i>`` of at most ``frame_max`` elements (default ``max_refs``),
    intermediate structures ``M<level>_<i>`` (each referencing at most ``max_refs`` structures, all at the
    origin) over the frame and the leaves, then the top structure (references only), ENDLIB."""
    fm = max_refs if frame_max is None else frame_max
    out = bytearray()
    names = []
    for i in range(0, len(frame_elements), fm):
        nm = frame_name(i // fm)
        out += bgnstr(nm) + b"".join(frame_elements[i:i + fm]) + _ENDSTR
        names.append(nm)
    names += list(leaves)
    level = 0
    while len(names) > max_refs:
        level += 1
        nxt = []
        for i in range(0, len(names), max_refs):
            nm = f"M{level}_{i // max_refs:05d}"
            out += bgnstr(nm)
            for child in names[i:i + max_refs]:
                out += sref(child)
            out += _ENDSTR
            nxt.append(nm)
        names = nxt
    out += top_open
    for child in names:
        out += sref(child)
    out += ENDSTR_ENDLIB
    return bytes(out)

"""Read an exported layout back with an independent reader and compare it with the design.

Readers
-------
* ``klayout``: KLayout's Python module (``klayout.db``), what fabs use; GDSII and OASIS.
* ``gdstk``: gdstk's readers (fast for large OASIS files).
* ``stream``: :class:`GdsScanner`, a streaming GDSII record scanner written here (it shares no code
  with the writer), for GDSII files too large to load whole: runs of 28-byte SREF groups and 64-byte
  5-point BOUNDARY groups are checked and reduced with numpy, everything else is parsed record by
  record. Memory is one read buffer.

Checks: one top cell with the expected name; database unit 1 nm; each post cell holds exactly one
rectangle on the posts layer of the expected size, centred at the cell origin; posts per type equal
the design's counts; every post on a lattice site; bounding box of the posts and (full lens) of the
whole layout; the set of layers used.
"""

from __future__ import annotations

import os
import struct
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.errors import InputError, check_choice
from metafovea.layout.tiling import Expected, LayoutSpec, expected_content, has_frame, mark_boxes_nm

READERS = ("auto", "klayout", "gdstk", "stream")
STREAM_THRESHOLD_BYTES = 256 << 20


@dataclass
class Observed:
    """What a reader found (coordinates in database units)."""

    reader: str
    format: str
    dbu_um: float = 0.0
    top_cells: list[str] = field(default_factory=list)
    cell_rects: dict[str, list[tuple[int, int, int, int, int, int]]] = field(default_factory=dict)
    ref_counts: Counter = field(default_factory=Counter)  # child cell name -> references in the top cell
    flat_counts: Counter = field(default_factory=Counter)  # (w, h) of posts-layer rectangles in the top cell
    posts_bbox: tuple[int, int, int, int] | None = None
    bbox: tuple[int, int, int, int] | None = None
    layers: set = field(default_factory=set)
    off_lattice: int = 0
    anomalies: list[str] = field(default_factory=list)
    structures: int = 0
    max_refs: int = 0  # most elements (reference instances + shapes + texts) in one structure


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

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def _union(a, b):
    if a is None:
        return b
    if b is None:
        return a
    return (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))


def sniff_format(path: Path) -> str:
    with open(path, "rb") as fh:
        head = fh.read(16)
    if head.startswith(b"%SEMI-OASIS\r\n"):
        return "oas"
    if len(head) >= 4 and head[2:4] == b"\x00\x02":
        return "gds"
    raise InputError("FILE", str(path), "a GDSII or OASIS file")


# ----------------------------------------------------------------------------------------------
# KLayout
# ----------------------------------------------------------------------------------------------
def read_klayout(path: Path, lattice: tuple[int, int, int] | None, posts_layer: tuple[int, int],
                 post_names: Any = None) -> Observed:
    import klayout.db as db

    fmt = sniff_format(path)
    ly = db.Layout()
    ly.read(str(path))
    ob = Observed("klayout", fmt, dbu_um=ly.dbu)
    ob.top_cells = [c.name for c in ly.top_cells()]
    ob.structures = ly.cells()
    tops = [c for c in ly.top_cells() if post_names is None or c.name not in set(post_names)]
    if len(tops) != 1:
        return ob
    top = tops[0]
    li_posts = None
    for li in ly.layer_indexes():
        info = ly.get_info(li)
        if not top.begin_shapes_rec(li).at_end():
            ob.layers.add((info.layer, info.datatype))
        if (info.layer, info.datatype) == posts_layer:
            li_posts = li
    pn = None if post_names is None else set(post_names)

    def is_post(c) -> bool:
        return (c.name in pn) if pn is not None else not c.child_cells()

    if lattice is not None:
        cx, oP, P = lattice
    memo: dict[int, tuple[Counter, Counter, int]] = {}

    def content(ci: int) -> tuple[Counter, Counter, int]:
        """(references per post cell, posts-layer rectangles per size, posts off the lattice) of cell
        ``ci`` with its intermediate (non-post) child cells expanded."""
        if ci in memo:
            return memo[ci]
        cell = ly.cell(ci)
        refs: Counter = Counter()
        flatc: Counter = Counter()
        off = 0
        nrefs = 0
        for inst in cell.each_inst():
            arr = inst.cell_inst
            n = arr.size()
            nrefs += n
            child = ly.cell(inst.cell_index)
            nm = child.name
            if arr.is_complex():
                ob.anomalies.append(f"a reference to {nm} is rotated, mirrored or magnified")
            disps = [inst.trans.disp] if n == 1 else [t.disp for t in arr.each_trans()]
            if is_post(child):
                refs[nm] += n
                if nm not in ob.cell_rects:
                    rects = []
                    for li in ly.layer_indexes():
                        info = ly.get_info(li)
                        for sh in child.shapes(li).each():
                            b = sh.bbox()
                            if not (sh.is_box() or (sh.is_polygon() and sh.polygon.is_box())):
                                ob.anomalies.append(f"cell {nm}: a non-rectangular shape on {info.layer}/{info.datatype}")
                            rects.append((info.layer, info.datatype, b.width(), b.height(), b.center().x, b.center().y))
                    if child.child_cells():
                        ob.anomalies.append(f"cell {nm} has child cells")
                    ob.cell_rects[nm] = rects
                if lattice is not None:
                    off += sum(((d.x - cx - oP) % P != 0) or ((d.y - cx - oP) % P != 0) for d in disps)
            else:
                sr, sf, so = content(inst.cell_index)
                if lattice is not None and any(d.x % P or d.y % P for d in disps):
                    ob.anomalies.append(f"references to structure {nm} off the lattice period")
                for k, v in sr.items():
                    refs[k] += n * v
                for k, v in sf.items():
                    flatc[k] += n * v
                off += n * so
        nrefs += sum(cell.shapes(li).size() for li in ly.layer_indexes())
        ob.max_refs = max(ob.max_refs, nrefs)
        if li_posts is not None:
            for sh in cell.shapes(li_posts).each():
                b = sh.bbox()
                if not (sh.is_box() or (sh.is_polygon() and sh.polygon.is_box())):
                    ob.anomalies.append(f"a non-rectangular post in cell {cell.name}")
                flatc[(b.width(), b.height())] += 1
                if lattice is not None:
                    c = b.center()
                    off += ((c.x - cx - oP) % P != 0) or ((c.y - cx - oP) % P != 0)
        memo[ci] = (refs, flatc, int(off))
        return memo[ci]

    refs, flatc, off = content(top.cell_index())
    ob.ref_counts.update(refs)
    ob.flat_counts.update(flatc)
    if li_posts is not None:
        pb = top.bbox_per_layer(li_posts)
        if not pb.empty():
            ob.posts_bbox = (pb.left, pb.bottom, pb.right, pb.top)
    b = top.bbox()
    if not b.empty():
        ob.bbox = (b.left, b.bottom, b.right, b.top)
    ob.off_lattice = int(off)
    return ob


# ----------------------------------------------------------------------------------------------
# gdstk
# ----------------------------------------------------------------------------------------------
class _captured_stderr:
    """Redirect file descriptor 2 (where C libraries print) to a temporary file while active."""

    def __enter__(self):
        import tempfile
        self._tmp = tempfile.TemporaryFile()
        try:
            sys.stderr.flush()
        except (OSError, ValueError, AttributeError):
            pass
        try:
            self._saved = os.dup(2)
            os.dup2(self._tmp.fileno(), 2)
        except OSError:
            self._saved = None
        return self

    def __exit__(self, *exc):
        if self._saved is not None:
            os.dup2(self._saved, 2)
            os.close(self._saved)
            self._saved = None
        self._tmp.close()
        return False

    def text(self) -> str:
        try:
            self._tmp.seek(0)
            return self._tmp.read().decode("utf-8", "replace")[-500:]
        except OSError:
            return ""


def read_gdstk(path: Path, lattice: tuple[int, int, int] | None, posts_layer: tuple[int, int],
               post_names: Any = None) -> Observed:
    import gdstk

    fmt = sniff_format(path)
    with _captured_stderr() as cap:  # gdstk prints '[GDSTK] ...' lines from C on damaged files
        try:
            lib = gdstk.read_oas(str(path), unit=1e-6) if fmt == "oas" else gdstk.read_gds(str(path), unit=1e-6)
        except (RuntimeError, OSError) as e:
            said = " ".join(cap.text().split())
            raise RuntimeError(f"{said} {e}".strip()) from None
    ob = Observed("gdstk", fmt, dbu_um=lib.precision / lib.unit)
    ob.top_cells = [c.name for c in lib.top_level()]
    ob.structures = len(lib.cells)
    tops = [c for c in lib.top_level() if post_names is None or c.name not in set(post_names)]
    if len(tops) != 1:
        return ob
    top = tops[0]
    s = 1e3  # um -> nm
    pn = None if post_names is None else set(post_names)

    def is_post(c) -> bool:
        return (c.name in pn) if pn is not None else not c.references

    for c in top.dependencies(True):
        if not is_post(c):
            continue
        rects = []
        for p in c.polygons:
            pts = np.rint(p.points * s).astype(np.int64)
            x0, y0 = pts.min(0)
            x1, y1 = pts.max(0)
            if len(pts) != 4 or len(set(pts[:, 0].tolist())) != 2 or len(set(pts[:, 1].tolist())) != 2:
                ob.anomalies.append(f"cell {c.name}: a non-rectangular shape")
            rects.append((p.layer, p.datatype, int(x1 - x0), int(y1 - y0), int(x0 + x1) // 2, int(y0 + y1) // 2))
        if c.references:
            ob.anomalies.append(f"cell {c.name} has child cells")
        ob.cell_rects[c.name] = rects
    memo: dict[str, tuple] = {}

    def content(cell):
        """(post refs per name, flat posts per size, off lattice, posts bbox, layers) of ``cell`` with its
        intermediate child cells expanded (their references at lattice-period offsets)."""
        if cell.name in memo:
            return memo[cell.name]
        refs: Counter = Counter()
        flatc: Counter = Counter()
        off = 0
        pbb = None
        layers = set()
        nrefs = 0
        for p in cell.polygons:
            layers.add((p.layer, p.datatype))
        for lb in cell.labels:
            layers.add((lb.layer, lb.texttype))
        for r in cell.references:
            child = r.cell
            nm = child.name if hasattr(child, "name") else str(child)
            o = np.array([r.origin[0], r.origin[1]])
            pos = np.asarray(r.repetition.get_offsets()) + o if r.repetition.size else o[None, :]
            pos = np.rint(pos * s).astype(np.int64)
            nrefs += len(pos)
            if r.rotation or r.magnification != 1 or r.x_reflection:
                ob.anomalies.append(f"a reference to {nm} is rotated, mirrored or magnified")
            if not hasattr(child, "name") or is_post(child):
                refs[nm] += len(pos)
                if lattice is not None:
                    cx, oP, P = lattice
                    off += int(np.count_nonzero(((pos - cx - oP) % P != 0).any(axis=1)))
                for (l_, d_, w, h, ccx, ccy) in ob.cell_rects.get(nm, []):
                    layers.add((l_, d_))
                    if (l_, d_) == posts_layer:
                        bb = (int(pos[:, 0].min()) + ccx - w // 2, int(pos[:, 1].min()) + ccy - h // 2,
                              int(pos[:, 0].max()) + ccx + w // 2, int(pos[:, 1].max()) + ccy + h // 2)
                        pbb = _union(pbb, bb)
                continue
            sr, sf, so, sb, sl = content(child)
            if lattice is not None and np.any(pos % lattice[2] != 0):
                ob.anomalies.append(f"references to structure {nm} off the lattice period")
            n = len(pos)
            for k, v in sr.items():
                refs[k] += n * v
            for k, v in sf.items():
                flatc[k] += n * v
            off += n * so
            layers |= sl
            if sb is not None:
                pbb = _union(pbb, (sb[0] + int(pos[:, 0].min()), sb[1] + int(pos[:, 1].min()),
                                   sb[2] + int(pos[:, 0].max()), sb[3] + int(pos[:, 1].max())))
        ob.max_refs = max(ob.max_refs, nrefs + len(cell.polygons) + len(cell.labels))
        for p in cell.polygons:
            if (p.layer, p.datatype) == posts_layer:
                pts = np.rint(p.points * s).astype(np.int64)
                x0, y0 = pts.min(0)
                x1, y1 = pts.max(0)
                flatc[(int(x1 - x0), int(y1 - y0))] += 1
                pbb = _union(pbb, (int(x0), int(y0), int(x1), int(y1)))
                if lattice is not None:
                    cx, oP, P = lattice
                    off += ((int(x0 + x1) // 2 - cx - oP) % P != 0) or ((int(y0 + y1) // 2 - cx - oP) % P != 0)
        memo[cell.name] = (refs, flatc, int(off), pbb, layers)
        return memo[cell.name]

    refs, flatc, off, pbb, layers = content(top)
    ob.ref_counts.update(refs)
    ob.flat_counts.update(flatc)
    ob.layers |= layers
    ob.posts_bbox = pbb
    (a, b), (c2, d) = top.bounding_box()
    ob.bbox = (int(round(a * s)), int(round(b * s)), int(round(c2 * s)), int(round(d * s)))
    ob.off_lattice = int(off)
    return ob


# ----------------------------------------------------------------------------------------------
# streaming GDSII scanner
# ----------------------------------------------------------------------------------------------
def _real8(b: bytes) -> float:
    v = int.from_bytes(b, "big")
    sign = -1.0 if v >> 63 else 1.0
    exp = (v >> 56) & 0x7F
    mant = v & ((1 << 56) - 1)
    return sign * mant / float(1 << 56) * 16.0 ** (exp - 64)


_SREF_T = np.array([0x00040A00, 0x00081206, 0, 0x000C1003, 0, 0, 0x00041100], dtype=np.uint32)
_SREF_N = np.frombuffer(_SREF_T.astype(">u4").tobytes(), dtype=np.uint32)  # raw big-endian bytes, native view
_SLACK_DBU = 100_000  # exact posts bbox for cells up to 200 um wide (see GdsScanner._sref_run)
_BND_DTYPE = np.dtype({"names": ["h", "lh", "layer", "dh", "dt", "xyh", "xy", "end"],
                       "formats": [">u4", ">u4", ">i2", ">u4", ">i2", ">u4", (">i4", (10,)), ">u4"],
                       "offsets": [0, 4, 8, 10, 14, 16, 20, 60], "itemsize": 64})


class GdsScanner:
    """Streaming GDSII reader reducing a file to an :class:`Observed` with bounded memory."""

    CHUNK = 32 << 20

    def __init__(self, path: Path, lattice: tuple[int, int, int] | None, posts_layer: tuple[int, int],
                 progress: bool = False, post_names: Any = None):
        self.path, self.lattice, self.posts_layer, self.progress = path, lattice, posts_layer, progress
        self.post_names = None if post_names is None else set(post_names)

    def run(self) -> Observed:
        ob = Observed("stream", "gds")
        structs: dict[str, dict[str, Any]] = {}
        refs: dict[str, dict[str, Any]] = {}  # structure -> sname -> {"n", "min", "max"}
        flat: dict[str, dict[tuple[int, int], list]] = {}  # structure -> (w,h) -> [n, bbox]
        texts: dict[str, list] = {}
        cur = None
        el: dict[str, Any] | None = None
        off: dict[str, int] = {}  # posts off the lattice, per structure
        cand: dict[str, list] = {}  # SREF bounding-box candidates per structure
        lat = self.lattice
        size = self.path.stat().st_size
        bar = None
        if self.progress:
            from tqdm.auto import tqdm
            bar = tqdm(total=size, unit="B", unit_scale=True, desc=f"scan {self.path.name}")
        endlib = False
        with open(self.path, "rb") as fh:
            buf = b""
            pos = 0
            eof = False
            consumed = 0
            while True:
                if len(buf) - pos < 65536 + 8 and not eof:
                    chunk = fh.read(self.CHUNK)
                    if not chunk:
                        eof = True
                    consumed += len(chunk)
                    buf = buf[pos:] + chunk
                    pos = 0
                    if bar is not None:
                        bar.update(len(chunk))
                if len(buf) - pos < 4:
                    if len(buf) - pos:
                        ob.anomalies.append("trailing bytes after the last record")
                    break
                ln = (buf[pos] << 8) | buf[pos + 1]
                rt = buf[pos + 2]
                if ln < 4 or pos + ln > len(buf):
                    ob.anomalies.append(f"corrupt record at byte {consumed - (len(buf) - pos)}")
                    break
                # ---- fast paths -------------------------------------------------------------
                if cur is not None and el is None and rt in (0x0A, 0x08) and len(buf) - pos >= 4096:
                    if rt == 0x0A:
                        nall = (len(buf) - pos) // 28
                        # look at a short window first (leaf structures of hierarchical files are short runs)
                        for nmax in ((min(nall, 16384), nall) if nall > 16384 else (nall,)):
                            v = np.frombuffer(buf, dtype=np.uint32, count=nmax * 7, offset=pos).reshape(nmax, 7)
                            okm = (v[:, 0] == _SREF_N[0]) & (v[:, 1] == _SREF_N[1]) & \
                                (v[:, 3] == _SREF_N[3]) & (v[:, 6] == _SREF_N[6])
                            m = nmax if okm.all() else int(np.argmin(okm))
                            if m < nmax:
                                break
                        if m > 0:
                            v = v[:m]
                            self._sref_run(cur, v[:, 2], v[:, 4:6].byteswap().view(np.int32), refs, cand, off)
                            pos += 28 * m
                            continue
                    else:
                        nall = (len(buf) - pos) // 64
                        for nmax in ((min(nall, 16384), nall) if nall > 16384 else (nall,)):
                            v = np.frombuffer(buf, dtype=_BND_DTYPE, count=nmax, offset=pos)
                            okm = (v["h"] == 0x00040800) & (v["lh"] == 0x00060D02) & (v["dh"] == 0x00060E02) & \
                                (v["xyh"] == 0x002C1003) & (v["end"] == 0x00041100)
                            m = nmax if okm.all() else int(np.argmin(okm))
                            if m < nmax:
                                break
                        if m > 0:
                            v = v[:m]
                            xy = v["xy"].astype(np.int64)
                            x, y = xy[:, 0::2], xy[:, 1::2]
                            x0, x1, y0, y1 = x.min(1), x.max(1), y.min(1), y.max(1)
                            rect = ((np.count_nonzero(x == x0[:, None], axis=1) == 3)
                                    & (np.count_nonzero(y == y0[:, None], axis=1) == 3)
                                    & (x[:, 0] == x[:, 4]) & (y[:, 0] == y[:, 4])
                                    & ((x[:, :4] == x0[:, None]) | (x[:, :4] == x1[:, None])).all(1))
                            if not rect.all():
                                ob.anomalies.append(f"{int((~rect).sum())} non-rectangular boundaries in {cur}")
                            ld = v["layer"].astype(np.int64) * 65536 + v["dt"].astype(np.int64)
                            key = ((x1 - x0) << 32) + (y1 - y0)
                            comb = np.stack([ld, key], 1)
                            uk, inv = np.unique(comb, axis=0, return_inverse=True)
                            inv = inv.reshape(-1)
                            fd = flat.setdefault(cur, {})
                            for j, (ldj, kj) in enumerate(uk.tolist()):
                                sel = inv == j
                                lay = (ldj >> 16, ldj & 0xFFFF)
                                ob.layers.add(lay)
                                wh = (kj >> 32, kj & 0xFFFFFFFF)
                                bb = (int(x0[sel].min()), int(y0[sel].min()), int(x1[sel].max()), int(y1[sel].max()))
                                e = fd.setdefault((lay, wh), [0, None])
                                e[0] += int(sel.sum())
                                e[1] = _union(e[1], bb)
                            if lat is not None:
                                cx, oP, P = lat
                                onposts = ld == self.posts_layer[0] * 65536 + self.posts_layer[1]
                                ccx = (x0 + x1) // 2
                                ccy = (y0 + y1) // 2
                                bad = ((ccx - cx - oP) % P != 0) | ((ccy - cx - oP) % P != 0)
                                off[cur] = off.get(cur, 0) + int(np.count_nonzero(bad & onposts))
                            pos += 64 * m
                            continue
                # ---- generic record ---------------------------------------------------------
                data = buf[pos + 4:pos + ln]
                pos += ln
                if rt == 0x04:  # ENDLIB: anything after it is padding (tools pad to 2048-byte blocks)
                    endlib = True
                    break
                if rt == 0x03:  # UNITS
                    ob.dbu_um = _real8(data[:8])
                elif rt == 0x05:  # BGNSTR
                    cur = ""
                elif rt == 0x06:  # STRNAME
                    cur = data.rstrip(b"\0").decode("ascii", "replace")
                    structs[cur] = {"rects": [], "other": 0}
                elif rt == 0x07:  # ENDSTR
                    cur = None
                elif rt in (0x08, 0x09, 0x0A, 0x0B, 0x0C, 0x15, 0x2D):
                    el = {"type": rt}
                elif rt == 0x0D and el is not None:
                    el["layer"] = struct.unpack(">h", data[:2])[0]
                elif rt in (0x0E, 0x16, 0x2E) and el is not None:
                    el["dt"] = struct.unpack(">h", data[:2])[0]
                elif rt == 0x12 and el is not None:
                    el["sname"] = data.rstrip(b"\0").decode("ascii", "replace")
                elif rt == 0x13 and el is not None:
                    el["colrow"] = struct.unpack(">hh", data[:4])
                elif rt == 0x10 and el is not None:
                    el["xy"] = np.frombuffer(data, dtype=">i4").astype(np.int64).reshape(-1, 2)
                elif rt == 0x1A and el is not None:
                    el["strans"] = struct.unpack(">H", data[:2])[0]
                elif rt in (0x1B, 0x1C) and el is not None:
                    el["magangle"] = True
                elif rt == 0x11 and el is not None:  # ENDEL
                    off[cur] = off.get(cur, 0) + self._element(ob, cur, el, structs, refs, flat, texts)
                    el = None
        if bar is not None:
            bar.close()
        if not endlib:
            where = "; ".join(ob.anomalies[-1:]) or f"ends after {size:,} bytes"
            raise InputError("FILE", str(self.path), "a complete GDSII file (ending with an ENDLIB record)",
                             detail=f"truncated or damaged: {where}")
        # ---- reduce -------------------------------------------------------------------------
        for sname, cl in cand.items():
            if not cl:
                continue
            w, xy = _prune(cl)
            for word in np.unique(w).tolist():
                nm = int(word).to_bytes(4, "little").rstrip(b"\0").decode("ascii", "replace")
                pts = xy[w == word]
                rr = refs[sname][nm]
                mn, mx = pts.min(0), pts.max(0)
                rr["min"] = mn if rr["min"] is None else np.minimum(rr["min"], mn)
                rr["max"] = mx if rr["max"] is None else np.maximum(rr["max"], mx)
        children = {n for s in refs.values() for n in s}
        ob.top_cells = [n for n in structs if n not in children]
        pn = self.post_names
        tops = [n for n in ob.top_cells if pn is None or n not in pn]

        def is_post(name: str) -> bool:
            return (name in pn) if pn is not None else (name not in refs)

        for name, s in structs.items():
            if name in tops or not is_post(name):
                continue
            rects = list(s["rects"])
            for (lay, wh), (n, bb) in flat.get(name, {}).items():
                rects += [(lay[0], lay[1], wh[0], wh[1], (bb[0] + bb[2]) // 2, (bb[1] + bb[3]) // 2)] * n
            ob.cell_rects[name] = rects
            if name in refs:
                ob.anomalies.append(f"cell {name} has child cells")
        ob.structures = len(structs)
        ob.max_refs = max((sum(rr["n"] for rr in refs.get(S, {}).values())
                           + sum(e[0] for e in flat.get(S, {}).values()) + len(texts.get(S, []))
                           for S in structs), default=0)
        if len(tops) == 1:
            top = tops[0]
            P_, F_, off_top, T_ = self._content(top, refs, flat, off, texts, structs, is_post, ob, {}, ())
            pbb = None
            bb = None
            for nm, (n, _, mn, mx) in P_.items():
                ob.ref_counts[nm] += n
                for (l_, d_, w, h, ccx, ccy) in ob.cell_rects.get(nm, []):
                    b = (int(mn[0]) + ccx - w // 2, int(mn[1]) + ccy - h // 2,
                         int(mx[0]) + ccx + w // 2, int(mx[1]) + ccy + h // 2)
                    bb = _union(bb, b)
                    if (l_, d_) == self.posts_layer:
                        pbb = _union(pbb, b)
                    ob.layers.add((l_, d_))
            for (lay, wh), (n, b) in F_.items():
                ob.layers.add(lay)
                bb = _union(bb, b)
                if lay == self.posts_layer:
                    ob.flat_counts[wh] += n
                    pbb = _union(pbb, b)
            for (lay, x, y) in T_:
                ob.layers.add(lay)
                bb = _union(bb, (x, y, x, y))
            ob.posts_bbox = pbb
            ob.bbox = bb
            ob.off_lattice = off_top
        return ob

    def _content(self, S, refs, flat, off, texts, structs, is_post, ob, memo, stack):
        """Structure ``S`` flattened: (post cell -> [references, off lattice, min, max position]),
        ((layer, size) -> [rectangles, bbox]), off-lattice rectangles, texts. Intermediate structures
        are expanded (their references must sit at one lattice-compatible offset, e.g. the origin)."""
        if S in memo:
            return memo[S]
        if S in stack:
            ob.anomalies.append(f"structure {S} references itself")
            return {}, {}, 0, []
        P_: dict[str, list] = {}
        F_: dict = {k: [v[0], v[1]] for k, v in flat.get(S, {}).items()}
        offs = off.get(S, 0)
        T_ = list(texts.get(S, []))
        lat = self.lattice
        for nm, rr in refs.get(S, {}).items():
            if is_post(nm) or nm not in structs:
                e = P_.setdefault(nm, [0, 0, None, None])
                e[0] += rr["n"]
                e[1] += rr.get("off", 0)
                e[2] = rr["min"] if e[2] is None else np.minimum(e[2], rr["min"])
                e[3] = rr["max"] if e[3] is None else np.maximum(e[3], rr["max"])
                continue
            sP, sF, soff, sT = self._content(nm, refs, flat, off, texts, structs, is_post, ob, memo, stack + (S,))
            n, mn, mx = rr["n"], np.asarray(rr["min"]), np.asarray(rr["max"])
            if lat is not None and (np.any(mn != mx) or np.any(mn % lat[2] != 0)):
                ob.anomalies.append(f"references to structure {nm} at offsets {mn.tolist()}..{mx.tolist()}: "
                                    "the lattice check needs them at one multiple of the period")
            for pnm, (a, o, smin, smax) in sP.items():
                e = P_.setdefault(pnm, [0, 0, None, None])
                e[0] += n * a
                e[1] += n * o
                lo_, hi_ = smin + mn, smax + mx
                e[2] = lo_ if e[2] is None else np.minimum(e[2], lo_)
                e[3] = hi_ if e[3] is None else np.maximum(e[3], hi_)
            for key, (a, b) in sF.items():
                e = F_.setdefault(key, [0, None])
                e[0] += n * a
                e[1] = _union(e[1], (b[0] + int(mn[0]), b[1] + int(mn[1]), b[2] + int(mx[0]), b[3] + int(mx[1])))
            offs += n * soff
            T_ += [(lay, x + int(mn[0]), y + int(mn[1])) for (lay, x, y) in sT]
        memo[S] = (P_, F_, offs, T_)
        return memo[S]

    def _sref_run(self, cur, words, xy32, refs, cand, off) -> None:
        """A run of plain SREFs: counts (and posts off the lattice) per cell name (hashed bincount,
        collision-checked) and the refs within ``_SLACK_DBU`` of the run's extremes as bounding-box
        candidates."""
        words = np.ascontiguousarray(words)
        xy = xy32.astype(np.int64)
        bad = None
        if self.lattice is not None:
            cx, oP, P = self.lattice
            bad = ((xy - cx - oP) % P != 0).any(axis=1)
        dref = refs.setdefault(cur, {})
        if words.size < 65536:  # short run (a leaf structure of a hierarchical file): exact per name
            order = np.argsort(words)
            ws = words[order]
            starts = np.flatnonzero(np.concatenate([[True], ws[1:] != ws[:-1]]))
            uw = ws[starts]
            cnt = np.diff(np.append(starts, ws.size))
            xo = xy[order]
            mins = np.minimum.reduceat(xo, starts, axis=0)
            maxs = np.maximum.reduceat(xo, starts, axis=0)
            nbad = (np.add.reduceat(bad[order].astype(np.int64), starts) if bad is not None
                    else np.zeros(len(uw)))
            for g, (w, n, b) in enumerate(zip(uw.tolist(), cnt.tolist(), nbad.tolist())):
                nm = int(w).to_bytes(4, "little").rstrip(b"\0").decode("ascii", "replace")
                rr = dref.setdefault(nm, {"n": 0, "min": None, "max": None, "off": 0})
                rr["n"] += int(n)
                rr["off"] = rr.get("off", 0) + int(round(b))
                rr["min"] = mins[g] if rr["min"] is None else np.minimum(rr["min"], mins[g])
                rr["max"] = maxs[g] if rr["max"] is None else np.maximum(rr["max"], maxs[g])
            return
        bins = ((words ^ (words >> np.uint32(16))) & np.uint32(0xFFFF)).astype(np.intp)
        rep = np.zeros(65536, dtype=np.uint32)
        rep[bins] = words
        if np.any(rep[bins] != words):  # hash collision: exact but slower
            uw, inv = np.unique(words, return_inverse=True)
            inv = inv.reshape(-1)
            cnt = np.bincount(inv, minlength=len(uw))
            nbad = np.bincount(inv, weights=bad, minlength=len(uw)) if bad is not None else np.zeros(len(uw))
            triples = zip(uw.tolist(), cnt.tolist(), nbad.tolist())
        else:
            cnt = np.bincount(bins, minlength=65536)
            nz = np.flatnonzero(cnt)
            nbad = (np.bincount(bins, weights=bad, minlength=65536)[nz] if bad is not None
                    else np.zeros(nz.size))
            triples = zip(rep[nz].tolist(), cnt[nz].tolist(), nbad.tolist())
        for w, n, b in triples:
            nm = int(w).to_bytes(4, "little").rstrip(b"\0").decode("ascii", "replace")
            rr = dref.setdefault(nm, {"n": 0, "min": None, "max": None, "off": 0})
            rr["n"] += int(n)
            rr["off"] = rr.get("off", 0) + int(round(b))
        x, y = xy[:, 0], xy[:, 1]
        sel = ((x <= x.min() + _SLACK_DBU) | (x >= x.max() - _SLACK_DBU) | (y <= y.min() + _SLACK_DBU)
               | (y >= y.max() - _SLACK_DBU))
        cl = cand.setdefault(cur, [])
        cl.append((words[sel], xy[sel]))
        if sum(len(c[0]) for c in cl) > 1_000_000:
            cl[:] = [_prune(cl)]

    def _element(self, ob, cur, el, structs, refs, flat, texts) -> int:
        t = el["type"]
        xy = el.get("xy")
        if cur is None or xy is None:
            return 0
        if t == 0x0A:  # SREF
            rr = refs.setdefault(cur, {}).setdefault(el.get("sname", "?"), {"n": 0, "min": None, "max": None, "off": 0})
            rr["n"] += 1
            p = xy[0]
            rr["min"] = p if rr["min"] is None else np.minimum(rr["min"], p)
            rr["max"] = p if rr["max"] is None else np.maximum(rr["max"], p)
            if el.get("strans") or el.get("magangle"):
                ob.anomalies.append(f"a reference to {el.get('sname')} is rotated, mirrored or magnified")
            if self.lattice is not None:
                cx, oP, P = self.lattice
                rr["off"] = rr.get("off", 0) + int(((p[0] - cx - oP) % P != 0) or ((p[1] - cx - oP) % P != 0))
            return 0
        if t == 0x0B:  # AREF
            cols, rows = el.get("colrow", (1, 1))
            o, pc, pr = xy[0], xy[1], xy[2]
            dc = (pc - o) // max(cols, 1)
            dr = (pr - o) // max(rows, 1)
            rr = refs.setdefault(cur, {}).setdefault(el.get("sname", "?"), {"n": 0, "min": None, "max": None, "off": 0})
            rr["n"] += cols * rows
            corners = np.array([o, o + dc * (cols - 1), o + dr * (rows - 1), o + dc * (cols - 1) + dr * (rows - 1)])
            mn, mx = corners.min(0), corners.max(0)
            rr["min"] = mn if rr["min"] is None else np.minimum(rr["min"], mn)
            rr["max"] = mx if rr["max"] is None else np.maximum(rr["max"], mx)
            if self.lattice is not None:
                cx, oP, P = self.lattice
                bad = bool(((o - cx - oP) % P != 0).any() or (dc % P != 0).any() or (dr % P != 0).any())
                rr["off"] = rr.get("off", 0) + (cols * rows if bad else 0)
            return 0
        lay = (el.get("layer", -1), el.get("dt", 0))
        if t == 0x0C:
            texts.setdefault(cur, []).append((lay, int(xy[0][0]), int(xy[0][1])))
            return 0
        x0, y0 = xy.min(0)
        x1, y1 = xy.max(0)
        b = (int(x0), int(y0), int(x1), int(y1))
        is_rect = t in (0x08, 0x2D) and len(xy) == 5 and len(set(xy[:4, 0].tolist())) == 2 and \
            len(set(xy[:4, 1].tolist())) == 2 and (xy[0] == xy[4]).all()
        fd = flat.setdefault(cur, {})
        bad = 0
        if is_rect and lay == self.posts_layer and self.lattice is not None:
            cx, oP, P = self.lattice
            bad = int((((b[0] + b[2]) // 2 - cx - oP) % P != 0) or (((b[1] + b[3]) // 2 - cx - oP) % P != 0))
        if is_rect:
            e = fd.setdefault((lay, (b[2] - b[0], b[3] - b[1])), [0, None])
            e[0] += 1
            e[1] = _union(e[1], b)
        else:
            # a general polygon: keep it as a (layer, bbox) entry with a unique key
            e = fd.setdefault((lay, ("poly", len(fd))), [0, None])
            e[0] += 1
            e[1] = _union(e[1], b)
        return bad


def _prune(cl):
    w = np.concatenate([c[0] for c in cl])
    xy = np.concatenate([c[1] for c in cl])
    x, y = xy[:, 0], xy[:, 1]
    sel = ((x <= x.min() + _SLACK_DBU) | (x >= x.max() - _SLACK_DBU) | (y <= y.min() + _SLACK_DBU)
           | (y >= y.max() - _SLACK_DBU))
    return w[sel], xy[sel]


def read_stream(path: Path, lattice, posts_layer, progress: bool = False, post_names: Any = None) -> Observed:
    if sniff_format(path) != "gds":
        raise InputError("--reader", "stream", "klayout or gdstk for OASIS files (the scanner reads GDSII)")
    return GdsScanner(path, lattice, posts_layer, progress, post_names).run()


# ----------------------------------------------------------------------------------------------
# comparison
# ----------------------------------------------------------------------------------------------
def lattice_of(spec: LayoutSpec) -> tuple[int, int, int] | None:
    P = spec.period_nm
    if P is None:
        return None
    o = 0 if spec.design.lattice == "integer" else P // 2
    return spec.centre_nm, o, P


def compare(ob: Observed, spec: LayoutSpec, exp: Expected, *, top_name: str | None = None,
            frame: bool | None = None, expected_layers: set | None = None) -> tuple[list[str], np.ndarray]:
    """Mismatches between what was read and what the design implies, and the counts per type."""
    mm: list[str] = []
    top_name = top_name or spec.top_name
    frame = has_frame(spec) if frame is None else frame
    if abs(ob.dbu_um - 1e-3) > 1e-12:
        mm.append(f"database unit {ob.dbu_um:g} um, expected 0.001 um (1 nm)")
    tops = [t for t in ob.top_cells if t not in spec.post_names]  # unused post cells are harmless
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
        boxes = mark_boxes_nm(spec)
        fb = (min(b[0] for b in boxes), min(b[1] for b in boxes), max(b[2] for b in boxes), max(b[3] for b in boxes))
        if ob.bbox != fb:
            mm.append(f"layout bounding box {ob.bbox} nm, expected {fb} (the alignment marks)")
    if ob.bbox is not None and min(ob.bbox[:2]) < 0:
        mm.append(f"negative coordinates in the layout bounding box {ob.bbox}")
    L = spec.layers
    if expected_layers is None:
        expected_layers = {L.posts, L.label} | ({L.aperture, L.marks} if frame else set())
    if set(ob.layers) != set(expected_layers):
        mm.append(f"layers {sorted(ob.layers)}, expected {sorted(expected_layers)}")
    mm += ob.anomalies[:20]
    return mm, counts


def verify_layout(path: str | os.PathLike, spec: LayoutSpec, *, reader: str = "auto", test_array: Any = None,
                  workers: int | None = 1, progress: bool = False, expected: Expected | None = None,
                  max_refs: int | None = None) -> VerifyReport:
    """Read ``path`` back and compare it with ``spec`` (or with the calibration array ``test_array``).

    Hierarchical files are counted through the hierarchy (cells not named like post cells are
    expanded); ``max_refs``: also a mismatch when a structure holds more references than that."""
    path = Path(path)
    if not path.is_file():
        raise InputError("FILE", str(path), "an existing GDSII or OASIS file")
    reader = check_choice("--reader", reader, READERS)
    fmt = sniff_format(path)
    size = path.stat().st_size
    if reader == "auto":
        if fmt == "gds":
            reader = "stream" if size > STREAM_THRESHOLD_BYTES else "klayout"
        else:
            reader = "klayout" if size < (16 << 20) else "gdstk"
    lat = lattice_of(spec)
    t0 = time.perf_counter()
    if test_array is not None:
        exp = _expected_test_array(test_array)
        lat = None
    else:
        exp = expected or expected_content(spec, workers=workers, progress=progress)
    t_exp = time.perf_counter() - t0
    t0 = time.perf_counter()
    names = spec.post_names
    try:
        if reader == "klayout":
            ob = read_klayout(path, lat, spec.layers.posts, names)
        elif reader == "gdstk":
            ob = read_gdstk(path, lat, spec.layers.posts, names)
        else:
            ob = read_stream(path, lat, spec.layers.posts, progress, names)
    except InputError:
        raise
    except (RuntimeError, OSError, ValueError, EOFError) as e:
        # a truncated or damaged file: the reader libraries raise RuntimeError (klayout, gdstk) or OSError
        detail = " ".join(str(e).split())[:200] or type(e).__name__
        raise InputError("FILE", str(path), f"a complete, readable {'OASIS' if fmt == 'oas' else 'GDSII'} file "
                         f"(the {reader} reader failed)", detail=detail) from None
    t_read = time.perf_counter() - t0
    if test_array is not None:
        name = f"{spec.top_name.rsplit('_', 1)[0]}_CAL"
        mm, counts = compare(ob, spec, exp, top_name=name, frame=False,
                             expected_layers={spec.layers.posts, spec.layers.label})
    else:
        mm, counts = compare(ob, spec, exp)
    if max_refs is not None and ob.max_refs > max_refs:
        mm.append(f"a structure holds {ob.max_refs:,} elements (references and shapes), more than --max-refs "
                  f"{max_refs}")
    return VerifyReport(not mm, str(path), ob.reader, fmt, int(counts.sum()), exp.total, counts.tolist(),
                        exp.counts.tolist(), ob.posts_bbox, exp.posts_bbox_nm, ob.bbox,
                        sorted([list(x) for x in ob.layers]), mm, t_read, t_exp, size, ob.structures, ob.max_refs)


def _expected_test_array(ta: Any) -> Expected:
    s = ta.spec
    n = ta.block * ta.block
    counts = np.full(s.levels, n, dtype=np.int64)
    p = int(round(s.design.period_um * 1000))
    bb = None
    for k in range(s.levels):
        x, y = ta.block_origin_nm(k)
        w, h = (int(v) for v in s.post_sizes_nm[k])
        bb = _union(bb, (x - w // 2, y - h // 2, x + (ta.block - 1) * p + w // 2, y + (ta.block - 1) * p + h // 2))
    return Expected(counts, bb)


__all__ = ["GdsScanner", "Observed", "READERS", "VerifyReport", "compare", "read_gdstk", "read_klayout",
           "read_stream", "sniff_format", "verify_layout"]

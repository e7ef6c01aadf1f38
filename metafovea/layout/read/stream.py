"""Stream reader: :class:`GdsScanner`, a streaming GDSII record scanner written here, for GDSII files too large
to load whole.

It shares no code with the writer (:mod:`metafovea.layout.gds`): runs of 28-byte SREF groups and 64-byte
5-point BOUNDARY groups are recognised in the read buffer, checked and reduced with numpy; everything else is
parsed record by record. Memory is one read buffer plus a summary per structure (references per child name with
their position range, rectangles per layer and size with their bounding box, texts). The summaries are then
flattened from the top cell through the hierarchy.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.errors import InputError
from metafovea.layout.bbox import union_bbox
from metafovea.layout.read.base import Observed, add_moments, moments, sniff_format

_SREF_T = np.array([0x00040A00, 0x00081206, 0, 0x000C1003, 0, 0, 0x00041100], dtype=np.uint32)
_SREF_N = np.frombuffer(_SREF_T.astype(">u4").tobytes(), dtype=np.uint32)  # raw big-endian bytes, native view
_SLACK_DBU = 100_000  # exact posts bbox for cells up to 200 um wide (see GdsScanner._sref_run)
_BND_DTYPE = np.dtype({"names": ["h", "lh", "layer", "dh", "dt", "xyh", "xy", "end"],
                       "formats": [">u4", ">u4", ">i2", ">u4", ">i2", ">u4", (">i4", (10,)), ">u4"],
                       "offsets": [0, 4, 8, 10, 14, 16, 20, 60], "itemsize": 64})
_WINDOW = 16384  # groups looked at first when searching a run (leaf structures of hierarchical files are short)


def _real8(b: bytes) -> float:
    """GDSII 8-byte excess-64 real."""
    v = int.from_bytes(b, "big")
    sign = -1.0 if v >> 63 else 1.0
    exp = (v >> 56) & 0x7F
    mant = v & ((1 << 56) - 1)
    return sign * mant / float(1 << 56) * 16.0 ** (exp - 64)


def _word_name(w: int) -> str:
    """A 4-character SNAME from its raw record bytes read as a native (little-endian) uint32."""
    return int(w).to_bytes(4, "little").rstrip(b"\0").decode("ascii", "replace")


def _run_length(ok_of: Any, nall: int) -> int:
    """Number of leading groups for which ``ok_of(n)`` (a bool per group of the first ``n``) holds: a short
    window first, the whole buffer only when the window is all one run."""
    m = 0
    for nmax in ((min(nall, _WINDOW), nall) if nall > _WINDOW else (nall,)):
        okm = ok_of(nmax)
        m = nmax if okm.all() else int(np.argmin(okm))
        if m < nmax:
            break
    return m


def _prune(cl):
    """Bounding-box candidates (SNAME words, positions) reduced to those within ``_SLACK_DBU`` of the extremes."""
    w = np.concatenate([c[0] for c in cl])
    xy = np.concatenate([c[1] for c in cl])
    x, y = xy[:, 0], xy[:, 1]
    sel = ((x <= x.min() + _SLACK_DBU) | (x >= x.max() - _SLACK_DBU) | (y <= y.min() + _SLACK_DBU)
           | (y >= y.max() - _SLACK_DBU))
    return w[sel], xy[sel]


class GdsScanner:
    """Streaming GDSII reader reducing a file to an :class:`Observed` with bounded memory.

    :meth:`run` scans the records (:meth:`_scan`), collecting per structure ``refs`` (child name ->
    ``{"n", "min", "max", "off"}``: references, their position range, those off the lattice), ``flat``
    (``(layer, (w, h))`` -> ``[rectangles, bbox]``; other polygons under unique keys), ``texts`` and posts
    off the lattice, then flattens the top cell (:meth:`_content`) into the :class:`Observed`.
    """

    CHUNK = 32 << 20

    def __init__(self, path: Path, lattice: tuple[int, int, int] | None, posts_layer: tuple[int, int],
                 progress: bool = False, post_names: Any = None, sink: Any = None, sizes: dict | None = None):
        self.path, self.lattice, self.posts_layer, self.progress = path, lattice, posts_layer, progress
        self.post_names = None if post_names is None else set(post_names)
        # the post-by-post check: posts are handed to ``sink`` as they are read, at the positions written,
        # which are absolute when every structure is placed once at the origin (checked in _content)
        self.sink, self.sizes = sink, dict(sizes or {})
        names = list(post_names or [])
        words = np.array([int.from_bytes(n.encode("ascii", "replace")[:4].ljust(4, b"\0"), "little") for n in names],
                         dtype=np.uint32)
        order = np.argsort(words)
        self._pw, self._pk = words[order], order.astype(np.int64)
        self._index = {n: k for k, n in enumerate(names)}
        self.placements: dict[str, int] = {}

    def run(self) -> Observed:
        self.ob = Observed("stream", "gds")
        self.structs: dict[str, None] = {}  # structure names, in file order
        self.refs: dict[str, dict[str, Any]] = {}  # structure -> sname -> {"n", "min", "max", "off"}
        self.flat: dict[str, dict[tuple, list]] = {}  # structure -> (layer, (w, h)) -> [n, bbox]
        self.mom: dict[str, dict[tuple, list]] = {}  # structure -> layer -> [A, Sx, Sy] off the posts layer
        self.texts: dict[str, list] = {}
        self.off: dict[str, int] = {}  # posts off the lattice, per structure
        self.cand: dict[str, list] = {}  # SREF bounding-box candidates per structure
        self.cur: str | None = None  # the structure being read
        self.el: dict[str, Any] | None = None  # the element being read
        size = self.path.stat().st_size
        if not self._scan(size):
            where = "; ".join(self.ob.anomalies[-1:]) or f"ends after {size:,} bytes"
            raise InputError("FILE", str(self.path), "a complete GDSII file (ending with an ENDLIB record)",
                             detail=f"truncated or damaged: {where}")
        self._merge_candidates()
        tops, is_post = self._cells()
        if len(tops) == 1:
            self._top(tops[0], is_post)
        return self.ob

    # ---- scanning ------------------------------------------------------------------------------
    def _scan(self, size: int) -> bool:
        """Walk the file's records through one read buffer; True when the ENDLIB record was reached (anything
        after it is padding: tools pad to 2048-byte blocks)."""
        bar = None
        if self.progress:
            from tqdm.auto import tqdm
            bar = tqdm(total=size, unit="B", unit_scale=True, desc=f"scan {self.path.name}")
        try:
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
                            self.ob.anomalies.append("trailing bytes after the last record")
                        return False
                    ln = (buf[pos] << 8) | buf[pos + 1]
                    rt = buf[pos + 2]
                    if ln < 4 or pos + ln > len(buf):
                        self.ob.anomalies.append(f"corrupt record at byte {consumed - (len(buf) - pos)}")
                        return False
                    if self.cur is not None and self.el is None and rt in (0x0A, 0x08) and len(buf) - pos >= 4096:
                        n = self._sref_block(buf, pos) if rt == 0x0A else self._boundary_block(buf, pos)
                        if n:
                            pos += n
                            continue
                    data = buf[pos + 4:pos + ln]
                    pos += ln
                    if rt == 0x04:  # ENDLIB
                        return True
                    self._record(rt, data)
        finally:
            if bar is not None:
                bar.close()

    def _record(self, rt: int, data: bytes) -> None:
        """One record outside the fast paths."""
        el = self.el
        if rt == 0x03:  # UNITS
            self.ob.dbu_um = _real8(data[:8])
        elif rt == 0x05:  # BGNSTR
            self.cur = ""
        elif rt == 0x06:  # STRNAME
            self.cur = data.rstrip(b"\0").decode("ascii", "replace")
            self.structs[self.cur] = None
        elif rt == 0x07:  # ENDSTR
            self.cur = None
        elif rt in (0x08, 0x09, 0x0A, 0x0B, 0x0C, 0x15, 0x2D):
            self.el = {"type": rt}
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
            self.off[self.cur] = self.off.get(self.cur, 0) + self._element(el)
            self.el = None

    def _ref(self, name: str) -> dict[str, Any]:
        """The current structure's reference summary for child ``name``."""
        return self.refs.setdefault(self.cur, {}).setdefault(name, {"n": 0, "min": None, "max": None, "off": 0,
                                                                          "records": 0, "sx": 0, "sy": 0})

    def _sref_block(self, buf: bytes, pos: int) -> int:
        """Bytes of the run of plain 28-byte SREF groups (4-character SNAME, one point) at ``pos``, reduced
        by :meth:`_sref_run`; 0 when there is none."""
        nall = (len(buf) - pos) // 28

        def ok_of(n: int) -> np.ndarray:
            v = np.frombuffer(buf, dtype=np.uint32, count=n * 7, offset=pos).reshape(n, 7)
            return (v[:, 0] == _SREF_N[0]) & (v[:, 1] == _SREF_N[1]) & (v[:, 3] == _SREF_N[3]) & \
                (v[:, 6] == _SREF_N[6])

        m = _run_length(ok_of, nall)
        if m == 0:
            return 0
        v = np.frombuffer(buf, dtype=np.uint32, count=m * 7, offset=pos).reshape(m, 7)
        self._sref_run(v[:, 2], v[:, 4:6].byteswap().view(np.int32))
        return 28 * m

    def _boundary_block(self, buf: bytes, pos: int) -> int:
        """Bytes of the run of 64-byte 5-point BOUNDARY groups at ``pos``, reduced by :meth:`_boundary_run`;
        0 when there is none."""
        nall = (len(buf) - pos) // 64

        def ok_of(n: int) -> np.ndarray:
            v = np.frombuffer(buf, dtype=_BND_DTYPE, count=n, offset=pos)
            return (v["h"] == 0x00040800) & (v["lh"] == 0x00060D02) & (v["dh"] == 0x00060E02) & \
                (v["xyh"] == 0x002C1003) & (v["end"] == 0x00041100)

        m = _run_length(ok_of, nall)
        if m == 0:
            return 0
        self._boundary_run(np.frombuffer(buf, dtype=_BND_DTYPE, count=m, offset=pos))
        return 64 * m

    def _post_kinds(self, words: np.ndarray) -> np.ndarray:
        """Type index of each SNAME word, -2 for a name that is no post cell (a structure)."""
        if self._pw.size == 0:
            return np.full(words.shape, -2, dtype=np.int64)
        i = np.clip(np.searchsorted(self._pw, words), 0, self._pw.size - 1)
        return np.where(self._pw[i] == words, self._pk[i], -2)

    def _sink_refs(self, words: np.ndarray, xy: np.ndarray) -> None:
        k = self._post_kinds(words)
        sel = k >= 0
        if sel.any():
            self.sink(xy[sel, 0], xy[sel, 1], k[sel])

    def _sref_run(self, words, xy32) -> None:
        """A run of plain SREFs: counts (and posts off the lattice) per cell name (hashed bincount,
        collision-checked) and the refs within ``_SLACK_DBU`` of the run's extremes as bounding-box
        candidates."""
        words = np.ascontiguousarray(words)
        xy = xy32.astype(np.int64)
        if self.sink is not None:
            self._sink_refs(words, xy)
        bad = None
        if self.lattice is not None:
            cx, oP, P = self.lattice
            bad = ((xy - cx - oP) % P != 0).any(axis=1)
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
            sums = np.add.reduceat(xo, starts, axis=0)  # the placements' offsets summed (the frame's moments)
            for g, (w, n, b) in enumerate(zip(uw.tolist(), cnt.tolist(), nbad.tolist())):
                rr = self._ref(_word_name(w))
                rr["sx"] += int(sums[g, 0])
                rr["sy"] += int(sums[g, 1])
                rr["n"] += int(n)
                rr["records"] += int(n)
                rr["off"] += int(round(b))
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
            sums = np.stack([np.bincount(inv, weights=xy[:, k], minlength=len(uw)) for k in (0, 1)], 1)
            triples = zip(uw.tolist(), cnt.tolist(), nbad.tolist(), sums.tolist())
        else:
            cnt = np.bincount(bins, minlength=65536)
            nz = np.flatnonzero(cnt)
            nbad = (np.bincount(bins, weights=bad, minlength=65536)[nz] if bad is not None
                    else np.zeros(nz.size))
            sums = np.stack([np.bincount(bins, weights=xy[:, k], minlength=65536)[nz] for k in (0, 1)], 1)
            triples = zip(rep[nz].tolist(), cnt[nz].tolist(), nbad.tolist(), sums.tolist())
        for w, n, b, (sx, sy) in triples:  # float sums of int offsets: exact below 2^53 (9e6 refs at 1e9 nm)
            rr = self._ref(_word_name(w))
            rr["sx"] += sx
            rr["sy"] += sy
            rr["n"] += int(n)
            rr["records"] += int(n)
            rr["off"] += int(round(b))
        x, y = xy[:, 0], xy[:, 1]
        sel = ((x <= x.min() + _SLACK_DBU) | (x >= x.max() - _SLACK_DBU) | (y <= y.min() + _SLACK_DBU)
               | (y >= y.max() - _SLACK_DBU))
        cl = self.cand.setdefault(self.cur, [])
        cl.append((words[sel], xy[sel]))
        if sum(len(c[0]) for c in cl) > 1_000_000:
            cl[:] = [_prune(cl)]

    def _boundary_run(self, v: np.ndarray) -> None:
        """A run of 5-point BOUNDARYs: rectangles per (layer, size) with their bounding box, non-rectangles
        and posts-layer rectangles off the lattice counted."""
        ob, cur = self.ob, self.cur
        xy = v["xy"].astype(np.int64)
        x, y = xy[:, 0::2], xy[:, 1::2]
        x0, x1, y0, y1 = x.min(1), x.max(1), y.min(1), y.max(1)
        # a rectangle (starting at any corner, either orientation): closed, every edge axis-parallel and
        # non-degenerate, horizontal and vertical edges alternating
        hx, hy = np.diff(x, axis=1) != 0, np.diff(y, axis=1) != 0
        rect = ((x[:, 0] == x[:, 4]) & (y[:, 0] == y[:, 4]) & (hx ^ hy).all(1) & (hx[:, :3] != hx[:, 1:]).all(1))
        ld = v["layer"].astype(np.int64) * 65536 + v["dt"].astype(np.int64)
        bad_rect = ~rect & (ld == self.posts_layer[0] * 65536 + self.posts_layer[1])
        if bad_rect.any():
            ob.anomalies.append(f"{int(bad_rect.sum())} non-rectangular boundaries on the posts layer in {cur}")
        if self.sink is not None and cur not in self._index:  # a post cell's own rectangle is not a post
            onp = ld == self.posts_layer[0] * 65536 + self.posts_layer[1]
            if onp.any():
                kk = np.array([self.sizes.get((int(w), int(h)), -1)
                               for w, h in zip((x1 - x0)[onp].tolist(), (y1 - y0)[onp].tolist())], dtype=np.int64)
                self.sink(((x0 + x1) // 2)[onp], ((y0 + y1) // 2)[onp], kk)
        frame = ld != self.posts_layer[0] * 65536 + self.posts_layer[1]
        if frame.any():  # the frame's area moments per layer (the posts' rectangles are checked one by one)
            m = moments(xy[frame].reshape(-1, 5, 2))
            md = self.mom.setdefault(cur, {})
            for ldj in np.unique(ld[frame]).tolist():
                add_moments(md, (ldj >> 16, ldj & 0xFFFF), m[ld[frame] == ldj].sum(0))
        key = ((x1 - x0) << 32) + (y1 - y0)
        comb = np.stack([ld, key], 1)
        uk, inv = np.unique(comb, axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        fd = self.flat.setdefault(cur, {})
        for j, (ldj, kj) in enumerate(uk.tolist()):
            sel = inv == j
            lay = (ldj >> 16, ldj & 0xFFFF)
            ob.layers.add(lay)
            wh = (kj >> 32, kj & 0xFFFFFFFF)
            bb = (int(x0[sel].min()), int(y0[sel].min()), int(x1[sel].max()), int(y1[sel].max()))
            e = fd.setdefault((lay, wh), [0, None])
            e[0] += int(sel.sum())
            e[1] = union_bbox(e[1], bb)
        if self.lattice is not None:
            cx, oP, P = self.lattice
            onposts = ld == self.posts_layer[0] * 65536 + self.posts_layer[1]
            ccx = (x0 + x1) // 2
            ccy = (y0 + y1) // 2
            bad = ((ccx - cx - oP) % P != 0) | ((ccy - cx - oP) % P != 0)
            self.off[cur] = self.off.get(cur, 0) + int(np.count_nonzero(bad & onposts))

    def _element(self, el: dict[str, Any]) -> int:
        """One element read record by record into the current structure's summary; returns 1 for a
        posts-layer rectangle off the lattice (references off the lattice are counted per child)."""
        t = el["type"]
        xy = el.get("xy")
        if self.cur is None or xy is None:
            return 0
        if t == 0x0A:  # SREF
            rr = self._ref(el.get("sname", "?"))
            rr["n"] += 1
            rr["records"] += 1
            p = xy[0]
            rr["sx"] += int(p[0])
            rr["sy"] += int(p[1])
            rr["min"] = p if rr["min"] is None else np.minimum(rr["min"], p)
            rr["max"] = p if rr["max"] is None else np.maximum(rr["max"], p)
            if el.get("strans") or el.get("magangle"):
                self.ob.anomalies.append(f"a reference to {el.get('sname')} is rotated, mirrored or magnified")
            if self.lattice is not None:
                cx, oP, P = self.lattice
                rr["off"] += int(((p[0] - cx - oP) % P != 0) or ((p[1] - cx - oP) % P != 0))
            if self.sink is not None and el.get("sname") in self._index:
                self.sink(np.array([p[0]]), np.array([p[1]]), np.array([self._index[el["sname"]]]))
            return 0
        if t == 0x0B:  # AREF
            cols, rows = el.get("colrow", (1, 1))
            o, pc, pr = xy[0], xy[1], xy[2]
            dc = (pc - o) // max(cols, 1)
            dr = (pr - o) // max(rows, 1)
            rr = self._ref(el.get("sname", "?"))
            rr["n"] += cols * rows
            rr["records"] += 1
            tot = cols * rows * o + dc * rows * cols * (cols - 1) // 2 + dr * cols * rows * (rows - 1) // 2
            rr["sx"] += int(tot[0])
            rr["sy"] += int(tot[1])
            corners = np.array([o, o + dc * (cols - 1), o + dr * (rows - 1), o + dc * (cols - 1) + dr * (rows - 1)])
            mn, mx = corners.min(0), corners.max(0)
            rr["min"] = mn if rr["min"] is None else np.minimum(rr["min"], mn)
            rr["max"] = mx if rr["max"] is None else np.maximum(rr["max"], mx)
            if self.lattice is not None:
                cx, oP, P = self.lattice
                bad = bool(((o - cx - oP) % P != 0).any() or (dc % P != 0).any() or (dr % P != 0).any())
                rr["off"] += cols * rows if bad else 0
            if self.sink is not None and el.get("sname") in self._index:
                ii, jj = np.meshgrid(np.arange(cols), np.arange(rows))
                pts = o[None, :] + ii.reshape(-1, 1) * dc[None, :] + jj.reshape(-1, 1) * dr[None, :]
                self.sink(pts[:, 0], pts[:, 1], np.full(len(pts), self._index[el["sname"]]))
            return 0
        lay = (el.get("layer", -1), el.get("dt", 0))
        if t == 0x0C:
            self.texts.setdefault(self.cur, []).append((lay, int(xy[0][0]), int(xy[0][1])))
            return 0
        x0, y0 = xy.min(0)
        x1, y1 = xy.max(0)
        b = (int(x0), int(y0), int(x1), int(y1))
        is_rect = t in (0x08, 0x2D) and len(xy) == 5 and len(set(xy[:4, 0].tolist())) == 2 and \
            len(set(xy[:4, 1].tolist())) == 2 and (xy[0] == xy[4]).all()
        fd = self.flat.setdefault(self.cur, {})
        bad = 0
        if is_rect and lay == self.posts_layer and self.sink is not None and self.cur not in self._index:
            self.sink(np.array([(b[0] + b[2]) // 2]), np.array([(b[1] + b[3]) // 2]),
                      np.array([self.sizes.get((b[2] - b[0], b[3] - b[1]), -1)]))
        if is_rect and lay == self.posts_layer and self.lattice is not None:
            cx, oP, P = self.lattice
            bad = int((((b[0] + b[2]) // 2 - cx - oP) % P != 0) or (((b[1] + b[3]) // 2 - cx - oP) % P != 0))
        if lay != self.posts_layer:
            add_moments(self.mom.setdefault(self.cur, {}), lay, moments(xy))
        # a general polygon: kept as a (layer, bbox) entry with a unique key
        e = fd.setdefault((lay, (b[2] - b[0], b[3] - b[1]) if is_rect else ("poly", len(fd))), [0, None])
        e[0] += 1
        e[1] = union_bbox(e[1], b)
        return bad

    # ---- reduction -----------------------------------------------------------------------------
    def _merge_candidates(self) -> None:
        """Position ranges of the long SREF runs from their bounding-box candidates."""
        for sname, cl in self.cand.items():
            if not cl:
                continue
            w, xy = _prune(cl)
            for word in np.unique(w).tolist():
                pts = xy[w == word]
                rr = self.refs[sname][_word_name(word)]
                mn, mx = pts.min(0), pts.max(0)
                rr["min"] = mn if rr["min"] is None else np.minimum(rr["min"], mn)
                rr["max"] = mx if rr["max"] is None else np.maximum(rr["max"], mx)

    def _cells(self):
        """Top cells, post cells' shapes, structure count and the most elements in one structure; returns the
        top cells that are not post cells and the post-cell test."""
        ob, refs, flat = self.ob, self.refs, self.flat
        children = {n for s in refs.values() for n in s}
        ob.top_cells = [n for n in self.structs if n not in children]
        pn = self.post_names
        tops = [n for n in ob.top_cells if pn is None or n not in pn]

        def is_post(name: str) -> bool:
            return (name in pn) if pn is not None else (name not in refs)

        for name in self.structs:
            if name in tops or not is_post(name):
                continue
            rects = []
            for (lay, wh), (n, bb) in flat.get(name, {}).items():
                rects += [(lay[0], lay[1], wh[0], wh[1], (bb[0] + bb[2]) // 2, (bb[1] + bb[3]) // 2)] * n
            ob.cell_rects[name] = rects
            if name in refs:
                ob.anomalies.append(f"cell {name} has child cells")
        ob.structures = len(self.structs)
        ob.max_references = max((sum(rr["records"] for rr in refs.get(S, {}).values()) for S in self.structs),
                                default=0)
        ob.max_refs = max((sum(rr["n"] for rr in refs.get(S, {}).values())
                           + sum(e[0] for e in flat.get(S, {}).values()) + len(self.texts.get(S, []))
                           for S in self.structs), default=0)
        return tops, is_post

    def _top(self, top: str, is_post) -> None:
        """Counts, layers, bounding boxes and posts off the lattice of the top cell, through the hierarchy."""
        ob = self.ob
        P_, F_, off_top, T_, M_ = self._content(top, is_post, {}, ())
        pbb = None
        bb = None
        for nm, (n, _, mn, mx) in P_.items():
            ob.ref_counts[nm] += n
            for (l_, d_, w, h, ccx, ccy) in ob.cell_rects.get(nm, []):
                b = (int(mn[0]) + ccx - w // 2, int(mn[1]) + ccy - h // 2,
                     int(mx[0]) + ccx + w // 2, int(mx[1]) + ccy + h // 2)
                bb = union_bbox(bb, b)
                if (l_, d_) == self.posts_layer:
                    pbb = union_bbox(pbb, b)
                ob.layers.add((l_, d_))
        ob.frame_layers = {}
        ob.frame_moments = {lay: list(m) for lay, m in M_.items() if lay != self.posts_layer}
        for (lay, wh), (n, b) in F_.items():
            ob.layers.add(lay)
            bb = union_bbox(bb, b)
            if lay == self.posts_layer:
                ob.flat_counts[wh] += n
                pbb = union_bbox(pbb, b)
            else:
                e = ob.frame_layers.setdefault(lay, [0, None])
                e[0] += n
                e[1] = union_bbox(e[1], b)
        for (lay, x, y) in T_:
            ob.layers.add(lay)
            bb = union_bbox(bb, (x, y, x, y))
        ob.posts_bbox = pbb
        ob.bbox = bb
        ob.off_lattice = off_top

    def _content(self, S, is_post, memo, stack):
        """Structure ``S`` flattened: (post cell -> [references, off lattice, min, max position]),
        ((layer, size) -> [rectangles, bbox]), off-lattice rectangles, texts. Intermediate structures
        are expanded (their references must sit at one lattice-compatible offset, e.g. the origin)."""
        if S in memo:
            return memo[S]
        if S in stack:
            self.ob.anomalies.append(f"structure {S} references itself")
            return {}, {}, 0, [], {}
        P_: dict[str, list] = {}
        F_: dict = {k: [v[0], v[1]] for k, v in self.flat.get(S, {}).items()}
        M_: dict = {k: list(v) for k, v in self.mom.get(S, {}).items()}
        offs = self.off.get(S, 0)
        T_ = list(self.texts.get(S, []))
        lat = self.lattice
        for nm, rr in self.refs.get(S, {}).items():
            if is_post(nm) or nm not in self.structs:
                e = P_.setdefault(nm, [0, 0, None, None])
                e[0] += rr["n"]
                e[1] += rr["off"]
                e[2] = rr["min"] if e[2] is None else np.minimum(e[2], rr["min"])
                e[3] = rr["max"] if e[3] is None else np.maximum(e[3], rr["max"])
                continue
            self.placements[nm] = self.placements.get(nm, 0) + rr["n"]
            n, mn, mx = rr["n"], np.asarray(rr["min"]), np.asarray(rr["max"])
            if self.sink is not None and (self.placements[nm] > 1 or np.any(mn != 0) or np.any(mx != 0)):
                self.ob.anomalies.append(
                    f"structure {nm} is placed {self.placements[nm]} time(s) at offsets {mn.tolist()}..{mx.tolist()}: "
                    "the streaming reader checks posts one by one only in structures placed once at the origin "
                    "(as metafovea writes them); use reader='gdstk'")
            sP, sF, soff, sT, sM = self._content(nm, is_post, memo, stack + (S,))
            for lay, m in sM.items():
                add_moments(M_, lay, m, copies=n, offsets=(rr["sx"], rr["sy"]))
            if lat is not None and (np.any(mn != mx) or np.any(mn % lat[2] != 0)):
                self.ob.anomalies.append(f"references to structure {nm} at offsets {mn.tolist()}..{mx.tolist()}: "
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
                e[1] = union_bbox(e[1], (b[0] + int(mn[0]), b[1] + int(mn[1]), b[2] + int(mx[0]), b[3] + int(mx[1])))
            offs += n * soff
            T_ += [(lay, x + int(mn[0]), y + int(mn[1])) for (lay, x, y) in sT]
        memo[S] = (P_, F_, offs, T_, M_)
        return memo[S]


def read_stream(path: Path, lattice, posts_layer, progress: bool = False, post_names: Any = None,
                sink: Any = None, sizes: dict | None = None) -> Observed:
    """Read the GDSII file ``path`` with :class:`GdsScanner` (an OASIS file is an :class:`InputError`);
    arguments as :func:`~metafovea.layout.read.klayout.read_klayout`, ``progress``: a bar over the bytes."""
    if sniff_format(path) != "gds":
        raise InputError("reader", "stream", "klayout or gdstk for OASIS files (the scanner reads GDSII)")
    return GdsScanner(path, lattice, posts_layer, progress, post_names, sink, sizes).run()

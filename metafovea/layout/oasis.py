"""OASIS (SEMI P39) writer for lens layouts, streaming, with compact repetitions.

Records written: START (version 1.0, unit 1000 per um = 1 nm, table offsets in START, all zero),
CELLNAME (implicit reference numbers: post cells 0..N-1, top cell N), CELL by reference number,
RECTANGLE (post cells, marks), POLYGON (ring quarters, g-delta point lists), TEXT (label),
PLACEMENT and CBLOCK (raw deflate), END (padded to 256 bytes, no validation).

The posts: per band, per site row and post type, one PLACEMENT of that post cell at the first site
with a repetition listing the others: type 5 (horizontal, varying spaces on a grid = the lattice
period, one byte per post for spaces < 128 periods) or none for a single post. Each band is one
CBLOCK. Lens rows contain few equal neighbours (mean run 1.3-1.6 sites), so per-row-per-type lists
capture the structure better than arrays.
"""

from __future__ import annotations

import zlib

import numpy as np

from metafovea.layout.frame import frame_shapes
from metafovea.layout.gds import band_index, task_index
from metafovea.layout.tiling import LayoutSpec, used_levels

MAGIC = b"%SEMI-OASIS\r\n"


def uint(v: int) -> bytes:
    if v < 0:
        raise ValueError("unsigned integer expected")
    out = bytearray()
    while True:
        b = v & 0x7F
        v >>= 7
        if v:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def sint(v: int) -> bytes:
    return uint((-v << 1) | 1 if v < 0 else v << 1)


def astring(s: str | bytes) -> bytes:
    b = s.encode("ascii") if isinstance(s, str) else s
    return uint(len(b)) + b


def gdelta(dx: int, dy: int) -> bytes:
    """g-delta form 2 (general): |dx| with sign, then signed dy."""
    return uint((abs(dx) << 2) | (2 if dx < 0 else 0) | 1) + sint(dy)


def uints(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised unsigned varints of a 1-D array of non-negative ints: (uint8 bytes concatenated,
    bytes per value)."""
    v = np.asarray(v, dtype=np.uint64)
    nb = np.ones(v.size, dtype=np.int64)
    if v.size == 0:
        return np.zeros(0, np.uint8), nb
    big = np.flatnonzero(v >= 128)
    if big.size == 0:
        return v.astype(np.uint8), nb
    vb = v[big]
    nbb = np.ones(big.size, dtype=np.int64)
    t = vb >> np.uint64(7)
    while np.any(t):
        nbb += t > 0
        t >>= np.uint64(7)
    nb[big] = nbb
    end = np.cumsum(nb)
    start = end - nb
    out = np.empty(int(end[-1]), dtype=np.uint8)
    small = np.ones(v.size, dtype=bool)
    small[big] = False
    out[start[small]] = v[small].astype(np.uint8)
    sb = start[big]
    for j in range(int(nbb.max())):
        sel = nbb > j
        byte = ((vb[sel] >> np.uint64(7 * j)) & np.uint64(0x7F)).astype(np.uint8)
        out[sb[sel] + j] = byte | ((nbb[sel] > j + 1).astype(np.uint8) << 7)
    return out, nb


def rectangle(layer: int, datatype: int, x: int, y: int, w: int, h: int) -> bytes:
    # info SWHXYRDL: W H X Y D L
    return bytes([20, 0x40 | 0x20 | 0x10 | 0x08 | 0x02 | 0x01]) + uint(layer) + uint(datatype) + \
        uint(w) + uint(h) + sint(x) + sint(y)


def polygon(layer: int, datatype: int, pts: np.ndarray) -> bytes:
    pts = np.asarray(pts, dtype=np.int64)
    d = np.diff(pts, axis=0)
    body = bytearray(uint(4) + uint(len(d)))
    for dx, dy in d.tolist():
        body += gdelta(dx, dy)
    return bytes([21, 0x20 | 0x10 | 0x08 | 0x02 | 0x01]) + uint(layer) + uint(datatype) + bytes(body) + \
        sint(int(pts[0, 0])) + sint(int(pts[0, 1]))


def text(layer: int, texttype: int, x: int, y: int, s: str) -> bytes:
    # info 0CNXYRTL: C X Y T L (string given inline)
    return bytes([19, 0x40 | 0x10 | 0x08 | 0x02 | 0x01]) + astring(s) + uint(layer) + uint(texttype) + \
        sint(x) + sint(y)


def oas_header(spec: LayoutSpec) -> bytes:
    """Magic, START, cell names, the post cells and the top cell's frame (ring, marks, label)."""
    out = bytearray(MAGIC)
    out += bytes([1]) + astring("1.0") + bytes([0]) + uint(1000) + uint(0) + bytes(12)
    used = used_levels(spec)
    for k in used:  # CELLNAME with explicit reference numbers: the post types a patch does not use are not defined
        out += bytes([4]) + astring(spec.post_names[k]) + uint(k)
    out += bytes([4]) + astring(spec.top_name) + uint(spec.levels)
    pl, pd = spec.layers.posts
    sizes = spec.post_sizes_nm.tolist()
    for k in used:
        wx, wy = sizes[k]
        out += bytes([13]) + uint(k)
        out += rectangle(pl, pd, -(wx // 2), -(wy // 2), wx, wy)
    out += bytes([13]) + uint(spec.levels)
    for sh in frame_shapes(spec):
        out += polygon(sh.layer[0], sh.layer[1], sh.points)
    tl, tt = spec.layers.label
    lx, ly = spec.label_position_nm()
    out += text(tl, tt, lx, ly, spec.label_text())
    return bytes(out)


def oas_footer() -> bytes:
    pad = 256 - 1 - 2 - 1  # record id, b-string length (2 bytes for 252), validation scheme
    return bytes([2]) + uint(pad) + bytes(pad) + uint(0)


def cblock(raw: bytes, level: int = 1) -> bytes:
    c = zlib.compressobj(level, zlib.DEFLATED, -15)
    comp = c.compress(raw) + c.flush()
    return bytes([34]) + uint(0) + uint(len(raw)) + uint(len(comp)) + comp


def encode_band_oas(spec: LayoutSpec, compress: int, band: tuple[int, int, int, int]) -> tuple[bytes, np.ndarray]:
    """PLACEMENT records of one band (one per row and post type), in a CBLOCK when ``compress > 0``."""
    k, r, c, xs, ys = band_index(spec, band)
    n = k.size
    counts = np.bincount(k, minlength=spec.levels)
    if n == 0:
        return b"", counts
    # stable sort by type (radix sort on uint8), keeping row-major order inside a type
    order = np.argsort(k, kind="stable")
    ks, rs, cs = k[order], r[order], c[order]
    new = np.ones(n, dtype=bool)
    new[1:] = (ks[1:] != ks[:-1]) | (rs[1:] != rs[:-1])
    starts = np.flatnonzero(new)
    ends = np.append(starts[1:], n)
    cont = ~new[1:]  # element i+1 continues the group of element i
    spaces, grid = _repetition_spaces(spec, cs, xs, cont)
    enc, nbytes = uints(spaces)
    boff = np.concatenate([[0], np.cumsum(nbytes)])
    # index of group g's first space: continuing elements before starts[g] = starts[g] - g
    sidx = starts - np.arange(starts.size)
    enc_b = enc.tobytes()
    grid_b = uint(grid)
    rep = (bytes([5]), grid_b) if grid > 1 else (bytes([4]), b"")
    parts = []
    xg = xs[cs[starts]].tolist()
    yg = ys[rs[starts]].tolist()
    kg = ks[starts].tolist()
    cnt_a = ends - starts
    cnts = cnt_a.tolist()
    b0 = boff[sidx].tolist()
    b1 = boff[sidx + np.maximum(cnt_a - 1, 0)].tolist()
    for g in range(starts.size):
        cnt = cnts[g]
        head = bytes([17, 0xF8 if cnt > 1 else 0xF0]) + uint(kg[g]) + sint(xg[g]) + sint(yg[g])
        if cnt == 1:
            parts.append(head)
        else:
            parts.append(head + rep[0] + uint(cnt - 2) + rep[1] + enc_b[b0[g]:b1[g]])
    raw = b"".join(parts)
    if compress > 0:
        return cblock(raw, compress), counts
    return raw, counts


def _scatter(out: np.ndarray, dst: np.ndarray, src: np.ndarray, src_start: np.ndarray, lengths: np.ndarray) -> None:
    """``out[dst[g]:dst[g] + lengths[g]] = src[src_start[g]:src_start[g] + lengths[g]]`` for every g."""
    lengths = np.asarray(lengths, dtype=np.int64)
    tot = int(lengths.sum())
    if tot == 0:
        return
    before = np.cumsum(lengths) - lengths
    ar = np.arange(tot, dtype=np.int64)
    out[np.repeat(dst - before, lengths) + ar] = src[np.repeat(src_start - before, lengths) + ar]


def _varint_field(out: np.ndarray, dst: np.ndarray, values: np.ndarray) -> None:
    enc, nb = uints(values)
    _scatter(out, dst, enc, np.cumsum(nb) - nb, nb)


def _zigzag(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.int64)
    return np.where(v < 0, ((-v) << 1) | 1, v << 1)


def _varint_len(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.uint64)
    n = np.ones(v.size, dtype=np.int64)
    t = v >> np.uint64(7)
    while True:
        nz = t > 0
        if not nz.any():
            return n
        n += nz
        t >>= np.uint64(7)


def _repetition_spaces(spec, cs: np.ndarray, xs: np.ndarray, cont: np.ndarray) -> tuple[np.ndarray, int]:
    """Spaces between repeated placements and their grid: in periods on a grid of P when every site lies
    exactly on the lattice (``spec.period_nm``), else in database units on a grid of 1."""
    if spec.period_nm is not None:
        return np.diff(cs)[cont], spec.period_nm
    return np.diff(xs[cs])[cont], 1


def placements(kg: np.ndarray, xg: np.ndarray, yg: np.ndarray, cnt: np.ndarray, spaces: np.ndarray,
               sp_start: np.ndarray, sp_len: np.ndarray, grid: int) -> np.ndarray:
    """PLACEMENT records (vectorised): group g places cell ``kg[g]`` at ``(xg, yg)`` and, with
    ``cnt[g] > 1``, repeats it with a type-5 (``grid`` > 1) or type-4 repetition whose encoded spaces are
    ``spaces[sp_start[g]:sp_start[g] + sp_len[g]]``. Same bytes as writing them one by one."""
    rep = cnt > 1
    grid_b = np.frombuffer(uint(grid), dtype=np.uint8) if grid > 1 else np.zeros(0, np.uint8)
    zx, zy = _zigzag(xg), _zigzag(yg)
    lk, lx, ly = _varint_len(kg), _varint_len(zx), _varint_len(zy)
    cm2 = np.where(rep, cnt - 2, 0)
    lc = _varint_len(cm2)
    length = 2 + lk + lx + ly + rep * (1 + lc + grid_b.size + sp_len)
    start = np.cumsum(length) - length
    out = np.empty(int(length.sum()), dtype=np.uint8)
    out[start] = 17
    out[start + 1] = np.where(rep, 0xF8, 0xF0)
    p = start + 2
    _varint_field(out, p, kg)
    p = p + lk
    _varint_field(out, p, zx)
    p = p + lx
    _varint_field(out, p, zy)
    p = p + ly
    ri = np.flatnonzero(rep)
    if ri.size:
        q = p[ri]
        out[q] = 5 if grid > 1 else 4
        q = q + 1
        _varint_field(out, q, cm2[ri])
        q = q + lc[ri]
        for j, b in enumerate(grid_b.tolist()):
            out[q + j] = b
        q = q + grid_b.size
        _scatter(out, q, spaces, sp_start[ri], sp_len[ri])
    return out


def encode_task_oas(spec: LayoutSpec, compress: int, task) -> tuple[list[bytes], np.ndarray]:
    """PLACEMENT records of one task (per row side, row and post type one placement with a repetition),
    both row sides in one CBLOCK when ``compress > 0``."""
    k, r, c, xs, sides = task_index(spec, task)
    n = k.size
    counts = np.zeros(spec.levels, dtype=np.int64)
    if n == 0:
        return [], counts
    order = np.argsort(k, kind="stable")
    ks, rs, cs = k[order], r[order], c[order]
    del order
    new = np.ones(n, dtype=bool)
    new[1:] = (ks[1:] != ks[:-1]) | (rs[1:] != rs[:-1])
    starts = np.flatnonzero(new)
    ends = np.append(starts[1:], n)
    cont = ~new[1:]
    spaces, grid = _repetition_spaces(spec, cs, xs, cont)
    enc, nbytes = uints(spaces)
    boff = np.concatenate([[0], np.cumsum(nbytes)])
    cnt = ends - starts
    sidx = starts - np.arange(starts.size)
    sp_start = boff[sidx]
    sp_len = boff[sidx + np.maximum(cnt - 1, 0)] - sp_start
    kg = ks[starts].astype(np.int64)
    xg = xs[cs[starts]]
    rg = rs[starts]
    parts = []
    for _, mask, ys in sides:
        sel = mask[rg]
        if sel.all():
            parts.append(placements(kg, xg, ys[rg], cnt, enc, sp_start, sp_len, grid))
            counts += np.bincount(kg, weights=cnt, minlength=spec.levels).astype(np.int64)
        else:
            g = np.flatnonzero(sel)
            parts.append(placements(kg[g], xg[g], ys[rg[g]], cnt[g], enc, sp_start[g], sp_len[g], grid))
            counts += np.bincount(kg[g], weights=cnt[g], minlength=spec.levels).astype(np.int64)
    raw = np.concatenate(parts).tobytes() if len(parts) > 1 else parts[0].tobytes()
    if compress > 0:
        return [cblock(raw, compress)], counts
    return [raw], counts

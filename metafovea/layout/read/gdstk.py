"""gdstk reader: gdstk's GDSII and OASIS readers (fast for large OASIS files).

The file is loaded whole; gdstk's own messages on a damaged file (printed from C on file descriptor 2) are
captured into the error. The top cell's content is counted through the hierarchy as in the KLayout reader.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.layout.bbox import union_bbox
from metafovea.layout.read.base import Observed, captured_stderr, moments, sniff_format


def read_gdstk(path: Path, lattice: tuple[int, int, int] | None, posts_layer: tuple[int, int],
               post_names: Any = None, sink: Any = None, sizes: dict | None = None) -> Observed:
    """Read ``path`` (GDSII or OASIS) with gdstk; arguments as :func:`~metafovea.layout.read.klayout.read_klayout`."""
    import gdstk

    fmt = sniff_format(path)
    with captured_stderr() as cap:  # gdstk prints '[GDSTK] ...' lines from C on damaged files
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
        frame = _frame_polygons(cell, posts_layer, layers)
        for lb in cell.labels:
            layers.add((lb.layer, lb.texttype))
        # references to post cells, counted per post cell after the loop (one array operation for a hierarchical
        # file's tens of thousands of single references instead of a few per reference): their origins (um) and
        # the positions (nm) of those with a repetition
        origins: dict[str, list] = {}
        placed: dict[str, list] = {}
        for r in cell.references:
            child = r.cell
            nm = child.name if hasattr(child, "name") else str(child)
            if r.rotation or r.magnification != 1 or r.x_reflection:
                ob.anomalies.append(f"a reference to {nm} is rotated, mirrored or magnified")
            if not hasattr(child, "name") or is_post(child):
                refs[nm] += 0  # the name's place among the counts: where its first reference is
                if r.repetition.size:
                    o = np.array([r.origin[0], r.origin[1]])
                    placed.setdefault(nm, []).append(np.rint((np.asarray(r.repetition.get_offsets()) + o) * s)
                                                     .astype(np.int64))
                else:
                    origins.setdefault(nm, []).append(r.origin)
                continue
            o = np.array([r.origin[0], r.origin[1]])
            pos = np.asarray(r.repetition.get_offsets()) + o if r.repetition.size else o[None, :]
            pos = np.rint(pos * s).astype(np.int64)
            nrefs += len(pos)
            sr, sf, so, sb, sl, sfr = content(child)
            _add_placed(frame, sfr, pos)
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
                pbb = union_bbox(pbb, (sb[0] + int(pos[:, 0].min()), sb[1] + int(pos[:, 1].min()),
                                       sb[2] + int(pos[:, 0].max()), sb[3] + int(pos[:, 1].max())))
        n, o_, pbb = _count_post_refs(origins, placed, s, lattice, ob.cell_rects, posts_layer, refs, layers, pbb)
        nrefs += n
        off += o_
        ob.max_refs = max(ob.max_refs, nrefs + len(cell.polygons) + len(cell.labels))
        ob.max_references = max(ob.max_references, len(cell.references))
        o_, pbb = _count_post_polygons([p for p in cell.polygons if (p.layer, p.datatype) == posts_layer], s, lattice,
                                       flatc, pbb)
        memo[cell.name] = (refs, flatc, int(off + o_), pbb, layers, frame)
        return memo[cell.name]

    if sink is not None:
        _walk_posts(top, np.zeros(2, dtype=np.int64), is_post, list(post_names or []), posts_layer, sizes or {}, sink)
    refs, flatc, off, pbb, layers, frame = content(top)
    ob.frame_layers = {k: v[:2] for k, v in frame.items()}
    ob.frame_moments = {k: v[2:] for k, v in frame.items()}
    ob.ref_counts.update(refs)
    ob.flat_counts.update(flatc)
    ob.layers |= layers
    ob.posts_bbox = pbb
    (a, b), (c2, d) = top.bounding_box()
    ob.bbox = (int(round(a * s)), int(round(b * s)), int(round(c2 * s)), int(round(d * s)))
    ob.off_lattice = int(off)
    return ob


def _frame_polygons(cell: Any, posts_layer: tuple[int, int], layers: set) -> dict:
    """``(layer, datatype) -> [polygons, bbox nm]`` of ``cell``'s own polygons off the posts layer (and every
    polygon's layer into ``layers``)."""
    frame: dict = {}
    for p in cell.polygons:
        layers.add((p.layer, p.datatype))
        if (p.layer, p.datatype) != posts_layer:
            pts = np.rint(p.points * 1e3).astype(np.int64)
            e = frame.setdefault((p.layer, p.datatype), [0, None, 0.0, 0.0, 0.0])
            e[0] += 1
            e[1] = union_bbox(e[1], (*pts.min(0).tolist(), *pts.max(0).tolist()))
            e[2:] = (np.asarray(e[2:]) + moments(pts)).tolist()
    return frame


def _add_placed(frame: dict, child: dict, pos: np.ndarray) -> None:
    """A child's per-layer polygons placed at ``pos`` (n, 2) nm, added to ``frame``."""
    for lay, (fn, fb, a, sx, sy) in child.items():
        e = frame.setdefault(lay, [0, None, 0.0, 0.0, 0.0])
        e[0] += len(pos) * fn
        e[1] = union_bbox(e[1], (fb[0] + int(pos[:, 0].min()), fb[1] + int(pos[:, 1].min()),
                                 fb[2] + int(pos[:, 0].max()), fb[3] + int(pos[:, 1].max())))
        e[2] += len(pos) * a
        e[3] += len(pos) * sx + a * float(pos[:, 0].sum())
        e[4] += len(pos) * sy + a * float(pos[:, 1].sum())


def _count_post_refs(origins: dict, placed: dict, s: float, lattice: tuple[int, int, int] | None, cell_rects: dict,
                     posts_layer: tuple[int, int], refs: Counter, layers: set, pbb: Any) -> tuple[int, int, Any]:
    """A cell's references to post cells (``origins``: name -> single references' origins, um; ``placed``: name ->
    positions of those with a repetition, nm) counted into ``refs`` and ``layers``: ``(references, off the lattice,
    posts bbox)``."""
    nrefs = off = 0
    for nm in {**origins, **placed}:
        pos = np.concatenate(([np.rint(np.array(origins[nm], dtype=np.float64) * s).astype(np.int64)]
                              if nm in origins else []) + placed.get(nm, []))
        nrefs += len(pos)
        refs[nm] += len(pos)
        if lattice is not None:
            cx, oP, P = lattice
            off += int(np.count_nonzero(((pos - cx - oP) % P != 0).any(axis=1)))
        for (l_, d_, w, h, ccx, ccy) in cell_rects.get(nm, []):
            layers.add((l_, d_))
            if (l_, d_) == posts_layer:
                bb = (int(pos[:, 0].min()) + ccx - w // 2, int(pos[:, 1].min()) + ccy - h // 2,
                      int(pos[:, 0].max()) + ccx + w // 2, int(pos[:, 1].max()) + ccy + h // 2)
                pbb = union_bbox(pbb, bb)
    return nrefs, off, pbb


def _count_post_polygons(polygons: list, s: float, lattice: tuple[int, int, int] | None, flatc: Counter,
                         pbb: Any) -> tuple[int, Any]:
    """A cell's own posts-layer polygons counted per size into ``flatc``: ``(off the lattice, posts bbox)``."""
    b = _post_boxes(polygons, s)
    if not len(b):
        return 0, pbb
    x0, y0, x1, y1 = b.T
    flatc.update(zip((x1 - x0).tolist(), (y1 - y0).tolist()))
    pbb = union_bbox(pbb, (int(x0.min()), int(y0.min()), int(x1.max()), int(y1.max())))
    if lattice is None:
        return 0, pbb
    cx, oP, P = lattice
    return int(np.count_nonzero((((x0 + x1) // 2 - cx - oP) % P != 0) | (((y0 + y1) // 2 - cx - oP) % P != 0))), pbb


def _post_boxes(polygons: list, scale: float) -> np.ndarray:
    """``(n, 4)`` int64 ``(x0, y0, x1, y1)`` of each polygon: its points scaled by ``scale`` (um -> nm) and rounded,
    their least and greatest coordinates."""
    if not polygons:
        return np.zeros((0, 4), dtype=np.int64)
    pts = [p.points for p in polygons]
    starts = np.cumsum([0] + [len(q) for q in pts[:-1]])
    allp = np.rint(np.concatenate(pts) * scale)
    return np.concatenate([np.minimum.reduceat(allp, starts, axis=0), np.maximum.reduceat(allp, starts, axis=0)],
                          axis=1).astype(np.int64)


def _walk_posts(cell: Any, off: np.ndarray, is_post: Any, names: list[str], posts_layer: tuple[int, int],
                sizes: dict, sink: Any) -> None:
    """Hand every post under ``cell`` (placed at ``off``, nm) to ``sink(x, y, type)``: references to post cells
    by name, posts-layer rectangles by size (type -1 for neither). Consecutive single references to post cells go
    to ``sink`` together, in their order."""
    index = {nm: k for k, nm in enumerate(names)}
    run: list = []  # (origin um, type) of the single references to post cells not yet handed over

    def hand_over() -> None:
        if run:
            pos = np.rint(np.array([o for o, _ in run], dtype=np.float64) * 1e3).astype(np.int64) + off
            sink(pos[:, 0], pos[:, 1], np.array([k for _, k in run], dtype=np.int64))
            run.clear()

    for r in cell.references:
        child = r.cell
        nm = child.name if hasattr(child, "name") else str(child)
        post = not hasattr(child, "name") or is_post(child)
        if post and not r.repetition.size:
            run.append((r.origin, index.get(nm, -1)))
            continue
        hand_over()
        o = np.array([r.origin[0], r.origin[1]])
        pos = np.asarray(r.repetition.get_offsets()) + o if r.repetition.size else o[None, :]
        pos = np.rint(pos * 1e3).astype(np.int64) + off
        if post:
            sink(pos[:, 0], pos[:, 1], np.full(len(pos), index.get(nm, -1)))
        else:
            for p in pos:
                _walk_posts(child, p, is_post, names, posts_layer, sizes, sink)
    hand_over()
    rects = [p for p in cell.polygons if (p.layer, p.datatype) == posts_layer]
    if rects:
        b = _post_boxes(rects, 1e3)
        k = np.array([sizes.get(wh, -1) for wh in zip((b[:, 2] - b[:, 0]).tolist(), (b[:, 3] - b[:, 1]).tolist())])
        sink((b[:, 0] + b[:, 2]) // 2 + off[0], (b[:, 1] + b[:, 3]) // 2 + off[1], k)

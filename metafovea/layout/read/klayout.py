"""KLayout reader: KLayout's Python module (``klayout.db``), what fabs use; GDSII and OASIS.

The file is loaded whole (KLayout's own data structures); the top cell's content is counted through the
hierarchy, each intermediate cell once (memoised) and multiplied by its references.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

from metafovea.layout.read.base import Observed, sniff_format


def read_klayout(path: Path, lattice: tuple[int, int, int] | None, posts_layer: tuple[int, int],
                 post_names: Any = None, sink: Any = None, sizes: dict | None = None) -> Observed:
    """Read ``path`` (GDSII or OASIS) with KLayout; ``lattice``: see :func:`~metafovea.layout.read.base.lattice_of`
    (None: positions are not checked); ``post_names``: the post cells (default: cells without children);
    ``sink``: called as ``sink(x_nm, y_nm, type)`` with every post (absolute centre; type the index of its cell
    in ``post_names``, or of its size in ``sizes`` for a flat rectangle; -1 for neither)."""
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

    if sink is not None:
        _walk_posts(ly, top.cell_index(), 0, 0, is_post, {nm: k for k, nm in enumerate(post_names or [])},
                    sizes or {}, li_posts, sink)
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


def _walk_posts(ly: Any, ci: int, ox: int, oy: int, is_post: Any, index: dict, sizes: dict, li_posts: Any,
                sink: Any) -> None:
    """Hand every post under cell ``ci`` (placed at ``(ox, oy)``) to ``sink(x, y, type)``: references to post
    cells by name (``index``), posts-layer shapes by size (``sizes``); type -1 for neither."""
    import numpy as np

    cell = ly.cell(ci)
    for inst in cell.each_inst():
        arr = inst.cell_inst
        child = ly.cell(inst.cell_index)
        disps = [inst.trans.disp] if arr.size() == 1 else [t.disp for t in arr.each_trans()]
        if is_post(child):
            sink(np.array([d.x + ox for d in disps]), np.array([d.y + oy for d in disps]),
                 np.full(len(disps), index.get(child.name, -1)))
        else:
            for d in disps:
                _walk_posts(ly, inst.cell_index, d.x + ox, d.y + oy, is_post, index, sizes, li_posts, sink)
    if li_posts is not None:
        bs = [sh.bbox() for sh in cell.shapes(li_posts).each()]
        if bs:
            sink(np.array([b.center().x + ox for b in bs]), np.array([b.center().y + oy for b in bs]),
                 np.array([sizes.get((b.width(), b.height()), -1) for b in bs]))

"""KLayout reader: KLayout's Python module (``klayout.db``), what fabs use; GDSII and OASIS.

The file is loaded whole into a non-editable layout (KLayout's own data structures; an OASIS repetition stays one
instance array, as in the file). Per instance *record* (one per GDSII SREF/AREF, one per OASIS placement with its
repetition) the top cell's content is counted through the hierarchy, each intermediate cell once (memoised) and
multiplied by its references: references per post cell, elements per structure, rotated or magnified references,
intermediate references off the lattice period, non-rectangular posts.

Per *post*, nothing is done in Python: the posts' absolute positions are flattened by KLayout's C++. A marker
square centred on the origin of each post cell (on a layer of its own, in this private copy of the layout) is
collected with a :class:`RecursiveShapeIterator` into a scratch layout, strip by strip, and the scratch layout is
written to GDSII (KLayout's writer, to a file in memory), whose boundary records have one fixed size and are read
as a numpy array. The centre of a transformed square centred on the origin is the transformed origin: exact in
integer database units. Flat posts (posts-layer boxes outside the post cells) are flattened the same way and typed
by their size. The frame (polygons and bounding box per layer but the posts') is counted per cell and bounded by
KLayout's hierarchical bounding boxes, without flattening.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from metafovea.layout.read.base import Observed, moments, sniff_format

if TYPE_CHECKING:
    import klayout.db as kdb

#: ``sink(x_nm, y_nm, types)``: called with each slice of posts (absolute centres and type indices)
Sink = Callable[[np.ndarray, np.ndarray, np.ndarray], None]

#: posts flattened per strip (bounds the scratch layout and the GDSII bytes: ~100 bytes a post)
STRIP_POSTS = 4 << 20
#: posts handed to the sink per call
SINK_POSTS = 1 << 18
#: one boundary record of KLayout's GDSII writer for a four-corner polygon on layer 0/0: BOUNDARY, LAYER, DATATYPE,
#: XY (5 points), ENDEL
_HEAD = np.frombuffer(bytes.fromhex("00040800" "00060d020000" "00060e020000" "002c1003"), np.uint8)
_TAIL = np.frombuffer(bytes.fromhex("00041100"), np.uint8)
_RECORD = np.dtype([("head", np.uint8, (20,)), ("xy", ">i4", (10,)), ("tail", np.uint8, (4,))])


def read_klayout(path: Path, lattice: tuple[int, int, int] | None, posts_layer: tuple[int, int],
                 post_names: Iterable[str] | None = None, sink: Sink | None = None,
                 sizes: dict | None = None) -> Observed:
    """Read ``path`` (GDSII or OASIS) with KLayout; ``lattice``: see :func:`~metafovea.layout.read.base.lattice_of`
    (None: positions are not checked); ``post_names``: the post cells (default: cells without children);
    ``sink``: called as ``sink(x_nm, y_nm, type)`` with every post (absolute centre; type the index of its cell
    in ``post_names``, or of its size in ``sizes`` for a flat rectangle; -1 for neither)."""
    import klayout.db as db

    fmt = sniff_format(path)
    ly = db.Layout(False)  # non-editable: instance arrays (OASIS repetitions) are kept as arrays
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
    if li_posts is not None:
        pb = top.bbox_per_layer(li_posts)
        if not pb.empty():
            ob.posts_bbox = (pb.left, pb.bottom, pb.right, pb.top)
    b = top.bbox()
    if not b.empty():
        ob.bbox = (b.left, b.bottom, b.right, b.top)
    pn = None if post_names is None else set(post_names)

    def is_post(c) -> bool:
        return (c.name in pn) if pn is not None else not c.child_cells()

    layers = list(ly.layer_indexes())
    refs, held, holders = _census(ly, top.cell_index(), is_post, li_posts, lattice, ob)
    ob.ref_counts.update(refs)
    with_refs = sink is not None or lattice is not None  # else only the flat shapes' sizes are needed
    # queries first, then the changes, then one update: a query after a change updates the layout (sorts the
    # instance trees again: ~10 s for 30 M GDSII references)
    frame = _frame_census(ly, held, [li for li in layers if li != li_posts])
    passes = _mark_posts(ly, top, is_post, li_posts, holders, refs, with_refs,
                         {nm: k for k, nm in enumerate(post_names or [])})
    frame = _copy_frame(ly, frame)
    ly.update()
    ob.frame_layers, ob.frame_moments = {}, {}
    for key, n, li in frame:
        fb = top.bbox_per_layer(li)
        ob.frame_layers[key] = [n, (fb.left, fb.bottom, fb.right, fb.top)]
        ob.frame_moments[key] = _layer_moments(top, li)
    flatc, off, found = _flatten_posts(ly, top, passes, sizes or {}, lattice, sink)
    ob.flat_counts.update(flatc)
    ob.off_lattice = int(off)
    for li, _, what, n, _ in passes:  # KLayout's flattening against its own count, record by record
        if found[li] != n:
            ob.anomalies.append(f"klayout flattened {found[li]:,} {what}, counted {n:,}")
    return ob


def _census(ly: kdb.Layout, top_ci: int, is_post: Callable[[kdb.Cell], bool], li_posts: int | None,
            lattice: tuple[int, int, int] | None, ob: Observed) -> tuple[Counter, Counter, dict[int, tuple[int, int]]]:
    """References per post cell in cell ``top_ci`` through the hierarchy, one Python step per instance record (an
    array counts as its size); the placements of the cells that hold shapes (cell index -> placements in the top
    cell); and of those, the ones with posts-layer shapes: cell index -> (boxes and polygons, other shapes) in the
    top cell through the hierarchy. Fills ``ob``'s ``cell_rects``, ``max_refs``, ``max_references`` and anomalies
    (complex references, intermediate references off the lattice period, non-rectangular posts, post cells with
    child cells)."""
    import klayout.db as db

    layers = list(ly.layer_indexes())
    odd_flags = db.Shapes.SAll & ~db.Shapes.SBoxes
    P = None if lattice is None else lattice[2]
    memo: dict[int, tuple[Counter, Counter]] = {}  # cell -> (references per post cell, placements per holder)
    own: dict[int, tuple[int, int]] = {}  # cell -> its own posts-layer (boxes and polygons, other shapes)

    def post_cell(child) -> None:
        nm = child.name
        rects = []
        for li in layers:
            info = ly.get_info(li)
            for sh in child.shapes(li).each():
                bb = sh.bbox()
                if not (sh.is_box() or (sh.is_polygon() and sh.polygon.is_box())):
                    ob.anomalies.append(f"cell {nm}: a non-rectangular shape on {info.layer}/{info.datatype}")
                rects.append((info.layer, info.datatype, bb.width(), bb.height(), bb.center().x, bb.center().y))
        if child.child_cells():
            ob.anomalies.append(f"cell {nm} has child cells")
        ob.cell_rects[nm] = rects

    def off_period(inst) -> bool:
        """Whether a reference (array) to an intermediate cell has a displacement off the lattice period."""
        d = inst.trans.disp
        if inst.size() == 1 or inst.is_regular_array():
            vs = [d] + ([inst.a] if inst.na > 1 else []) + ([inst.b] if inst.nb > 1 else [])
        else:  # an irregular array of an intermediate cell (not written by the exporter): member by member
            vs = [t.disp for t in inst.cell_inst.each_trans()]
        return any(v.x % P or v.y % P for v in vs)

    seen: dict[int, tuple[bool, str]] = {}

    def kinds(ci: int) -> tuple[bool, str]:
        """(whether cell ``ci`` is a post cell, its name), once per cell."""
        if ci not in seen:
            c = ly.cell(ci)
            seen[ci] = (bool(is_post(c)), c.name)
        return seen[ci]

    def content(ci: int) -> tuple[Counter, Counter]:
        if ci in memo:
            return memo[ci]
        cell = ly.cell(ci)
        refs: Counter = Counter()
        held: Counter = Counter()
        counts: dict[int, int] = {}  # child cell -> instances (a GDSII SREF-per-post cell: one record a post)
        for inst in cell.each_inst():
            cc = inst.cell_index
            n = inst.size()
            t = inst.trans  # is_complex(): magnified or off the right angles only; a quarter turn or a mirror too
            if inst.is_complex() or t.angle != 0 or t.is_mirror():
                ob.anomalies.append(f"a reference to {kinds(cc)[1]} is rotated, mirrored or magnified")
            if cc in counts:
                counts[cc] += n
            else:
                counts[cc] = n
                post, nm = kinds(cc)
                if post and nm not in ob.cell_rects:
                    post_cell(ly.cell(cc))
                elif not post:
                    content(cc)
            if P is not None and not kinds(cc)[0] and off_period(inst):
                ob.anomalies.append(f"references to structure {kinds(cc)[1]} off the lattice period")
        for cc, n in counts.items():
            post, nm = kinds(cc)
            if post:
                refs[nm] += n
                continue
            sr, sh = content(cc)
            for k, v in sr.items():
                refs[k] += n * v
            for k, v in sh.items():
                held[k] += n * v
        nrefs = sum(counts.values())
        nshapes = sum(cell.shapes(li).size() for li in layers)
        ob.max_refs = max(ob.max_refs, nrefs + nshapes)
        ob.max_references = max(ob.max_references, cell.child_instances())
        if nshapes:
            held[ci] += 1
        if li_posts is not None and not cell.shapes(li_posts).is_empty():
            other = 0
            for sh in cell.shapes(li_posts).each(odd_flags):  # boxes are rectangles; only the others are looked at
                poly = sh.is_polygon()
                other += not poly
                if not (poly and sh.polygon.is_box()):
                    ob.anomalies.append(f"a non-rectangular post in cell {cell.name}")
            own[ci] = (cell.shapes(li_posts).size() - other, other)
        memo[ci] = (refs, held)
        return memo[ci]

    refs, held = content(top_ci)
    return refs, held, {ci: (held[ci] * a, held[ci] * b) for ci, (a, b) in own.items()}


def _frame_census(ly: kdb.Layout, held: Counter,
                  layers: list[int]) -> list[tuple[tuple[int, int], int, int, list[int]]]:
    """``((layer, datatype), polygons, layer index, cells holding them)`` for each of the file's ``layers`` (all
    but the posts') with polygons (boxes included) in the top cell through the hierarchy, outside the post cells (as
    the other readers report the frame): polygons counted per cell times its placements ``held``."""
    import klayout.db as db

    rest = db.Shapes.SAll & ~(db.Shapes.SBoxes | db.Shapes.SPolygons)
    found = []
    for li in layers:
        n, cells = 0, []
        for ci, k in held.items():
            shapes = ly.cell(ci).shapes(li)
            m = 0 if shapes.is_empty() else shapes.size() - sum(1 for _ in shapes.each(rest))
            if m:
                n += k * m
                cells.append(ci)
        if n:
            info = ly.get_info(li)
            found.append(((info.layer, info.datatype), n, li, cells))
    return found


def _layer_moments(top: kdb.Cell, li: int) -> list[float]:
    """``[A, Sx, Sy]`` (:func:`~metafovea.layout.bbox.moments`, database units) of layer ``li``'s shapes in ``top``
    through the hierarchy, each placed by its instances' transformations (holes subtracted)."""
    tot = np.zeros(3)
    it = top.begin_shapes_rec(li)
    while not it.at_end():
        poly = it.shape().polygon
        if poly is not None:
            poly = poly.transformed(it.trans())
            tot += moments(np.array([(p.x, p.y) for p in poly.each_point_hull()], dtype=np.float64))
            for h in range(poly.holes()):
                tot -= moments(np.array([(p.x, p.y) for p in poly.each_point_hole(h)], dtype=np.float64))
        it.next()
    return tot.tolist()


def _copy_frame(ly: kdb.Layout, found: list) -> list[tuple[tuple[int, int], int, int]]:
    """The frame polygons ``found`` (:func:`_frame_census`) copied to layers of their own, whose hierarchical
    bounding boxes (KLayout's, no flattening) are theirs: ``((layer, datatype), polygons, copy layer)``."""
    import klayout.db as db

    keep = db.Shapes.SBoxes | db.Shapes.SPolygons
    frame = []
    for key, n, li, cells in found:
        copy = ly.insert_layer(db.LayerInfo(f"metafovea frame {li}"))
        for ci in cells:
            ly.cell(ci).shapes(copy).insert(ly.cell(ci).shapes(li), keep)
        frame.append((key, n, copy))
    return frame


def _mark_posts(ly: kdb.Layout, top: kdb.Cell, is_post: Callable[[kdb.Cell], bool], li_posts: int | None, holders: dict,
                refs: Counter, with_refs: bool, index: dict) -> list[tuple[int, int | None, str, int, bool]]:
    """Prepare this private copy of the layout for flattening; returns the passes ``(layer, type (None: by size),
    what, posts counted, boundaries only)``: a layer per post cell (``with_refs``) holding a marker square on the
    cell's origin, and the posts-layer boxes and polygons, and other shapes, of the cells ``holders`` copied to two
    layers of their own (the post cells' own rectangles are not posts of the top cell). The post cells' child
    instances are removed (posts inside post cells are not posts of the top cell either; the census did not count
    them). The caller updates the layout (:meth:`Layout.update`) before flattening."""
    import klayout.db as db

    passes = []
    posts = [(ly.cell(ci), bool(ly.cell(ci).child_instances())) for ci in top.called_cells() if is_post(ly.cell(ci))]
    for cell, parent in posts:  # queried first: a query after a change to the layout updates it
        if parent:
            cell.clear_insts()
        if with_refs:
            li = ly.insert_layer(db.LayerInfo(f"metafovea marker {cell.cell_index()}"))
            cell.shapes(li).insert(db.Box(-1, -1, 1, 1))
            passes.append((li, index.get(cell.name, -1), f"references to {cell.name}", refs[cell.name], True))
    if holders:
        odd_flags = db.Shapes.SAll & ~(db.Shapes.SBoxes | db.Shapes.SPolygons)
        li_box = ly.insert_layer(db.LayerInfo("metafovea flat boxes"))
        li_odd = ly.insert_layer(db.LayerInfo("metafovea flat shapes"))
        for ci in holders:
            src = ly.cell(ci).shapes(li_posts)
            ly.cell(ci).shapes(li_box).insert(src, db.Shapes.SBoxes | db.Shapes.SPolygons)
            ly.cell(ci).shapes(li_odd).insert(src, odd_flags)
        nbox, nodd = (sum(v[i] for v in holders.values()) for i in (0, 1))
        passes.append((li_box, None, "posts-layer boxes and polygons", nbox, True))
        if nodd:
            passes.append((li_odd, None, "other posts-layer shapes", nodd, False))
    return passes


def _flatten_posts(ly: kdb.Layout, top: kdb.Cell, passes: list, sizes: dict, lattice: tuple[int, int, int] | None,
                   sink: Sink | None) -> tuple[Counter, int, Counter]:
    """Flatten each pass's layer under ``top`` in KLayout (see :func:`_mark_posts`), in strips of about
    :data:`STRIP_POSTS` posts, and hand the posts to ``sink`` in slices of :data:`SINK_POSTS`: a marker's centre
    (the post cell's origin) with the pass's type, or a shape's bounding-box centre with the index of its size in
    ``sizes``. Returns (flat shapes per size, posts off the lattice, posts flattened per pass layer)."""
    import klayout.db as db

    scratch = db.Layout(False)
    scratch.dbu = ly.dbu
    out = scratch.create_cell("FLAT")
    lo = scratch.insert_layer(db.LayerInfo(0, 0))
    dump = _GdsDump()
    flatc: Counter = Counter()
    found: Counter = Counter()
    off = 0
    for li, kind, _, n, exact in passes:
        bb = top.bbox_per_layer(li)
        if bb.empty():
            continue
        nstrip = max(1, -(-n // STRIP_POSTS))
        edges = [bb.bottom + (bb.height() + 1) * i // nstrip for i in range(nstrip + 1)]
        for y0, y1 in zip(edges[:-1], edges[1:]):
            it = top.begin_shapes_rec(li) if nstrip == 1 else top.begin_shapes_rec_touching(
                li, db.Box(bb.left, y0, bb.right, y1))
            out.shapes(lo).insert(it)
            xy = _corners(dump, out.shapes(lo), exact)
            out.shapes(lo).clear()
            for i in range(0, len(xy), SINK_POSTS):
                k, o = _hand_over(xy[i:i + SINK_POSTS], kind, (y0, y1) if nstrip > 1 else None, sizes, lattice,
                                  sink, flatc)
                found[li] += k
                off += o
    return flatc, off, found


def _hand_over(xy: np.ndarray, kind: int | None, strip: tuple[int, int] | None, sizes: dict,
               lattice: tuple[int, int, int] | None, sink: Sink | None, flatc: Counter) -> tuple[int, int]:
    """Posts from the corners ``xy`` (rows of five points) of one slice of a strip: a marker's centre (the midpoint
    of opposite corners) with type ``kind``, or (``kind`` None) a shape's bounding-box centre typed by its size
    (counted into ``flatc``); only centres in ``strip`` (y0 <= y < y1; a post on a strip edge is touched by two
    strips). Hands them to ``sink``; returns (posts, posts off the lattice)."""
    if kind is not None:
        x = (xy[:, 0].astype(np.int64) + xy[:, 4]) // 2
        y = (xy[:, 1].astype(np.int64) + xy[:, 5]) // 2
    else:
        xs, ys = xy[:, 0:8:2], xy[:, 1:8:2]
        x0, y0, x1, y1 = (v.astype(np.int64) for v in (xs.min(1), ys.min(1), xs.max(1), ys.max(1)))
        x, y, w, h = (x0 + x1) // 2, (y0 + y1) // 2, x1 - x0, y1 - y0
    if strip is not None:
        keep = (y >= strip[0]) & (y < strip[1])
        x, y = x[keep], y[keep]
    if kind is not None:
        types = np.full(x.size, kind, np.int64)
    else:
        if strip is not None:
            w, h = w[keep], h[keep]
        u, inv, cnt = np.unique((w << 32) | h, return_inverse=True, return_counts=True)
        wh = [(int(k >> 32), int(k & 0xFFFFFFFF)) for k in u]
        flatc.update(dict(zip(wh, cnt.tolist())))
        types = np.array([sizes.get(k, -1) for k in wh], np.int64)[inv]
    off = 0
    if lattice is not None:
        cx, oP, P = lattice
        off = int(np.count_nonzero(((x - cx - oP) % P != 0) | ((y - cx - oP) % P != 0)))
    if sink is not None and x.size:
        sink(x, y, types)
    return int(x.size), off


def _corners(dump: _GdsDump, shapes: kdb.Shapes, exact: bool) -> np.ndarray:
    """The corners of the shapes in ``shapes`` (the only ones in the scratch layout ``dump`` writes), an ``(n,
    10)`` integer array of five points per row: read from the GDSII bytes KLayout writes when every shape is a
    four-corner boundary (boxes and transformed boxes; ``exact``; a view on the dump's buffer, valid until its next
    call), else each shape's bounding box, shape by shape."""
    if shapes.is_empty():
        return np.zeros((0, 10), np.int64)
    if exact:
        data = dump(shapes.layout())
        start = _first_element(data)
        n = shapes.size()
        if start is not None and start + n * _RECORD.itemsize <= len(data):
            rec = np.frombuffer(data, _RECORD, count=n, offset=start)
            if (rec["head"] == _HEAD).all() and (rec["tail"] == _TAIL).all():
                return rec["xy"]
    b = np.array([(q.left, q.bottom, q.right, q.top) for q in (sh.bbox() for sh in shapes.each())],
                 np.int64).reshape(-1, 4)
    return b[:, [0, 1, 0, 3, 2, 3, 2, 1, 0, 1]]


class _GdsDump:
    """The GDSII bytes of a scratch layout, written by KLayout to a file in ``/dev/shm`` (memory; else the temporary
    directory), read into a buffer kept for the next call, the file removed at once: half the time of
    :meth:`Layout.write_bytes`, whose growing in-memory stream is copied into a new bytes object each time."""

    def __init__(self):
        import klayout.db as db

        self.opts = db.SaveLayoutOptions()
        self.opts.format = "GDS2"
        self.opts.write_context_info = False
        self.buf = np.empty(0, np.uint8)

    def __call__(self, layout: kdb.Layout) -> memoryview:
        import os
        import tempfile

        shm = "/dev/shm"
        where = shm if os.path.isdir(shm) and os.access(shm, os.W_OK) else None
        fd, path = tempfile.mkstemp(suffix=".gds", prefix="metafovea_klayout_", dir=where)
        try:
            os.close(fd)
            layout.write(path, self.opts)
            n = os.path.getsize(path)
            if self.buf.size < n:
                self.buf = np.empty(n, np.uint8)
            with open(path, "rb") as fh:
                got = fh.readinto(memoryview(self.buf)[:n])
        finally:
            os.unlink(path)
        return memoryview(self.buf)[:got]


def _first_element(data: bytes | memoryview) -> int | None:
    """Offset of the first element record after the first STRNAME in a GDSII byte string (None if none)."""
    i = 0
    while i + 4 <= len(data):
        n = int.from_bytes(data[i:i + 2], "big")
        if n < 4:
            return None
        if data[i + 2] == 0x06:  # STRNAME
            return i + n
        i += n
    return None

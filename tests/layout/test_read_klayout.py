"""The KLayout reader flattens posts in KLayout's C++ (a marker square per post cell, the scratch layout's GDSII
bytes read as numpy): every post it hands to the sink is compared with a brute-force gdstk walk written here, on
exported files (references, flat, OASIS, ``--max-refs``, patches), on tampered ones (a post moved, two types
swapped) and in many strips; hand-built layouts cover what the exporter never writes (rotated and magnified
references, arrays of intermediate cells, posts inside post cells, non-rectangular and text shapes)."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.layout import ExportOptions, export_layout, make_spec
from metafovea.layout.read import klayout as kl
from metafovea.layout.read import lattice_of, read_gdstk, read_klayout

db = pytest.importorskip("klayout.db")
gdstk = pytest.importorskip("gdstk")


def _sizes(spec) -> dict:
    return {(int(w), int(h)): k for k, (w, h) in enumerate(spec.post_sizes_nm.tolist())}


def _sorted(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, np.int64).reshape(-1, 3)
    return a[np.lexsort((a[:, 2], a[:, 1], a[:, 0]))]


def _collect(path, lattice, posts_layer, names, sizes):
    """(Observed, sorted (x, y, type) rows) of :func:`read_klayout` with a sink."""
    chunks = []
    ob = read_klayout(path, lattice, posts_layer, names, sizes=sizes,
                      sink=lambda x, y, k: chunks.append(np.stack([x, y, k], 1)))
    return ob, _sorted(np.concatenate(chunks) if chunks else np.zeros((0, 3)))


def _brute(path, names, posts_layer, sizes) -> np.ndarray:
    """Every post of ``path`` by a plain gdstk walk: references to the post cells ``names`` (their origin, the type
    their index) and posts-layer polygons elsewhere (bounding-box centre, the type their size's index), rows
    ``(x, y, type)`` in nm, sorted. Translations only (what the exporter writes)."""
    oas = str(path).endswith(".oas")
    lib = gdstk.read_oas(str(path), unit=1e-9) if oas else gdstk.read_gds(str(path), unit=1e-9)
    index = {nm: k for k, nm in enumerate(names)}
    top = next(c for c in lib.top_level() if c.name not in index)
    rows = []

    def places(el) -> np.ndarray:
        o = np.array(getattr(el, "origin", (0.0, 0.0)), float)
        return o + (np.asarray(el.repetition.get_offsets()) if el.repetition.size else np.zeros((1, 2)))

    def walk(cell, off) -> None:
        for r in cell.references:
            assert r.rotation == 0 and r.magnification == 1 and not r.x_reflection
            for p in places(r) + off:
                if r.cell.name in index:
                    rows.append((*np.rint(p).astype(np.int64), index[r.cell.name]))
                else:
                    walk(r.cell, p)
        for poly in cell.polygons:
            if (poly.layer, poly.datatype) == posts_layer:
                lo, hi = np.rint(poly.points.min(0)).astype(np.int64), np.rint(poly.points.max(0)).astype(np.int64)
                w, h = (hi - lo).tolist()
                for p in places(poly) + off:
                    c = np.rint(p).astype(np.int64) + (lo + hi) // 2
                    rows.append((int(c[0]), int(c[1]), sizes.get((w, h), -1)))

    walk(top, np.zeros(2))
    return _sorted(np.array(rows, np.int64))


def _check_against_gdstk(path, spec) -> np.ndarray:
    """The KLayout reader's posts equal the brute-force walk's; its counts equal the gdstk reader's."""
    args = (path, lattice_of(spec), spec.layers.posts, spec.post_names)
    ob, got = _collect(*args, _sizes(spec))
    want = _brute(path, spec.post_names, spec.layers.posts, _sizes(spec))
    assert got.shape == want.shape and np.array_equal(got, want)
    g = read_gdstk(*args)
    assert (dict(ob.ref_counts), dict(ob.flat_counts), ob.off_lattice, ob.posts_bbox, ob.bbox, sorted(ob.layers),
            ob.anomalies, ob.structures, ob.top_cells, ob.max_refs, ob.max_references) == (
        dict(g.ref_counts), dict(g.flat_counts), g.off_lattice, g.posts_bbox, g.bbox, sorted(g.layers),
        g.anomalies, g.structures, g.top_cells, g.max_refs, g.max_references)
    assert ob.frame_layers == {k: [n, tuple(b)] for k, (n, b) in g.frame_layers.items()}
    assert ob.cell_rects == g.cell_rects
    return got


@pytest.mark.parametrize("key", [("gds", False), ("gds", True), ("oas", False)])
def test_every_post_as_gdstk_sees_it(spec, exported, key):
    p, res = exported[key]
    got = _check_against_gdstk(p, spec)
    assert len(got) == res.posts and (got[:, 2] >= 0).all()
    assert np.bincount(got[:, 2], minlength=spec.levels).tolist() == res.counts


def test_many_strips_same_posts(monkeypatch, spec, exported):
    """Strips of ~2,000 posts (~35 strips, posts on strip edges included once) hand over the same posts."""
    p, res = exported[("oas", False)]
    args = (p, lattice_of(spec), spec.layers.posts, spec.post_names, _sizes(spec))
    _, one = _collect(*args)
    monkeypatch.setattr(kl, "STRIP_POSTS", 2000)
    ob, many = _collect(*args)
    assert np.array_equal(one, many) and len(many) == res.posts and not ob.anomalies


@pytest.mark.parametrize("fmt,flat,max_refs", [("gds", False, 64), ("gds", True, 64), ("gds", False, None),
                                               ("gds", True, None), ("oas", False, None)])
def test_patch_and_hierarchical_files(tmp_path, design, small_frame, fmt, flat, max_refs):
    """A patch at the rim, with references, flat, OASIS, and hierarchical (at most 64 elements per structure)."""
    sp = make_spec(design, patch_mm=(0.45, -0.3, 0.12), band_rows=8, **small_frame)
    p = tmp_path / f"patch.{fmt}"
    res = export_layout(sp, p, fmt, ExportOptions(flat=flat, max_refs=max_refs))
    got = _check_against_gdstk(p, sp)
    assert len(got) == res.posts > 500
    if max_refs:
        ob = read_klayout(p, lattice_of(sp), sp.layers.posts, sp.post_names)
        assert 1 < ob.max_refs <= max_refs and ob.structures > 10


def _rewrite(src, dst, names, how: str, period_um: float) -> None:
    """Rewrite ``src`` with gdstk (references expanded), ``how``: 'move' one post one period to the right (from
    the middle of the file on, the first whose right-hand site holds no post of its type), 'swap' two posts of
    different types (counts per type unchanged), or 'none'."""
    oas = str(src).endswith(".oas")
    lib = gdstk.read_oas(str(src), unit=1e-6) if oas else gdstk.read_gds(str(src), unit=1e-6)
    top = next(c for c in lib.top_level() if c.name not in names)
    plain = []
    for r in top.references:
        offs = r.repetition.get_offsets() + np.array(r.origin) if r.repetition.size else [np.array(r.origin)]
        plain += [[r.cell, (float(o[0]), float(o[1]))] for o in offs]
    top.remove(*top.references)
    i = len(plain) // 2
    j = next(j for j in range(i + 1, len(plain)) if plain[j][0].name != plain[i][0].name)
    if how == "move":
        held = {(c.name, round(o[0] / period_um), round(o[1] / period_um)) for c, o in plain}
        i = next(i for i in range(i, len(plain)) if (plain[i][0].name, round(plain[i][1][0] / period_um) + 1,
                                                     round(plain[i][1][1] / period_um)) not in held)
        plain[i][1] = (plain[i][1][0] + period_um, plain[i][1][1])
    elif how == "swap":
        plain[i][0], plain[j][0] = plain[j][0], plain[i][0]
    for c, o in plain:
        top.add(gdstk.Reference(c, o))
    lib.write_oas(str(dst)) if oas else lib.write_gds(str(dst))


@pytest.mark.parametrize("fmt", ["gds", "oas"])
def test_tampered_files(tmp_path, tamper_spec, tamper_exported, fmt):
    """A moved post and two swapped types show in the sink output exactly as in the brute-force walk: one row
    differs in x (by one period), two rows differ in type (on the tamper tests' smaller lens)."""
    spec = tamper_spec
    src, res = tamper_exported[fmt]
    rows = {}
    for how in ("none", "move", "swap"):
        q = tmp_path / f"{how}.{fmt}"
        _rewrite(src, q, spec.post_names, how, spec.design.period_um)
        rows[how] = _check_against_gdstk(q, spec)
    same, moved, swapped = rows["none"], rows["move"], rows["swap"]
    assert len(same) == res.posts
    assert np.array_equal(same, _sorted(_collect(src, lattice_of(spec), spec.layers.posts, spec.post_names,
                                                 _sizes(spec))[1]))
    a = {tuple(r) for r in same.tolist()}
    assert len(a - {tuple(r) for r in moved.tolist()}) == 1 and len(moved) == len(same)
    (gone,), (new,) = a - {tuple(r) for r in moved.tolist()}, {tuple(r) for r in moved.tolist()} - a
    assert new == (gone[0] + spec.period_nm, gone[1], gone[2])
    b = {tuple(r) for r in swapped.tolist()}
    assert len(a - b) == 2 and len(b - a) == 2
    assert sorted((x, y) for x, y, _ in a - b) == sorted((x, y) for x, y, _ in b - a)
    assert np.array_equal(np.bincount(same[:, 2]), np.bincount(swapped[:, 2]))


# ----------------------------------------------------------------------------------------------
# hand-built layouts: what the exporter never writes
# ----------------------------------------------------------------------------------------------
P = 1000  # lattice period (nm) of the hand-built layouts; sites at C + i P with C = 50_000
LAT = (50_000, 0, P)
SIZES = {(400, 400): 0, (600, 300): 1}


def _hand_built(path):
    """P000 (400x400 box), P001 (600x300 box), P002 (a box and a P000 reference: a post cell with a child);
    M (two P000 and a 600x300 flat box) placed by a 2x3 array, rotated by 90 degrees and once off the period;
    P001 magnified 2x and rotated 45 degrees; a triangle and a text on the posts layer in the top cell. Returns the
    posts as they lie (the rotated M's flat box is 300x600, of no post size)."""
    ly = db.Layout()
    ly.dbu = 0.001
    L1 = ly.layer(1, 0)
    p0, p1, p2, m, top = (ly.create_cell(n) for n in ("P000", "P001", "P002", "M", "TOP"))
    p0.shapes(L1).insert(db.Box(-200, -200, 200, 200))
    p1.shapes(L1).insert(db.Box(-300, -150, 300, 150))
    p2.shapes(L1).insert(db.Box(-100, -100, 100, 100))
    p2.insert(db.CellInstArray(p0.cell_index(), db.Trans(0, 0)))
    m.insert(db.CellInstArray(p0.cell_index(), db.Trans(0, 0)))
    m.insert(db.CellInstArray(p0.cell_index(), db.Trans(P, 0)))
    m.shapes(L1).insert(db.Box(2 * P - 300, -150, 2 * P + 300, 150))
    C = LAT[0]
    top.insert(db.CellInstArray(m.cell_index(), db.Trans(C, C), db.Vector(3 * P, 0), db.Vector(0, 2 * P), 2, 3))
    top.insert(db.CellInstArray(m.cell_index(), db.Trans(db.Trans.R90, db.Vector(C + 20 * P, C))))
    top.insert(db.CellInstArray(m.cell_index(), db.Trans(C + 30 * P + 1, C)))  # off the period and the lattice
    top.insert(db.CellInstArray(p1.cell_index(), db.ICplxTrans(2.0, 0, False, C + 40 * P, C)))
    top.insert(db.CellInstArray(p1.cell_index(), db.ICplxTrans(1.0, 45, False, C + 41 * P, C)))
    top.insert(db.CellInstArray(p2.cell_index(), db.Trans(C + 42 * P, C)))
    top.shapes(L1).insert(db.Polygon([db.Point(C, C + 10 * P), db.Point(C + 400, C + 10 * P),
                                      db.Point(C, C + 10 * P + 400)]))
    top.shapes(L1).insert(db.Text("x", C + 11 * P, C + 11 * P))
    ly.write(str(path))
    C, rows = LAT[0], []
    for i in range(2):
        for j in range(3):
            x, y = C + 3 * P * i, C + 2 * P * j
            rows += [(x, y, 0), (x + P, y, 0), (x + 2 * P, y, 1)]
    rows += [(C + 20 * P, C, 0), (C + 20 * P, C + P, 0), (C + 20 * P, C + 2 * P, -1)]  # rotated: x -> y, 300x600
    rows += [(C + 30 * P + 1, C, 0), (C + 31 * P + 1, C, 0), (C + 32 * P + 1, C, 1)]
    rows += [(C + 40 * P, C, 1), (C + 41 * P, C, 1), (C + 42 * P, C, 2)]
    rows += [(C + 200, C + 10 * P + 200, 0), (C + 11 * P, C + 11 * P, -1)]  # a 400x400 bounding box, a point
    return _sorted(np.array(rows))


@pytest.mark.parametrize("fmt", ["gds", "oas"])
def test_hand_built_layout(tmp_path, fmt):
    p = tmp_path / f"hand.{fmt}"
    want = _hand_built(p)
    ob, got = _collect(p, LAT, (1, 0), ["P000", "P001", "P002"], SIZES)
    assert np.array_equal(got, want)
    assert dict(ob.ref_counts) == {"P000": 16, "P001": 2, "P002": 1}
    assert dict(ob.flat_counts) == {(600, 300): 7, (300, 600): 1, (400, 400): 1, (0, 0): 1}
    assert ob.off_lattice == 4  # the three posts of the M placed one nm off, the triangle's centre
    assert ob.max_refs == 6 + 5 + 2  # the top cell: 6 + 5 references, the triangle, the text
    assert ob.anomalies.count("a non-rectangular post in cell TOP") == 2
    assert "cell P002 has child cells" in ob.anomalies
    assert "references to structure M off the lattice period" in ob.anomalies
    assert ob.anomalies.count("a reference to P001 is rotated, mirrored or magnified") == 2
    assert not any(a.startswith("klayout flattened") for a in ob.anomalies)
    # lowest: the 600x300 P001 turned by 45 degrees; highest: the text
    assert ob.posts_bbox == (50_000 - 200, 50_000 - round(450 / 2 ** 0.5), 50_000 + 42 * P + 200, 50_000 + 11 * P)


def test_posts_on_strip_edges(tmp_path, monkeypatch):
    """One strip per post: posts on the strip edges (and the layout's top and bottom edges) are handed over once."""
    p = tmp_path / "hand.oas"
    want = _hand_built(p)
    monkeypatch.setattr(kl, "STRIP_POSTS", 1)
    _, got = _collect(p, LAT, (1, 0), ["P000", "P001", "P002"], SIZES)
    assert np.array_equal(got, want)


def test_irregular_array_of_an_intermediate_cell(tmp_path):
    """An OASIS repetition of an intermediate cell (KLayout keeps it as one irregular array): its members' posts,
    and one member off the lattice period."""
    lib = gdstk.Library(unit=1e-9, precision=1e-9)
    post = lib.new_cell("P000")
    post.add(gdstk.rectangle((-200, -200), (200, 200), layer=1))
    m = lib.new_cell("M")
    m.add(gdstk.Reference(post, (0, 0)), gdstk.Reference(post, (P, 0)))
    top = lib.new_cell("TOP")
    offs = [(0, 0), (5 * P, 0), (7 * P, 3 * P), (2 * P, 9 * P)]
    r = gdstk.Reference(m, (LAT[0], LAT[0]))
    r.repetition = gdstk.Repetition(offsets=offs)
    top.add(r)
    p = tmp_path / "irr.oas"
    lib.write_oas(str(p))
    ob, got = _collect(p, LAT, (1, 0), ["P000"], {(400, 400): 0})
    want = _sorted([(LAT[0] + x + d, LAT[0] + y, 0) for x, y in offs for d in (0, P)])
    assert np.array_equal(got, want) and ob.ref_counts == {"P000": 8} and not ob.anomalies
    offs[2] = (7 * P, 3 * P + 5)
    r.repetition = gdstk.Repetition(offsets=offs)
    lib.write_oas(str(p))
    ob, got = _collect(p, LAT, (1, 0), ["P000"], {(400, 400): 0})
    assert ob.anomalies == ["references to structure M off the lattice period"] and ob.off_lattice == 2
    assert len(got) == 8


def test_without_sink_or_lattice(spec, exported):
    """Counts and bounding boxes without a sink, and without a lattice (nothing flattened but flat shapes)."""
    for key in (("gds", True), ("oas", False)):
        p, res = exported[key]
        a = read_klayout(p, lattice_of(spec), spec.layers.posts, spec.post_names)
        b = read_klayout(p, None, spec.layers.posts, spec.post_names)
        n = sum(a.flat_counts.values()) + sum(a.ref_counts.values())
        assert n == res.posts and a.off_lattice == b.off_lattice == 0 and not a.anomalies and not b.anomalies
        assert (a.ref_counts, a.flat_counts, a.bbox, a.posts_bbox) == (b.ref_counts, b.flat_counts, b.bbox,
                                                                       b.posts_bbox)

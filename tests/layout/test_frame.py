"""The fab frame (layout.frame): geometry that fits the wafer and keeps the exposures apart, verniers that read an
overlay error, labels with date and content hash, a verifier that fails on a tampered frame or label, pre-bias,
patches that define only the cells they use, and the DWL 66 mode's limits."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from metafovea.config import LensDesign
from metafovea.errors import InputError
from metafovea.layout import ExportOptions, export_layout, make_spec
from metafovea.layout.frame import MAX_POINTS, frame_shapes, vernier_origins_nm, vernier_readout
from metafovea.layout.tiling import load_spec
from metafovea.layout.verify import verify_layout

db = pytest.importorskip("klayout.db")


def _region(shapes, layer, roles=None):
    r = db.Region()
    for s in shapes:
        if s.layer == layer and (roles is None or s.role in roles):
            r.insert(db.Polygon([db.Point(int(x), int(y)) for x, y in s.points]))
    return r


@pytest.mark.parametrize("lens,die", [("designs/foveal.toml", "circle"), ("designs/perifoveal.toml", "square")])
def test_paper_lenses_frame_fits_the_wafer(lens, die):
    """Both paper lenses on the default 100 mm wafer: every frame polygon inside the wafer's usable area (edge
    exclusion, flat), at most MAX_POINTS vertices; the exposure-2 marks clear of the exposure-1 crosses by the
    clearance; nothing of the frame on the lens; the 75 mm lens gets a round die (a square one does not fit)."""
    spec = load_spec(lens, posts="ideal")
    sh = frame_shapes(spec)
    L = spec.layers
    assert max(len(s.points) for s in sh) <= MAX_POINTS
    c = spec.centre_nm
    R_use = (spec.wafer_diameter_mm * 500 - spec.wafer_edge_exclusion_mm * 1000) * 1000
    y_flat = c - (spec.wafer_flat_distance_um - spec.wafer_edge_exclusion_mm * 1000) * 1000
    for s in sh:
        if s.layer == L.wafer:
            continue
        r = np.hypot(s.points[:, 0] - c, s.points[:, 1] - c)
        assert r.max() <= R_use and s.points[:, 1].min() >= y_flat, s.role
        if s.role != "ring":
            assert r.min() > spec.ring_outer_um * 1000 - 1, s.role  # outside the ring (so off the lens)
    n_die = sum(s.role == "die" for s in sh)
    assert (n_die == 4) == (die == "square")
    assert (_region(sh, L.marks) & _region(sh, L.marks2)).is_empty()  # the verniers' scales abut, never overlap
    m1, m2 = _region(sh, L.marks, {"mark"}), _region(sh, L.marks2, {"mark2"})
    clear = int(spec.mark_clearance_um * 1000)
    # every exposure-2 square is the clearance from its cross
    assert (m2.sized(clear - 1) & m1).is_empty()
    assert not (m2.sized(clear + 1) & m1).is_empty()
    # the printed label is on the wafer and says what the file holds
    txt = spec.printed_text()
    assert spec.date in txt and "#" in txt and "RCWA" not in txt and "IDEAL" in txt
    assert not _region(sh, L.printed).is_empty()


def test_vernier_reads_an_overlay_error(tmp_path, spec, exported):
    """Exported file read back with gdstk: with exposure 2 shifted by (dx, dy), each x vernier reads dx and each y
    vernier dy to its resolution (vernier_step_um); untouched, they read 0."""
    import gdstk

    lib = gdstk.read_gds(str(exported[("gds", False)][0]), unit=1e-6)
    top = next(c for c in lib.top_level() if c.name == spec.top_name)
    L = spec.layers
    s = spec.vernier_step_um * 1000
    for dx, dy in ((0.0, 0.0), (0.5, -0.75), (-1.25, 2.0)):
        for axis, x0, y0 in vernier_origins_nm(spec):
            bars = {}
            for p in top.polygons:
                lay = (p.layer, p.datatype)
                if lay not in (L.marks, L.marks2):
                    continue
                pts = p.points * 1000 + (np.array([dx, dy]) * 1000 if lay == L.marks2 else 0)
                cx, cy = pts.mean(0)
                w, h = np.ptp(pts, axis=0)
                along, across = (cy - y0, cx - x0) if axis == "x" else (cx - x0, cy - y0)
                thin = w < h if axis == "x" else h < w
                if thin and abs(across) < 200_000 and abs(along) < 100_000:
                    bars.setdefault(lay, []).append(across)
            main, second = sorted(bars[L.marks]), sorted(bars[L.marks2])
            assert len(main) == len(second) == spec.vernier_bars
            got = vernier_readout(np.array(main), np.array(second), s) / 1000
            want = dx if axis == "x" else dy
            assert abs(got - want) <= spec.vernier_step_um / 2 + 1e-9, (axis, want, got)


def _rewrite(src, dst, spec, *, drop_layer=None, move_layer=None, label=None, nudge=None, grow=None):
    """``src`` rewritten with gdstk: the top cell's first polygon on ``drop_layer`` removed, every polygon on
    ``move_layer`` moved 10 um, or the text label replaced; ``nudge=(layer, um)``: the layer's first polygon moved by
    ``um`` towards its layer's centre along x and y (inside the layer's bounding box: the polygon count and the box
    stay); ``grow=(layer, factor)``: that polygon scaled about its centre."""
    import gdstk

    oas = str(src).endswith(".oas")
    lib = gdstk.read_oas(str(src), unit=1e-6) if oas else gdstk.read_gds(str(src), unit=1e-6)
    top = next(c for c in lib.top_level() if c.name == spec.top_name)
    if drop_layer is not None:
        top.remove(next(p for p in top.polygons if (p.layer, p.datatype) == drop_layer))
    if move_layer is not None:
        for p in top.polygons:
            if (p.layer, p.datatype) == move_layer:
                p.translate(10.0, 0.0)
    for change in (nudge, grow):
        if change is None:
            continue
        lay, v = change
        polys = [p for p in top.polygons if (p.layer, p.datatype) == lay]
        allp = np.concatenate([p.points for p in polys])
        mid, c = (allp.min(0) + allp.max(0)) / 2, polys[0].points.mean(0)
        if change is nudge:
            polys[0].translate(*(v * np.sign(mid - c)))
        else:
            polys[0].scale(v, v, c)
    if label is not None:
        lb = top.labels[0]
        top.remove(lb)
        top.add(gdstk.Label(label, lb.origin, layer=lb.layer, texttype=lb.texttype))
    lib.write_oas(str(dst)) if oas else lib.write_gds(str(dst))


@pytest.mark.parametrize("fmt,reader", [("gds", "stream"), ("gds", "gdstk"), ("oas", "gdstk"), ("gds", "klayout"),
                                        ("oas", "klayout")])
def test_verify_fails_on_a_tampered_frame_or_label(tmp_path, tamper_spec, tamper_exported, fmt, reader):
    """A missing exposure-2 mark, a missing ring polygon, a moved label and a label of another design each fail (on
    the tamper tests' smaller lens, its small frame); so do one alignment mark moved 20 nm or 10 um, and one made 1 %
    larger, inside its layer's bounding box (the polygon count and the box unchanged: the layer's area moments catch
    them); the untampered rewrite passes, also on another day."""
    spec = tamper_spec
    src = tamper_exported[fmt][0]
    L = spec.layers
    same = tmp_path / f"same.{fmt}"
    _rewrite(src, same, spec)
    assert verify_layout(same, spec, reader=reader).ok
    for name, kw, words in (("mark", dict(drop_layer=L.marks2), "4/0"),
                            ("ring", dict(drop_layer=L.aperture), "2/0"),
                            ("label", dict(move_layer=L.printed), "6/0"),
                            ("nudge", dict(nudge=(L.marks, 0.02)), "moved inside the layer's bounding box"),
                            ("move", dict(nudge=(L.marks2, 10.0)), "moved inside the layer's bounding box"),
                            ("grow", dict(grow=(L.marks, 1.01)), "resized, added or removed")):
        bad = tmp_path / f"{name}.{fmt}"
        _rewrite(src, bad, spec, **kw)
        rep = verify_layout(bad, spec, reader=reader)
        assert not rep.ok and any(words in m for m in rep.mismatches), (name, rep.mismatches)
    # a label from another design (its hash) fails; the date is taken from the file
    text = spec.label_text().replace(spec.label_text().split("hash=")[1][:12], "0" * 12)
    bad = tmp_path / f"hash.{fmt}"
    _rewrite(src, bad, spec, label=text)
    rep = verify_layout(bad, spec, reader=reader)
    assert not rep.ok and any("content hash" in m for m in rep.mismatches)
    later = replace(spec, date="2031-07-04")  # verified on another day: the file's date is used
    assert verify_layout(same, later, reader=reader).ok
    # a label whose hash is kept but whose focal length is edited fails, naming the word
    text = spec.label_text().replace(f" f={spec.design.f_mm:g}mm ", f" f={spec.design.f_mm + 1:g}mm ")
    bad = tmp_path / f"f.{fmt}"
    _rewrite(src, bad, spec, label=text)
    rep = verify_layout(bad, spec, reader=reader)
    assert not rep.ok and any(f"the label reads f={spec.design.f_mm + 1:g}mm" in m for m in rep.mismatches)
    if fmt == "gds":  # bytes appended after the end record fail; zero padding to a tape block passes
        (tmp_path / "pad.gds").write_bytes(same.read_bytes() + bytes(2048 - same.stat().st_size % 2048))
        assert verify_layout(tmp_path / "pad.gds", spec, reader=reader).ok
        (tmp_path / "junk.gds").write_bytes(same.read_bytes() + b"garbage\n")
        rep = verify_layout(tmp_path / "junk.gds", spec, reader=reader)
        assert not rep.ok and any("8 bytes after the library's end record" in m for m in rep.mismatches)


def test_date_is_recorded_and_kept_on_resume(tmp_path, design, small_frame, monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", str(int(1e9)))  # 2001-09-09
    a = make_spec(design, band_rows=16, **small_frame)
    assert a.date == "2001-09-09" and "2001-09-09" in a.printed_text()
    p = tmp_path / "d.gds"
    with pytest.raises(KeyboardInterrupt):
        export_layout(a, p, "gds", ExportOptions(max_refs=4096, stop_after=3))
    b = replace(a, date="2001-09-10")  # the next day: the resumed file keeps its date, bytes as one run
    res = export_layout(b, p, "gds", ExportOptions(max_refs=4096))
    assert res.resumed_bands == 3 and res.extra["date"] == "2001-09-09"
    q = tmp_path / "one.gds"
    export_layout(a, q, "gds", ExportOptions(max_refs=4096))
    assert p.read_bytes() == q.read_bytes()


def test_write_bias_and_wafer_rules(design, small_frame):
    base = make_spec(design, **small_frame)
    biased = make_spec(design, write_bias_um=0.05, **small_frame)
    assert np.all(biased.post_sizes_nm - base.post_sizes_nm == 100)  # widths + 2 x 50 nm
    assert "write_bias=0.05um" in biased.label_text()
    from metafovea.layout.frame import content_hash
    assert content_hash(biased) != content_hash(base)
    big = LensDesign("big", 150_000.0, 96_000.0, polarization="x")
    with pytest.raises(InputError, match="wafer_diameter_mm.*150 mm"):
        make_spec(big, post_set="ideal")
    ok = make_spec(big, post_set="ideal", wafer_diameter_mm=150.0)
    assert ok.centre_nm == 75_000_000 and math.isclose(ok.wafer_flat_distance_um, math.sqrt(75e3 ** 2 - 28.75e3 ** 2))


def test_patch_defines_only_its_cells_and_verifies_from_its_label(tmp_path, design, small_frame):
    sp = make_spec(design, patch_mm=(0.2, 0.1, 0.03), band_rows=8, **small_frame)
    p = tmp_path / "patch.gds"
    export_layout(sp, p, "gds")
    ly = db.Layout()
    ly.read(str(p))
    assert [c.name for c in ly.top_cells()] == [sp.top_name]  # no unused post cell as an extra top cell
    full = make_spec(design, band_rows=8, **small_frame)
    for reader in ("klayout", "stream", "gdstk"):
        rep = verify_layout(p, full, reader=reader)  # no --patch: the label's patch is used
        assert rep.ok, (reader, rep.mismatches)
    other = replace(full, patch_um=(0.0, 0.0, 30.0))
    assert not verify_layout(p, other, reader="stream").ok


def test_dwl_mode_limits(tmp_path, spec):
    """DWL 66 mode: posts as rectangles, structure definitions and references per structure within 8192 (counted
    here from the records), readable and verified by every reader, refused where it makes no sense."""
    import gdstk

    p = tmp_path / "dwl.gds"
    res = export_layout(spec, p, "gds", ExportOptions(dwl=True))
    assert res.flat and res.extra["dwl"]
    lib = gdstk.read_gds(str(p), unit=1e-6)
    assert len(lib.cells) <= 8192
    assert max(len(c.references) for c in lib.cells) <= 8192
    assert not any(c.name in spec.post_names for c in lib.cells)
    assert sum(len(c.polygons) for c in lib.cells if c.name.startswith("L")) == res.posts
    for reader in ("stream", "gdstk", "klayout"):
        rep = verify_layout(p, spec, reader=reader, dwl=True)
        assert rep.ok, (reader, rep.mismatches)
    with pytest.raises(InputError, match="^dwl = "):
        export_layout(spec, tmp_path / "x.oas", "oas", ExportOptions(dwl=True))
    with pytest.raises(InputError, match="^dwl = "):
        ExportOptions(dwl=True, max_refs=100)

"""Layout export: exact counts, geometry (XOR against the design), read-back, resume, bad input."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from metafovea import lens
from metafovea.config import LensDesign
from metafovea.errors import InputError
from metafovea.layout import TestArraySpec, band_levels, expected_content, export_layout, export_test_array, make_spec
from metafovea.layout.export import part_paths
from metafovea.layout.verify import verify_layout
from metafovea.library import PostSet

db = pytest.importorskip("klayout.db")

SMALL = dict(ring_width_um=100.0, mark_offset_um=50.0, mark_size_um=40.0, mark_width_um=4.0)


@pytest.fixture(scope="module")
def design():
    return LensDesign("small", 1500.0, 1200.0, polarization="x")  # ~70k posts


@pytest.fixture(scope="module")
def spec(design):
    return make_spec(design, band_rows=16, **SMALL)


@pytest.fixture(scope="module")
def exported(tmp_path_factory, spec):
    d = tmp_path_factory.mktemp("lay")
    out = {}
    for fmt, flat in (("gds", False), ("gds", True), ("oas", False)):
        p = d / f"lens{'_flat' if flat else ''}.{fmt}"
        out[(fmt, flat)] = (p, export_layout(spec, p, fmt, flat=flat))
    return out


def _tile_counts(design, levels):
    c = np.zeros(levels, np.int64)
    for t in lens.iter_tiles(design, 256, levels=levels):
        v = t.levels[t.levels >= 0]
        c += np.bincount(v, minlength=levels)
    return c


@pytest.mark.parametrize("lattice", ["integer", "half"])
def test_band_levels_equal_evaluate_tile(lattice):
    d = LensDesign("t", 900.0, 700.0, lattice=lattice)
    lo, hi = lens.site_index_range(d)
    for (iy0, rows, ix0, cols) in [(lo, 20, lo, hi - lo + 1), (-5, 11, -40, 30), (3, 7, 10, 50), (-9, 5, -60, 12)]:
        a = band_levels(d, iy0, rows, ix0, cols, 8)
        b = lens.evaluate_tile(d, iy0, ix0, rows, cols, levels=8).levels
        assert np.array_equal(a, b)


def test_exact_counts_per_type(design, spec, exported):
    exp = expected_content(spec)
    assert exp.total == lens.count_posts(design)
    assert np.array_equal(exp.counts, _tile_counts(design, 8))
    for (fmt, flat), (p, res) in exported.items():
        assert res.counts == exp.counts.tolist(), (fmt, flat)
        assert res.posts == exp.total
    p, res = exported[("gds", False)]
    assert res.bytes == p.stat().st_size
    assert abs(res.bytes / res.posts - 28) < 0.5


@pytest.mark.parametrize("key,reader", [(("gds", False), "klayout"), (("gds", False), "stream"),
                                        (("gds", True), "klayout"), (("gds", True), "stream"),
                                        (("oas", False), "klayout"), (("oas", False), "gdstk")])
def test_readback_verifies(spec, exported, key, reader):
    p, res = exported[key]
    rep = verify_layout(p, spec, reader=reader)
    assert rep.ok, rep.mismatches
    assert rep.counts == res.counts
    assert rep.layers == [[1, 0], [2, 0], [3, 0], [10, 0]]
    assert min(rep.bbox_nm[:2]) == 0  # origin convention: lower-left of the frame at (0, 0)


def _design_region(spec):
    """The patch's posts built directly from the design (lens.evaluate_tile), as a klayout Region."""
    iy_lo, iy_hi, ix_lo, ix_hi = spec.window()
    t = lens.evaluate_tile(spec.design, iy_lo, ix_lo, iy_hi - iy_lo + 1, ix_hi - ix_lo + 1, levels=spec.levels)
    r = db.Region()
    w = np.rint(spec.post_set.widths_um * 1000 / (2 * spec.grid_nm)).astype(int) * 2 * spec.grid_nm
    c = spec.centre_nm
    P = int(round(spec.design.period_um * 1000))
    for (a, b) in zip(*np.nonzero(t.levels >= 0)):
        k = t.levels[a, b]
        x, y = c + (ix_lo + b) * P, c + (iy_lo + a) * P
        hx, hy = int(w[k, 0]) // 2, int(w[k, 1]) // 2
        r.insert(db.Box(int(x) - hx, int(y) - hy, int(x) + hx, int(y) + hy))
    return r, int((t.levels >= 0).sum())


@pytest.mark.parametrize("fmt,flat", [("gds", False), ("gds", True), ("oas", False)])
def test_patch_xor_against_design(tmp_path, design, fmt, flat):
    # a patch at the rim: cut by the aperture
    sp = make_spec(design, patch_mm=(0.45, -0.3, 0.12), band_rows=8, **SMALL)
    p = tmp_path / f"patch.{fmt}"
    res = export_layout(sp, p, fmt, flat=flat)
    ly = db.Layout()
    ly.read(str(p))
    top = ly.top_cells()[0]
    li = ly.layer(1, 0)
    got = db.Region(top.begin_shapes_rec(li))
    want, n = _design_region(sp)
    assert res.posts == n > 100
    assert got.count() == n
    assert (got ^ want).is_empty()
    assert verify_layout(p, sp).ok


def test_resume_after_interrupt(tmp_path, spec, exported):
    p = tmp_path / "r.gds"
    with pytest.raises(KeyboardInterrupt):
        export_layout(spec, p, "gds", _stop_after=3)
    part, journal = part_paths(p)
    assert not p.exists() and part.exists() and journal.exists()
    # a crash after the last checkpoint leaves extra bytes: they are cut off on resume
    with open(part, "ab") as fh:
        fh.write(b"\x00garbage")
    res = export_layout(spec, p, "gds")
    assert res.resumed_bands == 3
    assert not part.exists() and not journal.exists()
    ref = exported[("gds", False)][0]
    assert p.read_bytes() == ref.read_bytes()


def test_resume_oasis_and_changed_parameters_restart(tmp_path, spec, design, exported):
    p = tmp_path / "r.oas"
    with pytest.raises(KeyboardInterrupt):
        export_layout(spec, p, "oas", _stop_after=2)
    res = export_layout(spec, p, "oas")
    assert res.resumed_bands == 2
    assert p.read_bytes() == exported[("oas", False)][0].read_bytes()
    # a partial export with other parameters is not continued
    q = tmp_path / "q.gds"
    with pytest.raises(KeyboardInterrupt):
        export_layout(spec, q, "gds", _stop_after=2)
    other = make_spec(design, levels=4, band_rows=16, **SMALL)
    res = export_layout(other, q, "gds")
    assert res.resumed_bands == 0 and verify_layout(q, other).ok


def test_parallel_workers_same_bytes(tmp_path, spec, exported):
    p = tmp_path / "w.oas"
    export_layout(spec, p, "oas", workers=2)
    assert p.read_bytes() == exported[("oas", False)][0].read_bytes()


def test_refuses_overwrite_without_force(tmp_path, spec):
    p = tmp_path / "x.gds"
    export_layout(spec, p, "gds")
    with pytest.raises(InputError, match="force"):
        export_layout(spec, p, "gds")
    export_layout(spec, p, "gds", force=True)
    assert verify_layout(p, spec).ok


def test_bad_input(tmp_path, design):
    with pytest.raises(InputError, match="--patch"):
        make_spec(design, patch_mm=(5.0, 5.0, 0.5))
    with pytest.raises(InputError, match="--levels"):
        make_spec(design, PostSet.ideal(8, period_um=4.0), levels=4)
    sp = make_spec(design, **SMALL)
    with pytest.raises(InputError, match="--format"):
        export_layout(sp, tmp_path / "a.dxf", "dxf")
    with pytest.raises(InputError, match="--flat"):
        export_layout(sp, tmp_path / "a.oas", "oas", flat=True)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(InputError, match="--out"):
        export_layout(sp, blocker / "sub" / "a.gds", "gds")
    assert not (tmp_path / "a.dxf").exists() and not (tmp_path / "a.oas").exists()


def test_disk_full_leaves_no_file(tmp_path, toml):
    # RLIMIT_FSIZE makes writes fail part-way (EFBIG), like a full disk
    out = tmp_path / "big.gds"
    code = textwrap.dedent(f"""
        import resource, signal, sys
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))
        from metafovea.cli import main
        sys.exit(main(["export", {str(toml)!r}, "--out", {str(out)!r}, "--quiet", "--ring-width-um", "100"]))
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert "error:" in r.stderr and ("disk" in r.stderr or "space" in r.stderr)
    assert len(r.stderr.strip().splitlines()) == 1
    assert not out.exists()


@pytest.fixture(scope="module")
def toml(tmp_path_factory):
    p = tmp_path_factory.mktemp("design") / "small.toml"
    p.write_text('name = "small"\nf_mm = 1.5\ndiameter_mm = 1.2\nwavelength_um = 10.0\n'
                 'polarization = "x"\nlevels = 8\nlattice = "integer"\n')
    return p


def test_verify_detects_mismatch(tmp_path, spec, design, exported):
    p, _ = exported[("gds", False)]
    other = make_spec(design.with_(f_um=1600.0), band_rows=16, **SMALL)
    rep = verify_layout(p, other, reader="klayout")
    assert not rep.ok and any("expected" in m for m in rep.mismatches)
    # tamper with one reference (P000 -> P001): both readers see the changed counts
    data = bytearray(p.read_bytes())
    i = data.index(b"\x00\x08\x12\x06P000", len(data) // 2)
    data[i + 7] = ord("1")
    q = tmp_path / "t.gds"
    q.write_bytes(bytes(data))
    for reader in ("klayout", "stream"):
        rep = verify_layout(q, spec, reader=reader)
        assert not rep.ok
        assert any(m.startswith("P000") for m in rep.mismatches) and any(m.startswith("P001") for m in rep.mismatches)


@pytest.mark.parametrize("fmt,flat", [("gds", False), ("gds", True), ("oas", False)])
def test_calibration_array(tmp_path, spec, fmt, flat):
    ta = TestArraySpec(spec, block=12)
    p = tmp_path / f"cal.{fmt}"
    res = export_test_array(ta, p, fmt, flat=flat)
    assert res.counts == [144] * 8
    rep = verify_layout(p, spec, test_array=ta)
    assert rep.ok, rep.mismatches
    if not flat:
        rep = verify_layout(p, spec, test_array=ta, reader="gdstk")
        assert rep.ok, rep.mismatches


@pytest.mark.parametrize("fmt", ["stl", "glb"])
def test_mesh_patch(tmp_path, design, fmt):
    import trimesh

    from metafovea.layout.mesh import export_mesh, patch_mesh

    sp = make_spec(design, patch_mm=(0.1, 0.1, 0.04), **SMALL)
    m = patch_mesh(sp)
    n = len(m.faces) // 12 - 1
    assert n == 100  # 10 x 10 sites of 4 um
    sz = sp.post_sizes_nm / 1000.0
    res = export_mesh(sp, tmp_path / f"m.{fmt}")
    assert res["posts"] == n
    back = trimesh.load(tmp_path / f"m.{fmt}", force="mesh")
    assert len(back.faces) == len(m.faces)
    assert back.bounds[0][2] == pytest.approx(-design.post_height_um)
    assert back.bounds[1][2] == pytest.approx(design.post_height_um)
    assert m.volume > 0 and m.volume == pytest.approx(
        sum(abs(trimesh.Trimesh(m.vertices[8 * i:8 * i + 8], m.faces[12 * i:12 * i + 12] - 8 * i).volume)
            for i in range(len(m.faces) // 12)))
    assert (sz[:, 0] * sz[:, 1]).min() > 0
    with pytest.raises(InputError, match="--patch"):
        patch_mesh(make_spec(design, **SMALL))


def test_cli_export_verify(tmp_path, capsys, toml):
    from metafovea.cli import main

    out = tmp_path / "cli"
    args = [str(toml), "--ring-width-um", "100", "--quiet"]
    assert main(["export", *args, "--format", "oas", "--out", str(out), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["path"].endswith("cli.oas") and os.path.isfile(res["path"])
    assert main(["verify", res["path"], "--design", str(toml), "--ring-width-um", "100", "--quiet"]) == 0
    # mismatching design parameters: exit 1
    assert main(["verify", res["path"], "--design", str(toml), "--quiet"]) == 1
    # existing output: exit 2 with a one-line error
    assert main(["export", *args, "--format", "oas", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--force" in err
    assert main(["export", *args, "--format", "gds", "--patch", "9,9,0.1", "--out", str(tmp_path / "z")]) == 2
    assert main(["export", *args, "--format", "oas", "--levels", "5", "--post-set", str(tmp_path / "none.npz")]) == 2
    assert not (tmp_path / "z.gds").exists()


# ----------------------------------------------------------------------------------------------
# mirror tasks, threads, hierarchical GDSII (--max-refs)
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("lattice", ["integer", "half"])
def test_tasks_cover_each_row_once(lattice):
    d = LensDesign("t", 900.0, 700.0, lattice=lattice)
    for patch in (None, (0.1, -0.2, 0.15), (-0.25, 0.3, 0.1)):
        sp = make_spec(d, band_rows=7, patch_mm=patch)
        from metafovea.layout.tiling import task_rows
        seen = []
        two_o = 0 if lattice == "integer" else 1
        for t in sp.tasks():
            j = np.arange(t[1], t[1] + t[2])
            for sign, mask, ys in task_rows(sp, t):
                iy = j if sign == 1 else -j - two_o
                seen += iy[mask].tolist()
                assert np.array_equal(ys, sp.site_y_nm(iy))
        want = [b[0] + i for b in sp.bands() for i in range(b[1])]
        lo, hi = lens.row_half_counts(d, np.array(want))
        iy_lo, iy_hi, ix_lo, ix_hi = sp.window()
        want = [w for w, a, b in zip(want, lo, hi) if max(a, ix_lo) <= min(b, ix_hi)]
        assert sorted(seen) == sorted(want) and len(seen) == len(set(seen))


def test_oasis_vectorised_placements_match_loop(spec):
    from metafovea.layout import oasis as o
    # the +y side of a task equals the per-band loop encoder on the same rows
    t = spec.tasks()[2]
    parts, c = o.encode_task_oas(spec, 0, t)
    old, c_old = o.encode_band_oas(spec, 0, (t[1], t[2], t[3], t[4]))
    assert parts[0][:len(old)] == old and len(parts[0]) == 2 * len(old)
    assert c.sum() == 2 * c_old.sum()


@pytest.mark.parametrize("fmt,flat", [("gds", False), ("gds", True)])
def test_threads_same_bytes_gds(tmp_path, spec, exported, fmt, flat):
    p = tmp_path / f"w.{fmt}"
    export_layout(spec, p, fmt, flat=flat, workers=2, inflight=3)
    assert p.read_bytes() == exported[(fmt, flat)][0].read_bytes()
    q = tmp_path / f"wp.{fmt}"  # processes
    export_layout(spec, q, fmt, flat=flat, workers=2, threads=False)
    assert q.read_bytes() == p.read_bytes()


def _gds_structures(path):
    """structure name -> (SREF count, {SNAME: count}, BOUNDARY count), by an independent record walk."""
    data = Path(path).read_bytes()
    out, pos, cur, el = {}, 0, None, None
    while pos < len(data):
        ln = int.from_bytes(data[pos:pos + 2], "big")
        rt = data[pos + 2]
        body = data[pos + 4:pos + ln]
        if rt == 0x06:
            cur = body.rstrip(b"\0").decode()
            out[cur] = [0, {}, 0]
        elif rt == 0x0A:
            el = "sref"
        elif rt == 0x08:
            out[cur][2] += 1
        elif rt == 0x12 and el == "sref":
            nm = body.rstrip(b"\0").decode()
            out[cur][0] += 1
            out[cur][1][nm] = out[cur][1].get(nm, 0) + 1
        elif rt == 0x11:
            el = None
        pos += ln
    return out


@pytest.mark.parametrize("flat,max_refs", [(False, 64), (False, 8192), (True, 100)])
def test_hierarchical_gds_max_refs(tmp_path, spec, flat, max_refs):
    exp = expected_content(spec)
    p = tmp_path / "h.gds"
    res = export_layout(spec, p, "gds", flat=flat, max_refs=max_refs, workers=2)
    assert res.counts == exp.counts.tolist()
    st = _gds_structures(p)
    # every structure within the limit (elements: references + boundaries + the top's texts)
    for name, (nref, _, nb) in st.items():
        assert nref + nb <= max_refs, name
    # counts per post type through the hierarchy, computed here independently
    memo = {}

    def flatten(name):
        if name in memo:
            return memo[name]
        nref, children, nb = st[name]
        c = np.zeros(spec.levels, np.int64)
        for ch, n in children.items():
            if ch in spec.post_names:
                c[spec.post_names.index(ch)] += n
            else:
                c += n * flatten(ch)
        if flat and name.startswith("L"):
            c[0] += 0  # flat leaves hold boundaries (counted by the readers below)
        memo[name] = c
        return c

    if not flat:
        assert np.array_equal(flatten(spec.top_name), exp.counts)
        assert sum(st[n][0] for n in st if n.startswith("L")) == exp.total
    else:
        assert sum(st[n][2] for n in st if n.startswith("L")) == exp.total
    depth = 1 + max(int(n[1:].split("_")[0]) for n in st if n.startswith("M")) if any(
        n.startswith("M") for n in st) else 1
    if max_refs == 64:
        assert depth >= 2  # more than 64 leaves: intermediate levels
    for reader in ("klayout", "stream", "gdstk"):
        rep = verify_layout(p, spec, reader=reader, max_refs=max_refs)
        assert rep.ok, (reader, rep.mismatches)
        assert rep.counts == exp.counts.tolist()
        assert 0 < rep.max_elements_per_structure <= max_refs
        assert rep.structures == len(st)
    # a tighter limit is reported
    rep = verify_layout(p, spec, reader="stream", max_refs=max_refs // 2)
    assert not rep.ok and any("--max-refs" in m for m in rep.mismatches)
    # klayout reads it with one top cell and the same flattened shape count
    ly = db.Layout()
    ly.read(str(p))
    assert [c.name for c in ly.top_cells()] == [spec.top_name]
    top = ly.top_cells()[0]
    assert db.Region(top.begin_shapes_rec(ly.layer(1, 0))).count() == exp.total


def test_hierarchical_resume_and_tamper(tmp_path, spec):
    ref = tmp_path / "ref.gds"
    export_layout(spec, ref, "gds", max_refs=64)
    p = tmp_path / "r.gds"
    with pytest.raises(KeyboardInterrupt):
        export_layout(spec, p, "gds", max_refs=64, _stop_after=2)
    res = export_layout(spec, p, "gds", max_refs=64)
    assert res.resumed_bands == 2 and p.read_bytes() == ref.read_bytes()
    # moving one post reference into another type is seen through the hierarchy
    data = bytearray(p.read_bytes())
    i = data.index(b"\x00\x08\x12\x06P003", len(data) // 3)
    data[i + 7] = ord("4")
    q = tmp_path / "t.gds"
    q.write_bytes(bytes(data))
    for reader in ("stream", "klayout"):
        rep = verify_layout(q, spec, reader=reader)
        assert not rep.ok
        assert any(m.startswith("P003") for m in rep.mismatches) and any(m.startswith("P004") for m in rep.mismatches)


def test_max_refs_bad_input(tmp_path, spec, toml):
    with pytest.raises(InputError, match="--max-refs"):
        export_layout(spec, tmp_path / "a.oas", "oas", max_refs=8192)
    with pytest.raises(InputError, match="--max-refs"):
        export_layout(spec, tmp_path / "a.gds", "gds", max_refs=3)
    big = make_spec(LensDesign("big", 60000.0, 40000.0, polarization="x"))  # ring fractured into 25 polygons
    with pytest.raises(InputError, match="--max-refs"):
        export_layout(big, tmp_path / "a.gds", "gds", max_refs=16)  # not above the frame's 29 elements
    assert not (tmp_path / "a.gds").exists()
    from metafovea.cli import main
    assert main(["export", str(toml), "--format", "oas", "--max-refs", "8192", "--out", str(tmp_path / "b"),
                 "--quiet"]) == 2
    assert main(["export", str(toml), "--ring-width-um", "100", "--max-refs", "8192", "--out",
                 str(tmp_path / "c.gds"), "--quiet", "--json"]) == 0
    assert main(["verify", str(tmp_path / "c.gds"), "--design", str(toml), "--ring-width-um", "100",
                 "--max-refs", "8192", "--quiet"]) == 0
    assert main(["verify", str(tmp_path / "c.gds"), "--design", str(toml), "--ring-width-um", "100",
                 "--max-refs", "100", "--quiet"]) == 1


def test_direct_file_matches_buffered(tmp_path, spec, exported):
    from metafovea.layout.export import DirectFile

    rng = np.random.default_rng(1)
    chunks = [rng.integers(0, 256, int(n), dtype=np.uint8) for n in rng.integers(1, 30000, 40)]
    want = b"".join(c.tobytes() for c in chunks)
    a = tmp_path / "a.bin"
    f = DirectFile(a, staging=16384)
    for i, c in enumerate(chunks[:25]):
        f.write(c)
        if i % 7 == 3:
            f.flush()
            assert a.stat().st_size == f.pos  # everything written so far is in the file
    f.flush()
    f.close()
    f = DirectFile(a, len(b"".join(c.tobytes() for c in chunks[:20])), staging=16384)  # resume mid-way
    for c in chunks[20:]:
        f.write(c)
    f.sync()
    f.close()
    assert a.read_bytes() == want
    # the export with and without O_DIRECT: same bytes
    p = tmp_path / "b.gds"
    export_layout(spec, p, "gds", direct=False)
    assert p.read_bytes() == exported[("gds", False)][0].read_bytes()


@pytest.mark.parametrize("fmt", ["gds", "oas"])
def test_half_lattice_export_counts_and_xor(tmp_path, fmt):
    d = LensDesign("half", 1500.0, 1200.0, polarization="x", lattice="half")
    sp = make_spec(d, band_rows=16, **SMALL)
    p = tmp_path / f"h.{fmt}"
    res = export_layout(sp, p, fmt, workers=2)
    assert res.counts == _tile_counts(d, 8).tolist()
    rep = verify_layout(p, sp, reader="klayout")
    assert rep.ok, rep.mismatches
    # a patch across the centre row and column (both row sides, both column sides) against the design
    pp = make_spec(d, patch_mm=(0.0, 0.0, 0.1), band_rows=4, **SMALL)
    q = tmp_path / f"c.{fmt}"
    export_layout(pp, q, fmt)
    ly = db.Layout()
    ly.read(str(q))
    got = db.Region(ly.cell(pp.top_name).begin_shapes_rec(ly.layer(1, 0)))
    assert verify_layout(q, pp, reader="klayout").ok  # post types unused in the patch are extra top cells
    iy_lo, iy_hi, ix_lo, ix_hi = pp.window()
    t = lens.evaluate_tile(d, iy_lo, ix_lo, iy_hi - iy_lo + 1, ix_hi - ix_lo + 1, levels=8)
    want = db.Region()
    w = pp.post_sizes_nm
    for (a, b) in zip(*np.nonzero(t.levels >= 0)):
        k = t.levels[a, b]
        x, y = int(pp.site_x_nm(ix_lo + b)), int(pp.site_y_nm(iy_lo + a))
        want.insert(db.Box(x - int(w[k, 0]) // 2, y - int(w[k, 1]) // 2, x + int(w[k, 0]) // 2, y + int(w[k, 1]) // 2))
    assert got.count() == want.count() == 625 and (got ^ want).is_empty()

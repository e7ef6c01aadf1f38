"""Layout export: exact counts, geometry (XOR against the design), resume, workers, atomic and direct writes,
calibration arrays, output names, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea import lens
from metafovea.config import LensDesign
from metafovea.errors import InputError
from metafovea.layout import (
    ExportOptions,
    TestArraySpec,
    expected_content,
    export_file,
    export_layout,
    export_test_array,
    make_spec,
)
from metafovea.layout.export import DirectFile, output_path, part_paths
from metafovea.layout.verify import verify_layout

db = pytest.importorskip("klayout.db")


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


# ----------------------------------------------------------------------------------------------
# reference: the files hold exactly the design's posts
# ----------------------------------------------------------------------------------------------
def test_exact_counts_per_type(design, spec, exported, tile_counts):
    exp = expected_content(spec)
    assert exp.total == lens.count_posts(design)
    assert np.array_equal(exp.counts, tile_counts(design, 8))
    for (fmt, flat), (_p, res) in exported.items():
        assert res.counts == exp.counts.tolist(), (fmt, flat)
        assert res.posts == exp.total
    p, res = exported[("gds", False)]
    assert res.bytes == p.stat().st_size
    from metafovea.layout.gds import ENDSTR_ENDLIB, gds_header
    assert (res.bytes - len(gds_header(spec)) - len(ENDSTR_ENDLIB)) == 28 * res.posts  # one 28-byte SREF per post


@pytest.mark.parametrize("fmt,flat", [("gds", False), ("gds", True), ("oas", False)])
def test_patch_xor_against_design(tmp_path, design, small_frame, fmt, flat):
    # a patch at the rim: cut by the aperture
    sp = make_spec(design, patch_mm=(0.45, -0.3, 0.12), band_rows=8, **small_frame)
    p = tmp_path / f"patch.{fmt}"
    res = export_layout(sp, p, fmt, ExportOptions(flat=flat))
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


@pytest.mark.parametrize("fmt", ["gds", "oas"])
def test_half_lattice_export_counts_and_xor(tmp_path, small_frame, tile_counts, fmt):
    d = LensDesign("half", 1500.0, 1200.0, polarization="x", lattice="half")
    sp = make_spec(d, band_rows=16, **small_frame)
    p = tmp_path / f"h.{fmt}"
    res = export_layout(sp, p, fmt, ExportOptions(workers=2))
    assert res.counts == tile_counts(d, 8).tolist()
    rep = verify_layout(p, sp, reader="klayout")
    assert rep.ok, rep.mismatches
    # a patch across the centre row and column (both row sides, both column sides) against the design
    pp = make_spec(d, patch_mm=(0.0, 0.0, 0.1), band_rows=4, **small_frame)
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


# ----------------------------------------------------------------------------------------------
# resume, workers, writes
# ----------------------------------------------------------------------------------------------
def test_resume_after_interrupt(tmp_path, spec, exported):
    p = tmp_path / "r.gds"
    with pytest.raises(KeyboardInterrupt):
        export_layout(spec, p, "gds", ExportOptions(stop_after=3))
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


def test_resume_oasis_and_changed_parameters_restart(tmp_path, spec, design, small_frame, exported):
    p = tmp_path / "r.oas"
    with pytest.raises(KeyboardInterrupt):
        export_layout(spec, p, "oas", ExportOptions(stop_after=2))
    res = export_layout(spec, p, "oas")
    assert res.resumed_bands == 2
    assert p.read_bytes() == exported[("oas", False)][0].read_bytes()
    # a partial export with other parameters is not continued
    q = tmp_path / "q.gds"
    with pytest.raises(KeyboardInterrupt):
        export_layout(spec, q, "gds", ExportOptions(stop_after=2))
    other = make_spec(design, levels=4, band_rows=16, **small_frame)
    res = export_layout(other, q, "gds")
    assert res.resumed_bands == 0 and verify_layout(q, other).ok


@pytest.mark.parametrize("journal", ['[]', '{"bands_done": "2", "offset": 10}', '{"offset": 5}', '"x"',
                                     '{"bands_done": 1, "offset": 10, "counts": 3}'])
def test_export_resume_with_malformed_journal_starts_over(tmp_path, journal):
    """A valid-JSON but malformed resume journal raised AttributeError/KeyError/TypeError tracebacks."""
    spec = make_spec(LensDesign("t", 900.0, 400.0), band_rows=8, ring_width_um=30.0)
    ref = export_layout(spec, tmp_path / "ref.gds", "gds")
    p = tmp_path / "lens.gds"
    with pytest.raises(KeyboardInterrupt):
        export_layout(spec, p, "gds", ExportOptions(stop_after=2))
    part, jpath = part_paths(p)
    jpath.write_text(journal)
    res = export_layout(spec, p, "gds")
    assert res.posts == ref.posts and p.read_bytes() == (tmp_path / "ref.gds").read_bytes()


def test_parallel_workers_same_bytes(tmp_path, spec, exported):
    p = tmp_path / "w.oas"
    export_layout(spec, p, "oas", ExportOptions(workers=2))
    assert p.read_bytes() == exported[("oas", False)][0].read_bytes()


@pytest.mark.parametrize("fmt,flat", [("gds", False), ("gds", True)])
def test_threads_same_bytes_gds(tmp_path, spec, exported, fmt, flat):
    p = tmp_path / f"w.{fmt}"
    export_layout(spec, p, fmt, ExportOptions(flat=flat, workers=2, inflight=3))
    assert p.read_bytes() == exported[(fmt, flat)][0].read_bytes()
    q = tmp_path / f"wp.{fmt}"  # processes
    export_layout(spec, q, fmt, ExportOptions(flat=flat, workers=2, threads=False))
    assert q.read_bytes() == p.read_bytes()


def test_direct_file_matches_buffered(tmp_path, spec, exported):
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
    export_layout(spec, p, "gds", ExportOptions(direct=False))
    assert p.read_bytes() == exported[("gds", False)][0].read_bytes()


def test_direct_file_placed_buffers(tmp_path, monkeypatch):
    """Buffers an encoder filled in place (at the file's offset within its block) go to the disk as they are, between
    staged writes, flushes and a resume: the same bytes as one plain write; each buffer is given back once."""
    import mmap
    import os

    with open(tmp_path / "probe", "wb"):
        pass
    try:  # where O_DIRECT is refused (tmpfs): a plain descriptor, the same code path
        os.close(os.open(tmp_path / "probe", os.O_WRONLY | os.O_DIRECT))
    except (OSError, AttributeError):
        monkeypatch.setattr(os, "O_DIRECT", 0, raising=False)
    rng = np.random.default_rng(2)
    chunks = [rng.integers(0, 256, int(n), dtype=np.uint8) for n in rng.integers(1, 30000, 30)]
    want = b"".join(c.tobytes() for c in chunks)
    a = tmp_path / "a.bin"
    given_back = []
    for resume_at in (None, 17):
        f = DirectFile(a, staging=16384, depth=1) if resume_at is None else \
            DirectFile(a, sum(c.size for c in chunks[:resume_at]), staging=16384, depth=1)
        assert f.direct
        for i, c in enumerate(chunks[resume_at or 0:], start=resume_at or 0):
            if resume_at is None and i >= 25:
                break
            if i % 3 == 0:
                f.write(c)
                continue
            pre = f.pos % f.BLOCK
            buf = mmap.mmap(-1, pre + c.size + f.BLOCK)
            np.frombuffer(buf, np.uint8, count=c.size, offset=pre)[:] = c
            f.write_placed(buf, pre, c.size, done=lambda i=i: given_back.append(i))
            if i % 5 == 0:
                f.flush()
                assert a.stat().st_size == f.pos
            with pytest.raises(ValueError):
                f.write_placed(buf, (f.pos + 1) % f.BLOCK, 1)  # not at the file's offset in its block
        f.sync()
        f.close()
    assert a.read_bytes() == want
    placed = [i for i in range(30) if i % 3]
    assert sorted(given_back) == sorted(placed[:placed.index(25)] + [i for i in placed if i >= 17])


def test_direct_file_background_error_is_raised(tmp_path, monkeypatch):
    """A failed background write (disk full) comes back as the OSError of the next write or flush, not lost."""
    import errno
    import os

    # where the file system refuses O_DIRECT (tmpfs), open the direct descriptor as a plain one: the staging
    # buffers and the background thread under test run the same
    with open(tmp_path / "probe", "wb"):
        pass
    try:
        os.close(os.open(tmp_path / "probe", os.O_WRONLY | os.O_DIRECT))
    except (OSError, AttributeError):
        monkeypatch.setattr(os, "O_DIRECT", 0, raising=False)
    f = DirectFile(tmp_path / "e.bin", staging=16384)
    assert f.direct
    real = os.pwrite

    def full(fd, data, off):
        if fd == f.dfd:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(fd, data, off)

    monkeypatch.setattr(os, "pwrite", full)
    with pytest.raises(OSError) as e:
        for _ in range(8):
            f.write(np.zeros(16384, np.uint8))  # the second write hands the first buffer off, later ones see it
        f.flush()
    assert e.value.errno == errno.ENOSPC
    monkeypatch.setattr(os, "pwrite", real)
    f.close()


def test_refuses_overwrite_without_force(tmp_path, spec):
    p = tmp_path / "x.gds"
    export_layout(spec, p, "gds")
    with pytest.raises(InputError, match="force"):
        export_layout(spec, p, "gds")
    export_layout(spec, p, "gds", ExportOptions(force=True))
    assert verify_layout(p, spec).ok


# ----------------------------------------------------------------------------------------------
# calibration array, one file as `metafovea export` writes it
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("fmt,flat", [("gds", False), ("gds", True), ("oas", False)])
def test_calibration_array(tmp_path, spec, fmt, flat):
    ta = TestArraySpec(spec, block=12)
    p = tmp_path / f"cal.{fmt}"
    res = export_test_array(ta, p, fmt, flat=flat)
    assert res.counts == [144] * 8
    rep = verify_layout(p, spec, test_array=ta)
    assert rep.ok, rep.mismatches
    assert rep.expected_counts == [144] * 8 and rep.expected_posts_bbox_nm == ta.expected().posts_bbox_nm
    if not flat:
        rep = verify_layout(p, spec, test_array=ta, reader="gdstk")
        assert rep.ok, rep.mismatches


def test_calibration_block_checked(spec):
    for block in (0, 5000):
        with pytest.raises(InputError, match="block"):
            TestArraySpec(spec, block=block)


def test_output_path_names_and_suffixes(spec, design):
    """Default names come from the sanitised lens name plus what was asked; a suffix of another format is
    refused (a .oas name with GDSII inside misleads every tool), no suffix gets the format's."""
    assert output_path(spec, "gds") == output_path(spec, "gds", None)
    assert str(output_path(spec, "gds")) == "gds_export/small.gds"
    assert output_path(spec, "oas", test_array=True).name == "small_cal.oas"
    assert output_path(spec, "gds", flat=True, max_refs=64).name == "small_flat_h64.gds"
    odd = make_spec(design.with_(name=".a b+c"), patch_mm=(0, 0, 0.05))
    assert str(output_path(odd, "stl")) == "gds_export/a_b_c_patch.stl"
    assert output_path(spec, "gds", "out/a.GDSII").name == "a.GDSII"
    assert output_path(spec, "oas", "out/a").name == "a.oas"
    assert output_path(spec, "gds", "out/a.b").name == "a.b.gds"
    with pytest.raises(InputError, match="out = .*ending in .oas or .oasis for fmt='oas'"):
        output_path(spec, "oas", "a.gds")


def test_export_file_writes_the_lens_the_array_or_the_mesh(tmp_path, spec, design, small_frame, exported):
    res = export_file(spec, tmp_path / "a", "GDS", ExportOptions(workers=1))
    assert res["path"] == str(tmp_path / "a.gds") and res["posts"] == exported[("gds", False)][1].posts
    assert (tmp_path / "a.gds").read_bytes() == exported[("gds", False)][0].read_bytes()
    res = export_file(spec, tmp_path / "c", "oas", test_array=TestArraySpec(spec, block=3))
    assert res["counts"] == [9] * 8 and res["path"].endswith("c.oas")
    pytest.importorskip("trimesh")
    patch = make_spec(design, patch_mm=(0.1, 0.1, 0.02), **small_frame)
    res = export_file(patch, tmp_path / "m", "stl")
    assert res["posts"] == 25 and res["path"].endswith("m.stl")


def test_export_bad_input(tmp_path, design, spec, small_frame):
    sp = make_spec(design, **small_frame)
    with pytest.raises(InputError, match="^fmt = "):
        export_layout(sp, tmp_path / "a.dxf", "dxf")
    with pytest.raises(InputError, match="^flat = "):
        export_layout(sp, tmp_path / "a.oas", "oas", ExportOptions(flat=True))
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(InputError, match="^path = "):
        export_layout(sp, blocker / "sub" / "a.gds", "gds")
    assert not (tmp_path / "a.dxf").exists() and not (tmp_path / "a.oas").exists()
    for fmt, kw, flag in (("dxf", {}, "^fmt = 'dxf'"), ("oas", dict(max_refs=100), "^max_refs = "),
                          ("stl", dict(flat=True), "^fmt = 'stl' .*flat=True or test_array=")):
        with pytest.raises(InputError, match=flag):
            export_file(spec, tmp_path / "z", fmt, ExportOptions(**kw))
    for kw, flag in ((dict(compress=10), "^compress = "), (dict(workers=0), "^workers = "),
                     (dict(tiles_dir=tmp_path / "t"), r"^tiles_dir = .* only with scheduler=\.\.\."),
                     (dict(dwl=True, max_refs=100), r"^dwl = .*only without max_refs=\.\.\.")):
        with pytest.raises(InputError, match=flag):
            ExportOptions(**kw)
    assert not list(tmp_path.glob("z*")) and not (tmp_path / "t").exists()


def test_estimated_size_and_free_space(tmp_path, spec, exported, monkeypatch):
    """The estimate is the posts' records (the header and frame left out; OASIS unknown); a disk without the room
    for it is refused before anything is written, naming the file."""
    import shutil

    from metafovea.layout.export import estimated_bytes, size_notice
    from metafovea.layout.gds import BOUNDARY_BYTES, SREF_BYTES

    for flat, size in ((False, SREF_BYTES), (True, BOUNDARY_BYTES)):
        p, res = exported[("gds", flat)]
        est = estimated_bytes(spec, "gds", ExportOptions(flat=flat))
        assert est == res.posts * size and 0 < res.bytes - est < 200_000
    assert estimated_bytes(spec, "oas") is None and size_notice(spec, tmp_path / "a.gds") is None  # small: no notice
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage._replace(free=est - 1))
    with pytest.raises(InputError, match=r"^path = .*enough free space.*to write, .* free there"):
        export_layout(spec, tmp_path / "a.gds", "gds", ExportOptions(flat=True))
    assert list(tmp_path.iterdir()) == []
    export_layout(spec, tmp_path / "a.oas", "oas")  # size unknown: written

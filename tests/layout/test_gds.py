"""GDSII: hierarchical files (``max_refs``) hold every post within the element limit, read the same by three
readers and an independent record walk here; resume and tampering through the hierarchy; bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from metafovea.errors import InputError
from metafovea.layout import ExportOptions, expected_content, export_layout, make_spec
from metafovea.layout.verify import verify_layout

db = pytest.importorskip("klayout.db")


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
    res = export_layout(spec, p, "gds", ExportOptions(flat=flat, max_refs=max_refs, workers=2))
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
        memo[name] = c
        return c

    if not flat:
        assert np.array_equal(flatten(spec.top_name), exp.counts)
        assert sum(st[n][0] for n in st if n.startswith("L")) == exp.total
    else:  # flat leaves hold boundaries
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
    assert not rep.ok and any(f"max_refs={max_refs // 2}" in m for m in rep.mismatches)
    # klayout reads it with one top cell and the same flattened shape count
    ly = db.Layout()
    ly.read(str(p))
    assert [c.name for c in ly.top_cells()] == [spec.top_name]
    top = ly.top_cells()[0]
    assert db.Region(top.begin_shapes_rec(ly.layer(1, 0))).count() == exp.total


def test_hierarchical_resume_and_tamper(tmp_path, spec, retype_reference):
    ref = tmp_path / "ref.gds"
    export_layout(spec, ref, "gds", ExportOptions(max_refs=64))
    p = tmp_path / "r.gds"
    with pytest.raises(KeyboardInterrupt):
        export_layout(spec, p, "gds", ExportOptions(max_refs=64, stop_after=2))
    res = export_layout(spec, p, "gds", ExportOptions(max_refs=64))
    assert res.resumed_bands == 2 and p.read_bytes() == ref.read_bytes()
    # moving one post reference into another type is seen through the hierarchy
    q = retype_reference(p, tmp_path / "t.gds", "P003", "P004", start=1 / 3)
    for reader in ("stream", "klayout"):
        rep = verify_layout(q, spec, reader=reader)
        assert not rep.ok
        assert any(m.startswith("P003") for m in rep.mismatches) and any(m.startswith("P004") for m in rep.mismatches)


def test_max_refs_bad_input(tmp_path, spec):
    with pytest.raises(InputError, match="^max_refs = "):
        export_layout(spec, tmp_path / "a.oas", "oas", ExportOptions(max_refs=8192))
    with pytest.raises(InputError, match="^max_refs = "):
        export_layout(spec, tmp_path / "a.gds", "gds", ExportOptions(max_refs=3))
    assert not (tmp_path / "a.gds").exists()


@pytest.mark.parametrize("flat", [False, True])
def test_encoding_in_place_is_the_records(spec, design, small_frame, flat):
    """The records written into a buffer of the size known beforehand (the posts from the rows' site ranges) are
    the records encoded into new arrays, byte for byte, for the lens and a patch across its edge."""
    import mmap

    from metafovea.layout.gds import BOUNDARY_BYTES, SREF_BYTES, encode_task_into, encode_task_records
    from metafovea.layout.tiling import task_post_counts

    size = BOUNDARY_BYTES if flat else SREF_BYTES
    patch = make_spec(design, patch_mm=(0.35, -0.1, 0.3), **small_frame)
    for sp in (spec, patch):
        for task in sp.tasks():
            pieces, counts = encode_task_records(sp, flat, task)
            n = sum(task_post_counts(sp, task)) * size
            buf = mmap.mmap(-1, n + 6)
            out = np.frombuffer(buf, np.uint8, count=n, offset=6)  # at an offset, as in a file's block
            assert np.array_equal(encode_task_into(sp, flat, task, out), counts)
            assert out.tobytes() == b"".join(p.tobytes() for p in pieces)
            del out

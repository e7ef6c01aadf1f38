"""Layout readers: the three independent readers observe the same content; format sniffing; the stream
scanner's record handling (padding, truncation)."""

from __future__ import annotations

import pytest

from metafovea.errors import InputError
from metafovea.layout.read import lattice_of, read_gdstk, read_klayout, read_stream, sniff_format

pytest.importorskip("klayout.db")
pytest.importorskip("gdstk")


def _summary(ob):
    return (dict(ob.ref_counts), dict(ob.flat_counts), ob.posts_bbox, ob.bbox, sorted(ob.layers), ob.off_lattice,
            ob.top_cells, ob.dbu_um, ob.anomalies, ob.structures)


@pytest.mark.parametrize("flat", [False, True])
def test_readers_agree_on_gdsii(spec, exported, flat):
    """KLayout, gdstk and the streaming scanner share no code: on the same GDSII file they see the same
    references per post cell, rectangles per size, bounding boxes, layers and lattice positions."""
    p, res = exported[("gds", flat)]
    args = (p, lattice_of(spec), spec.layers.posts, spec.post_names)
    obs = [read_klayout(*args), read_gdstk(*args), read_stream(p, lattice_of(spec), spec.layers.posts,
                                                                False, spec.post_names)]
    assert [o.reader for o in obs] == ["klayout", "gdstk", "stream"]
    assert _summary(obs[0]) == _summary(obs[1]) == _summary(obs[2])
    n = sum(obs[0].flat_counts.values()) if flat else sum(obs[0].ref_counts.values())
    assert n == res.posts and obs[0].off_lattice == 0


def test_readers_agree_on_oasis(spec, exported):
    p, res = exported[("oas", False)]
    args = (p, lattice_of(spec), spec.layers.posts, spec.post_names)
    a, b = read_klayout(*args), read_gdstk(*args)
    assert a.format == b.format == "oas"
    assert dict(a.ref_counts) == dict(b.ref_counts) and sum(a.ref_counts.values()) == res.posts
    assert (a.posts_bbox, a.bbox, sorted(a.layers)) == (b.posts_bbox, b.bbox, sorted(b.layers))


def test_sniff_format(tmp_path, exported):
    assert sniff_format(exported[("gds", False)][0]) == "gds"
    assert sniff_format(exported[("oas", False)][0]) == "oas"
    (tmp_path / "x").write_text("not a layout")
    with pytest.raises(InputError, match="FILE .*a GDSII or OASIS file"):
        sniff_format(tmp_path / "x")


def test_stream_reader_accepts_padding_after_endlib(tmp_path, spec, exported):
    """Tools pad GDSII files with zeros after ENDLIB; the scanner called that a corrupt record (exit 1)."""
    gds = exported[("gds", False)][0]
    padded = tmp_path / "padded.gds"
    padded.write_bytes(gds.read_bytes() + bytes(2048 - gds.stat().st_size % 2048))
    ob = read_stream(padded, lattice_of(spec), spec.layers.posts, False, spec.post_names)
    assert not ob.anomalies and sum(ob.ref_counts.values()) == exported[("gds", False)][1].posts


def test_stream_reader_refuses_oasis_and_truncated_files(tmp_path, spec, exported, damaged):
    with pytest.raises(InputError, match="^reader = 'stream' .*klayout or gdstk for OASIS"):
        read_stream(exported[("oas", False)][0], None, spec.layers.posts)
    cut = damaged(exported[("gds", False)][0], tmp_path / "cut.gds", "truncated", keep=0.6)
    with pytest.raises(InputError, match="FILE .*ending with an ENDLIB record.*truncated or damaged"):
        read_stream(cut, None, spec.layers.posts)

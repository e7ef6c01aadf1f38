"""Verification: every export verifies with every reader that reads its format; a different design or a
tampered reference is a mismatch; the reader ``auto`` stands for."""

from __future__ import annotations

import pytest

from metafovea.layout import make_spec
from metafovea.layout.verify import STREAM_THRESHOLD_BYTES, choose_reader, verify_layout

pytest.importorskip("klayout.db")


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


def test_verify_detects_mismatch(tmp_path, spec, design, small_frame, exported, retype_reference):
    p, _ = exported[("gds", False)]
    other = make_spec(design.with_(f_um=1600.0), band_rows=16, **small_frame)
    rep = verify_layout(p, other, reader="klayout")
    assert not rep.ok and any("expected" in m for m in rep.mismatches)
    # tamper with one reference (P000 -> P001): both readers see the changed counts
    q = retype_reference(p, tmp_path / "t.gds", "P000", "P001")
    for reader in ("klayout", "stream"):
        rep = verify_layout(q, spec, reader=reader)
        assert not rep.ok
        assert any(m.startswith("P000") for m in rep.mismatches) and any(m.startswith("P001") for m in rep.mismatches)


def test_auto_reader_by_format_and_size():
    assert choose_reader("auto", "gds", STREAM_THRESHOLD_BYTES) == "klayout"
    assert choose_reader("auto", "gds", STREAM_THRESHOLD_BYTES + 1) == "stream"
    assert choose_reader("auto", "oas", (16 << 20) - 1) == "klayout"
    assert choose_reader("auto", "oas", 16 << 20) == "gdstk"
    assert choose_reader("gdstk", "gds", 1) == "gdstk"

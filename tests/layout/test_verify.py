"""Verification: every export verifies with every reader that reads its format; a different design or a
tampered reference is a mismatch; the reader ``auto`` stands for."""

from __future__ import annotations

import numpy as np
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
    assert rep.layers == [[1, 0], [2, 0], [3, 0], [4, 0], [5, 0], [6, 0], [10, 0], [11, 0]]
    # origin convention: the lens (wafer) centre at (R, R), R the wafer radius: the wafer outline touches x = 0
    # (to its arc's sampling) and the flat keeps y > 0
    assert 0 <= rep.bbox_nm[0] < 1000 and rep.bbox_nm[1] > 0
    assert 2 * spec.centre_nm - 1000 < rep.bbox_nm[2] <= 2 * spec.centre_nm


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


TAMPERS = {"swap": "of the wrong type for their site", "move": "already taken", "duplicate": "already taken",
           "delete": "hold no post", "off_lattice": "off their lattice site",
           "rotate": "rotated, mirrored or magnified", "mirror": "rotated, mirrored or magnified"}


def _tamper(src, dst, how: str, spec) -> None:
    """Rewrite an exported file with gdstk, one post changed: two neighbouring posts of different types swapped,
    one moved onto its (occupied) neighbour's site, one duplicated, one deleted, or one shifted 1 um off its
    site, or one turned by a quarter turn or mirrored in place (a rectangular post's x and y responses swapped: klayout
    calls such a reference simple, not complex). Counts per type stay the same for a swap, a move, a turn and a
    mirror: what a verifier of counts alone would miss."""
    import gdstk

    oas = str(src).endswith(".oas")
    lib = gdstk.read_oas(str(src), unit=1e-6) if oas else gdstk.read_gds(str(src), unit=1e-6)
    top = next(c for c in lib.top_level() if c.name not in spec.post_names)
    plain = []
    for r in top.references:
        offs = r.repetition.get_offsets() + np.array(r.origin) if r.repetition.size else [np.array(r.origin)]
        plain += [(r.cell, (float(o[0]), float(o[1]))) for o in offs]
    top.remove(*top.references)
    p = spec.design.period_um
    # sites share one fractional offset in units of the period: floor keeps neighbours one apart
    where = {(int(np.floor(o[0] / p + 1e-6)), int(np.floor(o[1] / p + 1e-6))): i for i, (c, o) in enumerate(plain)}
    # a post in the middle and its right-hand neighbour of another type
    keys = sorted(where)
    for key in keys[len(keys) // 2:]:
        j = where.get((key[0] + 1, key[1]))
        i = where[key]
        if j is not None and plain[i][0].name != plain[j][0].name:
            break
    else:
        raise AssertionError("no neighbouring posts of different types")
    (ci, oi), (cj, oj) = plain[i], plain[j]
    if how == "swap":
        plain[i], plain[j] = (cj, oi), (ci, oj)
    elif how == "move":
        plain[i] = (ci, oj)
    elif how == "duplicate":
        plain.append((ci, oi))
    elif how == "delete":
        del plain[i]
    elif how == "off_lattice":
        plain[i] = (ci, (oi[0] + 1.0, oi[1]))
    turned = {"rotate": {"rotation": np.pi / 2}, "mirror": {"x_reflection": True}}.get(how, {})
    for k, (c, o) in enumerate(plain):
        top.add(gdstk.Reference(c, o, **(turned if k == i else {})))
    if oas:
        lib.write_oas(str(dst))
    else:
        lib.write_gds(str(dst))


#: the formats of the tampered files and the readers that read each
TAMPER_READERS = [("gds", ("klayout", "gdstk", "stream")), ("oas", ("klayout", "gdstk"))]


@pytest.mark.parametrize("fmt,readers", TAMPER_READERS)
def test_the_untampered_rewrite_verifies(tmp_path, tamper_spec, tamper_exported, fmt, readers):
    """The control of the tampered files: rewritten by gdstk as they are, with nothing changed, they pass with
    every reader (so a failure below is the tamper's)."""
    same = tmp_path / f"same.{fmt}"
    src, res = tamper_exported[fmt]
    _tamper(src, same, "none", tamper_spec)
    for reader in readers:
        rep = verify_layout(same, tamper_spec, reader=reader)
        assert rep.ok and rep.sites["posts"] == res.posts, (reader, rep.mismatches)


@pytest.mark.parametrize("fmt,readers", TAMPER_READERS)
@pytest.mark.parametrize("how", sorted(TAMPERS))
def test_verify_checks_every_post(tmp_path, tamper_spec, tamper_exported, fmt, readers, how):
    """Post by post: a swapped, moved, duplicated, missing or off-lattice post in a real exported file (GDSII and
    OASIS) fails with every reader, naming what is wrong and where, every post of the file checked (the
    untampered rewrite passes: :func:`test_the_untampered_rewrite_verifies`)."""
    src, res = tamper_exported[fmt]
    bad = tmp_path / f"{how}.{fmt}"
    _tamper(src, bad, how, tamper_spec)
    posts = res.posts + {"duplicate": 1, "delete": -1}.get(how, 0)
    for reader in readers:
        rep = verify_layout(bad, tamper_spec, reader=reader)
        assert not rep.ok, (how, reader)
        assert any(TAMPERS[how] in m for m in rep.mismatches), (how, reader, rep.mismatches)
        assert rep.sites is not None and rep.sites["posts"] == posts, (how, reader, rep.sites)


def test_lens_with_added_phase_exports_verifies_and_a_different_phase_fails(tmp_path, small_frame):
    """A lens with a phase beyond the hyperbola (``phase_poly_rad``) is exported and verifies like any design; its
    label names the coefficients; the same file against a spec with other coefficients (the same hyperbola) fails,
    post by post (posts of the wrong type), and so does the plain hyperbola's spec."""
    from metafovea.config import LensDesign
    from metafovea.layout import export_layout
    from metafovea.layout.frame import content_hash

    lens = LensDesign("corrected", 375.0, 300.0, polarization="x", phase_poly_rad=(6.0, -4.0))
    spec = make_spec(lens, band_rows=16, **small_frame)
    p = tmp_path / "corrected.gds"
    export_layout(spec, p, "gds")
    rep = verify_layout(p, spec, reader="klayout")
    assert rep.ok, rep.mismatches
    assert "phase_poly_rad=(6,-4)rad" in spec.label_text()
    for other in (lens.with_(phase_poly_rad=(6.0, -3.0)), lens.with_(phase_poly_rad=())):
        ospec = make_spec(other, band_rows=16, **small_frame)
        assert content_hash(ospec) != content_hash(spec)
        bad = verify_layout(p, ospec, reader="klayout")
        assert not bad.ok
        assert bad.sites is not None and bad.sites.get("wrong_type", 0) > 0, bad.sites

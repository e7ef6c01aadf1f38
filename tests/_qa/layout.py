"""QA regression tests for layout, split out of tests/test_qa_*.py: merge each into its subject test file
(keep the bug sentence as its docstring), then delete this file."""

from __future__ import annotations
import textwrap
import numpy as np
import pytest
from metafovea.cli import main
from metafovea.config import LensDesign
from metafovea.errors import InputError


def _lens_toml(tmp_path, name="qa", f_mm=0.8, d_mm=0.4, levels=8, lattice="integer", pol="x"):
    p = tmp_path / f"{name}.toml"
    p.write_text(textwrap.dedent(f"""\
        name = "{name}"
        f_mm = {f_mm}
        diameter_mm = {d_mm}
        wavelength_um = 10.0
        polarization = "{pol}"
        levels = {levels}
        lattice = "{lattice}"
        """))
    return p


def _err(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    return err


@pytest.fixture()
def exported_gds(tmp_path):
    toml = _lens_toml(tmp_path)
    out = tmp_path / "lens.gds"
    assert main(["export", str(toml), "--out", str(out), "--ring-width-um", "50", "--quiet"]) == 0
    return toml, out


@pytest.mark.parametrize("fmt,patch", [("oas", "0,0,10"), ("gds", "0.05,-0.1,3"), ("oas", "-0.1,0.1,0.5")])
def test_patch_wider_than_lens_label_inside_frame(tmp_path, capsys, fmt, patch):
    """A patch wider than the lens put its label at negative coordinates: verify then failed its own export."""
    pytest.importorskip("klayout.db")
    toml = _lens_toml(tmp_path)
    out = tmp_path / f"p.{fmt}"
    common = ["--design", str(toml), f"--patch={patch}", "--ring-width-um", "50", "--quiet"]
    assert main(["export", str(toml), "--format", fmt, "--out", str(out), f"--patch={patch}",
                 "--ring-width-um", "50", "--quiet"]) == 0
    assert main(["verify", str(out), *common]) == 0, capsys.readouterr().err
    if fmt == "gds":
        assert main(["verify", str(out), *common, "--reader", "stream"]) == 0


def test_label_position_inside_frame_for_any_patch():
    from metafovea.layout import make_spec
    d = LensDesign("t", 900.0, 500.0)
    for patch in [(0, 0, 50.0), (-0.2, 0.2, 0.3), (0.2, 0.0, 0.1), (0, 0, 0.01)]:
        s = make_spec(d, patch_mm=patch, ring_width_um=30.0)
        x, y = s.label_position_nm()
        assert 0 <= x <= 2 * s.centre_nm and 0 <= y <= 2 * s.centre_nm


@pytest.mark.parametrize("value", ["inf", "nan", "0", "-3", "1e9"])
def test_ring_width_must_be_finite_and_fit_coordinates(tmp_path, capsys, value):
    """--ring-width-um inf was a JSON traceback; 1e9 silently wrapped the 32-bit coordinates."""
    toml = _lens_toml(tmp_path)
    out = tmp_path / "r.gds"
    assert main(["export", str(toml), "--out", str(out), "--ring-width-um", value, "--quiet"]) == 2
    err = _err(capsys)
    assert "--ring-width-um" in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_frame_beyond_32bit_coordinates_refused():
    from metafovea.layout import make_spec
    from metafovea.layout.tiling import MAX_COORD_NM
    d = LensDesign("t", 900.0, 500.0)
    # just inside: fine; just outside (the ring alone is legal, the frame is not): refused
    ok = make_spec(d, ring_width_um=1.0e6)
    assert 2 * ok.centre_nm <= MAX_COORD_NM
    with pytest.raises(InputError, match="32-bit"):
        make_spec(d, ring_width_um=1.08e6)


@pytest.mark.parametrize("value", ["nan", "-5", "inf", "1e9"])
def test_mesh_substrate_thickness_checked(tmp_path, capsys, value):
    """--substrate-um nan/-5 were silently ignored, inf wrote a mesh with infinite vertices."""
    pytest.importorskip("trimesh")
    toml = _lens_toml(tmp_path)
    out = tmp_path / "m.stl"
    assert main(["export", str(toml), "--format", "stl", "--patch", "0,0,0.02", "--out", str(out),
                 "--substrate-um", value, "--quiet"]) == 2
    assert "--substrate-um" in _err(capsys)
    assert not out.exists()


def test_mesh_substrate_zero_and_positive(tmp_path):
    pytest.importorskip("trimesh")
    from metafovea.layout import make_spec
    from metafovea.layout.mesh import patch_mesh
    s = make_spec(LensDesign("t", 900.0, 500.0), patch_mm=(0, 0, 0.03))
    m0 = patch_mesh(s, 0.0)
    m7 = patch_mesh(s, 7.0)
    assert len(m7.faces) == len(m0.faces) + 12
    assert np.all(np.isfinite(m7.vertices)) and m7.bounds[0, 2] == pytest.approx(-7.0)


@pytest.mark.parametrize("cut", [0.5, 0.77, -1])
@pytest.mark.parametrize("reader", ["auto", "klayout", "gdstk", "stream"])
def test_verify_truncated_file_is_a_clear_error(tmp_path, capsys, exported_gds, cut, reader):
    """A truncated GDSII file gave a RuntimeError traceback (klayout) or a mismatch list (stream)."""
    if reader in ("auto", "klayout"):
        pytest.importorskip("klayout.db")
    if reader == "gdstk":
        pytest.importorskip("gdstk")
    toml, gds = exported_gds
    data = gds.read_bytes()
    n = len(data) - 4 if cut == -1 else int(len(data) * cut)  # -1: only the ENDLIB record missing
    bad = tmp_path / "trunc.gds"
    bad.write_bytes(data[:n])
    rc = main(["verify", str(bad), "--design", str(toml), "--ring-width-um", "50", "--quiet", "--reader", reader])
    err = _err(capsys)
    assert rc == 2, err
    assert "FILE" in err and "trunc.gds" in err


def test_verify_truncated_oasis_is_a_clear_error(tmp_path, capsys):
    pytest.importorskip("klayout.db")
    toml = _lens_toml(tmp_path)
    out = tmp_path / "lens.oas"
    assert main(["export", str(toml), "--format", "oas", "--out", str(out), "--ring-width-um", "50", "--quiet"]) == 0
    data = out.read_bytes()
    bad = tmp_path / "trunc.oas"
    bad.write_bytes(data[: len(data) // 3])
    for reader in ("klayout", "gdstk"):
        if reader == "gdstk" and pytest.importorskip("gdstk") is None:
            continue
        rc = main(["verify", str(bad), "--design", str(toml), "--ring-width-um", "50", "--quiet",
                   "--reader", reader])
        err = _err(capsys)
        assert rc == 2 and "FILE" in err, err


def test_stream_reader_accepts_padding_after_endlib(tmp_path, capsys, exported_gds):
    """Tools pad GDSII files with zeros after ENDLIB; the scanner called that a corrupt record (exit 1)."""
    toml, gds = exported_gds
    padded = tmp_path / "padded.gds"
    padded.write_bytes(gds.read_bytes() + bytes(2048 - gds.stat().st_size % 2048))
    assert main(["verify", str(padded), "--design", str(toml), "--ring-width-um", "50", "--quiet",
                 "--reader", "stream"]) == 0, capsys.readouterr().err


def test_export_cli_post_set_not_npz(tmp_path, capsys):
    toml = _lens_toml(tmp_path)
    rc = main(["export", str(toml), "--post-set", str(toml), "--out", str(tmp_path / "x.oas"), "--format", "oas",
               "--quiet"])
    err = _err(capsys)
    assert rc == 2 and err.startswith("metafovea export: error: --post-set") and len(err.splitlines()) == 1


@pytest.mark.parametrize("fmt,name", [("gds", "a.oas"), ("oas", "a.gds"), ("gds", "a.OASIS"), ("stl", "a.glb")])
def test_export_suffix_must_match_format(tmp_path, capsys, fmt, name):
    """--format gds --out x.oas wrote GDSII bytes into a file named .oas."""
    toml = _lens_toml(tmp_path)
    out = tmp_path / name
    rc = main(["export", str(toml), "--format", fmt, "--out", str(out), "--patch=0,0,0.02", "--quiet"])
    err = _err(capsys)
    assert rc == 2 and "--out" in err
    assert not out.exists()


@pytest.mark.parametrize("fmt,name", [("gds", "a.GDS"), ("oas", "a.oasis"), ("gds", "a")])
def test_export_suffix_accepted(tmp_path, fmt, name):
    toml = _lens_toml(tmp_path)
    assert main(["export", str(toml), "--format", fmt, "--out", str(tmp_path / name), "--quiet"]) == 0
    written = [p for p in tmp_path.iterdir() if p.name.startswith("a")]
    assert len(written) == 1


@pytest.mark.parametrize("journal", ['[]', '{"bands_done": "2", "offset": 10}', '{"offset": 5}', '"x"',
                                     '{"bands_done": 1, "offset": 10, "counts": 3}'])
def test_export_resume_with_malformed_journal_starts_over(tmp_path, journal):
    """A valid-JSON but malformed resume journal raised AttributeError/KeyError/TypeError tracebacks."""
    from metafovea.layout import export_layout, make_spec
    from metafovea.layout.export import part_paths
    spec = make_spec(LensDesign("t", 900.0, 400.0), band_rows=8, ring_width_um=30.0)
    ref = export_layout(spec, tmp_path / "ref.gds", "gds")
    p = tmp_path / "lens.gds"
    with pytest.raises(KeyboardInterrupt):
        export_layout(spec, p, "gds", _stop_after=2)
    part, jpath = part_paths(p)
    jpath.write_text(journal)
    res = export_layout(spec, p, "gds")
    assert res.posts == ref.posts and p.read_bytes() == (tmp_path / "ref.gds").read_bytes()


@pytest.mark.parametrize("name", ["ü lens", "Ørsted-2", "lens\\u00e9"])
@pytest.mark.parametrize("fmt,reader", [("oas", "klayout"), ("gds", "stream"), ("gds", "gdstk")])
def test_non_ascii_lens_name_exports_and_verifies(tmp_path, capsys, name, fmt, reader):
    """A non-ASCII name was an OASIS UnicodeEncodeError traceback and a GDSII the stream reader mismatched."""
    if reader == "klayout":
        pytest.importorskip("klayout.db")
    if reader == "gdstk":
        pytest.importorskip("gdstk")
    toml = tmp_path / "lens.toml"
    toml.write_text(f'name = "{name}"\nf_mm = 2.0\ndiameter_mm = 0.3\npolarization = "x"\n', encoding="utf-8")
    out = tmp_path / f"x.{fmt}"
    assert main(["export", str(toml), "--format", fmt, "--out", str(out), "--quiet", "--ring-width-um", "20"]) == 0
    assert main(["verify", str(out), "--design", str(toml), "--quiet", "--ring-width-um", "20",
                 "--reader", reader]) == 0, capsys.readouterr().err


def test_gdstk_damaged_file_error_is_one_line(tmp_path, capfd, exported_gds):
    """gdstk printed its own '[GDSTK] ...' lines to the terminal before the error."""
    pytest.importorskip("gdstk")
    toml, gds = exported_gds
    bad = tmp_path / "t.gds"
    bad.write_bytes(gds.read_bytes()[:5000])
    rc = main(["verify", str(bad), "--design", str(toml), "--ring-width-um", "50", "--quiet", "--reader", "gdstk"])
    out, err = capfd.readouterr()
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert err.startswith("metafovea verify: error: FILE")

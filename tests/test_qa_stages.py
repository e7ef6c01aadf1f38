"""Regression tests from QA probing of `library`, `export`/`verify` and `psf` with unusual input.

Each test reproduces a bug found by probing the command line (a traceback, a silently wrong file or a
misleading error) and checks the fixed behaviour on cases other than the probe's numbers.
"""

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


# ----------------------------------------------------------------------------------------------
# export / verify
# ----------------------------------------------------------------------------------------------
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


@pytest.fixture()
def exported_gds(tmp_path):
    toml = _lens_toml(tmp_path)
    out = tmp_path / "lens.gds"
    assert main(["export", str(toml), "--out", str(out), "--ring-width-um", "50", "--quiet"]) == 0
    return toml, out


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


# ----------------------------------------------------------------------------------------------
# psf
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("f_um,d_um,m", [(20000.0, 2000.0, 2), (5000.0, 5000.0, 2), (8000.0, 3000.0, 3)])
def test_sensor_psf_where_another_order_focuses_is_finite(f_um, d_um, m):
    """At lambda0 / m the focusing order vanishes and order m focuses on the sensor: it was drawn as a
    1e-9 um disk, giving pixel values of ~1e19 (fractions of the incident power!)."""
    from metafovea.errors import NotConvergedWarning
    from metafovea.optics import sensor_psf
    lens = LensDesign("t", f_um, d_um)
    with pytest.warns(NotConvergedWarning):  # the disk stand-in for a focused order is flagged as rough
        P = sensor_psf(lens, pixel_pitch_um=17.0, wavelengths_um=[lens.wavelength_um / m], size_px=41)
    assert np.all(np.isfinite(P.intensity)) and P.intensity.min() >= 0
    assert 0 < P.intensity.sum() <= 1.0 + 1e-9 and P.intensity.max() <= 1.0
    assert P.error_estimate > 1e-3


@pytest.mark.parametrize("r,cx,cy", [(0.3, 0.1, -0.2), (2.0, 8.4, 8.4), (5.0, 0.0, 0.0), (40.0, 3.0, -7.0)])
def test_disk_pixels_conserve_power(r, cx, cy):
    from metafovea.optics.psf import _disk_pixels
    p, size = 17.0, 11
    x0 = y0 = -size * p / 2
    d = _disk_pixels((cx, cy), r, x0, y0, p, size)
    assert d.sum() == pytest.approx(1.0, rel=0.03)
    assert d.max() <= 1.0 + 1e-12
    # a disk half outside the window keeps only its inside share; one wholly outside leaves nothing
    if r >= 1.0:
        e = _disk_pixels((x0, cy), r, x0, y0, p, size)
        assert e.sum() == pytest.approx(0.5, rel=0.1)
    assert _disk_pixels((x0 - r - 1, cy), r, x0, y0, p, size).sum() == 0


def test_psf_at_zero_order_efficiency_names_the_wavelength():
    from metafovea.optics import psf
    lens = LensDesign("t", 20000.0, 2000.0)
    for wl in (lens.wavelength_um / 2, lens.wavelength_um / 3, lens.wavelength_um / 4):
        with pytest.raises(InputError) as e:
            psf(lens, wavelengths_um=[wl], quantize=True)
        assert e.value.parameter == "wavelengths_um"


@pytest.mark.parametrize("opts,flag", [
    (["--wavelength-um", "5"], "--wavelength-um"),
    (["--wavelength-um", "2.5"], "--wavelength-um"),
    (["--wavelengths", "100000"], "--wavelengths"),
    (["--temperature-k", "1"], "--temperature-k"),
    (["--pixel-um", "1e6"], "--pixel-um"),
    (["--filter-um", "20", "0.5"], "--filter-um"),
    (["--filter-um", "3", "0.2"], "--filter-um"),
])
def test_psf_cli_errors_name_the_option(tmp_path, capsys, opts, flag):
    toml = _lens_toml(tmp_path, f_mm=20.0, d_mm=2.0)
    rc = main(["psf", str(toml), "--field-deg", "0", "--wavelengths", "3", "--out", str(tmp_path / "o"), *opts])
    err = _err(capsys)
    assert rc == 2, err
    assert err.startswith("metafovea psf: error: " + flag) and len(err.splitlines()) == 1
    assert "RuntimeWarning" not in err


# ----------------------------------------------------------------------------------------------
# library
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("period,mf", [(4.0, 0.5), (4.0, 1.5), (3.0, 0.2), (6.0, 1.9), (2.5, 0.01)])
def test_width_grid_allowed_step_is_stated_and_exact(period, mf):
    """The error said 'grid_step_um <= 4' for p = 4 although 1.5 already failed, or 'fit posts between
    4 and 0 um'; the stated maximum is now the real one."""
    from metafovea.library import width_grid
    max_step = period / 3 if mf <= period / 3 else period - 2 * mf
    w = width_grid(period, max_step * 0.999, mf)
    assert len(w) >= 2 and w[0] >= mf and w[-1] <= period - mf + 1e-9
    with pytest.raises(InputError) as e:
        width_grid(period, max_step * 1.01, mf, name="--grid-step-um")
    assert e.value.parameter == "--grid-step-um" and f"{max_step:.6g}" in e.value.allowed


@pytest.mark.parametrize("step", ["1.5", "4", "3", "0.0001", "0", "-1"])
def test_library_cli_bad_step_names_option_and_writes_nothing(tmp_path, capsys, step):
    out = tmp_path / "lib"
    rc = main(["library", "--grid-step-um", step, "--harmonics", "5", "--cache-dir", str(tmp_path / "c"),
               "--no-progress", "--out", str(out)])
    err = _err(capsys)
    assert rc == 2 and "--grid-step-um" in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_library_cli_platform_min_feature_names_file(tmp_path, capsys):
    plat = tmp_path / "plat.toml"
    plat.write_text("period_um = 3.0\nmin_feature_um = 1.6\n")
    assert main(["library", str(plat), "--cache-dir", str(tmp_path / "c"), "--no-progress"]) == 2
    err = _err(capsys)
    assert "plat.toml" in err and "min_feature_um" in err and "1.5" in err


def test_library_cli_too_few_converged_posts_names_levels(tmp_path, capsys):
    """'library = 4 is invalid' named no option; now --levels with what to change."""
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = main(["library", "--grid-step-um", "1.3", "--harmonics", "5", "--levels", "6",
                   "--cache-dir", str(tmp_path / "c"), "--no-progress"])
    err = _err(capsys)
    assert rc == 2
    last = err.splitlines()[-1]
    assert last.startswith("metafovea library: error: --levels = ") and "--harmonics" in last


# ----------------------------------------------------------------------------------------------
# post-set files and output names
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("content", ["toml", "empty", "truncated", "other_npz"])
def test_postset_load_of_wrong_file_is_input_error(tmp_path, content):
    """--post-set design.toml was a numpy 'pickled data' ValueError traceback."""
    from metafovea.library import Library, PostSet
    good = tmp_path / "good.npz"
    PostSet.ideal(4).save(good)
    bad = tmp_path / "bad.npz"
    if content == "toml":
        bad.write_text('name = "x"\nf_mm = 1.0\n')
    elif content == "empty":
        bad.write_bytes(b"")
    elif content == "truncated":
        bad.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    else:
        np.savez(bad, widths_um=np.ones((4, 2)))
    for cls in (PostSet, Library):
        with pytest.raises(InputError) as e:
            cls.load(bad)
        assert e.value.parameter == "path"
    assert PostSet.load(good).levels == 4


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


def test_psf_two_lenses_with_one_name_refused(tmp_path, capsys):
    """Two designs with the same 'name' silently overwrote each other's report files."""
    a = _lens_toml(tmp_path, name="same", f_mm=20.0, d_mm=2.0)
    b = tmp_path / "other.toml"
    b.write_text(a.read_text().replace("f_mm = 20.0", "f_mm = 25.0"))
    out = tmp_path / "o"
    rc = main(["psf", str(a), str(b), "--field-deg", "0", "--wavelengths", "3", "--out", str(out)])
    err = _err(capsys)
    assert rc == 2 and "'same'" in err and not out.exists()


@pytest.mark.parametrize("damage", ["truncate", "garbage", "empty"])
def test_damaged_library_cache_is_recomputed(tmp_path, damage):
    """A damaged cached library (library-<key>.npz) made every later run fail instead of recomputing."""
    import warnings

    from metafovea.library import compute_library, width_grid
    kw = dict(harmonics=5, cache_dir=tmp_path, workers=1, progress=False, tol=None)
    w = width_grid(4.0, 1.0, 0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a = compute_library(w, None, [10.0], **kw)
        (f,) = tmp_path.glob("library-*.npz")
        data = f.read_bytes()
        f.write_bytes({"truncate": data[: len(data) // 2], "garbage": b"\x00junk" * 50, "empty": b""}[damage])
        b = compute_library(w, None, [10.0], **kw)
        assert not b.meta.get("from_cache")
        np.testing.assert_allclose(b.t_x, a.t_x)
        c = compute_library(w, None, [10.0], **kw)  # the cache was rewritten
    assert c.meta.get("from_cache")


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


def test_sensor_psf_capped_window_warning_says_so():
    """Pixels far below the PSF size truncate the window at max_size_px; the warning blamed 'geometric haze'."""
    from metafovea.errors import NotConvergedWarning
    from metafovea.optics import sensor_psf
    lens = LensDesign("t", 20000.0, 2000.0)
    with pytest.warns(NotConvergedWarning, match="capped at 31 pixels"):
        sensor_psf(lens, pixel_pitch_um=2.0, max_size_px=31)


@pytest.mark.parametrize("opts,flag", [(["--band-um", "8", "300"], "--band-um"), (["--band-um", "0.01", "1e4"], "--band-um"),
                                       (["--wavelength-um", "250"], "--wavelength-um")])
def test_psf_band_beyond_evanescent_limit_names_band(tmp_path, capsys, opts, flag):
    """A band reaching lambda0/NA failed deep inside with '--field-deg = 0.0 is invalid; |field| <= 0.000'."""
    toml = _lens_toml(tmp_path, f_mm=20.0, d_mm=2.0)  # NA 0.05: limit 200 um
    rc = main(["psf", str(toml), "--field-deg", "0", "--wavelengths", "3", "--out", str(tmp_path / "o"), *opts])
    err = _err(capsys)
    assert rc == 2 and err.startswith("metafovea psf: error: " + flag), err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("name", ["../../escape", "a/b", "..", "x y*?"])
def test_lens_name_cannot_escape_output_directory(tmp_path, monkeypatch, capsys, name):
    """A lens 'name' was used verbatim in file names: '../../x' wrote the export outside gds_export/
    (and the psf report outside --out), 'a/b' made subdirectories. Path-like names are now refused when
    the design is loaded; other odd characters are sanitised by the stages that build file names."""
    monkeypatch.chdir(tmp_path)
    work = tmp_path / "w"
    work.mkdir()
    toml = work / "lens.toml"
    toml.write_text(f'name = "{name}"\nf_mm = 20.0\ndiameter_mm = 0.3\npolarization = "x"\n')
    monkeypatch.chdir(work)
    if "/" in name or name == "..":
        assert main(["export", str(toml), "--format", "oas", "--quiet"]) == 2
        assert "name" in capsys.readouterr().err
        assert not (work / "gds_export").exists()
        return
    assert main(["export", str(toml), "--format", "oas", "--quiet", "--ring-width-um", "20"]) == 0
    files = [p for p in work.rglob("*") if p.is_file() and p.suffix == ".oas"]
    assert len(files) == 1 and files[0].parent == work / "gds_export", files
    out = work / "psf"
    assert main(["psf", str(toml), "--field-deg", "0", "--wavelengths", "2", "--out", str(out)]) == 0
    written = [p for p in tmp_path.rglob("*") if p.is_file() and p.suffix in (".html", ".json", ".png")]
    assert written and all(p.parent == out for p in written), written


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


def test_library_cli_convergence_warning_is_one_line(tmp_path, capfd):
    """The NotConvergedWarning was printed with Python's source line of the call ('  lib = compute_library(')."""
    rc = main(["library", "--grid-step-um", "1.3", "--harmonics", "5", "--levels", "3",
               "--cache-dir", str(tmp_path / "c"), "--no-progress"])
    out, err = capfd.readouterr()
    assert rc == 0
    lines = [x for x in err.splitlines() if x.strip()]
    assert lines and all(x.startswith("metafovea library: warning: ") for x in lines), err

"""``metafovea export``: files written and the summary printed; bad input -> exit 2 with one line that names the
option typed and no file written; a full disk leaves no file."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

from metafovea.cli import main


@pytest.fixture(scope="module")
def toml(tmp_path_factory):
    p = tmp_path_factory.mktemp("design") / "small.toml"
    p.write_text('name = "small"\nf_mm = 1.5\ndiameter_mm = 1.2\nwavelength_um = 10.0\n'
                 'polarization = "x"\nlevels = 8\nlattice = "integer"\n')
    return p


def test_export_writes_and_refuses(tmp_path, capsys, toml):
    out = tmp_path / "cli"
    args = [str(toml), "--ring-width-um", "100", "--quiet"]
    assert main(["export", *args, "--format", "oas", "--out", str(out), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["path"].endswith("cli.oas") and os.path.isfile(res["path"])
    assert res["posts"] == sum(res["counts"]) > 0 and res["bytes"] == os.path.getsize(res["path"])
    assert main(["export", *args, "--out", str(out)]) == 0
    line, posts_line, drc_line, printed, tone = capsys.readouterr().out.strip().splitlines()
    assert drc_line.startswith("  DRC OK: smallest side")
    assert printed.startswith("  printed label: SMALL F1.5 D1.2 POL-X N8 RCWA 20") and "#" in printed
    assert tone.startswith("  tone: posts negative")
    assert line.startswith(f"wrote {out}.gds: {res['posts']:,} posts, ") and line.endswith(" s")
    # by default the cells are the RCWA library's post set, named as such
    from metafovea.library import platform_post_sets

    rcwa = platform_post_sets(None, 8)[0]["x"]
    assert res["post_set"]["source"] == "rcwa" and res["post_set"]["widths_um"] == rcwa.widths_um.tolist()
    assert posts_line.startswith("  posts: rcwa post set") and "idealised" not in posts_line
    assert res["drc"]["ok"]
    assert res["drc"]["max_aspect_ratio"] == pytest.approx(10 / min(min(w) for w in rcwa.widths_um))
    # existing output: exit 2 with a one-line error
    assert main(["export", *args, "--format", "oas", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--force" in err
    assert main(["export", *args, "--format", "gds", "--patch", "9,9,0.1", "--out", str(tmp_path / "z")]) == 2
    assert main(["export", *args, "--format", "oas", "--levels", "5", "--post-set", str(tmp_path / "none.npz")]) == 2
    assert not (tmp_path / "z.gds").exists()


def test_export_max_refs(tmp_path, toml):
    assert main(["export", str(toml), "--format", "oas", "--max-refs", "8192", "--out", str(tmp_path / "b"),
                 "--quiet"]) == 2
    assert main(["export", str(toml), "--ring-width-um", "100", "--max-refs", "8192", "--out",
                 str(tmp_path / "c.gds"), "--quiet", "--json"]) == 0
    assert (tmp_path / "c.gds").is_file() and not (tmp_path / "b.oas").exists()


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


@pytest.mark.parametrize("value", ["inf", "nan", "0", "-3", "1e9"])
def test_ring_width_must_be_finite_and_fit_coordinates(tmp_path, capsys, value, lens_toml, cli_error):
    """--ring-width-um inf was a JSON traceback; 1e9 silently wrapped the 32-bit coordinates."""
    toml = lens_toml(tmp_path)
    out = tmp_path / "r.gds"
    assert main(["export", str(toml), "--out", str(out), "--ring-width-um", value, "--quiet"]) == 2
    err = cli_error(capsys)
    assert "--ring-width-um" in err and len(err.splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize("value", ["nan", "-5", "inf", "1e9"])
def test_mesh_substrate_thickness_checked(tmp_path, capsys, value, lens_toml, cli_error):
    """--substrate-um nan/-5 were silently ignored, inf wrote a mesh with infinite vertices."""
    pytest.importorskip("trimesh")
    toml = lens_toml(tmp_path)
    out = tmp_path / "m.stl"
    assert main(["export", str(toml), "--format", "stl", "--patch", "0,0,0.02", "--out", str(out),
                 "--substrate-um", value, "--quiet"]) == 2
    assert "--substrate-um" in cli_error(capsys)
    assert not out.exists()
    # a layout format has no substrate: a bad value is still an error (it was accepted in silence), a good one ignored
    # with a warning
    gds = tmp_path / "m.gds"
    assert main(["export", str(toml), "--patch", "0,0,0.02", "--out", str(gds), "--substrate-um", value,
                 "--quiet"]) == 2
    assert "--substrate-um" in cli_error(capsys) and not gds.exists()
    assert main(["export", str(toml), "--patch", "0,0,0.02", "--out", str(gds), "--substrate-um", "20", "--quiet"]) == 0
    assert "--substrate-um is the STL/GLB patch mesh's substrate: --format gds has none" in capsys.readouterr().err


def test_export_cli_post_set_not_npz(tmp_path, capsys, lens_toml, cli_error):
    """A design TOML given as --post-set is one line that names --post-set."""
    toml = lens_toml(tmp_path)
    rc = main(["export", str(toml), "--post-set", str(toml), "--out", str(tmp_path / "x.oas"), "--format", "oas",
               "--quiet"])
    err = cli_error(capsys)
    assert rc == 2 and err.startswith("metafovea export: error: --post-set") and len(err.splitlines()) == 1


@pytest.mark.parametrize("fmt,name", [("gds", "a.oas"), ("oas", "a.gds"), ("gds", "a.OASIS"), ("stl", "a.glb")])
def test_export_suffix_must_match_format(tmp_path, capsys, fmt, name, lens_toml, cli_error):
    """--format gds --out x.oas wrote GDSII bytes into a file named .oas."""
    toml = lens_toml(tmp_path)
    out = tmp_path / name
    rc = main(["export", str(toml), "--format", fmt, "--out", str(out), "--patch=0,0,0.02", "--quiet"])
    err = cli_error(capsys)
    assert rc == 2 and "--out" in err
    assert not out.exists()


@pytest.mark.parametrize("fmt,name", [("gds", "a.GDS"), ("oas", "a.oasis"), ("gds", "a")])
def test_export_suffix_accepted(tmp_path, fmt, name, lens_toml):
    toml = lens_toml(tmp_path)
    assert main(["export", str(toml), "--format", fmt, "--out", str(tmp_path / name), "--quiet"]) == 0
    written = [p for p in tmp_path.iterdir() if p.name.startswith("a")]
    assert len(written) == 1


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


def test_export_labels_an_idealised_post_set_and_refuses_posts_that_break_the_rules(tmp_path, capsys, toml):
    """`--posts ideal` is the width ramp and every output says so; a post set with a 0.2 um post (the platform's
    minimum feature is 0.5 um) is refused, naming the rule."""
    import gdstk

    from metafovea.library import PostSet

    out = tmp_path / "ideal.gds"
    assert main(["export", str(toml), "--patch", "0,0,0.1", "--posts", "ideal", "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "ideal post set" in text and "idealised ramp, not a physical design" in text
    labels = [lb.text for c in gdstk.read_gds(str(out)).cells for lb in c.labels]
    assert any("posts=ideal" in t for t in labels)
    ideal = PostSet.ideal(8, polarization="x")
    w = ideal.widths_um.copy()
    w[3] = [0.2, 2.0]
    bad = PostSet("x", 4.0, 10.0, 10.0, w, ideal.t_x, ideal.t_y, source="rcwa")
    bad.save(tmp_path / "bad.npz")
    rc = main(["export", str(toml), "--patch", "0,0,0.1", "--post-set", str(tmp_path / "bad.npz"),
               "--out", str(tmp_path / "bad.gds")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "min_feature_um" in err and "post 3" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "bad.gds").exists()


def test_a_large_write_is_announced_and_refused_without_the_space(tmp_path, capsys, toml, monkeypatch, cli_error):
    """A 7.7 GB GDSII started writing with no size notice; now the size and the free space come first (here every
    file counts as large), and a disk without the space is one line with nothing written."""
    import shutil

    import metafovea.layout.export as export

    monkeypatch.setattr(export, "SIZE_NOTICE_BYTES", 0)
    out = tmp_path / "n.gds"
    assert main(["export", str(toml), "--ring-width-um", "100", "--posts", "ideal", "--out", str(out)]) == 0
    cap = capsys.readouterr()
    notice = cap.err.strip().splitlines()[0]
    assert notice.startswith("metafovea export: writing about ") and f"to {out}; " in notice, cap.err
    assert notice.endswith("free there") and "posts" in cap.out
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage._replace(free=1000))
    rc = main(["export", str(toml), "--ring-width-um", "100", "--posts", "ideal", "--out", str(tmp_path / "m.gds"),
               "--quiet"])
    err = cli_error(capsys)
    assert rc == 2 and err.startswith("metafovea export: error: --out = ") and "enough free space" in err, err
    assert "1000 B free there" in err and len(err.splitlines()) == 1
    assert [p.name for p in tmp_path.iterdir()] == ["n.gds"]


def test_export_never_overwrites_its_design_even_with_force(tmp_path, capsys, toml):
    """`export d.gds --out d.gds --force` where d.gds is the design (a TOML under any name) replaced the design by
    the layout; now refused with one line, the design intact."""
    design = tmp_path / "d.gds"
    design.write_text(toml.read_text())
    assert main(["export", str(design), "--format", "gds", "--out", str(design), "--force"]) == 2
    err = capsys.readouterr().err
    assert "a path other than the design" in err and "Traceback" not in err
    assert design.read_text() == toml.read_text()

"""``metafovea verify``: exit 0 when the file matches the design, 1 on a mismatch (listed on stderr), 2 with one
line naming FILE for a damaged, truncated or foreign file."""

from __future__ import annotations

import pytest

from metafovea.cli import main

pytest.importorskip("klayout.db")


@pytest.fixture()
def exported_gds(tmp_path, lens_toml):
    toml = lens_toml(tmp_path)
    out = tmp_path / "lens.gds"
    assert main(["export", str(toml), "--out", str(out), "--ring-width-um", "50", "--quiet"]) == 0
    return toml, out


def test_verify_exit_status(tmp_path, capsys, exported_gds, cli_error):
    toml, gds = exported_gds
    common = ["--design", str(toml), "--quiet"]
    capsys.readouterr()
    assert main(["verify", str(gds), *common, "--ring-width-um", "50"]) == 0
    out, drc = capsys.readouterr().out.strip().splitlines()
    n = out.split()[-1]
    assert out.startswith(f"OK: {gds} (gds, read by klayout in ") and out.endswith(f"): {n} posts, expected {n}")
    assert drc.startswith("  DRC OK:")
    # mismatching design parameters (another ring width): exit 1, the label's content hash on stderr
    assert main(["verify", str(gds), *common]) == 1
    cap = capsys.readouterr()
    assert cap.out.startswith("MISMATCH: ") and "  - the label's content hash" in cap.err
    # a limit on the elements per structure
    assert main(["verify", str(gds), *common, "--ring-width-um", "50", "--max-refs", "100"]) == 1
    assert "--max-refs 100" in capsys.readouterr().err
    assert main(["verify", str(gds), *common, "--max-refs", "0"]) == 2
    assert cli_error(capsys) == "metafovea verify: error: --max-refs = 0 is invalid; allowed: an integer >= 1"
    assert main(["verify", str(gds), *common, "--workers", "0"]) == 2  # checked as every command's --workers
    assert cli_error(capsys) == ("metafovea verify: error: --workers = '0' is invalid; allowed: integer 1 <= --workers "
                                 "<= 4096")


def test_verify_hierarchical_max_refs(tmp_path, lens_toml):
    toml = lens_toml(tmp_path)
    gds = tmp_path / "h.gds"
    assert main(["export", str(toml), "--ring-width-um", "50", "--max-refs", "64", "--out", str(gds), "--quiet"]) == 0
    args = ["verify", str(gds), "--design", str(toml), "--ring-width-um", "50", "--quiet"]
    assert main([*args, "--max-refs", "64"]) == 0
    assert main([*args, "--max-refs", "32"]) == 1


@pytest.mark.parametrize("fmt,patch", [("oas", "0,0,10"), ("gds", "0.05,-0.1,3"), ("oas", "-0.1,0.1,0.5")])
def test_patch_wider_than_lens_label_inside_frame(tmp_path, capsys, fmt, patch, lens_toml):
    """A patch wider than the lens put its label at negative coordinates: verify then failed its own export."""
    toml = lens_toml(tmp_path)
    out = tmp_path / f"p.{fmt}"
    common = ["--design", str(toml), f"--patch={patch}", "--ring-width-um", "50", "--quiet"]
    assert main(["export", str(toml), "--format", fmt, "--out", str(out), f"--patch={patch}",
                 "--ring-width-um", "50", "--quiet"]) == 0
    assert main(["verify", str(out), *common]) == 0, capsys.readouterr().err
    if fmt == "gds":
        assert main(["verify", str(out), *common, "--reader", "stream"]) == 0


@pytest.mark.parametrize("cut", [0.5, 0.77, -1])
@pytest.mark.parametrize("reader", ["auto", "klayout", "gdstk", "stream"])
def test_verify_truncated_file_is_a_clear_error(tmp_path, capsys, exported_gds, damaged, cut, reader, cli_error):
    """A truncated GDSII file gave a RuntimeError traceback (klayout) or a mismatch list (stream)."""
    if reader == "gdstk":
        pytest.importorskip("gdstk")
    toml, gds = exported_gds
    keep = gds.stat().st_size - 4 if cut == -1 else cut  # -1: only the ENDLIB record missing
    bad = damaged(gds, tmp_path / "trunc.gds", "truncated", keep=keep)
    rc = main(["verify", str(bad), "--design", str(toml), "--ring-width-um", "50", "--quiet", "--reader", reader])
    err = cli_error(capsys)
    assert rc == 2, err
    assert "FILE" in err and "trunc.gds" in err


@pytest.mark.parametrize("damage", ["empty", "garbage", "text"])
def test_verify_foreign_file_is_a_clear_error(tmp_path, capsys, exported_gds, damaged, damage, cli_error):
    toml, gds = exported_gds
    bad = damaged(gds, tmp_path / "bad.gds", damage)
    assert main(["verify", str(bad), "--design", str(toml), "--ring-width-um", "50", "--quiet"]) == 2
    err = cli_error(capsys)
    assert err == f"metafovea verify: error: FILE = '{bad}' is invalid; allowed: a GDSII or OASIS file"


def test_verify_truncated_oasis_is_a_clear_error(tmp_path, capsys, damaged, lens_toml, cli_error):
    toml = lens_toml(tmp_path)
    out = tmp_path / "lens.oas"
    assert main(["export", str(toml), "--format", "oas", "--out", str(out), "--ring-width-um", "50", "--quiet"]) == 0
    bad = damaged(out, tmp_path / "trunc.oas", "truncated", keep=1 / 3)
    for reader in ("klayout", "gdstk"):
        if reader == "gdstk" and pytest.importorskip("gdstk") is None:
            continue
        rc = main(["verify", str(bad), "--design", str(toml), "--ring-width-um", "50", "--quiet",
                   "--reader", reader])
        err = cli_error(capsys)
        assert rc == 2 and "FILE" in err, err


def test_gdstk_damaged_file_error_is_one_line(tmp_path, capfd, exported_gds, damaged):
    """gdstk printed its own '[GDSTK] ...' lines to the terminal before the error."""
    pytest.importorskip("gdstk")
    toml, gds = exported_gds
    bad = damaged(gds, tmp_path / "t.gds", "truncated", keep=5000)
    rc = main(["verify", str(bad), "--design", str(toml), "--ring-width-um", "50", "--quiet", "--reader", "gdstk"])
    out, err = capfd.readouterr()
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert err.startswith("metafovea verify: error: FILE")



def test_verify_help_is_its_own(capsys):
    """``verify --help`` showed export's text for the options they share (encoder threads, tiles); the options both
    take now share one text that fits both (``metafovea.cli.options.SHARED_OPTIONS``)."""
    text = {}
    for command in ("verify", "export"):
        with pytest.raises(SystemExit) as e:
            main([command, "--help"])
        assert e.value.code == 0
        text[command] = " ".join(capsys.readouterr().out.split())
    assert "Read FILE" in text["verify"] and "Read FILE" not in text["export"]
    assert "encoder threads" not in text["verify"] and "tiles-dir" not in text["verify"]
    assert "tiles-dir" in text["export"] and "Stream a lens layout" in text["export"]

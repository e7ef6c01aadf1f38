"""`metafovea design`: outputs, bundle, and every bad input (exit 2, one line)."""

import json
import subprocess
import sys

import pytest

from metafovea.cli import main


def run(argv, capsys):
    rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


def test_design_paper_foveal(capsys):
    rc, out, _ = run(["design", "--f", "150", "--d", "75", "--json", "--samples", "20000"], capsys)
    assert rc == 0
    s = json.loads(out)
    assert s["posts_in_aperture"] == 276_116_425
    assert s["na"] == pytest.approx(0.2425, abs=1e-4)
    assert s["f_number"] == 2.0
    assert s["rim_zone_width_um"] == pytest.approx(41.2, abs=0.05)
    assert s["rim_posts_per_2pi"] == pytest.approx(10.3, abs=0.01)
    assert s["substrate_orders"] and any("substrate" in w for w in s["warnings"])


def test_design_perifoveal_table(capsys):
    rc, out, _ = run(["design", "--f", "25", "--d", "25", "--polarization", "y", "--samples", "20000"], capsys)
    assert rc == 0
    assert "0.4472" in out and "5.59 posts per 2 pi" in out and "30,679,505" in out
    assert "WARNING" in out and "substrate" in out


def test_design_system_file_and_bundle(tmp_path, capsys, designs_dir):
    out_dir = tmp_path / "bundle"
    rc, out, _ = run(["design", str(designs_dir / "system.toml"), "--out", str(out_dir), "--samples", "20000"], capsys)
    assert rc == 0
    for lens in ("foveal", "perifoveal"):
        d = out_dir / lens
        for f in ("summary.json", "design.toml", "radial_profile.csv", "phase_patch.png", "radial_profile.png",
                  "posts_per_2pi.png"):
            assert (d / f).stat().st_size > 0
        # the written design TOML loads back to the same lens
        from metafovea.config import load_lens
        back = load_lens(d / "design.toml")
        assert back.f_um == json.loads((d / "summary.json").read_text())["f_mm"] * 1000
    # refuses to overwrite, then --force works
    rc, _, err = run(["design", str(designs_dir / "system.toml"), "--out", str(out_dir), "--samples", "20000"], capsys)
    assert rc == 2 and "--force" in err
    rc, _, _ = run(["design", str(designs_dir / "system.toml"), "--out", str(out_dir), "--force", "--samples",
                    "20000"], capsys)
    assert rc == 0


def test_design_file_with_override(capsys, designs_dir):
    rc, out, _ = run(["design", str(designs_dir / "foveal.toml"), "--levels", "16", "--json", "--samples",
                      "20000"], capsys)
    s = json.loads(out)
    assert rc == 0 and s["levels"] == 16 and s["scalar_efficiency"] > 0.98


@pytest.mark.parametrize("argv,param", [
    (["--f", "0", "--d", "75"], "--f"),
    (["--f", "-150", "--d", "75"], "--f"),
    (["--f", "abc", "--d", "75"], "--f"),
    (["--f", "nan", "--d", "75"], "--f"),
    (["--f", "inf", "--d", "75"], "--f"),
    (["--f", "150", "--d", "0"], "--d"),
    (["--f", "150", "--d", "-1"], "--d"),
    (["--f", "150", "--d", "x1"], "--d"),
    (["--f", "150", "--d", "75", "--wavelength-um", "0"], "--wavelength-um"),
    (["--f", "150", "--d", "75", "--wavelength-um", "-10"], "--wavelength-um"),
    (["--f", "150", "--d", "75", "--wavelength-um", "nan"], "--wavelength-um"),
    (["--f", "150", "--d", "75", "--period-um", "0"], "--period-um"),
    (["--f", "150", "--d", "75", "--period-um", "inf"], "--period-um"),
    (["--f", "150", "--d", "75", "--levels", "1"], "--levels"),
    (["--f", "150", "--d", "75", "--levels", "2.5"], "--levels"),
    (["--f", "150", "--d", "75", "--polarization", "z"], "--polarization"),
    (["--f", "1e-12", "--d", "75"], "NA"),
    (["--f", "150"], "--d"),
    (["/nonexistent/lens.toml"], "design file"),
])
def test_design_bad_input(argv, param, capsys):
    rc, out, err = run(["design", *argv], capsys)
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert param in lines[0] and "allowed" in lines[0]
    assert "Traceback" not in err


def test_design_malformed_toml(tmp_path, capsys):
    p = tmp_path / "x.toml"
    p.write_text("f_mm = [\n")
    rc, _, err = run(["design", str(p)], capsys)
    assert rc == 2 and "valid TOML" in err and len(err.strip().splitlines()) == 1


def test_console_script_runs_as_module():
    # the installed entry point and `python -m metafovea` work in a subprocess with a clean exit code
    r = subprocess.run([sys.executable, "-m", "metafovea", "design", "--f", "25", "--d", "25", "--samples", "5000"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "30,679,505" in r.stdout
    r = subprocess.run([sys.executable, "-m", "metafovea", "design", "--f", "-1", "--d", "25"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr


def test_unknown_option_is_one_line(capsys):
    with pytest.raises(SystemExit) as ei:
        main(["design", "--bogus"])
    assert ei.value.code == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_design_lists_post_set(tmp_path, capsys):
    from metafovea.library import PostSet
    ps = PostSet.ideal(8, polarization="y")
    f = tmp_path / "ps.npz"
    ps.save(f)
    rc, out, _ = run(["design", "--f", "25", "--d", "25", "--polarization", "y", "--post-set", str(f), "--json",
                      "--samples", "5000"], capsys)
    s = json.loads(out)
    assert rc == 0 and len(s["posts"]) == 8 and s["post_set"]["source"] == "ideal"
    assert s["posts"][3]["wy_um"] == pytest.approx(ps.widths_um[3, 1])
    # a post set for the other polarisation is refused with a clear message
    rc, _, err = run(["design", "--f", "25", "--d", "25", "--polarization", "x", "--post-set", str(f)], capsys)
    assert rc == 2 and "--post-set" in err


def test_system_file_refuses_per_lens_flags(capsys, designs_dir):
    rc, _, err = run(["design", str(designs_dir / "system.toml"), "--f", "100"], capsys)
    assert rc == 2 and "--f" in err and "system file" in err
    # platform-wide flags are fine with a system file
    rc, out, _ = run(["design", str(designs_dir / "system.toml"), "--levels", "4", "--json", "--samples", "5000"],
                     capsys)
    assert rc == 0 and [s["levels"] for s in json.loads(out)] == [4, 4]


def test_post_set_and_library_are_exclusive(tmp_path, capsys):
    from metafovea.library import PostSet
    f = PostSet.ideal(8).save(tmp_path / "ps.npz")
    rc, _, err = run(["design", "--f", "25", "--d", "25", "--post-set", str(f), "--library"], capsys)
    assert rc == 2 and "--library" in err and "--post-set" in err and len(err.strip().splitlines()) == 1


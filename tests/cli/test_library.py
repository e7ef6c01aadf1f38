"""`metafovea library`: the files it writes, its JSON, and bad input (exit 2, one line naming the flag)."""

from __future__ import annotations

import json
import warnings

import pytest

from metafovea.cli import main
from metafovea.io import load_npz
from metafovea.library import PostSet


def _err(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    return err


def test_library_writes_figures_and_json(tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["library", "--grid-step-um", "1.0", "--harmonics", "5", "--cache-dir", str(tmp_path / "c"),
            "--out", str(out), "--no-progress", "--workers", "1"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(argv + ["--levels", "2", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert set(data["post_sets"]) == {"x", "y"}
    assert data["post_sets"]["x"]["lens"] == "foveal" and len(data["post_sets"]["y"]["levels"]) == 2
    files = ("library.npz", "postset_x.npz", "postset_y.npz", "fig7b_phase_maps.png", "fig7c_selected_posts.png",
             "library.json")
    for f in files:
        assert (out / f).is_file()
    assert data["files"] == sorted(files)
    assert json.loads((out / "library.json").read_text())["post_sets"] == data["post_sets"]
    assert PostSet.load(out / "postset_y.npz").polarization == "y"
    arrays, meta = load_npz(out / "library.npz")
    assert meta["harmonics"] == 5 and arrays["t_x"].shape == (1, 3, 3)
    # existing output is not overwritten without --force
    assert main(argv) == 2
    assert "--force" in _err(capsys)
    # the table names both lenses and the cache
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(argv + ["--levels", "2", "--force"]) == 0
    text = capsys.readouterr().out
    assert "(cache)" in text and "foveal lens (focuses x" in text and "perifoveal lens (focuses y" in text


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
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = main(["library", "--grid-step-um", "1.3", "--harmonics", "5", "--levels", "6",
                   "--cache-dir", str(tmp_path / "c"), "--no-progress"])
    err = _err(capsys)
    assert rc == 2
    last = err.splitlines()[-1]
    assert last.startswith("metafovea library: error: --levels = ") and "--harmonics" in last


def test_library_cli_convergence_warning_is_one_line(tmp_path, capfd):
    """The NotConvergedWarning was printed with Python's source line of the call ('  lib = compute_library(')."""
    rc = main(["library", "--grid-step-um", "1.3", "--harmonics", "5", "--levels", "3",
               "--cache-dir", str(tmp_path / "c"), "--no-progress"])
    out, err = capfd.readouterr()
    assert rc == 0
    lines = [x for x in err.splitlines() if x.strip()]
    assert lines and all(x.startswith("metafovea library: warning: ") for x in lines), err


def test_library_cli_bias_weight_selects_jointly(tmp_path, capsys):
    """--bias-weight reaches the selection: the posts are chosen jointly for -bias, nominal and +bias (a 0.25 um
    bias per side moves the widths by one step of the 0.5 um grid), the JSON and the table say so; a negative
    weight is one line naming the option."""
    plat = tmp_path / "plat.toml"
    plat.write_text("edge_bias_um = 0.25\n")
    argv = ["library", str(plat), "--grid-step-um", "0.5", "--harmonics", "5", "--levels", "2",
            "--cache-dir", str(tmp_path / "c"), "--no-progress", "--workers", "1"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(argv + ["--bias-weight", "1", "--json"]) == 0
        data = json.loads(capsys.readouterr().out)
        for pol in ("x", "y"):
            p = data["post_sets"][pol]
            assert p["bias_weight"] == 1.0 and p["selection"].startswith("joint search")
            tol = p["selection_tolerance"]
            # the 24 edge posts' biased widths leave the grid (and a few need a post that did not converge)
            assert tol["posts_excluded"] >= 24 and tol["joint_cost"] <= tol["nominal_choice_joint_cost"] + 1e-12
            assert set(tol["cases"]) == {"-", "0", "+"} and p["edge_bias"]["delta_um"] == 0.25
        assert main(argv + ["--bias-weight", "1"]) == 0
        assert "posts chosen jointly over the three cases (bias_weight 1" in capsys.readouterr().out
        assert main(argv) == 0
        assert "posts chosen for the nominal case (bias_weight 0)" in capsys.readouterr().out
    assert main(argv + ["--bias-weight", "-1"]) == 2
    err = _err(capsys)
    assert "--bias-weight" in err and len(err.splitlines()) == 1


def test_a_library_sweep_off_a_terminal_logs_progress_lines(tmp_path, capsys, monkeypatch):
    """The library sweep (also what a first `metafovea design` runs) drew its bar on terminals only: off a terminal
    it was silent for the minutes it takes. It now writes a line every PROGRESS_LINE_S (0 here): done, total, ETA."""
    import metafovea.parallel

    monkeypatch.setattr(metafovea.parallel, "PROGRESS_LINE_S", 0.0, raising=False)
    argv = ["library", "--grid-step-um", "1.0", "--harmonics", "5", "--workers", "1", "--no-cache", "--levels", "2"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main([*argv, "--cache-dir", str(tmp_path / "c")]) == 0
        err = capsys.readouterr().err
        assert "metafovea: RCWA library: 1/3 task (33 %)" in err
        assert "metafovea: RCWA library: 3/3 task (100 %) in" in err
        assert main([*argv, "--cache-dir", str(tmp_path / "d"), "-q"]) == 0
    assert "metafovea: RCWA library" not in capsys.readouterr().err


def test_library_tolerance_rad_chooses_the_harmonics_and_says_why(tmp_path, capsys):
    """--tolerance-rad: the harmonics chosen from probe posts, printed with the reason and written to library.json
    and the library file's meta; with --harmonics it is refused (one line naming the flag)."""
    out = tmp_path / "out"
    argv = ["library", "--grid-step-um", "1.0", "--levels", "2", "--cache-dir", str(tmp_path / "c"), "--no-progress",
            "--workers", "1", "--tolerance-rad", "0.2"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(argv + ["--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "harmonics chosen for a phase error of 0.2 rad: harmonics 8:" in text and "<= 0.2 on 9 probe posts" in text
    choice = json.loads((out / "library.json").read_text())["harmonics_choice"]
    assert choice["chose"] == {"harmonics": 8} and choice["estimate_rad"] <= 0.2
    _, meta = load_npz(out / "library.npz")
    assert meta["harmonics"] == 8 and meta["harmonics_choice"]["why"] == choice["why"]
    assert main(argv + ["--harmonics", "8"]) == 2
    err = _err(capsys)
    assert err.startswith("metafovea library: error: --harmonics") and "--tolerance-rad" in err


@pytest.mark.parametrize("argv,words", [
    (["--bias-weight", "1e308"], "0 <= --bias-weight <= 1e+06"),  # overflowed into the nominal selection, "joint"
    (["--wavelengths-um", "9", "9", "9"], "distinct wavelengths"),  # solved the library three times
])
def test_values_that_ran_wrong_or_thrice_are_refused(argv, words, capsys):
    assert main(["library", *argv]) == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err


def test_an_empty_platform_file_is_not_the_papers_platform(tmp_path, capsys):
    (tmp_path / "p.toml").write_text("")
    assert main(["library", str(tmp_path / "p.toml")]) == 2
    assert "this one is empty" in capsys.readouterr().err


def test_a_write_stopped_by_ctrl_c_is_completed_and_other_files_are_not_taken(tmp_path, capsys):
    """Ctrl-C during the final writes left the library and post sets without figures or library.json, and the rerun
    was refused without --force; such a folder is now recognised (LibraryReport.stopped_write), a folder with any
    other file, or with library.json (a finished run), is not."""
    from metafovea.library.report import LibraryReport

    d = tmp_path / "lib"
    d.mkdir()
    (d / "library.npz").write_bytes(b"x")
    (d / "postset_x.npz").write_bytes(b"x")
    assert LibraryReport.stopped_write(d)
    (d / "library.json").write_text("{}")
    assert not LibraryReport.stopped_write(d)
    (d / "library.json").unlink()
    (d / "notes.txt").write_text("mine")
    assert not LibraryReport.stopped_write(d) and not LibraryReport.stopped_write(tmp_path / "none")
    assert main(["library", "--out", str(d)]) == 2  # someone else's file: refused before any work
    assert "pass --force" in capsys.readouterr().err

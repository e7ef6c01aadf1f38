"""QA regression tests for library, split out of tests/test_qa_*.py: merge each into its subject test file
(keep the bug sentence as its docstring), then delete this file."""

from __future__ import annotations
import numpy as np
import pytest
from metafovea.cli import main
from metafovea.errors import InputError


def _err(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    return err


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


def test_library_cli_convergence_warning_is_one_line(tmp_path, capfd):
    """The NotConvergedWarning was printed with Python's source line of the call ('  lib = compute_library(')."""
    rc = main(["library", "--grid-step-um", "1.3", "--harmonics", "5", "--levels", "3",
               "--cache-dir", str(tmp_path / "c"), "--no-progress"])
    out, err = capfd.readouterr()
    assert rc == 0
    lines = [x for x in err.splitlines() if x.strip()]
    assert lines and all(x.startswith("metafovea library: warning: ") for x in lines), err

"""One vocabulary across commands (issue 14): ``-q/--quiet`` and ``-v/--verbose`` everywhere, old spellings as
hidden aliases, warnings once on one line, limits checked before any work, and every bad input answered by one
line on stderr that names the flag or the file typed (exit 2, no traceback, nothing written, inputs untouched)."""

import io
import json

import numpy as np
import pytest

from metafovea.cli import build_parser, main
from metafovea.cli.options import iter_subparsers, warning_printer
from tests.conftest import DAMAGES


def _snapshot(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def test_every_command_has_quiet_and_verbose():
    for name, p in iter_subparsers(build_parser()):
        opts = {s for a in p._actions for s in a.option_strings}  # argparse keeps its options here
        assert {"-q", "--quiet", "-v", "--verbose"} <= opts, name


@pytest.mark.parametrize("argv,dest,value", [
    (["psf", "a.toml", "--jobs", "2"], "workers", 2),
    (["psf", "a.toml", "--wavelengths", "3"], "wavelength_bins", 3),
    (["library", "--no-progress"], "quiet", True),
    (["simulate", "--pitch", "17"], "pixel_um", "17"),
    (["simulate", "--no-filter"], "filter", "off"),
    (["simulate", "--filter"], "filter", "on"),
    (["export", "a.toml", "--quiet"], "quiet", True),
])
def test_old_spellings_still_work(argv, dest, value):
    """Renamed options keep their old spelling as a hidden alias (old scripts keep running)."""
    assert getattr(build_parser().parse_args(argv), dest) == value


def test_verbose_counts_before_and_after_the_command():
    args = build_parser().parse_args(["-v", "design", "-v"])
    assert args.global_verbose == 1 and args.verbose == 1


def test_each_warning_once_on_one_line():
    stream = io.StringIO()
    show = warning_printer("design", stream)
    for _ in range(3):
        show("posts\nundersampled", UserWarning, "x.py", 1)
    show("another", UserWarning, "x.py", 2)
    assert stream.getvalue().splitlines() == ["metafovea design: warning: posts undersampled",
                                              "metafovea design: warning: another"]


def test_extreme_design_warns_about_the_physics(tmp_path, capsys, monkeypatch):
    """--f 0.001 --d 75 printed F/1.33e-05 and 'Airy first zero 0.00 um' without comment."""
    monkeypatch.chdir(tmp_path)
    assert main(["design", "--f", "0.001", "--d", "75", "--posts", "ideal"]) == 0
    cap = capsys.readouterr()
    lines = [x.strip() for x in cap.out.splitlines() if x.strip().startswith("WARNING: ")]  # in the table, once each
    assert len(lines) == len(set(lines)) and "Traceback" not in cap.err
    assert any("f/D" in x and "0.5" in x for x in lines) and any("near field" in x for x in lines)
    assert "Airy first zero             0.00 um" not in cap.out and list(tmp_path.iterdir()) == []


def _neg_scene(folder):
    path = folder / "cold.npy"
    np.save(path, -np.ones((16, 16)))
    return path


#: (argv after the command, the flag or file the one error line must name, text it must not contain)
BAD = [
    (["design", "--f", "150", "--d", "1e9", "--posts", "ideal"], "--d = 1000000000.0", "diameter_um"),
    (["design", "--f", "150", "--d", "1e5", "--posts", "ideal"], "--d = 100000.0", "diameter_um"),
    (["design", "--f", "150", "--d", "75", "--period-um", "0.001", "--posts", "ideal"], "--period-um", "period_um"),
    (["library", "--harmonics", "40", "--workers", "1", "--cache-dir", "{tmp}/c"], "--harmonics", None),
    (["simulate", "--netd", "-1", "--out", "{tmp}/m.npz"], "--netd", "netd_k"),
    (["simulate", "--pixel-um", "-1", "--out", "{tmp}/m.npz"], "--pixel-um", "pixel_pitch_um"),
    (["simulate", "--pitch", "-1", "--out", "{tmp}/m.npz"], "--pitch", "pixel_pitch_um"),
    (["simulate", "--psf", "gaussian:-1", "--out", "{tmp}/m.npz"], "--psf", "sigma_um"),
    (["simulate", "--psf-size", "4", "--out", "{tmp}/m.npz"], "--psf-size", "psf_size_px"),
    (["simulate", "--scene", "no-such-scene", "--out", "{tmp}/m.npz"], "--scene", "error: scene"),
    (["simulate", "--scene", "{scene}", "--psf", "airy", "--out", "{tmp}/m.npz"], "--scene {scene}", None),
    (["simulate", "--out", "{tmp}/m.tif"], "--out", None),
    (["export", "{lens}", "--band-rows", "0", "--posts", "ideal", "--out", "{tmp}/l.gds"], "--band-rows", "band_rows"),
    (["export", "{lens}", "--posts", "ideal", "--out", "{tmp}/adir.npz"], "--out", None),
    (["export", "{lens}", "--posts", "ideal", "--format", "oas", "--out", "{tmp}/l.gds"], "--out", None),
    (["psf", "{lens}", "--temperature-k", "-1", "--out", "{tmp}/p"], "--temperature-k", "temperature_k"),
    (["psf", "{lens}", "--wavelengths", "100000", "--out", "{tmp}/p"], "--wavelengths", "n_wavelengths"),
    (["psf", "{lens}", "--wavelength-bins", "0", "--out", "{tmp}/p"], "--wavelength-bins", "n_wavelengths"),
    (["psf", "{lens}", "--field-deg", *map(str, range(100)), "--out", "{tmp}/p"], "--field-deg", None),
    (["psf", "{lens}", "--filter", "on", "--band-um", "8", "12", "--out", "{tmp}/p"], "--filter", None),
]


@pytest.mark.parametrize("argv,names,never", BAD, ids=[" ".join(b[0][:3]) + " " + b[1] for b in BAD])
def test_bad_input_one_line_naming_the_flag(argv, names, never, tmp_path, capsys, lens_toml, cli_error, monkeypatch):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    lens, scene = lens_toml(tmp_path, f_mm=4.0, d_mm=0.4), _neg_scene(tmp_path)
    fill = {"tmp": str(work), "lens": str(lens), "scene": str(scene)}
    argv = [a.format(**fill) for a in argv]
    before = _snapshot(tmp_path)
    rc = main(argv)
    err = cli_error(capsys)
    assert rc == 2, err
    assert len(err.splitlines()) == 1 and err.startswith(f"metafovea {argv[0]}: error: "), err
    assert names.format(**fill) in err, err
    assert never is None or never not in err, err
    assert list(work.iterdir()) == [], "nothing written"
    assert _snapshot(tmp_path) == before, "inputs untouched"


def test_design_limit_says_why(capsys, cli_error):
    assert main(["design", "--f", "150", "--d", "1e9", "--posts", "ideal"]) == 2
    err = cli_error(capsys)
    assert "lattice rows" in err and "posts" in err and "TiB" in err and "at most" in err


@pytest.mark.parametrize("damage", DAMAGES)
def test_damaged_design_file_is_named(damage, tmp_path, capsys, lens_toml, damaged, cli_error):
    bad = damaged(lens_toml(tmp_path), tmp_path / "bad.toml", damage)
    data = bad.read_bytes()
    for argv in (["design", str(bad), "--posts", "ideal"], ["export", str(bad), "--out", str(tmp_path / "l.gds")]):
        assert main(argv) == 2
        err = cli_error(capsys)
        assert len(err.splitlines()) == 1 and str(bad) in err, err
    assert bad.read_bytes() == data and not (tmp_path / "l.gds").exists()


def test_export_adds_a_missing_suffix_and_says_so(tmp_path, capsys, lens_toml):
    """--out X became X.gds silently; now it is said (and a wrong suffix is an error, above)."""
    lens = lens_toml(tmp_path, f_mm=4.0, d_mm=0.2)
    assert main(["export", str(lens), "--posts", "ideal", "--out", str(tmp_path / "X"), "-q", "--json"]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["path"] == str(tmp_path / "X.gds") and (tmp_path / "X.gds").is_file()
    assert cap.err.startswith("metafovea export: warning: --out") and "X.gds" in cap.err
    # the format follows the --out suffix when --format is not given
    assert main(["export", str(lens), "--posts", "ideal", "--out", str(tmp_path / "Y.oas"), "-q", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["format"] == "oas"


def test_stage_messages_in_the_words_of_the_flags():
    """A stage's message names parameters (``fmt='gds'``, ``max_refs=...``, ``force=True``); the CLI writes the flags
    a user types instead. A bare name stays: it may be a file's key or an English word."""
    from metafovea.cli import as_flag_error, flag_map
    from metafovea.cli.options import in_flags
    from metafovea.errors import InputError

    flags = flag_map("export")
    assert in_flags("only with fmt='gds' and without max_refs=...", flags) == \
        "only with --format gds and without --max-refs"
    assert in_flags("(or pass force=True to overwrite); more than max_refs=100", flags) == \
        "(or pass --force to overwrite); more than --max-refs 100"
    bare = "a flat file; the system file's [sensor] max_refs; fmt; path=x"  # 'path' is --out only as a parameter
    assert in_flags(bare, flags) == bare.replace("path=x", "--out x")
    err = as_flag_error("export", InputError("tiles_dir", "t", "only with scheduler=... (local exports: one file)"))
    assert str(err) == "--tiles-dir = 't' is invalid; allowed: only with --scheduler (local exports: one file)"
    assert str(as_flag_error("import", InputError("frame_rate_hz", None, "a rate (or name them with times=...)"))) == \
        "--frame-rate = None is invalid; allowed: a rate (or name them with --times)"

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
    (["psf", "a.toml", "--jobs", "2"], "workers", "2"),  # checked by workers_arg, as --workers
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
    (["design", "--f", "150", "--d", "1e9", "--posts", "ideal"], "--d = 1e+09", "diameter_um"),
    (["design", "--f", "150", "--d", "1e5", "--posts", "ideal"], "--d = 100000", "diameter_um"),
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


def test_default_out_dir_is_new_each_time(tmp_path):
    """One rule for the folders commands write without --out: out/<command>[-label]-<time>/, never an existing one
    (validate and study did this each on their own; psf wrote psf_report/ and failed on the second run)."""
    from datetime import datetime

    from metafovea.cli.output import default_out_dir

    now = datetime(2026, 12, 3, 9, 5, 7)
    first = default_out_dir("psf", root=tmp_path, now=now)
    assert first == tmp_path / "psf-20261203-090507" and not first.exists()
    first.mkdir()
    assert default_out_dir("psf", root=tmp_path, now=now).name == "psf-20261203-090507-2"
    assert default_out_dir("study", "gallery", root=tmp_path, now=now).name == "study-gallery-20261203-090507"


def test_an_existing_default_file_is_not_blamed_on_an_untyped_out(tmp_path, monkeypatch, capsys):
    """A second `metafovea simulate` said "--out = 'meas.npz' is invalid" though no --out was typed; the error now
    names the default output and what to type instead."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "meas.npz").write_bytes(b"an earlier run")
    assert main(["simulate", "--frames", "1", "--psf", "airy", "--no-tiff", "--no-preview"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("metafovea simulate: error: default output = 'meas.npz' is invalid") and "--out =" not in err
    assert "--out PATH writes elsewhere" in err and "--force" in err and len(err.splitlines()) == 1
    assert main(["simulate", "--frames", "1", "--psf", "airy", "--no-tiff", "--no-preview", "--out", "meas.npz"]) == 2
    assert capsys.readouterr().err.startswith("metafovea simulate: error: --out = 'meas.npz'")  # typed: named


def test_results_less_accurate_than_asked_are_one_line_naming_the_commands_options():
    """Eight NotConvergedWarnings each advised 'raise error or reduce wavelengths' (psf and simulate have neither
    option); the printer holds them and prints one line whose advice maps the parameters to the command's flags."""
    from metafovea.errors import NotConvergedWarning

    def item(fd, est):
        return {"subject": "sensor PSF of 'foveal'", "field_deg": fd, "estimate": est, "requested": 1e-4,
                "reason": "the window is capped at 255 pixels, narrower than the PSF",
                "advice": {"band_um": "a narrower band", "max_size_px": "a larger window", "error": "accept it"}}

    stream = io.StringIO()
    show = warning_printer("psf", stream, flags={"band_um": "--band-um", "error": "--error"})
    for k in range(8):
        w = NotConvergedWarning("raise error, reduce wavelengths", item(0.32445394261570504 * (k + 1), 0.01 * (k + 1)))
        show(w, NotConvergedWarning, "x.py", 1)
    assert stream.getvalue() == ""
    show.flush()
    (line,) = stream.getvalue().splitlines()
    assert line == ("metafovea psf: warning: 8 results less accurate than the requested error 0.0001: sensor PSF of "
                    "'foveal' at 8 fields (0.324-2.6 deg): estimated error 0.01 to 0.08 of the peak (the window is "
                    "capped at 255 pixels, narrower than the PSF); what changes it: --band-um (a narrower band), "
                    "--error 0.08 accepts them")
    other = io.StringIO()
    show = warning_printer("simulate", other, flags={})
    show(NotConvergedWarning("m", item(0.0, 0.01)), NotConvergedWarning, "x.py", 1)
    show.flush()
    assert "no option of 'simulate' changes it" in other.getvalue() and "--" not in other.getvalue()


#: options a command spells its own way, with the reason (none: every shared option has one default and one help)
SHARED_PENDING: dict[tuple[str, str], str] = {
    ("study", "--workers"): "with --fast the default is 1 (the cases in this process, as StudyOptions' default): at "
                            "the fast sizes worker processes cost more than the cases (each compiles the solvers)",
}


def test_an_option_several_commands_take_has_one_default_and_one_help_text():
    """--workers had four defaults (all cores, 1, 2 threads, min(2, lenses, CPUs)); --seed, --force, --json,
    --frames, --scene, --pixel-um, --relay and --posts each had a different help text (and --seed different limits)
    per command. Each is now defined once (options.SHARED_OPTIONS)."""
    from metafovea.cli.options import SHARED_OPTIONS

    seen: dict[str, list[str]] = {}
    for name, p in iter_subparsers(build_parser()):
        for a in p._actions:  # argparse keeps its options here
            for flag in set(a.option_strings) & set(SHARED_OPTIONS):
                seen.setdefault(flag, []).append(name)
                if (name, flag) in SHARED_PENDING:
                    continue
                want = SHARED_OPTIONS[flag]
                assert a.help == want["help"], (name, flag, a.help)
                assert a.default == want.get("default", False if want.get("action") == "store_true" else None), \
                    (name, flag, a.default)
                assert a.choices == want.get("choices"), (name, flag)
    assert all(len(v) >= 2 for v in seen.values()), seen  # shared: by two commands at least
    assert len(seen["--workers"]) >= 2 and len(seen["--seed"]) == 4


def test_seed_and_workers_are_checked_alike_everywhere(tmp_path, capsys):
    """--seed took 0..2^63-1 in simulate and validate, 0..2^32-1 in study and any integer >= 0 in reconstruct (as an
    argparse type there); --workers 1..1024 in library, 0..4096 in study. One check each now, one message."""
    allowed = set()
    for argv in (["simulate", "--out", str(tmp_path / "a.npz")], ["study", "frames", "--out", str(tmp_path / "s")],
                 ["validate", "--out", str(tmp_path / "v")], ["reconstruct", str(tmp_path / "m.npz")]):
        if argv[0] == "reconstruct":
            from metafovea.io import atomic_save_npz

            atomic_save_npz(tmp_path / "m.npz", meta={}, frames=np.zeros((4, 8, 8), np.float32),
                            times_s=np.arange(4.0), alpha=np.linspace(0.1, 0.9, 4))
        assert main([*argv, "--seed", "-1"]) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--seed = '-1' is invalid" in err, err
        allowed.add(err.split("allowed: ", 1)[1])
    assert len(allowed) == 1, allowed
    for argv in (["library"], ["study", "frames", "--out", str(tmp_path / "t")]):
        assert main([*argv, "--workers", "5000"]) == 2, argv
        err = capsys.readouterr().err
        allowed.add(err.split("allowed: ", 1)[1])
    assert len(allowed) == 2, allowed


def test_progress_is_shown_off_a_terminal_unless_quiet_or_json():
    """Progress went to terminals only, so a long command in a log or a pipe printed nothing for minutes."""
    from metafovea.cli.options import show_progress

    p = build_parser()
    assert show_progress(p.parse_args(["simulate"]))  # capsys: stderr is not a terminal here
    assert not show_progress(p.parse_args(["simulate", "-q"])) and not show_progress(p.parse_args(["simulate",
                                                                                                    "--json"]))


def test_stage_messages_in_the_words_of_the_flags():
    """A stage's message names parameters (``fmt='gds'``, ``max_refs=...``, ``force=True``); the CLI writes the flags
    a user types instead. A bare name stays: it may be a file's key or an English word."""
    from metafovea.cli.flags import as_flag_error, flag_map, in_flags
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
        "--frame-rate is missing; allowed: a rate (or name them with --times)"

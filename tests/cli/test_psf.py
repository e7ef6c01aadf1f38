"""``metafovea psf``: files written and the summary printed (key figures per lens and field, the whole run's
time, progress lines), bad input -> exit 2 with one line that names the option typed, two lenses in two processes
give the numbers of one, a system file reports both lenses, default output folders that do not collide, one
summary warning for the results less accurate than asked."""

import contextlib
import io
import json
import re
import shutil
from pathlib import Path

import pytest

from metafovea.cli import main
from metafovea.config import load_lens
from metafovea.optics import max_field_deg

#: a progress line on stderr (``metafovea psf: [  12.3 s] stage``): not part of an error's one line
STAGE = re.compile(r"^metafovea psf: \[ *[\d.]+ s\] ")


def error_lines(err):
    return [x for x in err.splitlines() if x.strip() and not STAGE.match(x)]


@pytest.fixture(scope="module")
def tiny_toml(tmp_path_factory, lens_toml):
    return lens_toml(tmp_path_factory.mktemp("toml"), name="tiny", f_mm=4.0, d_mm=2.0)


def _psf_to_files(d: Path, args: list[str]) -> None:
    """``metafovea psf ARGS``: its status, stdout and stderr into ``d`` (rc.txt, stdout.txt, stderr.txt)."""
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        rc = main(["psf", *args])
    for name, text in (("rc", str(rc)), ("stdout", stdout.getvalue()), ("stderr", stderr.getvalue())):
        (d / f"{name}.txt").write_text(text)


def _read(d: Path) -> tuple[int, str, str]:
    return int((d / "rc.txt").read_text()), (d / "stdout.txt").read_text(), (d / "stderr.txt").read_text()


@pytest.fixture(scope="module")
def tiny(made_once, lens_toml):
    """The text summary of one report (one run for all the test workers): (lens file, folder, stdout, stderr, the
    report's JSON)."""
    def make(d):
        toml = lens_toml(d, name="tiny", f_mm=4.0, d_mm=2.0)
        _psf_to_files(d, [str(toml), "--field-deg", "0", "3", "--wavelengths", "9", "--out", str(d / "report")])

    d = made_once("psf-tiny", make)
    rc, stdout, stderr = _read(d)
    assert rc == 0, stderr
    out = d / "report"
    return d / "tiny.toml", out, stdout, stderr, json.loads((out / "tiny_psf_report.json").read_text())


@pytest.fixture(scope="module")
def system_pair(made_once, lens_toml):
    """Both lenses of a system file, each in its own process (``--workers 2``): a foveal lens as ``tiny`` (4 mm,
    2 mm, x) at 4.0 mm from the sensor and a perifoveal one (3 mm, 2 mm, y) at 3.02 mm, the other settings as
    ``tiny``'s report: (the designs folder, the output folder, the summary printed with --json)."""
    def make(d):
        designs = d / "designs"
        shutil.copytree(Path(__file__).resolve().parents[2] / "designs", designs)
        lens_toml(designs, name="foveal", f_mm=4.0, d_mm=2.0, pol="x")
        lens_toml(designs, name="perifoveal", f_mm=3.0, d_mm=2.0, pol="y")
        text = (designs / "system.toml").read_text().replace("= 150.0", "= 4.0").replace("= 25.0", "= 3.02")
        (designs / "system.toml").write_text(text)
        _psf_to_files(d, [str(designs / "system.toml"), "--field-deg", "0", "3", "--wavelengths", "9", "--workers",
                          "2", "--out", str(d / "o"), "--json"])

    d = made_once("psf-system", make)
    rc, stdout, stderr = _read(d)
    assert rc == 0, stderr
    return d / "designs", d / "o", json.loads(stdout)


def test_writes_the_report_and_prints_its_summary(tiny):
    _, out, text, _, res = tiny
    for name in ("psf_mono.png", "mtf.png", "ee_field.png", "psf_report.json", "psf_report.html"):
        assert (out / f"tiny_{name}").is_file()
    assert str(out / "tiny_psf_report.html") in text
    assert [m["field_deg"] for m in res["sensor"]] == [0.0, 3.0]


def test_prints_the_key_figures_per_field(tiny):
    """psf printed no Strehl ratio, efficiency or encircled energy; each field's row now carries the report's."""
    _, _, text, _, res = tiny
    rows = {line.split()[0]: line.split() for line in text.splitlines() if re.match(r"^  \d[\d.]* deg ", line)}
    assert set(rows) == {"0", "3"}
    for m in res["monochromatic"]:
        row = rows[f"{m['field_deg']:g}"]
        assert row[2:4] == [f"{m['strehl']:.3f}", f"{m['focusing_efficiency']:.3f}"]
        assert row[4] == f"{m['fwhm_um'][0]:.4g}" and row[8] == f"{m['ee']:.3f}"
    r = res["monochromatic"][0]["ee_radius_um"]
    assert f"EE r {r:.4g} um" in text and "Strehl" in text and "focusing eff." in text
    ee = res["on_axis_ee_pixel_radius"]
    assert f"within one pixel pitch (r {ee['radius_um']:g} um): {ee['mono']:.3f} at 10 um, {ee['band']:.3f}" in text


def test_prints_the_whole_run_time_and_progress_lines(tiny):
    """The summary gave the lens' report time (23.5 s) for a 235 s run; nothing said what the first run was
    computing. Now: the whole run's time and its stages on stdout, one line per stage on stderr (off a terminal)."""
    _, _, text, err, res = tiny
    m = re.search(r"^([\d.]+) s in all \(posts \(RCWA library\) ([\d.]+) s, .*reports ([\d.]+) s, start and checks "
                  r"([\d.]+) s\); files in ", text, re.M)
    assert m, text
    total, parts = float(m.group(1)), [float(x) for x in re.findall(r" ([\d.]+) s[,)]", m.group(0))]
    assert total >= res["seconds"] - 0.05 and sum(parts) == pytest.approx(total, abs=0.1 * len(parts))
    stages = [x for x in err.splitlines() if STAGE.match(x)]
    assert [x.split("] ")[1].split(":")[0] for x in stages] == ["posts", "posts at oblique incidence", "optical train",
                                                                "report of 'tiny'"]


def test_default_output_folders_do_not_collide(tiny_toml, tmp_path, monkeypatch, capsys):
    """Without --out psf wrote psf_report/ in the current folder and failed on the second run with
    "--out = 'psf_report' is invalid" though no --out was typed. Now each run gets a new out/psf-<time>/ (a second
    one the same second gets -2: tests/cli/test_options.py), and an error about it names the default output."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "psf_report").mkdir()
    (tmp_path / "psf_report" / "tiny_psf_report.html").write_text("an earlier run's report")
    assert main(["psf", str(tiny_toml), "--field-deg", "0", "--wavelengths", "3", "--posts", "ideal", "-q"]) == 0
    (run,) = (tmp_path / "out").iterdir()
    assert run.name.startswith("psf-") and (run / "tiny_psf_report.html").is_file()
    assert f"files in {Path('out') / run.name}" in capsys.readouterr().out
    (tmp_path / "out").rename(tmp_path / "elsewhere")
    (tmp_path / "out").write_text("a file where the default folder goes")
    assert main(["psf", str(tiny_toml), "--field-deg", "0", "--wavelengths", "3", "--posts", "ideal", "-q"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("metafovea psf: error: default output = 'out/psf-") and "--out =" not in err, err


def test_one_summary_warning_naming_the_options_psf_has(tiny_toml, tmp_path, capsys):
    """Results less accurate than --error gave a warning each, advising 'raise error or reduce wavelengths' (no such
    options) with the field as (0.32445394261570504, 0.0); now one line names --error and formats the fields."""
    rc = main(["psf", str(tiny_toml), "--field-deg", "0", "0.32445394261570504", "--wavelengths", "3", "--error",
               "1e-5", "--out", str(tmp_path / "o")])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    warns = [x for x in cap.err.splitlines() if x.startswith("metafovea psf: warning: ")]
    assert len(warns) == 1, cap.err
    w = warns[0]
    assert "less accurate than the requested error 1e-05" in w and "sensor PSF of 'tiny'" in w
    advice = w.split("what changes it: ", 1)[1]
    assert "--error " in advice and "raise error" not in w and "wavelengths_um" not in w
    assert all(a.split()[0] in ("--error", "--filter-um") for a in advice.split(", "))  # flags psf has
    assert not re.search(r"\d\.\d{6,}", cap.out + cap.err), "numbers for people: no 17-digit floats"
    assert "0.3245 deg" in cap.out


def test_system_file_reports_both_lenses(system_pair, tmp_path, capsys):
    """psf refused the system file that design takes; now it reports both lenses at the system's distances."""
    d, out, s = system_pair
    assert s["foveal"]["z_um"] == 4000.0 and s["perifoveal"]["z_um"] == pytest.approx(3020.0)
    assert (out / "perifoveal_psf_report.html").is_file() and s["timing"]["seconds"]["total"] > 0
    assert main(["psf", str(d / "system.toml"), "--system", str(d / "system.toml"), "--out", str(tmp_path / "p")]) == 2
    assert "--system" in capsys.readouterr().err and not (tmp_path / "p").exists()


@pytest.mark.parametrize("args,param", [
    (["--wavelength-um", "0"], "--wavelength-um"),
    (["--wavelength-um", "-3"], "--wavelength-um"),
    (["--band-um", "0", "14"], "--band-um"),
    (["--band-um", "14", "8"], "--band-um"),
    (["--field-deg", "0", "60"], "--field-deg"),
    (["--window-um", "60", "--field-deg", "0"], "--window-um"),  # below 4 diffraction radii
    (["--window-um", "150", "--field-deg", "0"], "for error 0.0001"),  # truncates the Airy rings at 1.7e-3
    (["--error", "0"], "--error"),
    (["--pixel-um", "-17"], "--pixel-um"),
])
def test_bad_input_exit_2_one_line(tiny_toml, tmp_path, capsys, args, param):
    capsys.readouterr()
    rc = main(["psf", str(tiny_toml), "--wavelengths", "3", "--out", str(tmp_path / "o")] + args)
    err = capsys.readouterr().err
    assert rc == 2
    lines = error_lines(err)
    assert len(lines) == 1 and param in lines[0] and "Traceback" not in err, err
    assert not (tmp_path / "o").exists()  # nothing written: a late error left the folder it made (now removed)


def test_field_limit_is_the_lens_field(tiny_toml, tmp_path):
    path = tiny_toml
    lens = load_lens(path)
    lim = max_field_deg(lens, 14.0)
    assert 0 < lim < 60
    assert main(["psf", str(path), "--field-deg", f"{lim + 0.01:.4f}", "--out", str(tmp_path / "o")]) == 2


def test_window_ok_for_a_looser_error(tiny_toml, tmp_path):
    path = tiny_toml
    out = tmp_path / "o"
    assert main(["psf", str(path), "--wavelengths", "3", "--field-deg", "0", "--window-um", "150", "--error", "0.01",
                 "--out", str(out)]) == 0
    res = json.loads((out / "tiny_psf_report.json").read_text())
    m = res["monochromatic"][0]
    assert 150 <= m["samples"] * m["pitch_um"] <= 150 + 2 * m["pitch_um"]


def test_two_lenses_in_two_processes(tiny, system_pair, tmp_path, capsys, lens_toml):
    """Two lenses, one process each: the numbers of the single-process run (``tiny``'s lens is the system's foveal
    lens), and an error in a worker is one line naming the option."""
    def strip(rows):
        return [{k: v for k, v in r.items() if k != "seconds"} for r in rows]

    a = json.loads((system_pair[1] / "foveal_psf_report.json").read_text())
    assert strip(a["sensor"]) == strip(tiny[4]["sensor"])  # the same numbers as the single-process run
    other = lens_toml(tmp_path, name="tiny2", f_mm=3.0, d_mm=2.0)
    capsys.readouterr()
    assert main(["psf", str(tiny[0]), str(other), "--field-deg", "0", "--wavelengths", "3", "--window-um", "150",
                 "--jobs", "2", "--out", str(tmp_path / "o2")]) == 2
    lines = error_lines(capsys.readouterr().err)
    assert len(lines) == 1 and "--window-um" in lines[0]


@pytest.mark.parametrize("opts,flag", [
    # zero first-order efficiency at lambda0 / lambda = 2, 4 holds for exact phases (RCWA posts leave a little)
    (["--wavelength-um", "5", "--posts", "ideal"], "--wavelength-um"),
    (["--wavelength-um", "2.5", "--posts", "ideal"], "--wavelength-um"),
    (["--wavelengths", "100000"], "--wavelengths"),
    (["--temperature-k", "1"], "--temperature-k"),
    (["--pixel-um", "1e6"], "--pixel-um"),
    (["--filter-um", "20", "0.5"], "--filter-um"),
    (["--filter-um", "3", "0.2"], "--filter-um"),
])
def test_psf_cli_errors_name_the_option(tmp_path, capsys, opts, flag, lens_toml, cli_error):
    """--wavelengths 100000 hung; --pixel-um / --filter-um / --temperature-k errors did not name the option
    (a temperature of 1 K printed a RuntimeWarning and blamed band_um); a wavelength at zero first-order
    efficiency named 'polarization = None'."""
    toml = lens_toml(tmp_path, f_mm=20.0, d_mm=2.0)
    rc = main(["psf", str(toml), "--field-deg", "0", "--wavelengths", "3", "--out", str(tmp_path / "o"), *opts])
    err = "\n".join(error_lines(cli_error(capsys)))
    assert rc == 2, err
    assert err.startswith("metafovea psf: error: " + flag) and len(err.splitlines()) == 1
    assert "RuntimeWarning" not in err


def test_psf_two_lenses_with_one_name_refused(tmp_path, capsys, lens_toml, cli_error):
    """Two designs with the same 'name' silently overwrote each other's report files."""
    a = lens_toml(tmp_path, name="same", f_mm=20.0, d_mm=2.0)
    b = tmp_path / "other.toml"
    b.write_text(a.read_text().replace("f_mm = 20.0", "f_mm = 25.0"))
    out = tmp_path / "o"
    rc = main(["psf", str(a), str(b), "--field-deg", "0", "--wavelengths", "3", "--out", str(out)])
    err = cli_error(capsys)
    assert rc == 2 and "'same'" in err and not out.exists()


@pytest.mark.parametrize("opts,flag", [(["--band-um", "8", "300"], "--band-um"),
                                       (["--band-um", "0.01", "1e4"], "--band-um"),
                                       (["--wavelength-um", "250"], "--wavelength-um")])
def test_psf_band_beyond_evanescent_limit_names_band(tmp_path, capsys, opts, flag, lens_toml, cli_error):
    """A band reaching lambda0/NA failed deep inside with '--field-deg = 0.0 is invalid; |field| <= 0.000'."""
    toml = lens_toml(tmp_path, f_mm=20.0, d_mm=2.0)  # NA 0.05: limit 200 um
    rc = main(["psf", str(toml), "--field-deg", "0", "--wavelengths", "3", "--out", str(tmp_path / "o"), *opts])
    err = cli_error(capsys)
    assert rc == 2 and err.startswith("metafovea psf: error: " + flag), err
    assert not (tmp_path / "o").exists()


def test_psf_takes_relay_and_distances_from_the_system_file(tmp_path, capsys, lens_toml):
    import shutil

    from metafovea.config import load_system

    d = tmp_path / "designs"
    shutil.copytree(Path(__file__).resolve().parents[2] / "designs", d)
    text = (d / "system.toml").read_text().replace("magnification = 0.5", "magnification = 0.25")
    (d / "system.toml").write_text(text)
    system = load_system(d / "system.toml")
    small = lens_toml(tmp_path, name=system.perifoveal.name, f_mm=25.0, d_mm=2.0)
    out = tmp_path / "o"
    capsys.readouterr()
    rc = main(["psf", str(small), "--system", str(d / "system.toml"), "--field-deg", "0", "--wavelengths", "3",
               "--out", str(out), "--json"])
    assert rc == 0
    s = json.loads(capsys.readouterr().out)[system.perifoveal.name]
    assert s["relay_magnification"] == 0.25 and s["pixel_pitch_um"] == pytest.approx(17.0 / 0.25)
    assert s["z_um"] == system.lens_to_sensor_um[1]
    rc = main(["psf", str(small), "--relay", "0", "--out", str(tmp_path / "p")])
    assert rc == 2 and "--relay" in capsys.readouterr().err


def test_psf_and_simulate_print_the_same_throughput(tiny, tmp_path, capsys):
    """The optical train's per-channel throughput (wafers, both lenses' RCWA posts, the ring) of the paper's camera:
    the psf report's numbers are the ones `metafovea simulate` prints and stores."""
    from metafovea.measurement import Measurement
    from metafovea.optics.train import throughput_lines

    trains = tiny[4]["optical_train"]
    assert [t["channel"] for t in trains] == ["foveal", "perifoveal"] and {t["posts"] for t in trains} == {"rcwa"}
    for t in trains:
        assert 0.2 < t["throughput"] < 0.5
        assert t["throughput"] == pytest.approx(float(__import__("numpy").prod(list(t["factors"].values()))), rel=2e-3)
    capsys.readouterr()
    rc = main(["simulate", "--frames", "1", "--psf", "airy", "--no-tiff", "--no-preview", "--out",
               str(tmp_path / "m.npz")])
    out = capsys.readouterr().out
    assert rc == 0
    for line in throughput_lines(trains):
        assert line in out
    assert Measurement.load(tmp_path / "m.npz").meta["optical_train"] == json.loads(json.dumps(trains))


def test_tolerance_is_the_error_in_the_words_of_the_other_stages(tiny, tiny_toml, tmp_path, capsys):
    """--tolerance (the --error of the other stages' vocabulary): the output names it with the engines it chose and
    the largest error estimate, in the lens' JSON too; a bad value names the spelling typed."""
    from metafovea.cli import build_parser

    _, _, stdout, _, res = tiny
    assert "tolerance 0.0001 of the peak (--tolerance, --error): engines " in stdout
    tol = res["tolerance"]
    assert tol["tolerance_of_peak"] == 1e-4 and tol["chose"]["sensor"] and tol["chose"]["monochromatic"]
    assert tol["above_tolerance"] == len(res["accuracy"]) and tol["estimate_of_peak"] > 0 and tol["why"] in stdout
    args = build_parser(["psf", "x.toml"]).parse_args(["psf", "x.toml", "--tolerance", "0.01"])
    assert args.error == 0.01 and args.error_flag == "--tolerance"
    assert main(["psf", str(tiny_toml), "--tolerance", "0", "--out", str(tmp_path / "p")]) == 2
    assert error_lines(capsys.readouterr().err)[0].startswith("metafovea psf: error: --tolerance = 0")

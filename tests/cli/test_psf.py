"""``metafovea psf``: files written and the summary printed, bad input -> exit 2 with one line that names the
option typed, two lenses in two processes give the numbers of one."""

import contextlib
import io
import json
from pathlib import Path

import pytest

from metafovea.cli import main
from metafovea.config import load_lens
from metafovea.optics import max_field_deg


@pytest.fixture(scope="module")
def tiny(tmp_path_factory, lens_toml):
    d = tmp_path_factory.mktemp("tiny")
    path = lens_toml(d, name="tiny", f_mm=4.0, d_mm=2.0)
    out = d / "report"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        rc = main(["psf", str(path), "--field-deg", "0", "3", "--wavelengths", "9", "--out", str(out), "--json"])
    assert rc == 0
    return path, out, json.loads(stdout.getvalue())


def test_writes_the_report_and_prints_its_summary(tiny):
    _, out, summary = tiny
    for name in ("psf_mono.png", "mtf.png", "ee_field.png", "psf_report.json", "psf_report.html"):
        assert (out / f"tiny_{name}").is_file()
    s = summary["tiny"]
    assert s["html"] == str(out / "tiny_psf_report.html")
    res = json.loads((out / "tiny_psf_report.json").read_text())
    assert s["sensor"] == res["sensor"] and s["monochromatic"] == res["monochromatic"]
    assert [m["field_deg"] for m in s["sensor"]] == [0.0, 3.0]


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
def test_bad_input_exit_2_one_line(tiny, tmp_path, capsys, args, param):
    path, _, _ = tiny
    capsys.readouterr()
    rc = main(["psf", str(path), "--wavelengths", "3", "--out", str(tmp_path / "o")] + args)
    err = capsys.readouterr().err
    assert rc == 2
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1 and param in lines[0] and "Traceback" not in err, err


def test_field_limit_is_the_lens_field(tiny, tmp_path):
    path, _, _ = tiny
    lens = load_lens(path)
    lim = max_field_deg(lens, 14.0)
    assert 0 < lim < 60
    assert main(["psf", str(path), "--field-deg", f"{lim + 0.01:.4f}", "--out", str(tmp_path / "o")]) == 2


def test_window_ok_for_a_looser_error(tiny, tmp_path):
    path, _, _ = tiny
    out = tmp_path / "o"
    assert main(["psf", str(path), "--wavelengths", "3", "--field-deg", "0", "--window-um", "150", "--error", "0.01",
                 "--out", str(out)]) == 0
    res = json.loads((out / "tiny_psf_report.json").read_text())
    m = res["monochromatic"][0]
    assert 150 <= m["samples"] * m["pitch_um"] <= 150 + 2 * m["pitch_um"]


def test_two_lenses_in_two_processes(tiny, tmp_path, capsys, lens_toml):
    path, out1, _ = tiny
    other = lens_toml(tmp_path, name="tiny2", f_mm=3.0, d_mm=2.0)
    out = tmp_path / "o"
    assert main(["psf", str(path), str(other), "--field-deg", "0", "3", "--wavelengths", "9", "--jobs", "2",
                 "--out", str(out)]) == 0
    a = json.loads((out / "tiny_psf_report.json").read_text())
    b = json.loads((out1 / "tiny_psf_report.json").read_text())
    strip = lambda rows: [{k: v for k, v in r.items() if k != "seconds"} for r in rows]
    assert strip(a["sensor"]) == strip(b["sensor"])  # the same numbers as the single-process run
    assert (out / "tiny2_psf_report.html").is_file()
    capsys.readouterr()
    assert main(["psf", str(path), str(other), "--field-deg", "0", "--wavelengths", "3", "--window-um", "150",
                 "--jobs", "2", "--out", str(tmp_path / "o2")]) == 2
    lines = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
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
    err = cli_error(capsys)
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


@pytest.mark.parametrize("opts,flag", [(["--band-um", "8", "300"], "--band-um"), (["--band-um", "0.01", "1e4"], "--band-um"),
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

    trains = tiny[2]["optical_train"]
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

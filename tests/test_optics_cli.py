"""``metafovea psf``: files written, JSON numbers equal to the library's, bad input -> exit 2, one line."""

import json
import warnings

import pytest

from metafovea.cli import main
from metafovea.config import load_lens
from metafovea.optics import psf, sensor_psf
from metafovea.radiometry import psf_wavelengths
from metafovea.optics.pupil import max_field_deg

TOML = """name = "tiny"
f_mm = 4.0
diameter_mm = 2.0
wavelength_um = 10.0
polarization = "x"
levels = 8
lattice = "integer"
"""


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    d = tmp_path_factory.mktemp("tiny")
    path = d / "tiny.toml"
    path.write_text(TOML)
    out = d / "report"
    rc = main(["psf", str(path), "--field-deg", "0", "3", "--wavelengths", "9", "--out", str(out)])
    assert rc == 0
    return path, out


def test_writes_png_json_html(tiny):
    _, out = tiny
    for name in ("psf_mono.png", "mtf.png", "ee_field.png"):
        data = (out / f"tiny_{name}").read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 1000
    page = (out / "tiny_psf_report.html").read_text()
    assert page.startswith("<!doctype html>") and page.count("data:image/png;base64,") == 3
    res = json.loads((out / "tiny_psf_report.json").read_text())
    assert res["lens"] == "tiny" and len(res["sensor"]) == 2 and res["spectral"]["n_wavelengths"] >= 9


def test_json_numbers_match_library(tiny):
    path, out = tiny
    lens = load_lens(path)
    res = json.loads((out / "tiny_psf_report.json").read_text())
    assert res["mtf_cutoff_cyc_per_mm"] == pytest.approx(2 * lens.na / lens.wavelength_um * 1000)
    P = psf(lens, field_deg=0.0, quantize=True, lattice=True, error=1e-4)
    m0 = res["monochromatic"][0]
    assert m0["engine"] == P.engine and m0["samples"] == P.shape[0]
    assert m0["energy_fraction"] == pytest.approx(P.energy_fraction, rel=1e-9)
    assert m0["peak_fraction_per_um2"] == pytest.approx(P.intensity.max() / P.pitch_um ** 2, rel=1e-9)
    wl, w = psf_wavelengths((8.0, 14.0), design_um=lens.wavelength_um, n=9, temperature_k=300.0)
    assert res["spectral"]["n_wavelengths"] == wl.size
    for s, fd in zip(res["sensor"], (0.0, 3.0)):
        assert s["field_deg"] == fd
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mono = sensor_psf(lens, pixel_pitch_um=17.0, field_deg=fd, error=1e-4)
            poly = sensor_psf(lens, pixel_pitch_um=17.0, field_deg=fd, wavelengths_um=wl, weights=w, error=1e-4)
        c = mono.shape[0] // 2
        assert s["mono_center_pixel"] == pytest.approx(mono.intensity[c, c], rel=1e-9)
        c = poly.shape[0] // 2
        assert s["poly_center_pixel"] == pytest.approx(poly.intensity[c, c], rel=1e-9)
        assert s["poly_energy_fraction"] == pytest.approx(poly.energy_fraction, rel=1e-9)
        assert s["poly_error_estimate"] == pytest.approx(poly.error_estimate, rel=1e-9)
        assert s["size_px"] == poly.shape[0]


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
    path, _ = tiny
    capsys.readouterr()
    rc = main(["psf", str(path), "--wavelengths", "3", "--out", str(tmp_path / "o")] + args)
    err = capsys.readouterr().err
    assert rc == 2
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1 and param in lines[0] and "Traceback" not in err, err


def test_field_limit_is_the_lens_field(tiny, tmp_path):
    path, _ = tiny
    lens = load_lens(path)
    lim = max_field_deg(lens, 14.0)
    assert 0 < lim < 60
    assert main(["psf", str(path), "--field-deg", f"{lim + 0.01:.4f}", "--out", str(tmp_path / "o")]) == 2


def test_window_ok_for_a_looser_error(tiny, tmp_path):
    path, _ = tiny
    out = tmp_path / "o"
    assert main(["psf", str(path), "--wavelengths", "3", "--field-deg", "0", "--window-um", "150", "--error", "0.01",
                 "--out", str(out)]) == 0
    res = json.loads((out / "tiny_psf_report.json").read_text())
    m = res["monochromatic"][0]
    assert 150 <= m["samples"] * m["pitch_um"] <= 150 + 2 * m["pitch_um"]


def test_two_lenses_in_two_processes(tiny, tmp_path, capsys):
    path, out1 = tiny
    other = tmp_path / "tiny2.toml"
    other.write_text(TOML.replace('"tiny"', '"tiny2"').replace("f_mm = 4.0", "f_mm = 3.0"))
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

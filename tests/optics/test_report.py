"""The PSF report: the files of one lens (PNG figures, JSON numbers equal to the library's, one HTML page) and the
rules of the several-lens pipeline ``psf_reports`` (refused before any work and before the output is made)."""

import json
import warnings

import pytest

from metafovea.config import LensDesign, load_lens
from metafovea.errors import InputError
from metafovea.optics import SamplingError, psf, sensor_psf
from metafovea.optics.report import psf_report, psf_reports
from metafovea.radiometry import psf_wavelengths


@pytest.fixture(scope="module")
def tiny(tmp_path_factory, lens_toml):
    d = tmp_path_factory.mktemp("tiny")
    path = lens_toml(d, name="tiny", f_mm=4.0, d_mm=2.0)
    out = d / "report"
    res = psf_report(load_lens(path), out, fields_deg=[0.0, 3.0], n_wavelengths=9)
    return path, out, res


def test_writes_png_json_html(tiny, browser_check):
    _, out, res = tiny
    browser_check(out / "tiny_psf_report.html")
    for name in ("psf_mono.png", "mtf.png", "ee_field.png", "through_focus.png", "wavefront.png"):
        data = (out / f"tiny_{name}").read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 1000
    page = (out / "tiny_psf_report.html").read_text()
    assert page.lower().startswith("<!doctype html>") and page.count("data:image/png;base64,") == 5
    assert "PSF / MTF report: tiny" in page and page.count("<table>") == 2
    on_file = json.loads((out / "tiny_psf_report.json").read_text())
    assert on_file["lens"] == "tiny" and len(on_file["sensor"]) == 2 and on_file["spectral"]["n_wavelengths"] >= 9
    assert on_file["sensor"] == res["sensor"] and on_file["monochromatic"] == res["monochromatic"]


def test_json_numbers_match_library(tiny):
    path, out, _ = tiny
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


def test_psf_reports_refuses_one_name_twice_before_any_output(tmp_path):
    a = LensDesign("same", 20000.0, 2000.0)
    b = LensDesign("same", 25000.0, 2000.0)
    with pytest.raises(InputError) as e:
        psf_reports([a, b], tmp_path / "o", fields_deg=[0.0], n_wavelengths=3)
    assert e.value.parameter == "designs" and "'same'" in str(e.value)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("kw,parameter", [
    (dict(band_um=(8.0, 300.0)), "band_um"),  # NA 0.05: the rim is evanescent beyond 200 um
    (dict(wavelength_um=250.0), "wavelength_um"),
    (dict(filter_um=(20.0, 0.5)), "filter_um"),  # outside the band
    (dict(temperature_k=1.0), "temperature_k"),  # no light in the band
    (dict(fields_deg=[0.0, 80.0]), "field_deg"),
])
def test_psf_reports_names_the_parameter(tmp_path, kw, parameter):
    kw = {"fields_deg": [0.0], "n_wavelengths": 3, **kw}
    with pytest.raises(InputError) as e:
        psf_reports([LensDesign("t", 20000.0, 2000.0)], tmp_path / "o", **kw)
    assert e.value.parameter == parameter
    assert not (tmp_path / "o").exists()


def test_psf_report_monochromatic_errors_name_wavelength_um(tmp_path):
    # lambda0 / 2: the focusing order carries no light; the error names the report's own parameter
    with pytest.raises(InputError) as e:
        psf_report(LensDesign("t", 20000.0, 2000.0), tmp_path, fields_deg=[0.0], n_wavelengths=3, wavelength_um=5.0)
    assert e.value.parameter == "wavelength_um" and e.value.value == 5.0


def test_psf_report_truncating_window_is_refused(tiny, tmp_path):
    path, _, _ = tiny
    with pytest.raises(SamplingError, match="for error 0.0001") as e:
        psf_report(load_lens(path), tmp_path, fields_deg=[0.0], n_wavelengths=3, window_um=150.0)
    assert e.value.parameter == "window_um" and "allow_truncation" not in str(e.value)


def test_relay_and_lens_to_sensor_distance_are_honoured(tmp_path, lens_toml):
    """A 17 um sensor pixel behind a 0.5x relay covers 34 um of the focal plane; a sensor 200 um behind the focus of
    an F/2 lens (depth of focus +-80 um) is warned about and its PSFs are those of the defocused plane."""
    lens = load_lens(lens_toml(tmp_path, name="geo", f_mm=4.0, d_mm=2.0))
    focus = psf_report(lens, tmp_path / "a", fields_deg=[0.0], n_wavelengths=5, relay_magnification=0.5)
    assert focus["pixel_pitch_um"] == pytest.approx(34.0) and focus["sensor_pixel_um"] == 17.0
    assert focus["on_axis_ee_pixel_radius"]["radius_um"] == pytest.approx(34.0)
    assert not any("depth of focus" in w for w in focus["warnings"])
    z = lens.f_um + 200.0
    off = psf_report(lens, tmp_path / "b", fields_deg=[0.0], n_wavelengths=5, relay_magnification=0.5, z_um=z)
    assert off["z_um"] == z and off["defocus_um"] == pytest.approx(200.0)
    assert any("depth of focus" in w and "+200.0 um" in w for w in off["warnings"])
    assert off["monochromatic"][0]["peak_fraction_per_um2"] < 0.5 * focus["monochromatic"][0]["peak_fraction_per_um2"]
    P = psf(lens, quantize=True, lattice=True, z_um=z)
    assert off["monochromatic"][0]["peak_fraction_per_um2"] == pytest.approx(P.intensity.max() / P.pitch_um ** 2,
                                                                             rel=1e-9)
    page = (tmp_path / "b" / "geo_psf_report.html").read_text()
    assert "0.5x relay" in page and "34 um at the focal plane" in page


def test_through_focus_curve(tiny):
    """The curve's in-focus value is the report's exact on-axis pixel-radius energy, the core energy peaks at focus
    and falls symmetrically (non-paraxial lens: to within a few per cent) beyond the depth of focus."""
    import numpy as np

    _, _, res = tiny
    tf = res["through_focus"]
    dz = np.asarray(tf["defocus_um"])
    i0 = int(np.argmin(np.abs(dz)))
    assert abs(dz[i0]) < 1e-6 * res["f_mm"] * 1000
    assert tf["mono"][i0] == pytest.approx(res["on_axis_ee_pixel_radius"]["mono"], rel=1e-6)
    core = np.asarray(tf["mono_core"])
    assert abs(int(np.argmax(core)) - i0) <= 1
    assert core[0] < 0.9 * core[i0] and core[-1] < 0.9 * core[i0]
    assert core[0] == pytest.approx(core[-1], rel=0.05)
    assert tf["depth_of_focus_um"] == pytest.approx(2 * 10.0 * 2.0 ** 2)


def test_wavefront_error_of_ideal_posts_is_the_quantisation(tiny):
    """With ideal posts the phase error against the continuous lens is the N-level quantisation (uniform, rms
    pi / (N sqrt 3)) plus the hold over each lattice cell (uniform over +-pi p / zone width): where a patch spans
    several zones (the rim) their rms add in quadrature; at the centre the phase hardly varies across the patch."""
    import math

    path, _, res = tiny
    lens = load_lens(path)
    wf = res["wavefront"]
    assert wf["post_set"] == "ideal posts"
    r = wf["rim"]["center_um"][0]
    zone = lens.wavelength_um * math.hypot(r, lens.f_um) / r  # local zone width at the rim patch
    q = math.pi / (lens.levels * math.sqrt(3))
    hold = math.pi * lens.period_um / zone / math.sqrt(3)
    assert wf["rim"]["rms_rad"] == pytest.approx(math.hypot(q, hold), rel=0.05)
    assert wf["centre"]["rms_rad"] < wf["rim"]["rms_rad"] and wf["rim"]["max_rad"] <= math.pi


def test_mtf_against_field_from_the_sensor_psfs(tiny):
    """The report's MTF at half the pixel Nyquist frequency and at Nyquist, per field, equals mtf_slices of the
    sensor PSF it shows (the field's tangential and sagittal directions; values in [0, 1])."""
    from metafovea.optics import mtf_slices

    path, _, res = tiny
    lens = load_lens(path)
    s0 = res["sensor"][0]
    nu = s0["mono_mtf"]["nu_cyc_per_mm"]
    assert nu[1] == pytest.approx(1000.0 / (2 * res["pixel_pitch_um"]))
    P = sensor_psf(lens, pixel_pitch_um=res["pixel_pitch_um"], field_deg=0.0, error=1e-4)
    m = mtf_slices(P, nu)
    assert s0["mono_mtf"]["tangential"] == pytest.approx(list(m["tangential"]), rel=1e-9)
    assert len(res["sensor"]) == 2 and all(0 <= v <= 1 for s in res["sensor"] for v in s["poly_mtf"]["sagittal"])


def test_key_figures_per_field_are_the_library_functions(tiny):
    """Each monochromatic row carries the figures `metafovea psf` prints: Strehl ratio, focusing efficiency, FWHM
    and the encircled energy within the first dark ring (on axis the exact radial integral, off axis the fine PSF's
    about its centroid), equal to the optics functions of the same PSF."""
    from metafovea.optics import encircled_energy, fwhm_um, strehl
    from metafovea.optics.psf import diffraction_radius_um, encircled_energy_on_axis

    path, _, res = tiny
    lens = load_lens(path)
    r1 = diffraction_radius_um(lens)
    on, off = res["monochromatic"][0], res["monochromatic"][-1]
    assert on["field_deg"] == 0.0 and off["field_deg"] == 3.0 and on["ee_radius_um"] == r1
    assert on["ee"] == pytest.approx(encircled_energy_on_axis(lens, r1, wavelengths_um=[10.0]), rel=1e-12)
    P = psf(lens, field_deg=3.0, quantize=True, lattice=True, error=1e-4)
    assert off["ee"] == pytest.approx(float(encircled_energy(P, [r1])[0]), rel=1e-9)
    assert off["fwhm_um"] == pytest.approx(list(fwhm_um(P)), rel=1e-9) and off["strehl"] == pytest.approx(strehl(P))
    assert 0.9 < off["strehl"] < on["strehl"] <= 1.0 + 1e-9 and 0.5 < off["ee"] < on["ee"] < 0.838


def test_psf_reports_times_the_whole_run_and_folds_accuracy_into_data(tmp_path):
    """The run's stages are announced as they start and timed (the summary gave the lens' report time only); a
    sensor PSF less accurate than ``error`` is one ``accuracy`` item (why, and the parameters that change it), not
    a warning line each."""
    said = []
    lens = LensDesign("t", 4000.0, 2000.0)
    out = psf_reports([lens], tmp_path / "o", fields_deg=[0.0], n_wavelengths=3, error=1e-6, posts="ideal",
                      say=said.append)
    assert [x.split(":")[0] for x in said] == ["optical train", "report of 't'"]
    sec = out["timing"]["seconds"]
    assert set(sec) == {"optical_train", "reports", "total"} and sec["total"] >= sec["reports"] > out["t"]["seconds"]
    acc = out["t"]["accuracy"]
    assert acc and all(a["estimate"] > a["requested"] == 1e-6 and "error" in a["advice"] for a in acc)
    assert not any("exceeds the requested" in w for w in out["t"]["warnings"])
    assert out["timing"]["out_dir"] == str(tmp_path / "o")

"""QA regression tests for optics, split out of tests/test_qa_*.py: merge each into its subject test file
(keep the bug sentence as its docstring), then delete this file."""

from __future__ import annotations
import textwrap
import numpy as np
import pytest
from metafovea.cli import main
from metafovea.config import LensDesign
from metafovea.errors import InputError


def _lens_toml(tmp_path, name="qa", f_mm=0.8, d_mm=0.4, levels=8, lattice="integer", pol="x"):
    p = tmp_path / f"{name}.toml"
    p.write_text(textwrap.dedent(f"""\
        name = "{name}"
        f_mm = {f_mm}
        diameter_mm = {d_mm}
        wavelength_um = 10.0
        polarization = "{pol}"
        levels = {levels}
        lattice = "{lattice}"
        """))
    return p


def _err(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    return err


@pytest.mark.parametrize("f_um,d_um,m", [(20000.0, 2000.0, 2), (5000.0, 5000.0, 2), (8000.0, 3000.0, 3)])
def test_sensor_psf_where_another_order_focuses_is_finite(f_um, d_um, m):
    """At lambda0 / m the focusing order vanishes and order m focuses on the sensor: it was drawn as a
    1e-9 um disk, giving pixel values of ~1e19 (fractions of the incident power!)."""
    from metafovea.errors import NotConvergedWarning
    from metafovea.optics import sensor_psf
    lens = LensDesign("t", f_um, d_um)
    with pytest.warns(NotConvergedWarning):  # the disk stand-in for a focused order is flagged as rough
        P = sensor_psf(lens, pixel_pitch_um=17.0, wavelengths_um=[lens.wavelength_um / m], size_px=41)
    assert np.all(np.isfinite(P.intensity)) and P.intensity.min() >= 0
    assert 0 < P.intensity.sum() <= 1.0 + 1e-9 and P.intensity.max() <= 1.0
    assert P.error_estimate > 1e-3


@pytest.mark.parametrize("r,cx,cy", [(0.3, 0.1, -0.2), (2.0, 8.4, 8.4), (5.0, 0.0, 0.0), (40.0, 3.0, -7.0)])
def test_disk_pixels_conserve_power(r, cx, cy):
    from metafovea.optics.psf import _disk_pixels
    p, size = 17.0, 11
    x0 = y0 = -size * p / 2
    d = _disk_pixels((cx, cy), r, x0, y0, p, size)
    assert d.sum() == pytest.approx(1.0, rel=0.03)
    assert d.max() <= 1.0 + 1e-12
    # a disk half outside the window keeps only its inside share; one wholly outside leaves nothing
    if r >= 1.0:
        e = _disk_pixels((x0, cy), r, x0, y0, p, size)
        assert e.sum() == pytest.approx(0.5, rel=0.1)
    assert _disk_pixels((x0 - r - 1, cy), r, x0, y0, p, size).sum() == 0


def test_psf_at_zero_order_efficiency_names_the_wavelength():
    from metafovea.optics import psf
    lens = LensDesign("t", 20000.0, 2000.0)
    for wl in (lens.wavelength_um / 2, lens.wavelength_um / 3, lens.wavelength_um / 4):
        with pytest.raises(InputError) as e:
            psf(lens, wavelengths_um=[wl], quantize=True)
        assert e.value.parameter == "wavelengths_um"


@pytest.mark.parametrize("opts,flag", [
    (["--wavelength-um", "5"], "--wavelength-um"),
    (["--wavelength-um", "2.5"], "--wavelength-um"),
    (["--wavelengths", "100000"], "--wavelengths"),
    (["--temperature-k", "1"], "--temperature-k"),
    (["--pixel-um", "1e6"], "--pixel-um"),
    (["--filter-um", "20", "0.5"], "--filter-um"),
    (["--filter-um", "3", "0.2"], "--filter-um"),
])
def test_psf_cli_errors_name_the_option(tmp_path, capsys, opts, flag):
    toml = _lens_toml(tmp_path, f_mm=20.0, d_mm=2.0)
    rc = main(["psf", str(toml), "--field-deg", "0", "--wavelengths", "3", "--out", str(tmp_path / "o"), *opts])
    err = _err(capsys)
    assert rc == 2, err
    assert err.startswith("metafovea psf: error: " + flag) and len(err.splitlines()) == 1
    assert "RuntimeWarning" not in err


def test_psf_two_lenses_with_one_name_refused(tmp_path, capsys):
    """Two designs with the same 'name' silently overwrote each other's report files."""
    a = _lens_toml(tmp_path, name="same", f_mm=20.0, d_mm=2.0)
    b = tmp_path / "other.toml"
    b.write_text(a.read_text().replace("f_mm = 20.0", "f_mm = 25.0"))
    out = tmp_path / "o"
    rc = main(["psf", str(a), str(b), "--field-deg", "0", "--wavelengths", "3", "--out", str(out)])
    err = _err(capsys)
    assert rc == 2 and "'same'" in err and not out.exists()


def test_sensor_psf_capped_window_warning_says_so():
    """Pixels far below the PSF size truncate the window at max_size_px; the warning blamed 'geometric haze'."""
    from metafovea.errors import NotConvergedWarning
    from metafovea.optics import sensor_psf
    lens = LensDesign("t", 20000.0, 2000.0)
    with pytest.warns(NotConvergedWarning, match="capped at 31 pixels"):
        sensor_psf(lens, pixel_pitch_um=2.0, max_size_px=31)


@pytest.mark.parametrize("opts,flag", [(["--band-um", "8", "300"], "--band-um"), (["--band-um", "0.01", "1e4"], "--band-um"),
                                       (["--wavelength-um", "250"], "--wavelength-um")])
def test_psf_band_beyond_evanescent_limit_names_band(tmp_path, capsys, opts, flag):
    """A band reaching lambda0/NA failed deep inside with '--field-deg = 0.0 is invalid; |field| <= 0.000'."""
    toml = _lens_toml(tmp_path, f_mm=20.0, d_mm=2.0)  # NA 0.05: limit 200 um
    rc = main(["psf", str(toml), "--field-deg", "0", "--wavelengths", "3", "--out", str(tmp_path / "o"), *opts])
    err = _err(capsys)
    assert rc == 2 and err.startswith("metafovea psf: error: " + flag), err
    assert not (tmp_path / "o").exists()

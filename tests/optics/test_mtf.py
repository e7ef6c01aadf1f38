"""PSF metrics: the MTF of the flat lens against REFERENCES.md (values at 10 and 29.4 cycles/mm, the 2 NA / lambda
cutoff) and the paraxial diffraction-limited MTF, then FWHM and encircled energy of sampled PSFs."""

import numpy as np
import pytest

from metafovea.config import LensDesign
from metafovea.errors import InputError
from metafovea.optics import diffraction_mtf, encircled_energy, fwhm_um, psf, pupil_mtf

F1 = LensDesign.perifoveal()  # F/1, D = 25 mm
F2 = LensDesign.foveal()  # F/2, D = 75 mm


@pytest.mark.parametrize("lens,cut,m10,m29", [(F1, 89.44, 0.8346, 0.5654), (F2, 48.51, 0.7320, 0.2797)])
def test_mtf_references(lens, cut, m10, m29):
    m = pupil_mtf(lens, [10.0, 29.4, cut * 0.995, cut * 1.005])
    assert m[0] == pytest.approx(m10, abs=1.5e-4)
    assert m[1] == pytest.approx(m29, abs=1.5e-4)
    assert 0 < m[2] < 1e-3 and m[3] == 0.0
    assert 2 * lens.na / lens.wavelength_um * 1000 == pytest.approx(cut, abs=0.01)


def test_paraxial_limit_diffraction_mtf():
    # a slow lens (F/20): the exact pupil MTF tends to the paraxial diffraction-limited one, cutoff D / (lambda f)
    lens = LensDesign("slow", 100_000.0, 5_000.0)
    cut = 1000 * lens.diameter_um / (lens.wavelength_um * lens.f_um)
    nu = np.array([0.1, 0.3, 0.6, 0.9]) * cut
    assert np.allclose(pupil_mtf(lens, nu), diffraction_mtf(nu, cut), atol=2e-3)


def test_metrics_fwhm_and_ee():
    P = psf(F1, window_um=200, pitch_um=0.5, allow_truncation=True)
    fx, fy = fwhm_um(P)
    assert fx == pytest.approx(fy, rel=1e-6)
    assert 0.5 * 10 / F1.na < fx < 0.53 * 10 / F1.na
    ee = encircled_energy(P, [17.0, 24.0], center_um=(0.0, 0.0))
    assert ee == pytest.approx([0.8216, 0.8878], abs=2e-3)


@pytest.mark.parametrize("lens,ee17,ee24", [(F1, 0.8216, 0.8878), (F2, 0.7611, 0.8277)])
def test_encircled_energy_of_default_sampled_psf(lens, ee17, ee24):
    # the default pitch is near the intensity Nyquist pitch: EE must interpolate, not treat samples as squares
    P = psf(lens)
    assert P.pitch_um > 4.0
    e = encircled_energy(P, [17.0, 24.0])
    assert e[0] == pytest.approx(ee17, abs=2e-3)
    assert e[1] == pytest.approx(ee24, abs=2e-3)


def test_key_figures_of_a_perfect_slow_lens_are_the_airy_pattern():
    """The figures `metafovea psf` prints, against the Airy pattern of an F/10 lens (paraxial to ~1e-3): Strehl
    ratio 1 and focusing efficiency (peak / ideal lens' peak) 1 for the continuous lens, sinc^2(pi/8) = 0.9496 for 8
    ideal levels in focus (the focusing order's power), encircled energy 1 - J0^2 - J1^2 = 0.8378 within the first
    dark ring, FWHM 1.029 lambda F#. The FWHM was taken by linear interpolation between samples a third of a
    first-zero radius apart: 106.1 um against 102.9 um (3 % wide)."""
    from metafovea.optics import strehl
    from metafovea.optics.mtf import focusing_efficiency
    from metafovea.optics.psf import diffraction_radius_um, encircled_energy_on_axis

    lens = LensDesign("f10", 20_000.0, 2_000.0)
    P = psf(lens)
    assert strehl(P) == pytest.approx(1.0, abs=1e-6) and focusing_efficiency(P) == pytest.approx(1.0, abs=1e-6)
    q = psf(lens, quantize=True)
    assert strehl(q) == pytest.approx(1.0, abs=1e-6)
    assert focusing_efficiency(q) == pytest.approx(np.sinc(1 / 8) ** 2, rel=1e-6)
    r1 = diffraction_radius_um(lens)
    assert r1 == pytest.approx(1.21967 * lens.wavelength_um * 10, rel=2e-3)  # 1.22 lambda F#
    ee_exact = encircled_energy_on_axis(lens, r1, quantize=False, lattice=False)
    assert ee_exact == pytest.approx(0.8378, abs=1.5e-3)
    assert encircled_energy(P, [r1])[0] == pytest.approx(ee_exact, abs=2e-4)  # sampled PSF, centroid
    fx, fy = fwhm_um(P)
    assert fx == pytest.approx(fy, rel=1e-9)
    assert fx == pytest.approx(1.02899 * lens.wavelength_um * 10, rel=2e-3)


def test_a_sampled_psfs_mtf_is_refused_above_its_sample_nyquist():
    """At 49 cycles/mm a PSF sampled every 20.4 um (sample Nyquist 24.5) read 0.9998, where a lens of cutoff 19.9
    cycles/mm has none: the aliased transform. Up to the sample Nyquist it is the MTF; above, an InputError."""
    from metafovea.optics import mtf_slices, psf

    p = psf(LensDesign(name="t", f_um=5000.0, diameter_um=1000.0))
    nyq = 1000.0 / (2 * p.pitch_um)
    assert mtf_slices(p, [2.0, nyq])["tangential"][1] < 0.02
    with pytest.raises(InputError, match="sample Nyquist"):
        mtf_slices(p, [2.0, 2 * nyq])

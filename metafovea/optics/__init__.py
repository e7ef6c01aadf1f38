"""Optics stage: pupil fields of the metalenses, propagation engines, PSFs and MTF (spectral weights:
:mod:`metafovea.radiometry`).

Public API::

    PSF, psf, sensor_psf, encircled_energy_on_axis   (metafovea.optics.psf)
    build_pupils, Pupil, max_field_deg      (metafovea.optics.pupil)
    asm_propagate, mft_field, hankel_field, hankel_profiles, mft_intensity_multi  (metafovea.optics.propagate)
    mtf_2d, mtf_radial, mtf_slices, encircled_energy, strehl, fwhm_um, diffraction_mtf, pixel_mtf
"""

from .mtf import (diffraction_mtf, encircled_energy, fwhm_um, mtf_2d, mtf_radial, mtf_slices, pixel_mtf, pupil_mtf,
                  strehl)
from .propagate import (AliasingWarning, SamplingError, asm_propagate, hankel_field, hankel_profiles, mft_field,
                        mft_intensity_multi)
from .psf import PSF, diffraction_radius_um, encircled_energy_on_axis, nyquist_pitch_um, psf, sensor_psf
from .pupil import Pupil, build_pupils, field_direction, max_field_deg

__all__ = ["PSF", "AliasingWarning", "Pupil", "SamplingError", "asm_propagate", "build_pupils",
           "diffraction_mtf", "diffraction_radius_um", "encircled_energy", "encircled_energy_on_axis",
           "field_direction", "fwhm_um", "hankel_field", "hankel_profiles", "max_field_deg", "mft_field",
           "mft_intensity_multi", "mtf_2d", "mtf_radial", "mtf_slices", "nyquist_pitch_um", "pixel_mtf",
           "psf", "pupil_mtf", "sensor_psf", "strehl"]

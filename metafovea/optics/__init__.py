"""Optics stage: pupil fields of the metalenses, propagation engines, PSFs, sensor PSFs, MTF and the PSF report
(spectral weights: :mod:`metafovea.radiometry`).

Files, in the order light meets them::

    pupil      the lens as a pupil in direction-sine space, per wavelength, field and polarisation: the
               focusing order (Pupil) and the other diffraction orders as haze (PupilSet); max_field_deg; the
               numerical ray map of a lens with phase_poly_rad (design_na, radius_of_direction_sine)
    propagate  the engines: asm_propagate (band-limited angular spectrum of a sampled field, exact; the
               reference for small apertures), mft_field / mft_intensity_multi (windowed direction-sine
               transform, any field), hankel_field / hankel_profiles (1-D, on axis); SamplingError,
               AliasingWarning
    rayleigh   rs_field (the windowed exact Rayleigh-Sommerfeld engine over the hard-edged aperture: off-axis
               PSFs, with an evaluated error estimate) and rs_reference (brute force, polar per Fresnel zone)
    psf        the PSF type; psf() (field PSF on a fine grid: hankel on axis in focus, rs off axis, on axis where
               the Debye model's rim wave is off (debye_error_bound) and for lenses with phase_poly_rad, mft on
               request);
               encircled_energy_on_axis (exact radial integral); diffraction_radius_um, nyquist_pitch_um
    sensor     sensor_psf(): the PSF integrated over pixels, broadband, on and off axis (batched hankel on
               axis; batched mft near focus and the geometric ray engine elsewhere off axis, with an error
               bound for each; a result less accurate than asked says why in info['accuracy']); box_integrate,
               disk_pixels, geometric_pixels_multi, debye_pixel_error (the Debye rim wave's error on pixels)
    sweep      sensor_psf_sweep(): sensor PSFs over fields and wavelength sets, one task each through
               metafovea.parallel.run_tasks (local threads or processes, or a Dask cluster: psf --scheduler)
    mtf        metrics of a PSF or a lens: mtf_2d, mtf_radial, mtf_slices, pupil_mtf (exact pupil
               autocorrelation), diffraction_mtf, pixel_mtf, encircled_energy, strehl, fwhm_um
    jaxpsf     the differentiable imaging model (JAX, float64): imaging_model() -> ImagingModel (band PSF of a
               channel per field point on a fine or sensor grid, its MTF area; differentiable in the added radial
               phase and the posts' level transmissions), train_gains; loaded on first use (JAX takes seconds)
    report     psf_report (one lens: PNG figures, JSON, HTML page) and psf_reports (several lenses, the
               ``metafovea psf`` pipeline); lens_lines, timing_line (what the command prints)
"""

from .mtf import (
                  diffraction_mtf,
                  encircled_energy,
                  fwhm_um,
                  mtf_2d,
                  mtf_radial,
                  mtf_slices,
                  pixel_mtf,
                  pupil_mtf,
                  strehl,
)
from .propagate import (
                  AliasingWarning,
                  SamplingError,
                  asm_propagate,
                  hankel_field,
                  hankel_profiles,
                  mft_field,
                  mft_intensity_multi,
)
from .psf import PSF, debye_error_bound, diffraction_radius_um, encircled_energy_on_axis, nyquist_pitch_um, psf
from .pupil import Pupil, build_pupils, field_direction, max_field_deg
from .rayleigh import rs_field, rs_reference
from .sensor import box_integrate, debye_pixel_error, disk_pixels, sensor_psf

__all__ = ["AliasingWarning", "PSF", "Pupil", "SamplingError", "asm_propagate", "box_integrate", "build_pupils",
           "debye_error_bound", "debye_pixel_error", "diffraction_mtf", "diffraction_radius_um", "disk_pixels",
           "encircled_energy", "encircled_energy_on_axis", "field_direction", "fwhm_um", "hankel_field",
           "hankel_profiles", "max_field_deg", "mft_field", "mft_intensity_multi", "mtf_2d", "mtf_radial",
           "mtf_slices", "nyquist_pitch_um", "pixel_mtf", "psf", "pupil_mtf", "rs_field", "rs_reference", "sensor_psf",
           "strehl"]

#: names of the JAX model, imported on first use (``import jax`` takes ~3 s; nothing else here needs it)
_JAX_NAMES = frozenset({"ImagingModel", "TrainGains", "imaging_model", "train_gains"})


def __getattr__(name: str) -> object:
    if name in _JAX_NAMES:
        from . import jaxpsf

        return getattr(jaxpsf, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

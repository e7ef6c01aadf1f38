"""Reconstruction of the foveal (``x1``) and perifoveal (``x2``) images from polarisation-multiplexed frames

    y_t = alpha_t x1 + (1 - alpha_t) x2 (+ fpn + noise),

on plain numpy arrays (frames ``(T, H, W)``, float32 preserved; alpha ``(T,)``) or on a
:class:`~metafovea.measurement.Measurement` through :func:`reconstruct_measurement`.

Files:

=================  ==========================================================================================
``api``            :func:`reconstruct_measurement` (the pipeline: windows, FPN, denoising, scores; a
                   :class:`PipelineResult`) and :func:`reconstruct` (arrays in, one solver)
``auto``           :func:`choose_method` (``method='auto'``: the solver, windows and PSF-aware step from the
                   recording's motion, :func:`motion_of`, and the time allowed)
``lsq``            known alpha: :func:`lsq_known_alpha`, :class:`SlidingLSQ` (closed form, conditioning reported)
``alternating``    unknown alpha: :func:`alternating` (:class:`AlternatingOptions`; subspace start, foveal gauge
                   fix, TV prior)
``deep_prior``     :func:`dip` (:class:`DipOptions`): double deep image prior (JAX, imported on first use)
``snapshot``       :func:`snapshot`, :func:`register`: one frame, registration then separation
``video``          :func:`video`: sliding windows over a sequence
``fpn``            :func:`estimate_fpn`: fixed-pattern noise (calibration frames, foveal constraint, TV prior)
``polarizer``      the polariser's rotation model of alpha (fixes the unknown-alpha gauge)
``denoise``        :func:`denoise`: TV, bilateral, non-local means, with weights from the noise level
``operators``      :class:`FovealOperator`, :func:`downsample`, :func:`downsample_adjoint`, :func:`centre_crop`:
                   the foveal constraint ``D x1 = gain C x2 + offset``
``deconvolve``     PSF-aware: :func:`deconvolve_measurement`, :func:`separate_deconvolve`: joint separation and
                   deconvolution to the scene's radiance and brightness temperature
``joint``          its model and linear solves: :class:`ChannelPSFs`, the padded grid, CG, TV-ADMM
``field``          its field-dependent PSF (``psf_patches_x*``): the patches the data need, solved and blended
``psf_refine``     its PSFs refined from the data: :func:`psf_family` (one-parameter families from the optics
                   engine), :func:`refine_psf` (the member of largest evidence, where it beats the nominal)
``spectra``        its scene prior: radially averaged spectra, the fitted power law
``wavelet``        its non-linear step: the stationary wavelet frame, SURE-LET shrinkage and its risk estimate
``metrics``        PSNR, SSIM, :func:`~metafovea.reconstruct.metrics.score`; :func:`wiener_bound` and the
                   PSF-aware scores against the scene
``result``         :class:`Reconstruction` (saved as ``.npz``), :class:`PipelineResult`
``files``          writing a pipeline result (the ``.npz`` and its PNG figures) and a PSF-aware scene
``synthetic``      test scenes with an exact foveal constraint
``_common``        input checks, options with keyword overrides, the noise estimator, timers
=================  ==========================================================================================

Measured figures: BENCHMARKS.md, section "Reconstruction".
"""

import importlib
import sys
import types
from typing import Any

#: public name -> the submodule that holds it; imported on first use (PEP 562), so that ``import
#: metafovea.reconstruct`` (and a known-alpha CLI run) does not load the unknown-alpha, deep-prior and
#: deconvolution solvers
_HOMES = {
    "AlternatingOptions": "alternating", "alternating": "alternating", "foveal_gauge": "alternating",
    "MethodChoice": "auto", "Motion": "auto", "auto_lines": "auto", "choose_method": "auto", "motion_of": "auto",
    "FPN_MODES": "api", "METHODS": "api", "METHOD_CHOICES": "api", "fpn_mode": "api", "reconstruct": "api",
    "reconstruct_measurement": "api",
    "DECONVOLUTION_METHODS": "_common", "DEFAULT_DECONVOLUTION": "_common", "ChannelPSFs": "joint",
    "Deconvolution": "deconvolve",
    "deconvolve_measurement": "deconvolve", "separate_deconvolve": "deconvolve", "wiener_bound": "metrics",
    "FAMILY_KINDS": "psf_refine", "PSFFamily": "psf_refine", "psf_family": "psf_refine", "refine_psf": "psf_refine",
    "DipOptions": "deep_prior", "dip": "deep_prior",
    "DENOISERS": "denoise", "denoise": "denoise",
    "figure_paths": "files", "prepare_outputs": "files", "write_outputs": "files",
    "estimate_fpn": "fpn",
    "SlidingLSQ": "lsq", "condition_number": "lsq", "lsq_known_alpha": "lsq",
    "FovealOperator": "operators", "centre_crop": "operators", "downsample": "operators",
    "downsample_adjoint": "operators",
    "PipelineResult": "result", "Reconstruction": "result",
    "register": "snapshot", "snapshot": "snapshot",
    "video": "video",
}


#: functions named as their module: the package attribute is the function (as with eager imports), not the
#: submodule that the import system binds on the package when it loads it
_SAME_NAME = frozenset(n for n, home in _HOMES.items() if n == home)


class _Package(types.ModuleType):
    def __setattr__(self, name: str, value: Any) -> None:
        if name in _SAME_NAME and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{home}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_HOMES))


__all__ = ["AlternatingOptions", "ChannelPSFs", "DECONVOLUTION_METHODS", "DEFAULT_DECONVOLUTION", "DENOISERS",
           "Deconvolution", "DipOptions", "FAMILY_KINDS", "FPN_MODES", "FovealOperator", "METHODS", "METHOD_CHOICES",
           "MethodChoice", "Motion", "PSFFamily", "PipelineResult", "Reconstruction", "SlidingLSQ", "alternating",
           "auto_lines", "centre_crop", "choose_method", "condition_number", "deconvolve_measurement", "denoise",
           "dip", "downsample", "downsample_adjoint", "estimate_fpn", "figure_paths", "foveal_gauge", "fpn_mode",
           "lsq_known_alpha", "motion_of", "prepare_outputs", "psf_family", "reconstruct", "reconstruct_measurement",
           "refine_psf", "register", "separate_deconvolve", "snapshot", "video", "wiener_bound", "write_outputs"]

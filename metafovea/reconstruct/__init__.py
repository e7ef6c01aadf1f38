"""Reconstruction of the foveal (``x1``) and perifoveal (``x2``) images from polarisation-multiplexed
frames ``y_t = alpha_t x1 + (1 - alpha_t) x2 (+ fpn + noise)``.

Works on plain numpy arrays: frames ``(T, H, W)`` (float32 preserved), alpha ``(T,)``; or on a
:class:`~metafovea.measurement.Measurement` through :func:`reconstruct_measurement`.

* ``api``: :func:`reconstruct_measurement` (the pipeline: which windows, FPN, denoising, scoring against the
  file's truth; a :class:`PipelineResult`) and :func:`reconstruct` (arrays in, one solver).
* ``lsq``: :func:`lsq_known_alpha`, :class:`SlidingLSQ`: known alpha, closed form, conditioning reported.
* ``alternating``: :func:`alternating` (:class:`AlternatingOptions`): unknown alpha, classical (subspace init,
  foveal gauge fix, TV prior).
* ``deconvolve``: :func:`deconvolve_measurement`, :func:`separate_deconvolve` (:class:`ChannelPSFs`): PSF-aware
  joint separation and deconvolution to the scene's radiance and brightness temperature, :func:`wiener_bound`.
* ``deep_prior``: :func:`dip` (:class:`DipOptions`): double deep image prior (JAX, imported on first use).
* ``fpn``: :func:`estimate_fpn`: fixed-pattern noise (calibration frames or low-rank prior).
* ``snapshot``: :func:`snapshot`, :func:`register`: single-frame registration and separation.
* ``video``: :func:`video`: sliding windows over a sequence.
* ``denoise``: :func:`denoise`; ``metrics``: PSNR, SSIM and :func:`~metafovea.reconstruct.metrics.score`.
* ``operators``: :class:`FovealOperator`, :func:`downsample`, :func:`downsample_adjoint`, :func:`centre_crop`:
  the foveal constraint ``D x1 == gain * C x2 + offset`` (``foveal_gain``/``foveal_offset`` wherever
  ``scale`` is accepted; a Measurement's :class:`~metafovea.measurement.FovealConstraint`).
* ``result``: :class:`Reconstruction` (saved as ``.npz``), :class:`PipelineResult`; ``files``: writing a
  pipeline result (the ``.npz`` and its PNG figures).
* ``synthetic``: test scenes with an exact foveal constraint.
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
    "FPN_MODES": "api", "METHODS": "api", "fpn_mode": "api", "reconstruct": "api", "reconstruct_measurement": "api",
    "DECONVOLUTION_METHODS": "deconvolve", "ChannelPSFs": "deconvolve", "Deconvolution": "deconvolve",
    "deconvolve_measurement": "deconvolve", "separate_deconvolve": "deconvolve", "wiener_bound": "deconvolve",
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


__all__ = ["AlternatingOptions", "ChannelPSFs", "DECONVOLUTION_METHODS", "DENOISERS", "Deconvolution", "DipOptions",
           "FPN_MODES", "FovealOperator", "METHODS", "PipelineResult", "Reconstruction", "SlidingLSQ", "alternating",
           "centre_crop", "condition_number", "deconvolve_measurement", "denoise", "dip", "downsample",
           "downsample_adjoint", "estimate_fpn", "figure_paths", "foveal_gauge", "fpn_mode", "lsq_known_alpha",
           "prepare_outputs", "reconstruct", "reconstruct_measurement", "register", "separate_deconvolve", "snapshot",
           "video", "wiener_bound", "write_outputs"]

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

from metafovea.reconstruct.alternating import AlternatingOptions, alternating, foveal_gauge
from metafovea.reconstruct.api import FPN_MODES, METHODS, reconstruct, reconstruct_measurement
from metafovea.reconstruct.deconvolve import (DECONVOLUTION_METHODS, ChannelPSFs, Deconvolution,
                                              deconvolve_measurement, separate_deconvolve, wiener_bound)
from metafovea.reconstruct.deep_prior import DipOptions, dip
from metafovea.reconstruct.denoise import DENOISERS, denoise
from metafovea.reconstruct.files import figure_paths, prepare_outputs, write_outputs
from metafovea.reconstruct.fpn import estimate_fpn
from metafovea.reconstruct.lsq import SlidingLSQ, condition_number, lsq_known_alpha
from metafovea.reconstruct.operators import FovealOperator, centre_crop, downsample, downsample_adjoint
from metafovea.reconstruct.result import PipelineResult, Reconstruction
from metafovea.reconstruct.snapshot import register, snapshot
from metafovea.reconstruct.video import video

__all__ = ["AlternatingOptions", "ChannelPSFs", "DECONVOLUTION_METHODS", "DENOISERS", "Deconvolution", "DipOptions", "FPN_MODES", "FovealOperator", "METHODS",
           "PipelineResult", "Reconstruction", "SlidingLSQ", "alternating", "centre_crop", "condition_number",
           "deconvolve_measurement", "denoise", "dip", "downsample", "downsample_adjoint", "estimate_fpn", "figure_paths", "foveal_gauge",
           "lsq_known_alpha", "prepare_outputs", "reconstruct", "reconstruct_measurement", "register",
           "separate_deconvolve", "snapshot", "video", "wiener_bound", "write_outputs"]

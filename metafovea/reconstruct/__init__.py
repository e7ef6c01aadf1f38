"""Reconstruction of the foveal (``x1``) and perifoveal (``x2``) images from polarisation-multiplexed
frames ``y_t = alpha_t x1 + (1 - alpha_t) x2 (+ fpn + noise)``.

Works on plain numpy arrays: frames ``(T, H, W)`` (float32 preserved), alpha ``(T,)``.

* :func:`lsq_known_alpha`, :class:`SlidingLSQ`: known alpha, closed form, conditioning reported.
* :func:`alternating`: unknown alpha, classical (subspace init, foveal gauge fix, TV prior).
* :func:`dip`: double deep image prior (JAX, imported lazily).
* :func:`estimate_fpn`: fixed-pattern noise (calibration frames or low-rank prior).
* :func:`snapshot`: single-frame registration and separation.
* :func:`video`: sliding windows over a sequence.
* :func:`reconstruct`: dispatcher returning a :class:`Reconstruction`.
* :class:`FovealOperator`, :func:`downsample`, :func:`downsample_adjoint`, :func:`centre_crop`:
  the foveal constraint ``D x1 == gain * C x2 + offset`` (``foveal_gain``/``foveal_offset`` wherever
  ``scale`` is accepted; a Measurement's ``meta['foveal_constraint']``; 1 and 0 for common units).
"""

from metafovea.reconstruct.alternating import alternating, foveal_gauge
from metafovea.reconstruct.api import reconstruct
from metafovea.reconstruct.denoise import denoise
from metafovea.reconstruct.fpn import estimate_fpn
from metafovea.reconstruct.lsq import SlidingLSQ, condition_number, lsq_known_alpha
from metafovea.reconstruct.operators import FovealOperator, centre_crop, downsample, downsample_adjoint
from metafovea.reconstruct.result import Reconstruction
from metafovea.reconstruct.snapshot import register, snapshot
from metafovea.reconstruct.video import video


def dip(*args, **kwargs):  # noqa: D401
    """Double deep image prior (JAX); see :func:`metafovea.reconstruct.deep_prior.dip`. JAX is imported on
    first use only."""
    from metafovea.reconstruct.deep_prior import dip as _dip

    return _dip(*args, **kwargs)


__all__ = ["FovealOperator", "Reconstruction", "SlidingLSQ", "alternating", "centre_crop", "condition_number",
           "denoise", "dip", "downsample", "downsample_adjoint", "estimate_fpn", "foveal_gauge",
           "lsq_known_alpha", "reconstruct", "register", "snapshot", "video"]

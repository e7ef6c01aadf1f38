"""Fixtures of the imaging tests: a small paper system, delta and Gaussian PSFs, and the noise-free switches."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from metafovea.config import SensorDesign, SystemDesign
from metafovea.imaging.kernels import gaussian_kernel


@pytest.fixture
def small_system():
    """``small_system(n=48, **sensor_kw)``: the paper's system on an ``n x n`` crop."""
    def make(n: int = 48, **sensor_kw) -> SystemDesign:
        return replace(SystemDesign.paper(), sensor=replace(SensorDesign(), crop=(n, n), **sensor_kw))
    return make


@pytest.fixture
def delta_psf() -> dict:
    """A perfect (1 x 1) kernel for both channels."""
    return {"foveal": np.ones((1, 1)), "perifoveal": np.ones((1, 1))}


@pytest.fixture
def gauss_psf():
    """``gauss_psf(s1=0.6, s2=0.6)``: Gaussian kernels (sigma in samples) per channel."""
    def make(s1: float = 0.6, s2: float = 0.6) -> dict:
        return {"foveal": gaussian_kernel(s1), "perifoveal": gaussian_kernel(s2)}
    return make


@pytest.fixture
def quiet() -> dict:
    """simulate() switches for noise-free, FPN-free, unquantised frames."""
    return dict(noise=False, fpn_rank=0, quantize=False)

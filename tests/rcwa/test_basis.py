"""Plane-wave bases (metafovea.rcwa.basis): in a uniform medium P Q is diagonal with the dispersion relation
gamma^2 = eps - kx^2 - ky^2 of every harmonic, in the full and in both parity-adapted bases."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.rcwa.basis import Basis

EPS = 3.42 ** 2


@pytest.mark.parametrize("kind,kx0,ky0", [("full", 0.13, -0.07), ("xpol", 0.0, 0.0), ("ypol", 0.0, 0.0)])
def test_uniform_medium_dispersion_relation(kind, kx0, ky0):
    M = N = 3
    lam_over_p = 2.5  # 10 um light on a 4 um lattice
    kx = (kx0 + np.arange(-M, M + 1) * lam_over_p)[None, :]
    ky = (ky0 + np.arange(-N, N + 1) * lam_over_p)[None, :]
    b = Basis(kind, M, N, kx, ky)
    # Ex and Ey of every harmonic, or (parity) one class with (M+1)(N+1) and one with M N: ~4x fewer unknowns
    assert b.n == (2 * (2 * M + 1) * (2 * N + 1) if kind == "full" else (M + 1) * (N + 1) + M * N)
    PQ = b.P(np.eye(b.size["Ez"])[None] / EPS) @ b.Q_uniform(np.array([EPS]))
    np.testing.assert_allclose(PQ[0], np.diag(EPS - b.kt2_E[0]), atol=1e-12)

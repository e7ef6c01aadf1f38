"""Fourier building blocks (metafovea.rcwa.fourier): analytic rectangle coefficients against quadrature, and the
parity-adapted reduction (products and inverses of reduced operators are the reduced products and inverses)."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.rcwa.fourier import DiagOp, interval_coefficients, k_op_1d, orders, rebuild, reduce_op, toeplitz_full

P, NSI = 4.0, 3.42


def permittivity_toeplitz(width, M, center=0.0):
    """[[eps]] of a Si interval of ``width`` in air on period P, harmonics |m| <= M."""
    coef = (NSI ** 2 - 1) * interval_coefficients(width, center, P, 2 * M)
    coef[..., 2 * M] += 1.0
    return toeplitz_full(coef, M)


@pytest.mark.parametrize("width,center", [(1.3, 0.4), (2.0, 0.0), (3.9, -1.1)])
def test_interval_coefficients_match_quadrature(width, center):
    """c_k = (1/p) integral over the interval of exp(-2 pi i k x / p)."""
    x = np.linspace(center - width / 2, center + width / 2, 200_001)
    k = np.arange(-6, 7)
    num = np.trapezoid(np.exp(-2j * np.pi * k[:, None] * x[None, :] / P), x, axis=1) / P
    np.testing.assert_allclose(interval_coefficients(width, center, P, 6), num, atol=1e-10)


def test_toeplitz_of_a_uniform_medium_is_diagonal():
    A = toeplitz_full(interval_coefficients(P - 1e-12, 0.0, P, 6), 3)
    np.testing.assert_allclose(A, np.eye(7), atol=1e-11)


@pytest.mark.parametrize("space", ["e", "o"])
def test_reduced_product_and_inverse_of_a_mirror_symmetric_operator(space):
    """A centred interval commutes with x -> -x: in the even (odd) class its reduced form acts exactly as the
    full operator, and inverting the reduced matrix gives the reduced inverse."""
    M = 4
    A = permittivity_toeplitz(1.3, M)
    B = rebuild(space, M)
    assert B.shape == (2 * M + 1, orders(space, M).size)
    a = np.random.default_rng(1).normal(size=B.shape[1])
    np.testing.assert_allclose(A @ (B @ a), B @ (reduce_op(A, space, space, M) @ a), atol=1e-12)
    np.testing.assert_allclose(np.linalg.inv(reduce_op(A, space, space, M)),
                               reduce_op(np.linalg.inv(A), space, space, M), atol=1e-12)


@pytest.mark.parametrize("s_in,s_out", [("e", "o"), ("o", "e"), ("f", "f")])
def test_wave_vector_operator_is_the_reduced_diagonal(s_in, s_out):
    """diag(k) flips parity (k_m is odd in m): as a DiagOp it equals the reduced dense matrix, from both sides."""
    M = 4
    k = 0.7 * np.arange(-M, M + 1)
    op = DiagOp(*k_op_1d(k, s_in, s_out, M))
    ref = reduce_op(np.diag(k), s_in, s_out, M)
    rng = np.random.default_rng(2)
    X, Y = rng.normal(size=(op.n_in, 3)), rng.normal(size=(3, op.n_out))
    np.testing.assert_allclose(op.dense(), ref, atol=1e-14)
    np.testing.assert_allclose(op.lmul(X), ref @ X, atol=1e-13)
    np.testing.assert_allclose(op.rmul(Y), Y @ ref, atol=1e-13)

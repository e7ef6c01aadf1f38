"""Scattering matrices in modal bases and the Redheffer star product.

Convention: a region's fields are ``[E; H] = [[W, W], [V, -V]] [c+; c-]`` with ``c+`` forward
(``+z``) and ``c-`` backward mode amplitudes, both referenced at the face of the region where the
S-matrix acts. An S-matrix maps incoming to outgoing amplitudes:

    [c-_left ; c+_right] = [[S11, S12], [S21, S22]] [c+_left ; c-_right]

so S11 is reflection seen from the left (below), S21 transmission left -> right, S12 transmission
right -> left and S22 reflection seen from the right. Only decaying exponentials
``exp(i gamma k0 d)`` (``Im gamma >= 0``) ever appear, which keeps thick (10 um) high-index layers
stable. Identity mode matrices are passed as ``None`` (uniform media, E basis).
"""

from __future__ import annotations

import numpy as np


def _solve(A, B):
    return np.linalg.solve(A, B)


def interface(WA, VA, WB, VB, n: int):
    """S-matrix of the interface from region A (left/below) to region B (right/above)."""
    I = np.eye(n)
    if WA is None:
        X = I if WB is None else WB
    else:
        X = np.linalg.inv(WA) if WB is None else _solve(WA, WB)
    Y = _solve(VA, VB)
    inv = np.linalg.inv(X + Y)
    S21 = 2.0 * inv
    S22 = -inv @ (X - Y)
    S11 = X @ S21 - I
    S12 = X @ (S22 + I)
    return [S11, S12, S21, S22]


def propagate(S, phase):
    """Star product of S with a homogeneous propagation ``diag(phase)`` on its right side."""
    S11, S12, S21, S22 = S
    return [S11, S12 * phase[..., None, :], phase[..., :, None] * S21,
            phase[..., :, None] * S22 * phase[..., None, :]]


def star(A, B):
    """Redheffer star product: A on the left (below), B on the right (above)."""
    A11, A12, A21, A22 = A
    B11, B12, B21, B22 = B
    n = A11.shape[-1]
    I = np.eye(n)
    D_lhs = I - A22 @ B11
    X = _solve(D_lhs, np.concatenate([A21, A22 @ B12], axis=-1))
    DA21, DA22B12 = X[..., :n], X[..., n:]
    C_lhs = I - B11 @ A22
    CB12 = _solve(C_lhs, B12)
    S11 = A11 + A12 @ (B11 @ DA21)
    S12 = A12 @ CB12
    S21 = B21 @ DA21
    S22 = B22 + B21 @ DA22B12
    return [S11, S12, S21, S22]

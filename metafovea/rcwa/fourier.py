"""Fourier-space building blocks: harmonic index sets, 1-D Toeplitz matrices, parity reduction.

Harmonics are indexed per axis by ``m = -M..M`` (the "full" space ``'f'``). At normal incidence a
structure that is mirror symmetric about ``x = 0`` has fields that are either even or odd in x; an
even field is described by its coefficients at ``m = 0..M`` (space ``'e'``), an odd one by
``m = 1..M`` (space ``'o'``). An operator ``A`` that maps the parity class ``s`` to the class ``s'``
is represented in reduced coordinates ("value at the representative ``m >= 0``") by

    A_red = A_full[rows of s', :] @ B_s

where ``B_s`` (full x reduced) rebuilds the full coefficient vector (``a_{-m} = +-a_m``). Products and
inverses of reduced operators are the reduced products and inverses, so the RCWA equations can be
written once and evaluated either in the full or in a parity-adapted basis (4x fewer unknowns in 2-D).

2-D operators on a (x-space, y-space) class are Kronecker products with x as the slow index:
flat index ``i * n_y + j``.
"""

from __future__ import annotations

import numpy as np


def orders(space: str, M: int) -> np.ndarray:
    """Harmonic indices represented by ``space`` for truncation order ``M``."""
    if space == "f":
        return np.arange(-M, M + 1)
    if space == "e":
        return np.arange(0, M + 1)
    if space == "o":
        return np.arange(1, M + 1)
    raise ValueError(space)


def rebuild(space: str, M: int) -> np.ndarray:
    """``B_s``: (2M+1, n_s) matrix rebuilding full coefficients from reduced ones."""
    full = np.arange(-M, M + 1)
    if space == "f":
        return np.eye(2 * M + 1)
    red = orders(space, M)
    B = (np.abs(full)[:, None] == red[None, :]).astype(float)
    if space == "o":
        B *= np.sign(full)[:, None]
    return B


def rows(space: str, M: int) -> np.ndarray:
    """Positions in the full index list of the representatives of ``space``."""
    return orders(space, M) + M


def interval_coefficients(width, center, period, kmax: int) -> np.ndarray:
    """Fourier coefficients c_k, k = -kmax..kmax, of the indicator of [c - w/2, c + w/2].

    ``width`` and ``center`` may be arrays (batch, leading axes); returns shape (..., 2 kmax + 1).
    """
    w = np.asarray(width, dtype=float)[..., None]
    c = np.asarray(center, dtype=float)[..., None]
    k = np.arange(-kmax, kmax + 1)
    return (w / period) * np.sinc(k * w / period) * np.exp(-2j * np.pi * k * c / period)


def toeplitz_full(coef: np.ndarray, M: int) -> np.ndarray:
    """(..., 2M+1, 2M+1) Toeplitz matrix T[i, j] = c_{m_i - m_j} from coefficients for k=-2M..2M."""
    m = np.arange(-M, M + 1)
    idx = (m[:, None] - m[None, :]) + 2 * M
    return coef[..., idx]


def reduce_op(A_full: np.ndarray, s_in: str, s_out: str, M: int) -> np.ndarray:
    """Reduce a full (..., 2M+1, 2M+1) operator mapping class s_in to class s_out."""
    if s_in == "f" and s_out == "f":
        return A_full
    return A_full[..., rows(s_out, M), :] @ rebuild(s_in, M)


def indicator_toeplitz(width, center, period, M: int, space: str) -> np.ndarray:
    """Reduced Toeplitz matrix of an interval indicator acting within ``space``."""
    coef = interval_coefficients(width, center, period, 2 * M)
    return reduce_op(toeplitz_full(coef, M), space, space, M)


class DiagOp:
    """A 'diagonal' operator between two (possibly different) reduced spaces.

    out[..., i] = scale[..., i] * in[..., idx[i]] ; entries with scale 0 are zero rows. Used for the
    wave-vector matrices Kx, Ky, which flip parity in the reduced representation.
    """

    __slots__ = ("idx", "scale", "n_in")

    def __init__(self, idx: np.ndarray, scale: np.ndarray, n_in: int):
        self.idx = np.asarray(idx, dtype=int)
        self.scale = np.asarray(scale)
        self.n_in = int(n_in)

    @property
    def n_out(self) -> int:
        return self.idx.shape[0]

    def lmul(self, X: np.ndarray) -> np.ndarray:
        """self @ X for X of shape (..., n_in, k)."""
        return self.scale[..., :, None] * X[..., self.idx, :]

    def rmul(self, X: np.ndarray) -> np.ndarray:
        """X @ self for X of shape (..., k, n_out)."""
        shape = np.broadcast_shapes(X.shape[:-1], self.scale.shape[:-1] + (1,))
        out = np.zeros(shape[:-1] + (X.shape[-2], self.n_in), dtype=np.result_type(X, self.scale))
        nz = np.flatnonzero(np.any(np.reshape(self.scale != 0, (-1, self.n_out)), axis=0))
        out[..., self.idx[nz]] = X[..., nz] * self.scale[..., None, nz]
        return out

    def dense(self) -> np.ndarray:
        eye = np.eye(self.n_in)
        return self.lmul(np.broadcast_to(eye, self.scale.shape[:-1] + eye.shape))


def k_op_1d(k_full: np.ndarray, s_in: str, s_out: str, M: int) -> tuple[np.ndarray, np.ndarray, int]:
    """1-D wave-vector operator diag(k) from class s_in to s_out as (idx, scale, n_in).

    ``k_full``: (..., 2M+1) normalised wave numbers for m = -M..M.
    """
    if s_in == "f":
        assert s_out == "f"
        return np.arange(2 * M + 1), k_full, 2 * M + 1
    out_m = orders(s_out, M)
    in_m = orders(s_in, M)
    pos = {int(m): i for i, m in enumerate(in_m)}
    idx = np.array([pos.get(int(m), 0) for m in out_m], dtype=int)
    present = np.array([int(m) in pos for m in out_m])
    scale = k_full[..., out_m + M] * present
    return idx, scale, len(in_m)

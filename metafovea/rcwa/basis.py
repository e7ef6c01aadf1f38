"""Plane-wave bases (full or parity-adapted) and the RCWA operators P, Q built in them.

Maxwell's curl equations with ``exp(-i omega t)``, lengths scaled by ``k0`` (``z' = k0 z``) and
``H' = Z0 H``, for fields ``exp(i (kx x + ky y))`` summed over harmonics, give

    d/dz' [Ex, Ey] = i P [Hx, Hy],     d/dz' [Hx, Hy] = i Q [Ex, Ey]

    P = [[Kx G Ky,  I - Kx G Kx], [Ky G Ky - I, -Ky G Kx]],   G = [[eps]]^-1 (acts on Ez)
    Q = [[-Kx Ky, Kx^2 - E_yy], [E_xx - Ky^2, Ky Kx]]

``E_xx`` maps Ex to Dx and ``E_yy`` maps Ey to Dy: with the Laurent rule both are the Toeplitz matrix
``[[eps]]``; with Li's rules for crossed gratings (Li 1997) ``E_xx = [[ [[1/eps]]_x^-1 ]]_y`` (inverse
rule across the x discontinuities, Laurent along y) and ``E_yy = [[ [[1/eps]]_y^-1 ]]_x``.

Forward modes are ``exp(+i gamma z')`` with ``gamma^2`` the eigenvalues of ``P Q``; ``E = W``,
``H = V = Q W / gamma``; backward modes have ``H = -V``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metafovea.rcwa.fourier import DiagOp, k_op_1d, orders

#: field classes (x-space, y-space) for each basis kind
CLASSES = {
    "full": dict(Ex=("f", "f"), Ey=("f", "f"), Hx=("f", "f"), Hy=("f", "f"), Ez=("f", "f"), Hz=("f", "f")),
    # x-polarised light at normal incidence on a structure with mirror planes x=0 and y=0
    "xpol": dict(Ex=("e", "e"), Ey=("o", "o"), Hx=("o", "o"), Hy=("e", "e"), Ez=("o", "e"), Hz=("e", "o")),
    # y-polarised light
    "ypol": dict(Ex=("o", "o"), Ey=("e", "e"), Hx=("e", "e"), Hy=("o", "o"), Ez=("e", "o"), Hz=("o", "e")),
}


def _k2d(k1d, M: int, N: int, c_in, c_out, axis: str) -> DiagOp:
    """2-D diag(kx) (axis 'x') or diag(ky) (axis 'y') from class c_in to class c_out."""
    if axis == "x":
        idx1, sc1, nin1 = k_op_1d(k1d, c_in[0], c_out[0], M)
        ny = len(orders(c_in[1], N))
        assert c_in[1] == c_out[1]
        idx = (idx1[:, None] * ny + np.arange(ny)[None, :]).reshape(-1)
        scale = np.repeat(sc1, ny, axis=-1)
        return DiagOp(idx, scale, nin1 * ny)
    idx1, sc1, nin1 = k_op_1d(k1d, c_in[1], c_out[1], N)
    nx = len(orders(c_in[0], M))
    assert c_in[0] == c_out[0]
    idx = (np.arange(nx)[:, None] * nin1 + idx1[None, :]).reshape(-1)
    scale = np.tile(sc1, (1,) * (sc1.ndim - 1) + (nx,))
    return DiagOp(idx, scale, nx * nin1)


@dataclass
class Basis:
    """Harmonics |m| <= M (x), |n| <= N (y) in one of the bases of :data:`CLASSES`.

    kx, ky: (B, 2M+1), (B, 2N+1) normalised in-plane wave numbers (k / k0) of all full orders.
    """

    kind: str
    M: int
    N: int
    kx: np.ndarray
    ky: np.ndarray

    def __post_init__(self):
        c = CLASSES[self.kind]
        self.cls = c
        M, N = self.M, self.N
        self.size = {f: len(orders(c[f][0], M)) * len(orders(c[f][1], N)) for f in c}
        kx, ky = self.kx, self.ky
        self.Kx_Ez_Ex = _k2d(kx, M, N, c["Ez"], c["Ex"], "x")
        self.Ky_Hx_Ez = _k2d(ky, M, N, c["Hx"], c["Ez"], "y")
        self.Kx_Hy_Ez = _k2d(kx, M, N, c["Hy"], c["Ez"], "x")
        self.Ky_Ez_Ey = _k2d(ky, M, N, c["Ez"], c["Ey"], "y")
        self.Ky_Ex_Hz = _k2d(ky, M, N, c["Ex"], c["Hz"], "y")
        self.Kx_Hz_Hx = _k2d(kx, M, N, c["Hz"], c["Hx"], "x")
        self.Kx_Ey_Hz = _k2d(kx, M, N, c["Ey"], c["Hz"], "x")
        self.Ky_Hz_Hy = _k2d(ky, M, N, c["Hz"], c["Hy"], "y")
        # K-only blocks of Q (dense, small)
        self.Q11k = -self.Kx_Hz_Hx.lmul(self.Ky_Ex_Hz.dense())
        self.Q12k = self.Kx_Hz_Hx.lmul(self.Kx_Ey_Hz.dense())
        self.Q21k = -self.Ky_Hz_Hy.lmul(self.Ky_Ex_Hz.dense())
        self.Q22k = self.Ky_Hz_Hy.lmul(self.Kx_Ey_Hz.dense())
        self.nE = self.size["Ex"] + self.size["Ey"]
        self.nH = self.size["Hx"] + self.size["Hy"]
        assert self.nE == self.nH
        # squared transverse wave number of each E coordinate (representative harmonic)
        kt2 = []
        for f in ("Ex", "Ey"):
            mx = orders(c[f][0], M) + M
            ny_ = orders(c[f][1], N) + N
            kt2.append((kx[..., mx, None] ** 2 + ky[..., None, ny_] ** 2).reshape(kx.shape[:-1] + (-1,)))
        self.kt2_E = np.concatenate(kt2, axis=-1)
        kt2 = []
        for f in ("Hx", "Hy"):
            mx = orders(c[f][0], M) + M
            ny_ = orders(c[f][1], N) + N
            kt2.append((kx[..., mx, None] ** 2 + ky[..., None, ny_] ** 2).reshape(kx.shape[:-1] + (-1,)))
        self.kt2_H = np.concatenate(kt2, axis=-1)

    @property
    def n(self) -> int:
        return self.nE

    def P(self, G: np.ndarray) -> np.ndarray:
        """P from G = [[eps]]^-1 restricted to the Ez class, shape (B, nEz, nEz)."""
        GKy = self.Ky_Hx_Ez.rmul(G)
        GKx = self.Kx_Hy_Ez.rmul(G)
        P11 = self.Kx_Ez_Ex.lmul(GKy)
        P12 = -self.Kx_Ez_Ex.lmul(GKx)
        P21 = self.Ky_Ez_Ey.lmul(GKy)
        P22 = -self.Ky_Ez_Ey.lmul(GKx)
        i12 = np.arange(min(P12.shape[-2], P12.shape[-1]))
        P12[..., i12, i12] += 1.0   # Hy -> Ex identity (same class)
        i21 = np.arange(min(P21.shape[-2], P21.shape[-1]))
        P21[..., i21, i21] -= 1.0
        top = np.concatenate([P11, P12], axis=-1)
        bot = np.concatenate([P21, P22], axis=-1)
        return np.concatenate([top, bot], axis=-2)

    def Q(self, Exx: np.ndarray, Eyy: np.ndarray) -> np.ndarray:
        """Q from E_xx (Ex class) and E_yy (Ey class) matrices, shape (B, ., .)."""
        Q12 = self.Q12k - Eyy
        Q21 = Exx + self.Q21k
        Q11 = np.broadcast_to(self.Q11k, Q12.shape[:-2] + self.Q11k.shape[-2:])
        Q22 = np.broadcast_to(self.Q22k, Q12.shape[:-2] + self.Q22k.shape[-2:])
        top = np.concatenate([Q11, Q12], axis=-1)
        bot = np.concatenate([Q21, Q22], axis=-1)
        return np.concatenate([top, bot], axis=-2)

    def Q_uniform(self, eps: np.ndarray) -> np.ndarray:
        eps = np.asarray(eps)[..., None, None]
        I_x = np.eye(self.size["Ex"])
        I_y = np.eye(self.size["Ey"])
        return self.Q(eps * I_x, eps * I_y)

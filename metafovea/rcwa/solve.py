"""RCWA (Fourier modal method) solver: driver, results and the fast post-response path.

Conventions (tested in tests/rcwa/)
----------------------------------
* Time dependence ``exp(-i omega t)``; a forward plane wave is ``exp(+i kz z)``; loss is ``Im n > 0``.
* z points from the substrate (below) to the superstrate (above). "Incidence from the substrate"
  means light travelling +z; "from the superstrate" means -z.
* Reference planes: incident and reflected waves are referenced at the bottom face of the stack
  (``z = 0``, the substrate/first-layer interface), transmitted waves from below at the top face
  (``z = sum of thicknesses``); for incidence from the superstrate the roles swap. An empty stack is a
  single interface.
* Amplitudes are **power normalised**: ``|t|^2`` and ``|r|^2`` are diffraction efficiencies (power
  fractions) of propagating orders. For a wave with transverse field ``E_t``, normalised wave vector
  ``(kx, ky, kz)`` (units of k0), index n, the amplitudes are
  ``a_s = (E_t . s) sqrt(kz)`` and ``a_p = (E_t . k_par) n / sqrt(kz)``, with ``k_par`` the unit
  in-plane direction of propagation and ``s = z x k_par``. At normal incidence ``k_par`` is
  ``(cos phi, sin phi)``; with ``phi = 0`` the 'p' amplitude is ``sqrt(n) E_x`` and 's' is
  ``sqrt(n) E_y``. The field (E-ratio) transmission at normal incidence is
  ``t_field = t * sqrt(n_in / n_out)``. The same transverse definition is used for waves travelling
  either way (so ``r_pp = r_xx`` at normal incidence, unlike the Fresnel p convention).
* Polarisation index 0 = 'p' (= x at normal incidence, phi = 0), 1 = 's' (= y).
"""

from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from metafovea.errors import InputError, NotConvergedWarning, check_choice, check_int, check_positive, check_range
from metafovea.materials import index_of
from metafovea.rcwa.basis import Basis
from metafovea.rcwa.fourier import indicator_toeplitz, orders, rebuild
from metafovea.rcwa.geometry import Stack
from metafovea.rcwa.smatrix import interface, propagate, star

log = logging.getLogger(__name__)

FACTORIZATIONS = ("li", "laurent")
SIDES = ("substrate", "superstrate")
GAMMA_FLOOR = 1e-9
#: relative index contrast below which a patterned layer is solved as uniform (see _layer_modes)
UNIFORM_CONTRAST = 1e-9
MIN_HARMONICS = 1
MAX_HARMONICS = 60


def branch(lam: np.ndarray) -> np.ndarray:
    """Normalised kz = sqrt(lam) on the physical branch (Im >= 0; propagating ones with Re > 0)."""
    g = np.sqrt(np.asarray(lam, dtype=complex))
    flip = (g.imag < 0) & (g.real <= -g.imag)
    g = np.where(flip, -g, g)
    small = np.abs(g) < GAMMA_FLOOR
    return np.where(small, GAMMA_FLOOR * (1 + 1j), g)


def _bkron(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    a1, a2 = A.shape[-2:]
    b1, b2 = B.shape[-2:]
    out = A[..., :, None, :, None] * B[..., None, :, None, :]
    return out.reshape(out.shape[:-4] + (a1 * b1, a2 * b2))


@dataclass
class _LayerData:
    d: np.ndarray            # (B,) thickness um
    eps_b: np.ndarray        # (B,) background permittivity
    rect: dict | None = None  # eps_i, wx, wy (B,), cx, cy (float)


def _uniform_modes(basis: Basis, eps: np.ndarray):
    """Analytic modes of a uniform medium: W = I (E_t basis), V = Q / gamma.

    ``eps`` is written as ``gamma^2 + kt^2`` per harmonic so that at a Rayleigh anomaly (gamma -> 0,
    floored at GAMMA_FLOOR) the TE column of V stays finite and non-zero and V stays invertible.
    """
    g = branch(eps[..., None] - basis.kt2_E)
    e_eff = g * g + basis.kt2_E
    nEx = basis.size["Ex"]
    Exx = _diag(e_eff[..., :nEx])
    Eyy = _diag(e_eff[..., nEx:])
    V = basis.Q(Exx, Eyy) / g[..., None, :]
    return None, V, g


def _diag(v: np.ndarray) -> np.ndarray:
    out = np.zeros(v.shape + (v.shape[-1],), dtype=v.dtype)
    i = np.arange(v.shape[-1])
    out[..., i, i] = v
    return out


def _layer_modes(basis: Basis, lay: _LayerData, px: float, py: float, factorization: str):
    """(W, V, gamma) of a layer. W is None for uniform layers (identity, solved analytically)."""
    if lay.rect is None:
        return _uniform_modes(basis, lay.eps_b)
    r = lay.rect
    eps_b, eps_i = lay.eps_b, r["eps_i"]
    if np.all(np.abs(eps_i - eps_b) <= UNIFORM_CONTRAST * np.abs(eps_b)):
        # A patterned layer whose contrast is below rounding level is uniform: solving it as a
        # patterned layer would hand a degenerate spectrum to the eigen-solver for no gain.
        return _uniform_modes(basis, eps_b)
    c = basis.cls
    M, N = basis.M, basis.N
    sx_needed = {c[f][0] for f in ("Ex", "Ey", "Ez")}
    sy_needed = {c[f][1] for f in ("Ex", "Ey", "Ez")}
    Tx = {s: indicator_toeplitz(r["wx"], r["cx"], px, M, s) for s in sx_needed}
    Ty = {s: indicator_toeplitz(r["wy"], r["cy"], py, N, s) for s in sy_needed}
    eb = eps_b[..., None, None]
    ei = eps_i[..., None, None]

    def laurent(cl):
        A = (ei - eb) * _bkron(Tx[cl[0]], Ty[cl[1]])
        i = np.arange(A.shape[-1])
        A[..., i, i] += eb[..., 0]
        return A

    G = np.linalg.inv(laurent(c["Ez"]))
    if factorization == "laurent":
        Exx, Eyy = laurent(c["Ex"]), laurent(c["Ey"])
    else:
        sx, sy = c["Ex"]
        Ix = np.eye(Tx[sx].shape[-1])
        Ax = np.linalg.inv(Ix / eb + (1 / ei - 1 / eb) * Tx[sx])
        Exx = _bkron(Ax - eb * Ix, Ty[sy])
        i = np.arange(Exx.shape[-1])
        Exx[..., i, i] += eb[..., 0]
        sx, sy = c["Ey"]
        Iy = np.eye(Ty[sy].shape[-1])
        Ay = np.linalg.inv(Iy / eb + (1 / ei - 1 / eb) * Ty[sy])
        Eyy = _bkron(Tx[sx], Ay - eb * Iy)
        i = np.arange(Eyy.shape[-1])
        Eyy[..., i, i] += eb[..., 0]
    P = basis.P(G)
    Q = basis.Q(Exx, Eyy)
    if np.iscomplexobj(P) and not np.any(P.imag) and not np.any(Q.imag):
        # lossless, normal incidence, centred inclusions: P and Q are real, and so is their product; the real
        # eigen-solver is several times faster (complex-conjugate eigenpairs come back as complex anyway)
        P, Q = P.real, Q.real
    PQ = P @ Q
    if np.iscomplexobj(PQ) and not np.any(PQ.imag):
        PQ = PQ.real
    lam, W = np.linalg.eig(PQ)
    g = branch(lam)
    V = real_matmul(Q, W) / g[..., None, :]
    return W, V, g


def real_matmul(A: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``A @ X``; a real ``A`` times a complex ``X`` as one real product on X's (re, im) pairs (half the work of
    the complex product numpy would do after promoting A)."""
    if np.iscomplexobj(A) or not np.iscomplexobj(X) or X.dtype != np.complex128:
        return A @ X
    Xc = np.ascontiguousarray(X)
    return (A @ Xc.view(np.float64)).view(np.complex128)


def _smatrix(basis: Basis, wl: np.ndarray, eps_sub, eps_sup, layers: list[_LayerData], px, py,
             factorization: str):
    """Total S-matrix (E_t bases of the half-spaces) of the stack."""
    n = basis.n
    _, V_sub, _ = _uniform_modes(basis, eps_sub)
    _, V_sup, _ = _uniform_modes(basis, eps_sup)
    k0 = 2 * np.pi / wl
    prevW, prevV = None, V_sub
    S = None
    for lay in layers:
        W, V, g = _layer_modes(basis, lay, px, py, factorization)
        Si = interface(prevW, prevV, W, V, n)
        S = Si if S is None else star(S, Si)
        S = propagate(S, np.exp(1j * g * (k0 * lay.d)[..., None]))
        prevW, prevV = W, V
    Si = interface(prevW, prevV, None, V_sup, n)
    S = Si if S is None else star(S, Si)
    return S


def _expand_full(basis: Basis, vec: np.ndarray):
    """Reduced E_t coordinates (..., nE, k) -> full (Ex, Ey) each (..., (2M+1)(2N+1), k)."""
    M, N = basis.M, basis.N
    out = []
    off = 0
    for f in ("Ex", "Ey"):
        sx, sy = basis.cls[f]
        nx, ny = len(orders(sx, M)), len(orders(sy, N))
        blk = vec[..., off:off + nx * ny, :]
        off += nx * ny
        if sx == "f" and sy == "f":
            out.append(blk)
            continue
        Bm = np.kron(rebuild(sx, M), rebuild(sy, N))
        out.append(Bm @ blk)
    return out


def _sp_vectors(kx, ky, phi):
    """Unit in-plane propagation direction k_par and s = z x k_par for each order (..., Q, 2)."""
    kt = np.hypot(kx, ky)
    safe = kt > 1e-12
    cx = np.where(safe, kx / np.where(safe, kt, 1), math.cos(phi))
    cy = np.where(safe, ky / np.where(safe, kt, 1), math.sin(phi))
    return (cx, cy), (-cy, cx)


@dataclass
class Result:
    """Diffraction amplitudes of one solve (leading axes: wavelength batch, squeezed if scalar).

    orders: (Q, 2) integer (m, n) of every retained order, m along x.
    kx, ky: (..., Q) normalised in-plane wave numbers; kz_sub, kz_sup: (..., Q) in each half-space.
    t, r: dict side -> (..., Q, 2 out, 2 in) power-normalised amplitudes ('p', 's'),
        side = 'substrate' (light enters from below, +z) or 'superstrate' (enters from above).
    T, R: dict side -> (..., Q, 2 in) efficiencies (summed over the output polarisation).
    """

    orders: np.ndarray
    kx: np.ndarray
    ky: np.ndarray
    kz_sub: np.ndarray
    kz_sup: np.ndarray
    t: dict
    r: dict
    T: dict
    R: dict
    n_substrate: np.ndarray
    n_superstrate: np.ndarray
    info: dict = field(default_factory=dict)

    @property
    def zero(self) -> int:
        return int(np.flatnonzero((self.orders[:, 0] == 0) & (self.orders[:, 1] == 0))[0])

    def t00(self, side: str = "substrate") -> np.ndarray:
        """(..., 2 out, 2 in) zero-order power-normalised Jones matrix in the (p, s) basis."""
        return self.t[check_choice("side", side, SIDES)][..., self.zero, :, :]

    def r00(self, side: str = "substrate") -> np.ndarray:
        return self.r[check_choice("side", side, SIDES)][..., self.zero, :, :]

    def t00_field(self, side: str = "substrate") -> np.ndarray:
        """Zero-order E-field ratio E_out/E_in at normal incidence (t * sqrt(n_in / n_out))."""
        n_in, n_out = ((self.n_substrate, self.n_superstrate) if side == "substrate"
                       else (self.n_superstrate, self.n_substrate))
        return self.t00(side) * np.sqrt(n_in / n_out)[..., None, None]

    def total_T(self, side: str = "substrate") -> np.ndarray:
        return self.T[side].sum(axis=-2)

    def total_R(self, side: str = "substrate") -> np.ndarray:
        return self.R[side].sum(axis=-2)


def _kz(eps, kx, ky):
    return branch(eps[..., None] - kx ** 2 - ky ** 2)


def _to_power(Ex, Ey, kx, ky, kz, n, phi):
    """Full-order transverse fields (..., Q, k) -> (a_p, a_s) power-normalised (..., Q, k)."""
    (px_, py_), (sx_, sy_) = _sp_vectors(kx, ky, phi)
    sq = np.sqrt(kz)
    a_s = (Ex * sx_[..., None] + Ey * sy_[..., None]) * sq[..., None]
    a_p = (Ex * px_[..., None] + Ey * py_[..., None]) * (n[..., None, None] / sq[..., None])
    return a_p, a_s


def _incident(kx0, ky0, kz0, n, phi):
    """E_t of unit power-normalised p and s waves at the zero order: (..., 2 comp, 2 pol)."""
    (px_, py_), (sx_, sy_) = _sp_vectors(kx0, ky0, phi)
    sq = np.sqrt(kz0)
    ep = np.stack([px_, py_], -1) * (sq / n)[..., None]
    es = np.stack([sx_, sy_], -1) / sq[..., None]
    return np.stack([ep, es], -1)


def _assemble(kind_results, M, N, kx_full, ky_full, eps_sub, eps_sup, phi):
    """Build a Result from per-basis S-matrices.

    kind_results: list of (basis, S, pols) where pols are the incident polarisation indices the
    basis carries (full: (0, 1); xpol: (0,); ypol: (1,)).
    """
    mm, nn = np.meshgrid(np.arange(-M, M + 1), np.arange(-N, N + 1), indexing="ij")
    ords = np.stack([mm.ravel(), nn.ravel()], 1)
    kx = kx_full[..., ords[:, 0] + M]
    ky = ky_full[..., ords[:, 1] + N]
    kz = {"substrate": _kz(eps_sub, kx, ky), "superstrate": _kz(eps_sup, kx, ky)}
    n_med = {"substrate": np.sqrt(eps_sub).real, "superstrate": np.sqrt(eps_sup).real}
    z0 = M * (2 * N + 1) + N
    Bshape = kx.shape[:-1]
    Q = ords.shape[0]
    t = {s: np.zeros(Bshape + (Q, 2, 2), complex) for s in SIDES}
    r = {s: np.zeros(Bshape + (Q, 2, 2), complex) for s in SIDES}
    for basis, S, pols in kind_results:
        S11, S12, S21, S22 = S
        for side in SIDES:
            other = "superstrate" if side == "substrate" else "substrate"
            Sr, St = (S11, S21) if side == "substrate" else (S22, S12)
            inc = _incident(kx[..., z0], ky[..., z0], kz[side][..., z0], n_med[side], phi)  # (...,2,2)
            # position of the zero order E_x / E_y in this basis' E coordinates
            e = np.zeros(Bshape + (basis.n, 2), complex)
            cEx = basis.cls["Ex"]
            nEx = basis.size["Ex"]
            ix = _pos00(cEx, M, N)
            iy = _pos00(basis.cls["Ey"], M, N)
            if ix is not None:
                e[..., ix, :] = inc[..., 0, :]
            if iy is not None:
                e[..., nEx + iy, :] = inc[..., 1, :]
            for out_side, Smat, amp in ((side, Sr, r), (other, St, t)):
                v = Smat @ e
                Ex, Ey = _expand_full(basis, v)
                a_p, a_s = _to_power(Ex, Ey, kx, ky, kz[out_side], n_med[out_side], phi)
                for p in pols:
                    amp[side][..., :, 0, p] = a_p[..., :, p]
                    amp[side][..., :, 1, p] = a_s[..., :, p]
    prop = {s: (np.abs(kz[s].imag) < 1e-10) & (kz[s].real > 1e-10) for s in SIDES}
    T, R = {}, {}
    for side in SIDES:
        other = "superstrate" if side == "substrate" else "substrate"
        T[side] = (np.abs(t[side]) ** 2).sum(-2) * prop[other][..., None]
        R[side] = (np.abs(r[side]) ** 2).sum(-2) * prop[side][..., None]
    return ords, kx, ky, kz, t, r, T, R


def _pos00(cl, M, N):
    sx, sy = cl
    if "o" in (sx, sy):
        return None
    ix = M if sx == "f" else 0
    iy = N if sy == "f" else 0
    ny = 2 * N + 1 if sy == "f" else N + 1
    return ix * ny + iy


def _harmonics(h) -> tuple[int, int]:
    if isinstance(h, (tuple, list)):
        if len(h) != 2:
            raise InputError("harmonics", h, "an integer M or a pair (M, N): orders |m| <= M, |n| <= N")
        return (check_int("harmonics", h[0], MIN_HARMONICS, MAX_HARMONICS),
                check_int("harmonics", h[1], MIN_HARMONICS, MAX_HARMONICS))
    m = check_int("harmonics", h, MIN_HARMONICS, MAX_HARMONICS)
    return m, m


def n_harmonics(harmonics) -> int:
    """Number of plane waves (2M+1)(2N+1) of a truncation."""
    M, N = _harmonics(harmonics)
    return (2 * M + 1) * (2 * N + 1)


#: core-seconds of one post at one wavelength at 10 harmonics (441 plane waves), and the cost's growth: the
#: eigenproblem is O((plane waves)^3). Measured: the 31 x 31 library in 35 s on 2 cores; one post at M = 14 / 18
#: took 2.6 / 12.2 s on one core (ratio 4.6 against 4.3 from the cube law); peak memory ~1.7 (2 x plane waves)^2
#: complex numbers per worker
SOLVE_CORE_S_M10, SOLVE_BYTES_PER_MODE2 = 0.073, 1.7 * 16


def solve_cost(harmonics, n_solves: int = 1) -> tuple[float, float]:
    """Estimated ``(core-seconds, peak bytes per worker)`` of ``n_solves`` post solves at ``harmonics``, to refuse
    a sweep that cannot finish before starting it."""
    pw = n_harmonics(harmonics)
    return n_solves * SOLVE_CORE_S_M10 * (pw / 441) ** 3, SOLVE_BYTES_PER_MODE2 * (2 * pw) ** 2


def solve(stack: Stack, wavelength_um, *, harmonics=8, theta_deg: float = 0.0, phi_deg: float = 0.0,
          incidence: str = "substrate", factorization: str = "li", symmetry: str = "auto",
          check_energy: bool = True) -> Result:
    """Solve a periodic stack for plane-wave incidence.

    Parameters
    ----------
    stack: the :class:`Stack` (layers bottom to top, substrate below).
    wavelength_um: vacuum wavelength (scalar or 1-D array: batched).
    harmonics: M or (M, N): Fourier orders |m| <= M along x, |n| <= N along y
        ((2M+1)(2N+1) plane waves; rectangular truncation, which Li's rules need).
    theta_deg, phi_deg: polar angle in the incidence medium and azimuth (from +x) of the incident
        wave vector. Both sides are always computed; ``incidence`` only fixes which medium
        ``theta_deg`` is measured in (the in-plane wave vector is ``n_inc sin(theta)``, shared by both).
    factorization: 'li' (Li's crossed-grating rules, default) or 'laurent' (plain Laurent rule,
        for comparison only: it converges slowly for Si/air).
    symmetry: 'auto' picks the parity-adapted bases exactly where they are valid: normal incidence
        (theta = 0, phi = 0) on a stack whose inclusions are all centred at the origin
        (:attr:`Stack.mirror_symmetric`, mirror planes x = 0 and y = 0). There x- and y-polarised light
        never mix and each is solved in a basis of even/odd harmonics about 4x smaller than the full one
        (two eigenproblems ~64x cheaper each; the same result to rounding). Every other case (oblique
        incidence, phi != 0, off-centre inclusions) takes the full basis. 'none' forces the full basis.
        ``Result.info['symmetric']`` says which path ran.
    check_energy: for lossless stacks, warn (:class:`NotConvergedWarning`) if R + T deviates from 1
        by more than 1e-6, which flags numerical breakdown.
    """
    if not isinstance(stack, Stack):
        raise InputError("stack", type(stack).__name__, "a metafovea.rcwa.Stack")
    M, N = _harmonics(harmonics)
    factorization = check_choice("factorization", factorization, FACTORIZATIONS)
    symmetry = check_choice("symmetry", symmetry, ("auto", "none"))
    incidence = check_choice("incidence", incidence, SIDES)
    wl = np.atleast_1d(np.asarray(wavelength_um, dtype=float))
    scalar = np.ndim(wavelength_um) == 0
    if wl.ndim != 1:
        raise InputError("wavelength_um", wavelength_um, "a positive number or 1-D array")
    for w in wl:
        check_positive("wavelength_um", w, "um")
    theta = math.radians(check_range("theta_deg", theta_deg, 0.0, 90.0, lo_inclusive=True, hi_inclusive=False))
    phi = math.radians(check_range("phi_deg", phi_deg, -360.0, 360.0, lo_inclusive=True))
    eps_sub = index_of("n_substrate", stack.n_substrate, wl) ** 2
    eps_sup = index_of("n_superstrate", stack.n_superstrate, wl) ** 2
    n_inc = np.sqrt(eps_sub if incidence == "substrate" else eps_sup).real
    kx0 = n_inc * math.sin(theta) * math.cos(phi)
    ky0 = n_inc * math.sin(theta) * math.sin(phi)
    px, py = stack.period_x, stack.period_y
    kx_full = kx0[:, None] + np.arange(-M, M + 1)[None, :] * (wl[:, None] / px)
    ky_full = ky0[:, None] + np.arange(-N, N + 1)[None, :] * (wl[:, None] / py)
    layers = []
    lossless = bool(np.all(np.abs(eps_sub.imag) == 0) and np.all(np.abs(eps_sup.imag) == 0))
    for j, lay in enumerate(stack.layers):
        eb = index_of(f"layers[{j}].n", lay.n, wl) ** 2
        lossless &= bool(np.all(eb.imag == 0))
        rect = None
        if lay.shapes:
            s = lay.shapes[0]
            ei = index_of(f"layers[{j}].shapes[0].n", s.n, wl) ** 2
            lossless &= bool(np.all(ei.imag == 0))
            rect = dict(eps_i=ei, wx=np.full(wl.shape, s.wx), wy=np.full(wl.shape, s.wy), cx=s.cx, cy=s.cy)
        layers.append(_LayerData(np.full(wl.shape, lay.thickness), eb, rect))
    use_sym = symmetry == "auto" and theta == 0.0 and phi == 0.0 and stack.mirror_symmetric
    kinds = [("xpol", (0,)), ("ypol", (1,))] if use_sym else [("full", (0, 1))]
    results = []
    for kind, pols in kinds:
        basis = Basis(kind, M, N, kx_full, ky_full)
        S = _smatrix(basis, wl, eps_sub, eps_sup, layers, px, py, factorization)
        results.append((basis, S, pols))
    ords, kx, ky, kz, t, r, T, R = _assemble(results, M, N, kx_full, ky_full, eps_sub, eps_sup, phi)
    res = Result(ords, kx, ky, kz["substrate"], kz["superstrate"], t, r, T, R,
                 np.sqrt(eps_sub).real, np.sqrt(eps_sup).real,
                 info=dict(harmonics=(M, N), factorization=factorization, symmetric=use_sym, lossless=lossless))
    if check_energy and lossless:
        for side in SIDES:
            tot = T[side].sum(-2) + R[side].sum(-2)
            err = float(np.max(np.abs(tot - 1)))
            res.info[f"energy_error_{side}"] = err
            if err > 1e-6:
                warnings.warn(f"RCWA energy balance violated (|R+T-1| = {err:.2e}, incidence from the "
                              f"{side}): the result is numerically unreliable", NotConvergedWarning, stacklevel=2)
    if scalar:
        res = _squeeze(res)
    return res


def _squeeze(res: Result) -> Result:
    def sq(a):
        return a[0]

    return Result(res.orders, sq(res.kx), sq(res.ky), sq(res.kz_sub), sq(res.kz_sup),
                  {k: sq(v) for k, v in res.t.items()}, {k: sq(v) for k, v in res.r.items()},
                  {k: sq(v) for k, v in res.T.items()}, {k: sq(v) for k, v in res.R.items()},
                  sq(res.n_substrate), sq(res.n_superstrate), res.info)

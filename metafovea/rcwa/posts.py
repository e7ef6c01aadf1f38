"""Fast, batched zero-order response of rectangular posts (the scatterer-library workhorse).

Platform geometry (see README / DESIGN): a single layer of height ``h`` holding a centred
``wx x wy`` post of index ``n_post`` surrounded by ``n_surround`` (air), on a substrate
``n_substrate`` (Si wafer, below) with ``n_superstrate`` (air) above. Square lattice of period p.

Entry side. The default ``incidence='substrate'`` has light arrive through the wafer and leave the
posts into air (posts facing the sensor). With p = 4 um, lambda = 10 um only the zero order
propagates in air, so all transmitted power is in the zero order; the first orders (+-1,0),
(0,+-1) propagate in Si (p > lambda/n_Si) and only appear in reflection, where they are
reported as ``other``. With ``incidence='superstrate'`` (posts facing the scene) the first orders are
transmitted into the wafer at ~47 deg, beyond the Si/air critical angle: that power is trapped and
lost to imaging, reported in ``other`` as well.

Reference planes: the phase of ``t`` is that of the transmitted zero order at the exit face of the
post layer relative to the incident wave at the entry face (the layer faces, z = 0 and z = h).
``t`` is power normalised (``|t|^2`` is the zero-order efficiency; ``t_field = t sqrt(n_in/n_out)``).

Symmetry. At normal incidence a centred rectangle has mirror planes x = 0 and y = 0, so x- and y-
polarised light live in separate parity classes (no cross-polarisation, exactly); each class is
solved in a parity-adapted basis about 4x smaller than the full one. And ``t_yy(wx, wy) =
t_xx(wy, wx)`` (90-degree rotation), so y is computed as x of the swapped post.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from metafovea.config import PAPER_PERIOD_UM, PAPER_POST_HEIGHT_UM, PAPER_WAVELENGTH_UM
from metafovea.errors import InputError, NotConvergedWarning, check_choice, check_int, check_positive
from metafovea.materials import AIR, SILICON, IndexLike, index_of
from metafovea.rcwa.basis import Basis
from metafovea.rcwa.solve import FACTORIZATIONS, MAX_HARMONICS, SIDES, _LayerData

log = logging.getLogger(__name__)

#: smallest truncation accepted for a post response (below it the phase error exceeds 0.1 rad)
MIN_POST_HARMONICS = 3


@dataclass
class PostResponse:
    """Zero-order response of posts; all arrays share the broadcast shape of (wx, wy, wavelength).

    t_x, t_y: power-normalised zero-order co-polarised transmission for x- and y-polarised light.
    T_x, T_y: zero-order transmitted efficiency |t|^2.
    R_x, R_y: total reflected efficiency (all orders).
    other_x, other_y: efficiency in all orders other than the transmitted zero order and the
        reflected zero order (substrate/air diffraction), i.e. 1 - T - R00 for lossless posts.
    err_x, err_y: the difference |t(M) - t(M - 2)| (NaN if not computed). Not a bound: against a harmonics-22
        reference it understates the error for ~60 % of random posts; :func:`convergence_bound` is one.
    """

    wx_um: np.ndarray
    wy_um: np.ndarray
    wavelength_um: np.ndarray
    t_x: np.ndarray
    t_y: np.ndarray
    T_x: np.ndarray
    T_y: np.ndarray
    R_x: np.ndarray
    R_y: np.ndarray
    other_x: np.ndarray
    other_y: np.ndarray
    err_x: np.ndarray
    err_y: np.ndarray
    info: dict = field(default_factory=dict)


def _check_widths(name, w, period):
    w = np.asarray(w, dtype=float)
    if not np.all(np.isfinite(w)) or np.any(w <= 0) or np.any(w >= period):
        bad = w[~(np.isfinite(w) & (w > 0) & (w < period))]
        raise InputError(name, bad.ravel()[:5].tolist(), f"0 < {name} < period_um = {period:g} um")
    return w


class _RowSparse:
    """A batch of matrices with at most a few non-zeros per row, ``(B, n, n)`` -> ``(B, n, k)`` values and the
    ``(n, k)`` column of each (the half-space operators ``V = Q / gamma``: each row of Q couples at most two
    coordinates). ``self @ X`` costs O(k n^2) against the O(n^3) of a dense product."""

    def __init__(self, A: np.ndarray):
        nz = np.any(A != 0, axis=tuple(range(A.ndim - 2)))
        k = max(1, int(nz.sum(-1).max()))
        self.cols = np.argsort(~nz, axis=-1, kind="stable")[:, :k]
        self.vals = np.take_along_axis(A, np.broadcast_to(self.cols, A.shape[:-2] + self.cols.shape), axis=-1)

    def __matmul__(self, X: np.ndarray) -> np.ndarray:
        out = self.vals[..., 0, None] * X[..., self.cols[:, 0], :]
        for j in range(1, self.cols.shape[1]):
            out += self.vals[..., j, None] * X[..., self.cols[:, j], :]
        return out


def _single_layer(basis: Basis, W, V, g, d_k0, V_in, V_out, e_in):
    """Reflected and transmitted E_t (reduced coordinates) of one layer between two half-spaces.

    Direct, stable elimination (only exp(+i gamma k0 d) with |.| <= 1 appears):
    c- = rho phi c+ with rho = (V + V_out W)^-1 (V - V_out W) at the exit face, then
    [(V_in W + V) + (V_in W - V) phi rho phi] c+ = 2 V_in e_in at the entry face.
    About a quarter of the cost of building the full S-matrix with star products. ``V_in`` and ``V_out`` are
    :class:`_RowSparse` (or dense) half-space operators.
    """
    phi = np.exp(1j * g * d_k0[..., None])
    VoW = V_out @ W
    rho = np.linalg.solve(V + VoW, V - VoW)
    ViW = V_in @ W
    A = (ViW + V) + (ViW - V) @ (phi[..., :, None] * rho * phi[..., None, :])
    rhs = 2.0 * (V_in @ e_in)
    cp = np.linalg.solve(A, rhs)
    cm = rho @ (phi[..., :, None] * cp)
    r = W @ (cp + phi[..., :, None] * cm) - e_in
    t = W @ (phi[..., :, None] * cp + cm)
    return r, t


@lru_cache(maxsize=64)
def _expansion(M: int, N: int) -> tuple[np.ndarray, np.ndarray]:
    """Full-order (Ex, Ey) from the x-polarised parity basis' E coordinates: two ((2M+1)(2N+1), nE) matrices."""
    from metafovea.rcwa.basis import CLASSES
    from metafovea.rcwa.fourier import orders, rebuild
    cls = CLASSES["xpol"]
    sizes = [len(orders(cls[f][0], M)) * len(orders(cls[f][1], N)) for f in ("Ex", "Ey")]
    out = []
    off = 0
    for f, n in zip(("Ex", "Ey"), sizes):
        B = np.zeros(((2 * M + 1) * (2 * N + 1), sum(sizes)))
        B[:, off:off + n] = np.kron(rebuild(cls[f][0], M), rebuild(cls[f][1], N))
        off += n
        out.append(B)
    return out[0], out[1]


@lru_cache(maxsize=32)
def _xpol_basis(Mx: int, My: int, wavelengths: bytes, period: float) -> Basis:
    """The x-polarised parity basis at normal incidence for a chunk's wavelengths (float64 bytes), kept between
    calls: a library sweep or a benchmark solves many chunks at the same wavelengths, and building the basis is
    about a tenth of a small solve. Read-only by its users."""
    w = np.frombuffer(wavelengths, dtype=float)
    kx = np.arange(-Mx, Mx + 1)[None, :] * (w[:, None] / period)
    ky = np.arange(-My, My + 1)[None, :] * (w[:, None] / period)
    return Basis("xpol", Mx, My, kx, ky)


def _zero_order_x(wx, wy, wl, *, period, height, eps_post, eps_fill, eps_sub, eps_sup, M, factorization,
                  incidence, chunk):
    """x-polarised zero-order response for flat arrays wx, wy, wl (same length); ``M`` is (Mx, My)."""
    from metafovea.rcwa.solve import _incident, _kz, _layer_modes, _to_power, _uniform_modes
    Mx, My = M
    n_tot = wx.shape[0]
    t = np.empty(n_tot, complex)
    T = np.empty(n_tot)
    R = np.empty(n_tot)
    other = np.empty(n_tot)
    ev = np.empty(n_tot)
    z0 = Mx * (2 * My + 1) + My
    mx, my = np.arange(-Mx, Mx + 1), np.arange(-My, My + 1)
    Bx, By = _expansion(Mx, My)
    for a in range(0, n_tot, chunk):
        sl = slice(a, min(n_tot, a + chunk))
        w = wl[sl]
        kx = mx[None, :] * (w[:, None] / period)
        ky = my[None, :] * (w[:, None] / period)
        basis = _xpol_basis(Mx, My, w.tobytes(), period)
        e_in_, e_out_ = (eps_sub[sl], eps_sup[sl]) if incidence == "substrate" else (eps_sup[sl], eps_sub[sl])
        lay = _LayerData(np.full(w.shape, height), eps_fill[sl],
                         dict(eps_i=eps_post[sl], wx=wx[sl], wy=wy[sl], cx=0.0, cy=0.0))
        W, V, g = _layer_modes(basis, lay, period, period, factorization)
        V_in = _RowSparse(_uniform_modes(basis, e_in_)[1])
        V_out = _RowSparse(_uniform_modes(basis, e_out_)[1])
        if W is None:
            W = np.broadcast_to(np.eye(basis.n), V.shape)
        kxo = kx[:, np.repeat(mx + Mx, 2 * My + 1)]
        kyo = ky[:, np.tile(my + My, 2 * Mx + 1)]
        kz_in, kz_out = _kz(e_in_, kxo, kyo), _kz(e_out_, kxo, kyo)
        n_in, n_out = np.sqrt(e_in_).real, np.sqrt(e_out_).real
        inc = _incident(kxo[:, z0], kyo[:, z0], kz_in[:, z0], n_in, 0.0)  # (B, 2 comp, 2 pol)
        e = np.zeros((w.shape[0], basis.n, 1), complex)
        e[:, 0, 0] = inc[:, 0, 0]   # E_x of the (0,0) order is coordinate 0 of the xpol basis
        r_v, t_v = _single_layer(basis, W, V, g, 2 * np.pi / w * height, V_in, V_out, e)
        res = {}
        for name, v, kz, nn in (("r", r_v, kz_in, n_in), ("t", t_v, kz_out, n_out)):
            a_p, a_s = _to_power(Bx @ v, By @ v, kxo, kyo, kz, nn, 0.0)
            prop = (np.abs(kz.imag) < 1e-10) & (kz.real > 1e-10)
            res[name] = (a_p[..., 0], (np.abs(a_p[..., 0]) ** 2 + np.abs(a_s[..., 0]) ** 2) * prop)
        t[sl] = res["t"][0][:, z0]
        T[sl] = res["t"][1][:, z0]
        R[sl] = res["r"][1].sum(-1)
        Ttot = res["t"][1].sum(-1)
        other[sl] = Ttot - T[sl] + R[sl] - res["r"][1][:, z0]
        ev[sl] = np.abs(Ttot + R[sl] - 1)
    return t, T, R, other, ev


#: factor of :func:`convergence_bound`, set on 96 random posts against a harmonics-22 reference (M = 8, 10, 12)
BOUND_FACTOR = 3.0


def convergence_bound(t_m: np.ndarray, t_m2: np.ndarray, t_m4: np.ndarray) -> np.ndarray:
    """A bound on |t(M) - t(converged)|: ``BOUND_FACTOR * max(|t(M) - t(M-2)|, |t(M) - t(M-4)|)``.

    Against a harmonics-22 reference on 96 random posts of the paper's platform (0.5-3.5 um sides) it holds for
    99 % (M = 10), 100 % (M = 8) and 97 % (M = 12) of the posts; |t(M) - t(M-2)| alone holds for 38 % at M = 10
    (the convergence of Li's rule is not monotone near the posts' resonances). Tested in
    ``tests/rcwa/test_posts.py`` on posts drawn there."""
    a = np.abs(np.asarray(t_m) - np.asarray(t_m2))
    b = np.abs(np.asarray(t_m) - np.asarray(t_m4))
    return BOUND_FACTOR * np.maximum(a, b)


def post_response(wx_um, wy_um, wavelength_um=PAPER_WAVELENGTH_UM, *, period_um: float = PAPER_PERIOD_UM,
                  height_um: float = PAPER_POST_HEIGHT_UM, n_post: IndexLike = SILICON, n_surround: IndexLike = AIR,
                  n_substrate: IndexLike = SILICON, n_superstrate: IndexLike = AIR,
                  harmonics: int | tuple[int, int] = 8, factorization: str = "li", incidence: str = "substrate",
                  estimate: bool = False, tol: float | None = None, polarizations: tuple[str, ...] = ("x", "y"),
                  chunk: int = 32) -> PostResponse:
    """Zero-order transmission of centred rectangular posts at normal incidence (batched).

    wx_um, wy_um, wavelength_um broadcast together. ``harmonics`` is M (orders |m|, |n| <= M,
    (2M+1)^2 plane waves; in the parity basis the eigenproblem has (M+1)^2 + M^2 unknowns), or a pair
    ``(M_along, M_across)``: orders up to M_along along the incident E-field and M_across across it (x then y
    for x-polarised light, y then x for y-polarised light; (M_along + 1)(M_across + 1) + M_along M_across
    unknowns). The field along E jumps across the post's side walls normal to it (the inverse rule's
    direction) and converges slowest, so for most posts a pair such as (10, 5) reaches the accuracy of M = 8
    with fewer unknowns; the worst post of a library does not gain (its error is not set by that direction
    alone), so the square truncation stays the default and the library's (figures in BENCHMARKS.md).
    ``estimate`` also solves at M - 2 (both entries of a pair) and returns ``err = |t(M) - t(M-2)|``, the step
    between truncations (not a bound on the error: convergence is not monotone, see :func:`convergence_bound`);
    with ``tol`` a :class:`NotConvergedWarning` names the posts whose step exceeds it.

    Symmetry: a centred rectangle at normal incidence has the mirror planes x = 0 and y = 0, so x- and
    y-polarised light never mix and each is solved in its own parity-adapted basis (even/odd harmonics, 4x
    fewer unknowns than the full plane-wave basis: the same numbers as :func:`metafovea.rcwa.solve` with
    ``symmetry='none'`` to rounding, tested in tests/rcwa/test_posts.py); y-polarised light is solved as
    x-polarised light on the post turned by 90 degrees. Geometries without these mirror planes (off-centre
    inclusions, oblique incidence) go through :func:`metafovea.rcwa.solve`, which picks the full basis for them.
    """
    period = check_positive("period_um", period_um, "um")
    height = check_positive("height_um", height_um, "um")
    lo = MIN_POST_HARMONICS + (2 if estimate else 0)
    if isinstance(harmonics, (tuple, list)):
        if len(harmonics) != 2:
            raise InputError("harmonics", harmonics, "an integer M or a pair (M_along, M_across)")
        Mp = (check_int("harmonics", harmonics[0], lo, MAX_HARMONICS),
              check_int("harmonics", harmonics[1], lo, MAX_HARMONICS))
    else:
        Mp = (check_int("harmonics", harmonics, lo, MAX_HARMONICS),) * 2
    M = Mp[0] if Mp[0] == Mp[1] else Mp
    factorization = check_choice("factorization", factorization, FACTORIZATIONS)
    incidence = check_choice("incidence", incidence, SIDES)
    pols = tuple(check_choice("polarizations", p, ("x", "y")) for p in polarizations)
    wl = np.asarray(wavelength_um, dtype=float)
    if not np.all(np.isfinite(wl)) or np.any(wl <= 0):
        raise InputError("wavelength_um", wl.ravel()[:5].tolist(), "positive wavelengths (um)")
    wx = _check_widths("wx_um", wx_um, period)
    wy = _check_widths("wy_um", wy_um, period)
    if tol is not None:
        tol = check_positive("tol", tol)
        estimate = True
    shape = np.broadcast_shapes(wx.shape, wy.shape, wl.shape)
    wxf, wyf, wlf = (np.broadcast_to(a, shape).ravel() for a in (wx, wy, wl))
    eps = {}
    for name, val in (("n_post", n_post), ("n_surround", n_surround), ("n_substrate", n_substrate),
                      ("n_superstrate", n_superstrate)):
        eps[name] = index_of(name, val, wlf) ** 2
    for name in ("n_substrate", "n_superstrate"):
        if np.any(eps[name].imag != 0):
            raise InputError(name, "complex", "a real (lossless) half-space index")
    kw = dict(period=period, height=height, eps_post=eps["n_post"], eps_fill=eps["n_surround"],
              eps_sub=eps["n_substrate"], eps_sup=eps["n_superstrate"], factorization=factorization,
              incidence=incidence, chunk=max(1, int(chunk)))
    out: dict[str, np.ndarray] = {}
    nan = np.full(wxf.shape, np.nan)
    energy = 0.0
    lossless = all(np.all(e.imag == 0) for e in eps.values())
    for pol in ("x", "y"):
        if pol not in pols:
            for k in ("t", "T", "R", "other", "err"):
                out[f"{k}_{pol}"] = nan.astype(complex) if k == "t" else nan
            continue
        a, b = (wxf, wyf) if pol == "x" else (wyf, wxf)
        t, T, R, other, ev = _zero_order_x(a, b, wlf, M=Mp, **kw)
        energy = max(energy, float(ev.max(initial=0.0)))
        err = nan
        if estimate:
            t_lo = _zero_order_x(a, b, wlf, M=(Mp[0] - 2, Mp[1] - 2), **kw)[0]
            err = np.abs(t - t_lo)
        out.update({f"t_{pol}": t, f"T_{pol}": T, f"R_{pol}": R, f"other_{pol}": other, f"err_{pol}": err})
    if lossless and energy > 1e-6:
        warnings.warn(f"post_response: energy balance violated by {energy:.2e}", NotConvergedWarning, stacklevel=2)
    res = PostResponse(np.broadcast_to(wx, shape), np.broadcast_to(wy, shape), np.broadcast_to(wl, shape),
                       **{k: v.reshape(shape) for k, v in out.items()},
                       info=dict(harmonics=M, factorization=factorization, incidence=incidence,
                                 period_um=period, height_um=height, energy_error=energy if lossless else None))
    if tol is not None:
        worst = np.nanmax(np.stack([np.nan_to_num(res.err_x, nan=0.0), np.nan_to_num(res.err_y, nan=0.0)]))
        res.info["max_error_estimate"] = float(worst)
        if worst > tol:
            n_bad = int(np.sum((np.nan_to_num(res.err_x) > tol) | (np.nan_to_num(res.err_y) > tol)))
            warnings.warn(f"post_response not converged to tol={tol:g}: {n_bad} post(s) have an estimated "
                          f"error up to {worst:.3g} at M={M}; increase harmonics", NotConvergedWarning,
                          stacklevel=2)
    return res

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
from typing import Any

import numpy as np

from metafovea.errors import InputError, NotConvergedWarning, check_choice, check_int, check_positive
from metafovea.materials import AIR, SILICON, IndexLike, index_of
from metafovea.rcwa.basis import Basis
from metafovea.rcwa.solve import (FACTORIZATIONS, SIDES, MAX_HARMONICS, _assemble, _LayerData, _smatrix)

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
    err_x, err_y: convergence estimate |t(M) - t(M - 2)| (NaN if not computed).
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


def _zero_order_x(wx, wy, wl, *, period, height, eps_post, eps_fill, eps_sub, eps_sup, M, factorization,
                  incidence, chunk):
    """x-polarised zero-order response for flat arrays wx, wy, wl (same length)."""
    n_tot = wx.shape[0]
    t = np.empty(n_tot, complex)
    T = np.empty(n_tot)
    R = np.empty(n_tot)
    other = np.empty(n_tot)
    ev = np.empty(n_tot)
    for a in range(0, n_tot, chunk):
        sl = slice(a, min(n_tot, a + chunk))
        w = wl[sl]
        kx = np.arange(-M, M + 1)[None, :] * (w[:, None] / period)
        basis = Basis("xpol", M, M, kx, kx)
        lay = _LayerData(np.full(w.shape, height), eps_fill[sl],
                         dict(eps_i=eps_post[sl], wx=wx[sl], wy=wy[sl], cx=0.0, cy=0.0))
        S = _smatrix(basis, w, eps_sub[sl], eps_sup[sl], [lay], period, period, factorization)
        ords, _, _, _, tt, rr, TT, RR = _assemble([(basis, S, (0,))], M, M, kx, kx, eps_sub[sl], eps_sup[sl], 0.0)
        z0 = M * (2 * M + 1) + M
        t[sl] = tt[incidence][:, z0, 0, 0]
        T[sl] = TT[incidence][:, z0, 0]
        R[sl] = RR[incidence][:, :, 0].sum(-1)
        other[sl] = TT[incidence][:, :, 0].sum(-1) - T[sl] + R[sl] - RR[incidence][:, z0, 0]
        ev[sl] = np.abs(TT[incidence][:, :, 0].sum(-1) + R[sl] - 1)
    return t, T, R, other, ev


def post_response(wx_um, wy_um, wavelength_um=10.0, *, period_um: float = 4.0, height_um: float = 10.0,
                  n_post: IndexLike = SILICON, n_surround: IndexLike = AIR, n_substrate: IndexLike = SILICON,
                  n_superstrate: IndexLike = AIR, harmonics: int = 8, factorization: str = "li",
                  incidence: str = "substrate", estimate: bool = False, tol: float | None = None,
                  polarizations: tuple[str, ...] = ("x", "y"), chunk: int = 32) -> PostResponse:
    """Zero-order transmission of centred rectangular posts at normal incidence (batched).

    wx_um, wy_um, wavelength_um broadcast together. ``harmonics`` is M (orders |m|, |n| <= M,
    (2M+1)^2 plane waves; in the parity basis the eigenproblem has (M+1)^2 + M^2 unknowns).
    ``estimate`` also solves at M - 2 and returns ``err = |t(M) - t(M-2)|`` (a conservative
    estimate of the truncation error for Li's rule, whose error decays like M^-2..M^-2.5); with
    ``tol`` a :class:`NotConvergedWarning` names the posts whose estimate exceeds it.
    """
    period = check_positive("period_um", period_um, "um")
    height = check_positive("height_um", height_um, "um")
    M = check_int("harmonics", harmonics, MIN_POST_HARMONICS + (2 if estimate else 0), MAX_HARMONICS)
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
        t, T, R, other, ev = _zero_order_x(a, b, wlf, M=M, **kw)
        energy = max(energy, float(ev.max(initial=0.0)))
        err = nan
        if estimate:
            t_lo = _zero_order_x(a, b, wlf, M=M - 2, **kw)[0]
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

"""Rayleigh-Sommerfeld engines for the focusing order over the true (hard-edged) lens aperture.

The direction-sine engines of :mod:`metafovea.optics.propagate` evaluate the angular spectrum of the lens by
stationary phase and cut it at the pupil disk. On axis that is exact for the paper's lenses; off axis it
misses part of the diffraction of the aperture edge (0.6-5 % of the peak at 1-5 deg field for the F/2 and
F/1 lenses). The engines here integrate the first Rayleigh-Sommerfeld formula over the aperture itself,

    U(x) = int_{|rho| <= a} t(rho) exp(i k s0.rho) (z / (i lambda r^2)) (1 - 1 / (i k r)) exp(i k r) d^2 rho,
    r = |(x - rho, z)|,

with the order's lens field ``t(rho) = c_m L(rho) exp(i m [-k0 (sqrt(rho^2 + f0^2) - f0) + psi(rho)])`` (``c_m`` the
order coefficient, ``L`` the lattice factor of :mod:`metafovea.optics.pupil`, taken at the local phase gradient;
``psi`` the phase a design adds to the hyperbola, ``LensDesign.phase_poly_rad``, zero for the plain hyperbola):
the same thin-element lens as the pupil model, without the stationary-phase step. ``psi`` enters the integrands
and the ray directions that set the node counts (its slope adds to the residual phase slope), nothing else.
Conventions: um, ``exp(-i omega t)``, arrays ``(H, W)`` with row = y.

``rs_field``      the windowed exact engine. The output window is cut into blocks; for the block centred at
                  ``x_b`` the aperture is parametrised by the direction sines ``n`` of the line from the
                  aperture point to ``x_b`` (``rho = x_b - z n / sqrt(1 - |n|^2)``). In these variables the
                  lens' spherical phase cancels the kernel's (what is left is the aberration, so the node count
                  is set by the aberration and the window, not by the 300-500 Fresnel zones), the hard edge is
                  the boundary of the domain (an oval: rows of constant ``n_y`` with their exact ends, Gauss
                  nodes on each), and the kernel across the block is ``exp(i k n.delta)`` times a quadratic
                  Taylor factor in the offset ``delta`` (phase and amplitude), so each block is six separable
                  matrix Fourier sums. Errors: the quadrature rule's (nodes from the phase slope) plus the
                  Taylor remainder, evaluated at every block's corners and edge midpoints against the exact
                  kernel (x 2); blocks whose share exceeds the budget are split (down to single samples,
                  where no Taylor factor is used).
``rs_reference``  the brute-force reference: polar quadrature over the aperture, Gauss-Legendre per Fresnel zone
                  of the lens phase radially and the trapezoidal rule azimuthally (nodes from the phase slope
                  along each zone's outer ring), the exact kernel at every node and output point. Seconds for a
                  few hundred output points of a lens a few mm across; minutes for the paper's lenses. For tests
                  and benchmarks.

Not modelled by either (as by the pupil model): vector effects, the coupling between neighbouring posts
beyond the library's periodic approximation, the other diffraction orders (haze, :mod:`pupil`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy import special

from metafovea.parallel import StoppableThreadPool, blas_threads

from .propagate import _gl, mft_field, nodes_for_phase
from .pupil import Pupil, ray_map_monotone

#: Safety factor on the evaluated Taylor remainder (it is a smooth, mostly cubic function of the offset: its
#: largest value between the probes exceeds the largest probe by well under this).
TAYLOR_SAFETY = 2.0
#: Side (samples) of the blocks the planner starts from, and the smallest block.
BLOCK_PLAN, BLOCK_MIN = 128, 1


def _added(lens: Any, rho: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(psi, g / rho) at radii rho: the added phase as the focusing order carries it (rad; ``-phase_sign`` times the
    design's, like the hyperbola) and the design direction sine per radius (1/um) of the full phase."""
    from metafovea.lens import added_phase, direction_sine_over_r  # lens stage (rank 3): allowed

    return -lens.phase_sign * added_phase(lens, rho), direction_sine_over_r(lens, rho)


# ----------------------------------------------------------------------------------------------
# the aperture in the direction sines towards a block centre
# ----------------------------------------------------------------------------------------------
def _rim_n(a: float, xb: float, yb: float, z: float, phi: np.ndarray | float) -> tuple[Any, Any]:
    mx = xb - a * np.cos(phi)
    my = yb - a * np.sin(phi)
    r = np.sqrt(mx * mx + my * my + z * z)
    return mx / r, my / r


def _extreme_phi(a: float, xb: float, yb: float, z: float, sign: float) -> float:
    """Rim angle where n_y is largest (sign +1) or smallest (-1): dense scan, then golden section."""
    m = 1024
    ph = np.linspace(0.0, 2 * np.pi, m, endpoint=False)
    i = int(np.argmax(sign * _rim_n(a, xb, yb, z, ph)[1]))
    lo, hi = ph[i] - 2 * np.pi / m, ph[i] + 2 * np.pi / m
    g = (math.sqrt(5.0) - 1.0) / 2.0
    for _ in range(64):
        c, d = hi - g * (hi - lo), lo + g * (hi - lo)
        if sign * _rim_n(a, xb, yb, z, c)[1] > sign * _rim_n(a, xb, yb, z, d)[1]:
            hi = d
        else:
            lo = c
    return 0.5 * (lo + hi)


def _row_ends(a: float, xb: float, yb: float, z: float, v: np.ndarray, p0: float, p1: float) -> np.ndarray:
    """n_x where the row n_y = v meets the rim on the branch of rim angles p0 -> p1 (n_y monotonic): bisection."""
    inc = _rim_n(a, xb, yb, z, p1)[1] > _rim_n(a, xb, yb, z, p0)[1]
    lo = np.full(v.shape, p0)
    hi = np.full(v.shape, p1)
    for _ in range(56):
        mid = 0.5 * (lo + hi)
        f = _rim_n(a, xb, yb, z, mid)[1] - v
        up = (f < 0) if inc else (f > 0)
        lo = np.where(up, mid, lo)
        hi = np.where(up, hi, mid)
    return _rim_n(a, xb, yb, z, 0.5 * (lo + hi))[0]


def aperture_nodes(pupil: Pupil, xb: float, yb: float, n_t: int, n_r: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, np.ndarray]:
    """Gauss nodes of the aperture in direction sines towards (xb, yb): u (n_t, n_r), v (n_t,), weights, b, half.

    Rows ``v = v_c + b sin t`` (t Gauss-Legendre on [-pi/2, pi/2]) between the oval's extremes; on each row
    ``u`` Gauss-Legendre between the row's two rim crossings (half-widths ``half`` (n_t,)). The chord length goes
    like cos t at the extremes, so the weights are smooth and the hard edge costs nothing.
    """
    a, z = pupil.lens.radius_um, pupil.z_um
    pmax = _extreme_phi(a, xb, yb, z, 1.0)
    pmin = _extreme_phi(a, xb, yb, z, -1.0)
    vmax = float(_rim_n(a, xb, yb, z, pmax)[1])
    vmin = float(_rim_n(a, xb, yb, z, pmin)[1])
    xt, wt = _gl(n_t)
    xr, wr = _gl(n_r)
    t = 0.5 * np.pi * xt
    vc, b = 0.5 * (vmax + vmin), 0.5 * (vmax - vmin)
    v = vc + b * np.sin(t)
    p1 = pmax if pmax > pmin else pmax + 2 * np.pi
    ua = _row_ends(a, xb, yb, z, v, pmin, p1)
    ub = _row_ends(a, xb, yb, z, v, p1, pmin + 2 * np.pi)
    lo, hi = np.minimum(ua, ub), np.maximum(ua, ub)
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    u = mid[:, None] + half[:, None] * xr[None, :]
    w = (0.5 * np.pi * b * np.cos(t) * wt * half)[:, None] * wr[None, :]
    return u, v, w, b, half


def _integrand(pupil: Pupil, xb: float, yb: float, u: np.ndarray, v: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(h, R, gu, gv): the integrand at delta = 0 (Jacobian included, weights not), the distance aperture point ->
    block centre, and the phase gradient in (u, v) (for the node rule)."""
    lens = pupil.lens
    z, f, k = pupil.z_um, lens.f_um, pupil.k
    km = 2 * np.pi / lens.wavelength_um * pupil.order
    vv = np.broadcast_to(v[:, None], u.shape)
    c = np.sqrt(1.0 - u * u - vv * vv)
    R = z / c
    px, py = xb - R * u, yb - R * vv
    L = np.sqrt(px * px + py * py + f * f)
    theta = -km * (L - f) + k * (pupil.s0[0] * px + pupil.s0[1] * py) + k * R
    if lens.phase_poly_rad:  # the added phase, and the direction sine g of the full phase (g / rho = hx)
        psi, hx = _added(lens, np.sqrt(px * px + py * py))
        theta = theta + pupil.order * psi
        wx, wy = px * hx, py * hx
    amp: complex | np.ndarray = pupil.amplitude_factor
    if pupil.lattice:
        q = lens.period_um / lens.wavelength_um * pupil.order
        if lens.phase_poly_rad:
            amp = amp * np.sinc(q * wx) * np.sinc(q * wy)
        else:
            amp = amp * np.sinc(q * px / L) * np.sinc(q * py / L)
    kernel = z / (1j * pupil.wavelength_um * R * R) * (1.0 - 1.0 / (1j * k * R))
    h = amp * kernel * (z * z / c ** 4) * np.exp(1j * theta)
    # d theta / d n = k z J (n - s_ray), J = I / c + n n^T / c^3, s_ray the ray direction leaving rho
    if lens.phase_poly_rad:
        du = u - (pupil.s0[0] - km / k * wx)
        dv = vv - (pupil.s0[1] - km / k * wy)
    else:
        du = u - (pupil.s0[0] - km / k * px / L)
        dv = vv - (pupil.s0[1] - km / k * py / L)
    nd = u * du + vv * dv
    return h, R, k * z * (du / c + u * nd / c ** 3), k * z * (dv / c + vv * nd / c ** 3)


def _taylor_coefficients(k: float, z: float, R: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coefficients of the kernel's quadratic Taylor factor in the offset: ``1 + l1 n.d + l2 |d|^2 + l3 (n.d)^2``
    (after the node-independent phase ``k |d|^2 / (2 z)`` is taken out)."""
    l1 = -2.0 / R + 1.0 / (1j * k * R * R * (1.0 - 1.0 / (1j * k * R)))
    l2 = 1j * k / (2 * R) - 1.0 / (R * R) - 1j * k / (2 * z)
    l3 = -1j * k / (2 * R) + 2.0 / (R * R)
    return l1, l2, l3


def _taylor_remainder(k: float, z: float, R: np.ndarray, u: np.ndarray, vv: np.ndarray, h: np.ndarray,
                      l1: np.ndarray, l2: np.ndarray, l3: np.ndarray, dxs: np.ndarray, dys: np.ndarray,
                      Ep: np.ndarray, Ey: np.ndarray) -> float:
    """Largest |sum h exp(i k n.d) (exact kernel factor - Taylor factor)| over the block's corners, edge midpoints
    (samples 0, middle, last of each side); ``Ep``: exp(i k u dx_m) at those columns, ``Ey``: exp(i k v dy_l)."""
    mx = sorted({0, (dxs.size - 1) // 2, dxs.size - 1})
    my = sorted({0, (dys.size - 1) // 2, dys.size - 1})
    R2 = R * R
    inv = 1.0 / (1.0 - 1.0 / (1j * k * R))
    worst = 0.0
    for im, m in enumerate(mx):
        for l in my:
            dx, dy = float(dxs[m]), float(dys[l])
            if abs(dx) + abs(dy) == 0.0:
                continue
            nd = u * dx + vv * dy
            d2 = dx * dx + dy * dy
            r2 = R2 + 2 * R * nd + d2
            r = np.sqrt(r2)
            ex = (R2 / r2) * (1.0 - 1.0 / (1j * k * r)) * inv * np.exp(1j * k * (d2 - nd * nd) / (r + R + nd))
            ap = np.exp(1j * k * d2 / (2 * z)) * (1 + l1 * nd + l2 * d2 + l3 * nd * nd)
            s = np.sum(np.sum(h * Ep[:, :, im] * (ex - ap), axis=1) * Ey[l])
            worst = max(worst, abs(complex(s)))
    return worst


# ----------------------------------------------------------------------------------------------
# one block
# ----------------------------------------------------------------------------------------------
def _block_nodes(pupil: Pupil, xb: float, yb: float, dxs: np.ndarray, dys: np.ndarray, q: float) -> tuple[int, int]:
    u, v, _, b, half = aperture_nodes(pupil, xb, yb, 48, 48)
    _, _, gu, gv = _integrand(pupil, xb, yb, u, v)
    k = pupil.k
    # phase range along each row: its largest slope times its half-width (rows differ in both)
    beta_u = float(((1.1 * np.abs(gu).max(axis=1) + k * float(np.abs(dxs).max())) * half).max())
    beta_v = (1.1 * float(np.abs(gv).max()) + k * float(np.abs(dys).max())) * b * 0.5 * np.pi
    return nodes_for_phase(beta_v, q, 4), nodes_for_phase(beta_u, q, 4)


def _block(pupil: Pupil, xb: float, yb: float, dxs: np.ndarray, dys: np.ndarray, q: float
           ) -> tuple[np.ndarray, float, tuple[int, int]]:
    """(U (len(dys), len(dxs)), absolute error estimate of U, nodes) of one block centred at (xb, yb)."""
    k, z = pupil.k, pupil.z_um
    nt, nr = _block_nodes(pupil, xb, yb, dxs, dys, q)
    u, v, w, _, _ = aperture_nodes(pupil, xb, yb, nt, nr)
    h, R, _, _ = _integrand(pupil, xb, yb, u, v)
    h = h * w
    vv = np.broadcast_to(v[:, None], u.shape)
    l1, l2, l3 = _taylor_coefficients(k, z, R)
    g = np.stack([np.ones_like(h), l1 * u, l1 * vv, l2 + l3 * u * u, 2 * l3 * u * vv, l2 + l3 * vv * vv])
    Hq = (h[None] * g).transpose(1, 0, 2)  # (nt, 6, nr)
    # exp(i k u dx_m) by a running product along the (uniform) offsets, a few rows at a time (cache-sized)
    G = np.empty((nt, 6, dxs.size), dtype=complex)
    probe_cols = sorted({0, (dxs.size - 1) // 2, dxs.size - 1})
    Ep = np.empty((nt, nr, len(probe_cols)), dtype=complex)
    rows = max(1, int(2e6 // (16 * nr * dxs.size)))
    for j0 in range(0, nt, rows):
        j1 = min(nt, j0 + rows)
        E = np.empty((j1 - j0, nr, dxs.size), dtype=complex)
        E[..., 0] = np.exp(1j * k * u[j0:j1] * dxs[0])
        if dxs.size > 1:
            E[..., 1:] = np.exp(1j * k * u[j0:j1] * (dxs[1] - dxs[0]))[..., None]
            np.cumprod(E, axis=-1, out=E)
        G[j0:j1] = np.matmul(Hq[j0:j1], E)  # (rows, 6, Bx)
        Ep[j0:j1] = E[:, :, probe_cols]
    Ey = np.exp(1j * k * np.outer(dys, v))  # (By, nt)
    F = np.tensordot(Ey, G, axes=([1], [0]))  # (By, 6, Bx)
    DX, DY = dxs[None, :], dys[:, None]
    U = F[:, 0] + DX * F[:, 1] + DY * F[:, 2] + DX * DX * F[:, 3] + DX * DY * F[:, 4] + DY * DY * F[:, 5]
    U = U * np.exp(1j * k * (DX * DX + DY * DY) / (2 * z))
    # Taylor remainder against the exact kernel on a grid of offsets (corners and edges included)
    worst = _taylor_remainder(k, z, R, u, vv, h, l1, l2, l3, dxs, dys, Ep, Ey)
    quad = 2.0 * q * float(np.abs(h).sum())
    return U, TAYLOR_SAFETY * worst + quad, (nt, nr)


Box = tuple[int, int, int, int]  # (j0, j1, i0, i1): rows j0:j1, columns i0:i1 of the output window


def _quarters(box: Box) -> list[Box]:
    j0, j1, i0, i1 = box
    jm, im = (j0 + j1 + 1) // 2, (i0 + i1 + 1) // 2
    return [b for b in ((j0, jm, i0, im), (j0, jm, im, i1), (jm, j1, i0, im), (jm, j1, im, i1))
            if b[0] < b[1] and b[2] < b[3]]


def _plan(pupil: Pupil, xs: np.ndarray, ys: np.ndarray, error: float, q: float, block_px: int | None) -> list[Box]:
    """Blocks sized to the Taylor budget before any exact work: a coarse preview of |U| (direction-sine engine,
    every other sample; only used to size blocks), the remainder's d^3 scaling calibrated on one 64-sample block at
    the preview's peak, and blocks split while the predicted error exceeds a quarter of the budget."""
    size = BLOCK_PLAN if block_px is None else max(1, int(block_px))
    boxes = [(j0, min(ys.size, j0 + size), i0, min(xs.size, i0 + size))
             for j0 in range(0, ys.size, size) for i0 in range(0, xs.size, size)]
    if block_px is not None or xs.size * ys.size <= 64 * 64:
        return boxes
    if pupil.lens.phase_poly_rad and not ray_map_monotone(pupil.lens):
        return boxes  # no direction-sine preview of such a lens: the blocks are split by their evaluated errors
    A = np.abs(mft_field(pupil, xs[::2], ys[::2], error=1e-3))
    jp, ip = (2 * int(v) for v in np.unravel_index(int(np.argmax(A)), A.shape))
    c0 = min(max(0, ip - 32), max(0, xs.size - 64))
    r0 = min(max(0, jp - 32), max(0, ys.size - 64))
    bx, by = xs[c0:c0 + 64], ys[r0:r0 + 64]
    xb, yb = 0.5 * (bx[0] + bx[-1]), 0.5 * (by[0] + by[-1])
    U, e, _ = _block(pupil, xb, yb, bx - xb, by - yb, q)
    peak = max(float(A.max()), float(np.abs(U).max())) ** 2
    d_cal = math.hypot(bx[-1] - bx[0], by[-1] - by[0]) / 2
    C = max(e, 1e-300) / d_cal ** 3  # evaluated error of U per um^3 of half-diagonal
    out: list[Box] = []
    while boxes:
        box = boxes.pop()
        j0, j1, i0, i1 = box
        amp = 1.1 * float(A[j0 // 2:(j1 + 1) // 2 + 1, i0 // 2:(i1 + 1) // 2 + 1].max())
        d = math.hypot(xs[i1 - 1] - xs[i0], ys[j1 - 1] - ys[j0]) / 2
        if 2 * amp * C * d ** 3 > 0.4 * error * peak and max(j1 - j0, i1 - i0) > BLOCK_MIN:
            boxes += _quarters(box)
        else:
            out.append(box)
    return out


def rs_field(pupil: Pupil, xs: ArrayLike, ys: ArrayLike, *, error: float = 1e-4, workers: int = 2,
             block_px: int | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """Complex field (len(ys), len(xs)) of the pupil's focusing order at the plane ``pupil.z_um`` (exact RS).

    ``xs``, ``ys``: uniformly spaced output coordinates (um). ``error``: the largest intensity error wanted,
    relative to the window's peak intensity. Blocks are planned from a preview (:func:`_plan`; ``block_px`` fixes
    the starting size instead) and split wherever their evaluated error exceeds half the budget. Returns the
    field and an info dict whose ``intensity_error`` is the estimated largest absolute error of ``|U|^2``
    (quadrature plus Taylor remainder, evaluated per block) and ``field_error`` the largest absolute error of
    ``U``; ``blocks``, ``splits``, ``nodes``.
    """
    xs = np.asarray(xs, dtype=float).reshape(-1)
    ys = np.asarray(ys, dtype=float).reshape(-1)
    q = error * 1e-3
    todo = _plan(pupil, xs, ys, error, q, block_px)
    out = np.empty((ys.size, xs.size), dtype=complex)
    errs: dict[Box, float] = {}
    nodes: list[tuple[int, int]] = []

    def run(box: Box) -> tuple[Box, np.ndarray, float, tuple[int, int]]:
        j0, j1, i0, i1 = box
        bx, by = xs[i0:i1], ys[j0:j1]
        xb, yb = 0.5 * (bx[0] + bx[-1]), 0.5 * (by[0] + by[-1])
        U, e, nn = _block(pupil, xb, yb, bx - xb, by - yb, q)
        return box, U, e, nn

    splits = 0
    planned = len(todo)
    with blas_threads(1), StoppableThreadPool(max(1, int(workers))) as ex:
        while todo:
            for box, U, e, nn in ex.map(run, todo):
                out[box[0]:box[1], box[2]:box[3]] = U
                errs[box] = e
                nodes.append(nn)
            peak = float(np.max(np.abs(out) ** 2)) if out.size else 0.0
            todo = []
            for box, e in list(errs.items()):
                j0, j1, i0, i1 = box
                amp = float(np.abs(out[j0:j1, i0:i1]).max())
                if (2 * amp * e + e * e) > 0.5 * error * peak and max(j1 - j0, i1 - i0) > BLOCK_MIN:
                    del errs[box]
                    todo += _quarters(box)
                    splits += 1
    ierr = 0.0
    ferr = 0.0
    for (j0, j1, i0, i1), e in errs.items():
        amp = float(np.abs(out[j0:j1, i0:i1]).max())
        ierr = max(ierr, 2 * amp * e + e * e)
        ferr = max(ferr, e)
    info = {"engine": "rs", "blocks": len(errs), "planned_blocks": planned, "splits": splits,
            "nodes": [max(n[0] for n in nodes), max(n[1] for n in nodes)] if nodes else [0, 0],
            "intensity_error": ierr, "field_error": ferr}
    return out, info


# ----------------------------------------------------------------------------------------------
# brute-force reference
# ----------------------------------------------------------------------------------------------
def zone_radii(pupil: Pupil) -> np.ndarray:
    """Radii (um) where the order's lens phase passes a multiple of 2 pi, from 0 to the aperture radius.

    With ``phase_poly_rad``: where the total variation of the order's full lens phase (hyperbola plus added phase,
    monotone or not) passes a multiple of 2 pi, found on a fine radial grid (64 samples per zone) and refined by
    linear interpolation of the accumulated variation.
    """
    lens = pupil.lens
    a, f = lens.radius_um, lens.f_um
    if lens.phase_poly_rad:
        from metafovea.lens import phase_gradient_over_r  # lens stage (rank 3): allowed

        rough = float(np.abs(pupil.order * phase_gradient_over_r(lens, np.linspace(0, a, 4097))).max()) * a * a
        n = int(min(5e7, 64 * (rough / (2 * np.pi) + 1)))
        r = np.linspace(0.0, a, n + 1)
        slope = np.abs(pupil.order * phase_gradient_over_r(lens, r) * r)  # |d phase / d rho|
        var = np.concatenate([[0.0], np.cumsum(0.5 * (slope[1:] + slope[:-1]) * np.diff(r))])
        nz = int(var[-1] // (2 * np.pi))
        edges = np.interp(2 * np.pi * np.arange(nz + 1), var, r)
        edges = edges[edges < a]
        return np.append(edges, a)
    step = lens.wavelength_um / pupil.order
    nz = int(math.ceil((math.hypot(a, f) - f) / step))
    r = np.sqrt(np.maximum((f + np.arange(nz + 1) * step) ** 2 - f * f, 0.0))
    r = r[r < a]
    return np.append(r, a)


def rs_reference(pupil: Pupil, xs: ArrayLike, ys: ArrayLike, *, nodes_per_zone: int = 16, phi_margin: int = 48,
                 chunk: int = 4_000_000) -> np.ndarray:
    """Brute-force Rayleigh-Sommerfeld field (len(ys), len(xs)) over the true aperture (see the module docstring).

    Cost ~ (zones x nodes_per_zone x azimuthal nodes) x output points kernel evaluations: keep the output small.
    """
    lens = pupil.lens
    f, z, k = lens.f_um, pupil.z_um, pupil.k
    km = 2 * np.pi / lens.wavelength_um * pupil.order
    s0 = np.asarray(pupil.s0, float)
    xs = np.asarray(xs, dtype=float).reshape(-1)
    ys = np.asarray(ys, dtype=float).reshape(-1)
    X, Y = np.meshgrid(xs, ys)
    px_out, py_out = X.ravel(), Y.ravel()
    probe = np.array([[xs.min(), ys.min()], [xs.min(), ys.max()], [xs.max(), ys.min()], [xs.max(), ys.max()],
                      [xs.mean(), ys.mean()]])
    xg, wg = special.roots_legendre(int(nodes_per_zone))
    out = np.zeros(px_out.size, dtype=complex)
    edges = zone_radii(pupil)
    ring = np.linspace(0.0, 2 * np.pi, 4096, endpoint=False)
    for r0, r1 in zip(edges[:-1], edges[1:]):
        rho = 0.5 * (r1 - r0) * xg + 0.5 * (r1 + r0)
        wr = 0.5 * (r1 - r0) * wg
        # azimuthal nodes: twice the largest phase slope (rad per rad) along the outer ring, plus a margin
        cx, cy = r1 * np.cos(ring), r1 * np.sin(ring)
        th = k * (s0[0] * cx + s0[1] * cy)[None, :] + \
            k * np.sqrt((probe[:, :1] - cx) ** 2 + (probe[:, 1:] - cy) ** 2 + z * z)
        slope = float(np.abs(np.angle(np.exp(1j * (np.roll(th, -1, axis=1) - th)))).max()) * ring.size / (2 * np.pi)
        n_phi = int(2 * slope + phi_margin)
        phi = np.arange(n_phi) * (2 * np.pi / n_phi)
        R, PH = np.meshgrid(rho, phi)
        W = np.meshgrid(wr, phi)[0] * (2 * np.pi / n_phi) * R
        qx, qy = (R * np.cos(PH)).ravel(), (R * np.sin(PH)).ravel()
        L = np.sqrt(qx * qx + qy * qy + f * f)
        amp: complex | np.ndarray = pupil.amplitude_factor * W.ravel()
        if lens.phase_poly_rad:
            psi, hx = _added(lens, R.ravel())
            if pupil.lattice:
                p = lens.period_um / lens.wavelength_um * pupil.order
                amp = amp * np.sinc(p * qx * hx) * np.sinc(p * qy * hx)
            src = amp * np.exp(1j * (-km * (L - f) + pupil.order * psi + k * (s0[0] * qx + s0[1] * qy)))
        else:
            if pupil.lattice:
                p = lens.period_um / lens.wavelength_um * pupil.order
                amp = amp * np.sinc(p * qx / L) * np.sinc(p * qy / L)
            src = amp * np.exp(1j * (-km * (L - f) + k * (s0[0] * qx + s0[1] * qy)))
        step = max(1, chunk // qx.size)
        for j0 in range(0, px_out.size, step):
            ox, oy = px_out[j0:j0 + step, None], py_out[j0:j0 + step, None]
            r = np.sqrt((ox - qx) ** 2 + (oy - qy) ** 2 + z * z)
            K = (z / (1j * pupil.wavelength_um)) * (1.0 - 1.0 / (1j * k * r)) * np.exp(1j * k * r) / (r * r)
            out[j0:j0 + step] += K @ src
    return out.reshape(X.shape)

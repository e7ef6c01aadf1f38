"""Metalens phase profiles on the square lattice, evaluated tile by tile, and the numbers a designer checks.

Phase convention (see :mod:`metafovea.units`): a lens multiplies the field by ``exp(i phi)``; the
focusing hyperbolic profile is ``phi(r) = sign * (2 pi / lambda0) * (sqrt(r^2 + f^2) - f)`` with
``sign = -1`` under ``exp(-i omega t)``; a design may add a radial polynomial ``sum_j a_j (r / R)^(2 j)``
(``LensDesign.phase_poly_rad``, :func:`design_phase`), and the quantities that depend on the local phase slope
(zone widths, posts per zone, the lattice factor) then use the actual gradient. Wrapped phases are in
``[0, 2 pi)``; level ``k`` of an N-level design carries phase ``2 pi k / N`` and site levels are
``round(wrapped / (2 pi / N)) mod N``.

Lattice: posts sit at ``x = (ix + o) * p``, ``y = (iy + o) * p`` with ``o = 0`` (``lattice='integer'``,
a post at the centre) or ``o = 0.5`` (``'half'``); a site is inside the aperture when its centre has
``r <= D/2``. A 75 mm lens has ~276 million sites, so nothing here builds the whole lens: phases are
functions of lattice coordinates, :func:`iter_tiles` yields bounded tiles, counts are exact per row.

Arrays: tiles are ``(rows, cols)`` with row = y index increasing with y.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from fractions import Fraction
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.config import LensDesign
from metafovea.errors import InputError, PhysicsWarning, check_int
from metafovea.units import TWO_PI, UM_PER_MM

if TYPE_CHECKING:
    from metafovea.library import PostSet

EMPTY = -1  #: level value of lattice sites outside the aperture


# ----------------------------------------------------------------------------------------------
# phase profiles
# ----------------------------------------------------------------------------------------------
def hyperbolic_phase(r_um: ArrayLike, f_um: float, wavelength_um: float, sign: int = -1) -> np.ndarray:
    """Unwrapped hyperbolic phase (rad) at radius ``r_um``; 0 at the centre.

    Evaluated as ``r^2 / (sqrt(r^2 + f^2) + f)`` to avoid cancellation for r << f.
    """
    r2 = np.square(np.asarray(r_um, dtype=float))
    return sign * (TWO_PI / wavelength_um) * r2 / (np.sqrt(r2 + f_um * f_um) + f_um)


def paraxial_phase(r_um: ArrayLike, f_um: float, wavelength_um: float, sign: int = -1) -> np.ndarray:
    """Paraxial (quadratic) phase ``sign * k r^2 / (2 f)`` for comparison."""
    r2 = np.square(np.asarray(r_um, dtype=float))
    return sign * (TWO_PI / wavelength_um) * r2 / (2.0 * f_um)


def wrap_phase(phi: ArrayLike) -> np.ndarray:
    """Wrap to ``[0, 2 pi)`` (exactly: values that round to 2 pi are mapped to 0)."""
    w = np.mod(np.asarray(phi, dtype=float), TWO_PI)
    return np.where(w >= TWO_PI, 0.0, w)


def quantize_phase(phi: ArrayLike, levels: int) -> np.ndarray:
    """Level index ``k in [0, N)`` nearest to the wrapped phase (ties to the upper level, mod N)."""
    n = check_int("levels", levels, 2, 256)
    k = np.floor(wrap_phase(phi) * (n / TWO_PI) + 0.5).astype(np.int64)
    return np.mod(k, n)


def level_phase(k: ArrayLike, levels: int) -> np.ndarray:
    """Phase (rad) carried by level ``k``."""
    return TWO_PI * np.asarray(k, dtype=float) / levels


def added_phase(design: LensDesign, r_um: ArrayLike) -> np.ndarray:
    """The phase beyond the hyperbola (rad): ``sum_j a_j (r / R)^(2 j)``, ``a_j = design.phase_poly_rad[j-1]``.

    Zero for the plain hyperbola (``phase_poly_rad = ()``). Evaluated by Horner's rule in ``u = (r / R)^2``.
    """
    r = np.asarray(r_um, dtype=float)
    u = np.square(r / design.radius_um)
    acc = np.zeros_like(u)
    for a in reversed(design.phase_poly_rad):
        acc = (acc + a) * u
    return acc


def _added_slope_over_r(design: LensDesign, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(psi'(r) / r, d/dr (psi'(r) / r))`` of the added phase psi (rad / um^2, rad / um^3); no singularity at 0."""
    R2 = design.radius_um ** 2
    u = np.square(r) / R2
    s = np.zeros_like(u)
    ds = np.zeros_like(u)
    n = len(design.phase_poly_rad)
    for j in range(n, 0, -1):  # S(u) = sum 2 j a_j u^(j-1), S'(u) = sum 2 j (j-1) a_j u^(j-2)
        a = design.phase_poly_rad[j - 1]
        s = s * u + 2 * j * a
        if j >= 2:
            ds = ds * u + 2 * j * (j - 1) * a
    return s / R2, ds * 2 * r / (R2 * R2)


def design_phase(design: LensDesign, x_um: ArrayLike, y_um: ArrayLike) -> np.ndarray:
    """Unwrapped design phase at positions (um); broadcasting.

    ``hyperbolic_phase(r, f, lambda0, phase_sign) + added_phase(r)`` (:class:`metafovea.config.LensDesign`); the
    plain hyperbola when ``phase_poly_rad`` is empty (the same numbers, bit for bit).
    """
    r = np.hypot(x_um, y_um)
    phi = hyperbolic_phase(r, design.f_um, design.wavelength_um, design.phase_sign)
    if design.phase_poly_rad:
        phi = phi + added_phase(design, r)
    return phi


def phase_gradient_over_r(design: LensDesign, r_um: ArrayLike) -> np.ndarray:
    """``(d phi / d r) / r`` of the design phase (rad / um^2): the local gradient is this times ``(x, y)``.

    ``phase_sign k0 / sqrt(r^2 + f^2)`` for the hyperbola, plus the added phase's ``psi'(r) / r``.
    """
    r = np.asarray(r_um, dtype=float)
    k0 = TWO_PI / design.wavelength_um
    out = design.phase_sign * k0 / np.sqrt(r * r + design.f_um ** 2)
    if design.phase_poly_rad:
        out = out + _added_slope_over_r(design, r)[0]
    return out


def direction_sine_over_r(design: LensDesign, r_um: ArrayLike) -> np.ndarray:
    """``g(r) / r`` (1/um): ``g(r)`` is the design direction sine (magnitude, towards the axis) into which the lens
    point at radius r sends the focusing order at the design wavelength, ``g = -(d phi_focus / d r) / k0``.

    ``1 / sqrt(r^2 + f^2)`` for the hyperbola (``g = r / sqrt(r^2 + f^2)``); the local focal length is
    ``r sqrt(1 - g^2) / g``. Independent of ``phase_sign`` (the optics engines work with the focusing lens).
    """
    return design.phase_sign * phase_gradient_over_r(design, r_um) * (design.wavelength_um / TWO_PI)


def direction_sine_slope(design: LensDesign, r_um: ArrayLike) -> np.ndarray:
    """``d g / d r`` (1/um) of :func:`direction_sine_over_r`'s ``g``: positive everywhere for a lens whose ray
    directions are monotone in radius (the direction-sine engines' condition); ``f^2 / (r^2 + f^2)^(3/2)`` for the
    hyperbola."""
    r = np.asarray(r_um, dtype=float)
    L = np.sqrt(r * r + design.f_um ** 2)
    h = direction_sine_over_r(design, r)
    dh = -r / L ** 3
    if design.phase_poly_rad:
        dh = dh + design.phase_sign * _added_slope_over_r(design, r)[1] * (design.wavelength_um / TWO_PI)
    return h + r * dh


def ray_map_check(design: LensDesign, n: int = 4097) -> tuple[bool, float, str]:
    """``(monotone, largest design direction sine, reason)`` of the lens' ray map r -> g(r) over the aperture.

    Monotone: ``dg/dr > 0`` on ``[0, R]`` (sampled at ``n`` radii), so each direction is reached from one radius
    (no caustic inside the lens' directions) and the local focal length stays positive; and ``g < 1`` (no
    evanescent design direction). Always true for the plain hyperbola. ``reason`` is empty when monotone.
    """
    r = np.linspace(0.0, design.radius_um, n)
    g = r * direction_sine_over_r(design, r)
    dg = direction_sine_slope(design, r)
    gmax = float(np.max(np.abs(g)))
    bad = np.flatnonzero(~(dg > 0))
    if bad.size:
        return False, gmax, (f"the ray direction is not monotone in radius (dg/dr = {dg[bad[0]]:.3g} / um at "
                             f"r = {r[bad[0]] / UM_PER_MM:.4g} mm): the local focal length changes sign or two radii "
                             "send light into one direction")
    if gmax >= 1.0:
        return False, gmax, f"the design direction sine reaches {gmax:.4f} >= 1 at the rim (evanescent light)"
    return True, gmax, ""


def posts_per_2pi(design: LensDesign, r_um: ArrayLike) -> np.ndarray:
    """Local zone width divided by the lattice period at radius r (inf at the centre).

    From the actual local phase gradient (``phase_poly_rad`` included): ``2 pi / |d phi / d r| / period``.
    """
    r = np.asarray(r_um, dtype=float)
    if design.phase_poly_rad:
        with np.errstate(divide="ignore"):
            zone = TWO_PI / np.abs(phase_gradient_over_r(design, r) * r)
        return zone / design.period_um
    with np.errstate(divide="ignore"):
        zone = design.wavelength_um * np.sqrt(r * r + design.f_um ** 2) / r
    return zone / design.period_um


def zone_width_um(design: LensDesign, r_um: ArrayLike) -> np.ndarray:
    """Local 2 pi zone width (um) = 2 pi / |d phi / d r| (= lambda sqrt(r^2+f^2) / r for the hyperbola)."""
    return posts_per_2pi(design, r_um) * design.period_um


def narrowest_zone(design: LensDesign, n: int = 4097) -> tuple[float, float]:
    """``(posts per 2 pi, radius um)`` of the narrowest 2 pi zone in the aperture: the rim for the hyperbola; for a
    lens with ``phase_poly_rad`` the smallest of ``n`` radii sampled over ``[0, R]``."""
    R = design.radius_um
    if not design.phase_poly_rad:
        return float(posts_per_2pi(design, R)), R
    r = np.linspace(0.0, R, n)
    p = posts_per_2pi(design, r)
    i = int(np.argmin(p))
    return float(p[i]), float(r[i])


# ----------------------------------------------------------------------------------------------
# lattice
# ----------------------------------------------------------------------------------------------
def _offset(design: LensDesign) -> Fraction:
    return Fraction(0) if design.lattice == "integer" else Fraction(1, 2)


def site_index_range(design: LensDesign) -> tuple[int, int]:
    """Inclusive range ``(lo, hi)`` of site indices (same for rows and columns) that can be inside."""
    rho = Fraction(design.radius_um) / Fraction(design.period_um)
    o = _offset(design)
    hi = math.floor(rho - o)
    lo = -math.floor(rho + o)
    return lo, hi


def row_half_counts(design: LensDesign, iy: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """For each row index ``iy``: the inclusive column range ``[lo, hi]`` of sites inside the aperture.

    Exact for any size (rational arithmetic on the float inputs, integer square roots). Rows with no
    site get ``lo > hi``. Returns ``(lo, hi)`` arrays of int64 aligned with ``iy`` (default: all rows).
    """
    lo_all, hi_all = site_index_range(design)
    if iy is None:
        iy = np.arange(lo_all, hi_all + 1)
    rho = Fraction(design.radius_um) / Fraction(design.period_um)
    a, b = rho.numerator, rho.denominator  # rho = a/b
    o2 = 2 * _offset(design)  # 0 or 1
    lo = np.empty(len(iy), dtype=np.int64)
    hi = np.empty(len(iy), dtype=np.int64)
    # condition for column ix: (2 ix + o2)^2 <= 4 rho^2 - (2 iy + o2)^2 =: S (exact rational)
    for n, j in enumerate(np.asarray(iy).tolist()):
        yy = (2 * j + int(o2)) ** 2
        num = 4 * a * a - yy * b * b  # S = num / b^2
        if num < 0:
            lo[n], hi[n] = 1, 0
            continue
        m = math.isqrt(num // (b * b))  # floor(sqrt(S)): largest |2 ix + o2| allowed
        if o2 == 0:
            h = m // 2
            lo[n], hi[n] = -h, h
        else:
            # 2 ix + 1 in [-m, m] and odd
            h = (m - 1) // 2 if m >= 1 else -1
            lo[n], hi[n] = -h - 1, h
    return lo, hi


def count_posts(design: LensDesign) -> int:
    """Exact number of lattice sites with centre inside the aperture (r <= D/2)."""
    lo, hi = row_half_counts(design)
    return int(np.maximum(hi - lo + 1, 0).sum())


def site_positions_um(design: LensDesign, ix: ArrayLike, iy: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    o = float(_offset(design))
    return (np.asarray(ix, dtype=float) + o) * design.period_um, (np.asarray(iy, dtype=float) + o) * design.period_um


@dataclass(frozen=True)
class Tile:
    """One rectangular block of lattice sites.

    iy0, ix0: site index of the first row / column. levels: (rows, cols) int16, -1 outside the
    aperture. phase: (rows, cols) wrapped design phase (rad) when requested, else None.
    """

    iy0: int
    ix0: int
    levels: np.ndarray
    phase: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.levels.shape  # type: ignore[return-value]

    @property
    def count(self) -> int:
        return int((self.levels >= 0).sum())


def tile_grid(design: LensDesign, tile_sites: int = 1024) -> list[tuple[int, int, int, int]]:
    """Tiles ``(iy0, ix0, rows, cols)`` covering the aperture; tiles entirely outside are skipped."""
    ts = check_int("tile_sites", tile_sites, 1, 1 << 16)
    lo, hi = site_index_range(design)
    starts = range(lo, hi + 1, ts)
    out = []
    rho_p = design.radius_um / design.period_um + 1.0
    for iy0 in starts:
        ny = min(ts, hi + 1 - iy0)
        ymin = 0.0 if iy0 <= 0 < iy0 + ny else min(abs(iy0), abs(iy0 + ny - 1))
        for ix0 in starts:
            nx = min(ts, hi + 1 - ix0)
            xmin = 0.0 if ix0 <= 0 < ix0 + nx else min(abs(ix0), abs(ix0 + nx - 1))
            if math.hypot(xmin, ymin) <= rho_p:
                out.append((iy0, ix0, ny, nx))
    return out


def evaluate_tile(design: LensDesign, iy0: int, ix0: int, rows: int, cols: int, *,
                  with_phase: bool = False, levels: int | None = None) -> Tile:
    """Levels (and optionally wrapped phase) of one tile; sites outside the aperture are ``EMPTY``."""
    n = design.levels if levels is None else check_int("levels", levels, 2, 256)
    iy = np.arange(iy0, iy0 + rows)
    ix = np.arange(ix0, ix0 + cols)
    x, y = site_positions_um(design, ix[None, :], iy[:, None])
    phi = design_phase(design, x, y)
    lev = quantize_phase(phi, n).astype(np.int16)
    lo, hi = row_half_counts(design, iy)
    inside = (ix[None, :] >= lo[:, None]) & (ix[None, :] <= hi[:, None])
    lev[~inside] = EMPTY
    return Tile(iy0, ix0, lev, wrap_phase(phi) if with_phase else None)


def iter_tiles(design: LensDesign, tile_sites: int = 1024, *, with_phase: bool = False,
               levels: int | None = None) -> Iterator[Tile]:
    """Yield the lens tile by tile (bounded memory: one tile of ``tile_sites^2`` sites at a time)."""
    for iy0, ix0, ny, nx in tile_grid(design, tile_sites):
        yield evaluate_tile(design, iy0, ix0, ny, nx, with_phase=with_phase, levels=levels)


# ----------------------------------------------------------------------------------------------
# efficiency estimates
# ----------------------------------------------------------------------------------------------
def scalar_efficiency(levels: int) -> float:
    """Point-sampled N-level focusing efficiency estimate ``sinc^2(pi / N)``."""
    n = check_int("levels", levels, 2, 256)
    x = math.pi / n
    return (math.sin(x) / x) ** 2


def _site_terms(design: LensDesign, x: np.ndarray, y: np.ndarray, levels: int | None) -> np.ndarray:
    """Per-site contribution to the on-axis focal field, relative to a continuous-phase lens.

    Each post imposes a constant phase over its p x p cell; the focal field of a cell is the ideal
    phase at its centre times ``sinc`` of the local phase gradient across the cell, and the post's
    phase differs from the ideal by the quantisation error.
    """
    phi = design_phase(design, x, y)
    err = 0.0 if levels is None else level_phase(quantize_phase(phi, levels), levels) - wrap_phase(phi)
    p = design.period_um
    if design.phase_poly_rad:  # the actual local gradient (cycles per period)
        gr = phase_gradient_over_r(design, np.hypot(x, y)) * (p / TWO_PI)
        return np.exp(1j * err) * np.sinc(gr * x) * np.sinc(gr * y)
    r2 = x * x + y * y
    rr = np.sqrt(r2 + design.f_um ** 2)
    k = TWO_PI / design.wavelength_um
    gx = k * x / rr * p / TWO_PI
    gy = k * y / rr * p / TWO_PI
    return np.exp(1j * err) * np.sinc(gx) * np.sinc(gy)


@dataclass(frozen=True)
class EfficiencyEstimate:
    value: float  #: focal peak intensity relative to a continuous-phase lens (same aperture)
    stderr: float  #: 1-sigma statistical error (0 when exact)
    sites: int  #: number of sites evaluated
    exact: bool


def lattice_efficiency(design: LensDesign, levels: int | None = None, *, samples: int = 1 << 20,
                       exact: bool | None = None, rng: np.random.Generator | int | None = 0,
                       tile_sites: int = 1024) -> EfficiencyEstimate:
    """Focal-peak ratio of the lattice-sampled, N-level lens to the continuous-phase lens.

    ``levels=None`` means the design's levels; ``levels=0`` evaluates lattice sampling alone
    (continuous phase per post). ``exact`` sums over every site (tile by tile); by default it is used
    when the lens has at most ``samples`` sites, otherwise ``samples`` sites are drawn uniformly from
    the aperture (seeded by ``rng``) and the standard error is reported.
    """
    n = design.levels if levels is None else levels
    lv = None if n == 0 else check_int("levels", n, 2, 256)
    total = count_posts(design)
    if total == 0:
        raise InputError("diameter_um", design.diameter_um,
                         f"a diameter that holds at least one lattice site (period {design.period_um:g} um, "
                         f"lattice '{design.lattice}')")
    if exact is None:
        exact = total <= samples
    if exact:
        acc = 0j
        for t in iter_tiles(design, tile_sites):
            iy, ix = np.nonzero(t.levels >= 0)
            x, y = site_positions_um(design, ix + t.ix0, iy + t.iy0)
            acc += _site_terms(design, x, y, lv).sum()
        amp = abs(acc) / total
        return EfficiencyEstimate(amp * amp, 0.0, total, True)
    g = np.random.default_rng(rng)
    lo_r, hi_r = site_index_range(design)
    rows = np.arange(lo_r, hi_r + 1)
    lo, hi = row_half_counts(design, rows)
    cnt = np.maximum(hi - lo + 1, 0).astype(float)
    ridx = g.choice(len(rows), size=samples, p=cnt / cnt.sum())
    col = lo[ridx] + np.floor(g.random(samples) * cnt[ridx]).astype(np.int64)
    x, y = site_positions_um(design, col, rows[ridx])
    terms = _site_terms(design, x, y, lv)
    m = terms.mean()
    se_amp = terms.std() / math.sqrt(samples)
    return EfficiencyEstimate(abs(m) ** 2, 2 * abs(m) * se_amp, samples, False)


# ----------------------------------------------------------------------------------------------
# summary
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LensSummary:
    """The numbers a designer checks (lengths in um unless the name says otherwise).

    With ``phase_poly_rad``: the rim phase, zones, zone widths, posts per zone and the lattice efficiencies are the
    full design phase's (its actual local gradient); the NA, F-number, Airy radius, FWHM and MTF cutoff describe the
    aperture at the focal length f (the hyperbolic part), not the corrected lens' PSF (:mod:`metafovea.optics`).
    """

    name: str
    f_mm: float
    diameter_mm: float
    wavelength_um: float
    polarization: str
    period_um: float
    levels: int
    lattice: str
    na: float
    f_number: float
    zones_2pi: float
    rim_phase_rad: float
    rim_zone_width_um: float
    rim_posts_per_2pi: float
    posts_in_aperture: int
    airy_first_zero_paraxial_um: float
    airy_first_zero_na_um: float
    fwhm_um: float
    mtf_cutoff_cyc_per_mm: float
    scalar_efficiency: float
    lattice_efficiency: float
    lattice_efficiency_stderr: float
    lattice_efficiency_sites: int
    lattice_sampling_efficiency: float
    radius_below_4_posts_um: float | None
    substrate_orders: bool
    warnings: tuple[str, ...] = field(default_factory=tuple)
    posts: tuple[dict[str, Any], ...] = field(default_factory=tuple)
    post_set: dict[str, Any] | None = None  #: source and figures of merit of the post set used, if any
    phase_poly_rad: tuple[float, ...] = ()  #: the phase added to the hyperbola (LensDesign), rad
    narrowest_posts_per_2pi: float | None = None  #: with phase_poly_rad: the narrowest zone anywhere (posts per 2 pi)
    narrowest_zone_radius_um: float | None = None  #: ... and its radius (um)


def design_warnings(design: LensDesign, n_superstrate: float = 1.0) -> list[str]:
    """Physics warnings for a design (also emitted as :class:`PhysicsWarning` by :func:`summarize`)."""
    out = []
    rim = float(posts_per_2pi(design, design.radius_um))
    if design.phase_poly_rad:
        out += added_phase_warnings(design)
    elif rim < 4.0:
        r4_mm = radius_below_posts(design, 4.0) / UM_PER_MM
        out.append(f"only {rim:.2f} posts per 2 pi at the rim (< 4): the outer zones are undersampled; "
                   f"expect lower efficiency and stray orders beyond r = {r4_mm:.3g} mm")
    out += aperture_warnings(design)
    lam_sub = design.wavelength_um / design.n_substrate
    if design.period_um > lam_sub:
        out.append(f"lattice period {design.period_um:g} um > lambda / n_substrate = {lam_sub:.3f} um: "
                   "diffraction orders propagate in the substrate; use the RCWA zero-order transmission and "
                   "account for the power in the other orders")
    if design.period_um > design.wavelength_um / n_superstrate:
        out.append(f"lattice period {design.period_um:g} um > lambda = {design.wavelength_um:g} um: "
                   "diffraction orders propagate in air (not a metasurface regime)")
    return out


def added_phase_warnings(design: LensDesign) -> list[str]:
    """Warnings of a lens with ``phase_poly_rad``: zones narrower than 4 posts anywhere in the aperture (fewer
    than 2: the lattice cannot represent the local phase slope at all), saying when the added phase is what makes
    them so, and a ray map that is not monotone (the direction-sine PSF engines do not apply)."""
    out = []
    hyp = replace(design, phase_poly_rad=())
    p_min, r_min = narrowest_zone(design)
    p_hyp = float(posts_per_2pi(hyp, max(r_min, 1e-300)))
    if p_min < 4.0:
        r4_mm = radius_below_posts(design, 4.0) / UM_PER_MM
        why = (f"the added phase (phase_poly_rad) makes the zones narrower than the posts allow (the hyperbola alone "
               f"has {p_hyp:.2f} posts per 2 pi there)" if p_hyp >= 4.0 or p_min < 0.999 * p_hyp else
               "as the hyperbola alone")
        out.append(f"only {p_min:.2f} posts per 2 pi at r = {r_min / UM_PER_MM:.4g} mm (< 4): {why}; the zones "
                   f"beyond r = {r4_mm:.4g} mm are undersampled: expect lower efficiency and stray orders")
        if p_min < 2.0:
            out.append(f"fewer than 2 posts per 2 pi zone ({p_min:.2f}): the lattice cannot represent the local phase "
                       "slope (it aliases into another direction); the lens will not focus as designed there")
    ok, _, reason = ray_map_check(design)
    if not ok:
        out.append(f"phase_poly_rad: {reason}; the direction-sine PSF engines (hankel, mft, geometric) do not apply "
                   "to this lens, psf() uses the exact Rayleigh-Sommerfeld engine")
    return out


def aperture_warnings(design: LensDesign) -> list[str]:
    """Warnings for extreme but legal apertures: f << D (f/D below 0.5), NA near 1, a focus in the near field."""
    out = []
    na, fd, wl = design.na, design.f_um / design.diameter_um, design.wavelength_um
    bend = math.degrees(math.asin(min(na, 1.0)))
    if fd < 0.5:
        out.append(f"f/D = {fd:.3g} < 0.5 (f << D): rim rays bend by {bend:.1f} deg. The F-number printed is f/D; the "
                   f"working F-number 1/(2 NA) = {0.5 / na:.3g} can never fall below 0.5 (NA <= 1), so a shorter f "
                   "buys little resolution, and a flat lens focuses such steep rays poorly: the scalar efficiency "
                   "and spot numbers are optimistic")
    elif na > 0.8:
        out.append(f"NA {na:.3g} is near 1 (rim rays bend by {bend:.1f} deg): a flat lens' posts deflect such angles "
                   "with much lower efficiency than the scalar estimate below (vectorial and shadowing effects)")
    if design.f_um < 10 * wl:
        out.append(f"f = {design.f_um:.3g} um is {design.f_um / wl:.3g} wavelengths: the focus lies in the lens' near "
                   "field, where the far-field numbers below (Airy zero, FWHM, MTF cutoff) do not apply")
    return out


def radius_below_posts(design: LensDesign, n_posts: float) -> float:
    """Radius (um) beyond which a 2 pi zone spans fewer than ``n_posts`` posts (inf if never).

    For the hyperbola in closed form (it may lie beyond the rim); with ``phase_poly_rad`` the smallest radius in
    the aperture where the zone is first narrower (inf if nowhere in the aperture).
    """
    if design.phase_poly_rad:
        r = np.linspace(0.0, design.radius_um, 4097)
        below = np.flatnonzero(posts_per_2pi(design, r) < n_posts)
        if below.size == 0:
            return math.inf
        i = int(below[0])
        if i == 0:
            return 0.0
        lo, hi = float(r[i - 1]), float(r[i])
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if posts_per_2pi(design, mid) < n_posts else (mid, hi)
        return hi
    # lambda sqrt(r^2+f^2)/r = n p  ->  r = f / sqrt((n p / lambda)^2 - 1)
    q = n_posts * design.period_um / design.wavelength_um
    if q <= 1.0:
        return math.inf
    return design.f_um / math.sqrt(q * q - 1.0)


def summarize(design: LensDesign, *, post_set: PostSet | None = None, samples: int = 1 << 20,
              rng: np.random.Generator | int | None = 0, emit_warnings: bool = True) -> LensSummary:
    """Compute the design summary (exact post count, sampled lattice efficiency).

    Parameters
    ----------
    design : LensDesign
    post_set : PostSet, optional
        The posts of the lens' polarisation and levels: their widths, transmissions and expected efficiency are
        added (``posts``, ``post_set``).
    samples : int
        Lattice sites sampled for the lattice efficiency (its standard error ~1/sqrt(samples)).
    rng : int or numpy.random.Generator
        Seed of the site sampling.
    emit_warnings : bool
        Also emit the physics warnings as :class:`PhysicsWarning` (they are in ``warnings`` either way).

    Returns
    -------
    LensSummary
        NA, F-number, zones, rim zone width (um, posts per 2 pi), exact post count, Airy radius and FWHM (um), MTF
        cutoff (cycles/mm), efficiencies; :func:`metafovea.design_report.format_summary` prints it.
    """
    R = design.radius_um
    wl = design.wavelength_um
    na = design.na
    rim_phase = float(design_phase(design, R, 0.0))
    eff = lattice_efficiency(design, samples=samples, rng=rng)
    eff0 = lattice_efficiency(design, levels=0, samples=samples, rng=rng)
    r4 = radius_below_posts(design, 4.0)
    narrow = narrowest_zone(design)
    warn = design_warnings(design)
    if emit_warnings:
        for w in warn:
            warnings.warn(w, PhysicsWarning, stacklevel=2)
    posts: tuple[dict[str, Any], ...] = ()
    ps_info: dict[str, Any] | None = None
    if post_set is not None:
        if post_set.polarization != design.polarization:
            raise InputError("post_set", f"focuses {post_set.polarization}",
                             f"a post set that focuses the lens' polarisation ({design.polarization})")
        keys = ("expected_focusing_efficiency", "max_abs_phase_error_rad", "rms_phase_error_rad",
                "pass_phase_spread_rad", "pass_coherent_transmission", "mean_T_focus", "mean_T_pass")
        ps_info = {"source": post_set.source, **{k: post_set.info[k] for k in keys if k in post_set.info}}
        if "expected_focusing_efficiency" in ps_info:
            # RCWA post-set efficiency (zero order, equal-area levels) times the lattice sampling factor
            ps_info["expected_lens_efficiency"] = ps_info["expected_focusing_efficiency"] * eff0.value
        if post_set.levels != design.levels:
            raise InputError("levels", design.levels, f"the post set's number of levels ({post_set.levels})")
        tf = post_set.t_focus
        posts = tuple({"level": k, "target_phase_rad": TWO_PI * k / design.levels,
                       "wx_um": float(post_set.widths_um[k, 0]), "wy_um": float(post_set.widths_um[k, 1]),
                       "t_focus_abs": float(abs(tf[k])), "t_focus_phase_rad": float(np.angle(tf[k]) % TWO_PI),
                       "t_pass_abs": float(abs(post_set.t_pass[k])),
                       "t_pass_phase_rad": float(np.angle(post_set.t_pass[k]) % TWO_PI)}
                      for k in range(post_set.levels))
    return LensSummary(
        name=design.name, f_mm=design.f_mm, diameter_mm=design.diameter_mm, wavelength_um=wl,
        polarization=design.polarization, period_um=design.period_um, levels=design.levels,
        lattice=design.lattice, na=na, f_number=design.f_um / design.diameter_um,
        zones_2pi=abs(rim_phase) / TWO_PI, rim_phase_rad=rim_phase,
        rim_zone_width_um=float(zone_width_um(design, R)), rim_posts_per_2pi=float(posts_per_2pi(design, R)),
        posts_in_aperture=count_posts(design),
        airy_first_zero_paraxial_um=1.21967 * wl * design.f_um / design.diameter_um,
        airy_first_zero_na_um=0.60983 * wl / na, fwhm_um=0.51446 * wl / na,
        mtf_cutoff_cyc_per_mm=2 * na / wl * UM_PER_MM, scalar_efficiency=scalar_efficiency(design.levels),
        lattice_efficiency=eff.value, lattice_efficiency_stderr=eff.stderr, lattice_efficiency_sites=eff.sites,
        lattice_sampling_efficiency=eff0.value,
        radius_below_4_posts_um=None if math.isinf(r4) or r4 >= R else r4,
        substrate_orders=design.period_um > wl / design.n_substrate, warnings=tuple(warn), posts=posts,
        post_set=ps_info, phase_poly_rad=design.phase_poly_rad,
        narrowest_posts_per_2pi=narrow[0] if design.phase_poly_rad else None,
        narrowest_zone_radius_um=narrow[1] if design.phase_poly_rad else None)

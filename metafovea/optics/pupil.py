"""Pupil fields of a metalens in direction-sine space, from the design and the post set.

Model (scalar, thin element, stationary phase; valid for Fresnel numbers a^2/(lambda f) >> 1, i.e. for
every lens of this project: 625 for the 25 mm F/1 lens, 937 for the 75 mm F/2 lens)
-----------------------------------------------------------------------------------------------
A lens of focal length f0 designed at lambda0 imposes the phase ``phi0(rho)`` (hyperbolic, see
:mod:`metafovea.units`). Under a plane wave of direction sines ``s0`` (field angle) at wavelength
lambda, its field is decomposed into diffraction orders of the wrapped, N-level profile:
``t(rho) = sum_m c_m exp(i m phi0(rho))`` with

    c_m = sinc(m / N) * (1/N) * sum_k tau_k(lambda) exp(-2 pi i k m / N)      (normalised sinc)

where ``tau_k`` is level k's transmission in the polarisation considered (the lens' own polarisation:
``PostSet.t_focus``; the other one: ``PostSet.t_pass``). Away from lambda0 a post's phase scales as
``arg(tau_k) * lambda0 / lambda`` (propagation phase of a nanopost waveguide), which gives the familiar
order efficiency ``sinc^2(1 - lambda0/lambda)`` for ideal posts. Order m = 1 focuses at
``f0 lambda0 / lambda`` (chromatic focal shift); the other orders are broad haze.

Each order is mapped to direction-sine space by stationary phase: the lens point ``rho`` sends its light
into the direction ``s = s0 + m (lambda/lambda0) w`` with ``w = -rho / sqrt(rho^2 + f0^2)`` (the design
direction sine), and the angular spectrum at a plane z behind the lens is

    U(x, y) = integral P(s) exp(i [Phi(s) + k s.(x, y)]) d^2 s

    Phi(s)  = k0 f0 (1 - sqrt(1 - |w|^2)) + k z sqrt(1 - |s|^2),   w = (lambda0/lambda)(s - s0) / m
    |P(s)|  = |a| f0 (lambda0/lambda) / (lambda sqrt(1-|w|^2)^2)   (so that int |U|^2 = power through
              the aperture for an incident intensity of 1)

The ideal spherical term is therefore handled analytically: for lambda = lambda0, z = f0 and s0 = 0 the
phase Phi is constant and the PSF is the Fourier transform of a smooth amplitude over a disk. The disk is
``|w| <= NA``; directions with ``|s| >= 1`` are evanescent and lost.

A lens with a phase beyond the hyperbola (``LensDesign.phase_poly_rad``, a radial polynomial psi) keeps the same
model with the hyperbola's analytic mapping replaced by the stationary point of the full radial phase: the lens
point at radius rho sends its light into the design direction sine ``|w| = g(rho) = -phi'(rho) / k0``
(:func:`metafovea.lens.direction_sine_over_r`), inverted numerically (:func:`radius_of_direction_sine`; one radius
per direction as long as ``g`` increases with rho, :func:`metafovea.lens.ray_map_check`), and

    Phi(s)  = m [k0 f0 rho^2 / (L (L + f0)) + psi(rho) - rho psi'(rho)] + k z sqrt(1 - |s|^2),  L = sqrt(rho^2+f0^2)
    |P(s)|  = |a| alpha / (lambda sqrt((g / rho) g'(rho)))      (energy: d^2 rho = d^2 w / ((g / rho) g'))

which reduce to the formulas above for psi = 0 (the plain hyperbola takes the analytic code path, bit for bit).
The pupil disk's radius is ``g(R)`` (:func:`design_na`) instead of the NA. A ray leaves the lens at
``rho(w) = -w / (g / rho)`` and lands at ``rho(w) + z s / sqrt(1 - |s|^2)``.

Lattice sampling (posts on a square lattice of period p, each post carrying its own phase) multiplies the
local zero-order amplitude by ``sinc(p w_x / lambda0) sinc(p w_y / lambda0)`` (lens.py's site model). With
the design's quantisation the focal peak relative to a continuous phase is then ~0.935 (F/2) and ~0.90
(F/1) for 8 levels, matching :func:`metafovea.lens.lattice_efficiency`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.config import LensDesign
from metafovea.errors import InputError, check_choice, check_int, check_positive
from metafovea.library.postset import PostSet

#: Smallest distance of the pupil disk from the evanescent circle |s| = 1 that is accepted.
EVANESCENT_MARGIN = 1e-3
#: Radii of the table the inverse ray map starts its Newton steps from (linear interpolation: ~1e-8 R).
RAY_MAP_SAMPLES = 4097


def design_na(lens: LensDesign) -> float:
    """Radius of the focusing order's pupil disk in design direction sines: the NA for the plain hyperbola, the
    largest ``g(rho)`` over the aperture (:func:`metafovea.lens.direction_sine_over_r`) with ``phase_poly_rad``."""
    if not lens.phase_poly_rad:
        return lens.na
    return _ray_table(lens)[2]


@lru_cache(maxsize=64)
def _ray_table(lens: LensDesign) -> tuple[np.ndarray, np.ndarray, float, bool, str]:
    """(radii, g at those radii, largest |g|, monotone, reason) of a lens with phase_poly_rad."""
    from metafovea.lens import direction_sine_over_r, ray_map_check  # lens stage (rank 3): allowed

    ok, gmax, reason = ray_map_check(lens, RAY_MAP_SAMPLES)
    r = np.linspace(0.0, lens.radius_um, RAY_MAP_SAMPLES)
    g = r * direction_sine_over_r(lens, r)
    r.setflags(write=False)
    g.setflags(write=False)
    return r, g, gmax, ok, reason


def ray_map_monotone(lens: LensDesign) -> bool:
    """Whether the direction-sine engines apply: always for the hyperbola; with ``phase_poly_rad`` when the design
    direction sine increases with radius (:func:`metafovea.lens.ray_map_check`)."""
    return not lens.phase_poly_rad or _ray_table(lens)[3]


def check_ray_map(lens: LensDesign) -> None:
    """Raise an :class:`InputError` on ``phase_poly_rad`` when the lens' ray map is not monotone (the
    direction-sine engines need one radius per direction: :func:`metafovea.lens.ray_map_check`)."""
    if lens.phase_poly_rad and not _ray_table(lens)[3]:
        raise InputError("phase_poly_rad", list(lens.phase_poly_rad),
                         "a phase whose ray directions increase with radius for the direction-sine engines "
                         "(hankel, mft, geometric); psf(engine='rs') propagates any lens", detail=_ray_table(lens)[4])


def radius_of_direction_sine(lens: LensDesign, w_abs: ArrayLike) -> np.ndarray:
    """The lens radius rho (um) whose focusing ray leaves in the design direction sine ``|w| = w_abs``: the
    stationary point of the full radial phase, ``g(rho) = w_abs`` (table, then Newton steps to rounding error).

    ``f |w| / sqrt(1 - |w|^2)`` for the hyperbola. Needs a monotone ray map (:func:`check_ray_map`).
    """
    from metafovea.lens import direction_sine_over_r, direction_sine_slope  # lens stage (rank 3): allowed

    w = np.asarray(w_abs, dtype=float)
    if not lens.phase_poly_rad:
        return lens.f_um * w / np.sqrt(1.0 - w * w)
    check_ray_map(lens)
    r_tab, g_tab, _, _, _ = _ray_table(lens)
    rho = np.interp(w, g_tab, r_tab)
    for _ in range(3):
        rho = rho - (rho * direction_sine_over_r(lens, rho) - w) / direction_sine_slope(lens, rho)
    return rho


def _focus_added_phase(lens: LensDesign, rho: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(psi, rho psi') of the added phase as the focusing order sees it (rad): the engines' lens is the focusing
    one, ``-phase_sign`` times the design phase (the added phase's sign follows)."""
    from metafovea.lens import added_phase, direction_sine_over_r  # lens stage (rank 3): allowed

    sgn = -lens.phase_sign
    k0 = 2 * np.pi / lens.wavelength_um
    L = np.sqrt(rho * rho + lens.f_um ** 2)
    # rho psi'_focus = -k0 rho (g - rho / L) = -k0 rho^2 (g / rho - 1 / L)
    return sgn * added_phase(lens, rho), -k0 * rho * rho * (direction_sine_over_r(lens, rho) - 1.0 / L)


def field_direction(field_deg: ArrayLike) -> np.ndarray:
    """Direction sines (sx, sy) of the incident plane wave for a field angle in degrees.

    A scalar is an angle along +x; a pair (ax, ay) is the direction whose chief ray lands at
    ``(z tan ax, z tan ay)`` on a plane at distance z. The chief ray of a lens lands there at every
    wavelength (the centre of a thin lens does not deflect).
    """
    if np.ndim(field_deg) == 0:
        ax, ay = float(field_deg), 0.0
    else:
        v = list(np.asarray(field_deg, dtype=float).reshape(-1))
        if len(v) != 2:
            raise InputError("field_deg", field_deg, "a number or a pair (x, y) of angles in degrees")
        ax, ay = v
    for name, a in (("field_deg", ax), ("field_deg", ay)):
        if not math.isfinite(a) or abs(a) >= 89.0:
            raise InputError(name, field_deg, "finite angles with |angle| < 89 deg")
    tx, ty = math.tan(math.radians(ax)), math.tan(math.radians(ay))
    n = math.sqrt(1.0 + tx * tx + ty * ty)
    return np.array([tx / n, ty / n])


def max_field_deg(lens: LensDesign, wavelength_um: float | None = None) -> float:
    """Largest field angle (deg) for which every ray of the focusing order propagates.

    The rim of the pupil disk sits at ``|s0| + NA lambda/lambda0``; beyond 1 light is evanescent (and
    the hyperbolic lens is far outside its useful field long before). This is the lens' field.
    """
    wl = lens.wavelength_um if wavelength_um is None else wavelength_um
    r = 1.0 - design_na(lens) * wl / lens.wavelength_um - EVANESCENT_MARGIN
    if r <= 0:
        return 0.0
    return math.degrees(math.asin(min(r, 1.0)))


def _sinc(x: np.ndarray | float) -> np.ndarray:
    return np.sinc(x)


def level_transmissions(lens: LensDesign, post_set: PostSet | None, polarization: str,
                        wavelength_um: float, quantize: bool = True) -> np.ndarray | None:
    """(N,) transmissions tau_k at ``wavelength_um`` for the polarisation, or None for a continuous phase.

    Without a post set the posts are ideal (exact phases, unit transmission for the lens' polarisation,
    unit pass-through). Phases scale with lambda0 / lambda away from the design wavelength.
    """
    alpha = lens.wavelength_um / wavelength_um
    if post_set is None:
        if not quantize:
            return None
        post_set = PostSet.ideal(lens.levels, period_um=lens.period_um, wavelength_um=lens.wavelength_um,
                                 polarization=lens.polarization)
    if post_set.polarization != lens.polarization:
        raise InputError("post_set.polarization", post_set.polarization,
                         f"the lens' polarisation '{lens.polarization}'")
    if post_set.levels != lens.levels:
        raise InputError("post_set.levels", post_set.levels, f"the lens' number of levels ({lens.levels})")
    t = post_set.t_focus if polarization == lens.polarization else post_set.t_pass
    ph = np.angle(t)
    if polarization == lens.polarization:
        # unwrap the focusing phases onto the ramp 2 pi k / N before scaling with wavelength
        target = 2 * np.pi * np.arange(lens.levels) / lens.levels
        ph = target + np.angle(np.exp(1j * (ph - target)))
    return np.abs(t) * np.exp(1j * ph * alpha)


def order_coefficients(tau: np.ndarray | None, levels: int, orders: np.ndarray) -> np.ndarray:
    """Complex amplitudes c_m of the diffraction orders exp(i m phi0) of an N-level element.

    ``tau=None`` is a continuous phase (c_1 = 1, all others 0).
    """
    orders = np.asarray(orders, dtype=int)
    if tau is None:
        return (orders == 1).astype(complex)
    n = levels
    k = np.arange(n)
    ph = np.exp(-2j * np.pi * np.outer(orders, k) / n)
    return _sinc(orders / n) * (ph @ tau) / n


@dataclass(frozen=True)
class Pupil:
    """One focusing diffraction order in direction-sine space, at one wavelength and field.

    All lengths um. ``center``: centre of the support disk in s (= s0); ``radius``: its radius
    (NA lambda / lambda0 / m). ``amplitude_factor``: complex order coefficient c_m (post set,
    quantisation, chromatic order efficiency). ``lattice``: include the lattice-sampling factor.
    ``z_um``: the plane where the field is evaluated (the sensor, default the design focal length).
    """

    lens: LensDesign
    wavelength_um: float
    s0: np.ndarray
    z_um: float
    order: int = 1
    amplitude_factor: complex = 1.0 + 0j
    lattice: bool = False

    @property
    def k(self) -> float:
        return 2 * np.pi / self.wavelength_um

    @property
    def alpha(self) -> float:
        """lambda0 / lambda / m: s - s0 = w / alpha."""
        return self.lens.wavelength_um / self.wavelength_um / self.order

    @property
    def center(self) -> np.ndarray:
        return np.asarray(self.s0, dtype=float)

    @property
    def radius(self) -> float:
        return design_na(self.lens) / self.alpha

    def w_of(self, sx: np.ndarray, sy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a = self.alpha
        return a * (sx - self.s0[0]), a * (sy - self.s0[1])

    def phase(self, sx: np.ndarray, sy: np.ndarray) -> np.ndarray:
        """Phi(s) (rad) up to a constant (the constant k z is dropped for precision)."""
        wx, wy = self.w_of(sx, sy)
        w2 = wx * wx + wy * wy
        k0m = 2 * np.pi / self.lens.wavelength_um * self.order
        s2 = sx * sx + sy * sy
        cs = np.sqrt(np.maximum(1.0 - s2, 0.0))
        if self.lens.phase_poly_rad:
            # stationary value of the full radial phase: m [k0 f0 rho^2 / (L (L + f0)) + psi - rho psi']
            from metafovea.lens import direction_sine_over_r  # lens stage (rank 3): allowed

            f0 = self.lens.f_um
            wa = np.sqrt(w2)
            rho = radius_of_direction_sine(self.lens, wa)
            L = np.sqrt(rho * rho + f0 * f0)
            psi, rpsi = _focus_added_phase(self.lens, rho)
            # + k0 rho (|w| - g(rho)): zero at the stationary point, and it makes the value stationary in rho (a
            # rounding error of the inverse map enters at second order)
            miss = k0m * rho * (wa - rho * direction_sine_over_r(self.lens, rho))
            lens_part = k0m * f0 * rho * rho / (L * (L + f0)) + self.order * (psi - rpsi) + miss
            return lens_part - self.k * self.z_um * s2 / (1.0 + cs)
        cw = np.sqrt(1.0 - w2)
        # m k0 f0 (1 - c_w) + k z (c_s - 1), each written without cancellation; the constant k z is dropped
        return k0m * self.lens.f_um * w2 / (1.0 + cw) - self.k * self.z_um * s2 / (1.0 + cs)

    def amplitude(self, sx: np.ndarray, sy: np.ndarray) -> np.ndarray:
        """Complex amplitude P(s) inside the support disk (caller restricts to the disk)."""
        wx, wy = self.w_of(sx, sy)
        w2 = wx * wx + wy * wy
        if self.lens.phase_poly_rad:
            from metafovea.lens import direction_sine_over_r, direction_sine_slope  # lens stage: allowed

            rho = radius_of_direction_sine(self.lens, np.sqrt(w2))
            jac = direction_sine_over_r(self.lens, rho) * direction_sine_slope(self.lens, rho)  # d^2 w / d^2 rho
            amp = self.alpha / (self.wavelength_um * np.sqrt(jac))
        else:
            cw2 = 1.0 - w2
            amp = self.lens.f_um * self.alpha / (self.wavelength_um * cw2)
        if self.lattice:
            q = self.lens.period_um / self.lens.wavelength_um
            amp = amp * _sinc(q * self.order * wx) * _sinc(q * self.order * wy)
        return self.amplitude_factor * amp

    def ray_landing(self, sx: np.ndarray, sy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where the geometric ray of direction s meets the plane z (um): -(1/k) grad Phi."""
        wx, wy = self.w_of(sx, sy)
        cs = np.sqrt(1.0 - sx * sx - sy * sy)
        if self.lens.phase_poly_rad:
            from metafovea.lens import direction_sine_over_r  # lens stage (rank 3): allowed

            # the ray leaves the lens point rho(w) = -w / (g / rho) (the stationary point)
            h = direction_sine_over_r(self.lens, radius_of_direction_sine(self.lens, np.hypot(wx, wy)))
            return (-wx / h + self.z_um * sx / cs, -wy / h + self.z_um * sy / cs)
        cw = np.sqrt(1.0 - wx * wx - wy * wy)
        # -(1/k) grad Phi; the factor m k0 f0 alpha / k equals f0 exactly
        f0 = self.lens.f_um
        return (-f0 * wx / cw + self.z_um * sx / cs, -f0 * wy / cw + self.z_um * sy / cs)

    def lens_ray_landing(self, rx: np.ndarray, ry: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where the ray from the lens point (rx, ry) (um) meets the plane z (um): traced forwards, the point plus
        ``z s / c_s`` with ``s = s0 + w(rho) / alpha`` (no inverse map: any ``phase_poly_rad``, monotone or not)."""
        from metafovea.lens import direction_sine_over_r  # lens stage (rank 3): allowed

        h = direction_sine_over_r(self.lens, np.hypot(rx, ry))
        sx = self.s0[0] - rx * h / self.alpha
        sy = self.s0[1] - ry * h / self.alpha
        cs = np.sqrt(np.maximum(1.0 - sx * sx - sy * sy, 1e-12))
        return rx + self.z_um * sx / cs, ry + self.z_um * sy / cs

    def chief_ray_um(self) -> np.ndarray:
        s = self.s0
        cs = math.sqrt(1.0 - float(s @ s))
        return self.z_um * s / cs

    def li_wolf(self) -> tuple[Pupil, float]:
        """The direction-sine model corrected for the focal shift: ``(pupil at z_D, m)`` with ``m = f'/z`` and
        ``z_D = f' (2 - f'/z)`` (``f' = f0 lambda0 / (m_order lambda)``), such that the field at ``(x, z)`` is
        ``m`` times this pupil's field at ``m x``. In the Fresnel approximation this is exact (Li and Wolf, Opt.
        Commun. 39, 211 (1981)): the converging wave's amplitude ``f'/z``, its scale and its defocus, which the Debye
        integral misses at first order in ``1 - f'/z``. The plain hyperbola on axis only (identity otherwise, and in
        focus); what it leaves is :meth:`rim_phase_error`."""
        if float(np.hypot(*self.s0)) > 0 or self.lens.phase_poly_rad:
            return self, 1.0
        fp = self.lens.f_um * self.alpha
        m = fp / self.z_um
        if m == 1.0:
            return self, 1.0
        return replace(self, z_um=fp * (2.0 - m)), m

    def rim_phase_error(self) -> float:
        """Phase error (rad) of the direction-sine (Debye) model's rim wave at the axis of the plane z.

        Stationary phase maps the lens into direction sines exactly inside the aperture; what it changes is the
        wave diffracted by the rim. On the axis the exact (Rayleigh-Sommerfeld) field is the centre's wave plus
        the rim's, their phase difference ``k (L_z - z) - m k0 (L_f - f0)`` (``L_z = sqrt(R^2 + z^2)``,
        ``L_f = sqrt(R^2 + f0^2)``); the direction-sine integral, evaluated at the plane :meth:`li_wolf` gives it,
        puts the rim at ``Phi(S) - Phi(0)``. Uncorrected the difference grows as ``pi N_F eps^2`` (Fresnel number
        ``N_F = R^2 / (lambda0 f0)``, ``eps`` the fractional focal shift or defocus: Li and Wolf 1981); the
        correction removes that paraxial part and leaves the rest, the smaller the lower the NA (BENCHMARKS.md).
        0 for a pupil off axis or of a lens with ``phase_poly_rad`` (their models are not bounded by it;
        :mod:`metafovea.optics.psf`)."""
        if float(np.hypot(*self.s0)) > 0 or self.lens.phase_poly_rad:
            return 0.0
        R, f0, z = self.lens.radius_um, self.lens.f_um, self.z_um
        z_model = self.li_wolf()[0].z_um  # the plane the corrected model evaluates
        k0m = 2 * np.pi / self.lens.wavelength_um * self.order
        exact = self.k * R * R / (math.hypot(R, z) + z) - k0m * R * R / (math.hypot(R, f0) + f0)
        na = self.lens.na
        S = na / self.alpha
        if not S < 1.0:
            return math.inf
        debye = (k0m * f0 * na * na / (1.0 + math.sqrt(1.0 - na * na))
                 - self.k * z_model * S * S / (1.0 + math.sqrt(1.0 - S * S)))
        return float(exact - debye)

    def focal_shift_ratio(self) -> float:
        """``1 - f' / z``: the plane z relative to the focus ``f' = f0 lambda0 / (m lambda)`` of this wavelength's
        focusing order (0 in focus). The exact field there is, paraxially, ``(f'/z)`` times the direction-sine
        field at scaled coordinates ``x f'/z`` and defocus ``(z - f') f'/z`` (Li and Wolf 1981): the amplitude
        and scale the Debye model misses, an O(``1 - f'/z``) relative error of the PSF."""
        return 1.0 - self.lens.f_um * self.alpha / self.z_um

    def evanescent_gap(self) -> float:
        """1 - (|s0| + radius): > 0 when the whole disk propagates."""
        return 1.0 - (float(np.hypot(*self.s0)) + self.radius)

    def lattice_anisotropy(self) -> float:
        """Largest relative azimuthal variation of the lattice factor at the rim (0 without lattice)."""
        if not self.lattice:
            return 0.0
        q = self.lens.period_um / self.lens.wavelength_um * self.order
        w = design_na(self.lens)
        a = float(np.sinc(q * w))
        b = float(np.sinc(q * w / math.sqrt(2)) ** 2)
        return abs(a - b) / max(a, b)


@dataclass(frozen=True)
class HazeOrder:
    """A non-focusing order drawn as a uniform geometric disk on the sensor plane."""

    order: int
    power_fraction: float  #: |c_m|^2 (times the mean lattice factor): fraction of the incident power
    radius_um: float  #: geometric blur radius on the plane z
    center_um: tuple[float, float]


@dataclass(frozen=True)
class PupilSet:
    """Everything a lens sends to the plane z at one wavelength and field for one polarisation."""

    focus: Pupil | None  #: the focusing order (None when its coefficient vanishes)
    haze: tuple[HazeOrder, ...]
    coefficients: dict[int, complex] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)


def build_pupils(lens: LensDesign, wavelength_um: float, *, field_deg: ArrayLike = 0.0,
                 post_set: PostSet | None = None, polarization: str | None = None,
                 quantize: bool = True, lattice: bool = True, z_um: float | None = None,
                 orders: int = 6) -> PupilSet:
    """Pupil of the focusing order plus haze orders for one wavelength, field and polarisation.

    ``polarization`` defaults to the lens' own; for the other one the lens acts through its pass-through
    transmission (``PostSet.t_pass``): mostly an unfocused plane wave (order 0, haze) plus whatever
    level-to-level variation of ``t_pass`` focuses. ``quantize=False`` with no post set gives the
    continuous-phase lens (c_1 = 1). ``lattice`` applies the lattice-sampling factor to the focusing
    order. ``orders``: haze orders -orders..orders are kept (their power is tiny per pixel). The haze disks' radii
    come from the hyperbola's order focal lengths (``phase_poly_rad`` changes them by its focal spread: a uniform
    disk is a rough stand-in either way).
    """
    wl = check_positive("wavelength_um", wavelength_um, "um", hi=1e4)
    pol = lens.polarization if polarization is None else check_choice("polarization", polarization, ("x", "y"))
    s0 = field_direction(field_deg)
    z = lens.f_um if z_um is None else check_positive("z_um", z_um, "um")
    n = check_int("orders", orders, 1, 64)
    tau = level_transmissions(lens, post_set, pol, wl, quantize)
    if tau is None and pol != lens.polarization:
        tau = np.ones(lens.levels, dtype=complex)  # continuous lens, ideal pass-through
    ms = np.arange(-n, n + 1)
    c = order_coefficients(tau, lens.levels, ms)
    coeffs = {int(m): complex(v) for m, v in zip(ms, c)}
    c1 = coeffs.get(1, 0j)
    focus = None
    if abs(c1) > 1e-9:
        focus = Pupil(lens, wl, s0, z, 1, c1, lattice)
        gap = focus.evanescent_gap()
        if gap < EVANESCENT_MARGIN:
            lim = max_field_deg(lens, wl)
            raise InputError("field_deg", field_deg,
                             f"|field| <= {lim:.3f} deg for lens '{lens.name}' at {wl:g} um "
                             "(beyond it the rim of the lens sends light into evanescent directions)")
    cs = math.sqrt(1.0 - float(s0 @ s0))
    chief = tuple(float(v) for v in z * s0 / cs)
    haze = []
    R = lens.radius_um
    for m, v in coeffs.items():
        if m == 1 or abs(v) ** 2 < 1e-14:
            continue
        if m == 0:
            rad = R
        else:
            fm = lens.f_um * lens.wavelength_um / (wl * m)  # signed focal length of order m
            rad = R * abs(1.0 - z / fm)
            # an order that focuses on (or near) this plane (lambda0 / lambda = m) is a diffraction-limited
            # spot, not a point: its first-zero radius 0.61 lambda / NA_m = 0.61 lambda0 / (NA |m|)
            rad = max(rad, 0.60983 * lens.wavelength_um / (lens.na * abs(int(m))))
        haze.append(HazeOrder(int(m), float(abs(v) ** 2), float(max(rad, 1e-9)), chief))
    info = {"order_efficiency": float(abs(c1) ** 2), "haze_power": float(sum(h.power_fraction for h in haze)),
            "polarization": pol}
    return PupilSet(focus, tuple(haze), coeffs, info)

"""A differentiable imaging model: the broadband PSF of one channel in JAX, per field point.

What is modelled (the production model of :mod:`metafovea.optics.psf` and :mod:`metafovea.optics.sensor`,
as pure JAX functions of the quantities a co-design changes)
-------------------------------------------------------------------------------------------------------------
The focusing lens carries, at every wavelength, the structural phase (issue 33's contract)

    phi(rho) = -k0 (sqrt(rho^2 + f0^2) - f0) + A(rho),    A(rho) = sum_j a_j (rho / R)^(2 j)

(``a_j``: ``phase_poly_rad``, radians at the design wavelength, ``R`` the lens radius; for ``phase_sign = +1``
the whole phase and the time convention flip together, so the added phase enters as ``-a_j``). Its focusing
(m = 1) order has the amplitude ``c_1(lambda)`` of :func:`metafovea.optics.pupil.order_coefficients`, computed
from the level transmissions ``t_focus[lambda, k]`` of the post set at that wavelength (from RCWA, a JAX
surrogate of it, or :func:`level_table`: production's phase scaling ``lambda0 / lambda`` of a single-wavelength
post set). The lattice factor is ``sinc(p d_x phi / 2 pi) sinc(p d_y phi / 2 pi)`` (the phase step per site;
:mod:`metafovea.optics.pupil`'s ``sinc(p w / lambda0)`` for the hyperbola). Orders m != 1 are the haze: uniform
disks of power ``|c_m|^2`` (sensor grid only, as :func:`metafovea.optics.sensor.sensor_psf`). Through the
camera's train (:mod:`metafovea.optics.train`) each wavelength is multiplied by
``T_b^2 G_L(lambda) G_O(lambda) V(0) |sum_k p_k t_pass[lambda, k]|^2``: the bare faces, the two wafers'
reflections and absorption, the other lens' clear aperture and its coherent pass-through ``|d_0|^2`` (the
focusing metasurface's own transmission is already in ``c_m``). The band PSF is the weighted sum over the
wavelengths. Normalisation as :class:`metafovea.optics.psf.PSF`: the fraction of the power incident on the lens
aperture (unit plane wave in the channel's polarisation) per grid cell (fine grid) or per pixel (sensor grid).

Methods (chosen per field point by :func:`imaging_model`; float64 throughout, see :func:`x64`)
----------------------------------------------------------------------------------------------
``debye``  on axis: the direction-sine (Debye) integral of production's ``hankel`` engine, written over the
           aperture radius instead of the direction sine, which makes it valid for any radial phase: the
           lens point ``rho`` sends its light into ``k s = phi'(rho)`` with the stationary-phase weight
           ``sqrt(|phi'' phi' / rho|) / 2 pi`` and the pupil phase ``phi - rho phi' + k z (sqrt(1 - s^2) - 1)``,
               U(r) = int_0^R rho c_1 L(rho) sqrt(|phi'' phi'/rho|) exp(i Phi(rho)) J0(|phi'(rho)| r) d rho
           (Gauss-Legendre nodes from the phase range, ``L`` the azimuthally averaged lattice factor, as
           production). ``J0(|phi'| r)`` does not depend on the wavelength: one Bessel matrix serves the band.
           For the hyperbola it is production's integral after the change of variable ``s(rho)``, so both agree
           to quadrature error, with production's focal-shift correction (``Pupil.li_wolf``: each wavelength's
           model at ``z_D`` and radii ``m r``, times ``m^2``, ``m = f'/z`` with the hyperbola's focus ``f'``; a
           Lagrange resampling per wavelength). Its model error against the exact propagation is production's
           (``psf.debye_error_bound``). A model with added-phase coefficients (co-design) has no single focus
           and goes uncorrected, as production's direction-sine engines do for such lenses (not bounded: ``rs``
           is exact); the mapping rho -> s must stay monotonic (no caustic inside the aperture: ``phi''`` and
           ``phi'/rho`` of one sign).
``rs``     any field: the first Rayleigh-Sommerfeld integral over the hard-edged aperture, exact kernel at every
           (node, output) pair, Gauss nodes over the disk (rows ``v = R sin t``, ``u`` between the row's ends:
           the edge costs nothing) sized from the largest slope of the lens-plus-kernel phase towards the window
           (plus the bound on the added phase's slope), per wavelength. Cost ~ nodes x outputs: small lenses,
           and the paper's lenses near focus on small windows (the nodes grow with the wavelength's defocus);
           the output is chunked and rematerialised so that gradients do not store the kernel.

On the sensor grid the fine samples (``n_sub`` per pixel, below the intensity Nyquist pitch) are integrated
over the pixels by production's band-limited box filter (:func:`metafovea.optics.sensor.box_integrate`, here in
JAX); on axis the radial intensity is sampled on a uniform radius grid and put on the fine grid by 8-point
Lagrange interpolation (step from the intensity band limit: interpolation error < 1e-5 of the peak).

Everything geometric (nodes, grids, haze disks, train gains, interpolation weights) is fixed when the model is
built (numpy); the model's functions of ``(phase_poly_rad, t_focus, t_pass)`` are pure and jit-able, and
``jax.grad`` goes through all of them. ``J0`` / ``J1`` are evaluated in JAX (power series below 12,
Hankel's asymptotic series above; 1e-12 absolute).

File map: :func:`x64` (scoped float64), :func:`level_table` (production's per-wavelength level transmissions),
:func:`train_gains` (the train's static factors per wavelength), :func:`imaging_model` (builds an
:class:`ImagingModel`: ``band_psf``, ``psf_per_wavelength``, ``mtf_area``), :func:`channel_model` and
:func:`channel_level_tables` (a camera channel: its lens, distance, pixel grid and train), :func:`mtf_area` (the
co-design objective on any PSF array), :func:`ray_map_is_monotonic` (the debye engine's condition).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import ArrayLike

from metafovea.config import LensDesign, SystemDesign
from metafovea.errors import InputError, check_choice, check_int, check_positive, check_range
from metafovea.io import use_jax_cache
from metafovea.library.postset import PostSet

from .propagate import _gl, disk_nodes, nodes_for_phase
from .psf import check_wavelengths, diffraction_radius_um, nyquist_pitch_um
from .pupil import field_direction, level_transmissions, max_field_deg
from .sensor import disk_pixels

use_jax_cache()  # before this module compiles anything (JAX checks once per process)

#: engines of :func:`imaging_model` ('auto': debye on axis, rs off axis)
JAX_ENGINES = ("auto", "debye", "rs")
#: haze orders -HAZE_ORDERS..HAZE_ORDERS (m != 1), as :func:`metafovea.optics.pupil.build_pupils`
HAZE_ORDERS = 6
#: complex kernel elements per chunk of the rs engine (memory ~ 16 bytes each, a few copies)
RS_CHUNK = 2_000_000


def x64() -> Any:
    """Context manager for float64 JAX (scoped; the global flag is not touched): ``with jaxpsf.x64(): ...``.

    The models need it (phases of 1e5 rad are summed); their functions raise an InputError outside it.
    """
    return jax.enable_x64(True)


def _require_x64() -> None:
    if jnp.zeros(1).dtype != jnp.float64:
        raise InputError("jax float64", "disabled", "run the model inside `with metafovea.optics.jaxpsf.x64():` "
                         "(or with jax_enable_x64): phases of ~1e5 rad need float64")


# ----------------------------------------------------------------------------------------------
# Bessel functions J0, J1 (float64, differentiable J0)
# ----------------------------------------------------------------------------------------------
_SERIES_J0 = [(-1) ** k / math.factorial(k) ** 2 for k in range(35)]
_SERIES_J1 = [(-1) ** k / (math.factorial(k) * math.factorial(k + 1)) for k in range(35)]


def _asym_coefficients(nu: int, n: int = 23) -> list[float]:
    mu, a, out = 4 * nu * nu, 1.0, [1.0]
    for k in range(1, n + 1):
        a = a * (mu - (2 * k - 1) ** 2) / (k * 8)
        out.append(a)
    return out


_ASYM = {0: _asym_coefficients(0), 1: _asym_coefficients(1)}


def _bessel01(x: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """(J0(x), J1(x)) for x >= 0: power series below 12, Hankel's asymptotic expansion above (error < 1e-12)."""
    xs = jnp.minimum(x, 12.0)
    y = 0.25 * xs * xs  # the coefficients carry the signs
    s0 = jnp.zeros_like(x)
    s1 = jnp.zeros_like(x)
    for c0, c1 in zip(reversed(_SERIES_J0), reversed(_SERIES_J1)):
        s0 = s0 * y + c0
        s1 = s1 * y + c1
    xl = jnp.maximum(x, 12.0)
    inv = 1.0 / xl
    big = []
    for nu in (0, 1):
        a = _ASYM[nu]
        P = jnp.zeros_like(x)
        Q = jnp.zeros_like(x)
        for k in range(len(a) - 1, 0, -1):  # Horner in 1/x over the two interleaved series
            sgn = (-1) ** (k // 2)
            if k % 2 == 0:
                P = (P + sgn * a[k]) * inv
                Q = Q * inv
            else:
                Q = (Q + sgn * a[k]) * inv
                P = P * inv
        P = P + 1.0
        chi = xl - (0.5 * nu + 0.25) * math.pi
        big.append(jnp.sqrt(2.0 / (math.pi * xl)) * (P * jnp.cos(chi) - Q * jnp.sin(chi)))
    small = x < 12.0
    return jnp.where(small, s0, big[0]), jnp.where(small, 0.5 * xs * s1, big[1])


@jax.custom_jvp
def bessel_j0(x: jnp.ndarray) -> jnp.ndarray:
    """J0(x) for x >= 0 in JAX (float64 accurate to 1e-12; derivative -J1)."""
    return _bessel01(x)[0]


@bessel_j0.defjvp
def _bessel_j0_jvp(primals: tuple[Any, ...], tangents: tuple[Any, ...]) -> tuple[Any, Any]:
    (x,), (t,) = primals, tangents
    j0, j1 = _bessel01(x)
    return j0, -j1 * t


# ----------------------------------------------------------------------------------------------
# the phase and the order coefficients
# ----------------------------------------------------------------------------------------------
def _added(a: jnp.ndarray, rho: jnp.ndarray, R: float) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """(A, A' / rho, A'') of ``A(rho) = sum_j a_j (rho / R)^(2 j)`` (A'/rho is regular at 0)."""
    u = (rho / R) ** 2
    A = jnp.zeros_like(rho)
    Ap_r = jnp.zeros_like(rho)
    App = jnp.zeros_like(rho)
    for j in range(a.shape[0], 0, -1):  # Horner in u
        aj = a[j - 1]
        A = (A + aj) * u
        Ap_r = Ap_r * u + 2 * j * aj / (R * R)
        App = App * u + 2 * j * (2 * j - 1) * aj / (R * R)
    return A, Ap_r, App


def ray_map_is_monotonic(lens: LensDesign, phase_poly_rad: ArrayLike, n: int = 4001) -> bool:
    """True when the lens point -> direction map of the phase is one to one over the aperture (``phi''`` and
    ``phi' / rho`` negative on a grid of ``n`` radii): the condition of the debye engine's stationary phase."""
    a = -lens.phase_sign * np.asarray(phase_poly_rad, dtype=float).reshape(-1)
    R, f = lens.radius_um, lens.f_um
    k0 = 2 * math.pi / lens.wavelength_um
    rho = np.linspace(0.0, R, n)
    L = np.sqrt(rho * rho + f * f)
    u = (rho / R) ** 2
    ap_r = sum(2 * (j + 1) * c * u ** j for j, c in enumerate(a)) / (R * R)
    app = sum(2 * (j + 1) * (2 * j + 1) * c * u ** j for j, c in enumerate(a)) / (R * R)
    return bool(np.all(-k0 / L + ap_r < 0) and np.all(-k0 * (f / L) ** 3 / f + app < 0))


def lens_coefficients(lens: LensDesign) -> np.ndarray:
    """The lens' own added-phase coefficients (``LensDesign.phase_poly_rad`` where the design has them, else none):
    the default of the model's ``phase_poly_rad``."""
    return np.asarray(getattr(lens, "phase_poly_rad", ()), dtype=float).reshape(-1)


def order_coefficient(tau: jnp.ndarray, levels: int, order: int) -> jnp.ndarray:
    """c_m of :func:`metafovea.optics.pupil.order_coefficients` in JAX: ``tau`` (..., N) -> (...)."""
    k = np.arange(levels)
    ph = np.exp(-2j * np.pi * order * k / levels)
    return float(np.sinc(order / levels)) * (tau @ ph) / levels


def level_table(lens: LensDesign, post_set: PostSet | None, polarization: str | None,
                wavelengths_um: ArrayLike) -> np.ndarray:
    """(K, N) complex level transmissions per wavelength as production computes them from a post set at one
    wavelength (:func:`metafovea.optics.pupil.level_transmissions`: phases scaled by ``lambda0 / lambda``);
    ``post_set=None``: ideal posts. ``polarization`` None: the lens' own (``t_focus``); the other: ``t_pass``."""
    pol = lens.polarization if polarization is None else check_choice("polarization", polarization, ("x", "y"))
    wl = np.atleast_1d(np.asarray(wavelengths_um, dtype=float)).reshape(-1)
    return np.array([level_transmissions(lens, post_set, pol, float(w), True) for w in wl])


@dataclass(frozen=True)
class TrainGains:
    """Static factors of a channel's optical train per wavelength (see :func:`train_gains`)."""

    gain: np.ndarray  #: (K,) T_b^2 G_L G_O V(0): everything but the coherent pass-through
    pass_fractions: np.ndarray  #: (N,) level fractions p_k of the other lens over the bundle's footprint
    channel: str
    metasurface_transmission: float  #: T_ms of the focusing lens (production's PSF power is relative to it)


def train_gains(system: SystemDesign, channel: str, post_sets: dict[str, PostSet],
                wavelengths_um: ArrayLike) -> TrainGains:
    """The train of ``channel`` ('foveal' | 'perifoveal') as static per-wavelength gains plus the other lens'
    level fractions, so that ``gain * |pass_fractions @ t_pass[lambda]|^2`` is production's
    :func:`metafovea.optics.train.channel_train` throughput per wavelength divided by ``T_ms`` (on axis, normal
    incidence: the posts' oblique response is not included)."""
    from .train import (
        _wafer_terms,
        bare_face_reflectance,
        channel_train,
        circle_overlap_fraction,
        level_fractions,
        silicon_absorption_per_cm,
    )

    check_choice("channel", channel, ("foveal", "perifoveal"))
    wl = np.atleast_1d(np.asarray(wavelengths_um, dtype=float)).reshape(-1)
    lenses = {"foveal": (system.foveal, system.lens_to_sensor_um[0]),
              "perifoveal": (system.perifoveal, system.lens_to_sensor_um[1])}
    (L, zL), (O, zO) = lenses[channel], lenses["perifoveal" if channel == "foveal" else "foveal"]
    plat = system.platform
    pol = L.polarization
    r_b = bare_face_reflectance(plat.n_substrate)
    alpha = silicon_absorption_per_cm(wl, plat.substrate_resistivity_ohm_cm, plat.substrate_dopant,
                                      plat.substrate_extra_absorption_per_cm)
    front = zL > zO
    gap = abs(zL - zO)
    samples = 1 << 16
    pL, _ = level_fractions(L, L.radius_um, samples=samples, rng=1)
    r_foot = L.radius_um * (abs(1.0 - gap / L.f_um) if front else 1.0)
    pO, _ = level_fractions(O, min(r_foot, O.radius_um), samples=samples, rng=2)
    t_msL, _, gL, _, _ = _wafer_terms(L, post_sets[L.polarization], pol, pL, wl, r_b, alpha,
                                      plat.substrate_thickness_um)
    _, _, gO, _, _ = _wafer_terms(O, post_sets[O.polarization], pol, pO, wl, r_b, alpha, plat.substrate_thickness_um)
    v0 = float(circle_overlap_fraction(r_foot, O.radius_um, 0.0))
    t_b = 1.0 - r_b
    del channel_train  # the reference these factors reproduce (tests compare)
    return TrainGains(np.asarray(t_b * t_b * gL * gO * v0, dtype=float), np.asarray(pO, dtype=float), channel,
                      float(t_msL))


def channel_lenses(system: SystemDesign, channel: str) -> tuple[LensDesign, LensDesign, float]:
    """(focusing lens, other lens, focusing lens-to-sensor distance in um) of ``channel``."""
    check_choice("channel", channel, ("foveal", "perifoveal"))
    if channel == "foveal":
        return system.foveal, system.perifoveal, float(system.lens_to_sensor_um[0])
    return system.perifoveal, system.foveal, float(system.lens_to_sensor_um[1])


def channel_level_tables(system: SystemDesign, channel: str, post_sets: dict[str, PostSet],
                         wavelengths_um: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """(t_focus, t_pass), each (K, N) complex: production's level transmissions of ``channel`` per wavelength
    (:func:`level_table` of the focusing lens' post set in its own polarisation, and of the other lens' set in the
    channel's polarisation): the inputs of a channel model for these post sets."""
    L, O, _ = channel_lenses(system, channel)
    return (level_table(L, post_sets[L.polarization], L.polarization, wavelengths_um),
            level_table(O, post_sets[O.polarization], L.polarization, wavelengths_um))


def channel_model(system: SystemDesign, channel: str, post_sets: dict[str, PostSet], *,
                  wavelengths_um: ArrayLike, weights: ArrayLike | None = None,
                  field_deg: float | tuple[float, float] = 0.0, size_px: int = 63, n_coefficients: int | None = None,
                  phase_bound_rad: ArrayLike | float | None = None, engine: str = "auto",
                  error: float = 1e-4) -> ImagingModel:
    """The differentiable sensor PSF of ``channel`` ('foveal' | 'perifoveal') of ``system``: its focusing lens at
    its lens-to-sensor distance, on the focal-plane pixel grid (sensor pitch / relay magnification, ``size_px``
    pixels), through the train (:func:`train_gains` of ``post_sets``, ``{'x': foveal set, 'y': perifoveal set}``).
    Evaluate it with ``channel_level_tables`` (or a surrogate's transmissions of the same shape)."""
    L, _, z = channel_lenses(system, channel)
    wl, w = check_wavelengths(L, wavelengths_um, weights)
    pitch = system.sensor.pixel_pitch_um / system.relay_magnification
    return imaging_model(L, wavelengths_um=wl, weights=w, field_deg=field_deg, pitch_um=pitch, size=size_px,
                         sensor=True, z_um=z, n_coefficients=n_coefficients, phase_bound_rad=phase_bound_rad,
                         train=train_gains(system, channel, post_sets, wl), engine=engine, error=error)


# ----------------------------------------------------------------------------------------------
# grids
# ----------------------------------------------------------------------------------------------
def _box_filters(n: int, n_sub: int) -> tuple[np.ndarray, int, np.ndarray]:
    pad = n + 2 * n_sub
    f = np.fft.rfftfreq(pad)
    shift = 0.5 if n_sub % 2 == 0 else 0.0
    H = n_sub * np.sinc(f * n_sub) * np.exp(2j * np.pi * f * shift)
    start = (n_sub - 1) // 2
    return H, pad, np.arange(start, n, n_sub)


def box_integrate_jax(I: jnp.ndarray, n_sub: int) -> jnp.ndarray:
    """:func:`metafovea.optics.sensor.box_integrate` in JAX: (n, n) fine samples -> (n / n_sub, n / n_sub) sums."""
    out = I
    for axis in (0, 1):
        n = out.shape[axis]
        H, pad, keep = _box_filters(n, n_sub)
        spec = jnp.fft.rfft(out, n=pad, axis=axis)
        shape = [1, 1]
        shape[axis] = -1
        conv = jnp.fft.irfft(spec * jnp.asarray(H).reshape(shape), n=pad, axis=axis)
        conv = jnp.take(conv, jnp.arange(n), axis=axis)
        out = jnp.take(conv, jnp.asarray(keep), axis=axis)
    return out


#: points of the Lagrange interpolation from the radial samples onto the grid, and the largest omega h it is
#: used at (omega: the intensity's band limit in rad/um): max error 1.07e-3 (omega h)^8 = 4e-6 of the peak
LAGRANGE_POINTS, LAGRANGE_OMEGA_H = 8, 0.5


def _lagrange(r_query: np.ndarray, h: float, n: int, points: int = LAGRANGE_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """Indices (Q, points) into samples ``j h`` (j = 0..n-1, mirrored at 0: the intensity is even in r) and the
    Lagrange weights (Q, points) of the ``points`` samples around each query (``points`` even)."""
    s = r_query / h
    i = np.floor(s).astype(np.int64)
    t = s - i
    offs = np.arange(points) - (points // 2 - 1)
    w = np.ones((r_query.size, points))
    for a, oa in enumerate(offs):
        for ob in offs:
            if ob != oa:
                w[:, a] *= (t - ob) / (oa - ob)
    idx = np.abs(i[:, None] + offs[None, :])
    if idx.size and idx.max() >= n:
        raise ValueError("radial samples do not cover the grid")
    return idx, w


# ----------------------------------------------------------------------------------------------
# the model
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ImagingModel:
    """A channel's band PSF at one field point as pure JAX functions (built by :func:`imaging_model`).

    Call ``band_psf(phase_poly_rad, t_focus, t_pass)``: ``phase_poly_rad`` (n,) float (the a_j; None: the lens'
    own, :func:`lens_coefficients`), ``t_focus``
    (K, N) complex level transmissions of the focusing lens per wavelength (None: continuous phase, c_1 = 1
    and no haze), ``t_pass`` (K, N) those of the other lens in this polarisation (needed with a train, ignored
    without). All static data are numpy arrays fixed at build time.
    """

    lens: LensDesign
    engine: str
    wavelengths_um: np.ndarray
    weights: np.ndarray
    field_deg: tuple[float, float]
    z_um: float
    pitch_um: float  #: output cell (pixel pitch on the sensor grid, sample pitch on the fine grid)
    size: int
    center_um: tuple[float, float]
    sensor: bool  #: pixel-integrated with haze (sensor_psf) or fine grid, focusing order only (psf)
    n_sub: int
    lattice: bool
    n_coefficients: int
    phase_bound_rad: np.ndarray
    train: TrainGains | None
    static: dict[str, Any] = field(repr=False, default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)

    # -- inputs ---------------------------------------------------------------------------------
    def _inputs(self, a: ArrayLike | None, t_focus: ArrayLike | None, t_pass: ArrayLike | None
                ) -> tuple[jnp.ndarray, jnp.ndarray | None, jnp.ndarray | None]:
        _require_x64()
        if a is None:
            a = lens_coefficients(self.lens)
        a = jnp.asarray(a, dtype=jnp.float64).reshape(-1)
        if a.shape[0] != self.n_coefficients:
            raise InputError("phase_poly_rad", tuple(a.shape), f"{self.n_coefficients} coefficients (as built)")
        if not isinstance(a, jax.core.Tracer):
            big = np.abs(np.asarray(a)) > self.phase_bound_rad * (1 + 1e-9) + 1e-12
            if big.any():
                raise InputError("phase_poly_rad", np.asarray(a).tolist(),
                                 f"|a_j| <= phase_bound_rad = {self.phase_bound_rad.tolist()} (the nodes' bound)")
            if self.engine == "debye" and self.n_coefficients and not ray_map_is_monotonic(self.lens, np.asarray(a)):
                raise InputError("phase_poly_rad", np.asarray(a).tolist(),
                                 "coefficients whose rays do not cross inside the aperture (phi'' < 0 and "
                                 "phi' / rho < 0 everywhere): the debye engine's stationary phase; use engine 'rs'")
        a = a * float(-self.lens.phase_sign)  # phase_sign = +1: the conjugate convention (module docstring)
        K, N = self.wavelengths_um.size, self.lens.levels
        tf = None if t_focus is None else jnp.asarray(t_focus, dtype=jnp.complex128)
        if tf is not None and tf.shape != (K, N):
            raise InputError("t_focus", tuple(tf.shape), f"({K}, {N}): wavelengths x levels")
        tp = None
        if self.train is not None:
            if t_pass is None:
                raise InputError("t_pass", None, f"({K}, {N}) pass-through level transmissions (a train is set)")
            tp = jnp.asarray(t_pass, dtype=jnp.complex128)
            if tp.shape != (K, N):
                raise InputError("t_pass", tuple(tp.shape), f"({K}, {N}): wavelengths x levels")
        return a, tf, tp

    def _c1(self, tf: jnp.ndarray | None) -> jnp.ndarray:
        if tf is None:
            return jnp.ones(self.wavelengths_um.size, dtype=jnp.complex128)
        return order_coefficient(tf, self.lens.levels, 1)

    def _gains(self, tp: jnp.ndarray | None) -> jnp.ndarray:
        """(K,) band weight times the train's factor per wavelength."""
        w = jnp.asarray(self.weights)
        if self.train is None:
            return w
        d0 = tp @ jnp.asarray(self.train.pass_fractions, dtype=jnp.complex128)
        return w * jnp.asarray(self.train.gain) * (d0.real ** 2 + d0.imag ** 2)

    # -- engines --------------------------------------------------------------------------------
    def _radial_intensity(self, a: jnp.ndarray, c1: jnp.ndarray) -> jnp.ndarray:
        """(K, M) intensity (power per um^2) at the radial samples, Debye engine."""
        st = self.static
        lens = self.lens
        R, f = lens.radius_um, lens.f_um
        k0 = 2 * math.pi / lens.wavelength_um
        rho, g = jnp.asarray(st["rho"]), jnp.asarray(st["rho_w"])
        Lh = jnp.sqrt(rho * rho + f * f)
        w = rho / Lh
        cw = f / Lh
        A, Ap_r, App = _added(a, rho, R)
        dphi_r = -k0 / Lh + Ap_r  # phi' / rho
        dphi = dphi_r * rho
        d2phi = -k0 * cw ** 3 / f + App
        sdet = jnp.sqrt(jnp.abs(d2phi * dphi_r))
        leg = k0 * f * w * w / (1.0 + cw) + A - rho * rho * Ap_r  # phi - rho phi'
        kr = jnp.abs(dphi)
        amp = rho * g * sdet
        if self.lattice:
            q = lens.period_um * kr / (2 * math.pi)
            th = (np.arange(16) + 0.5) * (np.pi / 32)
            lat = jnp.sinc(q[None, :] * np.cos(th)[:, None]) * jnp.sinc(q[None, :] * np.sin(th)[:, None])
            amp = amp * jnp.mean(lat, axis=0)
        k = jnp.asarray(2 * math.pi / self.wavelengths_um)[:, None]
        s = kr[None, :] / k
        cs = jnp.sqrt(jnp.maximum(1.0 - s * s, 0.0))
        Phi = leg[None, :] - k * jnp.asarray(st["lw_z"])[:, None] * s * s / (1.0 + cs)
        Q = (c1[:, None] * amp[None, :]) * jnp.exp(1j * Phi)  # (K, n)
        J = bessel_j0(jnp.asarray(st["r"])[:, None] * kr[None, :])  # (M_ext, n)
        U = Q @ J.T.astype(jnp.complex128)
        I = U.real ** 2 + U.imag ** 2
        if not st["lw"]:  # no focal-shift correction (in focus, or a model with added-phase coefficients)
            return I[:, :st["radial_samples"]]
        # at each wavelength's scaled radii m_k r (Lagrange, as onto the grid), times m_k^2
        gathered = jnp.take_along_axis(I[:, None, :], jnp.asarray(st["lw_idx"]).reshape(I.shape[0], 1, -1), axis=2)
        gathered = gathered.reshape(st["lw_idx"].shape)
        m = jnp.asarray(st["lw_m"])
        return (m * m)[:, None] * jnp.sum(gathered * jnp.asarray(st["lw_w"]), axis=-1)  # (K, M)

    def _rs_field(self, a: jnp.ndarray, c1: jnp.ndarray, xs: np.ndarray, ys: np.ndarray) -> jnp.ndarray:
        """(K, M) field at the points (xs, ys) (flattened), exact RS engine (each wavelength its own nodes)."""
        lens = self.lens
        R, f, z = lens.radius_um, lens.f_um, self.z_um
        k0 = 2 * math.pi / lens.wavelength_um
        s0 = field_direction(self.field_deg)
        M = xs.size
        out = []
        for i, (lam, nodes) in enumerate(zip(self.wavelengths_um, self.static["rs_nodes"])):
            px, py, W = (jnp.asarray(v) for v in nodes)
            rho2 = px * px + py * py
            Lh = jnp.sqrt(rho2 + f * f)
            A, Ap_r, _ = _added(a, jnp.sqrt(rho2), R)
            amp = W.astype(jnp.complex128)
            if self.lattice:
                q = lens.period_um / (2 * math.pi) * (-k0 / Lh + Ap_r)
                amp = amp * jnp.sinc(q * px) * jnp.sinc(q * py)
            k = 2 * math.pi / float(lam)
            src = c1[i] * amp * jnp.exp(1j * (-k0 * rho2 / (Lh + f) + A + k * (s0[0] * px + s0[1] * py)))
            J = px.shape[0]
            mc = max(1, min(M, RS_CHUNK // max(J, 1)))
            nc = -(-M // mc)
            pad = nc * mc - M
            ox = jnp.asarray(np.concatenate([xs, np.full(pad, xs[0])]).reshape(nc, mc))
            oy = jnp.asarray(np.concatenate([ys, np.full(pad, ys[0])]).reshape(nc, mc))
            pre = z / (1j * float(lam))

            @jax.checkpoint
            def chunk(o: tuple[jnp.ndarray, jnp.ndarray], px: jnp.ndarray = px, py: jnp.ndarray = py,
                      src: jnp.ndarray = src, k: float = k, pre: complex = pre) -> jnp.ndarray:
                x, y = o
                dx = x[:, None] - px[None, :]
                dy = y[:, None] - py[None, :]
                d2 = dx * dx + dy * dy
                r = jnp.sqrt(d2 + z * z)
                rz = d2 / (r + z)  # r - z without cancellation
                K = pre * (1.0 - 1.0 / (1j * k * r)) * jnp.exp(1j * k * rz) / (r * r)
                return K @ src

            out.append(jax.lax.map(chunk, (ox, oy)).reshape(nc * mc)[:M])
        return jnp.stack(out)

    # -- public functions -------------------------------------------------------------------------
    def psf_per_wavelength(self, phase_poly_rad: ArrayLike | None = None, t_focus: ArrayLike | None = None,
                           t_pass: ArrayLike | None = None) -> jnp.ndarray:
        """(K, size, size): each wavelength's PSF (unweighted; the train's factor included when set)."""
        return self._evaluate(phase_poly_rad, t_focus, t_pass, per_wavelength=True)

    def band_psf(self, phase_poly_rad: ArrayLike | None = None, t_focus: ArrayLike | None = None,
                 t_pass: ArrayLike | None = None) -> jnp.ndarray:
        """(size, size): the weighted band PSF (see the module docstring for the normalisation)."""
        return self._evaluate(phase_poly_rad, t_focus, t_pass, per_wavelength=False)

    def mtf_area(self, phase_poly_rad: ArrayLike | None = None, t_focus: ArrayLike | None = None,
                 t_pass: ArrayLike | None = None, *, f_max_cyc_per_um: float | None = None,
                 per_wavelength: bool = False) -> jnp.ndarray:
        """The co-design objective: MTF area to ``f_max_cyc_per_um`` (default: the grid's Nyquist 1 / (2 pitch)).

        ``per_wavelength=False``: :func:`mtf_area` of :meth:`band_psf` (the MTF of the band-integrated PSF, what the
        sensor sees); True: the band-weighted mean of each wavelength's MTF area."""
        f_max = 0.5 / self.pitch_um if f_max_cyc_per_um is None else f_max_cyc_per_um
        if not per_wavelength:
            return mtf_area(self.band_psf(phase_poly_rad, t_focus, t_pass), self.pitch_um, f_max)
        each = self.psf_per_wavelength(phase_poly_rad, t_focus, t_pass)
        areas = jnp.stack([mtf_area(each[i], self.pitch_um, f_max) for i in range(each.shape[0])])
        return jnp.asarray(self.weights) @ areas

    def _evaluate(self, a: ArrayLike | None, t_focus: ArrayLike | None, t_pass: ArrayLike | None,
                  per_wavelength: bool) -> jnp.ndarray:
        a, tf, tp = self._inputs(a, t_focus, t_pass)
        cache = self.static.setdefault("_jit", {})
        key = (per_wavelength, tf is None, tp is None)
        if key not in cache:
            cache[key] = jax.jit(lambda a_, tf_, tp_: self._core(a_, tf_, tp_, per_wavelength))
        return cache[key](a, tf, tp)

    def _core(self, a: jnp.ndarray, tf: jnp.ndarray | None, tp: jnp.ndarray | None,
              per_wavelength: bool) -> jnp.ndarray:
        c1 = self._c1(tf)
        g = self._gains(tp)  # (K,) weights x train
        if per_wavelength:
            g = g / jnp.asarray(self.weights)
        st = self.static
        P_in = math.pi * self.lens.radius_um ** 2
        n = self.size * self.n_sub
        cell = (self.pitch_um / self.n_sub) ** 2 / P_in
        if self.engine == "debye":
            Ir = self._radial_intensity(a, c1)  # (K, M)
            if not per_wavelength:
                Ir = (g @ Ir)[None]
            else:
                Ir = g[:, None] * Ir
            idx, wts = st["interp_idx"], st["interp_w"]
            vals = jnp.sum(Ir[:, idx] * jnp.asarray(wts)[None], axis=-1)  # (B, unique radii)
            fine = vals[:, st["grid_inverse"]].reshape(-1, n, n)
        else:
            U = self._rs_field(a, c1, st["gx"], st["gy"])  # (K, n*n)
            I = U.real ** 2 + U.imag ** 2
            fine = (g[:, None] * I) if per_wavelength else (g @ I)[None]
            fine = fine.reshape(-1, n, n)
        fine = fine * cell
        if self.sensor:
            out = jax.vmap(lambda x: box_integrate_jax(x, self.n_sub))(fine) if self.n_sub > 1 else fine
            if tf is not None and st["haze_maps"].shape[1]:
                cm = jnp.stack([order_coefficient(tf, self.lens.levels, int(m)) for m in st["haze_orders"]], axis=1)
                pw = cm.real ** 2 + cm.imag ** 2  # (K, orders)
                maps = jnp.asarray(st["haze_maps"])  # (K, orders, size, size)
                haze = jnp.einsum("ko,kohw->khw", pw, maps)
                out = out + (g[:, None, None] * haze if per_wavelength else jnp.einsum("k,khw->hw", g, haze)[None])
        else:
            out = fine
        return out if per_wavelength else out[0]


def mtf_area(psf: jnp.ndarray, pitch_um: float, f_max_cyc_per_um: float, *, pad: int = 2) -> jnp.ndarray:
    """Mean of the MTF over the frequency disk ``|f| <= f_max_cyc_per_um`` (1 for a point; the co-design
    objective with ``f_max`` the sensor's Nyquist frequency).

    ``psf``: (H, W) intensity on cells of ``pitch_um``; the MTF is ``|DFT(psf)| / sum(psf)`` on a grid ``pad``
    times finer in frequency, averaged over the frequency samples inside the disk (differentiable: ``|OTF|`` is
    smoothed by 1e-30 under the square root)."""
    psf = jnp.asarray(psf)
    H, W = psf.shape
    F = jnp.fft.fft2(psf, s=(pad * H, pad * W))
    otf = F / jnp.sum(psf)
    fx = np.fft.fftfreq(pad * W, pitch_um)
    fy = np.fft.fftfreq(pad * H, pitch_um)
    inside = (fy[:, None] ** 2 + fx[None, :] ** 2) <= f_max_cyc_per_um ** 2
    m = jnp.sqrt(otf.real ** 2 + otf.imag ** 2 + 1e-30)
    return jnp.sum(jnp.where(jnp.asarray(inside), m, 0.0)) / float(inside.sum())


# ----------------------------------------------------------------------------------------------
# building a model
# ----------------------------------------------------------------------------------------------
def _phase_slope_bound(bound: np.ndarray, R: float) -> float:
    """Largest |A'(rho)| (rad/um) over the aperture for |a_j| <= bound_j."""
    return float(sum(2 * (j + 1) * b for j, b in enumerate(bound))) / R


def _grid(center: np.ndarray, pitch: float, size: int, n_sub: int) -> tuple[np.ndarray, np.ndarray]:
    n = size * n_sub
    dx = pitch / n_sub
    ax = (np.arange(n) - (n - 1) / 2) * dx
    return center[0] + ax, center[1] + ax


def _debye_static(lens: LensDesign, wl: np.ndarray, z: float, center: np.ndarray, pitch: float, size: int,
                  n_sub: int, bound: np.ndarray, error: float, nodes: Any = None, focal_shift: bool = True
                  ) -> dict[str, Any]:
    """Radial nodes, radial samples and the interpolation from them onto the (fine) grid. ``focal_shift``: the
    focal-shift correction (the plain hyperbola; a model with added-phase coefficients has no single focus)."""
    R, f = lens.radius_um, lens.f_um
    k0 = 2 * math.pi / lens.wavelength_um
    slope_a = _phase_slope_bound(bound, R)
    n = size * n_sub
    dx = pitch / n_sub
    # grid radii: offsets are (2 i - (n - 1)) dx / 2; unique values of mx^2 + my^2
    m = 2 * np.arange(n) - (n - 1)
    key = (m[:, None] ** 2 + m[None, :] ** 2).ravel()
    uniq, inverse = np.unique(key, return_inverse=True)
    r_uniq = np.sqrt(uniq.astype(float)) * dx / 2
    r_max = float(r_uniq.max()) if r_uniq.size else 0.0
    kr_max = k0 * lens.na + slope_a  # largest |phi'| (rad/um)
    h = min(dx, LAGRANGE_OMEGA_H / (2 * kr_max)) if kr_max > 0 else dx
    n_r = int(math.ceil(r_max / h)) + LAGRANGE_POINTS
    idx, wts = _lagrange(r_uniq, h, n_r)
    # the focal-shift correction (production's Pupil.li_wolf, with the hyperbola's focus f' = f lambda0 / lambda):
    # wavelength k's intensity at r is m_k^2 times the model's at m_k r, the model evaluated at z_D,k
    fp = f * lens.wavelength_um / np.asarray(wl, dtype=float) if focal_shift else np.full(np.shape(wl), z)
    lw_m = fp / z
    lw_z = np.where(lw_m == 1.0, z, fp * (2.0 - lw_m))
    n_ext = int(math.ceil(r_max * max(1.0, float(lw_m.max())) / h)) + 2 * LAGRANGE_POINTS
    r_s = np.arange(max(n_r, n_ext)) * h
    lw = [_lagrange(np.arange(n_r) * h * m, h, r_s.size) for m in lw_m]
    lw_idx, lw_w = np.stack([a for a, _ in lw]), np.stack([b for _, b in lw])
    # radial nodes: the pupil phase's range over [0, R] plus the Bessel's, at the worst wavelength
    rr = np.linspace(0.0, R, 4001)
    Lh = np.sqrt(rr * rr + f * f)
    dphi = k0 * rr / Lh + slope_a
    d2 = k0 * (f / Lh) ** 3 / f + sum(2 * (j + 1) * (2 * j + 1) * b for j, b in enumerate(bound)) / (R * R)
    beta = 0.0
    for lam in wl:
        k = 2 * math.pi / lam
        s = np.minimum(dphi / k, 1 - 1e-9)
        # d Phi / d rho = -phi'' (rho + z s / c_s) with k s = phi' (< 0 when converging); the Bessel's phase
        # |phi'| r changes by |phi''| r per um of rho
        slope = d2 * (np.abs(rr - z * s / np.sqrt(1 - s * s)) + r_max)
        beta = max(beta, 0.5 * R * float(slope.max()))
    n_nodes = nodes_for_phase(beta, error * 1e-3, 8) if nodes is None else check_int("nodes", nodes, 2, 100000)
    x, w = _gl(n_nodes)
    return {"rho": 0.5 * R * (x + 1.0), "rho_w": 0.5 * R * w, "r": r_s, "interp_idx": idx, "interp_w": wts,
            "grid_inverse": inverse, "nodes": n_nodes, "radial_samples": n_r, "radial_step_um": h,
            "lw_m": lw_m, "lw_z": lw_z, "lw_idx": lw_idx, "lw_w": lw_w, "lw": bool(np.any(lw_m != 1.0))}


def _rs_static(lens: LensDesign, wl: np.ndarray, z: float, s0: np.ndarray, xs: np.ndarray, ys: np.ndarray,
               bound: np.ndarray, error: float, nodes: Any = None) -> dict[str, Any]:
    """Gauss nodes over the aperture disk for the exact RS engine, from the largest phase slope."""
    R, f = lens.radius_um, lens.f_um
    k0 = 2 * math.pi / lens.wavelength_um
    slope_a = _phase_slope_bound(bound, R)
    # probe the lens + kernel phase gradient on a polar set of aperture points towards the window's corners/centre
    rr = R * np.sqrt((np.arange(64) + 0.5) / 64)
    th = np.linspace(0, 2 * np.pi, 128, endpoint=False)
    qx = (rr[:, None] * np.cos(th)[None, :]).ravel()
    qy = (rr[:, None] * np.sin(th)[None, :]).ravel()
    rim = np.stack([R * np.cos(th), R * np.sin(th)], axis=1)
    qx, qy = np.concatenate([qx, rim[:, 0]]), np.concatenate([qy, rim[:, 1]])
    Lh = np.sqrt(qx * qx + qy * qy + f * f)
    probes = [(x, y) for x in (xs.min(), xs.mean(), xs.max()) for y in (ys.min(), ys.mean(), ys.max())]
    q = error * 1e-3
    out = []
    counts = []
    for lam in wl:
        k = 2 * math.pi / lam
        gx_max = gy_max = 0.0
        for ox, oy in probes:
            r = np.sqrt((ox - qx) ** 2 + (oy - qy) ** 2 + z * z)
            gx = -k0 * qx / Lh + k * s0[0] + k * (qx - ox) / r
            gy = -k0 * qy / Lh + k * s0[1] + k * (qy - oy) / r
            gx_max = max(gx_max, float(np.abs(gx).max()))
            gy_max = max(gy_max, float(np.abs(gy).max()))
        n_r = nodes_for_phase((1.1 * gx_max + slope_a) * R, q, 4)
        n_t = nodes_for_phase((1.1 * gy_max + slope_a) * R * 0.5 * np.pi, q, 4)
        if nodes is not None:
            n_t, n_r = (check_int("nodes", int(v), 2, 100000) for v in np.broadcast_to(np.asarray(nodes), (2,)))
        u, v, w = disk_nodes(np.zeros(2), R, n_t, n_r)
        vv = np.broadcast_to(v[:, None], u.shape)
        out.append((u.ravel().copy(), vv.ravel().copy(), w.ravel().copy()))
        counts.append([n_t, n_r])
    return {"rs_nodes": out, "nodes": counts}


def _haze_static(lens: LensDesign, wl: np.ndarray, z: float, chief: np.ndarray, x0: float, y0: float, pitch: float,
                 size: int) -> tuple[np.ndarray, np.ndarray]:
    """Haze orders and their unit-power disk maps (K, orders, size, size), geometry of build_pupils."""
    orders = np.array([m for m in range(-HAZE_ORDERS, HAZE_ORDERS + 1) if m != 1])
    R = lens.radius_um
    maps = np.zeros((wl.size, orders.size, size, size))
    for i, lam in enumerate(wl):
        for j, m in enumerate(orders):
            if m == 0:
                rad = R
            else:
                fm = lens.f_um * lens.wavelength_um / (lam * m)
                rad = max(R * abs(1.0 - z / fm), 0.60983 * lens.wavelength_um / (lens.na * abs(int(m))))
            maps[i, j] = disk_pixels((chief[0], chief[1]), max(rad, 1e-9), x0, y0, pitch, size)
    return orders, maps


def imaging_model(lens: LensDesign, *, wavelengths_um: ArrayLike | None = None, weights: ArrayLike | None = None,
                  field_deg: float | tuple[float, float] = 0.0, pitch_um: float, size: int, sensor: bool = False,
                  center_um: tuple[float, float] | None = None, n_sub: int | None = None, z_um: float | None = None,
                  lattice: bool = True, n_coefficients: int | None = None,
                  phase_bound_rad: ArrayLike | float | None = None,
                  train: TrainGains | None = None, engine: str = "auto", error: float = 1e-4,
                  nodes: int | tuple[int, int] | None = None) -> ImagingModel:
    """Build the differentiable band PSF of one channel at one field point (see the module docstring).

    Parameters
    ----------
    lens : LensDesign
        The focusing lens.
    wavelengths_um, weights : array_like, shape (K,), um and relative weights, optional
        The band (default: the design wavelength alone); weights are normalised to sum 1.
    field_deg : float or (float, float), deg
        Field angle (one number: along x).
    pitch_um : float, um
        Output cell: the pixel pitch on the focal plane (``sensor=True``) or the sample pitch (``sensor=False``,
        at most the intensity's Nyquist pitch ``lambda0 / (4 NA)``).
    size : int
        Cells per side (odd: one cell centred on ``center_um``).
    sensor : bool
        True: :func:`metafovea.optics.sensor.sensor_psf`'s grid and content (pixels of ``pitch_um`` centred on
        the chief ray, ``n_sub`` fine samples per pixel integrated over the pixels, haze disks included); False:
        :func:`metafovea.optics.psf.psf`'s (samples, the focusing order only).
    center_um : (float, float), um, optional
        Centre of the grid (default: the chief ray's landing point; the sensor grid is always centred there).
    n_sub : int, optional
        Fine samples per pixel (default as sensor_psf: ``ceil(pitch / (0.95 lambda0 / (4 NA)))``).
    z_um : float, um, optional
        Lens-to-plane distance (default f).
    lattice : bool
        Lattice-sampling factor of the posts (production's default: False for psf, True for sensor_psf).
    n_coefficients : int, optional
        Number of added-phase coefficients a_j the functions take (default: as many as the lens' own
        ``phase_poly_rad``, 0 for the hyperbola).
    phase_bound_rad : float or array_like, shape (n,), rad, optional
        Bound on |a_j| the quadrature is sized for (checked on concrete inputs; default twice the lens' own).
    train : TrainGains, optional
        The channel's train (:func:`train_gains`); the functions then need ``t_pass``.
    engine : {'auto', 'debye', 'rs'}
        'auto': 'debye' on axis, 'rs' off axis.
    error : float
        Quadrature error wanted, relative to the peak (nodes are sized for ``error * 1e-3`` per integral, as
        production's engines).
    nodes : int or (int, int), optional
        Override the quadrature: radial nodes (debye) or (rows, nodes per row) over the aperture (rs). For
        convergence studies and tests; too few nodes give wrong PSFs without warning.

    Returns
    -------
    ImagingModel
        ``band_psf``, ``psf_per_wavelength``, ``mtf_area``; ``info`` holds node counts and the grid.
    """
    wl, w = check_wavelengths(lens, wavelengths_um, weights)
    p = check_positive("pitch_um", pitch_um, "um", hi=1e4)
    size = check_int("size", size, 1, 4096)
    engine = check_choice("engine", engine, JAX_ENGINES)
    error = check_range("error", error, 1e-12, 0.5)
    own = lens_coefficients(lens)
    nc = check_int("n_coefficients", own.size if n_coefficients is None else n_coefficients, 0, 16)
    if phase_bound_rad is None:
        phase_bound_rad = 2.0 * np.abs(own) if own.size == nc else 0.0
    bound = np.broadcast_to(np.abs(np.asarray(phase_bound_rad, dtype=float)), (nc,)).astype(float).copy()
    s0 = field_direction(field_deg)
    lim = max_field_deg(lens, float(wl.max()))
    if math.degrees(math.asin(min(1.0, float(np.hypot(*s0))))) > lim:
        raise InputError("field_deg", field_deg, f"|field| <= {lim:.3f} deg for lens '{lens.name}'")
    on_axis = float(np.hypot(*s0)) == 0.0
    if engine == "auto":
        engine = "debye" if on_axis else "rs"
    if engine == "debye" and not on_axis:
        raise InputError("engine", engine, "'debye' only on axis (field_deg = 0); 'rs' off axis")
    z = lens.f_um if z_um is None else check_positive("z_um", z_um, "um")
    chief = z * s0 / math.sqrt(1.0 - float(s0 @ s0))
    if sensor:
        if center_um is not None:
            raise InputError("center_um", center_um, "None for the sensor grid (centred on the chief ray)")
        center = chief
        nsub = max(1, int(math.ceil(p / (0.95 * nyquist_pitch_um(lens))))) if n_sub is None else \
            check_int("n_sub", n_sub, 1, 64)
    else:
        if p > nyquist_pitch_um(lens) * (1 + 1e-9):
            raise InputError("pitch_um", p, f"<= lambda0/(4 NA) = {nyquist_pitch_um(lens):.4g} um on the fine grid")
        center = chief if center_um is None else np.asarray(center_um, dtype=float)
        nsub = 1
    if engine == "debye" and float(np.hypot(*center)) > 0:
        raise InputError("center_um", center_um, "(0, 0) for the on-axis (debye) engine")
    gx, gy = _grid(center, p, size, nsub)
    if engine == "debye":
        static = _debye_static(lens, wl, z, center, p, size, nsub, bound, error, nodes, focal_shift=nc == 0)
        info = {"nodes": static["nodes"], "radial_samples": static["radial_samples"],
                "radial_step_um": static["radial_step_um"]}
    else:
        static = _rs_static(lens, wl, z, s0, gx, gy, bound, error, nodes)
        X, Y = np.meshgrid(gx, gy)
        static["gx"], static["gy"] = X.ravel(), Y.ravel()
        info = {"nodes": static["nodes"]}
    if sensor:
        L = size * p
        orders, maps = _haze_static(lens, wl, z, chief, chief[0] - L / 2, chief[1] - L / 2, p, size)
        static["haze_orders"], static["haze_maps"] = orders, maps
    else:
        static["haze_maps"] = np.zeros((wl.size, 0, size, size))
    nf = lens.radius_um ** 2 / (lens.wavelength_um * lens.f_um)
    info.update({"engine": engine, "fine_pitch_um": p / nsub, "n_sub": nsub, "chief_ray_um": chief.tolist(),
                 "diffraction_radius_um": diffraction_radius_um(lens), "fresnel_number": nf})
    if engine == "debye":
        info["model_note"] = (f"direction-sine (Debye) model, production's on-axis model: against the exact "
                              f"(Rayleigh-Sommerfeld) propagation its error falls as 1 / N_F (N_F = {nf:.0f}) and "
                              "grows with the aberration and the defocus; engine 'rs' is exact")
    if train is not None and train.gain.shape != wl.shape:
        raise InputError("train", train.gain.shape, f"gains for the {wl.size} wavelengths")
    return ImagingModel(lens, engine, wl, w, _field_pair(field_deg), z, p, size,
                        (float(center[0]), float(center[1])), bool(sensor), nsub, bool(lattice), nc, bound, train,
                        static, info)


def _field_pair(field_deg: float | tuple[float, float]) -> tuple[float, float]:
    if np.ndim(field_deg) == 0:
        return float(field_deg), 0.0  # type: ignore[arg-type]
    a = np.asarray(field_deg, float).reshape(-1)
    return float(a[0]), float(a[1])

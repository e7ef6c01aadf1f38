"""A differentiable surrogate of the scatterer library: t_x, t_y of a post as smooth functions of (wx, wy, lambda).

Model. The zero-order complex transmission ``t_x(wx, wy, lambda)`` of the platform's posts (the convention and the
normalisation of :func:`metafovea.rcwa.post_response` and :class:`~metafovea.library.sweep.Library`: power
normalised, exp(-i omega t), phase planes at the post-layer faces) is represented by a tensor-product cubic B-spline
in (wx, wy, nu = 1 / lambda) that interpolates an RCWA library sweep (:func:`compute_library`: cached, resumable,
parallel) on a grid: the widths of the platform's fabrication range (:func:`width_grid`: min feature to period - min
feature) or a sub-range, and wavelengths uniform in frequency over the band (resonances crowd the short wavelengths).
The real and imaginary parts are interpolated (the complex field, never a wrapped phase), with not-a-knot end
conditions on every axis. A centred rectangular post at normal incidence on a square lattice maps onto itself with x
and y exchanged under a 90-degree rotation, so ``t_y(wx, wy, lambda) = t_x(wy, wx, lambda)`` exactly: only t_x is
solved and stored, t_y is evaluated with the widths swapped.

:meth:`Surrogate.transmission` is written in ``jax.numpy``: jit, vmap and grad trace it in all three inputs (arrays
broadcast; the four non-zero cubic B-splines per axis by the Cox-de Boor recurrence, 64 coefficients per point).
Inputs outside the fitted box extrapolate the end polynomials (not checked inside traced code: :meth:`Surrogate.
in_range` says). Precision follows JAX's: float32 by default (about 1e-6 rad), float64 under ``jax.enable_x64``.

The error of cubic interpolation falls as the fourth power of the grid step once the grid resolves the posts'
resonances, slower before; :func:`fit_surrogate` estimates it from the data by refitting on every 2nd and 4th grid
point (steps 2h, 4h), comparing at the dropped points and extrapolating with the observed order
(``meta['estimated_phase_rms_rad']``, ``meta['grid_scale_for_goal']``: the step factor that meets the goal);
:func:`error_report` measures it against fresh RCWA solves at random posts and wavelengths (seeded, off the grid),
both polarisations, with a breakdown by wavelength that says where a goal is not met.

File map::

    Surrogate          frozen dataclass: knots, coefficients, the fitting grid, meta; transmission (JAX),
                       transmission_np, phase_amplitude, in_range, save / load
    fit_surrogate      the RCWA sweep (compute_library) and the spline fit, cached as surrogate-<key>.npz under
                       $METAFOVEA_CACHE/surrogate (key: platform stack, widths, band, wavelengths, solver, fit)
    surrogate_grid     the fitting grid (widths, wavelengths) fit_surrogate uses for given settings
    surrogate_from_library  the spline of a computed library (every stride-th grid point)
    error_report       SurrogateError: rms / max phase (rad) and amplitude (%) errors against fresh RCWA solves
    rcwa_transmission  t_x, t_y of posts by RCWA with a surrogate's solver settings (the reference)
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.config import PAPER_BAND_UM, PlatformDesign
from metafovea.errors import InputError, check_int, check_positive
from metafovea.io import atomic_save_npz, cache_lock, input_hash, use_jax_cache
from metafovea.io import cache_dir as io_cache_dir

from .postset import _load_checked
from .sweep import Library, LibraryOptions, compute_library, library_key, width_grid

log = logging.getLogger(__name__)

#: the thermal band the surrogate covers by default (um)
DEFAULT_BAND_UM = PAPER_BAND_UM
#: the default fitting grid: width step (um) and number of wavelengths (uniform in 1 / lambda)
DEFAULT_WIDTH_STEP_UM = 0.1
DEFAULT_N_WAVELENGTHS = 31
#: the accuracy issue 33 asks of the surrogate: rms phase error (rad) and rms amplitude error (%)
GOAL_PHASE_RMS_RAD = 0.02
GOAL_AMPLITUDE_RMS_PCT = 1.0
#: spline degree (cubic) and the schema of the cache files
_DEGREE = 3
_SCHEMA = 2


@dataclass(frozen=True, eq=False)
class Surrogate:
    """Tensor-product cubic B-spline of the posts' zero-order transmission t_x in (wx, wy, 1 / lambda).

    Attributes
    ----------
    knots_wx_um, knots_wy_um : ndarray (n + 4,), um
        Knot vectors along the two widths.
    knots_nu_per_um : ndarray (n + 4,), 1/um
        Knot vector along the frequency 1 / lambda.
    coef : ndarray (n_wx, n_wy, n_nu) complex
        B-spline coefficients of t_x.
    widths_um : ndarray (n_w,), um
        The fitting grid's widths (the same on both axes).
    wavelengths_um : ndarray (n_wl,), um
        The fitting grid's wavelengths (ascending).
    meta : dict
        The platform stack, solver settings (``harmonics``, ``factorization``, ``incidence``), the library's cache
        key, the fit settings, the self-estimated error and the cache key of the surrogate.
    """

    knots_wx_um: np.ndarray
    knots_wy_um: np.ndarray
    knots_nu_per_um: np.ndarray
    coef: np.ndarray
    widths_um: np.ndarray
    wavelengths_um: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    def transmission(self, wx_um: Any, wy_um: Any, wavelength_um: Any) -> tuple[Any, Any]:
        """Complex zero-order transmission (t_x, t_y) of posts ``wx_um x wy_um`` at ``wavelength_um``.

        Parameters
        ----------
        wx_um, wy_um : array_like or jax array, um
            Post widths along x and y (broadcast with each other and the wavelength).
        wavelength_um : array_like or jax array, um

        Returns
        -------
        t_x, t_y : jax arrays (broadcast shape) complex
            Power-normalised co-polarised transmission for x- and y-polarised light (the convention of
            :func:`metafovea.rcwa.post_response`). Traceable by ``jax.jit``, ``jax.vmap`` and ``jax.grad`` in all
            three inputs.
        """
        import jax.numpy as jnp

        def real(a: Any) -> Any:
            x = jnp.asarray(a)
            return x if jnp.issubdtype(x.dtype, jnp.floating) else x.astype(jnp.result_type(float))

        wx, wy, wl = jnp.broadcast_arrays(real(wx_um), real(wy_um), real(wavelength_um))
        nu = 1.0 / wl
        return self._t(wx, wy, nu), self._t(wy, wx, nu)

    def _t(self, a: Any, b: Any, nu: Any) -> Any:
        """t_x at widths (a, b) and frequency nu (jax arrays of one shape)."""
        import jax.numpy as jnp

        return _kernel()(jnp.asarray(self.knots_wx_um), jnp.asarray(self.knots_wy_um),
                         jnp.asarray(self.knots_nu_per_um), jnp.asarray(self.coef.real), jnp.asarray(self.coef.imag),
                         a, b, nu)

    def transmission_np(self, wx_um: ArrayLike, wy_um: ArrayLike, wavelength_um: ArrayLike
                        ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`transmission` as numpy complex128 arrays (evaluated in float64)."""
        import jax

        with jax.enable_x64(True):
            tx, ty = self.transmission(np.asarray(wx_um, float), np.asarray(wy_um, float),
                                       np.asarray(wavelength_um, float))
            return np.asarray(tx, dtype=complex), np.asarray(ty, dtype=complex)

    def phase_amplitude(self, wx_um: Any, wy_um: Any, wavelength_um: Any) -> tuple[Any, Any, Any, Any]:
        """(phase_x, |t_x|, phase_y, |t_y|): phases in radians (wrapped to (-pi, pi]); differentiable wherever
        t != 0 (jax arrays)."""
        import jax.numpy as jnp

        tx, ty = self.transmission(wx_um, wy_um, wavelength_um)
        return jnp.angle(tx), jnp.abs(tx), jnp.angle(ty), jnp.abs(ty)

    @property
    def width_range_um(self) -> tuple[float, float]:
        return float(self.widths_um[0]), float(self.widths_um[-1])

    @property
    def band_um(self) -> tuple[float, float]:
        return float(self.wavelengths_um[0]), float(self.wavelengths_um[-1])

    def in_range(self, wx_um: ArrayLike, wy_um: ArrayLike, wavelength_um: ArrayLike) -> np.ndarray:
        """True where (wx, wy, lambda) lie in the fitted box (numpy; broadcast shape)."""
        lo, hi = self.width_range_um
        a, b = self.band_um
        eps = 1e-9
        wx, wy, wl = (np.asarray(v, float) for v in (wx_um, wy_um, wavelength_um))
        return ((wx >= lo - eps) & (wx <= hi + eps) & (wy >= lo - eps) & (wy <= hi + eps)
                & (wl >= a - eps) & (wl <= b + eps))

    def save(self, path: str | Path) -> Path:
        """Write the surrogate atomically (``.npz`` + JSON meta, :func:`metafovea.io.atomic_save_npz`)."""
        meta = dict(self.meta, type="Surrogate", units="um")
        return atomic_save_npz(path, meta, knots_wx_um=self.knots_wx_um, knots_wy_um=self.knots_wy_um,
                               knots_nu_per_um=self.knots_nu_per_um, coef=self.coef, widths_um=self.widths_um,
                               wavelengths_um=self.wavelengths_um)

    @classmethod
    def load(cls, path: str | Path, name: str = "path") -> Surrogate:
        """Read a file written by :meth:`save`; a damaged or foreign file is an :class:`InputError` naming
        ``name``."""
        arrays, meta = _load_checked(path, "Surrogate", name)
        try:
            s = cls(arrays["knots_wx_um"], arrays["knots_wy_um"], arrays["knots_nu_per_um"], arrays["coef"],
                    arrays["widths_um"], arrays["wavelengths_um"], meta)
        except KeyError as e:
            raise InputError(name, str(path), "a Surrogate file written by Surrogate.save",
                             detail=f"missing {e.args[0]!r}") from None
        n = tuple(k.size - _DEGREE - 1 for k in (s.knots_wx_um, s.knots_wy_um, s.knots_nu_per_um))
        if s.coef.shape != n:
            raise InputError(name, str(path), "a Surrogate file written by Surrogate.save",
                             detail=f"coefficients {s.coef.shape} do not match the knots {n}")
        return s


@functools.cache
def _kernel() -> Any:
    """The jitted spline evaluation (made on first use: importing this module never imports jax)."""
    use_jax_cache()
    import jax
    import jax.numpy as jnp

    def t(kx: Any, ky: Any, kn: Any, c_re: Any, c_im: Any, a: Any, b: Any, nu: Any) -> Any:
        ia, ba = _basis(kx, c_re.shape[0], a)
        ib, bb = _basis(ky, c_re.shape[1], b)
        ic, bc = _basis(kn, c_re.shape[2], nu)
        off = jnp.arange(_DEGREE + 1)
        ja = (ia[..., None] + off)[..., :, None, None]
        jb = (ib[..., None] + off)[..., None, :, None]
        jc = (ic[..., None] + off)[..., None, None, :]
        w = ba[..., :, None, None] * bb[..., None, :, None] * bc[..., None, None, :]
        return jnp.sum(w * c_re[ja, jb, jc], axis=(-3, -2, -1)) + 1j * jnp.sum(w * c_im[ja, jb, jc], axis=(-3, -2, -1))

    return jax.jit(t)


def _basis(knots: Any, n: int, x: Any) -> tuple[Any, Any]:
    """First coefficient index and the 4 non-zero cubic B-splines at ``x`` (Cox-de Boor; The NURBS Book, A2.2).

    Returns ``(i0, B)``: ``i0`` (shape of x, int) and ``B`` (shape of x + (4,)), with t(x) = sum_r B[r] c[i0 + r].
    The knot span is clamped to the first and last interval, so x outside the knots extrapolates the end pieces.
    """
    import jax.numpy as jnp

    p = _DEGREE
    span = jnp.clip(jnp.searchsorted(knots, x, side="right") - 1, p, n - 1)
    left = [None] + [x - knots[span + 1 - j] for j in range(1, p + 1)]
    right = [None] + [knots[span + j] - x for j in range(1, p + 1)]
    N = [jnp.ones_like(x)]
    for j in range(1, p + 1):
        saved = jnp.zeros_like(x)
        new = []
        for r in range(j):
            temp = N[r] / (right[r + 1] + left[j - r])
            new.append(saved + right[r + 1] * temp)
            saved = left[j - r] * temp
        N = new + [saved]
    return span - p, jnp.stack(N, axis=-1)


def _interp_coefficients(axes: Sequence[np.ndarray], values: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """Knots (one vector per axis) and coefficients of the tensor-product cubic not-a-knot spline that
    interpolates ``values`` on the grid ``axes`` (the 1-D collocation solved along each axis in turn)."""
    from scipy.interpolate import make_interp_spline

    c = np.asarray(values, dtype=complex)
    knots = []
    for ax, x in enumerate(axes):
        moved = np.moveaxis(c, ax, 0)
        sp = make_interp_spline(np.asarray(x, float), moved.reshape(moved.shape[0], -1), k=_DEGREE)
        knots.append(np.asarray(sp.t, float))
        c = np.moveaxis(np.asarray(sp.c).reshape(moved.shape), 0, ax)
    return knots, c


def _from_grid(widths: np.ndarray, wavelengths: np.ndarray, t_x: np.ndarray, meta: dict[str, Any]) -> Surrogate:
    """The surrogate interpolating ``t_x`` of shape (n_wl, n_w, n_w) (a library's order) on the grid."""
    order = np.argsort(1.0 / wavelengths)  # ascending frequency
    nu = 1.0 / wavelengths[order]
    values = np.moveaxis(t_x[order], 0, -1)  # (wx, wy, nu)
    (kx, ky, kn), coef = _interp_coefficients((widths, widths, nu), values)
    return Surrogate(kx, ky, kn, coef, np.asarray(widths, float), np.sort(np.asarray(wavelengths, float)), meta)


def surrogate_grid(platform: PlatformDesign | None = None, *, band_um: Sequence[float] = DEFAULT_BAND_UM,
                   width_step_um: float = DEFAULT_WIDTH_STEP_UM, n_wavelengths: int = DEFAULT_N_WAVELENGTHS,
                   width_range_um: Sequence[float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The grid :func:`fit_surrogate` fits on: (widths_um, wavelengths_um).

    Widths: :func:`width_grid` of the platform (its min feature to period - min feature, step ``width_step_um``), or
    ``width_range_um = (lo, hi)`` in steps of ``width_step_um`` (a sub-range: tests, a post family). Wavelengths:
    ``n_wavelengths`` uniform in 1 / lambda over ``band_um``, ascending, rounded to 1e-6 um.
    """
    plat = platform if platform is not None else PlatformDesign()
    band = tuple(float(b) for b in band_um)
    if len(band) != 2 or not 0 < band[0] < band[1] or not np.all(np.isfinite(band)):
        raise InputError("band_um", list(band_um), "two wavelengths 0 < lo < hi (um)")
    n_wl = check_int("n_wavelengths", n_wavelengths, _DEGREE + 1, 2001)
    if width_range_um is None:
        widths = width_grid(plat.period_um, width_step_um, plat.min_feature_um, name="width_step_um")
    else:
        lo, hi = (float(v) for v in width_range_um)
        step = check_positive("width_step_um", width_step_um, "um")
        if not plat.min_feature_um <= lo < hi <= plat.period_um - plat.min_feature_um + 1e-9:
            raise InputError("width_range_um", list(width_range_um),
                             f"lo < hi within the fabrication range [{plat.min_feature_um:g}, "
                             f"{plat.period_um - plat.min_feature_um:g}] um")
        n = int(np.floor((hi - lo) / step + 1e-9)) + 1
        widths = np.round(lo + step * np.arange(n), 10)
    if widths.size < _DEGREE + 1:
        raise InputError("width_step_um", width_step_um, f"a step giving at least {_DEGREE + 1} widths (cubic spline)")
    wls = np.round(np.sort(1.0 / np.linspace(1.0 / band[1], 1.0 / band[0], n_wl)), 6)
    return widths, wls


def _fit_options(platform: PlatformDesign, options: LibraryOptions | None, overrides: dict[str, Any]
                 ) -> LibraryOptions:
    """The sweep's options: ``options`` (default: no M - 2 estimate, no convergence warning) with the platform's
    stack and ``overrides``."""
    base = options if options is not None else LibraryOptions(estimate=False, tol=None)
    return replace(base, **overrides).with_platform(platform)


def fit_surrogate(platform: PlatformDesign | None = None, *, band_um: Sequence[float] = DEFAULT_BAND_UM,
                  width_step_um: float = DEFAULT_WIDTH_STEP_UM, n_wavelengths: int = DEFAULT_N_WAVELENGTHS,
                  width_range_um: Sequence[float] | None = None, stride: int = 1,
                  options: LibraryOptions | None = None, **overrides: Any) -> Surrogate:
    """Fit the surrogate of a platform's posts to an RCWA library sweep (cached).

    Parameters
    ----------
    platform : PlatformDesign, optional
        The stack (period, post height, indices) and min feature (default ``PlatformDesign()``, the paper's).
    band_um : (float, float), um
        The wavelength band.
    width_step_um : float, um
        The width grid's step (the same on both axes).
    n_wavelengths : int
        Wavelengths of the grid, uniform in 1 / lambda over the band.
    width_range_um : (float, float), um, optional
        A sub-range of widths (default: the platform's fabrication range, :func:`width_grid`).
    stride : int
        Interpolate every ``stride``-th point of the swept grid on each axis (:func:`surrogate_from_library`; 2:
        the same sweep at step 2h, for a convergence study).
    options : LibraryOptions, optional
        Solver and run settings of the sweep (default ``LibraryOptions(estimate=False, tol=None)``: the library's
        harmonics and factorisation, no M - 2 convergence solve); the stack is always the platform's.
    **overrides
        Fields of :class:`LibraryOptions` (``harmonics=8, workers=2, progress=False, cache_dir=...``). The
        surrogate is cached in ``$METAFOVEA_CACHE/surrogate``, or next to its library in ``cache_dir`` when one is
        given.

    Returns
    -------
    Surrogate
        With ``meta['estimated_phase_rms_rad']`` and ``meta['estimated_amplitude_rms_pct']``: the fit's own error
        estimate (from the same sweep interpolated at steps 2h and 4h: the observed order ``estimated_order``), and
        ``meta['grid_scale_for_goal']``: the factor on every grid step that this order says meets the goals (< 1:
        refine); :func:`error_report` measures the true error.

    Notes
    -----
    The RCWA sweep is :func:`compute_library` (cached, resumable, parallel, progress shown); only t_x is solved
    (square grid) and t_y is t_x of the swapped post. Fitting is a few tensor-product collocation solves.
    """
    plat = platform if platform is not None else PlatformDesign()
    widths, wls = surrogate_grid(plat, band_um=band_um, width_step_um=width_step_um, n_wavelengths=n_wavelengths,
                                 width_range_um=width_range_um)
    opts = _fit_options(plat, options, overrides)
    lib_key = library_key(widths, None, wls, options=opts)
    fit = {"schema": _SCHEMA, "library": lib_key, "stride": check_int("stride", stride, 1, 1000),
           "model": "cubic not-a-knot B-spline of complex t_x in (wx, wy, 1/lambda); t_y(wx, wy) = t_x(wy, wx)"}
    key = input_hash(fit)
    cdir = Path(opts.cache_dir) if opts.cache_dir is not None else io_cache_dir("surrogate")
    path = cdir / f"surrogate-{key}.npz"
    if opts.use_cache:
        with cache_lock(path):
            got = _cached(path)
            if got is None:
                got = _fit(widths, wls, opts, stride, lib_key, key)
                got.save(path)
        return got
    return _fit(widths, wls, opts, stride, lib_key, key)


def _cached(path: Path) -> Surrogate | None:
    if not path.is_file():
        return None
    try:
        s = Surrogate.load(path)
    except InputError as e:  # a damaged cache file is refitted
        log.warning("refitting damaged surrogate cache %s (%s)", path, e)
        return None
    log.info("surrogate loaded from cache %s", path)
    s.meta["from_cache"] = True
    return s


def _fit(widths: np.ndarray, wls: np.ndarray, opts: LibraryOptions, stride: int, lib_key: str, key: str
         ) -> Surrogate:
    """Sweep (or load) the library and interpolate it; the meta records the settings and the self-estimate."""
    t0 = time.perf_counter()
    lib = compute_library(widths, None, wls, options=opts)
    s = surrogate_from_library(lib, stride=stride)
    s.meta.update(library_key=lib_key, key=key, fit_s=time.perf_counter() - t0)
    log.info("surrogate %s: %d x %d widths x %d wavelengths, estimated phase rms %s rad", key, s.widths_um.size,
             s.widths_um.size, s.wavelengths_um.size, s.meta["estimated_phase_rms_rad"])
    return s


def surrogate_from_library(lib: Library, *, stride: int = 1) -> Surrogate:
    """The surrogate interpolating a library (every ``stride``-th width and wavelength of its grid, the last kept).

    Parameters
    ----------
    lib : Library
        A sweep on a square grid (the same widths on both axes, as :func:`compute_library` gives with
        ``wy_um=None``) of at least 4 widths and 4 wavelengths, every post solved, constant indices.
    stride : int
        Keep every ``stride``-th grid point on each axis (2: the grid of step 2h, for a convergence study).

    Returns
    -------
    Surrogate
        Its meta: the library's stack and solver settings, the grid and the self-estimate (see
        :func:`fit_surrogate`).
    """
    k = check_int("stride", stride, 1, 1000)
    widths, wls = np.asarray(lib.wx_um, float), np.asarray(lib.wavelengths_um, float)
    if widths.shape != np.asarray(lib.wy_um).shape or not np.allclose(widths, lib.wy_um):
        raise InputError("lib", "wx_um != wy_um", "a library on a square grid (wy_um=None)")
    iw, il = _every(widths.size, k), _every(wls.size, k)
    if min(iw.size, il.size) < _DEGREE + 1:
        raise InputError("stride", stride, f"a stride leaving at least {_DEGREE + 1} widths and wavelengths")
    order = np.argsort(wls)
    t_x = np.asarray(lib.t_x)[order][np.ix_(il, iw, iw)]
    widths, wls = widths[iw], wls[order][il]
    if not np.all(np.isfinite(t_x)):
        raise InputError("lib", "NaN transmissions", "a library with every post solved")
    meta = {key: lib.meta.get(key) for key in ("period_um", "height_um", "n_post", "n_surround", "n_substrate",
                                                "n_superstrate", "harmonics", "factorization", "incidence")}
    missing = [key for key, v in meta.items() if v is None]
    if missing:
        raise InputError("lib", f"meta without {missing[0]!r}", "a library from compute_library or Library.load")
    meta.update(library_key=lib.meta.get("key"), stride=k, width_step_um=float(widths[1] - widths[0]),
                n_wavelengths=int(wls.size), sweep_s=float(lib.meta.get("elapsed_s") or 0.0),
                conventions=lib.meta.get("conventions"))
    meta.update(_self_estimate(widths, wls, t_x))
    return _from_grid(widths, wls, t_x, meta)


def _every(n: int, k: int) -> np.ndarray:
    """Indices 0, k, 2k, ... of n points, the last point always kept."""
    idx = np.arange(0, n, k)
    return idx if idx[-1] == n - 1 else np.append(idx, n - 1)


def _self_estimate(widths: np.ndarray, wls: np.ndarray, t_x: np.ndarray) -> dict[str, float | None]:
    """The fit's error estimated from its own data.

    Interpolate every 2nd and every 4th grid point (steps 2h and 4h on all three axes, the last point kept) and
    compare both at the points the 2h grid leaves out; the ratio of the two rms errors gives the observed order p
    (clipped to 1..4; 4, the cubic's asymptotic order, where the 4h grid has under 4 points), and the error at h is
    the 2h error / 2^p. Grids that do not resolve the resonances converge slower than h^4: the observed order says
    so. ``grid_scale_for_goal``: the factor on every step that order gives for the goals. None under 6 points on an
    axis.
    """
    keys = ("estimated_phase_rms_rad", "estimated_amplitude_rms_pct", "estimated_order", "grid_scale_for_goal")
    if min(widths.size, wls.size) < 2 * _DEGREE:
        return dict.fromkeys(keys)
    iw, il = _every(widths.size, 2), _every(wls.size, 2)
    left = np.ones(t_x.shape, bool)
    left[np.ix_(il, iw, iw)] = False
    L, X, Y = np.meshgrid(wls, widths, widths, indexing="ij")
    ref = t_x[left]

    def rms_errors(stride: int) -> np.ndarray:
        jw, jl = _every(widths.size, stride), _every(wls.size, stride)
        coarse = _from_grid(widths[jw], wls[jl], t_x[np.ix_(jl, jw, jw)], {})
        tc, _ = coarse.transmission_np(X[left], Y[left], L[left])
        ph = np.angle(tc / ref)
        amp = 100 * (np.abs(tc) - np.abs(ref)) / np.abs(ref)
        return np.array([np.sqrt(np.mean(ph ** 2)), np.sqrt(np.mean(amp ** 2))])

    e2 = rms_errors(2)
    order = 4.0
    if min(_every(widths.size, 4).size, _every(wls.size, 4).size) > _DEGREE:
        e4 = rms_errors(4)
        ratio = np.max(e4 / np.maximum(e2, 1e-300))
        order = float(np.clip(np.log2(ratio), 1.0, 4.0)) if ratio > 1 else 1.0
    est = e2 / 2 ** order
    worst = max(est[0] / GOAL_PHASE_RMS_RAD, est[1] / GOAL_AMPLITUDE_RMS_PCT)
    return dict(zip(keys, (float(est[0]), float(est[1]), order, float(worst ** (-1 / order)) if worst > 0 else None)))


def _solver_kw(s: Surrogate) -> dict[str, Any]:
    """post_response's keyword arguments for the surrogate's stack and solver settings (its meta)."""
    def index(v: Any) -> Any:
        if isinstance(v, dict):  # a dispersive material: its indices at the library's wavelengths
            raise InputError("surrogate", "dispersive material", "a surrogate of a platform with constant indices")
        return complex(v[0], v[1]) if isinstance(v, list) else v

    m = s.meta
    return dict(period_um=m["period_um"], height_um=m["height_um"], n_post=index(m["n_post"]),
                n_surround=index(m["n_surround"]), n_substrate=index(m["n_substrate"]),
                n_superstrate=index(m["n_superstrate"]), harmonics=m["harmonics"],
                factorization=m["factorization"], incidence=m["incidence"])


def _rcwa_task(job: dict) -> tuple[np.ndarray, np.ndarray]:
    """One chunk of reference solves: t_x of (wx, wy) and of the swapped posts (t_y), one core."""
    import warnings

    from metafovea.errors import NotConvergedWarning
    from metafovea.parallel import blas_threads
    from metafovea.rcwa import post_response

    with warnings.catch_warnings(), blas_threads(1):
        warnings.simplefilter("ignore", NotConvergedWarning)
        a, b, wl = job["wx"], job["wy"], job["wl"]
        r = post_response(np.concatenate([a, b]), np.concatenate([b, a]), np.concatenate([wl, wl]),
                          polarizations=("x",), **job["kw"])
        return r.t_x[:a.size], r.t_x[a.size:]


def rcwa_transmission(surrogate: Surrogate, wx_um: ArrayLike, wy_um: ArrayLike, wavelength_um: ArrayLike, *,
                      workers: int | None = 1, progress: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(t_x, t_y) of posts solved by RCWA (:func:`metafovea.rcwa.post_response`) with the stack and solver
    settings the surrogate was fitted to: the reference of :func:`error_report` and of gradient checks.

    Parameters
    ----------
    surrogate : Surrogate
    wx_um, wy_um, wavelength_um : array_like, um
        Broadcast together.
    workers : int, optional
        Local processes (:func:`metafovea.parallel.run_tasks`; None: one per core).
    progress : bool

    Returns
    -------
    t_x, t_y : ndarray complex (broadcast shape)
    """
    from metafovea.parallel import run_tasks

    wx, wy, wl = (np.asarray(v, float) for v in np.broadcast_arrays(wx_um, wy_um, wavelength_um))
    shape = wx.shape
    flat = [v.ravel() for v in (wx, wy, wl)]
    kw = _solver_kw(surrogate)
    chunk = 16
    jobs = [dict(wx=flat[0][i:i + chunk], wy=flat[1][i:i + chunk], wl=flat[2][i:i + chunk], kw=kw, i=i)
            for i in range(0, flat[0].size, chunk)]
    tx, ty = np.empty(flat[0].size, complex), np.empty(flat[0].size, complex)
    for k, (a, b) in run_tasks(_rcwa_task, jobs, workers=workers, progress=progress, desc="RCWA reference"):
        i = jobs[k]["i"]
        tx[i:i + a.size], ty[i:i + b.size] = a, b
    return tx.reshape(shape), ty.reshape(shape)


@dataclass(frozen=True)
class SurrogateError:
    """A surrogate's error against fresh RCWA solves at held-out posts and wavelengths.

    Phase errors are |arg(t_surrogate / t_rcwa)| (rad), amplitude errors (|t_surrogate| - |t_rcwa|) / |t_rcwa|
    (percent); ``*_x`` / ``*_y`` per polarisation. ``by_band``: one row per wavelength bin (``lo_um``, ``hi_um``,
    ``n``, ``phase_rms_rad``, ``amplitude_rms_pct`` over both polarisations): where the goal is met and where not.
    ``points``: the held-out (wx, wy, lambda) (n, 3), um; ``reference``: RCWA's (t_x, t_y) there; ``worst``: the
    worst points, one dict each.
    """

    phase_rms_rad: dict[str, float]
    phase_max_rad: dict[str, float]
    amplitude_rms_pct: dict[str, float]
    amplitude_max_pct: dict[str, float]
    by_band: list[dict[str, float]]
    worst: list[dict[str, float]]
    points: np.ndarray
    reference: tuple[np.ndarray, np.ndarray]
    seconds: dict[str, float]

    def meets(self, phase_rms_rad: float = GOAL_PHASE_RMS_RAD,
              amplitude_rms_pct: float = GOAL_AMPLITUDE_RMS_PCT) -> bool:
        """True when both polarisations' rms phase and amplitude errors are within the goals."""
        return (max(self.phase_rms_rad.values()) <= phase_rms_rad
                and max(self.amplitude_rms_pct.values()) <= amplitude_rms_pct)

    def summary(self) -> str:
        """Lines for a log or a terminal: the figures per polarisation, then per wavelength bin."""
        lines = [f"{p}: phase rms {self.phase_rms_rad[p]:.4f} rad (max {self.phase_max_rad[p]:.3f}), amplitude rms "
                 f"{self.amplitude_rms_pct[p]:.3f} % (max {self.amplitude_max_pct[p]:.2f} %)" for p in ("x", "y")]
        for b in self.by_band:
            lines.append(f"  {b['lo_um']:.2f}-{b['hi_um']:.2f} um ({b['n']:d} points): phase rms "
                         f"{b['phase_rms_rad']:.4f} rad, amplitude rms {b['amplitude_rms_pct']:.3f} %")
        return "\n".join(lines)


def held_out_points(surrogate: Surrogate, n: int, rng: Any = 0) -> np.ndarray:
    """``n`` random (wx, wy, lambda) in the surrogate's box, uniform in widths and in 1 / lambda, none within
    1e-3 of a grid line (seeded: ``rng`` a seed or a numpy Generator); shape (n, 3), um."""
    gen = np.random.default_rng(rng)
    lo, hi = surrogate.width_range_um
    a, b = surrogate.band_um

    def off_grid(v: np.ndarray, grid: np.ndarray, span: float) -> np.ndarray:
        d = v[:, None] - grid[None, :]
        j = np.argmin(np.abs(d), axis=1)
        near = np.abs(d[np.arange(v.size), j]) < 1e-3 * span
        return np.where(near, v + np.where(v > grid[j], 2e-3, -2e-3) * span, v)

    w = off_grid(gen.uniform(lo, hi, (2, n)).ravel(), surrogate.widths_um, hi - lo).reshape(2, n)
    nu = off_grid(gen.uniform(1 / b, 1 / a, n), 1 / surrogate.wavelengths_um, 1 / a - 1 / b)
    return np.stack([np.clip(w[0], lo, hi), np.clip(w[1], lo, hi), np.clip(1 / nu, a, b)], axis=-1)


def error_report(surrogate: Surrogate, n_points: int = 200, *, rng: Any = 0, n_bands: int = 6,
                 workers: int | None = 1, progress: bool = False, reference: SurrogateError | None = None
                 ) -> SurrogateError:
    """The surrogate's error against fresh RCWA solves at random held-out posts and wavelengths.

    Parameters
    ----------
    surrogate : Surrogate
    n_points : int
        Held-out (wx, wy, lambda) points (:func:`held_out_points`: uniform in the fitted box, off the grid).
    rng : int or numpy.random.Generator
        Seed of the points.
    n_bands : int
        Wavelength bins of the breakdown (uniform in lambda over the band).
    workers, progress
        Of the RCWA solves (:func:`rcwa_transmission`).
    reference : SurrogateError, optional
        An earlier report whose points and RCWA solves are reused (``n_points`` and ``rng`` ignored): two
        surrogates of the same stack compared on the same posts.

    Returns
    -------
    SurrogateError
        rms and max phase error (rad) and amplitude error (%), both polarisations; :meth:`SurrogateError.meets`
        checks the goals (``GOAL_PHASE_RMS_RAD``, ``GOAL_AMPLITUDE_RMS_PCT``).
    """
    nb = check_int("n_bands", n_bands, 1, 100)
    t0 = time.perf_counter()
    if reference is None:
        pts = held_out_points(surrogate, check_int("n_points", n_points, 1, 10 ** 6), rng)
        ref = rcwa_transmission(surrogate, pts[:, 0], pts[:, 1], pts[:, 2], workers=workers, progress=progress)
    else:
        pts, ref = reference.points, reference.reference
    t1 = time.perf_counter()
    got = surrogate.transmission_np(pts[:, 0], pts[:, 1], pts[:, 2])
    t2 = time.perf_counter()
    ph = {p: np.abs(np.angle(g / r)) for p, g, r in zip("xy", got, ref)}
    amp = {p: 100 * np.abs(np.abs(g) - np.abs(r)) / np.abs(r) for p, g, r in zip("xy", got, ref)}

    def rms(v: np.ndarray) -> float:
        return float(np.sqrt(np.mean(v ** 2))) if v.size else float("nan")

    a, b = surrogate.band_um
    edges = np.linspace(a, b, nb + 1)
    by_band = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (pts[:, 2] >= lo) & ((pts[:, 2] < hi) | (hi == b))
        by_band.append(dict(lo_um=float(lo), hi_um=float(hi), n=int(m.sum()),
                            phase_rms_rad=rms(np.concatenate([ph["x"][m], ph["y"][m]])),
                            amplitude_rms_pct=rms(np.concatenate([amp["x"][m], amp["y"][m]]))))
    worst_ph = np.fmax(ph["x"], ph["y"])
    worst = [dict(wx_um=float(pts[i, 0]), wy_um=float(pts[i, 1]), wavelength_um=float(pts[i, 2]),
                  phase_x_rad=float(ph["x"][i]), phase_y_rad=float(ph["y"][i]), amp_x_pct=float(amp["x"][i]),
                  amp_y_pct=float(amp["y"][i]), abs_t_x=float(abs(ref[0][i])), abs_t_y=float(abs(ref[1][i])))
             for i in np.argsort(worst_ph)[::-1][:5]]
    return SurrogateError({p: rms(v) for p, v in ph.items()}, {p: float(v.max()) for p, v in ph.items()},
                          {p: rms(v) for p, v in amp.items()}, {p: float(v.max()) for p, v in amp.items()},
                          by_band, worst, pts, ref, {"rcwa_s": t1 - t0, "surrogate_s": t2 - t1})

"""The co-design run: a lens' added radial phase (``LensDesign.phase_poly_rad``) optimised for its channel's
band-integrated MTF through the camera's train, with the bounds that say how much any phase could win.

Per lens (``CodesignOptions.lenses``): the channel's differentiable sensor PSF
(:func:`metafovea.optics.jaxpsf.channel_model`: the focusing order's Debye integral on axis, the haze orders as
disks, the train's wafers and the other lens' pass-through, the system's post set at every wavelength) over the
band, on the focal-plane pixel grid; the objective ``mtf`` is the MTF area of the band PSF to the sensor's Nyquist
frequency (:meth:`ImagingModel.mtf_area`: what the camera records and the reconstruction inverts), maximised over
``n_coefficients`` terms ``a_j (rho / R)^(2 j)`` by :func:`metafovea.codesign.optimize.minimize` (Adam, a wave as
the scale, each term bounded by the phase that moves the focus across the whole band).

Spectral sampling is chosen from the lens (:func:`spectral_sampling`): the rim's defocus phase changes by
``pi R^2 / (z lambda^2)`` per um of wavelength, and a quarter wave per step resolves the focus; a band that needs
more than ``max_wavelengths`` is refused with the count it needs (the line bound of
:mod:`metafovea.codesign.bound` then says what the optimum is without a run).

Every result states the achromatic limit (:mod:`metafovea.codesign.limits`) and the line bound
(:mod:`metafovea.codesign.bound`) of the lens next to what the run reached.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.config import LensDesign, SystemDesign
from metafovea.errors import InputError, check_choice, check_int
from metafovea.io import input_hash
from metafovea.radiometry import check_band, system_filter_um

from .bound import MTFBound, band_mtf_bound, detected_density
from .limits import BandwidthLimit, bandwidth_limit
from .optimize import Bounds, OptimizeOptions, OptimizeResult, minimize

#: the objectives ``codesign`` optimises
CODESIGN_OBJECTIVES = ("mtf",)
#: the lenses a run may co-design (each is optimised for its own channel)
CODESIGN_LENSES = ("foveal", "perifoveal")
#: the least relative margin kept from a ray crossing (the Debye model's condition), and the penalty's weight
CROSSING_MARGIN = 0.05
CROSSING_PENALTY = 100.0
#: the largest defocus-phase step at the rim between neighbouring wavelength samples (rad): a quarter wave
RIM_PHASE_STEP_RAD = math.pi / 2


@dataclass(frozen=True)
class CodesignOptions:
    """``objective`` ('mtf'); ``band_um`` (default: the system's band); ``lenses`` to co-design; ``n_coefficients``
    added-phase terms per lens; ``size_px`` the sensor window (pixels) of the objective's PSF; ``max_wavelengths``
    the most spectral samples a run may take; ``posts`` the post sets ('rcwa': the platform's, 'ideal');
    ``optimize`` the optimiser's steps and rate."""

    objective: str = "mtf"
    band_um: tuple[float, float] | None = None
    lenses: tuple[str, ...] = ("foveal",)
    n_coefficients: int = 3
    size_px: int = 31
    max_wavelengths: int = 400
    posts: str = "rcwa"
    optimize: OptimizeOptions = field(default_factory=lambda: OptimizeOptions(steps=80, learning_rate=0.1))

    def __post_init__(self) -> None:
        check_choice("objective", self.objective, CODESIGN_OBJECTIVES)
        if self.band_um is not None:
            object.__setattr__(self, "band_um", check_band(self.band_um))
        if not self.lenses or any(x not in CODESIGN_LENSES for x in self.lenses):
            raise InputError("lenses", list(self.lenses), f"one or both of {list(CODESIGN_LENSES)}")
        check_int("n_coefficients", self.n_coefficients, 1, 8)
        check_int("size_px", self.size_px, 9, 255)
        if self.size_px % 2 == 0:
            raise InputError("size_px", self.size_px, "an odd number of pixels (one centred on the chief ray)")
        check_int("max_wavelengths", self.max_wavelengths, 3, 100_000)


@dataclass
class LensResult:
    """One lens' co-design: the designs, their objective values, the bounds and the optimisation."""

    lens: LensDesign  #: the co-designed lens (``phase_poly_rad`` set)
    hyperbolic: LensDesign  #: the lens as given
    mtf_area: float  #: the co-designed channel's band MTF area to Nyquist
    mtf_area_hyperbolic: float
    mtf_area_per_wavelength: float  #: the band mean of each wavelength's MTF area (a design metric, not the camera's)
    mtf_area_per_wavelength_hyperbolic: float
    limit: BandwidthLimit
    bound: MTFBound
    optimization: OptimizeResult
    sampling: dict[str, Any]
    psf: np.ndarray  #: (size_px, size_px) the co-designed channel's band PSF on the pixel grid
    psf_hyperbolic: np.ndarray
    pitch_um: float  #: the PSFs' pixel pitch on the focal plane

    def warnings(self) -> list[str]:
        """:func:`bound_warnings` of this lens' gain."""
        return bound_warnings(self.mtf_area / self.mtf_area_hyperbolic, self.bound.gain_limit, self.psf.shape[0],
                              self.pitch_um)

    def summary(self) -> dict[str, Any]:
        return {"lens": self.lens.name, "phase_poly_rad": list(self.lens.phase_poly_rad),
                "mtf_area": self.mtf_area, "mtf_area_hyperbolic": self.mtf_area_hyperbolic,
                "gain": self.mtf_area / self.mtf_area_hyperbolic, "warnings": self.warnings(),
                "mtf_area_per_wavelength": self.mtf_area_per_wavelength,
                "mtf_area_per_wavelength_hyperbolic": self.mtf_area_per_wavelength_hyperbolic,
                "line_bound_gain_limit": self.bound.gain_limit,
                "line_bound_best_wavelength_um": self.bound.best_wavelength_um,
                "bandwidth_limit": self.limit.lines() + self.bound.lines(self.lens.name),
                "sampling": self.sampling, "steps": self.optimization.steps,
                "resumed_from": self.optimization.resumed_from,
                "loss_history": self.optimization.history["loss"].tolist()}


#: the gain's margin over the line bound before it is called a contradiction: the bound is first order in the
#: shear and the objective's MTF area a discrete sum on a finite window
BOUND_SLACK = 0.01


def bound_warnings(gain: float, gain_limit: float, size_px: int, pitch_um: float) -> list[str]:
    """What contradicts the physics: a gain above the line bound (:mod:`metafovea.codesign.bound`), which no phase
    profile can exceed, by more than :data:`BOUND_SLACK` is the model's artefact (a PSF window that truncates the
    band's blur inflates its MTF), said as one warning; none otherwise."""
    if not gain > gain_limit * (1 + BOUND_SLACK):
        return []
    return [f"the co-designed gain {gain:.3f}x exceeds the line bound's {gain_limit:.3f}x, which no phase profile can "
            f"exceed: the objective's PSF window ({size_px} px of {pitch_um:.3g} um) truncates the band PSF's blur and "
            "inflates its MTF, or the band spans too few depths of focus for the bound; neither number is to be "
            "trusted (size_px=... larger)"]


@dataclass
class CodesignResult:
    """The co-designed system (the lenses not co-designed as given) and each lens' result."""

    system: SystemDesign
    lenses: dict[str, LensResult]
    options: CodesignOptions

    def summary(self) -> dict[str, Any]:
        return {"objective": self.options.objective, "band_um": list(self.options.band_um or self.system.band_um),
                "lenses": {k: v.summary() for k, v in self.lenses.items()}}


def spectral_sampling(lens: LensDesign, z_um: float, band_um: tuple[float, float]) -> tuple[int, str]:
    """The number of uniform wavelength samples that resolve the lens' focus over ``band_um`` and why (see the
    module docstring): the rim's defocus phase moves by at most :data:`RIM_PHASE_STEP_RAD` per step."""
    lo, hi = check_band(band_um)
    rate = math.pi * lens.radius_um**2 / (z_um * lo**2)  # rad per um of wavelength at the band's short end
    step = RIM_PHASE_STEP_RAD / rate
    n = max(3, int(math.ceil((hi - lo) / step)) + 1)
    return n, (f"{n} wavelengths over {lo:g}-{hi:g} um: the rim's defocus phase moves {rate:.3g} rad/um at "
               f"{lo:g} um; steps of {step:.3g} um keep it within a quarter wave")


def band_weights(wavelengths_um: np.ndarray, system: SystemDesign, band_um: tuple[float, float]) -> np.ndarray:
    """Trapezoid weights (sum 1) of the detected spectral density (:func:`~metafovea.codesign.bound.detected_density`
    at the system's scene temperature, through its filter when enabled) on uniform ``wavelengths_um``."""
    s = detected_density(wavelengths_um, band_um, temperature_k=system.scene_temperature_k,
                         filter_um=system_filter_um(system))
    w = np.gradient(wavelengths_um) * s
    return w / w.sum()


def _crossing_margin(lens: LensDesign, n: int = 512) -> Any:
    """A JAX function of the added-phase coefficients: how far (relative) the lens comes to crossing rays, i.e. the
    largest of ``phi'' / |phi0''|`` and ``(phi' / rho) / |phi0' / rho|`` plus :data:`CROSSING_MARGIN` over the
    aperture (``phi0`` the hyperbola; the same condition as :func:`metafovea.optics.jaxpsf.ray_map_is_monotonic`),
    clipped at 0: zero while every ray keeps a margin from crossing."""
    import jax.numpy as jnp

    R, f = lens.radius_um, lens.f_um
    k0 = 2 * math.pi / lens.wavelength_um
    rho = np.linspace(0.0, R, n)
    L = np.sqrt(rho * rho + f * f)
    h1, h2 = k0 / L, k0 * (f / L) ** 3 / f  # -phi0' / rho and -phi0'' of the hyperbola (> 0)
    u = (rho / R) ** 2
    sign = -lens.phase_sign

    def margin(coeffs: Any) -> Any:
        a = sign * coeffs
        j = jnp.arange(a.shape[0])
        powers = jnp.asarray(u)[:, None] ** j[None, :]
        ap_r = powers @ (2 * (j + 1) * a) / (R * R)
        app = powers @ (2 * (j + 1) * (2 * j + 1) * a) / (R * R)
        worst = jnp.maximum(jnp.max(ap_r / h1 - 1.0), jnp.max(app / h2 - 1.0))
        return jnp.maximum(worst + CROSSING_MARGIN, 0.0)

    return margin


def _problem_key(system: SystemDesign, lens: LensDesign, options: CodesignOptions, n_wl: int) -> str:
    return input_hash({"system": repr(system), "lens": repr(lens), "objective": options.objective,
                       "band": options.band_um, "n": options.n_coefficients, "size": options.size_px,
                       "posts": options.posts, "wavelengths": n_wl, "lr": options.optimize.learning_rate})


def codesign_lens(system: SystemDesign, name: str, options: CodesignOptions, *,
                  checkpoint: str | Path | None = None) -> LensResult:
    """Co-design one lens of ``system`` (``name``: 'foveal' | 'perifoveal') for its channel (see the module
    docstring); ``checkpoint``: the optimiser's checkpoint file (resumed from when it holds this problem)."""
    from metafovea.library.platform import system_post_sets
    from metafovea.optics import jaxpsf

    lens: LensDesign = getattr(system, name)
    if lens.phase_poly_rad:
        warnings.warn(f"the {name} lens already carries an added phase (phase_poly_rad, {len(lens.phase_poly_rad)} "
                      "coefficient(s)): the co-design starts from the plain hyperbola and replaces it; its gain is "
                      "against the hyperbola, not against the input", UserWarning, stacklevel=2)
    band = options.band_um or tuple(system.band_um)
    z = float(system.lens_to_sensor_um[0 if name == "foveal" else 1])
    n_wl, why = spectral_sampling(lens, z, band)
    if n_wl > options.max_wavelengths:
        b = band_mtf_bound(lens, band, [1.0], z_um=z, temperature_k=system.scene_temperature_k,
                           filter_um=system_filter_um(system))
        raise InputError("max_wavelengths", options.max_wavelengths,
                         f">= {n_wl} for the {name} lens ({why}); its band MTF optimum without a run: the line bound "
                         f"(focus {b.best_wavelength_um:.2f} um on the sensor, at most {b.gain_limit:.2f}x the "
                         "hyperbola)")
    wl = np.linspace(*band, n_wl)
    w = band_weights(wl, system, band)
    post_sets, source = system_post_sets(system, options.posts)
    n = options.n_coefficients
    rim = math.pi * lens.radius_um**2 / (lens.wavelength_um * lens.f_um)  # the hyperbola's rim phase (rad)
    frac = (1.0 / band[0] - 1.0 / band[1]) * lens.wavelength_um
    limit_rad = np.array([rim * frac / (j + 1) for j in range(n)])  # moves the focus across the band, per term
    with jaxpsf.x64():
        model = jaxpsf.channel_model(system, name, post_sets, wavelengths_um=wl, weights=w,
                                     size_px=options.size_px, n_coefficients=n, phase_bound_rad=limit_rad)
        tf, tp = jaxpsf.channel_level_tables(system, name, post_sets, wl)
        zero = np.zeros(n)

        crossing = _crossing_margin(lens)

        def loss(p: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
            area = model.mtf_area(p["a"], tf, tp)
            c = crossing(p["a"])  # > 0 where rays would cross: outside the Debye model's validity
            return -area + CROSSING_PENALTY * c * c, {"mtf_area": area, "crossing": c}

        res = minimize(loss, {"a": zero}, {"a": Bounds(-limit_rad, limit_rad, np.full(n, 2 * math.pi))},
                       options.optimize, checkpoint=checkpoint, problem_key=_problem_key(system, lens, options, n_wl),
                       desc=f"codesign {name}")
        a = res.params["a"]
        area0 = float(model.mtf_area(zero, tf, tp))
        area1 = float(model.mtf_area(a, tf, tp))
        pw0 = float(model.mtf_area(zero, tf, tp, per_wavelength=True))
        pw1 = float(model.mtf_area(a, tf, tp, per_wavelength=True))
        psf0 = np.asarray(model.band_psf(zero, tf, tp))
        psf1 = np.asarray(model.band_psf(a, tf, tp))
    coeffs = tuple(float(x) for x in a)
    if not jaxpsf.ray_map_is_monotonic(lens, coeffs):
        raise FloatingPointError(f"codesign {name}: the optimum's rays cross inside the aperture (the Debye model "
                                 "does not hold there): fewer coefficients or a smaller band")
    pitch = system.sensor.pixel_pitch_um / system.relay_magnification
    nyq = 0.5 / pitch * 1e3  # cyc/mm on the focal plane
    bound = band_mtf_bound(lens, band, np.linspace(nyq / 64, nyq, 64), z_um=z,
                           temperature_k=system.scene_temperature_k, filter_um=system_filter_um(system))
    sampling = {"channel": name, "wavelengths": n_wl, "why": why, "posts": source, "engine": model.engine,
                "pixel_pitch_focal_um": pitch, "size_px": options.size_px}
    return LensResult(replace(lens, phase_poly_rad=coeffs), lens, area1, area0, pw1, pw0,
                      bandwidth_limit(lens, system.platform, band), bound, res, sampling, psf1, psf0, pitch)


def codesign(system: SystemDesign, options: CodesignOptions = CodesignOptions(), *,
             checkpoint_dir: str | Path | None = None) -> CodesignResult:
    """Co-design ``options.lenses`` of ``system`` (each for its own channel); the others stay as given.

    Parameters
    ----------
    system : SystemDesign
    options : CodesignOptions
    checkpoint_dir : path, optional
        Where each lens' optimiser checkpoint lives (``checkpoint_<lens>.npz``): a stopped run resumes from it.

    Returns
    -------
    CodesignResult
    """
    out: dict[str, LensResult] = {}
    new = system
    for name in options.lenses:
        ck = None if checkpoint_dir is None else Path(checkpoint_dir) / f"checkpoint_{name}.npz"
        r = codesign_lens(system, name, options, checkpoint=ck)
        out[name] = r
        new = replace(new, **{name: r.lens})
    return CodesignResult(new, out, options)

"""The PSF refined from the data: one member of a one-parameter family of candidate PSFs, chosen by the evidence.

The PSF-aware reconstruction (:mod:`metafovea.reconstruct.deconvolve`) takes the channels' PSFs as known. When the
camera differs from the file's PSFs (a sensor off focus, a lens whose focal length is off), the data say so: under
the model of that module each separated channel ``z_i`` (crop, DN above the dark level, relative illumination
divided out) is a stationary Gaussian field

    z_i = K_i * s_i + n_i,    ln S_i(f) piecewise linear in ln |f|,    n_i white of variance C_ii             (1)

(``S_i``: the scene's spectrum, its values ``theta_k`` at knots one octave apart: natural scenes' spectra are close
to a power law [1]_, one straight line in these coordinates, but a scene of a few objects, a pattern of one period or
a horizon bends it, and a fixed law would then lend its error to the PSF; a Gaussian prior on the bends, of
:data:`CURVATURE_PER_OCTAVE` per octave, keeps the spectrum from following a smooth blur's attenuation instead. ``C``:
the separated channels' noise covariance, known from the frames' residuals and the fixed pattern's error). Its
Hann-tapered periodogram ``I_i(f)`` (per pixel) is, frequency by frequency, an exponential variable of mean

    E I_i(f) = W * (|D_i|^2 S_i)(f) + C_ii,    D_i the candidate kernel's OTF on the crop's grid                (2)

(``W``: the taper's spectral window, :data:`TAPER_WINDOW`), so the Gaussian marginal likelihood of a candidate PSF
(the evidence: the scene integrated out) is in closed form per frequency (Whittle's approximation [2]_), its
spectrum's knots fitted (type-II maximum likelihood, the bends' prior added):

    -ln p(z_i | K) = min_theta {sum_f w_f [ln E I_i(f) + I_i(f) / E I_i(f)] / rho
                                + sum_k (theta_k+1 - 2 theta_k + theta_k-1)^2 / (2 tau^2)} + const              (3)

with ``w_f`` 1/2 on the half plane's self-conjugate columns and 1 elsewhere, over ``|f|`` beyond the taper's main
lobe (:data:`MIN_FREQUENCY_CELLS`), ``rho = N sum w^4 / (sum w^2)^2`` the taper's variance inflation (it
correlates neighbouring frequencies, so the sum counts each one ``rho`` times) and ``tau`` the bends' prior (per
octave, for knots one octave apart). A member's evidence ratio against
the nominal PSF and its significance are

    2 ln B_k = 2 [ln p(z | K_k) - ln p(z | K_0)],    Z_k = sum_f d_f / sqrt(rho sum_f (d_f - mean d)^2)         (4)

``d_f`` the per-frequency difference of (3)'s terms: ``Z`` is Vuong's statistic [3]_, which stays a standard normal
under the null (neither model closer to the truth) when, as here, both models are approximations.

Why the evidence: it needs no knowledge of the scene; the scene is integrated out under the same stationary Gaussian
model whose posterior mean the Wiener step computes, and the spectrum is fitted for each candidate, so a blurrier PSF
cannot win by claiming a sharper scene. Maximising jointly over scene and PSF (MAP)
favours the sharpest PSF; the marginal likelihood does not [4]_ [5]_. A prediction-error criterion (GCV) would need a
deconvolution per candidate and would score the noise model rather than the PSF.

A member replaces the nominal PSF only where both ``2 ln B >= min_evidence`` (:data:`MIN_EVIDENCE`, "strong" on
Kass and Raftery's scale [6]_) and ``Z`` exceeds the one-sided 5 % level corrected for the family's ``K - 1``
comparisons (Bonferroni, :data:`FAMILY_ALPHA`): the fitted spectrum is an approximation of a real scene's, and its
error alone produces evidence ratios of tens over tens of thousands of frequencies, which ``Z`` discounts. Where the
channels' scale is known, the camera's own redundancy checks the choice without any scene model: the foveal image,
scaled down ``f1 / f2`` times, is the perifoveal image's centre up to a gain and an offset, and a member is taken only
where the two channels' Wiener estimates satisfy that relation at least as well with it as with the nominal PSF
(a scene whose spectrum the model misreads, a periodic texture, a horizon, can make a wrong member look likely; it
does not make the two channels agree better). A member at the family's edge, and a family whose nominal member is
not the file's PSF, are stated.

Families (:func:`psf_family`) are built with the project's optics engine as the simulator builds the file's PSFs
(:func:`metafovea.imaging.kernels.build_channel_optics`, :func:`metafovea.imaging.kernels.pixel_psf`):

* ``'defocus'``: the kernel the engine computes on a plane ``dz`` from the sensor, ``dz`` given as the
  peak-to-valley defocus ``W = dz (1 - sqrt(1 - NA^2)) / lambda0`` in waves at the design wavelength (the change of
  the pupil phase ``k z sqrt(1 - |s|^2)`` between the pupil's centre and rim, :mod:`metafovea.optics.pupil`); the
  far haze (the wavelengths whose blur exceeds the kernel's window) is kept, since ``dz`` changes its disks by
  ``dz / f`` (below 0.2 % for a wave);
* ``'focal-length'``: the lens' focal length times ``1 + e`` with the sensor in place: the kernel and the haze's
  disks (``a |z lambda / (f lambda0) - 1|``) both change.

Each family is cached on disk (``metafovea.io.cache_dir("psf_family")``), keyed by all its inputs.

Files: this module (:class:`PSFFamily`, :func:`psf_family`, :func:`families_for`, :func:`psf_evidence`,
:func:`refine_psf`, :func:`refine_measurement`, :class:`PSFRefinement`, :class:`DisplacedFocusProvider`); used by
:func:`metafovea.reconstruct.deconvolve.deconvolve_measurement` (``refine_psf``) and ``metafovea reconstruct
--deconvolve ... --refine-psf KIND``.

References
----------
.. [1] D. J. Field, "Relations between the statistics of natural images and the response properties of cortical
   cells", J. Opt. Soc. Am. A 4, 2379 (1987).
.. [2] P. Whittle, "Estimation and information in stationary time series", Ark. Mat. 2, 423 (1953).
.. [3] Q. H. Vuong, "Likelihood ratio tests for model selection and non-nested hypotheses", Econometrica 57, 307
   (1989).
.. [4] A. Levin, Y. Weiss, F. Durand and W. T. Freeman, "Understanding blind deconvolution algorithms", IEEE Trans.
   Pattern Anal. Mach. Intell. 33, 2354 (2011).
.. [5] R. L. Lagendijk, J. Biemond and D. E. Boekee, "Identification and restoration of noisy blurred images using
   the expectation-maximization algorithm", IEEE Trans. Acoust. Speech Signal Process. 38, 1180 (1990).
.. [6] R. E. Kass and A. E. Raftery, "Bayes factors", J. Am. Stat. Assoc. 90, 773 (1995).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.errors import InputError, check_choice
from metafovea.reconstruct.joint import ChannelPSFs, prepare_problem
from metafovea.reconstruct.spectra import rfft_frequencies

if TYPE_CHECKING:
    from metafovea.config import SystemDesign
    from metafovea.imaging.channel import Channel
    from metafovea.imaging.kernels import Kernel
    from metafovea.measurement import Measurement

log = logging.getLogger(__name__)

__all__ = ["DEFAULT_VALUES", "FAMILY_ALPHA", "FAMILY_KINDS", "MIN_EVIDENCE", "DisplacedFocusProvider", "PSFFamily",
           "PSFRefinement", "defocus_shift_um", "families_for", "psf_evidence", "psf_family", "refine_measurement",
           "refine_psf"]

#: the one-parameter families :func:`psf_family` builds
FAMILY_KINDS = ("defocus", "focal-length")
#: each family's default members: defocus in waves at the design wavelength (Rayleigh's depth of focus is +-1/4 wave:
#: a wave either way in eighths); the focal length's relative error, +-8 % in steps of 0.5 % (a 1 % step moves the
#: foveal lens' haze disks by ~11 pixels, too coarse to land near a true error between two members)
DEFAULT_VALUES = {"defocus": tuple(k / 8.0 for k in range(-8, 9)),
                  "focal-length": tuple(k / 200.0 for k in range(-16, 17))}
#: each family's parameter and its unit
UNITS = {"defocus": "waves", "focal-length": "relative"}
#: the smallest ``2 ln B`` (eq. 4) that replaces the nominal PSF: "strong" evidence (Kass and Raftery 1995: 6-10
#: strong, > 10 very strong; the upper end of "strong")
MIN_EVIDENCE = 10.0
#: the family-wise level of Vuong's test, eq. (4): a member must beat the nominal at ``FAMILY_ALPHA / (K - 1)``
#: one-sided (Bonferroni over the ``K - 1`` comparisons with the nominal)
FAMILY_ALPHA = 0.05
#: frequencies within this many DFT cells of DC are left out of eq. (3): the Hann taper's main lobe is 2 cells wide
#: either side, so the crop's mean and largest structures leak into them
MIN_FREQUENCY_CELLS = 3
#: knots of the spectrum's spline, eq. (1), per octave of ``|f|``
KNOTS_PER_OCTAVE = 1.0
#: the spectrum's curvature, eq. (1): the slope of ``ln S`` against octaves of ``|f|`` changes by this much per octave
#: (one standard deviation of a Gaussian prior on the second differences): a slope that wanders like natural scenes'
#: exponents between scenes (+-0.43 about 1.88: van der Schaaf and van Hateren, Vision Res. 36, 2759 (1996)) within
#: each octave. 0 would be a power law, which a scene of a few objects bends beyond; no limit lets the spectrum follow
#: a smooth blur's attenuation and the PSF go unidentified
CURVATURE_PER_OCTAVE = 0.5
#: Fisher-scoring steps of the spline's knots (each step halved up to 12 times until it lowers eq. 3)
SCORING_STEPS = 60
#: version of the cached families' format (part of the cache key)
FAMILY_CACHE_VERSION = 2


def defocus_shift_um(na: float, wavelength_um: float, waves: float) -> float:
    """The focal-plane shift of a peak-to-valley defocus.

    Parameters
    ----------
    na : float
        The lens' numerical aperture.
    wavelength_um : float, um
        The wavelength the defocus is counted in.
    waves : float
        Peak-to-valley defocus ``W``, waves.

    Returns
    -------
    float, um
        ``dz = W lambda / (1 - sqrt(1 - NA^2))``: the pupil phase ``k dz sqrt(1 - |s|^2)`` changes by ``W`` waves
        between the pupil's centre and rim.
    """
    return float(waves) * float(wavelength_um) / (1.0 - math.sqrt(1.0 - float(na) ** 2))


class DisplacedFocusProvider:
    """A PSF provider that evaluates another one on a plane shifted by ``shift_um`` (per channel name), and
    divides the kernel by ``transmission`` (per channel name; the focusing metasurface's, which
    :func:`metafovea.imaging.simulate.simulate` applies only to its own optics provider).

    With it ``simulate(..., psf=DisplacedFocusProvider(...))`` makes data through a defocused kernel while the
    camera's geometry (field angles, the foveal scale) and its far haze stay nominal.
    """

    def __init__(self, base: Any, shift_um: dict[str, float], transmission: dict[str, float] | None = None):
        self.base = base
        self.shift_um = {k: float(v) for k, v in shift_um.items()}
        self.transmission = {k: float(v) for k, v in (transmission or {}).items()}

    def __call__(self, channel: Channel, *, pitch_um: float, field_deg: float, wavelengths_um: np.ndarray,
                 weights: np.ndarray, size_px: int) -> Kernel:
        from metafovea.imaging.kernels import Kernel

        dz = self.shift_um.get(channel.name, 0.0)
        ch = replace(channel, focal_length_um=channel.focal_length_um + dz) if dz else channel
        k = self.base(ch, pitch_um=pitch_um, field_deg=field_deg, wavelengths_um=wavelengths_um, weights=weights,
                      size_px=size_px)
        t = self.transmission.get(channel.name, 1.0)
        return Kernel(k.intensity / t, k.pitch_um, k.window_radius_um, f"{k.source}, plane {dz:+.1f} um",
                      k.error_estimate)


@dataclass(frozen=True)
class PSFFamily:
    """One channel's candidate PSFs on the pixel grid, one per parameter value.

    Attributes
    ----------
    channel : int
        1 (foveal, ``psf_x1``) or 2 (perifoveal, ``psf_x2``).
    kind : str
        What varies (:data:`FAMILY_KINDS`, or any name for a family built elsewhere).
    values : ndarray, shape (K,)
        The parameter of each member, in ``unit``.
    kernels : tuple of K ndarray, shape (n, n)
        Odd, centred kernels (the ``K_i`` of :class:`~metafovea.reconstruct.joint.ChannelPSFs`).
    pedestals : tuple of K float
        Their pedestals (power beyond the kernel).
    nominal : float
        The parameter of the nominal PSF (one of ``values``).
    unit : str
    source : str
    """

    channel: int
    kind: str
    values: np.ndarray
    kernels: tuple[np.ndarray, ...]
    pedestals: tuple[float, ...]
    nominal: float = 0.0
    unit: str = ""
    source: str = "given"

    def __post_init__(self) -> None:
        if self.channel not in (1, 2):
            raise InputError("channel", self.channel, "1 (foveal) or 2 (perifoveal)")
        v = np.asarray(self.values, dtype=np.float64).reshape(-1)
        if v.size < 2 or not np.all(np.isfinite(v)) or np.any(np.diff(v) <= 0):
            raise InputError("values", self.values, "at least 2 finite, increasing parameter values")
        if len(self.kernels) != v.size or len(self.pedestals) != v.size:
            raise InputError("kernels", f"{len(self.kernels)} kernels, {len(self.pedestals)} pedestals",
                             f"one per value ({v.size})")
        if not np.any(np.isclose(v, self.nominal, rtol=0, atol=1e-12)):
            raise InputError("nominal", self.nominal, "one of the family's values")
        for k in self.kernels:  # each kernel's form (odd, square, finite, >= 0), checked as ChannelPSFs does
            ChannelPSFs((k, k))
        object.__setattr__(self, "values", v)
        object.__setattr__(self, "kernels", tuple(np.asarray(k, dtype=np.float64) for k in self.kernels))
        object.__setattr__(self, "pedestals", tuple(float(p) for p in self.pedestals))

    @property
    def nominal_index(self) -> int:
        return int(np.argmin(np.abs(self.values - self.nominal)))

    def member(self, base: ChannelPSFs, index: int) -> ChannelPSFs:
        """``base`` with this family's channel replaced by member ``index`` (the other channel, with its field
        patches, and the illumination kept; the family's members are on-axis kernels, so the channel replaced
        loses its field patches)."""
        ks, ped, pts = list(base.kernels), list(base.pedestals), list(base.patches)
        ks[self.channel - 1] = self.kernels[index]
        ped[self.channel - 1] = self.pedestals[index]
        pts[self.channel - 1] = None
        return ChannelPSFs((ks[0], ks[1]), (ped[0], ped[1]), base.illumination,
                           source=f"{base.source}; x{self.channel} {self.kind} {self.values[index]:+g} {self.unit}",
                           patches=(pts[0], pts[1]))


def _channel_index(channel: int | str) -> int:
    names = {"foveal": 1, "perifoveal": 2, "x1": 1, "x2": 2, 1: 1, 2: 2}
    if channel not in names:
        raise InputError("channel", channel, "'foveal' (1, 'x1') or 'perifoveal' (2, 'x2')")
    return names[channel]


def psf_family(system: SystemDesign | None = None, *, channel: int | str = "foveal", kind: str = "defocus",
               values: ArrayLike | None = None, filter_enabled: bool | None = None, supersample: int = 3,
               posts: str = "rcwa", optical_train: bool = True, cache: bool = True) -> PSFFamily:
    """A channel's PSFs on the pixel grid over a one-parameter family, built as the simulator builds ``psf_x*``.

    Parameters
    ----------
    system : SystemDesign, optional
        The camera (default: the paper's prototype).
    channel : {'foveal', 'perifoveal'} or {1, 2}
    kind : {'defocus', 'focal-length'}
        ``'defocus'``: the kernel on a plane ``dz`` from the sensor, ``values`` in waves peak-to-valley at the
        design wavelength (:func:`defocus_shift_um`); ``'focal-length'``: the lens' focal length times
        ``1 + value``, the sensor in place (module docstring).
    values : array_like, optional
        Increasing members, including 0 (the nominal PSF) (default :data:`DEFAULT_VALUES`).
    filter_enabled : bool, optional
        The 10 um filter (default: the system's).
    supersample : int
        Samples per pixel per axis (the simulator's default for a static scene: 3).
    posts : {'rcwa', 'ideal'}
        The lenses' posts (:func:`metafovea.library.system_post_sets`).
    optical_train : bool
        The optical train's metasurface transmission and glare (as the simulator).
    cache : bool
        Read and write the family in ``metafovea.io.cache_dir("psf_family")``.

    Returns
    -------
    PSFFamily
        Nominal value 0.
    """
    from dataclasses import asdict

    from metafovea.config import SystemDesign
    from metafovea.io import atomic_save_npz, cache_dir, input_hash, load_npz

    kind = check_choice("kind", kind, FAMILY_KINDS)
    ci = _channel_index(channel)
    system = system or SystemDesign.paper()
    v = np.asarray(DEFAULT_VALUES[kind] if values is None else values, dtype=np.float64).reshape(-1)
    if v.size < 2 or not np.any(v == 0.0):
        raise InputError("values", values, "at least 2 increasing values including 0 (the nominal PSF)")
    if kind == "focal-length" and np.any(v <= -0.5):
        raise InputError("values", values, "relative focal-length errors > -0.5")
    fe = system.filter_enabled if filter_enabled is None else bool(filter_enabled)
    key = {"v": FAMILY_CACHE_VERSION, "system": asdict(system), "channel": ci, "kind": kind,
           "values": np.round(v, 12).tolist(), "filter": fe, "ss": int(supersample), "posts": posts,
           "train": bool(optical_train)}
    path = cache_dir("psf_family") / f"family_x{ci}_{kind}_{input_hash(key)}.npz"
    unit = UNITS[kind]
    if cache and path.is_file():
        try:
            arrays, stored = load_npz(path)  # the cache file's own record (not a Measurement's metadata)
            ks = tuple(arrays[f"k{j}"] for j in range(v.size))
            return PSFFamily(ci, kind, v, ks, tuple(arrays["pedestals"].tolist()), 0.0, unit, stored["source"])
        except Exception as e:  # noqa: BLE001 - a corrupt cache entry is recomputed
            log.warning("ignoring unreadable PSF family cache %s: %s", path, e)
    kernels, pedestals, source = _build_family(system, ci, kind, v, fe, supersample, posts, optical_train)
    if cache:
        try:
            atomic_save_npz(path, {"kind": "psf-family", "key": key, "source": source},
                            pedestals=np.asarray(pedestals), **{f"k{j}": k for j, k in enumerate(kernels)})
        except OSError as e:
            log.warning("could not cache the PSF family in %s: %s", path, e)
    return PSFFamily(ci, kind, v, tuple(kernels), tuple(pedestals), 0.0, unit, source)


def _build_family(system: SystemDesign, ci: int, kind: str, values: np.ndarray, filter_enabled: bool,
                  supersample: int, posts: str, optical_train: bool) -> tuple[list[np.ndarray], list[float], str]:
    """The members' ``(kernels, pedestals, source)``: the simulator's channel optics (its camera, provider,
    metasurface transmission and glare) with the channel's kernel on a moved plane or its lens rescaled."""
    import warnings

    from metafovea.imaging.kernels import build_channel_optics, pixel_psf, resolve_provider
    from metafovea.imaging.simulate import SimulationOptions, camera_for

    opt = SimulationOptions(filter_enabled=filter_enabled, posts=posts, optical_train=optical_train,
                            supersample=supersample)
    cam = camera_for(system, opt)
    provider, provider_name = resolve_provider("auto", None, cam.post_sets)
    ch = cam.channels[ci - 1]
    tr = cam.trains[ci - 1] if cam.trains else None
    transmitted = 1.0 if tr is None or provider_name != "optics" else tr.metasurface_transmission
    leaks = () if tr is None else [(lk.power_fraction / tr.throughput, lk.radius_um) for lk in tr.leaks]
    kernels, pedestals = [], []
    for val in values:
        if kind == "defocus":
            dz = defocus_shift_um(ch.lens.na, ch.lens.wavelength_um, val)
            prov = DisplacedFocusProvider(provider, {ch.name: dz}, {ch.name: transmitted})
            chan, t = ch, 1.0
        else:
            prov, t = provider, transmitted
            chan = replace(ch, lens=ch.lens.with_(f_um=ch.lens.f_um * (1.0 + val)))
        with warnings.catch_warnings():  # the engine's accuracy notes on defocused kernels: the family's, not ours
            warnings.simplefilter("ignore")
            optics = build_channel_optics(chan, prov, cam.radiance, ss=supersample, field_patches=1,
                                          scene_temperature_k=system.scene_temperature_k, transmitted=t,
                                          leaks=leaks)
        k, ped = pixel_psf(optics)
        kernels.append(k)
        pedestals.append(float(ped))
    src = (f"{ch.name} lens, {kind} family ({provider_name} provider, {'10 um filter' if filter_enabled else 'band'},"
           f" {values.size} members)")
    return kernels, pedestals, src


def families_for(m: Measurement, system: SystemDesign | None = None, *, kind: str = "defocus",
                 channels: Sequence[int | str] = ("foveal", "perifoveal"), values: ArrayLike | None = None,
                 cache: bool = True) -> list[PSFFamily]:
    """The families of :func:`psf_family` for a Measurement: the system that made it (default: the paper's
    prototype) with the sensor's working crop set to the frames' size, and the filter its radiometric calibration
    states.

    Parameters
    ----------
    m : Measurement
    system : SystemDesign, optional
    kind : {'defocus', 'focal-length'}
    channels : sequence of {'foveal', 'perifoveal'}
    values : array_like, optional
        The members (default :data:`DEFAULT_VALUES`).
    cache : bool

    Returns
    -------
    list of PSFFamily
    """
    from metafovea.config import SystemDesign

    system = system or SystemDesign.paper()
    system = replace(system, sensor=replace(system.sensor, crop=(int(m.shape[1]), int(m.shape[2]))))
    cal = m.radiometric_calibration
    filt = None if cal is None else cal.filter_um is not None
    return [psf_family(system, channel=c, kind=kind, values=values, filter_enabled=filt, cache=cache)
            for c in channels]


def _otf_on(shape: tuple[int, int], k: np.ndarray) -> np.ndarray:
    """The kernel's transfer function at the rfft frequencies of ``shape`` (a kernel wider than the grid folded:
    the transfer function sampled at the grid's frequencies)."""
    from scipy.fft import rfft2

    H, W = shape
    n = k.shape[0]
    c = n // 2
    kk = np.zeros((H, W))
    iy, ix = (np.arange(n) - c) % H, (np.arange(n) - c) % W
    np.add.at(kk, (iy[:, None], ix[None, :]), k)
    return rfft2(kk)


def _hann(n: int) -> np.ndarray:
    """The taper along one axis: ``sin^2`` over ``n + 2`` points without its zero ends."""
    return np.hanning(n + 2)[1:-1]


#: the Hann taper's spectral window per axis, ``|W(k)|^2`` at DFT offsets -1, 0, +1 over their sum (its coefficients
#: are -1/4, 1/2, -1/4: powers 1/16, 1/4, 1/16): the tapered periodogram's expectation is the spectrum smoothed by it
TAPER_WINDOW = (1.0 / 6.0, 2.0 / 3.0, 1.0 / 6.0)


@dataclass
class _Periodogram:
    """Eq. (3)'s data on the crop's rfft grid ``(P, Q // 2 + 1)``: the tapered periodogram per pixel, each frequency's
    weight (0 where unused), ``ln |f|`` (clipped to the knots' span), the noise variance and the taper's variance
    inflation ``rho``; the spline's knots and each frequency's lower knot ``i0`` and upper knot's weight ``w1``."""

    shape: tuple[int, int]
    used: np.ndarray
    power: np.ndarray
    weight: np.ndarray
    noise_var: float
    rho: float
    knots: np.ndarray
    i0: np.ndarray
    w1: np.ndarray

    @classmethod
    def of(cls, z: np.ndarray, noise_var: float, knots_per_octave: float) -> _Periodogram:
        from scipy.fft import rfft2

        H, W = z.shape
        w = np.outer(_hann(H), _hann(W))
        s2 = float(np.sum(w ** 2))
        power = np.abs(rfft2((z - np.mean(z)) * w)) ** 2 / s2
        f = rfft_frequencies((H, W))
        used = f >= MIN_FREQUENCY_CELLS / min(H, W)
        wt = np.where(used, 1.0, 0.0)
        wt[:, 0] *= 0.5  # the self-conjugate columns hold each frequency twice
        if W % 2 == 0:
            wt[:, -1] *= 0.5
        rho = H * W * float(np.sum(w ** 4)) / s2 ** 2
        # the spline: knots 1 / knots_per_octave octaves apart from the lowest frequency used to the highest
        lo, hi = float(np.log(f[used].min())), float(np.log(f.max()))
        n = max(2, int(math.ceil((hi - lo) / math.log(2.0) * knots_per_octave)) + 1)
        knots = np.linspace(lo, hi, n)
        t = (np.clip(np.log(np.maximum(f, 1e-300)), lo, hi) - lo) / (knots[1] - knots[0])
        i0 = np.clip(np.floor(t).astype(int), 0, n - 2)
        return cls((H, W), used, power, wt, float(noise_var), rho, knots, i0, t - i0)

    def smooth(self, x: np.ndarray) -> np.ndarray:
        """``x`` (rfft grid) convolved with :data:`TAPER_WINDOW` along both axes; beyond the half plane's first and
        last columns the values are their mirror images (``x(-f) = x(f)`` for the symmetric fields here)."""
        a, b, _ = TAPER_WINDOW
        y = b * x + a * (np.roll(x, 1, axis=0) + np.roll(x, -1, axis=0))
        P, Q = self.shape
        neg = (-np.arange(P)) % P
        left = np.concatenate([y[neg, 1][:, None], y[:, :-1]], axis=1)
        # beyond the last column: the column of frequency -(last + 1), i.e. the mirror of Q/2 - 1 (Q even) or of
        # (Q - 1)/2 itself (Q odd)
        right = np.concatenate([y[:, 1:], y[neg, -2 if Q % 2 == 0 else -1][:, None]], axis=1)
        return b * y + a * (left + right)

    def _log_spectrum(self, theta: np.ndarray) -> np.ndarray:
        return (1.0 - self.w1) * theta[self.i0] + self.w1 * theta[self.i0 + 1]

    def terms(self, d2: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Eq. (3)'s term at each frequency of the grid (0 where unused; before the division by ``rho``): the
        expectation ``|D|^2 S`` smoothed by the taper's window, plus the noise."""
        m = self.smooth(d2 * np.exp(self._log_spectrum(theta))) + self.noise_var
        return self.weight * (np.log(m) + self.power / m)

    def fit(self, d2: np.ndarray) -> tuple[float, np.ndarray]:
        """Eq. (3) (before the division by ``rho``), plus the spectrum's curvature penalty, minimised over the
        spline's knots for the squared transfer function ``d2`` (rfft grid): ``(value, ln S at the knots)``. Fisher
        scoring (the expected Hessian, positive semi-definite), each step halved until it lowers the value."""
        K, i0, w1 = self.knots.size, self.i0, self.w1
        basis = [np.where(i0 == k, 1.0 - w1, 0.0) + np.where(i0 + 1 == k, w1, 0.0) for k in range(K)]
        P, wt, nv = self.power, self.weight, self.noise_var
        h = (self.knots[1] - self.knots[0]) / math.log(2.0)  # octaves between knots
        L = np.diff(np.eye(K), 2, axis=0)
        # the curvature penalty in the same units as eq. (3)'s sum: rho (sum_k (second difference / h^2)^2 h) / 2 tau^2
        R = (self.rho / (2.0 * CURVATURE_PER_OCTAVE ** 2 * h ** 3)) * (L.T @ L)
        dd = np.maximum(d2, 1e-300)
        # start: each knot's detected signal over the transfer function (a floor where nothing is detected)
        num = np.array([np.sum(wt * b * np.maximum(P - nv, 0.0)) for b in basis])
        den = np.array([np.sum(wt * b * dd) for b in basis])
        cnt = np.array([np.sum(wt * b) for b in basis])
        theta = np.log(np.maximum(num, 1e-3 * nv * np.maximum(cnt, 1e-30)) / np.maximum(den, 1e-300))

        def total(th: np.ndarray) -> float:
            return float(np.sum(self.terms(dd, th))) + float(th @ R @ th)

        v = total(theta)
        for _ in range(SCORING_STEPS):
            x = dd * np.exp(self._log_spectrum(theta))
            m = self.smooth(x) + nv
            r = wt * (1.0 / m - P / m ** 2)
            J = [self.smooth(x * b) for b in basis]  # d m / d theta_k
            grad = np.array([np.sum(r * j) for j in J]) + 2.0 * R @ theta
            g2 = wt / m ** 2
            F = np.array([[np.sum(g2 * ja * jb) for jb in J] for ja in J]) + 2.0 * R
            # a knot the data do not reach (no signal through the OTF) is held by a vanishing ridge
            F[np.diag_indices(K)] += 1e-9 * max(float(np.trace(F)), 1e-30) + 1e-12
            step = np.clip(-np.linalg.solve(F, grad), -3.0, 3.0)
            for _ in range(12):
                v_new = total(theta + step)
                if v_new <= v:
                    break
                step *= 0.5
            else:
                break
            theta, gain, v = theta + step, v - v_new, v_new
            if gain < 1e-9 * abs(v) + 1e-9:
                break
        return v, theta


def psf_evidence(z: ArrayLike, noise_var: float, kernels: Sequence[np.ndarray], *, reference: int = 0,
                 knots_per_octave: float = KNOTS_PER_OCTAVE) -> dict[str, Any]:
    """The evidence, eq. (3), of each candidate kernel for one separated channel, and eq. (4) against one of them.

    Parameters
    ----------
    z : array_like, shape (H, W)
        The channel's separated image on the crop (DN above the dark level, illumination divided out).
    noise_var : float, DN^2
        Its noise variance per pixel.
    kernels : sequence of ndarray, shape (n, n)
        The candidates (odd, centred; a pedestal changes only DC, which eq. 3 leaves out).
    reference : int
        The candidate the others are compared with (the nominal PSF).
    knots_per_octave : float
        The spectrum's knots per octave of ``|f|`` (:data:`KNOTS_PER_OCTAVE`).

    Returns
    -------
    dict
        ``neg_log_evidence`` (K,): eq. (3), whose differences are log evidence ratios; ``two_ln_b`` (K,) and ``z``
        (K,): eq. (4) against ``reference``; ``log_spectrum`` (K, n_knots): each candidate's fitted ``ln S`` (DN^2
        per pixel per unit bandwidth) at ``knots_cycles_per_px``; ``rho``; ``frequencies_used``.
    """
    zz = np.asarray(z, dtype=np.float64)
    if zz.ndim != 2 or min(zz.shape) < 4 * MIN_FREQUENCY_CELLS or not np.all(np.isfinite(zz)):
        raise InputError("z", f"array of shape {zz.shape}", f"a finite (H, W) image, H, W >= {4 * MIN_FREQUENCY_CELLS}")
    if not (math.isfinite(noise_var) and noise_var > 0):
        raise InputError("noise_var", noise_var, "a noise variance > 0 (DN^2)")
    if not (math.isfinite(knots_per_octave) and 0 < knots_per_octave <= 8):
        raise InputError("knots_per_octave", knots_per_octave, "knots per octave in (0, 8]")
    if not 0 <= reference < len(kernels):
        raise InputError("reference", reference, f"an index of the {len(kernels)} kernels")
    pg = _Periodogram.of(zz, noise_var, knots_per_octave)
    d2s = [np.abs(_otf_on(pg.shape, np.asarray(k, np.float64))) ** 2 for k in kernels]
    fits = [pg.fit(d2) for d2 in d2s]
    nle = np.array([v for v, _ in fits]) / pg.rho
    ref_terms = pg.terms(d2s[reference], fits[reference][1])
    zs = np.zeros(len(fits))
    for j, (d2, (_, th)) in enumerate(zip(d2s, fits)):
        d = (ref_terms - pg.terms(d2, th))[pg.used]
        sd = math.sqrt(pg.rho * float(np.sum((d - d.mean()) ** 2)))
        zs[j] = float(d.sum()) / sd if sd > 0 else 0.0
    return {"neg_log_evidence": nle, "two_ln_b": 2.0 * (nle[reference] - nle), "z": zs,
            "log_spectrum": np.array([th for _, th in fits]), "knots_cycles_per_px": np.exp(pg.knots),
            "rho": pg.rho, "frequencies_used": int(pg.used.sum())}


@dataclass
class PSFRefinement:
    """What :func:`refine_psf` chose, per family.

    Attributes
    ----------
    psfs : ChannelPSFs
        The PSFs to reconstruct with: the nominal ones with each refined channel replaced.
    channels : list of dict
        Per family: ``channel`` (``'x1'``/``'x2'``), ``kind``, ``unit``, ``nominal``, ``best`` (the member of largest
        evidence), ``chosen`` (``best`` where it passes both tests, else ``nominal``), ``refined`` (bool),
        ``two_ln_b`` and ``z`` (eq. 4 of ``best`` against the nominal), ``z_min`` (the corrected one-sided level),
        ``kernel_change`` (the total-variation distance of ``best``'s kernel from the nominal one, each normalised),
        ``interval`` (the members within ``2 ln B`` = 1 of ``best``), ``at_edge`` (``best`` is the family's first or
        last member), ``nominal_matches_file`` (the family's nominal kernel is the file's, within 1 % of its power),
        ``curve`` (``values``, ``two_ln_b``, ``z``), ``warning`` (a line, or None) and ``source``.
    min_evidence : float
    seconds : float
    """

    psfs: ChannelPSFs
    channels: list[dict[str, Any]] = field(default_factory=list)
    min_evidence: float = MIN_EVIDENCE
    seconds: float = 0.0

    @property
    def refined(self) -> bool:
        return any(c["refined"] for c in self.channels)

    def summary(self) -> dict[str, Any]:
        """The refinement for ``info`` and the JSON output (``lines``: :meth:`lines`)."""
        return {"refined": self.refined, "min_evidence": self.min_evidence, "seconds": self.seconds,
                "channels": self.channels, "lines": self.lines()}

    def lines(self) -> list[str]:
        """One line per family for a printed summary (what was chosen, by how much), then its warning."""
        out = []
        for c in self.channels:
            what = (f"refined to {c['chosen']:+g} {c['unit']} (nominal {c['nominal']:+g})" if c["refined"] else
                    f"nominal kept ({c['nominal']:+g} {c['unit']})")
            lo, hi = c["interval"]
            out.append(f"PSF {c['channel']} {c['kind']}: {what}; best {c['best']:+g} [{lo:+g}, {hi:+g}], "
                       f"2 ln B = {c['two_ln_b']:.1f} (>= {self.min_evidence:g}), Z = {c['z']:.1f} "
                       f"(>= {c['z_min']:.2f})")
            if c["warning"]:
                out.append(f"warning: {c['warning']}")
        return out


def _tv_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Total-variation distance of two centred kernels, each normalised (0: the same shape, 1: disjoint)."""
    n = max(a.shape[0], b.shape[0])

    def pad(x: np.ndarray) -> np.ndarray:
        p = (n - x.shape[0]) // 2
        return np.pad(x, p) / max(float(x.sum()), 1e-300)
    return 0.5 * float(np.abs(pad(a) - pad(b)).sum())


def _z_min(members: int) -> float:
    """Vuong's one-sided level at :data:`FAMILY_ALPHA` over ``members - 1`` comparisons (Bonferroni)."""
    from scipy.special import ndtri

    return float(ndtri(1.0 - FAMILY_ALPHA / max(members - 1, 1)))


def _channel_choice(fam: PSFFamily, ev: dict[str, Any], file_kernel: np.ndarray, min_evidence: float) -> dict:
    """The chosen member of one family, its evidence and the warnings (:class:`PSFRefinement` ``channels``)."""
    two_ln_b, z = ev["two_ln_b"], ev["z"]
    j0, jb = fam.nominal_index, int(np.argmax(ev["two_ln_b"]))
    ratio, z_min = float(two_ln_b[jb]), _z_min(fam.values.size)
    near = np.flatnonzero(two_ln_b >= ratio - 1.0)
    refined = jb != j0 and ratio >= min_evidence and float(z[jb]) >= z_min
    tv = _tv_distance(fam.kernels[j0], file_kernel)
    moved = _tv_distance(fam.kernels[j0], fam.kernels[jb])
    at_edge = jb in (0, fam.values.size - 1)
    notes = []
    if refined:
        notes.append(f"the x{fam.channel} PSF differs from the file's ({fam.kind} {fam.values[jb]:+g} {fam.unit}, "
                     f"2 ln B = {ratio:.0f}, Z = {z[jb]:.1f}; the kernel moves by a total-variation distance of "
                     f"{moved:.2f}): with the file's PSF the reconstruction would lose accuracy")
    elif jb != j0 and ratio >= min_evidence:
        notes.append(f"the x{fam.channel} evidence favours {fam.kind} {fam.values[jb]:+g} {fam.unit} (2 ln B = "
                     f"{ratio:.0f}) but not beyond the scene model's error (Z = {z[jb]:.1f} < {z_min:.2f}): a PSF "
                     "mismatch is possible; the nominal PSF is kept")
    if (refined or ratio >= min_evidence) and at_edge:
        notes.append("the best member is the family's last: the PSF may lie beyond it")
    if tv > 0.01:
        notes.append(f"the family's nominal x{fam.channel} kernel is not the file's (total-variation distance "
                     f"{tv:.3f}): the family may not describe this camera")
    return {"channel": f"x{fam.channel}", "kind": fam.kind, "unit": fam.unit, "nominal": float(fam.values[j0]),
            "best": float(fam.values[jb]), "chosen": float(fam.values[jb if refined else j0]), "refined": bool(refined),
            "two_ln_b": ratio, "z": float(z[jb]), "z_min": z_min, "kernel_change": moved,
            "interval": [float(fam.values[near.min()]), float(fam.values[near.max()])], "at_edge": bool(at_edge),
            "nominal_matches_file": bool(tv <= 0.01),
            "curve": {"values": fam.values.tolist(), "two_ln_b": two_ln_b.tolist(), "z": z.tolist()},
            "warning": "; ".join(notes) or None, "source": fam.source}


def _relation_misfit(scene: tuple[np.ndarray, np.ndarray], scale: float) -> float:
    """The foveal relation's misfit of both channels' estimates ``scene``: the rms of ``D s_1 - g C s_2 - o``
    (:mod:`metafovea.reconstruct.operators`; ``g``, ``o`` fitted), over the foveal side's standard deviation."""
    from metafovea.reconstruct.operators import centre_crop, downsample

    lo, c2 = downsample(np.asarray(scene[0], np.float64), scale), centre_crop(np.asarray(scene[1], np.float64), scale)
    A = np.stack([c2.ravel(), np.ones(c2.size)], axis=1)
    r = lo.ravel() - A @ np.linalg.lstsq(A, lo.ravel(), rcond=None)[0]
    return float(np.sqrt(np.mean(r ** 2)) / max(float(np.std(lo)), 1e-300))


def refine_psf(frames: ArrayLike, alpha: ArrayLike, psfs: ChannelPSFs, families: Sequence[PSFFamily], *,
               offset: float = 0.0, sigma: float | None = None, fpn_error_dn: float = 0.0,
               min_evidence: float = MIN_EVIDENCE, knots_per_octave: float = KNOTS_PER_OCTAVE,
               foveal_scale: float | None = None,
               estimate: Callable[[ChannelPSFs], tuple[np.ndarray, np.ndarray]] | None = None) -> PSFRefinement:
    """Each family's member of largest evidence, eq. (3), where it beats the nominal PSF by both tests of eq. (4).

    Parameters
    ----------
    frames : array_like, shape (T, H, W)
        DN, fixed pattern removed (as :func:`~metafovea.reconstruct.deconvolve.separate_deconvolve`).
    alpha : array_like, shape (T,)
        Mixing ratios.
    psfs : ChannelPSFs
        The nominal PSFs (the file's): their illumination divides the separated channels, and a channel without a
        family keeps its kernel.
    families : sequence of PSFFamily
        At most one per channel (:func:`psf_family`, :func:`families_for`, or built elsewhere).
    offset : float
        The dark level, DN.
    sigma : float, optional
        The frames' temporal noise, DN (default: from the residuals of the per-pixel separation).
    fpn_error_dn : float
        The rms error of the subtracted fixed pattern, DN (counted as noise, as the solver does).
    min_evidence : float
        The ``2 ln B`` of eq. (4) a member needs over the nominal (:data:`MIN_EVIDENCE`).
    knots_per_octave : float
        The scene spectrum's knots per octave (:data:`KNOTS_PER_OCTAVE`).
    foveal_scale : float, optional
        The channels' scale f1 / f2. With ``estimate``, a member that passes both tests replaces the nominal one
        only where the foveal relation of the two channels' estimates (the foveal image scaled down against the
        perifoveal centre) holds at least as well with it as with the nominal PSF: a check that needs no scene
        model (``relation_misfit`` in the output: nominal, refined).
    estimate : callable, optional
        ``estimate(psfs) -> (s_1, s_2)``: both channels' scene estimates (H, W) from these frames through ``psfs``
        (:func:`~metafovea.reconstruct.deconvolve.deconvolve_measurement` passes its Wiener solve).

    Returns
    -------
    PSFRefinement

    Notes
    -----
    The module docstring gives the model, eqs. (1)-(4), and why the evidence is the criterion.

    References
    ----------
    See the module docstring, [1]_ to [6]_.
    """
    import time

    t0 = time.perf_counter()
    if not (math.isfinite(min_evidence) and min_evidence >= 0):
        raise InputError("min_evidence", min_evidence, "a log evidence ratio 2 ln B >= 0")
    chans = [f.channel for f in families]
    if len(set(chans)) != len(chans):
        raise InputError("families", [f"x{c}" for c in chans], "at most one family per channel")
    pb, C, _ = prepare_problem(frames, alpha, psfs, offset, sigma, "padded", "edge", fpn_error_dn)
    out = PSFRefinement(psfs, [], float(min_evidence))
    refined = psfs
    base = None
    for fam in families:
        i = fam.channel - 1
        ev = psf_evidence(pb.zc[i], float(C[i, i]), fam.kernels, reference=fam.nominal_index,
                          knots_per_octave=knots_per_octave)
        choice = _channel_choice(fam, ev, psfs.kernels[i], float(min_evidence))
        if choice["refined"] and foveal_scale is not None and estimate is not None:
            if base is None:
                base = _relation_misfit(estimate(psfs), float(foveal_scale))
            cand = _relation_misfit(estimate(fam.member(psfs, int(np.argmax(ev["two_ln_b"])))), float(foveal_scale))
            choice["relation_misfit"] = [base, cand]
            if cand > base:
                choice.update(refined=False, chosen=choice["nominal"], warning=(
                    f"the x{fam.channel} evidence favours {fam.kind} {choice['best']:+g} {fam.unit} (2 ln B = "
                    f"{choice['two_ln_b']:.0f}, Z = {choice['z']:.1f}) but the foveal relation holds worse with it "
                    f"(misfit {cand:.3g} against {base:.3g}): the nominal PSF is kept; a PSF mismatch is possible"))
        out.channels.append(choice)
        if choice["refined"]:
            refined = fam.member(refined, int(np.argmax(ev["two_ln_b"])))
    out.psfs = refined
    out.seconds = time.perf_counter() - t0
    return out


def refine_measurement(m: Measurement, frames: ArrayLike, alpha: ArrayLike, psfs: ChannelPSFs,
                       families: str | Sequence[PSFFamily], *, offset: float, sigma: float | None = None,
                       fpn_error_dn: float = 0.0, system: SystemDesign | None = None,
                       estimate: Callable[[ChannelPSFs], tuple[np.ndarray, np.ndarray]] | None = None) -> PSFRefinement:
    """:func:`refine_psf` of a Measurement's frames, with a family kind built for it (:func:`families_for`).

    Parameters
    ----------
    m : Measurement
        Its radiometric calibration gives the filter of a family built here.
    frames : array_like, shape (T, H, W)
        Its frames, fixed pattern removed, invalid samples replaced (DN).
    alpha : array_like, shape (T,)
    psfs : ChannelPSFs
        The nominal PSFs.
    families : {'defocus', 'focal-length'} or sequence of PSFFamily
        A kind of :data:`FAMILY_KINDS` (both channels' families for ``system``), or the families.
    offset : float
        The dark level, DN.
    sigma : float, optional
    fpn_error_dn : float
    system : SystemDesign, optional
        The camera a family kind is built for (default: the paper's prototype).
    estimate : callable, optional
        Both channels' estimates through given PSFs, for the foveal relation's check at the file's scale
        (:func:`refine_psf`).

    Returns
    -------
    PSFRefinement
    """
    fams = families_for(m, system, kind=families) if isinstance(families, str) else list(families)
    return refine_psf(frames, alpha, psfs, fams, offset=offset, sigma=sigma, fpn_error_dn=fpn_error_dn,
                      foveal_scale=m.recorded_scale, estimate=estimate)

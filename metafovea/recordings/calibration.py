"""Counts to kelvin: the radiometric calibration of a recording in the Measurement's terms.

The Measurement's model (the simulator's, and what :func:`metafovea.reconstruct.deconvolve.temperatures` inverts)
is a sensor linear in the in-band radiance ``L(T)`` of :class:`metafovea.radiometry.BandRadiance`::

    DN_i = dark_dn + G_i L(T),    G_i = dn_per_k_300K[x_i] / dL/dT(300 K)

per channel ``i`` (``x1`` foveal, ``x2`` perifoveal), so a brightness temperature is ``L^-1((DN - dark_dn) / G_i)``.
A recording gets ``dark_dn``, ``G`` and the band in one of two ways; both keep the frames linear in radiance
(the separation mixes radiances, so no non-linear map is applied to the data):

* **Planck constants** (FLIR's ``R1, R2, B, F, O``, from the file or ``--planck R,B,F,O`` with ``R = R1 / R2``):
  the camera's counts are ``counts = R1 / (R2 (exp(B / T) - F)) - O``, FLIR's and ExifTool's sign of ``O``
  (flyr's too; ``PlanckO`` is typically negative, e.g. -7340). That curve is a one-wavelength fit to the camera's
  band response; :func:`from_planck` fits ``counts = dark_dn + G L(T)`` to it by least squares over the
  recording's temperature range (+-10 K) and reports the fit's largest temperature error (``fit_max_error_k``;
  figures for a FLIR curve: BENCHMARKS.md, "Recordings"). The band should be the camera's (``band_um``), and a
  wider scene range costs accuracy: the band model is affine in ``L(T)``, FLIR's curve is not.
* **Two-point blackbody** (frames of a blackbody filling the field at ``T1`` and at ``T2``, :func:`two_point`):
  per pixel ``g_p = (c2_p - c1_p) / (L(T2) - L(T1))``, ``o_p = c1_p - g_p L(T1)``; ``G`` and ``dark_dn`` are their
  medians. ``per-pixel`` (default) also corrects the frames, ``DN = dark_dn + (G / g_p) (counts - o_p)``, the
  two-point non-uniformity correction (pixels whose gain is not positive or is off the median by more than 2x are
  marked in ``bad_pixels``); ``global`` keeps the frames and uses ``G`` and ``dark_dn`` alone.

The object signal (FLIR's measurement model, a radiometric file's own ``Emissivity``,
``ReflectedApparentTemperature``, ``AtmosphericTemperature``, ``ObjectDistance``, ``RelativeHumidity``,
``IRWindowTemperature`` / ``IRWindowTransmission`` and the atmospheric constants ``Alpha1/2, Beta1/2, X``;
:class:`SceneParameters`): what reaches the detector is the object's radiance weighted by its emissivity and the
path's transmission plus the radiance of the reflected surroundings, the air and the window, every term on the
Planck curve's count scale::

    counts = g counts_obj + c,    g = e tau^2 t_w,
    c = (1 - e) tau^2 t_w counts(T_refl) + (1 - tau) tau t_w counts(T_atm) + (1 - t_w) tau counts(T_win)
        + (1 - tau) counts(T_atm)

(``tau`` the air's transmission over half the object distance, the window assumed half-way, as FLIR, ExifTool's
forum and Minkina & Dudzik, *Infrared Thermography: Errors and Uncertainties* (Wiley 2009) give it, and as flyr
and flirpy compute it). The map is affine, so the frames stay as recorded: :func:`from_planck` fits the band
model to the object's counts and folds ``g`` and ``c`` into the Measurement's gain and dark level
(``G' = g G``, ``dark' = g dark + c``), and ``temperatures`` then reports the object's temperature.

Both channels: a blackbody filling the field reaches the sensor through both lenses, so what either calibration
measures is the camera's gain over a mixture. With the channels' flat-field ratio ``r = G_1 / G_2``
(``--foveal-gain``, the foveal constraint's gain; 1 by default) and blackbody frames spanning whole turns of the
polariser (mean alpha 1/2), ``G_2 = 2 G / (1 + r)`` and ``G_1 = r G_2``; with ``r = 1`` no assumption is needed.
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.errors import InputError, as_float
from metafovea.radiometry import BAND_UM, T_MAX_K, BandRadiance

#: ``--calibration-gain`` choices
GAIN_MODES = ("per-pixel", "global")
#: a pixel whose two-point gain is off the median by more than this factor is a bad pixel
GAIN_OUTLIER = 2.0


@dataclass(frozen=True)
class PlanckConstants:
    """FLIR's calibration curve ``counts = R1 / (R2 (exp(B / T) - F)) - O`` (T in K)."""

    R1: float
    B: float
    F: float = 1.0
    O: float = 0.0  # FLIR's name
    R2: float = 1.0

    def __post_init__(self) -> None:
        for k in ("R1", "B", "R2"):
            if not (np.isfinite(getattr(self, k)) and getattr(self, k) > 0):
                raise InputError(f"Planck {k}", getattr(self, k), "a finite number > 0")
        for k in ("F", "O"):
            if not np.isfinite(getattr(self, k)):
                raise InputError(f"Planck {k}", getattr(self, k), "a finite number")

    @classmethod
    def parse(cls, text: str, name: str = "planck") -> PlanckConstants:
        """``'R,B,F,O'`` (``R = R1 / R2``)."""
        parts = [p for p in re.split(r"[,\s]+", str(text).strip()) if p]
        if len(parts) != 4:
            raise InputError(name, text, "four numbers R,B,F,O (counts = R / (exp(B / T) - F) - O)")
        r, b, f, o = (as_float(name, p) for p in parts)
        try:
            return cls(R1=r, B=b, F=f, O=o)
        except InputError as e:
            raise InputError(name, text, f"constants with {e.parameter.split()[-1]} {e.allowed}") from None

    def counts(self, temperature_k: ArrayLike) -> np.ndarray:
        t = np.asarray(temperature_k, dtype=np.float64)
        return self.R1 / (self.R2 * (np.exp(self.B / t) - self.F)) - self.O

    def temperature(self, counts: ArrayLike) -> np.ndarray:
        """The curve's inverse (NaN where the counts are below its range)."""
        c = np.asarray(counts, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            arg = self.R1 / (self.R2 * (c + self.O)) + self.F
            return np.where(arg > 1, self.B / np.log(np.where(arg > 1, arg, 2.0)), np.nan)


@dataclass(frozen=True)
class SceneParameters:
    """What a FLIR radiometric file says about the object and the path to it (module docstring): emissivity,
    reflected apparent temperature (K), air temperature (K), object distance (m), relative humidity (0-1), the
    IR window's temperature (K) and transmission, and the camera's atmospheric constants (ExifTool's
    ``AtmosphericTransAlpha1/2``, ``Beta1/2``, ``X``). The defaults are a black object seen through nothing."""

    emissivity: float = 1.0
    reflected_k: float = 293.15
    atmosphere_k: float = 293.15
    distance_m: float = 0.0
    humidity: float = 0.5
    window_k: float = 293.15
    window_transmission: float = 1.0
    alpha1: float = 0.006569
    alpha2: float = 0.01262
    beta1: float = -0.002276
    beta2: float = -0.00667
    x: float = 1.9

    def __post_init__(self) -> None:
        checks = {"emissivity": (0.0, 1.0), "window_transmission": (0.0, 1.0), "humidity": (0.0, 1.0),
                  "reflected_k": (0.0, T_MAX_K), "atmosphere_k": (0.0, T_MAX_K), "window_k": (0.0, T_MAX_K)}
        for k, (lo, hi) in checks.items():
            v = getattr(self, k)
            if not (np.isfinite(v) and lo < v <= hi) and not (k == "humidity" and v == 0.0):
                raise InputError(k, v, f"{lo:g} < {k} <= {hi:g}")
        for k in ("distance_m", "alpha1", "alpha2", "beta1", "beta2", "x"):
            if not np.isfinite(getattr(self, k)) or (k == "distance_m" and self.distance_m < 0):
                raise InputError(k, getattr(self, k), "a finite number" + (" >= 0" if k == "distance_m" else ""))

    def transmission(self) -> float:
        """The air's transmission over half the object distance (FLIR's two-band model; water vapour from the
        humidity and the air temperature in Celsius)."""
        t = self.atmosphere_k - 273.15
        h2o = self.humidity * math.exp(1.5587 + 0.06939 * t - 0.00027816 * t ** 2 + 0.00000068455 * t ** 3)
        d = -math.sqrt(self.distance_m / 2.0)
        return (self.x * math.exp(d * (self.alpha1 + self.beta1 * math.sqrt(h2o)))
                + (1.0 - self.x) * math.exp(d * (self.alpha2 + self.beta2 * math.sqrt(h2o))))

    def affine(self, planck: PlanckConstants) -> tuple[float, float]:
        """``(g, c)`` of ``counts = g counts_obj + c`` (module docstring), on ``planck``'s count scale."""
        tau, tw, e = self.transmission(), self.window_transmission, self.emissivity
        g = e * tau * tau * tw
        if not (np.isfinite(g) and g > 0):
            raise InputError("emissivity", e, "an object signal that reaches the camera (emissivity x "
                             "transmission > 0)", detail=f"air transmission {tau:.4g}, window {tw:.4g}")
        refl, atm, win = (float(planck.counts(t)) for t in (self.reflected_k, self.atmosphere_k, self.window_k))
        c = (1 - e) * tau * tau * tw * refl + (1 - tau) * tau * tw * atm + (1 - tw) * tau * win + (1 - tau) * atm
        return float(g), float(c)


@dataclass(frozen=True)
class Radiometric:
    """``DN = dark_dn + gain L(T)`` for the camera over a uniform field (module docstring): ``gain`` in DN per
    W m^-2 sr^-1, the band the radiance is integrated over, how it was found."""

    gain: float
    dark_dn: float
    band_um: tuple[float, float] = BAND_UM
    filter_um: tuple[float, float] | None = None
    method: str = "planck"
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def band(self) -> BandRadiance:
        return BandRadiance.from_band(self.band_um, filter_um=self.filter_um)

    def channel_gains(self, foveal_gain: float = 1.0) -> tuple[float, float]:
        """``(G_1, G_2)`` for the channels' flat-field ratio ``r`` (module docstring)."""
        g2 = 2.0 * self.gain / (1.0 + foveal_gain)
        return foveal_gain * g2, g2

    def meta(self, foveal_gain: float = 1.0) -> dict[str, Any]:
        """The Measurement metadata that makes ``reconstruct --deconvolve`` report kelvin: ``dark_dn``,
        ``dn_per_k_300K``, ``radiometry`` (as the simulator writes them) and ``calibration`` (this model)."""
        band = self.band
        dl = band.derivative(300.0)
        g1, g2 = self.channel_gains(foveal_gain)
        return {
            "dark_dn": self.dark_dn,
            "dn_per_k_300K": {"x1": g1 * dl, "x2": g2 * dl},
            "radiometry": {**band.summary(), "band_um": list(self.band_um),
                           "filter": list(self.filter_um) if self.filter_um else None,
                           "filter_enabled": self.filter_um is not None, "dL_dT_300K": dl},
            "calibration": {"method": self.method, "model": "DN = dark_dn + G_i L(T), L the in-band radiance; "
                            "G_2 = 2 G / (1 + r), G_1 = r G_2 (r: the foveal gain)",
                            "gain_dn_per_W_m2_sr": self.gain, "foveal_gain": foveal_gain, **self.info},
        }


def temperature_range(planck: PlanckConstants, frames: np.ndarray) -> tuple[float, float]:
    """The recording's temperatures through the curve (0.1-99.9 percentile of finite samples), +-10 K, within
    [150 K, T_MAX]."""
    sample = np.asarray(frames[:: max(1, frames.shape[0] // 16)], dtype=np.float64)
    sample = sample[np.isfinite(sample)]
    t = planck.temperature(np.percentile(sample, [0.1, 99.9])) if sample.size else np.array([np.nan, np.nan])
    if not np.all(np.isfinite(t)):
        raise InputError("planck", f"R1={planck.R1:g}, B={planck.B:g}, F={planck.F:g}, O={planck.O:g}",
                         "constants under which the recording's counts are temperatures (counts + O > 0)")
    return max(150.0, float(t[0]) - 10.0), min(T_MAX_K - 1.0, float(t[1]) + 10.0)


def from_planck(planck: PlanckConstants, frames: np.ndarray, *, band_um: tuple[float, float] = BAND_UM,
                filter_um: tuple[float, float] | None = None, source: str = "file",
                scene: SceneParameters | None = None) -> Radiometric:
    """``counts = dark_dn + G L(T)`` fitted to the Planck curve over the recording's range (module docstring);
    with ``scene``, ``L`` is the object's radiance (emissivity, reflections, air and window folded into the gain
    and the dark level; the fit range is the object's temperatures)."""
    g, pedestal = scene.affine(planck) if scene is not None else (1.0, 0.0)
    sample = np.asarray(frames[:: max(1, frames.shape[0] // 16)], dtype=np.float64)
    lo, hi = temperature_range(planck, (sample - pedestal) / g)
    band = BandRadiance.from_band(band_um, filter_um=filter_um)
    t = np.linspace(lo, hi, 96)
    c = planck.counts(t)
    L = band(t)
    A = np.stack([np.ones_like(L), L], axis=1)
    (dark, gain), *_ = np.linalg.lstsq(A, c, rcond=None)
    if not gain > 0:
        raise InputError("planck", f"B={planck.B:g}", "constants whose counts rise with temperature")
    err = band.temperature((c - dark) / gain) - t
    info = {"planck": {"R1": planck.R1, "R2": planck.R2, "B": planck.B, "F": planck.F, "O": planck.O,
                       "from": source, "curve": "counts = R1 / (R2 (exp(B / T) - F)) - O"},
            "fit_range_k": [lo, hi], "fit_max_error_k": float(np.nanmax(np.abs(err)))}
    if scene is not None:
        info["scene"] = {**asdict(scene), "from": source, "air_transmission": scene.transmission(),
                         "gain": g, "offset_counts": pedestal, "model": "counts = gain counts_obj(T) + offset_counts"}
    return Radiometric(float(g * gain), float(g * dark + pedestal), tuple(band_um), filter_um, "planck", info)


def parse_two_point(spec: str, name: str = "calibration") -> list[tuple[float, str]]:
    """``'two-point:T1=FILE1,T2=FILE2'`` (kelvin, an optional trailing K) -> ``[(T1, FILE1), (T2, FILE2)]``,
    colder first."""
    s = str(spec).strip()
    usage = "two-point:T1=FILE1,T2=FILE2 (blackbody temperatures in K, e.g. two-point:293.15=cold.tif,323.15=hot.tif)"
    if not s.lower().startswith("two-point:"):
        raise InputError(name, spec, usage)
    pts = []
    for part in s.split(":", 1)[1].split(","):
        if "=" not in part:
            raise InputError(name, spec, usage)
        t, f = part.split("=", 1)
        tk = as_float(name, t.strip().rstrip("Kk").strip())
        if not 0 < tk < T_MAX_K:
            raise InputError(name, spec, f"blackbody temperatures in K, 0 < T < {T_MAX_K:g}")
        pts.append((tk, f.strip()))
    if len(pts) != 2:
        raise InputError(name, spec, usage)
    pts.sort()
    if pts[1][0] - pts[0][0] < 1.0:
        raise InputError(name, spec, "two blackbody temperatures at least 1 K apart")
    return pts


def two_point(cold: np.ndarray, t_cold_k: float, hot: np.ndarray, t_hot_k: float, *, mode: str = "per-pixel",
              band_um: tuple[float, float] = BAND_UM, filter_um: tuple[float, float] | None = None,
              spec: str = "") -> tuple[Radiometric, np.ndarray | None, np.ndarray | None, np.ndarray]:
    """``(model, per-pixel gain or None, per-pixel offset or None, bad pixels (H, W))`` from the mean frames of a
    blackbody at ``t_cold_k`` and at ``t_hot_k`` (module docstring); an InputError naming ``calibration`` when
    the hotter one does not give more counts."""
    band = BandRadiance.from_band(band_um, filter_um=filter_um)
    l1, l2 = (float(band(t)) for t in (t_cold_k, t_hot_k))
    c1, c2 = np.asarray(cold, dtype=np.float64), np.asarray(hot, dtype=np.float64)
    g = (c2 - c1) / (l2 - l1)
    o = c1 - g * l1
    ok = np.isfinite(g) & np.isfinite(o) & (g > 0)
    if not ok.any():
        raise InputError("calibration", spec, "a hotter blackbody that gives more counts than the colder one")
    gm = float(np.median(g[ok]))
    ok &= (g > gm / GAIN_OUTLIER) & (g < gm * GAIN_OUTLIER)
    info = {"blackbody_k": [t_cold_k, t_hot_k], "mode": mode, "bad_pixels": int((~ok).sum()),
            "gain_spread_rel": float(np.std(g[ok]) / gm)}
    if mode == "global":
        gain = float((c2[ok].mean() - c1[ok].mean()) / (l2 - l1))
        dark = float(c1[ok].mean() - gain * l1)
        return Radiometric(gain, dark, tuple(band_um), filter_um, "two-point global", info), None, None, ~ok
    gain, dark = float(np.median(g[ok])), float(np.median(o[ok]))
    return Radiometric(gain, dark, tuple(band_um), filter_um, "two-point per-pixel", info), g, o, ~ok


def correct_frames(frames: np.ndarray, model: Radiometric, gain_map: np.ndarray, offset_map: np.ndarray,
                   bad: np.ndarray) -> np.ndarray:
    """The two-point non-uniformity correction ``DN = dark_dn + (G / g_p) (counts - o_p)`` (bad pixels kept as
    they are: the Measurement's ``bad_pixels`` leaves them out)."""
    scale = np.where(bad, 1.0, model.gain / np.where(bad, 1.0, gain_map))
    shift = np.where(bad, 0.0, model.dark_dn - scale * offset_map)
    return (np.asarray(frames, dtype=np.float32) * scale.astype(np.float32)[None]
            + shift.astype(np.float32)[None])

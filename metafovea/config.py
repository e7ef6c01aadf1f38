"""Design files (TOML) -> validated frozen dataclasses.

The paper's prototype is the built-in default: ``LensDesign.foveal()``, ``LensDesign.perifoveal()``,
``PlatformDesign()`` and ``SystemDesign.paper()`` equal what ``designs/*.toml`` spell out (a test keeps
them in step), so the default runs from any directory after ``pip install``. This module is the one home of the
paper's platform and camera numbers (the ``PAPER_*`` constants below; refractive indices in
:mod:`metafovea.materials`): other modules take them from here or require them as arguments, and a file that lacks
a physical parameter is an error, not a paper default (``tests/test_architecture.py`` rejects these literals
elsewhere).

Every value is checked on load; an error names the file, the key, the value and the allowed range
(:class:`metafovea.errors.InputError` with ``source`` = file path).

Units: lens-scale lengths are written in millimetres in the files (keys end in ``_mm``) and stored in
micrometres in the dataclasses (fields end in ``_um``).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.errors import InputError, check_choice, check_int, check_positive, check_range
from metafovea.materials import N_AIR, N_SI_10UM
from metafovea.units import PHASE_SIGN, UM_PER_MM

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

#: the polarisation a lens focuses: E along the lattice x or y axis
POLARIZATIONS = ("x", "y")
#: lattice sites at integer multiples of the period (a post at the centre) or half-integer ones
LATTICES = ("integer", "half")

# the paper's platform and camera (the defaults of the dataclasses below)
#: lattice period of the posts (um)
PAPER_PERIOD_UM = 4.0
#: height of the silicon posts (um)
PAPER_POST_HEIGHT_UM = 10.0
#: free-space wavelength the lenses are designed for (um)
PAPER_WAVELENGTH_UM = 10.0
#: the microbolometer's pixel pitch (um)
PAPER_PIXEL_PITCH_UM = 17.0
#: side of the working crop of the sensor (pixels; the crop is square)
PAPER_CROP_PX = 290
#: the sensor's frame rate (Hz)
PAPER_FRAME_RATE_HZ = 12.0
#: the spectral band without a filter (um)
PAPER_BAND_UM = (8.0, 14.0)
#: magnification of the selected relay
PAPER_RELAY_MAGNIFICATION = 0.5
#: lens-to-sensor distances of the (foveal, perifoveal) channels (um): their focal lengths
PAPER_LENS_TO_SENSOR_UM = (150.0 * UM_PER_MM, 25.0 * UM_PER_MM)


# ----------------------------------------------------------------------------------------------
# dataclasses
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlatformDesign:
    """Nanopost platform: square lattice of rectangular posts on a substrate.

    n_post / n_substrate / n_superstrate are refractive indices at the design wavelength.
    """

    period_um: float = PAPER_PERIOD_UM
    post_height_um: float = PAPER_POST_HEIGHT_UM
    post_material: str = "Si"
    n_post: float = N_SI_10UM
    n_substrate: float = N_SI_10UM
    n_superstrate: float = N_AIR
    substrate_thickness_um: float = 500.0
    min_feature_um: float = 0.5
    wavelength_um: float = PAPER_WAVELENGTH_UM
    min_gap_um: float | None = None  # smallest gap between neighbouring posts (default: min_feature_um)
    max_aspect_ratio: float = 20.0  # post height / smallest side: a typical limit of Bosch deep silicon etching
    edge_bias_um: float = 0.05  # +- edge bias per side the posts are chosen to tolerate (lithography + DRIE)
    substrate_resistivity_ohm_cm: float = 15.0  # the paper's 10-20 ohm cm wafers
    substrate_dopant: str = "p"  # boron (the common prime wafer; the paper does not say): 2.7x the electrons' loss
    substrate_extra_absorption_per_cm: float = 0.0  # measured lattice / oxygen absorption, added to free carriers
    wafer_diameter_mm: float = 100.0  # the wafer the lens is written on (layout: wafer outline, die frame)
    wafer_flat_mm: float | None = None  # primary flat length (default: SEMI M1 for the diameter; 0: none)
    wafer_edge_exclusion_mm: float = 3.0  # no die closer than this to the wafer's edge or flat
    write_bias_um: float = 0.0  # process pre-bias: added to each post edge when written (widths + 2 x bias)
    posts_resist_tone: str = "negative"  # exposure 1: polygons are the posts (resist stays where written)
    ring_resist_tone: str = "positive"  # exposure 2 (lift-off): polygons are the aluminium (resist opens)

    def __post_init__(self) -> None:
        check_positive("period_um", self.period_um, "um", hi=1e4)
        check_positive("post_height_um", self.post_height_um, "um", hi=1e4)
        check_range("n_post", self.n_post, 1.0, 10.0, lo_inclusive=True)
        check_range("n_substrate", self.n_substrate, 1.0, 10.0, lo_inclusive=True)
        check_range("n_superstrate", self.n_superstrate, 1.0, 10.0, lo_inclusive=True)
        check_positive("substrate_thickness_um", self.substrate_thickness_um, "um")
        check_range("min_feature_um", self.min_feature_um, 0.0, self.period_um, hi_inclusive=False)
        check_positive("wavelength_um", self.wavelength_um, "um", hi=1e4)
        if self.min_gap_um is not None:
            check_range("min_gap_um", self.min_gap_um, 0.0, self.period_um, hi_inclusive=False, lo_inclusive=True)
        check_positive("max_aspect_ratio", self.max_aspect_ratio, hi=1e4)
        check_range("edge_bias_um", self.edge_bias_um, 0.0, self.period_um / 4, lo_inclusive=True, unit="um")
        check_positive("substrate_resistivity_ohm_cm", self.substrate_resistivity_ohm_cm, "ohm cm", hi=1e6)
        check_choice("substrate_dopant", self.substrate_dopant, ("n", "p"))
        check_range("substrate_extra_absorption_per_cm", self.substrate_extra_absorption_per_cm, 0.0, 1e3,
                    unit="1/cm", lo_inclusive=True)
        check_range("wafer_diameter_mm", self.wafer_diameter_mm, 1.0, 1000.0, unit="mm", lo_inclusive=True)
        if self.wafer_flat_mm is not None:
            check_range("wafer_flat_mm", self.wafer_flat_mm, 0.0, self.wafer_diameter_mm, unit="mm", lo_inclusive=True)
        check_range("wafer_edge_exclusion_mm", self.wafer_edge_exclusion_mm, 0.0, self.wafer_diameter_mm / 4,
                    unit="mm", lo_inclusive=True)
        check_range("write_bias_um", self.write_bias_um, -self.period_um / 4, self.period_um / 4, unit="um",
                    lo_inclusive=True, hi_inclusive=True)
        check_choice("posts_resist_tone", self.posts_resist_tone, ("negative", "positive"))
        check_choice("ring_resist_tone", self.ring_resist_tone, ("negative", "positive"))

    def fabrication_violations(self, widths_um: ArrayLike, height_um: float | None = None) -> list[str]:
        """The fabrication rules (``min_feature_um``, ``min_gap_um``, ``max_aspect_ratio``) that posts of
        ``widths_um`` ``(N, 2)`` break, one sentence each naming the post, the value and the rule."""
        w = np.asarray(widths_um, dtype=float).reshape(-1, 2)
        h = self.post_height_um if height_um is None else float(height_um)
        gap_min = self.min_feature_um if self.min_gap_um is None else self.min_gap_um
        out = []
        for k, (wx, wy) in enumerate(w):
            side = min(wx, wy)
            if side < self.min_feature_um - 1e-9:
                out.append(f"post {k}: side {side:.3f} um below min_feature_um = {self.min_feature_um:g} um")
            gap = self.period_um - max(wx, wy)
            if gap < gap_min - 1e-9:
                out.append(f"post {k}: gap {gap:.3f} um below min_gap_um = {gap_min:g} um")
            if h / side > self.max_aspect_ratio + 1e-9:
                out.append(f"post {k}: aspect ratio {h / side:.1f} (height {h:g} um / side {side:.3f} um) above "
                           f"max_aspect_ratio = {self.max_aspect_ratio:g}")
        return out


#: the most coefficients ``LensDesign.phase_poly_rad`` may hold (terms up to (rho / R)^32): more than any smooth
#: radial correction of a lens needs, and few enough that the polynomial stays well conditioned in float64
MAX_PHASE_POLY_TERMS = 16


def check_phase_poly(key: str, value: Any, source: str | None = None) -> tuple[float, ...]:
    """``phase_poly_rad`` as a tuple of finite floats (rad), at most :data:`MAX_PHASE_POLY_TERMS` of them."""
    allowed = (f"a list of at most {MAX_PHASE_POLY_TERMS} finite numbers (rad): a_j of sum_j a_j (rho / R)^(2 j) "
               "added to the hyperbolic phase")
    if isinstance(value, (str, bytes, dict)) or not isinstance(value, (list, tuple, np.ndarray)):
        raise InputError(key, value, allowed, source)
    vals = list(np.asarray(value, dtype=object).reshape(-1)) if isinstance(value, np.ndarray) else list(value)
    if len(vals) > MAX_PHASE_POLY_TERMS:
        raise InputError(key, f"{len(vals)} coefficients", allowed, source)
    out = []
    for v in vals:
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(v):
            raise InputError(key, value if len(vals) < 10 else f"{len(vals)} coefficients", allowed, source)
        out.append(float(v))
    return tuple(out)


@dataclass(frozen=True)
class LensDesign:
    """One metalens: hyperbolic phase (plus an optional radial polynomial), square lattice, N phase levels, acting
    on one polarisation.

    ``phase_poly_rad`` (rad, at the design wavelength): coefficients ``a_j`` of the phase added to the hyperbola,
    ``phi(rho) = hyperbolic_phase(rho) + sum_{j=1..n} a_j (rho / R)^(2 j)`` with ``R = diameter_um / 2``
    (:func:`metafovea.lens.design_phase`); added as is, whatever ``phase_sign``. Like the hyperbola it is a
    structural phase: the focusing order carries ``exp(i phi)`` at every wavelength. The empty tuple (default) is the
    plain hyperbola.
    """

    name: str
    f_um: float
    diameter_um: float
    wavelength_um: float = PAPER_WAVELENGTH_UM
    polarization: str = "x"
    period_um: float = PAPER_PERIOD_UM
    post_height_um: float = PAPER_POST_HEIGHT_UM
    levels: int = 8
    phase_sign: int = PHASE_SIGN
    lattice: str = "integer"  # sites at integer multiples of the period ('integer') or half-integer ('half')
    n_substrate: float = N_SI_10UM
    phase_poly_rad: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        check_name("name", self.name)
        object.__setattr__(self, "phase_poly_rad", check_phase_poly("phase_poly_rad", self.phase_poly_rad))
        validate_lens_numbers(self.f_um, self.diameter_um, self.wavelength_um, self.period_um,
                              self.levels, self.polarization)
        check_positive("post_height_um", self.post_height_um, "um")
        if self.phase_sign not in (-1, 1):
            raise InputError("phase_sign", self.phase_sign, "-1 (focusing under exp(-i omega t)) or +1")
        check_choice("lattice", self.lattice, LATTICES)
        check_range("n_substrate", self.n_substrate, 1.0, 10.0, lo_inclusive=True)

    # convenience -------------------------------------------------------------------------
    @property
    def f_mm(self) -> float:
        return self.f_um / UM_PER_MM

    @property
    def diameter_mm(self) -> float:
        return self.diameter_um / UM_PER_MM

    @property
    def radius_um(self) -> float:
        return 0.5 * self.diameter_um

    @property
    def na(self) -> float:
        r = self.radius_um
        return r / math.hypot(r, self.f_um)

    def with_(self, **kw: Any) -> LensDesign:
        return replace(self, **kw)

    def plot(self, ax: Axes | Sequence[Axes] | None = None) -> Figure:
        """Posts per 2 pi zone against radius (mm) and the phase levels of a patch of posts at the rim.

        Parameters
        ----------
        ax : matplotlib Axes, sequence of 2 Axes, or None
            None: a new figure with both panels; one Axes: the posts-per-zone curve only.

        Returns
        -------
        matplotlib Figure
        """
        from metafovea.plotting import plot_lens

        return plot_lens(self, ax)

    def _repr_html_(self) -> str:
        from metafovea.plotting import lens_html

        return lens_html(self)

    @classmethod
    def foveal(cls, platform: PlatformDesign | None = None) -> LensDesign:
        p = platform or PlatformDesign()
        return cls("foveal", 150.0 * UM_PER_MM, 75.0 * UM_PER_MM, p.wavelength_um, "x", p.period_um,
                   p.post_height_um, 8, n_substrate=p.n_substrate)

    @classmethod
    def perifoveal(cls, platform: PlatformDesign | None = None) -> LensDesign:
        p = platform or PlatformDesign()
        return cls("perifoveal", 25.0 * UM_PER_MM, 25.0 * UM_PER_MM, p.wavelength_um, "y", p.period_um,
                   p.post_height_um, 8, n_substrate=p.n_substrate)


def check_name(key: str, value: Any, source: str | None = None) -> str:
    """A lens name becomes part of file, folder and layout-cell names: 1-64 printable characters, no path
    separators, not '.' or '..', no leading or trailing space (stages sanitise further where a format needs)."""
    ok = (isinstance(value, str) and 0 < len(value) <= 64 and value.isprintable() and value == value.strip()
          and "/" not in value and "\\" not in value and value not in (".", ".."))
    if not ok:
        raise InputError(key, value, "1-64 printable characters without '/' or '\\', not '.' or '..', no leading or "
                                     "trailing spaces (it names files and layout cells)", source)
    return value


#: the finest lattice period a design may have (10 nm: below any lithography's resolution)
MIN_PERIOD_UM = 0.01
#: the most lattice rows (D / period) a lens may span: the exact post count walks the rows in Python, measured
#: 0.7 us per row on one core (the paper's foveal lens: 18,750 rows, 13 ms), so this takes ~6 s and 200 MiB
MAX_LATTICE_ROWS = 1 << 23
#: seconds and bytes per lattice row of the exact post count (measured, rounded up), for the refusal's estimate
ROW_SECONDS, ROW_BYTES = 1e-6, 24


def check_lattice_rows(d_um: float, period_um: float, d_name: str = "diameter_um", period_name: str = "period_um",
                       source: str | None = None) -> int:
    """Refuse, before any work, a lens of more than :data:`MAX_LATTICE_ROWS` lattice rows (``D / period``); the
    error names the diameter, or the period when the lens would fit at the platform's 4 um period."""
    rows = d_um / period_um
    if rows <= MAX_LATTICE_ROWS:
        return int(rows)
    from metafovea.errors import human_bytes

    blame_d = d_um / PAPER_PERIOD_UM > MAX_LATTICE_ROWS
    name = d_name if blame_d else period_name
    in_mm = not name.endswith("_um") and blame_d  # a CLI flag (--d) is in mm
    value = d_um / UM_PER_MM if in_mm else (d_um if blame_d else period_um)
    secs = rows * ROW_SECONDS
    took = f"{secs / 3600:.3g} hours" if secs >= 3600 else f"{secs:.3g} s"
    detail = (f"the lens would span {rows:.3g} lattice rows, ~{math.pi / 4 * rows * rows:.2g} posts: "
              f"~{human_bytes(rows * ROW_BYTES)} of memory and {took} only to count them, and no layout or PSF of it "
              "could be made; the paper's 75 mm lens spans 18,750 rows")
    allowed = (f"at most {MAX_LATTICE_ROWS:,} lattice rows (D / period): D <= {MAX_LATTICE_ROWS * period_um / 1e6:.3g} "
               f"m at period {period_um:g} um" if blame_d else
               f"period >= {d_um / MAX_LATTICE_ROWS:.3g} um for D = {d_um / UM_PER_MM:g} mm (at most "
               f"{MAX_LATTICE_ROWS:,} lattice rows)")
    raise InputError(name, value, allowed, source, detail=detail)


def validate_lens_numbers(f_um: Any, diameter_um: Any, wavelength_um: Any, period_um: Any, levels: Any,
                          polarization: Any, source: str | None = None,
                          names: tuple[str, ...] = ("f_um", "diameter_um", "wavelength_um", "period_um",
                                                    "levels", "polarization")) -> None:
    """Shared checks for lens parameters (used by the dataclass and the CLI with its own names)."""
    f = check_positive(names[0], f_um, source=source)
    d = check_positive(names[1], diameter_um, source=source)
    check_positive(names[2], wavelength_um, "um", source=source, hi=1e4)
    p = check_positive(names[3], period_um, "um", source=source, hi=1e4)
    if p < MIN_PERIOD_UM:
        raise InputError(names[3], period_um, f"{MIN_PERIOD_UM:g} um <= {names[3]} <= 10000 um", source,
                         detail="a lattice of posts finer than 10 nm cannot be written: below e-beam resolution, "
                                "the layout grid is 5 nm")
    check_int(names[4], levels, 2, 256, source=source)
    check_choice(names[5], polarization, POLARIZATIONS, source=source)
    check_lattice_rows(d, p, names[1], names[3], source)
    na = (d / 2) / math.hypot(d / 2, f)
    if not na < 1.0:  # only reachable through rounding for absurd D/f ratios
        raise InputError("NA", na, "NA < 1 (D/2 / sqrt((D/2)^2 + f^2))", source)


@dataclass(frozen=True)
class SensorDesign:
    pixel_pitch_um: float = PAPER_PIXEL_PITCH_UM
    pitch_variants_um: tuple[float, ...] = (PAPER_PIXEL_PITCH_UM, 24.0)
    pixels: tuple[int, int] = (480, 640)  # (H, W)
    crop: tuple[int, int] = (PAPER_CROP_PX, PAPER_CROP_PX)  # working crop (H, W)
    frame_rate_hz: float = PAPER_FRAME_RATE_HZ
    netd_k: float = 0.05
    fpn_rank: int = 20
    fpn_amplitude: float = 0.1  # bound on the FPN term, fraction of the scene's dynamic range
    adc_bits: int = 14


@dataclass(frozen=True)
class SystemDesign:
    """The paper's two-channel camera.

    lens_to_sensor_um: (foveal, perifoveal) distances f1, f2 (um). relay_magnification: the selected
    relay (variants listed). polarizer_hz: rotation rate of the polariser (alpha_t = cos^2 theta_t
    repeats at twice this rate). band_um: spectral band without filter; filter_* a narrow-band filter.
    """

    foveal: LensDesign = field(default_factory=LensDesign.foveal)
    perifoveal: LensDesign = field(default_factory=LensDesign.perifoveal)
    platform: PlatformDesign = field(default_factory=PlatformDesign)
    lens_to_sensor_um: tuple[float, float] = PAPER_LENS_TO_SENSOR_UM
    relay_magnification: float = PAPER_RELAY_MAGNIFICATION
    relay_variants: tuple[float, ...] = (PAPER_RELAY_MAGNIFICATION, 0.3)
    polarizer_hz: float = 2.0
    polarizer_extinction: float = 0.0  # leaked fraction of the blocked polarisation (0 = ideal)
    sensor: SensorDesign = field(default_factory=SensorDesign)
    band_um: tuple[float, float] = PAPER_BAND_UM
    filter_enabled: bool = False
    filter_center_um: float = PAPER_WAVELENGTH_UM
    filter_bandwidth_um: float = 0.5
    scene_temperature_k: float = 300.0

    @property
    def expansion(self) -> float:
        """Field-of-view ratio of the two channels (f1 / f2; 6 for the paper)."""
        return self.lens_to_sensor_um[0] / self.lens_to_sensor_um[1]

    @classmethod
    def paper(cls) -> SystemDesign:
        return cls()


# ----------------------------------------------------------------------------------------------
# TOML loading
# ----------------------------------------------------------------------------------------------
def _read_toml(path: str | Path) -> dict[str, Any]:
    p = Path(path)
    if not p.is_file():
        raise InputError("design file", str(p), "an existing TOML file")
    try:
        with open(p, "rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as e:
        raise InputError("design file", str(p), "valid TOML", detail=str(e)) from None
    except UnicodeDecodeError:
        raise InputError("design file", str(p), "a UTF-8 TOML text file") from None


class _Reader:
    """Pulls keys out of a TOML table, validating each and remembering which were used."""

    def __init__(self, table: dict[str, Any], source: str, prefix: str = ""):
        self.t, self.src, self.prefix, self.used = table, source, prefix, set()

    def _key(self, k: str) -> str:
        return f"{self.prefix}{k}"

    def get(self, key: str, default: Any, check: Callable[[str, Any], Any]) -> Any:
        self.used.add(key)
        if key not in self.t:
            if default is _REQUIRED:
                raise InputError(self._key(key), "<missing>", "a value must be given", self.src)
            return default
        return check(self._key(key), self.t[key])

    def _unquoted(self, k: str, v: Any) -> Any:
        """``v`` unless it is a string: a TOML number is written without quotes (``"0.05"`` is text, which the
        checks below would otherwise read as a number, as they do a command-line flag)."""
        if isinstance(v, str):
            raise InputError(k, v, "a number (TOML: without quotes)", self.src)
        return v

    def num(self, key: str, default: Any, lo: float | None = 0.0, hi: float | None = None,
            unit: str = "", lo_inclusive: bool = False) -> float:
        return self.get(key, default, lambda k, v: check_range(k, self._unquoted(k, v), lo, hi, unit=unit,
                                                              source=self.src, lo_inclusive=lo_inclusive))

    def int(self, key: str, default: Any, lo: int, hi: int) -> int:
        return self.get(key, default, lambda k, v: check_int(k, self._unquoted(k, v), lo, hi, source=self.src))

    def choice(self, key: str, default: Any, choices: tuple[str, ...]) -> str:
        return self.get(key, default, lambda k, v: check_choice(k, v, choices, source=self.src))

    def boolean(self, key: str, default: bool) -> bool:
        def chk(k: str, v: Any) -> bool:
            if not isinstance(v, bool):
                raise InputError(k, v, "true or false", self.src)
            return v
        return self.get(key, default, chk)

    def text(self, key: str, default: Any) -> str:
        def chk(k: str, v: Any) -> str:
            if not isinstance(v, str) or not v.strip():
                raise InputError(k, v, "a non-empty string", self.src)
            return v
        return self.get(key, default, chk)

    def nums(self, key: str, default: Any, n: int | None, lo: float = 0.0, hi: float | None = None,
             integer: bool = False) -> tuple:
        def chk(k: str, v: Any) -> tuple:
            if not isinstance(v, list) or (n is not None and len(v) != n) or not v:
                raise InputError(k, v, f"a list of {n if n else 'one or more'} numbers", self.src)
            if integer:
                return tuple(check_int(k, self._unquoted(k, x), int(lo) + 1, None if hi is None else int(hi), self.src)
                             for x in v)
            return tuple(check_range(k, self._unquoted(k, x), lo, hi, source=self.src) for x in v)
        return self.get(key, default, chk)

    def table(self, key: str) -> _Reader:
        self.used.add(key)
        v = self.t.get(key, {})
        if not isinstance(v, dict):
            raise InputError(self._key(key), v, "a TOML table [" + key + "]", self.src)
        return _Reader(v, self.src, f"{self.prefix}{key}.")

    def done(self) -> None:
        extra = sorted(set(self.t) - self.used)
        if extra:
            raise InputError(self._key(extra[0]), self.t[extra[0]],
                             "one of the known keys: " + ", ".join(sorted(self.used)), self.src)


_REQUIRED = object()


def load_platform(path: str | Path) -> PlatformDesign:
    """Load ``platform.toml``."""
    t = _read_toml(path)
    if not t:  # every key has a default: an empty file would pass as the paper's platform
        raise InputError("platform file", str(path), "a platform TOML holding its keys (period_um, height_um, ...): "
                         "this one is empty (no file at all uses the paper's platform)")
    r = _Reader(t, str(path))
    d = PlatformDesign()
    r.text("name", "platform")
    period = r.num("period_um", d.period_um, hi=1e4, unit="um")
    out = PlatformDesign(
        period_um=period,
        post_height_um=r.num("post_height_um", d.post_height_um, hi=1e4, unit="um"),
        post_material=r.text("post_material", d.post_material),
        n_post=r.num("n_post", d.n_post, 1.0, 10.0, lo_inclusive=True),
        n_substrate=r.num("n_substrate", d.n_substrate, 1.0, 10.0, lo_inclusive=True),
        n_superstrate=r.num("n_superstrate", d.n_superstrate, 1.0, 10.0, lo_inclusive=True),
        substrate_thickness_um=r.num("substrate_thickness_um", d.substrate_thickness_um, unit="um"),
        min_feature_um=r.num("min_feature_um", d.min_feature_um, 0.0, period, unit="um"),
        wavelength_um=r.num("wavelength_um", d.wavelength_um, hi=1e4, unit="um"),
        min_gap_um=r.get("min_gap_um", None, lambda k, v: check_range(k, v, 0.0, period, hi_inclusive=False,
                                                                     lo_inclusive=True, unit="um", source=str(path))),
        max_aspect_ratio=r.num("max_aspect_ratio", d.max_aspect_ratio, hi=1e4),
        edge_bias_um=r.num("edge_bias_um", d.edge_bias_um, 0.0, period / 4, unit="um", lo_inclusive=True),
        substrate_resistivity_ohm_cm=r.num("substrate_resistivity_ohm_cm", d.substrate_resistivity_ohm_cm, hi=1e6,
                                           unit="ohm cm"),
        substrate_dopant=r.choice("substrate_dopant", d.substrate_dopant, ("n", "p")),
        substrate_extra_absorption_per_cm=r.num("substrate_extra_absorption_per_cm",
                                                d.substrate_extra_absorption_per_cm, 0.0, 1e3, unit="1/cm",
                                                lo_inclusive=True),
        wafer_diameter_mm=r.num("wafer_diameter_mm", d.wafer_diameter_mm, 1.0, 1000.0, unit="mm", lo_inclusive=True),
        wafer_flat_mm=r.get("wafer_flat_mm", None, lambda k, v: check_range(k, v, 0.0, 1000.0, unit="mm",
                                                                         lo_inclusive=True, source=str(path))),
        wafer_edge_exclusion_mm=r.num("wafer_edge_exclusion_mm", d.wafer_edge_exclusion_mm, 0.0, 250.0, unit="mm",
                                      lo_inclusive=True),
        write_bias_um=r.num("write_bias_um", d.write_bias_um, -period / 4, period / 4, unit="um", lo_inclusive=True),
        posts_resist_tone=r.choice("posts_resist_tone", d.posts_resist_tone, ("negative", "positive")),
        ring_resist_tone=r.choice("ring_resist_tone", d.ring_resist_tone, ("negative", "positive")),
    )
    r.done()
    return out


def load_lens(path: str | Path, platform: PlatformDesign | None = None) -> LensDesign:
    """Load a lens TOML (``foveal.toml``/``perifoveal.toml``).

    Keys: name, f_mm, diameter_mm, wavelength_um, polarization ('x'|'y'), levels, lattice, and
    optionally period_um / post_height_um (default: the platform's) and phase_poly_rad (a list of radians: the
    phase added to the hyperbola, :class:`LensDesign`; default none).
    """
    t = _read_toml(path)
    src = str(path)
    r = _Reader(t, src)
    p = platform or PlatformDesign()
    name = r.get("name", Path(path).stem, lambda k, v: check_name(k, v, src))
    f_mm = r.num("f_mm", _REQUIRED, unit="mm")
    d_mm = r.num("diameter_mm", _REQUIRED, unit="mm")
    wl = r.num("wavelength_um", p.wavelength_um, hi=1e4, unit="um")
    pol = r.choice("polarization", _REQUIRED, POLARIZATIONS)
    period = r.num("period_um", p.period_um, hi=1e4, unit="um")
    height = r.num("post_height_um", p.post_height_um, hi=1e4, unit="um")
    levels = r.int("levels", 8, 2, 256)
    lattice = r.choice("lattice", "integer", LATTICES)
    poly = r.get("phase_poly_rad", (), lambda k, v: check_phase_poly(k, v, src))
    r.done()
    validate_lens_numbers(f_mm, d_mm, wl, period, levels, pol, source=src,
                          names=("f_mm", "diameter_mm", "wavelength_um", "period_um", "levels", "polarization"))
    return LensDesign(name, f_mm * UM_PER_MM, d_mm * UM_PER_MM, wl, pol, period, height, levels,
                      lattice=lattice, n_substrate=p.n_substrate, phase_poly_rad=poly)


#: the top-level keys of a system file (:func:`load_system`)
SYSTEM_SECTIONS = ("name", "files", "distances", "relay", "polarizer", "sensor", "spectral")


def load_system(path: str | Path) -> SystemDesign:
    """Load ``system.toml``; lens and platform files are resolved relative to it.

    Parameters
    ----------
    path : str or Path
        A system design file (``designs/system.toml``): ``[files]`` names the platform and both lenses' files,
        ``[distances]`` (mm), ``[relay]``, ``[polarizer]``, ``[sensor]`` and ``[spectral]`` (um, K) the camera.

    Returns
    -------
    SystemDesign
        Lengths in um. Every value is checked; an :class:`InputError` names the file, the key, the value and the
        allowed range (unknown keys are refused with the list of known ones).
    """
    path = Path(path)
    t = _read_toml(path)
    src = str(path)
    if not t:  # every key has a default, so an empty file (a failed save, the wrong file) would pass as the paper's
        raise InputError("system file", src, "a system TOML holding its keys ([files], [sensor], ...): this one is "
                         "empty (no file at all runs the paper's prototype)")
    r = _Reader(t, src)
    foreign = sorted(set(t) - set(SYSTEM_SECTIONS))
    if foreign:  # a lens or platform file given as the system: said before its default [files] are looked for
        raise InputError(foreign[0], t[foreign[0]], "one of the system file's keys: " + ", ".join(SYSTEM_SECTIONS)
                         + " (is this a lens or platform file? a system file names them in [files])", src)
    r.text("name", "system")
    files = r.table("files")
    base = path.parent
    plat_file = files.text("platform", "platform.toml")
    fov_file = files.text("foveal", "foveal.toml")
    per_file = files.text("perifoveal", "perifoveal.toml")
    files.done()
    platform = load_platform(base / plat_file)
    foveal = load_lens(base / fov_file, platform)
    perifoveal = load_lens(base / per_file, platform)
    if foveal.polarization == perifoveal.polarization:
        raise InputError("files.perifoveal", per_file,
                         f"a lens acting on the other polarisation than the foveal lens ('{foveal.polarization}')",
                         src)
    dd = SystemDesign()
    dist = r.table("distances")
    f1 = dist.num("foveal_lens_to_sensor_mm", dd.lens_to_sensor_um[0] / UM_PER_MM, unit="mm")
    f2 = dist.num("perifoveal_lens_to_sensor_mm", dd.lens_to_sensor_um[1] / UM_PER_MM, unit="mm")
    dist.done()
    relay = r.table("relay")
    variants = relay.nums("variants", dd.relay_variants, None, 0.0, 10.0)
    mag = relay.num("magnification", dd.relay_magnification, 0.0, 10.0)
    relay.done()
    pol = r.table("polarizer")
    hz = pol.num("rotation_hz", dd.polarizer_hz, 0.0, 1000.0)
    ext = pol.num("extinction_leak", dd.polarizer_extinction, 0.0, 0.5, lo_inclusive=True)
    pol.done()
    s = r.table("sensor")
    ds = dd.sensor
    pitch = s.num("pixel_pitch_um", ds.pixel_pitch_um, 0.0, 1000.0, unit="um")
    sensor = SensorDesign(
        pixel_pitch_um=pitch,
        pitch_variants_um=s.nums("pitch_variants_um", ds.pitch_variants_um, None, 0.0, 1000.0),
        pixels=s.nums("pixels", ds.pixels, 2, 0, 100000, integer=True),
        crop=s.nums("crop", ds.crop, 2, 7, 8192, integer=True),  # 8..8192: imaging.sensor.SensorModel's range
        frame_rate_hz=s.num("frame_rate_hz", ds.frame_rate_hz, 0.0, 1e5),
        netd_k=s.num("netd_k", ds.netd_k, 0.0, 10.0, lo_inclusive=True),
        fpn_rank=s.int("fpn_rank", ds.fpn_rank, 0, 1000),
        fpn_amplitude=s.num("fpn_amplitude", ds.fpn_amplitude, 0.0, 1.0, lo_inclusive=True),
        adc_bits=s.int("adc_bits", ds.adc_bits, 1, 32),
    )
    s.done()
    if sensor.crop[0] > sensor.pixels[0] or sensor.crop[1] > sensor.pixels[1]:
        raise InputError("sensor.crop", list(sensor.crop), f"at most sensor.pixels = {list(sensor.pixels)}", src)
    sp = r.table("spectral")
    band = sp.nums("band_um", dd.band_um, 2, 0.0, 1e4)
    if not band[0] < band[1]:
        raise InputError("spectral.band_um", list(band), "[low, high] with low < high", src)
    fe = sp.boolean("filter_enabled", dd.filter_enabled)
    fc = sp.num("filter_center_um", dd.filter_center_um, 0.0, 1e4, unit="um")
    fb = sp.num("filter_bandwidth_um", dd.filter_bandwidth_um, 0.0, 1e4, unit="um")
    temp = sp.num("scene_temperature_k", dd.scene_temperature_k, 0.0, 1e4, unit="K")
    sp.done()
    r.done()
    return SystemDesign(foveal, perifoveal, platform, (f1 * UM_PER_MM, f2 * UM_PER_MM), mag, variants, hz, ext,
                        sensor, band, fe, fc, fb, temp)


def load_design(path: str | Path) -> LensDesign | SystemDesign | PlatformDesign:
    """Load any design file, deciding by its content (``[files]`` -> system, ``f_mm`` -> lens)."""
    t = _read_toml(path)
    if "files" in t:
        return load_system(path)
    if "f_mm" in t:
        plat = Path(path).parent / "platform.toml"
        return load_lens(path, load_platform(plat) if plat.is_file() else None)
    if "period_um" in t or "post_height_um" in t:
        return load_platform(path)
    raise InputError("design file", str(path), "a lens (f_mm, diameter_mm, ...), platform or system ([files]) TOML")



# ----------------------------------------------------------------------------------------------
# TOML writing (the loaders' inverse: load_system(written) == the design)
# ----------------------------------------------------------------------------------------------
def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, (tuple, list)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"no TOML form for {type(v).__name__}")


def platform_toml(platform: PlatformDesign, name: str = "platform") -> str:
    """The text of a ``platform.toml`` that :func:`load_platform` reads back as ``platform`` (unset options, such as
    ``min_gap_um = None``, are left out: the loader's defaults)."""
    lines = [f"name = {_toml_value(name)}"]
    for f in fields(platform):
        v = getattr(platform, f.name)
        if v is not None:
            lines.append(f"{f.name} = {_toml_value(v)}")
    return "\n".join(lines) + "\n"


def system_toml(system: SystemDesign, *, platform_file: str = "platform.toml", foveal_file: str = "foveal.toml",
                perifoveal_file: str = "perifoveal.toml", name: str = "system") -> str:
    """The text of a ``system.toml`` naming the given platform and lens files (relative to it), with every camera
    value of ``system``: :func:`load_system` of it (with those files) returns ``system``."""
    s, d = system.sensor, system.lens_to_sensor_um
    tables = {
        "files": {"platform": platform_file, "foveal": foveal_file, "perifoveal": perifoveal_file},
        "distances": {"foveal_lens_to_sensor_mm": d[0] / UM_PER_MM, "perifoveal_lens_to_sensor_mm": d[1] / UM_PER_MM},
        "relay": {"magnification": system.relay_magnification, "variants": system.relay_variants},
        "polarizer": {"rotation_hz": system.polarizer_hz, "extinction_leak": system.polarizer_extinction},
        "sensor": {"pixel_pitch_um": s.pixel_pitch_um, "pitch_variants_um": s.pitch_variants_um, "pixels": s.pixels,
                   "crop": s.crop, "frame_rate_hz": s.frame_rate_hz, "netd_k": s.netd_k, "fpn_rank": s.fpn_rank,
                   "fpn_amplitude": s.fpn_amplitude, "adc_bits": s.adc_bits},
        "spectral": {"band_um": system.band_um, "filter_enabled": system.filter_enabled,
                     "filter_center_um": system.filter_center_um, "filter_bandwidth_um": system.filter_bandwidth_um,
                     "scene_temperature_k": system.scene_temperature_k},
    }
    lines = [f"name = {_toml_value(name)}"]
    for table, kv in tables.items():
        lines += ["", f"[{table}]"] + [f"{k} = {_toml_value(v)}" for k, v in kv.items()]
    return "\n".join(lines) + "\n"

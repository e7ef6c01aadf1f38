"""Scenes: temperature (K) and emissivity fields over field angle and time.

A scene is a function of the field angles ``(ax, ay)`` in radians and the time ``t`` in seconds:
``ax`` grows to the right, ``ay`` grows *downward* (image rows), ``(0, 0)`` is the optical axis. The
camera maps a pixel at focal-plane position ``(x, y)`` of a lens with focal length ``f`` to
``(atan(x / f), atan(y / f))``, so the same scene is seen by both channels, the foveal one 6x
magnified. Scenes are *not* rasters: :meth:`Scene.sample` is evaluated on each channel's own
(super-sampled) pixel grid, so a scene is sampled only as finely as each channel needs (the Siemens
star's spokes are exact at the foveal channel's 0.23 mrad pixels without a 1740 x 1740 raster).
Image scenes (scikit-image's bundled pictures, user files) are rasters interpolated bilinearly: their
detail is limited by the picture's own resolution.

Every scene also returns an emissivity per region; the radiometry adds the reflected surroundings,
``eps L(T) + (1 - eps) L(T_refl)`` with the scene's ``reflected_k`` (sky for outdoor scenes).

Built-in scenes (``make_scene(name)``, ``list_scenes()``): natural images from scikit-image mapped to
temperatures, ``siemens-star``, ``bars``, ``hand``, ``parking-lot``, ``heater-5s``/``-10s``/``-20s``,
``uniform``, ``rooftop``, ``tall-buildings``, ``oven``; and generated held-out scenes ``gen:KIND:SEED``
(:mod:`metafovea.imaging.generator`, a family registered in :data:`SCENE_FAMILIES`).
Any name that is an existing file loads it (``.npy``/``.npz`` temperatures in K,
``.tif``/``.png``/``.jpg`` pictures mapped to temperatures, see :func:`load_scene_file`); so does an array of
temperatures. A file or array of temperatures is one channel in kelvin: a colour (RGB) or multi-channel image is
refused, and so is one whose hottest value is below :data:`MIN_HOTTEST_K` (no thermal scene in kelvin: values of
20-35 are degrees Celsius, which ``scene_unit='celsius'`` converts, +273.15 K, saying so in the scene's summary).
"""

from __future__ import annotations

import abc
import logging
import math
import warnings
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.config import (
    PAPER_CROP_PX,
    PAPER_FRAME_RATE_HZ,
    PAPER_LENS_TO_SENSOR_UM,
    PAPER_PIXEL_PITCH_UM,
    PAPER_RELAY_MAGNIFICATION,
)
from metafovea.errors import InputError, check_positive, check_range
from metafovea.radiometry import T_MAX_K

log = logging.getLogger(__name__)

#: Perifoveal full field of view of the paper's camera (rad): 290 px x 17 um / 0.5 relay / 25 mm.
PAPER_FOV_RAD = 2 * math.atan(PAPER_CROP_PX / 2 * PAPER_PIXEL_PITCH_UM / PAPER_RELAY_MAGNIFICATION
                              / PAPER_LENS_TO_SENSOR_UM[1])
AMBIENT_K = 294.0
#: the units a file or array of temperatures may be given in (``scene_unit``); kelvin is the default
SCENE_UNITS = ("kelvin", "celsius")
#: 0 degrees Celsius in kelvin: ``scene_unit='celsius'`` adds it
ZERO_CELSIUS_K = 273.15
#: the hottest value a temperature scene in kelvin reaches at least. Everything a camera on the ground looks at is
#: warmer than the clear sky, whose 8-14 um brightness temperature is 200-250 K (at 200 K the band radiance is
#: 11 % of 300 K's): a raster whose hottest pixel is colder is not kelvin (values of 20-35 are degrees Celsius,
#: values in 0-1 a picture's levels). Values in kelvin are not otherwise bounded: a liquid-nitrogen target (77 K)
#: in a room is a scene.
MIN_HOTTEST_K = 200.0
#: a colder value in a scene that passes :data:`MIN_HOTTEST_K` is warned about: colder than any sky, it is what
#: degrees Celsius read as kelvin look like when the scene also holds something above 200 degrees Celsius (or a
#: cryogenic target, which the warning names)
COLDEST_PLAUSIBLE_K = 150.0


@dataclass(frozen=True)
class SceneGeometry:
    """Field of view hints a scene uses to lay itself out (radians, full widths)."""

    fov_rad: float = PAPER_FOV_RAD  # perifoveal (wide) channel
    expansion: float = PAPER_LENS_TO_SENSOR_UM[0] / PAPER_LENS_TO_SENSOR_UM[1]  # f1 / f2: foveal field fov_rad / this
    duration_s: float = 8.0  # length of the recording (for videos that should fit in it)

    @property
    def half(self) -> float:
        return 0.5 * self.fov_rad

    @property
    def fovea_half(self) -> float:
        return 0.5 * self.fov_rad / self.expansion


class Scene(abc.ABC):
    """Base class. Subclasses implement :meth:`_sample` returning ``(temperature_k, emissivity)``."""

    name: str = "scene"
    static: bool = True
    reflected_k: float = AMBIENT_K
    description: str = ""

    def sample(self, ax: np.ndarray, ay: np.ndarray, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Temperature (K) and emissivity at field angles ``ax, ay`` (radians, same shape) at time ``t``."""
        ax = np.asarray(ax, dtype=np.float64)
        ay = np.asarray(ay, dtype=np.float64)
        temp, eps = self._sample(ax, ay, float(t))
        temp = np.broadcast_to(np.asarray(temp, dtype=np.float64), ax.shape)
        eps = np.broadcast_to(np.asarray(eps, dtype=np.float64), ax.shape)
        lo = float(np.min(temp)) if temp.size else 0.0
        if not np.isfinite(lo) or lo < 0.0 or not np.all(np.isfinite(temp)):
            raise InputError(f"scene '{self.name}' temperature", lo, "finite temperatures >= 0 K")
        if eps.size and not (np.all(np.isfinite(eps)) and float(np.min(eps)) >= 0.0 and float(np.max(eps)) <= 1.0):
            raise InputError(f"scene '{self.name}' emissivity", _worst(eps, 0.0, 1.0), "0 <= emissivity <= 1")
        return temp, eps

    @abc.abstractmethod
    def _sample(self, ax: np.ndarray, ay: np.ndarray, t: float) -> tuple[Any, Any]:
        """Temperature (K) and emissivity at the field angles; each scene implements it."""

    # Video scenes can declare what changes, so that a renderer re-renders only there: the static
    # background (``sample_background``) and the angular boxes that differ from it at time t
    # (``dynamic_regions``). ``None`` (the default) means "unknown: re-render everything".
    def dynamic_regions(self, t: float) -> list[tuple[float, float, float, float]] | None:
        """Boxes ``(x0, y0, x1, y1)`` (rad) outside which ``sample(..., t)`` equals the background."""
        return None

    def sample_background(self, ax: np.ndarray, ay: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The static part of a video scene (only meaningful when :meth:`dynamic_regions` is not None)."""
        return self.sample(ax, ay, 0.0)

    def summary(self) -> dict[str, Any]:
        return {"name": self.name, "static": self.static, "reflected_k": self.reflected_k,
                "description": self.description}


# ----------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------
def _worst(a: np.ndarray, lo: float, hi: float) -> float:
    """The most offending value of ``a`` for the range [lo, hi]: a non-finite one first (no NaN warnings)."""
    a = np.asarray(a, dtype=np.float64)
    bad = a[~np.isfinite(a)]
    if bad.size:
        return float(bad.flat[0])
    if a.size == 0:
        return float("nan")
    mn, mx = float(a.min()), float(a.max())
    return mn if mn < lo or mx <= hi else mx


def _paint(temp: np.ndarray, eps: np.ndarray, mask: np.ndarray, t_k: float, e: float) -> None:
    temp[mask] = t_k
    eps[mask] = e


def _capsule(ax: np.ndarray, ay: np.ndarray, p0: tuple[float, float], p1: tuple[float, float],
             r: float) -> np.ndarray:
    """Points within ``r`` of the segment p0-p1 (evaluated inside the capsule's bounding box only: a point outside
    it is farther than ``r`` from the segment)."""
    sel = _bbox_view(ax, ay, min(p0[0], p1[0]) - r, min(p0[1], p1[1]) - r, max(p0[0], p1[0]) + r,
                     max(p0[1], p1[1]) + r)
    out = np.zeros(np.shape(ax), dtype=bool)
    if not sel.any():
        return out
    bx, by = ax[sel], ay[sel]
    dx, dy = p1[0] - p0[0], p1[1] - p0[1]
    ll = dx * dx + dy * dy
    s = np.clip(((bx - p0[0]) * dx + (by - p0[1]) * dy) / max(ll, 1e-300), 0.0, 1.0)
    out[sel] = (bx - p0[0] - s * dx) ** 2 + (by - p0[1] - s * dy) ** 2 <= r * r
    return out


def _box(ax: np.ndarray, ay: np.ndarray, x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    return (ax >= x0) & (ax < x1) & (ay >= y0) & (ay < y1)


def _bbox_view(ax: np.ndarray, ay: np.ndarray, x0: float, y0: float, x1: float, y1: float):
    """Boolean mask of points inside a bounding box (to evaluate small objects only where they are)."""
    return (ax >= x0) & (ax <= x1) & (ay >= y0) & (ay <= y1)


# ----------------------------------------------------------------------------------------------
# analytic scenes
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class UniformScene(Scene):
    """A blackbody-like wall at one temperature (for tests and calibration)."""

    temperature_k: float = 300.0
    emissivity: float = 1.0
    name: str = "uniform"
    description: str = "uniform temperature"

    def __post_init__(self) -> None:
        check_range("temperature_k", self.temperature_k, 0.0, 3000.0, lo_inclusive=True, unit="K")
        check_range("emissivity", self.emissivity, 0.0, 1.0, lo_inclusive=True)

    def _sample(self, ax, ay, t):
        return np.full(ax.shape, self.temperature_k), np.full(ax.shape, self.emissivity)


@dataclass(frozen=True)
class SiemensStar(Scene):
    """The paper's wooden Siemens-star cut-out in front of a sheet of heated paper.

    Spokes are wood near room temperature; between them the heated paper shows through; the paper
    sheet (a square of half-width ``paper_half_rad``) hangs on a wall.
    """

    radius_rad: float = 0.8 * 0.5 * PAPER_FOV_RAD
    spokes: int = 36
    wood_k: float = 297.0
    wood_emissivity: float = 0.90
    paper_k: float = 320.0
    paper_emissivity: float = 0.93
    wall_k: float = AMBIENT_K
    paper_half_rad: float = 0.92 * 0.5 * PAPER_FOV_RAD
    name: str = "siemens-star"
    description: str = "wooden Siemens star (36 spokes) in front of heated paper"

    def _sample(self, ax, ay, t):
        temp = np.full(ax.shape, self.wall_k)
        eps = np.full(ax.shape, 0.9)
        paper = (np.abs(ax) <= self.paper_half_rad) & (np.abs(ay) <= self.paper_half_rad)
        _paint(temp, eps, paper, self.paper_k, self.paper_emissivity)
        r = np.hypot(ax, ay)
        phi = np.arctan2(ay, ax)
        wood = (r <= self.radius_rad) & (np.sin(self.spokes * 0.5 * phi) ** 2 >= 0.5)
        # a thin wooden rim holds the spokes together, as in a cut-out
        rim = (r <= self.radius_rad) & (r >= 0.94 * self.radius_rad)
        _paint(temp, eps, wood | rim, self.wood_k, self.wood_emissivity)
        return temp, eps


@dataclass(frozen=True)
class BarTargets(Scene):
    """Four-bar thermal targets (hot bars on an ambient plate), finest at the centre.

    ``frequencies`` are in cycles/rad. A central 2 x 2 cluster inside the foveal field spans the foveal
    channel's resolution; a ring of eight groups in the periphery spans the perifoveal channel's.
    """

    central: tuple[float, ...] = ()
    ring: tuple[float, ...] = ()
    plate_k: float = 295.0
    delta_k: float = 10.0
    emissivity: float = 0.95
    fovea_half_rad: float = 0.5 * PAPER_FOV_RAD / 6
    half_rad: float = 0.5 * PAPER_FOV_RAD
    name: str = "bars"
    description: str = "four-bar targets (hot bars, +10 K), finest in the fovea"

    def _groups(self) -> list[tuple[float, float, float, bool]]:
        """(centre x, centre y, frequency, vertical bars?) for each group."""
        out = []
        fh = self.fovea_half_rad
        for k, (f, (sx, sy)) in enumerate(zip(self.central, ((-1, -1), (1, -1), (-1, 1), (1, 1)))):
            out.append((0.5 * fh * sx, 0.5 * fh * sy, f, k % 2 == 0))
        n = len(self.ring)
        for k, f in enumerate(self.ring):
            a = 2 * np.pi * k / max(n, 1) + np.pi / 8
            rr = 0.55 * self.half_rad
            out.append((rr * np.cos(a), rr * np.sin(a), f, k % 2 == 0))
        return out

    def _sample(self, ax, ay, t):
        temp = np.full(ax.shape, self.plate_k)
        for cx, cy, f, vertical in self._groups():
            w = 0.5 / f  # bar width = half a period
            half = 3.5 * w  # 4 bars + 3 gaps = 7 w, bars 7 w long
            sel = _bbox_view(ax, ay, cx - half, cy - half, cx + half, cy + half)
            if not np.any(sel):
                continue
            u = (ax[sel] - (cx - half)) if vertical else (ay[sel] - (cy - half))
            k = np.floor(u / w)
            hot = (k % 2 == 0) & (k >= 0) & (k <= 6)
            sub = temp[sel]
            sub[hot] = self.plate_k + self.delta_k
            temp[sel] = sub
        return temp, np.full(ax.shape, self.emissivity)


@dataclass(frozen=True)
class WavingHand(Scene):
    """A person's forearm and hand waving (rotating about the elbow) in front of an indoor wall."""

    half_rad: float = 0.5 * PAPER_FOV_RAD
    wave_hz: float = 0.8
    wave_amplitude_deg: float = 25.0
    skin_k: float = 307.0
    finger_k: float = 304.5
    sleeve_k: float = 301.0
    wall_k: float = AMBIENT_K
    name: str = "hand"
    description: str = "a waving hand (0.8 Hz, +-25 deg) in front of a wall"
    static: bool = False

    def sample_background(self, ax, ay):
        h = self.half_rad
        ax = np.asarray(ax, dtype=np.float64)
        ay = np.asarray(ay, dtype=np.float64)
        temp = np.full(ax.shape, self.wall_k)
        eps = np.full(ax.shape, 0.92)
        # a radiator panel on the wall (warm) and a cold window, for context
        _paint(temp, eps, _box(ax, ay, 0.55 * h, -0.8 * h, 0.95 * h, -0.2 * h), 312.0, 0.9)
        _paint(temp, eps, _box(ax, ay, -0.95 * h, -0.9 * h, -0.55 * h, -0.35 * h), 285.0, 0.85)
        # torso and head of the person (lower left)
        _paint(temp, eps, _capsule(ax, ay, (-0.55 * h, 0.75 * h), (-0.55 * h, 1.6 * h), 0.32 * h), 300.0, 0.95)
        _paint(temp, eps, _capsule(ax, ay, (-0.55 * h, 0.05 * h), (-0.55 * h, 0.12 * h), 0.17 * h), 306.5, 0.98)
        return temp, eps

    def _pose(self, t: float):
        h = self.half_rad
        elbow = (0.05 * h, 0.95 * h)
        ang = np.deg2rad(self.wave_amplitude_deg) * np.sin(2 * np.pi * self.wave_hz * t)
        c, s = np.cos(ang), np.sin(ang)

        def rot(px: float, py: float) -> tuple[float, float]:  # hand frame (x right, y up from elbow)
            return elbow[0] + c * px + s * py, elbow[1] - (-s * px + c * py)
        return rot

    def dynamic_regions(self, t):
        h = self.half_rad
        rot = self._pose(t)
        L = 0.85 * h
        box = None
        # the arm, palm and fingers lie in this rectangle of the hand frame (plus their radii)
        pts = [rot(px, py) for px in (-0.2 * h, 0.3 * h) for py in (-0.12 * h, 0.12 * h + L, L + 0.52 * h)]
        xs, ys = [p[0] for p in pts], [p[1] for p in pts]
        box = (min(xs) - 0.05 * h, min(ys) - 0.05 * h, max(xs) + 0.05 * h, max(ys) + 0.05 * h)
        return [box]

    def _sample(self, ax, ay, t):
        h = self.half_rad
        temp, eps = self.sample_background(ax, ay)
        rot = self._pose(t)
        L = 0.85 * h  # elbow to wrist
        _paint(temp, eps, _capsule(ax, ay, rot(0, 0), rot(0, 0.55 * L), 0.1 * h), self.sleeve_k, 0.95)
        _paint(temp, eps, _capsule(ax, ay, rot(0, 0.5 * L), rot(0, L), 0.07 * h), self.skin_k, 0.98)
        # palm: a capsule plus fingers fanning out
        _paint(temp, eps, _capsule(ax, ay, rot(0, L + 0.06 * h), rot(0, L + 0.16 * h), 0.13 * h), self.skin_k, 0.98)
        fw = 0.028 * h
        for dx, ln, tilt in ((-0.09, 0.20, -0.12), (-0.03, 0.25, -0.04), (0.03, 0.27, 0.0), (0.09, 0.24, 0.05)):
            base = (dx * h, L + 0.22 * h)
            tip = (base[0] + np.sin(tilt) * ln * h, base[1] + np.cos(tilt) * ln * h)
            _paint(temp, eps, _capsule(ax, ay, rot(*base), rot(*tip), fw), self.finger_k, 0.98)
        # thumb
        _paint(temp, eps, _capsule(ax, ay, rot(0.11 * h, L + 0.08 * h), rot(0.24 * h, L + 0.22 * h), 1.1 * fw),
               self.finger_k, 0.98)
        return temp, eps


@dataclass(frozen=True)
class ParkingLot(Scene):
    """Cars crossing a sunlit parking lot, seen from a raised position (outdoor: cold sky reflected)."""

    half_rad: float = 0.5 * PAPER_FOV_RAD
    duration_s: float = 8.0
    asphalt_k: float = 308.0
    reflected_k: float = 255.0  # clear sky
    name: str = "parking-lot"
    description: str = "two cars with warm engines crossing a parking lot"
    static: bool = False

    def _car(self, temp, eps, ax, ay, x, y, size, direction, engine_k, parked=False):
        h = size
        x0, x1 = x - 1.0 * h, x + 1.0 * h
        sel = _bbox_view(ax, ay, x0 - 0.3 * h, y - 0.75 * h, x1 + 0.3 * h, y + 0.3 * h)
        if not np.any(sel):
            return
        bx, by = ax[sel], ay[sel]
        tt, ee = temp[sel], eps[sel]
        body = _box(bx, by, x0, y - 0.3 * h, x1, y + 0.05 * h)
        cabin = _box(bx, by, x - 0.55 * h, y - 0.62 * h, x + 0.45 * h, y - 0.3 * h)
        front = 1.0 if direction > 0 else -1.0
        hood = body & ((bx - x) * front > 0.45 * h)
        glass = cabin & ~_box(bx, by, x - 0.08 * h, y - 0.62 * h, x + 0.02 * h, y - 0.3 * h)
        tt[body | cabin], ee[body | cabin] = 300.0 if parked else 303.0, 0.9
        tt[glass], ee[glass] = 296.0, 0.84  # glass reflects the cold sky
        if not parked:
            tt[hood] = engine_k
        for wx in (x - 0.6 * h, x + 0.6 * h):
            wheel = (bx - wx) ** 2 + (by - y - 0.05 * h) ** 2 <= (0.2 * h) ** 2
            tt[wheel], ee[wheel] = (306.0 if parked else 318.0), 0.95
        if not parked:  # exhaust at the rear
            ex = x - front * 1.08 * h
            plume = (bx - ex) ** 2 / (0.12 * h) ** 2 + (by - y) ** 2 / (0.05 * h) ** 2 <= 1.0
            tt[plume], ee[plume] = 345.0, 0.95
        temp[sel], eps[sel] = tt, ee

    def _moving(self, t: float) -> list[tuple[float, float, float, int, float]]:
        """(x, y, size, direction, engine temperature) of the moving cars at time t."""
        h = self.half_rad
        d = max(self.duration_s, 1.0)
        return [(-1.3 * h + 2.6 * h * (t / d), 0.05 * h, 0.16 * h, 1, 330.0),
                (1.3 * h - 2.6 * h * (t / d) * 0.8, 0.38 * h, 0.2 * h, -1, 326.0)]

    def dynamic_regions(self, t):
        boxes = []
        for x, y, size, _, _ in self._moving(t):
            boxes.append((x - 1.3 * size, y - 0.8 * size, x + 1.3 * size, y + 0.35 * size))
        return boxes

    def sample_background(self, ax, ay):
        return self._paint_all(np.asarray(ax, dtype=np.float64), np.asarray(ay, dtype=np.float64), None)

    def _sample(self, ax, ay, t):
        return self._paint_all(ax, ay, t)

    def _paint_all(self, ax, ay, t):
        h = self.half_rad
        temp = np.full(ax.shape, self.asphalt_k)
        eps = np.full(ax.shape, 0.95)
        # painted parking lines (paint has a lower emissivity: looks colder, reflecting the sky)
        for k in range(-6, 7):
            _paint(temp, eps, _box(ax, ay, k * 0.32 * h - 0.012 * h, -0.95 * h, k * 0.32 * h + 0.012 * h, -0.5 * h),
                   self.asphalt_k, 0.82)
            _paint(temp, eps, _box(ax, ay, k * 0.32 * h - 0.012 * h, 0.55 * h, k * 0.32 * h + 0.012 * h, 1.0 * h),
                   self.asphalt_k, 0.82)
        # a shaded strip (tree shadow) is cooler
        _paint(temp, eps, _box(ax, ay, -1.2 * h, -1.2 * h, 1.2 * h, -0.97 * h), 298.0, 0.95)
        # parked cars
        for k in (-2, 0, 1, 3):
            self._car(temp, eps, ax, ay, (k + 0.5) * 0.32 * h, -0.62 * h, 0.13 * h, 1, 0, parked=True)
        for k in (-3, -1, 2):
            self._car(temp, eps, ax, ay, (k + 0.5) * 0.32 * h, 0.88 * h, 0.13 * h, 1, 0, parked=True)
        # moving cars: one left-to-right through the fovea, one right-to-left lower down
        if t is not None:
            for x, y, size, direction, engine in self._moving(t):
                self._car(temp, eps, ax, ay, x, y, size, direction, engine)
        return temp, eps


@dataclass(frozen=True)
class CoilHeater(Scene):
    """A coil heater switched on at ``t_on_s`` for ``on_duration_s`` (heating then cooling transients).

    Coil temperature above ambient: ``dT_max (1 - exp(-(t - t_on) / tau_heat))`` while on, then an
    exponential decay with ``tau_cool`` after switch-off.
    """

    on_duration_s: float = 5.0
    t_on_s: float = 1.0
    dt_max_k: float = 250.0
    tau_heat_s: float = 2.0
    tau_cool_s: float = 4.0
    loops: int = 9
    half_rad: float = 0.5 * PAPER_FOV_RAD
    wall_k: float = AMBIENT_K
    name: str = "heater"
    description: str = "coil heater switched on for a while: heating and cooling transients"
    static: bool = False

    def __post_init__(self) -> None:
        check_positive("on_duration_s", self.on_duration_s, "s")
        check_positive("tau_heat_s", self.tau_heat_s, "s")
        check_positive("tau_cool_s", self.tau_cool_s, "s")

    def coil_temperature(self, t: float) -> float:
        t_off = self.t_on_s + self.on_duration_s
        if t < self.t_on_s:
            h = 0.0
        elif t <= t_off:
            h = 1.0 - math.exp(-(t - self.t_on_s) / self.tau_heat_s)
        else:
            h = (1.0 - math.exp(-self.on_duration_s / self.tau_heat_s)) * math.exp(-(t - t_off) / self.tau_cool_s)
        return self.wall_k + self.dt_max_k * h

    def dynamic_regions(self, t):
        h = self.half_rad
        length = 0.5 * h
        return [(-length - 0.09 * h, -0.1 * h, length + 0.09 * h, 0.1 * h)]

    def sample_background(self, ax, ay):
        ax = np.asarray(ax, dtype=np.float64)
        return np.full(ax.shape, self.wall_k), np.full(ax.shape, 0.9)

    def _sample(self, ax, ay, t):
        h = self.half_rad
        tc = self.coil_temperature(t)
        temp, eps = self.sample_background(ax, ay)
        # ceramic holder (warms to a fraction of the coil's excess) and two terminals
        t_holder = self.wall_k + 0.12 * (tc - self.wall_k)
        length = 0.5 * h
        _paint(temp, eps, _box(ax, ay, -length - 0.08 * h, -0.09 * h, -length, 0.09 * h), t_holder, 0.92)
        _paint(temp, eps, _box(ax, ay, length, -0.09 * h, length + 0.08 * h, 0.09 * h), t_holder, 0.92)
        # the helix seen side-on: a row of tilted elliptical loops of wire
        a, b, wire = 0.6 * length / self.loops, 0.07 * h, 0.006 * h
        sel = _bbox_view(ax, ay, -length, -b - 2 * wire, length, b + 2 * wire)
        if np.any(sel):
            x, y = ax[sel], ay[sel]
            pitch = 2 * length / self.loops
            k = np.clip(np.floor((x + length) / pitch), 0, self.loops - 1)
            cx = -length + (k + 0.5) * pitch
            u = (x - cx) + 0.35 * y  # slant of the helix turns
            rr = np.sqrt((u / a) ** 2 + (y / b) ** 2)
            on = np.abs(rr - 1.0) * min(a, b) <= wire
            tt, ee = temp[sel], eps[sel]
            tt[on], ee[on] = tc, 0.85
            temp[sel], eps[sel] = tt, ee
        return temp, eps


@dataclass(frozen=True)
class Rooftop(Scene):
    """A flat sunlit roof seen from above its edge: HVAC units with fan grilles, vent pipes, a warm chimney and a
    strip of clear sky at the top (outdoor: the sky is reflected). An HVAC grille sits in the fovea."""

    half_rad: float = 0.5 * PAPER_FOV_RAD
    roof_k: float = 316.0
    sky_k: float = 250.0
    unit_k: float = 304.0
    chimney_k: float = 335.0
    reflected_k: float = 255.0  # clear sky
    name: str = "rooftop"
    description: str = "a sunlit roof with HVAC units, vents and a chimney under a clear sky"

    def _sample(self, ax, ay, t):
        h = self.half_rad
        temp = np.full(ax.shape, self.roof_k)
        eps = np.full(ax.shape, 0.93)
        _paint(temp, eps, ay < -0.7 * h, self.sky_k, 1.0)  # the sky above the far roof edge
        _paint(temp, eps, _box(ax, ay, -2 * h, -0.7 * h, 2 * h, -0.64 * h), 300.0, 0.9)  # parapet, in shade
        # the HVAC unit in the fovea: a cool box with a grille of fan slats (the fan's motor warm)
        _paint(temp, eps, _box(ax, ay, -0.3 * h, -0.22 * h, 0.3 * h, 0.22 * h), self.unit_k, 0.85)
        for k in range(-4, 5):
            y0 = k * 0.04 * h
            _paint(temp, eps, _box(ax, ay, -0.22 * h, y0 - 0.008 * h, 0.22 * h, y0 + 0.008 * h), 310.0, 0.9)
        _paint(temp, eps, np.hypot(ax, ay) <= 0.035 * h, 322.0, 0.95)
        # a second unit and vent pipes (round tops, warm) in the periphery
        _paint(temp, eps, _box(ax, ay, 0.5 * h, 0.3 * h, 0.9 * h, 0.65 * h), self.unit_k + 2.0, 0.85)
        for cx, cy in ((-0.7 * h, 0.5 * h), (-0.45 * h, 0.7 * h), (0.6 * h, -0.4 * h)):
            _paint(temp, eps, np.hypot(ax - cx, ay - cy) <= 0.05 * h, 309.0, 0.9)
        _paint(temp, eps, _box(ax, ay, -0.85 * h, -0.55 * h, -0.65 * h, -0.2 * h), self.chimney_k, 0.92)
        return temp, eps


@dataclass(frozen=True)
class TallBuildings(Scene):
    """Tall buildings against a cold sky: façades with a grid of windows (glass reflects the sky: it looks cold),
    a few warm lit rooms; the fovea holds one façade's window grid."""

    half_rad: float = 0.5 * PAPER_FOV_RAD
    sky_k: float = 240.0
    facade_k: float = 299.0
    glass_k: float = 288.0
    reflected_k: float = 250.0
    name: str = "tall-buildings"
    description: str = "tall buildings with window grids against a clear sky"

    def _sample(self, ax, ay, t):
        h = self.half_rad
        temp = np.full(ax.shape, self.sky_k)
        eps = np.full(ax.shape, 1.0)
        # (left, right, top, façade temperature, window pitch) of each building; the centre one fills the fovea
        for x0, x1, top, tk, pitch in ((-1.2, -0.45, -0.55, self.facade_k - 3.0, 0.14),
                                       (-0.4, 0.4, -0.85, self.facade_k, 0.06),
                                       (0.45, 1.2, -0.3, self.facade_k + 2.0, 0.11)):
            x0, x1, top, p = x0 * h, x1 * h, top * h, pitch * h
            _paint(temp, eps, _box(ax, ay, x0, top, x1, 2 * h), tk, 0.9)
            u = np.mod(ax - x0, p) / p
            v = np.mod(ay - top, p) / p
            win = _box(ax, ay, x0 + 0.5 * p, top + 0.5 * p, x1 - 0.5 * p, 2 * h) & (u > 0.3) & (u < 0.75) & \
                (v > 0.25) & (v < 0.7)
            _paint(temp, eps, win, self.glass_k, 0.84)
        # lit (warm) rooms: a few windows of the centre building
        for cx, cy in ((0.09, 0.03), (-0.15, -0.27), (0.21, 0.45)):
            lit = _box(ax, ay, (cx - 0.02) * h, (cy - 0.02) * h, (cx + 0.02) * h, (cy + 0.01) * h)
            _paint(temp, eps, lit, 303.0, 0.84)
        return temp, eps


@dataclass(frozen=True)
class Oven(Scene):
    """A kitchen oven, switched on: a warm body, a hot door window with the racks behind it and the glowing upper
    heating element, control knobs; indoor wall around. The door window's racks lie in the fovea."""

    half_rad: float = 0.5 * PAPER_FOV_RAD
    wall_k: float = AMBIENT_K
    body_k: float = 306.0
    window_k: float = 345.0
    element_k: float = 420.0
    name: str = "oven"
    description: str = "an oven switched on: hot door window, racks and heating element"

    def _sample(self, ax, ay, t):
        h = self.half_rad
        temp = np.full(ax.shape, self.wall_k)
        eps = np.full(ax.shape, 0.92)
        _paint(temp, eps, _box(ax, ay, -0.75 * h, -0.8 * h, 0.75 * h, 0.85 * h), self.body_k, 0.9)
        _paint(temp, eps, _box(ax, ay, -0.75 * h, -0.8 * h, 0.75 * h, -0.55 * h), 301.0, 0.9)  # control panel
        for cx in (-0.5, -0.25, 0.25, 0.5):
            _paint(temp, eps, np.hypot(ax - cx * h, ay + 0.675 * h) <= 0.07 * h, 311.0, 0.6)  # knobs (metal)
        win = _box(ax, ay, -0.55 * h, -0.4 * h, 0.55 * h, 0.45 * h)
        _paint(temp, eps, win, self.window_k, 0.88)
        # the upper element (a zigzag of hot wire) and two racks (horizontal bars, cooler than the glass's glow)
        for k in range(6):
            x0 = (-0.45 + 0.15 * k) * h
            _paint(temp, eps, _capsule(ax, ay, (x0, -0.32 * h), (x0 + 0.15 * h, -0.22 * h), 0.012 * h),
                   self.element_k, 0.9)
        for y0 in (-0.05, 0.0, 0.05, 0.25):
            _paint(temp, eps, _box(ax, ay, -0.5 * h, (y0 - 0.006) * h, 0.5 * h, (y0 + 0.006) * h), 330.0, 0.7)
        for k in range(-8, 9):
            _paint(temp, eps, _box(ax, ay, (k * 0.06 - 0.004) * h, -0.05 * h, (k * 0.06 + 0.004) * h, 0.05 * h),
                   330.0, 0.7)
        return temp, eps


# ----------------------------------------------------------------------------------------------
# raster scenes
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RasterScene(Scene):
    """Temperatures on a raster spanning ``half_width_rad`` horizontally (aspect kept), centred.

    ``temperature_k``: (h, w) or (T, h, w) kelvin; ``emissivity``: scalar or same spatial shape;
    ``frame_rate_hz``: the rate of a (T, h, w) raster (nearest earlier frame is used; the video
    repeats after its end). Outside the raster: ``background_k``. ``conversion``: how the values became
    kelvin (a picture's luminance mapped to a range, degrees Celsius converted), stated in :meth:`summary`.
    """

    temperature_k: np.ndarray = field(default_factory=lambda: np.full((2, 2), 300.0))
    emissivity: float | np.ndarray = 0.95
    half_width_rad: float = 0.5 * PAPER_FOV_RAD
    background_k: float = AMBIENT_K
    frame_rate_hz: float = PAPER_FRAME_RATE_HZ
    name: str = "raster"
    description: str = "temperature raster"
    static: bool = True
    conversion: str | None = None  #: how the values became kelvin, when they were not given in kelvin

    def summary(self) -> dict[str, Any]:
        out = super().summary()
        return out if self.conversion is None else {**out, "conversion": self.conversion}

    def __post_init__(self) -> None:
        t = np.asarray(self.temperature_k, dtype=np.float64)
        if t.ndim not in (2, 3) or min(t.shape[-2:]) < 2:
            raise InputError("temperature_k", f"array of shape {t.shape}", "a (h, w) or (T, h, w) array, h, w >= 2")
        if not np.all(np.isfinite(t)) or float(t.min()) < 0 or float(t.max()) > T_MAX_K:  # the radiance table's end
            raise InputError("temperature_k", _worst(t, 0.0, T_MAX_K),
                             f"finite temperatures in [0, {T_MAX_K:g}] K (kelvin, not Celsius)")
        check_positive("half_width_rad", self.half_width_rad, "rad", hi=math.pi / 2)
        e = np.asarray(self.emissivity, dtype=np.float64)
        if e.ndim and e.shape != t.shape[-2:]:
            raise InputError("emissivity", f"array of shape {e.shape}", f"a scalar or shape {t.shape[-2:]}")
        if e.size and not (np.all(np.isfinite(e)) and float(e.min()) >= 0 and float(e.max()) <= 1):
            raise InputError("emissivity", _worst(e, 0.0, 1.0), "finite, 0 <= emissivity <= 1")
        object.__setattr__(self, "temperature_k", t)
        object.__setattr__(self, "emissivity", e)
        object.__setattr__(self, "static", t.ndim == 2 or t.shape[0] == 1)

    def _coords(self, ax, ay):
        h, w = self.temperature_k.shape[-2:]
        px = self.half_width_rad * 2 / w  # angle per raster pixel
        col = ax / px + (w - 1) / 2
        row = ay / px + (h - 1) / 2
        return row, col

    def _sample(self, ax, ay, t):
        from scipy.ndimage import map_coordinates

        tk = self.temperature_k
        if tk.ndim == 3:
            tk = tk[int(math.floor(t * self.frame_rate_hz + 1e-9)) % tk.shape[0]]
        ax, ay = np.asarray(ax), np.asarray(ay)
        if ax.ndim == 2 and ax.strides[0] == 0 and ay.strides[1] == 0:
            # a grid (a renderer's rows x columns of field angles): the same interpolation, one axis at a time
            row, col = self._coords(ax[0], ay[:, 0])
            temp = bilinear_grid(tk, row, col, cval=self.background_k)
            eps = bilinear_grid(self.emissivity, row, col, cval=0.95) if self.emissivity.ndim else \
                np.full(ax.shape, float(self.emissivity))
            return temp, eps
        row, col = self._coords(ax, ay)
        temp = map_coordinates(tk, [row.ravel(), col.ravel()], order=1, mode="constant",
                               cval=self.background_k).reshape(ax.shape)
        if self.emissivity.ndim:
            eps = map_coordinates(self.emissivity, [row.ravel(), col.ravel()], order=1, mode="constant",
                                  cval=0.95).reshape(ax.shape)
        else:
            eps = np.full(ax.shape, float(self.emissivity))
        return temp, eps


def bilinear_grid(a: np.ndarray, rows: np.ndarray, cols: np.ndarray, cval: float | None = None) -> np.ndarray:
    """``a`` (2-D) interpolated linearly at the grid ``rows`` x ``cols`` (1-D fractional indices), one axis at a time:
    ``scipy.ndimage.map_coordinates(a, order=1)`` on the grid (to rounding) with ``mode='constant'`` (``cval`` where a
    row or column index is outside ``[0, n - 1]``) or, with ``cval=None``, ``mode='nearest'`` (indices clamped), for
    ``O(rows (W + cols))`` work instead of ``O(rows cols)`` 2-D interpolations. Returns ``(rows.size, cols.size)``."""
    a = np.asarray(a, dtype=np.float64)
    h, w = a.shape

    def axis(x: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        x = np.asarray(x, dtype=np.float64)
        outside = None if cval is None else (x < 0) | (x > n - 1)
        x = np.clip(x, 0.0, n - 1.0)
        i0 = np.minimum(np.floor(x).astype(np.intp), max(n - 2, 0))
        return i0, np.minimum(i0 + 1, n - 1), x - i0, outside

    i0, i1, fr, out_r = axis(rows, h)
    j0, j1, fc, out_c = axis(cols, w)
    t = a[i0] * (1.0 - fr)[:, None] + a[i1] * fr[:, None]
    out = t[:, j0] * (1.0 - fc) + t[:, j1] * fc
    if cval is not None:
        out[out_r, :] = cval
        out[:, out_c] = cval
    return out


#: scikit-image pictures bundled inside the package (no download needed).
SKIMAGE_IMAGES = ("astronaut", "camera", "coffee", "chelsea", "rocket", "coins", "moon", "brick", "grass",
                  "gravel", "text", "page", "horse", "clock", "immunohistochemistry", "hubble_deep_field",
                  "motorcycle", "logo", "retina", "cat")


def gray_to_temperature(gray: np.ndarray, t_range_k: tuple[float, float] = (288.0, 312.0),
                        gamma: float = 1.0) -> np.ndarray:
    """Map a picture's luminance in [0, 1] linearly (after ``gamma``) to ``t_range_k`` (kelvin).

    Bright surfaces are taken as warm: a plausible but not physical assignment (a visible image does
    not know temperatures); the range spans a typical indoor/outdoor 24 K contrast.
    """
    lo, hi = t_range_k
    check_range("t_range_k", lo, 0.0, 3000.0, lo_inclusive=True, unit="K")
    check_range("t_range_k", hi, lo, 3000.0, unit="K")
    g = np.clip(np.asarray(gray, dtype=np.float64), 0.0, 1.0) ** gamma
    return lo + (hi - lo) * g


def _to_gray(img: np.ndarray) -> np.ndarray:
    img = np.asarray(img)
    if img.ndim == 3 and img.shape[-1] in (3, 4):
        from skimage.color import rgb2gray
        g = rgb2gray(img[..., :3])
    elif img.ndim == 2:
        g = img.astype(np.float64)
        if np.issubdtype(img.dtype, np.integer):
            g = g / float(np.iinfo(img.dtype).max)
    else:
        raise InputError("image", f"array of shape {img.shape}", "a grey (h, w) or colour (h, w, 3|4) picture")
    g = np.asarray(g, dtype=np.float64)
    if g.max() > 1.0 or g.min() < 0.0:
        g = (g - g.min()) / max(g.max() - g.min(), 1e-12)
    return g


def _scene_unit(scene_unit: str) -> str:
    """``scene_unit`` checked: one of :data:`SCENE_UNITS`."""
    unit = str(scene_unit).strip().lower()
    if unit not in SCENE_UNITS:
        raise InputError("scene_unit", scene_unit, " or ".join(SCENE_UNITS))
    return unit


def _picture_advice(t_range_k: tuple[float, float]) -> str:
    return (f"save one channel of temperatures in kelvin (.npy, or a float TIFF), or the picture as an 8- or 16-bit "
            f"PNG or TIFF, whose luminance is mapped to {t_range_k[0]:g}-{t_range_k[1]:g} K")


def _one_channel(shape: tuple[int, ...], t_range_k: tuple[float, float], samples: str | None = None) -> None:
    """Refuse a colour or multi-channel image where a map of temperatures is expected: ``samples`` says what a file
    declares (a TIFF's samples or channels); else an ``(h, w, 3|4)`` array is a colour picture (a raster 3 or 4
    pixels wide is no scene). A ``(3|4, h, w)`` array with nothing declared is a video of 3 or 4 frames."""
    if samples is None and len(shape) == 3 and shape[-1] in (3, 4) and min(shape[:2]) > 4:
        samples = f"{shape[-1]} samples per pixel (an RGB{'A' if shape[-1] == 4 else ''} picture)"
    if samples is not None:
        raise InputError("temperature_k", f"array of shape {tuple(shape)}", "one channel (a temperature map in "
                         "kelvin): an (h, w) or (T, h, w) array", detail=f"{samples}; {_picture_advice(t_range_k)}")


def _in_kelvin(temp: np.ndarray, scene_unit: str, source: str,
               t_range_k: tuple[float, float]) -> tuple[np.ndarray, str | None]:
    """A file's or an array's temperatures in kelvin, and how they were converted (None: given in kelvin).

    Refuses values whose hottest is below :data:`MIN_HOTTEST_K` (in kelvin, after the conversion) with what they
    look like: degrees Celsius (``scene_unit='celsius'`` converts them) or a picture's levels. Non-finite and
    negative values are left to :class:`RasterScene`, which refuses them.
    """
    t = np.asarray(temp, dtype=np.float64)
    conversion = None
    if scene_unit == "celsius":
        t = t + ZERO_CELSIUS_K
        conversion = f"degrees Celsius converted to kelvin: T_K = T_C + {ZERO_CELSIUS_K:g}"
    finite = t[np.isfinite(t)]
    if finite.size == 0:
        return t, conversion
    if float(finite.max()) >= MIN_HOTTEST_K:
        lo = float(finite.min())
        if scene_unit == "kelvin" and 0.0 <= lo < COLDEST_PLAUSIBLE_K:
            warnings.warn(f"scene {source}: its coldest value, {lo:.4g} K, is colder than any sky (a cryogenic "
                          f"target?); if it is in degrees Celsius, scene_unit='celsius' converts it", UserWarning,
                          stacklevel=3)
        return t, conversion
    lo, hi = float(finite.min()), float(finite.max())
    allowed = f"temperatures in kelvin, a thermal scene's hottest part at {MIN_HOTTEST_K:g} K or warmer"
    if scene_unit == "celsius":
        value = f"values {lo - ZERO_CELSIUS_K:.4g} to {hi - ZERO_CELSIUS_K:.4g} degrees Celsius"
        detail = f"{lo:.4g} to {hi:.4g} K"
    else:
        value = f"values {lo:.4g} to {hi:.4g}"
        detail = (f"they look like a picture's levels: {_picture_advice(t_range_k)}" if lo >= 0.0 and hi <= 1.0 else
                  f"they look like degrees Celsius: scene_unit='celsius' converts them, +{ZERO_CELSIUS_K:g} K"
                  if lo >= -100.0 else None)
    raise InputError("temperature_k", value, allowed, detail=detail)


def image_scene(name: str, geometry: SceneGeometry | None = None, *,
                t_range_k: tuple[float, float] = (288.0, 312.0), emissivity: float = 0.95,
                fill: float = 1.0) -> RasterScene:
    """A scikit-image picture mapped to temperatures, spanning ``fill`` x the perifoveal field width."""
    from skimage import data

    if name not in SKIMAGE_IMAGES:
        raise InputError("scene", name, "one of the bundled scikit-image pictures: " + ", ".join(SKIMAGE_IMAGES))
    g = geometry or SceneGeometry()
    loader = getattr(data, name, None) or getattr(data, f"stereo_{name}", None)  # motorcycle: stereo_motorcycle
    if loader is None:
        raise InputError("scene", f"skimage:{name}", "a picture this scikit-image version bundles")
    try:
        img = loader()
    except (OSError, ValueError, ImportError) as e:  # e.g. a picture that needs a download, offline
        raise InputError("scene", f"skimage:{name}", "a scikit-image picture available offline",
                         detail=" ".join(str(e).split())[:160]) from None
    if isinstance(img, tuple):  # stereo pair helper returns (left, right, disparity)
        img = img[0]
    gray = _to_gray(img)
    temp = gray_to_temperature(gray, t_range_k)
    return RasterScene(temperature_k=temp, emissivity=emissivity, half_width_rad=fill * g.half,
                       name=name, description=f"scikit-image '{name}' picture mapped to "
                                              f"{t_range_k[0]:g}-{t_range_k[1]:g} K")


def load_scene_file(path: str | Path, geometry: SceneGeometry | None = None, *,
                    t_range_k: tuple[float, float] = (288.0, 312.0),
                    frame_rate_hz: float = PAPER_FRAME_RATE_HZ, scene_unit: str = "kelvin") -> RasterScene:
    """A scene from a file.

    * ``.npy``: (h, w) or (T, h, w) temperatures in kelvin.
    * ``.npz``: array ``temperature_k`` (as .npy), optional ``emissivity`` (h, w) and scalar
      ``half_width_deg`` (field half-width the raster spans; default the perifoveal field).
    * ``.tif``/``.tiff``: float data is temperatures, as .npy; integer data is a picture (mapped like below).
    * ``.png``/``.jpg``/``.jpeg``/``.bmp``: a picture; luminance mapped to ``t_range_k``.

    Temperatures (.npy, .npz, float TIFF) are one channel, in kelvin unless ``scene_unit='celsius'`` (+273.15 K,
    stated in the scene's :meth:`~Scene.summary`). A colour or multi-channel array (``(h, w, 3|4)``, a TIFF whose
    pixels hold several samples or channels) is refused, and so is one whose hottest value is below
    :data:`MIN_HOTTEST_K` (degrees Celsius, a picture's levels): each with how to convert it. A picture's mapping
    to temperatures is stated in the summary too.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError("scene", str(p), "a built-in scene name (see list_scenes()) or an existing file")
    unit = _scene_unit(scene_unit)
    g = geometry or SceneGeometry()
    suffix = p.suffix.lower()
    half = g.half
    emis: float | np.ndarray = 0.95
    picture = suffix in (".png", ".jpg", ".jpeg", ".bmp", ".gif")
    samples = None  # what a TIFF declares about its pixels' samples or channels
    try:
        if suffix == ".npy":
            temp = np.load(p, allow_pickle=False)
        elif suffix == ".npz":
            with np.load(p, allow_pickle=False) as z:
                if "temperature_k" not in z.files:
                    raise InputError("scene", str(p), "an .npz with an array 'temperature_k' (kelvin)")
                temp = z["temperature_k"]
                if "emissivity" in z.files:
                    emis = z["emissivity"]
                if "half_width_deg" in z.files:
                    hw = np.asarray(z["half_width_deg"])
                    if hw.size != 1 or not np.issubdtype(hw.dtype, np.number) or np.iscomplexobj(hw):
                        raise InputError("half_width_deg", f"array of shape {hw.shape}, dtype {hw.dtype}",
                                         "a real scalar (degrees)", source=str(p))
                    half = math.radians(float(hw.reshape(())))
        elif suffix in (".tif", ".tiff"):
            temp, samples = _read_tiff(p)
            picture = not np.issubdtype(temp.dtype, np.floating)
        elif picture:
            from skimage import io as skio
            temp = skio.imread(p)
        else:
            raise InputError("scene", str(p), "a file ending in .npy, .npz, .tif, .tiff, .png, .jpg, .jpeg or .bmp")
        if picture:
            if unit != "kelvin":
                raise InputError("scene_unit", scene_unit, f"kelvin for a picture ({p.name}: a .png, .jpg or integer "
                                 f"TIFF's luminance is mapped to {t_range_k[0]:g}-{t_range_k[1]:g} K)")
            temp = gray_to_temperature(_to_gray(temp), t_range_k)
    except InputError:
        raise
    except (OSError, ValueError, TypeError, KeyError, IndexError, EOFError, zipfile.BadZipFile, zlib.error) as e:
        # one line: some readers (imageio) explain themselves over several lines
        first = " ".join(str(e).split())[:200]
        raise InputError("scene", str(p), "a readable scene file", detail=first or type(e).__name__) from None
    temp = np.asarray(temp)
    if not np.issubdtype(temp.dtype, np.number) or np.iscomplexobj(temp):
        raise InputError("scene", str(p), "real-valued temperatures in kelvin")
    if picture:
        conversion = (f"a picture: its luminance (grey levels; colour weighted to grey) mapped linearly to "
                      f"{t_range_k[0]:g}-{t_range_k[1]:g} K")
    else:
        _one_channel(temp.shape, t_range_k, samples)
        temp, conversion = _in_kelvin(temp, unit, str(p), t_range_k)
    return RasterScene(temperature_k=temp, emissivity=emis, half_width_rad=half, frame_rate_hz=frame_rate_hz,
                       name=p.stem, description=f"file {p.name}", conversion=conversion)


def _read_tiff(p: Path) -> tuple[np.ndarray, str | None]:
    """A TIFF's first series, and what its pixels hold when that is more than one value (None: one).

    A float TIFF of 3 or 4 frames written by ``tifffile`` without ``photometric`` is stored as one RGB image with
    separate planes (tifffile 2023-2026): it says RGB, and is refused as such, with that hint.
    """
    import tifffile

    with tifffile.TiffFile(p) as tf:
        series = tf.series[0]
        arr = series.asarray()
        axes = series.axes
    sizes = {a: n for a, n in zip(axes, arr.shape)}
    if sizes.get("S", 1) > 1:
        n = sizes["S"]
        kind = f"{n} samples per pixel" + (f" (an RGB{'A' if n == 4 else ''} image)" if n in (3, 4) else "")
        if axes.index("S") < axes.index("Y"):
            kind += ", stored as separate planes (a stack written with tifffile needs photometric='minisblack')"
        return arr, kind
    if sizes.get("C", 1) > 1:
        return arr, f"{sizes['C']} channels"
    return arr, None


# ----------------------------------------------------------------------------------------------
# registry
# ----------------------------------------------------------------------------------------------
def _bars(g: SceneGeometry, **kw: Any) -> BarTargets:
    # Nyquist of each channel for the paper's 290-pixel field: 290 / (2 fov) cycles/rad
    nyq_p = PAPER_CROP_PX / (2 * g.fov_rad)
    nyq_f = nyq_p * g.expansion
    central = tuple(nyq_f * np.array([0.25, 0.4, 0.6, 0.85]))
    ring = tuple(nyq_p * np.array([0.1, 0.15, 0.2, 0.3, 0.4, 0.55, 0.7, 0.85]))
    return BarTargets(central=central, ring=ring, fovea_half_rad=g.fovea_half, half_rad=g.half, **kw)


SCENES: dict[str, tuple[Callable[..., Scene], str]] = {
    "siemens-star": (lambda g, **kw: SiemensStar(radius_rad=0.8 * g.half, paper_half_rad=0.92 * g.half, **kw),
                     "wooden Siemens star cut-out in front of heated paper (static)"),
    "bars": (_bars, "four-bar targets, +10 K, finest in the fovea (static)"),
    "hand": (lambda g, **kw: WavingHand(half_rad=g.half, **kw), "a waving hand in front of a wall (video)"),
    "parking-lot": (lambda g, **kw: ParkingLot(half_rad=g.half, duration_s=g.duration_s, **kw),
                    "cars crossing a parking lot (video)"),
    "heater-5s": (lambda g, **kw: CoilHeater(on_duration_s=5.0, half_rad=g.half, name="heater-5s", **kw),
                  "coil heater on for 5 s from t = 1 s (video)"),
    "heater-10s": (lambda g, **kw: CoilHeater(on_duration_s=10.0, half_rad=g.half, name="heater-10s", **kw),
                   "coil heater on for 10 s from t = 1 s (video)"),
    "heater-20s": (lambda g, **kw: CoilHeater(on_duration_s=20.0, half_rad=g.half, name="heater-20s", **kw),
                   "coil heater on for 20 s from t = 1 s (video)"),
    "uniform": (lambda g, **kw: UniformScene(**kw), "uniform 300 K blackbody (static)"),
    "rooftop": (lambda g, **kw: Rooftop(half_rad=g.half, **kw),
                "a sunlit roof with HVAC units and a chimney under a clear sky (static, outdoor)"),
    "tall-buildings": (lambda g, **kw: TallBuildings(half_rad=g.half, **kw),
                       "tall buildings with window grids against a cold sky (static, outdoor)"),
    "oven": (lambda g, **kw: Oven(half_rad=g.half, **kw), "an oven switched on: hot door window, racks and "
                                                            "heating element (static, indoor)"),
}
for _n in ("astronaut", "camera", "coffee", "chelsea", "rocket", "coins", "moon", "brick"):
    SCENES[_n] = (lambda g, _n=_n, **kw: image_scene(_n, g, **kw), f"scikit-image '{_n}' picture, 288-312 K")


#: families of scenes named ``PREFIX:SPEC`` that a module registers (:func:`register_scene_family`): prefix ->
#: (builder ``(spec, geometry, **params) -> Scene``, the names' pattern, a description). ``gen``
#: (:mod:`metafovea.imaging.generator`, registered when :mod:`metafovea.imaging` is imported): ``gen:KIND:SEED``.
SCENE_FAMILIES: dict[str, tuple[Callable[..., Scene], str, str]] = {}


def register_scene_family(prefix: str, builder: Callable[..., Scene], pattern: str, description: str) -> None:
    """Make names ``PREFIX:SPEC`` scenes for :func:`make_scene`: ``builder(spec, geometry, **params)``.

    Parameters
    ----------
    prefix : str
        Lower case, no ``:``; not a built-in scene's name nor ``skimage``.
    builder : callable
        ``(spec: str, geometry: SceneGeometry, **params) -> Scene``; raises :class:`InputError` for a bad spec.
    pattern : str
        How the names look (``gen:KIND:SEED``), for listings and errors.
    description : str
        One line.
    """
    if not prefix or prefix != prefix.lower() or ":" in prefix or prefix in SCENES or prefix == "skimage":
        raise InputError("prefix", prefix, "a new lower-case scene family prefix without ':'")
    SCENE_FAMILIES[prefix] = (builder, pattern, description)


def list_scene_families() -> dict[str, str]:
    """The patterns of the registered scene families (``gen:KIND:SEED``) and their one-line descriptions."""
    return {pattern: description for _, pattern, description in SCENE_FAMILIES.values()}


def list_scenes() -> dict[str, str]:
    """Built-in scene names and one-line descriptions (any of SKIMAGE_IMAGES also works as
    ``skimage:NAME``)."""
    return {k: v[1] for k, v in SCENES.items()}


def make_scene(name: str | Path | Scene | np.ndarray, geometry: SceneGeometry | None = None, *,
               scene_unit: str = "kelvin", **params: Any) -> Scene:
    """A scene by built-in name, ``skimage:NAME``, file path (see :func:`load_scene_file`) or array.

    Parameters
    ----------
    name : str, Path, Scene or ndarray, shape (h, w) or (T, h, w)
        A built-in name (:func:`list_scenes`), ``skimage:NAME``, a registered family's name
        (:func:`list_scene_families`: ``gen:KIND:SEED``, a generated scene), a file, a Scene (returned as it is), or
        temperatures (one channel, spanning the perifoveal field; a video at ``frame_rate_hz``).
    geometry : SceneGeometry, optional
        The field of view a scene lays itself out in (default: the paper's camera).
    scene_unit : {'kelvin', 'celsius'}
        The unit of a file's or an array's temperatures; ``'celsius'`` adds 273.15 K and says so in the scene's
        :meth:`~Scene.summary`. Temperatures whose hottest value is below :data:`MIN_HOTTEST_K` are refused.
    **params
        Passed to the scene's constructor (e.g. ``temperature_k=310`` for ``uniform``) or to
        :func:`load_scene_file` (``t_range_k``, ``frame_rate_hz``).

    Returns
    -------
    Scene
    """
    if isinstance(name, Scene):
        return name
    unit = _scene_unit(scene_unit)
    g = geometry or SceneGeometry()
    if isinstance(name, (list, tuple)):  # nested lists of temperatures: an array
        name = np.asarray(name)
        if name.dtype.kind not in "iuf":
            raise InputError("scene", f"a list of {name.dtype}", "temperatures (nested lists of numbers, kelvin)")
    if isinstance(name, np.ndarray):
        return _array_scene(name, g, unit, **params)
    if not isinstance(name, (str, Path)):
        raise InputError("scene", type(name).__name__, "a scene name, a file, a Scene or an array of temperatures")
    key = str(name).strip()
    prefix, colon, spec = key.partition(":")
    family = SCENE_FAMILIES.get(prefix.lower()) if colon else None
    if unit != "kelvin" and (key.lower() in SCENES or key.lower().startswith("skimage:") or family):
        raise InputError("scene_unit", scene_unit, f"kelvin for the built-in scene '{key}' (a unit applies to a "
                         "file or an array of temperatures)")
    try:
        if key.lower() in SCENES:
            return SCENES[key.lower()][0](g, **params)
        if key.lower().startswith("skimage:"):
            return image_scene(key.split(":", 1)[1], g, **params)
        if family is not None:
            return family[0](spec, g, **params)
    except TypeError as e:
        raise InputError("scene parameters", sorted(params), f"parameters accepted by scene '{key}'",
                         detail=str(e)) from None
    p = Path(key)
    if p.suffix and (p.exists() or "/" in key or "\\" in key or p.suffix.lower() in
                     (".npy", ".npz", ".tif", ".tiff", ".png", ".jpg", ".jpeg", ".bmp")):
        return load_scene_file(p, g, scene_unit=unit, **params)
    raise InputError("scene", key, "one of " + ", ".join([*sorted(SCENES), "skimage:NAME", *list_scene_families()])
                     + ", or an existing file")


def _array_scene(temp: np.ndarray, g: SceneGeometry, scene_unit: str, *,
                 t_range_k: tuple[float, float] = (288.0, 312.0), **params: Any) -> RasterScene:
    """An array of temperatures as a :class:`RasterScene` over the perifoveal field, checked as a file's are."""
    source = f"array of shape {temp.shape}"
    if not np.issubdtype(temp.dtype, np.number) or np.iscomplexobj(temp):
        raise InputError("scene", source, "real-valued temperatures in kelvin")
    _one_channel(temp.shape, t_range_k)
    t, conversion = _in_kelvin(temp, scene_unit, source, t_range_k)
    try:
        return RasterScene(**{"half_width_rad": g.half, "name": "array", "description": f"an {source}",
                              **params, "temperature_k": t, "conversion": conversion})
    except TypeError as e:
        raise InputError("scene parameters", sorted(params), "parameters accepted by RasterScene",
                         detail=str(e)) from None

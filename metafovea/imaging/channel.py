"""The two imaging channels on the sensor crop: geometry, field angles and relative illumination.

Both lenses share the optical axis and image onto the same focal plane, which a relay of
magnification ``m`` images onto the sensor. A sensor pixel of pitch ``p`` therefore covers
``p / m`` at the focal plane; at focal-plane position ``(x, y)`` (0 at the axis, the crop centre) the
channel with focal length ``f`` sees field angles ``(atan(x / f), atan(y / f))`` (chief ray through
the lens centre). The foveal channel (``f1 = 150 mm``, x-polarised) thus sees the centre of the
perifoveal channel's (``f2 = 25 mm``, y-polarised) field magnified ``f1 / f2 = 6`` times.

Relative illumination: ``cos^4`` of the field angle, times the part of the bundle the other lens' aperture ring
lets through and the posts' change at oblique incidence (:func:`relative_illumination_map`).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from metafovea.config import LensDesign, SystemDesign
from metafovea.errors import check_int, check_positive


@dataclass(frozen=True)
class Channel:
    """One imaging channel on the sensor crop."""

    name: str  # "foveal" or "perifoveal"
    lens: LensDesign
    focal_length_um: float  # lens to focal plane
    focal_pitch_um: float  # sensor pitch / relay magnification
    shape: tuple[int, int]

    @property
    def polarization(self) -> str:
        return self.lens.polarization

    @property
    def ifov_rad(self) -> float:
        """Angle per pixel at the axis."""
        return self.focal_pitch_um / self.focal_length_um

    @property
    def half_fov_rad(self) -> tuple[float, float]:
        """(vertical, horizontal) half field of view to the crop's edges."""
        H, W = self.shape
        return (math.atan(0.5 * H * self.focal_pitch_um / self.focal_length_um),
                math.atan(0.5 * W * self.focal_pitch_um / self.focal_length_um))

    @property
    def corner_field_rad(self) -> float:
        H, W = self.shape
        return math.atan(0.5 * math.hypot(H, W) * self.focal_pitch_um / self.focal_length_um)

    @property
    def radius_um(self) -> float:
        return self.lens.radius_um

    @property
    def na(self) -> float:
        return self.lens.na

    def positions_um(self, n: int, ss: int, margin: int, coarse: float = 1.0) -> np.ndarray:
        """Sample positions (um, focal plane) along one axis: ``n`` pixels, ``ss`` samples each, plus
        ``margin`` samples on both sides; pixel centres are symmetric about 0."""
        step = self.focal_pitch_um / ss * coarse
        m = int(round(n * ss / coarse))
        k = np.arange(-margin, m + margin, dtype=np.float64)
        return (k + 0.5 - m / 2.0) * step

    def summary(self) -> dict[str, Any]:
        hv, hh = self.half_fov_rad
        return {"name": self.name, "polarization": self.polarization, "f_mm": self.focal_length_um / 1000,
                "diameter_mm": self.lens.diameter_um / 1000, "na": self.na,
                "focal_plane_pitch_um": self.focal_pitch_um, "ifov_mrad": 1000 * self.ifov_rad,
                "fov_deg": [2 * math.degrees(hv), 2 * math.degrees(hh)]}


def channels_for(system: SystemDesign, *, pixel_pitch_um: float | None = None,
                 relay_magnification: float | None = None,
                 shape: tuple[int, int] | None = None) -> tuple[Channel, Channel]:
    """The (foveal, perifoveal) channels of ``system`` on the sensor's working crop."""
    pitch = check_positive("pixel_pitch_um", pixel_pitch_um if pixel_pitch_um is not None
                           else system.sensor.pixel_pitch_um, "um", hi=1000)
    m = check_positive("relay_magnification", relay_magnification if relay_magnification is not None
                       else system.relay_magnification, hi=10)
    shp = tuple(int(v) for v in (shape or system.sensor.crop))
    for v in shp:
        check_int("sensor crop (rows, columns)", v, 8, 8192)
    fp = pitch / m
    f1, f2 = system.lens_to_sensor_um
    from metafovea.optics.psf import defocus_note  # optics stage (above imaging): allowed

    for lens, z in ((system.foveal, f1), (system.perifoveal, f2)):
        note = defocus_note(lens, z)
        if note:
            warnings.warn(note, UserWarning, stacklevel=2)
    return (Channel("foveal", system.foveal, f1, fp, shp), Channel("perifoveal", system.perifoveal, f2, fp, shp))


def relative_illumination_map(ch: Channel,
                              field_factor: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """``cos^4`` of the field angle at each pixel centre, ``(H, W)``, times ``field_factor(tan_x, tan_y)`` when
    given (the other lens' aperture ring and the posts at oblique incidence:
    :meth:`metafovea.optics.train.ChannelTrain.field_factor`)."""
    H, W = ch.shape
    ty = (ch.positions_um(H, 1, 0) / ch.focal_length_um)[:, None]
    tx = (ch.positions_um(W, 1, 0) / ch.focal_length_um)[None, :]
    ri = 1.0 / (1.0 + tx ** 2 + ty ** 2) ** 2
    return ri if field_factor is None else ri * field_factor(tx, ty)

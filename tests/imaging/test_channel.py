"""metafovea.imaging.channel: the two channels' geometry on the sensor crop and the relative illumination."""

from __future__ import annotations

import math

import numpy as np
import pytest

from metafovea.config import SystemDesign
from metafovea.errors import InputError
from metafovea.imaging.channel import channels_for, relative_illumination_map


# ---------------------------------------------------------------------------------------------
# physics and geometry
# ---------------------------------------------------------------------------------------------
def test_channel_geometry_paper():
    c1, c2 = channels_for(SystemDesign.paper())
    assert c1.focal_pitch_um == pytest.approx(34.0)
    assert c2.ifov_rad / c1.ifov_rad == pytest.approx(6.0)
    assert math.degrees(2 * c2.half_fov_rad[1]) == pytest.approx(22.27, abs=0.05)
    c1b, _ = channels_for(SystemDesign.paper(), pixel_pitch_um=24.0, relay_magnification=0.3)
    assert c1b.focal_pitch_um == pytest.approx(80.0)


def test_relative_illumination_is_cos4_of_the_chief_ray_angle():
    _, c2 = channels_for(SystemDesign.paper(), shape=(20, 30))
    ri = relative_illumination_map(c2)
    assert ri.shape == (20, 30)
    # pixel centres symmetric about the axis, (k + 0.5 - n / 2) pitches from it
    y = (np.arange(20) + 0.5 - 10) * c2.focal_pitch_um
    x = (np.arange(30) + 0.5 - 15) * c2.focal_pitch_um
    theta = np.arctan(np.hypot(x[None, :], y[:, None]) / c2.focal_length_um)
    np.testing.assert_allclose(ri, np.cos(theta) ** 4, rtol=1e-12)
    np.testing.assert_allclose(ri, ri[::-1, ::-1], rtol=1e-12)
    assert ri.max() < 1.0 and ri.min() == pytest.approx(math.cos(c2.corner_field_rad) ** 4, rel=1e-2)


def test_channel_crop_too_small_is_named():
    with pytest.raises(InputError, match="sensor crop"):
        channels_for(SystemDesign.paper(), shape=(4, 64))


def test_sensor_beyond_the_depth_of_focus_is_warned_about():
    import dataclasses
    import warnings

    paper = SystemDesign.paper()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        channels_for(paper)  # the paper's distances are the focal lengths
    moved = dataclasses.replace(paper, lens_to_sensor_um=(paper.lens_to_sensor_um[0], 25_100.0))
    with pytest.warns(UserWarning, match=r"perifoveal.*\+100.0 um, beyond the depth of focus \+-20.0 um"):
        _, c2 = channels_for(moved)
    assert c2.focal_length_um == 25_100.0

"""metafovea.imaging.render: one channel's noise-free image (kernels, field patches, far haze, pixel integration,
relative illumination), full and incremental."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.imaging.channel import channels_for, relative_illumination_map
from metafovea.imaging.kernels import ExplicitPSF, airy_provider, build_channel_optics, gaussian_kernel
from metafovea.imaging.render import ChannelRenderer
from metafovea.imaging.scene import RasterScene, SceneGeometry, make_scene
from metafovea.radiometry import BandRadiance


# ---------------------------------------------------------------------------------------------
# physics references
# ---------------------------------------------------------------------------------------------
def test_uniform_scene_renders_to_its_radiance_kernel_and_haze_conserve_power(small_system):
    """A uniform blackbody fills every pixel with its band radiance L(T): the kernel, the near and the far haze
    together carry all the power; relative illumination then multiplies by cos^4."""
    s = small_system(40)
    br = BandRadiance.for_system(s)
    sc = make_scene("uniform", temperature_k=310.0)
    for ch in channels_for(s, shape=(40, 40)):
        o = build_channel_optics(ch, airy_provider, br, ss=2)
        assert o.far_kernel is not None  # the far-haze path is part of the sum
        img = ChannelRenderer(sc, o, br, relative_illumination=False).render(0.0)
        np.testing.assert_allclose(img, float(br(310.0)), rtol=1e-9)
        img_ri = ChannelRenderer(sc, o, br).render(0.0)
        np.testing.assert_allclose(img_ri, float(br(310.0)) * relative_illumination_map(ch), rtol=1e-9)


def test_a_point_source_is_imaged_as_the_kernel(small_system):
    """A hot pixel-sized square seen through a kernel K gives K (box-integrated) around it: the image of a point
    is the PSF, centred on the chief ray."""
    s = small_system(32)
    br = BandRadiance.for_system(s)
    _, ch2 = channels_for(s, shape=(32, 32))
    k = gaussian_kernel(1.2, 9)
    o = build_channel_optics(ch2, ExplicitPSF({"foveal": k, "perifoveal": k}), br, ss=1)
    # a raster whose one hot pixel (row 16, column 16 of 32) is exactly the sensor pixel there
    t = np.full((32, 32), 300.0)
    t[16, 16] = 330.0
    half = np.arctan(16 * ch2.focal_pitch_um / ch2.focal_length_um)
    sc = RasterScene(temperature_k=t, half_width_rad=half, background_k=300.0, emissivity=1.0)
    img = ChannelRenderer(sc, o, br, relative_illumination=False).render(0.0)
    bump = img - float(br(300.0))
    peak = np.unravel_index(np.argmax(bump), bump.shape)
    assert peak == (16, 16)
    local = bump[12:21, 12:21] / bump[12:21, 12:21].sum()
    assert np.abs(local - k).max() < 1e-6 * k.max()  # measured 3e-14


# ---------------------------------------------------------------------------------------------
# incremental rendering of video scenes
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["hand", "parking-lot", "heater-10s"])
def test_incremental_video_rendering_equals_full_rendering(name, small_system):
    s = small_system(40)
    br = BandRadiance.for_system(s)
    _, ch2 = channels_for(s, shape=(40, 40))
    g = SceneGeometry(fov_rad=2 * ch2.half_fov_rad[1], duration_s=4.0)
    sc = make_scene(name, g)
    opt = build_channel_optics(ch2, airy_provider, br, ss=2)
    assert opt.far_kernel is not None  # the haze path is exercised too
    inc = ChannelRenderer(sc, opt, br)
    full = ChannelRenderer(sc, opt, br)
    full.incremental = False
    assert inc.incremental
    for t in (0.0, 1.7, 3.9):
        np.testing.assert_allclose(inc.render(t), full.render(t), rtol=1e-9, atol=1e-9 * full.render(t).max())

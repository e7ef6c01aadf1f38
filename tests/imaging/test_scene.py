"""metafovea.imaging.scene: scenes over field angle and time, and the files and pictures they load."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import pytest

from metafovea.errors import InputError
from metafovea.imaging.scene import (
    SKIMAGE_IMAGES,
    CoilHeater,
    RasterScene,
    Scene,
    SceneGeometry,
    image_scene,
    list_scenes,
    load_scene_file,
    make_scene,
)


# ---------------------------------------------------------------------------------------------
# physics and geometry
# ---------------------------------------------------------------------------------------------
def test_scene_is_sampled_at_any_resolution_star_contrast_in_fovea():
    sc = make_scene("siemens-star")
    g = SceneGeometry()
    # a ring inside the foveal field still resolves the spokes when sampled finely
    phi = np.linspace(0, 2 * np.pi, 3600, endpoint=False)
    r = 0.5 * g.fovea_half
    temp, _ = sc.sample(r * np.cos(phi), r * np.sin(phi))
    changes = np.count_nonzero(np.diff(temp) != 0)
    assert changes == pytest.approx(2 * 36, abs=2)


def test_heater_transients():
    h = CoilHeater(on_duration_s=5.0, t_on_s=1.0)
    ts = np.linspace(0, 20, 201)
    tc = np.array([h.coil_temperature(t) for t in ts])
    assert tc[0] == pytest.approx(h.wall_k)
    on = (ts >= 1) & (ts <= 6)
    assert np.all(np.diff(tc[on]) > 0)  # heating
    assert np.all(np.diff(tc[ts > 6]) < 0)  # cooling
    assert h.coil_temperature(6.0) == pytest.approx(h.wall_k + h.dt_max_k * (1 - math.exp(-5 / h.tau_heat_s)))
    assert make_scene("heater-20s").on_duration_s == 20.0


def test_builtin_scenes_render_plausible_temperatures():
    g = SceneGeometry()
    ax, ay = np.meshgrid(np.linspace(-g.half, g.half, 40), np.linspace(-g.half, g.half, 40))
    for name in list_scenes():
        sc = make_scene(name, g)
        for t in (0.0, 3.0):
            temp, eps = sc.sample(ax, ay, t)
            assert temp.shape == ax.shape and np.all((temp > 200) & (temp < 700)), name
            assert np.all((eps > 0) & (eps <= 1)), name


# ---------------------------------------------------------------------------------------------
# files, pictures and bad input
# ---------------------------------------------------------------------------------------------
def test_bad_scene_inputs():
    with pytest.raises(InputError, match="scene"):
        make_scene("no-such-scene")
    with pytest.raises(InputError, match="scene"):
        make_scene("missing_file.npy")
    with pytest.raises(InputError, match="temperature"):
        RasterScene(temperature_k=np.full((8, 8), -5.0))


def test_scene_from_npy_file(tmp_path):
    t = np.full((32, 32), 300.0)
    t[12:20, 12:20] = 330.0
    np.save(tmp_path / "hot.npy", t)
    sc = make_scene(str(tmp_path / "hot.npy"))
    temp, _ = sc.sample(np.array([0.0, 0.9 * sc.half_width_rad]), np.array([0.0, 0.0]))
    assert temp[0] == pytest.approx(330.0) and temp[1] == pytest.approx(300.0)
    np.save(tmp_path / "neg.npy", t - 400)
    with pytest.raises(InputError, match="temperature"):
        make_scene(str(tmp_path / "neg.npy"))


def test_nan_emissivity_in_scene_file_is_refused(tmp_path):
    """A NaN emissivity in a scene (file, one raster pixel, or a scalar) was silent NaN frames; now an input error."""
    p = tmp_path / "s.npz"
    np.savez(p, temperature_k=np.full((20, 20), 300.0), emissivity=np.full((20, 20), np.nan))
    with pytest.raises(InputError, match="emissivity"):
        load_scene_file(p)
    e = np.full((20, 20), 0.9)
    e[3, 4] = np.nan  # one bad pixel is enough
    with pytest.raises(InputError, match="emissivity"):
        RasterScene(temperature_k=np.full((20, 20), 300.0), emissivity=e)
    with pytest.raises(InputError, match="emissivity"):
        RasterScene(temperature_k=np.full((20, 20), 300.0), emissivity=float("nan"))


def test_scene_returning_nan_emissivity_is_refused_when_sampled():
    """NaN emissivity was silent NaN frames: a scene whose sampling returns NaN is refused when sampled."""
    @dataclass(frozen=True)
    class Bad(Scene):
        name: str = "bad"

        def _sample(self, ax, ay, t):
            return np.full(ax.shape, 300.0), np.full(ax.shape, np.nan)

    with pytest.raises(InputError, match="emissivity"):
        Bad().sample(np.zeros((3, 3)), np.zeros((3, 3)))


def test_all_nan_temperature_raster_gives_one_clean_error(tmp_path):
    """A bad scene file is one input error: an all-NaN temperature raster too, with no numpy "All-NaN slice"
    RuntimeWarning on the way."""
    p = tmp_path / "nan.npy"
    np.save(p, np.full((8, 8), np.nan))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "All-NaN slice" RuntimeWarning on the way
        with pytest.raises(InputError, match="temperature_k"):
            make_scene(str(p))


def test_scene_npz_with_array_half_width_is_an_input_error(tmp_path):
    """An array half_width_deg in a scene .npz was not a one-line input error; a 1-element array is a scalar."""
    p = tmp_path / "hw.npz"
    np.savez(p, temperature_k=np.full((10, 10), 300.0), half_width_deg=np.array([1.0, 2.0]))
    with pytest.raises(InputError, match="half_width_deg"):
        load_scene_file(p)
    np.savez(p, temperature_k=np.full((10, 10), 300.0), half_width_deg=np.array([[3.0]]))
    assert load_scene_file(p).half_width_rad == pytest.approx(np.radians(3.0))


@pytest.mark.parametrize("content", [b"not a png", b""])
def test_unreadable_picture_gives_a_one_line_error(tmp_path, content):
    """An unreadable picture was not a one-line input error naming the scene (some readers explain themselves
    over several lines)."""
    p = tmp_path / "bad.png"
    p.write_bytes(content)
    with pytest.raises(InputError) as e:
        load_scene_file(p)
    assert "\n" not in str(e.value) and "scene" in str(e.value)


def test_truncated_scene_npz_is_an_input_error(tmp_path):
    """A truncated/corrupt .npz scene file was a BadZipFile traceback; now an input error naming the scene."""
    p = tmp_path / "s.npz"
    np.savez(p, temperature_k=np.full((20, 20), 300.0))
    p.write_bytes(p.read_bytes()[:300])
    with pytest.raises(InputError, match="scene"):
        load_scene_file(p)


def test_every_advertised_skimage_picture_loads_or_is_an_input_error(monkeypatch):
    """skimage:motorcycle (advertised) was an AttributeError traceback: the loader is stereo_motorcycle."""
    from skimage import data

    sc = image_scene("motorcycle")
    assert sc.temperature_k.ndim == 2 and sc.temperature_k.shape[0] > 2
    for name in SKIMAGE_IMAGES:  # names only: the pictures themselves are not loaded here
        assert hasattr(data, name) or hasattr(data, f"stereo_{name}"), name

    def offline():
        raise OSError("cannot download")

    monkeypatch.setattr(data, "camera", offline)
    with pytest.raises(InputError, match="skimage:camera"):
        image_scene("camera")


# ---------------------------------------------------------------------------------------------
# the unit and the channels of a file or an array of temperatures
# ---------------------------------------------------------------------------------------------
def _room_celsius(shape=(24, 32)) -> np.ndarray:
    """A room in degrees Celsius (20-35), as a camera's software exports it."""
    t = np.full(shape, 21.0)
    t[8:16, 10:22] = 34.5  # a person
    return t


def test_float_rgb_tiff_is_refused_as_one_channel_in_kelvin(tmp_path):
    """A float RGB TIFF was read as a video of H frames, W pixels by 3 (a scene 3 pixels tall) without a word."""
    import imageio.v3 as iio
    import tifffile

    rgb = np.random.default_rng(0).random((24, 32, 3)).astype(np.float32)
    tifffile.imwrite(tmp_path / "rgb.tif", rgb, photometric="rgb")
    iio.imwrite(tmp_path / "rgb_imageio.tif", rgb)
    tifffile.imwrite(tmp_path / "planar.tif", np.moveaxis(rgb, -1, 0), photometric="rgb", planarconfig="separate")
    for name in ("rgb.tif", "rgb_imageio.tif", "planar.tif"):
        with pytest.raises(InputError, match=r"one channel \(a temperature map in kelvin\)") as e:
            make_scene(str(tmp_path / name))
        msg = str(e.value)
        assert "\n" not in msg and e.value.parameter == "temperature_k" and "24, 32" in e.value.value
        assert "3 samples per pixel (an RGB image)" in msg
        assert "8- or 16-bit PNG or TIFF" in msg  # how to convert it
    assert "photometric='minisblack'" in str(pytest.raises(InputError, load_scene_file, tmp_path / "planar.tif").value)
    # an (h, w, 3) array holds colour samples too; a grey stack written as such is a video
    np.save(tmp_path / "rgb.npy", 300.0 + rgb)
    with pytest.raises(InputError, match=r"\(24, 32, 3\)' is invalid.*\(3 samples per pixel"):
        make_scene(str(tmp_path / "rgb.npy"))
    with pytest.raises(InputError, match="one channel"):
        make_scene(300.0 + rgb)
    tifffile.imwrite(tmp_path / "video.tif", 300.0 + rgb[..., 0][None].repeat(4, 0), photometric="minisblack")
    assert make_scene(str(tmp_path / "video.tif")).temperature_k.shape == (4, 24, 32)


def test_celsius_scene_is_refused_unless_its_unit_is_given(tmp_path):
    """A scene in degrees Celsius (20-35) was simulated as 20-35 K (a scene colder than liquid nitrogen) without a
    word; now an error naming the unit and the keyword that converts it, and with scene_unit='celsius' the same
    scene as in kelvin, the conversion stated in its summary."""
    import tifffile

    c = _room_celsius()
    np.save(tmp_path / "room.npy", c)
    tifffile.imwrite(tmp_path / "room.tif", c.astype(np.float32))
    np.savez(tmp_path / "room.npz", temperature_k=c)
    for name in ("room.npy", "room.tif", "room.npz"):
        with pytest.raises(InputError, match="temperatures in kelvin") as e:
            make_scene(str(tmp_path / name))
        assert "look like degrees Celsius: scene_unit='celsius' converts them, +273.15 K" in str(e.value)
        assert e.value.parameter == "temperature_k" and e.value.value == "values 21 to 34.5"
        sc = make_scene(str(tmp_path / name), scene_unit="celsius")
        np.testing.assert_array_equal(sc.temperature_k, c + 273.15)  # 21 and 34.5: exact in float32 too
        assert sc.summary()["conversion"] == "degrees Celsius converted to kelvin: T_K = T_C + 273.15"
    kelvin = make_scene(c + 273.15)
    assert "conversion" not in kelvin.summary()
    np.testing.assert_array_equal(make_scene(c, scene_unit="celsius").temperature_k, kelvin.temperature_k)
    with pytest.raises(InputError, match="look like degrees Celsius"):
        make_scene(c)
    with pytest.raises(InputError, match="values -300 to -260 degrees Celsius' is invalid.*-26.85 to 13.15 K"):
        make_scene(np.linspace(-300, -260, 64).reshape(8, 8), scene_unit="celsius")


def test_scene_unit_is_checked_and_applies_to_temperatures_only(tmp_path):
    from skimage import io as skio

    np.save(tmp_path / "hot.npy", np.full((8, 8), 310.0))
    with pytest.raises(InputError, match="scene_unit = 'fahrenheit'.*kelvin or celsius"):
        make_scene(str(tmp_path / "hot.npy"), scene_unit="fahrenheit")
    with pytest.raises(InputError, match="scene_unit = 'celsius'.*built-in scene 'bars'"):
        make_scene("bars", scene_unit="celsius")
    picture = (np.random.default_rng(1).random((16, 16, 3)) * 255).astype(np.uint8)
    skio.imsave(tmp_path / "photo.png", picture, check_contrast=False)
    with pytest.raises(InputError, match="scene_unit = 'celsius'.*kelvin for a picture"):
        make_scene(str(tmp_path / "photo.png"), scene_unit="celsius")
    # a picture is mapped to temperatures as documented, and its summary says so
    sc = make_scene(str(tmp_path / "photo.png"))
    assert 288.0 <= sc.temperature_k.min() and sc.temperature_k.max() <= 312.0
    assert sc.summary()["conversion"].startswith("a picture: its luminance")


def test_a_picture_s_levels_and_a_cold_pixel_are_named(tmp_path):
    """Float levels in 0-1 are a picture, not kelvin; a scene of room temperatures with a pixel at 20 K is warned
    about (degrees Celsius read as kelvin, when the scene also holds something above 200 degrees Celsius)."""
    levels = np.random.default_rng(2).random((16, 16))
    with pytest.raises(InputError, match="look like a picture's levels: save one channel"):
        make_scene(levels)
    t = np.full((16, 16), 295.0)
    t[0, 0] = 20.0
    with pytest.warns(UserWarning, match=r"coldest value, 20 K, is colder than any sky.*scene_unit='celsius'"):
        make_scene(t)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        make_scene(np.full((16, 16), 250.0))  # a clear sky: a scene


@pytest.mark.parametrize("shape", [(7, 9), (1, 5), (2, 2)])
def test_bilinear_grid_is_map_coordinates_on_a_grid(shape):
    """The one-axis-at-a-time interpolation against scipy's order-1 map_coordinates on the grid, both edge modes,
    with indices on, just outside and far outside the edges."""
    from scipy.ndimage import map_coordinates

    from metafovea.imaging.scene import bilinear_grid

    rng = np.random.default_rng(1)
    h, w = shape
    a = rng.normal(size=shape)
    r = np.concatenate([rng.uniform(-2, h + 1, 30), [0, h - 1, -1e-9, h - 1 + 1e-9]])
    c = np.concatenate([rng.uniform(-2, w + 1, 20), [0, w - 1, -1e-9, w - 1 + 1e-9]])
    yy, xx = np.meshgrid(r, c, indexing="ij")
    for cval, mode in ((3.5, "constant"), (None, "nearest")):
        ref = map_coordinates(a, [yy.ravel(), xx.ravel()], order=1, mode=mode, cval=cval or 0.0).reshape(yy.shape)
        np.testing.assert_allclose(bilinear_grid(a, r, c, cval), ref, rtol=0, atol=1e-12)

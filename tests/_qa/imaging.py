"""QA regression tests for imaging, split out of tests/test_qa_*.py: merge each into its subject test file
(keep the bug sentence as its docstring), then delete this file."""

from __future__ import annotations
import warnings
from dataclasses import dataclass
import numpy as np
import pytest
from metafovea.errors import InputError
from metafovea.imaging.scene import RasterScene, Scene, load_scene_file, make_scene




def test_nan_emissivity_in_scene_file_is_refused(tmp_path):
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
    @dataclass(frozen=True)
    class Bad(Scene):
        name: str = "bad"

        def _sample(self, ax, ay, t):
            return np.full(ax.shape, 300.0), np.full(ax.shape, np.nan)

    with pytest.raises(InputError, match="emissivity"):
        Bad().sample(np.zeros((3, 3)), np.zeros((3, 3)))


def test_all_nan_temperature_raster_gives_one_clean_error(tmp_path):
    p = tmp_path / "nan.npy"
    np.save(p, np.full((8, 8), np.nan))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "All-NaN slice" RuntimeWarning on the way
        with pytest.raises(InputError, match="temperature_k"):
            make_scene(str(p))


def test_scene_npz_with_array_half_width_is_an_input_error(tmp_path):
    p = tmp_path / "hw.npz"
    np.savez(p, temperature_k=np.full((10, 10), 300.0), half_width_deg=np.array([1.0, 2.0]))
    with pytest.raises(InputError, match="half_width_deg"):
        load_scene_file(p)
    np.savez(p, temperature_k=np.full((10, 10), 300.0), half_width_deg=np.array([[3.0]]))
    assert load_scene_file(p).half_width_rad == pytest.approx(np.radians(3.0))


@pytest.mark.parametrize("content", [b"not a png", b""])
def test_unreadable_picture_gives_a_one_line_error(tmp_path, content):
    p = tmp_path / "bad.png"
    p.write_bytes(content)
    with pytest.raises(InputError) as e:
        load_scene_file(p)
    assert "\n" not in str(e.value) and "scene" in str(e.value)


def test_large_psf_window_is_bounded_and_airy_kernel_is_computed_in_blocks(tmp_path, capsys):
    """--psf-size up to 4097 was accepted and asked the Airy model for a (4097*7)^2 grid (tens of GB)."""
    from scipy.special import j1

    from metafovea.cli import main
    from metafovea.imaging.system import MAX_PSF_SIZE, airy_kernel

    assert main(["simulate", "--psf", "airy", "--psf-size", str(MAX_PSF_SIZE + 2), "--frames", "1",
                 "--out", str(tmp_path / "m.npz")]) == 2
    err = capsys.readouterr().err
    assert "--psf-size" in err and not (tmp_path / "m.npz").exists()
    # block-wise evaluation (size 251 > one block) equals the plain one
    size, sub, pitch, lam, n_f = 251, 7, 3.0, 10.0, 2.0
    u = (np.arange(size * sub) + 0.5) / sub - size / 2.0
    x = u * pitch
    v = np.pi * np.hypot(x[None, :], x[:, None]) / (lam * n_f)
    a = np.where(v > 1e-9, (2 * j1(v) / np.where(v > 1e-9, v, 1.0)) ** 2, 1.0)
    ref = a.reshape(size, sub, size, sub).mean(axis=(1, 3)) / (4.0 / np.pi * (lam * n_f) ** 2 / pitch ** 2)
    np.testing.assert_allclose(airy_kernel(n_f, lam, pitch, size, sub), ref, rtol=1e-12, atol=1e-15)


def test_a_sequence_that_cannot_fit_in_memory_is_refused_up_front(monkeypatch):
    """--frames 100000 (allowed by the range) was an out-of-memory kill at 290 x 290; now a clear error
    that says how many frames fit, raised before the PSFs are built."""
    import importlib

    from metafovea.config import SystemDesign

    sim = importlib.import_module("metafovea.imaging.simulate")  # the package exports a function of that name

    monkeypatch.setattr(sim, "_available_memory_bytes", lambda: 200 * 2**20)  # a 200 MiB machine
    monkeypatch.setattr(sim, "resolve_provider", lambda *a, **k: pytest.fail("work started"), raising=False)
    with pytest.raises(InputError, match="at most about") as e:
        sim.simulate(SystemDesign.paper(), "bars", frames=1000, psf="airy")  # 1000 x 290 x 290 x 4 B x 2 > 160 MiB
    assert e.value.parameter == "frames"
    with pytest.raises(InputError, match="frames"):  # video scenes also keep (T, H, W) truth images
        sim.simulate(SystemDesign.paper(), "hand", frames=300, psf="airy")
    sim._check_memory(96, (290, 290), video=True, available=2**30)  # the default fits in 1 GiB


def test_every_advertised_skimage_picture_loads_or_is_an_input_error(monkeypatch):
    """skimage:motorcycle (advertised) was an AttributeError traceback: the loader is stereo_motorcycle."""
    from skimage import data

    from metafovea.imaging.scene import SKIMAGE_IMAGES, image_scene

    sc = image_scene("motorcycle")
    assert sc.temperature_k.ndim == 2 and sc.temperature_k.shape[0] > 2
    for name in SKIMAGE_IMAGES:  # names only: the pictures themselves are not loaded here
        assert hasattr(data, name) or hasattr(data, f"stereo_{name}"), name

    def offline():
        raise OSError("cannot download")

    monkeypatch.setattr(data, "camera", offline)
    with pytest.raises(InputError, match="skimage:camera"):
        image_scene("camera")


def test_small_crop_errors_name_the_crop_and_where_fpn_rank_comes_from():
    from metafovea.imaging.sensor import SensorModel

    with pytest.raises(InputError, match="sensor crop"):
        SensorModel(shape=(7, 64))
    with pytest.raises(InputError, match="--fpn-rank") as e:
        SensorModel(shape=(12, 40), fpn_rank=20)
    assert e.value.parameter == "fpn_rank" and "12" in e.value.allowed
    assert SensorModel(shape=(12, 40), fpn_rank=12).fpn_rank == 12


def test_simulate_never_overwrites_its_scene_file_even_with_force(tmp_path, monkeypatch, capsys):
    from metafovea.cli import main

    monkeypatch.chdir(tmp_path)
    np.savez("s.npz", temperature_k=np.full((20, 20), 300.0))
    before = (tmp_path / "s.npz").read_bytes()
    assert main(["simulate", "--scene", "s.npz", "--out", "s.npz", "--force", "--frames", "1", "--psf", "airy"]) == 2
    assert "--out" in capsys.readouterr().err and (tmp_path / "s.npz").read_bytes() == before
    np.save("k.npy", np.full((20, 20), 300.0))
    import tifffile

    tifffile.imwrite("k.tif", np.full((20, 20), 300.0, np.float32))  # the TIFF written next to k.npz
    assert main(["simulate", "--scene", "k.tif", "--out", "k.npz", "--force", "--frames", "1", "--psf", "airy"]) == 2
    assert "k.tif" in capsys.readouterr().err


def test_truncated_scene_npz_is_an_input_error(tmp_path):
    p = tmp_path / "s.npz"
    np.savez(p, temperature_k=np.full((20, 20), 300.0))
    p.write_bytes(p.read_bytes()[:300])
    with pytest.raises(InputError, match="scene"):
        load_scene_file(p)

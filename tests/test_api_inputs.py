"""The Python API on arguments a careful user gets wrong (a hunt through the public functions): each is the project's
InputError naming the argument, never numpy's, scipy's or Python's own error, a typo silently ignored, or work done
on a value that can only fail later."""

from __future__ import annotations

import numpy as np
import pytest

import metafovea as mf
from metafovea.errors import InputError
from metafovea.measurement import Measurement
from metafovea.optics import psf
from metafovea.reconstruct import lsq_known_alpha, reconstruct, video
from metafovea.recordings.convert import ImportOptions
from metafovea.recordings.timestamps import check_timing

Y = np.random.default_rng(0).random((8, 6, 6))
A = np.linspace(0.1, 0.9, 8)


@pytest.mark.parametrize("call,name", [
    (lambda: video(Y, A, windw=4), "windw"),  # ran with window 8
    (lambda: reconstruct(Y, A, "lsq", regularise="difference"), "regularise"),  # Python's TypeError
    (lambda: lsq_known_alpha(Y, A, saturation="x"), "saturation"),  # numpy's UFuncTypeError
    (lambda: lsq_known_alpha(Y, A, denoise="tv", denoise_kw={"foo": 1}), "foo"),
    (lambda: lsq_known_alpha(Y, A, noise_sigma="a"), "noise_sigma"),
    (lambda: lsq_known_alpha(Y, A, denoise="tv", noise_sigma=-1), "noise_sigma"),  # accepted, no denoising
    (lambda: lsq_known_alpha(Y, A, max_condition=0), "max_condition"),  # blamed on alpha
])
def test_solver_arguments(call, name):
    with pytest.raises(InputError) as e:
        call()
    assert e.value.parameter == name


def test_the_geometry_keywords_the_pipeline_passes_still_reach_lsq_videos():
    assert video(Y, A, window=4, scale=6.0, foveal_gain=0.3).x1.shape == (5, 6, 6)


def test_psf_arguments():
    lens = mf.SystemDesign.paper().perifoveal
    for kw, name in ((dict(center_um=(1.0,)), "center_um"), (dict(center_um=(np.nan, 0.0)), "center_um"),
                     (dict(post_set=42), "post_set")):
        with pytest.raises(InputError) as e:
            psf(lens, **kw)
        assert e.value.parameter == name
    with pytest.raises(InputError, match="a LensDesign"):
        psf("foveal")


def test_simulate_arguments_refused_before_the_work():
    system = mf.SystemDesign.paper()
    fast = dict(frames=2, psf="airy", optical_train=False, posts="ideal")
    for kw in (dict(polarizer_phase_deg=float("nan")), dict(t0_s=float("nan"))):  # all-NaN frames, blamed on them
        with pytest.raises(InputError) as e:
            mf.simulate(system, "siemens-star", **fast, **kw)
        assert e.value.parameter == next(iter(kw))
    for size in (0, 10):  # 0 ran the default size, 10 ran 11
        with pytest.raises(InputError) as e:
            mf.simulate(system, "siemens-star", **fast, psf_size_px=size)
        assert e.value.parameter == "psf_size_px"
    with pytest.raises(InputError, match="scene"):
        mf.simulate(system, [["a", "b"]], **fast)


def test_a_scene_given_as_nested_lists_is_an_array_of_temperatures():
    """It was turned into a string and looked up as a file name (OSError: File name too long)."""
    t = 300.0 + 5.0 * np.random.default_rng(1).random((32, 32))
    system = mf.SystemDesign.paper()
    fast = dict(frames=2, psf="airy", optical_train=False, posts="ideal")
    a, b = mf.simulate(system, t.tolist(), **fast), mf.simulate(system, t, **fast)
    np.testing.assert_array_equal(a.frames, b.frames)


def test_a_measurement_plots_the_frame_asked_or_refuses_it():
    m = Measurement(frames=Y.astype(np.float32), times_s=np.arange(8) / 12.0, alpha=A)
    with pytest.raises(InputError, match="frame"):
        m.plot(frame=99)  # showed frame 99 % 8 = 3
    m.plot(frame=-1)


def test_timing_and_import_options():
    fr = np.random.default_rng(0).random((12, 4, 4))
    t = np.arange(12) / 12.0
    for args, kw in (((fr, t[:5]), {}), ((fr[:5], t), {}), ((fr, np.r_[t[:11], np.nan]), {}),
                     ((fr, t), dict(frame_rate_hz=-12))):
        with pytest.raises(InputError):
            check_timing(*args, **kw)
    for kw in (dict(frame_rate_hz="12x"), dict(foveal_gain="a"), dict(calibration_gain="foo"),
               dict(time_unit="fortnight")):
        with pytest.raises(InputError) as e:
            ImportOptions(**kw)
        assert e.value.parameter == next(iter(kw))


def test_a_scene_hotter_than_the_radiance_table_is_refused_when_made():
    """validate --scene of 1e9 K ran the design and PSF stages (~3 s) and left an empty folder before its radiance
    was looked up and refused."""
    from metafovea.imaging.scene import make_scene

    with pytest.raises(InputError, match=r"\[0, 3000\] K"):
        make_scene(np.full((16, 16), 1e9))

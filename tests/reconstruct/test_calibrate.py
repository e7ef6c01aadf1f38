"""The camera calibrated from a recording (:mod:`metafovea.reconstruct.calibrate`) and what the pipeline does with
it, against references the calibration does not share: images made exactly by the foveal operator of the
classical solver (:func:`metafovea.reconstruct.synthetic.scene`), and the simulator's paper camera with device
constants the file does not state."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from metafovea.config import SystemDesign
from metafovea.errors import InputError
from metafovea.imaging import simulate
from metafovea.measurement import Measurement
from metafovea.reconstruct import reconstruct_measurement
from metafovea.reconstruct.calibrate import fit_foveal
from metafovea.reconstruct.synthetic import measure, polariser_alpha, scene


@pytest.mark.parametrize("rho", [1.0, 0.9, 1.05])
def test_the_amplitude_and_the_stated_geometry_from_exact_images(rho):
    """Images that satisfy the solver's own foveal operator exactly, with the difference image scaled as an
    amplitude ``rho`` would leave it: the fit finds ``rho``, the gain and offset, and keeps the stated geometry
    (nothing to move)."""
    x1, x2 = scene(288, lo=1700.0, hi=1760.0, foveal_gain=0.3, foveal_offset=700.0)
    f = fit_foveal((x1 + x2) / 2, (x1 - x2) * rho, scale=6.0, gain=0.3, offset=700.0)
    assert f.amplitude == pytest.approx(rho, abs=3 * f.se["amplitude"] + 1e-3)
    assert f.gain == pytest.approx(0.3, rel=0.01) and abs(f.scale - 6.0) < 0.005 * 6
    # the centre in perifoveal pixels (docs/measurement_format.md, "The foveal geometry"): 0.05 is 0.3 foveal px
    assert f.identified["amplitude"] and max(abs(c) for c in f.centre_px) < 0.05 and abs(f.rotation_deg) < 0.1


@pytest.mark.parametrize("side", ["x2", "x1"])
def test_the_channels_psf_difference_is_fitted_as_a_relative_blur(side):
    """The exact images with one channel blurred by a Gaussian of 0.6 perifoveal pixels (the perifoveal image, as
    its F/1 lens does; or the foveal one by as much, 3.6 foveal pixels): the fit finds the relative blur on the
    other side (+0.6: the foveal side blurred to match; -0.6: the perifoveal side) within 0.1 px, and alpha's
    amplitude within 1e-3."""
    from scipy.ndimage import gaussian_filter

    x1, x2 = scene(288, lo=1700.0, hi=1760.0, foveal_gain=0.3, foveal_offset=700.0)
    if side == "x2":
        x2 = gaussian_filter(x2, 0.6)
    else:
        x1 = gaussian_filter(x1, 6 * 0.6)
    f = fit_foveal((x1 + x2) / 2, (x1 - x2) * 0.9, scale=6.0, gain=0.3, offset=700.0)
    assert f.relative_blur_px == pytest.approx(0.6 if side == "x2" else -0.6, abs=0.1)
    assert f.amplitude == pytest.approx(0.9, abs=1e-3)


def test_bad_shapes_are_named():
    with pytest.raises(InputError, match="diff"):
        fit_foveal(np.zeros((48, 48)), np.zeros((40, 48)))
    with pytest.raises(InputError, match="scale"):
        fit_foveal(np.zeros((24, 24)), np.zeros((24, 24)), scale=6.0)


@pytest.fixture(scope="module")
def leaky():
    """The paper camera (10 um filter, diffraction-limited PSFs, its fixed pattern measured by the default 16 shutter
    frames) with a polariser
    that leaks 5 %, recorded free-running: the file states the extinction; the copy that does not is what a camera
    with a mis-specified polariser gives."""
    m = simulate(SystemDesign.paper(), "rooftop", frames=24, polarizer_mode="free", extinction=0.05, rng=1,
                 filter_enabled=True, psf="airy")
    meta = {k: v for k, v in m.meta.items() if k != "polarizer_extinction"}
    return m, dataclasses.replace(m, meta=meta)


def test_an_unstated_extinction_is_calibrated_from_the_recording(leaky):
    """Stated: the amplitude agrees with it and nothing changes. Unstated: the stated (ideal) polariser is 10 %
    off in alpha's amplitude; the calibration finds it within its error and alpha comes back within 2e-3, where
    the uncalibrated model is 10x worse."""
    stated, unstated = leaky
    a = reconstruct_measurement(stated, "alternating", window=24)
    assert not a.reconstruction.info["calibration"]["applied"] and a.alpha_mae < 1e-4
    b = reconstruct_measurement(unstated, "alternating", window=24)
    cal = b.reconstruction.info["calibration"]
    true = 0.95 / 1.05
    assert cal["applied"] and abs(cal["amplitude"] - true) <= max(3 * cal["se"]["amplitude"], 0.004)
    assert b.alpha_mae < 2e-3 and "extinction" in b.summary()["warnings"][0]
    c = reconstruct_measurement(unstated, "alternating", window=24, calibrate=False)
    assert c.alpha_mae > 10 * b.alpha_mae
    # without shutter frames the blind fixed-pattern estimate, made with the stated relation, hides the amplitude's
    # departure (it takes it for a pattern): the summary says the calibration could not see it
    d = reconstruct_measurement(unstated, "alternating", window=24, fpn="prior")
    assert any("blind" in w for w in d.summary()["warnings"])


def test_stuck_pixels_are_found_and_left_out():
    """Dead pixels (a constant in range) and saturated ones (stuck at one value) are left out without a map, and
    counted; the others separate as before."""
    x1, x2 = scene(48)
    a = polariser_alpha(12)
    Y = measure(x1, x2, a, sigma=0.01, rng=0, dtype=np.float32)
    Y[:, 5, 7] = 0.3
    Y[:, 20, 30] = 1.5
    m = Measurement(frames=Y, times_s=np.arange(12) / 12.0, alpha=a, truth_x1=x1, truth_x2=x2, meta={"scale": 6.0})
    res = reconstruct_measurement(m, "lsq")
    iv = res.reconstruction.info["invalid_samples"]
    assert iv["stuck_pixels"] == 2 and iv["count"] == 2 * 12
    assert np.isnan(res.reconstruction.x1[5, 7]) and np.isfinite(res.reconstruction.x1[6, 7])


def test_what_a_recording_cannot_tell_is_said():
    """A window shorter than half a polariser turn, and a fovea mostly saturated: each a warning naming why."""
    x1, x2 = scene(48)
    a = polariser_alpha(16)
    Y = measure(x1, x2, a, sigma=0.01, rng=0, dtype=np.float32)
    m = Measurement(frames=Y, times_s=np.arange(16) / 12.0, meta={"scale": 6.0, "polarizer_hz": 2.0})
    w = reconstruct_measurement(m, "alternating", window=16, solver={"strict": False}).summary()
    assert not any("half a turn" in x for x in w.get("warnings", []))
    with pytest.raises(InputError):  # two frames cannot fix the gauge at all
        reconstruct_measurement(m, "alternating", window=2)
    sat = Y.copy()
    sat[:, 18:30, 18:30] = 2.0
    m2 = Measurement(frames=sat, times_s=m.times_s, meta={"scale": 6.0, "saturation_dn": 2.0})
    s = reconstruct_measurement(m2, "alternating", window=16, solver={"strict": False}).summary()
    assert any("of the fovea's samples are saturated" in x for x in s["warnings"])


def test_a_nominal_alpha_that_disagrees_with_the_frames_is_said_and_refined():
    """A polariser stated as synchronised at phase 0.3 rad, frames made at 0.5 rad: lsq uses the nominal alpha, says
    it disagrees with the frames, and refine_alpha fits it from them."""
    x1, x2 = scene(96)
    a = polariser_alpha(24, phase=0.5)
    Y = measure(x1, x2, a, sigma=0.005, rng=0, dtype=np.float32)
    meta = {"scale": 6.0, "polarizer_hz": 2.0, "polarizer_mode": "sync", "polarizer_phase_deg": float(np.degrees(0.3))}
    m = Measurement(frames=Y, times_s=np.arange(24) / 12.0, meta=meta, truth_x1=x1, truth_x2=x2)
    res = reconstruct_measurement(m, "lsq", window=24)
    chk = res.reconstruction.info["alpha_nominal"]
    assert "warning" in chk and chk["frames_vs_nominal_rms"] > 0.05
    good = Measurement(frames=measure(x1, x2, polariser_alpha(24), sigma=0.005, rng=0, dtype=np.float32),
                       times_s=m.times_s, meta=meta)
    assert "warning" not in reconstruct_measurement(good, "lsq", window=24).reconstruction.info["alpha_nominal"]
    ref = reconstruct_measurement(dataclasses.replace(m, alpha=a), "lsq", window=24, refine_alpha=True,
                                  solver={"strict": False})
    assert ref.reconstruction.method == "alternating" and ref.alpha_mae < 2e-3


def test_a_flat_field_is_divided_out_of_both_images():
    """Frames vignetted by a known gain map (20 % at the corner) above a dark level: with the map as the file's
    ``flat_field`` both separated images are the unvignetted truth (to the noise); without it they carry the map."""
    x1, x2 = scene(48, lo=2000.0, hi=3000.0)
    a = polariser_alpha(12)
    H, W = x1.shape
    yy, xx = np.mgrid[:H, :W]
    v = 1 - 0.2 * (((yy - (H - 1) / 2) ** 2 + (xx - (W - 1) / 2) ** 2) / ((H - 1) ** 2 / 2))
    dark = 1000.0
    Y = (dark + v * (measure(x1, x2, a, sigma=0.0, rng=0) - 0.0)).astype(np.float32)
    meta = {"scale": 6.0, "dark_dn": dark}
    kw = dict(frames=Y, times_s=np.arange(12) / 12.0, alpha=a, truth_x1=dark + x1, truth_x2=dark + x2)
    plain = reconstruct_measurement(Measurement(**kw, meta=meta), "lsq").reconstruction
    flat = reconstruct_measurement(Measurement(**kw, meta=meta, extras={"flat_field": v}), "lsq").reconstruction
    for got, want in ((flat.x1, dark + x1), (flat.x2, dark + x2)):
        assert np.max(np.abs(got - want)) < 1e-2 * np.ptp(want)
    assert np.max(np.abs(plain.x1 - (dark + x1))) > 0.1 * np.ptp(x1)
    assert "divided out" in flat.info["flat_field"]
    with pytest.raises(InputError, match="flat_field"):
        Measurement(**kw, meta=meta, extras={"flat_field": np.zeros((H, W))})

"""``method='auto'``: the motion test and the choice tested against the truth they stand for (each frame's error
against that frame's truth), the time allowed, and what the choice reports."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from metafovea.config import SystemDesign
from metafovea.errors import InputError
from metafovea.imaging import simulate
from metafovea.reconstruct import choose_method, motion_of, reconstruct_measurement
from metafovea.reconstruct.auto import predicted_seconds


def _system(n: int = 96) -> SystemDesign:
    s = SystemDesign.paper()
    return dataclasses.replace(s, sensor=dataclasses.replace(s.sensor, crop=(n, n), pixels=(n, n)))


@pytest.fixture(scope="module")
def static():
    """24 frames of the bars, 96 x 96, Airy PSFs (stored in the file), 16 shutter frames."""
    return simulate(_system(), "bars", frames=24, psf="airy", optical_train=False, rng=1)


@pytest.fixture(scope="module")
def moving():
    """24 frames of the waving hand (a video scene), as the static fixture."""
    return simulate(_system(), "hand", frames=24, psf="airy", optical_train=False, rng=1)


def per_frame_psnr_x2(m, res) -> float:
    """Each frame's nearest output against that frame's perifoveal truth (PSNR over all frames, dB): one window's
    images are a mean over time, which the pipeline's score (against the truth averaged over each output's frames)
    does not penalise."""
    T = m.shape[0]
    mid = np.array([(a + b - 1) / 2 for a, b in res.spans])
    t = m.truth_x2 if m.truth_x2.ndim == 3 else np.broadcast_to(m.truth_x2, (T,) + m.truth_x2.shape)
    err = [np.mean((res.x2s[int(np.argmin(np.abs(mid - f)))].astype(np.float64) - t[f]) ** 2) for f in range(T)]
    return float(10 * np.log10(np.ptp(t) ** 2 / np.mean(err)))


def test_a_static_recording_is_one_window_and_a_moving_one_sliding_windows_each_the_better_against_the_truth(
        static, moving):
    """The motion test against the truth it stands for: the bars (static) get one window of all frames, the waving
    hand sliding windows of 8 frames; each choice's per-frame error against each frame's truth beats the other path's
    (bars: 45.4 against 42.5 dB; hand: 29.3 against 26.7 dB), so the test fails if the verdicts swap."""
    res = {}
    for name, m in (("static", static), ("moving", moving)):
        chosen = reconstruct_measurement(m, "auto", deconvolve="none")
        auto = chosen.reconstruction.info["auto"]
        other = dict(window=8) if auto["chose"]["window"] == 24 else dict(window=24)
        alt = reconstruct_measurement(m, auto["chose"]["method"], denoise=auto["chose"]["denoise"], **other)
        res[name] = (auto, per_frame_psnr_x2(m, chosen), per_frame_psnr_x2(m, alt))
    (sa, s_psnr, s_alt), (ma, m_psnr, m_alt) = res["static"], res["moving"]
    assert not sa["motion"]["moving"] and sa["motion"]["changing_fraction"] < 1e-3
    assert sa["chose"] == {"method": "lsq", "window": 24, "stride": 1, "denoise": "tv", "deconvolve": None}
    assert ma["motion"]["moving"] and ma["motion"]["changing_fraction"] > 0.5
    assert ma["chose"]["window"] == 8 and ma["chose"]["stride"] == 1
    assert s_psnr > s_alt + 1.0 and m_psnr > m_alt + 1.0


def test_the_noise_of_a_recording_without_shutter_frames_comes_from_its_frames():
    """Without shutter frames the noise is estimated from the residual frames: within 10 % of the simulator's 2 DN;
    the static scene stays static."""
    m = simulate(_system(64), "siemens-star", frames=12, psf="airy", optical_train=False, calibration_frames=0, rng=2)
    mo = motion_of(m)
    assert "from the frames" in mo.noise_from and abs(mo.noise_dn / 2.0 - 1) < 0.1
    assert not mo.moving and abs(mo.excess - 1) < 0.1


def test_the_time_allowed_picks_the_faster_candidate(static, moving):
    """No limit: the static scene's PSF-aware wavelet step (the file holds the PSFs); a budget between the wiener and
    the wavelet steps' predictions: wiener; below both: none; below every candidate: the fastest, said so. The moving
    scene's stride grows as the time shrinks, then its denoising goes."""
    rows = {r["deconvolve"]: r["predicted_s"] for r in choose_method(static).rows if r["denoise"] == "tv"}
    assert choose_method(static).deconvolve == "wavelet" and rows["wiener"] < rows["wavelet"]
    assert choose_method(static, (rows["wiener"] + rows["wavelet"]) / 2).deconvolve == "wiener"
    tight = choose_method(static, rows[None] * 1.5)
    assert tight.deconvolve is None and tight.denoise == "tv" and "a more accurate one needs" in tight.why
    fastest = choose_method(static, 1e-9)
    assert fastest.denoise is None and "no candidate fits" in fastest.why
    tv = {r["stride"]: r["predicted_s"] for r in choose_method(moving).rows if r["denoise"] == "tv"}
    budgets = [None] + [(tv[a] + tv[b]) / 2 for a, b in ((1, 2), (2, 4), (4, 8))]
    assert [choose_method(moving, t).stride for t in budgets] == [1, 2, 4, 8]
    assert choose_method(moving, tv[8] / 2).denoise is None


def test_auto_reports_its_choice_its_time_and_the_error(static):
    """The summary carries the choice, why, the predicted and taken seconds, the expected noise and the scores; a
    given window or PSF-aware step is kept; time_s and deconvolve are refused without auto."""
    res = reconstruct_measurement(static, "auto", time_s=10.0, deconvolve="wiener")
    s = res.summary()
    assert s["auto"]["chose"]["deconvolve"] == "wiener" and s["auto"]["given"] == ["deconvolve"]
    assert s["auto"]["seconds"] > 0 and s["auto"]["predicted_s"] > 0 and "predicted" in s["auto"]["why"]
    assert 0.3 < s["auto"]["noise_dn"][1] < 2.0 and s["metrics"]["psnr_x2"] > 40
    assert choose_method(static, window=12).window == 12
    with pytest.raises(InputError, match="time_s"):
        reconstruct_measurement(static, "lsq", time_s=1.0)
    with pytest.raises(InputError, match="time_s"):
        choose_method(static, -1.0)


def test_the_cost_model_scales_with_the_work():
    """Sliding windows cost per window; the unknown-alpha solver adds its calibration pass; a PSF-aware step adds
    its per-pixel cost."""
    one = predicted_seconds("lsq", 96, 290 * 290, 96)
    assert predicted_seconds("lsq", 96, 290 * 290, 8, 1) < predicted_seconds("alternating", 96, 290 * 290, 8, 1)
    assert predicted_seconds("lsq", 96, 290 * 290, 8, 8) < predicted_seconds("lsq", 96, 290 * 290, 8, 1)
    assert predicted_seconds("lsq", 96, 290 * 290, 96, deconvolve="wavelet") > \
        predicted_seconds("lsq", 96, 290 * 290, 96, deconvolve="wiener") > one


def test_one_frame_is_a_snapshot_and_two_cannot_tell_motion():
    """One frame: the snapshot; two frames: no motion test (one image and one number per frame fit any two),
    static, said so."""
    one = simulate(_system(48), "bars", frames=2, psf="airy", optical_train=False, rng=0)
    assert "cannot tell" in choose_method(one).why and choose_method(one).window == 2
    extras = {k: (v[:1] if k in ("theta_rad", "fpn_weights") else v) for k, v in one.extras.items()}
    single = dataclasses.replace(one, frames=one.frames[:1], times_s=one.times_s[:1], alpha=one.alpha[:1],
                                 extras=extras)
    assert choose_method(single).method == "snapshot"

"""The two entry points: :func:`reconstruct` (arrays, one solver) and :func:`reconstruct_measurement` (the pipeline's
rules on a Measurement). The reference check first: on a simulated paper measurement, known-alpha LSQ reaches the
noise-limited PSNR and unknown alpha is identified through the foveal constraint in the metadata."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import metafovea.reconstruct.api as api
from metafovea.errors import InputError
from metafovea.measurement import FovealConstraint, Measurement
from metafovea.reconstruct import alternating, denoise, reconstruct, reconstruct_measurement, snapshot, video
from metafovea.reconstruct.metrics import psnr, score
from metafovea.reconstruct.synthetic import lowrank_fpn, measure, polariser_alpha, scene


def _measurement(T=10, n=48, sigma=0.01, **over) -> Measurement:
    x1, x2 = scene(n)
    a = polariser_alpha(T)
    kw = dict(frames=measure(x1, x2, a, sigma=sigma, rng=0, dtype=np.float32), times_s=np.arange(T) / 12.0,
              alpha=a, truth_x1=x1, truth_x2=x2, meta={"scale": 6.0})
    kw.update(over)
    return Measurement(**kw)


def test_end_to_end_simulated_paper_measurement():
    """A small simulated paper measurement (bars, Airy PSFs, 192 x 192 crop, 8 frames, noise 2 DN,
    low-rank FPN, 14-bit): known-alpha LSQ reaches the noise-limited PSNR; unknown alpha is identified
    through the foveal constraint read from the metadata."""
    from metafovea.config import SystemDesign
    from metafovea.imaging import simulate

    s = SystemDesign.paper()
    s = dataclasses.replace(s, sensor=dataclasses.replace(s.sensor, crop=(192, 192), pixels=(192, 192)))
    m = simulate(s, "bars", frames=8, psf="airy", rng=0)
    geo = m.foveal_constraint.as_kwargs()
    t1, t2 = m.truth_x1, m.truth_x2
    # the stored pattern plays the part of a dark-frame calibration
    k = reconstruct(m.frames, m.alpha, method="lsq", fpn=m.fpn)
    sigma = m.meta["sensor"]["noise_sigma_dn"]
    # noise-limited PSNR: 20 log10(range / (sigma * noise gain)); 1 dB for quantisation (0.29 DN rms)
    for est, ref, gain in ((k.x1, t1, k.info["noise_gain"][0]), (k.x2, t2, k.info["noise_gain"][1])):
        assert psnr(est, ref) > 20 * np.log10(np.ptp(ref) / (sigma * gain)) - 1.0
    r = reconstruct(m.frames, method="alternating", fpn=m.fpn, **geo)
    assert r.info["gauge"]["applied"]
    err = float(np.max(np.abs(r.alpha - m.alpha)))
    # measured 0.023-0.029 over seeds 0-3 (0.003-0.005 before the optical train: its throughput of 0.31 leaves
    # the foveal bars 1.9 DN of contrast against 2 DN of noise)
    bound = 0.05
    assert err < bound
    # an alpha error e moves the images by ~e |x1 - x2| (~500 DN here, against a 1.9 DN foveal and
    # ~70 DN perifoveal contrast): the PSNR floor that error budget allows
    d = float(np.sqrt(np.mean((t1 - t2).astype(np.float64) ** 2)))
    for est, ref in ((r.x1, t1), (r.x2, t2)):
        assert psnr(est, ref) > 20 * np.log10(np.ptp(ref) / (2 * bound * d))
    # without the gain/offset (identity relation) the gauge cannot be fixed: a clear error
    with pytest.raises(InputError, match="gauge"):
        reconstruct(m.frames, method="alternating", fpn=m.fpn, scale=geo["scale"])
    # the pipeline on the Measurement: the constraint from its metadata, the stored pattern subtracted
    res = reconstruct_measurement(m, "alternating", window=8, fpn="file")
    assert res.constraint == m.foveal_constraint and res.reconstruction.info["alpha_identified"]
    assert res.alpha_mae < bound and res.metrics["psnr_x2"] > 20 * np.log10(np.ptp(t2) / (2 * bound * d))


def test_dispatcher_errors(truth, alpha8):
    Y = measure(*truth, alpha8, sigma=0.01, rng=0)
    with pytest.raises(InputError):
        reconstruct(Y, None, method="lsq")
    with pytest.raises(InputError):
        reconstruct(Y, alpha8, method="magic")
    with pytest.raises(InputError):
        reconstruct(Y, alpha8, method="snapshot")
    r = reconstruct(Y, method="alternating")
    assert r.method == "alternating"


def test_fpn_prior_with_known_alpha_uses_the_given_foveal_constraint(monkeypatch):
    """The lsq path dropped scale/gain/offset before the FPN prior saw them (it used gain 1, offset 0)."""
    seen = {}
    real = api.estimate_fpn

    def spy(**kw):
        seen.update({k: kw.get(k) for k in ("scale", "foveal_gain", "foveal_offset")})
        return real(**kw)

    monkeypatch.setattr(api, "estimate_fpn", spy)
    x1, x2 = scene(48)
    a = polariser_alpha(8)
    Y = measure(x1, x2, a, sigma=0.0, rng=0)
    reconstruct(Y, a, method="lsq", fpn="prior", scale=4.0, foveal_gain=0.3, foveal_offset=5.0)
    assert seen == {"scale": 4.0, "foveal_gain": 0.3, "foveal_offset": 5.0}


def test_a_sequence_longer_than_the_window_is_a_video_of_windows():
    """Default window: 8 frames, or all of a shorter sequence; the spans say which frames each output covers."""
    m = _measurement(T=10)
    res = reconstruct_measurement(m)
    assert res.reconstruction.is_video and res.spans == ((0, 8), (1, 9), (2, 10))
    v = video(m.frames, m.alpha, window=8)
    assert np.array_equal(res.reconstruction.x1, v.x1)
    short = reconstruct_measurement(_measurement(T=5))
    assert not short.reconstruction.is_video and short.spans == ((0, 5),) and short.outputs == 1
    strided = reconstruct_measurement(m, window=4, stride=3)
    assert strided.spans == ((0, 4), (3, 7), (6, 10))
    given = reconstruct_measurement(m, window=4, starts=[1, 6])
    assert given.spans == ((1, 5), (6, 10)) and given.reconstruction.is_video


def test_video_truth_is_scored_against_each_windows_mean():
    """Static frames, but a (T, H, W) truth that flickers around the real image: each window's
    reconstruction must be compared with the truth averaged over that window, not with frame k."""
    T, n = 10, 48
    x1, x2 = scene(n)
    flick = np.where(np.arange(T) % 2 == 0, 1.0, -1.0)[:, None, None] * 0.3 * np.ptp(x1)
    m = _measurement(T=T, n=n, sigma=0.0, truth_x1=(x1[None] + flick).astype(np.float32),
                     truth_x2=np.repeat(x2[None], T, 0).astype(np.float32))
    for kw in ({"window": 10}, {"window": 2, "stride": 2}, {"window": 4, "stride": 2}):
        res = reconstruct_measurement(m, **kw)
        assert res.metrics["psnr_x1"] > 40, (kw, res.metrics)
    snap = reconstruct_measurement(m, "snapshot", frame=3)
    assert snap.spans == ((3, 4),)
    assert snap.metrics == pytest.approx(score(snap.reconstruction, m.truth_x1[3], m.truth_x2[3]))


def test_snapshot_uses_the_files_alpha_only_when_told():
    m = _measurement(T=4)
    assumed = reconstruct_measurement(m, "snapshot", frame=1, solver={"iterations": 5})
    known = reconstruct_measurement(m, "snapshot", frame=1, known_alpha=True, solver={"iterations": 5})
    assert assumed.reconstruction.alpha[0] == 0.5 and known.reconstruction.alpha[0] == pytest.approx(m.alpha[1])
    ref = snapshot(m.frames[1], alpha=float(m.alpha[1]), iterations=5, **m.foveal_constraint.as_kwargs())
    assert np.array_equal(known.reconstruction.x1, ref.x1)
    assert assumed.alpha_mae is None and known.alpha_mae is None  # alpha not estimated


def test_fpn_from_the_file_a_given_pattern_or_the_calibration_frames():
    x1, x2 = scene(48)
    a = polariser_alpha(8)
    f = lowrank_fpn((48, 48), rank=3, amplitude=0.1, rng=1).astype(np.float32)
    cal = measure(np.full_like(x1, 0.5), np.full_like(x1, 0.5), np.full(6, 0.5), sigma=0.0, fpn=f, rng=0)
    m = _measurement(T=8, frames=measure(x1, x2, a, sigma=0.0, fpn=f, rng=0).astype(np.float32), fpn=f,
                     extras={"calibration": cal})
    plain = reconstruct_measurement(m)
    from_file = reconstruct_measurement(m, fpn="file")
    given = reconstruct_measurement(m, fpn=f.astype(np.float64))
    cal_res = reconstruct_measurement(m, fpn="calibration")
    assert np.array_equal(from_file.reconstruction.x1, given.reconstruction.x1)
    assert from_file.metrics["psnr_x1"] > plain.metrics["psnr_x1"] + 10
    assert cal_res.reconstruction.info["fpn"]["identified"] == "calibration"
    assert cal_res.metrics["psnr_x1"] > plain.metrics["psnr_x1"] + 10
    # estimated patterns are for one window; a missing array is named
    with pytest.raises(InputError, match="multi-window") as e:
        reconstruct_measurement(m, window=4, fpn="calibration")
    assert e.value.parameter == "fpn"
    with pytest.raises(InputError, match="calibration"):
        reconstruct_measurement(_measurement(T=8), fpn="calibration")
    with pytest.raises(InputError, match="'fpn'"):
        reconstruct_measurement(_measurement(T=8), fpn="file")
    with pytest.raises(InputError):
        reconstruct_measurement(m, fpn=np.zeros((3, 3)))


def test_denoise_inside_lsq_and_after_the_other_methods():
    m = _measurement(T=8, sigma=0.05)
    lsq = reconstruct_measurement(m, denoise="tv")
    assert lsq.reconstruction.info["denoise"] == "tv" and "noise_sigma" in lsq.reconstruction.info
    alt = reconstruct_measurement(m, "alternating", denoise="tv")
    ref = alternating(m.frames, **m.foveal_constraint.as_kwargs())
    assert np.array_equal(alt.reconstruction.x1, denoise(ref.x1, "tv"))
    assert alt.reconstruction.info["denoise"] == "tv"
    assert alt.alpha_mae == pytest.approx(np.mean(np.abs(ref.alpha - m.alpha)))


def test_the_constraint_given_overrides_the_files():
    m = _measurement(T=8, meta={"foveal_constraint": {"scale": 6.0, "gain": 1.0, "offset_dn": 0.0}})
    res = reconstruct_measurement(m, "alternating", constraint=FovealConstraint(scale=8.0),
                                  solver={"strict": False})
    assert res.constraint.scale == 8.0 and res.reconstruction.info["scale"] == 8.0


def test_rules_of_the_pipeline_are_input_errors():
    m = _measurement(T=10)
    with pytest.raises(InputError, match="snapshot") as e:
        reconstruct_measurement(_measurement(T=1))
    assert e.value.parameter == "frames"
    for kw, name in (({"window": 11}, "window"), ({"window": 1}, "window"),
                     ({"method": "snapshot", "frame": 10}, "frame"),
                     ({"method": "alternating", "known_alpha": True}, "known_alpha"),
                     ({"method": "alternating", "solver": {"regularize": "difference"}}, "regularize"),
                     ({"method": "magic"}, "method"), ({"fpn": "bogus"}, "fpn")):
        with pytest.raises(InputError) as e:
            reconstruct_measurement(m, **kw)
        assert e.value.parameter == name, kw
    no_alpha = _measurement(T=10, alpha=None)
    with pytest.raises(InputError, match="--method lsq") as e:
        reconstruct_measurement(no_alpha)
    assert e.value.value == "absent"
    assert reconstruct_measurement(no_alpha, "alternating").alpha_mae is None  # nothing to compare with


def test_nan_pixels_leave_the_metrics_uncomputed():
    m = _measurement(T=8)
    frames = m.frames.copy()
    frames[:, 7, 9] = np.nan
    res = reconstruct_measurement(dataclasses.replace(m, frames=frames))
    assert res.nonfinite_pixels == 2 and res.metrics.startswith("not computed")
    assert reconstruct_measurement(_measurement(T=8, truth_x1=None, truth_x2=None)).metrics is None

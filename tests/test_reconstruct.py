"""Reconstruction stage: operators, known-alpha LSQ, sliding windows, unknown alpha, FPN, hard cases."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from metafovea.errors import InputError
from metafovea.reconstruct import (FovealOperator, Reconstruction, SlidingLSQ, alternating, centre_crop,
                                   condition_number, denoise, downsample, downsample_adjoint, estimate_fpn,
                                   lsq_known_alpha, reconstruct, video)
from metafovea.reconstruct.metrics import psnr, score, ssim
from metafovea.reconstruct.synthetic import lowrank_fpn, measure, polariser_alpha, scene

N = 96


@pytest.fixture(scope="module")
def truth():
    return scene(N)


@pytest.fixture(scope="module")
def alpha8():
    return polariser_alpha(8)


# ----------------------------------------------------------------------------- operators
@pytest.mark.parametrize("shape,scale,offset", [((96, 96), 6, (0, 0)), ((64, 80), 6, (0, 0)),
                                                ((100, 90), 6.5, (1.5, -2.25)), ((290, 290), 6, (0, 0))])
def test_operator_adjoints_and_constraint(shape, scale, offset):
    rng = np.random.default_rng(0)
    op = FovealOperator(shape, scale, offset)
    x = rng.random(shape)
    u = rng.random(op.low_shape)
    assert op.low_shape == (int(shape[0] // scale), int(shape[1] // scale))
    assert np.sum(op.D(x) * u) == pytest.approx(np.sum(x * op.DT(u)), rel=1e-12)
    assert np.sum(op.C(x) * u) == pytest.approx(np.sum(x * op.CT(u)), rel=1e-12)
    assert np.allclose(op.D(np.ones(shape)), 1.0) and np.allclose(op.C(np.ones(shape)), 1.0)


def test_block_mean_and_crop_for_integer_scale():
    rng = np.random.default_rng(1)
    x = rng.random((96, 96)).astype(np.float32)
    d = downsample(x, 6)
    assert d.dtype == np.float32
    assert np.allclose(d, x.reshape(16, 6, 16, 6).mean(axis=(1, 3)), atol=1e-6)
    assert np.array_equal(centre_crop(x, 6), x[40:56, 40:56])
    assert downsample_adjoint(d, (96, 96), 6).shape == (96, 96)
    x1, x2 = scene(96)
    op = FovealOperator((96, 96), 6)
    assert np.abs(op.residual(x1, x2)).max() < 1e-12
    assert np.allclose(op.D(op.upsample(d.astype(np.float64))), d, atol=1e-6)


@pytest.mark.parametrize("bad", [0.5, 0, -3, float("nan"), "six", 60])
def test_bad_scale_is_input_error(bad):
    with pytest.raises(InputError) as e:
        FovealOperator((96, 96), bad)
    assert e.value.parameter == "scale"


def test_offset_outside_frame_refused():
    with pytest.raises(InputError) as e:
        FovealOperator((96, 96), 6, (50, 0))
    assert e.value.parameter == "offset"


# ----------------------------------------------------------------------------- known alpha
def test_lsq_exact_without_noise(truth, alpha8):
    x1, x2 = truth
    Y = measure(x1, x2, alpha8, sigma=0.0)
    r = lsq_known_alpha(Y, alpha8)
    assert np.allclose(r.x1, x1, atol=1e-9) and np.allclose(r.x2, x2, atol=1e-9)
    assert r.info["condition"] == pytest.approx(condition_number(alpha8))
    assert r.info["condition"] < 10


def test_lsq_accuracy_and_noise_gain(truth, alpha8):
    x1, x2 = truth
    Y = measure(x1, x2, alpha8, sigma=0.01, rng=0)
    r = lsq_known_alpha(Y, alpha8)
    # the noise of the estimate matches sigma * noise_gain (the reported conditioning is truthful)
    for est, ref, g in ((r.x1, x1, r.info["noise_gain"][0]), (r.x2, x2, r.info["noise_gain"][1])):
        assert np.std(est - ref) == pytest.approx(0.01 * g, rel=0.05)
    assert psnr(r.x1, x1, 1.0) > 42.0 and psnr(r.x2, x2, 1.0) > 42.0


def test_lsq_float32_preserved(truth, alpha8):
    Y = measure(*truth, alpha8, sigma=0.01, rng=0, dtype=np.float32)
    r = lsq_known_alpha(Y, alpha8)
    assert r.x1.dtype == np.float32 and r.x2.dtype == np.float32


@pytest.mark.parametrize("T", [2, 3])
def test_two_and_three_frames(truth, T):
    a = np.array([0.9, 0.1, 0.5])[:T]
    x1, x2 = truth
    Y = measure(x1, x2, a, sigma=0.0)
    r = lsq_known_alpha(Y, a)
    assert np.allclose(r.x1, x1) and np.allclose(r.x2, x2)
    # denoising with T=2 cannot use the residual: noise estimated from the images instead
    r2 = lsq_known_alpha(measure(x1, x2, a, sigma=0.02, rng=1), a, denoise="tv")
    assert r2.info["noise_sigma"] > 0


def test_one_frame_refused(truth):
    with pytest.raises(InputError) as e:
        lsq_known_alpha(truth[0][None], [0.5])
    assert e.value.parameter == "frames"


def test_equal_alphas_singular_is_clear_error(truth):
    a = np.full(8, 0.6)
    Y = measure(*truth, a, sigma=0.01, rng=0)
    assert condition_number(a) == np.inf
    with pytest.raises(InputError, match="condition number"):
        lsq_known_alpha(Y, a)


def test_equal_alphas_regularised_by_stated_rule(truth):
    x1, x2 = truth
    a = np.full(8, 0.6)
    Y = measure(x1, x2, a, sigma=0.01, rng=0)
    r = lsq_known_alpha(Y, a, regularize="difference")
    # rule: difference ridge -> both channels fall back to the unseparated mixture, no amplified noise
    mix = 0.6 * x1 + 0.4 * x2
    assert np.allclose(r.x1, r.x2, atol=1e-3)
    assert np.std(r.x1 - mix) < 0.01
    assert r.info["condition_regularized"] <= 1e4 * 1.001
    assert r.info["regularization_lambda"] > 0


def test_slow_polariser_condition_in_the_hundreds(truth, caplog):
    a = polariser_alpha(8, rate_hz=0.5 / 360 * 12, phase=0.75)  # 0.5 deg/frame
    x1, x2 = truth
    Y = measure(x1, x2, a, sigma=0.001, rng=0)
    with caplog.at_level(logging.WARNING, logger="metafovea.reconstruct.lsq"):
        r = lsq_known_alpha(Y, a)
    assert 300 < r.info["condition"] < 1000
    assert "condition number" in caplog.text  # never silently amplified
    # correct in expectation: the error matches the reported noise gain
    g = r.info["noise_gain"]
    assert max(g) > 5
    assert np.std(r.x1 - x1) == pytest.approx(0.001 * g[0], rel=0.1)
    # a stricter limit turns it into an error
    with pytest.raises(InputError):
        lsq_known_alpha(Y, a, max_condition=100)


def test_alpha_near_one_for_all_frames(truth):
    a = 0.9 + 0.05 * np.cos(np.arange(8) * 1.1)
    x1, x2 = truth
    r = lsq_known_alpha(measure(x1, x2, a, sigma=0.0), a)
    assert np.allclose(r.x1, x1, atol=1e-8) and np.allclose(r.x2, x2, atol=1e-8)
    assert r.info["condition"] > 100 and r.info["noise_gain"][1] > 5


def test_bad_alpha_refused(truth):
    Y = measure(*truth, polariser_alpha(4), sigma=0.0)
    for bad, param in (([0.1, 0.2, 0.3], "alpha"), ([0.1, 1.5, 0.2, 0.3], "alpha"),
                       ([0.1, np.nan, 0.2, 0.3], "alpha")):
        with pytest.raises(InputError) as e:
            lsq_known_alpha(Y, bad)
        assert e.value.parameter == param


def test_frames_of_different_shapes_refused():
    with pytest.raises(InputError, match="same"):
        lsq_known_alpha([np.zeros((8, 8)), np.zeros((8, 9))], [0.1, 0.9])
    with pytest.raises(InputError):
        lsq_known_alpha(np.zeros((2, 3, 4, 5)), [0.1, 0.9])


def test_nan_and_saturated_pixels_masked(truth, alpha8):
    x1, x2 = truth
    Y = measure(x1, x2, alpha8, sigma=0.0)
    Y[0, 10, 10] = np.nan
    Y[3, 20, 30] = np.inf
    Y[:7, 40, 40] = np.nan  # only one valid sample left: unresolvable
    Y[2, 50, 50] = 5.0  # saturated
    r = lsq_known_alpha(Y, alpha8, saturation=2.0)
    good = np.ones_like(x1, bool)
    good[40, 40] = False
    assert np.allclose(r.x1[good], x1[good], atol=1e-9) and np.allclose(r.x2[good], x2[good], atol=1e-9)
    assert np.isnan(r.x1[40, 40]) and r.info["unresolved_pixels"] == 1
    assert r.info["masked_samples"] == 10
    # without the saturation level the saturated sample corrupts its pixel (and only it)
    r2 = lsq_known_alpha(Y, alpha8)
    assert abs(r2.x1[50, 50] - x1[50, 50]) > 0.1


def test_denoise_improves_noisy_lsq(truth, alpha8):
    x1, x2 = truth
    Y = measure(x1, x2, alpha8, sigma=0.05, rng=0)
    raw = lsq_known_alpha(Y, alpha8)
    for method in ("tv", "bilateral"):
        d = lsq_known_alpha(Y, alpha8, denoise=method)
        assert psnr(d.x1, x1, 1.0) > psnr(raw.x1, x1, 1.0) + 1.0, method
        assert d.info["noise_sigma"] == pytest.approx(0.05, rel=0.1)
    with pytest.raises(InputError):
        denoise(x1, "median")


# ----------------------------------------------------------------------------- sliding / video
def test_sliding_lsq_matches_batch(truth):
    x1, x2 = truth
    a = polariser_alpha(20)
    Y = measure(x1, x2, a, sigma=0.01, rng=3, dtype=np.float32)
    s = SlidingLSQ(window=8, refresh=5)
    outs = [s.update(Y[t], a[t]) for t in range(20)]
    assert all(o is None for o in outs[:7])
    v = video(Y, a, window=8)
    assert v.x1.shape == (13, N, N) and v.x1.dtype == np.float32
    for k in range(13):
        o1, o2, cond = outs[k + 7]
        ref = lsq_known_alpha(Y[k:k + 8], a[k:k + 8])
        assert np.allclose(o1, ref.x1, atol=2e-5) and np.allclose(o2, ref.x2, atol=2e-5)
        assert np.allclose(v.x1[k], ref.x1, atol=2e-5)
        assert cond == pytest.approx(v.info["condition"][k])
    with pytest.raises(InputError):
        s.push(np.zeros((5, 5)), 0.3)


def test_video_window_longer_than_sequence(truth):
    Y = measure(*truth, polariser_alpha(5), sigma=0.0)
    with pytest.raises(InputError) as e:
        video(Y, polariser_alpha(5), window=8)
    assert e.value.parameter == "window"
    v = video(Y, polariser_alpha(5), window=5)
    assert v.x1.shape == (1, N, N)


def test_video_stride_and_singular_window(truth):
    a = np.concatenate([polariser_alpha(8), np.full(8, 0.3)])  # polariser stops
    Y = measure(*truth, a, sigma=0.01, rng=0)
    with pytest.raises(InputError, match="window"):
        video(Y, a, window=8, stride=2)
    v = video(Y, a, window=8, stride=2, regularize="difference")
    assert v.x1.shape == (5, N, N) and v.info["window_starts"] == [0, 2, 4, 6, 8]
    assert v.info["condition"][0] < 10 and v.info["condition"][-1] == np.inf


# ----------------------------------------------------------------------------- unknown alpha
def test_alternating_within_1db_of_known_alpha(truth, alpha8):
    x1, x2 = truth
    Y = measure(x1, x2, alpha8, sigma=0.01, rng=0)
    known = lsq_known_alpha(Y, alpha8)
    r = alternating(Y, prior=None)
    assert r.info["gauge"]["applied"] and r.info["alpha_identified"]
    assert np.max(np.abs(r.alpha - alpha8)) < 0.01
    for est, k, ref in ((r.x1, known.x1, x1), (r.x2, known.x2, x2)):
        assert psnr(est, ref, 1.0) > psnr(k, ref, 1.0) - 1.0
    tv = alternating(Y)  # TV prior on top
    assert psnr(tv.x1, x1, 1.0) > psnr(known.x1, x1, 1.0)
    assert r.timings["init"] + r.timings["gauge"] + r.timings["alternate"] < 1.0


def test_alternating_without_gauge_fix_stalls(truth, alpha8):
    """The gauge is real: without the foveal constraint alternating minimisation stays mixed."""
    x1, x2 = truth
    Y = measure(x1, x2, alpha8, sigma=0.01, rng=0)
    r = alternating(Y, gauge="none", prior=None, init="means")
    assert psnr(r.x1, x1, 1.0) < 35
    assert not r.info["alpha_identified"]
    # ... and the data fit is as good as with the fix (the gauge is invisible to the data term)
    fixed = alternating(Y, prior=None, init="means")
    assert r.info["loss_history"][-1] == pytest.approx(fixed.info["loss_history"][-1], rel=0.05)


def test_alternating_float32_and_nan(truth, alpha8):
    x1, x2 = truth
    Y = measure(x1, x2, alpha8, sigma=0.01, rng=0, dtype=np.float32)
    Y[2, 5, 5] = np.nan
    r = alternating(Y, prior=None)
    assert r.x1.dtype == np.float32 and np.all(np.isfinite(r.x1))
    assert r.info["masked_samples"] == 1
    assert psnr(r.x1, x1, 1.0) > 40


def test_alternating_unidentifiable_cases_are_clear(truth, alpha8):
    x1, x2 = truth
    # polariser stopped: nothing varies
    Y = measure(x1, x2, np.full(8, 0.5), sigma=0.01, rng=0)
    with pytest.raises(InputError):
        alternating(Y)
    # wrong foveal geometry: the gauge cannot be fixed -> clear error by default, flagged result otherwise
    Y = measure(x1, x2, alpha8, sigma=0.01, rng=0)
    with pytest.raises(InputError, match="gauge"):
        alternating(Y, scale=8.0)
    r = alternating(Y, scale=8.0, strict=False)
    assert not r.info["alpha_identified"] and r.info["gauge"]["reason"]
    with pytest.raises(InputError):
        alternating(Y[:2])  # needs >= 3 frames


def test_alternating_slow_polariser(truth):
    """cond ~626: unknown alpha still matches known alpha (both carry the amplified noise)."""
    x1, x2 = truth
    a = polariser_alpha(8, rate_hz=0.5 / 360 * 12, phase=0.75)
    Y = measure(x1, x2, a, sigma=0.01, rng=0)
    r = alternating(Y, prior=None)
    known = lsq_known_alpha(Y, a)
    assert r.info["alpha_identified"] and r.info["condition"] > 300
    assert psnr(r.x1, x1, 1.0) > psnr(known.x1, x1, 1.0) - 1.5


def test_alternating_alpha_near_one(truth):
    """x2 barely observed: guarded gauge fix still beats the frame-mean gauge; x1 stays good."""
    x1, x2 = truth
    a = 0.9 + 0.05 * np.cos(np.arange(8) * 1.1)
    Y = measure(x1, x2, a, sigma=0.002, rng=0)
    nofix = alternating(Y, gauge="none", prior=None)
    r = alternating(Y, prior=None)
    known = lsq_known_alpha(Y, a)
    assert r.info["gauge"]["applied"]
    assert psnr(r.x1, x1, 1.0) > psnr(nofix.x1, x1, 1.0)
    assert psnr(r.x1, x1, 1.0) > psnr(known.x1, x1, 1.0) - 3.0


def test_gauge_guard_rejects_wrong_geometry(truth, alpha8):
    """With a wrong foveal scale the constraint is false: the guard must not apply it blindly."""
    x1, x2 = truth
    Y = measure(x1, x2, alpha8, sigma=0.01, rng=0)
    for scale in (4.0, 5.0, 7.0, 8.0):
        r = alternating(Y, scale=scale, prior=None, strict=False)
        assert not r.info["gauge"]["applied"], scale
    forced = alternating(Y, scale=5.0, prior=None, gauge="foveal")
    assert forced.info["gauge"]["applied"] and psnr(forced.x1, x1, 1.0) < 35


# ----------------------------------------------------------------------------- FPN
def test_fpn_not_identifiable_from_mixture_alone(truth, alpha8):
    x1, x2 = truth
    f = lowrank_fpn(x1.shape, amplitude=0.1, rng=1)
    a = alpha8
    Y1 = measure(x1, x2, a, sigma=0.0, fpn=f)
    Y2 = measure(x1 + f, x2 + f, a, sigma=0.0)
    assert np.allclose(Y1, Y2)
    with pytest.raises(InputError, match="not identifiable"):
        estimate_fpn()


def test_strong_fpn_with_calibration_and_prior(truth, alpha8):
    x1, x2 = truth
    f = lowrank_fpn(x1.shape, rank=3, amplitude=0.1, rng=1)
    Y = measure(x1, x2, alpha8, sigma=0.01, fpn=f, rng=0)
    cal = measure(np.full_like(x1, 0.5), np.full_like(x1, 0.5), np.full(4, 0.5), sigma=0.01, fpn=f, rng=2)
    plain = reconstruct(Y, alpha8)
    withcal = reconstruct(Y, alpha8, fpn="calibration", calibration=cal)
    prior = reconstruct(Y, alpha8, fpn="prior", fpn_kw={"rank": 3, "iterations": 60})
    p0, pc, pp = (psnr(r.x1, x1, 1.0) for r in (plain, withcal, prior))
    assert pc > p0 + 8
    assert pp > p0 + 3
    assert withcal.info["fpn"]["identified"] == "calibration"
    assert prior.info["fpn"]["identified"] == "prior"
    assert np.abs(prior.fpn).max() <= 0.1 + 1e-12 and abs(prior.fpn.mean()) < 1e-12
    assert np.linalg.matrix_rank(prior.fpn, tol=1e-8) <= 3 + 1  # + the zero-mean shift


# ----------------------------------------------------------------------------- result type, metrics, dispatcher
def test_reconstruction_save_load(tmp_path, truth, alpha8):
    Y = measure(*truth, alpha8, sigma=0.01, rng=0, dtype=np.float32)
    r = reconstruct(Y, alpha8, method="lsq")
    p = tmp_path / "rec.npz"
    r.save(p)
    q = Reconstruction.load(p)
    assert np.array_equal(q.x1, r.x1) and q.x1.dtype == np.float32 and q.method == "lsq"
    assert q.info["condition"] == pytest.approx(r.info["condition"])
    with pytest.raises(AttributeError):
        r.method = "x"  # frozen
    (tmp_path / "other.npz").write_bytes(b"")
    np.savez(tmp_path / "other.npz", a=np.zeros(2))
    with pytest.raises(InputError):
        Reconstruction.load(tmp_path / "other.npz")


def test_metrics(truth):
    x1, x2 = truth
    assert psnr(x1, x1) == np.inf and ssim(x1, x1) == pytest.approx(1.0)
    noisy = x1 + np.random.default_rng(0).normal(0, 0.01, x1.shape)
    assert psnr(noisy, x1, 1.0) == pytest.approx(40.0, abs=0.3)
    s = score((noisy, x2), x1, x2, 1.0)
    assert set(s) == {"psnr_x1", "ssim_x1", "psnr_x2", "ssim_x2"}
    with pytest.raises(InputError):
        psnr(x1[:5], x1)


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


def test_grad2d_adjoint_and_tv_gradient():
    from metafovea.reconstruct.operators import grad2d, grad2d_adjoint, tv_charbonnier
    g = np.random.default_rng(0)
    z = g.normal(size=(7, 9))
    py, px = g.normal(size=(7, 9)), g.normal(size=(7, 9))
    gy, gx = grad2d(z)
    assert np.isclose((gy * py).sum() + (gx * px).sum(), (z * grad2d_adjoint(py, px)).sum())
    v, grad = tv_charbonnier(z, 0.1)
    e = np.zeros_like(z)
    e[3, 4] = 1e-6
    assert np.isclose((tv_charbonnier(z + e, 0.1)[0] - tv_charbonnier(z - e, 0.1)[0]) / 2e-6, grad[3, 4], rtol=1e-5)

"""Fixed-pattern noise: not identifiable from the mixture alone; from calibration frames or the low-rank prior."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.errors import InputError
from metafovea.reconstruct import estimate_fpn, reconstruct
from metafovea.reconstruct.fpn import project_lowrank
from metafovea.reconstruct.metrics import psnr
from metafovea.reconstruct.synthetic import lowrank_fpn, measure, polariser_alpha, scene


def test_fpn_not_identifiable_from_mixture_alone(truth, alpha8):
    """(x1 + f, x2 + f) explains the frames exactly as well as (x1, x2): the estimator refuses the mixture alone."""
    x1, x2 = truth
    f = lowrank_fpn(x1.shape, amplitude=0.1, rng=1)
    Y1 = measure(x1, x2, alpha8, sigma=0.0, fpn=f)
    Y2 = measure(x1 + f, x2 + f, alpha8, sigma=0.0)
    assert np.allclose(Y1, Y2)
    with pytest.raises(InputError, match="not identifiable"):
        estimate_fpn()


def test_calibration_frames_recover_the_pattern_up_to_its_mean(truth):
    x1, _ = truth
    f = lowrank_fpn(x1.shape, rank=3, amplitude=0.1, rng=1)
    cal = measure(np.full_like(x1, 0.5), np.full_like(x1, 0.5), np.full(16, 0.5), sigma=0.01, fpn=f, rng=2)
    est, info = estimate_fpn(calibration=cal, rank=3)
    assert info["identified"] == "calibration" and abs(est.mean()) < 1e-12
    # the calibration noise averages down as 1/sqrt(frames); the low-rank projection removes most of the rest
    assert np.sqrt(np.mean((est - (f - f.mean())) ** 2)) < 0.01 / np.sqrt(16)


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


def test_fpn_prior_constraint_in_the_images_units(dn):
    """The FPN prior's foveal term holds for gain/offset truth: on images that satisfy the constraint the estimate
    stays small; with the relation ignored it tries to explain a 1000-DN misfit."""
    x1, x2 = dn.x1, dn.x2
    f_ok, _ = estimate_fpn(x1=x1, x2=x2, foveal_gain=dn.gain, foveal_offset=dn.offset, rank=2, iterations=20,
                           method="tv")
    f_bad, _ = estimate_fpn(x1=x1, x2=x2, rank=2, iterations=20, method="tv")
    assert np.abs(f_ok).max() < 0.5 * np.abs(f_bad).max()
    # the bound is relative to the images' range (0.1 x 199 DN here; x2 after re-centring the mean)
    assert np.abs(f_bad).max() <= 2 * 0.1 * max(np.ptp(x1), np.ptp(x2))


def test_project_lowrank_is_zero_mean_low_rank_and_bounded():
    """Zero mean, rank <= rank (+ the mean shift), clipped to the bound (up to the re-centring after the clip)."""
    rng = np.random.default_rng(0)
    f = project_lowrank(rng.normal(size=(30, 40)), 2, 0.5)
    assert abs(f.mean()) < 1e-12 and 0.45 < np.abs(f).max() <= 0.5 * 1.02
    g = project_lowrank(np.outer(rng.normal(size=30), rng.normal(size=40)), 1, np.inf)
    assert np.linalg.matrix_rank(g - g.mean(), tol=1e-9) <= 2


def _foveal_case(rng_seed: int, detail: float):
    """A fresh DN pair with D x1 = 0.3 C x2 + 700 exactly and x1 = U D x1 + ``detail`` x (zero-box-mean detail),
    plus a rank-3 pattern of 6 DN peak (x1 spans ~60 DN)."""
    from metafovea.reconstruct.operators import FovealOperator

    rng = np.random.default_rng(rng_seed)
    g, o = 0.3, 700.0
    _, x2 = scene(96, lo=1700.0, hi=1760.0, foveal_gain=g, foveal_offset=o, perifoveal="camera")
    op = FovealOperator(x2.shape, 6.0)
    e = rng.normal(size=x2.shape)
    d = e - op.upsample(op.D(e))  # D d == 0: detail the constraint cannot see
    x1 = op.upsample(g * op.C(x2) + o) + detail * d
    f = 6.0 * lowrank_fpn(x2.shape, rank=3, amplitude=1.0, rng=rng_seed)
    return op, g, o, x1, x2, f, d


def test_blind_foveal_fpn_identifies_what_it_reports():
    """Under the stated assumption (x1 = U D x1) the pattern is recovered exactly; sub-box detail of x1 goes into
    the estimate as (I - g U C)^-1 (I - U D) x1 (the 'unidentified' part), while the 'observed' part (D - g C) f
    is right either way; the mean is never identified."""
    for detail in (0.0, 2.0):
        op, g, o, x1, x2, f, d = _foveal_case(3, detail)
        est, info = estimate_fpn(x1=x1 + f, x2=x2 + f, foveal_gain=g, foveal_offset=o, fit_gain=False, rank=96)
        assert info["identified"] == "foveal" and not info["foveal_gain_fitted"] and abs(est.mean()) < 1e-9
        assert "x1 = U D x1" in info["assumed"] and "(D - g C) f" in info["observed"]

        def obs(u, op=op, g=g):
            return op.D(u) - g * op.C(u)

        err_obs = obs(est) - obs(f)
        assert np.max(np.abs(err_obs - err_obs.mean())) < 1e-8 * np.abs(f).max() + 1e-9  # observed part: exact
        # the error is the stated unidentified part: (I - g U C)^-1 d, i.e. err - g U C err == detail * d
        err = est - (f - f.mean())
        lhs = err - g * op.upsample(op.C(err))
        assert np.allclose(lhs - lhs.mean(), detail * (d - d.mean()), atol=1e-8 * np.abs(f).max())
        if detail == 0.0:
            assert np.max(np.abs(err)) < 1e-8 * np.abs(f).max()


def test_blind_fpn_reduces_the_error_on_a_fresh_noisy_case():
    """Frames with noise and unknown contrast gain (fitted): the blind estimate removes most of the pattern (rms
    error against the truth, mean removed), far more than the TV prior, in well under a second."""
    import time

    op, g, o, x1, x2, f, _ = _foveal_case(11, 0.3)
    a = polariser_alpha(16)
    Y = measure(x1, x2 + 0.0, a, sigma=1.0, fpn=f, rng=5)
    plain = reconstruct(Y, a)
    t0 = time.perf_counter()
    est, info = estimate_fpn(x1=plain.x1, x2=plain.x2, foveal_gain=1.0, foveal_offset=0.0)  # stored gain wrong
    seconds = time.perf_counter() - t0
    tv, _ = estimate_fpn(x1=plain.x1, x2=plain.x2, foveal_gain=g, foveal_offset=o, method="tv", iterations=60)

    def rms(u):
        return float(np.sqrt(np.mean((u - u.mean()) ** 2)))

    assert info["foveal_gain_fitted"] and abs(info["foveal_gain"] - g) < 0.02
    assert rms(est - f) < 0.25 * rms(f) and rms(est - f) < 0.5 * rms(tv - f)
    assert seconds < 1.0
    r = reconstruct(Y, a, fpn="prior")
    assert r.info["fpn"]["identified"] == "foveal" and psnr(r.x1 - (r.x1 - x1).mean(), x1) > \
        psnr(plain.x1 - (plain.x1 - x1).mean(), x1) + 6


@pytest.mark.parametrize("seed, T, shape, rank",
                         [(21, 16, (96, 80), 20), (22, 9, (64, 64), 4), (23, 32, (120, 72), 10)])
def test_calibration_error_estimate_matches_the_true_error(seed, T, shape, rank):
    """The split-half estimate of the calibration FPN's error (``info['error_rms_dn']``) against the true error of
    the estimate, on rank-``rank`` patterns under white noise (odd frame counts too): within 20 %."""
    rng = np.random.default_rng(seed)
    H, W = shape
    f_true = (rng.normal(0, 3.0, (H, rank)) * np.linspace(2, 0.2, rank)) @ rng.normal(0, 1.0, (rank, W)) / rank
    cal = 50.0 + f_true[None] + rng.normal(0, 2.0, (T, H, W))
    f, info = estimate_fpn(calibration=cal, rank=rank)
    true_err = float(np.sqrt(np.mean(((f - f.mean()) - (f_true - f_true.mean())) ** 2)))
    assert 0.8 < info["error_rms_dn"] / true_err < 1.2, (info["error_rms_dn"], true_err)
    one, info1 = estimate_fpn(calibration=cal[:1], rank=rank)
    assert "error_rms_dn" not in info1  # one frame: nothing to split


@pytest.mark.parametrize("seed, T, shape", [(31, 16, (96, 80)), (32, 9, (64, 64)), (33, 32, (120, 72))])
def test_calibration_shrinkage_beats_a_fixed_rank_and_knows_its_error(seed, T, shape):
    """The default calibration estimate (optimal singular-value shrinkage) on a rank-20 pattern whose weak
    components lie under the noise of the frames' mean, as the sensor model's: a smaller error than the paper's
    rank-20 projection, and its SURE error estimate within 20 % of the true error."""
    rng = np.random.default_rng(seed)
    H, W = shape
    r = 20
    U = np.linalg.qr(rng.normal(size=(H, r)))[0]
    V = np.linalg.qr(rng.normal(size=(W, r)))[0]
    s = 60.0 * np.exp(-0.35 * np.arange(r)) * np.sqrt(H * W) / 10  # decaying, as metafovea.imaging.sensor's
    f_true = (U * s) @ V.T
    cal = 50.0 + f_true[None] + rng.normal(0, 2.0, (T, H, W))
    f, info = estimate_fpn(calibration=cal)
    f20, _ = estimate_fpn(calibration=cal, rank=20)

    def err(e):
        return float(np.sqrt(np.mean(((e - e.mean()) - (f_true - f_true.mean())) ** 2)))

    assert err(f) < 0.85 * err(f20), (err(f), err(f20))
    assert 0 < info["rank"] < 20 and info["rank_rule"] == "shrinkage" and info["error_rms_from"] == "sure"
    assert 0.8 < info["error_rms_dn"] / err(f) < 1.2, (info["error_rms_dn"], err(f))
    # one frame: no noise to shrink with: the paper's rank, no error estimate
    one, info1 = estimate_fpn(calibration=cal[:1])
    assert info1["rank"] == 20 and "error_rms_dn" not in info1


def test_the_rounding_bias_of_a_mean_of_quantised_samples_is_the_brute_force_ones():
    """Eq. (1) of ``quantisation_bias_variance`` against the mean of many rounded noisy samples of values spread
    over a step, averaged by brute force: 1/12 without noise, and the noise's dithering after it."""
    from metafovea.reconstruct.fpn import quantisation_bias_variance

    rng = np.random.default_rng(3)
    c = rng.uniform(0.0, 1.0, 20000)
    assert quantisation_bias_variance(0.0) == pytest.approx(1.0 / 12.0, rel=0.01)
    for s in (0.08, 0.15, 0.25):
        mean_err = np.mean([np.round(c + rng.normal(0.0, s, c.size)) - c for _ in range(400)], axis=0)
        brute = float(np.var(mean_err)) - s ** 2 / 400  # less the 400 samples' own noise of the mean
        assert quantisation_bias_variance(s ** 2) == pytest.approx(brute, rel=0.1, abs=2e-4), s


def test_calibration_frames_without_noise_keep_their_rounding_in_the_error():
    """Closed-shutter frames of whole counts without temporal noise (a noise-free simulation): their scatter is 0,
    yet their mean carries each pixel's rounding, which no number of frames averages away. The estimate shrinks
    that rounding as noise (it kept every component and all of the rounding before: 0.29 counts rms) and its stated
    error is the true one (it said 0)."""
    rng = np.random.default_rng(8)
    H, W = 90, 80
    f_true = rng.normal(0, 6.0, (H, 3)) @ rng.normal(0, 1.0, (3, W)) / 3 + 0.37
    cal = np.repeat(np.round(500.0 + f_true)[None], 16, axis=0)
    f, info = estimate_fpn(calibration=cal)
    true_err = float(np.sqrt(np.mean(((f - f.mean()) - (f_true - f_true.mean())) ** 2)))
    assert true_err < 0.15 and info["rank"] < 10, (true_err, info["rank"])
    assert info["error_rms_dn"] == pytest.approx(true_err, rel=0.3)
    # with noise that dithers the rounding the estimate is as before (the scatter alone)
    noisy = np.round(500.0 + f_true[None] + rng.normal(0, 2.0, (16, H, W)))
    _, info2 = estimate_fpn(calibration=noisy)
    assert info2["rounding_dn"] < 1e-6


@pytest.mark.parametrize("sigma, step", [(0.05, 1), (0.1, 1), (0.2, 1), (0.0, 16), (1.0, 16)])
def test_rounded_calibration_frames_state_their_error(sigma, step):
    """Frames of whole counts with noise below a count (or 12-bit counts in the top bits of 16: a step of 16): the
    rounded frames' scatter is not the noise's (the rounding adds to it), the step is the data's, and the estimate's
    stated error is its true error (it was 44 % low at 0.1 count, and 0 against 4.6 counts at the step of 16)."""
    from metafovea.reconstruct.fpn import quantiser_step

    rng = np.random.default_rng(9)
    H, W, T = 120, 100, 32
    p = (rng.standard_normal((H, 4)) * np.geomspace(1, 0.2, 4)) @ rng.standard_normal((4, W))
    p = 4.0 * step * (p - p.mean()) / p.std()
    cal = step * np.round((1000.3 * step + p[None] + sigma * step * rng.standard_normal((T, H, W))) / step)
    assert quantiser_step(cal) == step
    f, info = estimate_fpn(calibration=cal)
    true_err = float(np.sqrt(np.mean((f - p) ** 2)))
    assert info["error_rms_dn"] == pytest.approx(true_err, rel=0.25), (info["error_rms_dn"], true_err)
    assert true_err < 0.1 * step and info["rank"] <= 6


def test_the_noise_under_rounding_is_recovered_from_the_rounded_scatter():
    """``noise_variance`` against brute force: the scatter of rounded noisy samples of values spread over a step
    gives back the noise's variance."""
    from metafovea.reconstruct.fpn import noise_variance

    rng = np.random.default_rng(4)
    c = rng.uniform(0.0, 1.0, 100000)
    for s in (0.05, 0.1, 0.2, 0.5):
        v = float(np.mean(np.round(c[None] + rng.normal(0.0, s, (8, c.size))).var(axis=0, ddof=1)))
        assert noise_variance(v) == pytest.approx(s * s, rel=0.05, abs=2e-4), s
    assert noise_variance(0.0) == 0.0

"""The joint problem's periodic filter (:mod:`metafovea.reconstruct.joint`): the data-driven risk of its linear
estimate against the true error over repeated noise."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.fft import irfft2, rfft2

from metafovea.reconstruct.joint import Grid, PeriodicFilter, Problem, mean_square
from tests.independent.forward import disk_kernel, gauss_kernel


def _setup(prior_factor: float):
    """Two channels on a periodic grid: a 1/f^2 texture seen through a hazy (Gaussian core plus disk) and a sharp
    PSF, correlated noise; the filter's prior is the true spectrum times ``prior_factor``."""
    rng = np.random.default_rng(3)
    H = W = 48
    k1 = 0.3 * gauss_kernel(1.2, 25) + 0.7 * disk_kernel(8.0, 25)
    k2 = gauss_kernel(1.0, 25)
    g = Grid((H, W), (k1, k2), (0.0, 0.0))
    P, Q = g.shape
    f = np.maximum(g.f, 1.0 / max(P, Q))
    spec_true = 40.0 * P * Q / f ** 2  # per unnormalised bin
    C = np.array([[4.0, 1.5], [1.5, 2.0]])
    pb = Problem(g, np.zeros((2, H, W)), C)
    prior = np.stack([spec_true, spec_true])
    inv = 1.0 / (prior_factor * prior)
    inv[:, 0, 0] = 0.0
    return rng, g, pb, C, spec_true, PeriodicFilter(pb, inv)


def _trial(rng, g, C, spec_true, filt, taus, detection_snr):
    P, Q = g.shape
    chol = np.linalg.cholesky(C)
    white = rfft2(rng.standard_normal((2, P, Q)))
    S = np.sqrt(spec_true / (P * Q)) * white  # E|S|^2 = spec_true
    s = irfft2(S, s=(P, Q))
    z = irfft2(g.D * rfft2(s), s=(P, Q)) + np.einsum("ij,jhw->ihw", chol, rng.standard_normal((2, P, Q)))
    draws = np.stack([np.einsum("ij,jhw->ihw", chol, rng.standard_normal((2, P, Q))) for _ in range(4)])
    Z, Nd = rfft2(z), rfft2(draws)
    est, true = [], []
    for tau in taus:
        x = irfft2(filt.solve(tau, filt.rhs(Z)), s=(P, Q))
        est.append(filt.linear_risk(tau, np.ones((2,) + Z.shape[1:]), filt.risk_data(Z, Nd, detection_snr)))
        true.append(np.mean((x - s) ** 2, axis=(1, 2)))
    return np.array(est), np.array(true)


@pytest.mark.parametrize("prior_factor", [1.0, 0.1, 10.0])
def test_linear_risk_follows_the_true_error_more_closely_than_the_prior(prior_factor):
    """With the right prior, the risk's change with tau is the true error's (unbiased where the data show signal,
    eq. 4 of ``PeriodicFilter.linear_risk``; the prior's expectation is exact elsewhere). With a prior 10 times too
    small or too large (bins move across the split, and the prior's side follows its error) it is still closer to
    the true change than the prior's own prediction (every bin below the split)."""
    rng, g, pb, C, spec_true, filt = _setup(prior_factor)
    taus = (1.0, 1.0 / 16)
    shape = g.D.shape[1:]
    nothing = filt.risk_data(np.zeros((2,) + shape, complex), np.zeros((1, 2) + shape, complex), np.inf)
    prior_only = [filt.linear_risk(t, np.ones((2,) + shape), nothing) for t in taus]
    d_prior = prior_only[1] - prior_only[0]
    d_est, d_true = [], []
    for _ in range(12):
        est, true = _trial(rng, g, C, spec_true, filt, taus, 1.0)
        d_est.append(est[1] - est[0])
        d_true.append(true[1] - true[0])
    d_est, d_true = np.array(d_est), np.array(d_true)
    err = np.abs(d_est.mean(0) - d_true.mean(0))
    scale = np.abs(d_true.mean(0))
    if prior_factor == 1.0:
        se = np.sqrt(np.var(d_est - d_true, axis=0) / len(d_est))
        assert np.all(err < 4 * se + 0.05 * scale), (err, se, scale)
    else:
        err_prior = np.abs(d_prior - d_true.mean(0))
        assert np.all(err < err_prior), (err, err_prior)


def test_mean_square_is_parseval():
    """The mean over the grid's pixels of a field equals ``mean_square`` of its power per rfft bin."""
    rng, g, *_ = _setup(1.0)
    v = rng.standard_normal(g.shape)
    assert np.isclose(mean_square(g, np.abs(rfft2(v)) ** 2), np.mean(v ** 2), rtol=1e-12)


def test_the_solved_exterior_is_the_masked_wiener_estimate_of_a_dense_solve():
    """:func:`~metafovea.reconstruct.joint.solved_exterior` (CG on the ring's periodic grid, single precision) against
    the same estimate by a dense solve written here: the normal equations ``(D^T M D / c + Q) s = D^T M z / c`` with
    the blur and the prior built column by column and ``M`` the crop; the ring's data ``D s`` agree to a small part of
    the noise. A PSF within the ring (no wider part), so the edge-padded estimate plays no role."""
    from metafovea.reconstruct.joint import solved_exterior

    rng = np.random.default_rng(5)
    H = W = 20
    kernel = gauss_kernel(1.0, 7)
    g = Grid((H, W), (kernel, kernel), (0.0, 0.0))
    c = 0.5  # noise variance, DN^2
    big = rng.normal(0.0, 1.0, (H + 12, W + 12)).cumsum(0).cumsum(1) * 0.3 + 40.0
    big[:6] += 25.0  # a warmer band beyond the crop's top edge
    z = irfft2(rfft2(big) * rfft2(np.pad(kernel, ((0, H + 12 - 7), (0, W + 12 - 7)))), s=big.shape)
    z = np.roll(z, (-3, -3), axis=(0, 1))[6:6 + H, 6:6 + W] + rng.normal(0.0, np.sqrt(c), (H, W))

    def inverse_prior_on(gs: Grid) -> np.ndarray:
        f = np.maximum(gs.f, 1.0 / max(gs.shape))
        inv = f ** 2 / (30.0 * gs.shape[0] * gs.shape[1])
        inv[0, 0] = 0.0
        return inv

    out, info = solved_exterior(g, 1, z, kernel, c, inverse_prior_on, np.zeros(g.shape), width_px=8, iterations=500)
    r = info["width_px"]
    assert r == 3 and info["core_power"] == pytest.approx(1.0)
    gs = Grid((H, W), (kernel, kernel), (0.0, 0.0))
    P, Q = gs.shape
    n = P * Q
    q = n * inverse_prior_on(gs)
    eye = np.eye(n).reshape(n, P, Q)
    Dm = irfft2(gs.D[0] * rfft2(eye), s=(P, Q)).reshape(n, n).T  # column j: the blur of pixel j
    Qm = irfft2(q * rfft2(eye), s=(P, Q)).reshape(n, n).T
    mask = np.zeros((P, Q), dtype=bool)
    mask[gs.crop] = True
    m = mask.ravel()
    zfull = np.zeros((P, Q))
    zfull[gs.crop] = z
    A = Dm[m].T @ Dm[m] / c + Qm
    s = np.linalg.solve(A, Dm[m].T @ zfull.ravel()[m] / c)
    pred = (Dm @ s).reshape(P, Q)[:H + 2 * r, :W + 2 * r]
    ring = out[g.pad - r:g.pad + H + r, g.pad - r:g.pad + W + r]
    outside = np.ones(ring.shape, dtype=bool)
    outside[r:r + H, r:r + W] = False
    err = np.abs(ring - pred)[outside]
    assert np.max(err) < 0.1 * np.sqrt(c), (np.max(err), info)
    # the warmer band is seen: the solved ring above the crop is warmer than the crop's edge values
    assert np.mean(ring[:r, r:r + W]) > np.mean(z[0]) + 5.0

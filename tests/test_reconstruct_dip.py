"""Double deep image prior (JAX) with a tiny network and few steps."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("jax")

from metafovea.errors import InputError  # noqa: E402
from metafovea.reconstruct import dip, reconstruct  # noqa: E402
from metafovea.reconstruct.metrics import psnr  # noqa: E402
from metafovea.reconstruct.synthetic import measure, polariser_alpha, scene  # noqa: E402


@pytest.fixture(scope="module")
def data():
    x1, x2 = scene(32)
    a = polariser_alpha(6)
    return x1, x2, a, measure(x1, x2, a, sigma=0.01, rng=0, dtype=np.float32)


def test_dip_tiny_runs_and_learns(data):
    x1, x2, a, Y = data
    r = dip(Y, channels=4, depth=2, steps=40, rng=1)
    h = r.info["loss_history"]
    assert h[-1] < 0.5 * h[0]
    assert r.x1.shape == x1.shape and r.x1.dtype == np.float32
    assert r.alpha.shape == (6,) and np.all((r.alpha > 0) & (r.alpha < 1))
    assert r.info["alpha_learned"] and r.timings["compile"] > 0
    # deterministic for one seed
    r2 = dip(Y, channels=4, depth=2, steps=40, rng=1)
    assert np.allclose(r.x1, r2.x1, atol=1e-5)


def test_dip_known_alpha_fixed(data):
    x1, x2, a, Y = data
    r = reconstruct(Y, a, method="dip", channels=4, depth=2, steps=5, rng=0, foveal_weight=1.0,
                    foveal_gain=0.5, foveal_offset=0.02)
    assert np.allclose(r.alpha, a) and not r.info["alpha_learned"]
    assert r.info["foveal_gain"] == 0.5 and r.info["foveal_offset"] == 0.02


def test_dip_input_errors(data):
    *_, Y = data
    with pytest.raises(InputError):
        dip(Y, depth=6, steps=1)
    bad = Y.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InputError):
        dip(bad, steps=1)


@pytest.mark.slow
def test_dip_separates_with_more_steps(data):
    x1, x2, a, Y = data
    r = dip(Y, alpha=a, channels=8, depth=2, steps=300, rng=0)
    assert psnr(r.x1, x1, 1.0) > 20 and psnr(r.x2, x2, 1.0) > 20


def test_dip_warm_start_keeps_initialisation(data):
    """Residual warm start: step 0 is the initial estimate exactly; the DIP loss does not degrade it."""
    x1, x2, a, Y = data
    a0 = np.clip(a + 0.01, 0, 1)  # a slightly wrong alpha, as from the classical solver
    r = dip(Y, alpha_init=a0, init="lsq", channels=4, depth=2, steps=30, rng=0, checkpoints=(0, 30))
    c0, c30 = r.info["checkpoints"]
    ix1, ix2 = r.info["initial"]
    assert c0["step"] == 0 and np.allclose(c0["x1"], ix1, atol=1e-4) and np.allclose(c0["x2"], ix2, atol=1e-4)
    assert np.allclose(c30["x1"], r.x1) and r.info["warm"] == "residual" and r.info["tv_weight"] == 0.001
    p0 = (psnr(ix1, x1, 1.0), psnr(ix2, x2, 1.0))
    p1 = (psnr(r.x1, x1, 1.0), psnr(r.x2, x2, 1.0))
    assert p1[0] > p0[0] - 0.5 and p1[1] > p0[1] - 0.5, (p0, p1)
    assert np.max(np.abs(r.alpha - a0)) < 0.01  # alpha refined slowly (alpha_lr = lr / 10)
    # an explicit (x1, x2) pair with known alpha and the supervised warm start run too
    r2 = dip(Y, a, init=(ix1, ix2), warm="fit", warm_steps=3, channels=4, depth=2, steps=2, rng=0)
    assert r2.info["init"] == "images" and len(r2.info["warm_fit_history"]) == 3
    assert r2.x1.shape == x1.shape and np.all(np.isfinite(r2.x1))


def test_dip_warm_start_input_errors(data):
    x1, x2, a, Y = data
    for kw in ({"init": "bogus"}, {"init": 3}, {"init": (x1, x2[:-1])}, {"init": (x1 * np.nan, x2)},
               {"init": "lsq"},  # needs alpha or an alpha_init array
               {"init": "lsq", "alpha_init": a, "warm": "bogus"},
               {"init": "lsq", "alpha_init": a, "warm_steps": -1},
               {"init": "lsq", "alpha_init": a, "checkpoints": (5,)},  # beyond steps
               {"init": "lsq", "alpha_init": a, "tv_weight": -1.0}):
        with pytest.raises(InputError):
            dip(Y, channels=2, depth=1, steps=1, **kw)

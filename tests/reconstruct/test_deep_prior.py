"""Double deep image prior (JAX) with a tiny network and few steps. The reference check first: the constraint in
the networks' normalised units is the constraint in the frames' units."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.errors import InputError
from metafovea.reconstruct import DipOptions, FovealOperator, dip, reconstruct
from metafovea.reconstruct.metrics import psnr
from metafovea.reconstruct.synthetic import measure, polariser_alpha, scene


@pytest.fixture(scope="module")
def data():
    pytest.importorskip("jax")
    x1, x2 = scene(32)
    a = polariser_alpha(6)
    return x1, x2, a, measure(x1, x2, a, sigma=0.01, rng=0, dtype=np.float32)


def test_normalised_units_constraint(dn):
    """The DIP fits images in the frames' normalised units ``A y + B``: ``D x1 = g C x2 + b`` there reads
    ``D x1n = g C x2n + (1 - g) B + A b`` (the bias the network's foveal term uses)."""
    lo, span = 1500.0, 2500.0
    A, Bn = 0.9 / span, 0.05 - 0.9 * lo / span
    op = FovealOperator(dn.x1.shape, 6, gain=dn.gain, bias=dn.offset)
    bias_n = (1 - dn.gain) * Bn + A * dn.offset
    assert np.abs(op.D(A * dn.x1 + Bn) - dn.gain * op.C(A * dn.x2 + Bn) - bias_n).max() < 1e-9


def test_dip_tiny_runs_and_learns(data):
    x1, x2, a, Y = data
    r = dip(Y, channels=4, depth=2, steps=40, rng=1)
    h = r.info["loss_history"]
    assert h[-1] < 0.5 * h[0]
    assert r.x1.shape == x1.shape and r.x1.dtype == np.float32
    assert r.alpha.shape == (6,) and np.all((r.alpha > 0) & (r.alpha < 1))
    assert r.info["alpha_learned"] and r.timings["compile"] > 0
    # deterministic for one seed, and the options object is the same call as the keywords
    r2 = dip(Y, options=DipOptions(channels=4, depth=2, steps=40, rng=1))
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
    with pytest.raises(InputError) as e:
        dip(Y, step=1)  # not an option
    assert e.value.parameter == "option"


def test_dip_on_frames_too_small_for_the_network_names_the_frame_size():
    """4 x 6 frames for a depth-3 network failed inside JAX; it is an InputError naming the frames' size."""
    with pytest.raises(InputError, match="at least 8 x 8 pixels") as e:
        dip(np.ones((4, 4, 6), np.float32), steps=1)
    assert e.value.parameter == "frames"


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

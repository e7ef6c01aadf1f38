"""The bounded, resumable optimiser: analytic optima (inside and on the bounds), scales, an exact resume after a
stop, and a checkpoint of another problem refused."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.codesign.optimize import Bounds, OptimizeOptions, minimize
from metafovea.errors import InputError


def _quadratic(c_a, c_b):
    import jax.numpy as jnp

    def loss(p):
        va = jnp.sum((p["a"] - c_a) ** 2)
        vb = jnp.sum(((p["b"] - c_b) / 1e3) ** 2)  # b lives on a 1000x larger scale
        return va + vb, {"a_part": va}

    return loss


def test_reaches_the_projected_optimum_on_both_scales():
    c_a = np.array([0.3, -2.0, 5.0])  # the last one outside the box [-1, 1]: the optimum is the bound
    c_b = np.array([1500.0])
    bounds = {"a": Bounds(np.full(3, -1.0), np.full(3, 1.0), np.ones(3)),
              "b": Bounds(np.array([0.0]), np.array([4000.0]), np.array([1000.0]))}
    res = minimize(_quadratic(c_a, c_b), {"a": np.zeros(3), "b": np.array([100.0])}, bounds,
                   OptimizeOptions(steps=600, learning_rate=0.05, progress=False))
    np.testing.assert_allclose(res.params["a"], [0.3, -1.0, 1.0], atol=2e-3)
    np.testing.assert_allclose(res.params["b"], [1500.0], atol=2.0)
    assert res.loss == pytest.approx(16.0 + 1.0, abs=1e-2)  # (5 - 1)^2 + (-2 + 1)^2: the clipped entries
    assert res.history["loss"].size == 600 and np.all(np.isfinite(res.history["a_part"]))
    assert res.history["loss"][-1] < res.history["loss"][0]


def test_a_stopped_run_resumes_exactly(tmp_path):
    loss = _quadratic(np.array([0.5, 0.2, -0.4]), np.array([900.0]))
    bounds = {"a": Bounds(np.full(3, -1.0), np.full(3, 1.0), np.ones(3)),
              "b": Bounds(np.array([0.0]), np.array([4000.0]), np.array([1000.0]))}
    x0 = {"a": np.zeros(3), "b": np.array([100.0])}
    opts = OptimizeOptions(steps=40, learning_rate=0.02, checkpoint_every=7, progress=False)
    straight = minimize(loss, x0, bounds, opts)

    ck = tmp_path / "ck.npz"

    def stop_at_17(step, val, aux):
        if step == 17:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        minimize(loss, x0, bounds, opts, checkpoint=ck, problem_key="k1", on_step=stop_at_17)
    assert ck.is_file()
    resumed = minimize(loss, x0, bounds, opts, checkpoint=ck, problem_key="k1")
    assert resumed.resumed_from == 17 and resumed.steps == 40
    for k in x0:
        np.testing.assert_allclose(resumed.params[k], straight.params[k], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(resumed.history["loss"], straight.history["loss"], rtol=1e-12)
    # a checkpoint of another problem is refused, not resumed
    with pytest.raises(InputError, match="checkpoint"):
        minimize(loss, x0, bounds, opts, checkpoint=ck, problem_key="k2")


def test_bad_bounds_and_options_are_refused():
    with pytest.raises(InputError):
        Bounds(np.array([1.0]), np.array([0.0]), np.array([1.0]))
    with pytest.raises(InputError):
        Bounds(np.array([0.0]), np.array([1.0]), np.array([0.0]))
    with pytest.raises(InputError):
        OptimizeOptions(steps=0)
    with pytest.raises(InputError, match="bounds"):
        minimize(_quadratic(np.zeros(3), np.zeros(1)), {"a": np.zeros(3)}, {}, OptimizeOptions(progress=False))


def test_a_non_finite_loss_stops_with_its_step():
    import jax.numpy as jnp

    def loss(p):
        return jnp.sum(jnp.log(p["a"])), {}

    with pytest.raises(FloatingPointError, match="step 0"):
        minimize(loss, {"a": np.array([-1.0])}, {"a": Bounds(np.array([-2.0]), np.array([2.0]), np.array([1.0]))},
                 OptimizeOptions(steps=3, progress=False))

"""The differentiable surrogate of the scatterer library against the RCWA it is fitted to.

Small sizes keep CI fast: posts of 1.0-2.0 um (step 0.1 um) over 9.5-10.5 um (6 wavelengths) at harmonics 5,
fitted once per session in a temporary cache. The RCWA reference uses the same solver settings, so the errors
measured are the surrogate's own (interpolation), not the solver's truncation.
"""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.config import PlatformDesign
from metafovea.errors import InputError
from metafovea.library import (
    GOAL_AMPLITUDE_RMS_PCT,
    GOAL_PHASE_RMS_RAD,
    Surrogate,
    compute_library,
    error_report,
    fit_surrogate,
    held_out_points,
    rcwa_transmission,
    surrogate_from_library,
    surrogate_grid,
)
from metafovea.rcwa import post_response

jax = pytest.importorskip("jax")
jnp = jax.numpy

M = 5
RANGE = (1.0, 2.0)
BAND = (9.5, 10.5)
#: gradient check: central-difference step of the RCWA (um), and the tolerances: a phase derivative within
#: GRAD_REL['phase'] x max(|d phase_rcwa|, that derivative's rms over the points), an amplitude derivative within
#: GRAD_REL['amplitude'] x the rms of |dt / dx| (the complex derivative, t |t|'/|t| + i t phase') for that input
FD_STEP_UM = 1e-3
GRAD_REL = {"phase": 0.05, "amplitude": 0.1}


def _fit(cache, step: float, n_wl: int, stride: int = 1) -> Surrogate:
    return fit_surrogate(width_range_um=RANGE, width_step_um=step, n_wavelengths=n_wl, band_um=BAND, harmonics=M,
                         stride=stride, workers=1, progress=False, cache_dir=cache / "library")


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("surrogate-cache")


@pytest.fixture(scope="module")
def surr(cache) -> Surrogate:
    """The test fit: 11 x 11 widths x 6 wavelengths."""
    return _fit(cache, 0.1, 6)


@pytest.fixture(scope="module")
def coarse(cache) -> Surrogate:
    """A planted bad fit: 5 x 5 widths (step 0.25 um) x 4 wavelengths over the same box."""
    return _fit(cache, 0.25, 4)


def test_held_out_error_meets_the_goal(surr):
    err = error_report(surr, 60, rng=0)
    assert err.points.shape == (60, 3)
    for p in "xy":
        assert err.phase_rms_rad[p] <= GOAL_PHASE_RMS_RAD, err.summary()
        assert err.amplitude_rms_pct[p] <= GOAL_AMPLITUDE_RMS_PCT, err.summary()
    assert err.meets()
    assert sum(b["n"] for b in err.by_band) == 60


def test_planted_coarse_fit_fails_the_check(coarse):
    err = error_report(coarse, 60, rng=0)
    assert not err.meets(), err.summary()
    assert max(err.phase_rms_rad.values()) > GOAL_PHASE_RMS_RAD


def test_half_grid_of_the_same_sweep_is_worse_on_the_same_posts(surr, cache):
    """stride=2 interpolates the same library at step 2h; a report reusing the first one's RCWA solves compares
    both on the same posts (the convergence study of benchmarks/bench_surrogate.py)."""
    half = _fit(cache, 0.1, 6, stride=2)
    assert half.meta["stride"] == 2 and half.widths_um.size == 6
    assert half.meta["library_key"] == surr.meta["library_key"]
    fine = error_report(surr, 40, rng=4)
    rough = error_report(half, reference=fine)
    np.testing.assert_array_equal(rough.points, fine.points)
    assert max(rough.phase_rms_rad.values()) > 2 * max(fine.phase_rms_rad.values())
    widths, wls = surrogate_grid(width_range_um=RANGE, width_step_um=0.1, n_wavelengths=6, band_um=BAND)
    lib = compute_library(widths, None, wls, harmonics=M, estimate=False, tol=None, workers=1, progress=False,
                          cache_dir=cache / "library", n_post=3.42, n_substrate=3.42)
    assert lib.meta["key"] == surr.meta["library_key"]  # the same sweep, from the cache
    np.testing.assert_allclose(surrogate_from_library(lib).coef, surr.coef, atol=1e-12)


def test_held_out_points_are_off_the_grid_and_seeded(surr):
    pts = held_out_points(surr, 200, rng=5)
    np.testing.assert_array_equal(pts, held_out_points(surr, 200, rng=5))
    assert np.all(surr.in_range(pts[:, 0], pts[:, 1], pts[:, 2]))
    for col, grid in ((0, surr.widths_um), (1, surr.widths_um), (2, surr.wavelengths_um)):
        assert np.min(np.abs(pts[:, col, None] - grid[None, :])) > 1e-4


def test_interpolates_rcwa_at_the_grid_nodes_in_its_convention(surr):
    """At fitting nodes the surrogate returns post_response's t_x and t_y (both polarisations: t_y is t_x of the
    swapped post)."""
    wx, wy, wl = surr.widths_um[[0, 3, 10]], surr.widths_um[[7, 3, 1]], surr.wavelengths_um[[0, 2, 5]]
    r = post_response(wx, wy, wl, harmonics=M, n_post=3.42, n_substrate=3.42)
    tx, ty = surr.transmission_np(wx, wy, wl)
    np.testing.assert_allclose(tx, r.t_x, atol=1e-9)
    np.testing.assert_allclose(ty, r.t_y, atol=1e-9)


def test_symmetry_broadcasting_and_jax_transforms(surr):
    tx, ty = surr.transmission(jnp.array([1.2, 1.5]), 1.7, jnp.array([[9.8], [10.2]]))
    assert tx.shape == ty.shape == (2, 2)
    tyx, txy = surr.transmission(1.7, jnp.array([1.2, 1.5]), jnp.array([[9.8], [10.2]]))
    np.testing.assert_allclose(np.asarray(ty), np.asarray(tyx), atol=1e-6)
    np.testing.assert_allclose(np.asarray(tx), np.asarray(txy), atol=1e-6)
    f = jax.jit(lambda a, b, lam: jnp.angle(surr.transmission(a, b, lam)[0]))
    v = jax.vmap(f)(jnp.array([1.2, 1.4]), jnp.array([1.6, 1.8]), jnp.array([9.7, 10.3]))
    assert v.shape == (2,)
    g = jax.grad(lambda a, b, lam: jnp.abs(surr.transmission(a, b, lam)[1]), argnums=(0, 1, 2))(1.3, 1.6, 10.1)
    assert all(np.isfinite(float(x)) for x in g)


def _jacobians(s: Surrogate, pts: np.ndarray) -> np.ndarray:
    """d(phase_x, |t_x|, phase_y, |t_y|) / d(wx, wy, lambda) by jax (n, 4, 3), float64."""
    with jax.enable_x64(True):
        def f(p):
            return jnp.stack(s.phase_amplitude(p[0], p[1], p[2]))
        return np.asarray(jax.vmap(jax.jacfwd(f))(jnp.asarray(pts)))


def _rcwa_jacobians(s: Surrogate, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The same derivatives by central differences of the RCWA itself (steps FD_STEP_UM), and |t_x|, |t_y| (n, 2)."""
    out = np.zeros((pts.shape[0], 4, 3))
    abs_t = np.zeros((pts.shape[0], 2))
    for k in range(3):
        d = np.zeros(3)
        d[k] = FD_STEP_UM
        up, dn = pts + d, pts - d
        tp = rcwa_transmission(s, up[:, 0], up[:, 1], up[:, 2])
        tm = rcwa_transmission(s, dn[:, 0], dn[:, 1], dn[:, 2])
        for j, (a, b) in enumerate(zip(tp, tm)):
            out[:, 2 * j, k] = np.angle(a / b) / (2 * FD_STEP_UM)
            out[:, 2 * j + 1, k] = (np.abs(a) - np.abs(b)) / (2 * FD_STEP_UM)
            abs_t[:, j] = (np.abs(a) + np.abs(b)) / 2
    return out, abs_t


def _gradient_misfit(s: Surrogate, ref: tuple[np.ndarray, np.ndarray], pts: np.ndarray) -> dict[str, float]:
    """The worst gradient errors against the RCWA's, on the scales of GRAD_REL."""
    jac, abs_t = ref
    got = _jacobians(s, pts)
    ph, amp = jac[:, 0::2], jac[:, 1::2]  # (n, polarisation, input)
    ph_scale = np.maximum(np.abs(ph), np.sqrt(np.mean(ph ** 2, axis=0, keepdims=True)))
    dt = np.sqrt((abs_t[:, :, None] * ph) ** 2 + amp ** 2)  # |dt / dx|
    dt_scale = np.sqrt(np.mean(dt ** 2, axis=(0, 1), keepdims=True))
    return {"phase": float((np.abs(got[:, 0::2] - ph) / ph_scale).max()),
            "amplitude": float((np.abs(got[:, 1::2] - amp) / dt_scale).max())}


@pytest.fixture(scope="module")
def grad_points(surr):
    pts = held_out_points(surr, 6, rng=11)
    return pts, _rcwa_jacobians(surr, pts)


def test_gradients_match_finite_differences_of_rcwa(surr, grad_points):
    pts, ref = grad_points
    misfit = _gradient_misfit(surr, ref, pts)
    for kind, tol in GRAD_REL.items():
        assert misfit[kind] <= tol, misfit


def test_gradient_check_fails_on_the_planted_bad_fit(coarse, grad_points):
    pts, ref = grad_points
    misfit = _gradient_misfit(coarse, ref, pts)
    assert misfit["phase"] > GRAD_REL["phase"] or misfit["amplitude"] > GRAD_REL["amplitude"], misfit


def test_cached_saved_and_loaded(surr, cache, tmp_path):
    again = _fit(cache, 0.1, 6)
    assert again.meta.get("from_cache") is True
    assert again.meta["key"] == surr.meta["key"]
    p = surr.save(tmp_path / "s.npz")
    back = Surrogate.load(p)
    pts = held_out_points(surr, 5, rng=2)
    np.testing.assert_array_equal(back.transmission_np(*pts.T)[1], surr.transmission_np(*pts.T)[1])
    assert back.meta["harmonics"] == M
    (tmp_path / "bad.npz").write_bytes(b"not a surrogate")
    with pytest.raises(InputError):
        Surrogate.load(tmp_path / "bad.npz")
    est = surr.meta["estimated_phase_rms_rad"]
    assert est is not None and 0 < est < GOAL_PHASE_RMS_RAD


def test_grid_follows_the_platform_and_checks_its_inputs():
    widths, wls = surrogate_grid(PlatformDesign(), width_step_um=0.5, n_wavelengths=5)
    assert widths[0] == 0.5 and widths[-1] == 3.5  # the fabrication range: min feature to period - min feature
    assert wls[0] == 8.0 and wls[-1] == 14.0
    np.testing.assert_allclose(np.diff(1 / wls[::-1]), (1 / 8 - 1 / 14) / 4, rtol=1e-5)  # uniform in 1 / lambda
    with pytest.raises(InputError, match="band_um"):
        surrogate_grid(band_um=(14.0, 8.0))
    with pytest.raises(InputError, match="width_range_um"):
        surrogate_grid(width_range_um=(0.2, 2.0))
    with pytest.raises(InputError, match="width_step_um"):
        surrogate_grid(width_range_um=(1.0, 1.2), width_step_um=0.1)
    with pytest.raises(InputError, match="n_wavelengths"):
        surrogate_grid(n_wavelengths=3)

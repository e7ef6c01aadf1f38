"""metafovea.polarizer: the one model of the rotating polariser. The closed form against the step-by-step physics
(Malus, a first-order bolometer, the extinction leak) and the simulator's alpha against the reconstruction's model."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.signal import lfilter

from metafovea.errors import InputError
from metafovea.imaging.polarizer import Polarizer
from metafovea.polarizer import ALPHA_MEAN, RotatingPolarizer, check_mode
from metafovea.reconstruct.polarizer import PolarizerModel

EXTINCTIONS = (0.0, 0.01, 0.05, 0.3)
TAUS_S = (0.0, 0.004, 0.01, 0.08)
PHASES_RAD = (0.0, 0.3, 1.7, -2.9)


@pytest.mark.parametrize("extinction,tau_s,phase", list(itertools.product(EXTINCTIONS, TAUS_S, PHASES_RAD)))
def test_the_simulators_alpha_is_the_reconstructions_closed_form(extinction, tau_s, phase):
    """The effective alpha the simulator gives its frames (angles, then Malus through the bolometer, then the leak)
    equals the reconstruction model's ``1/2 + s cos(Omega t + phi)`` to 1e-12, for every extinction, lag and phase."""
    t = np.arange(48) / 12.0 + 0.013
    for rate in (2.0, 0.7):
        sim = Polarizer(rate_hz=rate, mode="sync", phase_rad=phase, extinction=extinction, tau_s=tau_s)
        theta, info = sim.angles(t, np.random.default_rng(0))
        alpha, a_eff, gain = sim.mixing(theta)
        model = PolarizerModel(t, rate, "sync", phase_rad=phase, extinction=extinction, tau_s=tau_s)
        np.testing.assert_allclose(a_eff, model.alpha(), rtol=0, atol=1e-12)
        assert gain == 1 + extinction and info["phase_rad"] == phase


@pytest.mark.parametrize("extinction,tau_s", list(itertools.product(EXTINCTIONS, TAUS_S)))
def test_the_old_algebras_agree(extinction, tau_s):
    """The two forms issue 29 found, written out as they were: the simulator's ``(alpha + e (1 - alpha)) / (1 + e)``
    of ``1/2 + A/2 cos(2 theta - atan(w tau))`` (``w = 2 pi 2 f``) and the reconstruction's
    ``1/2 + s cos(Omega t + 2 phase - atan(Omega tau))``, ``s = A (1 - e) / (2 (1 + e))``, against the model."""
    rate, phase, e = 2.0, 0.9, extinction
    t = np.linspace(0.0, 2.0, 97)
    theta = 2 * np.pi * rate * t + phase
    wt = 2 * np.pi * 2 * rate * tau_s
    amp, lag = 1 / math.sqrt(1 + wt * wt), math.atan(wt)
    a0 = 0.5 + 0.5 * amp * np.cos(2 * theta - lag) if tau_s > 0 else np.cos(theta) ** 2
    sim_old = (a0 + e * (1 - a0)) / (1 + e)
    W = 4 * math.pi * rate
    s_old = 0.5 / math.sqrt(1 + (W * tau_s) ** 2) * (1 - e) / (1 + e)
    rec_old = 0.5 + s_old * np.cos(W * t + 2 * phase - math.atan(W * tau_s))
    model = RotatingPolarizer(rate, e, tau_s)
    new = model.alpha(t, model.alpha_phase(phase))
    np.testing.assert_allclose(sim_old, new, rtol=0, atol=1e-12)
    np.testing.assert_allclose(rec_old, new, rtol=0, atol=1e-12)
    np.testing.assert_allclose(model.mixing(theta)[1], new, rtol=0, atol=1e-12)
    # mean and amplitude of the cosine form, whatever the phase: over whole turns
    assert np.mean(new[:-1]) == pytest.approx(ALPHA_MEAN, abs=1e-12)
    assert 0.5 * np.ptp(model.alpha(np.linspace(0, 0.25, 2001), 0.0)) == pytest.approx(model.amplitude, rel=1e-9)


def test_lag_and_extinction_against_the_step_by_step_physics():
    """Malus's cos^2 through dy/dt = (x - y) / tau (integrated in 10 us steps, settled after 20 tau), then the leak
    of ``e`` of the blocked polarisation into each channel normalised by its gain: the closed form to 2e-4
    (the integration's step error; measured 4e-5)."""
    rate, tau, e, phase, dt = 2.0, 0.05, 0.04, 0.4, 1e-5
    model = RotatingPolarizer(rate, e, tau)
    t = np.arange(0.0, 1.5, dt)
    a = np.exp(-dt / tau)
    x_pass = lfilter([1 - a], [1, -a], np.cos(2 * np.pi * rate * t + phase) ** 2, zi=[0.5 * a])[0]
    x_weight, y_weight = x_pass + e * (1 - x_pass), (1 - x_pass) + e * x_pass
    settled = t > 20 * tau
    a_eff = x_weight / (x_weight + y_weight)
    np.testing.assert_allclose(a_eff[settled], model.alpha(t, model.alpha_phase(phase))[settled], atol=2e-4)
    np.testing.assert_allclose(x_weight + y_weight, model.gain, rtol=1e-12)


def test_constants_and_modes_are_checked():
    with pytest.raises(InputError, match="extinction"):
        RotatingPolarizer(extinction=0.7)
    with pytest.raises(InputError, match="tau_s"):
        RotatingPolarizer(tau_s=-1.0)
    with pytest.raises(InputError, match="polarizer mode"):
        check_mode("spin")
    assert RotatingPolarizer(rate_hz=0.0).amplitude == 0.5  # a stopped polariser is a device too
    with pytest.raises(InputError, match="tau_s"):  # both users check through the one model
        PolarizerModel(np.arange(4.0), tau_s=20.0)
    with pytest.raises(InputError, match="extinction"):
        Polarizer(extinction=0.6)

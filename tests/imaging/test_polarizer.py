"""metafovea.imaging.polarizer: the rotating polariser's angles and the mixing ratio it gives the frames."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from metafovea.errors import InputError
from metafovea.imaging.polarizer import SYNC_PHASE_RAD, Polarizer


# ---------------------------------------------------------------------------------------------
# physics references
# ---------------------------------------------------------------------------------------------
def test_polarizer_modes_and_extinction():
    t = np.arange(12) / 12.0
    th, info = Polarizer(phase_rad=0.0).angles(t, np.random.default_rng(0))
    a, ae, gain = Polarizer().mixing(th)
    np.testing.assert_allclose(a, np.cos(2 * np.pi * 2 * t) ** 2)  # Malus: cos^2 of the polariser angle
    np.testing.assert_allclose(a[::3], 1.0)
    th1, i1 = Polarizer(mode="free").angles(t, np.random.default_rng(1))
    th2, i2 = Polarizer(mode="free").angles(t, np.random.default_rng(2))
    assert i1["phase_rad"] != i2["phase_rad"]
    _, ae, gain = Polarizer(extinction=0.05).mixing(th)
    assert gain == pytest.approx(1.05)
    assert ae.max() == pytest.approx(1 / 1.05) and ae.min() >= 0.05 / 1.05 - 1e-12


def test_bolometer_time_constant_is_a_first_order_low_pass_of_malus():
    """alpha with a bolometer time constant tau equals cos^2(theta) passed through dy/dt = (x - y) / tau,
    integrated here step by step (10 us steps, after 20 tau of settling)."""
    rate, tau, dt = 2.0, 0.05, 1e-5
    pol = Polarizer(rate_hz=rate, phase_rad=0.4, tau_s=tau)
    t = np.arange(0.0, 1.5, dt)
    theta, _ = pol.angles(t, np.random.default_rng(0))
    a = np.exp(-dt / tau)
    y = lfilter([1 - a], [1, -a], np.cos(theta) ** 2, zi=[0.5 * a])[0]
    alpha, _, _ = pol.mixing(theta)
    settled = t > 20 * tau
    np.testing.assert_allclose(alpha[settled], y[settled], atol=2e-4)  # measured 4e-5
    # and the modulation depth is 1 / sqrt(1 + (4 pi f tau)^2)
    w = 4 * np.pi * rate * tau
    assert alpha.max() - alpha.min() == pytest.approx(1 / np.sqrt(1 + w * w), rel=1e-4)


def test_sync_default_phase_gives_three_distinct_alphas_per_cycle():
    t = np.arange(6) / 12.0  # 2 Hz at 12 fps: 6 frames per turn, alpha repeats every 3
    th, info = Polarizer().angles(t, np.random.default_rng(0))
    a, _, _ = Polarizer().mixing(th)
    assert info["phase_rad"] == SYNC_PHASE_RAD
    assert len(np.unique(np.round(a, 9))) == 3
    np.testing.assert_allclose(a[:3], [0.913, 0.049, 0.538], atol=1e-3)


def test_bad_polarizer_parameters():
    with pytest.raises(InputError, match="polarizer mode"):
        Polarizer(mode="spin")
    with pytest.raises(InputError, match="extinction"):
        Polarizer(extinction=0.7)

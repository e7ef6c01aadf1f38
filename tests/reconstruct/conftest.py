"""Shared data of the reconstruction tests: a 96 x 96 scene pair with an exact foveal constraint, the reference
polariser's 8 mixing ratios, and a scene in DN with the paper-like radiometric gain and offset."""

from types import SimpleNamespace

import pytest

from metafovea.reconstruct.synthetic import polariser_alpha, scene

N = 96


@pytest.fixture(scope="session")
def truth():
    """``(x1, x2)``, 96 x 96 in [0, 1], ``D x1 == C x2`` exactly."""
    return scene(N)


@pytest.fixture(scope="session")
def alpha8():
    return polariser_alpha(8)


@pytest.fixture(scope="session")
def dn():
    """x1 in [1700, 1760] DN with ``D x1 == 0.3 C x2 + 700`` exactly (x2 ~ 3300-3500 DN): like the paper's F/2 vs F/1
    gain 0.294 and its ``(1 - gain) * 1000`` DN dark level."""
    gain, offset = 0.3, 700.0
    x1, x2 = scene(96, lo=1700.0, hi=1760.0, foveal_gain=gain, foveal_offset=offset)
    return SimpleNamespace(x1=x1, x2=x2, gain=gain, offset=offset)

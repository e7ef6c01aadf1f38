"""A known synthetic recording: foveal and perifoveal scenes in kelvin, through a camera linear in band radiance
(or FLIR's Planck curve), with per-pixel gain and offset non-uniformity, noise and 16-bit quantisation.

The camera: ``counts = p_o + p_g (dark + G L(T))`` per channel, mixed ``alpha u_1 + (1 - alpha) u_2`` by the
polariser, ``G`` 50 DN/K at 300 K, noise ``SIGMA_DN``; blackbody frames through the same pixels."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from metafovea.cli import main
from metafovea.radiometry import BandRadiance
from metafovea.reconstruct.synthetic import measure, polariser_alpha, scene

N, T, FPS = 48, 24, 24.0
SIGMA_DN = 2.0
DARK_DN = 2000.0
DN_PER_K = 50.0
BAND_UM = (8.0, 14.0)
#: FLIR's typical constants (ExifTool names): counts = R1 / (R2 (exp(B / T) - F)) - O
FLIR = {"PlanckR1": 21106.77, "PlanckR2": 0.012545258, "PlanckB": 1501.0, "PlanckF": 1.0, "PlanckO": -7340.0}


@pytest.fixture
def cli(capsys):
    """``cli(*argv)``: ``(exit status, stdout, stderr)`` of ``metafovea ARGV``."""
    def run(*argv):
        rc = main([str(a) for a in argv])
        cap = capsys.readouterr()
        return rc, cap.out, cap.err
    return run


@pytest.fixture(scope="session")
def camera_constants():
    """The constants above and :func:`predicted_noise_k`, for the tests."""
    return SimpleNamespace(N=N, T=T, FPS=FPS, SIGMA_DN=SIGMA_DN, DARK_DN=DARK_DN, DN_PER_K=DN_PER_K, FLIR=FLIR,
                           predicted_noise_k=predicted_noise_k)


@pytest.fixture(scope="session")
def truth():
    """Scene temperatures (K): foveal 290-320 K, perifoveal about the same, 48 x 48; the polariser's alpha."""
    x1, x2 = scene(N)
    return SimpleNamespace(T1=290.0 + 30.0 * x1, T2=290.0 + 30.0 * x2, alpha=polariser_alpha(T, fps=FPS),
                           times=np.arange(T) / FPS, band=BandRadiance.from_band(BAND_UM))


@pytest.fixture(scope="session")
def linear_camera(truth):
    """Frames (uint16) of the linear camera with a 5 % per-pixel gain and +-50 DN offset pattern, and its
    blackbody frames at 293.15 K and 323.15 K (8 each)."""
    rng = np.random.default_rng(1)
    band = truth.band
    G = DN_PER_K / band.derivative(300.0)
    pg = 1.0 + 0.05 * rng.standard_normal((N, N))
    po = 50.0 * rng.standard_normal((N, N))

    def camera(u):
        return np.clip(np.round(po + pg * u), 0, 65534).astype(np.uint16)

    u1, u2 = DARK_DN + G * band(truth.T1), DARK_DN + G * band(truth.T2)
    frames = camera(measure(u1, u2, truth.alpha, sigma=SIGMA_DN, rng=rng))
    bb = {t: camera(DARK_DN + G * band(np.full((8, N, N), t)) + SIGMA_DN * rng.standard_normal((8, N, N)))
          for t in (293.15, 323.15)}
    return SimpleNamespace(frames=frames, blackbody=bb, u1=u1, u2=u2)


@pytest.fixture(scope="session")
def flir_camera(truth):
    """Frames (uint16) of a camera on FLIR's Planck curve (uniform pixels), as the channels mix them."""
    rng = np.random.default_rng(2)
    R = FLIR["PlanckR1"] / FLIR["PlanckR2"]

    def counts(t):
        return R / (np.exp(FLIR["PlanckB"] / t) - FLIR["PlanckF"]) - FLIR["PlanckO"]

    frames = measure(counts(truth.T1), counts(truth.T2), truth.alpha, sigma=SIGMA_DN, rng=rng)
    return SimpleNamespace(frames=np.round(frames).astype(np.uint16))


def predicted_noise_k(alpha, dn_per_k: float = DN_PER_K, window: int = 8) -> float:
    """The per-pixel temperature noise (K) of a known-alpha LSQ separation over ``window`` frames: the largest
    ``sigma sqrt((N^-1)_ii) / (DN per K)`` over the windows, ``sigma`` the frame noise with 16-bit quantisation,
    ``N = sum_t [a_t, 1 - a_t]^T [a_t, 1 - a_t]``."""
    sig = np.hypot(SIGMA_DN, np.sqrt(1.0 / 12.0))
    worst = 0.0
    for s in range(len(alpha) - window + 1):
        a = np.asarray(alpha[s:s + window])
        A = np.stack([a, 1 - a], axis=1)
        worst = max(worst, float(np.sqrt(np.max(np.diag(np.linalg.inv(A.T @ A))))))
    return sig * worst / dn_per_k

"""The rotating polariser: one model of the mixing ratio alpha, used by the simulator and the reconstruction.

A polariser turning at ``f_p`` (Hz) in front of the sensor passes the fraction ``alpha_t`` of the x-polarised
(foveal) image and ``1 - alpha_t`` of the y-polarised (perifoveal) one. The model, in the order the light meets it:

1. Angle law: ``theta(t) = 2 pi f_p t + theta_0`` (``theta_0``: the rotation's phase at ``t = 0``).
2. Malus's law: ``alpha_0(t) = cos^2 theta = 1/2 + 1/2 cos(Omega t + 2 theta_0)``, ``Omega = 4 pi f_p`` (alpha turns
   twice per revolution).
3. Bolometer lag: a first-order sensor of time constant ``tau`` (``dy/dt = (x - y) / tau``) passes the mean and
   scales the ``Omega`` term by ``A = 1 / sqrt(1 + (Omega tau)^2)``, delaying it by ``atan(Omega tau)``:
   ``alpha = 1/2 + A/2 cos(2 theta - atan(Omega tau))``.
4. Extinction: a polariser leaks the fraction ``e`` of the blocked polarisation: the sensor sees
   ``alpha + e (1 - alpha)`` of x and ``1 - alpha + e alpha`` of y, that is ``(1 + e) [a' x1 + (1 - a') x2]`` with the
   effective ratio ``a' = (alpha + e (1 - alpha)) / (1 + e)`` and the gain ``1 + e``.

Together (the closed form the reconstruction fits)::

    a'(t) = 1/2 + s cos(Omega t + phi),   s = A (1 - e) / (2 (1 + e)),   phi = 2 theta_0 - atan(Omega tau)

since ``a' = (e + (1 - e) alpha) / (1 + e)`` and ``alpha = 1/2 + A/2 cos(.)``: the mean stays 1/2 whatever the
extinction, lag and phase, and the amplitude ``s`` is known from the device's three constants
(:class:`RotatingPolarizer`: ``rate_hz``, ``extinction``, ``tau_s``).

What is not a constant of the device lives with its user: the simulator's draws of a free-running rotation (phase,
rate error) in :mod:`metafovea.imaging.polarizer`; the reconstruction's fit of phase and frequency, and the alpha
gauge it fixes, in :mod:`metafovea.reconstruct.polarizer`. ``mode`` (:data:`MODES`) says which of the rotation's phase
and rate are known: ``'sync'`` (locked to the frames: both) or ``'free'`` (free-running: neither, the rate within a
tolerance of the nominal one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from metafovea.errors import check_choice, check_range

#: the polariser's modes: ``'sync'`` (rotation locked to the frames, phase and rate known), ``'free'`` (free-running)
MODES = ("sync", "free")
#: the mean of alpha over a turn, whatever the extinction, lag and phase
ALPHA_MEAN = 0.5


def check_mode(mode: str) -> str:
    """``mode`` if it is one of :data:`MODES`, else :class:`~metafovea.errors.InputError` naming ``polarizer mode``."""
    return check_choice("polarizer mode", mode, MODES)


@dataclass(frozen=True)
class RotatingPolarizer:
    """The device's constants: rotation rate, extinction leak and the bolometer's time constant.

    Parameters
    ----------
    rate_hz : float, Hz
        Revolutions per second of the polariser (alpha's frequency is twice this). 0 is a stopped polariser.
    extinction : float
        Leaked fraction ``e`` of the blocked polarisation, in [0, 0.5] (0: ideal).
    tau_s : float, s
        First-order time constant of the bolometer, in [0, 10] (0: instantaneous).

    Notes
    -----
    The model, its closed form ``a'(t) = 1/2 + s cos(Omega t + phi)`` and its derivation are in the module docstring.
    """

    rate_hz: float = 2.0
    extinction: float = 0.0
    tau_s: float = 0.0

    def __post_init__(self) -> None:
        check_range("polarizer rate_hz", self.rate_hz, 0.0, 1000.0, lo_inclusive=True, unit="Hz")
        check_range("extinction", self.extinction, 0.0, 0.5, lo_inclusive=True)
        check_range("tau_s", self.tau_s, 0.0, 10.0, lo_inclusive=True, unit="s")

    @property
    def omega(self) -> float:
        """``Omega = 4 pi f_p`` (rad/s): alpha's angular frequency, twice the rotation's."""
        return 4 * math.pi * self.rate_hz

    @property
    def response(self) -> float:
        """``A = 1 / sqrt(1 + (Omega tau)^2)``: the bolometer's amplitude response at ``Omega``."""
        wt = self.omega * self.tau_s
        return 1.0 / math.sqrt(1.0 + wt * wt)

    @property
    def lag_rad(self) -> float:
        """``atan(Omega tau)``: the bolometer's phase lag at ``Omega`` (rad)."""
        return math.atan(self.omega * self.tau_s)

    @property
    def gain(self) -> float:
        """``1 + e``: the frames' gain from the leaked polarisation."""
        return 1.0 + self.extinction

    @property
    def amplitude(self) -> float:
        """``s = A (1 - e) / (2 (1 + e))``: half the peak-to-peak range of the effective alpha."""
        return 0.5 * self.response * (1.0 - self.extinction) / (1.0 + self.extinction)

    def alpha_phase(self, phase_rad: float) -> float:
        """``phi = 2 theta_0 - atan(Omega tau)``: the closed form's phase for a rotation of phase ``theta_0``."""
        return 2 * float(phase_rad) - self.lag_rad

    def angles(self, times_s: ArrayLike, phase_rad: float, rate_hz: float | None = None) -> np.ndarray:
        """``theta(t) = 2 pi f t + theta_0`` (rad) at ``times_s`` (s); ``rate_hz`` (default the nominal rate) is the
        rate the rotation actually turns at."""
        rate = self.rate_hz if rate_hz is None else rate_hz
        return 2 * np.pi * rate * np.asarray(times_s) + phase_rad

    def nominal_alpha(self, theta: ArrayLike) -> np.ndarray:
        """Malus's ``cos^2 theta`` as the bolometer sees it: ``1/2 + A/2 cos(2 theta - lag)`` (exactly ``cos^2`` for
        ``tau_s = 0``), before the extinction leak."""
        theta = np.asarray(theta)
        if self.tau_s > 0:
            return 0.5 + 0.5 * self.response * np.cos(2 * theta - self.lag_rad)
        return np.cos(theta) ** 2

    def leak(self, alpha: ArrayLike) -> np.ndarray:
        """The effective ratio ``a' = (alpha + e (1 - alpha)) / (1 + e)`` of a nominal ``alpha``."""
        alpha = np.asarray(alpha)
        e = self.extinction
        return (alpha + e * (1 - alpha)) / (1 + e)

    def mixing(self, theta: ArrayLike) -> tuple[np.ndarray, np.ndarray, float]:
        """``(alpha, a', 1 + e)`` at the angles ``theta``: the sensor sees ``(1 + e) [a' x1 + (1 - a') x2]``."""
        alpha = self.nominal_alpha(theta)
        return alpha, self.leak(alpha), self.gain

    def alpha(self, times_s: ArrayLike, phase: float, omega: float | None = None) -> np.ndarray:
        """The closed form ``a'(t) = 1/2 + s cos(omega t + phase)`` at ``times_s`` (s), for alpha's phase ``phase``
        (:meth:`alpha_phase` of the rotation's) and angular frequency ``omega`` (default :attr:`omega`)."""
        w = self.omega if omega is None else omega
        return ALPHA_MEAN + self.amplitude * np.cos(w * np.asarray(times_s, dtype=np.float64) + phase)


__all__ = ["ALPHA_MEAN", "MODES", "RotatingPolarizer", "check_mode"]

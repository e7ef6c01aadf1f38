"""The simulated rotating polariser: the realised rotation and the mixing ratio alpha it gives each frame.

The physics (angle law, Malus, bolometer lag, extinction leak, the frames' ``(1 + e) [a' x1 + (1 - a') x2]``) is
:mod:`metafovea.polarizer`'s :class:`~metafovea.polarizer.RotatingPolarizer`; this module adds what a simulation
draws. ``sync`` mode: the phase is given (default :data:`SYNC_PHASE_RAD`) and the rotation is locked to the frames at
the nominal rate; ``free`` mode: the phase is drawn from ``rng`` (unknown to a reconstruction) and the rate is off by a
random relative error (``rate_error``, standard deviation).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.errors import check_range
from metafovea.polarizer import RotatingPolarizer, check_mode

#: default polariser phase in sync mode: 0.3 rad gives three distinct alphas per 2 Hz / 12 fps cycle
#: (0.913, 0.049, 0.538); phase 0 would give only two (1, 0.25, 0.25) and a repeated value
SYNC_PHASE_RAD = 0.3


@dataclass(frozen=True)
class Polarizer:
    """Rotating polariser of the simulator: the device (:attr:`physics`) and how its rotation is drawn.

    Parameters
    ----------
    rate_hz : float, Hz
        Nominal revolutions per second.
    mode : {'sync', 'free'}
        ``'sync'``: locked to the frames (phase ``phase_rad``, nominal rate); ``'free'``: phase and rate drawn.
    phase_rad : float or None, rad
        The rotation's phase at ``t = 0``; None: :data:`SYNC_PHASE_RAD` in sync mode, drawn from ``rng`` in free mode.
    rate_error : float
        Free mode: relative standard deviation of the actual rotation rate.
    extinction : float
        Leaked fraction of the blocked polarisation.
    tau_s : float, s
        Bolometer time constant.
    """

    rate_hz: float = 2.0
    mode: str = "sync"
    phase_rad: float | None = None
    rate_error: float = 0.002
    extinction: float = 0.0
    tau_s: float = 0.0

    def __post_init__(self) -> None:
        RotatingPolarizer(self.rate_hz, self.extinction, self.tau_s)  # checks the device's constants
        object.__setattr__(self, "mode", check_mode(self.mode))
        check_range("rate_error", self.rate_error, 0.0, 0.5, lo_inclusive=True)

    @property
    def physics(self) -> RotatingPolarizer:
        """The device's constants and the model of alpha (:class:`~metafovea.polarizer.RotatingPolarizer`)."""
        return RotatingPolarizer(self.rate_hz, self.extinction, self.tau_s)

    def angles(self, times_s: ArrayLike, rng: np.random.Generator) -> tuple[np.ndarray, dict[str, Any]]:
        """Polariser angles (rad) at ``times_s`` (s) and the realised ``mode``, ``rate_hz`` and ``phase_rad``."""
        rate = self.rate_hz
        if self.mode == "free":
            phase = float(rng.uniform(0, 2 * np.pi)) if self.phase_rad is None else float(self.phase_rad)
            rate = rate * (1.0 + self.rate_error * float(rng.standard_normal()))
        else:
            phase = SYNC_PHASE_RAD if self.phase_rad is None else float(self.phase_rad)
        theta = self.physics.angles(times_s, phase, rate)
        return theta, {"mode": self.mode, "rate_hz": rate, "phase_rad": phase}

    def mixing(self, theta: ArrayLike) -> tuple[np.ndarray, np.ndarray, float]:
        """(nominal alpha, effective alpha a', gain 1 + e) so that the sensor sees ``(1 + e) [a' I1 + (1 - a') I2]``
        (:meth:`metafovea.polarizer.RotatingPolarizer.mixing`)."""
        return self.physics.mixing(theta)

"""The rotating polariser and the mixing ratio alpha it gives each frame.

``theta(t) = 2 pi f_p t + phase`` (``f_p = 2 Hz``). ``alpha_t = cos^2 theta_t`` of the x (foveal) power
reaches the sensor and ``1 - alpha_t`` of the y (perifoveal). ``sync`` mode: the phase is given
(default 0.3 rad, three distinct alphas per cycle) and the rotation is locked to the frames; ``free`` mode: the
phase is drawn from ``rng`` (unknown to a reconstruction) and the rate is off by a random relative error
(``rate_error``). A finite extinction leaks ``eps`` of the blocked polarisation: weights ``alpha + eps (1 - alpha)``
and ``1 - alpha + eps alpha``, which the simulator writes as ``(1 + eps) [a' x1 + (1 - a') x2]``.
An optional bolometer time constant ``tau`` low-passes alpha (amplitude ``1/sqrt(1 + (w tau)^2)``,
lag ``atan(w tau)``, ``w = 4 pi f_p``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from metafovea.errors import check_choice, check_range

#: default polariser phase in sync mode: 0.3 rad gives three distinct alphas per 2 Hz / 12 fps cycle
#: (0.913, 0.049, 0.538); phase 0 would give only two (1, 0.25, 0.25) and a repeated value
SYNC_PHASE_RAD = 0.3


@dataclass(frozen=True)
class Polarizer:
    """Rotating polariser: ``theta(t) = 2 pi rate t + phase``; see module docstring."""

    rate_hz: float = 2.0
    mode: str = "sync"  # 'sync' or 'free'
    phase_rad: float | None = None  # None: SYNC_PHASE_RAD in sync mode, drawn from rng in free mode
    rate_error: float = 0.002  # free mode: relative std of the actual rotation rate
    extinction: float = 0.0
    tau_s: float = 0.0

    def __post_init__(self) -> None:
        check_range("polarizer rate_hz", self.rate_hz, 0.0, 1000.0, lo_inclusive=True, unit="Hz")
        object.__setattr__(self, "mode", check_choice("polarizer mode", self.mode, ("sync", "free")))
        check_range("rate_error", self.rate_error, 0.0, 0.5, lo_inclusive=True)
        check_range("extinction", self.extinction, 0.0, 0.5, lo_inclusive=True)
        check_range("tau_s", self.tau_s, 0.0, 10.0, lo_inclusive=True, unit="s")

    def angles(self, times_s: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, dict[str, Any]]:
        """Polariser angles (rad) at ``times_s`` and the realised parameters."""
        rate = self.rate_hz
        if self.mode == "free":
            phase = float(rng.uniform(0, 2 * np.pi)) if self.phase_rad is None else float(self.phase_rad)
            rate = rate * (1.0 + self.rate_error * float(rng.standard_normal()))
        else:
            phase = SYNC_PHASE_RAD if self.phase_rad is None else float(self.phase_rad)
        return 2 * np.pi * rate * np.asarray(times_s) + phase, {"mode": self.mode, "rate_hz": rate, "phase_rad": phase}

    def mixing(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """(nominal alpha, effective alpha a', gain 1 + eps) so that the sensor sees
        ``(1 + eps) [a' I1 + (1 - a') I2]``."""
        if self.tau_s > 0:
            wt = 2 * np.pi * 2 * self.rate_hz * self.tau_s
            amp, lag = 1 / math.sqrt(1 + wt * wt), math.atan(wt)
            alpha = 0.5 + 0.5 * amp * np.cos(2 * theta - lag)
        else:
            alpha = np.cos(theta) ** 2
        e = self.extinction
        a_eff = (alpha + e * (1 - alpha)) / (1 + e)
        return alpha, a_eff, 1.0 + e

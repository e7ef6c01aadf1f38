"""Microbolometer sensor: radiance to digital numbers, temporal noise, low-rank FPN, 14-bit ADC.

Units: frames are **digital numbers (DN)** of the ADC, stored as float32 (integers after
quantisation). The response is linear in the in-band radiance ``L`` reaching each pixel::

    DN = dark_dn + counts_per_k * g_i * L / (dL/dT at 300 K)

``g_i`` is the channel's relative radiometric gain: 1 for the perifoveal (F/1) channel and
``(NA1 / NA2)^2`` (0.294 for the paper's F/2 foveal lens) for the foveal one, times ``cos^4`` relative
illumination. So ``counts_per_k`` is the DN change for 1 K at 300 K seen through the perifoveal channel
alone (alpha = 0); the NETD is specified the same way: temporal noise ``sigma_DN = netd_k *
counts_per_k`` (white Gaussian, signal independent: Johnson and 1/f noise of the bolometer and readout
dominate). Seen through the foveal channel the same noise is ``netd / g_1`` kelvin (~170 mK for 50 mK).

Fixed-pattern noise (FPN): ``F = U diag(s) V^T`` of exactly ``rank`` r: a column-stripe
component (readout column amplifiers), a row-stripe component, smooth low-order shading and random
components (zero mean except the shading). ``max |F| = fpn_amplitude * dynamic range`` (the config's convention;
the dynamic range is that of the noise-free images, at least ``counts_per_k * 1 K``). Optional slow drift: the r
component weights vary as ``s_k (1 + drift * w_k(t))`` with smooth random ``w_k`` (|w| <= 1) over
``drift_period_s``; the pattern stays rank r in each frame.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from metafovea.config import PAPER_CROP_PX, PAPER_FRAME_RATE_HZ, PAPER_PIXEL_PITCH_UM, SensorDesign
from metafovea.errors import InputError, as_rng, check_int, check_positive, check_range

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FixedPattern:
    """Low-rank FPN: ``fpn_t = (U * (s * (1 + drift * w_t))) @ V.T``.

    u: (H, r), v: (W, r), s: (r,) DN, w: (T, r) drift shapes (None without drift), drift: amplitude.
    """

    u: np.ndarray
    v: np.ndarray
    s: np.ndarray
    w: np.ndarray | None = None
    drift: float = 0.0

    @property
    def rank(self) -> int:
        return int(self.s.size)

    def weights(self, k: int | None = None) -> np.ndarray:
        if self.w is None or k is None or self.drift == 0:
            return self.s
        return self.s * (1.0 + self.drift * self.w[k])

    def frame(self, k: int | None = None) -> np.ndarray:
        """The pattern (H, W) float32 in frame ``k`` (``None``: without drift)."""
        if self.rank == 0:
            return np.zeros((self.u.shape[0], self.v.shape[0]), np.float32)
        return ((self.u * self.weights(k)) @ self.v.T).astype(np.float32)


@dataclass(frozen=True)
class SensorModel:
    """Sensor parameters (see module docstring). Build from a config with :meth:`from_design`."""

    pixel_pitch_um: float = PAPER_PIXEL_PITCH_UM
    shape: tuple[int, int] = (PAPER_CROP_PX, PAPER_CROP_PX)
    frame_rate_hz: float = PAPER_FRAME_RATE_HZ
    netd_k: float = 0.05
    counts_per_k: float = 40.0
    dark_dn: float = 1000.0
    adc_bits: int = 14
    fpn_rank: int = 20
    fpn_amplitude: float = 0.1
    fpn_drift: float = 0.0
    drift_period_s: float = 60.0
    noise: bool = True
    quantize: bool = True

    def __post_init__(self) -> None:
        # from a tenth of the 10 um wavelength up: finer, the supersampled pixel kernels outgrow memory, while LWIR
        # bolometers are 10-50 um
        check_range("pixel_pitch_um", self.pixel_pitch_um, 1.0, 1000.0, lo_inclusive=True, unit="um")
        if len(self.shape) != 2:
            raise InputError("shape", self.shape, "(rows, columns)")
        for v in self.shape:
            check_int("sensor crop (rows, columns)", v, 8, 8192)
        check_positive("frame_rate_hz", self.frame_rate_hz, "Hz", hi=1e5)
        check_range("netd_k", self.netd_k, 0.0, 10.0, lo_inclusive=True, unit="K")
        check_positive("counts_per_k", self.counts_per_k, "DN/K", hi=1e6)
        check_range("dark_dn", self.dark_dn, 0.0, 2.0 ** 32, lo_inclusive=True, unit="DN")
        check_int("adc_bits", self.adc_bits, 1, 32)
        r = check_int("fpn_rank", self.fpn_rank, 0, 10**9)
        if r > min(self.shape):
            raise InputError("fpn_rank", r, f"integer 0 <= fpn_rank <= {min(self.shape)} (the smaller side of the "
                             f"{self.shape[0]} x {self.shape[1]} crop)",
                             detail="set by fpn_rank=... or the system file's [sensor] fpn_rank")
        check_range("fpn_amplitude", self.fpn_amplitude, 0.0, 1.0, lo_inclusive=True)
        check_range("fpn_drift", self.fpn_drift, 0.0, 1.0, lo_inclusive=True)
        check_positive("drift_period_s", self.drift_period_s, "s")

    @classmethod
    def from_design(cls, s: SensorDesign, **overrides: Any) -> SensorModel:
        kw = dict(pixel_pitch_um=s.pixel_pitch_um, shape=tuple(s.crop), frame_rate_hz=s.frame_rate_hz,
                  netd_k=s.netd_k, adc_bits=s.adc_bits, fpn_rank=s.fpn_rank, fpn_amplitude=s.fpn_amplitude)
        kw.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**kw)

    @property
    def full_scale_dn(self) -> float:
        return float(2 ** self.adc_bits - 1)

    @property
    def noise_sigma_dn(self) -> float:
        return self.netd_k * self.counts_per_k if self.noise else 0.0

    def frame_times(self, n: int, t0: float = 0.0) -> np.ndarray:
        n = check_int("frames", n, 1, 1_000_000)
        return t0 + np.arange(n, dtype=np.float64) / self.frame_rate_hz

    def to_dn(self, radiance: np.ndarray, gain: float, dl_dt_300: float) -> np.ndarray:
        """Noise-free DN (float) of an image of in-band radiance seen with relative gain ``gain``."""
        return self.dark_dn + (self.counts_per_k * gain / dl_dt_300) * radiance

    # ----------------------------------------------------------------------------------------------
    def make_fpn(self, dynamic_range_dn: float, times_s: np.ndarray,
                 rng: np.random.Generator | int | None) -> FixedPattern:
        """Zero-mean rank-``fpn_rank`` pattern with ``max |F| = fpn_amplitude * max(range, counts_per_k)``."""
        rng = as_rng(rng)
        H, W = self.shape
        r = self.fpn_rank
        if r == 0 or self.fpn_amplitude == 0:
            return FixedPattern(np.zeros((H, 0)), np.zeros((W, 0)), np.zeros(0))
        yy = np.linspace(-1, 1, H)
        xx = np.linspace(-1, 1, W)
        us, vs = [], []
        for k in range(r):
            if k == 0:  # column stripes (column amplifiers) with a little row dependence
                u, v = 1.0 + 0.1 * yy, rng.standard_normal(W)
            elif k == 1:  # row stripes
                u, v = rng.standard_normal(H), 1.0 + 0.1 * xx
            elif k == 2:  # smooth shading (narcissus / vignetting of the housing)
                u, v = 1.0 - yy ** 2, 1.0 - xx ** 2
            else:  # random components, half smooth half stripe-like
                if k % 2:
                    u = np.cumsum(rng.standard_normal(H))
                    v = np.cumsum(rng.standard_normal(W))
                else:
                    u, v = rng.standard_normal(H), rng.standard_normal(W)
            us.append(u - u.mean() if k != 2 else u)
            vs.append(v - v.mean() if k != 2 else v)
        U = np.stack(us, axis=1)
        V = np.stack(vs, axis=1)
        # orthonormalise so that the pattern has exactly rank r and the weights are its singular values
        qu, ru = np.linalg.qr(U)
        qv, rv = np.linalg.qr(V)
        core = ru @ np.diag(np.exp(-0.35 * np.arange(r))) @ rv.T  # decaying component strengths
        a, s, bt = np.linalg.svd(core)
        U, V = qu @ a, qv @ bt.T
        F = (U * s) @ V.T
        rng_dn = max(float(dynamic_range_dn), self.counts_per_k)
        scale = self.fpn_amplitude * rng_dn / max(float(np.abs(F).max()), 1e-300)
        w = None
        if self.fpn_drift > 0:
            t = np.asarray(times_s, dtype=np.float64)
            ph = rng.uniform(0, 2 * np.pi, size=(2, r))
            w = 0.5 * (np.sin(2 * np.pi * t[:, None] / self.drift_period_s + ph[0])
                       + np.sin(2 * np.pi * t[:, None] / (1.7 * self.drift_period_s) + ph[1]))
        return FixedPattern(U, V, s * scale, w, self.fpn_drift)

    def add_noise_and_digitise(self, frames: np.ndarray, rng: np.random.Generator | int | None, chunk: int = 8) -> None:
        """In place: add white Gaussian noise (``noise_sigma_dn``) then round and clip to the ADC range.

        Noise is drawn in fixed chunks of ``chunk`` frames (float32), so memory stays bounded by the
        frames and the same seed gives the same frames.
        """
        rng = as_rng(rng)
        sig = self.noise_sigma_dn
        for k0 in range(0, frames.shape[0], chunk):
            blk = frames[k0:k0 + chunk]
            if sig > 0:
                n = rng.standard_normal(blk.shape, dtype=np.float32)
                n *= np.float32(sig)
                blk += n
            if self.quantize:
                np.rint(blk, out=blk)
                np.clip(blk, 0.0, self.full_scale_dn, out=blk)

    def summary(self) -> dict[str, Any]:
        return {"pixel_pitch_um": self.pixel_pitch_um, "shape": list(self.shape), "frame_rate_hz": self.frame_rate_hz,
                "netd_k": self.netd_k, "counts_per_k": self.counts_per_k, "dark_dn": self.dark_dn,
                "adc_bits": self.adc_bits, "noise_sigma_dn": self.noise_sigma_dn, "fpn_rank": self.fpn_rank,
                "fpn_amplitude": self.fpn_amplitude, "fpn_drift": self.fpn_drift, "drift_period_s": self.drift_period_s,
                "noise": self.noise, "quantize": self.quantize}

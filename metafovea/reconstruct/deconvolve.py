"""PSF-aware reconstruction: joint separation and deconvolution of the two channels, to scene radiance and kelvin.

The frames of a static scene through the camera are, per pixel and frame (DN, after the fixed pattern)::

    y_t = a_t u_1 + (1 - a_t) u_2 + n_t,    u_i = offset + r_i (K_i * s_i + p_i mean(s_i))

with ``a_t`` the mixing ratios, ``K_i`` channel ``i``'s PSF on the pixel grid (core, chromatic haze and glare,
:func:`metafovea.imaging.kernels.pixel_psf`), ``p_i`` its pedestal (the power of disks wider than the crop, a
uniform level), ``r_i`` its relative illumination, ``offset`` the sensor's dark level and ``s_i`` the scene in DN
above it as a perfect lens would image it. The per-pixel normal equations of the frames (``N = sum_t [a_t,
1 - a_t]^T [a_t, 1 - a_t]``, the same 2 x 2 matrix at every pixel) are a sufficient statistic: the separated
``u_hat = N^-1 sum_t [a_t, 1 - a_t]^T y_t`` carry every bit of the frames' information about ``s`` with noise
covariance ``sigma^2 N^-1``, correlated between the channels. The joint problem is therefore solved exactly per
spatial frequency, one 2 x 2 system for both channels, on a grid padded by the kernels' radius (mirror
boundary), with

* ``method='wiener'`` (default): the linear minimum-mean-square-error estimate with the scene spectrum estimated
  from the crop's Hann-tapered periodogram over the PSF's ``|D|^2``: ``prior='hybrid'`` (default) fits a power law
  ``c / |f|^beta`` on the detected bins beyond the spectrum's peak, and below that tail, where the signal exceeds
  4x the noise, takes the padded grid's own measured spectrum (radially averaged periodogram less the noise, over
  ``|D|^2``); ``'power-law'`` fits all detected bins, ``'empirical'`` uses the crop's measured spectrum alone (both
  measured worse, BENCHMARKS.md); the mean is not shrunk. The fitted law is per pixel of the crop, the solve per
  bin of the padded grid, whose padding (the crop's edge values) carries no texture but stripes along the axes:
  ``prior_scale='geometric'`` (default) spreads the law as ``sqrt(n_crop n_grid) x PSD``, between ``'grid'``
  (``n_grid x PSD``, the estimator before 2026-12-03: too much prior power at high frequencies, 10-400x the padded
  truth's on the siemens star) and ``'crop'`` (``n_crop x PSD``: too little where the padding extends edges);
* ``method='tv'``: total-variation regularised least squares, ``min_s 1/2 ||u_hat - A s||^2_{C^-1}
  + sum_i lambda_i TV(s_i)`` by ADMM (every linear step per frequency or per pixel), started from the Wiener
  estimate, ``lambda_i = 1 / mean |grad s_i|`` of that estimate (the scale of a Laplace prior on the gradients);
  1.5-2.5 dB above the Wiener estimate with the 10 um filter, ~20x slower;

the boundary: the crop is padded by the kernels' radius with its edge values (``pad_mode='edge'``, measured best
of edge / reflect / mean / ramp), and the foveal channel's padding is then replaced by what the perifoveal estimate
predicts there (the foveal haze gathers light from several crop widths around the fovea, which the perifoveal
channel images: ``foveal_scale``, the channels' 6x relation), level-matched to the data by a quadratic surface and
either alone or joined to the data's edge values below the perifoveal Nyquist frequency, whichever solution explains
the foveal data better (:func:`_foveal_surround`);
``boundary='unknown'`` solves for the scene beyond the crop instead (far less determined: not used by default);

and the reference bound :func:`wiener_bound`: the same linear estimate with the true scene's (radially averaged)
power spectrum, the true PSFs and the noise: the best a stationary linear reconstruction can do. ``sigma``, the
frames' temporal noise, is estimated from the residuals of the per-pixel fit (``T > 2``). (The bound pads each
channel with its own edge values; it is a reference, not a limit a non-linear or a joint-boundary method obeys.)

Measured (``benchmarks/bench_deconvolve.py --calibration-frames 16``, BENCHMARKS.md; 290 x 290, known alpha, the
FPN from 16 shutter frames with its error counted, PSNR against the scene; eight scenes x two bands, 48 frames,
seed 7): at or above the bound in 23 of 32 channel cases (mean margin +0.91 dB); the siemens star's foveal channel
+0.18 / +0.23 dB (8-14 / 10 um; -0.78 / -0.04 before the padded-grid prior and the level-matched surround),
tall-buildings' -0.31 dB at 8-14 um (was -1.98); below it by 0.01-0.74 dB in nine channel cases.

Temperatures: ``L = s dL/dT(300 K) / (counts_per_k g_i)`` (the radiometric calibration the simulator writes as
``dn_per_k_300K``) is in-band radiance, and its brightness temperature the inverse of the band's ``L(T)``
(:meth:`metafovea.radiometry.BandRadiance.temperature`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from metafovea.errors import InputError, check_choice, check_int

#: the foveal surround's low-pass (Gaussian sigma, px per unit of the channels' scale): half power at the perifoveal
#: channel's Nyquist frequency 0.5 / scale cycles per foveal pixel (sigma = sqrt(ln 2 / 2) / (pi f))
SURROUND_SIGMA_PER_SCALE = math.sqrt(math.log(2.0) / 2.0) / (math.pi * 0.5)

#: methods of :func:`separate_deconvolve`
DECONVOLUTION_METHODS = ("tv", "wiener")
#: scene spectrum models of the Wiener step (:func:`separate_deconvolve` ``prior``)
PRIORS = ("hybrid", "power-law", "empirical")
#: spectral power-law exponents the Wiener prior's fit may take
BETA_RANGE = (1.0, 4.0)
#: how the crop's fitted spectrum (per pixel) becomes the padded grid's (per FFT bin) in :func:`separate_deconvolve`
#: (``prior_scale``): ``'grid'`` as if the whole grid carried the crop's texture (n_grid x PSD), ``'crop'`` as if only
#: the crop did (n_crop x PSD; the edge padding adds stripes along the axes only), ``'geometric'`` their geometric
#: mean (default; BENCHMARKS.md "PSF-aware": chosen on 8 cases, checked on 4 more)
PRIOR_SCALES = ("geometric", "grid", "crop")


@dataclass(frozen=True)
class ChannelPSFs:
    """Both channels' PSFs on the pixel grid: ``kernels`` ``(n_i, n_i)`` odd, centred; ``pedestals`` (power beyond
    the kernels, uniform); ``illumination`` ``(H, W)`` each or None (1); ``source`` where they came from."""

    kernels: tuple[np.ndarray, np.ndarray]
    pedestals: tuple[float, float] = (0.0, 0.0)
    illumination: tuple[np.ndarray | None, np.ndarray | None] = (None, None)
    source: str = "given"

    def __post_init__(self) -> None:
        ks = []
        for i, k in enumerate(self.kernels, start=1):
            a = np.asarray(k, dtype=np.float64)
            if a.ndim != 2 or a.shape[0] != a.shape[1] or a.shape[0] % 2 == 0:
                raise InputError(f"psf_x{i}", f"array of shape {a.shape}", "a square kernel of odd size, centred")
            if not np.all(np.isfinite(a)) or a.min() < 0 or a.sum() <= 0:
                raise InputError(f"psf_x{i}", "kernel", "finite values >= 0 with a positive sum")
            ks.append(a)
        object.__setattr__(self, "kernels", tuple(ks))
        peds = []
        for i, p in enumerate(self.pedestals, start=1):
            if not (math.isfinite(p) and -1e-9 <= p < 1):
                raise InputError(f"pedestal_x{i}", p, "a power fraction in [0, 1)")
            peds.append(max(0.0, float(p)))  # a rounding residue below 0 is 0
        object.__setattr__(self, "pedestals", tuple(peds))

    @classmethod
    def from_measurement(cls, m: Any) -> ChannelPSFs:
        """The PSFs a Measurement carries (``extras`` ``psf_x1``/``psf_x2``, ``illumination_x*``, the pedestals in
        ``meta['psf']['pixel']``), as :func:`metafovea.imaging.simulate.simulate` writes them."""
        ex = m.extras
        if "psf_x1" not in ex or "psf_x2" not in ex:
            raise InputError("measurement", m.source or "in memory", "a file with the channel PSFs 'psf_x1' and "
                             "'psf_x2' (metafovea simulate writes them), or a PSF file (--psf)", source=m.source)
        pix = (m.meta.get("psf") or {}).get("pixel") or {}
        ped = tuple(float((pix.get(f"x{i}") or {}).get("pedestal", 0.0)) for i in (1, 2))
        ill = tuple(ex.get(f"illumination_x{i}") for i in (1, 2))
        return cls((ex["psf_x1"], ex["psf_x2"]), ped, ill, source=m.source or "measurement")

    @classmethod
    def from_file(cls, path: Any, name: str = "--psf") -> ChannelPSFs:
        """PSFs from a user's ``.npz``: ``psf_x1``, ``psf_x2`` (pixel grid, odd, centred) and optionally
        ``pedestal_x1``/``_x2`` (scalars) and ``illumination_x1``/``_x2`` (H, W); an InputError naming ``name``
        otherwise."""
        from pathlib import Path

        p = Path(path)
        if not p.is_file() or p.suffix.lower() != ".npz":
            raise InputError(name, str(p), "an existing .npz file with arrays psf_x1 and psf_x2")
        try:
            with np.load(p, allow_pickle=False) as z:
                if "psf_x1" not in z.files or "psf_x2" not in z.files:
                    raise InputError(name, str(p), "an .npz file with arrays psf_x1 and psf_x2")
                ks = (z["psf_x1"], z["psf_x2"])
                ped = tuple(float(z[f"pedestal_x{i}"]) if f"pedestal_x{i}" in z.files else 0.0 for i in (1, 2))
                ill = tuple(z[f"illumination_x{i}"] if f"illumination_x{i}" in z.files else None for i in (1, 2))
        except (OSError, ValueError) as e:
            raise InputError(name, str(p), f"a readable .npz file ({e})") from None
        return cls(ks, ped, ill, source=str(p))  # type: ignore[arg-type]


@dataclass
class Deconvolution:
    """Scene estimates of both channels: ``scene`` ``(s_1, s_2)`` in the frames' DN (a perfect lens' image, the
    offset added back), ``temperature_k`` their brightness temperatures (or None without a radiometric
    calibration), ``info`` what was chosen (sigma, priors, weights, iterations) and timings."""

    scene: tuple[np.ndarray, np.ndarray]
    temperature_k: tuple[np.ndarray, np.ndarray] | None
    info: dict[str, Any] = field(default_factory=dict)


# -- the per-frequency model -----------------------------------------------------------------------------------
def _normal_equations(frames: np.ndarray, alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, int]:
    """``(u_hat (2, H, W), N (2, 2), sigma, dof)``: the per-pixel least-squares separation, its normal matrix and
    the residual noise estimate."""
    a = np.asarray(alpha, dtype=np.float64)
    A = np.stack([a, 1.0 - a], axis=1)  # (T, 2)
    N = A.T @ A
    if np.linalg.cond(N) > 1e8:
        raise InputError("alpha", "nearly constant mixing ratios", "a sequence whose alpha varies (the 2 x 2 normal "
                         "matrix is singular)")
    T, H, W = frames.shape
    y = frames.reshape(T, -1).astype(np.float64)
    u = np.linalg.solve(N, A.T @ y)
    dof = T - 2
    sigma = float(np.sqrt(np.mean((y - A @ u) ** 2) * T / dof)) if dof > 0 else float("nan")
    return u.reshape(2, H, W), N, sigma, dof


class _Grid:
    """The padded periodic grid of the solve: mirror padding by the larger kernel's radius, FFT-friendly size."""

    def __init__(self, shape: tuple[int, int], kernels: tuple[np.ndarray, np.ndarray], pedestals: tuple[float, float]):
        from scipy.fft import next_fast_len

        H, W = shape
        r = max(k.shape[0] // 2 for k in kernels)
        self.pad = min(r, 3 * max(H, W))
        self.shape = (next_fast_len(H + 2 * self.pad, real=True), next_fast_len(W + 2 * self.pad, real=True))
        self.crop = (slice(self.pad, self.pad + H), slice(self.pad, self.pad + W))
        P, Q = self.shape
        self.D = np.stack([self._otf(k, p) for k, p in zip(kernels, pedestals)])  # (2, P, Q//2+1)
        fy = np.fft.fftfreq(P)[:, None]
        fx = np.fft.rfftfreq(Q)[None, :]
        self.f = np.hypot(fy, fx)
        # the forward-difference operator's transfer functions (periodic): TV's gradient
        self.gy = np.exp(2j * np.pi * fy) - 1.0
        self.gx = np.exp(2j * np.pi * fx) - 1.0
        self.lap = np.abs(self.gy) ** 2 + np.abs(self.gx) ** 2

    def _otf(self, k: np.ndarray, pedestal: float) -> np.ndarray:
        from scipy.fft import rfft2

        P, Q = self.shape
        n = k.shape[0]
        if n > min(P, Q):  # a kernel wider than the grid: fold it (periodic), its power kept
            c = n // 2
            kk = np.zeros((P, Q))
            iy, ix = (np.arange(n) - c) % P, (np.arange(n) - c) % Q
            np.add.at(kk, (iy[:, None], ix[None, :]), k)
        else:
            kk = np.zeros((P, Q))
            kk[:n, :n] = k
            kk = np.roll(kk, (-(n // 2), -(n // 2)), axis=(0, 1))
        D = rfft2(kk)
        D[0, 0] += pedestal
        return D

    def padded(self, img: np.ndarray, mode: str = "edge") -> np.ndarray:
        H, W = img.shape
        P, Q = self.shape
        p = self.pad
        if mode == "reflect" and max(p, P - H - p, Q - W - p) >= min(H, W):
            mode = "symmetric"
        return np.pad(img, ((p, P - H - p), (p, Q - W - p)), mode=mode)

    def rfft(self, imgs: np.ndarray) -> np.ndarray:
        from scipy.fft import rfft2

        return rfft2(imgs, axes=(-2, -1), workers=-1)

    def irfft(self, spec: np.ndarray) -> np.ndarray:
        from scipy.fft import irfft2

        return irfft2(spec, s=self.shape, axes=(-2, -1), workers=-1)


def _solve2(M: tuple[np.ndarray, np.ndarray, np.ndarray], b: np.ndarray) -> np.ndarray:
    """Per-frequency solve of the Hermitian 2 x 2 systems ``[[m11, m12], [conj(m12), m22]] x = b``."""
    m11, m12, m22 = M
    det = m11 * m22 - np.abs(m12) ** 2
    det = np.where(np.abs(det) > 0, det, np.inf)
    return np.stack([(m22 * b[0] - m12 * b[1]) / det, (m11 * b[1] - np.conj(m12) * b[0]) / det])


def _radial_mean(g: _Grid, v: np.ndarray, nbins: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Radially averaged ``v`` (P, Q//2+1) in ``nbins`` bins of |f| up to 0.5 sqrt 2: (bin centres, means)."""
    edges = np.linspace(0.0, 0.5 * math.sqrt(2), nbins + 1)
    idx = np.clip(np.digitize(g.f.ravel(), edges) - 1, 0, nbins - 1)
    cnt = np.bincount(idx, minlength=nbins)
    s = np.bincount(idx, weights=v.ravel(), minlength=nbins)
    return 0.5 * (edges[1:] + edges[:-1]), np.where(cnt > 0, s / np.maximum(cnt, 1), np.nan)


def _radial_field(g: _Grid, values: np.ndarray) -> np.ndarray:
    """Bin values (nbins,) spread back onto the frequency grid."""
    nb = values.size
    edges = np.linspace(0.0, 0.5 * math.sqrt(2), nb + 1)
    return np.nan_to_num(values, nan=0.0)[np.clip(np.digitize(g.f, edges) - 1, 0, nb - 1)]


def _crop_periodogram(z: np.ndarray, nbins: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Radially binned periodogram of the crop ``z`` (mean removed, Hann-tapered: no padding, whose repeated
    edge noise would look like signal): ``(bin centres in cycles/pixel, power per pixel of taper, counts)``."""
    from scipy.fft import rfft2

    H, W = z.shape
    w = np.outer(np.hanning(H + 2)[1:-1], np.hanning(W + 2)[1:-1])
    P = np.abs(rfft2((z - np.mean(z)) * w)) ** 2
    f = np.hypot(np.fft.fftfreq(H)[:, None], np.fft.rfftfreq(W)[None, :])
    edges = np.linspace(0.0, 0.5 * math.sqrt(2), nbins + 1)
    idx = np.clip(np.digitize(f.ravel(), edges) - 1, 0, nbins - 1)
    cnt = np.bincount(idx, minlength=nbins)
    sw2 = float(np.sum(w ** 2))
    mean = np.bincount(idx, weights=P.ravel(), minlength=nbins) / np.maximum(cnt, 1)
    return 0.5 * (edges[1:] + edges[:-1]), np.where(cnt > 0, mean / sw2, np.nan), cnt


def _fitted_spectrum(g: _Grid, z: np.ndarray, noise_var: float, D: np.ndarray,
                     prior: str = "power-law", scale: float = 1.0) -> tuple[np.ndarray, dict[str, Any]]:
    """The scene's power spectrum (per unnormalised-FFT bin of the grid) estimated from the crop ``z``: per
    radial bin, the tapered periodogram's power less the noise's, over the PSF's ``|D|^2`` (``'empirical'``: 0
    where no signal is detected), or a power law ``c / |f|^beta`` fitted where the signal exceeds twice the noise
    (``'power-law'``, ``beta`` in :data:`BETA_RANGE`); the per-pixel spectrum is spread over the grid as
    ``scale x n_grid x PSD`` (see ``prior_scale``). ``'hybrid'``: below the fitted tail, where the crop's signal
    exceeds 4x the noise, the padded grid's own radially averaged periodogram less the noise, over ``|D|^2``: the
    spectrum of the scene the solve is posed on (the crop and its edge-extended padding, whose stripes hold most of
    the low frequencies' power; the crop's periodogram scaled by its share was 200-500x too low there on the siemens
    star's foveal channel, and the estimate's error at 0.03-0.06 cycles/px 6x the bound's, along the crop's edges)."""
    nb = 64
    fc, pz, cnt = _crop_periodogram(z, nb)
    _, pd = _radial_mean(g, np.abs(D) ** 2, nbins=nb)
    sig = pz - noise_var  # power spectral density per pixel
    n_grid = g.shape[0] * g.shape[1]
    if prior == "empirical":
        est = np.where(np.isfinite(sig) & (sig > 0) & (pd > 0), sig / np.maximum(pd, 1e-300), 0.0)
        return _radial_field(g, est) * n_grid * scale, {"prior": "empirical", "bins": nb,
                                                        "bins_with_signal": int(np.sum(est > 0))}
    ok = np.isfinite(sig) & (sig > noise_var) & (fc > 0) & (pd > 0)
    ok[0] = False
    idx = np.flatnonzero(ok)
    if prior == "hybrid" and idx.size >= 6:
        # the tail beyond the spectrum's peak sets the extrapolation: fit the detected bins above the peak
        ratio = np.where(ok, sig / np.maximum(pd, 1e-300), 0.0)
        peak = int(idx[np.argmax(ratio[idx])])
        tail = ok & (np.arange(ok.size) >= peak)
        if tail.sum() >= 3:
            ok = tail
    beta = 2.0
    if ok.sum() >= 3:
        beta = float(np.clip(-np.polyfit(np.log(fc[ok]), np.log(sig[ok] / pd[ok]), 1)[0], *BETA_RANGE))
        logc = float(np.mean(np.log(sig[ok] / pd[ok]) + beta * np.log(fc[ok])))
    else:
        logc = math.log(max(noise_var, 1e-30))
    f = np.maximum(g.f, 1.0 / max(g.shape))
    law = n_grid * scale * np.exp(logc) / f ** beta
    info = {"prior": prior, "beta": beta, "bins_used": int(ok.sum())}
    if prior == "hybrid":
        # below the fitted tail, where the signal is strong (4x the noise): the padded grid's measured spectrum
        strong = np.isfinite(sig) & (sig > 4 * noise_var) & (pd > 0) & (fc < fc[ok].min() if ok.any() else False)
        _, pp = _radial_mean(g, np.abs(g.rfft(g.padded(z - np.mean(z)))) ** 2, nbins=nb)
        meas = np.where(strong, np.maximum(pp - n_grid * noise_var, 0.0) / np.maximum(pd, 1e-300), 0.0)
        field = _radial_field(g, meas)
        law = np.where(field > 0, field, law)
        info["measured_bins"] = int(strong.sum())
        half_bin = 0.5 * float(fc[1] - fc[0])
        info["measured_below_cycles_per_px"] = float(fc[strong].max()) + half_bin if strong.any() else 0.0
        info["measured_from"] = "the padded grid's periodogram"
    return law, info


class _Problem:
    """The joint problem on the grid: data ``z`` (2, H, W) with per-pixel noise covariance ``C`` (2, 2). With
    ``boundary='mirror'`` the data are mirrored onto the padding and the problem is periodic (diagonal per
    frequency); with ``'unknown'`` only the crop is data and the scene beyond it is solved for (seen through the
    PSFs' tails; far less determined)."""

    def __init__(self, g: _Grid, z: np.ndarray, C: np.ndarray, boundary: str = "mirror", pad_mode: str = "edge"):
        self.g, self.Cinv, self.boundary, self.pad_mode = g, np.linalg.inv(C), boundary, pad_mode
        self.crop, self.zc = g.crop, z
        if boundary == "mirror":
            self.z = np.stack([g.padded(zi, pad_mode) for zi in z])
            self.region = (slice(None), slice(None))
        else:
            self.z = z
            self.region = g.crop

    def blur(self, s: np.ndarray) -> np.ndarray:
        return self.g.irfft(self.g.D * self.g.rfft(s))

    def blur_t(self, v: np.ndarray) -> np.ndarray:
        return self.g.irfft(np.conj(self.g.D) * self.g.rfft(v))

    def weighted(self, r: np.ndarray) -> np.ndarray:
        """``M^T C^-1 M r`` for a residual on the grid (zero outside the data region)."""
        out = np.zeros_like(r)
        cy, cx = self.region
        out[:, cy, cx] = np.einsum("ij,jhw->ihw", self.Cinv, r[:, cy, cx])
        return out

    def data_rhs(self) -> np.ndarray:
        v = np.zeros((2,) + self.g.shape)
        cy, cx = self.region
        v[:, cy, cx] = self.z
        return self.blur_t(self.weighted(v))


def _linear_solve(pb: _Problem, prior_inv: np.ndarray, x0: np.ndarray | None, iterations: int = 200,
                  tol: float = 1e-6) -> tuple[np.ndarray, int]:
    """Conjugate gradients for ``(A^T M^T C^-1 M A + P^-1) s = A^T M^T C^-1 z`` (``prior_inv`` (2, P, Q//2+1): the
    prior's inverse spectrum per unnormalised bin, 0 at DC), preconditioned by the same system without the mask
    (per frequency, 2 x 2)."""
    g = pb.g
    n_bins = g.shape[0] * g.shape[1]
    D1, D2 = g.D
    Ci = pb.Cinv
    cy, cx = pb.region
    frac = float(np.ones(g.shape)[cy, cx].size) / n_bins  # the data region's share: the preconditioner's weight
    Mpre = (Ci[0, 0] * frac * np.abs(D1) ** 2 + prior_inv[0] * n_bins, Ci[0, 1] * frac * np.conj(D1) * D2,
            Ci[1, 1] * frac * np.abs(D2) ** 2 + prior_inv[1] * n_bins)
    eps = 1e-12 * float(np.max(np.abs(Mpre[0])) + np.max(np.abs(Mpre[2])))
    Mpre = (Mpre[0] + eps, Mpre[1], Mpre[2] + eps)

    def op(s: np.ndarray) -> np.ndarray:
        S = g.rfft(s)
        return pb.blur_t(pb.weighted(g.irfft(g.D * S))) + g.irfft(prior_inv * n_bins * S)

    def pre(r: np.ndarray) -> np.ndarray:
        return g.irfft(_solve2(Mpre, g.rfft(r)))

    b = pb.data_rhs()
    x = np.zeros_like(b) if x0 is None else x0.copy()
    r = b - op(x)
    zz = pre(r)
    p = zz.copy()
    rz = float(np.vdot(r, zz))
    bn = float(np.linalg.norm(b)) or 1.0
    for it in range(1, iterations + 1):
        Ap = op(p)
        step = rz / float(np.vdot(p, Ap))
        x += step * p
        r -= step * Ap
        if float(np.linalg.norm(r)) < tol * bn:
            return x, it
        zz = pre(r)
        rz_new = float(np.vdot(r, zz))
        p = zz + (rz_new / rz) * p
        rz = rz_new
    return x, iterations


def _shrink(gy: np.ndarray, gx: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mag = np.sqrt(gy ** 2 + gx ** 2)
    f = np.maximum(1.0 - t / np.maximum(mag, 1e-30), 0.0)
    return gy * f, gx * f


def _tv_admm(pb: _Problem, s0: np.ndarray, lam: np.ndarray, iterations: int) -> tuple[np.ndarray, int]:
    """ADMM for ``min 1/2 ||M A s - z||^2_{C^-1} + sum_i lam_i TV_iso(s_i)`` with unknown boundaries (the splits
    ``v = A s``, ``w = grad s``: every step is per frequency or per pixel), from ``s0``."""
    g = pb.g
    cy, cx = pb.region
    rho1 = float(np.max(np.abs(pb.Cinv)))
    rho2 = rho1 * 0.1
    den = rho1 * np.abs(g.D) ** 2 + rho2 * g.lap[None]
    den[:, 0, 0] = np.maximum(den[:, 0, 0], 1e-12 * rho1)
    # the data step inside the crop: (C^-1 + rho1 I) v = C^-1 z + rho1 q
    Kd = np.linalg.inv(pb.Cinv + rho1 * np.eye(2))
    Ciz = np.einsum("ij,jhw->ihw", pb.Cinv, pb.z)
    s = s0.copy()
    S = g.rfft(s)
    v = g.irfft(g.D * S)
    wy, wx = g.irfft(g.gy * S), g.irfft(g.gx * S)
    d1 = np.zeros_like(v)
    dy, dx = np.zeros_like(wy), np.zeros_like(wx)
    t = (lam / rho2)[:, None, None]
    for _ in range(iterations):
        S = (rho1 * np.conj(g.D) * g.rfft(v - d1)
             + rho2 * (np.conj(g.gy) * g.rfft(wy - dy) + np.conj(g.gx) * g.rfft(wx - dx))) / den
        As = g.irfft(g.D * S)
        gy_s, gx_s = g.irfft(g.gy * S), g.irfft(g.gx * S)
        q = As + d1
        v = q.copy()
        v[:, cy, cx] = np.einsum("ij,jhw->ihw", Kd, Ciz + rho1 * q[:, cy, cx])
        wy, wx = _shrink(gy_s + dy, gx_s + dx, t)
        d1 += As - v
        dy += gy_s - wy
        dx += gx_s - wx
    return g.irfft(S), iterations


# -- public ----------------------------------------------------------------------------------------------------
def _prepared(frames: Any, alpha: Any, psfs: ChannelPSFs, offset: float, sigma: float | None,
              boundary: str = "mirror", pad_mode: str = "edge",
              fpn_error_dn: float = 0.0) -> tuple[_Problem, np.ndarray, dict[str, Any]]:
    """The masked problem (separated, offset-removed, illumination-divided channels on the crop; their per-pixel
    noise covariance ``C`` (2, 2)) and what was found (``info``). ``fpn_error_dn``: the rms error of the fixed
    pattern subtracted from the frames; it is the same in every frame, so it does not average out and enters both
    separated channels in full (``u + [1, 1] e``: ``C += e^2 [[1, 1], [1, 1]]``)."""
    fr = np.asarray(frames, dtype=np.float64)
    if fr.ndim != 3 or fr.shape[0] < 3:
        raise InputError("frames", f"array of shape {fr.shape}", "(T, H, W) frames with T >= 3")
    T, H, W = fr.shape
    a = np.asarray(alpha, dtype=np.float64).reshape(-1)
    if a.shape != (T,) or not np.all(np.isfinite(a)):
        raise InputError("alpha", f"array of shape {a.shape}", f"({T},) finite mixing ratios")
    u, N, sig_fit, dof = _normal_equations(fr, a)
    sig = sig_fit if sigma is None else float(sigma)
    if not (math.isfinite(sig) and sig > 0):
        raise InputError("sigma", sig, "a frame noise level > 0 (DN)")
    z = np.empty_like(u)
    r_rms = []
    for i in range(2):
        r = psfs.illumination[i]
        r = np.ones((H, W)) if r is None else np.asarray(r, dtype=np.float64)
        if r.shape != (H, W) or not np.all(r > 0):
            raise InputError(f"illumination_x{i + 1}", f"array of shape {r.shape}", f"(H, W) = {(H, W)} values > 0")
        z[i] = (u[i] - offset) / r
        r_rms.append(float(np.sqrt(np.mean(r ** -2.0))))
    g = _Grid((H, W), psfs.kernels, psfs.pedestals)
    fe = float(fpn_error_dn or 0.0)
    if not (math.isfinite(fe) and fe >= 0):
        raise InputError("fpn_error_dn", fpn_error_dn, "the rms error (DN) of the subtracted fixed pattern, >= 0")
    # the separated channels' noise covariance: temporal noise through the 2 x 2 fit, plus the FPN estimate's error
    C = (sig ** 2 * np.linalg.inv(N) + fe ** 2 * np.ones((2, 2))) * np.outer(r_rms, r_rms)
    info = {"sigma_dn": sig, "sigma_source": "residuals of the per-pixel fit" if sigma is None else "given",
            "fpn_error_dn": fe,
            "noise_std_dn": [float(math.sqrt(C[0, 0])), float(math.sqrt(C[1, 1]))],
            "noise_correlation": float(C[0, 1] / math.sqrt(C[0, 0] * C[1, 1])),
            "grid": list(g.shape), "pad_px": g.pad, "psf_source": psfs.source,
            "boundary": boundary}
    return _Problem(g, z, C, boundary, pad_mode), C, info


def _inverse_prior(spectra: list[np.ndarray]) -> np.ndarray:
    # a bin without signal gets the largest penalty, not none
    inv = np.stack([1.0 / np.maximum(p, 1e-9 * max(float(np.max(p)), 1e-300)) for p in spectra])
    inv[:, 0, 0] = 0.0  # the mean is not shrunk
    return inv


def _calibration(meta: dict[str, Any] | None):
    """``(dn_per_k (2,), dL/dT(300 K), BandRadiance)`` from a measurement's metadata, or None."""
    if not meta or "dn_per_k_300K" not in meta or "radiometry" not in meta:
        return None
    from metafovea.radiometry import BandRadiance

    rad = meta["radiometry"]
    filt = rad.get("filter")
    band = BandRadiance.from_band(tuple(rad["band_um"]), filter_um=tuple(filt) if filt else None)
    d = meta["dn_per_k_300K"]
    return (float(d["x1"]), float(d["x2"])), float(rad.get("dL_dT_300K") or band.derivative(300.0)), band


def temperatures(scene_dn: tuple[np.ndarray, np.ndarray], offset: float,
                 meta: dict[str, Any] | None) -> tuple[np.ndarray, np.ndarray] | None:
    """Brightness temperatures (K) of both channels' scene images (DN) through the radiometric calibration in
    ``meta`` (``dn_per_k_300K``, ``radiometry``); None when ``meta`` has none."""
    cal = _calibration(meta)
    if cal is None:
        return None
    dn_per_k, dl_dt, band = cal
    return tuple(band.temperature((np.asarray(s, dtype=np.float64) - offset) * dl_dt / k)
                 for s, k in zip(scene_dn, dn_per_k))  # type: ignore[return-value]


def _foveal_surround(pb: _Problem, s: np.ndarray, scale: float, ratio: float, join: bool = True) -> float:
    """Replace the foveal channel's padding by what the perifoveal estimate predicts there: the foveal field at
    focal-plane position ``p`` is the perifoveal one at ``p / scale`` (both channels share the focal-plane pitch),
    ``s_1 = ratio s_2`` (the channels' radiometric gains), blurred by the foveal PSF. The foveal haze gathers light
    from several crop widths around the fovea: the perifoveal channel sees that surround directly.

    Light the prediction cannot hold (the PSF's disks wider than the grid, its pedestal, gather the scene far
    beyond it) adds a smooth field over the crop: the prediction is corrected by the quadratic surface fitted to the
    data less the prediction on the crop, so that the padding continues the data's level and slope (tall-buildings
    at 8-14 um: the residual rose by 0.8 DN across the crop even predicted from the true scene, a third of the
    data's contrast; with the surface the foveal estimate gains 1.4 dB).

    ``join=False``: the padding is that corrected prediction. ``join=True``: the prediction enters only below the
    perifoveal channel's Nyquist frequency, ``0.5 / scale`` cycles per foveal pixel, as its difference from the
    edge-extended data, zero on the crop and low-passed (a Gaussian of ``SURROUND_SIGMA_PER_SCALE x scale`` px, half
    power at that frequency): far out the padding is the prediction's low-pass, at the crop's edge it joins the
    data's edge values, which carry detail finer than the perifoveal channel resolves (the siemens star's spokes
    crossing the crop's edge: +0.2 dB at 10 um), but wrong detail where the scene has none finer than that.
    :func:`separate_deconvolve` solves with both and keeps the one whose solution explains the foveal data better.
    Returns the surface's rms on the crop (DN)."""
    from scipy.ndimage import gaussian_filter, map_coordinates

    g = pb.g
    P, Q = g.shape
    H, W = pb.zc.shape[1:]
    p = g.pad
    # grid index j -> foveal pixel j - p -> offset from the crop centre -> perifoveal pixel
    yy = ((np.arange(P) - p) - (H - 1) / 2) / scale + (H - 1) / 2
    xx = ((np.arange(Q) - p) - (W - 1) / 2) / scale + (W - 1) / 2
    s2 = s[1][g.crop]
    ext = ratio * map_coordinates(s2, np.meshgrid(yy, xx, indexing="ij"), order=1, mode="nearest")
    pred = g.irfft(g.D[0] * g.rfft(ext))
    # the smooth field the prediction lacks: a quadratic surface in the crop's normalised coordinates
    v, u = np.meshgrid((np.arange(P) - p - (H - 1) / 2) / H, (np.arange(Q) - p - (W - 1) / 2) / W, indexing="ij")
    basis = [np.ones_like(v), v, u, v * v, u * u, u * v]
    A = np.stack([b[g.crop].ravel() for b in basis], axis=1)
    coef = np.linalg.lstsq(A, (pb.zc[0] - pred[g.crop]).ravel(), rcond=None)[0]
    field = sum(c * b for c, b in zip(coef, basis))
    if join:
        edge = g.padded(pb.zc[0], pb.pad_mode)
        diff = pred + field - edge
        diff[g.crop] = 0.0
        z1 = edge + gaussian_filter(diff, SURROUND_SIGMA_PER_SCALE * scale, mode="wrap")
    else:
        z1 = pred + field
    z1[g.crop] = pb.zc[0]
    pb.z[0] = z1
    return float(np.sqrt(np.mean(field[g.crop] ** 2)))


def separate_deconvolve(frames: Any, alpha: Any, psfs: ChannelPSFs, *, method: str = "wiener", offset: float = 0.0,
                        sigma: float | None = None, iterations: int = 100, tv_weight: float | None = None,
                        meta: dict[str, Any] | None = None, boundary: str = "mirror",
                        pad_mode: str = "edge", prior: str = "hybrid", foveal_scale: float | None = None,
                        foveal_ratio: float = 1.0, fpn_error_dn: float = 0.0,
                        prior_scale: str = "geometric") -> Deconvolution:
    """The scene radiance of both channels from ``frames (T, H, W)`` (DN, fixed pattern removed) with mixing ratios
    ``alpha (T,)`` (known, or a solver's estimate) and the channels' PSFs (see the module docstring).

    ``offset``: the frames' dark level (DN); ``sigma``: the frames' temporal noise (DN; default from the fit's
    residuals); ``iterations``: ADMM iterations of ``'tv'``; ``tv_weight``: a multiplier of the automatic TV
    weights; ``meta``: a Measurement's metadata for the temperatures (``dn_per_k_300K``, ``radiometry``);
    ``fpn_error_dn``: the rms error (DN) of the fixed pattern already subtracted from ``frames`` (for calibration
    frames, :func:`metafovea.reconstruct.fpn.estimate_fpn`'s ``info['error_rms_dn']``): a static error that the
    frames do not average, counted in the noise model (measured: +1.4 to +1.8 dB on the siemens star's foveal channel
    with the FPN from 16 shutter frames).

    ``info`` holds what was chosen: the noise (``sigma_dn``, ``noise_std_dn``), the grid (``grid``, ``pad_px``),
    each channel's prior fit (``prior_fit``) and the prior itself radially averaged (``prior_radial``: per
    unnormalised bin of the padded grid, 64 bins of ``cycles_per_px``), the foveal surround's form
    (``foveal_surround``, ``foveal_surround_join``, ``foveal_surround_surface_rms_dn``), iterations and seconds.
    """
    method = check_choice("method", method, DECONVOLUTION_METHODS)
    prior = check_choice("prior", prior, PRIORS)
    prior_scale = check_choice("prior_scale", prior_scale, PRIOR_SCALES)
    iterations = check_int("iterations", iterations, 1, 100_000)
    t0 = time.perf_counter()
    pb, C, info = _prepared(frames, alpha, psfs, offset, sigma, boundary, pad_mode, fpn_error_dn)
    g = pb.g
    frac = pb.zc.shape[1] * pb.zc.shape[2] / float(g.shape[0] * g.shape[1])  # the crop's share of the grid
    scale = {"grid": 1.0, "crop": frac, "geometric": math.sqrt(frac)}[prior_scale]
    fits = [_fitted_spectrum(g, pb.zc[i], C[i, i], g.D[i], prior, scale) for i in range(2)]
    prior_inv = _inverse_prior([f[0] for f in fits])
    radial = [_radial_mean(g, f[0]) for f in fits]  # (bin centres, mean) per channel
    info.update(prior_scale=prior_scale, prior_scale_factor=scale,
                prior_radial={"cycles_per_px": radial[0][0].tolist(),
                              "x1": radial[0][1].tolist(), "x2": radial[1][1].tolist()})
    s, n_cg = _linear_solve(pb, prior_inv, None)
    if foveal_scale is not None and boundary == "mirror":
        # both forms of the surround; the one whose solution explains the foveal data on the crop better is kept
        cands = []
        for join in (True, False):
            smooth = _foveal_surround(pb, s, float(foveal_scale), float(foveal_ratio), join=join)
            s_j, n_j = _linear_solve(pb, prior_inv, s)
            n_cg += n_j
            r = pb.zc[0] - g.irfft(g.D[0] * g.rfft(s_j[0]))[g.crop]
            cands.append((float(np.mean(r ** 2)), join, s_j, pb.z[0].copy(), smooth))
        res2, join, s, pb.z[0], smooth = min(cands, key=lambda c: c[0])
        form = (f"joined to the data's edge values below the perifoveal Nyquist ({0.5 / float(foveal_scale):.3g} "
                f"cycles/px)" if join else "the prediction itself")
        info["foveal_surround"] = (
            f"the foveal channel's surround (its padding) predicted from the perifoveal estimate at "
            f"1/{float(foveal_scale):g} scale, gain ratio {float(foveal_ratio):.4g}, with a quadratic surface of "
            f"{smooth:.3g} DN rms on the crop; {form}: its foveal residual {res2:.4g} DN^2 against "
            f"{max(c[0] for c in cands):.4g} for the other form")
        info["foveal_surround_join"] = bool(join)
        info["foveal_surround_surface_rms_dn"] = smooth
    info.update(method=method, prior=prior, prior_fit=[f[1] for f in fits],
                cg_iterations=n_cg)
    if method == "tv":
        cy, cx = g.crop
        grad = [float(np.mean(np.hypot(np.diff(s[i][cy, cx], axis=0)[:, :-1], np.diff(s[i][cy, cx], axis=1)[:-1])))
                for i in range(2)]
        mult = 1.0 if tv_weight is None else float(tv_weight)
        if not (math.isfinite(mult) and mult > 0):
            raise InputError("tv_weight", tv_weight, "a multiplier > 0 of the automatic weight")
        lam = np.array([mult / max(gr, 1e-12) for gr in grad])
        s, its = _tv_admm(pb, s, lam, iterations)
        info.update(tv_weight=[float(v) for v in lam], tv_weight_rule="1 / mean |grad s| of the Wiener estimate "
                    "(Laplace prior on the gradients)" + ("" if tv_weight is None else f" x {mult:g}"),
                    admm_iterations=its)
    scene = (s[0][g.crop] + offset, s[1][g.crop] + offset)
    info["seconds"] = time.perf_counter() - t0
    return Deconvolution(scene, temperatures(scene, offset, meta), info)


def wiener_bound(frames: Any, alpha: Any, psfs: ChannelPSFs, truth: tuple[np.ndarray, np.ndarray], *,
                 offset: float = 0.0, sigma: float, boundary: str = "mirror",
                 pad_mode: str = "edge", fpn_error_dn: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The reference: the best stationary linear reconstruction, the joint Wiener estimate of
    :func:`separate_deconvolve` with the true scene's radially averaged power spectrum (``truth``: both channels'
    scene images in DN) in place of the fitted one, the true PSFs, the true frame noise ``sigma`` (DN) and the true
    rms error ``fpn_error_dn`` (DN) of the subtracted fixed pattern."""
    pb, _, _ = _prepared(frames, alpha, psfs, offset, sigma, boundary, pad_mode, fpn_error_dn)
    g = pb.g
    spectra = []
    for t in truth:
        st = g.rfft(g.padded(np.asarray(t, dtype=np.float64) - offset))
        spectra.append(_radial_field(g, _radial_mean(g, np.abs(st) ** 2, nbins=128)[1]))
    s, _ = _linear_solve(pb, _inverse_prior(spectra), None)
    return s[0][g.crop] + offset, s[1][g.crop] + offset


def true_noise_dn(meta: dict[str, Any]) -> float | None:
    """The simulator's frame noise (DN): temporal noise and, when quantised, the ADC's 1/12 DN^2; None if unknown."""
    sen = meta.get("sensor") or {}
    if "noise_sigma_dn" not in sen:
        return None
    return math.sqrt(float(sen["noise_sigma_dn"]) ** 2 + (1.0 / 12.0 if sen.get("quantize", True) else 0.0))


def _frames_for(m: Any, fpn: Any) -> np.ndarray:
    """The frames in float64 with ``fpn`` (H, W) subtracted and the invalid samples (ADC range, bad pixels) set to
    their pixel's mean of valid samples."""
    fr = np.asarray(m.frames, dtype=np.float64)
    bad = m.invalid_samples()
    if bad is not None:
        fr = np.where(bad, np.nan, fr)
        mean = np.nanmean(fr, axis=0)
        fr = np.where(np.isnan(fr), np.where(np.isnan(mean), np.nanmean(mean), mean)[None], fr)
    if fpn is not None:
        f = np.asarray(fpn, dtype=np.float64)
        if f.shape != fr.shape[1:]:
            raise InputError("fpn", f"array of shape {f.shape}", f"the frames' (H, W) = {fr.shape[1:]}", source=m.source)
        fr = fr - f
    return fr


def deconvolve_measurement(m: Any, *, alpha: Any = None, fpn: Any = None, method: str = "wiener",
                           psfs: ChannelPSFs | None = None, score_truth: bool = True, **kw: Any) -> Deconvolution:
    """:func:`separate_deconvolve` of a static Measurement: its frames (``fpn`` subtracted; samples outside the ADC
    range or on bad pixels replaced by their pixel's mean), ``alpha`` (default: the file's; an unknown-alpha
    solver's estimate otherwise), its PSFs (``psfs``, default :meth:`ChannelPSFs.from_measurement`), dark level and
    radiometric calibration. With ``score_truth`` and the file's scene truth (``scene_x1``/``_x2``), ``info['scores']``
    holds PSNR against the scene (data range: the truth's), the brightness-temperature error (K), the hazy images'
    own PSNR against the scene and the Wiener bound's (:func:`wiener_bound`, with the file's true noise).

    Parameters
    ----------
    m : Measurement
        A static sequence, frames ``(T, H, W)`` in DN.
    alpha : array_like, shape (T,), optional
        Mixing ratios (default: the file's).
    fpn : ndarray, shape (H, W), optional
        Fixed pattern to subtract (DN).
    method : {'wiener', 'tv'}
    psfs : ChannelPSFs, optional
        Each channel's PSF on the pixel grid and relative illumination (default: the file's).
    score_truth : bool
        Score against the file's scene truth when it has one.
    **kw
        Keywords of :func:`separate_deconvolve`.

    Returns
    -------
    Deconvolution
        ``scene`` ``(s_1, s_2)``, each ``(H, W)`` in DN; ``temperature_k`` their brightness temperatures (K) or
        None without a radiometric calibration; ``info`` (choices, timings, ``scores``).
    """
    a = m.alpha if alpha is None else alpha
    if a is None:
        raise InputError("alpha", None, "mixing ratios: the file's, or an unknown-alpha solver's estimate "
                         "(reconstruct --method alternating first)", source=m.source)
    psfs = psfs or ChannelPSFs.from_measurement(m)
    offset = float(m.meta.get("dark_dn", 0.0))
    frames = _frames_for(m, fpn)
    cg = m.meta.get("channel_gain") or {}
    if "foveal_scale" not in kw and m.meta.get("scale"):
        kw.update(foveal_scale=float(m.meta["scale"]),
                  foveal_ratio=float(cg.get("x1", 1.0)) / float(cg.get("x2", 1.0)))
    res = separate_deconvolve(frames, a, psfs, method=method, offset=offset, meta=m.meta, **kw)
    if score_truth and "scene_x1" in m.extras and "scene_x2" in m.extras:
        res.info["scores"] = _scores(m, res, frames, np.asarray(a, dtype=np.float64), psfs, offset,
                                     kw.get("boundary", "mirror"), kw.get("pad_mode", "edge"), fpn)
    return res


def true_fpn_error_dn(m: Any, fpn: Any) -> float:
    """The rms error (DN) of the pattern ``fpn`` (None: nothing subtracted) against the file's true one, means
    removed (the mean of a pattern is the dark level's, not identifiable); 0 without a true pattern."""
    if m.fpn is None:
        return 0.0
    t = np.asarray(m.fpn, dtype=np.float64)
    e = -(t - t.mean()) if fpn is None else (np.asarray(fpn, np.float64) - np.mean(fpn)) - (t - t.mean())
    return float(np.sqrt(np.mean(e ** 2)))


def _scores(m: Any, res: Deconvolution, frames: np.ndarray, alpha: np.ndarray, psfs: ChannelPSFs, offset: float,
            boundary: str, pad_mode: str, fpn: Any = None) -> dict[str, Any]:
    from metafovea.reconstruct.metrics import psnr

    truth = (np.asarray(m.extras["scene_x1"], np.float64), np.asarray(m.extras["scene_x2"], np.float64))
    out: dict[str, Any] = {"against": "the scene through a perfect lens (scene_x1, scene_x2)"}
    for i, t in enumerate(truth, start=1):
        out[f"psnr_x{i}"] = psnr(res.scene[i - 1], t)
        hz = getattr(m, f"truth_x{i}")
        if hz is not None and np.ndim(hz) == 2:
            out[f"psnr_x{i}_hazy_image"] = psnr(np.asarray(hz, np.float64), t)
    tt = temperatures(truth, offset, m.meta)
    if tt is not None and res.temperature_k is not None:
        for i in (1, 2):
            e = res.temperature_k[i - 1] - tt[i - 1]
            out[f"temperature_rmse_x{i}_k"] = float(np.sqrt(np.nanmean(e ** 2)))
    sig = true_noise_dn(m.meta)
    if sig is not None and sig > 0:
        t0 = time.perf_counter()
        # the oracle may count the subtracted pattern's true error as noise or not: the better of the two per channel
        # (the error is low-rank stripes, not the white noise the linear model assumes, so counting it can lose)
        fe = true_fpn_error_dn(m, fpn)
        best = [-math.inf, -math.inf]
        for e in ((0.0, fe) if fe > 0 else (0.0,)):
            wb = wiener_bound(frames, alpha, psfs, truth, offset=offset, sigma=sig, boundary=boundary,
                              pad_mode=pad_mode, fpn_error_dn=e)
            best = [max(best[i], psnr(wb[i], truth[i])) for i in range(2)]
        out.update(wiener_bound_psnr_x1=best[0], wiener_bound_psnr_x2=best[1],
                   wiener_bound_seconds=time.perf_counter() - t0, wiener_bound_fpn_error_dn=fe,
                   wiener_bound="linear MMSE with the true PSFs, the true frame noise (with and without the true "
                                "error of the subtracted fixed pattern: the better) and the truth's radially averaged "
                                "power spectrum")
    return out


def deconvolve_result(m: Any, res: Any, method: str = "wiener", psf: Any = None, **kw: Any) -> Deconvolution:
    """The PSF-aware step after a reconstruction ``res`` (:class:`~metafovea.reconstruct.PipelineResult`) of ``m``:
    :func:`deconvolve_measurement` with the reconstruction's alpha (the file's when it used them, else its estimate
    over the sequence) and fixed pattern, the PSFs of ``psf`` (a file, :meth:`ChannelPSFs.from_file`) or of the
    file; ``info['alpha_from']`` says which alpha."""
    rec = res.reconstruction
    alpha = rec.alpha_per_frame(m.shape[0])
    if not np.all(np.isfinite(alpha)):
        raise InputError("--deconvolve", rec.method, f"a reconstruction whose alpha covers all {m.shape[0]} frames "
                         "(use --window with all frames, or a stride that reaches every frame)", source=m.source)
    known = m.alpha is not None and bool(np.array_equal(alpha, np.asarray(m.alpha, dtype=np.float64)))
    psfs = ChannelPSFs.from_file(psf) if psf is not None else None
    err = ((rec.info or {}).get("fpn") or {}).get("error_rms_dn")
    if err is not None and "fpn_error_dn" not in kw:
        kw["fpn_error_dn"] = float(err)
    d = deconvolve_measurement(m, alpha=alpha, fpn=rec.fpn, method=method, psfs=psfs, **kw)
    d.info["alpha_from"] = "the file" if known else f"the {rec.method} estimate"
    return d

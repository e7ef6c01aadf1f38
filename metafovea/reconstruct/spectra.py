"""Radially averaged power spectra: the scene prior of the PSF-aware reconstruction.

Frequencies are those of a real FFT of an ``(P, Q)`` image, ``|f| = hypot(f_y, f_x)`` in cycles per pixel on the
``(P, Q // 2 + 1)`` half plane (:func:`rfft_frequencies`); a radial profile averages over ``nbins`` rings of equal
width from 0 to the grid's corner ``F_MAX = 0.5 sqrt 2`` (:func:`radial_mean`, and back onto the grid with
:func:`radial_field`). The scene's spectrum is estimated from a crop ``z`` with white noise of variance
``sigma^2`` per pixel, seen through a PSF of transfer function ``D``:

    P_z(f) = <|FFT(w (z - mean z))|^2>_ring / sum w^2                                  (1)
    S(f)   = (P_z(f) - sigma^2) / <|D|^2>_ring                                          (2)
    S(f)   ~ c |f|^-beta,  fitted in log-log where P_z - sigma^2 > DETECTION_SNR sigma^2  (3)

(1) is the Hann-tapered periodogram per pixel (:func:`crop_periodogram`), (2) the scene's spectral density per
pixel, (3) the power law that extrapolates it beyond the detected bins (:func:`fitted_spectrum`). Where fewer than
:data:`MIN_FIT_BINS` rings are detected, ``beta`` is :data:`DEFAULT_BETA` and ``c`` maximises the Whittle likelihood
of every ring's periodogram (:func:`whittle_level`, eq. 4 there): the non-detections bound the level. The solver works
per unnormalised FFT bin of a padded grid of ``n_grid`` pixels, so a per-pixel density ``S`` becomes
``scale n_grid S`` there (``scale``: the solver's ``prior_scale``). The Wiener solve needs the prior's inverse,
:func:`inverse_prior`.

Measured figures (which prior and scale, and why): BENCHMARKS.md, section "PSF-aware reconstruction against the
scene".
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from metafovea.errors import InputError

#: the rfft grid's largest ``|f|`` (its corner), cycles per pixel: the radial bins span ``[0, F_MAX]``
F_MAX = 0.5 * math.sqrt(2.0)
#: rings of the fitted spectrum and of ``info['prior_radial']``: 0.011 cycles/px wide, about three of a 290 px
#: crop's frequency steps (1/290), so that each ring averages several periodogram samples
RADIAL_BINS = 64
#: rings of the true spectrum in :func:`metafovea.reconstruct.evaluate.wiener_bound`, taken on the padded grid
#: (2-3x the crop's size, so twice the rings of the crop's profile still average several samples each)
TRUTH_RADIAL_BINS = 128
#: the scene prior's models (:func:`fitted_spectrum` ``prior``)
PRIORS = ("hybrid", "power-law", "empirical")
#: the power-law exponents the fit may take (``beta`` of eq. 3), around the ``|f|^-2`` of natural scenes' power
#: spectra (D. J. Field, J. Opt. Soc. Am. A 4, 2379 (1987)); the fitted slope is clipped to this range
BETA_RANGE = (1.0, 4.0)
#: ``beta`` where fewer than :data:`MIN_FIT_BINS` bins are detected: the natural-image spectrum ``1 / |f|^2``
DEFAULT_BETA = 2.0
#: a ring is detected where its signal ``P_z - sigma^2`` exceeds this multiple of the noise ``sigma^2``, i.e. the
#: periodogram is over twice the noise level
DETECTION_SNR = 1.0
#: ``'hybrid'``: below the fitted tail, rings whose signal exceeds this multiple of the noise take the padded
#: grid's measured spectrum instead of the law. Set with the hybrid prior, not tuned on its own (BENCHMARKS.md,
#: "PSF-aware reconstruction against the scene": the hybrid against its alternatives): the measured spectrum less
#: the noise is used only where the signal clearly dominates it
MEASURED_SNR = 4.0
#: fewest detected rings a power-law fit uses (two parameters, one degree of freedom left)
MIN_FIT_BINS = 3
#: ``'hybrid'`` fits only the tail beyond the spectrum's peak when at least this many rings are detected
MIN_HYBRID_BINS = 6
#: the Hann taper's inflation of the Whittle likelihood ratio (:func:`noise_floor`): neighbouring periodogram
#: samples of a Hann-tapered crop are correlated (the taper's spectral window spans three of them), so a ring holds
#: about half as many independent samples as it has bins (Percival and Walden, *Spectral Analysis for Physical
#: Applications*, 1993, sec. 6.7: the Hann taper's variance inflation 1.94); rounded up to 2
NOISE_FLOOR_INFLATION = 2.0
#: the scene's spectral slopes :func:`noise_floor` allows: from white (0: a scene of dense small sources is as flat
#: as noise, and is not taken for it) to the steepest of :data:`BETA_RANGE`
NOISE_FLOOR_BETA_RANGE = (0.0, BETA_RANGE[1])
#: the step of :func:`noise_floor`'s slopes (each costs two FFTs of the grid)
NOISE_FLOOR_BETA_STEP = 0.1
#: the corrected likelihood ratio above which the data's excess noise is used (:func:`noise_floor`): the 0.999
#: quantile of chi^2 with one degree of freedom, i.e. a false alarm rate of 5e-4 on the boundary (half of the
#: statistic's mass is at 0)
NOISE_FLOOR_CRITICAL = 10.83
#: a bin without signal gets the prior of this fraction of the spectrum's largest value (the largest penalty,
#: not none) in :func:`inverse_prior`
PRIOR_FLOOR = 1e-9


def rfft_frequencies(shape: tuple[int, int]) -> np.ndarray:
    """``|f|`` (cycles per pixel) of a real 2-D FFT of an image of ``shape``.

    Parameters
    ----------
    shape : tuple of int
        ``(P, Q)``: the image's size.

    Returns
    -------
    ndarray, shape (P, Q // 2 + 1)
        ``hypot(f_y, f_x)`` on the half plane ``scipy.fft.rfft2`` returns.
    """
    return np.hypot(np.fft.fftfreq(shape[0])[:, None], np.fft.rfftfreq(shape[1])[None, :])


def rfft_weights(shape: tuple[int, int]) -> np.ndarray:
    """Each rfft column's count in the full plane of an image of ``shape`` ``(P, Q)``: ``(Q // 2 + 1,)``, 2 for the
    inner columns, 1 for the zero frequency and (``Q`` even) the Nyquist column; a sum over the half plane weighted
    by it is the full plane's (Parseval)."""
    Q = shape[1]
    wt = np.full(Q // 2 + 1, 2.0)
    wt[0] = 1.0
    if Q % 2 == 0:
        wt[-1] = 1.0
    return wt


def _ring_index(f: np.ndarray, nbins: int) -> tuple[np.ndarray, np.ndarray]:
    """``(edges (nbins + 1,), ring of each frequency)``: equal rings over ``[0, F_MAX]``, the last one closed."""
    edges = np.linspace(0.0, F_MAX, nbins + 1)
    return edges, np.clip(np.digitize(f, edges) - 1, 0, nbins - 1)


def radial_mean(f: np.ndarray, values: np.ndarray, nbins: int = RADIAL_BINS) -> tuple[np.ndarray, np.ndarray,
                                                                                     np.ndarray]:
    """The mean of ``values`` over rings of ``|f|``.

    Parameters
    ----------
    f : ndarray
        ``|f|`` in cycles per pixel (:func:`rfft_frequencies`).
    values : ndarray, same shape as ``f``
        A quantity per frequency (a periodogram, ``|D|^2``, a spectrum).
    nbins : int
        Rings of equal width over ``[0, F_MAX]``.

    Returns
    -------
    centres : ndarray, shape (nbins,)
        The rings' centres, cycles per pixel.
    means : ndarray, shape (nbins,)
        The mean of ``values`` in each ring; NaN in a ring without a frequency.
    counts : ndarray of int, shape (nbins,)
        Frequencies per ring.
    """
    edges, idx = _ring_index(f.ravel(), nbins)
    cnt = np.bincount(idx, minlength=nbins)
    s = np.bincount(idx, weights=values.ravel(), minlength=nbins)
    return 0.5 * (edges[1:] + edges[:-1]), np.where(cnt > 0, s / np.maximum(cnt, 1), np.nan), cnt


def radial_field(f: np.ndarray, profile: np.ndarray) -> np.ndarray:
    """A radial profile spread back onto the frequencies ``f``: each frequency takes its ring's value.

    Parameters
    ----------
    f : ndarray
        ``|f|`` in cycles per pixel.
    profile : ndarray, shape (nbins,)
        One value per ring of :func:`radial_mean` (NaN counts as 0).

    Returns
    -------
    ndarray, same shape as ``f``
    """
    _, idx = _ring_index(f, profile.size)
    return np.nan_to_num(profile, nan=0.0)[idx]


def hann_taper(shape: tuple[int, int]) -> np.ndarray:
    """The separable Hann taper of eq. (1), without its zero end points, ``shape``."""
    return np.outer(np.hanning(shape[0] + 2)[1:-1], np.hanning(shape[1] + 2)[1:-1])


def crop_periodogram(z: np.ndarray, nbins: int = RADIAL_BINS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The radially averaged, Hann-tapered periodogram of ``z`` per pixel, eq. (1).

    Parameters
    ----------
    z : ndarray, shape (H, W)
        The crop; its mean is removed. It is not padded: repeated edge noise would look like signal.
    nbins : int
        Rings over ``[0, F_MAX]``.

    Returns
    -------
    centres : ndarray, shape (nbins,)
        Cycles per pixel.
    power : ndarray, shape (nbins,)
        Power per pixel of taper (``sum w^2``): white noise of variance ``sigma^2`` gives ``sigma^2``; NaN in an
        empty ring.
    counts : ndarray of int, shape (nbins,)
    """
    from scipy.fft import rfft2

    H, W = z.shape
    w = hann_taper((H, W))
    P = np.abs(rfft2((z - np.mean(z)) * w)) ** 2
    fc, mean, cnt = radial_mean(rfft_frequencies((H, W)), P, nbins)
    return fc, mean / float(np.sum(w ** 2)), cnt


def whittle_level(fc: np.ndarray, power: np.ndarray, otf2: np.ndarray, counts: np.ndarray, noise_var: float,
                  beta: float) -> float:
    """The log level ``log c`` of the spectrum ``c |f|^-beta`` that maximises the Whittle likelihood of ring-averaged
    periodograms, eq. (4).

    Parameters
    ----------
    fc : ndarray, shape (n,)
        The rings' frequencies (> 0), cycles per pixel.
    power : ndarray, shape (n,)
        Their periodograms per pixel (:func:`crop_periodogram`).
    otf2 : ndarray, shape (n,)
        ``<|D|^2>`` per ring (> 0).
    counts : ndarray, shape (n,)
        Periodogram samples per ring (the likelihood's weights).
    noise_var : float
        The white noise's variance per pixel (> 0).
    beta : float
        The exponent, held fixed.

    Returns
    -------
    float
        ``log c`` (``c``: the per-pixel density at 1 cycle per pixel).

    Notes
    -----
    A ring's mean periodogram ``I_r`` of ``m_r`` samples of a stationary Gaussian field has mean
    ``mu_r = <|D|^2>_r c f_r^-beta + sigma^2``; the Whittle approximation of the likelihood [P. Whittle, "Curve and
    periodogram smoothing", J. R. Stat. Soc. B 19, 38 (1957)] is

        -log L(c) = sum_r m_r (log mu_r + I_r / mu_r)                                                   (4)

    which counts the rings where no signal was detected too: their periodogram bounds ``c`` from above. The search
    is over ``c`` from 1e-8 to 1e8 times the level whose signal equals the noise in the strongest or the weakest
    ring (a numerical range, wide enough that no data reach its ends).
    """
    from scipy.optimize import minimize_scalar

    a = otf2 * fc ** -beta
    m = counts.astype(np.float64)

    def nll(logc: float) -> float:
        mu = a * math.exp(logc) + noise_var
        return float(np.sum(m * (np.log(mu) + power / mu)))

    lo = math.log(noise_var * 1e-8 / float(np.max(a)))
    hi = math.log(noise_var * 1e8 / float(np.min(a)))
    return float(minimize_scalar(nll, bounds=(lo, hi), method="bounded").x)


def noise_floor(z: np.ndarray, D: np.ndarray, grid_shape: tuple[int, int], noise_var: float,
                nbins: int = RADIAL_BINS) -> tuple[float, dict[str, Any]]:
    """The data's white noise level per pixel, fitted with the scene's spectrum, never below the modelled one: eq. (5).

    Parameters
    ----------
    z : ndarray, shape (H, W)
        One channel's separated data on the crop (DN).
    D : ndarray, shape (P, Q // 2 + 1)
        The channel's transfer function on the solve's grid ``grid_shape``.
    grid_shape : tuple of int
        ``(P, Q)``.
    noise_var : float
        The modelled noise variance per pixel (> 0), DN^2.
    nbins : int
        Rings.

    Returns
    -------
    variance : float
        ``noise_var`` plus the excess eq. (5) finds, where the likelihood ratio shows one (else ``noise_var``).
    info : dict
        ``modelled_dn2``, ``fitted_dn2`` (the fit's level, ``noise_var`` or more), ``ratio``, ``beta``,
        ``statistic`` (the likelihood ratio's ``2 delta log L`` over :data:`NOISE_FLOOR_INFLATION`), ``threshold``
        (:data:`NOISE_FLOOR_CRITICAL`), ``used`` and ``model`` (``'sampled'``: the screen found no excess;
        ``'leakage'``: the exact expectation decided).

    Notes
    -----
    The rings' periodograms (eq. 1) have mean ``mu_r = <|D|^2>_r c f_r^-beta + sigma^2 + e``: the scene through the
    PSF, the modelled noise and an excess ``e >= 0`` that is flat in frequency, which a scene seen through a PSF is not
    (``beta`` in :data:`NOISE_FLOOR_BETA_RANGE`, down to a scene as flat as white noise: only an excess that the
    PSF's shape cannot have made counts; through a PSF that passes every frequency alike, none can be told from a
    scene, and none needs to be: nothing is amplified): data whose noise model leaves something out (rounding
    without dither, the same in every frame, a fixed pattern subtracted with a larger error than stated, a PSF that
    differs from the data's). ``(c, beta, e)`` maximise the Whittle likelihood (eq. 4), and ``e = 0`` (the noise
    model as stated) is tested against it by the likelihood ratio, whose ``2 delta log L`` is ``chi^2`` with one
    degree of freedom on the boundary (half of it 0) for independent samples; the Hann taper makes neighbouring
    samples correlated and the ratio larger by :data:`NOISE_FLOOR_INFLATION`. The excess is used when the ratio so
    corrected exceeds :data:`NOISE_FLOOR_CRITICAL`.

        sigma_used^2 = sigma^2 + e   if  2 delta log L / NOISE_FLOOR_INFLATION > NOISE_FLOOR_CRITICAL      (5)

    The taper's spectral window smooths the periodogram: a PSF's near zeros and a steep spectrum's tail fill with
    their neighbours' power, which the spectrum sampled at the rings takes for a flat excess. The test is therefore
    made twice: with ``mu_r`` sampled (cheap, a screen), and, where that finds an excess, with the tapered
    periodogram's exact expectation on the solve's grid, ``FFT(R A_w) / sum w^2`` (``R``: the autocovariance of
    ``|D|^2 c f^-beta``; ``A_w``: the taper's), whose verdict stands. The leakage adds power mostly where the sampled
    spectrum is low (zeros, the tail), so the screen's statistic is the larger one; an excess only the exact test
    would find is not looked for (the exact fit costs two FFTs of the grid per slope).
    """
    betas = np.arange(NOISE_FLOOR_BETA_RANGE[0], NOISE_FLOOR_BETA_RANGE[1] + 1e-9, NOISE_FLOOR_BETA_STEP)
    info: dict[str, Any] = {"modelled_dn2": float(noise_var), "fitted_dn2": float(noise_var), "ratio": 1.0,
                            "beta": None, "statistic": 0.0, "threshold": NOISE_FLOOR_CRITICAL, "used": False,
                            "model": None}
    if not (math.isfinite(noise_var) and noise_var > 0.0 and np.all(np.isfinite(z))):
        return float(noise_var), info  # nothing to compare with (prepare_problem passes neither)
    for model in ("sampled", "leakage"):  # the screen, then (where it finds an excess) the exact expectation
        fit = _floor_fit(z, D, grid_shape, float(noise_var), betas, nbins, model == "leakage")
        if fit is None:
            return float(noise_var), info
        stat, beta, e = fit
        used = stat > NOISE_FLOOR_CRITICAL
        fitted = float(noise_var) + e
        info.update(fitted_dn2=float(fitted), ratio=float(fitted / noise_var), beta=beta, statistic=float(stat),
                    used=used, model=model)
        if not used:
            return float(noise_var), info
    return float(info["fitted_dn2"]), info


def _floor_fit(z: np.ndarray, D: np.ndarray, grid_shape: tuple[int, int], nv: float, betas: np.ndarray, nbins: int,
               leakage: bool) -> tuple[float, float, float] | None:
    """:func:`noise_floor`'s fit: ``(statistic, beta, e)``, or None with too few rings. ``leakage``: the exact
    expectation of the tapered periodogram (the scene's spectrum convolved with the taper's), else the spectrum
    sampled at the rings (eq. 5's screen)."""
    from scipy.fft import irfft2, rfft2
    from scipy.optimize import minimize

    H, W = z.shape
    P, Q = grid_shape
    f = rfft_frequencies(grid_shape)
    D2 = np.abs(D) ** 2
    if not leakage:
        fc, pz, cnt = crop_periodogram(z, nbins)
        _, pd, _ = radial_mean(f, D2, nbins)
        shapes = pd[None, :] * np.where(fc > 0, fc, np.inf)[None, :] ** -betas[:, None]
        m = cnt.astype(np.float64)
    else:
        # the crop's tapered periodogram on the grid's frequencies (zero-padded: the same one, sampled finer) and its
        # expectation for a scene spectrum S, FFT(R A_w) / sum w^2 (R: S's autocovariance, A_w: the taper's, on the
        # grid): a PSF's near zeros fill with their neighbours' power, which is no flat excess
        w = hann_taper((H, W))
        sw2 = float(np.sum(w ** 2))
        fc, pz, cnt = radial_mean(f, np.abs(rfft2((z - np.mean(z)) * w, s=(P, Q), workers=-1)) ** 2 / sw2, nbins)
        taper_acf = irfft2(np.abs(rfft2(w, s=(P, Q), workers=-1)) ** 2, s=(P, Q), workers=-1)
        f_dc = np.where(f > 0, f, np.inf)  # the mean removed: no power at 0
        shapes = np.array([radial_mean(f, np.real(rfft2(irfft2(D2 * f_dc ** -b, s=(P, Q), workers=-1) * taper_acf,
                                                         workers=-1)) / sw2, nbins)[1] for b in betas])
        m = cnt.astype(np.float64) * (H * W) / (P * Q)  # a ring's independent samples: its bins on the crop's grid
    ok = np.isfinite(pz) & (fc > 0) & (cnt > 0) & np.all(np.isfinite(shapes) & (shapes > 0), axis=0)
    if ok.sum() < MIN_FIT_BINS + 1:  # three parameters and one degree of freedom
        return None
    pz, shapes, m = pz[ok], shapes[:, ok], m[ok]
    scale = float(np.mean(pz))  # the likelihood in units of the data's power (well scaled for the optimiser)
    if not scale > 0.0:  # a constant crop: nothing to fit
        return None

    def nll(p: np.ndarray, a: np.ndarray) -> tuple[float, np.ndarray]:
        c, e = math.exp(p[0]), math.exp(p[1])
        mu = (a * c + nv + e) / scale
        r = m * (1.0 / mu - pz / scale / mu ** 2) / scale
        return float(np.sum(m * (np.log(mu) + pz / scale / mu))), np.array([np.sum(r * a * c), np.sum(r * e)])

    e0 = math.log(nv) - 60.0  # e = 0 (to 1e-26 of the noise)

    def nll0(q: np.ndarray, a: np.ndarray) -> tuple[float, np.ndarray]:  # the null: the level alone, e = 0
        v, grad = nll(np.array([q[0], e0]), a)
        return v, grad[:1]

    best0 = best1 = (math.inf, 0.0, 0.0)
    for beta, a in zip(betas, shapes):
        # the level's start: the signal's mean over the PSF's and the law's shape (>= 1e-12 of the data's power)
        c0 = math.log(max(float(np.sum(m * (pz - nv)) / np.sum(m * a)), 1e-12 * scale / float(np.max(a))))
        r0 = minimize(nll0, np.array([c0]), args=(a,), jac=True, method="L-BFGS-B",
                      bounds=[(c0 - 30.0, c0 + 30.0)])
        f0 = float(r0.fun)
        best0 = min(best0, (f0, float(beta), 0.0))
        c0 = float(r0.x[0])
        r = minimize(nll, np.array([c0, math.log(max(float(np.median(pz[-5:])) - nv, nv * 1e-6))]), args=(a,),
                     jac=True, method="L-BFGS-B", bounds=[(c0 - 30.0, c0 + 30.0), (e0, math.log(scale) + 30.0)])
        f1 = min(float(r.fun), f0)
        e = math.exp(float(r.x[1])) if float(r.fun) < f0 else 0.0
        best1 = min(best1, (f1, float(beta), e))
    return max(2.0 * (best0[0] - best1[0]), 0.0) / NOISE_FLOOR_INFLATION, best1[1], best1[2]


def common_excess(z1: np.ndarray, z2: np.ndarray, modelled_cov: float, excess: tuple[float, float]) -> float:
    """The part of both channels' excess noise (:func:`noise_floor`) that they share, DN^2: eq. (6).

    Parameters
    ----------
    z1, z2 : ndarray, shape (H, W)
        The two channels' separated data on the crop (DN).
    modelled_cov : float
        Their modelled noise covariance per pixel, DN^2.
    excess : tuple of 2 float
        Each channel's excess variance (>= 0), DN^2.

    Returns
    -------
    float
        ``sqrt(excess_1 excess_2)`` (shared in full) or 0 (each channel's own).

    Notes
    -----
    The excess has two kinds of cause. An error that is the same in every frame (undithered rounding, a fixed
    pattern's error) enters both separated channels in full, ``u + [1, 1] e``: correlation 1. A PSF or a model that
    differs from the data's acts on each channel's own scene: correlation 0. The two channels image different scenes
    (the fovea magnified, the field around it), whose cross-spectrum averages to 0, so the mean cross-periodogram over
    the upper half of the frequencies (beyond 0.25 cycles per pixel, where the scenes are weakest), less the modelled
    covariance, estimates the shared part; the nearer of the two causes is taken (the estimate's own scatter, from
    the scenes' detail, is large next to its 0-1 range, and a correlation estimated short of 1 costs the joint
    solve several dB where the error is in fact shared):

        rho = (<Re P_12(f)>_{|f| > 1/4} - C_12) / sqrt(e_1 e_2),   e_12 = sqrt(e_1 e_2) if rho > 1/2 else 0   (6)
    """
    from scipy.fft import rfft2

    if min(excess) <= 0.0:
        return 0.0
    H, W = z1.shape
    w = hann_taper((H, W))
    F1, F2 = (rfft2((z - np.mean(z)) * w) for z in (z1, z2))
    hi = rfft_frequencies((H, W)) > 0.25
    wt = np.broadcast_to(rfft_weights((H, W)), hi.shape)[hi]
    cross = float(np.sum(wt * np.real(F1[hi] * np.conj(F2[hi]))) / np.sum(wt)) / float(np.sum(w ** 2))
    both = math.sqrt(excess[0] * excess[1])
    return both if cross - modelled_cov > 0.5 * both else 0.0


def fitted_spectrum(z: np.ndarray, z_padded: np.ndarray, D: np.ndarray, noise_var: float, prior: str = "power-law",
                    scale: float = 1.0) -> tuple[np.ndarray, dict[str, Any]]:
    """The scene's power spectrum per unnormalised FFT bin of the padded grid, estimated from the crop ``z``.

    Parameters
    ----------
    z : ndarray, shape (H, W)
        One channel's separated data on the crop (DN above the dark level).
    z_padded : ndarray, shape (P, Q)
        ``z`` less its mean on the padded grid of the solve (edge values in the padding).
    D : ndarray, shape (P, Q // 2 + 1)
        The channel's transfer function on that grid.
    noise_var : float
        The data's noise variance per pixel, DN^2.
    prior : {'power-law', 'hybrid', 'empirical'}
        ``'empirical'``: eq. (2) where the signal is positive, 0 elsewhere. ``'power-law'``: eq. (3) fitted on
        every detected ring. ``'hybrid'``: eq. (3) fitted on the detected rings beyond the spectrum's peak, and
        below that tail, where the signal exceeds :data:`MEASURED_SNR` x the noise, the padded grid's own
        radially averaged periodogram less the noise, over ``|D|^2``: the spectrum of the scene the solve is posed
        on (the crop and its edge-extended padding, whose stripes hold most of the low frequencies' power).
    scale : float
        The per-pixel spectrum becomes ``scale x n_grid x S`` on the grid (the solver's ``prior_scale``).

    Returns
    -------
    spectrum : ndarray, shape (P, Q // 2 + 1)
    info : dict
        ``prior``; ``bins`` and ``bins_with_signal`` (empirical) or ``beta``, ``bins_used`` and ``level_from``
        (``'detected rings'``, or ``'likelihood'``: :func:`whittle_level`) (the fit);
        ``'hybrid'`` adds ``measured_bins`` and ``measured_below_cycles_per_px``.
    """
    from scipy.fft import rfft2

    nb = RADIAL_BINS
    shape = z_padded.shape
    f_grid = rfft_frequencies(shape)
    fc, pz, cnt = crop_periodogram(z, nb)
    _, pd, _ = radial_mean(f_grid, np.abs(D) ** 2, nb)
    sig = pz - noise_var  # power spectral density per pixel
    n_grid = shape[0] * shape[1]
    if prior == "empirical":
        est = np.where(np.isfinite(sig) & (sig > 0) & (pd > 0), sig / np.maximum(pd, 1e-300), 0.0)
        return radial_field(f_grid, est) * n_grid * scale, {"prior": "empirical", "bins": nb,
                                                             "bins_with_signal": int(np.sum(est > 0))}
    ok = np.isfinite(sig) & (sig > DETECTION_SNR * noise_var) & (fc > 0) & (pd > 0)
    ok[0] = False
    idx = np.flatnonzero(ok)
    if prior == "hybrid" and idx.size >= MIN_HYBRID_BINS:
        # the tail beyond the spectrum's peak sets the extrapolation: fit the detected rings above the peak
        ratio = np.where(ok, sig / np.maximum(pd, 1e-300), 0.0)
        peak = int(idx[np.argmax(ratio[idx])])
        tail = ok & (np.arange(ok.size) >= peak)
        if tail.sum() >= MIN_FIT_BINS:
            ok = tail
    beta = DEFAULT_BETA
    if ok.sum() >= MIN_FIT_BINS:
        beta = float(np.clip(-np.polyfit(np.log(fc[ok]), np.log(sig[ok] / pd[ok]), 1)[0], *BETA_RANGE))
        logc = float(np.mean(np.log(sig[ok] / pd[ok]) + beta * np.log(fc[ok])))
        level_from = "detected rings"
    else:  # too few detected rings for a fit: the level that makes the whole periodogram likeliest
        valid = np.isfinite(pz) & (fc > 0) & (pd > 0) & (cnt > 0)
        valid[0] = False
        if not valid.any():
            raise InputError("frames", f"a crop of {z.shape[0]} x {z.shape[1]} px",
                             "a crop holding a frequency besides the mean that the channel's PSF transmits (a few "
                             "pixels across): the scene's spectrum cannot be estimated from this one")
        logc = whittle_level(fc[valid], pz[valid], pd[valid], cnt[valid], noise_var, beta)
        level_from = "likelihood"
    f = np.maximum(f_grid, 1.0 / max(shape))
    law = n_grid * scale * np.exp(logc) / f ** beta
    info = {"prior": prior, "beta": beta, "bins_used": int(ok.sum()), "level_from": level_from}
    if prior == "hybrid":
        # below the fitted tail, where the signal is strong: the padded grid's measured spectrum
        strong = (np.isfinite(sig) & (sig > MEASURED_SNR * noise_var) & (pd > 0)
                  & (fc < fc[ok].min() if ok.any() else False))
        _, pp, _ = radial_mean(f_grid, np.abs(rfft2(z_padded, axes=(-2, -1), workers=-1)) ** 2, nb)
        meas = np.where(strong, np.maximum(pp - n_grid * noise_var, 0.0) / np.maximum(pd, 1e-300), 0.0)
        field = radial_field(f_grid, meas)
        law = np.where(field > 0, field, law)
        info["measured_bins"] = int(strong.sum())
        half_bin = 0.5 * float(fc[1] - fc[0])
        info["measured_below_cycles_per_px"] = float(fc[strong].max()) + half_bin if strong.any() else 0.0
    return law, info


def inverse_prior(spectra: list[np.ndarray]) -> np.ndarray:
    """The inverse of both channels' prior spectra, floored, with the mean (DC) not shrunk.

    Parameters
    ----------
    spectra : list of 2 ndarray, shape (P, Q // 2 + 1)
        Each channel's prior per unnormalised FFT bin.

    Returns
    -------
    ndarray, shape (2, P, Q // 2 + 1)
        ``1 / max(S, PRIOR_FLOOR max S)``, 0 at DC.
    """
    # a bin without signal gets the largest penalty, not none
    inv = np.stack([1.0 / np.maximum(p, PRIOR_FLOOR * max(float(np.max(p)), 1e-300)) for p in spectra])
    inv[:, 0, 0] = 0.0  # the mean is not shrunk
    return inv

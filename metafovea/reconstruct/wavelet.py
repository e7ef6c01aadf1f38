"""The non-linear step of the PSF-aware reconstruction: a regularised Fourier inverse, then wavelet shrinkage whose
parameters minimise Stein's unbiased risk estimate (SURE).

A linear deconvolution must trade noise against blur with one filter for the whole image; edges and small sources
need little regularisation, flat regions much. Following ForWaRD [1]_, each channel is first inverted with *less*
regularisation than the Wiener filter (the prior's inverse times ``tau <= 1``: eq. (3) of
:mod:`metafovea.reconstruct.joint`), which leaves a sharp but noisy estimate ``x_tau = G_tau z``; its noise is
coloured Gaussian, ``G_tau`` applied to the data's noise, and is then removed where the image is smooth by
shrinking the coefficients of an undecimated (stationary) wavelet transform [2]_. Every coefficient ``w`` of
subband ``j`` is mapped through the linear expansion of thresholds (SURE-LET, [3]_)

    theta_j(w) = a_j1 w + a_j2 w exp(-w^2 / (12 sigma_j^2))                                         (1)

with ``sigma_j^2`` the noise variance of subband ``j`` and ``(a_j1, a_j2)`` the minimisers of that subband's SURE, a
2 x 2 linear system. Below the coarsest level a coefficient's parent ``q`` (the coefficient at the same position
one level coarser, of the same orientation) says whether it lies on a feature: large wavelet coefficients persist
across scales, noise does not. Eq. (1) is then split by the parent, as in the interscale SURE-LET of [3]_,

    theta_j(w, q) = gamma(q) (a_j1 w + a_j2 w e(w)) + (1 - gamma(q)) (a_j3 w + a_j4 w e(w)),            (1b)

    gamma(q) = exp(-q^2 / (12 sigma_q^2)),  e(w) = exp(-w^2 / (12 sigma_j^2)),

``sigma_q^2`` the parent's noise variance: four coefficients, again the minimisers of the subband's SURE (a 4 x 4
system). The parent's coefficient at the same position (no shift): the frame's atoms are causal filters, so the
parent's would be centred ``2^j`` px away; aligned, the parents predicted no better on the scene generator's tuning
seeds. In a redundant frame a coefficient's noise and its parent's are correlated (their filters share
frequencies), so the divergence of eq. (1b) carries a second term: ``sum_k (d theta / d w) sigma_j^2 + rho_j sum_k
(d theta / d q)``, ``rho_j`` the two coefficients' noise covariance (:meth:`StationaryFrame.parent_covariances`).
Without it SURE undercounts the noise that the parent passes on, and the coefficients it picks are far from the
best on tuning cases. The noise variances are measured, not modelled: :data:`NOISE_SAMPLES` draws of the data's noise
(per-pixel covariance ``C``, padded as the data are) are passed through the same filter and transform
(:meth:`StationaryFrame.noise_variances`), so the padding and the joint 2 x 2 filter are counted exactly.

The regularisation ``tau`` is chosen per channel by the estimated mean squared error against the scene. The shrunk
estimate is split into its best linear fit per subband, ``L x_tau`` with ``L = F^T diag(g) F`` (``g_b = <theta_b(w),
w> / <w, w>``: a stationary filter ``L(f) = sum_b g_b |F_b(f)|^2``), and what the non-linear map changes,

    R(tau) = R_lin(tau) + SURE(tau) - SURE_lin(tau)                                                    (2)

``R_lin`` the risk of the linear estimate ``L G_tau z`` against the scene, estimated from the data (the generalised
SURE of a linear estimate [4]_, eq. (4) of :meth:`metafovea.reconstruct.joint.PeriodicFilter.linear_risk`: no prior
where the prior predicts the data's signal above their noise, the prior's expectation where it does not), and
``SURE - SURE_lin`` the shrinkage's Stein estimate less that of its linear fit, both against ``E[x_tau] = G_tau D
s``. The linear fit carries the cross term between the Fourier step's bias and the shrinkage (both remove detail in
the same bands); only the non-linear remainder's cross term with the bias is neglected. A risk predicted from the
prior alone (``B(tau) = sum_f |[(I - G_tau D)]_i|^2 P(f) / n^2`` plus SURE, the cross term neglected) follows the
prior's errors; it is what ``boundary='unknown'`` (no periodic data) still uses:

    R_prior(tau) = B(tau) + SURE(tau)                                                                  (2b)

The search runs over :data:`TAUS`; the chosen ``tau`` is the largest whose risk is within one standard error of
the lowest (the one-standard-error rule: a sharper estimate only where the data show it better by more than the
estimate's own noise; :func:`metafovea.reconstruct.deconvolve.separate_deconvolve`).

The linear fit's SURE (``theta_j'`` replaced by ``g_j``)::

    SURE_lin = (||L x - x||^2 - tr C_x + 2 sum_j g_j sigma_j^2 n_j) / n                              (3)

Constants: :data:`NOISE_SAMPLES`, :data:`TAUS`, :data:`MIN_COARSEST_PX`, and the 12 of eq. (1) and (1b) (the
thresholds ``sqrt(6) sigma`` of [3]_) (the module docstring of
:mod:`metafovea.reconstruct.deconvolve` lists where each comes from); the wavelet (``wavelet``, default
:data:`DEFAULT_WAVELET`) is an option.

References
----------
.. [1] R. Neelamani, H. Choi and R. Baraniuk, "ForWaRD: Fourier-wavelet regularized deconvolution for
   ill-conditioned systems", IEEE Trans. Signal Process. 52, 418 (2004).
.. [2] G. P. Nason and B. W. Silverman, "The stationary wavelet transform and some statistical applications",
   in *Wavelets and Statistics*, Lecture Notes in Statistics 103, 281 (Springer, 1995).
.. [3] F. Luisier, T. Blu and M. Unser, "A new SURE approach to image denoising: interscale orthonormal wavelet
   thresholding", IEEE Trans. Image Process. 16, 593 (2007).
.. [4] Y. C. Eldar, "Generalized SURE for exponential families: applications to regularization", IEEE Trans. Signal
   Process. 57, 471 (2009).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from metafovea.errors import InputError
from metafovea.reconstruct.spectra import rfft_weights

#: wavelets :func:`shrink` accepts (PyWavelets names): Haar's piecewise-constant atoms and two smoother ones
WAVELETS = ("haar", "db2", "sym4")
#: the default wavelet: with eq. (1b) Haar has the highest median and mean margin to the Wiener bound on the scene
#: generator's tuning seeds, db2 and sym4 0.04-0.3 dB below it (BENCHMARKS.md, "PSF-aware reconstruction on scenes
#: never seen"), and the shortest filters; an option of
#: :func:`metafovea.reconstruct.deconvolve.separate_deconvolve` (``wavelet``)
DEFAULT_WAVELET = "haar"
#: draws of the noise through the filter per channel: the subband variances' relative standard error is about
#: ``sqrt(2 / (NOISE_SAMPLES n_eff))`` with ``n_eff`` the subband's independent coefficients (> 100 at the coarsest
#: of :func:`swt_levels`), i.e. < 7 %, a < 0.3 dB change of the threshold
NOISE_SAMPLES = 4
#: the regularisation multipliers searched (eq. 2): 1 is the Wiener filter, each step halves the prior's weight,
#: down to 1/64, where the Fourier step's noise is 64 times (at most) the Wiener filter's in the bins that the
#: prior governs
TAUS = tuple(2.0 ** -k for k in range(7))
#: the coarsest subband's atoms (``2^levels`` px) fit at least this many times across the crop (:func:`swt_levels`)
MIN_COARSEST_PX = 8


def swt_levels(shape: tuple[int, int]) -> int:
    """The stationary transform's depth for an image of ``shape``: the largest ``L`` with ``2^L`` at most
    ``min(shape) / MIN_COARSEST_PX``, between 1 and 6.

    Parameters
    ----------
    shape : tuple of 2 int

    Returns
    -------
    int
    """
    n = min(shape) / MIN_COARSEST_PX
    return int(min(6, max(1, math.floor(math.log2(max(n, 2.0))))))


def _check_wavelet(wavelet: str) -> str:
    if wavelet not in WAVELETS:
        raise InputError("wavelet", wavelet, "one of " + ", ".join(WAVELETS))
    return wavelet


@functools.lru_cache(maxsize=8)
def stationary_frame(shape: tuple[int, int], wavelet: str, levels: int) -> StationaryFrame:
    """:class:`StationaryFrame` ``(shape, wavelet, levels)``, made once (the channels and every ``tau`` share it)."""
    return StationaryFrame(shape, wavelet, levels)


class StationaryFrame:
    """The stationary (undecimated) 2-D wavelet transform of a ``(P, Q)`` periodic image as FFT filters.

    Subband ``b`` of an image ``y`` is ``irfft2(rfft2(y) F_b)``; the filters are the separable products of the
    wavelet's analysis filters ``h_0``, ``h_1`` (PyWavelets' ``dec_lo``, ``dec_hi``), dilated by ``2^(j-1)`` at
    level ``j`` (the *a trous* scheme) and divided by ``sqrt 2`` per axis and level, so that
    ``sum_b |F_b(f)|^2 = 1``: a Parseval frame, whose synthesis is its adjoint,
    ``y = irfft2(sum_b rfft2(w_b) conj(F_b))``.

    Attributes
    ----------
    factors : tuple of 2 ndarray
        The separable factors of :attr:`filters`.
    shape : tuple of 2 int
    """

    def __init__(self, shape: tuple[int, int], wavelet: str, levels: int):
        import pywt

        w = pywt.Wavelet(_check_wavelet(wavelet))
        P, Q = shape

        def resp(h: list[float], f: np.ndarray, j: int) -> np.ndarray:
            n = np.arange(len(h))
            return np.exp(-2j * np.pi * (2 ** j) * f[:, None] * n).dot(np.asarray(h)) / math.sqrt(2.0)

        # every filter is the product of a response along y and one along x: kept as the two factors (the grid's
        # frame is only ever asked for its power's weighted sums, :meth:`transfer`: 0.8 s and 50 MB on a 900 x 900
        # grid as full arrays)
        fy, fx = np.fft.fftfreq(P), np.fft.rfftfreq(Q)
        low_y, low_x = np.ones(P, dtype=complex), np.ones(Q // 2 + 1, dtype=complex)
        details = []
        for j in range(levels):
            ly, hy = resp(w.dec_lo, fy, j), resp(w.dec_hi, fy, j)
            lx, hx = resp(w.dec_lo, fx, j), resp(w.dec_hi, fx, j)
            details.append([(low_y * ly, low_x * hx), (low_y * hy, low_x * lx), (low_y * hy, low_x * hx)])
            low_y, low_x = low_y * ly, low_x * lx
        pairs = [(low_y, low_x)] + [pair for level in details[::-1] for pair in level]
        #: the factors along y ``(3 L + 1, P)`` and x ``(3 L + 1, Q // 2 + 1)``: ``filters[b] = fy[b] (x) fx[b]``
        self.factors = (np.array([py for py, _ in pairs]), np.array([px for _, px in pairs]))
        self._power_factors = (np.abs(self.factors[0]) ** 2, np.abs(self.factors[1]) ** 2)
        self.shape = (P, Q)

    @functools.cached_property
    def filters(self) -> np.ndarray:
        """The subbands' transfer functions, ``(3 L + 1, P, Q // 2 + 1)``: the approximation at level ``L`` first,
        then per level (coarsest first) the three details."""
        fy, fx = self.factors
        return fy[:, :, None] * fx[:, None, :]

    @functools.cached_property
    def _filters32(self) -> np.ndarray:
        return self.filters.astype(np.complex64)

    @functools.cached_property
    def power(self) -> np.ndarray:
        """``|F_b(f)|^2``, shape ``(3 L + 1, P, Q // 2 + 1)``: a subband-diagonal linear map's transfer function is
        ``sum_b g_b |F_b(f)|^2`` (:meth:`transfer`)."""
        py, px = self._power_factors
        return py[:, :, None] * px[:, None, :]

    def transfer(self, gains: np.ndarray) -> np.ndarray:
        """``sum_b gains_b |F_b(f)|^2`` ``(P, Q // 2 + 1)``: the transfer function of the map that multiplies
        subband ``b`` by ``gains_b`` (``(3 L + 1,)``) and synthesises (a sum of separable products: no
        ``(3 L + 1, P, Q // 2 + 1)`` array)."""
        py, px = self._power_factors
        return (np.asarray(gains, dtype=np.float64)[:, None] * py).T @ px

    def _f(self, a: np.ndarray) -> np.ndarray:
        return self._filters32 if a.dtype in (np.float32, np.complex64) else self.filters

    def analysis(self, y: np.ndarray) -> np.ndarray:
        """All subbands of ``y`` (P, Q): shape ``(3 L + 1, P, Q)``, in ``y``'s precision."""
        from scipy.fft import irfft2, rfft2

        return irfft2(rfft2(y, workers=-1)[None] * self._f(y), s=self.shape, axes=(-2, -1), workers=-1)

    def synthesis(self, c: np.ndarray) -> np.ndarray:
        """The image of subbands ``c`` ``(3 L + 1, P, Q)``: the frame's adjoint (its inverse on its range)."""
        from scipy.fft import irfft2, rfft2

        spec = np.sum(rfft2(c, axes=(-2, -1), workers=-1) * np.conj(self._f(c)), axis=0)
        return irfft2(spec, s=self.shape, workers=-1)

    def mean_square(self, spec: np.ndarray) -> float:
        """The mean over the image's pixels of a field whose power per unnormalised rfft bin is ``spec``
        ``(P, Q // 2 + 1)`` (Parseval, the half plane's inner columns counted twice)."""
        P, Q = self.shape
        return float(np.sum(spec * rfft_weights(self.shape)) / float(P * Q) ** 2)

    def noise_moments(self, noise: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`noise_variances` and :meth:`parent_covariances` of the draws ``(K, P, Q)``, their spectra taken
        once."""
        from scipy.fft import rfft2

        P, Q = self.shape
        spec = np.mean(np.abs(rfft2(noise, axes=(-2, -1), workers=-1)) ** 2, axis=0) * rfft_weights(self.shape)
        py, px = self._power_factors
        var = np.sum((py @ spec) * px, axis=1)
        fy, fx = self.factors
        cov = np.zeros(fy.shape[0])
        b = np.arange(4, fy.shape[0])
        if b.size:  # Re(u_y v_x) summed against the spectrum, u = F_b conj(F_q) along y, v along x
            uy, vx = fy[b] * np.conj(fy[b - 3]), fx[b] * np.conj(fx[b - 3])
            cov[b] = np.sum((uy.real @ spec) * vx.real, axis=1) - np.sum((uy.imag @ spec) * vx.imag, axis=1)
        return var / float(P * Q) ** 2, cov / float(P * Q) ** 2

    def parent_covariances(self, noise: np.ndarray) -> np.ndarray:
        """Each subband's noise covariance with its parent's (:func:`parent_of`) at the same position, over the noise
        draws ``(K, P, Q)`` (Parseval on their spectra: ``sum_f Re(F_b conj(F_q)) |N(f)|^2``): ``(3 L + 1,)``, 0
        where there is no parent."""
        return self.noise_moments(noise)[1]

    def noise_variances(self, noise: np.ndarray) -> np.ndarray:
        """Each subband's mean square over the noise draws ``(K, P, Q)`` (Parseval on their spectra): ``(3 L + 1,)``."""
        return self.noise_moments(noise)[0]


def parent_of(b: int) -> int | None:
    """The subband of :attr:`StationaryFrame.filters` one level coarser than subband ``b``, of its orientation
    (None: the approximation or the coarsest level's details)."""
    return b - 3 if b > 3 else None


class _Shrinkage:
    """Eq. (1) (or (1b), given the parent's coefficients) fitted on one subband by its SURE: the shrunk coefficients
    and their derivatives in the coefficient (:meth:`dw`) and in its parent (:meth:`dq`, None without one)."""

    def __init__(self, w: np.ndarray, var: float, q: np.ndarray | None = None, q_var: float = 0.0,
                 rho: float = 0.0):
        n = w.size
        e = np.exp(-w * w / (12.0 * var))
        self._w, self._f2, self._d2 = w, w * e, e * (1.0 - w * w / (6.0 * var))
        self._gam = self._dgam = None
        # the atoms as rows, and the sums over the subband of their derivatives in w and in q
        if q is None or not q_var > 0:
            X = np.stack([w.ravel(), self._f2.ravel()])
            sdw, sdq = np.array([n, np.sum(self._d2)]), np.zeros(2)
        else:
            gam = np.exp(-q * q / (12.0 * q_var))
            self._gam, self._dgam = gam, -q / (6.0 * q_var) * gam
            gw, gf = gam * w, gam * self._f2
            X = np.stack([gw.ravel(), gf.ravel(), (w - gw).ravel(), (self._f2 - gf).ravel()])
            sg, sgd, sd = float(np.sum(gam)), float(np.sum(gam * self._d2)), float(np.sum(self._d2))
            qw, qf = float(np.sum(self._dgam * w)), float(np.sum(self._dgam * self._f2))
            sdw, sdq = np.array([sg, sgd, n - sg, sd - sgd]), np.array([qw, qf, -qw, -qf])
        # SURE of sum_k a_k atom_k is ||sum_k a_k atom_k - w||^2 + 2 (var sum dtheta/dw + rho sum dtheta/dq) + const:
        # its minimiser solves (X X^T) a = X w - var sdw - rho sdq
        # a numerically singular system (condition number above 1e12, double precision's 1e-16 leaving 1e-4 of the
        # coefficients) has no stable minimiser: a parent that splits nothing (the same weight everywhere) falls back
        # to eq. (1); a subband whose two atoms coincide (all of it far below its noise, or none) is kept
        G = X @ X.T
        a = None
        if np.all(np.isfinite(G)) and np.linalg.cond(G) < 1e12:
            a = np.linalg.solve(G, X @ w.ravel() - var * sdw - rho * sdq)
        elif self._gam is not None:
            self.__init__(w, var)  # type: ignore[misc]
            return
        #: the coefficients (None: the subband is kept)
        self.a = a if a is not None and np.all(np.isfinite(a)) else None
        self._sdw, self._sdq, self._var, self._rho = sdw, sdq, var, rho

    def _pair(self) -> tuple[float, float, float, float]:
        """Eq. (1b) as ``(b1 + gamma c1) w + (b2 + gamma c2) w e(w)``: ``(b1, b2, c1, c2)``."""
        a = self.a
        if len(a) == 2:  # type: ignore[arg-type]
            return a[0], a[1], 0.0, 0.0  # type: ignore[index]
        return a[2], a[3], a[0] - a[2], a[1] - a[3]  # type: ignore[index]

    def value(self) -> np.ndarray:
        if self.a is None:
            return self._w
        b1, b2, c1, c2 = self._pair()
        out = b1 * self._w + b2 * self._f2
        return out if self._gam is None else out + self._gam * (c1 * self._w + c2 * self._f2)

    def dw(self) -> np.ndarray | None:
        if self.a is None:
            return None
        b1, b2, c1, c2 = self._pair()
        out = b1 + b2 * self._d2
        return out if self._gam is None else out + self._gam * (c1 + c2 * self._d2)

    def dq(self) -> np.ndarray | None:
        if self.a is None or self._dgam is None:
            return None
        _, _, c1, c2 = self._pair()
        return self._dgam * (c1 * self._w + c2 * self._f2)

    def divergence(self) -> float:
        """``sum_k (var dtheta/dw + rho dtheta/dq)``, the divergence term of SURE (a kept subband: ``n var``)."""
        if self.a is None:
            return self._var * self._w.size
        return float(self._var * self.a @ self._sdw + self._rho * self.a @ self._sdq)


def _shrinkages(c: np.ndarray, var: np.ndarray, cov: np.ndarray | None) -> dict[int, _Shrinkage]:
    """Each detail subband's fitted shrinkage (eq. 1 at the coarsest level, 1b below; eq. 1 everywhere where
    ``cov`` is None), those with noise only."""
    out = {}
    for b in range(1, c.shape[0]):
        if var[b] > 0:
            p = None if cov is None else parent_of(b)
            out[b] = _Shrinkage(c[b], float(var[b]), None if p is None else c[p],
                                0.0 if p is None else float(var[p]), 0.0 if p is None else float(cov[b]))
    return out


def shrink_jacobian(img: np.ndarray, noise: np.ndarray, wavelet: str = DEFAULT_WAVELET,
                    levels: int | None = None, interscale: bool = True) -> np.ndarray:
    """The Jacobian of :func:`shrink` at ``img`` applied to each draw of ``noise``: the shrunk estimate's noise to
    first order in the noise, ``F^T diag(theta'(F img)) F n``.

    Parameters
    ----------
    img, noise, wavelet, levels, interscale
        As :func:`shrink` (the draws set the thresholds, as there, and are the vectors the Jacobian is applied to).

    Returns
    -------
    ndarray, shape (K, H, W)
    """
    img = np.asarray(img, dtype=np.float64)
    noise = np.asarray(noise, dtype=np.float64)
    levels = swt_levels(img.shape) if levels is None else int(levels)
    frame = stationary_frame(img.shape, _check_wavelet(wavelet), levels)
    var, cov = frame.noise_moments(noise)
    c = frame.analysis(img.astype(np.float32)).astype(np.float64)
    # d theta / d w and d theta / d q per shrunk subband (the others are kept: d theta / d w = 1)
    deriv = {}
    for b, sh in _shrinkages(c, var, cov if interscale else None).items():
        dw, dq = sh.dw(), sh.dq()
        if dw is not None:
            deriv[b] = (dw.astype(np.float32), None if dq is None else dq.astype(np.float32))
    out = np.empty_like(noise)
    for k in range(noise.shape[0]):
        cn = frame.analysis(noise[k].astype(np.float32))
        jn = cn.copy()
        for b, (dw, dq) in deriv.items():
            jn[b] = dw * cn[b] if dq is None else dw * cn[b] + dq * cn[parent_of(b)]  # type: ignore[index]
        out[k] = frame.synthesis(jn)
    return out


def shrink(img: np.ndarray, noise: np.ndarray, wavelet: str = DEFAULT_WAVELET,
           levels: int | None = None, interscale: bool = True) -> tuple[np.ndarray, float]:
    """SURE-LET shrinkage of a noisy image in the stationary wavelet transform, eq. (1b) (eq. (1) at the coarsest
    level).

    Parameters
    ----------
    img : ndarray, shape (H, W)
        The noisy image (any units), transformed as periodic. Its noise must be (close to) stationary: the
        thresholds are per subband, not per pixel (a mirror or edge extension, whose noise repeats the edge's,
        makes the risk estimate wrong there).
    noise : ndarray, shape (K, H, W)
        Draws of its noise (same units): their subband variances set the thresholds.
    wavelet : str
        One of :data:`WAVELETS`.
    levels : int, optional
        Transform depth (default :func:`swt_levels` of ``img.shape``).
    interscale : bool
        Eq. (1b), each coefficient's shrinkage split by its parent (default); False: eq. (1), each coefficient by
        its own value only (the held-out set's comparison: BENCHMARKS.md, "PSF-aware reconstruction on scenes
        never seen").

    Returns
    -------
    estimate : ndarray, shape (H, W)
    sure : float
        Stein's unbiased estimate of the estimate's mean squared error per pixel against the noise-free image.

    Notes
    -----
    The frame (:class:`StationaryFrame`) is Parseval, so its synthesis is its adjoint and the SURE of
    ``f(y) = F^T theta(F y)`` under Gaussian noise of any covariance ``C`` is
    ``(||f(y) - y||^2 - tr C + 2 sum_jk (theta_j,w(w_jk, q_jk) sigma_j^2 + theta_j,q(w_jk, q_jk) rho_j)) / n``
    (``tr C``: the noise draws' mean energy; ``theta_j,w``, ``theta_j,q`` the derivatives of eq. (1b) in the
    coefficient and in its parent, ``rho_j`` their noise covariance; eq. (1): ``theta_j,q = 0``). The coefficients
    of eq. (1b) minimise each subband's own SURE, so the total is slightly optimistic (by the 4 x 3 (L - 1) + 2 x 3
    fitted parameters' share of the coefficients).
    """
    est, sure, _, _ = shrink_linearised(img, noise, wavelet, levels, interscale)
    return est, sure


def shrink_linearised(img: np.ndarray, noise: np.ndarray, wavelet: str = DEFAULT_WAVELET,
                      levels: int | None = None,
                      interscale: bool = True) -> tuple[np.ndarray, float, np.ndarray, float]:
    """:func:`shrink`, with the shrinkage's best linear fit per subband and that fit's own SURE, eq. (3).

    Parameters
    ----------
    img, noise, wavelet, levels, interscale
        As :func:`shrink`.

    Returns
    -------
    estimate : ndarray, shape (H, W)
    sure : float
        As :func:`shrink`.
    gains : ndarray, shape (3 L + 1,)
        ``g_b = <theta_b(w), w> / <w, w>`` per subband (the approximation first, kept: 1), in the order of
        :attr:`StationaryFrame.filters`: the linear map ``F^T diag(g) F`` is the filter
        ``sum_b g_b |F_b(f)|^2``.
    sure_linear : float
        The SURE of that linear map's estimate, per pixel (``theta_j'`` replaced by ``g_j``).
    """
    img = np.asarray(img, dtype=np.float64)
    noise = np.asarray(noise, dtype=np.float64)
    if img.ndim != 2 or noise.ndim != 3 or noise.shape[1:] != img.shape or noise.shape[0] < 1:
        raise InputError("noise", f"array of shape {noise.shape}", f"(K, H, W) draws with (H, W) = {img.shape}")
    levels = swt_levels(img.shape) if levels is None else int(levels)
    frame = stationary_frame(img.shape, _check_wavelet(wavelet), levels)
    var, cov = frame.noise_moments(noise)
    # the subbands in single precision (their rounding, ~1e-7 of the image's range, is far below any noise shrunk)
    c = frame.analysis(img.astype(np.float32)).astype(np.float64)
    div = float(var[0]) * c[0].size  # the approximation is kept: theta' = 1
    div_lin = div
    gains = np.ones(c.shape[0])
    out = c.copy()  # a subband without noise is kept
    for b, sh in _shrinkages(c, var, cov if interscale else None).items():
        out[b] = sh.value()
        div += sh.divergence()
        ww = float(np.sum(c[b] * c[b]))
        gains[b] = float(np.sum(out[b] * c[b])) / ww if ww > 0 else 1.0
        div_lin += gains[b] * float(var[b]) * c[b].size
    est = frame.synthesis(out.astype(np.float32)).astype(np.float64)
    tr = float(np.mean(np.sum(noise ** 2, axis=(1, 2))))
    sure = (float(np.sum((est - img) ** 2)) - tr + 2.0 * div) / img.size
    # ||L x - x||^2 in the Fourier domain: L x - x has the spectrum (sum_b g_b |F_b|^2 - 1) X
    from scipy.fft import rfft2

    resid = (frame.transfer(gains) - 1.0) ** 2 * np.abs(rfft2(img, workers=-1)) ** 2
    sure_lin = frame.mean_square(resid) - (tr - 2.0 * div_lin) / img.size
    return est, sure, gains, sure_lin

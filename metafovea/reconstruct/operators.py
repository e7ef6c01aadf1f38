"""The foveal constraint as explicit linear operators.

The foveal image ``x1`` is a ``scale``-times magnified view of the centre of the perifoveal image ``x2``
(``scale = f1 / f2 = 150 / 25 = 6`` for the paper's lenses). With both images on the same ``(H, W)``
sensor grid, the relation is

    D x1 == gain * C x2 + bias                                                                           (1)

(``gain = 1``, ``bias = 0`` for images in common radiometric units; a real two-lens camera has
``gain = NA1^2 / NA2^2`` -- 0.294 for the paper's F/2 foveal and F/1 perifoveal lenses -- and, for
frames in ADC numbers with a dark level, ``bias = (1 - gain) * dark``; see
``meta['foveal_constraint']`` of a Measurement). The relation holds only up to the two channels' PSF
difference on real data: :func:`lowpass` compares both sides at a common, coarser resolution.

* ``D`` (downsampling): area-weighted mean of ``x1`` over boxes of ``scale x scale`` pixels, giving an
  ``(h, w) = (floor(H / scale), floor(W / scale))`` image. The boxes tile the centred region of ``x1``
  of size ``h * scale`` (all of ``x1`` when ``scale`` divides ``H``); for an integer ``scale`` that
  divides the shape, ``D`` is the plain block mean. A non-integer ``scale`` is exact too: a sensor
  pixel that straddles two boxes is split by area.
* ``C`` (crop): the centred ``(h, w)`` window of ``x2``, optionally displaced by a (sub-pixel)
  ``offset`` in ``x2`` pixels (registration); a fractional offset interpolates linearly (box
  overlap weights). With a ``rotation_deg``, the window turns with the foveal image: constraint pixel ``k``,
  the box of ``D`` centred ``F_k`` from the sensor's centre, reads ``x2`` at ``offset + R(rotation) F_k / scale``
  (``(row, column)`` vectors, ``R(phi) = [[cos, -sin], [sin, cos]]``) by bilinear interpolation, which is the
  box-overlap weighting above when the rotation is 0.

The geometry ``(scale, offset, rotation_deg)`` is the foveal relation's, in the convention of
docs/measurement_format.md ("The foveal geometry"): ``offset`` is the foveal centre, the point of the perifoveal
image (``x2`` pixels from the sensor's centre) that the foveal image's centre shows, and a scene point ``q`` lands in
the foveal image at ``scale R(-rotation) (q - offset)``: a positive rotation turns the foveal image's scene from
``+x`` (columns) towards ``+y`` (rows, down).

Both operators are separable without rotation, ``D x = Dy @ x @ Dx.T``, so their adjoints are exact and cheap; the
rotated crop is a sparse matrix of four weights per constraint pixel. They act on any leading batch axes
``(..., H, W)``. The TV helpers at the end (:func:`grad2d`, :func:`tv_charbonnier`) are
shared by the solvers that regularise with total variation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from metafovea.errors import InputError, as_float


def _box_weights(n_out: int, n_in: int, starts: np.ndarray, width: float) -> np.ndarray:
    """Matrix ``(n_out, n_in)``: row k holds the overlap of pixel j = [j, j+1) with
    [starts[k], starts[k] + width), divided by ``width`` (rows sum to 1 inside the grid)."""
    j = np.arange(n_in, dtype=np.float64)
    lo = np.maximum(starts[:, None], j[None, :])
    hi = np.minimum(starts[:, None] + width, j[None, :] + 1.0)
    return np.clip(hi - lo, 0.0, None) / width


def _rotated_crop(shape: tuple[int, int], low: tuple[int, int], scale: float, offset: tuple[float, float],
                  phi: float) -> object:
    """The rotated crop as a sparse ``(h w, H W)`` matrix: constraint pixel ``k`` reads ``x2`` by bilinear
    interpolation at ``offset + R(phi) F_k / scale`` from the sensor's centre, ``F_k`` the centre of its box of
    ``D`` (module docstring); every read point must lie inside the frame's pixel centres."""
    from scipy.sparse import csr_matrix

    (H, W), (h, w) = shape, low
    fy = ((np.arange(h) - h / 2.0 + 0.5) * scale)[:, None] * np.ones((1, w))
    fx = np.ones((h, 1)) * ((np.arange(w) - w / 2.0 + 0.5) * scale)[None, :]
    co, si = math.cos(phi), math.sin(phi)
    # pixel-index coordinates of the read points (pixel j's centre is j + 1/2 from the frame's edge)
    ry = (H / 2.0 - 0.5 + offset[0] + (co * fy - si * fx) / scale).ravel()
    rx = (W / 2.0 - 0.5 + offset[1] + (si * fy + co * fx) / scale).ravel()
    if ry.min() < -1e-9 or rx.min() < -1e-9 or ry.max() > H - 1 + 1e-9 or rx.max() > W - 1 + 1e-9:
        raise InputError("offset", offset, f"a foveal centre and rotation that keep the {h} x {w} rotated crop inside "
                         f"the {H} x {W} frame")
    y0 = np.clip(np.floor(ry).astype(int), 0, H - 2)
    x0 = np.clip(np.floor(rx).astype(int), 0, W - 2)
    ty, tx = ry - y0, rx - x0
    rows = np.repeat(np.arange(h * w), 4)
    cols = np.stack([y0 * W + x0, y0 * W + x0 + 1, (y0 + 1) * W + x0, (y0 + 1) * W + x0 + 1], axis=1).ravel()
    vals = np.stack([(1 - ty) * (1 - tx), (1 - ty) * tx, ty * (1 - tx), ty * tx], axis=1).ravel()
    return csr_matrix((vals, (rows, cols)), shape=(h * w, H * W))


def _sparse_apply(A: object, x: np.ndarray, out_shape: tuple[int, int]) -> np.ndarray:
    """``A`` (sparse, ``(n_out, n_in)``) applied to the last two axes of ``x``, flattened, with its leading axes and
    float32 kept."""
    x = np.asarray(x)
    lead = x.shape[:-2]
    flat = x.reshape(-1, x.shape[-2] * x.shape[-1])
    out = (A @ flat.T).T  # type: ignore[operator]
    dt = np.float32 if x.dtype == np.float32 else np.float64
    return np.asarray(out, dtype=dt).reshape(*lead, *out_shape)


def _check_scale(scale: float) -> float:
    s = as_float("scale", scale)
    if not (1.0 <= s <= 1000.0):
        raise InputError("scale", scale, "1 <= scale <= 1000 (f1/f2, 6 for the paper's lenses)")
    return s


@dataclass(frozen=True)
class FovealOperator:
    """``D`` (downsample x1) and ``C`` (centred crop of x2) of eq. (1) for one sensor shape and foveal geometry.

    Attributes
    ----------
    shape : tuple of 2 int
        ``(H, W)``.
    scale : float
        f1 / f2, in [1, 1000].
    offset : tuple of 2 float
        The crop's registration offset in x2 pixels: the foveal centre (module docstring).
    low : tuple of 2 int, optional
        Fix the constraint's size ``(h, w)`` (registration refines the scale at fixed size).
    gain, bias : float
        The constraint's radiometric gain and offset.
    rotation_deg : float
        The foveal image's rotation against the perifoveal one, degrees (module docstring); at most 45.
    Dy, Dx, Cy, Cx : ndarray
        The separable factors, ``(h, H)``, ``(w, W)`` (``Cy``, ``Cx``: the crop without rotation).
    Cs : scipy.sparse matrix or None
        The rotated crop, ``(h w, H W)``; None without rotation.
    """

    shape: tuple[int, int]
    scale: float = 6.0
    offset: tuple[float, float] = (0.0, 0.0)
    low: tuple[int, int] | None = None
    gain: float = 1.0
    bias: float = 0.0
    rotation_deg: float = 0.0
    Dy: np.ndarray = field(init=False, repr=False, compare=False)
    Dx: np.ndarray = field(init=False, repr=False, compare=False)
    Cy: np.ndarray = field(init=False, repr=False, compare=False)
    Cx: np.ndarray = field(init=False, repr=False, compare=False)
    Cs: object = field(init=False, repr=False, compare=False, default=None)

    def __post_init__(self) -> None:
        H, W = (int(v) for v in self.shape)
        s = _check_scale(self.scale)
        oy, ox = (as_float("offset", v) for v in self.offset)
        g = as_float("foveal_gain", self.gain)
        if not 0.0 < g < 1e6:
            raise InputError("foveal_gain", self.gain, "a positive radiometric gain (NA1^2/NA2^2; 1 for equal units)")
        b = as_float("foveal_offset", self.bias)
        rot = as_float("rotation_deg", self.rotation_deg)
        if not abs(rot) <= 45.0:
            raise InputError("rotation_deg", self.rotation_deg, "-45 <= rotation_deg <= 45 (the foveal image's "
                             "rotation against the perifoveal one, degrees)")
        h, w = int(math.floor(H / s + 1e-9)), int(math.floor(W / s + 1e-9))
        if self.low is not None:  # fixed constraint size (registration refines scale at fixed size)
            h, w = min(h, int(self.low[0])), min(w, int(self.low[1]))
        if h < 2 or w < 2:
            raise InputError("scale", self.scale, f"a scale that leaves at least 2 x 2 foveal-constraint "
                             f"pixels for frames of shape {(H, W)} (scale <= {min(H, W) / 2:g})")
        mats = {}
        for axis, (n, m, o) in {"y": (H, h, oy), "x": (W, w, ox)}.items():
            k = np.arange(m, dtype=np.float64)
            d_starts = n / 2.0 + (k - m / 2.0) * s
            c_starts = n / 2.0 - m / 2.0 + k + o
            if c_starts[0] < -1e-9 or c_starts[-1] + 1.0 > n + 1e-9:
                raise InputError("offset", self.offset, f"an offset that keeps the {m}-pixel crop inside "
                                 f"the {n}-pixel frame (|offset| <= {(n - m) / 2:g})")
            mats["D" + axis] = _box_weights(m, n, d_starts, s)
            mats["C" + axis] = _box_weights(m, n, c_starts, 1.0)
        object.__setattr__(self, "shape", (H, W))
        object.__setattr__(self, "scale", s)
        object.__setattr__(self, "offset", (oy, ox))
        object.__setattr__(self, "gain", g)
        object.__setattr__(self, "bias", b)
        object.__setattr__(self, "rotation_deg", rot)
        for k2, v in mats.items():
            object.__setattr__(self, k2, v)
        if rot:
            object.__setattr__(self, "Cs", _rotated_crop((H, W), (h, w), s, (oy, ox), math.radians(rot)))

    @property
    def low_shape(self) -> tuple[int, int]:
        """``(h, w)``: the constraint's size."""
        return self.Dy.shape[0], self.Dx.shape[0]

    def _mats(self, x: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dt = np.float32 if x.dtype == np.float32 else np.float64
        return a.astype(dt, copy=False), b.astype(dt, copy=False)

    def D(self, x1: np.ndarray) -> np.ndarray:
        """Downsample ``x1 (..., H, W) -> (..., h, w)`` (area mean over scale x scale boxes)."""
        my, mx = self._mats(x1, self.Dy, self.Dx)
        return my @ x1 @ mx.T

    def DT(self, u: np.ndarray) -> np.ndarray:
        """Adjoint of :meth:`D`: ``(..., h, w) -> (..., H, W)``."""
        my, mx = self._mats(u, self.Dy, self.Dx)
        return my.T @ u @ mx

    def C(self, x2: np.ndarray) -> np.ndarray:
        """Centred (offset, rotated) crop of ``x2 (..., H, W) -> (..., h, w)``."""
        if self.Cs is not None:
            return _sparse_apply(self.Cs, x2, self.low_shape)
        my, mx = self._mats(x2, self.Cy, self.Cx)
        return my @ x2 @ mx.T

    def CT(self, u: np.ndarray) -> np.ndarray:
        """Adjoint of :meth:`C`: zero-padded embedding ``(..., h, w) -> (..., H, W)``."""
        if self.Cs is not None:
            return _sparse_apply(self.Cs.T.tocsr(), u, self.shape)
        my, mx = self._mats(u, self.Cy, self.Cx)
        return my.T @ u @ mx

    def C_pinv(self, u: np.ndarray) -> np.ndarray:
        """The pseudo-inverse of :meth:`C` (without rotation): the least-norm ``x2`` change ``(..., H, W)`` whose crop
        is ``u`` ``(..., h, w)``, for any offset (a crop between pixels spreads over two)."""
        if self.Cs is not None:
            raise InputError("rotation_deg", self.rotation_deg, "0 for the crop's pseudo-inverse")
        return np.linalg.pinv(self.Cy) @ u @ np.linalg.pinv(self.Cx).T

    def upsample(self, u: np.ndarray) -> np.ndarray:
        """Each constraint pixel spread over its box (``U``): ``(..., h, w) -> (..., H, W)``.

        The normalised adjoint of :meth:`D` (area-weighted); pixels outside the covered region take the nearest
        box value. ``D(upsample(u)) == u`` exactly when boxes align with pixels (integer scale), otherwise it is a
        mild blur.
        """
        my, mx = self._mats(u, self.Dy, self.Dx)
        ny = my.T / np.maximum(my.T.sum(1, keepdims=True), 1e-300)
        nx = mx.T / np.maximum(mx.T.sum(1, keepdims=True), 1e-300)
        out = ny @ u @ nx.T
        # rows/columns outside the covered region (only when scale does not divide the shape)
        ry = np.where(my.sum(0) > 0)[0]
        rx = np.where(mx.sum(0) > 0)[0]
        if ry.size < out.shape[-2] or rx.size < out.shape[-1]:
            iy = np.clip(np.arange(out.shape[-2]), ry[0], ry[-1])
            ix = np.clip(np.arange(out.shape[-1]), rx[0], rx[-1])
            out = out[..., iy, :][..., :, ix]
        return out

    def residual(self, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
        """``D x1 - gain C x2 - bias``: zero when eq. (1) holds."""
        r = self.D(x1) - self.gain * self.C(x2)
        return r - self.bias if self.bias else r


def lowpass(u: np.ndarray, sigma: float) -> np.ndarray:
    """A Gaussian low-pass over the last two axes (linear, so the foveal gauge stays a linear problem).

    Parameters
    ----------
    u : ndarray, shape (..., h, w)
    sigma : float
        Pixels of ``u``; 0 returns ``u``. Edges reflected, kernel truncated at 3 sigma.

    Returns
    -------
    ndarray, shape (..., h, w)
    """
    if not sigma:
        return u
    from scipy.ndimage import gaussian_filter

    s = [0.0] * (u.ndim - 2) + [float(sigma), float(sigma)]
    return gaussian_filter(u, s, mode="reflect", truncate=3.0)


def lowpass_noise_factor(sigma: float, shape: tuple[int, int]) -> float:
    """The variance factor of white noise after :func:`lowpass`.

    Parameters
    ----------
    sigma : float
    shape : tuple of 2 int

    Returns
    -------
    float
        ``sum k^2`` of the kernel at the centre pixel of ``shape`` (1 for ``sigma = 0``).
    """
    if not sigma:
        return 1.0
    d = np.zeros(shape)
    d[shape[0] // 2, shape[1] // 2] = 1.0
    return float(np.sum(lowpass(d, sigma) ** 2))


def downsample(x1: np.ndarray, scale: float = 6.0) -> np.ndarray:
    """Area-mean downsampling ``D`` of eq. (1).

    Parameters
    ----------
    x1 : ndarray, shape (..., H, W)
    scale : float

    Returns
    -------
    ndarray, shape (..., floor(H / scale), floor(W / scale))
    """
    return FovealOperator(x1.shape[-2:], scale).D(np.asarray(x1))


def downsample_adjoint(u: np.ndarray, shape: tuple[int, int], scale: float = 6.0) -> np.ndarray:
    """The adjoint ``D^T`` of :func:`downsample`.

    Parameters
    ----------
    u : ndarray, shape (..., h, w)
    shape : tuple of 2 int
        ``(H, W)`` of the full grid.
    scale : float

    Returns
    -------
    ndarray, shape (..., H, W)
    """
    return FovealOperator(shape, scale).DT(np.asarray(u))


def centre_crop(x2: np.ndarray, scale: float = 6.0, offset: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """The centred crop ``C`` of eq. (1), matching :func:`downsample`.

    Parameters
    ----------
    x2 : ndarray, shape (..., H, W)
    scale : float
    offset : tuple of 2 float
        Registration offset in x2 pixels (fractional: box-overlap interpolation).

    Returns
    -------
    ndarray, shape (..., floor(H / scale), floor(W / scale))
    """
    return FovealOperator(x2.shape[-2:], scale, offset).C(np.asarray(x2))


def grad2d(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forward differences of an image.

    Parameters
    ----------
    z : ndarray, shape (H, W)

    Returns
    -------
    gy, gx : ndarray, shape (H, W)
        ``d/dy`` and ``d/dx``, zero in the last row / column.
    """
    gy = np.zeros_like(z)
    gx = np.zeros_like(z)
    gy[:-1] = z[1:] - z[:-1]
    gx[:, :-1] = z[:, 1:] - z[:, :-1]
    return gy, gx


def grad2d_adjoint(py: np.ndarray, px: np.ndarray) -> np.ndarray:
    """The adjoint of :func:`grad2d` (the negative divergence).

    Parameters
    ----------
    py, px : ndarray, shape (H, W)

    Returns
    -------
    ndarray, shape (H, W)
    """
    out = np.zeros_like(py)
    out[1:] += py[:-1]
    out[:-1] -= py[:-1]
    out[:, 1:] += px[:, :-1]
    out[:, :-1] -= px[:, :-1]
    return out


def tv_charbonnier(z: np.ndarray, eps: float) -> tuple[float, np.ndarray]:
    """Value and gradient of the anisotropic Charbonnier-smoothed total variation.

    Parameters
    ----------
    z : ndarray, shape (H, W)
    eps : float
        The smoothing.

    Returns
    -------
    value : float
        ``sum sqrt(gy^2 + eps^2) + sqrt(gx^2 + eps^2)`` (:func:`grad2d`).
    gradient : ndarray, shape (H, W)
    """
    gy, gx = grad2d(z)
    ry, rx = np.sqrt(gy ** 2 + eps ** 2), np.sqrt(gx ** 2 + eps ** 2)
    return float(ry.sum() + rx.sum()), grad2d_adjoint(gy / ry, gx / rx)

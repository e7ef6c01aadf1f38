"""Held-out thermal scenes from a seeded generator: random analytic scenes that no default was tuned on.

Each scene is a :class:`GeneratedScene`, a function of field angle like the built-in scenes of
:mod:`~metafovea.imaging.scene`: a stack of analytic layers (a background, regions painted with a temperature and an
emissivity, sums of plane waves, small Gaussian sources) evaluated on each channel's own grid, so the foveal
channel's 6x magnified view holds detail down to its own pixels. The kinds (:data:`GENERATOR_KINDS`):

* ``texture``: a 1/f texture, a sum of :data:`TEXTURE_WAVES` plane waves from half a cycle across the perifoveal
  field up to the foveal channel's Nyquist frequency. Its spectrum is therefore a set of lines, not a continuum: a
  method that estimates a 2-D spectrum from the data beats the radially averaged Wiener bound on these scenes by a
  margin that natural thermal textures would not give (BENCHMARKS.md, "PSF-aware reconstruction on scenes never
  seen");
* ``hot-objects``: ellipses and convex polygons (mostly warmer, some colder) on a cool, faintly textured background;
* ``edges``: random half-planes (steps), one through the fovea;
* ``sources``: small hot points, from a quarter of a foveal pixel to a few perifoveal pixels, some in the fovea;
* ``horizon``: a cold sky whose temperature rises towards a ridged horizon, over warm textured ground;
* ``person``: a warm figure (head, body, arms, legs: smooth edges, a warmer face) on a background;
* ``mixture``: a texture with objects, an edge, sources and sometimes a person.

Model of a layer, at field angles ``(ax, ay)`` (rad; ``ay`` grows downward, as every scene's):

* a region painted: ``T <- T + w (T_r + F(ax, ay) - T)`` and the same for the emissivity, with ``w`` the region's
  edge profile ``(1 - tanh(d / s)) / 2`` of its signed distance ``d`` (rad, negative inside); ``F`` a field
  (plane waves, a ramp, the sky's rise towards the horizon);
* plane waves: ``sum_k a_k cos(2 pi (fx_k ax + fy_k ay) + phi_k)``; drawn log-uniformly in frequency, equal
  amplitudes make the 2-D amplitude spectrum fall as ``1/f`` (equal power per octave), amplitudes
  ``a_k ~ f_k^(1 - beta)`` as ``f^-beta``; ``beta`` is drawn in [0.7, 1.3];
* sources: ``dT exp(-r^2 / (2 sigma^2))`` added.

Sampled on a grid (the renderer's tensor grids of field angles), each sample is the layer's mean over its cell,
not its value at the cell's centre: a plane wave is multiplied by ``sinc(fx dx) sinc(fy dy)`` and a Gaussian
source integrated exactly (error functions), both exact; an edge is widened to ``s = sqrt(s0^2 + (c / pi)^2)``,
``c`` the cell's size: the logistic profile with the variance of the edge averaged over the cell. So detail finer
than a channel's samples is averaged, as a pixel does, instead of aliased; scattered points get point values.

Temperatures: every draw keeps the scene inside [:data:`MIN_TEMPERATURE_K`, :data:`MAX_TEMPERATURE_K`] =
250-340 K; where textures and overlapping sources add up beyond it, the sum is clipped to it. Contrasts are
drawn log-uniformly (objects 0.5-40 K, steps 0.5-30 K: about a third below 2 K; textures 0.1-8 K rms, sources
1 K up to the hottest), so low-contrast cases come as often as hot ones.

Seeds and determinism: scene ``(kind, seed)`` draws everything from ``numpy.random.Generator(PCG64(SeedSequence(
[seed, crc32(kind)])))``: the same name gives the same scene (to rounding) on every machine and numpy version that
keeps the Generator's streams. Seeds :data:`TEST_SEEDS` (0-9999) are for tests and benchmarks
(:func:`held_out_scenes`); seeds from :data:`TUNING_SEED_START` (10000) up are for choosing a default
(:func:`tuning_scenes`): a default chosen on the second set is judged on the first.

Names: ``gen:KIND:SEED`` works wherever a scene name does (:func:`~metafovea.imaging.scene.make_scene`,
``metafovea simulate --scene gen:horizon:17``). Sizes are in units of the geometry's perifoveal half field and the
Nyquist frequencies of :data:`~metafovea.config.PAPER_CROP_PX` pixels across each channel's field.

File map: constants and the public functions at the top; the layers (:class:`Waves`, :class:`Paint`,
:class:`Sources` and the shapes); the kinds' recipes; the name registered with the scene registry at the end.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from metafovea.config import PAPER_CROP_PX
from metafovea.errors import InputError, check_int
from metafovea.imaging.scene import AMBIENT_K, Scene, SceneGeometry, register_scene_family

#: the kinds of scene the generator draws, in the order :func:`held_out_scenes` cycles through them
GENERATOR_KINDS = ("texture", "hot-objects", "edges", "sources", "horizon", "person", "mixture")
#: a generated scene's name is ``gen:KIND:SEED``
GENERATOR_PREFIX = "gen"
#: seeds of the held-out set, for tests and benchmarks: no default may be chosen on them
TEST_SEEDS = range(0, 10_000)
#: seeds from here up are for tuning (choosing a default, a constant): disjoint from :data:`TEST_SEEDS`
TUNING_SEED_START = 10_000
#: the coldest and the hottest temperature of a generated scene (K): a clear sky to a hot object indoors
MIN_TEMPERATURE_K = 250.0
MAX_TEMPERATURE_K = 340.0
#: plane waves in a texture: ~24 per octave over the 10.8 octaves from half a cycle across the field to the foveal
#: channel's Nyquist frequency, enough for a texture without visible single waves
TEXTURE_WAVES = 256
#: the highest temperature an object or a source is drawn to reach (K), below :data:`MAX_TEMPERATURE_K` so that a
#: texture on top stays mostly unclipped
HOTTEST_DRAWN_K = 338.0


def generated_scene(kind: str, seed: int, geometry: SceneGeometry | None = None) -> GeneratedScene:
    """The generator's scene ``kind`` drawn with ``seed``.

    Parameters
    ----------
    kind : {'texture', 'hot-objects', 'edges', 'sources', 'horizon', 'person', 'mixture'}
        :data:`GENERATOR_KINDS`.
    seed : int
        >= 0; :data:`TEST_SEEDS` (0-9999) for tests and benchmarks, from :data:`TUNING_SEED_START` for tuning.
    geometry : SceneGeometry, optional
        The field of view the scene is laid out in (default: the paper's camera).

    Returns
    -------
    GeneratedScene
        Named ``gen:KIND:SEED``; static; temperatures in [250, 340] K.

    Examples
    --------
    >>> sc = generated_scene("horizon", 17)
    >>> sc.name
    'gen:horizon:17'
    """
    if kind not in GENERATOR_KINDS:
        raise InputError("kind", kind, "one of " + ", ".join(GENERATOR_KINDS))
    seed = check_int("seed", seed, 0, 2**63 - 1)
    g = geometry or SceneGeometry()
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, zlib.crc32(kind.encode())])))
    layers, reflected_k, detail = _RECIPES[kind](rng, _Units(g))
    return GeneratedScene(kind=kind, seed=seed, layers=tuple(layers), reflected_k=reflected_k,
                          name=scene_name(kind, seed), description=f"generated {kind} scene: {detail}")


def scene_name(kind: str, seed: int) -> str:
    """The name ``gen:KIND:SEED`` of a generated scene (:func:`~metafovea.imaging.scene.make_scene` reads it)."""
    return f"{GENERATOR_PREFIX}:{kind}:{int(seed)}"


def held_out_scenes(n: int = 64, seed_offset: int = 0,
                    geometry: SceneGeometry | None = None) -> list[tuple[str, GeneratedScene]]:
    """The held-out set: ``n`` scenes of test seeds, the kinds in turn.

    Parameters
    ----------
    n : int
        How many scenes (1 to 10000).
    seed_offset : int
        Scene ``i`` is kind ``GENERATOR_KINDS[i % 7]`` with seed ``seed_offset + i``; every seed must be one of
        :data:`TEST_SEEDS`.
    geometry : SceneGeometry, optional

    Returns
    -------
    list of (str, GeneratedScene)
        ``(name, scene)``, the name ``gen:KIND:SEED``.
    """
    n = check_int("n", n, 1, len(TEST_SEEDS))
    seed_offset = check_int("seed_offset", seed_offset, 0, len(TEST_SEEDS) - n)
    return _scene_set(n, seed_offset, geometry)


def tuning_scenes(n: int = 64, seed_offset: int = 0,
                  geometry: SceneGeometry | None = None) -> list[tuple[str, GeneratedScene]]:
    """The tuning set: as :func:`held_out_scenes`, with seeds ``TUNING_SEED_START + seed_offset + i``.

    Parameters
    ----------
    n : int
    seed_offset : int
        >= 0.
    geometry : SceneGeometry, optional

    Returns
    -------
    list of (str, GeneratedScene)
    """
    n = check_int("n", n, 1, 1_000_000)
    seed_offset = check_int("seed_offset", seed_offset, 0, 2**62)
    return _scene_set(n, TUNING_SEED_START + seed_offset, geometry)


def _scene_set(n: int, first_seed: int, geometry: SceneGeometry | None) -> list[tuple[str, GeneratedScene]]:
    out = []
    for i in range(n):
        sc = generated_scene(GENERATOR_KINDS[i % len(GENERATOR_KINDS)], first_seed + i, geometry)
        out.append((sc.name, sc))
    return out


def parse_scene_name(name: str) -> tuple[str, int]:
    """``(kind, seed)`` of a name ``gen:KIND:SEED`` (or of its ``KIND:SEED`` part).

    Parameters
    ----------
    name : str

    Returns
    -------
    tuple of (str, int)

    Raises
    ------
    InputError
        Parameter ``scene``: a name that is not ``gen:KIND:SEED`` with a known kind and a seed >= 0.
    """
    spec = str(name).strip()
    if spec.lower().startswith(GENERATOR_PREFIX + ":"):
        spec = spec[len(GENERATOR_PREFIX) + 1:]
    kind, _, seed = spec.partition(":")
    kind = kind.strip().lower()
    allowed = f"{GENERATOR_PREFIX}:KIND:SEED, KIND one of {', '.join(GENERATOR_KINDS)}, SEED an integer >= 0"
    if kind not in GENERATOR_KINDS or not seed.strip().isdigit():
        raise InputError("scene", name, allowed)
    return kind, int(seed)


# ----------------------------------------------------------------------------------------------
# where a scene is evaluated: a tensor grid (cells known) or scattered points
# ----------------------------------------------------------------------------------------------
def _tensor_axes(ax: np.ndarray, ay: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``(x (W,), y (H,))`` when ``ax[i, j] = x[j]`` and ``ay[i, j] = y[i]``, both increasing; else None."""
    if ax.ndim != 2 or min(ax.shape) < 2:
        return None
    x, y = ax[0], ay[:, 0]
    if not (np.all(np.diff(x) > 0) and np.all(np.diff(y) > 0)):
        return None
    if np.array_equal(ax, np.broadcast_to(x, ax.shape)) and np.array_equal(ay, np.broadcast_to(y[:, None], ay.shape)):
        return x, y
    return None


class _Where:
    """The field angles a scene is evaluated at: a tensor grid, whose cells (each sample's spacing) are known, or
    scattered points. :meth:`part` gives the samples inside a box, as an index into the output and the angles."""

    def __init__(self, ax: np.ndarray, ay: np.ndarray):
        axes = _tensor_axes(ax, ay)
        self.grid = axes is not None
        if axes is not None:
            self.x, self.y = axes
            self.cx, self.cy = np.gradient(self.x), np.gradient(self.y)
            self.shape = ax.shape
        else:
            self.x, self.y = ax.ravel(), ay.ravel()
            self.cx = self.cy = None
            self.shape = self.x.shape

    def part(self, box: tuple[float, float, float, float] | None = None):
        """``(index, X, Y, CX, CY)`` of the samples inside ``box = (x0, y0, x1, y1)`` (rad; None: all), None when
        there are none. On a grid ``X``, ``CX`` are ``(1, w)`` and ``Y``, ``CY`` ``(h, 1)``; at points all are
        ``(m,)`` and the cells None."""
        if self.grid:
            if box is None:
                r, c = slice(None), slice(None)
            else:
                x0, y0, x1, y1 = box
                c = slice(int(np.searchsorted(self.x, x0)), int(np.searchsorted(self.x, x1, side="right")))
                r = slice(int(np.searchsorted(self.y, y0)), int(np.searchsorted(self.y, y1, side="right")))
                if c.start >= c.stop or r.start >= r.stop:
                    return None
            return (r, c), self.x[c][None, :], self.y[r][:, None], self.cx[c][None, :], self.cy[r][:, None]
        if box is None:
            return slice(None), self.x, self.y, None, None
        x0, y0, x1, y1 = box
        sel = (self.x >= x0) & (self.x <= x1) & (self.y >= y0) & (self.y <= y1)
        if not np.any(sel):
            return None
        return sel, self.x[sel], self.y[sel], None, None


def _edge_weight(d: np.ndarray, edge_rad: float, cx: np.ndarray | None, cy: np.ndarray | None) -> np.ndarray:
    """The weight of a region (1 inside, 0 outside) at signed distance ``d`` (rad, negative inside): the logistic
    profile of width ``edge_rad``, widened by the sample's cell (module docstring); a step at points."""
    s2 = edge_rad ** 2 + (0.0 if cx is None else np.abs(cx * cy) / math.pi ** 2)
    if cx is None and edge_rad == 0.0:
        return (d <= 0).astype(np.float64)
    return 0.5 * (1.0 - np.tanh(d / np.sqrt(s2)))


# ----------------------------------------------------------------------------------------------
# fields: temperatures added inside a painted region
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Waves:
    """A zero-mean sum of plane waves ``sum_k a_k cos(2 pi (fx_k ax + fy_k ay) + phi_k)`` (K), averaged over each
    grid cell (``sinc(fx dx) sinc(fy dy)``). Frequencies in cycles/rad, phases in rad, amplitudes in K."""

    fx: np.ndarray
    fy: np.ndarray
    phase: np.ndarray
    amplitude_k: np.ndarray

    def evaluate(self, X, Y, CX, CY) -> np.ndarray:
        a = self.amplitude_k
        if CX is not None:  # a tensor grid: cos(u + v) = cos u cos v - sin u sin v, two matrix products
            x, y, cx, cy = X[0], Y[:, 0], CX[0], CY[:, 0]
            u = 2 * np.pi * x[:, None] * self.fx[None, :] + self.phase[None, :]
            v = 2 * np.pi * y[:, None] * self.fy[None, :]
            fu = np.sinc(cx[:, None] * self.fx[None, :])
            fv = np.sinc(cy[:, None] * self.fy[None, :]) * a[None, :]
            return (np.cos(v) * fv) @ (np.cos(u) * fu).T - (np.sin(v) * fv) @ (np.sin(u) * fu).T
        out = np.empty(np.broadcast(X, Y).shape)
        xf, yf, of = np.broadcast_to(X, out.shape).ravel(), np.broadcast_to(Y, out.shape).ravel(), out.reshape(-1)
        step = max(1, 2**22 // max(a.size, 1))
        for i in range(0, xf.size, step):
            ph = 2 * np.pi * (xf[i:i + step, None] * self.fx + yf[i:i + step, None] * self.fy) + self.phase
            of[i:i + step] = np.cos(ph) @ a
        return out


@dataclass(frozen=True, eq=False)
class Ramp:
    """A linear ramp ``gx ax + gy ay`` (K); a cell's mean is its centre's value."""

    gx_k_per_rad: float
    gy_k_per_rad: float

    def evaluate(self, X, Y, CX, CY) -> np.ndarray:
        return self.gx_k_per_rad * X + self.gy_k_per_rad * Y


@dataclass(frozen=True, eq=False)
class Horizon:
    """The ground below a horizon ``y_h(ax) = y0 + slope ax + sum_k a_k cos(2 pi f_k ax + phi_k)`` (rad): as a shape,
    the signed distance ``(y_h - ay) cos(atan(slope))`` (negative on the ground, ``ay`` grows downward)."""

    y0_rad: float
    slope: float
    f: np.ndarray
    phase: np.ndarray
    amplitude_rad: np.ndarray

    def height(self, X) -> np.ndarray:
        ridge = np.cos(2 * np.pi * np.asarray(X)[..., None] * self.f + self.phase) @ self.amplitude_rad
        return self.y0_rad + self.slope * X + ridge

    def box(self, margin: float) -> None:
        return None

    def distance(self, X, Y) -> np.ndarray:
        return (self.height(X) - Y) * math.cos(math.atan(self.slope))


@dataclass(frozen=True)
class Bump:
    """A broad warm bump ``dt_k exp(-r^2 / (2 sigma^2))`` (K) about ``(cx, cy)`` (rad): a body's smooth interior
    profile (many cells wide: the centre's value is the cell's mean)."""

    cx: float
    cy: float
    sigma_rad: float
    dt_k: float

    def evaluate(self, X, Y, CX, CY) -> np.ndarray:
        return self.dt_k * np.exp(-0.5 * ((X - self.cx) ** 2 + (Y - self.cy) ** 2) / self.sigma_rad ** 2)


@dataclass(frozen=True, eq=False)
class Sky:
    """The sky's brightness temperature above a :class:`Horizon`: ``(T_h - T_z) exp(-e / scale)`` added to the
    zenith's ``T_z``, ``e = max(y_h - ay, 0)`` the elevation (rad)."""

    horizon: Horizon
    rise_k: float
    scale_rad: float

    def evaluate(self, X, Y, CX, CY) -> np.ndarray:
        e = np.maximum(self.horizon.height(X) - Y, 0.0)
        return self.rise_k * np.exp(-e / self.scale_rad)


# ----------------------------------------------------------------------------------------------
# shapes: signed distance (rad, negative inside) and a bounding box
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Ellipse:
    """Centre ``(cx, cy)``, semi-axes ``a``, ``b`` (rad), rotated by ``angle`` (rad). The distance is first order in
    the implicit function, exact on the boundary."""

    cx: float
    cy: float
    a: float
    b: float
    angle: float = 0.0

    def box(self, margin: float) -> tuple[float, float, float, float]:
        r = max(self.a, self.b) + margin
        return self.cx - r, self.cy - r, self.cx + r, self.cy + r

    def distance(self, X, Y) -> np.ndarray:
        c, s = math.cos(self.angle), math.sin(self.angle)
        u = c * (X - self.cx) + s * (Y - self.cy)
        v = -s * (X - self.cx) + c * (Y - self.cy)
        q = (u / self.a) ** 2 + (v / self.b) ** 2
        grad = 2 * np.sqrt(u ** 2 / self.a ** 4 + v ** 2 / self.b ** 4)
        return (q - 1) / np.maximum(grad, 1e-300)


@dataclass(frozen=True, eq=False)
class Polygon:
    """A convex polygon, vertices ``(n, 2)`` (rad) counter-clockwise in ``(ax, ay)``: the distance is the largest
    of the edges' (exact inside and across an edge, a lower bound beyond a corner)."""

    vertices: np.ndarray

    def box(self, margin: float) -> tuple[float, float, float, float]:
        v = self.vertices
        return (float(v[:, 0].min()) - margin, float(v[:, 1].min()) - margin, float(v[:, 0].max()) + margin,
                float(v[:, 1].max()) + margin)

    def distance(self, X, Y) -> np.ndarray:
        v = self.vertices
        d = None
        for p, q in zip(v, np.roll(v, -1, axis=0)):
            e = q - p
            n = np.array([e[1], -e[0]]) / math.hypot(*e)  # outward for counter-clockwise vertices
            di = (X - p[0]) * n[0] + (Y - p[1]) * n[1]
            d = di if d is None else np.maximum(d, di)
        return d


@dataclass(frozen=True)
class HalfPlane:
    """The half-plane ``nx ax + ny ay <= c`` (unit normal, rad)."""

    nx: float
    ny: float
    c: float

    def box(self, margin: float) -> None:
        return None

    def distance(self, X, Y) -> np.ndarray:
        return self.nx * X + self.ny * Y - self.c


@dataclass(frozen=True)
class Capsule:
    """Points within ``r`` of the segment ``p0``-``p1`` (rad)."""

    x0: float
    y0: float
    x1: float
    y1: float
    r: float

    def box(self, margin: float) -> tuple[float, float, float, float]:
        m = self.r + margin
        return min(self.x0, self.x1) - m, min(self.y0, self.y1) - m, max(self.x0, self.x1) + m, max(self.y0,
                                                                                                    self.y1) + m

    def distance(self, X, Y) -> np.ndarray:
        dx, dy = self.x1 - self.x0, self.y1 - self.y0
        s = np.clip(((X - self.x0) * dx + (Y - self.y0) * dy) / max(dx * dx + dy * dy, 1e-300), 0.0, 1.0)
        return np.hypot(X - self.x0 - s * dx, Y - self.y0 - s * dy) - self.r


# ----------------------------------------------------------------------------------------------
# layers
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Paint:
    """A region (None: everywhere) painted with ``temperature_k`` plus its fields and ``emissivity``, through an
    edge of width ``edge_rad`` (0: sharp). ``additive``: ``temperature_k`` (plus fields) is a contrast added to what
    lies below (a step or an object keeps the background's texture) instead of a temperature replacing it."""

    shape: Any
    temperature_k: float
    emissivity: float
    edge_rad: float = 0.0
    fields: tuple = ()
    additive: bool = False

    def apply(self, where: _Where, temp: np.ndarray, eps: np.ndarray) -> None:
        cell = 0.0 if where.cx is None else float(max(np.max(where.cx), np.max(where.cy)))
        box = None if self.shape is None else self.shape.box(6 * max(self.edge_rad, cell))
        part = where.part(box)
        if part is None:
            return
        idx, X, Y, CX, CY = part
        value = self.temperature_k + sum((f.evaluate(X, Y, CX, CY) for f in self.fields), 0.0)
        if self.shape is None:
            temp[idx] = value
            eps[idx] = self.emissivity
            return
        w = _edge_weight(self.shape.distance(X, Y), self.edge_rad, CX, CY)
        temp[idx] += w * (value if self.additive else value - temp[idx])
        eps[idx] += w * (self.emissivity - eps[idx])


@dataclass(frozen=True, eq=False)
class Sources:
    """Gaussian hot points added to the temperature: ``dt_k exp(-r^2 / (2 sigma^2))`` each, centres ``(cx, cy)``
    and ``sigma`` in rad; on a grid each sample is the Gaussian's exact mean over its cell."""

    cx: np.ndarray
    cy: np.ndarray
    sigma_rad: np.ndarray
    dt_k: np.ndarray

    @staticmethod
    def _profile(x, c: float, sigma: float, cell) -> np.ndarray:
        if cell is None:
            return np.exp(-0.5 * ((x - c) / sigma) ** 2)
        from scipy.special import erf

        h = 0.5 * cell
        k = 1.0 / (math.sqrt(2) * sigma)
        mean = (erf((x - c + h) * k) - erf((x - c - h) * k)) * (sigma * math.sqrt(math.pi / 2) / np.maximum(cell,
                                                                                                             1e-300))
        return np.where(cell > 1e-3 * sigma, mean, np.exp(-0.5 * ((x - c) / sigma) ** 2))

    def apply(self, where: _Where, temp: np.ndarray, eps: np.ndarray) -> None:
        for cx, cy, s, dt in zip(self.cx, self.cy, self.sigma_rad, self.dt_k):
            m = 5 * s + (0.0 if where.cx is None else float(max(np.max(where.cx), np.max(where.cy))))
            part = where.part((cx - m, cy - m, cx + m, cy + m))
            if part is None:
                continue
            idx, X, Y, CX, CY = part
            temp[idx] += dt * self._profile(X, cx, s, CX) * self._profile(Y, cy, s, CY)


# ----------------------------------------------------------------------------------------------
# the scene
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class GeneratedScene(Scene):
    """A generated scene: its ``layers`` applied in order (the first paints everywhere), temperatures clipped to
    [:data:`MIN_TEMPERATURE_K`, :data:`MAX_TEMPERATURE_K`]. Made by :func:`generated_scene`."""

    kind: str = "texture"
    seed: int = 0
    layers: tuple = ()
    reflected_k: float = AMBIENT_K
    name: str = "gen"
    description: str = "a generated scene"

    def _sample(self, ax, ay, t):
        where = _Where(ax, ay)
        temp = np.full(where.shape, AMBIENT_K)
        eps = np.ones(where.shape)
        for layer in self.layers:
            layer.apply(where, temp, eps)
        np.clip(temp, MIN_TEMPERATURE_K, MAX_TEMPERATURE_K, out=temp)
        np.clip(eps, 0.0, 1.0, out=eps)
        return temp.reshape(ax.shape), eps.reshape(ax.shape)

    def summary(self) -> dict[str, Any]:
        return {**super().summary(), "kind": self.kind, "seed": self.seed}


# ----------------------------------------------------------------------------------------------
# recipes
# ----------------------------------------------------------------------------------------------
class _Units:
    """A geometry's scales: the perifoveal half field ``h``, the foveal ``fh``, each channel's pixel (rad) and the
    frequencies a texture spans (cycles/rad)."""

    def __init__(self, g: SceneGeometry):
        self.h, self.fh = g.half, g.fovea_half
        self.px_p = g.fov_rad / PAPER_CROP_PX
        self.px_f = self.px_p / g.expansion
        self.f_lo = 1.0 / (4 * self.h)  # half a cycle across the perifoveal field
        self.f_hi = 0.5 / self.px_f  # the foveal channel's Nyquist frequency


def _logu(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(math.log(lo), math.log(hi))))


def _waves(rng: np.random.Generator, u: _Units, rms_k: float, n: int = TEXTURE_WAVES,
           f_hi: float | None = None) -> Waves:
    """A 1/f-like texture of ``rms_k`` (module docstring): spectral slope drawn in [0.7, 1.3]."""
    beta = rng.uniform(0.7, 1.3)
    f = u.f_lo * (((f_hi or u.f_hi) / u.f_lo) ** rng.uniform(0.0, 1.0, n))
    theta = rng.uniform(0.0, 2 * np.pi, n)
    a = f ** (1.0 - beta)
    a *= rms_k / math.sqrt(0.5 * float(np.sum(a * a)))
    return Waves(fx=f * np.cos(theta), fy=f * np.sin(theta), phase=rng.uniform(0.0, 2 * np.pi, n), amplitude_k=a)


def _edge(rng: np.random.Generator, u: _Units) -> float:
    """An edge's width: sharp half the time, else from a third of a foveal pixel to three perifoveal pixels."""
    return 0.0 if rng.uniform() < 0.5 else _logu(rng, 0.3 * u.px_f, 3 * u.px_p)


def _contrast(rng: np.random.Generator, lo: float = 0.5, hi: float = 40.0) -> float:
    return _logu(rng, lo, hi)


def _point(rng: np.random.Generator, u: _Units, foveal: bool) -> tuple[float, float]:
    r = 0.8 * u.fh if foveal else 1.05 * u.h
    return float(rng.uniform(-r, r)), float(rng.uniform(-r, r))


def _background(rng: np.random.Generator, u: _Units, t_k: tuple[float, float],
                rms_k: tuple[float, float]) -> tuple[Paint, float]:
    bg = float(rng.uniform(*t_k))
    return Paint(None, bg, float(rng.uniform(0.9, 0.98)), fields=(_waves(rng, u, _logu(rng, *rms_k)),)), bg


def _objects(rng: np.random.Generator, u: _Units, n: int, bg_k: float) -> list[Paint]:
    """``n`` ellipses and convex polygons, the first in the fovea; most warmer than ``bg_k``, a sixth colder: each a
    contrast added to the background (its texture kept)."""
    out = []
    for i in range(n):
        cx, cy = _point(rng, u, foveal=i == 0)
        size = _logu(rng, 0.3 * u.fh, 0.45 * u.h)
        a, b = size, size * rng.uniform(0.3, 1.0)
        ang = float(rng.uniform(0, np.pi))
        if rng.uniform() < 0.5:
            shape: Any = Ellipse(cx, cy, a, b, ang)
        else:
            phi = np.sort(rng.uniform(0, 2 * np.pi, int(rng.integers(3, 8))))
            px, py = a * np.cos(phi), b * np.sin(phi)  # on an ellipse: convex, counter-clockwise
            c, s = math.cos(ang), math.sin(ang)
            shape = Polygon(np.stack([cx + c * px - s * py, cy + s * px + c * py], axis=1))
        dt = _contrast(rng)
        dt = -min(dt, bg_k - MIN_TEMPERATURE_K - 5) if rng.uniform() < 1 / 6 else min(dt, HOTTEST_DRAWN_K - bg_k)
        out.append(Paint(shape, dt, float(rng.uniform(0.85, 0.98)), _edge(rng, u), additive=True))
    return out


def _edges(rng: np.random.Generator, u: _Units, n: int, bg_k: float) -> list[Paint]:
    """``n`` half-planes (steps), the first through the fovea, each ``+-`` a contrast from the background."""
    out = []
    for i in range(n):
        px, py = _point(rng, u, foveal=i == 0)
        ang = rng.uniform(0, 2 * np.pi)
        nx, ny = math.cos(ang), math.sin(ang)
        dt = _contrast(rng, 0.5, 30.0) * (1 if rng.uniform() < 0.6 else -1)
        dt = float(np.clip(dt, MIN_TEMPERATURE_K + 5 - bg_k, HOTTEST_DRAWN_K - bg_k))
        out.append(Paint(HalfPlane(nx, ny, nx * px + ny * py), dt, float(rng.uniform(0.85, 0.98)), _edge(rng, u),
                         additive=True))
    return out


def _sources(rng: np.random.Generator, u: _Units, n: int, bg_k: float) -> Sources:
    """``n`` Gaussian hot points, a third (at least three) in the fovea: there a quarter of a foveal pixel to three
    foveal pixels wide (sigma), elsewhere a third of a perifoveal pixel to three."""
    n_fov = max(3, n // 3)
    cx, cy, sig, dt = [], [], [], []
    for i in range(n):
        foveal = i < n_fov
        x, y = _point(rng, u, foveal)
        cx.append(x)
        cy.append(y)
        sig.append(_logu(rng, 0.25 * u.px_f, 3 * u.px_f) if foveal else _logu(rng, 0.3 * u.px_p, 3 * u.px_p))
        dt.append(_logu(rng, 1.0, max(HOTTEST_DRAWN_K - bg_k, 1.5)))
    return Sources(np.array(cx), np.array(cy), np.array(sig), np.array(dt))


def _person(rng: np.random.Generator, u: _Units) -> tuple[list[Any], str]:
    """A standing figure: clothed body, arms and legs (smooth edges), a warmer head and hands; the torso and the face
    warmest at their centres."""
    tall = _logu(rng, 0.3 * u.h, 1.8 * u.h)
    # the head, the chest or the belly in the fovea, or anywhere
    at = rng.choice(4)
    anchor = (0.0, 0.4 * tall, 0.25 * tall, rng.uniform(-0.5, 0.5) * tall)[at]
    x0 = float(rng.uniform(-0.6, 0.6) * u.fh if at < 3 else rng.uniform(-0.6, 0.6) * u.h)
    top = -anchor + float(rng.uniform(-0.5, 0.5) * u.fh)  # head centre
    cloth = float(rng.uniform(296.0, 305.0))
    skin = float(rng.uniform(305.0, 310.0))
    soft = _logu(rng, 0.005, 0.03) * tall
    ec, es = float(rng.uniform(0.9, 0.96)), 0.98
    sh, hip = top + 0.16 * tall, top + 0.52 * tall
    w = 0.11 * tall * rng.uniform(0.85, 1.15)
    layers: list[Any] = [
        Paint(Capsule(x0 - 0.5 * w, hip, x0 - 0.45 * w, top + 0.95 * tall, 0.05 * tall), cloth - 1.0, ec, soft),
        Paint(Capsule(x0 + 0.5 * w, hip, x0 + 0.45 * w, top + 0.95 * tall, 0.05 * tall), cloth - 1.0, ec, soft),
        Paint(Capsule(x0, sh + 0.5 * w, x0, hip - 0.3 * w, w), cloth, ec, soft,
              fields=(Bump(x0, 0.5 * (sh + hip), 0.5 * w, float(rng.uniform(0.3, 1.5))),)),
    ]
    for side in (-1, 1):
        ang = float(rng.uniform(-0.3, 1.2))  # from the body's side (0) outwards
        ln = 0.36 * tall
        s0 = (x0 + side * 1.05 * w, sh + 0.2 * w)
        s1 = (s0[0] + side * ln * math.sin(ang), s0[1] + ln * math.cos(ang))
        layers.append(Paint(Capsule(*s0, *s1, 0.035 * tall), cloth, ec, soft))
        layers.append(Paint(Ellipse(s1[0], s1[1], 0.03 * tall, 0.04 * tall), skin - 1.5, es, soft))
    layers += [Paint(Capsule(x0, top + 0.05 * tall, x0, sh, 0.03 * tall), skin, es, soft),
               Paint(Ellipse(x0, top, 0.065 * tall, 0.085 * tall), skin, es, soft,
                     fields=(Bump(x0, top + 0.01 * tall, 0.035 * tall, float(rng.uniform(0.5, 2.0))),))]
    return layers, f"{tall / u.h:.2f} half fields tall, clothes {cloth:.1f} K, skin {skin:.1f} K"


def _texture_recipe(rng, u):
    bg, t = _background(rng, u, (275.0, 310.0), (0.3, 8.0))
    rms = math.sqrt(0.5 * float(np.sum(bg.fields[0].amplitude_k ** 2)))
    return [bg], AMBIENT_K, f"1/f texture around {t:.1f} K, rms {rms:.2f} K"


def _hot_objects_recipe(rng, u):
    bg, t = _background(rng, u, (270.0, 300.0), (0.1, 1.0))
    objs = _objects(rng, u, int(rng.integers(3, 10)), t)
    return [bg, *objs], AMBIENT_K, f"{len(objs)} objects on {t:.1f} K, " + _span(objs)


def _edges_recipe(rng, u):
    bg, t = _background(rng, u, (275.0, 310.0), (0.1, 1.0))
    steps = _edges(rng, u, int(rng.integers(1, 5)), t)
    return [bg, *steps], AMBIENT_K, f"{len(steps)} steps on {t:.1f} K, " + _span(steps)


def _sources_recipe(rng, u):
    bg, t = _background(rng, u, (270.0, 300.0), (0.1, 2.0))
    src = _sources(rng, u, int(rng.integers(6, 41)), t)
    return [bg, src], AMBIENT_K, (f"{src.dt_k.size} sources on {t:.1f} K, +{src.dt_k.min():.1f} to "
                                  f"+{src.dt_k.max():.1f} K")


def _horizon_recipe(rng, u):
    y0 = float(rng.uniform(-0.9, 0.9) * u.fh if rng.uniform() < 0.3 else rng.uniform(-0.6, 0.6) * u.h)
    n = 12  # a ridge: 12 waves over the lowest 5.3 octaves, amplitude ~ 1/f, rms 0.2-5 % of the half field
    f = u.f_lo * 40.0 ** rng.uniform(0, 1, n)
    amp = 1.0 / f
    amp *= _logu(rng, 0.002, 0.05) * u.h / math.sqrt(0.5 * float(amp @ amp))
    hz = Horizon(y0, math.tan(math.radians(rng.uniform(-8, 8))), f, rng.uniform(0, 2 * np.pi, n), amp)
    zenith = float(rng.uniform(250.0, 265.0))
    near = float(rng.uniform(zenith + 5.0, 285.0))
    ground = float(rng.uniform(283.0, 318.0))
    layers = [Paint(None, zenith, 1.0, fields=(Sky(hz, near - zenith, _logu(rng, 0.1, 0.6) * u.h),)),
              Paint(hz, ground, float(rng.uniform(0.9, 0.97)), _edge(rng, u),
                    fields=(_waves(rng, u, _logu(rng, 0.5, 5.0)), Ramp(0.0, float(rng.uniform(-5, 5)) / u.h)))]
    return layers, zenith + 5.0, f"sky {zenith:.1f}-{near:.1f} K over ground at {ground:.1f} K"


def _person_recipe(rng, u):
    bg, t = _background(rng, u, (285.0, 300.0), (0.1, 1.5))
    fig, detail = _person(rng, u)
    return [bg, *fig], AMBIENT_K, f"a person on {t:.1f} K, {detail}"


def _mixture_recipe(rng, u):
    bg, t = _background(rng, u, (275.0, 305.0), (0.3, 4.0))
    layers: list[Any] = [bg, *_edges(rng, u, int(rng.integers(0, 2)), t),
                         *_objects(rng, u, int(rng.integers(1, 4)), t)]
    if rng.uniform() < 0.5:
        layers += _person(rng, u)[0]
    layers.append(_sources(rng, u, int(rng.integers(3, 16)), t))
    return layers, AMBIENT_K, f"texture, objects, sources on {t:.1f} K ({len(layers)} layers)"


def _span(paints: list[Paint]) -> str:
    ts = [p.temperature_k for p in paints]
    return f"contrasts {min(ts):+.1f} to {max(ts):+.1f} K"


_RECIPES: dict[str, Callable[[np.random.Generator, _Units], tuple[list[Any], float, str]]] = {
    "texture": _texture_recipe, "hot-objects": _hot_objects_recipe, "edges": _edges_recipe,
    "sources": _sources_recipe, "horizon": _horizon_recipe, "person": _person_recipe, "mixture": _mixture_recipe,
}


def _from_name(spec: str, geometry: SceneGeometry) -> GeneratedScene:
    kind, seed = parse_scene_name(f"{GENERATOR_PREFIX}:{spec}")
    return generated_scene(kind, seed, geometry)


register_scene_family(GENERATOR_PREFIX, _from_name, f"{GENERATOR_PREFIX}:KIND:SEED",
                      f"a generated held-out scene (KIND: {', '.join(GENERATOR_KINDS)}; SEED: 0-9999 for tests, "
                      f">= {TUNING_SEED_START} for tuning), 250-340 K")

"""Geometry of 2-D periodic layer stacks for the RCWA solver.

Coordinates: z is the stacking axis, pointing from the **substrate** (below, ``z < 0``) to the
**superstrate** (above). Layers are listed bottom to top; layer 0 starts at ``z = 0``. The unit cell
is ``[-px/2, px/2) x [-py/2, py/2)``; a rectangle centred at (0, 0) is mirror symmetric about the x=0
and y=0 planes. Lengths in micrometres; materials are refractive indices (``n``, ``eps = n^2``) or
:class:`metafovea.materials.Material` objects (dispersive).

Each layer is uniform or holds one axis-aligned rectangular inclusion (``shapes`` is a tuple so that
more shapes, ellipses or rotated rectangles can be added later; today exactly zero or one
:class:`Rectangle` is supported, which is what Li's crossed-grating factorisation handles exactly).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from metafovea.errors import InputError, as_float, check_positive
from metafovea.materials import IndexLike, Material, check_index


def _check_n(name: str, n: IndexLike) -> IndexLike:
    if isinstance(n, Material):
        return n
    check_index(name, n)
    return complex(n) if isinstance(n, complex) or getattr(n, "imag", 0) != 0 else float(n)


@dataclass(frozen=True)
class Rectangle:
    """Axis-aligned rectangle of index ``n``, side widths ``wx`` x ``wy`` centred at (cx, cy)."""

    wx: float
    wy: float
    n: IndexLike
    cx: float = 0.0
    cy: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "wx", check_positive("wx", self.wx, "um"))
        object.__setattr__(self, "wy", check_positive("wy", self.wy, "um"))
        object.__setattr__(self, "cx", as_float("cx", self.cx))
        object.__setattr__(self, "cy", as_float("cy", self.cy))
        object.__setattr__(self, "n", _check_n("n (rectangle)", self.n))


@dataclass(frozen=True)
class Layer:
    """A layer of thickness ``thickness`` (um) and background index ``n`` holding ``shapes``."""

    thickness: float
    n: IndexLike
    shapes: tuple = field(default_factory=tuple)

    def __post_init__(self):
        object.__setattr__(self, "thickness", check_positive("thickness", self.thickness, "um"))
        object.__setattr__(self, "n", _check_n("n (layer)", self.n))
        shapes = tuple(self.shapes)
        if len(shapes) > 1:
            raise InputError("shapes", len(shapes), "0 or 1 rectangle per layer (split into layers otherwise)")
        for s in shapes:
            if not isinstance(s, Rectangle):
                raise InputError("shapes", type(s).__name__, "Rectangle instances")
        object.__setattr__(self, "shapes", shapes)


@dataclass(frozen=True)
class Stack:
    """Periodic stack: ``layers`` (bottom to top) between a substrate (below) and a superstrate.

    The half-spaces must be lossless (real index) so that diffraction efficiencies are defined.
    """

    period_x: float
    period_y: float
    layers: tuple
    n_substrate: IndexLike = 1.0
    n_superstrate: IndexLike = 1.0

    def __post_init__(self):
        px = check_positive("period_x", self.period_x, "um")
        py = check_positive("period_y", self.period_y, "um")
        object.__setattr__(self, "period_x", px)
        object.__setattr__(self, "period_y", py)
        layers = tuple(self.layers)
        for lay in layers:
            if not isinstance(lay, Layer):
                raise InputError("layers", type(lay).__name__, "Layer instances")
            for s in lay.shapes:
                if not (s.wx < px):
                    raise InputError("wx", s.wx, f"0 < wx < period_x = {px:g} um")
                if not (s.wy < py):
                    raise InputError("wy", s.wy, f"0 < wy < period_y = {py:g} um")
        object.__setattr__(self, "layers", layers)
        for nm in ("n_substrate", "n_superstrate"):
            v = _check_n(nm, getattr(self, nm))
            if not isinstance(v, Material) and complex(v).imag != 0:
                raise InputError(nm, v, "a real (lossless) index for a half-space")
            object.__setattr__(self, nm, v)

    @property
    def mirror_symmetric(self) -> bool:
        """True if every inclusion is centred on (0, 0) (mirror planes x = 0 and y = 0)."""
        return all(s.cx == 0 and s.cy == 0 for lay in self.layers for s in lay.shapes)

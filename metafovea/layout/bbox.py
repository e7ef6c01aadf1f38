"""Bounding boxes in database units (nm): the type, and the union that the frame (:mod:`metafovea.layout.frame`,
what a reader should find) and the readers (:mod:`metafovea.layout.read`, what they found) both build boxes with;
and the polygons' area moments both compare (:func:`moments`).

It sits below both, so that neither imports the other for it.
"""

from __future__ import annotations

import numpy as np

#: bounding box ``(x0, y0, x1, y1)`` in database units
BBox = tuple[int, int, int, int]


def union_bbox(a: BBox | None, b: BBox | None) -> BBox | None:
    """The smallest box holding boxes ``a`` and ``b`` (either may be None: no box)."""
    if a is None:
        return b
    if b is None:
        return a
    return (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))


def moments(xy: np.ndarray) -> np.ndarray:
    """``(A, Sx, Sy)`` of polygons: ``xy`` ``(..., n, 2)`` vertices (closed or not), ``A`` the area and ``(Sx, Sy)``
    ``A`` times the centroid, whatever the vertices' orientation (nm^2 and nm^3 for nm vertices). The shoelace sums
    are taken about each polygon's first vertex (no cancellation of 1e16-size products far from the origin)."""
    p = np.asarray(xy, dtype=np.float64)
    o = p[..., :1, :]
    q = p - o
    x, y = q[..., 0], q[..., 1]
    x1, y1 = np.roll(x, -1, axis=-1), np.roll(y, -1, axis=-1)
    c = x * y1 - x1 * y
    a = c.sum(-1) / 2
    sx, sy = ((x + x1) * c).sum(-1) / 6, ((y + y1) * c).sum(-1) / 6
    sgn = np.where(a < 0, -1.0, 1.0)
    a, sx, sy = sgn * a, sgn * sx, sgn * sy
    return np.stack([a, sx + a * o[..., 0, 0], sy + a * o[..., 0, 1]], -1)


__all__ = ["BBox", "moments", "union_bbox"]

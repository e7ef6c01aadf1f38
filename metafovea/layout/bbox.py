"""Bounding boxes in database units (nm): the type, and the union that the frame (:mod:`metafovea.layout.frame`,
what a reader should find) and the readers (:mod:`metafovea.layout.read`, what they found) both build boxes with.

It sits below both, so that neither imports the other for it.
"""

from __future__ import annotations

#: bounding box ``(x0, y0, x1, y1)`` in database units
BBox = tuple[int, int, int, int]


def union_bbox(a: BBox | None, b: BBox | None) -> BBox | None:
    """The smallest box holding boxes ``a`` and ``b`` (either may be None: no box)."""
    if a is None:
        return b
    if b is None:
        return a
    return (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))


__all__ = ["BBox", "union_bbox"]

"""3-D mesh (trimesh) of a patch of posts on the substrate, for visualisation and field-solver import.

Coordinates in um, relative to the lens centre (not the file origin of the GDSII/OASIS export):
x, y as in :mod:`metafovea.lens`, z = 0 at the substrate surface, posts from z = 0 to the post height,
the substrate slab from ``-substrate_thickness_um`` to 0 covering the patch's sites. Posts are the
same snapped rectangles as in the layout files. Each post is a closed box (8 vertices, 12 triangles).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.errors import InputError, check_choice, check_range
from metafovea.io import atomic_write_bytes, prepare_output
from metafovea.layout.gds import band_sites
from metafovea.layout.tiling import LayoutSpec

MESH_FORMATS = ("stl", "glb")
MAX_POSTS = 250_000

_CORNERS = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]])
_FACES = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                   [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])


def boxes_mesh(lo: np.ndarray, hi: np.ndarray):
    """One trimesh of axis-aligned boxes ``lo[i]..hi[i]`` ((n, 3) arrays), outward normals."""
    import trimesh

    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    v = lo[:, None, :] + _CORNERS[None, :, :] * (hi - lo)[:, None, :]
    f = _FACES[None, :, :] + 8 * np.arange(len(lo))[:, None, None]
    return trimesh.Trimesh(v.reshape(-1, 3), f.reshape(-1, 3), process=False)


def patch_mesh(spec: LayoutSpec, substrate_thickness_um: float | None = None):
    """Posts of ``spec``'s patch on a substrate slab, as one :class:`trimesh.Trimesh` (um)."""
    if spec.patch_um is None:
        raise InputError("patch_mm", None, "a patch X,Y,W (mm) for a mesh export (a whole lens is too large)")
    ks, xs, ys = [], [], []
    for band in spec.bands():
        k, x, y = band_sites(spec, band)
        ks.append(k), xs.append(x), ys.append(y)
    k = np.concatenate(ks)
    if k.size > MAX_POSTS:
        raise InputError("patch_mm", spec.patch_um, f"a patch with at most {MAX_POSTS:,} posts for a mesh "
                         f"(this one has {k.size:,})")
    c = spec.centre_nm
    x = (np.concatenate(xs) - c) / 1000.0
    y = (np.concatenate(ys) - c) / 1000.0
    sz = spec.post_sizes_nm[k] / 1000.0
    h = spec.design.post_height_um
    lo = np.stack([x - sz[:, 0] / 2, y - sz[:, 1] / 2, np.zeros_like(x)], 1)
    hi = np.stack([x + sz[:, 0] / 2, y + sz[:, 1] / 2, np.full_like(x, h)], 1)
    t = h if substrate_thickness_um is None else check_range("substrate_thickness_um", substrate_thickness_um, 0.0, 1e5,
                                                             unit="um", lo_inclusive=True)
    if t > 0:
        p = spec.design.period_um
        slo = np.array([[x.min() - p / 2, y.min() - p / 2, -t]])
        shi = np.array([[x.max() + p / 2, y.max() + p / 2, 0.0]])
        lo = np.concatenate([slo, lo])
        hi = np.concatenate([shi, hi])
    return boxes_mesh(lo, hi)


def export_mesh(spec: LayoutSpec, path: str | os.PathLike, fmt: str | None = None, *, force: bool = False,
                substrate_thickness_um: float | None = None) -> dict[str, Any]:
    """Write the patch mesh as binary STL or GLB (atomically)."""
    path = Path(path)
    fmt = check_choice("fmt", fmt or path.suffix.lstrip("."), MESH_FORMATS)
    if substrate_thickness_um is not None:
        substrate_thickness_um = check_range("substrate_thickness_um", substrate_thickness_um, 0.0, 1e5, unit="um",
                                             lo_inclusive=True)
    prepare_output(path, force, name="path")
    m = patch_mesh(spec, substrate_thickness_um)
    data = m.export(file_type=fmt)
    try:
        atomic_write_bytes(path, data)
    except OSError as e:
        raise InputError("path", str(path), "a writable location with free space", detail=e.strerror) from None
    t = spec.design.post_height_um if substrate_thickness_um is None else substrate_thickness_um
    return {"path": str(path), "format": fmt, "posts": int(len(m.faces) // 12 - (1 if t > 0 else 0)),
            "triangles": int(len(m.faces)), "bytes": len(data), "bounds_um": m.bounds.tolist()}

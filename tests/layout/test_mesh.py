"""Patch meshes: one closed box per post on a substrate slab, read back with the same triangles."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.config import LensDesign
from metafovea.errors import InputError
from metafovea.layout import make_spec
from metafovea.layout.mesh import export_mesh, patch_mesh

trimesh = pytest.importorskip("trimesh")


@pytest.mark.parametrize("fmt", ["stl", "glb"])
def test_mesh_patch(tmp_path, design, small_frame, fmt):
    sp = make_spec(design, patch_mm=(0.1, 0.1, 0.04), **small_frame)
    m = patch_mesh(sp)
    n = len(m.faces) // 12 - 1
    assert n == 100  # 10 x 10 sites of 4 um
    sz = sp.post_sizes_nm / 1000.0
    res = export_mesh(sp, tmp_path / f"m.{fmt}")
    assert res["posts"] == n
    back = trimesh.load(tmp_path / f"m.{fmt}", force="mesh")
    assert len(back.faces) == len(m.faces)
    assert back.bounds[0][2] == pytest.approx(-design.post_height_um)
    assert back.bounds[1][2] == pytest.approx(design.post_height_um)
    assert m.volume > 0 and m.volume == pytest.approx(
        sum(abs(trimesh.Trimesh(m.vertices[8 * i:8 * i + 8], m.faces[12 * i:12 * i + 12] - 8 * i).volume)
            for i in range(len(m.faces) // 12)))
    assert (sz[:, 0] * sz[:, 1]).min() > 0
    with pytest.raises(InputError, match="^patch_mm is missing"):
        patch_mesh(make_spec(design, **small_frame))


def test_mesh_substrate_zero_and_positive():
    """--substrate-um 0 leaves the slab out, a positive thickness adds one box of that depth (finite vertices)."""
    s = make_spec(LensDesign("t", 900.0, 500.0), patch_mm=(0, 0, 0.03))
    m0 = patch_mesh(s, 0.0)
    m7 = patch_mesh(s, 7.0)
    assert len(m7.faces) == len(m0.faces) + 12
    assert np.all(np.isfinite(m7.vertices)) and m7.bounds[0, 2] == pytest.approx(-7.0)

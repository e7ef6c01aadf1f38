"""Fabrication layout: the lens as posts on a lattice, streamed to GDSII/OASIS, read back and checked.

See :mod:`metafovea.layout.tiling` for the file conventions (origin, layers, database unit, grid).
"""

from metafovea.layout.export import (ExportError, ExportResult, TestArraySpec, export_layout,
                                     export_test_array)
from metafovea.layout.tiling import Expected, Layers, LayoutSpec, band_levels, expected_content, make_spec

__all__ = ["ExportError", "ExportResult", "Expected", "Layers", "LayoutSpec", "TestArraySpec", "band_levels",
           "expected_content", "export_layout", "export_test_array", "make_spec"]

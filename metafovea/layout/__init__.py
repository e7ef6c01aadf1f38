"""Fabrication layout: the lens as posts on a lattice, streamed to GDSII/OASIS, read back and checked.

Files
-----
* :mod:`~metafovea.layout.tiling`: :class:`LayoutSpec` (everything that fixes a file's content; the file
  conventions: origin, layers, 1 nm database unit, grid), :func:`make_spec` / :func:`load_spec` (from design and
  post-set files), the lens as mirror-row tasks of lattice sites, the frame (ring, marks, label) and the
  :class:`Expected` content (:func:`expected_content`).
* :mod:`~metafovea.layout.export`: streamed, resumable, atomic writing (:func:`export_layout`, its
  :class:`ExportOptions`), the calibration array (:class:`TestArraySpec`, :func:`export_test_array`) and
  :func:`export_file`, the one entry that picks the writer and the output name as ``metafovea export`` does.
* :mod:`~metafovea.layout.tilefiles`: an export on a Dask cluster: each worker writes its bands as tile files
  (with size and CRC-32 records) on a shared file system, the client stitches them in band order.
* :mod:`~metafovea.layout.gds`: GDSII records (header through gdstk, posts as numpy-encoded SREFs or
  BOUNDARYs, hierarchical files for ``max_refs``).
* :mod:`~metafovea.layout.oasis`: the OASIS writer (compact per-row repetitions, CBLOCKs).
* :mod:`~metafovea.layout.mesh`: a 3-D mesh (STL/GLB) of a patch of posts on the substrate.
* :mod:`~metafovea.layout.bbox`: bounding boxes in database units and their union (the frame's and the readers').
* :mod:`~metafovea.layout.read`: independent readers (KLayout, gdstk, the streaming GDSII scanner), each
  reducing a file to an ``Observed`` record.
* :mod:`~metafovea.layout.verify`: :func:`verify_layout`, a file read back and compared with the design.
"""

from metafovea.layout.export import (
                                     ExportError,
                                     ExportOptions,
                                     ExportResult,
                                     TestArraySpec,
                                     export_file,
                                     export_layout,
                                     export_test_array,
)
from metafovea.layout.tiling import Expected, Layers, LayoutSpec, band_levels, expected_content, load_spec, make_spec
from metafovea.layout.verify import VerifyReport, verify_layout

__all__ = ["ExportError", "ExportOptions", "ExportResult", "Expected", "Layers", "LayoutSpec", "TestArraySpec",
           "VerifyReport", "band_levels", "expected_content", "export_file", "export_layout", "export_test_array",
           "load_spec", "make_spec", "verify_layout"]

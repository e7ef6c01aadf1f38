"""What a layout reader reports, and what the readers share: format sniffing, the lattice a reader checks
positions against and capturing what C libraries print on file descriptor 2 (the bounding-box union is
:mod:`metafovea.layout.bbox`'s, which the frame shares)."""

from __future__ import annotations

import os
import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from metafovea.errors import InputError
from metafovea.layout.bbox import BBox
from metafovea.layout.bbox import moments as moments  # re-exported: the readers' home of the frame's geometry
from metafovea.layout.bbox import union_bbox as union_bbox  # re-exported: the readers' old home of it
from metafovea.layout.tiling import LayoutSpec


@dataclass
class Observed:
    """What a reader found (coordinates in database units).

    ``cell_rects``: post cell name -> its shapes ``(layer, datatype, w, h, centre x, centre y)``;
    ``ref_counts``: post cell name -> references to it in the top cell (through the hierarchy);
    ``flat_counts``: ``(w, h)`` -> posts-layer rectangles in the top cell (through the hierarchy);
    ``off_lattice``: posts whose centre is not on a lattice site; ``max_refs``: most elements (reference
    instances + shapes + texts) in one structure; ``max_references``: most reference records in one structure;
    ``frame_layers``: polygons and bounding box per layer other than the posts' (the frame);
    ``anomalies``: anything else that is wrong, as sentences.
    """

    reader: str
    format: str
    dbu_um: float = 0.0
    top_cells: list[str] = field(default_factory=list)
    cell_rects: dict[str, list[tuple[int, int, int, int, int, int]]] = field(default_factory=dict)
    ref_counts: Counter = field(default_factory=Counter)  # child cell name -> references in the top cell
    flat_counts: Counter = field(default_factory=Counter)  # (w, h) of posts-layer rectangles in the top cell
    posts_bbox: BBox | None = None
    bbox: BBox | None = None
    layers: set = field(default_factory=set)
    off_lattice: int = 0
    anomalies: list[str] = field(default_factory=list)
    structures: int = 0
    max_refs: int = 0  # most elements (reference instances + shapes + texts) in one structure
    #: (layer, datatype) -> [polygons, bbox] of every layer but the posts', through the hierarchy (None: not read)
    frame_layers: dict | None = None
    max_references: int = 0  # most reference records (SREF/AREF or instances) in one structure
    #: (layer, datatype) -> [area, area x centroid x, area x centroid y] (nm^2, nm^3) of the same polygons
    #: (:func:`moments`): a shape moved or resized inside its layer's bounding box changes them (None: not read)
    frame_moments: dict | None = None


def add_moments(table: dict, layer: tuple[int, int], m: Any, copies: int = 1, offsets: Any = None) -> None:
    """Add ``copies`` placements of moments ``m`` (``(A, Sx, Sy)``) to ``table[layer]``; ``offsets``: the sum of the
    placements' (x, y) offsets (nm; None: all at the origin)."""
    e = table.setdefault(layer, [0.0, 0.0, 0.0])
    a, sx, sy = (float(v) for v in m)
    ox, oy = (0.0, 0.0) if offsets is None else (float(offsets[0]), float(offsets[1]))
    e[0] += copies * a
    e[1] += copies * sx + a * ox
    e[2] += copies * sy + a * oy


def read_label(path: Path, span: int = 4 << 20) -> str | None:
    """The metafovea text label of a layout file (``metafovea ...`` in a TEXT record), found in its first and last
    ``span`` bytes (the label is in the header, or in the footer of a hierarchical GDSII), without parsing the
    file: None when there is none."""
    import re

    size = path.stat().st_size
    with open(path, "rb") as fh:
        chunks = [fh.read(span)]
        if size > span:
            fh.seek(max(span, size - span))
            chunks.append(fh.read())
    for c in chunks:
        m = re.search(rb"metafovea [\x20-\x7e]+", c)
        if m:
            return m.group(0).decode("ascii")
    return None


def sniff_format(path: Path) -> str:
    """``'oas'`` or ``'gds'`` from the file's first bytes; anything else is an :class:`InputError`."""
    with open(path, "rb") as fh:
        head = fh.read(16)
    if head.startswith(b"%SEMI-OASIS\r\n"):
        return "oas"
    if len(head) >= 4 and head[2:4] == b"\x00\x02":
        return "gds"
    raise InputError("FILE", str(path), "a GDSII or OASIS file")


def lattice_of(spec: LayoutSpec) -> tuple[int, int, int] | None:
    """``(C, o P, P)`` (nm): post centres lie on ``C + o P + i P``; None when they are not exactly on a lattice
    of integer nanometres (see :attr:`LayoutSpec.period_nm`), and then the readers do not check positions."""
    P = spec.period_nm
    if P is None:
        return None
    o = 0 if spec.design.lattice == "integer" else P // 2
    return spec.centre_nm, o, P


class captured_stderr:
    """Redirect file descriptor 2 (where C libraries print) to a temporary file while active;
    :meth:`text` is the last 500 characters printed."""

    def __enter__(self):
        import tempfile
        self._tmp = tempfile.TemporaryFile()
        try:
            sys.stderr.flush()
        except (OSError, ValueError, AttributeError):
            pass
        try:
            self._saved = os.dup(2)
            os.dup2(self._tmp.fileno(), 2)
        except OSError:
            self._saved = None
        return self

    def __exit__(self, *exc):
        if self._saved is not None:
            os.dup2(self._saved, 2)
            os.close(self._saved)
            self._saved = None
        self._tmp.close()
        return False

    def text(self) -> str:
        try:
            self._tmp.seek(0)
            return self._tmp.read().decode("utf-8", "replace")[-500:]
        except OSError:
            return ""

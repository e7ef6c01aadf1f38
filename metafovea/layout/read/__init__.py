"""Readers of exported layouts, each independent of the writers: a file reduced to an :class:`Observed`.

* :mod:`~metafovea.layout.read.base`: the :class:`Observed` record, :func:`sniff_format`, :func:`lattice_of`
  and what the readers share (capturing what C libraries print; the bounding-box union is
  :mod:`metafovea.layout.bbox`'s).
* :mod:`~metafovea.layout.read.klayout`: :func:`read_klayout`, KLayout's Python module (what fabs use);
  GDSII and OASIS, loaded whole.
* :mod:`~metafovea.layout.read.gdstk`: :func:`read_gdstk`, gdstk's readers (fast for large OASIS files).
* :mod:`~metafovea.layout.read.stream`: :func:`read_stream` / :class:`GdsScanner`, a streaming GDSII record
  scanner written here for GDSII files too large to load whole (memory: one read buffer).

:func:`metafovea.layout.verify.verify_layout` picks one and compares what it observed with the design.
"""

from metafovea.layout.read.base import Observed, lattice_of, sniff_format
from metafovea.layout.read.gdstk import read_gdstk
from metafovea.layout.read.klayout import read_klayout
from metafovea.layout.read.stream import GdsScanner, read_stream

__all__ = ["GdsScanner", "Observed", "lattice_of", "read_gdstk", "read_klayout", "read_stream", "sniff_format"]

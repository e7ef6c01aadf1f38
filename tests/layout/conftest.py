"""Fixtures shared by the layout tests: a small lens (~70k posts, a 1.2 mm aperture) with a small frame, its
spec, its exports (GDSII with references, flat GDSII, OASIS) and its design file; a smaller one (~4.4k posts) for
the tamper tests, which rewrite and re-read a file many times."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea import lens
from metafovea.config import LensDesign
from metafovea.layout import ExportOptions, export_layout, make_spec

#: ring and marks small enough for a 1.2 mm lens
SMALL = dict(ring_width_um=100.0, mark_offset_um=50.0, mark_size_um=40.0, mark_width_um=4.0)


@pytest.fixture(scope="session")
def small_frame() -> dict:
    """``make_spec`` keywords for a small ring and small marks."""
    return dict(SMALL)


@pytest.fixture(scope="session")
def design():
    return LensDesign("small", 1500.0, 1200.0, polarization="x")  # ~70k posts


@pytest.fixture(scope="session")
def spec(design):
    return make_spec(design, band_rows=16, **SMALL)


@pytest.fixture(scope="session")
def exported(tmp_path_factory, spec):
    """``(format, flat) -> (path, ExportResult)`` for GDSII, flat GDSII and OASIS exports of ``spec``."""
    d = tmp_path_factory.mktemp("lay")
    out = {}
    for fmt, flat in (("gds", False), ("gds", True), ("oas", False)):
        p = d / f"lens{'_flat' if flat else ''}.{fmt}"
        out[(fmt, flat)] = (p, export_layout(spec, p, fmt, ExportOptions(flat=flat)))
    return out


@pytest.fixture(scope="session")
def tamper_spec():
    """The spec of a smaller lens (~4.4k posts, a 0.3 mm aperture, 5 bands of 16 rows, the small frame) for the
    tests that tamper with a file: a tampered file is rewritten with one plain reference per post, which the gdstk
    reader and the tests' own gdstk walks take post by post in Python (a gdstk verify: 3.3 s at 70k posts, 0.25 s
    here, on the loaded 2-core machine)."""
    return make_spec(LensDesign("little", 375.0, 300.0, polarization="x"), band_rows=16, **SMALL)


@pytest.fixture(scope="session")
def tamper_exported(tmp_path_factory, tamper_spec):
    """``format -> (path, ExportResult)`` for the GDSII (references) and OASIS exports of ``tamper_spec``."""
    d = tmp_path_factory.mktemp("tamper")
    return {fmt: (d / f"little.{fmt}", export_layout(tamper_spec, d / f"little.{fmt}", fmt)) for fmt in ("gds", "oas")}


@pytest.fixture(scope="session")
def tile_counts():
    """``tile_counts(design, levels)``: posts per type counted over ``lens.iter_tiles`` (the reference)."""
    def count(design, levels):
        c = np.zeros(levels, np.int64)
        for t in lens.iter_tiles(design, 256, levels=levels):
            v = t.levels[t.levels >= 0]
            c += np.bincount(v, minlength=levels)
        return c
    return count


def _retype_one_reference(src, dst, old: str, new: str, start: float = 0.5):
    """Copy the GDSII file ``src`` to ``dst`` with one SREF to cell ``old`` (the first after ``start`` of the file)
    pointing to cell ``new`` instead (same-length names): a tampered file whose counts per type change."""
    data = bytearray(src.read_bytes())
    i = data.index(b"\x00\x08\x12\x06" + old.encode(), int(len(data) * start))
    data[i + 4:i + 4 + len(new)] = new.encode()
    dst.write_bytes(bytes(data))
    return dst


@pytest.fixture(scope="session")
def retype_reference():
    """Factory fixture: ``retype_reference(src, dst, old, new, start=0.5)`` (see :func:`_retype_one_reference`)."""
    return _retype_one_reference

"""Layout spec and tiling: band levels equal the lens' own tiles, mirror-row tasks cover each row once,
validation of the spec (patch, levels, post set, 32-bit coordinates), label placement."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea import lens
from metafovea.config import LensDesign
from metafovea.errors import InputError
from metafovea.layout import band_levels, expected_content, load_spec, make_spec
from metafovea.layout.tiling import MAX_COORD_NM, post_count, task_rows
from metafovea.library import PostSet


@pytest.mark.parametrize("lattice", ["integer", "half"])
def test_band_levels_equal_evaluate_tile(lattice):
    d = LensDesign("t", 900.0, 700.0, lattice=lattice)
    lo, hi = lens.site_index_range(d)
    for (iy0, rows, ix0, cols) in [(lo, 20, lo, hi - lo + 1), (-5, 11, -40, 30), (3, 7, 10, 50), (-9, 5, -60, 12)]:
        a = band_levels(d, iy0, rows, ix0, cols, 8)
        b = lens.evaluate_tile(d, iy0, ix0, rows, cols, levels=8).levels
        assert np.array_equal(a, b)


@pytest.mark.parametrize("lattice", ["integer", "half"])
def test_tasks_cover_each_row_once(lattice):
    d = LensDesign("t", 900.0, 700.0, lattice=lattice)
    for patch in (None, (0.1, -0.2, 0.15), (-0.25, 0.3, 0.1)):
        sp = make_spec(d, band_rows=7, patch_mm=patch)
        seen = []
        two_o = 0 if lattice == "integer" else 1
        for t in sp.tasks():
            j = np.arange(t[1], t[1] + t[2])
            for sign, mask, ys in task_rows(sp, t):
                iy = j if sign == 1 else -j - two_o
                seen += iy[mask].tolist()
                assert np.array_equal(ys, sp.site_y_nm(iy))
        want = [b[0] + i for b in sp.bands() for i in range(b[1])]
        lo, hi = lens.row_half_counts(d, np.array(want))
        iy_lo, iy_hi, ix_lo, ix_hi = sp.window()
        want = [w for w, a, b in zip(want, lo, hi) if max(a, ix_lo) <= min(b, ix_hi)]
        assert sorted(seen) == sorted(want) and len(seen) == len(set(seen))


def test_make_spec_bad_input(design):
    with pytest.raises(InputError, match="^patch_mm = "):
        make_spec(design, patch_mm=(5.0, 5.0, 0.5))
    with pytest.raises(InputError, match="^levels = "):
        make_spec(design, PostSet.ideal(8, period_um=4.0), levels=4)


def test_load_spec_checks_the_post_set_file(tmp_path, designs_dir):
    """The post set given as a file must be a PostSet, for the design's polarisation, with ``levels`` posts;
    its errors name post_set (PostSet.load names its file 'path')."""
    toml = tmp_path / "lens.toml"
    toml.write_text('name = "t"\nf_mm = 0.9\ndiameter_mm = 0.4\npolarization = "x"\n')
    ps = tmp_path / "ps.npz"
    PostSet.ideal(6, period_um=4.0, polarization="x").save(ps)
    sp = load_spec(toml, ps)
    assert sp.levels == 6 and sp.design.name == "t"
    assert np.array_equal(sp.post_set.widths_um, PostSet.load(ps).widths_um)
    with pytest.raises(InputError, match="^levels = 4 .*the number of posts in"):
        load_spec(toml, ps, 4)
    PostSet.ideal(6, period_um=4.0, polarization="y").save(tmp_path / "y.npz")
    with pytest.raises(InputError, match="^post_set = .*polarisation 'x'"):
        load_spec(toml, tmp_path / "y.npz")
    with pytest.raises(InputError, match="^post_set = .*an existing .npz file"):
        load_spec(toml, tmp_path / "none.npz")
    with pytest.raises(InputError, match="^post_set = .*not an .npz"):
        load_spec(toml, toml)
    with pytest.raises(InputError, match="^design = .*a lens design file"):
        load_spec(designs_dir / "system.toml")


def test_label_position_inside_frame_for_any_patch():
    """A patch wider than the lens put its label at negative coordinates: the label stays inside the chip
    frame [0, 2 C] for any patch."""
    d = LensDesign("t", 900.0, 500.0)
    for patch in [(0, 0, 50.0), (-0.2, 0.2, 0.3), (0.2, 0.0, 0.1), (0, 0, 0.01)]:
        s = make_spec(d, patch_mm=patch, ring_width_um=30.0)
        x, y = s.label_position_nm()
        assert 0 <= x <= 2 * s.centre_nm and 0 <= y <= 2 * s.centre_nm


def test_frame_beyond_32bit_coordinates_refused():
    """--ring-width-um 1e9 silently wrapped the 32-bit coordinates: a frame beyond them is refused."""
    d = LensDesign("t", 900.0, 500.0)
    # just inside: fine; just outside (the ring alone is legal, the frame is not): refused
    ok = make_spec(d, ring_width_um=1.0e6, wafer_diameter_mm=2100.0)
    assert 2 * ok.centre_nm <= MAX_COORD_NM
    with pytest.raises(InputError, match="32-bit"):
        make_spec(d, ring_width_um=1.08e6, wafer_diameter_mm=2100.0)


@pytest.mark.parametrize("lattice", ["integer", "half"])
def test_post_count_is_the_expected_total(lattice):
    """The posts counted from the rows' site ranges alone are those the levels give, for the lens and a patch."""
    d = LensDesign("c", 900.0, 400.0, lattice=lattice)
    for patch in (None, (0.1, -0.05, 0.12), (0.19, 0.0, 0.05)):
        sp = make_spec(d, "ideal", patch_mm=patch, ring_width_um=30.0)
        assert post_count(sp) == expected_content(sp).total

"""Designing a list of lenses (metafovea.design_report): which lens gets which posts, the platform lenses share,
and the design bundle of each lens."""

from __future__ import annotations

import json

import pytest

from metafovea.config import LensDesign, PlatformDesign
from metafovea.design_report import design_lenses, format_summary, shared_platform, summary_dict, write_design_bundles
from metafovea.errors import InputError
from metafovea.lens import summarize
from metafovea.library import PostSet

FOV = LensDesign("fov", 2_000.0, 400.0, polarization="x")
PERI = LensDesign("peri", 1_000.0, 400.0, polarization="y")


def test_design_lenses_equals_summarize_per_lens():
    (s,) = design_lenses([FOV], samples=5000)
    ref = summarize(FOV, samples=5000, emit_warnings=False)
    assert summary_dict(s) == summary_dict(ref)
    assert "substrate" in format_summary(s)   # physics warnings are in the summary, not emitted


def test_post_set_goes_to_the_lens_of_its_polarisation():
    ps = PostSet.ideal(8, polarization="y")
    fov, peri = design_lenses([FOV, PERI], post_set=ps, samples=5000)
    assert fov.posts == () and fov.post_set is None
    assert len(peri.posts) == 8 and peri.post_set["source"] == "ideal"
    with pytest.raises(InputError) as e:   # one lens of the other polarisation: an error, not silence
        design_lenses([FOV], post_set=ps, samples=5000)
    assert e.value.parameter == "post_set" and "(x)" in e.value.allowed
    with pytest.raises(InputError) as e:
        design_lenses([PERI], post_set=ps, from_library=True, samples=5000)
    assert e.value.parameter == "post_set"


def test_shared_platform_of_the_lenses():
    plat = shared_platform([FOV, PERI])
    assert plat == PlatformDesign(min_feature_um=0.5)
    assert shared_platform([FOV.with_(period_um=2.0)]).min_feature_um == 0.25   # an eighth of a fine period
    with pytest.raises(InputError) as e:
        shared_platform([FOV, PERI.with_(levels=4)])
    assert e.value.parameter == "from_library"


def test_write_design_bundles_one_folder_per_lens(tmp_path):
    lenses = [FOV, PERI]
    summaries = design_lenses(lenses, samples=5000)
    written = write_design_bundles(lenses, summaries, tmp_path)
    assert {p.parent.name for p in written} == {"fov", "peri"} and len(written) == 12
    assert json.loads((tmp_path / "peri" / "summary.json").read_text())["polarization"] == "y"
    for p in written:
        if p.suffix == ".png":
            assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    (one,) = design_lenses([FOV], samples=5000)
    assert {p.parent for p in write_design_bundles([FOV], [one], tmp_path / "one")} == {tmp_path / "one"}


def test_a_corrected_lens_shows_its_added_phase_and_the_plain_lens_keeps_its_keys(tmp_path):
    """phase_poly_rad shows in the summary (table, JSON, design.toml, radial profile from the full phase); a plain
    lens' summary JSON has exactly the keys it had before the field existed."""
    from metafovea.config import load_lens
    from metafovea.lens import design_phase

    plain = summary_dict(summarize(FOV, samples=4096, emit_warnings=False))
    assert not {"phase_poly_rad", "narrowest_posts_per_2pi", "narrowest_zone_radius_um"} & set(plain)
    lens = FOV.with_(phase_poly_rad=(-3.0, 1.5))
    s = summarize(lens, samples=4096, emit_warnings=False)
    d = summary_dict(s)
    assert d["phase_poly_rad"] == [-3.0, 1.5] and d["narrowest_posts_per_2pi"] > 0
    assert "phase beyond the hyperbola" in format_summary(s) and "-3, 1.5" in format_summary(s)
    write_design_bundles([lens], [s], tmp_path)
    assert load_lens(tmp_path / "design.toml") == lens
    assert json.loads((tmp_path / "summary.json").read_text())["phase_poly_rad"] == [-3.0, 1.5]
    import numpy as np

    prof = np.genfromtxt(tmp_path / "radial_profile.csv", delimiter=",", names=True)
    assert np.allclose(prof["phase_rad"], design_phase(lens, prof["r_um"], 0.0), rtol=0, atol=1e-6)

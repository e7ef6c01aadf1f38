"""``metafovea study gallery --fast``: the paper's scene types with and without the 10 um filter (~12 s on 2 cores),
and the procedural scenes added for it (rooftop, tall buildings, oven): their temperatures."""

from __future__ import annotations

import json

import numpy as np
import pytest

from metafovea.cli import main
from metafovea.imaging.scene import list_scenes, make_scene


@pytest.mark.parametrize("name, lo, hi, fovea_lo, fovea_hi", [
    ("rooftop", 245.0, 340.0, 300.0, 325.0),  # cold sky, sunlit roof, warm chimney; an HVAC grille in the fovea
    ("tall-buildings", 235.0, 305.0, 285.0, 305.0),  # cold sky; façades and windows fill the fovea
    ("oven", 290.0, 425.0, 325.0, 350.0),  # the hot door window and racks in the fovea, element at 420 K
])
def test_new_scene_temperatures(name, lo, hi, fovea_lo, fovea_hi):
    assert name in list_scenes()
    s = make_scene(name)
    h = s.half_rad
    a = np.linspace(-h, h, 241)
    ax, ay = np.meshgrid(a, a)
    temp, eps = s.sample(ax, ay)
    assert lo <= temp.min() and temp.max() <= hi and temp.max() - temp.min() > 40.0
    fov = (np.abs(ax) <= h / 6) & (np.abs(ay) <= h / 6)
    assert fovea_lo <= temp[fov].min() and temp[fov].max() <= fovea_hi
    assert np.ptp(temp[fov]) > 5.0  # structure for the foveal channel
    assert 0.0 < eps.min() and eps.max() <= 1.0
    assert s.static


@pytest.mark.slow  # a study, at its --fast size
def test_gallery_fast(tmp_path, capsys):
    out = tmp_path / "gal"
    assert main(["study", "gallery", "--fast", "--out", str(out), "-q", "--workers", "1"]) == 0
    printed = capsys.readouterr().out
    assert "study gallery" in printed and "paper:" in printed
    for suffix in ("json", "png", "html"):
        f = out / f"gallery.{suffix}"
        assert f.is_file() and f.stat().st_size > 200, f
    html = (out / "gallery.html").read_text()
    assert "What was modelled" in html and "data:image/png;base64" in html
    rep = json.loads((out / "gallery.json").read_text())
    assert {"expected", "observed", "holds", "note"} <= set(rep["trend"])
    cases = rep["results"]["cases"]
    types = {c["type"] for c in cases}
    assert len(types) >= 3 and {"static", "video", "snapshot"} <= {c["kind"] for c in cases}
    assert sorted(c["filter"] for c in cases) == [False] * len(types) + [True] * len(types)
    on = {c["type"]: c for c in cases if c["filter"]}
    off = {c["type"]: c for c in cases if not c["filter"]}
    # with the filter, the multi-frame reconstructions of both channels are good
    for t, c in on.items():
        if c["kind"] != "snapshot":
            assert c["ssim_x1"] > 0.5 and c["ssim_x2"] > 0.5, t
    # without it the foveal channel loses contrast to haze on the static scenes (structure in their fovea)
    for t, c in on.items():
        if c["kind"] == "static":
            assert off[t]["contrast"] < c["contrast"], t
            assert off[t]["ssim_x1"] < c["ssim_x1"], t
    tr = rep["trend"]
    if tr["holds"]:
        assert tr["foveal_contrast_ratio"] < 1.0 and tr["foveal_ssim_change"] < 0.0
    else:
        assert "hand" in tr["note"]

"""metafovea.studies.snapshot_heldout: the snapshot mode on held-out generated scenes (the core of
benchmarks/bench_snapshot.py) at CI size: generator test seeds, a 96 x 96 crop, Airy PSFs, three frames."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from metafovea.config import SensorDesign, SystemDesign
from metafovea.imaging.generator import held_out_scenes, parse_scene_name
from metafovea.studies.heldout import HeldOutCase
from metafovea.studies.snapshot_heldout import (
    METHODS,
    overlap,
    registration_error,
    run_case,
    true_geometry,
)

SYSTEM = replace(SystemDesign.paper(), sensor=replace(SensorDesign(), crop=(96, 96)))


@pytest.fixture(scope="module")
def cases():
    """Four test-seed scenes (texture, hot objects, edges, sources), the bands in turn."""
    out = []
    for i, (name, _) in enumerate(held_out_scenes(4)):
        case = HeldOutCase(name, filter_enabled=bool(i % 2), frames=3, calibration_frames=8, psf="airy",
                           seed=parse_scene_name(name)[1])
        out.append(run_case(SYSTEM, case))
    return out


def test_the_snapshot_beats_the_unseparated_frame_on_every_scene(cases):
    """Both channels, against the noise-free sensor images, above the frame taken as both images and above that frame
    moved to each truth's mean (an oracle level); the frame's foveal error is the perifoveal image (overlap up to 1),
    the snapshot's less so."""
    for res in cases:
        rows = {r["method"]: r for r in res["rows"]}
        assert list(rows) == list(METHODS) and "truth_x1" in res["truth"]
        snap, frame, level = rows["snapshot"], rows["frame"], rows["frame_level"]
        for ch in ("x1", "x2"):
            assert snap[f"psnr_{ch}"] > frame[f"psnr_{ch}"] + 3.0, (res["scene"], ch, rows)
            assert snap[f"psnr_{ch}"] > level[f"psnr_{ch}"], (res["scene"], ch, rows)
        # the frame's foveal error is its perifoveal image (less where the frame's noise outweighs that image)
        assert frame["overlap_x1"] > 0.4 and abs(snap["overlap_x1"]) < min(0.5, frame["overlap_x1"]), (res, rows)
        assert all(np.isfinite(r[k]) for r in rows.values() for k in ("overlap_x1", "overlap_x2", "seconds"))
        assert abs(res["alpha"] - 0.5) < 0.1  # the frame nearest the polariser's 45 degrees


def test_registration_error_is_reported_and_bounded(cases):
    """The simulator realises no misregistration: the error is against the nominal geometry and stays small."""
    for res in cases:
        assert res["geometry"] == {"scale": 6.0, "offset": (0.0, 0.0), "rotation_deg": 0.0, "source": "nominal"}
        reg = res["registration"]
        assert reg["offset_error_px"] <= 1.0 and abs(reg["scale_error"]) <= 0.03 and reg["rotation_error_deg"] == 0.0


def test_registration_error_against_a_realised_geometry():
    """A file that records its realised geometry (meta truth) is judged against it, not against the nominal one."""
    from metafovea.measurement import Measurement

    m = Measurement(frames=np.zeros((2, 12, 12), np.float32), times_s=np.arange(2.0), alpha=np.array([0.4, 0.6]),
                    meta={"scale": 6.0, "truth": {"geometry": {"scale": 6.06, "offset": [1.0, -2.0],
                                                               "rotation_deg": 0.5}}})
    geo = true_geometry(m)
    assert geo["source"] == "truth" and geo["offset"] == (1.0, -2.0)
    err = registration_error({"scale": 6.0, "offset": (0.0, 0.0), "rotation_deg": 0.0}, geo)
    assert err["offset_error_px"] == pytest.approx(np.hypot(1.0, 2.0)) and err["rotation_error_deg"] == -0.5
    assert err["scale_error"] == pytest.approx(6.0 / 6.06 - 1.0)


def test_overlap_counts_the_other_channel_not_the_own_channels_loss():
    """The unseparated frame's foveal error is the perifoveal image: overlap 1; an error that is the foveal image's
    own contrast loss counts 0 even when the two images share structure; noise counts ~0."""
    rng = np.random.default_rng(0)
    t2 = rng.normal(size=(40, 40))
    t1 = 0.5 * t2 + rng.normal(size=(40, 40))  # images that share structure
    a = 0.5
    assert overlap((a * t1 + (1 - a) * t2) - t1, t2, t1) == pytest.approx(1.0)
    assert abs(overlap(-0.3 * t1, t2, t1)) < 1e-9 and overlap(-0.3 * t1, t2) < -0.3  # plain correlation is fooled
    assert abs(overlap(rng.normal(size=(40, 40)), t2, t1)) < 0.1

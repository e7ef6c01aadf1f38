"""`metafovea validate` end to end on a small crop (the full-size run is the README's main job)."""

import dataclasses
import json

import pytest

from metafovea.cli import main
from metafovea.config import SystemDesign
from metafovea.validate import ValidateOptions, validate_system


@pytest.fixture
def small_system():
    s = SystemDesign.paper()
    return dataclasses.replace(s, sensor=dataclasses.replace(s.sensor, crop=(192, 192), pixels=(192, 192)))


def test_validate_small_runs_every_stage(tmp_path, monkeypatch, small_system):
    monkeypatch.setenv("METAFOVEA_CACHE", str(tmp_path / "cache"))
    opts = ValidateOptions(scene="bars", frames=16, calibration_frames=8, filters=(True,), alternating_windows=2,
                           dip_steps=2, dip_channels=4, snapshot_iterations=20, library_grid_step_um=0.5,
                           library_harmonics=5, psf="airy", cache_dir=str(tmp_path / "psf"))
    out = tmp_path / "report"
    out.mkdir()
    rep = validate_system(small_system, opts, out)
    assert set(rep["stages"]) == {"library", "design", "psf", "simulate_reconstruct"}
    methods = {r["method"].split(" (")[0] for r in rep["table"]}
    assert {"lsq", "lsq + TV denoise", "alternating", "dip", "snapshot"} <= methods
    rows = {r["method"].split(" (")[0]: r for r in rep["table"]}
    # known alpha is the noise-limited reference; FPN correction from the shutter frames must help
    assert rows["lsq"]["psnr_x2"] > 30
    assert rows["lsq"]["psnr_x1"] > rows["lsq, no FPN correction"]["psnr_x1"]
    assert rows["alternating"]["alpha_mae"] < 0.05
    # the PSF stage agrees with the design-stage efficiency estimate and the Airy reference where it applies
    for lens in rep["stages"]["psf"]["lenses"].values():
        assert lens["peak_ratio_fabricated_vs_continuous"] == pytest.approx(lens["expected_peak_ratio_from_design"],
                                                                            rel=0.05)
    html = (out / "validate.html").read_text()
    assert "speed against error" in html and "data:image/png;base64" in html
    assert json.loads((out / "validate.json").read_text())["table"]


def test_validate_cli_bad_input(tmp_path, capsys):
    assert main(["validate", "--frames", "1", "--out", str(tmp_path / "x")]) == 2
    assert "--frames" in capsys.readouterr().err
    d = tmp_path / "full"
    d.mkdir()
    (d / "f").write_text("x")
    assert main(["validate", "--out", str(d)]) == 2
    assert "--force" in capsys.readouterr().err


def test_single_frame_rows_are_scored_against_that_frames_truth_of_a_video():
    """Snapshot and 'no separation' show one frame: on a video scene (truth (T, H, W)) they are scored
    against the truth of that frame, not against the mean over the 8 frames after it."""
    from types import SimpleNamespace

    import numpy as np

    from metafovea.reconstruct.synthetic import polariser_alpha, scene
    from metafovea.validate import _reconstruct_stage, _score, _Stages

    T, n = 8, 48
    x1, x2 = scene(n)
    ramp = 1.0 + np.arange(T)[:, None, None]  # strongly changing scene
    t1, t2 = x1[None] * ramp, x2[None] * ramp[::-1]
    a = polariser_alpha(T)
    frames = (a[:, None, None] * t1 + (1 - a[:, None, None]) * t2).astype(np.float32)
    meas = SimpleNamespace(frames=frames, alpha=a, meta={"scale": 6.0}, fpn=None, truth_x1=t1, truth_x2=t2,
                           extras={"calibration": np.zeros((4, n, n), np.float32)})
    opts = ValidateOptions(frames=T, alternating_windows=1, snapshot_iterations=5)
    res = _reconstruct_stage(meas, opts, _Stages(False), "video", run_dip=False)
    row = next(r for r in res["rows"] if r["method"].startswith("no separation"))
    k = int(np.argmin(np.abs(a - 0.5)))
    y = frames[k].astype(np.float64)
    want = _score(y, y, t1[k], t2[k])
    assert row["psnr_x1"] == pytest.approx(want["psnr_x1"]) and row["psnr_x2"] == pytest.approx(want["psnr_x2"])


@pytest.mark.parametrize("argv, name", [(["--frames", "2"], "--frames"), (["--dip-steps", "0"], "--dip-steps"),
                                        (["--scene", "no-such-scene"], "scene")])
def test_validate_bad_arguments_fail_before_any_work(tmp_path, capsys, argv, name):
    out = tmp_path / "v"
    assert main(["validate", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert name in err and err.count("\n") == 1
    assert not out.exists()

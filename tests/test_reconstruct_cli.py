"""``metafovea reconstruct`` subcommand (called through add_parser/run, as cli.py will)."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from metafovea.cli import reconstruct as cli_reconstruct
from metafovea.io import atomic_save_npz
from metafovea.reconstruct import Reconstruction
from metafovea.reconstruct.synthetic import measure, polariser_alpha, scene


def _parse(argv):
    p = argparse.ArgumentParser(prog="metafovea")
    sub = p.add_subparsers(dest="command")
    cli_reconstruct.add_parser(sub)
    return p.parse_args(["reconstruct", *argv])


@pytest.fixture()
def meas(tmp_path):
    x1, x2 = scene(64)
    T = 10
    a = polariser_alpha(T)
    frames = measure(x1, x2, a, sigma=0.01, rng=0, dtype=np.float32)
    path = tmp_path / "meas.npz"
    atomic_save_npz(path, meta={"scale": 6, "pixel_pitch_um": 17.0}, frames=frames, times_s=np.arange(T) / 12.0,
                    alpha=a, truth_x1=x1, truth_x2=x2)
    return path


def test_cli_lsq_single_window_json(meas, tmp_path, capsys):
    out = tmp_path / "rec.npz"
    rc = cli_reconstruct.run(_parse([str(meas), "--window", "10", "--out", str(out), "--json"]))
    assert rc == 0
    s = json.loads(capsys.readouterr().out)
    assert s["metrics"]["psnr_x1"] > 40 and s["condition"] < 10
    rec = Reconstruction.load(out)
    assert rec.x1.shape == (64, 64)
    assert (tmp_path / "rec_x1.png").stat().st_size > 0 and (tmp_path / "rec.png").exists()
    # refuses to overwrite without --force
    assert cli_reconstruct.run(_parse([str(meas), "--window", "10", "--out", str(out)])) == 2
    assert cli_reconstruct.run(_parse([str(meas), "--window", "10", "--out", str(out), "--force"])) == 0


def test_cli_video_and_alternating(meas, tmp_path, capsys):
    out = tmp_path / "v.npz"
    assert cli_reconstruct.run(_parse([str(meas), "--out", str(out), "--no-figures"])) == 0
    assert Reconstruction.load(out).x1.shape == (3, 64, 64)
    assert "3 reconstruction(s)" in capsys.readouterr().out
    out2 = tmp_path / "alt.npz"
    assert cli_reconstruct.run(_parse([str(meas), "--method", "alternating", "--window", "10", "--out",
                                       str(out2), "--json", "--no-figures"])) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["alpha_identified"] and s["gauge"]["applied"] and s["metrics"]["psnr_x1"] > 40
    assert Reconstruction.load(out2).info["alpha_identified"]


def test_cli_errors(meas, tmp_path, capsys):
    assert cli_reconstruct.run(_parse([str(meas), "--window", "20", "--out", str(tmp_path / "a.npz")])) == 2
    assert "window" in capsys.readouterr().err
    assert cli_reconstruct.run(_parse([str(tmp_path / "missing.npz")])) == 2
    bare = tmp_path / "bare.npz"
    atomic_save_npz(bare, meta={}, frames=np.zeros((4, 16, 16)), times_s=np.arange(4.0))
    assert cli_reconstruct.run(_parse([str(bare), "--window", "4", "--out", str(tmp_path / "b.npz")])) == 2
    assert "alpha" in capsys.readouterr().err

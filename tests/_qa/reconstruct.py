"""QA regression tests for reconstruct, split out of tests/test_qa_*.py: merge each into its subject test file
(keep the bug sentence as its docstring), then delete this file."""

from __future__ import annotations
import argparse
import json
import numpy as np
import pytest
from metafovea.cli import reconstruct as cli_reconstruct
from metafovea.errors import InputError
from metafovea.io import atomic_save_npz
from metafovea.reconstruct.metrics import score
from metafovea.reconstruct.synthetic import measure, polariser_alpha, scene


def _run(argv, capsys):
    rc = cli_reconstruct.run(_parse([str(a) for a in argv]))
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def _parse(argv):
    p = argparse.ArgumentParser(prog="metafovea")
    sub = p.add_subparsers(dest="command")
    cli_reconstruct.add_parser(sub)
    return p.parse_args(["reconstruct", *argv])


def _save(path, T=10, n=48, **over):
    x1, x2 = scene(n)
    a = polariser_alpha(T)
    arrays = dict(frames=measure(x1, x2, a, sigma=0.0, rng=0, dtype=np.float32), times_s=np.arange(T) / 12.0,
                  alpha=a, truth_x1=x1.astype(np.float32), truth_x2=x2.astype(np.float32))
    for k, v in over.items():
        if v is None:
            arrays.pop(k, None)
        else:
            arrays[k] = v
    atomic_save_npz(path, meta={"scale": 6}, **arrays)
    return path


@pytest.mark.parametrize("kind", ["text", "empty", "object", "badjson", "listjson"])
def test_files_that_are_not_measurements_are_input_errors(tmp_path, capsys, kind):
    p = tmp_path / "x.npz"
    if kind == "text":
        p.write_text("hello")
    elif kind == "empty":
        p.write_bytes(b"")
    elif kind == "object":
        np.savez(p, frames=np.array([{"a": 1}], dtype=object))
    else:
        meta = b"{not json" if kind == "badjson" else b"[1, 2]"
        np.savez(p, frames=np.ones((4, 16, 16), np.float32), __meta__=np.frombuffer(meta, np.uint8))
    rc, _, err = _run([p, "--out", tmp_path / "r.npz"], capsys)
    assert rc == 2 and err.count("\n") == 1 and "error" in err
    assert not (tmp_path / "r.npz").exists()


def test_truth_of_the_wrong_shape_is_an_input_error(tmp_path, capsys):
    m = _save(tmp_path / "m.npz", truth_x1=np.ones((5, 5), np.float32))
    rc, _, err = _run([m, "--window", "10", "--no-figures"], capsys)
    assert rc == 2 and "truth_x1" in err
    m = _save(tmp_path / "m2.npz", truth_x2=np.ones((3, 48, 48), np.float32))  # 3 truth frames for 10 frames
    rc, _, err = _run([m, "--window", "10", "--no-figures"], capsys)
    assert rc == 2 and "truth_x2" in err


def test_score_refuses_truth_with_another_number_of_frames():
    x = np.zeros((2, 8, 8))
    with pytest.raises(InputError, match="truth_x1"):
        score((x, x), np.zeros((5, 8, 8)), None)
    with pytest.raises(InputError, match="truth_x1"):
        score((x, x), np.zeros((4, 4)), None)


def test_video_truth_is_scored_against_each_windows_mean(tmp_path, capsys):
    """Static frames, but a (T, H, W) truth that flickers around the real image: each window's
    reconstruction must be compared with the truth averaged over that window, not with frame k."""
    T, n = 10, 48
    x1, x2 = scene(n)
    flick = np.where(np.arange(T) % 2 == 0, 1.0, -1.0)[:, None, None] * 0.3 * np.ptp(x1)
    t1 = (x1[None] + flick).astype(np.float32)
    t2 = np.repeat(x2[None], T, 0).astype(np.float32)
    m = _save(tmp_path / "m.npz", T=T, n=n, truth_x1=t1, truth_x2=t2)
    for argv in (["--window", "10"], ["--window", "2", "--stride", "2"], ["--window", "4", "--stride", "2"]):
        rc, out, err = _run([m, *argv, "--no-figures", "--json", "--force"], capsys)
        assert rc == 0, err
        s = json.loads(out)
        assert s["metrics"]["psnr_x1"] > 40, (argv, s["metrics"])
    rc, out, _ = _run([m, "--method", "snapshot", "--frame", "3", "--no-figures", "--json", "--force",
                       "--out", tmp_path / "snap.npz"], capsys)
    assert rc == 0
    from metafovea.reconstruct import Reconstruction

    rec = Reconstruction.load(tmp_path / "snap.npz")
    assert json.loads(out)["metrics"] == pytest.approx(score(rec, t1[3], t2[3]))  # that frame's truth, not frame 0's


def test_all_nan_frames_are_an_input_error(tmp_path, capsys):
    m = _save(tmp_path / "m.npz", frames=np.full((10, 48, 48), np.nan, np.float32))
    rc, _, err = _run([m, "--window", "10", "--no-figures"], capsys)
    assert rc == 2 and "frames" in err and err.count("\n") == 1
    assert not (tmp_path / "m_rec.npz").exists()


def test_single_frame_needs_snapshot(tmp_path, capsys):
    m = _save(tmp_path / "m.npz", T=1)
    rc, _, err = _run([m, "--no-figures"], capsys)
    assert rc == 2 and "snapshot" in err
    rc, _, err = _run([m, "--method", "snapshot", "--no-figures"], capsys)
    assert rc == 0, err


def test_nothing_is_written_when_a_figure_would_be_overwritten(tmp_path, capsys):
    m = _save(tmp_path / "m.npz")
    (tmp_path / "m_rec_x2.png").write_bytes(b"keep")
    rc, _, err = _run([m, "--window", "10"], capsys)
    assert rc == 2 and "m_rec_x2.png" in err
    assert not (tmp_path / "m_rec.npz").exists() and (tmp_path / "m_rec_x2.png").read_bytes() == b"keep"


def test_out_must_be_npz_and_never_the_measurement(tmp_path, capsys):
    m = _save(tmp_path / "m.npz")
    before = m.read_bytes()
    rc, _, err = _run([m, "--window", "10", "--out", tmp_path / "r.txt", "--no-figures"], capsys)
    assert rc == 2 and ".npz" in err and not (tmp_path / "r.txt").exists()
    rc, _, err = _run([m, "--window", "10", "--out", tmp_path / "sub" / ".." / "m.npz", "--force",
                       "--no-figures"], capsys)
    assert rc == 2 and "--out" in err
    assert m.read_bytes() == before


def test_bad_fpn_and_calibration_arrays_are_named(tmp_path, capsys):
    f = np.zeros((48, 48), np.float32)
    f[0, 0] = np.nan
    m = _save(tmp_path / "m.npz", fpn=f)
    rc, _, err = _run([m, "--window", "10", "--fpn", "file", "--no-figures"], capsys)
    assert rc == 2 and "fpn" in err
    m = _save(tmp_path / "c.npz", calibration=np.zeros((4, 3, 3), np.float32))
    rc, _, err = _run([m, "--window", "10", "--fpn", "calibration", "--no-figures"], capsys)
    assert rc == 2 and "calibration" in err


@pytest.mark.parametrize("argv", [["--stride", "0"], ["--window", "1"], ["--window", "11"]])
def test_window_and_stride_ranges(tmp_path, capsys, argv):
    m = _save(tmp_path / "m.npz")
    rc, _, err = _run([m, *argv, "--no-figures"], capsys)
    assert rc == 2 and argv[0] in err.replace("window =", "--window =") and err.count("\n") == 1


def test_fpn_prior_with_known_alpha_uses_the_given_foveal_constraint(monkeypatch):
    """The lsq path dropped scale/gain/offset before the FPN prior saw them (it used gain 1, offset 0)."""
    import metafovea.reconstruct.fpn as fpn_mod
    from metafovea.reconstruct import reconstruct

    seen = {}
    real = fpn_mod.estimate_fpn

    def spy(**kw):
        seen.update({k: kw.get(k) for k in ("scale", "foveal_gain", "foveal_offset")})
        return real(**kw)

    monkeypatch.setattr(fpn_mod, "estimate_fpn", spy)
    x1, x2 = scene(48)
    a = polariser_alpha(8)
    Y = measure(x1, x2, a, sigma=0.0, rng=0)
    reconstruct(Y, a, method="lsq", fpn="prior", scale=4.0, foveal_gain=0.3, foveal_offset=5.0)
    assert seen == {"scale": 4.0, "foveal_gain": 0.3, "foveal_offset": 5.0}


def test_snapshot_honours_denoise(tmp_path, capsys):
    from metafovea.reconstruct import Reconstruction

    x1, x2 = scene(48)
    a = polariser_alpha(4)
    frames = measure(x1, x2, a, sigma=0.05, rng=1, dtype=np.float32)
    m = tmp_path / "m.npz"
    atomic_save_npz(m, meta={"scale": 6}, frames=frames, times_s=np.arange(4) / 12.0, alpha=a)
    outs = []
    for extra in ([], ["--denoise", "tv"]):
        out = tmp_path / f"r{len(extra)}.npz"
        rc, _, err = _run([m, "--method", "snapshot", "--frame", "1", "--no-figures", "--out", out, *extra], capsys)
        assert rc == 0, err
        outs.append(Reconstruction.load(out).x1)
    assert not np.allclose(outs[0], outs[1])
    assert np.std(np.diff(outs[1], axis=1)) < np.std(np.diff(outs[0], axis=1))


def test_no_strict_gives_the_frame_mean_gauge_result_the_error_points_to(tmp_path, capsys):
    """The alternating solver's error told CLI users to 'pass strict=False', which the CLI had no way to do."""
    from metafovea.reconstruct import Reconstruction

    x1 = np.random.default_rng(0).random((48, 48))  # unrelated to x2: the foveal constraint cannot fix the gauge
    _, x2 = scene(48)
    a = polariser_alpha(8)
    m = tmp_path / "m.npz"
    atomic_save_npz(m, meta={"scale": 6}, frames=measure(x1, x2, a, sigma=0.0, rng=0, dtype=np.float32),
                    times_s=np.arange(8) / 12.0)
    rc, _, err = _run([m, "--method", "alternating", "--no-figures"], capsys)
    assert rc == 2 and "--no-strict" in err
    rc, _, err = _run([m, "--method", "alternating", "--no-strict", "--no-figures"], capsys)
    assert rc == 0, err
    assert Reconstruction.load(tmp_path / "m_rec.npz").info["alpha_identified"] is False


def test_dip_on_frames_too_small_for_the_network_names_the_frame_size():
    from metafovea.reconstruct.deep_prior import dip

    with pytest.raises(InputError, match="at least 8 x 8 pixels") as e:
        dip(np.ones((4, 4, 6), np.float32), steps=1)
    assert e.value.parameter == "frames"


@pytest.mark.parametrize("method", ["tv", "bilateral", "nlm"])
def test_denoise_keeps_dead_pixels_nan_without_spreading_or_failing(method):
    from metafovea.reconstruct import denoise

    x1, _ = scene(48)
    noisy = x1 + 0.05 * np.random.default_rng(0).standard_normal(x1.shape)
    img = noisy.copy()
    img[10, 20] = np.nan
    out = denoise(img, method, sigma=0.05)
    assert np.isnan(out[10, 20]) and np.isfinite(np.delete(out.ravel(), 10 * 48 + 20)).all()
    with pytest.raises(InputError):
        denoise(np.full((8, 8), np.nan), method, sigma=0.05)


def test_cli_dead_pixel_with_denoise(tmp_path, capsys):
    from metafovea.reconstruct import Reconstruction

    x1, x2 = scene(48)
    a = polariser_alpha(10)
    frames = measure(x1, x2, a, sigma=0.01, rng=0, dtype=np.float32)
    frames[:, 7, 9] = np.nan  # a dead pixel: no valid sample in any frame
    m = _save(tmp_path / "m.npz", frames=frames)
    for argv in (["--window", "10"], ["--window", "4", "--stride", "3"]):
        out = tmp_path / f"r{argv[1]}.npz"
        rc, stdout, err = _run([m, *argv, "--denoise", "tv", "--no-figures", "--out", out], capsys)
        assert rc == 0, err
        assert "NaN value(s)" in stdout
        x = Reconstruction.load(out).x1
        x = x if x.ndim == 3 else x[None]
        assert np.isnan(x[:, 7, 9]).all() and np.isnan(x).sum() == x.shape[0]


@pytest.mark.parametrize("alpha", [np.array(0.5), polariser_alpha(10).astype(complex)])
def test_alpha_in_a_file_must_be_real_and_one_per_frame(tmp_path, capsys, alpha):
    m = _save(tmp_path / "m.npz", alpha=alpha)
    for method in ("lsq", "snapshot"):
        rc, _, err = _run([m, "--method", method, "--known-alpha", "--window", "10", "--no-figures"], capsys)
        assert rc == 2 and "alpha" in err and err.count("\n") == 1


def test_regularize_option_is_what_the_ill_conditioned_error_points_to(tmp_path, capsys):
    """A slow bolometer (alpha barely varies) made lsq fail with 'pass regularize=...', an API keyword only."""
    x1, x2 = scene(48)
    a = 0.5 + 0.002 * np.cos(np.arange(10) * 2.1)
    m = _save(tmp_path / "m.npz", frames=measure(x1, x2, a, sigma=0.0, rng=0, dtype=np.float32), alpha=a)
    rc, _, err = _run([m, "--window", "10", "--no-figures"], capsys)
    assert rc == 2 and "--regularize" in err
    for argv in (["--window", "10"], ["--window", "5", "--stride", "5"]):
        rc, _, err = _run([m, *argv, "--regularize", "difference", "--no-figures", "--force"], capsys)
        assert rc == 0, err
    rc, _, err = _run([m, "--window", "10", "--regularize", "-1", "--no-figures", "--force"], capsys)
    assert rc == 2 and "--regularize" in err


def test_negative_seed_and_impossible_scale_are_input_errors(tmp_path, capsys):
    m = _save(tmp_path / "m.npz")
    rc, _, err = _run([m, "--method", "dip", "--steps", "1", "--seed", "-1", "--no-figures"], capsys)
    assert rc == 2 and "--seed" in err and err.count("\n") == 1
    for bad in ("-5", "0.5", "1e9"):
        rc, _, err = _run([m, "--window", "10", "--scale", bad, "--no-figures"], capsys)
        assert rc == 2 and "--scale" in err
    from metafovea.reconstruct._common import as_rng

    with pytest.raises(InputError, match="seed"):
        as_rng(-3)


@pytest.mark.parametrize("kind", ["empty", "truncated", "corrupt-member", "listjson"])
def test_measurement_load_and_reconstruct_refuse_damaged_files(tmp_path, capsys, kind):
    from metafovea.measurement import Measurement

    good = _save(tmp_path / "good.npz")
    p = tmp_path / "bad.npz"
    if kind == "empty":
        p.write_bytes(b"")
    elif kind == "truncated":
        p.write_bytes(good.read_bytes()[:3000])
    elif kind == "corrupt-member":
        np.savez_compressed(p, frames=np.random.default_rng(0).random((4, 32, 32)).astype(np.float32))
        b = bytearray(p.read_bytes())
        for i in range(200, 1500):
            b[i] ^= 0x55
        p.write_bytes(bytes(b))
    else:
        np.savez(p, frames=np.ones((4, 16, 16), np.float32), __meta__=np.frombuffer(b"[1]", np.uint8))
    with pytest.raises(InputError):
        Measurement.load(p)
    rc, _, err = _run([p, "--out", tmp_path / "r.npz"], capsys)
    assert rc == 2 and err.count("\n") == 1


def test_default_window_covers_a_sequence_shorter_than_8_frames(tmp_path, capsys):
    m = _save(tmp_path / "m.npz", T=5)
    rc, out, err = _run([m, "--no-figures", "--json"], capsys)
    assert rc == 0, err
    assert json.loads(out)["outputs"] == 1
    rc, _, err = _run([m, "--window", "8", "--no-figures", "--force"], capsys)  # an explicit window is checked
    assert rc == 2 and "--window" in err


def test_lsq_without_alpha_names_alpha_and_the_method(tmp_path, capsys):
    m = _save(tmp_path / "m.npz", alpha=None)
    rc, _, err = _run([m, "--no-figures"], capsys)
    assert rc == 2 and "alpha = 'absent'" in err and "--method lsq" in err

"""``metafovea reconstruct`` through :func:`metafovea.cli.main`: outputs, summaries, and every bad input as one
line with exit status 2 (nothing written)."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest

from metafovea.cli import main
from metafovea.errors import InputError, as_rng
from metafovea.io import atomic_save_npz
from metafovea.measurement import Measurement
from metafovea.reconstruct import Reconstruction
from metafovea.reconstruct.metrics import score
from metafovea.reconstruct.synthetic import measure, polariser_alpha, scene


def _run(argv, capsys):
    rc = main(["reconstruct", *[str(a) for a in argv]])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def _save(path, T=10, n=48, meta=None, **over):
    x1, x2 = scene(n)
    a = polariser_alpha(T)
    arrays = dict(frames=measure(x1, x2, a, sigma=0.0, rng=0, dtype=np.float32), times_s=np.arange(T) / 12.0,
                  alpha=a, truth_x1=x1.astype(np.float32), truth_x2=x2.astype(np.float32))
    for k, v in over.items():
        if v is None:
            arrays.pop(k, None)
        else:
            arrays[k] = v
    atomic_save_npz(path, meta={"scale": 6} if meta is None else meta, **arrays)
    return path


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
    rc, stdout, err = _run([meas, "--window", "10", "--out", out, "--json"], capsys)
    assert rc == 0, err
    s = json.loads(stdout)
    assert s["metrics"]["psnr_x1"] > 40 and s["condition"] < 10
    assert list(s)[:9] == ["measurement", "method", "frames", "foveal_constraint", "outputs", "seconds",
                           "ms_per_output", "timings", "files"]
    rec = Reconstruction.load(out)
    assert rec.x1.shape == (64, 64)
    assert (tmp_path / "rec_x1.png").stat().st_size > 0 and (tmp_path / "rec.png").exists()
    # refuses to overwrite without --force
    assert _run([meas, "--window", "10", "--out", out], capsys)[0] == 2
    assert _run([meas, "--window", "10", "--out", out, "--force"], capsys)[0] == 0


def test_cli_video_and_alternating(meas, tmp_path, capsys):
    out = tmp_path / "v.npz"
    rc, stdout, _ = _run([meas, "--window", "8", "--out", out, "--no-figures"], capsys)
    assert rc == 0 and Reconstruction.load(out).x1.shape == (3, 64, 64)
    assert "3 reconstruction(s)" in stdout and "psnr_x1" in stdout and "wrote" in stdout
    rc, stdout, _ = _run([meas, "--out", tmp_path / "one.npz", "--no-figures"], capsys)  # 10 frames: one window
    assert rc == 0 and Reconstruction.load(tmp_path / "one.npz").x1.shape == (64, 64)
    out2 = tmp_path / "alt.npz"
    rc, stdout, _ = _run([meas, "--method", "alternating", "--window", "10", "--out", out2, "--json",
                          "--no-figures"], capsys)
    assert rc == 0
    s = json.loads(stdout)
    # the file says nothing of its polariser: the paper's free-running 2 Hz one is assumed (and said) and fixes
    # alpha's gauge; its extinction and lag are guesses that a 64 x 64 recording cannot check (no fovea to calibrate
    # on), so alpha's amplitude is known only to the spread of real devices: not identified, and said so
    assert s["alpha_gauge"] == "absolute (polariser model)" and s["metrics"]["psnr_x1"] > 40
    assert not s["alpha_identified"] and s["alpha_se_max"] > 5e-3
    assert s["calibration"]["amplitude_se_used"] > 0.05 and any("--extinction" in w for w in s["warnings"])
    assert s["images_gauge_se"][0] > 0 and s["images_gauge_se"][1] > 0
    text = _run([meas, "--method", "alternating", "--window", "10", "--out", tmp_path / "alt2.npz", "--no-figures"],
                capsys)[1]
    assert s["polarizer"]["model"]["assumed"] and "assumed: polarizer_hz = 2.0" in text
    # each assumption names the flag that states it instead
    assumed = [ln for ln in text.splitlines() if ln.startswith("  assumed: ")]
    flags = {"polarizer_hz": "--polarizer-hz", "polarizer_mode": "--polarizer-mode",
             "polarizer_extinction": "--extinction", "bolometer_tau_s": "--tau"}
    assert assumed and all(ln.endswith(f"; {flags[ln.split()[1]]} states it)") for ln in assumed)
    assert "what alpha's gauge leaves uncertain in the images" in text
    assert not Reconstruction.load(out2).info["alpha_identified"]
    # stated constants (the ideal device the data were made with): taken as exact, alpha identified
    rc, stdout, _ = _run([meas, "--method", "alternating", "--window", "10", "--out", tmp_path / "alt3.npz", "--json",
                          "--no-figures", "--extinction", "0", "--tau", "0"], capsys)
    s = json.loads(stdout)
    assert rc == 0 and s["alpha_identified"] and s["alpha_se_max"] < 1e-3 and s["metrics"]["psnr_x1"] > 40


def test_cli_errors(meas, tmp_path, capsys):
    rc, _, err = _run([meas, "--window", "20", "--out", tmp_path / "a.npz"], capsys)
    assert rc == 2 and "window" in err
    assert _run([tmp_path / "missing.npz"], capsys)[0] == 2
    bare = tmp_path / "bare.npz"
    atomic_save_npz(bare, meta={}, frames=np.zeros((4, 16, 16)), times_s=np.arange(4.0))
    rc, _, err = _run([bare, "--window", "4", "--out", tmp_path / "b.npz"], capsys)
    assert rc == 2 and "alpha" in err


def test_cli_foveal_constraint_from_meta(dn_scene, tmp_path, capsys):
    x1, x2, G, B = dn_scene
    a = polariser_alpha(10)
    frames = measure(x1, x2, a, sigma=0.6, rng=0, dtype=np.float32)
    meta = {"scale": 6.0, "units": "DN",
            "foveal_constraint": {"scale": 6.0, "gain": G, "offset_dn": B, "relation": "..."}}
    path = tmp_path / "meas.npz"
    atomic_save_npz(path, meta=meta, frames=frames, times_s=np.arange(10) / 12.0, alpha=a, truth_x1=x1, truth_x2=x2)
    rc, stdout, _ = _run([path, "--method", "alternating", "--window", "10", "--out", tmp_path / "alt.npz", "--json",
                          "--no-figures", "--polarizer", "none"], capsys)  # the foveal constraint alone
    assert rc == 0
    s = json.loads(stdout)
    assert s["foveal_constraint"] == {"scale": 6.0, "foveal_gain": G, "foveal_offset": B}
    assert s["alpha_identified"] and s["gauge"]["applied"]
    # overriding the file's gain with 1 breaks the constraint: clear error, exit 2
    rc, _, err = _run([path, "--method", "alternating", "--window", "10", "--out", tmp_path / "b.npz",
                       "--no-figures", "--foveal-gain", "1", "--polarizer", "none"], capsys)
    assert rc == 2 and "gauge" in err


@pytest.fixture(scope="module")
def dn_scene():
    """x1 in [1700, 1760] DN, D x1 == 0.3 C x2 + 700 exactly (x2 ~ 3300-3500 DN)."""
    G, B = 0.3, 700.0
    return (*scene(96, lo=1700.0, hi=1760.0, foveal_gain=G, foveal_offset=B), G, B)


def test_cli_on_a_simulated_measurement(tmp_path, capsys):
    """The saved simulator file: constraint from the metadata, stored pattern subtracted (--fpn file), unknown
    alpha identified."""
    from metafovea.config import SystemDesign
    from metafovea.imaging import simulate

    s = SystemDesign.paper()
    s = dataclasses.replace(s, sensor=dataclasses.replace(s.sensor, crop=(192, 192), pixels=(192, 192)))
    m = simulate(s, "bars", frames=8, psf="airy", rng=0)
    path = m.save(tmp_path / "meas.npz")
    np.save(tmp_path / "pattern.npy", m.fpn)  # a calibrated pattern of the user's
    rc, stdout, err = _run([path, "--method", "alternating", "--window", "8", "--fpn", tmp_path / "pattern.npy",
                            "--out", tmp_path / "rec.npz", "--json", "--no-figures"], capsys)
    assert rc == 0, err
    out = json.loads(stdout)
    assert out["foveal_constraint"]["foveal_gain"] == pytest.approx(m.meta["foveal_constraint"]["gain"])
    # the figures of reconstruct_measurement on the same file (tests/reconstruct/test_api.py; equal here for seeds
    # 0-2): x1 25.53-25.89 dB, x2 44.91-45.53 dB over seeds 0-9 (this seed 25.75 / 44.98), floors 1 dB under the worst
    assert out["alpha_identified"] and out["metrics"]["psnr_x1"] > 24.5 and out["metrics"]["psnr_x2"] > 43.9


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


@pytest.mark.parametrize("kind", ["empty", "truncated", "corrupt-member", "listjson"])
def test_measurement_load_and_reconstruct_refuse_damaged_files(tmp_path, capsys, kind):
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


def test_truth_of_the_wrong_shape_is_an_input_error(tmp_path, capsys):
    m = _save(tmp_path / "m.npz", truth_x1=np.ones((5, 5), np.float32))
    rc, _, err = _run([m, "--window", "10", "--no-figures"], capsys)
    assert rc == 2 and "truth_x1" in err and str(m) in err
    m = _save(tmp_path / "m2.npz", truth_x2=np.ones((3, 48, 48), np.float32))  # 3 truth frames for 10 frames
    rc, _, err = _run([m, "--window", "10", "--no-figures"], capsys)
    assert rc == 2 and "truth_x2" in err


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
    m = _save(tmp_path / "m.npz")
    np.save(tmp_path / "bad.npy", f)
    rc, _, err = _run([m, "--window", "10", "--fpn", tmp_path / "bad.npy", "--no-figures"], capsys)
    assert rc == 2 and "--fpn" in err and "finite" in err
    rc, _, err = _run([m, "--window", "10", "--fpn", tmp_path / "missing.npy", "--no-figures"], capsys)
    assert rc == 2 and "--fpn" in err
    rc, _, err = _run([m, "--window", "10", "--fpn", "file", "--no-figures"], capsys)
    assert rc == 2 and "true pattern" in err
    m = _save(tmp_path / "c.npz", calibration=np.zeros((4, 3, 3), np.float32))
    rc, _, err = _run([m, "--window", "10", "--fpn", "calibration", "--no-figures"], capsys)
    assert rc == 2 and "calibration" in err
    rc, _, err = _run([_save(tmp_path / "n.npz"), "--window", "10", "--fpn", "calibration", "--no-figures"], capsys)
    assert rc == 2 and "--fpn = 'calibration' is invalid" in err and "--fpn auto" in err and "n.npz has none" in err


@pytest.mark.parametrize("argv", [["--stride", "0"], ["--window", "1"], ["--window", "11"]])
def test_window_and_stride_ranges(tmp_path, capsys, argv):
    m = _save(tmp_path / "m.npz")
    rc, _, err = _run([m, *argv, "--no-figures"], capsys)
    assert rc == 2 and argv[0] in err.replace("window =", "--window =") and err.count("\n") == 1


def test_snapshot_honours_denoise(tmp_path, capsys):
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
        outs.append(Reconstruction.load(out))
    assert outs[1].info.get("denoise") == "tv" and "denoise" not in outs[0].info
    # the default separation's x1 is the constraint's smooth low-pass and its x2 is denoised already: the pipeline's
    # denoiser may leave them (SURE declines a weight that does not pay), and never roughens them
    for k in ("x1", "x2"):
        a, b = (np.asarray(getattr(r, k), np.float64) for r in outs)
        assert np.std(np.diff(b, axis=1)) <= np.std(np.diff(a, axis=1)) + 1e-6


def _unrelated_images(tmp_path, T):
    """A file of ``T`` frames whose foveal image is unrelated to the perifoveal one (the foveal constraint cannot
    fix the gauge), the paper's polariser, no polariser keys."""
    x1 = np.random.default_rng(0).random((48, 48))
    _, x2 = scene(48)
    m = tmp_path / "m.npz"
    atomic_save_npz(m, meta={"scale": 6}, frames=measure(x1, x2, polariser_alpha(T), sigma=0.0, rng=0,
                                                         dtype=np.float32), times_s=np.arange(T) / 12.0)
    return m


def test_no_strict_gives_the_frame_mean_gauge_result_the_error_points_to(tmp_path, capsys):
    """The alternating solver's error told CLI users to 'pass strict=False', which the CLI had no way to do."""
    m = _unrelated_images(tmp_path, 8)
    rc, _, err = _run([m, "--method", "alternating", "--polarizer", "none", "--no-figures"], capsys)
    assert rc == 2 and "--no-strict" in err
    rc, _, err = _run([m, "--method", "alternating", "--polarizer", "none", "--no-strict", "--no-figures"], capsys)
    assert rc == 0, err
    assert Reconstruction.load(tmp_path / "m_rec.npz").info["alpha_identified"] is False
    # with the polariser model (the paper's 2 Hz, assumed: the file says nothing), the rotation alone fixes alpha
    rc, out, err = _run([m, "--method", "alternating", "--no-figures", "--json", "--out", tmp_path / "p.npz"], capsys)
    assert rc == 0, err
    assert json.loads(out)["alpha_gauge"] == "absolute (polariser model)"


def test_the_gauge_error_is_one_message_naming_the_flags_to_use(tmp_path, capsys):
    """The alternating gauge error nested three messages (a window's, the solver's, its detail) and named the library
    keyword strict=False: one message now, in the window, naming the flags that fix it."""
    m = _unrelated_images(tmp_path, 20)
    rc, out, err = _run([m, "--method", "alternating", "--polarizer", "none", "--no-figures"], capsys)
    assert rc == 2 and out == "" and err.count("\n") == 1
    assert err.count("is invalid") == 1 and "window 0 (frames 0..7)" in err
    for flag in ("--no-strict", "--polarizer auto", "--scale", "--foveal-gain", "--foveal-offset", "--method lsq"):
        assert flag in err, flag
    for keyword in ("strict=False", "foveal_gain", "scale/offset/gain", "method='lsq'"):
        assert keyword not in err, keyword


def test_cli_dead_pixel_with_denoise(tmp_path, capsys):
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
    rc, _, err = _run([m, "--method", "alternating", "--regularize", "difference", "--no-figures", "--force"], capsys)
    assert rc == 2 and "--regularize" in err and "--method lsq" in err


def test_negative_seed_and_impossible_scale_are_input_errors(tmp_path, capsys):
    m = _save(tmp_path / "m.npz")
    rc, _, err = _run([m, "--method", "dip", "--steps", "1", "--seed", "-1", "--no-figures"], capsys)
    assert rc == 2 and "--seed" in err and err.count("\n") == 1
    for bad in ("-5", "0.5", "1e9"):
        rc, _, err = _run([m, "--window", "10", "--scale", bad, "--no-figures"], capsys)
        assert rc == 2 and "--scale" in err
    with pytest.raises(InputError, match="seed"):
        as_rng(-3)


def test_known_alpha_is_refused_with_alternating(tmp_path, capsys):
    rc, _, err = _run([_save(tmp_path / "m.npz"), "--method", "alternating", "--known-alpha", "--no-figures"],
                      capsys)
    assert rc == 2 and "--known-alpha" in err and err.count("\n") == 1


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


def test_polarizer_model_from_the_file_fixes_alpha(tmp_path, capsys):
    """A free-running polariser in a simulated file: --polarizer auto (default) takes rate, mode and extinction
    from the metadata (not the realised phase) and gets alpha to the oracle's level; --polarizer none leaves it to
    the foveal constraint, which does worse here."""
    from metafovea.config import SystemDesign
    from metafovea.imaging import simulate

    s = SystemDesign.paper()
    s = dataclasses.replace(s, sensor=dataclasses.replace(s.sensor, crop=(192, 192), pixels=(192, 192)))
    m = simulate(s, "camera", frames=10, psf="airy", rng=4, polarizer_mode="free")
    path = m.save(tmp_path / "free.npz")
    maes = {}
    for pol in ("auto", "none"):
        rc, stdout, err = _run([path, "--method", "alternating", "--window", "10", "--polarizer", pol, "--out",
                                tmp_path / f"r_{pol}.npz", "--json", "--no-figures", "--no-strict"], capsys)
        assert rc == 0, err
        out = json.loads(stdout)
        rec = np.load(tmp_path / f"r_{pol}.npz")
        maes[pol] = float(np.mean(np.abs(rec["alpha"] - m.alpha)))
        if pol == "auto":
            assert out["alpha_gauge"] == "absolute (polariser model)" and out["polarizer"]["mode"] == "free"
            assert out["alpha_identified"] and out["alpha_se_max"] >= maes[pol]
    assert maes["auto"] <= 2e-3 and maes["auto"] < maes["none"]
    rc, stdout, err = _run([path, "--method", "alternating", "--window", "10", "--out", tmp_path / "r.npz",
                            "--no-figures", "--force"], capsys)
    assert "alpha gauge: absolute (polariser model); identified: True" in stdout


def test_default_fpn_is_chosen_from_the_file_and_printed(tmp_path, capsys):
    """``--fpn`` defaulted to none: a simulated file's fixed pattern stayed in the foveal image (-8.1 dB) with no
    hint. The default is now auto, and the summary says what it chose and why (text and JSON)."""
    from metafovea.reconstruct.synthetic import lowrank_fpn

    x1, x2 = scene(48)
    a = polariser_alpha(8)
    f = lowrank_fpn((48, 48), rank=3, amplitude=0.1, rng=1).astype(np.float32)
    frames = measure(x1, x2, a, sigma=0.0, fpn=f, rng=0, dtype=np.float32)
    cal = measure(np.full_like(x1, 0.5), np.full_like(x1, 0.5), np.full(4, 0.5), sigma=0.0, fpn=f, rng=0)
    cases = {"cal": ({"scale": 6}, {"calibration": cal.astype(np.float32)}, "calibration, from the file's 4 shutter"),
             "declared": ({"scale": 6, "fpn_rank": 3}, {}, "prior, blind estimate"),
             "silent": ({"scale": 6}, {}, "none, not corrected (the file has no shutter frames")}
    for name, (meta, extra, line) in cases.items():
        m = _save(tmp_path / f"{name}.npz", T=8, meta=meta, frames=frames, alpha=a, fpn=f, **extra)
        rc, out, err = _run([m, "--no-figures"], capsys)
        assert rc == 0, err
        assert f"fixed-pattern noise: {line}" in out and "(--fpn auto)" in out, out
    rc, out, _ = _run([tmp_path / "cal.npz", "--no-figures", "--force", "--fpn", "none"], capsys)
    assert rc == 0 and "fixed-pattern noise: none\n" in out  # a mode given: no reason to explain


def test_dip_off_a_terminal_logs_progress_lines_and_says_when_the_time_cap_stopped_it(meas, tmp_path, capsys,
                                                                                        monkeypatch):
    """`reconstruct --method dip` printed nothing off a terminal (its bar was for terminals only) and had no time
    cap. Off a terminal it now writes a progress line every PROGRESS_LINE_S (0 here: every update) with step, total
    and ETA; the time cap stops it, and the summary says so. Every run solves windows of 4 frames of 64 x 64 (one
    compilation of the DIP's step for the three: a 4-frame file in one window, then 4-frame windows of ``meas``)."""
    import metafovea.parallel

    monkeypatch.setattr(metafovea.parallel, "PROGRESS_LINE_S", 0.0, raising=False)
    four = _save(tmp_path / "four.npz", T=4, n=64)
    rc, out, err = _run([four, "--method", "dip", "--known-alpha", "--window", "4", "--channels", "4",
                         "--steps", "100000", "--max-seconds", "0.5", "--no-figures", "--out", tmp_path / "d.npz"],
                        capsys)
    assert rc == 0, err
    assert re.search(r"metafovea: dip: \d+/100000 step \(\d+ %\), \d+ s, ETA ", err), err  # (the first step compiles)
    assert "dip: 1 window(s)" in out and "stopped: 1 by time" in out
    assert "warning: the time cap (--max-seconds 0.5) stopped the run 1 window(s) before their steps were done" in out
    # and says how much of the cap the first step took (the network's compilation, for a shape new to the process)
    first = float(re.search(r"the first step took ([0-9.e+-]+) s: it compiles a new shape's network", out).group(1))
    assert 0 < first == pytest.approx(Reconstruction.load(tmp_path / "d.npz").info["first_step_seconds"], rel=0.01)
    rc, out, err = _run([four, "--method", "dip", "--known-alpha", "--window", "4", "--channels", "4",
                         "--steps", "5", "--no-figures", "--out", tmp_path / "q.npz", "-q"], capsys)
    assert rc == 0 and "metafovea: dip" not in err and "stopped: 1 by steps" in out  # --quiet: no progress
    rc, out, err = _run([meas, "--method", "dip", "--known-alpha", "--window", "4", "--stride", "4", "--channels", "4",
                         "--steps", "100000", "--max-seconds", "0.001", "--no-figures", "--out", tmp_path / "w.npz"],
                        capsys)
    assert rc == 0, err
    assert "stopped the run after 1 of 2 windows (the output holds those)" in out
    assert Reconstruction.load(tmp_path / "w.npz").x1.shape == (1, 64, 64)
    assert _run([meas, "--method", "dip", "--max-seconds", "-1"], capsys)[0] == 2
    # NaN is refused whatever the method (it was ignored outside dip, accepted in silence)
    rc, _, err = _run([meas, "--max-seconds", "nan", "--out", tmp_path / "n.npz"], capsys)
    assert rc == 2 and "--max-seconds" in err and len(err.strip().splitlines()) == 1


def test_method_auto_says_what_it_chose_and_runs_the_psf_aware_step_it_chose(tmp_path, capsys):
    """--method auto on a static simulated file with its PSFs: one window, the PSF-aware scene written, the choice
    and why printed with the time taken and the scores; a tight --time-s leaves the scene out; --time-s without auto
    is one line naming it (exit 2)."""
    from metafovea.config import SystemDesign
    from metafovea.imaging import simulate

    s = SystemDesign.paper()
    s = dataclasses.replace(s, sensor=dataclasses.replace(s.sensor, crop=(64, 64), pixels=(64, 64)))
    path = simulate(s, "bars", frames=12, psf="airy", optical_train=False, rng=0).save(tmp_path / "meas.npz")
    rc, stdout, err = _run([path, "--method", "auto", "--no-figures"], capsys)
    assert rc == 0, err
    assert "auto: lsq (alpha known), one window of all 12 frames, denoise tv, deconvolve wavelet: static:" in stdout
    assert "took" in stdout and "psnr_x2" in stdout and (tmp_path / "meas_rec_scene.npz").is_file()
    rc, stdout, err = _run([path, "--method", "auto", "--time-s", "0.001", "--json", "--no-figures",
                            "--out", tmp_path / "fast.npz"], capsys)
    auto = json.loads(stdout)["auto"]
    assert rc == 0 and auto["chose"]["deconvolve"] is None and "no candidate fits 0.001 s" in auto["why"]
    assert not (tmp_path / "fast_scene.npz").exists()
    rc, _, err = _run([path, "--time-s", "1", "--force"], capsys)
    assert rc == 2 and err.count("\n") == 1 and "--time-s" in err and "--method auto" in err


def test_the_solvers_warnings_name_the_flags_to_type(tmp_path, capsys):
    # a 0.5 Hz polariser, 8-frame windows: the library advises window=12; the command says --window 12, printed and
    # in its JSON
    T = 24
    x1, x2 = scene(48)
    a = np.cos(2 * np.pi * 0.5 * np.arange(T) / 12.0) ** 2
    f = _save(tmp_path / "slow.npz", T=T, meta={"scale": 6, "polarizer_hz": 0.5, "polarizer_mode": "free"},
              frames=measure(x1, x2, a, sigma=0.01, rng=0, dtype=np.float32), alpha=None)
    rc, out, _ = _run([f, "--method", "alternating", "--out", tmp_path / "r.npz", "--no-figures"], capsys)
    (line,) = [s for s in out.splitlines() if "half a turn of the polariser" in s]
    assert rc == 0 and line.startswith("  warning: ") and line.endswith("at least 12 frames (--window 12)")
    rc, out, _ = _run([f, "--method", "alternating", "--out", tmp_path / "j.npz", "--no-figures", "--json"], capsys)
    assert rc == 0 and any(w.endswith("(--window 12)") for w in json.loads(out)["warnings"])


def test_the_calibration_line_says_which_frames_it_used(tmp_path, capsys):
    # the calibration pass fits the first 24 frames (CALIBRATION_FRAMES) of a longer recording: the line says so
    T = 30
    x1, x2 = scene(96)  # a fovea the calibration can fit (16 x 16 perifoveal pixels)
    a = np.cos(2 * np.pi * 2.0 * np.arange(T) / 12.0 + 0.3) ** 2
    f = _save(tmp_path / "long.npz", T=T, n=96, meta={"scale": 6, "polarizer_hz": 2.0, "polarizer_mode": "free"},
              frames=measure(x1, x2, a, sigma=0.01, rng=0, dtype=np.float32), alpha=None)
    rc, out, _ = _run([f, "--method", "alternating", "--out", tmp_path / "r.npz", "--no-figures"], capsys)
    assert rc == 0 and "  calibrated from the recording (the first 24 of 30 frames): foveal scale" in out
    rc, out, _ = _run([f, "--method", "alternating", "--out", tmp_path / "j.npz", "--no-figures", "--json"], capsys)
    c = json.loads(out)["calibration"]
    assert rc == 0 and (c["frames"], c["frames_in_recording"]) == (24, 30)


def test_snapshot_without_a_frame_takes_the_frame_whose_alpha_is_nearest_a_half(tmp_path, capsys):
    """`--method snapshot` without `--frame` separates the frame whose file alpha is nearest 1/2 (both channels most
    evenly mixed: frame 0, at alpha 0.91 on the paper's polariser, did worse than the unseparated frame on 6 of 36
    cases of an independent check) and says which and why; with `--frame` that one; without a file alpha frame 0."""
    m = _save(tmp_path / "m.npz", T=10)
    a = np.load(m)["alpha"]
    best = int(np.argmin(np.abs(a - 0.5)))
    assert best != 0
    rc, out, err = _run([m, "--method", "snapshot", "--no-figures", "--json", "--out", tmp_path / "a.npz"], capsys)
    assert rc == 0, err
    assert json.loads(out)["frame"]["index"] == best and "nearest alpha 1/2" in json.loads(out)["frame"]["why"]
    rc, out, _ = _run([m, "--method", "snapshot", "--no-figures", "--out", tmp_path / "b.npz"], capsys)
    assert rc == 0 and f"  frame {best}: the file's frame nearest alpha 1/2 (alpha {a[best]:.2f})" in out
    rc, out, _ = _run([m, "--method", "snapshot", "--frame", "2", "--no-figures", "--json", "--out",
                       tmp_path / "c.npz"], capsys)
    assert rc == 0 and json.loads(out)["frame"]["index"] == 2
    bare = _save(tmp_path / "bare.npz", T=10, alpha=None)
    rc, out, _ = _run([bare, "--method", "snapshot", "--no-figures", "--json", "--out", tmp_path / "d.npz"], capsys)
    assert rc == 0 and json.loads(out)["frame"]["index"] == 0

"""``metafovea reconstruct`` on inputs a user gets wrong or a file states oddly: refused before anything is written,
flags that would change nothing refused, frames no window reaches said, a value the user did not type not blamed on
its flag, and an unknown-alpha video's output file holding its estimates (not NaN)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from metafovea.cli import main
from metafovea.io import atomic_save_npz
from metafovea.reconstruct.synthetic import measure, polariser_alpha, scene


def _run(argv, capsys):
    rc = main(["reconstruct", *[str(a) for a in argv]])
    cap = capsys.readouterr()
    assert "Traceback" not in cap.err
    return rc, cap.out, cap.err


def _save(path, T=24, n=48, meta=None, alpha=True, frames=None):
    x1, x2 = scene(n)
    a = polariser_alpha(T)
    f = measure(x1, x2, a, sigma=0.01, rng=0, dtype=np.float32) if frames is None else frames
    arrays = dict(frames=f, times_s=np.arange(T) / 12.0, **({"alpha": a} if alpha else {}))
    atomic_save_npz(path, meta={"scale": 6} if meta is None else meta, **arrays)
    return path, a


def test_deconvolve_refused_leaves_no_output(tmp_path, capsys):
    """A file without PSFs, and snapshot with --deconvolve: exit 2 with nothing written (the separation's files were
    written before the PSF-aware step refused)."""
    path, _ = _save(tmp_path / "m.npz")
    for extra in ([], ["--method", "snapshot"]):
        out = tmp_path / "out" / "r.npz"
        rc, _, err = _run([path, "--deconvolve", "--out", out, "--no-score", *extra], capsys)
        assert rc == 2 and len(err.strip().splitlines()) == 1, err
        assert not list((tmp_path / "out").glob("*")) if (tmp_path / "out").exists() else True


@pytest.mark.parametrize("flags", [["--psf", "k.npz"], ["--refine-psf", "defocus"], ["--field-psf", "patches"]])
def test_psf_flags_without_deconvolve_are_refused(tmp_path, capsys, flags):
    path, _ = _save(tmp_path / "m.npz")
    rc, _, err = _run([path, *flags, "--out", tmp_path / "r.npz"], capsys)
    assert rc == 2 and f"{flags[0]} = " in err and "only with --deconvolve" in err
    assert not (tmp_path / "r.npz").exists()


def test_frames_no_window_reaches_are_said_with_a_stride_that_reaches_them(tmp_path, capsys):
    path, _ = _save(tmp_path / "m.npz")  # 24 frames
    rc, out, err = _run([path, "--window", 8, "--stride", 5, "--out", tmp_path / "a.npz", "--json", "--no-figures"],
                        capsys)
    assert rc == 0, err
    warns = json.loads(out)["warnings"]
    said = [w for w in warns if "in no window" in w]
    assert said and "frame 23 of 24" in said[0] and "--stride 4" in said[0], warns
    rc, out, err = _run([path, "--window", 8, "--stride", 4, "--out", tmp_path / "b.npz", "--json", "--no-figures"],
                        capsys)
    assert rc == 0 and not any("in no window" in w for w in json.loads(out).get("warnings") or [])
    rc, out, err = _run([path, "--window", 8, "--stride", 100, "--out", tmp_path / "c.npz", "--no-figures"], capsys)
    assert rc == 0 and "frames 8 to 23 of 24 in no window" in out and "--stride 16" in out


def test_an_unknown_alpha_videos_file_holds_its_alpha_estimates(tmp_path, capsys):
    path, a = _save(tmp_path / "m.npz", alpha=False, meta={"scale": 6, "polarizer_hz": 2.0})
    out = tmp_path / "r.npz"
    rc, _, err = _run([path, "--method", "alternating", "--window", 8, "--out", out, "--no-figures"], capsys)
    assert rc == 0, err
    with np.load(out) as z:
        alpha = z["alpha"]
    assert alpha.shape == (24,) and np.all(np.isfinite(alpha))
    assert np.mean(np.abs(alpha - a)) < 0.02


def test_a_stopped_polariser_in_the_file_is_named_as_the_files_key(tmp_path, capsys):
    path, _ = _save(tmp_path / "m.npz", alpha=False, meta={"scale": 6, "polarizer_hz": 0})
    rc, _, err = _run([path, "--method", "alternating", "--out", tmp_path / "r.npz"], capsys)
    assert rc == 2 and "m.npz: polarizer_hz = 0 is invalid" in err and "rotating polariser" in err, err
    assert _run([path, "--method", "lsq", "--out", tmp_path / "r.npz", "--no-figures"], capsys)[0] == 2  # no alpha


def test_a_bad_frame_rate_without_times_names_the_key(tmp_path, capsys):
    x1, x2 = scene(32)
    f = measure(x1, x2, polariser_alpha(12), sigma=0.01, rng=0, dtype=np.float32)
    for rate in (0, -12):
        path = atomic_save_npz(tmp_path / f"m{rate}.npz", meta={"scale": 6, "frame_rate_hz": rate}, frames=f)
        rc, _, err = _run([path, "--method", "alternating"], capsys)
        assert rc == 2 and len(err.strip().splitlines()) == 1, err
        assert f"meta.frame_rate_hz = {rate} is invalid" in err and "0 < frame_rate_hz" in err


def test_a_value_from_the_file_is_not_blamed_on_a_flag_the_user_did_not_type(tmp_path, capsys):
    """A 6 x 6 recording with the file's scale 6: the foveal constraint has no room. Untyped, the error names
    ``scale`` and says --scale sets it; typed, it names --scale."""
    x1, x2 = scene(48)
    f = measure(x1, x2, polariser_alpha(24), sigma=0.01, rng=0, dtype=np.float32)[:, :6, :6]
    path, _ = _save(tmp_path / "m.npz", alpha=False, frames=f)
    rc, _, err = _run([path, "--method", "alternating", "--out", tmp_path / "r.npz"], capsys)
    assert rc == 2 and "scale = 6 is invalid" in err and "--scale = 6" not in err and "--scale sets it" in err, err
    rc, _, err = _run([path, "--method", "alternating", "--scale", 4, "--out", tmp_path / "r.npz"], capsys)
    assert rc == 2 and "--scale = 4 is invalid" in err, err
    rc, _, err = _run([path, "--method", "alternating", "--foveal-gain", 0, "--out", tmp_path / "r.npz"], capsys)
    assert rc == 2 and "--foveal-gain = 0 is invalid" in err, err


@pytest.mark.parametrize("method", ["lsq", "alternating"])
def test_a_dead_pixel_prints_no_numpy_warning(tmp_path, capsys, method):
    path, _ = _save(tmp_path / "m.npz", T=12, n=32)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["frames"][:, 3, 4] = np.nan
    np.savez(path, **arrays)
    rc, out, err = _run([path, "--method", method, "--out", tmp_path / "r.npz", "--no-figures"], capsys)
    assert rc == 0, err
    assert "slice" not in err and "RuntimeWarning" not in err, err
    assert "NaN value(s) in x1/x2" in out


def test_an_error_in_the_files_arrays_names_the_file_and_keeps_to_one_short_line(tmp_path, capsys):
    """A NaN alpha was printed as all its 24 values with no file named; a NaN calibration named no file."""
    path, a = _save(tmp_path / "m.npz")
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["alpha"] = np.full(24, np.nan)
    np.savez(tmp_path / "a.npz", **arrays)
    rc, _, err = _run([tmp_path / "a.npz", "--out", tmp_path / "r.npz"], capsys)
    assert rc == 2 and "a.npz: alpha = [nan, nan, nan, nan, ... (24 values)] is invalid" in err, err
    arrays["alpha"] = a
    arrays["calibration"] = np.full((4, 48, 48), np.nan, dtype=np.float32)
    np.savez(tmp_path / "c.npz", **arrays)
    rc, _, err = _run([tmp_path / "c.npz", "--out", tmp_path / "r.npz"], capsys)
    assert rc == 2 and "c.npz: calibration = " in err, err

"""``metafovea import`` on files a camera or a careless script can write: each is one line naming the recording
(or its key) and what is allowed, exit 2, nothing written; a frame axis the user states is honoured for TIFF too.
The files come from tifffile and h5py (the standard writers), never from our importer."""

from __future__ import annotations

import numpy as np
import pytest

tifffile = pytest.importorskip("tifffile")

T, H, W = 24, 12, 16


def _frames() -> np.ndarray:
    rng = np.random.default_rng(3)
    x1, x2 = rng.uniform(1000, 2000, (H, W)), rng.uniform(1000, 2000, (H, W))
    a = np.cos(2 * np.pi * 2 * np.arange(T) / 12 + 0.3) ** 2
    return a[:, None, None] * x1 + (1 - a)[:, None, None] * x2 + rng.normal(0, 2, (T, H, W))


def test_a_directory_or_an_empty_name_is_one_line(tmp_path, cli, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for path in (".", str(tmp_path), ""):
        rc, out, err = cli("import", path, "--frame-rate", 12)
        assert rc == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1
        assert f"recording = '{path}' is invalid" in err and "an existing recording file" in err
    assert not list(tmp_path.iterdir())


def test_frame_axis_last_is_honoured_for_a_tiff_stack(tmp_path, cli):
    f = _frames().astype(np.uint16)
    tifffile.imwrite(tmp_path / "thw.tif", f)
    tifffile.imwrite(tmp_path / "hwt.tif", np.moveaxis(f, 0, -1))  # (H, W, T): 12 x 16 pages of 24 values
    assert cli("import", tmp_path / "thw.tif", "--frame-rate", 12, "--no-preview")[0] == 0
    rc, out, err = cli("import", tmp_path / "hwt.tif", "--frame-rate", 12, "--frame-axis", "last", "--no-preview")
    assert rc == 0, err
    with np.load(tmp_path / "thw.npz") as a, np.load(tmp_path / "hwt.npz") as b:
        assert a["frames"].shape == b["frames"].shape == (T, H, W)
        np.testing.assert_array_equal(a["frames"], b["frames"])


@pytest.mark.parametrize("kind", ["complex", "bool", "one_pixel_wide"])
def test_frames_reconstruct_would_refuse_are_refused_at_import(tmp_path, cli, kind):
    f = _frames()
    data = {"complex": f.astype(np.complex64), "bool": f > 1500, "one_pixel_wide": f[:, :1].astype(np.uint16)}[kind]
    tifffile.imwrite(tmp_path / "r.tif", data)
    rc, out, err = cli("import", tmp_path / "r.tif", "--frame-rate", 12, "--no-preview")
    assert rc == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert "r.tif" in err and not (tmp_path / "r.npz").exists()
    assert {"complex": "complex64", "bool": "bool", "one_pixel_wide": "at least 2 x 2 pixels"}[kind] in err


def test_counts_float32_cannot_hold_are_refused_not_flattened(tmp_path, cli):
    """int64 counts on a 2^40 offset: float32 steps by 131072 there, so the 1000 counts of signal would all become
    one value. Refused, naming the range and the step; the same counts without the offset import exactly."""
    h5py = pytest.importorskip("h5py")
    f = np.round(_frames()).astype(np.int64)
    with h5py.File(tmp_path / "big.h5", "w") as h:
        h["frames"] = f + 2 ** 40
        h["times_s"] = np.arange(T) / 12
    rc, out, err = cli("import", tmp_path / "big.h5", "--no-preview")
    assert rc == 2 and "big.h5" in err and "float32" in err and "1.31e+05" in err, err
    assert not (tmp_path / "big.npz").exists()
    with h5py.File(tmp_path / "small.h5", "w") as h:
        h["frames"] = f
        h["times_s"] = np.arange(T) / 12
    assert cli("import", tmp_path / "small.h5", "--no-preview")[0] == 0
    with np.load(tmp_path / "small.npz") as z:
        np.testing.assert_array_equal(z["frames"], f.astype(np.float32))


def test_a_time_unit_that_is_not_one_is_an_error_and_a_spelled_out_one_is_read(tmp_path, cli):
    h5py = pytest.importorskip("h5py")
    f = _frames().astype(np.uint16)
    for name, unit, scale in (("fort", "fortnights", 1.0), ("ms", "milliseconds", 1000.0)):
        with h5py.File(tmp_path / f"{name}.h5", "w") as h:
            h["frames"] = f
            h.create_dataset("times_s", data=np.arange(T) / 12 * scale).attrs["units"] = unit
    rc, out, err = cli("import", tmp_path / "fort.h5", "--no-preview")
    assert rc == 2 and "fort.h5: times_s.units = 'fortnights' is invalid" in err and "--time-unit" in err
    rc, out, err = cli("import", tmp_path / "ms.h5", "--no-preview")
    assert rc == 0 and "12 Hz" in out, out + err


def test_a_filter_outside_the_band_is_refused_without_a_calibration_too(tmp_path, cli):
    tifffile.imwrite(tmp_path / "r.tif", _frames().astype(np.uint16))
    rc, out, err = cli("import", tmp_path / "r.tif", "--frame-rate", 12, "--filter-um", 100, 0.5, "--no-preview")
    assert rc == 2 and "--filter-um" in err and "inside the band 8-14 um" in err
    assert cli("import", tmp_path / "r.tif", "--frame-rate", 12, "--filter-um", 10, 0.5, "--no-preview")[0] == 0


def test_a_truncated_tiff_is_our_one_line_without_tifffiles_log(tmp_path, cli):
    tifffile.imwrite(tmp_path / "r.tif", _frames().astype(np.uint16))
    (tmp_path / "cut.tif").write_bytes((tmp_path / "r.tif").read_bytes()[:3000])
    rc, out, err = cli("import", tmp_path / "cut.tif", "--frame-rate", 12, "--no-preview")
    # tifffile logs through logging (its last-resort handler writes to sys.stderr, which cli captures)
    assert rc == 2 and "cut.tif" in err and "a readable TIFF stack" in err
    assert "tifffile" not in err and len([ln for ln in err.splitlines() if ln.strip()]) == 1, err


def test_a_file_that_is_no_npz_is_not_called_pickled(tmp_path, capsys):
    from metafovea.cli import main

    (tmp_path / "m.npz").write_text("hello")
    assert main(["reconstruct", str(tmp_path / "m.npz")]) == 2
    err = capsys.readouterr().err
    assert "not an .npz (zip) archive" in err and "pickled" not in err

"""The readers on files of the standard writers: MAT v5 (scipy.io.savemat) and v7.3 (HDF5 with MATLAB's header,
column-major), HDF5 keys found by name or shape, TIFF's ImageJ frame interval, a sidecar file of times, recorded
polariser angles, saturated samples."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.errors import InputError
from metafovea.measurement import Measurement
from metafovea.recordings import ImportOptions, read_recording, to_measurement

h5py = pytest.importorskip("h5py")
tifffile = pytest.importorskip("tifffile")
scipy_io = pytest.importorskip("scipy.io")


@pytest.fixture
def frames():
    return np.random.default_rng(3).integers(1000, 30000, (12, 10, 14)).astype(np.uint16)


def test_mat_v5_matlab_axis_order_and_angles(tmp_path, frames):
    """A MATLAB-style H x W x T video with times and polariser angles in degrees (a uniform 2 Hz rotation): the
    frames come back (T, H, W), the angles as theta_rad, the rotation as the polariser model's rate and phase."""
    t = np.arange(12) / 30.0
    theta_deg = np.rad2deg(0.3 + 2 * np.pi * 2.0 * t)
    scipy_io.savemat(tmp_path / "rec.mat", {"video": np.moveaxis(frames, 0, -1), "t": t, "theta_deg": theta_deg})
    rec = read_recording(tmp_path / "rec.mat", frame_axis="last", polarizer_key="theta_deg")
    np.testing.assert_array_equal(rec.frames, frames)
    assert rec.format == "mat" and rec.frames_key == "video" and rec.times_from == "key t"
    m, s = to_measurement(rec)
    np.testing.assert_allclose(m.extras["theta_rad"], np.deg2rad(theta_deg))
    assert m.meta["polarizer_mode"] == "sync" and m.meta["polarizer_hz"] == pytest.approx(2.0)
    assert m.meta["polarizer_phase_deg"] == pytest.approx(np.rad2deg(0.3)) and s["theta_rad"] and not s["alpha_known"]
    assert s["polarizer"]["mode"] == "sync" and s["polarizer"]["sources"]["phase_deg"] == "file"


def test_mat_v73_is_read_through_hdf5_in_matlab_order(tmp_path, frames):
    path = tmp_path / "rec.mat"
    with h5py.File(path, "w", userblock_size=512) as f:
        f["frames"] = np.moveaxis(frames, 0, -1).T  # MATLAB's H x W x T, as MATLAB writes it (column-major)
        f["times_s"] = (np.arange(12) / 25.0)[None].T
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
    with open(path, "r+b") as fh:
        fh.write(header.ljust(116, b" ") + b"\0" * 8 + b"\x00\x02IM")
    rec = read_recording(path, frame_axis="last")
    np.testing.assert_array_equal(rec.frames, frames)
    np.testing.assert_allclose(rec.times_s, np.arange(12) / 25.0)


def test_hdf5_frames_found_as_the_only_3d_array(tmp_path, frames):
    with h5py.File(tmp_path / "rec.h5", "w") as f:
        f["cam/stack"] = frames
        f["cam/exposure"] = np.ones(12)
        f.attrs["frame_rate_hz"] = 50.0
    rec = read_recording(tmp_path / "rec.h5")
    assert rec.frames_key == "cam/stack" and rec.times_from == "file's frame_rate_hz"
    np.testing.assert_allclose(np.diff(rec.times_s), 0.02)
    with h5py.File(tmp_path / "two.h5", "w") as f:
        f["a"], f["b"] = frames, frames
    with pytest.raises(InputError, match="2 3-D arrays") as e:
        read_recording(tmp_path / "two.h5")
    assert e.value.parameter == "frames_key"


def test_tiff_imagej_interval_and_sidecar_times(tmp_path, frames):
    tifffile.imwrite(tmp_path / "ij.tif", frames, imagej=True, metadata={"axes": "TYX", "finterval": 0.04})
    rec = read_recording(tmp_path / "ij.tif")
    assert rec.times_from == "file's finterval" and rec.times_s[-1] == pytest.approx(11 * 0.04)
    tifffile.imwrite(tmp_path / "plain.tif", frames, photometric="minisblack")
    t = np.arange(12) * 33.0 + 7.0
    np.savetxt(tmp_path / "times.csv", np.c_[t, np.arange(12)], delimiter=",")
    rec = read_recording(tmp_path / "plain.tif", times=str(tmp_path / "times.csv"), time_unit="ms")
    np.testing.assert_allclose(rec.times_s, (t - t[0]) * 1e-3)  # times start at 0
    with pytest.raises(InputError) as e:
        read_recording(tmp_path / "plain.tif", times=str(tmp_path / "missing.csv"))
    assert e.value.parameter == "times"


def test_saturated_samples_are_left_out(tmp_path, frames):
    frames = frames.copy()
    frames[2, 3, 4] = 65535
    tifffile.imwrite(tmp_path / "rec.tif", frames, photometric="minisblack")
    m, s = to_measurement(read_recording(tmp_path / "rec.tif"), ImportOptions(frame_rate_hz=30.0))
    assert np.isnan(m.frames[2, 3, 4]) and np.isfinite(np.delete(m.frames.ravel(), 2 * 140 + 3 * 14 + 4)).all()
    assert m.meta["saturated_samples"] == 1 and any("full scale" in w for w in s["warnings"])
    assert m.invalid_samples()[2, 3, 4]


def test_written_measurement_round_trips(tmp_path, frames):
    from metafovea.recordings import import_recording

    with h5py.File(tmp_path / "rec.h5", "w") as f:
        f["frames"], f["alpha"] = frames, np.linspace(0, 1, 12)
    out, s = import_recording(tmp_path / "rec.h5", options=ImportOptions(frame_rate_hz=12.0,
                                                                         polarizer_key="alpha"))
    m = Measurement.load(out)
    assert m.alpha_known and m.shape == (12, 10, 14) and m.meta["source"]["format"] == "hdf5"
    assert m.meta["frame_rate_hz"] == pytest.approx(12.0)


def test_an_unreadable_mat_file_is_one_error_naming_it(tmp_path):
    bad = tmp_path / "broken.mat"
    bad.write_bytes(b"not a MAT file at all" * 20)
    with pytest.raises(InputError, match="broken.mat") as e:
        read_recording(bad)
    assert "MAT file" in str(e.value)

"""``metafovea import`` end to end: files written by the standard writers (tifffile, h5py, scipy.io.savemat) from a
known synthetic sequence go through import and ``metafovea reconstruct``; the separated images come back in kelvin.

Tolerance: the LSQ separation's per-pixel noise, predicted from the frames' noise and the windows' alpha
(``predicted_noise_k``, ~0.1 K here), sets the scale. The RMS temperature error over the image must be below that
prediction (an RMS over 2304 pixels of a noise with that standard deviation is below it with overwhelming
probability when the errors are noise and nothing else) plus, for the Planck curve, the fit error the import
reports (the band model vs FLIR's one-wavelength curve), plus 20 mK for the two-point calibration's own noise
(8 blackbody frames per point: 2 DN / sqrt(8) = 0.7 DN per pixel = 14 mK at 50 DN/K)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from metafovea.measurement import Measurement
from metafovea.reconstruct import Reconstruction
from metafovea.reconstruct.deconvolve import temperatures

tifffile = pytest.importorskip("tifffile")


def _kelvin_rms(rec_path, meas_path, truth):
    """RMS (K) of each channel's temperature video (the recipe: reconstruction images through the file's
    calibration) against the truth."""
    m = Measurement.load(meas_path)
    r = Reconstruction.load(rec_path)
    tk = temperatures((r.x1, r.x2), m.meta["dark_dn"], m.meta)
    return [float(np.sqrt(np.mean((t - ref) ** 2))) for t, ref in zip(tk, (truth.T1, truth.T2))]


def test_tiff_stack_two_point_to_kelvin(tmp_path, cli, camera_constants, truth, linear_camera):
    """A 16-bit TIFF stack with alpha in its JSON description, timed by --frame-rate, calibrated per pixel by two
    blackbodies: reconstruct (LSQ) gives both channels within the noise in kelvin; --deconvolve (a delta PSF)
    reads the same calibration."""
    rec, cold, hot = tmp_path / "rec.tif", tmp_path / "cold.tif", tmp_path / "hot.tif"
    tifffile.imwrite(rec, linear_camera.frames, metadata={"alpha": truth.alpha.tolist()}, photometric="minisblack")
    tifffile.imwrite(cold, linear_camera.blackbody[293.15], photometric="minisblack")
    tifffile.imwrite(hot, linear_camera.blackbody[323.15], photometric="minisblack")
    rc, out, err = cli("import", rec, "--frame-rate", camera_constants.FPS, "--polarizer-key", "alpha",
                           "--calibration", f"two-point:293.15={cold},323.15={hot}", "--json")
    assert rc == 0, err
    s = json.loads(out)
    assert s["frames"] == 24 and s["alpha_known"] and s["calibration"]["method"] == "two-point per-pixel"
    assert s["n_dropped"] == 0 and s["duplicates_removed"] == 0 and s["uniform_timing"] and not err
    meas = tmp_path / "rec.npz"
    m = Measurement.load(meas)
    assert m.meta["units"] == "DN"
    assert m.meta["dn_per_k_300K"]["x1"] == pytest.approx(camera_constants.DN_PER_K, rel=0.01)
    np.savez(tmp_path / "delta.npz", psf_x1=np.ones((1, 1)), psf_x2=np.ones((1, 1)))
    rc, out, err = cli("reconstruct", meas, "--no-figures", "--json", "--deconvolve", "wiener",
                           "--psf", tmp_path / "delta.npz")
    assert rc == 0, err
    tol = camera_constants.predicted_noise_k(truth.alpha) + 0.02
    rms = _kelvin_rms(tmp_path / "rec_rec.npz", meas, truth)
    assert max(rms) < tol, (rms, tol)
    with np.load(tmp_path / "rec_rec_scene.npz") as z:
        for k, ref in (("temperature_x1_k", truth.T1), ("temperature_x2_k", truth.T2)):
            assert np.sqrt(np.mean((z[k] - ref) ** 2)) < tol


def test_hdf5_with_planck_constants_to_kelvin(tmp_path, cli, camera_constants, truth, flir_camera):
    """An HDF5 recording with FLIR's Planck constants as attributes, timestamps in ms (a 'units' attribute) and
    alpha: the file's constants are used; temperatures within the noise plus the reported fit error."""
    h5py = pytest.importorskip("h5py")
    rec = tmp_path / "rec.h5"
    with h5py.File(rec, "w") as f:
        ds = f.create_dataset("camera/frames", data=flir_camera.frames)
        ds.attrs.update(camera_constants.FLIR)
        f.create_dataset("camera/timestamps", data=1e3 * truth.times).attrs["units"] = "ms"
        f.create_dataset("camera/alpha", data=truth.alpha)
    rc, out, err = cli("import", rec, "--times", "camera/timestamps", "--polarizer-key", "camera/alpha",
                           "--band-um", 7.5, 13.5, "--json")
    assert rc == 0, err
    s = json.loads(out)
    assert s["frame_rate_hz"] == pytest.approx(camera_constants.FPS) and s["calibration"]["method"] == "planck"
    fit = s["calibration"]["fit_max_error_k"]
    assert fit < 0.2  # FLIR's curve against a 7.5-13.5 um band (0.28 K against 8-14 um)
    meas = tmp_path / "rec.npz"
    rc, _, err = cli("reconstruct", meas, "--no-figures", "--json")
    assert rc == 0, err
    slope = Measurement.load(meas).meta["dn_per_k_300K"]["x1"]
    tol = camera_constants.predicted_noise_k(truth.alpha, slope) + fit
    rms = _kelvin_rms(tmp_path / "rec_rec.npz", meas, truth)
    assert max(rms) < tol, (rms, tol)


def test_planck_flag_overrides_and_matches_the_file(tmp_path, cli, camera_constants, flir_camera, truth):
    """--planck R,B,F,O (R = R1 / R2) gives the file's calibration on a TIFF stack that has none."""
    rec = tmp_path / "rec.tif"
    tifffile.imwrite(rec, flir_camera.frames, metadata={"times_s": truth.times.tolist()}, photometric="minisblack")
    R = camera_constants.FLIR["PlanckR1"] / camera_constants.FLIR["PlanckR2"]
    planck = f"{R},{camera_constants.FLIR['PlanckB']},1,{camera_constants.FLIR['PlanckO']}"
    rc, out, err = cli("import", rec, "--planck", planck, "--json")
    assert rc == 0, err
    s = json.loads(out)
    assert s["times_from"] == "key times_s" and s["calibration"]["method"] == "planck"
    m = Measurement.load(tmp_path / "rec.npz")
    assert m.meta["calibration"]["planck"]["from"] == "given"
    # default band 8-14 um: the fit is poorer and the import says so
    assert any("--band-um" in w for w in s["warnings"]) == (s["calibration"]["fit_max_error_k"] > 0.25)


def test_no_calibration_keeps_counts(tmp_path, cli, linear_camera):
    rec = tmp_path / "rec.tif"
    tifffile.imwrite(rec, linear_camera.frames, photometric="minisblack")
    rc, out, err = cli("import", rec, "--frame-rate", 30)
    assert rc == 0, err
    m = Measurement.load(tmp_path / "rec.npz")
    assert m.meta["units"] == "counts" and "dn_per_k_300K" not in m.meta
    np.testing.assert_array_equal(m.frames, linear_camera.frames.astype(np.float32))
    assert "no kelvin" in out
    # the preview: the frames and, with no truth, their mean and spread per pixel, colour bars in the file's counts
    from metafovea.imaging.simulate import preview_figure

    assert (tmp_path / "rec_preview.png").read_bytes()[:4] == b"\x89PNG" and "rec_preview.png" in out
    fig = preview_figure(m)
    bars = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert len(bars) == 6 and all(ax.get_ylabel() == "counts" for ax in bars)
    assert any(ax.get_title().startswith("spread (std)") for ax in fig.axes)


@pytest.mark.parametrize("argv, flag", [
    (["missing.tif", "--frame-rate", "30"], "missing.tif"),
    (["rec.tif"], "--frame-rate"),
    (["rec.h5", "--frames-key", "nope"], "--frames-key"),
    (["rec.h5", "--times", "nope"], "--times"),
    (["rec.h5", "--polarizer-key", "nope"], "--polarizer-key"),
    (["rec.tif", "--frame-rate", "30", "--calibration", "blackbody:300=a.tif"], "--calibration"),
    (["rec.tif", "--frame-rate", "30", "--calibration", "two-point:293=cold.tif,323=gone.tif"], "gone.tif"),
    (["rec.tif", "--frame-rate", "30", "--calibration", "two-point:293=cold.tif,293.5=cold.tif"], "--calibration"),
    (["rec.tif", "--frame-rate", "30", "--planck", "1,2,3"], "--planck"),
    (["rec.tif", "--frame-rate", "-4"], "--frame-rate"),
    (["rec.tif", "--frame-rate", "30", "--out", "rec.txt"], "--out"),
    (["rec.bin", "--frame-rate", "30"], "--format"),
    (["rec.tif", "--frame-rate", "30", "--scale", "nan"], "--scale"),
    (["rec.tif", "--frame-rate", "30", "--scale", "0.5"], "--scale"),
    (["rec.tif", "--frame-rate", "30", "--filter-um", "10", "nan"], "--filter-um width"),  # it named filter_um
])
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, cli, monkeypatch, argv, flag, linear_camera):
    h5py = pytest.importorskip("h5py")
    monkeypatch.chdir(tmp_path)
    tifffile.imwrite("rec.tif", linear_camera.frames[:4], photometric="minisblack")
    tifffile.imwrite("cold.tif", linear_camera.frames[:2], photometric="minisblack")
    (tmp_path / "rec.bin").write_bytes(b"\0" * 64)
    with h5py.File("rec.h5", "w") as f:
        f["frames"] = linear_camera.frames[:4]
        f["times_s"] = np.arange(4) / 30.0
    before = set(tmp_path.iterdir())
    rc, out, err = cli("import", *argv)
    assert rc == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and flag in err, err
    assert set(tmp_path.iterdir()) == before


def test_existing_output_needs_force(tmp_path, cli, linear_camera):
    rec = tmp_path / "rec.tif"
    tifffile.imwrite(rec, linear_camera.frames[:4], photometric="minisblack")
    assert cli("import", rec, "--frame-rate", 30)[0] == 0
    rc, _, err = cli("import", rec, "--frame-rate", 30)
    assert rc == 2 and "--force" in err
    assert cli("import", rec, "--frame-rate", 30, "--force")[0] == 0
    # an existing preview alone is refused too, before anything is written; --no-preview writes none
    (tmp_path / "rec.npz").unlink()
    rc, _, err = cli("import", rec, "--frame-rate", 30)
    assert rc == 2 and "preview" in err and "--force" in err and not (tmp_path / "rec.npz").exists()
    assert cli("import", rec, "--frame-rate", 30, "--out", tmp_path / "n.npz", "--no-preview")[0] == 0
    assert (tmp_path / "n.npz").exists() and not (tmp_path / "n_preview.png").exists()


def test_a_free_running_recording_imported_from_tiff_reconstructs_as_simulated(tmp_path, cli):
    """The simulator's TIFF stack (frames only: no alpha, no polariser, no truth, no foveal relation) imported with
    the camera's rate and the polariser's (``--frame-rate 12 --polarizer-hz 2``, free-running: phase unknown)
    reconstructs with unknown alpha to the simulated file's alpha MAE: the file's keys say what the frames need,
    nothing else counts, and the calibration finds the channels the stated relation (gain 1) would swap. The sensor's
    fixed pattern is off: a TIFF carries no shutter frames (with an uncorrected pattern the summary says the foveal
    relation does not hold)."""
    rc, out, err = cli("simulate", "--scene", "rooftop", "--frames", "24", "--polarizer", "free", "--pixel-um", "24",
                       "--calibration-frames", "0", "--psf", "airy", "--fpn-rank", "0", "--no-preview",
                       "--out", tmp_path / "sim.npz", "--json")
    assert rc == 0, err
    sim = Measurement.load(tmp_path / "sim.npz")
    rc, out, err = cli("import", tmp_path / "sim.tif", "--frame-rate", "12", "--polarizer-hz", "2",
                       "--polarizer-mode", "free", "--out", tmp_path / "imp.npz", "--json")
    assert rc == 0, err
    s = json.loads(out)
    assert s["polarizer"]["rate_hz"] == 2.0 and s["polarizer"]["sources"]["rate_hz"] == "given"
    imp = Measurement.load(tmp_path / "imp.npz")
    assert imp.meta["polarizer_hz"] == 2.0 and imp.meta["polarizer_mode"] == "free" and imp.alpha is None
    maes = []
    for name in ("sim", "imp"):
        rc, out, err = cli("reconstruct", tmp_path / f"{name}.npz", "--method", "alternating", "--window", "24",
                           "--no-figures", "--json", "--no-score")
        assert rc == 0, err
        rec = Reconstruction.load(tmp_path / f"{name}_rec.npz")
        maes.append(float(np.mean(np.abs(rec.alpha - sim.alpha))))
        assert json.loads(out)["polarizer"]["model"]["sources"]["rate_hz"] == "file"
    assert maes[0] < 2e-3 and maes[1] < 2e-3 and abs(maes[1] - maes[0]) < 2e-4, maes


def test_a_14_bit_cameras_full_scale_is_saturated_with_adc_bits(tmp_path, cli):
    """A 14-bit camera's counts in a 16-bit TIFF: its full scale, 16383, is not the file type's 65535, so without
    `--adc-bits` nothing was left out and its clipped samples biased the separation ("the polariser is stopped...");
    `--adc-bits 14` leaves them out, counted and said. A bit count outside 1-32 is one line naming the flag."""
    import tifffile

    rng = np.random.default_rng(0)
    frames = rng.integers(1500, 9000, (12, 16, 20)).astype(np.uint16)
    frames[0:4, :, :10] = 16383
    tifffile.imwrite(tmp_path / "rec.tif", frames, photometric="minisblack")
    rc, out, err = cli("import", tmp_path / "rec.tif", "--frame-rate", 12, "--out", tmp_path / "a.npz", "--json")
    assert rc == 0, err
    assert Measurement.load(tmp_path / "a.npz").meta["saturated_samples"] == 0
    rc, out, err = cli("import", tmp_path / "rec.tif", "--frame-rate", 12, "--adc-bits", 14, "--out",
                       tmp_path / "b.npz", "--json")
    assert rc == 0, err
    m = Measurement.load(tmp_path / "b.npz")
    assert m.meta["saturated_samples"] == 4 * 16 * 10 and np.isnan(m.frames[0:4, :, :10]).all()
    assert np.isfinite(m.frames[4:]).all() and "14-bit full scale (16383)" in out
    for bad in (0, 33):
        rc, _, err = cli("import", tmp_path / "rec.tif", "--frame-rate", 12, "--adc-bits", bad, "--out",
                         tmp_path / f"c{bad}.npz")
        assert rc == 2 and "--adc-bits" in err and len(err.strip().splitlines()) == 1, err


def test_adc_bits_also_masks_the_blackbody_frames(tmp_path, cli, camera_constants, truth, linear_camera):
    """`--adc-bits` is the camera's: a blackbody frame clipped at the 14-bit full scale is left out of that pixel's
    mean as a recording frame is, so the pixel's two-point calibration stays within a tenth of the bias the clipped
    sample gives when it is counted (it was counted: only the recording's frames were masked)."""
    rec, cold, hot, hot_clip = (tmp_path / n for n in ("rec.tif", "cold.tif", "hot.tif", "hot_clip.tif"))
    tifffile.imwrite(rec, linear_camera.frames, metadata={"alpha": truth.alpha.tolist()}, photometric="minisblack")
    tifffile.imwrite(cold, linear_camera.blackbody[293.15], photometric="minisblack")
    bb = np.array(linear_camera.blackbody[323.15])
    assert bb.ndim == 3 and bb.shape[0] > 1 and bb.max() < 16383
    tifffile.imwrite(hot, bb, photometric="minisblack")
    bb[0, 3, 4] = 16383
    tifffile.imwrite(hot_clip, bb, photometric="minisblack")
    px = {}
    for name, h, bits in (("clean", hot, ["--adc-bits", 14]), ("masked", hot_clip, ["--adc-bits", 14]),
                          ("counted", hot_clip, [])):
        rc, _, err = cli("import", rec, "--frame-rate", camera_constants.FPS, "--polarizer-key", "alpha", *bits,
                         "--calibration", f"two-point:293.15={cold},323.15={h}", "--out", tmp_path / f"{name}.npz")
        assert rc == 0, err
        px[name] = Measurement.load(tmp_path / f"{name}.npz").frames[:, 3, 4].astype(np.float64)
    bias = np.abs(px["counted"] - px["clean"]).max()
    assert bias > 1.0 and np.abs(px["masked"] - px["clean"]).max() < 0.1 * bias

"""The Measurement file and its metadata (metafovea/measurement.py, the one reader of both): every array checked
against the frames with the file named, damaged files refused, the foveal constraint's fallbacks."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from metafovea.config import SensorDesign, SystemDesign
from metafovea.errors import InputError
from metafovea.imaging import simulate
from metafovea.io import atomic_save_npz
from metafovea.measurement import FovealConstraint, Measurement


def small_system(n: int = 48, **sensor_kw) -> SystemDesign:
    return replace(SystemDesign.paper(), sensor=replace(SensorDesign(), crop=(n, n), **sensor_kw))


def delta_psf() -> dict:
    return {"foveal": np.ones((1, 1)), "perifoveal": np.ones((1, 1))}


def _arrays(T: int = 4, n: int = 16, **over) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    arrays = {"frames": rng.random((T, n, n)).astype(np.float32), "times_s": np.arange(T) / 12.0,
              "alpha": np.linspace(0.1, 0.9, T), "truth_x1": rng.random((n, n)).astype(np.float32),
              "truth_x2": rng.random((n, n)).astype(np.float32)}
    for k, v in over.items():
        if v is None:
            arrays.pop(k, None)
        else:
            arrays[k] = v
    return arrays


def _file(path, meta=None, **over):
    atomic_save_npz(path, meta={"scale": 6.0} if meta is None else meta, **_arrays(**over))
    return path


def test_measurement_roundtrip_and_no_clobber(tmp_path):
    s = small_system(24)
    m = simulate(s, "bars", frames=3, psf=delta_psf(), supersample=1, fpn_drift=0.1, rng=2)
    p = m.save(tmp_path / "m.npz")
    r = Measurement.load(p)
    assert np.array_equal(r.frames, m.frames) and np.array_equal(r.alpha, m.alpha)
    assert r.frames.dtype == np.float32 and r.meta["scale"] == 6.0 and r.meta["units"] == "DN"
    np.testing.assert_allclose(r.fpn_frame(2), m.fpn_frame(2), rtol=1e-5, atol=1e-3)
    assert r.source == str(p) and m.source is None  # the file it was read from
    with pytest.raises(InputError, match="force"):
        m.save(tmp_path / "m.npz")
    m.save(tmp_path / "m.npz", force=True)
    with pytest.raises(InputError):
        Measurement.load(tmp_path / "absent.npz")
    with pytest.raises(InputError, match="alpha"):
        Measurement(frames=np.zeros((2, 4, 4)), times_s=[0, 1], alpha=[0.5])


@pytest.mark.parametrize("damage", ["empty", "truncated", "garbage", "text"])
def test_damaged_files_are_input_errors(tmp_path, damaged, damage):
    good = _file(tmp_path / "good.npz")
    with pytest.raises(InputError) as e:
        Measurement.load(damaged(good, tmp_path / "bad.npz", damage))
    assert e.value.parameter == "measurement"


@pytest.mark.parametrize("kind", ["object", "badjson", "listjson", "noframes"])
def test_files_that_are_not_measurements(tmp_path, kind):
    p = tmp_path / "x.npz"
    if kind == "object":
        np.savez(p, frames=np.array([{"a": 1}], dtype=object))
    elif kind == "noframes":
        atomic_save_npz(p, meta={}, images=np.ones((4, 8, 8)))
    else:
        meta = b"{not json" if kind == "badjson" else b"[1, 2]"
        np.savez(p, frames=np.ones((4, 16, 16), np.float32), __meta__=np.frombuffer(meta, np.uint8))
    with pytest.raises(InputError) as e:
        Measurement.load(p)
    assert e.value.parameter == "measurement" and str(p) in str(e.value)


@pytest.mark.parametrize("key, value, match", [
    ("truth_x1", np.ones((5, 5), np.float32), "truth_x1"),
    ("truth_x2", np.ones((3, 16, 16), np.float32), "truth_x2"),  # 3 truth frames for 4 frames
    ("truth_x1", np.full((16, 16), np.nan, np.float32), "NaN"),
    ("alpha", np.array(0.5), "one real mixing ratio per frame"),
    ("alpha", np.linspace(0.1, 0.9, 4).astype(complex), "one real mixing ratio per frame"),
    ("alpha", np.array([0.1, 0.2, 1.5, 0.3]), r"\[0, 1\]"),
    ("fpn", np.ones((4, 4), np.float32), "fpn"),
    ("fpn", np.where(np.eye(16) > 0, np.nan, 0.0).astype(np.float32), "finite fixed pattern"),
    ("calibration", np.zeros((4, 3, 3), np.float32), "calibration"),
    ("frames", np.full((4, 16, 16), np.nan, np.float32), "no finite value"),
    # each of these was read as it came (found by tampering with a simulated file's arrays): a traceback in
    # reconstruct (float('abc'), an index error on a 1-D kernel, an SVD that did not converge, int(nan)) or a silent
    # answer (a complex PSF cast to real with a warning, exit 0)
    ("psf_x1", np.array(["abc"] * 3), "real numbers"),
    ("psf_x1", np.ones(9), "square kernel of odd size"),
    ("psf_x2", np.ones((3, 3), complex), "real numbers"),
    ("psf_x2", np.full((3, 3), np.inf), "finite values >= 0"),
    ("psf_x2", np.full((3, 3), 1e300), "at most 1e\\+30"),
    ("illumination_x1", np.full((16, 16), 1e300), "at most 1e\\+30"),
    ("flat_field", np.full((16, 16), 1e300), "at most 1e\\+30"),  # divided out: images of 1e-297, exit 0
    ("psf_patches_x1", np.array(["abc"] * 3), "real numbers"),
    ("illumination_x1", np.full((16, 16), np.inf), "finite relative illumination"),
    ("illumination_x2", np.ones((8, 8)), "real values of"),
    ("bad_pixels", np.full((16, 16), np.nan), "an \\(H, W\\)"),
    ("bad_pixels", np.ones((16, 16), bool), "leaves pixels"),
    ("theta_rad", np.zeros(3), "one per frame"),
    ("theta_rad", np.array(["a", "b", "c", "d"]), "one per frame"),
    ("frames", np.ones((2, 3, 4, 5), np.float32), "frames"),
    ("times_s", np.arange(3.0), "times_s"),
    # out of order or repeated: the polariser model took them as they were (decreasing times, the free-running
    # polariser's fit: x1 at -54 dB, exit 0)
    ("times_s", np.arange(4.0)[::-1].copy(), "strictly increasing"),
    ("times_s", np.zeros(4), "strictly increasing"),
])
def test_arrays_that_do_not_fit_the_frames_name_the_file_and_the_key(tmp_path, key, value, match):
    """The reconstruct command re-checked the file with its own rules; Measurement.load now does, and says which
    file and which key."""
    p = _file(tmp_path / "m.npz", **{key: value})
    with pytest.raises(InputError, match=match) as e:
        Measurement.load(p)
    assert e.value.parameter == key and e.value.source == str(p)


def test_frames_all_beyond_the_adcs_range_name_the_range(tmp_path):
    """Every sample at or beyond the ADC's floor or full scale: the reconstruction said 'sigma = nan'."""
    p = _file(tmp_path / "m.npz", meta={"scale": 6.0, "floor_dn": 0.0, "saturation_dn": 16383.0},
              frames=-np.ones((4, 16, 16), np.float32))
    with pytest.raises(InputError, match="floor_dn = 0.0 and meta.saturation_dn = 16383.0") as e:
        Measurement.load(p)
    assert e.value.parameter == "frames" and e.value.source == str(p)
    # beyond float32's range: inf (masked), without an overflow warning as a second line before the error
    import warnings

    p = _file(tmp_path / "h.npz", meta={"scale": 6.0, "floor_dn": 0.0, "saturation_dn": 16383.0},
              frames=np.full((4, 16, 16), 1e300))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError, match="ADC's range"):
            Measurement.load(p)


def test_times_without_a_frame_rate_are_an_error_naming_the_file(tmp_path):
    """A file without times_s took 12 frames/s (the paper's camera) when its metadata stated no frame rate."""
    p = _file(tmp_path / "m.npz", meta={"scale": 6.0}, times_s=None)
    with pytest.raises(InputError) as e:
        Measurement.load(p)
    assert e.value.parameter == "times_s" and e.value.source == str(p) and "frame_rate_hz" in e.value.allowed


def test_optional_arrays_and_defaults(tmp_path):
    """Without times_s the frame rate gives the times; NaN alpha means unknown; a video truth is accepted."""
    p = _file(tmp_path / "m.npz", meta={"frame_rate_hz": 10.0}, times_s=None,
              alpha=np.array([0.1, np.nan, 0.5, 0.7]), truth_x1=np.ones((4, 16, 16)))
    m = Measurement.load(p)
    assert np.allclose(m.times_s, np.arange(4) / 10.0) and not m.alpha_known
    assert m.truth_x1.shape == (4, 16, 16) and m.truth_x1.dtype == np.float32


def test_truth_over_averages_a_video_truth_over_each_outputs_frames():
    T, n = 6, 8
    t1 = np.arange(T, dtype=np.float32)[:, None, None] * np.ones((T, n, n), np.float32)
    m = Measurement(frames=np.ones((T, n, n)), times_s=np.arange(T), truth_x1=t1, truth_x2=np.ones((n, n)))
    x1, x2 = m.truth_over([(0, 2), (3, 6)])
    assert x1.shape == (2, n, n) and np.allclose(x1[:, 0, 0], [0.5, 4.0]) and x1.dtype == np.float64
    assert x2.shape == (n, n)  # a static truth as stored
    assert Measurement(frames=np.ones((T, n, n)), times_s=np.arange(T)).truth_over([(0, 1)]) == (None, None)


def test_foveal_constraint_fallbacks_and_explicit_values():
    """One reader of meta['foveal_constraint']: the file's values, then meta['scale'] with gain 1 and offset 0,
    then scale 6; explicit values win."""
    meta = {"scale": 6.0, "foveal_constraint": {"scale": 6.0, "gain": 0.3, "offset_dn": 700.0, "relation": "..."}}
    assert FovealConstraint.from_meta(meta).as_kwargs() == {"scale": 6.0, "foveal_gain": 0.3, "foveal_offset": 700.0}
    assert FovealConstraint.from_meta({"scale": 5.0}).as_kwargs() == {"scale": 5.0, "foveal_gain": 1.0,
                                                                      "foveal_offset": 0.0}
    assert FovealConstraint.from_meta({}) == FovealConstraint(6.0, 1.0, 0.0)
    assert FovealConstraint.from_meta(meta, gain=0.5).gain == 0.5
    m = Measurement(frames=np.ones((2, 8, 8)), times_s=[0, 1], meta=meta)
    assert m.foveal_constraint == FovealConstraint(6.0, 0.3, 700.0) and m.scale == 6.0
    for bad in ({"foveal_constraint": {"gain": -1}}, {"foveal_constraint": {"gain": "x"}},
                {"foveal_constraint": [1, 2]}, {"foveal_constraint": {"scale": 0.5}}):
        with pytest.raises(InputError):
            FovealConstraint.from_meta(bad)
    with pytest.raises(InputError) as e:
        FovealConstraint.from_meta({}, scale=1e9)
    assert e.value.parameter == "scale"


def test_the_reconstructions_metadata_is_read_here(tmp_path):
    """What the PSF-aware reconstruction reads from a file's metadata comes through the Measurement's accessors: the
    simulator's values when it wrote them, the documented defaults when a file (a real recording) has none."""
    m = simulate(small_system(24), "bars", frames=3, psf=delta_psf(), supersample=1, rng=2)
    m = Measurement.load(m.save(tmp_path / "m.npz"))
    meta = m.meta
    assert m.dark_dn == meta["dark_dn"] and m.recorded_scale == meta["scale"] == 6.0
    assert m.channel_gains == (meta["channel_gain"]["x1"], meta["channel_gain"]["x2"])
    assert m.psf_pedestals == tuple(meta["psf"]["pixel"][f"x{i}"]["pedestal"] for i in (1, 2))
    assert m.valid_range_dn == (0.0, 2.0 ** meta["sensor"]["adc_bits"] - 1) and m.fpn_rank == meta["sensor"]["fpn_rank"]
    sen = meta["sensor"]
    assert m.true_noise_dn == pytest.approx(np.sqrt(sen["noise_sigma_dn"] ** 2 + 1 / 12))  # quantised: ADC's 1/12
    cal = m.radiometric_calibration
    assert cal.dn_per_k_300k == (meta["dn_per_k_300K"]["x1"], meta["dn_per_k_300K"]["x2"])
    assert cal.dl_dt_300k == meta["radiometry"]["dL_dT_300K"]
    # 300 K in, 300 K out: a uniform 300 K scene is dark_dn + L(300 K) / (dL/dT) x DN per kelvin
    from metafovea.radiometry import BandRadiance

    L300 = BandRadiance.from_band(cal.band_um, filter_um=cal.filter_um)(300.0)
    dn = [m.dark_dn + L300 / cal.dl_dt_300k * g for g in cal.dn_per_k_300k]
    np.testing.assert_allclose(cal.temperatures(dn, m.dark_dn), [300.0, 300.0], atol=1e-6)
    assert m.scene_truth is not None and m.scene_truth[0].shape == m.shape[1:]
    bare = Measurement(frames=m.frames, times_s=m.times_s)
    assert (bare.dark_dn, bare.channel_gains, bare.recorded_scale, bare.psf_pedestals) == (0.0, (1.0, 1.0), None,
                                                                                           (0.0, 0.0))
    assert bare.true_noise_dn is None and bare.radiometric_calibration is None and bare.scene_truth is None
    assert bare.scale == 6.0  # the foveal constraint's default, not a stated scale


#: a recording's documented keys with their values as a camera's file would state them
GOOD_META = {"units": "DN", "frame_rate_hz": 12.0, "pixel_pitch_um": 17.0, "netd_k": 0.05, "scale": 6.0,
             "dark_dn": 1000.0, "saturation_dn": 16383.0, "floor_dn": 0.0, "channel_gain": {"x1": 0.09, "x2": 0.31},
             "dn_per_k_300K": {"x1": 3.6, "x2": 12.4}, "fpn_rank": 20, "psf_pedestal": {"x1": 0.04, "x2": 1e-5},
             "radiometry": {"band_um": [8.0, 14.0], "filter": None, "dL_dT_300K": 0.84}}


@pytest.mark.parametrize("key, value", [
    # each was read as it came: a traceback (float('abc'), a float's .get, float division by zero) or a silent
    # answer (nan, inf and negative gains, rates and pitches gave exit 0); found by tampering with a file's keys
    ("units", 3.0), ("frame_rate_hz", float("nan")), ("frame_rate_hz", -12.0), ("pixel_pitch_um", 0.0),
    ("netd_k", "abc"), ("scale", float("inf")), ("scale", 0.5), ("dark_dn", [1, 2]), ("dark_dn", True),
    ("saturation_dn", "abc"), ("floor_dn", 1e300), ("channel_gain", 0.5), ("channel_gain.x2", 0.0),
    ("channel_gain.x1", None), ("dn_per_k_300K.x1", "abc"), ("dn_per_k_300K", {"x1": 3.6}), ("fpn_rank", 2.5),
    ("fpn_rank", -1), ("psf_pedestal.x1", float("nan")), ("radiometry", [8, 14]), ("radiometry.band_um", None),
    ("radiometry.band_um", [14.0, 8.0]), ("radiometry.band_um", [8.0, float("inf")]),
    ("radiometry.filter", [10.0, -0.5]), ("radiometry.filter", "10um"), ("radiometry.dL_dT_300K", 0.0),
])
def test_a_tampered_documented_key_names_the_file_and_the_key(tmp_path, key, value):
    """Every documented key of the recording schema is checked on reading, against its type and range: one
    InputError naming the file and the key (``meta.KEY``), never a traceback in the reconstruction or a silent
    answer. The untampered file reads; null stays 'not stated' where the schema has a default."""
    import copy

    assert Measurement.load(_file(tmp_path / "good.npz", meta=GOOD_META)).meta["netd_k"] == 0.05
    meta = copy.deepcopy(GOOD_META)
    top, _, sub = key.partition(".")
    if sub:
        meta[top][sub] = value
    else:
        meta[top] = value
    # written as another program would (json.dumps writes NaN and Infinity; our writer would store null)
    p = tmp_path / "m.npz"
    np.savez(p, __meta__=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **_arrays())
    with pytest.raises(InputError) as e:
        Measurement.load(p)
    assert e.value.parameter.startswith(f"meta.{top}") and e.value.source == str(p)
    assert str(p) in str(e.value) and "\n" not in str(e.value)
    # null where the schema has a default (the whole key, a gain's channel left out) is 'not stated'
    meta = copy.deepcopy(GOOD_META)
    meta[top] = None
    m = Measurement.load(_file(tmp_path / "null.npz", meta=meta))
    assert m.radiometric_calibration is None or top not in ("radiometry", "dn_per_k_300K")
    assert Measurement.load(_file(tmp_path / "one.npz", meta={**GOOD_META, "channel_gain": {"x1": 0.2}})
                            ).channel_gains == (0.2, 1.0)


def test_a_tampered_key_through_reconstruct_is_one_line_and_exit_2(tmp_path, capsys):
    """The command that reads the file: one line naming the file and the key, exit 2 (it was a traceback)."""
    from metafovea.cli import main

    p = _file(tmp_path / "m.npz", meta={**GOOD_META, "channel_gain": {"x1": 0.09, "x2": "abc"}})
    rc = main(["reconstruct", str(p), "--method", "lsq", "--out", str(tmp_path / "r.npz")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "meta.channel_gain.x2" in err[0] and str(p) in err[0]


def test_a_kernels_rounding_residue_is_zero_and_a_negative_value_is_not():
    """The simulator's reduced model writes a kernel with -1.6e-17 in it (FFT resampling): read as 0, where -1e-3 of
    the peak is an error."""
    from metafovea.measurement import check_kernel

    k = np.zeros((3, 3))
    k[1, 1], k[0, 0] = 1.0, -1.6e-17
    assert check_kernel("psf_x1", k).min() == 0.0
    k[0, 0] = -1e-3
    with pytest.raises(InputError, match="finite values >= 0"):
        check_kernel("psf_x1", k)

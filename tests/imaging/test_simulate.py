"""metafovea.imaging.simulate: the end-to-end simulation (mixture form, the 6x foveal relation, seeds, video,
calibration frames, memory check) and simulate_to_files."""

from __future__ import annotations

import importlib
from pathlib import Path

import numpy as np
import pytest

from metafovea.config import SystemDesign
from metafovea.errors import InputError
from metafovea.imaging import simulate, simulate_to_files
from metafovea.measurement import Measurement

sim = importlib.import_module("metafovea.imaging.simulate")  # the package exports a function of that name


def _downsample(x: np.ndarray, s: int) -> np.ndarray:
    H, W = x.shape
    return x[: H // s * s, : W // s * s].reshape(H // s, s, W // s, s).mean(axis=(1, 3))


def _centre_crop(x: np.ndarray, h: int) -> np.ndarray:
    H = x.shape[0]
    y0 = (H - h) // 2
    return x[y0:y0 + h, y0:y0 + h]


# ---------------------------------------------------------------------------------------------
# physics: the mixture and the foveal relation
# ---------------------------------------------------------------------------------------------
def test_alpha_one_is_foveal_and_alpha_zero_is_perifoveal(small_system, gauss_psf, quiet):
    s = small_system()
    m = simulate(s, "camera", frames=4, psf=gauss_psf(), supersample=1, polarizer_phase_deg=0.0, **quiet)
    assert m.alpha[0] == pytest.approx(1.0)
    np.testing.assert_allclose(m.frames[0], m.truth_x1, rtol=1e-6)
    m0 = simulate(s, "camera", frames=2, psf=gauss_psf(), supersample=1, polarizer_phase_deg=90.0, **quiet)
    assert m0.alpha[0] == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(m0.frames[0], m0.truth_x2, rtol=1e-6)
    # every frame is the mixture (float32 arithmetic)
    mix = m.alpha[:, None, None] * m.truth_x1 + (1 - m.alpha[:, None, None]) * m.truth_x2
    np.testing.assert_allclose(m.frames, mix, rtol=1e-5)
    # the two channels differ: the foveal one sees a magnified, dimmer (F/2) view
    assert not np.allclose(m.truth_x1, m.truth_x2)
    # the flat-field gain between the channels: (NA_1 / NA_2)^2 times the ratio of their optical-train throughputs
    # and glare
    tr = m.meta["optical_train"]
    assert m.meta["foveal_constraint"]["gain"] == pytest.approx(
        (0.24254 / 0.44721) ** 2 * tr[0]["throughput"] * (1 + tr[0]["leak_fraction"])
        / (tr[1]["throughput"] * (1 + tr[1]["leak_fraction"])), rel=1e-3)


def test_downsampled_foveal_matches_centre_of_perifoveal(small_system, delta_psf, gauss_psf, quiet):
    s = small_system(96)
    kw = dict(frames=1, supersample=3, relative_illumination=True, **quiet)
    m = simulate(s, "camera", psf=delta_psf, **kw)
    fc = m.meta["foveal_constraint"]
    d = _downsample(m.truth_x1.astype(np.float64), 6)
    c = fc["gain"] * _centre_crop(m.truth_x2.astype(np.float64), 16) + fc["offset_dn"]
    contrast = d.std()
    # same angular boxes: only the sampling of the picture's sharp edges differs (3 x 3 samples per
    # perifoveal pixel against 18 x 18 in the foveal block)
    assert np.sqrt(np.mean((d - c) ** 2)) < 0.05 * contrast
    # with different PSFs the mismatch grows, bounded by the PSF difference
    m2 = simulate(s, "camera", psf=gauss_psf(0.4, 1.2), **kw)
    d2 = _downsample(m2.truth_x1.astype(np.float64), 6)
    c2 = fc["gain"] * _centre_crop(m2.truth_x2.astype(np.float64), 16) + fc["offset_dn"]
    err2 = np.sqrt(np.mean((d2 - c2) ** 2))
    assert np.sqrt(np.mean((d - c) ** 2)) < err2 < 0.5 * contrast


def test_extinction_keeps_the_mixture_form(small_system, delta_psf, quiet):
    s = small_system(32)
    m = simulate(s, "bars", frames=6, psf=delta_psf, supersample=1, extinction=0.1, **quiet)
    assert m.alpha.max() <= 1 / 1.1 + 1e-9 and m.alpha.min() >= 0.1 / 1.1 - 1e-9
    mix = m.alpha[:, None, None] * m.truth_x1 + (1 - m.alpha[:, None, None]) * m.truth_x2
    np.testing.assert_allclose(m.frames, mix, rtol=1e-5)


def test_video_scene_truth_is_per_frame(small_system, delta_psf, quiet):
    s = small_system(32)
    m = simulate(s, "hand", frames=3, psf=delta_psf, supersample=1, **quiet)
    assert m.truth_x1.shape == (3, 32, 32) and m.meta["truth_is_video"]
    assert not np.allclose(m.truth_x2[0], m.truth_x2[2])
    mix = m.alpha[:, None, None] * m.truth_x1 + (1 - m.alpha[:, None, None]) * m.truth_x2
    np.testing.assert_allclose(m.frames, mix, rtol=1e-5)


# ---------------------------------------------------------------------------------------------
# seeds, calibration frames, memory, bad input
# ---------------------------------------------------------------------------------------------
def test_same_seed_same_frames_different_seed_different(small_system, gauss_psf):
    s = small_system(32)
    kw = dict(frames=5, psf=gauss_psf(), supersample=1, polarizer_mode="free", fpn_drift=0.2)
    a = simulate(s, "siemens-star", rng=7, **kw)
    b = simulate(s, "siemens-star", rng=7, **kw)
    c = simulate(s, "siemens-star", rng=8, **kw)
    assert np.array_equal(a.frames, b.frames) and np.array_equal(a.alpha, b.alpha)
    assert not np.array_equal(a.frames, c.frames) and not np.allclose(a.alpha, c.alpha)


def test_shutter_calibration_frames_share_the_fpn():
    """Calibration frames (closed shutter) carry the measurement's fixed pattern and leave its frames unchanged."""
    import dataclasses

    sysd = SystemDesign.paper()
    sysd = dataclasses.replace(sysd, sensor=dataclasses.replace(sysd.sensor, crop=(64, 64), pixels=(64, 64)))
    a = simulate(sysd, "bars", rng=3, frames=4, psf="airy", calibration_frames=0)
    b = simulate(sysd, "bars", rng=3, frames=4, psf="airy", calibration_frames=32)
    assert np.array_equal(a.frames, b.frames)
    cal = b.extras["calibration"]
    assert cal.shape == (32, 64, 64)
    pattern = cal.mean(axis=0) - cal.mean()
    true = b.fpn - b.fpn.mean()
    # the averaged shutter frames recover the pattern to the noise level sigma / sqrt(32)
    sigma = b.meta["sensor"]["noise_sigma_dn"]
    assert np.sqrt(np.mean((pattern - true) ** 2)) < 2.0 * sigma / np.sqrt(32) + 0.3
    assert np.std(true) > 3 * sigma / np.sqrt(32)  # the check above is not trivially met by a flat pattern


def test_a_sequence_that_cannot_fit_in_memory_is_refused_up_front(monkeypatch):
    """--frames 100000 (allowed by the range) was an out-of-memory kill at 290 x 290; now a clear error
    that says how many frames fit, raised before the PSFs are built."""
    monkeypatch.setattr(sim, "available_memory_bytes", lambda: 200 * 2**20)  # a 200 MiB machine
    monkeypatch.setattr(sim, "resolve_provider", lambda *a, **k: pytest.fail("work started"))
    with pytest.raises(InputError, match="at most about") as e:
        sim.simulate(SystemDesign.paper(), "bars", frames=1000, psf="airy")  # 1000 x 290 x 290 x 4 B x 2 > 160 MiB
    assert e.value.parameter == "frames"
    with pytest.raises(InputError, match="frames"):  # video scenes also keep (T, H, W) truth images
        sim.simulate(SystemDesign.paper(), "hand", frames=300, psf="airy")
    sim.check_memory(96, (290, 290), video=True, available=2**30)  # the default fits in 1 GiB


def test_bad_simulation_inputs(small_system, delta_psf):
    s = small_system(32)
    with pytest.raises(InputError, match="frames"):
        simulate(s, "bars", frames=0, psf=delta_psf)
    with pytest.raises(InputError, match="scene"):
        simulate(s, "nope", frames=1, psf=delta_psf)
    with pytest.raises(InputError, match="psf"):
        simulate(s, "bars", frames=1, psf="magic")
    with pytest.raises(InputError, match="kernel sum"):
        simulate(s, "bars", frames=1, psf={"foveal": np.full((3, 3), 1.0), "perifoveal": np.ones((1, 1))})
    with pytest.raises(InputError, match="option"):
        simulate(s, "bars", frames=1, psf=delta_psf, no_such_option=1)
    # the system: a SystemDesign or its TOML file (a path string raised AttributeError)
    with pytest.raises(InputError, match="^system = "):
        simulate(42, "bars", frames=1, psf=delta_psf)
    with pytest.raises(InputError):
        simulate("no_such_system.toml", "bars", frames=1, psf=delta_psf)


def test_a_system_file_simulates_as_its_design(delta_psf):
    from metafovea.config import load_system

    f = Path(__file__).resolve().parents[2] / "designs" / "system.toml"
    kw = {"frames": 1, "psf": delta_psf, "optical_train": False, "posts": "ideal", "supersample": 1}
    assert np.array_equal(simulate(str(f), "bars", **kw).frames, simulate(load_system(f), "bars", **kw).frames)


def test_a_scene_in_celsius_is_simulated_only_with_its_unit_given(small_system, delta_psf):
    """mf.simulate(system, scene=array) took degrees Celsius as kelvin (an array was not even a scene: an OSError
    'file name too long'); now a Celsius array is an input error, and with scene_unit='celsius' it gives the same
    frames as the same scene in kelvin, the conversion stated in the metadata."""
    import metafovea as mf

    s = small_system(32)
    c = np.full((40, 40), 22.0)
    c[10:30, 15:25] = 34.0
    kw = dict(frames=3, psf=delta_psf, posts="ideal", optical_train=False)
    with pytest.raises(InputError, match="look like degrees Celsius: scene_unit='celsius'"):
        mf.simulate(s, c, **kw)
    celsius = mf.simulate(s, c, scene_unit="celsius", **kw)
    kelvin = mf.simulate(s, c + 273.15, **kw)
    np.testing.assert_array_equal(celsius.frames, kelvin.frames)
    assert celsius.meta["scene_info"]["conversion"] == "degrees Celsius converted to kelvin: T_K = T_C + 273.15"
    assert "conversion" not in kelvin.meta["scene_info"]
    with pytest.raises(InputError, match=r"one channel \(a temperature map in kelvin\)"):
        mf.simulate(s, np.stack([c + 273.15] * 3, axis=-1), **kw)


# ---------------------------------------------------------------------------------------------
# simulate_to_files
# ---------------------------------------------------------------------------------------------
def test_simulate_to_files_writes_the_measurement_tiff_and_preview(tmp_path, small_system, delta_psf):
    import tifffile

    s = small_system(24)
    run = simulate_to_files(s, "bars", tmp_path / "m.npz", sim.SimulationOptions(frames=3, psf=delta_psf,
                                                                                   supersample=1), rng=2)
    assert set(run.files) == {"measurement", "tiff", "preview"}
    back = Measurement.load(run.files["measurement"])
    assert np.array_equal(back.frames, run.measurement.frames)
    assert np.array_equal(back.frames, simulate(s, "bars", frames=3, psf=delta_psf, supersample=1, rng=2).frames)
    assert np.array_equal(tifffile.imread(run.files["tiff"]), back.frames.astype(np.uint16))
    assert run.files["preview"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the preview's six thermal images (four frames, two truths) each carry a colour bar in the file's units
    fig = sim.preview_figure(back)
    bars = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert len(bars) == 6 and all(ax.get_ylabel() == "DN" for ax in bars)
    summary = run.summary()
    assert summary["frames"] == 3 and summary["seed"] == 2 and set(summary["seconds"]) == {"simulate", "total"}
    with pytest.raises(InputError, match="force"):  # nothing is overwritten without force
        simulate_to_files(s, "bars", tmp_path / "m.npz", sim.SimulationOptions(frames=1, psf=delta_psf))
    only = simulate_to_files(s, "bars", tmp_path / "n.npz", sim.SimulationOptions(frames=1, psf=delta_psf),
                             tiff=False, preview=False)
    assert set(only.files) == {"measurement"} and not (tmp_path / "n.tif").exists()


def test_simulate_to_files_refuses_to_overwrite_what_it_reads_even_with_force(tmp_path, monkeypatch):
    """--scene s.npz --out s.npz destroyed the scene, even with --force; k.tif as scene and k.npz as out
    overwrote it with the TIFF stack."""
    monkeypatch.setattr(sim, "simulate", lambda *a, **k: pytest.fail("work started"))
    scene = tmp_path / "s.npz"
    np.savez(scene, temperature_k=np.full((20, 20), 300.0))
    before = scene.read_bytes()
    with pytest.raises(InputError, match="other than the input"):
        simulate_to_files(None, str(scene), scene, force=True)
    tif = tmp_path / "k.tif"
    tif.write_bytes(b"a scene picture")
    with pytest.raises(InputError, match="k.tif"):
        simulate_to_files(None, str(tif), tmp_path / "k.npz", force=True)
    # without the TIFF output k.tif is not written: the run gets past the input check (and stops at the existing
    # preview, without force)
    (tmp_path / "k_preview.png").write_bytes(b"")
    with pytest.raises(InputError, match="preview"):
        simulate_to_files(None, str(tif), tmp_path / "k.npz", tiff=False)
    assert scene.read_bytes() == before and tif.read_bytes() == b"a scene picture"
    with pytest.raises(InputError, match=".npz"):
        simulate_to_files(None, "bars", tmp_path / "m.tif")


def test_the_optical_train_sets_gain_and_relative_illumination(small_system, delta_psf, quiet):
    """A uniform scene through the full paper crop: each channel's level is the train's throughput (and its glare),
    and the perifoveal image falls off to the corner as cos^4 times the foveal lens' ring (clipping beyond
    11.3 deg) times the posts at oblique incidence."""
    import math

    from metafovea.library import system_post_sets
    from metafovea.optics.train import system_trains

    s = small_system(290)
    on = simulate(s, "uniform", frames=1, psf=delta_psf, supersample=1, **quiet)
    off = simulate(s, "uniform", frames=1, psf=delta_psf, supersample=1, optical_train=False, **quiet)
    trains = system_trains(s, *system_post_sets(s))
    dark = on.meta["dark_dn"]
    for img_on, img_off, tr in ((on.truth_x1, off.truth_x1, trains[0]), (on.truth_x2, off.truth_x2, trains[1])):
        c = (145, 145)
        # a uniform scene also fills the glare disks of the other lens' pass-through ripple
        assert (img_on[c] - dark) / (img_off[c] - dark) == pytest.approx(
            tr.throughput * (1 + tr.leak_fraction) * float(tr.field_factor(17 / 25000, 17 / 25000)), rel=3e-4)
    # the corner pixel of the perifoveal image: field tan = (144.5 * 34 um) / 25 mm along both axes
    t = 144.5 * 34.0 / 25000.0
    cos4 = 1.0 / (1.0 + 2 * t * t) ** 2
    corner = (on.truth_x2[0, 0] - dark) / (on.truth_x2[145, 145] - dark)
    centre_t = 0.5 * 34.0 / 25000.0
    expect = cos4 * float(trains[1].field_factor(t, t)) / (1.0 / (1.0 + 2 * centre_t ** 2) ** 2)
    assert corner == pytest.approx(expect, rel=2e-3)
    assert float(trains[1].clear_fraction(math.hypot(t, t))) < 0.8  # the ring clips the corner
    assert on.meta["posts"] == "rcwa" and isinstance(on.meta["optical_train"], list)
    assert "simplified" in off.meta["optical_train"]["note"]


def test_simulate_runs_on_a_system_with_a_corrected_lens(small_system, delta_psf, quiet):
    """A foveal lens with a phase beyond the hyperbola (LensDesign.phase_poly_rad) simulates like any design: the
    optical train samples its lattice sites with the full design phase (the other channel's pass-through)."""
    from dataclasses import replace

    s = small_system(32)
    corrected = replace(s, foveal=s.foveal.with_(phase_poly_rad=(120.0, -35.5)))
    m = simulate(corrected, "bars", frames=2, psf=delta_psf, supersample=1, **quiet)
    assert m.frames.shape[0] == 2 and np.all(np.isfinite(m.frames))
    plain = simulate(s, "bars", frames=2, psf=delta_psf, supersample=1, **quiet)
    assert m.frames.shape == plain.frames.shape


# ---------------------------------------------------------------------------------------------
# the PSF kernels' error request, derived from what the recording shows
# ---------------------------------------------------------------------------------------------
def test_the_kernels_error_request_is_met_on_the_default_camera_and_warns_when_planted_tight(tmp_path):
    """The paper's camera at its default noise (8-14 um, the siemens star), PSFs computed afresh: the request derived
    from half of one frame's noise is met by the engines (no NotConvergedWarning), the a-priori bound on the kernel's
    sum holds, and the output says which request and why. A planted camera with almost no noise (NETD 1e-4 K, no ADC)
    asks for more than the engines' estimates: it warns, also from the cache."""
    import warnings

    from metafovea.errors import NotConvergedWarning

    opts = dict(frames=2, psf="optics", psf_cache_dir=str(tmp_path / "psf"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m = simulate(SystemDesign.paper(), "siemens-star", **opts)
    assert not [w for w in caught if issubclass(w.category, NotConvergedWarning)], [str(w.message) for w in caught]
    for c in ("foveal", "perifoveal"):
        info = m.meta["psf"][c]
        r = info["psf_request"]
        assert r["met"] and r["bound_k"] <= r["allowed_k"] and r["kernel_sum_bound"] >= info["kernel_sum"]
        assert r["error"] > 1e-4 and "noise" in r["why"]  # looser than the constant it replaces, and says why
        assert r["engine_error"] == 1e-4  # the engines are asked for the tighter
        assert r["allowed_k"] == pytest.approx(0.5 * np.hypot(0.05 * 40, 1 / np.sqrt(12)) / m.meta["model"]["dn_per_k"][
            "x1" if c == "foveal" else "x2"], rel=1e-6)
    for _ in range(2):  # computed, then from the cache: both warn
        with pytest.warns(NotConvergedWarning):
            t = simulate(SystemDesign.paper(), "siemens-star", netd_k=1e-4, quantize=False, **opts)
        assert not t.meta["psf"]["perifoveal"]["psf_request"]["met"]

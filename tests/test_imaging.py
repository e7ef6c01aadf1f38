"""Imaging simulation: scenes, radiometry, system model, sensor, Measurement, CLI (small sizes)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from metafovea.config import SensorDesign, SystemDesign
from metafovea.errors import InputError
from metafovea.measurement import Measurement
from metafovea.imaging import SensorModel, make_scene, simulate
from metafovea.radiometry import BandRadiance, planck_radiance, spectral_weights
from metafovea.imaging.scene import CoilHeater, RasterScene, SceneGeometry, list_scenes
from metafovea.imaging.system import Polarizer, channels_for, gaussian_kernel

QUIET = dict(noise=False, fpn_rank=0, quantize=False)


def small_system(n: int = 48, **sensor_kw) -> SystemDesign:
    return replace(SystemDesign.paper(), sensor=replace(SensorDesign(), crop=(n, n), **sensor_kw))


def delta_psf() -> dict:
    return {"foveal": np.ones((1, 1)), "perifoveal": np.ones((1, 1))}


def gauss_psf(s1: float = 0.6, s2: float = 0.6) -> dict:
    return {"foveal": gaussian_kernel(s1), "perifoveal": gaussian_kernel(s2)}


# ---------------------------------------------------------------------------------------------
# radiometry
# ---------------------------------------------------------------------------------------------
def test_planck_matches_independent_formula_and_stefan_boltzmann():
    lam = np.array([8.0, 10.0, 12.0])
    c1, c2 = 2 * 6.62607015e-34 * 299792458.0 ** 2, 6.62607015e-34 * 299792458.0 / 1.380649e-23
    direct = c1 / (lam * 1e-6) ** 5 / np.expm1(c2 / (lam * 1e-6 * 300.0)) * 1e-6
    np.testing.assert_allclose(planck_radiance(lam, 300.0), direct, rtol=1e-4)
    # the whole spectrum integrates to sigma T^4 / pi
    lam_w, w = spectral_weights((0.5, 2000.0), n=40001)
    w = np.where((lam_w > 0.5) & (lam_w < 2000.0), 1.0, 0.0)
    L = np.trapezoid(planck_radiance(lam_w, 300.0) * w, lam_w)
    assert L == pytest.approx(5.670374e-8 * 300.0 ** 4 / math.pi, rel=5e-3)


def test_band_radiance_table_and_derivative():
    br = BandRadiance.for_system(SystemDesign.paper())
    t = np.array([250.0, 300.0, 333.3, 600.0])
    np.testing.assert_allclose(br(t), br.exact(t), rtol=1e-5)
    # dL/dT by finite difference of the table
    assert (br(300.5) - br(299.5)) == pytest.approx(br.derivative(300.0), rel=1e-3)
    # filter passes less than the band; emissivity mixes in the reflected surroundings
    brf = BandRadiance.for_system(SystemDesign.paper(), filter_enabled=True)
    assert brf(300.0) < 0.2 * br(300.0)
    assert br.apparent(320.0, 0.5, 300.0) == pytest.approx(0.5 * (br(320.0) + br(300.0)))
    with pytest.raises(InputError, match="temperature"):
        br(-1.0)


# ---------------------------------------------------------------------------------------------
# scenes
# ---------------------------------------------------------------------------------------------
def test_builtin_scenes_render_plausible_temperatures():
    g = SceneGeometry()
    ax, ay = np.meshgrid(np.linspace(-g.half, g.half, 40), np.linspace(-g.half, g.half, 40))
    for name in list_scenes():
        sc = make_scene(name, g)
        for t in (0.0, 3.0):
            temp, eps = sc.sample(ax, ay, t)
            assert temp.shape == ax.shape and np.all((temp > 200) & (temp < 700)), name
            assert np.all((eps > 0) & (eps <= 1)), name


def test_scene_is_sampled_at_any_resolution_star_contrast_in_fovea():
    sc = make_scene("siemens-star")
    g = SceneGeometry()
    # a ring inside the foveal field still resolves the spokes when sampled finely
    phi = np.linspace(0, 2 * np.pi, 3600, endpoint=False)
    r = 0.5 * g.fovea_half
    temp, _ = sc.sample(r * np.cos(phi), r * np.sin(phi))
    changes = np.count_nonzero(np.diff(temp) != 0)
    assert changes == pytest.approx(2 * 36, abs=2)


def test_heater_transients():
    h = CoilHeater(on_duration_s=5.0, t_on_s=1.0)
    ts = np.linspace(0, 20, 201)
    tc = np.array([h.coil_temperature(t) for t in ts])
    assert tc[0] == pytest.approx(h.wall_k)
    on = (ts >= 1) & (ts <= 6)
    assert np.all(np.diff(tc[on]) > 0)  # heating
    assert np.all(np.diff(tc[ts > 6]) < 0)  # cooling
    assert h.coil_temperature(6.0) == pytest.approx(h.wall_k + h.dt_max_k * (1 - math.exp(-5 / h.tau_heat_s)))
    assert make_scene("heater-20s").on_duration_s == 20.0


def test_bad_scene_inputs():
    with pytest.raises(InputError, match="scene"):
        make_scene("no-such-scene")
    with pytest.raises(InputError, match="scene"):
        make_scene("missing_file.npy")
    with pytest.raises(InputError, match="temperature"):
        RasterScene(temperature_k=np.full((8, 8), -5.0))


def test_scene_from_npy_file(tmp_path):
    t = np.full((32, 32), 300.0)
    t[12:20, 12:20] = 330.0
    np.save(tmp_path / "hot.npy", t)
    sc = make_scene(str(tmp_path / "hot.npy"))
    temp, _ = sc.sample(np.array([0.0, 0.9 * sc.half_width_rad]), np.array([0.0, 0.0]))
    assert temp[0] == pytest.approx(330.0) and temp[1] == pytest.approx(300.0)
    np.save(tmp_path / "neg.npy", t - 400)
    with pytest.raises(InputError, match="temperature"):
        make_scene(str(tmp_path / "neg.npy"))


# ---------------------------------------------------------------------------------------------
# system model
# ---------------------------------------------------------------------------------------------
def test_channel_geometry_paper():
    c1, c2 = channels_for(SystemDesign.paper())
    assert c1.focal_pitch_um == pytest.approx(34.0)
    assert c2.ifov_rad / c1.ifov_rad == pytest.approx(6.0)
    assert math.degrees(2 * c2.half_fov_rad[1]) == pytest.approx(22.27, abs=0.05)
    c1b, _ = channels_for(SystemDesign.paper(), pixel_pitch_um=24.0, relay_magnification=0.3)
    assert c1b.focal_pitch_um == pytest.approx(80.0)


def test_polarizer_modes_and_extinction():
    t = np.arange(12) / 12.0
    th, info = Polarizer(phase_rad=0.0).angles(t, np.random.default_rng(0))
    a, ae, gain = Polarizer().mixing(th)
    np.testing.assert_allclose(a, np.cos(2 * np.pi * 2 * t) ** 2)
    np.testing.assert_allclose(a[::3], 1.0)
    th1, i1 = Polarizer(mode="free").angles(t, np.random.default_rng(1))
    th2, i2 = Polarizer(mode="free").angles(t, np.random.default_rng(2))
    assert i1["phase_rad"] != i2["phase_rad"]
    _, ae, gain = Polarizer(extinction=0.05).mixing(th)
    assert gain == pytest.approx(1.05)
    assert ae.max() == pytest.approx(1 / 1.05) and ae.min() >= 0.05 / 1.05 - 1e-12


# ---------------------------------------------------------------------------------------------
# end to end
# ---------------------------------------------------------------------------------------------
def test_alpha_one_is_foveal_and_alpha_zero_is_perifoveal():
    s = small_system()
    m = simulate(s, "camera", frames=4, psf=gauss_psf(), supersample=1, polarizer_phase_deg=0.0, **QUIET)
    assert m.alpha[0] == pytest.approx(1.0)
    np.testing.assert_allclose(m.frames[0], m.truth_x1, rtol=1e-6)
    m0 = simulate(s, "camera", frames=2, psf=gauss_psf(), supersample=1, polarizer_phase_deg=90.0, **QUIET)
    assert m0.alpha[0] == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(m0.frames[0], m0.truth_x2, rtol=1e-6)
    # every frame is the mixture (float32 arithmetic)
    mix = m.alpha[:, None, None] * m.truth_x1 + (1 - m.alpha[:, None, None]) * m.truth_x2
    np.testing.assert_allclose(m.frames, mix, rtol=1e-5)
    # the two channels differ: the foveal one sees a magnified, dimmer (F/2) view
    assert not np.allclose(m.truth_x1, m.truth_x2)
    assert m.meta["foveal_constraint"]["gain"] == pytest.approx((0.24254 / 0.44721) ** 2, rel=1e-3)


def test_noise_statistics_match_netd():
    s = small_system(64, netd_k=0.04)
    m = simulate(s, "uniform", frames=40, psf=delta_psf(), supersample=1, fpn_rank=0, quantize=False,
                 relative_illumination=False, rng=3)
    mix = m.alpha[:, None, None] * m.truth_x1 + (1 - m.alpha[:, None, None]) * m.truth_x2
    n = (m.frames - mix).astype(np.float64)
    sigma_dn = 0.04 * m.meta["counts_per_k"]
    assert n.mean() == pytest.approx(0.0, abs=0.01 * sigma_dn)
    assert n.std() == pytest.approx(sigma_dn, rel=0.02)
    # the DN change per kelvin at 300 K through the perifoveal channel is counts_per_k, so the
    # temperature-referred noise of an alpha = 0 frame is the NETD
    hot = simulate(s, "uniform", frames=1, psf=delta_psf(), supersample=1, relative_illumination=False,
                   scene_params={"temperature_k": 300.05}, **QUIET)
    cold = simulate(s, "uniform", frames=1, psf=delta_psf(), supersample=1, relative_illumination=False,
                    scene_params={"temperature_k": 299.95}, **QUIET)
    dn_per_k = float((hot.truth_x2 - cold.truth_x2).mean()) / 0.1
    assert dn_per_k == pytest.approx(m.meta["dn_per_k_300K"]["x2"], rel=2e-3)
    assert sigma_dn / dn_per_k == pytest.approx(0.04, rel=3e-3)
    assert m.meta["netd_effective_k"]["x1"] == pytest.approx(0.04 / m.meta["foveal_constraint"]["gain"])


@pytest.mark.parametrize("rank", [1, 4, 9])
def test_fpn_has_the_asked_rank_and_amplitude(rank):
    sm = SensorModel(shape=(40, 56), fpn_rank=rank, fpn_amplitude=0.1, fpn_drift=0.3)
    f = sm.make_fpn(500.0, np.arange(5) / 12, rng=0)
    for k in (None, 0, 4):
        F = f.frame(k).astype(np.float64)
        s = np.linalg.svd(F, compute_uv=False)
        assert np.sum(s > 1e-4 * s[0]) == rank
    assert np.abs(f.frame(None)).max() == pytest.approx(50.0, rel=1e-5)
    assert not np.allclose(f.frame(0), f.frame(4))  # drift


def test_fpn_in_measurement_and_quantisation():
    s = small_system(48, fpn_rank=5, fpn_amplitude=0.1)
    m = simulate(s, "bars", frames=3, psf=delta_psf(), supersample=1, noise=False, quantize=True, rng=1)
    assert np.array_equal(m.frames, np.rint(m.frames)) and m.frames.max() <= 2 ** 14 - 1
    mix = m.alpha[:, None, None] * m.truth_x1 + (1 - m.alpha[:, None, None]) * m.truth_x2 + m.fpn
    assert np.abs(m.frames - mix).max() <= 0.5 + 1e-3
    assert np.linalg.matrix_rank(m.fpn.astype(np.float64), tol=1e-3 * np.abs(m.fpn).max()) == 5


def test_same_seed_same_frames_different_seed_different():
    s = small_system(32)
    kw = dict(frames=5, psf=gauss_psf(), supersample=1, polarizer_mode="free", fpn_drift=0.2)
    a = simulate(s, "siemens-star", rng=7, **kw)
    b = simulate(s, "siemens-star", rng=7, **kw)
    c = simulate(s, "siemens-star", rng=8, **kw)
    assert np.array_equal(a.frames, b.frames) and np.array_equal(a.alpha, b.alpha)
    assert not np.array_equal(a.frames, c.frames) and not np.allclose(a.alpha, c.alpha)


def _downsample(x: np.ndarray, s: int) -> np.ndarray:
    H, W = x.shape
    return x[: H // s * s, : W // s * s].reshape(H // s, s, W // s, s).mean(axis=(1, 3))


def _centre_crop(x: np.ndarray, h: int) -> np.ndarray:
    H = x.shape[0]
    y0 = (H - h) // 2
    return x[y0:y0 + h, y0:y0 + h]


def test_downsampled_foveal_matches_centre_of_perifoveal():
    s = small_system(96)
    kw = dict(frames=1, supersample=3, relative_illumination=True, **QUIET)
    m = simulate(s, "camera", psf=delta_psf(), **kw)
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


def test_video_scene_truth_is_per_frame():
    s = small_system(32)
    m = simulate(s, "hand", frames=3, psf=delta_psf(), supersample=1, **QUIET)
    assert m.truth_x1.shape == (3, 32, 32) and m.meta["truth_is_video"]
    assert not np.allclose(m.truth_x2[0], m.truth_x2[2])
    mix = m.alpha[:, None, None] * m.truth_x1 + (1 - m.alpha[:, None, None]) * m.truth_x2
    np.testing.assert_allclose(m.frames, mix, rtol=1e-5)


def test_extinction_keeps_the_mixture_form():
    s = small_system(32)
    m = simulate(s, "bars", frames=6, psf=delta_psf(), supersample=1, extinction=0.1, **QUIET)
    assert m.alpha.max() <= 1 / 1.1 + 1e-9 and m.alpha.min() >= 0.1 / 1.1 - 1e-9
    mix = m.alpha[:, None, None] * m.truth_x1 + (1 - m.alpha[:, None, None]) * m.truth_x2
    np.testing.assert_allclose(m.frames, mix, rtol=1e-5)


def test_haze_without_filter_and_airy_model():
    s = small_system(40)
    m = simulate(s, "siemens-star", frames=2, psf="airy", **QUIET)
    for c in ("foveal", "perifoveal"):
        assert m.meta["psf"][c]["haze"]["fraction"] > 0.9
    mf = simulate(s, "siemens-star", frames=2, psf="airy", filter_enabled=True, **QUIET)
    # the filter keeps more power near focus: more contrast in the perifoveal image
    assert mf.truth_x2.std() / mf.truth_x2.mean() > m.truth_x2.std() / m.truth_x2.mean()
    assert np.all(np.isfinite(m.frames))


def test_field_dependent_psf_patches_decided_and_reported():
    s = small_system(36)
    wide = {"foveal": lambda fld: gaussian_kernel(0.5 + 0.2 * fld, 9), "perifoveal":
            lambda fld: gaussian_kernel(0.5 + 0.3 * fld, 9)}
    m = simulate(s, "bars", frames=1, psf=wide, supersample=1, field_patches="auto", **QUIET)
    assert m.meta["psf"]["perifoveal"]["mode"] == "3 x 3 patches"
    assert m.meta["psf"]["foveal"]["mode"] == "shift-invariant"
    assert "TV distance" in m.meta["psf"]["perifoveal"]["patch_decision"]
    # constant kernels in patches give the same image as shift-invariant
    g = gauss_psf()
    a = simulate(s, "camera", frames=1, psf=g, supersample=1, field_patches=1, **QUIET)
    b = simulate(s, "camera", frames=1, psf=g, supersample=1, field_patches=3, **QUIET)
    np.testing.assert_allclose(a.truth_x2, b.truth_x2, rtol=1e-5)


def test_bad_simulation_inputs():
    s = small_system(32)
    with pytest.raises(InputError, match="frames"):
        simulate(s, "bars", frames=0, psf=delta_psf())
    with pytest.raises(InputError, match="scene"):
        simulate(s, "nope", frames=1, psf=delta_psf())
    with pytest.raises(InputError, match="psf"):
        simulate(s, "bars", frames=1, psf="magic")
    with pytest.raises(InputError, match="kernel sum"):
        simulate(s, "bars", frames=1, psf={"foveal": np.full((3, 3), 1.0), "perifoveal": np.ones((1, 1))})


# ---------------------------------------------------------------------------------------------
# Measurement file and CLI
# ---------------------------------------------------------------------------------------------
def test_measurement_roundtrip_and_no_clobber(tmp_path):
    s = small_system(24)
    m = simulate(s, "bars", frames=3, psf=delta_psf(), supersample=1, fpn_drift=0.1, rng=2)
    p = m.save(tmp_path / "m.npz")
    r = Measurement.load(p)
    assert np.array_equal(r.frames, m.frames) and np.array_equal(r.alpha, m.alpha)
    assert r.frames.dtype == np.float32 and r.meta["scale"] == 6.0 and r.meta["units"] == "DN"
    np.testing.assert_allclose(r.fpn_frame(2), m.fpn_frame(2), rtol=1e-5, atol=1e-3)
    with pytest.raises(InputError, match="force"):
        m.save(tmp_path / "m.npz")
    m.save(tmp_path / "m.npz", force=True)
    with pytest.raises(InputError):
        Measurement.load(tmp_path / "absent.npz")
    with pytest.raises(InputError, match="alpha"):
        Measurement(frames=np.zeros((2, 4, 4)), times_s=[0, 1], alpha=[0.5])


def test_cli_simulate(tmp_path, designs_dir, capsys):
    import json

    from metafovea.cli import main

    out = tmp_path / "meas.npz"
    args = ["simulate", str(designs_dir / "system.toml"), "--scene", "bars", "--frames", "3", "--psf",
            "gaussian:12", "--supersample", "1", "--out", str(out), "--json"]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frames"] == 3 and summary["shape"] == [290, 290]
    assert out.is_file() and (tmp_path / "meas.tif").is_file() and (tmp_path / "meas_preview.png").is_file()
    import tifffile
    assert tifffile.imread(tmp_path / "meas.tif").shape == (3, 290, 290)
    assert main(args) == 2  # refuses to overwrite
    assert main(args[:-3] + ["--out", str(tmp_path / "x.npz"), "--frames", "0"]) == 2
    assert main(["simulate", "--scene", "nope.npy", "--out", str(tmp_path / "y.npz")]) == 2
    assert main(["simulate", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "z.npz")]) == 2
    err = capsys.readouterr().err
    assert "frames" in err and "scene" in err


@pytest.mark.parametrize("name", ["hand", "parking-lot", "heater-10s"])
def test_incremental_video_rendering_equals_full_rendering(name):
    from metafovea.imaging.system import ChannelRenderer, airy_provider, build_channel_optics

    s = small_system(40)
    br = BandRadiance.for_system(s)
    _, ch2 = channels_for(s, shape=(40, 40))
    g = SceneGeometry(fov_rad=2 * ch2.half_fov_rad[1], duration_s=4.0)
    sc = make_scene(name, g)
    opt = build_channel_optics(ch2, airy_provider, br, ss=2)
    assert opt.far_kernel is not None  # the haze path is exercised too
    inc = ChannelRenderer(sc, opt, br)
    full = ChannelRenderer(sc, opt, br)
    full.incremental = False
    assert inc.incremental
    for t in (0.0, 1.7, 3.9):
        np.testing.assert_allclose(inc.render(t), full.render(t), rtol=1e-9, atol=1e-9 * full.render(t).max())


def test_shutter_calibration_frames_share_the_fpn():
    """Calibration frames (closed shutter) carry the measurement's fixed pattern and leave its frames unchanged."""
    import dataclasses

    from metafovea.config import SystemDesign
    from metafovea.imaging import simulate
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

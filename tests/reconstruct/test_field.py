"""A field-dependent PSF in the PSF-aware reconstruction (:mod:`metafovea.reconstruct.field`).

The reference is a camera written here by brute force: every pixel has its own kernel from a continuous law (a
Gaussian that widens, moves outward and loses light with the field, as an off-axis metalens spot does), applied
pixel by pixel to a scene three crops wide. The reconstruction is given what a camera's file carries: the kernels
at the 3 x 3 patch centres only (``psf_patches_x2``), not the law."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from metafovea.errors import InputError
from metafovea.reconstruct import ChannelPSFs, separate_deconvolve
from metafovea.reconstruct.metrics import psnr
from tests.independent.forward import gauss_kernel

N, K, P = 96, 21, 3


def _kernel(y: float, x: float, strength: float) -> np.ndarray:
    """The perifoveal kernel at pixel (y, x): wider, further out and dimmer with the field (0 on axis)."""
    c = (N - 1) / 2
    r2 = ((y - c) ** 2 + (x - c) ** 2) / (2 * c * c)  # 1 at the corners
    sig = 0.7 + 2.2 * strength * r2
    shift = 1.5 * strength * r2
    ang = np.arctan2(y - c, x - c)
    d = np.arange(K) - K // 2
    yy, xx = np.meshgrid(d, d, indexing="ij")
    k = np.exp(-((yy - shift * np.sin(ang)) ** 2 + (xx - shift * np.cos(ang)) ** 2) / (2 * sig ** 2))
    return (1 - 0.25 * strength * r2) * k / k.sum()


def _scene(rng: np.random.Generator, n: int) -> np.ndarray:
    s = np.full((n, n), 300.0)
    for _ in range(160):
        y, x = rng.integers(0, n - 4, 2)
        h, w = rng.integers(2, 18, 2)
        s[y:y + h, x:x + w] += rng.uniform(-80, 80)
    return s


def _camera(strength: float, seed: int = 2, sigma: float = 1.0, T: int = 24):
    """Frames through the brute-force camera, the alpha, the PSFs its file would carry and the scenes."""
    rng = np.random.default_rng(seed)
    big = 3 * N
    s1, s2 = _scene(rng, big), _scene(rng, big)
    c = slice(N, 2 * N)
    k1 = gauss_kernel(0.9, K)
    h = K // 2
    win = sliding_window_view(s1[N - h:2 * N + h, N - h:2 * N + h], (K, K))  # (N, N, K, K) around each pixel
    u1 = np.einsum("yxab,ab->yx", win, k1[::-1, ::-1])
    win2 = sliding_window_view(s2[N - h:2 * N + h, N - h:2 * N + h], (K, K))
    per_pixel = np.array([[_kernel(y, x, strength) for x in range(N)] for y in range(N)])
    u2 = np.einsum("yxab,yxab->yx", win2, per_pixel[:, :, ::-1, ::-1])  # each pixel through its own kernel
    a = np.cos(np.linspace(0, 2 * np.pi, T, endpoint=False) + 0.3) ** 2
    frames = a[:, None, None] * u1 + (1 - a[:, None, None]) * u2 + rng.normal(0, sigma, (T, N, N))
    centres = [(i + 0.5) * N / P - 0.5 for i in range(P)]
    patches = np.array([[_kernel(y, x, strength) for x in centres] for y in centres])
    on_axis = _kernel((N - 1) / 2, (N - 1) / 2, strength)
    psfs = ChannelPSFs((k1, on_axis), patches=(None, patches))
    return frames, a, psfs, (s1[c, c], s2[c, c])


@pytest.fixture(scope="module")
def strong():
    return _camera(1.0)


def test_the_field_dependent_psf_is_modelled_where_the_data_need_it(strong):
    frames, a, psfs, truth = strong
    on = separate_deconvolve(frames, a, psfs, method="wiener", sigma=1.0, field_psf="on-axis")
    auto = separate_deconvolve(frames, a, psfs, method="wiener", sigma=1.0)
    gain = psnr(auto.scene[1], truth[1]) - psnr(on.scene[1], truth[1])
    assert gain > 6.0, gain  # the corners lose a quarter of their light and blur 4x: the on-axis kernel is wrong
    assert abs(psnr(auto.scene[0], truth[0]) - psnr(on.scene[0], truth[0])) < 0.05  # x1 is shift-invariant
    f = auto.info["field"]
    assert f["mode"] == "3 x 3 patches" and len(f["solved"]) == 8  # the centre patch is the on-axis kernel
    assert all(ch == [2] for *_, ch in f["solved"])
    assert np.asarray(f["change_over_noise"])[..., 0].max() == 0.0
    assert on.info["field"]["mode"] == "on-axis" and "left out" in on.info["field"]["why"]
    # every patch asked for: the same (the centre's own kernels are the on-axis ones)
    every = separate_deconvolve(frames, a, psfs, method="wiener", sigma=1.0, field_psf="patches")
    assert np.allclose(every.scene[1], auto.scene[1])


def test_the_patches_solved_on_threads_give_the_same_numbers(strong, monkeypatch):
    from metafovea.reconstruct import field

    frames, a, psfs, _ = strong
    monkeypatch.setattr(field, "MAX_THREADS", 3)
    threads = separate_deconvolve(frames, a, psfs, method="wiener", sigma=1.0)
    monkeypatch.setattr(field, "MAX_THREADS", 1)
    one = separate_deconvolve(frames, a, psfs, method="wiener", sigma=1.0)
    assert np.array_equal(threads.scene[0], one.scene[0]) and np.array_equal(threads.scene[1], one.scene[1])
    assert threads.info["field"]["solved"] == one.info["field"]["solved"]


def test_the_default_method_gains_too(strong):
    frames, a, psfs, truth = strong
    on = separate_deconvolve(frames, a, psfs, sigma=1.0, field_psf="on-axis")
    auto = separate_deconvolve(frames, a, psfs, sigma=1.0)
    assert psnr(auto.scene[1], truth[1]) - psnr(on.scene[1], truth[1]) > 6.0
    assert set(auto.info["field"]["tau_per_patch"]) == {f"{i},{j}" for i in range(3) for j in range(3)} - {"1,1"}


def test_a_field_variation_below_the_noise_is_not_modelled():
    frames, a, psfs, truth = _camera(0.002, sigma=3.0)
    on = separate_deconvolve(frames, a, psfs, method="wiener", sigma=3.0, field_psf="on-axis")
    auto = separate_deconvolve(frames, a, psfs, method="wiener", sigma=3.0)
    assert auto.info["field"]["solved"] == [] and "below the noise" in auto.info["field"]["mode"]
    assert 0 < np.max(auto.info["field"]["change_over_noise"]) < 0.5
    assert np.array_equal(auto.scene[1], on.scene[1])


def test_shift_invariant_psfs_say_so_and_bad_patches_are_refused(strong):
    frames, a, psfs, _ = strong
    plain = ChannelPSFs(psfs.kernels)
    r = separate_deconvolve(frames[:, :32, :32], a, plain, method="wiener", sigma=1.0)
    assert r.info["field"]["mode"] == "shift-invariant"
    with pytest.raises(InputError, match="field_psf"):
        separate_deconvolve(frames[:, :32, :32], a, plain, method="wiener", sigma=1.0, field_psf="patches")
    with pytest.raises(InputError, match="psf_patches_x2"):
        ChannelPSFs(psfs.kernels, patches=(None, np.ones((3, 2, 5, 5))))
    with pytest.raises(InputError, match="psf_patches_x2"):
        ChannelPSFs(psfs.kernels, patches=(np.ones((2, 2, 5, 5)), np.ones((3, 3, 5, 5))))
    with pytest.raises(InputError, match="psf_patches_x1"):
        ChannelPSFs(psfs.kernels, patches=(-np.ones((2, 2, 5, 5)), None))


def test_the_simulators_field_patches_reach_the_reconstruction_through_the_file(tmp_path):
    """``simulate --field-patches 3`` writes every patch's kernel; ``reconstruct --deconvolve`` reads them from the
    file (the documented ``psf_patches_x*``) and recovers what the on-axis kernel loses at 10 um in the perifoveal
    channel, without losing the foveal one: the foveal surround is predicted from the on-axis solve's perifoveal
    centre (a corner patch's solve images that centre wrong: 1.0 dB below the on-axis kernel's x1 without it)."""
    import dataclasses

    from metafovea.config import load_system
    from metafovea.imaging.simulate import simulate
    from metafovea.measurement import Measurement
    from metafovea.reconstruct.deconvolve import deconvolve_measurement
    from metafovea.reconstruct.fpn import estimate_fpn

    system = load_system("designs/system.toml")
    system = dataclasses.replace(system, sensor=dataclasses.replace(system.sensor, crop=(128, 128)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = simulate(system, "coins", field_patches=3, rng=5, frames=24, calibration_frames=16, filter_enabled=True)
    path = m.save(tmp_path / "field.npz")
    rec = Measurement.load(path).as_recording()
    assert rec.extras["psf_patches_x2"].shape[:2] == (3, 3)
    assert ChannelPSFs.from_measurement(rec).n_patches == 3
    full = Measurement.load(path)  # the scene truth, for scoring
    fpn, info = estimate_fpn(calibration=full.extras["calibration"])
    kw = dict(fpn=fpn, fpn_error_dn=info["error_rms_dn"], method="wiener")
    on = deconvolve_measurement(full, field_psf="on-axis", **kw).info["scores"]
    auto = deconvolve_measurement(full, **kw)
    sc = auto.info["scores"]
    assert auto.info["field"]["solved"] and sc["wiener_bound_psf"].startswith("sectioned")
    assert sc["psnr_x2"] > on["psnr_x2"] + 10.0  # measured 5.7 -> 25.8 dB
    assert sc["psnr_x1"] > on["psnr_x1"] - 0.05  # measured 25.4 -> 25.9 dB (24.3 with a patch's own surround)
    # each patch solved with its own kernels chose its own padding beyond the perifoveal crop: the output says so
    ex = auto.info["exterior"]
    assert set(ex["kept_per_patch"]) == {f"{i},{j}" for i, j, _ in auto.info["field"]["solved"]}
    assert set(ex["kept_per_patch"].values()) <= {"solved", "padded"} and "patches solved with their own" in ex["why"]


@pytest.fixture(scope="module")
def small_file(tmp_path_factory):
    """A 64 px recording of the paper's camera at 10 um in 3 x 3 field patches, saved."""
    import dataclasses

    from metafovea.config import load_system
    from metafovea.imaging.simulate import simulate

    system = load_system("designs/system.toml")
    system = dataclasses.replace(system, sensor=dataclasses.replace(system.sensor, crop=(64, 64)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = simulate(system, "coins", field_patches=3, rng=1, frames=12, filter_enabled=True)
    return m.save(tmp_path_factory.mktemp("field") / "f.npz")


def test_auto_costs_the_patches_in_its_time_budget(small_file):
    """``reconstruct --method auto --time-s S``: the PSF-aware step of a field-dependent file may solve every patch,
    so a budget that fits one shift-invariant solve does not pick it."""
    from metafovea.measurement import Measurement
    from metafovea.reconstruct.auto import choose_method, predicted_seconds

    m = Measurement.load(small_file)
    T, H, W = m.shape
    one = predicted_seconds("lsq", T, H * W, T, deconvolve="wavelet")
    nine = predicted_seconds("lsq", T, H * W, T, deconvolve="wavelet", field_patches=3)
    plain = predicted_seconds("lsq", T, H * W, T)
    assert nine - plain == pytest.approx(9 * (one - plain))
    c = choose_method(m, time_s=0.5 * (one + nine), known_alpha=True)
    assert c.deconvolve != "wavelet" and c.predicted_s <= 0.5 * (one + nine)
    assert choose_method(m, time_s=1.01 * nine, known_alpha=True).deconvolve == "wavelet"


def test_reconstruct_says_which_patches_it_solved_and_why(small_file, tmp_path, capsys):
    import json

    from metafovea.cli import main

    path = small_file
    base = ["reconstruct", str(path), "--method", "lsq", "--deconvolve", "wiener", "--no-figures"]
    assert main(base + ["--out", str(tmp_path / "a.npz")]) == 0
    out = capsys.readouterr().out
    assert "field-dependent PSF (3 x 3 patches): 3 x 3 patches;" in out and "the noise" in out
    assert main(base + ["--out", str(tmp_path / "b.npz"), "--field-psf", "on-axis", "--json"]) == 0
    f = json.loads(capsys.readouterr().out)["scene"]["field"]
    assert f["mode"] == "on-axis" and "left out" in f["why"]


def test_a_psf_file_carries_the_patches_and_bad_ones_are_named(strong, tmp_path):
    """``reconstruct --psf FILE``: a calibration's field-dependent PSF in the documented arrays."""
    _, _, psfs, _ = strong
    path = tmp_path / "psf.npz"
    np.savez(path, psf_x1=psfs.kernels[0], psf_x2=psfs.kernels[1], psf_patches_x2=psfs.patches[1])
    loaded = ChannelPSFs.from_file(path)
    assert loaded.n_patches == 3 and loaded.patches[0] is None
    assert np.array_equal(loaded.patches[1], psfs.patches[1])
    np.savez(path, psf_x1=psfs.kernels[0], psf_x2=psfs.kernels[1], psf_patches_x2=psfs.patches[1][:, :, :-1])
    with pytest.raises(InputError, match="psf_patches_x2"):
        ChannelPSFs.from_file(path)

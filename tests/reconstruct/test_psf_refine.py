"""The PSF refined from the data (:mod:`metafovea.reconstruct.psf_refine`): families built here with numpy (Gaussian
cores in a disk of haze, and defocused polychromatic Airy patterns of the independent forward model), data made
through one member by direct convolution of a larger scene (so the boundary is real), refined back to it; a case
where nothing is wrong keeps the nominal PSF; the families the optics engine builds are the simulator's PSFs."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
from scipy.signal import fftconvolve

from metafovea.errors import InputError
from metafovea.measurement import Measurement
from metafovea.reconstruct import ChannelPSFs, PSFFamily, deconvolve_measurement, refine_psf, separate_deconvolve
from metafovea.reconstruct.metrics import psnr
from metafovea.reconstruct.psf_refine import defocus_shift_um, psf_evidence, psf_family
from tests.independent.forward import disk_kernel, gauss_kernel, pixel_kernel

N = 96
SIGMAS = tuple(round(0.6 + 0.2 * k, 1) for k in range(9))  # the x1 family: 0.6 ... 2.2 px, nominal 1.0
WAVES = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5)  # the x2 family: defocus in waves, nominal 0


def _core_in_haze(sigma: float) -> np.ndarray:
    """A Gaussian core of ``sigma`` px carrying 60 % of the power in a 12 px disk of haze (35 x 35)."""
    return 0.6 * gauss_kernel(sigma, 35) + 0.4 * disk_kernel(12, 35)


def _airy(waves: float) -> np.ndarray:
    """A polychromatic 8-14 um Airy pattern at NA 0.25 on 24 um pixels (the core within one pixel), defocused by
    ``waves`` at 10 um (21 x 21: a wave and a half blurs over ~10 px)."""
    return np.asarray(pixel_kernel(0.25, 24.0, 1, 10, defocus_waves=waves), dtype=np.float64)


@pytest.fixture(scope="module")
def families() -> tuple[PSFFamily, PSFFamily]:
    x1 = PSFFamily(1, "core-sigma", np.array(SIGMAS), tuple(_core_in_haze(s) for s in SIGMAS), (0.0,) * len(SIGMAS),
                   nominal=1.0, unit="px")
    x2 = PSFFamily(2, "defocus", np.array(WAVES), tuple(_airy(w) for w in WAVES), (0.0,) * len(WAVES), nominal=0.0,
                   unit="waves")
    return x1, x2


def _scene(rng: np.random.Generator, n: int) -> np.ndarray:
    """A Gaussian scene with a 1/f^2 power spectrum (natural images' [Field 1987]), DN above the dark level: the
    scene model the evidence assumes (how it fares on other scenes: benchmarks/bench_psf_mismatch.py)."""
    f = np.hypot(np.fft.fftfreq(n)[:, None], np.fft.fftfreq(n)[None, :])
    f[0, 0] = 1.0
    return 200.0 + 3.0 * np.real(np.fft.ifft2(np.fft.fft2(rng.standard_normal((n, n))) / f))


def _data(k1: np.ndarray, k2: np.ndarray, seed: int, sigma: float = 1.0, T: int = 24):
    """Frames of both channels through ``k1``, ``k2`` (a 3x larger scene convolved and cropped), alpha, the scenes."""
    rng = np.random.default_rng(seed)
    c = slice(N, 2 * N)
    s = [_scene(rng, 3 * N) for _ in range(2)]
    u = [fftconvolve(si, k, mode="same")[c, c] for si, k in zip(s, (k1, k2))]
    a = np.cos(np.linspace(0, 2 * np.pi, T, endpoint=False) + 0.3) ** 2
    frames = a[:, None, None] * u[0] + (1 - a[:, None, None]) * u[1] + rng.normal(0, sigma, (T, N, N))
    return frames, a, (s[0][c, c], s[1][c, c])


def _psnr(frames, a, psfs: ChannelPSFs, truth, i: int) -> float:
    return psnr(separate_deconvolve(frames, a, psfs, method="wiener", sigma=1.0).scene[i], truth[i])


@pytest.mark.parametrize("seed", [2, 7])
def test_data_through_a_member_are_refined_to_it(families, seed):
    """Data made through x2's 1 wave of defocus are refined to that member (within one step), and the reconstruction
    with the refined PSFs is within 0.3 dB of the true PSFs' where the nominal ones lose more. x1's family (a
    Gaussian core in haze: a smooth attenuation, close to what the scene's spectrum may do) is identified within one
    step by the evidence, and where the tests let it replace the nominal one, it gains as the true one does."""
    f1, f2 = families
    t1, t2 = SIGMAS.index(2.0), WAVES.index(1.0)
    frames, a, truth = _data(f1.kernels[t1], f2.kernels[t2], seed)
    nominal = ChannelPSFs((f1.kernels[f1.nominal_index], f2.kernels[f2.nominal_index]))
    true = ChannelPSFs((f1.kernels[t1], f2.kernels[t2]))
    r = refine_psf(frames, a, nominal, [f1, f2], sigma=1.0)
    c1, c2 = r.channels
    assert abs(c1["best"] - 2.0) <= 0.2 + 1e-9 and c1["two_ln_b"] > r.min_evidence, c1
    assert c2["refined"] and abs(c2["chosen"] - 1.0) <= 0.25 + 1e-9, c2
    assert c2["two_ln_b"] >= r.min_evidence and c2["z"] >= c2["z_min"] and "differs from the file's" in c2["warning"]
    assert c2["curve"]["two_ln_b"][f2.nominal_index] == 0.0 and len(c2["curve"]["z"]) == len(WAVES)
    for i in range(2):
        p_true, p_ref, p_nom = (_psnr(frames, a, p, truth, i) for p in (true, r.psfs, nominal))
        if r.channels[i]["refined"]:
            assert p_ref > p_true - 0.3, (i, p_ref, p_true)
        assert p_nom < p_true - 0.3, (i, p_nom, p_true)
    assert any("refined to" in line for line in r.lines()) and r.refined


def test_nothing_wrong_keeps_the_nominal(families):
    """Data made through the nominal PSFs keep them: no member passes both tests, the output says so."""
    f1, f2 = families
    nominal = ChannelPSFs((f1.kernels[f1.nominal_index], f2.kernels[f2.nominal_index]))
    for seed in (3, 11):
        frames, a, _ = _data(*nominal.kernels, seed)
        r = refine_psf(frames, a, nominal, [f1, f2], sigma=1.0)
        assert not r.refined and r.psfs is nominal, r.lines()
        for c in r.channels:
            assert c["chosen"] == c["nominal"] and "nominal kept" in " ".join(r.lines())
            assert c["nominal_matches_file"]


def test_the_rule_needs_both_the_evidence_and_vuongs_test(families):
    """The gate can refuse: a threshold no evidence reaches keeps the nominal PSF although the evidence favours the
    true member, and says that a mismatch is possible."""
    f1, f2 = families
    frames, a, _ = _data(f1.kernels[f1.nominal_index], f2.kernels[WAVES.index(1.0)], 5)
    nominal = ChannelPSFs((f1.kernels[f1.nominal_index], f2.kernels[0]))
    (c,) = refine_psf(frames, a, nominal, [f2], sigma=1.0, min_evidence=1e12).channels
    assert not c["refined"] and c["best"] == 1.0 and c["chosen"] == 0.0
    assert c["two_ln_b"] > 10 and c["z"] > c["z_min"] and "nominal PSF is kept" not in (c["warning"] or "")


def test_a_family_without_the_files_psf_is_stated(families):
    f1, _ = families
    frames, a, _ = _data(f1.kernels[f1.nominal_index], _airy(0.0), 4)
    other = ChannelPSFs((disk_kernel(3, 35), _airy(0.0)))  # the "file's" x1 PSF is none of the family's
    (c,) = refine_psf(frames, a, other, [f1], sigma=1.0).channels
    assert not c["nominal_matches_file"] and "not the file's" in c["warning"]


def test_evidence_is_highest_at_the_true_member_of_a_power_law_scene():
    """On a Gaussian scene of the model's own kind (a 1/f^2 spectrum), the evidence peaks at the true blur."""
    rng = np.random.default_rng(0)
    n = 3 * N
    f = np.hypot(np.fft.fftfreq(n)[:, None], np.fft.fftfreq(n)[None, :])
    f[0, 0] = 1.0
    s = np.real(np.fft.ifft2(np.fft.fft2(rng.normal(size=(n, n))) / f)) * 3.0
    ks = [gauss_kernel(w, 25) for w in (0.8, 1.2, 1.6, 2.0, 2.4)]
    z = fftconvolve(s, ks[2], mode="same")[N:2 * N, N:2 * N] + rng.normal(0, 0.5, (N, N))
    ev = psf_evidence(z, 0.25, ks, reference=0)
    assert int(np.argmax(ev["two_ln_b"])) == 2 and ev["two_ln_b"][0] == 0.0
    assert ev["log_spectrum"].shape == (5, ev["knots_cycles_per_px"].size)


def test_deconvolve_measurement_refines_and_says_so(families):
    """``deconvolve_measurement(refine_psf=families)``: the refined PSFs are used, ``info['psf_refinement']`` and
    the summary carry what was chosen."""
    f1, f2 = families
    frames, a, truth = _data(f1.kernels[f1.nominal_index], f2.kernels[WAVES.index(1.0)], 9)
    m = Measurement(frames=frames.astype(np.float32), times_s=np.arange(frames.shape[0]) / 12.0, alpha=a,
                    meta={"dark_dn": 0.0}, extras={"psf_x1": f1.kernels[f1.nominal_index], "psf_x2": f2.kernels[0]})
    plain = deconvolve_measurement(m, method="wiener", sigma=1.0)
    d = deconvolve_measurement(m, method="wiener", sigma=1.0, refine_psf=[f2])
    info = d.info["psf_refinement"]
    assert info["refined"] and info["channels"][0]["chosen"] == pytest.approx(1.0)
    assert "x2 defocus: refined to +1 waves" in info["lines"][0] and d.summary()["psf_refinement"] is info
    assert psnr(d.scene[1], truth[1]) > psnr(plain.scene[1], truth[1]) + 0.3
    assert "psf_refinement" not in plain.info


def test_bad_families_are_input_errors(families):
    f1, f2 = families
    with pytest.raises(InputError, match="values"):
        PSFFamily(1, "x", np.array([1.0, 0.5]), (np.ones((1, 1)),) * 2, (0.0, 0.0), nominal=1.0)
    with pytest.raises(InputError, match="nominal"):
        PSFFamily(1, "x", np.array([0.0, 1.0]), (np.ones((1, 1)),) * 2, (0.0, 0.0), nominal=0.5)
    with pytest.raises(InputError, match="psf_x"):
        PSFFamily(1, "x", np.array([0.0, 1.0]), (np.ones((2, 2)),) * 2, (0.0, 0.0))
    frames, a, _ = _data(f1.kernels[2], f2.kernels[0], 1, T=6)
    with pytest.raises(InputError, match="one family per channel"):
        refine_psf(frames, a, ChannelPSFs((f1.kernels[2], f2.kernels[0])), [f1, f1])
    with pytest.raises(InputError, match="min_evidence"):
        refine_psf(frames, a, ChannelPSFs((f1.kernels[2], f2.kernels[0])), [f1], min_evidence=-1)


def test_defocus_shift_is_the_pupil_phase_change():
    """``W`` waves peak-to-valley: the phase ``k dz sqrt(1 - s^2)`` differs by ``W`` between the axis and the rim."""
    na = 37.5 / np.hypot(37.5, 150.0)  # the foveal lens: 75 mm at f = 150 mm
    dz = defocus_shift_um(na, 10.0, 0.25)
    assert dz * (1 - np.sqrt(1 - na ** 2)) / 10.0 == pytest.approx(0.25)
    assert 83 < dz < 84  # a quarter wave is ~84 um of focus (8 lambda N^2 W, paraxially: 80 um)


def test_the_engines_family_is_the_simulators_psf():
    """The family's nominal member is the simulator's ``psf_x1``; its focal-length member is the ``psf_x1`` of the
    simulated camera whose lens has that focal length (the sensor where it was): the family is built as the file's
    PSFs are."""
    from metafovea.config import SensorDesign, SystemDesign
    from metafovea.imaging.simulate import simulate

    system = dataclasses.replace(SystemDesign.paper(), sensor=dataclasses.replace(SensorDesign(), crop=(32, 32)))
    opts = dict(posts="ideal", optical_train=False, filter_enabled=True, frames=3, calibration_frames=0)
    fam = psf_family(system, channel="foveal", kind="focal-length", values=(0.0, 0.02), filter_enabled=True,
                     posts="ideal", optical_train=False, cache=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the moved focus is beyond the depth of focus: warned, as it should be
        m0 = simulate(system, "siemens-star", rng=0, **opts)
        lens = system.foveal.with_(f_um=system.foveal.f_um * 1.02)
        m1 = simulate(dataclasses.replace(system, foveal=lens), "siemens-star", rng=0, **opts)
    for j, m in enumerate((m0, m1)):
        k = m.extras["psf_x1"]
        assert fam.kernels[j].shape == k.shape
        assert np.max(np.abs(fam.kernels[j] - k)) < 1e-6 * float(np.max(k))
        assert fam.pedestals[j] == pytest.approx(m.psf_pedestals[0], abs=1e-9)
    assert np.max(np.abs(fam.kernels[1] - fam.kernels[0])) > 0.1 * float(np.max(fam.kernels[0]))


def test_the_foveal_relation_confirms_a_refinement():
    """With the channels' scale, a refinement must also leave the foveal relation (the foveal estimate scaled down
    against the perifoveal centre) no worse: on a pair that satisfies it exactly, the true member improves it."""
    from metafovea.reconstruct.synthetic import scene

    f2 = PSFFamily(2, "defocus", np.array(WAVES), tuple(_airy(w) for w in WAVES), (0.0,) * len(WAVES), unit="waves")
    x1, x2 = (200.0 + 100.0 * x for x in scene(N))
    k1, k2 = gauss_kernel(1.0, 9), f2.kernels[WAVES.index(1.0)]
    u = [fftconvolve(np.pad(x, k.shape[0] // 2, mode="reflect"), k, mode="valid") for x, k in ((x1, k1), (x2, k2))]
    rng = np.random.default_rng(0)
    a = np.cos(np.linspace(0, 2 * np.pi, 24, endpoint=False) + 0.3) ** 2
    frames = a[:, None, None] * u[0] + (1 - a[:, None, None]) * u[1] + rng.normal(0, 0.5, (24, N, N))
    r = refine_psf(frames, a, ChannelPSFs((k1, f2.kernels[0])), [f2], sigma=0.5, foveal_scale=6.0,
                   estimate=lambda p: separate_deconvolve(frames, a, p, method="wiener", sigma=0.5).scene)
    (c,) = r.channels
    base, cand = c["relation_misfit"]
    assert c["refined"] and c["chosen"] == pytest.approx(1.0, abs=0.25) and cand < base, c

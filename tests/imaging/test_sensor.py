"""metafovea.imaging.sensor: DN response, temporal noise at the NETD, low-rank FPN, ADC."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.errors import InputError
from metafovea.imaging import simulate
from metafovea.imaging.sensor import SensorModel


# ---------------------------------------------------------------------------------------------
# physics references
# ---------------------------------------------------------------------------------------------
def test_noise_statistics_match_netd(small_system, delta_psf, quiet):
    s = small_system(64, netd_k=0.04)
    m = simulate(s, "uniform", frames=40, psf=delta_psf, supersample=1, fpn_rank=0, quantize=False,
                 relative_illumination=False, rng=3)
    mix = m.alpha[:, None, None] * m.truth_x1 + (1 - m.alpha[:, None, None]) * m.truth_x2
    n = (m.frames - mix).astype(np.float64)
    sigma_dn = 0.04 * m.meta["counts_per_k"]
    assert n.mean() == pytest.approx(0.0, abs=0.01 * sigma_dn)
    assert n.std() == pytest.approx(sigma_dn, rel=0.02)
    # the DN change per kelvin at 300 K through the perifoveal channel is counts_per_k times its optical-train
    # throughput (the NETD is the sensor's behind lossless F/1 optics), so the temperature-referred noise of an
    # alpha = 0 frame is the NETD over that throughput
    hot = simulate(s, "uniform", frames=1, psf=delta_psf, supersample=1, relative_illumination=False,
                   scene_params={"temperature_k": 300.05}, **quiet)
    cold = simulate(s, "uniform", frames=1, psf=delta_psf, supersample=1, relative_illumination=False,
                    scene_params={"temperature_k": 299.95}, **quiet)
    dn_per_k = float((hot.truth_x2 - cold.truth_x2).mean()) / 0.1
    assert dn_per_k == pytest.approx(m.meta["dn_per_k_300K"]["x2"], rel=2e-3)
    throughput = m.meta["optical_train"][1]["throughput"]
    assert 0.2 < throughput < 0.5  # two wafers of ~55-60 % each
    assert sigma_dn / dn_per_k == pytest.approx(0.04 / throughput, rel=3e-3)
    assert m.meta["netd_effective_k"]["x2"] == pytest.approx(0.04 / throughput, rel=1e-9)
    tr1 = m.meta["optical_train"][0]
    na_gain = (0.24254 / 0.44721) ** 2
    assert m.meta["netd_effective_k"]["x1"] == pytest.approx(0.04 / (tr1["throughput"] * na_gain), rel=1e-4)


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


def test_fpn_in_measurement_and_quantisation(small_system, delta_psf):
    s = small_system(48, fpn_rank=5, fpn_amplitude=0.1)
    m = simulate(s, "bars", frames=3, psf=delta_psf, supersample=1, noise=False, quantize=True, rng=1)
    assert np.array_equal(m.frames, np.rint(m.frames)) and m.frames.max() <= 2 ** 14 - 1
    mix = m.alpha[:, None, None] * m.truth_x1 + (1 - m.alpha[:, None, None]) * m.truth_x2 + m.fpn
    assert np.abs(m.frames - mix).max() <= 0.5 + 1e-3
    assert np.linalg.matrix_rank(m.fpn.astype(np.float64), tol=1e-3 * np.abs(m.fpn).max()) == 5


def test_adc_rounds_and_clips_to_its_range():
    sm = SensorModel(shape=(8, 8), adc_bits=4, fpn_rank=0, noise=False)
    frames = np.array([-3.2, 0.4, 7.5, 14.6, 99.0], np.float32).reshape(5, 1, 1) * np.ones((1, 8, 8), np.float32)
    sm.add_noise_and_digitise(frames, rng=0)
    np.testing.assert_array_equal(frames[:, 0, 0], [0.0, 0.0, 8.0, 15.0, 15.0])


# ---------------------------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------------------------
def test_small_crop_errors_name_the_crop_and_where_fpn_rank_comes_from():
    """A too-small crop was reported as 'shape'; an fpn_rank above the crop did not say that it comes from
    fpn_rank (--fpn-rank at the CLI) or the system file's [sensor] fpn_rank."""
    with pytest.raises(InputError, match="sensor crop"):
        SensorModel(shape=(7, 64))
    with pytest.raises(InputError, match=r"fpn_rank=\.\.\. or the system file's \[sensor\] fpn_rank") as e:
        SensorModel(shape=(12, 40), fpn_rank=20)
    assert e.value.parameter == "fpn_rank" and "12" in e.value.allowed
    assert SensorModel(shape=(12, 40), fpn_rank=12).fpn_rank == 12

"""A small version of the deviation grid (``benchmarks/bench_real_recordings.py``) for CI: recordings of the
independent forward model at the paper's size, documented keys only, reconstructed with unknown alpha
(``alternating``) and scored against the least-squares oracle on the true alpha, with the issue's targets:
alpha MAE <= 2e-3 and both images within 1 dB of the oracle."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.measurement import Measurement
from metafovea.reconstruct import reconstruct_measurement
from tests.independent.forward import RANGE_ENDS, Camera, Deviations, record

FRAMES = 24
MAE_MAX = 2e-3
DB_MAX = 1.0


def psnr(est: np.ndarray, ref: np.ndarray) -> float:
    ref = ref.astype(np.float64)
    ok = np.isfinite(est)
    mse = float(np.mean((est[ok].astype(np.float64) - ref[ok]) ** 2))
    return 10 * np.log10(float(ref.max() - ref.min()) ** 2 / mse)


def recording(tmp_path, dev: Deviations) -> Measurement:
    return Measurement.load(record("mixed", dev, frames=FRAMES, seed=0).write(tmp_path / "rec.npz"))


def test_the_oracle_reaches_the_noise_floor(tmp_path):
    """The file's alpha and truth are what the frames hold: LSQ on the true alpha recovers the truth to the noise
    its 2 x 2 normal matrix predicts (the forward model and the reader agree)."""
    m = recording(tmp_path, Deviations())
    res = reconstruct_measurement(m, "lsq", window=FRAMES)
    a = np.stack([m.alpha, 1 - m.alpha], axis=1)
    cov = np.linalg.inv(a.T @ a) * (Camera().noise_dn ** 2 + 1 / 12)
    for k, (est, ref) in enumerate(((res.reconstruction.x1, m.truth_x1), (res.reconstruction.x2, m.truth_x2))):
        rms = float(np.sqrt(np.mean((est.astype(np.float64) - ref) ** 2)))
        assert rms == pytest.approx(np.sqrt(cov[k, k]), rel=0.05)


GAUGE = "issue 30: documented keys alone do not engage the polariser model; the foveal constraint fixes the gauge"
CASES = {
    "nominal": (Deviations(), "issue 30: unknown-alpha images 6 (x1) and 14 (x2) dB below the oracle with no "
                              "deviation (the polariser model is not engaged; the TV prior costs 1.4 / 3.6 dB more)"),
    "jitter 2 deg": (RANGE_ENDS["jitter 2 deg"], GAUGE + "; jitter: images 6 / 14 dB below the oracle"),
    "vignetting 20 %": (RANGE_ENDS["vignetting 20 %"], GAUGE + "; vignetting breaks it: MAE 2.8e-2"),
    "centre (3, -3) px": (RANGE_ENDS["centre (3, -3) px"], GAUGE + "; a 3 px centre offset breaks it: MAE 6e-2"),
}


@pytest.mark.parametrize("name", [pytest.param(k, marks=pytest.mark.xfail(strict=True, reason=why))
                                  for k, (_, why) in CASES.items()])
def test_unknown_alpha_meets_the_issue_targets(tmp_path, name):
    m = recording(tmp_path, CASES[name][0])
    oracle = reconstruct_measurement(m, "lsq", window=FRAMES).reconstruction
    res = reconstruct_measurement(m, "alternating", window=FRAMES)
    rec = res.reconstruction
    mae = float(np.mean(np.abs(rec.alpha - m.alpha)))
    assert float(np.mean(np.abs(1 - rec.alpha - m.alpha))) > 0.1, "alpha returned as 1 - alpha"
    gaps = {k: psnr(getattr(oracle, k), t) - psnr(getattr(rec, k), t)
            for k, t in (("x1", m.truth_x1), ("x2", m.truth_x2))}
    assert mae <= MAE_MAX and max(gaps.values()) <= DB_MAX, f"alpha MAE {mae:.1e}, dB below the oracle {gaps}"

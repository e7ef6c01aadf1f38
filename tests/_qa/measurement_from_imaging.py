"""Measurement file-format tests moved verbatim out of tests/test_imaging.py (they test metafovea/measurement.py):
merge into tests/test_measurement.py, then delete this file. The helpers below are the ones test_imaging.py
defined for them."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from metafovea.config import SensorDesign, SystemDesign
from metafovea.errors import InputError
from metafovea.measurement import Measurement
from metafovea.imaging import simulate


def small_system(n: int = 48, **sensor_kw) -> SystemDesign:
    return replace(SystemDesign.paper(), sensor=replace(SensorDesign(), crop=(n, n), **sensor_kw))


def delta_psf() -> dict:
    return {"foveal": np.ones((1, 1)), "perifoveal": np.ones((1, 1))}


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

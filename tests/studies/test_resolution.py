"""``metafovea study resolution --fast``: the Siemens star at 9:1 (paper point 4). ~3 s on 2 cores."""

from __future__ import annotations

import json

import numpy as np
import pytest

from metafovea.cli import main
from metafovea.studies.resolution import spoke_contrast


def test_spoke_contrast_reads_the_fundamental():
    phi = np.arange(720) * 2 * np.pi / 720
    assert abs(spoke_contrast(10.0 + 2.0 * np.cos(36 * phi) + np.cos(5 * phi), 36) - 0.2) < 1e-9
    assert spoke_contrast(np.full(720, 5.0), 36) < 1e-12


@pytest.mark.slow  # a study, at its --fast size, run twice (the same seed, the same JSON)
def test_resolution_fast(tmp_path, capsys):
    """The foveal image keeps the spokes' modulation to finer line pairs than the perifoveal one upsampled x9,
    which inside its own Nyquist radius (36 x 9 / pi = 103 foveal px) carries almost none."""
    out = tmp_path / "res"
    assert main(["study", "resolution", "--fast", "--out", str(out), "-q"]) == 0
    printed = capsys.readouterr().out
    assert "study resolution" in printed and "paper:" in printed
    for suffix in ("json", "png", "html"):
        f = out / f"resolution.{suffix}"
        assert f.is_file() and f.stat().st_size > 200, f
    assert "data:image/png;base64" in (out / "resolution.html").read_text()
    rep = json.loads((out / "resolution.json").read_text())
    assert {"expected", "observed", "holds", "note"} <= set(rep["trend"]) and rep["why"] and rep["modelled"]
    assert "object distance" in rep["why"] and "64/290" in rep["why"]
    res = rep["results"]
    n = rep["parameters"]["radii"]
    m1 = np.array(res["curves"]["foveal"]["modulation"][:n])
    m2 = np.array(res["curves"]["perifoveal_upsampled"]["modulation"][:n])
    lp = np.array(res["lp_per_px"][:n])
    assert np.all(np.diff(lp) < 0) and lp[0] <= 0.5 + 1e-9  # finest first, no finer than the foveal Nyquist
    assert rep["trend"]["holds"]
    # the perifoveal image reaches 0.5 nowhere on these radii: said in words, never 'nan' (page, summary), null in JSON
    assert rep["trend"]["perifoveal_limit_lp_per_px"] is None and "nowhere on the sweep" in rep["trend"]["observed"]
    assert "nan" not in printed.lower() and "nan lp" not in (out / "resolution.html").read_text()
    assert np.all(m1 > m2)
    assert m1[-1] > 0.5 and m1[-1] > m1[0]  # the foveal modulation falls toward the centre, as a real lens's
    assert np.all(m2 < 0.1)  # all these radii are inside the perifoveal Nyquist radius (~103 px)
    assert set(res["circles"]) == {"9", "18", "31"}
    assert main(["study", "resolution", "--fast", "--out", str(tmp_path / "again"), "-q"]) == 0
    again = json.loads((tmp_path / "again" / "resolution.json").read_text())
    assert {k: v for k, v in again.items() if k != "timing"} == {k: v for k, v in rep.items() if k != "timing"}

"""The recording schema is the reconstruction's only input: every key the documentation does not list is stripped
from simulated recordings, and the reconstruction (known and unknown alpha, the fixed pattern from shutter frames or
blind, the PSF-aware step) comes out the same to 1e-9."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from metafovea.config import SensorDesign, SystemDesign
from metafovea.imaging import simulate
from metafovea.io import atomic_save_npz, load_npz
from metafovea.measurement import RECORDING_ARRAYS, RECORDING_META, SCORING_ARRAYS, TRUTH_KEY, Measurement
from metafovea.reconstruct import reconstruct_measurement
from metafovea.reconstruct.deconvolve import deconvolve_result

DOC = Path(__file__).resolve().parents[2] / "docs" / "measurement_format.md"


def documented() -> tuple[set[str], set[str], set[str]]:
    """(recording arrays, recording metadata keys, scoring-only names) as the documentation's section "The recording
    schema" lists them: the first column of its two tables, and the backquoted names of its scoring paragraph."""
    text = DOC.read_text()
    sec = text[text.index("## The recording schema"):]
    sec = sec[:sec.index("\n## ", 5)]
    tables = re.findall(r"((?:^\|.*\|\n)+)", sec, flags=re.M)
    arrays, meta = ({k for row in t.splitlines()[2:] for k in re.findall(r"`([\w]+)`", row.split("|")[1])}
                    for t in tables[:2])
    scoring = sec[sec.index("Scoring only"):]
    scoring = set(re.findall(r"`([\w]+)`", scoring.split("(what the writer")[0]))
    return arrays, meta, scoring


def strip(path: Path, out: Path) -> Path:
    """``path`` with only the documented arrays and metadata keys (and ``truth``, scoring only) kept."""
    arrays, meta = load_npz(path, name="measurement")
    docs_arrays, docs_meta, scoring = documented()
    keep_meta = {k: v for k, v in meta.items() if k in docs_meta or k in scoring or k == "kind"}
    keep = {k: v for k, v in arrays.items() if k in docs_arrays or k in scoring}
    assert set(meta) - set(keep_meta) >= {"sensor", "psf", "system", "scene_info"}  # the strip removes something
    atomic_save_npz(out, keep_meta, compress=False, **keep)
    return out


def test_the_code_reads_what_the_documentation_lists():
    arrays, meta, scoring = documented()
    assert arrays == set(RECORDING_ARRAYS)
    assert meta == set(RECORDING_META)
    assert scoring == set(SCORING_ARRAYS) | {TRUTH_KEY}


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A free-running polariser (unknown alpha), a rank-2 fixed pattern with shutter frames, the PSFs on file, and
    the same file stripped to the schema; a second pair without shutter frames (the blind fixed-pattern estimate)."""
    d = tmp_path_factory.mktemp("schema")
    system = replace(SystemDesign.paper(), sensor=replace(SensorDesign(), crop=(48, 48)))
    kw = dict(frames=12, psf="airy", supersample=1, polarizer_mode="free", rng=3)
    out = {}
    for name, cal in (("shutter", 8), ("blind", 0)):
        m = simulate(system, "siemens-star", calibration_frames=cal, **kw)
        full = m.save(d / f"{name}.npz")
        out[name] = (Measurement.load(full), Measurement.load(strip(full, d / f"{name}_stripped.npz")))
    return out


@pytest.mark.parametrize("name, method, fpn", [("shutter", "lsq", "auto"), ("shutter", "alternating", "auto"),
                                               ("blind", "alternating", "auto"), ("shutter", "alternating", "none")])
def test_stripping_undocumented_keys_changes_nothing(files, name, method, fpn):
    full, stripped = files[name]
    a = reconstruct_measurement(full, method, fpn=fpn, window=12)
    b = reconstruct_measurement(stripped, method, fpn=fpn, window=12)
    for x, y in ((a.reconstruction.x1, b.reconstruction.x1), (a.reconstruction.x2, b.reconstruction.x2),
                 (a.reconstruction.alpha, b.reconstruction.alpha)):
        np.testing.assert_allclose(np.asarray(y, np.float64), np.asarray(x, np.float64), rtol=0, atol=1e-9)
    assert a.metrics == b.metrics and a.alpha_mae == b.alpha_mae
    if method == "alternating":
        spec = a.reconstruction.info["polarizer_spec"]
        assert spec["mode"] == "free" and spec["sources"]["mode"] == "file" and not spec["assumed"]
        assert spec == b.reconstruction.info["polarizer_spec"]


def test_the_psf_aware_step_reads_the_schema_only(files):
    full, stripped = files["shutter"]
    out = []
    for m in (full, stripped):
        res = reconstruct_measurement(m, "lsq", window=12)
        out.append(deconvolve_result(m, res, "wiener"))
    for x, y in zip(out[0].scene, out[1].scene):
        np.testing.assert_allclose(np.asarray(y, np.float64), np.asarray(x, np.float64), rtol=0, atol=1e-9)
    def timeless(d):
        return {k: v for k, v in (d or {}).items() if "seconds" not in k}

    assert timeless(out[0].info.get("scores")) == timeless(out[1].info.get("scores"))


def test_a_reader_of_an_undocumented_key_is_caught(files, monkeypatch):
    """Planted: the fixed pattern's rank read from the simulator's private 'sensor' block (as it was), with the
    pipeline's view of the schema switched off: the stripped file reconstructs differently, and the check sees it."""
    monkeypatch.setattr(Measurement, "as_recording", lambda self: self)
    monkeypatch.setattr(Measurement, "fpn_rank", property(lambda self: (self.meta.get("sensor") or {}).get("fpn_rank")))
    full, stripped = files["blind"]
    a = reconstruct_measurement(full, "alternating", window=12)
    b = reconstruct_measurement(stripped, "alternating", window=12)
    assert np.max(np.abs(np.asarray(a.reconstruction.x1, float) - np.asarray(b.reconstruction.x1, float))) > 1e-3

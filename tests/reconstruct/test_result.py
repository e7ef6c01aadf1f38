"""The Reconstruction file (round trip, frozen, refuses other files) and the pipeline result's views."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.errors import InputError
from metafovea.measurement import FovealConstraint
from metafovea.reconstruct import PipelineResult, Reconstruction, reconstruct
from metafovea.reconstruct.synthetic import measure


def test_reconstruction_save_load(tmp_path, truth, alpha8):
    Y = measure(*truth, alpha8, sigma=0.01, rng=0, dtype=np.float32)
    r = reconstruct(Y, alpha8, method="lsq")
    p = tmp_path / "rec.npz"
    r.save(p)
    q = Reconstruction.load(p)
    assert np.array_equal(q.x1, r.x1) and q.x1.dtype == np.float32 and q.method == "lsq"
    assert q.info["condition"] == pytest.approx(r.info["condition"])
    with pytest.raises(AttributeError):
        r.method = "x"  # frozen
    np.savez(tmp_path / "other.npz", a=np.zeros(2))
    with pytest.raises(InputError):
        Reconstruction.load(tmp_path / "other.npz")


def test_pipeline_result_stacks_outputs_and_counts_nan():
    x = np.zeros((4, 4), np.float32)
    x[1, 2] = np.nan
    rec = Reconstruction(x1=x, x2=np.ones((4, 4), np.float32), alpha=np.array([0.5]), method="snapshot",
                         info={"iterations": 3})
    res = PipelineResult(reconstruction=rec, spans=((2, 3),), seconds=0.5, constraint=FovealConstraint(), frames=5)
    assert res.outputs == 1 and res.x1s.shape == (1, 4, 4) and res.nonfinite_pixels == 1
    s = res.summary(["a.npz"])
    assert s["outputs"] == 1 and s["ms_per_output"] == pytest.approx(500.0) and s["nonfinite_pixels"] == 1
    assert s["foveal_constraint"] == {"scale": 6.0, "foveal_gain": 1.0, "foveal_offset": 0.0}
    assert s["iterations"] == 3 and s["files"] == ["a.npz"] and "metrics" not in s


def test_alpha_per_frame_takes_each_windows_estimate_where_the_sequence_has_none():
    rec = Reconstruction(x1=np.zeros((2, 4, 4)), x2=np.zeros((2, 4, 4)), alpha=np.full(10, np.nan),
                         info={"window_starts": [0, 6], "alpha_windows": [[0.1, 0.2, 0.3], [0.7, 0.8, 0.9, 1.0]]})
    a = rec.alpha_per_frame(10)
    assert np.allclose(a[:3], [0.1, 0.2, 0.3]) and np.allclose(a[6:], [0.7, 0.8, 0.9, 1.0])
    assert np.all(np.isnan(a[3:6]))
    own = Reconstruction(x1=np.zeros((4, 4)), x2=np.zeros((4, 4)), alpha=np.linspace(0, 1, 10),
                         info={"window_starts": [0], "alpha_windows": [[0.5] * 3]})
    assert np.allclose(own.alpha_per_frame(10), np.linspace(0, 1, 10))  # the sequence's own wins


def test_the_written_figures_carry_the_recordings_units(tmp_path, monkeypatch):
    """The side-by-side figure's colour bars name the recording's units (an imported camera's counts, not DN)."""
    import metafovea.reconstruct.files as files
    from metafovea.reconstruct import write_outputs

    figs = []
    real = files.fig_to_png
    monkeypatch.setattr(files, "fig_to_png", lambda fig, *a, **k: figs.append(fig) or real(fig, *a, **k))
    rng = np.random.default_rng(0)
    x1, x2 = rng.uniform(0, 1, (2, 8, 8)).astype(np.float32)
    rec = Reconstruction(x1=x1, x2=x2, alpha=np.array([0.5]), method="lsq")
    res = PipelineResult(reconstruction=rec, spans=((0, 2),), seconds=0.1, constraint=FovealConstraint(), frames=2)
    pngs = [tmp_path / f"r{i}.png" for i in range(3)]
    written = write_outputs(res, tmp_path / "r.npz", pngs, units="counts")
    assert len(written) == 4 and all(p.stat().st_size > 0 for p in pngs)
    labels = [ax.get_ylabel() for ax in figs[0].axes if ax.get_label() == "<colorbar>"]
    assert labels == ["signal (counts)", "signal (counts)"]

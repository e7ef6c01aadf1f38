"""The timing check: duplicated frames removed (same time or same pixels), dropped frames and non-uniform intervals
detected and recorded in the Measurement's meta, timestamps that go backwards refused."""

from __future__ import annotations

import json

import numpy as np
import pytest

from metafovea.errors import InputError
from metafovea.measurement import Measurement
from metafovea.recordings import check_timing

h5py = pytest.importorskip("h5py")


def _noisy(n, shape=(8, 8), seed=0):
    return np.random.default_rng(seed).integers(1000, 2000, (n, *shape)).astype(np.uint16)


def test_clean_sequence_is_uniform():
    kept, rep = check_timing(_noisy(10), np.arange(10) / 30.0)
    assert kept.tolist() == list(range(10)) and rep.uniform and not rep.dropped and not rep.warnings()
    assert rep.frame_rate_hz == pytest.approx(30.0)


def test_dropped_frames_are_counted_not_filled():
    t = np.delete(np.arange(20) / 30.0, [5, 6, 12])  # two gaps: 2 frames and 1 frame lost
    kept, rep = check_timing(_noisy(t.size), t)
    assert kept.size == t.size and rep.n_dropped == 3
    assert rep.dropped == [{"after_frame": 4, "missing": 2}, {"after_frame": 9, "missing": 1}]
    assert rep.uniform  # a gap is not jitter


def test_duplicates_are_removed_first_copy_kept():
    f = _noisy(10)
    f[4] = f[3]  # a frame grabber repeating a buffer: same pixels, its own timestamp
    t = np.arange(10) / 30.0
    t[7] = t[6]  # a repeated timestamp
    kept, rep = check_timing(f, t)
    assert rep.duplicates_removed == [4, 7] and 4 not in kept and 3 in kept and 6 in kept
    assert rep.duplicate_kinds == {"same_time": 1, "same_pixels": 1}
    # a repeated buffer or time stands where an exposure was lost: the gap each removal leaves is a dropped frame
    assert rep.n_dropped == 2 and [d["missing"] for d in rep.dropped] == [1, 1]


def test_non_uniform_intervals_are_flagged():
    t = np.cumsum(np.r_[0.0, np.full(15, 1 / 30.0) * (1 + 0.03 * np.sin(np.arange(15)))])
    _, rep = check_timing(_noisy(16), t)
    assert not rep.uniform and 0.025 < rep.max_deviation_rel < 0.04  # 3 % about the median interval
    assert any("non-uniform" in w for w in rep.warnings())


def test_a_given_frame_rate_is_the_nominal_interval():
    """With the file's times and --frame-rate, a steady half-rate recording is all drops."""
    _, rep = check_timing(_noisy(6), np.arange(6) / 15.0, frame_rate_hz=30.0)
    assert rep.n_dropped == 5


def test_backwards_timestamps_are_an_error():
    with pytest.raises(InputError) as e:
        check_timing(_noisy(4), np.array([0.0, 0.1, 0.05, 0.2]))
    assert e.value.parameter == "times"


def test_import_records_timing_in_meta(tmp_path, cli):
    """Through metafovea import: the warnings (one line each), the summary and meta['timing']."""
    f = _noisy(12)
    f[3] = f[2]
    t = np.delete(np.arange(13) / 30.0, [8])
    with h5py.File(tmp_path / "rec.h5", "w") as h:
        h["frames"], h["timestamps"] = f, t
    rc, out, err = cli("import", tmp_path / "rec.h5", "--json")
    assert rc == 0
    s = json.loads(out)
    assert s["frames"] == 11 and s["duplicates_removed"] == 1 and s["n_dropped"] == 2
    assert "1 duplicated frame(s) removed" in err and "2 dropped frame(s)" in err
    assert all(line.startswith("metafovea import: warning:") for line in err.strip().splitlines())
    m = Measurement.load(tmp_path / "rec.npz")
    assert m.meta["timing"]["duplicates_removed"] == [3] and m.meta["timing"]["n_dropped"] == 2
    np.testing.assert_allclose(m.times_s, np.delete(t, 3))

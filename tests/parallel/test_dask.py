"""The Dask executor against the serial path on a real LocalCluster of worker processes: library arrays and layout
bytes bit for bit, a worker killed mid-job (the task is rerun elsewhere; a task that kills every worker it meets
stops the job with WorkerLost, never a partial result), and bad scheduler addresses."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

from metafovea.errors import InputError  # noqa: E402
from metafovea.library import LIBRARY_ARRAYS, compute_library  # noqa: E402
from metafovea.parallel import DaskExecutor, WorkerLost, run_tasks  # noqa: E402


def _register() -> None:
    import cloudpickle

    # this module's task functions travel by value (the workers cannot import the tests)
    cloudpickle.register_pickle_by_value(sys.modules[__name__])


@pytest.fixture(scope="module")
def cluster():
    _register()
    ex = DaskExecutor("local:2")
    yield ex
    ex.close()


@pytest.fixture
def fragile_cluster():
    """A cluster of its own for the tests that kill workers: a task may kill one worker and be rerun once."""
    import dask

    _register()
    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        ex = DaskExecutor("local:2")
        ex.no_worker_timeout_s = 20.0
        yield ex
        ex.close()


def test_library_on_a_cluster_is_bit_identical_to_the_serial_sweep(tmp_path, cluster):
    widths = [1.0, 1.5, 2.0, 2.5]
    kw = dict(harmonics=5, use_cache=False, progress=False, tol=None)
    serial = compute_library(widths, None, (9.5, 10.0), workers=1, cache_dir=tmp_path / "a", **kw)
    spread = compute_library(widths, None, (9.5, 10.0), scheduler=cluster.address, cache_dir=tmp_path / "b", **kw)
    for k in LIBRARY_ARRAYS:
        a, b = getattr(serial, k, None), getattr(spread, k, None)
        if a is not None:
            assert np.array_equal(np.asarray(a), np.asarray(b)), k


def _small_spec():
    from metafovea.config import LensDesign
    from metafovea.layout import make_spec

    return make_spec(LensDesign("small", 1500.0, 1200.0, polarization="x"), band_rows=16, ring_width_um=100.0,
                     mark_offset_um=50.0, mark_size_um=40.0, mark_width_um=4.0)


@pytest.mark.parametrize("fmt,kw", [("oas", {}), ("gds", {"max_refs": 4096})])
def test_layout_export_on_a_cluster_writes_tiles_and_stitches_the_same_bytes(tmp_path, cluster, fmt, kw):
    """The workers write one tile per band, the client stitches them in band order: the serial file's bytes (also
    hierarchical GDSII, whose footer needs every band's leaf count), the tiles removed once the file is in place."""
    from metafovea.layout import ExportOptions, export_file

    spec = _small_spec()
    a = export_file(spec, tmp_path / f"serial.{fmt}", fmt, ExportOptions(workers=1, **kw))
    b = export_file(spec, tmp_path / f"dask.{fmt}", fmt, ExportOptions(scheduler=cluster.address, **kw))
    assert Path(a["path"]).read_bytes() == Path(b["path"]).read_bytes()
    assert b["bands"] > 2 and b["counts"] == a["counts"] and b["extra"]["tiles_dir"].endswith(f".dask.{fmt}.tiles")
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"dask.{fmt}", f"serial.{fmt}"]


def test_cluster_export_resumes_from_its_tiles_and_names_a_missing_or_corrupt_tile(tmp_path, cluster):
    from metafovea.layout import ExportOptions, export_layout
    from metafovea.layout.tilefiles import tile_paths

    spec = _small_spec()
    ref = export_layout(spec, tmp_path / "ref.oas", "oas")
    tiles = tmp_path / "shared"
    p = tmp_path / "lens.oas"
    with pytest.raises(KeyboardInterrupt):
        export_layout(spec, p, "oas", ExportOptions(scheduler=cluster.address, tiles_dir=tiles, stop_after=2))
    assert not p.exists() and len(list(tiles.glob("band_*.bin"))) == 2
    res = export_layout(spec, p, "oas", ExportOptions(scheduler=cluster.address, tiles_dir=tiles))
    assert res.resumed_bands == 2 and p.read_bytes() == (tmp_path / "ref.oas").read_bytes()
    assert res.posts == ref.posts and not list(tiles.iterdir())  # the tiles removed, the given directory kept
    # a corrupt tile stops the stitch naming the file, and its record is removed: a rerun writes it again
    q = tmp_path / "q.oas"
    with pytest.raises(KeyboardInterrupt):
        export_layout(spec, q, "oas", ExportOptions(scheduler=cluster.address, tiles_dir=tiles,
                                                    stop_after=ref.bands - 1))
    b1, r1 = tile_paths(tiles, 1)
    b1.write_bytes(b"\x00" + b1.read_bytes()[1:])
    with pytest.raises(InputError, match=r"^tiles_dir = .*band 1: band_0000001.bin is corrupt.*rerun"):
        export_layout(spec, q, "oas", ExportOptions(scheduler=cluster.address, tiles_dir=tiles))
    assert not q.exists() and not r1.exists() and tile_paths(tiles, 0)[1].exists()
    res = export_layout(spec, q, "oas", ExportOptions(scheduler=cluster.address, tiles_dir=tiles))
    assert res.resumed_bands == ref.bands - 1 and q.read_bytes() == (tmp_path / "ref.oas").read_bytes()
    with pytest.raises(InputError, match=r"^tiles_dir = .*only with scheduler=\.\.\."):
        export_layout(spec, tmp_path / "x.oas", "oas", ExportOptions(tiles_dir=tiles))
    with pytest.raises(InputError, match="^scheduler = "):  # refused before the tiles' folder is made
        export_layout(spec, tmp_path / "y.oas", "oas", ExportOptions(scheduler="local:x"))
    assert not list(tmp_path.glob("*y.oas*"))


def _square_dying_once(marker: str, x: int) -> int:
    m = Path(marker) / f"{x}"
    if x == 3 and not m.exists():
        m.write_text("died")
        os._exit(1)  # the worker process dies mid-task, once
    return x * x


def _always_dying(x: int) -> int:
    os._exit(1)


def test_a_killed_worker_is_recovered_and_a_task_that_kills_every_worker_stops_the_job(tmp_path, fragile_cluster):
    got = dict(run_tasks(lambda x: _square_dying_once(str(tmp_path), x), range(6), executor=fragile_cluster))
    assert got == {i: i * i for i in range(6)} and (tmp_path / "3").exists()
    with pytest.raises(WorkerLost, match="died|no worker"):
        list(run_tasks(_always_dying, [1], executor=fragile_cluster))


def test_a_tile_the_client_cannot_see_names_the_shared_directory(tmp_path):
    """Workers on machines without the client's file system write their tiles where the client cannot read them:
    the stitch names the band, the file and the shared-directory requirement."""
    from metafovea.layout.tilefiles import TileDir, tile_paths, write_tile

    td = TileDir(tmp_path / "t", "k", 3)
    td.open(True, "2026-01-01")
    for i in range(3):
        write_tile(lambda task: ([bytes([task]) * 10], np.array([task, 1]), None), str(td.d), "k", (i, i))
    tile_paths(td.d, 2)[0].unlink()
    got = []
    with pytest.raises(InputError, match=r"^tiles_dir = .*client and every worker share.*band 2: its tile "
                                         r"\(band_0000002.bin\) is missing"):
        td.stitch(got.append)
    assert b"".join(got) == bytes(10) + bytes([1]) * 10


def test_bad_scheduler_is_one_line_naming_the_flag():
    """Also an unknown scheme; and an address where nothing listens is refused at once (Dask's client retried it
    for its whole 10 s timeout)."""
    import socket
    import time

    with pytest.raises(InputError, match="^scheduler = "):
        DaskExecutor("local:x")
    with pytest.raises(InputError, match="^scheduler = .*a known scheme .*tcp"):
        DaskExecutor("foo://127.0.0.1:9")
    with socket.socket() as s:  # a port bound but not listening: a connection to it is refused
        s.bind(("127.0.0.1", 0))
        t0 = time.monotonic()
        with pytest.raises(InputError, match="^scheduler = .*connection refused"):
            DaskExecutor(f"tcp://127.0.0.1:{s.getsockname()[1]}")
        assert time.monotonic() - t0 < 5.0


def test_every_commands_bad_scheduler_is_one_line_before_any_work(monkeypatch, capsys, tmp_path):
    """A bad --scheduler was refused only when the executor was made: `study` first simulated (3 s), and the
    PSF-accuracy warning of that work followed the error line. Now every command checks it before its work."""
    import metafovea.studies as studies
    from metafovea.cli import main

    monkeypatch.setattr(studies, "run_study", lambda *a, **k: pytest.fail("the study started"))
    for i, address in enumerate(("foo", "foo://127.0.0.1:9", "local:0", "local:x")):
        rc = main(["study", "frames", "--fast", "--scheduler", address, "--out", str(tmp_path / f"s{i}")])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and err[0].startswith(f"metafovea study: error: --scheduler = '{address}'")
        assert not (tmp_path / f"s{i}").exists()


def test_a_study_on_a_cluster_gives_the_same_json(cluster):
    import json

    from metafovea.studies import StudyOptions, run_study

    strip = lambda r: json.dumps({k: v for k, v in r.items() if k != "timing"}, sort_keys=True)  # noqa: E731
    serial = run_study("frames", StudyOptions(fast=True, seed=1, workers=1)).to_json()
    spread = run_study("frames", StudyOptions(fast=True, seed=1, scheduler=cluster.address)).to_json()
    assert strip(json.loads(json.dumps(serial))) == strip(json.loads(json.dumps(spread)))


def test_psf_sweep_on_a_cluster_is_bit_identical_to_the_serial_sweep(cluster):
    """The sensor PSFs across the field (the sweep `metafovea psf --scheduler` spreads): on and off axis, one
    wavelength and a weighted band, every array and error estimate the same bit for bit as in this process."""
    from metafovea.config import LensDesign
    from metafovea.optics.sweep import sensor_psf_sweep

    lens = LensDesign("small", 2000.0, 1000.0)
    bands = [([10.0], None), ([9.0, 10.0, 11.0], [0.3, 0.4, 0.3])]
    kw = dict(pixel_pitch_um=17.0, size_px=15, error=1e-2)
    serial = sensor_psf_sweep(lens, [0.0, 2.0, 5.0], bands, workers=1, **kw)
    spread = sensor_psf_sweep(lens, [0.0, 2.0, 5.0], bands, executor=cluster, **kw)
    assert [[p.engine for p in row] for row in spread.psfs] == [[p.engine for p in row] for row in serial.psfs]
    for row_a, row_b in zip(serial.psfs, spread.psfs):
        for a, b in zip(row_a, row_b):
            assert a.intensity.shape == (15, 15) and np.array_equal(a.intensity, b.intensity)
            assert a.error_estimate == b.error_estimate and a.center_um == b.center_um
    assert serial.warnings == spread.warnings


def test_psf_report_with_a_scheduler_gives_the_same_numbers(tmp_path, cluster):
    """`metafovea psf --scheduler`: each lens' sensor PSFs across the field run on the cluster; the report's
    numbers are those of the local run."""
    from metafovea.config import LensDesign
    from metafovea.optics.report import psf_reports

    lens = LensDesign("t", 20000.0, 2000.0)
    kw = dict(fields_deg=[0.0, 1.0], n_wavelengths=3, posts="ideal")
    a = psf_reports([lens], tmp_path / "a", **kw)["t"]
    b = psf_reports([lens], tmp_path / "b", scheduler=cluster.address, **kw)["t"]
    drop = lambda rows: [{k: v for k, v in r.items() if k != "seconds"} for r in rows]  # noqa: E731
    assert drop(a["sensor"]) == drop(b["sensor"]) and a["warnings"] == b["warnings"]


def test_every_worker_gets_glibcs_dynamic_heap_back(cluster):
    """Dask's MALLOC_TRIM_THRESHOLD_ made the layout encoder 2.4x slower in a worker than in the client: each
    worker runs parallel.numpy_malloc through a plugin (also a worker that joins later)."""
    got = cluster.client.run(lambda dask_worker: "metafovea-malloc" in dask_worker.plugins)
    assert len(got) == 2 and all(got.values())


def test_a_bad_scheduler_for_psf_writes_nothing(tmp_path):
    from metafovea.config import LensDesign
    from metafovea.optics.report import psf_reports

    with pytest.raises(InputError, match="^scheduler = "):
        psf_reports([LensDesign("t", 20000.0, 2000.0)], tmp_path / "o", fields_deg=[0.0], n_wavelengths=3,
                    posts="ideal", scheduler="local:x")
    assert not (tmp_path / "o").exists()

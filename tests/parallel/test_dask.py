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


def test_layout_export_on_a_cluster_writes_the_same_bytes(tmp_path, cluster):
    from metafovea.config import LensDesign
    from metafovea.layout import export_file, make_spec

    spec = make_spec(LensDesign("small", 1500.0, 1200.0, polarization="x"), band_rows=16, ring_width_um=100.0,
                     mark_offset_um=50.0, mark_size_um=40.0, mark_width_um=4.0)
    a = export_file(spec, tmp_path / "serial.oas", "oas", workers=1)
    b = export_file(spec, tmp_path / "dask.oas", "oas", scheduler=cluster.address)
    assert Path(a["path"]).read_bytes() == Path(b["path"]).read_bytes()


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


def test_bad_scheduler_is_one_line_naming_the_flag():
    with pytest.raises(InputError, match="--scheduler"):
        DaskExecutor("local:x")
    with pytest.raises(InputError, match="--scheduler"):
        DaskExecutor("tcp://127.0.0.1:9")


def test_a_study_on_a_cluster_gives_the_same_json(cluster):
    import json

    from metafovea.studies import StudyOptions, run_study

    strip = lambda r: json.dumps({k: v for k, v in r.items() if k != "timing"}, sort_keys=True)  # noqa: E731
    serial = run_study("frames", StudyOptions(fast=True, seed=1, workers=1)).to_json()
    spread = run_study("frames", StudyOptions(fast=True, seed=1, scheduler=cluster.address)).to_json()
    assert strip(json.loads(json.dumps(serial))) == strip(json.loads(json.dumps(spread)))

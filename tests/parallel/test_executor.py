"""Local process pools from a user's script: a script without an ``if __name__ == "__main__":`` guard would be rerun
by every forkserver/spawn worker (and wait on the locks its parent holds: a silent hang), so its tasks run in the
calling process with a warning; a guarded script gets the pool."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time

import pytest

BODY = """
import warnings
from metafovea.parallel import get_executor, run_tasks
with warnings.catch_warnings(record=True) as w:
    warnings.simplefilter("always")
    ex = get_executor(2)
    res = sorted(dict(run_tasks(abs, [-1, -2, -3], executor=ex)).values())
    print(type(ex).__name__, res, any("has no `if __name__" in str(x.message) for x in w))
    ex.shutdown()
"""


def _run(tmp_path, guarded: bool) -> str:
    src = ("if __name__ == '__main__':\n" + textwrap.indent(BODY, "    ")) if guarded else BODY
    script = tmp_path / ("guarded.py" if guarded else "plain.py")
    script.write_text(src)
    env = {**os.environ, "METAFOVEA_CACHE": str(tmp_path / "cache")}
    return subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120, env=env,
                          cwd=tmp_path).stdout


def test_an_unguarded_script_runs_its_tasks_in_process_with_a_warning(tmp_path):
    assert _run(tmp_path, guarded=False).split() == ["SerialExecutor", "[1,", "2,", "3]", "True"]


def test_a_guarded_script_gets_the_process_pool(tmp_path):
    assert _run(tmp_path, guarded=True).split() == ["ProcessPoolExecutor", "[1,", "2,", "3]", "False"]


STOP = """
import os, sys, time
from pathlib import Path
from metafovea.io import atomic_open
from metafovea.parallel import get_executor, run_tasks


def slow(item):
    path, seconds = item
    if path is None:
        return os.getpid()
    with atomic_open(path, "wb") as fh:  # a temporary file next to path until the block ends
        fh.write(b"partial")
        time.sleep(seconds)
    return os.getpid()


if __name__ == "__main__":
    d = Path(sys.argv[1])
    ex = get_executor(2)
    gen = run_tasks(slow, [(None, 0), (str(d / "a.bin"), 120), (str(d / "b.bin"), 120)], executor=None, workers=2)
    next(gen)  # one result, then the caller stops (as after a Ctrl-C)
    time.sleep(1.0)  # the two slow tasks are running, their temporary files written
    t0 = time.monotonic()
    gen.close()
    print(round(time.monotonic() - t0, 2), sorted(p.name for p in d.iterdir()))
    ex.shutdown()
"""


def test_stopping_a_sweep_ends_its_running_tasks_and_their_temporary_files(tmp_path):
    """A caller that stops reading (Ctrl-C) does not wait for the running tasks (two-minute ones here); each worker
    unwinds on SIGTERM, so its atomic write removes its temporary file."""
    script = tmp_path / "stop.py"
    script.write_text(STOP)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    env = {**os.environ, "METAFOVEA_CACHE": str(tmp_path / "cache")}
    r = subprocess.run([sys.executable, str(script), str(out_dir)], capture_output=True, text=True, timeout=100,
                       env=env, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    seconds, files = r.stdout.split(maxsplit=1)
    assert float(seconds) < 15.0, r.stdout
    assert files.strip() == "[]", r.stdout  # neither the outputs nor their temporary files


def test_leaving_a_thread_pool_on_a_ctrl_c_stops_its_running_tasks_and_their_temporary_files(tmp_path):
    """Regression: ``metafovea psf`` took 12-17 s to stop on Ctrl-C: its sensor PSFs ran in a thread pool that waited
    for every task submitted. Left by an exception, a StoppableThreadPool cancels the tasks not started and unwinds
    the running ones (their atomic writes remove their temporary files); no exception escapes into a thread. Left
    normally, it waits for every task."""
    import threading

    from metafovea.io import atomic_open
    from metafovea.parallel import StoppableThreadPool

    started, ended = [], []

    def slow(name: str) -> str:
        started.append(name)
        try:
            with atomic_open(tmp_path / name, "wb") as fh:
                fh.write(b"partial")
                for _ in range(1200):  # two minutes, a Python step every 0.1 s (a stop lands between steps)
                    time.sleep(0.1)
            return name
        finally:
            ended.append(name)

    escaped = []
    hook, threading.excepthook = threading.excepthook, escaped.append
    try:
        t0 = time.monotonic()
        with pytest.raises(KeyboardInterrupt), StoppableThreadPool(2, "stop-test") as ex:
            futs = [ex.submit(slow, f"{i}.bin") for i in range(6)]
            assert _until(lambda: len(started) == 2, 10)
            raise KeyboardInterrupt  # as a Ctrl-C in the caller
        stopped = time.monotonic() - t0
        assert not [t for t in threading.enumerate() if t.name.startswith("stop-test")]
    finally:
        threading.excepthook = hook
    assert stopped < 5.0, stopped
    assert sorted(started) == sorted(ended) == ["0.bin", "1.bin"]  # four cancelled, two unwound
    assert all(f.cancelled() for f in futs[2:]) and list(tmp_path.iterdir()) == []
    assert not escaped, escaped

    with StoppableThreadPool(2) as ex:
        futs = [ex.submit(time.sleep, 0.2) for _ in range(4)]
    assert all(f.done() and not f.cancelled() for f in futs)


def _until(cond, timeout_s: float) -> bool:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if cond():
            return True
        time.sleep(0.02)
    return False


def test_a_stop_request_that_was_dropped_stops_run_tasks_at_the_next_result():
    """A stop signal whose KeyboardInterrupt compiled code dropped is on record (metafovea.stopping): run_tasks raises
    it at the next result, once; without a request the tasks all run."""
    from metafovea import stopping
    from metafovea.parallel import run_tasks

    assert sorted(r for _, r in run_tasks(abs, [-1, -2, -3], workers=1)) == [1, 2, 3]
    done = []
    try:
        stopping.request(2)  # what the signal handler records before its KeyboardInterrupt was dropped
        with pytest.raises(KeyboardInterrupt, match="raised again"):
            for _, r in run_tasks(abs, [-1, -2, -3], workers=1):
                done.append(r)
        assert done == [] and not stopping.requested()  # raised once, at the first result
    finally:
        stopping.clear()

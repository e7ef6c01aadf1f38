"""Progress of long loops (:func:`metafovea.parallel.progress_bar`): a bar on a terminal, log lines otherwise.

Off a terminal (a log file, ``nohup``, a pipe, a scheduler) the commands printed nothing for minutes: tqdm's bars were
asked only on a terminal. Now a line every ``PROGRESS_LINE_S`` seconds says how far the loop is and when it ends."""

from __future__ import annotations

import io
import os
import re
import time

import pytest

import metafovea.parallel as par
from metafovea.errors import InputError
from metafovea.parallel import LineProgress, heartbeat, progress_bar, progress_iter, run_tasks, task_workers


def test_lines_say_done_total_elapsed_and_eta_then_the_total_time():
    out = io.StringIO()
    with progress_bar(4, "RCWA library", "task", interval_s=0.0, stream=out) as bar:
        for _ in range(4):
            bar.set_postfix(loss="0.5")
            bar.update(1)
    lines = out.getvalue().splitlines()
    assert len(lines) == 5
    assert re.fullmatch(r"metafovea: RCWA library: 1/4 task \(25 %\), \d+ s, ETA \d+ s; loss 0\.5", lines[0])
    assert re.fullmatch(r"metafovea: RCWA library: 4/4 task \(100 %\) in \d+ s; loss 0\.5", lines[-1])


def test_a_quick_loop_writes_nothing_and_disabled_progress_never_writes():
    out = io.StringIO()
    assert list(progress_iter(range(50), "fast", stream=out)) == list(range(50))  # under PROGRESS_LINE_S
    with progress_bar(3, "off", enabled=False, interval_s=0.0, stream=out) as bar:
        bar.update(3)
    assert out.getvalue() == ""


def test_a_bar_on_a_terminal_lines_elsewhere(monkeypatch):
    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    monkeypatch.setattr("sys.stderr", Terminal())
    bar = progress_bar(3, "x")
    assert not isinstance(bar, LineProgress)  # tqdm
    bar.close()
    monkeypatch.setattr("sys.stderr", io.StringIO())
    assert isinstance(progress_bar(3, "x"), LineProgress)


def test_run_tasks_reports_progress_off_a_terminal(monkeypatch, capsys):
    monkeypatch.setattr(par, "PROGRESS_LINE_S", 0.0)
    res = dict(run_tasks(abs, [-1, -2, -3], workers=1, progress=True, desc="sweep"))
    assert res == {0: 1, 1: 2, 2: 3}
    err = capsys.readouterr().err
    assert "metafovea: sweep: 1/3 task (33 %)" in err and "metafovea: sweep: 3/3 task (100 %) in" in err


def test_one_worker_per_core_never_more_than_the_tasks():
    """``workers=None`` (every ``--workers``' default) is one process per core, and a pool never gets more workers
    than tasks: a single task runs in this process."""
    assert task_workers(None, 10_000) == par.default_workers()
    assert task_workers(8, 3) == 3 and task_workers(None, 1) == 1 and task_workers(2, 0) == 1
    assert dict(run_tasks(_pid, [0], workers=4)) == {0: os.getpid()}
    with pytest.raises(InputError, match="workers"):
        task_workers(0, 5)


def _pid(_: int) -> int:
    return os.getpid()


def test_a_long_step_without_a_loop_says_it_is_alive():
    """A first run's PSFs or post responses have no loop to count: a line every interval while the step runs, none
    for a step that ends sooner."""
    out = io.StringIO()
    with heartbeat("simulate: the channels' PSFs", interval_s=0.05, stream=out):
        time.sleep(0.3)
    lines = out.getvalue().splitlines()
    assert len(lines) >= 2 and all(re.fullmatch(r"metafovea: simulate: the channels' PSFs: \d+ s", x) for x in lines)
    quiet = io.StringIO()
    with heartbeat("fast", interval_s=5.0, stream=quiet):
        pass
    with heartbeat("off", enabled=False, interval_s=0.01, stream=quiet):
        time.sleep(0.05)
    assert quiet.getvalue() == ""


def test_a_loop_whose_first_step_is_slow_still_writes_a_line_every_interval():
    """`design --period-um 100` started a library of ~28 s rows on 2 workers and printed nothing in its first minute
    (a line came only with an update): the progress now writes on a timer when the steps are slower than the
    interval, and stops at close."""
    out = io.StringIO()
    with LineProgress(3, "RCWA library", "task", interval_s=0.1, stream=out) as bar:
        time.sleep(0.45)
        assert len(out.getvalue().splitlines()) >= 3  # no update yet: the timer's lines
        assert all(re.fullmatch(r"metafovea: RCWA library: 0/3 task \(0 %\), \d+ s", ln)
                   for ln in out.getvalue().splitlines())
        bar.update(3)
    n = len(out.getvalue().splitlines())
    time.sleep(0.3)
    assert len(out.getvalue().splitlines()) == n  # closed: silent
    assert re.search(r"3/3 task \(100 %\) in \d+ s$", out.getvalue().strip())


def test_a_loop_stopped_by_an_exception_writes_no_final_line():
    """Ctrl-C (or an error) inside a loop: no 'N/M ... in S' line after the command's own one-line message (the
    progress of a generator, closed when collected, wrote it after 'interrupted'); a loop that ends writes it."""
    out = io.StringIO()
    with pytest.raises(KeyboardInterrupt):
        for k in progress_iter(range(5), "windows", "window", interval_s=0.0, stream=out):
            if k == 2:
                raise KeyboardInterrupt
    lines = out.getvalue().splitlines()
    assert lines and not any(" in " in ln and "ETA" not in ln for ln in lines), lines
    it = progress_iter(range(5), "windows", "window", interval_s=0.0, stream=out)
    next(it)
    it.close()  # a generator closed early (GeneratorExit)
    assert not any(" in " in ln and "ETA" not in ln for ln in out.getvalue().splitlines())
    done = io.StringIO()
    assert list(progress_iter(range(3), "windows", "window", interval_s=0.0, stream=done)) == [0, 1, 2]
    assert re.fullmatch(r"metafovea: windows: 3/3 window \(100 %\) in \d+ s", done.getvalue().splitlines()[-1])

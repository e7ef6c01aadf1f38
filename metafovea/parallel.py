"""One executor interface for sweeps and tiles: local processes by default, Dask when asked.

``get_executor(workers=None, scheduler=None)`` returns a ``concurrent.futures.Executor``-like object
with ``submit`` and ``map``; with a scheduler (``tcp://host:8786``, or ``local``/``local:N`` for a Dask
``LocalCluster`` of worker processes started for the run) it is a :class:`DaskExecutor` (futures with
``.result()``; a task whose worker keeps dying raises :class:`WorkerLost`, never a partial result), otherwise a
``ProcessPoolExecutor`` (or a serial in-process executor when ``workers == 1``, which keeps tests and
debugging simple). Dask is the optional extra ``metafovea[dask]``. Use :func:`run_tasks` to map a function over
items with progress and ordered results. Local threads: :class:`StoppableThreadPool`, whose running tasks stop on a
Ctrl-C (as :func:`stop_workers` ends a process pool's) instead of holding the command until they finish.

Progress of a long loop (:func:`progress_bar`, :func:`progress_iter`): a tqdm bar when stderr is a terminal,
otherwise one log line every :data:`PROGRESS_LINE_S` seconds (done, total, elapsed, ETA), so that a run under a
scheduler, ``nohup`` or a pipe still shows that it is alive and when it will end; :func:`heartbeat` for a long step
with no loop to count.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import os
import sys
import threading
import time
import weakref
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from metafovea import stopping
from metafovea.errors import InputError

#: seconds between two progress lines off a terminal: a sign of life in a log every 10 s, and a 30-minute run writes
#: ~180 lines (a tqdm bar redraws 10 times a second, which a log file would keep)
PROGRESS_LINE_S = 10.0


def _duration(s: float) -> str:
    """``s`` seconds as ``42 s``, ``3 min 20 s`` or ``1 h 05 min``."""
    s = max(0.0, float(s))
    if s < 60:
        return f"{s:.0f} s"
    if s < 3600:
        return f"{int(s // 60)} min {int(s % 60):02d} s"
    return f"{int(s // 3600)} h {int(s % 3600 // 60):02d} min"


class LineProgress:
    """Progress as log lines on ``stream`` (default: stderr at each write), at most one per ``interval_s``:
    ``metafovea: DESC: 120/2000 step (6 %), 1 min 24 s, ETA 21 min 56 s; loss 0.0123``; on :meth:`close` a last
    line with the total time, when a line was written before (a quick loop writes nothing). A loop whose steps take
    longer than ``interval_s`` still writes a line every ``interval_s`` (a timer thread, holding the progress only
    weakly and ending at :meth:`close`). The methods are tqdm's that the
    project uses (``update``, ``set_postfix``, ``set_postfix_str``, ``close``, context manager)."""

    def __init__(self, total: int | None = None, desc: str = "", unit: str = "it", *, initial: int = 0,
                 interval_s: float | None = None, stream: Any = None):
        self.total, self.desc, self.unit, self.n = total, desc, unit, int(initial)
        self.interval_s = PROGRESS_LINE_S if interval_s is None else float(interval_s)
        self.stream = stream
        self.postfix = ""
        self.t0 = self.last = time.monotonic()
        self.start_n = self.n
        self.lines = 0
        self.closed = False
        self._lock = threading.Lock()
        self._stop = threading.Event()
        if type(self) is LineProgress and self.interval_s > 0:  # not the silent subclass; 0: a line per update
            threading.Thread(target=LineProgress._tick, args=(weakref.ref(self), self._stop, self.interval_s),
                             name="metafovea-progress", daemon=True).start()

    @staticmethod
    def _tick(ref: Any, stop: threading.Event, every: float) -> None:
        """A line when ``every`` seconds passed without one (the loop's steps are slow), until closed."""
        while not stop.wait(max(every, 0.01)):
            bar = ref()
            if bar is None or bar.closed:
                return
            with bar._lock:
                if time.monotonic() - bar.last >= bar.interval_s:
                    bar.last = time.monotonic()
                    bar._write(bar._line())
            del bar

    def _line(self, final: bool = False) -> str:
        el = time.monotonic() - self.t0
        done = f"{self.n}/{self.total}" if self.total else f"{self.n}"
        text = f"metafovea: {self.desc}: {done} {self.unit}"
        if self.total:
            text += f" ({100.0 * self.n / self.total:.0f} %)"
        if final:
            text += f" in {_duration(el)}"
        else:
            text += f", {_duration(el)}"
            rate = (self.n - self.start_n) / el if el > 0 else 0.0
            if self.total and rate > 0:
                text += f", ETA {_duration((self.total - self.n) / rate)}"
        return text + (f"; {self.postfix}" if self.postfix else "")

    def _write(self, text: str) -> None:
        out = self.stream or sys.stderr
        out.write(text + "\n")
        out.flush()
        self.lines += 1

    def update(self, n: int = 1) -> None:
        self.n += int(n)
        now = time.monotonic()
        if now - self.last >= self.interval_s:
            with self._lock:
                self.last = now
                self._write(self._line())

    def set_postfix(self, ordered_dict: Any = None, refresh: bool = True, **kw: Any) -> None:
        items = {**(ordered_dict or {}), **kw}
        self.postfix = ", ".join(f"{k} {v}" for k, v in items.items())

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        self.postfix = str(s)

    def close(self) -> None:
        self._stop.set()
        with self._lock:
            if not self.closed and self.lines:
                self._write(self._line(final=True))
            self.closed = True

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, exc_type: Any, *exc: Any) -> None:
        if exc_type is None:
            self.close()
            return
        self._stop.set()  # a loop stopped by an exception (Ctrl-C, an error, a generator closed): no final line after
        with self._lock:  # the command's own one-line message
            self.closed = True


class _NoProgress(LineProgress):
    """Progress that shows nothing (``enabled=False``)."""

    def update(self, n: int = 1) -> None:
        self.n += int(n)

    def close(self) -> None:
        self.closed = True


def progress_bar(total: int | None = None, desc: str = "", unit: str = "it", *, enabled: bool = True,
                 initial: int = 0, leave: bool = True, position: int | None = None,
                 interval_s: float | None = None, stream: Any = None) -> Any:
    """The progress of a loop of ``total`` ``unit``: a tqdm bar on stderr when it is a terminal, else a
    :class:`LineProgress` (a log line every ``interval_s``, default :data:`PROGRESS_LINE_S`); nothing when not
    ``enabled``. Either has ``update(n)``, ``set_postfix(...)``, ``close()`` and works as a context manager.
    ``stream``: where the lines go (tests; it also selects the lines)."""
    if not enabled:
        return _NoProgress(total, desc, unit, initial=initial)
    if stream is None and sys.stderr.isatty():
        from tqdm.auto import tqdm

        return tqdm(total=total, desc=desc, unit=unit, initial=initial, leave=leave, position=position,
                    file=sys.stderr)
    return LineProgress(total, desc, unit, initial=initial, interval_s=interval_s, stream=stream)


def _say(text: str, stream: Any = None) -> None:
    """One progress line on ``stream`` (default stderr; through tqdm on a terminal, so that bars stay whole)."""
    if stream is None and sys.stderr.isatty():
        from tqdm.auto import tqdm

        tqdm.write(text, file=sys.stderr)
        return
    out = stream or sys.stderr
    out.write(text + "\n")
    out.flush()


@contextlib.contextmanager
def heartbeat(desc: str, *, enabled: bool = True, interval_s: float | None = None, stream: Any = None
              ) -> Iterator[None]:
    """While the block runs, a line every ``interval_s`` (default :data:`PROGRESS_LINE_S`):
    ``metafovea: DESC: 20 s``; nothing for a block that ends sooner. For a step with no loop to count (a first run's
    PSFs or post responses, cached afterwards), so that it is not silent for minutes."""
    if not enabled:
        yield
        return
    import threading

    every = max(PROGRESS_LINE_S if interval_s is None else float(interval_s), 0.01)
    stop = threading.Event()
    t0 = time.monotonic()

    def beat() -> None:
        while not stop.wait(every):
            _say(f"metafovea: {desc}: {_duration(time.monotonic() - t0)}", stream)

    th = threading.Thread(target=beat, name="metafovea-heartbeat", daemon=True)
    th.start()
    try:
        yield
    finally:
        stop.set()
        th.join()


def progress_iter(items: Iterable[Any], desc: str = "", unit: str = "it", *, enabled: bool = True,
                  total: int | None = None, **kw: Any) -> Iterator[Any]:
    """``items``, one at a time, with :func:`progress_bar`'s progress (``total`` default ``len(items)``)."""
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    with progress_bar(total, desc, unit, enabled=enabled, **kw) as bar:
        for it in items:
            yield it
            bar.update(1)


class SerialExecutor(cf.Executor):
    """Runs tasks in the calling process when submitted (workers = 1)."""

    def submit(self, fn: Callable, /, *args: Any, **kwargs: Any) -> cf.Future:  # type: ignore[override]
        fut: cf.Future = cf.Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as e:  # noqa: BLE001 - delivered through the future
            fut.set_exception(e)
        return fut


@contextlib.contextmanager
def blas_threads(n: int = 1) -> Iterator[None]:
    """Limit BLAS/OpenMP threads inside the block (threadpoolctl).

    Small matrix products (2x2 normal equations, foveal operators, RCWA eigenproblems of a few hundred
    unknowns) run slower with OpenBLAS' threads than without on a loaded 2-core machine (measured here:
    a 0.4 ms product took 94 ms), and process-parallel sweeps already use every core.
    """
    with _blas_controller().limit(limits=n):  # what threadpool_limits(limits=n) does, on a kept controller
        yield


#: a threadpoolctl controller of the libraries loaded when it was made, and ``len(sys.modules)`` then
_BLAS_CONTROLLER: list[Any] = [None, -1]


def _blas_controller() -> Any:
    """The loaded BLAS/OpenMP libraries (a ``threadpoolctl.ThreadpoolController``). Finding them costs ~1 ms (each
    loaded library is inspected) and loops enter :func:`blas_threads` thousands of times (a Hankel profile per
    focal distance): they are looked for again only when a module was imported since (a BLAS comes with an
    extension module)."""
    n = len(sys.modules)
    if _BLAS_CONTROLLER[0] is None or _BLAS_CONTROLLER[1] != n:
        from threadpoolctl import ThreadpoolController

        _BLAS_CONTROLLER[:] = [ThreadpoolController(), len(sys.modules)]
    return _BLAS_CONTROLLER[0]


def default_workers() -> int:
    """The cores this process may run on: the default number of local workers (``workers=None``)."""
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


def task_workers(workers: int | None, tasks: int) -> int:
    """Local workers for ``tasks`` tasks: ``workers``, or one per core when None, and never more than the tasks
    (an idle process costs its start-up: ~1 s to import the package)."""
    if workers is None:
        workers = default_workers()
    if not isinstance(workers, int) or isinstance(workers, bool) or workers < 1:
        raise InputError("workers", workers, "an integer >= 1 (None: one per core)")
    return max(1, min(workers, tasks))


class WorkerLost(OSError):
    """A task's worker process died (again and again: Dask reschedules a task whose worker dies, up to its
    ``allowed-failures``); no partial result is returned."""


class _DaskFuture:
    """A Dask future whose ``result()`` names a lost worker instead of Dask's ``KilledWorker``."""

    def __init__(self, fut: Any):
        self.fut = fut

    def result(self, timeout: float | None = None) -> Any:
        from distributed import KilledWorker  # type: ignore

        try:
            return self.fut.result(timeout=timeout)
        except KilledWorker as e:
            raise WorkerLost(f"a Dask worker died running {self.fut.key} (every retry too: {e}); the job stopped "
                             "without a partial result") from None


def numpy_malloc() -> bool:
    """glibc's dynamic heap for numpy's temporaries again, in a Dask worker (True when set).

    Dask's nanny starts its workers with ``MALLOC_TRIM_THRESHOLD_=65536`` (to hand memory back to the system);
    setting it turns off glibc's dynamic mmap threshold, so every temporary above 128 kB is a fresh mmap whose
    pages fault in again. The layout encoder took 5.4-5.5 s for a 25 mm lens' 98 bands with that variable, 2.1-2.7 s
    without it and 1.9-2.0 s with it and these settings (one process on the 2-core machine). Allocations
    above 32 MB are still mmapped and returned at once; a worker keeps at most 64 MB of freed heap."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False  # not glibc: nothing to undo
    m_trim_threshold, m_mmap_threshold = -1, -3
    return bool(mallopt(m_mmap_threshold, 32 << 20)) and bool(mallopt(m_trim_threshold, 64 << 20))


def _malloc_plugin() -> Any:
    """A Dask worker plugin that runs :func:`numpy_malloc` in every worker process when it starts (built here:
    distributed is an optional dependency)."""
    from distributed import WorkerPlugin  # type: ignore

    class MallocPlugin(WorkerPlugin):
        def setup(self, worker: Any) -> None:
            numpy_malloc()

    return MallocPlugin()


def _refused(address: str) -> str | None:
    """Why a ``tcp://`` (or ``tls://``) scheduler address cannot be reached at once: its host name does not resolve
    or the host refuses the connection (nothing listens on the port); None otherwise, also for a host that does not
    answer within 2 s (Dask's client then waits for its own timeout)."""
    import socket

    from distributed.comm.addressing import parse_address, parse_host_port  # type: ignore

    try:
        proto, loc = parse_address(address)
        host, port = parse_host_port(loc)
    except (ValueError, TypeError):
        return None  # Dask's client says what is wrong with it
    if proto not in ("tcp", "tls"):
        return None
    try:
        with socket.create_connection((host, int(port)), timeout=2.0):
            return None
    except socket.gaierror as e:
        return f"host {host!r} not found: {e.strerror}"
    except ConnectionRefusedError:
        return f"connection refused by {host}:{port}"
    except OSError:
        return None


def check_scheduler(scheduler: str) -> str:
    """``scheduler`` checked before any work starts (a command's ``--scheduler``; :class:`DaskExecutor` again):
    ``local``, ``local:N`` (N >= 1) or an address of a scheme Dask knows whose host answers; the stripped address,
    else an :class:`InputError` naming ``scheduler`` (a bad address was refused only when the executor was made,
    after the command's first work)."""
    s = str(scheduler).strip()
    if s == "local" or s.startswith("local:"):
        try:
            n = int(s.split(":", 1)[1]) if ":" in s else 1
        except ValueError:
            raise InputError("scheduler", scheduler, "local, local:N (N >= 1 worker processes) or "
                             "tcp://host:port") from None
        if n < 1:
            raise InputError("scheduler", scheduler, "local:N with N >= 1 worker processes")
        return s
    try:
        from distributed.comm.addressing import parse_address, parse_host_port  # type: ignore
        from distributed.comm.registry import backends  # type: ignore
    except ImportError:
        raise InputError("scheduler", scheduler, "a Dask scheduler with dask.distributed installed "
                         "(pip install 'metafovea[dask]')") from None
    try:
        proto, loc = parse_address(s)
        if proto in ("tcp", "tls"):
            parse_host_port(loc)
    except (ValueError, TypeError) as e:
        raise InputError("scheduler", scheduler, f"a Dask scheduler address such as tcp://host:8786 ({e})") from None
    if proto not in backends:
        raise InputError("scheduler", scheduler, "a Dask scheduler address of a known scheme (" +
                         ", ".join(sorted(backends)) + "), e.g. tcp://host:8786")
    refused = _refused(s)
    if refused is not None:  # nothing listens there: say so at once (Dask's client retries until timeout)
        raise InputError("scheduler", scheduler, f"a reachable Dask scheduler address ({refused})")
    return s


class DaskExecutor:
    """``submit``/``map``/``close`` on a Dask client: a scheduler at an address (``tcp://host:8786``), or a
    ``LocalCluster`` of worker processes started for this run (``local`` = one per core, ``local:N``)."""

    def __init__(self, scheduler: str):
        try:
            from distributed import Client, LocalCluster  # type: ignore
        except ImportError:
            raise InputError("scheduler", scheduler, "a Dask scheduler with dask.distributed installed "
                             "(pip install 'metafovea[dask]')") from None
        s = check_scheduler(scheduler)
        self.cluster = None
        if s == "local" or s.startswith("local:"):
            n = int(s.split(":", 1)[1]) if ":" in s else default_workers()
            self.cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None)
            self.client = Client(self.cluster)
        else:
            try:
                self.client = Client(s, timeout="10s")  # an address that does not answer: 10 s
            except (OSError, TimeoutError, ValueError) as e:  # ValueError: an unknown scheme (foo://)
                raise InputError("scheduler", scheduler, f"a reachable Dask scheduler address ({e})") from None
        self.address = self.client.scheduler.address
        #: seconds without any worker, tasks waiting, before :meth:`completed` gives up
        self.no_worker_timeout_s = 60.0
        self._register(_malloc_plugin())

    def _register(self, plugin: Any) -> None:
        """A worker plugin on every worker, present and future (a worker restarted after a kill too)."""
        reg = getattr(self.client, "register_plugin", None) or self.client.register_worker_plugin
        reg(plugin, name="metafovea-malloc")

    def submit(self, fn: Callable, /, *args: Any, **kwargs: Any) -> _DaskFuture:
        return _DaskFuture(self.client.submit(fn, *args, pure=False, **kwargs))

    def completed(self, wrapped: list[_DaskFuture]) -> Iterator[tuple[int, _DaskFuture]]:
        """``(index, future)`` as they finish. When the cluster has had no worker for ``no_worker_timeout_s``
        while tasks wait (every worker died and none came back), :class:`WorkerLost` instead of waiting forever."""
        import time

        from distributed import wait  # type: ignore

        index = {w.fut.key: (i, w) for i, w in enumerate(wrapped)}
        pending = [w.fut for w in wrapped]
        idle_since: float | None = None
        while pending:
            try:
                done, rest = wait(pending, timeout=2.0, return_when="FIRST_COMPLETED")
            except TimeoutError:
                if self.client.scheduler_info().get("workers"):
                    idle_since = None
                elif idle_since is None:
                    idle_since = time.monotonic()
                elif time.monotonic() - idle_since > self.no_worker_timeout_s:
                    raise WorkerLost(f"the Dask cluster at {self.address} has had no worker for "
                                     f"{self.no_worker_timeout_s:g} s with {len(pending)} task(s) waiting; the job "
                                     "stopped without a partial result") from None
                continue
            pending = list(rest)
            for f in done:
                yield index[f.key]

    def map(self, fn: Callable, *iterables: Iterable[Any]) -> Iterator[Any]:
        futs = [self.submit(fn, *a) for a in zip(*iterables)]
        return (f.result() for f in futs)

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()

    def __enter__(self) -> DaskExecutor:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def get_executor(workers: int | None = None, scheduler: str | None = None):
    """Executor for ``workers`` local processes, or a :class:`DaskExecutor` for ``scheduler`` (an address, or
    ``local``/``local:N`` for a LocalCluster of worker processes)."""
    if scheduler:
        return DaskExecutor(scheduler)
    if workers is None:
        workers = default_workers()
    if not isinstance(workers, int) or workers < 1:
        raise InputError("workers", workers, "an integer >= 1")
    if workers == 1:
        return SerialExecutor()
    # forkserver, not fork: a process that has started JAX's (or OpenBLAS') threads must not fork (JAX warns that
    # os.fork() may deadlock; the library sweep runs after JAX in validate and in the test suite)
    import multiprocessing

    if _unguarded_script():
        import warnings

        warnings.warn("the running script has no `if __name__ == \"__main__\":` guard: worker processes would run it "
                      "again (and wait on its locks); running the tasks in this process instead", stacklevel=2)
        return SerialExecutor()
    method = "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"
    return cf.ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context(method),
                                  initializer=_worker_init, initargs=(os.getpid(),))


def _unguarded_script() -> bool:
    """Whether ``__main__`` is a script file whose source has no ``__name__ == "__main__"`` test: forkserver and
    spawn workers import the main script again, so such a script would rerun its work in every worker."""
    import sys

    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if not path or getattr(main, "__spec__", None) is not None or not str(path).endswith(".py"):
        return False  # interactive, -c, -m or a notebook: nothing is rerun
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            src = f.read()
    except OSError:
        return False
    return not ("__name__" in src and "__main__" in src)


def _worker_term(signum: int, frame: object) -> None:
    """A worker's SIGTERM (:func:`stop_workers`): unwind the running task (its atomic writes remove their temporary
    files) instead of dying mid-write."""
    raise SystemExit(128 + signum)


def _worker_init(owner_pid: int) -> None:
    """In each worker process: leave SIGINT to the command (a Ctrl-C reaches the whole process group: the command
    stops the pool, :func:`stop_workers`), unwind on SIGTERM, and die with the command even when it is killed hard
    (SIGKILL runs no clean-up; the workers are children of the forkserver, not of the command, so a watchdog thread
    checks that ``owner_pid`` is alive twice a second)."""
    import signal
    import threading
    import time

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_term)

    def watch() -> None:
        while True:
            time.sleep(0.5)
            try:
                os.kill(owner_pid, 0)
            except ProcessLookupError:
                os._exit(1)
            except PermissionError:
                pass

    threading.Thread(target=watch, name="metafovea-owner-watch", daemon=True).start()


def stop_workers(ex: cf.ProcessPoolExecutor, grace_s: float = 10.0) -> None:
    """Stop a process pool after an interruption: cancel the tasks not started and end the running ones (SIGTERM:
    each worker unwinds, :func:`_worker_term`; SIGKILL after ``grace_s``) instead of waiting for them, which held a
    Ctrl-C of ``metafovea psf`` for the rest of a lens' report (24 s measured). A running task's result is lost
    either way: the caller has stopped reading them."""
    import time

    procs = list((getattr(ex, "_processes", None) or {}).values())  # the pool's processes (CPython's attribute)
    ex.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    deadline = time.monotonic() + grace_s
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
        if p.is_alive():
            p.kill()
            p.join(1.0)


class TaskStopped(BaseException):
    """Raised inside a :class:`StoppableThreadPool` task by :meth:`StoppableThreadPool.stop`: the task unwinds (its
    ``finally`` blocks and atomic writes clean up) and its result is dropped. A ``BaseException``, so that no
    ``except Exception`` in the task swallows it."""


def _raise_in_thread(ident: int, exc: type[BaseException] | None) -> None:
    """Raise ``exc`` in thread ``ident`` at its next Python instruction (CPython's ``PyThreadState_SetAsyncExc``; a
    thread inside one long numpy call sees it when the call returns); ``None`` takes back one not raised yet."""
    import ctypes

    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(ident), ctypes.py_object(exc) if exc else None)


class StoppableThreadPool(cf.ThreadPoolExecutor):
    """A thread pool whose running tasks stop when the block that uses it is left by an exception (a Ctrl-C): the
    tasks not started are cancelled and :class:`TaskStopped` is raised in the running ones (:meth:`stop`), where a
    ``ThreadPoolExecutor`` waits for every task submitted (the rest of a PSF report's sensor PSFs, seconds to
    minutes). Left normally, it waits for its tasks as a ``ThreadPoolExecutor`` does."""

    def __init__(self, max_workers: int | None = None, thread_name_prefix: str = "metafovea"):
        import threading

        super().__init__(max_workers, thread_name_prefix=thread_name_prefix)
        self._stop_lock = threading.Lock()
        self._running: dict[int, bool] = {}  # thread ident -> TaskStopped sent to it

    def submit(self, fn: Callable, /, *args: Any, **kwargs: Any) -> cf.Future:  # type: ignore[override]
        return super().submit(self._tracked, fn, args, kwargs)

    def _tracked(self, fn: Callable, args: tuple, kwargs: dict) -> Any:
        """``fn(*args, **kwargs)`` with its thread marked as running a task, so that :meth:`stop` raises only inside
        a task (where the pool's future catches it), never in the pool's own loop."""
        import threading

        ident = threading.get_ident()
        with self._stop_lock:
            self._running[ident] = False
        try:
            return fn(*args, **kwargs)
        finally:
            with self._stop_lock:
                if self._running.pop(ident, False):
                    _raise_in_thread(ident, None)  # a stop that has not landed yet must not land outside the task

    def stop(self, grace_s: float = 5.0) -> None:
        """Cancel the tasks not started, raise :class:`TaskStopped` in the running ones and wait up to ``grace_s``
        for the threads to end (a thread still inside one long native call is left to finish it)."""
        import time

        self.shutdown(wait=False, cancel_futures=True)
        with self._stop_lock:
            for ident, sent in self._running.items():
                if not sent:
                    self._running[ident] = True
                    _raise_in_thread(ident, TaskStopped)
        deadline = time.monotonic() + grace_s
        for t in list(self._threads):
            t.join(max(0.0, deadline - time.monotonic()))

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> bool:
        if exc_type is None:
            self.shutdown(wait=True)
        else:
            self.stop()
        return False


def run_tasks(fn: Callable, items: Iterable[Any], *, workers: int | None = None,
              scheduler: str | None = None, progress: bool = False, desc: str = "",
              executor=None) -> Iterator[tuple[int, Any]]:
    """Yield ``(index, fn(item))`` as tasks complete (not in order), with optional progress
    (:func:`progress_bar`: a bar on a terminal, log lines otherwise).

    ``workers``: local processes; ``None`` (the default of every ``--workers``): one per core
    (:func:`default_workers`), never more than there are items (one item runs in this process). Callers that need
    resumability write each result as it arrives.
    """
    items = list(items)
    own = executor is None
    if own and scheduler is None:
        workers = task_workers(workers, len(items))
    ex = executor if executor is not None else get_executor(workers, scheduler)
    bar = progress_bar(len(items), desc, "task") if progress else None
    interrupted = True  # until every result has been handed over (Ctrl-C, an error, the caller stopping)
    try:
        if isinstance(ex, DaskExecutor):
            pairs = ex.completed([ex.submit(fn, it) for it in items])
        else:
            cfuts = {ex.submit(fn, it): i for i, it in enumerate(items)}
            pairs = ((cfuts[f], f) for f in cf.as_completed(cfuts))
        for i, fut in pairs:
            res = fut.result()
            if bar is not None:
                bar.update(1)
            stopping.check()  # a stop signal that compiled code's callback dropped (metafovea.stopping)
            yield i, res
        interrupted = False
    finally:
        if bar is not None:
            bar.close()
        if own:
            if interrupted and isinstance(ex, cf.ProcessPoolExecutor):
                stop_workers(ex)
            elif isinstance(ex, cf.Executor):
                ex.shutdown(wait=True, cancel_futures=True)
            else:
                ex.close()
